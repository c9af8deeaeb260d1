//! One environment as Gymnasium sees it: a [`JacoEnv`] with its start scheme, its episode length
//! and the episode bookkeeping (`step` before `reset` or after the time limit is refused). No
//! Python here: the single and the vector environment both drive [`Episode`]s.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicU64, Ordering};

use dex_env::{
    Demonstrator, EnvConfig, JacoEnv, Observation, Predicates, Reward, Scene, StartKind,
    StartScheme, StartStates, Task,
};
use dex_runtime::interface::ACT_DIM;

use crate::error::{Error, Result};

/// The scene, compiled once per process and shared by every environment.
pub fn scene() -> Result<&'static Scene> {
    static SCENE: OnceLock<Scene> = OnceLock::new();
    if let Some(s) = SCENE.get() {
        return Ok(s);
    }
    let loaded = Scene::load()?;
    Ok(SCENE.get_or_init(|| loaded))
}

/// A task from its name (`reach`, `grasp`, `stack-in-hand`, `stack`).
pub fn parse_task(name: &str) -> Result<Task> {
    name.parse()
        .map_err(|_| Error::UnknownTask(name.to_owned()))
}

/// The kebab-case name of a task (the inverse of [`parse_task`]).
pub fn task_name(task: Task) -> String {
    serde_name(&task)
}

/// The kebab-case name of a reward function, as in `trainer train --reward`.
pub fn reward_name(reward: Reward) -> String {
    serde_name(&reward)
}

/// A reward function from its kebab-case name (`full-composite`, `sparse-stack`, ...).
pub fn parse_reward(name: &str) -> Result<Reward> {
    Reward::ALL
        .into_iter()
        .find(|&r| reward_name(r) == name)
        .ok_or_else(|| Error::UnknownReward {
            name: name.to_owned(),
            expected: Reward::ALL.map(reward_name).join(", "),
        })
}

fn serde_name<T: serde::Serialize + std::fmt::Debug>(v: &T) -> String {
    match serde_json::to_value(v) {
        Ok(serde_json::Value::String(s)) => s,
        _ => format!("{v:?}"),
    }
}

/// What a Python environment is made from: the `gymnasium.make` keyword arguments, parsed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// The task.
    pub task: Task,
    /// The reward function.
    pub reward: Reward,
    /// Where episodes start.
    pub scheme: StartScheme,
    /// Control steps of an episode (the time limit at which `truncated` is set).
    pub episode_steps: u32,
}

impl Options {
    /// Parses and checks the names and numbers. `episode_steps` defaults to the task's length
    /// (150, Reach 50), or to the training length under `along-demonstrations` (50).
    pub fn parse(
        task: &str,
        reward: Option<&str>,
        start: &str,
        episode_steps: Option<u32>,
        in_hand_probability: f64,
    ) -> Result<Self> {
        let task = parse_task(task)?;
        let reward = match reward {
            None => task.default_reward(),
            Some(r) => parse_reward(r)?,
        };
        let scheme = match start {
            "original" => StartScheme::Original,
            "mixture" => StartScheme::Mixture {
                in_hand_probability,
            },
            "along-demonstrations" => StartScheme::AlongDemonstrations {
                train_episode_steps: episode_steps
                    .unwrap_or(dex_env::start_states::DEMO_TRAIN_EPISODE_STEPS),
                demonstrations: 0,
            },
            other => return Err(Error::UnknownStart(other.to_owned())),
        };
        scheme
            .validate()
            .map_err(|e| Error::BadOption(e.to_string()))?;
        let episode_steps =
            episode_steps.unwrap_or(scheme.train_episode_steps(task.episode_steps()));
        if episode_steps == 0 {
            return Err(Error::BadOption(
                "episode_steps must be at least 1".to_owned(),
            ));
        }
        Ok(Options {
            task,
            reward,
            scheme,
            episode_steps,
        })
    }

    /// The Rust environment's configuration. Under `along-demonstrations` the demonstration that
    /// makes a start keeps the task's own step budget; otherwise the episode length is the limit.
    fn env_config(&self) -> EnvConfig {
        let steps = match self.scheme {
            StartScheme::AlongDemonstrations { .. } => self.task.episode_steps(),
            _ => self.episode_steps,
        };
        EnvConfig {
            task: self.task,
            reward: self.reward,
            episode_steps: steps,
        }
    }
}

