//! The output folder of a run: its lock, the in-progress marker, the checks and clean-up of
//! `--resume`, and the writes of files.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::card::{Card, ShardCard};
use crate::error::{DatasetError, out_err, write_err};
use crate::generate::RunOptions;
use crate::io::IoError;
use crate::plan::Plan;
use crate::shard::Shard;

/// Name of the in-progress marker.
pub const RUN_MARKER: &str = ".stscam-run.json";

#[derive(Serialize, Deserialize, PartialEq)]
struct RunMarker {
    recipe_sha256: String,
    shard: Option<Shard>,
}

/// Removes the temporary files (`.NAME.tmp-PID`) a killed run left in `root` and its
/// sub-folders; returns how many.
fn remove_temporaries(root: &Path) -> Result<usize, DatasetError> {
    let mut n = 0;
    let mut dirs = vec![root.to_path_buf()];
    while let Some(d) = dirs.pop() {
        for e in std::fs::read_dir(&d).map_err(|e| IoError::Io {
            path: d.clone(),
            source: e,
        })? {
            let e = e.map_err(|e| IoError::Io {
                path: d.clone(),
                source: e,
            })?;
            let p = e.path();
            let name = e.file_name().to_string_lossy().into_owned();
            if p.is_dir() {
                dirs.push(p);
            } else if name.starts_with('.') && name.contains(".tmp-") {
                std::fs::remove_file(&p).map_err(|e| write_err(&p, e))?;
                n += 1;
            }
        }
    }
    Ok(n)
}

/// Locks `out` for this run (see [`crate::io::lock`]): a second run in the same folder is
/// refused while this one works.
pub(crate) fn lock_out(out: &Path) -> Result<crate::io::FolderLock, DatasetError> {
    crate::io::FolderLock::acquire(out).map_err(|e| match e {
        crate::io::LockError::Io(e) => DatasetError::Write(e),
        held => DatasetError::Locked(held),
    })
}

/// Whether `out` is a folder with something in it.
pub(crate) fn is_nonempty_folder(out: &Path) -> Result<bool, DatasetError> {
    Ok(out.is_dir()
        && std::fs::read_dir(out)
            .map_err(|e| IoError::Io {
                path: out.to_path_buf(),
                source: e,
            })?
            .next()
            .is_some())
}

/// Checks and prepares the output folder and locks it for the run.
pub(crate) fn prepare_out(
    plan: &Plan,
    opts: &RunOptions,
) -> Result<crate::io::FolderLock, DatasetError> {
    let out = &opts.out;
    let marker = RunMarker {
        recipe_sha256: plan.recipe_sha256.clone(),
        shard: opts.shard,
    };
    let nonempty = is_nonempty_folder(out)?;
    if out.exists() && !out.is_dir() {
        return Err(out_err(out, "exists and is not a folder"));
    }
    let lock = if nonempty {
        if !opts.resume {
            return Err(out_err(
                out,
                "is not empty: pass --resume to continue the run that wrote it, or choose another --out",
            ));
        }
        let lock = lock_out(out)?;
        let found: Option<RunMarker> = crate::io::read_input(&out.join(RUN_MARKER), 1 << 20)
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok())
            .or_else(|| {
                let card = if opts.shard.is_some() {
                    "shard.json"
                } else {
                    "dataset.json"
                };
                let b = crate::io::read_input(&out.join(card), crate::io::MAX_BINARY_BYTES).ok()?;
                if let Some(s) = opts.shard {
                    let c: ShardCard = serde_json::from_slice(&b).ok()?;
                    Some(RunMarker {
                        recipe_sha256: c.card.recipe_sha256,
                        shard: Some(s).filter(|s| *s == c.shard),
                    })
                } else {
                    let c: Card = serde_json::from_slice(&b).ok()?;
                    Some(RunMarker {
                        recipe_sha256: c.recipe_sha256,
                        shard: None,
                    })
                }
            });
        match found {
            Some(m) if m == marker => {}
            Some(_) => {
                return Err(out_err(
                    out,
                    "was written by a different recipe or shard; --resume needs the same recipe and --shard",
                ));
            }
            None => {
                return Err(out_err(
                    out,
                    "is not a stscam dataset run (no .stscam-run.json); cannot --resume it",
                ));
            }
        }
        remove_temporaries(out)?;
        lock
    } else {
        std::fs::create_dir_all(out).map_err(|e| write_err(out, e))?;
        lock_out(out)?
    };
    let bytes = serde_json::to_vec_pretty(&marker).map_err(|e| out_err(out, e.to_string()))?;
    crate::io::write_atomic(&out.join(RUN_MARKER), &bytes).map_err(DatasetError::Write)?;
    Ok(lock)
}

/// Writes a file of a sample: temporary name, rename (no fsync per file; the card is synced).
pub(crate) fn put(root: &Path, rel: &str, bytes: &[u8]) -> Result<(), DatasetError> {
    crate::io::atomic::write_atomic_unsynced(&root.join(rel), bytes)
        .map_err(DatasetError::Write)?;
    Ok(())
}
