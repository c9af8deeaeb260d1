//! int8 export of trained policies. The goals on a quantisation-aware trained policy
//! (actions within 1% of each joint's range of the f32 policy's on held-out observations; closed-loop
//! success like the f32 policy's); post-training quantisation keeps every layout, the int8 file runs
//! through `trainer eval`'s runtime path; equalisation before quantisation keeps the f32 function
//! and cuts the int8 error of a policy trained without quantisation.
//!
//! Fixtures:
//! - `tests/fixtures/reach_seed0.dxpl`: the Reach policy of `trainer train --out DIR --quiet`
//!   (default settings, seed 0), f32, format version 1.
//! - `tests/fixtures/reach_int8_seed0.dxpl`: the Reach policy of `trainer train --config
//!   experiments/reach-int8.toml --seeds 0 --quiet` (quantisation-aware from 45k of 60k
//!   transitions), f32 weights on the int8 grid, format version 1.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::{LayerDtype, PolicyView};
use dex_runtime::interface::ACTION_JOINTS;
use dex_runtime::testkit::aligned_copy;
use dex_trainer::env::seeds::EVAL_SEED;
use dex_trainer::env::{EnvConfig, Scene, Task};
use dex_trainer::evaluate::{
    EvalSettings, action_error, episode_outcomes, evaluate_policy_file,
    heldout_observations_of_both,
};
use dex_trainer::files::export::{
    calibration_observations, equalise_policy_file, quantise_policy_file,
    quantise_policy_file_calibrated,
};

const TRAINED: &[u8] = include_bytes!("fixtures/reach_seed0.dxpl");
const TRAINED_FOR_INT8: &[u8] = include_bytes!("fixtures/reach_int8_seed0.dxpl");

/// Calibration observations of `f32_file`: `CALIBRATION_EPISODES` f32 episodes from
/// `CALIBRATION_SEED`, a seed range apart from the held-out one.
fn calibration(
    f32_file: &[u8],
    scene: &Scene,
    env: EnvConfig,
) -> Vec<[f32; dex_runtime::interface::OBS_DIM]> {
    calibration_observations(f32_file, scene, env).unwrap()
}

/// Held-out observations driven by the f32 policy and by `int8` (5 episodes each).
fn heldout(
    f32_file: &[u8],
    scene: &Scene,
    env: EnvConfig,
    int8: &[u8],
) -> Vec<[f32; dex_runtime::interface::OBS_DIM]> {
    let observations = heldout_observations_of_both(f32_file, int8, scene, env, 5).unwrap();
    assert!(observations.len() > 100, "{}", observations.len());
    observations
}

#[test]
fn quantisation_aware_policy_stays_within_one_percent_of_each_joint_range() {
    let scene = Scene::load().unwrap();
    let env = EnvConfig::new(Task::Reach);
    let aligned = aligned_copy(TRAINED_FOR_INT8);
    assert!(
        dex_policy::int8::policy_on_grid(&PolicyView::decode(aligned.as_bytes()).unwrap()).unwrap()
    );
    // Equalisation leaves a file on the grid alone; the int8 file is its plain quantisation.
    let calibration = calibration(TRAINED_FOR_INT8, &scene, env);
    let eq = equalise_policy_file(TRAINED_FOR_INT8, &calibration).unwrap();
    assert_eq!(
        (eq.file.as_slice(), eq.max_f32_change),
        (TRAINED_FOR_INT8, 0.0)
    );
    assert!(eq.on_grid);
    let (int8, change) =
        quantise_policy_file_calibrated(TRAINED_FOR_INT8, None, &calibration).unwrap();
    assert_eq!(int8, quantise_policy_file(TRAINED_FOR_INT8, None).unwrap());
    assert_eq!(change, 0.0);
    let error = action_error(
        TRAINED_FOR_INT8,
        &int8,
        &heldout(TRAINED_FOR_INT8, &scene, env, &int8),
    )
    .unwrap();
    for (joint, e) in ACTION_JOINTS.iter().zip(error) {
        assert!(
            e <= 0.01,
            "{}: int8 error {:.3}% of the joint's range (goal <= 1%)",
            joint.name,
            e * 100.0
        );
    }
    // Not trivially zero: the runtime's int16 activations do round.
    assert!(error.iter().any(|&e| e > 0.0), "{error:?}");
    // The same held-out measure on a policy trained without quantisation, for contrast: far over.
    let (plain, _) = quantise_policy_file_calibrated(
        TRAINED,
        None,
        &calibration_observations(TRAINED, &scene, env).unwrap(),
    )
    .unwrap();
    let worst = action_error(TRAINED, &plain, &heldout(TRAINED, &scene, env, &plain))
        .unwrap()
        .iter()
        .copied()
        .fold(0.0, f64::max);
    assert!(worst > 0.05, "{worst}");
}

