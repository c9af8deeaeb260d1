//! What one iteration of a fine-tune did, as a progress line and for a terminal.

use serde::{Deserialize, Serialize};

/// What one iteration did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IterationReport {
    /// Iteration index (from 0).
    pub iteration: u32,
    /// Episodes run.
    pub episodes: u32,
    /// Of them successful (with the noise).
    pub successes: u32,
    /// Groups whose episodes' rewards differ (the only ones with a gradient): both outcomes or,
    /// with a contact cost, touches of brick 2 in some of the episodes only.
    pub mixed_groups: u32,
    /// Steps the update used.
    pub samples: u64,
    /// Share of the update's sample gradients the ratio clip removed.
    pub clipped: f64,
    /// Root mean square of `(mu - clone) / sigma` over the kept steps after the update.
    pub drift: f64,
    /// Environment steps so far (all iterations).
    pub env_steps: u64,
    /// Groups run from stalled states (counted in `episodes`).
    #[serde(default)]
    pub stall_groups: u32,
    /// Of their episodes, successful.
    #[serde(default)]
    pub stall_successes: u32,
    /// Stalled states in the pool after the iteration.
    #[serde(default)]
    pub stall_pool: u32,
    /// Groups run from close starts (counted in `episodes`).
    #[serde(default)]
    pub close_groups: u32,
    /// Of their episodes, successful.
    #[serde(default)]
    pub close_successes: u32,
    /// Groups run from starts the starting file fails (counted in `episodes`).
    #[serde(default)]
    pub failed_groups: u32,
    /// Of their episodes, successful.
    #[serde(default)]
    pub failed_successes: u32,
    /// Episodes in which the robot touched brick 2 before it first grasped brick 1.
    #[serde(default)]
    pub touched: u32,
    /// Of them, episodes from close starts.
    #[serde(default)]
    pub close_touched: u32,
}

impl IterationReport {
    /// One line for a terminal (`trainer pg --quiet`, `trainer train`'s `[pg]` stage): the
    /// iteration, its successes with the noise, the groups with a gradient, the clipped share,
    /// the drift, the environment steps and, when it ran stall groups or holds stalls, their
    /// episodes' successes (each group `replicates` episodes) and the pool, and likewise the
    /// close groups' and the failed-start groups' successes, and the episodes that touched brick
    /// 2 before the grasp.
    pub fn line(&self, replicates: u32) -> String {
        let mut line = format!(
            "iteration {} success {}/{} with noise, {} groups with a gradient, clipped {:.3}, \
             drift {:.3}, {} env steps",
            self.iteration + 1,
            self.successes,
            self.episodes,
            self.mixed_groups,
            self.clipped,
            self.drift,
            self.env_steps
        );
        if self.close_groups > 0 {
            line += &format!(
                "; from close starts {}/{} ({} groups)",
                self.close_successes,
                self.close_groups * replicates,
                self.close_groups
            );
        }
        if self.failed_groups > 0 {
            line += &format!(
                "; from failed starts {}/{} ({} groups)",
                self.failed_successes,
                self.failed_groups * replicates,
                self.failed_groups
            );
        }
        if self.touched > 0 {
            line += &format!(
                "; touched brick 2 before the grasp in {} episodes ({} from close starts)",
                self.touched, self.close_touched
            );
        }
        if self.stall_groups > 0 || self.stall_pool > 0 {
            line += &format!(
                "; from stalls {}/{} ({} groups, pool {})",
                self.stall_successes,
                self.stall_groups * replicates,
                self.stall_groups,
                self.stall_pool
            );
        }
        line
    }
}
