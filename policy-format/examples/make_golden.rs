//! Writes the committed golden policy files. Run after an intentional format change:
//! `cargo run -p dex-policy --features std --example make_golden`
//! then review the diff and bump the format version if the bytes changed (docs/policy-format.md).

use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    std::fs::create_dir_all(&dir)?;
    let bytes = dex_policy::synth::synth_policy(&dex_policy::synth::golden_small_spec())?;
    std::fs::write(dir.join("small.dxpl"), &bytes)?;
    println!(
        "wrote {} bytes to {}",
        bytes.len(),
        dir.join("small.dxpl").display()
    );
    Ok(())
}