/// The result of one step, as Gymnasium reports it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outcome {
    /// Observation after the step.
    pub observation: Observation,
    /// Reward of the state after the step.
    pub reward: f32,
    /// The time limit was reached (Gymnasium's `truncated`; `terminated` is always false).
    pub truncated: bool,
    /// The task's success predicate after the step.
    pub success: bool,
    /// The reach, grasp and stack predicates after the step.
    pub predicates: Predicates,
}

/// How an episode started: `original`, `in-hand`, `demonstration` (with the steps `k` of `n`) or
/// `revisit` (a fine-tune's revisited start).
pub fn start_kind_name(kind: StartKind) -> &'static str {
    match kind {
        StartKind::Original => "original",
        StartKind::InHand => "in-hand",
        StartKind::Demonstration { .. } => "demonstration",
        StartKind::Revisit { .. } => "revisit",
    }
}

static NEXT_ID: AtomicU64 = AtomicU64::new(1);

/// One environment with its episode state.
#[derive(Debug)]
pub struct Episode {
    env: JacoEnv,
    starts: StartStates<Demonstrator>,
    options: Options,
    running: bool,
    id: u64,
    episodes: u64,
    last_start: StartKind,
}

impl Episode {
    /// A new environment; [`Episode::reset`] must come before [`Episode::step`].
    pub fn new(options: Options) -> Result<Self> {
        let scene = scene()?;
        let starts = StartStates::scripted(options.scheme, options.task)?;
        Ok(Episode {
            env: JacoEnv::new(scene, options.env_config()),
            starts,
            options,
            running: false,
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            episodes: 0,
            last_start: StartKind::Original,
        })
    }

    /// The options it was made with.
    pub fn options(&self) -> &Options {
        &self.options
    }

    /// The Rust environment (read-only).
    pub fn env(&self) -> &JacoEnv {
        &self.env
    }

    /// A process-unique id of this environment and the number of resets so far: a demonstrator
    /// acting on it restarts its script when this pair changes.
    pub fn episode_key(&self) -> (u64, u64) {
        (self.id, self.episodes)
    }

    /// How the current episode started.
    pub fn start_kind(&self) -> StartKind {
        self.last_start
    }

    /// Starts an episode from `seed` under the start scheme (the original start: exactly
    /// `JacoEnv::reset(seed)`). On error the environment needs another reset.
    pub fn reset(&mut self, seed: u64) -> Result<Observation> {
        self.running = false;
        self.episodes += 1;
        let handover = self.starts.reset(&mut self.env, seed)?;
        self.last_start = handover.kind;
        self.running = true;
        Ok(handover.observation)
    }

    /// Checks an action without stepping: finite, 9 components.
    pub fn check_action(&self, action: &[f32; ACT_DIM]) -> Result<()> {
        if !self.running {
            return Err(Error::ResetNeeded(if self.episodes == 0 {
                "step() before reset(): call reset() first".to_owned()
            } else {
                "the episode has ended (truncated at the time limit, or a failed reset): call reset()"
                    .to_owned()
            }));
        }
        check_finite(action, None)
    }

    /// One control step. Bad input is refused before anything changes.
    pub fn step(&mut self, action: &[f32; ACT_DIM]) -> Result<Outcome> {
        self.check_action(action)?;
        let out = match self.env.step(action) {
            Ok(out) => out,
            Err(e) => {
                self.running = false;
                return Err(e.into());
            }
        };
        let truncated = self.env.steps_taken() >= self.options.episode_steps;
        if truncated {
            self.running = false;
        }
        Ok(Outcome {
            observation: out.observation,
            reward: out.reward,
            truncated,
            success: out.success,
            predicates: out.predicates,
        })
    }
}

/// `Ok` if every component is finite; `env` names the environment of a vector environment.
pub fn check_finite(action: &[f32], env: Option<usize>) -> Result<()> {
    match action.iter().enumerate().find(|(_, a)| !a.is_finite()) {
        None => Ok(()),
        Some((index, &value)) => Err(Error::NonFinite {
            index,
            value,
            env: env
                .map(|k| format!(" (environment {k})"))
                .unwrap_or_default(),
        }),
    }
}
