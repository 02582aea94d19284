//! Fabrication tolerance analysis (`stscam tolerance`): Monte Carlo draws of the film's
//! fabrication errors (the `hoe.*` keys, `optics::fabrication`) and, per draw, the design
//! figures an engineer checks before recording a film, their spread, the yield against
//! thresholds and which tolerance costs most.
//!
//! # Draws
//! `--draw KEY=normal(MEAN,SD)` or `KEY=uniform(LO,HI)` (KEY a `hoe.*` scene key). Draw i's
//! value of key k is a pure function of (seed, i, k): u = splitmix64 hashes of the tuple
//! (`sampler::hash`), normal by Box–Muller (mean + sd·√(−2 ln(1 − u1))·cos 2πu2), uniform by
//! lo + (hi − lo)·u1. So a draw does not depend on the shard split or the thread count, and a
//! zero-width distribution gives exactly its mean (0·z = 0). Each draw is the scene with its
//! values as `--set` overrides (checked like any scene), and its waveguide and camera built
//! from it; the display, sensor and the wavelength sampler's tables are the nominal scene's
//! (`hoe.*` keys do not touch them; the sampler stays unbiased for any design).
//!
//! # Figures per draw (deterministic, chief rays, no render)
//! - `fov_vertical_deg`, `fov_horizontal_deg`: the waveguide FOV of `stscam info`
//!   (`analysis::scan_fov`: chief rays at their Bragg wavelengths, 0.05° steps, no crop).
//! - `peak_efficiency[_te|_tm]` per grating: the Kogelnik efficiency of the in-coupling (order
//!   +1, the bottom vHOE) of the on-axis field (normal incidence) at its exact Bragg wavelength
//!   `bragg_on_axis_nm` (where η(λ) peaks), TE, TM and weighted by the display polarisation.
//! - `throughput_on_axis`: the end-to-end field response T of the on-axis chief ray
//!   (`sweep::field_response`: spectrum × sensor × every replica).
//! - `replica_weights` per grating: the on-axis chief ray's replica weights (display
//!   polarisation), nearest the top vHOE first (`analysis::probe_direction`).
//! - `band_centre_nm` per grating and per vertical field angle of `--field-deg`: the exact Bragg
//!   wavelength of the chief ray (the centre of that field's colour band).
//! - `psnr_db` (with `--psnr`): the calibration going stale. H of the *nominal* design at
//!   `--psnr-spp` and the seed, exposure and dark frame from it (the `demo` protocol); the
//!   target captured through the *drawn* design (a Monte Carlo render, seed + 1) with the sensor
//!   noise, reconstructed by ADMM-TV with the nominal H; PSNR against the target. Every draw
//!   uses the same render seed and noise stream (common random numbers), so draws differ by
//!   their design only and a nominal draw gives the nominal PSNR exactly.
//! - `psnr_gain_db` (with `--psnr`): the PSNR of that reconstruction f̂ times its best single
//!   gain a = ⟨f̂, t⟩/⟨f̂, f̂⟩ (least squares against the target t). A draw that only dims or
//!   brightens the capture (a pure gain: the reconstruction scales with it, up to the
//!   regulariser and the noise) loses PSNR but little `psnr_gain_db`; a draw that moves the
//!   colour bands or the replicas loses both. The gain is the one a flat-field recalibration of
//!   the exposure would restore (the oracle value here, not estimated from a white frame).
//! - `metrics` (when a requirement names one of them): the geometry and colour metrics of
//!   `stscam evaluate` (`sweep::geometry_metrics`: the captured and waveguide throughput FOVs,
//!   scene field, replicas, efficiency, colour band coverage), each under its `evaluate` name;
//!   NaN ones (a mono display's band coverage) left out of the JSON. They cost about 0.35 s of
//!   CPU per draw (field-response quadratures over two field scans and the crop), against
//!   about 2 ms for the figures above, so they are computed only when asked for.
//!
//! # Summary
//! Scalar figures: the FOVs, `efficiency_min` (smallest peak η over the gratings),
//! `throughput_on_axis`, `band_shift_on_axis_nm` (grating 0's on-axis Bragg wavelength minus
//! the nominal), `band_shift_max_nm` (largest |shift| over gratings and fields),
//! `replica_weight_max` (the strongest on-axis replica), each `evaluate` metric a requirement
//! names (e.g. the captured FOV `fov_capture_vertical_deg`), and `psnr_db` and `psnr_gain_db`.
//! For each: nominal, mean, sd, min, 5 %, median, 95 %, max. **Yield**: the fraction of draws
//! meeting every threshold given (`min_fov_deg` on the waveguide's vertical FOV,
//! `min_efficiency` on `efficiency_min`, `max_band_shift_nm` on `band_shift_max_nm`,
//! `min_psnr_db`, and each `--require NAME>=V` or `NAME<=V` on the scalar NAME, e.g.
//! `fov_capture_vertical_deg>=30`; a NaN value fails it), with each threshold's own pass
//! fraction. **Sensitivity**: per scalar figure and drawn key, Spearman's rank correlation ρ
//! over the draws (average ranks for ties), and the share ρ²/Σρ² — the part of the figure's
//! rank variance each tolerance explains to first order when the keys are drawn independently
//! (a monotone, additive reading: interactions are not separated); the keys sorted by it.
//!
//! # Shards
//! `--shard I/N` evaluates draws [I·S/N, (I+1)·S/N) and writes `draws.jsonl` and `shard.json`;
//! `stscam tolerance merge` checks that the shards share settings and version and cover 0..N−1
//! once, and writes what one unsharded run writes, byte for byte: both compute the summary from
//! the draws' JSON lines as written.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::analysis;
use crate::dataset::Shard;
use crate::plot::{Bar, BarChart, LinePlot, Series};
use crate::scene::{SceneError, load_scene};
use crate::sweep::{PsnrSettings, ResponseGrid, SpectralWeight};
use crate::system::{System, build_camera, build_waveguide};

/// Most draws of one run: every draw's record (0.76 KB as JSON for the paper's film) is held
/// in memory for the summary, and by `merge` for all shards together.
pub const MAX_SAMPLES: usize = 1_000_000;
/// Default vertical field angles (degrees in air) of the band centres.
pub const DEFAULT_FIELDS_DEG: &[f64] = &[-15.0, -10.0, -5.0, 0.0, 5.0, 10.0, 15.0];
/// Replica-weight columns per grating in `draws.csv` (the JSON has every replica).
pub const CSV_REPLICAS: usize = 6;

/// A tolerance error: one line naming the flag, key or file.
#[derive(Debug, thiserror::Error)]
pub enum ToleranceError {
    /// Bad input (a flag, a draw spec, a draw's scene, a shard folder): exit code 2.
    #[error("{0}")]
    Input(String),
    /// The scene.
    #[error("{0}")]
    Scene(#[from] SceneError),
}

fn input(m: impl Into<String>) -> ToleranceError {
    ToleranceError::Input(m.into())
}

/// A distribution of one drawn key.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Dist {
    /// Normal with this mean and standard deviation (≥ 0).
    Normal {
        /// Mean.
        mean: f64,
        /// Standard deviation.
        sd: f64,
    },
    /// Uniform on [lo, hi].
    Uniform {
        /// Lower end.
        lo: f64,
        /// Upper end.
        hi: f64,
    },
}

/// One `--draw KEY=DIST`.
#[derive(Clone, Debug, PartialEq)]
pub struct DrawSpec {
    /// Dotted scene key (`hoe.…`).
    pub key: String,
    /// Its distribution.
    pub dist: Dist,
}

