//! `trainer train` from the command line: a tiny run, refusal to overwrite, resume checks on the
//! learner, task, reward and start scheme, and clear errors for bad flags (needs MuJoCo).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::{Command, Output};

fn trainer(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_trainer"))
        .args(args)
        .output()
        .expect("run trainer")
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

#[test]
fn tiny_run_then_resume_rules_and_bad_flags() {
    let out = std::env::temp_dir().join(format!("dex-cli-train-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let out_s = out.to_str().unwrap();
    let base = [
        "train",
        "--task",
        "grasp",
        "--start",
        "along-demonstrations",
        "--transitions",
        "120",
        "--hidden",
        "16,16",
        "--checkpoint-every",
        "60",
        "--final-eval-episodes",
        "1",
        "--select-best-episodes",
        "2",
        "--quiet",
        "--out",
        out_s,
    ];
    let o = trainer(&base);
    assert!(o.status.success(), "{}", text(&o));
    let seed = Path::new(&out).join("seed-0");
    for f in [
        "checkpoint.bin",
        "policy.dxpl",
        "settings.toml",
        "final_eval.json",
    ] {
        assert!(seed.join(f).exists(), "{f} missing:\n{}", text(&o));
    }
    // The exported policy is the best checkpoint on the selection starts.
    let best: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(seed.join("best.json")).unwrap()).unwrap();
    let fin: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(seed.join("final_eval.json")).unwrap())
            .unwrap();
    assert_eq!(best["transitions"], fin["transitions"], "{best} {fin}");
    assert!(text(&o).contains("selection at"), "{}", text(&o));
    let settings = std::fs::read_to_string(seed.join("settings.toml")).unwrap();
    assert!(settings.contains("along-demonstrations"), "{settings}");

    // Same command again: refuses to overwrite the run.
    let o = trainer(&base);
    assert!(!o.status.success());
    assert!(text(&o).contains("--resume"), "{}", text(&o));

    // Resume with another start scheme: refused, the checkpoint is kept.
    let before = std::fs::read(seed.join("checkpoint.bin")).unwrap();
    let mut other: Vec<&str> = base.to_vec();
    other[4] = "mixture";
    other.push("--resume");
    let o = trainer(&other);
    assert!(!o.status.success());
    assert!(text(&o).contains("settings differ"), "{}", text(&o));
    assert_eq!(std::fs::read(seed.join("checkpoint.bin")).unwrap(), before);

    // Resume with the same settings and a larger budget: continues.
    let mut more: Vec<&str> = base.to_vec();
    more[6] = "180";
    more.push("--resume");
    let o = trainer(&more);
    assert!(o.status.success(), "{}", text(&o));

    // Bad flags: clap names the culprit and the accepted values.
    let o = trainer(&["train", "--start", "teleport"]);
    assert!(!o.status.success());
    let t = text(&o);
    assert!(
        t.contains("teleport") && t.contains("along-demonstrations"),
        "{t}"
    );
    let o = trainer(&[
        "train",
        "--start",
        "mixture",
        "--in-hand-probability",
        "2",
        "--out",
        out_s,
    ]);
    assert!(!o.status.success());
    assert!(text(&o).contains("in-hand probability"), "{}", text(&o));
    // A demonstrator policy needs the demonstration scheme, and must be a valid file.
    let cfg = out.with_extension("toml");
    std::fs::write(
        &cfg,
        "[start]\nscheme = \"mixture\"\ndemonstrator_policy = \"x.dxpl\"\n",
    )
    .unwrap();
    let o = trainer(&["train", "--config", cfg.to_str().unwrap(), "--out", out_s]);
    assert!(!o.status.success());
    assert!(text(&o).contains("along-demonstrations"), "{}", text(&o));
    std::fs::write(
        &cfg,
        "[start]\nscheme = \"along-demonstrations\"\ndemonstrator_policy = \"/nonexistent.dxpl\"\n",
    )
    .unwrap();
    let o = trainer(&["train", "--config", cfg.to_str().unwrap(), "--out", out_s]);
    assert!(!o.status.success());
    assert!(text(&o).contains("/nonexistent.dxpl"), "{}", text(&o));
    let _ = std::fs::remove_file(&cfg);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn quantisation_aware_run_exports_int8_without_loss() {
    let out = std::env::temp_dir().join(format!("dex-cli-qat-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let out_s = out.to_str().unwrap();
    let o = trainer(&[
        "train",
        "--task",
        "reach",
        "--transitions",
        "200",
        "--hidden",
        "16,16",
        "--quantise-aware-from",
        "100",
        "--checkpoint-every",
        "50",
        "--final-eval-episodes",
        "2",
        "--select-best-episodes",
        "2",
        "--quiet",
        "--out",
        out_s,
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    // Only checkpoints of the quantised phase are candidates for export.
    let selections: Vec<u64> = t
        .lines()
        .filter_map(|l| l.split("selection at ").nth(1))
        .filter_map(|l| l.split(' ').next()?.parse().ok())
        .collect();
    assert!(
        !selections.is_empty() && selections.iter().all(|&n| n >= 100),
        "{t}"
    );
    let seed = out.join("seed-0");
    let trained = std::fs::read(seed.join("policy.dxpl")).unwrap();
    let aligned = dex_runtime::testkit::aligned_copy(&trained);
    let view = dex_policy::PolicyView::decode(aligned.as_bytes()).unwrap();
    assert!(dex_policy::int8::policy_on_grid(&view).unwrap());

    // `trainer export --int8` re-exports the same f32 policy and quantises it as it is.
    let o = trainer(&["export", out_s, "--int8"]);
    assert!(o.status.success(), "{}", text(&o));
    let t = text(&o);
    assert!(t.contains("on the int8 grid"), "{t}");
    assert!(!t.contains("warning"), "{t}");
    assert_eq!(std::fs::read(seed.join("policy.dxpl")).unwrap(), trained);
    let int8 = std::fs::read(seed.join("policy-int8.dxpl")).unwrap();
    let aligned = dex_runtime::testkit::aligned_copy(&int8);
    let view = dex_policy::PolicyView::decode(aligned.as_bytes()).unwrap();
    assert_eq!(view.header().version, 2);
    let _ = std::fs::remove_dir_all(&out);
}
