//! An exported policy file read back into the learner's actor: the starting point of a
//! reinforcement-learning stage that fine-tunes a clone (`trainer train --init-policy FILE`,
//! `TrainSettings::init_policy`).
//!
//! Two ways in. [`actor_params_from_policy`] folds the file's observation normalisation
//! `(x - mean) / scale` into the first layer (`w'[i][j] = w[i][j] / scale[i]`,
//! `b'[j] = b[j] - sum_i w[i][j] mean[i] / scale[i]`, in f64, rounded once), so the actor takes raw
//! observations as the learner's do by default. [`normalised_actor_from_policy`] keeps them apart:
//! the run's frozen normaliser becomes the file's (`obs_norm.frozen_from_init`), so the actor is
//! fine-tuned in the input coordinates it was trained in, and the critic sees the same. Either way
//! the file's clip of the normalised observations (5 for `trainer imitate`'s clones) is dropped: the
//! learner's normaliser does not clip, so the imported actor equals the file wherever no
//! normalised observation exceeds the clip (`trainer/tests/init_policy.rs` checks both ways on
//! observations inside it).

use dex_policy::{LayerDtype, PolicyView};
use dex_runtime::interface::ACTION_JOINTS;

use crate::env::Task;
use crate::learn::nets::{Activation, Mlp};

/// Why a policy file cannot start the run's actor.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImportError {
    /// The file does not decode, or its layout is not this build's interface.
    #[error("policy file: {0}")]
    Format(#[from] dex_policy::FormatError),
    /// The file is for another task.
    #[error("the policy file solves {file:?}; this run learns {run:?}")]
    Task {
        /// The file's task.
        file: dex_policy::Task,
        /// The run's task.
        run: dex_policy::Task,
    },
    /// The file's action map differs from the environment's (scale or limits of a joint).
    #[error(
        "the policy file's action map of joint {joint} differs from the environment's; it was \
         made for another version of the cell"
    )]
    ActionMap {
        /// Joint index.
        joint: usize,
    },
    /// A layer is int8: fine-tuning starts from f32 weights.
    #[error(
        "layer {layer} of the policy file is int8; start from the f32 file (the int8 twin is \
         made from it after training)"
    )]
    NotF32 {
        /// Layer index.
        layer: usize,
    },
    /// The file's network is not the run's actor.
    #[error(
        "the policy file's network is {file}, the run's actor is {actor}: set \
         run.ddpg.actor_hidden to the file's hidden sizes"
    )]
    Shape {
        /// The file's layer widths and activations.
        file: String,
        /// The actor's.
        actor: String,
    },
    /// The file takes the task features and the run does not, or the other way round.
    #[error(
        "the policy file {} the task features and the run {}: set `features = {file}` \
         (`trainer train --features`) to match the file",
        if *file { "takes" } else { "does not take" },
        if *file { "does not" } else { "does" }
    )]
    Features {
        /// Whether the file takes them.
        file: bool,
    },
    /// The actor has layer normalisation, which a policy file has no parameters for.
    #[error("the run's actor has layer normalisation; a policy file has no parameters for it")]
    LayerNorm,
    /// The actor's parameter layout refused the imported values.
    #[error("actor parameters: {0}")]
    Actor(#[from] crate::learn::LearnError),
    /// A folded weight or bias is not finite (a scale of zero or an overflow).
    #[error(
        "folding the file's normalisation into layer 0 gives a non-finite value at input {input}"
    )]
    NotFinite {
        /// Observation component.
        input: usize,
    },
}

fn describe(input: usize, layers: impl Iterator<Item = (usize, &'static str)>) -> String {
    let mut s = input.to_string();
    for (size, act) in layers {
        s.push_str(&format!("-{size} {act}"));
    }
    s
}

fn act_name(a: Activation) -> &'static str {
    match a {
        Activation::Relu => "relu",
        Activation::Tanh => "tanh",
        Activation::Linear => "linear",
    }
}

pub(crate) fn file_act(a: dex_policy::Activation) -> Activation {
    match a {
        dex_policy::Activation::Relu => Activation::Relu,
        dex_policy::Activation::Tanh => Activation::Tanh,
        dex_policy::Activation::Linear => Activation::Linear,
    }
}

/// The parameters of `actor` that compute what the f32 policy file `file` computes (see the
/// module docs for the clip), after checking that the file is for `task`, has this build's
/// observation and action layout and action map, and has the actor's shape.
pub fn actor_params_from_policy(
    file: &[u8],
    task: Task,
    actor: &Mlp,
) -> Result<Vec<f32>, ImportError> {
    Ok(read(file, task, actor, true)?.params)
}

/// A policy file's network as the learner's actor, with the file's normalisation kept apart.
#[derive(Debug, Clone, PartialEq)]
pub struct NormalisedActor {
    /// The actor's parameters: the file's layers as they are (they take normalised inputs).
    pub params: Vec<f32>,
    /// The file's normalisation: subtracted per component.
    pub mean: Vec<f32>,
    /// Multiplied per component after the subtraction (`1 / scale` of the file).
    pub inv_std: Vec<f32>,
}

/// The actor of `file` without folding: its layers and its normalisation apart, for a run whose
/// frozen normaliser is the file's (`obs_norm.frozen_from_init`), so the actor is fine-tuned in
/// the input coordinates it was trained in. The same checks as [`actor_params_from_policy`].
pub fn normalised_actor_from_policy(
    file: &[u8],
    task: Task,
    actor: &Mlp,
) -> Result<NormalisedActor, ImportError> {
    read(file, task, actor, false)
}

