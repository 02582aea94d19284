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

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use glam::{DVec2, DVec3};
use rayon::prelude::*;
use serde::Serialize;

use crate::analysis::{self, Fov, FovEdge, crop_field_range_deg, field_blocker, field_direction};
use crate::plot::{LinePlot, Series};
use crate::scene::{SceneError, SceneSource};
use crate::system::System;
use crate::trace::{BranchKind, trace_camera_path};

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

/// The scene field along one axis: the chief rays of the capture FOV `capture` along that axis
/// (`step_deg` apart) traced at their Bragg wavelengths, and the object points of their
/// replicas carrying at least [`REPLICA_FRACTION`] of each ray's strongest.
fn scene_field(sys: &System, vertical: bool, capture: &Fov, step_deg: f64) -> SceneField {
    let nan = SceneField {
        min_mm: f64::NAN,
        max_mm: f64::NAN,
        extent_mm: f64::NAN,
        full_deg: f64::NAN,
    };
    let (lo, hi) = (capture.min.angle_deg, capture.max.angle_deg);
    if !(lo.is_finite() && hi.is_finite() && hi >= lo) {
        return nan;
    }
    let n = (((hi - lo) / step_deg).ceil() as usize).max(1);
    let axis = usize::from(vertical);
    let spans: Vec<(f64, f64)> = (0..=n)
        .into_par_iter()
        .filter_map(|k| {
            let a = lo + (hi - lo) * k as f64 / n as f64;
            let p = analysis::probe_direction(
                sys,
                sys.camera.lens_center_mm,
                field_direction(a, vertical),
                [0, 0],
            )?;
            let strongest = p.replicas.iter().map(|r| r.weight).fold(0.0, f64::max);
            p.replicas
                .iter()
                .filter(|r| strongest > 0.0 && r.weight >= REPLICA_FRACTION * strongest)
                .map(|r| r.object_point_mm[axis])
                .fold(None, |acc: Option<(f64, f64)>, y| {
                    Some(acc.map_or((y, y), |(a, b)| (a.min(y), b.max(y))))
                })
        })
        .collect();
    if spans.is_empty() {
        return nan;
    }
    let min_mm = spans.iter().map(|s| s.0).fold(f64::INFINITY, f64::min);
    let max_mm = spans.iter().map(|s| s.1).fold(f64::NEG_INFINITY, f64::max);
    let d = -sys.display.z_mm;
    SceneField {
        min_mm,
        max_mm,
        extent_mm: max_mm - min_mm,
        full_deg: ((max_mm / d).atan() - (min_mm / d).atan()).to_degrees(),
    }
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

/// Display spectrum × mean sensor response and its integral over the scene's band.
#[derive(Clone, Debug)]
pub struct SpectralWeight {
    lo_nm: f64,
    hi_nm: f64,
    spectrum: crate::spectra::Spectrum,
    response: Vec<crate::spectra::Spectrum>,
    /// ∫_band S·R̄ dλ (midpoint rule, `broadband_step_nm` bins).
    norm: f64,
}

/// Midpoint-rule bins of width ≤ `step` exactly covering [lo, hi]: (centre, width) pairs.
fn bins(lo: f64, hi: f64, step: f64) -> impl Iterator<Item = (f64, f64)> {
    let n = if hi > lo {
        ((hi - lo) / step).ceil() as usize
    } else {
        0
    };
    (0..n).map(move |i| {
        let a = lo + i as f64 * step;
        let b = (a + step).min(hi);
        (0.5 * (a + b), b - a)
    })
}

impl SpectralWeight {
    /// The weight S(λ)·R̄(λ) of `sys`, normalised over its band with `grid.broadband_step_nm`.
    pub fn new(sys: &System, grid: &ResponseGrid) -> SpectralWeight {
        let mut w = SpectralWeight {
            lo_nm: sys.scene.sampling.lambda_min_nm,
            hi_nm: sys.scene.sampling.lambda_max_nm,
            spectrum: sys.display.spectrum.clone(),
            response: sys.response.curves.clone(),
            norm: 0.0,
        };
        w.norm = bins(w.lo_nm, w.hi_nm, grid.broadband_step_nm)
            .map(|(l, dl)| w.at(l) * dl)
            .sum();
        w
    }

    /// S(λ)·R̄(λ) (R̄ the mean over the sensor channels).
    pub fn at(&self, lambda_nm: f64) -> f64 {
        let r: f64 = self.response.iter().map(|c| c.eval(lambda_nm)).sum::<f64>()
            / self.response.len().max(1) as f64;
        self.spectrum.eval(lambda_nm) * r
    }

    /// ∫_band S·R̄ dλ.
    pub fn norm(&self) -> f64 {
        self.norm
    }
}

/// Field response T of the chief ray leaving the lens centre along `dir` (module header).
pub fn field_response(
    sys: &System,
    weight: &SpectralWeight,
    grid: &ResponseGrid,
    dir: DVec3,
) -> f64 {
    field_response_of(sys, weight, grid, dir, None)
}

/// [`field_response`] through grating `only` of the film (its replicas, integrated around its
/// Bragg wavelength), or through all of them (`None`: the sum over gratings, each around its
/// own Bragg wavelength).
pub fn field_response_of(
    sys: &System,
    weight: &SpectralWeight,
    grid: &ResponseGrid,
    dir: DVec3,
    only: Option<usize>,
) -> f64 {
    if weight.norm <= 0.0 {
        return 0.0;
    }
    let wg = &sys.waveguide;
    let origin = sys.camera.lens_center_mm;
    let pol = sys.display.polarization_weights;
    let mut sum = 0.0;
    for (j, grating) in wg.gratings.as_slice().iter().enumerate() {
        if only.is_some_and(|o| o != j) {
            continue;
        }
        let (lo, hi, step) = match grating.bragg_wavelength_nm(-dir.truncate()) {
            Some(lb) => (
                (lb - grid.bragg_half_width_nm).max(weight.lo_nm),
                (lb + grid.bragg_half_width_nm).min(weight.hi_nm),
                grid.bragg_step_nm,
            ),
            None => (weight.lo_nm, weight.hi_nm, grid.broadband_step_nm),
        };
        for (lambda, dl) in bins(lo, hi, step) {
            let sr = weight.at(lambda);
            if sr <= 0.0 {
                continue;
            }
            let mut w = 0.0;
            trace_camera_path(wg, sys.display.z_mm, sys.limits, origin, dir, lambda, |b| {
                if matches!(b.kind, BranchKind::Replica(_)) && b.grating as usize == j {
                    w += pol[0] * b.weight[0] + pol[1] * b.weight[1];
                }
            });
            sum += sr * w * dl;
        }
    }
    sum / weight.norm
}

/// T(θ) on the scan grid along one axis (vertical or horizontal): (angles in degrees, T).
pub fn scan_response(
    sys: &System,
    weight: &SpectralWeight,
    grid: &ResponseGrid,
    vertical: bool,
) -> (Vec<f64>, Vec<f64>) {
    let n = (grid.angle_max_deg / grid.angle_step_deg).floor() as i64;
    let angles: Vec<f64> = (-n..=n).map(|k| k as f64 * grid.angle_step_deg).collect();
    let t: Vec<f64> = angles
        .par_iter()
        .map(|&a| field_response(sys, weight, grid, field_direction(a, vertical)))
        .collect();
    (angles, t)
}

/// One side of a threshold interval: the edge angle and the first grid index beyond it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Side {
    edge_deg: f64,
    /// Index of the first grid angle below the threshold (`None`: the scan ended first).
    out: Option<usize>,
}

