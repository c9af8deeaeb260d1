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

/// The demonstration behind a training run's start states: the scripted demonstrator or a policy.
#[derive(Debug, Clone)]
pub enum DemoSource {
    /// The scripted demonstrator of the task.
    Scripted(Demonstrator),
    /// The Markov scripted demonstrator of the task (its action depends on the state alone).
    Markov(MarkovDemonstrator),
    /// An exported policy.
    Policy(Box<PolicyDemonstration>),
}

impl Demonstration for DemoSource {
    fn restart(&mut self) {
        match self {
            DemoSource::Scripted(d) => Demonstration::restart(d),
            DemoSource::Markov(d) => Demonstration::restart(d),
            DemoSource::Policy(p) => p.restart(),
        }
    }

    fn act(&mut self, env: &JacoEnv) -> Result<[f32; ACT_DIM], EnvError> {
        match self {
            DemoSource::Scripted(d) => Demonstration::act(d, env),
            DemoSource::Markov(d) => Demonstration::act(d, env),
            DemoSource::Policy(p) => p.act(env),
        }
    }
}
