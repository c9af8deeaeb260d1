//! Instructive start states: the schemes hand over states the simulation reached, deterministically,
//! and a held brick stays held after the hand-over (needs `scripts/setup-mujoco.sh` to have run).
//! The schemes with the trainer's parts (the learner's adapter, an exported policy as demonstrator)
//! are tested in `trainer/tests/learner_start_states.rs`.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;
use common::{bits, scene};

use dex_env::{
    Demonstrator, EnvConfig, JacoEnv, Revisits, StartKind, StartScheme, StartStates, Task,
};
use dex_runtime::interface::ACT_DIM;

/// Arm still, fingers closing: what a policy that keeps its grip would command.
const HOLD: [f32; ACT_DIM] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0];

/// Brick 1 is within 3 cm of the pinch site and above 4 cm, for `steps` steps of the hold action.
fn assert_held(env: &mut JacoEnv, steps: usize, what: &str) {
    let dist = |env: &JacoEnv| {
        let s = env.reward_state();
        let d: f64 = (0..3).map(|i| (s.brick1_pos[i] - s.pinch[i]).powi(2)).sum();
        (d.sqrt(), s.brick1_pos[2])
    };
    let (d0, z0) = dist(env);
    assert!(
        d0 < 0.03 && z0 > 0.04,
        "{what}: not held at hand-over: d {d0:.3} z {z0:.3}"
    );
    for t in 0..steps {
        env.step(&HOLD).unwrap();
        let (d, z) = dist(env);
        assert!(
            d < 0.03 && z > 0.04,
            "{what}: brick slipped {t} steps after the hand-over: d {d:.3} z {z:.3}"
        );
    }
}

#[test]
fn scheme_settings_are_checked() {
    for bad in [
        StartScheme::Mixture {
            in_hand_probability: -0.1,
        },
        StartScheme::Mixture {
            in_hand_probability: f64::NAN,
        },
        StartScheme::AlongDemonstrations {
            train_episode_steps: 0,
            demonstrations: 0,
        },
        StartScheme::AlongDemonstrations {
            train_episode_steps: 50,
            demonstrations: dex_env::start_states::MAX_POOL + 1,
        },
    ] {
        assert!(StartStates::scripted(bad, Task::Stack).is_err(), "{bad:?}");
    }
    assert_eq!(
        StartScheme::along_demonstrations().train_episode_steps(150),
        50
    );
    assert_eq!(StartScheme::Original.train_episode_steps(150), 150);
}

#[test]
fn mixture_draws_in_hand_starts_at_its_rate_and_they_are_held() {
    let mut env = JacoEnv::new(scene(), EnvConfig::new(Task::Stack));
    let mut all = StartStates::scripted(
        StartScheme::Mixture {
            in_hand_probability: 1.0,
        },
        Task::Stack,
    )
    .unwrap();
    let mut none = StartStates::scripted(
        StartScheme::Mixture {
            in_hand_probability: 0.0,
        },
        Task::Stack,
    )
    .unwrap();
    let mut half = StartStates::scripted(
        StartScheme::Mixture {
            in_hand_probability: 0.5,
        },
        Task::Stack,
    )
    .unwrap();
    for seed in 0..3 {
        let h = all.reset(&mut env, seed).unwrap();
        assert_eq!(h.kind, StartKind::InHand);
        assert_eq!(env.steps_taken(), 0);
        assert_held(&mut env, 10, &format!("in-hand seed {seed}"));
        let h = none.reset(&mut env, seed).unwrap();
        assert_eq!(h.kind, StartKind::Original);
        // The original start of a seed is the same under every scheme.
        assert_eq!(bits(&h.observation), bits(&env.reset(seed).unwrap()));
    }
    let in_hand = (0..40)
        .filter(|&seed| {
            let kind = half.reset(&mut env, seed).unwrap().kind;
            // The coin is drawn from the seed alone.
            assert_eq!(kind, half.reset(&mut env, seed).unwrap().kind);
            kind == StartKind::InHand
        })
        .count();
    assert!((10..=30).contains(&in_hand), "{in_hand}/40 in-hand starts");
}

