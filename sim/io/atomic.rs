//! Atomic file replacement: write to a temporary file in the target's
//! directory, flush and fsync it, then rename it over the target, so readers
//! never see a partially written file.

use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};

use super::IoError;

/// Writes `bytes` to `path` atomically.
///
/// The data goes to `.<filename>.tmp-<pid>` in the same directory, is flushed
/// and fsynced, and is then renamed over `path`. On any error the temporary
/// file is removed and `path` is left untouched.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let file_name = path
        .file_name()
        .ok_or_else(|| IoError::format(path, "path has no file name"))?;
    let dir = match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(file_name);
    tmp_name.push(format!(".tmp-{}", std::process::id()));
    let tmp = dir.join(tmp_name);

    let result = write_and_sync(&tmp, bytes).and_then(|()| fs::rename(&tmp, path));
    match result {
        Ok(()) => {
            // Persist the rename itself; not all platforms can open directories,
            // and the data is already safely in place, so failures are ignored.
            if let Ok(d) = File::open(&dir) {
                let _ = d.sync_all();
            }
            Ok(())
        }
        Err(e) => {
            let _ = fs::remove_file(&tmp);
            Err(IoError::io(path, e))
        }
    }
}

/// Writes `bytes` to `path` through a temporary file and a rename, without fsync: readers and
/// a later run never see a partial file, even if this process is killed, but the data may not
/// survive a power loss until the OS flushes it. For the many per-sample files of a dataset,
/// where a per-file fsync would dominate the run time.
pub fn write_atomic_unsynced(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let tmp = temp_path(path)?;
    let result = fs::write(&tmp, bytes).and_then(|()| fs::rename(&tmp, path));
    result.map_err(|e| {
        let _ = fs::remove_file(&tmp);
        IoError::io(path, e)
    })
}

fn temp_path(path: &Path) -> Result<PathBuf, IoError> {
    let file_name = path
        .file_name()
        .ok_or_else(|| IoError::format(path, "path has no file name"))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(file_name);
    tmp_name.push(format!(".tmp-{}", std::process::id()));
    Ok(path.with_file_name(tmp_name))
}

/// Writes several files into `dir` as one unit: `dir` is created if needed, every file is
/// first written and synced under a temporary name, and only when all writes succeeded are
/// they renamed into place. On failure the temporary files are removed, and `dir` too if this
/// call created it and it is empty, so nothing new is left behind.
pub fn write_all_atomic(dir: &Path, files: &[(&str, &[u8])]) -> Result<(), IoError> {
    let created = !dir.exists();
    fs::create_dir_all(dir).map_err(|e| IoError::io(dir, e))?;
    let mut temps: Vec<(PathBuf, PathBuf)> = Vec::new();
    let cleanup = |temps: &[(PathBuf, PathBuf)]| {
        for (tmp, _) in temps {
            let _ = fs::remove_file(tmp);
        }
        if created {
            let _ = fs::remove_dir(dir);
        }
    };
    for (name, bytes) in files {
        let path = dir.join(name);
        let tmp = match temp_path(&path) {
            Ok(t) => t,
            Err(e) => {
                cleanup(&temps);
                return Err(e);
            }
        };
        if let Err(e) = write_and_sync(&tmp, bytes) {
            let _ = fs::remove_file(&tmp);
            cleanup(&temps);
            return Err(IoError::io(&path, e));
        }
        temps.push((tmp, path));
    }
    // A target that exists but is not a regular file would make its rename fail after others
    // succeeded: refuse before renaming anything.
    if let Some((_, bad)) = temps.iter().find(|(_, p)| p.exists() && !p.is_file()) {
        let bad = bad.clone();
        cleanup(&temps);
        return Err(IoError::format(&bad, "exists and is not a regular file"));
    }
    for (i, (tmp, path)) in temps.iter().enumerate() {
        if let Err(e) = fs::rename(tmp, path) {
            cleanup(&temps[i..]);
            return Err(IoError::io(path, e));
        }
    }
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

fn write_and_sync(tmp: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut file = File::create(tmp)?;
    file.write_all(bytes)?;
    file.flush()?;
    file.sync_all()
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn missing_directory_is_an_error_naming_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("no/such/dir/out.bin");
        let err = write_atomic(&path, b"x").unwrap_err();
        assert!(matches!(err, IoError::Io { .. }));
        assert!(err.to_string().contains("out.bin"));
    }
}
