//! The state a [`Trainer`] keeps between runs: the shared halves of the networks, each worker's
//! own state and the counters.

use super::*;

#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct SharedState {
    pub(crate) actor: Vec<f32>,
    pub(crate) critic: Vec<f32>,
    pub(crate) target_actor: Vec<f32>,
    pub(crate) target_critic: Vec<f32>,
    pub(crate) actor_adam: AdamShared,
    pub(crate) critic_adam: AdamShared,
    /// The twin critic (empty without `td3.twin_critics`).
    pub(crate) critic2: Vec<f32>,
    pub(crate) target_critic2: Vec<f32>,
    pub(crate) critic2_adam: AdamShared,
    pub(crate) updates: u64,
    pub(crate) train_return_sum: f64,
    pub(crate) train_return_n: u64,
    pub(crate) obs_stats: ObsStats,
}

impl Default for AdamShared {
    fn default() -> Self {
        AdamShared::new(0)
    }
}

#[derive(Debug, Clone)]
pub(crate) struct WorkerState {
    pub(crate) rng: Rng,
    pub(crate) actor_m: AdamLocal,
    pub(crate) critic_m: AdamLocal,
    /// First moment of the twin critic (empty without it).
    pub(crate) critic2_m: AdamLocal,
    pub(crate) replay: Option<Replay>,
    pub(crate) transitions: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Counters {
    pub(crate) episodes: u64,
    pub(crate) evals: u64,
    pub(crate) wall_s: f64,
}
