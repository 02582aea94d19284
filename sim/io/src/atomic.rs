//! Atomic file replacement, and output sets that appear together or not at all.
//!
//! Data is written into **unnamed** files first (Linux `O_TMPFILE` in the target's folder): a
//! run killed while it writes leaves nothing behind, because an unnamed file vanishes with its
//! last descriptor. Only when the data is complete and fsynced is a name linked to it
//! (`linkat` through `/proc/self/fd`, which fails rather than follow or replace anything at
//! the new name). Where the file system or the platform has no `O_TMPFILE`, the files are
//! created under their temporary names from the start, as described below.
//!
//! One file ([`write_atomic`]): the bytes go to a temporary name `.<NAME>.tmp-<pid>-<n>` in the
//! target's folder, created exclusively (`O_CREAT | O_EXCL`, so a symbolic link or any file
//! already there is never opened or followed: the next `n` is tried), are flushed and fsynced,
//! and the temporary file is renamed over the target.
//!
//! A set of files ([`write_all_atomic`]: capture, frontal, depth, mask and sidecars; H and its
//! siblings; the members of a depth stack) is written and fsynced into unnamed files in the
//! output folder first (or, without them, into a per-run staging folder
//! `.stscam-stage-<pid>-<n>` created exclusively with `mkdir`, which never follows a link).
//! Then, under the folder's commit lock `.stscam-commit` (created with `O_EXCL`; a second
//! writer waits for it, a lock whose process is gone is taken over), the set is committed:
//!
//! - **By one exchange** (Linux, the usual case): a sibling folder
//!   `.<NAME>.stscam-swap-<pid>-<n>` beside the output folder gets a hard link of every other
//!   file of the folder, a copy of every symbolic link and the set's files, is fsynced, and
//!   one `renameat2(RENAME_EXCHANGE)` swaps it with the output folder; the old folder (now
//!   under the sibling's name, with the lock inside) is removed. A reader who opens a file of
//!   the folder at any instant, a SIGKILL at any instant included, sees the old set or the new
//!   one, never a mix, with no repair. A killed run leaves at most a hidden sibling folder,
//!   which the next writer of the folder (or [`recover_folder`]) deletes. The folder's
//!   identity changes (its inode; a shell whose working directory it is keeps the old one);
//!   its permission bits are kept, extended attributes and ACLs are not.
//! - **File by file**, where the exchange cannot keep the folder's other entries whole (a
//!   sub-folder or a special file in it, the output folder itself a link, a parent folder that
//!   cannot be written, no hard links or no `RENAME_EXCHANGE` on the file system): the files
//!   are linked into a staging folder, a marker `.commit` is written into it and the files are
//!   renamed into place one by one, after which the staging folder and the lock are removed.
//!   A run killed during those renames (microseconds) leaves the marker; whoever next writes a
//!   set into the folder first repairs it under the lock: a staging folder of a dead process
//!   with a marker is rolled forward (its remaining files renamed into place, completing that
//!   run's set), one without is deleted.
//!
//! Either way two runs writing into one folder commit one after the other: the folder ends
//! with the complete set of the run that committed last, never a mix. A failure before the
//! commit (full disk, read-only folder) leaves the output folder as it was (exit 1 in the CLI).
//! With unnamed files a run killed at any point before its commit leaves the folder exactly
//! as it was, with no temporary name.
//!
//! Testing hook: `STSCAM_TEST_COMMIT_DELAY_MS=N` makes a set's writer sleep N ms once its data
//! are written (before it takes the lock), before each link into the exchange's sibling and
//! before the exchange (or before each rename of a file-by-file commit), to widen the windows
//! the concurrency and SIGKILL tests aim at. It changes no output.
//!
//! Assumptions: one local file system (rename within a folder is atomic); Linux-style `/proc`
//! to tell a dead lock owner (elsewhere a stale lock must be removed by hand, as the error says).

use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use super::IoError;

/// Name of a folder's commit lock.
pub const COMMIT_LOCK: &str = ".stscam-commit";
/// Prefix of a run's staging folder.
pub const STAGE_PREFIX: &str = ".stscam-stage-";
/// Marker written into a staging folder when its renames start.
const COMMIT_MARKER: &str = ".commit";
/// How long a writer waits for another run's commit lock before giving up.
const LOCK_WAIT: Duration = Duration::from_secs(600);

