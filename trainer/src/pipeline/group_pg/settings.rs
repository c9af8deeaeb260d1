//! The settings of a group-relative policy-gradient fine-tune, and why one cannot run.

use std::path::PathBuf;

use dex_runtime::interface::ACT_DIM;
use dex_runtime::kinematics::ARM_JOINTS;
use serde::{Deserialize, Serialize};

use crate::env::Task;
use crate::env::seeds::{DEMO_SEED, episode_seed};
use crate::evaluate::EvalError;
use crate::learn::noise::{ExplorationNoise, NoiseConfig};
use crate::learn::{LearnError, Rng};
use crate::pipeline::file_actor::FileActorError;

use super::{MAX_STALL_BACK, STALL_POOL};

/// Why a fine-tune cannot run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GroupPgError {
    /// A setting is out of range.
    #[error("group_pg: {0}")]
    Settings(String),
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
    /// A rollout failed (the file, the runtime or the simulation).
    #[error(transparent)]
    Eval(#[from] EvalError),
    /// The learner refused a shape.
    #[error(transparent)]
    Learn(#[from] LearnError),
    /// The starting file is not an actor this fine-tune can start from, or the actor could not
    /// be written as a policy file.
    #[error(transparent)]
    Actor(#[from] FileActorError),
    /// The checkpoint does not decode or is of another start.
    #[error("checkpoint {path}: {why}")]
    Checkpoint {
        /// The file.
        path: PathBuf,
        /// Why it is refused.
        why: String,
    },
}

/// Settings of a group-relative policy-gradient fine-tune.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupPg {
    /// The f32 policy file (of the run's task) the actor starts from.
    pub policy: PathBuf,
    /// Iterations (each: rollouts, then the update).
    pub iterations: u32,
    /// Training starts per iteration.
    pub groups: u32,
    /// Episodes from each start (at least 2: the baseline is the group's mean).
    pub replicates: u32,
    /// Standard deviation of the noise on the arm's actions, action units.
    pub arm_noise: f32,
    /// Standard deviation of the noise on the fingers' actions.
    pub finger_noise: f32,
    /// Adam's step size.
    pub lr: f32,
    /// Passes over an iteration's kept steps.
    pub epochs: u32,
    /// Steps per Adam step.
    pub minibatch: u32,
    /// PPO's ratio clip.
    pub clip: f32,
    /// Weight of the KL divergence to the starting file (0: none).
    pub anchor: f32,
    /// Share of each iteration's groups that revisit starts where a recent group failed at
    /// least once (0: every start is fresh). Such starts carry both outcomes more often, so more
    /// of the episodes carry a gradient; the objective then weighs the hard starts more.
    #[serde(default)]
    pub revisit: f32,
    /// Groups per iteration, beside `groups`, that start from stalled states of the policy
    /// (0: none; at most [`STALL_POOL`]).
    #[serde(default)]
    pub stall_groups: u32,
    /// Noise-free episodes of the starting file whose stalls fill the pool before the first
    /// iteration (0: the pool fills from the noisy episodes alone).
    #[serde(default)]
    pub stall_harvest: u32,
    /// Weight of the KL divergence to the starting file on every step of the start-seed groups'
    /// episodes, whether their group carries a gradient or not (0: none). It holds the policy
    /// where it works while the stall groups move it where it stalls; `anchor` acts on the
    /// steps with a gradient only, stall groups' included. The kept rows share the minibatches,
    /// so the policy-gradient term's mean is over more rows (a smaller step at the same `lr`).
    #[serde(default)]
    pub fresh_anchor: f32,
    /// Steps before each stall that a pool entry keeps (0: the stalled state itself). The
    /// detector needs ten still steps, so from about 12 on an entry lies in the approach, where
    /// a noise-free policy can avoid the stall rather than escape it (session 32).
    #[serde(default)]
    pub stall_back: u32,
    /// Steps at the beginning of each episode from a stalled state that carry the noise (0: all
    /// of them). The rest run the policy's own action and stay out of the update, so an episode
    /// succeeds when a perturbation in its first steps puts the *noise-free* policy on a path
    /// that works, the behaviour the flashed file needs; with noise on every step the groups
    /// learn grasps that only the noise makes work (sessions 31-33).
    #[serde(default)]
    pub stall_noise_steps: u32,
    /// Groups per iteration, beside `groups`, whose fresh starts are drawn with the bricks'
    /// centres at most `close_spacing` apart ([`crate::env::JacoEnv::reset_close`]; 0: none).
    /// On Stack the shipped file's failures lie there (session 36: 15 of its 17 failures on
    /// 1000 starts at spacings of 8-9 cm, where 14% of starts fail, and none above 9.3 cm), so
    /// these groups carry the gradient where the failures are, from new starts every time,
    /// unlike the stall pool's few states. No anchor acts on their steps beyond `anchor`.
    #[serde(default)]
    pub close_groups: u32,
    /// The largest spacing of the bricks' centres in the close groups' starts, metres (above
    /// the 8 cm the start draw keeps between them).
    #[serde(default = "default_close_spacing")]
    pub close_spacing: f32,
    /// Steps at the beginning of each close group's episodes that carry the noise (0: all of
    /// them), as `stall_noise_steps` does for the stall groups: the rest run the policy's own
    /// action and stay out of the update, so a close group's outcome is that of the noise-free
    /// policy after a perturbation of its approach (session 36 saw the close starts' success
    /// with the noise on every step rise without the noise-free file's).
    #[serde(default)]
    pub close_noise_steps: u32,
    /// Groups per iteration, beside `groups`, from starts the starting file fails without noise
    /// (`failed_starts`; 0: none; at most as many as the list holds). Session 38 found the
    /// Stack clone's failures as rare as 11 in 1000 starts, and the teacher solving most of
    /// them: these groups spend the rollouts where the file is known to fail, revisiting each
    /// such start with new noise every iteration (session 39).
    #[serde(default)]
    pub failed_groups: u32,
    /// The start seeds the starting file fails without noise (`trainer pg --failed-from`
    /// reads them from a `trainer compare --json` record of that file on training starts,
    /// [`crate::env::seeds::SCREEN_SEED`]'s block by default). Part of the settings, so a resumed run
    /// refuses another list.
    #[serde(default)]
    pub failed_starts: Vec<u64>,
    /// Steps at the beginning of each failed-start group's episodes that carry the noise (0: all
    /// of them), as `close_noise_steps` does for the close groups.
    #[serde(default)]
    pub failed_noise_steps: u32,
    /// What an episode that touches brick 2 with the robot before it first grasps brick 1
    /// ([`crate::env::JacoEnv::robot_touches_brick2`]) loses beside its success (0: nothing;
    /// at most 1, a failure's worth). On Stack about half of the clone's episodes with such a
    /// contact fail, against a quarter of a percent of the others (session 40), and whether the
    /// fingers touch brick 2 on the way down depends on the approach smoothly, where whether an
    /// episode that touched it ends well is a coin flip: the cost gives the groups a gradient
    /// toward approaches that keep clear of brick 2, in groups whose episodes all succeed too.
    #[serde(default)]
    pub contact_cost: f32,
    /// With `contact_cost`, the distance (metres) within which a fingertip that passes brick 2
    /// before the grasp without touching it is charged too (0: only a contact is): the share of
    /// the cost is `(margin - clearance) / margin`, clearance being the nearest the fingers'
    /// geoms came to brick 2's ([`crate::env::JacoEnv::finger_clearance_to_brick2`]).
    /// A contact is a yes or no that the noise of one group rarely changes; how near the tips
    /// pass changes with every draw, so more groups carry the gradient away from brick 2.
    #[serde(default)]
    pub contact_margin: f32,
    /// Correlation from one step's exploration noise to the next, in [0, 1) (0: white noise, as
    /// before session 41). Each joint's noise is a first-order autoregression
    /// `z_t = rho z_(t-1) + sqrt(1 - rho^2) w_t` in units of its `arm_noise` or `finger_noise`,
    /// so every step keeps that spread while the hand's path drifts: white noise of a tenth of
    /// the command averages out over the approach, and whether the fingers meet brick 2 on the
    /// way down rarely changes within a group (session 40); a correlated drift moves the
    /// approach itself. The update is unchanged: it moves each kept step's action toward or away
    /// from the noisy action that step took, weighted by the group advantage (per step, as if
    /// the noise were white; an advantage-weighted surrogate, not the exact likelihood ratio of
    /// the correlated draw).
    #[serde(default)]
    pub noise_correlation: f32,
    /// Seed of the starts, the noise and the minibatch order.
    pub seed: u64,
}

impl GroupPg {
    /// The settings `trainer pg` starts from (chosen in session 30's spike, docs/experiments.md).
    pub fn new(policy: PathBuf) -> Self {
        GroupPg {
            policy,
            iterations: 60,
            groups: 16,
            replicates: 8,
            arm_noise: 0.1,
            finger_noise: 0.05,
            lr: 1e-5,
            epochs: 4,
            minibatch: 1024,
            clip: 0.2,
            anchor: 0.0,
            revisit: 0.0,
            stall_groups: 0,
            stall_harvest: 0,
            fresh_anchor: 0.0,
            stall_back: 0,
            stall_noise_steps: 0,
            close_groups: 0,
            close_spacing: default_close_spacing(),
            close_noise_steps: 0,
            failed_groups: 0,
            failed_starts: Vec::new(),
            failed_noise_steps: 0,
            contact_cost: 0.0,
            contact_margin: 0.0,
            noise_correlation: 0.0,
            seed: 1,
        }
    }

    /// Checks the ranges (not the file: [`GroupPg::run`] reads it).
    pub fn validate(&self) -> Result<(), GroupPgError> {
        let bad = |why: &str| Err(GroupPgError::Settings(why.to_owned()));
        if self.iterations == 0 || self.groups == 0 || self.epochs == 0 || self.minibatch == 0 {
            return bad("iterations, groups, epochs and minibatch must be at least 1");
        }
        if self.replicates < 2 {
            return bad("replicates must be at least 2 (the baseline is the group's mean)");
        }
        let noise_ok = |s: f32| s.is_finite() && s > 0.0 && s <= 1.0;
        if !noise_ok(self.arm_noise) || !noise_ok(self.finger_noise) {
            return bad("noise must be in (0, 1]: the gradient divides by it");
        }
        if !(self.lr.is_finite() && self.lr > 0.0 && self.lr < 1.0) {
            return bad("lr must be in (0, 1)");
        }
        if !(self.clip.is_finite() && self.clip > 0.0 && self.clip < 1.0) {
            return bad("clip must be in (0, 1)");
        }
        if !(self.anchor.is_finite() && self.anchor >= 0.0) {
            return bad("anchor must be finite and at least 0");
        }
        if !(self.fresh_anchor.is_finite() && self.fresh_anchor >= 0.0) {
            return bad("fresh_anchor must be finite and at least 0");
        }
        if !(self.revisit.is_finite() && (0.0..1.0).contains(&self.revisit)) {
            return bad("revisit must be in [0, 1)");
        }
        if self.stall_groups as usize > STALL_POOL {
            return bad("stall_groups must be at most 256 (the stall pool's size)");
        }
        if self.stall_harvest > 0 && self.stall_groups == 0 {
            return bad("stall_harvest finds states for stall_groups, which is 0");
        }
        if self.stall_back > 0 && self.stall_groups == 0 {
            return bad("stall_back places the states of stall_groups, which is 0");
        }
        if self.stall_noise_steps > 0 && self.stall_groups == 0 {
            return bad("stall_noise_steps limits the noise of stall_groups, which is 0");
        }
        if let Err(e) = crate::env::random_start::check_close_spacing(f64::from(self.close_spacing))
        {
            return bad(&format!("close_spacing: {e}"));
        }
        if self.close_noise_steps > 0 && self.close_groups == 0 {
            return bad("close_noise_steps limits the noise of close_groups, which is 0");
        }
        if self.close_groups > 4096 {
            return bad("close_groups must be at most 4096");
        }
        if self.failed_groups as usize > self.failed_starts.len() {
            return bad(&format!(
                "failed_groups ({}) must be at most the failed starts listed ({}); list them \
                 with `--failed-from`",
                self.failed_groups,
                self.failed_starts.len()
            ));
        }
        if self.failed_noise_steps > 0 && self.failed_groups == 0 {
            return bad("failed_noise_steps limits the noise of failed_groups, which is 0");
        }
        if !(self.contact_cost.is_finite() && (0.0..=1.0).contains(&self.contact_cost)) {
            return bad("contact_cost must be in [0, 1] (1: a touch costs as much as a failure)");
        }
        if !(self.contact_margin.is_finite() && (0.0..=0.05).contains(&self.contact_margin)) {
            return bad("contact_margin must be in [0, 0.05] metres");
        }
        if self.contact_margin > 0.0 && self.contact_cost == 0.0 {
            return bad("contact_margin widens contact_cost, which is 0");
        }
        if !(self.noise_correlation.is_finite() && (0.0..1.0).contains(&self.noise_correlation)) {
            return bad("noise_correlation must be in [0, 1)");
        }
        if self.stall_back > MAX_STALL_BACK {
            return bad("stall_back must be at most 100 steps");
        }
        if self.stall_harvest > 100_000 {
            return bad("stall_harvest must be at most 100000 episodes");
        }
        Ok(())
    }

    /// The task of the starting file (read from its header).
    pub fn task(&self) -> Result<Task, GroupPgError> {
        let file = std::fs::read(&self.policy).map_err(|source| GroupPgError::Io {
            path: self.policy.clone(),
            source,
        })?;
        let aligned = dex_runtime::aligned::aligned_copy(&file);
        let view = crate::evaluate::decode_jaco_policy(aligned.as_bytes())?;
        Ok(Task::from(view.body().task))
    }

    /// The share (0 to 1) of `contact_cost` an episode pays: all of it when the robot touched
    /// brick 2 before the grasp, else the part of `contact_margin` its nearest fingertip came
    /// within.
    pub fn contact_share(&self, touched: bool, clearance: f32) -> f32 {
        if touched {
            1.0
        } else if self.contact_margin > 0.0 {
            ((self.contact_margin - clearance) / self.contact_margin).clamp(0.0, 1.0)
        } else {
            0.0
        }
    }

    /// Noise standard deviation of action component `j`.
    pub(super) fn sigma(&self, j: usize) -> f32 {
        if j < ARM_JOINTS {
            self.arm_noise
        } else {
            self.finger_noise
        }
    }

    /// An episode's exploration noise: `arm_noise` on the arm joints, `finger_noise` on the
    /// fingers, white or with `noise_correlation`, its state drawn from the stationary spread
    /// (white noise draws nothing here, so its stream is the plain Gaussian one).
    pub(super) fn exploration_noise(&self, rng: &mut Rng) -> ExplorationNoise {
        let cfg = NoiseConfig {
            std: 1.0,
            correlation: self.noise_correlation,
            scale: (0..ACT_DIM).map(|j| self.sigma(j)).collect(),
        };
        let mut noise = ExplorationNoise::new(&cfg, ACT_DIM);
        noise.reset(rng);
        noise
    }

    /// Fresh start seed of group `g` of iteration `i`.
    pub fn start_seed(&self, iteration: u32, group: u32) -> u64 {
        episode_seed(
            DEMO_SEED + self.seed * 1_000 + 7,
            u64::from(iteration) * u64::from(self.groups) + u64::from(group),
        )
    }

    /// Start seed of close group `g` of iteration `i` (its start drawn with the bricks close).
    pub fn close_seed(&self, iteration: u32, group: u32) -> u64 {
        episode_seed(
            DEMO_SEED + self.seed * 1_000 + 9,
            u64::from(iteration) * u64::from(self.close_groups) + u64::from(group),
        )
    }

    /// Start seed of the `i`-th noise-free episode that harvests stalls before the first
    /// iteration.
    pub fn harvest_seed(&self, i: u32) -> u64 {
        episode_seed(DEMO_SEED + self.seed * 1_000 + 8, u64::from(i))
    }

    /// The pool entries the stall groups of iteration `i` start from: `stall_groups` of `pool`
    /// (all of them when it holds fewer), without repeats.
    pub fn stall_picks(&self, iteration: u32, pool: usize) -> Vec<usize> {
        let mut rng = Rng::derive(self.seed, 0x6770_5000 + u64::from(iteration));
        let all: Vec<usize> = (0..pool).collect();
        draw_without_repeats(&all, self.stall_groups as usize, &mut rng)
    }

    /// The failed starts the failed-start groups of iteration `i` run from: `failed_groups` of
    /// [`GroupPg::failed_starts`], without repeats.
    pub fn failed_picks(&self, iteration: u32) -> Vec<u64> {
        let mut rng = Rng::derive(self.seed, 0x6773_5000 + u64::from(iteration));
        draw_without_repeats(&self.failed_starts, self.failed_groups as usize, &mut rng)
    }

    /// How many of an iteration's groups revisit a start, with `hard` starts to choose from.
    pub fn revisits(&self, hard: usize) -> usize {
        ((self.revisit * self.groups as f32).round() as usize).min(hard)
    }

    /// The start seeds of iteration `i`: the first `revisit * groups` (at most as many as
    /// `hard` holds) drawn from `hard` without repeats, the rest fresh.
    pub fn starts(&self, iteration: u32, hard: &[u64]) -> Vec<u64> {
        let k = self.revisits(hard.len());
        let mut rng = Rng::derive(self.seed, 0x6770_4000 + u64::from(iteration));
        let mut out = draw_without_repeats(hard, k, &mut rng);
        for g in k as u32..self.groups {
            out.push(self.start_seed(iteration, g));
        }
        out
    }
}

/// `k` entries of `pool` (all of them when it holds fewer), drawn without repeats: the one draw
/// behind the revisits, the stall picks and the failed-start picks.
fn draw_without_repeats<T: Copy>(pool: &[T], k: usize, rng: &mut Rng) -> Vec<T> {
    let mut left = pool.to_vec();
    (0..k.min(pool.len()))
        .map(|_| left.swap_remove(rng.below(left.len())))
        .collect()
}

/// [`GroupPg::close_spacing`]'s default: 9.5 cm, above the largest spacing of the shipped Stack
/// file's failures on 1000 development starts (9.3 cm; session 36).
fn default_close_spacing() -> f32 {
    0.095
}
