//! `trainer train` settings: defaults, then a TOML file, then command-line flags, validated once.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};

use dex_trainer::env::{EnvConfig, Reward, StartScheme, Task};
use dex_trainer::learn::{RunConfig, TargetUpdate};

/// Task names on the command line and in config files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TaskArg {
    /// Bring the pinch site to brick 1 (50 steps; learns in minutes).
    Reach,
    /// Lift brick 1.
    Grasp,
    /// Stack brick 1, starting in the hand.
    StackInHand,
    /// Pick up brick 1 and stack it.
    Stack,
}

impl TaskArg {
    /// The environment's task.
    pub fn task(self) -> Task {
        match self {
            TaskArg::Reach => Task::Reach,
            TaskArg::Grasp => Task::Grasp,
            TaskArg::StackInHand => Task::StackInHand,
            TaskArg::Stack => Task::Stack,
        }
    }

    /// From the environment's task.
    pub fn from_task(task: Task) -> Self {
        match task {
            Task::Reach => TaskArg::Reach,
            Task::Grasp => TaskArg::Grasp,
            Task::StackInHand => TaskArg::StackInHand,
            Task::Stack => TaskArg::Stack,
        }
    }

    /// From a policy file's task.
    pub fn from_policy(task: dex_policy::Task) -> Self {
        match task {
            dex_policy::Task::Reach => TaskArg::Reach,
            dex_policy::Task::Grasp => TaskArg::Grasp,
            dex_policy::Task::StackInHand => TaskArg::StackInHand,
            dex_policy::Task::Stack => TaskArg::Stack,
        }
    }
}

/// Reward names on the command line and in config files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RewardArg {
    /// The task's own sparse reward.
    TaskDefault,
    /// Paper: 1 if stacked.
    SparseStack,
    /// Paper: 1 stacked, 0.25 grasped.
    GraspShaping,
    /// Paper: 1 stacked, 0.25 grasped, 0.125 reached.
    ReachGraspShaping,
    /// Paper: full composite with the tanh^2 distance terms.
    FullComposite,
    /// 1 if brick 1 is lifted.
    SparseGrasp,
    /// 1 if the pinch site is in the reach box.
    SparseReach,
    /// 1 in the reach box, else a broad distance term (the Reach task's dense reward).
    ReachShaping,
}

impl RewardArg {
    /// The environment configuration for `task` with this reward.
    pub fn env_config(self, task: Task) -> EnvConfig {
        let base = EnvConfig::new(task);
        let reward = match self {
            RewardArg::TaskDefault => return base,
            RewardArg::SparseStack => Reward::SparseStack,
            RewardArg::GraspShaping => Reward::GraspShaping,
            RewardArg::ReachGraspShaping => Reward::ReachGraspShaping,
            RewardArg::FullComposite => Reward::FullComposite,
            RewardArg::SparseGrasp => Reward::SparseGrasp,
            RewardArg::SparseReach => Reward::SparseReach,
            RewardArg::ReachShaping => Reward::ReachShaping,
        };
        base.with_reward(reward)
    }
}

/// Start-state scheme names on the command line and in config files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StartArg {
    /// The task's own start states.
    Original,
    /// The in-hand start with probability `start.in_hand_probability`, else the original one.
    Mixture,
    /// States along the scripted demonstrator's trajectories; short training episodes.
    AlongDemonstrations,
}

/// Where training episodes start (evaluation always uses the task's original starts, full length).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StartSettings {
    /// The scheme.
    pub scheme: StartArg,
    /// Probability of the in-hand start under `mixture`.
    pub in_hand_probability: f64,
    /// Training episode length under `along-demonstrations` (the paper: 50; evaluation keeps 150).
    pub train_episode_steps: u32,
    /// Under `along-demonstrations`: an exported policy file to demonstrate instead of the
    /// scripted demonstrator.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub demonstrator_policy: Option<PathBuf>,
}

