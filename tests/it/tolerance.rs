//! Fabrication tolerances (`stscam::tolerance`, `optics::fabrication`): zero-width draws give
//! the nominal figures exactly, a shrinkage draw moves the band centre by the closed-form
//! amount (checked against the tolerance figure and against the tracer's own peak), the
//! results are the same bytes for any shard split and thread count, and bad input is one line
//! naming the flag or key with exit code 2.

use std::path::PathBuf;

use glam::DVec2;
use stscam::analysis::field_direction;
use stscam::optics::fabrication::shrunk_bragg_wavelength_nm;
use stscam::scene::load_scene;
use stscam::sweep::PsnrSettings;
use stscam::system::System;
use stscam::tolerance::{Thresholds, ToleranceSettings, merge, run_tolerance};
use stscam::trace::{BranchKind, trace_camera_path};

use crate::common::stscam;

/// The small PSNR problem of the README (a 96 × 160 crop that frames a 16 × 16 target).
fn small() -> Vec<String> {
    vec![
        "sensor.crop_px=[96,160]".into(),
        "display.image=letter:F@16".into(),
    ]
}

fn settings(draws: &[&str], samples: usize, psnr: bool) -> ToleranceSettings {
    ToleranceSettings {
        draws: draws.iter().map(|s| s.to_string()).collect(),
        samples,
        seed: 5,
        field_deg: vec![-10.0, 0.0, 10.0],
        psnr: psnr.then(|| PsnrSettings {
            target: "letter:F".into(),
            spp: 2,
            seed: 5,
        }),
        thresholds: Thresholds {
            min_efficiency: Some(0.7),
            max_band_shift_nm: Some(2.0),
            ..Thresholds::default()
        },
    }
}

/// Every fabrication key drawn with zero width (at 0): each draw's figures, PSNR included, are
/// the nominal ones bit for bit. The same run with one key 10⁻⁶ off nominal differs (the check
/// can fail).
#[test]
fn zero_width_draws_reproduce_the_nominal_figures() {
    let zero = [
        "hoe.shrinkage=normal(0,0)",
        "hoe.mean_index_change=uniform(0,0)",
        "hoe.thickness_error_um=normal(0,0)",
        "hoe.temperature_change_k=normal(0,0)",
        "hoe.index_modulation_shortfall=uniform(0,0)",
        "hoe.reference_angle_error_deg=normal(0,0)",
    ];
    let out = run_tolerance(None, &small(), &settings(&zero, 3, true), None, false).unwrap();
    assert!(out.nominal.psnr_db.unwrap() > 10.0);
    for d in &out.draws {
        assert_eq!(d.values, vec![0.0; 6]);
        assert_eq!(d.figures, out.nominal, "draw {}", d.draw);
    }
    // Every scalar figure: its spread is 0 and the yield is the nominal design's.
    let s = out.summary.unwrap();
    for (name, st) in &s.figures {
        assert_eq!(st.min, st.nominal, "{name}");
        assert_eq!(st.max, st.nominal, "{name}");
    }
    let mut off = zero.to_vec();
    off[0] = "hoe.shrinkage=normal(0.000001,0)";
    let out = run_tolerance(None, &small(), &settings(&off, 1, false), None, false).unwrap();
    assert_ne!(
        out.draws[0].figures.band_centre_nm,
        out.nominal.band_centre_nm
    );
}

