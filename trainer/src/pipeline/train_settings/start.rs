//! The `[start]` settings: where training episodes start.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::StartArg;
use crate::env::StartScheme;

/// Where training episodes start (evaluation always uses the task's original starts, full length).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StartSettings {
    /// The scheme.
    pub scheme: StartArg,
    /// Probability of the in-hand start under `mixture`.
    pub in_hand_probability: f64,
    /// Training episode length under `along-demonstrations` (the paper: 50; evaluation keeps 150).
    pub train_episode_steps: u32,
    /// Under `along-demonstrations`: the size of the fixed set of demonstration trajectories the
    /// starts are drawn from, each simulated once (0: a fresh demonstration at every start, which
    /// costs its whole length in environment steps; `dex_env::start_states` module docs).
    pub demonstrations: u32,
    /// Under `along-demonstrations`: an exported policy file to demonstrate instead of the
    /// scripted demonstrator.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub demonstrator_policy: Option<PathBuf>,
    /// Failed-start revisits of a fine-tune (0: off): the starting policy (`init_policy` or the
    /// clone stage's file) runs on this many screening starts
    /// ([`SCREEN_SEED`](crate::env::seeds::SCREEN_SEED)) before training, and training episodes
    /// start from the ones it failed with probability `failed_start_probability`
    /// (`dex_env::start_states`, revisits; the list is kept in the seed folder's
    /// `failed_starts.json`).
    pub failed_starts: u32,
    /// Probability that a training episode revisits a failed start (with `failed_starts`).
    pub failed_start_probability: f64,
}

impl Default for StartSettings {
    fn default() -> Self {
        StartSettings {
            scheme: StartArg::Original,
            in_hand_probability: 0.5,
            train_episode_steps: crate::env::start_states::DEMO_TRAIN_EPISODE_STEPS,
            demonstrations: 0,
            demonstrator_policy: None,
            failed_starts: 0,
            failed_start_probability: 0.5,
        }
    }
}

impl StartSettings {
    /// The environment's scheme.
    pub fn scheme(&self) -> StartScheme {
        match self.scheme {
            StartArg::Original => StartScheme::Original,
            StartArg::Mixture => StartScheme::Mixture {
                in_hand_probability: self.in_hand_probability,
            },
            StartArg::AlongDemonstrations => StartScheme::AlongDemonstrations {
                train_episode_steps: self.train_episode_steps,
                demonstrations: self.demonstrations,
            },
        }
    }
}
