//! Dataset recipes: the TOML file that fully determines a dataset.
//!
//! ```toml
//! name = "paper-small"          # names the default output folder
//! seed = 2022                   # every sample's seed derives from it and the sample id
//! samples = 300
//! mode = "matrix"               # "matrix": g = H f (+ offset); "render": a Monte Carlo render per sample
//! spp = 64                      # samples per pixel of H (matrix) or of each capture (render)
//! noise = "sensor"              # "sensor": the scene's [noise] section; "none": noiseless
//!
//! [scene]                       # optional
//! file = "../scenes/paper-2022.toml"   # relative to the recipe; default: the embedded paper scene
//! set = ["plate.thickness_mm=3"]       # scene overrides, as `--set`
//!
//! [split]
//! train = 0.8
//! val = 0.1
//! test = 0.1
//!
//! [objects]
//! size_px = 64                  # objects are size_px × size_px display pixels
//! random_levels = false         # binary patterns: random dark/bright levels instead of 0 and 1
//! frontal_space = "sensor"      # 3-D only: frontal ground truth in "sensor" RGB, "xyz" or "linear-srgb"
//! frontal_spp = 64              # 3-D only: samples per pixel of the frontal ground truth (default: spp)
//! [[objects.sources]]
//! generator = "glyphs"          # see `Source`
//! weight = 2.0
//!
//! [[vary]]                      # optional per-sample scene variation
//! key = "display.distance_mm"
//! values = [450.0, 550.0, 650.0]   # or range = [450.0, 650.0] (render mode only)
//!
//! [depth]                       # optional, matrix mode: planar objects at random depths
//! values_mm = [300.0, 450.0]    # or grid_mm = "300:600:4" (START:STOP:STEPS, ends included)
//! ```
//!
//! 3-D scenes (render mode): every source is `generator = "meshes"` (see [`MeshSource`] for
//! its keys and defaults); `objects.size_px` is then the side of the frontal ground truth.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// How a capture is made.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CaptureMode {
    /// g = H·f + offset with the ground-truth H of the sample's scene (exact for the flat
    /// display model; fast).
    Matrix,
    /// An independent Monte Carlo render of the object per sample.
    Render,
}

/// Which light paths a rendered capture holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TracePaths {
    /// The designed path only (what H models; the default).
    #[default]
    Designed,
    /// Every path through the plate (`stscam stray`'s `all_paths`): the designed path with
    /// the plate's ghosts, every grating's stray orders, cross-coupling and, where the scene
    /// has them, the display behind the screen, edges and haze. Render mode, display objects.
    All,
}

impl TracePaths {
    fn is_designed(&self) -> bool {
        *self == TracePaths::Designed
    }
}

/// Which noise the captures get.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum NoiseModel {
    /// The scene's `[noise]` section (shot, read, dark offset, ADC), exposure fixed once.
    Sensor,
    /// Noiseless captures (float32 rounding only).
    None,
}

/// `[scene]`: the scene file and overrides.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneRef {
    /// Scene TOML relative to the recipe; default: the embedded paper scene.
    #[serde(default)]
    pub file: Option<String>,
    /// Overrides `KEY=VALUE`, applied in order.
    #[serde(default)]
    pub set: Vec<String>,
}

/// `[split]`: fractions of the samples in each split (summing to 1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Split {
    /// Training fraction.
    pub train: f64,
    /// Validation fraction.
    pub val: f64,
    /// Test fraction.
    pub test: f64,
}

fn one() -> f64 {
    1.0
}

fn default_chars() -> String {
    "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789".to_string()
}

fn default_true() -> bool {
    true
}

/// How an image from a folder is brought to the object size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Resize {
    /// Crop the largest centred square, then area-average to size × size.
    CenterCrop,
    /// Area-average the whole image to size × size (aspect ratio not kept).
    Stretch,
}

