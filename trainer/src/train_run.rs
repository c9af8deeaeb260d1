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
//! `demos.dxdm` (recorded demonstrations, when asked for), `policy.dxpl` and `final_eval.json`.

use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use dex_runtime::interface::{ACT_DIM, OBS_DIM};

use crate::demos::DemoError;
use crate::env::{Demonstrator, EnvError, Scene, StartStates};
use crate::evaluate::{EvalError, EvalSettings, PolicyEval, evaluate_policy_file};
use crate::export::{ExportError, ExportInfo, ObsNormalisation, export_actor};
use crate::jaco::JacoLearnEnv;
use crate::learn::distributed::server::Server;
use crate::learn::distributed::worker::WorkerRank;
use crate::learn::distributed::{DistributedConfig, DistributedError, ExchangeStats, Transport};
use crate::learn::{DemoBuffer, EvalRecord, Event, LearnError, Progress, RunSummary, Trainer};
use crate::policy_demo::{DemoSource, PolicyDemonstration};
use crate::run_lock::{RunLock, RunLockError};
use crate::run_plots::{RunPlotError, plot_run};
use crate::train_settings::{SettingsError, TrainSettings};

/// Start seed of the checkpoint-selection evaluations: apart from the final evaluation's
/// (1,000,000) and from `trainer eval`'s default, so the final figure of a selected policy is not
/// biased by the selection.
pub const SELECTION_SEED: u64 = 2_000_000;

/// Why a training run (or the export of one of its seeds) failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TrainRunError {
    /// The settings are not valid, or could not be written.
    #[error(transparent)]
    Settings(#[from] SettingsError),
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

/// What a training run tells its front end, in order, on the calling thread.
#[derive(Debug)]
#[non_exhaustive]
pub enum TrainEvent<'a> {
    /// The run folder is locked and its `settings.toml` written; seeds follow.
    Started {
        /// The run's settings.
        settings: &'a TrainSettings,
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
    /// A seed's policy is exported and evaluated through the runtime.
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
                DemoSource::Policy(Box::new(
                    PolicyDemonstration::from_file_bytes(&bytes).map_err(|source| {
                        TrainRunError::DemonstratorPolicy {
                            path: path.clone(),
                            source,
                        }
                    })?,
                ))
            }
        };
        let starts =
            StartStates::new(settings.start.scheme(), demo).map_err(TrainRunError::StartStates)?;
        Ok(TrainPlan { settings, starts })
    }

    /// The settings.
    pub fn settings(&self) -> &TrainSettings {
        &self.settings
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
        write_atomic(&s.out.join("settings.toml"), s.to_toml()?.as_bytes())?;
        on_event(TrainEvent::Started { settings: s });
        for &seed in &s.seeds {
            if !train_seed(s, seed, scene, &self.starts, resume, stop, on_event, None)? {
                return Ok(false);
            }
        }
        plot_and_report(&s.out, on_event);
        Ok(true)
    }
}

