//! The 20 Hz controller: a CANopen-style state machine around the policy evaluator.
//!
//! Frames come in through [`Controller::on_frame`], time through [`Controller::poll`] and a
//! [`Clock`]. Both return the frames to send in an [`Outbox`] (fixed capacity, no heap). An
//! observation is evaluated as soon as its last frame arrives (so latency is one forward pass);
//! `poll` runs the cycle bookkeeping once per period: watchdog, heartbeat, and the safe action in
//! every state but operational. The CAN driver reports bus-off and its end through
//! [`Controller::on_bus_off`] and [`Controller::on_bus_recovered`].
//!
//! The policy is either a file borrowed for `'p` ([`Controller::load_policy`]) or the active slot
//! of [`PolicySlots`] ([`Controller::attach_slots`]), which the controller then reads on every
//! evaluation: such a controller takes its frames through [`Controller::on_frame_slots`] and its
//! time through [`Controller::poll_slots`], which also serve the CANopen SDO server on
//! `0x600 + node` / `0x580 + node` ([`crate::canopen`]): the communication objects and program
//! download (CiA 302-3: transfer into the inactive slot, activation, roll-back).

use dex_policy::{FORMAT_VERSION, PolicyView};
use heapless::Vec;

use core::marker::PhantomData;

use crate::can::e2e::E2eSender;
use crate::can::fd_frame::{AnyFrame, FdFrame, TxFrame};
use crate::can::fd_messages::encode_action_fd;
use crate::can::frame::CanFrame;
use crate::can::layout::FrameLayout;
use crate::can::messages::{
    ACTION_FRAMES, ACTION_QUANTITY, NMT_ID, NmtCommand, NodeIdError, OBS_FRAMES, TPDOS,
    check_node_id, emcy_frame, encode_action, heartbeat_frame, policy_info_frame, status_frame,
    to_raw, tpdo_cob_id,
};
use crate::canopen::device::{DeviceObjects, DeviceState, Identity};
use crate::canopen::program::{ProgramObjects, ProgramState};
use crate::canopen::{SdoFrame, SdoServer};
use crate::clock::Clock;
use crate::envelope::{Envelope, EnvelopeConfig, EnvelopeStats};
use crate::error::{EvalError, LoadError};
use crate::features::{INPUT_MAX, policy_input};
use crate::interface::{ACT_DIM, CONTROL_PERIOD_US, OBS_DIM};
use crate::interface::{Quantity, quantity_of};
use crate::mlp::{Mlp, Network};
use crate::observation::{FrameOutcome, ObservationAssembler, ObservationFault, check_observation};
use crate::slots::{PolicySlots, SlotError};

/// SDO request identifier base (`+ node`): client to this controller (CiA 301 default SDO).
pub const SDO_REQUEST_BASE: u16 = 0x600;
/// SDO response identifier base (`+ node`): this controller to the client.
pub const SDO_RESPONSE_BASE: u16 = 0x580;

/// Frames to send after one call; 10 slots, and no call produces more than 8 (a poll's 7: a
/// state change's heartbeat and status, an emergency, three safe-action frames and the policy
/// information; and an SDO timeout's abort). `F` is the controller's frame type: classic frames
/// ([`CanFrame`], the default), or [`AnyFrame`] for a controller in the FD layout
/// ([`Controller::new_fd`]), whose action goes out as one FD frame.
pub type Outbox<F = CanFrame> = Vec<F, 10>;

/// Controller states, in CANopen's spirit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// Just powered or reset; becomes pre-operational at the first poll.
    Boot,
    /// Configured, not controlling: policies may be loaded; sends the safe action.
    PreOperational,
    /// Evaluating the policy on every complete observation.
    Operational,
    /// Stopped by command or by a fault: sends the safe action; NMT start resumes.
    SafeStop,
    /// Unrecoverable without NMT reset: sends the safe action.
    Fault,
}

impl State {
    /// Code in the status TPDO and object 0x2002:1.
    pub const fn code(self) -> u8 {
        match self {
            State::Boot => 0,
            State::PreOperational => 1,
            State::Operational => 2,
            State::SafeStop => 3,
            State::Fault => 4,
        }
    }

    /// CANopen NMT state byte (the heartbeat's one byte).
    pub const fn canopen(self) -> u8 {
        match self {
            State::Boot => 0x00,
            State::PreOperational => 0x7F,
            State::Operational => 0x05,
            State::SafeStop | State::Fault => 0x04,
        }
    }
}

/// Why the controller left operational (reported in the status TPDO, object 0x2002:2 and
/// emergency frames).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultCode {
    /// No fault.
    None,
    /// No complete observation for longer than the watchdog allows.
    ObservationTimeout,
    /// An observation value was not finite.
    ObservationNonFinite,
    /// An observation value was out of its plausible range.
    ObservationOutOfRange,
    /// The network produced a non-finite output.
    ActionNonFinite,
    /// Start was commanded with no policy loaded.
    NoPolicy,
    /// The CAN controller went bus-off (reported with emergency 0x8140 once the bus is back).
    BusOff,
    /// A newly activated policy's first evaluation failed: the previous slot is active again.
    PolicyRolledBack,
    /// The safety envelope limited the policy's action for more than
    /// [`EnvelopeConfig::sustained_cycles`] consecutive cycles. A warning in emergency frames
    /// only (0xFF10 when the run starts, 0x0000 with this fault code when it ends): never
    /// latched, the controller stays operational and keeps limiting.
    EnvelopeSustained,
    /// NMT start refused: the envelope's configuration is invalid ([`EnvelopeConfig::validate`]).
    EnvelopeConfig,
}