/// A per-process counter that makes temporary names unique within the process.
static SEQ: AtomicU64 = AtomicU64::new(0);

fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// A fresh temporary name `.<NAME>.tmp-<pid>-<n>` for `file_name`.
fn temp_name(file_name: &std::ffi::OsStr) -> std::ffi::OsString {
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(file_name);
    tmp_name.push(format!(
        ".tmp-{}-{}",
        std::process::id(),
        SEQ.fetch_add(1, Ordering::Relaxed)
    ));
    tmp_name
}

/// Creates a fresh temporary file next to `path` with `O_EXCL` (never through a link) and
/// returns it with its name.
fn create_temp(path: &Path) -> Result<(File, PathBuf), IoError> {
    let file_name = path
        .file_name()
        .ok_or_else(|| IoError::format(path, "path has no file name"))?;
    let dir = parent_dir(path);
    loop {
        let tmp = dir.join(temp_name(file_name));
        match OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => return Ok((f, tmp)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(IoError::io(path, e)),
        }
    }
}

/// An unnamed file in `dir` (Linux `O_TMPFILE`), or `None` where the platform or the file
/// system has none (the caller then writes under a temporary name instead).
#[cfg(target_os = "linux")]
fn anonymous_in(dir: &Path) -> std::io::Result<Option<File>> {
    use rustix::fs::{CWD, Mode, OFlags, openat};
    use rustix::io::Errno;
    if !Path::new("/proc/self/fd").is_dir() {
        // `link_anonymous` names the file through /proc.
        return Ok(None);
    }
    let flags = OFlags::WRONLY | OFlags::TMPFILE | OFlags::CLOEXEC;
    // 0o666 less the umask, as for files created by name.
    match openat(CWD, dir, flags, Mode::from_raw_mode(0o666)) {
        Ok(fd) => Ok(Some(File::from(fd))),
        // Kernel or file system without O_TMPFILE (EISDIR: kernels older than 3.11).
        Err(Errno::OPNOTSUPP | Errno::ISDIR | Errno::INVAL) => Ok(None),
        Err(e) => Err(e.into()),
    }
}

#[cfg(not(target_os = "linux"))]
fn anonymous_in(_dir: &Path) -> std::io::Result<Option<File>> {
    Ok(None)
}

/// Whether files written into `dir` are unnamed until their commit (`O_TMPFILE` and `/proc`
/// available there); where not, the named staging described in the module comment is used.
pub fn unnamed_files_supported(dir: &Path) -> bool {
    matches!(anonymous_in(dir), Ok(Some(_)))
}

/// Gives the unnamed `file` the name `path`. Fails with `AlreadyExists` if anything (a file
/// or a link) is there: `linkat` neither follows nor replaces the new name.
#[cfg(target_os = "linux")]
fn link_anonymous(file: &File, path: &Path) -> std::io::Result<()> {
    use rustix::fs::{AtFlags, CWD, linkat};
    use std::os::unix::io::AsRawFd;
    let from = format!("/proc/self/fd/{}", file.as_raw_fd());
    linkat(CWD, from.as_str(), CWD, path, AtFlags::SYMLINK_FOLLOW).map_err(Into::into)
}

#[cfg(not(target_os = "linux"))]
fn link_anonymous(_file: &File, _path: &Path) -> std::io::Result<()> {
    Err(std::io::Error::from(std::io::ErrorKind::Unsupported))
}

/// Writes and fsyncs `bytes` into an unnamed file in `dir`; `None` where there are none.
fn anonymous_with(dir: &Path, bytes: &[u8], sync: bool) -> std::io::Result<Option<File>> {
    let Some(mut file) = anonymous_in(dir)? else {
        return Ok(None);
    };
    file.write_all(bytes)?;
    if sync {
        file.sync_all()?;
    }
    Ok(Some(file))
}

/// Writes `bytes` to `path` atomically.
///
/// The data goes to an exclusively created `.<filename>.tmp-<pid>-<n>` in the same directory,
/// is flushed and fsynced, and is then renamed over `path`. On any error the temporary file
/// is removed and `path` is left untouched.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    write_via_temp(path, bytes, true)?;
    // Persist the rename itself; not all platforms can open directories, and the data is
    // already safely in place, so failures are ignored.
    if let Ok(d) = File::open(parent_dir(path)) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Writes `bytes` to `path` through a temporary file and a rename, without fsync: readers and