/// One source of objects, chosen per sample with probability ∝ `weight`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "generator", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Source {
    /// Strings of 1..=`max_len` glyphs of the embedded 5×7 font drawn from `chars`, randomly
    /// scaled, rotated and shifted.
    Glyphs {
        /// Relative weight.
        #[serde(default = "one")]
        weight: f64,
        /// Characters to draw from (A–Z, 0–9).
        #[serde(default = "default_chars")]
        chars: String,
        /// Longest string.
        #[serde(default = "one_usize")]
        max_len: usize,
    },
    /// Filled shapes (disk, ring, triangle, star, cross, heart), randomly scaled, rotated and
    /// shifted.
    Shapes {
        /// Relative weight.
        #[serde(default = "one")]
        weight: f64,
    },
    /// Binary Siemens stars with a random spoke count in `min_spokes..=max_spokes` and a random
    /// rotation.
    Siemens {
        /// Relative weight.
        #[serde(default = "one")]
        weight: f64,
        /// Fewest spoke pairs.
        #[serde(default = "four")]
        min_spokes: usize,
        /// Most spoke pairs.
        #[serde(default = "twenty_four")]
        max_spokes: usize,
    },
    /// Resolution bars: groups of three bars of a random period (pixels) in
    /// `min_period_px..=max_period_px`, horizontal or vertical, at a random position.
    Bars {
        /// Relative weight.
        #[serde(default = "one")]
        weight: f64,
        /// Smallest bar width, pixels.
        #[serde(default = "one_usize")]
        min_period_px: usize,
        /// Largest bar width, pixels.
        #[serde(default = "eight")]
        max_period_px: usize,
    },
    /// Smooth photo-like random fields (`smooth:SEED` with a per-sample seed).
    Smooth {
        /// Relative weight.
        #[serde(default = "one")]
        weight: f64,
    },
    /// 3-D scenes (render mode only): a mesh with a random pose, placement, material and
    /// lighting per sample.
    Meshes(Box<MeshSource>),
    /// Images (PNG or JPEG) from a folder, chosen at random per sample, converted to
    /// luminance in linear light (Rec. 709 weights after the display gamma) and resized.
    Images {
        /// Relative weight.
        #[serde(default = "one")]
        weight: f64,
        /// Folder relative to the recipe.
        folder: String,
        /// Resize rule.
        #[serde(default = "center_crop")]
        resize: Resize,
        /// Also take images from sub-folders.
        #[serde(default)]
        recursive: bool,
        /// Flip half of the samples left–right.
        #[serde(default = "default_true")]
        flip: bool,
    },
}

fn one_usize() -> usize {
    1
}
fn four() -> usize {
    4
}
fn eight() -> usize {
    8
}
fn twenty_four() -> usize {
    24
}
fn center_crop() -> Resize {
    Resize::CenterCrop
}

impl Source {
    /// The generator name as written in recipes.
    pub fn name(&self) -> &'static str {
        match self {
            Source::Glyphs { .. } => "glyphs",
            Source::Shapes { .. } => "shapes",
            Source::Siemens { .. } => "siemens",
            Source::Bars { .. } => "bars",
            Source::Smooth { .. } => "smooth",
            Source::Images { .. } => "images",
            Source::Meshes(_) => "meshes",
        }
    }

    /// Relative weight.
    pub fn weight(&self) -> f64 {
        match self {
            Source::Glyphs { weight, .. }
            | Source::Shapes { weight }
            | Source::Siemens { weight, .. }
            | Source::Bars { weight, .. }
            | Source::Smooth { weight }
            | Source::Images { weight, .. } => *weight,
            Source::Meshes(m) => m.weight,
        }
    }
}

/// Names of the generators, for messages.
pub const GENERATORS: &[&str] = &[
    "glyphs", "shapes", "siemens", "bars", "smooth", "images", "meshes",
];

/// A source of 3-D scenes (`generator = "meshes"`). Ranges `[lo, hi]` are drawn uniformly
/// (ends included; `lo = hi` fixes a value) per sample with `rand`'s distributions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshSource {
    /// Relative weight.
    #[serde(default = "one")]
    pub weight: f64,
    /// Built-in meshes to draw from (`head`, `hand`, `sphere`, `box`, `cylinder`, `quad`).
    #[serde(default = "default_builtins")]
    pub builtin: Vec<String>,
    /// Folder of `.gltf`, `.glb` and `.obj` files (relative to the recipe), drawn from too.
    #[serde(default)]
    pub folder: Option<String>,
    /// What one OBJ file unit is (`mm`, `cm`, `m`, `in`); glTF is metres.
    #[serde(default)]
    pub units: Option<String>,
    /// Distance of the mesh origin from the plate along −z, mm.
    #[serde(default = "default_distance")]
    pub distance_mm: [f64; 2],
    /// Horizontal position of the mesh origin, mm.
    #[serde(default = "default_lateral")]
    pub x_mm: [f64; 2],
    /// Vertical position of the mesh origin, mm.
    #[serde(default = "default_lateral")]
    pub y_mm: [f64; 2],
    /// Largest rotation about x, y and z, degrees (each drawn in ±max).
    #[serde(default = "default_rotation")]
    pub rotation_deg: [f64; 3],
    /// Uniform scale.
    #[serde(default = "default_scale")]
    pub scale: [f64; 2],
    /// Hand: flexion of each finger, degrees (drawn per finger, within [−30, 120]).
    #[serde(default = "default_bend")]
    pub bend_deg: [f64; 2],
    /// Hand: finger spread, degrees (within [−20, 30]).
    #[serde(default = "default_spread")]
    pub spread_deg: [f64; 2],
    /// Linear RGB base colour, each channel (within [0, 1]).
    #[serde(default = "default_albedo")]
    pub albedo: [f64; 2],
    /// GGX roughness (within [0, 1]).
    #[serde(default = "default_roughness")]
    pub roughness: [f64; 2],
    /// Probability that the material is a metal (metallic = 1) instead of a dielectric.
    #[serde(default)]
    pub metallic_probability: f64,
    /// Radiance scale of the key light (a 400 × 400 mm D65-to-tungsten panel toward the mesh).
    #[serde(default = "default_key")]
    pub key_light: [f64; 2],
    /// Colour temperature of the key light, kelvin (a black body).
    #[serde(default = "default_cct")]
    pub key_light_kelvin: [f64; 2],
    /// Radiance scale of the screen's glow (white LED, 518 × 324 mm at the plate).
    #[serde(default = "default_glow")]
    pub screen_glow: [f64; 2],
    /// Radiance scale of a uniform D65 environment (0: none, a black background).
    #[serde(default = "default_environment")]
    pub environment: [f64; 2],
}

