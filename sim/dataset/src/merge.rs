//! Merging of finished shards into one dataset, byte-identical to an unsharded run.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;

use crate::card::{FileEntry, ShardCard, file_entry};
use crate::error::{DatasetError, out_err, write_err};
use crate::folder::{RUN_MARKER, is_nonempty_folder, lock_out, put};
use crate::generate::RunSummary;
use crate::io::IoError;
use crate::recipe::SPLITS;

/// Joins shard folders into `out` (which must not exist or be empty): checks that they come
/// from one recipe, that shards 0..N−1 are each present once and finished, and every file's
/// checksum; copies the files, concatenates the metadata in id order and writes the card.
/// The result is byte-identical to an unsharded run.
pub fn merge(shards: &[PathBuf], out: &Path) -> Result<RunSummary, DatasetError> {
    let t0 = Instant::now();
    if shards.is_empty() {
        return Err(out_err(out, "no shard folders given"));
    }
    let cards = read_shard_cards(shards)?;
    check_shards(&cards, out)?;
    let first = &cards[0].1;
    // Verify every file before writing anything.
    let (mut files, origin) = verified_files(&cards)?;
    let nonempty = is_nonempty_folder(out)?;
    if nonempty || (out.exists() && !out.is_dir()) {
        return Err(out_err(out, "exists and is not empty"));
    }
    std::fs::create_dir_all(out).map_err(|e| write_err(out, e))?;
    let _lock = lock_out(out)?;
    crate::io::write_atomic(&out.join(RUN_MARKER), b"{\"merge\": true}\n")
        .map_err(DatasetError::Write)?;
    origin
        .par_iter()
        .try_for_each(|(rel, d)| -> Result<(), DatasetError> {
            let dst = out.join(rel);
            if let Some(parent) = dst.parent() {
                std::fs::create_dir_all(parent).map_err(|e| write_err(parent, e))?;
            }
            let bytes = crate::io::read_input(&d.join(rel), crate::io::MAX_BINARY_BYTES)?;
            put(out, rel, &bytes)
        })?;
    let counts = merge_metadata(&cards, out, &mut files)?;
    let scenes = merged_scenes(&cards);
    let mut card = first.card.clone();
    card.samples = counts.values().sum();
    if card.samples != card.recipe.samples {
        let _ = std::fs::remove_dir_all(out);
        return Err(out_err(out, "the shards do not cover every sample"));
    }
    card.counts = counts;
    card.scenes = scenes.into_values().collect();
    card.files = files;
    let bytes = serde_json::to_vec_pretty(&card).map_err(|e| out_err(out, e.to_string()))?;
    crate::io::write_atomic(&out.join("dataset.json"), &bytes).map_err(DatasetError::Write)?;
    std::fs::remove_file(out.join(RUN_MARKER)).map_err(|e| write_err(&out.join(RUN_MARKER), e))?;
    Ok(RunSummary {
        samples: card.samples,
        generated: 0,
        scenes_s: 0.0,
        samples_s: 0.0,
        samples_per_s: 0.0,
        finish_s: t0.elapsed().as_secs_f64(),
    })
}

/// The shard cards of `shards` (each folder's shard.json), in shard order.
fn read_shard_cards(shards: &[PathBuf]) -> Result<Vec<(PathBuf, ShardCard)>, DatasetError> {
    let mut cards: Vec<(PathBuf, ShardCard)> = Vec::new();
    for d in shards {
        let p = d.join("shard.json");
        if !p.is_file() {
            return Err(out_err(
                d,
                "has no shard.json (not a finished shard; finish it with --resume)",
            ));
        }
        let bytes = crate::io::read_input(&p, crate::io::MAX_BINARY_BYTES)?;
        let c: ShardCard = serde_json::from_slice(&bytes)
            .map_err(|e| out_err(&p, format!("not a shard card: {e}")))?;
        cards.push((d.clone(), c));
    }
    cards.sort_by_key(|c| c.1.shard.index);
    Ok(cards)
}

