//! The bus thread: owns all bus state, orders, times and delivers every frame.

use std::collections::{BinaryHeap, HashMap, VecDeque};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use dex_runtime::can::{AnyFrame, CanFrame, FdFrame};
use embedded_can::{Frame, Id};

use crate::arbitration::{Arbiter, OnWire};
use crate::protocol::{any_frame_message, candump_any_line, error_message};

#[cfg(doc)]
use super::Bus;
use super::config::{BusClock, BusConfig};
use super::control::{ControlCommand, FaultKind, FaultRule};
use super::io::Outgoing;
use super::stats::BusStats;
use super::{ERR_BUSOFF, ERR_RESTARTED};

pub(super) enum Event {
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

pub(super) struct Client {
    out: SyncSender<Outgoing>,
    subscribed: bool,
    dropped: u64,
    /// Offer time (us) of the frames it sends next, from `< txtime US >`.
    txtime: u64,
}

/// A frame on its way over the wire: who sent it.
type Carried = (u64, AnyFrame);

#[derive(PartialEq, Eq, PartialOrd, Ord)]
pub(super) struct Delayed {
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

pub(super) struct Shared {
    pub(super) stats: Mutex<BusStats>,
    pub(super) status: Arc<Mutex<String>>,
    pub(super) stop: AtomicBool,
    pub(super) quit: AtomicBool,
}

pub(super) struct BusThread {
    pub(super) cfg: BusConfig,
    pub(super) shared: Arc<Shared>,
    pub(super) clients: HashMap<u64, Client>,
    pub(super) rules: Vec<FaultRule>,
    pub(super) delayed: BinaryHeap<Delayed>,
    pub(super) seq: u64,
    pub(super) busoff_until: Option<u64>,
    pub(super) start: Instant,
    pub(super) vnow: u64,
    pub(super) log: Option<BufWriter<File>>,
    pub(super) stats: BusStats,
    /// The wire, when timed.
    pub(super) arbiter: Option<Arbiter<Carried>>,
    /// Real time: frames committed to the wire whose end of frame the wall clock has not reached.
    pub(super) in_flight: VecDeque<OnWire<Carried>>,
    /// Real time: when the event being handled arrived (ns), the offer time of all its frames.
    pub(super) event_ns: u64,
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

    pub(super) fn run(mut self, rx: Receiver<Event>) {
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
