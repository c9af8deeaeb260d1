//! Integration tests of the MuJoCo Jaco environment (needs `scripts/setup-mujoco.sh` to have run).

#![allow(clippy::expect_used)]

mod common;
use common::scene;

use dex_env::observation::field_offset;
use dex_env::rng::SeedRng;
use dex_env::{Demonstrator, EnvConfig, EnvError, JacoEnv, Reward, Scene, Task};
use dex_runtime::interface::{ACT_DIM, ACTION_JOINTS, OBS_DIM};

fn random_actions(seed: u64, n: usize) -> Vec<[f32; ACT_DIM]> {
    let mut rng = SeedRng::new(seed);
    (0..n)
        .map(|_| std::array::from_fn(|_| rng.uniform(-1.0, 1.0) as f32))
        .collect()
}

fn rollout(env: &mut JacoEnv, seed: u64, actions: &[[f32; ACT_DIM]]) -> Vec<[f32; OBS_DIM]> {
    let mut out = vec![env.reset(seed).expect("reset")];
    for a in actions {
        out.push(env.step(a).expect("step").observation);
    }
    out
}

fn bits(obs: &[[f32; OBS_DIM]]) -> Vec<u32> {
    obs.iter().flatten().map(|x| x.to_bits()).collect()
}

#[test]
fn scene_has_the_expected_sizes_and_actuators() {
    let m = scene().model();
    assert_eq!((m.nq(), m.nv(), m.nu()), (23, 21, 9));
    assert_eq!(m.opt().timestep, 0.002);
    assert_eq!(m.opt().noslip_iterations, 5);
    for (range, joint) in m.actuator_ctrlrange().iter().zip(ACTION_JOINTS) {
        // dm_control: 36 and 48 degrees per second; the interface rounds to 3 decimals.
        assert!(
            (range[1] - f64::from(joint.max)).abs() < 1e-3,
            "{}: {range:?}",
            joint.name
        );
        assert!(
            (range[0] - f64::from(joint.min)).abs() < 1e-3,
            "{}: {range:?}",
            joint.name
        );
    }
}

#[test]
fn observation_follows_the_interface_layout() {
    let mut env = JacoEnv::new(scene(), EnvConfig::new(Task::Stack));
    let obs = env.reset(3).expect("reset");
    for i in 0..6 {
        let (s, c) = (obs[i], obs[6 + i]);
        assert!((s * s + c * c - 1.0).abs() < 1e-5);
    }
    let state = env.reward_state();
    let b1 = field_offset("brick1_pos").expect("field");
    let b2 = field_offset("brick2_pos").expect("field");
    let p1 = field_offset("pinch_to_brick1").expect("field");
    for k in 0..3 {
        assert_eq!(obs[b1 + k], state.brick1_pos[k] as f32);
        assert_eq!(obs[b2 + k], state.brick2_pos[k] as f32);
        assert!((obs[p1 + k] - (state.brick1_pos[k] - state.pinch[k]) as f32).abs() < 1e-6);
    }
    // Both bricks start on the table, apart, and the hand above it.
    assert!(obs[b1 + 2].abs() < 1e-3 && obs[b2 + 2].abs() < 1e-3);
    let apart = (obs[b1] - obs[b2]).hypot(obs[b1 + 1] - obs[b2 + 1]);
    assert!(apart >= 0.08 - 1e-6, "bricks {apart} m apart");
    assert!(
        state.pinch[2] >= 0.145 && state.pinch[2] <= 0.405,
        "pinch z {}",
        state.pinch[2]
    );
}

#[test]
fn same_seed_and_actions_give_bit_identical_observations() {
    let actions = random_actions(11, 12);
    let mut a = JacoEnv::new(scene(), EnvConfig::new(Task::Stack));
    let mut b = JacoEnv::new(scene(), EnvConfig::new(Task::Stack));
    let ra = rollout(&mut a, 5, &actions);
    let rb = rollout(&mut b, 5, &actions);
    assert_eq!(bits(&ra), bits(&rb));
    let rc = rollout(&mut b, 6, &actions);
    assert_ne!(bits(&ra), bits(&rc), "another seed gives another start");
}

#[test]
fn threads_share_one_model_and_agree_with_sequential_runs() {
    let actions = random_actions(2, 8);
    let sequential: Vec<Vec<u32>> = (0..2)
        .map(|seed| {
            bits(&rollout(
                &mut JacoEnv::new(scene(), EnvConfig::new(Task::Grasp)),
                seed,
                &actions,
            ))
        })
        .collect();
    let threaded: Vec<Vec<u32>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..2u64)
            .map(|seed| {
                let actions = &actions;
                s.spawn(move || {
                    bits(&rollout(
                        &mut JacoEnv::new(scene(), EnvConfig::new(Task::Grasp)),
                        seed,
                        actions,
                    ))
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("thread"))
            .collect()
    });
    assert_eq!(sequential, threaded);
}

#[test]
fn snapshot_then_restore_continues_identically() {
    let actions = random_actions(4, 10);
    let mut env = JacoEnv::new(scene(), EnvConfig::new(Task::Stack));
    env.reset(9).expect("reset");
    for a in &actions[..4] {
        env.step(a).expect("step");
    }
    let snap = env.snapshot();
    assert_eq!(snap.steps(), 4);
    let first: Vec<_> = actions[4..]
        .iter()
        .map(|a| env.step(a).expect("step").observation)
        .collect();
    // Wander off, then come back.
    env.reset(123).expect("reset");
    env.step(&actions[0]).expect("step");
    env.restore(&snap).expect("restore");
    assert_eq!(env.steps_taken(), 4);
    let second: Vec<_> = actions[4..]
        .iter()
        .map(|a| env.step(a).expect("step").observation)
        .collect();
    assert_eq!(bits(&first), bits(&second));
}

