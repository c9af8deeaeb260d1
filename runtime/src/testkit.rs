//! Synthetic policies on the cell's layout and observation traces, for tests, benchmarks, goldens
//! and the firmware check (`std` only).

use std::vec::Vec;

use dex_policy::synth::{SplitMix64, SynthSpec, synth_policy};
use dex_policy::{Activation, FormatError, Task};

use crate::interface::{ACTION_JOINTS, OBS_DIM, OBSERVATION_FIELDS, quantity_of};

/// A random-weight policy file on the cell's layout with the given hidden widths.
pub fn jaco_policy(hidden: &[u16], seed: u64) -> Result<Vec<u8>, FormatError> {
    let observation: Vec<(&str, u16)> = OBSERVATION_FIELDS
        .iter()
        .map(|f| (f.name, f.size as u16))
        .collect();
    let action: Vec<(&str, f32, f32, f32)> = ACTION_JOINTS
        .iter()
        .map(|j| (j.name, j.scale, j.min, j.max))
        .collect();
    synth_policy(&SynthSpec {
        task: Task::Stack,
        observation: &observation,
        action: &action,
        hidden,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Tanh,
        seed,
    })
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

/// A byte buffer whose start is 8-byte aligned, so a policy's values can be borrowed as `&[f32]`.
pub fn aligned_copy(bytes: &[u8]) -> AlignedBytes {
    let mut words = std::vec![0u64; bytes.len().div_ceil(8)];
    bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
    AlignedBytes {
        words,
        len: bytes.len(),
    }
}

/// Owned bytes with 8-byte alignment (see [`aligned_copy`]).
#[derive(Debug, Clone)]
pub struct AlignedBytes {
    words: Vec<u64>,
    len: usize,
}

impl AlignedBytes {
    /// The bytes.
    pub fn as_bytes(&self) -> &[u8] {
        let all: &[u8] = bytemuck::cast_slice(&self.words);
        &all[..self.len]
    }
}
