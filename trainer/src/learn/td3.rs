//! TD3's stabilisers (Fujimoto et al. 2018), each switchable: twin critics with the minimum of the
//! two target critics in the target, target policy smoothing (clipped Gaussian noise on the target
//! action), and delayed actor and target updates (one per `policy_delay` critic updates).
//!
//! All off by default, which is the paper's DDPG. The pieces act in [`super::ddpg`] (targets and
//! the second critic's regression) and in the trainer's update (the delay, the second critic's
//! Adam step and target).

use super::LearnError;
use serde::{Deserialize, Serialize};

/// TD3 switches.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Td3Config {
    /// A second critic (own initial weights, target and Adam state); targets use the minimum of the
    /// two target critics, the actor follows the first.
    pub twin_critics: bool,
    /// Standard deviation of the noise on the target action (0: no smoothing); TD3 uses 0.2.
    pub target_noise: f32,
    /// The target noise is clipped to `+-target_noise_clip` (TD3: 0.5).
    pub target_noise_clip: f32,
    /// Actor and target updates once per this many critic updates (1: every update; TD3: 2).
    pub policy_delay: u64,
}

impl Default for Td3Config {
    fn default() -> Self {
        Td3Config {
            twin_critics: false,
            target_noise: 0.0,
            target_noise_clip: 0.5,
            policy_delay: 1,
        }
    }
}

impl Td3Config {
    /// All three pieces at TD3's published settings.
    pub fn td3() -> Self {
        Td3Config {
            twin_critics: true,
            target_noise: 0.2,
            target_noise_clip: 0.5,
            policy_delay: 2,
        }
    }

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), LearnError> {
        let bad = |field, why| Err(LearnError::Config { field, why });
        if !(self.target_noise >= 0.0 && self.target_noise.is_finite()) {
            return bad("td3.target_noise", "must be finite and non-negative");
        }
        if !(self.target_noise_clip >= 0.0 && self.target_noise_clip.is_finite()) {
            return bad("td3.target_noise_clip", "must be finite and non-negative");
        }
        if self.policy_delay == 0 {
            return bad("td3.policy_delay", "must be at least 1");
        }
        Ok(())
    }

    /// Whether the actor (and the targets) move at update number `u` (counted from 1).
    pub fn actor_due(&self, u: u64) -> bool {
        u.is_multiple_of(self.policy_delay.max(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_and_the_delay() {
        assert!(Td3Config::default().validate().is_ok());
        assert!(Td3Config::td3().validate().is_ok());
        let d = Td3Config::td3();
        assert!(!d.actor_due(1) && d.actor_due(2) && !d.actor_due(3));
        assert!(Td3Config::default().actor_due(1));
        for bad in [
            Td3Config {
                policy_delay: 0,
                ..d
            },
            Td3Config {
                target_noise: -1.0,
                ..d
            },
            Td3Config {
                target_noise_clip: f32::NAN,
                ..d
            },
        ] {
            assert!(bad.validate().is_err());
        }
    }
}
