//! End-to-end learner tests on the toy point-mass task: DDPG learns it, one worker is deterministic,
//! a checkpoint round trip continues bit-identically, and two ADPG-R workers learn too.

use dex_trainer::learn::distributed::point_mass::point_mass_config;
use dex_trainer::learn::{Event, PointMass, PointMassConfig, RunConfig, Trainer};
use std::sync::atomic::AtomicBool;

/// The library's point-mass learner (the one the distributed runs use), one worker.
fn small_config(seed: u64) -> RunConfig {
    point_mass_config(seed, 1)
}

fn env(_: usize) -> PointMass {
    PointMass::new(PointMassConfig::default())
}

#[test]
fn ddpg_learns_point_mass() {
    let cfg = small_config(1);
    let mut t = Trainer::new(cfg, 6, 2).expect("trainer");
    let stop = AtomicBool::new(false);
    let started = std::time::Instant::now();
    let mut best = 0.0f64;
    let mut log = Vec::new();
    let s = t
        .run(env, 6_000, &stop, &mut |e| {
            if let Event::Eval(r) = e {
                log.push(r.to_json_line());
            }
        })
        .expect("run");
    for r in &s.records {
        best = best.max(r.success_rate);
    }
    let last = s.records.last().map_or(0.0, |r| r.success_rate);
    eprintln!(
        "point mass: {} transitions, {} updates, {:.1}s, best success {best}, last {last}",
        s.progress.transitions,
        s.progress.updates,
        started.elapsed().as_secs_f64()
    );
    for l in &log {
        eprintln!("{l}");
    }
    assert!(best >= 0.9, "best success rate {best}");
    assert!(last >= 0.9, "final success rate {last}");
}

fn params_bits(t: &Trainer) -> Vec<u32> {
    let (_, a) = t.actor();
    let (_, c) = t.critic();
    a.iter().chain(c).map(|v| v.to_bits()).collect()
}

