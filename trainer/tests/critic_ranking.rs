//! `trainer critic-rank`: a run's critic against rollouts in the simulator, checked against the
//! run's own networks driven independently; the measurement does not depend on the thread count;
//! runs it cannot read and settings out of range are refused.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use dex_trainer::cell::critic_ranking::{CriticRankingError, RankedRun, RankingSettings};
use dex_trainer::env::seeds::episode_seed;
use dex_trainer::env::{JacoEnv, Task};
use dex_trainer::learn::Trainer;
use dex_trainer::pipeline::train_settings::TrainSettings;

mod common;
use common::{fresh_path, reach_fixture_run, scene, text, trainer};

/// A short Reach fine-tune of the fixture (twin critics when `twin`, the observations normalised
/// when `obs_norm`); its seed folder.
fn reach_run(name: &str, twin: bool, obs_norm: bool) -> std::path::PathBuf {
    reach_fixture_run(&fresh_path("rank", name), 300, |s| {
        s.run.obs_norm.enabled = obs_norm;
        s.run.obs_norm.frozen_from_init = obs_norm;
        s.run.updates_per_step = 2;
        s.run.td3.twin_critics = twin;
    })
}

#[test]
fn the_ranking_reads_the_runs_networks_and_the_simulator_as_they_are() {
    let dir = reach_run("twin", true, false);
    let run = RankedRun::from_run(&dir).unwrap();
    assert_eq!(run.raters(), ["critic", "min of twin", "mean of twin"]);
    let settings = RankingSettings {
        states: 3,
        candidates: 3,
        noise: 0.3,
        horizon: 8,
        seed: 123,
        threads: 1,
        replicates: 1,
        jitter: 0.01,
        hold: 1,
    };
    let report = run.measure(scene(), &settings, &|| {}).unwrap();
    assert_eq!(report.per_state.len(), 3);
    let two = run
        .measure(
            scene(),
            &RankingSettings {
                threads: 2,
                ..settings
            },
            &|| {},
        )
        .unwrap();
    assert_eq!(report, two, "the thread count changed the measurement");

    // Candidate 0 is the actor's own action: its value is the actor's episode from the state
    // on, computed here with the checkpoint's actor and a fresh environment; the critics'
    // values are the checkpoint's critics on the state and that action.
    let t = Trainer::load(&dir.join("checkpoint.bin")).unwrap();
    let nets = t.networks();
    let gamma = f64::from(t.config().ddpg.gamma);
    let mut env = JacoEnv::new(
        scene(),
        TrainSettings::default().reward.env_config(Task::Reach),
    );
    for (i, st) in report.per_state.iter().enumerate() {
        assert_eq!(st.start_seed, episode_seed(123, i as u64));
        assert_eq!(st.true_q.len(), 3);
        let mut obs = env.reset(st.start_seed).unwrap();
        let mut a = [0.0f32; 9];
        for _ in 0..st.step {
            t.act(&obs[..nets.obs_dim], &mut a).unwrap();
            obs = env.step(&a).unwrap().observation;
        }
        t.act(&obs[..nets.obs_dim], &mut a).unwrap();
        let mut row = obs[..nets.obs_dim].to_vec();
        assert_eq!(st.input, row, "state {i}: the networks' input");
        assert_eq!(st.candidates[0], a, "state {i}: the actor's action first");
        row.extend_from_slice(&a);
        let q = |params: &[f32]| {
            nets.critic
                .forward(params, &row, 1, &mut nets.critic.scratch(1))
                .unwrap()[0]
        };
        let (q1, q2) = (q(t.critic().1), q(t.twin_critic().unwrap()));
        assert_eq!(st.rated[0][0], q1);
        assert_eq!(st.rated[1][0], q1.min(q2));
        assert_eq!(st.rated[2][0], (q1 + q2) / 2.0);
        let (mut g, mut discount) = (0.0f64, 1.0f64);
        for _ in 0..settings.horizon {
            let out = env.step(&a).unwrap();
            g += discount * f64::from(out.reward);
            discount *= gamma;
            t.act(&out.observation[..nets.obs_dim], &mut a).unwrap();
        }
        assert_eq!(st.true_q[0], g, "state {i}");
        // The noisy candidates differ from the actor's action, so their values are their own.
        assert!(st.rated[0][1] != st.rated[0][0] || st.rated[0][2] != st.rated[0][0]);
    }
    for s in &report.stats {
        assert!((0.0..=1.0).contains(&s.agreement), "{s:?}");
    }
    assert_eq!(report.rollout_agreement, None);

    // Replicates: the first rollout is the candidate as drawn (the single rollout's value);
    // without jitter every replicate repeats it, so one orders the other's pairs fully.
    let exact = run
        .measure(
            scene(),
            &RankingSettings {
                replicates: 3,
                jitter: 0.0,
                ..settings
            },
            &|| {},
        )
        .unwrap();
    assert_eq!(exact.rollout_agreement, Some(1.0));
    let jittered = run
        .measure(
            scene(),
            &RankingSettings {
                replicates: 2,
                ..settings
            },
            &|| {},
        )
        .unwrap();
    for ((one, e), j) in report
        .per_state
        .iter()
        .zip(&exact.per_state)
        .zip(&jittered.per_state)
    {
        assert_eq!(e.replicate_q.len(), 3);
        assert!(e.replicate_q.iter().all(|r| *r == one.true_q));
        for (m, v) in e.true_q.iter().zip(&one.true_q) {
            assert!(
                (m - v).abs() <= 1e-12 * v.abs().max(1.0),
                "mean {m} of three {v}"
            );
        }
        assert_eq!(j.replicate_q[0], one.true_q);
        assert_ne!(j.replicate_q[1], one.true_q, "the jitter changed nothing");
        assert_eq!(j.candidates, one.candidates);
    }

    // Held candidates: a noisy candidate executed three times, then the actor.
    let held = run
        .measure(
            scene(),
            &RankingSettings {
                hold: 3,
                ..settings
            },
            &|| {},
        )
        .unwrap();
    for (st, one) in held.per_state.iter().zip(&report.per_state) {
        assert_eq!(st.candidates, one.candidates);
        let mut obs = env.reset(st.start_seed).unwrap();
        let mut a = [0.0f32; 9];
        for _ in 0..st.step {
            t.act(&obs[..nets.obs_dim], &mut a).unwrap();
            obs = env.step(&a).unwrap().observation;
        }
        let (mut g, mut discount) = (0.0f64, 1.0f64);
        for k in 0..settings.horizon {
            if k < 3 {
                a = st.candidates[1];
            } else {
                t.act(&obs[..nets.obs_dim], &mut a).unwrap();
            }
            let out = env.step(&a).unwrap();
            g += discount * f64::from(out.reward);
            discount *= gamma;
            obs = out.observation;
        }
        assert_eq!(st.true_q[1], g, "held candidate at state {}", st.step);
    }
}

#[test]
fn the_command_prints_and_writes_the_measurement_and_refuses_what_it_cannot_read() {
    let dir = reach_run("plain", false, false);
    let json = fresh_path("rank", "out.json");
    let o = trainer(&[
        "critic-rank",
        dir.to_str().unwrap(),
        "--states",
        "2",
        "--candidates",
        "2",
        "--horizon",
        "4",
        "--quiet",
        "--json",
        json.to_str().unwrap(),
    ]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(out.contains("pairs ordered right"), "{out}");
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(v["per_state"].as_array().unwrap().len(), 2);

    let o = trainer(&["critic-rank", dir.to_str().unwrap(), "--candidates", "1"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("candidates"), "{}", text(&o));
    let o = trainer(&["critic-rank", dir.join("nothing").to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(text(&o).contains("settings.toml"), "{}", text(&o));

    let normalised = reach_run("norm", false, true);
    assert!(matches!(
        RankedRun::from_run(&normalised),
        Err(CriticRankingError::Unsupported(_))
    ));
}
