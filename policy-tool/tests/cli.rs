//! The `policy` command line: inspect prints the metadata, verify accepts good and refuses bad files.
#![cfg(feature = "cli")]
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_policy");
const GOLDEN: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../policy-format/tests/golden/small.dxpl"
);

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

#[test]
fn quantise_writes_the_int8_twin_and_refuses_bad_input() {
    let dir = std::env::temp_dir();
    let out = dir.join(format!("dex-cli-q-{}.dxpl", std::process::id()));
    let o = Command::new(BIN)
        .arg("quantise")
        .arg(GOLDEN)
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("format version 2"), "{text}");
    // The golden's random weights are not on the grid.
    assert!(text.contains("not on the int8 grid"), "{text}");
    let bytes = std::fs::read(&out).unwrap();
    let view = dex_policy::PolicyView::decode(&bytes).unwrap();
    assert!(view.body().has_int8());
    assert_eq!(view.body().provenance.success_rate, None);
    // Quantising the int8 file again copies it.
    let twice = dir.join(format!("dex-cli-q2-{}.dxpl", std::process::id()));
    let o = Command::new(BIN)
        .arg("quantise")
        .arg(&out)
        .arg(&twice)
        .output()
        .unwrap();
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stdout).contains("already int8"));
    assert_eq!(std::fs::read(&twice).unwrap(), bytes);
    let _ = std::fs::remove_file(&out);
    let _ = std::fs::remove_file(&twice);
    // A damaged input is refused with the reason, and nothing is written.
    let mut bad = std::fs::read(GOLDEN).unwrap();
    bad[100] ^= 0x04;
    let bad_path = dir.join(format!("dex-cli-qbad-{}.dxpl", std::process::id()));
    std::fs::write(&bad_path, &bad).unwrap();
    let o = Command::new(BIN)
        .arg("quantise")
        .arg(&bad_path)
        .arg(&out)
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&bad_path);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("CRC-32"));
    assert!(!out.exists());
}
