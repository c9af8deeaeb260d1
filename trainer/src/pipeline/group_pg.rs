//! Group-relative policy gradient (issue #26): on-policy fine-tuning of a policy file from the
//! task's success alone, with no critic.
//!
//! Every iteration draws `groups` training starts and runs `replicates` episodes from each, the
//! file's actions plus Gaussian noise (the DART noise of the clones' recordings by default), through
//! the runtime with CAN quantisation as `trainer eval` runs it. An episode's advantage is its
//! success (0 or 1) minus its group's success rate: a group whose episodes all succeed, or all
//! fail, carries no signal and is skipped. The actor (the file's network in the coordinates it was
//! trained in) then takes `epochs` passes of Adam over the kept steps with PPO's clipped
//! surrogate (Schulman et al. 2017) for the fixed-variance Gaussian around its action:
//! `log pi(a | s) = -sum_j (a_j - mu_j(s))^2 / (2 sigma_j^2)`, the ratio to the iteration's
//! actor clipped to `[1 - clip, 1 + clip]`; an optional anchor adds `anchor / 2 * sum_j (mu_j(s) -
//! clone_j(s))^2 / sigma_j^2`, the KL divergence to the starting file's Gaussian.
//!
//! Why this form: sessions 24-29 measured that this task's critics order nearby actions at
//! 53-63% against a rollout ceiling near 90%, and that the DDPG stage's critic gradient unlearns a
//! 97-99% clone the longer it runs (docs/experiments.md). The group baseline (the mean outcome
//! of episodes from the same start: GRPO's, Shao et al. 2024; RLOO's, Ahmadian et al. 2024)
//! replaces the critic; what the update follows is the gradient of the success rate under the
//! noise, the quantity session 26 found the failures to depend on (they are fragile: small
//! perturbations rescue most of them).
//!
//! Fresh starts come from their own seed block (`DEMO_SEED + 1000 * seed + 7`, beside the rollout
//! teacher's `+ 6`), start `i * groups + g` for group `g` of iteration `i`; with `revisit`, a share
//! of the groups instead revisit starts where a recent group failed (kept in the checkpoint).
//! Episode `k` of a group in iteration `i` draws its noise from its own stream. An iteration's
//! result therefore does not depend on the thread count, and a run resumed from its checkpoint
//! repeats the run that was not stopped.
//!
//! With `stall_groups` (session 31), each iteration also runs that many groups from stalled
//! states ([`super::stall_starts`]): simulator snapshots where an episode of the policy got stuck
//! before its grasp and then failed, harvested from the starting file's noise-free episodes
//! (`stall_harvest` of them, from their own seed block `+ 8`) and from the first noisy episode of
//! each start-seed group that stalled and failed, one per seed and step, the newest
//! [`STALL_POOL`] kept in the checkpoint. Episodes from a stall run from its
//! step to the task's last.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use dex_runtime::Mlp as RuntimeMlp;
use dex_runtime::can::messages::quantise_observation;
use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_runtime::kinematics::ARM_JOINTS;
use serde::{Deserialize, Serialize};

use crate::env::seeds::{DEMO_SEED, episode_seed};
use crate::env::{EnvConfig, JacoEnv, Scene, Task};
use crate::evaluate::{EVAL_WIDTH, EvalError, controller_command, physical_to_env_action};
use crate::files::atomic_write::write_atomic;
use crate::files::export::ExportInfo;
use crate::learn::adam::{AdamConfig, AdamLocal, AdamShared, adam_step};
use crate::learn::nets::MlpScratch;
use crate::learn::{LearnError, Rng};
use crate::pipeline::file_actor::{FileActor, FileActorError};
use crate::pipeline::stall_starts::{StallStart, StallWatch, harvest};

