//! Settings of a training run (`trainer train`): defaults, then a TOML file, then command-line
//! flags, validated once into one [`TrainSettings`] value.
//!
//! Each run folder keeps its settings as `settings.toml` ([`TrainSettings::to_toml`]); missing keys
//! take their defaults, so folders written before a setting existed still load.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::env::{EnvConfig, EnvError, Reward, StartScheme, Task};
use crate::learn::bc::BcConfig;
use crate::learn::{LearnError, RunConfig, TargetUpdate};
use crate::pipeline::clone_members::{
    self, CloneMember, DEFAULT_DISTIL_EPISODES_PER_ROUND, DEFAULT_DISTIL_ROUNDS, Ensemble,
    MembersError,
};
use crate::pipeline::imitation::{ImitationConfig, ImitationError};

/// Why settings could not be loaded, or are not valid.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SettingsError {
    /// The settings file could not be read.
    #[error("cannot read {}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The settings file is not TOML.
    #[error("{} is not valid TOML", path.display())]
    Toml {
        /// The file.
        path: PathBuf,
        /// The parser's error (boxed: it is large).
        source: Box<toml::de::Error>,
    },
    /// A value of the file has the wrong type or is not one of the accepted names.
    #[error("bad value in {}", path.display())]
    BadValue {
        /// The file.
        path: PathBuf,
        /// The parser's error (boxed: it is large).
        source: Box<toml::de::Error>,
    },
    /// The file has a key that no setting has (a typo serde would otherwise skip).
    #[error("in {}", path.display())]
    UnknownKey {
        /// The file.
        path: PathBuf,
        /// The key.
        source: UnknownSetting,
    },
    /// The settings could not be written as TOML.
    #[error(transparent)]
    Serialize(#[from] toml::ser::Error),
    /// No seed.
    #[error("at least one seed is needed")]
    NoSeeds,
    /// A guard without a policy to guard.
    #[error(
        "guard_episodes (--guard-episodes) compares the run's policy with the one it started from: \
         it needs init_policy (--init-policy) or the clone stage ([clone], --clone)"
    )]
    GuardWithoutInit,
    /// A residual actor without a starting policy to be the residual's base.
    #[error(
        "run.ddpg.residual learns a correction on top of the policy the run starts from: it \
         needs init_policy (--init-policy) or the clone stage ([clone], --clone)"
    )]
    ResidualWithoutInit,
    /// IBRL's proposal without a starting policy to propose.
    #[error(
        "run.ibrl proposes the actions of the policy the run starts from: it needs init_policy \
         (--init-policy) or the clone stage ([clone], --clone)"
    )]
    IbrlWithoutInit,
    /// `start.failed_starts` without a starting policy to screen.
    #[error(
        "start.failed_starts screens the policy a run starts from: it needs init_policy \
         (--init-policy) or the clone stage ([clone], --clone)"
    )]
    FailedStartsWithoutInit,
    /// `start.failed_starts` with another scheme than the original starts, or out of range.
    #[error(
        "start.failed_starts needs start.scheme = \"original\" (full-length episodes from the \
         failed starts), at most {max} starts and a failed_start_probability in [0, 1]; got \
         {starts} starts, probability {probability}"
    )]
    FailedStarts {
        /// The number of screening starts given.
        starts: u32,
        /// The probability given.
        probability: f64,
        /// The most screening starts.
        max: u32,
    },
    /// More guard starts than the selection range holds apart from the other ranges.
    #[error("guard_episodes {episodes} is above the limit of {MAX_GUARD_EPISODES}")]
    GuardTooLong {
        /// The value given.
        episodes: u32,
    },
    /// `transitions` is 0.
    #[error("transitions must be positive")]
    NoTransitions,
    /// `checkpoint_every` is 0.
    #[error("checkpoint_every must be positive")]
    NoCheckpointPeriod,
    /// The `[start]` scheme's settings are out of range.
    #[error("invalid [start] settings")]
    Start(#[source] EnvError),
    /// `start.demonstrator_policy` without the along-demonstrations scheme.
    #[error("start.demonstrator_policy needs start.scheme = \"along-demonstrations\"")]
    DemonstratorPolicyScheme,
    /// The learner refused its settings.
    #[error("invalid learner settings")]
    Learner(#[source] LearnError),
    /// `run.demos.fraction` > 0 without demonstration files or recorded demonstrations.
    #[error(
        "run.demos.fraction > 0 needs demonstrations: demo_files (--demos) or record_demos \
         (--record-demos)"
    )]
    DemosMissing,
    /// Demonstrations given while `run.demos.fraction` is 0.
    #[error(
        "demonstrations given but run.demos.fraction is 0 (--demo-fraction): they would \
         not be used"
    )]
    DemosUnused,
    /// `demo_noise` is outside [0, 1].
    #[error("demo_noise must be in [0, 1]")]
    DemoNoise,
    /// Training episodes along demonstrations longer than the task's (evaluation) episodes.
    #[error(
        "start.train_episode_steps = {train} is longer than the task's {eval}-step evaluation \
         episodes (the paper: 50 of 150)"
    )]
    TrainEpisodeTooLong {
        /// The setting.
        train: u32,
        /// The task's episode length.
        eval: u32,
    },
    /// `init_policy` with a normaliser of the run's own, or `obs_norm.frozen_from_init` without
    /// `init_policy`.
    #[error(
        "init_policy takes either run.obs_norm.enabled = false (the file's normalisation folded \
         into the actor's first layer) or run.obs_norm.enabled = true with \
         run.obs_norm.frozen_from_init = true (the file's normalisation kept, frozen); \
         frozen_from_init needs init_policy"
    )]
    InitPolicyNorm,
    /// Both a clone stage and `init_policy`: two starting points for the actor.
    #[error(
        "[clone] (--clone) makes the actor's starting point and init_policy (--init-policy) names \
         another: give one of them"
    )]
    CloneAndInitPolicy,
    /// The clone stage's imitation settings are out of range.
    #[error("invalid [clone] settings")]
    Clone(#[source] ImitationError),
    /// The clone stage's members or distillation are refused (for one of the run's seeds).
    #[error("invalid [clone] members or distillation")]
    CloneMembers(#[source] MembersError),
}

/// A key of a settings file that no setting has, by its dotted path (`run.updates_per_step`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown setting `{key}`")]
pub struct UnknownSetting {
    /// The dotted key path.
    pub key: String,
}

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
    /// Under `along-demonstrations`: the size of the fixed set of demonstration trajectories the
    /// starts are drawn from, each simulated once (0: a fresh demonstration at every start, which
    /// costs its whole length in environment steps; `dex_env::start_states` module docs).
    pub demonstrations: u32,
    /// Under `along-demonstrations`: an exported policy file to demonstrate instead of the
    /// scripted demonstrator.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub demonstrator_policy: Option<PathBuf>,
    /// Failed-start revisits of a fine-tune (0: off): the starting policy (`init_policy` or the
    /// clone stage's file) runs on this many screening starts
    /// ([`SCREEN_SEED`](crate::env::seeds::SCREEN_SEED)) before training, and training episodes
    /// start from the ones it failed with probability `failed_start_probability`
    /// (`dex_env::start_states`, revisits; the list is kept in the seed folder's
    /// `failed_starts.json`).
    pub failed_starts: u32,
    /// Probability that a training episode revisits a failed start (with `failed_starts`).
    pub failed_start_probability: f64,
}

