//! Extreme scenes finish in bounded time, stay finite and physical, and say what they dropped.

fn render(dir: &std::path::Path, sets: &[&str]) -> (serde_json::Value, String) {
    let mut args = vec![
        "render",
        "--spp",
        "2",
        "--out",
        dir.to_str().unwrap(),
        "--set",
        "sensor.crop_px=[24,24]",
    ];
    for s in sets {
        args.push("--set");
        args.push(s);
    }
    let out = crate::common::stscam(&args);
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{args:?}: {stderr}");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("capture.json")).unwrap()).unwrap();
    let (_, _, ch) = stscam::io::read_exr(&dir.join("capture.exr")).unwrap();
    assert!(
        ch.iter()
            .all(|c| c.data.iter().all(|v| v.is_finite() && *v >= 0.0))
    );
    (json, stderr)
}

#[test]
fn thin_plate_with_thousands_of_bounces_is_bounded_and_warned() {
    let d = tempfile::tempdir().unwrap();
    // 0.05 mm plate: a guided path makes thousands of contacts across the 50 mm vHOE.
    let (j, _) = render(&d.path().join("a"), &["plate.thickness_mm=0.05"]);
    let st = &j["stats"];
    assert!(st["contacts"].as_f64().unwrap() / st["camera_paths"].as_f64().unwrap() > 500.0);
    assert_eq!(st["nonfinite_samples"], 0);
    assert!(st["max_branch_weight"].as_f64().unwrap() <= 1.0);
    // The same with a contact limit: bounded, and the dropped weight is reported and warned.
    let (j, err) = render(
        &d.path().join("b"),
        &["plate.thickness_mm=0.05", "sampling.max_contacts=200"],
    );
    assert!(j["stats"]["max_contacts_hits"].as_u64().unwrap() > 0);
    assert!(
        j["stats"]["contacts"].as_f64().unwrap() / j["stats"]["camera_paths"].as_f64().unwrap()
            <= 200.0
    );
    assert!(
        err.contains("warning") && err.contains("max_contacts"),
        "{err}"
    );
    // A coarse truncation tolerance is warned too.
    let (_, err) = render(&d.path().join("c"), &["sampling.min_guided_weight=0.5"]);
    assert!(err.contains("min_guided_weight"), "{err}");
}

#[test]
fn grazing_incidence_and_saturated_gratings_stay_physical() {
    let d = tempfile::tempdir().unwrap();
    // A ±80° field of view: rays reach the plate at grazing incidence.
    let (j, _) = render(
        &d.path().join("a"),
        &["sensor.pitch_um=3000", "camera.f_number=1.0"],
    );
    assert_eq!(j["stats"]["nonfinite_samples"], 0);
    assert!(j["stats"]["max_branch_weight"].as_f64().unwrap() <= 1.0);
    // An index modulation so large that η saturates (ν ≫ 1), and a lossy film.
    let (j, _) = render(
        &d.path().join("b"),
        &[
            "hoe.index_modulation=0.1",
            "hoe.film_thickness_um=200",
            "hoe.amplitude_absorption_per_mm=5",
        ],
    );
    assert_eq!(j["stats"]["nonfinite_samples"], 0);
    assert!(j["stats"]["max_branch_weight"].as_f64().unwrap() <= 1.0);
}