/// Rank 0 of a distributed run as the pipeline drives it ([`TrainPlan::train_distributed`]).
pub trait ParameterServer {
    /// Serves the worker ranks until the run's transitions reach `until` (see
    /// [`Server::serve`]).
    fn serve(
        &mut self,
        trainer: &mut Trainer,
        until: u64,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(Event<'_>),
    ) -> Result<RunSummary, LearnError>;
    /// Tells the worker ranks the run is over.
    fn finish(&mut self) -> Result<(), LearnError>;
    /// The exchange counters (refused messages among them).
    fn stats(&self) -> ExchangeStats;
}

impl<T: Transport> ParameterServer for Server<'_, T> {
    fn serve(
        &mut self,
        trainer: &mut Trainer,
        until: u64,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(Event<'_>),
    ) -> Result<RunSummary, LearnError> {
        Server::serve(self, trainer, until, stop, on_event)
    }
    fn finish(&mut self) -> Result<(), LearnError> {
        Server::finish(self)
    }
    fn stats(&self) -> ExchangeStats {
        Server::stats(self)
    }
}

/// Refuses settings whose state is per process and would silently diverge across ranks.
fn check_distributable(s: &TrainSettings) -> Result<(), TrainRunError> {
    let no = |why| Err(TrainRunError::NotDistributable { why });
    if s.seeds.len() != 1 {
        return no("one seed per distributed run (start one run per seed)");
    }
    if s.run.obs_norm.enabled && !s.run.obs_norm.frozen_from_demos {
        return no("running observation statistics (use frozen statistics from demonstrations)");
    }
    if s.run.quantise.aware_from.is_some() {
        return no("quantisation-aware training (it starts at a rank-local transition count)");
    }
    Ok(())
}

impl TrainPlan {
    /// Rank 0 of a distributed run: the run folder's pipeline of [`TrainPlan::train`] (one seed),
    /// with `server` collecting the transitions and updates from the worker ranks instead of local
    /// threads. A lost rank ends the run with a checkpoint and the error. The exchange counters go
    /// to the seed folder's `distributed.json`.
    pub fn train_distributed(
        &self,
        scene: &Scene,
        resume: bool,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(TrainEvent<'_>),
        server: &mut dyn ParameterServer,
    ) -> Result<bool, TrainRunError> {
        let s = &self.settings;
        check_distributable(s)?;
        std::fs::create_dir_all(&s.out).map_err(|source| TrainRunError::Create {
            path: s.out.clone(),
            source,
        })?;
        write_atomic(&s.out.join("settings.toml"), s.to_toml()?.as_bytes())?;
        on_event(TrainEvent::Started { settings: s });
        let seed = s.seeds[0];
        let done = train_seed(
            s,
            seed,
            scene,
            &self.starts,
            resume,
            stop,
            on_event,
            Some(&mut *server),
        );
        let stats = server.stats();
        let dir = s.out.join(format!("seed-{seed}"));
        write_atomic(
            &dir.join("distributed.json"),
            serde_json::to_string(&stats)?.as_bytes(),
        )?;
        if !done? {
            server.finish()?;
            return Ok(false);
        }
        plot_and_report(&s.out, on_event);
        Ok(true)
    }

    /// A worker rank of a distributed run: W worker threads on this rank's environments, their
    /// updates exchanged with rank 0 through `transport`, until rank 0 ends the run. Writes
    /// nothing into the run folder; reads the demonstrations rank 0 recorded or was given.
    pub fn train_worker_rank<T: Transport>(
        &self,
        scene: &Scene,
        transport: &mut T,
        cfg: DistributedConfig,
        stop: &AtomicBool,
    ) -> Result<(ExchangeStats, Progress), TrainRunError> {
        let s = &self.settings;
        check_distributable(s)?;
        let seed = s.seeds[0];
        let dir = s.out.join(format!("seed-{seed}"));
        let mut run = s.run.clone();
        run.seed = seed;
        // Each worker rank evaluates on its own episodes: together at the local run's rate.
        let ranks = transport.size().saturating_sub(1).max(1) as u64;
        run.eval.every_episodes = run.eval.every_episodes.saturating_mul(ranks);
        let mut trainer = Trainer::new(run, OBS_DIM, ACT_DIM)?;
        let mut rank = WorkerRank::new(transport, cfg, &trainer)?;
        // After rank 0's state: it has recorded the demonstrations by then.
        if !rank.start(&mut trainer)? {
            return Ok((rank.stats(), trainer.progress()));
        }
        if let Some(d) = load_demonstrations(s, &dir)? {
            trainer.set_demonstrations(d)?;
        }
        let env_cfg = s.reward.env_config(s.task.task());
        let starts = &self.starts;
        let stats = rank.run(
            &mut trainer,
            |_| JacoLearnEnv::with_start_states(scene, env_cfg, starts.clone()),
            stop,
            &mut |_| {},
        )?;
        Ok((stats, trainer.progress()))
    }
}

/// The demonstrations of a worker rank: the files rank 0 uses (given, or recorded into the seed
/// folder by rank 0 before the ranks started).
fn load_demonstrations(s: &TrainSettings, dir: &Path) -> Result<Option<DemoBuffer>, TrainRunError> {
    use crate::demos::{DemoSet, demo_buffer};
    if !s.run.demos.uses_demos() {
        return Ok(None);
    }
    let env_cfg = s.reward.env_config(s.task.task());
    let paths = if s.demo_files.is_empty() {
        vec![dir.join("demos.dxdm")]
    } else {
        s.demo_files.clone()
    };
    let mut sets = Vec::new();
    for path in paths {
        sets.push((DemoSet::load(&path)?, path));
    }
    Ok(Some(demo_buffer(&sets, s.task.task(), env_cfg.reward)?))
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

/// Writes `bytes` to `path` atomically (temporary file, fsync, rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), TrainRunError> {
    let tmp = path.with_extension("tmp");
    {
        let mut f = std::fs::File::create(&tmp).map_err(|source| TrainRunError::Create {
            path: tmp.clone(),
            source,
        })?;
        f.write_all(bytes).map_err(io_at(&tmp))?;
        f.sync_all().map_err(io_at(&tmp))?;
    }
    std::fs::rename(&tmp, path).map_err(|source| TrainRunError::Write {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(())
}

/// The demonstration buffer of a seed's run: the settings' files, or `record_demos` episodes of
/// the Markov demonstrator recorded into the seed's folder (`demos.dxdm`, reused when there).
fn demonstrations(
    s: &TrainSettings,
    seed: u64,
    dir: &Path,
    scene: &Scene,
    on_event: &mut dyn FnMut(TrainEvent<'_>),
) -> Result<Option<DemoBuffer>, TrainRunError> {
    use crate::demos::{DEMO_SEED, DemoSet, RecordSettings, demo_buffer, record_with};
    if !s.run.demos.uses_demos() {
        return Ok(None);
    }
    let env_cfg = s.reward.env_config(s.task.task());
    let mut sets = Vec::new();
    for path in &s.demo_files {
        sets.push((DemoSet::load(path)?, path.clone()));
    }
    if sets.is_empty() {
        let path = dir.join("demos.dxdm");
        let want = RecordSettings {
            episodes: s.record_demos,
            seed: DEMO_SEED + 500_000 + seed,
            arm_noise: s.demo_noise,
            finger_noise: 0.5 * s.demo_noise,
            reward: Some(env_cfg.reward),
            ..RecordSettings::new(s.task.task())
        };
        let set = match DemoSet::load(&path) {
            Ok(set) if set.header.settings == want => set,
            _ => {
                on_event(TrainEvent::RecordingDemos {
                    seed,
                    episodes: want.episodes,
                    path: &path,
                });
                let source = DemoSource::Markov(crate::env::MarkovDemonstrator::new(s.task.task()));
                let set = record_with(scene, None, &source, &want, &|| {})?;
                set.save(&path)?;
                set
            }
        };
        sets.push((set, path));
    }
    Ok(Some(demo_buffer(&sets, s.task.task(), env_cfg.reward)?))
}

/// Trains one seed, holding its run lock, on local threads or (with `server`) on the worker
/// ranks of a distributed run; returns false if interrupted.
#[allow(clippy::too_many_arguments)]
fn train_seed(
    s: &TrainSettings,
    seed: u64,
    scene: &Scene,
    starts: &StartStates<DemoSource>,
    resume: bool,
    stop: &AtomicBool,
    on_event: &mut dyn FnMut(TrainEvent<'_>),
    mut server: Option<&mut dyn ParameterServer>,
) -> Result<bool, TrainRunError> {
    let dir = s.out.join(format!("seed-{seed}"));
    std::fs::create_dir_all(&dir).map_err(io_at(&dir))?;
    // Held until this seed is done: a second trainer on it is refused at once.
    let _lock = RunLock::acquire(&dir)?;
    let ckpt = dir.join("checkpoint.bin");
    let log_path = dir.join("eval.jsonl");
    let mut per_seed = s.clone();
    per_seed.seeds = vec![seed];
    per_seed.run.seed = seed;
    let mut trainer = if ckpt.exists() {
        if !resume {
            return Err(TrainRunError::CheckpointExists { path: ckpt });
        }
        let t = Trainer::load(&ckpt).map_err(|source| TrainRunError::Resume {
            path: ckpt.clone(),
            source,
        })?;
        let saved: Option<TrainSettings> = std::fs::read_to_string(dir.join("settings.toml"))
            .ok()
            .and_then(|t| toml::from_str(&t).ok());
        let same_env = saved.as_ref().is_none_or(|o| {
            (o.task, o.reward, &o.start) == (s.task, s.reward, &s.start)
                && (&o.demo_files, o.record_demos, o.demo_noise.to_bits())
                    == (&s.demo_files, s.record_demos, s.demo_noise.to_bits())
        });
        if t.config() != &per_seed.run || !same_env {
            return Err(TrainRunError::SettingsDiffer { dir });
        }
        // Records written after the checkpoint (a kill between the two) are dropped: the resumed
        // run writes them again.
        truncate_log(&log_path, t.progress().transitions)?;
        t
    } else {
        // A fresh run: nothing of an earlier one in this folder may be mistaken for its own.
        for stale in [
            &log_path,
            &dir.join("best.json"),
            &dir.join("best_actor.bin"),
        ] {
            let _ = std::fs::remove_file(stale);
        }
        Trainer::new(per_seed.run.clone(), OBS_DIM, ACT_DIM)?
    };
    if let Some(d) = demonstrations(s, seed, &dir, scene, on_event)? {
        on_event(TrainEvent::DemosLoaded {
            seed,
            transitions: d.len(),
            fraction: s.run.demos.fraction,
        });
        trainer.set_demonstrations(d)?;
    }
    write_atomic(&dir.join("settings.toml"), per_seed.to_toml()?.as_bytes())?;
    let mut log = OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .map_err(|source| TrainRunError::Open {
            path: log_path.clone(),
            source,
        })?;
    let env_cfg = s.reward.env_config(s.task.task());
    on_event(TrainEvent::SeedStarted {
        seed,
        budget: s.transitions,
        progress: &trainer.progress(),
    });
    loop {
        let done = trainer.progress().transitions;
        if done >= s.transitions {
            break;
        }
        let target = (done / s.checkpoint_every + 1) * s.checkpoint_every;
        let mut write_err = None;
        let mut forward = |ev: Event<'_>| match ev {
            Event::Eval(record) => {
                if let Err(e) = writeln!(log, "{}", record.to_json_line()) {
                    write_err = Some(e);
                }
                on_event(TrainEvent::Eval { seed, record });
            }
            Event::Progress(progress) => on_event(TrainEvent::Progress { seed, progress }),
        };
        let until = target.min(s.transitions);
        let summary = match server.as_deref_mut() {
            None => trainer.run(
                |_| JacoLearnEnv::with_start_states(scene, env_cfg, starts.clone()),
                until,
                stop,
                &mut forward,
            )?,
            Some(srv) => match srv.serve(&mut trainer, until, stop, &mut forward) {
                Ok(summary) => summary,
                Err(LearnError::Distributed(e @ DistributedError::RankLost { .. })) => {
                    // What the server holds is a consistent state: keep it, then fail.
                    let _ = log.flush();
                    trainer
                        .save(&ckpt)
                        .map_err(|source| TrainRunError::SaveCheckpoint {
                            path: ckpt.clone(),
                            source,
                        })?;
                    return Err(LearnError::Distributed(e).into());
                }
                Err(e) => return Err(e.into()),
            },
        };
        if let Some(source) = write_err {
            return Err(TrainRunError::AppendLog {
                path: log_path,
                source,
            });
        }
        log.flush().map_err(io_at(&log_path))?;
        // Selection before the checkpoint: a kill in between repeats this chunk on resume, which
        // reaches the same policy and the same selection (deterministic), so the exported file is
        // the uninterrupted run's.
        if !summary.stopped
            && let Some(line) = select_best(&trainer, s, seed, &dir, scene)?
        {
            on_event(TrainEvent::Selection { seed, line });
        }
        trainer
            .save(&ckpt)
            .map_err(|source| TrainRunError::SaveCheckpoint {
                path: ckpt.clone(),
                source,
            })?;
        if summary.stopped {
            on_event(TrainEvent::Stopped { seed });
            return Ok(false);
        }
    }
    if let Some(srv) = server {
        // The worker ranks stop before the export's evaluation takes the cores.
        srv.finish()?;
    }
    on_event(TrainEvent::Trained { seed });
    let out = dir.join("policy.dxpl");
    let eval = export_selected(&trainer, s, seed, &dir, &out, scene)?;
    on_event(TrainEvent::Exported {
        seed,
        path: &out,
        eval: &eval,
    });
    Ok(true)
}

/// Exports the policy of a seed's run folder `dir` (what `trainer train` exports and `trainer
/// export` writes again): the best checkpoint on the selection starts (`best_actor.bin`) when
/// there is one, else `trainer`'s current actor. Evaluates the file through the runtime on the
/// final-evaluation starts and writes it to `out` with the measured success in its provenance,
/// plus `final_eval.json` beside it.
pub fn export_selected(
    trainer: &Trainer,
    s: &TrainSettings,
    seed: u64,
    dir: &Path,
    out: &Path,
    scene: &Scene,
) -> Result<PolicyEval, TrainRunError> {
    match read_best(dir)? {
        Some((params, best)) => {
            let (net, _) = trainer.actor();
            export_and_evaluate(net, &params, None, best.transitions, s, seed, out, scene)
        }
        None => export_checkpoint_trainer(trainer, s, seed, out, scene),
    }
}

/// Exports the trainer's actor, evaluates the file through the runtime, and writes the file with the
/// measured success rate in its provenance, plus `final_eval.json`.
fn export_checkpoint_trainer(
    trainer: &Trainer,
    s: &TrainSettings,
    seed: u64,
    out: &Path,
    scene: &Scene,
) -> Result<PolicyEval, TrainRunError> {
    let (net, raw) = trainer.actor();
    // Quantisation-aware: the int8-grid weights the learner trained (no normaliser then).
    let grid;
    let params = if trainer.quantisation_aware() {
        grid = trainer.policy_params()?;
        &grid[..]
    } else {
        raw
    };
    let normaliser = trainer.obs_normalizer();
    let norm = normaliser.as_ref().map(|n| ObsNormalisation {
        mean: &n.mean,
        inv_std: &n.inv_std,
    });
    export_and_evaluate(
        net,
        params,
        norm,
        trainer.progress().transitions,
        s,
        seed,
        out,
        scene,
    )
}

/// Keeps the records of `eval.jsonl` up to `transitions` (those a checkpoint holds), rewriting the
/// file atomically when it has later ones.
fn truncate_log(path: &Path, transitions: u64) -> Result<(), TrainRunError> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(());
    };
    let keep: Vec<&str> = text
        .lines()
        .filter(|l| {
            serde_json::from_str::<serde_json::Value>(l)
                .ok()
                .and_then(|v| v["transitions"].as_u64())
                .is_some_and(|t| t <= transitions)
        })
        .collect();
    if keep.len() != text.lines().count() {
        let mut out = keep.join("\n");
        if !out.is_empty() {
            out.push('\n');
        }
        write_atomic(path, out.as_bytes())?;
    }
    Ok(())
}

/// The best checkpoint so far of a seed (`best.json` beside `best_actor.bin`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BestPolicy {
    /// Transitions of the checkpoint.
    pub transitions: u64,
    /// Its success rate on the selection starts.
    pub success_rate: f64,
    /// Its mean return there.
    pub mean_return: f64,
    /// Selection starts it was evaluated on.
    pub episodes: u32,
}

/// Evaluates the trainer's current policy on the selection starts and keeps it when it beats the
/// best so far (success rate, then mean return). Returns a line to print.
fn select_best(
    trainer: &Trainer,
    s: &TrainSettings,
    seed: u64,
    dir: &Path,
    scene: &Scene,
) -> Result<Option<String>, TrainRunError> {
    // A quantisation-aware run chooses among its quantised policies only: the exported policy is
    // then the one trained for int8.
    if s.select_best_episodes == 0
        || (s.run.quantise.aware_from.is_some() && !trainer.quantisation_aware())
    {
        return Ok(None);
    }
    let (net, _) = trainer.actor();
    // Normalisation folded into the first layer: the candidate stands alone.
    let params = trainer.policy_params()?;
    let info = ExportInfo {
        task: s.task.task(),
        seed,
        transitions: trainer.progress().transitions,
        success_rate: None,
        eval_episodes: 0,
    };
    let draft = export_actor(net, &params, None, &info)?;
    let settings = EvalSettings {
        env: s.reward.env_config(s.task.task()),
        episodes: s.select_best_episodes,
        seed: SELECTION_SEED,
        threads: s.eval_threads,
        can_quantisation: true,
        envelope: false,
    };
    let e = evaluate_policy_file(&draft, scene, &settings, &|| {})?;
    let now = BestPolicy {
        transitions: info.transitions,
        success_rate: e.success_rate(),
        mean_return: e.mean_return,
        episodes: e.episodes,
    };
    let best = read_best(dir)?.map(|(_, b)| b);
    let better =
        best.is_none_or(|b| (now.success_rate, now.mean_return) > (b.success_rate, b.mean_return));
    let line = format!(
        "selection at {} transitions: {:.0}% ({} starts), return {:.2}{}",
        now.transitions,
        now.success_rate * 100.0,
        now.episodes,
        now.mean_return,
        if better { " - new best" } else { "" }
    );
    if better {
        let bytes: Vec<u8> = params.iter().flat_map(|x| x.to_le_bytes()).collect();
        write_atomic(&dir.join("best_actor.bin"), &bytes)?;
        write_atomic(
            &dir.join("best.json"),
            serde_json::to_string(&now)?.as_bytes(),
        )?;
    }
    Ok(Some(line))
}

/// The best checkpoint of a seed's folder `dir`: its actor parameters (normalisation folded in)
/// and its record, if there is one.
pub fn read_best(dir: &Path) -> Result<Option<(Vec<f32>, BestPolicy)>, TrainRunError> {
    let (json, bin) = (dir.join("best.json"), dir.join("best_actor.bin"));
    if !json.exists() || !bin.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&json).map_err(io_at(&json))?;
    let best: BestPolicy =
        serde_json::from_str(&text).map_err(|source| TrainRunError::DamagedBest {
            path: json.clone(),
            source,
        })?;
    let bytes = std::fs::read(&bin).map_err(io_at(&bin))?;
    if bytes.len() % 4 != 0 {
        return Err(TrainRunError::DamagedBestActor {
            len: bytes.len(),
            path: bin,
        });
    }
    let params = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok(Some((params, best)))
}

/// Exports `params` of `net`, evaluates the file through the runtime on the final-evaluation
/// starts, and writes it with the measured success in its provenance, plus `final_eval.json`.
#[allow(clippy::too_many_arguments)]
fn export_and_evaluate(
    net: &crate::learn::nets::Mlp,
    params: &[f32],
    norm: Option<ObsNormalisation<'_>>,
    transitions: u64,
    s: &TrainSettings,
    seed: u64,
    out: &Path,
    scene: &Scene,
) -> Result<PolicyEval, TrainRunError> {
    let mut info = ExportInfo {
        task: s.task.task(),
        seed,
        transitions,
        success_rate: None,
        eval_episodes: 0,
    };
    let draft = export_actor(net, params, norm, &info)?;
    let settings = EvalSettings {
        env: s.reward.env_config(s.task.task()),
        episodes: s.final_eval_episodes,
        seed: 1_000_000,
        threads: s.eval_threads,
        can_quantisation: true,
        envelope: false,
    };
    let eval = evaluate_policy_file(&draft, scene, &settings, &|| {})?;
    info.success_rate = Some(eval.success_rate() as f32);
    info.eval_episodes = eval.episodes;
    write_atomic(out, &export_actor(net, params, norm, &info)?)?;
    let json = serde_json::json!({
        "policy": out.file_name().map(|n| n.to_string_lossy().to_string()),
        "episodes": eval.episodes,
        "successes": eval.successes,
        "success_rate": eval.success_rate(),
        "ci95": [eval.ci95.0, eval.ci95.1],
        "mean_return": eval.mean_return,
        "start_seed": settings.seed,
        "transitions": info.transitions,
    });
    if let Some(dir) = out.parent() {
        write_atomic(&dir.join("final_eval.json"), json.to_string().as_bytes())?;
    }
    Ok(eval)
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
