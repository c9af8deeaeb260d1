//! `trainer export --int8` as a library step: an exported f32 policy file becomes an int8 file
//! (format version 2) evaluated through the runtime. The CLI only reads and writes the files and
//! prints what this returns.
//!
//! Steps: calibration observations from the f32 policy's own episodes
//! ([`crate::files::export::calibration_observations`]); equalisation of the f32 weights
//! ([`crate::files::export::equalise_policy_file`], skipped for a file already on the int8 grid);
//! post-training quantisation; the int8 file's worst action error against the f32 file on
//! held-out observations of both; the int8 file's success over the run's evaluation starts, which
//! goes into its provenance.

use crate::env::{EnvConfig, Scene};
use crate::evaluate::{
    EvalSettings, PolicyEval, action_error, evaluate_policy_file, heldout_observations_of_both,
};
use crate::files::export::{
    ExportError, calibration_observations, equalise_policy_file, quantise_policy_file,
};

/// Held-out episodes per policy of the reported action error.
pub const HELDOUT_EPISODES: u32 = 10;

/// Action error (fraction of a joint's range) above which the int8 file is reported as not made
/// for int8 ([`Int8Export::needs_aware_training`]).
pub const INT8_ERROR_WARNING: f64 = 0.01;

/// What [`export_int8`] made and measured.
#[derive(Debug, Clone, PartialEq)]
pub struct Int8Export {
    /// The int8 policy file, its own success in the provenance.
    pub file: Vec<u8>,
    /// Calibration observations used.
    pub calibration: usize,
    /// The f32 weights were already on the int8 grid (quantisation-aware training): not
    /// equalised.
    pub on_grid: bool,
    /// The f32 function change of the equalisation (fraction of a joint's range).
    pub equalisation_change: f64,
    /// Held-out observations behind [`Int8Export::worst_error`].
    pub heldout: usize,
    /// Worst action error of the int8 file against the f32 file (fraction of a joint's range).
    pub worst_error: f64,
    /// The int8 file through the runtime on the evaluation starts.
    pub eval: PolicyEval,
}

impl Int8Export {
    /// Whether the error says the policy was not trained for int8 (over [`INT8_ERROR_WARNING`]).
    pub fn needs_aware_training(&self) -> bool {
        self.worst_error > INT8_ERROR_WARNING
    }
}

/// Quantises the f32 policy file `f32_file` for `env` (see the module docs); `eval` gives the
/// evaluation's starts and threads (its `env` is replaced by `env`).
pub fn export_int8(
    f32_file: &[u8],
    scene: &Scene,
    env: EnvConfig,
    eval: &EvalSettings,
) -> Result<Int8Export, ExportError> {
    let calibration = calibration_observations(f32_file, scene, env)?;
    // Equalised once; the draft (for the error and the evaluation) and the written file are
    // quantisations of the same weights.
    let eq = equalise_policy_file(f32_file, &calibration)?;
    let draft = quantise_policy_file(&eq.file, None)?;
    let heldout = heldout_observations_of_both(f32_file, &draft, scene, env, HELDOUT_EPISODES)?;
    let worst_error = action_error(f32_file, &draft, &heldout)?
        .iter()
        .copied()
        .fold(0.0, f64::max);
    let settings = EvalSettings { env, ..*eval };
    let e = evaluate_policy_file(&draft, scene, &settings, &|| {})?;
    let file = quantise_policy_file(&eq.file, Some((e.success_rate() as f32, e.episodes)))?;
    Ok(Int8Export {
        file,
        calibration: calibration.len(),
        on_grid: eq.on_grid,
        equalisation_change: eq.max_f32_change,
        heldout: heldout.len(),
        worst_error,
        eval: e,
    })
}
