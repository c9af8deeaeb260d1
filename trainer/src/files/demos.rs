//! Demonstrations as data: episodes of a demonstrator (the scripted one or an exported policy)
//! recorded transition by transition into a versioned, checksummed file under a run folder.
//!
//! Recording can inject noise into the *executed* action while storing the demonstrator's clean
//! action as the label (DART, Laskey et al. 2017): the data then covers states a little off the
//! demonstrator's path, each labelled with how the demonstrator recovers from it, which is what a
//! cloned policy meets when its own small errors compound. The executed action is kept too, so the
//! transitions are the environment's real `(s, a, r, s')` for an off-policy learner's demo buffer.
//!
//! File format: magic `DXDEMO02`; a `postcard` body of the JSON header ([`DemoHeader`]: task,
//! observation and action layout hash, sizes, how it was recorded; JSON because its settings keep
//! optional fields that a non-self-describing encoding cannot skip) and the rows as one f32 array,
//! per row `obs | label | executed | reward | next_obs | flags` (flags bit 0: last step of its
//! episode); finally a CRC-32 (ISO-HDLC, little-endian) of everything before it. Loading checks
//! all of it and names what does not match. Format 01 wrote the body by hand; postcard reads and
//! writes f32 arrays about as fast (`examples/format_spike.rs`, docs/benchmarks.md), and 01 files
//! are refused as written by an older version.

use std::path::Path;

use dex_runtime::features::{INPUT_MAX, policy_input};
use dex_runtime::interface::{ACT_DIM, ACTION_JOINTS, OBS_DIM, OBSERVATION_FIELDS};
use serde::{Deserialize, Serialize};

use crate::cell::policy_demo::{DemoSource, PolicyDemonstration};
use crate::env::scene::ARM_JOINTS;
use crate::env::{Demonstration, EnvConfig, EnvError, JacoEnv, Scene, Task};
use crate::evaluate::episode_seed;
use crate::learn::Rng;

pub use crate::files::record_settings::{CLOSE_BURST_STEPS, Keep, RecordMode, RecordSettings};

// Start seed of recorded demonstrations (`env::seeds::DEMO_SEED`, apart from the other ranges
// there), under its old path.
pub use crate::env::seeds::DEMO_SEED;

const MAGIC: &[u8; 8] = b"DXDEMO02";
/// Version of the demo file format written by this build.
pub const DEMO_FORMAT_VERSION: u32 = 2;

/// Everything between the magic and the checksum.
#[derive(Serialize, Deserialize)]
struct FileBody<'a> {
    header_json: std::borrow::Cow<'a, str>,
    rows: std::borrow::Cow<'a, [f32]>,
}
const ROW: usize = OBS_DIM + ACT_DIM + ACT_DIM + 1 + OBS_DIM + 1;

/// Why demonstrations could not be recorded, saved or loaded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DemoError {
    /// Reading or writing the file failed.
    #[error("demo file {path}: {source}")]
    Io {
        /// File involved.
        path: std::path::PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// The file is not a demo file, is truncated or damaged.
    #[error("demo file {path} is not usable: {why}")]
    Corrupt {
        /// File involved.
        path: std::path::PathBuf,
        /// What is wrong.
        why: String,
    },
    /// The file was recorded for something else than what it is used for.
    #[error("demo file {path} does not match: {why}")]
    Mismatch {
        /// File involved.
        path: std::path::PathBuf,
        /// What differs.
        why: String,
    },
    /// A recording setting is out of range.
    #[error("demo recording: {0}")]
    Settings(String),
    /// The simulation failed while recording.
    #[error("simulation: {0}")]
    Env(#[from] EnvError),
}

/// Header of a demo file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DemoHeader {
    /// Format version.
    pub version: u32,
    /// Task name (`grasp`, `stack-in-hand`, `stack`, `reach`).
    pub task: String,
    /// Observation and action layout hash of the runtime interface it was recorded with.
    pub layout_hash: u32,
    /// Observation width.
    pub obs_dim: usize,
    /// Action width.
    pub act_dim: usize,
    /// What demonstrated: `scripted` or `policy`.
    pub source: String,
    /// How it was recorded.
    pub settings: RecordSettings,
    /// Episodes tried and episodes that ended in success.
    pub tried: u32,
    /// Successful episodes among the tried ones.
    pub successes: u32,
    /// Episodes stored.
    pub episodes: u32,
    /// Environment steps simulated for the file (policy steps before a takeover and dropped
    /// episodes included): the data's cost in transitions.
    #[serde(default)]
    pub env_steps: u64,
}

