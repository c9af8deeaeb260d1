//! Writes the committed golden policy files. Run after an intentional format change:
//! `cargo run -p dex-policy --features std --example make_format_golden`
//! then review the diff and bump the format version if the bytes changed (docs/policy-format.md).
//!
//! - `small.dxpl`: version 1 (all-f32), the compatibility fixture; its bytes must never change.
//! - `small_int8.dxpl`: version 2, the same policy with both layers quantised to int8.

use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    std::fs::create_dir_all(&dir)?;
    let files = [
        (
            "small.dxpl",
            dex_policy::synth::synth_policy(&dex_policy::synth::golden_small_spec())?,
        ),
        ("small_int8.dxpl", dex_policy::synth::golden_small_int8()?),
    ];
    for (name, bytes) in files {
        std::fs::write(dir.join(name), &bytes)?;
        println!(
            "wrote {} bytes to {}",
            bytes.len(),
            dir.join(name).display()
        );
    }
    Ok(())
}