impl FaultCode {
    /// Code in the status TPDO, object 0x2002:2 and emergency frames (byte 3).
    pub const fn code(self) -> u8 {
        match self {
            FaultCode::None => 0,
            FaultCode::ObservationTimeout => 1,
            FaultCode::ObservationNonFinite => 2,
            FaultCode::ObservationOutOfRange => 3,
            FaultCode::ActionNonFinite => 4,
            FaultCode::NoPolicy => 5,
            FaultCode::BusOff => 6,
            FaultCode::PolicyRolledBack => 7,
            FaultCode::EnvelopeSustained => 16,
            FaultCode::EnvelopeConfig => 17,
        }
    }

    /// CANopen-style emergency error code (0x8250 is CANopen's RPDO timeout, 0x8140 its
    /// "recovered from bus-off"; 0xFFxx are manufacturer-specific; 0x0000 is "error reset").
    pub const fn emcy_code(self) -> u16 {
        match self {
            FaultCode::None => 0x0000,
            FaultCode::ObservationTimeout => 0x8250,
            FaultCode::ObservationNonFinite => 0xFF02,
            FaultCode::ObservationOutOfRange => 0xFF03,
            FaultCode::ActionNonFinite => 0xFF04,
            FaultCode::NoPolicy => 0xFF05,
            FaultCode::BusOff => 0x8140,
            FaultCode::PolicyRolledBack => 0xFF07,
            FaultCode::EnvelopeSustained => 0xFF10,
            FaultCode::EnvelopeConfig => 0xFF11,
        }
    }
}

/// Controller settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControllerConfig {
    /// CANopen node id (1..=31, [`ControllerConfig::check`]): every node-specific identifier
    /// derives from it ([`crate::can::messages`]).
    pub node_id: u8,
    /// Control period in microseconds.
    pub period_us: u32,
    /// Safe-stop when the newest complete observation is older than this many periods.
    pub watchdog_cycles: u32,
    /// The producer heartbeat time (0x1017) after boot, in periods (0: no heartbeat but the
    /// boot-up message); an SDO write to 0x1017 changes it, in ms. The heartbeat also goes out
    /// on every state change while it is on.
    pub heartbeat_cycles: u32,
    /// Largest accepted alive-counter jump on observation frames (1: no frame may be lost).
    pub e2e_max_delta: u8,
    /// The safety envelope applied to every policy action ([`crate::envelope`]); on by default.
    pub envelope: EnvelopeConfig,
}

impl Default for ControllerConfig {
    fn default() -> Self {
        ControllerConfig {
            node_id: 0x10,
            period_us: CONTROL_PERIOD_US,
            watchdog_cycles: 3,
            heartbeat_cycles: 10,
            e2e_max_delta: 1,
            envelope: EnvelopeConfig::jaco(),
        }
    }
}

impl ControllerConfig {
    /// Whether the configuration can run on a shared bus: the node id must lie in 1..=31
    /// ([`check_node_id`]). Check it when the configuration is made; a controller built from a
    /// configuration that fails it sends frames on identifiers of other nodes.
    pub const fn check(&self) -> Result<(), NodeIdError> {
        match check_node_id(self.node_id) {
            Ok(_) => Ok(()),
            Err(e) => Err(e),
        }
    }
}

/// Counters for diagnosis; they saturate instead of wrapping.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Diagnostics {
    /// Control cycles run.
    pub cycles: u64,
    /// Cycles skipped because `poll` came late.
    pub missed_cycles: u64,
    /// Policy evaluations.
    pub evaluations: u64,
    /// Cycles with more than one evaluation.
    pub overruns: u64,
    /// Frames dropped for a wrong CRC, a bad counter or a wrong length.
    pub e2e_errors: u64,
    /// Frames dropped as repetitions.
    pub repeated: u64,
    /// Frames dropped for a counter jump.
    pub wrong_sequence: u64,
    /// Observations abandoned incomplete.
    pub incomplete_observations: u64,
    /// Cycles in which no observation frame arrived.
    pub no_new_data: u64,
    /// Frames with identifiers this controller does not use.
    pub ignored_frames: u64,
    /// Times the CAN controller went bus-off ([`Controller::on_bus_off`]).
    pub bus_off_events: u64,
}

/// Identity of the loaded policy, reported in the policy-info TPDO.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PolicyInfo {
    /// Layout hash from the file header.
    pub layout_hash: u32,
    /// Format version of the file.
    pub format_version: u16,
    /// Task code (order of [`dex_policy::Task`]).
    pub task: u8,
}

/// The controller's SDO side: the server and what its object dictionary keeps between requests.
#[derive(Debug, Clone)]
struct SdoSide {
    server: SdoServer,
    device: DeviceState,
    program: ProgramState,
}

impl SdoSide {
    fn new(cfg: &ControllerConfig) -> Self {
        let heartbeat_ms = u64::from(cfg.heartbeat_cycles) * u64::from(cfg.period_us) / 1000;
        SdoSide {
            server: SdoServer::default(),
            device: DeviceState::new(
                Identity::default(),
                u16::try_from(heartbeat_ms).unwrap_or(u16::MAX),
            ),
            program: ProgramState::default(),
        }
    }
}

/// Where the controller's policy lives.
#[derive(Debug, Clone)]
enum Policy<'p, const WIDTH: usize> {
    /// A file borrowed for `'p` ([`Controller::load_policy`]).
    File(Mlp<'p, WIDTH>),
    /// The active slot of the [`PolicySlots`] passed to [`Controller::on_frame_slots`].
    Slot(Network<WIDTH>),
}

