//! Scene description: serde structs (pure data, units in every name), loading from TOML,
//! `--set KEY=VALUE` overrides and validation.
//!
//! A scene file may list only the keys it changes: it is merged over the embedded paper scene
//! (`scenes/paper-2022.toml`), so every key always exists. Keys that the embedded scene does
//! not have are errors, as are values of the wrong type or out of range; each error names the
//! file (or `--set`), the dotted key and the problem.
//!
//! Layer: scene descriptions (serde, pure data): parsing, merge, `--set` overrides, validation, the embedded scenes.
//! May depend on: stscam-base, stscam-io, stscam-optics (docs/design.md, "Crates"; checked by `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod desc;

// The layers below, under the names this crate's modules use (`crate::io::…`).
use stscam_base::{limits, noise, numfmt, suggest};
use stscam_io as io;
use stscam_optics as optics;

use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use crate::numfmt::sig6;

/// The paper's setup, compiled into the binary.
pub const PAPER_SCENE_TOML: &str = include_str!("../../../scenes/paper-2022.toml");

/// The scenes shipped in `scenes/` by name (file name without `.toml`), with their TOML text.
pub const SHIPPED_SCENES: &[(&str, &str)] = &[
    ("paper-2022", PAPER_SCENE_TOML),
    ("eye-contact", include_str!("../../../scenes/eye-contact.toml")),
    ("gesture", include_str!("../../../scenes/gesture.toml")),
];
/// The full-colour design of `scenes/rgb-multiplex.toml`, compiled into the binary for
/// `stscam demo --colour`.
pub const RGB_MULTIPLEX_TOML: &str = include_str!("../../../scenes/rgb-multiplex.toml");
/// Name used in messages for the embedded RGB design.
pub const RGB_MULTIPLEX_NAME: &str = "<embedded scenes/rgb-multiplex.toml>";

/// Name used in messages for the embedded scene.
pub const EMBEDDED_NAME: &str = "<embedded scenes/paper-2022.toml>";

/// A scene error: one line naming the source (file or `--set`), the key and the problem.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("{file}: cannot read scene file: {message}")]
    Read {
        /// Scene file.
        file: String,
        /// OS error text.
        message: String,
    },
    /// TOML syntax error.
    #[error("{file}: {location}: malformed TOML: {message}")]
    Syntax {
        /// Scene file.
        file: String,
        /// "line L, column C".
        location: String,
        /// Parser message.
        message: String,
    },
    /// A key-specific problem (unknown key, wrong type, out of range, missing asset).
    #[error("{file}: {key}: {message}")]
    Key {
        /// Scene file, or `--set`.
        file: String,
        /// Dotted key, e.g. `plate.thickness_mm`.
        key: String,
        /// What is wrong.
        message: String,
    },
}

/// A value that is either the word "auto" or a number.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged, expecting = "\"auto\" or a number")]
pub enum AutoOr {
    /// A number.
    Value(f64),
    /// Should be "auto" (checked by validation).
    Word(String),
}

impl AutoOr {
    /// The number, or `None` for "auto".
    pub fn value(&self) -> Option<f64> {
        match self {
            AutoOr::Value(v) => Some(*v),
            AutoOr::Word(_) => None,
        }
    }
}

/// Glass of the plate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(
    untagged,
    expecting = "\"soda-lime\", \"n-bk7\" or a constant refractive index"
)]
pub enum GlassSpec {
    /// Constant, non-dispersive index.
    Index(f64),
    /// A named glass model.
    Name(String),
}

/// Display polarisation: "none" or the E-field angle in degrees from the x axis.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged, expecting = "\"none\" or an angle in degrees")]
pub enum PolarizationSpec {
    /// E-field angle in degrees from the horizontal x axis.
    AngleDeg(f64),
    /// Should be "none".
    Word(String),
}

/// Sensor crop: a square size or [width, height].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged, expecting = "a pixel count or [width, height]")]
pub enum CropSpec {
    /// Square crop.
    Square(u32),
    /// Width and height.
    Rect([u32; 2]),
}

impl CropSpec {
    /// (width, height) in pixels.
    pub fn size(&self) -> (u32, u32) {
        match self {
            CropSpec::Square(s) => (*s, *s),
            CropSpec::Rect([w, h]) => (*w, *h),
        }
    }
}

/// `[plate]`: the glass waveguide.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlateDesc {
    /// Plate thickness w in mm.
    pub thickness_mm: f64,
    /// Glass model.
    pub glass: GlassSpec,
    /// Intensity absorption in 1/mm or "auto" (from the glass model).
    pub absorption_per_mm: AutoOr,
}

/// `[hoe]`: the film both volume holograms are made of, and the gratings recorded in it.
///
/// A film holds one or more gratings. The single-grating keys (`recording_wavelength_nm`,
/// `reference_angle_deg`, `index_modulation`) describe one grating; a scene may instead list
/// `[[hoe.grating]]` entries ([`GratingDesc`], at most [`MAX_GRATINGS`]); giving both is an
/// error. Thickness, mean index and absorption belong to the film and are shared.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HoeDesc {
    /// Recording wavelength λ0 in nm (single-grating form).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recording_wavelength_nm: Option<f64>,
    /// Reference-beam angle inside the film, degrees (single-grating form).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_angle_deg: Option<f64>,
    /// Film thickness in µm.
    pub film_thickness_um: f64,
    /// Index modulation n1 (peak-to-mean; single-grating form).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub index_modulation: Option<f64>,
    /// Mean film index.
    pub mean_index: f64,
    /// Mean amplitude absorption α0 of the film in 1/mm.
    pub amplitude_absorption_per_mm: f64,
    /// Gratings multiplexed in the film (`[[hoe.grating]]`); empty in the single-grating form.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub grating: Vec<GratingDesc>,
    /// Efficiency model of the tracer: Kogelnik's closed form or RCWA tables (docs/rcwa.md).
    #[serde(
        default,
        skip_serializing_if = "crate::optics::GratingModel::is_kogelnik"
    )]
    pub model: crate::optics::GratingModel,
    /// Fabrication: relative loss of film thickness after recording (shrinkage s; the fringes'
    /// normal component scales, K_z → K_z/(1 − s), the in-plane period is held by the
    /// substrate; `optics::fabrication`). 0 = nominal.
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub shrinkage: f64,
    /// Fabrication: change of the mean film index after recording (post-cure, bleaching); the
    /// fringes stay where they were recorded. 0 = nominal.
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub mean_index_change: f64,
    /// Fabrication: error of the coated film thickness in µm (the fringes are recorded in the
    /// film as coated, so only the thickness changes). 0 = nominal.
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub thickness_error_um: f64,
    /// Playback temperature minus recording temperature, K (thermal expansion and dn/dT of
    /// the film). 0 = nominal.
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub temperature_change_k: f64,
    /// Linear thermal expansion of the film across its thickness, 1/K (used with
    /// `temperature_change_k`).
    #[serde(
        default = "default_film_expansion",
        skip_serializing_if = "is_default_film_expansion"
    )]
    pub film_expansion_per_k: f64,
    /// Linear thermal expansion of the substrate (the film's in-plane period), 1/K.
    #[serde(
        default = "default_substrate_expansion",
        skip_serializing_if = "is_default_substrate_expansion"
    )]
    pub substrate_expansion_per_k: f64,
    /// Thermo-optic coefficient dn/dT of the film's mean index, 1/K.
    #[serde(
        default = "default_index_change_per_k",
        skip_serializing_if = "is_default_index_change_per_k"
    )]
    pub index_change_per_k: f64,
    /// Fabrication, single-grating form: relative shortfall f of the index modulation,
    /// n1 → n1·(1 − f). 0 = nominal.
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub index_modulation_shortfall: f64,
    /// Fabrication, single-grating form: error of the reference-beam angle at recording,
    /// degrees inside the film. 0 = nominal.
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub reference_angle_error_deg: f64,
}

