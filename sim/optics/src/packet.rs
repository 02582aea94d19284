//! Four waves at once: the Kogelnik orders of a lossless film ([`super::grating`]) and the
//! Fresnel and plate-crossing quantities ([`super::interface`]) of four camera paths as one SIMD
//! packet (`wide::f64x4`: four f64 lanes, one AVX register where the build targets AVX, two SSE2
//! registers otherwise).
//!
//! Model: the scalar functions' formulas, unchanged (docs/physics.md §1.2 lossless reflection
//! grating in the unified form, §1.4 lossless transmission grating, §1.7 the SVEA taper, §4.3
//! Fresnel), written lane for lane in the scalar code's order of operations. Additions,
//! multiplications, divisions and square roots are IEEE-rounded the same in a lane as in a
//! scalar register, and the few transcendental calls (tan, tanh, sin of the efficiency formulas)
//! are the scalar functions, lane by lane, so every lane equals the scalar result bit for bit
//! (tests below, over random waves and every branch of the formulas). What the packet buys is
//! throughput: a Kogelnik order is a chain of about ten dependent divisions and square roots,
//! and four chains in one instruction stream keep the divider busy where one chain waits on it.
//!
//! Assumptions: a lossless film (α0 = 0: the packet has no absorbing forms; a film with
//! absorption is traced by the scalar code) and one grating (a multiplexed film's cross terms
//! are scalar).
//! Source of the formulas: H. Kogelnik, Bell Syst. Tech. J. 48, 2909 (1969), as in
//! [`super::kogelnik`]; the layout follows the packet tracers of the rendering literature
//! (structure of arrays, one lane per path, masks instead of branches).

use std::f64::consts::PI;

use glam::DVec2;
use wide::f64x4;

use super::grating::VolumeGrating;
use super::kogelnik;

/// Lanes of a packet.
pub const LANES: usize = 4;

/// Two lanes-wide values, [TE, TM].
pub type Pair = [f64x4; 2];

/// A 2-vector per lane (structure of arrays).
#[derive(Clone, Copy, Debug)]
pub struct Vec2x4 {
    /// x of every lane.
    pub x: f64x4,
    /// y of every lane.
    pub y: f64x4,
}

impl Vec2x4 {
    /// The lanes' vectors packed.
    #[inline]
    pub fn from_lanes(v: [DVec2; LANES]) -> Self {
        Vec2x4 {
            x: f64x4::new(v.map(|v| v.x)),
            y: f64x4::new(v.map(|v| v.y)),
        }
    }

    /// |v|² per lane, as glam's `length_squared` (x·x + y·y).
    #[inline]
    pub fn length_squared(&self) -> f64x4 {
        self.x * self.x + self.y * self.y
    }

    /// Every lane scaled by its `s`.
    #[inline]
    pub fn scale(&self, s: f64x4) -> Self {
        Vec2x4 {
            x: self.x * s,
            y: self.y * s,
        }
    }
}

/// Applies the scalar `f` to every lane.
#[inline(always)]
fn per_lane(x: f64x4, f: impl Fn(f64) -> f64) -> f64x4 {
    f64x4::new(x.to_array().map(f))
}

/// `f64::max(x, 0.0)` per lane for finite or NaN x (NaN gives 0, as the scalar max).
#[inline(always)]
fn max0(x: f64x4) -> f64x4 {
    x.simd_gt(f64x4::ZERO).select(x, f64x4::ZERO)
}

/// Fresnel reflectance [R_s, R_p] from index `n_a` into `n_b` of waves with |u|² = `u2`
/// ([`super::interface::reflectance`] per lane; [1, 1] under total internal reflection).
#[inline]
pub fn reflectance(n_a: f64x4, n_b: f64x4, u2: f64x4) -> Pair {
    let one = f64x4::ONE;
    let tir = u2.simd_ge(n_b * n_b);
    let cos_a = max0(one - u2 / (n_a * n_a)).sqrt();
    let cos_b = (one - u2 / (n_b * n_b)).sqrt();
    let rs = (n_a * cos_a - n_b * cos_b) / (n_a * cos_a + n_b * cos_b);
    let rp = (n_b * cos_a - n_a * cos_b) / (n_b * cos_a + n_a * cos_b);
    [tir.select(one, rs * rs), tir.select(one, rp * rp)]
}

/// Fresnel transmittance 1 − R ([`super::interface::transmittance`] per lane).
#[inline]
pub fn transmittance(n_a: f64x4, n_b: f64x4, u2: f64x4) -> Pair {
    let r = reflectance(n_a, n_b, u2);
    [f64x4::ONE - r[0], f64x4::ONE - r[1]]
}

