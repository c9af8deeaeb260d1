//! How demonstrations are recorded: who acts, what noise the executed actions carry, which
//! episodes are kept. The settings travel in every demo file's header (JSON), so they read back
//! from files of earlier builds: the two booleans `successes_only` / `failures_only` that came
//! before [`Keep`] are still understood.

use serde::{Deserialize, Serialize};

use crate::env::Task;
use crate::files::demos::{DEMO_SEED, DemoError};

/// Which recorded episodes a file keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Keep {
    /// Every episode.
    All,
    /// Only the episodes that end in success (clean demonstrations, DART data).
    #[default]
    Successes,
    /// Only the episodes that end in failure (DAgger over a policy that mostly succeeds: its
    /// failed episodes hold the states the data lacks).
    Failures,
}

impl Keep {
    /// Whether an episode that ended with `success` is stored.
    pub fn keeps(self, success: bool) -> bool {
        match self {
            Keep::All => true,
            Keep::Successes => success,
            Keep::Failures => !success,
        }
    }
}

/// How demonstrations were (or are to be) recorded.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RecordSettingsFile")]
pub struct RecordSettings {
    /// Task (start states and success).
    pub task: Task,
    /// Episodes to record.
    pub episodes: u32,
    /// Episode `i` starts from `episode_seed(seed, i)`.
    pub seed: u64,
    /// Standard deviation of Gaussian noise added to the executed arm actions (0: none).
    pub arm_noise: f32,
    /// Standard deviation of the noise on the executed finger actions.
    pub finger_noise: f32,
    /// Close bursts (0: none): at each step where no burst runs, with this probability the
    /// executed finger actions are held fully closing (+1) for the next 3 to 8 steps, while the
    /// label stays the demonstrator's. The data then holds fingers closed early, away from the
    /// brick, with the demonstrator's way out (open and approach again): the state a clone that
    /// closes short of the brick is in (docs/experiments.md, "How the Grasp clone fails").
    #[serde(default, skip_serializing_if = "is_zero")]
    pub close_bursts: f32,
    /// Open bursts (0: none): as [`RecordSettings::close_bursts`] with the executed finger
    /// actions held fully opening (-1). Near brick 2 they undo a tucked finger, the state from
    /// which a teacher that tucks first ([`crate::env::MarkovDemonstrator::with_tuck_first`])
    /// holds the hand up until it is tucked again. A burst is a close burst with probability
    /// `close_bursts / (close_bursts + open_bursts)`.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub open_bursts: f32,
    /// Which episodes are stored.
    pub keep: Keep,
    /// Who drives the episodes (the demonstrator always labels).
    #[serde(default)]
    pub mode: RecordMode,
    /// Reward written into the rows (None: the task's own, [`Task::default_reward`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reward: Option<crate::env::Reward>,
    /// The episodes start with the bricks' centres at most this many metres apart
    /// ([`crate::env::JacoEnv::reset_close`]: the task's start draw, drawn again while they are
    /// farther apart), where the Stack files fail (docs/experiments.md, session 36). None: the
    /// task's own start draw.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub close_spacing: Option<f32>,
}

fn is_zero(v: &f32) -> bool {
    *v == 0.0
}

/// Shortest and longest close burst, in steps.
pub const CLOSE_BURST_STEPS: (usize, usize) = (3, 8);

/// What a header's settings may hold: today's fields and the booleans of earlier files.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RecordSettingsFile {
    task: Task,
    episodes: u32,
    seed: u64,
    arm_noise: f32,
    finger_noise: f32,
    #[serde(default)]
    close_bursts: f32,
    #[serde(default)]
    open_bursts: f32,
    #[serde(default)]
    keep: Option<Keep>,
    #[serde(default)]
    successes_only: Option<bool>,
    #[serde(default)]
    failures_only: Option<bool>,
    #[serde(default)]
    mode: RecordMode,
    #[serde(default)]
    reward: Option<crate::env::Reward>,
    #[serde(default)]
    close_spacing: Option<f32>,
}

impl TryFrom<RecordSettingsFile> for RecordSettings {
    type Error = String;

    fn try_from(f: RecordSettingsFile) -> Result<Self, String> {
        let old = (f.successes_only, f.failures_only);
        let keep = match (f.keep, old) {
            (Some(k), (None, None)) => k,
            (Some(_), _) => {
                return Err("settings hold both `keep` and the older successes_only / \
                            failures_only"
                    .into());
            }
            (None, (Some(true), Some(true))) => {
                return Err("successes_only and failures_only together keep no episode".into());
            }
            (None, (Some(true), _)) => Keep::Successes,
            (None, (_, Some(true))) => Keep::Failures,
            (None, (Some(false), _)) => Keep::All,
            (None, (None, _)) => return Err("missing field `keep`".into()),
        };
        Ok(Self {
            task: f.task,
            episodes: f.episodes,
            seed: f.seed,
            arm_noise: f.arm_noise,
            finger_noise: f.finger_noise,
            close_bursts: f.close_bursts,
            open_bursts: f.open_bursts,
            keep,
            mode: f.mode,
            reward: f.reward,
            close_spacing: f.close_spacing,
        })
    }
}

