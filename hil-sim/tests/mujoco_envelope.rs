//! The safety envelope against adversarial policies, with the MuJoCo plant over the bus: saturated,
//! bang-bang alternating and garbage (large random weights) policies, and random ones, run in the
//! controller node (envelope on, its default) for many episodes. No joint passes its envelope
//! limit and the pinch site (MuJoCo's, from the plant's observation: brick 1 minus the
//! pinch-to-brick vector, not the envelope's own kinematics) never goes below the table margin.
//! The same policies without the envelope (the runtime evaluator driving the environment directly)
//! do break those limits, so the test has teeth.
#![cfg(feature = "mujoco")]
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

mod common;

use dex_env::Task;
use dex_hil_sim::plant::{MujocoPlant, Plant, PlantError, PlantStep};
use dex_policy::encode_to_vec;
use dex_policy::synth::{SplitMix64, SynthSpec, synth_parts};
use dex_policy::{Activation, PolicyView, Task as PolicyTask};
use dex_runtime::envelope::EnvelopeConfig;
use dex_runtime::interface::{ACT_DIM, OBS_DIM, OBSERVATION_FIELDS};
use dex_runtime::testkit::{aligned_copy, cell_layout, jaco_policy};

fn offset(name: &str) -> usize {
    let mut start = 0;
    for f in OBSERVATION_FIELDS {
        if f.name == name {
            return start;
        }
        start += f.size;
    }
    panic!("no field {name}")
}

/// A one-layer tanh policy: `values` gets (obs, outputs) weights from `weight` and biases from
/// `bias`; the input normalisation is the identity.
fn linear_policy(
    seed: u64,
    weight: impl Fn(usize, usize, &mut SplitMix64) -> f32,
    bias: impl Fn(usize, &mut SplitMix64) -> f32,
) -> Vec<u8> {
    let (observation, action) = cell_layout();
    let spec = SynthSpec {
        task: PolicyTask::Stack,
        observation: &observation,
        action: &action,
        hidden: &[],
        hidden_activation: Activation::Relu,
        output_activation: Activation::Tanh,
        seed,
    };
    let (body, mut values) = synth_parts(&spec).unwrap();
    let mut rng = SplitMix64::new(seed);
    let n = OBS_DIM;
    for i in 0..n {
        values[i] = 0.0;
        values[n + i] = 1.0;
    }
    // Input-major weights, then biases.
    for i in 0..n {
        for j in 0..ACT_DIM {
            values[2 * n + i * ACT_DIM + j] = weight(i, j, &mut rng);
        }
    }
    for j in 0..ACT_DIM {
        values[2 * n + n * ACT_DIM + j] = bias(j, &mut rng);
    }
    encode_to_vec(&body, &values).unwrap()
}

/// The adversaries: each drives the arm as hard as the clamps allow.
fn adversaries() -> Vec<(&'static str, Vec<u8>)> {
    let vel = offset("joint_vel");
    let sign = |r: &mut SplitMix64| {
        if r.uniform(-1.0, 1.0) < 0.0 {
            -3.0
        } else {
            3.0
        }
    };
    vec![
        // Saturated: a constant full-speed command, all joints one way, then the other, then mixed.
        ("saturated+", linear_policy(1, |_, _, _| 0.0, |_, _| 3.0)),
        ("saturated-", linear_policy(2, |_, _, _| 0.0, |_, _| -3.0)),
        (
            "saturated mixed",
            linear_policy(3, |_, _, _| 0.0, |_, r| sign(r)),
        ),
        // Alternating: full speed against the measured velocity, flipping every cycle.
        (
            "bang-bang",
            linear_policy(
                4,
                move |i, j, _| if i == vel + j { -500.0 } else { 0.0 },
                |j, _| if j % 2 == 0 { 0.2 } else { -0.2 },
            ),
        ),
        // Garbage but finite: large random weights on every input.
        (
            "garbage",
            linear_policy(
                5,
                |_, _, r| r.uniform(-20.0, 20.0),
                |_, r| r.uniform(-3.0, 3.0),
            ),
        ),
        ("random 64-64", jaco_policy(&[64, 64], 11).unwrap()),
    ]
}

/// Worst values seen by a plant wrapper.
#[derive(Debug, Clone, Copy)]
struct Worst {
    /// Largest excursion of a limited joint past the envelope's limit, radians (negative: inside).
    joint_past_limit: f32,
    /// Lowest pinch-site height, metres.
    pinch_z: f32,
}

