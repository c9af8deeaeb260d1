//! The controller's own flashing path (issue #29): its CiA 301 SDO server with CiA 302-3 program
//! download into two policy slots, driven by well-formed and arbitrary SDO requests, program
//! control, NMT, observations, clock steps and power cuts, with a reference model checked after
//! every step: the active policy is the previous one or a file downloaded whole, verified and
//! started, never a partial one. The harness is `dex_fuzz::program` (`fuzz/src/program.rs`).
#![no_main]

use dex_fuzz::program::{ProgramInput, run_program};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: ProgramInput| run_program(&input));