/// a later run never see a partial file, even if this process is killed, but the data may not
/// survive a power loss until the OS flushes it. For the many per-sample files of a dataset,
/// where a per-file fsync would dominate the run time.
pub fn write_atomic_unsynced(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    write_via_temp(path, bytes, false)
}

fn write_via_temp(path: &Path, bytes: &[u8], sync: bool) -> Result<(), IoError> {
    let dir = parent_dir(path);
    if let Some(file) = anonymous_with(&dir, bytes, sync).map_err(|e| IoError::io(path, e))? {
        // Only the link and the rename can leave a temporary name behind.
        let file_name = path
            .file_name()
            .ok_or_else(|| IoError::format(path, "path has no file name"))?;
        loop {
            let tmp = dir.join(temp_name(file_name));
            match link_anonymous(&file, &tmp) {
                Ok(()) => {
                    return fs::rename(&tmp, path).map_err(|e| {
                        let _ = fs::remove_file(&tmp);
                        IoError::io(path, e)
                    });
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(IoError::io(path, e)),
            }
        }
    }
    let (mut file, tmp) = create_temp(path)?;
    let result = file
        .write_all(bytes)
        .and_then(|()| if sync { file.sync_all() } else { Ok(()) })
        .and_then(|()| {
            drop(file);
            fs::rename(&tmp, path)
        });
    result.map_err(|e| {
        let _ = fs::remove_file(&tmp);
        IoError::io(path, e)
    })
}

/// The test-only delay before each rename of a commit (see the module comment).
fn commit_delay() -> Option<Duration> {
    std::env::var("STSCAM_TEST_COMMIT_DELAY_MS")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
        .map(Duration::from_millis)
}

/// Writes several files into `dir` as one unit (see the module comment): `dir` is created if
/// needed, every file is first written and synced in a staging folder, and only when all
/// writes succeeded are they renamed into place, under the folder's commit lock. On failure
/// the staging folder is removed, and `dir` too if this call created it and it is empty, so
/// nothing new is left behind. File names must be plain names (no folders).
pub fn write_all_atomic(dir: &Path, files: &[(&str, &[u8])]) -> Result<(), IoError> {
    let created = !dir.exists();
    fs::create_dir_all(dir).map_err(|e| IoError::io(dir, e))?;
    let remove_created = || {
        if created {
            let _ = fs::remove_dir(dir);
        }
    };
    let fail = |stage: Option<&Path>, e: IoError| {
        if let Some(stage) = stage {
            let _ = remove_tree(stage);
        }
        remove_created();
        Err(e)
    };
    if let Some((name, _)) = files.iter().find(|(name, _)| {
        Path::new(name).components().count() != 1
            || name.starts_with(STAGE_PREFIX)
            || *name == COMMIT_LOCK
    }) {
        // A name with folders cannot be staged; report it as the old writer did.
        let e = std::io::Error::new(
            std::io::ErrorKind::NotFound,
            "output names must be plain file names",
        );
        return fail(None, IoError::io(&dir.join(name), e));
    }
    // The data, written and synced before the lock is taken: into unnamed files where the file
    // system has them (nothing named exists until the commit), else into a staging folder.
    let mut unnamed = Vec::with_capacity(files.len());
    for (name, bytes) in files {
        match anonymous_with(dir, bytes, true) {
            Ok(Some(file)) => unnamed.push(file),
            Ok(None) => break,
            Err(e) => return fail(None, IoError::io(&dir.join(name), e)),
        }
    }
    let staged_early = if unnamed.len() == files.len() {
        None
    } else {
        unnamed.clear();
        let stage = match create_stage(dir) {
            Ok(s) => s,
            Err(e) => return fail(None, e),
        };
        for (name, bytes) in files {
            if let Err(e) = write_new_synced(&stage.join(name), bytes) {
                return fail(Some(&stage), IoError::io(&dir.join(name), e));
            }
        }
        Some(stage)
    };
    // A target that exists but is not a regular file would make its rename fail after others
    // succeeded: refuse before renaming anything.
    if let Some((name, _)) = files.iter().find(|(n, _)| {
        let p = dir.join(n);
        p.exists() && !p.is_file()
    }) {
        return fail(
            staged_early.as_deref(),
            IoError::format(&dir.join(name), "exists and is not a regular file"),
        );
    }
    let delay = commit_delay();
    if let Some(d) = delay {
        std::thread::sleep(d);
    }
    let lock = match CommitLock::acquire(dir) {
        Ok(l) => l,
        Err(e) => return fail(staged_early.as_deref(), e),
    };
    if let Err(e) = recover_locked(dir) {
        drop(lock);
        return fail(staged_early.as_deref(), e);
    }
    match swap_in(dir, files, &unnamed, staged_early.as_deref(), delay) {
        Ok(true) => {
            // The old folder, the lock and any early staging folder in it, are gone.
            lock.disarm();
            return Ok(());
        }
        Ok(false) => {}
        Err(e) => {
            drop(lock);
            return fail(staged_early.as_deref(), e);
        }
    }
    let stage = match staged_early {
        Some(stage) => stage,
        None => match stage_unnamed(dir, files, &unnamed) {
            Ok(stage) => stage,
            Err(e) => {
                drop(lock);
                return fail(None, e);
            }
        },
    };
    if let Err(e) = File::open(&stage)
        .and_then(|d| d.sync_all())
        .and_then(|()| write_new_synced(&stage.join(COMMIT_MARKER), b""))
        .and_then(|()| File::open(&stage).and_then(|d| d.sync_all()))
    {
        drop(lock);
        return fail(Some(&stage), IoError::io(&stage, e));
    }
    let result = roll_forward(&stage, dir, delay);
    drop(lock);
    result
}

/// Prefix (after `.<folder name>`) of the sibling folder an exchange commit builds.
const SWAP_INFIX: &str = ".stscam-swap-";

/// The exchange commit (see the module comment), under the commit lock: a sibling folder
/// `.<NAME>.stscam-swap-<pid>-<n>` beside `dir` gets a hard link of every other file of
/// `dir`, a copy of every symbolic link, and the set's files (linked from their unnamed files
/// or from the early staging folder `staged`); then one `renameat2(RENAME_EXCHANGE)` swaps it
/// with `dir`, and the old folder (now under the sibling's name) is removed. `Ok(false)`, with
/// nothing changed, where the exchange cannot keep the folder's other entries whole (a
/// sub-folder or a special file in it, `dir` itself a link, a parent that cannot be written,
/// no hard links or no `RENAME_EXCHANGE` on this file system): the caller then renames the
/// files one by one.
#[cfg(target_os = "linux")]
fn swap_in(
    dir: &Path,
    files: &[(&str, &[u8])],
    unnamed: &[File],
    staged: Option<&Path>,
    delay: Option<Duration>,
) -> Result<bool, IoError> {
    use std::os::unix::fs::PermissionsExt;
    let Ok(meta) = fs::symlink_metadata(dir) else {
        return Ok(false);
    };
    if !meta.is_dir() || (staged.is_none() && unnamed.len() != files.len()) {
        return Ok(false);
    }
    let Some((parent, name)) = parent_and_name(dir) else {
        return Ok(false);
    };
    let is_set = |n: &std::ffi::OsStr| files.iter().any(|(f, _)| std::ffi::OsStr::new(f) == n);
    // The folder's other entries: plain files are linked, links copied; anything else keeps
    // the one-by-one commit.
    let mut keep: Vec<(std::ffi::OsString, bool)> = Vec::new();
    for entry in fs::read_dir(dir).map_err(|e| IoError::io(dir, e))? {
        let entry = entry.map_err(|e| IoError::io(dir, e))?;
        let n = entry.file_name();
        let n_str = n.to_string_lossy();
        if n == COMMIT_LOCK || n_str.starts_with(STAGE_PREFIX) || is_set(&n) {
            continue;
        }
        let t = entry
            .file_type()
            .map_err(|e| IoError::io(&entry.path(), e))?;
        if t.is_file() {
            keep.push((n, false));
        } else if t.is_symlink() {
            keep.push((n, true));
        } else {
            return Ok(false);
        }
    }
    let mut sib_name = std::ffi::OsString::from(".");
    sib_name.push(name);
    sib_name.push(format!(
        "{SWAP_INFIX}{}-{}",
        std::process::id(),
        SEQ.fetch_add(1, Ordering::Relaxed)
    ));
    let sib = parent.join(&sib_name);
    if fs::create_dir(&sib).is_err() {
        return Ok(false);
    }
    let give_up = |sib: &Path| {
        let _ = remove_tree(sib);
        Ok(false)
    };
    if fs::set_permissions(&sib, fs::Permissions::from_mode(meta.permissions().mode())).is_err() {
        return give_up(&sib);
    }
    for (n, link) in &keep {
        if let Some(d) = delay {
            std::thread::sleep(d);
        }
        let (from, to) = (dir.join(n), sib.join(n));
        let ok = if *link {
            fs::read_link(&from).and_then(|t| std::os::unix::fs::symlink(t, &to))
        } else {
            fs::hard_link(&from, &to)
        };
        if ok.is_err() {
            return give_up(&sib);
        }
    }
    for (i, (n, _)) in files.iter().enumerate() {
        if let Some(d) = delay {
            std::thread::sleep(d);
        }
        let to = sib.join(n);
        let r = match staged {
            Some(stage) => fs::hard_link(stage.join(n), &to),
            None => link_anonymous(&unnamed[i], &to),
        };
        if let Err(e) = r {
            let _ = remove_tree(&sib);
            return Err(IoError::io(&dir.join(n), e));
        }
    }
    if let Err(e) = File::open(&sib).and_then(|d| d.sync_all()) {
        let _ = remove_tree(&sib);
        return Err(IoError::io(&sib, e));
    }
    if let Some(d) = delay {
        std::thread::sleep(d);
    }
    use rustix::fs::{CWD, RenameFlags, renameat_with};
    if renameat_with(CWD, &sib, CWD, dir, RenameFlags::EXCHANGE).is_err() {
        return give_up(&sib);
    }
    if let Ok(d) = File::open(parent) {
        let _ = d.sync_all();
    }
    // The old folder now has the sibling's name: its files, links, lock and staging folders go.
    let _ = remove_tree(&sib);
    Ok(true)
}

#[cfg(not(target_os = "linux"))]
fn swap_in(
    _dir: &Path,
    _files: &[(&str, &[u8])],
    _unnamed: &[File],
    _staged: Option<&Path>,
    _delay: Option<Duration>,
) -> Result<bool, IoError> {
    Ok(false)
}

/// The folder holding `dir` (`.` for a bare name) and `dir`'s own name; `None` for `.`, `..`
/// or a root.
fn parent_and_name(dir: &Path) -> Option<(&Path, &std::ffi::OsStr)> {
    let (parent, name) = (dir.parent()?, dir.file_name()?);
    let parent = if parent.as_os_str().is_empty() {
        Path::new(".")
    } else {
        parent
    };
    Some((parent, name))
}

/// Removes the exchange siblings of `dir` left by dead runs (killed before or just after
/// their exchange: an unfinished new folder or an old one; neither is ever visible as `dir`).
fn remove_dead_swaps(dir: &Path) {
    let Some((parent, name)) = parent_and_name(dir) else {
        return;
    };
    let mut prefix = String::from(".");
    prefix.push_str(&name.to_string_lossy());
    prefix.push_str(SWAP_INFIX);
    let Ok(entries) = fs::read_dir(parent) else {
        return;
    };
    for entry in entries.flatten() {
        let n = entry.file_name();
        let Some(rest) = n.to_str().and_then(|n| n.strip_prefix(&prefix)) else {
            continue;
        };
        let pid = rest.split('-').next().and_then(|p| p.parse::<u32>().ok());
        if pid.is_none_or(|p| p == std::process::id() || process_alive(p)) {
            continue;
        }
        if entry.file_type().is_ok_and(|t| t.is_dir()) {
            let _ = remove_tree(&entry.path());
        }
    }
}

/// Under the commit lock: a staging folder holding `files`' names linked to their unnamed
/// files. On failure the folder is removed.
fn stage_unnamed(
    dir: &Path,
    files: &[(&str, &[u8])],
    unnamed: &[File],
) -> Result<PathBuf, IoError> {
    let stage = create_stage(dir)?;
    for ((name, _), file) in files.iter().zip(unnamed) {
        if let Err(e) = link_anonymous(file, &stage.join(name)) {
            let _ = remove_tree(&stage);
            return Err(IoError::io(&dir.join(name), e));
        }
    }
    Ok(stage)
}

/// Creates this run's staging folder inside `dir` exclusively.
fn create_stage(dir: &Path) -> Result<PathBuf, IoError> {
    loop {
        let stage = dir.join(format!(
            "{STAGE_PREFIX}{}-{}",
            std::process::id(),
            SEQ.fetch_add(1, Ordering::Relaxed)
        ));
        match fs::create_dir(&stage) {
            Ok(()) => return Ok(stage),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(IoError::io(&stage, e)),
        }
    }
}

/// Renames every file of a committed staging folder (but its marker) into `dir`, then removes
/// the marker and the folder.
fn roll_forward(stage: &Path, dir: &Path, delay: Option<Duration>) -> Result<(), IoError> {
    let mut names: Vec<std::ffi::OsString> = fs::read_dir(stage)
        .map_err(|e| IoError::io(stage, e))?
        .filter_map(|e| e.ok().map(|e| e.file_name()))
        .filter(|n| n != COMMIT_MARKER)
        .collect();
    names.sort();
    for name in names {
        if let Some(d) = delay {
            std::thread::sleep(d);
        }
        fs::rename(stage.join(&name), dir.join(&name))
            .map_err(|e| IoError::io(&dir.join(&name), e))?;
    }
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
    let _ = fs::remove_file(stage.join(COMMIT_MARKER));
    fs::remove_dir(stage).map_err(|e| IoError::io(stage, e))
}

/// Repairs `dir` after runs that were killed while writing a set into it (see the module
/// comment): takes the commit lock, rolls forward every staging folder of a dead process that
/// holds a commit marker and deletes every other one, and returns how many it completed and
/// deleted. A no-op (and cheap) in a folder without staging folders.
pub fn recover_folder(dir: &Path) -> Result<(usize, usize), IoError> {
    let lock = CommitLock::acquire(dir)?;
    let r = recover_locked(dir);
    drop(lock);
    r
}

fn recover_locked(dir: &Path) -> Result<(usize, usize), IoError> {
    remove_dead_swaps(dir);
    let (mut done, mut removed) = (0, 0);
    let entries = fs::read_dir(dir).map_err(|e| IoError::io(dir, e))?;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(rest) = name.to_str().and_then(|n| n.strip_prefix(STAGE_PREFIX)) else {
            continue;
        };
        let pid = rest.split('-').next().and_then(|p| p.parse::<u32>().ok());
        if pid.is_some_and(|p| p == std::process::id() || process_alive(p)) {
            continue;
        }
        let stage = entry.path();
        if !fs::symlink_metadata(&stage).is_ok_and(|m| m.is_dir()) {
            continue;
        }
        if stage.join(COMMIT_MARKER).exists() {
            roll_forward(&stage, dir, None)?;
            done += 1;
        } else {
            remove_tree(&stage).map_err(|e| IoError::io(&stage, e))?;
            removed += 1;
        }
    }
    Ok((done, removed))
}

