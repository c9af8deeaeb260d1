//! Demonstrations as data: recording is deterministic, files round-trip, and bad files (truncated,
//! damaged, another task, another version or layout) are refused with a clear error (needs
//! `scripts/setup-mujoco.sh` to have run).

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;
use common::scene;

use dex_trainer::cell::policy_demo::{DemoSource, PolicyDemonstration, PolicyEnsemble};
use dex_trainer::env::{Demonstrator, Task};
use dex_trainer::files::demos::{
    CLOSE_BURST_STEPS, DEMO_FORMAT_VERSION, DemoError, DemoSet, Keep, RecordSettings, record,
    record_with,
};

fn small(task: Task) -> DemoSet {
    let settings = RecordSettings {
        episodes: 2,
        arm_noise: 0.1,
        finger_noise: 0.05,
        ..RecordSettings::new(task)
    };
    record(
        scene(),
        &DemoSource::Scripted(Demonstrator::new(task)),
        &settings,
        &|| {},
    )
    .unwrap()
}

#[test]
fn recording_is_deterministic_and_round_trips() {
    let a = small(Task::Grasp);
    let b = small(Task::Grasp);
    assert_eq!(a, b, "same settings, same demonstrations");
    assert_eq!(a.header.successes, 2, "the scripted demonstrator grasps");
    assert_eq!(a.rows.len(), 300);
    assert_eq!(a.rows.iter().filter(|r| r.last).count(), 2);
    // Noise goes into the executed action only; labels stay the demonstrator's.
    assert!(a.rows.iter().any(|r| r.label != r.executed));
    // Each row's next observation is the following row's observation inside an episode.
    assert_eq!(a.rows[0].next_obs, a.rows[1].obs);
    let one = a.first_episodes(1);
    assert_eq!(one.rows.len(), 150);
    assert_eq!(one.rows[..], a.rows[..150]);
    assert_eq!(a.first_episodes(9).rows.len(), 300);
    let dir = std::env::temp_dir().join(format!("dex-demos-{}", std::process::id()));
    let path = dir.join("g.dxdm");
    a.save(&path).unwrap();
    let back = DemoSet::load(&path).unwrap();
    assert_eq!(back, a);
    back.check_task(Task::Grasp, &path).unwrap();
    let e = back.check_task(Task::Stack, &path).unwrap_err();
    assert!(matches!(e, DemoError::Mismatch { .. }), "{e}");
    assert!(e.to_string().contains("recorded for task grasp"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_files_are_refused() {
    let a = small(Task::StackInHand);
    let bytes = a.to_bytes();
    let p = std::path::Path::new("x.dxdm");
    // Truncated anywhere.
    for cut in [0, 7, 20, bytes.len() / 2, bytes.len() - 1] {
        let e = DemoSet::from_bytes(&bytes[..cut], p).unwrap_err();
        assert!(matches!(e, DemoError::Corrupt { .. }), "cut {cut}: {e}");
    }
    // One flipped bit in the data.
    let mut flipped = bytes.clone();
    let at = bytes.len() - 100;
    flipped[at] ^= 0x10;
    let e = DemoSet::from_bytes(&flipped, p).unwrap_err();
    assert!(e.to_string().contains("checksum"), "{e}");
    // Another version or layout (re-checksummed so only that differs).
    let current = format!(r#""version":{DEMO_FORMAT_VERSION}"#);
    for (what, from, to) in [
        ("version", current.as_str(), r#""version":9"#),
        ("layout", r#""obs_dim":44"#, r#""obs_dim":43"#),
    ] {
        let mut other = a.clone();
        let json = serde_json::to_string(&other.header).unwrap();
        assert!(json.contains(from), "{json}");
        other.header = serde_json::from_str(&json.replace(from, to)).unwrap();
        let e = DemoSet::from_bytes(&other.to_bytes(), p).unwrap_err();
        assert!(matches!(e, DemoError::Mismatch { .. }), "{what}: {e}");
    }
    // A file of the older, hand-made format (magic DXDEMO01) is refused as such, not as damaged.
    let mut old = bytes.clone();
    old[..8].copy_from_slice(b"DXDEMO01");
    let e = DemoSet::from_bytes(&old, p).unwrap_err();
    assert!(
        matches!(e, DemoError::Mismatch { .. }) && e.to_string().contains("format 01"),
        "{e}"
    );
    // Not a demo file at all.
    let e = DemoSet::from_bytes(b"DXPL....................................", p).unwrap_err();
    assert!(e.to_string().contains("magic"), "{e}");
    // Settings out of range.
    let bad = RecordSettings {
        arm_noise: 2.0,
        ..RecordSettings::new(Task::Grasp)
    };
    assert!(bad.validate().is_err());
    let none = RecordSettings {
        episodes: 0,
        ..RecordSettings::new(Task::Grasp)
    };
    assert!(none.validate().is_err());
}

#[test]
fn the_demonstrator_takes_over_from_a_policy() {
    // A policy of another task (the committed Reach fixture: it goes to the brick but never grasps) leads each episode for up to 60
    // steps; the demonstrator, restarted in the phase that fits the state, still grasps.
    let fixture = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/reach_seed0.dxpl"
    ));
    let Ok(fixture) = fixture else {
        panic!("tests/fixtures/reach_seed0.dxpl is missing");
    };
    let lead = PolicyDemonstration::from_file_bytes(&fixture).unwrap();
    let settings = RecordSettings {
        episodes: 3,
        mode: dex_trainer::files::demos::RecordMode::Takeover { max_step: 60 },
        ..RecordSettings::new(Task::Grasp)
    };
    let src = DemoSource::Scripted(Demonstrator::new(Task::Grasp));
    let set = record_with(scene(), Some(&lead), &src, &settings, &|| {}).unwrap();
    assert!(set.header.successes >= 2, "{:?}", set.header);
    assert!(set.header.source.contains("taking over"));
    let again = record_with(scene(), Some(&lead), &src, &settings, &|| {}).unwrap();
    assert_eq!(set, again, "deterministic");
    // Takeover without a policy is refused.
    assert!(record_with(scene(), None, &src, &settings, &|| {}).is_err());
    // Failures only: the same episodes, the successful ones dropped (the Reach policy alone
    // never grasps, so every DAgger episode it drives fails and is kept).
    let failed = RecordSettings {
        keep: Keep::Failures,
        ..settings
    };
    let kept = record_with(scene(), Some(&lead), &src, &failed, &|| {}).unwrap();
    assert_eq!(kept.header.successes, set.header.successes);
    assert_eq!(kept.header.episodes, 3 - set.header.successes);
    let dagger = RecordSettings {
        mode: dex_trainer::files::demos::RecordMode::Dagger,
        episodes: 2,
        ..failed
    };
    let markov = DemoSource::Markov(dex_trainer::env::MarkovDemonstrator::new(Task::Grasp));
    let all = record_with(scene(), Some(&lead), &markov, &dagger, &|| {}).unwrap();
    assert_eq!((all.header.successes, all.header.episodes), (0, 2));
    assert_eq!(all.rows.len(), 2 * 150);
}

#[test]
fn an_ensemble_labels_with_the_mean_of_its_members() {
    // The two committed Reach policies label the states one of them drives (DAgger, no noise):
    // the ensemble's label is the mean of theirs at every state, an ensemble of one file is that
    // file, and an empty ensemble or one of mixed tasks is refused.
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/");
    let a = std::fs::read(format!("{dir}reach_seed0.dxpl")).unwrap();
    let b = std::fs::read(format!("{dir}reach_int8_seed0.dxpl")).unwrap();
    let lead = PolicyDemonstration::from_file_bytes(&a).unwrap();
    let settings = RecordSettings {
        episodes: 2,
        mode: dex_trainer::files::demos::RecordMode::Dagger,
        keep: Keep::All,
        ..RecordSettings::new(Task::Reach)
    };
    let labels = |src: &DemoSource| {
        let set = record_with(scene(), Some(&lead), src, &settings, &|| {}).unwrap();
        (set.rows.iter().map(|r| r.label).collect::<Vec<_>>(), set)
    };
    let policy =
        |f: &[u8]| DemoSource::Policy(Box::new(PolicyDemonstration::from_file_bytes(f).unwrap()));
    let (la, set_a) = labels(&policy(&a));
    let (lb, _) = labels(&policy(&b));
    let (pair, _) = PolicyEnsemble::from_files(&[a.clone(), b.clone()]).unwrap();
    assert_eq!(pair.len(), 2);
    let (le, set_e) = labels(&DemoSource::Ensemble(pair));
    assert!(
        set_e.header.source.starts_with("policy ensemble"),
        "{}",
        set_e.header.source
    );
    assert_eq!(le.len(), 2 * Task::Reach.episode_steps() as usize);
    let mut differ = 0;
    for ((e, x), y) in le.iter().zip(&la).zip(&lb) {
        for k in 0..e.len() {
            assert!(
                (e[k] - 0.5 * (x[k] + y[k])).abs() < 1e-5,
                "{e:?} {x:?} {y:?}"
            );
            differ += usize::from((x[k] - y[k]).abs() > 1e-3);
        }
    }
    assert!(
        differ > 0,
        "the two fixtures act alike: the test would not see a mean"
    );
    let (one, _) = PolicyEnsemble::from_files(std::slice::from_ref(&a)).unwrap();
    let (l1, set_1) = labels(&DemoSource::Ensemble(one));
    assert_eq!(l1, la);
    assert_eq!(set_1.rows, set_a.rows);
    assert!(PolicyEnsemble::from_files(&[]).is_err());
    let grasp = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../policies/grasp.dxpl"
    ))
    .unwrap();
    assert!(PolicyEnsemble::from_files(&[a, grasp]).is_err());
}

#[test]
fn close_bursts_hold_the_executed_fingers_closing_and_keep_the_labels() {
    // Two Markov Grasp episodes with a burst started at a tenth of the steps: the executed finger
    // actions are +1 for runs of 3-8 steps, while the labels stay the demonstrator's (which opens
    // the fingers again when they close away from the brick).
    let settings = RecordSettings {
        episodes: 2,
        close_bursts: 0.1,
        keep: Keep::All,
        ..RecordSettings::new(Task::Grasp)
    };
    let src = DemoSource::Markov(dex_trainer::env::MarkovDemonstrator::new(Task::Grasp));
    let set = record(scene(), &src, &settings, &|| {}).unwrap();
    assert_eq!(set.rows.len(), 2 * 150);
    let closing =
        |r: &dex_trainer::files::demos::DemoRow| r.executed[6..].iter().all(|&a| a == 1.0);
    let (lo, hi) = CLOSE_BURST_STEPS;
    let mut runs = Vec::new();
    let mut run = 0;
    for r in &set.rows {
        if closing(r) {
            run += 1;
        } else if run > 0 {
            runs.push(run);
            run = 0;
        }
    }
    assert!(runs.len() >= 5, "bursts {runs:?}");
    // A burst is at least `lo` steps (two may follow each other; the demonstrator closes too).
    assert!(
        runs.iter().all(|&n| n >= lo),
        "{runs:?} (burst {lo}..={hi})"
    );
    let relabelled = set
        .rows
        .iter()
        .filter(|r| closing(r) && r.label[6..].iter().any(|&a| a < 0.5))
        .count();
    assert!(
        relabelled > 0,
        "no burst step where the demonstrator wanted otherwise"
    );
    // Deterministic, and the setting travels in the header.
    assert_eq!(record(scene(), &src, &settings, &|| {}).unwrap(), set);
    let back = DemoSet::from_bytes(&set.to_bytes(), std::path::Path::new("x.dxdm")).unwrap();
    assert_eq!(back.header.settings.close_bursts, 0.1);
    // The bursts changed the episodes (recordings without them are the shipped clones' data,
    // reproduced bit for bit: docs/experiments.md).
    let clean = RecordSettings {
        close_bursts: 0.0,
        ..settings
    };
    let plain = record(scene(), &src, &clean, &|| {}).unwrap();
    assert_ne!(plain.rows, set.rows);
}

#[test]
fn open_bursts_hold_the_executed_fingers_opening_and_mix_with_close_bursts() {
    // Open bursts alone: runs of executed -1 on the fingers (the Markov teacher never opens all
    // three fingers fully for 3 steps while approaching a Grasp brick), labels the teacher's.
    let src = DemoSource::Markov(dex_trainer::env::MarkovDemonstrator::new(Task::Grasp));
    let opening =
        |r: &dex_trainer::files::demos::DemoRow| r.executed[6..].iter().all(|&a| a == -1.0);
    let closing =
        |r: &dex_trainer::files::demos::DemoRow| r.executed[6..].iter().all(|&a| a == 1.0);
    let settings = RecordSettings {
        episodes: 2,
        open_bursts: 0.1,
        keep: Keep::All,
        ..RecordSettings::new(Task::Grasp)
    };
    let set = record(scene(), &src, &settings, &|| {}).unwrap();
    let opened = set.rows.iter().filter(|r| opening(r)).count();
    assert!(opened >= 3 * 5, "{opened} steps held opening");
    assert!(
        set.rows
            .iter()
            .any(|r| opening(r) && r.label[6..].iter().any(|&a| a > -0.5))
    );
    // Both kinds: both appear; with open bursts at zero no step is held opening.
    let both = RecordSettings {
        close_bursts: 0.05,
        open_bursts: 0.05,
        ..settings
    };
    let mixed = record(scene(), &src, &both, &|| {}).unwrap();
    assert!(mixed.rows.iter().any(opening) && mixed.rows.iter().any(closing));
    let close_only = RecordSettings {
        close_bursts: 0.1,
        open_bursts: 0.0,
        ..settings
    };
    let a = record(scene(), &src, &close_only, &|| {}).unwrap();
    assert!(!a.rows.iter().any(opening));
    // The header keeps the setting.
    let back = DemoSet::from_bytes(&set.to_bytes(), std::path::Path::new("x.dxdm")).unwrap();
    assert_eq!(back.header.settings.open_bursts, 0.1);
}

#[test]
fn close_spacing_starts_every_episode_with_the_bricks_close() {
    // brick1_pos and brick2_pos in the observation (runtime::interface::OBSERVATION_FIELDS).
    let spacing = |o: &[f32]| (o[24] - o[31]).hypot(o[25] - o[32]);
    let record_of = |close_spacing: Option<f32>| {
        let settings = RecordSettings {
            episodes: 4,
            close_spacing,
            keep: Keep::All,
            ..RecordSettings::new(Task::Stack)
        };
        record(
            scene(),
            &DemoSource::Scripted(Demonstrator::new(Task::Stack)),
            &settings,
            &|| {},
        )
        .unwrap()
    };
    let close = record_of(Some(0.09));
    let firsts: Vec<f32> = std::iter::once(&close.rows[0])
        .chain(close.rows.windows(2).filter(|w| w[0].last).map(|w| &w[1]))
        .map(|r| spacing(&r.obs))
        .collect();
    assert_eq!(firsts.len(), 4, "{firsts:?}");
    // The bricks settle a little after the draw; the draw keeps them 8.0-9.0 cm apart.
    assert!(
        firsts.iter().all(|s| (0.079..=0.091).contains(s)),
        "{firsts:?}"
    );
    assert_eq!(
        close,
        record_of(Some(0.09)),
        "the close starts repeat by seed"
    );
    let own = record_of(None);
    assert_ne!(own.rows[0].obs, close.rows[0].obs);
    assert!(
        spacing(&own.rows[0].obs) > 0.091,
        "this seed's own start is not close"
    );
    // The header records the spacing, a file without it writes no field.
    assert_eq!(close.header.settings.close_spacing, Some(0.09));
    let own_json = serde_json::to_value(own.header.settings).unwrap();
    assert!(own_json.get("close_spacing").is_none(), "{own_json}");
    for bad in [0.08f32, 0.05, 0.31, f32::NAN] {
        let s = RecordSettings {
            close_spacing: Some(bad),
            ..RecordSettings::new(Task::Stack)
        };
        let e = s.validate().unwrap_err();
        assert!(e.to_string().contains("close-start spacing"), "{bad}: {e}");
    }
}
