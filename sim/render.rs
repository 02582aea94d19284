//! The image loop: for every crop pixel and sample, a camera ray, a wavelength, one backward
//! path with all its replicas, and the sensor's spectral response.
//!
//! Estimator (DESIGN.md): for channel c the pixel value is
//!   E[ cos⁴θ · S(λ) · R_c(λ)/∫R_c · Σ_branches L_rel(x_b)·(f_TE W_b,TE + f_TM W_b,TM) / p(λ) ]
//! with S the backlight spectrum (mean 1), R_c the sensor response, L_rel the display's relative
//! radiance, W the branch weights of `trace`, f the display's polarisation fractions and p the
//! wavelength density. Unit: 1 = a white display pixel seen by an on-axis pixel through
//! lossless optics with a vanishing aperture (flat spectrum and response); the finite aperture
//! and the field angle add the cos⁴ falloff. Optional spectral channels hold the
//! same estimate without R_c, per nm, binned by wavelength.
//!
//! Parallelism: rows are rendered by rayon and collected in row order; each pixel accumulates
//! its samples in f64 in sample order; the sampler is addressable. The output is therefore
//! bit-identical for any thread count.

use std::ops::ControlFlow;

use rayon::prelude::*;

use crate::sampler::{LatticeRule, PixelSampler, SamplerKind};
use crate::system::System;
use crate::trace::sees_through_n;

/// Uniform fraction of the wavelength density for paths with a straight-through (broadband)
/// view: the Bragg table and the uniform part get equal shares, so f/p stays within a factor of
/// two of the best either alone would give.
pub const BROADBAND_UNIFORM_FRACTION: f64 = 0.5;

/// How a render estimates each pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Estimator {
    /// stscam's estimator: wavelengths importance-sampled around each path's Bragg wavelength,
    /// every replica summed (deterministic splitting).
    Bragg,
    /// What a plain spectral path tracer does, for comparison: wavelengths uniform over the
    /// band, and one analog outcome per path: the polarisation and the branch (or death) are
    /// chosen with their probabilities (Russian roulette at every interaction), and the path
    /// stops at the chosen branch.
    UniformAnalog,
}

/// How the user-side path of a 3-D scene draws the numbers of its first vertex (each light's
/// area sample and the first BSDF direction); every later number is hashed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum UserSideSampler {
    /// Padded 2-D point sets shared by a pixel's samples ([`crate::sampler::padded`]), one per
    /// (branch contact, purpose): the light and BSDF samples of a pixel's first vertices are
    /// stratified. Hashed as well with `SamplerKind::Independent`.
    #[default]
    Padded,
    /// Independent hashed numbers (the only behaviour until 2026-11).
    Hashed,
}

/// Render settings that are not part of the scene.
#[derive(Clone, Debug)]
pub struct RenderSettings {
    /// Samples (camera paths) per pixel.
    pub spp: u32,
    /// Seed of the sampler.
    pub seed: u64,
    /// Sample sequence.
    pub sampler: SamplerKind,
    /// 3-D scenes: how the user side draws the numbers of its first vertex.
    pub user_side: UserSideSampler,
    /// Spectral bins (start nm, bin width nm, count), if spectral output is wanted.
    pub spectral_bins: Option<(f64, f64, usize)>,
    /// Show a progress bar on a terminal.
    pub progress: bool,
}

impl RenderSettings {
    /// The default sequence (lattice), no spectral output: what `matrix`, `demo`, datasets and
    /// sweeps use.
    pub fn lattice(spp: u32, seed: u64, progress: bool) -> RenderSettings {
        RenderSettings {
            spp,
            seed,
            sampler: crate::sampler::SamplerKind::Lattice,
            user_side: Default::default(),
            spectral_bins: None,
            progress,
        }
    }
}

/// Counters gathered over a render (summed in row order).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct RenderStats {
    /// Camera paths traced.
    pub camera_paths: u64,
    /// Branches that reached the display.
    pub branches: u64,
    /// Plate contacts visited.
    pub contacts: u64,
    /// Samples whose value was NaN or infinite (zeroed).
    pub nonfinite_samples: u64,
    /// Paths stopped by `sampling.max_contacts`.
    pub max_contacts_hits: u64,
    /// Largest guided weight truncated by `min_guided_weight` or `max_contacts`.
    pub max_truncated_weight: f64,
    /// Largest branch weight seen (must be ≤ 1).
    pub max_branch_weight: f64,
    /// 3-D scenes: rays traced on the user side (closest-hit and shadow rays).
    #[serde(skip_serializing_if = "is_zero")]
    pub scene_rays: u64,
}

