//! A rollout teacher (issue #26): policy improvement from simulator resets, with no critic. A
//! policy file runs clean episodes from its own block of training starts; at every `stride`-th
//! state of each failed episode, candidate branches (the policy's actions plus Gaussian noise,
//! drawn for each step, for `hold` steps, then the policy to the episode's end) are rolled out from
//! a snapshot of that state, each `replicates` times (the later replicates add `jitter` to the
//! held actions: a branch must win robustly, not by one lucky contact). Where the best branch's
//! success rate beats the policy's own continuation by `margin`, its held states, labelled with
//! the actions the branch executed, join the cloning data (`repeat` times).
//!
//! This is one step of approximate policy iteration with Monte-Carlo action values (Lagoudakis
//! and Parr 2003, "classification-based" policy iteration; Bertsekas' rollout algorithm), and
//! DAgger with a teacher that is the policy's own rollouts: it credits the steps from which the
//! outcome could still be changed, which the success filter of self-imitation cannot, and it needs
//! no critic (the critics of this task order actions at 53-63% against a rollout ceiling of about
//! 90%; docs/experiments.md, sessions 24-26).
//!
//! The policy acts through the runtime with CAN quantisation, as `trainer eval` runs it. The
//! episodes start from `DEMO_SEED + 1000 * run seed + 6` (beside self-imitation's `+ 5`). The
//! result does not depend on the thread count: each episode draws from its own streams.

use std::path::{Path, PathBuf};

use dex_runtime::Mlp;
use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_runtime::kinematics::ARM_JOINTS;
use serde::{Deserialize, Serialize};

use super::imitation::ImitationError;
use crate::env::seeds::{DEMO_SEED, episode_seed};
use crate::env::{EnvConfig, EnvSnapshot, JacoEnv, Scene, Task};
use crate::evaluate::{EVAL_WIDTH, EvalError, controller_command, physical_to_env_action};
use crate::files::demos::{
    DEMO_FORMAT_VERSION, DemoHeader, DemoRow, DemoSet, interface_layout_hash, task_name,
};
use crate::files::record_settings::{Keep, RecordMode, RecordSettings};
use crate::learn::Rng;

/// The file the labelled branches are kept in, in the run folder.
pub const ROLLOUT_DEMOS: &str = "demos-0-rollout.dxdm";

/// Settings of the rollout teacher.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RolloutTeacher {
    /// The policy file (of the run's task) whose failed episodes are branched.
    pub policy: PathBuf,
    /// Clean episodes of the policy tried; the failed ones are branched.
    pub episodes: u32,
    /// Every `stride`-th state of a failed episode is a branch point.
    pub stride: u32,
    /// Perturbed branches per branch point (beside the policy's own continuation).
    pub candidates: u32,
    /// Standard deviation of a branch's noise on each held arm action, action units.
    pub arm_noise: f32,
    /// Standard deviation of a branch's noise on each held finger action, action units.
    pub finger_noise: f32,
    /// Steps a branch's noise lasts before the policy alone takes over.
    pub hold: u32,
    /// Rollouts of each branch (at least 1); the later ones add `jitter` to its held actions.
    pub replicates: u32,
    /// Noise of the later replicates on the held actions, action units.
    pub jitter: f32,
    /// The best branch's success rate must beat the policy's own by this much to be labelled.
    pub margin: f32,
    /// Times each labelled row counts in the cloning data.
    pub repeat: u32,
}

impl RolloutTeacher {
    /// The settings `trainer imitate --rollout-teacher POLICY` starts from: 1000 episodes,
    /// branch points every 5 steps, 8 branches held 5 steps with the DART noise of the clones'
    /// recordings (0.1 on the arm, 0.05 on the fingers), 2 replicates with jitter 0.05, margin
    /// 0.5 (with 2 replicates: the branch succeeds in both where the policy succeeds in at most
    /// one), each row counted once. Session 27 measured noise 0.3 on every action (what rescued
    /// every failure of the single Stack clone in session 26's `perturbed_episodes`) with each
    /// row counted 10 times: the clone fell from 98.4% to 78.7% (docs/experiments.md).
    pub fn new(policy: PathBuf) -> Self {
        RolloutTeacher {
            policy,
            episodes: 1000,
            stride: 5,
            candidates: 8,
            arm_noise: 0.1,
            finger_noise: 0.05,
            hold: 5,
            replicates: 2,
            jitter: 0.05,
            margin: 0.5,
            repeat: 1,
        }
    }

    /// Checks the ranges (not the file: [`RolloutTeacher::policy_file`] reads it).
    pub fn validate(&self) -> Result<(), ImitationError> {
        let bad = |why: &str| Err(ImitationError::Settings(format!("rollout_teacher: {why}")));
        if self.episodes == 0 || self.stride == 0 || self.candidates == 0 {
            return bad("episodes, stride and candidates must be at least 1");
        }
        if self.hold == 0 || self.replicates == 0 || self.repeat == 0 {
            return bad("hold, replicates and repeat must be at least 1");
        }
        let noise_ok = |n: f32| n.is_finite() && (0.0..=1.0).contains(&n);
        if !noise_ok(self.arm_noise) || !noise_ok(self.finger_noise) {
            return bad("noise must be in [0, 1]");
        }
        if self.arm_noise == 0.0 && self.finger_noise == 0.0 {
            return bad("without noise every branch is the policy's own continuation");
        }
        if !(self.jitter.is_finite() && (0.0..=1.0).contains(&self.jitter)) {
            return bad("jitter must be in [0, 1]");
        }
        if !(self.margin.is_finite() && self.margin > 0.0 && self.margin <= 1.0) {
            return bad("margin must be in (0, 1]");
        }
        Ok(())
    }