impl DrawSpec {
    /// Parses `KEY=normal(MEAN,SD)` or `KEY=uniform(LO,HI)`.
    pub fn parse(spec: &str) -> Result<DrawSpec, ToleranceError> {
        let err = |m: String| input(format!("--draw {spec}: {m}"));
        let (key, dist) = spec
            .split_once('=')
            .ok_or_else(|| err("expected KEY=normal(MEAN,SD) or KEY=uniform(LO,HI)".into()))?;
        let key = key.trim();
        if !key.starts_with("hoe.") || key.contains(char::is_whitespace) {
            return Err(err(format!(
                "{key:?}: only hoe.* keys (the film, its gratings and their fabrication errors) can be drawn"
            )));
        }
        let dist = dist.trim();
        let (name, args) = dist
            .strip_suffix(')')
            .and_then(|d| d.split_once('('))
            .ok_or_else(|| err(format!("{dist:?} is not normal(MEAN,SD) or uniform(LO,HI)")))?;
        let nums: Vec<f64> = args
            .split(',')
            .map(|a| a.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<_>>()
            .filter(|v: &Vec<f64>| v.len() == 2)
            .ok_or_else(|| err(format!("{dist:?}: expected two finite numbers")))?;
        let dist = match name.trim() {
            "normal" if nums[1] >= 0.0 => Dist::Normal {
                mean: nums[0],
                sd: nums[1],
            },
            "normal" => return Err(err("normal(MEAN,SD) needs SD >= 0".into())),
            "uniform" if nums[1] >= nums[0] => Dist::Uniform {
                lo: nums[0],
                hi: nums[1],
            },
            "uniform" => return Err(err("uniform(LO,HI) needs LO <= HI".into())),
            other => {
                return Err(err(format!(
                    "unknown distribution {other:?}; expected normal or uniform"
                )));
            }
        };
        Ok(DrawSpec {
            key: key.to_string(),
            dist,
        })
    }

    /// The spec as `KEY=normal(M,SD)` (shortest round-trip numbers).
    pub fn text(&self) -> String {
        match self.dist {
            Dist::Normal { mean, sd } => format!("{}=normal({mean},{sd})", self.key),
            Dist::Uniform { lo, hi } => format!("{}=uniform({lo},{hi})", self.key),
        }
    }

    /// The value of draw `draw` for key number `k` of a run with `seed` (module notes).
    pub fn sample(&self, seed: u64, draw: u64, k: usize) -> f64 {
        use crate::sampler::{hash, to_unit};
        const TAG: u64 = 0x544F_4C45; // "TOLE"
        let u = |d: u64| to_unit(hash(&[seed, TAG, draw, k as u64, d]));
        match self.dist {
            Dist::Normal { mean, sd } => {
                let z = (-2.0 * (1.0 - u(0)).ln()).sqrt() * (std::f64::consts::TAU * u(1)).cos();
                mean + sd * z
            }
            Dist::Uniform { lo, hi } => lo + (hi - lo) * u(0),
        }
    }
}

/// Yield thresholds (each optional).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Thresholds {
    /// Smallest acceptable vertical FOV, degrees.
    pub min_fov_deg: Option<f64>,
    /// Smallest acceptable `efficiency_min` (peak η of the weakest grating).
    pub min_efficiency: Option<f64>,
    /// Largest acceptable `band_shift_max_nm`.
    pub max_band_shift_nm: Option<f64>,
    /// Smallest acceptable PSNR, dB.
    pub min_psnr_db: Option<f64>,
    /// Requirements on any scalar figure by name (`--require NAME>=V`), the geometry and
    /// colour metrics of `stscam evaluate` among them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub require: Vec<Requirement>,
}

/// A requirement on one scalar figure of a draw (`--require NAME>=VALUE` or `NAME<=VALUE`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Requirement {
    /// The figure's name: a scalar of the summary or a name of
    /// [`GEOMETRY_METRICS`](crate::sweep::GEOMETRY_METRICS).
    pub figure: String,
    /// Smallest acceptable value.
    pub min: Option<f64>,
    /// Largest acceptable value.
    pub max: Option<f64>,
}

impl Requirement {
    /// Parses `NAME>=VALUE` or `NAME<=VALUE` (the name checked by the run, which knows
    /// whether the PSNR is drawn).
    pub fn parse(spec: &str) -> Result<Requirement, ToleranceError> {
        let err = || {
            input(format!(
                "--require {spec:?}: expected NAME>=VALUE or NAME<=VALUE"
            ))
        };
        let (name, value, at_least) = if let Some((a, b)) = spec.split_once(">=") {
            (a, b, true)
        } else if let Some((a, b)) = spec.split_once("<=") {
            (a, b, false)
        } else {
            return Err(err());
        };
        let v: f64 = value
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite())
            .ok_or_else(err)?;
        let figure = name.trim().to_string();
        if figure.is_empty() {
            return Err(err());
        }
        Ok(Requirement {
            figure,
            min: at_least.then_some(v),
            max: (!at_least).then_some(v),
        })
    }

    /// `NAME>=VALUE` or `NAME<=VALUE`.
    pub fn text(&self) -> String {
        match (self.min, self.max) {
            (Some(v), _) => format!("{}>={v}", self.figure),
            (_, Some(v)) => format!("{}<={v}", self.figure),
            _ => self.figure.clone(),
        }
    }

    /// Whether `v` meets it (NaN never does).
    pub fn met_by(&self, v: f64) -> bool {
        !v.is_nan() && self.min.is_none_or(|m| v >= m) && self.max.is_none_or(|m| v <= m)
    }
}

/// What a run computes (recorded in `shard.json` and `summary.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ToleranceSettings {
    /// The `--draw` specs, in order.
    pub draws: Vec<String>,
    /// Number of draws.
    pub samples: usize,
    /// Seed of the draws (and of H and the captures with `psnr`).
    pub seed: u64,
    /// Vertical field angles of the band centres, degrees in air.
    pub field_deg: Vec<f64>,
    /// The stale-calibration PSNR (None: not computed).
    pub psnr: Option<PsnrSettings>,
    /// Yield thresholds.
    pub thresholds: Thresholds,
}

/// The figures of one design (module notes).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Figures {
    /// Waveguide vertical FOV, degrees.
    pub fov_vertical_deg: f64,
    /// Waveguide horizontal FOV, degrees.
    pub fov_horizontal_deg: f64,
    /// Per grating: the on-axis Bragg wavelength, nm (None: none).
    pub bragg_on_axis_nm: Vec<Option<f64>>,
    /// Per grating: in-coupling η at that wavelength, display polarisation.
    pub peak_efficiency: Vec<f64>,
    /// Per grating: TE.
    pub peak_efficiency_te: Vec<f64>,
    /// Per grating: TM.
    pub peak_efficiency_tm: Vec<f64>,
    /// End-to-end field response T of the on-axis chief ray.
    pub throughput_on_axis: f64,
    /// Per grating: the on-axis chief ray's replica weights, first replica first.
    pub replica_weights: Vec<Vec<f64>>,
    /// Per grating, per field of `field_deg`: the chief ray's Bragg wavelength, nm.
    pub band_centre_nm: Vec<Vec<Option<f64>>>,
    /// Stale-calibration PSNR, dB.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub psnr_db: Option<f64>,
    /// The same reconstruction after the best single gain (module notes), dB.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub psnr_gain_db: Option<f64>,
    /// The geometry and colour metrics of `stscam evaluate` (`sweep::geometry_metrics`),
    /// the finite ones.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub metrics: BTreeMap<String, f64>,
}

/// One draw: its index, the drawn values (in `--draw` order) and its figures.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DrawRecord {
    /// Draw index.
    pub draw: u64,
    /// Drawn values.
    pub values: Vec<f64>,
    /// Figures.
    pub figures: Figures,
}