/// The contiguous interval of `angles` where `t` ≥ `fraction`·max t containing 0° (or the first
/// maximum if T(0°) is below it), with linearly interpolated edges. `None` if T is 0 everywhere.
fn threshold_interval(angles: &[f64], t: &[f64], fraction: f64) -> Option<(Side, Side)> {
    let max = t.iter().copied().fold(0.0, f64::max);
    if max <= 0.0 || t.is_empty() {
        return None;
    }
    let thr = fraction * max;
    let zero = angles
        .iter()
        .position(|&a| a == 0.0)
        .unwrap_or(angles.len() / 2);
    let anchor = if t[zero] >= thr {
        zero
    } else {
        t.iter().position(|&v| v == max).unwrap_or(zero)
    };
    let side = |step: isize| -> Side {
        let mut i = anchor;
        loop {
            let next = i as isize + step;
            if next < 0 || next >= t.len() as isize {
                return Side {
                    edge_deg: angles[i],
                    out: None,
                };
            }
            let j = next as usize;
            if t[j] < thr {
                let f = (t[i] - thr) / (t[i] - t[j]);
                return Side {
                    edge_deg: angles[i] + (angles[j] - angles[i]) * f,
                    out: Some(j),
                };
            }
            i = j;
        }
    };
    Some((side(-1), side(1)))
}

/// (front-face contacts under the top vHOE, replicas carrying ≥ `REPLICA_FRACTION` of the
/// strongest) of the chief ray along `dir` at its Bragg wavelength.
fn path_counts(sys: &System, dir: DVec3) -> (u32, usize) {
    // The first grating with a Bragg wavelength for the ray (the only one in most films).
    let Some(lambda) = sys
        .waveguide
        .gratings
        .bragg_wavelengths_nm(-dir.truncate())
        .into_iter()
        .flatten()
        .next()
    else {
        return (0, 0);
    };
    let pol = sys.display.polarization_weights;
    let mut weights = Vec::new();
    let summary = trace_camera_path(
        &sys.waveguide,
        sys.display.z_mm,
        sys.limits,
        sys.camera.lens_center_mm,
        dir,
        lambda,
        |b| {
            if matches!(b.kind, BranchKind::Replica(_)) {
                weights.push(pol[0] * b.weight[0] + pol[1] * b.weight[1]);
            }
        },
    );
    let max = weights.iter().copied().fold(0.0, f64::max);
    let strong = weights
        .iter()
        .filter(|&&w| max > 0.0 && w >= REPLICA_FRACTION * max)
        .count();
    (summary.top_contacts, strong)
}

/// What stops the field response at grid index `out` (the first below the threshold), given
/// the grid maximum at `peak`: the geometric blocker of `analysis` at `out` if there is one;
/// else T_out/T_peak = s·b is split into the spectral ratio s = S·R̄(λ_B,out)/S·R̄(λ_B,peak) and
/// the waveguide ratio b; if s < b the spectrum limits, otherwise the waveguide: the top vHOE
/// if the guided path has more contacts under it than at the peak, the bottom vHOE if the
/// chief ray has fewer strong replicas, else the Bragg/Kogelnik efficiency.
fn edge_limiter(
    sys: &System,
    weight: &SpectralWeight,
    scan: (&[f64], &[f64], bool),
    out: usize,
    peak: usize,
) -> &'static str {
    let (angles, t, vertical) = scan;
    let dir = |i: usize| field_direction(angles[i], vertical);
    if let Some(why) = field_blocker(sys, dir(out), false) {
        return why;
    }
    let sr = |i: usize| {
        sys.waveguide
            .gratings
            .bragg_wavelengths_nm(-dir(i).truncate())
            .into_iter()
            .flatten()
            .next()
            .map_or(0.0, |l| weight.at(l))
    };
    let (sr_out, sr_peak) = (sr(out), sr(peak));
    // s < b ⇔ s² < s·b = T_out/T_peak.
    if sr_peak > 0.0 && (sr_out / sr_peak).powi(2) < t[out] / t[peak] {
        return SPECTRUM_LIMITER;
    }
    let ((top_peak, strong_peak), (top_out, strong_out)) =
        (path_counts(sys, dir(peak)), path_counts(sys, dir(out)));
    if top_out > top_peak {
        TOP_RECOUPLING_LIMITER
    } else if strong_out < strong_peak {
        BOTTOM_CONTACT_LIMITER
    } else {
        FALLOFF_LIMITER
    }
}

/// The FOV along one axis from its scan, with the limiter of each edge.
fn fov_of_scan(
    sys: &System,
    weight: &SpectralWeight,
    vertical: bool,
    angles: &[f64],
    t: &[f64],
    fraction: f64,
) -> Fov {
    let peak = t
        .iter()
        .enumerate()
        .fold(0, |best, (i, &v)| if v > t[best] { i } else { best });
    let limiter = |side: Side| -> String {
        match side.out {
            None => SCAN_LIMITER.to_string(),
            Some(j) => edge_limiter(sys, weight, (angles, t, vertical), j, peak).to_string(),
        }
    };
    match threshold_interval(angles, t, fraction) {
        Some((lo, hi)) => Fov {
            full_deg: hi.edge_deg - lo.edge_deg,
            min: FovEdge {
                angle_deg: lo.edge_deg,
                limited_by: limiter(lo),
            },
            max: FovEdge {
                angle_deg: hi.edge_deg,
                limited_by: limiter(hi),
            },
        },
        None => {
            let why = field_blocker(sys, field_direction(0.0, vertical), false)
                .unwrap_or(FALLOFF_LIMITER)
                .to_string();
            empty_fov(&why, &why)
        }
    }
}

fn empty_fov(min_why: &str, max_why: &str) -> Fov {
    Fov {
        full_deg: 0.0,
        min: FovEdge {
            angle_deg: f64::NAN,
            limited_by: min_why.to_string(),
        },
        max: FovEdge {
            angle_deg: f64::NAN,
            limited_by: max_why.to_string(),
        },
    }
}

