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
    assert!(
        (m - 1.0).abs() < 4.0 * s + 1e-12,
        "furnace frontal mean {m} ± {s}"
    );
    assert!(s < 0.01, "standard error {s}");
    // Background pixels see the environment directly: exactly 1 up to the spectral estimate.
    let (m9, s9, _) = check("grey.csv");
    assert!(
        (m9 - 1.0).abs() > 10.0 * s9,
        "a 0.9 albedo must fail: {m9} ± {s9}"
    );
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
    assert!(
        mean_b > 1e-3,
        "the environment is seen through the waveguide: {mean_b}"
    );
    assert!(
        md.abs() < 4.0 * sd + 1e-9 * mean_b,
        "furnace vs empty: {md} ± {sd} (mean {mean_b})"
    );
    assert!(sd < 0.01 * mean_b, "noise {sd} vs level {mean_b}");
}

/// An emissive quad carrying the display's target, with the display's spectrum, at the
/// display's distance and size, gives the display's capture. The camera samples are the same
/// (same seed); the only randomness left is the Russian roulette over weak replica branches
/// (unbiased), so the per-pixel difference has zero mean: the rule is |mean difference| < 4
/// standard errors (measured per pixel), and the relative RMSE stays below 10 %. A quad whose
/// emission is 3 % too weak, or 5 % too small, must fail the mean rule.
#[test]
fn emissive_quad_matches_the_display() {
    let dir = tempfile::tempdir().unwrap();
    // The target as a PNG: the built-in letter F (binary, so sRGB and gamma 2.2 agree).
    let t = stscam::targets::builtin_target("letter:F").unwrap();
    let codes: Vec<u16> = t
        .values
        .iter()
        .map(|v| (v * 65535.0).round() as u16)
        .collect();
    assert!(t.values.iter().all(|v| *v == 0.0 || *v == 1.0));
    let png = stscam::io::encode_png16(t.width, t.height, 1, &codes, stscam::io::PngTransfer::Srgb)
        .unwrap();
    std::fs::write(dir.path().join("target.png"), png).unwrap();
    let size = t.width as f64 * 0.27 * 10.0;
    let sets = [
        SMALL[0],
        SMALL[1],
        "display.black_level=0",
        "display.image=\"letter:F\"",
    ];
    let display = system(dir.path(), "", &sets);
    let quad = |s: f64, emission: f64| {
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
emission_scale = {emission}
emission_texture = "target.png"
texture_filter = "nearest"
"#
        )
    };
    let set = RenderSettings::lattice(16, 2, false);
    let a = render(&display, &set);
    let compare = |s: f64, e: f64| {
        let b = render(&system(dir.path(), &quad(s, e), &sets), &set);
        let d: Vec<f64> = b.channels[0]
            .iter()
            .zip(&a.channels[0])
            .map(|(x, y)| f64::from(*x) - f64::from(*y))
            .collect();
        let level = a.channels[0].iter().map(|v| f64::from(*v)).sum::<f64>() / d.len() as f64;
        let (m, sem) = mean_sem(&d);
        let rmse =
            stscam::render::relative_rmse(&[(b.channels[0].as_slice(), a.channels[0].as_slice())]);
        (m / level, sem / level, rmse)
    };
    let (m, sem, rmse) = compare(size, 1.0);
    eprintln!(
        "quad vs display: mean difference {m:.2e} ± {sem:.2e} of the level, relative RMSE {rmse:.3}"
    );
    assert!(m.abs() < 4.0 * sem, "quad vs display: {m} ± {sem}");
    assert!(rmse < 0.1, "relative RMSE {rmse}");
    let (m, sem, _) = compare(size, 0.97);
    assert!(
        m.abs() > 4.0 * sem,
        "3 % weaker emission must fail: {m} ± {sem}"
    );
    let (m, sem, _) = compare(size * 0.95, 1.0);
    assert!(
        m.abs() > 4.0 * sem,
        "a 5 % smaller quad must fail: {m} ± {sem}"
    );
}

