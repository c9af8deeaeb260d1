//! Writing a trained actor as a `dex-policy` file, the format the controller runs, in f32 or, after
//! post-training quantisation, with int8 weights (format version 2).

use dex_policy::{ActionJoint, Body, LayerSpec, ObsField, Provenance, encode_to_vec};
use dex_runtime::interface::{ACTION_JOINTS, CONTROL_PERIOD_US, OBSERVATION_FIELDS};

use crate::env::Task;
use crate::learn::nets::{Activation, Mlp};

/// Why an actor could not be exported.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExportError {
    /// The actor uses layer normalisation, which the runtime does not evaluate.
    #[error(
        "the actor has layer normalisation in layer {layer}; the runtime evaluates plain dense layers"
    )]
    LayerNorm {
        /// Layer index.
        layer: usize,
    },
    /// The actor's input or output width is not the cell's observation or action dimension.
    #[error("actor is {inputs} -> {outputs}, the cell needs {obs} -> {act}")]
    Shape {
        /// Actor inputs.
        inputs: usize,
        /// Actor outputs.
        outputs: usize,
        /// Cell observation dimension.
        obs: usize,
        /// Cell action dimension.
        act: usize,
    },
    /// The parameter vector does not fit the network.
    #[error("actor parameters: {0}")]
    Params(#[from] crate::learn::LearnError),
    /// The policy-format encoder refused the policy.
    #[error("policy file: {0}")]
    Format(#[from] dex_policy::FormatError),
    /// More layers or wider layers than the format can describe.
    #[error("the actor has {0} layers or a layer wider than 65535; the format allows 8")]
    TooLarge(usize),
}

/// What the exporter writes into the file's provenance.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportInfo {
    /// Task the actor was trained for.
    pub task: Task,
    /// Seed of the training run.
    pub seed: u64,
    /// Transitions used.
    pub transitions: u64,
    /// Success rate of an evaluation, if one ran before export.
    pub success_rate: Option<f32>,
    /// Episodes behind `success_rate`.
    pub eval_episodes: u32,
}

/// Precision of an exported policy's weights.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Precision {
    /// f32 weights (a format version 1 file).
    #[default]
    F32,
    /// Post-training quantisation of every layer: int8 weights with symmetric per-output-channel
    /// scales (`scale[j] = max_i |w[i][j]| / 127`), f32 biases; evaluated by the runtime with int16
    /// activations and exact int32 accumulation (a format version 2 file).
    Int8,
}

/// Post-training quantisation of an exported f32 policy file: every layer becomes int8 (see
/// [`Precision::Int8`]); layouts, normalisation and the action map are kept. The provenance is kept
/// except the success rate, which belonged to the f32 weights: it is replaced by `evaluation`
/// (success rate, episodes) of the int8 file itself, or cleared (`None`, 0 episodes).
pub fn quantise_policy_file(
    f32_file: &[u8],
    evaluation: Option<(f32, u32)>,
) -> Result<Vec<u8>, ExportError> {
    let aligned = dex_runtime::testkit::aligned_copy(f32_file);
    let view = dex_policy::PolicyView::decode(aligned.as_bytes())?;
    let provenance = Provenance {
        success_rate: evaluation.map(|e| e.0),
        eval_episodes: evaluation.map_or(0, |e| e.1),
        ..view.body().provenance
    };
    Ok(dex_policy::int8::quantise_policy(
        &view,
        |_| true,
        Some(provenance),
    )?)
}

/// [`export_actor`] at the given precision.
pub fn export_actor_with(
    net: &Mlp,
    params: &[f32],
    normalisation: Option<ObsNormalisation<'_>>,
    info: &ExportInfo,
    precision: Precision,
) -> Result<Vec<u8>, ExportError> {
    let file = export_actor(net, params, normalisation, info)?;
    match precision {
        Precision::F32 => Ok(file),
        Precision::Int8 => {
            let aligned = dex_runtime::testkit::aligned_copy(&file);
            let view = dex_policy::PolicyView::decode(aligned.as_bytes())?;
            Ok(dex_policy::int8::quantise_policy(&view, |_| true, None)?)
        }
    }
}

/// Observation clip of exported policies. The learner does not clip normalised observations, so the
/// clip only has to stay clear of every value the learner saw: raw observations (mean 0, scale 1)
/// are below 30 in magnitude, and normalised ones are bounded by the normaliser's standard-deviation
/// floor.
pub const EXPORT_OBS_CLIP: f32 = 1.0e4;

