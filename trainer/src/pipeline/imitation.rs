//! The imitation learner: behaviour cloning of the Markov demonstrator, recorded clean and with
//! noise injected into the executed actions (DART, Laskey et al. 2017: states just off the
//! demonstrator's path, labelled with its recovery), then optional DAgger rounds (Ross et al. 2011)
//! in which the cloned policy drives episodes and the demonstrator labels every state it visits.
//! After each round the policy is cloned again on all data so far, exported, and scored through the
//! runtime on fixed selection starts. The best round's file is the run's policy.
//!
//! Run folder: `settings.json` (the [`ImitationConfig`]), `demos-0.dxdm` and `demos-0-dart.dxdm`
//! (round 0: the demonstrator's own episodes, clean and noisy), `demos-R.dxdm` (DAgger round R),
//! `policy-R.dxpl`, `eval.jsonl` (one
//! [`EvalRecord`] per round: environment steps and BC gradient steps so far, wall-clock, success on
//! the selection starts) and `policy.dxpl` (the best round). Each file is written whole (demo files
//! atomically), so a killed run resumes at the first round whose policy is missing.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::cell::policy_demo::{DemoSource, PolicyDemonstration, PolicyEnsemble};
use crate::cell::proposal_pair::ProposalPair;
use crate::env::{MarkovDemonstrator, Scene, Task};
use crate::evaluate::{EvalError, EvalSettings, evaluate_policy_file};
use crate::files::atomic_write::write_atomic;
use crate::files::demos::{
    DEMO_SEED, DemoError, DemoSet, Keep, RecordMode, RecordSettings, record_with,
};
use crate::learn::EvalRecord;
use crate::learn::bc::BcConfig;
use crate::pipeline::cloning::{CloneError, clone_repeated_to_policy_file};
use crate::pipeline::rollout_teacher::{ROLLOUT_DEMOS, RolloutTeacher};
use crate::pipeline::self_imitation::{SELF_DEMOS, SelfImitation, executed_labels};

// Start seed of the per-round selection evaluation (`env::seeds::SELECTION_SEED`, checkpoint
// selection's seed), under its old path.
pub use crate::env::seeds::SELECTION_SEED;

/// Settings of an imitation run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ImitationConfig {
    /// Task.
    pub task: Task,
    /// Clean demonstrator episodes of round 0.
    pub demo_episodes: u32,
    /// Demonstrator episodes of round 0 recorded with noise on the executed actions (DART).
    pub dart_episodes: u32,
    /// DAgger rounds after round 0.
    pub rounds: u32,
    /// Policy episodes labelled per DAgger round.
    pub episodes_per_round: u32,
    /// DAgger rounds keep only the policy's failed episodes (of `episodes_per_round` tried): a
    /// clone that succeeds 97-99% of the time visits the states its data lacks mostly in those.
    pub dagger_failures_only: bool,
    /// Each DAgger round's episodes count this many times in the cloning data (oversampling: a
    /// few dozen failed episodes beside thousands of demonstrations).
    pub dagger_repeat: u32,
    /// Stack only: DART episodes started with brick 1 in the hand (StackInHand's starts), so the
    /// carrying and placing part of the task gets data of its own (0: none).
    pub in_hand_episodes: u32,
    /// DART episodes of round 0 started with the bricks' centres at most `close_spacing` apart
    /// ([`RecordSettings::close_spacing`]; 0: none), beside the DART episodes of the task's own
    /// start draw: more data where the Stack files fail (docs/experiments.md, session 36).
    #[serde(skip_serializing_if = "is_zero")]
    pub close_dart_episodes: u32,
    /// The close DART episodes' largest spacing of the bricks' centres, metres.
    #[serde(skip_serializing_if = "is_default_close_spacing")]
    pub close_spacing: f32,
    /// Noise (standard deviation) on the executed arm actions of the DART episodes, action units.
    pub arm_noise: f32,
    /// Noise on the executed finger actions of the DART episodes.
    pub finger_noise: f32,
    /// The Markov teacher tucks first ([`MarkovDemonstrator::with_tuck_first`]): it labels every
    /// recorded state (clean, DART and DAgger episodes) holding the hand up while a finger whose
    /// tip is over brick 2 is not yet tucked.
    pub tuck_first: bool,
    /// The Markov teacher's tuck is a ramp over the knuckle's gap to brick 2
    /// ([`MarkovDemonstrator::with_tuck_ramp`]) instead of a switch.
    pub tuck_ramp: bool,
    /// The teacher is the mean of these policy files of the task ([`PolicyEnsemble`]: clones of
    /// other seeds, say) instead of the Markov demonstrator: the run distils them into one
    /// network, recording and labelling every episode (clean, DART, DAgger) with their mean
    /// action. Empty: the Markov demonstrator.
    pub teacher_policies: Vec<PathBuf>,
    /// The teacher is an IBRL run's pair instead ([`ProposalPair`]: the seed folder of a
    /// `trainer train --ibrl` run; at each state the better-rated of its actor and its
    /// proposal): the run distils the pair into one network. None: not a pair.
    pub teacher_pair: Option<PathBuf>,
    /// Close bursts in the DART episodes ([`RecordSettings::close_bursts`]: the probability per
    /// step of holding the fingers closing for 3-8 steps; 0: none).
    pub close_bursts: f32,
    /// Open bursts in the DART episodes ([`RecordSettings::open_bursts`]; 0: none).
    pub open_bursts: f32,
    /// Success-filtered self-imitation ([`SelfImitation`]): a policy file's successful noisy
    /// episodes join round 0's data, labelled with their executed actions. None: off.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub self_imitation: Option<SelfImitation>,
    /// A rollout teacher ([`RolloutTeacher`]): the winning branches of a policy file's failed
    /// episodes join round 0's data. None: off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rollout_teacher: Option<RolloutTeacher>,
    /// Behaviour cloning settings (its seed is the run's seed).
    pub bc: BcConfig,
    /// Selection starts per round (0: keep the last round).
    pub select_episodes: u32,
    /// Seed of the run (demonstration starts, network initialisation, sampling).
    pub seed: u64,
    /// Threads of the selection evaluation.
    pub eval_threads: usize,
}