#[test]
fn quantisation_aware_policy_succeeds_like_its_f32_file_start_by_start() {
    // 300 starts from `trainer eval`'s seed, CAN quantisation on. Outcomes of this task are chaotic:
    // any change of the actions (even 0.2% of a joint's range) flips about one start in ten either
    // way (docs/benchmarks.md), so the check is that int8 does not change the success rate
    // significantly: McNemar's test on the flipped starts at 1%, and the rates within 4 points
    // (the spread of 300 such starts is about +-1.7 points; on a machine whose physics rounds
    // differently the flips are drawn anew, and the check must not fail by chance). On dev-2c:
    // f32 84.3%, int8 82.3%, flipped 16 / 10. The 2 points is measured over 1,000 starts
    // in docs/benchmarks.md.
    let scene = Scene::load().unwrap();
    let int8 = quantise_policy_file(TRAINED_FOR_INT8, None).unwrap();
    let settings = EvalSettings {
        env: EnvConfig::new(Task::Reach),
        episodes: 300,
        seed: EVAL_SEED,
        threads: 2,
        can_quantisation: true,
        envelope: false,
    };
    let a = episode_outcomes(TRAINED_FOR_INT8, &scene, &settings, &|| {}).unwrap();
    let b = episode_outcomes(&int8, &scene, &settings, &|| {}).unwrap();
    let only = |x: bool| {
        a.iter()
            .zip(&b)
            .filter(|(p, q)| (p.1, q.1) == (x, !x))
            .count() as f64
    };
    let (f32_only, int8_only) = (only(true), only(false));
    let rate = |o: &[(f64, bool)]| o.iter().filter(|e| e.1).count() as f64 / o.len() as f64;
    let (ra, rb) = (rate(&a), rate(&b));
    eprintln!("f32 {ra:.3}, int8 {rb:.3}; flipped: f32 only {f32_only}, int8 only {int8_only}");
    assert!(
        ra >= 0.75,
        "the fixture is a trained policy: f32 success {ra}"
    );
    assert!(
        (f32_only - int8_only).abs() <= 2.576 * (f32_only + int8_only).sqrt(),
        "int8 changes the outcome significantly: {f32_only} starts lost, {int8_only} won"
    );
    assert!((rb - ra).abs() <= 0.04, "f32 {ra} vs int8 {rb}");
}

#[test]
fn equalisation_keeps_the_f32_function_and_cuts_the_int8_error() {
    let scene = Scene::load().unwrap();
    let env = EnvConfig::new(Task::Reach);
    let calibration = calibration(TRAINED, &scene, env);
    let eq = equalise_policy_file(TRAINED, &calibration).unwrap();
    // The f32 function is unchanged (f32 rounding of the rewritten weights only), on calibration
    // and on held-out observations.
    assert!(eq.max_f32_change <= 1e-5, "{}", eq.max_f32_change);
    assert!(!eq.on_grid);
    let plain = quantise_policy_file(TRAINED, None).unwrap();
    let (calibrated, change) =
        quantise_policy_file_calibrated(TRAINED, None, &calibration).unwrap();
    assert_eq!(change, eq.max_f32_change);
    let observations = heldout(TRAINED, &scene, env, &calibrated);
    let f32_change = action_error(TRAINED, &eq.file, &observations).unwrap();
    assert!(f32_change.iter().all(|&e| e <= 1e-5), "{f32_change:?}");
    let worst = |e: [f64; 9]| e.iter().copied().fold(0.0, f64::max);
    let before = worst(action_error(TRAINED, &plain, &observations).unwrap());
    let after = worst(action_error(TRAINED, &calibrated, &observations).unwrap());
    assert!(
        after < 0.75 * before,
        "worst error {after} after, {before} before"
    );
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
        seed: EVAL_SEED,
        threads: 2,
        can_quantisation: true,
        envelope: false,
    };
    let a = evaluate_policy_file(&int8, &scene, &settings, &|| {}).unwrap();
    let b = evaluate_policy_file(&int8, &scene, &settings, &|| {}).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.episodes, 4);
}

