//! Behaviour cloning of recorded demonstrations into a policy file: the demonstrations' observations
//! and labels go to [`crate::learn::bc::train_bc`], the cloned actor leaves through the exporter with
//! its fixed input scaling, and the file is evaluated through the runtime like every other policy.

use crate::env::Task;
use crate::files::demos::DemoSet;
use crate::files::export::{ExportError, ExportInfo, export_scaled_actor};
use crate::learn::LearnError;
use crate::learn::bc::{BcConfig, BcPolicy, train_bc};
use dex_runtime::features::{INPUT_MAX, task_features};
use dex_runtime::interface::{ACT_DIM, OBS_DIM};

/// Why cloning failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CloneError {
    /// No demonstration rows were given.
    #[error("no demonstration rows to clone")]
    NoRows,
    /// A demo set is of a task the policy's task does not learn from.
    #[error("demonstrations of task {found} given for a {wanted} policy")]
    TaskMismatch {
        /// Task of the policy.
        wanted: &'static str,
        /// Task of a demo set.
        found: String,
    },
    /// The learner refused the data or the settings.
    #[error("behaviour cloning: {0}")]
    Learn(#[from] LearnError),
    /// The exporter refused the actor.
    #[error("export: {0}")]
    Export(#[from] ExportError),
}

/// The observation and label rows of `sets` (each of `task` or a task it learns from,
/// [`Task::learns_from`]), flattened.
pub fn clone_rows(sets: &[DemoSet], task: Task) -> Result<(Vec<f32>, Vec<f32>), CloneError> {
    let once: Vec<(&DemoSet, u32)> = sets.iter().map(|s| (s, 1)).collect();
    clone_rows_repeated(&once, task)
}

/// [`clone_rows`] with each set's rows `count` times: the rows are copied `count` times into the
/// flat matrices (and their task features computed as often), which gives the uniform sampler
/// the weights an oversampled set needs. At the counts `trainer imitate` uses (a DAgger round's
/// 10-20 failed episodes, K = 5) that is a few percent of the data; a weighted sampler would avoid
/// the copies.
pub fn clone_rows_repeated(
    sets: &[(&DemoSet, u32)],
    task: Task,
) -> Result<(Vec<f32>, Vec<f32>), CloneError> {
    let wanted = crate::files::demos::task_name(task);
    let mut obs = Vec::new();
    let mut labels = Vec::new();
    for &(s, count) in sets {
        let fits = s
            .header
            .task
            .parse::<Task>()
            .is_ok_and(|t| task.learns_from(t));
        if !fits {
            return Err(CloneError::TaskMismatch {
                wanted,
                found: s.header.task.clone(),
            });
        }
        for _ in 0..count {
            for r in &s.rows {
                obs.extend_from_slice(&r.obs);
                labels.extend_from_slice(&r.label);
            }
        }
    }
    if obs.is_empty() {
        return Err(CloneError::NoRows);
    }
    Ok((obs, labels))
}

/// Clones `sets` for `task` and exports the actor as a policy file (provenance: `cfg.seed`, the
/// number of demonstration transitions). Returns the cloned actor and the file.
pub fn clone_to_policy_file(
    sets: &[DemoSet],
    task: Task,
    cfg: &BcConfig,
    progress: &mut dyn FnMut(u64, f32),
) -> Result<(BcPolicy, Vec<u8>), CloneError> {
    let once: Vec<(&DemoSet, u32)> = sets.iter().map(|s| (s, 1)).collect();
    clone_repeated_to_policy_file(&once, task, cfg, progress)
}

/// [`clone_to_policy_file`] with each set's rows counted `count` times in the cloning data
/// ([`clone_rows_repeated`]); the file's provenance counts each transition once.
pub fn clone_repeated_to_policy_file(
    sets: &[(&DemoSet, u32)],
    task: Task,
    cfg: &BcConfig,
    progress: &mut dyn FnMut(u64, f32),
) -> Result<(BcPolicy, Vec<u8>), CloneError> {
    let (obs, labels) = clone_rows_repeated(sets, task)?;
    let transitions = sets.iter().map(|(s, _)| s.rows.len() as u64).sum();
    let (inputs, dim) = if cfg.features {
        (with_features(&obs), INPUT_MAX)
    } else {
        (obs, OBS_DIM)
    };
    let policy = train_bc(&inputs, &labels, dim, ACT_DIM, cfg, progress)?;
    let info = ExportInfo {
        task,
        seed: cfg.seed,
        transitions,
        success_rate: None,
        eval_episodes: 0,
    };
    let file = export_scaled_actor(&policy.actor, &policy.params, &policy.scaling, &info)?;
    Ok((policy, file))
}

/// Observation rows (`OBS_DIM` wide) with the runtime's task features appended to each
/// (`INPUT_MAX` wide), as the controller feeds a policy that takes them.
pub fn with_features(obs: &[f32]) -> Vec<f32> {
    let mut out = Vec::with_capacity(obs.len() / OBS_DIM * INPUT_MAX);
    for row in obs.chunks_exact(OBS_DIM) {
        let mut o = [0.0f32; OBS_DIM];
        o.copy_from_slice(row);
        out.extend_from_slice(&o);
        out.extend_from_slice(&task_features(&o));
    }
    out
}
