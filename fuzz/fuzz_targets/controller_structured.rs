//! Structure-aware fuzzing of the controller's logic (issue 16, part 5).
//!
//! `controller_frames` feeds raw bytes, which almost never pass the E2E CRC, so it mostly exercises
//! the rejection paths. This target derives an operation sequence with `arbitrary` and turns it into
//! what a plant, an NMT master, a clock, a CAN driver and a flashing tool would do:
//!
//! - observation frames sealed like the plant seals them (CRC-8/SAE-J1850 over the data id, alive
//!   counter, sample nibble), with values, counters and nibbles chosen by the fuzzer: whole samples,
//!   parts of samples interleaved with other operations, and flaws (a wrong CRC, a repeated, skipped
//!   or invalid counter, a short frame, a frame of another sample, a lost or duplicated frame, values
//!   "not available", saturated, at or beyond their plausible range);
//! - NMT commands (to this node, to all, to another node, unknown commands);
//! - clock steps (`MockClock`, the controller's only source of time) with or without a `poll`;
//! - bus-off and recovery reports from the driver;
//! - policy flashing: a segmented transfer of one of several seeded synthetic policy files into a
//!   staging slot (init, data segments, corrupted bytes, end with a right or wrong transfer CRC,
//!   optionally with the file CRC recomputed so that corruption reaches the decoder), verification,
//!   activation with `Controller::load_policy`, abort; and direct loads of refused files (wrong
//!   period, wrong layout, over capacity).
//!
//! The controller starts with a real policy (f32, two-hidden-layer f32, int8, or one whose network
//! output is never finite) or none, and a configuration chosen by the fuzzer (watchdog 0..=6 cycles,
//! heartbeat 0..=20 cycles, E2E max delta 0..=14, node id).
//!
//! # Invariants (checked after every step; a violation panics)
//!
//! Model-free, from `docs/runtime.md` and the controller's documentation:
//! 1. Safe action whenever not operational: outside `Operational`, `last_action()` is zero, and every
//!    action frame sent by a step that ends outside `Operational` carries zero velocity.
//! 2. No action from an incomplete or mismatched sample: a non-zero (policy) action leaves the
//!    controller only in answer to an observation frame, in `Operational`, tagged with that frame's
//!    sample nibble, and only when that frame completed a sample whose 15 frames all passed the E2E
//!    check with that nibble (the reference model below tracks the accepted frames).
//! 3. No non-finite action: no action signal is "not available" (raw -32768) and `last_action()` is
//!    finite.
//! 4. Watchdog: after every `poll` in `Operational`, the newest complete observation (or the NMT
//!    start) is less than `watchdog_cycles + 1` periods old; a cycle boundary that finds it older
//!    than `watchdog_cycles` periods leaves `Operational` for `SafeStop` with fault
//!    `ObservationTimeout` and emergency 0x8250.
//! 5. Legal transitions only (the state table of `docs/runtime.md`): poll: Boot -> PreOperational,
//!    Operational -> SafeStop; NMT start: PreOperational/SafeStop -> Operational; NMT stop:
//!    PreOperational/Operational -> SafeStop; NMT pre-op: Operational/SafeStop -> PreOperational;
//!    NMT reset node/communication: any -> Boot; observation frame: Operational -> SafeStop/Fault;
//!    bus-off: Operational -> PreOperational; recovery and policy loads change no state. `Fault` is
//!    left by NMT reset only; never `Operational` while bus-off, nor without a policy.
//! 6. Frames sent are well-formed: only the controller's identifiers; E2E-protected ones (action,
//!    emergency, policy info) have a correct CRC and an alive counter that advances by one per
//!    identifier (restarting at 0 after NMT reset communication); the three action frames go
//!    together with one sample nibble; a heartbeat's CANopen byte matches its state byte; at most 6
//!    frames per call (the `Outbox` holds 8, and frames past it would be lost silently).
//! 7. Policy loads: refused while operational (`LoadError::Operational`), and a refused file leaves
//!    the active policy (its identity and its actions) in place; a transfer whose bytes differ from
//!    the file sent never verifies unless its file CRC was recomputed.
//!
//! Reference model (exact outputs): an independent model of the documented behaviour (E2E receiver
//! per observation frame, sample assembly, state machine, watchdog and cycle bookkeeping, fault
//! latching, bus-off, heartbeat and policy-info scheduling, safe-action sample counter) predicts
//! every frame of every step: each action bit for bit (the model evaluates its own `Mlp` over the
//! same policy bytes, so an action computed from anything but the completed sample's values shows),
//! each emergency (code, fault, state), heartbeat and policy-info frame, plus the state, the
//! latched fault and the diagnostic counters. Any difference panics.
#![no_main]

use std::sync::OnceLock;

