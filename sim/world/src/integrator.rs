//! The user-side path tracer: radiance arriving along a ray that leaves the plate's front
//! face (a replica branch, with the camera ray's own direction) or a frontal pinhole.
//!
//! Estimator (pbrt-v4 `PathIntegrator`, §13.4): at every surface interaction the emitted
//! radiance is added, weighted by multiple importance sampling (power heuristic, Veach 1997)
//! against next-event estimation; next-event estimation samples every emitter (the lights and
//! the display) once at each interaction when there are at most `ALL_EMITTERS_MAX` of them (no
//! selection noise: a screen close to a hand and a ceiling light far above it are both
//! estimated at every vertex), otherwise one chosen uniformly, and traces a shadow ray per
//! sample; the BSDF is then sampled for the next direction. The environment (uniform in
//! direction) is found by BSDF sampling only, with weight 1: a cosine-weighted next-event
//! sample of it has the BSDF sample's density on a diffuse surface and a worse one on a glossy
//! surface, so it cost a shadow ray per vertex for at most half the environment's variance.
//! Measured when it was dropped (2026-11-27): eye contact from the camera-side table, 440 ×
//! 440, 64 paths, the same relative RMS difference of two seeds (1.91 % both) with 21 % fewer
//! scene rays and 17 % less render time; the gesture scene lit by the environment alone, 160 ×
//! 160, 32 spp, 5.32 % against 5.22 % at the same time. Where the shading normal
//! differs from the geometric one, both strategies use the folded BSDF of [`super::shading`]
//! (the part of the lobe below the geometric surface mirrored back above it), so no energy is
//! lost. `max_depth` interactions at most (1 = direct lighting only); Russian roulette from
//! the fourth interaction on, with survival probability max(throughput) (unbiased). One wavelength per path, scalar spectra.
//! Emissive mesh triangles are found only by BSDF sampling (weight 1; they are not
//! next-event-estimation targets). Surfaces are two-sided (the side the ray arrives on is the
//! front) unless single-sided, and alpha cut-outs and blended surfaces are passed through
//! inside the scene queries ([`super::coverage`]; the ray's key comes from
//! [`PathRng::ray_key`]); emission is one-sided (the side the triangle's winding faces).
//!
//! Polarisation: the display's light is polarised as the display model says; light scattered
//! by a surface or coming from the other emitters is taken as unpolarised. The result
//! therefore separates the display seen directly from everything else, and the caller weights
//! the two with the branch's TE/TM weights accordingly.
//!
//! Random numbers: a counter-based hash stream per path (the caller's key: seed, pixel, and
//! the sample and branch, or the replica and the path's index), the same for any thread
//! count. Through the waveguide (`render::UserSideSampler::Resampled`, the default, and
//! `Padded`) the numbers of the first vertex — each emitter's two area or direction numbers
//! and the BSDF direction's two — and, with `Padded`, the caller's branch-roulette decision
//! instead come from padded 2-D point sets ([`crate::sampler::padded`]) shared by the pixel's
//! paths of the same branch contact, so they are stratified over the pixel (the lobe choice,
//! the display's third number and every later vertex stay hashed). Each point is marginally
//! uniform, so the estimator is unchanged in expectation; its noise is lower where the direct
//! light varies smoothly (the eye-contact scene at 440 × 440, every branch traced: 2.99 %
//! against 3.95 % relative RMS error for two 32-spp halves, 7 % more time).

use glam::{DVec2, DVec3};

use super::bsdf::Frame;
use super::shading::FoldedBsdf;
use super::{Emitter, World};
use crate::display::Display;
use crate::sampler::PathRng;

/// Radiance along a ray, split by polarisation state.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Radiance {
    /// The display seen directly (polarised as the display).
    pub display: f64,
    /// Everything else (unpolarised).
    pub other: f64,
}

/// Counters of user-side work.
#[derive(Clone, Copy, Debug, Default)]
pub struct PathCounts {
    /// Rays traced against the scene (closest-hit and shadow).
    pub rays: u64,
}

/// What a ray meets first.
#[derive(Clone, Copy, Debug)]
#[allow(missing_docs)] // the fields are named for what they hold: distance, triangle, barycentrics, radiance
pub enum Hit {
    /// A mesh triangle at distance `t` with barycentric coordinates `bary`.
    Surface { t: f64, tri: u32, bary: [f64; 3] },
    /// Light `index` at distance `t`, emitting radiance `le`.
    Light { t: f64, index: usize, le: f64 },
    /// The display at distance `t`, emitting radiance `le`.
    Display { t: f64, le: f64 },
    /// Nothing: the ray leaves the scene.
    Escape,
}

