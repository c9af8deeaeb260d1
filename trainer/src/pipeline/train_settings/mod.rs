//! Settings of a training run (`trainer train`): defaults, then a TOML file, then command-line
//! flags, validated once into one [`TrainSettings`] value.
//!
//! Each run folder keeps its settings as `settings.toml` ([`TrainSettings::to_toml`]); missing keys
//! take their defaults, so folders written before a setting existed still load.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::learn::{RunConfig, TargetUpdate};

mod clone_stage;
mod error;
mod load;
mod pg_stage;
mod presets;
mod start;
mod task_args;

pub use clone_stage::{CloneStage, STACK_CLOSE_DART_EPISODES};
pub use error::{SettingsError, UnknownSetting};
pub use load::load;
pub use pg_stage::PgStage;
pub use presets::{
    DEMOS_TRANSITIONS, FINETUNE_GUARD_EPISODES, FINETUNE_TRANSITIONS, MAX_GUARD_EPISODES,
    MAX_SCREEN_STARTS, PresetArg, REACH_DEMOS_CHECKPOINT_EVERY, REACH_DEMOS_TRANSITIONS,
    TaskDefault,
};
pub use start::StartSettings;
pub use task_args::{RewardArg, StartArg, TaskArg};

/// Everything `trainer train` does, after merging defaults, the file and the flags.
/// Missing keys take their defaults, so run folders written before a setting existed still load.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainSettings {
    /// Task to learn.
    pub task: TaskArg,
    /// Reward function.
    pub reward: RewardArg,
    /// Where training episodes start.
    pub start: StartSettings,
    /// Transitions per seed (all workers together).
    pub transitions: u64,
    /// Seeds, one run each.
    pub seeds: Vec<u64>,
    /// Output folder.
    pub out: PathBuf,
    /// Checkpoint every this many transitions.
    pub checkpoint_every: u64,
    /// Episodes of the evaluation of the exported policy (through the runtime).
    pub final_eval_episodes: u32,
    /// At every checkpoint the current policy is evaluated through the runtime on this many
    /// selection starts (seeds apart from the final evaluation's) and the best one so far is kept;
    /// the exported policy is the best, not the last. 0 exports the last policy.
    pub select_best_episodes: u32,
    /// Threads for that evaluation.
    pub eval_threads: usize,
    /// Demonstration files (`trainer demos`) for `run.demos`: the run's demonstration buffer.
    pub demo_files: Vec<PathBuf>,
    /// Markov-demonstrator episodes recorded into each seed's folder (`demos.dxdm`, DART noise
    /// `demo_noise` on the executed arm actions, half of it on the fingers) when `run.demos` draws
    /// demonstration rows and no files are given.
    pub record_demos: u32,
    /// Noise on the recorded demonstrations' executed arm actions.
    pub demo_noise: f32,
    /// An exported f32 policy file of the task (e.g. `trainer imitate`'s clone) whose network
    /// starts the actor (`--init-policy`; `run.ddpg.actor_hidden` must be its hidden sizes; with
    /// `obs_norm` off the file's normalisation is folded into the first layer, with
    /// `obs_norm.enabled` and `obs_norm.frozen_from_init` it becomes the run's frozen normaliser).
    pub init_policy: Option<PathBuf>,
    /// The actor and the critic also take the controller's task features after the observation
    /// (`dex_runtime::features`; `--features`); the exported file lists them, the runtime
    /// computes them. An `init_policy` must agree.
    pub features: bool,
    /// The clone stage (`[clone]`, `--clone`): before each seed's reinforcement learning, the
    /// imitation learner clones the Markov demonstrator into `OUT/clone/seed-S` and the seed's
    /// actor starts from that file, as it would from `init_policy` (which must then be unset);
    /// with members ([`CloneStage::members`]) the stage is an ensemble of clones distilled into
    /// one network, whose file the actor starts from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub clone: Option<CloneStage>,
    /// The guard of a run that starts from a policy (`init_policy` or the clone stage): at the
    /// export, the selected policy and the starting one are evaluated on this many selection
    /// starts (the same starts for both) and the selected policy is shipped only when it solves
    /// more of them with a McNemar p below 0.01; otherwise (a tie included) the starting policy's
    /// file is, so the reinforcement-learning stage ships only a file measurably better than the
    /// one it was given (`--guard-episodes`; 0: off, the selected policy is shipped).
    pub guard_episodes: u32,
    /// The policy-gradient stage (`[pg]`, `--pg`): after each seed's export, its file is
    /// fine-tuned by [`crate::pipeline::group_pg`] in `OUT/seed-S/pg`, whose last actor is the
    /// seed's final file (`OUT/seed-S/pg/policy.dxpl`, evaluated as the export is).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pg: Option<PgStage>,
    /// The learner.
    pub run: RunConfig,
}

