//! Design sweeps (`stscam::sweep`): axis parsing, the spectral integral of the field response,
//! the throughput FOV against the geometric FOV of `analysis::info`, the paper's dilemma (FOV
//! and replicas grow with the bottom-vHOE height), error reporting, the output files, the PSNR
//! protocol shared with `demo`, and determinism across thread counts.

use stscam::analysis::info;
use stscam::scene::load_scene;
use stscam::sweep::{
    PsnrSettings, ResponseGrid, SpectralWeight, SweepError, SweepSettings, VaryAxis,
    design_figures, field_response, run_sweep,
};
use stscam::system::System;

fn system(overrides: &[&str]) -> System {
    let ov: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    System::build(&load_scene(None, &ov).expect("scene")).expect("system")
}

fn axis(spec: &str) -> VaryAxis {
    VaryAxis::parse(spec).expect("axis")
}

/// A coarse grid for tests that check plumbing rather than numbers.
fn coarse() -> ResponseGrid {
    ResponseGrid {
        angle_step_deg: 0.5,
        angle_max_deg: 40.0,
        bragg_half_width_nm: 20.0,
        bragg_step_nm: 0.5,
        broadband_step_nm: 2.0,
        crop_grid: 5,
    }
}

#[test]
fn vary_axis_parses_good_specs_with_exact_ends() {
    let a = axis("bottom_hoe.height_mm=10:80:15");
    assert_eq!(a.key, "bottom_hoe.height_mm");
    let v = a.values();
    assert_eq!(v.len(), 15);
    assert_eq!(
        v,
        (0..15).map(|i| 10.0 + 5.0 * i as f64).collect::<Vec<_>>()
    );
    // Ends are exact even where the step is not representable.
    let b = axis(" hoe.index_modulation = 0.005 : 0.03 : 7 ");
    let v = b.values();
    assert_eq!((v[0], v[6]), (0.005, 0.03));
    assert!((v[1] - (0.005 + 0.025 / 6.0)).abs() < 1e-14);
    // Interior points are rounded to 12 significant digits.
    assert_eq!(axis("k=0.01:0.03:3").values(), vec![0.01, 0.02, 0.03]);
    // Descending and negative ranges, and a single point.
    assert_eq!(axis("k=1:-1:3").values(), vec![1.0, 0.0, -1.0]);
    assert_eq!(axis("k=2.5:2.5:1").values(), vec![2.5]);
    assert_eq!(axis("k=1e1:2e1:2").values(), vec![10.0, 20.0]);
}

#[test]
fn vary_axis_rejects_bad_specs_naming_them() {
    for (spec, why) in [
        ("bottom_hoe.height_mm", "expected KEY=START:STOP:STEPS"),
        ("=1:2:3", "bad key"),
        ("k=1:2", "expected START:STOP:STEPS"),
        ("k=1:2:3:4", "expected START:STOP:STEPS"),
        ("k=a:2:3", "START must be a finite number"),
        ("k=1:inf:3", "STOP must be a finite number"),
        ("k=1:2:0", "STEPS must be an integer"),
        ("k=1:2:2.5", "STEPS must be an integer"),
        ("k=1:2:-3", "STEPS must be an integer"),
        ("k=1:1:3", "START = STOP needs STEPS = 1"),
        ("k=1:2:1", "STEPS = 1 needs START = STOP"),
    ] {
        let e = VaryAxis::parse(spec).expect_err(spec);
        let msg = e.to_string();
        assert!(matches!(e, SweepError::Axis { .. }), "{spec}: {msg}");
        assert!(
            msg.starts_with(&format!("--vary {spec}: ")) && msg.contains(why),
            "{spec}: {msg}"
        );
        assert!(!msg.contains('\n'), "{msg}");
    }
}