/// A shrinkage s = 0.02 moves each field's band centre to the closed form
/// λ_B(Θ, s) = 2λ0 q (a cos Θ − b q sin Θ)/(a² + b² q²) (`optics::fabrication`; a = 1 + cos θ_R,
/// b = sin θ_R, q = 1 − s, Θ the internal angle), tolerance 10⁻⁹ relative. The tracer agrees:
/// the in-coupling efficiency it computes peaks there (0.001 nm grid, within 0.05 nm: ν and c_S
/// vary with λ, which moves η's maximum 0.012 nm), equal to Kogelnik's tanh²ν of
/// the shrunk film, and the on-axis first replica's end-to-end weight peaks that much lower
/// than the nominal film's (tolerance 0.2 nm: its peak sits 0.5–0.7 nm below λ_B, the
/// guided wave's losses under the top vHOE being largest at Bragg, and the thinner film widens
/// the band; measured 5.39 against 5.23 nm).
/// The form with a wrong coefficient (K_z scaled by 1 − s instead of 1/(1 − s)) is ~10 nm off
/// and fails the same check.
#[test]
fn shrinkage_moves_the_band_centre_by_the_closed_form() {
    let s = 0.02;
    let out = run_tolerance(
        None,
        &[],
        &settings(&["hoe.shrinkage=uniform(0.02,0.02)"], 1, false),
        None,
        false,
    )
    .unwrap();
    let f = &out.draws[0].figures;
    let wrong = |theta: f64| {
        let (tr, ti) = (61.2f64.to_radians(), theta.to_radians());
        let (a, b, q) = (1.0 + tr.cos(), tr.sin(), 1.0 - s);
        // K_z → K_z (1 − s): λ_B = 4πn(sinΘ K_y + cosΘ K_z q)/(K_y² + K_z² q²).
        2.0 * 532.0 * (a * q * ti.cos() - b * ti.sin()) / (b * b + a * a * q * q)
    };
    for (k, &air) in [-10.0f64, 0.0, 10.0].iter().enumerate() {
        // The field's internal angle in the film (n = 1.5): n sin Θ = u_y = −sin(air).
        let theta = (-(air.to_radians().sin()) / 1.5).asin().to_degrees();
        let want = shrunk_bragg_wavelength_nm(532.0, 61.2, s, theta);
        let got = f.band_centre_nm[0][k].unwrap();
        assert!((got - want).abs() < 1e-9 * want, "{air}: {got} vs {want}");
        assert!(
            (got - wrong(theta)).abs() > 1.0,
            "{air}: the wrong form passes"
        );
        // The shift against the nominal band centre, as the closed form gives it.
        let nominal = out.nominal.band_centre_nm[0][k].unwrap();
        let shift = want - shrunk_bragg_wavelength_nm(532.0, 61.2, 0.0, theta);
        assert!((got - nominal - shift).abs() < 1e-9, "{air}");
        assert!(shift < -4.0, "{air}: shift {shift}");
    }
    // On axis: the tracer's peak.
    let on_axis = f.bragg_on_axis_nm[0].unwrap();
    assert!((on_axis - shrunk_bragg_wavelength_nm(532.0, 61.2, s, 0.0)).abs() < 1e-9);
    let build = |ov: &[String]| System::build(&load_scene(None, ov).unwrap()).unwrap();
    let sys = build(&["hoe.shrinkage=0.02".into()]);
    let nominal_sys = build(&[]);
    let dir = field_direction(0.0, true);
    // Wavelength (0.001 nm grid within ±3 nm of `centre`) where the on-axis chief ray's first
    // replica is brightest.
    let peak = |sys: &System, centre: f64| {
        let (mut best, mut best_w) = (f64::NAN, 0.0);
        for i in -3000..=3000 {
            let lam = centre + 0.001 * f64::from(i);
            let mut w = 0.0;
            trace_camera_path(
                &sys.waveguide,
                sys.display.z_mm,
                sys.limits,
                sys.camera.lens_center_mm,
                dir,
                lam,
                |b| {
                    if matches!(b.kind, BranchKind::Replica(0)) {
                        w += b.weight[0] + b.weight[1];
                    }
                },
            );
            if w > best_w {
                (best, best_w) = (lam, w);
            }
        }
        best
    };
    let (p_shrunk, p_nominal) = (peak(&sys, on_axis), peak(&nominal_sys, 532.0));
    let traced_shift = p_shrunk - p_nominal;
    let closed_shift = on_axis - 532.0;
    assert!(
        (traced_shift - closed_shift).abs() < 0.2,
        "tracer shift {traced_shift} vs closed form {closed_shift}"
    );
    // The in-coupling efficiency the tracer uses (on-shell closure, `diffract`) peaks at the
    // closed form (0.001 nm grid), where it is Kogelnik's tanh²ν of the shrunk film.
    let g = *sys.waveguide.gratings.get(0);
    let eta = |lam: f64| {
        g.diffract(DVec2::ZERO, 1.0, lam, 1)
            .map_or(0.0, |d| d.eta[0])
    };
    let mut best = (f64::NAN, 0.0);
    for i in -3000..=3000 {
        let lam = on_axis + 0.001 * f64::from(i);
        if eta(lam) > best.1 {
            best = (lam, eta(lam));
        }
    }
    assert!(
        (best.0 - on_axis).abs() < 0.05,
        "η peaks at {} vs {on_axis}",
        best.0
    );
    // K_t is held, so the order leaves with n sin θ_S = sin θ_R · λ_B/λ0 · n.
    let c_s = (1.0 - (61.2f64.to_radians().sin() * on_axis / 532.0).powi(2)).sqrt();
    let nu = std::f64::consts::PI * 0.015 * 16000.0 * (1.0 - s) / (on_axis * c_s.sqrt());
    assert!((eta(on_axis) - nu.tanh().powi(2)).abs() < 1e-9);
    assert!(
        eta(wrong(0.0)) < 0.5 * eta(on_axis),
        "the wrong form is Bragg-matched"
    );
    assert!(
        (traced_shift - (wrong(0.0) - 532.0)).abs() > 1.0,
        "the wrong form agrees with the tracer"
    );
    // The shrunk system built from the scene has the same grating as the tolerance draw.
    let g = sys.waveguide.gratings.get(0);
    assert!((g.bragg_wavelength_nm(DVec2::ZERO).unwrap() - on_axis).abs() < 1e-12);
}