/// Removes a staging folder, or a folder an exchange left (or an unfinished sibling): its
/// files and links, the folders in it (staging folders) the same way, then the folder; never
/// follows a link.
fn remove_tree(dir: &Path) -> std::io::Result<()> {
    for entry in fs::read_dir(dir)?.flatten() {
        if entry.file_type().is_ok_and(|t| t.is_dir()) {
            let _ = remove_tree(&entry.path());
        } else {
            let _ = fs::remove_file(entry.path());
        }
    }
    fs::remove_dir(dir)
}

/// True unless `/proc` says no process `pid` exists (where there is no `/proc`, always true:
/// the safe side).
fn process_alive(pid: u32) -> bool {
    !Path::new("/proc/self").exists() || Path::new(&format!("/proc/{pid}")).exists()
}

/// The folder's commit lock: `.stscam-commit` holding the owner's pid, removed on drop
/// (unless disarmed: after an exchange the lock file sits in the old folder, removed with it,
/// and the name in the new folder may already be another run's lock).
struct CommitLock {
    file: Option<PathBuf>,
}

impl CommitLock {
    fn acquire(dir: &Path) -> Result<CommitLock, IoError> {
        let file = dir.join(COMMIT_LOCK);
        let start = std::time::Instant::now();
        loop {
            match OpenOptions::new().write(true).create_new(true).open(&file) {
                Ok(mut f) => {
                    let lock = CommitLock {
                        file: Some(file.clone()),
                    };
                    f.write_all(format!("{}\n", std::process::id()).as_bytes())
                        .map_err(|e| IoError::io(&file, e))?;
                    return Ok(lock);
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    // The owner may be between creating and writing the file: an empty or
                    // unreadable lock counts as alive until it has been so for a second.
                    let owner = fs::symlink_metadata(&file)
                        .ok()
                        .filter(|m| m.is_file())
                        .and_then(|_| fs::read_to_string(&file).ok())
                        .and_then(|t| t.trim().parse::<u32>().ok());
                    let stale = match owner {
                        Some(pid) => !process_alive(pid),
                        None => start.elapsed() > Duration::from_secs(1),
                    };
                    if stale {
                        match fs::remove_file(&file) {
                            Ok(()) => continue,
                            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
                            Err(e) => return Err(IoError::io(&file, e)),
                        }
                    }
                    if start.elapsed() > LOCK_WAIT {
                        return Err(IoError::format(
                            &file,
                            format!(
                                "another stscam run (pid {}) has held this folder's commit lock for {} s; delete this file if no such run is working",
                                owner.map_or("?".to_string(), |p| p.to_string()),
                                LOCK_WAIT.as_secs()
                            ),
                        ));
                    }
                    std::thread::sleep(Duration::from_millis(5));
                }
                Err(e) => return Err(IoError::io(&file, e)),
            }
        }
    }
}