#[test]
fn spectral_integral_converges() {
    let sys = system(&[]);
    let base = ResponseGrid::default();
    let fine = ResponseGrid {
        bragg_step_nm: base.bragg_step_nm / 2.0,
        broadband_step_nm: base.broadband_step_nm / 2.0,
        ..base.clone()
    };
    let wide = ResponseGrid {
        bragg_half_width_nm: 2.0 * base.bragg_half_width_nm,
        ..base.clone()
    };
    let (w_base, w_fine) = (
        SpectralWeight::new(&sys, &base),
        SpectralWeight::new(&sys, &fine),
    );
    assert!(
        (w_fine.norm() / w_base.norm() - 1.0).abs() < 1e-4,
        "{} vs {}",
        w_fine.norm(),
        w_base.norm()
    );
    let dir = |v: f64, h: f64| {
        let (v, h) = (v.to_radians(), h.to_radians());
        glam::DVec3::new(h.sin(), v.sin(), -(h.cos() * v.cos())).normalize()
    };
    // −4.3°: inside the top-vHOE re-coupling transition, where W(λ) jumps within the band.
    for (v, h) in [
        (0.0, 0.0),
        (-10.0, 0.0),
        (12.0, 0.0),
        (0.0, 20.0),
        (5.0, -8.0),
        (-4.3, 0.0),
    ] {
        let d = dir(v, h);
        let t = field_response(&sys, &w_base, &base, d);
        let t_fine = field_response(&sys, &w_fine, &fine, d);
        let t_wide = field_response(&sys, &w_base, &wide, d);
        assert!(t > 1e-3 && t < 0.1, "({v}, {h}): T = {t}");
        assert!(
            (t_fine / t - 1.0).abs() < 0.005,
            "({v}, {h}): step {} nm gives {t}, half the step {t_fine}",
            base.bragg_step_nm
        );
        // The Kogelnik side lobes beyond ±40 nm add almost nothing.
        assert!(
            t_wide >= t && (t_wide / t - 1.0) < 0.005,
            "({v}, {h}): ±40 nm {t}, ±80 nm {t_wide}"
        );
    }
}

#[test]
fn throughput_fov_matches_the_geometric_fov_at_the_top_vhoe_aperture() {
    let sys = system(&[]);
    let geo = info(&sys).fov_vertical_waveguide;
    assert_eq!(geo.min.limited_by, "top vHOE aperture");
    assert_eq!(geo.max.limited_by, "top vHOE aperture");
    // A low threshold: T stays above 5 % of its maximum up to the aperture at both ends.
    let set = SweepSettings {
        fov_fraction: 0.05,
        ..Default::default()
    };
    let f = design_figures(&sys, &set);
    let fov = &f.fov_vertical;
    for (edge, g) in [(&fov.min, &geo.min), (&fov.max, &geo.max)] {
        assert_eq!(edge.limited_by, "top vHOE aperture", "{fov:?}");
        assert!(
            (edge.angle_deg - g.angle_deg).abs() <= 0.3,
            "throughput edge {} vs geometric {}",
            edge.angle_deg,
            g.angle_deg
        );
    }
    assert!(
        (fov.full_deg - geo.full_deg).abs() <= 0.6,
        "{fov:?} vs {geo:?}"
    );
    // At the default threshold the FOV lies inside the geometric one.
    let f = design_figures(&sys, &SweepSettings::default());
    let fov = &f.fov_vertical;
    assert!(
        fov.min.angle_deg >= geo.min.angle_deg - 0.3
            && fov.max.angle_deg <= geo.max.angle_deg + 0.3,
        "{fov:?} vs {geo:?}"
    );
    assert!(f.efficiency_peak > 0.0 && f.efficiency_peak <= 1.0);
    assert!(f.efficiency_on_axis <= f.efficiency_peak);
    assert!(f.efficiency_crop_mean > 0.0 && f.efficiency_crop_mean <= f.efficiency_peak);
    // The capture FOV is the throughput FOV inside the crop (±9.9° for 440 px at f = 6 mm).
    let cap = &f.fov_horizontal_capture;
    assert_eq!(cap.min.limited_by, "sensor crop");
    assert!((cap.full_deg - 19.76).abs() < 0.05, "{cap:?}");
}