impl Default for StartSettings {
    fn default() -> Self {
        StartSettings {
            scheme: StartArg::Original,
            in_hand_probability: 0.5,
            train_episode_steps: crate::env::start_states::DEMO_TRAIN_EPISODE_STEPS,
            demonstrations: 0,
            demonstrator_policy: None,
            failed_starts: 0,
            failed_start_probability: 0.5,
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
                demonstrations: self.demonstrations,
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
    /// The learner.
    pub run: RunConfig,
}

/// The clone stage of a pipeline run: `trainer imitate`'s recipe for the task
/// ([`ImitationConfig::for_task`]) with the run's seed, actor sizes, task features and evaluation
/// threads; each field, when set, overrides the recipe's.
///
/// Without members that is the stage: one imitation run per seed, in `OUT/clone/seed-S`. With
/// members (`[[clone.members]]`) it is an ensemble and its distillation
/// ([`crate::pipeline::clone_members`]): each member entry's runs (the recipe with the entry's
/// tweaks, at seeds derived from the pipeline seed) in `OUT/clone/seed-S/NAME-sK`, then one
/// network taught by the mean of their files over `distil_rounds` DAgger rounds in
/// `OUT/clone/seed-S/distil`, whose last round's file starts the fine-tune.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CloneStage {
    /// Clean demonstrator episodes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub demo_episodes: Option<u32>,
    /// Demonstrator episodes with noise on the executed actions (DART).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dart_episodes: Option<u32>,
    /// Stack only: DART episodes started with brick 1 in the hand.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub in_hand_episodes: Option<u32>,
    /// Behaviour-cloning gradient steps.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bc_steps: Option<u64>,
    /// Selection starts of the clone.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub select_episodes: Option<u32>,
    /// With members: DAgger rounds of the distillation (unset:
    /// [`clone_members::DEFAULT_DISTIL_ROUNDS`]); its last round's file starts the fine-tune.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distil_rounds: Option<u32>,
    /// With members: policy episodes labelled per distillation round (unset:
    /// [`clone_members::DEFAULT_DISTIL_EPISODES_PER_ROUND`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distil_episodes_per_round: Option<u32>,
    /// The ensemble (`[[clone.members]]`; empty: a single clone), in the order their files enter
    /// the distillation's mean.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub members: Vec<CloneMember>,
}

impl CloneStage {
    /// The imitation run of seed `seed` of a run with settings `s`.
    pub fn imitation(&self, s: &TrainSettings, seed: u64) -> ImitationConfig {
        let base = ImitationConfig::for_task(s.task.task());
        ImitationConfig {
            demo_episodes: self.demo_episodes.unwrap_or(base.demo_episodes),
            dart_episodes: self.dart_episodes.unwrap_or(base.dart_episodes),
            in_hand_episodes: self.in_hand_episodes.unwrap_or(base.in_hand_episodes),
            select_episodes: self.select_episodes.unwrap_or(base.select_episodes),
            bc: BcConfig {
                steps: self.bc_steps.unwrap_or(base.bc.steps),
                hidden: s.run.ddpg.actor_hidden.clone(),
                features: s.features,
                ..base.bc.clone()
            },
            seed,
            eval_threads: s.eval_threads,
            ..base
        }
    }