impl RecordSettings {
    /// 200 clean successful episodes of `task` from [`DEMO_SEED`].
    pub fn new(task: Task) -> Self {
        Self {
            task,
            episodes: 200,
            seed: DEMO_SEED,
            arm_noise: 0.0,
            finger_noise: 0.0,
            close_bursts: 0.0,
            open_bursts: 0.0,
            keep: Keep::Successes,
            mode: RecordMode::Demonstrator,
            reward: None,
            close_spacing: None,
        }
    }

    /// The reward the rows carry.
    pub fn row_reward(&self) -> crate::env::Reward {
        self.reward.unwrap_or(self.task.default_reward())
    }

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), DemoError> {
        if self.episodes == 0 {
            return Err(DemoError::Settings("episodes must be at least 1".into()));
        }
        for (name, v) in [
            ("arm noise", self.arm_noise),
            ("finger noise", self.finger_noise),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(DemoError::Settings(format!(
                    "{name} {v} is outside [0, 1] (a standard deviation in action units)"
                )));
            }
        }
        for (name, p) in [("close", self.close_bursts), ("open", self.open_bursts)] {
            if !(0.0..=0.5).contains(&p) {
                return Err(DemoError::Settings(format!(
                    "{name} bursts {p} is outside [0, 0.5] (a probability per step)"
                )));
            }
        }
        if let Some(m) = self.close_spacing {
            crate::env::random_start::check_close_spacing(f64::from(m))
                .map_err(|e| DemoError::Settings(e.to_string()))?;
        }
        Ok(())
    }
}

/// Who acts in a recorded episode; the demonstrator labels every recorded state either way.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RecordMode {
    /// The demonstrator acts (plus the recording noise).
    #[default]
    Demonstrator,
    /// A learned policy acts for `k` steps, `k` uniform in `0..=max_step`, then the demonstrator
    /// takes over from that state (a phase machine restarts in the phase that fits it) with a
    /// fresh step budget; only the demonstrator's part is recorded.
    Takeover {
        /// Last step at which the demonstrator may take over.
        max_step: u32,
    },
    /// DAgger (Ross et al. 2011): the learned policy acts for the whole episode, every state it
    /// visits is labelled with the demonstrator's action. Needs a demonstrator whose action depends
    /// on the state alone ([`crate::env::MarkovDemonstrator`]).
    Dagger,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn json_of(s: &RecordSettings) -> serde_json::Value {
        serde_json::to_value(s).unwrap()
    }

    #[test]
    fn settings_round_trip_through_json() {
        for keep in [Keep::All, Keep::Successes, Keep::Failures] {
            let s = RecordSettings {
                keep,
                close_bursts: 0.02,
                ..RecordSettings::new(Task::Stack)
            };
            let back: RecordSettings = serde_json::from_value(json_of(&s)).unwrap();
            assert_eq!(back, s);
        }
    }

    #[test]
    fn earlier_files_booleans_read_as_keep() {
        let mut v = json_of(&RecordSettings::new(Task::Grasp));
        let o = v.as_object_mut().unwrap();
        o.remove("keep");
        for (succ, fail, want) in [
            (Some(true), None, Keep::Successes),
            (Some(false), None, Keep::All),
            (Some(false), Some(true), Keep::Failures),
            (Some(true), Some(false), Keep::Successes),
        ] {
            let mut o = o.clone();
            if let Some(b) = succ {
                o.insert("successes_only".into(), b.into());
            }
            if let Some(b) = fail {
                o.insert("failures_only".into(), b.into());
            }
            let s: RecordSettings = serde_json::from_value(o.into()).unwrap();
            assert_eq!(s.keep, want, "{succ:?} {fail:?}");
            assert_eq!(s.close_bursts, 0.0);
        }
        let mut both = o.clone();
        both.insert("successes_only".into(), true.into());
        both.insert("failures_only".into(), true.into());
        let e = serde_json::from_value::<RecordSettings>(both.into()).unwrap_err();
        assert!(e.to_string().contains("keep no episode"), "{e}");
        let e = serde_json::from_value::<RecordSettings>(o.clone().into()).unwrap_err();
        assert!(e.to_string().contains("keep"), "{e}");
    }

    #[test]
    fn a_file_without_bursts_writes_no_burst_field() {
        let v = json_of(&RecordSettings::new(Task::Grasp));
        assert!(v.get("close_bursts").is_none() && v.get("open_bursts").is_none());
        assert_eq!(v["keep"], "successes");
    }

    #[test]
    fn burst_probability_out_of_range_is_refused() {
        for p in [-0.1, 0.6, f32::NAN] {
            let s = RecordSettings {
                close_bursts: p,
                ..RecordSettings::new(Task::Grasp)
            };
            assert!(s.validate().is_err(), "{p}");
            let s = RecordSettings {
                open_bursts: p,
                ..RecordSettings::new(Task::Grasp)
            };
            assert!(s.validate().is_err(), "{p}");
        }
    }
}