/// The paper's dilemma: a taller bottom vHOE widens the FOV and the scene field and adds
/// replicas. Checked at 10 % of the maximum (the default) over 4–12 mm and at half the maximum
/// over 2–8 mm: the ranges where the bottom vHOE binds. (At half the maximum the vertical FOV
/// is set by the white-LED spectrum and by the top vHOE's re-coupling step once the bottom vHOE
/// is taller than about 8 mm; beyond 12 mm the relative threshold rises with the peak field's
/// extra replicas, and the FOV need not grow monotonically.)
#[test]
fn fov_and_replicas_grow_with_the_bottom_vhoe_height() {
    let set = SweepSettings {
        fov_fraction: 0.1,
        ..Default::default()
    };
    let out = run_sweep(None, &[], &[axis("bottom_hoe.height_mm=4:12:3")], &set).expect("sweep");
    let heights: Vec<f64> = out.rows.iter().map(|r| r.varied[0].value).collect();
    assert_eq!(heights, vec![4.0, 8.0, 12.0]);
    let fov: Vec<f64> = out
        .rows
        .iter()
        .map(|r| r.figures.fov_vertical.full_deg)
        .collect();
    let reps: Vec<usize> = out.rows.iter().map(|r| r.figures.replicas_total).collect();
    let strong: Vec<usize> = out
        .rows
        .iter()
        .map(|r| r.figures.replicas_above_5pct)
        .collect();
    let geo: Vec<f64> = out
        .rows
        .iter()
        .map(|r| r.figures.geometric_fov_vertical_deg)
        .collect();
    for w in fov.windows(2) {
        assert!(w[1] >= w[0], "FOV {fov:?}");
    }
    for w in reps.windows(2) {
        assert!(w[1] >= w[0], "replicas {reps:?}");
    }
    for w in strong.windows(2) {
        assert!(w[1] >= w[0], "replicas >= 5 % {strong:?}");
    }
    assert!(fov[2] > fov[0] + 20.0, "FOV {fov:?}");
    assert!(
        reps[2] > reps[0] && strong[2] > strong[0],
        "{reps:?} {strong:?}"
    );
    assert!(geo[2] > geo[0], "geometric FOV {geo:?}");
    // The scene field (display region seen through strong replicas) widens too, and is at least
    // the capture FOV's direct view at the display distance (550 mm).
    let scene: Vec<f64> = out
        .rows
        .iter()
        .map(|r| r.figures.scene_field_vertical.extent_mm)
        .collect();
    for w in scene.windows(2) {
        assert!(w[1] > w[0], "scene field {scene:?}");
    }
    for r in &out.rows {
        let c = &r.figures.fov_vertical_capture;
        let direct =
            550.0 * (c.max.angle_deg.to_radians().tan() - c.min.angle_deg.to_radians().tan());
        let e = r.figures.scene_field_vertical.extent_mm;
        assert!(
            e >= direct - 1.0 && e < direct + 8.0 * 6.8,
            "{e} vs {direct}"
        );
    }
    // 4 mm: the bottom vHOE is what stops the field on both sides.
    let first = &out.rows[0].figures.fov_vertical;
    assert!(
        first.min.limited_by.starts_with("bottom vHOE")
            && first.max.limited_by.starts_with("bottom vHOE"),
        "{first:?}"
    );
    // The display-side pitch 2w·tanΘ' of the centre field does not depend on the height.
    let p0 = out.rows[0].figures.replica_pitch_mm;
    assert!((p0 - 6.785).abs() < 0.01, "{p0}");
    assert!(out.rows.iter().all(|r| r.figures.replica_pitch_mm == p0));

    // Half the maximum, bottom vHOE 2–8 mm: still limited by the bottom vHOE, still growing.
    let out = run_sweep(
        None,
        &[],
        &[axis("bottom_hoe.height_mm=2:8:4")],
        &SweepSettings {
            fov_fraction: 0.5,
            ..Default::default()
        },
    )
    .expect("sweep");
    let fov: Vec<f64> = out
        .rows
        .iter()
        .map(|r| r.figures.fov_vertical.full_deg)
        .collect();
    for w in fov.windows(2) {
        assert!(w[1] > w[0], "FOV {fov:?}");
    }
    assert!(
        out.rows[1]
            .figures
            .fov_vertical
            .max
            .limited_by
            .starts_with("bottom vHOE"),
        "{:?}",
        out.rows[1].figures.fov_vertical
    );
}

