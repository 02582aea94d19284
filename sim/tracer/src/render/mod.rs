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
//!
//! Layout: [`render`] picks the pixel estimator and runs the row loop; the one camera-sample
//! driver is in [`samples`] (shared with the system matrix), the estimators of the display in
//! `display`, of 3-D scenes in `user_side`, and the analog reference in `analog`.

use crate::sampler::SamplerKind;
use crate::system::System;

pub mod adaptive;
mod analog;
pub mod camera_table;
mod display;
pub(crate) mod samples;
pub mod table_file;
mod user_side;

pub use samples::BROADBAND_UNIFORM_FRACTION;
pub use samples::{
    CameraSample, SampleConsumer, channel_weights, display_weight, draw_samples, drive_pixel,
    lattice_rule,
};
pub use user_side::{
    BRANCH_ROULETTE_FRACTION, RESAMPLE_WINDOW_BRANCHES, USER_SIDE_PATHS_PER_SAMPLE,
};

/// How a render estimates each pixel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Estimator {
    /// stscam's estimator: wavelengths importance-sampled around each path's Bragg wavelength,
    /// every replica summed (deterministic splitting).
    #[default]
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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
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
    /// one path per camera sample in all, allotted to replicas by weight. First-vertex numbers
    /// as `Padded`, over a replica's paths.
    Resampled,
    /// Every branch of every camera sample traced (weak ones through Russian roulette), with
    /// padded 2-D point sets shared by a pixel's samples ([`crate::sampler::padded`]), one per
    /// (branch contact, purpose): the light and BSDF samples of a pixel's first vertices are
    /// stratified. Hashed numbers instead with `SamplerKind::Independent`.
    Padded,
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
    /// How each pixel is estimated (stscam's estimator unless a benchmark compares).
    pub estimator: Estimator,
    /// Adaptive sample counts ([`adaptive`]): `spp` is then the mean over the pixels, pilot
    /// included, and each pixel gets samples in proportion to its noise.
    pub adaptive: bool,
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
            estimator: Estimator::Bragg,
            adaptive: false,
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
    /// Adaptive renders: the pilot's and the pixels' sample counts.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sample_counts: Option<adaptive::SampleCounts>,
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

/// Progress over `len` rows (a bar on a terminal, plain lines otherwise), hidden unless
/// `show`.
pub fn row_progress(show: bool, len: usize, what: &str) -> crate::progress::Progress {
    crate::progress::Progress::new(show, len as u64, what)
}

/// Checks the run time and memory of `renders` renders of `sys` with `set` against
/// [`crate::limits`] before any work starts: camera paths (crop pixels × spp × renders,
/// blamed on `spp_setting`, the flag or key that set `set.spp`) and the capture's arrays
/// (per value: the row result in f64, the f32 image and its encoded copy, 16 bytes; an
/// adaptive render's pilots and allocation on top, [`adaptive::extra_bytes_per_pixel`]).
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
        pixels
            * (values * 16
                + if set.adaptive {
                    adaptive::extra_bytes_per_pixel(values)
                } else {
                    0
                }),
    )
}

/// The spectral bins of `render --spectral`: about 10 nm wide, tiling the sampled band exactly,
/// as (start nm, width nm, count) for [`RenderSettings::spectral_bins`].
pub fn spectral_bins(sm: &crate::scene::SamplingDesc) -> (f64, f64, usize) {
    let band = sm.lambda_max_nm - sm.lambda_min_nm;
    let n = (band / 10.0).round().max(1.0) as usize;
    (sm.lambda_min_nm, band / n as f64, n)
}

/// Renders the capture of `sys`: picks the pixel estimator for the scene and `set` (the
/// display seen through the camera, a 3-D scene's user side, or the analog reference) and runs
/// the row loop [`render_rows`] with it, once, or with `set.adaptive` after a pilot
/// ([`adaptive::render`]). Deterministic for a given seed, whatever the thread count.
pub fn render(sys: &System, set: &RenderSettings) -> Capture {
    // `Auto` resolved once for the scene: the rows see the user side's estimator itself.
    let set = &RenderSettings {
        user_side: set.user_side.resolve(sys.world.as_deref()),
        ..set.clone()
    };
    adaptive::render(set, |s, counts| render_counts(sys, s, counts))
}

