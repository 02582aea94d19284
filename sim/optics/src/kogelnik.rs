//! Kogelnik coupled-wave efficiencies of a thick (volume) grating.
//!
//! Model: two-wave coupled-wave theory (H. Kogelnik, Bell Syst. Tech. J. 48, 2909 (1969)) for a
//! slab grating of thickness d with index modulation n1 (peak-to-mean) and mean amplitude
//! absorption α0. The inputs are Kogelnik's ν (coupling strength) and ξ (dephasing), or for the
//! lossy case κ, ϑ, c_R, c_S directly. Formulas and their numerical forms follow
//! `docs/physics.md` §1:
//! - lossless reflection grating, in the overflow-free unified form
//!   η = ν² / (ξ² + G(ν² − ξ²)²), G(x) = √x·coth√x (x > 0), 1 (x = 0), √−x·cot√−x (x < 0)
//!   (§1.2, equal to Kogelnik Eq. 57 everywhere, no sinh overflow, no 0/0 at ξ = ν);
//! - lossless transmission grating, Kogelnik Eq. 42–43: η = sin²√(ν²+ξ²) / (1 + ξ²/ν²) (§1.4);
//! - lossy/mixed reflection grating in the overflow-free rewrite of Kogelnik Eqs. 30/39 (§1.3):
//!   S(0) = −iκ / [½(α0 + iϑ − α0 c_S/c_R) − c_S·q·coth(qd)], η = (|c_S|/c_R)|S(0)|².
//!
//! Assumptions: two waves only, slowly varying envelopes, no reflections at the film boundaries
//! (Kogelnik's own assumptions; accurate for 16 µm HX200 films with n1 ≤ 0.03, §1.7).
//! All quantities are dimensionless except where a unit is named; any consistent length unit
//! may be used for κ, ϑ, α0 and d.

use num_complex::Complex64;

/// G(x) of docs/physics.md §1.2: √x·coth√x for x > 0, √−x·cot√−x for x < 0, with a series near 0.
#[inline]
pub fn g_unified(x: f64) -> f64 {
    if x.abs() < 1e-3 {
        // 1 + x/3 − x²/45 + 2x³/945 (Taylor series of √x coth √x).
        1.0 + x / 3.0 - x * x / 45.0 + 2.0 * x * x * x / 945.0
    } else if x > 0.0 {
        let s = x.sqrt();
        // coth s = 1/tanh s; tanh saturates to 1, so no overflow for large s.
        s / s.tanh()
    } else {
        let s = (-x).sqrt();
        // s·cot s; tan(s) = 0 gives ±inf, i.e. an exact efficiency zero, never NaN.
        s / s.tan()
    }
}

/// Lossless reflection-grating diffraction efficiency η(ν, ξ) (Kogelnik Eq. 57, unified form).
///
/// Finite and in [0, 1] for all finite ν ≥ 0 and ξ; η = tanh²ν at Bragg (ξ = 0).
#[inline]
pub fn reflection_lossless(nu: f64, xi: f64) -> f64 {
    if nu <= 0.0 {
        return 0.0;
    }
    let g = g_unified(nu * nu - xi * xi);
    let den = xi * xi + g * g;
    if !den.is_finite() {
        return 0.0;
    }
    (nu * nu / den).clamp(0.0, 1.0)
}

/// Lossless transmission-grating diffraction efficiency (Kogelnik Eqs. 42–43):
/// η = ν² sin²√(ν² + ξ²) / (ν² + ξ²).
pub fn transmission_lossless(nu: f64, xi: f64) -> f64 {
    if nu <= 0.0 {
        return 0.0;
    }
    let r2 = nu * nu + xi * xi;
    let s = r2.sqrt().sin();
    (nu * nu * s * s / r2).clamp(0.0, 1.0)
}

