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

mod config;
mod diagnostics;
mod hosts;
mod slots;
mod state;
mod transmit;

pub use config::ControllerConfig;
pub use diagnostics::{Diagnostics, PolicyInfo};
pub use state::{FaultCode, State};

use heapless::Vec;

use core::marker::PhantomData;

use self::slots::SdoSide;
use crate::can::e2e::E2eSender;
use crate::can::fd_frame::{AnyFrame, TxFrame};
use crate::can::frame::CanFrame;
use crate::can::layout::FrameLayout;
use crate::can::messages::{ACTION_FRAMES, NMT_ID, NmtCommand, OBS_FRAMES, TPDOS, heartbeat_frame};
use crate::canopen::device::DeviceState;
use crate::canopen::program::ProgramState;
use crate::clock::Clock;
use crate::envelope::{Envelope, EnvelopeStats};
use crate::error::EvalError;
use crate::features::{INPUT_MAX, policy_input};
use crate::interface::{ACT_DIM, OBS_DIM};
use crate::mlp::{Mlp, Network};
use crate::observation::{FrameOutcome, ObservationAssembler, ObservationFault, check_observation};
use crate::slots::PolicySlots;

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
}

/// Number of frames the plant sends per cycle.
pub const OBS_FRAMES_PER_CYCLE: usize = OBS_FRAMES;
