//! With the MuJoCo plant: a lockstep episode over the bus gives the same actions, return and
//! success as the runtime evaluator driving the environment directly with the CAN quantisation on
//! both sides (what `trainer eval --can-quantisation` measures); on a CAN FD bus (`--fd`, the FD
//! layout) the shipped Grasp policy's episodes are those of the classic bus, bit for bit.
#![cfg(feature = "mujoco")]
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

mod common;

use dex_env::Task;
use dex_hil_sim::plant::{MujocoPlant, Plant};
use dex_policy::PolicyView;
use dex_runtime::Mlp;
use dex_runtime::can::messages::{quantise_action, quantise_observation};
use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_runtime::testkit::{aligned_copy, jaco_policy};

#[test]
fn mujoco_lockstep_over_the_bus_equals_direct_evaluation() {
    let policy = jaco_policy(&[64, 64], 9).unwrap();
    let seed = 4;

    let mut plant = MujocoPlant::new(Task::Stack).unwrap();
    let (over_bus, reports) =
        common::lockstep_over_the_bus(&policy, &mut plant, &[(seed, u32::MAX)]);
    let report = &reports[0];

    let bytes = aligned_copy(&policy);
    let view = PolicyView::decode(bytes.as_bytes()).unwrap();
    let mut mlp = Mlp::<256>::new(&view).unwrap();
    // The controller node runs the safety envelope (its default) after the policy.
    let mut envelope = dex_env::evaluate::eval_envelope();
    let mut plant = MujocoPlant::new(Task::Stack).unwrap();
    let mut obs = plant.reset(seed).unwrap();
    let mut total = 0.0f64;
    let mut direct = Vec::new();
    let success = loop {
        let input: [f32; OBS_DIM] = core::array::from_fn(|i| quantise_observation(i, obs[i]));
        let mut action = [0.0f32; ACT_DIM];
        mlp.act(&input, &mut action).unwrap();
        envelope.apply(&input, &mut action);
        let action = action.map(quantise_action);
        direct.push(action);
        let s = plant.step(&action).unwrap();
        total += f64::from(s.reward);
        obs = s.observation;
        if s.done {
            break s.success;
        }
    };
    assert_eq!(over_bus.len(), direct.len());
    for (i, (a, b)) in over_bus.iter().zip(&direct).enumerate() {
        assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits), "step {i}");
    }
    assert_eq!(report.episode_return.to_bits(), total.to_bits());
    assert_eq!(report.success, success);
    assert_eq!(report.steps_without_action, 0);
}

/// Runs `file` over the bus with the MuJoCo plant on `episodes` starts from `trainer eval`'s seed
/// 1,000,000 and checks every episode's return and success against `trainer eval`'s (CAN
/// quantisation on); returns the successes.
fn over_the_bus_like_trainer_eval(file: &[u8], task: Task, episodes: u64) -> usize {
    use dex_env::evaluate::{EvalSettings, episode_outcomes};
    use dex_env::seeds::{EVAL_SEED, episode_seed};
    use dex_env::{EnvConfig, Scene};
    let seeds: Vec<(u64, u32)> = (0..episodes)
        .map(|i| (episode_seed(EVAL_SEED, i), u32::MAX))
        .collect();
    let mut plant = MujocoPlant::new(task).unwrap();
    let (_, reports) = common::lockstep_over_the_bus(file, &mut plant, &seeds);
    let settings = EvalSettings {
        env: EnvConfig::new(task),
        episodes: episodes as u32,
        seed: EVAL_SEED,
        threads: 1,
        can_quantisation: true,
        // The controller node runs the safety envelope (its default).
        envelope: true,
    };
    let expected = episode_outcomes(file, &Scene::load().unwrap(), &settings, &|| {}).unwrap();
    assert_eq!(reports.len(), expected.len());
    for (r, (ret, success)) in reports.iter().zip(&expected) {
        assert_eq!(r.episode_return.to_bits(), ret.to_bits());
        assert_eq!(r.success, *success);
        assert_eq!(r.steps_without_action, 0);
    }
    reports.iter().filter(|r| r.success).count()
}

