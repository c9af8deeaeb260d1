//! The policies shipped in `policies/` run through the runtime's evaluator (CAN quantisation on,
//! as the controller sees them) on 50 starts no training, selection or documented evaluation used
//! (seed 4,000,000), and succeed at least as often as `policies/README.md` promises for CI (needs
//! `scripts/setup-mujoco.sh` to have run). A missing file fails the test.
//!
//! Measured on dev-2c (2026-12-03, the session-14 files, which take the task features): StackInHand
//! 50/50 (the clone fine-tuned by the RL learner); Grasp (2026-12-04, session 22's distilled
//! ensemble of clones) 50/50; the 128-wide Grasp file and its int8 twin (2026-12-05) 50/50 each;
//! Stack (2026-12-06, session 38's close-start clone) 49/50. Each bound is two episodes below, so a machine whose physics rounds differently (outcomes of these chaotic
//! episodes can flip) does not fail a policy that is as good.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use dex_trainer::env::seeds::CI_SEED;
use dex_trainer::env::{EnvConfig, Scene, Task};
use dex_trainer::evaluate::{EvalSettings, evaluate_policy_file};

fn check(file: &str, task: Task, at_least: u32) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../policies")
        .join(file);
    let bytes = std::fs::read(&path).unwrap_or_else(|e| {
        panic!(
            "{} is missing ({e}): it is shipped with the repo",
            path.display()
        )
    });
    let scene = Scene::load().unwrap();
    let settings = EvalSettings {
        env: EnvConfig::new(task),
        episodes: 50,
        seed: CI_SEED,
        threads: 2,
        can_quantisation: true,
        envelope: false,
    };
    let e = evaluate_policy_file(&bytes, &scene, &settings, &|| {}).unwrap();
    assert!(
        e.successes >= at_least,
        "{file}: {}/50 successes, the README promises at least {at_least}",
        e.successes
    );
}

#[test]
fn grasp_policy_succeeds() {
    check("grasp.dxpl", Task::Grasp, 48);
}

#[test]
fn stack_in_hand_policy_succeeds() {
    check("stack-in-hand.dxpl", Task::StackInHand, 48);
}

#[test]
fn stack_policy_succeeds() {
    check("stack.dxpl", Task::Stack, 47);
}

/// The 128-wide Grasp file (session 27) and its int8 twin, which `scripts/firmware-sil.sh`
/// flashes into the firmware node.
#[test]
fn grasp_128_policies_succeed() {
    check("grasp-128.dxpl", Task::Grasp, 48);
    check("grasp-128-int8.dxpl", Task::Grasp, 48);
}
