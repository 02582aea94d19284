//! Taking a simulated capture, as every study that reconstructs does it (`demo`, `colour_demo`,
//! the PSNR of `sweep` and `tolerance`, the calibration tests of `hadamard`): a built-in target
//! as linear object intensities; the sensor noise with the exposure set from the all-white
//! capture H·1 + o, a noisy dark frame and the black level it leaves; and the measured noisy
//! capture of an object, rendered by the tracer with an independent seed (no inverse crime) or
//! computed from a matrix. [`DemoSettings`] holds the seed and samples of that protocol (and
//! the demo's solver settings).

use crate::matrix::SystemMatrix;
use crate::noise::{NoiseRng, SensorNoise};
use crate::recon::admm::AdmmSettings;
use crate::recon::cg::CgSettings;
use crate::render::{RenderSettings, render};
use crate::system::System;

/// Settings of the demo.
#[derive(Clone, Debug)]
pub struct DemoSettings {
    /// Samples per pixel for H and the captures.
    pub spp: u32,
    /// Seed (H uses it, captures use seed + 1, noise uses it too).
    pub seed: u64,
    /// CGM settings.
    pub cg: CgSettings,
    /// ADMM-TV settings.
    pub admm: AdmmSettings,
    /// Show progress bars.
    pub progress: bool,
}

/// A built-in target spec as (width, height, linear intensities in [0, 1]) under display
/// gamma `gamma`.
pub fn intensity_of_spec(spec: &str, gamma: f64) -> Result<(usize, usize, Vec<f64>), String> {
    planes_of_spec(spec, gamma, 1)
}

/// A built-in target spec (grey, or `rgb:R+G+B`) as (width, height, linear intensities) in
/// `planes` object planes (1: luminance; 3: R, G, B primary-major).
pub fn planes_of_spec(
    spec: &str,
    gamma: f64,
    planes: usize,
) -> Result<(usize, usize, Vec<f64>), String> {
    let (w, h, c, values) = crate::targets::builtin_image(spec)?;
    Ok((
        w,
        h,
        crate::display::Display::planes_of(&values, c, false, gamma, planes),
    ))
}

/// The reconstruction problem of `h` (an H of `sys`) over `sys`'s object: its planes stacked
/// vertically (one for a monochrome display, three for a colour one: H's column blocks), as the
/// design metrics and the colour demo solve it; cancelled with the thread's job.
pub fn object_problem(sys: &System, h: &crate::sparse::CsrMatrix) -> crate::recon::Problem {
    crate::recon::Problem::with_cancel(
        h,
        sys.display.width_px,
        sys.display.height_px * sys.display.planes(),
        crate::cancel::current(),
    )
}

/// The sensor noise model of `sys` with the exposure set from the all-white capture H·1 + o of
/// `m` (docs/physics.md §7.3: "set the exposure from v0"), and a noisy dark frame (the capture of an
/// all-black display, `m`'s offset) measured with it from the noise stream of `seed`.
pub fn exposure_and_dark(sys: &System, m: &SystemMatrix, seed: u64) -> (SensorNoise, Vec<f64>) {
    let noise = SensorNoise::new(&sys.scene.noise, white_peak_of(m));
    let dark = dark_frame(m, &noise, seed);
    (noise, dark)
}

/// The brightest value of the all-white capture H·1 + o of `m` (every object pixel of every
/// primary white): what fixes the exposure.
pub fn white_peak_of(m: &SystemMatrix) -> f64 {
    crate::recon::discrepancy::white_peak(&m.h, &m.offset)
}

/// Samples per pixel of [`white_peak_of_render`].
pub const WHITE_PEAK_SPP: u32 = 16;

/// The exposure of a rendered capture's sensor noise when no matrix is at hand (`render
/// --noise sensor`, Python's `sensor_noise`): the brightest value of a [`WHITE_PEAK_SPP`]-spp
/// render (lattice, seed 1) of `sys` with every display pixel white.
pub fn white_peak_of_render(sys: &System) -> f64 {
    let mut s = sys.clone();
    s.display.set_intensity(&vec![1.0; s.display.object_len()]);
    let cap = render(&s, &RenderSettings::lattice(WHITE_PEAK_SPP, 1, false));
    cap.channels
        .iter()
        .flatten()
        .fold(0.0f64, |a, &v| a.max(f64::from(v)))
}

/// A noisy dark frame (the capture of an all-black display, `m`'s offset) measured by `noise`
/// from the noise stream of `seed`.
pub fn dark_frame(m: &SystemMatrix, noise: &SensorNoise, seed: u64) -> Vec<f64> {
    m.offset
        .iter()
        .enumerate()
        .map(|(i, &o)| {
            noise.measure_at(
                f64::from(o),
                i as u64,
                &mut NoiseRng::new(&[seed, 0x4441_524B, i as u64]),
            )
        })
        .collect()
}

/// The black level each pixel sits at, from a measured dark frame (capture units, the sensor's
/// dark offset removed): what `recon::discrepancy::NoiseLevel::of_capture` takes as `offset`.
pub fn black_level_of(dark: &[f64], noise: &SensorNoise) -> Vec<f32> {
    dark.iter()
        .map(|&d| (d - noise.dark_offset_units()) as f32)
        .collect()
}

/// The measured capture of the linear object `truth` (the object size of `sys`'s display):
/// rendered by the Monte Carlo tracer at `set.spp` with the independent seed `set.seed + 1` (no
/// inverse crime with an H computed at `set.seed`), measured by `noise` from the stream
/// (`set.seed`, `index`). Returns (noisy frame, g = noisy frame − `dark`).
pub fn measured_capture(
    sys: &System,
    truth: &[f64],
    set: &DemoSettings,
    noise: &SensorNoise,
    dark: &[f64],
    index: u64,
) -> (Vec<f64>, Vec<f64>) {
    let mut s = sys.clone();
    s.display.set_intensity(truth);
    let cap = render(
        &s,
        &RenderSettings::lattice(set.spp, set.seed.wrapping_add(1), set.progress),
    );
    let noisy = measure_frame(
        cap.channels
            .iter()
            .flat_map(|c| c.iter().map(|&v| f64::from(v))),
        noise,
        set.seed,
        index,
    );
    let g: Vec<f64> = noisy.iter().zip(dark).map(|(a, d)| a - d).collect();
    (noisy, g)
}

/// The measured capture of the linear object `truth` computed from a matrix instead of the
/// tracer: `noise` applied to H·f + offset of `m` (an H of a different seed than the one that
/// reconstructs avoids the inverse crime) from the noise stream (`seed`, `index`).
pub fn noisy_capture_of(
    m: &SystemMatrix,
    truth: &[f64],
    noise: &SensorNoise,
    seed: u64,
    index: u64,
) -> Vec<f64> {
    measure_frame(
        m.capture_of(truth).iter().flatten().copied(),
        noise,
        seed,
        index,
    )
}

/// `noise` applied to each value of a clean frame, value i from the stream
/// (`seed`, "CAPT", `index`, i).
fn measure_frame(
    clean: impl Iterator<Item = f64>,
    noise: &SensorNoise,
    seed: u64,
    index: u64,
) -> Vec<f64> {
    clean
        .enumerate()
        .map(|(i, v)| {
            noise.measure_at(
                v,
                i as u64,
                &mut NoiseRng::new(&[seed, 0x4341_5054, index, i as u64]),
            )
        })
        .collect()
}