    /// The seed block of a run with seed `run_seed`.
    pub fn seed(&self, run_seed: u64) -> u64 {
        DEMO_SEED + run_seed * 1_000 + 6
    }

    /// The policy file's bytes, checked to be a usable policy of `task` (a run calls it before
    /// it touches its folder).
    pub fn policy_file(&self, task: Task) -> Result<Vec<u8>, ImitationError> {
        let bytes = std::fs::read(&self.policy).map_err(|source| ImitationError::Io {
            path: self.policy.clone(),
            source,
        })?;
        let aligned = dex_runtime::aligned::aligned_copy(&bytes);
        let view = crate::evaluate::decode_jaco_policy(aligned.as_bytes())?;
        let file_task = view.body().task;
        if Task::from(file_task) != task {
            return Err(ImitationError::Settings(format!(
                "rollout_teacher: {} is a {file_task:?} policy; the run learns {}",
                self.policy.display(),
                task_name(task)
            )));
        }
        Ok(bytes)
    }

    /// What the file's header says it was made from (the settings as JSON, less `repeat`, which
    /// only the cloning reads): a resumed run checks it, and a new repeat reuses the labels.
    fn source(&self) -> String {
        let mut v = serde_json::to_value(self).unwrap_or_default();
        if let Some(m) = v.as_object_mut() {
            m.remove("repeat");
        }
        format!("rollout teacher {v}")
    }

    /// Runs the episodes and labels the winning branches of the failed ones on `threads`
    /// threads, calling `on_episode` after each episode.
    pub fn label(
        &self,
        scene: &Scene,
        task: Task,
        run_seed: u64,
        threads: usize,
        on_episode: &(dyn Fn() + Sync),
    ) -> Result<DemoSet, ImitationError> {
        self.validate()?;
        let file = self.policy_file(task)?;
        let aligned = dex_runtime::aligned::aligned_copy(&file);
        let seed = self.seed(run_seed);
        let episodes = crate::env::parallel::map_in_order(
            self.episodes as usize,
            threads,
            || -> Result<_, ImitationError> {
                let view = crate::evaluate::decode_jaco_policy(aligned.as_bytes())?;
                let mlp = Mlp::<EVAL_WIDTH>::new(&view).map_err(EvalError::from)?;
                Ok((mlp, JacoEnv::new(scene, EnvConfig::new(task))))
            },
            |(mlp, env), i| self.one_episode(env, mlp, episode_seed(seed, i as u64)),
            on_episode,
        )?;
        let (mut successes, mut stored, mut env_steps) = (0u32, 0u32, 0u64);
        let mut rows = Vec::new();
        for e in episodes {
            successes += u32::from(e.success);
            env_steps += e.env_steps;
            stored += e.segments;
            rows.extend(e.rows);
        }
        Ok(DemoSet {
            header: DemoHeader {
                version: DEMO_FORMAT_VERSION,
                task: task_name(task).to_owned(),
                layout_hash: interface_layout_hash(),
                obs_dim: OBS_DIM,
                act_dim: ACT_DIM,
                source: self.source(),
                settings: self.record_settings(task, run_seed),
                tried: self.episodes,
                successes,
                episodes: stored,
                env_steps,
            },
            rows,
        })
    }

    /// The header's recording settings (the seed block, the branches' noise; every labelled
    /// branch is kept).
    pub fn record_settings(&self, task: Task, run_seed: u64) -> RecordSettings {
        RecordSettings {
            task,
            episodes: self.episodes,
            seed: self.seed(run_seed),
            arm_noise: self.arm_noise,
            finger_noise: self.finger_noise,
            close_bursts: 0.0,
            open_bursts: 0.0,
            keep: Keep::All,
            mode: RecordMode::Demonstrator,
            reward: None,
            close_spacing: None,
        }
    }

    /// The labelled set at `path` if it is there (checked to be of these settings), otherwise
    /// labelled now and saved there.
    pub fn load_or_label(
        &self,
        scene: &Scene,
        task: Task,
        run_seed: u64,
        threads: usize,
        path: &Path,
    ) -> Result<DemoSet, ImitationError> {
        if path.exists() {
            let set = DemoSet::load(path)?;
            if set.header.source != self.source()
                || set.header.settings != self.record_settings(task, run_seed)
            {
                return Err(ImitationError::Settings(format!(
                    "{} was labelled with other settings; remove it or use another folder",
                    path.display()
                )));
            }
            return Ok(set);
        }
        let set = self.label(scene, task, run_seed, threads, &|| {})?;
        set.save(path)?;
        Ok(set)
    }

