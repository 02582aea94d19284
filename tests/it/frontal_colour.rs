//! The frontal ground truth in a standard colour space (`render --frontal-space`): CIE 1931
//! XYZ with Y = 1 for a flat radiance at display white, and linear sRGB (Rec. 709, D65).
//! Expected values come from published constants (the D65 white point, the CIE 1931 2° table
//! at 600 nm), not from the code's output.

use std::path::Path;

use stscam::scene::load_scene;
use stscam::system::System;
use stscam::world::colour::FrontalSpace;
use stscam::world::frontal::{Frontal, render_frontal_in};

/// Frontal image of a scene with a white (reflectance 1) box in a uniform environment of
/// spectrum `env` (a name or a CSV path), 24×24 px at 64 spp.
fn render(dir: &Path, env: &str, space: FrontalSpace) -> Frontal {
    let csv = dir.join("white.csv");
    std::fs::write(&csv, "nm,value\n300,1\n900,1\n").unwrap();
    let toml = format!(
        r#"
[display]
enabled = false
[sampling]
max_depth = 64
[[object]]
mesh = "box"
scale = 300.0
position_mm = [0.0, 0.0, -600.0]
[object.material]
reflectance = "{}"
[[light]]
kind = "environment"
spectrum = "{}"
scale = 1.0
"#,
        csv.display(),
        env
    );
    let p = dir.join("scene.toml");
    std::fs::write(&p, toml).unwrap();
    let sets = ["sensor.crop_px=[24,24]".to_string()];
    let ls = load_scene(Some(&p), &sets).unwrap();
    let sys = System::build(&ls).unwrap();
    render_frontal_in(&sys, 24, 24, 64, 5, space).unwrap()
}

/// Mean of each channel over the image.
fn means(f: &Frontal) -> Vec<f64> {
    f.channels
        .iter()
        .map(|c| c.iter().map(|v| f64::from(*v)).sum::<f64>() / c.len() as f64)
        .collect()
}

/// (x, y) chromaticity.
fn xy(v: &[f64]) -> (f64, f64) {
    let s = v[0] + v[1] + v[2];
    (v[0] / s, v[1] / s)
}

#[test]
fn d65_white_reads_the_d65_white_point_and_equal_srgb() {
    let dir = tempfile::tempdir().unwrap();
    // A white surface in a D65 furnace returns D65 on every pixel (surface and background).
    let f = render(dir.path(), "d65", FrontalSpace::Xyz);
    assert_eq!(f.channel_names, ["X", "Y", "Z"]);
    assert_eq!(f.space, FrontalSpace::Xyz);
    let xyz = means(&f);
    // D65 (CIE 015): x = 0.31272, y = 0.32903. Tolerance 2e-3: the 380–780 nm band, the 5 nm
    // tables and the wavelength sampling noise.
    let (x, y) = xy(&xyz);
    assert!(
        (x - 0.31272).abs() < 2e-3 && (y - 0.32903).abs() < 2e-3,
        "x {x}, y {y}"
    );
    // D65 normalised to mean 1 over 380–780 nm has Y = ∫D65·ȳ/∫ȳ / mean(D65) = 1.129 (sums
    // of the CIE 5 nm D65 and ȳ tables over 380–780 nm); tolerance 1.5 % (sums vs the
    // interpolants' integrals, noise).
    assert!((xyz[1] / 1.1294 - 1.0).abs() < 0.015, "Y {}", xyz[1]);
    let g = render(dir.path(), "d65", FrontalSpace::LinearSrgb);
    assert_eq!(g.channel_names, ["R", "G", "B"]);
    let rgb = means(&g);
    for c in &rgb {
        assert!((c / rgb[1] - 1.0).abs() < 0.01, "linear sRGB {rgb:?}");
    }
    // Same wavelengths for both spaces: sRGB = M·XYZ pixel by pixel (f32 rounding).
    let m = stscam::world::colour::XYZ_TO_LINEAR_SRGB;
    for i in 0..f.channels[0].len() {
        let v = [0, 1, 2].map(|k| f64::from(f.channels[k][i]));
        let r = stscam::world::colour::mat3(&m, v);
        for (rk, gk) in r.iter().zip(&g.channels) {
            assert!((rk - f64::from(gk[i])).abs() < 1e-5 * (1.0 + rk.abs()));
        }
    }
    // A deliberately wrong illuminant (3500 K blackbody, x ≈ 0.405) fails the white point.
    let warm = means(&render(dir.path(), "blackbody:3500", FrontalSpace::Xyz));
    let (xw, _) = xy(&warm);
    assert!((xw - 0.31272).abs() > 0.05, "x {xw}");
}

#[test]
fn narrow_band_emitter_reads_the_cmfs_at_600_nm() {
    let dir = tempfile::tempdir().unwrap();
    // An environment emitting only around 600 nm (a 2 nm wide triangle), every pixel.
    let bump = dir.path().join("bump.csv");
    std::fs::write(&bump, "nm,value\n300,0\n599,0\n600,1\n601,0\n900,0\n").unwrap();
    let f = render(dir.path(), bump.to_str().unwrap(), FrontalSpace::Xyz);
    let v = means(&f);
    // CIE 1931 2° at 600 nm (CIE 015:2018): x̄ = 1.0622, ȳ = 0.6310, z̄ = 0.0008.
    let cie = [1.0622, 0.631, 0.0008];
    // Emission spectra have mean 1 over 380–780 nm, so the bump's area is 400 nm and
    // Y = 400·ȳ(600)/∫ȳ with ∫ȳ over 380–780 nm = 106.86 nm (Σ of the CIE 5 nm table × 5).
    let check = |v: &[f64]| {
        let ratio_ok = (v[0] / v[1] - cie[0] / cie[1]).abs() < 0.01 * cie[0] / cie[1];
        let z_ok = (v[2] / v[1] - cie[2] / cie[1]).abs() < 1e-3;
        let y_ok = (v[1] - 400.0 * cie[1] / 106.86).abs() < 0.03 * 400.0 * cie[1] / 106.86;
        ratio_ok && z_ok && y_ok
    };
    assert!(check(&v), "XYZ {v:?}");
    // Channel order X, Y, Z: the reversed order fails the same check.
    let reversed = [v[2], v[1], v[0]];
    assert!(!check(&reversed));
}
