//! What a run reports: evaluation records, live counters and the events streamed to the caller.

use super::*;

/// One evaluation, as written to the JSON-lines log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalRecord {
    /// Evaluation number (1, 2, ...).
    pub eval_index: u64,
    /// Training episodes finished (all workers).
    pub episodes: u64,
    /// Environment transitions (all workers).
    pub transitions: u64,
    /// Environment transitions of each worker.
    pub transitions_per_worker: Vec<u64>,
    /// Mini-batch updates applied (all workers).
    pub updates: u64,
    /// Training wall-clock time in seconds (summed over resumed runs).
    pub wall_s: f64,
    /// Mean undiscounted return of the evaluation episodes.
    pub mean_return: f64,
    /// Fraction of evaluation episodes ending in success.
    pub success_rate: f64,
    /// Mean return of the training episodes since the previous evaluation (with noise).
    pub train_return: f64,
    /// The worker that ran the evaluation.
    pub worker: usize,
    /// With [`super::RunConfig::ibrl`]: the share of the training steps since the previous
    /// evaluation on which the proposal's action was executed (this process's workers).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub proposal_share: Option<f64>,
}

impl EvalRecord {
    /// One JSON line (no trailing newline).
    pub fn to_json_line(&self) -> String {
        // Serialising plain numbers and vectors cannot fail.
        serde_json::to_string(self).unwrap_or_default()
    }
}

/// Live counters, reported about twice a second during [`Trainer::run`].
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct Progress {
    /// Environment transitions (all workers).
    pub transitions: u64,
    /// Environment transitions of each worker.
    pub transitions_per_worker: Vec<u64>,
    /// Updates applied.
    pub updates: u64,
    /// Training episodes finished.
    pub episodes: u64,
    /// Training wall-clock seconds (summed over resumed runs).
    pub wall_s: f64,
}

/// What [`Trainer::run`] streams to its caller (on the calling thread).
#[derive(Debug, Clone, Copy)]
pub enum Event<'a> {
    /// An evaluation finished.
    Eval(&'a EvalRecord),
    /// Periodic counters.
    Progress(&'a Progress),
}

/// What one [`Trainer::run`] call did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RunSummary {
    /// Evaluations of this call, in order.
    pub records: Vec<EvalRecord>,
    /// Counters at the end of the call (cumulative over the whole training).
    pub progress: Progress,
    /// True if the stop flag ended the call before the budget.
    pub stopped: bool,
}