/// The figures of `sys` (module notes); the PSNRs are filled by the caller.
pub fn figures(sys: &System, weight: &SpectralWeight, field_deg: &[f64]) -> Figures {
    let wg = &sys.waveguide;
    let pol = sys.display.polarization_weights;
    let axis = analysis::field_direction(0.0, true);
    let u0 = -axis.truncate();
    let n = wg.gratings.len();
    let mut bragg = Vec::with_capacity(n);
    let (mut eta, mut te, mut tm) = (Vec::new(), Vec::new(), Vec::new());
    for g in wg.gratings.as_slice() {
        let lb = g.bragg_wavelength_nm(u0);
        let e = lb.map_or([0.0, 0.0], |l| g.efficiency(u0, 1.0, l, 1));
        bragg.push(lb);
        te.push(e[0]);
        tm.push(e[1]);
        eta.push(pol[0] * e[0] + pol[1] * e[1]);
    }
    let mut replica_weights = vec![Vec::new(); n];
    if let Some(p) = analysis::probe_direction(sys, sys.camera.lens_center_mm, axis, [0, 0]) {
        for r in &p.replicas {
            replica_weights[r.grating as usize].push(r.weight);
        }
    }
    let band_centre_nm = wg
        .gratings
        .as_slice()
        .iter()
        .map(|g| {
            field_deg
                .iter()
                .map(|&a| g.bragg_wavelength_nm(-analysis::field_direction(a, true).truncate()))
                .collect()
        })
        .collect();
    let grid = ResponseGrid::default();
    Figures {
        fov_vertical_deg: analysis::scan_fov(sys, true, false).full_deg,
        fov_horizontal_deg: analysis::scan_fov(sys, false, false).full_deg,
        bragg_on_axis_nm: bragg,
        peak_efficiency: eta,
        peak_efficiency_te: te,
        peak_efficiency_tm: tm,
        throughput_on_axis: crate::sweep::field_response(sys, weight, &grid, axis),
        replica_weights,
        band_centre_nm,
        psnr_db: None,
        psnr_gain_db: None,
        metrics: BTreeMap::new(),
    }
}

/// The finite geometry and colour metrics of `sys` (`sweep::geometry_metrics`) by name.
fn metrics_of(sys: &System) -> BTreeMap<String, f64> {
    crate::sweep::geometry_metrics(sys)
        .into_iter()
        .filter(|(_, v)| v.is_finite())
        .map(|(k, v)| (k.to_string(), v))
        .collect()
}

/// Whether a requirement names an `evaluate` metric, so that every draw computes them.
fn needs_metrics(t: &Thresholds) -> bool {
    t.require
        .iter()
        .any(|r| crate::sweep::GEOMETRY_METRICS.contains(&r.figure.as_str()))
}

/// The nominal system and what every draw shares.
struct Context<'a> {
    scene: Option<&'a Path>,
    overrides: &'a [String],
    specs: Vec<DrawSpec>,
    nominal: System,
    weight: SpectralWeight,
    psnr: Option<StaleCalibration>,
    /// Whether each draw computes the `evaluate` metrics (a requirement names one).
    metrics: bool,
}

/// The nominal H and the capture protocol of the stale-calibration PSNR.
struct StaleCalibration {
    problem: crate::recon::Problem,
    truth: Vec<f64>,
    noise: crate::noise::SensorNoise,
    dark: Vec<f64>,
    demo: crate::capture::DemoSettings,
}

impl StaleCalibration {
    fn new(sys: &System, p: &PsnrSettings) -> Result<StaleCalibration, ToleranceError> {
        let truth = crate::sweep::psnr_target(sys, p).map_err(|m| input(format!("--psnr: {m}")))?;
        crate::render::check_limits(
            sys,
            &crate::render::RenderSettings::lattice(p.spp, 0, false),
            2,
            "--psnr-spp",
        )
        .map_err(|e| input(e.to_string()))?;
        let m = crate::matrix::compute_matrix(
            sys,
            &crate::render::RenderSettings::lattice(p.spp, p.seed, false),
        );
        let (noise, dark) = crate::capture::exposure_and_dark(sys, &m, p.seed);
        Ok(StaleCalibration {
            problem: crate::capture::object_problem(sys, &m.h),
            truth,
            noise,
            dark,
            demo: crate::sweep::psnr_demo_settings(p, false),
        })
    }

    /// PSNR of the target captured through `sys` and reconstructed with the nominal H, and
    /// the PSNR of that reconstruction times its best single gain (module notes).
    fn psnr(&self, sys: &System) -> (f64, f64) {
        let (_, g) = crate::capture::measured_capture(
            sys,
            &self.truth,
            &self.demo,
            &self.noise,
            &self.dark,
            0,
        );
        let pr = &self.problem;
        let f = crate::recon::admm::admm_tv(pr, &pr.back_project(&g), &self.demo.admm).f;
        let a = best_gain(&f, &self.truth);
        let gained: Vec<f64> = f.iter().map(|v| v * a).collect();
        (
            crate::recon::metrics::psnr(&f, &self.truth),
            crate::recon::metrics::psnr(&gained, &self.truth),
        )
    }
}

impl Context<'_> {
    /// The scene's overrides with a draw's `values` of the drawn keys.
    fn overrides_of(&self, values: &[f64]) -> Vec<String> {
        let mut ov = self.overrides.to_vec();
        ov.extend(
            self.specs
                .iter()
                .zip(values)
                .map(|(s, v)| format!("{}={v}", s.key)),
        );
        ov
    }

    /// Checks every draw's scene (draws `range` with `values`) before anything expensive runs.
    fn check_draws(
        &self,
        range: std::ops::Range<usize>,
        values: &[Vec<f64>],
    ) -> Result<(), ToleranceError> {
        for (i, v) in range.zip(values) {
            load_scene(self.scene, &self.overrides_of(v))
                .map_err(|e| draw_error(e.into(), i as u64, &self.specs, v))?;
        }
        Ok(())
    }

    /// The figures of draws `range` with `values`, in parallel, stopping when cancelled.
    fn run_draws(
        &self,
        range: std::ops::Range<usize>,
        values: &[Vec<f64>],
        field_deg: &[f64],
        progress: bool,
    ) -> Result<Vec<DrawRecord>, ToleranceError> {
        let pb = crate::render::row_progress(progress, values.len(), "tolerance draws");
        let cancel = crate::cancel::current();
        let draws: Vec<DrawRecord> = range
            .zip(values)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|(i, v)| -> Result<DrawRecord, ToleranceError> {
                if cancel.is_cancelled() {
                    return Err(input("cancelled"));
                }
                let sys = self
                    .system(v)
                    .map_err(|e| draw_error(e, i as u64, &self.specs, v))?;
                let figures = self.evaluate(&sys, field_deg);
                pb.inc(1);
                Ok(DrawRecord {
                    draw: i as u64,
                    values: v.clone(),
                    figures,
                })
            })
            .collect::<Result<_, _>>()?;
        pb.finish_and_clear();
        Ok(draws)
    }

    /// The system of draw `draw` with `values` (the nominal one's display, sensor and
    /// wavelength tables, the drawn film).
    fn system(&self, values: &[f64]) -> Result<System, ToleranceError> {
        let ls = load_scene(self.scene, &self.overrides_of(values))?;
        let mut sys = self.nominal.clone();
        sys.waveguide = build_waveguide(&ls.scene);
        sys.camera = build_camera(&ls.scene, &sys.waveguide);
        sys.scene = ls.scene;
        Ok(sys)
    }

    fn evaluate(&self, sys: &System, field_deg: &[f64]) -> Figures {
        let mut f = figures(sys, &self.weight, field_deg);
        if self.metrics {
            f.metrics = metrics_of(sys);
        }
        if let Some((p, g)) = self.psnr.as_ref().map(|p| p.psnr(sys)) {
            f.psnr_db = Some(p);
            f.psnr_gain_db = Some(g);
        }
        f
    }
}

/// The least-squares gain a = ⟨f, t⟩/⟨f, f⟩ that brings `f` closest to `t` (1 for f = 0).
pub fn best_gain(f: &[f64], t: &[f64]) -> f64 {
    let ff: f64 = f.iter().map(|v| v * v).sum();
    let ft: f64 = f.iter().zip(t).map(|(a, b)| a * b).sum();
    if ff > 0.0 && ft.is_finite() {
        ft / ff
    } else {
        1.0
    }
}

