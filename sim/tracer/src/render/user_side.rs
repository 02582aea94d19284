//! The user side of 3-D scenes: the pixel estimators that follow a camera sample's branches
//! out of the plate's front face into the scene.
//!
//! Each branch leaves the front face at its exit point with the camera ray's own direction
//! (the waveguide is a periscope); the radiance arriving along that exit ray comes from the
//! user-side path tracer ([`crate::world::integrator`]), split into the display seen directly
//! (polarised as the display says) and everything else (unpolarised), and weighted with the
//! branch's TE/TM weights accordingly. The sample's value is cos⁴θ/p(λ) times the weighted sum
//! (the scene's emitters carry their own spectra).
//!
//! Two estimators ([`super::UserSideSampler`]):
//! - [`EveryBranch`] (`padded`): every branch of every sample traced, weak ones through
//!   Russian roulette over branches ([`BRANCH_ROULETTE_FRACTION`]; J. Arvo & D. Kirk,
//!   "Particle transport and image synthesis", SIGGRAPH 1990: a path kept with probability q
//!   and weighted 1/q keeps its expectation);
//! - [`Resampled`] (the default): a pixel's branches share user-side paths, about
//!   [`USER_SIDE_PATHS_PER_SAMPLE`] per camera sample (the estimator is described there).

use std::ops::ControlFlow;

use super::samples::{CameraSample, PixelEstimator, PixelSums, SampleConsumer, channel_weights};
use super::{RenderSettings, RenderStats};
use crate::sampler::{PathRng, SamplerKind};
use crate::system::System;
use crate::trace::Branch;
use crate::world::World;
use crate::world::integrator::{ROULETTE_SLOT, branch_weights};

/// Branches below this fraction of a path's strongest branch are traced on the user side only
/// with probability (weight / (this × strongest)) and weighted up by its inverse (Russian
/// roulette over branches: unbiased, and most of a path's weak replicas cost nothing).
pub const BRANCH_ROULETTE_FRACTION: f64 = 0.25;

/// User-side paths per camera sample of [`super::UserSideSampler::Resampled`], on average
/// over a pixel (eye-contact scene, 128 × 128, 128 spp, error² × time: 0.6 → 7.5, 1 → 6.8,
/// 1.5 → 7.3).
pub const USER_SIDE_PATHS_PER_SAMPLE: f64 = 1.0;

/// [`super::UserSideSampler::Resampled`] gathers at most about this many branches before it
/// traces their user side (a pixel with more is done in windows of whole camera samples),
/// bounding its memory whatever the spp and the contact limit.
pub const RESAMPLE_WINDOW_BRANCHES: usize = 16_384;

/// The first hit of the exit ray traced last, kept for the next path that starts on the
/// same ray (a representative or a branch drawn more than once for a pixel): the first ray
/// of such paths is traced once ([`crate::world::World::first_hit_shareable`]).
#[derive(Debug, Default)]
pub(super) struct FirstHitCache {
    /// The ray's exit point, direction and wavelength, as bits.
    ray: [u64; 6],
    hit: Option<crate::world::integrator::Hit>,
}

/// Traces one branch's exit ray (front-face exit point `exit`, the camera ray's direction
/// `dir`, wavelength `lambda_nm`) on the user side and counts its rays; with a `cache`, the
/// path's first hit comes from it when it holds this very ray, and is kept there otherwise.
/// The radiance is the same with or without the cache.
#[allow(clippy::too_many_arguments)]
pub(super) fn trace_exit(
    sys: &System,
    world: &World,
    dir: glam::DVec3,
    lambda_nm: f64,
    exit: glam::DVec2,
    rng: &mut PathRng,
    stats: &mut RenderStats,
    cache: Option<&mut FirstHitCache>,
) -> crate::world::integrator::Radiance {
    let mut counts = crate::world::integrator::PathCounts::default();
    let o = crate::world::integrator::exit_point(exit);
    let first = match cache {
        Some(c) if world.first_hit_shareable() => {
            let ray = [exit.x, exit.y, dir.x, dir.y, dir.z, lambda_nm].map(f64::to_bits);
            if c.hit.is_none() || c.ray != ray {
                c.ray = ray;
                c.hit = Some(world.path_first_hit(&sys.display, o, dir, lambda_nm, rng));
                counts.rays += 1;
            }
            c.hit
        }
        _ => None,
    };
    let l = world.radiance(&sys.display, o, dir, lambda_nm, rng, &mut counts, first);
    stats.scene_rays += counts.rays;
    stats.scene_paths += 1;
    l
}