/// The close DART episodes' default largest spacing of the bricks' centres, metres: above every
/// failure of the shipped Stack file on session 36's samples (8.1-9.3 cm, one at 10.0).
pub const DEFAULT_CLOSE_SPACING: f32 = 0.095;

// A settings file without close DART episodes is the one written before they existed.
fn is_zero(v: &u32) -> bool {
    *v == 0
}

fn is_default_close_spacing(v: &f32) -> bool {
    *v == DEFAULT_CLOSE_SPACING
}

impl Default for ImitationConfig {
    /// Grasp; 200 clean and 400 DART demonstrations (noise 0.1 on the arm, 0.05 on the fingers);
    /// no DAgger rounds (they made the policy worse, docs/experiments.md "Imitation"); 30,000
    /// cloning steps of a 256-256 network (128-128, a 92 kB file, scored 93.7% against 96.3% on
    /// Grasp seed 0 over 1000 starts) that takes the controller's task features (session 14:
    /// Grasp 98.9% against 94.6-95.9% without them over the 1000 Table II starts); selection over
    /// 100 starts.
    fn default() -> Self {
        Self {
            task: Task::Grasp,
            demo_episodes: 200,
            dart_episodes: 400,
            in_hand_episodes: 0,
            close_dart_episodes: 0,
            close_spacing: DEFAULT_CLOSE_SPACING,
            rounds: 0,
            episodes_per_round: 50,
            dagger_failures_only: false,
            dagger_repeat: 1,
            arm_noise: 0.1,
            finger_noise: 0.05,
            close_bursts: 0.0,
            open_bursts: 0.0,
            tuck_first: false,
            tuck_ramp: false,
            teacher_policies: Vec::new(),
            teacher_pair: None,
            self_imitation: None,
            rollout_teacher: None,
            bc: BcConfig {
                steps: 30_000,
                features: true,
                ..BcConfig::default()
            },
            select_episodes: 100,
            seed: 0,
            eval_threads: 2,
        }
    }
}