    /// The ensemble and distillation of seed `seed` of a run with settings `s`, its members' files
    /// in `OUT/clone/seed-S` (None: no members, a single clone).
    pub fn ensemble(&self, s: &TrainSettings, seed: u64) -> Result<Option<Ensemble>, MembersError> {
        if self.members.is_empty() {
            clone_members::check_members(
                &self.members,
                self.distil_rounds,
                self.distil_episodes_per_round,
            )?;
            return Ok(None);
        }
        let dir = s.out.join("clone").join(format!("seed-{seed}"));
        Ensemble::new(
            &self.imitation(s, seed),
            &self.members,
            self.distil_rounds,
            self.distil_episodes_per_round,
            seed,
            &dir,
        )
        .map(Some)
    }

    /// The clone stage of the task's default pipeline ([`PresetArg::Finetune`]): the shipped
    /// recipe of its policy file. Grasp: members of the default recipe at seeds 0-3, with close
    /// bursts 0.02 at seeds 0-1 and with the teacher that tucks first at seeds 0-1, distilled
    /// over one round (`experiments/grasp-distil.sh`, policies/grasp.dxpl); Stack: Stack's recipe
    /// at seeds 1-7, distilled over one round (`experiments/stack-distil.sh`,
    /// policies/stack.dxpl); both with 400 episodes a round at pipeline seed 1. The other tasks:
    /// one clone (StackInHand's file is its clone fine-tuned).
    pub fn for_task(task: TaskArg) -> CloneStage {
        let member = |name: &str, seeds: &[u64]| CloneMember {
            name: name.to_owned(),
            seeds: seeds.to_vec(),
            ..CloneMember::default()
        };
        let members = match task {
            TaskArg::Grasp => vec![
                member("default", &[0, 1, 2, 3]),
                CloneMember {
                    close_bursts: Some(0.02),
                    ..member("close-bursts", &[0, 1])
                },
                CloneMember {
                    tuck_first: true,
                    ..member("tuck-first", &[0, 1])
                },
            ],
            TaskArg::Stack => vec![member("default", &[1, 2, 3, 4, 5, 6, 7])],
            TaskArg::Reach | TaskArg::StackInHand => return CloneStage::default(),
        };
        CloneStage {
            members,
            distil_rounds: Some(DEFAULT_DISTIL_ROUNDS),
            distil_episodes_per_round: Some(DEFAULT_DISTIL_EPISODES_PER_ROUND),
            ..CloneStage::default()
        }
    }
}

/// Named starting points for the learner's settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PresetArg {
    /// The paper's plain DDPG: no demonstrations, no TD3 pieces, one-step returns, white noise.
    Paper,
    /// The learner from demonstrations (the default of `trainer train --task reach` without a
    /// settings file; until session 16 also of the other tasks: the Grasp ablation's `no-norm`
    /// row, 47/50 and 46/50): 200 recorded Markov-demonstrator episodes,
    /// 20,000 pre-training updates (actor lr 3e-4), a quarter of each batch from them with the
    /// cloning term on every row, TD3+BC's Q normalisation 2.5, actor lr 3e-5, raw observations,
    /// gamma 0.98 for the 150-step tasks.
    Demos,
    /// The pipeline of issue #26: a clone stage (`trainer imitate`'s recipe for the task, with the
    /// task features) and reinforcement learning from the clone that cannot forget it: 40,000
    /// transitions (the `budget` the preset sets when the run gives none), a critic warm-up of
    /// 10,000 updates on the clone's own transitions before the actor moves, R = 2, actor lr
    /// 3e-5, 200 recorded Markov demonstrations a quarter of each batch with the cloning term at
    /// weight 5 and TD3+BC's Q normalisation 2.5, gamma 0.98, the clone's 256-256 actor
    /// (`experiments/finetune/*-features-clone-bc5.toml`; docs/experiments.md, session 14:
    /// StackInHand 989 -> 995 of 1000, Stack 974 -> 981, Grasp 989 -> 978), guarded against the
    /// clone on [`FINETUNE_GUARD_EPISODES`] selection starts. On Grasp and Stack the clone stage
    /// is the shipped file's ensemble and distillation ([`CloneStage::for_task`]; a run with its
    /// own `[clone]` keeps that). The default of `trainer train --task grasp|stack-in-hand|stack`
    /// without a settings file ([`TaskArg::default_pipeline`]).
    Finetune,
}