/// The checkpoint of a run folder (parameters, Adam's moments, the next iteration).
pub const CHECKPOINT: &str = "group-pg.ckpt";
/// One JSON line per iteration, in the run folder.
pub const PROGRESS: &str = "group-pg.jsonl";
/// The latest iteration's actor, in the run folder.
pub const LATEST: &str = "policy-latest.dxpl";

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

    /// Noise standard deviation of action component `j`.
    fn sigma(&self, j: usize) -> f32 {
        if j < ARM_JOINTS {
            self.arm_noise
        } else {
            self.finger_noise
        }
    }

    /// Fresh start seed of group `g` of iteration `i`.
    pub fn start_seed(&self, iteration: u32, group: u32) -> u64 {
        episode_seed(
            DEMO_SEED + self.seed * 1_000 + 7,
            u64::from(iteration) * u64::from(self.groups) + u64::from(group),
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
        let mut left: Vec<usize> = (0..pool).collect();
        let mut rng = Rng::derive(self.seed, 0x6770_5000 + u64::from(iteration));
        (0..(self.stall_groups as usize).min(pool))
            .map(|_| left.swap_remove(rng.below(left.len())))
            .collect()
    }

    /// How many of an iteration's groups revisit a start, with `hard` starts to choose from.
    pub fn revisits(&self, hard: usize) -> usize {
        ((self.revisit * self.groups as f32).round() as usize).min(hard)
    }

    /// The start seeds of iteration `i`: the first `revisit * groups` (at most as many as
    /// `hard` holds) drawn from `hard` without repeats, the rest fresh.
    pub fn starts(&self, iteration: u32, hard: &[u64]) -> Vec<u64> {
        let k = self.revisits(hard.len());
        let mut pool = hard.to_vec();
        let mut rng = Rng::derive(self.seed, 0x6770_4000 + u64::from(iteration));
        let mut out = Vec::with_capacity(self.groups as usize);
        for _ in 0..k {
            out.push(pool.swap_remove(rng.below(pool.len())));
        }
        for g in k as u32..self.groups {
            out.push(self.start_seed(iteration, g));
        }
        out
    }
}

/// What one iteration did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IterationReport {
    /// Iteration index (from 0).
    pub iteration: u32,
    /// Episodes run.
    pub episodes: u32,
    /// Of them successful (with the noise).
    pub successes: u32,
    /// Groups with both outcomes (the only ones with a gradient).
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
}

