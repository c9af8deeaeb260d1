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
//!
//! Replacement worker ranks ([`Transport::replace`], docs/distributed.md "Replacing a killed
//! rank"): rank 0 starts one more process of the same program with the same arguments by
//! `MPI_Comm_spawn` over `MPI_COMM_SELF` (raw FFI: rsmpi 0.8's `spawn` passes no info, leaves the
//! error handler fatal and disconnects, a blocking collective, when its communicator is dropped),
//! and talks to it over the intercommunicator that returns. The ranks are numbered on from the
//! world: the first replacement is rank `world size`, the next one more. The new process finds
//! its parent with `MPI_Comm_get_parent` (that is what marks it as a replacement; its command
//! line is rank 0's) and takes its number from rank 0's first message (tag 8). At the end rank 0
//! disconnects from every replacement still present before it ends the job
//! ([`MpiTransport::disconnect_replacements`]): measured, an `MPI_Abort` while a spawned process
//! sat in its own disconnect left `mpirun` hanging.

use super::{DistributedError, Transport};
use mpi::environment::Universe;
use mpi::request::{Request, StaticScope};
use mpi::topology::{InterCommunicator, SimpleCommunicator};
use mpi::traits::*;
use std::mem::ManuallyDrop;
use std::time::{Duration, Instant};

/// The one message tag of the trainer's traffic.
const TAG: i32 = 7;

/// The tag of rank 0's first message to a replacement: its rank and the world's size.
const HELLO_TAG: i32 = 8;

/// The longest a replacement waits for that message.
const HELLO_WAIT: Duration = Duration::from_secs(600);

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

/// Where a rank's messages go: the world, or an intercommunicator with one process on the far
/// side (rank 0 of it).
enum Route<'a> {
    World(i32),
    Inter(&'a InterCommunicator),
}

/// The MPI world, and the replacements started since, as a [`Transport`]. Dropping it finalises
/// MPI.
pub struct MpiTransport {
    world: SimpleCommunicator,
    /// Rank 0: the replacements' intercommunicators, rank `world size + i` at `i` (None once
    /// disconnected). Never dropped implicitly: dropping disconnects, which waits for the other
    /// side (for ever when it is dead).
    replacements: Vec<Option<ManuallyDrop<InterCommunicator>>>,
    /// A replacement: its rank, the world's size (the ranks the run started with: its
    /// [`Transport::size`], so per-rank settings such as the evaluation rate are those of the
    /// rank it replaces), and rank 0 on the far side of its parent intercommunicator (dropped, i.e. disconnected, before MPI is
    /// finalised).
    parent: Option<(usize, usize, InterCommunicator)>,
    pending: Vec<Pending>,
    receiving: Vec<Receiving>,
    // Last: finalised after everything above is gone.
    _universe: Universe,
}