/// Transitions of the [`PresetArg::Finetune`] stage after the clone.
pub const FINETUNE_TRANSITIONS: u64 = 40_000;

/// Selection starts of the [`PresetArg::Finetune`] guard ([`TrainSettings::guard_episodes`]): the
/// fine-tuned policy against its clone, paired, before the export. 500 resolves a difference of
/// about 1.5 points at 97-99% success (a McNemar test on ~15 discordant starts) for about two
/// minutes of evaluation on two cores; the 30 selection starts of every checkpoint cannot rank
/// files at 97-100% (docs/experiments.md, session 14).
pub const FINETUNE_GUARD_EPISODES: u32 = 500;

/// The most guard starts (they are drawn from the selection range, 1,000,000 seeds wide).
pub const MAX_GUARD_EPISODES: u32 = 100_000;

/// The most screening starts of `start.failed_starts` (the starting policy runs every one of them
/// before training: 100,000 Stack episodes are about 15 million environment steps).
pub const MAX_SCREEN_STARTS: u32 = 100_000;

/// The transition budget of the learner from demonstrations on Grasp, StackInHand and Stack: the
/// Grasp ablation's `no-norm` row, 47/50 and 46/50 for seeds 0 and 1 (docs/experiments.md).
pub const DEMOS_TRANSITIONS: u64 = 20_000;

/// The budget of the learner from demonstrations on Reach: seeds 0, 1, 2 score 98.5-100% over 200
/// starts (docs/experiments.md, session 7).
pub const REACH_DEMOS_TRANSITIONS: u64 = 10_000;

/// Reach's checkpoint (and selection) interval with the learner from demonstrations: 50-step
/// episodes, so a checkpoint every 50 episodes.
pub const REACH_DEMOS_CHECKPOINT_EVERY: u64 = 2_500;

