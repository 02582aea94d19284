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

// The layers below, under the names this crate's modules use (`crate::io::…`).
use stscam_base::{VERSION, cancel, limits, noise, progress, sparse, targets};
use stscam_io as io;
use stscam_scene as scene;
use stscam_world as world;
use stscam_world::display;
use stscam_tracer::{matrix, output, render, system};

use std::borrow::Cow;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::io::IoError;
use crate::matrix::{SystemMatrix, compute_matrix};
use crate::noise::{NoiseRng, SensorNoise};
use crate::render::{RenderSettings, render};
use crate::scene::{LoadedScene, load_scene};
use crate::sparse::CsrMatrix;
use crate::system::System;

use objects::{ObjectDraw, ObjectSpec, draw, list_images};
use recipe::{
    CaptureMode, DEPTH_KEY, NoiseModel, Recipe, Resize, SPLITS, Source, fmt_value, parse_recipe,
};

/// Format tag of the dataset card.
pub const FORMAT: &str = "stscam-dataset/1";
/// Name of the in-progress marker.
pub const RUN_MARKER: &str = ".stscam-run.json";

const SAMPLE_TAG: u64 = 0x5341_4D50;
const SCENE_TAG: u64 = 0x5343_454E;
const VARY_TAG: u64 = 0x5641_5259;
const WHITE_TAG: u64 = 0x5748_4954;
const DEPTH_TAG: u64 = 0x4445_5054;

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
fn write_err(path: &Path, e: std::io::Error) -> DatasetError {
    DatasetError::Write(IoError::io(path, e))
}

fn out_err(path: &Path, message: impl Into<String>) -> DatasetError {
    DatasetError::Output {
        path: path.display().to_string(),
        message: message.into(),
    }
}

/// One distinct scene of the recipe (a combination of the `values` lists).
#[derive(Clone, Debug)]
pub struct PlannedScene {
    /// Folder name, `scene_NNN`.
    pub id: String,
    /// Overrides after the recipe's own.
    pub overrides: Vec<String>,
    /// Varied keys and their values.
    pub params: BTreeMap<String, f64>,
    /// The loaded, validated scene.
    pub loaded: LoadedScene,
    /// Its runtime system.
    pub system: System,
}

/// A recipe checked against everything it refers to, ready to generate.
#[derive(Clone, Debug)]
pub struct Plan {
    /// The recipe.
    pub recipe: Recipe,
    /// Recipe file.
    pub recipe_path: PathBuf,
    /// SHA-256 of the canonical JSON form of the recipe.
    pub recipe_sha256: String,
    /// Scene file, resolved.
    scene_file: Option<PathBuf>,
    /// The recipe's overrides and the object size, before any varied key.
    base_overrides: Vec<String>,
    /// Distinct discrete scenes (index 0 is the reference scene).
    pub scenes: Vec<PlannedScene>,
    /// Image files (mesh files for `meshes`) per source.
    images: Vec<Vec<(PathBuf, String)>>,
    /// The `[depth]` grid in mm (empty without one).
    pub depths_mm: Vec<f64>,
    /// True if every sample's scene is one of `scenes` (no ranged keys): H is written.
    pub has_matrix: bool,
    /// Samples per split.
    pub counts: [usize; 3],
    /// Digits in sample ids.
    pub id_width: usize,
    /// Objects given as arrays (sample i's object is array i), instead of the recipe's sources.
    arrays: Option<ObjectArrays>,
}

/// Objects given in memory (the Python module's `build_dataset(objects=...)`): `n` images of
/// the recipe's `objects.size_px`², as linear intensities or display code values.
#[derive(Clone, Debug)]
pub struct ObjectArrays {
    values: Vec<f32>,
    n: usize,
    size: usize,
    linear: bool,
}

impl ObjectArrays {
    /// `n` objects of `size`² values each (row-major, object-major); `linear` false means
    /// display code values in [0, 1] (the display gamma is applied, as for generated objects),
    /// true linear intensity. Refuses a wrong length and values outside [0, 1] or not finite.
    pub fn new(values: Vec<f32>, n: usize, size: usize, linear: bool) -> Result<Self, String> {
        if n == 0 || size == 0 || n.checked_mul(size * size) != Some(values.len()) {
            return Err(format!(
                "objects: {} values are not {n} objects of {size}x{size} pixels",
                values.len()
            ));
        }
        if let Some(i) = values.iter().position(|v| !(0.0..=1.0).contains(v)) {
            return Err(format!(
                "objects: value {i} ({}) is outside [0, 1] (object {}, pixel {})",
                values[i],
                i / (size * size),
                i % (size * size)
            ));
        }
        Ok(ObjectArrays {
            values,
            n,
            size,
            linear,
        })
    }

    /// SHA-256 of the values and their encoding: part of the recipe hash, so that shards,
    /// resume and merge refuse to mix datasets of different arrays.
    fn sha256(&self) -> String {
        let mut bytes: Vec<u8> = Vec::with_capacity(self.values.len() * 4 + 32);
        bytes.extend(
            format!(
                "{}x{}x{} linear={};",
                self.n, self.size, self.size, self.linear
            )
            .bytes(),
        );
        self.values
            .iter()
            .for_each(|v| bytes.extend(v.to_le_bytes()));
        sha256_hex(&bytes)
    }
}

/// Everything about one sample that follows from the recipe and its id, without pixels.
#[derive(Clone, Debug)]
pub struct SampleSpec {
    /// Global id.
    pub id: usize,
    /// Split index (0 train, 1 val, 2 test).
    pub split: usize,
    /// Sample seed.
    pub seed: u64,
    /// Object draw.
    pub object: ObjectDraw,
    /// Index of its discrete scene.
    pub scene: usize,
    /// Values of every varied key.
    pub params: BTreeMap<String, f64>,
}

/// The recipe key of a sample's object source.
fn source_key(s: &SampleSpec) -> String {
    format!("objects.sources[{}]", s.object.source)
}

fn recipe_err(file: &Path, key: impl Into<String>, message: impl Into<String>) -> DatasetError {
    DatasetError::Recipe {
        file: file.display().to_string(),
        key: key.into(),
        message: message.into(),
    }
}

