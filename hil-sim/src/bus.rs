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

use std::collections::{BinaryHeap, HashMap, VecDeque};
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use dex_runtime::can::{AnyFrame, CanFrame, FdFrame};
use embedded_can::{Frame, Id};

use crate::wire::WireConfig;
use crate::wire_fd::BusWire;

use crate::arbitration::{Arbiter, OnWire};
use crate::protocol::{
    Framer, Request, any_frame_message, candump_any_line, error_message, parse_request,
};

/// Linux `CAN_ERR_BUSOFF` class bit, sent as `< error 040 TS >` when bus-off starts.
pub const ERR_BUSOFF: u32 = 0x040;
/// Linux `CAN_ERR_RESTARTED` class bit, sent when bus-off ends.
pub const ERR_RESTARTED: u32 = 0x100;
/// How long a new client is left alone after its `< rawmode >` `< ok >` (python-can reads the
/// handshake reply with one `recv` that could swallow a frame sent right behind it).
pub const HANDSHAKE_GRACE: Duration = Duration::from_millis(20);

/// Errors of the bus server.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    /// The listening socket could not be set up.
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        /// Address asked for.
        addr: SocketAddr,
        /// Cause.
        source: std::io::Error,
    },
    /// The bus log could not be created.
    #[error("cannot create bus log {path}: {source}")]
    Log {
        /// Path asked for.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// A thread could not be started.
    #[error("cannot start a bus thread: {0}")]
    Thread(std::io::Error),
}

/// Where bus time comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BusClock {
    /// Microseconds of wall clock since the bus started.
    Wall,
    /// Simulation time, set by [`Bus::set_time`] or the `< time US >` control verb (lockstep).
    Virtual,
}

/// Settings of the bus server.
#[derive(Debug, Clone)]
pub struct BusConfig {
    /// Address to listen on (port 0: a free port).
    pub addr: SocketAddr,
    /// Source of bus time.
    pub clock: BusClock,
    /// Messages queued per client before frames to it are dropped.
    pub queue_depth: usize,
    /// candump-format log file.
    pub log: Option<PathBuf>,
    /// Channel name in the log.
    pub channel: String,
    /// Fixed kernel send buffer per client socket (`SO_SNDBUF`); `None` keeps autotuning. A small
    /// one makes a stalled client's queue fill quickly (tests of the slow-client path).
    pub send_buffer: Option<usize>,
    /// Time on the wire: bit rate and stuffing of every frame, arbitration by identifier,
    /// end-of-frame timestamps. `None`: untimed (a frame's timestamp is when it arrived).
    pub wire: Option<WireConfig>,
    /// CAN FD (`hil-sim bus --fd --data-bitrate D`): the data-phase bit rate. The bus then carries
    /// FD frames (`< fdsend >`, delivered as `< fdframe >`) beside classic ones, each FD frame
    /// timed over the two bit rates ([`BusWire`]). `None`: a classic bus, which ignores FD frames
    /// (counted in `unknown_messages`).
    pub fd_data_bitrate: Option<u32>,
}

impl Default for BusConfig {
    fn default() -> Self {
        BusConfig {
            addr: SocketAddr::from(([127, 0, 0, 1], 0)),
            clock: BusClock::Wall,
            queue_depth: 4096,
            log: None,
            channel: "vcan0".to_string(),
            send_buffer: None,
            wire: None,
            fd_data_bitrate: None,
        }
    }
}

/// Counters of the bus.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BusStats {
    /// Frames received from clients.
    pub frames_in: u64,
    /// Frames put on the bus (after faults; each counted once, however many clients got it).
    pub frames_on_bus: u64,
    /// Frame copies queued to clients.
    pub deliveries: u64,
    /// Frame copies dropped because a client's queue was full.
    pub queue_drops: u64,
    /// Frames dropped by a drop fault.
    pub fault_dropped: u64,
    /// Frames corrupted by a corrupt fault.
    pub fault_corrupted: u64,
    /// Frames delayed by a delay fault.
    pub fault_delayed: u64,
    /// Frames lost while the bus was off.
    pub busoff_dropped: u64,
    /// Messages that were not understood (ignored).
    pub unknown_messages: u64,
    /// Clients connected now.
    pub clients: u64,
    /// Clients connected since start.
    pub connections: u64,
    /// Frames that waited for the wire (offered while it was busy or lost arbitration).
    pub wire_waited: u64,
    /// Most frames waiting for the wire at once.
    pub wire_queue_peak: u64,
}

