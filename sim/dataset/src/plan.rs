//! The plan of a dataset: a recipe checked against everything it names (scene, overrides,
//! every distinct scene, object folders), and what follows for each sample from its id alone
//! (seed, split, object draw, scene, files).

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use sha2::{Digest, Sha256};

use crate::error::{DatasetError, recipe_err};
use crate::noise::NoiseRng;
use crate::objects::{ObjectDraw, ObjectSpec, draw, list_images};
use crate::recipe::{
    self, CaptureMode, DEPTH_KEY, Recipe, Resize, SPLITS, Source, fmt_value, parse_recipe,
};
use crate::render::RenderSettings;
use crate::scene::{LoadedScene, load_scene};
use crate::system::System;
use crate::{depth, meshes};

const SAMPLE_TAG: u64 = 0x5341_4D50;
const SCENE_TAG: u64 = 0x5343_454E;
const VARY_TAG: u64 = 0x5641_5259;
pub(crate) const WHITE_TAG: u64 = 0x5748_4954;
const DEPTH_TAG: u64 = 0x4445_5054;

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
pub(crate) fn source_key(s: &SampleSpec) -> String {
    format!("objects.sources[{}]", s.object.source)
}

/// Hex SHA-256 of `bytes` (the checksums of a dataset's card, and of tolerance shards).
pub fn sha256_hex(bytes: &[u8]) -> String {
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
        // Cycled keys: sample id's combination, in mixed radix with the last key fastest.
        let mut stride: usize = self
            .recipe
            .vary
            .iter()
            .filter(|v| v.cycle)
            .map(|v| v.values.as_ref().map_or(1, Vec::len))
            .product();
        for v in &self.recipe.vary {
            if let Some(vals) = &v.values {
                let k = if v.cycle {
                    stride /= vals.len();
                    (id / stride.max(1)) % vals.len()
                } else {
                    ((rng.uniform() * vals.len() as f64) as usize).min(vals.len() - 1)
                };
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
    pub(crate) fn mesh_draw(
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
    pub(crate) fn mesh_source(
        &self,
        s: &SampleSpec,
    ) -> Option<(&recipe::MeshSource, &[(PathBuf, String)])> {
        match &self.recipe.objects.sources[s.object.source] {
            Source::Meshes(m) => Some((m, &self.images[s.object.source])),
            _ => None,
        }
    }

    /// Sample `s`'s object as linear intensities (`objects.size_px`², row-major), with the
    /// display `gamma` for code values.
    pub(crate) fn object_of(&self, s: &SampleSpec, gamma: f64) -> Result<Vec<f64>, DatasetError> {
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
    pub(crate) fn scene_seed(&self, k: usize) -> u64 {
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
    pub(crate) fn designs_planned(&self) -> bool {
        self.recipe.vary.iter().all(|v| v.values.is_some())
    }

    /// The scene of a sample: its discrete scene, or with ranged keys one built for it.
    #[allow(clippy::type_complexity)]
    pub(crate) fn sample_scene(
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
