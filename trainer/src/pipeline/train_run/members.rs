//! The clone stage of a seed with members ([`crate::pipeline::clone_members`]): the member
//! imitation runs side by side, then the distillation, whose last round's file starts the
//! fine-tune.
//!
//! Folders under `OUT/clone/seed-S`: one per member run (`NAME-sK`) and `distil`, each an
//! imitation run folder, so each resumes on its own (a finished run redoes nothing; a killed one
//! goes on from its last whole file). Before any of them starts, every folder that already holds
//! a run is checked against its settings, so a resumed stage with changed members or
//! distillation is refused before any work, like a changed single clone.
//!
//! The members run `eval_threads` at a time (one evaluation thread each; two on the two-core
//! machines the recipes were measured on): each is a function of its own settings only (its own
//! seed, start seeds and network), so which thread runs it and in what order changes no bit, and
//! the distillation takes their files in the settings' order, not the order they finished in.
//! Their events reach the front end on the calling thread. The teacher's files are named by
//! absolute paths in the distillation's settings, so a resume that spells `OUT` otherwise (or
//! runs from another folder) still matches them.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;

use super::*;
use crate::pipeline::clone_members::{DISTIL_FOLDER, Ensemble, member_policy};
use crate::pipeline::imitation::{
    ImitationConfig, ImitationError, ImitationSummary, check_run_folder,
};

/// An [`ImitationEvent`] that can cross threads.
enum OwnedEvent {
    /// [`ImitationEvent::Recording`].
    Recording { round: u32, episodes: u32 },
    /// [`ImitationEvent::Cloning`].
    Cloning { round: u32, steps: u64 },
    /// [`ImitationEvent::CloneStep`].
    CloneStep(u64, f32),
    /// [`ImitationEvent::Round`].
    Round(EvalRecord),
}

impl OwnedEvent {
    fn new(event: ImitationEvent<'_>) -> Self {
        match event {
            ImitationEvent::Recording { round, episodes } => {
                OwnedEvent::Recording { round, episodes }
            }
            ImitationEvent::Cloning { round, steps } => OwnedEvent::Cloning { round, steps },
            ImitationEvent::CloneStep(step, loss) => OwnedEvent::CloneStep(step, loss),
            ImitationEvent::Round(r) => OwnedEvent::Round(r.clone()),
        }
    }

    fn event(&self) -> ImitationEvent<'_> {
        match *self {
            OwnedEvent::Recording { round, episodes } => {
                ImitationEvent::Recording { round, episodes }
            }
            OwnedEvent::Cloning { round, steps } => ImitationEvent::Cloning { round, steps },
            OwnedEvent::CloneStep(step, loss) => ImitationEvent::CloneStep(step, loss),
            OwnedEvent::Round(ref r) => ImitationEvent::Round(r),
        }
    }
}

/// What a member thread tells the calling thread, by the member's index.
enum Message {
    /// The member's run starts (or resumes).
    Started(usize),
    /// Its progress.
    Event(usize, OwnedEvent),
    /// It ended.
    Done(usize, Result<ImitationSummary, ImitationError>),
}

