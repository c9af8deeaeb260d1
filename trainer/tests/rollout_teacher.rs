//! The rollout teacher (issue #26): the failed episodes of a policy file are branched from
//! snapshots, and the winning branches' held states and actions are the labels.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use dex_runtime::Mlp;
use dex_trainer::env::seeds::episode_seed;
use dex_trainer::env::{EnvConfig, JacoEnv, Scene, Task};
use dex_trainer::evaluate::{EVAL_WIDTH, controller_command, physical_to_env_action};
use dex_trainer::pipeline::imitation::{ImitationConfig, ImitationError, run_imitation};
use dex_trainer::pipeline::rollout_teacher::{ROLLOUT_DEMOS, RolloutTeacher};

fn grasp_clone() -> std::path::PathBuf {
    std::path::PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/grasp_clone_session14.dxpl"
    ))
}

/// Small settings: branch points 20 steps apart, four branches of two replicates, noise 0.3.
fn small(episodes: u32) -> RolloutTeacher {
    RolloutTeacher {
        episodes,
        stride: 20,
        candidates: 4,
        arm_noise: 0.3,
        finger_noise: 0.3,
        ..RolloutTeacher::new(grasp_clone())
    }
}

/// Each clean episode of the file from the teacher's starts: its success and its observations.
fn clean_episodes(
    rt: &RolloutTeacher,
    scene: &Scene,
    run_seed: u64,
) -> Vec<(bool, Vec<[f32; 44]>)> {
    let bytes = std::fs::read(&rt.policy).unwrap();
    let aligned = dex_runtime::aligned::aligned_copy(&bytes);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes()).unwrap();
    let mut mlp = Mlp::<EVAL_WIDTH>::new(&view).unwrap();
    let mut env = JacoEnv::new(scene, EnvConfig::new(Task::Grasp));
    (0..u64::from(rt.episodes))
        .map(|i| {
            let mut obs = env.reset(episode_seed(rt.seed(run_seed), i)).unwrap();
            let mut seen = Vec::new();
            loop {
                seen.push(obs);
                let a = physical_to_env_action(
                    &controller_command(&mut mlp, &obs, true, None).unwrap(),
                );
                let out = env.step(&a).unwrap();
                obs = out.observation;
                if out.done {
                    return (out.success, seen);
                }
            }
        })
        .collect()
}

#[test]
fn the_teacher_labels_winning_branches_of_failed_episodes_only() {
    let scene = Scene::load().unwrap();
    // Run seed 4's starts: the clone fails the sixth (found by running the clone on them).
    let rt = small(6);
    let clean = clean_episodes(&rt, &scene, 4);
    let set = rt.label(&scene, Task::Grasp, 4, 2, &|| {}).unwrap();
    let failed: Vec<&Vec<[f32; 44]>> = clean.iter().filter(|e| !e.0).map(|e| &e.1).collect();
    eprintln!(
        "{} failed of {}, {} segments, {} rows",
        failed.len(),
        clean.len(),
        set.header.episodes,
        set.rows.len()
    );
    assert_eq!(set.header.tried, 6);
    assert_eq!(set.header.successes as usize, clean.len() - failed.len());
    assert!(
        !failed.is_empty(),
        "the starts include a failure of the clone"
    );
    assert!(set.header.episodes >= 1, "some branch rescues a failure");
    // Every segment starts at a branch point of a failed episode and holds `hold` steps.
    let segments: Vec<&[dex_trainer::files::demos::DemoRow]> =
        set.rows.split_inclusive(|r| r.last).collect();
    assert_eq!(segments.len() as u32, set.header.episodes);
    for seg in &segments {
        assert!(seg.len() as u32 <= rt.hold);
        let first = seg[0].obs;
        let at_branch = failed
            .iter()
            .any(|obs| obs.iter().step_by(rt.stride as usize).any(|o| o == &first));
        assert!(
            at_branch,
            "a segment starts at a failed episode's branch point"
        );
        for (a, b) in seg.iter().zip(seg.iter().skip(1)) {
            assert_eq!(a.next_obs, b.obs, "a segment's rows are consecutive steps");
        }
        assert!(seg.iter().all(|r| r.label == r.executed));
    }
    // The same settings label the same rows on any thread count.
    let again = rt.label(&scene, Task::Grasp, 4, 1, &|| {}).unwrap();
    assert_eq!(again.rows.len(), set.rows.len());
    assert!(
        again
            .rows
            .iter()
            .zip(&set.rows)
            .all(|(a, b)| a.obs == b.obs && a.label == b.label)
    );
}