impl CommitLock {
    /// Forgets the lock without removing anything (see the type's comment).
    fn disarm(mut self) {
        self.file = None;
    }
}

impl Drop for CommitLock {
    fn drop(&mut self) {
        if let Some(f) = &self.file {
            let _ = fs::remove_file(f);
        }
    }
}

/// Creates `path` exclusively (never through a link), writes and fsyncs it.
fn write_new_synced(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut file = OpenOptions::new().write(true).create_new(true).open(path)?;
    file.write_all(bytes)?;
    file.flush()?;
    file.sync_all()
}

/// A directory as a [`stscam_base::store::BlobStore`]: a blob is a file of that name in it,
/// written whole or not at all ([`write_all_atomic`]).
#[derive(Clone, Debug)]
pub struct DirStore {
    /// The directory (created on the first write).
    pub dir: PathBuf,
}

impl DirStore {
    /// The store in `dir`.
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        DirStore { dir: dir.into() }
    }
}

impl stscam_base::store::BlobStore for DirStore {
    /// The blob's bytes if it is a regular file within the binary-input limit (a FIFO, a
    /// device or a link to one is not read: no blob), read as every input is.
    fn load(&self, name: &str) -> Option<Vec<u8>> {
        crate::input::read_input(&self.dir.join(name), crate::input::MAX_BINARY_BYTES).ok()
    }

