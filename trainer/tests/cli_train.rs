//! `trainer train` from the command line: a tiny run, refusal to overwrite, resume checks on the
//! learner, task, reward and start scheme, and clear errors for bad flags (needs MuJoCo).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

mod common;
use common::{text, trainer};

#[test]
fn tiny_run_then_resume_rules_and_bad_flags() {
    let out = std::env::temp_dir().join(format!("dex-cli-train-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let out_s = out.to_str().unwrap();
    let base = [
        "train",
        "--preset",
        "paper",
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
    other[6] = "mixture";
    other.push("--resume");
    let o = trainer(&other);
    assert!(!o.status.success());
    assert!(text(&o).contains("settings differ"), "{}", text(&o));
    assert_eq!(std::fs::read(seed.join("checkpoint.bin")).unwrap(), before);

    // Resume with the same settings and a larger budget: continues.
    let mut more: Vec<&str> = base.to_vec();
    more[8] = "180";
    more.push("--resume");
    let o = trainer(&more);
    assert!(o.status.success(), "{}", text(&o));

    // `trainer export` writes the run's selected checkpoint again; with --latest, the latest
    // checkpoint's actor, whatever the selection chose, by default into policy-latest.dxpl with
    // its own record: neither touches the seed's policy.dxpl or final_eval.json.
    let shipped = std::fs::read(seed.join("policy.dxpl")).unwrap();
    let shipped_eval = std::fs::read(seed.join("final_eval.json")).unwrap();
    let json = |path: std::path::PathBuf| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
    };
    let best = json(seed.join("best.json"));
    std::fs::create_dir_all(out.join("selected")).unwrap();
    let file = out.join("selected").join("policy.dxpl");
    let o = trainer(&["export", out_s, "--out", file.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let fin = json(out.join("selected").join("final_eval.json"));
    assert_eq!(fin["source"], "selected", "{fin}");
    assert_eq!(fin["transitions"], best["transitions"], "{fin} {best}");
    assert_eq!(std::fs::read(&file).unwrap(), shipped);
    let o = trainer(&["export", out_s, "--latest"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(seed.join("policy-latest.dxpl").exists(), "{}", text(&o));
    let fin = json(seed.join("final_eval-latest.json"));
    assert_eq!(fin["source"], "latest", "{fin}");
    assert_eq!(fin["policy"], "policy-latest.dxpl", "{fin}");
    assert!(fin["transitions"].as_u64().unwrap() >= 180, "{fin}");
    assert_eq!(std::fs::read(seed.join("policy.dxpl")).unwrap(), shipped);
    assert_eq!(
        std::fs::read(seed.join("final_eval.json")).unwrap(),
        shipped_eval
    );

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

#[test]
fn demonstration_runs_record_their_demos_resume_and_refuse_bad_demo_settings() {
    let out = std::env::temp_dir().join(format!("dex-cli-demos-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&out).unwrap();
    let run = out.join("run");
    let run_s = run.to_str().unwrap();
    let base = [
        "train",
        "--task",
        "reach",
        "--transitions",
        "100",
        "--hidden",
        "16,16",
        "--checkpoint-every",
        "50",
        "--final-eval-episodes",
        "1",
        "--select-best-episodes",
        "0",
        "--record-demos",
        "2",
        "--demo-fraction",
        "0.25",
        "--bc-weight",
        "0.5",
        "--td3",
        "--n-step",
        "3",
        "--noise-correlation",
        "0.8",
        "--finger-noise-scale",
        "0.5",
        "--action-l2",
        "0.001",
        "--quiet",
        "--out",
        run_s,
    ];
    let o = trainer(&base);
    assert!(o.status.success(), "{}", text(&o));
    let seed = run.join("seed-0");
    assert!(seed.join("demos.dxdm").exists(), "{}", text(&o));
    assert!(
        text(&o).contains("demonstration transitions"),
        "{}",
        text(&o)
    );
    let settings = std::fs::read_to_string(seed.join("settings.toml")).unwrap();
    for key in ["twin_critics = true", "n_step = 3", "correlation = 0.8"] {
        assert!(settings.contains(key), "{key} not in\n{settings}");
    }
    // Resuming with the same flags continues (the demonstrations are loaded again, not
    // re-recorded); other demonstration settings are refused.
    let mut longer = base.to_vec();
    longer[4] = "200";
    longer.push("--resume");
    let o = trainer(&longer);
    assert!(o.status.success(), "{}", text(&o));
    assert!(!text(&o).contains("recording"), "{}", text(&o));
    let mut other = longer.clone();
    other[14] = "3";
    let o = trainer(&other);
    assert!(!o.status.success());
    assert!(text(&o).contains("demonstrations"), "{}", text(&o));

    // A demo file of another task, or with another reward in its rows, is refused before training.
    let grasp = out.join("grasp.dxdm");
    let o = trainer(&[
        "demos",
        "--task",
        "grasp",
        "--episodes",
        "1",
        "--out",
        grasp.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let sparse = out.join("reach-sparse.dxdm");
    let o = trainer(&[
        "demos",
        "--task",
        "reach",
        "--episodes",
        "1",
        "--out",
        sparse.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let cases: [(&[&str], &str); 7] = [
        (
            &["--demos", grasp.to_str().unwrap()],
            "recorded for task grasp",
        ),
        (&["--demos", sparse.to_str().unwrap()], "reward"),
        (&["--demos", "/nonexistent/x.dxdm"], "x.dxdm"),
        (&["--demo-fraction", "1.5"], "demos.fraction"),
        (&["--bc-weight", "1"], "demos.bc_weight"),
        (&["--demo-fraction", "0.5"], "needs demonstrations"),
        (&["--preset", "paper", "--td3"], "cannot be used with"),
    ];
    for (extra, want) in cases {
        let dir = out.join("bad");
        let _ = std::fs::remove_dir_all(&dir);
        let mut args = vec![
            "train",
            "--task",
            "reach",
            "--transitions",
            "50",
            "--quiet",
            "--out",
            dir.to_str().unwrap(),
        ];
        if extra[0] == "--demos" {
            args.extend(["--demo-fraction", "0.5"]);
        }
        args.extend_from_slice(extra);
        let o = trainer(&args);
        assert!(!o.status.success(), "{extra:?} was accepted");
        assert!(text(&o).contains(want), "{extra:?}: {}", text(&o));
        assert!(
            !dir.join("seed-0").join("checkpoint.bin").exists(),
            "{extra:?} trained"
        );
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn eval_writes_a_record_that_the_results_page_accepts() {
    let dir = std::env::temp_dir().join(format!("dex-cli-record-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let record = dir.join("reach.json");
    let policy = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/reach_seed0.dxpl"
    );
    let o = trainer(&[
        "eval",
        policy,
        "--episodes",
        "3",
        "--threads",
        "1",
        "--record",
        record.to_str().unwrap(),
        "--section",
        "table2",
        "--what",
        "Reach fixture",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&record).unwrap()).unwrap();
    // The fields scripts/results.py requires, with the evaluation's own values.
    for key in [
        "section",
        "order",
        "what",
        "evaluated",
        "command",
        "successes",
        "episodes",
        "interval_95",
        "start_seed",
        "evaluation",
        "date",
        "machine",
        "compute",
        "source",
    ] {
        assert!(r.get(key).is_some(), "missing {key}: {r}");
    }
    assert_eq!(r["episodes"], 3);
    assert_eq!(r["start_seed"], 1_000_000);
    assert_eq!(r["what"], "Reach fixture");
    assert_eq!(r["evaluated"]["sha256"].as_str().unwrap().len(), 64);
    assert!(
        r["command"].as_str().unwrap().contains("--episodes 3"),
        "{r}"
    );
    let printed = text(&o);
    let successes = r["successes"].as_u64().unwrap();
    assert!(printed.contains(&format!("{successes}/3")), "{printed}");
    // --record without its section and label is a usage error, and nothing is written.
    let lone = dir.join("lone.json");
    let o = trainer(&["eval", policy, "--record", lone.to_str().unwrap()]);
    assert!(!o.status.success() && !lone.exists(), "{}", text(&o));
    let _ = std::fs::remove_dir_all(&dir);
}
