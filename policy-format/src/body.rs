//! The postcard body: everything about a policy except its numbers.

use serde::{Deserialize, Serialize};

/// Most observation fields a file may list.
pub const MAX_OBS_FIELDS: usize = 32;
/// Most action joints a file may list.
pub const MAX_ACTIONS: usize = 16;
/// Most layers (hidden and output) a network may have.
pub const MAX_LAYERS: usize = 8;
/// Longest name, in bytes, of an observation field or action joint.
pub const MAX_NAME_LEN: usize = 32;

/// The task a policy was trained for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Task {
    /// Bring the pinch site into the reach box of brick 1.
    Reach,
    /// Lift brick 1 off the table.
    Grasp,
    /// Stack brick 1, which starts in the hand, on brick 2.
    StackInHand,
    /// Pick up brick 1 from the table and stack it on brick 2.
    Stack,
}

/// Activation applied to a layer's outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Activation {
    /// `max(0, x)`.
    Relu,
    /// Hyperbolic tangent.
    Tanh,
    /// Identity.
    Linear,
}

/// One named block of the observation vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ObsField<'a> {
    /// Field name (1 to [`MAX_NAME_LEN`] bytes of UTF-8).
    pub name: &'a str,
    /// Number of consecutive values.
    pub size: u16,
}

/// One commanded joint: network output `y` in [-1, 1] becomes `clamp(y * scale, min, max)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ActionJoint<'a> {
    /// Joint name (1 to [`MAX_NAME_LEN`] bytes of UTF-8).
    pub name: &'a str,
    /// Physical command per unit of network output.
    pub scale: f32,
    /// Lowest command.
    pub min: f32,
    /// Highest command.
    pub max: f32,
}

/// One dense layer: `outputs` neurons followed by `activation`. Its input width is the previous
/// layer's output width (the observation dimension for the first layer).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LayerSpec {
    /// Number of outputs.
    pub outputs: u16,
    /// Activation applied to the outputs.
    pub activation: Activation,
}

/// Where a policy came from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Provenance<'a> {
    /// Version string of the trainer that exported it.
    pub trainer_version: &'a str,
    /// Seed of the training run.
    pub seed: u64,
    /// Environment transitions used for training.
    pub transitions: u64,
    /// Success rate measured by the exporter's evaluation, if one ran.
    pub success_rate: Option<f32>,
    /// Episodes behind `success_rate`.
    pub eval_episodes: u32,
}

/// The decoded body of a policy file (borrows its strings from the file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Body<'a> {
    /// Task the policy solves.
    pub task: Task,
    /// Observation layout, in order.
    #[serde(borrow)]
    pub observation: heapless::Vec<ObsField<'a>, MAX_OBS_FIELDS>,
    /// Normalised observations are clipped to `[-obs_clip, obs_clip]`.
    pub obs_clip: f32,
    /// Action layout, in order.
    #[serde(borrow)]
    pub action: heapless::Vec<ActionJoint<'a>, MAX_ACTIONS>,
    /// Control period in microseconds (50 000 for 20 Hz).
    pub control_period_us: u32,
    /// Network layers, input to output.
    pub layers: heapless::Vec<LayerSpec, MAX_LAYERS>,
    /// Where the policy came from.
    #[serde(borrow)]
    pub provenance: Provenance<'a>,
}

impl Body<'_> {
    /// Observation dimension: the sum of the field sizes.
    pub fn obs_dim(&self) -> usize {
        self.observation.iter().map(|f| usize::from(f.size)).sum()
    }

    /// Action dimension: the number of joints.
    pub fn act_dim(&self) -> usize {
        self.action.len()
    }

    /// Number of f32 values the file must store: normalisation (mean and scale per observation
    /// value) then, per layer, the weights (`inputs x outputs`) and biases (`outputs`).
    /// `None` on arithmetic overflow.
    pub fn stored_values(&self) -> Option<usize> {
        let mut inputs = self.obs_dim();
        let mut total = inputs.checked_mul(2)?;
        for layer in &self.layers {
            let outputs = usize::from(layer.outputs);
            total = total.checked_add(inputs.checked_mul(outputs)?.checked_add(outputs)?)?;
            inputs = outputs;
        }
        Some(total)
    }

    /// Widest layer (or input).
    pub fn max_width(&self) -> usize {
        self.layers
            .iter()
            .map(|l| usize::from(l.outputs))
            .fold(self.obs_dim(), usize::max)
    }
}