fn is_zero(v: &u64) -> bool {
    *v == 0
}

impl RenderStats {
    /// Adds the counters of `o` (maxima for the max fields).
    pub fn merge(&mut self, o: &RenderStats) {
        self.camera_paths += o.camera_paths;
        self.branches += o.branches;
        self.contacts += o.contacts;
        self.nonfinite_samples += o.nonfinite_samples;
        self.max_contacts_hits += o.max_contacts_hits;
        self.max_truncated_weight = self.max_truncated_weight.max(o.max_truncated_weight);
        self.max_branch_weight = self.max_branch_weight.max(o.max_branch_weight);
        self.scene_rays += o.scene_rays;
    }
}

/// A rendered capture.
#[derive(Clone, Debug)]
pub struct Capture {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Channel names.
    pub channel_names: Vec<&'static str>,
    /// Channel data (row-major, row 0 top).
    pub channels: Vec<Vec<f32>>,
    /// Spectral bin centres (nm) and data, if requested.
    pub spectral: Vec<(f64, Vec<f32>)>,
    /// Counters.
    pub stats: RenderStats,
}

struct RowResult {
    values: Vec<f64>,   // width × channels
    spectral: Vec<f64>, // width × bins
    stats: RenderStats,
}

/// One camera sample ready to trace: the ray, its wavelength and the factor
/// cos⁴θ·S(λ)/p(λ) shared by every branch. Render and matrix draw samples with this one
/// function, so equal seeds give equal samples (the contract H·f = render(f)).
#[derive(Clone, Copy, Debug)]
pub(crate) struct CameraSample {
    pub(crate) ray: crate::camera::CameraRay,
    pub(crate) lambda_nm: f64,
    pub(crate) factor: f64,
    /// The wavelength density p(λ) (3-D scenes use cos⁴θ/p(λ): their emitters carry their own
    /// spectra).
    pub(crate) pdf: f64,
}

/// Camera samples drawn at a time: drawing a sample is a chain of dependent steps (lattice
/// point, ray, Bragg wavelength, plate crossing, table inversion), and drawing several in a
/// row, apart from the tracing, lets the processor overlap their chains.
pub(crate) const SAMPLE_BATCH: usize = 16;

/// Samples `start`, `start + 1`, … of pixel (col, row) into `out` (at most [`SAMPLE_BATCH`]),
/// each `None` when its wavelength falls outside the band. Render and matrix draw samples
/// with this one function, so equal seeds give equal samples (the contract H·f = render(f)).
#[inline]
pub(crate) fn camera_samples(
    sys: &System,
    sampler: &PixelSampler,
    col: usize,
    row: usize,
    start: u64,
    out: &mut [Option<CameraSample>],
) {
    camera_samples_with(sys, sampler, col, row, start, out, Estimator::Bragg);
}

#[inline]
fn camera_samples_with(
    sys: &System,
    sampler: &PixelSampler,
    col: usize,
    row: usize,
    start: u64,
    out: &mut [Option<CameraSample>],
    estimator: Estimator,
) {
    let mut u = [[0.0; crate::sampler::DIMS]; SAMPLE_BATCH];
    let u = &mut u[..out.len()];
    sampler.get_batch(start, u);
    // The glass index of the see-through test is the same for every ray.
    let n0 = sys.waveguide.n_glass(sys.scene.hoe.recording_wavelength_nm);
    for (o, u) in out.iter_mut().zip(u.iter()) {
        *o = camera_sample_at(sys, col, row, u, n0, estimator);
    }
}

/// The sample of lattice point `u` in pixel (col, row); `n0` is the glass index at the
/// recording wavelength.
#[inline(always)]
fn camera_sample_at(
    sys: &System,
    col: usize,
    row: usize,
    u: &[f64; crate::sampler::DIMS],
    n0: f64,
    estimator: Estimator,
) -> Option<CameraSample> {
    let ray = sys
        .camera
        .generate_ray(col, row, [u[0], u[1]], [u[2], u[3]]);
    let lb = sys
        .waveguide
        .grating
        .bragg_wavelength_nm(-ray.dir.truncate());
    // Paths that also see straight through the plate need a broadband wavelength density.
    let fu = if estimator == Estimator::UniformAnalog {
        1.0
    } else if sees_through_n(&sys.waveguide, ray.origin, ray.dir, n0) {
        sys.wavelengths
            .uniform_fraction()
            .max(BROADBAND_UNIFORM_FRACTION)
    } else {
        sys.wavelengths.uniform_fraction()
    };
    let (lambda, pdf) = sys.wavelengths.sample_mixed(u[4], lb, fu);
    if !sys.wavelengths.in_band(lambda) || pdf <= 0.0 {
        return None;
    }
    Some(CameraSample {
        ray,
        lambda_nm: lambda,
        factor: ray.cos4 * sys.display.spectrum.eval(lambda) / pdf,
        pdf,
    })
}