fn sha256_hex(bytes: &[u8]) -> String {
    let d = Sha256::digest(bytes);
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// Loads the scene with `base` and `extra` overrides and builds its system; errors name the
/// recipe and `key`.
fn load_system(
    scene_file: Option<&Path>,
    base: &[String],
    extra: &[String],
    recipe_path: &Path,
    key: &str,
) -> Result<(LoadedScene, System), DatasetError> {
    let overrides: Vec<String> = base.iter().chain(extra).cloned().collect();
    let ls = load_scene(scene_file, &overrides)
        .map_err(|e| recipe_err(recipe_path, key, e.to_string()))?;
    let sys = System::build(&ls).map_err(|e| recipe_err(recipe_path, key, e.to_string()))?;
    if sys.display.primaries.is_some() {
        return Err(recipe_err(
            recipe_path,
            key,
            "display.primaries: datasets have one object plane; a colour display (\"lcd\") is not supported by datasets yet",
        ));
    }
    Ok((ls, sys))
}

/// The ground-truth files of a 3-D sample after its capture: `ID_frontal.npy`,
/// `ID_frontal.png`, `ID_depth.npy`, `ID_mask.png`.
pub const MESH_FILES: [&str; 4] = ["frontal.npy", "frontal.png", "depth.npy", "mask.png"];

/// The depth index of the sample with seed `seed` among `n` depths: `rand`'s `Uniform` over a
/// ChaCha12 generator seeded from `NoiseRng([seed, DEPTH_TAG])`.
fn depth_index(seed: u64, n: usize) -> usize {
    use rand::SeedableRng;
    use rand::distr::{Distribution, Uniform};
    let mut rng =
        rand::rngs::ChaCha12Rng::seed_from_u64(NoiseRng::new(&[seed, DEPTH_TAG]).next_u64());
    Uniform::new(0, n.max(1)).map_or(0, |d| d.sample(&mut rng))
}

/// The mesh files of a `meshes` source's folder, each loaded once so that a broken file stops
/// the run before anything is written.
fn mesh_files(
    recipe_path: &Path,
    base: &Path,
    i: usize,
    folder: &str,
    m: &recipe::MeshSource,
    scene: &LoadedScene,
) -> Result<Vec<(PathBuf, String)>, DatasetError> {
    let key = format!("objects.sources[{i}].folder");
    let files = folder_files(
        recipe_path,
        &base.join(folder),
        &key,
        ".gltf, .glb or .obj",
        |d| meshes::list_meshes(d, folder),
    )?;
    files
        .par_iter()
        .try_for_each(|(p, name)| {
            let o = crate::world::desc::ObjectDesc {
                mesh: p.display().to_string(),
                name: Some(name.clone()),
                position_mm: [0.0; 3],
                rotation_deg: [0.0; 3],
                scale: crate::world::desc::ScaleSpec::Uniform(1.0),
                units: m.units.clone(),
                material: None,
                pose: None,
            };
            crate::world::placed_object(scene, 0, &o).map(|_| ())
        })
        .map_err(|e| recipe_err(recipe_path, &key, e.to_string()))?;
    Ok(files)
}

/// The files `list` finds in the folder `dir` of recipe key `key`; an error if `dir` is not a
/// folder or holds none (`what`: the kinds of file, for the message).
fn folder_files(
    recipe_path: &Path,
    dir: &Path,
    key: &str,
    what: &str,
    list: impl FnOnce(&Path) -> Result<Vec<(PathBuf, String)>, String>,
) -> Result<Vec<(PathBuf, String)>, DatasetError> {
    if !dir.is_dir() {
        return Err(recipe_err(
            recipe_path,
            key,
            format!("{} is not a folder", dir.display()),
        ));
    }
    let files = list(dir).map_err(|m| recipe_err(recipe_path, key, m))?;
    if files.is_empty() {
        return Err(recipe_err(
            recipe_path,
            key,
            format!("no {what} files in {}", dir.display()),
        ));
    }
    Ok(files)
}

/// Reads and checks a recipe and everything it names (scene file, overrides, every distinct
/// scene, image folders), without writing anything.
pub fn plan(recipe_path: &Path) -> Result<Plan, DatasetError> {
    plan_with_objects(recipe_path, None)
}

/// [`plan`] with the objects given as arrays: sample i's object is array i, the recipe's
/// `samples` becomes the number of arrays and its object sources are not drawn from. The
/// arrays must be `objects.size_px` square; 2-D recipes only (not `meshes`).
pub fn plan_with_objects(
    recipe_path: &Path,
    arrays: Option<ObjectArrays>,
) -> Result<Plan, DatasetError> {
    let text = crate::io::read_text(recipe_path)?;
    let mut recipe = parse_recipe(&text).map_err(|(k, m)| recipe_err(recipe_path, k, m))?;
    if let Some(a) = &arrays {
        check_arrays(recipe_path, &recipe, a)?;
        recipe.samples = a.n;
    }
    let base = recipe_path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf);
    let canonical =
        serde_json::to_vec(&recipe).map_err(|e| recipe_err(recipe_path, "", e.to_string()))?;
    let recipe_sha256 = match &arrays {
        None => sha256_hex(&canonical),
        Some(a) => {
            sha256_hex(format!("{}+arrays:{}", sha256_hex(&canonical), a.sha256()).as_bytes())
        }
    };
    let scene_file = recipe.scene.file.as_ref().map(|f| base.join(f));
    let mut base_overrides = recipe.scene.set.clone();
    base_overrides.push(format!("display.image=black@{}", recipe.objects.size_px));
    let load = |extra: &[String], key: &str| {
        load_system(
            scene_file.as_deref(),
            &base_overrides,
            extra,
            recipe_path,
            key,
        )
    };
    let scenes = planned_scenes(&recipe, &load)?;
    // Ranged keys: both ends must give valid scenes.
    for (i, v) in recipe.vary.iter().enumerate() {
        if let Some([lo, hi]) = v.range {
            for x in [lo, hi] {
                load(
                    &[format!("{}={}", v.key, fmt_value(x))],
                    &format!("vary[{i}].range"),
                )?;
            }
        }
    }
    let images = object_files(recipe_path, &base, &recipe, &scenes)?;
    // 3-D datasets have no H (the display's H says nothing of a mesh).
    let has_matrix = !recipe.is_meshes() && recipe.vary.iter().all(|v| v.values.is_some());
    check_run_limits(recipe_path, &recipe, &scenes)?;
    let counts = recipe.split_counts();
    let id_width = (recipe.samples - 1).to_string().len().max(6);
    let depths_mm = match &recipe.depth {
        Some(d) => d
            .depths_mm()
            .map_err(|(k, m)| recipe_err(recipe_path, k, m))?,
        None => Vec::new(),
    };
    Ok(Plan {
        recipe,
        recipe_path: recipe_path.to_path_buf(),
        recipe_sha256,
        scene_file,
        base_overrides,
        scenes,
        images,
        depths_mm,
        has_matrix,
        counts,
        id_width,
        arrays,
    })
}

/// Checks object arrays `a` against the recipe: a 2-D recipe, the objects' size, at most
/// [`recipe::MAX_SAMPLES`] of them.
fn check_arrays(recipe_path: &Path, recipe: &Recipe, a: &ObjectArrays) -> Result<(), DatasetError> {
    if recipe.is_meshes() {
        return Err(recipe_err(
            recipe_path,
            "objects.sources",
            "objects given as arrays replace 2-D sources; a `meshes` recipe has 3-D objects",
        ));
    }
    if a.size != recipe.objects.size_px {
        return Err(recipe_err(
            recipe_path,
            "objects.size_px",
            format!(
                "the recipe's objects are {0}x{0} pixels but the arrays are {1}x{1}",
                recipe.objects.size_px, a.size
            ),
        ));
    }
    if a.n > recipe::MAX_SAMPLES {
        return Err(recipe_err(
            recipe_path,
            "samples",
            format!("{} arrays: at most {} samples", a.n, recipe::MAX_SAMPLES),
        ));
    }
    Ok(())
}

/// The recipe's distinct scenes (one per combination of listed `vary` values), each loaded by
/// `load(overrides, key)` and moved to its `[depth]` distance.
fn planned_scenes(
    recipe: &Recipe,
    load: &impl Fn(&[String], &str) -> Result<(LoadedScene, System), DatasetError>,
) -> Result<Vec<PlannedScene>, DatasetError> {
    let mut scenes = Vec::new();
    for (k, (overrides, params)) in recipe.discrete_scenes().into_iter().enumerate() {
        let key = if params.is_empty() { "scene" } else { "vary" };
        let (loaded, mut system) = load(&overrides, key)?;
        if let Some(&d) = params.get(DEPTH_KEY) {
            system = depth::at_depth(&system, d);
        }
        scenes.push(PlannedScene {
            id: format!("scene_{k:03}"),
            overrides,
            params,
            loaded,
            system,
        });
    }
    Ok(scenes)
}

/// The files of each object source (none for built-in targets): image folders listed with
/// every header read (so a file that is not an image stops the run before anything is
/// written), mesh folders listed.
fn object_files(
    recipe_path: &Path,
    base: &Path,
    recipe: &Recipe,
    scenes: &[PlannedScene],
) -> Result<Vec<Vec<(PathBuf, String)>>, DatasetError> {
    let mut images = Vec::new();
    for (i, src) in recipe.objects.sources.iter().enumerate() {
        if let Source::Images {
            folder, recursive, ..
        } = src
        {
            let key = format!("objects.sources[{i}].folder");
            let files = folder_files(
                recipe_path,
                &base.join(folder),
                &key,
                ".png, .jpg or .jpeg",
                |d| list_images(d, folder, *recursive),
            )?;
            // Every header is read now, so that a file that is not an image stops the run
            // before anything is written (pixel data is decoded when a sample draws it).
            files
                .par_iter()
                .try_for_each(|(p, _)| crate::io::image_load::probe_image(p).map(|_| ()))
                .map_err(|e| recipe_err(recipe_path, &key, e.to_string()))?;
            images.push(files);
        } else if let Source::Meshes(m) = src {
            let files = match &m.folder {
                Some(folder) => mesh_files(recipe_path, base, i, folder, m, &scenes[0].loaded)?,
                None => Vec::new(),
            };
            images.push(files);
        } else {
            images.push(Vec::new());
        }
    }
    Ok(images)
}