#[test]
fn invalid_values_name_the_key_and_value_before_any_work() {
    let set = SweepSettings::default();
    let e = run_sweep(None, &[], &[axis("plate.thickness_mm=-1:1:3")], &set).expect_err("w < 0");
    let msg = e.to_string();
    assert!(matches!(e, SweepError::GridPoint { .. }), "{msg}");
    assert!(
        msg.starts_with("grid point plate.thickness_mm=-1: ")
            && msg.contains("plate.thickness_mm: must be a positive finite number, got -1"),
        "{msg}"
    );
    assert!(!msg.contains('\n'));
    // A bad value at the last point of a two-axis grid is found before anything is computed.
    let e = run_sweep(
        None,
        &[],
        &[
            axis("bottom_hoe.height_mm=30:50:2"),
            axis("plate.thickness_mm=2:0:2"),
        ],
        &set,
    )
    .expect_err("w = 0");
    assert!(
        e.to_string()
            .starts_with("grid point bottom_hoe.height_mm=30, plate.thickness_mm=0: "),
        "{e}"
    );
    // Unknown keys, wrong types.
    let e = run_sweep(None, &[], &[axis("plate.colour_mm=1:2:2")], &set).expect_err("key");
    assert!(
        e.to_string().contains("plate.colour_mm: unknown key"),
        "{e}"
    );
    let e = run_sweep(None, &[], &[axis("sensor.crop_px=10.5:20.5:2")], &set).expect_err("type");
    assert!(
        e.to_string()
            .starts_with("grid point sensor.crop_px=10.5: --vary sensor.crop_px"),
        "{e}"
    );
    // A bad base override is the scene's error, not a grid point's.
    let e = run_sweep(
        None,
        &["plate.thickness_mm=0".into()],
        &[axis("bottom_hoe.height_mm=30:50:2")],
        &set,
    )
    .expect_err("base");
    assert!(matches!(e, SweepError::Scene(_)), "{e}");
    // Settings.
    assert!(matches!(
        run_sweep(None, &[], &[], &set),
        Err(SweepError::Settings(_))
    ));
    let twice = [
        axis("plate.thickness_mm=1:2:2"),
        axis("plate.thickness_mm=3:4:2"),
    ];
    assert!(
        run_sweep(None, &[], &twice, &set)
            .expect_err("twice")
            .to_string()
            .contains("varied twice")
    );
    let bad_fraction = SweepSettings {
        fov_fraction: 0.0,
        ..Default::default()
    };
    assert!(matches!(
        run_sweep(
            None,
            &[],
            &[axis("plate.thickness_mm=1:2:2")],
            &bad_fraction
        ),
        Err(SweepError::Settings(_))
    ));
    let bad_target = SweepSettings {
        psnr: Some(PsnrSettings {
            target: "letter:A@32".into(),
            ..Default::default()
        }),
        ..Default::default()
    };
    let e =
        run_sweep(None, &[], &[axis("plate.thickness_mm=1:2:2")], &bad_target).expect_err("target");
    assert!(e.to_string().contains("without @SIZE"), "{e}");
}

fn file<'a>(files: &'a [(String, Vec<u8>)], name: &str) -> &'a [u8] {
    &files
        .iter()
        .find(|f| f.0 == name)
        .unwrap_or_else(|| panic!("no {name}"))
        .1
}

