//! Seeded synthetic policies on the cell's layout and observation traces (`std` only): a policy
//! file where there is no trained one (`hil-sim run` without `--policy`, the controller node's
//! benchmarks and examples), random observations for benchmarks, and the networks tests, goldens
//! and fuzz targets build on. Deterministic in their seed.

use std::vec::Vec;

use dex_policy::synth::{SplitMix64, SynthSpec, synth_policy};
use dex_policy::{Activation, FormatError, Task};

use crate::interface::{ACTION_JOINTS, OBS_DIM, OBSERVATION_FIELDS, quantity_of};

/// An observation field of a synthetic policy's layout: (name, size).
pub type ObservationField = (&'static str, u16);
/// An action joint of a synthetic policy's layout: (name, scale, min, max).
pub type ActionJoint = (&'static str, f32, f32, f32);

/// The cell's observation fields and action joints, as `dex_policy::synth::SynthSpec` takes them
/// (for tests and fuzz targets that build their own synthetic policies on the cell's layout).
pub fn cell_layout() -> (Vec<ObservationField>, Vec<ActionJoint>) {
    let observation = OBSERVATION_FIELDS
        .iter()
        .map(|f| (f.name, f.size as u16))
        .collect();
    let action = ACTION_JOINTS
        .iter()
        .map(|j| (j.name, j.scale, j.min, j.max))
        .collect();
    (observation, action)
}

/// A random-weight policy file on the cell's layout with the given hidden widths.
pub fn jaco_policy(hidden: &[u16], seed: u64) -> Result<Vec<u8>, FormatError> {
    let (observation, _) = cell_layout();
    relu_tanh_policy(Task::Stack, &observation, hidden, seed)
}

/// A random-weight ReLU network with a tanh output on `observation` and the cell's joints.
fn relu_tanh_policy(
    task: Task,
    observation: &[ObservationField],
    hidden: &[u16],
    seed: u64,
) -> Result<Vec<u8>, FormatError> {
    let (_, action) = cell_layout();
    synth_policy(&SynthSpec {
        task,
        observation,
        action: &action,
        hidden,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Tanh,
        seed,
    })
}

/// A valid policy file on the cell's layout (one hidden layer of `hidden`) whose every output is
/// infinite for any observation: hidden weights 0 and biases `f32::MAX`, output weights and
/// biases `f32::MAX`, linear output. It loads, and faults at its first evaluation.
pub fn jaco_policy_faulting(hidden: u16, seed: u64) -> Result<Vec<u8>, FormatError> {
    let (observation, action) = cell_layout();
    let widths = [hidden];
    let (body, mut values) = dex_policy::synth::synth_parts(&SynthSpec {
        task: Task::Stack,
        observation: &observation,
        action: &action,
        hidden: &widths,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Linear,
        seed,
    })?;
    let h = usize::from(hidden);
    let w1 = 2 * OBS_DIM;
    let b1 = w1 + OBS_DIM * h;
    values[w1..b1].fill(0.0);
    values[b1..].fill(f32::MAX);
    dex_policy::encode_to_vec(&body, &values)
}

/// [`jaco_policy`] after post-training quantisation of every layer to int8 (format version 2).
pub fn jaco_policy_int8(hidden: &[u16], seed: u64) -> Result<Vec<u8>, FormatError> {
    let f32_file = jaco_policy(hidden, seed)?;
    let view = dex_policy::PolicyView::decode(&f32_file)?;
    dex_policy::int8::quantise_policy(&view, |_| true, None)
}

/// `n` pseudo-random observations, each value within 90% of its quantity's limit.
pub fn observation_trace(n: usize, seed: u64) -> Vec<[f32; OBS_DIM]> {
    let mut rng = SplitMix64::new(seed);
    (0..n)
        .map(|_| {
            core::array::from_fn(|i| {
                let limit = quantity_of(i).map_or(1.0, |q| q.limit()) * 0.9;
                rng.uniform(-limit, limit)
            })
        })
        .collect()
}

/// A random-weight policy file that takes the task features (`crate::features`): the cell's
/// observation fields followed by [`crate::features::FEATURE_FIELDS`].
pub fn jaco_policy_with_features(hidden: &[u16], seed: u64) -> Result<Vec<u8>, FormatError> {
    let (mut observation, _) = cell_layout();
    observation.extend(
        crate::features::FEATURE_FIELDS
            .iter()
            .map(|f| (f.name, f.size)),
    );
    relu_tanh_policy(Task::Grasp, &observation, hidden, seed)
}
