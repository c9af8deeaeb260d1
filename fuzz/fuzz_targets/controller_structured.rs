//! Structure-aware fuzzing of the controller's logic (issue 16, part 5): operation sequences
//! derived with `arbitrary` (sealed observation frames, NMT, clock, bus-off and flashing) played
//! into a controller with a real policy, with invariants and a reference model checked after every
//! step. The harness is `dex_fuzz::structured` (`fuzz/src/structured/`).
#![no_main]

use dex_fuzz::structured::{Input, run_scenario};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: Input| run_scenario(&input));
