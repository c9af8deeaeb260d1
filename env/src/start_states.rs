//! Instructive start states (the paper's second exploration strategy): where a *training* episode
//! begins. Evaluation always starts from the task's original start states with full-length episodes,
//! so learning curves stay comparable across schemes.
//!
//! - [`StartScheme::Original`]: the task's own start (both bricks on the table, random arm).
//! - [`StartScheme::Mixture`]: with probability `in_hand_probability` the episode starts with brick 1
//!   already grasped and lifted (the StackInHand start), otherwise from the original start.
//! - [`StartScheme::AlongDemonstrations`]: a demonstration (the scripted [`Demonstrator`], or any
//!   [`Demonstration`], e.g. an exported policy) runs from an original start until it first solves
//!   the task (or the episode's step budget runs out); that takes `n` steps. The learner starts from
//!   the state after `k` steps, `k` uniform in `1..=n` (reservoir sampling keeps one snapshot, so the
//!   cost is `n` environment steps and one state copy). Training episodes are then
//!   `train_episode_steps` long (50 in the paper).
//!
//!   With `demonstrations = P > 0` the demonstrations form a fixed set of P trajectories (a
//!   dataset, the same for every run seed: trajectory `i` starts from the original start of seed
//!   [`POOL_SEED_BASE`]` + i`, and only trajectories that solve the task are used). An episode
//!   seed picks a trajectory and a state uniformly along it; each trajectory is simulated once,
//!   when first picked, and its states kept, so a start costs one state copy instead of `n`
//!   environment steps. The pick is a function of the seed alone, so a resumed run hands over the
//!   same states as an uninterrupted one. Memory: about 2 kB per kept state (P = 500 Stack
//!   trajectories: ~100 MB per environment). P = 0 runs a fresh demonstration at every start.
//!
//! Revisits ([`StartStates::with_revisits`], on top of any scheme): with a given probability a
//! training episode starts instead from the original start of one of a list of seeds, picked
//! uniformly. A fine-tune lists the starts its starting policy failed on (screened on
//! [`crate::seeds::SCREEN_SEED`]'s starts), so that its episodes meet the starting policy's
//! failures far more often than the policy's failure rate would bring them (at 97% success,
//! 3 episodes in 100).
//!
//! Every handed-over state is a state the simulation reached by stepping: nothing is teleported, so
//! contacts and velocities are consistent (`env/tests/env_start_states.rs` checks that a held brick
//! stays held after the hand-over).

use std::collections::HashMap;

use dex_runtime::interface::ACT_DIM;

use super::demo::Demonstrator;
use super::environment::{EnvSnapshot, JacoEnv};
use super::error::EnvError;
use super::observation::Observation;
use super::rng::SeedRng;
use super::tasks::Task;

/// Training episode length of [`StartScheme::AlongDemonstrations`] in the paper (evaluation keeps 150).
pub const DEMO_TRAIN_EPISODE_STEPS: u32 = 50;

/// Salt mixed into an episode seed for the scheme's own random choices, so that the original start
/// drawn from a seed is the same under every scheme.
const SCHEME_SALT: u64 = 0x5EED_57A7_E5C4_E3E5;

/// Salt of the revisit draw (whether to revisit, and which seed), apart from the scheme's draws.
const REVISIT_SALT: u64 = 0x2E71_5175_0F5E_ED5A;

/// The largest list of revisited starts.
pub const MAX_REVISITS: usize = 100_000;

pub use super::seeds::POOL_SEED_BASE;

/// The largest demonstration pool (memory: ~2 kB per kept state, ~100 states per trajectory).
pub const MAX_POOL: u32 = 100_000;