fn default_builtins() -> Vec<String> {
    vec!["head".into(), "hand".into()]
}
fn default_distance() -> [f64; 2] {
    [250.0, 600.0]
}
fn default_lateral() -> [f64; 2] {
    [-30.0, 30.0]
}
fn default_rotation() -> [f64; 3] {
    [15.0, 30.0, 10.0]
}
fn default_scale() -> [f64; 2] {
    [0.9, 1.1]
}
fn default_bend() -> [f64; 2] {
    [0.0, 70.0]
}
fn default_spread() -> [f64; 2] {
    [-5.0, 20.0]
}
fn default_albedo() -> [f64; 2] {
    [0.1, 0.8]
}
fn default_roughness() -> [f64; 2] {
    [0.3, 1.0]
}
fn default_key() -> [f64; 2] {
    [0.5, 3.0]
}
fn default_cct() -> [f64; 2] {
    [2700.0, 6500.0]
}
fn default_glow() -> [f64; 2] {
    [0.1, 0.5]
}
fn default_environment() -> [f64; 2] {
    [0.0, 0.05]
}

/// `[depth]`: the depths of a planar-object dataset (matrix mode), each with its own H.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthGrid {
    /// Depths in mm (distance of the object plane from the plate).
    #[serde(default)]
    pub values_mm: Option<Vec<f64>>,
    /// `START:STOP:STEPS` in mm, STEPS values with both ends included.
    #[serde(default)]
    pub grid_mm: Option<String>,
}

/// Largest number of depths.
pub const MAX_DEPTHS: usize = 1000;

impl DepthGrid {
    /// The depths in mm, checked (finite, positive, distinct, at most [`MAX_DEPTHS`]); the
    /// error is (key, message).
    pub fn depths_mm(&self) -> Result<Vec<f64>, (String, String)> {
        let e = |k: &str, m: String| Err((format!("depth.{k}"), m));
        let v = match (&self.values_mm, &self.grid_mm) {
            (Some(v), None) => v.clone(),
            (None, Some(g)) => {
                let parts: Vec<&str> = g.split(':').map(str::trim).collect();
                let bad = || format!("{g:?} is not START:STOP:STEPS (mm, mm, count >= 1)");
                if parts.len() != 3 {
                    return e("grid_mm", bad());
                }
                let (Ok(a), Ok(b), Ok(n)) = (
                    parts[0].parse::<f64>(),
                    parts[1].parse::<f64>(),
                    parts[2].parse::<usize>(),
                ) else {
                    return e("grid_mm", bad());
                };
                if n == 0 || n > MAX_DEPTHS {
                    return e(
                        "grid_mm",
                        format!("STEPS must be in 1..={MAX_DEPTHS}, got {n}"),
                    );
                }
                if n == 1 {
                    vec![a]
                } else {
                    (0..n)
                        .map(|i| a + (b - a) * i as f64 / (n - 1) as f64)
                        .collect()
                }
            }
            _ => {
                return e(
                    "values_mm",
                    "give exactly one of `values_mm` or `grid_mm`".into(),
                );
            }
        };
        let key = if self.values_mm.is_some() {
            "values_mm"
        } else {
            "grid_mm"
        };
        if v.is_empty() || v.len() > MAX_DEPTHS {
            return e(
                key,
                format!("needs 1..={MAX_DEPTHS} depths, got {}", v.len()),
            );
        }
        if let Some(d) = v
            .iter()
            .find(|d| !(d.is_finite() && **d > 0.0 && **d < 1e7))
        {
            return e(
                key,
                format!("depths must be positive distances in mm, got {d}"),
            );
        }
        let mut sorted = v.clone();
        sorted.sort_by(f64::total_cmp);
        if sorted.windows(2).any(|w| w[0] == w[1]) {
            return e(key, "depths must be distinct".into());
        }
        Ok(v)
    }
}