/// Every branch of every sample traced on the user side with its own random stream; with
/// padded sets (unless the sampler is independent) the first-vertex numbers of a pixel's
/// paths from one replica are stratified. Kept apart from the display estimators so their
/// loops stay as tight as they were.
pub(super) struct EveryBranch<'a> {
    sys: &'a System,
    world: &'a World,
    seed: u64,
    /// The pixel's sample count when the first vertices use padded sets.
    padded_n: Option<u32>,
    sums: PixelSums<'a>,
    /// The current sample's branches: (exit point, weight, replica key (grating, contact)).
    branches: Vec<(glam::DVec2, [f64; 2], u64)>,
}

impl<'a> EveryBranch<'a> {
    pub(super) fn new(sys: &'a System, set: &RenderSettings, world: &'a World) -> Self {
        EveryBranch {
            sys,
            world,
            seed: set.seed,
            padded_n: (set.sampler != SamplerKind::Independent).then_some(set.spp),
            sums: PixelSums::new(sys, set),
            branches: Vec::with_capacity(16),
        }
    }
}

impl SampleConsumer for EveryBranch<'_> {
    fn begin(&mut self, _s: &CameraSample, _i: u64) {
        self.branches.clear();
    }

    fn branch(&mut self, _s: &CameraSample, b: &Branch) -> ControlFlow<()> {
        if b.weight[0] > 0.0 || b.weight[1] > 0.0 {
            self.branches
                .push((b.exit_point_mm, b.weight, b.replica_key()));
        }
        ControlFlow::Continue(())
    }

    fn end(&mut self, s: &CameraSample, i: u64, stats: &mut RenderStats) {
        let pol = self.sys.display.polarization_weights;
        let strongest = self
            .branches
            .iter()
            .map(|b| b.1[0] + b.1[1])
            .fold(0.0, f64::max);
        let threshold = BRANCH_ROULETTE_FRACTION * strongest;
        let mut total = 0.0;
        for &(exit, weight, replica) in &self.branches {
            let mut rng = PathRng::new(&[self.seed, self.sums.pixel, i, replica]);
            if let Some(n) = self.padded_n {
                // One padded set per (seed, pixel, replica (grating, contact)), shared by the
                // pixel's samples.
                let pad_key = PathRng::padded_key(&[self.seed, self.sums.pixel, replica]);
                rng = rng.with_padded(pad_key, i, n);
            }
            let w = weight[0] + weight[1];
            let keep = if w < threshold { w / threshold } else { 1.0 };
            if keep < 1.0 && rng.single(ROULETTE_SLOT) >= keep {
                continue;
            }
            let l = trace_exit(
                self.sys,
                self.world,
                s.ray.dir,
                s.lambda_nm,
                exit,
                &mut rng,
                stats,
                None,
            );
            let (wd, wo) = branch_weights(weight, pol);
            total += (wd * l.display + wo * l.other) / keep;
        }
        self.sums
            .add(s.ray.cos4 * total / s.pdf, s.lambda_nm, stats);
    }
}

impl<'a> PixelEstimator<'a> for EveryBranch<'a> {
    fn sums(&mut self) -> &mut PixelSums<'a> {
        &mut self.sums
    }

    fn start(&mut self, pixel: u64, spp: u32) {
        self.sums.start(pixel);
        // The padded sets have as many points as the pixel has samples.
        if let Some(n) = &mut self.padded_n {
            *n = spp;
        }
    }
}

/// One branch of a pixel's camera samples waiting for its user side ([`Resampled`], and the
/// camera-side table's representatives, [`super::camera_table`]).
#[derive(Clone, Copy, Debug)]
pub(super) struct PendingBranch {
    /// The branch's replica, (grating, plate contact) as [`Branch::replica_key`].
    pub(super) replica: u64,
    /// Its camera sample's index in [`Gathered::samples`] (the samples in order).
    pub(super) sample: u32,
    /// Front-face exit point, mm.
    pub(super) exit: glam::DVec2,
    /// Energy fractions [TE, TM].
    pub(super) weight: [f64; 2],
    /// Selection weight: the branch's weight to the sensor, ½(w_TE + w_TM)·cos⁴θ/p(λ)·Σ_c R_c(λ)
    /// (without the response sum when spectral bins are written, which do not use it).
    pub(super) sel: f64,
}

