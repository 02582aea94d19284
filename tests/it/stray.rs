//! Every path light can take (`stscam::stray`): energy closes per camera ray, Russian roulette
//! leaves the mean unchanged, the designed paths it finds are `render`'s image, a plain plate's
//! first ghost sits where geometry puts it with the Fresnel closed form's power, and a
//! cross-coupled order leaves in the direction k-closure gives. Each check states its
//! tolerance and shows a wrong input failing it.

use glam::{DVec2, DVec3};

use stscam::optics::interface::lateral_shift;
use stscam::render::{RenderSettings, render};
use stscam::sampler::PathRng;
use stscam::stray::classes::{self, SIGNAL};
use stscam::stray::image::{StraySettings, stray_images};
use stscam::stray::paths::{Event, Face, Ledger, PathSettings, Sink, Surround, trace_all_paths};
use stscam::system::{System, repo_system};

/// No roulette: every branch above 1e-13 of the camera ray's weight followed (what is below
/// is accounted in the `cutoff` sink), no practical event limit.
const EXACT: PathSettings = PathSettings {
    roulette_threshold: 0.0,
    cutoff_weight: 1e-13,
    max_events: 100_000,
};

/// Sum per polarisation of every exit's weight and every sink's.
fn closure(
    sys: &System,
    surround: Surround,
    ray: (DVec3, DVec3, f64),
    set: PathSettings,
    seed: u64,
) -> ([f64; 2], Ledger) {
    let mut exits = [0.0; 2];
    let mut rng = PathRng::new(&[seed]);
    let ledger = trace_all_paths(&sys.waveguide, surround, set, ray, &mut rng, |e| {
        exits[0] += e.weight[0];
        exits[1] += e.weight[1];
    });
    let mut sum = exits;
    for s in Sink::ALL {
        let w = ledger.get(s);
        sum[0] += w[0];
        sum[1] += w[1];
    }
    (sum, ledger)
}

/// Camera rays of `sys` spread over the image and the lens, at wavelengths over the band.
fn rays(sys: &System, n: usize) -> Vec<(DVec3, DVec3, f64)> {
    let mut state = 99u64;
    let mut next = || {
        state = stscam::sampler::mix64(state);
        stscam::sampler::to_unit(state)
    };
    (0..n)
        .map(|_| {
            let r = sys.camera.generate_ray(
                (next() * sys.camera.width_px as f64) as usize,
                (next() * sys.camera.height_px as f64) as usize,
                [next(), next()],
                [next(), next()],
            );
            (r.origin, r.dir, 420.0 + 240.0 * next())
        })
        .collect()
}

/// Per camera ray, the display's share and every sink's sum to 1 within 1e-12 (TE and TM), on
/// the paper camera, uncovered, with the RGB multiplex film (cross-coupling included), with a
/// film haze of 0.1 and with polished edges. The
/// camera side's share is above 1e-3 on every design, so a ledger that forgot it would fail.
#[test]
fn energy_closes_per_camera_ray() {
    // Haze and polished edges make far larger trees: a coarser cutoff (still accounted in the
    // ledger, so the sum is exact) and fewer rays.
    let coarse = PathSettings {
        cutoff_weight: 1e-8,
        ..EXACT
    };
    for (scene, sets, set, n) in [
        ("scenes/paper-2022.toml", &[][..], EXACT, 300),
        (
            "scenes/paper-2022.toml",
            &["top_hoe.covered=false"][..],
            EXACT,
            300,
        ),
        ("scenes/rgb-multiplex.toml", &[][..], EXACT, 300),
        (
            "scenes/paper-2022.toml",
            &["hoe.haze_fraction=0.1"][..],
            coarse,
            40,
        ),
        (
            "scenes/paper-2022.toml",
            &["plate.edges=polished"][..],
            coarse,
            40,
        ),
    ] {
        let sys = repo_system(scene, sets);
        let surround = stscam::stray::image::surround(&sys);
        let mut camera_side = 0.0f64;
        for ray in rays(&sys, n) {
            let (sum, ledger) = closure(&sys, surround, ray, set, 1);
            for p in 0..2 {
                assert!(
                    (sum[p] - 1.0).abs() <= 1e-12,
                    "{scene} {sets:?}: energy {} (pol {p}) for ray {ray:?}",
                    sum[p]
                );
            }
            assert_eq!(ledger.get(Sink::Roulette), [0.0, 0.0]);
            camera_side = camera_side.max(ledger.get(Sink::CameraSide)[0]);
        }
        assert!(camera_side > 1e-3, "{scene}: camera side {camera_side}");
    }
}