/// Where training episodes start.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum StartScheme {
    /// The task's own start states.
    #[default]
    Original,
    /// The in-hand start with this probability, else the original start.
    Mixture {
        /// Probability of starting with brick 1 grasped and lifted, in `[0, 1]`.
        in_hand_probability: f64,
    },
    /// States along demonstrations from original starts, with short training episodes.
    AlongDemonstrations {
        /// Steps of a training episode from such a state.
        train_episode_steps: u32,
        /// Size of the fixed set of demonstration trajectories starts are drawn from (0: a fresh
        /// demonstration at every start; see the module docs).
        demonstrations: u32,
    },
}

impl StartScheme {
    /// The paper's demonstration scheme: 50-step training episodes.
    pub const fn along_demonstrations() -> Self {
        StartScheme::AlongDemonstrations {
            train_episode_steps: DEMO_TRAIN_EPISODE_STEPS,
            demonstrations: 0,
        }
    }

    /// Checks the scheme's numbers.
    pub fn validate(&self) -> Result<(), EnvError> {
        match *self {
            StartScheme::Original => Ok(()),
            StartScheme::Mixture {
                in_hand_probability: p,
            } if (0.0..=1.0).contains(&p) => Ok(()),
            StartScheme::Mixture {
                in_hand_probability,
            } => Err(EnvError::StartScheme(format!(
                "in-hand probability {in_hand_probability} is not in [0, 1]"
            ))),
            StartScheme::AlongDemonstrations {
                train_episode_steps: 0,
                ..
            } => Err(EnvError::StartScheme(
                "training episodes along demonstrations need at least one step".into(),
            )),
            StartScheme::AlongDemonstrations { demonstrations, .. }
                if demonstrations > MAX_POOL =>
            {
                Err(EnvError::StartScheme(format!(
                    "a pool of {demonstrations} demonstrations is more than {MAX_POOL}"
                )))
            }
            StartScheme::AlongDemonstrations { .. } => Ok(()),
        }
    }

    /// Length of a training episode under this scheme, given the task's episode length.
    pub fn train_episode_steps(&self, task_steps: u32) -> u32 {
        match *self {
            StartScheme::AlongDemonstrations {
                train_episode_steps,
                ..
            } => train_episode_steps.min(task_steps),
            _ => task_steps,
        }
    }
}

/// Something that acts in the environment to produce demonstration states.
pub trait Demonstration {
    /// Prepares for a new episode.
    fn restart(&mut self);
    /// The normalised action (each component in `[-1, 1]`) for the environment's current state.
    fn act(&mut self, env: &JacoEnv) -> Result<[f32; ACT_DIM], EnvError>;
}

impl Demonstration for Demonstrator {
    fn restart(&mut self) {
        Demonstrator::restart(self);
    }

    fn act(&mut self, env: &JacoEnv) -> Result<[f32; ACT_DIM], EnvError> {
        Ok(Demonstrator::act(self, env))
    }
}

/// How a handed-over training start was made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StartKind {
    /// The task's original start.
    Original,
    /// Brick 1 grasped and lifted (the StackInHand start).
    InHand,
    /// The original start of a revisited seed ([`StartStates::with_revisits`]).
    Revisit {
        /// The seed whose original start it is.
        seed: u64,
    },
    /// The state after `k` of the `n` steps a demonstration needed.
    Demonstration {
        /// Steps taken by the demonstration before the hand-over (`1..=n`).
        k: u32,
        /// Steps the demonstration needed to first solve the task (or the step budget).
        n: u32,
        /// Whether the demonstration solved the task.
        solved: bool,
    },
}

/// A training start handed to the learner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Handover {
    /// The first observation of the training episode.
    pub observation: Observation,
    /// How the state was made.
    pub kind: StartKind,
}

/// One trajectory of a demonstration pool: the state after each step (empty when the
/// demonstration did not solve the task).
type Trajectory = Vec<EnvSnapshot>;