/// [`transmission_lossless`] for two coupling strengths (TE and TM) at the same ξ. Far off
/// Bragg (ξ ≫ ν) both arguments √(ν² + ξ²) = ξ + δ lie close to ξ, so one `sin_cos(ξ)` and the
/// angle-addition formula with series for sin δ and cos δ (|δ| < 0.05, truncation < 1e-13)
/// replace two `sin` calls; otherwise each is evaluated directly.
#[inline]
pub fn transmission_lossless_pair(nu_s: f64, nu_p: f64, xi: f64) -> [f64; 2] {
    let xi = xi.abs();
    let delta = |nu: f64| nu * nu / ((nu * nu + xi * xi).sqrt() + xi);
    let (ds, dp) = (delta(nu_s), delta(nu_p));
    if !(ds < 0.05 && dp < 0.05 && xi > 0.0) || nu_s <= 0.0 || nu_p <= 0.0 {
        return [
            transmission_lossless(nu_s, xi),
            transmission_lossless(nu_p, xi),
        ];
    }
    let (sx, cx) = xi.sin_cos();
    let eta = |nu: f64, d: f64| {
        let d2 = d * d;
        let sin_d = d * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0));
        let cos_d = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0));
        let s = sx * cos_d + cx * sin_d;
        (nu * nu * s * s / (nu * nu + xi * xi)).clamp(0.0, 1.0)
    };
    [eta(nu_s, ds), eta(nu_p, dp)]
}

/// Stable complex hyperbolic cotangent: coth z = (1 + e^{−2z})/(1 − e^{−2z}) for Re z ≥ 0, odd.
fn coth(z: Complex64) -> Complex64 {
    if z.re < 0.0 {
        return -coth(-z);
    }
    let e = (-2.0 * z).exp();
    (1.0 + e) / (1.0 - e)
}

/// q·coth(q·d), even in q, with the limit 1/d as q → 0.
fn q_coth_qd(q: Complex64, d: f64) -> Complex64 {
    let qd = q * d;
    if qd.norm() < 1e-6 {
        // q coth(qd) = 1/d + q²d/3 + O(q⁴)
        Complex64::new(1.0 / d, 0.0) + q * q * d / 3.0
    } else {
        q * coth(qd)
    }
}

/// Inputs of the general (lossy or mixed) coupled-wave problem of one reflection grating.
#[derive(Clone, Copy, Debug)]
pub struct CoupledWave {
    /// Coupling constant κ = π n1/λ − i α1/2 (per unit length).
    pub kappa: Complex64,
    /// Mean amplitude absorption α0 (per unit length).
    pub alpha0: f64,
    /// Dephasing ϑ (per unit length), signed.
    pub theta: f64,
    /// Obliquity factor of the incident wave, c_R > 0.
    pub c_r: f64,
    /// Obliquity factor of the signal wave; c_S < 0 for reflection geometry.
    pub c_s: f64,
    /// Grating thickness d (same length unit).
    pub d: f64,
}

impl CoupledWave {
    /// Signal amplitude S(0) of a reflection grating (boundary conditions R(0) = 1, S(d) = 0),
    /// overflow-free form of docs/physics.md §1.3.
    pub fn reflection_amplitude(&self) -> Complex64 {
        let i = Complex64::i();
        let a = Complex64::new(self.alpha0, self.theta);
        let p = Complex64::new(self.alpha0 / self.c_r, 0.0) - a / self.c_s;
        let disc = p * p - 4.0 * self.kappa * self.kappa / (self.c_r * self.c_s);
        let q = 0.5 * disc.sqrt();
        let den = 0.5 * (a - self.alpha0 * self.c_s / self.c_r) - self.c_s * q_coth_qd(q, self.d);
        -i * self.kappa / den
    }

