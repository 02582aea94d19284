use super::*;
use crate::grating::VolumeGrating;
use proptest::prelude::*;

/// The paper's film: 532 nm, 61.2°, n = 1.50, 16 µm, n1 as given.
fn paper(n1: f64) -> VolumeGrating {
    VolumeGrating::from_recording(532.0, 61.2, 1.50, 16.0, n1, 0.0)
}

fn film_of(gs: &[VolumeGrating]) -> Film {
    Film {
        mean_index: gs[0].n_film,
        alpha0_per_nm: gs[0].alpha0_per_nm,
        thickness_nm: gs[0].thickness_nm,
        gratings: gs.iter().map(Grating::of).collect(),
    }
}

fn bulk(n: f64) -> Stack {
    Stack { n_in: n, n_out: n }
}

fn eta_of(sol: &Solution, reflected: bool, order: i32) -> [f64; 2] {
    sol.orders
        .iter()
        .find(|o| o.reflected == reflected && o.order == order)
        .map_or([0.0, 0.0], |o| o.eta)
}

/// Airy (thin-film) reflectance of a homogeneous layer n1 of thickness d between n0 and n2,
/// for s and p, at tangential direction cosine u: an independent closed form.
fn airy_reflectance(n0: f64, n1: f64, n2: f64, d_nm: f64, lambda_nm: f64, u: f64) -> [f64; 2] {
    let cz = |n: f64| C::from(n * n - u * u).sqrt();
    let (k0z, k1z, k2z) = (cz(n0), cz(n1), cz(n2));
    let rs = |a: C, b: C| (a - b) / (a + b);
    let rp =
        |na: f64, a: C, nb: f64, b: C| (nb * nb * a - na * na * b) / (nb * nb * a + na * na * b);
    let phase = (C::i() * 2.0 * k1z * 2.0 * PI / lambda_nm * d_nm).exp();
    let total = |r01: C, r12: C| {
        let r = (r01 + r12 * phase) / (1.0 + r01 * r12 * phase);
        r.norm_sqr()
    };
    [
        total(rs(k0z, k1z), rs(k1z, k2z)),
        total(rp(n0, k0z, n1, k1z), rp(n1, k1z, n2, k2z)),
    ]
}

#[test]
fn homogeneous_film_matches_airy_formula_both_polarisations_and_conical() {
    // n1 = 0: a plain layer; glass | layer | air at oblique and conical incidence.
    let mut g = paper(0.0);
    g.thickness_nm = 1234.0;
    let film = Film {
        mean_index: 1.50,
        alpha0_per_nm: 0.0,
        thickness_nm: 1234.0,
        gratings: vec![Grating::of(&g)],
    };
    let stack = Stack {
        n_in: 1.7,
        n_out: 1.0,
    };
    for (ux, uy) in [(0.0, 0.0), (0.0, 0.6), (0.45, 0.3), (-0.2, 0.8)] {
        let u = DVec2::new(ux, uy);
        let sol = solve(&film, &stack, 550.0, u, &Settings::default()).unwrap();
        let want = airy_reflectance(1.7, 1.5, 1.0, 1234.0, 550.0, u.length());
        let got = eta_of(&sol, true, 0);
        for p in 0..2 {
            assert!(
                (got[p] - want[p]).abs() < 1e-10,
                "u={u:?} pol {p}: {got:?} vs {want:?}"
            );
            assert!((sol.total[p] - 1.0).abs() < 1e-10);
        }
    }
    // A wrong reference (the layer's index 1.49 instead of 1.50) is far outside the tolerance.
    let wrong = airy_reflectance(1.7, 1.49, 1.0, 1234.0, 550.0, 0.6);
    let sol = solve(
        &film,
        &stack,
        550.0,
        DVec2::new(0.0, 0.6),
        &Settings::default(),
    )
    .unwrap();
    assert!((eta_of(&sol, true, 0)[0] - wrong[0]).abs() > 1e-4);
}

