//! [`Transport`] over MPI (the `mpi` crate on Open MPI; feature `mpi`).
//!
//! MPI is initialised with `MPI_THREAD_FUNNELED`: a rank runs W worker threads, but only the
//! thread that initialised MPI (the run's calling thread) makes MPI calls, so FUNNELED is the level
//! needed and it is checked. No call waits for another rank:
//! - receives are probes (`MPI_Improbe`) then *non-blocking* matched receives (`MPI_Imrecv`),
//!   kept until `MPI_Test` completes them. A matched message larger than the TCP transport's eager
//!   limit (64 KiB: every push of 64-wide networks or more) arrives as a header first and its body
//!   only when the sender's MPI library next makes progress; a blocking matched receive of it
//!   waited for ever when the sender was stopped (SIGSTOP) or killed between the two, which hung
//!   rank 0 in about one lost-rank test in seven. Now the message is simply not delivered, the
//!   sender's silence grows and the server times it out;
//! - sends are `MPI_Isend`s kept in flight until `MPI_Test` completes them, so a rank that stops
//!   cannot block its peer either: the peer sees the send stay in flight
//!   ([`Transport::in_flight`]) and times the rank out.

use super::{DistributedError, Transport};
use mpi::environment::Universe;
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

/// A matched receive in flight: MPI writes `buf` until the request completes.
struct Receiving {
    from: usize,
    req: Request<'static, [u8], StaticScope>,
    buf: *mut [u8],
}

/// The MPI world as a [`Transport`]. Dropping it finalises MPI.
pub struct MpiTransport {
    world: SimpleCommunicator,
    pending: Vec<Pending>,
    receiving: Vec<Receiving>,
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
            receiving: Vec::new(),
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
        // Start a matched receive for every message that has arrived (from `from`, or anyone).
        loop {
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
            let Some((message, status)) = probed else {
                break;
            };
            let len = usize::try_from(status.count(u8::equivalent_datatype())).unwrap_or(0);
            let buf: *mut [u8] = Box::into_raw(vec![0u8; len].into_boxed_slice());
            // SAFETY: the allocation stays alive until the request completes (then `try_recv`
            // takes it back with `Box::from_raw`) or, for one that never completes, forever.
            let target: &'static mut [u8] = unsafe { &mut *buf };
            let req = message.immediate_matched_receive_into(StaticScope, target);
            self.receiving.push(Receiving {
                from: status.source_rank() as usize,
                req,
                buf,
            });
        }
        // Hand over the first complete one; a sender's messages in the order MPI matched them
        // (one still arriving holds back that sender's later ones).
        let mut done = None;
        let mut held: Vec<usize> = Vec::new();
        let mut still = Vec::with_capacity(self.receiving.len());
        for r in self.receiving.drain(..) {
            if done.is_some() || held.contains(&r.from) || from.is_some_and(|f| f != r.from) {
                still.push(r);
                continue;
            }
            match r.req.test() {
                Ok(_) => {
                    // SAFETY: `buf` came from `Box::into_raw` above and only the request, now
                    // complete, borrowed it.
                    let bytes = unsafe { Box::from_raw(r.buf) }.into_vec();
                    done = Some((r.from, bytes));
                }
                Err(req) => {
                    held.push(r.from);
                    still.push(Receiving { req, ..r });
                }
            }
        }
        self.receiving = still;
        Ok(done)
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
        // Completed sends give their buffers back; sends and receives still in flight keep
        // theirs (leaked) and their requests are forgotten rather than dropped (the crate panics
        // on that).
        self.progress();
        for p in self.pending.drain(..) {
            std::mem::forget(p.req);
        }
        for r in self.receiving.drain(..) {
            std::mem::forget(r.req);
        }
    }
}
