//! An exported policy file as the demonstration of the "along demonstrations" start scheme (the
//! paper allows a previously trained policy in place of the scripted demonstrator). It acts through
//! the runtime's evaluator, exactly as a controller would run it.

use std::sync::Arc;

use dex_runtime::Network;
use dex_runtime::aligned::AlignedBytes;
use dex_runtime::interface::ACT_DIM;

use crate::env::{Demonstration, Demonstrator, EnvError, JacoEnv, MarkovDemonstrator};
use crate::evaluate::{EVAL_WIDTH, EvalError, decode_jaco_policy, physical_to_env_action};

/// A policy file driving demonstrations: an aligned copy of the file, shared by the clones (one
/// per worker), and the runtime's evaluator over it.
#[derive(Debug, Clone)]
pub struct PolicyDemonstration {
    file: Arc<AlignedBytes>,
    net: Network<EVAL_WIDTH>,
}

impl PolicyDemonstration {
    /// Decodes and checks `file` (any alignment).
    pub fn from_file_bytes(file: &[u8]) -> Result<Self, EvalError> {
        Ok(Self::with_task(file)?.0)
    }

    /// [`PolicyDemonstration::from_file_bytes`], also giving the task the file was made for.
    pub fn with_task(file: &[u8]) -> Result<(Self, dex_policy::Task), EvalError> {
        let aligned = Arc::new(dex_runtime::aligned::aligned_copy(file));
        let (net, task) = {
            let view = decode_jaco_policy(aligned.as_bytes())?;
            (Network::new(&view, aligned.as_bytes())?, view.body().task)
        };
        Ok((Self { file: aligned, net }, task))
    }
}

impl Demonstration for PolicyDemonstration {
    /// The policy is stateless.
    fn restart(&mut self) {}

    fn act(&mut self, env: &JacoEnv) -> Result<[f32; ACT_DIM], EnvError> {
        let mut physical = [0.0f32; ACT_DIM];
        let mut buf = [0.0f32; dex_runtime::features::INPUT_MAX];
        let x =
            dex_runtime::features::policy_input(env.observation(), self.net.obs_dim(), &mut buf);
        self.net
            .act(self.file.as_bytes(), x, &mut physical)
            .map_err(|e| EnvError::StartScheme(format!("demonstration policy: {e}")))?;
        Ok(physical_to_env_action(&physical))
    }
}

/// Several policy files of one task acting as one: the mean of their normalised actions. Clones
/// of one teacher that differ only in their seed fail on largely different starts (the Grasp
/// clones of sessions 20-21: each fails 8-13 of 1000 selection starts, the mean of eight of them
/// 4), so the mean is a better teacher for a single network to be distilled from
/// (docs/experiments.md, session 22).
#[derive(Debug, Clone)]
pub struct PolicyEnsemble {
    members: Vec<PolicyDemonstration>,
}

impl PolicyEnsemble {
    /// The ensemble of `files` (any alignment), all of one task; that task. None is an error, as
    /// is a file of another task than the first.
    pub fn from_files(files: &[Vec<u8>]) -> Result<(Self, dex_policy::Task), EvalError> {
        let mut members = Vec::with_capacity(files.len());
        let mut task = None;
        for f in files {
            let (p, t) = PolicyDemonstration::with_task(f)?;
            match task {
                None => task = Some(t),
                Some(first) if first != t => return Err(EvalError::EnsembleTasks),
                Some(_) => {}
            }
            members.push(p);
        }
        let task = task.ok_or(EvalError::EnsembleTasks)?;
        Ok((Self { members }, task))
    }

    /// The number of member policies.
    pub fn len(&self) -> usize {
        self.members.len()
    }

    /// Never true: [`PolicyEnsemble::from_files`] refuses an empty ensemble.
    pub fn is_empty(&self) -> bool {
        self.members.is_empty()
    }
}

impl Demonstration for PolicyEnsemble {
    /// The members are stateless.
    fn restart(&mut self) {}

    fn act(&mut self, env: &JacoEnv) -> Result<[f32; ACT_DIM], EnvError> {
        let mut mean = [0.0f32; ACT_DIM];
        let n = self.members.len().max(1) as f32;
        for m in &mut self.members {
            let a = m.act(env)?;
            for (s, x) in mean.iter_mut().zip(a) {
                *s += x / n;
            }
        }
        Ok(mean)
    }
}

/// The demonstration behind a training run's start states: the scripted demonstrator or a policy.
#[derive(Debug, Clone)]
pub enum DemoSource {
    /// The scripted demonstrator of the task.
    Scripted(Demonstrator),
    /// The Markov scripted demonstrator of the task (its action depends on the state alone).
    Markov(MarkovDemonstrator),
    /// An exported policy.
    Policy(Box<PolicyDemonstration>),
    /// Several exported policies of one task acting as one ([`PolicyEnsemble`]).
    Ensemble(PolicyEnsemble),
    /// An IBRL run's actor and proposal, the better-rated action at each state
    /// ([`crate::cell::proposal_pair::ProposalPair`]).
    Pair(Box<crate::cell::proposal_pair::ProposalPair>),
}

impl Demonstration for DemoSource {
    fn restart(&mut self) {
        match self {
            DemoSource::Scripted(d) => Demonstration::restart(d),
            DemoSource::Markov(d) => Demonstration::restart(d),
            DemoSource::Policy(p) => p.restart(),
            DemoSource::Ensemble(e) => e.restart(),
            DemoSource::Pair(p) => p.restart(),
        }
    }

    fn act(&mut self, env: &JacoEnv) -> Result<[f32; ACT_DIM], EnvError> {
        match self {
            DemoSource::Scripted(d) => Demonstration::act(d, env),
            DemoSource::Markov(d) => Demonstration::act(d, env),
            DemoSource::Policy(p) => p.act(env),
            DemoSource::Ensemble(e) => e.act(env),
            DemoSource::Pair(p) => p.act(env),
        }
    }
}
