//! Physical invariants over random inputs: the periscope property of the two vHOEs, energy
//! conservation of every path (no branch weight above 1, branch weights summing to at most 1),
//! finiteness, and on-shell diffraction.

use glam::{DVec2, DVec3};
use proptest::prelude::*;
use stscam::optics::grating::VolumeGrating;
use stscam::optics::interface::direction;
use stscam::scene::load_scene;
use stscam::system::build_waveguide;
use stscam::trace::{TraceLimits, trace_camera_path};

fn grating(n_film: f64, n1: f64, thickness_um: f64) -> VolumeGrating {
    VolumeGrating::from_recording(532.0, 61.2, n_film, thickness_um, n1, 0.0)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// A ray entering the bottom vHOE and leaving the top vHOE comes out parallel to itself
    /// (docs/physics.md §0.3), for any incidence direction and wavelength that couples: forward
    /// physical trace in full 3-D wave vectors.
    #[test]
    fn periscope(theta_deg in 0.0f64..40.0, phi in 0.0f64..std::f64::consts::TAU, lambda in 360.0f64..830.0,
                 n_glass in 1.3f64..2.0, n_film in 1.3f64..2.0) {
        let g = grating(n_film, 0.02, 16.0);
        let t = theta_deg.to_radians();
        let s_in = DVec3::new(t.sin() * phi.cos(), t.sin() * phi.sin(), t.cos()); // in air, toward +z
        let u = s_in.truncate();
        // In-coupling at the bottom vHOE (order +1, reflection back toward the front face).
        let Some(inc) = g.diffract(u, 1.0, lambda, 1) else { return Ok(()); };
        prop_assume!(inc.reflection && inc.u.length() < n_glass);
        // The guided wave in the glass; TIR flips only its z component, u is unchanged.
        let k = 2.0 * std::f64::consts::PI / lambda;
        let kg = direction(inc.u, n_glass, -1.0) * (k * n_glass);
        prop_assert!((kg.length() - k * n_glass).abs() < 1e-9 * k);
        // Out-coupling at the top vHOE: the guided wave arrives travelling −z.
        let out = g.diffract(inc.u, -1.0, lambda, -1);
        prop_assert!(out.is_some());
        let out = out.unwrap();
        prop_assert!(out.reflection && out.z_sign > 0.0);
        let s_out = direction(out.u, 1.0, 1.0);
        prop_assert!((s_out - s_in).length() < 1e-12, "in {s_in} out {s_out}");
        // Efficiencies are the same both ways in a lossless film (reciprocity).
        for p in 0..2 {
            prop_assert!((inc.eta[p] - out.eta[p]).abs() < 1e-12);
        }
    }

    /// Every path's branch weights are finite, in [0, 1], and sum to at most 1, over random
    /// designs, directions and wavelengths.
    #[test]
    fn path_energy_is_conserved(
        thickness in 0.05f64..20.0, n_glass in 1.3f64..2.0, n_film in 1.3f64..2.0, n1 in 1e-6f64..0.1,
        film_um in 1.0f64..200.0, lambda in 360.0f64..830.0, theta_deg in 0.0f64..89.9, phi in 0.0f64..std::f64::consts::TAU,
        covered in any::<bool>(), alpha0 in prop_oneof![Just(0.0), 0.0f64..5.0],
        bottom_h in 0.1f64..80.0, top_h in 0.1f64..40.0,
    ) {
        let sets = vec![
            format!("plate.thickness_mm={thickness}"),
            format!("plate.glass={n_glass}"),
            format!("hoe.mean_index={n_film}"),
            format!("hoe.index_modulation={n1}"),
            format!("hoe.film_thickness_um={film_um}"),
            format!("hoe.amplitude_absorption_per_mm={alpha0}"),
            format!("top_hoe.covered={covered}"),
            format!("bottom_hoe.height_mm={bottom_h}"),
            format!("top_hoe.height_mm={top_h}"),
        ];
        let ls = load_scene(None, &sets).unwrap();
        let wg = build_waveguide(&ls.scene);
        let t = theta_deg.to_radians();
        let dir = DVec3::new(t.sin() * phi.cos(), t.sin() * phi.sin(), -t.cos());
        let origin = DVec3::new(0.0, wg.top.center().y, thickness + 30.0) - dir * 0.0;
        let limits = TraceLimits { min_weight: 1e-9, max_contacts: 200_000 };
        let mut total = [0.0f64; 2];
        let mut ok = true;
        let summary = trace_camera_path(&wg, -550.0, limits, origin, dir, lambda, |b| {
            for (t, w) in total.iter_mut().zip(b.weight) {
                ok &= w.is_finite() && (0.0..=1.0).contains(&w);
                *t += w;
            }
            ok &= b.object_point_mm.is_finite();
        });
        prop_assert!(ok);
        prop_assert!(total[0] <= 1.0 + 1e-12 && total[1] <= 1.0 + 1e-12, "{total:?}");
        prop_assert!(summary.truncated_weight.is_finite() && summary.truncated_weight <= 1.0);
    }

    /// Diffracted orders are on-shell: |k_d| = β, tangential k shifted by exactly m·K_t.
    #[test]
    fn diffraction_is_on_shell(ux in -1.2f64..1.2, uy in -1.2f64..1.2, lambda in 360.0f64..830.0,
                               order in prop_oneof![Just(1), Just(-1)], zs in prop_oneof![Just(1.0), Just(-1.0)]) {
        let g = grating(1.5, 0.02, 16.0);
        let u = DVec2::new(ux, uy);
        if let Some(d) = g.diffract(u, zs, lambda, order) {
            prop_assert!(d.u.length() < 1.5);
            let expect = u - f64::from(order) * g.u_shift(lambda);
            prop_assert!((d.u - expect).length() < 1e-12);
            for p in 0..2 {
                prop_assert!(d.eta[p].is_finite() && (0.0..=1.0).contains(&d.eta[p]));
            }
        }
    }
}