use arbitrary::Arbitrary;
use crc::{CRC_32_ISO_HDLC, Crc};
use dex_policy::synth::{SplitMix64, SynthSpec, golden_small_spec, synth_parts, synth_policy};
use dex_policy::{
    Activation, Body, CRC_OFFSET, FORMAT_VERSION, PolicyView, Task, encode_to_vec, file_crc,
};
use dex_runtime::can::CanFrame;
use dex_runtime::can::e2e::{COUNTER_MAX, crc8, next_counter, protect};
use dex_runtime::can::messages::{
    ACTION_BASE_ID, ACTION_FRAMES, ACTION_QUANTITY, EMCY_BASE_ID, HEARTBEAT_BASE_ID, NMT_ID,
    NmtCommand, OBS_BASE_ID, OBS_FRAMES, POLICY_INFO_ID, RAW_NOT_AVAILABLE, SIGNALS_PER_FRAME,
    from_raw, to_raw,
};
use dex_runtime::controller::PolicyInfo;
use dex_runtime::envelope::EnvelopeConfig;
use dex_runtime::interface::{ACT_DIM, CONTROL_PERIOD_US, OBS_DIM, quantity_of};
use dex_runtime::testkit::{
    AlignedBytes, aligned_copy, cell_layout, jaco_policy, jaco_policy_int8,
};
use dex_runtime::{
    Clock, Controller, ControllerConfig, Diagnostics, FaultCode, LoadError, Mlp, MockClock, Outbox,
    State,
};
use embedded_can::Frame;
use libfuzzer_sys::fuzz_target;

/// Evaluator capacity of the fuzzed controller (widest layer).
const WIDTH: usize = 64;
const PERIOD: u64 = CONTROL_PERIOD_US as u64;
const ALL_FRAMES: u32 = (1 << OBS_FRAMES) - 1;
const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);
/// Bytes per flash data segment (CANopen SDO-block style, as `hil-sim`'s flash server).
const SEGMENT_BYTES: usize = 6;
/// Staging buffers per input for verified files that differ from every prepared one.
const POOL_SLOTS: usize = 4;

// ---------------------------------------------------------------------------------------------
// Policy files
// ---------------------------------------------------------------------------------------------

/// A prepared policy file and whether the controller must take it.
struct Image {
    bytes: AlignedBytes,
    loads: bool,
}

/// A policy on the cell's layout, edited before encoding.
fn jaco_file(
    hidden: &[u16],
    seed: u64,
    output: Activation,
    edit: impl FnOnce(&mut Body<'_>, &mut Vec<f32>),
) -> Vec<u8> {
    let (observation, action) = cell_layout();
    let spec = SynthSpec {
        task: Task::Stack,
        observation: &observation,
        action: &action,
        hidden,
        hidden_activation: Activation::Relu,
        output_activation: output,
        seed,
    };
    let (mut body, mut values) = synth_parts(&spec).expect("synthetic policy");
    edit(&mut body, &mut values);
    encode_to_vec(&body, &values).expect("synthetic policy encodes")
}

/// The files the fuzzer flashes or loads; the first four load, the rest are refused.
fn images() -> &'static [Image] {
    static IMAGES: OnceLock<Vec<Image>> = OnceLock::new();
    IMAGES.get_or_init(|| {
        let image = |bytes: Vec<u8>, loads: bool| Image {
            bytes: aligned_copy(&bytes),
            loads,
        };
        vec![
            image(jaco_policy(&[16], 1).expect("policy"), true),
            image(jaco_policy(&[8, 8], 2).expect("policy"), true),
            image(jaco_policy_int8(&[16], 3).expect("policy"), true),
            // First-layer weights of +-1e38: every product overflows, the sums are inf - inf.
            image(
                jaco_file(&[16], 4, Activation::Linear, |_, values| {
                    let start = 2 * OBS_DIM;
                    for (i, w) in values[start..start + OBS_DIM * 16].iter_mut().enumerate() {
                        *w = if i % 2 == 0 { 1e38 } else { -1e38 };
                    }
                }),
                true,
            ),
            image(
                jaco_file(&[16], 5, Activation::Tanh, |body, _| {
                    body.control_period_us = 40_000;
                }),
                false,
            ),
            image(synth_policy(&golden_small_spec()).expect("policy"), false),
            image(jaco_policy(&[128], 6).expect("policy"), false),
        ]
    })
}

// ---------------------------------------------------------------------------------------------
// Operations
// ---------------------------------------------------------------------------------------------

#[derive(Arbitrary, Debug)]
struct Input {
    watchdog_cycles: u8,
    heartbeat_cycles: u8,
    e2e_max_delta: u8,
    node_id: u8,
    /// Index into the loadable images, or none.
    initial_policy: Option<u8>,
    ops: Vec<Op>,
}

#[derive(Arbitrary, Debug)]
enum Op {
    /// All 15 frames of one sample, in order, without flaws.
    Sample {
        sample: SampleSel,
        values: Values,
    },
    /// Frames `first ..= first + count` of one sample (the rest of it may come in a later op).
    Frames {
        sample: SampleSel,
        first: u8,
        count: u8,
        values: Values,
        flaw: Option<(u8, Flaw)>,
        reverse: bool,
    },
    Nmt {
        command: NmtSel,
        node: NodeSel,
    },
    Clock {
        step: Step,
        poll: bool,
    },
    Poll,
    BusOff,
    BusRecovered,
    FlashInit {
        image: u8,
    },
    FlashData {
        segments: u16,
    },
    FlashCorrupt {
        offset: u16,
        xor: u8,
    },
    FlashEnd {
        crc: CrcSel,
        reseal: bool,
    },
    FlashActivate,
    FlashAbort,
    /// `load_policy` with a prepared file, loadable or not.
    Load {
        image: u8,
    },
    /// Any frame (observation ids included: a random CRC sometimes matches).
    Raw {
        id: u16,
        data: [u8; 8],
        len: u8,
    },
}

