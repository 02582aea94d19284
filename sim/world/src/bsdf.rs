//! Spectral BSDFs of scene surfaces: one wavelength, scalar reflectance, evaluated and sampled
//! in a local shading frame whose normal is +z.
//!
//! Model (reflection only; no transmission; both directions point away from the surface):
//! - `Diffuse`: Lambert, f = albedo/π, sampled with the cosine-weighted hemisphere density
//!   cos θi/π (Malley's method).
//! - `MetallicRoughness`: the glTF 2.0 metallic-roughness material (glTF 2.0 specification,
//!   Appendix B "BRDF Implementation"), material = mix(dielectric, metal, metallic):
//!   c_diff = base·(1 − metallic), F0 = mix(0.04, base, metallic), α = roughness²,
//!   F = F0 + (1 − F0)(1 − |V·H|)⁵ (Schlick 1994),
//!   f = c_diff/π·T(N·V)·T(N·L)/(1 − 0.04) + F·D(H)·G2(V, L)/(4|N·V||N·L|),
//!   T(c) = 1 − F_d(c), F_d = Schlick with F0 = 0.04 (the dielectric's Fresnel).
//!   **Deviation from the specification**: its `fresnel_mix` weights the diffuse lobe by
//!   (1 − F(V·H)), which is not energy-bounded: for base = 1, metallic = 0, roughness 0 the
//!   directional albedo is 1.025 at θo = 60°, 1.35 at 80° and 1.85 at 89° (measured with this
//!   module's estimator), because the specular lobe reflects F(θo) while the diffuse lobe, whose
//!   half vectors are far from grazing, still keeps ≈ 96 %. We use instead the Fresnel
//!   transmittance into and out of the dielectric, T(N·V)·T(N·L) (the coupling of Shirley et
//!   al. 1997 and Ashikhmin & Shirley 2000), divided by 1 − 0.04 so that it equals the
//!   specification's weight 1 − F0 at normal incidence. It is reciprocal, and the diffuse
//!   albedo is c_diff·T(N·V)·(20/21) (∫ T(cos θ)·2cos θ dcos θ = (1 − 0.04)·20/21), leaving
//!   room for the specular lobe, whose albedo is at most F at the viewing angle plus a few
//!   percent for rough surfaces.
//!   D is the GGX / Trowbridge–Reitz distribution D = α²/(π((N·H)²(α² − 1) + 1)²) (Walter et
//!   al. 2007). G2 is the **height-correlated** Smith masking-shadowing function
//!   G2 = 1/(1 + Λ(V) + Λ(L)), Λ(ω) = (√(1 + α² tan²θ) − 1)/2 (Heitz 2014, "Understanding the
//!   Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 3(2), eq. 99), the form of the
//!   Khronos glTF Sample Viewer's `V_GGX`; it is never larger than the separable product
//!   G1(V)·G1(L).
//!
//! Assumptions and deviations:
//! - α is clamped to ≥ [`MIN_ALPHA`] = 1e−3 (roughness ≈ 0.032), so roughness 0 is a very sharp
//!   but finite GGX lobe instead of a Dirac mirror (which the eval/pdf interface cannot
//!   represent). Parameters are clamped to [0, 1]; a NaN base or metallic is read as 0 and a
//!   NaN roughness as 1 (the glTF default).
//! - The model is single-scattering: energy lost to masking is not reinserted (no multiple
//!   scattering compensation), so rough metals are darker than a white furnace; the
//!   (1 − F(V·H)) weighting of the diffuse lobe is the specification's approximation and does
//!   not conserve energy exactly.
//! - `eval` returns f·|cos θi| and is 0 unless both directions have z > 0 (no back faces; the
//!   caller flips the frame for two-sided surfaces).
//!
//! Sampling (one-sample MIS over the two lobes, Veach 1997 §9.2.4): the specular lobe is
//! chosen with probability p_s = F_s/(F_s + c_diff·T(N·V)), F_s = Schlick Fresnel at the
//! viewing angle, clamped to [0.1, 0.9], and p_s = 1 when c_diff = 0 (pure metal or black
//! base). The specular lobe draws a visible microfacet normal with Heitz 2018 ("Sampling the
//! GGX Distribution of Visible Normals", JCGT 7(4)) and reflects V about it, density
//! D_V(H)/(4 V·H) = G1(V)·D(H)/(4 cos θo); the diffuse lobe is cosine sampled. `pdf` is the
//! mixture p_s·pdf_spec + (1 − p_s)·pdf_cos, so `weight = eval/pdf` lies between the two
//! lobes' ratios (mediant inequality) and is at most max(1/p_s, 1/(1 − p_s)) ≤ 10, since each
//! lobe's eval/pdf (F·G2/G1, resp. c_diff·T·T/0.96) is ≤ 1.
//!
//! Frame: the branchless orthonormal basis of Duff et al. 2017 ("Building an Orthonormal
//! Basis, Revisited", JCGT 6(1)).

