//! A policy file's network as a trainable actor: its parameters in the coordinates it was trained
//! in (normalised, clipped inputs), the starting parameters kept beside them, and the way back to
//! a policy file. Fine-tunes that start from a file (`group_pg`, the session-32 spikes) share it.

use dex_runtime::features::{INPUT_MAX, policy_input};
use dex_runtime::interface::{ACT_DIM, OBS_DIM};

use crate::env::Task;
use crate::evaluate::EvalError;
use crate::files::export::{ExportError, ExportInfo, export_scaled_actor};
use crate::files::policy_import::{ImportError, file_act, normalised_actor_from_policy};
use crate::learn::LearnError;
use crate::learn::bc::ObsScaling;
use crate::learn::nets::{LayerSpec, Mlp, MlpScratch, MlpSpec};
use crate::learn::norm::Normalizer;

/// Why a policy file cannot become an actor, or an actor a file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FileActorError {
    /// The file does not decode as a Jaco policy.
    #[error(transparent)]
    Eval(#[from] EvalError),
    /// The file's network is not one the trainer can hold.
    #[error(transparent)]
    Import(#[from] ImportError),
    /// The learner refused a shape.
    #[error(transparent)]
    Learn(#[from] LearnError),
    /// The actor could not be written as a policy file.
    #[error(transparent)]
    Export(#[from] ExportError),
}

/// A policy file's network, being fine-tuned.
#[derive(Debug, Clone)]
pub struct FileActor {
    /// The network's shape (the file's layers).
    pub net: Mlp,
    /// The parameters being tuned.
    pub params: Vec<f32>,
    /// The file's own parameters.
    pub clone: Vec<f32>,
    /// The file's input normalisation and clip.
    pub scaling: ObsScaling,
}

impl FileActor {
    /// The actor of the f32 policy file `file` of `task`.
    pub fn from_file(file: &[u8], task: Task) -> Result<Self, FileActorError> {
        let aligned = dex_runtime::aligned::aligned_copy(file);
        let view = crate::evaluate::decode_jaco_policy(aligned.as_bytes())?;
        let body = view.body();
        let spec = MlpSpec {
            input: body.obs_dim(),
            layers: body
                .layers
                .iter()
                .map(|l| LayerSpec {
                    size: usize::from(l.outputs),
                    activation: file_act(l.activation),
                    layer_norm: false,
                })
                .collect(),
        };
        let clip = body.obs_clip;
        let net = Mlp::new(spec, crate::learn::kernel::Engine::default())?;
        let imported = normalised_actor_from_policy(file, task, &net)?;
        Ok(FileActor {
            net,
            clone: imported.params.clone(),
            params: imported.params,
            scaling: ObsScaling {
                norm: Normalizer {
                    mean: imported.mean,
                    inv_std: imported.inv_std,
                },
                clip,
            },
        })
    }

    /// The network's input for a (quantised) observation: the task features when it takes them,
    /// normalised and clipped as the file does.
    pub fn input(&self, obs: &[f32; OBS_DIM], out: &mut [f32]) {
        let mut buf = [0.0f32; INPUT_MAX];
        out.copy_from_slice(policy_input(obs, self.net.input_dim(), &mut buf));
        self.scaling.apply_rows(out);
    }

    /// `params` (of this actor's shape) as a policy file.
    pub fn export_params(
        &self,
        params: &[f32],
        info: &ExportInfo,
    ) -> Result<Vec<u8>, FileActorError> {
        Ok(export_scaled_actor(&self.net, params, &self.scaling, info)?)
    }

    /// The tuned parameters as a policy file.
    pub fn export(&self, info: &ExportInfo) -> Result<Vec<u8>, FileActorError> {
        self.export_params(&self.params, info)
    }

    /// `params`' outputs on every row of `inputs`, in chunks of the scratch's capacity.
    pub fn outputs(
        &self,
        params: &[f32],
        inputs: &[f32],
        scratch: &mut MlpScratch,
    ) -> Result<Vec<f32>, FileActorError> {
        let d = self.net.input_dim();
        let cap = scratch.max_batch();
        let mut out = Vec::with_capacity(inputs.len() / d * ACT_DIM);
        for chunk in inputs.chunks(cap * d) {
            let rows = chunk.len() / d;
            out.extend_from_slice(self.net.forward(params, chunk, rows, scratch)?);
        }
        Ok(out)
    }
}
