//! The dataset card (`dataset.json`, or a shard's `shard.json`): recipe, counts, seeds,
//! units and the checksum of every file; and the samples' `metadata.jsonl` lines it lists.

use std::collections::BTreeMap;
use std::path::Path;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{DatasetError, out_err};
use crate::folder::put;
use crate::meshes;
use crate::objects::ObjectSpec;
use crate::plan::{Plan, SampleSpec, sha256_hex};
use crate::recipe::{Recipe, SPLITS};
use crate::shard::Shard;

/// Format tag of the dataset card.
pub const FORMAT: &str = "stscam-dataset/1";

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

/// One `metadata.jsonl` line (Hugging Face imagefolder: `file_name` is the capture PNG).
pub(crate) fn metadata_line(plan: &Plan, s: &SampleSpec) -> Result<String, DatasetError> {
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

pub(crate) struct CardContext<'a> {
    pub(crate) plan: &'a Plan,
    pub(crate) capture_shape: Vec<usize>,
    pub(crate) channels: Vec<String>,
    pub(crate) exposure: serde_json::Value,
}

pub(crate) fn file_entry(root: &Path, rel: &str) -> Result<FileEntry, DatasetError> {
    let p = root.join(rel);
    let bytes = crate::io::read_input(&p, crate::io::MAX_BINARY_BYTES)?;
    Ok(FileEntry {
        sha256: sha256_hex(&bytes),
        bytes: bytes.len() as u64,
    })
}

/// Writes the metadata of the samples in `lines` (split, line; sorted by id) and builds the
/// card over them, the scenes `scene_ids` and every file.
pub(crate) fn finish(
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