/// Tag of the resampled user side's random streams (keeps them apart from the per-branch ones).
const RESAMPLED_TAG: u64 = 0x5E5A_4D91_ED00_0000;

/// A run of camera samples and their branches gathered for resampling (a [`Resampled`]
/// window, or a whole pixel of the camera-side table).
pub(super) struct Gathered<'a> {
    sys: &'a System,
    /// Spectral bins are written (the selection weights then leave out the response).
    spectral_bins: bool,
    /// The camera samples, in order.
    pub(super) samples: Vec<CameraSample>,
    /// Their branches with a positive selection weight, in order.
    pub(super) branches: Vec<PendingBranch>,
    /// The current sample's selection scale, cos⁴θ/p(λ)·Σ_c R_c(λ).
    sel_scale: f64,
    /// Scratch space of the sort: the distinct replicas, the sorted branches.
    keys: Vec<u64>,
    scratch: Vec<PendingBranch>,
}

/// Most distinct replicas the counting sort of [`Gathered`] handles (more: a comparison sort).
const MAX_COUNTED_REPLICAS: usize = 64;

impl<'a> Gathered<'a> {
    /// Nothing gathered yet.
    pub(super) fn new(sys: &'a System, spectral_bins: bool) -> Self {
        Gathered {
            sys,
            spectral_bins,
            samples: Vec::new(),
            branches: Vec::new(),
            sel_scale: 0.0,
            keys: Vec::new(),
            scratch: Vec::new(),
        }
    }

    /// Forgets what was gathered.
    pub(super) fn clear(&mut self) {
        self.samples.clear();
        self.branches.clear();
    }

    /// Sample `s` begins ([`SampleConsumer::begin`]).
    #[inline]
    pub(super) fn begin(&mut self, s: &CameraSample) {
        let response = if self.spectral_bins {
            1.0
        } else {
            channel_weights(self.sys, s.lambda_nm)
                .iter()
                .take(self.sys.response.curves.len())
                .sum()
        };
        self.sel_scale = s.ray.cos4 / s.pdf * response;
        self.samples.push(*s);
    }

    /// A branch of the current sample ([`SampleConsumer::branch`]).
    #[inline]
    pub(super) fn branch(&mut self, b: &Branch) {
        let sel = 0.5 * (b.weight[0] + b.weight[1]) * self.sel_scale;
        if sel > 0.0 && sel.is_finite() {
            self.branches.push(PendingBranch {
                replica: b.replica_key(),
                sample: (self.samples.len() - 1) as u32,
                exit: b.exit_point_mm,
                weight: b.weight,
                sel,
            });
        }
    }

    /// Orders the branches by (replica, sample): a counting sort over the few distinct
    /// replicas (the branches arrive in sample order, and a sample has at most one branch per
    /// replica), a comparison sort where there are many.
    fn sort_by_replica(&mut self) {
        let keys = &mut self.keys;
        keys.clear();
        for p in &self.branches {
            if !keys.contains(&p.replica) {
                keys.push(p.replica);
                if keys.len() > MAX_COUNTED_REPLICAS {
                    self.branches
                        .sort_unstable_by_key(|p| (p.replica, p.sample));
                    return;
                }
            }
        }
        keys.sort_unstable();
        let mut start = [0usize; MAX_COUNTED_REPLICAS + 1];
        let slot = |r: u64| keys.binary_search(&r).unwrap_or(0);
        for p in &self.branches {
            start[slot(p.replica) + 1] += 1;
        }
        for i in 1..=keys.len() {
            start[i] += start[i - 1];
        }
        // Same length; every entry is overwritten below.
        self.scratch.clone_from(&self.branches);
        for p in &self.branches {
            let k = slot(p.replica);
            self.scratch[start[k]] = *p;
            start[k] += 1;
        }
        std::mem::swap(&mut self.branches, &mut self.scratch);
    }

    /// Sorts the branches by (replica, sample) and calls `group` for each replica's run with
    /// the selection weight of all branches.
    pub(super) fn by_replica(&mut self, mut group: impl FnMut(&[PendingBranch], f64)) {
        self.sort_by_replica();
        let total: f64 = self.branches.iter().map(|p| p.sel).sum();
        for g in self.branches.chunk_by(|a, b| a.replica == b.replica) {
            group(g, total);
        }
    }
}

