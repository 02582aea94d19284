//! Multiplexed vHOEs (`[[hoe.grating]]`): the one-grating list is the old single-grating keys
//! byte for byte, the scene errors name file and key, and a two-grating film renders each
//! grating's replicas where the deterministic chief-ray trace (`probe`/`info`) puts them, each
//! in its own band.

use std::path::Path;

use stscam::analysis::{PointReplica, point_replicas};
use stscam::render::{RenderSettings, render};
use stscam::scene::load_scene;
use stscam::system::System;

use crate::common::{stscam, stscam_json, stscam_ok, write};

/// The paper's grating as a one-entry `[[hoe.grating]]` list (n1 given as text).
fn one_grating_scene(n1: &str) -> String {
    format!(
        "[hoe]\nfilm_thickness_um = 16.0\nmean_index = 1.50\n\n[[hoe.grating]]\n\
         recording_wavelength_nm = 532.0\nreference_angle_deg = 61.2\nindex_modulation = {n1}\n"
    )
}

/// A one-grating `[[hoe.grating]]` list renders and builds H exactly as the single-grating
/// keys do (capture.exr and H.npz byte for byte); a list whose n1 differs in the fourth digit
/// (0.01501) does not, so the comparison can fail.
#[test]
fn one_grating_list_equals_the_single_grating_keys_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let same = write(d, "same.toml", &one_grating_scene("0.015"));
    let off = write(d, "off.toml", &one_grating_scene("0.01501"));
    let sets = [
        "--set",
        "sensor.crop_px=[40,40]",
        "--set",
        "display.image=letter:F",
    ];
    let render_to = |scene: Option<&Path>, name: &str| -> Vec<u8> {
        let out = d.join(name);
        let mut args = vec!["render"];
        let s;
        if let Some(p) = scene {
            s = p.display().to_string();
            args.push(&s);
        }
        let o = out.display().to_string();
        args.extend(["--spp", "8", "--out", &o]);
        args.extend(sets);
        stscam_ok(&args);
        std::fs::read(out.join("capture.exr")).unwrap()
    };
    let keys = render_to(None, "keys");
    assert!(
        keys == render_to(Some(&same), "list"),
        "capture.exr differs"
    );
    assert!(
        keys != render_to(Some(&off), "off"),
        "n1 0.01501 gives the same capture"
    );
    let matrix_of = |scene: Option<&Path>, name: &str| -> Vec<u8> {
        let out = d.join(name);
        let mut args = vec!["matrix"];
        let s;
        if let Some(p) = scene {
            s = p.display().to_string();
            args.push(&s);
        }
        let o = out.display().to_string();
        args.extend(["--spp", "4", "--out", &o]);
        args.extend(sets);
        stscam_ok(&args);
        std::fs::read(out.join("H.npz")).unwrap()
    };
    let h = matrix_of(None, "hkeys");
    assert!(h == matrix_of(Some(&same), "hlist"), "H.npz differs");
    assert!(
        h != matrix_of(Some(&off), "hoff"),
        "n1 0.01501 gives the same H"
    );
}