/// The render limits of every scene for the run's renders: one H per scene, the white capture
/// and, in render mode, one render per sample.
fn check_run_limits(
    recipe_path: &Path,
    recipe: &Recipe,
    scenes: &[PlannedScene],
) -> Result<(), DatasetError> {
    let renders = scenes.len() as u64
        + 1
        + if recipe.mode == CaptureMode::Render {
            recipe.samples as u64
        } else {
            0
        };
    for ps in scenes {
        crate::render::check_limits(
            &ps.system,
            &RenderSettings::lattice(recipe.spp, 0, false),
            renders,
            "spp",
        )
        .map_err(|e| recipe_err(recipe_path, "spp", e.message))?;
    }
    // 3-D recipes: every sample's frontal ground truth.
    if recipe.is_meshes() {
        let side = recipe.objects.size_px as u128;
        let paths = side * side * u128::from(recipe.objects.frontal_spp(recipe.spp));
        let key = match recipe.objects.frontal_spp {
            Some(_) => "objects.frontal_spp",
            None => "objects.size_px",
        };
        crate::limits::check_paths(key, paths * recipe.samples as u128)
            .map_err(|e| recipe_err(recipe_path, key, e.message))?;
    }
    Ok(())
}

impl Plan {
    /// The seed of sample `id`.
    pub fn sample_seed(&self, id: usize) -> u64 {
        NoiseRng::new(&[self.recipe.seed, SAMPLE_TAG, id as u64]).next_u64() >> 11
    }

    /// Everything about sample `id` except its pixels.
    pub fn sample(&self, id: usize) -> SampleSpec {
        let seed = self.sample_seed(id);
        let split = if id < self.counts[0] {
            0
        } else if id < self.counts[0] + self.counts[1] {
            1
        } else {
            2
        };
        let mut rng = NoiseRng::new(&[seed, VARY_TAG]);
        let mut scene = 0;
        let mut params = BTreeMap::new();
        for v in &self.recipe.vary {
            if let Some(vals) = &v.values {
                let k = ((rng.uniform() * vals.len() as f64) as usize).min(vals.len() - 1);
                scene = scene * vals.len() + k;
                params.insert(v.key.clone(), vals[k]);
            } else if let Some([lo, hi]) = v.range {
                params.insert(v.key.clone(), lo + (hi - lo) * rng.uniform());
            }
        }
        if !self.depths_mm.is_empty() {
            let k = depth_index(seed, self.depths_mm.len());
            scene = scene * self.depths_mm.len() + k;
            params.insert(DEPTH_KEY.to_string(), self.depths_mm[k]);
        }
        SampleSpec {
            id,
            split,
            seed,
            object: match &self.arrays {
                Some(_) => ObjectDraw {
                    source: 0,
                    spec: ObjectSpec::Array { index: id },
                    levels: None,
                },
                None => draw(&self.recipe.objects, &self.images, seed),
            },
            scene,
            params,
        }
    }

    /// File name stem of sample `id` (zero-padded).
    pub fn stem(&self, id: usize) -> String {
        format!("{id:0width$}", width = self.id_width)
    }

    /// The files of a sample, relative to the dataset root: object `.npy` and `.png`, capture
    /// `.npy` and `.png`; for `meshes` capture `.npy` and `.png`, then [`MESH_FILES`].
    pub fn sample_files(&self, s: &SampleSpec) -> Vec<String> {
        let (d, stem) = (SPLITS[s.split], self.stem(s.id));
        let kinds: &[&str] = if self.recipe.is_meshes() {
            &[
                "capture.npy",
                "capture.png",
                MESH_FILES[0],
                MESH_FILES[1],
                MESH_FILES[2],
                MESH_FILES[3],
            ]
        } else {
            &["object.npy", "object.png", "capture.npy", "capture.png"]
        };
        kinds.iter().map(|k| format!("{d}/{stem}_{k}")).collect()
    }

    /// The 3-D draw of a sample, settled on the user side, and the mesh's world bounds.
    fn mesh_draw(
        &self,
        s: &SampleSpec,
        src: &recipe::MeshSource,
        files: &[(PathBuf, String)],
        ls: &LoadedScene,
    ) -> Result<(meshes::MeshDraw, [[f64; 3]; 2]), DatasetError> {
        let mut d = meshes::draw(src, files, s.seed);
        let b = d
            .settle(ls, src.units.as_deref())
            .map_err(|e| recipe_err(&self.recipe_path, source_key(s), e.to_string()))?;
        Ok((d, b))
    }

    /// The `meshes` source of a 3-D sample and its mesh files.
    fn mesh_source(&self, s: &SampleSpec) -> Option<(&recipe::MeshSource, &[(PathBuf, String)])> {
        match &self.recipe.objects.sources[s.object.source] {
            Source::Meshes(m) => Some((m, &self.images[s.object.source])),
            _ => None,
        }
    }

    /// Sample `s`'s object as linear intensities (`objects.size_px`², row-major), with the
    /// display `gamma` for code values.
    fn object_of(&self, s: &SampleSpec, gamma: f64) -> Result<Vec<f64>, DatasetError> {
        match (&s.object.spec, &self.arrays) {
            (ObjectSpec::Array { index }, Some(a)) => {
                let px = a.size * a.size;
                let v = &a.values[index * px..(index + 1) * px];
                Ok(crate::display::Display::intensity_of(v, 1, a.linear, gamma))
            }
            _ => s
                .object
                .intensity(
                    self.recipe.objects.size_px,
                    gamma,
                    self.resize_of(s.object.source),
                )
                .map_err(|m| recipe_err(&self.recipe_path, source_key(s), m)),
        }
    }

    fn resize_of(&self, source: usize) -> Resize {
        match &self.recipe.objects.sources[source] {
            Source::Images { resize, .. } => *resize,
            _ => Resize::CenterCrop,
        }
    }

    /// The seed of H of distinct scene `k`; the depths of one scene share it (their H see the
    /// same camera rays, as in a one-pass depth stack).
    fn scene_seed(&self, k: usize) -> u64 {
        let k = k / self.depths_mm.len().max(1);
        NoiseRng::new(&[self.recipe.seed, SCENE_TAG, k as u64]).next_u64() >> 11
    }

    /// The files of distinct scene `k`, relative to the root.
    pub fn scene_files(&self, k: usize) -> Vec<String> {
        let id = &self.scenes[k].id;
        let mut f = vec![format!("{id}/scene.json")];
        if self.has_matrix {
            for n in ["H.npz", "offset.npy", "H.json"] {
                f.push(format!("{id}/{n}"));
            }
        }
        f
    }

    /// Whether every sample's design is one of the planned scenes (no ranged `vary` key,
    /// which draws a design per sample).
    fn designs_planned(&self) -> bool {
        self.recipe.vary.iter().all(|v| v.values.is_some())
    }

    /// The scene of a sample: its discrete scene, or with ranged keys one built for it.
    #[allow(clippy::type_complexity)]
    fn sample_scene(
        &self,
        s: &SampleSpec,
    ) -> Result<(Cow<'_, LoadedScene>, Cow<'_, System>), DatasetError> {
        if self.designs_planned() {
            let ps = &self.scenes[s.scene];
            return Ok((Cow::Borrowed(&ps.loaded), Cow::Borrowed(&ps.system)));
        }
        let extra: Vec<String> = s
            .params
            .iter()
            .map(|(k, v)| format!("{k}={}", fmt_value(*v)))
            .collect();
        let (ls, sys) = load_system(
            self.scene_file.as_deref(),
            &self.base_overrides,
            &extra,
            &self.recipe_path,
            "vary",
        )?;
        Ok((Cow::Owned(ls), Cow::Owned(sys)))
    }
}

/// Which part of a dataset a run makes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    /// Index, 0-based.
    pub index: usize,
    /// Number of shards.
    pub count: usize,
}

/// Most shards of one dataset (a SLURM array holds at most a few hundred thousand tasks; a
/// larger N is a typo, and every shard writes a manifest).
pub const MAX_SHARDS: usize = 1_000_000;

impl Shard {
    /// Parses `I/N` (0 ≤ I < N ≤ [`MAX_SHARDS`]).
    pub fn parse(spec: &str) -> Result<Shard, String> {
        let (i, n) = spec
            .split_once('/')
            .ok_or_else(|| format!("{spec:?} is not I/N"))?;
        let (i, n) = (
            i.trim()
                .parse::<usize>()
                .map_err(|_| format!("{spec:?}: I is not an integer"))?,
            n.trim()
                .parse::<usize>()
                .map_err(|_| format!("{spec:?}: N is not an integer"))?,
        );
        if n == 0 || i >= n {
            return Err(format!("{spec:?}: need 0 <= I < N"));
        }
        if n > MAX_SHARDS {
            return Err(format!("{spec:?}: N must be at most {MAX_SHARDS}"));
        }
        Ok(Shard { index: i, count: n })
    }

