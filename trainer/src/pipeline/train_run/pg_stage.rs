//! A seed's policy-gradient stage (`[pg]`): the seed's exported file fine-tuned by
//! [`crate::pipeline::group_pg`] in `OUT/seed-S/pg`, whose last actor is the seed's final file,
//! evaluated on the final-evaluation starts as the export is.

use std::sync::atomic::Ordering;

use super::seed_export::{Source, final_evaluation, write_final_eval};
use super::*;
use crate::pipeline::group_pg::run_until;

/// The stage's folder in a seed's folder (checkpoint, progress lines, `policy.dxpl`,
/// `final_eval.json`).
pub const PG_DIR: &str = "pg";

/// The copy of the seed's export that the stage fine-tunes, in its folder.
pub const START_FILE: &str = "start.dxpl";

/// Runs (or resumes: the stage's checkpoint refuses other settings, the iterations aside, and
/// the stage refuses an export other than the one it started from) the stage of seed `seed`
/// when the settings have one; returns false when `stop` was raised (the checkpoint then holds
/// every finished iteration).
pub(super) fn pg_seed(
    s: &TrainSettings,
    seed: u64,
    scene: &Scene,
    stop: &AtomicBool,
    on_event: &mut dyn FnMut(TrainEvent<'_>),
) -> Result<bool, TrainRunError> {
    let Some(stage) = &s.pg else {
        return Ok(true);
    };
    let seed_dir = s.out.join(format!("seed-{seed}"));
    let _lock = RunLock::acquire(&seed_dir)?;
    let dir = seed_dir.join(PG_DIR);
    // The stage fine-tunes a copy of the export it started from: a resumed run whose export has
    // changed since (more transitions) would otherwise mix two fine-tunes in one checkpoint.
    let export = seed_dir.join("policy.dxpl");
    let bytes = std::fs::read(&export).map_err(io_at(&export))?;
    let start = dir.join(START_FILE);
    match std::fs::read(&start) {
        Ok(kept) if kept != bytes => return Err(TrainRunError::PgStartChanged { dir }),
        Ok(_) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            std::fs::create_dir_all(&dir).map_err(io_at(&dir))?;
            write_file(&start, &bytes)?;
        }
        Err(e) => return Err(io_at(&start)(e)),
    }
    let settings = stage.group_pg(start, seed);
    on_event(TrainEvent::PgStarted {
        seed,
        dir: &dir,
        iterations: stage.iterations,
    });
    let file = run_until(
        &settings,
        scene,
        s.task.task(),
        &dir,
        s.eval_threads,
        stage.save_every,
        stop,
        &mut |report| {
            on_event(TrainEvent::PgIteration {
                seed,
                report,
                replicates: stage.replicates,
            });
        },
    )
    .map_err(|source| TrainRunError::Pg {
        dir: dir.clone(),
        source,
    })?;
    if stop.load(Ordering::SeqCst) {
        on_event(TrainEvent::Stopped { seed });
        return Ok(false);
    }
    let out = dir.join("policy.dxpl");
    let eval = final_evaluation(&file, s, scene)?;
    write_file(&out, &file)?;
    write_final_eval(&out, &eval, 0, Source::GroupPg, None)?;
    on_event(TrainEvent::Exported {
        seed,
        path: &out,
        eval: &eval,
    });
    Ok(true)
}