impl std::fmt::Debug for MpiTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MpiTransport")
            .field("rank", &self.rank())
            .field("size", &self.size())
            .field("replacements", &self.replacements.len())
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
    /// A process started as a replacement (it has an MPI parent) then waits for rank 0's first
    /// message, which gives its rank.
    pub fn init() -> Result<Self, DistributedError> {
        let (universe, got) = mpi::initialize_with_threading(mpi::Threading::Funneled)
            .ok_or(DistributedError::Init)?;
        if got < mpi::Threading::Funneled {
            return Err(DistributedError::Threading {
                wanted: level_name(mpi::Threading::Funneled),
                got: level_name(got),
            });
        }
        let world = universe.world();
        let parent = match world.parent().map(hello) {
            Some(Ok(p)) => Some(p),
            Some(Err(e)) => {
                // Not finalised: that would first disconnect from rank 0 and wait for it (for
                // ever if it is gone); the process ends as a dead rank does.
                std::mem::forget(universe);
                return Err(e);
            }
            None => None,
        };
        Ok(MpiTransport {
            world,
            replacements: Vec::new(),
            parent,
            pending: Vec::new(),
            receiving: Vec::new(),
            _universe: universe,
        })
    }

    /// Whether this process was started as a replacement worker rank.
    pub fn is_replacement(&self) -> bool {
        self.parent.is_some()
    }

    /// Rank 0, at the end of a run that started replacements: disconnects from each one not in
    /// `lost` (they disconnect from their side once they have taken the stop), after taking
    /// what they still send (a send still in flight would hold the disconnect), so that the
    /// job can end. A lost replacement is left alone: disconnecting would wait for it for ever.
    pub fn disconnect_replacements(&mut self, lost: &[usize]) {
        let base = self.world.size() as usize;
        for i in 0..self.replacements.len() {
            let rank = base + i;
            if lost.contains(&rank) || self.replacements[i].is_none() {
                continue;
            }
            // Take messages until none came for 200 ms (at most 2 s).
            let t0 = Instant::now();
            let mut quiet = Instant::now();
            while quiet.elapsed() < Duration::from_millis(200)
                && t0.elapsed() < Duration::from_secs(2)
            {
                if matches!(self.try_recv(Some(rank)), Ok(Some(_))) {
                    quiet = Instant::now();
                } else {
                    std::thread::sleep(Duration::from_millis(1));
                }
            }
            if let Some(c) = self.replacements[i].take() {
                // MPI_Comm_disconnect (rsmpi's drop of an intercommunicator).
                drop(ManuallyDrop::into_inner(c));
            }
        }
    }

    fn route(&self, rank: usize) -> Option<Route<'_>> {
        if let Some((_, _, p)) = &self.parent {
            return (rank == 0).then_some(Route::Inter(p));
        }
        let world = self.world.size() as usize;
        if rank < world {
            return Some(Route::World(rank as i32));
        }
        self.replacements
            .get(rank - world)?
            .as_ref()
            .map(|c| Route::Inter(c))
    }

    /// A message that has arrived from `from` (or anyone), probed: the message, its status and
    /// the sender's rank.
    fn probe(
        &self,
        from: Option<usize>,
    ) -> Option<(
        mpi::point_to_point::Message,
        mpi::point_to_point::Status,
        usize,
    )> {
        if let Some(r) = from {
            let (m, st) = match self.route(r)? {
                Route::World(w) => self
                    .world
                    .process_at_rank(w)
                    .immediate_matched_probe_with_tag(TAG),
                Route::Inter(c) => c.process_at_rank(0).immediate_matched_probe_with_tag(TAG),
            }?;
            return Some((m, st, r));
        }
        if let Some((_, _, p)) = &self.parent {
            let (m, st) = p.any_process().immediate_matched_probe_with_tag(TAG)?;
            return Some((m, st, 0));
        }
        if let Some((m, st)) = self
            .world
            .any_process()
            .immediate_matched_probe_with_tag(TAG)
        {
            let r = st.source_rank() as usize;
            return Some((m, st, r));
        }
        let world = self.world.size() as usize;
        self.replacements.iter().enumerate().find_map(|(i, c)| {
            let (m, st) = c
                .as_ref()?
                .any_process()
                .immediate_matched_probe_with_tag(TAG)?;
            Some((m, st, world + i))
        })
    }

    fn send_tagged(&mut self, to: usize, bytes: Vec<u8>, tag: i32) -> Result<(), DistributedError> {
        let buf: *mut [u8] = Box::into_raw(bytes.into_boxed_slice());
        // SAFETY: the allocation stays alive until `progress` sees the request complete (or,
        // for a request that never completes, forever: leaked).
        let shared: &'static [u8] = unsafe { &*buf };
        let req = match self.route(to) {
            Some(Route::World(w)) => {
                self.world
                    .process_at_rank(w)
                    .immediate_send_with_tag(StaticScope, shared, tag)
            }
            Some(Route::Inter(c)) => {
                c.process_at_rank(0)
                    .immediate_send_with_tag(StaticScope, shared, tag)
            }
            None => {
                // SAFETY: nothing borrowed it.
                drop(unsafe { Box::from_raw(buf) });
                return Err(DistributedError::Config {
                    why: "send to a rank beyond the world and its replacements",
                });
            }
        };
        self.pending.push(Pending { to, req, buf });
        Ok(())
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
        match &self.parent {
            Some((rank, _, _)) => *rank,
            None => self.world.rank() as usize,
        }
    }

    fn size(&self) -> usize {
        match &self.parent {
            Some((_, size, _)) => *size,
            None => self.world.size() as usize + self.replacements.len(),
        }
    }

    fn try_recv(
        &mut self,
        from: Option<usize>,
    ) -> Result<Option<(usize, Vec<u8>)>, DistributedError> {
        self.progress();
        // Start a matched receive for every message that has arrived (from `from`, or anyone).
        while let Some((message, status, sender)) = self.probe(from) {
            let len = usize::try_from(status.count(u8::equivalent_datatype())).unwrap_or(0);
            let buf: *mut [u8] = Box::into_raw(vec![0u8; len].into_boxed_slice());
            // SAFETY: the allocation stays alive until the request completes (then `try_recv`
            // takes it back with `Box::from_raw`) or, for one that never completes, forever.
            let target: &'static mut [u8] = unsafe { &mut *buf };
            let req = message.immediate_matched_receive_into(StaticScope, target);
            self.receiving.push(Receiving {
                from: sender,
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
        self.send_tagged(to, bytes, TAG)
    }

    fn in_flight(&mut self, to: usize) -> usize {
        self.progress();
        self.pending.iter().filter(|p| p.to == to).count()
    }

    fn replace(&mut self, lost: usize) -> Result<usize, DistributedError> {
        if self.parent.is_some() || self.world.rank() != 0 {
            return Err(DistributedError::Spawn {
                why: format!("only rank 0 starts replacements (asked for rank {lost})"),
            });
        }
        let comm = spawn_same_program()?;
        let rank = self.size();
        self.replacements.push(Some(ManuallyDrop::new(comm)));
        let size = self.world.size() as usize;
        let hello: Vec<u8> = [rank as u64, size as u64]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        self.send_tagged(rank, hello, HELLO_TAG)?;
        Ok(rank)
    }
}

/// The text of an MPI error code.
fn error_text(code: i32) -> String {
    let mut buf = vec![0u8; 512];
    let mut len: i32 = 0;
    // SAFETY: `buf` holds more than MPI_MAX_ERROR_STRING (256 in Open MPI) bytes.
    let rc = unsafe { mpi::ffi::MPI_Error_string(code, buf.as_mut_ptr().cast(), &mut len) };
    if rc != mpi::ffi::MPI_SUCCESS as i32 {
        return format!("MPI error {code}");
    }
    buf.truncate(usize::try_from(len).unwrap_or(0).min(512));
    format!("{} (MPI error {code})", String::from_utf8_lossy(&buf))
}

/// Starts one more process of this program with this process's arguments and working directory
/// (`MPI_Comm_spawn` over `MPI_COMM_SELF`, errors returned rather than fatal).
fn spawn_same_program() -> Result<InterCommunicator, DistributedError> {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    let fail = |why: String| DistributedError::Spawn { why };
    let exe = std::env::current_exe().map_err(|e| fail(format!("this program's path: {e}")))?;
    let cstr = |b: &[u8]| CString::new(b).map_err(|_| fail("an argument holds a NUL byte".into()));
    let prog = cstr(exe.as_os_str().as_bytes())?;
    let args = std::env::args_os()
        .skip(1)
        .map(|a| cstr(a.as_bytes()))
        .collect::<Result<Vec<_>, _>>()?;
    let mut argv: Vec<*mut std::os::raw::c_char> = args
        .iter()
        .map(|a| a.as_ptr().cast_mut())
        .chain(std::iter::once(std::ptr::null_mut()))
        .collect();
    let wdir = std::env::current_dir().map_err(|e| fail(format!("the working directory: {e}")))?;
    let key = cstr(b"wdir")?;
    let value = cstr(wdir.as_os_str().as_bytes())?;
    let mut errcode: i32 = 0;
    // SAFETY: every pointer is to a live, NUL-terminated string (`argv` ends in a null pointer)
    // or to a local the call writes; the info object is freed after the call.
    let (rc, inter) = unsafe {
        let ffi = &mpi::ffi::RSMPI_COMM_SELF;
        mpi::ffi::MPI_Comm_set_errhandler(*ffi, mpi::ffi::RSMPI_ERRORS_RETURN);
        let mut info = mpi::ffi::RSMPI_INFO_NULL;
        mpi::ffi::MPI_Info_create(&mut info);
        mpi::ffi::MPI_Info_set(info, key.as_ptr(), value.as_ptr());
        let mut inter = mpi::ffi::RSMPI_COMM_NULL;
        let rc = mpi::ffi::MPI_Comm_spawn(
            prog.as_ptr(),
            argv.as_mut_ptr(),
            1,
            info,
            0,
            *ffi,
            &mut inter,
            &mut errcode,
        );
        mpi::ffi::MPI_Info_free(&mut info);
        (rc, inter)
    };
    let ok = mpi::ffi::MPI_SUCCESS as i32;
    if rc != ok || errcode != ok {
        let code = if rc != ok { rc } else { errcode };
        return Err(fail(format!(
            "MPI_Comm_spawn: {} (a replacement needs a free slot: mpirun --oversubscribe, or \
             more slots than ranks)",
            error_text(code)
        )));
    }
    // SAFETY: a live intercommunicator that MPI_Comm_spawn just returned.
    unsafe { InterCommunicator::try_from_raw(inter) }
        .ok_or_else(|| fail("MPI_Comm_spawn returned no intercommunicator".into()))
}

/// A replacement's start: waits for rank 0's first message (its rank and the world's size).
fn hello(parent: InterCommunicator) -> Result<(usize, usize, InterCommunicator), DistributedError> {
    match read_hello(&parent) {
        Ok((rank, size)) => Ok((rank, size, parent)),
        Err(e) => {
            // Not disconnected: that waits for rank 0 (for ever if it is gone).
            std::mem::forget(parent);
            Err(e)
        }
    }
}

/// Waits for rank 0's first message on `parent` and reads it.
fn read_hello(parent: &InterCommunicator) -> Result<(usize, usize), DistributedError> {
    let t0 = Instant::now();
    loop {
        if let Some((m, _)) = parent
            .process_at_rank(0)
            .immediate_matched_probe_with_tag(HELLO_TAG)
        {
            let mut b = [0u8; 16];
            m.matched_receive_into(&mut b[..]);
            let word = |i: usize| {
                let mut w = [0u8; 8];
                w.copy_from_slice(&b[8 * i..8 * i + 8]);
                u64::from_le_bytes(w)
            };
            let rank = usize::try_from(word(0)).map_err(|_| DistributedError::BadMessage {
                why: "a replacement's rank out of range",
            })?;
            let size = usize::try_from(word(1)).map_err(|_| DistributedError::BadMessage {
                why: "a replacement's rank count out of range",
            })?;
            if rank == 0 || size == 0 {
                return Err(DistributedError::BadMessage {
                    why: "a replacement's rank out of range",
                });
            }
            return Ok((rank, size));
        }
        if t0.elapsed() > HELLO_WAIT {
            return Err(DistributedError::NoServer {
                rank: 0,
                waited_s: t0.elapsed().as_secs_f64(),
            });
        }
        std::thread::sleep(Duration::from_millis(1));
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
