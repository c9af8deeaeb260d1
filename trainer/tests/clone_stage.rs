//! The clone stage of `trainer train` (`[clone]`, `--clone`, `--preset finetune`): per seed the
//! imitation learner clones the Markov demonstrator into `OUT/clone/seed-S`, then reinforcement
//! learning starts its actor from that file; a resumed run reuses the clone and refuses changed
//! clone settings; a clone stage beside `--init-policy` is refused before any work (needs MuJoCo).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

mod common;
use common::{text, trainer};

const CONFIG: &str = r#"
task = "reach"
transitions = 300
checkpoint_every = 150
final_eval_episodes = 3
select_best_episodes = 3
features = true
record_demos = 4

[clone]
demo_episodes = 4
dart_episodes = 4
bc_steps = 200
select_episodes = 3

[run]
updates_per_step = 1
critic_warmup_updates = 100

[run.ddpg]
actor_hidden = [32, 32]

[run.demos]
fraction = 0.25
bc_weight = 5.0
q_filter = false
"#;

#[test]
fn the_clone_stage_makes_the_actors_start_and_resumes() {
    let dir = std::env::temp_dir().join(format!("dex-clone-stage-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("run.toml");
    std::fs::write(&config, CONFIG).unwrap();
    let out = dir.join("run");
    let args = |extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = ["train", "--config", config.to_str().unwrap(), "--quiet"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        v.extend(["--out".to_string(), out.to_str().unwrap().to_string()]);
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let run = |extra: &[&str]| {
        let a = args(extra);
        trainer(&a.iter().map(String::as_str).collect::<Vec<_>>())
    };

    let o = run(&[]);
    let log = text(&o);
    assert!(o.status.success(), "{log}");
    let clone = out.join("clone/seed-0/policy.dxpl");
    assert!(clone.exists(), "{log}");
    assert!(
        log.contains("clone stage") && log.contains("starts from the clone"),
        "{log}"
    );
    // The seed's settings record the clone as its starting point; the run's keep the stage.
    let seed = std::fs::read_to_string(out.join("seed-0/settings.toml")).unwrap();
    assert!(
        seed.contains("clone/seed-0/policy.dxpl") && !seed.contains("[clone]"),
        "{seed}"
    );
    let run_settings = std::fs::read_to_string(out.join("settings.toml")).unwrap();
    assert!(run_settings.contains("[clone]"), "{run_settings}");
    for f in ["policy.dxpl", "final_eval.json", "checkpoint.bin"] {
        assert!(out.join("seed-0").join(f).exists(), "{f}: {log}");
    }
    // The clone's network is the actor's (features: 58 inputs, 32-32).
    let bytes = std::fs::read(&clone).unwrap();
    let aligned = dex_runtime::aligned::aligned_copy(&bytes);
    let view = dex_policy::PolicyView::decode(aligned.as_bytes()).unwrap();
    assert_eq!(view.body().obs_dim(), dex_runtime::features::INPUT_MAX);
    assert_eq!(view.layers().next().unwrap().outputs, 32);

    // Resumed with a larger budget: the clone is reused, not made again.
    let before = std::fs::read(&clone).unwrap();
    let o = run(&["--resume", "--transitions", "450"]);
    let log = text(&o);
    assert!(o.status.success(), "{log}");
    assert_eq!(std::fs::read(&clone).unwrap(), before);
    assert!(
        !log.contains("recording"),
        "the clone was made again: {log}"
    );

    // A changed clone stage on resume is refused, naming the stage's folder.
    std::fs::write(&config, CONFIG.replace("bc_steps = 200", "bc_steps = 300")).unwrap();
    let o = run(&["--resume", "--transitions", "600"]);
    let log = text(&o);
    assert!(!o.status.success(), "{log}");
    assert!(log.contains("clone stage in"), "{log}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_clone_stage_and_an_init_policy_are_refused_together() {
    let policy = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/reach_seed0.dxpl"
    );
    let out = std::env::temp_dir().join(format!("dex-clone-both-{}", std::process::id()));
    let o = trainer(&[
        "train",
        "--task",
        "reach",
        "--clone",
        "--init-policy",
        policy,
        "--out",
        out.to_str().unwrap(),
    ]);
    let log = text(&o);
    assert!(!o.status.success(), "{log}");
    assert!(log.contains("give one of them"), "{log}");
    assert!(!Path::new(&out).join("clone").exists());
}