impl Default for StartSettings {
    fn default() -> Self {
        StartSettings {
            scheme: StartArg::Original,
            in_hand_probability: 0.5,
            train_episode_steps: dex_trainer::env::start_states::DEMO_TRAIN_EPISODE_STEPS,
            demonstrator_policy: None,
        }
    }
}

impl StartSettings {
    /// The environment's scheme.
    pub fn scheme(&self) -> StartScheme {
        match self.scheme {
            StartArg::Original => StartScheme::Original,
            StartArg::Mixture => StartScheme::Mixture {
                in_hand_probability: self.in_hand_probability,
            },
            StartArg::AlongDemonstrations => StartScheme::AlongDemonstrations {
                train_episode_steps: self.train_episode_steps,
            },
        }
    }
}

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
    /// The learner.
    pub run: RunConfig,
}

/// Named starting points for the learner's settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PresetArg {
    /// The paper's plain DDPG: no demonstrations, no TD3 pieces, one-step returns, white noise.
    Paper,
}

impl PresetArg {
    /// Applies the preset to `s`'s learner settings.
    pub fn apply(self, s: &mut TrainSettings) {
        match self {
            PresetArg::Paper => {
                let plain = dex_trainer::learn::RunConfig::default();
                s.run.td3 = plain.td3;
                s.run.n_step = plain.n_step;
                s.run.demos = plain.demos;
                s.run.noise.correlation = 0.0;
                s.run.noise.scale.clear();
                s.run.ddpg.action_l2 = 0.0;
                s.run.obs_norm.frozen_from_demos = false;
                s.demo_files.clear();
                s.record_demos = 0;
            }
        }
    }
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
            run,
        }
    }
}

