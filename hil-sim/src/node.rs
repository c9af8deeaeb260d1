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
//!
//! Policy storage: the runtime's A/B slots (`dex_runtime::slots`) over two fixed regions owned by
//! the node ([`SlotStorage`]); every frame goes through `Controller::on_frame_slots` and every
//! poll through `Controller::poll_slots`, which also serve the CANopen SDO server on
//! `0x600 + node` (program download into 0x1F50, program control 0x1F51: [`crate::flash`]).
//! Nothing is allocated per flash.
//!
//! Frame layout ([`NodeConfig::layout`]): classic, or on a CAN FD bus (`hil-sim bus --fd`) the
//! FD layout of `dex_runtime::can::fd_messages` (`Controller::new_fd`): the observation in two
//! FD frames, the action in one; the node's other frames stay classic.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use dex_policy::PolicyView;
use dex_runtime::aligned::aligned_copy;
use dex_runtime::can::{AnyFrame, FdFrame, FrameLayout, TxFrame};
use dex_runtime::canopen::SdoAbort;
use dex_runtime::canopen::program::PROGRAM_CONTROL;
use dex_runtime::canopen::sdo::abort_code;
use dex_runtime::controller::SDO_RESPONSE_BASE;
use dex_runtime::{
    Clock, Controller, ControllerConfig, Diagnostics, MockClock, Network, Outbox, PolicySlots,
};

use crate::bus::{ERR_BUSOFF, ERR_RESTARTED};
use crate::client::{BusClient, ClientError, Received};
use crate::flash::SlotStorage;
use dex_runtime::can::CanFrame;
use embedded_can::Frame;

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

/// How the node gets time, and (lockstep) how long its control step takes in bus time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NodeTiming {
    /// Clock and polling.
    pub mode: TimeMode,
    /// Lockstep on a timed bus: an answer that evaluated the policy is offered to the wire this
    /// many microseconds after the frame that caused it (the controller's compute on its target,
    /// e.g. [`crate::compute::StepCompute`]); every other answer at that frame's time. Real time
    /// ignores it (the host's own compute is what it is).
    pub step_compute_us: u64,
}

impl From<TimeMode> for NodeTiming {
    /// No compute time in bus time.
    fn from(mode: TimeMode) -> Self {
        NodeTiming {
            mode,
            step_compute_us: 0,
        }
    }
}

/// The controller node's settings: the controller's, and its frame layout.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeConfig {
    /// The controller's settings (node id, period, watchdog, envelope).
    pub controller: ControllerConfig,
    /// Classic frames, or the CAN FD layout (on a bus started with `--fd`).
    pub layout: FrameLayout,
}

impl From<ControllerConfig> for NodeConfig {
    /// The classic layout.
    fn from(controller: ControllerConfig) -> Self {
        NodeConfig {
            controller,
            layout: FrameLayout::Classic,
        }
    }
}

/// The node's controller: its outbox holds classic and FD frames.
type NodeController = Controller<'static, NODE_WIDTH, AnyFrame>;