#[derive(Arbitrary, Debug, Clone, Copy)]
enum SampleSel {
    Same,
    Next,
    Nibble(u8),
}

#[derive(Arbitrary, Debug, Clone, Copy)]
enum Values {
    /// Every value within `spread / 255` of its plausible range.
    Nominal { seed: u16, spread: u8 },
    /// Nominal except value `index`.
    Special {
        seed: u16,
        spread: u8,
        index: u8,
        value: Special,
    },
}

#[derive(Arbitrary, Debug, Clone, Copy)]
enum Special {
    NotAvailable,
    SaturatedHigh,
    SaturatedLow,
    AtLimit,
    BeyondLimit,
    Raw(i16),
}

#[derive(Arbitrary, Debug, Clone, Copy)]
enum Flaw {
    BadCrc(u8),
    RepeatCounter,
    SkipCounters(u8),
    Counter15,
    Short(u8),
    OtherSample(u8),
    Lost,
    Duplicate,
}

#[derive(Arbitrary, Debug, Clone, Copy)]
enum NmtSel {
    Start,
    Stop,
    PreOperational,
    ResetNode,
    ResetCommunication,
    Unknown(u8),
}

#[derive(Arbitrary, Debug, Clone, Copy)]
enum NodeSel {
    All,
    Own,
    Other(u8),
}

#[derive(Arbitrary, Debug, Clone, Copy)]
enum Step {
    Period,
    Periods(u8),
    Micros(u16),
    Long(u32),
}

#[derive(Arbitrary, Debug, Clone, Copy)]
enum CrcSel {
    /// CRC-32 of the bytes sent.
    Sent,
    /// CRC-32 of the file the transfer started with.
    Original,
    /// Neither.
    Wrong,
}

/// Raw signal of observation value `index`.
fn value_raw(values: Values, index: usize) -> i16 {
    let (seed, spread) = match values {
        Values::Nominal { seed, spread } | Values::Special { seed, spread, .. } => (seed, spread),
    };
    let q = quantity_of(index).expect("index within the observation");
    let limit = f64::from(q.limit()) / f64::from(q.lsb());
    if let Values::Special {
        index: special,
        value,
        ..
    } = values
        && usize::from(special) % OBS_DIM == index
    {
        return match value {
            Special::NotAvailable => RAW_NOT_AVAILABLE,
            Special::SaturatedHigh => i16::MAX,
            Special::SaturatedLow => -i16::MAX,
            Special::AtLimit => limit.floor() as i16,
            Special::BeyondLimit => -(limit.ceil() as i16 + 1),
            Special::Raw(r) => r,
        };
    }
    let mut rng = SplitMix64::new((u64::from(seed) << 8) | index as u64);
    let unit = f64::from(rng.uniform(-1.0, 1.0));
    (unit * limit * f64::from(spread) / 255.0) as i16
}

// ---------------------------------------------------------------------------------------------
// The plant and the flashing tool (harness side)
// ---------------------------------------------------------------------------------------------

/// The plant's sending side: one alive counter per observation frame and the current sample.
#[derive(Debug, Default)]
struct Plant {
    next: [u8; OBS_FRAMES],
    last: [Option<u8>; OBS_FRAMES],
    sample: u8,
}

impl Plant {
    fn select(&mut self, sel: SampleSel) -> u8 {
        self.sample = match sel {
            SampleSel::Same => self.sample,
            SampleSel::Next => (self.sample + 1) & 0x0F,
            SampleSel::Nibble(n) => n & 0x0F,
        };
        self.sample
    }

    /// The frames observation frame `k` turns into on the bus (none if lost, two if duplicated).
    fn frames(
        &mut self,
        k: usize,
        sample: u8,
        values: Values,
        flaw: Option<Flaw>,
    ) -> Vec<CanFrame> {
        let id = OBS_BASE_ID + k as u16;
        let mut counter = self.next[k];
        match flaw {
            Some(Flaw::RepeatCounter) => counter = self.last[k].unwrap_or(counter),
            Some(Flaw::SkipCounters(n)) => {
                for _ in 0..=(n % COUNTER_MAX) {
                    counter = next_counter(counter);
                }
            }
            _ => {}
        }
        let nibble = match flaw {
            Some(Flaw::OtherSample(n)) => n & 0x0F,
            _ => sample,
        };
        let mut data = [0u8; 8];
        data[1] = nibble << 4;
        for s in 0..SIGNALS_PER_FRAME {
            let index = k * SIGNALS_PER_FRAME + s;
            if index < OBS_DIM {
                let raw = value_raw(values, index);
                data[2 + 2 * s..4 + 2 * s].copy_from_slice(&raw.to_le_bytes());
            }
        }
        let sent = if matches!(flaw, Some(Flaw::Counter15)) {
            15
        } else {
            counter
        };
        protect(id, sent, &mut data);
        if sent <= COUNTER_MAX {
            self.last[k] = Some(sent);
            self.next[k] = next_counter(sent);
        }
        let mut len = 8;
        match flaw {
            Some(Flaw::BadCrc(x)) => data[0] ^= x.max(1),
            Some(Flaw::Short(l)) => len = usize::from(l % 8),
            Some(Flaw::Lost) => return Vec::new(),
            _ => {}
        }
        let frame = CanFrame::standard(id, &data[..len]).expect("observation frame");
        if matches!(flaw, Some(Flaw::Duplicate)) {
            vec![frame, frame]
        } else {
            vec![frame]
        }
    }
}