/// Traces one sample, calling `visit` for every branch that reaches the display plane (it may
/// stop the path early), and adds the path's counters to `stats`.
#[inline]
fn trace_counted(
    sys: &System,
    s: &CameraSample,
    stats: &mut RenderStats,
    mut visit: impl FnMut(&crate::trace::Branch) -> ControlFlow<()>,
) {
    let mut max_w: f64 = 0.0;
    let mut branches = 0u64;
    stats.camera_paths += 1;
    let summary = crate::trace::trace_camera_path_until(
        &sys.waveguide,
        sys.display.z_mm,
        sys.limits,
        s.ray.origin,
        s.ray.dir,
        s.lambda_nm,
        |b| {
            branches += 1;
            max_w = max_w.max(b.weight[0]).max(b.weight[1]);
            visit(b)
        },
    );
    stats.branches += branches;
    stats.contacts += u64::from(summary.contacts);
    stats.max_contacts_hits += u64::from(summary.hit_max_contacts);
    stats.max_truncated_weight = stats.max_truncated_weight.max(summary.truncated_weight);
    stats.max_branch_weight = stats.max_branch_weight.max(max_w);
}

/// Traces one sample and calls `visit(weight, object_point)` for every branch that reaches the
/// display plane, with the weight already averaged over the display's polarisation.
#[inline]
pub(crate) fn trace_sample(
    sys: &System,
    s: &CameraSample,
    stats: &mut RenderStats,
    mut visit: impl FnMut(f64, glam::DVec2),
) {
    trace_branches(sys, s, stats, |wt, b| visit(wt, b.object_point_mm));
}

/// As [`trace_sample`], but `visit(weight, branch)` gets the whole branch (its front-face exit
/// point meets any other object plane along the camera ray's direction).
#[inline]
pub(crate) fn trace_branches(
    sys: &System,
    s: &CameraSample,
    stats: &mut RenderStats,
    mut visit: impl FnMut(f64, &crate::trace::Branch),
) {
    let pol = sys.display.polarization_weights;
    trace_counted(sys, s, stats, |b| {
        let wt = pol[0] * b.weight[0] + pol[1] * b.weight[1];
        if wt > 0.0 {
            visit(wt, b);
        }
        ControlFlow::Continue(())
    });
}

/// Branches below this fraction of a path's strongest branch are traced on the user side only
/// with probability (weight / (this × strongest)) and weighted up by its inverse (Russian
/// roulette over branches: unbiased, and most of a path's weak replicas cost nothing).
pub const BRANCH_ROULETTE_FRACTION: f64 = 0.25;

/// Traces one branch's exit ray (front-face exit point, the camera ray's direction) on the
/// user side and counts its rays.
fn trace_exit(
    sys: &System,
    world: &crate::world::World,
    s: &CameraSample,
    exit: glam::DVec2,
    rng: &mut crate::world::integrator::PathRng,
    stats: &mut RenderStats,
) -> crate::world::integrator::Radiance {
    let mut counts = crate::world::integrator::PathCounts::default();
    let l = world.radiance(
        &sys.display,
        crate::world::integrator::exit_point(exit),
        s.ray.dir,
        s.lambda_nm,
        rng,
        &mut counts,
    );
    stats.scene_rays += counts.rays;
    l
}

