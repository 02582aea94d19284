//! Design sweeps: for every point of a grid of scene-key values (`--vary KEY=START:STOP:STEPS`,
//! Cartesian product, first axis slowest), the design figures an optical engineer needs before
//! fabrication (docs/design.md, user 2): throughput-based field of view and what limits it, replica
//! count and pitch, display-to-sensor light efficiency, the Bragg colour band across the
//! capture, and optionally the ADMM-TV reconstruction PSNR of a standard target.
//!
//! # Model and definitions
//! Every grid point is `load_scene(scene, base_overrides + ["KEY=value", ...])` followed by
//! `System::build`; all points are loaded and built (validated) before anything expensive runs.
//!
//! - **Field response T(d)** of a chief ray leaving the lens centre along the unit direction d:
//!   the fraction of the display's light that reaches the camera *through the waveguide*,
//!
//!   T(d) = ∫ S(λ)·R̄(λ)·W(d, λ) dλ / ∫_band S(λ)·R̄(λ) dλ,
//!
//!   with W(d, λ) = Σ_replicas (f_TE·W_TE + f_TM·W_TM) the branch weights of
//!   `trace::trace_camera_path` summed over every out-coupled branch (all replicas; the
//!   straight-through branch is not light through the waveguide and is excluded), f the
//!   display's polarisation fractions, S the display spectrum, R̄ the mean of the sensor's
//!   channel responses, and the band `sampling.lambda_min_nm..lambda_max_nm`. T is a pure
//!   transmission: Fresnel, Kogelnik efficiencies (both vHOEs, every bounce), TIR and glass
//!   absorption are in W; the lens's cos⁴ falloff and aperture are not. 0 ≤ T ≤ 1.
//!   The numerator is a midpoint sum over λ_B ± `bragg_half_width_nm` (λ_B the exact Bragg
//!   wavelength of d, docs/physics.md §3.2) clipped to the band, in `bragg_step_nm` bins; where no
//!   wavelength is Bragg-matched, over the whole band in `broadband_step_nm` bins. The
//!   denominator uses the same rule over the band. Convergence on the paper's scene: halving
//!   the steps changes T by ≤ 1.4·10⁻⁴ (relative), also where W(λ) jumps (a guided contact
//!   entering the top vHOE within the band); widening the window to ±80 nm adds ≤ 0.12 % (the
//!   Kogelnik side lobes, neglected).
//! - **Throughput FOV** (vertical: d = (0, sin θ, −cos θ); horizontal: d = (sin θ, 0, −cos θ),
//!   θ the field angle in air, as `analysis::info`): T(θ) on a grid of `angle_step_deg` over
//!   ±`angle_max_deg`; the FOV is the contiguous interval where T ≥ `fov_fraction`·max T that
//!   contains 0° (or, if T(0°) is below that, the first grid maximum), its edges interpolated
//!   linearly between grid angles; reported as the full angle and both edges. Each edge names
//!   what limits it, judged at the first grid angle beyond it ("out") against the grid maximum
//!   ("peak"): the geometric blocker of `analysis` at out (top-vHOE aperture, TIR, no contact
//!   in the bottom vHOE, Bragg band outside the spectrum) if there is one; otherwise
//!   T_out/T_peak = s·b is split into the spectral ratio s = S·R̄(λ_B,out)/S·R̄(λ_B,peak) and the
//!   waveguide ratio b, and the larger fall names the limiter: the display spectrum × sensor
//!   response if s < b; else the top vHOE's re-coupling if the guided path at out meets more
//!   front-face contacts under the top vHOE than at peak (each out-couples most of the guided
//!   light, docs/physics.md §5), the bottom vHOE if out has fewer replicas ≥ 5 %, else the
//!   "Bragg/Kogelnik efficiency falloff". Note that T varies strongly across the field in the
//!   paper's scene (white-LED spectrum and the top-vHOE re-coupling steps), so the FOV depends
//!   on `fov_fraction` much more than a geometric FOV would.
//!   The default fraction is 0.1 ([`DEFAULT_FOV_FRACTION`]): at 0.5 the paper's FOV would be an
//!   off-axis 6° window set by the spectrum and the re-coupling steps, not by an aperture.
//! - **Scene field** (what the user sees as the camera's field, and what a taller bottom vHOE
//!   widens): the chief rays of the capture FOV along one axis, traced at their Bragg
//!   wavelengths; the object points (display plane) of their replicas carrying ≥ 5 % of each
//!   ray's strongest; their extent (mm, from the bottom vHOE's centre) and the full angle it
//!   subtends at the bottom vHOE's centre. Each strong replica adds one pitch 2w·tanΘ' of scene
//!   below the first: more field, and more overlapping copies to unmix — the paper's dilemma.
//! - **Capture FOV**: the throughput FOV intersected with the field angles whose chief rays land
//!   inside the sensor crop; "sensor crop" names the edges the crop sets.
//! - **Replicas** (from `analysis::info`, chief ray of the crop's centre pixel at its Bragg
//!   wavelength): bottom-vHOE contacts that out-couple (`replicas_total`) and those carrying at
//!   least 5 % of the strongest (`replicas_above_5pct`); replica pitch on the display
//!   2w·tanΘ' (`replica_pitch_mm`) and the mean spacing on the sensor of the ≥ 5 % replicas of
//!   a point at the display centre (`replica_pitch_sensor_px`, NaN with fewer than two).
//! - **Efficiency**: `efficiency_peak` = the largest T over both field scans;
//!   `efficiency_on_axis` = T(0°); `efficiency_crop_mean` = the mean of T over the chief rays of
//!   a `crop_grid`² grid of points spread evenly over the sensor crop (cell centres).
//! - **Bragg range**: the smallest and largest λ_B over the same crop grid (nm).
//! - **PSNR** (optional, the protocol of `demo`): H by `matrix::compute_matrix` at `spp` and
//!   `seed`; the target (a built-in spec at the scene's display-target size, which must be
//!   square) rendered with seed + 1; the sensor noise model of the scene with the exposure set
//!   from the all-white capture H·1 + o and a noisy dark frame subtracted; ADMM-TV (50
//!   iterations) with τ by the discrepancy principle (`recon::discrepancy`, as the demo's
//!   table); PSNR (peak 1) against the linear target (`recon::metrics`).
//!   With it, `psnr_nominal_h_db`: how fast a calibration goes stale. The same capture (of the
//!   grid point's scene) reconstructed with the H of the *base* scene (no `--vary` values, the
//!   same `spp` and `seed`, computed once): with `--vary display.distance_mm=…` the PSNR at
//!   each true depth with the H of the nominal distance, against `psnr_db` with the H of the
//!   true depth. NaN where the point's capture or object shape differs from the base scene's.
//!
//! Determinism: angles, crop rays and grid points are evaluated independently and collected in
//! order, spectral sums run in wavelength order, and the PSNR pipeline is deterministic per
//! seed, so every output byte is the same for any thread count. Files hold no timings.
//!
//! Sources: docs/physics.md §3.2 (λ_B), §3.4 and §5 (FOV limits, replicas, pitch), §8.4 (PSNR);
//! docs/design.md (sweeps of vHOE size against FOV).