impl Default for Worst {
    fn default() -> Self {
        Worst {
            joint_past_limit: f32::NEG_INFINITY,
            pinch_z: f32::INFINITY,
        }
    }
}

impl Worst {
    fn observe(&mut self, obs: &[f32; OBS_DIM]) {
        let cfg = EnvelopeConfig::jaco();
        let (sin, cos) = (offset("arm_joint_sin"), offset("arm_joint_cos"));
        for j in 0..6 {
            if !cfg.joint_limited[j] {
                continue;
            }
            // Limited joints' ranges lie inside (0, 2 pi): unwrap there.
            let mut q = obs[sin + j].atan2(obs[cos + j]);
            if q < 0.0 {
                q += std::f32::consts::TAU;
            }
            let past = (q - cfg.joint_max[j]).max(cfg.joint_min[j] - q);
            self.joint_past_limit = self.joint_past_limit.max(past);
        }
        let (b1, to_b1) = (offset("brick1_pos"), offset("pinch_to_brick1"));
        self.pinch_z = self.pinch_z.min(obs[b1 + 2] - obs[to_b1 + 2]);
    }
}

/// The MuJoCo plant, watching every observation.
struct Watched {
    plant: MujocoPlant,
    worst: Worst,
}

impl Plant for Watched {
    fn reset(&mut self, seed: u64) -> Result<[f32; OBS_DIM], PlantError> {
        let obs = self.plant.reset(seed)?;
        self.worst.observe(&obs);
        Ok(obs)
    }
    fn step(&mut self, command: &[f32; ACT_DIM]) -> Result<PlantStep, PlantError> {
        let s = self.plant.step(command)?;
        self.worst.observe(&s.observation);
        Ok(s)
    }
}

const EPISODES: u64 = 3;

#[test]
fn adversarial_policies_over_the_bus_stay_inside_the_envelope() {
    let cfg = EnvelopeConfig::jaco();
    let floor = cfg.table_z + cfg.table_margin;
    let mut unguarded = Worst::default();
    for (name, file) in adversaries() {
        let mut watched = Watched {
            plant: MujocoPlant::new(Task::Stack).unwrap(),
            worst: Worst::default(),
        };
        let seeds: Vec<(u64, u32)> = (0..EPISODES).map(|i| (1000 + i, u32::MAX)).collect();
        let (_, reports) = common::lockstep_over_the_bus(&file, &mut watched, &seeds);
        for r in &reports {
            assert_eq!(
                r.steps_without_action, 0,
                "{name}: the controller answered every step"
            );
        }
        let w = watched.worst;
        println!(
            "{name}: worst joint {:+.4} rad past its envelope limit, lowest pinch {:.4} m",
            w.joint_past_limit, w.pinch_z
        );
        // One control period of tracking lag and the CAN quantisation: a few milliradians.
        assert!(w.joint_past_limit < 0.01, "{name}: joint {w:?}");
        assert!(w.pinch_z > floor - 0.002, "{name}: pinch site {w:?}");

        // The same policy unguarded, directly on the environment.
        let bytes = aligned_copy(&file);
        let view = PolicyView::decode(bytes.as_bytes()).unwrap();
        let mut mlp = dex_runtime::Mlp::<256>::new(&view).unwrap();
        let mut plant = Watched {
            plant: MujocoPlant::new(Task::Stack).unwrap(),
            worst: Worst::default(),
        };
        for &(seed, _) in &seeds {
            let mut obs = plant.reset(seed).unwrap();
            loop {
                let mut a = [0.0f32; ACT_DIM];
                mlp.act(&obs, &mut a).unwrap();
                let s = plant.step(&a).unwrap();
                obs = s.observation;
                if s.done {
                    break;
                }
            }
        }
        unguarded.joint_past_limit = unguarded.joint_past_limit.max(plant.worst.joint_past_limit);
        unguarded.pinch_z = unguarded.pinch_z.min(plant.worst.pinch_z);
    }
    println!("without the envelope: {unguarded:?}");
    assert!(
        unguarded.joint_past_limit > 0.0 && unguarded.pinch_z < floor - 0.002,
        "the adversaries do break the limits without the envelope: {unguarded:?}"
    );
}
