//! The controller node: `dex_runtime::Controller` behind the bus adapter, the same calls a
//! microcontroller's main loop makes (`on_frame` for each received frame, `poll` each period,
//! transmit whatever comes back).
//!
//! Time: in [`TimeMode::RealTime`] the controller reads a wall clock and the node polls at every
//! period boundary; in [`TimeMode::Lockstep`] the controller's clock is the bus timestamp of the
//! frames it receives and the node polls when a CANopen SYNC frame (id 0x080, sent by the plant at
//! the start of every simulated cycle) arrives, so the run is deterministic.
//!
//! Error frames: bus-off (Linux `CAN_ERR_BUSOFF`) goes to [`Controller::on_bus_off`], the restart
//! after it (`CAN_ERR_RESTARTED`) to [`Controller::on_bus_recovered`]; the bus's
//! `< fault busoff MILLIS >` sends both.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use dex_policy::PolicyView;
use dex_runtime::testkit::aligned_copy;
use dex_runtime::{Clock, Controller, ControllerConfig, Diagnostics, MockClock, Outbox};

use crate::bus::{ERR_BUSOFF, ERR_RESTARTED};
use crate::client::{BusClient, ClientError, Received};
use crate::flash::FlashServer;
use dex_runtime::can::CanFrame;

/// CANopen SYNC identifier: the lockstep cycle tick.
pub const SYNC_ID: u16 = 0x080;
/// Widest layer the host controller node accepts.
pub const NODE_WIDTH: usize = 256;

/// How the node gets time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeMode {
    /// Wall clock, polled at every period boundary (20 Hz).
    RealTime,
    /// Bus time of received frames; poll on SYNC.
    Lockstep,
}

/// Errors of the controller node.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// The bus connection failed.
    #[error(transparent)]
    Bus(#[from] ClientError),
}

/// A monotonic wall clock in microseconds since its creation.
#[derive(Debug, Clone, Copy)]
pub struct WallClock(Instant);

impl WallClock {
    /// A clock reading 0 now.
    pub fn new() -> Self {
        WallClock(Instant::now())
    }
}

impl Default for WallClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for WallClock {
    fn now_us(&self) -> u64 {
        self.0.elapsed().as_micros() as u64
    }
}

/// What the node reports when it stops.
#[derive(Debug, Clone)]
pub struct NodeReport {
    /// The controller's counters.
    pub diagnostics: Diagnostics,
    /// Why the policy was refused, if it was.
    pub load_error: Option<String>,
}

/// One status line: state, fault, policy load result, bus-off, every diagnostic counter and the
/// number of flashed files the controller refused at activation.
pub fn status_line<const W: usize>(
    c: &Controller<'_, W>,
    load: &str,
    activation_failures: u64,
) -> String {
    let d = c.diagnostics();
    format!(
        "state={:?} fault={:?} policy={load} bus_off={} cycles={} missed_cycles={} evaluations={} \
         overruns={} e2e_errors={} repeated={} wrong_sequence={} incomplete_observations={} \
         no_new_data={} ignored_frames={} bus_off_events={} activation_failures={activation_failures}",
        c.state(),
        c.fault(),
        c.is_bus_off(),
        d.cycles,
        d.missed_cycles,
        d.evaluations,
        d.overruns,
        d.e2e_errors,
        d.repeated,
        d.wrong_sequence,
        d.incomplete_observations,
        d.no_new_data,
        d.ignored_frames,
        d.bus_off_events
    )
}

fn send(port: &mut impl NodePort, out: &Outbox) -> Result<(), ClientError> {
    for f in out {
        port.queue(f);
    }
    port.flush()
}

