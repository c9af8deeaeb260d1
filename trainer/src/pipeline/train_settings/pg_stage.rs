//! The `[pg]` settings: the group-relative policy-gradient stage after a seed's export.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::pipeline::group_pg::{GroupPg, GroupPgError};

/// The policy-gradient stage of a pipeline run ([`crate::pipeline::group_pg`], `trainer pg`'s
/// fine-tune): after a seed's export, its file `OUT/seed-S/policy.dxpl` is fine-tuned in
/// `OUT/seed-S/pg/` from the task's success alone, with these settings and the pipeline seed as
/// its seed; the stage's last actor is the seed's final file, `OUT/seed-S/pg/policy.dxpl`.
///
/// The defaults are session 32's run F (docs/experiments.md): four fresh groups and sixteen
/// groups started 20 steps before the stalls that 3000 noise-free episodes of the file find,
/// step 1e-4 held by the KL anchor on the fresh groups, 20 iterations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PgStage {
    /// Iterations (each: the rollouts, then the update).
    pub iterations: u32,
    /// Fresh training starts per iteration.
    pub groups: u32,
    /// Episodes from each start (at least 2).
    pub replicates: u32,
    /// Noise on the arm's actions (standard deviation, action units).
    pub arm_noise: f32,
    /// Noise on the fingers' actions.
    pub finger_noise: f32,
    /// Adam's step size.
    pub lr: f32,
    /// Passes over an iteration's steps.
    pub epochs: u32,
    /// Steps per Adam step.
    pub minibatch: u32,
    /// PPO's ratio clip.
    pub clip: f32,
    /// Weight of the KL divergence to the starting file on the steps with a gradient.
    pub anchor: f32,
    /// Share of the groups that revisit starts where a recent group failed.
    pub revisit: f32,
    /// Groups per iteration from states where the policy stalled before its grasp.
    pub stall_groups: u32,
    /// Noise-free episodes of the starting file whose stalls fill the pool first.
    pub stall_harvest: u32,
    /// Weight of the KL divergence to the starting file on every step of the fresh groups.
    pub fresh_anchor: f32,
    /// Steps before each stall that the pool keeps.
    pub stall_back: u32,
    /// Steps at the beginning of each stall group's episodes that carry noise (0: every step).
    pub stall_noise_steps: u32,
    /// Groups per iteration from fresh starts with the bricks close together.
    pub close_groups: u32,
    /// The close groups' largest spacing of the bricks' centres, metres.
    pub close_spacing: f32,
    /// Steps at the beginning of each close group's episodes that carry noise (0: every step).
    pub close_noise_steps: u32,
    /// Keep the actor as `policy-NNNN.dxpl` every this many iterations (0: only the latest).
    pub save_every: u32,
}

impl Default for PgStage {
    fn default() -> Self {
        PgStage {
            iterations: 20,
            groups: 4,
            stall_groups: 16,
            stall_harvest: 3000,
            lr: 1e-4,
            fresh_anchor: 1.0,
            stall_back: 20,
            save_every: 10,
            ..PgStage::from_group_pg(&GroupPg::new(PathBuf::new()))
        }
    }
}

impl PgStage {
    /// The stage with `g`'s settings (its file and seed are the pipeline's).
    fn from_group_pg(g: &GroupPg) -> Self {
        PgStage {
            iterations: g.iterations,
            groups: g.groups,
            replicates: g.replicates,
            arm_noise: g.arm_noise,
            finger_noise: g.finger_noise,
            lr: g.lr,
            epochs: g.epochs,
            minibatch: g.minibatch,
            clip: g.clip,
            anchor: g.anchor,
            revisit: g.revisit,
            stall_groups: g.stall_groups,
            stall_harvest: g.stall_harvest,
            fresh_anchor: g.fresh_anchor,
            stall_back: g.stall_back,
            stall_noise_steps: g.stall_noise_steps,
            close_groups: g.close_groups,
            close_spacing: g.close_spacing,
            close_noise_steps: g.close_noise_steps,
            save_every: 10,
        }
    }

    /// The fine-tune of `policy` for pipeline seed `seed`.
    pub fn group_pg(&self, policy: PathBuf, seed: u64) -> GroupPg {
        GroupPg {
            policy,
            iterations: self.iterations,
            groups: self.groups,
            replicates: self.replicates,
            arm_noise: self.arm_noise,
            finger_noise: self.finger_noise,
            lr: self.lr,
            epochs: self.epochs,
            minibatch: self.minibatch,
            clip: self.clip,
            anchor: self.anchor,
            revisit: self.revisit,
            stall_groups: self.stall_groups,
            stall_harvest: self.stall_harvest,
            fresh_anchor: self.fresh_anchor,
            stall_back: self.stall_back,
            stall_noise_steps: self.stall_noise_steps,
            close_groups: self.close_groups,
            close_spacing: self.close_spacing,
            close_noise_steps: self.close_noise_steps,
            // The failed-start groups need a list of the clone's failures, which the pipeline
            // does not screen for (session 39 measured them with `trainer pg` alone).
            failed_groups: 0,
            failed_starts: Vec::new(),
            failed_noise_steps: 0,
            // Measured with `trainer pg` alone first (session 40).
            contact_cost: 0.0,
            contact_margin: 0.0,
            // Measured with `trainer pg` alone first (session 41).
            noise_correlation: 0.0,
            seed,
        }
    }

    /// Checks the ranges (those of [`GroupPg::validate`]).
    pub fn validate(&self) -> Result<(), GroupPgError> {
        self.group_pg(PathBuf::new(), 0).validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_is_session_32s_run_f() {
        let g = PgStage::default().group_pg(PathBuf::from("p.dxpl"), 1);
        let f = GroupPg {
            iterations: 20,
            groups: 4,
            stall_groups: 16,
            stall_harvest: 3000,
            lr: 1e-4,
            fresh_anchor: 1.0,
            stall_back: 20,
            ..GroupPg::new(PathBuf::from("p.dxpl"))
        };
        assert_eq!(g, f);
        assert!(PgStage::default().validate().is_ok());
    }
}