mod figures;
mod metrics;
mod scan;

pub use figures::DEFINITIONS;
pub use metrics::{BAND_ROWS, GEOMETRY_METRICS, geometry_metrics};
pub use scan::{
    SpectralWeight, design_figures, field_response, field_response_of, psnr_demo_settings,
    psnr_figure, psnr_figures, psnr_problem, psnr_target, run_sweep, run_sweep_from, scan_response,
};

use serde::Serialize;

use crate::analysis::Fov;
use crate::scene::SceneError;

/// Limiter named when the field response falls through the threshold although the chief ray
/// still reaches the display, and neither the spectral weight at λ_B nor a change of the guided
/// path explains the fall (in-/out-coupling efficiency, Bragg selectivity).
pub const FALLOFF_LIMITER: &str = "Bragg/Kogelnik efficiency falloff";
/// Limiter named when the spectral weight S·R̄ at λ_B fell more than the waveguide's efficiency
/// (the field's Bragg colour moves out of the display spectrum or the sensor response).
pub const SPECTRUM_LIMITER: &str = "display spectrum x sensor response at the Bragg wavelength";
/// Limiter named when the waveguide's efficiency fell more than the spectral weight and the
/// guided path meets more front-face contacts under the top vHOE than at the maximum (each
/// out-couples most of the guided light toward other camera directions).
pub const TOP_RECOUPLING_LIMITER: &str = "top vHOE re-coupling (more front-face contacts under it)";
/// Limiter named when the waveguide's efficiency fell more than the spectral weight and the
/// chief ray has fewer strong replicas (bottom-vHOE contacts) than at the maximum.
pub const BOTTOM_CONTACT_LIMITER: &str = "bottom vHOE (fewer strong contacts)";
/// Limiter named for a capture-FOV edge set by the sensor crop.
pub const CROP_LIMITER: &str = "sensor crop";
/// Limiter named when the response stays above the threshold up to the end of the scan.
pub const SCAN_LIMITER: &str = "end of the angle scan";
/// Default throughput fraction of the FOV. T varies by more than 2× across the paper's field
/// for reasons other than its edges (the white-LED spectrum times the sensor response at each
/// field's Bragg colour; the top vHOE re-coupling steps), so a half-maximum FOV would be an
/// off-axis 6° window; at 10 % the FOV is within 1.5° of the geometric one.
pub const DEFAULT_FOV_FRACTION: f64 = 0.1;
/// Fraction of the strongest replica above which a replica counts (as `analysis::info`).
pub const REPLICA_FRACTION: f64 = 0.05;
/// Largest number of grid points per axis.
pub const MAX_STEPS: usize = 10_000;
/// Largest number of grid points of a sweep.
pub const MAX_POINTS: usize = 100_000;

