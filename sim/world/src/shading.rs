//! Shading normals without energy loss: the BSDF of a surface whose shading normal n_s
//! (interpolated vertex normals, a normal map) differs from its geometric normal n_g.
//!
//! Problem: the BSDF lives in the hemisphere about n_s, but light can only leave a reflecting
//! surface into the hemisphere about n_g. A direction sampled about n_s that dips below the
//! geometric surface used to end the path, so a white Lambertian sphere in a white furnace
//! lost ≈ 0.03 % of the light at the first hit (and more at every further bounce); NEE and
//! BSDF sampling lost the same part, so MIS did not hide it (Veach 1997, §5.3, on the
//! non-physical nature of shading normals; Schüßler et al. 2017, "Microfacet-based Normal
//! Mapping for Robust Monte Carlo Path Tracing", ACM TOG 36(6), §1–3, on the energy lost and the
//! black artefacts).
//!
//! Model (the *folded* BSDF): the part of the shading lobe below the geometric tangent plane is
//! mirrored back across that plane, R(ω) = ω − 2(ω·n_g)n_g, like the perfectly specular
//! tangent facet of Schüßler et al. 2017 that sends the light which a perturbed facet scatters
//! into the surface back out (there the mirror plane is the facet perpendicular to n_s; here it
//! is the geometric plane, so one reflection always suffices and no random walk is needed):
//!
//!   f′(ωo, ωi)·cos′ = f(ωo, ωi)·cos_s(ωi) + f(ωo, R ωi)·cos_s(R ωi),   ωi above n_g,
//!   p′(ωo, ωi)      = p(ωo, ωi) + p(ωo, R ωi).
//!
//! R is an isometry of the sphere (a change of variables with Jacobian 1), so
//! ∫_{H_g} f′cos′ dω = ∫_{H_s} f cos_s dω: the folded BSDF reflects exactly the energy of the
//! shading-frame BSDF (a white Lambertian surface reflects all of it, as a flat-shaded one
//! does), and sampling it is sampling the shading lobe and reflecting directions that fall
//! below n_g, with density p′. Next-event estimation evaluates f′ and p′, BSDF sampling returns
//! f′/p′ and p′, so the MIS weights of both strategies use the same densities (unbiased; for a
//! Lambertian lobe f′cos′/p′ = albedo exactly). Where n_s = n_g, R maps the lobe's hemisphere
//! onto its complement, both extra terms are zero and the BSDF is the unfolded one, bit for bit.
//!
//! Assumption: the outgoing direction is above both the geometric and the shading surface (the
//! caller falls back to n_g as shading normal otherwise). The folded BSDF is not reciprocal in
//! general (neither is any shading-normal BSDF, Veach 1997 §5.3).

use glam::DVec3;

use super::bsdf::{Bsdf, BsdfSample, Frame};

/// The BSDF at a hit in its shading frame, with the geometric normal for the fold.
#[derive(Clone, Copy, Debug)]
pub struct FoldedBsdf {
    /// The shading-frame BSDF.
    pub bsdf: Bsdf,
    /// The geometric normal in the shading frame (unit; `None` when it is the frame's +z, so
    /// nothing folds).
    ng_local: Option<DVec3>,
}

impl FoldedBsdf {
    /// `bsdf` in shading frame `frame`, on a surface with unit geometric normal `ng` (world).
    pub fn new(bsdf: Bsdf, frame: &Frame, ng: DVec3) -> FoldedBsdf {
        let g = frame.to_local(ng);
        let ng_local = (frame.n != ng).then_some(g);
        FoldedBsdf { bsdf, ng_local }
    }

    /// Mirror image of local `v` across the geometric tangent plane.
    #[inline]
    fn reflect(g: DVec3, v: DVec3) -> DVec3 {
        v - 2.0 * v.dot(g) * g
    }

    /// f′·cos′ (local directions; `wi` above the geometric surface).
    #[inline]
    pub fn eval(&self, wo: DVec3, wi: DVec3) -> f64 {
        let f = self.bsdf.eval(wo, wi);
        match self.ng_local {
            Some(g) => f + self.bsdf.eval(wo, Self::reflect(g, wi)),
            None => f,
        }
    }

    /// p′ (local directions; `wi` above the geometric surface).
    #[inline]
    pub fn pdf(&self, wo: DVec3, wi: DVec3) -> f64 {
        let p = self.bsdf.pdf(wo, wi);
        match self.ng_local {
            Some(g) => p + self.bsdf.pdf(wo, Self::reflect(g, wi)),
            None => p,
        }
    }