#[test]
fn non_finite_actions_are_rejected_and_large_ones_clipped() {
    let mut env = JacoEnv::new(scene(), EnvConfig::new(Task::Reach));
    env.reset(1).expect("reset");
    let mut a = [0.0f32; ACT_DIM];
    a[3] = f32::NAN;
    match env.step(&a) {
        Err(EnvError::NonFiniteAction { index: 3, .. }) => {}
        other => panic!("expected NonFiniteAction, got {other:?}"),
    }
    a[3] = f32::INFINITY;
    assert!(matches!(
        env.step(&a),
        Err(EnvError::NonFiniteAction { index: 3, .. })
    ));
    assert_eq!(env.steps_taken(), 0, "a rejected action does not step");
    let big = [7.0f32, -7.0, 1.0, 1.0, -1.0, 3.0, 100.0, -100.0, 0.5];
    env.step(&big).expect("step");
    let ctrl = env.data().ctrl();
    let expect = [0.628, -0.628, 0.628, 0.838, -0.838, 0.838, 5.0, -5.0, 2.5];
    for (c, e) in ctrl.iter().zip(expect) {
        // MuJoCo also clamps to the actuator's ctrlrange (dm_control's exact 36 and 48 deg/s).
        assert!((c - e).abs() < 1e-3, "{ctrl:?}");
    }
}

#[test]
fn episodes_end_after_the_step_budget_and_rewards_follow_the_config() {
    let config = EnvConfig {
        episode_steps: 3,
        ..EnvConfig::new(Task::Stack).with_reward(Reward::FullComposite)
    };
    let mut env = JacoEnv::new(scene(), config);
    env.reset(2).expect("reset");
    let zero = [0.0f32; ACT_DIM];
    let mut dones = vec![];
    for _ in 0..3 {
        let out = env.step(&zero).expect("step");
        let s = env.reward_state();
        // Far from everything: the full composite pays 0.125 r_S1.
        assert!(!out.predicates.reach && !out.predicates.grasp && !out.predicates.stack);
        assert!((f64::from(out.reward) - 0.125 * s.r_s1()).abs() < 1e-6);
        dones.push(out.done);
    }
    assert_eq!(dones, [false, false, true]);
}

#[test]
fn demonstrator_grasps_and_stack_in_hand_starts_held() {
    let mut env = JacoEnv::new(scene(), EnvConfig::new(Task::Grasp));
    env.reset(0).expect("reset");
    let mut demo = Demonstrator::new(Task::Grasp);
    let mut last = None;
    for _ in 0..Task::Grasp.episode_steps() {
        last = Some(env.step(&demo.act(&env)).expect("step"));
    }
    let last = last.expect("steps");
    assert!(
        last.done && last.success,
        "the scripted grasp lifts brick 1"
    );

    let mut env = JacoEnv::new(scene(), EnvConfig::new(Task::StackInHand));
    env.reset(0).expect("reset");
    let p = env.predicates();
    assert!(p.grasp && p.reach, "brick 1 starts lifted in the hand");
    assert_eq!(env.steps_taken(), 0);
}

#[test]
fn environments_can_move_between_threads() {
    fn assert_send<T: Send>() {}
    fn assert_sync<T: Sync>() {}
    assert_send::<JacoEnv>();
    assert_send::<Scene>();
    assert_sync::<Scene>();
}

#[test]
fn close_starts_keep_the_bricks_close_and_repeat_by_seed() {
    let scene = scene();
    let mut env = JacoEnv::new(scene, EnvConfig::new(Task::Stack));
    let (b1, b2) = (
        field_offset("brick1_pos").unwrap(),
        field_offset("brick2_pos").unwrap(),
    );
    let spacing = |o: &[f32; OBS_DIM]| (o[b1] - o[b2]).hypot(o[b1 + 1] - o[b2 + 1]);
    let min = dex_env::random_start::MIN_BRICK_SPACING as f32;
    for seed in 0..8 {
        let o = env.reset_close(seed, 0.09).unwrap();
        let d = spacing(&o);
        // The bricks settle by a fraction of a millimetre after they are placed.
        assert!(d > min - 1e-3 && d < 0.09 + 1e-3, "seed {seed}: {d}");
        let again = env.reset_close(seed, 0.09).unwrap();
        assert_eq!(bits(&[o]), bits(&[again]), "seed {seed} repeats");
    }
    // Above the start square's diagonal the condition is no condition: the task's own start.
    let plain = env.reset(3).unwrap();
    let wide = env
        .reset_close(3, dex_env::random_start::MAX_CLOSE_SPACING)
        .unwrap();
    assert_eq!(bits(&[plain]), bits(&[wide]));
    // No start has the bricks closer than they may be placed; beyond the square, no condition.
    assert!(dex_env::random_start::check_close_spacing(f64::from(0.3f32)).is_ok());
    for bad in [0.05, 0.08, 0.31, f64::NAN, f64::INFINITY] {
        let e = env.reset_close(3, bad).unwrap_err();
        assert!(matches!(e, EnvError::CloseSpacing { .. }), "{bad}: {e}");
        assert!(e.to_string().contains("(0.08, 0.3]"), "{e}");
    }
}
