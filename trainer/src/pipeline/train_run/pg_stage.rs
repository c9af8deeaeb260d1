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

/// Runs (or resumes: the stage's checkpoint refuses other settings, the iterations aside) the
/// stage of seed `seed` when the settings have one; returns false when `stop` was raised (the
/// checkpoint then holds every finished iteration).
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
    let settings = stage.group_pg(seed_dir.join("policy.dxpl"), seed);
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
        &mut |report| on_event(TrainEvent::PgIteration { seed, report }),
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
