//! Checkpoint selection: the best policy so far on the selection starts (`best.json` beside
//! `best_actor.bin`).

use super::*;

/// Start seed of the checkpoint-selection evaluations (`dex_env::seeds`): apart from the final
/// evaluation's, so the final figure of a selected policy is not biased by the selection.
pub use crate::env::seeds::SELECTION_SEED;

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
pub(super) fn select_best(
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
    let settings = eval_settings(s, s.select_best_episodes, SELECTION_SEED);
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
        write_file(&dir.join("best_actor.bin"), &bytes)?;
        write_file(
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