    fn save(&self, name: &str, bytes: &[u8]) -> Result<PathBuf, String> {
        write_all_atomic(&self.dir, &[(name, bytes)])
            .map(|()| self.dir.join(name))
            .map_err(|e| e.to_string())
    }

    fn location(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A blob that is a FIFO or a link to /dev/zero is not read (no hang, no growth).
    #[test]
    #[cfg(unix)]
    fn dir_store_reads_only_regular_files() {
        use stscam_base::store::BlobStore;
        let dir = tempfile::tempdir().unwrap();
        let store = DirStore::new(dir.path());
        store.save("a.bin", b"abc").unwrap();
        assert_eq!(store.load("a.bin").as_deref(), Some(&b"abc"[..]));
        std::os::unix::fs::symlink("/dev/zero", dir.path().join("z.bin")).unwrap();
        assert!(store.load("z.bin").is_none());
        let fifo = dir.path().join("f.bin");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            assert!(store.load("f.bin").is_none());
        }
    }

    #[test]
    fn writes_and_replaces_without_leftovers() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.bin");
        write_atomic(&path, b"first").unwrap();
        write_atomic(&path, b"second").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"second");
        let names: Vec<_> = fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out.bin")]);
    }

    #[test]
    fn several_files_commit_together_or_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        write_all_atomic(&out, &[("a.txt", b"1"), ("b.txt", b"2")]).unwrap();
        assert_eq!(fs::read(out.join("b.txt")).unwrap(), b"2");
        // The temp write of "c.txt" succeeds but "no/such/d.txt" cannot be written: nothing
        // may be renamed into place.
        let fresh = dir.path().join("fresh");
        let err = write_all_atomic(&fresh, &[("c.txt", b"3"), ("no/such/d.txt", b"4")]);
        assert!(err.is_err());
        assert!(
            !fresh.exists(),
            "a failed call must not leave its new directory behind"
        );
        // In an existing directory a failure leaves only what was there before.
        let err = write_all_atomic(&out, &[("c.txt", b"3"), ("no/such/d.txt", b"4")]);
        assert!(err.is_err());
        let mut names: Vec<_> = fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        names.sort();
        assert_eq!(
            names,
            vec![
                std::ffi::OsString::from("a.txt"),
                std::ffi::OsString::from("b.txt")
            ]
        );
    }

    /// Links planted at the next temporary and staging names this process will try (and at
    /// the target) are skipped, not followed: the file they point to is unchanged.
    #[cfg(unix)]
    #[test]
    fn planted_links_at_temporary_names_are_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let victim = dir.path().join("victim");
        fs::write(&victim, b"precious").unwrap();
        let out = dir.path().join("out");
        fs::create_dir(&out).unwrap();
        let next = SEQ.load(Ordering::Relaxed);
        let pid = std::process::id();
        for n in next..next + 64 {
            let _ = std::os::unix::fs::symlink(&victim, out.join(format!(".a.bin.tmp-{pid}-{n}")));
            let _ =
                std::os::unix::fs::symlink(&victim, out.join(format!("{STAGE_PREFIX}{pid}-{n}")));
        }
        std::os::unix::fs::symlink(&victim, out.join("b.bin")).unwrap();
        write_atomic(&out.join("a.bin"), b"A").unwrap();
        write_all_atomic(&out, &[("b.bin", b"B"), ("c.bin", b"C")]).unwrap();
        assert_eq!(fs::read(&victim).unwrap(), b"precious");
        assert_eq!(fs::read(out.join("a.bin")).unwrap(), b"A");
        assert!(fs::symlink_metadata(out.join("b.bin")).unwrap().is_file());
        assert_eq!(fs::read(out.join("b.bin")).unwrap(), b"B");
        assert!(!out.join(COMMIT_LOCK).exists());
    }

    /// A staging folder of a dead process is deleted without its marker and rolled forward
    /// with it.
    #[test]
    fn recovery_rolls_forward_or_back() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        fs::write(out.join("x.txt"), b"old").unwrap();
        fs::write(out.join("y.txt"), b"old").unwrap();
        // pid 0 is never a user process; u32::MAX - 1 is beyond pid_max.
        let dead = u32::MAX - 1;
        let a = out.join(format!("{STAGE_PREFIX}{dead}-0"));
        fs::create_dir(&a).unwrap();
        fs::write(a.join("x.txt"), b"half").unwrap();
        assert_eq!(recover_folder(out).unwrap(), (0, 1));
        assert_eq!(fs::read(out.join("x.txt")).unwrap(), b"old");
        let b = out.join(format!("{STAGE_PREFIX}{dead}-1"));
        fs::create_dir(&b).unwrap();
        fs::write(b.join("y.txt"), b"new").unwrap();
        fs::write(b.join(COMMIT_MARKER), b"").unwrap();
        // x.txt was already renamed before the kill.
        fs::write(out.join("x.txt"), b"new").unwrap();
        assert_eq!(recover_folder(out).unwrap(), (1, 0));
        assert_eq!(fs::read(out.join("y.txt")).unwrap(), b"new");
        let mut names: Vec<_> = fs::read_dir(out)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        names.sort();
        assert_eq!(names, ["x.txt", "y.txt"]);
    }

    #[test]
    fn missing_directory_is_an_error_naming_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("no/such/dir/out.bin");
        let err = write_atomic(&path, b"x").unwrap_err();
        assert!(matches!(err, IoError::Io { .. }));
        assert!(err.to_string().contains("out.bin"));
    }
}