/// Errors: both forms at once, a bad entry, too many gratings and `--set` on the wrong form
/// each give exit code 2 and one line naming the file (or `--set KEY`) and the key; `--set`
/// reaches a grating entry by index.
#[test]
fn grating_list_errors_name_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let fail = |args: &[&str]| -> String {
        let out = stscam(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8(out.stderr).unwrap();
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        err.trim_end().to_string()
    };
    let both = write(
        d,
        "both.toml",
        &format!(
            "{}",
            one_grating_scene("0.015").replace(
                "mean_index = 1.50\n",
                "mean_index = 1.50\nindex_modulation = 0.01\n"
            )
        ),
    );
    let e = fail(&["info", both.to_str().unwrap()]);
    assert!(
        e.contains(&format!(
            "{}: hoe.index_modulation: give either [[hoe.grating]]",
            both.display()
        )),
        "{e}"
    );
    let two = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/two-grating.toml"),
    )
    .unwrap();
    let bad = write(
        d,
        "bad.toml",
        &two.replacen("index_modulation = 0.0075", "index_modulation = 0.0075", 1)
            .replace("reference_angle_deg = 55.0", "reference_angle_deg = 95.0"),
    );
    let e = fail(&["info", bad.to_str().unwrap()]);
    assert!(
        e.contains(&format!(
            "{}: hoe.grating[1].reference_angle_deg: must be in (0, 90)",
            bad.display()
        )),
        "{e}"
    );
    let nine: String = (0..9)
        .map(|i| format!("[[hoe.grating]]\nrecording_wavelength_nm = {}\nreference_angle_deg = 60.0\nindex_modulation = 0.001\n", 450 + 10 * i))
        .collect();
    let many = write(d, "many.toml", &format!("[hoe]\nmean_index = 1.5\n{nine}"));
    let e = fail(&["info", many.to_str().unwrap()]);
    assert!(
        e.contains("hoe.grating: 9 gratings; a film holds at most 8"),
        "{e}"
    );
    let two_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/two-grating.toml");
    let tp = two_path.to_str().unwrap();
    let e = fail(&["info", tp, "--set", "hoe.grating.1.index_modulation=2"]);
    assert!(
        e.contains(
            "--set hoe.grating.1.index_modulation: hoe.grating[1].index_modulation: \
             hoe.grating[1].index_modulation must be in [0"
        ),
        "{e}"
    );
    let e = fail(&["info", tp, "--set", "hoe.recording_wavelength_nm=500"]);
    assert!(e.contains("the scene lists [[hoe.grating]] entries"), "{e}");
    let e = fail(&["info", "--set", "hoe.grating.0.index_modulation=0.01"]);
    assert!(e.contains("has no [[hoe.grating]] entries"), "{e}");
    let e = fail(&["info", tp, "--set", "hoe.grating.2.index_modulation=0.01"]);
    assert!(e.contains("index 2 is out of range (2 elements)"), "{e}");
    // --set reaches an entry, and a key the entry does not list yet.
    let info = stscam_json(&[
        "info",
        tp,
        "--json",
        "--set",
        "hoe.grating.1.index_modulation=0.004",
        "--set",
        "hoe.grating.0.object_angle_deg=2",
    ]);
    let g = info["gratings"].as_array().unwrap();
    assert_eq!(g.len(), 2);
    assert_eq!(g[1]["index_modulation"].as_f64(), Some(0.004));
    assert_eq!(g[0]["object_angle_deg"].as_f64(), Some(2.0));
}

/// Peaks of a vertical profile near the predicted rows: for each predicted row r the centroid
/// of the profile over rows r ± 2 and the ratio of the mean there to the mean over the rows
/// 4 to 7 away on both sides (the background between replicas).
fn peaks_at(profile: &[f64], rows: &[f64]) -> Vec<(f64, f64, f64)> {
    rows.iter()
        .map(|&r| {
            let c = r.round() as i64;
            let at = |i: i64| profile.get(i as usize).copied().unwrap_or(0.0);
            let (mut m, mut mr) = (0.0, 0.0);
            for i in c - 2..=c + 2 {
                m += at(i);
                mr += at(i) * i as f64;
            }
            let bg: f64 = (4..=7).map(|k| at(c - k) + at(c + k)).sum::<f64>() / 8.0;
            (r, mr / m, (m / 5.0) / bg.max(1e-300))
        })
        .collect()
}