fn quiet(_: Event<'_>) {}

#[test]
fn one_worker_is_deterministic_and_resumes_bit_identically() {
    let stop = AtomicBool::new(false);
    let run_once = || {
        let mut t = Trainer::new(small_config(7), 6, 2).expect("trainer");
        let s = t.run(env, 1_500, &stop, &mut quiet).expect("run");
        (params_bits(&t), s.records)
    };
    let (a, ra) = run_once();
    let (b, rb) = run_once();
    assert!(a == b, "two runs with one worker and the same seed differ");
    let strip = |r: &[dex_trainer::learn::EvalRecord]| {
        r.iter()
            .map(|r| (r.transitions, r.updates, r.mean_return.to_bits()))
            .collect::<Vec<_>>()
    };
    assert_eq!(strip(&ra), strip(&rb));

    // Same run in two chunks with a checkpoint round trip in between.
    let dir = std::env::temp_dir().join(format!("dex-learn-ckpt-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp dir");
    let path = dir.join("ckpt.bin");
    let mut t = Trainer::new(small_config(7), 6, 2).expect("trainer");
    t.run(env, 700, &stop, &mut quiet).expect("first chunk");
    t.save(&path).expect("save");
    let mut resumed = Trainer::load(&path).expect("load");
    assert_eq!(resumed.progress().transitions, t.progress().transitions);
    resumed
        .run(env, 1_500, &stop, &mut quiet)
        .expect("second chunk");
    assert!(
        params_bits(&resumed) == a,
        "resumed run differs from the uninterrupted one"
    );

    // A damaged checkpoint is refused, and the last good one is untouched by a failed load.
    let mut bytes = std::fs::read(&path).expect("read");
    let mid = bytes.len() / 2;
    bytes[mid] ^= 1;
    assert!(Trainer::from_checkpoint_bytes(&bytes).is_err());
    assert!(Trainer::from_checkpoint_bytes(&bytes[..mid]).is_err());
    assert!(Trainer::load(&path).is_ok());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn two_workers_learn_with_shared_and_per_worker_replay() {
    for shared in [true, false] {
        let mut cfg = small_config(3);
        cfg.workers = 2;
        cfg.replay.shared = shared;
        let mut t = Trainer::new(cfg, 6, 2).expect("trainer");
        let stop = AtomicBool::new(false);
        let s = t.run(env, 8_000, &stop, &mut quiet).expect("run");
        let p = &s.progress;
        assert_eq!(p.transitions_per_worker.len(), 2);
        assert!(p.transitions_per_worker.iter().all(|&n| n > 1_000));
        let best = s.records.iter().map(|r| r.success_rate).fold(0.0, f64::max);
        assert!(best >= 0.9, "shared replay {shared}: best success {best}");
    }
}

#[test]
fn stop_flag_ends_the_run_and_bad_configs_are_refused() {
    let stop = AtomicBool::new(true);
    let mut t = Trainer::new(small_config(1), 6, 2).expect("trainer");
    let s = t.run(env, 1_000_000, &stop, &mut quiet).expect("run");
    assert!(s.stopped && s.progress.transitions < 10);
    let mut bad = small_config(1);
    bad.workers = 0;
    assert!(Trainer::new(bad, 6, 2).is_err());
    let stop = AtomicBool::new(false);
    let mut t = Trainer::new(small_config(1), 6, 2).expect("trainer");
    let first = t.run(env, 60, &stop, &mut quiet).expect("run");
    assert_eq!(
        first.progress.transitions, 75,
        "runs to the end of the episode"
    );
    let again = t.run(env, 60, &stop, &mut quiet).expect("run");
    assert_eq!(
        again.progress.transitions, 75,
        "a reached budget collects nothing"
    );
    let mut t = Trainer::new(small_config(1), 5, 2).expect("trainer");
    assert!(t.run(env, 100, &stop, &mut quiet).is_err());
}

#[test]
fn observation_normalisation_learns_folds_and_resumes() {
    let mut cfg = small_config(5);
    cfg.obs_norm.enabled = true;
    let stop = AtomicBool::new(false);
    let mut t = Trainer::new(cfg.clone(), 6, 2).expect("trainer");
    let s = t.run(env, 6_000, &stop, &mut quiet).expect("run");
    let best = s.records.iter().map(|r| r.success_rate).fold(0.0, f64::max);
    assert!(best >= 0.9, "best success with normalisation {best}");

    // The folded policy on raw observations acts like the trainer (which normalises first).
    let n = t.obs_normalizer().expect("normalisation is on");
    assert!(n.inv_std.iter().all(|s| s.is_finite() && *s > 0.0));
    let (actor, _) = t.actor();
    let folded = t.policy_params().expect("fold");
    let mut scratch = actor.scratch(1);
    let obs = [0.3f32, -0.2, 0.5, 0.1, 0.2, 0.3];
    let exported = actor
        .forward(&folded, &obs, 1, &mut scratch)
        .expect("forward")
        .to_vec();
    let mut direct = [0.0f32; 2];
    t.act(&obs, &mut direct).expect("act");
    for (a, b) in exported.iter().zip(&direct) {
        assert!((a - b).abs() < 1e-4, "{a} vs {b}");
    }

    // Chunked run with a checkpoint in between equals one run, statistics included.
    let mut one = Trainer::new(cfg.clone(), 6, 2).expect("trainer");
    one.run(env, 1_200, &stop, &mut quiet).expect("run");
    let mut two = Trainer::new(cfg, 6, 2).expect("trainer");
    two.run(env, 600, &stop, &mut quiet).expect("run");
    let mut two = Trainer::from_checkpoint_bytes(&two.to_checkpoint_bytes()).expect("restore");
    two.run(env, 1_200, &stop, &mut quiet).expect("run");
    assert!(params_bits(&one) == params_bits(&two));
    assert_eq!(one.obs_normalizer(), two.obs_normalizer());
}

/// Whether every layer of `params` lies on the int8 grid of the exporter.
fn on_grid(t: &Trainer, params: &[f32]) -> bool {
    let (actor, _) = t.actor();
    actor.weight_spans().all(|(start, fan_in, fan_out)| {
        dex_policy::int8::on_grid(fan_in, fan_out, &params[start..start + fan_in * fan_out])
    })
}

#[test]
fn quantisation_aware_training_keeps_learning_on_the_int8_grid() {
    let mut cfg = small_config(1);
    cfg.quantise.aware_from = Some(3_000);
    let stop = AtomicBool::new(false);
    let mut t = Trainer::new(cfg.clone(), 6, 2).expect("trainer");
    t.run(env, 2_000, &stop, &mut quiet).expect("run");
    // Before the quantised phase the policy is the plain f32 actor.
    assert!(!t.quantisation_aware());
    let (_, raw) = t.actor();
    assert_eq!(t.policy_params().expect("params"), raw);
    assert!(!on_grid(&t, raw));
    let s = t.run(env, 6_000, &stop, &mut quiet).expect("run");
    assert!(t.quantisation_aware());
    // Evaluations of the quantised phase (their policy is the int8-grid one) still succeed.
    let quantised: Vec<f64> = s
        .records
        .iter()
        .filter(|r| r.transitions >= 3_000)
        .map(|r| r.success_rate)
        .collect();
    assert!(quantised.len() >= 3, "{quantised:?}");
    let last = quantised.last().copied().unwrap_or(0.0);
    assert!(last >= 0.9, "success of the quantised policy {quantised:?}");
    // The exported policy lies on the grid; the f32 shadow weights it was trained through do not.
    let grid = t.policy_params().expect("params");
    let (actor, raw) = t.actor();
    assert!(on_grid(&t, &grid) && !on_grid(&t, raw));
    // And `act` is that policy.
    let obs = [0.3f32, -0.2, 0.5, 0.1, 0.2, 0.3];
    let mut scratch = actor.scratch(1);
    let want = actor
        .forward(&grid, &obs, 1, &mut scratch)
        .expect("forward")
        .to_vec();
    let mut got = [0.0f32; 2];
    t.act(&obs, &mut got).expect("act");
    assert_eq!(want, got);
    // Deterministic through a checkpoint, like the f32 learner.
    let mut again = Trainer::new(cfg.clone(), 6, 2).expect("trainer");
    again.run(env, 3_500, &stop, &mut quiet).expect("run");
    let mut again = Trainer::from_checkpoint_bytes(&again.to_checkpoint_bytes()).expect("restore");
    again.run(env, 6_000, &stop, &mut quiet).expect("run");
    assert!(params_bits(&again) == params_bits(&t));
    // Normalisation would fold the normaliser into the first layer, off the grid: refused.
    cfg.obs_norm.enabled = true;
    assert!(Trainer::new(cfg, 6, 2).is_err());
}

#[test]
fn fixed_evaluation_starts_repeat_fresh_ones_do_not() {
    // No updates (learning never starts), so the actor is the same at every evaluation: with fixed
    // starts every evaluation gives the same return; with fresh starts (the paper's protocol) the
    // returns differ between evaluations.
    let returns = |fixed: bool| -> Vec<u64> {
        let mut cfg = small_config(4);
        cfg.learning_starts = usize::MAX;
        cfg.eval.fixed_starts = fixed;
        cfg.eval.episodes = 5;
        let mut t = Trainer::new(cfg, 6, 2).expect("trainer");
        let stop = AtomicBool::new(false);
        let s = t.run(env, 3_000, &stop, &mut quiet).expect("run");
        assert!(s.records.len() >= 3);
        s.records.iter().map(|r| r.mean_return.to_bits()).collect()
    };
    let fixed = returns(true);
    assert!(fixed.iter().all(|&r| r == fixed[0]), "{fixed:?}");
    let fresh = returns(false);
    assert!(fresh.iter().any(|&r| r != fresh[0]), "{fresh:?}");
}

/// The point mass without a teacher: [`dex_trainer::learn::Env::expert_action`] says false.
struct NoTeacher(PointMass);

impl dex_trainer::learn::Env for NoTeacher {
    fn obs_dim(&self) -> usize {
        self.0.obs_dim()
    }
    fn act_dim(&self) -> usize {
        self.0.act_dim()
    }
    fn reset(&mut self, rng: &mut dex_trainer::learn::Rng, obs: &mut [f32]) {
        self.0.reset(rng, obs)
    }
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> dex_trainer::learn::Step {
        self.0.step(action, obs)
    }
}

#[test]
fn teacher_labels_hold_the_actor_to_the_teacher_on_its_own_states_and_resume() {
    use dex_trainer::learn::Env;
    let mut cfg = small_config(11);
    cfg.teacher_labels = true;
    cfg.demos.bc_weight = 5.0;
    // A critic that knows nothing yet: the cloning term toward the labels must carry the actor.
    let stop = AtomicBool::new(false);
    let mut t = Trainer::new(cfg.clone(), 6, 2).expect("trainer");
    let s = t.run(env, 1_500, &stop, &mut quiet).expect("run");
    let best = s.records.iter().map(|r| r.success_rate).fold(0.0, f64::max);
    // The actor's action on fresh states points where the teacher's does.
    let mut probe = PointMass::new(PointMassConfig::default());
    let mut rng = dex_trainer::learn::Rng::seed_from_u64(5);
    let (mut obs, mut teacher) = ([0.0f32; 6], [0.0f32; 2]);
    let mut agree = 0;
    for _ in 0..200 {
        probe.reset(&mut rng, &mut obs);
        assert!(probe.expert_action(&mut teacher));
        let mut a = [0.0f32; 2];
        t.act(&obs, &mut a).expect("act");
        agree += usize::from(a[0] * teacher[0] + a[1] * teacher[1] > 0.0);
    }
    assert!(
        agree >= 190,
        "actor agrees with the teacher on {agree}/200 states"
    );
    assert!(best >= 0.9, "best success with teacher labels {best}");

    // The labels go through a checkpoint: a resumed run equals an uninterrupted one.
    let whole = {
        let mut t = Trainer::new(cfg.clone(), 6, 2).expect("trainer");
        t.run(env, 1_200, &stop, &mut quiet).expect("run");
        params_bits(&t)
    };
    let dir = std::env::temp_dir().join(format!("dex-learn-labels-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp dir");
    let path = dir.join("ckpt.bin");
    let mut t = Trainer::new(cfg.clone(), 6, 2).expect("trainer");
    t.run(env, 600, &stop, &mut quiet).expect("first chunk");
    t.save(&path).expect("save");
    let mut resumed = Trainer::load(&path).expect("load");
    resumed
        .run(env, 1_200, &stop, &mut quiet)
        .expect("second chunk");
    assert!(
        params_bits(&resumed) == whole,
        "resumed labelled run differs"
    );
    let _ = std::fs::remove_dir_all(&dir);

    // Refused: labels with n-step returns or without a cloning weight; an env with no teacher.
    let mut bad = cfg.clone();
    bad.n_step = 3;
    assert!(Trainer::new(bad, 6, 2).is_err());
    let mut bad = cfg.clone();
    bad.demos.bc_weight = 0.0;
    assert!(Trainer::new(bad, 6, 2).is_err());
    let mut t = Trainer::new(cfg, 6, 2).expect("trainer");
    let err = t
        .run(
            |_| NoTeacher(PointMass::new(PointMassConfig::default())),
            100,
            &stop,
            &mut quiet,
        )
        .expect_err("no teacher");
    assert!(err.to_string().contains("no teacher"), "{err}");
}
