//! Demonstrations as data (DDPGfD, Vecerik et al. 2017; Nair et al. 2018; RLPD, Ball et al. 2023):
//! a separate buffer of demonstration transitions that is never overwritten, a fixed fraction of
//! every mini-batch drawn from it, and a behaviour-cloning term on those rows in the actor's loss,
//! optionally Q-filtered (only where the critic rates the demonstrated action above the actor's).
//!
//! The actor's loss with `k` demonstration rows in a batch of `N` (see [`super::ddpg::actor_gradient`]):
//! `-1/N sum_N Q(s, mu(s)) + bc_weight / k sum_k f(s, a_d) |mu(s) - a_d|^2 + action_l2 / N sum_N |mu(s)|^2`,
//! with `f` 1, or with the Q-filter `1[Q(s, a_d) > Q(s, mu(s))]`. The regression target `a_d` is the
//! demonstrator's own (clean) action; the critic learns from the action the environment executed
//! (the label plus the recording's noise), which is what the reward and next observation follow.

use super::LearnError;
use super::replay::{Batch, Replay};
use super::rng::Rng;
use serde::{Deserialize, Serialize};

/// How demonstrations enter the updates (all off by default: the paper's DDPG).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DemoDataConfig {
    /// Fraction of each mini-batch drawn from the demonstration buffer, in `[0, 1]` (rounded to
    /// whole rows).
    pub fraction: f32,
    /// Weight of the behaviour-cloning term on the demonstration rows (0: none).
    pub bc_weight: f32,
    /// Apply the cloning term only where `Q(s, a_demo) > Q(s, mu(s))` (Nair et al.'s Q-filter).
    pub q_filter: bool,
    /// Updates on demonstration rows alone before the first environment step (DDPGfD's
    /// pre-training): the critic learns the demonstrations' returns by the usual TD target and the
    /// actor clones the labels (the cloning term alone: no `-Q`, no filter, weight 1). The run then
    /// starts from a behaviour-cloned policy and a critic that rates it, instead of from noise.
    pub pretrain_updates: u64,
    /// TD3+BC's normalisation of the `-Q` term (`alpha / mean|Q|`, Fujimoto and Gu 2021; they use
    /// alpha = 2.5): keeps the cloning term from being drowned once the critic's returns grow, so
    /// a pre-trained policy is fine-tuned instead of forgotten. 0: off.
    pub q_normalisation: f32,
    /// The actor's learning rate during the pre-training (None: `actor_adam.lr`). Cloning takes a
    /// higher rate than the fine-tuning that follows.
    pub pretrain_actor_lr: Option<f32>,
}

impl Default for DemoDataConfig {
    fn default() -> Self {
        DemoDataConfig {
            fraction: 0.0,
            bc_weight: 0.0,
            q_filter: true,
            pretrain_updates: 0,
            q_normalisation: 0.0,
            pretrain_actor_lr: None,
        }
    }
}

impl DemoDataConfig {
    /// Whether the run needs a demonstration buffer.
    pub fn uses_demos(&self) -> bool {
        self.fraction > 0.0
    }

    /// Demonstration rows in a batch of `n`.
    pub fn rows(&self, n: usize) -> usize {
        ((self.fraction * n as f32).round() as usize).min(n)
    }

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), LearnError> {
        self.validate_with(false)
    }

    /// [`DemoDataConfig::validate`] for a run whose replay rows carry teacher labels
    /// (`teacher_labels`): then the cloning term has targets without demonstration rows.
    pub fn validate_with(&self, teacher_labels: bool) -> Result<(), LearnError> {
        let bad = |field, why| Err(LearnError::Config { field, why });
        if !(0.0..=1.0).contains(&self.fraction) {
            return bad("demos.fraction", "must be in [0, 1]");
        }
        if !(self.bc_weight >= 0.0 && self.bc_weight.is_finite()) {
            return bad("demos.bc_weight", "must be finite and non-negative");
        }
        if !(self.q_normalisation >= 0.0 && self.q_normalisation.is_finite()) {
            return bad("demos.q_normalisation", "must be finite and non-negative");
        }
        if self
            .pretrain_actor_lr
            .is_some_and(|lr| !(lr > 0.0 && lr.is_finite()))
        {
            return bad("demos.pretrain_actor_lr", "must be positive and finite");
        }
        if self.pretrain_updates > 0 && self.fraction == 0.0 {
            return bad(
                "demos.pretrain_updates",
                "pre-training needs the demonstration buffer (demos.fraction > 0)",
            );
        }
        if self.bc_weight > 0.0 && self.fraction == 0.0 && !teacher_labels {
            return bad(
                "demos.bc_weight",
                "a cloning term needs demonstration rows in the batch (demos.fraction > 0) or \
                 teacher labels",
            );
        }
        Ok(())
    }
}

/// Demonstration transitions with their clean labels (filled once, sampled uniformly).
#[derive(Debug, Clone)]
pub struct DemoBuffer {
    rows: Replay,
    labels: Vec<f32>,
    act_dim: usize,
}

/// One demonstration transition as [`DemoBuffer::from_rows`] takes it.
#[derive(Debug, Clone, Copy)]
pub struct DemoTransition<'a> {
    /// Observation before the step.
    pub obs: &'a [f32],
    /// Action executed (what the critic learns from).
    pub executed: &'a [f32],
    /// The demonstrator's own action (the cloning target).
    pub label: &'a [f32],
    /// Reward under the run's reward function.
    pub reward: f32,
    /// Observation after the step.
    pub next_obs: &'a [f32],
    /// True only for a terminal step (a time limit is not one).
    pub terminal: bool,
}

