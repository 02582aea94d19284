//! `validation/analytic`: stscam against closed forms across the whole field (docs/physics.md
//! §0.3, §2, §3.2–3.4, §5): Bragg wavelength, guided angle, replica pitch 2w·tanΘ', replica
//! count (also against bottom-vHOE height), FOV limits, and the replica rows of a rendered
//! point target. Run with `cargo test --release --test analytic_field -- --nocapture` to print
//! the Markdown table.

use stscam::analytic::{self, ClosedForm, quantity};
use stscam::render::{RenderSettings, render};
use stscam::sampler::SamplerKind;
use stscam::scene::load_scene;
use stscam::system::System;

fn system(overrides: &[&str]) -> System {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    System::build(&load_scene(None, &o).expect("scene")).expect("system")
}

#[test]
fn closed_forms_match_the_tracer_over_the_whole_field() {
    let sys = system(&[]);
    let report = analytic::compare(&sys, 60);
    println!("{}", report.to_markdown());
    assert!(report.fields_deg.len() >= 50);
    let field_rows = |q: &str| {
        report
            .rows
            .iter()
            .filter(|r| r.quantity == q && r.section == "field")
            .count()
    };
    for q in [
        quantity::LAMBDA_B,
        quantity::GUIDED,
        quantity::PITCH,
        quantity::COUNT,
    ] {
        assert!(field_rows(q) >= 50, "{q}: {} rows", field_rows(q));
    }
    for s in &report.summary {
        match s.quantity.as_str() {
            quantity::COUNT | quantity::COUNT_H => {
                assert_eq!(s.max_abs_diff, 0.0, "{}: counts differ", s.quantity)
            }
            quantity::FOV_INFO | quantity::LAMBDA_PEAK => {}
            _ => assert!(
                s.max_rel_diff <= 1e-6,
                "{}: max rel diff {:e}",
                s.quantity,
                s.max_rel_diff
            ),
        }
        assert!(s.pass, "{}: {s:?}", s.quantity);
    }
    assert!(report.pass);
    // Serialisable, and the CSV has one line per row.
    let json = serde_json::to_string(&report).unwrap();
    assert!(json.contains("\"rows\""));
    assert_eq!(report.to_csv().lines().count(), report.rows.len() + 1);
}

#[test]
fn a_perturbed_closed_form_fails_the_comparison() {
    // The check has teeth: a 1 % thicker plate in the closed forms (w + 1 %) must fail.
    let sys = system(&[]);
    let mut cf = ClosedForm::from_scene(&sys.scene);
    cf.thickness_mm *= 1.01;
    let report = analytic::compare_with(&sys, &cf, 50);
    assert!(!report.pass);
    let pitch = report
        .summary
        .iter()
        .find(|s| s.quantity == quantity::PITCH)
        .unwrap();
    assert!(!pitch.pass && pitch.max_rel_diff > 5e-3, "{pitch:?}");
    // λ_B does not depend on w: it still agrees.
    let lb = report
        .summary
        .iter()
        .find(|s| s.quantity == quantity::LAMBDA_B)
        .unwrap();
    assert!(lb.pass, "{lb:?}");
    // A 1e-5 change of θ_R moves λ_B by more than the tolerance.
    let mut cf = ClosedForm::from_scene(&sys.scene);
    cf.reference_angle_deg *= 1.0 + 1e-5;
    let report = analytic::compare_with(&sys, &cf, 50);
    let lb = report
        .summary
        .iter()
        .find(|s| s.quantity == quantity::LAMBDA_B)
        .unwrap();
    assert!(!lb.pass && lb.max_rel_diff > 1e-6, "{lb:?}");
}

/// Row centroid of the rendered image (all columns) over rows [lo, hi], with its Monte Carlo
/// standard deviation from the per-pixel variance estimated by two independent renders.
fn centroid(a: &[f32], b: &[f32], w: usize, lo: usize, hi: usize) -> (f64, f64) {
    let (mut s, mut sr) = (0.0, 0.0);
    for r in lo..=hi {
        for c in 0..w {
            let m = 0.5 * (f64::from(a[r * w + c]) + f64::from(b[r * w + c]));
            s += m;
            sr += m * r as f64;
        }
    }
    let cen = sr / s;
    // Var of the mean of two renders: (a − b)²/4 per pixel (unbiased: E(a−b)² = 2σ², /2²·2).
    let mut var = 0.0;
    for r in lo..=hi {
        for c in 0..w {
            let d = f64::from(a[r * w + c]) - f64::from(b[r * w + c]);
            let vm = d * d / 4.0;
            var += (r as f64 - cen).powi(2) * vm;
        }
    }
    (cen, var.sqrt() / s)
}

