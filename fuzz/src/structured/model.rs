//! The reference model: an independent model of the documented behaviour (E2E receiver per
//! observation frame, sample assembly, state machine, watchdog and cycle bookkeeping, fault latching,
//! bus-off, heartbeat and policy-info scheduling, safe-action sample counter) that predicts every
//! frame of every step: each action bit for bit (the model evaluates its own `Mlp` over the same
//! policy bytes, so an action computed from anything but the completed sample's values shows), each
//! emergency (code, error register, fault, state), heartbeat (one NMT state byte), status TPDO
//! (state, fault) and policy-info frame, plus the state, the latched fault
//! and the diagnostic counters. [`super::checks`] compares them with the controller's.

use dex_policy::FORMAT_VERSION;
use dex_runtime::can::CanFrame;
use dex_runtime::can::e2e::{COUNTER_MAX, crc8};
use dex_runtime::can::messages::{
    ACTION_QUANTITY, NMT_ID, NmtCommand, OBS_FRAMES, SIGNALS_PER_FRAME, from_raw, rpdo_cob_id,
    to_raw,
};
use dex_runtime::controller::PolicyInfo;
use dex_runtime::interface::{ACT_DIM, OBS_DIM, quantity_of};
use dex_runtime::{ControllerConfig, Diagnostics, FaultCode, Mlp, State};
use embedded_can::Frame;

use super::{PERIOD, WIDTH};

const ALL_FRAMES: u32 = (1 << OBS_FRAMES) - 1;

/// A frame as the model predicts it (CRC and counters are checked while parsing).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Out {
    Action {
        sample: u8,
        raw: [i16; ACT_DIM],
    },
    Emcy {
        code: u16,
        register: u8,
        fault: u8,
        state: u8,
    },
    /// CiA 301 heartbeat: the NMT state byte alone.
    Heartbeat {
        canopen: u8,
    },
    /// The status TPDO sent with every heartbeat and state change.
    Status {
        state: u8,
        fault: u8,
    },
    Info {
        hash: u32,
        version: u8,
        task: u8,
    },
}

/// The policy the model evaluates, and its identity as the controller reports it.
pub(crate) struct ActivePolicy<'p> {
    pub(crate) mlp: Mlp<'p, WIDTH>,
    pub(crate) info: PolicyInfo,
}

/// The reference model's state, and the frames it predicts for the current step (`out`).
pub(crate) struct Model<'p> {
    pub(crate) cfg: ControllerConfig,
    pub(crate) state: State,
    pub(crate) fault: FaultCode,
    pub(crate) bus_off: bool,
    pub(crate) policy: Option<ActivePolicy<'p>>,
    pub(crate) rx_last: [Option<u8>; OBS_FRAMES],
    pub(crate) sample: Option<u8>,
    pub(crate) mask: u32,
    pub(crate) values: [f32; OBS_DIM],
    pub(crate) last_obs_us: u64,
    pub(crate) next_tick: Option<u64>,
    pub(crate) frames_this_cycle: bool,
    pub(crate) evaluations_this_cycle: u32,
    pub(crate) cycles_since_heartbeat: u32,
    pub(crate) announce: bool,
    pub(crate) own_sample: u8,
    pub(crate) action: [f32; ACT_DIM],
    pub(crate) diag: Diagnostics,
    pub(crate) out: Vec<Out>,
}

impl<'p> Model<'p> {
    pub(crate) fn new(cfg: ControllerConfig) -> Self {
        Model {
            cfg,
            state: State::Boot,
            fault: FaultCode::None,
            bus_off: false,
            policy: None,
            rx_last: [None; OBS_FRAMES],
            sample: None,
            mask: 0,
            values: [0.0; OBS_DIM],
            last_obs_us: 0,
            next_tick: None,
            frames_this_cycle: false,
            evaluations_this_cycle: 0,
            cycles_since_heartbeat: 0,
            announce: false,
            own_sample: 0,
            action: [0.0; ACT_DIM],
            diag: Diagnostics::default(),
            out: Vec::new(),
        }
    }

    /// The producer heartbeat time in ms as the controller starts with it (0x1017; the fuzz
    /// target writes no SDO): `heartbeat_cycles` periods, 0 = no heartbeat.
    fn heartbeat_ms(&self) -> u64 {
        (u64::from(self.cfg.heartbeat_cycles) * PERIOD / 1000).min(u64::from(u16::MAX))
    }

    /// The heartbeat (when on) and the status TPDO.
    fn heartbeat(&mut self) {
        self.cycles_since_heartbeat = 0;
        if self.heartbeat_ms() != 0 {
            self.out.push(Out::Heartbeat {
                canopen: self.state.canopen(),
            });
        }
        self.out.push(Out::Status {
            state: self.state.code(),
            fault: self.fault.code(),
        });
    }