#[test]
fn kogelnik_agrees_with_rcwa_at_bragg_on_the_paper_film() {
    // Beta-value closure Kogelnik against RCWA in the bulk stack at the exact on-shell Bragg
    // wavelength of normal incidence: within 0.2 % for TE and TM (measured 0.03 % / 0.1 %).
    for n1 in [0.015, 0.03] {
        let g = paper(n1);
        let lam = g.bragg_wavelength_nm(DVec2::ZERO).unwrap();
        let k = g.diffract(DVec2::ZERO, 1.0, lam, 1).unwrap().eta;
        let sol = solve(
            &film_of(&[g]),
            &bulk(1.5),
            lam,
            DVec2::ZERO,
            &Settings::default(),
        )
        .unwrap();
        let r = eta_of(&sol, true, 1);
        for p in 0..2 {
            let rel = (k[p] - r[p]).abs() / r[p];
            assert!(
                rel < 2e-3,
                "n1 {n1} pol {p}: Kogelnik {} RCWA {} ({rel:.2e})",
                k[p],
                r[p]
            );
        }
        // A wrong slant (reference angle off by 1°) fails the same tolerance (TM: TE saturates).
        let wrong = VolumeGrating::from_recording(532.0, 62.2, 1.50, 16.0, n1, 0.0);
        let kw = wrong
            .diffract(DVec2::ZERO, 1.0, lam, 1)
            .map_or(0.0, |d| d.eta[1]);
        assert!(
            (kw - r[1]).abs() / r[1] > 2e-3,
            "wrong slant: {kw} vs {}",
            r[1]
        );
    }
}

#[test]
fn two_half_gratings_equal_one_grating() {
    // Two superposed gratings with the same K and n1/2 each make exactly the permittivity of one
    // grating with n1 (cos + cos = 2 cos), so the RCWA must give the same efficiencies to
    // rounding. Kogelnik applied to each grating on its own (no cross-coupling) would give
    // tanh²(ν/2) per grating instead of tanh²(ν): 0.46 + 0.46 against 0.93 at Bragg; the
    // RCWA's superposition is what a multiplexed film needs.
    let g = paper(0.015);
    let lam = g.bragg_wavelength_nm(DVec2::ZERO).unwrap();
    let one = solve(
        &film_of(&[g]),
        &bulk(1.5),
        lam,
        DVec2::ZERO,
        &Settings::default(),
    )
    .unwrap();
    let h = paper(0.0075);
    let two = solve(
        &film_of(&[h, h]),
        &bulk(1.5),
        lam,
        DVec2::ZERO,
        &Settings::default(),
    )
    .unwrap();
    let (a, b) = (eta_of(&one, true, 1), eta_of(&two, true, 1));
    for p in 0..2 {
        assert!((a[p] - b[p]).abs() < 1e-9, "{a:?} vs {b:?}");
    }
    let half = h.diffract(DVec2::ZERO, 1.0, lam, 1).unwrap().eta[0];
    assert!(
        (a[0] - half).abs() > 0.3,
        "one grating {} vs a half grating {half}",
        a[0]
    );
    // A second half grating of 1 % different slant (K_z) is a different film: the check can
    // fail (and this takes the path with one eigendecomposition per slice).
    let mut d = h;
    d.k_rad_per_nm.z *= 0.99;
    let det = solve(
        &film_of(&[h, d]),
        &bulk(1.5),
        lam,
        DVec2::ZERO,
        &Settings::default(),
    )
    .unwrap();
    assert!((eta_of(&det, true, 1)[0] - a[0]).abs() > 1e-3);
}

#[test]
fn shift_trick_matches_one_eigendecomposition_per_slice() {
    // The doubling of shifted slices against the plain slice-by-slice product on a 3 µm film.
    let mut g = paper(0.03);
    g.thickness_nm = 3000.0;
    let film = film_of(&[g]);
    let lam = 540.0;
    let u = DVec2::new(0.1, -0.2);
    let fast = solve(&film, &bulk(1.5), lam, u, &Settings::default()).unwrap();
    let slow = solve_per_slice(&film, &bulk(1.5), lam, u, &Settings::default()).unwrap();
    assert_eq!(fast.orders.len(), slow.orders.len());
    for (a, b) in fast.orders.iter().zip(&slow.orders) {
        assert_eq!((a.order, a.reflected), (b.order, b.reflected));
        for p in 0..2 {
            assert!((a.eta[p] - b.eta[p]).abs() < 1e-10, "{a:?} vs {b:?}");
        }
    }
}

