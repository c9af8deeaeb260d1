//! Train a tiny Jaco Reach actor, export it, and check that the policy file, run through the
//! `dex-runtime` evaluator, acts like the learner's own actor; evaluation and export are deterministic.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use std::sync::atomic::AtomicBool;

use dex_policy::PolicyView;
use dex_runtime::Mlp;
use dex_runtime::features::{INPUT_MAX, policy_input};
use dex_runtime::interface::{ACT_DIM, ACTION_JOINTS, OBS_DIM};
use dex_runtime::testkit::aligned_copy;
use dex_trainer::cell::jaco::JacoLearnEnv;
use dex_trainer::env::{EnvConfig, JacoEnv, Reward, Scene, Task};
use dex_trainer::evaluate::{EvalSettings, episode_seed, evaluate_policy_file};
use dex_trainer::files::export::{ExportInfo, ObsNormalisation, export_actor};
use dex_trainer::learn::{RunConfig, Trainer};

fn tiny_run(seed: u64) -> (Trainer, Vec<u8>) {
    tiny_run_with(seed, false)
}

/// A tiny Reach run; with `features` its networks take the task features too.
fn tiny_run_with(seed: u64, features: bool) -> (Trainer, Vec<u8>) {
    let scene = Scene::load().unwrap();
    let mut cfg = RunConfig::default();
    cfg.ddpg.actor_hidden = vec![16, 16];
    cfg.ddpg.critic_hidden = vec![16, 16];
    cfg.learning_starts = 100;
    cfg.eval.every_episodes = 0;
    cfg.obs_norm.enabled = true;
    cfg.seed = seed;
    let env_cfg = EnvConfig::new(Task::Reach).with_reward(Reward::ReachShaping);
    let inputs = if features { INPUT_MAX } else { OBS_DIM };
    let mut trainer = Trainer::new(cfg, inputs, ACT_DIM).unwrap();
    let stop = AtomicBool::new(false);
    trainer
        .run(
            |_| JacoLearnEnv::new(&scene, env_cfg).with_features(features),
            400,
            &stop,
            &mut |_| {},
        )
        .unwrap();
    let (net, params) = trainer.actor();
    let n = trainer.obs_normalizer().unwrap();
    let file = export_actor(
        net,
        params,
        Some(ObsNormalisation {
            mean: &n.mean,
            inv_std: &n.inv_std,
        }),
        &ExportInfo {
            task: Task::Reach,
            seed,
            transitions: trainer.progress().transitions,
            success_rate: None,
            eval_episodes: 0,
        },
    )
    .unwrap();
    (trainer, file)
}

#[test]
fn exported_policy_acts_like_the_learner_and_runs_deterministically() {
    let (trainer, file) = tiny_run(3);
    let aligned = aligned_copy(&file);
    let view = PolicyView::decode(aligned.as_bytes()).unwrap();
    assert_eq!(view.body().task, dex_policy::Task::Reach);
    assert_eq!(view.body().provenance.seed, 3);
    assert!(view.body().provenance.transitions >= 400);
    let mut mlp = Mlp::<64>::new(&view).unwrap();

    // Along a real trajectory, the runtime's command equals the learner's action times the joint
    // scale (up to float rounding: the runtime divides by std, the learner multiplies by 1/std).
    let scene = Scene::load().unwrap();
    let mut env = JacoEnv::new(&scene, EnvConfig::new(Task::Reach));
    let mut obs = env.reset(episode_seed(7, 0)).unwrap();
    for _ in 0..20 {
        let mut learner = [0.0f32; ACT_DIM];
        trainer.act(&obs, &mut learner).unwrap();
        let mut runtime = [0.0f32; ACT_DIM];
        mlp.act(&obs, &mut runtime).unwrap();
        for ((r, l), j) in runtime.iter().zip(&learner).zip(ACTION_JOINTS) {
            let expected = (l * j.scale).clamp(j.min, j.max);
            assert!(
                (r - expected).abs() < 1e-4 * j.scale.max(1.0),
                "{r} vs {expected}"
            );
        }
        obs = env.step(&learner).unwrap().observation;
    }

    // Evaluation through the runtime is deterministic, with or without CAN quantisation.
    let settings = EvalSettings {
        env: EnvConfig::new(Task::Reach),
        episodes: 4,
        seed: 11,
        threads: 2,
        can_quantisation: true,
        envelope: false,
    };
    let a = evaluate_policy_file(&file, &scene, &settings, &|| {}).unwrap();
    let b = evaluate_policy_file(&file, &scene, &settings, &|| {}).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.episodes, 4);
    assert!(a.ci95.0 <= a.success_rate() && a.success_rate() <= a.ci95.1);

    // A one-worker run with the same seed exports the same bytes.
    let (_, again) = tiny_run(3);
    assert_eq!(again, file);
}