    /// One clean episode from `seed`; if it fails, its branch points' winning branches.
    fn one_episode(
        &self,
        env: &mut JacoEnv,
        mlp: &mut Mlp<'_, EVAL_WIDTH>,
        seed: u64,
    ) -> Result<Labelled, ImitationError> {
        let mut obs = env.reset(seed).map_err(EvalError::from)?;
        let mut snaps: Vec<EnvSnapshot> = Vec::new();
        let mut env_steps = 0u64;
        let success = loop {
            snaps.push(env.snapshot());
            let a = physical_to_env_action(&controller_command(mlp, &obs, true, None)?);
            let out = env.step(&a).map_err(EvalError::from)?;
            env_steps += 1;
            obs = out.observation;
            if out.done {
                break out.success;
            }
        };
        let mut labelled = Labelled {
            success,
            env_steps,
            segments: 0,
            rows: Vec::new(),
        };
        if success {
            return Ok(labelled);
        }
        let reps = self.replicates as usize;
        for t in (0..snaps.len()).step_by(self.stride as usize) {
            let mut rng = Rng::derive(seed, 0x5011_0000 + t as u64);
            // The policy's own continuation: its first replicate is the failed episode itself.
            let mut own = 0u32;
            for _ in 1..reps {
                let jitter = self.draw(&mut rng, self.jitter, self.jitter);
                let (ok, _, steps) = self.branch(env, mlp, &snaps[t], &jitter, false)?;
                own += u32::from(ok);
                env_steps += steps;
            }
            let own_rate = own as f32 / reps as f32;
            let mut best: Option<(f32, Vec<DemoRow>)> = None;
            for _ in 0..self.candidates {
                let noise = self.draw(&mut rng, self.arm_noise, self.finger_noise);
                let (mut wins, mut first_rows) = (0u32, Vec::new());
                for r in 0..reps {
                    let mut held = noise.clone();
                    if r > 0 {
                        for (h, j) in
                            held.iter_mut()
                                .zip(self.draw(&mut rng, self.jitter, self.jitter))
                        {
                            for (x, y) in h.iter_mut().zip(j) {
                                *x += y;
                            }
                        }
                    }
                    let (ok, rows, steps) = self.branch(env, mlp, &snaps[t], &held, r == 0)?;
                    wins += u32::from(ok);
                    env_steps += steps;
                    if r == 0 {
                        first_rows = rows;
                    }
                }
                let rate = wins as f32 / reps as f32;
                if best.as_ref().is_none_or(|(b, _)| rate > *b) {
                    best = Some((rate, first_rows));
                }
            }
            if let Some((rate, rows)) = best
                && rate - own_rate >= self.margin - 1e-6
                && !rows.is_empty()
            {
                labelled.segments += 1;
                labelled.rows.extend(rows);
            }
        }
        labelled.env_steps = env_steps;
        Ok(labelled)
    }

    /// `hold` steps of Gaussian noise: standard deviation `arm` on the arm's actions, `fingers`
    /// on the fingers'.
    fn draw(&self, rng: &mut Rng, arm: f32, fingers: f32) -> Vec<[f32; ACT_DIM]> {
        (0..self.hold)
            .map(|_| {
                std::array::from_fn(|j| {
                    let sd = if j < ARM_JOINTS { arm } else { fingers };
                    if sd > 0.0 { rng.normal(0.0, sd) } else { 0.0 }
                })
            })
            .collect()
    }

    /// From `snap`: the policy's actions plus `held[k]` for the first steps, then the policy
    /// alone to the episode's end. Returns the success, the held steps' rows (when `record`)
    /// and the steps taken.
    fn branch(
        &self,
        env: &mut JacoEnv,
        mlp: &mut Mlp<'_, EVAL_WIDTH>,
        snap: &EnvSnapshot,
        held: &[[f32; ACT_DIM]],
        record: bool,
    ) -> Result<(bool, Vec<DemoRow>, u64), ImitationError> {
        let mut obs = env.restore(snap).map_err(EvalError::from)?;
        let mut rows = Vec::new();
        let mut steps = 0u64;
        loop {
            let mut a = physical_to_env_action(&controller_command(mlp, &obs, true, None)?);
            let noisy = (steps as usize) < held.len();
            if let Some(n) = held.get(steps as usize) {
                for (x, e) in a.iter_mut().zip(n) {
                    *x = (*x + e).clamp(-1.0, 1.0);
                }
            }
            let out = env.step(&a).map_err(EvalError::from)?;
            steps += 1;
            if record && noisy {
                rows.push(DemoRow {
                    obs,
                    label: a,
                    executed: a,
                    reward: out.reward,
                    next_obs: out.observation,
                    last: out.done || steps as usize == held.len(),
                });
            }
            obs = out.observation;
            if out.done {
                return Ok((out.success, rows, steps));
            }
        }
    }
}

/// What one episode gave.
struct Labelled {
    success: bool,
    env_steps: u64,
    segments: u32,
    rows: Vec<DemoRow>,
}