/// Checks that the shards of `cards` (in shard order) come from one recipe, stscam version and
/// exposure and are shards 0..N−1 each once.
fn check_shards(cards: &[(PathBuf, ShardCard)], out: &Path) -> Result<(), DatasetError> {
    let first = &cards[0].1;
    let n = first.shard.count;
    for (d, c) in cards {
        if c.card.recipe_sha256 != first.card.recipe_sha256
            || c.card.stscam_version != first.card.stscam_version
        {
            return Err(out_err(
                d,
                "comes from a different recipe or stscam version than the other shards",
            ));
        }
        if c.shard.count != n {
            return Err(out_err(
                d,
                format!(
                    "is shard {}/{} but others are of {n}",
                    c.shard.index, c.shard.count
                ),
            ));
        }
        if c.card.exposure != first.card.exposure {
            return Err(out_err(d, "has a different exposure than the other shards"));
        }
    }
    let indices: Vec<usize> = cards.iter().map(|c| c.1.shard.index).collect();
    if indices != (0..n).collect::<Vec<_>>() {
        return Err(out_err(
            out,
            format!("need shards 0..{n} each exactly once, got {indices:?}"),
        ));
    }
    Ok(())
}

/// Every shard's files checked against its card's checksums; the files to copy (all but the
/// metadata, the same in every shard that has them) with their entries and the shard folder
/// each is copied from.
#[allow(clippy::type_complexity)]
fn verified_files(
    cards: &[(PathBuf, ShardCard)],
) -> Result<(BTreeMap<String, FileEntry>, BTreeMap<String, PathBuf>), DatasetError> {
    // Verify every file before writing anything.
    let mut files: BTreeMap<String, FileEntry> = BTreeMap::new();
    let mut origin: BTreeMap<String, PathBuf> = BTreeMap::new();
    for (d, c) in cards {
        let checks: Vec<Result<(), DatasetError>> = c
            .card
            .files
            .par_iter()
            .map(|(rel, want)| {
                let got = file_entry(d, rel)?;
                if &got != want {
                    return Err(out_err(
                        &d.join(rel),
                        "checksum differs from shard.json (corrupted or modified)",
                    ));
                }
                Ok(())
            })
            .collect();
        checks.into_iter().collect::<Result<(), _>>()?;
        for (rel, e) in &c.card.files {
            if rel.ends_with("metadata.jsonl") {
                continue;
            }
            if let Some(prev) = files.get(rel) {
                if prev != e {
                    return Err(out_err(&d.join(rel), "differs between shards"));
                }
            } else {
                files.insert(rel.clone(), e.clone());
                origin.insert(rel.clone(), d.clone());
            }
        }
    }
    Ok((files, origin))
}

/// The metadata of each split, the shards' concatenated in shard (= id) order, written to
/// `out` and entered in `files`; returns the sample count of each split.
fn merge_metadata(
    cards: &[(PathBuf, ShardCard)],
    out: &Path,
    files: &mut BTreeMap<String, FileEntry>,
) -> Result<BTreeMap<String, usize>, DatasetError> {
    // Metadata: concatenate per split in shard (= id) order.
    let mut counts = BTreeMap::new();
    for split in SPLITS {
        let rel = format!("{split}/metadata.jsonl");
        let mut text = String::new();
        for (d, c) in cards {
            if c.card.files.contains_key(&rel) {
                text.push_str(
                    &std::fs::read_to_string(d.join(&rel)).map_err(|e| IoError::Io {
                        path: d.join(&rel),
                        source: e,
                    })?,
                );
            }
        }
        let lines = text.lines().count();
        counts.insert(split.to_string(), lines);
        if lines > 0 {
            put(out, &rel, text.as_bytes())?;
            files.insert(rel.clone(), file_entry(out, &rel)?);
        }
    }
    Ok(counts)
}

/// The union of the shards' scenes, in index order (ids sort as indices).
fn merged_scenes(cards: &[(PathBuf, ShardCard)]) -> BTreeMap<String, serde_json::Value> {
    // Scenes: union, in index order (ids sort as indices).
    let mut scenes: BTreeMap<String, serde_json::Value> = BTreeMap::new();
    for (_, c) in cards {
        for s in &c.card.scenes {
            let id = s
                .get("id")
                .and_then(|v| v.as_str())
                .unwrap_or_default()
                .to_string();
            scenes.entry(id).or_insert_with(|| s.clone());
        }
    }
    scenes
}