/// A layer's crossing per lane, from one root √(n² − |u|²): the factor thickness/√(n² − |u|²)
/// of [`super::interface::lateral_shift`] (shift = u · factor) and the geometric path length
/// thickness·n/√(n² − |u|²) of [`super::interface::path_length`].
#[inline]
pub fn crossing(n: f64x4, u2: f64x4, thickness_mm: f64) -> (f64x4, f64x4) {
    let root = (n * n - u2).sqrt();
    let t = f64x4::splat(thickness_mm);
    (t / root, t * n / root)
}

/// Four plane waves inside the film (the packet of the grating module's `Incident`): one
/// direction of travel along z for all lanes, per-lane wavelength and direction.
#[derive(Clone, Copy, Debug)]
pub struct Incident4 {
    z_sign: f64,
    lambda_nm: f64x4,
    beta: f64x4,
    beta2: f64x4,
    rho: [f64x4; 3],
    /// All ones where the wave can enter the film.
    pub valid: f64x4,
}

/// One order of four waves: efficiencies [TE, TM] (0 where the order does not exist), and
/// masks.
#[derive(Clone, Copy, Debug)]
pub struct Order4 {
    /// η [TE, TM] per lane (taper included), 0 where the order is evanescent or the wave
    /// cannot enter.
    pub eta: Pair,
    /// All ones where the order exists (the scalar `order` returns `Some`; the tracer needs
    /// only `reflection`, the tests check both).
    #[cfg_attr(not(test), allow(dead_code))]
    pub exists: f64x4,
    /// All ones where it exists and is reflection-type.
    pub reflection: f64x4,
}

impl Incident4 {
    /// The waves (u, `z_sign`) at `lambda_nm` in the film of `g`
    /// (`VolumeGrating::incident` per lane).
    #[inline]
    pub fn new(g: &VolumeGrating, u: &Vec2x4, z_sign: f64, lambda_nm: f64x4) -> Self {
        let k_vac = f64x4::splat(2.0 * PI) / lambda_nm;
        let beta = k_vac * f64x4::splat(g.n_film);
        let beta2 = beta * beta;
        let rho_t = u.scale(k_vac);
        let rz2 = beta2 - rho_t.length_squared();
        let valid = rz2.simd_gt(f64x4::ZERO);
        Incident4 {
            z_sign,
            lambda_nm,
            beta,
            beta2,
            rho: [rho_t.x, rho_t.y, f64x4::splat(z_sign) * rz2.sqrt()],
            valid,
        }
    }

    /// The same waves with only the lanes of `mask` kept valid: the others' orders are not
    /// evaluated (they come out as not existing), which saves their transcendental calls.
    #[inline]
    pub fn masked(self, mask: f64x4) -> Self {
        Incident4 {
            valid: self.valid & mask,
            ..self
        }
    }

    /// The same waves travelling the other way along z (`Incident::reversed`).
    #[inline]
    pub fn reversed(self) -> Self {
        Incident4 {
            z_sign: -self.z_sign,
            rho: [self.rho[0], self.rho[1], -self.rho[2]],
            ..self
        }
    }

    /// Order `order` of grating `g` (lossless: `g.alpha0_per_nm == 0`) for every lane
    /// (`Incident::order` per lane).
    #[inline]
    pub fn order(&self, g: &VolumeGrating, order: i32) -> Order4 {
        debug_assert!(g.alpha0_per_nm == 0.0, "the packet is for lossless films");
        let zero = f64x4::ZERO;
        let m = f64::from(order);
        let k = g.k_rad_per_nm;
        let sigma = [
            self.rho[0] - f64x4::splat(m * k.x),
            self.rho[1] - f64x4::splat(m * k.y),
            self.rho[2] - f64x4::splat(m * k.z),
        ];
        let kz2 = self.beta2 - (sigma[0] * sigma[0] + sigma[1] * sigma[1]);
        let root = kz2.sqrt();
        let kd_z = sigma[2].simd_ge(zero).select(root, -root);
        let c_r = self.rho[2].abs() / self.beta;
        let c_s = kd_z * f64x4::splat(self.z_sign) / self.beta;
        let exists = self.valid & kz2.simd_gt(zero) & !c_s.abs().simd_lt(f64x4::splat(1e-12));
        let dkz = kd_z - sigma[2];
        let d = f64x4::splat(g.thickness_nm);
        let reflection = exists & c_s.simd_lt(zero);
        let cos_pp = ((self.rho[0] * sigma[0] + self.rho[1] * sigma[1] + self.rho[2] * kd_z)
            / self.beta2)
            .abs();
        let kappa_s = f64x4::splat(PI * g.n1) / self.lambda_nm;
        let nu_s = kappa_s * d / (c_r * c_s.abs()).sqrt();
        let nu_p = nu_s * cos_pp;
        let xi = f64x4::splat(0.5) * dkz.abs() * d;
        let refl = [
            reflection_lossless(nu_s, xi, reflection),
            reflection_lossless(nu_p, xi, reflection),
        ];
        let trans = transmission_lossless_pair(nu_s, nu_p, xi, exists & !reflection);
        let c_min = c_r.simd_lt(c_s.abs()).select(c_r, c_s.abs());
        let taper = per_lane(c_min, |c| super::grating::svea_taper(g.n1, g.n_film, c));
        let eta = |p: usize| exists.select(reflection.select(refl[p], trans[p]) * taper, zero);
        Order4 {
            eta: [eta(0), eta(1)],
            exists,
            reflection,
        }
    }

