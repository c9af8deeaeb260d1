//! Harness code of the fuzz targets in `fuzz_targets/` (a library of the `dex-fuzz` package, so
//! that each target file holds only its `fuzz_target!` entry).
#![warn(missing_docs)]

pub mod program;
pub mod structured;