/// `fov` intersected with the crop's field range along the same axis.
fn capture_fov(fov: &Fov, crop: Option<[f64; 2]>) -> Fov {
    let Some([c_lo, c_hi]) = crop else {
        return empty_fov(CROP_LIMITER, CROP_LIMITER);
    };
    if fov.min.angle_deg.is_nan() || fov.max.angle_deg.is_nan() {
        return fov.clone();
    }
    let edge = |own: &FovEdge, crop_deg: f64, crop_binds: bool| {
        if crop_binds {
            FovEdge {
                angle_deg: crop_deg,
                limited_by: CROP_LIMITER.to_string(),
            }
        } else {
            own.clone()
        }
    };
    let min = edge(&fov.min, c_lo, c_lo > fov.min.angle_deg);
    let max = edge(&fov.max, c_hi, c_hi < fov.max.angle_deg);
    if max.angle_deg <= min.angle_deg {
        return empty_fov(&min.limited_by, &max.limited_by);
    }
    Fov {
        full_deg: max.angle_deg - min.angle_deg,
        min,
        max,
    }
}

/// Chief-ray directions of a `n`×`n` grid of cell centres over the sensor crop.
fn crop_grid_directions(sys: &System, n: usize) -> Vec<DVec3> {
    let cam = &sys.camera;
    let size = DVec2::new(cam.width_px as f64, cam.height_px as f64) * cam.pitch_mm;
    let centre = cam.offset_px * cam.pitch_mm;
    (0..n * n)
        .map(|k| {
            let (i, j) = ((k % n) as f64, (k / n) as f64);
            let f = DVec2::new((i + 0.5) / n as f64 - 0.5, 0.5 - (j + 0.5) / n as f64);
            cam.ray_through(centre + f * size, DVec2::ZERO).dir
        })
        .collect()
}