    /// Samples the folded BSDF: a shading-lobe sample, reflected across the geometric tangent
    /// plane if it falls below it; weight f′cos′/p′ and density p′. `None` where the shading
    /// lobe gives no sample.
    pub fn sample(&self, wo: DVec3, u: [f64; 3]) -> Option<BsdfSample> {
        let s = self.bsdf.sample(wo, u)?;
        let Some(g) = self.ng_local else {
            return Some(s);
        };
        let wi = if s.wi.dot(g) <= 0.0 {
            Self::reflect(g, s.wi)
        } else {
            s.wi
        };
        if wi.dot(g) <= 0.0 {
            return None;
        }
        let r = Self::reflect(g, wi);
        let (fr, pr) = (self.bsdf.eval(wo, r), self.bsdf.pdf(wo, r));
        if wi == s.wi && fr == 0.0 && pr == 0.0 {
            // The mirror direction is outside the lobe: the unfolded sample, unchanged.
            return Some(s);
        }
        let f = self.bsdf.eval(wo, wi) + fr;
        let p = self.bsdf.pdf(wo, wi) + pr;
        (p > 0.0 && f.is_finite()).then(|| BsdfSample {
            wi,
            weight: f / p,
            pdf: p,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::PathRng;

    /// Directional albedo ∫ f′cos′ over the geometric hemisphere by uniform-hemisphere
    /// quadrature about n_g, and the sampling estimate E[weight] (Monte Carlo); both must equal
    /// the shading lobe's own albedo. Tolerance: 4 SEM (+ 2e-3 for the quadrature) for the
    /// estimate; the unfolded estimate (what the integrator did before) must fail it.
    #[test]
    fn fold_keeps_the_energy_of_the_shading_lobe() {
        let ng = DVec3::Z;
        let ns = DVec3::new(0.35, 0.0, 1.0).normalize();
        let frame = Frame::from_normal(ns);
        let wo = frame.to_local(DVec3::new(-0.8, 0.1, 0.3).normalize());
        for bsdf in [
            Bsdf::Diffuse { albedo: 1.0 },
            Bsdf::MetallicRoughness {
                base: 0.9,
                metallic: 0.0,
                roughness: 0.5,
            },
        ] {
            let fb = FoldedBsdf::new(bsdf, &frame, ng);
            let g = frame.to_local(ng);
            let n = 400_000;
            let mut rng = PathRng::new(&[7, 1]);
            let (mut sum_shading, mut sum_folded, mut s_lost) = (0.0, 0.0, 0.0);
            let (mut sw, mut sw2, mut pdf_err) = (0.0, 0.0, 0.0f64);
            for _ in 0..n {
                // Uniform directions on the sphere (pdf 1/4π).
                let z = 2.0 * rng.uniform() - 1.0;
                let phi = 2.0 * std::f64::consts::PI * rng.uniform();
                let r = (1.0 - z * z).max(0.0).sqrt();
                let w = DVec3::new(r * phi.cos(), r * phi.sin(), z);
                let wl = frame.to_local(w);
                sum_shading += bsdf.eval(wo, wl);
                if w.z > 0.0 {
                    sum_folded += fb.eval(wo, wl);
                }
                let u = [rng.uniform(), rng.uniform(), rng.uniform()];
                match fb.sample(wo, u) {
                    Some(s) => {
                        assert!(s.wi.dot(g) > 0.0);
                        sw += s.weight;
                        sw2 += s.weight * s.weight;
                        pdf_err = pdf_err.max((fb.pdf(wo, s.wi) - s.pdf).abs() / s.pdf);
                    }
                    None => {}
                }
                if let Some(s) = bsdf.sample(wo, u)
                    && frame.to_world(s.wi).z > 0.0
                {
                    s_lost += s.weight;
                }
            }
            let to = 4.0 * std::f64::consts::PI / n as f64;
            let (a_s, a_f) = (sum_shading * to, sum_folded * to);
            assert!((a_s - a_f).abs() < 0.01 * a_s, "{bsdf:?}: {a_s} vs {a_f}");
            let m = sw / n as f64;
            let sem = ((sw2 / n as f64 - m * m).max(0.0) / n as f64).sqrt();
            let unfolded = s_lost / n as f64;
            assert!(
                (m - a_s).abs() < 4.0 * sem + 0.01 * a_s,
                "{bsdf:?}: {m} ± {sem} vs {a_s}"
            );
            assert!(pdf_err < 1e-12, "{pdf_err}");
            // The unfolded estimator loses the part of the lobe below n_g: it must fail.
            assert!(
                m - unfolded > 10.0 * sem + 0.005,
                "{bsdf:?}: {m} vs lost {unfolded}"
            );
            if let Bsdf::Diffuse { .. } = bsdf {
                assert!(
                    (m - 1.0).abs() < 1e-12 && sem < 1e-12,
                    "Lambert: weight {m}"
                );
            }
        }
    }

    /// Where the shading normal is the geometric one, the folded BSDF is the BSDF, bit for bit.
    #[test]
    fn no_fold_without_a_shading_normal() {
        let frame = Frame::from_normal(DVec3::new(0.1, 0.2, 1.0));
        let b = Bsdf::MetallicRoughness {
            base: 0.5,
            metallic: 0.3,
            roughness: 0.4,
        };
        let fb = FoldedBsdf::new(b, &frame, frame.n);
        let wo = DVec3::new(0.3, -0.2, 0.9).normalize();
        for u in [[0.05, 0.3, 0.7], [0.9, 0.1, 0.2], [0.5, 0.99, 0.01]] {
            assert_eq!(fb.sample(wo, u), b.sample(wo, u));
        }
        let wi = DVec3::new(-0.5, 0.1, 0.4).normalize();
        assert_eq!(fb.eval(wo, wi), b.eval(wo, wi));
        assert_eq!(fb.pdf(wo, wi), b.pdf(wo, wi));
    }
}
