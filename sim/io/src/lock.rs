//! An exclusive lock on an output folder while a run works in it.
//!
//! Model: the lock is a file `.stscam-lock` in the folder, created atomically with
//! `O_CREAT | O_EXCL` (`create_new`), holding the process id and the host name of its owner.
//! A second run that finds it refuses to start with a message naming the owner; the lock is
//! removed when the owner drops it (normal end or error). A run killed with SIGKILL leaves the
//! file behind: a lock is *stale* when it names this host and no process with its pid is
//! alive (`/proc/PID` is absent), and a stale lock is taken over (removed and created anew,
//! again with `create_new`, so two runs that both see a stale lock cannot both win).
//! Assumptions: Linux-style `/proc` (elsewhere a lock is never judged stale and must be
//! removed by hand); pids are not reused between a kill and the next run (a reused pid makes
//! the lock look alive, which is the safe side: the message says which file to delete); a
//! lock written on another host (shared file systems) is never judged stale.

use std::io::Write;
use std::path::{Path, PathBuf};

use super::IoError;

/// Name of the lock file inside the locked folder.
pub const LOCK_FILE: &str = ".stscam-lock";

/// Why a folder could not be locked.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    /// Another live run holds the lock.
    #[error(
        "{}: another stscam run (pid {pid} on {host}) is working in this folder; wait for it to finish, or delete {} if it is no longer running",
        folder.display(),
        file.display()
    )]
    Held {
        /// The locked folder.
        folder: PathBuf,
        /// The lock file.
        file: PathBuf,
        /// The owner's process id.
        pid: u32,
        /// The owner's host name.
        host: String,
    },
    /// The lock file could not be created, read or removed.
    #[error(transparent)]
    Io(#[from] IoError),
}

/// A held lock; dropping it removes the lock file.
#[derive(Debug)]
pub struct FolderLock {
    file: PathBuf,
}

impl FolderLock {
    /// Locks `folder` (which must exist) for this process.
    pub fn acquire(folder: &Path) -> Result<FolderLock, LockError> {
        let file = folder.join(LOCK_FILE);
        for _ in 0..2 {
            match std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&file)
            {
                Ok(mut f) => {
                    let text = format!("{}\n{}\n", std::process::id(), host_name());
                    let lock = FolderLock { file: file.clone() };
                    f.write_all(text.as_bytes())
                        .and_then(|()| f.sync_all())
                        .map_err(|e| IoError::io(&file, e))?;
                    return Ok(lock);
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let (pid, host) = read_owner(&file)?;
                    if is_stale(pid, &host) {
                        match std::fs::remove_file(&file) {
                            Ok(()) => continue,
                            // Another run removed it first: try to create it again.
                            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
                            Err(e) => return Err(IoError::io(&file, e).into()),
                        }
                    }
                    return Err(LockError::Held {
                        folder: folder.to_path_buf(),
                        file,
                        pid,
                        host,
                    });
                }
                Err(e) => return Err(IoError::io(&file, e).into()),
            }
        }
        // Twice stale and twice taken by someone else: report the current owner.
        let (pid, host) = read_owner(&file)?;
        Err(LockError::Held {
            folder: folder.to_path_buf(),
            file,
            pid,
            host,
        })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.file
    }
}

impl Drop for FolderLock {
    fn drop(&mut self) {
        // Nothing useful can be done if the removal fails; the next run judges the lock
        // stale (this pid will have exited).
        let _ = std::fs::remove_file(&self.file);
    }
}

/// This machine's host name (empty if unknown).
fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .unwrap_or_default()
}

/// The owner recorded in a lock file: (pid, host). A file being written by its owner right
/// now may still be empty: it is then reported as held by pid 0, never judged stale.
fn read_owner(file: &Path) -> Result<(u32, String), IoError> {
    let text = match super::input::read_input(file, 4096) {
        Ok(b) => String::from_utf8_lossy(&b).into_owned(),
        Err(IoError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
            String::new()
        }
        Err(e) => return Err(e),
    };
    let mut lines = text.lines();
    let pid = lines
        .next()
        .and_then(|l| l.trim().parse().ok())
        .unwrap_or(0);
    let host = lines.next().unwrap_or("").trim().to_string();
    Ok((pid, host))
}

/// Whether a lock of (pid, host) is stale: this host, and no such process alive.
fn is_stale(pid: u32, host: &str) -> bool {
    pid != 0
        && host == host_name()
        && Path::new("/proc/self").exists()
        && !Path::new("/proc").join(pid.to_string()).exists()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn second_lock_is_refused_and_released_on_drop() {
        let dir = tempfile::tempdir().unwrap();
        let lock = FolderLock::acquire(dir.path()).unwrap();
        let text = std::fs::read_to_string(lock.path()).unwrap();
        assert_eq!(text.lines().next().unwrap(), std::process::id().to_string());
        let e = FolderLock::acquire(dir.path()).unwrap_err();
        let m = e.to_string();
        assert!(
            matches!(e, LockError::Held { pid, .. } if pid == std::process::id()),
            "{m}"
        );
        assert!(
            m.contains("another stscam run") && m.contains(LOCK_FILE),
            "{m}"
        );
        drop(lock);
        assert!(!dir.path().join(LOCK_FILE).exists());
        let again = FolderLock::acquire(dir.path()).unwrap();
        drop(again);
    }

    #[test]
    fn stale_lock_of_a_dead_process_is_taken_over() {
        let dir = tempfile::tempdir().unwrap();
        // A child that has exited: its pid names no live process.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        let file = dir.path().join(LOCK_FILE);
        std::fs::write(&file, format!("{dead}\n{}\n", host_name())).unwrap();
        let lock = FolderLock::acquire(dir.path()).unwrap();
        assert_eq!(
            std::fs::read_to_string(lock.path()).unwrap().lines().next(),
            Some(std::process::id().to_string().as_str())
        );
        drop(lock);
        // The same pid written by another host is not judged stale.
        std::fs::write(&file, format!("{dead}\nsome-other-host\n")).unwrap();
        assert!(matches!(
            FolderLock::acquire(dir.path()),
            Err(LockError::Held { .. })
        ));
    }
}
