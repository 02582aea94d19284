//! Volume reflection hologram (vHOE) as a thick slanted grating: grating vector from the
//! recording geometry, on-shell k-closure for arbitrary (conical) incidence, and the Kogelnik
//! efficiency for TE (s) and TM (p).
//!
//! Model (`docs/physics.md` §0.2, §2, §3):
//! - Recording beams inside the film: object ŝ_O = (0, 0, 1), reference
//!   ŝ_R = (0, sin θ_R, −cos θ_R); K = k0 (ŝ_O − ŝ_R), k0 = 2π n_film/λ0 (a reflection grating,
//!   with the sign correction of §0.2 to the paper's Eq. 4).
//! - A plane wave is described by its tangential "optical direction cosines" u = n·ŝ_t, which
//!   every planar interface conserves (Snell) and a grating shifts by −m·(λ/2π)·K_t.
//! - Closure (§2.1): ρ = β ŝ, σ = ρ − mK, k_d,t = σ_t exactly, k_d,z = sign(σ_z)√(β² − |k_d,t|²)
//!   (on-shell, Uchida's "beta-value" method); evanescent orders have η = 0.
//! - Dephasing (§2.2 (b)): |ξ| = |Δk_z|·d/2 with Δk_z = k_d,z − σ_z, ν = π n1 d/(λ√(c_R|c_S|)),
//!   c_R = |ρ_z|/β, c_S = k_d,z/β (signed relative to the incident direction); reflection
//!   geometry when c_S < 0. In the lossy case ϑ_β = c_S·Δk_z enters Kogelnik's general form.
//! - Polarisation (§1.5): κ_s = κ, κ_p = κ·(ρ̂·k̂_d); s and p do not cross-couple.
//! - Grazing orders: coupled-wave theory drops d²S/dz² against 2iβc_S·dS/dz (slowly varying
//!   envelopes). With dS/dz ~ (κ/c_S)·R the neglected term is ε = κ/(2βc_S²) = n1/(4 n c_S²)
//!   of the kept one, and likewise for R with c_R; the smaller of |c_S| and c_R decides, so
//!   the weight is reciprocal. Toward a diffracted order's grazing cut-off (c_S → 0) the on-shell form
//!   has ν ∝ 1/√|c_S| → ∞ with ξ finite, so η → 1: an artefact of the approximation, not
//!   physics. Criterion: full η while ε ≤ 0.1, none once ε ≥ 1 (the dropped term as large as the
//!   kept one), a C¹ smoothstep in ε between ([`svea_taper`]). For the paper's film (n1 = 0.015,
//!   n = 1.50) η is cut below |c_S| = 0.050 and tapered below 0.158 (9.1° from grazing inside the
//!   film); the guided orders the camera uses have |c_S| ≥ 0.38 and are untouched.
//!
//! Assumptions: the film (thickness d, mean index n_film, no dispersion of n_film) and the
//! fringes are uniform through the film (fabrication errors such as shrinkage change K, d and
//! n_film as a whole, `optics::fabrication`); reflections at the glass–film boundary
//! are neglected (index mismatch ≲ 0.03). Absorption of a transmission-type order uses the
//! lossless Kogelnik value times exp(−α0 d (1/c_R + 1/c_S)), an approximation used only for
//! far-off-Bragg stray orders.

use glam::{DVec2, DVec3};
use num_complex::Complex64;
use std::f64::consts::PI;

use super::kogelnik::{self, CoupledWave};

/// Weight in [0, 1] applied to a diffracted order's Kogelnik efficiency for the validity of the
/// slowly-varying-envelope approximation (module notes): `c` is the smaller obliquity factor of
/// the incident and diffracted waves; with ε = n1/(4 n_film c²), 1 for
/// ε ≤ 0.1, 0 for ε ≥ 1, and the smoothstep 3t² − 2t³ of t = (1 − ε)/0.9 between.
#[inline]
pub fn svea_taper(n1: f64, n_film: f64, c: f64) -> f64 {
    let eps = n1.abs() / (4.0 * n_film * c * c);
    if !(eps > 0.1) {
        // ε ≤ 0.1, or NaN-free zero modulation (ε = 0).
        return if eps.is_nan() { 0.0 } else { 1.0 };
    }
    let t = ((1.0 - eps) / 0.9).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// A volume grating recorded by two plane waves, ready for playback at any wavelength.
#[derive(Clone, Copy, Debug)]
pub struct VolumeGrating {
    /// Grating vector K in rad/nm (frame of `docs/design.md`: z from the user toward the camera).
    pub k_rad_per_nm: DVec3,
    /// Mean index of the film (non-dispersive).
    pub n_film: f64,
    /// Film thickness in nm.
    pub thickness_nm: f64,
    /// Index modulation amplitude n1 (peak-to-mean).
    pub n1: f64,
    /// Mean amplitude absorption α0 of the film in 1/nm.
    pub alpha0_per_nm: f64,
}

/// One diffracted order leaving a grating.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Diffraction {
    /// Tangential optical direction cosines n·ŝ_t of the diffracted wave.
    pub u: DVec2,
    /// +1 if the diffracted wave travels toward +z, −1 otherwise.
    pub z_sign: f64,
    /// Diffraction efficiency for TE (s) and TM (p) light.
    pub eta: [f64; 2],
    /// True for reflection geometry (the order leaves through the face it entered).
    pub reflection: bool,
}

