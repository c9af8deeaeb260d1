//! Success-filtered self-imitation (issue #26): a policy file's own episodes with noise on its
//! executed actions, kept when they succeed, join the cloning data labelled with the *executed*
//! actions. Where the outcome depends on the noise, the labels' mean at a state moves toward the
//! actions that succeeded: reward-weighted regression with the task's binary success as the
//! weight (Peters and Schaal 2007; Oh et al. 2018 imitate their own good episodes), a policy
//! improvement step that needs no critic. It is measured against the same recipe without it
//! (docs/experiments.md, session 26): the critics of this task do not order actions, and the
//! failures of its clones are fragile, rescued by small random perturbations.
//!
//! The episodes start from their own block of seeds (`DEMO_SEED + 1000 * run seed + 5`, beside
//! the recipe's recordings at `+ 0`, `+ 1`, `+ 2` and `+ 10 * round`). The file keeps what was
//! recorded (labels: the policy's own action; executed: with the noise); only the cloning reads
//! the executed actions ([`executed_labels`]).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::imitation::ImitationError;
use crate::cell::policy_demo::{DemoSource, PolicyDemonstration};
use crate::env::seeds::DEMO_SEED;
use crate::env::{Scene, Task};
use crate::files::demos::{DemoSet, record, task_name};
use crate::files::record_settings::{Keep, RecordMode, RecordSettings};

/// The file the recorded episodes are kept in, in the run folder.
pub const SELF_DEMOS: &str = "demos-0-self.dxdm";

/// Settings of the self-imitation data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SelfImitation {
    /// The policy file (of the run's task) whose noisy episodes are recorded.
    pub policy: PathBuf,
    /// Episodes tried; the successful ones are kept.
    pub episodes: u32,
    /// Noise (standard deviation) on the executed arm actions, action units.
    pub arm_noise: f32,
    /// Noise on the executed finger actions.
    pub finger_noise: f32,
    /// Times each kept row counts in the cloning data.
    pub repeat: u32,
}

impl SelfImitation {
    /// Checks the ranges (not the file: [`SelfImitation::record`] reads it).
    pub fn validate(&self) -> Result<(), ImitationError> {
        let bad = |why: &str| Err(ImitationError::Settings(format!("self_imitation: {why}")));
        if self.episodes == 0 {
            return bad("episodes must be at least 1");
        }
        if self.repeat == 0 {
            return bad("repeat must be at least 1");
        }
        let noise_ok = |s: f32| s.is_finite() && (0.0..=1.0).contains(&s);
        if !noise_ok(self.arm_noise) || !noise_ok(self.finger_noise) {
            return bad("noise must be in [0, 1]");
        }
        if self.arm_noise == 0.0 && self.finger_noise == 0.0 {
            return bad("without noise the episodes repeat the policy's own labels");
        }
        Ok(())
    }

    /// How the episodes of a run with seed `run_seed` on `task` are recorded.
    pub fn record_settings(&self, task: Task, run_seed: u64) -> RecordSettings {
        RecordSettings {
            task,
            episodes: self.episodes,
            seed: DEMO_SEED + run_seed * 1_000 + 5,
            arm_noise: self.arm_noise,
            finger_noise: self.finger_noise,
            close_bursts: 0.0,
            open_bursts: 0.0,
            keep: Keep::Successes,
            mode: RecordMode::Demonstrator,
            reward: None,
            close_spacing: None,
        }
    }

    /// The policy file as the episodes' driver, checked to be a usable policy of `task` (a run
    /// calls it before it touches its folder).
    pub fn policy(&self, task: Task) -> Result<PolicyDemonstration, ImitationError> {
        let bytes = std::fs::read(&self.policy).map_err(|source| ImitationError::Io {
            path: self.policy.clone(),
            source,
        })?;
        let (policy, file_task) = PolicyDemonstration::with_task(&bytes)?;
        if Task::from(file_task) != task {
            return Err(ImitationError::Settings(format!(
                "self_imitation: {} is a {file_task:?} policy; the run learns {}",
                self.policy.display(),
                task_name(task)
            )));
        }
        Ok(policy)
    }

    /// Records the episodes (the policy drives and labels; the noise is on the executed
    /// actions), after checking that the file is a policy of `task`.
    pub fn record(
        &self,
        scene: &Scene,
        task: Task,
        run_seed: u64,
    ) -> Result<DemoSet, ImitationError> {
        let source = DemoSource::Policy(Box::new(self.policy(task)?));
        Ok(record(
            scene,
            &source,
            &self.record_settings(task, run_seed),
            &|| {},
        )?)
    }

    /// The recorded set at `path` if it is there (checked to be of this run's recording),
    /// otherwise recorded now and saved there.
    pub fn load_or_record(
        &self,
        scene: &Scene,
        task: Task,
        run_seed: u64,
        path: &Path,
    ) -> Result<DemoSet, ImitationError> {
        if path.exists() {
            let set = DemoSet::load(path)?;
            if set.header.settings != self.record_settings(task, run_seed) {
                return Err(ImitationError::Settings(format!(
                    "{} was recorded with other settings; remove it or use another folder",
                    path.display()
                )));
            }
            return Ok(set);
        }
        let set = self.record(scene, task, run_seed)?;
        set.save(path)?;
        Ok(set)
    }
}

/// `set` with each row's label replaced by the action the environment executed.
pub fn executed_labels(mut set: DemoSet) -> DemoSet {
    for r in &mut set.rows {
        r.label = r.executed;
    }
    set
}