/// What a fault rule does to a matching frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// The frame disappears.
    Drop,
    /// One bit of the last data byte is flipped (an E2E CRC error for protected frames).
    Corrupt,
    /// The frame is put on the bus this many microseconds of bus time later.
    Delay(u64),
}

/// One injected fault: applies to frames with `id` (all frames if `None`), `remaining` times
/// (until cleared if `None`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultRule {
    /// The effect.
    pub kind: FaultKind,
    /// Raw identifier matched, or every frame.
    pub id: Option<u32>,
    /// Frames left to affect.
    pub remaining: Option<u64>,
}

/// A parsed control command (`< fault ... >`, `< time US >`, `< stats >`, `< diag >`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ControlCommand {
    /// Add a fault rule.
    Fault(FaultRule),
    /// Bus-off for this many microseconds of bus time (0: until [`ControlCommand::Clear`]).
    BusOff(u64),
    /// Remove every fault rule and end bus-off.
    Clear,
    /// Set virtual bus time (lockstep).
    Time(u64),
    /// The frames this client sends next are offered to the wire at this bus time (lockstep;
    /// never earlier than the bus time): a node's answer after its compute. Not answered.
    TxTime(u64),
    /// Report the bus time: the clock, or the end of the last frame on the wire if later.
    Now,
    /// Report the bus counters.
    Stats,
    /// Report the status line of the in-process controller node.
    Diag,
    /// Ask the process that owns the bus to exit (see [`Bus::quit_requested`]).
    Quit,
}

/// Parses control words, e.g. `fault drop 205 1`, `fault delay * 30000 0`, `fault busoff 300`
/// (`fault busoff 0`: off until `fault clear`).
pub fn parse_control(words: &[String]) -> Result<ControlCommand, String> {
    let w: Vec<&str> = words.iter().map(String::as_str).collect();
    let id = |s: &str| -> Result<Option<u32>, String> {
        if s == "*" {
            Ok(None)
        } else {
            u32::from_str_radix(s.trim_start_matches("0x"), 16)
                .map(Some)
                .map_err(|_| format!("bad id {s}"))
        }
    };
    let num = |s: &str| -> Result<u64, String> { s.parse().map_err(|_| format!("bad number {s}")) };
    let count = |s: &str| -> Result<Option<u64>, String> {
        num(s).map(|n| if n == 0 { None } else { Some(n) })
    };
    match w.as_slice() {
        ["fault", "drop", i, n] => Ok(ControlCommand::Fault(FaultRule {
            kind: FaultKind::Drop,
            id: id(i)?,
            remaining: count(n)?,
        })),
        ["fault", "corrupt", i, n] => Ok(ControlCommand::Fault(FaultRule {
            kind: FaultKind::Corrupt,
            id: id(i)?,
            remaining: count(n)?,
        })),
        ["fault", "delay", i, us, n] => Ok(ControlCommand::Fault(FaultRule {
            kind: FaultKind::Delay(num(us)?),
            id: id(i)?,
            remaining: count(n)?,
        })),
        ["fault", "busoff", ms] => Ok(ControlCommand::BusOff(num(ms)?.saturating_mul(1000))),
        ["fault", "clear"] => Ok(ControlCommand::Clear),
        ["time", us] => Ok(ControlCommand::Time(num(us)?)),
        ["txtime", us] => Ok(ControlCommand::TxTime(num(us)?)),
        ["now"] => Ok(ControlCommand::Now),
        ["stats"] => Ok(ControlCommand::Stats),
        ["diag"] => Ok(ControlCommand::Diag),
        ["quit"] => Ok(ControlCommand::Quit),
        _ => Err(format!("unknown control command: {}", w.join(" "))),
    }
}

