//! The policy-gradient stage of `trainer train` (`[pg]`, `--pg-iterations`): after a seed's
//! export, the file is fine-tuned by `group_pg` in `seed-S/pg`, whose file is `trainer pg`'s for
//! the same settings bit for bit; a stopped stage resumes to the same file, a resumed one with
//! other settings or another export is refused, settings out of range are refused before any
//! work (needs MuJoCo).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use dex_trainer::env::{Scene, Task};
use dex_trainer::pipeline::group_pg::{self, GroupPgError};
use dex_trainer::pipeline::train_run::{PG_DIR, TrainEvent, TrainPlan, TrainRunError};
use dex_trainer::pipeline::train_settings::{PgStage, SettingsError, TaskArg, TrainSettings};

mod common;
use common::{REACH_FIXTURE as FIXTURE, fresh_path, reach_fixture_hidden as fixture_hidden};

/// A short Reach run from the fixture, then two iterations of two groups of two noisy episodes.
fn settings(out: &Path) -> TrainSettings {
    let mut s = TrainSettings {
        task: TaskArg::Reach,
        out: out.to_path_buf(),
        transitions: 200,
        checkpoint_every: 200,
        final_eval_episodes: 4,
        select_best_episodes: 0,
        init_policy: Some(FIXTURE.into()),
        pg: Some(PgStage {
            iterations: 2,
            groups: 2,
            replicates: 2,
            arm_noise: 0.5,
            finger_noise: 0.5,
            lr: 1e-3,
            epochs: 1,
            minibatch: 64,
            stall_groups: 0,
            stall_harvest: 0,
            stall_back: 0,
            fresh_anchor: 0.0,
            save_every: 0,
            ..PgStage::default()
        }),
        ..TrainSettings::default()
    };
    s.run.ddpg.actor_hidden = fixture_hidden();
    s.run.obs_norm.enabled = false;
    s.run.learning_starts = 100;
    s
}

/// What a run reported: the policy-gradient iterations and the exported files, in order.
#[derive(Default)]
struct Seen {
    iterations: Vec<u32>,
    exported: Vec<std::path::PathBuf>,
}

fn train(s: &TrainSettings, scene: &Scene, resume: bool, stop_after: Option<u32>) -> (bool, Seen) {
    let stop = AtomicBool::new(false);
    let mut seen = Seen::default();
    let done = TrainPlan::new(s.clone())
        .unwrap()
        .train(scene, resume, &stop, &mut |e| match e {
            TrainEvent::PgIteration { report, .. } => {
                seen.iterations.push(report.iteration);
                if stop_after == Some(report.iteration) {
                    stop.store(true, Ordering::SeqCst);
                }
            }
            TrainEvent::Exported { path, .. } => seen.exported.push(path.to_path_buf()),
            _ => {}
        })
        .unwrap();
    (done, seen)
}

#[test]
fn the_stage_fine_tunes_the_export_as_trainer_pg_does() {
    let scene = Scene::load().unwrap();
    let out = fresh_path("pg-stage", "run");
    let _ = std::fs::remove_dir_all(&out);
    let s = settings(&out);
    let (done, seen) = train(&s, &scene, false, None);
    assert!(done);
    assert_eq!(seen.iterations, vec![0, 1]);
    let seed_dir = out.join("seed-0");
    let final_file = seed_dir.join(PG_DIR).join("policy.dxpl");
    assert_eq!(
        seen.exported,
        vec![seed_dir.join("policy.dxpl"), final_file.clone()],
        "the export, then the stage's file"
    );
    let export = std::fs::read(seed_dir.join("policy.dxpl")).unwrap();
    let tuned = std::fs::read(&final_file).unwrap();
    assert_ne!(tuned, export, "the stage moved the policy");
    // The same fine-tune by `group_pg` alone (what `trainer pg` runs) makes the same file.
    let alone = out.join("alone");
    let g =
        s.pg.as_ref()
            .unwrap()
            .group_pg(seed_dir.join("policy.dxpl"), 0);
    let bytes = group_pg::run(&g, &scene, Task::Reach, &alone, 1, 0, &mut |_| {}).unwrap();
    assert_eq!(bytes, tuned);
    let record: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(seed_dir.join(PG_DIR).join("final_eval.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(record["source"], "group_pg");
    assert_eq!(record["episodes"], 4);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_stopped_stage_resumes_to_the_same_file_and_other_settings_are_refused() {
    let scene = Scene::load().unwrap();
    let whole = fresh_path("pg-stage", "whole");
    let cut = fresh_path("pg-stage", "cut");
    for d in [&whole, &cut] {
        let _ = std::fs::remove_dir_all(d);
    }
    let (done, _) = train(&settings(&whole), &scene, false, None);
    assert!(done);
    let s = settings(&cut);
    let (done, seen) = train(&s, &scene, false, Some(0));
    assert!(!done, "stopped after the first iteration");
    assert_eq!(seen.iterations, vec![0]);
    let file = |d: &Path| std::fs::read(d.join("seed-0").join(PG_DIR).join("policy.dxpl"));
    assert!(file(&cut).is_err(), "no final file before the stage ends");
    // Another step size on resumption: refused, and the checkpoint stays.
    let mut other = s.clone();
    other.pg.as_mut().unwrap().lr = 2e-3;
    let e = TrainPlan::new(other)
        .unwrap()
        .train(&scene, true, &AtomicBool::new(false), &mut |_| {})
        .unwrap_err();
    assert!(
        matches!(
            e,
            TrainRunError::Pg {
                source: GroupPgError::Checkpoint { .. },
                ..
            }
        ),
        "{e:?}"
    );
    let (done, seen) = train(&s, &scene, true, None);
    assert!(done);
    assert_eq!(seen.iterations, vec![1], "only the missing iteration runs");
    assert_eq!(file(&cut).unwrap(), file(&whole).unwrap());
    // More transitions on resumption make another export: the stage does not fine-tune it
    // from the old one's checkpoint.
    let mut longer = s.clone();
    longer.transitions = 400;
    let e = TrainPlan::new(longer)
        .unwrap()
        .train(&scene, true, &AtomicBool::new(false), &mut |_| {})
        .unwrap_err();
    assert!(matches!(e, TrainRunError::PgStartChanged { .. }), "{e:?}");
    assert_eq!(file(&cut).unwrap(), file(&whole).unwrap(), "nothing lost");
    for d in [&whole, &cut] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn stage_settings_out_of_range_are_refused_before_any_work() {
    let out = fresh_path("pg-stage", "bad");
    let _ = std::fs::remove_dir_all(&out);
    let mut s = settings(&out);
    s.pg.as_mut().unwrap().replicates = 1;
    assert!(matches!(
        TrainPlan::new(s.clone()).err(),
        Some(TrainRunError::Settings(SettingsError::Pg(_)))
    ));
    s.pg.as_mut().unwrap().replicates = 2;
    s.pg.as_mut().unwrap().stall_back = 5;
    assert!(matches!(
        TrainPlan::new(s).err(),
        Some(TrainRunError::Settings(SettingsError::Pg(_)))
    ));
    assert!(!out.exists(), "nothing was written");
}