/// The defaults learn Reach: 92% (46/50) for seed 0 after 60k transitions in about 165 s on two
/// cores (`experiments/reach-g90-ln-clr1e-3.toml`, `docs/training.md` "Reach tuning log"); other
/// seeds reach 80-86%. The short discount suits 50-step episodes with a dense reward; the critic's
/// layer norm with critic lr 1e-3 made the step from ~60% to 80-90%.
impl Default for TrainSettings {
    fn default() -> Self {
        let mut run = RunConfig::default();
        run.ddpg.actor_hidden = vec![128, 128];
        run.ddpg.critic_hidden = vec![128, 128];
        run.ddpg.critic_layer_norm = true;
        run.ddpg.gamma = 0.9;
        run.ddpg.batch_size = 128;
        run.ddpg.target = TargetUpdate::Polyak { tau: 0.005 };
        run.actor_adam.lr = 3e-4;
        run.critic_adam.lr = 1e-3;
        run.noise.std = 0.1;
        run.updates_per_step = 2;
        run.replay.capacity = 200_000;
        TrainSettings {
            task: TaskArg::Reach,
            reward: RewardArg::ReachShaping,
            start: StartSettings::default(),
            transitions: 60_000,
            seeds: vec![0],
            out: PathBuf::from("runs/reach"),
            checkpoint_every: 5_000,
            final_eval_episodes: 50,
            select_best_episodes: 30,
            eval_threads: 2,
            demo_files: Vec::new(),
            record_demos: 0,
            demo_noise: 0.1,
            init_policy: None,
            clone: None,
            features: false,
            guard_episodes: 0,
            pg: None,
            run,
        }
    }
}

impl TrainSettings {
    /// Width of the networks' input: the observation, and the task features when `features`.
    pub fn input_dim(&self) -> usize {
        if self.features {
            dex_runtime::features::INPUT_MAX
        } else {
            dex_runtime::interface::OBS_DIM
        }
    }

