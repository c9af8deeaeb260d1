//! The virtual CAN bus: a TCP server speaking the socketcand subset of [`crate::protocol`].
//!
//! Threads: one acceptor; per client one reader (parses, forwards events) and one writer (drains a
//! bounded queue onto the socket); one central bus thread that owns all state. Every frame passes the
//! bus thread, which gives it its place in the one global order and its timestamp (bus time), applies
//! the injected faults, writes the candump log and queues it for every *other* subscribed client. A
//! full client queue drops the frame for that client only (counted), so a slow client never stalls
//! the bus. Delayed frames wait in a time-ordered heap inside the bus thread. Bus time is the wall
//! clock since start, or in lockstep mode a virtual clock set by [`Bus::set_time`] or `< time US >`.
//!
//! Wire time ([`BusConfig::wire`], `hil-sim bus --bitrate`): every frame is offered to the wire
//! ([`crate::arbitration`]) and takes its bits over the bit rate; frames offered while the wire is
//! busy wait, and at each idle the lowest identifier among them goes next. A frame's timestamp is
//! its end of frame. In real time a frame is delivered when the wall clock reaches its end of frame;
//! in lockstep it is delivered at once with its virtual end time, and is offered at the bus time (or
//! at the later time its sender names with `< txtime US >`: a lockstep node's answer, after its
//! compute), so the run stays deterministic. Without `wire` the bus is untimed, as before: a frame's
//! timestamp is the bus time it arrived at.
//!
//! What a client writes in one system call reaches the bus thread as one event: a reader hands over
//! every message of one read together ([`Event::Batch`]). A node flushes its answer to a frame in one
//! write (the controller's action frames and the emergency after them, a heartbeat and the status
//! TPDO after it), so no other client's event comes between those frames. In lockstep this keeps
//! such an answer at one bus time: the plant advances the clock as soon as it has the last action
//! frame (or the heartbeat it waits for), and the frames behind it in the same write must not be
//! stamped with the next cycle's time.
//!
//! std threads rather than an async runtime: the client count is small (a handful), the per-frame
//! work is tiny, and blocking sockets with `TCP_NODELAY` give the lowest latency without pulling in
//! a runtime; the only shared state is behind one channel into the bus thread.

mod config;
mod control;
mod error;
mod io;
mod stats;
mod thread;

use std::collections::{BinaryHeap, HashMap, VecDeque};
use std::fs::File;
use std::io::BufWriter;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::arbitration::Arbiter;
use crate::wire_fd::BusWire;

pub use config::{BusClock, BusConfig};
pub use control::{ControlCommand, FaultKind, FaultRule, parse_control};
pub use error::BusError;
pub use stats::BusStats;

use io::accept_loop;
use thread::{BusThread, Event, Shared};

/// Linux `CAN_ERR_BUSOFF` class bit, sent as `< error 040 TS >` when bus-off starts.
pub const ERR_BUSOFF: u32 = 0x040;
/// Linux `CAN_ERR_RESTARTED` class bit, sent when bus-off ends.
pub const ERR_RESTARTED: u32 = 0x100;
/// How long a new client is left alone after its `< rawmode >` `< ok >` (python-can reads the
/// handshake reply with one `recv` that could swallow a frame sent right behind it).
pub const HANDSHAKE_GRACE: Duration = Duration::from_millis(20);

/// A running bus; dropping it (or [`Bus::shutdown`]) stops its threads.
pub struct Bus {
    addr: SocketAddr,
    events: Sender<Event>,
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
}

impl std::fmt::Debug for Bus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bus").field("addr", &self.addr).finish()
    }
}

