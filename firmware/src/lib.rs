//! `dex-firmware`: the `dex-runtime` controller on a Cortex-M4F, checked bit for bit against the host.
//!
//! The policy file and an observation trace are embedded at build time (`build.rs`: `DEX_POLICY`,
//! `DEX_TRACE`). [`run`] decodes and validates the policy, then replays the trace twice:
//!
//! 1. through the evaluator alone ([`Mlp::act`]): one `A` line per step with the action's f32 bits,
//!    which must equal the host's goldens (`runtime/tests/golden/actions_64.f32`);
//! 2. through the full [`Controller`]: NMT start, then per step one control period of the mock
//!    clock and the observation as end-to-end-protected CAN frames; one `C` line per step with the
//!    controller's action bits and the action frames it sent (the controller runs its safety
//!    envelope, on by default, after the policy);
//! 3. through the safety envelope alone, on a saturated command that changes sign from step to
//!    step: one `E` line per step with the scale, the limits that bound and the action bits.
//!
//! The policy may be f32 (format version 1) or int8 (version 2, post-training quantised by the
//! exporter): the runtime's evaluator picks the kernel from the file, so both paths run int8 files
//! exactly as a product controller would.
//!
//! Everything here is target-independent and `no_std`: the board binary (`src/main.rs`) and the
//! host twin (`host/`) call the same [`run`] with their own [`Platform`], so their `A` and `C`
//! lines must be identical. The board adds instruction counts per step (`I` lines) and the stack
//! high-water mark. This crate does not drive a CAN peripheral or a real clock.
#![no_std]

use core::fmt;

use dex_policy::{FormatError, PolicyView};
use dex_runtime::can::CanFrame;
use dex_runtime::can::E2eSender;
use dex_runtime::can::messages::{
    ACTION_BASE_ID, ACTION_FRAMES, NmtCommand, OBS_FRAMES, encode_observation, nmt_frame,
};
use dex_runtime::envelope::{Envelope, EnvelopeConfig};
use dex_runtime::interface::{ACT_DIM, ACTION_JOINTS, OBS_DIM};
use dex_runtime::{
    Controller, ControllerConfig, EvalError, FaultCode, LoadError, Mlp, MockClock, State,
};
use embedded_can::Frame;

/// Widest layer (or input) the firmware's evaluator accepts: 2 x 1 kB of activations.
pub const WIDTH: usize = 256;

/// Bytes with 4-byte alignment, so the policy's values can be borrowed as `&[f32]` in place.
#[repr(C, align(4))]
pub struct Aligned<T: ?Sized>(pub T);

/// The embedded policy file (`DEX_POLICY` at build time).
pub static POLICY: &Aligned<[u8]> =
    &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/policy.bin")));

/// The embedded observation trace (`DEX_TRACE` at build time): little-endian f32,
/// [`OBS_DIM`] per step.
pub static TRACE: &Aligned<[u8]> =
    &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/trace.bin")));

/// Name of the board the memory map was chosen for (`DEX_BOARD` at build time).
pub const BOARD: &str = env!("DEX_BOARD_NAME");

/// What the firmware runs on: where report lines go and how time is measured.
pub trait Platform {
    /// Writes one report line (the platform adds the newline).
    fn line(&mut self, args: fmt::Arguments<'_>);

    /// Runs `f`; returns its result and the guest instructions it took, where measurable.
    fn measure<R>(&mut self, f: impl FnOnce() -> R) -> (R, Option<u32>);

    /// Ends a phase of the run: a board reports the deepest stack use since the previous
    /// checkpoint (or boot) under `phase` and starts measuring afresh. The host does nothing.
    fn stack_checkpoint(&mut self, phase: &str) {
        let _ = phase;
    }
}

/// Why the firmware stopped in its fault state.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum Fault {
    /// The embedded policy file failed to decode or validate, or does not fit the evaluator.
    Policy(FormatError),
    /// The controller refused the policy (layout, control period or capacity).
    Load(LoadError),
    /// The embedded trace is empty or not a whole number of observations.
    Trace {
        /// Length of the trace in bytes.
        len: usize,
    },
    /// The evaluator refused an observation or produced a non-finite action.
    Eval {
        /// Step of the trace.
        step: usize,
        /// The evaluator's error.
        error: EvalError,
    },
    /// The controller left operational while replaying the trace.
    Controller {
        /// Step of the trace.
        step: usize,
        /// State it was in.
        state: State,
        /// Its latched fault code.
        fault: FaultCode,
    },
}

