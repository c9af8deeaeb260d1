//! Writes `can/jaco.dbc` and its CAN FD variant `can/jaco_fd.dbc` from the codec's definitions:
//! `cargo run -p dex-runtime --example make_dbc`.

use std::path::Path;

fn main() -> std::io::Result<()> {
    let node = dex_runtime::ControllerConfig::default().node_id;
    for (name, text) in [
        ("jaco.dbc", dex_runtime::dbc::generate(node)),
        ("jaco_fd.dbc", dex_runtime::dbc::generate_fd(node)),
    ] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../can")
            .join(name);
        std::fs::create_dir_all(path.parent().unwrap_or(Path::new(".")))?;
        std::fs::write(&path, text)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