/// Systematic resampling of one replica's branches `group` (selection weight `s_c`) into
/// about `q` draws: K = round(q) draws for q ≥ 1; one draw for `t` ≤ q < 1; for q < t one
/// draw with probability q/t (Russian roulette on the uniform of hash `h`), else none. Calls
/// `draw(kk, K, s_c/K_eff, branch)` for draw kk of K, in order: each draw stands for s_c/K_eff
/// of selection weight, K_eff = K (or q/t), so Σ draws·(s_c/K_eff)·v/s is unbiased for Σ_j v_j
/// (Douc, Cappé & Moulines 2005). The offset comes from `mix64(h)`.
pub(super) fn resample_group(
    group: &[PendingBranch],
    s_c: f64,
    q: f64,
    t: f64,
    h: u64,
    mut draw: impl FnMut(u64, u64, f64, &PendingBranch),
) {
    let (k, k_eff) = if q >= 1.0 {
        let k = q.round() as u64;
        (k, k as f64)
    } else if q >= t {
        (1, 1.0)
    } else if t == 1.0 {
        // (q/t written as q: the resampled user side's numbers, unchanged.)
        if crate::sampler::to_unit(h) < q {
            (1, q)
        } else {
            return;
        }
    } else if crate::sampler::to_unit(h) < q / t {
        (1, q / t)
    } else {
        return;
    };
    let offset = crate::sampler::to_unit(crate::sampler::mix64(h));
    let step = s_c / k as f64;
    let share = s_c / k_eff;
    let mut j = 0;
    let mut cum = group[0].sel;
    for kk in 0..k {
        // The branch whose cumulative weight passes (kk + offset)·step.
        let t = (kk as f64 + offset) * step;
        while cum <= t && j + 1 < group.len() {
            j += 1;
            cum += group[j].sel;
        }
        draw(kk, k, share, &group[j]);
    }
}

/// The pixel's branches share user-side paths.
///
/// Estimator. The pixel's sum is Σ_i Σ_b v_ib·L_ib over camera samples i and their branches b,
/// where v_ib (the branch's TE/TM weights, cos⁴θ/p(λ) and the channel responses at λ_i) comes
/// from the cheap waveguide trace and L_ib (the radiance arriving along the branch's exit ray)
/// from an expensive user-side path. Each sample's branches are gathered per replica
/// (grating and plate contact c); replica c's sum Σ_j v_j·L_j over its G_c branches, of total
/// selection weight S_c = Σ_j s_j, is estimated from K_c user-side paths traced from branches
/// drawn by systematic resampling in proportion to s_j (one uniform offset, the branches in
/// sample order): (S_c/K_c)·Σ_k v_jk·L̂_jk/s_jk ([`resample_group`]). Systematic resampling
/// draws branch j K_c·s_j/S_c times in expectation (Douc, Cappé & Moulines 2005, "Comparison
/// of resampling schemes for particle filtering"), and each L̂ is an independent unbiased path
/// estimate, so the estimate is unbiased for any K_c fixed by the branches. Paths are allotted
/// by weight, K_c = round(τ·N·S_c/Σ S) for τ = [`USER_SIDE_PATHS_PER_SAMPLE`] and N camera
/// samples; a replica with τ·N·S_c/ΣS = q < 1 is traced once with probability q and weighted
/// 1/q (Russian roulette). Why it pays: every camera sample still contributes its exact branch
/// weights (the replica edges, the Bragg selectivity and the pixel footprint are integrated
/// with all N samples), while the user side, about 85 % of a sample's cost, is sampled only as
/// often as its own noise needs; branches of one replica in one pixel see nearly the same
/// radiance, so drawing among them adds little. The first-vertex numbers of a replica's paths
/// come from padded sets over its K_c paths (as [`EveryBranch`], unless the sampler is
/// independent).
///
/// Memory: the branches are gathered in windows of whole camera samples holding at least
/// `window_branches` branches (the last one fewer), each window traced on its own.
pub(super) struct Resampled<'a> {
    sys: &'a System,
    world: &'a World,
    seed: u64,
    padded: bool,
    window_branches: usize,
    sums: PixelSums<'a>,
    /// The window's camera samples and branches.
    gathered: Gathered<'a>,
    /// The window's sample indices, [start, end).
    window: (u64, u64),
}

