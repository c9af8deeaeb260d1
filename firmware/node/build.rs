//! Puts the memory map of the chosen target on the linker search path: `boards/netduinoplus2-qemu`
//! (the 192 KB of SRAM QEMU models) for feature `qemu`, `boards/netduinoplus2` (the STM32F405's
//! 128 KB main SRAM) for feature `board`.

use std::env;
use std::error::Error;
use std::fs;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn Error>> {
    let manifest = PathBuf::from(env::var("CARGO_MANIFEST_DIR")?);
    let out = PathBuf::from(env::var("OUT_DIR")?);
    let board = if env::var_os("CARGO_FEATURE_BOARD").is_some() {
        "netduinoplus2"
    } else {
        "netduinoplus2-qemu"
    };
    if env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let map = manifest.join("../boards").join(board).join("memory.x");
        println!("cargo::rerun-if-changed={}", map.display());
        fs::copy(&map, out.join("memory.x"))
            .map_err(|e| format!("board map {}: {e}", map.display()))?;
        println!("cargo::rustc-link-search={}", out.display());
    }
    Ok(())
}