/// One run, three shards merged, and one thread: the same bytes (PSNR included).
#[test]
fn any_shard_split_and_thread_count_give_the_same_bytes() {
    let draws = [
        "hoe.shrinkage=normal(0.01,0.005)",
        "hoe.index_modulation_shortfall=uniform(0,0.3)",
        "hoe.temperature_change_k=normal(0,15)",
    ];
    let set = settings(&draws, 7, true);
    let run = |threads: usize, shard: Option<&str>| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let shard = shard.map(|s| stscam::dataset::Shard::parse(s).unwrap());
        pool.install(|| run_tolerance(None, &small(), &set, shard, false))
            .unwrap()
    };
    let whole = run(2, None);
    let one = run(1, None);
    assert_eq!(whole.files, one.files);
    assert!(whole.files.iter().any(|(n, _)| n == "ranking_psnr_db.png"));
    let dir = tempfile::tempdir().unwrap();
    let mut shards: Vec<PathBuf> = Vec::new();
    for i in [2, 0, 1] {
        let out = run(2, Some(&format!("{i}/3")));
        let d = dir.path().join(format!("s{i}"));
        std::fs::create_dir(&d).unwrap();
        for (name, bytes) in &out.files {
            std::fs::write(d.join(name), bytes).unwrap();
        }
        shards.push(d);
    }
    let (files, _) = merge(&shards).unwrap();
    assert_eq!(files, whole.files);
    // A missing shard is refused, naming what is missing.
    let e = merge(&shards[..2]).unwrap_err().to_string();
    assert!(e.contains("need shards 0..2 once each"), "{e}");
}