#[test]
fn states_along_demonstrations_are_the_demonstrators_states_and_held_bricks_stay_held() {
    let cfg = EnvConfig::new(Task::Stack);
    let mut env = JacoEnv::new(scene(), cfg);
    let mut starts =
        StartStates::scripted(StartScheme::along_demonstrations(), Task::Stack).unwrap();
    let mut ks = Vec::new();
    for seed in 0..12 {
        let h = starts.reset(&mut env, seed).unwrap();
        let StartKind::Demonstration { k, n, solved } = h.kind else {
            panic!("{:?}", h.kind)
        };
        assert!(
            solved,
            "seed {seed}: the demonstrator did not stack within 150 steps"
        );
        assert!((1..=n).contains(&k) && n <= 150, "k {k} n {n}");
        assert_eq!(
            env.steps_taken(),
            0,
            "the episode clock restarts at the hand-over"
        );
        ks.push(k);
        // Same seed, same hand-over, bit for bit.
        let again = starts.reset(&mut env, seed).unwrap();
        assert_eq!(again.kind, h.kind);
        assert_eq!(bits(&again.observation), bits(&h.observation));
        // The state is the one the demonstrator reaches after k steps from the original start.
        let mut replay = JacoEnv::new(scene(), cfg);
        replay.reset(seed).unwrap();
        let mut demo = Demonstrator::new(Task::Stack);
        for _ in 0..k {
            let a = demo.act(&replay);
            replay.step(&a).unwrap();
        }
        assert_eq!(
            bits(replay.observation()),
            bits(&h.observation),
            "seed {seed}"
        );
    }
    assert!(
        ks.iter().any(|&k| k < 40) && ks.iter().any(|&k| k > 60),
        "hand-overs should spread over the trajectory: {ks:?}"
    );
}

/// A demonstration pool hands over, for a seed, a state of the demonstrator along one of its
/// trajectories, the same whatever was drawn before (a fresh `StartStates`, an empty memo, gives
/// the same state: what a resumed run sees), and draws its states from across the trajectories.
#[test]
fn a_demonstration_pool_hands_over_the_demonstrators_states_whatever_came_before() {
    use dex_env::start_states::POOL_SEED_BASE;
    let cfg = EnvConfig::new(Task::Stack);
    let mut env = JacoEnv::new(scene(), cfg);
    let pooled = StartScheme::AlongDemonstrations {
        train_episode_steps: 50,
        demonstrations: 3,
    };
    let mut starts = StartStates::scripted(pooled, Task::Stack).unwrap();
    let seeds: Vec<u64> = (0..10).collect();
    let first: Vec<_> = seeds
        .iter()
        .map(|&s| starts.reset(&mut env, s).unwrap())
        .collect();
    let mut fresh = StartStates::scripted(pooled, Task::Stack).unwrap();
    let mut ns = Vec::new();
    for (&seed, h) in seeds.iter().zip(&first).rev() {
        let again = fresh.reset(&mut env, seed).unwrap();
        assert_eq!(again.kind, h.kind, "seed {seed}");
        assert_eq!(
            bits(&again.observation),
            bits(&h.observation),
            "seed {seed}"
        );
        assert_eq!(env.steps_taken(), 0);
        let StartKind::Demonstration { k, n, solved } = h.kind else {
            panic!("{:?}", h.kind)
        };
        assert!(solved && (1..=n).contains(&k), "k {k} n {n}");
        // The state after k steps of the demonstrator from one of the pool's three starts.
        let found = (0..3).any(|i| {
            let mut replay = JacoEnv::new(scene(), cfg);
            replay.reset(POOL_SEED_BASE + i).unwrap();
            let mut demo = Demonstrator::new(Task::Stack);
            for _ in 0..k {
                let a = demo.act(&replay);
                replay.step(&a).unwrap();
            }
            bits(replay.observation()) == bits(&h.observation)
        });
        assert!(
            found,
            "seed {seed}: not a state of the pool's demonstrations"
        );
        ns.push(n);
    }
    ns.sort_unstable();
    ns.dedup();
    assert!(
        ns.len() >= 2,
        "ten seeds drew from one trajectory only: {ns:?}"
    );
}