/// All figures of `sys` except the PSNR.
pub fn design_figures(sys: &System, set: &SweepSettings) -> DesignFigures {
    let grid = &set.grid;
    let weight = SpectralWeight::new(sys, grid);
    let (va, vt) = scan_response(sys, &weight, grid, true);
    let (ha, ht) = scan_response(sys, &weight, grid, false);
    let fov_v = fov_of_scan(sys, &weight, true, &va, &vt, set.fov_fraction);
    let fov_h = fov_of_scan(sys, &weight, false, &ha, &ht, set.fov_fraction);
    let crop_dirs = crop_grid_directions(sys, grid.crop_grid);
    let crop_t: Vec<f64> = crop_dirs
        .par_iter()
        .map(|&d| field_response(sys, &weight, grid, d))
        .collect();
    let bragg_range = |j: usize| {
        let lambdas: Vec<f64> = crop_dirs
            .iter()
            .filter_map(|d| {
                sys.waveguide
                    .gratings
                    .get(j)
                    .bragg_wavelength_nm(-d.truncate())
            })
            .collect();
        if lambdas.is_empty() {
            (f64::NAN, f64::NAN)
        } else {
            (
                lambdas.iter().copied().fold(f64::INFINITY, f64::min),
                lambdas.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            )
        }
    };
    // The first grating's Bragg range (the film's only one unless multiplexed).
    let (bragg_min_nm, bragg_max_nm) = bragg_range(0);
    // A multiplexed film: Bragg range and efficiency per grating.
    let n_gratings = sys.waveguide.gratings.len();
    let per_grating: Vec<GratingFigures> = if n_gratings > 1 {
        (0..n_gratings)
            .map(|j| {
                let (lo, hi) = bragg_range(j);
                let crop: Vec<f64> = crop_dirs
                    .par_iter()
                    .map(|&d| field_response_of(sys, &weight, grid, d, Some(j)))
                    .collect();
                GratingFigures {
                    grating: j as u32,
                    bragg_min_nm: lo,
                    bragg_max_nm: hi,
                    efficiency_on_axis: field_response_of(
                        sys,
                        &weight,
                        grid,
                        field_direction(0.0, true),
                        Some(j),
                    ),
                    efficiency_crop_mean: crop.iter().sum::<f64>() / crop.len().max(1) as f64,
                }
            })
            .collect()
    } else {
        Vec::new()
    };
    let info = analysis::info(sys);
    let centre = info.field.iter().find(|f| f.name == "centre");
    let mid = va.len() / 2;
    let cap_v = capture_fov(&fov_v, crop_field_range_deg(&sys.camera, true));
    let cap_h = capture_fov(&fov_h, crop_field_range_deg(&sys.camera, false));
    DesignFigures {
        scene_field_vertical: scene_field(sys, true, &cap_v, grid.angle_step_deg),
        scene_field_horizontal: scene_field(sys, false, &cap_h, grid.angle_step_deg),
        fov_vertical_capture: cap_v,
        fov_horizontal_capture: cap_h,
        fov_vertical: fov_v,
        fov_horizontal: fov_h,
        geometric_fov_vertical_deg: info.fov_vertical_waveguide.full_deg,
        geometric_fov_horizontal_deg: info.fov_horizontal_waveguide.full_deg,
        replicas_above_5pct: centre.map_or(0, |c| c.replicas_above_5pct),
        replicas_total: centre.map_or(0, |c| c.replicas),
        replica_pitch_mm: centre.map_or(f64::NAN, |c| c.replica_pitch_mm),
        replica_pitch_sensor_px: info.replica_pitch_sensor_px,
        efficiency_peak: vt.iter().chain(&ht).copied().fold(0.0, f64::max),
        efficiency_on_axis: vt.get(mid).copied().unwrap_or(0.0),
        efficiency_crop_mean: crop_t.iter().sum::<f64>() / crop_t.len().max(1) as f64,
        bragg_min_nm,
        bragg_max_nm,
        per_grating,
        psnr_db: None,
        psnr_nominal_h_db: None,
    }
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

/// The demo settings that give the sweep's PSNR protocol.
pub fn psnr_demo_settings(p: &PsnrSettings, progress: bool) -> crate::demo::DemoSettings {
    crate::demo::DemoSettings {
        spp: p.spp,
        seed: p.seed,
        cg: crate::recon::cg::CgSettings {
            iters: crate::recon::cg::DEFAULT_CG_ITERS,
            tol: 0.0,
        },
        admm: crate::recon::admm::AdmmSettings::default(),
        progress,
    }
}

/// The PSNR target of `sys`: its spec at the display-target size and its linear intensities.
pub fn psnr_target(sys: &System, p: &PsnrSettings) -> Result<Vec<f64>, String> {
    let (ow, oh) = (sys.display.width_px, sys.display.height_px);
    if ow != oh {
        return Err(format!(
            "display.image: the PSNR needs a square object, got {ow}x{oh}"
        ));
    }
    if p.target.contains('@') {
        return Err(format!(
            "PSNR target {:?}: give it without @SIZE (the size is the scene's, {ow})",
            p.target
        ));
    }
    let spec = format!("{}@{ow}", p.target);
    let (_, _, truth) = crate::demo::intensity_of_spec(&spec, sys.scene.display.gamma)
        .map_err(|e| format!("PSNR target {spec:?}: {e}"))?;
    Ok(truth)
}

/// ADMM-TV PSNR of the target on `sys` (module header, the `demo` protocol), dB.
pub fn psnr_figure(sys: &System, p: &PsnrSettings, progress: bool) -> Result<f64, String> {
    psnr_figures(sys, p, None, progress).map(|(v, _)| v)
}

/// The reconstruction problem of `sys`'s H at the PSNR settings (the stale-calibration
/// reference of [`psnr_figures`]).
pub fn psnr_problem(sys: &System, p: &PsnrSettings, progress: bool) -> crate::recon::Problem {
    let m = crate::matrix::compute_matrix(
        sys,
        &crate::render::RenderSettings::lattice(p.spp, p.seed, progress),
    );
    crate::recon::Problem::new(&m.h, sys.display.width_px, sys.display.height_px)
}

/// The PSNR of [`psnr_figure`] and, with `nominal` (the problem of another scene's H, e.g. the
/// base scene's), the PSNR of the same capture reconstructed with it (None where the shapes
/// differ).
pub fn psnr_figures(
    sys: &System,
    p: &PsnrSettings,
    nominal: Option<&crate::recon::Problem>,
    progress: bool,
) -> Result<(f64, Option<f64>), String> {
    let truth = psnr_target(sys, p)?;
    let (ow, oh) = (sys.display.width_px, sys.display.height_px);
    let set = psnr_demo_settings(p, progress);
    let m = crate::matrix::compute_matrix(
        sys,
        &crate::render::RenderSettings::lattice(p.spp, p.seed, progress),
    );
    let (noise, dark) = crate::demo::exposure_and_dark(sys, &m, p.seed);
    let (_, g) = crate::demo::measured_capture(sys, &truth, &set, &noise, &dark, 0);
    let problem = crate::recon::Problem::new(&m.h, ow, oh);
    // τ by the discrepancy principle on the sensor noise, as the demo's table chooses it.
    let black = crate::demo::black_level_of(&dark, &noise);
    let solve = |pr: &crate::recon::Problem| {
        let level = crate::recon::discrepancy::NoiseLevel::of_capture(pr, &g, &black, true, &noise);
        let htg = pr.back_project(&g);
        let f = crate::recon::discrepancy::admm_tv_discrepancy(pr, &htg, &level, &set.admm)
            .result
            .f;
        crate::recon::metrics::psnr(&f, &truth)
    };
    let stale = nominal
        .filter(|n| n.width == ow && n.height == oh && n.ht.cols == g.len())
        .map(solve);
    Ok((solve(&problem), stale))
}

/// The grid points: one value per axis, first axis slowest.
fn grid_points(axes: &[VaryAxis]) -> Vec<Vec<f64>> {
    let values: Vec<Vec<f64>> = axes.iter().map(VaryAxis::values).collect();
    let total: usize = values.iter().map(Vec::len).product();
    (0..total)
        .map(|mut k| {
            let mut p = vec![0.0; values.len()];
            for (a, v) in values.iter().enumerate().rev() {
                p[a] = v[k % v.len()];
                k /= v.len();
            }
            p
        })
        .collect()
}

/// `KEY=value` of a grid point (shortest round-trip formatting, parsed back exactly by TOML).
fn point_overrides(axes: &[VaryAxis], point: &[f64]) -> Vec<String> {
    axes.iter()
        .zip(point)
        .map(|(a, v)| format!("{}={v}", a.key))
        .collect()
}

/// Runs a sweep (module header). All grid points are loaded and built before any figure is
/// computed, so a bad value fails fast with an error naming its key and value.
pub fn run_sweep(
    scene: Option<&Path>,
    base_overrides: &[String],
    axes: &[VaryAxis],
    set: &SweepSettings,
) -> Result<SweepOutput, SweepError> {
    run_sweep_from(SceneSource::File(scene), base_overrides, axes, set)
}

/// [`run_sweep`] of a scene from any [`SceneSource`] (e.g. TOML text in memory).
pub fn run_sweep_from(
    scene: SceneSource<'_>,
    base_overrides: &[String],
    axes: &[VaryAxis],
    set: &SweepSettings,
) -> Result<SweepOutput, SweepError> {
    let total = check_sweep(axes, set)?;
    // The base scene on its own (an error here is not the grid's).
    scene.load(base_overrides)?;
    let points = grid_points(axes);
    debug_assert_eq!(points.len(), total);
    let grid = Grid {
        scene,
        base_overrides,
        axes,
    };
    // Validate every point before computing anything expensive. The systems are built again
    // one at a time below, so memory does not grow with the number of grid points.
    for p in &points {
        grid.check_point(p, set.psnr.as_ref())?;
    }
    // The base scene's H for the stale-calibration PSNR (module header).
    let nominal = match &set.psnr {
        Some(ps) => {
            let base = scene
                .load(base_overrides)
                .and_then(|ls| System::build(&ls))?;
            Some(psnr_problem(&base, ps, false))
        }
        None => None,
    };
    let pb = crate::render::row_progress(set.progress, points.len(), "sweep points");
    let mut rows = Vec::with_capacity(points.len());
    let mut point_seconds = Vec::with_capacity(points.len());
    let cancel = crate::cancel::current();
    for p in &points {
        if cancel.is_cancelled() {
            break;
        }
        let (row, seconds) = grid.row(p, set, nominal.as_ref())?;
        point_seconds.push(seconds);
        rows.push(row);
        pb.inc(1);
    }
    pb.finish_and_clear();
    let files = encode_outputs(scene, base_overrides, axes, set, &rows)?;
    Ok(SweepOutput {
        rows,
        files,
        point_seconds,
    })
}

/// Checks the axes (some, each key once) and settings of a sweep; returns its number of grid
/// points (at most [`MAX_POINTS`]).
fn check_sweep(axes: &[VaryAxis], set: &SweepSettings) -> Result<usize, SweepError> {
    if axes.is_empty() {
        return Err(SweepError::Settings(
            "nothing to sweep: give at least one --vary KEY=START:STOP:STEPS".into(),
        ));
    }
    for (i, a) in axes.iter().enumerate() {
        if axes[..i].iter().any(|b| b.key == a.key) {
            return Err(SweepError::Settings(format!(
                "--vary {}: the key is varied twice",
                a.key
            )));
        }
    }
    if !(set.fov_fraction > 0.0 && set.fov_fraction <= 1.0) {
        return Err(SweepError::Settings(format!(
            "the FOV fraction must be in (0, 1], got {}",
            set.fov_fraction
        )));
    }
    if set.psnr.as_ref().is_some_and(|p| p.spp == 0) {
        return Err(SweepError::Settings(
            "the PSNR spp must be at least 1".into(),
        ));
    }
    set.grid.check()?;
    axes.iter()
        .try_fold(1usize, |acc, a| acc.checked_mul(a.steps))
        .filter(|&n| n <= MAX_POINTS)
        .ok_or_else(|| {
            SweepError::Settings(format!("the sweep has more than {MAX_POINTS} grid points"))
        })
}

/// The scene of a sweep, its base overrides and its axes: the system at each grid point.
struct Grid<'a> {
    scene: SceneSource<'a>,
    base_overrides: &'a [String],
    axes: &'a [VaryAxis],
}

