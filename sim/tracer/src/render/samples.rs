//! The camera-sample driver: the one loop over a pixel's camera samples that every estimator
//! of the camera side shares (the image, the system matrix H and its depth stack, the user
//! side of 3-D scenes, the analog reference, the colour demo's grating shares).
//!
//! A camera sample is a sensor point and a lens point (a thin-lens ray), and a wavelength drawn
//! around the ray's Bragg wavelength (closed form: docs/physics.md §3.2), mixed with a uniform
//! part so the estimator stays unbiased (docs/design.md, "Estimator decisions"), with the factor cos⁴θ·S(λ)/p(λ) every branch shares. [`drive_pixel`] draws the
//! pixel's samples in order from the addressable sampler, traces each one backward through the
//! waveguide ([`crate::trace`]) and hands each branch that reaches the object plane to a
//! [`SampleConsumer`]. What is done with the branches is the consumer's business, so the
//! samples, their order and their counters are the same for every use: `render(f)` and `H·f +
//! offset` agree to float rounding by construction (docs/design.md, "One camera sample, end to
//! end").

use std::ops::ControlFlow;

use super::{Estimator, RenderSettings, RenderStats};
use crate::optics::packet::LANES;
use crate::sampler::{LatticeRule, PixelSampler};
use crate::system::System;
use crate::trace::{Branch, Prepared, sees_through_n};
use glam::DVec3;

/// Uniform fraction of the wavelength density for paths with a straight-through (broadband)
/// view: the Bragg table and the uniform part get equal shares, so f/p stays within a factor of
/// two of the best either alone would give.
pub const BROADBAND_UNIFORM_FRACTION: f64 = 0.5;

/// One camera sample ready to trace: the ray, its wavelength and the factor
/// cos⁴θ·S(λ)/p(λ) shared by every branch.
#[derive(Clone, Copy, Debug)]
pub struct CameraSample {
    /// The camera ray (sensor point through the lens).
    pub ray: crate::camera::CameraRay,
    /// The sampled wavelength, nm.
    pub lambda_nm: f64,
    /// cos⁴θ·S(λ)/p(λ), shared by every branch.
    pub factor: f64,
    /// The wavelength density p(λ) (3-D scenes use cos⁴θ/p(λ): their emitters carry their own
    /// spectra).
    pub pdf: f64,
}

/// Camera samples drawn at a time: drawing a sample is a chain of dependent steps (lattice
/// point, ray, Bragg wavelength, plate crossing, table inversion), and drawing several in a
/// row, apart from the tracing, lets the processor overlap their chains.
pub(crate) const SAMPLE_BATCH: usize = 16;

/// What is done with a pixel's camera samples: [`drive_pixel`] calls, for every sample index
/// `i` in order, `begin`, `branch` for each branch that reaches the object plane, and `end`
/// (only for samples drawn inside the band), then `after` (for every index).
pub trait SampleConsumer {
    /// Sample `i` is about to be traced.
    #[inline(always)]
    fn begin(&mut self, _s: &CameraSample, _i: u64) {}

    /// A branch of the current sample reached the object plane; `Break` ends the path there
    /// (later branches are not traced).
    fn branch(&mut self, s: &CameraSample, b: &Branch) -> ControlFlow<()>;

    /// Every branch of sample `i` has been handed over.
    fn end(&mut self, s: &CameraSample, i: u64, stats: &mut RenderStats);

    /// Sample index `i` is done, whether it was traced or drawn outside the band.
    #[inline(always)]
    fn after(&mut self, _i: u64, _stats: &mut RenderStats) {}
}

