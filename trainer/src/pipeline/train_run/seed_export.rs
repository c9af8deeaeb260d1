//! The exported policy file of a seed: the selected (or current) actor, or the policy the run
//! started from where the guard ([`super::guard`]) found it better, evaluated through the runtime,
//! with `final_eval.json` beside it.

use super::guard::{GuardVerdict, read_verdict};
use super::*;

/// The policy a seed's run folder exports when no guard intervenes: its network, parameters,
/// normaliser (none when folded) and transitions.
pub(super) struct Selected<'t> {
    net: &'t crate::learn::nets::Mlp,
    params: Cow<'t, [f32]>,
    normaliser: Option<crate::learn::norm::Normalizer>,
    /// Transitions of the checkpoint.
    pub transitions: u64,
}

impl Selected<'_> {
    /// The policy file, with `info`'s provenance.
    fn file(&self, info: &ExportInfo) -> Result<Vec<u8>, TrainRunError> {
        let norm = self.normaliser.as_ref().map(|n| ObsNormalisation {
            mean: &n.mean,
            inv_std: &n.inv_std,
        });
        Ok(export_actor(self.net, &self.params, norm, info)?)
    }

    /// The file before its final evaluation (no success in its provenance).
    pub(super) fn draft(&self, s: &TrainSettings, seed: u64) -> Result<Vec<u8>, TrainRunError> {
        self.file(&export_info(s, seed, self.transitions))
    }
}

fn export_info(s: &TrainSettings, seed: u64, transitions: u64) -> ExportInfo {
    ExportInfo {
        task: s.task.task(),
        seed,
        transitions,
        success_rate: None,
        eval_episodes: 0,
    }
}

/// What [`export_selected`] exports unless the guard keeps the starting policy: the best
/// checkpoint on the selection starts (`best_actor.bin`, normalisation folded in) when there is
/// one, else `trainer`'s current actor (quantisation-aware: the int8-grid weights it trained, no
/// normaliser then).
pub(super) fn selected<'t>(
    trainer: &'t Trainer,
    dir: &Path,
) -> Result<Selected<'t>, TrainRunError> {
    let (net, _) = trainer.actor();
    if let Some((params, best)) = read_best(dir)? {
        return Ok(Selected {
            net,
            params: Cow::Owned(params),
            normaliser: None,
            transitions: best.transitions,
        });
    }
    latest(trainer)
}

/// `trainer`'s current actor, whatever the selection chose (quantisation-aware: the int8-grid
/// weights it trained, no normaliser then).
fn latest(trainer: &Trainer) -> Result<Selected<'_>, TrainRunError> {
    let (net, raw) = trainer.actor();
    let params = if trainer.quantisation_aware() {
        Cow::Owned(trainer.policy_params()?)
    } else {
        Cow::Borrowed(raw)
    };
    Ok(Selected {
        net,
        params,
        normaliser: trainer.obs_normalizer(),
        transitions: trainer.progress().transitions,
    })
}

/// Exports the policy of a seed's run folder `dir` (what `trainer train` exports and `trainer
/// export` writes again): the selected policy ([`selected`]), or, where the folder's guard verdict
/// (`guard.json`, of this same selected checkpoint) says the policy the run started from solved
/// more of the guard's starts, that policy's file as it is. Evaluates the file through the runtime
/// on the final-evaluation starts and writes it to `out` (a selected policy with the measured
/// success in its provenance), plus `final_eval.json` beside it.
pub fn export_selected(
    trainer: &Trainer,
    s: &TrainSettings,
    seed: u64,
    dir: &Path,
    out: &Path,
    scene: &Scene,
) -> Result<PolicyEval, TrainRunError> {
    let chosen = selected(trainer, dir)?;
    let verdict = read_verdict(dir)?.filter(|v| v.selected_transitions == chosen.transitions);
    if let Some(v) = verdict.as_ref().filter(|v| v.ships_init) {
        return export_init(v, s, out, scene);
    }
    write_chosen(
        &chosen,
        s,
        seed,
        out,
        scene,
        Source::Selected,
        verdict.as_ref(),
    )
}