    /// The shard from the environment of a cluster engine: SLURM job arrays
    /// (`SLURM_ARRAY_TASK_ID` − `SLURM_ARRAY_TASK_MIN`, `SLURM_ARRAY_TASK_COUNT`) or a
    /// Kubernetes Indexed Job (`JOB_COMPLETION_INDEX`, with the count in
    /// `STSCAM_SHARD_COUNT`). `None` if neither is set.
    pub fn from_env(get: impl Fn(&str) -> Option<String>) -> Result<Option<Shard>, String> {
        let num = |k: &str| -> Result<Option<usize>, String> {
            match get(k) {
                None => Ok(None),
                Some(v) => v
                    .trim()
                    .parse::<usize>()
                    .map(Some)
                    .map_err(|_| format!("environment variable {k}={v:?} is not an integer")),
            }
        };
        if let Some(id) = num("SLURM_ARRAY_TASK_ID")? {
            let count = num("SLURM_ARRAY_TASK_COUNT")?
                .ok_or("SLURM_ARRAY_TASK_ID is set but SLURM_ARRAY_TASK_COUNT is not")?;
            let min = num("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
            let index = id
                .checked_sub(min)
                .ok_or("SLURM_ARRAY_TASK_ID is below SLURM_ARRAY_TASK_MIN")?;
            return Shard::parse(&format!("{index}/{count}"))
                .map(Some)
                .map_err(|e| format!("from SLURM_ARRAY_TASK_*: {e} (use a contiguous --array)"));
        }
        if let Some(index) = num("JOB_COMPLETION_INDEX")? {
            let count = num("STSCAM_SHARD_COUNT")?.ok_or(
                "JOB_COMPLETION_INDEX is set but STSCAM_SHARD_COUNT (the Job's completions) is not",
            )?;
            return Shard::parse(&format!("{index}/{count}"))
                .map(Some)
                .map_err(|e| format!("from JOB_COMPLETION_INDEX: {e}"));
        }
        Ok(None)
    }

    /// Sample ids of this shard among `samples`.
    pub fn range(&self, samples: usize) -> std::ops::Range<usize> {
        self.index * samples / self.count..(self.index + 1) * samples / self.count
    }
}

/// Options of a run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Output folder.
    pub out: PathBuf,
    /// Part to make (None: all).
    pub shard: Option<Shard>,
    /// Continue a run in `out`.
    pub resume: bool,
    /// Progress bar on a terminal.
    pub progress: bool,
}

/// What a run did.
#[derive(Clone, Debug, Serialize)]
pub struct RunSummary {
    /// Samples of this run (shard).
    pub samples: usize,
    /// Samples generated now (the rest were already finished).
    pub generated: usize,
    /// Seconds spent on H and the exposure.
    pub scenes_s: f64,
    /// Seconds spent generating samples.
    pub samples_s: f64,
    /// Generated samples per second.
    pub samples_per_s: f64,
    /// Seconds to finish (checksums, metadata, card).
    pub finish_s: f64,
}

/// The dataset card (`dataset.json`). A shard's `shard.json` is the card of its part plus the
/// shard fields.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Card {
    /// Format tag.
    pub format: String,
    /// Recipe name.
    pub name: String,
    /// Recipe description.
    pub description: String,
    /// stscam version that generated it.
    pub stscam_version: String,
    /// The recipe, parsed (defaults filled in).
    pub recipe: Recipe,
    /// SHA-256 of the canonical JSON of `recipe`.
    pub recipe_sha256: String,
    /// Samples in the dataset.
    pub samples: usize,
    /// Samples per split, in this card.
    pub counts: BTreeMap<String, usize>,
    /// Object shape [height, width].
    pub object_shape: [usize; 2],
    /// Capture shape ([height, width] or [channels, height, width]).
    pub capture_shape: Vec<usize>,
    /// Capture channel names.
    pub channels: Vec<String>,
    /// Seeds.
    pub seeds: serde_json::Value,
    /// Units and encodings.
    pub units: BTreeMap<String, String>,
    /// Exposure and sensor noise.
    pub exposure: serde_json::Value,
    /// Distinct scenes with files in this card.
    pub scenes: Vec<serde_json::Value>,
    /// How to load it.
    pub loading: BTreeMap<String, String>,
    /// Every other file: relative path → {sha256, bytes}.
    pub files: BTreeMap<String, FileEntry>,
}

/// Checksum and size of a file.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileEntry {
    /// SHA-256, hex.
    pub sha256: String,
    /// Size in bytes.
    pub bytes: u64,
}

/// `shard.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ShardCard {
    /// The shard.
    pub shard: Shard,
    /// Its sample ids [start, end).
    pub ids: [usize; 2],
    /// The card of its part.
    pub card: Card,
}

#[derive(Serialize, Deserialize, PartialEq)]
struct RunMarker {
    recipe_sha256: String,
    shard: Option<Shard>,
}

