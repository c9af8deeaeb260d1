//! A `trainer train` seed folder read back: the run's settings (`settings.toml`) and its last
//! checkpoint (`checkpoint.bin`), for the tools that look inside a run's networks
//! ([`super::proposal_pair`], [`super::critic_ranking`]).

use std::path::{Path, PathBuf};

use crate::learn::{LearnError, Trainer};
use crate::pipeline::train_settings::TrainSettings;

/// Why a seed folder cannot be read back.
#[derive(Debug, thiserror::Error)]
pub enum RunFolderError {
    /// A file of the folder could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The run's settings could not be read.
    #[error("{path}: not a run's settings: {why}")]
    Settings {
        /// The file.
        path: PathBuf,
        /// What failed.
        why: String,
    },
    /// The run's checkpoint could not be loaded.
    #[error("{path}: {source}")]
    Checkpoint {
        /// The file.
        path: PathBuf,
        /// The error.
        source: LearnError,
    },
}

/// The settings and the last checkpoint of the seed folder `seed_dir` (`OUT/seed-S` of a
/// `trainer train` run).
pub fn load_run(seed_dir: &Path) -> Result<(TrainSettings, Trainer), RunFolderError> {
    let path = seed_dir.join("settings.toml");
    let bytes = std::fs::read(&path).map_err(|source| RunFolderError::Io {
        path: path.clone(),
        source,
    })?;
    let text = String::from_utf8(bytes).map_err(|e| RunFolderError::Settings {
        path: path.clone(),
        why: e.to_string(),
    })?;
    let settings: TrainSettings = toml::from_str(&text).map_err(|e| RunFolderError::Settings {
        path: path.clone(),
        why: e.to_string(),
    })?;
    let ckpt = seed_dir.join("checkpoint.bin");
    let trainer = Trainer::load(&ckpt).map_err(|source| RunFolderError::Checkpoint {
        path: ckpt.clone(),
        source,
    })?;
    Ok((settings, trainer))
}
