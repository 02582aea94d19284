//! The dataset error, reported on one line, and the helpers that make one.

use std::path::Path;

use crate::io::IoError;

/// A dataset error, reported on one line. [`DatasetError::Write`] is a failed write (exit
/// code 1 in the CLI); every other variant is the user's to fix (recipe, images, output
/// folder, shards, a concurrent run: exit code 2).
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A recipe key (or the recipe file) is wrong.
    #[error("{file}: {key}: {message}")]
    Recipe {
        /// Recipe file.
        file: String,
        /// Key path (empty for syntax errors).
        key: String,
        /// What is wrong.
        message: String,
    },
    /// A file could not be read (or an input is malformed).
    #[error(transparent)]
    Io(#[from] IoError),
    /// A file or folder of the output could not be written (full disk, permissions): not
    /// the recipe's fault, so the CLI exits with code 1 for it.
    #[error(transparent)]
    Write(IoError),
    /// Another run is working in the output folder.
    #[error(transparent)]
    Locked(crate::io::LockError),
    /// The output folder or the shards are not usable as asked.
    #[error("{path}: {message}")]
    Output {
        /// The folder or file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// The run was cancelled ([`crate::cancel`]); what was finished is kept for `--resume`.
    #[error("cancelled")]
    Cancelled,
}

/// A failed write of `path`.
pub(crate) fn write_err(path: &Path, e: std::io::Error) -> DatasetError {
    DatasetError::Write(IoError::io(path, e))
}

pub(crate) fn out_err(path: &Path, message: impl Into<String>) -> DatasetError {
    DatasetError::Output {
        path: path.display().to_string(),
        message: message.into(),
    }
}

pub(crate) fn recipe_err(
    file: &Path,
    key: impl Into<String>,
    message: impl Into<String>,
) -> DatasetError {
    DatasetError::Recipe {
        file: file.display().to_string(),
        key: key.into(),
        message: message.into(),
    }
}