impl ImitationConfig {
    /// The measured recipe for `task`: [`ImitationConfig::default`]'s for Grasp and StackInHand;
    /// for Reach 100 clean and 200 DART episodes and 10,000 cloning steps; for Stack 800 DART and 1600 in-hand episodes, 60,000 cloning steps with the learning
    /// rate annealed to 5% (390,000 environment steps, about 20 minutes on a loaded core; 90.5% and
    /// 91.0% over 200 starts for seeds 0 and 1, where the Grasp-sized default gives 38-57%).
    pub fn for_task(task: Task) -> Self {
        let base = Self {
            task,
            ..Self::default()
        };
        match task {
            Task::Stack => Self {
                dart_episodes: 800,
                in_hand_episodes: 1600,
                bc: BcConfig {
                    steps: 60_000,
                    final_lr_fraction: 0.05,
                    ..base.bc.clone()
                },
                ..base
            },
            // 50-step episodes and one phase: a fifth of the data and a third of the steps fit it
            // (100% over 200 starts for seeds 0-2 in about 70 s a seed on a loaded core).
            Task::Reach => Self {
                demo_episodes: 100,
                dart_episodes: 200,
                bc: BcConfig {
                    steps: 10_000,
                    ..base.bc.clone()
                },
                ..base
            },
            _ => base,
        }
    }

    /// Checks ranges.
    pub fn validate(&self) -> Result<(), ImitationError> {
        if self.demo_episodes == 0 {
            return Err(ImitationError::Settings(
                "demo_episodes must be at least 1".into(),
            ));
        }
        if self.in_hand_episodes > 0 && self.task != Task::Stack {
            return Err(ImitationError::Settings(
                "in_hand_episodes is for the Stack task (the others start in the hand or never hold)"
                    .into(),
            ));
        }
        crate::env::random_start::check_close_spacing(f64::from(self.close_spacing))
            .map_err(|e| ImitationError::Settings(format!("close_spacing: {e}")))?;
        if !(1..=100).contains(&self.dagger_repeat) {
            return Err(ImitationError::Settings(format!(
                "dagger_repeat {} is outside 1..=100",
                self.dagger_repeat
            )));
        }
        if self.teacher_pair.is_some() && !self.teacher_policies.is_empty() {
            return Err(ImitationError::Settings(
                "one teacher: teacher_pair or teacher_policies, not both".into(),
            ));
        }
        let by_policies = !self.teacher_policies.is_empty() || self.teacher_pair.is_some();
        if by_policies && (self.tuck_first || self.tuck_ramp) {
            return Err(ImitationError::Settings(
                "tuck_first and tuck_ramp change the Markov teacher; a run taught by policy files \
                 (teacher_policies, teacher_pair) has none"
                    .into(),
            ));
        }
        if self.rounds > 0 && self.episodes_per_round == 0 {
            return Err(ImitationError::Settings(
                "episodes_per_round must be at least 1 when there are DAgger rounds".into(),
            ));
        }
        if let Some(si) = &self.self_imitation {
            si.validate()?;
        }
        if let Some(rt) = &self.rollout_teacher {
            rt.validate()?;
        }
        self.bc
            .validate()
            .map_err(|e| ImitationError::Settings(e.to_string()))?;
        for r in self.recordings(0) {
            r.1.validate()?;
        }
        Ok(())
    }

    /// The files of round `round` and how each is recorded (round 0: the demonstrator's clean
    /// and DART episodes; then DAgger over the previous round's policy, without noise). Every set
    /// has its own start seeds.
    pub fn recordings(&self, round: u32) -> Vec<(String, RecordSettings)> {
        let seed = DEMO_SEED + self.seed * 1_000 + 10 * u64::from(round);
        let base = RecordSettings {
            task: self.task,
            episodes: self.episodes_per_round,
            seed,
            arm_noise: 0.0,
            finger_noise: 0.0,
            close_bursts: 0.0,
            open_bursts: 0.0,
            keep: if self.dagger_failures_only {
                Keep::Failures
            } else {
                Keep::All
            },
            mode: RecordMode::Dagger,
            reward: None,
            close_spacing: None,
        };
        if round > 0 {
            return vec![(format!("demos-{round}.dxdm"), base)];
        }
        let clean = RecordSettings {
            episodes: self.demo_episodes,
            keep: Keep::Successes,
            mode: RecordMode::Demonstrator,
            ..base
        };
        let dart = RecordSettings {
            episodes: self.dart_episodes,
            seed: seed + 1,
            arm_noise: self.arm_noise,
            finger_noise: self.finger_noise,
            close_bursts: self.close_bursts,
            open_bursts: self.open_bursts,
            ..clean
        };
        let in_hand = RecordSettings {
            task: Task::StackInHand,
            episodes: self.in_hand_episodes,
            seed: seed + 2,
            ..dart
        };
        let close = RecordSettings {
            episodes: self.close_dart_episodes,
            seed: seed + 3,
            close_spacing: Some(self.close_spacing),
            ..dart
        };
        let mut v = vec![("demos-0.dxdm".to_owned(), clean)];
        if self.dart_episodes > 0 {
            v.push(("demos-0-dart.dxdm".to_owned(), dart));
        }
        if self.in_hand_episodes > 0 {
            v.push(("demos-0-in-hand.dxdm".to_owned(), in_hand));
        }
        if self.close_dart_episodes > 0 {
            v.push(("demos-0-close.dxdm".to_owned(), close));
        }
        v
    }
}