/// The controller; `WIDTH` is the evaluator's compile-time capacity (widest layer), `F` the
/// frames it sends ([`Outbox`]): classic frames by default, [`AnyFrame`] for the FD layout.
#[derive(Debug, Clone)]
pub struct Controller<'p, const WIDTH: usize, F: TxFrame = CanFrame> {
    cfg: ControllerConfig,
    frames: PhantomData<fn() -> F>,
    state: State,
    fault: FaultCode,
    policy: Option<Policy<'p, WIDTH>>,
    info: Option<PolicyInfo>,
    assembler: ObservationAssembler,
    obs: [f32; OBS_DIM],
    last_obs_us: u64,
    frames_this_cycle: bool,
    evaluations_this_cycle: u32,
    action: [f32; ACT_DIM],
    action_tx: [E2eSender; ACTION_FRAMES],
    emcy_tx: E2eSender,
    info_tx: E2eSender,
    status_tx: E2eSender,
    own_sample: u8,
    /// A status (heartbeat and status TPDO) went out since the flag was last cleared.
    status_sent: bool,
    /// Bytes 0-1 of the last frame sent on each TPDO (object 0x2201).
    tpdo_headers: [u16; TPDOS],
    next_tick_us: Option<u64>,
    cycles_since_heartbeat: u32,
    announce: bool,
    /// Program control asked to stop (0x1F51 = 0): leave operational at the next cycle.
    stop_requested: bool,
    bus_off: bool,
    diag: Diagnostics,
    envelope: Envelope,
    sdo: SdoSide,
}

impl<'p, const WIDTH: usize> Controller<'p, WIDTH, AnyFrame> {
    /// A controller in [`State::Boot`] with no policy, in the CAN FD layout
    /// ([`crate::can::fd_messages`]): it takes the observation in two FD frames and sends the
    /// action in one; every other frame it takes and sends is a classic frame, as in
    /// [`Controller::new`]. The same states, watchdog, E2E checks and refusals as classic.
    pub fn new_fd(cfg: ControllerConfig) -> Self {
        let mut c = Self::new(cfg);
        // The assembler's layout is the controller's ([`Controller::layout`]).
        c.assembler =
            ObservationAssembler::with_layout(cfg.node_id, cfg.e2e_max_delta, FrameLayout::Fd);
        c
    }
}

impl<'p, const WIDTH: usize, F: TxFrame> Controller<'p, WIDTH, F> {
    /// A controller in [`State::Boot`] with no policy, in the classic layout.
    pub fn new(cfg: ControllerConfig) -> Self {
        Controller {
            cfg,
            frames: PhantomData,
            state: State::Boot,
            fault: FaultCode::None,
            policy: None,
            info: None,
            assembler: ObservationAssembler::new(cfg.node_id, cfg.e2e_max_delta),
            obs: [0.0; OBS_DIM],
            last_obs_us: 0,
            frames_this_cycle: false,
            evaluations_this_cycle: 0,
            action: [0.0; ACT_DIM],
            action_tx: [E2eSender::default(); ACTION_FRAMES],
            emcy_tx: E2eSender::default(),
            info_tx: E2eSender::default(),
            status_tx: E2eSender::default(),
            own_sample: 0,
            status_sent: false,
            tpdo_headers: [0; TPDOS],
            next_tick_us: None,
            cycles_since_heartbeat: 0,
            announce: false,
            stop_requested: false,
            bus_off: false,
            diag: Diagnostics::default(),
            envelope: Envelope::new(cfg.envelope, cfg.period_us),
            sdo: SdoSide::new(&cfg),
        }
    }

    /// What program download last reported (0x1F57): the result of the last download or
    /// program control, whether one runs.
    pub fn program_state(&self) -> &ProgramState {
        &self.sdo.program
    }

    /// The communication objects' state: identity, heartbeat time, the emergency history (0x1003).
    pub fn device_state(&self) -> &DeviceState {
        &self.sdo.device
    }

    /// The frame layout of the observation and the action: the classic layout for a controller
    /// whose frame type holds no FD frames ([`TxFrame::HOLDS_FD`]; [`CanFrame`]), a constant
    /// there, so that its frame path has neither layout branches nor FD code; else the layout it
    /// was made with ([`Controller::new_fd`]: FD), which its observation assembler holds.
    #[inline(always)]
    pub fn layout(&self) -> FrameLayout {
        if F::HOLDS_FD {
            self.assembler.layout()
        } else {
            FrameLayout::Classic
        }
    }

    /// Current state.
    pub fn state(&self) -> State {
        self.state
    }

    /// Latched fault code.
    pub fn fault(&self) -> FaultCode {
        self.fault
    }

    /// Whether the CAN controller is bus-off (between [`Controller::on_bus_off`] and
    /// [`Controller::on_bus_recovered`]).
    pub fn is_bus_off(&self) -> bool {
        self.bus_off
    }

    /// Diagnostic counters.
    pub fn diagnostics(&self) -> &Diagnostics {
        &self.diag
    }

    /// What the safety envelope did so far.
    pub fn envelope_stats(&self) -> &EnvelopeStats {
        self.envelope.stats()
    }

    /// The safety envelope's status bits (`envelope::status`, object 0x2001, status TPDO byte 4).
    pub fn envelope_status(&self) -> u8 {
        self.envelope.status()
    }

    /// The last action sent (zero velocity outside operational).
    pub fn last_action(&self) -> &[f32; ACT_DIM] {
        &self.action
    }

    /// The newest complete observation received.
    pub fn last_observation(&self) -> &[f32; OBS_DIM] {
        &self.obs
    }

    /// Identity of the loaded policy.
    pub fn policy_info(&self) -> Option<PolicyInfo> {
        self.info
    }