#[test]
fn truncation_and_slicing_converge_on_the_paper_film() {
    // The defaults against 2x the harmonics and 4x the slices at Bragg and in a sideband.
    let g = paper(0.015);
    let film = film_of(&[g]);
    let lam_b = g.bragg_wavelength_nm(DVec2::ZERO).unwrap();
    for lam in [lam_b, lam_b + 4.0] {
        let base = solve(&film, &bulk(1.5), lam, DVec2::ZERO, &Settings::default()).unwrap();
        let more_h = Settings {
            harmonics: 2 * DEFAULT_HARMONICS,
            ..Settings::default()
        };
        let more_s = Settings {
            slices_per_period: 4 * DEFAULT_SLICES_PER_PERIOD,
            ..Settings::default()
        };
        for s in [more_h, more_s] {
            let fine = solve(&film, &bulk(1.5), lam, DVec2::ZERO, &s).unwrap();
            for p in 0..2 {
                let (a, b) = (eta_of(&base, true, 1)[p], eta_of(&fine, true, 1)[p]);
                assert!((a - b).abs() < 5e-4, "λ {lam} {s:?} pol {p}: {a} vs {b}");
            }
        }
    }
}

#[test]
fn refuses_bad_input() {
    let g = paper(0.015);
    let film = film_of(&[g]);
    let s = Settings::default();
    assert!(matches!(
        solve(&film, &bulk(1.5), 532.0, DVec2::new(1.6, 0.0), &s),
        Err(RcwaError::CannotEnter { .. })
    ));
    let mut rotated = g;
    rotated.k_rad_per_nm.x = 0.3 * rotated.k_rad_per_nm.y;
    assert_eq!(
        solve(&film_of(&[g, rotated]), &bulk(1.5), 532.0, DVec2::ZERO, &s),
        Err(RcwaError::NotParallel(2))
    );
    let mut odd = g;
    odd.k_rad_per_nm.y *= std::f64::consts::SQRT_2;
    assert_eq!(
        solve(&film_of(&[g, odd]), &bulk(1.5), 532.0, DVec2::ZERO, &s),
        Err(RcwaError::Incommensurate(2))
    );
    assert!(solve(&film, &bulk(1.5), -1.0, DVec2::ZERO, &s).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, .. ProptestConfig::default() })]
    /// Lossless films conserve energy (Σ R + Σ T = 1) for any direction and wavelength, in
    /// both stacks, for one and two gratings.
    #[test]
    fn lossless_films_conserve_energy(
        ux in -0.9f64..0.9, uy in -0.9f64..0.9, lam in 420.0f64..700.0,
        contact in any::<bool>(), two in any::<bool>(), n1 in 0.0f64..0.05,
    ) {
        let mut g = VolumeGrating::from_recording(532.0, 61.2, 1.50, 4.0, n1, 0.0);
        let mut gs = vec![g];
        if two {
            g = VolumeGrating::from_recording(532.0, 61.2, 1.50, 4.0, 0.5 * n1, 0.0);
            g.k_rad_per_nm.z *= 0.9;
            gs.push(g);
        }
        let stack = if contact { Stack { n_in: 1.52, n_out: 1.0 } } else { bulk(1.5) };
        let settings = Settings { harmonics: 4, slices_per_period: 16 };
        let sol = solve(&film_of(&gs), &stack, lam, DVec2::new(ux, uy), &settings).unwrap();
        for p in 0..2 {
            prop_assert!((sol.total[p] - 1.0).abs() < 1e-9, "{:?}", sol.total);
        }
        for o in &sol.orders {
            prop_assert!(o.eta[0] >= -1e-12 && o.eta[1] >= -1e-12);
            prop_assert!((o.direction.length() - 1.0).abs() < 1e-12);
            prop_assert!((o.direction.z < 0.0) == o.reflected);
        }
    }
}

#[test]
fn absorbing_film_loses_energy() {
    // α0 = 1/mm over 16 µm at normal incidence: Σ η ≈ exp(−2 α0 d) away from Bragg.
    let g = VolumeGrating::from_recording(532.0, 61.2, 1.50, 16.0, 0.015, 1.0);
    let sol = solve(
        &film_of(&[g]),
        &bulk(1.5),
        600.0,
        DVec2::ZERO,
        &Settings::default(),
    )
    .unwrap();
    let want = (-2.0 * 1e-3 * 16.0f64).exp();
    assert!(
        (sol.total[0] - want).abs() < 1e-3,
        "{:?} vs {want}",
        sol.total
    );
}