#[test]
fn trained_int8_policy_over_the_bus_scores_like_trainer_eval() {
    // The Reach policy trained for int8, quantised as `policy quantise` / `trainer export --int8`
    // do, runs behind the CAN interface with the MuJoCo plant: every episode's return and success
    // equal what `trainer eval` measures for the same start seeds (CAN quantisation on).
    let trained = aligned_copy(include_bytes!(
        "../../trainer/tests/fixtures/reach_int8_seed0.dxpl"
    ));
    let view = PolicyView::decode(trained.as_bytes()).unwrap();
    let int8 = dex_policy::int8::quantise_policy(&view, |_| true, None).unwrap();
    assert!(
        over_the_bus_like_trainer_eval(&int8, Task::Reach, 4) > 0,
        "a trained policy reaches"
    );
}

#[test]
fn shipped_grasp_policy_over_the_bus_scores_like_trainer_eval() {
    // The shipped Grasp policy (policies/grasp.dxpl, cloned from the Markov demonstrator) behind
    // the CAN interface with the MuJoCo plant, and it grasps.
    let file = include_bytes!("../../policies/grasp.dxpl");
    assert!(
        over_the_bus_like_trainer_eval(file, Task::Grasp, 4) >= 3,
        "the shipped Grasp policy grasps"
    );
}

#[test]
fn shipped_grasp_policy_over_an_fd_bus_equals_the_classic_bus() {
    // The same starts (`trainer eval`'s first seeds) on a timed CAN FD bus at 1 Mbit/s nominal,
    // 5 Mbit/s data (the FD layout: two 48-byte observation frames, one 20-byte action frame) and
    // on a timed classic bus at 1 Mbit/s: the policy takes the same quantised values either way,
    // so every action frame carries the same values and the episodes end alike.
    use dex_env::seeds::{EVAL_SEED, episode_seed};
    use dex_hil_sim::compute::{DEFAULT_CPU_HZ, StepCompute};
    use dex_hil_sim::wire::{Stuffing, WireConfig};
    let file = include_bytes!("../../policies/grasp.dxpl");
    let episodes: Vec<(u64, u32)> = (0..4)
        .map(|i| (episode_seed(EVAL_SEED, i), u32::MAX))
        .collect();
    let nominal = WireConfig {
        bitrate: 1_000_000,
        stuffing: Stuffing::Exact,
    };
    // The Cortex-M4F's step (firmware/budget.txt) as the node's compute, as `hil-sim latency`.
    let compute_us = StepCompute::new(None, DEFAULT_CPU_HZ).unwrap().us();
    let (fd, fd_reports) = common::lockstep_over_an_fd_wire(
        file,
        &mut MujocoPlant::new(Task::Grasp).unwrap(),
        &episodes,
        Some(nominal),
        Some(5_000_000),
        compute_us,
        None,
    );
    let (classic, classic_reports) = common::lockstep_over_a_wire(
        file,
        &mut MujocoPlant::new(Task::Grasp).unwrap(),
        &episodes,
        Some(nominal),
        compute_us,
        None,
    );
    let steps: u32 = fd_reports.iter().map(|r| r.steps).sum();
    assert_eq!((fd.len(), classic.len()), (steps as usize, steps as usize));
    for (i, (a, b)) in fd.iter().zip(&classic).enumerate() {
        assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits), "step {i}");
    }
    assert_eq!(fd_reports.len(), episodes.len());
    for (f, c) in fd_reports.iter().zip(&classic_reports) {
        assert_eq!(f.episode_return.to_bits(), c.episode_return.to_bits());
        assert_eq!((f.seed, f.success, f.steps), (c.seed, c.success, c.steps));
        assert_eq!((f.steps_without_action, c.steps_without_action), (0, 0));
    }
    assert!(
        fd_reports.iter().filter(|r| r.success).count() >= 3,
        "the shipped Grasp policy grasps on the FD bus"
    );
}
