//! Picks the board's memory map and embeds the policy file and the observation trace.
//!
//! - `DEX_BOARD`: a folder under `boards/` (default `mps2-an386`); its `memory.x` goes on the
//!   linker search path. Only for bare-metal targets: host builds of the library need none.
//! - `DEX_POLICY`: the policy file to embed (default: the runtime's golden 44-64-64-9 policy).
//! - `DEX_TRACE`: observations, little-endian f32, 44 per step (default: the golden trace).
//! - `DEX_FLASH`: a recorded flash transfer for feature `slots` (default: the golden recording
//!   `runtime/tests/golden/flash_int8.frames`, `hil-sim/tests/flash_golden.rs`).
//!
//! Relative paths are taken from this crate's folder (`firmware/`).

use std::env;
use std::error::Error;
use std::fs;
use std::path::{Path, PathBuf};

/// Boards with a memory map under `boards/`.
const BOARDS: &[&str] = &["mps2-an386", "netduinoplus2"];

fn main() -> Result<(), Box<dyn Error>> {
    let manifest = PathBuf::from(env::var("CARGO_MANIFEST_DIR")?);
    let out = PathBuf::from(env::var("OUT_DIR")?);
    let golden = manifest.join("../runtime/tests/golden");

    embed(
        &manifest,
        &out,
        "DEX_POLICY",
        &golden.join("jaco_64.dxpl"),
        "policy.bin",
    )?;
    embed(
        &manifest,
        &out,
        "DEX_TRACE",
        &golden.join("obs_trace.f32"),
        "trace.bin",
    )?;
    embed(
        &manifest,
        &out,
        "DEX_FLASH",
        &golden.join("flash_int8.frames"),
        "flash.bin",
    )?;

    println!("cargo::rerun-if-env-changed=DEX_BOARD");
    println!("cargo::rustc-check-cfg=cfg(dex_board, values(\"mps2-an386\", \"netduinoplus2\"))");
    let board = env::var("DEX_BOARD").unwrap_or_else(|_| String::from("mps2-an386"));
    if !BOARDS.contains(&board.as_str()) {
        return Err(format!("DEX_BOARD={board}: unknown board (known: {BOARDS:?})").into());
    }
    println!("cargo::rustc-cfg=dex_board=\"{board}\"");
    println!("cargo::rustc-env=DEX_BOARD_NAME={board}");
    if env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        // Keep the map in a subfolder and copy it: a stray memory.x in the crate root would
        // silently win the linker's search and the image would lock up.
        let map = manifest.join("boards").join(&board).join("memory.x");
        println!("cargo::rerun-if-changed={}", map.display());
        fs::copy(&map, out.join("memory.x"))
            .map_err(|e| format!("board map {}: {e}", map.display()))?;
        println!("cargo::rustc-link-search={}", out.display());
    }
    Ok(())
}

/// Copies the file named by `var` (or `default`) to `OUT_DIR/name` for `include_bytes!`.
fn embed(
    manifest: &Path,
    out: &Path,
    var: &str,
    default: &Path,
    name: &str,
) -> Result<(), Box<dyn Error>> {
    println!("cargo::rerun-if-env-changed={var}");
    let path = match env::var_os(var) {
        Some(p) if !p.is_empty() => manifest.join(p),
        _ => default.to_path_buf(),
    };
    println!("cargo::rerun-if-changed={}", path.display());
    fs::copy(&path, out.join(name)).map_err(|e| format!("{var}={}: {e}", path.display()))?;
    Ok(())
}