/// The [`PathRng::pair`] slot of the first BSDF direction (emitters use their index).
pub const BSDF_SLOT: u64 = u64::MAX;

/// The [`PathRng::pair`] slot of the branch roulette's decision (its first number).
pub const ROULETTE_SLOT: u64 = u64::MAX - 1;

/// Up to this many emitters, next-event estimation samples each of them at every vertex.
pub const ALL_EMITTERS_MAX: usize = 8;

/// Offset of a ray origin along the geometric normal, relative to the coordinates' size.
#[inline]
fn offset_eps(p: DVec3) -> f64 {
    1e-9 * (1.0 + p.abs().max_element()) * 1e3
}

impl World {
    fn closest(
        &self,
        disp: &Display,
        o: DVec3,
        d: DVec3,
        skip: Option<u32>,
        lambda_nm: f64,
        ray_key: u64,
    ) -> Hit {
        let mut best = Hit::Escape;
        let mut tmax = f64::INFINITY;
        if let Some(h) = self.mesh_hit(o, d, tmax, skip, ray_key) {
            tmax = h.t;
            best = Hit::Surface {
                t: h.t,
                tri: h.triangle,
                bary: h.bary,
            };
        }
        for (i, l) in self.lights.iter().enumerate() {
            if let Some((t, le)) = l.hit(o, d, tmax, lambda_nm) {
                tmax = t;
                best = Hit::Light { t, index: i, le };
            }
        }
        if self.display.is_some() && d.z != 0.0 {
            let t = (disp.z_mm - o.z) / d.z;
            if t > 0.0 && t < tmax {
                let q = o + d * t;
                if disp.on_lcd(q.truncate()) {
                    let le = if d.z < 0.0 {
                        disp.spectral_radiance_at(q.truncate(), lambda_nm)
                    } else {
                        0.0
                    };
                    best = Hit::Display { t, le };
                }
            }
        }
        best
    }

    /// True if nothing blocks the segment from `o` along unit `d` up to `dist` (the target
    /// emitter itself excluded), for a shadow ray of key `ray_key`.
    #[allow(clippy::too_many_arguments)]
    fn visible(
        &self,
        disp: &Display,
        o: DVec3,
        d: DVec3,
        dist: f64,
        skip: Option<u32>,
        target: Emitter,
        ray_key: u64,
    ) -> bool {
        let tmax = dist * (1.0 - 1e-9);
        for (i, l) in self.lights.iter().enumerate() {
            if target != Emitter::Light(i) && l.hit(o, d, tmax, 550.0).is_some() {
                return false;
            }
        }
        if target != Emitter::Display && self.display.is_some() && d.z != 0.0 {
            let t = (disp.z_mm - o.z) / d.z;
            if t > 0.0 && t < tmax && disp.on_lcd((o + d * t).truncate()) {
                return false;
            }
        }
        self.mesh_unoccluded(o, d, tmax, skip, ray_key)
    }

    /// Solid-angle density with which next-event estimation from `p` picks direction `d`
    /// reaching emitter `e` at distance `t` (including the emitter choice).
    fn light_pdf(&self, disp: &Display, e: Emitter, p: DVec3, d: DVec3, t: f64) -> f64 {
        if self.emitters.is_empty() {
            return 0.0;
        }
        let sel = self.selection_probability();
        sel * match e {
            Emitter::Light(i) => self.lights[i].pdf(p, d, t),
            Emitter::Display => match &self.display {
                Some(dl) => {
                    let q = p + d * t;
                    let cos_l = (-d.z).max(0.0);
                    if cos_l <= 0.0 {
                        0.0
                    } else {
                        dl.pdf_area(disp, q.truncate()) * t * t / cos_l
                    }
                }
                None => 0.0,
            },
            // Not a next-event target: found by BSDF sampling only (module docs).
            Emitter::Environment => 0.0,
        }
    }

    /// Probability that next-event estimation samples a given emitter at a vertex.
    fn selection_probability(&self) -> f64 {
        if self.emitters.len() <= ALL_EMITTERS_MAX {
            1.0
        } else {
            1.0 / self.emitters.len() as f64
        }
    }

