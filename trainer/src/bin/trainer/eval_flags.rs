//! The flags that say where a policy file is evaluated, shared by `trainer eval` and `trainer
//! compare` (each keeps its own `--episodes`: 100 for a quick look, 1000 for a comparison).

use clap::Args;

use dex_trainer::env::evaluate::EvalSettings;
use dex_trainer::env::seeds::EVAL_SEED;
use dex_trainer::pipeline::train_settings::{RewardArg, TaskArg};

/// The starts, the threads and the bus.
#[derive(Args, Debug)]
pub struct EvalFlags {
    /// Seed of the start states (1000000: the final evaluation's; 3000000: the Table II starts).
    #[arg(long, default_value_t = EVAL_SEED)]
    pub seed: u64,
    /// Worker threads.
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Skip the CAN quantisation of the policies' observations and actions.
    #[arg(long)]
    pub no_can_quantisation: bool,
}

impl EvalFlags {
    /// The evaluation of `episodes` starts of `task` with the task's own reward.
    pub fn settings(&self, task: TaskArg, episodes: u32, envelope: bool) -> EvalSettings {
        EvalSettings {
            env: RewardArg::TaskDefault.env_config(task.task()),
            episodes,
            seed: self.seed,
            threads: self.threads,
            can_quantisation: !self.no_can_quantisation,
            envelope,
        }
    }
}