/// What `trainer train --task T` runs without a settings file or a learner flag: the one
/// definition of each task's default pipeline and budget, for every front end.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TaskDefault {
    /// The preset applied to the settings.
    pub preset: PresetArg,
    /// Transitions per seed (of the reinforcement-learning stage).
    pub transitions: u64,
    /// The checkpoint interval, where it is not the settings' default.
    pub checkpoint_every: Option<u64>,
    /// The seed when none is given: 1 on Grasp and Stack, whose clone stages' member seeds are
    /// written for pipeline seed 1 (the shipped files' seed; seed 0 would make members' seeds
    /// negative, [`crate::pipeline::clone_members`]), else 0.
    pub seed: u64,
}

impl TaskArg {
    /// The task's default pipeline: on the manipulation tasks the clone stage and the fine-tune
    /// that keeps it ([`PresetArg::Finetune`], guarded against its clone; on Grasp and Stack the
    /// clone stage is the shipped file's ensemble and distillation, at seed 1); on Reach, whose
    /// demonstrations are solved by a few thousand transitions, the learner from demonstrations.
    pub fn default_pipeline(self) -> TaskDefault {
        match self {
            TaskArg::Reach => TaskDefault {
                preset: PresetArg::Demos,
                transitions: REACH_DEMOS_TRANSITIONS,
                checkpoint_every: Some(REACH_DEMOS_CHECKPOINT_EVERY),
                seed: 0,
            },
            TaskArg::StackInHand => TaskDefault {
                preset: PresetArg::Finetune,
                transitions: FINETUNE_TRANSITIONS,
                checkpoint_every: None,
                seed: 0,
            },
            TaskArg::Grasp | TaskArg::Stack => TaskDefault {
                preset: PresetArg::Finetune,
                transitions: FINETUNE_TRANSITIONS,
                checkpoint_every: None,
                seed: 1,
            },
        }
    }
}

impl TrainSettings {
    /// The settings of `trainer train --task T` without a settings file or a learner flag
    /// ([`TaskArg::default_pipeline`] over the defaults, with the task's own reward).
    pub fn for_task(task: TaskArg) -> TrainSettings {
        let mut s = TrainSettings {
            task,
            ..TrainSettings::default()
        };
        if task != TaskArg::Reach {
            s.reward = RewardArg::TaskDefault;
        }
        s.out = PathBuf::from(format!("runs/{}", format!("{task:?}").to_lowercase()));
        let d = task.default_pipeline();
        d.preset.apply(&mut s);
        s.transitions = d.transitions;
        s.seeds = vec![d.seed];
        if let Some(c) = d.checkpoint_every {
            s.checkpoint_every = c;
        }
        s
    }
}

