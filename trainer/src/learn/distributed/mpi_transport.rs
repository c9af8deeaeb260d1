//! [`Transport`] over MPI (the `mpi` crate on Open MPI; feature `mpi`).
//!
//! MPI is initialised with `MPI_THREAD_FUNNELED`: a rank runs W worker threads, but only the
//! thread that initialised MPI (the run's calling thread) makes MPI calls, so FUNNELED is the level
//! needed and it is checked. Receives are probes (`MPI_Improbe`) then matched receives of what is
//! there, so no call waits for another rank; sends are `MPI_Isend`s kept in flight until
//! `MPI_Test` completes them, so a rank that stops (SIGSTOP) cannot block its peer: the peer sees
//! the send stay in flight ([`Transport::in_flight`]) and times the rank out.

use super::{DistributedError, Transport};
use mpi::environment::Universe;
use mpi::point_to_point::MatchedReceiveVec;
use mpi::request::{Request, StaticScope};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;

/// The one message tag of the trainer's traffic.
const TAG: i32 = 7;

/// A send in flight: MPI reads `buf` until the request completes.
struct Pending {
    to: usize,
    req: Request<'static, [u8], StaticScope>,
    buf: *mut [u8],
}

/// The MPI world as a [`Transport`]. Dropping it finalises MPI.
pub struct MpiTransport {
    world: SimpleCommunicator,
    pending: Vec<Pending>,
    // Last: finalised after everything above is gone.
    _universe: Universe,
}

impl std::fmt::Debug for MpiTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MpiTransport")
            .field("rank", &self.world.rank())
            .field("size", &self.world.size())
            .field("in_flight", &self.pending.len())
            .finish()
    }
}

fn level_name(t: mpi::Threading) -> &'static str {
    match t {
        mpi::Threading::Single => "MPI_THREAD_SINGLE",
        mpi::Threading::Funneled => "MPI_THREAD_FUNNELED",
        mpi::Threading::Serialized => "MPI_THREAD_SERIALIZED",
        mpi::Threading::Multiple => "MPI_THREAD_MULTIPLE",
    }
}

impl MpiTransport {
    /// Initialises MPI (FUNNELED, checked); call once, on the thread that will make every MPI call.
    pub fn init() -> Result<Self, DistributedError> {
        let (universe, got) = mpi::initialize_with_threading(mpi::Threading::Funneled)
            .ok_or(DistributedError::Init)?;
        if got < mpi::Threading::Funneled {
            return Err(DistributedError::Threading {
                wanted: level_name(mpi::Threading::Funneled),
                got: level_name(got),
            });
        }
        Ok(MpiTransport {
            world: universe.world(),
            pending: Vec::new(),
            _universe: universe,
        })
    }

    /// Ends the whole job (`MPI_Abort`) with `code`: after a lost rank, the other ranks would
    /// wait for the server forever.
    pub fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
    }

    fn progress(&mut self) {
        let mut still = Vec::with_capacity(self.pending.len());
        for p in self.pending.drain(..) {
            match p.req.test() {
                Ok(_) => {
                    // SAFETY: `buf` came from `Box::into_raw` in `send` and only the request,
                    // now complete, borrowed it.
                    drop(unsafe { Box::from_raw(p.buf) });
                }
                Err(req) => still.push(Pending { req, ..p }),
            }
        }
        self.pending = still;
    }
}

impl Transport for MpiTransport {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }

    fn size(&self) -> usize {
        self.world.size() as usize
    }

    fn try_recv(
        &mut self,
        from: Option<usize>,
    ) -> Result<Option<(usize, Vec<u8>)>, DistributedError> {
        self.progress();
        let probed = match from {
            Some(r) => self
                .world
                .process_at_rank(r as i32)
                .immediate_matched_probe_with_tag(TAG),
            None => self
                .world
                .any_process()
                .immediate_matched_probe_with_tag(TAG),
        };
        Ok(probed.map(|m| {
            let (bytes, status) = m.matched_receive_vec::<u8>();
            (status.source_rank() as usize, bytes)
        }))
    }

    fn send(&mut self, to: usize, bytes: Vec<u8>) -> Result<(), DistributedError> {
        if to >= self.size() {
            return Err(DistributedError::Config {
                why: "send to a rank beyond the world",
            });
        }
        let buf: *mut [u8] = Box::into_raw(bytes.into_boxed_slice());
        // SAFETY: the allocation stays alive until `progress` sees the request complete (or,
        // for a request that never completes, forever: leaked).
        let shared: &'static [u8] = unsafe { &*buf };
        let req = self
            .world
            .process_at_rank(to as i32)
            .immediate_send_with_tag(StaticScope, shared, TAG);
        self.pending.push(Pending { to, req, buf });
        Ok(())
    }

    fn in_flight(&mut self, to: usize) -> usize {
        self.progress();
        self.pending.iter().filter(|p| p.to == to).count()
    }
}

impl Drop for MpiTransport {
    fn drop(&mut self) {
        // Completed sends give their buffers back; any still in flight keep them (leaked) and
        // their requests are forgotten rather than dropped (the crate panics on that).
        self.progress();
        for p in self.pending.drain(..) {
            std::mem::forget(p.req);
        }
    }
}