/// A draw's scene error, naming the draw and its values.
fn draw_error(e: ToleranceError, draw: u64, specs: &[DrawSpec], values: &[f64]) -> ToleranceError {
    let vals: Vec<String> = specs
        .iter()
        .zip(values)
        .map(|(s, v)| format!("{}={v}", s.key))
        .collect();
    input(format!(
        "--draw: draw {draw} ({}): {}",
        vals.join(", "),
        e.to_string().replace("--set ", "--draw ")
    ))
}

/// What a run produced: the files to write into `--out` (flat names) and the draws.
#[derive(Debug)]
pub struct ToleranceOutput {
    /// Files: a whole run `draws.csv`, `draws.jsonl`, `summary.json`, `hist_*.png`,
    /// `ranking_*.png`; a shard `draws.jsonl` and `shard.json`.
    pub files: Vec<(String, Vec<u8>)>,
    /// The nominal figures.
    pub nominal: Figures,
    /// This run's draws, in order.
    pub draws: Vec<DrawRecord>,
    /// The summary (a whole run only).
    pub summary: Option<Summary>,
}

/// The scene a run drew from: its source (file or the embedded scene) and `--set` overrides.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Origin {
    /// Scene file, or the embedded scene's name.
    pub scene: String,
    /// `--set` overrides, in order.
    pub overrides: Vec<String>,
}

/// `shard.json`: a shard's settings and what it holds.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct ShardManifest {
    stscam_version: String,
    origin: Origin,
    settings: ToleranceSettings,
    shard: Shard,
    draws: [usize; 2],
    nominal: Figures,
    /// SHA-256 (hex) of the shard's `draws.jsonl` bytes: a merge refuses a file that was
    /// changed, truncated or swapped for another shard's after the shard was written.
    draws_sha256: String,
}

/// Most bytes of a shard's `shard.json` a merge reads.
const MAX_MANIFEST_BYTES: u64 = 1 << 20;

/// Most bytes one draw record of `draws.jsonl` may take on average (a record is a few hundred
/// bytes: the drawn values and the figures at each field angle).
const MAX_RECORD_BYTES: u64 = 64 << 10;

/// Runs draws `shard`'s part (all without a shard) of the tolerance analysis of the scene
/// `scene` with `overrides` (module notes).
pub fn run_tolerance(
    scene: Option<&Path>,
    overrides: &[String],
    set: &ToleranceSettings,
    shard: Option<Shard>,
    progress: bool,
) -> Result<ToleranceOutput, ToleranceError> {
    let specs = checked_specs(set)?;
    let ls = load_scene(scene, overrides)?;
    let origin = Origin {
        scene: ls.source.clone(),
        overrides: overrides.to_vec(),
    };
    let nominal = System::build(&ls)?;
    let weight = SpectralWeight::new(&nominal, &ResponseGrid::default());
    let psnr = match &set.psnr {
        Some(p) => Some(StaleCalibration::new(&nominal, p)?),
        None => None,
    };
    let ctx = Context {
        scene,
        overrides,
        specs,
        nominal,
        weight,
        psnr,
        metrics: needs_metrics(&set.thresholds),
    };
    let range = shard.map_or(0..set.samples, |s| s.range(set.samples));
    let values: Vec<Vec<f64>> = range
        .clone()
        .map(|i| {
            ctx.specs
                .iter()
                .enumerate()
                .map(|(k, s)| s.sample(set.seed, i as u64, k))
                .collect()
        })
        .collect();
    ctx.check_draws(range.clone(), &values)?;
    let nominal_figures = ctx.evaluate(&ctx.nominal, &set.field_deg);
    let draws = ctx.run_draws(range.clone(), &values, &set.field_deg, progress)?;
    tolerance_output(&origin, set, shard, range, nominal_figures, draws)
}

/// The draw specifications of `set`, checked with its sample count, fields and PSNR samples.
fn checked_specs(set: &ToleranceSettings) -> Result<Vec<DrawSpec>, ToleranceError> {
    let specs = set
        .draws
        .iter()
        .map(|d| DrawSpec::parse(d))
        .collect::<Result<Vec<_>, _>>()?;
    if specs.is_empty() {
        return Err(input("--draw: give at least one KEY=DIST"));
    }
    for (i, s) in specs.iter().enumerate() {
        if specs[..i].iter().any(|t| t.key == s.key) {
            return Err(input(format!("--draw {}: the key is drawn twice", s.key)));
        }
    }
    if !(1..=MAX_SAMPLES).contains(&set.samples) {
        return Err(input(format!(
            "--samples: must be in 1..={MAX_SAMPLES}, got {}",
            set.samples
        )));
    }
    if set.field_deg.is_empty() || set.field_deg.iter().any(|a| !(a.abs() < 89.0)) {
        return Err(input("--field-deg: give field angles in (-89, 89) degrees"));
    }
    if set.psnr.as_ref().is_some_and(|p| p.spp == 0) {
        return Err(input("--psnr-spp: must be at least 1"));
    }
    let known = scalar_names(set.psnr.is_some());
    for r in &set.thresholds.require {
        if !known.contains(&r.figure.as_str()) {
            let psnr = r.figure.starts_with("psnr") && set.psnr.is_none();
            return Err(input(format!(
                "--require {}: {}",
                r.text(),
                if psnr {
                    "needs --psnr".to_string()
                } else {
                    format!("unknown figure; expected one of {}", known.join(", "))
                }
            )));
        }
        if !r.min.or(r.max).is_some_and(f64::is_finite) {
            return Err(input(format!(
                "--require {}: needs a finite bound",
                r.text()
            )));
        }
    }
    Ok(specs)
}

/// The files of a run: a shard's draws and manifest, or the whole analysis ([`finish`]).
fn tolerance_output(
    origin: &Origin,
    set: &ToleranceSettings,
    shard: Option<Shard>,
    range: std::ops::Range<usize>,
    nominal_figures: Figures,
    draws: Vec<DrawRecord>,
) -> Result<ToleranceOutput, ToleranceError> {
    let lines: Vec<String> = draws.iter().map(json_line).collect::<Result<_, _>>()?;
    let nominal_line = json_line(&nominal_figures)?;
    match shard {
        Some(sh) => {
            let draws_bytes = jsonl(&lines);
            let manifest = ShardManifest {
                stscam_version: env!("CARGO_PKG_VERSION").to_string(),
                origin: origin.clone(),
                settings: set.clone(),
                shard: sh,
                draws: [range.start, range.end],
                nominal: parse_line(&nominal_line)?,
                draws_sha256: crate::dataset::sha256_hex(&draws_bytes),
            };
            let files = vec![
                ("draws.jsonl".to_string(), draws_bytes),
                ("shard.json".to_string(), pretty(&manifest)?.into_bytes()),
            ];
            Ok(ToleranceOutput {
                files,
                nominal: nominal_figures,
                draws,
                summary: None,
            })
        }
        None => {
            let (files, summary) = finish(origin, set, &nominal_line, &lines)?;
            Ok(ToleranceOutput {
                files,
                nominal: nominal_figures,
                draws,
                summary: Some(summary),
            })
        }
    }
}

fn json_line<T: Serialize>(v: &T) -> Result<String, ToleranceError> {
    serde_json::to_string(v).map_err(|e| input(format!("cannot encode JSON: {e}")))
}

fn pretty<T: Serialize>(v: &T) -> Result<String, ToleranceError> {
    serde_json::to_string_pretty(v)
        .map(|s| s + "\n")
        .map_err(|e| input(format!("cannot encode JSON: {e}")))
}

