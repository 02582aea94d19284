//! Fabrication errors of a recorded photopolymer vHOE: what the film that was made differs in
//! from the film that was designed, applied to the grating vector, thickness, mean index and
//! index modulation of each grating (the `hoe.*` fabrication keys, docs/keys.md; all 0 =
//! nominal, which reproduces the nominal grating bit for bit).
//!
//! Model (each a standard first-order treatment):
//! - **Recording-angle error** δθ (per grating): the reference beam stood at θ_R + δθ inside the
//!   film when the grating was recorded, so K = k0(ŝ_O − ŝ_R(θ_R + δθ)) with k0 = 2π n/λ0 at
//!   the nominal mean index n (the index the recording beams saw).
//! - **Thickness error** e (µm): the film was coated e thicker than designed; the fringes are
//!   recorded through the film as coated, so only the thickness changes, d → d + e.
//! - **Shrinkage** s (relative thickness loss after recording, polymerisation shrinkage): the
//!   film is bonded to the substrate, so the in-plane fringe period is held (K_x, K_y fixed)
//!   while every length normal to the film scales by 1 − s: d → d(1 − s) and K_z → K_z/(1 − s).
//!   The fringes rotate toward the film plane's normal component (slant changes) and the Bragg
//!   wavelength shifts. This is the standard treatment of photopolymer shrinkage for slanted
//!   gratings bonded to a substrate (Zhao & Mouroulis 1994, "Diffusion model of hologram
//!   formation in dry photopolymer materials", J. Mod. Opt. 41, 1929; Kogelnik's coupled-wave
//!   theory then applies to the shrunk grating, Kogelnik 1969).
//! - **Mean-index change** δn (after recording: final cure, bleaching): n → n + δn with the
//!   fringes where they were recorded (K unchanged): the Bragg condition moves with n.
//! - **Index-modulation shortfall** f (per grating, multiplicative): n1 → n1(1 − f) (a weaker
//!   exposure or diffusion than designed).
//! - **Temperature** ΔT (playback minus recording): the film expands across its thickness by
//!   α_f ΔT (d and K_z scale by 1 + α_f ΔT as for shrinkage), the in-plane period follows the
//!   substrate, K_t → K_t/(1 + α_s ΔT), and n → n + (dn/dT)·ΔT. Linear expansion, no stress
//!   coupling between the in-plane and the normal strain (a film free to expand across its
//!   thickness); coefficients are scene keys with documented, assumed defaults.
//!
//! The combined film: d' = (d + e)(1 − s)(1 + α_f ΔT), K'_t = K_t/(1 + α_s ΔT),
//! K'_z = K_z/((1 − s)(1 + α_f ΔT)), n' = n + δn + (dn/dT)ΔT, n1' = n1(1 − f). The absorption is
//! unchanged. With every error 0 each factor is exactly 1 and each term exactly 0, so the
//! grating is the nominal one bit for bit.
//!
//! Closed form used by the tests (docs/tolerance.md): for a grating recorded with the object
//! beam normal (θ_O = 0), a = 1 + cos θ_R, b = sin θ_R, q = 1 − s, a wave entering at internal
//! angle Θ in the yz plane has the Bragg wavelength
//! λ_B(Θ, s) = 2 λ0 q (a cos Θ − b q sin Θ)/(a² + b² q²) (docs/physics.md §3.2's
//! λ_B = 4π n (sin Θ K_y + cos Θ K_z)/|K|² with K_y = −k0 b, K_z = k0 a/q); at s = 0 it is
//! λ0 cos(Θ + θ_R/2)/cos(θ_R/2).

use super::grating::VolumeGrating;

/// A film as designed and the fabrication errors of the whole film, as plain numbers (the
/// scene's `hoe.*` keys; `stscam_scene::HoeDesc::fabrication` makes one).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FilmFabrication {
    /// Designed film thickness, µm.
    pub film_thickness_um: f64,
    /// Designed mean index of the film.
    pub mean_index: f64,
    /// Amplitude absorption of the film, 1/mm.
    pub amplitude_absorption_per_mm: f64,
    /// Relative thickness loss after recording.
    pub shrinkage: f64,
    /// Mean-index change after recording.
    pub mean_index_change: f64,
    /// Coated-thickness error, µm.
    pub thickness_error_um: f64,
    /// Playback minus recording temperature, K.
    pub temperature_change_k: f64,
    /// Film expansion across its thickness, 1/K.
    pub film_expansion_per_k: f64,
    /// Substrate (in-plane) expansion, 1/K.
    pub substrate_expansion_per_k: f64,
    /// Mean-index change per kelvin.
    pub index_change_per_k: f64,
}

