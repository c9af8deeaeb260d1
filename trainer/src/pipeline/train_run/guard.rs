//! The guard of a run that starts from a policy (a clone stage or `init_policy`): before the export,
//! the selected policy and the starting one run on the same [`TrainSettings::guard_episodes`]
//! selection starts, and the selected policy is shipped only when it solves more of them with
//! an exact McNemar p below [`GUARD_P`]; otherwise the starting policy is (a tie included). The
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
    /// Whether the starting policy is shipped (the selected one did not solve more of the
    /// starts with p < [`GUARD_P`]).
    pub ships_init: bool,
}

/// The selected policy replaces the starting one only when it solves more of the guard's starts
/// with an exact two-sided McNemar p below this, the project's rule for replacing a shipped file.
/// Since session 24 (before it: whenever it solved at least as many): eight fine-tunes of 98.5-99.2%
/// Stack files lost to the file they started from on average (docs/experiments.md, sessions 23
/// and 24), and `trainer critic-rank` found their critics ordering actions at chance, so a tie or
/// a small lead on 500 starts is no evidence for the fine-tune.
pub const GUARD_P: f64 = 0.01;

/// Whether the guard ships the starting policy (B) rather than the selected one (A).
pub fn ships_starting_policy(paired: &Paired) -> bool {
    !(paired.a_successes > paired.b_successes && paired.p_value < GUARD_P)
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
    let settings = eval_settings(s, s.guard_episodes, SELECTION_SEED);
    let a = episode_outcomes(&chosen.draft(s, seed)?, scene, &settings, &|| {})?;
    let b = episode_outcomes(&init_file, scene, &settings, &|| {})?;
    let paired = Paired::of(&a, &b);
    let verdict = GuardVerdict {
        selected_transitions: chosen.transitions,
        init_policy: init.clone(),
        start_seed: SELECTION_SEED,
        paired,
        ships_init: ships_starting_policy(&paired),
    };
    write_file(
        &dir.join(VERDICT_FILE),
        serde_json::to_string_pretty(&verdict)?.as_bytes(),
    )?;
    Ok(Some(verdict))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn paired(a: u32, b: u32, only_a: u32, only_b: u32) -> Paired {
        let outcome = |s: bool| (0.0, s);
        // Starts: both solve, only A, only B, neither.
        let both = a - only_a;
        let neither = 500 - both - only_a - only_b;
        let mut xa = Vec::new();
        let mut xb = Vec::new();
        for (n, sa, sb) in [
            (both, true, true),
            (only_a, true, false),
            (only_b, false, true),
            (neither, false, false),
        ] {
            for _ in 0..n {
                xa.push(outcome(sa));
                xb.push(outcome(sb));
            }
        }
        let p = Paired::of(&xa, &xb);
        assert_eq!((p.a_successes, p.b_successes), (a, b));
        p
    }

    #[test]
    fn only_a_significant_lead_ships_the_selected_policy() {
        // 495 against 485: 10 / 0 discordant, p = 0.002.
        assert!(!ships_starting_policy(&paired(495, 485, 10, 0)));
        // A tie, a small lead (p = 0.25) and a loss keep the starting policy.
        assert!(ships_starting_policy(&paired(490, 490, 3, 3)));
        assert!(ships_starting_policy(&paired(494, 490, 5, 1)));
        assert!(ships_starting_policy(&paired(480, 490, 0, 10)));
    }
}