/// The display as a light: an all-white LCD lights a sphere just in front of it exactly as a
/// rect light of the same size, place, spectrum and radiance does (the two are sampled by
/// different strategies: the display by its mixture of uniform and target-proportional points,
/// the rect as a spherical rectangle). Frontal renders of the two scenes agree on the sphere:
/// the mean of the per-pixel differences is within 4 of its standard errors (the noise, as
/// measured by the spread of those differences); a rect 10 % too bright fails the rule (its
/// mean difference judged against the same noise: its own spread would also count 10 % of
/// the sphere's shading across pixels, which is signal, not noise).
#[test]
fn display_lights_the_scene_like_an_equal_rect_light() {
    let dir = tempfile::tempdir().unwrap();
    let sphere = "[[object]]\nmesh = \"sphere\"\nposition_mm = [0.0, 0.0, -505.0]\nscale = 80.0\n";
    let lcd = format!(
        "[display]\nsize_px = [640, 640]\nimage = \"white\"\nspectrum = \"white-led\"\n{sphere}"
    );
    let rect = |scale: f64| {
        format!(
            "[display]\nenabled = false\n{sphere}[[light]]\nkind = \"rect\"\nposition_mm = [0.0, 0.0, -550.0]\nsize_mm = [172.8, 172.8]\nnormal = [0.0, 0.0, 1.0]\nspectrum = \"white-led\"\nscale = {scale}\n"
        )
    };
    let frontal = |toml: &str| {
        let sys = system(dir.path(), toml, &SMALL);
        render_frontal(&sys, 40, 40, 64, 9).unwrap()
    };
    let a = frontal(&lcd);
    let on_sphere = |f: &stscam::world::frontal::Frontal,
                     g: &stscam::world::frontal::Frontal|
     -> (f64, f64, f64) {
        let d: Vec<f64> = (0..f.mask.len())
            .filter(|&i| f.mask[i] == 1)
            .map(|i| f64::from(f.channels[0][i]) - f64::from(g.channels[0][i]))
            .collect();
        let mean_a = (0..f.mask.len())
            .filter(|&i| f.mask[i] == 1)
            .map(|i| f64::from(g.channels[0][i]))
            .sum::<f64>()
            / d.len() as f64;
        let (m, s) = mean_sem(&d);
        (m, s, mean_a)
    };
    let b = frontal(&rect(1.0));
    let sphere_px =
        |f: &stscam::world::frontal::Frontal| f.mask.iter().map(|m| *m == 1).collect::<Vec<_>>();
    assert_eq!(sphere_px(&a), sphere_px(&b));
    let (m, s, level) = on_sphere(&b, &a);
    assert!(level > 1e-3, "the sphere is lit: {level}");
    assert!(
        m.abs() < 4.0 * s,
        "rect - display on the sphere: {m} ± {s} (level {level})"
    );
    // The emitters seen directly agree exactly in expectation too (background pixels).
    let c = frontal(&rect(1.1));
    let (m2, _, _) = on_sphere(&c, &a);
    assert!(m2 > 4.0 * s, "a 10 % brighter rect must fail: {m2} ± {s}");
}

/// The shipped eye-contact scene at the SMALL crop.
fn eye_contact_small() -> System {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/eye-contact.toml");
    let sets: Vec<String> = SMALL.iter().map(|s| s.to_string()).collect();
    System::build(&load_scene(Some(&scene), &sets).unwrap()).unwrap()
}

/// A 64-spp render's pixel values and its user-side rays.
fn render_64(
    sys: &System,
    seed: u64,
    user_side: stscam::render::UserSideSampler,
) -> (Vec<f64>, f64) {
    let mut set = RenderSettings::lattice(64, seed, false);
    set.user_side = user_side;
    let cap = render(sys, &set);
    let v = cap
        .channels
        .iter()
        .flatten()
        .map(|v| f64::from(*v))
        .collect::<Vec<f64>>();
    (v, cap.stats.scene_rays as f64)
}

