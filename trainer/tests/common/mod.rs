//! Helpers shared by the tests that run the `trainer` binary (each test file uses some of them).

#![allow(dead_code, clippy::expect_used)]

use std::path::PathBuf;
use std::process::{Command, Output};

/// Runs `trainer ARGS` to the end and returns what it printed.
pub fn trainer(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_trainer"))
        .args(args)
        .output()
        .expect("run trainer")
}

/// A command's stdout and stderr together, for assertions and failure messages.
pub fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// A path in the temporary folder for this test process, `dex-{group}-{name}-{pid}`, with whatever
/// an earlier run left there removed (the folder itself is not made: `trainer train --out` makes it).
pub fn fresh_path(group: &str, name: &str) -> PathBuf {
    let p = std::env::temp_dir().join(format!("dex-{group}-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&p);
    p
}