/// The one camera-sample driver: walks the `spp` samples of pixel (col, row) in index order
/// (`set.spp`, or the pixel's own count in an adaptive render), traces each through the
/// waveguide with its counters added to `stats`, and hands the sample and its branches to
/// `consumer` ([`SampleConsumer`]). `rule` is the lattice rule of `spp` samples
/// ([`lattice_rule`]). The same seed gives the same samples for any caller.
#[inline(always)]
pub fn drive_pixel<C: SampleConsumer>(
    sys: &System,
    set: &RenderSettings,
    (spp, rule): (u32, Option<LatticeRule>),
    (col, row): (usize, usize),
    stats: &mut RenderStats,
    consumer: &mut C,
) {
    let pixel = (row * sys.camera.width_px + col) as u64;
    let sampler = PixelSampler::new(set.sampler, set.seed, pixel).with_rule(rule);
    let spp = u64::from(spp);
    // The glass index of the see-through test is the same for every ray.
    let n0 = sys.waveguide.n_glass(sys.scene.hoe.primary_wavelength_nm());
    let mut batch = [None; SAMPLE_BATCH];
    // Film quantities of four paths at a time (optics::packet), where the film allows.
    let packets = crate::trace::packets_apply(&sys.waveguide);
    let mut prepared = [Prepared::default(); SAMPLE_BATCH];
    let mut first = 0u64;
    while first < spp {
        let len = (spp - first).min(SAMPLE_BATCH as u64) as usize;
        camera_samples(
            sys,
            &sampler,
            (col, row),
            first,
            &mut batch[..len],
            (n0, set.estimator),
        );
        if packets {
            prepare_batch(sys, &batch[..len], &mut prepared[..len]);
        }
        for ((i, s), pre) in (first..).zip(&batch[..len]).zip(&prepared) {
            if let Some(s) = s {
                consumer.begin(s, i);
                let mut max_w: f64 = 0.0;
                let mut branches = 0u64;
                stats.camera_paths += 1;
                let visit = |b: &Branch| {
                    branches += 1;
                    max_w = max_w.max(b.weight[0]).max(b.weight[1]);
                    consumer.branch(s, b)
                };
                let (wg, z, lim) = (&sys.waveguide, sys.display.z_mm, sys.limits);
                let (o, d, l) = (s.ray.origin, s.ray.dir, s.lambda_nm);
                let summary = if packets {
                    crate::trace::trace_prepared_until(wg, z, lim, (o, d, l), pre, visit)
                } else {
                    crate::trace::trace_camera_path_until(wg, z, lim, o, d, l, visit)
                };
                stats.branches += branches;
                stats.contacts += u64::from(summary.contacts);
                stats.max_contacts_hits += u64::from(summary.hit_max_contacts);
                stats.max_truncated_weight =
                    stats.max_truncated_weight.max(summary.truncated_weight);
                stats.max_branch_weight = stats.max_branch_weight.max(max_w);
                consumer.end(s, i, stats);
            }
            consumer.after(i, stats);
        }
        first += len as u64;
    }
}

/// Camera samples `start`, `start + 1`, … of pixel (col, row) into `out` (at most
/// [`SAMPLE_BATCH`] at a time), exactly as [`drive_pixel`] draws them for `set` and the lattice
/// rule `rule` ([`lattice_rule`] of `set.spp`): `None` where a wavelength falls outside the band.
/// For estimators outside this crate that trace the samples their own way (the stray-light
/// tracer), so that their images and `render`'s share every sample.
pub fn draw_samples(
    sys: &System,
    set: &RenderSettings,
    rule: Option<LatticeRule>,
    (col, row): (usize, usize),
    start: u64,
    out: &mut [Option<CameraSample>],
) {
    let pixel = (row * sys.camera.width_px + col) as u64;
    let sampler = PixelSampler::new(set.sampler, set.seed, pixel).with_rule(rule);
    let n0 = sys.waveguide.n_glass(sys.scene.hoe.primary_wavelength_nm());
    for (k, chunk) in out.chunks_mut(SAMPLE_BATCH).enumerate() {
        let first = start + (k * SAMPLE_BATCH) as u64;
        camera_samples(sys, &sampler, (col, row), first, chunk, (n0, set.estimator));
    }
}

/// The film quantities of a batch's samples, four at a time ([`crate::trace::prepare_paths`]);
/// a lane without a sample repeats one of its packet's samples (its result is not used).
#[inline]
fn prepare_batch(sys: &System, batch: &[Option<CameraSample>], out: &mut [Prepared]) {
    for (samples, out) in batch.chunks(LANES).zip(out.chunks_mut(LANES)) {
        let Some(fill) = samples.iter().flatten().next() else {
            continue;
        };
        let rays: [(DVec3, DVec3, f64); LANES] = std::array::from_fn(|k| {
            let s = samples.get(k).copied().flatten().unwrap_or(*fill);
            (s.ray.origin, s.ray.dir, s.lambda_nm)
        });
        let p = crate::trace::prepare_paths(&sys.waveguide, &rays);
        out.copy_from_slice(&p[..out.len()]);
    }
}

