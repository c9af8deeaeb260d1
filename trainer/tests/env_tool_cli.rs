//! `env-tool` from the command line: clap's usage errors (exit 2) for unknown commands, unknown
//! flags and bad values, `--help`, and one cheap real command (a short `trace` on Reach; needs
//! MuJoCo).

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;
use common::{env_tool, text};

/// A command-line error: exit 2 and an `error:` message naming `what` (with the usage line when
/// `usage`; clap leaves it out for a bad value).
fn assert_cli_error(args: &[&str], what: &str, usage: bool) {
    let o = env_tool(args);
    let t = text(&o);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {t}");
    assert!(t.contains("error:"), "{args:?} should say error: {t}");
    assert!(t.contains(what), "{args:?} should name {what:?}: {t}");
    if usage {
        assert!(t.contains("Usage:"), "{args:?} should print usage: {t}");
    }
}

#[test]
fn unknown_commands_flags_and_values_are_usage_errors() {
    assert_cli_error(&["juggle"], "juggle", true);
    assert_cli_error(
        &["demo", "--task", "reach", "--episodez", "1"],
        "--episodez",
        true,
    );
    assert_cli_error(&["trace", "--task", "reach"], "--out", true);
    assert_cli_error(&["bench", "--mode", "fast"], "fast", false);
    assert_cli_error(&["demo", "--task", "juggle"], "juggle", false);
    assert_cli_error(&["demo", "--episodes", "many"], "many", false);
    // No command at all is not a silent success either.
    let o = env_tool(&[]);
    assert_ne!(o.status.code(), Some(0), "{}", text(&o));
    assert!(text(&o).contains("Usage:"), "{}", text(&o));
}

#[test]
fn help_lists_the_commands_and_their_flags() {
    let o = env_tool(&["--help"]);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    for cmd in ["demo", "bench", "record", "trace"] {
        assert!(t.contains(cmd), "--help should list {cmd}: {t}");
    }
    let o = env_tool(&["trace", "--help"]);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    for flag in [
        "--task", "--reward", "--seed", "--steps", "--noise", "--out",
    ] {
        assert!(t.contains(flag), "trace --help should list {flag}: {t}");
    }
    assert!(t.contains("[default: reach]"), "{t}");
}

#[test]
fn a_short_trace_on_reach_is_written() {
    let dir = std::env::temp_dir().join(format!("dex-env-tool-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("trace.json");
    let o = env_tool(&[
        "trace",
        "--task",
        "reach",
        "--seed",
        "7",
        "--steps",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let doc: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!(doc["seed"], 7);
    assert_eq!(doc["steps"].as_array().map(Vec::len), Some(2));
    // Written atomically: nothing but the trace in the folder.
    let names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, ["trace.json"]);
    std::fs::remove_dir_all(&dir).unwrap();
}