impl PresetArg {
    /// Applies the preset to `s`'s learner settings.
    pub fn apply(self, s: &mut TrainSettings) {
        match self {
            PresetArg::Paper => {
                let plain = RunConfig::default();
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
            PresetArg::Finetune => {
                if s.demo_files.is_empty() && s.record_demos == 0 {
                    s.record_demos = 200;
                }
                let task = s.task;
                s.clone.get_or_insert_with(|| CloneStage::for_task(task));
                s.features = true;
                s.run.demos = crate::learn::DemoDataConfig {
                    fraction: 0.25,
                    bc_weight: 5.0,
                    q_filter: false,
                    pretrain_updates: 0,
                    q_normalisation: 2.5,
                    pretrain_actor_lr: None,
                };
                s.run.critic_warmup_updates = 10_000;
                s.guard_episodes = FINETUNE_GUARD_EPISODES;
                s.run.updates_per_step = 2;
                s.run.actor_adam.lr = 3e-5;
                s.run.ddpg.actor_hidden = vec![256, 256];
                s.run.obs_norm.enabled = false;
                s.run.obs_norm.frozen_from_init = false;
                if s.task != TaskArg::Reach {
                    s.run.ddpg.gamma = 0.98;
                }
            }
            PresetArg::Demos => {
                if s.demo_files.is_empty() && s.record_demos == 0 {
                    s.record_demos = 200;
                }
                s.run.demos = crate::learn::DemoDataConfig {
                    fraction: 0.25,
                    bc_weight: 1.0,
                    q_filter: false,
                    pretrain_updates: 20_000,
                    q_normalisation: 2.5,
                    pretrain_actor_lr: Some(3e-4),
                };
                s.run.actor_adam.lr = 3e-5;
                if s.task != TaskArg::Reach {
                    s.run.ddpg.gamma = 0.98;
                }
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
            init_policy: None,
            clone: None,
            features: false,
            guard_episodes: 0,
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
fn check_keys(
    overlay: &toml::Value,
    parsed: &toml::Value,
    path: &str,
) -> Result<(), UnknownSetting> {
    if let (toml::Value::Table(o), toml::Value::Table(p)) = (overlay, parsed) {
        for (k, v) in o {
            let here = if path.is_empty() {
                k.clone()
            } else {
                format!("{path}.{k}")
            };
            match p.get(k) {
                Some(pv) => check_keys(v, pv, &here)?,
                None => return Err(UnknownSetting { key: here }),
            }
        }
    }
    Ok(())
}

/// Defaults overlaid with the TOML file at `path`.
pub fn load(path: Option<&Path>) -> Result<TrainSettings, SettingsError> {
    let Some(path) = path else {
        return Ok(TrainSettings::default());
    };
    let text = std::fs::read_to_string(path).map_err(|source| SettingsError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let overlay: toml::Value = toml::from_str(&text).map_err(|source| SettingsError::Toml {
        path: path.to_path_buf(),
        source: Box::new(source),
    })?;
    let mut base = toml::Value::try_from(TrainSettings::default())?;
    merge(&mut base, overlay.clone());
    let settings: TrainSettings = base.try_into().map_err(|source| SettingsError::BadValue {
        path: path.to_path_buf(),
        source: Box::new(source),
    })?;
    check_keys(&overlay, &toml::Value::try_from(&settings)?, "").map_err(|source| {
        SettingsError::UnknownKey {
            path: path.to_path_buf(),
            source,
        }
    })?;
    Ok(settings)
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

    /// An error and its causes, as `anyhow` prints them with `{:#}`.
    fn chain(e: &dyn std::error::Error) -> String {
        let mut s = e.to_string();
        let mut cause = e.source();
        while let Some(c) = cause {
            s.push_str(&format!(": {c}"));
            cause = c.source();
        }
        s
    }

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
        assert_eq!(s.run.ddpg.target, TargetUpdate::Polyak { tau: 0.01 });
        let copy = dir.join("copy.toml");
        std::fs::write(&copy, "[run.ddpg.target.copy]\nevery = 50\n").unwrap();
        let s = load(Some(&copy)).unwrap();
        assert_eq!(s.run.ddpg.target, TargetUpdate::Copy { every: 50 });
        let bad = dir.join("bad.toml");
        std::fs::write(&bad, "[run]\nupdates_per_stepp = 40\n").unwrap();
        let e = load(Some(&bad)).unwrap_err();
        assert!(chain(&e).contains("updates_per_stepp"), "{}", chain(&e));
        std::fs::write(&bad, "task = \"juggle\"\n").unwrap();
        assert!(load(Some(&bad)).is_err());
        let demo = dir.join("demo.toml");
        std::fs::write(&demo, "[start]\nscheme = \"along-demonstrations\"\n").unwrap();
        let s = load(Some(&demo)).unwrap();
        assert_eq!(
            s.start.scheme(),
            StartScheme::AlongDemonstrations {
                train_episode_steps: 50,
                demonstrations: 0,
            }
        );
        std::fs::write(
            &bad,
            "[start]\nscheme = \"mixture\"\nin_hand_probability = 1.5\n",
        )
        .unwrap();
        let e = load(Some(&bad)).unwrap().validate().unwrap_err();
        assert!(chain(&e).contains("in-hand probability"), "{}", chain(&e));
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
    fn every_setting_at_its_default_value_loads() {
        // A key written at its default (here the guard off) is a known key, not an unknown one.
        let dir = std::env::temp_dir().join(format!("dex-guard-zero-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("s.toml");
        std::fs::write(&path, "guard_episodes = 0\n").unwrap();
        assert_eq!(load(Some(&path)).unwrap().guard_episodes, 0);
        std::fs::write(&path, "guard_episodes = 500\n").unwrap();
        assert_eq!(load(Some(&path)).unwrap().guard_episodes, 500);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn unknown_keys_are_named_by_their_path() {
        let parsed = toml::Value::try_from(TrainSettings::default()).unwrap();
        let overlay: toml::Value = toml::from_str("[run]\nupdates_per_stepp = 40\n").unwrap();
        let e = check_keys(&overlay, &parsed, "").unwrap_err();
        assert_eq!(e.to_string(), "unknown setting `run.updates_per_stepp`");
        let known: toml::Value = toml::from_str("[run]\nupdates_per_step = 40\n").unwrap();
        assert!(check_keys(&known, &parsed, "").is_ok());
    }

    #[test]
    fn round_trips_through_toml() {
        let s = TrainSettings::default();
        let text = s.to_toml().unwrap();
        let back: TrainSettings = toml::from_str(&text).unwrap();
        assert_eq!(back, s);
        for task in [TaskArg::Grasp, TaskArg::Stack, TaskArg::StackInHand] {
            let s = TrainSettings::for_task(task);
            let text = s.to_toml().unwrap();
            let back: TrainSettings = toml::from_str(&text).unwrap();
            assert_eq!(back, s, "{text}");
        }
    }

    /// The imitation seeds of the member runs of `task`'s default pipeline at pipeline seed `seed`,
    /// with their folders, in the order they enter the distillation's mean.
    fn member_seeds(task: TaskArg, seed: u64) -> Result<Vec<(String, u64)>, SettingsError> {
        let mut s = TrainSettings::for_task(task);
        s.seeds = vec![seed];
        s.validate()?;
        let e = s
            .clone
            .as_ref()
            .unwrap()
            .ensemble(&s, seed)
            .unwrap()
            .unwrap();
        assert_eq!(e.distil.seed, seed);
        Ok(e.members
            .iter()
            .map(|m| (m.folder.clone(), m.config.seed))
            .collect())
    }

    #[test]
    fn the_default_members_at_seed_one_are_the_shipped_recipes() {
        // experiments/stack-distil.sh: Stack's recipe at seeds 1-7, distilled at seed 1 over one
        // round of 400 episodes.
        let stack = member_seeds(TaskArg::Stack, 1).unwrap();
        let seeds: Vec<u64> = stack.iter().map(|m| m.1).collect();
        assert_eq!(seeds, (1..=7).collect::<Vec<_>>());
        let s = TrainSettings::for_task(TaskArg::Stack);
        assert_eq!(s.seeds, vec![1]);
        let e = s.clone.as_ref().unwrap().ensemble(&s, 1).unwrap().unwrap();
        assert_eq!((e.distil.rounds, e.distil.episodes_per_round), (1, 400));
        let recipe = ImitationConfig::for_task(Task::Stack);
        for m in &e.members {
            let c = &m.config;
            assert_eq!(
                (
                    c.dart_episodes,
                    c.in_hand_episodes,
                    c.bc.steps,
                    &c.bc.hidden
                ),
                (recipe.dart_episodes, 1600, 60_000, &vec![256, 256])
            );
            assert!(c.bc.features && !c.tuck_first && c.close_bursts == 0.0);
        }
        assert_eq!(
            e.distil.teacher_policies[0],
            PathBuf::from("runs/stack/clone/seed-1/default-s1/policy.dxpl")
        );
        // experiments/grasp-distil.sh: the default recipe's seeds 0-3, close bursts 0.02 at 0-1,
        // the teacher that tucks first at 0-1, in this order; distilled at seed 1 (round 1).
        let grasp = member_seeds(TaskArg::Grasp, 1).unwrap();
        let want: Vec<(String, u64)> = [
            ("default-s0", 0),
            ("default-s1", 1),
            ("default-s2", 2),
            ("default-s3", 3),
            ("close-bursts-s0", 0),
            ("close-bursts-s1", 1),
            ("tuck-first-s0", 0),
            ("tuck-first-s1", 1),
        ]
        .iter()
        .map(|&(f, k)| (f.to_owned(), k))
        .collect();
        assert_eq!(grasp, want);
        let s = TrainSettings::for_task(TaskArg::Grasp);
        let e = s.clone.as_ref().unwrap().ensemble(&s, 1).unwrap().unwrap();
        assert_eq!((e.distil.rounds, e.distil.episodes_per_round), (1, 400));
        let tweaks: Vec<(f32, bool)> = e
            .members
            .iter()
            .map(|m| (m.config.close_bursts, m.config.tuck_first))
            .collect();
        assert_eq!(tweaks[3], (0.0, false));
        assert_eq!(tweaks[5], (0.02, false));
        assert_eq!(tweaks[6], (0.0, true));
        // Other pipeline seeds: members of their own, none shared with seed 1's.
        let two = member_seeds(TaskArg::Stack, 2).unwrap();
        assert_eq!(two[0].1, 8);
        let two = member_seeds(TaskArg::Grasp, 2).unwrap();
        assert!(two.iter().all(|m| !grasp.contains(m)), "{two:?}");
        // Seed 0 would run negative member seeds.
        for task in [TaskArg::Grasp, TaskArg::Stack] {
            assert!(matches!(
                member_seeds(task, 0),
                Err(SettingsError::CloneMembers(
                    MembersError::NegativeSeed { .. }
                ))
            ));
        }
    }

    #[test]
    fn members_in_a_settings_file_and_their_refusals() {
        let dir = std::env::temp_dir().join(format!("dex-cfg-members-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("members.toml");
        let base = "task = \"grasp\"\nseeds = [1]\nfeatures = true\n[clone]\nbc_steps = 100\n\
                    distil_rounds = 2\n[[clone.members]]\nname = \"a\"\nseeds = [0, 1]\n\
                    [[clone.members]]\nname = \"b\"\nseeds = [0]\nclose_bursts = 0.02\n\
                    tuck_first = true\n";
        let load_with = |text: &str| {
            std::fs::write(&path, text).unwrap();
            load(Some(&path))
        };
        let s = load_with(base).unwrap();
        let stage = s.clone.as_ref().unwrap();
        assert_eq!(stage.members.len(), 2);
        assert_eq!(stage.members[1].close_bursts, Some(0.02));
        assert!(stage.members[1].tuck_first && !stage.members[0].tuck_first);
        s.validate().unwrap();
        let e = stage.ensemble(&s, 1).unwrap().unwrap();
        assert_eq!(e.members.len(), 3);
        assert_eq!(e.members[2].config.bc.steps, 100, "the stage's overrides");
        assert_eq!((e.distil.rounds, e.distil.episodes_per_round), (2, 400));
        // Written into the run folder and read back.
        let back: TrainSettings = toml::from_str(&s.to_toml().unwrap()).unwrap();
        assert_eq!(back, s);
        // A typo inside a member entry is an error.
        assert!(load_with(&base.replace("tuck_first", "tuck_frist")).is_err());
        let refused = |text: &str| load_with(text).unwrap().validate().unwrap_err();
        let members = |e: SettingsError| match e {
            SettingsError::CloneMembers(m) => m,
            other => panic!("{other}"),
        };
        assert!(matches!(
            members(refused(&base.replace("seeds = [0]", "seeds = []"))),
            MembersError::NoSeeds { .. }
        ));
        assert!(matches!(
            members(refused(
                &base.replace("distil_rounds = 2", "distil_rounds = 0")
            )),
            MembersError::NoDistilRounds
        ));
        assert!(matches!(
            members(refused(
                &base.replace("distil_rounds = 2", "distil_episodes_per_round = 0")
            )),
            MembersError::NoDistilEpisodes
        ));
        assert!(matches!(
            members(refused(&base.replace("seeds = [1]", "seeds = [1, 0]"))),
            MembersError::NegativeSeed {
                pipeline_seed: 0,
                ..
            }
        ));
        assert!(matches!(
            members(refused(&base.replace("name = \"b\"", "name = \"a\""))),
            MembersError::Duplicate { .. }
        ));
        // Distillation settings without members.
        let single = "task = \"grasp\"\nfeatures = true\n[clone]\ndistil_rounds = 1\n";
        assert!(matches!(
            members(refused(single)),
            MembersError::DistilWithoutMembers
        ));
        // Members and an init_policy: two starting points.
        let init = base.replace(
            "features = true\n",
            "features = true\ninit_policy = \"p.dxpl\"\n",
        );
        assert!(matches!(refused(&init), SettingsError::CloneAndInitPolicy));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
