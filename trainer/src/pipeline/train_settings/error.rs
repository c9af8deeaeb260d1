//! Why settings could not be loaded, or are not valid.

use std::path::PathBuf;

use super::MAX_GUARD_EPISODES;
use crate::env::EnvError;
use crate::learn::LearnError;
use crate::pipeline::clone_members::MembersError;
use crate::pipeline::group_pg::GroupPgError;
use crate::pipeline::imitation::ImitationError;

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
    /// The policy-gradient stage's settings are out of range.
    #[error("invalid [pg] settings")]
    Pg(#[source] GroupPgError),
}

/// A key of a settings file that no setting has, by its dotted path (`run.updates_per_step`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown setting `{key}`")]
pub struct UnknownSetting {
    /// The dotted key path.
    pub key: String,
}
