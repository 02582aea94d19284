//! The scene error: one line naming the source (file or `--set`), the key and the problem.

/// A scene error: one line naming the source (file or `--set`), the key and the problem.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("{file}: cannot read scene file: {message}")]
    Read {
        /// Scene file.
        file: String,
        /// OS error text.
        message: String,
    },
    /// TOML syntax error.
    #[error("{file}: {location}: malformed TOML: {message}")]
    Syntax {
        /// Scene file.
        file: String,
        /// "line L, column C".
        location: String,
        /// Parser message.
        message: String,
    },
    /// A key-specific problem (unknown key, wrong type, out of range, missing asset).
    #[error("{file}: {key}: {message}")]
    Key {
        /// Scene file, or `--set`.
        file: String,
        /// Dotted key, e.g. `plate.thickness_mm`.
        key: String,
        /// What is wrong.
        message: String,
    },
}