/// One recorded transition.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DemoRow {
    /// Observation before the step.
    pub obs: [f32; OBS_DIM],
    /// The demonstrator's own action (the label for cloning).
    pub label: [f32; ACT_DIM],
    /// The action the environment executed (label plus noise, clipped to [-1, 1]).
    pub executed: [f32; ACT_DIM],
    /// Reward of the step under the task's own reward.
    pub reward: f32,
    /// Observation after the step.
    pub next_obs: [f32; OBS_DIM],
    /// Last step of its episode (a time limit: bootstrap through it).
    pub last: bool,
}

/// Recorded demonstrations: a header and the rows of every stored episode, in order.
#[derive(Debug, Clone, PartialEq)]
pub struct DemoSet {
    /// What and how.
    pub header: DemoHeader,
    /// The transitions.
    pub rows: Vec<DemoRow>,
}

/// The interface's observation and action layout hash (what a policy file of this build carries).
pub fn interface_layout_hash() -> u32 {
    dex_policy::layout_hash(
        OBSERVATION_FIELDS.iter().map(|f| (f.name, f.size)),
        ACTION_JOINTS.iter().map(|j| j.name),
    )
}

/// The command-line name of a task.
pub fn task_name(task: Task) -> &'static str {
    match task {
        Task::Grasp => "grasp",
        Task::StackInHand => "stack-in-hand",
        Task::Stack => "stack",
        Task::Reach => "reach",
    }
}

/// Records `settings.episodes` episodes of `source` (restarted per episode) on `scene`, calling
/// `on_episode` after each; the episodes `settings.keep` names are stored.
pub fn record(
    scene: &Scene,
    source: &DemoSource,
    settings: &RecordSettings,
    on_episode: &dyn Fn(),
) -> Result<DemoSet, DemoError> {
    record_with(scene, None, source, settings, on_episode)
}

