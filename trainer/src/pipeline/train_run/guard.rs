//! The guard of a run that starts from a policy (a clone stage or `init_policy`): before the export,
//! the selected policy and the starting one run on the same [`TrainSettings::guard_episodes`]
//! selection starts, and the starting policy is shipped when it solves more of them. The
//! checkpoint selection sees 30 starts, which cannot rank files at 97-100% success; the guard sees
//! enough to catch a fine-tune that lost what its clone had (docs/experiments.md, session 14:
//! Grasp 989 -> 978 of 1000, p = 0.007). The verdict is written to `guard.json` in the seed's
//! folder, so `trainer export` ships the same file again without re-evaluating.

use serde::{Deserialize, Serialize};

use super::seed_export::selected;
use super::*;
use crate::env::evaluate::episode_outcomes;
use crate::env::paired::Paired;

/// The guard's verdict on a seed's selected policy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GuardVerdict {
    /// Transitions of the selected checkpoint that was compared.
    pub selected_transitions: u64,
    /// The policy file the run started from.
    pub init_policy: PathBuf,
    /// First seed of the guard's starts.
    pub start_seed: u64,
    /// The selected policy (A) against the starting one (B), start by start.
    pub paired: Paired,
    /// Whether the starting policy is shipped (it solved more of the starts).
    pub ships_init: bool,
}

impl GuardVerdict {
    /// One line for the terminal.
    pub fn line(&self) -> String {
        let p = &self.paired;
        format!(
            "guard on {} selection starts: selected ({} transitions) {} / starting policy {} \
             (only the selected {}, only the starting {}, McNemar p = {:.3}) - ships the {}",
            p.episodes,
            self.selected_transitions,
            p.a_successes,
            p.b_successes,
            p.only_a,
            p.only_b,
            p.p_value,
            if self.ships_init {
                "starting policy"
            } else {
                "selected policy"
            }
        )
    }
}

const VERDICT_FILE: &str = "guard.json";

/// The verdict in a seed's folder `dir`, if the guard ran there.
pub(super) fn read_verdict(dir: &Path) -> Result<Option<GuardVerdict>, TrainRunError> {
    let path = dir.join(VERDICT_FILE);
    if !path.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path).map_err(io_at(&path))?;
    serde_json::from_str(&text)
        .map(Some)
        .map_err(|source| TrainRunError::DamagedGuard { path, source })
}

/// Runs the guard of seed `seed` (folder `dir`) when the settings ask for one and the run started
/// from a policy: the selected policy and the starting one on the guard's starts, the verdict
/// written to `guard.json`. A verdict of the same selected checkpoint already there is reused (a
/// resumed export).
pub(super) fn run_guard(
    trainer: &Trainer,
    s: &TrainSettings,
    seed: u64,
    dir: &Path,
    scene: &Scene,
) -> Result<Option<GuardVerdict>, TrainRunError> {
    let Some(init) = s.init_policy.as_ref().filter(|_| s.guard_episodes > 0) else {
        return Ok(None);
    };
    let chosen = selected(trainer, dir)?;
    if let Some(v) = read_verdict(dir)?
        && v.selected_transitions == chosen.transitions
        && &v.init_policy == init
        && v.paired.episodes == s.guard_episodes
    {
        return Ok(Some(v));
    }
    let init_file = std::fs::read(init).map_err(io_at(init))?;
    let settings = EvalSettings {
        env: s.reward.env_config(s.task.task()),
        episodes: s.guard_episodes,
        seed: SELECTION_SEED,
        threads: s.eval_threads,
        can_quantisation: true,
        envelope: false,
    };
    let a = episode_outcomes(&chosen.draft(s, seed)?, scene, &settings, &|| {})?;
    let b = episode_outcomes(&init_file, scene, &settings, &|| {})?;
    let paired = Paired::of(&a, &b);
    let verdict = GuardVerdict {
        selected_transitions: chosen.transitions,
        init_policy: init.clone(),
        start_seed: SELECTION_SEED,
        paired,
        ships_init: paired.b_successes > paired.a_successes,
    };
    write_file(
        &dir.join(VERDICT_FILE),
        serde_json::to_string_pretty(&verdict)?.as_bytes(),
    )?;
    Ok(Some(verdict))
}
