//! Synthetic policies with seeded pseudo-random weights, for tests, benchmarks and golden files.

use std::vec::Vec;

use crate::body::{ActionJoint, Activation, Body, LayerSpec, ObsField, Provenance, Task};
use crate::encode::encode_to_vec;
use crate::error::FormatError;

/// What a synthetic policy looks like.
#[derive(Debug, Clone)]
pub struct SynthSpec<'a> {
    /// Task written into the body.
    pub task: Task,
    /// Observation fields (name, size).
    pub observation: &'a [(&'a str, u16)],
    /// Action joints (name, scale, min, max).
    pub action: &'a [(&'a str, f32, f32, f32)],
    /// Hidden layer widths.
    pub hidden: &'a [u16],
    /// Activation of the hidden layers.
    pub hidden_activation: Activation,
    /// Activation of the output layer.
    pub output_activation: Activation,
    /// Seed of the weights.
    pub seed: u64,
}

/// SplitMix64: a tiny, well-known generator, so goldens never depend on an RNG crate's version.
/// The workspace's one SplitMix64: it also seeds the xoshiro256++ core (`dex_env::rng::SeedRng`).
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator seeded with `seed`.
    pub fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        let unit = (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32;
        lo + (hi - lo) * unit
    }
}

/// Builds the body and the stored values of a synthetic policy.
pub fn synth_parts<'a>(spec: &SynthSpec<'a>) -> Result<(Body<'a>, Vec<f32>), FormatError> {
    let mut observation = heapless::Vec::new();
    for &(name, size) in spec.observation {
        observation
            .push(ObsField { name, size })
            .map_err(|_| FormatError::MalformedBody)?;
    }
    let mut action = heapless::Vec::new();
    for &(name, scale, min, max) in spec.action {
        action
            .push(ActionJoint {
                name,
                scale,
                min,
                max,
            })
            .map_err(|_| FormatError::MalformedBody)?;
    }
    let mut layers = heapless::Vec::new();
    for &outputs in spec.hidden {
        layers
            .push(LayerSpec::f32(outputs, spec.hidden_activation))
            .map_err(|_| FormatError::MalformedBody)?;
    }
    layers
        .push(LayerSpec::f32(
            spec.action.len() as u16,
            spec.output_activation,
        ))
        .map_err(|_| FormatError::MalformedBody)?;
    let body = Body {
        task: spec.task,
        observation,
        obs_clip: 5.0,
        action,
        control_period_us: 50_000,
        layers,
        provenance: Provenance {
            trainer_version: "synthetic",
            seed: spec.seed,
            transitions: 0,
            success_rate: None,
            eval_episodes: 0,
        },
    };
    let mut rng = SplitMix64::new(spec.seed);
    let obs = body.obs_dim();
    let mut values = Vec::with_capacity(body.stored_values().unwrap_or(0));
    values.extend((0..obs).map(|_| rng.uniform(-0.5, 0.5)));
    values.extend((0..obs).map(|_| rng.uniform(0.5, 2.0)));
    let mut inputs = obs;
    for layer in &body.layers {
        let outputs = usize::from(layer.outputs);
        let bound = (6.0 / (inputs + outputs) as f32).sqrt();
        values.extend((0..inputs * outputs).map(|_| rng.uniform(-bound, bound)));
        values.extend((0..outputs).map(|_| rng.uniform(-0.1, 0.1)));
        inputs = outputs;
    }
    Ok((body, values))
}

/// Encodes a synthetic policy file.
pub fn synth_policy(spec: &SynthSpec<'_>) -> Result<Vec<u8>, FormatError> {
    let (body, values) = synth_parts(spec)?;
    encode_to_vec(&body, &values)
}

/// The spec of the committed golden file `tests/golden/small.dxpl`: a 2-field, 5-value observation,
/// 3 joints and an 8-wide ReLU hidden layer with a tanh output.
pub fn golden_small_spec() -> SynthSpec<'static> {
    SynthSpec {
        task: Task::Grasp,
        observation: &[("joint_pos", 3), ("brick_pos", 2)],
        action: &[
            ("joint_a", 0.5, -0.5, 0.5),
            ("joint_b", 1.0, -0.8, 0.8),
            ("finger", 5.0, -5.0, 5.0),
        ],
        hidden: &[8],
        hidden_activation: Activation::Relu,
        output_activation: Activation::Tanh,
        seed: 7,
    }
}

/// The committed int8 golden file `tests/golden/small_int8.dxpl` (format version 2): the policy of
/// [`golden_small_spec`] with both layers quantised by [`crate::int8::quantise_policy`].
pub fn golden_small_int8() -> Result<Vec<u8>, FormatError> {
    let f32_file = synth_policy(&golden_small_spec())?;
    let view = crate::view::PolicyView::decode(&f32_file)?;
    crate::int8::quantise_policy(&view, |_| true, None)
}
