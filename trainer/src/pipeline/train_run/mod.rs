//! The training pipeline of a run folder (`trainer train`), front-end free: for each seed, train
//! with checkpoints (fresh or resumed), keep the best checkpoint on the selection starts, export the
//! selected policy, evaluate the file through the runtime, and at the end plot the folder.
//!
//! A front end turns its input into one [`TrainSettings`] value, makes a [`TrainPlan`] of it
//! (validated, start states built) and calls [`TrainPlan::train`]; progress arrives as
//! [`TrainEvent`]s, nothing is printed here.
//!
//! A run folder `OUT` holds `settings.toml`, `.lock` and per seed `seed-S/`: `checkpoint.bin`,
//! `settings.toml`, `eval.jsonl`, `best.json` + `best_actor.bin` (the selected checkpoint),
//! `demos.dxdm` (recorded demonstrations, when asked for), `policy.dxpl` and `final_eval.json`;
//! with a clone stage also `clone/seed-S/`: the clone's imitation run folder, or with members one
//! folder per member run (`NAME-sK`) and the distillation's (`distil`); with a policy-gradient
//! stage (`[pg]`) also `seed-S/pg/`, whose `policy.dxpl` is the seed's final file.

use std::borrow::Cow;
use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use dex_runtime::interface::ACT_DIM;

use crate::cell::jaco::JacoLearnEnv;
use crate::cell::policy_demo::{DemoSource, PolicyDemonstration};
use crate::env::{Demonstrator, EnvError, Scene, StartStates};
use crate::evaluate::{EvalError, EvalSettings, PolicyEval, evaluate_policy_file};
use crate::files::demos::DemoError;
use crate::files::export::{ExportError, ExportInfo, ObsNormalisation, export_actor};
use crate::learn::distributed::membership::RankChange;
use crate::learn::distributed::server::Server;
use crate::learn::distributed::worker::WorkerRank;
use crate::learn::distributed::{DistributedConfig, DistributedError, ExchangeStats, Transport};
use crate::learn::{DemoBuffer, EvalRecord, Event, LearnError, Progress, RunSummary, Trainer};
use crate::pipeline::imitation::{ImitationEvent, run_imitation};
use crate::pipeline::run_lock::{RunLock, RunLockError};
use crate::pipeline::run_plots::{RunPlotError, plot_run};
use crate::pipeline::train_settings::{SettingsError, TrainSettings};

mod demonstrations;
mod distributed;
mod guard;
mod members;
mod pg_stage;
mod run_log;
mod screen;
mod seed_export;
mod seed_run;
mod selection;

use demonstrations::demonstrations;
pub use distributed::ParameterServer;
pub use guard::GuardVerdict;
use guard::run_guard;
pub use pg_stage::{PG_DIR, START_FILE};
use run_log::truncate_log;
pub use screen::Screening;
pub use seed_export::{export_latest, export_selected};
use seed_run::train_seed;
use selection::select_best;
pub use selection::{BestPolicy, SELECTION_SEED, read_best};