/// H of one scene, in memory.
struct SceneMatrix {
    h: CsrMatrix,
    offset: Vec<f32>,
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
fn lock_out(out: &Path) -> Result<crate::io::FolderLock, DatasetError> {
    crate::io::FolderLock::acquire(out).map_err(|e| match e {
        crate::io::LockError::Io(e) => DatasetError::Write(e),
        held => DatasetError::Locked(held),
    })
}

/// Whether `out` is a folder with something in it.
fn is_nonempty_folder(out: &Path) -> Result<bool, DatasetError> {
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
fn prepare_out(plan: &Plan, opts: &RunOptions) -> Result<crate::io::FolderLock, DatasetError> {
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
fn put(root: &Path, rel: &str, bytes: &[u8]) -> Result<(), DatasetError> {
    crate::io::atomic::write_atomic_unsynced(&root.join(rel), bytes)
        .map_err(DatasetError::Write)?;
    Ok(())
}

fn npy(rel: &str, shape: &[usize], v: &[f32]) -> Result<Vec<u8>, DatasetError> {
    Ok(crate::io::npz::encode_npy_f32(Path::new(rel), shape, v)?)
}

/// The exposure of the dataset.
struct Exposure {
    white_peak: f64,
    full_scale: f64,
    noise: Option<SensorNoise>,
}

impl Exposure {
    /// The stored capture of a clean one: measured by the sensor model (pixel i with
    /// `NoiseRng([seed, NOISE_TAG, i])`) minus the mean dark offset, or as it is.
    fn measure(&self, clean: &[f64], seed: u64) -> Vec<f32> {
        match &self.noise {
            Some(n) => crate::noise::measure_capture(n, clean, seed),
            None => clean.iter().map(|&v| v as f32).collect(),
        }
    }
}

/// H of the incomplete depth scenes among `used`, one [`depth::depth_matrices`] call per
/// discrete scene (its depths share the seed); empty without `[depth]`.
fn depth_stack(
    plan: &Plan,
    root: &Path,
    used: &BTreeSet<usize>,
    progress: bool,
) -> BTreeMap<usize, SystemMatrix> {
    let n = plan.depths_mm.len();
    let mut out = BTreeMap::new();
    if n == 0 || !plan.has_matrix {
        return out;
    }
    let todo: Vec<usize> = used
        .iter()
        .copied()
        .filter(|&k| !plan.scene_files(k).iter().all(|f| root.join(f).is_file()))
        .collect();
    let groups: BTreeSet<usize> = todo.iter().map(|k| k / n).collect();
    for g in groups {
        let ks: Vec<usize> = todo.iter().copied().filter(|k| k / n == g).collect();
        let depths: Vec<f64> = ks.iter().map(|k| plan.depths_mm[k % n]).collect();
        let settings = RenderSettings::lattice(plan.recipe.spp, plan.scene_seed(ks[0]), progress);
        let ms = depth::depth_matrices(&plan.scenes[ks[0]].system, &depths, &settings);
        out.extend(ks.into_iter().zip(ms));
    }
    out
}

/// Generates a dataset (or one shard of it) into `opts.out`: the scenes (H, scene.json), the
/// exposure, the samples, then the metadata and card ([`Generation`]'s steps).
pub fn generate(plan: &Plan, opts: &RunOptions) -> Result<RunSummary, DatasetError> {
    let recipe = &plan.recipe;
    let ids = opts
        .shard
        .map_or(0..recipe.samples, |s| s.range(recipe.samples));
    // Held until the run ends (dropped on return, also on an error).
    let _lock = prepare_out(plan, opts)?;
    let run = Generation {
        plan,
        opts,
        root: &opts.out,
        cancel: crate::cancel::current(),
        tables: Default::default(),
        keys: Default::default(),
    };
    let t0 = Instant::now();
    let specs: Vec<SampleSpec> = ids.clone().map(|i| plan.sample(i)).collect();
    let done = |s: &SampleSpec| {
        plan.sample_files(s)
            .iter()
            .all(|f| run.root.join(f).is_file())
    };
    let todo: Vec<&SampleSpec> = specs.iter().filter(|s| !done(s)).collect();
    // Scenes: the reference scene 0 and every scene a sample of this run uses.
    let used: BTreeSet<usize> = std::iter::once(0)
        .chain(specs.iter().map(|s| s.scene))
        .collect();
    let need_h: BTreeSet<usize> = std::iter::once(0)
        .chain(
            todo.iter()
                .filter(|_| recipe.mode == CaptureMode::Matrix)
                .map(|s| s.scene),
        )
        .collect();
    let scenes = run.scenes(&used, &need_h)?;
    let exposure = run.exposure(&scenes.matrices)?;
    let scenes_s = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let generated = run.samples(&todo, &scenes, &exposure)?;
    let samples_s = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    run.finish(ids, &specs, used, scenes, &exposure)?;
    let finish_s = t2.elapsed().as_secs_f64();
    Ok(RunSummary {
        samples: specs.len(),
        generated,
        scenes_s,
        samples_s,
        samples_per_s: if samples_s > 0.0 {
            generated as f64 / samples_s
        } else {
            0.0
        },
        finish_s,
    })
}

/// What the steps of [`generate`] share: the plan, the run's options and output folder, and
/// the cancel token of the calling thread (checked between steps and samples).
struct Generation<'a> {
    plan: &'a Plan,
    opts: &'a RunOptions,
    root: &'a Path,
    cancel: crate::cancel::Token,
    /// Camera-side tables drawn so far, by design key (`[camera_table]`).
    tables: std::sync::Mutex<
        BTreeMap<[u64; 2], std::sync::Arc<crate::render::camera_table::CameraTable>>,
    >,
    /// Design keys of the planned scenes, by scene index (computed once: a key prints the
    /// whole camera side, milliseconds a sample otherwise).
    keys: std::sync::Mutex<BTreeMap<usize, [u64; 2]>>,
}

/// The scenes of a run: H and offset of each scene a matrix-mode sample needs, and the
/// sensor's crop and channel names (the same in every scene).
struct SceneSetup {
    matrices: BTreeMap<usize, SceneMatrix>,
    crop: (usize, usize),
    channel_names: Vec<String>,
}

impl Generation<'_> {
    /// `Err(Cancelled)` once the run was cancelled.
    fn check_cancel(&self) -> Result<(), DatasetError> {
        if self.cancel.is_cancelled() {
            Err(DatasetError::Cancelled)
        } else {
            Ok(())
        }
    }

    /// The object size of the recipe, pixels.
    fn object(&self) -> (usize, usize) {
        let n = self.plan.recipe.objects.size_px;
        (n, n)
    }

    /// Step 1: every scene of `used` written (scene.json, and H with its sidecar where the
    /// recipe has H) unless complete; H loaded or kept for the scenes of `need_h`.
    fn scenes(
        &self,
        used: &BTreeSet<usize>,
        need_h: &BTreeSet<usize>,
    ) -> Result<SceneSetup, DatasetError> {
        let (plan, root, object) = (self.plan, self.root, self.object());
        let mut matrices: BTreeMap<usize, SceneMatrix> = BTreeMap::new();
        let mut crop = (0, 0);
        let mut channel_names: Vec<String> = Vec::new();
        let mut stack = depth_stack(plan, root, used, self.opts.progress);
        for &k in used {
            let ps = &plan.scenes[k];
            let sys = &ps.system;
            crop = (sys.camera.width_px, sys.camera.height_px);
            channel_names = sys.response.names.iter().map(|s| s.to_string()).collect();
            let dir = root.join(&ps.id);
            let files = plan.scene_files(k);
            let complete = files.iter().all(|f| root.join(f).is_file());
            if plan.has_matrix && complete && need_h.contains(&k) {
                let m = crate::matrix::load_matrix(&dir.join("H.npz"), Some(object), None)?;
                let offset = m.offset.ok_or_else(|| {
                    out_err(
                        &dir.join("offset.npy"),
                        "missing; delete the scene folder and --resume",
                    )
                })?;
                matrices.insert(k, SceneMatrix { h: m.h, offset });
            } else if !complete && let Some(m) = self.write_scene(k, stack.remove(&k))? {
                matrices.insert(k, m);
            }
        }
        Ok(SceneSetup {
            matrices,
            crop,
            channel_names,
        })
    }

    /// Writes scene `k`'s folder: scene.json, and where the recipe has H, H (from the depth
    /// stack's `stacked`, else computed here) with its sidecar, which it returns.
    fn write_scene(
        &self,
        k: usize,
        stacked: Option<SystemMatrix>,
    ) -> Result<Option<SceneMatrix>, DatasetError> {
        let (plan, recipe, object) = (self.plan, &self.plan.recipe, self.object());
        let ps = &plan.scenes[k];
        let dir = self.root.join(&ps.id);
        let scene_json = serde_json::to_vec_pretty(&ps.loaded.scene)
            .map_err(|e| out_err(&dir, e.to_string()))?;
        if !plan.has_matrix {
            std::fs::create_dir_all(&dir).map_err(|e| write_err(&dir, e))?;
            crate::io::write_atomic(&dir.join("scene.json"), &scene_json)
                .map_err(DatasetError::Write)?;
            return Ok(None);
        }
        let m: SystemMatrix = stacked.unwrap_or_else(|| {
            compute_matrix(
                &ps.system,
                &RenderSettings::lattice(recipe.spp, plan.scene_seed(k), self.opts.progress),
            )
        });
        self.check_cancel()?;
        let sidecar = serde_json::json!({
            "object_px": [object.0, object.1],
            "crop_px": [m.crop.0, m.crop.1],
            "shape": [m.h.rows, m.h.cols],
            "nnz": m.h.nnz(),
            "channels": m.channels,
            "spp": recipe.spp,
            "seed": plan.scene_seed(k),
            "overrides": ps.overrides,
            "depth_mm": ps.params.get(DEPTH_KEY),
            "units": crate::matrix::MATRIX_UNITS,
            "stscam_version": crate::VERSION,
        });
        crate::output::write_matrix(&dir, &m, &sidecar).map_err(DatasetError::Write)?;
        crate::io::write_atomic(&dir.join("scene.json"), &scene_json)
            .map_err(DatasetError::Write)?;
        Ok(Some(SceneMatrix {
            h: m.h,
            offset: m.offset,
        }))
    }

    /// Step 2: the exposure, from the reference scene's all-white capture (H's where it has
    /// one, else rendered).
    fn exposure(&self, matrices: &BTreeMap<usize, SceneMatrix>) -> Result<Exposure, DatasetError> {
        let (recipe, object) = (&self.plan.recipe, self.object());
        let ref_sys = &self.plan.scenes[0].system;
        let white_peak = if let Some(m) = matrices.get(&0) {
            let g = m.h.mul_vec(&vec![1.0; m.h.cols]);
            g.iter()
                .zip(&m.offset)
                .map(|(a, &b)| a + f64::from(b))
                .fold(0.0, f64::max)
        } else {
            let white = vec![1.0; object.0 * object.1];
            let seed = NoiseRng::new(&[recipe.seed, WHITE_TAG]).next_u64() >> 11;
            // 3-D datasets: display white on the scene's display plane, without the scene's
            // objects.
            let mut flat = ref_sys.clone();
            if recipe.is_meshes() {
                flat.world = None;
            }
            render_object(&flat, &white, recipe.spp, seed)
                .into_iter()
                .fold(0.0f64, f64::max)
        };
        self.check_cancel()?;
        let noise_desc = &ref_sys.scene.noise;
        Ok(Exposure {
            white_peak,
            full_scale: white_peak / noise_desc.exposure_fraction,
            noise: (recipe.noise == NoiseModel::Sensor)
                .then(|| SensorNoise::new(noise_desc, white_peak)),
        })
    }

    /// Step 3: the samples of `todo` (in parallel with H, one by one when rendered); returns
    /// how many were made.
    fn samples(
        &self,
        todo: &[&SampleSpec],
        scenes: &SceneSetup,
        exposure: &Exposure,
    ) -> Result<usize, DatasetError> {
        let (plan, recipe) = (self.plan, &self.plan.recipe);
        let bar = progress_bar(self.opts.progress, todo.len());
        let counter = AtomicUsize::new(0);
        let made = || {
            counter.fetch_add(1, Ordering::Relaxed);
            bar.inc(1);
        };
        match recipe.mode {
            CaptureMode::Matrix => {
                todo.par_iter().try_for_each(|s| {
                    self.flat_sample(s, &plan.scenes[s.scene].system, scenes, exposure)
                        .map(|()| made())
                })?;
            }
            CaptureMode::Render if recipe.is_meshes() => {
                // A few samples at a time: one sample's serial steps (its world and BVH, the
                // frontal view, the files) overlap another's render, and memory stays bounded
                // (at most `chunk` worlds alive). Each sample's bytes depend on its seed only.
                self.draw_scene_tables(todo)?;
                let chunk = 2 * rayon::current_num_threads();
                for group in todo.chunks(chunk) {
                    group.par_iter().try_for_each(|s| {
                        self.check_cancel()?;
                        if self.mesh_sample(s, scenes.crop, exposure)? {
                            made();
                        }
                        Ok::<(), DatasetError>(())
                    })?;
                }
            }
            CaptureMode::Render => {
                for s in todo {
                    let (_, sys) = plan.sample_scene(s)?;
                    self.flat_sample(s, &sys, scenes, exposure)?;
                    made();
                }
            }
        }
        bar.finish_and_clear();
        self.check_cancel()?;
        Ok(counter.load(Ordering::Relaxed))
    }

    /// A sample of a flat object on the display: its object, its capture (with H or rendered
    /// in `sys`), measured and written.
    fn flat_sample(
        &self,
        s: &SampleSpec,
        sys: &System,
        scenes: &SceneSetup,
        exposure: &Exposure,
    ) -> Result<(), DatasetError> {
        let plan = self.plan;
        let gamma = sys.scene.display.gamma;
        let f = plan.object_of(s, gamma)?;
        let clean: Vec<f64> = match plan.recipe.mode {
            CaptureMode::Matrix => {
                let m = &scenes.matrices[&s.scene];
                let g = m.h.mul_vec(&f);
                g.iter()
                    .zip(&m.offset)
                    .map(|(a, &b)| a + f64::from(b))
                    .collect()
            }
            CaptureMode::Render => render_object(sys, &f, plan.recipe.spp, s.seed),
        };
        self.check_cancel()?;
        let capture = exposure.measure(&clean, s.seed);
        write_sample(
            plan,
            self.root,
            s,
            &f,
            &capture,
            scenes.crop,
            scenes.channel_names.len(),
            gamma,
            exposure.full_scale,
        )
    }

    /// The camera-side table of `sys`'s design, whose key is `key` (drawn on first use, then
    /// shared by every sample of the run with that design; seeded by the recipe, so every shard
    /// draws the same).
    fn camera_table(
        &self,
        sys: &System,
        key: [u64; 2],
        t: &recipe::TableRecipe,
    ) -> Result<std::sync::Arc<crate::render::camera_table::CameraTable>, DatasetError> {
        let known = {
            let tables = self.tables.lock().unwrap_or_else(|e| e.into_inner());
            tables.get(&key).cloned()
        };
        if let Some(t) = known {
            return Ok(t);
        }
        // Drawn without the lock: the draw's own rayon work may run a sibling sample on this
        // thread, which must not wait for a lock its own thread holds. (`samples` draws each
        // planned scene's table before the parallel loop, so a table is drawn once.)
        let ts = crate::render::camera_table::TableSettings {
            spp: t.spp,
            reps: t.reps,
            seed: self.plan.recipe.seed,
        };
        let err = |k: &str, e: crate::render::camera_table::TableError| {
            recipe_err(&self.plan.recipe_path, k, e.to_string())
        };
        let table = match &t.dir {
            None => crate::render::camera_table::build(sys, &ts, false)
                .map_err(|e| err("camera_table", e))?,
            Some(d) => {
                let dir = self
                    .plan
                    .recipe_path
                    .parent()
                    .unwrap_or(Path::new("."))
                    .join(d);
                crate::render::table_file::cached(sys, &ts, &dir, false)
                    .map_err(|e| err("camera_table.dir", e))?
                    .table
            }
        };
        let mut tables = self.tables.lock().unwrap_or_else(|e| e.into_inner());
        Ok(tables
            .entry(key)
            .or_insert_with(|| std::sync::Arc::new(table))
            .clone())
    }

    /// The design key of sample `s`, whose scene's system is `sys`. A mesh draw adds objects
    /// and lights, which the key leaves out: a planned scene's key serves all its samples
    /// (computed once); a design drawn per sample (`vary`) has its own.
    fn sample_design_key(&self, s: &SampleSpec, sys: &Cow<'_, System>) -> [u64; 2] {
        match sys {
            Cow::Borrowed(base) => *self
                .keys
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .entry(s.scene)
                .or_insert_with(|| crate::render::camera_table::design_key(base)),
            Cow::Owned(own) => crate::render::camera_table::design_key(own),
        }
    }

    /// Draws (or reads) the camera-side table of every planned scene that a mesh sample of
    /// `todo` renders, one scene at a time, before the samples run in parallel (designs drawn
    /// per sample get theirs with the sample).
    fn draw_scene_tables(&self, todo: &[&SampleSpec]) -> Result<(), DatasetError> {
        let Some(t) = self.plan.recipe.camera_table.as_ref() else {
            return Ok(());
        };
        if !self.plan.designs_planned() {
            return Ok(());
        }
        let mut done = BTreeSet::new();
        for s in todo {
            if self.plan.mesh_source(s).is_none() || !done.insert(s.scene) {
                continue;
            }
            let sys = Cow::Borrowed(&self.plan.scenes[s.scene].system);
            let key = self.sample_design_key(s, &sys);
            self.camera_table(&sys, key, t)?;
        }
        Ok(())
    }

    /// A sample of a 3-D scene: its meshes drawn, rendered with the frontal view, measured and
    /// written; `false` where the sample has no mesh source.
    fn mesh_sample(
        &self,
        s: &SampleSpec,
        crop: (usize, usize),
        exposure: &Exposure,
    ) -> Result<bool, DatasetError> {
        let (plan, recipe) = (self.plan, &self.plan.recipe);
        let (ls, sys) = plan.sample_scene(s)?;
        let Some((src, files)) = plan.mesh_source(s) else {
            return Ok(false);
        };
        let key = recipe
            .camera_table
            .as_ref()
            .map(|_| self.sample_design_key(s, &sys));
        let (d, _) = plan.mesh_draw(s, src, files, &ls)?;
        let sys = meshes::sample_system(&ls, &sys, &d, src.units.as_deref())
            .map_err(|e| recipe_err(&plan.recipe_path, source_key(s), e.to_string()))?;
        let space = recipe.objects.frontal_space();
        let band = &sys.scene.sampling;
        if space != crate::world::colour::FrontalSpace::Sensor
            && crate::world::colour::ColourWeights::new(
                space,
                band.lambda_min_nm,
                band.lambda_max_nm,
            )
            .is_none()
        {
            return Err(recipe_err(
                &plan.recipe_path,
                "objects.frontal_space",
                format!(
                    "{}: the CIE luminance function is 0 over the sampling band",
                    space.name()
                ),
            ));
        }
        let table = recipe
            .camera_table
            .as_ref()
            .zip(key)
            .map(|(t, key)| self.camera_table(&sys, key, t).map(|t| (t, key)))
            .transpose()?;
        let (clean, frontal) = meshes::render_sample(
            &sys,
            recipe.objects.size_px,
            [recipe.spp, recipe.objects.frontal_spp(recipe.spp)],
            s.seed,
            space,
            table.as_ref().map(|(t, key)| (&**t, *key)),
        )
        .map_err(|e| recipe_err(&plan.recipe_path, "camera_table", e.to_string()))?;
        let capture = exposure.measure(&clean, s.seed);
        write_mesh_sample(
            plan,
            self.root,
            s,
            &capture,
            &frontal,
            crop,
            exposure.full_scale,
        )?;
        Ok(true)
    }

    /// Step 4: metadata, checksums and the card (`dataset.json`, or a shard's `shard.json`
    /// for ids `ids`); then the run marker is removed.
    fn finish(
        &self,
        ids: std::ops::Range<usize>,
        specs: &[SampleSpec],
        used: BTreeSet<usize>,
        scenes: SceneSetup,
        exposure: &Exposure,
    ) -> Result<(), DatasetError> {
        let (plan, root) = (self.plan, self.root);
        let (crop, channel_names) = (scenes.crop, scenes.channel_names);
        let capture_shape = if channel_names.len() == 1 {
            vec![crop.1, crop.0]
        } else {
            vec![channel_names.len(), crop.1, crop.0]
        };
        let ctx = CardContext {
            plan,
            capture_shape,
            channels: channel_names,
            exposure: serde_json::json!({
                "rule": "fixed once for the whole dataset from the reference scene's all-white capture (scene_000)",
                "white_peak": exposure.white_peak,
                "capture_full_scale": exposure.full_scale,
                "noise_model": plan.recipe.noise,
                "sensor": plan.scenes[0].system.scene.noise,
                "electrons_per_unit": exposure.noise.as_ref().map(|n| n.electrons_per_unit),
            }),
        };
        let metadata: Vec<(usize, String)> = specs
            .par_iter()
            .map(|s| Ok((s.split, metadata_line(plan, s)?)))
            .collect::<Result<_, DatasetError>>()?;
        let scene_ids: Vec<usize> = used.into_iter().collect();
        let card = finish(root, &ctx, &metadata, &scene_ids, specs)?;
        let (name, bytes) = match self.opts.shard {
            Some(shard) => {
                let sc = ShardCard {
                    shard,
                    ids: [ids.start, ids.end],
                    card,
                };
                ("shard.json", serde_json::to_vec_pretty(&sc))
            }
            None => ("dataset.json", serde_json::to_vec_pretty(&card)),
        };
        let bytes = bytes.map_err(|e| out_err(root, e.to_string()))?;
        crate::io::write_atomic(&root.join(name), &bytes).map_err(DatasetError::Write)?;
        std::fs::remove_file(root.join(RUN_MARKER))
            .map_err(|e| write_err(&root.join(RUN_MARKER), e))
    }
}

/// The capture of object `f` (linear intensities) rendered by the tracer, channel-major.
fn render_object(sys: &System, f: &[f64], spp: u32, seed: u64) -> Vec<f64> {
    let mut s = sys.clone();
    s.display.set_intensity(f);
    let cap = render(&s, &RenderSettings::lattice(spp, seed, false));
    cap.channels
        .iter()
        .flatten()
        .map(|&v| f64::from(v))
        .collect()
}

fn progress_bar(show: bool, len: usize) -> crate::progress::Progress {
    crate::progress::Progress::new(show, len as u64, "samples")
}

#[allow(clippy::too_many_arguments)]
fn write_sample(
    plan: &Plan,
    root: &Path,
    s: &SampleSpec,
    f: &[f64],
    capture: &[f32],
    crop: (usize, usize),
    channels: usize,
    gamma: f64,
    full_scale: f64,
) -> Result<(), DatasetError> {
    let n = plan.recipe.objects.size_px;
    let files = plan.sample_files(s);
    let (on, op, cn, cp) = (&files[0], &files[1], &files[2], &files[3]);
    split_dir(root, s)?;
    let f32s: Vec<f32> = f.iter().map(|&v| v as f32).collect();
    put(root, on, &npy(on, &[n, n], &f32s)?)?;
    let png =
        crate::output::encode_object_png(f, n, n, gamma).map_err(|m| out_err(&root.join(op), m))?;
    put(root, op, &png)?;
    put_image(root, [cn, cp], capture, crop, channels, full_scale)
}

/// Creates the split folder of a sample.
fn split_dir(root: &Path, s: &SampleSpec) -> Result<(), DatasetError> {
    let dir = root.join(SPLITS[s.split]);
    if !dir.is_dir() {
        std::fs::create_dir_all(&dir).map_err(|e| write_err(&dir, e))?;
    }
    Ok(())
}

/// Writes an image `v` (channel-major, `size` = (w, h)) as float32 `.npy` ([h, w], or
/// [c, h, w] for several channels) and 16-bit linear PNG, round(65535·clamp(v / full_scale)).
fn put_image(
    root: &Path,
    [rel_npy, rel_png]: [&str; 2],
    v: &[f32],
    size: (usize, usize),
    channels: usize,
    full_scale: f64,
) -> Result<(), DatasetError> {
    let shape: Vec<usize> = if channels == 1 {
        vec![size.1, size.0]
    } else {
        vec![channels, size.1, size.0]
    };
    put(root, rel_npy, &npy(rel_npy, &shape, v)?)?;
    // PNG: pixel-major, channels interleaved.
    let p = size.0 * size.1;
    let q = |x: f32| ((f64::from(x) / full_scale).clamp(0.0, 1.0) * 65535.0).round() as u16;
    let samples: Vec<u16> = if channels == 1 {
        v.iter().map(|&x| q(x)).collect()
    } else {
        (0..p)
            .flat_map(|i| (0..channels).map(move |c| q(v[c * p + i])))
            .collect()
    };
    let png = crate::io::encode_png16(
        size.0,
        size.1,
        channels.min(3),
        &samples,
        crate::io::PngTransfer::Linear,
    )
    .map_err(|m| out_err(&root.join(rel_png), m))?;
    put(root, rel_png, &png)
}

/// Writes the six files of a 3-D sample: capture (`.npy`, `.png` as for 2-D samples), frontal
/// (`.npy` in capture units, `.png` with full scale [`meshes::FRONTAL_PNG_FULL_SCALE`]),
/// depth (`.npy`, mm, +inf where nothing is hit) and mask (16-bit `.png`).
fn write_mesh_sample(
    plan: &Plan,
    root: &Path,
    s: &SampleSpec,
    capture: &[f32],
    frontal: &stscam_tracer::frontal::Frontal,
    crop: (usize, usize),
    full_scale: f64,
) -> Result<(), DatasetError> {
    let files = plan.sample_files(s);
    split_dir(root, s)?;
    let nch = frontal.channels.len();
    let size = (frontal.width, frontal.height);
    // The capture has the sensor's channels; the frontal image those of its colour space.
    let capture_channels = capture.len() / (crop.0 * crop.1).max(1);
    put_image(
        root,
        [&files[0], &files[1]],
        capture,
        crop,
        capture_channels,
        full_scale,
    )?;
    let fv: Vec<f32> = frontal.channels.concat();
    put_image(
        root,
        [&files[2], &files[3]],
        &fv,
        size,
        nch,
        meshes::FRONTAL_PNG_FULL_SCALE,
    )?;
    put(
        root,
        &files[4],
        &npy(&files[4], &[size.1, size.0], &frontal.depth_mm)?,
    )?;
    let png = crate::io::encode_png16(
        size.0,
        size.1,
        1,
        &frontal.mask,
        crate::io::PngTransfer::Labels,
    )
    .map_err(|m| out_err(&root.join(&files[5]), m))?;
    put(root, &files[5], &png)
}

/// One `metadata.jsonl` line (Hugging Face imagefolder: `file_name` is the capture PNG).
fn metadata_line(plan: &Plan, s: &SampleSpec) -> Result<String, DatasetError> {
    let files = plan.sample_files(s);
    let base = |p: &str| p.rsplit('/').next().unwrap_or(p).to_string();
    let mut m = serde_json::Map::new();
    let names: &[&str] = if plan.recipe.is_meshes() {
        &[
            "capture_npy",
            "file_name",
            "frontal_npy",
            "frontal_file_name",
            "depth_npy",
            "mask_file_name",
        ]
    } else {
        &["object_npy", "object_file_name", "capture_npy", "file_name"]
    };
    for (k, f) in names.iter().zip(&files) {
        m.insert((*k).into(), base(f).into());
    }
    m.insert("id".into(), s.id.into());
    m.insert("split".into(), SPLITS[s.split].into());
    m.insert("seed".into(), s.seed.into());
    m.insert(
        "source".into(),
        match s.object.spec {
            ObjectSpec::Array { .. } => "array".into(),
            _ => plan.recipe.objects.sources[s.object.source].name().into(),
        },
    );
    m.insert("object_draw".into(), s.object.describe().into());
    m.insert("scene".into(), plan.scenes[s.scene].id.clone().into());
    if plan.has_matrix {
        m.insert(
            "matrix".into(),
            format!("../{}/H.npz", plan.scenes[s.scene].id).into(),
        );
    }
    for (k, v) in &s.params {
        m.insert(k.clone(), (*v).into());
    }
    if let Some((src, files)) = plan.mesh_source(s) {
        let (ls, _) = plan.sample_scene(s)?;
        let (d, bounds) = plan.mesh_draw(s, src, files, &ls)?;
        let mut drawn =
            serde_json::to_value(&d).map_err(|e| out_err(&plan.recipe_path, e.to_string()))?;
        let space = plan.recipe.objects.frontal_space();
        if space != crate::world::colour::FrontalSpace::Sensor {
            m.insert("frontal_space".into(), space.name().into());
        }
        if let Some(o) = drawn.as_object_mut() {
            o.insert("bounds_mm".into(), serde_json::json!(bounds));
            o.insert(
                "mask_value".into(),
                ls.scene
                    .object
                    .len()
                    .saturating_add(1)
                    .min(usize::from(u16::MAX - 1))
                    .into(),
            );
            m.append(o);
        }
    }
    serde_json::to_string(&m).map_err(|e| out_err(&plan.recipe_path, e.to_string()))
}

struct CardContext<'a> {
    plan: &'a Plan,
    capture_shape: Vec<usize>,
    channels: Vec<String>,
    exposure: serde_json::Value,
}