/// `--require` on `evaluate` metrics: each requirement's pass fraction is the fraction of the
/// draws whose recorded metric meets it (counted here from `draws.jsonl`-equivalent records),
/// the yield the fraction meeting both, and the captured FOV is summarised. A threshold set at
/// the median splits the draws, so a yield computed on the wrong metric would differ.
#[test]
fn requirements_on_evaluate_metrics_count_the_draws_that_meet_them() {
    use stscam::tolerance::Requirement;
    let draws = ["hoe.index_modulation_shortfall=uniform(0,0.4)"];
    // Without a requirement on one, no draw computes the evaluate metrics (0.35 s each).
    let plain = run_tolerance(None, &small(), &settings(&draws, 2, false), None, false).unwrap();
    assert!(plain.draws.iter().all(|d| d.figures.metrics.is_empty()));
    let mut set = settings(&draws, 12, false);
    set.thresholds.require = vec![Requirement::parse("efficiency_mean>=0").unwrap()];
    let first = run_tolerance(None, &small(), &set, None, false).unwrap();
    let mut eff: Vec<f64> = first
        .draws
        .iter()
        .map(|d| d.figures.metrics["efficiency_mean"])
        .collect();
    eff.sort_by(f64::total_cmp);
    let median = 0.5 * (eff[5] + eff[6]);
    let fov = first.nominal.metrics["fov_capture_vertical_deg"];
    assert!(fov > 1.0 && fov < 60.0, "{fov}");
    set.thresholds = Thresholds {
        require: vec![
            Requirement::parse(&format!("efficiency_mean>={median}")).unwrap(),
            Requirement::parse(&format!("fov_capture_vertical_deg<={}", fov - 0.5)).unwrap(),
        ],
        ..Thresholds::default()
    };
    let out = run_tolerance(None, &small(), &set, None, false).unwrap();
    let s = out.summary.unwrap();
    let names: Vec<&str> = s.figures.iter().map(|f| f.0.as_str()).collect();
    assert!(names.contains(&"efficiency_mean") && names.contains(&"fov_capture_vertical_deg"));
    let y = &s.yield_;
    assert_eq!(y.per_threshold[0].0, format!("efficiency_mean>={median}"));
    assert_eq!(y.per_threshold[0].1, 0.5);
    // Shortfall does not move the captured FOV: no draw is 0.5 degrees below nominal.
    assert_eq!(y.per_threshold[1].1, 0.0);
    assert_eq!(y.passed, 0);
    // Only the efficiency requirement: half the draws.
    set.thresholds.require.pop();
    let out = run_tolerance(None, &small(), &set, None, false).unwrap();
    assert_eq!(out.summary.unwrap().yield_.passed, 6);
}

/// `psnr_gain_db` separates a pure gain from a spectral change: a lower index modulation
/// mostly dims the capture, so its draws spread `psnr_db` several times more than
/// `psnr_gain_db`, and the gain-fitted PSNR is never below the plain one (a = 1 is a candidate
/// of the least-squares gain).
#[test]
fn the_gain_fitted_psnr_discounts_a_pure_brightness_loss() {
    let draws = ["hoe.index_modulation_shortfall=uniform(0,0.4)"];
    let out = run_tolerance(None, &small(), &settings(&draws, 8, true), None, false).unwrap();
    let sd = |v: Vec<f64>| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
    };
    let plain: Vec<f64> = out
        .draws
        .iter()
        .map(|d| d.figures.psnr_db.unwrap())
        .collect();
    let gain: Vec<f64> = out
        .draws
        .iter()
        .map(|d| d.figures.psnr_gain_db.unwrap())
        .collect();
    for (p, g) in plain.iter().zip(&gain) {
        assert!(g >= p, "{g} < {p}");
    }
    let (sp, sg) = (sd(plain), sd(gain));
    assert!(sp > 0.5 && sg < 0.2 * sp, "sd psnr {sp}, sd psnr_gain {sg}");
}