/// Samples `start`, `start + 1`, … of pixel (col, row) into `out` (at most [`SAMPLE_BATCH`]),
/// each `None` when its wavelength falls outside the band; `n0` is the glass index at the
/// recording wavelength.
#[inline]
fn camera_samples(
    sys: &System,
    sampler: &PixelSampler,
    (col, row): (usize, usize),
    start: u64,
    out: &mut [Option<CameraSample>],
    (n0, estimator): (f64, Estimator),
) {
    let mut u = [[0.0; crate::sampler::DIMS]; SAMPLE_BATCH];
    let u = &mut u[..out.len()];
    sampler.get_batch(start, u);
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

/// A branch's weight averaged over the display's polarisation, f_TE·w_TE + f_TM·w_TM.
#[inline(always)]
pub fn display_weight(sys: &System, b: &Branch) -> f64 {
    let pol = sys.display.polarization_weights;
    pol[0] * b.weight[0] + pol[1] * b.weight[1]
}

/// Per-channel spectral weights R_c(λ)/∫R_c of the sensor response.
#[inline]
pub fn channel_weights(sys: &System, lambda_nm: f64) -> [f64; 4] {
    let mut r = [0.0; 4];
    for (c, w) in r.iter_mut().enumerate().take(sys.response.curves.len()) {
        *w = sys.response.curves[c].eval(lambda_nm) * sys.response.inv_integral[c];
    }
    r
}

/// The lattice rule of `spp` samples per pixel with `set`'s sampler (searched once; it depends
/// only on the sample count).
pub fn lattice_rule(set: &RenderSettings, spp: u32) -> Option<LatticeRule> {
    match set.sampler {
        crate::sampler::SamplerKind::Lattice => LatticeRule::korobov(u64::from(spp)),
        crate::sampler::SamplerKind::Independent | crate::sampler::SamplerKind::Sobol => None,
    }
}

/// A pixel's sums over its samples: the sensor channels and the optional spectral bins, with
/// the pixel's row-major index (the key of its random streams).
pub(crate) struct PixelSums<'a> {
    sys: &'a System,
    /// The pixel's row-major index.
    pub(crate) pixel: u64,
    bins: Option<(f64, f64, usize)>,
    /// Channel sums (unused channels stay 0).
    pub(crate) acc: [f64; 4],
    /// Spectral-bin sums, per nm.
    pub(crate) spectral: Vec<f64>,
}

impl<'a> PixelSums<'a> {
    /// Empty sums for the channels of `sys` and the bins of `set`.
    pub(crate) fn new(sys: &'a System, set: &RenderSettings) -> Self {
        PixelSums {
            sys,
            pixel: 0,
            bins: set.spectral_bins,
            acc: [0.0; 4],
            spectral: vec![0.0; set.spectral_bins.map_or(0, |b| b.2)],
        }
    }

    /// Empty sums for pixel `pixel`.
    #[inline]
    pub(crate) fn start(&mut self, pixel: u64) {
        self.pixel = pixel;
        self.acc = [0.0; 4];
        self.spectral.fill(0.0);
    }

    /// Adds a sample's value `base` (before the sensor response) at `lambda_nm`; a non-finite
    /// value is counted and dropped.
    #[inline(always)]
    pub(crate) fn add(&mut self, base: f64, lambda_nm: f64, stats: &mut RenderStats) {
        if !base.is_finite() {
            stats.nonfinite_samples += 1;
            return;
        }
        let r = channel_weights(self.sys, lambda_nm);
        for (a, rc) in self
            .acc
            .iter_mut()
            .zip(r)
            .take(self.sys.response.curves.len())
        {
            *a += base * rc;
        }
        if let Some((start, width, n)) = self.bins {
            let k = ((lambda_nm - start) / width).floor();
            if k >= 0.0 && (k as usize) < n {
                self.spectral[k as usize] += base / width;
            }
        }
    }
}

/// A pixel estimator of the image: a [`SampleConsumer`] that sums its samples' values into
/// [`PixelSums`].
pub(crate) trait PixelEstimator<'a>: SampleConsumer {
    /// The pixel's sums.
    fn sums(&mut self) -> &mut PixelSums<'a>;

    /// Starts pixel `pixel` (row-major index), of `spp` samples, with empty sums.
    #[inline]
    fn start(&mut self, pixel: u64, _spp: u32) {
        self.sums().start(pixel);
    }

    /// Ends the pixel (work still pending is done, its counters added to `stats`) and gives
    /// its sums.
    #[inline]
    fn finish(&mut self, _stats: &mut RenderStats) -> &PixelSums<'a> {
        self.sums()
    }
}