/// `[objects]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Objects {
    /// Objects are `size_px` × `size_px` display pixels (the columns of H).
    pub size_px: usize,
    /// Binary patterns get a random dark level in [0, 0.3] and bright level in [0.6, 1]
    /// (display code values) instead of 0 and 1.
    #[serde(default)]
    pub random_levels: bool,
    /// Where objects come from.
    pub sources: Vec<Source>,
    /// 3-D recipes: the colour space of the frontal ground truth (`sensor`, `xyz`,
    /// `linear-srgb`; absent: `sensor`), as `render --frontal-space`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frontal_space: Option<String>,
    /// 3-D recipes: samples per pixel of the frontal ground truth (absent: the recipe's
    /// `spp`), as `render --frontal-spp`. With `[camera_table]`, `spp` counts user-side paths
    /// of the capture, and this keeps the ground truth's quality apart from it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frontal_spp: Option<u32>,
}

impl Objects {
    /// Samples per pixel of the frontal ground truth of a recipe whose `spp` is `spp`.
    pub fn frontal_spp(&self, spp: u32) -> u32 {
        self.frontal_spp.unwrap_or(spp)
    }

    /// The frontal ground truth's colour space (sensor unless `frontal_space` says otherwise;
    /// the recipe check refuses other spellings).
    pub fn frontal_space(&self) -> crate::world::colour::FrontalSpace {
        self.frontal_space
            .as_deref()
            .and_then(crate::world::colour::FrontalSpace::parse)
            .unwrap_or_default()
    }
}

/// `[[vary]]`: one scene key varied per sample.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Vary {
    /// Scene key, as in `--set`.
    pub key: String,
    /// Values drawn uniformly per sample (each distinct scene gets its own H).
    #[serde(default)]
    pub values: Option<Vec<f64>>,
    /// Continuous uniform range [lo, hi] (render mode only: no H is written).
    #[serde(default)]
    pub range: Option<[f64; 2]>,
    /// With `values`: take them in turn instead of at random (sample i gets value
    /// i mod len; several cycled keys run through their combinations, the last one fastest),
    /// so every value gets its share of the samples.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub cycle: bool,
}

/// A dataset recipe.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    /// Name (default output folder `out/datasets/NAME`).
    pub name: String,
    /// Free text for the dataset card.
    #[serde(default)]
    pub description: String,
    /// Recipe seed.
    pub seed: u64,
    /// Number of samples.
    pub samples: usize,
    /// Capture mode.
    pub mode: CaptureMode,
    /// Samples per pixel of H (matrix mode) or of each capture (render mode).
    #[serde(default = "default_spp")]
    pub spp: u32,
    /// Render mode: the light paths a capture holds (left out of the card at the default, so
    /// datasets without it keep their bytes).
    #[serde(default, skip_serializing_if = "TracePaths::is_designed")]
    pub paths: TracePaths,
    /// Sensor noise.
    #[serde(default = "default_noise")]
    pub noise: NoiseModel,
    /// Scene.
    #[serde(default)]
    pub scene: SceneRef,
    /// Split fractions.
    pub split: Split,
    /// Objects.
    pub objects: Objects,
    /// Per-sample scene variation.
    #[serde(default)]
    pub vary: Vec<Vary>,
    /// Planar objects at random depths (matrix mode).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth: Option<DepthGrid>,
    /// 3-D (meshes) render-mode datasets: the camera side from one table per design, drawn
    /// once per run and shared by its samples (`spp` is then user-side paths per pixel).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_table: Option<TableRecipe>,
}

/// `[camera_table]`: the camera-side table of a 3-D dataset (docs/design.md, "The camera side
/// is scene-independent"); its seed is the recipe's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableRecipe {
    /// Camera samples per pixel drawn for the table.
    #[serde(default = "default_table_spp")]
    pub spp: u32,
    /// Representative exit rays per pixel.
    #[serde(default = "default_table_reps")]
    pub reps: u32,
    /// Cache directory (relative to the recipe) shared by runs and shards: the table is read
    /// from there when present, else drawn and written there; none: drawn in memory per run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dir: Option<String>,
}

fn default_table_spp() -> u32 {
    crate::render::camera_table::DEFAULT_TABLE_SPP
}
fn default_table_reps() -> u32 {
    crate::render::camera_table::DEFAULT_TABLE_REPS
}

fn default_spp() -> u32 {
    64
}
fn default_noise() -> NoiseModel {
    NoiseModel::Sensor
}

/// Largest object side accepted.
pub const MAX_OBJECT_PX: usize = 1024;
/// Largest sample count accepted: a run keeps a few KiB of bookkeeping per sample (its
/// spec, metadata line and the card's checksums), so 2·10⁶ samples need up to about 6 GiB of
/// memory (and about 2.4 TB of files at the paper's size); larger sets are several recipes.
pub const MAX_SAMPLES: usize = 2_000_000;
/// Most distinct scenes (combinations of the `vary` `values` lists) accepted.
pub const MAX_SCENES: usize = 256;