    /// Samples one emitter for next-event estimation from `p`: (direction, distance, incident
    /// radiance / combined density, density for MIS or None if delta, emitter).
    fn sample_emitter(
        &self,
        disp: &Display,
        slot: usize,
        p: DVec3,
        lambda_nm: f64,
        rng: &mut PathRng,
    ) -> Option<(DVec3, f64, f64, Option<f64>, Emitter)> {
        let e = self.emitters[slot];
        let sel = self.selection_probability();
        let [u0, u1] = rng.pair(slot as u64);
        let u2 = rng.uniform();
        match e {
            Emitter::Light(i) => {
                let s = self.lights[i].sample(p, [u0, u1], lambda_nm)?;
                let pdf = sel * s.pdf;
                Some((s.wi, s.dist, s.li / pdf, (!s.delta).then_some(pdf), e))
            }
            Emitter::Display => {
                let dl = self.display.as_ref()?;
                let q2 = dl.sample_point(disp, [u0, u1, u2]);
                let q = DVec3::new(q2.x, q2.y, disp.z_mm);
                let v = q - p;
                let dist = v.length();
                if dist <= 0.0 {
                    return None;
                }
                let wi = v / dist;
                let cos_l = -wi.z;
                if cos_l <= 0.0 {
                    return None;
                }
                let pdf = sel * dl.pdf_area(disp, q2) * dist * dist / cos_l;
                let le = disp.spectral_radiance_at(q2, lambda_nm);
                (pdf > 0.0).then_some((wi, dist, le / pdf, Some(pdf), e))
            }
            // Never in `emitters` (module docs).
            Emitter::Environment => None,
        }
    }

    /// What the first ray of a path from `o` along `d` meets: the hit [`Self::radiance`]
    /// finds first, for paths that start on one ray to share (see
    /// [`Self::first_hit_shareable`]).
    pub fn path_first_hit(
        &self,
        disp: &Display,
        o: DVec3,
        d: DVec3,
        lambda_nm: f64,
        rng: &PathRng,
    ) -> Hit {
        self.closest(disp, o, d, None, lambda_nm, rng.ray_key())
    }

    /// Whether paths that start on the same ray (origin, direction, wavelength) meet the
    /// same first hit whatever their random numbers: yes unless some material's coverage is
    /// not plain (alpha cut-outs or blending, single-sided faces: `coverage_filter`), where
    /// the hit filter sees the path's ray key (conservative: only blending draws from it).
    pub fn first_hit_shareable(&self) -> bool {
        !self.coverage_filter
    }