/// One grating's recording and its own errors, as plain numbers (a scene's grating entry).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GratingRecording {
    /// Recording wavelength in vacuum, nm.
    pub recording_wavelength_nm: f64,
    /// Reference-beam angle inside the film, degrees.
    pub reference_angle_deg: f64,
    /// Object-beam angle inside the film, degrees.
    pub object_angle_deg: f64,
    /// Designed index modulation.
    pub index_modulation: f64,
    /// Relative shortfall of the index modulation.
    pub index_modulation_shortfall: f64,
    /// Error of the reference-beam angle at recording, degrees.
    pub reference_angle_error_deg: f64,
}

/// True if the film `h` or a grating of `gs` departs from its design (the film's shrinkage,
/// mean-index change, thickness error or temperature change, a grating's index-modulation
/// shortfall or angle error): the film traced then differs from the one designed.
pub fn is_fabricated(h: &FilmFabrication, gs: &[GratingRecording]) -> bool {
    [
        h.shrinkage,
        h.mean_index_change,
        h.thickness_error_um,
        h.temperature_change_k,
    ]
    .iter()
    .any(|&v| v != 0.0)
        || gs
            .iter()
            .any(|g| g.index_modulation_shortfall != 0.0 || g.reference_angle_error_deg != 0.0)
}

/// The grating `g` of the film `h` as fabricated (module notes): the recording with its angle
/// error, then the film's thickness error, shrinkage, mean-index change, temperature and the
/// grating's index-modulation shortfall.
pub fn fabricated_grating(h: &FilmFabrication, g: &GratingRecording) -> VolumeGrating {
    let dt = h.temperature_change_k;
    let normal_scale = (1.0 - h.shrinkage) * (1.0 + h.film_expansion_per_k * dt);
    let in_plane_scale = 1.0 + h.substrate_expansion_per_k * dt;
    let thickness_um = (h.film_thickness_um + h.thickness_error_um) * normal_scale;
    let mut vg = VolumeGrating::from_recording_beams(
        g.recording_wavelength_nm,
        g.reference_angle_deg + g.reference_angle_error_deg,
        g.object_angle_deg,
        h.mean_index,
        thickness_um,
        g.index_modulation * (1.0 - g.index_modulation_shortfall),
        h.amplitude_absorption_per_mm,
    );
    let k = vg.k_rad_per_nm;
    vg.k_rad_per_nm = glam::DVec3::new(
        k.x / in_plane_scale,
        k.y / in_plane_scale,
        k.z / normal_scale,
    );
    vg.n_film = h.mean_index + h.mean_index_change + h.index_change_per_k * dt;
    vg
}

/// Every grating `gs` of the film `h` as fabricated, in order.
pub fn fabricated_gratings(h: &FilmFabrication, gs: &[GratingRecording]) -> Vec<VolumeGrating> {
    gs.iter().map(|g| fabricated_grating(h, g)).collect()
}

/// Closed-form Bragg wavelength (nm) of a grating recorded at `lambda0_nm` with the reference
/// beam at `theta_r_deg` and the object beam normal to the film, after a shrinkage `s`, for a
/// wave entering the film at internal angle `theta_in_deg` in the yz plane (module notes).
pub fn shrunk_bragg_wavelength_nm(
    lambda0_nm: f64,
    theta_r_deg: f64,
    s: f64,
    theta_in_deg: f64,
) -> f64 {
    let (tr, ti) = (theta_r_deg.to_radians(), theta_in_deg.to_radians());
    let (a, b, q) = (1.0 + tr.cos(), tr.sin(), 1.0 - s);
    2.0 * lambda0_nm * q * (a * ti.cos() - b * q * ti.sin()) / (a * a + b * b * q * q)
}

