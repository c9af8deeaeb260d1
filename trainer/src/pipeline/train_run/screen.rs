//! Failed-start revisits of a fine-tune (`start.failed_starts`): before training, the policy the
//! run starts from runs on that many screening starts ([`SCREEN_SEED`]), and training episodes
//! revisit the starts it failed (`dex_env::start_states`, revisits). A clone at 97% success fails 3
//! starts in 100, so a fine-tune from uniform starts meets its clone's failures a few times in a
//! whole run; revisiting puts them in a fixed share of its episodes. The list goes to the seed
//! folder's `failed_starts.json` and is reused when the same file was screened on the same starts
//! (a resumed run trains on the same list).

use crate::files::result_record::sha256_hex;
use serde::{Deserialize, Serialize};

use super::*;
use crate::env::Revisits;
use crate::env::evaluate::episode_outcomes;
use crate::env::seeds::{SCREEN_SEED, episode_seed};

/// What a seed's screening found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Screening {
    /// The policy file screened.
    pub policy: PathBuf,
    /// Its SHA-256 (hex), so that a re-made file of the same name is screened again.
    pub sha256: String,
    /// First seed of the screening starts.
    pub start_seed: u64,
    /// Starts screened.
    pub screened: u32,
    /// The seeds (`episode_seed(start_seed, i)`) of the starts the policy failed, in episode order.
    pub failed: Vec<u64>,
}

const SCREEN_FILE: &str = "failed_starts.json";

/// The screening of `init` for seed folder `dir` (`start.failed_starts` starts), read from
/// `failed_starts.json` when that file screened the same policy bytes on the same starts, else
/// taken from another seed folder of the run that screened them (the screening does not depend on
/// the seed: a run of several seeds screens once), else run; written there either way.
pub(super) fn screen(
    s: &TrainSettings,
    (seed, init): (u64, &Path),
    dir: &Path,
    scene: &Scene,
    on_event: &mut dyn FnMut(TrainEvent<'_>),
) -> Result<Screening, TrainRunError> {
    let file = std::fs::read(init).map_err(io_at(init))?;
    let sha256 = sha256_hex(&file);
    let path = dir.join(SCREEN_FILE);
    if path.exists() {
        let text = std::fs::read_to_string(&path).map_err(io_at(&path))?;
        let kept: Screening =
            serde_json::from_str(&text).map_err(|source| TrainRunError::DamagedScreening {
                path: path.clone(),
                source,
            })?;
        if kept.screens(&sha256, s.start.failed_starts) {
            return Ok(kept);
        }
    }
    let screening = match sibling_screening(dir, &sha256, s.start.failed_starts) {
        Some(shared) => Screening {
            policy: init.to_path_buf(),
            ..shared
        },
        None => {
            let settings = eval_settings(s, s.start.failed_starts, SCREEN_SEED);
            on_event(TrainEvent::ScreeningStarted {
                seed,
                starts: s.start.failed_starts,
            });
            let outcomes = episode_outcomes(&file, scene, &settings, &|| {})?;
            let failed = (0u64..)
                .zip(&outcomes)
                .filter(|(_, (_, success))| !success)
                .map(|(i, _)| episode_seed(SCREEN_SEED, i))
                .collect();
            Screening {
                policy: init.to_path_buf(),
                sha256,
                start_seed: SCREEN_SEED,
                screened: s.start.failed_starts,
                failed,
            }
        }
    };
    std::fs::create_dir_all(dir).map_err(|source| TrainRunError::Create {
        path: dir.to_path_buf(),
        source,
    })?;
    write_file(&path, serde_json::to_string_pretty(&screening)?.as_bytes())?;
    Ok(screening)
}

/// A screening of the same policy bytes on the same starts in another seed folder beside `dir`
/// (`seed-*/failed_starts.json`); lists that do not read are left to their own seed's run.
fn sibling_screening(dir: &Path, sha256: &str, starts: u32) -> Option<Screening> {
    let parent = dir.parent()?;
    let mut folders: Vec<PathBuf> = std::fs::read_dir(parent)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p != dir
                && p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("seed-"))
        })
        .collect();
    folders.sort();
    folders.into_iter().find_map(|f| {
        let text = std::fs::read_to_string(f.join(SCREEN_FILE)).ok()?;
        let kept: Screening = serde_json::from_str(&text).ok()?;
        kept.screens(sha256, starts).then_some(kept)
    })
}

impl Screening {
    /// Whether this screening ran the policy of `sha256` on the `starts` screening starts.
    fn screens(&self, sha256: &str, starts: u32) -> bool {
        self.sha256 == sha256 && self.screened == starts && self.start_seed == SCREEN_SEED
    }

    /// The revisits of the run's start states.
    pub fn revisits(&self, probability: f64) -> Revisits {
        Revisits {
            seeds: self.failed.clone(),
            probability,
        }
    }
}
