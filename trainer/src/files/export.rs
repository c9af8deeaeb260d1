//! Writing a trained actor as a `dex-policy` file, the format the controller runs, in f32 or, after
//! post-training quantisation, with int8 weights (format version 2).

use dex_policy::{Body, LayerSpec, Provenance, encode_to_vec};
use dex_runtime::interface::CONTROL_PERIOD_US;

use crate::env::Task;
use crate::learn::nets::{Activation, Mlp};

// Start seed of the int8 exporter's calibration episodes (`env::seeds::CALIBRATION_SEED`, apart
// from evaluation and the held-out range), under its old path.
pub use crate::env::seeds::CALIBRATION_SEED;

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
    /// Equalisation needs an f32 policy file; this layer is already int8.
    #[error("layer {layer} of the policy file is already int8; equalisation needs f32 weights")]
    NotF32 {
        /// Layer index.
        layer: usize,
    },
    /// Comparing the equalised file with the original through the runtime failed.
    #[error("evaluation: {0}")]
    Evaluation(#[from] crate::evaluate::EvalError),
    /// Equalisation needs at least one calibration observation of the policy's width.
    #[error("no calibration observations of width {0}")]
    NoCalibration(usize),
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

impl ExportInfo {
    /// The provenance of an actor of `task` from no recorded run: seed 0, no transitions, not
    /// evaluated (spikes, tests, files made from other files).
    pub fn bare(task: Task) -> Self {
        ExportInfo {
            task,
            seed: 0,
            transitions: 0,
            success_rate: None,
            eval_episodes: 0,
        }
    }
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
    let aligned = dex_runtime::aligned::aligned_copy(f32_file);
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

/// Episodes whose observations calibrate the int8 exporter.
pub const CALIBRATION_EPISODES: u32 = 20;

/// The int8 exporter's calibration set: every observation of [`CALIBRATION_EPISODES`] episodes of
/// `env` driven by the f32 policy `f32_file` from [`CALIBRATION_SEED`].
pub fn calibration_observations(
    f32_file: &[u8],
    scene: &crate::env::Scene,
    env: crate::env::EnvConfig,
) -> Result<Vec<[f32; dex_runtime::interface::OBS_DIM]>, crate::evaluate::EvalError> {
    crate::evaluate::heldout_observations(
        f32_file,
        scene,
        env,
        CALIBRATION_EPISODES,
        CALIBRATION_SEED,
    )
}

/// Smallest per-input range [`equalise_policy_file`] folds into the first layer, in normalised
/// units: inputs that barely vary in calibration are not blown up, and with the file's clip of
/// [`EXPORT_OBS_CLIP`] the folded normalisation still clips only values beyond
/// `1e4 * 1e-2 = 100` normalised units from the calibration centre (raw observations stay below 30).
pub const MIN_FOLDED_RANGE: f64 = 1.0e-2;

/// An f32 policy file rewritten for quantisation, with the same function.
#[derive(Debug, Clone, PartialEq)]
pub struct Equalised {
    /// The rewritten f32 file (same layout, format version 1).
    pub file: Vec<u8>,
    /// Largest `|a_new - a_old| / (max - min)` over the calibration observations and joints,
    /// through the runtime: the f32 function change caused by rounding the new weights to f32.
    pub max_f32_change: f64,
    /// The source was already on the int8 grid (quantisation-aware training) and is returned
    /// unchanged.
    pub on_grid: bool,
}

/// Rewrites an f32 policy so that post-training quantisation loses less, without changing its f32
/// function (up to f32 rounding, reported in [`Equalised::max_f32_change`]):
///
/// 1. Input folding: from the normalised calibration inputs `z_i` (range `[lo_i, hi_i]`), centre
///    `m_i = (lo_i + hi_i) / 2` and half-range `r_i = max((hi_i - lo_i) / 2, MIN_FOLDED_RANGE)`
///    go into the file's normalisation (`mean += scale * m_i`, `scale *= r_i`), so every input the
///    first layer sees spans about [-1, 1]; the first layer's weight row `i` is multiplied by `r_i`
///    and its biases gain `sum_i w[i][j] * m_i`. Nearly constant inputs no longer carry a large
///    constant term through quantised weights, and rows of inputs that barely move no longer set
///    the per-output weight scales.
/// 2. Cross-layer equalisation (Nagel et al. 2019, "Data-Free Quantization"): between a ReLU layer
///    and the next, output `j` (weight column and bias) is divided by `c_j` and the next layer's
///    weight row `j` multiplied by it, `c_j = sqrt(r1_j / r2_j)` with `r1_j`, `r2_j` the largest
///    weight magnitudes of that column and row (ReLU is positively homogeneous, so the function
///    is the same).
///
/// The arithmetic is done in f64 and rounded once to f32. `calibration` holds raw observations
/// (what the controller receives), e.g. `CALIBRATION_EPISODES` episodes from `CALIBRATION_SEED`.
///
/// A file whose every layer already lies on the int8 grid (`dex_policy::int8::policy_on_grid`: a
/// quantisation-aware trained actor, see `learn::quantise`) is returned unchanged, with a change of
/// 0: its quantisation loses nothing, and rescaling would move the weights off the grid.
pub fn equalise_policy_file(
    f32_file: &[u8],
    calibration: &[[f32; dex_runtime::interface::OBS_DIM]],
) -> Result<Equalised, ExportError> {
    let aligned = dex_runtime::aligned::aligned_copy(f32_file);
    let view = dex_policy::PolicyView::decode(aligned.as_bytes())?;
    let values = view.values().as_slice()?;
    let n = view.body().obs_dim();
    let featured = dex_runtime::features::takes_features(n);
    if calibration.is_empty() || (n != dex_runtime::interface::OBS_DIM && !featured) {
        return Err(ExportError::NoCalibration(n));
    }
    let get = |start: usize, len: usize| -> Result<Vec<f64>, ExportError> {
        values
            .get(start..start + len)
            .map(|v| v.iter().map(|&x| f64::from(x)).collect())
            .ok_or(ExportError::Format(dex_policy::FormatError::MalformedBody))
    };
    if dex_policy::int8::policy_on_grid(&view)? {
        return Ok(Equalised {
            file: f32_file.to_vec(),
            max_f32_change: 0.0,
            on_grid: true,
        });
    }
    let mut mean = get(0, n)?;
    let mut scale = get(n, n)?;
    struct Dense {
        inputs: usize,
        outputs: usize,
        w: Vec<f64>,
        b: Vec<f64>,
        relu: bool,
    }
    let mut layers = Vec::new();
    for (index, (l, spec)) in view.layers().zip(view.body().layers.iter()).enumerate() {
        if l.dtype != dex_policy::LayerDtype::F32 {
            return Err(ExportError::NotF32 { layer: index });
        }
        layers.push(Dense {
            inputs: l.inputs,
            outputs: l.outputs,
            w: get(l.weights, l.inputs * l.outputs)?,
            b: get(l.biases, l.outputs)?,
            relu: spec.activation == dex_policy::Activation::Relu,
        });
    }
    // 1. Input folding, only where the file's clip never binds: folding moves each input's clip
    // to `m_i +- clip * r_i` in the old units, which changes the function of a file whose clip is
    // part of it (the imitation learner's `ObsScaling` clips at +-5; the RL exporter's
    // EXPORT_OBS_CLIP clips nothing the learner saw).
    let fold = view.body().obs_clip >= EXPORT_OBS_CLIP;
    if let Some(first) = layers.first_mut().filter(|_| fold) {
        // What the first layer's inputs are: the observation, or the observation followed by the
        // task features the controller computes from it (`dex_runtime::features`).
        let mut buf = [0.0f32; dex_runtime::features::INPUT_MAX];
        let inputs: Vec<Vec<f32>> = calibration
            .iter()
            .map(|o| dex_runtime::features::policy_input(o, n, &mut buf).to_vec())
            .collect();
        for i in 0..n.min(first.inputs) {
            let (lo, hi) = inputs.iter().fold((f64::MAX, f64::MIN), |(lo, hi), o| {
                let z = (f64::from(o[i]) - mean[i]) / scale[i];
                (lo.min(z), hi.max(z))
            });
            let m = 0.5 * (lo + hi);
            let r = (0.5 * (hi - lo)).max(MIN_FOLDED_RANGE);
            mean[i] += scale[i] * m;
            scale[i] *= r;
            for j in 0..first.outputs {
                let w = &mut first.w[i * first.outputs + j];
                first.b[j] += *w * m;
                *w *= r;
            }
        }
    }
    // 2. Cross-layer equalisation across ReLUs.
    for k in 1..layers.len() {
        let (head, tail) = layers.split_at_mut(k);
        let (Some(a), Some(b)) = (head.last_mut(), tail.first_mut()) else {
            continue;
        };
        if !a.relu || a.outputs != b.inputs {
            continue;
        }
        for j in 0..a.outputs {
            let r1 = (0..a.inputs).fold(0.0f64, |m, i| m.max(a.w[i * a.outputs + j].abs()));
            let r2 = (0..b.outputs).fold(0.0f64, |m, t| m.max(b.w[j * b.outputs + t].abs()));
            if r1 > 0.0 && r2 > 0.0 {
                let c = (r1 / r2).sqrt();
                for i in 0..a.inputs {
                    a.w[i * a.outputs + j] /= c;
                }
                a.b[j] /= c;
                for t in 0..b.outputs {
                    b.w[j * b.outputs + t] *= c;
                }
            }
        }
    }
    let mut out: Vec<f32> = Vec::with_capacity(values.len());
    out.extend(mean.iter().map(|&x| x as f32));
    out.extend(scale.iter().map(|&x| x as f32));
    for l in &layers {
        out.extend(l.w.iter().map(|&x| x as f32));
        out.extend(l.b.iter().map(|&x| x as f32));
    }
    let file = encode_to_vec(view.body(), &out)?;
    let max_f32_change = evaluate_change(f32_file, &file, calibration)?;
    Ok(Equalised {
        file,
        max_f32_change,
        on_grid: false,
    })
}

/// Largest action difference of two f32-or-int8 policy files over `observations`, as a fraction
/// of each joint's range (through the runtime evaluator).
fn evaluate_change(
    a: &[u8],
    b: &[u8],
    observations: &[[f32; dex_runtime::interface::OBS_DIM]],
) -> Result<f64, ExportError> {
    let err = crate::evaluate::action_error(a, b, observations)?;
    Ok(err.iter().copied().fold(0.0, f64::max))
}

/// Post-training quantisation with calibration: [`equalise_policy_file`] on `calibration`, then
/// [`quantise_policy_file`] of the result (every layer int8). Returns the int8 file and the f32
/// function change of the equalisation (see [`Equalised::max_f32_change`]).
pub fn quantise_policy_file_calibrated(
    f32_file: &[u8],
    evaluation: Option<(f32, u32)>,
    calibration: &[[f32; dex_runtime::interface::OBS_DIM]],
) -> Result<(Vec<u8>, f64), ExportError> {
    let eq = equalise_policy_file(f32_file, calibration)?;
    Ok((
        quantise_policy_file(&eq.file, evaluation)?,
        eq.max_f32_change,
    ))
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
            let aligned = dex_runtime::aligned::aligned_copy(&file);
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

pub(crate) fn task_code(task: Task) -> dex_policy::Task {
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
    export_actor_clipped(net, params, normalisation, info, EXPORT_OBS_CLIP)
}

/// Encodes an actor trained on inputs scaled by the fixed `scaling` (mean, inverse standard
/// deviation, clip): the file applies the same scaling and clip in front of the network.
pub fn export_scaled_actor(
    net: &Mlp,
    params: &[f32],
    scaling: &crate::learn::bc::ObsScaling,
    info: &ExportInfo,
) -> Result<Vec<u8>, ExportError> {
    export_actor_clipped(
        net,
        params,
        Some(ObsNormalisation {
            mean: &scaling.norm.mean,
            inv_std: &scaling.norm.inv_std,
        }),
        info,
        scaling.clip,
    )
}

fn export_actor_clipped(
    net: &Mlp,
    params: &[f32],
    normalisation: Option<ObsNormalisation<'_>>,
    info: &ExportInfo,
    obs_clip: f32,
) -> Result<Vec<u8>, ExportError> {
    // An actor as wide as the observation and the task features takes both
    // (dex_runtime::features); any other width must be the observation's.
    let features = dex_runtime::features::takes_features(net.input_dim());
    let obs_dim = if features {
        dex_runtime::features::INPUT_MAX
    } else {
        dex_runtime::interface::OBS_DIM
    };
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
    let observation = if features {
        dex_runtime::features::policy_observation_with_features()
    } else {
        dex_runtime::interface::policy_observation()
    };
    let action = dex_runtime::interface::policy_action();
    let body = Body {
        task: task_code(info.task),
        observation,
        obs_clip,
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
