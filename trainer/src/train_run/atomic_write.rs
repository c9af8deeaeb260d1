//! Files written so that a crash leaves either the old or the new contents.

use super::*;

/// Writes `bytes` to `path` atomically (temporary file, fsync, rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), TrainRunError> {
    let tmp = path.with_extension("tmp");
    {
        let mut f = std::fs::File::create(&tmp).map_err(|source| TrainRunError::Create {
            path: tmp.clone(),
            source,
        })?;
        f.write_all(bytes).map_err(io_at(&tmp))?;
        f.sync_all().map_err(io_at(&tmp))?;
    }
    std::fs::rename(&tmp, path).map_err(|source| TrainRunError::Write {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(())
}
