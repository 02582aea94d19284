//! The scene description: one serde struct per section (pure data, units in every name), and
//! the loaded scene, which knows the origin of each key for messages.

use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::path::PathBuf;

use crate::error::SceneError;

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
    /// The plate's edges as the stray-light tracer sees them: `"absorbing"` or `"polished"`
    /// (specular, Fresnel or total reflection). The designed-path tracer never reaches them.
    /// Left out of serialised scenes at its default, as are the two keys below.
    #[serde(default = "default_edges", skip_serializing_if = "is_default_edges")]
    pub edges: String,
    /// The plate's size [width, height], mm.
    #[serde(
        default = "default_plate_size",
        skip_serializing_if = "is_default_plate_size"
    )]
    pub size_mm: [f64; 2],
    /// The plate's centre [x, y], mm.
    #[serde(
        default = "default_plate_center",
        skip_serializing_if = "is_default_plate_center"
    )]
    pub center_mm: [f64; 2],
}

/// Default of `plate.edges`.
pub const DEFAULT_EDGES: &str = "absorbing";
/// Default of `plate.size_mm` (ASSUMED: the paper does not give the plate's size).
pub const DEFAULT_PLATE_SIZE_MM: [f64; 2] = [100.0, 120.0];
/// Default of `plate.center_mm` (ASSUMED: the films' span centred).
pub const DEFAULT_PLATE_CENTER_MM: [f64; 2] = [0.0, 10.0];

fn default_edges() -> String {
    DEFAULT_EDGES.into()
}

fn is_default_edges(v: &String) -> bool {
    v == DEFAULT_EDGES
}

fn default_plate_size() -> [f64; 2] {
    DEFAULT_PLATE_SIZE_MM
}

fn is_default_plate_size(v: &[f64; 2]) -> bool {
    *v == DEFAULT_PLATE_SIZE_MM
}

fn default_plate_center() -> [f64; 2] {
    DEFAULT_PLATE_CENTER_MM
}

fn is_default_plate_center(v: &[f64; 2]) -> bool {
    *v == DEFAULT_PLATE_CENTER_MM
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
    /// Film haze: the fraction of the light crossing the film undiffracted that the film
    /// scatters into a Henyey–Greenstein lobe (only `stscam stray` traces it). 0 = clear.
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub haze_fraction: f64,
    /// Asymmetry g of the haze lobe (mean cosine of the scattering angle).
    #[serde(
        default = "default_haze_asymmetry",
        skip_serializing_if = "is_default_haze_asymmetry"
    )]
    pub haze_asymmetry: f64,
}

/// Default of `hoe.haze_asymmetry` (ASSUMPTION: a forward-peaked lobe, typical of polymer
/// film haze; no datasheet value for Bayfol HX).
pub const DEFAULT_HAZE_ASYMMETRY: f64 = 0.9;

fn default_haze_asymmetry() -> f64 {
    DEFAULT_HAZE_ASYMMETRY
}

fn is_default_haze_asymmetry(v: &f64) -> bool {
    *v == DEFAULT_HAZE_ASYMMETRY
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

    /// True if a fabrication key differs from the design (the film's shrinkage, mean-index
    /// change, thickness error or temperature change, or a grating's shortfall or angle
    /// error): the film traced then differs from the one designed.
    pub fn is_fabricated(&self) -> bool {
        let gs: Vec<_> = self.gratings().iter().map(GratingDesc::recording).collect();
        crate::optics::fabrication::is_fabricated(&self.fabrication(), &gs)
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
pub(crate) fn single_form_keys() -> impl Iterator<Item = &'static str> {
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

/// `[behind_display]`: the display behind the screen in the eye-contact application (on the
/// camera side, facing the user through the plate). Only the stray-light tracer sees it
/// (`stscam stray`): it is a uniform Lambertian emitter with the front display's backlight
/// spectrum and polarisation. Left out of serialised scenes while disabled, so every other
/// output keeps its bytes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BehindDisplayDesc {
    /// Whether it is there.
    pub enabled: bool,
    /// Distance of its emitting plane behind the back face, mm.
    pub distance_mm: f64,
    /// Centre of its emitting area on its plane, mm [x, y].
    pub center_mm: [f64; 2],
    /// Size of its emitting area, mm [width, height].
    pub size_mm: [f64; 2],
    /// Radiance relative to the front display's white (1 = the same white).
    pub luminance: f64,
}

impl Default for BehindDisplayDesc {
    fn default() -> Self {
        BehindDisplayDesc {
            enabled: false,
            distance_mm: 10.0,
            center_mm: [0.0, 0.0],
            size_mm: [50.0, 50.0],
            luminance: 1.0,
        }
    }
}

impl BehindDisplayDesc {
    fn is_off(&self) -> bool {
        *self == BehindDisplayDesc::default()
    }
}

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
    /// The display behind the screen (stray light only).
    #[serde(default, skip_serializing_if = "BehindDisplayDesc::is_off")]
    pub behind_display: BehindDisplayDesc,
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
pub(crate) fn is_overridden(overridden: &BTreeSet<String>, key: &str) -> bool {
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
pub(crate) fn blame<'a>(ls: &LoadedScene, keys: &[&'a str]) -> &'a str {
    keys.iter()
        .copied()
        .find(|k| is_overridden(&ls.overridden, k))
        .unwrap_or(keys[0])
}