use std::f64::consts::{FRAC_1_PI, PI};

use glam::DVec3;

/// Smallest GGX α = roughness² used (roughness 0 would be a Dirac mirror).
pub const MIN_ALPHA: f64 = 1e-3;
/// Normal-incidence Fresnel reflectance of the glTF dielectric (index of refraction 1.5).
pub const DIELECTRIC_F0: f64 = 0.04;
/// Smallest probability of choosing either lobe when both lobes are non-zero.
pub const MIN_LOBE_PROB: f64 = 0.1;

/// An orthonormal, right-handed basis (t, b, n) around a unit normal n.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// First tangent (local x axis).
    pub t: DVec3,
    /// Second tangent (local y axis), n × t.
    pub b: DVec3,
    /// Normal (local z axis).
    pub n: DVec3,
}

impl Frame {
    /// Frame around `n` (Duff et al. 2017). `n` is normalised first; a zero or non-finite `n`
    /// gives the world frame.
    pub fn from_normal(n: DVec3) -> Frame {
        let n = n.try_normalize().unwrap_or(DVec3::Z);
        let sign = 1.0f64.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        Frame {
            t: DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
            b: DVec3::new(b, sign + n.y * n.y * a, -n.y),
            n,
        }
    }

    /// Components of world vector `v` in this frame.
    #[inline]
    pub fn to_local(&self, v: DVec3) -> DVec3 {
        DVec3::new(v.dot(self.t), v.dot(self.b), v.dot(self.n))
    }

    /// World vector with local components `v`.
    #[inline]
    pub fn to_world(&self, v: DVec3) -> DVec3 {
        self.t * v.x + self.b * v.y + self.n * v.z
    }
}

/// A sampled incident direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BsdfSample {
    /// Sampled unit direction in the local frame (z > 0).
    pub wi: DVec3,
    /// eval(wo, wi)/pdf(wo, wi): the path throughput factor.
    pub weight: f64,
    /// Solid-angle density of the sample (sr⁻¹).
    pub pdf: f64,
}

/// A spectral BSDF at one wavelength (scalar reflectance parameters).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bsdf {
    /// Lambertian reflector.
    Diffuse {
        /// Hemispherical reflectance in [0, 1].
        albedo: f64,
    },
    /// glTF 2.0 metallic-roughness material.
    MetallicRoughness {
        /// Base colour (reflectance at this wavelength) in [0, 1].
        base: f64,
        /// Metalness in [0, 1].
        metallic: f64,
        /// Perceptual roughness in [0, 1]; α = roughness².
        roughness: f64,
    },
}

/// Sanitised parameters of the metallic-roughness model.
#[derive(Clone, Copy, Debug)]
struct Mr {
    /// base·(1 − metallic).
    c_diff: f64,
    f0: f64,
    alpha: f64,
}

/// Schlick's Fresnel approximation F0 + (1 − F0)(1 − cos)⁵.
#[inline]
fn schlick(f0: f64, cos: f64) -> f64 {
    let m = (1.0 - cos).clamp(0.0, 1.0);
    let m2 = m * m;
    f0 + (1.0 - f0) * m2 * m2 * m
}

fn unit_or(x: f64, nan: f64) -> f64 {
    if x.is_nan() { nan } else { x.clamp(0.0, 1.0) }
}

impl Mr {
    fn new(base: f64, metallic: f64, roughness: f64) -> Mr {
        let base = unit_or(base, 0.0);
        let metallic = unit_or(metallic, 0.0);
        let roughness = unit_or(roughness, 1.0);
        Mr {
            c_diff: base * (1.0 - metallic),
            f0: DIELECTRIC_F0 + (base - DIELECTRIC_F0) * metallic,
            alpha: (roughness * roughness).max(MIN_ALPHA),
        }
    }

    #[inline]
    fn fresnel(&self, cos: f64) -> f64 {
        schlick(self.f0, cos)
    }

    /// Fresnel transmittance 1 − F_d(cos) of the dielectric (F0 = 0.04).
    #[inline]
    fn transmittance(cos: f64) -> f64 {
        1.0 - schlick(DIELECTRIC_F0, cos)
    }

