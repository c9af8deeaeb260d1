//! int8 export of a trained policy: the post-training quantisation keeps every layout, the int8 file
//! runs through `trainer eval`'s runtime path, and its actions stay within 1% of each joint's range
//! of the f32 policy's on held-out observations (the goal, on a fixed trained policy).
//!
//! Fixture `tests/fixtures/reach_seed0.dxpl`: the Reach policy of `trainer train --out DIR --quiet`
//! (default settings, seed 0), f32, format version 1.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::{LayerDtype, PolicyView};
use dex_runtime::interface::ACTION_JOINTS;
use dex_runtime::testkit::aligned_copy;
use dex_trainer::env::{EnvConfig, Scene, Task};
use dex_trainer::evaluate::{
    EvalSettings, HELDOUT_SEED, action_error, evaluate_policy_file, heldout_observations,
};
use dex_trainer::export::quantise_policy_file;

const TRAINED: &[u8] = include_bytes!("fixtures/reach_seed0.dxpl");

#[test]
#[ignore = "fails today: the all-int8 export of this trained policy errs by up to 43% of a joint's range \
            (docs/benchmarks.md, int8 policies); run with --ignored once the quantiser meets the goal"]
fn quantised_trained_policy_stays_within_one_percent_of_each_joint_range() {
    let int8 = quantise_policy_file(TRAINED, None).unwrap();
    let scene = Scene::load().unwrap();
    let env = EnvConfig::new(Task::Reach);
    let mut observations = heldout_observations(TRAINED, &scene, env, 5, HELDOUT_SEED).unwrap();
    observations.extend(heldout_observations(&int8, &scene, env, 5, HELDOUT_SEED).unwrap());
    assert!(observations.len() > 100, "{}", observations.len());
    let error = action_error(TRAINED, &int8, &observations).unwrap();
    for (joint, e) in ACTION_JOINTS.iter().zip(error) {
        assert!(
            e <= 0.01,
            "{}: int8 error {:.3}% of the joint's range (goal <= 1%)",
            joint.name,
            e * 100.0
        );
    }
}

#[test]
fn int8_export_keeps_the_layout_and_carries_its_own_success_rate() {
    let f32_file = aligned_copy(TRAINED);
    let f32_view = PolicyView::decode(f32_file.as_bytes()).unwrap();
    assert_eq!(f32_view.header().version, 1);
    let draft = quantise_policy_file(TRAINED, None).unwrap();
    let draft = aligned_copy(&draft);
    let view = PolicyView::decode(draft.as_bytes()).unwrap();
    assert_eq!(view.header().version, 2);
    assert_eq!(view.header().layout_hash, f32_view.header().layout_hash);
    assert!(
        view.body()
            .layers
            .iter()
            .all(|l| l.dtype == LayerDtype::Int8)
    );
    assert_eq!(view.body().provenance.success_rate, None);
    assert_eq!(view.body().provenance.seed, f32_view.body().provenance.seed);
    let ratio = f32_view.weight_bytes() as f64 / view.weight_bytes() as f64;
    assert!((3.8..=4.0).contains(&ratio), "{ratio}");
    let stamped = quantise_policy_file(TRAINED, Some((0.5, 10))).unwrap();
    let stamped = aligned_copy(&stamped);
    let view = PolicyView::decode(stamped.as_bytes()).unwrap();
    assert_eq!(view.body().provenance.success_rate, Some(0.5));
    assert_eq!(view.body().provenance.eval_episodes, 10);
}

#[test]
fn trainer_eval_runs_int8_files_deterministically() {
    let int8 = quantise_policy_file(TRAINED, None).unwrap();
    let scene = Scene::load().unwrap();
    let settings = EvalSettings {
        env: EnvConfig::new(Task::Reach),
        episodes: 4,
        seed: 1_000_000,
        threads: 2,
        can_quantisation: true,
    };
    let a = evaluate_policy_file(&int8, &scene, &settings, &|| {}).unwrap();
    let b = evaluate_policy_file(&int8, &scene, &settings, &|| {}).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.episodes, 4);
}