enum Outgoing {
    Line(String),
    Grace,
}

enum Event {
    Join {
        client: u64,
        out: SyncSender<Outgoing>,
    },
    Leave {
        client: u64,
    },
    Open {
        client: u64,
    },
    Subscribe {
        client: u64,
    },
    Frame {
        client: u64,
        frame: AnyFrame,
    },
    Control {
        client: Option<u64>,
        command: Result<ControlCommand, String>,
    },
    Unknown,
    /// Asks for the bus time ([`Bus::bus_time`]).
    Now(Sender<u64>),
    /// Everything one read of a client's socket held, in order: handled as one event, so that the
    /// frames a client writes at once get onto the bus with nothing of another client's between.
    Batch(Vec<Event>),
    Shutdown,
}

struct Client {
    out: SyncSender<Outgoing>,
    subscribed: bool,
    dropped: u64,
    /// Offer time (us) of the frames it sends next, from `< txtime US >`.
    txtime: u64,
}

/// A frame on its way over the wire: who sent it.
type Carried = (u64, AnyFrame);

#[derive(PartialEq, Eq, PartialOrd, Ord)]
struct Delayed {
    due: std::cmp::Reverse<(u64, u64)>,
    from: u64,
    frame: CanFrameOrd,
}

#[derive(PartialEq, Eq)]
struct CanFrameOrd(AnyFrame);
impl PartialOrd for CanFrameOrd {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for CanFrameOrd {
    fn cmp(&self, _: &Self) -> std::cmp::Ordering {
        std::cmp::Ordering::Equal
    }
}

struct Shared {
    stats: Mutex<BusStats>,
    status: Arc<Mutex<String>>,
    stop: AtomicBool,
    quit: AtomicBool,
}

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

/// Sets `SO_SNDBUF` (best effort).
fn set_send_buffer(stream: &TcpStream, bytes: usize) {
    use std::os::fd::AsRawFd;
    let value = libc::c_int::try_from(bytes).unwrap_or(libc::c_int::MAX);
    // SAFETY: the descriptor is open for the lifetime of `stream`, and the option value is a
    // c_int whose size is passed alongside.
    unsafe {
        libc::setsockopt(
            stream.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_SNDBUF,
            (&value as *const libc::c_int).cast(),
            std::mem::size_of::<libc::c_int>() as libc::socklen_t,
        );
    }
}

fn accept_loop(
    listener: TcpListener,
    events: Sender<Event>,
    shared: Arc<Shared>,
    depth: usize,
    sndbuf: Option<usize>,
) {
    let mut next_id = 0u64;
    for conn in listener.incoming() {
        if shared.stop.load(Ordering::SeqCst) {
            break;
        }
        let Ok(stream) = conn else { continue };
        let _ = stream.set_nodelay(true);
        if let Some(bytes) = sndbuf {
            set_send_buffer(&stream, bytes);
        }
        let Ok(write_half) = stream.try_clone() else {
            continue;
        };
        next_id += 1;
        let client = next_id;
        let (out_tx, out_rx) = mpsc::sync_channel(depth);
        if events
            .send(Event::Join {
                client,
                out: out_tx,
            })
            .is_err()
        {
            break;
        }
        let ev = events.clone();
        let spawned_reader = std::thread::Builder::new()
            .name(format!("bus-rd-{client}"))
            .spawn(move || reader_loop(client, stream, ev));
        let spawned_writer = std::thread::Builder::new()
            .name(format!("bus-wr-{client}"))
            .spawn(move || writer_loop(write_half, out_rx));
        if spawned_reader.is_err() || spawned_writer.is_err() {
            let _ = events.send(Event::Leave { client });
        }
    }
}

fn reader_loop(client: u64, mut stream: TcpStream, events: Sender<Event>) {
    let mut framer = Framer::default();
    // Large enough that a node's write (a few hundred bytes per answer) comes in one read.
    let mut buf = vec![0u8; 64 * 1024];
    loop {
        let n = match stream.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        framer.push(&buf[..n]);
        // Every complete message of this read in one event (see the module's documentation).
        let mut batch = Vec::new();
        while let Some(text) = framer.next_message() {
            batch.push(match parse_request(&text) {
                Request::Open(_) => Event::Open { client },
                Request::RawMode => Event::Subscribe { client },
                Request::Send(frame) => Event::Frame {
                    client,
                    frame: AnyFrame::Classic(frame),
                },
                Request::SendFd(frame) => Event::Frame {
                    client,
                    frame: AnyFrame::Fd(frame),
                },
                Request::Control(words) => Event::Control {
                    client: Some(client),
                    command: parse_control(&words),
                },
                Request::Unknown => Event::Unknown,
            });
        }
        let event = match batch.len() {
            0 => continue,
            1 => batch.swap_remove(0),
            _ => Event::Batch(batch),
        };
        if events.send(event).is_err() {
            return;
        }
    }
    let _ = stream.shutdown(std::net::Shutdown::Both);
    let _ = events.send(Event::Leave { client });
}

fn writer_loop(mut stream: TcpStream, out: Receiver<Outgoing>) {
    let mut batch = String::new();
    while let Ok(first) = out.recv() {
        let mut next = Some(first);
        while let Some(msg) = next.take() {
            match msg {
                Outgoing::Line(line) => {
                    batch.push_str(&line);
                    if batch.len() < 16 * 1024 {
                        next = out.try_recv().ok();
                    }
                }
                Outgoing::Grace => {
                    if stream.write_all(batch.as_bytes()).is_err() {
                        return;
                    }
                    batch.clear();
                    std::thread::sleep(HANDSHAKE_GRACE);
                }
            }
        }
        if !batch.is_empty() {
            if stream.write_all(batch.as_bytes()).is_err() {
                return;
            }
            batch.clear();
        }
    }
    let _ = stream.shutdown(std::net::Shutdown::Both);
}

struct BusThread {
    cfg: BusConfig,
    shared: Arc<Shared>,
    clients: HashMap<u64, Client>,
    rules: Vec<FaultRule>,
    delayed: BinaryHeap<Delayed>,
    seq: u64,
    busoff_until: Option<u64>,
    start: Instant,
    vnow: u64,
    log: Option<BufWriter<File>>,
    stats: BusStats,
    /// The wire, when timed.
    arbiter: Option<Arbiter<Carried>>,
    /// Real time: frames committed to the wire whose end of frame the wall clock has not reached.
    in_flight: VecDeque<OnWire<Carried>>,
    /// Real time: when the event being handled arrived (ns), the offer time of all its frames.
    event_ns: u64,
}

impl BusThread {
    fn now(&self) -> u64 {
        match self.cfg.clock {
            BusClock::Wall => self.start.elapsed().as_micros() as u64,
            BusClock::Virtual => self.vnow,
        }
    }