impl IterationReport {
    /// One line for a terminal (`trainer pg --quiet`, `trainer train`'s `[pg]` stage): the
    /// iteration, its successes with the noise, the groups with a gradient, the clipped share,
    /// the drift, the environment steps and, when it ran stall groups or holds stalls, their
    /// episodes' successes (each group `replicates` episodes) and the pool.
    pub fn line(&self, replicates: u32) -> String {
        let mut line = format!(
            "iteration {} success {}/{} with noise, {} groups with both outcomes, clipped {:.3}, \
             drift {:.3}, {} env steps",
            self.iteration + 1,
            self.successes,
            self.episodes,
            self.mixed_groups,
            self.clipped,
            self.drift,
            self.env_steps
        );
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

#[derive(Serialize, Deserialize)]
struct Checkpoint {
    settings: GroupPg,
    next_iteration: u32,
    env_steps: u64,
    params: Vec<f32>,
    m: Vec<f32>,
    v: Vec<f32>,
    t_local: u64,
    t_shared: u64,
    hard: Vec<u64>,
    stalls: Vec<StallStart>,
}

/// Most steps [`GroupPg::stall_back`] may reach back (each watched episode keeps that many
/// snapshots).
pub const MAX_STALL_BACK: u32 = 100;

/// Stalled states kept for the stall groups (the newest).
pub const STALL_POOL: usize = 256;

/// One noisy episode: the observations the controller saw (CAN-quantised), the noise added to
/// each action, the outcome, and (from a start seed) the state where it stalled before failing.
struct Episode {
    obs: Vec<[f32; OBS_DIM]>,
    noise: Vec<[f32; ACT_DIM]>,
    success: bool,
    stall: Option<StallStart>,
}

/// Where a group's episodes begin.
enum Start<'a> {
    /// A start seed and the noise stream tag of its episodes.
    Seed(u64, u64),
    /// A stalled state and the noise stream tag of its episodes.
    Stall(&'a StallStart, u64),
}

/// Runs (or resumes) a fine-tune in `dir`: the checkpoint, one progress line and the latest
/// actor after every iteration, `policy-NNNN.dxpl` every `save_every` iterations (0: none);
/// calls `on_iteration` with each iteration's report. Returns the last actor's file.
pub fn run(
    settings: &GroupPg,
    scene: &Scene,
    task: Task,
    dir: &Path,
    threads: usize,
    save_every: u32,
    on_iteration: &mut dyn FnMut(&IterationReport),
) -> Result<Vec<u8>, GroupPgError> {
    let never = AtomicBool::new(false);
    run_until(
        settings,
        scene,
        task,
        dir,
        threads,
        save_every,
        &never,
        on_iteration,
    )
}

/// [`run`] that also stops before an iteration once `stop` is raised (the checkpoint then holds
/// every finished iteration, and the file returned is the latest actor's: the caller checks
/// `stop` to tell a stopped run from a finished one).
#[allow(clippy::too_many_arguments)]
pub fn run_until(
    settings: &GroupPg,
    scene: &Scene,
    task: Task,
    dir: &Path,
    threads: usize,
    save_every: u32,
    stop: &AtomicBool,
    on_iteration: &mut dyn FnMut(&IterationReport),
) -> Result<Vec<u8>, GroupPgError> {
    settings.validate()?;
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| GroupPgError::Io { path, source }
    };
    let file = std::fs::read(&settings.policy).map_err(io(&settings.policy))?;
    let mut actor = FileActor::from_file(&file, task)?;
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let n = actor.params.len();
    let mut local = AdamLocal::new(n);
    let mut shared = AdamShared::new(n);
    let (mut first, mut env_steps) = (0u32, 0u64);
    let mut hard: Vec<u64> = Vec::new();
    let mut stalls: Vec<StallStart> = Vec::new();
    let ckpt_path = dir.join(CHECKPOINT);
    if ckpt_path.exists() {
        let bytes = std::fs::read(&ckpt_path).map_err(io(&ckpt_path))?;
        let bad = |why: String| GroupPgError::Checkpoint {
            path: ckpt_path.clone(),
            why,
        };
        let c: Checkpoint = postcard::from_bytes(&bytes).map_err(|e| bad(e.to_string()))?;
        // The budget may grow on resumption (as `trainer train --resume --transitions`); any
        // other change would make the run a mixture of two.
        let same = GroupPg {
            iterations: settings.iterations,
            ..c.settings.clone()
        };
        if same != *settings {
            return Err(bad(
                "it was written with other settings (only iterations may change); use another \
                 folder"
                    .to_owned(),
            ));
        }
        if c.params.len() != n || c.m.len() != n || c.v.len() != n {
            return Err(bad("its actor is not the starting file's shape".to_owned()));
        }
        actor.params = c.params;
        local.m = c.m;
        local.t = c.t_local;
        shared.v = c.v;
        shared.t = c.t_shared;
        first = c.next_iteration;
        env_steps = c.env_steps;
        hard = c.hard;
        stalls = c.stalls;
    }
    let info = |env_steps: u64| ExportInfo {
        task,
        seed: settings.seed,
        transitions: env_steps,
        success_rate: None,
        eval_episodes: 0,
    };
    let adam = AdamConfig {
        lr: settings.lr,
        ..AdamConfig::default()
    };
    let mb = settings.minibatch as usize;
    let mut scratch = actor.net.scratch(mb);
    // The actor the rollouts run: after each update it is also the iteration's saved file.
    let mut policy = actor.export(&info(env_steps))?;
    if first == 0 && settings.stall_harvest > 0 && !stop.load(Ordering::SeqCst) {
        let seeds: Vec<u64> = (0..settings.stall_harvest)
            .map(|i| settings.harvest_seed(i))
            .collect();
        let back = settings.stall_back as usize;
        let (found, steps) = harvest(&file, scene, task, &seeds, back, threads)?;
        env_steps += steps;
        remember_stalls(&mut stalls, found);
    }
    let reps = settings.replicates as usize;
    for iteration in first..settings.iterations {
        if stop.load(Ordering::SeqCst) {
            break;
        }
        let seeds = settings.starts(iteration, &hard);
        let revisited = settings.revisits(hard.len());
        let picks = settings.stall_picks(iteration, stalls.len());
        let mut starts: Vec<Start<'_>> = seeds
            .iter()
            .enumerate()
            .map(|(g, &seed)| {
                // A fresh start is used once; a revisited one draws new noise, from a stream
                // that names the iteration too.
                let tag = if g < revisited {
                    (0x6770 << 48) + (u64::from(iteration) << 16)
                } else {
                    0x6770_0000
                };
                Start::Seed(seed, tag)
            })
            .collect();
        starts.extend(picks.iter().map(|&p| {
            let s = &stalls[p];
            let tag = (0x6771 << 48)
                + (u64::from(s.snapshot.steps()) << 32)
                + (u64::from(iteration) << 16);
            Start::Stall(s, tag)
        }));
        let mut episodes = rollouts(settings, scene, task, &policy, &starts, threads)?;
        remember_hard(&mut hard, &seeds, &episodes, reps);
        let from_stalls = &episodes[seeds.len() * reps..];
        let stall_successes = from_stalls.iter().filter(|e| e.success).count() as u32;
        let found: Vec<StallStart> = episodes[..seeds.len() * reps]
            .chunks_mut(reps)
            .filter_map(|group| group.iter_mut().find_map(|e| e.stall.take()))
            .collect();
        remember_stalls(&mut stalls, found);
        env_steps += episodes.iter().map(|e| e.obs.len() as u64).sum::<u64>();
        let mut report = update(
            settings,
            &mut actor,
            &episodes,
            seeds.len(),
            iteration,
            &adam,
            &mut local,
            &mut shared,
            &mut scratch,
        )?;
        report.env_steps = env_steps;
        report.stall_groups = picks.len() as u32;
        report.stall_successes = stall_successes;
        report.stall_pool = stalls.len() as u32;
        policy = actor.export(&info(env_steps))?;
        let save = |name: String, bytes: &[u8]| {
            let p = dir.join(name);
            write_atomic(&p, bytes).map_err(io(&p))
        };
        save(LATEST.to_owned(), &policy)?;
        if save_every > 0 && (iteration + 1) % save_every == 0 {
            save(format!("policy-{:04}.dxpl", iteration + 1), &policy)?;
        }
        let ckpt = Checkpoint {
            settings: settings.clone(),
            next_iteration: iteration + 1,
            env_steps,
            params: actor.params.clone(),
            m: local.m.clone(),
            v: shared.v.clone(),
            t_local: local.t,
            t_shared: shared.t,
            hard: hard.clone(),
            stalls: stalls.clone(),
        };
        let bytes = postcard::to_allocvec(&ckpt).map_err(|e| GroupPgError::Checkpoint {
            path: ckpt_path.clone(),
            why: e.to_string(),
        })?;
        save(CHECKPOINT.to_owned(), &bytes)?;
        let line = serde_json::to_string(&report).unwrap_or_default();
        let progress = dir.join(PROGRESS);
        append_line(&progress, &line).map_err(io(&progress))?;
        on_iteration(&report);
    }
    Ok(policy)
}

fn append_line(path: &Path, line: &str) -> std::io::Result<()> {
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)?;
    writeln!(f, "{line}")
}

