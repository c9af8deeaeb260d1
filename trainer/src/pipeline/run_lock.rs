//! One trainer per run folder: an exclusive advisory lock on `RUN/.lock`, held for as long as the
//! [`RunLock`] lives.
//!
//! Two `trainer train --resume` on one folder (a retried job, a second terminal) would otherwise
//! both run and interleave their logs and checkpoints. The lock is the operating system's
//! (`flock` on Unix, `LockFileEx` on Windows, through [`std::fs::File::try_lock`]): the kernel drops
//! it when the process ends in any way, `kill -9` included, so a crash never leaves a stale lock
//! behind. The file holds the holder's process id, which the refusal names.

use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// Why a run folder could not be locked.
#[derive(Debug, thiserror::Error)]
pub enum RunLockError {
    /// Another process holds the folder.
    #[error(
        "run folder {} is in use by another trainer (pid {pid}); wait for it to finish, stop it, \
         or choose another --out",
        folder.display()
    )]
    Busy {
        /// The folder.
        folder: PathBuf,
        /// The holder's process id as it wrote it (`unknown` when unreadable).
        pid: String,
    },
    /// The lock file could not be created or written.
    #[error("cannot lock run folder {}: {source}", folder.display())]
    Io {
        /// The folder.
        folder: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
}

/// An exclusive lock on a run folder; released when dropped (or when the process dies).
#[derive(Debug)]
pub struct RunLock {
    _file: File,
    path: PathBuf,
}

impl RunLock {
    /// Name of the lock file inside a run folder.
    pub const FILE: &'static str = ".lock";

    /// Takes the lock of `folder` (created if missing) without waiting: fails at once with
    /// [`RunLockError::Busy`] when another process holds it.
    pub fn acquire(folder: &Path) -> Result<RunLock, RunLockError> {
        let io = |source| RunLockError::Io {
            folder: folder.to_path_buf(),
            source,
        };
        std::fs::create_dir_all(folder).map_err(io)?;
        let path = folder.join(Self::FILE);
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(io)?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                let mut pid = String::new();
                let _ = file.read_to_string(&mut pid);
                let pid = pid.trim();
                return Err(RunLockError::Busy {
                    folder: folder.to_path_buf(),
                    pid: if pid.is_empty() {
                        "unknown".into()
                    } else {
                        pid.into()
                    },
                });
            }
            Err(TryLockError::Error(e)) => return Err(io(e)),
        }
        file.set_len(0).map_err(io)?;
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        writeln!(file, "{}", std::process::id()).map_err(io)?;
        file.flush().map_err(io)?;
        Ok(RunLock { _file: file, path })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_on_a_folder_is_refused_until_the_first_is_dropped() {
        let dir = std::env::temp_dir().join(format!("dex-run-lock-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let first = RunLock::acquire(&dir).expect("first lock");
        // A second open file description on the same file: refused, naming this process.
        let err = RunLock::acquire(&dir).expect_err("second lock");
        let text = err.to_string();
        assert!(
            text.contains(&format!("pid {}", std::process::id())),
            "{text}"
        );
        assert!(matches!(err, RunLockError::Busy { .. }));
        drop(first);
        let again = RunLock::acquire(&dir).expect("lock after release");
        assert!(again.path().ends_with(RunLock::FILE));
        drop(again);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