/// Errors of the controller node.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// The bus connection failed.
    #[error(transparent)]
    Bus(#[from] ClientError),
    /// The slot storage could not be mounted.
    #[error("policy slots: {0}")]
    Slots(dex_runtime::SlotError),
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
pub fn status_line<const W: usize, F: TxFrame>(
    c: &Controller<'_, W, F>,
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

fn send(port: &mut impl NodePort, out: &Outbox<AnyFrame>) -> Result<(), ClientError> {
    for f in out {
        match f {
            AnyFrame::Classic(f) => port.queue(f),
            AnyFrame::Fd(f) => port.queue_fd(f),
        }
    }
    port.flush()
}

/// Flash bookkeeping of the node for its status line.
#[derive(Debug, Default, Clone, Copy)]
struct FlashCounters {
    /// Starts (0x1F51:1 = 1) aborted with 0x0800_0020: the controller refused the file.
    activation_failures: u64,
}

/// Runs the controller node until `stop` is set or the bus goes away. `policy` is a policy file,
/// written into a slot and activated as a flash over the bus would; a refused file leaves the
/// controller without policy (it stays pre-operational), as on a device.
pub fn run_controller_node(
    port: &mut impl NodePort,
    policy: Option<&[u8]>,
    cfg: impl Into<NodeConfig>,
    timing: impl Into<NodeTiming>,
    stop: &AtomicBool,
    status: Option<Arc<Mutex<String>>>,
) -> Result<NodeReport, NodeError> {
    let NodeConfig {
        controller: cfg,
        layout,
    } = cfg.into();
    let mut storage = SlotStorage::new();
    let (a, b) = storage.regions();
    // Erased regions: no active slot yet.
    let mut slots = PolicySlots::mount(a, b).map_err(NodeError::Slots)?;
    let mut controller = match layout {
        FrameLayout::Classic => NodeController::new(cfg),
        FrameLayout::Fd => NodeController::new_fd(cfg),
    };
    let mut load_error = None;
    if let Some(p) = policy
        && let Err(e) = install(&mut controller, &mut slots, p)
    {
        eprintln!("hil-sim: controller node refused the policy: {e}");
        load_error = Some(e);
    }
    let load = match (&load_error, policy) {
        (Some(_), _) => "refused",
        (None, Some(_)) => "loaded",
        (None, None) => "none",
    };
    let publish = |c: &NodeController, f: &FlashCounters| {
        if let Some(slot) = status.as_ref()
            && let Ok(mut s) = slot.lock()
        {
            *s = status_line(c, load, f.activation_failures);
        }
    };
    let mut counters = FlashCounters::default();
    publish(&controller, &counters);
    let mut node = Node {
        node_id: cfg.node_id,
        controller: &mut controller,
        slots: &mut slots,
        counters: &mut counters,
    };
    let timing = timing.into();
    let result = match timing.mode {
        TimeMode::RealTime => real_time_loop(port, &mut node, cfg.period_us, stop, &publish),
        TimeMode::Lockstep => {
            lockstep_loop(port, &mut node, timing.step_compute_us, stop, &publish)
        }
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

/// Writes `policy` into the inactive slot, verifies and activates it (the start-up policy): the
/// controller's checks first, for a readable refusal.
fn install(
    controller: &mut NodeController,
    slots: &mut PolicySlots<'_>,
    policy: &[u8],
) -> Result<(), String> {
    let copy = aligned_copy(policy);
    let view = PolicyView::decode(copy.as_bytes()).map_err(|e| e.to_string())?;
    controller.check_policy(&view).map_err(|e| e.to_string())?;
    Network::<NODE_WIDTH>::new(&view, copy.as_bytes()).map_err(|e| e.to_string())?;
    slots.begin(policy.len()).map_err(|e| e.to_string())?;
    slots
        .write_at(0, policy)
        .map_err(|e| format!("slot write: {e}"))?;
    slots
        .finish(|view, _| controller.check_policy(view))
        .map_err(|e| format!("slot verification: {e}"))?;
    controller.activate_slot(slots).map_err(|e| e.to_string())
}

/// The controller with its slots.
struct Node<'a, 'r> {
    node_id: u8,
    controller: &'a mut NodeController,
    slots: &'a mut PolicySlots<'r>,
    counters: &'a mut FlashCounters,
}

/// Every frame goes to the controller with the slots (SDO requests included); refused
/// activations are counted.
fn dispatch(node: &mut Node<'_, '_>, frame: &impl Frame, clock: &impl Clock) -> Outbox<AnyFrame> {
    let out = node.controller.on_frame_slots(frame, clock, node.slots);
    let response = SDO_RESPONSE_BASE + u16::from(node.node_id);
    let control = PROGRAM_CONTROL.to_le_bytes();
    for f in &out {
        if f.standard_id() == Some(response)
            && f.data().get(1..3) == Some(&control[..])
            && abort_code(f.data()) == Some(SdoAbort::CannotStore.code())
        {
            node.counters.activation_failures = node.counters.activation_failures.saturating_add(1);
            eprintln!("hil-sim: flashed policy refused at activation");
        }
    }
    out
}

/// Hands an error frame to the controller: bus-off, then (if the same frame says so) the restart;
/// other error classes are not the controller's business. Returns what to send, in order.
fn on_error_frame(controller: &mut NodeController, class: u32) -> [Outbox<AnyFrame>; 2] {
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
    node: &mut Node<'_, '_>,
    period_us: u32,
    stop: &AtomicBool,
    publish: &dyn Fn(&NodeController, &FlashCounters),
) -> Result<(), ClientError> {
    let clock = WallClock::new();
    let period = u64::from(period_us.max(1));
    let out = node.controller.poll_slots(&clock, node.slots);
    send(port, &out)?;
    let mut next = clock.now_us() + period;
    while !stop.load(Ordering::Relaxed) {
        let now = clock.now_us();
        if now >= next {
            let out = node.controller.poll_slots(&clock, node.slots);
            send(port, &out)?;
            next += period * ((now - next) / period + 1);
            publish(node.controller, node.counters);
            continue;
        }
        let wait = Duration::from_micros((next - now).min(20_000));
        match port.receive_timeout(wait)? {
            Some(Received::Frame(frame, _)) => {
                let out = dispatch(node, &frame, &clock);
                send(port, &out)?;
                if !out.is_empty() {
                    publish(node.controller, node.counters);
                }
            }
            Some(Received::Fd(frame, _)) => {
                let out = dispatch(node, &frame, &clock);
                send(port, &out)?;
                if !out.is_empty() {
                    publish(node.controller, node.counters);
                }
            }
            Some(Received::Error(class, _)) => {
                for out in on_error_frame(node.controller, class) {
                    send(port, &out)?;
                }
                publish(node.controller, node.counters);
            }
            None => {}
        }
    }
    Ok(())
}

fn lockstep_loop(
    port: &mut impl NodePort,
    node: &mut Node<'_, '_>,
    step_compute_us: u64,
    stop: &AtomicBool,
    publish: &dyn Fn(&NodeController, &FlashCounters),
) -> Result<(), ClientError> {
    let clock = MockClock::new(0);
    while !stop.load(Ordering::Relaxed) {
        let received = match port.receive_timeout(Duration::from_millis(50))? {
            Some(Received::Frame(frame, ts)) => Some((Some(AnyFrame::Classic(frame)), ts, 0)),
            Some(Received::Fd(frame, ts)) => Some((Some(AnyFrame::Fd(frame)), ts, 0)),
            Some(Received::Error(class, ts)) => Some((None, ts, class)),
            None => None,
        };
        match received {
            Some((Some(frame), ts, _)) => {
                clock.set(ts);
                let evaluations = node.controller.diagnostics().evaluations;
                let out = if frame.standard_id() == Some(SYNC_ID) {
                    node.controller.poll_slots(&clock, node.slots)
                } else {
                    dispatch(node, &frame, &clock)
                };
                if !out.is_empty() {
                    // On a timed bus the answer leaves after the compute it took.
                    let computed = node.controller.diagnostics().evaluations != evaluations;
                    port.offer_at(ts + if computed { step_compute_us } else { 0 });
                }
                send(port, &out)?;
            }
            Some((None, ts, class)) => {
                clock.set(ts);
                port.offer_at(ts);
                for out in on_error_frame(node.controller, class) {
                    send(port, &out)?;
                }
            }
            None => continue,
        }
        publish(node.controller, node.counters);
    }
    Ok(())
}

/// What the controller node needs from its CAN interface: the virtual bus ([`BusClient`]) or, with
/// the `socketcan` feature, a Linux SocketCAN interface ([`crate::port::SocketCanPort`]).
pub trait NodePort {
    /// Queues a frame for transmission.
    fn queue(&mut self, frame: &CanFrame);
    /// Queues an FD frame for transmission (the FD layout's action). An interface without CAN FD
    /// cannot send it: by default it is dropped, as a classic controller's driver refuses it.
    fn queue_fd(&mut self, frame: &FdFrame) {
        let _ = frame;
    }
    /// Transmits everything queued.
    fn flush(&mut self) -> Result<(), ClientError>;
    /// The next frame or error frame, waiting at most `timeout`.
    fn receive_timeout(&mut self, timeout: Duration) -> Result<Option<Received>, ClientError>;
    /// Lockstep: the frames queued next are offered to the wire at bus time `us` (a timed
    /// virtual bus's `< txtime US >`); a real interface sends when it sends, so by default nothing.
    fn offer_at(&mut self, us: u64) {
        let _ = us;
    }
}

impl NodePort for BusClient {
    fn queue(&mut self, frame: &CanFrame) {
        BusClient::queue(self, frame);
    }

    fn queue_fd(&mut self, frame: &FdFrame) {
        BusClient::queue_fd(self, frame);
    }

    fn flush(&mut self) -> Result<(), ClientError> {
        BusClient::flush(self)
    }

    fn receive_timeout(&mut self, timeout: Duration) -> Result<Option<Received>, ClientError> {
        BusClient::receive_timeout(self, timeout)
    }

    fn offer_at(&mut self, us: u64) {
        self.queue_line(&format!("< txtime {us} >"));
    }
}

/// Connects a controller node (settings `cfg`) to the bus at `addr` and runs it on a new thread.
pub fn spawn_controller_node(
    addr: std::net::SocketAddr,
    policy: Option<Vec<u8>>,
    cfg: impl Into<NodeConfig>,
    timing: impl Into<NodeTiming>,
    stop: Arc<AtomicBool>,
    status: Option<Arc<Mutex<String>>>,
) -> Result<std::thread::JoinHandle<Result<NodeReport, NodeError>>, NodeError> {
    let mut port = BusClient::connect(addr, "vcan0")?;
    let timing = timing.into();
    let cfg = cfg.into();
    std::thread::Builder::new()
        .name("controller-node".into())
        .spawn(move || {
            run_controller_node(&mut port, policy.as_deref(), cfg, timing, &stop, status)
        })
        .map_err(|e| NodeError::Bus(ClientError::Io(e)))
}
