//! Stall states (issue #26, session 31): a Stack clone's episode that stalls before its grasp is
//! found at its stall, stays there without noise (brick 1 never leaves the table), and its snapshot survives a checkpoint's
//! round trip; a snapshot that does not fit the scene is refused. Kept some steps before the
//! stall (session 32), the state is that many steps earlier on the same episode: the noise-free
//! policy run from it comes to the same stalled state.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use dex_trainer::env::seeds::episode_seed;
use dex_trainer::env::{EnvConfig, EnvError, EnvSnapshot, JacoEnv, Scene, Task};
use dex_trainer::evaluate::{controller_command, physical_to_env_action};
use dex_trainer::pipeline::stall_starts::{StallStart, TABLE_Z, WINDOW, harvest};

/// Session 14's Stack clone (the first member of `policies/stack.dxpl`'s ensemble).
fn stack_clone() -> Vec<u8> {
    std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/stack_clone_session14.dxpl"
    ))
    .unwrap()
}

/// Development starts of session 31: the clone stalls from start 12 (at step 64) and succeeds
/// from start 0 (docs/experiments.md, session 31).
const DEV: u64 = 7_101_500;

#[test]
fn a_stalled_episode_is_found_at_its_stall_and_stays_stuck_without_noise() {
    let scene = Scene::load().unwrap();
    let file = stack_clone();
    let seeds = [episode_seed(DEV, 12), episode_seed(DEV, 0)];
    let (found, steps) = harvest(&file, &scene, Task::Stack, &seeds, 0, 2).unwrap();
    assert_eq!(steps, 300, "two whole episodes");
    assert_eq!(found.len(), 1, "only the failed episode stalls");
    let stall = &found[0];
    assert_eq!(stall.seed, seeds[0]);
    let at = stall.snapshot.steps();
    assert!((WINDOW as u32..150).contains(&at), "stall at step {at}");

    // From the snapshot the noise-free policy goes nowhere: the closed loop's fixed point.
    let aligned = dex_runtime::aligned::aligned_copy(&file);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes()).unwrap();
    let mut mlp = dex_runtime::Mlp::<1024>::new(&view).unwrap();
    let mut env = JacoEnv::new(&scene, EnvConfig::new(Task::Stack));
    let mut o = env.restore(&stall.snapshot).unwrap();
    let pinch = env.reward_state().pinch;
    let out = loop {
        let a = physical_to_env_action(&controller_command(&mut mlp, &o, true, None).unwrap());
        let out = env.step(&a).unwrap();
        o = out.observation;
        if out.done {
            break out;
        }
    };
    assert!(!out.success && !out.predicates.grasp);
    let state = env.reward_state();
    assert!(state.brick1_pos[2] < TABLE_Z, "brick 1 left the table");
    let moved = (0..3)
        .map(|k| (state.pinch[k] - pinch[k]).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(moved < 0.03, "the hand moved {moved} m after its stall");

    // A checkpoint's round trip keeps the state exactly.
    let bytes = postcard::to_allocvec(stall).unwrap();
    let back: StallStart = postcard::from_bytes(&bytes).unwrap();
    assert_eq!(&back, stall);
    let mut other = JacoEnv::new(&scene, EnvConfig::new(Task::Stack));
    assert_eq!(
        other.restore(&back.snapshot).unwrap(),
        env.restore(&stall.snapshot).unwrap()
    );
}

#[test]
fn a_state_kept_before_the_stall_leads_back_to_it() {
    let scene = Scene::load().unwrap();
    let file = stack_clone();
    let seeds = [episode_seed(DEV, 12)];
    let (at, _) = harvest(&file, &scene, Task::Stack, &seeds, 0, 1).unwrap();
    let (before, steps) = harvest(&file, &scene, Task::Stack, &seeds, 20, 1).unwrap();
    assert_eq!(steps, 150);
    assert_eq!((at.len(), before.len()), (1, 1));
    let (at, before) = (&at[0].snapshot, &before[0].snapshot);
    assert_eq!(before.steps() + 20, at.steps(), "20 steps before the stall");
    assert_ne!(before, at);

    // Twenty noise-free steps from the earlier state reach the stalled state itself.
    let aligned = dex_runtime::aligned::aligned_copy(&file);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes()).unwrap();
    let mut mlp = dex_runtime::Mlp::<1024>::new(&view).unwrap();
    let mut env = JacoEnv::new(&scene, EnvConfig::new(Task::Stack));
    let mut o = env.restore(before).unwrap();
    for _ in 0..20 {
        let a = physical_to_env_action(&controller_command(&mut mlp, &o, true, None).unwrap());
        o = env.step(&a).unwrap().observation;
    }
    let reached = env.snapshot();
    let mut there = JacoEnv::new(&scene, EnvConfig::new(Task::Stack));
    assert_eq!(there.restore(at).unwrap(), o, "the same observation");
    assert_eq!(reached.steps(), at.steps());
    let pinch = |e: &JacoEnv| e.reward_state().pinch;
    let gap = (0..3)
        .map(|k| (pinch(&env)[k] - pinch(&there)[k]).abs())
        .fold(0.0, f64::max);
    assert!(gap < 1e-9, "the hand is {gap} m from the stalled state");
}

#[test]
fn a_snapshot_of_another_size_is_refused() {
    let scene = Scene::load().unwrap();
    let mut env = JacoEnv::new(&scene, EnvConfig::new(Task::Stack));
    env.reset(episode_seed(DEV, 0)).unwrap();
    let mut json: serde_json::Value = serde_json::to_value(env.snapshot()).unwrap();
    json["state"].as_array_mut().unwrap().pop();
    let short: EnvSnapshot = serde_json::from_value(json).unwrap();
    let e = env.restore(&short).unwrap_err();
    assert!(matches!(e, EnvError::Snapshot { .. }), "{e}");
}