/// Russian roulette is unbiased: over 400 seeds, the mean weight reaching the display with a
/// threshold of 0.02 (most branches play) is within 4 standard errors of the exact tree's,
/// on a ray through the top vHOE. Truncating at 6 events instead (a biased estimator) is
/// outside that band, so the test can fail.
#[test]
fn roulette_leaves_the_mean_unchanged() {
    let sys = repo_system("scenes/paper-2022.toml", &["top_hoe.covered=false"]);
    let r = sys
        .camera
        .chief_ray(sys.camera.width_px / 2, sys.camera.height_px / 2);
    let lb = sys
        .waveguide
        .gratings
        .film()
        .bragg_wavelength_nm(-r.dir.truncate());
    let ray = (r.origin, r.dir, lb.unwrap_or(532.0));
    let exits = |set: PathSettings, seed: u64| -> f64 {
        let mut sum = 0.0;
        let mut rng = PathRng::new(&[seed, 7]);
        trace_all_paths(
            &sys.waveguide,
            Surround::front(sys.display.z_mm),
            set,
            ray,
            &mut rng,
            |e| sum += e.weight[0],
        );
        sum
    };
    let exact = exits(EXACT, 0);
    let roulette = PathSettings {
        roulette_threshold: 0.02,
        ..EXACT
    };
    let n = 400;
    let xs: Vec<f64> = (0..n).map(|s| exits(roulette, s)).collect();
    let mean = xs.iter().sum::<f64>() / n as f64;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let se = (var / n as f64).sqrt();
    assert!(var > 0.0, "the roulette never played");
    assert!(
        (mean - exact).abs() <= 4.0 * se,
        "roulette mean {mean} vs exact {exact} (se {se})"
    );
    let truncated = exits(
        PathSettings {
            max_events: 6,
            ..EXACT
        },
        0,
    );
    assert!(
        (truncated - exact).abs() > 4.0 * se,
        "truncation {truncated} vs exact {exact} (se {se}): the test cannot tell a bias"
    );
}

/// Fresnel reflectance [R_s, R_p] from the angles (Born & Wolf §1.5.2, written out here
/// independently of `optics::interface`).
fn fresnel_r(n1: f64, n2: f64, theta1: f64) -> [f64; 2] {
    let s2 = n1 / n2 * theta1.sin();
    let theta2 = s2.asin();
    let rs = (theta1 - theta2).sin() / (theta1 + theta2).sin();
    let rp = (theta1 - theta2).tan() / (theta1 + theta2).tan();
    [rs * rs, rp * rp]
}