/// [`record`] with a learned policy `lead` acting as `settings.mode` says (takeover or DAgger);
/// `source` labels.
pub fn record_with(
    scene: &Scene,
    lead: Option<&PolicyDemonstration>,
    source: &DemoSource,
    settings: &RecordSettings,
    on_episode: &dyn Fn(),
) -> Result<DemoSet, DemoError> {
    settings.validate()?;
    let mut lead = match (lead, settings.mode) {
        (_, RecordMode::Demonstrator) => None,
        (Some(p), _) => Some(p.clone()),
        (None, _) => {
            return Err(DemoError::Settings(format!(
                "{:?} recording needs a policy to act",
                settings.mode
            )));
        }
    };
    if settings.mode == RecordMode::Dagger && matches!(source, DemoSource::Scripted(_)) {
        return Err(DemoError::Settings(
            "DAgger needs a labeller whose action depends on the state alone (the Markov \
             demonstrator or a policy), not the phase machine"
                .into(),
        ));
    }
    let mut env_steps = 0u64;
    let config = EnvConfig::new(settings.task).with_reward(settings.row_reward());
    let mut env = JacoEnv::new(scene, config);
    let mut demo = source.clone();
    let mut rows = Vec::new();
    let mut stored = 0u32;
    let mut successes = 0u32;
    for i in 0..settings.episodes {
        let seed = episode_seed(settings.seed, u64::from(i));
        let mut noise = Rng::derive(seed, 0xDA27);
        // Its own stream, so recordings without bursts draw exactly what they drew before.
        let mut bursts = Rng::derive(seed, 0xB125);
        let mut burst_left = 0usize;
        let mut burst_value = 1.0f32;
        let mut obs = match settings.close_spacing {
            Some(m) => env.reset_close(seed, f64::from(m))?,
            None => env.reset(seed)?,
        };
        demo.restart();
        if let (Some(policy), RecordMode::Takeover { max_step }) = (lead.as_mut(), settings.mode) {
            let mut pick = Rng::derive(seed, 0x7A4E);
            let k = pick.below(max_step as usize + 1) as u32;
            policy.restart();
            for _ in 0..k {
                let a = policy.act(&env)?;
                env.step(&a)?;
                env_steps += 1;
            }
            if let DemoSource::Scripted(d) = &mut demo {
                d.restart_from_state(&env);
            }
            obs = env.begin_episode();
        }
        let mut episode = Vec::with_capacity(config.episode_steps as usize);
        loop {
            let label = demo.act(&env)?;
            let driven = match (lead.as_mut(), settings.mode) {
                (Some(policy), RecordMode::Dagger) => Some(policy.act(&env)?),
                _ => None,
            };
            let base = driven.unwrap_or(label);
            let mut executed: [f32; ACT_DIM] = std::array::from_fn(|j| {
                let sd = if j < ARM_JOINTS {
                    settings.arm_noise
                } else {
                    settings.finger_noise
                };
                let n = if sd > 0.0 { noise.normal(0.0, sd) } else { 0.0 };
                (base[j].clamp(-1.0, 1.0) + n).clamp(-1.0, 1.0)
            });
            let (close, open) = (
                f64::from(settings.close_bursts),
                f64::from(settings.open_bursts),
            );
            if close + open > 0.0 {
                if burst_left == 0 {
                    // One draw decides whether a burst starts and which (with open bursts off,
                    // the draws of a close-burst recording are unchanged).
                    let u = bursts.uniform_f64();
                    if u < close + open {
                        let (lo, hi) = CLOSE_BURST_STEPS;
                        burst_left = lo + bursts.below(hi - lo + 1);
                        burst_value = if u < close { 1.0 } else { -1.0 };
                    }
                }
                if burst_left > 0 {
                    burst_left -= 1;
                    executed[ARM_JOINTS..].fill(burst_value);
                }
            }
            let out = env.step(&executed)?;
            env_steps += 1;
            episode.push(DemoRow {
                obs,
                label: label.map(|a| a.clamp(-1.0, 1.0)),
                executed,
                reward: out.reward,
                next_obs: out.observation,
                last: out.done,
            });
            obs = out.observation;
            if out.done {
                successes += u32::from(out.success);
                if settings.keep.keeps(out.success) {
                    rows.extend(episode);
                    stored += 1;
                }
                break;
            }
        }
        on_episode();
    }
    Ok(DemoSet {
        header: DemoHeader {
            version: DEMO_FORMAT_VERSION,
            task: task_name(settings.task).to_owned(),
            layout_hash: interface_layout_hash(),
            obs_dim: OBS_DIM,
            act_dim: ACT_DIM,
            source: format!(
                "{}{}",
                match source {
                    DemoSource::Scripted(_) => "scripted",
                    DemoSource::Markov(m) if m.tuck_first() && m.tuck_ramp() => {
                        "markov (tuck first, tuck ramp)"
                    }
                    DemoSource::Markov(m) if m.tuck_first() => "markov (tuck first)",
                    DemoSource::Markov(m) if m.tuck_ramp() => "markov (tuck ramp)",
                    DemoSource::Markov(_) => "markov",
                    DemoSource::Policy(_) => "policy",
                    DemoSource::Ensemble(_) => "policy ensemble",
                    DemoSource::Pair(_) => "IBRL pair",
                },
                match settings.mode {
                    RecordMode::Demonstrator => "",
                    RecordMode::Takeover { .. } => ", taking over from a policy",
                    RecordMode::Dagger => ", labelling a policy's states (DAgger)",
                }
            ),
            settings: *settings,
            tried: settings.episodes,
            successes,
            episodes: stored,
            env_steps,
        },
        rows,
    })
}

