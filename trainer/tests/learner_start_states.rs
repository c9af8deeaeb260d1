//! Instructive start states with the trainer's parts: the learner's adapter trains short episodes
//! from demonstration states and evaluates full ones from original starts, and an exported policy
//! can be the demonstrator (needs `scripts/setup-mujoco.sh` to have run). The schemes themselves
//! are tested in `env/tests/env_start_states.rs`.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;
use common::{bits, scene};

use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_trainer::cell::jaco::JacoLearnEnv;
use dex_trainer::cell::policy_demo::PolicyDemonstration;
use dex_trainer::env::{
    Demonstration, EnvConfig, JacoEnv, StartKind, StartScheme, StartStates, Task,
};
use dex_trainer::learn::{Env, Rng};

#[test]
fn learner_env_trains_short_episodes_from_demonstrations_and_evaluates_full_ones_from_original_starts()
 {
    let cfg = EnvConfig::new(Task::Grasp);
    let mut env =
        JacoLearnEnv::with_starts(scene(), cfg, StartScheme::along_demonstrations()).unwrap();
    let mut rng = Rng::seed_from_u64(3);
    let mut obs = [0.0f32; OBS_DIM];
    let run = |env: &mut JacoLearnEnv, obs: &mut [f32; OBS_DIM]| {
        let mut steps = 0;
        loop {
            steps += 1;
            if env.step(&[0.0; ACT_DIM], obs).done() {
                return steps;
            }
        }
    };
    env.reset(&mut rng, &mut obs);
    assert_eq!(run(&mut env, &mut obs), 50);
    // Evaluation: original start (the same one a plain environment gives for the seed), 150 steps.
    let mut probe = rng.clone();
    let seed = probe.next_u64();
    env.reset_eval(&mut rng, &mut obs);
    let mut plain = JacoEnv::new(scene(), cfg);
    assert_eq!(bits(&obs), bits(&plain.reset(seed).unwrap()));
    assert_eq!(run(&mut env, &mut obs), 150);
    env.reset(&mut rng, &mut obs);
    assert_eq!(run(&mut env, &mut obs), 50);
    assert_eq!(env.errors, 0);
}

#[test]
fn an_exported_policy_can_demonstrate_and_bad_files_are_refused() {
    // The trained Reach policy of the int8 tests: it solves most Reach starts in well under 50 steps.
    let file = std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/reach_seed0.dxpl"),
    )
    .unwrap();
    let policy = PolicyDemonstration::from_file_bytes(&file).unwrap();
    let cfg = EnvConfig::new(Task::Reach);
    let mut env = JacoEnv::new(scene(), cfg);
    let mut starts = StartStates::new(StartScheme::along_demonstrations(), policy.clone()).unwrap();
    let mut solved = 0;
    for seed in 0..6 {
        let h = starts.reset(&mut env, seed).unwrap();
        let StartKind::Demonstration { k, n, solved: s } = h.kind else {
            panic!("{:?}", h.kind)
        };
        assert!((1..=n).contains(&k) && n <= 50);
        solved += usize::from(s);
        // The hand-over is the state the policy reaches after k steps from the original start.
        let mut replay = JacoEnv::new(scene(), cfg);
        replay.reset(seed).unwrap();
        let mut p = policy.clone();
        for _ in 0..k {
            let a = p.act(&replay).unwrap();
            replay.step(&a).unwrap();
        }
        assert_eq!(
            bits(replay.observation()),
            bits(&h.observation),
            "seed {seed}"
        );
    }
    assert!(solved >= 3, "{solved}/6 demonstrations solved Reach");
    let mut bad = file.clone();
    let last = bad.len() - 1;
    bad[last] ^= 1;
    assert!(PolicyDemonstration::from_file_bytes(&bad).is_err());
    assert!(PolicyDemonstration::from_file_bytes(&[]).is_err());
}

#[test]
fn the_teacher_labels_of_the_jaco_env_are_the_markov_demonstrators_actions() {
    // Following the labels is following the teacher: it stacks (the labels come from the state
    // the step will act on, not from the one before).
    let mut env = JacoLearnEnv::new(scene(), EnvConfig::new(Task::Stack));
    let mut rng = Rng::seed_from_u64(4);
    let mut obs = [0.0f32; OBS_DIM];
    let mut label = [0.0f32; ACT_DIM];
    let mut successes = 0;
    for _ in 0..5 {
        env.reset_eval(&mut rng, &mut obs);
        loop {
            assert!(env.expert_action(&mut label));
            assert!(label.iter().all(|a| a.is_finite() && a.abs() <= 1.0));
            let step = env.step(&label, &mut obs);
            if step.done() {
                successes += usize::from(step.success);
                break;
            }
        }
    }
    assert!(successes >= 4, "the teacher's labels stacked {successes}/5");
}
