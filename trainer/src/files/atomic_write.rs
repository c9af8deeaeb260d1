//! The one way this crate writes a file that must survive a crash or a power cut: checkpoints, demo
//! files (`.dxdm`), exported and cloned policies (`.dxpl`), imitation outputs, run settings, logs
//! rewritten in place and selection records.
//!
//! [`write_atomic`] writes the bytes to a temporary file in the target's folder (a unique hidden
//! name, `.NAME.PID.N.tmp`), flushes it to disk (`sync_all`), renames it over the target, and then
//! (on Unix) flushes the folder too, so that the rename itself is on disk when it returns. A crash at
//! any point leaves either the previous file or the new one, never a torn one; a crash before the
//! rename may leave the temporary file behind (a hidden `*.tmp` next to the target), which nothing
//! reads.
//!
//! Only a regular file is replaced. A path that names something else (`/dev/null`, `/dev/stdout`, a
//! named pipe: a user's `--actions /dev/null`) is written straight into, as `>` in a shell does; a
//! rename there would put a regular file in the device's place for every other program on the
//! machine. A symbolic link keeps being a link: the file it points to is the one replaced.

use std::ffi::OsString;
use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Makes temporary names unique within the process (the process id makes them unique across).
static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// How many names are tried when a temporary name is taken (a stale file of a dead process
/// with the same id).
const TEMP_ATTEMPTS: u32 = 64;

/// Writes `bytes` to `path` atomically and durably: a temporary file in the same folder, `sync_all`,
/// rename over `path`, then `sync_all` of the folder (Unix).
///
/// The folder must exist. On an error before the rename, `path` is untouched and the temporary
/// file is removed; an error flushing the folder is reported after the new file is in place (file
/// systems that cannot flush a folder, `EINVAL`, are accepted as they are).
///
/// A path that exists and is neither a regular file nor a folder (a device such as `/dev/null`, a
/// named pipe) is written straight into instead; a symbolic link is followed, so the link stays
/// and the file it names is replaced.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let resolved;
    let path = match std::fs::symlink_metadata(path) {
        Ok(meta) if meta.file_type().is_symlink() => {
            resolved = resolve_link(path)?;
            resolved.as_path()
        }
        _ => path,
    };
    if let Ok(meta) = std::fs::metadata(path)
        && !meta.is_file()
        && !meta.is_dir()
    {
        return write_in_place(path, bytes);
    }
    let tmp = write_temp(path, bytes)?;
    if let Err(e) = std::fs::rename(&tmp, path) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    sync_dir(parent_dir(path))
}

/// The path a symbolic link finally names (the link's own folder anchors a relative target); a
/// dangling link names the file it would create.
fn resolve_link(path: &Path) -> io::Result<PathBuf> {
    let mut path = path.to_path_buf();
    // As the kernel does, give up on a chain of links too long to be anything but a loop.
    for _ in 0..40 {
        match std::fs::symlink_metadata(&path) {
            Ok(meta) if meta.file_type().is_symlink() => {
                let target = std::fs::read_link(&path)?;
                path = parent_dir(&path).join(target);
            }
            _ => return Ok(path),
        }
    }
    Err(io::Error::new(
        io::ErrorKind::InvalidInput,
        format!("{}: too many levels of symbolic links", path.display()),
    ))
}

/// Writes into something that is not a regular file (a device, a named pipe): opened for writing
/// as it is, never removed or renamed over.
fn write_in_place(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut file = OpenOptions::new().write(true).open(path)?;
    file.write_all(bytes)?;
    file.flush()
}