impl DemoSet {
    /// The file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut rows = Vec::with_capacity(self.rows.len() * ROW);
        for r in &self.rows {
            rows.extend_from_slice(&r.obs);
            rows.extend_from_slice(&r.label);
            rows.extend_from_slice(&r.executed);
            rows.push(r.reward);
            rows.extend_from_slice(&r.next_obs);
            rows.push(if r.last { 1.0 } else { 0.0 });
        }
        let body = FileBody {
            // The header holds numbers, strings and enums: serialising it cannot fail.
            header_json: serde_json::to_string(&self.header)
                .unwrap_or_default()
                .into(),
            rows: rows.into(),
        };
        // Into a Vec postcard cannot fail (no buffer to fill, no unsupported type).
        let mut buf = postcard::to_extend(&body, MAGIC.to_vec()).unwrap_or_default();
        let crc = dex_policy::CRC32.checksum(&buf);
        buf.extend_from_slice(&crc.to_le_bytes());
        buf
    }

    /// Writes the file atomically and durably ([`crate::files::atomic_write::write_atomic`]), creating
    /// its folder if needed.
    pub fn save(&self, path: &Path) -> Result<(), DemoError> {
        let io = |source| DemoError::Io {
            path: path.to_owned(),
            source,
        };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
        crate::files::atomic_write::write_atomic(path, &self.to_bytes()).map_err(io)
    }

    /// Parses a file's bytes (`path` only names it in errors); checks magic, checksum, version,
    /// sizes and the layout hash of this build's interface.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, DemoError> {
        let corrupt = |why: &str| DemoError::Corrupt {
            path: path.to_owned(),
            why: why.to_owned(),
        };
        let mismatch = |why: String| DemoError::Mismatch {
            path: path.to_owned(),
            why,
        };
        if bytes.len() < MAGIC.len() + 4 || !bytes.starts_with(b"DXDEMO") {
            return Err(corrupt(
                "no demo-file magic (DXDEMO02) or shorter than a header",
            ));
        }
        if &bytes[..MAGIC.len()] != MAGIC {
            return Err(mismatch(format!(
                "format {} (this build reads {DEMO_FORMAT_VERSION:02}): record it again",
                String::from_utf8_lossy(&bytes[6..MAGIC.len()])
            )));
        }
        let (body, tail) = bytes.split_at(bytes.len() - 4);
        let stored = u32::from_le_bytes([tail[0], tail[1], tail[2], tail[3]]);
        if dex_policy::CRC32.checksum(body) != stored {
            return Err(corrupt("checksum mismatch (truncated or damaged)"));
        }
        let (file, rest) = postcard::take_from_bytes::<FileBody<'_>>(&body[MAGIC.len()..])
            .map_err(|e| corrupt(&format!("body: {e}")))?;
        if !rest.is_empty() {
            return Err(corrupt("trailing bytes after the rows"));
        }
        let header: DemoHeader = serde_json::from_str(&file.header_json)
            .map_err(|e| corrupt(&format!("header: {e}")))?;
        if header.version != DEMO_FORMAT_VERSION {
            return Err(mismatch(format!(
                "format version {} (this build reads {DEMO_FORMAT_VERSION})",
                header.version
            )));
        }
        if header.obs_dim != OBS_DIM
            || header.act_dim != ACT_DIM
            || header.layout_hash != interface_layout_hash()
        {
            return Err(mismatch(format!(
                "observation/action layout {}x{} hash {:#010x}, this build's is {OBS_DIM}x{ACT_DIM} hash {:#010x}",
                header.obs_dim,
                header.act_dim,
                header.layout_hash,
                interface_layout_hash()
            )));
        }
        if file.rows.len() % ROW != 0 {
            return Err(corrupt("row data is not a whole number of rows"));
        }
        let n = file.rows.len() / ROW;
        let mut vals = file.rows.iter().copied();
        let mut rows = Vec::with_capacity(n);
        let mut take = || vals.next().unwrap_or(f32::NAN);
        for _ in 0..n {
            let obs = std::array::from_fn(|_| take());
            let label = std::array::from_fn(|_| take());
            let executed = std::array::from_fn(|_| take());
            let reward = take();
            let next_obs = std::array::from_fn(|_| take());
            let last = take() != 0.0;
            rows.push(DemoRow {
                obs,
                label,
                executed,
                reward,
                next_obs,
                last,
            });
        }
        if rows.iter().any(|r| {
            r.obs.iter().chain(&r.next_obs).any(|v| !v.is_finite())
                || r.label
                    .iter()
                    .chain(&r.executed)
                    .any(|v| !(-1.0..=1.0).contains(v))
                || !r.reward.is_finite()
        }) {
            return Err(corrupt(
                "a row holds a non-finite value or an action outside [-1, 1]",
            ));
        }
        Ok(Self { header, rows })
    }

    /// Loads and checks a demo file.
    pub fn load(path: &Path) -> Result<Self, DemoError> {
        let bytes = std::fs::read(path).map_err(|source| DemoError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_bytes(&bytes, path)
    }

    /// The first `n` episodes (all if there are fewer), for data-size studies.
    pub fn first_episodes(&self, n: u32) -> DemoSet {
        let mut left = n;
        let mut rows = Vec::new();
        for r in &self.rows {
            if left == 0 {
                break;
            }
            rows.push(*r);
            if r.last {
                left -= 1;
            }
        }
        let mut header = self.header.clone();
        header.episodes = n.min(self.header.episodes);
        DemoSet { header, rows }
    }

    /// Checks that the file was recorded for `task`.
    pub fn check_task(&self, task: Task, path: &Path) -> Result<(), DemoError> {
        if self.header.task != task_name(task) {
            return Err(DemoError::Mismatch {
                path: path.to_owned(),
                why: format!(
                    "recorded for task {}, the run is for {}",
                    self.header.task,
                    task_name(task)
                ),
            });
        }
        Ok(())
    }
}