impl Grid<'_> {
    /// Grid point `p` as `KEY=VALUE, ...`.
    fn label(&self, p: &[f64]) -> String {
        point_overrides(self.axes, p).join(", ")
    }

    /// The system at grid point `p`; an error names the point and blames `--vary KEY`.
    fn build(&self, p: &[f64]) -> Result<System, SweepError> {
        let mut ov = self.base_overrides.to_vec();
        ov.extend(point_overrides(self.axes, p));
        self.scene
            .load(&ov)
            .and_then(|ls| System::build(&ls))
            .map_err(|source| SweepError::GridPoint {
                point: self.label(p),
                source: blame_vary(source, self.axes),
            })
    }

    /// Checks grid point `p`'s scene and, with `psnr`, its target and render limits.
    fn check_point(&self, p: &[f64], psnr: Option<&PsnrSettings>) -> Result<(), SweepError> {
        let sys = self.build(p)?;
        if let Some(ps) = psnr {
            psnr_target(&sys, ps).map_err(|message| SweepError::Psnr {
                point: self.label(p),
                message,
            })?;
            // H and one capture per point.
            crate::render::check_limits(
                &sys,
                &crate::render::RenderSettings::lattice(ps.spp, 0, false),
                2,
                "--psnr-spp",
            )
            .map_err(|e| SweepError::Psnr {
                point: self.label(p),
                message: e.to_string(),
            })?;
        }
        Ok(())
    }

    /// The row of grid point `p` (its figures, with `set.psnr` the PSNR against the base H
    /// `nominal`) and the seconds it took.
    fn row(
        &self,
        p: &[f64],
        set: &SweepSettings,
        nominal: Option<&crate::recon::Problem>,
    ) -> Result<(SweepRow, f64), SweepError> {
        let sys = &self.build(p)?;
        let t0 = Instant::now();
        let mut figures = design_figures(sys, set);
        if let Some(ps) = &set.psnr {
            let (v, stale) =
                psnr_figures(sys, ps, nominal, false).map_err(|message| SweepError::Psnr {
                    point: self.label(p),
                    message,
                })?;
            figures.psnr_db = Some(v);
            figures.psnr_nominal_h_db = Some(stale.unwrap_or(f64::NAN));
        }
        let row = SweepRow {
            varied: self
                .axes
                .iter()
                .zip(p)
                .map(|(a, &value)| VariedValue {
                    key: a.key.clone(),
                    value,
                })
                .collect(),
            figures,
        };
        Ok((row, t0.elapsed().as_secs_f64()))
    }
}

/// A grid point's scene error blamed on `--vary KEY` where the key is a swept one (the
/// sweep passes its values as overrides, which the scene reports as `--set KEY`).
fn blame_vary(e: SceneError, axes: &[VaryAxis]) -> SceneError {
    match e {
        SceneError::Key { file, key, message }
            if axes.iter().any(|a| file == format!("--set {}", a.key)) =>
        {
            SceneError::Key {
                file: file.replacen("--set", "--vary", 1),
                key,
                message,
            }
        }
        other => other,
    }
}

/// Definitions recorded in `sweep.json` (the module header in short).
pub const DEFINITIONS: &[(&str, &str)] = &[
    (
        "field_response",
        "T(d) = integral of S(lambda) Rbar(lambda) W(d, lambda) dlambda / integral over the sampling band of S Rbar dlambda, for the chief ray from the lens centre along d; W = sum over all out-coupled replica branches of the display-polarisation-weighted TE/TM branch weights (Fresnel, Kogelnik efficiencies of both vHOEs at every bounce, TIR, glass absorption); S = display spectrum, Rbar = mean of the sensor channel responses; straight-through light and the lens cos^4 falloff are excluded; midpoint sums over lambda_B +- bragg_half_width_nm (bragg_step_nm bins) or, without a Bragg wavelength, the whole band (broadband_step_nm bins)",
    ),
    (
        "fov",
        "vertical: d = (0, sin t, -cos t), horizontal: d = (sin t, 0, -cos t), t the field angle in air on a grid of angle_step_deg over +-angle_max_deg; the contiguous interval where T >= fov_fraction * max T containing 0 deg (else the first maximum), edges linearly interpolated; full_deg = max - min; limited_by, judged at the first grid angle beyond the edge (out) against the grid maximum (peak): the geometric blocker of `stscam info` at out if any; else with T_out/T_peak = s b, s = ratio of S Rbar at the Bragg wavelengths, b = waveguide ratio: the display spectrum x sensor response if s < b, else the top vHOE re-coupling if the guided path at out has more front-face contacts under the top vHOE than at peak, else the bottom vHOE if out has fewer replicas >= 5 %, else 'Bragg/Kogelnik efficiency falloff'",
    ),
    (
        "fov_capture",
        "the FOV intersected with the field angles whose chief rays land inside the sensor crop ('sensor crop' where the crop binds)",
    ),
    (
        "scene_field",
        "the part of the display plane the capture sees: chief rays of the capture FOV along the axis (angle_step_deg apart) traced at their Bragg wavelengths; object points of the replicas carrying >= 5 % of each ray's strongest; min_mm/max_mm from the bottom vHOE centre, extent_mm, and full_deg = the angle the extent subtends at the bottom vHOE centre at the display distance. Taller bottom vHOEs add replicas, which widen it: the paper's dilemma",
    ),
    (
        "geometric_fov",
        "full FOV of the waveguide from `stscam info` (chief rays at their Bragg wavelength, 0.05 deg steps, no throughput threshold)",
    ),
    (
        "replicas",
        "chief ray of the crop's centre pixel at its Bragg wavelength (`stscam info`, field 'centre'): replicas_total = out-coupling bottom-vHOE contacts, replicas_above_5pct = those with at least 5 % of the strongest's weight",
    ),
    (
        "replica_pitch",
        "replica_pitch_mm = 2 w tan(guided angle) of the centre field on the display side; replica_pitch_sensor_px = mean sensor spacing of the >= 5 % replicas of a point at the display centre (NaN with fewer than two)",
    ),
    (
        "efficiency",
        "fractions of the display light reaching the sensor through the waveguide: efficiency_peak = max T over both field scans, efficiency_on_axis = T(0 deg), efficiency_crop_mean = mean T over the chief rays of a crop_grid x crop_grid grid of cell centres over the sensor crop",
    ),
    (
        "bragg_range",
        "min and max exact Bragg wavelength (nm) over the same crop grid's chief rays",
    ),
    (
        "psnr",
        "the demo's protocol: H at spp and seed, the target rendered with seed + 1, sensor noise with the exposure from the all-white capture H 1 + o and a noisy dark frame subtracted, ADMM-TV (50 iterations) with tau by the discrepancy principle on the sensor noise (recon::discrepancy); PSNR (peak 1) of the reconstruction clipped to [0, 1] against the linear target",
    ),
];

