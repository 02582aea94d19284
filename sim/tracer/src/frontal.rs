//! Ground truth for learning: the 3-D scene as an ideal pinhole camera at the see-through
//! screen sees it (`frontal`), its depth and an object mask.
//!
//! Model: the pinhole sits on the front face at the centre of the bottom vHOE (x = y = z = 0),
//! the point the periscope makes the hidden camera look from, and looks along −z. Pixel
//! (c, r) of a W×H frontal image looks along the chief-ray direction of the capture at the
//! corresponding fractional crop position (c + ½)·W_crop/W, so the frontal image covers the
//! capture's own angular field (each replica in the capture is this view, shifted). Values:
//! E[R_c(λ)/∫R_c · L(λ)/p(λ)] with λ drawn from p ∝ Σ_c R_c(λ)/∫R_c (the sensor's own
//! response, tabulated on 1 nm bins over the sampling band: for a mono sensor the spectral
//! weight is then constant and only the scene's spectrum adds noise), the same sensor
//! response and capture unit (1 = display white) as the capture, but no waveguide, no lens
//! falloff and no noise; pixel-area antialiasing with `spp` samples. Pixel position and
//! wavelength come from the capture's rank-1 lattice (stratified within a pixel), the
//! user-side path from a hash stream per (seed, pixel, sample) whose first vertex draws its
//! light and BSDF numbers from padded sets stratified over the pixel's samples (as the
//! capture's user side does, `render::UserSideSampler`). Depth and mask come from
//! each pixel's centre ray: depth = −z of the first surface hit in mm (the display plane
//! included, +inf where nothing is hit); mask = object index + 1 for objects, 65535 for the
//! display, 0 for nothing (lights and the environment).

use glam::{DVec2, DVec3};

use crate::sampler::PathRng;
use crate::sampler::{LatticeRule, PixelSampler, SamplerKind};
use crate::system::System;
use crate::world::colour::{ColourWeights, FrontalSpace};
use crate::world::integrator::PathCounts;

/// One rendered row: values (width × channels), depth, mask, rays traced.
type FrontalRow = (Vec<f64>, Vec<f32>, Vec<u16>, u64);

/// Mask value of the display.
pub use stscam_world::MASK_DISPLAY;

/// The frontal ground truth of a render.
#[derive(Clone, Debug)]
pub struct Frontal {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Channel names (as the capture for [`FrontalSpace::Sensor`], else X, Y, Z or R, G, B).
    pub channel_names: Vec<&'static str>,
    /// The colour space of `channels`.
    pub space: FrontalSpace,
    /// Channels, row-major.
    pub channels: Vec<Vec<f32>>,
    /// Depth in mm (+inf where nothing is hit).
    pub depth_mm: Vec<f32>,
    /// Object mask.
    pub mask: Vec<u16>,
    /// Rays traced.
    pub rays: u64,
}

/// A piecewise-constant density over the band ∝ Σ_c R_c(λ)/∫R_c on 1 nm bins (for a
/// standard colour space ∝ Σ_k cmf_k(λ)/∫cmf_k instead).
struct ResponseTable {
    lo: f64,
    step: f64,
    cdf: Vec<f64>,
    pdf: Vec<f64>,
}

impl ResponseTable {
    fn new(sys: &System, colour: Option<&ColourWeights>, lo: f64, hi: f64) -> ResponseTable {
        let n = ((hi - lo).ceil() as usize).clamp(1, 100_000);
        let step = (hi - lo) / n as f64;
        let w: Vec<f64> = (0..n)
            .map(|i| {
                let l = lo + (i as f64 + 0.5) * step;
                match colour {
                    Some(cw) => cw.density(l).max(0.0),
                    None => crate::render::channel_weights(sys, l)
                        .iter()
                        .sum::<f64>()
                        .max(0.0),
                }
            })
            .collect();
        let total: f64 = w.iter().sum::<f64>() * step;
        let (pdf, cdf) = if total > 0.0 {
            let pdf: Vec<f64> = w.iter().map(|v| v / total).collect();
            let mut acc = 0.0;
            let cdf = pdf
                .iter()
                .map(|p| {
                    acc += p * step;
                    acc
                })
                .collect();
            (pdf, cdf)
        } else {
            let pdf = vec![1.0 / (hi - lo); n];
            let cdf = (1..=n).map(|i| i as f64 / n as f64).collect();
            (pdf, cdf)
        };
        ResponseTable { lo, step, cdf, pdf }
    }

    /// (λ, density) for a uniform number `u`.
    fn sample(&self, u: f64) -> (f64, f64) {
        let last = *self.cdf.last().unwrap_or(&1.0);
        let v = u * last;
        let k = self
            .cdf
            .partition_point(|c| *c <= v)
            .min(self.cdf.len() - 1);
        let before = if k == 0 { 0.0 } else { self.cdf[k - 1] };
        let p = self.pdf[k];
        let frac = if p > 0.0 {
            ((v - before) / (p * self.step)).clamp(0.0, 1.0)
        } else {
            0.5
        };
        (self.lo + (k as f64 + frac) * self.step, p / last)
    }
}