    /// Probability of sampling the specular lobe for outgoing cosine `zo`.
    fn spec_prob(&self, zo: f64) -> f64 {
        if self.c_diff <= 0.0 {
            return 1.0;
        }
        let fs = self.fresnel(zo);
        let ps = fs / (fs + self.c_diff * Self::transmittance(zo));
        ps.clamp(MIN_LOBE_PROB, 1.0 - MIN_LOBE_PROB)
    }

    /// GGX normal distribution at a unit half vector.
    #[inline]
    fn d(&self, h: DVec3) -> f64 {
        let a2 = self.alpha * self.alpha;
        let sin2 = h.x * h.x + h.y * h.y;
        let cos2 = h.z * h.z;
        let t = sin2 + a2 * cos2;
        a2 / (PI * t * t)
    }

    /// √(α² + (1 − α²) z²) = z·(1 + 2Λ(z)).
    #[inline]
    fn a(&self, z: f64) -> f64 {
        let a2 = self.alpha * self.alpha;
        (a2 + (1.0 - a2) * z * z).sqrt()
    }

    fn eval(&self, wo: DVec3, wi: DVec3) -> f64 {
        let (zo, zi) = (wo.z, wi.z);
        if !(zo > 0.0 && zi > 0.0) {
            return 0.0;
        }
        let Some(h) = (wo + wi).try_normalize() else {
            return 0.0;
        };
        let f = self.fresnel(wo.dot(h));
        let diffuse = if self.c_diff > 0.0 {
            self.c_diff * FRAC_1_PI * Self::transmittance(zo) * Self::transmittance(zi) * zi
                / (1.0 - DIELECTRIC_F0)
        } else {
            0.0
        };
        // F·D·G2/(4 zo) with 4 zo (1 + Λo + Λi) = 2 (zi a_o + zo a_i)/zi.
        let spec = f * self.d(h) * zi / (2.0 * (zi * self.a(zo) + zo * self.a(zi)));
        let v = diffuse + spec;
        if v.is_finite() { v.max(0.0) } else { 0.0 }
    }

    /// Density of the VNDF-reflection lobe: G1(wo)·D(h)/(4 zo) = D/(2 (zo + a_o)).
    fn pdf_spec(&self, wo: DVec3, wi: DVec3) -> f64 {
        let Some(h) = (wo + wi).try_normalize() else {
            return 0.0;
        };
        self.d(h) / (2.0 * (wo.z + self.a(wo.z)))
    }

    fn pdf(&self, wo: DVec3, wi: DVec3) -> f64 {
        if !(wo.z > 0.0 && wi.z > 0.0) {
            return 0.0;
        }
        let ps = self.spec_prob(wo.z);
        let p = ps * self.pdf_spec(wo, wi) + (1.0 - ps) * wi.z * FRAC_1_PI;
        if p.is_finite() { p } else { 0.0 }
    }

    /// Heitz 2018 visible-normal sample for unit `wo` (z > 0), isotropic α.
    fn sample_vndf(&self, wo: DVec3, u1: f64, u2: f64) -> DVec3 {
        let a = self.alpha;
        let vh = DVec3::new(a * wo.x, a * wo.y, wo.z).normalize();
        let lensq = vh.x * vh.x + vh.y * vh.y;
        let t1 = if lensq > 0.0 {
            DVec3::new(-vh.y, vh.x, 0.0) / lensq.sqrt()
        } else {
            DVec3::X
        };
        let t2 = vh.cross(t1);
        let r = u1.sqrt();
        let phi = 2.0 * PI * u2;
        let p1 = r * phi.cos();
        let p2 = r * phi.sin();
        let s = 0.5 * (1.0 + vh.z);
        let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * p2;
        let nh = t1 * p1 + t2 * p2 + vh * (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
        DVec3::new(a * nh.x, a * nh.y, nh.z.max(0.0)).normalize_or(DVec3::Z)
    }
}

/// Cosine-weighted hemisphere direction from two uniforms.
#[inline]
fn sample_cosine(u1: f64, u2: f64) -> DVec3 {
    let r = u1.sqrt();
    let phi = 2.0 * PI * u2;
    DVec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt())
}

fn clamp_u(u: f64) -> f64 {
    if u.is_nan() { 0.0 } else { u.clamp(0.0, 1.0) }
}

impl Bsdf {
    /// f(wo, wi)·|cos θi| for unit wo, wi in the local frame (0 unless both have z > 0).
    pub fn eval(&self, wo: DVec3, wi: DVec3) -> f64 {
        match *self {
            Bsdf::Diffuse { albedo } => {
                if wo.z > 0.0 && wi.z > 0.0 {
                    unit_or(albedo, 0.0) * FRAC_1_PI * wi.z
                } else {
                    0.0
                }
            }
            Bsdf::MetallicRoughness {
                base,
                metallic,
                roughness,
            } => Mr::new(base, metallic, roughness).eval(wo, wi),
        }
    }