fn parse_line<T: for<'de> Deserialize<'de>>(line: &str) -> Result<T, ToleranceError> {
    serde_json::from_str(line).map_err(|e| input(format!("malformed draw record: {e}")))
}

fn jsonl(lines: &[String]) -> Vec<u8> {
    let mut out = String::new();
    for l in lines {
        out.push_str(l);
        out.push('\n');
    }
    out.into_bytes()
}

/// Joins finished shard folders into the outputs of one unsharded run (module notes).
pub fn merge(shards: &[PathBuf]) -> Result<(Vec<(String, Vec<u8>)>, Summary), ToleranceError> {
    let mut parts: Vec<(ShardManifest, Vec<String>)> = Vec::new();
    for dir in shards {
        // Regular files of bounded size only: a FIFO, a device or a link to /dev/zero is
        // refused in one line instead of hanging or filling the memory.
        let read = |name: &str, max_bytes: u64| {
            let p = dir.join(name);
            let bytes =
                crate::io::input::read_input(&p, max_bytes).map_err(|e| input(e.to_string()))?;
            String::from_utf8(bytes).map_err(|_| input(format!("{}: not UTF-8 text", p.display())))
        };
        let manifest_path = dir.join("shard.json");
        let m: ShardManifest = serde_json::from_str(&read("shard.json", MAX_MANIFEST_BYTES)?)
            .map_err(|e| {
                input(format!(
                    "{}: not a tolerance shard: {e}",
                    manifest_path.display()
                ))
            })?;
        let [start, end] = m.draws;
        if start > end || end > MAX_SAMPLES {
            return Err(input(format!(
                "{}: draws {start}..{end} is not a range of at most {MAX_SAMPLES} draws",
                manifest_path.display()
            )));
        }
        let count = (end - start) as u64;
        let draws_path = dir.join("draws.jsonl");
        let text = read("draws.jsonl", (count + 1).saturating_mul(MAX_RECORD_BYTES))?;
        if crate::dataset::sha256_hex(text.as_bytes()) != m.draws_sha256 {
            return Err(input(format!(
                "{}: its SHA-256 is not the one shard.json records (the file was changed after the shard was written)",
                draws_path.display()
            )));
        }
        let lines: Vec<String> = text.lines().map(str::to_string).collect();
        if lines.len() != end - start {
            return Err(input(format!(
                "{}: holds {} draws, shard.json says {}",
                draws_path.display(),
                lines.len(),
                end - start
            )));
        }
        // Each record is the draw it should be, with one value per drawn key.
        let keys = m.settings.draws.len();
        for (k, line) in lines.iter().enumerate() {
            let r: DrawRecord = parse_line(line)
                .map_err(|e| input(format!("{} line {}: {e}", draws_path.display(), k + 1)))?;
            if r.draw != (start + k) as u64 || r.values.len() != keys {
                return Err(input(format!(
                    "{} line {}: draw {} with {} values, expected draw {} with {keys} (one per --draw key)",
                    draws_path.display(),
                    k + 1,
                    r.draw,
                    r.values.len(),
                    start + k
                )));
            }
        }
        parts.push((m, lines));
    }
    let Some((first, _)) = parts.first() else {
        return Err(input("merge: give the shard folders"));
    };
    let (set, count) = (first.settings.clone(), first.shard.count);
    let origin = first.origin.clone();
    let nominal_line = json_line(&first.nominal)?;
    for (m, _) in &parts {
        if m.settings != set
            || m.origin != origin
            || m.shard.count != count
            || m.stscam_version != first.stscam_version
        {
            return Err(input(format!(
                "merge: shard {}/{} comes from another run (scene, settings, shard count or version differ)",
                m.shard.index, m.shard.count
            )));
        }
    }
    parts.sort_by_key(|(m, _)| m.shard.index);
    let indices: Vec<usize> = parts.iter().map(|(m, _)| m.shard.index).collect();
    if indices != (0..count).collect::<Vec<_>>() {
        return Err(input(format!(
            "merge: need shards 0..{} once each, got {indices:?}",
            count - 1
        )));
    }
    let lines: Vec<String> = parts.into_iter().flat_map(|(_, l)| l).collect();
    finish(&origin, &set, &nominal_line, &lines)
}

/// Statistics of one scalar figure over the draws (finite values only).
#[derive(Clone, Debug, Serialize)]
pub struct Stats {
    /// The nominal design's value.
    pub nominal: f64,
    /// Draws with a finite value.
    pub n: usize,
    /// Mean.
    pub mean: f64,
    /// Standard deviation (n − 1).
    pub sd: f64,
    /// Smallest.
    pub min: f64,
    /// 5th percentile (nearest rank).
    pub p05: f64,
    /// Median (nearest rank).
    pub median: f64,
    /// 95th percentile (nearest rank).
    pub p95: f64,
    /// Largest.
    pub max: f64,
}

/// One key's sensitivity for one figure.
#[derive(Clone, Debug, Serialize)]
pub struct Sensitivity {
    /// Drawn key.
    pub key: String,
    /// Spearman's rank correlation of the key's values with the figure (0 for a constant).
    pub rho: f64,
    /// ρ²/Σρ² over the drawn keys.
    pub share: f64,
}

/// Yield against the thresholds.
#[derive(Clone, Debug, Serialize)]
pub struct Yield {
    /// Draws meeting every threshold given.
    pub passed: usize,
    /// Draws.
    pub total: usize,
    /// passed/total.
    pub fraction: f64,
    /// Binomial standard error of the fraction.
    pub std_error: f64,
    /// Per threshold (its name): the fraction meeting it.
    pub per_threshold: Vec<(String, f64)>,
}

/// `summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// stscam version.
    pub stscam_version: String,
    /// The scene and its overrides.
    pub origin: Origin,
    /// Settings.
    pub settings: ToleranceSettings,
    /// The nominal design's figures.
    pub nominal: Figures,
    /// Per scalar figure (name, statistics).
    pub figures: Vec<(String, Stats)>,
    /// Yield.
    #[serde(rename = "yield")]
    pub yield_: Yield,
    /// Per scalar figure (name, keys from the largest share down).
    pub ranking: Vec<(String, Vec<Sensitivity>)>,
    /// Definitions (the module notes in short).
    pub definitions: Vec<(String, String)>,
}

/// The fixed scalar figures, before the captured FOVs and the required metrics.
const FIXED_SCALARS: [&str; 7] = [
    "fov_vertical_deg",
    "fov_horizontal_deg",
    "efficiency_min",
    "throughput_on_axis",
    "band_shift_on_axis_nm",
    "band_shift_max_nm",
    "replica_weight_max",
];

/// Every name a requirement may use.
fn scalar_names(with_psnr: bool) -> Vec<&'static str> {
    let mut v: Vec<&'static str> = FIXED_SCALARS.to_vec();
    v.extend(crate::sweep::GEOMETRY_METRICS);
    if with_psnr {
        v.extend(["psnr_db", "psnr_gain_db"]);
    }
    v
}

/// The scalar figures of a draw against the nominal (module notes), by name: the fixed
/// ones, the `evaluate` metrics a requirement names, the PSNRs.
fn scalars(f: &Figures, nominal: &Figures, set: &ToleranceSettings) -> Vec<(&'static str, f64)> {
    let shift_on_axis = match (f.bragg_on_axis_nm.first(), nominal.bragg_on_axis_nm.first()) {
        (Some(Some(a)), Some(Some(b))) => a - b,
        _ => f64::NAN,
    };
    let mut shift_max = f64::NAN;
    for (g, gn) in f.band_centre_nm.iter().zip(&nominal.band_centre_nm) {
        for (a, b) in g.iter().zip(gn) {
            if let (Some(a), Some(b)) = (a, b) {
                let d = (a - b).abs();
                shift_max = if shift_max.is_nan() {
                    d
                } else {
                    shift_max.max(d)
                };
            }
        }
    }
    // In the order of FIXED_SCALARS.
    let fixed = [
        f.fov_vertical_deg,
        f.fov_horizontal_deg,
        f.peak_efficiency
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min),
        f.throughput_on_axis,
        shift_on_axis,
        shift_max,
        f.replica_weights
            .first()
            .map_or(0.0, |w| w.iter().copied().fold(0.0, f64::max)),
    ];
    let mut out: Vec<(&'static str, f64)> = FIXED_SCALARS.into_iter().zip(fixed).collect();
    for name in crate::sweep::GEOMETRY_METRICS {
        let required = set.thresholds.require.iter().any(|r| r.figure == name);
        if required {
            out.push((name, f.metrics.get(name).copied().unwrap_or(f64::NAN)));
        }
    }
    if set.psnr.is_some() {
        out.push(("psnr_db", f.psnr_db.unwrap_or(f64::NAN)));
        out.push(("psnr_gain_db", f.psnr_gain_db.unwrap_or(f64::NAN)));
    }
    out
}