/// The two-grating example film (scenes/two-grating.toml): a point on the display renders
/// each grating's strong replicas (at least 25 % of its strongest) where `info`'s chief-ray
/// bisection (`analysis::point_replicas`, the same trace as `probe`) puts them, and in that
/// grating's band: the capture's spectral bins within ±25 nm of a grating's Bragg wavelength
/// at the crop centre hold a peak whose centroid is within 0.6 px of each predicted row and at
/// least 3× the background between replicas. Failing inputs: grating 0's rows looked for in
/// grating 1's band (a wrong grating index), and the rows predicted with grating 1's reference
/// angle 1° off (56° instead of 55°).
#[test]
fn two_gratings_render_their_replicas_where_probe_predicts_in_their_own_bands() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/two-grating.toml");
    let sets = |extra: &[&str]| -> Vec<String> {
        let mut v = vec![
            "sensor.crop_px=[8,440]".to_string(),
            "display.image=point".to_string(),
            "display.lcd_pixels_per_image_pixel=1".to_string(),
            // No black-level glow from the rest of the LCD: the replicas on a dark background.
            "display.black_level=0".to_string(),
        ];
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let sys = System::build(&load_scene(Some(&scene), &sets(&[])).unwrap()).unwrap();
    let mut set = RenderSettings::lattice(256, 1, false);
    set.spectral_bins = Some((380.0, 5.0, 80));
    let cap = render(&sys, &set);
    let (w, h) = (cap.width, cap.height);
    let predicted = |sys: &System, j: u32| -> Vec<f64> {
        // The lit pixel of the `point` target: (w/2, h/2) of the image, its centre in mm.
        let d = &sys.display;
        let (ow, oh) = (d.width_px as f64, d.height_px as f64);
        let x = d.center_mm.x + ((ow / 2.0).floor() + 0.5 - 0.5 * ow) * d.image_pixel_mm;
        let y = d.center_mm.y + (0.5 * oh - (oh / 2.0).floor() - 0.5) * d.image_pixel_mm;
        let reps: Vec<PointReplica> = point_replicas(sys, glam::DVec2::new(x, y))
            .into_iter()
            .filter(|r| r.grating == j)
            .collect();
        let max = reps.iter().map(|r| r.weight).fold(0.0, f64::max);
        reps.iter()
            .filter(|r| r.weight >= 0.25 * max)
            .map(|r| r.row)
            .collect()
    };
    let band_profile = |j: usize| -> Vec<f64> {
        let p = stscam::analysis::probe(&sys, w / 2, h / 2).unwrap();
        let lb = p
            .gratings
            .iter()
            .find(|g| g.grating as usize == j)
            .unwrap()
            .lambda_nm;
        let mut prof = vec![0.0; h];
        for (centre, data) in &cap.spectral {
            if (centre - lb).abs() <= 25.0 {
                for row in 0..h {
                    prof[row] += (0..w).map(|c| f64::from(data[row * w + c])).sum::<f64>();
                }
            }
        }
        prof
    };
    let ok = |profile: &[f64], rows: &[f64]| -> bool {
        peaks_at(profile, rows)
            .iter()
            .all(|&(r, c, ratio)| (c - r).abs() < 0.6 && ratio > 3.0)
    };
    let bands = [band_profile(0), band_profile(1)];
    for j in 0..2u32 {
        let rows = predicted(&sys, j);
        assert!(rows.len() >= 2, "grating {j}: {rows:?}");
        let found = peaks_at(&bands[j as usize], &rows);
        // Measured: centroids within 0.07 px of the predicted rows.
        assert!(ok(&bands[j as usize], &rows), "grating {j}: {found:?}");
        // A wrong grating index: these rows in the other grating's band.
        let other = &bands[1 - j as usize];
        assert!(
            !ok(other, &rows),
            "grating {j}'s rows in the other band: {:?}",
            peaks_at(other, &rows)
        );
    }
    // A wrong reference angle for grating 1 predicts rows the capture does not have.
    let wrong = System::build(
        &load_scene(
            Some(&scene),
            &sets(&["hoe.grating.1.reference_angle_deg=56"]),
        )
        .unwrap(),
    )
    .unwrap();
    let rows = predicted(&wrong, 1);
    assert!(!ok(&bands[1], &rows), "{:?}", peaks_at(&bands[1], &rows));
}

/// `demo --colour SCENE` with the user's own multiplexed film (issue 43, item 5): compared with
/// the paper's single grating, the design named after the scene file; with the paper scene the
/// comparison stays the single grating against the built-in RGB multiplex.
#[test]
fn colour_demo_compares_the_users_film_with_the_single_grating() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/rgb-multiplex.toml"),
    )
    .unwrap();
    let mine = write(dir.path(), "my-film.toml", &text);
    let small = [
        "display.image=white@16",
        "display.lcd_pixels_per_image_pixel=40",
        "sensor.crop_px=64",
        "sensor.pitch_um=30",
    ];
    let run = |scene: Option<&str>, out: &str| -> Vec<(String, u64)> {
        let o = dir.path().join(out);
        let mut a = vec![
            "demo",
            "--colour",
            "--spp",
            "2",
            "--out",
            o.to_str().unwrap(),
        ];
        if let Some(s) = scene {
            a.insert(2, s);
        }
        for s in &small {
            a.extend(["--set", s]);
        }
        stscam_ok(&a);
        let t: serde_json::Value =
            serde_json::from_slice(&std::fs::read(o.join("table.json")).unwrap()).unwrap();
        t["designs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|d| {
                (
                    d["design"].as_str().unwrap().to_string(),
                    d["gratings"].as_u64().unwrap(),
                )
            })
            .collect()
    };
    assert_eq!(
        run(Some(mine.to_str().unwrap()), "mine"),
        [
            ("single-grating".to_string(), 1),
            ("my-film".to_string(), 3)
        ]
    );
    assert_eq!(
        run(None, "paper"),
        [
            ("single-grating".to_string(), 1),
            ("rgb-multiplex".to_string(), 3)
        ]
    );
}
