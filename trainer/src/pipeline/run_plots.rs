//! Learning curves of run folders: the evaluation records of every seed (`seed-*/eval.jsonl`)
//! read back, and drawn as return and success plots (PNG and SVG) with [`crate::pipeline::plot`].

use std::path::{Path, PathBuf};

use crate::learn::EvalRecord;
use crate::pipeline::plot::{Condition, Mark, Metric, PlotError, XAxis, plot, read_eval_log};
use crate::pipeline::train_settings::TrainSettings;

/// Why a run folder could not be read or plotted.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RunPlotError {
    /// The run folder could not be listed.
    #[error("cannot read run folder {}", path.display())]
    ReadFolder {
        /// The run folder.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A seed's `eval.jsonl` could not be read (the message is the system's).
    #[error("{error}")]
    ReadLog {
        /// The log file.
        path: PathBuf,
        /// The cause.
        error: std::io::Error,
    },
    /// No seed of the folder has an evaluation record.
    #[error("no evaluations in {} (seed-*/eval.jsonl)", path.display())]
    NoEvaluations {
        /// The run folder.
        path: PathBuf,
    },
    /// Drawing failed.
    #[error(transparent)]
    Plot(#[from] PlotError),
}

/// What a run folder holds for its plots.
#[derive(Debug, Clone, PartialEq)]
pub struct RunRecords {
    /// The evaluation records of each seed with any, in folder-name order.
    pub seeds: Vec<Vec<EvalRecord>>,
    /// The run's `settings.toml`, when it is there and loads.
    pub settings: Option<TrainSettings>,
}

/// The evaluation records of every seed in a run folder (`seed-*/eval.jsonl`) and its settings.
/// `on_malformed(seed_dir, lines)` is told of each log with malformed lines (they are skipped).
pub fn read_run(
    run: &Path,
    on_malformed: &mut dyn FnMut(&Path, usize),
) -> Result<RunRecords, RunPlotError> {
    let mut seeds = Vec::new();
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(run)
        .map_err(|source| RunPlotError::ReadFolder {
            path: run.to_path_buf(),
            source,
        })?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.join("eval.jsonl").exists())
        .collect();
    dirs.sort();
    for d in &dirs {
        let log = d.join("eval.jsonl");
        let (records, bad) =
            read_eval_log(&log).map_err(|error| RunPlotError::ReadLog { path: log, error })?;
        if bad > 0 {
            on_malformed(d, bad);
        }
        if !records.is_empty() {
            seeds.push(records);
        }
    }
    if seeds.is_empty() {
        return Err(RunPlotError::NoEvaluations {
            path: run.to_path_buf(),
        });
    }
    let settings: Option<TrainSettings> = std::fs::read_to_string(run.join("settings.toml"))
        .ok()
        .and_then(|t| toml::from_str(&t).ok());
    Ok(RunRecords { seeds, settings })
}

/// Return and success plots (PNG + SVG) of `conditions` as `dir`/`prefix`return.* and
/// `dir`/`prefix`success.* (and `..._per_worker` too when `per_worker`), with `marks` (published
/// figures) drawn where their axes are.
pub fn plot_conditions(
    dir: &Path,
    prefix: &str,
    title: &str,
    conditions: &[Condition],
    marks: &[Mark],
    per_worker: bool,
) -> Result<Vec<PathBuf>, PlotError> {
    let mut files = Vec::new();
    let titled = |what: String| {
        if title.is_empty() {
            what
        } else {
            format!("{title}: {what}")
        }
    };
    let name_of = |suffix: &str| dir.join(format!("{prefix}{suffix}"));
    for (metric, name) in [
        (Metric::MeanReturn, "return"),
        (Metric::SuccessRate, "success"),
        (Metric::TrainReturn, "train_return"),
    ] {
        files.extend(plot(
            &name_of(name),
            &titled(format!("{name} against transitions")),
            conditions,
            marks,
            metric,
            XAxis::Total,
        )?);
        // Against wall-clock for the figures (a run folder's own plots keep to transitions).
        if !prefix.is_empty() && metric != Metric::TrainReturn {
            files.extend(plot(
                &name_of(&format!("{name}_wall")),
                &titled(format!("{name} against wall-clock")),
                conditions,
                marks,
                metric,
                XAxis::WallClock,
            )?);
        }
        if per_worker {
            files.extend(plot(
                &name_of(&format!("{name}_per_worker")),
                &titled(format!("{name} against transitions per worker")),
                conditions,
                marks,
                metric,
                XAxis::PerWorker,
            )?);
        }
    }
    Ok(files)
}

/// Learning curves of every seed in a run folder (`trainer plot`), drawn into the folder; returns
/// the files written. `on_malformed` as in [`read_run`].
pub fn plot_run(
    run: &Path,
    on_malformed: &mut dyn FnMut(&Path, usize),
) -> Result<Vec<PathBuf>, RunPlotError> {
    let RunRecords { seeds, settings } = read_run(run, on_malformed)?;
    let (label, workers) = match &settings {
        Some(s) => (
            format!(
                "{:?} {:?}, R={}, W={}",
                s.task, s.reward, s.run.updates_per_step, s.run.workers
            ),
            s.run.workers,
        ),
        None => (run.display().to_string(), 1),
    };
    let conditions = [Condition { label, seeds }];
    Ok(plot_conditions(run, "", "", &conditions, &[], workers > 1)?)
}