    /// Loads or swaps the policy. Refused while operational; refused (leaving the current policy
    /// active) when the file does not fit this controller's capacity, layout or period.
    pub fn load_policy(&mut self, view: &PolicyView<'p>) -> Result<(), LoadError> {
        if self.state == State::Operational {
            return Err(LoadError::Operational);
        }
        self.check_policy(view)?;
        self.policy = Some(Policy::File(Mlp::new(view)?));
        self.info = Some(policy_info_of(view));
        self.announce = true;
        Ok(())
    }

    /// This controller's checks of a policy file: layout against [`crate::interface`], control
    /// period; capacity is checked when the evaluator is built.
    pub fn check_policy(&self, view: &PolicyView<'_>) -> Result<(), LoadError> {
        crate::features::check_layout(view)?;
        let period = view.body().control_period_us;
        if period != self.cfg.period_us {
            return Err(LoadError::ControlPeriod {
                policy_us: period,
                controller_us: self.cfg.period_us,
            });
        }
        Ok(())
    }

    /// The slot evaluator of `file` (decoded as `view`), after this controller's checks.
    fn bind_slot(&self, view: &PolicyView<'_>, file: &[u8]) -> Result<Network<WIDTH>, LoadError> {
        self.check_policy(view)?;
        Ok(Network::new(view, file)?)
    }

    /// Takes the active slot of `slots` as the policy (at start-up, after [`PolicySlots::mount`]).
    /// Refused while operational; refused, leaving the current policy, when the slot is empty or
    /// the controller refuses its file. Frames then go through [`Controller::on_frame_slots`].
    pub fn attach_slots(&mut self, slots: &PolicySlots<'_>) -> Result<(), SlotError> {
        if self.state == State::Operational {
            return Err(SlotError::Operational);
        }
        let (net, info) = slots
            .bind_active(|view, file| Ok((self.bind_slot(view, file)?, policy_info_of(view))))?;
        self.set_slot_policy(net, info);
        Ok(())
    }

    /// Activates the verified file in the inactive slot of `slots`: refused while operational,
    /// and (leaving the active policy) when the controller refuses the file. Takes effect at
    /// once, between two control cycles; the policy-info frame goes out at the next cycle. The
    /// policy is on trial until its first evaluation: if that fails, the controller rolls it back.
    pub fn activate_slot(&mut self, slots: &mut PolicySlots<'_>) -> Result<(), SlotError> {
        if self.state == State::Operational {
            return Err(SlotError::Operational);
        }
        let (net, info) =
            slots.activate(|view, file| Ok((self.bind_slot(view, file)?, policy_info_of(view))))?;
        self.set_slot_policy(net, info);
        Ok(())
    }

    /// Makes the previous policy of `slots` active again (explicit roll-back, program control
    /// 0x1F51 = 0x80); refused while operational or when no previous policy is kept.
    pub fn roll_back_slot(&mut self, slots: &mut PolicySlots<'_>) -> Result<(), SlotError> {
        if self.state == State::Operational {
            return Err(SlotError::Operational);
        }
        let (net, info) = slots
            .roll_back(|view, file| Ok((self.bind_slot(view, file)?, policy_info_of(view))))?;
        self.set_slot_policy(net, info);
        Ok(())
    }

    #[inline(always)]
    fn set_slot_policy(&mut self, net: Network<WIDTH>, info: PolicyInfo) {
        self.policy = Some(Policy::Slot(net));
        self.info = Some(info);
        self.announce = true;
    }

    /// [`Controller::on_frame`] for a controller whose policy lives in `slots`: SDO requests
    /// (`0x600 + node`) go to the SDO server over the controller's object dictionary
    /// ([`crate::canopen::device`], program download onto `slots` included) and are answered on
    /// `0x580 + node` (every refusal an abort with its CiA 301 code); every other frame is
    /// handled as by `on_frame`, evaluating the active slot. A fault in the first evaluation of a
    /// newly activated policy rolls it back (previous slot active again), goes to safe-stop and
    /// sends emergency 0xFF07 (fault `PolicyRolledBack`); NMT start then runs the previous policy.
    /// NMT reset (node or communication) drops a running SDO transfer without an answer.
    pub fn on_frame_slots(
        &mut self,
        frame: &impl embedded_can::Frame,
        clock: &impl Clock,
        slots: &mut PolicySlots<'_>,
    ) -> Outbox<F> {
        let request = SDO_REQUEST_BASE + u16::from(self.cfg.node_id);
        match frame.id() {
            embedded_can::Id::Standard(s) if !frame.is_remote_frame() && s.as_raw() == request => {
                let now_ms = sdo_ms(clock);
                let mut out = Outbox::new();
                let response = self.with_sdo(slots, |server, od| {
                    server.on_request(frame.data(), now_ms, od)
                });
                self.push_sdo(response, &mut out);
                out
            }
            embedded_can::Id::Standard(s) if !frame.is_remote_frame() && s.as_raw() == NMT_ID => {
                let reset = matches!(
                    (frame.data().first().copied().and_then(NmtCommand::from_code), frame.data().get(1)),
                    (Some(NmtCommand::ResetNode | NmtCommand::ResetCommunication), Some(&n))
                        if n == 0 || n == self.cfg.node_id
                );
                if reset && self.sdo.server.busy() {
                    let _ = self.with_sdo(slots, |server, od| {
                        server.abort(od, crate::canopen::SdoAbort::General)
                    });
                }
                self.frame_in(frame, clock, Some(slots))
            }
            _ => self.frame_in(frame, clock, Some(slots)),
        }
    }