/// Unit of a scene key from its suffix, for axis labels.
fn key_unit(key: &str) -> Option<&'static str> {
    // `_per_mm` before `_mm`: the first matching suffix wins.
    [
        ("_per_mm", "1/mm"),
        ("_mm", "mm"),
        ("_deg", "deg"),
        ("_um", "um"),
        ("_nm", "nm"),
        ("_px", "px"),
        ("_e", "e-"),
        ("_dn", "DN"),
    ]
    .iter()
    .find(|(s, _)| key.ends_with(s))
    .map(|(_, u)| *u)
}

fn axis_label(key: &str) -> String {
    match key_unit(key) {
        Some(u) => format!("{key} ({u})"),
        None => key.to_string(),
    }
}

/// A float with six significant digits (fixed notation for 1e-4 ≤ |v| < 1e6), `NaN` for NaN.
fn fmt_num(v: f64) -> String {
    if v.is_nan() {
        return "NaN".into();
    }
    if v == 0.0 || v.is_infinite() {
        return format!("{v}");
    }
    let mag = v.abs().log10().floor() as i32;
    if (-4..6).contains(&mag) {
        format!("{v:.*}", (5 - mag).max(0) as usize)
    } else {
        format!("{v:.5e}")
    }
}

fn csv_text(s: &str) -> String {
    format!("\"{}\"", s.replace('"', "\"\""))
}

/// One numeric figure of a row.
type Figure = fn(&DesignFigures) -> f64;

/// Flattened CSV columns: (header, value of a row).
type Column = (String, Box<dyn Fn(&SweepRow) -> String>);

fn csv_columns(axes: &[VaryAxis], with_psnr: bool) -> Vec<Column> {
    let mut cols: Vec<Column> = Vec::new();
    for (i, a) in axes.iter().enumerate() {
        cols.push((
            a.key.clone(),
            Box::new(move |r| format!("{}", r.varied[i].value)),
        ));
    }
    type FovOf = fn(&DesignFigures) -> &Fov;
    let fovs: [(&str, FovOf); 4] = [
        ("fov_vertical", |f| &f.fov_vertical),
        ("fov_horizontal", |f| &f.fov_horizontal),
        ("fov_vertical_capture", |f| &f.fov_vertical_capture),
        ("fov_horizontal_capture", |f| &f.fov_horizontal_capture),
    ];
    for (name, get) in fovs {
        cols.push((
            format!("{name}_deg"),
            Box::new(move |r| fmt_num(get(&r.figures).full_deg)),
        ));
        cols.push((
            format!("{name}_min_deg"),
            Box::new(move |r| fmt_num(get(&r.figures).min.angle_deg)),
        ));
        cols.push((
            format!("{name}_max_deg"),
            Box::new(move |r| fmt_num(get(&r.figures).max.angle_deg)),
        ));
        cols.push((
            format!("{name}_min_limited_by"),
            Box::new(move |r| csv_text(&get(&r.figures).min.limited_by)),
        ));
        cols.push((
            format!("{name}_max_limited_by"),
            Box::new(move |r| csv_text(&get(&r.figures).max.limited_by)),
        ));
    }
    let nums: [(&str, Figure); 15] = [
        ("scene_field_vertical_mm", |f| {
            f.scene_field_vertical.extent_mm
        }),
        ("scene_field_vertical_deg", |f| {
            f.scene_field_vertical.full_deg
        }),
        ("scene_field_horizontal_mm", |f| {
            f.scene_field_horizontal.extent_mm
        }),
        ("scene_field_horizontal_deg", |f| {
            f.scene_field_horizontal.full_deg
        }),
        ("geometric_fov_vertical_deg", |f| {
            f.geometric_fov_vertical_deg
        }),
        ("geometric_fov_horizontal_deg", |f| {
            f.geometric_fov_horizontal_deg
        }),
        ("replica_pitch_mm", |f| f.replica_pitch_mm),
        ("replica_pitch_sensor_px", |f| f.replica_pitch_sensor_px),
        ("efficiency_peak", |f| f.efficiency_peak),
        ("efficiency_on_axis", |f| f.efficiency_on_axis),
        ("efficiency_crop_mean", |f| f.efficiency_crop_mean),
        ("bragg_min_nm", |f| f.bragg_min_nm),
        ("bragg_max_nm", |f| f.bragg_max_nm),
        ("psnr_db", |f| f.psnr_db.unwrap_or(f64::NAN)),
        ("psnr_nominal_h_db", |f| {
            f.psnr_nominal_h_db.unwrap_or(f64::NAN)
        }),
    ];
    cols.push((
        "replicas_above_5pct".into(),
        Box::new(|r| r.figures.replicas_above_5pct.to_string()),
    ));
    cols.push((
        "replicas_total".into(),
        Box::new(|r| r.figures.replicas_total.to_string()),
    ));
    for (name, get) in nums {
        if name.starts_with("psnr") && !with_psnr {
            continue;
        }
        cols.push((
            name.to_string(),
            Box::new(move |r| fmt_num(get(&r.figures))),
        ));
    }
    cols
}