/// Default of `hoe.film_expansion_per_k` (ASSUMPTION, docs/keys.md: a typical acrylate
/// polymer's linear expansion).
pub const DEFAULT_FILM_EXPANSION_PER_K: f64 = 1.0e-4;
/// Default of `hoe.substrate_expansion_per_k`: soda-lime float glass.
pub const DEFAULT_SUBSTRATE_EXPANSION_PER_K: f64 = 9.0e-6;
impl HoeDesc {
    /// The film's design and fabrication errors as the numbers the optics take.
    pub fn fabrication(&self) -> crate::optics::fabrication::FilmFabrication {
        crate::optics::fabrication::FilmFabrication {
            film_thickness_um: self.film_thickness_um,
            mean_index: self.mean_index,
            amplitude_absorption_per_mm: self.amplitude_absorption_per_mm,
            shrinkage: self.shrinkage,
            mean_index_change: self.mean_index_change,
            thickness_error_um: self.thickness_error_um,
            temperature_change_k: self.temperature_change_k,
            film_expansion_per_k: self.film_expansion_per_k,
            substrate_expansion_per_k: self.substrate_expansion_per_k,
            index_change_per_k: self.index_change_per_k,
        }
    }

    /// Every grating of the film as fabricated ([`crate::optics::fabrication`]), in scene
    /// order.
    pub fn fabricated_gratings(&self) -> Vec<crate::optics::grating::VolumeGrating> {
        let rec: Vec<_> = self.gratings().iter().map(GratingDesc::recording).collect();
        crate::optics::fabrication::fabricated_gratings(&self.fabrication(), &rec)
    }
}

impl GratingDesc {
    /// The grating's recording and its errors as the numbers the optics take.
    pub fn recording(&self) -> crate::optics::fabrication::GratingRecording {
        crate::optics::fabrication::GratingRecording {
            recording_wavelength_nm: self.recording_wavelength_nm,
            reference_angle_deg: self.reference_angle_deg,
            object_angle_deg: self.object_angle_deg,
            index_modulation: self.index_modulation,
            index_modulation_shortfall: self.index_modulation_shortfall,
            reference_angle_error_deg: self.reference_angle_error_deg,
        }
    }
}

/// Default of `hoe.index_change_per_k` (ASSUMPTION: typical of acrylate polymers).
pub const DEFAULT_INDEX_CHANGE_PER_K: f64 = -1.0e-4;

fn default_film_expansion() -> f64 {
    DEFAULT_FILM_EXPANSION_PER_K
}
fn is_default_film_expansion(v: &f64) -> bool {
    *v == DEFAULT_FILM_EXPANSION_PER_K
}
fn default_substrate_expansion() -> f64 {
    DEFAULT_SUBSTRATE_EXPANSION_PER_K
}
fn is_default_substrate_expansion(v: &f64) -> bool {
    *v == DEFAULT_SUBSTRATE_EXPANSION_PER_K
}
fn default_index_change_per_k() -> f64 {
    DEFAULT_INDEX_CHANGE_PER_K
}
fn is_default_index_change_per_k(v: &f64) -> bool {
    *v == DEFAULT_INDEX_CHANGE_PER_K
}

/// One grating of a multiplexed film (`[[hoe.grating]]`): the recording that made it.
/// Recording beams inside the film: object ŝ_O = (0, sin θ_O, cos θ_O), reference
/// ŝ_R = (0, sin θ_R, −cos θ_R).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GratingDesc {
    /// Recording wavelength λ0 in nm.
    pub recording_wavelength_nm: f64,
    /// Reference-beam angle θ_R inside the film, degrees from −z.
    pub reference_angle_deg: f64,
    /// Object-beam angle θ_O inside the film, degrees from +z (0: normal to the film).
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub object_angle_deg: f64,
    /// Index modulation n1 of this grating (peak-to-mean).
    pub index_modulation: f64,
    /// Fabrication: relative shortfall f of this grating's index modulation, n1 → n1·(1 − f).
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub index_modulation_shortfall: f64,
    /// Fabrication: error of this grating's reference-beam angle at recording, degrees.
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub reference_angle_error_deg: f64,
}

pub use crate::optics::multiplex::MAX_GRATINGS;

fn is_zero_f64(v: &f64) -> bool {
    *v == 0.0
}

/// The single-grating keys of `[hoe]`, which `[[hoe.grating]]` entries replace.
pub const SINGLE_GRATING_KEYS: &[&str] = &[
    "recording_wavelength_nm",
    "reference_angle_deg",
    "index_modulation",
];

/// The single-grating form's per-grating fabrication keys of `[hoe]` (optional, default 0),
/// which `[[hoe.grating]]` entries carry themselves.
pub const SINGLE_GRATING_FABRICATION_KEYS: &[&str] =
    &["index_modulation_shortfall", "reference_angle_error_deg"];

/// Every single-grating key of `[hoe]` (required and optional).
fn single_form_keys() -> impl Iterator<Item = &'static str> {
    SINGLE_GRATING_KEYS
        .iter()
        .chain(SINGLE_GRATING_FABRICATION_KEYS)
        .copied()
}

impl HoeDesc {
    /// The film's gratings in order: the `[[hoe.grating]]` entries, or the one grating of the
    /// single-grating keys.
    pub fn gratings(&self) -> Vec<GratingDesc> {
        if !self.grating.is_empty() {
            return self.grating.clone();
        }
        vec![GratingDesc {
            recording_wavelength_nm: self.recording_wavelength_nm.unwrap_or(f64::NAN),
            reference_angle_deg: self.reference_angle_deg.unwrap_or(f64::NAN),
            object_angle_deg: 0.0,
            index_modulation: self.index_modulation.unwrap_or(f64::NAN),
            index_modulation_shortfall: self.index_modulation_shortfall,
            reference_angle_error_deg: self.reference_angle_error_deg,
        }]
    }

    /// The first grating's recording wavelength (nm): the reference wavelength of the design
    /// (auto focus, the glass index of the see-through test).
    pub fn primary_wavelength_nm(&self) -> f64 {
        self.grating.first().map_or_else(
            || self.recording_wavelength_nm.unwrap_or(f64::NAN),
            |g| g.recording_wavelength_nm,
        )
    }

    /// The key of field `field` of grating `i` as messages name it: `hoe.FIELD` in the
    /// single-grating form, `hoe.grating[i].FIELD` for a list.
    pub fn key_of(&self, i: usize, field: &str) -> String {
        if self.grating.is_empty() {
            format!("hoe.{field}")
        } else {
            format!("hoe.grating[{i}].{field}")
        }
    }
}