/// [`render`] with each pixel's sample count from `counts` (row major; `set.spp` for every
/// pixel when `None`), `set.user_side` resolved.
fn render_counts(sys: &System, set: &RenderSettings, counts: Option<&[u32]>) -> Capture {
    // One monomorphised loop per kind of pixel estimator: the display-only loop is the tight
    // one it always was.
    match (sys.world.as_deref(), set.estimator) {
        (Some(world), Estimator::Bragg) if set.user_side == UserSideSampler::Resampled => {
            render_rows(sys, set, counts, || {
                user_side::Resampled::new(sys, set, world, RESAMPLE_WINDOW_BRANCHES)
            })
        }
        (Some(world), Estimator::Bragg) => render_rows(sys, set, counts, || {
            user_side::EveryBranch::new(sys, set, world)
        }),
        (Some(world), Estimator::UniformAnalog) => {
            render_rows(sys, set, counts, || analog::Scene::new(sys, set, world))
        }
        (None, Estimator::Bragg) if sys.display.primaries.is_some() => {
            render_rows(sys, set, counts, || display::Primaries::new(sys, set))
        }
        (None, Estimator::Bragg) => {
            render_rows(sys, set, counts, || display::Monochrome::new(sys, set))
        }
        (None, Estimator::UniformAnalog) => {
            render_rows(sys, set, counts, || analog::Display::new(sys, set))
        }
    }
}

/// Renders with a chosen estimator (both are unbiased; they differ in variance and cost):
/// [`render`] with `set.estimator` replaced.
pub fn render_with(sys: &System, set: &RenderSettings, estimator: Estimator) -> Capture {
    render(
        sys,
        &RenderSettings {
            estimator,
            ..set.clone()
        },
    )
}

/// The work of one pixel: its sums over its `spp` samples (counters added to `stats`).
pub(crate) trait PixelJob<'a> {
    /// Pixel (col, row)'s sums over `spp` samples.
    fn pixel(
        &mut self,
        px: (usize, usize),
        spp: u32,
        stats: &mut RenderStats,
    ) -> &samples::PixelSums<'a>;
}

/// A pixel estimator driven by the camera samples ([`drive_pixel`]): the job of every
/// estimator that traces the camera side.
struct Driven<'s, E> {
    sys: &'s System,
    set: &'s RenderSettings,
    /// The lattice rule of the last sample count asked for (an adaptive render's pixels have
    /// a few counts).
    rule: (u32, Option<crate::sampler::LatticeRule>),
    est: E,
}

impl<'a, E: samples::PixelEstimator<'a>> PixelJob<'a> for Driven<'_, E> {
    #[inline]
    fn pixel(
        &mut self,
        (col, row): (usize, usize),
        spp: u32,
        stats: &mut RenderStats,
    ) -> &samples::PixelSums<'a> {
        if self.rule.0 != spp {
            self.rule = (spp, lattice_rule(self.set, spp));
        }
        self.est
            .start((row * self.sys.camera.width_px + col) as u64, spp);
        drive_pixel(
            self.sys,
            self.set,
            self.rule,
            (col, row),
            stats,
            &mut self.est,
        );
        self.est.finish(stats)
    }
}

/// The row loop of the estimators that trace the camera side: [`job_rows`] with each pixel's
/// samples walked by the camera-sample driver [`drive_pixel`] into a pixel estimator made by
/// `estimator` (one per row).
fn render_rows<'a, E: samples::PixelEstimator<'a>>(
    sys: &'a System,
    set: &RenderSettings,
    counts: Option<&[u32]>,
    estimator: impl Fn() -> E + Sync,
) -> Capture {
    let rule = (set.spp, lattice_rule(set, set.spp));
    job_rows(sys, set, counts, || Driven {
        sys,
        set,
        rule,
        est: estimator(),
    })
}