    /// Checks what the learner does not check itself.
    pub fn validate(&self) -> Result<(), SettingsError> {
        if self.seeds.is_empty() {
            return Err(SettingsError::NoSeeds);
        }
        if self.transitions == 0 {
            return Err(SettingsError::NoTransitions);
        }
        if self.checkpoint_every == 0 {
            return Err(SettingsError::NoCheckpointPeriod);
        }
        self.start
            .scheme()
            .validate()
            .map_err(SettingsError::Start)?;
        if self.start.demonstrator_policy.is_some()
            && self.start.scheme != StartArg::AlongDemonstrations
        {
            return Err(SettingsError::DemonstratorPolicyScheme);
        }
        let eval_steps = self.task.task().episode_steps();
        if self.start.scheme == StartArg::AlongDemonstrations
            && self.start.train_episode_steps > eval_steps
        {
            return Err(SettingsError::TrainEpisodeTooLong {
                train: self.start.train_episode_steps,
                eval: eval_steps,
            });
        }
        self.run.validate().map_err(SettingsError::Learner)?;
        let uses = self.run.demos.uses_demos();
        if uses && self.demo_files.is_empty() && self.record_demos == 0 {
            return Err(SettingsError::DemosMissing);
        }
        if !uses && (!self.demo_files.is_empty() || self.record_demos > 0) {
            return Err(SettingsError::DemosUnused);
        }
        if !(self.demo_noise >= 0.0 && self.demo_noise <= 1.0) {
            return Err(SettingsError::DemoNoise);
        }
        let from_init = self.run.obs_norm.frozen_from_init;
        if self.init_policy.is_some() && self.run.obs_norm.enabled != from_init {
            return Err(SettingsError::InitPolicyNorm);
        }
        if from_init && self.init_policy.is_none() && self.clone.is_none() {
            return Err(SettingsError::InitPolicyNorm);
        }
        if self.guard_episodes > 0 && self.init_policy.is_none() && self.clone.is_none() {
            return Err(SettingsError::GuardWithoutInit);
        }
        if self.run.ddpg.residual.is_some() && self.init_policy.is_none() && self.clone.is_none() {
            return Err(SettingsError::ResidualWithoutInit);
        }
        if self.run.ibrl && self.init_policy.is_none() && self.clone.is_none() {
            return Err(SettingsError::IbrlWithoutInit);
        }
        let f = &self.start;
        if f.failed_starts > 0 {
            if self.init_policy.is_none() && self.clone.is_none() {
                return Err(SettingsError::FailedStartsWithoutInit);
            }
            if f.scheme != StartArg::Original
                || f.failed_starts > MAX_SCREEN_STARTS
                || !(0.0..=1.0).contains(&f.failed_start_probability)
            {
                return Err(SettingsError::FailedStarts {
                    starts: f.failed_starts,
                    probability: f.failed_start_probability,
                    max: MAX_SCREEN_STARTS,
                });
            }
        }
        if self.guard_episodes > MAX_GUARD_EPISODES {
            return Err(SettingsError::GuardTooLong {
                episodes: self.guard_episodes,
            });
        }
        if let Some(pg) = &self.pg {
            pg.validate().map_err(SettingsError::Pg)?;
        }
        if let Some(stage) = &self.clone {
            if self.init_policy.is_some() {
                return Err(SettingsError::CloneAndInitPolicy);
            }
            if self.run.obs_norm.enabled != from_init {
                return Err(SettingsError::InitPolicyNorm);
            }
            stage
                .imitation(self, 0)
                .validate()
                .map_err(SettingsError::Clone)?;
            for &seed in &self.seeds {
                stage
                    .ensemble(self, seed)
                    .map_err(SettingsError::CloneMembers)?;
            }
        }
        Ok(())
    }

    /// The settings as TOML (written into each run folder).
    pub fn to_toml(&self) -> Result<String, SettingsError> {
        Ok(toml::to_string_pretty(self)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_written_before_newer_keys_existed_still_load() {
        let mut v = toml::Value::try_from(TrainSettings::default()).unwrap();
        let t = v.as_table_mut().unwrap();
        t.remove("start");
        t.remove("select_best_episodes");
        let old: TrainSettings = toml::from_str(&toml::to_string(&v).unwrap()).unwrap();
        assert_eq!(old, TrainSettings::default());
    }

    #[test]
    fn round_trips_through_toml() {
        let s = TrainSettings::default();
        let text = s.to_toml().unwrap();
        let back: TrainSettings = toml::from_str(&text).unwrap();
        assert_eq!(back, s);
        for task in [TaskArg::Grasp, TaskArg::Stack, TaskArg::StackInHand] {
            let mut s = TrainSettings::for_task(task);
            if task == TaskArg::Stack {
                s.pg = Some(PgStage::default());
            }
            let text = s.to_toml().unwrap();
            let back: TrainSettings = toml::from_str(&text).unwrap();
            assert_eq!(back, s, "{text}");
        }
    }
}