/// Starts kept for revisits.
const HARD_STARTS: usize = 256;

/// Updates the hard starts after an iteration: a start whose group failed at least once is kept
/// (the most recent [`HARD_STARTS`]), one whose group succeeded every time is dropped.
fn remember_hard(hard: &mut Vec<u64>, starts: &[u64], episodes: &[Episode], reps: usize) {
    for (seed, group) in starts.iter().zip(episodes.chunks(reps)) {
        hard.retain(|h| h != seed);
        if group.iter().any(|e| !e.success) {
            hard.push(*seed);
        }
    }
    if hard.len() > HARD_STARTS {
        let extra = hard.len() - HARD_STARTS;
        hard.drain(..extra);
    }
}

/// Adds newly found stalls to the pool, keeping the newest [`STALL_POOL`].
///
/// A stall of a start seed at a step the pool already holds is not added: with revisits a start
/// can stall again at the same step, and the stall groups' noise streams are named by the seed,
/// the step and the iteration, so two such entries picked in one iteration would draw the same
/// noise.
fn remember_stalls(pool: &mut Vec<StallStart>, found: Vec<StallStart>) {
    for f in found {
        let same = |p: &StallStart| p.seed == f.seed && p.snapshot.steps() == f.snapshot.steps();
        if !pool.iter().any(same) {
            pool.push(f);
        }
    }
    if pool.len() > STALL_POOL {
        let extra = pool.len() - STALL_POOL;
        pool.drain(..extra);
    }
}

