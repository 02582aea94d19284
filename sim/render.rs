//! The image loop: for every crop pixel and sample, a camera ray, a wavelength, one backward
//! path with all its replicas, and the sensor's spectral response.
//!
//! Estimator (docs/design.md): for channel c the pixel value is
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

/// How a 3-D scene's user side is sampled: which branches get a user-side path, and how the
/// path draws the numbers of its first vertex (each light's area sample and the first BSDF
/// direction; every later number is hashed).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum UserSideSampler {
    /// The default: `Resampled`, except in scenes with emissive meshes, where the camera sees
    /// emission whose texture varies within a replica's branches as they spread over a pixel,
    /// and drawing among them adds more noise than the shared paths save (`Padded` there).
    /// [`Self::resolve`] gives the choice for a scene.
    #[default]
    Auto,
    /// The pixel's branches share user-side paths (the default, through `Auto`): every camera
    /// sample's branches are gathered per replica (plate contact), and each replica's sum is
    /// estimated from paths traced from branches chosen in proportion to their weight, about
    /// [`USER_SIDE_PATHS_PER_SAMPLE`] paths per camera sample in all, allotted to replicas by
    /// weight (the estimator is described at `render_pixel_resampled`). First-vertex numbers as
    /// `Padded`, over a replica's paths.
    Resampled,
    /// Every branch of every camera sample traced (weak ones through Russian roulette), with
    /// padded 2-D point sets shared by a pixel's samples ([`crate::sampler::padded`]), one per
    /// (branch contact, purpose): the light and BSDF samples of a pixel's first vertices are
    /// stratified. Hashed as well with `SamplerKind::Independent`.
    Padded,
    /// As `Padded` with independent hashed numbers (kept for the benchmark's earlier curve;
    /// CHANGELOG.md).
    Hashed,
}

impl UserSideSampler {
    /// The estimator used for `world` (`Auto` resolved; the others as they are).
    pub fn resolve(self, world: Option<&crate::world::World>) -> UserSideSampler {
        match self {
            UserSideSampler::Auto => {
                if world.is_some_and(|w| w.materials.iter().any(|m| m.emits())) {
                    UserSideSampler::Padded
                } else {
                    UserSideSampler::Resampled
                }
            }
            other => other,
        }
    }
}

/// User-side paths per camera sample of [`UserSideSampler::Resampled`], on average over a
/// pixel (eye-contact scene, 128 × 128, 128 spp, error² × time: 0.6 → 7.5, 1 → 6.8,
/// 1.5 → 7.3).
pub const USER_SIDE_PATHS_PER_SAMPLE: f64 = 1.0;

