//! Physics of the user-side path tracer, end to end through the waveguide and through the
//! frontal pinhole: the white furnace and an emissive quad standing in for the display.

use std::path::Path;

use stscam::render::{RenderSettings, render};
use stscam::scene::load_scene;
use stscam::system::System;
use stscam::world::frontal::render_frontal;

fn system(dir: &Path, toml: &str, sets: &[&str]) -> System {
    let p = dir.join("scene.toml");
    std::fs::write(&p, toml).unwrap();
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let ls = load_scene(Some(&p), &sets).unwrap();
    System::build(&ls).unwrap()
}

/// A small crop with the paper's field of view (pitch scaled).
const SMALL: [&str; 2] = ["sensor.crop_px=[40,40]", "sensor.pitch_um=52.8"];

/// Mean and standard error of the mean.
fn mean_sem(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

const FURNACE: &str = r#"
[display]
enabled = false
[sampling]
max_depth = 64
[[object]]
mesh = "head"
position_mm = [0.0, -12.0, -400.0]
[object.material]
reflectance = "white.csv"
[[light]]
kind = "environment"
spectrum = "flat"
scale = 1.0
"#;

/// White furnace: a Lambertian head of albedo 1 (concave: eye sockets, nose, ears) inside a
/// uniform environment of radiance 1 reflects exactly the environment's radiance, so every
/// frontal pixel on the head reads 1 (sensor-weighted radiance of a flat spectrum of mean 1),
/// within Monte Carlo noise; and the capture through the waveguide equals the capture of the
/// empty environment. Tolerance: 4 standard errors of the mean over the object pixels (the
/// spread of per-pixel values is measured, not assumed). A deliberately wrong albedo (0.9)
/// must fail the same rule.
#[test]
fn white_furnace_renders_the_environment() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("white.csv"), "nm,value\n300,1\n900,1\n").unwrap();
    std::fs::write(dir.path().join("grey.csv"), "nm,value\n300,0.9\n900,0.9\n").unwrap();
    let check = |csv: &str| -> (f64, f64, usize) {
        let sys = system(dir.path(), &FURNACE.replace("white.csv", csv), &SMALL);
        let f = render_frontal(&sys, 40, 40, 16, 3).unwrap();
        let vals: Vec<f64> = f.channels[0]
            .iter()
            .zip(&f.mask)
            .filter(|(_, m)| **m == 1)
            .map(|(v, _)| f64::from(*v))
            .collect();
        assert!(f.channels[0].iter().all(|v| v.is_finite()));
        let (m, s) = mean_sem(&vals);
        (m, s, vals.len())
    };
    let (m, s, n) = check("white.csv");
    assert!(n > 300, "the head covers {n} frontal pixels");
    assert!((m - 1.0).abs() < 4.0 * s + 1e-12, "furnace frontal mean {m} ± {s}");
    assert!(s < 0.01, "standard error {s}");
    // Background pixels see the environment directly: exactly 1 up to the spectral estimate.
    let (m9, s9, _) = check("grey.csv");
    assert!((m9 - 1.0).abs() > 10.0 * s9, "a 0.9 albedo must fail: {m9} ± {s9}");
    assert!(m9 < 0.99);

    // Through the waveguide: capture of the furnace = capture of the empty environment.
    let sys = system(dir.path(), FURNACE, &SMALL);
    let empty = system(
        dir.path(),
        "[display]\nenabled = false\n[[light]]\nkind = \"environment\"\nspectrum = \"flat\"\n",
        &SMALL,
    );
    let set = RenderSettings::lattice(32, 5, false);
    let a = render(&sys, &set);
    let b = render(&empty, &set);
    let diffs: Vec<f64> = a.channels[0]
        .iter()
        .zip(&b.channels[0])
        .map(|(x, y)| f64::from(*x) - f64::from(*y))
        .collect();
    let (md, sd) = mean_sem(&diffs);
    let mean_b = b.channels[0].iter().map(|v| f64::from(*v)).sum::<f64>() / diffs.len() as f64;
    assert!(mean_b > 1e-3, "the environment is seen through the waveguide: {mean_b}");
    assert!(md.abs() < 4.0 * sd + 1e-9 * mean_b, "furnace vs empty: {md} ± {sd} (mean {mean_b})");
    assert!(sd < 0.01 * mean_b, "noise {sd} vs level {mean_b}");
}

/// An emissive quad carrying the display's target, with the display's spectrum, at the
/// display's distance and size, gives the display's capture: the primary hit is deterministic,
/// so the two captures agree to float rounding except where a lens sample lands within
/// rounding of a target-pixel edge. Tolerance: relative RMSE < 1e-3 (measured ~1e-6); a quad
/// 1 % too small must fail it.
#[test]
fn emissive_quad_matches_the_display() {
    let dir = tempfile::tempdir().unwrap();
    // The target as a PNG: the built-in letter F (binary, so sRGB and gamma 2.2 agree).
    let t = stscam::targets::builtin_target("letter:F").unwrap();
    let codes: Vec<u16> = t.values.iter().map(|v| (v * 65535.0).round() as u16).collect();
    assert!(t.values.iter().all(|v| *v == 0.0 || *v == 1.0));
    let png = stscam::io::encode_png16(t.width, t.height, 1, &codes).unwrap();
    std::fs::write(dir.path().join("target.png"), png).unwrap();
    let size = t.width as f64 * 0.27 * 10.0;
    let sets = [SMALL[0], SMALL[1], "display.black_level=0", "display.image=\"letter:F\""];
    let display = system(dir.path(), "", &sets);
    let quad = |s: f64| {
        format!(
            r#"
[display]
enabled = false
[[object]]
mesh = "quad"
position_mm = [0.0, 0.0, -550.0]
scale = [{s}, {s}, 1.0]
[object.material]
emission = "white-led"
emission_texture = "target.png"
texture_filter = "nearest"
"#
        )
    };
    let set = RenderSettings::lattice(8, 2, false);
    let a = render(&display, &set);
    let b = render(&system(dir.path(), &quad(size), &sets), &set);
    let pairs = [(b.channels[0].as_slice(), a.channels[0].as_slice())];
    let e = stscam::render::relative_rmse(&pairs);
    assert!(e < 1e-3, "quad vs display relative RMSE {e}");
    let c = render(&system(dir.path(), &quad(size * 0.99), &sets), &set);
    let e_wrong = stscam::render::relative_rmse(&[(c.channels[0].as_slice(), a.channels[0].as_slice())]);
    assert!(e_wrong > 1e-2, "a 1 % smaller quad must fail: {e_wrong}");
}