    /// The error register as documented (0x1001): 0 without a latched fault (the envelope's
    /// warning is none), generic + communication for a watchdog timeout or bus-off, generic +
    /// manufacturer-specific for the others.
    fn register(&self) -> u8 {
        match self.fault {
            FaultCode::None | FaultCode::EnvelopeSustained => 0,
            FaultCode::ObservationTimeout | FaultCode::BusOff => 0x11,
            _ => 0x81,
        }
    }

    fn enter(&mut self, state: State) {
        if self.state != state {
            self.state = state;
            self.heartbeat();
            if matches!(state, State::PreOperational | State::Operational) {
                self.announce = true;
            }
        }
    }

    fn emcy(&mut self, fault: FaultCode) {
        self.out.push(Out::Emcy {
            code: fault.emcy_code(),
            register: self.register(),
            fault: fault.code(),
            state: self.state.code(),
        });
    }

    fn safe_action(&mut self) {
        self.action = [0.0; ACT_DIM];
        self.own_sample = (self.own_sample + 1) & 0x0F;
        self.out.push(Out::Action {
            sample: self.own_sample,
            raw: [0; ACT_DIM],
        });
    }

    fn safe_stop(&mut self, fault: FaultCode) {
        self.fault = fault;
        self.enter(State::SafeStop);
        self.emcy(fault);
        self.safe_action();
    }

    fn boot_up(&mut self) {
        self.state = State::Boot;
        // The boot-up message goes out whatever the heartbeat time.
        self.out.push(Out::Heartbeat {
            canopen: State::Boot.canopen(),
        });
        self.enter(State::PreOperational);
    }

    fn reset_assembly(&mut self) {
        self.rx_last = [None; OBS_FRAMES];
        self.sample = None;
        self.mask = 0;
    }

    pub(crate) fn poll(&mut self, now: u64) {
        let Some(next) = self.next_tick else {
            self.next_tick = Some(now + PERIOD);
            self.boot_up();
            return;
        };
        if now < next {
            return;
        }
        let late = (now - next) / PERIOD;
        self.diag.missed_cycles += late;
        self.next_tick = Some(next + (late + 1) * PERIOD);
        self.diag.cycles += 1;
        if !self.frames_this_cycle {
            self.diag.no_new_data += 1;
        }
        if self.evaluations_this_cycle > 1 {
            self.diag.overruns += 1;
        }
        self.frames_this_cycle = false;
        self.evaluations_this_cycle = 0;
        let before = self.out.len();
        match self.state {
            State::Boot => self.boot_up(),
            State::Operational => {
                if now - self.last_obs_us > u64::from(self.cfg.watchdog_cycles) * PERIOD {
                    self.safe_stop(FaultCode::ObservationTimeout);
                }
            }
            _ => self.safe_action(),
        }
        self.cycles_since_heartbeat += 1;
        // At most one heartbeat per cycle: none on schedule when the state change sent one.
        let sent = self.out[before..]
            .iter()
            .any(|o| matches!(o, Out::Status { .. }));
        let ms = self.heartbeat_ms();
        if ms != 0 && !sent && u64::from(self.cycles_since_heartbeat) * PERIOD >= ms * 1000 {
            self.heartbeat();
        }
        if self.announce {
            self.announce = false;
            self.info();
        }
    }

    fn info(&mut self) {
        let (hash, version, task) = match &self.policy {
            Some(p) => (p.info.layout_hash, p.info.format_version as u8, p.info.task),
            None => (0, FORMAT_VERSION as u8, 0xFF),
        };
        self.out.push(Out::Info {
            hash,
            version,
            task,
        });
    }

    pub(crate) fn frame(&mut self, frame: &CanFrame, now: u64) {
        let id = frame.standard_id().expect("standard frames only");
        let data = frame.data();
        if id == NMT_ID {
            self.nmt(data, now);
        } else if let Some(k) = (0..OBS_FRAMES).find(|&k| rpdo_cob_id(self.cfg.node_id, k) == id) {
            self.observation(k, data, now);
        } else {
            self.diag.ignored_frames += 1;
        }
    }

