//! `dex-firmware`: the `dex-runtime` controller on a Cortex-M4F, checked bit for bit against the host.
//!
//! The policy file and an observation trace are embedded at build time (`build.rs`: `DEX_POLICY`,
//! `DEX_TRACE`). [`run`] decodes and validates the policy, then replays the trace twice:
//!
//! 1. through the evaluator alone ([`Mlp::act`]; a file that takes the task features gets them
//!    after the observation, as the controller gives them): one `A` line per step with the
//!    action's f32 bits, which must equal the host's goldens (`runtime/tests/golden/actions_64.f32`);
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
//! 3. with feature `slots`, the A/B policy slots ([`slots::replay_slots`]): the embedded policy in
//!    one of two static slots, the recorded flash transfer of another file (`DEX_FLASH`, frames
//!    of a real CANopen program download by `hil-sim`'s SDO client) fed to the controller's SDO
//!    server, which writes the inactive slot and activates it on the recorded start; the trace replayed before and after the swap (`P`/`R` and `Q`/`V` lines), and a transfer
//!    cut in the middle (then a reset) and one with a corrupt segment, both leaving the old slot
//!    active (`F` lines).
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
    ACTION_FRAMES, NmtCommand, OBS_FRAMES, action_frame_index, encode_observation, nmt_frame,
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
    /// The slot phase went wrong (feature `slots`): what, as a short text.
    Slots {
        /// What failed.
        what: &'static str,
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
            Fault::Slots { what } => write!(f, "slots: {what}"),
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
    /// Feature `slots`: one controller period with the policy in a slot (`on_frame_slots`).
    pub slot_controller: Stats,
    /// Feature `slots`: one SDO request frame of the recorded program download (a block segment;
    /// the end of the block download, which verifies the file, and the start are the maxima).
    pub flash_request: Stats,
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
            action_frame_index(ControllerConfig::default().node_id, id).map(|_| (id, f))
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
    #[cfg(feature = "slots")]
    slots::replay_slots(p, steps, overhead, &mut summary)?;
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
        // A policy that takes the task features gets them after the observation, as the
        // controller gives them (counted in the step: they are part of what it computes).
        let mut input = [0.0f32; dex_runtime::features::INPUT_MAX];
        let inputs = mlp.obs_dim();
        let (result, n) = p.measure(|| {
            let x = dex_runtime::features::policy_input(&obs, inputs, &mut input);
            mlp.act(x, &mut action)
        });
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
        let frames = encode_observation(cfg.node_id, &obs, step as u8, &mut senders);
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

/// The A/B slot phase (feature `slots`).
#[cfg(feature = "slots")]
pub mod slots {
    use dex_runtime::can::messages::{NmtCommand, OBS_FRAMES, encode_observation, nmt_frame};
    use dex_runtime::can::{CanFrame, E2eSender};
    use dex_runtime::canopen::program::{PROGRAM_CONTROL, control};
    use dex_runtime::canopen::sdo::abort_code;
    use dex_runtime::controller::{SDO_REQUEST_BASE, SDO_RESPONSE_BASE};
    use dex_runtime::interface::ACT_DIM;
    use dex_runtime::slots::SLOT_HEADER_BYTES;
    use dex_runtime::{Controller, ControllerConfig, MockClock, Network, PolicySlots, State};
    use dex_slot_mirror::SlotRegions;
    use embedded_can::Frame;

    use super::{
        Aligned, Bits, Fault, POLICY, Platform, Stats, Summary, TRACE, WIDTH, observation,
    };

    /// The recorded flash transfer (`DEX_FLASH`): 12 bytes a frame (direction, length, id u16 LE,
    /// 8 data bytes); direction 0 is a request to the controller, 1 its recorded response.
    pub static FLASH: &Aligned<[u8]> =
        &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/flash.bin")));

    /// Bytes of one slot region: header and 32 KiB of policy file.
    pub const REGION: usize = SLOT_HEADER_BYTES + 32 * 1024;

    /// The two static regions standing for two flash sectors (in `.bss`: erased at boot).
    static REGIONS: SlotRegions<REGION> = SlotRegions::new();

    /// Both regions, once per run.
    fn take() -> Option<(&'static mut [u8], &'static mut [u8])> {
        REGIONS.take()
    }

    /// Recorded frame `k`: (direction, frame).
    fn recorded(k: usize) -> Option<(u8, CanFrame)> {
        let r = FLASH.0.get(12 * k..12 * k + 12)?;
        let len = usize::from(r[1]).min(8);
        let frame = CanFrame::standard(u16::from_le_bytes([r[2], r[3]]), &r[4..4 + len])?;
        Some((r[0], frame))
    }

    fn fail(what: &'static str) -> Fault {
        Fault::Slots { what }
    }

    /// The controller's SDO responses (`0x580 + node`).
    const RESPONSE: u16 = SDO_RESPONSE_BASE + 0x10;

    /// An SDO response's bytes.
    fn bytes8(f: &CanFrame) -> [u8; 8] {
        let mut d = [0u8; 8];
        let n = f.data().len().min(8);
        d[..n].copy_from_slice(&f.data()[..n]);
        d
    }

    /// What feeding recorded requests did.
    struct Fed {
        /// The last SDO response.
        last: Option<[u8; 8]>,
        /// Responses that differ from the recording.
        mismatches: usize,
    }

    /// Feeds the recorded requests `0..until` (frames, in order) to the controller; `corrupt`
    /// flips a bit in that request. Responses are compared with the recorded ones.
    fn feed(
        p: &mut impl Platform,
        ctrl: &mut Controller<'static, WIDTH>,
        slots: &mut PolicySlots<'_>,
        until: usize,
        corrupt: Option<usize>,
        stats: &mut Stats,
        overhead: u32,
    ) -> Fed {
        let clock = MockClock::new(0);
        let mut fed = Fed {
            last: None,
            mismatches: 0,
        };
        let mut expect: Option<CanFrame> = None;
        let mut k = 0;
        let mut request = 0;
        while let Some((dir, frame)) = recorded(k) {
            k += 1;
            if dir == 1 {
                // A recorded response: what the controller must have answered.
                let same = expect
                    .take()
                    .is_some_and(|e| e.data() == frame.data() && e.id() == frame.id());
                fed.mismatches += usize::from(!same);
                continue;
            }
            if request == until {
                break;
            }
            let mut f = frame;
            if corrupt == Some(request) {
                let mut d = [0u8; 8];
                let n = f.data().len();
                d[..n].copy_from_slice(f.data());
                d[n - 1] ^= 0x10;
                let id = f.standard_id().unwrap_or(0);
                f = CanFrame::standard(id, &d[..n]).unwrap_or(f);
            }
            request += 1;
            let (out, n) = p.measure(|| ctrl.on_frame_slots(&f, &clock, slots));
            stats.add(n.map(|v| v.saturating_sub(overhead)));
            if let Some(r) = out.iter().find(|r| r.standard_id() == Some(RESPONSE)) {
                fed.last = Some(bytes8(r));
                expect = Some(*r);
            }
        }
        fed
    }

    /// Requests in the recording.
    fn requests() -> usize {
        (0..FLASH.0.len() / 12)
            .filter(|&k| matches!(recorded(k), Some((0, _))))
            .count()
    }

    /// The trace through the evaluator over the active slot's bytes (`tag` lines: exact f32
    /// observations, so the golden actions apply) and through the controller (`ctag` lines).
    fn replay(
        p: &mut impl Platform,
        ctrl: &mut Controller<'static, WIDTH>,
        slots: &mut PolicySlots<'_>,
        steps: usize,
        tags: (&str, &str),
        stats: &mut Stats,
        overhead: u32,
    ) -> Result<(), Fault> {
        let mut net = {
            let view =
                dex_policy::PolicyView::decode(slots.active_file()).map_err(Fault::Policy)?;
            Network::<WIDTH>::new(&view, slots.active_file()).map_err(Fault::Policy)?
        };
        for step in 0..steps {
            let obs = observation(&TRACE.0, step).ok_or(Fault::Trace { len: TRACE.0.len() })?;
            let mut action = [0.0f32; ACT_DIM];
            net.act(slots.active_file(), &obs, &mut action)
                .map_err(|error| Fault::Eval { step, error })?;
            p.line(format_args!("{} {step} {}", tags.0, Bits(&action)));
        }
        let cfg = ControllerConfig::default();
        let clock = MockClock::new(0);
        ctrl.poll(&clock);
        let mut senders = [E2eSender::default(); OBS_FRAMES];
        // One observation before the start: the controller's end-to-end counters follow this
        // fresh sender (not evaluated outside operational).
        if let Some(obs) = observation(&TRACE.0, 0) {
            for f in &encode_observation(cfg.node_id, &obs, 15, &mut senders) {
                ctrl.on_frame_slots(f, &clock, slots);
            }
        }
        ctrl.on_frame_slots(&nmt_frame(NmtCommand::Start, cfg.node_id), &clock, slots);
        for step in 0..steps {
            let obs = observation(&TRACE.0, step).ok_or(Fault::Trace { len: TRACE.0.len() })?;
            let frames = encode_observation(cfg.node_id, &obs, step as u8, &mut senders);
            clock.advance(u64::from(cfg.period_us));
            let ((), n) = p.measure(|| {
                ctrl.poll(&clock);
                for f in &frames {
                    ctrl.on_frame_slots(f, &clock, slots);
                }
            });
            stats.add(n.map(|v| v.saturating_sub(overhead)));
            if ctrl.state() != State::Operational {
                return Err(Fault::Controller {
                    step,
                    state: ctrl.state(),
                    fault: ctrl.fault(),
                });
            }
            p.line(format_args!(
                "{} {step} {}",
                tags.1,
                Bits(ctrl.last_action())
            ));
        }
        ctrl.on_frame_slots(&nmt_frame(NmtCommand::Stop, cfg.node_id), &clock, slots);
        Ok(())
    }

    /// The slot phase; see the crate documentation.
    pub fn replay_slots(
        p: &mut impl Platform,
        steps: usize,
        overhead: u32,
        summary: &mut Summary,
    ) -> Result<(), Fault> {
        let (a, b) = take().ok_or(fail("regions taken twice"))?;
        let mut slots = PolicySlots::mount(a, b).map_err(|_| fail("mount"))?;
        if slots.active().is_some() {
            return Err(fail("erased regions hold a policy"));
        }
        let cfg = ControllerConfig::default();
        let mut ctrl = Controller::<'static, WIDTH>::new(cfg);
        // Factory provisioning: the embedded policy written into a slot through the same API
        // program download uses.
        let file = &POLICY.0;
        slots
            .begin(file.len())
            .map_err(|_| fail("policy larger than a slot"))?;
        slots
            .write_at(0, file)
            .map_err(|_| fail("provisioning write"))?;
        slots
            .finish(|view, _| ctrl.check_policy(view))
            .map_err(|_| fail("provisioning verification"))?;
        ctrl.activate_slot(&mut slots)
            .map_err(|_| fail("provisioning activation"))?;
        let old_crc = slots.active_crc();
        p.stack_checkpoint("slots-provision");
        replay(
            p,
            &mut ctrl,
            &mut slots,
            steps,
            ("P", "R"),
            &mut summary.slot_controller,
            overhead,
        )?;
        p.stack_checkpoint("slots-before");

        let total = requests();
        // 1. Cut in the middle of the data, then a reset: the old slot is active.
        let fed = feed(
            p,
            &mut ctrl,
            &mut slots,
            total / 2,
            None,
            &mut summary.flash_request,
            overhead,
        );
        let (a, b) = slots.into_regions();
        slots = PolicySlots::mount(a, b).map_err(|_| fail("mount after the cut"))?;
        ctrl = Controller::<'static, WIDTH>::new(cfg);
        ctrl.attach_slots(&slots)
            .map_err(|_| fail("attach after the cut"))?;
        let cut_ok = slots.active_crc() == old_crc && fed.mismatches == 0;
        p.line(format_args!(
            "F cut requests={} of {total} active={:08x} old={}",
            total / 2,
            slots.active_crc(),
            cut_ok
        ));
        if !cut_ok {
            return Err(fail("a cut transfer changed the active slot"));
        }
        // 2. A corrupt segment (one bit in the middle block segment), fed up to the end of the
        // block download: its CRC-16 refuses it (abort 0x0504_0004); a start then finds nothing
        // to activate (0x0800_0024); the old slot stays active.
        let end = end_request().ok_or(fail("no end of block download in the recording"))?;
        let fed = feed(
            p,
            &mut ctrl,
            &mut slots,
            end + 1,
            Some(total / 2),
            &mut summary.flash_request,
            overhead,
        );
        let activate = feed_activate(p, &mut ctrl, &mut slots);
        let end_abort = fed.last.as_ref().and_then(|r| abort_code(r));
        let start_abort = activate.as_ref().and_then(|r| abort_code(r));
        let corrupt_ok = end_abort == Some(0x0504_0004)
            && start_abort == Some(0x0800_0024)
            && slots.active_crc() == old_crc;
        p.line(format_args!(
            "F corrupt end-abort={:08x?} start-abort={:08x?} active={:08x} old={}",
            end_abort,
            start_abort,
            slots.active_crc(),
            corrupt_ok
        ));
        if !corrupt_ok {
            return Err(fail("a corrupt transfer was not refused"));
        }
        // 3. The whole recording: every response as recorded, the new file active.
        let fed = feed(
            p,
            &mut ctrl,
            &mut slots,
            total,
            None,
            &mut summary.flash_request,
            overhead,
        );
        // The last response is the upload of 0x1F56:1: the new file's CRC-32, now active.
        let identified = fed.last.is_some_and(|r| {
            r[..4] == [0x43, 0x56, 0x1F, 1]
                && u32::from_le_bytes([r[4], r[5], r[6], r[7]]) == slots.active_crc()
        });
        let swapped = fed.mismatches == 0 && identified && slots.active_crc() != old_crc;
        p.line(format_args!(
            "F flash requests={total} mismatches={} last={:02x?} active={:08x} swapped={swapped}",
            fed.mismatches,
            fed.last,
            slots.active_crc()
        ));
        if !swapped {
            return Err(fail("the recorded flash did not activate"));
        }
        p.stack_checkpoint("slots-flash");
        replay(
            p,
            &mut ctrl,
            &mut slots,
            steps,
            ("Q", "V"),
            &mut summary.slot_controller,
            overhead,
        )?;
        p.stack_checkpoint("slots-after");
        Ok(())
    }

    /// The index (among the requests) of the recording's end-of-block-download request: the
    /// request the response 0xA1 answers.
    fn end_request() -> Option<usize> {
        let mut requests = 0usize;
        let mut k = 0;
        while let Some((dir, f)) = recorded(k) {
            k += 1;
            if dir == 0 {
                requests += 1;
            } else if f.data().first() == Some(&0xA1) {
                return requests.checked_sub(1);
            }
        }
        None
    }

    /// Sends program control 0x1F51:1 = 1 (start); the response.
    fn feed_activate(
        p: &mut impl Platform,
        ctrl: &mut Controller<'static, WIDTH>,
        slots: &mut PolicySlots<'_>,
    ) -> Option<[u8; 8]> {
        let _ = p;
        let i = PROGRAM_CONTROL.to_le_bytes();
        let f = CanFrame::standard(
            SDO_REQUEST_BASE + 0x10,
            &[0x2F, i[0], i[1], 1, control::START, 0, 0, 0],
        )?;
        let out = ctrl.on_frame_slots(&f, &MockClock::new(0), slots);
        out.iter()
            .find(|r| r.standard_id() == Some(RESPONSE))
            .map(bytes8)
    }
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
            if (step + j) % 3 == 0 {
                joint.max
            } else {
                joint.min
            }
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
