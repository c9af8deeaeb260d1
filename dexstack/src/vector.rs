//! N environments stepped on Rust threads (the caller releases the GIL around [`Batch::step`]).

use dex_runtime::interface::{ACT_DIM, OBS_DIM};

use crate::episode::{Episode, Options, Outcome, check_finite};
use crate::error::{Error, Result};

/// What one sub-environment does in a batch step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Step with its action.
    Step,
    /// Start a new episode from this seed (its action is ignored: Gymnasium's next-step autoreset).
    Reset(u64),
}

/// Observations, rewards and flags of a batch, environment-major.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BatchOutcome {
    /// `N * 44` observation values.
    pub observations: Vec<f32>,
    /// Rewards (0 for an environment that was reset).
    pub rewards: Vec<f32>,
    /// Time limit reached.
    pub truncated: Vec<bool>,
    /// Success predicate of the task.
    pub success: Vec<bool>,
    /// Reach predicate.
    pub reach: Vec<bool>,
    /// Grasp predicate.
    pub grasp: Vec<bool>,
    /// Stack predicate.
    pub stack: Vec<bool>,
}

/// A batch of environments of one configuration.
#[derive(Debug)]
pub struct Batch {
    envs: Vec<Episode>,
    threads: usize,
}

/// One environment's result in a batch step: an observation, or an outcome.
type Slot = Result<(Option<Outcome>, [f32; OBS_DIM])>;

impl Batch {
    /// `n` environments, stepped on at most `threads` threads (0: one per core, at most `n`).
    pub fn new(options: Options, n: usize, threads: usize) -> Result<Self> {
        if n == 0 {
            return Err(Error::BadOption("num_envs must be at least 1".to_owned()));
        }
        let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
        let threads = if threads == 0 { cores } else { threads }.clamp(1, n);
        let envs = (0..n)
            .map(|_| Episode::new(options))
            .collect::<Result<Vec<_>>>()?;
        Ok(Batch { envs, threads })
    }

    /// Number of environments.
    pub fn len(&self) -> usize {
        self.envs.len()
    }

    /// Whether the batch is empty (never: [`Batch::new`] refuses 0).
    pub fn is_empty(&self) -> bool {
        self.envs.is_empty()
    }

    /// Threads a step uses.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// The environments.
    pub fn envs(&self) -> &[Episode] {
        &self.envs
    }

    /// Runs `commands[k]` on environment `k` with `actions[k*9..]`. Every action of a stepped
    /// environment is checked (finite, episode running) before any environment moves.
    pub fn step(&mut self, actions: &[f32], commands: &[Command]) -> Result<BatchOutcome> {
        let n = self.envs.len();
        if actions.len() != n * ACT_DIM {
            return Err(Error::Shape {
                what: "actions",
                got: actions.len(),
                expected: n * ACT_DIM,
            });
        }
        if commands.len() != n {
            return Err(Error::Shape {
                what: "commands",
                got: commands.len(),
                expected: n,
            });
        }
        let mut batch = Vec::with_capacity(n);
        for (k, ((env, chunk), cmd)) in self
            .envs
            .iter()
            .zip(actions.chunks_exact(ACT_DIM))
            .zip(commands)
            .enumerate()
        {
            let mut a = [0.0f32; ACT_DIM];
            a.copy_from_slice(chunk);
            if *cmd == Command::Step {
                check_finite(&a, Some(k))?;
                env.check_action(&a)?;
            }
            batch.push((a, *cmd));
        }
        let per = n.div_ceil(self.threads);
        let results: Vec<Slot> = std::thread::scope(|s| {
            let handles: Vec<_> = self
                .envs
                .chunks_mut(per)
                .zip(batch.chunks(per))
                .map(|(envs, work)| {
                    s.spawn(move || {
                        envs.iter_mut()
                            .zip(work)
                            .map(|(env, (a, cmd))| run(env, a, *cmd))
                            .collect::<Vec<Slot>>()
                    })
                })
                .collect();
            handles
                .into_iter()
                .flat_map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
                .collect()
        });
        let mut out = BatchOutcome {
            observations: Vec::with_capacity(n * OBS_DIM),
            ..BatchOutcome::default()
        };
        for r in results {
            let (outcome, obs) = r?;
            out.observations.extend_from_slice(&obs);
            let o = outcome.unwrap_or(Outcome {
                observation: obs,
                reward: 0.0,
                truncated: false,
                success: false,
                predicates: Default::default(),
            });
            out.rewards.push(o.reward);
            out.truncated.push(o.truncated);
            out.success.push(o.success);
            out.reach.push(o.predicates.reach);
            out.grasp.push(o.predicates.grasp);
            out.stack.push(o.predicates.stack);
        }
        Ok(out)
    }
}

fn run(env: &mut Episode, action: &[f32; ACT_DIM], cmd: Command) -> Slot {
    match cmd {
        Command::Reset(seed) => {
            let obs = env.reset(seed)?;
            let p = env.env().predicates();
            let task = env.options().task;
            Ok((
                Some(Outcome {
                    observation: obs,
                    reward: 0.0,
                    truncated: false,
                    success: task.is_success(p),
                    predicates: p,
                }),
                obs,
            ))
        }
        Command::Step => {
            let out = env.step(action)?;
            Ok((Some(out), out.observation))
        }
    }
}
