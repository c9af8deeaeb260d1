//! Writes `can/jaco.dbc` from the codec's definitions: `cargo run -p dex-runtime --example make_dbc`.

use std::path::Path;

fn main() -> std::io::Result<()> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../can/jaco.dbc");
    std::fs::create_dir_all(path.parent().unwrap_or(Path::new(".")))?;
    let text = dex_runtime::dbc::generate(dex_runtime::ControllerConfig::default().node_id);
    std::fs::write(&path, text)?;
    println!("wrote {}", path.display());
    Ok(())
}
