//! Writes `tests/can/vectors.json`, the bytes and signal values that the Python cantools test
//! checks against `can/jaco.dbc`: `cargo run -p dex-runtime --example make_can_vectors`.

use std::path::Path;

fn main() -> std::io::Result<()> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/can/vectors.json");
    std::fs::create_dir_all(path.parent().unwrap_or(Path::new(".")))?;
    std::fs::write(&path, dex_runtime::testkit::can_vectors_json())?;
    println!("wrote {}", path.display());
    Ok(())
}