    /// Reflection efficiency η = (|c_S|/c_R)|S(0)|², clamped to [0, 1] against rounding.
    pub fn reflection_efficiency(&self) -> f64 {
        let s = self.reflection_amplitude();
        let eta = self.c_s.abs() / self.c_r * s.norm_sqr();
        if eta.is_finite() {
            eta.clamp(0.0, 1.0)
        } else {
            0.0
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Direct numerical integration of Kogelnik's coupled-wave equations
    ///   c_R R' + α0 R = −iκS,  c_S S' + (α0 + iϑ) S = −iκR
    /// by classical RK4 with two fundamental solutions and the boundary conditions
    /// R(0) = 1, S(d) = 0 (reflection). Independent of the closed forms above.
    pub(crate) fn ode_reflection_efficiency(cw: &CoupledWave, steps: usize) -> f64 {
        let i = Complex64::i();
        let f = |y: [Complex64; 2]| -> [Complex64; 2] {
            let (r, s) = (y[0], y[1]);
            [
                (-i * cw.kappa * s - cw.alpha0 * r) / cw.c_r,
                (-i * cw.kappa * r - Complex64::new(cw.alpha0, cw.theta) * s) / cw.c_s,
            ]
        };
        let integrate = |y0: [Complex64; 2]| -> [Complex64; 2] {
            let h = cw.d / steps as f64;
            let mut y = y0;
            for _ in 0..steps {
                let k1 = f(y);
                let k2 = f([y[0] + k1[0] * (h / 2.0), y[1] + k1[1] * (h / 2.0)]);
                let k3 = f([y[0] + k2[0] * (h / 2.0), y[1] + k2[1] * (h / 2.0)]);
                let k4 = f([y[0] + k3[0] * h, y[1] + k3[1] * h]);
                for c in 0..2 {
                    y[c] += (k1[c] + 2.0 * k2[c] + 2.0 * k3[c] + k4[c]) * (h / 6.0);
                }
            }
            y
        };
        let one = Complex64::new(1.0, 0.0);
        let zero = Complex64::new(0.0, 0.0);
        let y1 = integrate([one, zero]);
        let y2 = integrate([zero, one]);
        // S(d) = y1_S(d) + b·y2_S(d) = 0  =>  S(0) = b.
        let b = -y1[1] / y2[1];
        cw.c_s.abs() / cw.c_r * b.norm_sqr()
    }

    /// Tiny deterministic generator for test cases (splitmix64).
    pub(crate) struct TestRng(pub u64);
    impl TestRng {
        pub(crate) fn next_f64(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 11) as f64 / (1u64 << 53) as f64
        }
        pub(crate) fn range(&mut self, lo: f64, hi: f64) -> f64 {
            lo + (hi - lo) * self.next_f64()
        }
    }

    #[test]
    fn bragg_efficiency_is_tanh_squared() {
        for &nu in &[0.01, 0.3, 0.681, 1.361, 2.723, 4.084, 10.0, 50.0] {
            let eta = reflection_lossless(nu, 0.0);
            assert!((eta - nu.tanh().powi(2)).abs() < 1e-14, "nu={nu}: {eta}");
        }
    }

    #[test]
    fn unified_form_matches_kogelnik_eq57() {
        let mut rng = TestRng(7);
        for _ in 0..2000 {
            let nu = rng.range(0.05, 5.0);
            let xi = rng.range(-15.0, 15.0);
            let x = nu * nu - xi * xi;
            if x.abs() < 1e-6 {
                continue;
            }
            let eq57 = if x > 0.0 {
                1.0 / (1.0 + (1.0 - xi * xi / (nu * nu)) / x.sqrt().sinh().powi(2))
            } else {
                1.0 / (1.0 + (xi * xi / (nu * nu) - 1.0) / (-x).sqrt().sin().powi(2))
            };
            assert!((reflection_lossless(nu, xi) - eq57).abs() < 1e-12);
        }
        // Limit ξ → ν: η → ν²/(1+ν²).
        let nu: f64 = 1.7;
        assert!((reflection_lossless(nu, nu) - nu * nu / (1.0 + nu * nu)).abs() < 1e-12);
    }

    #[test]
    fn ode_agrees_with_closed_forms_lossless_and_lossy() {
        let mut rng = TestRng(42);
        let mut worst: f64 = 0.0;
        for case in 0..120 {
            let lossy = case % 2 == 1;
            let d = rng.range(5.0, 30.0); // µm
            let lambda_um = rng.range(0.4, 0.7);
            let n1 = rng.range(0.001, 0.03);
            let c_r = rng.range(0.3, 1.0);
            let c_s = -rng.range(0.3, 1.0);
            let theta = rng.range(-1.0, 1.0); // per µm
            let alpha0 = if lossy { rng.range(0.0, 0.05) } else { 0.0 };
            let alpha1 = if lossy { rng.range(0.0, 0.01) } else { 0.0 };
            let cw = CoupledWave {
                kappa: Complex64::new(std::f64::consts::PI * n1 / lambda_um, -alpha1 / 2.0),
                alpha0,
                theta,
                c_r,
                c_s,
                d,
            };
            let ode = ode_reflection_efficiency(&cw, 4000);
            let closed = cw.reflection_efficiency();
            worst = worst.max((ode - closed).abs());
            assert!(
                (ode - closed).abs() < 1e-8,
                "case {case}: ode {ode} closed {closed}"
            );
            if !lossy {
                let nu = cw.kappa.re * d / (c_r * c_s.abs()).sqrt();
                let xi = -theta * d / (2.0 * c_s);
                let unified = reflection_lossless(nu, xi);
                assert!(
                    (ode - unified).abs() < 1e-8,
                    "case {case}: ode {ode} unified {unified}"
                );
            }
        }
        assert!(worst < 1e-8);
    }

    #[test]
    fn finite_and_bounded_for_extreme_arguments() {
        let mut rng = TestRng(3);
        for _ in 0..20000 {
            let nu = 10f64.powf(rng.range(-8.0, 3.0));
            let xi =
                10f64.powf(rng.range(-8.0, 6.0)) * if rng.next_f64() < 0.5 { -1.0 } else { 1.0 };
            let r = reflection_lossless(nu, xi);
            let t = transmission_lossless(nu, xi);
            assert!(
                r.is_finite() && (0.0..=1.0).contains(&r),
                "nu {nu} xi {xi}: {r}"
            );
            assert!(t.is_finite() && (0.0..=1.0).contains(&t));
        }
        for &(nu, xi) in &[
            (1e3, 0.0),
            (1e3, 1e6),
            (1e3, -1e6),
            (1e-300, 1e6),
            (1e3, 1e3),
        ] {
            let r = reflection_lossless(nu, xi);
            assert!(r.is_finite() && (0.0..=1.0).contains(&r));
        }
        assert_eq!(reflection_lossless(1e3, 0.0), 1.0);
        // Lossy form with huge |q|d (the naive form overflows here, docs/physics.md §1.3).
        let cw = CoupledWave {
            kappa: Complex64::new(std::f64::consts::PI * 0.03 / 0.5, 0.0),
            alpha0: 0.01,
            theta: 0.5,
            c_r: 1.0,
            c_s: -0.48,
            d: 20_000.0,
        };
        let eta = cw.reflection_efficiency();
        assert!(eta.is_finite() && eta > 0.0 && eta <= 1.0);
        // The lossy form over the same extreme range: ν up to 1e3, |ξ| up to 1e6, α0·d up to 1e3.
        for _ in 0..20000 {
            let d = 1.0;
            let c_r = rng.range(0.01, 1.0);
            let c_s = -rng.range(0.01, 1.0);
            let nu = 10f64.powf(rng.range(-8.0, 3.0));
            let xi =
                10f64.powf(rng.range(-8.0, 6.0)) * if rng.next_f64() < 0.5 { -1.0 } else { 1.0 };
            // An absorption grating needs α1 ≤ α0 (no gain anywhere); κ = πn1/λ − iα1/2.
            let alpha0 = 10f64.powf(rng.range(-6.0, 3.0));
            let alpha1 = alpha0 * rng.next_f64();
            let cw = CoupledWave {
                kappa: Complex64::new(nu * (c_r * c_s.abs()).sqrt() / d, -0.5 * alpha1),
                alpha0,
                theta: -2.0 * xi * c_s / d,
                c_r,
                c_s,
                d,
            };
            // Before any clamping: finite, and at most 1 (a lossy grating only loses energy).
            let raw = cw.c_s.abs() / cw.c_r * cw.reflection_amplitude().norm_sqr();
            assert!(
                raw.is_finite() && (0.0..=1.0 + 1e-9).contains(&raw),
                "{cw:?}: {raw}"
            );
        }
    }

    #[test]
    fn transmission_pair_matches_direct_evaluation() {
        let mut rng = TestRng(11);
        for _ in 0..100_000 {
            let nu_s = 10f64.powf(rng.range(-4.0, 1.0));
            let nu_p = nu_s * rng.next_f64();
            let xi = 10f64.powf(rng.range(-2.0, 4.0));
            let pair = transmission_lossless_pair(nu_s, nu_p, xi);
            assert!((pair[0] - transmission_lossless(nu_s, xi)).abs() < 1e-13);
            assert!((pair[1] - transmission_lossless(nu_p, xi)).abs() < 1e-13);
        }
    }

    #[test]
    fn weak_grating_limit() {
        // ν ≪ 1: η ≈ ν² sin²ξ/ξ².
        let nu = 1e-3;
        for &xi in &[0.5f64, 1.0, 2.0, 5.0] {
            let approx = nu * nu * xi.sin().powi(2) / (xi * xi);
            assert!((reflection_lossless(nu, xi) - approx).abs() < 1e-9);
        }
    }
}