/// Asserts that `a` has the expectation of `b` (independent renders): the mean per-pixel
/// difference within 4 standard errors of zero, relative to b's level; and that `a` made 3 %
/// too bright fails the same rule.
fn assert_same_expectation(a: &[f64], b: &[f64], what: &str) {
    let level = b.iter().sum::<f64>() / b.len() as f64;
    assert!(level > 0.0);
    let bias = |scale: f64| {
        let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| scale * x - y).collect();
        let (m, sem) = mean_sem(&d);
        (m / level, sem / level)
    };
    let (m, sem) = bias(1.0);
    eprintln!("{what}: mean {m:.2e} ± {sem:.2e} of the level");
    assert!(m.abs() < 4.0 * sem, "{what}: {m} ± {sem}");
    let (m3, sem3) = bias(1.03);
    assert!(
        m3.abs() > 4.0 * sem3,
        "{what}, 3 % too bright must fail: {m3} ± {sem3}"
    );
}

/// ‖a − b‖/‖a + b‖ of two independent renders.
fn halves_error(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    let den: f64 = a.iter().zip(b).map(|(x, y)| (x + y) * (x + y)).sum();
    (num / den).sqrt()
}

/// The padded user side (each light's sample and the BSDF direction of the first vertex, and
/// the branch roulette's decision, stratified over a pixel's samples) against independent
/// hashed numbers (`--sampler independent`, which hashes the camera side's numbers too), on
/// the shipped eye-contact scene (40 × 40 crop, 64 spp):
/// - unbiased: per pixel, padded (seed 1) minus hashed (seed 2) has zero mean, |mean| < 4
///   standard errors (measured over the pixels); a padded render 3 % too bright fails the rule;
/// - less noisy: the relative RMS difference of two independent padded renders (seeds 3, 4)
///   is at most 0.85 of that of two hashed renders.
#[test]
fn padded_user_side_is_unbiased_and_less_noisy() {
    use stscam::render::UserSideSampler::Padded;
    use stscam::sampler::SamplerKind::{Independent, Lattice};
    let sys = eye_contact_small();
    let run = |seed, sampler| {
        let mut set = RenderSettings::lattice(64, seed, false);
        set.user_side = Padded;
        set.sampler = sampler;
        let cap = render(&sys, &set);
        cap.channels
            .iter()
            .flatten()
            .map(|v| f64::from(*v))
            .collect::<Vec<f64>>()
    };
    assert_same_expectation(&run(1, Lattice), &run(2, Independent), "padded - hashed");
    let padded = halves_error(&run(3, Lattice), &run(4, Lattice));
    let hashed = halves_error(&run(3, Independent), &run(4, Independent));
    eprintln!("halves error: padded {padded:.4}, hashed {hashed:.4}");
    assert!(padded < 0.85 * hashed, "padded {padded} hashed {hashed}");
}

/// The resampled user side (the default: a pixel's branches share about one user-side path
/// per camera sample, drawn per replica in proportion to their weight) has the expectation of
/// the every-branch estimator, and reaches a given error with far fewer user-side rays.
#[test]
fn resampled_user_side_is_unbiased_and_cheaper() {
    use stscam::render::UserSideSampler::{self, Padded, Resampled};
    let sys = eye_contact_small();
    // The scene has no emissive mesh: the default resolves to the resampled user side.
    assert_eq!(
        UserSideSampler::default().resolve(sys.world.as_deref()),
        Resampled
    );
    let ((r1, rays_r), (p2, rays_p)) = (render_64(&sys, 1, Resampled), render_64(&sys, 2, Padded));
    assert_same_expectation(&r1, &p2, "resampled - padded");
    // Error of two independent renders, and its square times the user-side rays (the cost
    // that dominates; counted, so the rule does not depend on the machine).
    let run = |seed, user_side| render_64(&sys, seed, user_side).0;
    let resampled = halves_error(&run(3, Resampled), &run(4, Resampled));
    let padded = halves_error(&run(3, Padded), &run(4, Padded));
    let (cost_r, cost_p) = (resampled * resampled * rays_r, padded * padded * rays_p);
    eprintln!(
        "halves error: resampled {resampled:.4} ({rays_r} rays), padded {padded:.4} ({rays_p} rays); error² × rays {cost_r:.3e} vs {cost_p:.3e}"
    );
    assert!(
        cost_r < 0.3 * cost_p,
        "resampled {cost_r:.3e} padded {cost_p:.3e}"
    );
}