/// The first half of [`write_atomic`]: writes and flushes `bytes` to a new temporary file next to
/// `path` and returns its path; `path` itself is not touched. Stopping here is what a crash
/// between writing and renaming leaves (the tests use it so).
pub(crate) fn write_temp(path: &Path, bytes: &[u8]) -> io::Result<PathBuf> {
    let name = path.file_name().ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{} does not name a file", path.display()),
        )
    })?;
    let dir = parent_dir(path);
    let mut attempt = 0;
    let (tmp, mut file) = loop {
        let mut tmp_name = OsString::from(".");
        tmp_name.push(name);
        tmp_name.push(format!(
            ".{}.{}.tmp",
            std::process::id(),
            TEMP_COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let tmp = dir.join(tmp_name);
        match OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(file) => break (tmp, file),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists && attempt + 1 < TEMP_ATTEMPTS => {
                attempt += 1;
            }
            Err(e) => return Err(e),
        }
    };
    if let Err(e) = file.write_all(bytes).and_then(|()| file.sync_all()) {
        drop(file);
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    Ok(tmp)
}

/// The folder `path` is in (`.` for a bare file name).
fn parent_dir(path: &Path) -> &Path {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or_else(|| Path::new("."))
}

/// Flushes a folder's entries (a rename in it) to disk.
#[cfg(unix)]
fn sync_dir(dir: &Path) -> io::Result<()> {
    match File::open(dir).and_then(|d| d.sync_all()) {
        // Some file systems cannot flush a folder; nothing more can be done there.
        Err(e)
            if matches!(
                e.kind(),
                io::ErrorKind::InvalidInput | io::ErrorKind::Unsupported
            ) =>
        {
            Ok(())
        }
        r => r,
    }
}

/// Flushes a folder's entries to disk: not possible through `std` off Unix (renames are durable
/// on NTFS once the file is).
#[cfg(not(unix))]
fn sync_dir(_dir: &Path) -> io::Result<()> {
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh, empty folder for one test.
    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("dex-atomic-write-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// The names in a folder, sorted.
    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn bytes_round_trip_and_overwrite() {
        let dir = scratch("round-trip");
        let path = dir.join("policy.dxpl");
        let long: Vec<u8> = (0..100_000u32).map(|i| (i % 251) as u8).collect();
        write_atomic(&path, &long).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), long);
        // A shorter file replaces it whole (no tail of the longer one).
        write_atomic(&path, b"short").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"short");
        write_atomic(&path, b"").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn no_temporary_file_lingers_after_success() {
        let dir = scratch("no-temp");
        for i in 0..3u8 {
            write_atomic(&dir.join("checkpoint.bin"), &[i; 10]).unwrap();
            write_atomic(&dir.join("settings.toml"), b"x = 1\n").unwrap();
        }
        assert_eq!(names(&dir), ["checkpoint.bin", "settings.toml"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_crash_before_the_rename_keeps_the_old_file() {
        let dir = scratch("crash");
        let path = dir.join("checkpoint.bin");
        write_atomic(&path, b"old checkpoint").unwrap();
        // The process dies after the temporary file is written and flushed, before the rename.
        let tmp = write_temp(&path, b"new checkpoint, longer than the old one").unwrap();
        assert_eq!(tmp.parent(), Some(dir.as_path()));
        assert_ne!(tmp, path);
        assert_eq!(std::fs::read(&path).unwrap(), b"old checkpoint");
        // Only the target and the (hidden) leftover: no partial target under any other name.
        let leftover = tmp.file_name().unwrap().to_string_lossy().into_owned();
        assert!(leftover.starts_with(".checkpoint.bin.") && leftover.ends_with(".tmp"));
        assert_eq!(names(&dir), [leftover.clone(), "checkpoint.bin".to_owned()]);
        // The next write (a resumed run) neither trips over the leftover nor touches it.
        write_atomic(&path, b"newer").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"newer");
        assert_eq!(names(&dir), [leftover, "checkpoint.bin".to_owned()]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_failed_rename_keeps_the_target_and_removes_the_temporary_file() {
        let dir = scratch("rename-fails");
        // A non-empty folder where the file should go: the rename fails.
        let path = dir.join("best.json");
        std::fs::create_dir(&path).unwrap();
        std::fs::write(path.join("inside"), b"kept").unwrap();
        assert!(write_atomic(&path, b"{}").is_err());
        assert!(path.is_dir());
        assert_eq!(std::fs::read(path.join("inside")).unwrap(), b"kept");
        assert_eq!(names(&dir), ["best.json"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_missing_folder_or_name_is_an_error_and_writes_nothing() {
        let dir = scratch("missing");
        let e = write_atomic(&dir.join("absent/file.bin"), b"x").unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::NotFound);
        assert!(write_atomic(Path::new("/"), b"x").is_err());
        assert!(names(&dir).is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The kind of thing at `path`, its link not followed.
    #[cfg(unix)]
    fn kind(path: &Path) -> &'static str {
        use std::os::unix::fs::FileTypeExt;
        let t = std::fs::symlink_metadata(path).unwrap().file_type();
        match () {
            _ if t.is_symlink() => "link",
            _ if t.is_fifo() => "fifo",
            _ if t.is_char_device() => "char device",
            _ if t.is_file() => "file",
            _ => "other",
        }
    }

    /// `--actions /dev/null` once replaced the machine's `/dev/null` with a regular file (which
    /// then fed compiler messages to every program that read it). A named pipe stands in for the
    /// device here: it stays a pipe and its reader gets the bytes.
    #[cfg(unix)]
    #[test]
    fn a_named_pipe_is_written_into_not_replaced() {
        let dir = scratch("fifo");
        let fifo = dir.join("actions.csv");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success(), "mkfifo failed");
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read(&fifo).unwrap())
        };
        write_atomic(&fifo, b"step,a0\n0,0.5\n").unwrap();
        assert_eq!(reader.join().unwrap(), b"step,a0\n0,0.5\n");
        assert_eq!(kind(&fifo), "fifo");
        assert_eq!(names(&dir), ["actions.csv"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn the_null_device_stays_a_device() {
        let null = Path::new("/dev/null");
        assert_eq!(
            kind(null),
            "char device",
            "this machine's /dev/null is not a device"
        );
        write_atomic(null, b"discarded").unwrap();
        assert_eq!(kind(null), "char device");
        assert_eq!(std::fs::read(null).unwrap(), b"");
    }

    #[cfg(unix)]
    #[test]
    fn a_link_stays_a_link_and_its_file_is_replaced() {
        let dir = scratch("link");
        std::fs::create_dir(dir.join("store")).unwrap();
        std::fs::write(dir.join("store/policy-v1.dxpl"), b"old").unwrap();
        let link = dir.join("policy.dxpl");
        std::os::unix::fs::symlink("store/policy-v1.dxpl", &link).unwrap();
        write_atomic(&link, b"new").unwrap();
        assert_eq!(kind(&link), "link");
        assert_eq!(
            std::fs::read(dir.join("store/policy-v1.dxpl")).unwrap(),
            b"new"
        );
        assert_eq!(names(&dir.join("store")), ["policy-v1.dxpl"]);
        // A dangling link: the file it names is made.
        let dangling = dir.join("next.dxpl");
        std::os::unix::fs::symlink("store/policy-v2.dxpl", &dangling).unwrap();
        write_atomic(&dangling, b"v2").unwrap();
        assert_eq!(kind(&dangling), "link");
        assert_eq!(
            std::fs::read(dir.join("store/policy-v2.dxpl")).unwrap(),
            b"v2"
        );
        // A loop of links is an error, not a hang.
        std::os::unix::fs::symlink("loop-b", dir.join("loop-a")).unwrap();
        std::os::unix::fs::symlink("loop-a", dir.join("loop-b")).unwrap();
        assert!(write_atomic(&dir.join("loop-a"), b"x").is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_bare_name_is_in_the_current_folder() {
        assert_eq!(parent_dir(Path::new("eval.jsonl")), Path::new("."));
        assert_eq!(parent_dir(Path::new("runs/a/x")), Path::new("runs/a"));
    }
}