/// A sweep error: one line naming what is wrong (the axis spec, or the key and value of the
/// failing grid point).
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    /// A malformed `--vary` spec.
    #[error("--vary {spec}: {message}")]
    Axis {
        /// The spec as given.
        spec: String,
        /// What is wrong.
        message: String,
    },
    /// The scene with the base overrides alone is invalid.
    #[error("{0}")]
    Scene(#[from] SceneError),
    /// A grid point's scene is invalid.
    #[error("grid point {point}: {source}")]
    GridPoint {
        /// The point's values, `KEY=value, ...`.
        point: String,
        /// The scene error (names the key).
        source: SceneError,
    },
    /// Invalid sweep settings.
    #[error("{0}")]
    Settings(String),
    /// The PSNR set-up failed at a grid point (e.g. a non-square object or a bad target).
    #[error("grid point {point}: {message}")]
    Psnr {
        /// The point's values, `KEY=value, ...`.
        point: String,
        /// What is wrong.
        message: String,
    },
    /// Encoding an output file failed.
    #[error("{0}")]
    Output(String),
}

/// One `--vary KEY=START:STOP:STEPS` axis: `steps` evenly spaced values from `start` to `stop`
/// inclusive (`steps` ≥ 1; `start == stop` exactly when `steps == 1`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct VaryAxis {
    /// Dotted scene key, e.g. `bottom_hoe.height_mm`.
    pub key: String,
    /// First value.
    pub start: f64,
    /// Last value.
    pub stop: f64,
    /// Number of grid points.
    pub steps: usize,
}

impl VaryAxis {
    /// Parses `KEY=START:STOP:STEPS`.
    pub fn parse(spec: &str) -> Result<VaryAxis, SweepError> {
        let err = |message: String| SweepError::Axis {
            spec: spec.to_string(),
            message,
        };
        let Some((key, range)) = spec.split_once('=') else {
            return Err(err("expected KEY=START:STOP:STEPS".into()));
        };
        let key = key.trim();
        if key.is_empty() || key.contains(char::is_whitespace) {
            return Err(err(format!("bad key {key:?}")));
        }
        let parts: Vec<&str> = range.split(':').map(str::trim).collect();
        let [start, stop, steps] = parts[..] else {
            return Err(err(format!(
                "expected START:STOP:STEPS after '=', got {range:?}"
            )));
        };
        let number = |what: &str, s: &str| -> Result<f64, SweepError> {
            match s.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => Err(err(format!("{what} must be a finite number, got {s:?}"))),
            }
        };
        let (start, stop) = (number("START", start)?, number("STOP", stop)?);
        let steps: usize = steps
            .parse()
            .ok()
            .filter(|n| (1..=MAX_STEPS).contains(n))
            .ok_or_else(|| {
                err(format!(
                    "STEPS must be an integer in 1..={MAX_STEPS}, got {steps:?}"
                ))
            })?;
        if steps == 1 && start != stop {
            return Err(err("STEPS = 1 needs START = STOP".into()));
        }
        if steps > 1 && start == stop {
            return Err(err(format!("START = STOP needs STEPS = 1, got {steps}")));
        }
        Ok(VaryAxis {
            key: key.to_string(),
            start,
            stop,
            steps,
        })
    }

    /// The grid values: start + (stop − start)·i/(steps − 1), with both ends exact.
    pub fn values(&self) -> Vec<f64> {
        if self.steps <= 1 {
            return vec![self.start];
        }
        let last = self.steps - 1;
        (0..self.steps)
            .map(|i| match i {
                0 => self.start,
                i if i == last => self.stop,
                // Interior points are rounded to 12 significant digits, so that a grid such
                // as 0.01:0.03:3 gives 0.02 rather than 0.019999999999999997.
                i => {
                    let v = self.start + (self.stop - self.start) * i as f64 / last as f64;
                    format!("{v:.11e}").parse().unwrap_or(v)
                }
            })
            .collect()
    }
}