/// Makes training starts for one environment under one scheme.
#[derive(Clone)]
pub struct StartStates<D: Demonstration = Demonstrator> {
    scheme: StartScheme,
    demo: D,
    /// The demonstration pool's trajectories simulated so far, by index.
    pool: HashMap<u32, Trajectory>,
    /// Seeds whose original starts are revisited, and the probability of a revisit.
    revisits: Revisits,
}

/// The starts revisited in training and how often ([`StartStates::with_revisits`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Revisits {
    /// Seeds whose original starts are revisited.
    pub seeds: Vec<u64>,
    /// Probability that a training episode is a revisit (none when `seeds` is empty).
    pub probability: f64,
}

impl<D: Demonstration> std::fmt::Debug for StartStates<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StartStates")
            .field("scheme", &self.scheme)
            .finish_non_exhaustive()
    }
}

impl StartStates<Demonstrator> {
    /// Starts for `task` under `scheme`, with the scripted demonstrator for demonstrations.
    pub fn scripted(scheme: StartScheme, task: Task) -> Result<Self, EnvError> {
        Self::new(scheme, Demonstrator::new(task))
    }
}

impl<D: Demonstration> StartStates<D> {
    /// The original starts (never fails; `demo` is kept but unused).
    pub fn original(demo: D) -> Self {
        Self {
            scheme: StartScheme::Original,
            demo,
            pool: HashMap::new(),
            revisits: Revisits::default(),
        }
    }

    /// Starts under `scheme`, with `demo` for demonstrations.
    pub fn new(scheme: StartScheme, demo: D) -> Result<Self, EnvError> {
        scheme.validate()?;
        Ok(Self {
            scheme,
            demo,
            pool: HashMap::new(),
            revisits: Revisits::default(),
        })
    }

    /// The same starts, except that with probability `revisits.probability` an episode starts from
    /// the original start of one of `revisits.seeds` (uniformly), under any scheme. Refuses a
    /// probability outside `[0, 1]` and more than [`MAX_REVISITS`] seeds.
    pub fn with_revisits(mut self, revisits: Revisits) -> Result<Self, EnvError> {
        if !(0.0..=1.0).contains(&revisits.probability) {
            return Err(EnvError::StartScheme(format!(
                "revisit probability {} is not in [0, 1]",
                revisits.probability
            )));
        }
        if revisits.seeds.len() > MAX_REVISITS {
            return Err(EnvError::StartScheme(format!(
                "{} revisited starts are more than {MAX_REVISITS}",
                revisits.seeds.len()
            )));
        }
        self.revisits = revisits;
        Ok(self)
    }

    /// The scheme.
    pub fn scheme(&self) -> StartScheme {
        self.scheme
    }

    /// The revisited starts.
    pub fn revisits(&self) -> &Revisits {
        &self.revisits
    }

    /// The seed to revisit for the episode of `seed`, if it is a revisit.
    fn revisit(&self, seed: u64) -> Option<u64> {
        let seeds = &self.revisits.seeds;
        if seeds.is_empty() {
            return None;
        }
        let mut rng = SeedRng::new(seed ^ REVISIT_SALT);
        if rng.unit() >= self.revisits.probability {
            return None;
        }
        // unit() < 1, so the index is below the length.
        let i = ((rng.unit() * seeds.len() as f64) as usize).min(seeds.len() - 1);
        seeds.get(i).copied()
    }