fn file_entry(root: &Path, rel: &str) -> Result<FileEntry, DatasetError> {
    let p = root.join(rel);
    let bytes = crate::io::read_input(&p, crate::io::MAX_BINARY_BYTES)?;
    Ok(FileEntry {
        sha256: sha256_hex(&bytes),
        bytes: bytes.len() as u64,
    })
}

/// Writes the metadata of the samples in `lines` (split, line; sorted by id) and builds the
/// card over them, the scenes `scene_ids` and every file.
fn finish(
    root: &Path,
    ctx: &CardContext,
    lines: &[(usize, String)],
    scene_ids: &[usize],
    specs: &[SampleSpec],
) -> Result<Card, DatasetError> {
    let plan = ctx.plan;
    let mut rel_files: Vec<String> = Vec::new();
    let mut counts = BTreeMap::new();
    for (si, split) in SPLITS.iter().enumerate() {
        let mine: Vec<&str> = lines
            .iter()
            .filter(|l| l.0 == si)
            .map(|l| l.1.as_str())
            .collect();
        counts.insert(split.to_string(), mine.len());
        if mine.is_empty() {
            continue;
        }
        let mut text = mine.join("\n");
        text.push('\n');
        let rel = format!("{split}/metadata.jsonl");
        put(root, &rel, text.as_bytes())?;
        rel_files.push(rel);
    }
    for s in specs {
        rel_files.extend(plan.sample_files(s));
    }
    for &k in scene_ids {
        rel_files.extend(plan.scene_files(k));
    }
    let entries: Vec<FileEntry> = rel_files
        .par_iter()
        .map(|r| file_entry(root, r))
        .collect::<Result<_, _>>()?;
    let files: BTreeMap<String, FileEntry> = rel_files.into_iter().zip(entries).collect();
    Ok(build_card(ctx, counts, scene_ids, files))
}