    /// 1 − η_{+1} − η_{−1} of grating `g` (floored at 0), with `known` standing for order −1's
    /// η where it was computed already: `VolumeGrating::undiffracted_from` of a lossless film
    /// per lane (its absorption factor is 1).
    #[inline]
    pub fn undiffracted(&self, g: &VolumeGrating, known_minus: Option<Pair>) -> Pair {
        let plus = self.order(g, 1).eta;
        let minus = known_minus.unwrap_or_else(|| self.order(g, -1).eta);
        let one = f64x4::ONE;
        [
            max0(one - plus[0] - minus[0]),
            max0(one - plus[1] - minus[1]),
        ]
    }
}

/// [`kogelnik::reflection_lossless`] in the lanes of `mask` (anything elsewhere): the unified
/// form η = ν²/(ξ² + G(ν² − ξ²)²). Lanes outside the mask skip the tan or tanh.
#[inline]
fn reflection_lossless(nu: f64x4, xi: f64x4, mask: f64x4) -> f64x4 {
    let bits = mask.to_bitmask();
    let zero = f64x4::ZERO;
    let x = nu * nu - xi * xi;
    // G(x) (kogelnik::g_unified): the series near 0, s/tanh s above, s/tan s below.
    let series = f64x4::ONE + x / f64x4::splat(3.0) - x * x / f64x4::splat(45.0)
        + f64x4::splat(2.0) * x * x * x / f64x4::splat(945.0);
    let s = x.abs().sqrt();
    let pos = x.simd_gt(zero);
    let pos = pos.to_bitmask();
    let t = f64x4::new(std::array::from_fn(|i| {
        let s = s.as_array()[i];
        match (bits >> i & 1, pos >> i & 1) {
            (0, _) => 1.0,
            (_, 1) => s.tanh(),
            _ => s.tan(),
        }
    }));
    let g = x.abs().simd_lt(f64x4::splat(1e-3)).select(series, s / t);
    let den = xi * xi + g * g;
    let eta = (nu * nu / den).max(zero).min(f64x4::ONE);
    (nu.simd_gt(zero) & den.is_finite()).select(eta, zero)
}