/// Runs the controller node until `stop` is set or the bus goes away. `policy` is a policy file;
/// a refused file leaves the controller without policy (it stays pre-operational), as on a device.
pub fn run_controller_node(
    port: &mut impl NodePort,
    policy: Option<&[u8]>,
    cfg: ControllerConfig,
    mode: TimeMode,
    stop: &AtomicBool,
    status: Option<Arc<Mutex<String>>>,
) -> Result<NodeReport, NodeError> {
    // The controller borrows its policy for its whole life; flashing swaps in new files, so every
    // policy lives in a leaked aligned buffer (one per load; see `flash`).
    let bytes: Option<&'static [u8]> =
        policy.map(|p| Box::leak(Box::new(aligned_copy(p))).as_bytes());
    let mut controller = Controller::<'static, NODE_WIDTH>::new(cfg);
    let mut flash = FlashServer::new(cfg.node_id, bytes);
    let mut load_error = None;
    if let Some(bytes) = bytes {
        let loaded = PolicyView::decode(bytes)
            .map_err(|e| e.to_string())
            .and_then(|view| controller.load_policy(&view).map_err(|e| e.to_string()));
        if let Err(e) = loaded {
            eprintln!("hil-sim: controller node refused the policy: {e}");
            load_error = Some(e);
        }
    }
    let load = match (&load_error, policy) {
        (Some(_), _) => "refused",
        (None, Some(_)) => "loaded",
        (None, None) => "none",
    };
    let publish = |c: &Controller<'_, NODE_WIDTH>, f: &FlashServer| {
        if let Some(slot) = status.as_ref()
            && let Ok(mut s) = slot.lock()
        {
            *s = status_line(c, load, f.activation_failures());
        }
    };
    publish(&controller, &flash);
    let result = match mode {
        TimeMode::RealTime => real_time_loop(
            port,
            &mut controller,
            &mut flash,
            cfg.period_us,
            stop,
            &publish,
        ),
        TimeMode::Lockstep => lockstep_loop(port, &mut controller, &mut flash, stop, &publish),
    };
    match result {
        Ok(()) | Err(ClientError::Closed) => {}
        Err(e) => return Err(e.into()),
    }
    Ok(NodeReport {
        diagnostics: *controller.diagnostics(),
        load_error,
    })
}

/// Frames for the flash server go there (activation loads the new file, and only then is it
/// answered: status 5 when the controller refuses it); all others to the controller.
fn dispatch(
    controller: &mut Controller<'static, NODE_WIDTH>,
    flash: &mut FlashServer,
    frame: &CanFrame,
    clock: &impl Clock,
) -> Outbox {
    if !flash.is_request(frame) {
        return controller.on_frame(frame, clock);
    }
    let outcome = flash.handle(frame, controller.state());
    let mut out = Outbox::new();
    let mut response = outcome.response;
    if let Some(activation) = outcome.activate {
        let loaded = PolicyView::decode(activation.bytes())
            .map_err(|e| e.to_string())
            .and_then(|view| controller.load_policy(&view).map_err(|e| e.to_string()));
        if let Err(e) = &loaded {
            eprintln!("hil-sim: flashed policy refused at activation: {e}");
        }
        response = flash.activated(activation, loaded.is_ok());
    }
    if let Some(r) = response {
        let _ = out.push(r);
    }
    out
}

/// Hands an error frame to the controller: bus-off, then (if the same frame says so) the restart;
/// other error classes are not the controller's business. Returns what to send, in order.
fn on_error_frame(controller: &mut Controller<'static, NODE_WIDTH>, class: u32) -> [Outbox; 2] {
    let off = if class & ERR_BUSOFF != 0 {
        controller.on_bus_off()
    } else {
        Outbox::new()
    };
    let back = if class & ERR_RESTARTED != 0 {
        controller.on_bus_recovered()
    } else {
        Outbox::new()
    };
    [off, back]
}

