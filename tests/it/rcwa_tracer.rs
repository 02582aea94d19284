//! `hoe.model = "rcwa"` in the tracer: the matrix–render contract holds with the tables, the
//! capture moves from Kogelnik's by the measured model difference (and by much more with the
//! tables of another film), the cache is reused byte for byte, and films RCWA cannot take are
//! refused naming the key.

use std::process::Command;
use std::sync::Arc;

use stscam::matrix::compute_matrix;
use stscam::optics::multiplex::GratingSet;
use stscam::optics::rcwa::Settings;
use stscam::optics::rcwa::coupling::RcwaCouplings;
use stscam::render::{RenderSettings, render};
use stscam::sampler::SamplerKind;
use stscam::scene::load_scene;
use stscam::system::{System, rcwa_grid};

fn system(sets: &[&str]) -> System {
    let mut all = vec!["sensor.crop_px=[40,40]".to_string()];
    all.extend(sets.iter().map(|s| s.to_string()));
    System::build(&load_scene(None, &all).expect("scene")).expect("system")
}

fn settings() -> RenderSettings {
    RenderSettings {
        spp: 4,
        seed: 3,
        sampler: SamplerKind::Lattice,
        user_side: Default::default(),
        spectral_bins: None,
        progress: false,
        estimator: Default::default(),
        adaptive: false,
    }
}

/// The same system with RCWA tables of `set` attached (built here, no cache; the wavelength
/// sampler stays Kogelnik's, so both models see the same samples and only the model differs).
fn with_tables(sys: &System, set: &GratingSet) -> System {
    let mut r = sys.clone();
    let t = RcwaCouplings::build(
        set,
        &rcwa_grid(&sys.camera),
        &Settings::default(),
        20,
        &Default::default(),
    )
    .expect("tables");
    assert!(
        t.max_error() < 5e-3,
        "interpolation error {} per quantity {:?}",
        t.max_error(),
        t.measure_errors(20, 1)
    );
    r.waveguide.rcwa = Some(Arc::new(t));
    r
}

fn total(c: &stscam::render::Capture) -> f64 {
    c.channels[0].iter().map(|&v| f64::from(v)).sum()
}

#[test]
fn rcwa_tables_keep_the_matrix_contract_and_move_the_capture_by_the_model_difference() {
    let kog = system(&["display.image=letter:F@16"]);
    let rc = with_tables(&kog, &kog.waveguide.gratings);
    let set = settings();
    let (ck, cr) = (render(&kog, &set), render(&rc, &set));
    // H·f + offset = render(f) with the tables (f32 storage: a few ulps).
    let m = compute_matrix(&rc, &set);
    let pred = &m.capture_of(&rc.display.intensity)[0];
    let peak = cr.channels[0].iter().fold(0.0f32, |a, &b| a.max(b)) as f64;
    let err = pred
        .iter()
        .zip(&cr.channels[0])
        .map(|(p, &r)| (p - f64::from(r)).abs())
        .fold(0.0, f64::max)
        / peak;
    assert!(err < 1e-6, "H f + o vs render: {err:e}");
    // The model difference: RCWA (bulk) and Kogelnik differ by at most a few per cent in η on
    // this film (docs/rcwa.md), so the capture moves by more than rounding and less than 5 %.
    let rel = (total(&cr) / total(&ck) - 1.0).abs();
    assert!(
        rel > 1e-5 && rel < 0.05,
        "RCWA vs Kogelnik capture: {rel:e}"
    );
    // Tables of another film (twice the index modulation) move it far more: the check can fail.
    let mut strong = kog.waveguide.gratings;
    strong.as_mut_slice()[0].n1 *= 2.0;
    let wrong = render(&with_tables(&kog, &strong), &set);
    let rel_wrong = (total(&wrong) / total(&ck) - 1.0).abs();
    assert!(rel_wrong > 0.05, "tables of another film: {rel_wrong:e}");
}

fn cli(args: &[&str], cache: &std::path::Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_stscam"))
        .args(args)
        .env("STSCAM_CACHE_DIR", cache)
        .output()
        .expect("stscam runs")
}

#[test]
fn the_cli_builds_caches_and_reuses_the_tables() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let out = |n: &str| dir.path().join(n).to_string_lossy().into_owned();
    let args = |o: &str| {
        vec![
            "render".to_string(),
            "--spp".into(),
            "2".into(),
            "--set".into(),
            "hoe.model=rcwa".into(),
            "--set".into(),
            "sensor.crop_px=[32,32]".into(),
            "--out".into(),
            o.to_string(),
        ]
    };
    let run = |o: &str| {
        let a = args(o);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        cli(&a, &cache)
    };
    let first = run(&out("a"));
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let e1 = String::from_utf8_lossy(&first.stderr);
    assert!(
        e1.contains("hoe.model = rcwa: coupling tables built"),
        "{e1}"
    );
    let second = run(&out("b"));
    let e2 = String::from_utf8_lossy(&second.stderr);
    assert!(e2.contains("read from"), "{e2}");
    let read = |d: &str| std::fs::read(dir.path().join(d).join("capture.exr")).unwrap();
    assert_eq!(read("a"), read("b"), "cached tables give the same capture");
    // A film RCWA cannot take (two gratings with incommensurate in-plane periods): exit 2,
    // one line naming the key, nothing written.
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/two-grating.toml");
    let bad = cli(
        &[
            "render",
            scene,
            "--set",
            "hoe.model=rcwa",
            "--out",
            &out("c"),
        ],
        &cache,
    );
    assert_eq!(bad.status.code(), Some(2));
    let e = String::from_utf8_lossy(&bad.stderr);
    assert!(e.contains("hoe.model") && e.contains("grating 2"), "{e}");
    assert_eq!(e.trim().lines().count(), 1, "{e}");
    assert!(!dir.path().join("c").exists());
    // Three gratings of different slant (RGB sharing one in-plane period): RCWA can take the
    // film, but every slice needs its own eigensolution (≈ 0.8 s a solve at 16 µm), so the
    // tables would take hours: refused from a timed pilot node, in one line, nothing written.
    let s55 = 55f64.to_radians().sin();
    let mut rgb = String::from(
        "[hoe]\nfilm_thickness_um = 16.0\nmean_index = 1.50\namplitude_absorption_per_mm = 0.0\n",
    );
    for l in [460.0f64, 532.0, 620.0] {
        let a = (l / 532.0 * s55).asin().to_degrees();
        rgb += &format!(
            "[[hoe.grating]]\nrecording_wavelength_nm = {l}\nreference_angle_deg = {a}\nindex_modulation = 0.005\n"
        );
    }
    let rgb_path = dir.path().join("rgb.toml");
    std::fs::write(&rgb_path, rgb).unwrap();
    let slow = cli(
        &[
            "render",
            rgb_path.to_str().unwrap(),
            "--set",
            "hoe.model=rcwa",
            "--out",
            &out("e"),
        ],
        &cache,
    );
    assert_eq!(slow.status.code(), Some(2));
    let e = String::from_utf8_lossy(&slow.stderr);
    assert!(
        e.contains("hoe.model") && e.contains("would take about"),
        "{e}"
    );
    assert!(!dir.path().join("e").exists());
    // An unknown model names the key too.
    let typo = cli(
        &["render", "--set", "hoe.model=rcwaa", "--out", &out("d")],
        &cache,
    );
    assert_eq!(typo.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&typo.stderr).contains("hoe.model"));
}