impl DemoBuffer {
    /// A buffer holding exactly the given transitions. Fails when there are none or a row has the
    /// wrong size or a non-finite value.
    pub fn from_rows(
        obs_dim: usize,
        act_dim: usize,
        rows: &[DemoTransition<'_>],
    ) -> Result<Self, LearnError> {
        let n = rows.len();
        if n == 0 {
            return Err(LearnError::Config {
                field: "demos",
                why: "the demonstration set is empty",
            });
        }
        let mut buf = DemoBuffer {
            rows: Replay::new(n, obs_dim, act_dim),
            labels: Vec::with_capacity(n * act_dim),
            act_dim,
        };
        for t in rows {
            let t = *t;
            let sizes_ok = t.obs.len() == obs_dim
                && t.next_obs.len() == obs_dim
                && t.executed.len() == act_dim
                && t.label.len() == act_dim;
            if !sizes_ok {
                return Err(LearnError::Shape {
                    what: "demonstration row",
                    expected: 2 * obs_dim + 2 * act_dim,
                    got: t.obs.len() + t.next_obs.len() + t.executed.len() + t.label.len(),
                });
            }
            let finite = t
                .obs
                .iter()
                .chain(t.next_obs)
                .chain(t.executed)
                .chain(t.label)
                .all(|v| v.is_finite())
                && t.reward.is_finite();
            if !finite {
                return Err(LearnError::Config {
                    field: "demos",
                    why: "a demonstration row holds a non-finite value",
                });
            }
            buf.rows
                .push(t.obs, t.executed, t.reward, t.next_obs, t.terminal);
            buf.labels.extend_from_slice(t.label);
        }
        Ok(buf)
    }

    /// Transitions held.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Always false (an empty set is refused).
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Observation and action sizes.
    pub fn dims(&self) -> (usize, usize) {
        self.rows.dims()
    }

    /// The observations before each step, row-major (`len() * obs_dim` values).
    pub fn observations(&self) -> &[f32] {
        self.rows.observations()
    }

    /// Fills rows `0..k` of `batch` (transitions and `batch.bc_target`) with `k` transitions drawn
    /// uniformly with replacement and sets `batch.demo_rows = k`.
    pub fn sample_into(&self, rng: &mut Rng, k: usize, batch: &mut Batch) {
        let k = k.min(batch.capacity());
        let a = self.act_dim;
        for r in 0..k {
            let i = rng.below(self.len());
            self.rows.copy_row_into(i, batch, r);
            batch.bc_target[r * a..(r + 1) * a].copy_from_slice(&self.labels[i * a..(i + 1) * a]);
        }
        batch.demo_rows = k;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_ranges() {
        assert!(DemoDataConfig::default().validate().is_ok());
        let ok = DemoDataConfig {
            fraction: 0.25,
            bc_weight: 1.0,
            q_filter: true,
            pretrain_updates: 0,
            q_normalisation: 0.0,
            pretrain_actor_lr: None,
        };
        assert!(ok.validate().is_ok());
        assert_eq!(ok.rows(256), 64);
        for bad in [
            DemoDataConfig {
                fraction: 1.5,
                ..ok
            },
            DemoDataConfig {
                fraction: -0.1,
                ..ok
            },
            DemoDataConfig {
                bc_weight: f32::INFINITY,
                ..ok
            },
            DemoDataConfig {
                fraction: 0.0,
                ..ok
            },
            DemoDataConfig {
                fraction: 0.0,
                bc_weight: 0.0,
                pretrain_updates: 10,
                ..ok
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn samples_carry_their_own_labels_and_bad_rows_are_refused() {
        let obs: Vec<[f32; 2]> = (0..5).map(|i| [i as f32, 0.0]).collect();
        let exec: Vec<[f32; 1]> = (0..5).map(|i| [i as f32 * 0.1]).collect();
        let label: Vec<[f32; 1]> = (0..5).map(|i| [-(i as f32)]).collect();
        let rows: Vec<_> = (0..5)
            .map(|i| DemoTransition {
                obs: &obs[i],
                executed: &exec[i],
                label: &label[i],
                reward: i as f32,
                next_obs: &obs[i],
                terminal: false,
            })
            .collect();
        let buf = DemoBuffer::from_rows(2, 1, &rows).unwrap();
        assert_eq!(buf.len(), 5);
        let mut b = Batch::new(8, 2, 1);
        buf.sample_into(&mut Rng::seed_from_u64(1), 6, &mut b);
        assert_eq!(b.demo_rows, 6);
        for r in 0..6 {
            let i = b.obs[2 * r];
            assert_eq!(b.reward[r], i);
            assert_eq!(b.bc_target[r], -i);
            assert!((b.act[r] - i * 0.1).abs() < 1e-6);
        }
        let nan = [f32::NAN, 0.0];
        let bad = [DemoTransition {
            obs: &nan,
            executed: &exec[0],
            label: &label[0],
            reward: 0.0,
            next_obs: &obs[0],
            terminal: false,
        }];
        assert!(DemoBuffer::from_rows(2, 1, &bad).is_err());
        let short = [DemoTransition {
            obs: &exec[0],
            executed: &exec[0],
            label: &label[0],
            reward: 0.0,
            next_obs: &obs[0],
            terminal: false,
        }];
        assert!(DemoBuffer::from_rows(2, 1, &short).is_err());
        assert!(DemoBuffer::from_rows(2, 1, &[]).is_err());
    }
}