fn encode_csv(axes: &[VaryAxis], rows: &[SweepRow], with_psnr: bool) -> Vec<u8> {
    let mut cols = csv_columns(axes, with_psnr);
    // A multiplexed film: per-grating columns NAME_gJ.
    let n_gratings = rows
        .iter()
        .map(|r| r.figures.per_grating.len())
        .max()
        .unwrap_or(0);
    type PerGrating = fn(&GratingFigures) -> f64;
    let per: [(&str, PerGrating); 4] = [
        ("bragg_min_nm", |g| g.bragg_min_nm),
        ("bragg_max_nm", |g| g.bragg_max_nm),
        ("efficiency_on_axis", |g| g.efficiency_on_axis),
        ("efficiency_crop_mean", |g| g.efficiency_crop_mean),
    ];
    for j in 0..n_gratings {
        for (name, get) in per {
            cols.push((
                format!("{name}_g{j}"),
                Box::new(move |r: &SweepRow| {
                    r.figures
                        .per_grating
                        .get(j)
                        .map_or(String::new(), |g| fmt_num(get(g)))
                }),
            ));
        }
    }
    let mut s = cols
        .iter()
        .map(|c| c.0.as_str())
        .collect::<Vec<_>>()
        .join(",");
    s.push('\n');
    for r in rows {
        let line: Vec<String> = cols.iter().map(|c| (c.1)(r)).collect();
        let _ = writeln!(s, "{}", line.join(","));
    }
    s.into_bytes()
}