/// The recording (vacuum wavelength λ0' in nm, reference angle θ' in degrees, object beam
/// normal) that gives the grating vector of `g` in a film of `g`'s own mean index: the
/// fabricated grating seen as a designed one, so that closed forms written for a recording
/// (docs/physics.md §3) apply to it. With ŝ_O = ẑ, K = k0(0, −sin θ, 1 + cos θ), so
/// θ' = 2·atan2(−K_y, K_z) and k0' = K_z/(1 + cos θ'), λ0' = 2π n'/k0'. Exact when K_x = 0
/// (every error here keeps the fringes in the yz plane of an object beam normal to the film);
/// None if K_x ≠ 0 or K_z ≤ 0.
pub fn equivalent_recording(g: &VolumeGrating) -> Option<(f64, f64)> {
    let k = g.k_rad_per_nm;
    if k.x != 0.0 || k.z <= 0.0 {
        return None;
    }
    let theta = 2.0 * (-k.y).atan2(k.z);
    let k0 = k.z / (1.0 + theta.cos());
    Some((
        2.0 * std::f64::consts::PI * g.n_film / k0,
        theta.to_degrees(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec2;

    /// The paper's film (docs/physics.md: 532 nm, 61.2°, n 1.50, 16 µm, n1 0.015, no
    /// absorption) with the scene keys' default expansion and index coefficients.
    fn paper() -> (FilmFabrication, GratingRecording) {
        (
            FilmFabrication {
                film_thickness_um: 16.0,
                mean_index: 1.50,
                amplitude_absorption_per_mm: 0.0,
                shrinkage: 0.0,
                mean_index_change: 0.0,
                thickness_error_um: 0.0,
                temperature_change_k: 0.0,
                film_expansion_per_k: 1e-4,
                substrate_expansion_per_k: 9e-6,
                index_change_per_k: -1e-4,
            },
            GratingRecording {
                recording_wavelength_nm: 532.0,
                reference_angle_deg: 61.2,
                object_angle_deg: 0.0,
                index_modulation: 0.015,
                index_modulation_shortfall: 0.0,
                reference_angle_error_deg: 0.0,
            },
        )
    }

    /// All errors 0: the nominal grating bit for bit.
    #[test]
    fn nominal_is_exact() {
        let (h, r) = paper();
        let g = fabricated_grating(&h, &r);
        let n = VolumeGrating::from_recording(532.0, 61.2, 1.50, 16.0, 0.015, 0.0);
        assert_eq!(
            g.k_rad_per_nm.to_array().map(f64::to_bits),
            n.k_rad_per_nm.to_array().map(f64::to_bits)
        );
        assert_eq!(g.thickness_nm.to_bits(), n.thickness_nm.to_bits());
        assert_eq!(g.n_film.to_bits(), n.n_film.to_bits());
        assert_eq!(g.n1.to_bits(), n.n1.to_bits());
    }

    /// Shrinkage: the grating's own Bragg wavelength against the closed form (independent: from
    /// the recording angles, not from K), at several internal angles; tolerance 1e-9 relative.
    /// A model that scaled K_z by (1 − s) instead of 1/(1 − s) is 10 nm off and fails.
    #[test]
    fn shrinkage_bragg_closed_form() {
        let (mut h, r) = paper();
        h.shrinkage = 0.02;
        let g = fabricated_grating(&h, &r);
        let mut wrong = g;
        wrong.k_rad_per_nm.z *= (1.0 - 0.02) * (1.0 - 0.02);
        for theta in [-10.0f64, -3.0, 0.0, 4.0, 10.0] {
            let u = DVec2::new(0.0, 1.5 * theta.to_radians().sin());
            let want = shrunk_bragg_wavelength_nm(532.0, 61.2, 0.02, theta);
            let got = g.bragg_wavelength_nm(u).unwrap();
            assert!((got - want).abs() < 1e-9 * want, "{theta}: {got} {want}");
            let bad = wrong.bragg_wavelength_nm(u).unwrap();
            assert!((bad - want).abs() > 1.0, "{theta}: {bad} {want}");
        }
        // s = 0 reduces to docs/physics.md §3.3's λ0 cos(Θ + θ_R/2)/cos(θ_R/2).
        let l = shrunk_bragg_wavelength_nm(532.0, 61.2, 0.0, 5.0);
        let want = 532.0 * (5.0f64 + 30.6).to_radians().cos() / 30.6f64.to_radians().cos();
        assert!((l - want).abs() < 1e-9);
        // The film thinned by s.
        assert!((g.thickness_nm - 16000.0 * 0.98).abs() < 1e-9);
    }

    /// Mean-index change: K fixed, so at normal incidence λ_B = 4π n' K_z/|K|² = λ0 n'/n.
    /// Temperature: n' = n + (dn/dT)ΔT, K_z and d scale by 1 + α_f ΔT, K_t by 1/(1 + α_s ΔT).
    #[test]
    fn index_and_temperature() {
        let (mut h, r) = paper();
        h.mean_index_change = 0.003;
        let g = fabricated_grating(&h, &r);
        let l = g.bragg_wavelength_nm(DVec2::ZERO).unwrap();
        assert!((l - 532.0 * 1.503 / 1.5).abs() < 1e-9, "{l}");
        let (mut h, r) = paper();
        h.temperature_change_k = 20.0;
        let g = fabricated_grating(&h, &r);
        let n = fabricated_grating(&paper().0, &r);
        assert!((g.n_film - (1.5 - 1e-4 * 20.0)).abs() < 1e-15);
        assert!((g.thickness_nm / n.thickness_nm - (1.0 + 1e-4 * 20.0)).abs() < 1e-12);
        assert!((n.k_rad_per_nm.z / g.k_rad_per_nm.z - (1.0 + 1e-4 * 20.0)).abs() < 1e-12);
        assert!((n.k_rad_per_nm.y / g.k_rad_per_nm.y - (1.0 + 9e-6 * 20.0)).abs() < 1e-12);
    }

    /// The equivalent recording of a fabricated grating: for the design it gives back the
    /// recording (1e-12); for a shrunk film, a grating recorded at (λ0', θ') in the same film has
    /// the fabricated grating's K (1e-15 rad/nm) and the closed form's Bragg wavelength
    /// (independent: `shrunk_bragg_wavelength_nm`, 1e-9 relative); the design's recording is
    /// more than 2 nm off there (the check can fail).
    #[test]
    fn equivalent_recording_of_fabricated_films() {
        let (mut h, r) = paper();
        let (l, t) = equivalent_recording(&fabricated_grating(&h, &r)).unwrap();
        assert!(
            (l - 532.0).abs() < 1e-12 && (t - 61.2).abs() < 1e-12,
            "{l} {t}"
        );
        h.shrinkage = 0.02;
        h.mean_index_change = 0.002;
        let g = fabricated_grating(&h, &r);
        let (l, t) = equivalent_recording(&g).unwrap();
        let e = VolumeGrating::from_recording(l, t, g.n_film, 16.0, 0.015, 0.0);
        assert!((e.k_rad_per_nm - g.k_rad_per_nm).length() < 1e-15);
        h.mean_index_change = 0.0;
        let g = fabricated_grating(&h, &r);
        let (l, t) = equivalent_recording(&g).unwrap();
        let design = VolumeGrating::from_recording(532.0, 61.2, 1.5, 16.0, 0.015, 0.0);
        for theta in [-8.0f64, 0.0, 6.0] {
            let u = DVec2::new(0.0, 1.5 * theta.to_radians().sin());
            let want = shrunk_bragg_wavelength_nm(532.0, 61.2, 0.02, theta);
            let e = VolumeGrating::from_recording(l, t, 1.5, 16.0, 0.015, 0.0);
            let got = e.bragg_wavelength_nm(u).unwrap();
            assert!((got - want).abs() < 1e-9 * want, "{theta}: {got} {want}");
            assert!((design.bragg_wavelength_nm(u).unwrap() - want).abs() > 2.0);
        }
        // A grating tilted out of the yz plane has no such recording.
        let mut tilted = g;
        tilted.k_rad_per_nm.x = 1e-3;
        assert!(equivalent_recording(&tilted).is_none());
    }

    /// Shortfall, thickness error and angle error against their definitions.
    #[test]
    fn per_grating_errors() {
        let (mut h, mut r) = paper();
        r.index_modulation_shortfall = 0.2;
        h.thickness_error_um = -1.0;
        r.reference_angle_error_deg = 0.5;
        let g = fabricated_grating(&h, &r);
        assert!((g.n1 - 0.012).abs() < 1e-15);
        assert!((g.thickness_nm - 15000.0).abs() < 1e-9);
        let r = VolumeGrating::from_recording(532.0, 61.7, 1.5, 15.0, 0.012, 0.0);
        assert!((g.k_rad_per_nm - r.k_rad_per_nm).length() < 1e-18);
    }
}