/// `[bottom_hoe]`: the in-coupling hologram on the back face.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BottomHoeDesc {
    /// Width (x) in mm.
    pub width_mm: f64,
    /// Height (y) in mm.
    pub height_mm: f64,
}

/// `[top_hoe]`: the out-coupling hologram on the front face.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TopHoeDesc {
    /// Width (x) in mm.
    pub width_mm: f64,
    /// Height (y) in mm.
    pub height_mm: f64,
    /// Gap between the bottom vHOE's top edge and the top vHOE's bottom edge, mm.
    pub gap_mm: f64,
    /// Whether an absorbing cover (tape) sits on the user side of the top vHOE.
    pub covered: bool,
    /// Whether the cover makes optical contact and absorbs at TIR contacts under it.
    pub cover_frustrates_tir: bool,
}

/// `[camera]`: thin-lens camera behind the plate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraDesc {
    /// Lens to back face, mm (d1).
    pub distance_mm: f64,
    /// Focal length, mm.
    pub focal_length_mm: f64,
    /// F-number (aperture diameter = f / N).
    pub f_number: f64,
    /// Focus distance from the lens in mm (air-equivalent), or "auto".
    pub focus_distance_mm: AutoOr,
}

/// `[sensor]`: pixel grid, crop and spectral response.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorDesc {
    /// Full sensor width in pixels.
    pub width_px: u32,
    /// Full sensor height in pixels.
    pub height_px: u32,
    /// Pixel pitch in µm.
    pub pitch_um: f64,
    /// Rendered crop.
    pub crop_px: CropSpec,
    /// Crop centre offset from the sensor centre, pixels (+x right, +y up in the image).
    pub crop_offset_px: [i32; 2],
    /// Spectral response name.
    pub response: String,
}

/// `[display]`: the emissive LCD showing the target.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DisplayDesc {
    /// Distance from the front face, mm (display at z = −distance).
    pub distance_mm: f64,
    /// LCD pixel pitch, mm.
    pub pixel_pitch_mm: f64,
    /// LCD size in pixels [width, height].
    pub size_px: [u32; 2],
    /// Target image: a PNG/EXR path (relative to the scene file) or a built-in target name.
    pub image: String,
    /// LCD pixels per target pixel.
    pub lcd_pixels_per_image_pixel: u32,
    /// Centre of the target (and of the LCD) on the display plane, mm [x, y].
    pub center_mm: [f64; 2],
    /// Backlight spectrum name.
    pub spectrum: String,
    /// Colour primaries of the display: "none" (monochrome: every pixel emits the backlight
    /// spectrum, one object plane) or "lcd" (three primaries, backlight × colour filter; the
    /// object is linear R, G, B per pixel). Left out of serialised scenes at "none", so
    /// monochrome outputs keep their bytes.
    #[serde(default = "default_primaries", skip_serializing_if = "is_no_primaries")]
    pub primaries: String,
    /// Polarisation of the emitted light.
    pub polarization: PolarizationSpec,
    /// Display gamma (code value → linear radiance).
    pub gamma: f64,
    /// Black level as a fraction of white.
    pub black_level: f64,
    /// Whether the LCD is there (it emits and lights 3-D scenes). Left out of serialised
    /// scenes when true, so display-only outputs keep their bytes.
    #[serde(default = "yes", skip_serializing_if = "is_true")]
    pub enabled: bool,
}

/// `[sampling]`: Monte Carlo estimator settings that belong to the scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplingDesc {
    /// Lower end of the spectral band, nm.
    pub lambda_min_nm: f64,
    /// Upper end of the spectral band, nm.
    pub lambda_max_nm: f64,
    /// Fraction of wavelengths drawn uniformly over the band.
    pub uniform_fraction: f64,
    /// Guided weight below which a path stops.
    pub min_guided_weight: f64,
    /// Hard limit on plate contacts per path.
    pub max_contacts: u32,
    /// 3-D scenes: surface interactions per user-side path (1 = direct light only). Left
    /// out of serialised scenes at its default, so display-only outputs keep their bytes.
    #[serde(
        default = "default_max_depth",
        skip_serializing_if = "is_default_max_depth"
    )]
    pub max_depth: u32,
}

pub use crate::noise::NoiseDesc;

/// A complete scene description.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Glass plate.
    pub plate: PlateDesc,
    /// Shared hologram properties.
    pub hoe: HoeDesc,
    /// In-coupling hologram.
    pub bottom_hoe: BottomHoeDesc,
    /// Out-coupling hologram.
    pub top_hoe: TopHoeDesc,
    /// Camera.
    pub camera: CameraDesc,
    /// Sensor.
    pub sensor: SensorDesc,
    /// Display.
    pub display: DisplayDesc,
    /// Sampling.
    pub sampling: SamplingDesc,
    /// Sensor noise.
    pub noise: NoiseDesc,
    /// Objects of the user side (`[[object]]`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub object: Vec<crate::desc::ObjectDesc>,
    /// Lights of the user side (`[[light]]`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub light: Vec<crate::desc::LightDesc>,
}

/// Default of `sampling.max_depth`.
pub const DEFAULT_MAX_DEPTH: u32 = 5;

fn yes() -> bool {
    true
}

fn is_true(v: &bool) -> bool {
    *v
}

fn default_primaries() -> String {
    "none".into()
}

fn is_no_primaries(v: &String) -> bool {
    v == "none"
}

fn default_max_depth() -> u32 {
    DEFAULT_MAX_DEPTH
}

fn is_default_max_depth(v: &u32) -> bool {
    *v == DEFAULT_MAX_DEPTH
}

/// Top-level arrays of tables that a scene file adds (the embedded scene has none).
pub const LIST_SECTIONS: &[&str] = &["object", "light"];

impl Scene {
    /// True if the scene has a user side beyond the display (objects or lights).
    pub fn has_world(&self) -> bool {
        !self.object.is_empty() || !self.light.is_empty()
    }
}

/// A scene with the context needed to resolve its assets and report errors.
#[derive(Clone, Debug)]
pub struct LoadedScene {
    /// The description after merging and overrides.
    pub scene: Scene,
    /// Name of the source used in messages.
    pub source: String,
    /// Directory against which relative asset paths resolve.
    pub base_dir: PathBuf,
    /// Keys changed by `--set`.
    pub overridden: BTreeSet<String>,
}

impl LoadedScene {
    /// The name to blame for a key: `--set` if it was overridden, else the scene source.
    pub fn origin_of(&self, key: &str) -> String {
        if is_overridden(&self.overridden, key) {
            format!("--set {}", set_form(key))
        } else {
            self.source.clone()
        }
    }

    /// An error about a relation between `keys`, blamed on the first of them that `--set`
    /// changed (else on the first): the key the user set, not one derived from it.
    pub fn relation_error(&self, keys: &[&str], message: impl Into<String>) -> SceneError {
        self.key_error(blame(self, keys), message)
    }

    /// A key error attributed to the right origin.
    pub fn key_error(&self, key: &str, message: impl Into<String>) -> SceneError {
        SceneError::Key {
            file: self.origin_of(key),
            key: key.to_string(),
            message: message.into(),
        }
    }
}

/// `hoe.grating[1].index_modulation` → `hoe.grating.1.index_modulation` (the `--set` form of
/// a grating entry's key; other keys unchanged).
fn set_form(key: &str) -> String {
    if key.starts_with("hoe.grating[") {
        key.replace("].", ".").replace('[', ".").replace(']', "")
    } else {
        key.to_string()
    }
}