    fn now_ns(&self) -> u64 {
        match self.cfg.clock {
            BusClock::Wall => self.start.elapsed().as_nanos() as u64,
            BusClock::Virtual => self.vnow.saturating_mul(1000),
        }
    }

    /// Bus time in microseconds: the clock, or the end of the last frame on the wire if later.
    fn bus_time(&self) -> u64 {
        let wire = self
            .arbiter
            .as_ref()
            .map_or(0, |a| a.idle_from_ns().div_ceil(1000));
        self.now().max(wire)
    }

    /// Hands a frame to the wire at bus time `at_us` (a timed bus: it moves with the next
    /// [`BusThread::pump`]), or puts it on the bus at once.
    fn offer(&mut self, from: u64, frame: AnyFrame, at_us: u64) {
        let virtual_clock = self.cfg.clock == BusClock::Virtual;
        let txtime = self.clients.get(&from).map_or(0, |c| c.txtime);
        let Some(arbiter) = self.arbiter.as_mut() else {
            self.put_on_bus(from, &frame, at_us);
            return;
        };
        let at_ns = if virtual_clock {
            at_us.max(txtime).saturating_mul(1000)
        } else {
            self.event_ns
        };
        if arbiter.waiting() > 0 || arbiter.idle_from_ns() > at_ns {
            self.stats.wire_waited += 1;
        }
        arbiter.offer_any(at_ns, &frame, (from, frame));
        self.stats.wire_queue_peak = self.stats.wire_queue_peak.max(arbiter.waiting() as u64);
    }