impl VolumeGrating {
    /// Builds the grating from its recording: vacuum wavelength, reference angle inside the film
    /// (degrees from −z, in the yz plane), film index and thickness, index modulation, and the
    /// mean amplitude absorption α0 in 1/mm.
    pub fn from_recording(
        lambda0_nm: f64,
        reference_angle_deg: f64,
        n_film: f64,
        thickness_um: f64,
        n1: f64,
        alpha0_per_mm: f64,
    ) -> Self {
        Self::from_recording_beams(
            lambda0_nm,
            reference_angle_deg,
            0.0,
            n_film,
            thickness_um,
            n1,
            alpha0_per_mm,
        )
    }

    /// As [`Self::from_recording`] with an object beam tilted by `object_angle_deg` inside the
    /// film (from +z toward +y): ŝ_O = (0, sin θ_O, cos θ_O). At θ_O = 0 this is exactly
    /// [`Self::from_recording`] (sin 0 = 0 and cos 0 = 1 in floating point).
    pub fn from_recording_beams(
        lambda0_nm: f64,
        reference_angle_deg: f64,
        object_angle_deg: f64,
        n_film: f64,
        thickness_um: f64,
        n1: f64,
        alpha0_per_mm: f64,
    ) -> Self {
        let th = reference_angle_deg.to_radians();
        let k0 = 2.0 * PI * n_film / lambda0_nm;
        let to = object_angle_deg.to_radians();
        let s_o = DVec3::new(0.0, to.sin(), to.cos());
        let s_r = DVec3::new(0.0, th.sin(), -th.cos());
        VolumeGrating {
            k_rad_per_nm: k0 * (s_o - s_r),
            n_film,
            thickness_nm: thickness_um * 1e3,
            n1,
            alpha0_per_nm: alpha0_per_mm * 1e-6,
        }
    }

    /// Grating period Λ = 2π/|K| in nm.
    pub fn period_nm(&self) -> f64 {
        2.0 * PI / self.k_rad_per_nm.length()
    }

    /// The shift (λ/2π)·K_t that order m = +1 subtracts from u.
    #[inline]
    pub fn u_shift(&self, lambda_nm: f64) -> DVec2 {
        self.k_rad_per_nm.truncate() * (lambda_nm / (2.0 * PI))
    }

    /// Exact (on-shell) Bragg wavelength, in nm, for a wave with tangential direction cosines `u`
    /// entering the film toward +z and diffracted into order +1 (the in-coupling of the bottom
    /// vHOE): |ρ − K| = |ρ| gives λ_B = 4π(u·K_t + √(n² − |u|²)·K_z)/|K|² (docs/physics.md §3.2).
    /// Returns `None` when no positive wavelength is Bragg-matched or the wave cannot enter.
    pub fn bragg_wavelength_nm(&self, u: DVec2) -> Option<f64> {
        let nn = self.n_film * self.n_film - u.length_squared();
        if nn <= 0.0 {
            return None;
        }
        let k = self.k_rad_per_nm;
        let lam = (4.0 * PI / k.length_squared()) * (u.dot(k.truncate()) + nn.sqrt() * k.z);
        (lam > 0.0 && lam.is_finite()).then_some(lam)
    }

    /// Diffraction of the plane wave (u, travelling toward `z_sign`) at vacuum wavelength
    /// `lambda_nm` into order `order` (σ = ρ − order·K). `None` if the wave cannot enter the film
    /// or the order is evanescent.
    pub fn diffract(
        &self,
        u: DVec2,
        z_sign: f64,
        lambda_nm: f64,
        order: i32,
    ) -> Option<Diffraction> {
        self.incident(u, z_sign, lambda_nm)?.order(self, order)
    }