/// Evaluates `chosen` on the final-evaluation starts, writes it to `out` with the measured success
/// in its provenance, and the record of `source` beside it (with the guard's verdict, if any).
fn write_chosen(
    chosen: &Selected<'_>,
    s: &TrainSettings,
    seed: u64,
    out: &Path,
    scene: &Scene,
    source: Source,
    verdict: Option<&GuardVerdict>,
) -> Result<PolicyEval, TrainRunError> {
    let mut info = export_info(s, seed, chosen.transitions);
    let draft = chosen.file(&info)?;
    let eval = final_evaluation(&draft, s, scene)?;
    info.success_rate = Some(eval.success_rate() as f32);
    info.eval_episodes = eval.episodes;
    write_file(out, &chosen.file(&info)?)?;
    write_final_eval(out, &eval, chosen.transitions, source, verdict)?;
    Ok(eval)
}

/// Exports the latest checkpoint's actor of a seed's run folder (`trainer export --latest`), not
/// the selected one and whatever the guard decided: a run's policy at a point of its training, for
/// learning curves measured on many starts. Evaluated and written as [`export_selected`] does,
/// with `"source": "latest"`, its record in [`LATEST_EVAL_FILE`] beside `out`.
pub fn export_latest(
    trainer: &Trainer,
    s: &TrainSettings,
    seed: u64,
    out: &Path,
    scene: &Scene,
) -> Result<PolicyEval, TrainRunError> {
    write_chosen(&latest(trainer)?, s, seed, out, scene, Source::Latest, None)
}

/// The guard kept the starting policy: its file, unchanged, is the seed's policy.
fn export_init(
    v: &GuardVerdict,
    s: &TrainSettings,
    out: &Path,
    scene: &Scene,
) -> Result<PolicyEval, TrainRunError> {
    let bytes = std::fs::read(&v.init_policy).map_err(io_at(&v.init_policy))?;
    let eval = final_evaluation(&bytes, s, scene)?;
    write_file(out, &bytes)?;
    write_final_eval(out, &eval, 0, Source::InitPolicy, Some(v))?;
    Ok(eval)
}

/// `file` through the runtime on the final-evaluation starts.
pub(super) fn final_evaluation(
    file: &[u8],
    s: &TrainSettings,
    scene: &Scene,
) -> Result<PolicyEval, TrainRunError> {
    let settings = eval_settings(s, s.final_eval_episodes, crate::env::seeds::EVAL_SEED);
    Ok(evaluate_policy_file(file, scene, &settings, &|| {})?)
}

/// The evaluation record [`export_latest`] writes beside its file (`final_eval.json` stays the
/// record of the run's own export, which a latest checkpoint must not replace).
pub const LATEST_EVAL_FILE: &str = "final_eval-latest.json";

/// Which policy an export wrote: its `source` in the record, and the record's file name.
#[derive(Debug, Clone, Copy)]
pub(super) enum Source {
    /// The run's selected checkpoint.
    Selected,
    /// The policy the run started from (the guard kept it).
    InitPolicy,
    /// The latest checkpoint (`trainer export --latest`).
    Latest,
    /// The policy-gradient stage's last actor (`[pg]`, in its own folder).
    GroupPg,
}

impl Source {
    fn name(self) -> &'static str {
        match self {
            Source::Selected => "selected",
            Source::InitPolicy => "init_policy",
            Source::Latest => "latest",
            Source::GroupPg => "group_pg",
        }
    }

    /// `final_eval.json`, the record of the run's own export, or [`LATEST_EVAL_FILE`].
    fn record(self) -> &'static str {
        match self {
            Source::Latest => LATEST_EVAL_FILE,
            Source::Selected | Source::InitPolicy | Source::GroupPg => "final_eval.json",
        }
    }
}

/// The record of `source` beside `out`: the figures, which policy it is and the guard's verdict,
/// if any.
pub(super) fn write_final_eval(
    out: &Path,
    eval: &PolicyEval,
    transitions: u64,
    source: Source,
    guard: Option<&GuardVerdict>,
) -> Result<(), TrainRunError> {
    let mut json = serde_json::json!({
        "policy": out.file_name().map(|n| n.to_string_lossy().to_string()),
        "episodes": eval.episodes,
        "successes": eval.successes,
        "success_rate": eval.success_rate(),
        "ci95": [eval.ci95.0, eval.ci95.1],
        "mean_return": eval.mean_return,
        "start_seed": crate::env::seeds::EVAL_SEED,
        "transitions": transitions,
        "source": source.name(),
    });
    if let Some(v) = guard {
        json["guard"] = serde_json::to_value(v)?;
    }
    if let Some(dir) = out.parent() {
        write_file(&dir.join(source.record()), json.to_string().as_bytes())?;
    }
    Ok(())
}