#[test]
fn outputs_are_identical_for_one_and_two_threads() {
    let axes = [
        axis("bottom_hoe.height_mm=20:50:2"),
        axis("top_hoe.height_mm=15:20:2"),
    ];
    let set = SweepSettings {
        grid: coarse(),
        ..Default::default()
    };
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool")
            .install(|| run_sweep(None, &[], &axes, &set).expect("sweep"))
    };
    let (one, two) = (run(1), run(2));
    assert_eq!(one.files.len(), two.files.len());
    for (a, b) in one.files.iter().zip(&two.files) {
        assert_eq!(a.0, b.0);
        assert!(a.1 == b.1, "{} differs between 1 and 2 threads", a.0);
    }
    // The files: CSV, JSON and a PNG + SVG per quantity.
    let names: Vec<&str> = one.files.iter().map(|f| f.0.as_str()).collect();
    for stem in [
        "fov",
        "fov_capture",
        "scene_field",
        "replicas",
        "replica_pitch_mm",
        "replica_pitch_px",
        "efficiency",
        "bragg_range",
    ] {
        assert!(names.contains(&format!("{stem}.png").as_str()), "{names:?}");
        assert!(names.contains(&format!("{stem}.svg").as_str()), "{names:?}");
        assert_eq!(&file(&one.files, &format!("{stem}.png"))[1..4], b"PNG");
    }
    assert_eq!(names.len(), 2 + 2 * 8, "{names:?}");
    // Grid order: first axis slowest.
    let pts: Vec<(f64, f64)> = one
        .rows
        .iter()
        .map(|r| (r.varied[0].value, r.varied[1].value))
        .collect();
    assert_eq!(
        pts,
        vec![(20.0, 15.0), (20.0, 20.0), (50.0, 15.0), (50.0, 20.0)]
    );
    // CSV: a header with units, one line per point, the varied values as given.
    let csv = String::from_utf8(file(&one.files, "sweep.csv").to_vec()).expect("utf-8");
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 5);
    let header: Vec<&str> = lines[0].split(',').collect();
    assert_eq!(
        &header[..3],
        &[
            "bottom_hoe.height_mm",
            "top_hoe.height_mm",
            "fov_vertical_deg"
        ]
    );
    for col in [
        "fov_horizontal_min_limited_by",
        "replicas_above_5pct",
        "replicas_total",
        "replica_pitch_mm",
        "replica_pitch_sensor_px",
        "efficiency_crop_mean",
        "bragg_min_nm",
        "bragg_max_nm",
    ] {
        assert!(header.contains(&col), "{col} not in {header:?}");
    }
    assert!(!header.contains(&"psnr_db"));
    assert!(lines[3].starts_with("50,15,"), "{}", lines[3]);
    // JSON: version, settings, definitions and the rows.
    let json: serde_json::Value =
        serde_json::from_slice(file(&one.files, "sweep.json")).expect("json");
    assert_eq!(json["stscam_version"], stscam::VERSION);
    assert_eq!(json["settings"]["fov_fraction"], 0.1);
    assert!(json["definitions"]["field_response"].as_str().is_some());
    assert_eq!(json["rows"].as_array().map(Vec::len), Some(4));
    assert_eq!(json["rows"][2]["varied"][0]["value"], 50.0);
    assert_eq!(json["axes"][1]["values"], serde_json::json!([15.0, 20.0]));
    // Plots: against the first key with its unit, one series per value of the second.
    let svg = String::from_utf8(file(&one.files, "fov.svg").to_vec()).expect("utf-8");
    assert!(svg.contains("bottom_hoe.height_mm (mm)"), "x label");
    assert!(svg.contains("vertical, top_hoe.height_mm=15"), "series");
    assert!(svg.contains("horizontal, top_hoe.height_mm=20"), "series");
}