impl<'a> Resampled<'a> {
    /// The estimator with windows of about `window_branches` branches.
    pub(super) fn new(
        sys: &'a System,
        set: &RenderSettings,
        world: &'a World,
        window_branches: usize,
    ) -> Self {
        Resampled {
            sys,
            world,
            seed: set.seed,
            padded: set.sampler != SamplerKind::Independent,
            window_branches,
            sums: PixelSums::new(sys, set),
            gathered: Gathered::new(sys, set.spectral_bins.is_some()),
            window: (0, 0),
        }
    }

    /// Traces the user side of the window's branches, adds them to the pixel's sums and
    /// empties the window.
    fn trace_window(&mut self, stats: &mut RenderStats) {
        let (sys, window) = (self.sys, self.window);
        let paths = USER_SIDE_PATHS_PER_SAMPLE * (window.1 - window.0) as f64;
        let pol = sys.display.polarization_weights;
        let (seed, pixel, padded, world) = (self.seed, self.sums.pixel, self.padded, self.world);
        let sums = &mut self.sums;
        let samples = std::mem::take(&mut self.gathered.samples);
        let mut first_hits = FirstHitCache::default();
        self.gathered.by_replica(|group, total| {
            // The replica's key (grating, contact); the contact alone for grating 0.
            let contact = group[0].replica;
            let s_c: f64 = group.iter().map(|p| p.sel).sum();
            let tag = RESAMPLED_TAG ^ window.0;
            let h = crate::sampler::hash(&[seed, pixel, tag, contact]);
            let pad_key = PathRng::padded_key(&[seed, pixel, contact, tag]);
            resample_group(
                group,
                s_c,
                paths * s_c / total,
                1.0,
                h,
                |kk, k, share, p| {
                    let s = &samples[p.sample as usize];
                    let mut rng = PathRng::new(&[seed, pixel, tag, contact, kk]);
                    if padded && k <= u64::from(u32::MAX) {
                        rng = rng.with_padded(pad_key, kk, k as u32);
                    }
                    let l = trace_exit(
                        sys,
                        world,
                        s.ray.dir,
                        s.lambda_nm,
                        p.exit,
                        &mut rng,
                        stats,
                        Some(&mut first_hits),
                    );
                    let (wd, wo) = branch_weights(p.weight, pol);
                    let base = share * (wd * l.display + wo * l.other) / p.sel * s.ray.cos4 / s.pdf;
                    sums.add(base, s.lambda_nm, stats);
                },
            );
        });
        self.gathered.samples = samples;
        self.gathered.clear();
    }
}

impl SampleConsumer for Resampled<'_> {
    fn begin(&mut self, s: &CameraSample, _i: u64) {
        self.gathered.begin(s);
    }

    fn branch(&mut self, _s: &CameraSample, b: &Branch) -> ControlFlow<()> {
        self.gathered.branch(b);
        ControlFlow::Continue(())
    }

    fn end(&mut self, _s: &CameraSample, _i: u64, _stats: &mut RenderStats) {}

    fn after(&mut self, i: u64, stats: &mut RenderStats) {
        self.window.1 = i + 1;
        if self.gathered.branches.len() >= self.window_branches {
            self.trace_window(stats);
            self.window.0 = self.window.1;
        }
    }
}