    /// The incident wave's quantities shared by all its orders; `None` if it cannot enter
    /// the film.
    #[inline]
    pub(crate) fn incident(&self, u: DVec2, z_sign: f64, lambda_nm: f64) -> Option<Incident> {
        let k_vac = 2.0 * PI / lambda_nm;
        let beta = k_vac * self.n_film;
        let beta2 = beta * beta;
        let rho_t = u * k_vac;
        let rz2 = beta2 - rho_t.length_squared();
        if rz2 <= 0.0 {
            return None;
        }
        Some(Incident {
            z_sign,
            lambda_nm,
            k_vac,
            beta,
            beta2,
            rho: rho_t.extend(z_sign * rz2.sqrt()),
        })
    }
}

/// A plane wave inside the film, before diffraction (see [`VolumeGrating::diffract`]).
#[derive(Clone, Copy, Debug)]
pub struct Incident {
    z_sign: f64,
    lambda_nm: f64,
    k_vac: f64,
    beta: f64,
    beta2: f64,
    rho: DVec3,
}

impl Incident {
    /// The same wave travelling the other way along z (u unchanged): exactly what
    /// `incident(u, −z_sign, λ)` computes, without recomputing it.
    #[inline]
    pub fn reversed(self) -> Incident {
        Incident {
            z_sign: -self.z_sign,
            rho: DVec3::new(self.rho.x, self.rho.y, -self.rho.z),
            ..self
        }
    }

    /// Diffraction of this wave by `g` into order `order`; `None` if the order is evanescent.
    pub fn order(&self, g: &VolumeGrating, order: i32) -> Option<Diffraction> {
        let Incident {
            z_sign,
            lambda_nm,
            k_vac,
            beta,
            beta2,
            rho,
        } = *self;
        let sigma = rho - f64::from(order) * g.k_rad_per_nm;
        let kd_t = sigma.truncate();
        let kz2 = beta2 - kd_t.length_squared();
        if kz2 <= 0.0 {
            return None;
        }
        let kd_z = if sigma.z >= 0.0 {
            kz2.sqrt()
        } else {
            -kz2.sqrt()
        };
        let c_r = rho.z.abs() / beta;
        // Signed relative to the incident direction (mirror z when the wave travels −z).
        let c_s = kd_z * z_sign / beta;
        if c_s.abs() < 1e-12 {
            return None;
        }
        let dkz = kd_z - sigma.z;
        let d = g.thickness_nm;
        let reflection = c_s < 0.0;
        let kd = kd_t.extend(kd_z);
        let cos_pp = (rho.dot(kd) / beta2).abs();
        let kappa_s = PI * g.n1 / lambda_nm;
        let eta = if g.alpha0_per_nm == 0.0 {
            let nu_s = kappa_s * d / (c_r * c_s.abs()).sqrt();
            let xi = 0.5 * dkz.abs() * d;
            if reflection {
                [
                    kogelnik::reflection_lossless(nu_s, xi),
                    kogelnik::reflection_lossless(nu_s * cos_pp, xi),
                ]
            } else {
                kogelnik::transmission_lossless_pair(nu_s, nu_s * cos_pp, xi)
            }
        } else if reflection {
            let theta = c_s * dkz * z_sign;
            let cw = |kappa: f64| CoupledWave {
                kappa: Complex64::new(kappa, 0.0),
                alpha0: g.alpha0_per_nm,
                theta,
                c_r,
                c_s,
                d,
            };
            [
                cw(kappa_s).reflection_efficiency(),
                cw(kappa_s * cos_pp).reflection_efficiency(),
            ]
        } else {
            let nu_s = kappa_s * d / (c_r * c_s).sqrt();
            let xi = 0.5 * dkz.abs() * d;
            let att = (-g.alpha0_per_nm * d * (1.0 / c_r + 1.0 / c_s)).exp();
            [
                kogelnik::transmission_lossless(nu_s, xi) * att,
                kogelnik::transmission_lossless(nu_s * cos_pp, xi) * att,
            ]
        };
        // Both envelopes must vary slowly: the smaller obliquity decides (reciprocal).
        let taper = svea_taper(g.n1, g.n_film, c_r.min(c_s.abs()));
        Some(Diffraction {
            u: kd_t / k_vac,
            z_sign: kd_z.signum(),
            eta: eta.map(|e| e * taper),
            reflection,
        })
    }
}