/// The staging slot of a transfer (the protocol of `hil-sim`'s flash server, reduced to what
/// reaches the controller: the file that `load_policy` gets).
#[derive(Debug)]
enum Staging {
    Empty,
    Receiving { image: usize, data: Vec<u8> },
    Verified { image: usize, data: Vec<u8> },
}

// ---------------------------------------------------------------------------------------------
// Reference model
// ---------------------------------------------------------------------------------------------

/// A frame as the model predicts it (CRC and counters are checked while parsing).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Out {
    Action {
        sample: u8,
        raw: [i16; ACT_DIM],
    },
    Emcy {
        code: u16,
        fault: u8,
        state: u8,
    },
    Heartbeat {
        canopen: u8,
        counter: u8,
        state: u8,
        fault: u8,
    },
    Info {
        hash: u32,
        version: u8,
        task: u8,
    },
}

/// What happened to the controller in one step, for the transition check.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Event {
    Poll,
    Nmt(Option<NmtCommand>),
    Observation,
    BusOff,
    BusRecovered,
    Load,
    Other,
}

struct ActivePolicy<'p> {
    mlp: Mlp<'p, WIDTH>,
    info: PolicyInfo,
}

struct Model<'p> {
    cfg: ControllerConfig,
    state: State,
    fault: FaultCode,
    bus_off: bool,
    policy: Option<ActivePolicy<'p>>,
    rx_last: [Option<u8>; OBS_FRAMES],
    sample: Option<u8>,
    mask: u32,
    values: [f32; OBS_DIM],
    last_obs_us: u64,
    next_tick: Option<u64>,
    frames_this_cycle: bool,
    evaluations_this_cycle: u32,
    cycles_since_heartbeat: u32,
    announce: bool,
    own_sample: u8,
    heartbeat_counter: u8,
    action: [f32; ACT_DIM],
    diag: Diagnostics,
    out: Vec<Out>,
}

