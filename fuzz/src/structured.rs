//! The harness of the structure-aware controller target (`fuzz_targets/controller_structured.rs`,
//! issue 16, part 5).
//!
//! `controller_frames` feeds raw bytes, which almost never pass the E2E CRC, so it mostly exercises
//! the rejection paths. This target derives an operation sequence with `arbitrary` ([`Input`]) and
//! turns it into what a plant, an NMT master, a clock, a CAN driver and a flashing tool would do
//! ([`run_scenario`]):
//!
//! - observation frames sealed like the plant seals them (CRC-8/SAE-J1850 over the data id, alive
//!   counter, sample nibble), with values, counters and nibbles chosen by the fuzzer: whole samples,
//!   parts of samples interleaved with other operations, and flaws (a wrong CRC, a repeated, skipped
//!   or invalid counter, a short frame, a frame of another sample, a lost or duplicated frame, values
//!   "not available", saturated, at or beyond their plausible range);
//! - NMT commands (to this node, to all, to another node, unknown commands);
//! - clock steps (`MockClock`, the controller's only source of time) with or without a `poll`;
//! - bus-off and recovery reports from the driver;
//! - policy flashing as the controller sees it (the controller's own SDO program download into
//!   slots is the `program_download` target, `crate::program`): a transfer of one of several
//!   seeded synthetic policy files into a staging slot (init, data segments, corrupted bytes, end with a right or wrong transfer CRC,
//!   optionally with the file CRC recomputed so that corruption reaches the decoder), verification,
//!   activation with `Controller::load_policy`, abort; and direct loads of refused files (wrong
//!   period, wrong layout, over capacity).
//!
//! The controller starts with a real policy (f32, two-hidden-layer f32, int8, or one whose network
//! output is never finite) or none, and a configuration chosen by the fuzzer (watchdog 0..=6 cycles,
//! heartbeat 0..=20 cycles, E2E max delta 0..=14, node id).
//!
//! After every step the run checks the invariants listed in `checks.rs` and compares every frame,
//! the state, the fault and the diagnostic counters with the reference model of `model.rs`.
//!
//! Modules: `input` (the structured input and its decoding), `images` (the policy files),
//! `plant` (sealed observation frames), `flash` (staging and verification of transfers), `model`
//! (the reference model), `run` (the controller and the model in lockstep), `checks` (the invariants
//! and the comparison with the model), `stats` (what the inputs reached), `scenario` (the
//! operations played).

mod checks;
mod flash;
pub(crate) mod images;
mod input;
mod model;
mod plant;
mod run;
mod scenario;
mod stats;

use dex_runtime::interface::CONTROL_PERIOD_US;

pub use input::Input;
pub use scenario::run_scenario;

/// Evaluator capacity of the fuzzed controller (widest layer).
const WIDTH: usize = 64;
const PERIOD: u64 = CONTROL_PERIOD_US as u64;