#[test]
fn a_run_with_a_rollout_teacher_labels_once_and_refuses_what_does_not_fit() {
    let scene = Scene::load().unwrap();
    let dir = std::env::temp_dir().join(format!("dex-imitate-rollout-{}", std::process::id()));
    std::fs::remove_dir_all(&dir).ok();
    let tiny = ImitationConfig {
        demo_episodes: 3,
        dart_episodes: 2,
        rounds: 0,
        bc: dex_trainer::learn::bc::BcConfig {
            hidden: vec![32],
            steps: 200,
            batch: 64,
            ..dex_trainer::learn::bc::BcConfig::default()
        },
        select_episodes: 0,
        ..ImitationConfig::default()
    };
    let rt = small(3);
    let cfg = ImitationConfig {
        rollout_teacher: Some(rt.clone()),
        ..tiny.clone()
    };
    let s = run_imitation(&scene, &cfg, &dir, &mut |_| {}).unwrap();
    let path = dir.join(ROLLOUT_DEMOS);
    let set = dex_trainer::files::demos::DemoSet::load(&path).unwrap();
    assert_eq!(set.header.tried, 3);
    assert_eq!(s.records[0].episodes, 3 + 2 + 3, "episodes tried");
    // Resumed: the file is read, not relabelled.
    let again = run_imitation(&scene, &cfg, &dir, &mut |_| {}).unwrap();
    assert_eq!(again.records, s.records);
    // Other settings over the same file: refused, the file kept.
    let other = RolloutTeacher {
        candidates: 3,
        ..rt.clone()
    };
    let e = other
        .load_or_label(&scene, Task::Grasp, 0, 1, &path)
        .unwrap_err();
    assert!(e.to_string().contains("other settings"), "{e}");
    assert!(path.exists());
    // Another repeat only weighs the same labels differently: the file is read, not relabelled.
    let reweighted = RolloutTeacher {
        repeat: rt.repeat + 1,
        ..rt.clone()
    };
    let same = reweighted
        .load_or_label(&scene, Task::Grasp, 0, 1, &path)
        .unwrap();
    assert_eq!(same.rows.len(), set.rows.len());
    std::fs::remove_dir_all(&dir).ok();
    // A Grasp policy cannot teach a Reach run: refused before the folder is made.
    let reach = ImitationConfig {
        task: Task::Reach,
        rollout_teacher: Some(rt.clone()),
        ..tiny.clone()
    };
    let e = run_imitation(&scene, &reach, &dir, &mut |_| {}).unwrap_err();
    assert!(matches!(e, ImitationError::Settings(_)), "{e}");
    assert!(!dir.exists());
    for bad in [
        RolloutTeacher {
            episodes: 0,
            ..rt.clone()
        },
        RolloutTeacher {
            hold: 0,
            ..rt.clone()
        },
        RolloutTeacher {
            arm_noise: f32::NAN,
            ..rt.clone()
        },
        RolloutTeacher {
            arm_noise: 0.0,
            finger_noise: 0.0,
            ..rt.clone()
        },
        RolloutTeacher {
            margin: 0.0,
            ..rt.clone()
        },
        RolloutTeacher {
            policy: dir.join("missing.dxpl"),
            ..rt.clone()
        },
    ] {
        let cfg = ImitationConfig {
            rollout_teacher: Some(bad),
            ..tiny.clone()
        };
        assert!(run_imitation(&scene, &cfg, &dir, &mut |_| {}).is_err());
        assert!(!dir.exists(), "refused before the folder is made");
    }
}