/// Whether `key` (possibly with a `.field` or `[index]` suffix) was set by `--set`.
fn is_overridden(overridden: &BTreeSet<String>, key: &str) -> bool {
    let dotted = set_form(key);
    let key = dotted.as_str();
    overridden.iter().any(|k| {
        key == k
            || key
                .strip_prefix(k.as_str())
                .is_some_and(|rest| rest.starts_with('.') || rest.starts_with('['))
    })
}

/// The first of `keys` that was set by `--set`, else the first key: the one to name in an
/// error about a relation between several keys.
fn blame<'a>(ls: &LoadedScene, keys: &[&'a str]) -> &'a str {
    keys.iter()
        .copied()
        .find(|k| is_overridden(&ls.overridden, k))
        .unwrap_or(keys[0])
}

fn line_col(text: &str, offset: usize) -> String {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |s| s.chars().count()) + 1;
    format!("line {line}, column {col}")
}

fn parse_table(text: &str, file: &str) -> Result<toml::Table, SceneError> {
    text.parse::<toml::Table>().map_err(|e| SceneError::Syntax {
        file: file.to_string(),
        location: e.span().map_or_else(
            || "unknown position".to_string(),
            |s| line_col(text, s.start),
        ),
        message: e.message().trim().replace('\n', " "),
    })
}

/// Merges `over` into `base`; every key of `over` must exist in `base`.
fn merge(
    base: &mut toml::Table,
    over: toml::Table,
    prefix: &str,
    file: &str,
) -> Result<(), SceneError> {
    if prefix == "hoe" && over.contains_key("grating") {
        take_grating_list(base, &over, file)?;
    }
    for (k, v) in over {
        if prefix == "hoe" && k == "grating" {
            // Checked and prepared by `take_grating_list`.
            base.insert(k, v);
            continue;
        }
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        if prefix.is_empty() && LIST_SECTIONS.contains(&k.as_str()) {
            if !matches!(&v, toml::Value::Array(a) if a.iter().all(toml::Value::is_table)) {
                return Err(SceneError::Key {
                    file: file.to_string(),
                    key,
                    message: format!("expected [[{k}]] tables"),
                });
            }
            base.insert(k, v);
            continue;
        }
        let unknown = (!base.contains_key(&k)).then(|| unknown_key_message(prefix, &k, base));
        match (base.get_mut(&k), v) {
            (None, _) => {
                return Err(SceneError::Key {
                    file: file.to_string(),
                    key,
                    message: unknown.unwrap_or_default(),
                });
            }
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o, &key, file)?,
            (Some(toml::Value::Table(_)), _) => {
                return Err(SceneError::Key {
                    file: file.to_string(),
                    key,
                    message: "expected a table".into(),
                });
            }
            (Some(slot), v) => *slot = v,
        }
    }
    Ok(())
}

