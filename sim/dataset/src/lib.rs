//! Datasets for learned reconstruction: (object, capture) pairs with H, from a recipe.
//!
//! A recipe (`recipe.rs`) fixes everything: scene and overrides, object sources
//! (`objects.rs`), sample count and split, sensor noise, capture mode and per-sample scene
//! variation. Sample `i` has the seed `S_i = hash(recipe seed, i)` (53 bits); its object draw,
//! its scene choice, its Monte Carlo render (render mode) and its sensor noise all derive from
//! `S_i` alone, so any sample can be regenerated on its own and any shard split gives the same
//! bytes. H of each distinct scene uses its own seed `hash(recipe seed, scene index)`.
//!
//! Captures: `matrix` mode g = H f + offset (H and the offset of the sample's scene, exact for
//! the flat-display model), `render` mode an independent render of f at the recipe's spp. With
//! sensor noise the value is measured by `noise.rs` (exposure fixed once for the whole
//! dataset from the reference scene's all-white capture, like a camera with fixed exposure),
//! converted back to capture units with the mean dark offset removed. The reference scene is
//! the first distinct scene (every varied key at its first value; ranged keys as in the scene).
//!
//! Layout (Hugging Face imagefolder): `train/`, `val/`, `test/` with, per sample,
//! `ID_object.npy` (float32 [h, w], linear intensity f), `ID_object.png` (16-bit display code
//! values f^(1/γ): the image that shown on the display gives f), `ID_capture.npy` (float32
//! [h, w], or [c, h, w] for colour sensors; capture units), `ID_capture.png` (16-bit,
//! round(65535·clamp(g / full scale))) and a `metadata.jsonl`; `scene_NNN/` with `H.npz`,
//! `offset.npy`, `H.json` and `scene.json` per distinct scene; `dataset.json` (the card:
//! recipe, version, counts, seeds, units, sha256 and size of every file).
//!
//! Robustness: every file is written to a temporary name and renamed into place; a run keeps
//! `.stscam-run.json` until it finishes; `--resume` removes temporary files of a killed run,
//! keeps finished samples (all four files present) and regenerates the rest, which gives the
//! same bytes as an uninterrupted run. A shard (`I/N`: samples `[I·S/N, (I+1)·S/N)`) writes
//! `shard.json` instead of `dataset.json`; [`merge`] joins shards, checking recipe, coverage and
//! every checksum, and writes exactly what one unsharded run writes.
//!
//! Layer: datasets for learning: recipes, objects, shards, generation, cards, merge.
//! May depend on: stscam-base, stscam-io, stscam-optics, stscam-scene, stscam-world, stscam-tracer (docs/design.md, "Crates"; checked by `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod depth;
pub mod meshes;
pub mod objects;
pub mod recipe;

mod card;
mod error;
mod folder;
mod generate;
mod merge;
mod plan;
mod shard;

// The layers below, under the names this crate's modules use (`crate::io::…`).
use stscam_base::{VERSION, cancel, limits, noise, progress, sparse, targets};
use stscam_io as io;
use stscam_scene as scene;
use stscam_tracer::{matrix, output, render, system};
use stscam_world as world;
use stscam_world::display;

pub use self::card::{Card, FORMAT, FileEntry, ShardCard};
pub use self::error::DatasetError;
pub use self::folder::RUN_MARKER;
pub use self::generate::{RunOptions, RunSummary, generate};
pub use self::merge::merge;
pub use self::plan::{
    MESH_FILES, ObjectArrays, Plan, PlannedScene, SampleSpec, plan, plan_with_objects, sha256_hex,
};
pub use self::shard::{MAX_SHARDS, Shard};
