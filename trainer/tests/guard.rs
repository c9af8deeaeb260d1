//! The guard of a run that starts from a policy (`guard_episodes`, `--guard-episodes`, on in
//! `--preset finetune` and the default pipeline): the selected policy and the starting one on the
//! same selection starts, the starting policy shipped when it solves more of them, the verdict in
//! `guard.json` and followed by `trainer export`; a guard without a starting policy is refused
//! before any work (needs MuJoCo).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::sync::atomic::AtomicBool;

use dex_trainer::env::Scene;
use dex_trainer::learn::Trainer;
use dex_trainer::pipeline::train_run::{
    GuardVerdict, TrainEvent, TrainPlan, TrainRunError, export_selected,
};
use dex_trainer::pipeline::train_settings::{SettingsError, TaskArg, TrainSettings};

mod common;
use common::{REACH_FIXTURE as FIXTURE, fresh_path, reach_fixture_hidden as fixture_hidden};

/// A short Reach run from the fixture with a guard of 12 starts.
fn settings(out: &Path) -> TrainSettings {
    let mut s = TrainSettings {
        task: TaskArg::Reach,
        out: out.to_path_buf(),
        transitions: 400,
        checkpoint_every: 400,
        final_eval_episodes: 4,
        select_best_episodes: 0,
        init_policy: Some(FIXTURE.into()),
        guard_episodes: 12,
        ..TrainSettings::default()
    };
    s.run.ddpg.actor_hidden = fixture_hidden();
    s.run.obs_norm.enabled = false;
    s.run.updates_per_step = 4;
    s.run.learning_starts = 100;
    s
}

/// Trains `s` to the end and returns the guard's verdict.
fn train(s: TrainSettings, scene: &Scene) -> GuardVerdict {
    let mut verdict = None;
    let done = TrainPlan::new(s)
        .unwrap()
        .train(scene, false, &AtomicBool::new(false), &mut |e| {
            if let TrainEvent::Guarded { verdict: v, .. } = e {
                verdict = Some(v.clone());
            }
        })
        .unwrap();
    assert!(done);
    verdict.expect("the guard ran")
}

fn final_eval_source(seed_dir: &Path) -> String {
    let text = std::fs::read_to_string(seed_dir.join("final_eval.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    json["source"].as_str().unwrap().to_string()
}

#[test]
fn a_run_that_ruined_its_starting_policy_ships_the_starting_policy() {
    let scene = Scene::load().unwrap();
    let out = fresh_path("guard", "ruined");
    let _ = std::fs::remove_dir_all(&out);
    // An actor rate a thousand times the default, no warm-up: 1,200 updates wreck the actor.
    let mut s = settings(&out);
    s.run.actor_adam.lr = 0.3;
    let v = train(s.clone(), &scene);
    assert!(v.ships_init, "{}", v.line());
    assert!(v.paired.b_successes > v.paired.a_successes, "{}", v.line());
    assert_eq!(v.paired.episodes, 12);
    let seed_dir = out.join("seed-0");
    let shipped = std::fs::read(seed_dir.join("policy.dxpl")).unwrap();
    assert_eq!(shipped, std::fs::read(FIXTURE).unwrap());
    assert_eq!(final_eval_source(&seed_dir), "init_policy");
    // `trainer export` of the folder follows the verdict.
    let trainer = Trainer::load(&seed_dir.join("checkpoint.bin")).unwrap();
    let again = seed_dir.join("again.dxpl");
    export_selected(&trainer, &s, 0, &seed_dir, &again, &scene).unwrap();
    assert_eq!(std::fs::read(&again).unwrap(), shipped);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_tie_ships_the_starting_policy() {
    let scene = Scene::load().unwrap();
    let out = fresh_path("guard", "tie");
    let _ = std::fs::remove_dir_all(&out);
    // The critic's warm-up covers the whole run: the actor never moves, so both policies compute
    // the same function and solve the same starts.
    let mut s = settings(&out);
    s.run.critic_warmup_updates = 1_000_000;
    let v = train(s, &scene);
    assert_eq!(v.paired.only_a + v.paired.only_b, 0, "{}", v.line());
    assert!(v.ships_init, "{}", v.line());
    let seed_dir = out.join("seed-0");
    assert_eq!(final_eval_source(&seed_dir), "init_policy");
    assert_eq!(
        std::fs::read(seed_dir.join("policy.dxpl")).unwrap(),
        std::fs::read(FIXTURE).unwrap(),
        "the starting policy's file ships unchanged"
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_guard_without_a_starting_policy_is_refused() {
    let out = fresh_path("guard", "orphan");
    let mut s = settings(&out);
    s.init_policy = None;
    assert!(matches!(
        TrainPlan::new(s.clone()).err(),
        Some(TrainRunError::Settings(SettingsError::GuardWithoutInit))
    ));
    s.init_policy = Some(FIXTURE.into());
    s.guard_episodes = 100_001;
    assert!(matches!(
        TrainPlan::new(s).err(),
        Some(TrainRunError::Settings(SettingsError::GuardTooLong { .. }))
    ));
    assert!(!out.exists());
}