/// The sweep's PSNR is the demo's: same H, capture seed, noise streams and ADMM-TV, so on the
/// demo's first target (letter:A) it equals the demo's "ADMM-TV, H true" entry exactly.
#[test]
fn psnr_follows_the_demo_protocol() {
    let base = ["sensor.crop_px=48", "display.image=letter:F@32"];
    let sys = system(&base);
    let p = PsnrSettings {
        target: "letter:A".into(),
        spp: 2,
        seed: 7,
    };
    let psnr = stscam::sweep::psnr_figure(&sys, &p, false).expect("psnr");
    let demo = stscam::demo::run_demo(
        &sys,
        &stscam::demo::DemoSettings {
            spp: 2,
            seed: 7,
            cg: stscam::recon::cg::CgSettings {
                iters: stscam::recon::cg::DEFAULT_CG_ITERS,
                tol: 0.0,
            },
            admm: stscam::recon::admm::AdmmSettings::default(),
            progress: false,
        },
    )
    .expect("demo");
    let row = demo
        .rows
        .iter()
        .find(|r| r.target == "glyph" && r.matrix == "true" && r.method == "admm-tv")
        .expect("row");
    assert_eq!(row.spec, "letter:A@32");
    assert_eq!(
        psnr.to_bits(),
        row.psnr_db.to_bits(),
        "{psnr} vs {}",
        row.psnr_db
    );
    assert!(psnr.is_finite() && psnr > 5.0, "{psnr}");
    // Through run_sweep: one PSNR per point, a psnr plot and CSV column.
    let set = SweepSettings {
        psnr: Some(p),
        grid: coarse(),
        ..Default::default()
    };
    let base: Vec<String> = base.iter().map(|s| s.to_string()).collect();
    let out = run_sweep(None, &base, &[axis("camera.distance_mm=32:32:1")], &set).expect("sweep");
    assert_eq!(
        out.rows[0].figures.psnr_db.map(f64::to_bits),
        Some(psnr.to_bits())
    );
    assert!(out.files.iter().any(|f| f.0 == "psnr.png"));
    let csv = String::from_utf8(file(&out.files, "sweep.csv").to_vec()).expect("utf-8");
    assert!(
        csv.lines()
            .next()
            .is_some_and(|h| h.ends_with(",psnr_db,psnr_nominal_h_db"))
    );
}

#[test]
fn cli_refuses_bad_axes_and_values_with_one_line_and_writes_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("sweep");
    for (vary, expect) in [
        ("plate.thickness_mm=-1:1:3", "plate.thickness_mm"),
        ("bottom_hoe.height_mm", "KEY=START:STOP:STEPS"),
        ("no.such_key=1:2:2", "no.such_key"),
    ] {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_stscam"))
            .args([
                "sweep",
                "--vary",
                vary,
                "--out",
                out.to_str().expect("utf-8"),
            ])
            .output()
            .expect("run stscam");
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{vary}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains(expect), "{err}");
        assert!(!out.exists());
    }
}

/// `stscam sweep` prints the captured FOV beside the waveguide's, the same numbers as the
/// JSON rows (it printed only the waveguide's, which a crop can make much larger).
#[test]
fn sweep_prints_the_captured_fov_beside_the_waveguides() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s");
    let o = out.to_str().unwrap();
    let args = [
        "sweep",
        "--vary",
        "top_hoe.height_mm=8:24:2",
        "--set",
        "sensor.crop_px=[96,96]",
    ];
    let text = crate::common::stscam_ok(&[&args[..], &["--out", o]].concat());
    let json = crate::common::stscam_ok(&[&args[..], &["--json", "--out", o]].concat());
    let rows: serde_json::Value = serde_json::from_str(&json).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 2, "{text}");
    for (line, row) in lines.iter().zip(rows.as_array().unwrap()) {
        let deg = |k: &str| row[k]["full_deg"].as_f64().unwrap();
        let captured = format!(
            "FOV captured {:.2}° x {:.2}°, waveguide {:.2}° x {:.2}° (V x H)",
            deg("fov_vertical_capture"),
            deg("fov_horizontal_capture"),
            deg("fov_vertical"),
            deg("fov_horizontal")
        );
        assert!(line.contains(&captured), "{line}\nwants {captured}");
        // The 96-pixel crop sees less than the waveguide passes: the two numbers differ.
        assert!(
            deg("fov_vertical_capture") < deg("fov_vertical") - 1.0,
            "{line}"
        );
    }
}