/// Parses a recipe; the error is (key, message). Unknown keys and generators are refused with
/// the list of valid ones.
pub fn parse_recipe(text: &str) -> Result<Recipe, (String, String)> {
    let de = toml::Deserializer::parse(text).map_err(|e| {
        (
            String::new(),
            e.to_string()
                .split_whitespace()
                .collect::<Vec<_>>()
                .join(" "),
        )
    })?;
    let r: Recipe = serde_path_to_error::deserialize(de).map_err(|e| {
        let key = e.path().to_string();
        let msg = e
            .inner()
            .message()
            .split_whitespace()
            .collect::<Vec<_>>()
            .join(" ");
        (key, msg)
    })?;
    check(&r)?;
    Ok(r)
}

fn check(r: &Recipe) -> Result<(), (String, String)> {
    check_run(r)?;
    check_objects(r)?;
    for (i, src) in r.objects.sources.iter().enumerate() {
        check_source(i, src, r.objects.size_px, r.mode)?;
    }
    let meshes = check_kind(r)?;
    if let Some(d) = &r.depth {
        check_depth(d, r.mode, meshes)?;
    }
    if let Some(t) = &r.camera_table {
        if !(r.is_meshes() && r.mode == CaptureMode::Render) {
            return key_err(
                "camera_table",
                "a camera-side table is for render-mode 3-D datasets (a meshes source)".into(),
            );
        }
        for (k, v) in [("camera_table.spp", t.spp), ("camera_table.reps", t.reps)] {
            if !(1..=1 << 20).contains(&v) {
                return key_err(k, format!("must be 1..=1048576, got {v}"));
            }
        }
    }
    if r.paths == TracePaths::All && (r.mode != CaptureMode::Render || r.is_meshes()) {
        return key_err(
            "paths",
            "\"all\" needs mode = \"render\" and display objects (a capture H·f holds the designed path only; the stray tracer does not follow a 3-D user side)".into(),
        );
    }
    check_vary(r)
}

/// `Err((key, message))`: a recipe key and what is wrong with it.
fn key_err<T>(k: &str, m: String) -> Result<T, (String, String)> {
    Err((k.to_string(), m))
}

/// The run's keys: name, samples, spp and the split fractions.
fn check_run(r: &Recipe) -> Result<(), (String, String)> {
    let err = key_err;
    if r.name.is_empty()
        || !r
            .name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        || r.name.starts_with('.')
    {
        return err(
            "name",
            format!(
                "{:?} must be non-empty, use only A-Z a-z 0-9 - _ . and not start with '.'",
                r.name
            ),
        );
    }
    if r.samples == 0 || r.samples > MAX_SAMPLES {
        return err(
            "samples",
            format!("must be in 1..={MAX_SAMPLES}, got {}", r.samples),
        );
    }
    if r.spp == 0 {
        return err("spp", "must be at least 1".into());
    }
    let s = &r.split;
    for (k, v) in [
        ("split.train", s.train),
        ("split.val", s.val),
        ("split.test", s.test),
    ] {
        if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
            return err(k, format!("must be a fraction in [0, 1], got {v}"));
        }
    }
    let sum = s.train + s.val + s.test;
    if (sum - 1.0).abs() > 1e-9 {
        return err(
            "split",
            format!(
                "train + val + test must sum to 1, got {} + {} + {} = {sum}",
                s.train, s.val, s.test
            ),
        );
    }
    Ok(())
}

/// `objects.size_px`, `objects.frontal_space` and that there are sources.
fn check_objects(r: &Recipe) -> Result<(), (String, String)> {
    let err = key_err;
    let o = &r.objects;
    if !(2..=MAX_OBJECT_PX).contains(&o.size_px) {
        return err(
            "objects.size_px",
            format!("must be in 2..={MAX_OBJECT_PX}, got {}", o.size_px),
        );
    }
    if let Some(space) = &o.frontal_space {
        if crate::world::colour::FrontalSpace::parse(space).is_none() {
            return err(
                "objects.frontal_space",
                format!("must be \"sensor\", \"xyz\" or \"linear-srgb\", got {space:?}"),
            );
        }
        if !r.is_meshes() && space != "sensor" {
            return err(
                "objects.frontal_space",
                "applies to 3-D (generator = \"meshes\") recipes only, which have a frontal \
                 ground truth"
                    .to_string(),
            );
        }
    }
    if let Some(n) = o.frontal_spp {
        if n == 0 {
            return err("objects.frontal_spp", "must be at least 1".into());
        }
        if !r.is_meshes() {
            return err(
                "objects.frontal_spp",
                "applies to 3-D (generator = \"meshes\") recipes only, which have a frontal \
                 ground truth"
                    .to_string(),
            );
        }
    }
    if o.sources.is_empty() {
        return err(
            "objects.sources",
            format!(
                "needs at least one [[objects.sources]] (generators: {})",
                GENERATORS.join(", ")
            ),
        );
    }
    Ok(())
}