/// [`kogelnik::transmission_lossless_pair`] in the lanes of `mask` (0 elsewhere): its
/// branches and its sin/cos are the scalar function's, so it is called per lane.
#[inline]
fn transmission_lossless_pair(nu_s: f64x4, nu_p: f64x4, xi: f64x4, mask: f64x4) -> Pair {
    let bits = mask.to_bitmask();
    if bits == 0 {
        return [f64x4::ZERO; 2];
    }
    let (s, p, x) = (nu_s.as_array(), nu_p.as_array(), xi.as_array());
    let e: [[f64; 2]; LANES] = std::array::from_fn(|i| {
        if bits >> i & 1 == 1 {
            kogelnik::transmission_lossless_pair(s[i], p[i], x[i])
        } else {
            [0.0; 2]
        }
    });
    [f64x4::new(e.map(|e| e[0])), f64x4::new(e.map(|e| e[1]))]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::interface;

    fn grating(n1: f64) -> VolumeGrating {
        VolumeGrating::from_recording(532.0, 61.2, 1.50, 16.0, n1, 0.0)
    }

    /// A small deterministic generator (tests only).
    struct Gen(u64);
    impl Gen {
        fn next(&mut self) -> f64 {
            self.0 = crate::sampler::mix64(self.0);
            crate::sampler::to_unit(self.0)
        }
    }

    /// Every lane equals the scalar functions bit for bit: Kogelnik orders ±1 of both
    /// directions of travel (reflection, transmission near and far off Bragg, evanescent, waves
    /// that cannot enter), Fresnel in and out of TIR, shifts and path lengths. 20,000 random
    /// waves over the whole range of u and λ; each branch of the formulas is visited (counted).
    #[test]
    fn lanes_equal_the_scalar_functions_bit_for_bit() {
        let mut rng = Gen(99);
        let mut seen = [0usize; 4]; // reflection, transmission, no order, no wave
        for k in 0..5000 {
            let g = grating(if k % 2 == 0 { 0.01 } else { 0.03 });
            let u: [DVec2; LANES] = std::array::from_fn(|_| {
                let r = 1.6 * rng.next().sqrt();
                let a = 2.0 * PI * rng.next();
                DVec2::new(r * a.cos(), r * a.sin())
            });
            let lam: [f64; LANES] = std::array::from_fn(|_| 380.0 + 400.0 * rng.next());
            let n: [f64; LANES] = std::array::from_fn(|_| 1.45 + 0.1 * rng.next());
            let uv = Vec2x4::from_lanes(u);
            let lv = f64x4::new(lam);
            let nv = f64x4::new(n);
            for z in [1.0, -1.0] {
                let inc = Incident4::new(&g, &uv, z, lv);
                for order in [1, -1] {
                    for (w, rev) in [(inc, false), (inc.reversed(), true)] {
                        let o = w.order(&g, order);
                        for i in 0..LANES {
                            let zs = if rev { -z } else { z };
                            let inc1 = g.incident(u[i], zs, lam[i]);
                            let d = inc1.and_then(|w| w.order(&g, order));
                            let eta = [o.eta[0].as_array()[i], o.eta[1].as_array()[i]];
                            let exists = o.exists.to_bitmask() >> i & 1 == 1;
                            let refl = o.reflection.to_bitmask() >> i & 1 == 1;
                            assert_eq!(exists, d.is_some(), "lane {i}: {:?} {}", u[i], lam[i]);
                            match d {
                                Some(d) => {
                                    assert_eq!(refl, d.reflection);
                                    assert_eq!(eta.map(f64::to_bits), d.eta.map(f64::to_bits));
                                    seen[if d.reflection { 0 } else { 1 }] += 1;
                                }
                                None => {
                                    assert_eq!(eta, [0.0, 0.0]);
                                    seen[if inc1.is_some() { 2 } else { 3 }] += 1;
                                }
                            }
                        }
                    }
                }
                let t = inc.undiffracted(&g, None);
                let known = inc.order(&g, -1).eta;
                let t_known = inc.undiffracted(&g, Some(known));
                for i in 0..LANES {
                    let s = g.undiffracted(u[i], z, lam[i]);
                    assert_eq!(
                        [t[0].as_array()[i], t[1].as_array()[i]].map(f64::to_bits),
                        s.map(f64::to_bits)
                    );
                    assert_eq!(t_known[0].as_array()[i].to_bits(), s[0].to_bits());
                }
            }
            let u2 = uv.length_squared();
            let r = reflectance(nv, f64x4::ONE, u2);
            let t = transmittance(f64x4::ONE, nv, u2);
            let (sf, pl) = crossing(nv, u2, 3.0);
            for i in 0..LANES {
                let rs = interface::reflectance(n[i], 1.0, u[i]);
                let ts = interface::transmittance(1.0, n[i], u[i]);
                assert_eq!(
                    [r[0].as_array()[i], r[1].as_array()[i]].map(f64::to_bits),
                    rs.map(f64::to_bits)
                );
                assert_eq!(
                    [t[0].as_array()[i], t[1].as_array()[i]].map(f64::to_bits),
                    ts.map(f64::to_bits)
                );
                if u[i].length_squared() < n[i] * n[i] {
                    let ls = interface::lateral_shift(u[i], n[i], 3.0);
                    assert_eq!((u[i] * sf.as_array()[i]).to_array(), ls.to_array());
                    assert_eq!(
                        pl.as_array()[i].to_bits(),
                        interface::path_length(u[i], n[i], 3.0).to_bits()
                    );
                }
            }
        }
        assert!(seen.iter().all(|&c| c > 1000), "{seen:?}");
    }

    /// The reflection formula's three branches of G (series, tanh, tan) and its guards, at
    /// chosen points, lane for lane against the scalar function; a wrong lane order fails.
    #[test]
    fn reflection_branches_match_and_lanes_stay_apart() {
        let nu = f64x4::new([0.5, 2.0, 0.0, 1.0]);
        let xi = f64x4::new([0.5 + 1e-5, 0.3, 1.0, 9.0]);
        let all = f64x4::splat(0.0).simd_eq(f64x4::ZERO);
        let eta = reflection_lossless(nu, xi, all);
        for i in 0..LANES {
            let s = kogelnik::reflection_lossless(nu.as_array()[i], xi.as_array()[i]);
            assert_eq!(eta.as_array()[i].to_bits(), s.to_bits(), "lane {i}");
        }
        let swapped = reflection_lossless(
            f64x4::new([2.0, 0.5, 0.0, 1.0]),
            f64x4::new([0.3, 0.5 + 1e-5, 1.0, 9.0]),
            all,
        );
        assert_ne!(swapped.as_array()[0], eta.as_array()[0]);
        assert_eq!(swapped.as_array()[0], eta.as_array()[1]);
    }
}