/// The transitions of `sets` as the learner's demonstration buffer for a run of `task` under
/// `reward`. Each set must be of `task` or one it learns from ([`Task::learns_from`]) and its rows
/// must carry `reward` ([`RecordSettings::row_reward`]: record with the reward the run trains with).
/// The critic learns from the executed actions; the cloning term targets the labels. With
/// `features` the observations carry the task features after them, as the run's networks take
/// them (`TrainSettings::features`).
pub fn demo_buffer(
    sets: &[(DemoSet, std::path::PathBuf)],
    task: Task,
    reward: crate::env::Reward,
    features: bool,
) -> Result<crate::learn::DemoBuffer, DemoError> {
    for (set, path) in sets {
        let recorded: Option<Task> = set.header.task.parse().ok();
        if !recorded.is_some_and(|t| task.learns_from(t)) {
            return Err(DemoError::Mismatch {
                path: path.clone(),
                why: format!(
                    "recorded for task {}, the run is for {}",
                    set.header.task,
                    task_name(task)
                ),
            });
        }
        let carried = set.header.settings.row_reward();
        if carried != reward {
            return Err(DemoError::Mismatch {
                path: path.clone(),
                why: format!(
                    "its rows carry the {carried:?} reward, the run trains with {reward:?} \
                     (record with `trainer demos --reward`)"
                ),
            });
        }
    }
    let all = || sets.iter().flat_map(|(s, _)| &s.rows);
    // With the task features, each row's observations as the networks take them (owned here,
    // borrowed by the rows below).
    let featured: Vec<([f32; INPUT_MAX], [f32; INPUT_MAX])> = if features {
        all()
            .map(|r| {
                let mut pair = ([0.0; INPUT_MAX], [0.0; INPUT_MAX]);
                policy_input(&r.obs, INPUT_MAX, &mut pair.0);
                policy_input(&r.next_obs, INPUT_MAX, &mut pair.1);
                pair
            })
            .collect()
    } else {
        Vec::new()
    };
    let rows: Vec<crate::learn::DemoTransition<'_>> = all()
        .enumerate()
        .map(|(i, r)| {
            let (obs, next_obs): (&[f32], &[f32]) = match featured.get(i) {
                Some((o, n)) => (o, n),
                None => (&r.obs, &r.next_obs),
            };
            crate::learn::DemoTransition {
                obs,
                executed: &r.executed,
                label: &r.label,
                reward: r.reward,
                next_obs,
                terminal: false,
            }
        })
        .collect();
    let dim = if features { INPUT_MAX } else { OBS_DIM };
    crate::learn::DemoBuffer::from_rows(dim, ACT_DIM, &rows)
        .map_err(|e| DemoError::Settings(e.to_string()))
}
