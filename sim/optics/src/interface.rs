//! Planar dielectric interfaces: Snell's law, Fresnel reflectance (s and p) and total internal
//! reflection, written in terms of the tangential optical direction cosines u = n·ŝ_t.
//!
//! Model (`docs/physics.md` §4.3, standard textbook results): at a plane interface between
//! indices n_a (incident side) and n_b, u is conserved (Snell). cos θ_a = √(1 − |u|²/n_a²),
//! cos θ_b = √(1 − |u|²/n_b²); |u| ≥ n_b is total internal reflection (R = 1).
//!   r_s = (n_a cos θ_a − n_b cos θ_b)/(n_a cos θ_a + n_b cos θ_b)
//!   r_p = (n_b cos θ_a − n_a cos θ_b)/(n_b cos θ_a + n_a cos θ_b),   R = r², T = 1 − R.
//! Radiance divided by n² is invariant across a lossless interface, so a transmitted ray's
//! (basic) radiance is simply multiplied by T.
//!
//! Assumptions: non-absorbing, non-magnetic media; s and p are taken relative to each
//! interface's own plane of incidence (no basis rotation between successive elements, which is
//! exact for in-plane rays and a small approximation for conical ones).

use glam::{DVec2, DVec3};

/// Fresnel reflectance [R_s, R_p] for a wave with direction cosines `u` going from index `n_a`
/// into index `n_b`. Returns [1, 1] under total internal reflection.
#[inline]
pub fn reflectance(n_a: f64, n_b: f64, u: DVec2) -> [f64; 2] {
    let u2 = u.length_squared();
    if u2 >= n_b * n_b {
        return [1.0, 1.0];
    }
    let cos_a = (1.0 - u2 / (n_a * n_a)).max(0.0).sqrt();
    let cos_b = (1.0 - u2 / (n_b * n_b)).sqrt();
    let rs = (n_a * cos_a - n_b * cos_b) / (n_a * cos_a + n_b * cos_b);
    let rp = (n_b * cos_a - n_a * cos_b) / (n_b * cos_a + n_a * cos_b);
    [rs * rs, rp * rp]
}

/// Fresnel transmittance [T_s, T_p] = 1 − R (zero under total internal reflection).
#[inline]
pub fn transmittance(n_a: f64, n_b: f64, u: DVec2) -> [f64; 2] {
    let r = reflectance(n_a, n_b, u);
    [1.0 - r[0], 1.0 - r[1]]
}

/// True if a wave with direction cosines `u` is totally reflected at an interface into `n_b`.
#[inline]
pub fn is_tir(n_b: f64, u: DVec2) -> bool {
    u.length_squared() >= n_b * n_b
}

/// Critical angle (radians) from index `n_a` into `n_b` (< n_a); NaN if there is none.
pub fn critical_angle(n_a: f64, n_b: f64) -> f64 {
    (n_b / n_a).asin()
}

/// Unit direction of the wave (u, z_sign) in a medium of index `n`.
#[inline]
pub fn direction(u: DVec2, n: f64, z_sign: f64) -> DVec3 {
    let t = u / n;
    t.extend(z_sign * (1.0 - t.length_squared()).max(0.0).sqrt())
}

/// Lateral displacement, in mm, of a ray (u) crossing a layer of index `n` and thickness
/// `thickness_mm`: thickness·u/√(n² − |u|²) (i.e. thickness·tan θ along ŝ_t).
#[inline]
pub fn lateral_shift(u: DVec2, n: f64, thickness_mm: f64) -> DVec2 {
    u * (thickness_mm / (n * n - u.length_squared()).sqrt())
}

/// Geometric path length, in mm, of a ray (u) crossing a layer: thickness·n/√(n² − |u|²).
#[inline]
pub fn path_length(u: DVec2, n: f64, thickness_mm: f64) -> f64 {
    thickness_mm * n / (n * n - u.length_squared()).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn reference_values() {
        // docs/physics.md §4.3: air→glass n = 1.52: R = 0.0426 at 0°; (0.050, 0.036) at 20°;
        // (0.061, 0.027) at 30°.
        let r0 = reflectance(1.0, 1.52, DVec2::ZERO);
        assert!((r0[0] - 0.0426).abs() < 1e-4 && (r0[1] - 0.0426).abs() < 1e-4);
        let r20 = reflectance(1.0, 1.52, DVec2::new(20f64.to_radians().sin(), 0.0));
        assert!((r20[0] - 0.050).abs() < 1e-3 && (r20[1] - 0.036).abs() < 1e-3);
        let r30 = reflectance(1.0, 1.52, DVec2::new(0.0, 30f64.to_radians().sin()));
        assert!((r30[0] - 0.061).abs() < 1e-3 && (r30[1] - 0.027).abs() < 1e-3);
        // Critical angles 41.14° (n = 1.52) and 41.81° (n = 1.50).
        assert!((critical_angle(1.52, 1.0).to_degrees() - 41.14).abs() < 0.01);
        assert!((critical_angle(1.50, 1.0).to_degrees() - 41.81).abs() < 0.01);
    }

    #[test]
    fn brewster_angle_has_zero_p_reflectance() {
        let n = 1.5f64;
        let u = DVec2::new(n.atan().sin(), 0.0);
        assert!(reflectance(1.0, n, u)[1] < 1e-20);
    }

    proptest! {
        #[test]
        fn energy_and_reciprocity(n_a in 1.0f64..2.0, n_b in 1.0f64..2.0, s in 0.0f64..0.999, phi in 0.0f64..std::f64::consts::TAU) {
            let u = DVec2::new(phi.cos(), phi.sin()) * (s * n_a.min(n_b));
            let r_ab = reflectance(n_a, n_b, u);
            let r_ba = reflectance(n_b, n_a, u);
            for p in 0..2 {
                prop_assert!((0.0..=1.0).contains(&r_ab[p]));
                // Stokes reciprocity: R is the same from either side.
                prop_assert!((r_ab[p] - r_ba[p]).abs() < 1e-12);
            }
            // Snell: n_a sin θ_a = n_b sin θ_b, both equal |u|.
            let da = direction(u, n_a, 1.0);
            let db = direction(u, n_b, 1.0);
            prop_assert!((n_a * da.truncate().length() - n_b * db.truncate().length()).abs() < 1e-12);
            prop_assert!((da.length() - 1.0).abs() < 1e-12);
        }

        #[test]
        fn tir_threshold(n_a in 1.3f64..2.0, frac in 0.0f64..1.0) {
            // Beyond the critical angle R = 1, just below it R < 1.
            let uc = 1.0; // into air
            let u_above = DVec2::new(uc + frac * (n_a - uc) * 0.999 + 1e-9, 0.0);
            prop_assert_eq!(reflectance(n_a, 1.0, u_above), [1.0, 1.0]);
            let u_below = DVec2::new(uc * (1.0 - 1e-6), 0.0);
            let r = reflectance(n_a, 1.0, u_below);
            prop_assert!(r[0] < 1.0 && r[1] < 1.0);
        }
    }
}