#[test]
fn evaluation_refuses_a_policy_for_another_cell() {
    let scene = Scene::load().unwrap();
    let other = include_bytes!("../../policy-format/tests/golden/small.dxpl");
    let settings = EvalSettings {
        env: EnvConfig::new(Task::Reach),
        episodes: 1,
        seed: 0,
        threads: 1,
        can_quantisation: false,
        envelope: false,
    };
    let err = evaluate_policy_file(other, &scene, &settings, &|| {}).unwrap_err();
    assert!(err.to_string().contains("does not match"), "{err}");
    let mut corrupt = other.to_vec();
    corrupt[30] ^= 1;
    let err = evaluate_policy_file(&corrupt, &scene, &settings, &|| {}).unwrap_err();
    assert!(err.to_string().contains("CRC"), "{err}");
}

/// A learner with the task features (`TrainSettings::features`): its environment hands it the
/// observation and the features, its file lists them, and the runtime, feeding them through
/// `policy_input` as the controller does, commands what the learner's actor does.
#[test]
fn a_featured_learner_exports_a_file_the_runtime_feeds_the_same_features() {
    let (trainer, file) = tiny_run_with(4, true);
    let aligned = aligned_copy(&file);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes()).unwrap();
    assert_eq!(view.body().obs_dim(), INPUT_MAX);
    let mut mlp = Mlp::<64>::new(&view).unwrap();
    let scene = Scene::load().unwrap();
    let mut env = JacoEnv::new(&scene, EnvConfig::new(Task::Reach));
    let mut obs = env.reset(episode_seed(7, 0)).unwrap();
    let mut differs = 0;
    for _ in 0..20 {
        let mut buf = [0.0f32; INPUT_MAX];
        let input = policy_input(&obs, INPUT_MAX, &mut buf);
        let mut learner = [0.0f32; ACT_DIM];
        trainer.act(input, &mut learner).unwrap();
        let mut runtime = [0.0f32; ACT_DIM];
        mlp.act(input, &mut runtime).unwrap();
        for ((r, l), j) in runtime.iter().zip(&learner).zip(ACTION_JOINTS) {
            let expected = (l * j.scale).clamp(j.min, j.max);
            assert!(
                (r - expected).abs() < 1e-4 * j.scale.max(1.0),
                "{r} vs {expected}"
            );
        }
        // The features reach the actor: zeroing them changes its action.
        buf[OBS_DIM..].fill(0.0);
        let mut blind = [0.0f32; ACT_DIM];
        trainer.act(&buf, &mut blind).unwrap();
        differs += usize::from(blind != learner);
        obs = env.step(&learner).unwrap().observation;
    }
    assert!(differs > 10, "{differs}");
    let settings = EvalSettings {
        env: EnvConfig::new(Task::Reach),
        episodes: 2,
        seed: 11,
        threads: 1,
        can_quantisation: true,
        envelope: false,
    };
    assert_eq!(
        evaluate_policy_file(&file, &scene, &settings, &|| {})
            .unwrap()
            .episodes,
        2
    );
}