    /// [`Controller::poll`] for a controller whose policy lives in `slots`: also aborts an SDO
    /// transfer that has seen no request for the server's timeout (abort 0x0504_0000 on
    /// `0x580 + node`; a cut program download leaves the active policy as it was).
    pub fn poll_slots(&mut self, clock: &impl Clock, slots: &mut PolicySlots<'_>) -> Outbox<F> {
        let mut out = self.poll(clock);
        if self.sdo.server.busy() {
            let now_ms = sdo_ms(clock);
            let response = self.with_sdo(slots, |server, od| server.poll(now_ms, od));
            self.push_sdo(response, &mut out);
        }
        out
    }

    /// Runs `f` with the SDO server and the controller's dictionary over `slots`.
    fn with_sdo<T>(
        &mut self,
        slots: &mut PolicySlots<'_>,
        f: impl FnOnce(&mut SdoServer, &mut DeviceObjects<'_, '_, Self>) -> T,
    ) -> T {
        // The dictionary borrows the controller as its host: the SDO side is moved out meanwhile.
        let mut side = core::mem::replace(&mut self.sdo, SdoSide::new(&self.cfg));
        let result = {
            let program = ProgramObjects {
                slots,
                host: self,
                state: &mut side.program,
            };
            let mut od = DeviceObjects::new(&mut side.device, program);
            f(&mut side.server, &mut od)
        };
        self.sdo = side;
        result
    }

    fn push_sdo(&self, response: Option<SdoFrame>, out: &mut Outbox<F>) {
        let id = SDO_RESPONSE_BASE + u16::from(self.cfg.node_id);
        if let Some(f) = response.and_then(|r| CanFrame::standard(id, &r)) {
            let _ = out.push(F::classic(f));
        }
    }

    /// Handles one received frame; returns the frames to send (actions when this frame completed an
    /// observation while operational, an emergency when it caused a fault).
    pub fn on_frame(&mut self, frame: &impl embedded_can::Frame, clock: &impl Clock) -> Outbox<F> {
        self.frame_in(frame, clock, None)
    }

    fn frame_in(
        &mut self,
        frame: &impl embedded_can::Frame,
        clock: &impl Clock,
        slots: Option<&mut PolicySlots<'_>>,
    ) -> Outbox<F> {
        let mut out = Outbox::new();
        let id = match frame.id() {
            embedded_can::Id::Standard(s) if !frame.is_remote_frame() => s.as_raw(),
            _ => {
                self.diag.ignored_frames = self.diag.ignored_frames.saturating_add(1);
                return out;
            }
        };
        if id == NMT_ID {
            self.on_nmt(frame.data(), clock, &mut out);
        } else if let Some(k) = self.assembler.frame_index_as(self.layout(), id) {
            self.on_observation_frame(k, frame.data(), clock, &mut out, slots);
        } else {
            self.diag.ignored_frames = self.diag.ignored_frames.saturating_add(1);
        }
        out
    }

    /// The CAN controller went bus-off (its transmit error counter passed 255): nothing it sends
    /// reaches the bus until [`Controller::on_bus_recovered`].
    ///
    /// The reaction is CANopen's default for a communication error (CiA 301 object 0x1029,
    /// value 0): operational goes to pre-operational; safe-stop, pre-operational and fault keep
    /// their state. The fault `BusOff` is latched unless another fault already is, the partial
    /// observation and the end-to-end counters are dropped (the plant's frames are lost too), and
    /// the safe action goes out at once and then every cycle, as in every state but operational,
    /// so the first command on the bus when it comes back is zero velocity. NMT start is refused
    /// while the bus is off. Returns the frames to hand to the driver (it may drop them).
    /// A second call before recovery does nothing.
    pub fn on_bus_off(&mut self) -> Outbox<F> {
        let mut out = Outbox::new();
        if self.bus_off {
            return out;
        }
        self.bus_off = true;
        self.diag.bus_off_events = self.diag.bus_off_events.saturating_add(1);
        self.assembler.reset();
        if self.fault == FaultCode::None {
            self.fault = FaultCode::BusOff;
        }
        if self.state == State::Operational {
            self.enter(State::PreOperational, &mut out);
        }
        self.send_safe_action(&mut out);
        out
    }

    /// The CAN controller is back on the bus after a bus-off. Sends emergency 0x8140 ("recovered
    /// from bus-off", fault code `BusOff`, the current state) once, then a heartbeat with the
    /// state (pre-operational after a bus-off in operational: the master re-enables the node with
    /// NMT start, which reports the error reset with emergency 0x0000) and the safe action.
    /// Without a preceding [`Controller::on_bus_off`] it does nothing.
    pub fn on_bus_recovered(&mut self) -> Outbox<F> {
        let mut out = Outbox::new();
        if !self.bus_off {
            return out;
        }
        self.bus_off = false;
        self.push_emcy_code(FaultCode::BusOff, &mut out);
        self.push_status(&mut out);
        self.send_safe_action(&mut out);
        out
    }