/// A plain plate (no index modulation, no cover): the first ghost of a camera ray leaves the
/// front face 2w·tanθ_t from the direct ray (to 1e-12 mm) with weight T_back·R_front·R_back·
/// T_front·e^{−3αw/cosθ_t} of the Fresnel closed form (relative 1e-12; the issue asks 1 %).
/// The same closed form with the glass index off by 0.05 misses by more than 1 %.
#[test]
fn plain_plate_ghost_is_where_geometry_puts_it_with_fresnel_power() {
    let sys = repo_system(
        "scenes/paper-2022.toml",
        &["hoe.index_modulation=0", "top_hoe.covered=false"],
    );
    let wg = &sys.waveguide;
    let w = wg.thickness_mm;
    for (theta_deg, phi_deg) in [(5.0f64, 90.0f64), (20.0, 30.0), (35.0, -120.0)] {
        let (t, ph) = (theta_deg.to_radians(), phi_deg.to_radians());
        let dir = DVec3::new(t.sin() * ph.cos(), t.sin() * ph.sin(), -t.cos());
        // 1 mm behind the back face, far from both vHOEs (y = 70 mm).
        let origin = DVec3::new(0.0, 70.0, w) - dir * (1.0 / t.cos());
        let lambda = 550.0;
        let mut direct = None;
        let mut ghost = None;
        let mut rng = PathRng::new(&[1]);
        trace_all_paths(
            wg,
            Surround::front(sys.display.z_mm),
            EXACT,
            (origin, dir, lambda),
            &mut rng,
            |e| {
                let mut tokens = Vec::new();
                classes::fold(e.events, e.source, &mut tokens);
                let name = classes::name(&tokens);
                if name == SIGNAL {
                    direct = Some((e.exit_point_mm, e.weight));
                } else if name == "T(back) R(front) R(back) T(front)" {
                    ghost = Some((e.exit_point_mm, e.weight));
                }
            },
        );
        let (pd, wd) = direct.expect("direct branch");
        let (pg, wgh) = ghost.expect("first ghost");
        let n = wg.n_glass(lambda);
        let theta_t = (t.sin() / n).asin();
        let offset = 2.0 * w * theta_t.tan();
        let along = DVec2::new(ph.cos(), ph.sin());
        assert!(
            (pg - pd - along * offset).length() <= 1e-12,
            "ghost offset {:?} vs 2w tan θt = {offset} along {along:?}",
            pg - pd
        );
        let alpha = wg.absorption_per_mm(lambda);
        let cross = (-alpha * w / theta_t.cos()).exp();
        let closed = |n: f64| -> [f64; 2] {
            let r_out = fresnel_r(1.0, n, t);
            let r_in = fresnel_r(n, 1.0, (t.sin() / n).asin());
            [0, 1].map(|p| (1.0 - r_out[p]) * r_in[p] * r_in[p] * (1.0 - r_in[p]) * cross.powi(3))
        };
        let want = closed(n);
        for p in 0..2 {
            assert!(
                (wgh[p] / want[p] - 1.0).abs() <= 1e-12,
                "θ {theta_deg}: ghost weight {} vs closed form {}",
                wgh[p],
                want[p]
            );
            let wrong = closed(n - 0.05);
            assert!((wgh[p] / wrong[p] - 1.0).abs() > 0.01);
        }
        // The direct branch is T·T with one crossing.
        let r_out = fresnel_r(1.0, n, t);
        assert!((wd[0] / ((1.0 - r_out[0]).powi(2) * cross) - 1.0).abs() <= 1e-12);
    }
}

/// The designed paths the branching tracer finds are `render`'s image: its `signal` class
/// equals the capture pixel for pixel (within 2e-7 of the peak: both images are stored as
/// float32; per camera ray the two tracers agree to 1.4e-12 in weight over 3000 random rays),
/// on the paper camera with a 24 × 24 crop at 8 spp; the classes it
/// adds are not empty (their total is above 1e-4 of the signal's), so a tracer that called
/// every path signal would fail the first comparison.
#[test]
fn signal_class_is_the_render() {
    let sys = repo_system("scenes/paper-2022.toml", &["sensor.crop_px=[24,24]"]);
    let set = StraySettings {
        spp: 8,
        seed: 3,
        paths: EXACT,
        progress: false,
    };
    let st = stray_images(&sys, &set);
    let cap = render(&sys, &RenderSettings::lattice(8, 3, false));
    let signal = &st.classes[0];
    assert_eq!(signal.name, SIGNAL);
    let img = signal.image.as_ref().expect("signal image");
    let peak = cap.channels[0].iter().fold(0.0f32, |a, &b| a.max(b)) as f64;
    assert!(peak > 0.0);
    let mut worst = 0.0f64;
    for (a, b) in img[0].iter().zip(&cap.channels[0]) {
        worst = worst.max((f64::from(*a) - f64::from(*b)).abs());
    }
    assert!(
        worst <= 2e-7 * peak,
        "signal vs render: {worst} of peak {peak}"
    );
    let stray: f64 = st.classes[1..].iter().map(|c| c.total).sum();
    assert!(
        stray > 1e-4 * signal.total,
        "stray {stray} vs signal {}",
        signal.total
    );
    // Every image row's signal sum matches the render's row sums too.
    let w = cap.width;
    for (r, s) in signal.row_sums.iter().enumerate() {
        let want: f64 = cap.channels[0][r * w..(r + 1) * w]
            .iter()
            .map(|&v| f64::from(v))
            .sum();
        assert!((s - want).abs() <= 2e-7 * peak * w as f64);
    }
}