#[test]
fn rendered_replica_rows_of_a_point_match_the_closed_form() {
    // One lit 0.27 mm LCD pixel (target pixel 32,32 of 64, 1 LCD pixel per target pixel) at
    // the centre of the display, no black level; a 24 x 200 crop around the optical axis.
    let sys = system(&[
        "display.image=point:32,32@64",
        "display.lcd_pixels_per_image_pixel=1",
        "display.black_level=0",
        "sensor.crop_px=[24, 200]",
    ]);
    let cf = ClosedForm::from_scene(&sys.scene);
    // Target pixel (32, 32) spans x ∈ [0, 0.27), y ∈ (−0.27, 0] mm: its centre is y = −0.135.
    let predicted = cf.point_rows(-0.135);
    assert!(predicted.len() >= 5, "{predicted:?}");
    let settings = |seed| RenderSettings {
        spp: 768,
        seed,
        sampler: SamplerKind::Independent,
        user_side: Default::default(),
        spectral_bins: None,
        progress: false,
        estimator: Default::default(),
        adaptive: false,
    };
    let a = render(&sys, &settings(1));
    let b = render(&sys, &settings(2));
    let (w, h) = (a.width, a.height);
    let (ia, ib) = (&a.channels[0], &b.channels[0]);
    let mut checked = 0;
    for (k, &(contact, row)) in predicted.iter().enumerate() {
        // Window: half-way to the neighbouring predicted replicas.
        let prev = if k > 0 { predicted[k - 1].1 } else { row - 8.0 };
        let next = predicted.get(k + 1).map_or(row + 8.0, |p| p.1);
        let lo = (0.5 * (prev + row)).ceil();
        let hi = (0.5 * (row + next)).floor();
        if lo < 0.0 || hi > (h - 1) as f64 {
            continue;
        }
        let (cen, sigma) = centroid(ia, ib, w, lo as usize, hi as usize);
        if sigma.is_nan() || sigma >= 0.2 {
            continue; // a faint replica: too noisy to test
        }
        // Tolerance: 5 σ of Monte Carlo noise plus 0.05 px for what the chief-ray prediction
        // leaves out (the 0.58 px wide object pixel and the aperture blur, both mapped through
        // a slightly non-linear, weight-varying projection: second-order effects).
        let tol = 5.0 * sigma + 0.05;
        println!(
            "contact {contact}: predicted row {row:.4}, rendered centroid {cen:.4} ± {sigma:.4} (|Δ| = {:.4}, tol {tol:.4})",
            (cen - row).abs()
        );
        assert!(
            (cen - row).abs() <= tol,
            "contact {contact}: rendered {cen} vs closed form {row} (σ {sigma})"
        );
        checked += 1;
    }
    assert!(checked >= 3, "only {checked} replicas were bright enough");
}

/// A fabricated film (shrinkage, mean-index change, temperature, a reference-angle error):
/// the closed forms of its equivalent recording match the tracer, which traces the fabricated
/// film; the design's recording (the closed forms as they were before fabrication keys were
/// read) fails on the Bragg wavelength.
#[test]
fn closed_forms_follow_the_fabricated_film() {
    let sys = system(&[
        "hoe.shrinkage=0.02",
        "hoe.mean_index_change=0.002",
        "hoe.temperature_change_k=15",
        "hoe.reference_angle_error_deg=0.3",
    ]);
    let report = analytic::compare(&sys, 50);
    for s in &report.summary {
        assert!(s.pass, "{}: {s:?}", s.quantity);
    }
    assert!(report.pass);
    let mut design = ClosedForm::from_scene(&sys.scene);
    (design.lambda0_nm, design.reference_angle_deg, design.n_film) = (532.0, 61.2, 1.5);
    let r = analytic::compare_with(&sys, &design, 50);
    let lb = r
        .summary
        .iter()
        .find(|s| s.quantity == quantity::LAMBDA_B)
        .unwrap();
    assert!(!lb.pass && lb.max_abs_diff > 1.0, "{lb:?}");
}
