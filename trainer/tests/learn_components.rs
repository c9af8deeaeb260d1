//! The learner's components beyond the paper on the toy point-mass task: demonstrations as data
//! (a separate buffer, a batch fraction, the Q-filtered cloning term), TD3's pieces, n-step returns,
//! correlated per-joint noise and the action penalty: each learns, resumes bit-identically from a
//! checkpoint, and refuses bad settings.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::type_complexity)]

use dex_trainer::learn::distributed::point_mass::point_mass_config;
use dex_trainer::learn::{
    DemoBuffer, DemoTransition, Env, EvalConfig, Event, PointMass, PointMassConfig, Rng, RunConfig,
    Td3Config, Trainer,
};
use std::sync::atomic::AtomicBool;

/// The distributed point-mass learner's settings, learning from 200 transitions and evaluating
/// every 10 episodes.
fn small_config(seed: u64) -> RunConfig {
    let base = point_mass_config(seed, 1);
    RunConfig {
        learning_starts: 200,
        eval: EvalConfig {
            every_episodes: 10,
            ..base.eval
        },
        ..base
    }
}

fn env(_: usize) -> PointMass {
    PointMass::new(PointMassConfig::default())
}

fn quiet(_: Event<'_>) {}

/// `episodes` episodes of the scripted point-mass controller (straight at the goal), executed with
/// noise 0.3 on its actions, as demonstration transitions.
fn demonstrations(episodes: usize) -> DemoBuffer {
    let mut env = env(0);
    let mut rng = Rng::seed_from_u64(99);
    let mut rows: Vec<([f32; 6], [f32; 2], [f32; 2], f32, [f32; 6])> = Vec::new();
    for _ in 0..episodes {
        let mut obs = [0.0f32; 6];
        env.reset(&mut rng, &mut obs);
        loop {
            let label = [
                (obs[4] / 0.1).clamp(-1.0, 1.0),
                (obs[5] / 0.1).clamp(-1.0, 1.0),
            ];
            let exec = label.map(|a| rng.normal(a, 0.3).clamp(-1.0, 1.0));
            let mut next = [0.0f32; 6];
            let step = env.step(&exec, &mut next);
            rows.push((obs, label, exec, step.reward, next));
            obs = next;
            if step.done() {
                break;
            }
        }
    }
    let rows: Vec<DemoTransition<'_>> = rows
        .iter()
        .map(|(o, l, e, r, n)| DemoTransition {
            obs: o,
            executed: e,
            label: l,
            reward: *r,
            next_obs: n,
            terminal: false,
        })
        .collect();
    DemoBuffer::from_rows(6, 2, &rows).expect("demo buffer")
}

/// Transitions at the first evaluation with success >= 90% (None: not within the budget).
fn transitions_to_90(t: &mut Trainer, budget: u64) -> Option<u64> {
    let stop = AtomicBool::new(false);
    let s = t.run(env, budget, &stop, &mut quiet).expect("run");
    s.records
        .iter()
        .find(|r| r.success_rate >= 0.9)
        .map(|r| r.transitions)
}

fn best_success(t: &mut Trainer, budget: u64) -> f64 {
    let stop = AtomicBool::new(false);
    let s = t.run(env, budget, &stop, &mut quiet).expect("run");
    s.records.iter().map(|r| r.success_rate).fold(0.0, f64::max)
}

fn params_bits(t: &Trainer) -> Vec<u32> {
    let (_, a) = t.actor();
    let (_, c) = t.critic();
    a.iter().chain(c).map(|v| v.to_bits()).collect()
}

#[test]
fn demonstrations_in_the_batch_with_a_cloning_term_learn_faster() {
    let budget = 3_000;
    let mut results = Vec::new();
    for seed in [1, 2] {
        let mut base = small_config(seed);
        base.updates_per_step = 4;
        let mut plain = Trainer::new(base.clone(), 6, 2).expect("trainer");
        let p = transitions_to_90(&mut plain, budget);
        let mut cfg = base;
        cfg.demos.fraction = 0.25;
        cfg.demos.bc_weight = 1.0;
        let mut fd = Trainer::new(cfg, 6, 2).expect("trainer");
        fd.set_demonstrations(demonstrations(40)).expect("demos");
        let d = transitions_to_90(&mut fd, budget);
        results.push((seed, p, d));
    }
    eprintln!("(seed, plain, with demonstrations) transitions to 90%: {results:?}");
    // Measured on dev-2c: (750, 500) and (1000, 750).
    let total = |f: fn(&(u64, Option<u64>, Option<u64>)) -> Option<u64>| {
        results.iter().map(|r| f(r).unwrap_or(budget)).sum::<u64>()
    };
    let (plain, demo) = (total(|r| r.1), total(|r| r.2));
    assert!(
        results.iter().all(|r| r.2.is_some()) && demo < plain,
        "transitions to 90% over two seeds: plain {plain}, with demonstrations {demo}"
    );
}

#[test]
fn the_cloning_term_pulls_the_actor_onto_the_demonstrator() {
    // With a heavy cloning weight and no filter, the actor becomes the scripted controller on the
    // demonstration states whatever the critic says; without the term it does not.
    let demos = demonstrations(40);
    let gap = |bc_weight: f32| {
        let mut cfg = small_config(3);
        cfg.demos.fraction = 0.5;
        cfg.demos.bc_weight = bc_weight;
        cfg.demos.q_filter = false;
        cfg.updates_per_step = 4;
        let mut t = Trainer::new(cfg, 6, 2).expect("trainer");
        t.set_demonstrations(demos.clone()).expect("demos");
        let stop = AtomicBool::new(false);
        t.run(env, 1_000, &stop, &mut quiet).expect("run");
        cloning_gap(&t, &demos)
    };
    let (with, without) = (gap(10.0), gap(0.0));
    eprintln!("mean |mu - label|: cloning {with}, none {without}");
    assert!(with < 0.15, "cloning term: mean gap {with}");
    assert!(with < 0.5 * without, "cloning {with} vs none {without}");
}

fn all_components(seed: u64) -> RunConfig {
    let mut cfg = small_config(seed);
    cfg.td3 = Td3Config::td3();
    cfg.n_step = 3;
    cfg.noise.correlation = 0.7;
    cfg.noise.scale = vec![1.0, 0.5];
    cfg.ddpg.action_l2 = 1e-3;
    cfg.demos.fraction = 0.25;
    cfg.demos.bc_weight = 0.5;
    cfg.demos.pretrain_updates = 300;
    cfg.obs_norm.enabled = true;
    cfg.obs_norm.frozen_from_demos = true;
    cfg
}

/// Mean |mu(s) - label| of the trainer's actor over 256 demonstration rows.
fn cloning_gap(t: &Trainer, demos: &DemoBuffer) -> f32 {
    let mut batch = dex_trainer::learn::replay::Batch::new(256, 6, 2);
    demos.sample_into(&mut Rng::seed_from_u64(5), 256, &mut batch);
    let mut err = 0.0f32;
    for r in 0..256 {
        let mut a = [0.0f32; 2];
        t.act(&batch.obs[r * 6..(r + 1) * 6], &mut a).expect("act");
        err += (a[0] - batch.bc_target[2 * r]).abs() + (a[1] - batch.bc_target[2 * r + 1]).abs();
    }
    err / 512.0
}

#[test]
fn pretraining_on_demonstrations_starts_from_the_cloned_policy_with_frozen_scaling() {
    let demos = demonstrations(40);
    let mut cfg = small_config(6);
    cfg.demos.fraction = 0.25;
    cfg.demos.bc_weight = 1.0;
    cfg.demos.pretrain_updates = 2_000;
    cfg.obs_norm.enabled = true;
    cfg.obs_norm.frozen_from_demos = true;
    let mut t = Trainer::new(cfg.clone(), 6, 2).expect("trainer");
    t.set_demonstrations(demos.clone()).expect("demos");
    // The scaling is the demonstrations' mean and standard deviation.
    let obs = demos.observations();
    let n = (obs.len() / 6) as f64;
    let mean0 = obs.iter().step_by(6).map(|&v| f64::from(v)).sum::<f64>() / n;
    let frozen = t.obs_normalizer().expect("normaliser");
    assert!(
        (f64::from(frozen.mean[0]) - mean0).abs() < 1e-5,
        "{frozen:?}"
    );
    let before = cloning_gap(&t, &demos);
    let stop = AtomicBool::new(false);
    // One episode (a run ends at an episode's end): the pre-training runs first; the episode is
    // shorter than `learning_starts`, so every update is a pre-training one.
    t.run(env, 1, &stop, &mut quiet).expect("run");
    assert!(t.progress().transitions < 200);
    assert_eq!(t.progress().updates, 2_000, "pre-training updates only");
    let after = cloning_gap(&t, &demos);
    eprintln!("mean |mu - label| before {before}, after pre-training {after}");
    assert!(after < 0.15 && after < 0.3 * before, "{before} -> {after}");
    // The run goes on from there: the first evaluation already succeeds, and the scaling never
    // moves although the workers see states the demonstrations did not.
    let s = t.run(env, 1_500, &stop, &mut quiet).expect("run");
    let first = s.records.first().expect("an evaluation").success_rate;
    assert!(first >= 0.9, "first evaluation after pre-training: {first}");
    assert_eq!(t.obs_normalizer(), Some(frozen));
    // Without pre-training the same run starts from noise.
    cfg.demos.pretrain_updates = 0;
    let mut cold = Trainer::new(cfg, 6, 2).expect("trainer");
    cold.set_demonstrations(demos.clone()).expect("demos");
    cold.run(env, 1, &stop, &mut quiet).expect("run");
    assert!(cloning_gap(&cold, &demos) > 2.0 * after);
}

/// A starting actor that already solves the task: pre-trained on demonstrations.
fn pretrained_actor() -> Vec<f32> {
    let stop = AtomicBool::new(false);
    let mut cfg = small_config(6);
    cfg.demos.fraction = 0.25;
    cfg.demos.bc_weight = 1.0;
    cfg.demos.pretrain_updates = 2_000;
    let mut pre = Trainer::new(cfg, 6, 2).expect("trainer");
    pre.set_demonstrations(demonstrations(40)).expect("demos");
    pre.run(env, 1, &stop, &mut quiet).expect("run");
    pre.actor().1.to_vec()
}

#[test]
fn ibrl_executes_the_proposal_where_the_critic_prefers_it_and_resumes_bit_identically() {
    let stop = AtomicBool::new(false);
    let proposal = pretrained_actor();
    let mut cfg = small_config(9);
    cfg.ibrl = true;
    // The actor starts from fresh weights, the proposal solves the task.
    let mut t = Trainer::new(cfg.clone(), 6, 2).expect("trainer");
    assert!(
        t.run(env, 300, &stop, &mut quiet).is_err(),
        "an IBRL run without its proposal"
    );
    assert!(t.set_proposal(vec![0.0; 7]).is_err(), "another shape");
    t.set_proposal(proposal.clone()).expect("proposal");
    let s = t.run(env, 3_000, &stop, &mut quiet).expect("run");
    let shares: Vec<f64> = s
        .records
        .iter()
        .map(|r| r.proposal_share.expect("share reported"))
        .collect();
    assert!(
        shares.iter().all(|&x| (0.0..=1.0).contains(&x)) && shares.iter().any(|&x| x > 0.0),
        "{shares:?}"
    );
    let best = s.records.iter().map(|r| r.success_rate).fold(0.0, f64::max);
    assert!(
        best >= 0.9,
        "the actor did not learn beside its proposal: {best}"
    );
    // A run without ibrl takes no proposal and reports no share.
    let mut plain = Trainer::new(small_config(9), 6, 2).expect("trainer");
    assert!(plain.set_proposal(proposal.clone()).is_err());
    let s = plain.run(env, 400, &stop, &mut quiet).expect("run");
    assert!(s.records.iter().all(|r| r.proposal_share.is_none()));
    // Bad combinations are refused before training.
    let mut bad = cfg.clone();
    bad.ddpg.residual = Some(8);
    assert!(Trainer::new(bad, 6, 2).is_err(), "with a residual");
    let mut bad = cfg.clone();
    bad.quantise.aware_from = Some(100);
    assert!(Trainer::new(bad, 6, 2).is_err(), "quantisation-aware");

    let run = |chunks: &[u64]| {
        let dir =
            std::env::temp_dir().join(format!("dex-ibrl-{}-{}", std::process::id(), chunks.len()));
        std::fs::create_dir_all(&dir).expect("tmp");
        let path = dir.join("ckpt.bin");
        let mut t = Trainer::new(cfg.clone(), 6, 2).expect("trainer");
        t.set_proposal(proposal.clone()).expect("proposal");
        for &c in chunks {
            t.run(env, c, &stop, &mut quiet).expect("run");
            t.save(&path).expect("save");
            t = Trainer::load(&path).expect("load");
            // The checkpoint does not hold the proposal: running without it is refused.
            assert!(t.run(env, c + 100, &stop, &mut quiet).is_err());
            t.set_proposal(proposal.clone()).expect("proposal");
        }
        let _ = std::fs::remove_dir_all(&dir);
        params_bits(&t)
    };
    assert!(
        run(&[1_200]) == run(&[500, 1_200]),
        "a resumed IBRL run differs from the uninterrupted one"
    );
}

#[test]
fn critic_warm_up_keeps_the_starting_actor_until_the_critic_has_rated_it() {
    let stop = AtomicBool::new(false);
    let start = pretrained_actor();

    let mut warm = small_config(7);
    warm.critic_warmup_updates = 300;
    let mut t = Trainer::new(warm.clone(), 6, 2).expect("trainer");
    t.set_initial_actor(start.clone()).expect("fresh run");
    let (critic0, target0) = (t.critic().1.to_vec(), t.target_critic().to_vec());
    // learning_starts is 200 and R = 1: a run to 260 transitions makes fewer than 300 updates.
    let s = t.run(env, 260, &stop, &mut quiet).expect("run");
    let u = t.progress().updates;
    assert!(u > 0 && u <= 300, "{u} updates");
    assert_eq!(
        t.actor().1,
        &start[..],
        "the actor moved during the warm-up"
    );
    assert_ne!(t.critic().1, &critic0[..], "the critic did not learn");
    assert_ne!(
        t.target_critic(),
        &target0[..],
        "the critic's target did not follow"
    );
    // The evaluations in the warm-up are the starting actor's.
    assert!(
        s.records.iter().all(|r| r.success_rate >= 0.9),
        "{:?}",
        s.records
    );
    t.run(env, 800, &stop, &mut quiet).expect("run");
    assert!(t.progress().updates > 300);
    assert_ne!(
        t.actor().1,
        &start[..],
        "the actor never moved after the warm-up"
    );
    // Only a fresh run takes an initial actor.
    assert!(t.set_initial_actor(start.clone()).is_err());
    // Without the warm-up the actor moves from the first update.
    let mut cold = Trainer::new(small_config(7), 6, 2).expect("trainer");
    cold.set_initial_actor(start.clone()).expect("fresh run");
    cold.run(env, 260, &stop, &mut quiet).expect("run");
    assert_ne!(cold.actor().1, &start[..]);
}

#[test]
fn every_component_together_learns_and_resumes_bit_identically() {
    let stop = AtomicBool::new(false);
    let mut t = Trainer::new(all_components(4), 6, 2).expect("trainer");
    t.set_demonstrations(demonstrations(40)).expect("demos");
    let best = best_success(&mut t, 4_000);
    assert!(best >= 0.9, "all components: best success {best}");
    // Updates: the critics every step, the actor every second one.
    assert!(t.progress().updates > 3_000);

    let run = |chunks: &[u64]| {
        let dir = std::env::temp_dir().join(format!(
            "dex-components-{}-{}",
            std::process::id(),
            chunks.len()
        ));
        std::fs::create_dir_all(&dir).expect("tmp");
        let path = dir.join("ckpt.bin");
        let mut t = Trainer::new(all_components(8), 6, 2).expect("trainer");
        t.set_demonstrations(demonstrations(10)).expect("demos");
        for &c in chunks {
            t.run(env, c, &stop, &mut quiet).expect("run");
            t.save(&path).expect("save");
            t = Trainer::load(&path).expect("load");
            // The checkpoint does not hold the demonstrations: running without them is refused.
            assert!(t.run(env, c + 100, &stop, &mut quiet).is_err());
            t.set_demonstrations(demonstrations(10)).expect("demos");
        }
        let _ = std::fs::remove_dir_all(&dir);
        params_bits(&t)
    };
    assert!(
        run(&[1_200]) == run(&[500, 1_200]),
        "a resumed run with every component differs from the uninterrupted one"
    );
}

#[test]
fn component_settings_out_of_range_are_refused_before_training() {
    let mut cfg = small_config(1);
    cfg.noise.scale = vec![1.0; 3];
    assert!(
        Trainer::new(cfg, 6, 2).is_err(),
        "noise scale of 3 for 2 joints"
    );
    let mut cfg = small_config(1);
    cfg.demos.fraction = 1.5;
    assert!(Trainer::new(cfg, 6, 2).is_err());
    let mut cfg = small_config(1);
    cfg.demos.bc_weight = 1.0;
    assert!(
        Trainer::new(cfg, 6, 2).is_err(),
        "cloning without demo rows"
    );
    let mut cfg = small_config(1);
    cfg.n_step = 0;
    assert!(Trainer::new(cfg, 6, 2).is_err());
    let mut cfg = small_config(1);
    cfg.demos.pretrain_updates = 100;
    assert!(
        Trainer::new(cfg, 6, 2).is_err(),
        "pre-training without demo rows"
    );
    let mut cfg = small_config(1);
    cfg.obs_norm.enabled = true;
    cfg.obs_norm.frozen_from_demos = true;
    assert!(
        Trainer::new(cfg, 6, 2).is_err(),
        "scaling frozen on demonstrations without any"
    );
    let mut cfg = small_config(1);
    cfg.td3.policy_delay = 0;
    assert!(Trainer::new(cfg, 6, 2).is_err());
    let mut cfg = small_config(1);
    cfg.demos.fraction = 0.5;
    let mut t = Trainer::new(cfg, 6, 2).expect("trainer");
    let stop = AtomicBool::new(false);
    assert!(
        t.run(env, 100, &stop, &mut quiet).is_err(),
        "no demos given"
    );
    let other = DemoBuffer::from_rows(
        5,
        2,
        &[DemoTransition {
            obs: &[0.0; 5],
            executed: &[0.0; 2],
            label: &[0.0; 2],
            reward: 0.0,
            next_obs: &[0.0; 5],
            terminal: false,
        }],
    )
    .expect("buffer");
    assert!(
        t.set_demonstrations(other).is_err(),
        "other observation size"
    );
}

#[test]
fn a_residual_actor_keeps_its_base_bit_for_bit_and_learns_the_correction() {
    use dex_trainer::learn::residual;
    let stop = AtomicBool::new(false);
    // A base that does not solve the task: a fresh actor's random weights.
    let base_cfg = small_config(8);
    let base = Trainer::new(base_cfg.clone(), 6, 2).expect("trainer");
    let base_params = base.actor().1.to_vec();
    let mut cfg = base_cfg;
    cfg.ddpg.residual = Some(32);
    let mut t = Trainer::new(cfg.clone(), 6, 2).expect("trainer");
    // The base's shape is what a residual run takes; the composed actor is wider.
    assert!(t.set_initial_actor(vec![0.0; 7]).is_err());
    t.set_initial_actor(base_params.clone()).expect("fresh run");
    let widths: Vec<usize> = t.actor().0.spec().layers.iter().map(|l| l.size).collect();
    assert_eq!(widths, vec![96, 96, 2]);
    let start = t.actor().1.to_vec();
    let mut frozen = vec![1.0f32; start.len()];
    residual::freeze_base(t.actor().0, &cfg.ddpg.actor_hidden, &mut frozen).expect("mask");
    // It starts as the base: same actions on the same observations.
    let (b_net, w_net) = (base.actor().0, t.actor().0);
    let mut rng = Rng::seed_from_u64(5);
    let x: Vec<f32> = (0..6 * 8).map(|_| rng.normal(0.0, 1.0)).collect();
    let (mut sb, mut sw) = (b_net.scratch(8), w_net.scratch(8));
    let yb = b_net
        .forward(&base_params, &x, 8, &mut sb)
        .unwrap()
        .to_vec();
    let yw = w_net.forward(&start, &x, 8, &mut sw).unwrap().to_vec();
    assert!(yb.iter().zip(&yw).all(|(a, b)| (a - b).abs() < 1e-6));
    let s = t.run(env, 6_000, &stop, &mut quiet).expect("run");
    let best = s.records.iter().map(|r| r.success_rate).fold(0.0, f64::max);
    assert!(
        best >= 0.9,
        "the residual did not learn: best success {best}"
    );
    let end = t.actor().1;
    let (mut kept, mut moved) = (0, 0);
    for ((&a, &b), &m) in start.iter().zip(end).zip(&frozen) {
        if m == 0.0 {
            assert_eq!(a.to_bits(), b.to_bits(), "a frozen parameter moved");
            kept += 1;
        } else if a != b {
            moved += 1;
        }
    }
    assert!(kept > 0 && moved > 0, "{kept} kept, {moved} moved");
    // The same run is refused on a base of another shape.
    let mut other = Trainer::new(cfg, 6, 2).expect("trainer");
    assert!(other.set_initial_actor(start).is_err());
}
