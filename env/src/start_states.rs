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
//! Every handed-over state is a state the simulation reached by stepping: nothing is teleported, so
//! contacts and velocities are consistent (`tests/env_start_states.rs` checks that a held brick stays
//! held after the hand-over).

use dex_runtime::interface::ACT_DIM;

use super::demo::Demonstrator;
use super::environment::JacoEnv;
use super::error::EnvError;
use super::observation::Observation;
use super::rng::SeedRng;
use super::tasks::Task;

/// Training episode length of [`StartScheme::AlongDemonstrations`] in the paper (evaluation keeps 150).
pub const DEMO_TRAIN_EPISODE_STEPS: u32 = 50;

/// Salt mixed into an episode seed for the scheme's own random choices, so that the original start
/// drawn from a seed is the same under every scheme.
const SCHEME_SALT: u64 = 0x5EED_57A7_E5C4_E3E5;

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
    },
}

impl StartScheme {
    /// The paper's demonstration scheme: 50-step training episodes.
    pub const fn along_demonstrations() -> Self {
        StartScheme::AlongDemonstrations {
            train_episode_steps: DEMO_TRAIN_EPISODE_STEPS,
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
            } => Err(EnvError::StartScheme(
                "training episodes along demonstrations need at least one step".into(),
            )),
            StartScheme::AlongDemonstrations { .. } => Ok(()),
        }
    }

    /// Length of a training episode under this scheme, given the task's episode length.
    pub fn train_episode_steps(&self, task_steps: u32) -> u32 {
        match *self {
            StartScheme::AlongDemonstrations {
                train_episode_steps,
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

/// Makes training starts for one environment under one scheme.
#[derive(Clone)]
pub struct StartStates<D: Demonstration = Demonstrator> {
    scheme: StartScheme,
    demo: D,
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
        }
    }

    /// Starts under `scheme`, with `demo` for demonstrations.
    pub fn new(scheme: StartScheme, demo: D) -> Result<Self, EnvError> {
        scheme.validate()?;
        Ok(Self { scheme, demo })
    }

    /// The scheme.
    pub fn scheme(&self) -> StartScheme {
        self.scheme
    }

    /// Resets `env` to a training start drawn from `seed` alone. The environment's step counter is
    /// zero afterwards, whatever the hand-over.
    pub fn reset(&mut self, env: &mut JacoEnv, seed: u64) -> Result<Handover, EnvError> {
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
            StartScheme::AlongDemonstrations { .. } => {
                self.along_demonstration(env, seed, &mut rng)
            }
        }
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