/// The learner's observation normalisation, `(x - mean) * inv_std`, written into the file as
/// mean and scale = 1 / inv_std.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObsNormalisation<'a> {
    /// Subtracted per component.
    pub mean: &'a [f32],
    /// Multiplied per component after the subtraction.
    pub inv_std: &'a [f32],
}

fn task_code(task: Task) -> dex_policy::Task {
    match task {
        Task::Reach => dex_policy::Task::Reach,
        Task::Grasp => dex_policy::Task::Grasp,
        Task::StackInHand => dex_policy::Task::StackInHand,
        Task::Stack => dex_policy::Task::Stack,
    }
}

/// Encodes the actor `net` with parameters `params` (and the observation normalisation it was trained
/// with, if any) as a policy file for the Jaco cell. The file's action layer maps the actor's tanh
/// output in [-1, 1] to joint velocity commands exactly as the environment does (`scale` = the
/// actuator's range).
pub fn export_actor(
    net: &Mlp,
    params: &[f32],
    normalisation: Option<ObsNormalisation<'_>>,
    info: &ExportInfo,
) -> Result<Vec<u8>, ExportError> {
    let obs_dim = dex_runtime::interface::OBS_DIM;
    let act_dim = dex_runtime::interface::ACT_DIM;
    if net.input_dim() != obs_dim || net.output_dim() != act_dim {
        return Err(ExportError::Shape {
            inputs: net.input_dim(),
            outputs: net.output_dim(),
            obs: obs_dim,
            act: act_dim,
        });
    }
    let layers = net.layers(params)?;
    let mut body_layers = heapless::Vec::<LayerSpec, { dex_policy::MAX_LAYERS }>::new();
    let mut values: Vec<f32> = Vec::with_capacity(params.len() + 2 * obs_dim);
    match normalisation {
        Some(n) if n.mean.len() == obs_dim && n.inv_std.len() == obs_dim => {
            values.extend_from_slice(n.mean);
            values.extend(n.inv_std.iter().map(|s| 1.0 / s));
        }
        Some(n) => {
            return Err(ExportError::Shape {
                inputs: n.mean.len(),
                outputs: net.output_dim(),
                obs: obs_dim,
                act: act_dim,
            });
        }
        None => {
            values.extend(std::iter::repeat_n(0.0, obs_dim));
            values.extend(std::iter::repeat_n(1.0, obs_dim));
        }
    }
    for (i, l) in layers.iter().enumerate() {
        if l.layer_norm.is_some() {
            return Err(ExportError::LayerNorm { layer: i });
        }
        let outputs = u16::try_from(l.fan_out).map_err(|_| ExportError::TooLarge(layers.len()))?;
        body_layers
            .push(LayerSpec::f32(
                outputs,
                match l.activation {
                    Activation::Relu => dex_policy::Activation::Relu,
                    Activation::Tanh => dex_policy::Activation::Tanh,
                    Activation::Linear => dex_policy::Activation::Linear,
                },
            ))
            .map_err(|_| ExportError::TooLarge(layers.len()))?;
        // Both store weights input-major (row i: the weights leaving input i), then the biases.
        values.extend_from_slice(l.weights);
        values.extend_from_slice(l.bias);
    }
    let mut observation = heapless::Vec::new();
    for f in OBSERVATION_FIELDS {
        let _ = observation.push(ObsField {
            name: f.name,
            size: f.size as u16,
        });
    }
    let mut action = heapless::Vec::new();
    for j in ACTION_JOINTS {
        let _ = action.push(ActionJoint {
            name: j.name,
            scale: j.scale,
            min: j.min,
            max: j.max,
        });
    }
    let body = Body {
        task: task_code(info.task),
        observation,
        obs_clip: EXPORT_OBS_CLIP,
        action,
        control_period_us: CONTROL_PERIOD_US,
        layers: body_layers,
        provenance: Provenance {
            trainer_version: concat!("dex-trainer ", env!("CARGO_PKG_VERSION")),
            seed: info.seed,
            transitions: info.transitions,
            success_rate: info.success_rate,
            eval_episodes: info.eval_episodes,
        },
    };
    Ok(encode_to_vec(&body, &values)?)
}
