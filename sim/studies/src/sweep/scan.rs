//! Evaluating a sweep: the field response T(d) and its scans, the FOV edges and what limits
//! them, the scene field, the design figures of one system, the PSNR protocol, and the grid
//! of scene-key values that `run_sweep` builds and evaluates point by point (definitions in
//! the module header of `sweep`).

use std::path::Path;
use std::time::Instant;

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::figures::encode_outputs;
use super::{
    BOTTOM_CONTACT_LIMITER, CROP_LIMITER, DesignFigures, FALLOFF_LIMITER, GratingFigures,
    MAX_POINTS, PsnrSettings, REPLICA_FRACTION, ResponseGrid, SCAN_LIMITER, SPECTRUM_LIMITER,
    SceneField, SweepError, SweepOutput, SweepRow, SweepSettings, TOP_RECOUPLING_LIMITER,
    VariedValue, VaryAxis,
};
use crate::analysis::{self, Fov, FovEdge, crop_field_range_deg, field_blocker, field_direction};
use crate::scene::{SceneError, SceneSource};
use crate::system::System;
use crate::trace::{BranchKind, trace_camera_path};

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

/// The demo settings that give the sweep's PSNR protocol.
pub fn psnr_demo_settings(p: &PsnrSettings, progress: bool) -> crate::capture::DemoSettings {
    crate::capture::DemoSettings {
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
    // A colour display's object is three planes (H's column blocks); the target is grey in
    // each unless it has colour of its own.
    let (_, _, truth) =
        crate::capture::planes_of_spec(&spec, sys.scene.display.gamma, sys.display.planes())
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
    crate::capture::object_problem(sys, &m.h)
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
    let set = psnr_demo_settings(p, progress);
    let m = crate::matrix::compute_matrix(
        sys,
        &crate::render::RenderSettings::lattice(p.spp, p.seed, progress),
    );
    let (noise, dark) = crate::capture::exposure_and_dark(sys, &m, p.seed);
    let (_, g) = crate::capture::measured_capture(sys, &truth, &set, &noise, &dark, 0);
    let problem = crate::capture::object_problem(sys, &m.h);
    // τ by the discrepancy principle on the sensor noise, as the demo's table chooses it.
    let black = crate::capture::black_level_of(&dark, &noise);
    let solve = |pr: &crate::recon::Problem| {
        let level = crate::recon::discrepancy::NoiseLevel::of_capture(pr, &g, &black, true, &noise);
        let htg = pr.back_project(&g);
        let f = crate::recon::discrepancy::admm_tv_discrepancy(pr, &htg, &level, &set.admm)
            .result
            .f;
        crate::recon::metrics::psnr(&f, &truth)
    };
    let stale = nominal
        .filter(|n| n.width == problem.width && n.height == problem.height && n.ht.cols == g.len())
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