/// Bad input: one line naming the flag or key, exit code 2, nothing written.
#[test]
fn bad_input_is_one_line_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t");
    let o = out.to_str().unwrap();
    for (args, want) in [
        (
            vec![
                "--draw",
                "plate.thickness_mm=normal(2,0.1)",
                "--samples",
                "3",
            ],
            "--draw plate.thickness_mm=normal(2,0.1): ",
        ),
        (
            vec!["--draw", "hoe.shrinkage=normal(0,-1)", "--samples", "3"],
            "needs SD >= 0",
        ),
        (
            vec!["--draw", "hoe.shrinkage=normal(0,0.01)", "--samples", "0"],
            "--samples",
        ),
        (
            vec!["--draw", "hoe.shrinkage=uniform(0.6,0.7)", "--samples", "2"],
            "--draw hoe.shrinkage: hoe.shrinkage: must be in [-0.5, 0.5]",
        ),
        (
            vec![
                "--draw",
                "hoe.shrinkage=normal(0,0.01)",
                "--samples",
                "2",
                "--shard",
                "3/3",
            ],
            "--shard",
        ),
        (
            vec![
                "--draw",
                "hoe.shrinkage=normal(0,0.01)",
                "--samples",
                "2",
                "--min-psnr-db",
                "20",
            ],
            "--min-psnr-db: needs --psnr",
        ),
        (
            vec![
                "--draw",
                "hoe.shrinkage=normal(0,0.01)",
                "--samples",
                "2",
                "--require",
                "fov_capture_vertikal_deg>=30",
            ],
            "--require fov_capture_vertikal_deg>=30: unknown figure; expected one of",
        ),
        (
            vec![
                "--draw",
                "hoe.shrinkage=normal(0,0.01)",
                "--samples",
                "2",
                "--require",
                "psnr_gain_db>=20",
            ],
            "--require psnr_gain_db>=20: needs --psnr",
        ),
        (
            vec![
                "--draw",
                "hoe.shrinkage=normal(0,0.01)",
                "--samples",
                "2",
                "--require",
                "efficiency_mean=0.1",
            ],
            "expected NAME>=VALUE or NAME<=VALUE",
        ),
    ] {
        let mut a = vec!["tolerance"];
        a.extend(args);
        a.extend(["--out", o]);
        let r = stscam(&a);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{a:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{a:?}: {err}");
        assert!(err.contains(want), "{a:?}: {err}");
        assert!(!out.exists());
    }
}

/// The command line: two shards merged by `stscam tolerance merge`, and one thread, write the
/// same files as one run.
#[test]
fn cli_shards_merge_to_the_unsharded_files() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let base = [
        "tolerance",
        "--draw",
        "hoe.shrinkage=normal(0.01,0.005)",
        "--draw",
        "hoe.thickness_error_um=uniform(-1,1)",
        "--samples",
        "9",
        "--min-efficiency",
        "0.7",
    ];
    let run = |extra: &[&str]| {
        let mut a: Vec<&str> = base.to_vec();
        a.extend(extra);
        crate::common::stscam_ok(&a);
    };
    let (whole, one, s0, s1, merged) = (p("whole"), p("one"), p("s0"), p("s1"), p("merged"));
    run(&["--out", &whole]);
    run(&["--out", &one, "--threads", "1"]);
    run(&["--out", &s1, "--shard", "1/2"]);
    run(&["--out", &s0, "--shard", "0/2"]);
    crate::common::stscam_ok(&["tolerance", "merge", &s1, &s0, "--out", &merged]);
    crate::common::assert_same_tree(
        dir.path().join("whole").as_path(),
        dir.path().join("merged").as_path(),
    );
    crate::common::assert_same_tree(
        dir.path().join("whole").as_path(),
        dir.path().join("one").as_path(),
    );
    assert!(crate::common::files_in(dir.path().join("s0").as_path()).len() == 2);
}

/// A colour display (three object planes, H with three column blocks): the stale-calibration
/// PSNR is computed over all three planes (it panicked: the object's one plane against H's
/// three), and a zero-width draw reproduces the nominal PSNR bit for bit; the grey target
/// through the three primaries reconstructs better than the all-zero estimate.
#[test]
fn the_psnr_of_a_colour_display_is_computed_over_its_planes() {
    let mut ov = small();
    ov.push("display.primaries=\"lcd\"".into());
    let set = settings(&["hoe.shrinkage=normal(0,0)"], 1, true);
    let out = run_tolerance(None, &ov, &set, None, false).unwrap();
    let p = out.nominal.psnr_db.unwrap();
    // The trivial estimate (all zero) of the same three-plane target: the reconstruction
    // must beat it clearly (the paper's single grating passes only parts of each primary's
    // band, so a colour object is harder than a grey one).
    let sys = System::build(&load_scene(None, &ov).unwrap()).unwrap();
    let truth = stscam::sweep::psnr_target(&sys, set.psnr.as_ref().unwrap()).unwrap();
    assert_eq!(truth.len(), 3 * 16 * 16);
    let zero = stscam::recon::metrics::psnr(&vec![0.0; truth.len()], &truth);
    eprintln!("colour PSNR {p:.2} dB, zero estimate {zero:.2} dB");
    assert!(
        p.is_finite() && p > zero + 2.0,
        "colour PSNR {p} against {zero}"
    );
    assert_eq!(out.draws[0].figures.psnr_db, Some(p));
    // The sweep's PSNR (which panicked the same way) of the RGB multiplex film, whose three
    // gratings make the primaries separable: well above the zero estimate (measured 14.4 dB
    // against 6.6). The paper's single grating is not (its sweep PSNR, 4.3 dB, is below the
    // zero estimate: one band cannot tell the primaries apart).
    let rgb = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/rgb-multiplex.toml");
    let sw = stscam::sweep::run_sweep(
        Some(&rgb),
        &small(),
        &[stscam::sweep::VaryAxis::parse("top_hoe.height_mm=24:24:1").unwrap()],
        &stscam::sweep::SweepSettings {
            psnr: set.psnr.clone(),
            ..stscam::sweep::SweepSettings::default()
        },
    )
    .unwrap();
    let q = sw.rows[0].figures.psnr_db.unwrap();
    assert!(
        q.is_finite() && q > zero + 5.0,
        "sweep colour PSNR {q} against {zero}"
    );
    // The monochrome display's PSNR of the same target is another number (the planes count).
    let mono = run_tolerance(None, &small(), &set, None, false).unwrap();
    assert_ne!(mono.nominal.psnr_db, Some(p));
}