impl<'p> Model<'p> {
    fn new(cfg: ControllerConfig) -> Self {
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
            heartbeat_counter: 0,
            action: [0.0; ACT_DIM],
            diag: Diagnostics::default(),
            out: Vec::new(),
        }
    }

    fn heartbeat(&mut self) {
        self.cycles_since_heartbeat = 0;
        self.out.push(Out::Heartbeat {
            canopen: self.state.canopen(),
            counter: self.heartbeat_counter,
            state: self.state.code(),
            fault: self.fault.code(),
        });
        self.heartbeat_counter = self.heartbeat_counter.wrapping_add(1);
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
        self.heartbeat();
        self.enter(State::PreOperational);
    }

    fn reset_assembly(&mut self) {
        self.rx_last = [None; OBS_FRAMES];
        self.sample = None;
        self.mask = 0;
    }

    fn poll(&mut self, now: u64) {
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
        let heartbeats = self.heartbeat_counter;
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
        if self.heartbeat_counter == heartbeats
            && self.cycles_since_heartbeat >= self.cfg.heartbeat_cycles
        {
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

    fn frame(&mut self, frame: &CanFrame, now: u64) {
        let id = frame.standard_id().expect("standard frames only");
        let data = frame.data();
        if id == NMT_ID {
            self.nmt(data, now);
        } else if (OBS_BASE_ID..OBS_BASE_ID + OBS_FRAMES as u16).contains(&id) {
            self.observation(usize::from(id - OBS_BASE_ID), data, now);
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
        if crc8(OBS_BASE_ID + k as u16, data) != data[0] || data[1] & 0x0F > COUNTER_MAX {
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

    fn bus_off(&mut self) {
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

    fn bus_recovered(&mut self) {
        if !self.bus_off {
            return;
        }
        self.bus_off = false;
        self.emcy(FaultCode::BusOff);
        self.heartbeat();
        self.safe_action();
    }
}

// ---------------------------------------------------------------------------------------------
// The run: drive the controller and the model, compare, check the invariants
// ---------------------------------------------------------------------------------------------

struct Run<'p> {
    controller: Controller<'p, WIDTH>,
    model: Model<'p>,
    clock: MockClock,
    /// Next alive counter per protected identifier the controller sends.
    tx_action: [u8; ACTION_FRAMES],
    tx_emcy: u8,
    tx_info: u8,
}

impl<'p> Run<'p> {
    /// Parses an outbox, checking invariants 3 and 6 on the way.
    fn parse(&mut self, out: &Outbox) -> Vec<Out> {
        assert!(out.len() <= 6, "{} frames in one outbox", out.len());
        let node = self.model.cfg.node_id;
        let mut parsed = Vec::new();
        let mut i = 0;
        while i < out.len() {
            let f = &out[i];
            let id = f
                .standard_id()
                .expect("the controller sends standard frames");
            let data = f.data();
            let sealed = |id: u16, data: &[u8], next: &mut u8| {
                assert_eq!(
                    data.len(),
                    8,
                    "protected frame {id:#x} of {} bytes",
                    data.len()
                );
                assert_eq!(crc8(id, data), data[0], "wrong CRC on sent frame {id:#x}");
                let counter = data[1] & 0x0F;
                assert_eq!(counter, *next, "alive counter of {id:#x}");
                *next = next_counter(*next);
            };
            if id == ACTION_BASE_ID {
                assert!(i + ACTION_FRAMES <= out.len(), "action frames split");
                let mut raw = [0i16; ACT_DIM];
                let sample = data[1] >> 4;
                for k in 0..ACTION_FRAMES {
                    let g = &out[i + k];
                    assert_eq!(g.standard_id(), Some(ACTION_BASE_ID + k as u16));
                    let d = g.data();
                    sealed(ACTION_BASE_ID + k as u16, d, &mut self.tx_action[k]);
                    assert_eq!(d[1] >> 4, sample, "action frames of one action disagree");
                    for s in 0..SIGNALS_PER_FRAME {
                        let j = k * SIGNALS_PER_FRAME + s;
                        let r = i16::from_le_bytes([d[2 + 2 * s], d[3 + 2 * s]]);
                        assert_ne!(r, RAW_NOT_AVAILABLE, "non-finite action sent (joint {j})");
                        if j < ACT_DIM {
                            raw[j] = r;
                        }
                    }
                }
                parsed.push(Out::Action { sample, raw });
                i += ACTION_FRAMES;
                continue;
            }
            if id == EMCY_BASE_ID + u16::from(node) {
                sealed(id, data, &mut self.tx_emcy);
                parsed.push(Out::Emcy {
                    code: u16::from_le_bytes([data[2], data[3]]),
                    fault: data[4],
                    state: data[5],
                });
            } else if id == POLICY_INFO_ID {
                sealed(id, data, &mut self.tx_info);
                parsed.push(Out::Info {
                    hash: u32::from_le_bytes([data[2], data[3], data[4], data[5]]),
                    version: data[6],
                    task: data[7],
                });
            } else if id == HEARTBEAT_BASE_ID + u16::from(node) {
                assert_eq!(data.len(), 5, "heartbeat length");
                assert_eq!(data[4], 0, "envelope status byte with the envelope off");
                let canopen = [
                    State::Boot,
                    State::PreOperational,
                    State::Operational,
                    State::SafeStop,
                    State::Fault,
                ]
                .iter()
                .find(|s| s.code() == data[2])
                .map(|s| s.canopen());
                assert_eq!(canopen, Some(data[0]), "heartbeat state bytes disagree");
                parsed.push(Out::Heartbeat {
                    canopen: data[0],
                    counter: data[1],
                    state: data[2],
                    fault: data[3],
                });
            } else {
                panic!("the controller sent frame id {id:#x}");
            }
            i += 1;
        }
        parsed
    }

    /// Runs one step on both, then checks everything.
    fn step(&mut self, event: Event, before: State, obs_nibble: Option<u8>, out: Outbox) {
        let parsed = self.parse(&out);
        let expected = std::mem::take(&mut self.model.out);
        let c = &self.controller;
        let after = c.state();

        // 1. Safe action whenever not operational.
        if after != State::Operational {
            assert!(
                c.last_action().iter().all(|&a| a == 0.0),
                "non-zero last action in {after:?}"
            );
            for o in &parsed {
                if let Out::Action { raw, .. } = o {
                    assert_eq!(raw, &[0; ACT_DIM], "non-zero action sent in {after:?}");
                }
            }
        }
        // 2. A policy action only answers an observation frame in Operational, with its nibble.
        for o in &parsed {
            if let Out::Action { sample, raw } = o
                && raw != &[0; ACT_DIM]
            {
                assert_eq!(event, Event::Observation, "policy action outside a sample");
                assert_eq!(
                    before,
                    State::Operational,
                    "policy action outside operational"
                );
                assert_eq!(
                    Some(*sample),
                    obs_nibble,
                    "action tagged with another sample"
                );
            }
        }
        // 3. Finite actions.
        assert!(c.last_action().iter().all(|a| a.is_finite()));
        // 5. Legal transitions.
        if before != after {
            use State::*;
            let legal = match event {
                Event::Poll => matches!(
                    (before, after),
                    (Boot, PreOperational) | (Operational, SafeStop)
                ),
                Event::Nmt(Some(NmtCommand::Start)) => {
                    matches!(before, PreOperational | SafeStop) && after == Operational
                }
                Event::Nmt(Some(NmtCommand::Stop)) => {
                    matches!(before, PreOperational | Operational) && after == SafeStop
                }
                Event::Nmt(Some(NmtCommand::EnterPreOperational)) => {
                    matches!(before, Operational | SafeStop) && after == PreOperational
                }
                Event::Nmt(Some(NmtCommand::ResetNode | NmtCommand::ResetCommunication)) => {
                    after == Boot
                }
                Event::Observation => before == Operational && matches!(after, SafeStop | Fault),
                Event::BusOff => (before, after) == (Operational, PreOperational),
                _ => false,
            };
            assert!(
                legal,
                "illegal transition {before:?} -> {after:?} on {event:?}"
            );
            // A state change is announced by a heartbeat carrying the new state (reset goes to
            // Boot silently: the boot-up heartbeat follows at the next cycle).
            if after != Boot {
                assert!(
                    parsed.iter().any(
                        |o| matches!(o, Out::Heartbeat { state, .. } if *state == after.code())
                    ),
                    "{before:?} -> {after:?} without a heartbeat"
                );
            }
        }
        if c.is_bus_off() || c.policy_info().is_none() {
            assert_ne!(
                after,
                State::Operational,
                "operational while bus-off or without policy"
            );
        }
        // 4. Watchdog.
        if event == Event::Poll && after == State::Operational {
            let age = self.clock.now_us() - self.model.last_obs_us;
            let limit = (u64::from(self.model.cfg.watchdog_cycles) + 1) * PERIOD;
            assert!(age < limit, "operational with an observation {age} us old");
        }
        count_step(before, after, &parsed);
        // Reference model: every frame, the state, the fault and the counters.
        assert_eq!(
            parsed, expected,
            "frames differ from the model's on {event:?}"
        );
        assert_eq!(after, self.model.state, "state differs from the model's");
        assert_eq!(
            c.fault(),
            self.model.fault,
            "latched fault differs from the model's"
        );
        assert_eq!(c.is_bus_off(), self.model.bus_off);
        assert_eq!(
            c.diagnostics(),
            &self.model.diag,
            "diagnostics differ from the model's"
        );
        assert_eq!(
            c.policy_info(),
            self.model.policy.as_ref().map(|p| p.info),
            "policy identity differs from the model's"
        );
        assert!(
            c.last_action()
                .iter()
                .zip(&self.model.action)
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "last action {:?} differs from the model's {:?}",
            c.last_action(),
            self.model.action
        );
    }

    fn deliver(&mut self, frame: CanFrame) {
        let now = self.clock.now_us();
        let id = frame.standard_id().expect("standard");
        let event = if id == NMT_ID {
            Event::Nmt(frame.data().first().and_then(|&c| NmtCommand::from_code(c)))
        } else if (OBS_BASE_ID..OBS_BASE_ID + OBS_FRAMES as u16).contains(&id) {
            Event::Observation
        } else {
            Event::Other
        };
        // An NMT frame for another node or of 0-1 bytes changes nothing; treat it as "other".
        let event = match event {
            Event::Nmt(_)
                if frame.data().len() < 2
                    || (frame.data()[1] != 0 && frame.data()[1] != self.model.cfg.node_id) =>
            {
                Event::Other
            }
            e => e,
        };
        if let Event::Nmt(Some(NmtCommand::ResetCommunication)) = event {
            self.tx_action = [0; ACTION_FRAMES];
            self.tx_emcy = 0;
            self.tx_info = 0;
        }
        let nibble =
            (event == Event::Observation && frame.data().len() >= 2).then(|| frame.data()[1] >> 4);
        let before = self.controller.state();
        self.model.frame(&frame, now);
        let out = self.controller.on_frame(&frame, &self.clock);
        self.step(event, before, nibble, out);
    }

    fn poll(&mut self) {
        let now = self.clock.now_us();
        let before = self.controller.state();
        self.model.poll(now);
        let out = self.controller.poll(&self.clock);
        self.step(Event::Poll, before, None, out);
    }

    /// `load_policy` on both; checks invariant 7.
    fn load(&mut self, view: &PolicyView<'p>, must_load: bool) {
        let before = self.controller.state();
        let info_before = self.controller.policy_info();
        let result = self.controller.load_policy(view);
        if self.model.state == State::Operational {
            assert!(
                matches!(result, Err(LoadError::Operational)),
                "load while operational: {result:?}"
            );
        } else {
            assert_eq!(result.is_ok(), must_load, "load result {result:?}");
        }
        stats::count(if result.is_ok() { 6 } else { 7 });
        match result {
            Ok(()) => {
                let mlp = Mlp::new(view).expect("a file the controller took evaluates");
                self.model.policy = Some(ActivePolicy {
                    mlp,
                    info: PolicyInfo {
                        layout_hash: view.header().layout_hash,
                        format_version: view.header().version,
                        task: view.body().task as u8,
                    },
                });
                self.model.announce = true;
            }
            Err(_) => assert_eq!(
                self.controller.policy_info(),
                info_before,
                "a refused load changed the policy"
            ),
        }
        self.step(Event::Load, before, None, Outbox::new());
    }
}

/// Whether a fresh controller takes `view` (the flash server's verification).
fn verifies(view: &PolicyView<'_>, cfg: ControllerConfig) -> bool {
    Controller::<WIDTH>::new(cfg).load_policy(view).is_ok()
}

/// What the inputs reached, counted when `DEX_FUZZ_STATS` is set (replay a corpus with
/// `-runs=0` to see that the sequences get past the E2E check to the policy and the faults).
mod stats {
    use std::sync::OnceLock;
    use std::sync::atomic::{AtomicU64, Ordering};

    pub const NAMES: [&str; 10] = [
        "policy actions",
        "observation timeouts",
        "non-finite observations",
        "out-of-range observations",
        "non-finite outputs (Fault)",
        "bus-off recoveries",
        "loads taken",
        "loads refused",
        "corrupted (resealed) files activated",
        "NMT starts into operational",
    ];
    pub static COUNTS: [AtomicU64; 10] = [const { AtomicU64::new(0) }; 10];

    pub fn on() -> bool {
        static ON: OnceLock<bool> = OnceLock::new();
        *ON.get_or_init(|| std::env::var_os("DEX_FUZZ_STATS").is_some())
    }

    pub fn count(i: usize) {
        if on() {
            COUNTS[i].fetch_add(1, Ordering::Relaxed);
        }
    }

    pub fn print() {
        if on() {
            let line: Vec<String> = NAMES
                .iter()
                .zip(&COUNTS)
                .map(|(n, c)| format!("{n}: {}", c.load(Ordering::Relaxed)))
                .collect();
            eprintln!("stats | {}", line.join(" | "));
        }
    }
}

/// Counts what one step reached (see [`stats`]).
fn count_step(before: State, after: State, parsed: &[Out]) {
    for o in parsed {
        match o {
            Out::Action { raw, .. } if raw != &[0; ACT_DIM] => stats::count(0),
            Out::Emcy { code: 0x8250, .. } => stats::count(1),
            Out::Emcy { code: 0xFF02, .. } => stats::count(2),
            Out::Emcy { code: 0xFF03, .. } => stats::count(3),
            Out::Emcy { code: 0xFF04, .. } => stats::count(4),
            Out::Emcy { code: 0x8140, .. } => stats::count(5),
            _ => {}
        }
    }
    if before != State::Operational && after == State::Operational {
        stats::count(9);
    }
}

fuzz_target!(|input: Input| {
    let images = images();
    let loadable = images.iter().filter(|i| i.loads).count();
    let cfg = ControllerConfig {
        node_id: 1 + input.node_id % 127,
        period_us: CONTROL_PERIOD_US,
        watchdog_cycles: u32::from(input.watchdog_cycles % 7),
        heartbeat_cycles: u32::from(input.heartbeat_cycles % 21),
        e2e_max_delta: input.e2e_max_delta % 15,
        // The model predicts the policy's actions bit for bit: the safety envelope, which rescales
        // them from the kinematics, is off here (its own tests: runtime/tests/envelope.rs).
        envelope: EnvelopeConfig {
            enabled: false,
            ..EnvelopeConfig::default()
        },
    };
    // Storage for verified files that match no prepared one; it outlives the controller.
    let mut pool: [Vec<u64>; POOL_SLOTS] = Default::default();
    let mut free = pool.iter_mut();
    let mut run = Run {
        controller: Controller::<WIDTH>::new(cfg),
        model: Model::new(cfg),
        clock: MockClock::new(1_000_000),
        tx_action: [0; ACTION_FRAMES],
        tx_emcy: 0,
        tx_info: 0,
    };
    if let Some(i) = input.initial_policy {
        let image = &images[usize::from(i) % loadable];
        let view = PolicyView::decode(image.bytes.as_bytes()).expect("prepared file decodes");
        run.load(&view, true);
    }
    let mut plant = Plant::default();
    let mut staging = Staging::Empty;
    for op in input.ops.iter().take(512) {
        match *op {
            Op::Sample { sample, values } => {
                let sample = plant.select(sample);
                for k in 0..OBS_FRAMES {
                    for f in plant.frames(k, sample, values, None) {
                        run.deliver(f);
                    }
                }
            }
            Op::Frames {
                sample,
                first,
                count,
                values,
                flaw,
                reverse,
            } => {
                let sample = plant.select(sample);
                let first = usize::from(first) % OBS_FRAMES;
                let last = (first + usize::from(count) % OBS_FRAMES).min(OBS_FRAMES - 1);
                let mut ks: Vec<usize> = (first..=last).collect();
                if reverse {
                    ks.reverse();
                }
                let flawed = flaw.map(|(at, f)| (usize::from(at) % ks.len(), f));
                for (n, &k) in ks.iter().enumerate() {
                    let f = flawed.and_then(|(at, f)| (at == n).then_some(f));
                    for frame in plant.frames(k, sample, values, f) {
                        run.deliver(frame);
                    }
                }
            }
            Op::Nmt { command, node } => {
                let code = match command {
                    NmtSel::Start => NmtCommand::Start.code(),
                    NmtSel::Stop => NmtCommand::Stop.code(),
                    NmtSel::PreOperational => NmtCommand::EnterPreOperational.code(),
                    NmtSel::ResetNode => NmtCommand::ResetNode.code(),
                    NmtSel::ResetCommunication => NmtCommand::ResetCommunication.code(),
                    NmtSel::Unknown(c) => c,
                };
                let node = match node {
                    NodeSel::All => 0,
                    NodeSel::Own => cfg.node_id,
                    NodeSel::Other(n) => n,
                };
                run.deliver(CanFrame::standard(NMT_ID, &[code, node]).expect("NMT frame"));
            }
            Op::Clock { step, poll } => {
                run.clock.advance(match step {
                    Step::Period => PERIOD,
                    Step::Periods(n) => PERIOD * u64::from(n % 8),
                    Step::Micros(us) => u64::from(us),
                    Step::Long(us) => u64::from(us),
                });
                if poll {
                    run.poll();
                }
            }
            Op::Poll => run.poll(),
            Op::BusOff => {
                let before = run.controller.state();
                run.model.bus_off();
                let out = run.controller.on_bus_off();
                run.step(Event::BusOff, before, None, out);
            }
            Op::BusRecovered => {
                let before = run.controller.state();
                run.model.bus_recovered();
                let out = run.controller.on_bus_recovered();
                run.step(Event::BusRecovered, before, None, out);
            }
            Op::FlashInit { image } => {
                staging = Staging::Receiving {
                    image: usize::from(image) % images.len(),
                    data: Vec::new(),
                };
            }
            Op::FlashData { segments } => {
                if let Staging::Receiving { image, data } = &mut staging {
                    let file = images[*image].bytes.as_bytes();
                    let end =
                        (data.len() + usize::from(segments % 1024) * SEGMENT_BYTES).min(file.len());
                    data.extend_from_slice(&file[data.len()..end]);
                }
            }
            Op::FlashCorrupt { offset, xor } => {
                if let Staging::Receiving { data, .. } = &mut staging
                    && !data.is_empty()
                {
                    let at = usize::from(offset) % data.len();
                    data[at] ^= xor;
                }
            }
            Op::FlashEnd { crc, reseal } => {
                let Staging::Receiving { image, mut data } =
                    std::mem::replace(&mut staging, Staging::Empty)
                else {
                    continue;
                };
                let file = images[image].bytes.as_bytes();
                if data.len() != file.len() {
                    continue;
                }
                if reseal {
                    let c = file_crc(&data);
                    data[CRC_OFFSET..CRC_OFFSET + 4].copy_from_slice(&c.to_le_bytes());
                }
                let claimed = match crc {
                    CrcSel::Sent => CRC32.checksum(&data),
                    CrcSel::Original => CRC32.checksum(file),
                    CrcSel::Wrong => CRC32.checksum(&data) ^ 1,
                };
                if claimed != CRC32.checksum(&data) {
                    continue;
                }
                let aligned = aligned_copy(&data);
                let ok =
                    PolicyView::decode(aligned.as_bytes()).is_ok_and(|view| verifies(&view, cfg));
                // 7. Corruption that kept the file CRC never verifies.
                if data[..] != file[..] && !reseal {
                    assert!(!ok, "a corrupted transfer verified");
                }
                if data[..] == file[..] {
                    assert_eq!(
                        ok, images[image].loads,
                        "prepared file {image} verification"
                    );
                }
                if ok {
                    staging = Staging::Verified { image, data };
                }
            }
            Op::FlashActivate => {
                let Staging::Verified { image, data } =
                    std::mem::replace(&mut staging, Staging::Empty)
                else {
                    continue;
                };
                if run.model.state == State::Operational {
                    // Refused before the file is looked at (the prepared file it came from stands
                    // in for it); the verified file stays for a later activation.
                    let view = PolicyView::decode(images[image].bytes.as_bytes()).expect("decodes");
                    run.load(&view, false);
                    staging = Staging::Verified { image, data };
                    continue;
                }
                let file = images[image].bytes.as_bytes();
                let bytes: &[u8] = if data[..] == file[..] {
                    file
                } else {
                    let Some(slot) = free.next() else { continue };
                    *slot = vec![0u64; data.len().div_ceil(8)];
                    let buf: &mut [u8] = bytemuck::cast_slice_mut(slot.as_mut_slice());
                    buf[..data.len()].copy_from_slice(&data);
                    let buf: &[u8] = buf;
                    &buf[..data.len()]
                };
                if bytes != file {
                    stats::count(8);
                }
                let view = PolicyView::decode(bytes).expect("verified file decodes");
                run.load(&view, true);
            }
            Op::FlashAbort => staging = Staging::Empty,
            Op::Load { image } => {
                let image = &images[usize::from(image) % images.len()];
                let view = PolicyView::decode(image.bytes.as_bytes()).expect("prepared file");
                run.load(&view, image.loads);
            }
            Op::Raw { id, data, len } => {
                let frame =
                    CanFrame::standard(id & 0x7FF, &data[..usize::from(len % 9)]).expect("frame");
                run.deliver(frame);
            }
        }
    }
    stats::print();
});