    /// Spectral radiance arriving at `o` from direction −`d` (unit `d` is the ray's
    /// direction), at `lambda_nm`. `first`: the path's first hit when it is already known
    /// (from [`Self::path_first_hit`] of the same ray; None: traced here); the same numbers are
    /// drawn either way, so the result is the same.
    ///
    /// Longer than the project's ~120-line guide on purpose: it is the one bounce loop of the
    /// user-side path (emission with MIS, next-event estimation, BSDF sampling, Russian
    /// roulette), whose state (throughput, previous pdf, frame, counters) lives across every
    /// step of an iteration; its steps already call out to named functions (`closest`,
    /// `light_pdf`, `sample_emitter`, `visible`, the BSDF's `sample`).
    #[allow(clippy::too_many_arguments)]
    pub fn radiance(
        &self,
        disp: &Display,
        o: DVec3,
        d: DVec3,
        lambda_nm: f64,
        rng: &mut PathRng,
        counts: &mut PathCounts,
        mut first: Option<Hit>,
    ) -> Radiance {
        let mut out = Radiance::default();
        let mut beta = 1.0;
        let (mut o, mut d) = (o, d);
        let mut skip: Option<u32> = None;
        // Density of the BSDF sample that produced the current ray (None: camera ray).
        let mut prev_pdf: Option<f64> = None;
        let mut depth = 0u32;
        loop {
            let hit = match first.take() {
                Some(h) => h,
                None => {
                    counts.rays += 1;
                    self.closest(disp, o, d, skip, lambda_nm, rng.ray_key())
                }
            };
            let mis = |e: Emitter, t: f64| match prev_pdf {
                None => 1.0,
                Some(pb) => {
                    let pl = self.light_pdf(disp, e, o, d, t);
                    pb * pb / (pb * pb + pl * pl)
                }
            };
            let (t, tri, bary) = match hit {
                Hit::Escape => {
                    if let Some(env) = &self.environment {
                        out.other += beta
                            * env.radiance(d, lambda_nm)
                            * mis(Emitter::Environment, f64::INFINITY);
                    }
                    break;
                }
                Hit::Light { t, index, le } => {
                    out.other += beta * le * mis(Emitter::Light(index), t);
                    break;
                }
                Hit::Display { t, le } => {
                    let v = beta * le * mis(Emitter::Display, t);
                    if prev_pdf.is_none() {
                        out.display += v;
                    } else {
                        out.other += v;
                    }
                    break;
                }
                Hit::Surface { t, tri, bary } => (t, tri, bary),
            };
            let tv = self.mesh.triangles[tri as usize];
            let [a, b, c] = tv.map(|i| self.mesh.positions_mm[i as usize]);
            let p = a * bary[0] + b * bary[1] + c * bary[2];
            let _ = t;
            let mut ng = (b - a).cross(c - a).normalize_or_zero();
            let mut ns = (self.mesh.normals[tv[0] as usize] * bary[0]
                + self.mesh.normals[tv[1] as usize] * bary[1]
                + self.mesh.normals[tv[2] as usize] * bary[2])
                .normalize_or_zero();
            if ns == DVec3::ZERO {
                ns = ng;
            }
            let front = d.dot(ng) < 0.0;
            let uv = self.uv_at(tri, bary);
            let mut ns = self.mapped_normal(tri, bary, uv, ns);
            let mat = &self.materials[self.mesh.material_ids[tri as usize] as usize];
            if front && mat.emits() {
                out.other += beta * mat.emitted(uv, lambda_nm);
            }
            if depth >= self.max_depth {
                break;
            }
            depth += 1;
            if !front {
                ng = -ng;
                ns = -ns;
            }
            if ns.dot(ng) <= 0.0 {
                ns = ng;
            }
            let wo = -d;
            let mut frame = Frame::from_normal(ns);
            let mut wo_l = frame.to_local(wo);
            if wo_l.z <= 0.0 {
                frame = Frame::from_normal(ng);
                wo_l = frame.to_local(wo);
            }
            let bsdf = FoldedBsdf::new(
                mat.bsdf_tinted(uv, self.color_at(tri, bary), lambda_nm),
                &frame,
                ng,
            );
            let origin = p + ng * offset_eps(p);
            // Next-event estimation.
            let n_em = self.emitters.len();
            let picks = if n_em <= ALL_EMITTERS_MAX {
                0..n_em
            } else {
                let k = ((rng.uniform() * n_em as f64) as usize).min(n_em - 1);
                k..k + 1
            };
            for k in picks {
                let Some((wi, dist, li_over_pdf, pdf_l, e)) =
                    self.sample_emitter(disp, k, p, lambda_nm, rng)
                else {
                    continue;
                };
                if wi.dot(ng) <= 0.0 || li_over_pdf.is_nan() || li_over_pdf <= 0.0 {
                    continue;
                }
                let wi_l = frame.to_local(wi);
                let f = bsdf.eval(wo_l, wi_l);
                if f > 0.0 {
                    counts.rays += 1;
                    if self.visible(disp, origin, wi, dist, Some(tri), e, rng.ray_key()) {
                        let w = match pdf_l {
                            Some(pl) => {
                                let pb = bsdf.pdf(wo_l, wi_l);
                                pl * pl / (pl * pl + pb * pb)
                            }
                            None => 1.0,
                        };
                        out.other += beta * f * li_over_pdf * w;
                    }
                }
            }
            // BSDF sampling.
            let lobe = rng.uniform();
            let [d0, d1] = rng.pair(BSDF_SLOT);
            rng.end_first_vertex();
            let Some(s) = bsdf.sample(wo_l, [lobe, d0, d1]) else {
                break;
            };
            let wi = frame.to_world(s.wi);
            if wi.dot(ng) <= 0.0 || !s.weight.is_finite() || s.weight <= 0.0 {
                break;
            }
            beta *= s.weight;
            prev_pdf = Some(s.pdf);
            o = origin;
            d = wi.normalize();
            skip = Some(tri);
            if depth > 3 && beta < 1.0 {
                let q = (1.0 - beta).max(0.0);
                if rng.uniform() < q {
                    break;
                }
                beta /= 1.0 - q;
            }
        }
        out
    }
}

/// The unpolarised and polarised parts of a branch's weight: (display weight, other weight).
#[inline]
pub fn branch_weights(weight: [f64; 2], display_pol: [f64; 2]) -> (f64, f64) {
    (
        display_pol[0] * weight[0] + display_pol[1] * weight[1],
        0.5 * (weight[0] + weight[1]),
    )
}

/// Exit point of a branch on the front face as a 3-D point.
#[inline]
pub fn exit_point(p: DVec2) -> DVec3 {
    DVec3::new(p.x, p.y, 0.0)
}