impl VolumeGrating {
    /// Mean-absorption factor exp(−2α0 d/c_R) of the film for a wave with direction cosines
    /// `u` crossing it once (1 for a lossless film or a wave that cannot enter).
    #[inline]
    pub fn film_attenuation(&self, u: DVec2) -> f64 {
        if self.alpha0_per_nm <= 0.0 {
            return 1.0;
        }
        let cr2 = 1.0 - u.length_squared() / (self.n_film * self.n_film);
        if cr2 > 0.0 {
            (-2.0 * self.alpha0_per_nm * self.thickness_nm / cr2.sqrt()).exp()
        } else {
            1.0
        }
    }

    /// Efficiency [TE, TM] of one order (zero if it does not propagate).
    #[inline]
    pub fn efficiency(&self, u: DVec2, z_sign: f64, lambda_nm: f64, order: i32) -> [f64; 2] {
        self.diffract(u, z_sign, lambda_nm, order)
            .map_or([0.0, 0.0], |d| d.eta)
    }

    /// Fraction of a wave (u, z_sign) that crosses the film undiffracted: 1 − Σ_{m=±1} η_m,
    /// times the film's mean absorption. `known` supplies an order's efficiency already
    /// computed (the same wave and order give the same value), to avoid evaluating it twice.
    pub fn undiffracted_with(
        &self,
        u: DVec2,
        z_sign: f64,
        lambda_nm: f64,
        known: Option<(i32, [f64; 2])>,
    ) -> [f64; 2] {
        // The incident wave once for both orders (the same values `efficiency` computes).
        self.undiffracted_from(self.incident(u, z_sign, lambda_nm), u, known)
    }

    /// [`Self::undiffracted_with`] of the wave `incident` = `self.incident(u, …)` (computed
    /// once for several uses).
    #[inline]
    pub(crate) fn undiffracted_from(
        &self,
        incident: Option<Incident>,
        u: DVec2,
        known: Option<(i32, [f64; 2])>,
    ) -> [f64; 2] {
        let mut t = [1.0, 1.0];
        for order in [1, -1] {
            let eta = match known {
                Some((o, eta)) if o == order => eta,
                _ => incident
                    .and_then(|w| w.order(self, order))
                    .map_or([0.0, 0.0], |d| d.eta),
            };
            t[0] -= eta[0];
            t[1] -= eta[1];
        }
        let att = self.film_attenuation(u);
        [t[0].max(0.0) * att, t[1].max(0.0) * att]
    }