/// The noisy episodes of `policy`, `replicates` from each start, in (start, replicate) order;
/// episode `k` of a start draws its noise from the stream `tag + k` of the start's seed.
fn rollouts(
    s: &GroupPg,
    scene: &Scene,
    task: Task,
    policy: &[u8],
    starts: &[Start<'_>],
    threads: usize,
) -> Result<Vec<Episode>, GroupPgError> {
    let aligned = dex_runtime::aligned::aligned_copy(policy);
    let reps = s.replicates as usize;
    crate::env::parallel::map_in_order(
        starts.len() * reps,
        threads,
        || -> Result<_, GroupPgError> {
            let view = crate::evaluate::decode_jaco_policy(aligned.as_bytes())?;
            let mlp = RuntimeMlp::<EVAL_WIDTH>::new(&view).map_err(EvalError::from)?;
            Ok((mlp, JacoEnv::new(scene, EnvConfig::new(task))))
        },
        |(mlp, env), i| {
            let k = (i % reps) as u64;
            match &starts[i / reps] {
                Start::Seed(seed, tag) => {
                    let o = env.reset(*seed).map_err(EvalError::from)?;
                    let mut rng = Rng::derive(*seed, tag + k);
                    episode(s, env, mlp, o, Some(*seed), &mut rng)
                }
                Start::Stall(stall, tag) => {
                    let o = env.restore(&stall.snapshot).map_err(EvalError::from)?;
                    let mut rng = Rng::derive(stall.seed, tag + k);
                    episode(s, env, mlp, o, None, &mut rng)
                }
            }
        },
        &|| {},
    )
}

/// One noisy episode from the environment's current state `o` to the task's last step. With
/// `seed` (an episode from a start seed) it also watches for the stall.
fn episode(
    s: &GroupPg,
    env: &mut JacoEnv,
    mlp: &mut RuntimeMlp<'_, EVAL_WIDTH>,
    mut o: [f32; OBS_DIM],
    seed: Option<u64>,
    rng: &mut Rng,
) -> Result<Episode, GroupPgError> {
    let (mut obs, mut noise) = (Vec::with_capacity(160), Vec::with_capacity(160));
    // Only the start-seed episodes feed the pool.
    let watching = seed.is_some() && s.stall_groups > 0;
    let mut watch = StallWatch::new(s.stall_back as usize);
    loop {
        let mut a = physical_to_env_action(&controller_command(mlp, &o, true, None)?);
        let e: [f32; ACT_DIM] = std::array::from_fn(|j| rng.normal(0.0, s.sigma(j)));
        for (x, n) in a.iter_mut().zip(&e) {
            *x = (*x + n).clamp(-1.0, 1.0);
        }
        obs.push(std::array::from_fn(|i| quantise_observation(i, o[i])));
        noise.push(e);
        if watching {
            watch.before_step(env);
        }
        let out = env.step(&a).map_err(EvalError::from)?;
        if watching {
            watch.after_step(env, &out);
        }
        o = out.observation;
        if out.done {
            let stall = seed
                .zip(watch.into_found())
                .filter(|_| !out.success)
                .map(|(seed, snapshot)| StallStart { seed, snapshot });
            return Ok(Episode {
                obs,
                noise,
                success: out.success,
                stall,
            });
        }
    }
}

/// The group advantages, then `epochs` passes of the clipped surrogate (and the anchors) over the
/// kept steps: those of groups with both outcomes and, with `fresh_anchor`, every step of the
/// first `seed_groups` groups (the start-seed ones).
#[allow(clippy::too_many_arguments)]
fn update(
    s: &GroupPg,
    actor: &mut FileActor,
    episodes: &[Episode],
    seed_groups: usize,
    iteration: u32,
    adam: &AdamConfig,
    local: &mut AdamLocal,
    shared: &mut AdamShared,
    scratch: &mut MlpScratch,
) -> Result<IterationReport, GroupPgError> {
    let reps = s.replicates as usize;
    let d = actor.net.input_dim();
    let (mut inputs, mut noise, mut adv) = (Vec::new(), Vec::new(), Vec::new());
    // Each kept step's anchor weight.
    let mut weight = Vec::new();
    let mut mixed = 0u32;
    let mut row = vec![0.0f32; d];
    for (index, group) in episodes.chunks(reps).enumerate() {
        let wins = group.iter().filter(|e| e.success).count();
        let both = wins > 0 && wins < group.len();
        let fresh = if index < seed_groups {
            s.fresh_anchor
        } else {
            0.0
        };
        if !both && fresh == 0.0 {
            continue;
        }
        mixed += u32::from(both);
        let mean = wins as f32 / group.len() as f32;
        for e in group {
            // A group without both outcomes is kept for its anchor only: no advantage.
            let a = if both {
                f32::from(u8::from(e.success)) - mean
            } else {
                0.0
            };
            let w = if both { s.anchor + fresh } else { fresh };
            for (o, n) in e.obs.iter().zip(&e.noise) {
                actor.input(o, &mut row);
                inputs.extend_from_slice(&row);
                noise.extend_from_slice(n);
                adv.push(a);
                weight.push(w);
            }
        }
    }
    let samples = adv.len();
    let successes = episodes.iter().filter(|e| e.success).count() as u32;
    let mut report = IterationReport {
        iteration,
        episodes: episodes.len() as u32,
        successes,
        mixed_groups: mixed,
        samples: samples as u64,
        clipped: 0.0,
        drift: 0.0,
        env_steps: 0,
        stall_groups: 0,
        stall_successes: 0,
        stall_pool: 0,
    };
    if samples == 0 {
        return Ok(report);
    }
    let inv_var: [f32; ACT_DIM] = std::array::from_fn(|j| 1.0 / (s.sigma(j) * s.sigma(j)));
    let old = actor.outputs(&actor.params, &inputs, scratch)?;
    let clone = actor.outputs(&actor.clone, &inputs, scratch)?;
    let mut order: Vec<usize> = (0..samples).collect();
    let mut rng = Rng::derive(s.seed, 0x6770_8000 + u64::from(iteration));
    let mb = s.minibatch as usize;
    let (mut batch_in, mut dout) = (vec![0.0f32; mb * d], vec![0.0f32; mb * ACT_DIM]);
    let mut mu = vec![0.0f32; mb * ACT_DIM];
    let mut grads = vec![0.0f32; actor.params.len()];
    let (mut clipped, mut seen) = (0u64, 0u64);
    for _ in 0..s.epochs {
        for i in (1..samples).rev() {
            order.swap(i, rng.below(i + 1));
        }
        for chunk in order.chunks(mb) {
            let rows = chunk.len();
            for (r, &i) in chunk.iter().enumerate() {
                batch_in[r * d..(r + 1) * d].copy_from_slice(&inputs[i * d..(i + 1) * d]);
            }
            mu[..rows * ACT_DIM].copy_from_slice(actor.net.forward(
                &actor.params,
                &batch_in[..rows * d],
                rows,
                scratch,
            )?);
            let scale = 1.0 / rows as f32;
            for (r, &i) in chunk.iter().enumerate() {
                let (mo, ep, mc) = (
                    &old[i * ACT_DIM..(i + 1) * ACT_DIM],
                    &noise[i * ACT_DIM..(i + 1) * ACT_DIM],
                    &clone[i * ACT_DIM..(i + 1) * ACT_DIM],
                );
                let mn = &mu[r * ACT_DIM..(r + 1) * ACT_DIM];
                // a = mo + ep; log ratio = sum_j ((a - mo)^2 - (a - mn)^2) / (2 sigma^2).
                let mut log_ratio = 0.0f32;
                for j in 0..ACT_DIM {
                    let diff = mo[j] + ep[j] - mn[j];
                    log_ratio += (ep[j] * ep[j] - diff * diff) * 0.5 * inv_var[j];
                }
                let ratio = log_ratio.clamp(-20.0, 20.0).exp();
                let a = adv[i];
                let cut = (a > 0.0 && ratio > 1.0 + s.clip) || (a < 0.0 && ratio < 1.0 - s.clip);
                seen += 1;
                clipped += u64::from(cut);
                let g = &mut dout[r * ACT_DIM..(r + 1) * ACT_DIM];
                for j in 0..ACT_DIM {
                    let pg = if cut {
                        0.0
                    } else {
                        -a * ratio * (mo[j] + ep[j] - mn[j]) * inv_var[j]
                    };
                    g[j] = (pg + weight[i] * (mn[j] - mc[j]) * inv_var[j]) * scale;
                }
            }
            actor.net.backward(
                &actor.params,
                &batch_in[..rows * d],
                scratch,
                &dout[..rows * ACT_DIM],
                Some(&mut grads),
                None,
            )?;
            adam_step(adam, &mut actor.params, &grads, local, shared);
        }
    }
    let now = actor.outputs(&actor.params, &inputs, scratch)?;
    let mut sq = 0.0f64;
    for (i, (x, c)) in now.iter().zip(&clone).enumerate() {
        let z = f64::from((x - c) / s.sigma(i % ACT_DIM));
        sq += z * z;
    }
    report.clipped = clipped as f64 / seen.max(1) as f64;
    report.drift = (sq / now.len().max(1) as f64).sqrt();
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_report_line_counts_the_stall_episodes_by_the_replicates() {
        let mut r = IterationReport {
            iteration: 0,
            episodes: 160,
            successes: 82,
            mixed_groups: 8,
            samples: 0,
            clipped: 0.1,
            drift: 0.06,
            env_steps: 466_968,
            stall_groups: 0,
            stall_successes: 0,
            stall_pool: 0,
        };
        let plain = r.line(8);
        assert!(
            plain.starts_with("iteration 1 success 82/160 with noise"),
            "{plain}"
        );
        assert!(!plain.contains("from stalls"), "{plain}");
        (r.stall_groups, r.stall_successes, r.stall_pool) = (16, 50, 16);
        assert!(
            r.line(8)
                .ends_with("; from stalls 50/128 (16 groups, pool 16)"),
            "{}",
            r.line(8)
        );
    }

    fn settings(revisit: f32) -> GroupPg {
        GroupPg {
            groups: 8,
            revisit,
            ..GroupPg::new(PathBuf::from("p.dxpl"))
        }
    }

    #[test]
    fn revisits_take_their_share_from_the_hard_starts_without_repeats() {
        let fresh = settings(0.0).starts(3, &[1, 2, 3]);
        let expected: Vec<u64> = (0..8).map(|g| settings(0.0).start_seed(3, g)).collect();
        assert_eq!(fresh, expected, "without revisits every start is fresh");
        let s = settings(0.5);
        let mixed = s.starts(3, &[11, 12, 13, 14, 15, 16]);
        assert_eq!(mixed.len(), 8);
        let (old, new) = mixed.split_at(4);
        assert!(old.iter().all(|x| (11..=16).contains(x)));
        let mut sorted = old.to_vec();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(
            sorted.len(),
            4,
            "a hard start is revisited once per iteration"
        );
        assert_eq!(new, &expected[4..]);
        // Fewer hard starts than the share: all of them, the rest fresh.
        let few = s.starts(3, &[11]);
        assert_eq!(few[0], 11);
        assert_eq!(&few[1..], &expected[1..]);
        assert_eq!(s.starts(3, &[11, 12, 13]), s.starts(3, &[11, 12, 13]));
    }

    fn ep(success: bool) -> Episode {
        Episode {
            obs: Vec::new(),
            noise: Vec::new(),
            success,
            stall: None,
        }
    }

    #[test]
    fn the_stall_pool_keeps_one_entry_per_seed_and_step_and_the_newest() {
        let snap = |steps: u32| {
            let json = format!("{{\"state\":[0.0],\"steps\":{steps}}}");
            serde_json::from_str::<crate::env::EnvSnapshot>(&json).unwrap()
        };
        let entry = |seed: u64, steps: u32| StallStart {
            seed,
            snapshot: snap(steps),
        };
        let mut pool = vec![entry(1, 60)];
        remember_stalls(&mut pool, vec![entry(1, 60), entry(1, 70), entry(2, 60)]);
        assert_eq!(pool, vec![entry(1, 60), entry(1, 70), entry(2, 60)]);
        let many: Vec<StallStart> = (0..STALL_POOL as u64 + 5)
            .map(|s| entry(s + 10, 60))
            .collect();
        remember_stalls(&mut pool, many);
        assert_eq!(pool.len(), STALL_POOL);
        assert_eq!(pool.last(), Some(&entry(STALL_POOL as u64 + 14, 60)));
    }

    #[test]
    fn a_start_stays_hard_while_its_group_fails() {
        let mut hard = vec![5, 7];
        let episodes = [ep(false), ep(true), ep(true), ep(true), ep(true), ep(true)];
        remember_hard(&mut hard, &[9, 7, 5], &episodes, 2);
        // 9 failed once (kept, newest), 7 and 5 succeeded every time (dropped).
        assert_eq!(hard, vec![9]);
        let mut many: Vec<u64> = (0..HARD_STARTS as u64).collect();
        remember_hard(&mut many, &[1000], &[ep(false), ep(false)], 2);
        assert_eq!(many.len(), HARD_STARTS);
        assert_eq!(many.last(), Some(&1000));
        assert_eq!(many[0], 1, "the oldest start is dropped");
    }
}