fn real_time_loop(
    port: &mut impl NodePort,
    controller: &mut Controller<'static, NODE_WIDTH>,
    flash: &mut FlashServer,
    period_us: u32,
    stop: &AtomicBool,
    publish: &dyn Fn(&Controller<'static, NODE_WIDTH>, &FlashServer),
) -> Result<(), ClientError> {
    let clock = WallClock::new();
    let period = u64::from(period_us.max(1));
    let out = controller.poll(&clock);
    send(port, &out)?;
    let mut next = clock.now_us() + period;
    while !stop.load(Ordering::Relaxed) {
        let now = clock.now_us();
        if now >= next {
            let out = controller.poll(&clock);
            send(port, &out)?;
            next += period * ((now - next) / period + 1);
            publish(controller, flash);
            continue;
        }
        let wait = Duration::from_micros((next - now).min(20_000));
        match port.receive_timeout(wait)? {
            Some(Received::Frame(frame, _)) => {
                let out = dispatch(controller, flash, &frame, &clock);
                send(port, &out)?;
                if !out.is_empty() {
                    publish(controller, flash);
                }
            }
            Some(Received::Error(class, _)) => {
                for out in on_error_frame(controller, class) {
                    send(port, &out)?;
                }
                publish(controller, flash);
            }
            None => {}
        }
    }
    Ok(())
}

fn lockstep_loop(
    port: &mut impl NodePort,
    controller: &mut Controller<'static, NODE_WIDTH>,
    flash: &mut FlashServer,
    stop: &AtomicBool,
    publish: &dyn Fn(&Controller<'static, NODE_WIDTH>, &FlashServer),
) -> Result<(), ClientError> {
    let clock = MockClock::new(0);
    while !stop.load(Ordering::Relaxed) {
        match port.receive_timeout(Duration::from_millis(50))? {
            Some(Received::Frame(frame, ts)) => {
                clock.set(ts);
                let out = if frame.standard_id() == Some(SYNC_ID) {
                    controller.poll(&clock)
                } else {
                    dispatch(controller, flash, &frame, &clock)
                };
                send(port, &out)?;
            }
            Some(Received::Error(class, ts)) => {
                clock.set(ts);
                for out in on_error_frame(controller, class) {
                    send(port, &out)?;
                }
            }
            None => continue,
        }
        publish(controller, flash);
    }
    Ok(())
}

/// What the controller node needs from its CAN interface: the virtual bus ([`BusClient`]) or, with
/// the `socketcan` feature, a Linux SocketCAN interface ([`crate::port::SocketCanPort`]).
pub trait NodePort {
    /// Queues a frame for transmission.
    fn queue(&mut self, frame: &CanFrame);
    /// Transmits everything queued.
    fn flush(&mut self) -> Result<(), ClientError>;
    /// The next frame or error frame, waiting at most `timeout`.
    fn receive_timeout(&mut self, timeout: Duration) -> Result<Option<Received>, ClientError>;
}

impl NodePort for BusClient {
    fn queue(&mut self, frame: &CanFrame) {
        BusClient::queue(self, frame);
    }

    fn flush(&mut self) -> Result<(), ClientError> {
        BusClient::flush(self)
    }

    fn receive_timeout(&mut self, timeout: Duration) -> Result<Option<Received>, ClientError> {
        BusClient::receive_timeout(self, timeout)
    }
}

/// Connects a controller node to the bus at `addr` and runs it on a new thread.
pub fn spawn_controller_node(
    addr: std::net::SocketAddr,
    policy: Option<Vec<u8>>,
    mode: TimeMode,
    stop: Arc<AtomicBool>,
    status: Option<Arc<Mutex<String>>>,
) -> Result<std::thread::JoinHandle<Result<NodeReport, NodeError>>, NodeError> {
    let mut port = BusClient::connect(addr, "vcan0")?;
    std::thread::Builder::new()
        .name("controller-node".into())
        .spawn(move || {
            run_controller_node(
                &mut port,
                policy.as_deref(),
                ControllerConfig::default(),
                mode,
                &stop,
                status,
            )
        })
        .map_err(|e| NodeError::Bus(ClientError::Io(e)))
}