/// Overlays `overlay` onto `base` key by key (tables merge, other values replace). A table none of
/// whose keys the base has replaces it whole: that is how an enum switches variant
/// (`[run.ddpg.target.polyak]` over the default `copy`).
fn merge(base: &mut toml::Value, overlay: toml::Value) {
    match (base, overlay) {
        (toml::Value::Table(b), toml::Value::Table(o))
            if !b.is_empty() && o.keys().all(|k| !b.contains_key(k)) =>
        {
            *b = o;
        }
        (toml::Value::Table(b), toml::Value::Table(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}

/// Every key of `overlay` must exist in `parsed` (the settings read back): catches typos that serde
/// would silently skip.
fn check_keys(overlay: &toml::Value, parsed: &toml::Value, path: &str) -> anyhow::Result<()> {
    if let (toml::Value::Table(o), toml::Value::Table(p)) = (overlay, parsed) {
        for (k, v) in o {
            let here = if path.is_empty() {
                k.clone()
            } else {
                format!("{path}.{k}")
            };
            match p.get(k) {
                Some(pv) => check_keys(v, pv, &here)?,
                None => bail!("unknown setting `{here}`"),
            }
        }
    }
    Ok(())
}

/// Defaults overlaid with the TOML file at `path`.
pub fn load(path: Option<&Path>) -> anyhow::Result<TrainSettings> {
    let Some(path) = path else {
        return Ok(TrainSettings::default());
    };
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let overlay: toml::Value =
        toml::from_str(&text).with_context(|| format!("{} is not valid TOML", path.display()))?;
    let mut base = toml::Value::try_from(TrainSettings::default())?;
    merge(&mut base, overlay.clone());
    let settings: TrainSettings = base
        .try_into()
        .with_context(|| format!("bad value in {}", path.display()))?;
    check_keys(&overlay, &toml::Value::try_from(&settings)?, "")
        .with_context(|| format!("in {}", path.display()))?;
    Ok(settings)
}

impl TrainSettings {
    /// Checks what the learner does not check itself.
    pub fn validate(&self) -> anyhow::Result<()> {
        if self.seeds.is_empty() {
            bail!("at least one seed is needed");
        }
        if self.transitions == 0 {
            bail!("transitions must be positive");
        }
        if self.checkpoint_every == 0 {
            bail!("checkpoint_every must be positive");
        }
        self.start
            .scheme()
            .validate()
            .context("invalid [start] settings")?;
        if self.start.demonstrator_policy.is_some()
            && self.start.scheme != StartArg::AlongDemonstrations
        {
            bail!("start.demonstrator_policy needs start.scheme = \"along-demonstrations\"");
        }
        self.run.validate().context("invalid learner settings")?;
        let uses = self.run.demos.uses_demos();
        if uses && self.demo_files.is_empty() && self.record_demos == 0 {
            bail!(
                "run.demos.fraction > 0 needs demonstrations: demo_files (--demos) or record_demos \
                 (--record-demos)"
            );
        }
        if !uses && (!self.demo_files.is_empty() || self.record_demos > 0) {
            bail!(
                "demonstrations given but run.demos.fraction is 0 (--demo-fraction): they would \
                 not be used"
            );
        }
        if !(self.demo_noise >= 0.0 && self.demo_noise <= 1.0) {
            bail!("demo_noise must be in [0, 1]");
        }
        Ok(())
    }

    /// The settings as TOML (written into each run folder).
    pub fn to_toml(&self) -> anyhow::Result<String> {
        Ok(toml::to_string_pretty(self)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_values_override_defaults_and_typos_are_errors() {
        let dir = std::env::temp_dir().join(format!("dex-cfg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("good.toml");
        std::fs::write(
            &good,
            "task = \"grasp\"\ntransitions = 5\n[run]\nupdates_per_step = 40\n[run.ddpg]\nbatch_size = 256\n",
        )
        .unwrap();
        let s = load(Some(&good)).unwrap();
        assert_eq!(s.task, TaskArg::Grasp);
        assert_eq!(s.transitions, 5);
        assert_eq!(s.run.updates_per_step, 40);
        assert_eq!(s.run.ddpg.batch_size, 256);
        assert_eq!(s.run.ddpg.gamma, TrainSettings::default().run.ddpg.gamma);
        let polyak = dir.join("polyak.toml");
        std::fs::write(&polyak, "[run.ddpg.target.polyak]\ntau = 0.01\n").unwrap();
        let s = load(Some(&polyak)).unwrap();
        assert_eq!(
            s.run.ddpg.target,
            dex_trainer::learn::TargetUpdate::Polyak { tau: 0.01 }
        );
        let copy = dir.join("copy.toml");
        std::fs::write(&copy, "[run.ddpg.target.copy]\nevery = 50\n").unwrap();
        let s = load(Some(&copy)).unwrap();
        assert_eq!(s.run.ddpg.target, TargetUpdate::Copy { every: 50 });
        let bad = dir.join("bad.toml");
        std::fs::write(&bad, "[run]\nupdates_per_stepp = 40\n").unwrap();
        let e = load(Some(&bad)).unwrap_err();
        assert!(format!("{e:#}").contains("updates_per_stepp"), "{e:#}");
        std::fs::write(&bad, "task = \"juggle\"\n").unwrap();
        assert!(load(Some(&bad)).is_err());
        let demo = dir.join("demo.toml");
        std::fs::write(&demo, "[start]\nscheme = \"along-demonstrations\"\n").unwrap();
        let s = load(Some(&demo)).unwrap();
        assert_eq!(
            s.start.scheme(),
            StartScheme::AlongDemonstrations {
                train_episode_steps: 50
            }
        );
        std::fs::write(
            &bad,
            "[start]\nscheme = \"mixture\"\nin_hand_probability = 1.5\n",
        )
        .unwrap();
        let e = load(Some(&bad)).unwrap().validate().unwrap_err();
        assert!(format!("{e:#}").contains("in-hand probability"), "{e:#}");
        std::fs::write(&bad, "[start]\nscheme = \"teleport\"\n").unwrap();
        assert!(load(Some(&bad)).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }

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
    }
}