    /// Runs the periodic part when a period boundary has passed: watchdog, heartbeat and the safe
    /// action outside operational. Call it at least once per period; calling it more often is fine.
    pub fn poll(&mut self, clock: &impl Clock) -> Outbox<F> {
        let mut out = Outbox::new();
        let now = clock.now_us();
        let period = u64::from(self.cfg.period_us.max(1));
        let Some(next) = self.next_tick_us else {
            self.next_tick_us = Some(now.saturating_add(period));
            self.boot_up(&mut out);
            return out;
        };
        if now < next {
            return out;
        }
        let late = (now - next) / period;
        self.diag.missed_cycles = self.diag.missed_cycles.saturating_add(late);
        self.next_tick_us = Some(next.saturating_add((late + 1).saturating_mul(period)));
        self.diag.cycles = self.diag.cycles.saturating_add(1);
        if !self.frames_this_cycle {
            self.diag.no_new_data = self.diag.no_new_data.saturating_add(1);
        }
        if self.evaluations_this_cycle > 1 {
            self.diag.overruns = self.diag.overruns.saturating_add(1);
        }
        self.frames_this_cycle = false;
        self.evaluations_this_cycle = 0;

        self.status_sent = false;
        if core::mem::take(&mut self.stop_requested) && self.state == State::Operational {
            self.enter(State::PreOperational, &mut out);
        }
        match self.state {
            State::Boot => self.boot_up(&mut out),
            State::Operational => {
                let limit = u64::from(self.cfg.watchdog_cycles).saturating_mul(period);
                if now.saturating_sub(self.last_obs_us) > limit {
                    self.safe_stop(FaultCode::ObservationTimeout, &mut out);
                }
            }
            State::PreOperational | State::SafeStop | State::Fault => {
                self.send_safe_action(&mut out)
            }
        }
        self.cycles_since_heartbeat = self.cycles_since_heartbeat.saturating_add(1);
        // The producer heartbeat time (0x1017, ms; 0: off) as the SDO server last set it. A
        // cycle whose state change already sent a heartbeat sends no second one.
        let heartbeat_us = u64::from(self.sdo.device.heartbeat_ms) * 1000;
        let since_us = u64::from(self.cycles_since_heartbeat) * period;
        if heartbeat_us != 0 && !self.status_sent && since_us >= heartbeat_us {
            self.push_status(&mut out);
        }
        if self.announce {
            self.announce = false;
            self.push_policy_info(&mut out);
        }
        out
    }

    fn on_nmt(&mut self, data: &[u8], clock: &impl Clock, out: &mut Outbox<F>) {
        let (Some(&code), Some(&node)) = (data.first(), data.get(1)) else {
            self.diag.ignored_frames = self.diag.ignored_frames.saturating_add(1);
            return;
        };
        if node != 0 && node != self.cfg.node_id {
            return;
        }
        let Some(command) = NmtCommand::from_code(code) else {
            self.diag.ignored_frames = self.diag.ignored_frames.saturating_add(1);
            return;
        };
        match (command, self.state) {
            (NmtCommand::Start, State::PreOperational | State::SafeStop) => {
                if self.bus_off {
                    // Nothing would reach the plant: stay, the master starts the node again
                    // after the recovery emergency.
                    return;
                }
                if self.policy.is_none() {
                    self.fault = FaultCode::NoPolicy;
                    self.push_emcy(out);
                    return;
                }
                if self.cfg.envelope.validate().is_err() {
                    self.fault = FaultCode::EnvelopeConfig;
                    self.push_emcy(out);
                    return;
                }
                let had_fault = self.fault != FaultCode::None;
                self.fault = FaultCode::None;
                if had_fault {
                    self.push_emcy(out);
                }
                self.last_obs_us = clock.now_us();
                self.enter(State::Operational, out);
            }
            (NmtCommand::Stop, State::PreOperational | State::Operational) => {
                self.enter(State::SafeStop, out);
                self.send_safe_action(out);
            }
            (NmtCommand::EnterPreOperational, State::Operational | State::SafeStop) => {
                self.enter(State::PreOperational, out);
                self.send_safe_action(out);
            }
            (NmtCommand::ResetNode | NmtCommand::ResetCommunication, _) => {
                if command == NmtCommand::ResetCommunication {
                    self.action_tx = [E2eSender::default(); ACTION_FRAMES];
                    self.emcy_tx = E2eSender::default();
                    self.info_tx = E2eSender::default();
                    self.status_tx = E2eSender::default();
                }
                self.assembler.reset();
                self.fault = FaultCode::None;
                self.state = State::Boot;
                self.send_safe_action(out);
            }
            _ => {}
        }
    }

