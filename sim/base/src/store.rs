//! A store of named byte blobs that the caller hands to a kernel to keep what it computed once
//! (the RCWA tables): the kernel encodes, checks and decodes its own bytes, the store only keeps
//! them. The directory store is `stscam_io::DirStore`; a kernel given no store builds every time.

use std::path::PathBuf;

/// Named blobs a kernel may read back and write (a cache passed in, never found by itself).
pub trait BlobStore: Sync {
    /// The bytes stored under `name` (None if there are none or they cannot be read: a cache
    /// that cannot be read is rebuilt, never an error).
    fn load(&self, name: &str) -> Option<Vec<u8>>;
    /// Stores `bytes` under `name` whole or not at all; where they went, or why not.
    fn save(&self, name: &str, bytes: &[u8]) -> Result<PathBuf, String>;
    /// Where `name` is or would be stored (for reports).
    fn location(&self, name: &str) -> PathBuf;
}
