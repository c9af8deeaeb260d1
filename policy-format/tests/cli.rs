//! The `policy` command line: inspect prints the metadata, verify accepts good and refuses bad files.
#![cfg(feature = "cli")]
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_policy");
const GOLDEN: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/golden/small.dxpl");

#[test]
fn inspect_prints_metadata_sizes_and_checksum() {
    let out = Command::new(BIN)
        .args(["inspect", GOLDEN])
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    for needle in [
        "format version  1",
        "crc32           0x",
        "task            Grasp",
        "network         5 -> 8 relu -> 3 tanh",
        "stored values   85 f32 (340 bytes)",
        "brick_pos",
    ] {
        assert!(text.contains(needle), "missing {needle:?} in\n{text}");
    }
}

#[test]
fn verify_accepts_good_and_refuses_corrupt_files() {
    let ok = Command::new(BIN).args(["verify", GOLDEN]).output().unwrap();
    assert!(ok.status.success());
    let mut bytes = std::fs::read(GOLDEN).unwrap();
    bytes[100] ^= 0x04;
    let bad = std::env::temp_dir().join(format!("dex-cli-{}.dxpl", std::process::id()));
    std::fs::write(&bad, &bytes).unwrap();
    let out = Command::new(BIN).arg("verify").arg(&bad).output().unwrap();
    let _ = std::fs::remove_file(&bad);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("CRC-32"));
    let missing = Command::new(BIN)
        .args(["verify", "/nonexistent.dxpl"])
        .output()
        .unwrap();
    assert!(!missing.status.success());
    assert!(String::from_utf8_lossy(&missing.stderr).contains("cannot read"));
}