/// Numerical grids of the field-response figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ResponseGrid {
    /// Field-angle step of the FOV scans, degrees.
    pub angle_step_deg: f64,
    /// The scans cover ±this, degrees.
    pub angle_max_deg: f64,
    /// Half width of the spectral window around λ_B, nm.
    pub bragg_half_width_nm: f64,
    /// Spectral bin width inside that window, nm.
    pub bragg_step_nm: f64,
    /// Spectral bin width over the whole band (no Bragg wavelength, and the normalisation), nm.
    pub broadband_step_nm: f64,
    /// Crop points per side for the crop-mean efficiency and the Bragg range.
    pub crop_grid: usize,
}

impl Default for ResponseGrid {
    fn default() -> Self {
        ResponseGrid {
            angle_step_deg: 0.1,
            angle_max_deg: 60.0,
            bragg_half_width_nm: 40.0,
            bragg_step_nm: 0.1,
            broadband_step_nm: 0.5,
            crop_grid: 21,
        }
    }
}

impl ResponseGrid {
    fn check(&self) -> Result<(), SweepError> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        let good = ok(self.angle_step_deg)
            && ok(self.angle_max_deg)
            && self.angle_max_deg < 90.0
            && self.angle_max_deg / self.angle_step_deg <= 1e6
            && ok(self.bragg_half_width_nm)
            && ok(self.bragg_step_nm)
            && ok(self.broadband_step_nm)
            && (1..=1000).contains(&self.crop_grid);
        if good {
            Ok(())
        } else {
            Err(SweepError::Settings(format!(
                "invalid response grid {self:?}: steps and widths must be positive, the scan below 90°, the crop grid 1..=1000"
            )))
        }
    }
}

/// Settings of the optional PSNR figure.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct PsnrSettings {
    /// Built-in target spec without `@SIZE` (the size is the scene's display target size).
    pub target: String,
    /// Samples per pixel for H and the capture.
    pub spp: u32,
    /// Seed of H and of the noise; the capture uses seed + 1.
    pub seed: u64,
}

impl Default for PsnrSettings {
    fn default() -> Self {
        PsnrSettings {
            target: "letter:A".into(),
            spp: 64,
            seed: 1,
        }
    }
}

/// Settings of a sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepSettings {
    /// The FOV is where T ≥ this fraction of its maximum (default [`DEFAULT_FOV_FRACTION`]).
    pub fov_fraction: f64,
    /// Compute the PSNR figure (`None` = skip).
    pub psnr: Option<PsnrSettings>,
    /// Show progress on a terminal.
    pub progress: bool,
    /// Numerical grids.
    pub grid: ResponseGrid,
}

impl Default for SweepSettings {
    fn default() -> Self {
        SweepSettings {
            fov_fraction: DEFAULT_FOV_FRACTION,
            psnr: None,
            progress: false,
            grid: ResponseGrid::default(),
        }
    }
}

/// One varied key and its value at a grid point.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct VariedValue {
    /// Dotted scene key.
    pub key: String,
    /// Value.
    pub value: f64,
}