/// Object source `i` (`objects.sources[i]`) of objects `size_px` square in capture `mode`.
fn check_source(
    i: usize,
    src: &Source,
    size_px: usize,
    mode: CaptureMode,
) -> Result<(), (String, String)> {
    let err = key_err;
    let key = |k: &str| format!("objects.sources[{i}].{k}");
    let w = src.weight();
    if !(w.is_finite() && w > 0.0) {
        return err(
            &key("weight"),
            format!("must be a positive number, got {w}"),
        );
    }
    match src {
        Source::Glyphs { chars, max_len, .. } => {
            if chars.is_empty() || !chars.chars().all(|c| c.is_ascii_alphanumeric()) {
                return err(
                    &key("chars"),
                    format!("{chars:?} must be non-empty and use only A-Z, 0-9"),
                );
            }
            if !(1..=8).contains(max_len) {
                return err(&key("max_len"), format!("must be in 1..=8, got {max_len}"));
            }
        }
        Source::Siemens {
            min_spokes,
            max_spokes,
            ..
        } if *min_spokes < 1 || max_spokes < min_spokes || *max_spokes > 256 => {
            return err(
                &key("max_spokes"),
                format!(
                    "need 1 <= min_spokes <= max_spokes <= 256, got {min_spokes}..{max_spokes}"
                ),
            );
        }
        Source::Bars {
            min_period_px,
            max_period_px,
            ..
        } if *min_period_px < 1 || max_period_px < min_period_px || 5 * max_period_px > size_px => {
            return err(
                &key("max_period_px"),
                format!(
                    "need 1 <= min_period_px <= max_period_px and five bar widths within objects.size_px ({}), got {min_period_px}..{max_period_px}",
                    size_px
                ),
            );
        }
        Source::Images { folder, .. } if folder.is_empty() => {
            return err(&key("folder"), "must name a folder".into());
        }
        Source::Meshes(m) => check_meshes(m, mode).map_err(|(k, m)| (key(&k), m))?,
        _ => {}
    }
    Ok(())
}

/// That the sources are all 3-D (`meshes`, with a frontal side of at most
/// [`MAX_FRONTAL_PX`]) or all 2-D; returns the number of `meshes` sources.
fn check_kind(r: &Recipe) -> Result<usize, (String, String)> {
    let err = key_err;
    let o = &r.objects;
    let meshes = o
        .sources
        .iter()
        .filter(|s| matches!(s, Source::Meshes(_)))
        .count();
    if meshes > 0 && meshes < o.sources.len() {
        return err(
            "objects.sources",
            "`meshes` (3-D scenes) cannot be mixed with 2-D generators in one dataset".into(),
        );
    }
    if meshes > 0 && o.size_px > MAX_FRONTAL_PX {
        return err(
            "objects.size_px",
            format!(
                "is the frontal ground truth's side for `meshes`: must be in 2..={MAX_FRONTAL_PX}, got {}",
                o.size_px
            ),
        );
    }
    if let Some(d) = &r.depth {
        d.depths_mm()?;
        if r.mode != CaptureMode::Matrix {
            return err(
                "depth",
                "planar objects at random depths need mode = \"matrix\" (one H per depth)".into(),
            );
        }
        if meshes > 0 {
            return err("depth", "does not apply to `meshes` sources".into());
        }
    }
    Ok(meshes)
}

/// The `[depth]` section: its depths, matrix mode and 2-D sources.
fn check_depth(d: &DepthGrid, mode: CaptureMode, meshes: usize) -> Result<(), (String, String)> {
    let err = key_err;
    d.depths_mm()?;
    if mode != CaptureMode::Matrix {
        return err(
            "depth",
            "planar objects at random depths need mode = \"matrix\" (one H per depth)".into(),
        );
    }
    if meshes > 0 {
        return err("depth", "does not apply to `meshes` sources".into());
    }
    Ok(())
}

