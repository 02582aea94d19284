//! Checked reads of files a user names (scenes, recipes, captures, matrices, images, JSON
//! sidecars and curves).
//!
//! Model: a file is read whole only after its metadata says it is a regular file (a
//! directory, a FIFO, a socket or a device such as `/dev/zero` is refused at once, without
//! opening it, so a FIFO nobody writes to cannot block the run) and its size is at most a
//! limit given by the caller (so a multi-gigabyte or sparse file given as a scene is refused
//! before any allocation). The read itself stops one byte past the limit, so a file that
//! grows between the check and the read cannot exceed it either. Errors are
//! [`IoError`]s naming the file.

use std::io::Read;
use std::path::Path;

use super::IoError;

/// Largest text file (scene, recipe, JSON sidecar or curve) read whole: 64 MiB.
pub const MAX_TEXT_BYTES: u64 = 64 << 20;

/// Largest binary input (capture, offset, matrix archive, image) read whole: 4 GiB.
pub const MAX_BINARY_BYTES: u64 = 4 << 30;

/// What kind of non-regular file the metadata describes, for the message.
fn kind_of(meta: &std::fs::Metadata) -> &'static str {
    let ft = meta.file_type();
    if ft.is_dir() {
        return "a directory";
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if ft.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if ft.is_char_device() || ft.is_block_device() {
            return "a device";
        }
        if ft.is_socket() {
            return "a socket";
        }
    }
    "not a regular file"
}

/// Checks that `path` is a regular file of at most `max_bytes` bytes and returns its size.
pub fn check_input_file(path: &Path, max_bytes: u64) -> Result<u64, IoError> {
    let meta = std::fs::metadata(path).map_err(|e| IoError::io(path, e))?;
    if !meta.is_file() {
        return Err(IoError::format(
            path,
            format!("is {}, not a regular file", kind_of(&meta)),
        ));
    }
    if meta.len() > max_bytes {
        return Err(IoError::format(
            path,
            format!(
                "is {} bytes, more than the {} bytes accepted for this input",
                meta.len(),
                max_bytes
            ),
        ));
    }
    Ok(meta.len())
}

/// Reads a regular file of at most `max_bytes` bytes whole (see the module header).
pub fn read_input(path: &Path, max_bytes: u64) -> Result<Vec<u8>, IoError> {
    let len = check_input_file(path, max_bytes)?;
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let mut buf = Vec::new();
    buf.try_reserve_exact(usize::try_from(len).unwrap_or(usize::MAX))
        .map_err(|_| IoError::format(path, format!("cannot allocate {len} bytes to read it")))?;
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut buf)
        .map_err(|e| IoError::io(path, e))?;
    if buf.len() as u64 > max_bytes {
        return Err(IoError::format(
            path,
            format!("grew past the {max_bytes} bytes accepted for this input while being read"),
        ));
    }
    Ok(buf)
}

/// Reads a UTF-8 text file of at most [`MAX_TEXT_BYTES`] bytes.
pub fn read_text(path: &Path) -> Result<String, IoError> {
    let bytes = read_input(path, MAX_TEXT_BYTES)?;
    String::from_utf8(bytes).map_err(|e| {
        IoError::format(
            path,
            format!(
                "is not UTF-8 text (invalid byte at offset {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(r: Result<impl std::fmt::Debug, IoError>) -> String {
        r.expect_err("must fail").to_string()
    }

    #[test]
    fn devices_directories_and_fifos_are_refused_without_reading() {
        let m = message(read_input(Path::new("/dev/zero"), 1 << 20));
        assert!(m.contains("/dev/zero") && m.contains("a device"), "{m}");
        let dir = tempfile::tempdir().unwrap();
        let m = message(read_text(dir.path()));
        assert!(m.contains("a directory"), "{m}");
        let fifo = dir.path().join("pipe");
        let ok = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .is_ok_and(|s| s.success());
        if ok {
            // Nobody writes to the FIFO: opening it would block this test forever.
            let m = message(read_text(&fifo));
            assert!(m.contains("FIFO"), "{m}");
        }
    }

    #[test]
    fn size_limit_is_checked_before_reading() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("sparse.toml");
        let f = std::fs::File::create(&p).unwrap();
        // A sparse 5 GiB file: refused from its metadata, nothing is allocated.
        f.set_len(5 << 30).unwrap();
        let m = message(read_text(&p));
        assert!(
            m.contains("5368709120 bytes") && m.contains("67108864"),
            "{m}"
        );
        // At the limit it is read.
        f.set_len(16).unwrap();
        assert_eq!(read_input(&p, 16).unwrap().len(), 16);
        assert!(read_input(&p, 15).is_err());
    }

    #[test]
    fn text_must_be_utf8() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.toml");
        std::fs::write(&p, [b'a', 0xff, b'b']).unwrap();
        let m = message(read_text(&p));
        assert!(m.contains("not UTF-8") && m.contains("offset 1"), "{m}");
    }
}
