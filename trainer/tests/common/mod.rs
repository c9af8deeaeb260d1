//! Helpers shared by the trainer's integration tests (each test file uses some of them): running
//! the `trainer` and `env-tool` binaries, temporary paths, the MuJoCo scene loaded once.

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

/// Runs `env-tool ARGS` to the end and returns what it printed.
pub fn env_tool(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_env-tool"))
        .args(args)
        .output()
        .expect("run env-tool")
}

// The scene loader and observation bits of dex-env's tests, the same file.
#[path = "../../../env/tests/common/mod.rs"]
mod env_common;
#[allow(unused_imports)] // each test file uses some of them
pub use env_common::{bits, scene};

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

/// The Reach policy fixture (`tests/fixtures/reach_seed0.dxpl`, a trained Reach file): the starting
/// policy of the fine-tune tests.
pub const REACH_FIXTURE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/fixtures/reach_seed0.dxpl"
);

/// Hidden sizes of [`REACH_FIXTURE`]'s network (an actor that imports it must have them).
pub fn reach_fixture_hidden() -> Vec<usize> {
    let bytes = std::fs::read(REACH_FIXTURE).expect("the Reach fixture");
    let aligned = dex_runtime::aligned::aligned_copy(&bytes);
    let view = dex_policy::PolicyView::decode(aligned.as_bytes()).expect("a policy file");
    let outs: Vec<usize> = view.layers().map(|l| l.outputs).collect();
    outs[..outs.len() - 1].to_vec()
}

/// A short Reach fine-tune of [`REACH_FIXTURE`] into `out`: `transitions` transitions, one
/// checkpoint at the end, no checkpoint selection, one final episode, learning from 100
/// transitions on, the fixture's actor sizes, raw observations; `configure` then changes what the
/// test needs. Trained to the end; returns its seed folder (`out/seed-0`).
pub fn reach_fixture_run(
    out: &std::path::Path,
    transitions: u64,
    configure: impl FnOnce(&mut dex_trainer::pipeline::train_settings::TrainSettings),
) -> PathBuf {
    use dex_trainer::pipeline::train_settings::{TaskArg, TrainSettings};
    let mut s = TrainSettings {
        task: TaskArg::Reach,
        out: out.to_path_buf(),
        transitions,
        checkpoint_every: transitions,
        final_eval_episodes: 1,
        select_best_episodes: 0,
        init_policy: Some(REACH_FIXTURE.into()),
        ..TrainSettings::default()
    };
    s.run.ddpg.actor_hidden = reach_fixture_hidden();
    s.run.obs_norm.enabled = false;
    s.run.learning_starts = 100;
    configure(&mut s);
    let done = dex_trainer::pipeline::train_run::TrainPlan::new(s)
        .expect("valid settings")
        .train(
            scene(),
            false,
            &std::sync::atomic::AtomicBool::new(false),
            &mut |_| {},
        )
        .expect("the run trains");
    assert!(done);
    out.join("seed-0")
}