fn stats(nominal: f64, values: &[f64]) -> Stats {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    let q = |p: f64| {
        if n == 0 {
            f64::NAN
        } else {
            v[((p * n as f64).ceil() as usize).clamp(1, n) - 1]
        }
    };
    let mean = v.iter().sum::<f64>() / n.max(1) as f64;
    let var = if n > 1 {
        v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1) as f64
    } else {
        0.0
    };
    Stats {
        nominal,
        n,
        mean: if n == 0 { f64::NAN } else { mean },
        sd: var.sqrt(),
        min: q(0.0),
        p05: q(0.05),
        median: q(0.5),
        p95: q(0.95),
        max: v.last().copied().unwrap_or(f64::NAN),
    }
}

/// Ranks (1-based, ties averaged).
fn ranks(x: &[f64]) -> Vec<f64> {
    let mut idx: Vec<usize> = (0..x.len()).collect();
    idx.sort_by(|&a, &b| x[a].total_cmp(&x[b]));
    let mut r = vec![0.0; x.len()];
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && x[idx[j + 1]] == x[idx[i]] {
            j += 1;
        }
        let avg = 0.5 * (i + j) as f64 + 1.0;
        for &k in &idx[i..=j] {
            r[k] = avg;
        }
        i = j + 1;
    }
    r
}

/// Spearman's rank correlation of the pairs with both values finite (0 if either is constant).
pub fn spearman(x: &[f64], y: &[f64]) -> f64 {
    let (xs, ys): (Vec<f64>, Vec<f64>) = x
        .iter()
        .zip(y)
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| (*a, *b))
        .unzip();
    let (rx, ry) = (ranks(&xs), ranks(&ys));
    let n = rx.len() as f64;
    if n < 2.0 {
        return 0.0;
    }
    let (mx, my) = (rx.iter().sum::<f64>() / n, ry.iter().sum::<f64>() / n);
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in rx.iter().zip(&ry) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx) * (a - mx);
        syy += (b - my) * (b - my);
    }
    if sxx <= 0.0 || syy <= 0.0 {
        0.0
    } else {
        sxy / (sxx * syy).sqrt()
    }
}

/// The outputs of a whole run from the nominal figures' and the draws' JSON lines.
/// The whole analysis from the nominal figures and every draw's line: each figure's
/// statistics, the sensitivity ranking ([`sensitivity_ranking`]), the yield ([`yield_of`]),
/// then the files with their plots.
fn finish(
    origin: &Origin,
    set: &ToleranceSettings,
    nominal_line: &str,
    lines: &[String],
) -> Result<(Vec<(String, Vec<u8>)>, Summary), ToleranceError> {
    let nominal: Figures = parse_line(nominal_line)?;
    let draws: Vec<DrawRecord> = lines
        .iter()
        .map(|l| parse_line(l))
        .collect::<Result<_, _>>()?;
    let keys: Vec<String> = set
        .draws
        .iter()
        .map(|d| DrawSpec::parse(d).map(|s| s.key))
        .collect::<Result<_, _>>()?;
    let nominal_scalars = scalars(&nominal, &nominal, set);
    let per_draw: Vec<Vec<(&str, f64)>> = draws
        .iter()
        .map(|d| scalars(&d.figures, &nominal, set))
        .collect();
    let column = |i: usize| column_of(&per_draw, i);
    let figures: Vec<(String, Stats)> = nominal_scalars
        .iter()
        .enumerate()
        .map(|(i, (name, nom))| (name.to_string(), stats(*nom, &column(i))))
        .collect();
    let ranking = sensitivity_ranking(&nominal_scalars, &keys, &draws, &per_draw);
    let yield_ = yield_of(&set.thresholds, &per_draw);
    let summary = Summary {
        stscam_version: env!("CARGO_PKG_VERSION").to_string(),
        origin: origin.clone(),
        settings: set.clone(),
        nominal: nominal.clone(),
        figures,
        yield_,
        ranking,
        definitions: DEFINITIONS
            .iter()
            .map(|(a, b)| (a.to_string(), b.to_string()))
            .collect(),
    };
    let mut files = vec![
        ("draws.csv".to_string(), csv(&keys, &nominal, &draws)),
        ("draws.jsonl".to_string(), jsonl(lines)),
        ("summary.json".to_string(), pretty(&summary)?.into_bytes()),
    ];
    tolerance_plots(&mut files, &summary, &per_draw)?;
    Ok((files, summary))
}

/// Figure `i` of every draw.
fn column_of(per_draw: &[Vec<(&str, f64)>], i: usize) -> Vec<f64> {
    per_draw.iter().map(|s| s[i].1).collect()
}

/// For each figure, the drawn keys ranked by their share of the squared Spearman
/// correlations with it.
fn sensitivity_ranking(
    nominal_scalars: &[(&str, f64)],
    keys: &[String],
    draws: &[DrawRecord],
    per_draw: &[Vec<(&str, f64)>],
) -> Vec<(String, Vec<Sensitivity>)> {
    nominal_scalars
        .iter()
        .enumerate()
        .map(|(i, (name, _))| {
            let y = column_of(per_draw, i);
            let rhos: Vec<f64> = (0..keys.len())
                .map(|k| {
                    let x: Vec<f64> = draws.iter().map(|d| d.values[k]).collect();
                    spearman(&x, &y)
                })
                .collect();
            let total: f64 = rhos.iter().map(|r| r * r).sum();
            let mut s: Vec<Sensitivity> = keys
                .iter()
                .zip(&rhos)
                .map(|(k, &rho)| Sensitivity {
                    key: k.clone(),
                    rho,
                    share: if total > 0.0 { rho * rho / total } else { 0.0 },
                })
                .collect();
            s.sort_by(|a, b| b.share.total_cmp(&a.share));
            (name.to_string(), s)
        })
        .collect()
}

/// The fraction of draws meeting every given threshold (with its binomial standard error) and
/// each threshold's own pass fraction.
fn yield_of(t: &Thresholds, per_draw: &[Vec<(&str, f64)>]) -> Yield {
    let value = |d: usize, name: &str| {
        per_draw[d]
            .iter()
            .find(|(n, _)| *n == name)
            .map_or(f64::NAN, |x| x.1)
    };
    let checks: Vec<(String, Box<dyn Fn(usize) -> bool>)> = [
        ("min_fov_deg", "fov_vertical_deg", t.min_fov_deg, true),
        ("min_efficiency", "efficiency_min", t.min_efficiency, true),
        (
            "max_band_shift_nm",
            "band_shift_max_nm",
            t.max_band_shift_nm,
            false,
        ),
        ("min_psnr_db", "psnr_db", t.min_psnr_db, true),
    ]
    .into_iter()
    .filter_map(|(flag, fig, thr, at_least)| {
        let thr = thr?;
        let f: Box<dyn Fn(usize) -> bool> = Box::new(move |d| {
            let v = value(d, fig);
            if at_least { v >= thr } else { v <= thr }
        });
        Some((flag.to_string(), f))
    })
    .chain(t.require.iter().map(|r| {
        let f: Box<dyn Fn(usize) -> bool> = Box::new(move |d| r.met_by(value(d, &r.figure)));
        (r.text(), f)
    }))
    .collect();
    let total = per_draw.len();
    let passed = (0..total)
        .filter(|&d| checks.iter().all(|(_, c)| c(d)))
        .count();
    let fraction = passed as f64 / total.max(1) as f64;
    Yield {
        passed,
        total,
        fraction,
        std_error: (fraction * (1.0 - fraction) / total.max(1) as f64).sqrt(),
        per_threshold: checks
            .iter()
            .map(|(n, c)| {
                (
                    n.clone(),
                    (0..total).filter(|&d| c(d)).count() as f64 / total.max(1) as f64,
                )
            })
            .collect(),
    }
}