/// The row loop: rows in parallel (collected in row order), each pixel's sums from a job made
/// by `job` (one per row) over its samples (`set.spp`, or the pixel's entry of `counts`, row
/// major), divided by their count, and the image assembled.
fn job_rows<'a, J: PixelJob<'a>>(
    sys: &'a System,
    set: &RenderSettings,
    counts: Option<&[u32]>,
    job: impl Fn() -> J + Sync,
) -> Capture {
    let h = sys.camera.height_px;
    let cancel = crate::cancel::current();
    let (nch, nbins) = row_layout(sys, set);
    let rows: Vec<RowResult> = crate::rows::par_rows(
        h,
        set.progress,
        "rendering rows",
        &cancel,
        |row| {
            let mut r = RowResult::empty(sys, set);
            let mut job = job();
            let w = sys.camera.width_px;
            for col in 0..w {
                let spp = counts.map_or(set.spp, |c| c[row * w + col]);
                let inv = 1.0 / f64::from(spp.max(1));
                let sums = job.pixel((col, row), spp, &mut r.stats);
                // The pixel's values from its sums over its `spp` samples.
                for (v, a) in r.values[col * nch..(col + 1) * nch]
                    .iter_mut()
                    .zip(sums.acc)
                {
                    *v = a * inv;
                }
                for (v, a) in r.spectral[col * nbins..(col + 1) * nbins]
                    .iter_mut()
                    .zip(&sums.spectral)
                {
                    *v = a * inv;
                }
            }
            r
        },
        |_| RowResult::empty(sys, set),
    );
    assemble(sys, set, &rows)
}

/// Values per pixel of a row: (sensor channels, spectral bins).
fn row_layout(sys: &System, set: &RenderSettings) -> (usize, usize) {
    (
        sys.response.curves.len(),
        set.spectral_bins.map_or(0, |b| b.2),
    )
}

impl RowResult {
    /// A row of zeros (no counts).
    fn empty(sys: &System, set: &RenderSettings) -> RowResult {
        let (nch, nbins) = row_layout(sys, set);
        let w = sys.camera.width_px;
        RowResult {
            values: vec![0.0; w * nch],
            spectral: vec![0.0; w * nbins],
            stats: RenderStats::default(),
        }
    }
}

