//! An IBRL run's pair as one teacher ([`crate::learn::ibrl`]): at each state, whichever of the
//! run's actor and its frozen proposal (the clone the run started from) the run's critic rates
//! higher. The runtime runs one network, so the pair is measured (`trainer compare --pair`) and
//! distilled into one (`trainer imitate --teacher-pair`), not flashed.

use std::path::{Path, PathBuf};

use dex_runtime::features::{INPUT_MAX, policy_input};
use dex_runtime::interface::ACT_DIM;

use crate::cell::run_folder::{RunFolderError, load_run};
use crate::env::{Demonstration, EnvError, JacoEnv};
use crate::learn::ibrl::{Chosen, ProposalScratch, choose};
use crate::learn::nets::MlpScratch;
use crate::learn::{LearnError, Networks};
use crate::pipeline::train_settings::TaskArg;

/// Why an IBRL run's folder cannot be a teacher.
#[derive(Debug, thiserror::Error)]
pub enum ProposalPairError {
    /// A file of the run's folder could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The run's folder could not be read back.
    #[error(transparent)]
    Run(#[from] RunFolderError),
    /// The run is not an IBRL run, or its networks cannot be paired as they are.
    #[error("{dir}: {why}")]
    NotAPair {
        /// The run's seed folder.
        dir: PathBuf,
        /// What is missing.
        why: &'static str,
    },
    /// The run's starting policy file does not fit its actor.
    #[error("{path}: {source}")]
    Proposal {
        /// The file.
        path: PathBuf,
        /// The error.
        source: crate::files::policy_import::ImportError,
    },
}

/// The actor, the proposal and the critic(s) of an IBRL run's last checkpoint.
#[derive(Debug, Clone)]
pub struct ProposalPair {
    nets: Networks,
    actor: Vec<f32>,
    proposal: Vec<f32>,
    critic: Vec<f32>,
    twin: Option<Vec<f32>>,
    actor_scratch: MlpScratch,
    scratch: ProposalScratch,
    chosen: u64,
    steps: u64,
}

impl ProposalPair {
    /// The pair of the run in `seed_dir` (a `trainer train` seed folder: `checkpoint.bin`, and
    /// `settings.toml` naming the starting policy, read from where the run read it); also the
    /// run's task. The run must have `ibrl` on and its observation normalisation off (the pair
    /// then takes the observation as the learner's environment gives it).
    pub fn from_run(seed_dir: &Path) -> Result<(Self, TaskArg), ProposalPairError> {
        let (settings, t) = load_run(seed_dir)?;
        let not = |why| {
            Err(ProposalPairError::NotAPair {
                dir: seed_dir.to_owned(),
                why,
            })
        };
        if !t.config().ibrl {
            return not("the run was not an IBRL run (run.ibrl): it has no proposal");
        }
        if t.config().obs_norm.enabled {
            return not("the run normalises its observations; pairs are read without it");
        }
        let Some(init) = settings.init_policy.clone() else {
            return not("the run's settings name no init_policy to be the proposal");
        };
        let bytes = std::fs::read(&init).map_err(|source| ProposalPairError::Io {
            path: init.clone(),
            source,
        })?;
        let nets = t.networks().clone();
        let task = settings.task.task();
        let proposal =
            crate::files::policy_import::actor_params_from_policy(&bytes, task, &nets.actor)
                .map_err(|source| ProposalPairError::Proposal { path: init, source })?;
        let pair = ProposalPair {
            actor: t.actor().1.to_vec(),
            critic: t.critic().1.to_vec(),
            twin: t.twin_critic().map(<[f32]>::to_vec),
            proposal,
            actor_scratch: nets.actor.scratch(1),
            scratch: ProposalScratch::new(&nets),
            nets,
            chosen: 0,
            steps: 0,
        };
        Ok((pair, settings.task))
    }

    /// The share of [`Demonstration::act`] calls so far (this copy) that returned the proposal's
    /// action.
    pub fn proposal_share(&self) -> f64 {
        self.chosen as f64 / self.steps.max(1) as f64
    }

    /// The pair's action for the learner's observation `x` (with the task features where the run
    /// took them), and which member gave it.
    pub fn act_on(&mut self, x: &[f32]) -> Result<([f32; ACT_DIM], Chosen), LearnError> {
        let mut action = [0.0f32; ACT_DIM];
        let a = self
            .nets
            .actor
            .forward(&self.actor, x, 1, &mut self.actor_scratch)?;
        action.copy_from_slice(&a[..ACT_DIM]);
        let second = self.twin.as_deref().unwrap_or(&self.critic);
        let c = choose(
            &self.nets,
            &self.proposal,
            [&self.critic, second],
            x,
            &mut action,
            &mut self.scratch,
        )?;
        self.steps += 1;
        if c == Chosen::Proposal {
            self.chosen += 1;
        }
        Ok((action, c))
    }
}

impl Demonstration for ProposalPair {
    /// The pair is stateless.
    fn restart(&mut self) {}

    fn act(&mut self, env: &JacoEnv) -> Result<[f32; ACT_DIM], EnvError> {
        let mut buf = [0.0f32; INPUT_MAX];
        let x = policy_input(env.observation(), self.nets.obs_dim, &mut buf);
        self.act_on(x)
            .map(|(a, _)| a)
            .map_err(|e| EnvError::StartScheme(format!("IBRL pair: {e}")))
    }
}