/// Cross-coupling in the two-grating film: a path coupled out at the top vHOE by grating j and
/// in at the bottom vHOE by grating k ≠ j leaves in the direction k-closure gives,
/// u_out = u + (λ/2π)(K_k − K_j)_t for the importance ray (to 1e-12), and the designed path
/// (j = k) leaves parallel to the camera ray (the periscope), which the cross-coupled one does
/// not (their directions differ by more than 1e-3).
#[test]
fn cross_coupled_orders_follow_k_closure() {
    let sys = repo_system("scenes/two-grating.toml", &["top_hoe.covered=false"]);
    let wg = &sys.waveguide;
    assert!(wg.gratings.len() >= 2);
    let mut found = 0;
    for ray in rays(&sys, 400) {
        let (origin, dir, lambda) = ray;
        let mut rng = PathRng::new(&[5]);
        let v_in = dir.truncate();
        trace_all_paths(
            wg,
            Surround::front(sys.display.z_mm),
            EXACT,
            ray,
            &mut rng,
            |e| {
                let ds: Vec<(Face, u8)> = e
                    .events
                    .iter()
                    .filter_map(|ev| match *ev {
                        Event::D { face, grating, .. } => Some((face, grating)),
                        _ => None,
                    })
                    .collect();
                let [(Face::Front, j), (Face::Back, k)] = ds[..] else {
                    return;
                };
                // The exit direction from the air leg to the display.
                let leg = e.object_point_mm - e.exit_point_mm;
                let h = -sys.display.z_mm;
                let v_out = leg / (h * h + leg.length_squared()).sqrt();
                let shift = |g: u8| wg.gratings.get(usize::from(g)).u_shift(lambda);
                let want = v_in + shift(j) - shift(k);
                assert!(
                    (v_out - want).length() <= 1e-12,
                    "j {j} k {k}: {v_out:?} vs {want:?}"
                );
                if j != k {
                    assert!((v_out - v_in).length() > 1e-3);
                    found += 1;
                }
                // lateral_shift of the air leg is the direction's tangent: consistent geometry.
                assert!((lateral_shift(v_out, 1.0, h) - leg).length() <= 1e-9 * h);
            },
        );
        let _ = origin;
    }
    assert!(found > 0, "no cross-coupled path found");
}