    /// Resets `env` to a training start drawn from `seed` alone. The environment's step counter is
    /// zero afterwards, whatever the hand-over.
    pub fn reset(&mut self, env: &mut JacoEnv, seed: u64) -> Result<Handover, EnvError> {
        if let Some(revisit) = self.revisit(seed) {
            return Ok(Handover {
                observation: env.reset(revisit)?,
                kind: StartKind::Revisit { seed: revisit },
            });
        }
        let mut rng = SeedRng::new(seed ^ SCHEME_SALT);
        match self.scheme {
            StartScheme::Original => Ok(Handover {
                observation: env.reset(seed)?,
                kind: StartKind::Original,
            }),
            StartScheme::Mixture {
                in_hand_probability,
            } => {
                if rng.unit() < in_hand_probability {
                    Ok(Handover {
                        observation: env.reset_with_start(seed, Task::StackInHand)?,
                        kind: StartKind::InHand,
                    })
                } else {
                    Ok(Handover {
                        observation: env.reset(seed)?,
                        kind: StartKind::Original,
                    })
                }
            }
            StartScheme::AlongDemonstrations {
                demonstrations: 0, ..
            } => self.along_demonstration(env, seed, &mut rng),
            StartScheme::AlongDemonstrations { demonstrations, .. } => {
                self.along_pooled_demonstration(env, demonstrations, &mut rng)
            }
        }
    }

    /// A state along one of the pool's `size` trajectories: the seed picks the trajectory (the
    /// next one on, cyclically, where a demonstration failed) and the state uniformly along it.
    fn along_pooled_demonstration(
        &mut self,
        env: &mut JacoEnv,
        size: u32,
        rng: &mut SeedRng,
    ) -> Result<Handover, EnvError> {
        // unit() < 1, so the index is below `size`.
        let first = (rng.unit() * f64::from(size)) as u32;
        let along = rng.unit();
        for tried in 0..size {
            let i = (first + tried) % size;
            if !self.pool.contains_key(&i) {
                let t = self.demonstrate(env, POOL_SEED_BASE + u64::from(i))?;
                self.pool.insert(i, t);
            }
            let Some(t) = self.pool.get(&i).filter(|t| !t.is_empty()) else {
                continue;
            };
            let n = t.len();
            let k = ((along * n as f64) as usize).min(n - 1);
            env.restore(&t[k])?;
            return Ok(Handover {
                observation: env.begin_episode(),
                kind: StartKind::Demonstration {
                    k: k as u32 + 1,
                    n: n as u32,
                    solved: true,
                },
            });
        }
        Err(EnvError::StartScheme(format!(
            "none of the {size} pooled demonstrations solved the task"
        )))
    }

    /// Every state of the demonstration from the original start of `seed`, up to and with its
    /// first success; empty when it does not solve the task within the episode's budget.
    fn demonstrate(&mut self, env: &mut JacoEnv, seed: u64) -> Result<Trajectory, EnvError> {
        env.reset(seed)?;
        self.demo.restart();
        let budget = env.config().episode_steps.max(1);
        let task = env.config().task;
        let mut states = Vec::new();
        for _ in 0..budget {
            let action = self.demo.act(env)?;
            let out = env.step(&action)?;
            states.push(env.snapshot());
            if task.is_success(out.predicates) {
                return Ok(states);
            }
        }
        Ok(Vec::new())
    }

    fn along_demonstration(
        &mut self,
        env: &mut JacoEnv,
        seed: u64,
        rng: &mut SeedRng,
    ) -> Result<Handover, EnvError> {
        env.reset(seed)?;
        self.demo.restart();
        let budget = env.config().episode_steps.max(1);
        let task = env.config().task;
        let mut kept = None;
        let mut n = 0u32;
        let mut solved = false;
        while n < budget {
            let action = self.demo.act(env)?;
            let out = env.step(&action)?;
            n += 1;
            // Reservoir of one: after n steps, each of states 1..=n is kept with probability 1/n.
            if rng.unit() * f64::from(n) < 1.0 {
                kept = Some((env.snapshot(), n));
            }
            if task.is_success(out.predicates) {
                solved = true;
                break;
            }
        }
        let Some((snapshot, k)) = kept else {
            // Unreachable: the first step is always kept (unit() < 1).
            return Err(EnvError::StartScheme(
                "the demonstration took no step".into(),
            ));
        };
        env.restore(&snapshot)?;
        Ok(Handover {
            observation: env.begin_episode(),
            kind: StartKind::Demonstration { k, n, solved },
        })
    }
}