#[test]
fn demonstration_states_with_the_brick_in_the_air_stay_held_after_a_hand_over() {
    let cfg = EnvConfig::new(Task::Stack);
    let mut env = JacoEnv::new(scene(), cfg);
    let mut demo = Demonstrator::new(Task::Stack);
    env.reset(0).unwrap();
    let mut aloft = Vec::new();
    for _ in 0..150 {
        let a = demo.act(&env);
        let out = env.step(&a).unwrap();
        let s = env.reward_state();
        let d = (0..3)
            .map(|i| (s.brick1_pos[i] - s.pinch[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        if out.predicates.grasp && !out.predicates.stack && d < 0.03 && s.brick1_pos[2] > 0.045 {
            aloft.push((env.steps_taken(), env.snapshot()));
        }
    }
    assert!(aloft.len() >= 3, "the demonstrator never carried the brick");
    // First, middle and last carried state, each handed to a fresh environment.
    for i in [0, aloft.len() / 2, aloft.len() - 1] {
        let (k, snap) = &aloft[i];
        let mut handed = JacoEnv::new(scene(), cfg);
        handed.restore(snap).unwrap();
        handed.begin_episode();
        assert_eq!(handed.steps_taken(), 0);
        assert_held(&mut handed, 10, &format!("demonstration step {k}"));
    }
}

#[test]
fn revisits_hand_over_the_listed_original_starts_at_their_rate() {
    let scene = scene();
    let mut env = JacoEnv::new(scene, EnvConfig::new(Task::Stack));
    let listed = [11u64, 22, 33];
    let revisits = |probability| Revisits {
        seeds: listed.to_vec(),
        probability,
    };
    let mut always = StartStates::scripted(StartScheme::Original, Task::Stack)
        .unwrap()
        .with_revisits(revisits(1.0))
        .unwrap();
    let mut seen = std::collections::HashSet::new();
    for seed in 100..130 {
        let h = always.reset(&mut env, seed).unwrap();
        let StartKind::Revisit { seed: s } = h.kind else {
            panic!("seed {seed}: {:?} is not a revisit", h.kind);
        };
        assert!(listed.contains(&s));
        seen.insert(s);
        assert_eq!(env.steps_taken(), 0);
        // The revisited seed's original start, bit for bit.
        assert_eq!(bits(&h.observation), bits(&env.reset(s).unwrap()));
    }
    assert_eq!(seen.len(), listed.len(), "every listed start is picked");
    // A quarter of the episodes, decided by the episode seed alone; the others keep the scheme's
    // start (the original start of their own seed).
    let mut quarter = StartStates::scripted(StartScheme::Original, Task::Stack)
        .unwrap()
        .with_revisits(revisits(0.25))
        .unwrap();
    let n = (0..200)
        .filter(|&seed| {
            let h = quarter.reset(&mut env, seed).unwrap();
            assert_eq!(h.kind, quarter.reset(&mut env, seed).unwrap().kind);
            match h.kind {
                StartKind::Revisit { .. } => true,
                StartKind::Original => {
                    assert_eq!(bits(&h.observation), bits(&env.reset(seed).unwrap()));
                    false
                }
                k => panic!("{k:?}"),
            }
        })
        .count();
    assert!((30..=70).contains(&n), "{n}/200 revisits at p = 0.25");
    // No list: no revisit, whatever the probability.
    let mut none = StartStates::scripted(StartScheme::Original, Task::Stack)
        .unwrap()
        .with_revisits(Revisits {
            seeds: Vec::new(),
            probability: 1.0,
        })
        .unwrap();
    assert_eq!(none.reset(&mut env, 5).unwrap().kind, StartKind::Original);
    for bad in [-0.1, 1.5, f64::NAN] {
        assert!(
            StartStates::scripted(StartScheme::Original, Task::Stack)
                .unwrap()
                .with_revisits(revisits(bad))
                .is_err(),
            "probability {bad}"
        );
    }
}