/// One plotted quantity: file stem, title, y label and its curves (name, value of a row).
struct Quantity {
    stem: &'static str,
    title: &'static str,
    y_label: &'static str,
    parts: Vec<(&'static str, Figure)>,
}

fn quantities(with_psnr: bool) -> Vec<Quantity> {
    let mut q = vec![
        Quantity {
            stem: "fov",
            title: "Throughput FOV",
            y_label: "full angle (deg)",
            parts: vec![
                ("vertical", |f| f.fov_vertical.full_deg),
                ("horizontal", |f| f.fov_horizontal.full_deg),
            ],
        },
        Quantity {
            stem: "fov_capture",
            title: "Capture FOV (throughput FOV within the crop)",
            y_label: "full angle (deg)",
            parts: vec![
                ("vertical", |f| f.fov_vertical_capture.full_deg),
                ("horizontal", |f| f.fov_horizontal_capture.full_deg),
            ],
        },
        Quantity {
            stem: "scene_field",
            title: "Scene field: display region seen through strong replicas",
            y_label: "full angle at the plate (deg)",
            parts: vec![
                ("vertical", |f| f.scene_field_vertical.full_deg),
                ("horizontal", |f| f.scene_field_horizontal.full_deg),
            ],
        },
        Quantity {
            stem: "replicas",
            title: "Replicas of the centre field",
            y_label: "count",
            parts: vec![
                ("at least 5 % of the strongest", |f| {
                    f.replicas_above_5pct as f64
                }),
                ("total", |f| f.replicas_total as f64),
            ],
        },
        Quantity {
            stem: "replica_pitch_mm",
            title: "Replica pitch on the display (centre field)",
            y_label: "pitch (mm)",
            parts: vec![("2w tan(guided angle)", |f| f.replica_pitch_mm)],
        },
        Quantity {
            stem: "replica_pitch_px",
            title: "Replica pitch on the sensor",
            y_label: "pitch (px)",
            parts: vec![("replicas of at least 5 %", |f| f.replica_pitch_sensor_px)],
        },
        Quantity {
            stem: "efficiency",
            title: "Display-to-sensor efficiency",
            y_label: "fraction of display light",
            parts: vec![
                ("peak", |f| f.efficiency_peak),
                ("on axis", |f| f.efficiency_on_axis),
                ("crop mean", |f| f.efficiency_crop_mean),
            ],
        },
        Quantity {
            stem: "bragg_range",
            title: "Bragg wavelength across the capture field",
            y_label: "wavelength (nm)",
            parts: vec![("min", |f| f.bragg_min_nm), ("max", |f| f.bragg_max_nm)],
        },
    ];
    if with_psnr {
        q.push(Quantity {
            stem: "psnr",
            title: "ADMM-TV PSNR",
            y_label: "PSNR (dB)",
            parts: vec![
                ("ADMM-TV, H of the point", |f| f.psnr_db.unwrap_or(f64::NAN)),
                ("ADMM-TV, H of the base scene", |f| {
                    f.psnr_nominal_h_db.unwrap_or(f64::NAN)
                }),
            ],
        });
    }
    q
}

/// The plot of one quantity against the first axis: one series per curve and combination of
/// the other axes' values.
fn quantity_plot(axes: &[VaryAxis], rows: &[SweepRow], q: &Quantity) -> LinePlot {
    let n_first = axes[0].steps;
    let combos = rows.len() / n_first.max(1);
    let mut series = Vec::new();
    for j in 0..combos {
        let others: Vec<String> = rows[j].varied[1..]
            .iter()
            .map(|v| format!("{}={}", v.key, v.value))
            .collect();
        for (name, get) in &q.parts {
            let mut label: Vec<String> = Vec::new();
            if q.parts.len() > 1 || others.is_empty() {
                label.push((*name).to_string());
            }
            label.extend(others.iter().cloned());
            series.push(Series {
                name: label.join(", "),
                points: (0..n_first)
                    .map(|i| {
                        let r = &rows[i * combos + j];
                        (r.varied[0].value, get(&r.figures))
                    })
                    .collect(),
            });
        }
    }
    LinePlot {
        title: q.title.to_string(),
        x_label: axis_label(&axes[0].key),
        y_label: q.y_label.to_string(),
        log_x: false,
        log_y: false,
        series,
        h_line: None,
    }
}

fn encode_outputs(
    scene: SceneSource<'_>,
    base_overrides: &[String],
    axes: &[VaryAxis],
    set: &SweepSettings,
    rows: &[SweepRow],
) -> Result<Vec<(String, Vec<u8>)>, SweepError> {
    let with_psnr = set.psnr.is_some();
    let mut files = vec![("sweep.csv".to_string(), encode_csv(axes, rows, with_psnr))];
    let json = serde_json::json!({
        "stscam_version": crate::VERSION,
        "command": "sweep",
        "scene": match scene {
            SceneSource::File(p) => p.map_or_else(|| crate::scene::EMBEDDED_NAME.to_string(), |p| p.display().to_string()),
            SceneSource::Text(_, name, _) => name.to_string(),
        },
        "base_overrides": base_overrides,
        "axes": axes.iter().map(|a| serde_json::json!({
            "key": a.key, "start": a.start, "stop": a.stop, "steps": a.steps, "values": a.values(),
        })).collect::<Vec<_>>(),
        "settings": {
            "fov_fraction": set.fov_fraction,
            "replica_fraction": REPLICA_FRACTION,
            "grid": set.grid,
            "psnr": set.psnr.as_ref().map(|p| serde_json::json!({
                "target": p.target, "spp": p.spp, "seed": p.seed, "capture_seed": p.seed.wrapping_add(1),
                "reconstruction": "admm-tv, default settings",
            })),
        },
        "definitions": DEFINITIONS.iter().map(|(k, v)| ((*k).to_string(), serde_json::Value::from(*v))).collect::<serde_json::Map<_, _>>(),
        "rows": rows,
    });
    files.push((
        "sweep.json".to_string(),
        serde_json::to_vec_pretty(&json).map_err(|e| SweepError::Output(e.to_string()))?,
    ));
    for q in quantities(with_psnr) {
        let mut plot = quantity_plot(axes, rows, &q);
        if q.stem.starts_with("fov") {
            let _ = write!(plot.title, " (T >= {} of peak)", set.fov_fraction);
        }
        files.push((
            format!("{}.png", q.stem),
            plot.to_png().map_err(SweepError::Output)?,
        ));
        files.push((format!("{}.svg", q.stem), plot.to_svg().into_bytes()));
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::load_scene;

    #[test]
    fn grid_is_cartesian_first_axis_slowest() {
        let a = VaryAxis::parse("a.x_mm=1:2:2").unwrap();
        let b = VaryAxis::parse("b.y=10:30:3").unwrap();
        let p = grid_points(&[a.clone(), b.clone()]);
        assert_eq!(
            p,
            vec![
                vec![1.0, 10.0],
                vec![1.0, 20.0],
                vec![1.0, 30.0],
                vec![2.0, 10.0],
                vec![2.0, 20.0],
                vec![2.0, 30.0]
            ]
        );
        assert_eq!(
            point_overrides(&[a, b], &[1.5, 20.0]),
            vec!["a.x_mm=1.5".to_string(), "b.y=20".to_string()]
        );
    }

    #[test]
    fn threshold_interval_interpolates_and_anchors() {
        let angles: Vec<f64> = (-5..=5).map(f64::from).collect();
        // Peak 1 at 0; falls to 0.2 at ±3; threshold 0.5 crossed between 2 (0.6) and 3 (0.2).
        let t = [0.0, 0.0, 0.2, 0.6, 0.9, 1.0, 0.9, 0.6, 0.2, 0.0, 0.0];
        let (lo, hi) = threshold_interval(&angles, &t, 0.5).unwrap();
        assert!((hi.edge_deg - 2.25).abs() < 1e-12, "{hi:?}");
        assert!((lo.edge_deg + 2.25).abs() < 1e-12, "{lo:?}");
        assert_eq!((lo.out, hi.out), (Some(2), Some(8)));
        // Below threshold on axis: anchored on the maximum (at +3), not on 0.
        let t2 = [0.0, 0.0, 0.0, 0.0, 0.0, 0.1, 0.0, 0.8, 1.0, 0.9, 0.7];
        let (lo, hi) = threshold_interval(&angles, &t2, 0.5).unwrap();
        // Between 2° (0.8) and 1° (0.0): 2 − 0.3/0.8.
        assert!((lo.edge_deg - 1.625).abs() < 1e-12, "{lo:?}");
        assert_eq!(lo.out, Some(6));
        assert_eq!((hi.edge_deg, hi.out), (5.0, None));
        assert!(threshold_interval(&angles, &[0.0; 11], 0.5).is_none());
    }

    #[test]
    fn capture_fov_clips_to_the_crop_and_names_it() {
        let fov = Fov {
            full_deg: 30.0,
            min: FovEdge {
                angle_deg: -20.0,
                limited_by: "a".into(),
            },
            max: FovEdge {
                angle_deg: 10.0,
                limited_by: "b".into(),
            },
        };
        let c = capture_fov(&fov, Some([-9.0, 12.0]));
        assert_eq!(
            (c.min.angle_deg, c.max.angle_deg, c.full_deg),
            (-9.0, 10.0, 19.0)
        );
        assert_eq!(
            (c.min.limited_by.as_str(), c.max.limited_by.as_str()),
            (CROP_LIMITER, "b")
        );
        let none = capture_fov(&fov, Some([11.0, 12.0]));
        assert_eq!(none.full_deg, 0.0);
        assert_eq!(capture_fov(&fov, None).full_deg, 0.0);
    }

    #[test]
    fn number_formatting_is_stable() {
        assert_eq!(fmt_num(33.4), "33.4000");
        assert_eq!(fmt_num(0.0123456789), "0.0123457");
        assert_eq!(fmt_num(-16.75), "-16.7500");
        assert_eq!(fmt_num(1.5e-7), "1.50000e-7");
        assert_eq!(fmt_num(f64::NAN), "NaN");
        assert_eq!(fmt_num(0.0), "0");
        assert_eq!(
            axis_label("bottom_hoe.height_mm"),
            "bottom_hoe.height_mm (mm)"
        );
        assert_eq!(
            axis_label("hoe.amplitude_absorption_per_mm"),
            "hoe.amplitude_absorption_per_mm (1/mm)"
        );
        assert_eq!(axis_label("hoe.index_modulation"), "hoe.index_modulation");
    }

    #[test]
    fn response_is_a_fraction_and_mirror_symmetric_in_x() {
        let sys = System::build(&load_scene(None, &[]).unwrap()).unwrap();
        let grid = ResponseGrid::default();
        let w = SpectralWeight::new(&sys, &grid);
        for a in [3.0, 11.0, 25.0] {
            let (l, r) = (field_direction(-a, false), field_direction(a, false));
            let (tl, tr) = (
                field_response(&sys, &w, &grid, l),
                field_response(&sys, &w, &grid, r),
            );
            assert!(tl > 0.0 && tl < 1.0, "{a}: {tl}");
            assert!((tl - tr).abs() <= 1e-12 * tl, "{a}: {tl} vs {tr}");
        }
        // Outside the top-vHOE aperture nothing comes through the waveguide.
        assert_eq!(
            field_response(&sys, &w, &grid, field_direction(20.0, true)),
            0.0
        );
        // With a flat spectrum and response, the on-axis T is at most the Bragg band's share
        // of the band times the peak replica sum (< 1).
        let flat = System::build(
            &load_scene(
                None,
                &[
                    "display.spectrum=flat".into(),
                    "sensor.response=flat".into(),
                ],
            )
            .unwrap(),
        )
        .unwrap();
        let wf = SpectralWeight::new(&flat, &grid);
        assert!((wf.norm() - 400.0).abs() < 1e-9, "{}", wf.norm());
        let t0 = field_response(&flat, &wf, &grid, field_direction(0.0, true));
        assert!(t0 > 0.0 && t0 < 20.0 / 400.0, "{t0}");
    }

    #[test]
    fn bins_cover_the_interval_exactly() {
        let b: Vec<(f64, f64)> = bins(500.0, 501.05, 0.1).collect();
        assert_eq!(b.len(), 11);
        let total: f64 = b.iter().map(|x| x.1).sum();
        assert!((total - 1.05).abs() < 1e-12);
        assert!((b[10].1 - 0.05).abs() < 1e-9 && (b[10].0 - 501.025).abs() < 1e-9);
        assert_eq!(bins(2.0, 1.0, 0.1).count(), 0);
    }
}