/// A first layer (`w` input-major, `outputs` wide, biases `b`) with the input normalisation
/// `(x - mean) / scale` folded in, in f64: `w'[i][j] = w[i][j] / scale[i]`, `b'[j] = b[j] - sum_i
/// w[i][j] mean[i] / scale[i]`, so that it takes raw inputs. The callers round (and check) once.
pub(crate) fn fold_normalisation(
    w: &[f32],
    b: &[f32],
    mean: &[f32],
    scale: &[f32],
    outputs: usize,
) -> (Vec<f64>, Vec<f64>) {
    let mut weights = Vec::with_capacity(w.len());
    let mut bias: Vec<f64> = b.iter().map(|&x| f64::from(x)).collect();
    for (i, (&m, &sc)) in mean.iter().zip(scale).enumerate() {
        let inv = 1.0 / f64::from(sc);
        let shift = f64::from(m) * inv;
        for (j, bj) in bias.iter_mut().enumerate() {
            let wij = f64::from(w[i * outputs + j]);
            weights.push(wij * inv);
            *bj -= wij * shift;
        }
    }
    (weights, bias)
}

fn read(file: &[u8], task: Task, actor: &Mlp, fold: bool) -> Result<NormalisedActor, ImportError> {
    let aligned = dex_runtime::aligned::aligned_copy(file);
    let view = PolicyView::decode(aligned.as_bytes())?;
    dex_runtime::features::check_layout(&view)?;
    let body = view.body();
    let (file_features, run_features) = (
        dex_runtime::features::takes_features(body.obs_dim()),
        dex_runtime::features::takes_features(actor.input_dim()),
    );
    if file_features != run_features {
        return Err(ImportError::Features {
            file: file_features,
        });
    }
    let run = crate::files::export::task_code(task);
    if body.task != run {
        return Err(ImportError::Task {
            file: body.task,
            run,
        });
    }
    for (joint, (ours, theirs)) in ACTION_JOINTS.iter().zip(body.action.iter()).enumerate() {
        if (ours.scale, ours.min, ours.max) != (theirs.scale, theirs.min, theirs.max) {
            return Err(ImportError::ActionMap { joint });
        }
    }
    let file_layers: Vec<_> = view.layers().collect();
    for (layer, l) in file_layers.iter().enumerate() {
        if l.dtype != LayerDtype::F32 {
            return Err(ImportError::NotF32 { layer });
        }
    }
    let zeros = vec![0.0; actor.num_params()];
    let shapes = actor.layers(&zeros)?;
    let same = shapes.len() == file_layers.len()
        && actor.input_dim() == body.obs_dim()
        && shapes
            .iter()
            .zip(&file_layers)
            .zip(body.layers.iter())
            .all(|((a, f), spec)| {
                a.fan_in == f.inputs
                    && a.fan_out == f.outputs
                    && a.activation == file_act(spec.activation)
            });
    if !same {
        return Err(ImportError::Shape {
            file: describe(
                body.obs_dim(),
                body.layers
                    .iter()
                    .map(|l| (usize::from(l.outputs), act_name(file_act(l.activation)))),
            ),
            actor: describe(
                actor.input_dim(),
                shapes.iter().map(|l| (l.fan_out, act_name(l.activation))),
            ),
        });
    }
    if shapes.iter().any(|l| l.layer_norm.is_some()) {
        return Err(ImportError::LayerNorm);
    }
    let values = view.values().as_slice()?;
    let get = |start: usize, len: usize| {
        values
            .get(start..start + len)
            .ok_or(ImportError::Format(dex_policy::FormatError::MalformedBody))
    };
    let n = body.obs_dim();
    let norm = view.normalisation_offset();
    let (mean, scale) = (get(norm, n)?, get(norm + n, n)?);
    let mut params = Vec::with_capacity(actor.num_params());
    for (index, l) in file_layers.iter().enumerate() {
        let w = get(l.weights, l.inputs * l.outputs)?;
        let b = get(l.biases, l.outputs)?;
        if index > 0 || !fold {
            params.extend_from_slice(w);
            params.extend_from_slice(b);
            continue;
        }
        let (weights, bias) = fold_normalisation(w, b, mean, scale, l.outputs);
        for (k, &wk) in weights.iter().enumerate() {
            let folded = wk as f32;
            if !folded.is_finite() {
                return Err(ImportError::NotFinite {
                    input: k / l.outputs,
                });
            }
            params.push(folded);
        }
        for (j, &bj) in bias.iter().enumerate() {
            let v = bj as f32;
            if !v.is_finite() {
                return Err(ImportError::NotFinite { input: j });
            }
            params.push(v);
        }
    }
    // The flat layout is the exporter's: per layer, input-major weights then biases (no layer
    // norm, checked above); `Mlp::layers` confirms the length.
    actor.layers(&params)?;
    let mut inv_std = Vec::with_capacity(n);
    for (input, &sc) in scale.iter().enumerate() {
        let k = 1.0 / sc;
        if !(k.is_finite() && k > 0.0) {
            return Err(ImportError::NotFinite { input });
        }
        inv_std.push(k);
    }
    Ok(NormalisedActor {
        params,
        mean: mean.to_vec(),
        inv_std,
    })
}