/// Direction of the frontal pixel at fractional position (x, y) in [0, W)×[0, H).
fn direction(sys: &System, w: usize, h: usize, x: f64, y: f64) -> DVec3 {
    let cam = &sys.camera;
    let fx = x * cam.width_px as f64 / w as f64;
    let fy = y * cam.height_px as f64 / h as f64;
    let (col, row) = (fx.floor(), fy.floor());
    let img = cam.image_point_mm(col as usize, row as usize, [fx - col, fy - row]);
    cam.ray_through(img, DVec2::ZERO).dir
}

/// Renders the frontal image, depth and mask at `width`×`height` with `spp` samples per pixel,
/// in the sensor's colour space.
pub fn render_frontal(
    sys: &System,
    width: usize,
    height: usize,
    spp: u32,
    seed: u64,
) -> Option<Frontal> {
    render_frontal_in(sys, width, height, spp, seed, FrontalSpace::Sensor)
}

/// As [`render_frontal`], with the channels in `space` (wavelengths then drawn in proportion
/// to Σ_k cmf_k/∫cmf_k for a standard space; see [`crate::world::colour`]).
pub fn render_frontal_in(
    sys: &System,
    width: usize,
    height: usize,
    spp: u32,
    seed: u64,
    space: FrontalSpace,
) -> Option<Frontal> {
    let world = sys.world.as_deref()?;
    let disp = &sys.display;
    let (lo, hi) = (
        sys.scene.sampling.lambda_min_nm,
        sys.scene.sampling.lambda_max_nm,
    );
    let colour = ColourWeights::new(space, lo, hi);
    let (nch, channel_names, space) = match (&colour, space.channel_names()) {
        (Some(_), Some(names)) => (3, names, space),
        _ => (
            sys.response.curves.len(),
            sys.response.names.clone(),
            FrontalSpace::Sensor,
        ),
    };
    let weights = |lambda: f64| -> [f64; 4] {
        match &colour {
            Some(cw) => {
                let [a, b, c] = cw.at(lambda);
                [a, b, c, 0.0]
            }
            None => crate::render::channel_weights(sys, lambda),
        }
    };
    let origin = DVec3::ZERO;
    let table = ResponseTable::new(sys, colour.as_ref(), lo, hi);
    let rule = LatticeRule::korobov(u64::from(spp));
    let cancel = crate::cancel::current();
    let empty_row = || -> FrontalRow {
        (
            vec![0.0; width * nch],
            vec![f32::INFINITY; width],
            vec![0u16; width],
            0,
        )
    };
    let rows: Vec<FrontalRow> = crate::rows::par_rows(
        height,
        false,
        "frontal rows",
        &cancel,
        |r| {
            let (mut vals, mut depth, mut mask, _) = empty_row();
            let mut counts = PathCounts::default();
            for c in 0..width {
                let pixel = (r * width + c) as u64;
                let sampler = PixelSampler::new(SamplerKind::Lattice, seed ^ 0xF80_17A1, pixel)
                    .with_rule(rule);
                let pad_key = PathRng::padded_key(&[seed, pixel, 0xF80_17A1]);
                for i in 0..u64::from(spp) {
                    let mut rng =
                        PathRng::new(&[seed, pixel, i, 0xF80_17A1]).with_padded(pad_key, i, spp);
                    let u = sampler.get(i);
                    let (ux, uy, ul) = (u[0], u[1], u[4]);
                    let d = direction(sys, width, height, c as f64 + ux, r as f64 + uy);
                    let (lambda, pdf) = table.sample(ul);
                    if pdf.is_nan() || pdf <= 0.0 {
                        continue;
                    }
                    let l = world.radiance(disp, origin, d, lambda, &mut rng, &mut counts, None);
                    let v = (l.display + l.other) / pdf;
                    if !v.is_finite() {
                        continue;
                    }
                    let rc = weights(lambda);
                    for (k, w) in rc.iter().enumerate().take(nch) {
                        vals[c * nch + k] += v * w;
                    }
                }
                let inv = 1.0 / f64::from(spp.max(1));
                for k in 0..nch {
                    vals[c * nch + k] *= inv;
                }
                let d = direction(sys, width, height, c as f64 + 0.5, r as f64 + 0.5);
                let depth_key = crate::sampler::hash(&[seed, pixel, 0xDE97]);
                if let Some((t, m)) = world.first_hit(disp, origin, d, depth_key) {
                    depth[c] = (-(origin.z + d.z * t)) as f32;
                    mask[c] = m;
                }
            }
            (vals, depth, mask, counts.rays)
        },
        |_| empty_row(),
    );
    let mut channels = vec![vec![0f32; width * height]; nch];
    let mut depth_mm = Vec::with_capacity(width * height);
    let mut mask = Vec::with_capacity(width * height);
    let mut rays = 0;
    for (r, (v, d, m, n)) in rows.into_iter().enumerate() {
        for c in 0..width {
            for (k, ch) in channels.iter_mut().enumerate() {
                ch[r * width + c] = v[c * nch + k] as f32;
            }
        }
        depth_mm.extend(d);
        mask.extend(m);
        rays += n;
    }
    Some(Frontal {
        width,
        height,
        channel_names,
        space,
        channels,
        depth_mm,
        mask,
        rays,
    })
}