/// A scene's `[hoe]` table `over` lists `[[hoe.grating]]` entries: checks they are tables, at
/// most [`MAX_GRATINGS`], and that `over` does not also give a single-grating key; removes the
/// embedded scene's single-grating keys from `base` (the list replaces them).
fn take_grating_list(
    base: &mut toml::Table,
    over: &toml::Table,
    file: &str,
) -> Result<(), SceneError> {
    let fail = |key: &str, message: String| SceneError::Key {
        file: file.to_string(),
        key: key.to_string(),
        message,
    };
    if let Some(single) = single_form_keys().find(|k| over.contains_key(*k)) {
        return Err(fail(
            &format!("hoe.{single}"),
            format!(
                "give either [[hoe.grating]] entries or the single-grating keys {}, not both",
                SINGLE_GRATING_KEYS
                    .iter()
                    .map(|k| format!("hoe.{k}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ));
    }
    match over.get("grating") {
        Some(toml::Value::Array(a)) if !a.is_empty() && a.iter().all(toml::Value::is_table) => {
            if a.len() > MAX_GRATINGS {
                return Err(fail(
                    "hoe.grating",
                    format!("{} gratings; a film holds at most {MAX_GRATINGS}", a.len()),
                ));
            }
        }
        _ => {
            return Err(fail(
                "hoe.grating",
                "expected one or more [[hoe.grating]] tables".into(),
            ));
        }
    }
    for k in single_form_keys() {
        base.remove(k);
    }
    Ok(())
}

/// "unknown key", with the nearest key of `table` (the section `prefix`) as a suggestion.
fn unknown_key_message(prefix: &str, key: &str, table: &toml::Table) -> String {
    let full = |k: &str| {
        if prefix.is_empty() {
            k.to_string()
        } else {
            format!("{prefix}.{k}")
        }
    };
    let names: Vec<String> = table.keys().map(|k| full(k)).collect();
    format!(
        "unknown key{}",
        crate::suggest::did_you_mean(&full(key), names.iter().map(String::as_str))
    )
}

/// Parses a `--set` value: TOML syntax if it parses (numbers, booleans, arrays, quoted
/// strings), otherwise the raw text as a string.
fn parse_override_value(raw: &str) -> toml::Value {
    let doc = format!("v = {raw}");
    match doc.parse::<toml::Table>() {
        Ok(mut t) => t
            .remove("v")
            .unwrap_or_else(|| toml::Value::String(raw.to_string())),
        Err(_) => toml::Value::String(raw.to_string()),
    }
}

/// Applies one `KEY=VALUE` override to a full scene table. Array elements are addressed by
/// index (`object.0.position_mm`); inside an `[[object]]` or `[[light]]` element a key the
/// element does not list yet may be set (its name is checked when the scene is read).
fn apply_override(table: &mut toml::Table, spec: &str) -> Result<String, SceneError> {
    let Some((key, raw)) = spec.split_once('=') else {
        return Err(SceneError::Key {
            file: "--set".into(),
            key: spec.to_string(),
            message: "expected KEY=VALUE".into(),
        });
    };
    let key = key.trim();
    let fail = |message: String| SceneError::Key {
        file: format!("--set {key}"),
        key: key.to_string(),
        message,
    };
    let unknown = || fail("unknown key".into());
    let parts: Vec<&str> = key.split('.').collect();
    let in_list = (parts.len() > 2 && LIST_SECTIONS.contains(&parts[0]))
        || (parts.len() > 3 && parts[0] == "hoe" && parts[1] == "grating");
    if !table.contains_key(parts[0]) {
        return Err(if LIST_SECTIONS.contains(&parts[0]) {
            fail(format!("the scene has no [[{}]] elements to set", parts[0]))
        } else {
            fail(unknown_key_message("", parts[0], table))
        });
    }
    let mut cur: &mut toml::Value = table.get_mut(parts[0]).ok_or_else(unknown)?;
    for (depth, part) in parts.iter().enumerate().skip(1) {
        let last = depth + 1 == parts.len();
        cur = match cur {
            toml::Value::Array(a) => {
                let i: usize = part
                    .parse()
                    .map_err(|_| fail(format!("{part:?} is not an element index")))?;
                let n = a.len();
                a.get_mut(i)
                    .ok_or_else(|| fail(format!("index {i} is out of range ({n} elements)")))?
            }
            toml::Value::Table(t) => {
                if !t.contains_key(*part) {
                    if depth == 1 && parts[0] == "hoe" {
                        if let Some(m) = grating_form_mismatch(t, part) {
                            return Err(fail(m));
                        }
                    }
                    if !in_list {
                        return Err(fail(unknown_key_message(
                            &parts[..depth].join("."),
                            part,
                            t,
                        )));
                    }
                    let fill = if last {
                        toml::Value::Boolean(false)
                    } else {
                        toml::Value::Table(toml::Table::new())
                    };
                    t.insert((*part).to_string(), fill);
                }
                t.get_mut(*part).ok_or_else(unknown)?
            }
            _ => return Err(unknown()),
        };
    }
    if parts.len() == 1 || cur.is_table() || (cur.is_array() && parts.len() == 1) {
        return Err(fail("is a section; set one of its keys".into()));
    }
    *cur = parse_override_value(raw.trim());
    Ok(key.to_string())
}

/// Why `--set hoe.PART…` cannot apply to the `[hoe]` table `t`: a single-grating key on a
/// film that lists `[[hoe.grating]]` entries, or a grating entry on one that does not.
fn grating_form_mismatch(t: &toml::Table, part: &str) -> Option<String> {
    if t.contains_key("grating") && single_form_keys().any(|k| k == part) {
        Some(format!(
            "the scene lists [[hoe.grating]] entries; set hoe.grating.N.{part} (N from 0)"
        ))
    } else if part == "grating" && !t.contains_key("grating") {
        Some(
            "the scene has no [[hoe.grating]] entries to set; its one grating is \
             hoe.recording_wavelength_nm, hoe.reference_angle_deg, hoe.index_modulation"
                .into(),
        )
    } else {
        None
    }
}

/// Loads a scene: the embedded paper scene, merged with `path` if given, then the overrides.
/// The result is validated.
pub fn load_scene(path: Option<&Path>, overrides: &[String]) -> Result<LoadedScene, SceneError> {
    match path {
        Some(p) => {
            let file = p.display().to_string();
            let text = crate::io::read_text(p).map_err(|e| SceneError::Read {
                file: file.clone(),
                message: match e {
                    crate::io::IoError::Io { source, .. } => source.to_string(),
                    crate::io::IoError::Format { message, .. } => message,
                },
            })?;
            let dir = p.parent().map(Path::to_path_buf).unwrap_or_default();
            load_scene_text(Some((&text, &file, &dir)), overrides)
        }
        None => load_scene_text(None, overrides),
    }
}

/// Where a scene comes from, for jobs that load it more than once (a sweep loads it per grid
/// point): a file (or, with `None`, the embedded paper scene alone), or TOML text in memory
/// (the Python module's scenes built from dicts).
#[derive(Clone, Copy, Debug)]
pub enum SceneSource<'a> {
    /// [`load_scene`]'s file.
    File(Option<&'a Path>),
    /// [`load_scene_text`]'s (text, name to blame in messages, directory of relative paths).
    Text(&'a str, &'a str, &'a Path),
}

impl SceneSource<'_> {
    /// Loads the scene with `overrides` applied, as [`load_scene`] or [`load_scene_text`].
    pub fn load(&self, overrides: &[String]) -> Result<LoadedScene, SceneError> {
        match *self {
            SceneSource::File(path) => load_scene(path, overrides),
            SceneSource::Text(text, name, dir) => {
                load_scene_text(Some((text, name, dir)), overrides)
            }
        }
    }
}

/// As [`load_scene`], for a scene held in memory: `user` is (TOML text, the name to blame in
/// messages, the directory its relative asset paths resolve against), merged over the paper
/// scene; `None` is the paper scene alone.
pub fn load_scene_text(
    user: Option<(&str, &str, &Path)>,
    overrides: &[String],
) -> Result<LoadedScene, SceneError> {
    let mut table = parse_table(PAPER_SCENE_TOML, EMBEDDED_NAME)?;
    let (source, base_dir) = match user {
        Some((text, file, dir)) => {
            let user = parse_table(text, file)?;
            merge(&mut table, user, "", file)?;
            (file.to_string(), dir.to_path_buf())
        }
        None => (EMBEDDED_NAME.to_string(), PathBuf::from(".")),
    };
    let mut overridden = BTreeSet::new();
    for spec in overrides {
        overridden.insert(apply_override(&mut table, spec)?);
    }
    let mut loaded = LoadedScene {
        scene: placeholder_free_deserialize(table, &source, &overridden)?,
        source,
        base_dir,
        overridden,
    };
    if loaded.base_dir.as_os_str().is_empty() {
        loaded.base_dir = PathBuf::from(".");
    }
    validate(&loaded)?;
    canonical_single_grating(&mut loaded.scene.hoe);
    Ok(loaded)
}

/// A one-entry `[[hoe.grating]]` list with the object beam normal to the film is the same film
/// as the single-grating keys: it is stored in that form, so the scene (and every output that
/// records it) is the same whichever form the file used.
fn canonical_single_grating(h: &mut HoeDesc) {
    if let [g] = h.grating.as_slice() {
        if g.object_angle_deg == 0.0 {
            h.recording_wavelength_nm = Some(g.recording_wavelength_nm);
            h.reference_angle_deg = Some(g.reference_angle_deg);
            h.index_modulation = Some(g.index_modulation);
            h.index_modulation_shortfall = g.index_modulation_shortfall;
            h.reference_angle_error_deg = g.reference_angle_error_deg;
            h.grating.clear();
        }
    }
}

/// `object[0].mesh` → `object.0.mesh`: keys inside `[[object]]` and `[[light]]` are named as
/// `--set` takes them (other array elements keep serde's `key[i]` form).
fn dotted_path(path: &str) -> String {
    if LIST_SECTIONS
        .iter()
        .any(|l| path.starts_with(&format!("{l}[")))
    {
        path.replace("].", ".").replace('[', ".").replace(']', "")
    } else {
        path.to_string()
    }
}

fn placeholder_free_deserialize(
    table: toml::Table,
    source: &str,
    overridden: &BTreeSet<String>,
) -> Result<Scene, SceneError> {
    serde_path_to_error::deserialize::<_, Scene>(table).map_err(|e| {
        let key = dotted_path(&e.path().to_string());
        let file = if is_overridden(overridden, &key) {
            format!("--set {key}")
        } else {
            source.to_string()
        };
        SceneError::Key {
            file,
            key,
            message: e.inner().to_string().replace('\n', " "),
        }
    })
}

/// Names of the glasses `plate.glass` accepts.
pub const GLASS_NAMES: &[&str] = &["soda-lime", "n-bk7"];
/// Names `sensor.response` accepts.
pub const RESPONSE_NAMES: &[&str] = &["mono-qe", "mono-bayer-y", "flat", "rgb-bayer"];
/// Names `display.primaries` accepts.
pub const PRIMARIES_NAMES: &[&str] = &["none", "lcd"];

/// Names `display.spectrum` accepts.
pub const SPECTRUM_NAMES: &[&str] = &["white-led", "flat", "ccfl"];

fn check(
    ls: &LoadedScene,
    ok: bool,
    key: &str,
    message: impl FnOnce() -> String,
) -> Result<(), SceneError> {
    if ok {
        Ok(())
    } else {
        Err(ls.key_error(key, message()))
    }
}

fn positive(ls: &LoadedScene, v: f64, key: &str) -> Result<(), SceneError> {
    check(ls, v.is_finite() && v > 0.0, key, || {
        format!("must be a positive finite number, got {}", sig6(v))
    })
}

fn in_range(ls: &LoadedScene, v: f64, lo: f64, hi: f64, key: &str) -> Result<(), SceneError> {
    check(ls, v.is_finite() && v >= lo && v <= hi, key, || {
        format!("must be in [{}, {}], got {}", sig6(lo), sig6(hi), sig6(v))
    })
}

/// Checks ranges and names; every failure names its key. The sections are checked in the
/// order of the scene file; the first failure is reported.
pub fn validate(ls: &LoadedScene) -> Result<(), SceneError> {
    validate_plate(ls)?;
    validate_hoe(ls)?;
    validate_hoe_areas(ls)?;
    validate_camera(ls)?;
    validate_sensor(ls)?;
    validate_display(ls)?;
    validate_sampling(ls)?;
    validate_noise(ls)?;
    let sm = &ls.scene.sampling;
    check(
        ls,
        (1..=64).contains(&sm.max_depth),
        "sampling.max_depth",
        || format!("must be in [1, 64], got {}", sm.max_depth),
    )?;
    crate::desc::validate_world(&ls.scene.object, &ls.scene.light)
        .map_err(|p| ls.key_error(&p.key, p.message))?;
    Ok(())
}

/// `[plate]`: thickness, glass and absorption.
fn validate_plate(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    positive(ls, s.plate.thickness_mm, "plate.thickness_mm")?;
    match &s.plate.glass {
        GlassSpec::Index(n) => in_range(ls, *n, 1.0, 4.0, "plate.glass")?,
        GlassSpec::Name(name) => check(
            ls,
            GLASS_NAMES.contains(&name.as_str()),
            "plate.glass",
            || format!("unknown glass {name:?}; expected one of {GLASS_NAMES:?} or a number"),
        )?,
    }
    match &s.plate.absorption_per_mm {
        AutoOr::Value(a) => in_range(ls, *a, 0.0, 1e3, "plate.absorption_per_mm")?,
        AutoOr::Word(w) => check(ls, w == "auto", "plate.absorption_per_mm", || {
            format!("expected \"auto\" or a number, got {w:?}")
        })?,
    }
    Ok(())
}

/// The sizes of the bottom and top vHOEs and the gap between them.
fn validate_hoe_areas(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    positive(ls, s.bottom_hoe.width_mm, "bottom_hoe.width_mm")?;
    positive(ls, s.bottom_hoe.height_mm, "bottom_hoe.height_mm")?;
    positive(ls, s.top_hoe.width_mm, "top_hoe.width_mm")?;
    positive(ls, s.top_hoe.height_mm, "top_hoe.height_mm")?;
    in_range(ls, s.top_hoe.gap_mm, 0.0, 1e4, "top_hoe.gap_mm")?;
    Ok(())
}

/// `[camera]`: distance, lens and focus.
fn validate_camera(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    positive(ls, s.camera.distance_mm, "camera.distance_mm")?;
    positive(ls, s.camera.focal_length_mm, "camera.focal_length_mm")?;
    positive(ls, s.camera.f_number, "camera.f_number")?;
    match &s.camera.focus_distance_mm {
        AutoOr::Value(v) => check(
            ls,
            v.is_finite() && *v > s.camera.focal_length_mm,
            blame(ls, &["camera.focus_distance_mm", "camera.focal_length_mm"]),
            || {
                format!(
                    "camera.focus_distance_mm ({} mm) must exceed camera.focal_length_mm ({} mm)",
                    sig6(*v),
                    sig6(s.camera.focal_length_mm)
                )
            },
        )?,
        AutoOr::Word(w) => check(ls, w == "auto", "camera.focus_distance_mm", || {
            format!("expected \"auto\" or a number, got {w:?}")
        })?,
    }
    Ok(())
}

/// `[sensor]`: size, pitch, the crop within the sensor and the response.
fn validate_sensor(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    check(
        ls,
        s.sensor.width_px > 0 && s.sensor.height_px > 0,
        "sensor.width_px",
        || "sensor size must be positive".into(),
    )?;
    positive(ls, s.sensor.pitch_um, "sensor.pitch_um")?;
    let (cw, ch) = s.sensor.crop_px.size();
    check(
        ls,
        cw > 0 && ch > 0 && cw <= 8192 && ch <= 8192,
        "sensor.crop_px",
        || format!("crop {cw}x{ch} must be 1..=8192 pixels each way"),
    )?;
    let [ox, oy] = s.sensor.crop_offset_px;
    let fits = |crop: u32, off: i32, full: u32| {
        i64::from(crop) + 2 * i64::from(off).abs() <= i64::from(full)
    };
    check(
        ls,
        fits(cw, ox, s.sensor.width_px) && fits(ch, oy, s.sensor.height_px),
        blame(
            ls,
            &[
                "sensor.crop_px",
                "sensor.crop_offset_px",
                "sensor.width_px",
                "sensor.height_px",
            ],
        ),
        || {
            format!(
                "crop {cw}x{ch} offset [{ox}, {oy}] does not fit the {}x{} sensor",
                s.sensor.width_px, s.sensor.height_px
            )
        },
    )?;
    check(
        ls,
        RESPONSE_NAMES.contains(&s.sensor.response.as_str()),
        "sensor.response",
        || {
            format!(
                "unknown response {:?}; expected one of {RESPONSE_NAMES:?}",
                s.sensor.response
            )
        },
    )?;
    Ok(())
}

/// `[display]`: geometry, spectrum, primaries, polarisation, gamma, black level and image.
fn validate_display(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    positive(ls, s.display.distance_mm, "display.distance_mm")?;
    positive(ls, s.display.pixel_pitch_mm, "display.pixel_pitch_mm")?;
    check(
        ls,
        s.display.size_px[0] > 0 && s.display.size_px[1] > 0,
        "display.size_px",
        || "must be positive".into(),
    )?;
    check(
        ls,
        s.display.lcd_pixels_per_image_pixel > 0,
        "display.lcd_pixels_per_image_pixel",
        || "must be positive".into(),
    )?;
    check(
        ls,
        s.display.center_mm.iter().all(|v| v.is_finite()),
        "display.center_mm",
        || "must be finite".into(),
    )?;
    check(
        ls,
        SPECTRUM_NAMES.contains(&s.display.spectrum.as_str()),
        "display.spectrum",
        || {
            format!(
                "unknown spectrum {:?}; expected one of {SPECTRUM_NAMES:?}",
                s.display.spectrum
            )
        },
    )?;
    check(
        ls,
        PRIMARIES_NAMES.contains(&s.display.primaries.as_str()),
        "display.primaries",
        || {
            format!(
                "unknown primaries {:?}; expected one of {PRIMARIES_NAMES:?}",
                s.display.primaries
            )
        },
    )?;
    match &s.display.polarization {
        PolarizationSpec::AngleDeg(a) => check(ls, a.is_finite(), "display.polarization", || {
            "angle must be finite".into()
        })?,
        PolarizationSpec::Word(w) => check(ls, w == "none", "display.polarization", || {
            format!("expected \"none\" or an angle in degrees, got {w:?}")
        })?,
    }
    positive(ls, s.display.gamma, "display.gamma")?;
    check(
        ls,
        s.display.black_level >= 0.0 && s.display.black_level < 1.0,
        "display.black_level",
        || format!("must be in [0, 1), got {}", sig6(s.display.black_level)),
    )?;
    check(ls, s.display.image.trim() != "", "display.image", || {
        "must name a file or a built-in target".into()
    })?;
    Ok(())
}

/// `[sampling]`: the wavelength band, the sampling fractions and the contact limit (`max_depth` is checked last, after `[noise]`).
fn validate_sampling(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    let sm = &s.sampling;
    in_range(
        ls,
        sm.lambda_min_nm,
        200.0,
        2000.0,
        "sampling.lambda_min_nm",
    )?;
    in_range(
        ls,
        sm.lambda_max_nm,
        200.0,
        2000.0,
        "sampling.lambda_max_nm",
    )?;
    check(
        ls,
        sm.lambda_max_nm > sm.lambda_min_nm,
        blame(ls, &["sampling.lambda_max_nm", "sampling.lambda_min_nm"]),
        || "sampling.lambda_max_nm must exceed sampling.lambda_min_nm".into(),
    )?;
    check(
        ls,
        sm.uniform_fraction > 0.0 && sm.uniform_fraction <= 1.0,
        "sampling.uniform_fraction",
        || format!("must be in (0, 1], got {}", sig6(sm.uniform_fraction)),
    )?;
    check(
        ls,
        sm.min_guided_weight > 0.0 && sm.min_guided_weight < 1.0,
        "sampling.min_guided_weight",
        || format!("must be in (0, 1), got {}", sig6(sm.min_guided_weight)),
    )?;
    check(ls, sm.max_contacts >= 1, "sampling.max_contacts", || {
        "must be at least 1".into()
    })?;
    Ok(())
}

/// `[noise]`: full well, exposure, read noise, bit depth and the dark offset within the ADC range.
fn validate_noise(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    let nz = &s.noise;
    positive(ls, nz.full_well_e, "noise.full_well_e")?;
    check(
        ls,
        nz.exposure_fraction > 0.0 && nz.exposure_fraction <= 1.0,
        "noise.exposure_fraction",
        || format!("must be in (0, 1], got {}", sig6(nz.exposure_fraction)),
    )?;
    in_range(ls, nz.read_noise_e, 0.0, 1e6, "noise.read_noise_e")?;
    check(
        ls,
        (1..=24).contains(&nz.bit_depth),
        "noise.bit_depth",
        || format!("must be in [1, 24], got {}", nz.bit_depth),
    )?;
    let full_scale = f64::from((1u32 << nz.bit_depth) - 1);
    check(
        ls,
        nz.dark_offset_dn.is_finite() && nz.dark_offset_dn >= 0.0 && nz.dark_offset_dn < full_scale,
        blame(ls, &["noise.dark_offset_dn", "noise.bit_depth"]),
        || {
            format!(
                "noise.dark_offset_dn must be in [0, {full_scale}) (the ADC range of noise.bit_depth = {}), got {}",
                nz.bit_depth,
                sig6(nz.dark_offset_dn)
            )
        },
    )?;
    Ok(())
}

/// Checks `[hoe]`: the film, and each grating with its key named (`hoe.index_modulation`, or
/// `hoe.grating[1].index_modulation` in a list).
fn validate_hoe(ls: &LoadedScene) -> Result<(), SceneError> {
    let h = &ls.scene.hoe;
    if h.grating.is_empty() {
        for k in SINGLE_GRATING_KEYS {
            let given = match *k {
                "recording_wavelength_nm" => h.recording_wavelength_nm,
                "reference_angle_deg" => h.reference_angle_deg,
                _ => h.index_modulation,
            };
            check(ls, given.is_some(), &format!("hoe.{k}"), || {
                "missing: give it, or list [[hoe.grating]] entries".into()
            })?;
        }
    }
    check(ls, h.grating.len() <= MAX_GRATINGS, "hoe.grating", || {
        format!(
            "{} gratings; a film holds at most {MAX_GRATINGS}",
            h.grating.len()
        )
    })?;
    positive(ls, h.film_thickness_um, "hoe.film_thickness_um")?;
    in_range(ls, h.mean_index, 1.0, 4.0, "hoe.mean_index")?;
    let mut total_n1 = 0.0;
    for (i, g) in h.gratings().iter().enumerate() {
        let key = |f: &str| h.key_of(i, f);
        in_range(
            ls,
            g.recording_wavelength_nm,
            200.0,
            2000.0,
            &key("recording_wavelength_nm"),
        )?;
        let ref_key = key("reference_angle_deg");
        check(
            ls,
            g.reference_angle_deg > 0.0 && g.reference_angle_deg < 90.0,
            &ref_key,
            || {
                format!(
                    "must be in (0, 90) degrees, got {}",
                    sig6(g.reference_angle_deg)
                )
            },
        )?;
        let obj_key = key("object_angle_deg");
        check(
            ls,
            g.object_angle_deg > -90.0 && g.object_angle_deg < 90.0,
            &obj_key,
            || {
                format!(
                    "must be in (-90, 90) degrees, got {}",
                    sig6(g.object_angle_deg)
                )
            },
        )?;
        let n1_key = key("index_modulation");
        check(
            ls,
            g.index_modulation >= 0.0 && g.index_modulation < h.mean_index,
            blame(ls, &[n1_key.as_str(), "hoe.mean_index"]),
            || {
                format!(
                    "{n1_key} must be in [0, hoe.mean_index = {}), got {}",
                    sig6(h.mean_index),
                    sig6(g.index_modulation)
                )
            },
        )?;
        total_n1 += g.index_modulation;
        check(
            ls,
            total_n1 < h.mean_index,
            blame(ls, &[n1_key.as_str(), "hoe.mean_index"]),
            || {
                format!(
                    "the gratings' index modulations add up to {} (up to {n1_key}), which must stay below hoe.mean_index = {}",
                    sig6(total_n1),
                    sig6(h.mean_index)
                )
            },
        )?;
    }
    in_range(
        ls,
        h.amplitude_absorption_per_mm,
        0.0,
        1e4,
        "hoe.amplitude_absorption_per_mm",
    )?;
    validate_fabrication(ls)
}

/// Checks the fabrication keys of `[hoe]` and of each grating: ranges, and that the film as
/// fabricated is a film (positive thickness, index in [1, 4], the modulations below it).
fn validate_fabrication(ls: &LoadedScene) -> Result<(), SceneError> {
    let h = &ls.scene.hoe;
    in_range(ls, h.shrinkage, -0.5, 0.5, "hoe.shrinkage")?;
    in_range(ls, h.mean_index_change, -0.5, 0.5, "hoe.mean_index_change")?;
    check(
        ls,
        h.thickness_error_um.is_finite() && h.film_thickness_um + h.thickness_error_um > 0.0,
        blame(ls, &["hoe.thickness_error_um", "hoe.film_thickness_um"]),
        || {
            format!(
                "hoe.film_thickness_um + hoe.thickness_error_um must be positive, got {} + {}",
                sig6(h.film_thickness_um),
                sig6(h.thickness_error_um)
            )
        },
    )?;
    in_range(
        ls,
        h.temperature_change_k,
        -200.0,
        200.0,
        "hoe.temperature_change_k",
    )?;
    for (v, key) in [
        (h.film_expansion_per_k, "hoe.film_expansion_per_k"),
        (h.substrate_expansion_per_k, "hoe.substrate_expansion_per_k"),
        (h.index_change_per_k, "hoe.index_change_per_k"),
    ] {
        in_range(ls, v, -1e-3, 1e-3, key)?;
    }
    let n_eff = h.mean_index + h.mean_index_change + h.index_change_per_k * h.temperature_change_k;
    check(
        ls,
        (1.0..=4.0).contains(&n_eff),
        blame(
            ls,
            &[
                "hoe.mean_index_change",
                "hoe.temperature_change_k",
                "hoe.mean_index",
            ],
        ),
        || {
            format!(
                "the fabricated mean index hoe.mean_index + hoe.mean_index_change + hoe.index_change_per_k * hoe.temperature_change_k = {} must be in [1, 4]",
                sig6(n_eff)
            )
        },
    )?;
    let mut total = 0.0;
    for (i, g) in h.gratings().iter().enumerate() {
        let key = |f: &str| h.key_of(i, f);
        in_range(
            ls,
            g.index_modulation_shortfall,
            -1.0,
            1.0,
            &key("index_modulation_shortfall"),
        )?;
        let err_key = key("reference_angle_error_deg");
        let theta = g.reference_angle_deg + g.reference_angle_error_deg;
        check(
            ls,
            g.reference_angle_error_deg.is_finite() && theta > 0.0 && theta < 90.0,
            &err_key,
            || {
                format!(
                    "the recorded reference angle {} + {} must be in (0, 90) degrees",
                    sig6(g.reference_angle_deg),
                    sig6(g.reference_angle_error_deg)
                )
            },
        )?;
        total += g.index_modulation * (1.0 - g.index_modulation_shortfall);
    }
    check(
        ls,
        total < n_eff,
        blame(
            ls,
            &["hoe.mean_index_change", "hoe.index_modulation_shortfall"],
        ),
        || {
            format!(
                "the fabricated index modulations add up to {}, which must stay below the fabricated mean index {}",
                sig6(total),
                sig6(n_eff)
            )
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_scene_loads_and_has_paper_values() {
        let ls = load_scene(None, &[]).unwrap();
        let s = &ls.scene;
        assert_eq!(s.plate.thickness_mm, 2.0);
        assert_eq!(s.hoe.reference_angle_deg, Some(61.2));
        assert_eq!(s.hoe.gratings().len(), 1);
        assert_eq!(s.bottom_hoe.height_mm, 50.0);
        assert_eq!(s.sensor.crop_px.size(), (440, 440));
        assert_eq!(s.display.distance_mm, 550.0);
        assert!(s.display.enabled);
        assert_eq!(s.sampling.max_depth, DEFAULT_MAX_DEPTH);
        // Display-only scenes serialise without the 3-D keys (their outputs keep their bytes)
        // and read back equal.
        let json = serde_json::to_string(s).unwrap();
        assert!(
            !json.contains("enabled") && !json.contains("max_depth") && !json.contains("object")
        );
        let back: Scene = serde_json::from_str(&json).unwrap();
        assert_eq!(&back, s);
    }

    #[test]
    fn overrides_change_values_and_types() {
        let ls = load_scene(
            None,
            &[
                "plate.glass=1.5".into(),
                "plate.thickness_mm=3".into(),
                "sensor.crop_px=64".into(),
                "display.image=checker:8".into(),
            ],
        )
        .unwrap();
        assert_eq!(ls.scene.plate.glass, GlassSpec::Index(1.5));
        assert_eq!(ls.scene.plate.thickness_mm, 3.0);
        assert_eq!(ls.scene.sensor.crop_px.size(), (64, 64));
        assert_eq!(ls.scene.display.image, "checker:8");
    }

    /// Fabrication keys: out-of-range values name their key; a one-entry `[[hoe.grating]]`
    /// list keeps its per-grating errors in the single-grating form; a list refuses the
    /// single-grating form's per-grating keys.
    #[test]
    fn fabrication_keys_are_checked() {
        for (set, want) in [
            (
                "hoe.shrinkage=0.6",
                "--set hoe.shrinkage: hoe.shrinkage: must be in [-0.5, 0.5]",
            ),
            (
                "hoe.thickness_error_um=-16",
                "hoe.thickness_error_um: hoe.film_thickness_um + hoe.thickness_error_um must be positive",
            ),
            (
                "hoe.reference_angle_error_deg=30",
                "hoe.reference_angle_error_deg: the recorded reference angle 61.2 + 30",
            ),
            (
                "hoe.index_modulation_shortfall=1.5",
                "hoe.index_modulation_shortfall: must be in [-1, 1]",
            ),
            (
                "hoe.temperature_change_k=1e4",
                "hoe.temperature_change_k: must be in [-200, 200]",
            ),
        ] {
            let e = load_scene(None, &[set.into()]).unwrap_err().to_string();
            assert!(e.contains(want), "{set}: {e}");
        }
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.toml");
        std::fs::write(
            &p,
            "[[hoe.grating]]\nrecording_wavelength_nm = 532.0\nreference_angle_deg = 61.2\n\
             index_modulation = 0.015\nindex_modulation_shortfall = 0.2\n",
        )
        .unwrap();
        let h = load_scene(Some(&p), &[]).unwrap().scene.hoe;
        assert!(h.grating.is_empty());
        assert_eq!(h.index_modulation_shortfall, 0.2);
        assert_eq!(h.gratings()[0].index_modulation_shortfall, 0.2);
        let e = load_scene(Some(&p), &["hoe.reference_angle_error_deg=0.1".into()])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("set hoe.grating.N.reference_angle_error_deg"),
            "{e}"
        );
    }

    #[test]
    fn errors_name_source_and_key() {
        let e = load_scene(None, &["plate.nope=1".into()])
            .unwrap_err()
            .to_string();
        assert_eq!(e, "--set plate.nope: plate.nope: unknown key");
        let e = load_scene(None, &["plate.thickness_mm=-1".into()])
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("--set plate.thickness_mm: plate.thickness_mm: must be a positive"),
            "{e}"
        );
        let e = load_scene(None, &["plate.thickness_mm=thick".into()])
            .unwrap_err()
            .to_string();
        assert!(e.contains("plate.thickness_mm"), "{e}");
        let e = load_scene(None, &["plate.glass=flint".into()])
            .unwrap_err()
            .to_string();
        assert!(e.contains("plate.glass: unknown glass"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.toml");
        std::fs::write(&p, "[plate]\nthickness_mm = 1.0\n[hoe]\ncolour = 3\n").unwrap();
        let e = load_scene(Some(&p), &[]).unwrap_err().to_string();
        assert_eq!(e, format!("{}: hoe.colour: unknown key", p.display()));
        std::fs::write(&p, "[plate\nthickness_mm = 1.0\n").unwrap();
        let e = load_scene(Some(&p), &[]).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!("{}: line 1, column", p.display()))
                && e.contains("malformed TOML"),
            "{e}"
        );
        std::fs::write(&p, "[plate]\nthickness_mm = 1.5\n").unwrap();
        let ls = load_scene(Some(&p), &[]).unwrap();
        assert_eq!(ls.scene.plate.thickness_mm, 1.5);
        assert_eq!(ls.scene.hoe.film_thickness_um, 16.0);
    }
}