    /// Fraction of a wave (u, z_sign) that crosses the film undiffracted (see
    /// [`Self::undiffracted_with`]).
    pub fn undiffracted(&self, u: DVec2, z_sign: f64, lambda_nm: f64) -> [f64; 2] {
        self.undiffracted_with(u, z_sign, lambda_nm, None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn paper(n1: f64) -> VolumeGrating {
        VolumeGrating::from_recording(532.0, 61.2, 1.50, 16.0, n1, 0.0)
    }

    /// Toward a diffracted order's grazing cut-off the raw on-shell Kogelnik efficiency tends
    /// to 1 (ν ∝ 1/√|c_S|); the SVEA taper brings it to 0 there and leaves the camera's guided
    /// orders unchanged.
    #[test]
    fn grazing_orders_are_cut() {
        let g = paper(0.015);
        let lam = 532.0;
        let k_vac = 2.0 * PI / lam;
        let beta = k_vac * g.n_film;
        // In-plane incidence from the user side (+z) whose first order leaves at |c_S| = c:
        // k_d,y = k_vac u_y − K_y = β√(1 − c²).
        let order_at = |c: f64| {
            let u_y = (g.k_rad_per_nm.y + beta * (1.0 - c * c).sqrt()) / k_vac;
            let d = g.diffract(DVec2::new(0.0, u_y), 1.0, lam, 1).unwrap();
            let c_s = (1.0 - d.u.length_squared() / (g.n_film * g.n_film)).sqrt();
            assert!((c_s - c).abs() < 1e-6, "{c_s} vs {c}");
            (d, u_y)
        };
        // The raw coupled-wave value at c_S = 1e-5 is close to 1 (ν ≈ 450 ≫ ξ ≈ 80): what the
        // taper removes.
        let c = 1e-5;
        let (d, u_y) = order_at(c);
        let c_r = (1.0 - u_y * u_y / (g.n_film * g.n_film)).sqrt();
        let nu = PI * g.n1 * g.thickness_nm / (lam * (c_r * c).sqrt());
        let rho_z = beta * c_r;
        let sigma_z = rho_z - g.k_rad_per_nm.z;
        let xi = 0.5 * (-beta * c - sigma_z).abs() * g.thickness_nm;
        let raw = kogelnik::reflection_lossless(nu, xi);
        assert!(raw > 0.9, "raw on-shell efficiency near grazing {raw}");
        assert_eq!(d.eta, [0.0, 0.0]);
        // Monotone taper between the cut (|c_S| = 0.050) and full weight (0.158).
        let w: Vec<f64> = [0.04, 0.06, 0.1, 0.15, 0.16, 0.5]
            .iter()
            .map(|&c| svea_taper(g.n1, g.n_film, c))
            .collect();
        assert_eq!(w[0], 0.0);
        assert!(
            w[1] > 0.0 && w[1] < w[2] && w[2] < w[3] && w[3] < 1.0,
            "{w:?}"
        );
        assert_eq!(w[4], 1.0);
        assert_eq!(w[5], 1.0);
        // The guided order at the centre of the field (|c_S| ≈ 0.5) is untouched.
        let (d, _) = order_at(0.5);
        assert!(d.eta[0] > 0.0);
        assert_eq!(svea_taper(g.n1, g.n_film, 0.38), 1.0);
    }

    #[test]
    fn reversed_incident_is_exact() {
        let g = paper(0.015);
        for (u, lam) in [
            (DVec2::new(0.1, 0.9), 530.0),
            (DVec2::new(-0.2, 1.1), 610.5),
        ] {
            for z in [1.0, -1.0] {
                let w = g.incident(u, z, lam).unwrap();
                let r = w.reversed();
                let want = g.incident(u, -z, lam).unwrap();
                assert_eq!(r.z_sign, want.z_sign);
                assert_eq!(
                    r.rho.to_array().map(f64::to_bits),
                    want.rho.to_array().map(f64::to_bits)
                );
                for order in [-1, 1] {
                    assert_eq!(r.order(&g, order), want.order(&g, order));
                }
            }
        }
    }

    #[test]
    fn grating_vector_and_period() {
        let g = paper(0.01);
        // docs/physics.md §3.1: K = (0, −0.015524, 0.026250) nm⁻¹, Λ = 206.0 nm at n = 1.50.
        assert!((g.k_rad_per_nm.y - -0.015524).abs() < 2e-6);
        assert!((g.k_rad_per_nm.z - 0.026250).abs() < 2e-6);
        assert!((g.period_nm() - 206.0).abs() < 0.1);
        // K̂ tilted 30.6° from +z toward −y.
        let tilt = (-g.k_rad_per_nm.y).atan2(g.k_rad_per_nm.z).to_degrees();
        assert!((tilt - 30.6).abs() < 1e-9);
    }

    #[test]
    fn normal_incidence_couples_into_reference_direction() {
        let g = paper(0.01);
        let dif = g.diffract(DVec2::ZERO, 1.0, 532.0, 1).expect("propagating");
        assert!(dif.reflection);
        assert_eq!(dif.z_sign, -1.0);
        // Diffracted along ŝ_R: u = n sin θ_R ŷ.
        assert!((dif.u.y - 1.5 * 61.2f64.to_radians().sin()).abs() < 1e-12);
        assert!(dif.u.x.abs() < 1e-15);
        // At Bragg: η = tanh²ν with ν = π n1 d/(λ√(c_R|c_S|)).
        let nu = PI * 0.01 * 16000.0 / (532.0 * 61.2f64.to_radians().cos().sqrt());
        assert!((dif.eta[0] - nu.tanh().powi(2)).abs() < 1e-12);
        assert!((g.bragg_wavelength_nm(DVec2::ZERO).unwrap() - 532.0).abs() < 1e-9);
    }

    /// FWHM of η(λ) at normal incidence, found numerically on a fine grid.
    fn fwhm_nm(g: &VolumeGrating, pol: usize) -> (f64, f64) {
        let (lo, hi, n) = (500.0, 570.0, 70_001);
        let etas: Vec<f64> = (0..n)
            .map(|i| {
                let lam = lo + (hi - lo) * i as f64 / (n - 1) as f64;
                g.diffract(DVec2::ZERO, 1.0, lam, 1)
                    .map_or(0.0, |d| d.eta[pol])
            })
            .collect();
        let peak = etas.iter().cloned().fold(0.0, f64::max);
        let first = etas.iter().position(|&e| e >= peak / 2.0).unwrap();
        let last = etas.iter().rposition(|&e| e >= peak / 2.0).unwrap();
        (peak, (last - first) as f64 * (hi - lo) / (n - 1) as f64)
    }

    #[test]
    fn fwhm_matches_physics_reference_table() {
        // docs/physics.md §3.5: (n1, η_TE, FWHM_TE, η_TM, FWHM_TM)
        let table = [
            (0.005, 0.350, 3.95, 0.100, 3.53),
            (0.010, 0.769, 5.33, 0.331, 3.91),
            (0.020, 0.983, 8.57, 0.748, 5.21),
            (0.030, 0.999, 11.67, 0.925, 6.78),
        ];
        for (n1, eta_te, w_te, eta_tm, w_tm) in table {
            let g = paper(n1);
            let (p_te, f_te) = fwhm_nm(&g, 0);
            let (p_tm, f_tm) = fwhm_nm(&g, 1);
            assert!((p_te - eta_te).abs() < 1e-3, "n1 {n1}: η_TE {p_te}");
            assert!((p_tm - eta_tm).abs() < 1e-3, "n1 {n1}: η_TM {p_tm}");
            assert!((f_te / w_te - 1.0).abs() < 0.01, "n1 {n1}: FWHM_TE {f_te}");
            assert!((f_tm / w_tm - 1.0).abs() < 0.01, "n1 {n1}: FWHM_TM {f_tm}");
        }
    }

    #[test]
    fn bragg_wavelength_in_plane_closed_form() {
        // docs/physics.md §3.3: λ_B(Θ) = λ0 cos(Θ + θ_R/2)/cos(θ_R/2) for in-plane incidence.
        let g = paper(0.01);
        for &(theta_deg, expect) in &[(-10.0, 578.6), (-5.0, 557.4), (5.0, 502.6), (10.0, 469.3)] {
            let th: f64 = f64::to_radians(theta_deg);
            let u = DVec2::new(0.0, 1.5 * th.sin());
            let lam = g.bragg_wavelength_nm(u).unwrap();
            let closed = 532.0 * (th + 30.6f64.to_radians()).cos() / 30.6f64.to_radians().cos();
            assert!((lam - closed).abs() < 1e-9 * closed);
            assert!((lam - expect).abs() < 0.06, "{theta_deg}: {lam}");
            // At λ_B the closure is exact: the diffracted order is on-shell with Δk_z = 0,
            // so η = tanh²ν.
            let dif = g.diffract(u, 1.0, lam, 1).unwrap();
            let beta = 2.0 * PI * 1.5 / lam;
            let c_r = (1.0 - u.length_squared() / 2.25).sqrt();
            let c_s = (1.0 - dif.u.length_squared() / 2.25).sqrt();
            let nu = PI * 0.01 * 16000.0 / (lam * (c_r * c_s).sqrt());
            assert!((dif.eta[0] - nu.tanh().powi(2)).abs() < 1e-9, "β {beta}");
        }
    }

    #[test]
    fn conical_bragg_wavelength() {
        // docs/physics.md §3.3: horizontal tilt a at zero vertical tilt gives λ_B = λ0 cos a.
        let g = paper(0.01);
        for &a in &[5.0f64, 10.0, 15.0] {
            let u = DVec2::new(1.5 * a.to_radians().sin(), 0.0);
            let lam = g.bragg_wavelength_nm(u).unwrap();
            assert!((lam - 532.0 * a.to_radians().cos()).abs() < 1e-9);
        }
    }

    #[test]
    fn reciprocity_of_in_and_out_coupling() {
        // In-coupling u_in → u_g (order +1) and the reverse u_g → u_in (order −1) have the same
        // efficiency in the lossless case, at any wavelength and direction.
        let g = paper(0.02);
        let mut rng = crate::kogelnik::tests::TestRng(5);
        let mut checked = 0;
        for _ in 0..500 {
            let u = DVec2::new(rng.range(-0.3, 0.3), rng.range(-0.3, 0.3));
            let lam = rng.range(420.0, 650.0);
            // Directions whose order +1 is evanescent have nothing to compare.
            let Some(fwd) = g.diffract(u, 1.0, lam, 1) else {
                continue;
            };
            checked += 1;
            let back = g.diffract(fwd.u, fwd.z_sign, lam, -1).unwrap();
            assert!((back.u - u).length() < 1e-12);
            assert_eq!(back.z_sign, 1.0);
            for p in 0..2 {
                assert!((fwd.eta[p] - back.eta[p]).abs() < 1e-12);
            }
        }
        assert!(checked > 300, "{checked}");
    }
}