/// The design figures of one system (definitions in the module header).
#[derive(Clone, Debug, Serialize)]
pub struct DesignFigures {
    /// Throughput FOV, vertical (field angles in air, degrees).
    pub fov_vertical: Fov,
    /// Throughput FOV, horizontal.
    pub fov_horizontal: Fov,
    /// Vertical throughput FOV within the sensor crop.
    pub fov_vertical_capture: Fov,
    /// Horizontal throughput FOV within the sensor crop.
    pub fov_horizontal_capture: Fov,
    /// Geometric vertical FOV of the waveguide (`analysis::info`), degrees.
    pub geometric_fov_vertical_deg: f64,
    /// Geometric horizontal FOV of the waveguide (`analysis::info`), degrees.
    pub geometric_fov_horizontal_deg: f64,
    /// Part of the display plane the capture sees through its strong replicas, vertically.
    pub scene_field_vertical: SceneField,
    /// The same horizontally.
    pub scene_field_horizontal: SceneField,
    /// Replicas of the centre field carrying ≥ 5 % of the strongest.
    pub replicas_above_5pct: usize,
    /// All replicas (bottom-vHOE contacts) of the centre field.
    pub replicas_total: usize,
    /// Replica pitch on the display, 2w·tanΘ' of the centre field, mm.
    pub replica_pitch_mm: f64,
    /// Replica pitch on the sensor, pixels.
    pub replica_pitch_sensor_px: f64,
    /// Largest T over both field scans (fraction).
    pub efficiency_peak: f64,
    /// T on axis (fraction).
    pub efficiency_on_axis: f64,
    /// Mean T over the crop grid's chief rays (fraction).
    pub efficiency_crop_mean: f64,
    /// Smallest Bragg wavelength over the crop grid, nm.
    pub bragg_min_nm: f64,
    /// Largest Bragg wavelength over the crop grid, nm.
    pub bragg_max_nm: f64,
    /// A multiplexed film: Bragg range and efficiency of each grating (empty for one grating;
    /// the fields above are then the first grating's Bragg range and the whole film's
    /// efficiency).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub per_grating: Vec<GratingFigures>,
    /// ADMM-TV PSNR of the target, dB (when computed).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psnr_db: Option<f64>,
    /// The same capture reconstructed with the base scene's H (module header), dB.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psnr_nominal_h_db: Option<f64>,
}

/// The part of the display (object) plane that the capture sees through its strong replicas,
/// along one axis (module header: "scene field").
#[derive(Clone, Debug, Serialize)]
pub struct SceneField {
    /// Lowest (bottom or left) object coordinate seen, mm from the bottom vHOE's centre.
    pub min_mm: f64,
    /// Highest (top or right) object coordinate seen, mm.
    pub max_mm: f64,
    /// max − min, mm.
    pub extent_mm: f64,
    /// Full angle it subtends at the bottom vHOE's centre, degrees.
    pub full_deg: f64,
}

/// One grid point: the varied values and the figures.
#[derive(Clone, Debug, Serialize)]
pub struct SweepRow {
    /// Varied keys and values, in axis order.
    pub varied: Vec<VariedValue>,
    /// The figures.
    #[serde(flatten)]
    pub figures: DesignFigures,
}

/// What a sweep produced, in memory.
#[derive(Clone, Debug)]
pub struct SweepOutput {
    /// One row per grid point, in grid order (first axis slowest).
    pub rows: Vec<SweepRow>,
    /// Files to write (flat names): `sweep.csv`, `sweep.json`, and `<quantity>.png` + `.svg`.
    pub files: Vec<(String, Vec<u8>)>,
    /// Wall time of each grid point's figures, seconds (not in the files).
    pub point_seconds: Vec<f64>,
}

/// One grating's figures at a sweep point (multiplexed films; CSV columns `*_gJ`).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct GratingFigures {
    /// Grating index in the film's list.
    pub grating: u32,
    /// Smallest Bragg wavelength of this grating over the crop grid, nm.
    pub bragg_min_nm: f64,
    /// Largest, nm.
    pub bragg_max_nm: f64,
    /// T on axis through this grating's replicas alone (fraction).
    pub efficiency_on_axis: f64,
    /// Mean T over the crop grid's chief rays through this grating alone (fraction).
    pub efficiency_crop_mean: f64,
}