impl fmt::Display for Fault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Fault::Policy(e) => write!(f, "policy file rejected: {e}"),
            Fault::Load(e) => write!(f, "controller refused the policy: {e}"),
            Fault::Trace { len } => write!(
                f,
                "trace of {len} bytes is not a whole, non-zero number of {OBS_DIM}-value observations"
            ),
            Fault::Eval { step, error } => write!(f, "step {step}: evaluator: {error}"),
            Fault::Controller { step, state, fault } => write!(
                f,
                "step {step}: controller in {state:?} with fault {fault:?} (code {})",
                fault.code()
            ),
        }
    }
}

/// Minimum, maximum and sum of per-step instruction counts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Steps measured.
    pub count: u32,
    /// Fewest instructions in one step.
    pub min: u32,
    /// Most instructions in one step.
    pub max: u32,
    /// Sum over all measured steps.
    pub sum: u64,
}

impl Stats {
    fn add(&mut self, value: Option<u32>) {
        let Some(v) = value else { return };
        self.min = if self.count == 0 { v } else { self.min.min(v) };
        self.max = self.max.max(v);
        self.sum += u64::from(v);
        self.count += 1;
    }

    /// Mean instructions per step (0 when nothing was measured).
    pub fn mean(&self) -> u64 {
        self.sum.checked_div(u64::from(self.count)).unwrap_or(0)
    }
}

/// What a successful run measured.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Summary {
    /// Steps replayed (per path).
    pub steps: usize,
    /// Instructions of one evaluator call ([`Mlp::act`]).
    pub mlp: Stats,
    /// Instructions of one controller period: `poll` plus all observation frames, the last of
    /// which runs the evaluator and encodes the action frames.
    pub controller: Stats,
    /// Instructions of one safety-envelope call ([`Envelope::apply`]) on an adversarial command.
    pub envelope: Stats,
}

/// Hex words of an f32 slice, for report lines.
struct Bits<'a>(&'a [f32]);

impl fmt::Display for Bits<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, v) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            write!(f, "{:08x}", v.to_bits())?;
        }
        Ok(())
    }
}

/// The action frames among `self.0`, each as ` ID:BYTES` in hex.
struct ActionFrames<'a>(&'a [CanFrame]);

impl ActionFrames<'_> {
    fn iter(&self) -> impl Iterator<Item = (u16, &CanFrame)> {
        self.0.iter().filter_map(|f| {
            let id = f.standard_id()?;
            let k = id.checked_sub(ACTION_BASE_ID)?;
            (usize::from(k) < ACTION_FRAMES).then_some((id, f))
        })
    }

    fn count(&self) -> usize {
        self.iter().count()
    }
}

impl fmt::Display for ActionFrames<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (id, frame) in self.iter() {
            write!(f, " {id:03x}:")?;
            for b in frame.data() {
                write!(f, "{b:02x}")?;
            }
        }
        Ok(())
    }
}

/// Observation `step` of the embedded trace, if the trace has it.
fn observation(trace: &[u8], step: usize) -> Option<[f32; OBS_DIM]> {
    let bytes = trace.get(step * OBS_DIM * 4..(step + 1) * OBS_DIM * 4)?;
    let mut obs = [0.0f32; OBS_DIM];
    for (o, b) in obs.iter_mut().zip(bytes.chunks_exact(4)) {
        *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    }
    Some(obs)
}

/// Boots the controller on the embedded policy and replays the embedded trace (see the crate docs).
pub fn run(p: &mut impl Platform) -> Result<Summary, Fault> {
    let view = PolicyView::decode(&POLICY.0).map_err(Fault::Policy)?;
    let body = view.body();
    p.line(format_args!(
        "H board={BOARD} bytes={} version={} obs={} act={} values={} layers={} weight_bytes={}",
        POLICY.0.len(),
        view.header().version,
        body.obs_dim(),
        body.act_dim(),
        view.values().len(),
        body.layers.len(),
        view.weight_bytes(),
    ));
    for (i, l) in view.layers().enumerate() {
        let dtype = match l.dtype {
            dex_policy::LayerDtype::F32 => "f32",
            dex_policy::LayerDtype::Int8 => "int8",
        };
        p.line(format_args!("L {i} {}x{} {dtype}", l.inputs, l.outputs));
    }
    for (i, j) in body.action.iter().enumerate() {
        p.line(format_args!("J {i} {}", Bits(&[j.min, j.max])));
    }
    let steps = TRACE.0.len() / (OBS_DIM * 4);
    if steps == 0 || !TRACE.0.len().is_multiple_of(OBS_DIM * 4) {
        return Err(Fault::Trace { len: TRACE.0.len() });
    }
    let mut summary = Summary {
        steps,
        ..Summary::default()
    };
    // Overhead of the measurement itself, taken off every count.
    let ((), overhead) = p.measure(|| ());
    p.stack_checkpoint("decode");
    let overhead = overhead.unwrap_or(0);
    // Two separate frames, so the stack peak is the larger of the two paths, not their sum.
    summary.mlp = replay_evaluator(p, &view, steps, overhead)?;
    summary.controller = replay_controller(p, &view, steps, overhead)?;
    summary.envelope = replay_envelope(p, steps, overhead)?;
    Ok(summary)
}