impl Bus {
    /// Binds and starts the bus.
    pub fn start(cfg: BusConfig) -> Result<Bus, BusError> {
        let listener = TcpListener::bind(cfg.addr).map_err(|source| BusError::Bind {
            addr: cfg.addr,
            source,
        })?;
        let addr = listener.local_addr().map_err(|source| BusError::Bind {
            addr: cfg.addr,
            source,
        })?;
        let log = match &cfg.log {
            Some(path) => Some(BufWriter::new(File::create(path).map_err(|source| {
                BusError::Log {
                    path: path.clone(),
                    source,
                }
            })?)),
            None => None,
        };
        let shared = Arc::new(Shared {
            stats: Mutex::new(BusStats::default()),
            status: Arc::new(Mutex::new(String::from("no controller node"))),
            stop: AtomicBool::new(false),
            quit: AtomicBool::new(false),
        });
        let (tx, rx) = mpsc::channel();
        let mut threads = Vec::new();
        let state = BusThread {
            cfg: cfg.clone(),
            shared: Arc::clone(&shared),
            clients: HashMap::new(),
            rules: Vec::new(),
            delayed: BinaryHeap::new(),
            seq: 0,
            busoff_until: None,
            start: Instant::now(),
            vnow: 0,
            log,
            stats: BusStats::default(),
            arbiter: cfg.wire.map(|nominal| {
                Arbiter::new(BusWire {
                    nominal,
                    data_bitrate: cfg.fd_data_bitrate,
                })
            }),
            in_flight: VecDeque::new(),
            event_ns: 0,
        };
        threads.push(
            std::thread::Builder::new()
                .name("bus".into())
                .spawn(move || state.run(rx))
                .map_err(BusError::Thread)?,
        );
        let accept_tx = tx.clone();
        let accept_shared = Arc::clone(&shared);
        let depth = cfg.queue_depth.max(16);
        let sndbuf = cfg.send_buffer;
        threads.push(
            std::thread::Builder::new()
                .name("bus-accept".into())
                .spawn(move || accept_loop(listener, accept_tx, accept_shared, depth, sndbuf))
                .map_err(BusError::Thread)?,
        );
        Ok(Bus {
            addr,
            events: tx,
            shared,
            threads,
        })
    }

    /// The address clients connect to.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Sets the virtual bus time (lockstep); ordered with every frame a client sends afterwards.
    pub fn set_time(&self, us: u64) {
        let _ = self.events.send(Event::Control {
            client: None,
            command: Ok(ControlCommand::Time(us)),
        });
    }

    /// Applies a control command as if it came over the control connection.
    pub fn control(&self, command: ControlCommand) {
        let _ = self.events.send(Event::Control {
            client: None,
            command: Ok(command),
        });
    }

    /// The bus time in microseconds: the clock, or the end of the last frame on the wire if that
    /// is later (a lockstep plant starts its cycles after it). Ordered after every event sent to
    /// the bus before; 0 if the bus has stopped.
    pub fn bus_time(&self) -> u64 {
        let (tx, rx) = mpsc::channel();
        if self.events.send(Event::Now(tx)).is_err() {
            return 0;
        }
        rx.recv_timeout(Duration::from_secs(2)).unwrap_or(0)
    }

    /// A snapshot of the counters (updated by the bus thread after every event).
    pub fn stats(&self) -> BusStats {
        self.shared.stats.lock().map(|s| *s).unwrap_or_default()
    }

    /// The status line answered to `< diag >`; an in-process controller node writes it.
    pub fn status_slot(&self) -> Arc<Mutex<String>> {
        Arc::clone(&self.shared.status)
    }

    /// Whether a client sent `< quit >`.
    pub fn quit_requested(&self) -> bool {
        self.shared.quit.load(Ordering::SeqCst)
    }

    /// Stops every thread and flushes the log.
    pub fn shutdown(mut self) {
        self.stop_threads();
    }

    fn stop_threads(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        let _ = self.events.send(Event::Shutdown);
        // Wake the acceptor.
        let _ = TcpStream::connect_timeout(&self.addr, Duration::from_millis(200));
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl Drop for Bus {
    fn drop(&mut self) {
        if !self.threads.is_empty() {
            self.stop_threads();
        }
    }
}