/// Each figure's histogram and sensitivity ranking plots, appended to `files`.
fn tolerance_plots(
    files: &mut Vec<(String, Vec<u8>)>,
    summary: &Summary,
    per_draw: &[Vec<(&str, f64)>],
) -> Result<(), ToleranceError> {
    for (i, (name, st)) in summary.figures.iter().enumerate() {
        let png = histogram(name, &column_of(per_draw, i), st.nominal)
            .to_png()
            .map_err(|e| input(format!("plot {name}: {e}")))?;
        files.push((format!("hist_{name}.png"), png));
        let png = ranking_plot(name, &summary.ranking[i].1)
            .to_png()
            .map_err(|e| input(format!("plot {name}: {e}")))?;
        files.push((format!("ranking_{name}.png"), png));
    }
    Ok(())
}

/// Definitions recorded in `summary.json`.
pub const DEFINITIONS: &[(&str, &str)] = &[
    (
        "draws",
        "value of draw i, key k: normal mean + sd sqrt(-2 ln(1-u1)) cos(2 pi u2), uniform lo + (hi-lo) u1, u = splitmix64 hashes of (seed, i, k); the scene with the values as --set overrides",
    ),
    (
        "fov",
        "waveguide FOV of `stscam info` (chief rays at their Bragg wavelengths, 0.05 deg steps, no sensor crop)",
    ),
    (
        "peak_efficiency",
        "Kogelnik in-coupling efficiency (order +1, bottom vHOE) of the on-axis field at its exact Bragg wavelength bragg_on_axis_nm, per grating; TE, TM and weighted by the display polarisation; efficiency_min = the smallest over the gratings",
    ),
    (
        "throughput_on_axis",
        "end-to-end field response T of the on-axis chief ray (as `stscam sweep`)",
    ),
    (
        "replica_weights",
        "on-axis chief ray's replica weights per grating (display polarisation), first replica first; replica_weight_max = grating 0's strongest",
    ),
    (
        "band_centre_nm",
        "exact Bragg wavelength of the chief ray at each vertical field angle of field_deg, per grating; band_shift_on_axis_nm = grating 0's on-axis Bragg wavelength minus nominal, band_shift_max_nm = largest |shift| over gratings and fields",
    ),
    (
        "psnr_db",
        "target captured through the drawn design (render at psnr spp, seed + 1, sensor noise; the same render seed and noise for every draw), reconstructed by ADMM-TV with the nominal design's H at psnr spp and seed; PSNR against the target",
    ),
    (
        "psnr_gain_db",
        "PSNR of the same reconstruction times its best single gain a = <f, t>/<f, f> (least squares against the target): a pure brightness change costs psnr_db but little psnr_gain_db",
    ),
    (
        "metrics",
        "the geometry and colour metrics of `stscam evaluate` (captured and waveguide throughput FOVs, scene field, replicas, efficiency, band coverage) under their evaluate names; non-finite ones left out",
    ),
    (
        "yield",
        "fraction of draws meeting every threshold given: fov_vertical_deg >= min_fov_deg, efficiency_min >= min_efficiency, band_shift_max_nm <= max_band_shift_nm, psnr_db >= min_psnr_db, and each require (NAME>=V or NAME<=V on that scalar; NaN fails); std_error = sqrt(f (1-f)/n)",
    ),
    (
        "ranking",
        "per figure and drawn key: Spearman rank correlation rho over the draws (ties averaged, non-finite pairs dropped) and share = rho^2 / sum of rho^2 over the keys (first-order, monotone reading; interactions not separated)",
    ),
];

fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v}")
    } else {
        String::new()
    }
}

/// `draws.csv`: draw, drawn values, the figures (per grating `_gJ`, per field `_fK`; at most
/// [`CSV_REPLICAS`] replica weights per grating, 0 where a draw has fewer).
fn csv(keys: &[String], nominal: &Figures, draws: &[DrawRecord]) -> Vec<u8> {
    let ng = nominal.peak_efficiency.len();
    let nf = nominal.band_centre_nm.first().map_or(0, Vec::len);
    let nr: Vec<usize> = nominal
        .replica_weights
        .iter()
        .map(|w| w.len().min(CSV_REPLICAS))
        .collect();
    let mut head: Vec<String> = vec!["draw".into()];
    head.extend(keys.iter().cloned());
    head.extend(["fov_vertical_deg".into(), "fov_horizontal_deg".into()]);
    for j in 0..ng {
        head.extend([
            format!("bragg_on_axis_nm_g{j}"),
            format!("peak_efficiency_g{j}"),
            format!("peak_efficiency_te_g{j}"),
            format!("peak_efficiency_tm_g{j}"),
        ]);
    }
    head.push("throughput_on_axis".into());
    for (j, &n) in nr.iter().enumerate() {
        head.extend((0..n).map(|k| format!("replica_weight_g{j}_{k}")));
    }
    for j in 0..ng {
        head.extend((0..nf).map(|k| format!("band_centre_nm_g{j}_f{k}")));
    }
    let metrics = draws.iter().any(|d| !d.figures.metrics.is_empty());
    if metrics {
        head.extend(crate::sweep::GEOMETRY_METRICS.map(String::from));
    }
    let psnr = draws.iter().any(|d| d.figures.psnr_db.is_some());
    if psnr {
        head.extend(["psnr_db".into(), "psnr_gain_db".into()]);
    }
    let mut out = head.join(",") + "\n";
    for d in draws {
        let f = &d.figures;
        let mut row: Vec<String> = vec![d.draw.to_string()];
        row.extend(d.values.iter().map(|&v| num(v)));
        row.extend([num(f.fov_vertical_deg), num(f.fov_horizontal_deg)]);
        for j in 0..ng {
            row.extend([
                f.bragg_on_axis_nm
                    .get(j)
                    .copied()
                    .flatten()
                    .map_or(String::new(), num),
                num(f.peak_efficiency.get(j).copied().unwrap_or(f64::NAN)),
                num(f.peak_efficiency_te.get(j).copied().unwrap_or(f64::NAN)),
                num(f.peak_efficiency_tm.get(j).copied().unwrap_or(f64::NAN)),
            ]);
        }
        row.push(num(f.throughput_on_axis));
        for (j, &n) in nr.iter().enumerate() {
            let w = f.replica_weights.get(j);
            row.extend((0..n).map(|k| num(w.and_then(|w| w.get(k)).copied().unwrap_or(0.0))));
        }
        for j in 0..ng {
            row.extend((0..nf).map(|k| {
                f.band_centre_nm
                    .get(j)
                    .and_then(|g| g.get(k))
                    .copied()
                    .flatten()
                    .map_or(String::new(), num)
            }));
        }
        if metrics {
            row.extend(
                crate::sweep::GEOMETRY_METRICS
                    .map(|m| f.metrics.get(m).map_or(String::new(), |&v| num(v))),
            );
        }
        if psnr {
            row.push(f.psnr_db.map_or(String::new(), num));
            row.push(f.psnr_gain_db.map_or(String::new(), num));
        }
        out.push_str(&row.join(","));
        out.push('\n');
    }
    out.into_bytes()
}

