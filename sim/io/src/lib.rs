//! File input/output for the simulator: atomic writes, OpenEXR (including the
//! spectral-EXR channel layout), 16-bit PNG encoding with a preview tone map,
//! loading of display images from PNG or EXR, and NumPy `.npy`/`.npz` files
//! (including scipy.sparse CSR matrices), checked reads of user-named input files and an
//! exclusive lock on an output folder.
//!
//! Layer: file formats and safe writes: npy/npz (scipy CSR), OpenEXR, PNG, image loading, checked input reads, atomic output sets, folder locks, H stacks on disk, plots.
//! May depend on: stscam-base (docs/design.md, "Crates"; checked by `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod atomic;
pub mod exr;
pub mod hfile;
pub mod image_load;
pub mod input;
pub mod lock;
pub mod npz;
pub mod plot;
pub mod png;
pub mod stack;
// The layers below, under the names this crate's modules use (`crate::io::…`).
use stscam_base::{limits, sparse, targets};

use std::path::{Path, PathBuf};

pub use self::atomic::{DirStore, write_all_atomic, write_atomic};
pub use self::exr::{ExrAttr, ExrChannel, encode_exr, read_exr, spectral_channel_name};
pub use self::image_load::{LoadedImage, load_image};
pub use self::input::{MAX_BINARY_BYTES, MAX_TEXT_BYTES, check_input_file, read_input, read_text};
pub use self::lock::{FolderLock, LockError};
pub use self::npz::{
    CsrParts, decode_csr_npz, decode_npy_f32, encode_csr_npz, encode_npy_f32, read_csr_npz,
    read_npy_f32,
};
pub use self::png::{PngTransfer, encode_png16, preview_u16};

/// Largest pixel count accepted when reading an image, so that a corrupt or
/// hostile header cannot trigger a huge allocation.
pub(crate) const MAX_PIXELS: usize = 1 << 28;

/// The first value of `values` that is not a finite float32 (NaN or infinite; a float64
/// beyond float32's range becomes infinite when read), as (index, value).
pub fn first_nonfinite(values: &[f32]) -> Option<(usize, f32)> {
    values
        .iter()
        .position(|v| !v.is_finite())
        .map(|i| (i, values[i]))
}

/// Refuses the first non-finite value of `values` read from `path` (`what` names the array,
/// e.g. `data.npy: entry` or `value`), naming its index.
pub fn check_finite(path: &Path, what: &str, values: &[f32]) -> Result<(), IoError> {
    match first_nonfinite(values) {
        None => Ok(()),
        Some((i, v)) => Err(IoError::format(
            path,
            format!(
                "{what} {i} is {v}, not a finite float32 (NaN, infinite, or beyond ±3.40282e38)"
            ),
        )),
    }
}

/// An error while reading or writing a file; always names the file.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The operating system reported an error (missing file, permissions, …).
    #[error("{}: {source}", path.display())]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The file (or the request) is not in a form this module can handle.
    #[error("{}: {message}", path.display())]
    Format {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong, on one line.
        message: String,
    },
}

impl IoError {
    /// Builds an [`IoError::Io`] for `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        IoError::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    /// Builds an [`IoError::Format`] for `path`, folding the message onto one line.
    pub fn format(path: &Path, message: impl std::fmt::Display) -> Self {
        let message = message.to_string();
        IoError::Format {
            path: path.to_path_buf(),
            message: message.split_whitespace().collect::<Vec<_>>().join(" "),
        }
    }
}