    fn on_observation_frame(
        &mut self,
        k: usize,
        data: &[u8],
        clock: &impl Clock,
        out: &mut Outbox<F>,
        slots: Option<&mut PolicySlots<'_>>,
    ) {
        self.frames_this_cycle = true;
        let abandoned = self.assembler.abandoned;
        let outcome = self.assembler.push_as(self.layout(), k, data);
        if self.assembler.abandoned != abandoned {
            self.diag.incomplete_observations = self.diag.incomplete_observations.saturating_add(1);
        }
        let sample = match outcome {
            FrameOutcome::Stored => return,
            FrameOutcome::Complete { sample } => sample,
            FrameOutcome::Malformed => {
                self.diag.e2e_errors = self.diag.e2e_errors.saturating_add(1);
                return;
            }
            FrameOutcome::Rejected(status) => {
                let counter = match status {
                    crate::can::E2eStatus::Repeated => &mut self.diag.repeated,
                    crate::can::E2eStatus::WrongSequence => &mut self.diag.wrong_sequence,
                    _ => &mut self.diag.e2e_errors,
                };
                *counter = counter.saturating_add(1);
                return;
            }
        };
        self.obs = *self.assembler.values();
        self.last_obs_us = clock.now_us();
        if self.state != State::Operational {
            return;
        }
        if let Err(fault) = check_observation(&self.obs) {
            let code = match fault {
                ObservationFault::NonFinite { .. } => FaultCode::ObservationNonFinite,
                ObservationFault::OutOfRange { .. } => FaultCode::ObservationOutOfRange,
            };
            self.safe_stop(code, out);
            return;
        }
        let Some(policy) = self.policy.as_mut() else {
            self.safe_stop(FaultCode::NoPolicy, out);
            return;
        };
        self.evaluations_this_cycle += 1;
        self.diag.evaluations = self.diag.evaluations.saturating_add(1);
        let mut action = [0.0f32; ACT_DIM];
        let slot_policy = matches!(policy, Policy::Slot(_));
        // The observation, and the task features after it for a policy that takes them.
        let mut input = [0.0f32; INPUT_MAX];
        let result = match (policy, slots.as_deref()) {
            (Policy::File(mlp), _) => {
                let x = policy_input(&self.obs, mlp.obs_dim(), &mut input);
                mlp.act(x, &mut action)
            }
            (Policy::Slot(net), Some(s)) => {
                let x = policy_input(&self.obs, net.obs_dim(), &mut input);
                net.act(s.active_file(), x, &mut action)
            }
            (Policy::Slot(_), None) => Err(EvalError::PolicyBytes),
        };
        if let Some(s) = slots {
            if result.is_err() && slot_policy && s.on_trial() {
                self.roll_back_on_fault(s, out);
                return;
            }
            s.confirm();
        }
        match result {
            Ok(()) => {
                let limited = self.envelope.apply(&self.obs, &mut action);
                self.action = action;
                self.push_action(sample, out);
                // After the action frames, so a plant waiting for them reads them first.
                if limited.sustained_started {
                    self.push_emcy_code(FaultCode::EnvelopeSustained, out);
                } else if limited.sustained_ended {
                    self.push_emcy_with(0x0000, FaultCode::EnvelopeSustained, out);
                }
            }
            Err(_) => {
                self.fault = FaultCode::ActionNonFinite;
                self.enter(State::Fault, out);
                self.push_emcy(out);
                self.send_safe_action(out);
            }
        }
    }

    /// The first evaluation of a newly activated slot failed: safe-stop, the previous slot back,
    /// emergency 0xFF07. Without a previous policy to go back to, the usual fault.
    fn roll_back_on_fault(&mut self, slots: &mut PolicySlots<'_>, out: &mut Outbox<F>) {
        match slots
            .roll_back_trial(|view, file| Ok((self.bind_slot(view, file)?, policy_info_of(view))))
        {
            Ok((net, info)) => {
                self.set_slot_policy(net, info);
                self.safe_stop(FaultCode::PolicyRolledBack, out);
            }
            Err(_) => {
                self.fault = FaultCode::ActionNonFinite;
                self.enter(State::Fault, out);
                self.push_emcy(out);
                self.send_safe_action(out);
            }
        }
    }

    /// CANopen boot-up message (heartbeat with state 0x00, sent whatever the heartbeat time),
    /// then pre-operational.
    fn boot_up(&mut self, out: &mut Outbox<F>) {
        self.state = State::Boot;
        let _ = out.push(F::classic(heartbeat_frame(
            self.cfg.node_id,
            State::Boot.canopen(),
        )));
        self.enter(State::PreOperational, out);
    }

    fn safe_stop(&mut self, fault: FaultCode, out: &mut Outbox<F>) {
        self.fault = fault;
        self.enter(State::SafeStop, out);
        self.push_emcy(out);
        self.send_safe_action(out);
    }

    fn enter(&mut self, state: State, out: &mut Outbox<F>) {
        if self.state != state {
            if self.state == State::Operational {
                self.envelope.end_run();
            }
            self.state = state;
            self.push_status(out);
            if matches!(state, State::PreOperational | State::Operational) {
                self.announce = true;
            }
        }
    }

    fn send_safe_action(&mut self, out: &mut Outbox<F>) {
        self.action = [0.0; ACT_DIM];
        self.own_sample = self.own_sample.wrapping_add(1) & 0x0F;
        self.push_action(self.own_sample, out);
    }

    /// The heartbeat (one NMT state byte; not while the heartbeat time is 0) and the status
    /// TPDO (controller state, fault code, envelope status; always).
    fn push_status(&mut self, out: &mut Outbox<F>) {
        self.cycles_since_heartbeat = 0;
        self.status_sent = true;
        let node = self.cfg.node_id;
        if self.sdo.device.heartbeat_ms != 0 {
            let _ = out.push(F::classic(heartbeat_frame(node, self.state.canopen())));
        }
        let f = status_frame(
            node,
            self.state.code(),
            self.fault.code(),
            self.envelope.status(),
            &mut self.status_tx,
        );
        self.push_tpdo(f, out);
    }

    /// Sends a TPDO frame, remembering its E2E header for object 0x2201.
    fn push_tpdo(&mut self, f: CanFrame, out: &mut Outbox<F>) {
        let node = self.cfg.node_id;
        let id = f.standard_id();
        if let (Some(k), [a, b, ..]) = (
            (0..TPDOS).find(|&k| id == Some(tpdo_cob_id(node, k))),
            embedded_can::Frame::data(&f),
        ) {
            self.tpdo_headers[k] = u16::from_le_bytes([*a, *b]);
        }
        let _ = out.push(F::classic(f));
    }

    /// Sends the FD action frame (TPDO 0), remembering its E2E header for object 0x2201; a frame
    /// type without FD frames never gets here ([`Controller::new_fd`] is the FD layout's only way).
    fn push_tpdo_fd(&mut self, f: FdFrame, out: &mut Outbox<F>) {
        if let [a, b, ..] = embedded_can::Frame::data(&f) {
            self.tpdo_headers[0] = u16::from_le_bytes([*a, *b]);
        }
        if let Some(f) = F::fd(f) {
            let _ = out.push(f);
        }
    }