/// Why a training run (or the export of one of its seeds) failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TrainRunError {
    /// The settings are not valid, or could not be written.
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// The clone stage (the imitation learner) failed.
    #[error("clone stage in {}", dir.display())]
    Clone {
        /// The stage's run folder.
        dir: PathBuf,
        /// Why.
        #[source]
        source: crate::pipeline::imitation::ImitationError,
    },
    /// A clone stage in a distributed run (not supported yet: clone first with `trainer imitate`,
    /// then start the distributed run from the file with `init_policy`).
    #[error(
        "the clone stage ([clone], --clone) does not run under --distributed yet: make the clone \
         with `trainer imitate` and start the run from it with --init-policy"
    )]
    CloneDistributed,
    /// `start.demonstrator_policy` could not be read.
    #[error("cannot read demonstrator policy {}", path.display())]
    DemonstratorRead {
        /// The policy file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// `start.demonstrator_policy` is not a usable policy file.
    #[error("demonstrator policy {}", path.display())]
    DemonstratorPolicy {
        /// The policy file.
        path: PathBuf,
        /// The cause.
        source: EvalError,
    },
    /// `start.demonstrator_policy` solves another task than the run's.
    #[error(
        "demonstrator policy {} solves {file:?}; the run learns {run:?}: its states would not be \
         along this task's demonstrations",
        path.display()
    )]
    DemonstratorTask {
        /// The policy file.
        path: PathBuf,
        /// Its task.
        file: dex_policy::Task,
        /// The run's task.
        run: dex_policy::Task,
    },
    /// `init_policy` could not be read.
    #[error("cannot read the initial policy {}", path.display())]
    InitRead {
        /// The policy file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// `init_policy` cannot start the run's actor.
    #[error("initial policy {}", path.display())]
    InitPolicy {
        /// The policy file.
        path: PathBuf,
        /// The cause.
        source: crate::files::policy_import::ImportError,
    },
    /// The start states could not be built.
    #[error("invalid [start] settings")]
    StartStates(#[source] EnvError),
    /// Another trainer works in the run folder.
    #[error(transparent)]
    Lock(#[from] RunLockError),
    /// A folder or file could not be created.
    #[error("cannot create {}", path.display())]
    Create {
        /// The folder or file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A file could not be opened.
    #[error("cannot open {}", path.display())]
    Open {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A file could not be written (put in place).
    #[error("cannot write {}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// Reading, writing or flushing a file or folder failed (the message is the system's).
    #[error("{error}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The cause.
        error: std::io::Error,
    },
    /// An evaluation record could not be appended to a seed's `eval.jsonl`.
    #[error("cannot append to eval.jsonl")]
    AppendLog {
        /// The log file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A seed's checkpoint exists and the run was not asked to resume.
    #[error("{} exists: add --resume to continue it, or choose another --out", path.display())]
    CheckpointExists {
        /// The checkpoint.
        path: PathBuf,
    },
    /// A seed's checkpoint could not be loaded to resume it.
    #[error("cannot resume from {}", path.display())]
    Resume {
        /// The checkpoint.
        path: PathBuf,
        /// The cause.
        source: LearnError,
    },
    /// The checkpoint was trained with other settings than the run's.
    #[error(
        "settings differ from the checkpoint's in {} (learner, task, reward, start scheme or \
         demonstrations); resume with the same settings",
        dir.display()
    )]
    SettingsDiffer {
        /// The seed's folder.
        dir: PathBuf,
    },
    /// A checkpoint could not be written.
    #[error("cannot write checkpoint {}", path.display())]
    SaveCheckpoint {
        /// The checkpoint.
        path: PathBuf,
        /// The cause.
        source: LearnError,
    },
    /// `best.json` does not parse.
    #[error("{} is damaged", path.display())]
    DamagedBest {
        /// The file.
        path: PathBuf,
        /// The parser's error.
        source: serde_json::Error,
    },
    /// `best_actor.bin` is not a whole number of `f32`s.
    #[error("{} is damaged (length {len})", path.display())]
    DamagedBestActor {
        /// The file.
        path: PathBuf,
        /// Its length in bytes.
        len: usize,
    },
    /// A record could not be written as JSON.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// A seed's `guard.json` is not the guard's verdict.
    #[error("{} is damaged (delete it to run the guard again)", path.display())]
    DamagedGuard {
        /// The file.
        path: PathBuf,
        /// Why it does not parse.
        source: serde_json::Error,
    },
    /// A seed's `failed_starts.json` is not a screening.
    #[error("{} is damaged (delete it to screen the starting policy again)", path.display())]
    DamagedScreening {
        /// The file.
        path: PathBuf,
        /// Why it does not parse.
        source: serde_json::Error,
    },
    /// The learner failed.
    #[error(transparent)]
    Learn(#[from] LearnError),
    /// Evaluating a policy file failed.
    #[error(transparent)]
    Eval(#[from] EvalError),
    /// Exporting the actor failed.
    #[error(transparent)]
    Export(#[from] ExportError),
    /// Loading or recording demonstrations failed.
    #[error(transparent)]
    Demos(#[from] DemoError),
    /// The policy-gradient stage failed.
    #[error("policy-gradient stage in {}", dir.display())]
    Pg {
        /// The stage's folder.
        dir: PathBuf,
        /// Why.
        #[source]
        source: crate::pipeline::group_pg::GroupPgError,
    },
    /// The seed's export is not the file its policy-gradient stage started from (the run was
    /// resumed with settings that changed the export).
    #[error(
        "the seed's export changed since its policy-gradient stage started in {}: delete that \
         folder to fine-tune the new export, or resume with the settings that made the old one",
        dir.display()
    )]
    PgStartChanged {
        /// The stage's folder.
        dir: PathBuf,
    },
    /// The settings do not go with a distributed run.
    #[error("not supported in a distributed run: {why}")]
    NotDistributable {
        /// What and why.
        why: &'static str,
    },
}

/// An [`TrainRunError::Io`] maker for `path`.
fn io_at(path: &Path) -> impl FnOnce(std::io::Error) -> TrainRunError + '_ {
    move |error| TrainRunError::Io {
        path: path.to_path_buf(),
        error,
    }
}

/// Writes a run-folder file with [`crate::files::atomic_write::write_atomic`] (atomic and durable);
/// a failure is a [`TrainRunError::Write`] of `path`.
/// How the pipeline runs a policy file on `episodes` starts from `seed` (selection, guard,
/// screening, final evaluation): the run's environment and evaluation threads, with the CAN
/// quantisation the controller's bus applies, without the envelope.
fn eval_settings(s: &TrainSettings, episodes: u32, seed: u64) -> EvalSettings {
    EvalSettings {
        env: s.reward.env_config(s.task.task()),
        episodes,
        seed,
        threads: s.eval_threads,
        can_quantisation: true,
        envelope: false,
    }
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<(), TrainRunError> {
    crate::files::atomic_write::write_atomic(path, bytes).map_err(|source| TrainRunError::Write {
        path: path.to_path_buf(),
        source,
    })
}

/// What a training run tells its front end, in order, on the calling thread.
#[derive(Debug)]
#[non_exhaustive]
pub enum TrainEvent<'a> {
    /// The run folder is locked and its `settings.toml` written; seeds follow.
    Started {
        /// The run's settings.
        settings: &'a TrainSettings,
    },
    /// A seed's clone stage starts (or resumes): the imitation learner into `dir`.
    CloneStarted {
        /// The seed.
        seed: u64,
        /// The stage's run folder (`OUT/clone/seed-S`).
        dir: &'a Path,
    },
    /// A seed's clone stage is an ensemble ([`crate::pipeline::clone_members`]): `members`
    /// imitation runs, `parallel` at a time, in folders of `dir`, then the distillation.
    EnsembleStarted {
        /// The seed.
        seed: u64,
        /// The stage's folder (`OUT/clone/seed-S`).
        dir: &'a Path,
        /// Member runs.
        members: usize,
        /// Member runs at a time.
        parallel: usize,
    },
    /// A member run starts (or resumes) in the stage's folder `member` (`NAME-sK`).
    MemberStarted {
        /// The pipeline seed.
        seed: u64,
        /// The member run's folder name.
        member: &'a str,
        /// Its seed.
        member_seed: u64,
    },
    /// Progress of a member run (the events of members running side by side interleave).
    Member {
        /// The pipeline seed.
        seed: u64,
        /// The member run's folder name.
        member: &'a str,
        /// What its imitation learner reports.
        event: ImitationEvent<'a>,
    },
    /// A member run is done; its file is one of the distillation's teachers.
    MemberDone {
        /// The pipeline seed.
        seed: u64,
        /// The member run's folder name.
        member: &'a str,
        /// Its policy file.
        policy: &'a Path,
    },
    /// The members are done: the distillation starts (or resumes) in `dir`; its progress
    /// arrives as [`TrainEvent::Clone`], its last round's file as [`TrainEvent::Cloned`].
    DistilStarted {
        /// The seed.
        seed: u64,
        /// Its folder (`OUT/clone/seed-S/distil`).
        dir: &'a Path,
        /// The members' files whose mean action teaches it.
        teachers: usize,
        /// Its DAgger rounds.
        rounds: u32,
    },
    /// Progress of a seed's clone stage (with members: of the distillation).
    Clone {
        /// The seed.
        seed: u64,
        /// What the imitation learner reports.
        event: ImitationEvent<'a>,
    },
    /// A seed's clone (with members: the distilled network) is made; its actor starts from
    /// `policy`.
    Cloned {
        /// The seed.
        seed: u64,
        /// The clone's policy file.
        policy: &'a Path,
    },
    /// A seed's starting policy is being run on the screening starts (`start.failed_starts`; none
    /// kept in its folder).
    ScreeningStarted {
        /// The seed.
        seed: u64,
        /// Starts to run.
        starts: u32,
    },
    /// A seed's starting policy was screened (`start.failed_starts`): training revisits the
    /// starts it failed.
    Screened {
        /// The seed.
        seed: u64,
        /// What the screening found.
        screening: &'a Screening,
        /// Probability that a training episode revisits one of the failed starts.
        probability: f64,
    },
    /// A seed's demonstrations are being recorded (none reusable in its folder).
    RecordingDemos {
        /// The seed.
        seed: u64,
        /// Markov-demonstrator episodes to record.
        episodes: u32,
        /// The demo file they go to.
        path: &'a Path,
    },
    /// A seed's demonstration buffer is in place.
    DemosLoaded {
        /// The seed.
        seed: u64,
        /// Demonstration transitions.
        transitions: usize,
        /// Fraction of each mini-batch drawn from them.
        fraction: f32,
    },
    /// A seed's training starts (or resumes).
    SeedStarted {
        /// The seed.
        seed: u64,
        /// The transition budget.
        budget: u64,
        /// The counters it starts from (non-zero when resumed).
        progress: &'a Progress,
    },
    /// An evaluation of the learner finished (already appended to `eval.jsonl`).
    Eval {
        /// The seed.
        seed: u64,
        /// The record.
        record: &'a EvalRecord,
    },
    /// Periodic counters of the learner.
    Progress {
        /// The seed.
        seed: u64,
        /// The counters.
        progress: &'a Progress,
    },
    /// The guard compared the selected policy with the one the run started from
    /// ([`TrainSettings::guard_episodes`]); the export follows its verdict.
    Guarded {
        /// The seed.
        seed: u64,
        /// The comparison and which policy ships.
        verdict: &'a GuardVerdict,
    },
    /// A checkpoint was evaluated on the selection starts.
    Selection {
        /// The seed.
        seed: u64,
        /// One line: transitions, success, starts, return, and whether it is the new best.
        line: String,
    },
    /// The stop flag was raised: the seed's checkpoint is saved and the run ends here.
    Stopped {
        /// The seed.
        seed: u64,
    },
    /// A seed's budget is trained; export and evaluation follow.
    Trained {
        /// The seed.
        seed: u64,
    },
    /// A seed's policy-gradient stage (`[pg]`) starts (or resumes) from its exported file, in
    /// `dir`; its final file arrives as a second [`TrainEvent::Exported`].
    PgStarted {
        /// The seed.
        seed: u64,
        /// The stage's folder (`OUT/seed-S/pg`).
        dir: &'a Path,
        /// Its iteration budget.
        iterations: u32,
    },
    /// An iteration of a seed's policy-gradient stage is done (checkpoint saved).
    PgIteration {
        /// The seed.
        seed: u64,
        /// What the iteration did.
        report: &'a crate::pipeline::group_pg::IterationReport,
        /// Episodes per group (for [`crate::pipeline::group_pg::IterationReport::line`]).
        replicates: u32,
    },
    /// A seed's policy is exported and evaluated through the runtime (after a policy-gradient
    /// stage: once for the export it starts from, once for its own file).
    Exported {
        /// The seed.
        seed: u64,
        /// The policy file.
        path: &'a Path,
        /// Its evaluation.
        eval: &'a PolicyEval,
    },
    /// A seed's `eval.jsonl` has malformed lines (skipped in the plots).
    MalformedLog {
        /// The seed's folder.
        dir: &'a Path,
        /// Malformed lines.
        lines: usize,
    },
    /// Every seed is done and the run folder is plotted.
    Plotted {
        /// The files written.
        files: &'a [PathBuf],
    },
    /// Every seed is done but the plots failed (the run itself succeeded).
    PlotFailed {
        /// Why.
        error: RunPlotError,
    },
}

/// A training run ready to go: validated settings and the start states they describe.
#[derive(Clone)]
pub struct TrainPlan {
    settings: TrainSettings,
    starts: StartStates<DemoSource>,
    /// The actor's starting point read from `init_policy`, when set.
    init_actor: Option<InitActor>,
}

/// The actor's starting point read from `init_policy`.
#[derive(Debug, Clone)]
enum InitActor {
    /// Normalisation folded into the first layer (raw observations).
    Folded(Vec<f32>),
    /// The file's layers and its normalisation, which the run keeps frozen.
    Normalised(crate::files::policy_import::NormalisedActor),
}

impl TrainPlan {
    /// Validates `settings` and builds the training start states (reading
    /// `start.demonstrator_policy` when set).
    pub fn new(settings: TrainSettings) -> Result<Self, TrainRunError> {
        settings.validate()?;
        let demo = match &settings.start.demonstrator_policy {
            None => DemoSource::Scripted(Demonstrator::new(settings.task.task())),
            Some(path) => {
                let bytes =
                    std::fs::read(path).map_err(|source| TrainRunError::DemonstratorRead {
                        path: path.clone(),
                        source,
                    })?;
                let (demo, task) = PolicyDemonstration::with_task(&bytes).map_err(|source| {
                    TrainRunError::DemonstratorPolicy {
                        path: path.clone(),
                        source,
                    }
                })?;
                let run = crate::files::export::task_code(settings.task.task());
                if task != run {
                    return Err(TrainRunError::DemonstratorTask {
                        path: path.clone(),
                        file: task,
                        run,
                    });
                }
                DemoSource::Policy(Box::new(demo))
            }
        };
        let starts =
            StartStates::new(settings.start.scheme(), demo).map_err(TrainRunError::StartStates)?;
        let init_actor = match &settings.init_policy {
            None => None,
            Some(path) => {
                let bytes = std::fs::read(path).map_err(|source| TrainRunError::InitRead {
                    path: path.clone(),
                    source,
                })?;
                // The file is the base of a residual actor, or the actor itself.
                let nets = crate::learn::ddpg::Networks::new(
                    &settings.run.ddpg.base(),
                    settings.input_dim(),
                    ACT_DIM,
                )?;
                let task = settings.task.task();
                let imported = if settings.run.obs_norm.frozen_from_init {
                    crate::files::policy_import::normalised_actor_from_policy(
                        &bytes,
                        task,
                        &nets.actor,
                    )
                    .map(InitActor::Normalised)
                } else {
                    crate::files::policy_import::actor_params_from_policy(&bytes, task, &nets.actor)
                        .map(InitActor::Folded)
                };
                Some(imported.map_err(|source| TrainRunError::InitPolicy {
                    path: path.clone(),
                    source,
                })?)
            }
        };
        Ok(TrainPlan {
            settings,
            starts,
            init_actor,
        })
    }

    /// The settings.
    pub fn settings(&self) -> &TrainSettings {
        &self.settings
    }

    /// The plan of seed `seed`: this one, or with a clone stage the same settings with the
    /// seed's clone as `init_policy`, made first (or found made: the imitation learner resumes its
    /// folder) in `OUT/clone/seed-S`; with `start.failed_starts`, training also revisits the
    /// starts its starting policy failed on the screening starts (`screen`). None: `stop` was
    /// raised during the clone stage's members.
    fn for_seed(
        &self,
        seed: u64,
        scene: &Scene,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(TrainEvent<'_>),
    ) -> Result<Option<Cow<'_, TrainPlan>>, TrainRunError> {
        let Some(plan) = self.with_clone(seed, scene, stop, on_event)? else {
            return Ok(None);
        };
        let s = &plan.settings;
        let Some(init) = s.init_policy.as_ref().filter(|_| s.start.failed_starts > 0) else {
            return Ok(Some(plan));
        };
        let dir = s.out.join(format!("seed-{seed}"));
        let screening = screen::screen(s, (seed, init), &dir, scene, on_event)?;
        let probability = s.start.failed_start_probability;
        on_event(TrainEvent::Screened {
            seed,
            screening: &screening,
            probability,
        });
        let mut plan = plan.into_owned();
        plan.starts = plan
            .starts
            .with_revisits(screening.revisits(probability))
            .map_err(TrainRunError::StartStates)?;
        Ok(Some(Cow::Owned(plan)))
    }

    /// [`TrainPlan::for_seed`]'s clone stage: one imitation run, or with members the ensemble
    /// and its distillation (`members`).
    fn with_clone(
        &self,
        seed: u64,
        scene: &Scene,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(TrainEvent<'_>),
    ) -> Result<Option<Cow<'_, TrainPlan>>, TrainRunError> {
        let Some(stage) = &self.settings.clone else {
            return Ok(Some(Cow::Borrowed(self)));
        };
        let dir = self.settings.out.join("clone").join(format!("seed-{seed}"));
        on_event(TrainEvent::CloneStarted { seed, dir: &dir });
        let ensemble = stage
            .ensemble(&self.settings, seed)
            .map_err(SettingsError::CloneMembers)?;
        let policy = match ensemble {
            Some(ensemble) => {
                let made =
                    members::run_ensemble(&ensemble, &self.settings, seed, scene, stop, on_event)?;
                let Some(policy) = made else {
                    return Ok(None);
                };
                policy
            }
            None => {
                let cfg = stage.imitation(&self.settings, seed);
                run_imitation(scene, &cfg, &dir, &mut |event| {
                    on_event(TrainEvent::Clone { seed, event });
                })
                .map_err(|source| TrainRunError::Clone {
                    dir: dir.clone(),
                    source,
                })?
                .policy
            }
        };
        on_event(TrainEvent::Cloned {
            seed,
            policy: &policy,
        });
        let mut settings = self.settings.clone();
        settings.clone = None;
        settings.init_policy = Some(policy);
        TrainPlan::new(settings).map(|p| Some(Cow::Owned(p)))
    }

    /// Trains every seed into the run folder until done or `stop` is raised, holding each seed
    /// folder's [`RunLock`] while it trains (so two jobs may train other seeds of one run, one per
    /// core, but never the same seed); a seed with a checkpoint is continued only when `resume` (and only
    /// with the checkpoint's settings). Returns whether every seed finished (false: stopped with
    /// checkpoints saved). Plots the folder at the end ([`TrainEvent::Plotted`]).
    pub fn train(
        &self,
        scene: &Scene,
        resume: bool,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(TrainEvent<'_>),
    ) -> Result<bool, TrainRunError> {
        let s = &self.settings;
        std::fs::create_dir_all(&s.out).map_err(|source| TrainRunError::Create {
            path: s.out.clone(),
            source,
        })?;
        write_file(&s.out.join("settings.toml"), s.to_toml()?.as_bytes())?;
        on_event(TrainEvent::Started { settings: s });
        for &seed in &s.seeds {
            let Some(plan) = self.for_seed(seed, scene, stop, on_event)? else {
                on_event(TrainEvent::Stopped { seed });
                return Ok(false);
            };
            if !train_seed(&plan, seed, scene, resume, stop, on_event, None)? {
                return Ok(false);
            }
            if !pg_stage::pg_seed(&plan.settings, seed, scene, stop, on_event)? {
                return Ok(false);
            }
        }
        plot_and_report(&s.out, on_event);
        Ok(true)
    }
}

/// [`TrainPlan::new`] then [`TrainPlan::train`].
pub fn train_runs(
    settings: TrainSettings,
    scene: &Scene,
    resume: bool,
    stop: &AtomicBool,
    on_event: &mut dyn FnMut(TrainEvent<'_>),
) -> Result<bool, TrainRunError> {
    TrainPlan::new(settings)?.train(scene, resume, stop, on_event)
}

/// Plots the run folder `out` and reports the files, or why the plots failed (the run itself
/// succeeded either way).
fn plot_and_report(out: &Path, on_event: &mut dyn FnMut(TrainEvent<'_>)) {
    let plotted = plot_run(out, &mut |dir, lines| {
        on_event(TrainEvent::MalformedLog { dir, lines });
    });
    match plotted {
        Ok(files) => on_event(TrainEvent::Plotted { files: &files }),
        Err(error) => on_event(TrainEvent::PlotFailed { error }),
    }
}