/// [`UserSideSampler::Resampled`] gathers at most about this many branches before it traces
/// their user side (a pixel with more is done in windows of whole camera samples), bounding
/// its memory whatever the spp and the contact limit.
pub const RESAMPLE_WINDOW_BRANCHES: usize = 16_384;

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
    /// 3-D scenes: user-side paths traced (one per traced branch).
    #[serde(skip_serializing_if = "is_zero")]
    pub scene_paths: u64,
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
        self.scene_paths += o.scene_paths;
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
    let n0 = sys.waveguide.n_glass(sys.scene.hoe.primary_wavelength_nm());
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
    let gratings = &sys.waveguide.gratings;
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
    let (lambda, pdf) = if gratings.len() == 1 {
        // One grating: its Bragg wavelength and the single-band density, as always.
        let lb = gratings.film().bragg_wavelength_nm(-ray.dir.truncate());
        sys.wavelengths.sample_mixed(u[4], lb, fu)
    } else {
        // Each grating's Bragg wavelength for this ray (the density's components).
        let lb = gratings.bragg_wavelengths_nm(-ray.dir.truncate());
        sys.wavelengths.sample_multiplexed(u[4], &lb, fu)
    };
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
    stats.scene_paths += 1;
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
    // (exit point, weight, replica key (grating, contact)).
    let mut branches: Vec<(glam::DVec2, [f64; 2], u64)> = Vec::with_capacity(16);
    trace_counted(sys, s, stats, |b| {
        if b.weight[0] > 0.0 || b.weight[1] > 0.0 {
            branches.push((b.exit_point_mm, b.weight, b.replica_key()));
        }
        ControlFlow::Continue(())
    });
    let strongest = branches.iter().map(|b| b.1[0] + b.1[1]).fold(0.0, f64::max);
    let threshold = BRANCH_ROULETTE_FRACTION * strongest;
    let mut total = 0.0;
    for (exit, weight, replica) in branches {
        let mut rng = PathRng::new(&[key[0], key[1], key[2], replica]);
        if let Some(n) = padded_n {
            // One padded set per (seed, pixel, replica (grating, contact)), shared by the
            // pixel's samples.
            let pad_key = PathRng::padded_key(&[key[0], key[1], replica]);
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
    choose_branch(sys, s, pol, u_branch, stats).map_or(0.0, |b| {
        let w = sys.display.primary_weights(s.lambda_nm);
        sys.display.radiance_weighted_at(b.object_point_mm, &w)
    })
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
        (Some(world), Estimator::Bragg) if set.user_side == UserSideSampler::Resampled => {
            render_row_resampled(sys, set, world, rule, row, RESAMPLE_WINDOW_BRANCHES)
        }
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
        (None, Estimator::Bragg) if disp.primaries.is_some() => {
            // Colour primaries: the shares of white at the sample's wavelength, once per sample.
            render_row_with(sys, set, estimator, rule, row, |s, _, _, stats| {
                let w = disp.primary_weights(s.lambda_nm);
                let mut radiance = 0.0;
                trace_sample(sys, s, stats, |wt, x| {
                    radiance += wt * disp.radiance_weighted_at(x, &w);
                });
                s.factor * radiance
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
    row_of_pixels(sys, set, |col, px_spectral, stats| {
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
                let base = value(s, pixel, i, stats);
                add_sample(sys, set, &mut acc, px_spectral, base, s.lambda_nm, stats);
            }
            first += len as u64;
        }
        acc
    })
}

/// A row from `pixel(col, spectral bins, stats)`, which returns the pixel's channel sums over
/// its samples and adds its spectral sums into the bins.
#[inline(always)]
fn row_of_pixels(
    sys: &System,
    set: &RenderSettings,
    mut pixel: impl FnMut(usize, &mut [f64], &mut RenderStats) -> [f64; 4],
) -> RowResult {
    let (nch, nbins) = row_layout(sys, set);
    let mut r = empty_row(sys, set);
    for col in 0..sys.camera.width_px {
        let px_spectral = &mut r.spectral[col * nbins..(col + 1) * nbins];
        let acc = pixel(col, px_spectral, &mut r.stats);
        finish_pixel(
            set,
            acc,
            &mut r.values[col * nch..(col + 1) * nch],
            px_spectral,
        );
    }
    r
}

/// Values per pixel of a row: (sensor channels, spectral bins).
fn row_layout(sys: &System, set: &RenderSettings) -> (usize, usize) {
    (
        sys.response.curves.len(),
        set.spectral_bins.map_or(0, |b| b.2),
    )
}

/// A row of zeros (no counts).
fn empty_row(sys: &System, set: &RenderSettings) -> RowResult {
    let (nch, nbins) = row_layout(sys, set);
    let w = sys.camera.width_px;
    RowResult {
        values: vec![0.0; w * nch],
        spectral: vec![0.0; w * nbins],
        stats: RenderStats::default(),
    }
}

/// Adds a sample's value `base` (before the sensor response) at `lambda_nm` to a pixel's
/// channel sums `acc` and spectral bins `px_spectral`; a non-finite value is counted and
/// dropped.
#[inline(always)]
fn add_sample(
    sys: &System,
    set: &RenderSettings,
    acc: &mut [f64; 4],
    px_spectral: &mut [f64],
    base: f64,
    lambda_nm: f64,
    stats: &mut RenderStats,
) {
    if !base.is_finite() {
        stats.nonfinite_samples += 1;
        return;
    }
    let r = channel_weights(sys, lambda_nm);
    for (a, rc) in acc.iter_mut().zip(r).take(sys.response.curves.len()) {
        *a += base * rc;
    }
    if let Some((start, width, n)) = set.spectral_bins {
        let k = ((lambda_nm - start) / width).floor();
        if k >= 0.0 && (k as usize) < n {
            px_spectral[k as usize] += base / width;
        }
    }
}

/// A pixel's values from its sums over `set.spp` samples.
fn finish_pixel(
    set: &RenderSettings,
    acc: [f64; 4],
    px_values: &mut [f64],
    px_spectral: &mut [f64],
) {
    let inv = 1.0 / f64::from(set.spp.max(1));
    for (v, a) in px_values.iter_mut().zip(acc) {
        *v = a * inv;
    }
    for v in px_spectral {
        *v *= inv;
    }
}

/// One branch of a pixel's camera samples waiting for its user side
/// ([`UserSideSampler::Resampled`]).
#[derive(Clone, Copy, Debug)]
struct PendingBranch {
    /// The branch's replica, (grating, plate contact) as [`crate::trace::Branch::replica_key`].
    replica: u64,
    /// Its camera sample's index in [`Window::samples`] (the samples in order).
    sample: u32,
    /// Front-face exit point, mm.
    exit: glam::DVec2,
    /// Energy fractions [TE, TM].
    weight: [f64; 2],
    /// Selection weight: the branch's weight to the sensor, ½(w_TE + w_TM)·cos⁴θ/p(λ)·Σ_c R_c(λ)
    /// (without the response sum when spectral bins are written, which do not use it).
    sel: f64,
}

/// The camera samples of a window of a pixel and their branches waiting for the user side.
#[derive(Default)]
struct Window {
    samples: Vec<CameraSample>,
    branches: Vec<PendingBranch>,
}

/// Tag of the resampled user side's random streams (keeps them apart from the per-branch ones).
const RESAMPLED_TAG: u64 = 0x5E5A_4D91_ED00_0000;

/// The row loop of [`UserSideSampler::Resampled`], with windows of about `window_branches`
/// branches.
fn render_row_resampled(
    sys: &System,
    set: &RenderSettings,
    world: &crate::world::World,
    rule: Option<LatticeRule>,
    row: usize,
    window_branches: usize,
) -> RowResult {
    let mut pending = Window::default();
    row_of_pixels(sys, set, |col, px_spectral, stats| {
        render_pixel_resampled(
            sys,
            set,
            world,
            rule,
            (col, row, window_branches),
            &mut pending,
            px_spectral,
            stats,
        )
    })
}

/// One pixel of [`UserSideSampler::Resampled`]: the channel sums over its samples (spectral
/// bins added into `px_spectral`), its branches traced in windows of whole camera samples
/// holding at least `window_branches` branches (the last one fewer).
///
/// Estimator. The pixel's sum is Σ_i Σ_b v_ib·L_ib over camera samples i and their branches b,
/// where v_ib (the branch's TE/TM weights, cos⁴θ/p(λ) and the channel responses at λ_i) comes
/// from the cheap waveguide trace and L_ib (the radiance arriving along the branch's exit ray)
/// from an expensive user-side path. Each sample's branches are gathered per replica
/// (grating and plate contact c); replica c's sum Σ_j v_j·L_j over its G_c branches, of total selection
/// weight S_c = Σ_j s_j, is estimated from K_c user-side paths traced from branches drawn by
/// systematic resampling in proportion to s_j (one uniform offset, the branches in sample
/// order): (S_c/K_c)·Σ_k v_jk·L̂_jk/s_jk. Systematic resampling draws branch j K_c·s_j/S_c times
/// in expectation (Douc, Cappé & Moulines 2005, "Comparison of resampling schemes for particle
/// filtering"), and each L̂ is an independent unbiased path estimate, so the estimate is
/// unbiased for any K_c fixed by the branches. Paths are allotted by weight,
/// K_c = round(τ·N·S_c/Σ S) for τ = [`USER_SIDE_PATHS_PER_SAMPLE`] and N camera samples;
/// a replica with τ·N·S_c/ΣS = q < 1 is traced once with probability q and weighted 1/q
/// (Russian roulette). Why it pays: every camera sample still contributes its exact branch
/// weights (the replica edges, the Bragg selectivity and the pixel footprint are integrated
/// with all N samples), while the user side, about 85 % of a sample's cost, is sampled only as
/// often as its own noise needs; branches of one replica in one pixel see nearly the same
/// radiance, so drawing among them adds little. The first-vertex numbers of a replica's paths
/// come from padded sets over its K_c paths (as [`UserSideSampler::Padded`], unless the
/// sampler is independent).
#[allow(clippy::too_many_arguments)]
fn render_pixel_resampled(
    sys: &System,
    set: &RenderSettings,
    world: &crate::world::World,
    rule: Option<LatticeRule>,
    (col, row, window_branches): (usize, usize, usize),
    pending: &mut Window,
    px_spectral: &mut [f64],
    stats: &mut RenderStats,
) -> [f64; 4] {
    let w = sys.camera.width_px;
    let nch = sys.response.curves.len();
    let pixel = (row * w + col) as u64;
    let sampler = PixelSampler::new(set.sampler, set.seed, pixel).with_rule(rule);
    let mut acc = [0.0f64; 4];
    let spp = u64::from(set.spp);
    let mut batch = [None; SAMPLE_BATCH];
    let ctx = PixelContext {
        sys,
        set,
        world,
        pixel,
    };
    pending.samples.clear();
    pending.branches.clear();
    let mut window = (0u64, 0u64);
    let mut first = 0u64;
    while first < spp {
        let len = (spp - first).min(SAMPLE_BATCH as u64) as usize;
        camera_samples_with(
            sys,
            &sampler,
            col,
            row,
            first,
            &mut batch[..len],
            Estimator::Bragg,
        );
        for (i, s) in (first..).zip(&batch[..len]) {
            if let Some(s) = s {
                let response = if set.spectral_bins.is_some() {
                    1.0
                } else {
                    channel_weights(sys, s.lambda_nm).iter().take(nch).sum()
                };
                let sel_scale = s.ray.cos4 / s.pdf * response;
                let sample = pending.samples.len() as u32;
                pending.samples.push(*s);
                trace_counted(sys, s, stats, |b| {
                    let sel = 0.5 * (b.weight[0] + b.weight[1]) * sel_scale;
                    if sel > 0.0 && sel.is_finite() {
                        pending.branches.push(PendingBranch {
                            replica: b.replica_key(),
                            sample,
                            exit: b.exit_point_mm,
                            weight: b.weight,
                            sel,
                        });
                    }
                    ControlFlow::Continue(())
                });
            }
            window.1 = i + 1;
            if pending.branches.len() >= window_branches {
                trace_window(&ctx, window, pending, &mut acc, px_spectral, stats);
                window.0 = window.1;
            }
        }
        first += len as u64;
    }
    trace_window(&ctx, window, pending, &mut acc, px_spectral, stats);
    acc
}

/// What [`trace_window`] needs to know of the render and the pixel.
struct PixelContext<'a> {
    sys: &'a System,
    set: &'a RenderSettings,
    world: &'a crate::world::World,
    pixel: u64,
}

/// Traces the user side of the branches gathered from camera samples `window` (start, end) of
/// the pixel (see [`render_pixel_resampled`]), adds them to `acc` and `px_spectral`, and
/// empties `pending`.
fn trace_window(
    ctx: &PixelContext,
    window: (u64, u64),
    pending: &mut Window,
    acc: &mut [f64; 4],
    px_spectral: &mut [f64],
    stats: &mut RenderStats,
) {
    use crate::world::integrator::{PathRng, branch_weights};
    let PixelContext {
        sys,
        set,
        world,
        pixel,
    } = *ctx;
    let Window { samples, branches } = pending;
    if branches.is_empty() {
        samples.clear();
        return;
    }
    branches.sort_unstable_by_key(|p| (p.replica, p.sample));
    let total: f64 = branches.iter().map(|p| p.sel).sum();
    let paths = USER_SIDE_PATHS_PER_SAMPLE * (window.1 - window.0) as f64;
    let pol = sys.display.polarization_weights;
    let padded = set.sampler != SamplerKind::Independent;
    for group in branches.chunk_by(|a, b| a.replica == b.replica) {
        // The replica's key (grating, contact); the contact alone for grating 0.
        let contact = group[0].replica;
        let s_c: f64 = group.iter().map(|p| p.sel).sum();
        let q = paths * s_c / total;
        let h = crate::sampler::hash(&[set.seed, pixel, RESAMPLED_TAG ^ window.0, contact]);
        // K paths, each standing for S_c/K_eff of selection weight.
        let (k, k_eff) = if q >= 1.0 {
            let k = q.round() as u64;
            (k, k as f64)
        } else if crate::sampler::to_unit(h) < q {
            (1, q)
        } else {
            continue;
        };
        let offset = crate::sampler::to_unit(crate::sampler::mix64(h));
        let pad_key = PathRng::padded_key(&[set.seed, pixel, contact, RESAMPLED_TAG ^ window.0]);
        let step = s_c / k as f64;
        let mut j = 0;
        let mut cum = group[0].sel;
        for kk in 0..k {
            // Systematic resampling: the branch whose cumulative weight passes (kk + offset)·step.
            let t = (kk as f64 + offset) * step;
            while cum <= t && j + 1 < group.len() {
                j += 1;
                cum += group[j].sel;
            }
            let p = &group[j];
            let s = &samples[p.sample as usize];
            let mut rng = PathRng::new(&[set.seed, pixel, RESAMPLED_TAG ^ window.0, contact, kk]);
            if padded && k <= u64::from(u32::MAX) {
                rng = rng.with_padded(pad_key, kk, k as u32);
            }
            let l = trace_exit(sys, world, s, p.exit, &mut rng, stats);
            let (wd, wo) = branch_weights(p.weight, pol);
            let base = (s_c / k_eff) * (wd * l.display + wo * l.other) / p.sel * s.ray.cos4 / s.pdf;
            add_sample(sys, set, acc, px_spectral, base, s.lambda_nm, stats);
        }
    }
    samples.clear();
    branches.clear();
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
    // `Auto` resolved once for the scene: the rows see the user side's estimator itself.
    let set = &RenderSettings {
        user_side: set.user_side.resolve(sys.world.as_deref()),
        ..set.clone()
    };
    let cam = &sys.camera;
    let (w, h) = (cam.width_px, cam.height_px);
    let pb = row_progress(set.progress, h, "rendering rows");
    let rule = lattice_rule(set);
    let cancel = crate::cancel::current();
    let (nch, nbins) = row_layout(sys, set);
    let rows: Vec<RowResult> = (0..h)
        .into_par_iter()
        .map(|row| {
            if cancel.is_cancelled() {
                return empty_row(sys, set);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Mean and standard error of the mean.
    fn mean_sem(v: &[f64]) -> (f64, f64) {
        let n = v.len() as f64;
        let m = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
        (m, (var / n).sqrt())
    }

    /// Windows of a few samples (what bounds the resampled user side's memory at high spp)
    /// keep the estimate's expectation: the eye-contact scene's rows rendered with windows of
    /// 16 branches against one window per pixel, per-pixel differences within 4 standard
    /// errors of zero; a window render 3 % too bright fails the same rule.
    #[test]
    fn resampled_windows_keep_the_expectation() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/eye-contact.toml");
        let sets = [
            "sensor.crop_px=[40,40]".to_string(),
            "sensor.pitch_um=52.8".to_string(),
        ];
        let sys = System::build(&crate::scene::load_scene(Some(&path), &sets).unwrap()).unwrap();
        let world = sys.world.as_deref().unwrap();
        let rows = |seed: u64, window: usize| -> (Vec<f64>, u64) {
            let set = RenderSettings::lattice(64, seed, false);
            let rule = lattice_rule(&set);
            let mut paths = 0;
            let v = (0..sys.camera.height_px)
                .flat_map(|row| {
                    let r = render_row_resampled(&sys, &set, world, rule, row, window);
                    paths += r.stats.scene_paths;
                    r.values
                })
                .collect();
            (v, paths)
        };
        let ((small, small_paths), (whole, whole_paths)) = (rows(1, 16), rows(2, usize::MAX));
        // The windows do split the pixels (a 16-branch window holds 2–3 samples of ~7 branches),
        // which changes how many paths the replicas get.
        assert_ne!(small_paths, whole_paths);
        let level = whole.iter().sum::<f64>() / whole.len() as f64;
        assert!(level > 0.0);
        let check = |scale: f64| {
            let d: Vec<f64> = small
                .iter()
                .zip(&whole)
                .map(|(a, b)| scale * a - b)
                .collect();
            let (m, sem) = mean_sem(&d);
            (m / level, sem / level)
        };
        let (m, sem) = check(1.0);
        assert!(m.abs() < 4.0 * sem, "windows of 16 branches: {m} ± {sem}");
        let (m3, sem3) = check(1.03);
        assert!(
            m3.abs() > 4.0 * sem3,
            "3 % too bright must fail: {m3} ± {sem3}"
        );
    }
}