    /// The action frames of the current action, tagged `sample`, in the controller's layout.
    fn push_action(&mut self, sample: u8, out: &mut Outbox<F>) {
        let node = self.cfg.node_id;
        match self.layout() {
            FrameLayout::Classic => {
                for f in encode_action(node, &self.action, sample, &mut self.action_tx) {
                    self.push_tpdo(f, out);
                }
            }
            FrameLayout::Fd => {
                let f = encode_action_fd(node, &self.action, sample, &mut self.action_tx[0]);
                self.push_tpdo_fd(f, out);
            }
        }
    }

    fn push_emcy(&mut self, out: &mut Outbox<F>) {
        self.push_emcy_code(self.fault, out);
    }

    /// Emergency for `fault` (its error code and fault code) with the current state.
    fn push_emcy_code(&mut self, fault: FaultCode, out: &mut Outbox<F>) {
        self.push_emcy_with(fault.emcy_code(), fault, out);
    }

    /// Emergency with `error_code`, the error register (0x1001) as it stands, `fault`'s fault
    /// code and the current state; an error (not the error reset 0x0000) is recorded in the
    /// pre-defined error field (0x1003) with the same code.
    fn push_emcy_with(&mut self, error_code: u16, fault: FaultCode, out: &mut Outbox<F>) {
        if error_code != 0 {
            self.sdo.device.record_emergency(error_code, fault.code());
        }
        let register = crate::canopen::device::DeviceHost::error_register(self);
        let f = emcy_frame(
            self.cfg.node_id,
            error_code,
            register,
            fault.code(),
            self.state.code(),
            &mut self.emcy_tx,
        );
        let _ = out.push(F::classic(f));
    }

    fn push_policy_info(&mut self, out: &mut Outbox<F>) {
        let (hash, version, task) = match self.info {
            Some(i) => (i.layout_hash, i.format_version as u8, i.task),
            None => (0, FORMAT_VERSION as u8, 0xFF),
        };
        let f = policy_info_frame(self.cfg.node_id, hash, version, task, &mut self.info_tx);
        self.push_tpdo(f, out);
    }
}

/// The controller's clock in milliseconds, as the SDO server's timeout reads it (wrapping).
fn sdo_ms(clock: &impl Clock) -> u32 {
    (clock.now_us() / 1000) as u32
}

/// The policy-info fields of a file.
fn policy_info_of(view: &PolicyView<'_>) -> PolicyInfo {
    PolicyInfo {
        layout_hash: view.header().layout_hash,
        format_version: view.header().version,
        task: view.body().task as u8,
    }
}

/// Number of frames the plant sends per cycle.
pub const OBS_FRAMES_PER_CYCLE: usize = OBS_FRAMES;

/// The controller as the application of CiA 302-3 program download ([`crate::canopen::program`]).
impl<const WIDTH: usize, F: TxFrame> crate::canopen::program::ProgramHost
    for Controller<'_, WIDTH, F>
{
    fn may_change_program(&self) -> bool {
        self.state != State::Operational
    }

    fn accept(&self, view: &PolicyView<'_>, file: &[u8]) -> Result<(), LoadError> {
        self.bind_slot(view, file).map(|_| ())
    }

    fn activate(&mut self, slots: &mut PolicySlots<'_>) -> Result<(), SlotError> {
        self.activate_slot(slots)
    }

    fn roll_back(&mut self, slots: &mut PolicySlots<'_>) -> Result<(), SlotError> {
        self.roll_back_slot(slots)
    }

    fn stop(&mut self) {
        self.stop_requested = true;
    }

    fn running(&self) -> bool {
        self.state == State::Operational
    }
}

/// The controller as the application behind the communication objects
/// ([`crate::canopen::device`]).
impl<const WIDTH: usize, F: TxFrame> crate::canopen::device::DeviceHost
    for Controller<'_, WIDTH, F>
{
    /// Bit 0 (generic) while a fault is latched, bit 4 (communication) for a watchdog timeout or
    /// bus-off, bit 7 (manufacturer-specific) for the other faults.
    fn error_register(&self) -> u8 {
        match self.fault {
            FaultCode::None | FaultCode::EnvelopeSustained => 0,
            FaultCode::ObservationTimeout | FaultCode::BusOff => 0x01 | 0x10,
            _ => 0x01 | 0x80,
        }
    }

    fn active_policy(&self) -> Option<crate::canopen::device::ActivePolicy> {
        self.info.map(|i| crate::canopen::device::ActivePolicy {
            layout_hash: i.layout_hash,
            format_version: i.format_version,
            task: i.task,
        })
    }

    fn envelope_status(&self) -> u8 {
        self.envelope.status()
    }

    fn controller_state(&self) -> u8 {
        self.state.code()
    }

    fn fault_code(&self) -> u8 {
        self.fault.code()
    }

    fn node_id(&self) -> u8 {
        self.cfg.node_id
    }

    fn layout(&self) -> FrameLayout {
        Controller::layout(self)
    }

    fn observation_raw(&self, index: usize) -> i16 {
        let lsb = quantity_of(index).map_or(1.0, Quantity::lsb);
        self.obs.get(index).map_or(0, |&v| to_raw(v, lsb))
    }

    fn action_raw(&self, index: usize) -> i16 {
        self.action
            .get(index)
            .map_or(0, |&v| to_raw(v, ACTION_QUANTITY.lsb()))
    }

    fn observation_header(&self, k: usize) -> u16 {
        self.assembler.header(k)
    }

    fn tpdo_header(&self, k: usize) -> u16 {
        self.tpdo_headers.get(k).copied().unwrap_or(0)
    }
}
