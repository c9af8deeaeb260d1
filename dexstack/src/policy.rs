//! A policy file run through the runtime's evaluator, as `trainer eval` and a controller run it.

use dex_env::evaluate::{EVAL_WIDTH, decode_jaco_policy, physical_to_env_action};
use dex_policy::PolicyView;
use dex_runtime::Network;
use dex_runtime::aligned::AlignedBytes;
use dex_runtime::can::messages::{quantise_action, quantise_observation};
use dex_runtime::interface::{ACT_DIM, OBS_DIM};

use crate::error::{Error, Result};

/// What a policy file says about itself (header, layout, provenance), for `Policy.info()`.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyInfo {
    /// Format version (1: f32, 2: may hold int8 layers).
    pub version: u16,
    /// Header flags.
    pub flags: u16,
    /// Hash of the observation and action layout.
    pub layout_hash: u32,
    /// CRC-32 of the file.
    pub crc: u32,
    /// File size in bytes.
    pub bytes: usize,
    /// The task the policy was trained for (kebab-case).
    pub task: String,
    /// Observation fields: (name, size).
    pub observation: Vec<(String, u16)>,
    /// Observation clip applied by the evaluator.
    pub obs_clip: f32,
    /// Action joints: (name, scale, min, max).
    pub action: Vec<(String, f32, f32, f32)>,
    /// Control period in microseconds.
    pub control_period_us: u32,
    /// Layers: (outputs, activation, dtype), names in lower case.
    pub layers: Vec<(u16, String, String)>,
    /// Trainer version that exported it.
    pub trainer_version: String,
    /// Training seed.
    pub seed: u64,
    /// Training transitions.
    pub transitions: u64,
    /// Success rate recorded at export, if any.
    pub success_rate: Option<f32>,
    /// Episodes behind that success rate.
    pub eval_episodes: u32,
}

/// A decoded, checked policy and its evaluator. It owns an aligned copy of the file, and the
/// evaluator ([`Network`], the runtime's network without the borrow) reads the weights from it at
/// every step, so dropping the Python object frees the file.
#[derive(Debug)]
pub struct LoadedPolicy {
    file: AlignedBytes,
    net: Network<EVAL_WIDTH>,
    info: PolicyInfo,
    task: dex_env::Task,
}

impl LoadedPolicy {
    /// Decodes `file` (any alignment) and checks it against the Jaco cell's layout.
    pub fn from_bytes(file: &[u8]) -> Result<Self> {
        let aligned = dex_runtime::aligned::aligned_copy(file);
        let (net, info, task) = {
            let view = decode_jaco_policy(aligned.as_bytes())?;
            let net =
                Network::new(&view, aligned.as_bytes()).map_err(|e| Error::Policy(e.into()))?;
            let task = dex_env::Task::from(view.body().task);
            (net, describe(&view, file, task), task)
        };
        Ok(LoadedPolicy {
            file: aligned,
            net,
            info,
            task,
        })
    }

    /// The task the file was trained for.
    pub fn task(&self) -> dex_env::Task {
        self.task
    }

    /// Header, layout and provenance.
    pub fn info(&self) -> &PolicyInfo {
        &self.info
    }

    /// The environment's normalised action (each component in [-1, 1]) for `obs`: the runtime's
    /// physical command divided by each joint's scale. With `can_quantisation` the observation and
    /// the command pass the CAN bus's quantisation first, exactly as in `trainer eval` (its
    /// default).
    pub fn act(&mut self, obs: &[f32], can_quantisation: bool) -> Result<[f32; ACT_DIM]> {
        if obs.len() != OBS_DIM {
            return Err(Error::Shape {
                what: "observation",
                got: obs.len(),
                expected: OBS_DIM,
            });
        }
        if let Some((index, &value)) = obs.iter().enumerate().find(|(_, x)| !x.is_finite()) {
            return Err(Error::NonFiniteObservation { index, value });
        }
        let input: [f32; OBS_DIM] = core::array::from_fn(|i| {
            let x = obs.get(i).copied().unwrap_or(0.0);
            if can_quantisation {
                quantise_observation(i, x)
            } else {
                x
            }
        });
        let mut physical = [0.0f32; ACT_DIM];
        let mut buf = [0.0f32; dex_runtime::features::INPUT_MAX];
        let x = dex_runtime::features::policy_input(&input, self.net.obs_dim(), &mut buf);
        self.net
            .act(self.file.as_bytes(), x, &mut physical)
            .map_err(|e| Error::Policy(e.into()))?;
        if can_quantisation {
            physical = physical.map(quantise_action);
        }
        Ok(physical_to_env_action(&physical))
    }
}

fn describe(view: &PolicyView<'_>, file: &[u8], task: dex_env::Task) -> PolicyInfo {
    let h = view.header();
    let b = view.body();
    let lower = |s: String| s.to_lowercase();
    PolicyInfo {
        version: h.version,
        flags: h.flags,
        layout_hash: h.layout_hash,
        crc: h.crc,
        bytes: file.len(),
        task: crate::episode::task_name(task),
        observation: b
            .observation
            .iter()
            .map(|f| (f.name.to_owned(), f.size))
            .collect(),
        obs_clip: b.obs_clip,
        action: b
            .action
            .iter()
            .map(|j| (j.name.to_owned(), j.scale, j.min, j.max))
            .collect(),
        control_period_us: b.control_period_us,
        layers: b
            .layers
            .iter()
            .map(|l| {
                (
                    l.outputs,
                    lower(format!("{:?}", l.activation)),
                    lower(format!("{:?}", l.dtype)),
                )
            })
            .collect(),
        trainer_version: b.provenance.trainer_version.to_owned(),
        seed: b.provenance.seed,
        transitions: b.provenance.transitions,
        success_rate: b.provenance.success_rate,
        eval_episodes: b.provenance.eval_episodes,
    }
}