    fn nmt(&mut self, data: &[u8], now: u64) {
        if data.len() < 2 {
            self.diag.ignored_frames += 1;
            return;
        }
        if data[1] != 0 && data[1] != self.cfg.node_id {
            return;
        }
        let Some(command) = NmtCommand::from_code(data[0]) else {
            self.diag.ignored_frames += 1;
            return;
        };
        match (command, self.state) {
            (NmtCommand::Start, State::PreOperational | State::SafeStop) => {
                if self.bus_off {
                    return;
                }
                if self.policy.is_none() {
                    self.fault = FaultCode::NoPolicy;
                    self.emcy(FaultCode::NoPolicy);
                    return;
                }
                if self.fault != FaultCode::None {
                    self.fault = FaultCode::None;
                    self.emcy(FaultCode::None);
                }
                self.last_obs_us = now;
                self.enter(State::Operational);
            }
            (NmtCommand::Stop, State::PreOperational | State::Operational) => {
                self.enter(State::SafeStop);
                self.safe_action();
            }
            (NmtCommand::EnterPreOperational, State::Operational | State::SafeStop) => {
                self.enter(State::PreOperational);
                self.safe_action();
            }
            (NmtCommand::ResetNode | NmtCommand::ResetCommunication, _) => {
                // Reset communication also restarts the sent alive counters (checked in
                // `Run::parse`).
                self.reset_assembly();
                self.fault = FaultCode::None;
                self.state = State::Boot;
                self.safe_action();
            }
            _ => {}
        }
    }

    fn observation(&mut self, k: usize, data: &[u8], now: u64) {
        self.frames_this_cycle = true;
        if data.len() != 8 {
            self.diag.e2e_errors += 1;
            return;
        }
        // E2E (docs/runtime.md): CRC and counter 0..=14, then the counter's advance.
        if crc8(rpdo_cob_id(self.cfg.node_id, k), data) != data[0] || data[1] & 0x0F > COUNTER_MAX {
            self.diag.e2e_errors += 1;
            return;
        }
        let counter = data[1] & 0x0F;
        if let Some(last) = self.rx_last[k] {
            let delta = (counter + COUNTER_MAX + 1 - last) % (COUNTER_MAX + 1);
            if delta == 0 {
                self.diag.repeated += 1;
                return;
            }
            self.rx_last[k] = Some(counter);
            if delta > self.cfg.e2e_max_delta {
                self.diag.wrong_sequence += 1;
                return;
            }
        }
        self.rx_last[k] = Some(counter);
        // Sample assembly: a new nibble abandons an incomplete older sample.
        let sample = data[1] >> 4;
        if self.sample != Some(sample) {
            if self.mask != 0 && self.mask != ALL_FRAMES {
                self.diag.incomplete_observations += 1;
            }
            self.sample = Some(sample);
            self.mask = 0;
        }
        for s in 0..SIGNALS_PER_FRAME {
            let index = k * SIGNALS_PER_FRAME + s;
            if index < OBS_DIM {
                let raw = i16::from_le_bytes([data[2 + 2 * s], data[3 + 2 * s]]);
                let lsb = quantity_of(index).expect("index").lsb();
                self.values[index] = from_raw(raw, lsb);
            }
        }
        let before = self.mask;
        self.mask |= 1 << k;
        if self.mask != ALL_FRAMES || before == ALL_FRAMES {
            return;
        }
        self.last_obs_us = now;
        if self.state != State::Operational {
            return;
        }
        for (index, v) in self.values.iter().enumerate() {
            let limit = quantity_of(index).expect("index").limit();
            if !v.is_finite() {
                self.safe_stop(FaultCode::ObservationNonFinite);
                return;
            }
            if v.abs() > limit {
                self.safe_stop(FaultCode::ObservationOutOfRange);
                return;
            }
        }
        let Some(policy) = self.policy.as_mut() else {
            self.safe_stop(FaultCode::NoPolicy);
            return;
        };
        self.evaluations_this_cycle += 1;
        self.diag.evaluations += 1;
        let mut action = [0.0f32; ACT_DIM];
        match policy.mlp.act(&self.values, &mut action) {
            Ok(()) => {
                self.action = action;
                self.out.push(Out::Action {
                    sample,
                    raw: action.map(|a| to_raw(a, ACTION_QUANTITY.lsb())),
                });
            }
            Err(_) => {
                self.fault = FaultCode::ActionNonFinite;
                self.enter(State::Fault);
                self.emcy(FaultCode::ActionNonFinite);
                self.safe_action();
            }
        }
    }

    pub(crate) fn bus_off(&mut self) {
        if self.bus_off {
            return;
        }
        self.bus_off = true;
        self.diag.bus_off_events += 1;
        self.reset_assembly();
        if self.fault == FaultCode::None {
            self.fault = FaultCode::BusOff;
        }
        if self.state == State::Operational {
            self.enter(State::PreOperational);
        }
        self.safe_action();
    }

    pub(crate) fn bus_recovered(&mut self) {
        if !self.bus_off {
            return;
        }
        self.bus_off = false;
        self.emcy(FaultCode::BusOff);
        self.heartbeat();
        self.safe_action();
    }
}