/// Runs seed `seed`'s clone stage with members, `ensemble`, in `OUT/clone/seed-S`; returns the
/// distilled file that starts the fine-tune, or None when `stop` was raised (no member starts
/// after it; those running finish, the distillation does not start).
pub(super) fn run_ensemble(
    ensemble: &Ensemble,
    s: &TrainSettings,
    seed: u64,
    scene: &Scene,
    stop: &AtomicBool,
    on_event: &mut dyn FnMut(TrainEvent<'_>),
) -> Result<Option<PathBuf>, TrainRunError> {
    let stage = s.out.join("clone").join(format!("seed-{seed}"));
    std::fs::create_dir_all(&stage).map_err(|source| TrainRunError::Create {
        path: stage.clone(),
        source,
    })?;
    let abs = std::fs::canonicalize(&stage).map_err(io_at(&stage))?;
    let distil = ImitationConfig {
        teacher_policies: ensemble
            .members
            .iter()
            .map(|m| member_policy(&abs, &m.folder))
            .collect(),
        ..ensemble.distil.clone()
    };
    let distil_dir = abs.join(DISTIL_FOLDER);
    let clone_error = |dir: &Path| {
        let dir = dir.to_path_buf();
        move |source| TrainRunError::Clone { dir, source }
    };
    // Every folder against its settings before any run starts.
    for m in &ensemble.members {
        let dir = abs.join(&m.folder);
        check_run_folder(&m.config, &dir).map_err(clone_error(&dir))?;
    }
    check_run_folder(&distil, &distil_dir).map_err(clone_error(&distil_dir))?;
    let parallel = s.eval_threads.clamp(1, ensemble.members.len().max(1));
    on_event(TrainEvent::EnsembleStarted {
        seed,
        dir: &stage,
        members: ensemble.members.len(),
        parallel,
    });
    let results = run_members(
        ensemble,
        (&stage, &abs),
        parallel,
        seed,
        scene,
        stop,
        on_event,
    );
    let mut done = true;
    for (m, r) in ensemble.members.iter().zip(results) {
        match r {
            Some(Ok(_)) => {}
            Some(Err(source)) => {
                return Err(TrainRunError::Clone {
                    dir: stage.join(&m.folder),
                    source,
                });
            }
            None => done = false,
        }
    }
    if !done || stop.load(Ordering::SeqCst) {
        return Ok(None);
    }
    let dir = stage.join(DISTIL_FOLDER);
    on_event(TrainEvent::DistilStarted {
        seed,
        dir: &dir,
        teachers: distil.teacher_policies.len(),
        rounds: distil.rounds,
    });
    run_imitation(scene, &distil, &distil_dir, &mut |event| {
        on_event(TrainEvent::Clone { seed, event });
    })
    .map_err(clone_error(&dir))?;
    Ok(Some(ensemble.distilled_policy(&stage)))
}

/// Runs the members `parallel` at a time into their folders under `abs` (the stage's folder
/// `stage`, made absolute), forwarding their events to `on_event` on this thread; each member's
/// outcome by its index (None: not started, because `stop` was raised or another member failed).
fn run_members(
    ensemble: &Ensemble,
    (stage, abs): (&Path, &Path),
    parallel: usize,
    seed: u64,
    scene: &Scene,
    stop: &AtomicBool,
    on_event: &mut dyn FnMut(TrainEvent<'_>),
) -> Vec<Option<Result<ImitationSummary, ImitationError>>> {
    let runs = &ensemble.members;
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let mut results: Vec<Option<Result<ImitationSummary, ImitationError>>> =
        runs.iter().map(|_| None).collect();
    std::thread::scope(|scope| {
        let (tx, rx) = mpsc::channel::<Message>();
        for _ in 0..parallel {
            let tx = tx.clone();
            let (next, failed) = (&next, &failed);
            scope.spawn(move || {
                while !stop.load(Ordering::SeqCst) && !failed.load(Ordering::SeqCst) {
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    let Some(run) = runs.get(i) else { break };
                    // A send fails only when the calling thread is gone (it panicked).
                    let _ = tx.send(Message::Started(i));
                    let r = run_imitation(scene, &run.config, &abs.join(&run.folder), &mut |e| {
                        let _ = tx.send(Message::Event(i, OwnedEvent::new(e)));
                    });
                    if r.is_err() {
                        failed.store(true, Ordering::SeqCst);
                    }
                    let _ = tx.send(Message::Done(i, r));
                }
            });
        }
        drop(tx);
        for message in rx {
            match message {
                Message::Started(i) => on_event(TrainEvent::MemberStarted {
                    seed,
                    member: &runs[i].folder,
                    member_seed: runs[i].config.seed,
                }),
                Message::Event(i, e) => on_event(TrainEvent::Member {
                    seed,
                    member: &runs[i].folder,
                    event: e.event(),
                }),
                Message::Done(i, r) => {
                    if r.is_ok() {
                        on_event(TrainEvent::MemberDone {
                            seed,
                            member: &runs[i].folder,
                            policy: &member_policy(stage, &runs[i].folder),
                        });
                    }
                    results[i] = Some(r);
                }
            }
        }
    });
    results
}