#[test]
fn the_int8_export_step_reports_grid_error_and_its_own_success() {
    let scene = Scene::load().unwrap();
    let env = EnvConfig::new(Task::Reach);
    let eval = EvalSettings {
        env,
        episodes: 8,
        seed: EVAL_SEED,
        threads: 1,
        can_quantisation: true,
        envelope: false,
    };
    // A quantisation-aware file: on the grid, quantised as it is, within 1% of the f32 actions.
    let x =
        dex_trainer::files::int8_export::export_int8(TRAINED_FOR_INT8, &scene, env, &eval).unwrap();
    assert!(x.on_grid && x.equalisation_change == 0.0);
    assert!(!x.needs_aware_training(), "worst error {}", x.worst_error);
    assert!(x.heldout > 0 && x.calibration > 0);
    assert_eq!(x.eval.episodes, 8);
    let aligned = aligned_copy(&x.file);
    let view = PolicyView::decode(aligned.as_bytes()).unwrap();
    assert!(view.layers().all(|l| l.dtype == LayerDtype::Int8));
    let p = view.body().provenance;
    assert_eq!(p.eval_episodes, 8);
    assert_eq!(p.success_rate, Some(x.eval.success_rate() as f32));
    // A file trained without quantisation is equalised first (its f32 function barely changes).
    let y = dex_trainer::files::int8_export::export_int8(TRAINED, &scene, env, &eval).unwrap();
    assert!(!y.on_grid);
    assert!(y.equalisation_change < 1e-4, "{}", y.equalisation_change);
}

/// A clone of the imitation learner takes the task features and clips its normalised inputs at
/// +-5 (`ObsScaling`), a clip that binds on some inputs: the calibrated export folds no input
/// then (folding would move each input's clip), so the f32 function stays that of the file;
/// cross-layer equalisation still applies, and the int8 file takes the features too.
#[test]
fn a_featured_clone_with_a_binding_clip_keeps_its_f32_function() {
    let shipped = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../policies/grasp.dxpl"
    ))
    .unwrap();
    let scene = Scene::load().unwrap();
    let env = EnvConfig::new(Task::Grasp);
    let calibration = calibration(&shipped, &scene, env);
    let eq = equalise_policy_file(&shipped, &calibration).unwrap();
    assert!(eq.max_f32_change <= 1e-5, "{}", eq.max_f32_change);
    let (int8, _) = quantise_policy_file_calibrated(&shipped, None, &calibration).unwrap();
    let observations = heldout(&shipped, &scene, env, &int8);
    let f32_change = action_error(&shipped, &eq.file, &observations).unwrap();
    assert!(f32_change.iter().all(|&e| e <= 1e-5), "{f32_change:?}");
    let worst = action_error(&shipped, &int8, &observations)
        .unwrap()
        .iter()
        .copied()
        .fold(0.0, f64::max);
    // Measured 0.047 (dev-2c): post-training quantisation of a clone not trained for int8, above
    // the 1% a quantisation-aware policy keeps (`trainer export --int8` warns at 1%).
    eprintln!("featured Grasp clone, int8 worst action error {worst:.4} of a joint's range");
    assert!(worst < 0.1, "{worst}");
    let aligned = aligned_copy(&int8);
    let view = PolicyView::decode(aligned.as_bytes()).unwrap();
    assert_eq!(view.body().obs_dim(), dex_runtime::features::INPUT_MAX);
    assert!(view.layers().all(|l| l.dtype == LayerDtype::Int8));
}