/// `stscam stray` writes its report: stray.json with the signal first (fraction 1, peak ratio
/// 1) and every class's name, events, fraction of the signal and peak ratio, the fractions
/// summing to 1 + the stray fraction; the same seed gives the same JSON figures with 1 and 2
/// threads; class images as EXR and PNG; bad numbers, a 3-D scene and an --out that is a file
/// are refused with exit 2 and nothing written.
#[test]
fn stray_command_writes_the_report() {
    use crate::common::{stscam, write};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let run = |out: &str, threads: &str| {
        let out = d.join(out);
        let o = stscam(&[
            "stray",
            "--set",
            "sensor.crop_px=[32,32]",
            "--spp",
            "2",
            "--threads",
            threads,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let text = std::fs::read_to_string(out.join("stray.json")).unwrap();
        (
            out,
            serde_json::from_str::<serde_json::Value>(&text).unwrap(),
        )
    };
    let (out, j) = run("a", "2");
    let classes = j["classes"].as_array().unwrap();
    assert_eq!(classes[0]["name"], SIGNAL);
    assert_eq!(classes[0]["fraction_of_signal"].as_f64(), Some(1.0));
    assert_eq!(classes[0]["peak_ratio"].as_f64(), Some(1.0));
    let mut sum = 0.0;
    for c in classes {
        for key in [
            "name",
            "events",
            "fraction_of_signal",
            "peak_ratio",
            "row_fraction",
        ] {
            assert!(!c[key].is_null(), "{key} missing in {c}");
        }
        sum += c["fraction_of_signal"].as_f64().unwrap();
    }
    let stray = j["stray_fraction_of_signal"].as_f64().unwrap();
    assert!(stray > 0.0 && stray < 0.1, "stray {stray}");
    assert!((sum - 1.0 - stray).abs() <= 1e-9 * sum);
    assert!(out.join("class_00_signal.exr").is_file());
    assert!(out.join("class_00_signal.png").is_file());
    assert!(out.join("class_01.png").is_file());
    assert!(out.join("stray.md").is_file() && out.join("stray.png").is_file());
    // all_paths.exr is every class together: its sum is the classes' totals' (float32 images).
    let (_, _, chans) = stscam::io::exr::read_exr(&out.join("all_paths.exr")).unwrap();
    let all: f64 = chans[0].data.iter().map(|&v| f64::from(v)).sum();
    let classes_total: f64 = classes.iter().map(|c| c["total"].as_f64().unwrap()).sum();
    assert!(
        (all / classes_total - 1.0).abs() <= 1e-5,
        "all_paths {all} vs classes {classes_total}"
    );
    let (_, _, sig) = stscam::io::exr::read_exr(&out.join("class_00_signal.exr")).unwrap();
    let signal: f64 = sig[0].data.iter().map(|&v| f64::from(v)).sum();
    assert!(
        all > signal * (1.0 + 0.5 * stray),
        "{all} vs signal {signal}"
    );
    let (_, one) = run("b", "1");
    for k in ["classes", "stray_fraction_of_signal", "importance_per_ray"] {
        assert_eq!(one[k], j[k], "{k} differs with 1 thread");
    }
    // Refusals.
    let file = write(d, "file", "x");
    let scene3d = write(
        d,
        "s3d.toml",
        "[[object]]\nmesh = \"sphere\"\nscale = 100\nposition_mm = [0, 0, -500]\n",
    );
    for (args, needle) in [
        (vec!["--roulette", "2"], "--roulette"),
        (vec!["--roulette", "nan"], "--roulette"),
        (vec!["--max-events", "0"], "--max-events"),
        (vec!["--spp", "0"], "--spp"),
        (vec!["--out", file.to_str().unwrap()], "--out"),
        (vec![scene3d.to_str().unwrap()], "display scenes only"),
    ] {
        let target = d.join("refused");
        let mut a = vec!["stray"];
        if args[0] != "--out" {
            a.extend(["--out", target.to_str().unwrap()]);
        }
        a.extend(args.iter().copied());
        let o = stscam(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{a:?}: {err}");
        assert!(err.contains(needle), "{a:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{a:?}: {err}");
        assert!(!target.exists());
    }
}

/// `evaluate --metrics stray_percent` is `stscam stray`'s total at the same crop, spp and seed
/// (one replicate, no binning: equal to 1e-12 relative; with two replicates it carries an
/// error), a quantile of it and a 3-D scene are refused (exit 2). A scene without the cover
/// reports more stray light than the paper's, so the metric can tell designs apart.
#[test]
fn evaluate_stray_percent_is_the_stray_total() {
    use crate::common::{stscam, stscam_json, write};
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s");
    let crop = "sensor.crop_px=[40,40]";
    let o = stscam(&[
        "stray",
        "--set",
        crop,
        "--spp",
        "2",
        "--seed",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("stray.json")).unwrap()).unwrap();
    let want = 100.0 * j["stray_fraction_of_signal"].as_f64().unwrap();
    let eval = |extra: &[&str], reps: &str| {
        let mut a = vec![
            "evaluate",
            "--metrics",
            "stray_percent",
            "--json",
            "--set",
            crop,
            "--binning",
            "1",
            "--spp",
            "2",
            "--seed",
            "1",
            "--replicates",
            reps,
        ];
        a.extend_from_slice(extra);
        stscam_json(&a)
    };
    let one = eval(&[], "1");
    let got = one["stray_percent"].as_f64().unwrap();
    assert!(
        (got / want - 1.0).abs() <= 1e-12,
        "evaluate {got} vs stray {want}"
    );
    let two = eval(&[], "2");
    assert!(two["stray_percent_error"].as_f64().unwrap() > 0.0);
    let open = eval(&["--set", "top_hoe.covered=false"], "1");
    assert!(open["stray_percent"].as_f64().unwrap() > 2.0 * got);
    let scene3d = write(
        dir.path(),
        "s3d.toml",
        "[[object]]\nmesh = \"sphere\"\nscale = 100\nposition_mm = [0, 0, -500]\n",
    );
    for args in [
        vec![
            "evaluate",
            "--metrics",
            "stray_percent_q05",
            "--draw",
            "hoe.shrinkage=normal(0,0.01)",
        ],
        vec![
            "evaluate",
            scene3d.to_str().unwrap(),
            "--metrics",
            "stray_percent",
        ],
    ] {
        let o = stscam(&args);
        assert_eq!(
            o.status.code(),
            Some(2),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
}

/// The display behind the screen (`[behind_display]`): its light reaches the camera through the
/// gratings (classes ending in `display-behind` with a diffraction) and through Fresnel
/// reflections; with the index modulation at 0 only the Fresnel ghosts are left (no class of
/// it holds a diffraction, and they are not empty); disabled, it adds nothing. Energy still
/// closes per ray with it on (its share counts as reaching a source).
#[test]
fn display_behind_the_screen() {
    let base = [
        "sensor.crop_px=[24,24]",
        "behind_display.enabled=true",
        "behind_display.size_mm=[200,200]",
    ];
    let set = StraySettings {
        spp: 4,
        seed: 1,
        paths: PathSettings::default(),
        progress: false,
    };
    let behind = |extra: &[&str]| {
        let mut sets = base.to_vec();
        sets.extend_from_slice(extra);
        let sys = repo_system("scenes/paper-2022.toml", &sets);
        let st = stray_images(&sys, &set);
        st.classes
            .into_iter()
            .filter(|c| c.name.ends_with("display-behind"))
            .map(|c| (c.name, c.total))
            .collect::<Vec<_>>()
    };
    let on = behind(&[]);
    assert!(
        on.iter().any(|(n, t)| n.contains("D(") && *t > 0.0),
        "no diffracted display-behind class: {on:?}"
    );
    let plain = behind(&["hoe.index_modulation=0"]);
    assert!(!plain.is_empty() && plain.iter().all(|(_, t)| *t > 0.0));
    for (n, _) in &plain {
        assert!(!n.contains("D(") && !n.contains("Dt("), "{n} with n1 = 0");
    }
    let off = behind(&["behind_display.enabled=false"]);
    assert!(off.is_empty(), "{off:?}");
    let sys = repo_system("scenes/paper-2022.toml", &base);
    let sources = stscam::stray::image::surround(&sys);
    for ray in rays(&sys, 100) {
        let mut sum = [0.0; 2];
        let mut rng = PathRng::new(&[2]);
        let ledger = trace_all_paths(&sys.waveguide, sources, EXACT, ray, &mut rng, |e| {
            sum[0] += e.weight[0];
            sum[1] += e.weight[1];
        });
        for s in Sink::ALL {
            sum[0] += ledger.get(s)[0];
            sum[1] += ledger.get(s)[1];
        }
        assert!(
            (sum[0] - 1.0).abs() <= 1e-12 && (sum[1] - 1.0).abs() <= 1e-12,
            "{sum:?}"
        );
    }
}

/// Polished plate edges (`plate.edges = "polished"`): guided light that passes the bottom
/// vHOE reflects at the plate's edges and comes back. Geometry by unfolding: the guided wave's
/// back-face contacts on the unbounded plate are c_j = p_top + (2j − 1)·s_g (s_g its shift per
/// crossing); the edges y = y0 and y = y1 fold them into the plate (a triangle wave of period
/// 2(y1 − y0)), each fold flipping the wave's v_y; the replica coupled in there by order m
/// leaves along v_g' − m·(λ/2π)K_t, across the plate. Every returning replica of the chief ray
/// (5 nm off its Bragg wavelength, where the bottom vHOE leaves light to return) leaves the
/// front face and meets the display where that predicts (1e-9 mm), with as many edge events as
/// folds; replicas return after the bottom edge and after the bottom and the top edge (weight
/// > 1e-6 each); with absorbing edges no path meets an edge.
#[test]
fn polished_edges_return_replicas_where_geometry_puts_them() {
    let sets = [
        "plate.edges=polished",
        "plate.size_mm=[100,120]",
        "plate.center_mm=[0,10]",
    ];
    let sys = repo_system("scenes/paper-2022.toml", &sets);
    let wg = &sys.waveguide;
    let surround = stscam::stray::image::surround(&sys);
    let (y0, y1) = (10.0 - 60.0, 10.0 + 60.0);
    let r = sys
        .camera
        .chief_ray(sys.camera.width_px / 2, sys.camera.height_px / 2);
    let lb = wg
        .gratings
        .film()
        .bragg_wavelength_nm(-r.dir.truncate())
        .unwrap();
    let lambda = lb + 5.0;
    let (n, w) = (wg.n_glass(lambda), wg.thickness_mm);
    let v = r.dir.truncate();
    let shift = wg.gratings.film().u_shift(lambda);
    let p_back = r.origin.truncate() + r.dir.truncate() * ((r.origin.z - w) / -r.dir.z);
    let p_top = p_back + lateral_shift(v, n, w);
    let v_g = v + shift;
    let s_g = lateral_shift(v_g, n, w);
    // Folds y into [y0, y1]: the folded y and the number of edge reflections.
    let fold = |y: f64| -> (f64, i64) {
        let l = y1 - y0;
        let k = ((y - y0) / l).floor() as i64;
        let t = (y - y0).rem_euclid(2.0 * l);
        let yf = if t <= l { y0 + t } else { y0 + 2.0 * l - t };
        (yf, k.abs())
    };
    let (mut by_bottom, mut by_top) = (0.0f64, 0.0f64);
    let mut rng = PathRng::new(&[3]);
    trace_all_paths(
        wg,
        surround,
        EXACT,
        (r.origin, r.dir, lambda),
        &mut rng,
        |e| {
            let mut tokens = Vec::new();
            classes::fold(e.events, e.source, &mut tokens);
            let name = classes::name(&tokens);
            let Some(rest) = name.strip_prefix("T(back) D(top,g1,-1) TIR×n edge(") else {
                return;
            };
            let edges = name.matches("edge(").count() as i64;
            let m: f64 = if rest.ends_with("D(bottom,g1,+1) T(front)") {
                1.0
            } else if rest.ends_with("D(bottom,g1,-1) R(back) T(front)")
                || rest.ends_with("D(bottom,g1,-1) T(front)")
            {
                -1.0
            } else {
                return;
            };
            // Only the guided wave between the two films: TIR runs and edges.
            let middle = &tokens[2..tokens.len()
                - if m < 0.0 && name.contains("R(back) T(front)") {
                    3
                } else {
                    2
                }];
            if !middle.iter().all(|t| {
                matches!(
                    t,
                    classes::Token::TirRun | classes::Token::Event(Event::Edge(_))
                )
            }) {
                return;
            }
            let found = (1..2000).any(|j| {
                let c = p_top + s_g * (2 * j - 1) as f64;
                let (yf, k) = fold(c.y);
                if k != edges {
                    return false;
                }
                let vy = if k % 2 == 1 { -v_g.y } else { v_g.y };
                let v_out = DVec2::new(v_g.x, vy) - shift * m;
                let exit = DVec2::new(c.x, yf) + lateral_shift(v_out, n, w);
                let object = exit + lateral_shift(v_out, 1.0, -sys.display.z_mm);
                (exit - e.exit_point_mm).length() <= 1e-9
                    && (object - e.object_point_mm).length() <= 1e-9
            });
            assert!(
                found,
                "{name}: exit {:?} is no folded contact's",
                e.exit_point_mm
            );
            let wt = e.weight[0].max(e.weight[1]);
            if edges == 1 {
                by_bottom = by_bottom.max(wt);
            } else if edges == 2 {
                by_top = by_top.max(wt);
            }
        },
    );
    assert!(
        by_bottom > 1e-6,
        "no replica returned by the bottom edge ({by_bottom})"
    );
    assert!(
        by_top > 1e-6,
        "no replica returned by the bottom and the top edge ({by_top})"
    );
    // Absorbing edges: no path meets an edge.
    let absorbing = repo_system("scenes/paper-2022.toml", &["plate.size_mm=[100,120]"]);
    let mut rng = PathRng::new(&[3]);
    let s2 = stscam::stray::image::surround(&absorbing);
    let ray = (r.origin, r.dir, lambda);
    trace_all_paths(&absorbing.waveguide, s2, EXACT, ray, &mut rng, |e| {
        assert!(!e.events.iter().any(|ev| matches!(ev, Event::Edge(_))));
    });
}

/// Film haze (`hoe.haze_fraction`): scattered paths form their own classes (`S(top)`,
/// `S(bottom)`), the signal loses light to them, and a clear film has none.
#[test]
fn film_haze_scatters_out_of_the_designed_path() {
    let run = |haze: &str| {
        let sys = repo_system(
            "scenes/paper-2022.toml",
            &[
                "sensor.crop_px=[24,24]",
                &format!("hoe.haze_fraction={haze}"),
            ],
        );
        stray_images(
            &sys,
            &StraySettings {
                spp: 4,
                seed: 1,
                paths: PathSettings::default(),
                progress: false,
            },
        )
    };
    let clear = run("0");
    let hazy = run("0.05");
    let scattered = |st: &stscam::stray::image::StrayImages| -> f64 {
        st.classes
            .iter()
            .filter(|c| c.name.contains("S("))
            .map(|c| c.total)
            .sum()
    };
    assert_eq!(scattered(&clear), 0.0);
    assert!(scattered(&hazy) > 1e-3 * hazy.classes[0].total);
    assert!(hazy.classes[0].total < clear.classes[0].total);
}