impl<'a> PixelEstimator<'a> for Resampled<'a> {
    fn sums(&mut self) -> &mut PixelSums<'a> {
        &mut self.sums
    }

    fn start(&mut self, pixel: u64, _spp: u32) {
        self.sums.start(pixel);
        self.gathered.clear();
        self.window = (0, 0);
    }

    fn finish(&mut self, stats: &mut RenderStats) -> &PixelSums<'a> {
        self.trace_window(stats);
        &self.sums
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Paths that start on one ray get the radiance they get without the cache, bit for bit,
    /// and the ray is traced once: three paths on a ray that meets the head (each with its own
    /// stream) count two scene rays fewer than without the cache; a path on another ray (one
    /// that misses the head, so its radiance differs) after them gets its own first hit, and
    /// so does a ray to the ceiling light that differs from the one before it only in
    /// wavelength (the light's radiance differs), so a cache that ignored the direction or the
    /// wavelength would fail the comparison. With a coverage filter (any non-plain material)
    /// nothing is shared: the same radiance and as many rays as without the cache.
    #[test]
    fn shared_first_hit_gives_the_same_radiance_and_saves_the_ray() {
        let mut sys =
            crate::system::repo_system("scenes/eye-contact.toml", &["sensor.crop_px=[8,8]"]);
        let exit = glam::DVec2::new(0.0, -12.0);
        let head = (exit, glam::DVec3::NEG_Z, 550.0);
        let away = (exit, glam::DVec3::new(0.6, 0.0, -0.8), 550.0);
        let up = glam::DVec3::new(0.0, 0.9, -0.4).normalize();
        let rays = [
            head,
            head,
            head,
            away,
            head,
            (exit, up, 550.0),
            (exit, up, 450.0),
        ];
        let run = |sys: &System| {
            let world = sys.world.as_deref().unwrap();
            let mut cache = FirstHitCache::default();
            let (mut plain_stats, mut shared_stats) =
                (RenderStats::default(), RenderStats::default());
            let mut values = Vec::new();
            for (k, &(exit, dir, lambda)) in rays.iter().enumerate() {
                let trace = |stats: &mut RenderStats, cache: Option<&mut FirstHitCache>| {
                    let mut rng = PathRng::new(&[5, k as u64]);
                    trace_exit(sys, world, dir, lambda, exit, &mut rng, stats, cache)
                };
                let plain = trace(&mut plain_stats, None);
                let shared = trace(&mut shared_stats, Some(&mut cache));
                assert_eq!(
                    plain.display.to_bits(),
                    shared.display.to_bits(),
                    "path {k}"
                );
                assert_eq!(plain.other.to_bits(), shared.other.to_bits(), "path {k}");
                values.push(plain.other);
            }
            assert!(values[0] > 0.0 && values[0] != values[3], "{values:?}");
            assert!(values[5] > 0.0 && values[5] != values[6], "{values:?}");
            (plain_stats.scene_rays, shared_stats.scene_rays)
        };
        assert!(sys.world.as_deref().unwrap().first_hit_shareable());
        // The first three paths share one first ray; every other path traces its own.
        let (plain, shared) = run(&sys);
        assert_eq!(shared + 2, plain);
        let arc = sys.world.take().unwrap();
        let mut world = std::sync::Arc::try_unwrap(arc).expect("one owner");
        world.coverage_filter = true;
        assert!(!world.first_hit_shareable());
        sys.world = Some(std::sync::Arc::new(world));
        let (plain, shared) = run(&sys);
        assert_eq!(shared, plain);
    }

    /// `resample_group` is unbiased for Σ_j v_j: over many offsets (hashes), the mean of
    /// Σ_draws share·v_j/s_j matches the exact sum within 4 standard errors, for shares q
    /// above one, between the floor t and one, and below t (roulette); a 3 % error in the
    /// share fails the same rule.
    #[test]
    fn resample_group_is_unbiased_for_every_share() {
        let sel = [0.3, 1.7, 0.05, 2.2, 0.9];
        let v = [0.25, 1.5, 0.06, 2.0, 1.0];
        let group: Vec<PendingBranch> = sel
            .iter()
            .enumerate()
            .map(|(i, &s)| PendingBranch {
                replica: 3,
                sample: i as u32,
                exit: glam::DVec2::ZERO,
                weight: [1.0, 1.0],
                sel: s,
            })
            .collect();
        let s_c: f64 = sel.iter().sum();
        let exact: f64 = v.iter().sum();
        for (q, t) in [(3.4, 1.0), (0.6, 0.1), (0.04, 0.1), (0.3, 1.0)] {
            let n = 200_000u64;
            let est: Vec<f64> = (0..n)
                .map(|i| {
                    let mut sum = 0.0;
                    let h = crate::sampler::hash(&[i, 77]);
                    resample_group(&group, s_c, q, t, h, |_, _, share, p| {
                        sum += share * v[p.sample as usize] / p.sel;
                    });
                    sum
                })
                .collect();
            let m = est.iter().sum::<f64>() / n as f64;
            let var = est.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1) as f64;
            let sem = (var / n as f64).sqrt();
            assert!(
                (m - exact).abs() < 4.0 * sem + 1e-12,
                "q {q}, t {t}: {m} vs {exact} ± {sem}"
            );
            assert!(
                (1.03 * m - exact).abs() > 4.0 * sem,
                "q {q}, t {t}: 3 % must fail"
            );
        }
    }
}
