//! The exported policy file of a seed: the selected (or current) actor, evaluated through the
//! runtime, with `final_eval.json` beside it.

use super::*;

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
        seed: crate::env::seeds::EVAL_SEED,
        threads: s.eval_threads,
        can_quantisation: true,
        envelope: false,
    };
    let eval = evaluate_policy_file(&draft, scene, &settings, &|| {})?;
    info.success_rate = Some(eval.success_rate() as f32);
    info.eval_episodes = eval.episodes;
    write_file(out, &export_actor(net, params, norm, &info)?)?;
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
        write_file(&dir.join("final_eval.json"), json.to_string().as_bytes())?;
    }
    Ok(eval)
}