/// Why an imitation run failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImitationError {
    /// A setting is out of range.
    #[error("imitation settings: {0}")]
    Settings(String),
    /// The run folder holds a run with other settings.
    #[error(
        "{0} holds a run with other settings (settings.json differs); use another folder or remove it"
    )]
    SettingsChanged(PathBuf),
    /// Reading or writing a run file failed.
    #[error("{path}: {source}")]
    Io {
        /// File involved.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// Recording or loading demonstrations failed.
    #[error(transparent)]
    Demos(#[from] DemoError),
    /// Cloning failed.
    #[error(transparent)]
    Clone(#[from] CloneError),
    /// Evaluating a policy file failed.
    #[error("evaluation: {0}")]
    Eval(#[from] EvalError),
    /// Another process works in the run folder.
    #[error(transparent)]
    Locked(#[from] crate::pipeline::run_lock::RunLockError),
}

/// What a run reports while it works.
#[derive(Debug, Clone, Copy)]
pub enum ImitationEvent<'a> {
    /// A round starts recording `episodes` episodes.
    Recording {
        /// Round number.
        round: u32,
        /// Episodes to record.
        episodes: u32,
    },
    /// Cloning started (`steps` gradient steps).
    Cloning {
        /// Round number.
        round: u32,
        /// Gradient steps.
        steps: u64,
    },
    /// Cloning progress: gradient step and recent loss.
    CloneStep(u64, f32),
    /// A round's policy was scored (or loaded from an earlier call).
    Round(&'a EvalRecord),
}

/// The outcome of a run.
#[derive(Debug, Clone, PartialEq)]
pub struct ImitationSummary {
    /// One record per round.
    pub records: Vec<EvalRecord>,
    /// Round whose policy is `policy.dxpl`.
    pub best_round: u32,
    /// Where it is.
    pub policy: PathBuf,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ImitationError + '_ {
    move |source| ImitationError::Io {
        path: path.to_owned(),
        source,
    }
}

/// The policy files of `cfg.teacher_policies` as one teacher, checked to be of the run's task
/// (None: the run's teacher is the Markov demonstrator).
fn teacher_ensemble(cfg: &ImitationConfig) -> Result<Option<PolicyEnsemble>, ImitationError> {
    if cfg.teacher_policies.is_empty() {
        return Ok(None);
    }
    let files = cfg
        .teacher_policies
        .iter()
        .map(|p| std::fs::read(p).map_err(io(p)))
        .collect::<Result<Vec<_>, _>>()?;
    let (ensemble, task) = PolicyEnsemble::from_files(&files)?;
    if task != crate::files::export::task_code(cfg.task) {
        return Err(ImitationError::Settings(format!(
            "teacher_policies are {task:?} policies; the run learns {}",
            crate::files::demos::task_name(cfg.task)
        )));
    }
    Ok(Some(ensemble))
}

/// The IBRL run of `cfg.teacher_pair` as the teacher, checked to be of the run's task.
fn teacher_pair(cfg: &ImitationConfig) -> Result<Option<ProposalPair>, ImitationError> {
    let Some(dir) = &cfg.teacher_pair else {
        return Ok(None);
    };
    let (pair, task) =
        ProposalPair::from_run(dir).map_err(|e| ImitationError::Settings(e.to_string()))?;
    if task.task() != cfg.task {
        return Err(ImitationError::Settings(format!(
            "teacher_pair {} is a {task:?} run; the run learns {}",
            dir.display(),
            crate::files::demos::task_name(cfg.task)
        )));
    }
    Ok(Some(pair))
}

/// Whether `dir` holds a run of `cfg` to resume (false: no settings there yet); a run with other
/// settings is [`ImitationError::SettingsChanged`]. Compared as settings, not text: a folder
/// written before a setting existed (it takes its default) still resumes. Reads only.
pub fn check_run_folder(cfg: &ImitationConfig, dir: &Path) -> Result<bool, ImitationError> {
    match std::fs::read_to_string(dir.join("settings.json")) {
        Ok(old) if serde_json::from_str::<ImitationConfig>(&old).ok().as_ref() != Some(cfg) => {
            Err(ImitationError::SettingsChanged(dir.to_owned()))
        }
        Ok(_) => Ok(true),
        Err(_) => Ok(false),
    }
}

/// One of round 0's extra sets: its file in the run folder, the episodes it tries, the times its
/// rows count, and how it is read back (or made, the first time) at a path.
type ExtraSet<'a> = (
    &'static str,
    u32,
    u32,
    Box<dyn Fn(&Path) -> Result<DemoSet, ImitationError> + 'a>,
);

/// Round 0's extra sets beyond the recordings: self-imitation (cloned with its executed actions)
/// and the rollout teacher's labels.
fn extra_sets<'a>(scene: &'a Scene, cfg: &'a ImitationConfig) -> Vec<ExtraSet<'a>> {
    let mut extras: Vec<ExtraSet<'a>> = Vec::new();
    if let Some(si) = &cfg.self_imitation {
        extras.push((
            SELF_DEMOS,
            si.episodes,
            si.repeat,
            Box::new(move |p| {
                Ok(executed_labels(
                    si.load_or_record(scene, cfg.task, cfg.seed, p)?,
                ))
            }),
        ));
    }
    if let Some(rt) = &cfg.rollout_teacher {
        extras.push((
            ROLLOUT_DEMOS,
            rt.episodes,
            rt.repeat,
            Box::new(move |p| rt.load_or_label(scene, cfg.task, cfg.seed, cfg.eval_threads, p)),
        ));
    }
    extras
}

/// Runs (or resumes) an imitation run in `dir`.
pub fn run_imitation(
    scene: &Scene,
    cfg: &ImitationConfig,
    dir: &Path,
    on_event: &mut dyn FnMut(ImitationEvent<'_>),
) -> Result<ImitationSummary, ImitationError> {
    cfg.validate()?;
    // Before the folder is touched: a teacher file that is missing or of another task leaves
    // nothing behind.
    let ensemble = teacher_ensemble(cfg)?;
    let pair = teacher_pair(cfg)?;
    if let Some(si) = &cfg.self_imitation {
        si.policy(cfg.task)?;
    }
    if let Some(rt) = &cfg.rollout_teacher {
        rt.policy_file(cfg.task)?;
    }
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    // Held until the run ends: a second run in this folder is refused at once.
    let _lock = crate::pipeline::run_lock::RunLock::acquire(dir)?;
    let settings_path = dir.join("settings.json");
    if !check_run_folder(cfg, dir)? {
        let settings = serde_json::to_string_pretty(cfg).unwrap_or_default();
        write_atomic(&settings_path, settings.as_bytes()).map_err(io(&settings_path))?;
    }
    let expert = |task| match (&ensemble, &pair) {
        (Some(e), _) => DemoSource::Ensemble(e.clone()),
        (None, Some(p)) => DemoSource::Pair(Box::new(p.clone())),
        (None, None) => DemoSource::Markov(
            MarkovDemonstrator::new(task)
                .with_tuck_first(cfg.tuck_first)
                .with_tuck_ramp(cfg.tuck_ramp),
        ),
    };
    let bc = BcConfig {
        seed: cfg.seed,
        ..cfg.bc.clone()
    };
    let eval = EvalSettings {
        env: crate::env::EnvConfig::new(cfg.task),
        episodes: cfg.select_episodes,
        seed: SELECTION_SEED,
        threads: cfg.eval_threads,
        can_quantisation: true,
        envelope: false,
    };
    let log_path = dir.join("eval.jsonl");
    let mut records: Vec<EvalRecord> = match std::fs::read_to_string(&log_path) {
        Ok(text) => text
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect(),
        Err(_) => Vec::new(),
    };
    // Each set with the times its rows count in the cloning data (a DAgger round's `dagger_repeat`).
    let mut sets: Vec<(DemoSet, u32)> = Vec::new();
    let mut policy: Option<Vec<u8>> = None;
    let (mut env_steps, mut bc_steps, mut tried) = (0u64, 0u64, 0u64);
    for round in 0..=cfg.rounds {
        let policy_path = dir.join(format!("policy-{round}.dxpl"));
        let started = Instant::now();
        for (name, rec) in cfg.recordings(round) {
            let demo_path = dir.join(name);
            let set = if demo_path.exists() {
                let s = DemoSet::load(&demo_path)?;
                s.check_task(rec.task, &demo_path)?;
                s
            } else {
                on_event(ImitationEvent::Recording {
                    round,
                    episodes: rec.episodes,
                });
                let lead = match &policy {
                    Some(bytes) if round > 0 => Some(PolicyDemonstration::from_file_bytes(bytes)?),
                    _ => None,
                };
                let s = record_with(scene, lead.as_ref(), &expert(rec.task), &rec, &|| {})?;
                s.save(&demo_path)?;
                s
            };
            env_steps += set.header.env_steps;
            tried += u64::from(set.header.tried);
            sets.push((set, if round > 0 { cfg.dagger_repeat } else { 1 }));
        }
        if round == 0 {
            for (name, episodes, repeat, load) in extra_sets(scene, cfg) {
                let path = dir.join(name);
                if !path.exists() {
                    on_event(ImitationEvent::Recording { round, episodes });
                }
                let set = load(&path)?;
                env_steps += set.header.env_steps;
                tried += u64::from(set.header.tried);
                sets.push((set, repeat));
            }
        }
        let file =
            if policy_path.exists() && records.iter().any(|r| r.eval_index == u64::from(round)) {
                std::fs::read(&policy_path).map_err(io(&policy_path))?
            } else {
                on_event(ImitationEvent::Cloning {
                    round,
                    steps: bc.steps,
                });
                let counted: Vec<(&DemoSet, u32)> = sets.iter().map(|(s, k)| (s, *k)).collect();
                let (_, file) =
                    clone_repeated_to_policy_file(&counted, cfg.task, &bc, &mut |step, loss| {
                        on_event(ImitationEvent::CloneStep(step, loss));
                    })?;
                write_atomic(&policy_path, &file).map_err(io(&policy_path))?;
                let (mean_return, success_rate) = if cfg.select_episodes > 0 {
                    let e = evaluate_policy_file(&file, scene, &eval, &|| {})?;
                    (e.mean_return, e.success_rate())
                } else {
                    (0.0, 0.0)
                };
                let prev_wall = records
                    .iter()
                    .rfind(|r| r.eval_index + 1 == u64::from(round))
                    .map_or(0.0, |r| r.wall_s);
                let rec = EvalRecord {
                    eval_index: u64::from(round),
                    episodes: tried,
                    transitions: env_steps,
                    transitions_per_worker: vec![env_steps],
                    updates: bc_steps + bc.steps,
                    wall_s: prev_wall + started.elapsed().as_secs_f64(),
                    mean_return,
                    success_rate,
                    train_return: 0.0,
                    worker: 0,
                    proposal_share: None,
                };
                records.retain(|r| r.eval_index != u64::from(round));
                records.push(rec);
                let mut log = String::new();
                for r in &records {
                    log.push_str(&r.to_json_line());
                    log.push('\n');
                }
                write_atomic(&log_path, log.as_bytes()).map_err(io(&log_path))?;
                file
            };
        bc_steps += bc.steps;
        if let Some(r) = records.iter().find(|r| r.eval_index == u64::from(round)) {
            on_event(ImitationEvent::Round(r));
        }
        policy = Some(file);
    }
    // The best round on the selection starts (the later one on ties: it saw more data).
    let best = records
        .iter()
        .filter(|r| r.eval_index <= u64::from(cfg.rounds))
        .max_by(|a, b| {
            a.success_rate
                .total_cmp(&b.success_rate)
                .then(a.eval_index.cmp(&b.eval_index))
        })
        .map_or(u64::from(cfg.rounds), |r| r.eval_index) as u32;
    let best_path = dir.join(format!("policy-{best}.dxpl"));
    let out = dir.join("policy.dxpl");
    let bytes = std::fs::read(&best_path).map_err(io(&best_path))?;
    // A resumed finished run leaves the file as it is.
    if std::fs::read(&out).ok().as_deref() != Some(&bytes[..]) {
        write_atomic(&out, &bytes).map_err(io(&out))?;
    }
    Ok(ImitationSummary {
        records,
        best_round: best,
        policy: out,
    })
}
