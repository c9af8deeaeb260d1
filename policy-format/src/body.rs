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

impl Task {
    /// Every task, in the order of the paper's curriculum.
    pub const ALL: [Task; 4] = [Task::Reach, Task::Grasp, Task::StackInHand, Task::Stack];

    /// The task's name on command lines, in file metadata and in Python (`"stack-in-hand"`).
    pub const fn name(self) -> &'static str {
        match self {
            Task::Reach => "reach",
            Task::Grasp => "grasp",
            Task::StackInHand => "stack-in-hand",
            Task::Stack => "stack",
        }
    }

    /// The task called `name` ([`Task::name`]); `None` for any other string.
    pub fn from_name(name: &str) -> Option<Task> {
        Task::ALL.into_iter().find(|t| t.name() == name)
    }
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

/// How a layer stores its weights (format version 2; every layer of a version 1 file is `F32`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum LayerDtype {
    /// f32 weights, input-major, then f32 biases.
    #[default]
    F32,
    /// int8 weights with one f32 scale per output channel (`w = q * scale[j]`), packed for
    /// 4-output x 4-input blocks (see [`crate::int8`]), then the f32 scales, then f32 biases.
    Int8,
}

/// One dense layer: `outputs` neurons followed by `activation`. Its input width is the previous
/// layer's output width (the observation dimension for the first layer).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LayerSpec {
    /// Number of outputs.
    pub outputs: u16,
    /// Activation applied to the outputs.
    pub activation: Activation,
    /// How the weights are stored (version 2 field; version 1 files decode as `F32`).
    pub dtype: LayerDtype,
}

impl LayerSpec {
    /// An f32 layer.
    pub const fn f32(outputs: u16, activation: Activation) -> Self {
        LayerSpec {
            outputs,
            activation,
            dtype: LayerDtype::F32,
        }
    }
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

    /// Number of 4-byte words the file must store: normalisation (mean and scale per observation
    /// value) then, per f32 layer, the weights (`inputs x outputs`) and biases (`outputs`); per
    /// int8 layer the packed weights ([`crate::int8::packed_words`]), scales and biases
    /// (`outputs` each). For an all-f32 network this is the number of f32 values.
    /// `None` on arithmetic overflow.
    pub fn stored_values(&self) -> Option<usize> {
        let mut inputs = self.obs_dim();
        let mut total = inputs.checked_mul(2)?;
        for layer in &self.layers {
            let outputs = usize::from(layer.outputs);
            let words = match layer.dtype {
                LayerDtype::F32 => inputs.checked_mul(outputs)?.checked_add(outputs)?,
                LayerDtype::Int8 => crate::int8::packed_words(inputs, outputs)?
                    .checked_add(outputs.checked_mul(2)?)?,
            };
            total = total.checked_add(words)?;
            inputs = outputs;
        }
        Some(total)
    }

    /// Whether any layer stores int8 weights (such a file needs format version 2).
    pub fn has_int8(&self) -> bool {
        self.layers.iter().any(|l| l.dtype == LayerDtype::Int8)
    }

    /// Widest layer (or input).
    pub fn max_width(&self) -> usize {
        self.layers
            .iter()
            .map(|l| usize::from(l.outputs))
            .fold(self.obs_dim(), usize::max)
    }
}

/// A layer as format version 1 writes it (no dtype field).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct LayerSpecV1 {
    outputs: u16,
    activation: Activation,
}

/// The body as format version 1 writes it: [`Body`] with [`LayerSpecV1`] layers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct BodyV1<'a> {
    task: Task,
    #[serde(borrow)]
    observation: heapless::Vec<ObsField<'a>, MAX_OBS_FIELDS>,
    obs_clip: f32,
    #[serde(borrow)]
    action: heapless::Vec<ActionJoint<'a>, MAX_ACTIONS>,
    control_period_us: u32,
    layers: heapless::Vec<LayerSpecV1, MAX_LAYERS>,
    #[serde(borrow)]
    provenance: Provenance<'a>,
}

impl<'a> From<BodyV1<'a>> for Body<'a> {
    fn from(b: BodyV1<'a>) -> Self {
        Body {
            task: b.task,
            observation: b.observation,
            obs_clip: b.obs_clip,
            action: b.action,
            control_period_us: b.control_period_us,
            layers: b
                .layers
                .iter()
                .map(|l| LayerSpec::f32(l.outputs, l.activation))
                .collect(),
            provenance: b.provenance,
        }
    }
}

impl<'a> BodyV1<'a> {
    /// The version 1 form of `body`; `None` when a layer is not f32 (version 1 cannot carry it).
    pub(crate) fn from_body(body: &Body<'a>) -> Option<Self> {
        let mut layers = heapless::Vec::new();
        for l in &body.layers {
            if l.dtype != LayerDtype::F32 {
                return None;
            }
            layers
                .push(LayerSpecV1 {
                    outputs: l.outputs,
                    activation: l.activation,
                })
                .ok()?;
        }
        Some(BodyV1 {
            task: body.task,
            observation: body.observation.clone(),
            obs_clip: body.obs_clip,
            action: body.action.clone(),
            control_period_us: body.control_period_us,
            layers,
            provenance: body.provenance,
        })
    }
}