/// A merge verifies what it reads back: a changed `draws.jsonl` (one value dropped: this
/// panicked the merge) is refused by the SHA-256 that shard.json records; a record resealed
/// with a matching hash but the wrong number of values, or another draw's index, is refused
/// by the record check; a FIFO in place of draws.jsonl is refused at once instead of hanging.
/// The untouched shard still merges (the checks can pass).
#[test]
fn a_merge_refuses_changed_resealed_and_special_shard_files() {
    let set = settings(
        &[
            "hoe.shrinkage=normal(0.01,0.005)",
            "hoe.temperature_change_k=normal(0,15)",
        ],
        2,
        false,
    );
    let dir = tempfile::tempdir().unwrap();
    let shard = |name: &str| {
        let out = run_tolerance(
            None,
            &small(),
            &set,
            Some(stscam::dataset::Shard::parse("0/1").unwrap()),
            false,
        )
        .unwrap();
        let d = dir.path().join(name);
        std::fs::create_dir(&d).unwrap();
        for (n, bytes) in &out.files {
            std::fs::write(d.join(n), bytes).unwrap();
        }
        d
    };
    let good = shard("good");
    assert!(merge(std::slice::from_ref(&good)).is_ok());
    let draws = std::fs::read_to_string(good.join("draws.jsonl")).unwrap();
    let mut rec: serde_json::Value = serde_json::from_str(draws.lines().next().unwrap()).unwrap();
    rec["values"].as_array_mut().unwrap().pop();
    let changed = format!("{}\n{}\n", rec, draws.lines().nth(1).unwrap());
    // Changed: the hash no longer matches.
    let d = shard("changed");
    std::fs::write(d.join("draws.jsonl"), &changed).unwrap();
    let e = merge(&[d.clone()]).unwrap_err().to_string();
    assert!(e.contains("draws.jsonl") && e.contains("SHA-256"), "{e}");
    // Resealed: the hash is recomputed into shard.json; the record check refuses it.
    let sha: String = {
        use sha2::{Digest, Sha256};
        Sha256::digest(changed.as_bytes())
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    };
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("shard.json")).unwrap()).unwrap();
    m["draws_sha256"] = sha.into();
    std::fs::write(d.join("shard.json"), m.to_string()).unwrap();
    let e = merge(&[d]).unwrap_err().to_string();
    assert!(e.contains("line 1") && e.contains("1 values"), "{e}");
    // A FIFO: refused in one line, not read.
    let f = shard("fifo");
    std::fs::remove_file(f.join("draws.jsonl")).unwrap();
    let st = std::process::Command::new("mkfifo")
        .arg(f.join("draws.jsonl"))
        .status();
    if st.is_ok_and(|s| s.success()) {
        let e = merge(&[f]).unwrap_err().to_string();
        assert!(e.contains("draws.jsonl"), "{e}");
    }
}