    /// Moves frames over the wire: in lockstep every waiting frame is committed and delivered at
    /// its end of frame; in real time frames are committed when they start and delivered when the
    /// wall clock reaches their end.
    fn pump(&mut self) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        let virtual_clock = self.cfg.clock == BusClock::Virtual;
        let horizon = if virtual_clock {
            u64::MAX
        } else {
            self.start.elapsed().as_nanos() as u64
        };
        self.in_flight.extend(arbiter.commit_until(horizon));
        let now_ns = if virtual_clock { u64::MAX } else { horizon };
        while self.in_flight.front().is_some_and(|f| f.end_ns <= now_ns) {
            if let Some(f) = self.in_flight.pop_front() {
                let (from, frame) = f.item;
                self.put_on_bus(from, &frame, f.end_ns / 1000);
            }
        }
    }

    fn run(mut self, rx: Receiver<Event>) {
        loop {
            self.event_ns = self.now_ns();
            self.release_due();
            let wait = self.next_wait();
            let event = match rx.recv_timeout(wait) {
                Ok(e) => e,
                Err(RecvTimeoutError::Timeout) => {
                    if let Some(log) = self.log.as_mut() {
                        let _ = log.flush();
                    }
                    continue;
                }
                Err(RecvTimeoutError::Disconnected) => break,
            };
            if matches!(event, Event::Shutdown) {
                break;
            }
            // One offer time for everything this event carries (one write of a client).
            self.event_ns = self.now_ns();
            self.handle(event);
            // After the whole event: the frames one write offered are arbitrated together.
            self.pump();
            if let Ok(mut s) = self.shared.stats.lock() {
                *s = self.stats;
            }
        }
        if let Some(log) = self.log.as_mut() {
            let _ = log.flush();
        }
        self.clients.clear();
    }

    fn next_wait(&self) -> Duration {
        let idle = Duration::from_millis(100);
        if self.cfg.clock == BusClock::Virtual {
            return idle;
        }
        let now = self.now();
        let mut due = self.delayed.peek().map(|d| d.due.0.0);
        if let Some(until) = self.busoff_until {
            due = Some(due.map_or(until, |d| d.min(until)));
        }
        let wait = due.map_or(idle, |d| {
            Duration::from_micros(d.saturating_sub(now)).min(idle)
        });
        // The wire's next start or end of frame.
        let wire = self
            .in_flight
            .front()
            .map(|f| f.end_ns)
            .into_iter()
            .chain(self.arbiter.as_ref().and_then(Arbiter::next_start_ns))
            .min();
        wire.map_or(wait, |ns| {
            let now_ns = self.now_ns();
            wait.min(Duration::from_nanos(ns.saturating_sub(now_ns)))
        })
    }