/// The `[[vary]]` keys: each once, exactly one of `values` or `range` (render mode), and at
/// most [`MAX_SCENES`] distinct scenes.
fn check_vary(r: &Recipe) -> Result<(), (String, String)> {
    let err = key_err;
    let mut seen = std::collections::BTreeSet::new();
    for (i, v) in r.vary.iter().enumerate() {
        let key = |k: &str| format!("vary[{i}].{k}");
        if v.key.is_empty() || !seen.insert(v.key.clone()) {
            return err(&key("key"), format!("{:?} is empty or varied twice", v.key));
        }
        match (&v.values, &v.range) {
            (Some(vals), None) => {
                if vals.is_empty() || vals.iter().any(|x| !x.is_finite()) {
                    return err(
                        &key("values"),
                        "must be a non-empty list of finite numbers".into(),
                    );
                }
            }
            (None, Some([lo, hi])) => {
                if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                    return err(
                        &key("range"),
                        format!("must be [lo, hi] with lo < hi, got [{lo}, {hi}]"),
                    );
                }
                if r.mode == CaptureMode::Matrix {
                    return err(
                        &key("range"),
                        "a continuous range needs mode = \"render\" (matrix mode needs one H per scene: give `values`)".into(),
                    );
                }
            }
            _ => {
                return err(
                    &key("values"),
                    "give exactly one of `values` or `range`".into(),
                );
            }
        }
        if v.cycle && v.values.is_none() {
            return err(
                &key("cycle"),
                "cycles through `values`; a continuous `range` has none".into(),
            );
        }
    }
    let scenes = r.vary.iter().try_fold(1usize, |n, v| {
        n.checked_mul(v.values.as_ref().map_or(1, Vec::len))
    });
    if scenes.is_none_or(|n| n > MAX_SCENES) {
        return err(
            "vary",
            format!(
                "the `values` lists give more than {MAX_SCENES} distinct scenes (one H each, all held in memory); vary fewer keys or values"
            ),
        );
    }
    Ok(())
}

/// Largest frontal side of a 3-D dataset (objects.size_px with `meshes`).
pub const MAX_FRONTAL_PX: usize = 1024;

fn check_range(k: &str, r: [f64; 2], lo: f64, hi: f64) -> Result<(), (String, String)> {
    if r.iter().all(|v| v.is_finite() && *v >= lo && *v <= hi) && r[0] <= r[1] {
        Ok(())
    } else {
        Err((
            k.to_string(),
            format!(
                "must be [lo, hi] with {lo} <= lo <= hi <= {hi}, got [{}, {}]",
                r[0], r[1]
            ),
        ))
    }
}

/// Checks a `meshes` source; the error is (key within the source, message).
fn check_meshes(m: &MeshSource, mode: CaptureMode) -> Result<(), (String, String)> {
    let err = |k: &str, msg: String| Err((k.to_string(), msg));
    if mode != CaptureMode::Render {
        return err(
            "generator",
            "`meshes` makes 3-D scenes, which need mode = \"render\"".into(),
        );
    }
    let names = crate::world::shapes::builtin_names();
    if let Some(b) = m.builtin.iter().find(|b| !names.contains(&b.as_str())) {
        return err(
            "builtin",
            format!("unknown built-in mesh {b:?}; expected some of {names:?}"),
        );
    }
    if m.builtin.is_empty() && m.folder.is_none() {
        return err(
            "builtin",
            "give built-in meshes, a `folder` of mesh files, or both".into(),
        );
    }
    if crate::world::desc::unit_mm(m.units.as_deref()).is_none() {
        return err(
            "units",
            format!("unknown unit {:?}; expected mm, cm, m or in", m.units),
        );
    }
    check_range("distance_mm", m.distance_mm, 1.0, 1e5)?;
    check_range("x_mm", m.x_mm, -1e5, 1e5)?;
    check_range("y_mm", m.y_mm, -1e5, 1e5)?;
    for (i, v) in m.rotation_deg.iter().enumerate() {
        if !(v.is_finite() && (0.0..=180.0).contains(v)) {
            return err(
                "rotation_deg",
                format!("entry {i} must be a largest angle in [0, 180], got {v}"),
            );
        }
    }
    check_range("scale", m.scale, 1e-6, 1e6)?;
    check_range("bend_deg", m.bend_deg, -30.0, 120.0)?;
    check_range("spread_deg", m.spread_deg, -20.0, 30.0)?;
    check_range("albedo", m.albedo, 0.0, 1.0)?;
    check_range("roughness", m.roughness, 0.0, 1.0)?;
    if !(0.0..=1.0).contains(&m.metallic_probability) {
        return err(
            "metallic_probability",
            format!("must be in [0, 1], got {}", m.metallic_probability),
        );
    }
    check_range("key_light", m.key_light, 0.0, 1e6)?;
    check_range("key_light_kelvin", m.key_light_kelvin, 1000.0, 40000.0)?;
    check_range("screen_glow", m.screen_glow, 0.0, 1e6)?;
    check_range("environment", m.environment, 0.0, 1e6)?;
    Ok(())
}

impl Recipe {
    /// True for a 3-D dataset (`meshes` sources).
    pub fn is_meshes(&self) -> bool {
        self.objects
            .sources
            .iter()
            .any(|s| matches!(s, Source::Meshes(_)))
    }

    /// Sample counts per split: train and val rounded to the nearest integer, test the rest.
    pub fn split_counts(&self) -> [usize; 3] {
        let n = self.samples as f64;
        let train = ((n * self.split.train).round() as usize).min(self.samples);
        let val = ((n * self.split.val).round() as usize).min(self.samples - train);
        [train, val, self.samples - train - val]
    }