fn build_card(
    ctx: &CardContext,
    counts: BTreeMap<String, usize>,
    scene_ids: &[usize],
    files: BTreeMap<String, FileEntry>,
) -> Card {
    let plan = ctx.plan;
    let r = &plan.recipe;
    let n = r.objects.size_px;
    let scenes = scene_ids
        .iter()
        .map(|&k| {
            let s = &plan.scenes[k];
            serde_json::json!({
                "id": s.id,
                "overrides": s.overrides,
                "params": s.params,
                "matrix": plan.has_matrix.then(|| format!("{}/H.npz", s.id)),
                "matrix_seed": plan.has_matrix.then(|| plan.scene_seed(k)),
            })
        })
        .collect();
    let units: BTreeMap<String, String> = [
        ("object_npy", "float32 [h, w]: linear display intensity f in [0, 1] (0 = black, 1 = white; display gamma removed), the vector of g = H f (row-major)".to_string()),
        ("object_png", "16-bit grey: display code values round(65535 * f^(1/gamma)); shown on the scene's display it gives f".to_string()),
        ("capture_npy", format!("float32 [h, w] (or [channels, h, w]): {}; with sensor noise the ADC output converted back to these units with the mean dark offset removed", crate::output::CAPTURE_UNITS)),
        ("capture_png", "16-bit: round(65535 * clamp(capture / exposure.capture_full_scale, 0, 1)), linear".to_string()),
        ("matrix", crate::matrix::MATRIX_UNITS.to_string()),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    let mut units = units;
    let mut loading_3d = Vec::new();
    if r.is_meshes() {
        units.remove("object_npy");
        units.remove("object_png");
        units.remove("matrix");
        units.extend(
            meshes::units(r.objects.frontal_space())
                .into_iter()
                .map(|(k, v)| (k.to_string(), v)),
        );
        loading_3d.push(("metadata_3d", meshes::METADATA_3D));
        if r.objects.frontal_space() != crate::world::colour::FrontalSpace::Sensor {
            loading_3d.push(("metadata_3d_frontal_space", meshes::METADATA_FRONTAL_SPACE));
        }
    }
    let loading: BTreeMap<String, String> = [
        ("numpy", "np.load('train/000000_capture.npy'); H = scipy.sparse.load_npz('scene_000/H.npz'); offset = np.load('scene_000/offset.npy'); capture ≈ (H @ object.ravel() + offset).reshape(capture.shape)"),
        ("huggingface", "datasets.load_dataset('imagefolder', data_dir=DIR): column 'image' is the capture PNG, 'object' the object PNG (datasets 5.2, the version CI tests, reads *_file_name columns as images; older versions give the file name), the rest from metadata.jsonl; the split 'val' is named 'validation'; Pillow reads 16-bit RGB PNGs (colour sensors) as 8-bit, the .npy files are exact"),
        ("metadata", "SPLIT/metadata.jsonl: one JSON object per sample: file_name (capture PNG), object_file_name (object PNG), capture_npy, object_npy, id, split, seed, source (generator), object_draw (its random parameters), scene, matrix, and every varied scene key (depth_mm with [depth])"),
    ]
    .into_iter()
    .chain(loading_3d)
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    Card {
        format: FORMAT.to_string(),
        name: r.name.clone(),
        description: r.description.clone(),
        stscam_version: crate::VERSION.to_string(),
        recipe: r.clone(),
        recipe_sha256: plan.recipe_sha256.clone(),
        samples: counts.values().sum(),
        counts,
        object_shape: [n, n],
        capture_shape: ctx.capture_shape.clone(),
        channels: ctx.channels.clone(),
        seeds: serde_json::json!({
            "recipe_seed": r.seed,
            "sample_seed": "NoiseRng([recipe_seed, 0x53414D50, id]).next_u64() >> 11 (listed per sample in metadata.jsonl)",
            "matrix_seed": "NoiseRng([recipe_seed, 0x5343454E, scene_index]).next_u64() >> 11 (listed per scene)",
            "render_seed": "the sample seed (render mode)",
            "noise": "pixel i of sample s: NoiseRng([sample_seed, 0x4E4F4953, i])",
        }),
        units,
        exposure: ctx.exposure.clone(),
        scenes,
        loading,
        files,
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_ranges_tile_the_samples() {
        for samples in [1, 7, 300] {
            for count in 1..6 {
                let mut next = 0;
                for index in 0..count {
                    let r = Shard { index, count }.range(samples);
                    assert_eq!(r.start, next);
                    next = r.end;
                }
                assert_eq!(next, samples);
            }
        }
        assert!(Shard::parse("3/3").is_err());
        assert_eq!(Shard::parse("2/3").unwrap(), Shard { index: 2, count: 3 });
        assert!(Shard::parse("0/1000000").is_ok());
        let e = Shard::parse("0/1000000000000").unwrap_err();
        assert!(e.contains("at most 1000000"), "{e}");
    }

    #[test]
    fn shard_from_cluster_environments() {
        let env = |pairs: &'static [(&'static str, &'static str)]| {
            move |k: &str| pairs.iter().find(|p| p.0 == k).map(|p| p.1.to_string())
        };
        assert_eq!(Shard::from_env(env(&[])).unwrap(), None);
        assert_eq!(
            Shard::from_env(env(&[
                ("SLURM_ARRAY_TASK_ID", "5"),
                ("SLURM_ARRAY_TASK_COUNT", "4"),
                ("SLURM_ARRAY_TASK_MIN", "3")
            ]))
            .unwrap(),
            Some(Shard { index: 2, count: 4 })
        );
        assert_eq!(
            Shard::from_env(env(&[
                ("JOB_COMPLETION_INDEX", "1"),
                ("STSCAM_SHARD_COUNT", "3")
            ]))
            .unwrap(),
            Some(Shard { index: 1, count: 3 })
        );
        assert!(Shard::from_env(env(&[("JOB_COMPLETION_INDEX", "1")])).is_err());
        assert!(
            Shard::from_env(env(&[
                ("SLURM_ARRAY_TASK_ID", "4"),
                ("SLURM_ARRAY_TASK_COUNT", "4")
            ]))
            .is_err()
        );
    }
}