/// The capture from its rows (in row order): f32 channels and spectral bins, summed counters.
fn assemble(sys: &System, set: &RenderSettings, rows: &[RowResult]) -> Capture {
    let (w, h) = (sys.camera.width_px, sys.camera.height_px);
    let (nch, nbins) = row_layout(sys, set);
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

    /// The memory check counts an adaptive render's pilots and allocation: the largest crop
    /// (8192², 67 M pixels) with 12 spectral bins fits a plain render (13 values, 208 bytes a
    /// pixel: 13 GiB) but not an adaptive one (352 bytes a pixel: 22 GiB, above the 16 GiB
    /// accepted), and the refusal names the crop.
    /// The serde name of every user-side sampler is the name clap and Python accept.
    #[cfg(feature = "clap")]
    #[test]
    fn user_side_sampler_names_match_the_command_line() {
        use clap::ValueEnum;
        for v in UserSideSampler::value_variants() {
            let serde_name = serde_json::to_value(v).unwrap();
            let clap_name = v.to_possible_value().unwrap().get_name().to_string();
            assert_eq!(serde_name, serde_json::Value::String(clap_name));
        }
    }

    #[test]
    fn the_memory_check_counts_the_adaptive_pilots() {
        let sys = crate::system::repo_system(
            "scenes/paper-2022.toml",
            &[
                "sensor.width_px=8192",
                "sensor.height_px=8192",
                "sensor.crop_px=[8192,8192]",
                "sensor.pitch_um=0.5",
            ],
        );
        let mut set = RenderSettings::lattice(1, 1, false);
        set.spectral_bins = Some((450.0, 10.0, 12));
        assert_eq!(check_limits(&sys, &set, 1, "--spp"), Ok(()));
        set.adaptive = true;
        let e = check_limits(&sys, &set, 1, "--spp")
            .unwrap_err()
            .to_string();
        assert!(e.contains("sensor.crop_px") && e.contains("22 GiB"), "{e}");
    }

    /// A count map with every pixel at `spp` renders the bytes of the plain render, for the
    /// display and for both user-side estimators of a 3-D scene (the padded one sizes its
    /// point sets by the pixel's count); a map with one pixel changed changes that pixel only.
    #[test]
    fn equal_counts_are_the_plain_render() {
        let paper = crate::system::repo_system(
            "scenes/paper-2022.toml",
            &["sensor.crop_px=[12,12]", "sensor.pitch_um=176"],
        );
        let eye = crate::system::repo_system(
            "scenes/eye-contact.toml",
            &["sensor.crop_px=[8,8]", "sensor.pitch_um=264"],
        );
        for (sys, user_side) in [
            (&paper, UserSideSampler::Auto),
            (&eye, UserSideSampler::Resampled),
            (&eye, UserSideSampler::Padded),
        ] {
            let set = RenderSettings {
                user_side: user_side.resolve(sys.world.as_deref()),
                ..RenderSettings::lattice(8, 4, false)
            };
            let n = sys.camera.width_px * sys.camera.height_px;
            let plain = render_counts(sys, &set, None).channels;
            let mut counts = vec![8; n];
            assert_eq!(render_counts(sys, &set, Some(&counts)).channels, plain);
            counts[n / 2 + 3] = 16;
            let changed = render_counts(sys, &set, Some(&counts)).channels;
            let differ: Vec<usize> = (0..n).filter(|&i| changed[0][i] != plain[0][i]).collect();
            assert_eq!(differ, vec![n / 2 + 3], "{user_side:?}");
        }
    }

    /// An adaptive render is the plain render of the counts its two pilots give, drawn with
    /// the render's own seed; the pilots' seeds are neither the render's nor each other's (the
    /// image is independent of the samples that chose its counts); its counters hold the
    /// pilots' paths too.
    #[test]
    fn adaptive_render_is_the_render_of_its_counts() {
        let sys = crate::system::repo_system(
            "scenes/paper-2022.toml",
            &["sensor.crop_px=[16,16]", "sensor.pitch_um=132"],
        );
        let set = RenderSettings {
            adaptive: true,
            ..RenderSettings::lattice(32, 5, false)
        };
        let h = adaptive::pilot_spp(32);
        let seeds = [adaptive::pilot_seed(5, 0), adaptive::pilot_seed(5, 1)];
        assert!(seeds[0] != seeds[1] && !seeds.contains(&5));
        let pilots: Vec<Capture> = seeds
            .iter()
            .map(|&seed| {
                let s = RenderSettings {
                    spp: h,
                    seed,
                    adaptive: false,
                    ..set.clone()
                };
                render_counts(&sys, &s, None)
            })
            .collect();
        let counts = adaptive::allot(&pilots[0], &pilots[1], 32, h);
        assert!(counts.iter().any(|&c| c != counts[0]), "the counts vary");
        let want = render_counts(&sys, &set, Some(&counts));
        let got = render(&sys, &set);
        assert_eq!(got.channels, want.channels);
        assert_eq!(
            got.stats.camera_paths,
            want.stats.camera_paths + pilots[0].stats.camera_paths + pilots[1].stats.camera_paths
        );
    }

    /// Windows of a few samples (what bounds the resampled user side's memory at high spp)
    /// keep the estimate's expectation: the eye-contact scene's rows rendered with windows of
    /// 16 branches against one window per pixel, per-pixel differences within 4 standard
    /// errors of zero; a window render 3 % too bright fails the same rule.
    #[test]
    fn resampled_windows_keep_the_expectation() {
        let sys = crate::system::repo_system(
            "scenes/eye-contact.toml",
            &["sensor.crop_px=[40,40]", "sensor.pitch_um=52.8"],
        );
        let world = sys.world.as_deref().unwrap();
        let rows = |seed: u64, window: usize| -> (Vec<f64>, u64) {
            let set = RenderSettings::lattice(64, seed, false);
            let cap = render_rows(&sys, &set, None, || {
                user_side::Resampled::new(&sys, &set, world, window)
            });
            let v = cap.channels[0].iter().map(|&x| f64::from(x)).collect();
            (v, cap.stats.scene_paths)
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