    /// The distinct discrete scenes: every combination of the `values` lists (first key
    /// slowest) and, last, of the `[depth]` grid (param [`DEPTH_KEY`], no override), each as
    /// (overrides, params). Keys with a `range` are not part of it.
    pub fn discrete_scenes(&self) -> Vec<(Vec<String>, BTreeMap<String, f64>)> {
        let mut out: Vec<(Vec<String>, BTreeMap<String, f64>)> =
            vec![(Vec::new(), BTreeMap::new())];
        for v in &self.vary {
            if let Some(vals) = &v.values {
                out = out
                    .into_iter()
                    .flat_map(|(o, p)| {
                        vals.iter().map(move |&x| {
                            let mut o = o.clone();
                            let mut p = p.clone();
                            o.push(format!("{}={}", v.key, fmt_value(x)));
                            p.insert(v.key.clone(), x);
                            (o, p)
                        })
                    })
                    .collect();
            }
        }
        if let Some(d) = &self.depth {
            let depths = d.depths_mm().unwrap_or_default();
            out = out
                .into_iter()
                .flat_map(|(o, p)| {
                    depths.iter().map(move |&x| {
                        let mut p = p.clone();
                        p.insert(DEPTH_KEY.to_string(), x);
                        (o.clone(), p)
                    })
                })
                .collect();
        }
        out
    }

    /// Number of depths (1 without `[depth]`).
    pub fn depth_count(&self) -> usize {
        self.depth
            .as_ref()
            .map_or(1, |d| d.depths_mm().map_or(1, |v| v.len()))
    }
}

/// The parameter (and metadata column) holding a sample's depth in mm.
pub const DEPTH_KEY: &str = "depth_mm";

/// A value as written into an override (shortest round-trip form).
pub fn fmt_value(x: f64) -> String {
    format!("{x:?}")
}

/// Split names in order.
pub const SPLITS: [&str; 3] = ["train", "val", "test"];

#[cfg(test)]
mod tests {
    use super::*;

    const OK: &str = r#"
name = "t"
seed = 1
samples = 10
mode = "matrix"
[split]
train = 0.8
val = 0.1
test = 0.1
[objects]
size_px = 16
[[objects.sources]]
generator = "glyphs"
[[objects.sources]]
generator = "bars"
max_period_px = 3
"#;

    #[test]
    fn parses_defaults_and_counts() {
        let r = parse_recipe(OK).unwrap();
        assert_eq!(r.spp, 64);
        assert_eq!(r.noise, NoiseModel::Sensor);
        assert_eq!(r.split_counts(), [8, 1, 1]);
        assert_eq!(r.objects.sources[0].name(), "glyphs");
        assert_eq!(r.discrete_scenes().len(), 1);
    }

    #[test]
    fn refuses_bad_recipes_naming_the_key() {
        let bad = |from: &str, to: &str| parse_recipe(&OK.replace(from, to)).unwrap_err();
        let (k, m) = bad("\"glyphs\"", "\"glyfs\"");
        assert!(k.starts_with("objects.sources"), "{k}");
        assert!(m.contains("glyfs") && m.contains("shapes"), "{m}");
        let (k, m) = bad("test = 0.1", "test = 0.2");
        assert_eq!(k, "split");
        assert!(m.contains("sum to 1"), "{m}");
        let (k, _) = bad("samples = 10", "samples = 0");
        assert_eq!(k, "samples");
        let (k, _) = bad("size_px = 16", "size_px = 16\ncolour = 1");
        assert!(k.is_empty() || k.contains("objects"), "{k}");
        let (k, _) = bad("max_period_px = 3", "max_period_px = 4");
        assert_eq!(k, "objects.sources[1].max_period_px");
    }

    #[test]
    fn discrete_scenes_are_the_product_first_key_slowest() {
        let text = format!(
            "{OK}\n[[vary]]\nkey = \"a.b_mm\"\nvalues = [1.0, 2.5]\n[[vary]]\nkey = \"c.d\"\nvalues = [3.0, 4.0, 5.0]\n"
        );
        let r = parse_recipe(&text).unwrap();
        let s = r.discrete_scenes();
        assert_eq!(s.len(), 6);
        assert_eq!(
            s[0].0,
            vec!["a.b_mm=1.0".to_string(), "c.d=3.0".to_string()]
        );
        assert_eq!(
            s[5].0,
            vec!["a.b_mm=2.5".to_string(), "c.d=5.0".to_string()]
        );
        let ranged = format!("{OK}\n[[vary]]\nkey = \"a\"\nrange = [1.0, 2.0]\n");
        let (k, m) = parse_recipe(&ranged).unwrap_err();
        assert_eq!(k, "vary[0].range");
        assert!(m.contains("render"), "{m}");
    }
}