    /// Solid-angle density of `sample` producing wi (0 unless both wo and wi have z > 0).
    pub fn pdf(&self, wo: DVec3, wi: DVec3) -> f64 {
        match *self {
            Bsdf::Diffuse { .. } => {
                if wo.z > 0.0 && wi.z > 0.0 {
                    wi.z * FRAC_1_PI
                } else {
                    0.0
                }
            }
            Bsdf::MetallicRoughness {
                base,
                metallic,
                roughness,
            } => Mr::new(base, metallic, roughness).pdf(wo, wi),
        }
    }

    /// Samples wi from 3 uniforms in [0, 1) (u[0] picks the lobe, u[1], u[2] the direction);
    /// returns (wi, weight = eval/pdf, pdf), or `None` if wo is not above the surface or the
    /// sample falls below it (that probability is missing from `pdf`'s integral).
    pub fn sample(&self, wo: DVec3, u: [f64; 3]) -> Option<BsdfSample> {
        if wo.z.is_nan() || wo.z <= 0.0 {
            return None;
        }
        let u = u.map(clamp_u);
        let wi = match *self {
            Bsdf::Diffuse { .. } => sample_cosine(u[1], u[2]),
            Bsdf::MetallicRoughness {
                base,
                metallic,
                roughness,
            } => {
                let mr = Mr::new(base, metallic, roughness);
                if u[0] < mr.spec_prob(wo.z) {
                    let h = mr.sample_vndf(wo, u[1], u[2]);
                    (2.0 * wo.dot(h) * h - wo).normalize_or_zero()
                } else {
                    sample_cosine(u[1], u[2])
                }
            }
        };
        if wi.z.is_nan() || wi.z <= 0.0 {
            return None;
        }
        let pdf = self.pdf(wo, wi);
        if !(pdf > 0.0 && pdf.is_finite()) {
            return None;
        }
        let weight = self.eval(wo, wi) / pdf;
        weight.is_finite().then_some(BsdfSample { wi, weight, pdf })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::{hash, to_unit};
    use proptest::prelude::*;

    /// Uniform triple number `i` of stream `seed`.
    fn u3(seed: u64, i: u64) -> [f64; 3] {
        [0, 1, 2].map(|d| to_unit(hash(&[seed, i, d])))
    }

    fn dir_deg(theta_deg: f64, phi_deg: f64) -> DVec3 {
        let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
        DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    }

    fn mr(base: f64, metallic: f64, roughness: f64) -> Bsdf {
        Bsdf::MetallicRoughness {
            base,
            metallic,
            roughness,
        }
    }

    // ---- χ² goodness of fit (after Mitsuba's chi2.py) -----------------------------------

    /// ln Γ(x), Lanczos (g = 7, n = 9), |error| < 1e−13 for x > 0.5.
    fn ln_gamma(x: f64) -> f64 {
        const C: [f64; 9] = [
            0.999_999_999_999_809_9,
            676.520_368_121_885_1,
            -1_259.139_216_722_402_8,
            771.323_428_777_653_1,
            -176.615_029_162_140_6,
            12.507_343_278_686_905,
            -0.138_571_095_265_720_12,
            9.984_369_578_019_572e-6,
            1.505_632_735_149_311_6e-7,
        ];
        let x = x - 1.0;
        let t = x + 7.5;
        let s = C[0] + (1..9).map(|i| C[i] / (x + i as f64)).sum::<f64>();
        0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + s.ln()
    }

    /// Regularised upper incomplete gamma Q(a, x) (Numerical Recipes `gammq`).
    fn gamma_q(a: f64, x: f64) -> f64 {
        if x <= 0.0 {
            return 1.0;
        }
        let lg = a * x.ln() - x - ln_gamma(a);
        if x < a + 1.0 {
            let (mut ap, mut sum) = (a, 1.0 / a);
            let mut del = sum;
            for _ in 0..10_000 {
                ap += 1.0;
                del *= x / ap;
                sum += del;
                if del.abs() < sum.abs() * 1e-15 {
                    break;
                }
            }
            1.0 - sum * lg.exp()
        } else {
            let tiny = 1e-300;
            let mut b = x + 1.0 - a;
            let mut c = 1.0 / tiny;
            let mut d = 1.0 / b;
            let mut h = d;
            for i in 1..10_000 {
                let an = -(i as f64) * (i as f64 - a);
                b += 2.0;
                d = an * d + b;
                if d.abs() < tiny {
                    d = tiny;
                }
                c = b + an / c;
                if c.abs() < tiny {
                    c = tiny;
                }
                d = 1.0 / d;
                let del = d * c;
                h *= del;
                if (del - 1.0).abs() < 1e-15 {
                    break;
                }
            }
            lg.exp() * h
        }
    }

    const N_THETA: usize = 10;
    const N_PHI: usize = 20;
    /// Simpson sub-intervals per cell and dimension (even).
    const SUB: usize = 64;
    const N_SAMPLES: u64 = 1_000_000;
    /// Cells with a smaller expected count are pooled (Mitsuba chi2.py `min_exp_frequency`).
    const MIN_EXP: f64 = 5.0;

    /// p-value of Pearson's χ² test of `sample` (N_SAMPLES draws) against `pdf`, on a
    /// θ × φ grid of the upper hemisphere (θ uniform in [0, π/2], φ in [−π, π]); expected
    /// counts integrate pdf·sin θ over each cell with composite Simpson (SUB² points).
    fn chi2_p(
        sample: &dyn Fn([f64; 3]) -> Option<DVec3>,
        pdf: &dyn Fn(DVec3) -> f64,
        seed: u64,
    ) -> f64 {
        let dt = 0.5 * PI / N_THETA as f64;
        let dp = 2.0 * PI / N_PHI as f64;
        let mut obs = vec![0.0f64; N_THETA * N_PHI];
        for i in 0..N_SAMPLES {
            let Some(w) = sample(u3(seed, i)) else {
                continue;
            };
            assert!(
                w.z > 0.0 && (w.length() - 1.0).abs() < 1e-9,
                "bad sample {w}"
            );
            let t = w.z.clamp(-1.0, 1.0).acos();
            let p = w.y.atan2(w.x);
            let it = ((t / dt) as usize).min(N_THETA - 1);
            let ip = (((p + PI) / dp) as usize).min(N_PHI - 1);
            obs[it * N_PHI + ip] += 1.0;
        }
        let simpson = |k: usize| {
            if k == 0 || k == SUB {
                1.0
            } else if k % 2 == 1 {
                4.0
            } else {
                2.0
            }
        };
        let mut exp = vec![0.0f64; N_THETA * N_PHI];
        for it in 0..N_THETA {
            for ip in 0..N_PHI {
                let (h_t, h_p) = (dt / SUB as f64, dp / SUB as f64);
                let mut s = 0.0;
                for a in 0..=SUB {
                    let t = it as f64 * dt + a as f64 * h_t;
                    let wa = simpson(a) * t.sin();
                    for b in 0..=SUB {
                        let p = -PI + ip as f64 * dp + b as f64 * h_p;
                        let w = DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
                        s += wa * simpson(b) * pdf(w);
                    }
                }
                exp[it * N_PHI + ip] = s * h_t * h_p / 9.0 * N_SAMPLES as f64;
            }
        }
        // Pool low-expectation cells (chi2.py): sort by expected count, merge cells below
        // MIN_EXP (and following cells until the pool reaches MIN_EXP) into one cell.
        let mut idx: Vec<usize> = (0..exp.len()).collect();
        idx.sort_by(|&a, &b| exp[a].total_cmp(&exp[b]));
        let (mut chsq, mut dof) = (0.0, 0usize);
        let (mut pool_obs, mut pool_exp, mut pooled) = (0.0, 0.0, 0usize);
        for &i in &idx {
            if exp[i] == 0.0 && obs[i] > 0.0 {
                return 0.0; // samples where the pdf says there can be none
            }
            if exp[i] < MIN_EXP || (pooled > 0 && pool_exp < MIN_EXP) {
                pool_obs += obs[i];
                pool_exp += exp[i];
                pooled += 1;
            } else {
                chsq += (obs[i] - exp[i]).powi(2) / exp[i];
                dof += 1;
            }
        }
        if pooled > 0 && pool_exp > 0.0 {
            chsq += (pool_obs - pool_exp).powi(2) / pool_exp;
            dof += 1;
        }
        let dof = dof.saturating_sub(1).max(1);
        gamma_q(0.5 * dof as f64, 0.5 * chsq)
    }

    /// Test cases: (bsdf, θo in degrees).
    fn cases() -> Vec<(Bsdf, f64)> {
        vec![
            (Bsdf::Diffuse { albedo: 0.7 }, 40.0),
            (mr(0.8, 0.0, 0.2), 30.0),
            (mr(0.8, 1.0, 0.2), 30.0),
            (mr(0.5, 0.0, 0.8), 70.0),
            (mr(0.9, 1.0, 0.8), 70.0),
            (mr(0.3, 0.5, 0.5), 0.0),
            (mr(1.0, 0.0, 0.2), 80.0),
        ]
    }

    #[test]
    fn chi2_gamma_q_matches_tables() {
        // Q(k/2, x/2) = 1 − χ²_k CDF(x): χ²_1(3.841459) = 0.95, χ²_10(23.209251) = 0.99,
        // χ²_100(135.806723) = 0.99 (standard tables).
        assert!((gamma_q(0.5, 3.841_459 / 2.0) - 0.05).abs() < 1e-6);
        assert!((gamma_q(5.0, 23.209_251 / 2.0) - 0.01).abs() < 1e-6);
        assert!((gamma_q(50.0, 135.806_723 / 2.0) - 0.01).abs() < 1e-6);
        assert!((ln_gamma(5.0) - 24f64.ln()).abs() < 1e-12);
    }

    /// Tolerance: each case passes if p > 0.01 (1 % significance; fixed seeds, so the outcome is
    /// deterministic). Power: the same test with pdf·cos θ (a wrong density) gives p < 1e−6.
    #[test]
    fn chi2_sample_matches_pdf() {
        for (k, (bsdf, theta_o)) in cases().into_iter().enumerate() {
            let wo = dir_deg(theta_o, 30.0);
            let p = chi2_p(
                &|u| bsdf.sample(wo, u).map(|s| s.wi),
                &|w| bsdf.pdf(wo, w),
                100 + k as u64,
            );
            assert!(p > 0.01, "{bsdf:?} θo={theta_o}: p = {p}");
        }
    }

    #[test]
    fn chi2_rejects_wrong_pdf() {
        for (bsdf, theta_o) in [
            (Bsdf::Diffuse { albedo: 0.7 }, 40.0),
            (mr(0.5, 0.0, 0.8), 70.0),
        ] {
            let wo = dir_deg(theta_o, 30.0);
            let p = chi2_p(
                &|u| bsdf.sample(wo, u).map(|s| s.wi),
                &|w| bsdf.pdf(wo, w) * w.z,
                7,
            );
            assert!(p < 1e-6, "{bsdf:?}: wrong pdf accepted, p = {p}");
        }
    }

    #[test]
    fn weight_is_eval_over_pdf() {
        for (k, (bsdf, theta_o)) in cases().into_iter().enumerate() {
            let wo = dir_deg(theta_o, 10.0);
            let mut n_ok = 0;
            for i in 0..20_000 {
                let Some(s) = bsdf.sample(wo, u3(900 + k as u64, i)) else {
                    continue;
                };
                n_ok += 1;
                let pdf = bsdf.pdf(wo, s.wi);
                let eval = bsdf.eval(wo, s.wi);
                assert!(
                    (s.pdf - pdf).abs() <= 1e-9 * pdf,
                    "{bsdf:?} pdf {} vs {pdf}",
                    s.pdf
                );
                assert!((s.weight - eval / pdf).abs() <= 1e-9 * s.weight.max(1.0));
                assert!(
                    s.weight >= 0.0 && s.weight <= 10.0 + 1e-9,
                    "{bsdf:?} weight {}",
                    s.weight
                );
            }
            assert!(n_ok > 15_000, "{bsdf:?}: only {n_ok} samples succeeded");
        }
    }

    /// Mean and standard error of `f` over n draws.
    fn mean_se(n: u64, f: impl Fn(u64) -> f64) -> (f64, f64) {
        let (mut s, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let v = f(i);
            s += v;
            s2 += v * v;
        }
        let m = s / n as f64;
        let var = (s2 / n as f64 - m * m).max(0.0);
        (m, (var / n as f64).sqrt())
    }

    /// Tolerance: the directional albedo ∫ eval dω (estimated by the mean sample weight, 4·10⁵
    /// samples) must be ≤ 1 + 3σ for base = 1; the resolution check asserts 3σ < 0.015 (below
    /// 0.003 except at 89°). Power: `spec_model_gains_energy` shows that the specification's
    /// (1 − F(V·H)) diffuse weighting fails this same bound.
    #[test]
    fn furnace_bounded() {
        for metallic in [0.0, 0.5, 1.0] {
            for roughness in [0.0, 0.2, 0.5, 0.8, 1.0] {
                for theta_o in [0.0, 30.0, 60.0, 80.0, 89.0] {
                    let b = mr(1.0, metallic, roughness);
                    let wo = dir_deg(theta_o, 0.0);
                    let (m, se) = mean_se(400_000, |i| {
                        b.sample(wo, u3(5, i)).map_or(0.0, |s| s.weight)
                    });
                    assert!(m <= 1.0 + 3.0 * se, "{b:?} θo={theta_o}: albedo {m} ± {se}");
                    assert!(3.0 * se < 0.015, "{b:?} θo={theta_o}: σ = {se} too coarse");
                    if metallic == 1.0 && roughness == 0.0 && theta_o <= 80.0 {
                        // A smooth white metal (α = 1e−3) reflects everything: F = 1, G ≈ 1.
                        assert!(m > 0.999, "{b:?} θo={theta_o}: albedo {m}");
                    }
                }
            }
        }
    }

    /// The specification's diffuse weighting (1 − F(V·H)) exceeds the furnace bound of
    /// `furnace_bounded` (same estimator and tolerance): the reason for the deviation.
    #[test]
    fn spec_model_gains_energy() {
        let b = mr(1.0, 0.0, 0.0);
        let m = Mr::new(1.0, 0.0, 0.0);
        let spec_eval = |wo: DVec3, wi: DVec3| {
            let h = (wo + wi).normalize();
            let f = m.fresnel(wo.dot(h));
            let spec = m.eval(wo, wi)
                - m.c_diff * FRAC_1_PI * Mr::transmittance(wo.z) * Mr::transmittance(wi.z) * wi.z
                    / (1.0 - DIELECTRIC_F0);
            (1.0 - f) * m.c_diff * FRAC_1_PI * wi.z + spec
        };
        for (theta_o, at_least) in [(60.0, 1.02), (80.0, 1.3)] {
            let wo = dir_deg(theta_o, 0.0);
            let (e, se) = mean_se(400_000, |i| {
                b.sample(wo, u3(5, i))
                    .map_or(0.0, |s| spec_eval(wo, s.wi) / s.pdf)
            });
            assert!(
                e > 1.0 + 3.0 * se && e > at_least,
                "θo={theta_o}: {e} ± {se}"
            );
        }
    }

    /// Tolerance: |estimate − albedo| ≤ 3σ with uniform hemisphere sampling (independent of
    /// `sample`), 2·10⁵ samples; the same estimate must reject albedo + 0.01 (power check).
    #[test]
    fn furnace_diffuse_equals_albedo() {
        let b = Bsdf::Diffuse { albedo: 0.7 };
        let wo = dir_deg(25.0, 0.0);
        let (m, se) = mean_se(200_000, |i| {
            let u = u3(11, i);
            let z = u[0];
            let r = (1.0 - z * z).sqrt();
            let p = 2.0 * PI * u[1];
            b.eval(wo, DVec3::new(r * p.cos(), r * p.sin(), z)) * 2.0 * PI
        });
        assert!((m - 0.7).abs() <= 3.0 * se, "{m} ± {se}");
        assert!(
            (m - 0.71).abs() > 3.0 * se,
            "test cannot resolve 0.01: σ = {se}"
        );
        // Importance-sampled weights are exactly the albedo.
        for i in 0..1000 {
            let s = b.sample(wo, u3(12, i)).unwrap();
            assert!((s.weight - 0.7).abs() < 1e-12);
        }
    }

    #[test]
    fn hand_computed_values() {
        // Normal incidence, wo = wi = +z, base 0.5, metallic 0, roughness 0.5 (α = 0.25):
        // F = 0.04, D = 1/(π α²), G2 = 1, eval = F D/4 + (1 − F)·0.5/π.
        let b = mr(0.5, 0.0, 0.5);
        let expect = 0.04 / (PI * 0.0625) / 4.0 + 0.96 * 0.5 / PI;
        assert!((b.eval(DVec3::Z, DVec3::Z) - expect).abs() < 1e-12);
        assert!((expect - 0.203_718_327).abs() < 1e-9);
        // pdf there: p_s = F/(F + 0.5·(1 − F)) = 0.04/0.52, spec pdf = D/4, cos pdf = 1/π.
        let ps = MIN_LOBE_PROB; // 0.04/0.52 = 0.077, clamped up to 0.1
        let pexp = ps / (PI * 0.0625) / 4.0 + (1.0 - ps) / PI;
        assert!((b.pdf(DVec3::Z, DVec3::Z) - pexp).abs() < 1e-12);
        // Diffuse: albedo/π·cos θi.
        let d = Bsdf::Diffuse { albedo: 0.4 };
        let wi = dir_deg(60.0, 10.0);
        assert!((d.eval(DVec3::Z, wi) - 0.4 / PI * 0.5).abs() < 1e-12);
        // Below the surface: zero.
        assert_eq!(b.eval(DVec3::Z, -DVec3::Z), 0.0);
        assert_eq!(b.pdf(-DVec3::Z, DVec3::Z), 0.0);
        assert!(b.sample(-DVec3::Z, [0.5; 3]).is_none());
    }

    #[test]
    fn grazing_and_degenerate_inputs_are_finite() {
        let dirs = [
            DVec3::new(1.0, 0.0, 1e-300),
            DVec3::new(1.0, 0.0, 1e-12).normalize(),
            DVec3::new(0.0, 1.0, 1e-8).normalize(),
            DVec3::Z,
            DVec3::new(-1.0, 0.0, 0.0),
        ];
        let bsdfs = [
            mr(1.0, 1.0, 0.0),
            mr(1.0, 0.0, 0.0),
            mr(0.5, 0.5, 1.0),
            mr(f64::NAN, f64::NAN, f64::NAN),
            mr(7.0, -3.0, 2.0),
            Bsdf::Diffuse { albedo: f64::NAN },
        ];
        for b in bsdfs {
            for &wo in &dirs {
                for &wi in &dirs {
                    let e = b.eval(wo, wi);
                    let p = b.pdf(wo, wi);
                    assert!(e.is_finite() && e >= 0.0, "{b:?} {wo} {wi}: eval {e}");
                    assert!(p.is_finite() && p >= 0.0, "{b:?} {wo} {wi}: pdf {p}");
                }
                for u in [[0.0; 3], [1.0; 3], [0.05, 0.999_999, 0.5], [f64::NAN; 3]] {
                    if let Some(s) = b.sample(wo, u) {
                        assert!(s.weight.is_finite() && s.weight >= 0.0 && s.pdf > 0.0);
                    }
                }
            }
        }
    }

    proptest! {
        /// Tolerance: relative 1e−9 (directions with cos θ ≥ 1e−3).
        #[test]
        fn reciprocity(
            to in 0.0f64..89.9, po in -180.0f64..180.0, ti in 0.0f64..89.9, pi in -180.0f64..180.0,
            base in 0.0f64..1.0, metallic in 0.0f64..1.0, roughness in 0.0f64..1.0,
        ) {
            let (wo, wi) = (dir_deg(to, po), dir_deg(ti, pi));
            for b in [mr(base, metallic, roughness), Bsdf::Diffuse { albedo: base }] {
                let f1 = b.eval(wo, wi) / wi.z;
                let f2 = b.eval(wi, wo) / wo.z;
                prop_assert!((f1 - f2).abs() <= 1e-9 * f1.abs().max(f2.abs()), "{:?}: {} vs {}", b, f1, f2);
            }
        }

        /// Tolerance: 1e−12 on lengths, dot products and the round trip.
        #[test]
        fn frame_orthonormal(x in -1.0f64..1.0, y in -1.0f64..1.0, z in -1.0f64..1.0, v in prop::array::uniform3(-5.0f64..5.0)) {
            prop_assume!(DVec3::new(x, y, z).length() > 1e-3);
            let f = Frame::from_normal(DVec3::new(x, y, z));
            for (a, b) in [(f.t, f.b), (f.b, f.n), (f.n, f.t)] {
                prop_assert!(a.dot(b).abs() < 1e-12);
            }
            for a in [f.t, f.b, f.n] {
                prop_assert!((a.length() - 1.0).abs() < 1e-12);
            }
            prop_assert!((f.t.cross(f.b) - f.n).length() < 1e-12);
            let v = DVec3::from_array(v);
            prop_assert!((f.to_world(f.to_local(v)) - v).length() < 1e-12 * v.length().max(1.0));
            prop_assert!((f.to_local(f.n) - DVec3::Z).length() < 1e-12);
        }
    }

    #[test]
    fn frame_poles_and_degenerate() {
        for n in [DVec3::Z, -DVec3::Z, DVec3::X, DVec3::new(0.0, -1e-20, -1.0)] {
            let f = Frame::from_normal(n);
            assert!((f.t.cross(f.b) - f.n).length() < 1e-12);
            assert!(f.t.dot(f.n).abs() < 1e-12);
        }
        assert_eq!(Frame::from_normal(DVec3::ZERO).n, DVec3::Z);
        assert_eq!(Frame::from_normal(DVec3::splat(f64::NAN)).n, DVec3::Z);
    }
}
