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
//! [[objects.sources]]
//! generator = "glyphs"          # see `Source`
//! weight = 2.0
//!
//! [[vary]]                      # optional per-sample scene variation
//! key = "display.distance_mm"
//! values = [450.0, 550.0, 650.0]   # or range = [450.0, 650.0] (render mode only)
//! ```

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
        }
    }
}

/// Names of the generators, for messages.
pub const GENERATORS: &[&str] = &["glyphs", "shapes", "siemens", "bars", "smooth", "images"];

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
    let err = |k: &str, m: String| Err((k.to_string(), m));
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
    let o = &r.objects;
    if !(2..=MAX_OBJECT_PX).contains(&o.size_px) {
        return err(
            "objects.size_px",
            format!("must be in 2..={MAX_OBJECT_PX}, got {}", o.size_px),
        );
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
    for (i, src) in o.sources.iter().enumerate() {
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
            } if *min_period_px < 1
                || max_period_px < min_period_px
                || 5 * max_period_px > o.size_px =>
            {
                return err(
                    &key("max_period_px"),
                    format!(
                        "need 1 <= min_period_px <= max_period_px and five bar widths within objects.size_px ({}), got {min_period_px}..{max_period_px}",
                        o.size_px
                    ),
                );
            }
            Source::Images { folder, .. } if folder.is_empty() => {
                return err(&key("folder"), "must name a folder".into());
            }
            _ => {}
        }
    }
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

impl Recipe {
    /// Sample counts per split: train and val rounded to the nearest integer, test the rest.
    pub fn split_counts(&self) -> [usize; 3] {
        let n = self.samples as f64;
        let train = ((n * self.split.train).round() as usize).min(self.samples);
        let val = ((n * self.split.val).round() as usize).min(self.samples - train);
        [train, val, self.samples - train - val]
    }

    /// The distinct discrete scenes: every combination of the `values` lists (first key
    /// slowest), each as (overrides, params). Keys with a `range` are not part of it.
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
        out
    }
}

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