/// Histogram of a figure's finite values (30 bins, a step line) with the nominal marked.
fn histogram(name: &str, values: &[f64], nominal: f64) -> LinePlot {
    let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    let lo = v.iter().copied().fold(nominal, f64::min);
    let hi = v.iter().copied().fold(nominal, f64::max);
    let (lo, hi) = if hi > lo {
        (lo, hi)
    } else {
        let w = (lo.abs() * 1e-6).max(1e-12);
        (lo - w, hi + w)
    };
    const BINS: usize = 30;
    let width = (hi - lo) / BINS as f64;
    let mut counts = [0usize; BINS];
    for x in &v {
        counts[(((x - lo) / width) as usize).min(BINS - 1)] += 1;
    }
    let mut pts = vec![(lo, 0.0)];
    for (i, &c) in counts.iter().enumerate() {
        let a = lo + i as f64 * width;
        pts.push((a, c as f64));
        pts.push((a + width, c as f64));
    }
    pts.push((hi, 0.0));
    let top = counts.iter().copied().max().unwrap_or(0) as f64;
    LinePlot {
        title: format!("{name}: {} draws", v.len()),
        x_label: name.to_string(),
        y_label: "draws per bin".into(),
        log_x: false,
        log_y: false,
        series: vec![
            Series {
                name: "draws".into(),
                points: pts,
            },
            Series {
                name: "nominal".into(),
                points: vec![(nominal, 0.0), (nominal, top.max(1.0))],
            },
        ],
        h_line: None,
    }
}

/// The ranking of one figure: per key (x = its position in the `--draw` list, from 1) a bar
/// of height ρ² share, named in the legend.
fn ranking_plot(name: &str, ranking: &[Sensitivity]) -> BarChart {
    BarChart {
        title: format!("what costs most: {name}"),
        x_label: "share of rank variance (rho^2 / sum over the drawn keys)".into(),
        bars: ranking
            .iter()
            .map(|s| Bar {
                label: s.key.trim_start_matches("hoe.").to_string(),
                value: s.share,
                note: format!("{:.2} (rho {:+.2})", s.share, s.rho),
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_best_gain_undoes_a_scale_and_never_does_worse_than_one() {
        let t = [0.2, 0.9, 0.5, 0.0];
        let f: Vec<f64> = t.iter().map(|v| 0.4 * v).collect();
        assert!((best_gain(&f, &t) - 2.5).abs() < 1e-12);
        let noisy = [0.1, 1.0, 0.45, 0.05];
        let a = best_gain(&noisy, &t);
        let sse = |a: f64| -> f64 { noisy.iter().zip(&t).map(|(x, y)| (a * x - y).powi(2)).sum() };
        assert!(sse(a) <= sse(1.0) && sse(a) <= sse(a + 1e-3) && sse(a) <= sse(a - 1e-3));
        assert_eq!(best_gain(&[0.0; 4], &t), 1.0);
        let r = Requirement::parse("efficiency_mean <= 0.5").unwrap();
        assert_eq!(
            (r.figure.as_str(), r.max, r.text()),
            ("efficiency_mean", Some(0.5), "efficiency_mean<=0.5".into())
        );
        assert!(r.met_by(0.5) && !r.met_by(0.6) && !r.met_by(f64::NAN));
        assert!(Requirement::parse("a>=nan").is_err() && Requirement::parse(">=1").is_err());
    }

    #[test]
    fn draw_specs_parse_and_fail_with_the_flag() {
        let d = DrawSpec::parse("hoe.shrinkage=normal(0.01,0.005)").unwrap();
        assert_eq!(
            d.dist,
            Dist::Normal {
                mean: 0.01,
                sd: 0.005
            }
        );
        assert_eq!(d.text(), "hoe.shrinkage=normal(0.01,0.005)");
        let u = DrawSpec::parse("hoe.temperature_change_k=uniform(-10, 30)").unwrap();
        assert_eq!(
            u.dist,
            Dist::Uniform {
                lo: -10.0,
                hi: 30.0
            }
        );
        for (bad, want) in [
            ("hoe.shrinkage", "expected KEY=normal"),
            ("plate.thickness_mm=normal(2,0.1)", "only hoe.* keys"),
            ("hoe.shrinkage=normal(0,-1)", "SD >= 0"),
            ("hoe.shrinkage=uniform(1,0)", "LO <= HI"),
            ("hoe.shrinkage=gauss(0,1)", "unknown distribution"),
            ("hoe.shrinkage=normal(0)", "two finite numbers"),
            ("hoe.shrinkage=normal(0,nan)", "two finite numbers"),
        ] {
            let e = DrawSpec::parse(bad).unwrap_err().to_string();
            assert!(e.starts_with(&format!("--draw {bad}: ")), "{e}");
            assert!(e.contains(want), "{e}");
        }
    }

    /// Draws: zero width gives the mean exactly; moments of 20 000 normal and uniform draws
    /// within 4 standard errors; a draw depends only on (seed, draw, key).
    #[test]
    fn draws_have_their_distribution() {
        let z = DrawSpec::parse("hoe.shrinkage=normal(0.25,0)").unwrap();
        let u0 = DrawSpec::parse("hoe.shrinkage=uniform(0.5,0.5)").unwrap();
        for i in 0..100 {
            assert_eq!(z.sample(3, i, 0), 0.25);
            assert_eq!(u0.sample(3, i, 1), 0.5);
        }
        let n = 20_000;
        let nd = DrawSpec::parse("hoe.shrinkage=normal(1,2)").unwrap();
        let x: Vec<f64> = (0..n).map(|i| nd.sample(7, i, 0)).collect();
        let m = x.iter().sum::<f64>() / n as f64;
        let v = x.iter().map(|a| (a - m) * (a - m)).sum::<f64>() / (n - 1) as f64;
        assert!((m - 1.0).abs() < 4.0 * 2.0 / (n as f64).sqrt(), "{m}");
        assert!(
            (v.sqrt() - 2.0).abs() < 4.0 * 2.0 / (2.0 * n as f64).sqrt(),
            "{v}"
        );
        let ud = DrawSpec::parse("hoe.shrinkage=uniform(-1,3)").unwrap();
        let y: Vec<f64> = (0..n).map(|i| ud.sample(7, i, 1)).collect();
        assert!(y.iter().all(|&a| (-1.0..3.0).contains(&a)));
        let my = y.iter().sum::<f64>() / n as f64;
        assert!((my - 1.0).abs() < 4.0 * (16.0f64 / 12.0).sqrt() / (n as f64).sqrt());
        // Keys draw independently: the two streams are uncorrelated.
        assert!(spearman(&x, &y).abs() < 4.0 / (n as f64).sqrt());
        assert_ne!(nd.sample(7, 5, 0), nd.sample(8, 5, 0));
    }

    #[test]
    fn spearman_and_ranks() {
        assert_eq!(ranks(&[3.0, 1.0, 2.0, 1.0]), vec![4.0, 1.5, 3.0, 1.5]);
        let x = [1.0, 2.0, 3.0, 4.0, 5.0];
        assert!((spearman(&x, &[2.0, 4.0, 9.0, 16.0, 100.0]) - 1.0).abs() < 1e-15);
        assert!((spearman(&x, &[5.0, 4.0, 3.0, 2.0, 1.0]) + 1.0).abs() < 1e-15);
        // Textbook example: d² = 0+1+1+... ρ = 1 − 6Σd²/(n(n²−1)).
        let y = [2.0, 1.0, 4.0, 3.0, 5.0];
        assert!((spearman(&x, &y) - (1.0 - 6.0 * 4.0 / 120.0)).abs() < 1e-12);
        assert_eq!(spearman(&x, &[1.0; 5]), 0.0);
    }
}