    fn handle(&mut self, event: Event) {
        match event {
            Event::Join { client, out } => {
                let _ = out.try_send(Outgoing::Line("< hi >".into()));
                self.clients.insert(
                    client,
                    Client {
                        out,
                        subscribed: false,
                        dropped: 0,
                        txtime: 0,
                    },
                );
                self.stats.clients = self.clients.len() as u64;
                self.stats.connections += 1;
            }
            Event::Leave { client } => {
                self.clients.remove(&client);
                self.stats.clients = self.clients.len() as u64;
            }
            Event::Open { client } => self.reply(client, "< ok >".into()),
            Event::Subscribe { client } => {
                if let Some(c) = self.clients.get_mut(&client) {
                    let _ = c.out.try_send(Outgoing::Line("< ok >".into()));
                    let _ = c.out.try_send(Outgoing::Grace);
                    c.subscribed = true;
                }
            }
            Event::Frame { client, frame } => {
                self.stats.frames_in += 1;
                self.accept_frame(client, frame);
            }
            Event::Control {
                client: Some(c),
                command: Ok(ControlCommand::TxTime(us)),
            } => {
                if let Some(client) = self.clients.get_mut(&c) {
                    client.txtime = us;
                }
            }
            Event::Control { client, command } => {
                let reply = match command {
                    Ok(cmd) => self.apply_control(cmd),
                    Err(why) => format!("< nok {why} >"),
                };
                if let Some(c) = client {
                    self.reply(c, reply);
                }
            }
            Event::Unknown => self.stats.unknown_messages += 1,
            Event::Now(reply) => {
                let _ = reply.send(self.bus_time());
            }
            Event::Batch(events) => {
                for e in events {
                    self.handle(e);
                }
            }
            Event::Shutdown => {}
        }
    }

    fn reply(&mut self, client: u64, line: String) {
        if let Some(c) = self.clients.get_mut(&client) {
            let _ = c.out.try_send(Outgoing::Line(line));
        }
    }

    fn apply_control(&mut self, cmd: ControlCommand) -> String {
        match cmd {
            ControlCommand::Fault(rule) => self.rules.push(rule),
            ControlCommand::BusOff(us) => {
                let now = self.now();
                let until = if us == 0 {
                    u64::MAX
                } else {
                    now.saturating_add(us)
                };
                self.busoff_until = Some(until);
                self.broadcast_error(ERR_BUSOFF, now);
            }
            ControlCommand::Clear => {
                self.rules.clear();
                if self.busoff_until.take().is_some() {
                    let now = self.now();
                    self.broadcast_error(ERR_RESTARTED, now);
                }
            }
            ControlCommand::Time(us) => {
                if self.cfg.clock == BusClock::Virtual {
                    self.vnow = self.vnow.max(us);
                    self.release_due();
                }
            }
            ControlCommand::Stats => {
                let s = self.stats;
                return format!(
                    "< stats frames_in={} frames_on_bus={} deliveries={} queue_drops={} \
                     fault_dropped={} fault_corrupted={} fault_delayed={} busoff_dropped={} \
                     unknown_messages={} clients={} connections={} client_drops={} \
                     wire_waited={} wire_queue_peak={} >",
                    s.frames_in,
                    s.frames_on_bus,
                    s.deliveries,
                    s.queue_drops,
                    s.fault_dropped,
                    s.fault_corrupted,
                    s.fault_delayed,
                    s.busoff_dropped,
                    s.unknown_messages,
                    s.clients,
                    s.connections,
                    self.client_drops(),
                    s.wire_waited,
                    s.wire_queue_peak
                );
            }
            ControlCommand::Quit => self.shared.quit.store(true, Ordering::SeqCst),
            // A client's own offer time is set in `handle`; from elsewhere it means nothing.
            ControlCommand::TxTime(_) => {}
            ControlCommand::Now => return format!("< now {} >", self.bus_time()),
            ControlCommand::Diag => {
                let status = self
                    .shared
                    .status
                    .lock()
                    .map(|s| s.clone())
                    .unwrap_or_default();
                return format!("< diag {status} >");
            }
        }
        "< ok >".into()
    }

    /// `ID:DROPS` of every client that lost frames to a full queue, comma-separated (`-` if none).
    fn client_drops(&self) -> String {
        let mut v: Vec<String> = self
            .clients
            .iter()
            .filter(|(_, c)| c.dropped > 0)
            .map(|(id, c)| format!("{id}:{}", c.dropped))
            .collect();
        v.sort();
        if v.is_empty() {
            "-".into()
        } else {
            v.join(",")
        }
    }