/// The analog choice of a path's outcome: the branch whose cumulative weight in polarisation
/// state `pol` first exceeds `u` (the branch weights are outcome probabilities, summing to
/// ≤ 1), or none (the path dies). The path stops at the chosen branch.
fn choose_branch(
    sys: &System,
    s: &CameraSample,
    pol: usize,
    u: f64,
    stats: &mut RenderStats,
) -> Option<crate::trace::Branch> {
    let mut cum = 0.0;
    let mut chosen = None;
    trace_counted(sys, s, stats, |b| {
        cum += b.weight[pol];
        debug_assert!(cum <= 1.0 + 1e-9, "branch weights sum to {cum}");
        if u < cum {
            chosen = Some(*b);
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    chosen
}

/// Radiance a sample collects from a 3-D scene: every branch's exit ray (front-face exit
/// point, the camera ray's direction) traced on the user side with its own random stream,
/// weighted by the branch's TE/TM weights (the display's polarisation for the display seen
/// directly, unpolarised for the rest). Weak branches go through Russian roulette
/// ([`BRANCH_ROULETTE_FRACTION`]). Kept out of line so the display-only loop stays as tight as
/// it was.
#[inline(never)]
fn world_sample(
    sys: &System,
    world: &crate::world::World,
    s: &CameraSample,
    key: [u64; 3],
    padded_n: Option<u32>,
    stats: &mut RenderStats,
) -> f64 {
    use crate::world::integrator::{PathRng, branch_weights};
    let pol = sys.display.polarization_weights;
    let mut branches: Vec<(glam::DVec2, [f64; 2], u32)> = Vec::with_capacity(16);
    trace_counted(sys, s, stats, |b| {
        if b.weight[0] > 0.0 || b.weight[1] > 0.0 {
            branches.push((b.exit_point_mm, b.weight, b.contact));
        }
        ControlFlow::Continue(())
    });
    let strongest = branches.iter().map(|b| b.1[0] + b.1[1]).fold(0.0, f64::max);
    let threshold = BRANCH_ROULETTE_FRACTION * strongest;
    let mut total = 0.0;
    for (exit, weight, contact) in branches {
        let mut rng = PathRng::new(&[key[0], key[1], key[2], u64::from(contact)]);
        if let Some(n) = padded_n {
            // One padded set per (seed, pixel, branch contact), shared by the pixel's samples.
            let pad_key = PathRng::padded_key(&[key[0], key[1], u64::from(contact)]);
            rng = rng.with_padded(pad_key, key[2], n);
        }
        let w = weight[0] + weight[1];
        let keep = if w < threshold { w / threshold } else { 1.0 };
        if keep < 1.0 && rng.single(crate::world::integrator::ROULETTE_SLOT) >= keep {
            continue;
        }
        let l = trace_exit(sys, world, s, exit, &mut rng, stats);
        let (wd, wo) = branch_weights(weight, pol);
        total += (wd * l.display + wo * l.other) / keep;
    }
    total
}

/// The plain path tracer's version of [`world_sample`]: one polarisation state (TE or TM,
/// even odds) and one branch (or none) chosen with their probabilities, as [`trace_analog`]
/// does, and only that branch traced on the user side. Unpolarised light then has the right
/// expectation; the display seen directly is weighted by 2·f_state for its polarisation.
#[inline(never)]
fn world_sample_analog(
    sys: &System,
    world: &crate::world::World,
    s: &CameraSample,
    key: [u64; 3],
    stats: &mut RenderStats,
) -> f64 {
    let mut rng = crate::world::integrator::PathRng::new(&[key[0], key[1], key[2], 0x00A4_A106]);
    let (u_pol, u_branch) = (rng.uniform(), rng.uniform());
    let pol = usize::from(u_pol >= 0.5);
    let Some(b) = choose_branch(sys, s, pol, u_branch, stats) else {
        return 0.0;
    };
    let l = trace_exit(sys, world, s, b.exit_point_mm, &mut rng, stats);
    2.0 * sys.display.polarization_weights[pol] * l.display + l.other
}

/// One analog outcome of a sample: the polarisation and the branch (or none: the path dies)
/// drawn with their probabilities; returns the display radiance the path reaches (weight 1).
fn trace_analog(
    sys: &System,
    s: &CameraSample,
    seed: u64,
    pixel: u64,
    i: u64,
    stats: &mut RenderStats,
) -> f64 {
    let h = crate::sampler::hash(&[seed, pixel, i, 0x00A4_A106]);
    let (u_pol, u_branch) = (
        crate::sampler::to_unit(h),
        crate::sampler::to_unit(crate::sampler::mix64(h)),
    );
    let pol = usize::from(u_pol >= sys.display.polarization_weights[0]);
    choose_branch(sys, s, pol, u_branch, stats)
        .map_or(0.0, |b| sys.display.radiance_at(b.object_point_mm))
}

/// Per-channel spectral weights R_c(λ)/∫R_c of the sensor response.
#[inline]
pub(crate) fn channel_weights(sys: &System, lambda_nm: f64) -> [f64; 4] {
    let mut r = [0.0; 4];
    for (c, w) in r.iter_mut().enumerate().take(sys.response.curves.len()) {
        *w = sys.response.curves[c].eval(lambda_nm) * sys.response.inv_integral[c];
    }
    r
}

/// The lattice rule of a render (searched once; it depends only on the sample count).
pub(crate) fn lattice_rule(set: &RenderSettings) -> Option<LatticeRule> {
    match set.sampler {
        SamplerKind::Lattice => LatticeRule::korobov(u64::from(set.spp)),
        SamplerKind::R5 | SamplerKind::Independent | SamplerKind::Sobol => None,
    }
}

/// Progress over `len` rows (a bar on a terminal, plain lines otherwise), hidden unless
/// `show`.
pub(crate) fn row_progress(show: bool, len: usize, what: &str) -> crate::progress::Progress {
    crate::progress::Progress::new(show, len as u64, what)
}

/// Checks the run time and memory of `renders` renders of `sys` with `set` against
/// [`crate::limits`] before any work starts: camera paths (crop pixels × spp × renders,
/// blamed on `spp_setting`, the flag or key that set `set.spp`) and the capture's arrays
/// (per value: the row result in f64, the f32 image and its encoded copy, 16 bytes).
pub fn check_limits(
    sys: &System,
    set: &RenderSettings,
    renders: u64,
    spp_setting: &str,
) -> Result<(), crate::limits::LimitError> {
    let (w, h) = (sys.camera.width_px, sys.camera.height_px);
    let pixels = w as u128 * h as u128;
    crate::limits::check_paths(
        spp_setting,
        pixels * u128::from(set.spp) * u128::from(renders),
    )?;
    let values = (sys.response.curves.len() + set.spectral_bins.map_or(0, |b| b.2)) as u128;
    crate::limits::check_bytes(
        "sensor.crop_px",
        &format!("the capture ({w}x{h} px, {values} channels and spectral bins)"),
        pixels * values * 16,
    )
}

fn render_row(
    sys: &System,
    set: &RenderSettings,
    estimator: Estimator,
    rule: Option<LatticeRule>,
    row: usize,
) -> RowResult {
    let disp = &sys.display;
    // One monomorphised loop per kind of sample value: the display-only loop is the tight one
    // it always was.
    match (sys.world.as_deref(), estimator) {
        (Some(world), Estimator::Bragg) => {
            let padded_n = (set.user_side == UserSideSampler::Padded
                && set.sampler != SamplerKind::Independent)
                .then_some(set.spp);
            render_row_with(sys, set, estimator, rule, row, |s, pixel, i, stats| {
                let v = world_sample(sys, world, s, [set.seed, pixel, i], padded_n, stats);
                s.ray.cos4 * v / s.pdf
            })
        }
        (Some(world), Estimator::UniformAnalog) => {
            render_row_with(sys, set, estimator, rule, row, |s, pixel, i, stats| {
                s.ray.cos4 * world_sample_analog(sys, world, s, [set.seed, pixel, i], stats) / s.pdf
            })
        }
        (None, Estimator::Bragg) => {
            render_row_with(sys, set, estimator, rule, row, |s, _, _, stats| {
                let mut radiance = 0.0;
                trace_sample(sys, s, stats, |wt, x| {
                    radiance += wt * disp.radiance_at(x);
                });
                s.factor * radiance
            })
        }
        (None, Estimator::UniformAnalog) => {
            render_row_with(sys, set, estimator, rule, row, |s, pixel, i, stats| {
                s.factor * trace_analog(sys, s, set.seed, pixel, i, stats)
            })
        }
    }
}

/// The pixel loop of one row; `value(sample, pixel, index, stats)` gives a sample's value
/// before the sensor response.
#[inline(always)]
fn render_row_with(
    sys: &System,
    set: &RenderSettings,
    estimator: Estimator,
    rule: Option<LatticeRule>,
    row: usize,
    mut value: impl FnMut(&CameraSample, u64, u64, &mut RenderStats) -> f64,
) -> RowResult {
    let w = sys.camera.width_px;
    let nch = sys.response.curves.len();
    let nbins = set.spectral_bins.map_or(0, |b| b.2);
    let mut values = vec![0.0; w * nch];
    let mut spectral = vec![0.0; w * nbins];
    let mut stats = RenderStats::default();
    for col in 0..w {
        let pixel = (row * w + col) as u64;
        let sampler = PixelSampler::new(set.sampler, set.seed, pixel).with_rule(rule);
        let mut acc = [0.0f64; 4];
        let spp = u64::from(set.spp);
        let mut batch = [None; SAMPLE_BATCH];
        let mut first = 0u64;
        while first < spp {
            let len = (spp - first).min(SAMPLE_BATCH as u64) as usize;
            camera_samples_with(sys, &sampler, col, row, first, &mut batch[..len], estimator);
            for (i, s) in (first..).zip(&batch[..len]) {
                let Some(s) = s else {
                    continue;
                };
                let base = value(s, pixel, i, &mut stats);
                if !base.is_finite() {
                    stats.nonfinite_samples += 1;
                    continue;
                }
                let r = channel_weights(sys, s.lambda_nm);
                for (a, rc) in acc.iter_mut().zip(r).take(nch) {
                    *a += base * rc;
                }
                if let Some((start, width, n)) = set.spectral_bins {
                    let k = ((s.lambda_nm - start) / width).floor();
                    if k >= 0.0 && (k as usize) < n {
                        spectral[col * nbins + k as usize] += base / width;
                    }
                }
            }
            first += len as u64;
        }
        let inv = 1.0 / f64::from(set.spp.max(1));
        for c in 0..nch {
            values[col * nch + c] = acc[c] * inv;
        }
        for v in &mut spectral[col * nbins..(col + 1) * nbins] {
            *v *= inv;
        }
    }
    RowResult {
        values,
        spectral,
        stats,
    }
}

/// The spectral bins of `render --spectral`: about 10 nm wide, tiling the sampled band exactly,
/// as (start nm, width nm, count) for [`RenderSettings::spectral_bins`].
pub fn spectral_bins(sm: &crate::scene::SamplingDesc) -> (f64, f64, usize) {
    let band = sm.lambda_max_nm - sm.lambda_min_nm;
    let n = (band / 10.0).round().max(1.0) as usize;
    (sm.lambda_min_nm, band / n as f64, n)
}

/// Renders the capture of `sys`. Deterministic for a given seed, whatever the thread count.
pub fn render(sys: &System, set: &RenderSettings) -> Capture {
    render_with(sys, set, Estimator::Bragg)
}

/// Renders with a chosen estimator (both are unbiased; they differ in variance and cost).
pub fn render_with(sys: &System, set: &RenderSettings, estimator: Estimator) -> Capture {
    let cam = &sys.camera;
    let (w, h) = (cam.width_px, cam.height_px);
    let pb = row_progress(set.progress, h, "rendering rows");
    let rule = lattice_rule(set);
    let cancel = crate::cancel::current();
    let nch = sys.response.curves.len();
    let nbins = set.spectral_bins.map_or(0, |b| b.2);
    let rows: Vec<RowResult> = (0..h)
        .into_par_iter()
        .map(|row| {
            if cancel.is_cancelled() {
                return RowResult {
                    values: vec![0.0; w * nch],
                    spectral: vec![0.0; w * nbins],
                    stats: RenderStats::default(),
                };
            }
            let r = render_row(sys, set, estimator, rule, row);
            pb.inc(1);
            r
        })
        .collect();
    pb.finish_and_clear();
    let mut channels = vec![vec![0f32; w * h]; nch];
    let mut spec = vec![vec![0f32; w * h]; nbins];
    let mut stats = RenderStats::default();
    for (row, r) in rows.iter().enumerate() {
        stats.merge(&r.stats);
        for col in 0..w {
            for (c, ch) in channels.iter_mut().enumerate() {
                ch[row * w + col] = r.values[col * nch + c] as f32;
            }
            for (b, sb) in spec.iter_mut().enumerate() {
                sb[row * w + col] = r.spectral[col * nbins + b] as f32;
            }
        }
    }
    let spectral = match set.spectral_bins {
        Some((start, width, n)) => (0..n)
            .map(|k| start + (k as f64 + 0.5) * width)
            .zip(spec)
            .collect(),
        None => Vec::new(),
    };
    Capture {
        width: w,
        height: h,
        channel_names: sys.response.names.clone(),
        channels,
        spectral,
        stats,
    }
}

/// Relative RMSE ‖a − b‖₂/‖b‖₂ over all pixels of the given (a, b) channel pairs, summed in
/// order in f64 (b is the reference).
pub fn relative_rmse(pairs: &[(&[f32], &[f32])]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (a, b) in pairs {
        for (x, y) in a.iter().zip(b.iter()) {
            let (x, y) = (f64::from(*x), f64::from(*y));
            num += (x - y) * (x - y);
            den += y * y;
        }
    }
    if den > 0.0 {
        (num / den).sqrt()
    } else {
        f64::NAN
    }
}
