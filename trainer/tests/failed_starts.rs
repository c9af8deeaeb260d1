//! Failed-start revisits of a fine-tune (`start.failed_starts`): the starting policy is screened on
//! the screening starts before training, the starts it failed are listed in the seed folder's
//! `failed_starts.json` (reused by a resumed run, redone for another file), and settings that
//! cannot screen are refused before any work (needs MuJoCo). That revisits hand over the listed
//! starts at their rate is tested in `env/tests/env_start_states.rs`.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::sync::atomic::AtomicBool;

use dex_trainer::env::Scene;
use dex_trainer::env::evaluate::{EvalSettings, episode_outcomes};
use dex_trainer::env::seeds::{SCREEN_SEED, episode_seed};
use dex_trainer::pipeline::train_run::{Screening, TrainEvent, TrainPlan, TrainRunError};
use dex_trainer::pipeline::train_settings::{SettingsError, StartArg, TaskArg, TrainSettings};

mod common;
use common::{REACH_FIXTURE, fresh_path, reach_fixture_hidden};

/// Screening starts of the tests: the Reach fixture fails some of the first 40 (4 of them).
const SCREENED: u32 = 40;

/// A short Reach fine-tune from the fixture that screens it and revisits every failed start.
fn settings(out: &Path) -> TrainSettings {
    let mut s = TrainSettings {
        task: TaskArg::Reach,
        out: out.to_path_buf(),
        transitions: 300,
        checkpoint_every: 300,
        final_eval_episodes: 2,
        select_best_episodes: 0,
        init_policy: Some(REACH_FIXTURE.into()),
        ..TrainSettings::default()
    };
    s.start.failed_starts = SCREENED;
    s.start.failed_start_probability = 1.0;
    s.run.ddpg.actor_hidden = reach_fixture_hidden();
    s.run.obs_norm.enabled = false;
    s.run.learning_starts = 100;
    s
}

/// Trains `s` (resuming when asked) and returns the screenings it reported and how many it ran.
fn train(s: TrainSettings, scene: &Scene, resume: bool) -> (Vec<Screening>, usize) {
    let mut screened = Vec::new();
    let mut ran = 0;
    let done = TrainPlan::new(s)
        .unwrap()
        .train(scene, resume, &AtomicBool::new(false), &mut |e| match e {
            TrainEvent::ScreeningStarted { starts, .. } => {
                assert_eq!(starts, SCREENED);
                ran += 1;
            }
            TrainEvent::Screened {
                screening,
                probability,
                ..
            } => {
                assert_eq!(probability, 1.0);
                screened.push(screening.clone());
            }
            _ => {}
        })
        .unwrap();
    assert!(done);
    (screened, ran)
}

#[test]
fn the_starting_policy_is_screened_once_and_its_failed_starts_listed() {
    let scene = Scene::load().unwrap();
    let out = fresh_path("failed-starts", "screen");
    let _ = std::fs::remove_dir_all(&out);
    let s = settings(&out);
    let (screened, ran) = train(s.clone(), &scene, false);
    assert_eq!(ran, 1);
    let [screening] = &screened[..] else {
        panic!("one screening per seed: {screened:?}");
    };
    // The list is exactly the screening starts the file fails through the runtime.
    let eval = EvalSettings {
        env: s.reward.env_config(s.task.task()),
        episodes: SCREENED,
        seed: SCREEN_SEED,
        threads: 1,
        can_quantisation: true,
        envelope: false,
    };
    let outcomes = episode_outcomes(
        &std::fs::read(REACH_FIXTURE).unwrap(),
        &scene,
        &eval,
        &|| {},
    )
    .unwrap();
    let failed: Vec<u64> = (0u64..)
        .zip(&outcomes)
        .filter(|(_, o)| !o.1)
        .map(|(i, _)| episode_seed(SCREEN_SEED, i))
        .collect();
    assert!(
        !failed.is_empty(),
        "the fixture fails some screening starts"
    );
    assert!(failed.len() < SCREENED as usize);
    assert_eq!(screening.failed, failed);
    assert_eq!(
        (screening.screened, screening.start_seed),
        (SCREENED, SCREEN_SEED)
    );
    let file = out.join("seed-0").join("failed_starts.json");
    let kept: Screening = serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    assert_eq!(&kept, screening);
    // A resumed run reuses the list without screening again.
    let (again, ran) = train(s.clone(), &scene, true);
    assert_eq!(ran, 0, "the kept screening is reused");
    assert_eq!(again, screened);
    let mut fresh = settings(&fresh_path("failed-starts", "more"));
    fresh.start.failed_starts = SCREENED;
    let kept_dir = fresh.out.join("seed-0");
    std::fs::create_dir_all(&kept_dir).unwrap();
    // A damaged list is an error that names the file, not a silent re-screen.
    std::fs::write(kept_dir.join("failed_starts.json"), "{").unwrap();
    let err = TrainPlan::new(fresh.clone())
        .unwrap()
        .train(&scene, true, &AtomicBool::new(false), &mut |_| {})
        .unwrap_err();
    assert!(
        matches!(err, TrainRunError::DamagedScreening { .. }),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&fresh.out);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_run_of_two_seeds_screens_once() {
    let scene = Scene::load().unwrap();
    let out = fresh_path("failed-starts", "two-seeds");
    let _ = std::fs::remove_dir_all(&out);
    let mut s = settings(&out);
    s.seeds = vec![0, 1];
    let (screened, ran) = train(s, &scene, false);
    assert_eq!(ran, 1, "the second seed takes the first one's list");
    let [a, b] = &screened[..] else {
        panic!("one screening per seed: {screened:?}");
    };
    assert_eq!(a, b);
    for seed in ["seed-0", "seed-1"] {
        let f = out.join(seed).join("failed_starts.json");
        let kept: Screening = serde_json::from_str(&std::fs::read_to_string(&f).unwrap()).unwrap();
        assert_eq!(&kept, a, "{seed}");
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn revisits_without_a_starting_policy_or_with_short_episodes_are_refused() {
    let out = fresh_path("failed-starts", "refused");
    let mut s = settings(&out);
    s.init_policy = None;
    assert!(matches!(
        TrainPlan::new(s.clone()).err(),
        Some(TrainRunError::Settings(
            SettingsError::FailedStartsWithoutInit
        ))
    ));
    s.init_policy = Some(REACH_FIXTURE.into());
    for bad in [
        |s: &mut TrainSettings| s.start.scheme = StartArg::AlongDemonstrations,
        |s: &mut TrainSettings| s.start.failed_start_probability = 1.5,
        |s: &mut TrainSettings| s.start.failed_start_probability = f64::NAN,
        |s: &mut TrainSettings| s.start.failed_starts = 100_001,
    ] {
        let mut b = s.clone();
        bad(&mut b);
        assert!(matches!(
            TrainPlan::new(b).err(),
            Some(TrainRunError::Settings(SettingsError::FailedStarts { .. }))
        ));
    }
    assert!(!out.exists());
}