    fn accept_frame(&mut self, from: u64, mut frame: AnyFrame) {
        if frame.is_fd() && self.cfg.fd_data_bitrate.is_none() {
            // A classic bus carries no FD frames.
            self.stats.unknown_messages += 1;
            return;
        }
        let now = self.now();
        if self.busoff_until.is_some_and(|until| now < until) {
            self.stats.busoff_dropped += 1;
            return;
        }
        let raw = match frame.id() {
            Id::Standard(s) => u32::from(s.as_raw()),
            Id::Extended(e) => e.as_raw(),
        };
        let rule = self
            .rules
            .iter_mut()
            .find(|r| r.id.is_none_or(|id| id == raw) && r.remaining != Some(0));
        if let Some(rule) = rule {
            if let Some(n) = rule.remaining.as_mut() {
                *n -= 1;
            }
            match rule.kind {
                FaultKind::Drop => {
                    self.stats.fault_dropped += 1;
                    return;
                }
                FaultKind::Corrupt => {
                    self.stats.fault_corrupted += 1;
                    let mut data = [0u8; 64];
                    let len = frame.data().len();
                    data[..len].copy_from_slice(frame.data());
                    if len > 0 {
                        data[len - 1] ^= 0x01;
                    }
                    frame = match frame {
                        AnyFrame::Classic(f) => {
                            CanFrame::new(f.id(), &data[..len]).map_or(frame, AnyFrame::Classic)
                        }
                        AnyFrame::Fd(f) => {
                            FdFrame::new_fd(f.id(), &data[..len], f.bit_rate_switch())
                                .map_or(frame, AnyFrame::Fd)
                        }
                    };
                }
                FaultKind::Delay(us) => {
                    self.stats.fault_delayed += 1;
                    self.seq += 1;
                    self.delayed.push(Delayed {
                        due: std::cmp::Reverse((now.saturating_add(us), self.seq)),
                        from,
                        frame: CanFrameOrd(frame),
                    });
                    return;
                }
            }
        }
        self.rules.retain(|r| r.remaining != Some(0));
        self.offer(from, frame, now);
    }

    fn release_due(&mut self) {
        let now = self.now();
        if self.busoff_until.is_some_and(|until| now >= until) {
            self.busoff_until = None;
            self.broadcast_error(ERR_RESTARTED, now);
        }
        while self.delayed.peek().is_some_and(|d| d.due.0.0 <= now) {
            if let Some(d) = self.delayed.pop() {
                let ts = d.due.0.0;
                self.offer(d.from, d.frame.0, ts.max(now));
            }
        }
        self.pump();
    }

    fn put_on_bus(&mut self, from: u64, frame: &AnyFrame, ts: u64) {
        self.stats.frames_on_bus += 1;
        if let Some(log) = self.log.as_mut() {
            let _ = writeln!(log, "{}", candump_any_line(&self.cfg.channel, frame, ts));
        }
        let line = any_frame_message(frame, ts);
        let mut gone = Vec::new();
        for (&id, c) in self.clients.iter_mut() {
            if id == from || !c.subscribed {
                continue;
            }
            match c.out.try_send(Outgoing::Line(line.clone())) {
                Ok(()) => self.stats.deliveries += 1,
                Err(TrySendError::Full(_)) => {
                    c.dropped += 1;
                    self.stats.queue_drops += 1;
                }
                Err(TrySendError::Disconnected(_)) => gone.push(id),
            }
        }
        for id in gone {
            self.clients.remove(&id);
        }
        self.stats.clients = self.clients.len() as u64;
    }

    fn broadcast_error(&mut self, class: u32, ts: u64) {
        let line = error_message(class, ts);
        for c in self.clients.values_mut().filter(|c| c.subscribed) {
            let _ = c.out.try_send(Outgoing::Line(line.clone()));
        }
    }
}