/// Path 1: the evaluator alone, on the exact f32 observations (`A` lines).
#[inline(never)]
fn replay_evaluator(
    p: &mut impl Platform,
    view: &PolicyView<'static>,
    steps: usize,
    overhead: u32,
) -> Result<Stats, Fault> {
    let mut stats = Stats::default();
    let mut mlp = Mlp::<WIDTH>::new(view).map_err(Fault::Policy)?;
    p.stack_checkpoint("evaluator-load");
    for step in 0..steps {
        let obs = observation(&TRACE.0, step).ok_or(Fault::Trace { len: TRACE.0.len() })?;
        let mut action = [0.0f32; ACT_DIM];
        let (result, n) = p.measure(|| mlp.act(&obs, &mut action));
        result.map_err(|error| Fault::Eval { step, error })?;
        stats.add(n.map(|v| v.saturating_sub(overhead)));
        p.line(format_args!("A {step} {}", Bits(&action)));
    }
    p.stack_checkpoint("evaluator-steps");
    Ok(stats)
}

/// Path 2: the full controller, CAN frames in and out, one control period per step (`C` lines).
#[inline(never)]
fn replay_controller(
    p: &mut impl Platform,
    view: &PolicyView<'static>,
    steps: usize,
    overhead: u32,
) -> Result<Stats, Fault> {
    let mut stats = Stats::default();
    let cfg = ControllerConfig::default();
    let mut ctrl = Controller::<WIDTH>::new(cfg);
    ctrl.load_policy(view).map_err(Fault::Load)?;
    let clock = MockClock::new(0);
    ctrl.poll(&clock);
    ctrl.on_frame(&nmt_frame(NmtCommand::Start, cfg.node_id), &clock);
    p.stack_checkpoint("controller-load");
    let mut senders = [E2eSender::default(); OBS_FRAMES];
    for step in 0..steps {
        let obs = observation(&TRACE.0, step).ok_or(Fault::Trace { len: TRACE.0.len() })?;
        let frames = encode_observation(&obs, step as u8, &mut senders);
        clock.advance(u64::from(cfg.period_us));
        let (sent, n) = p.measure(|| {
            ctrl.poll(&clock);
            let mut sent = dex_runtime::Outbox::new();
            for f in &frames {
                let out = ctrl.on_frame(f, &clock);
                if !out.is_empty() {
                    sent = out;
                }
            }
            sent
        });
        stats.add(n.map(|v| v.saturating_sub(overhead)));
        if ctrl.state() != State::Operational {
            return Err(Fault::Controller {
                step,
                state: ctrl.state(),
                fault: ctrl.fault(),
            });
        }
        let actions = ActionFrames(&sent);
        if actions.count() != ACTION_FRAMES {
            return Err(Fault::Controller {
                step,
                state: ctrl.state(),
                fault: ctrl.fault(),
            });
        }
        p.line(format_args!(
            "C {step} {} |{actions}",
            Bits(ctrl.last_action())
        ));
    }
    p.stack_checkpoint("controller-steps");
    Ok(stats)
}

/// Path 3: the safety envelope alone (`E` lines), on each observation of the trace with a
/// saturated command whose signs change from step to step (the envelope's worst case: limits bind
/// and the position search bisects).
#[inline(never)]
fn replay_envelope(p: &mut impl Platform, steps: usize, overhead: u32) -> Result<Stats, Fault> {
    let mut stats = Stats::default();
    let mut envelope = Envelope::new(
        EnvelopeConfig::jaco(),
        ControllerConfig::default().period_us,
    );
    for step in 0..steps {
        let obs = observation(&TRACE.0, step).ok_or(Fault::Trace { len: TRACE.0.len() })?;
        let mut action: [f32; ACT_DIM] = core::array::from_fn(|j| {
            let joint = &ACTION_JOINTS[j];
            if (step + j) % 3 == 0 { joint.max } else { joint.min }
        });
        let (outcome, n) = p.measure(|| envelope.apply(&obs, &mut action));
        stats.add(n.map(|v| v.saturating_sub(overhead)));
        p.line(format_args!(
            "E {step} {:08x} {:02x} {}",
            outcome.scale.to_bits(),
            outcome.limits,
            Bits(&action)
        ));
    }
    p.stack_checkpoint("envelope-steps");
    Ok(stats)
}
