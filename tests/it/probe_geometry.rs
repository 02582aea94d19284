//! The chief-ray geometry of `stscam probe` against closed forms: replica pitch 2w·tanΘ',
//! object-side directions equal to the camera ray (periscope), and the Bragg colour of
//! docs/physics.md §3.2–3.3 along the vertical midline.

use crate::common::{stscam_json, vec3};

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn norm(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

#[test]
fn replicas_are_spaced_by_the_guided_pitch_and_parallel_to_the_camera_ray() {
    let mut checked = 0;
    for pixel in ["220,220", "30,40", "400,90", "220,5", "10,430", "439,300"] {
        let p = stscam_json(&["probe", "--pixel", pixel, "--json"]);
        let w = 2.0;
        let theta = p["guided_angle_deg"].as_f64().unwrap().to_radians();
        let pitch = 2.0 * w * theta.tan();
        let dir = vec3(&p["camera_ray_dir"]);
        let reps = p["replicas"].as_array().unwrap();
        assert!(reps.len() >= 3, "{pixel}: {} replicas", reps.len());
        for pair in reps.windows(2) {
            let d = norm(sub(
                vec3(&pair[1]["object_point_mm"]),
                vec3(&pair[0]["object_point_mm"]),
            ));
            assert!(
                (d / pitch - 1.0).abs() < 1e-9,
                "{pixel}: spacing {d} vs 2w tanΘ' {pitch}"
            );
            checked += 1;
        }
        for r in reps {
            // The object-side ray runs from the object point to the exit point on the front face;
            // the camera ray leaves the lens toward the screen: the physical rays are parallel.
            let v = sub(vec3(&r["object_point_mm"]), vec3(&r["exit_point_mm"]));
            let n = norm(v);
            for k in 0..3 {
                assert!(
                    (v[k] / n - dir[k]).abs() < 1e-12,
                    "{pixel}: object-side direction differs from the camera ray"
                );
            }
            let wgt = r["weight"].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&wgt));
            // Contacts lie on the back face, exits on the front face, objects on the display.
            assert!((r["bottom_contact_mm"][2].as_f64().unwrap() - 2.0).abs() < 1e-12);
            assert_eq!(r["exit_point_mm"][2].as_f64().unwrap(), 0.0);
            assert_eq!(r["object_point_mm"][2].as_f64().unwrap(), -550.0);
        }
        let total: f64 = reps.iter().map(|r| r["weight"].as_f64().unwrap()).sum();
        assert!(total <= 1.0, "{pixel}: replica weights sum to {total}");
    }
    assert!(checked > 20);
}

#[test]
fn bragg_colour_on_the_vertical_midline() {
    // With the glass index equal to the film index the probe wavelength follows
    // λ = λ0 cos(Θ' − θ_R/2)/cos(θ_R/2) (docs/physics.md §3.3) exactly.
    // An odd crop puts column 220 exactly on the vertical midline (in-plane rays).
    let sets = [
        "--set",
        "plate.glass=1.5",
        "--set",
        "hoe.mean_index=1.5",
        "--set",
        "sensor.crop_px=441",
    ];
    let half = 30.6f64.to_radians();
    let mut lambdas = Vec::new();
    for row in [0usize, 40, 110, 219, 220, 330, 400, 440] {
        let pixel = format!("220,{row}");
        let mut args = vec!["probe", "--pixel", pixel.as_str(), "--json"];
        args.extend_from_slice(&sets);
        let p = stscam_json(&args);
        let lam = p["lambda_nm"].as_f64().unwrap();
        let theta = p["guided_angle_deg"].as_f64().unwrap().to_radians();
        let expect = 532.0 * (theta - half).cos() / half.cos();
        assert!(
            (lam / expect - 1.0).abs() < 1e-9,
            "row {row}: {lam} vs {expect}"
        );
        lambdas.push(lam);
    }
    // Top rows red-shifted, bottom rows blue-shifted, monotonically (the paper's Fig. 4b).
    assert!(lambdas.windows(2).all(|w| w[0] > w[1]), "{lambdas:?}");
    assert!(
        lambdas[0] > 545.0 && *lambdas.last().unwrap() < 520.0,
        "{lambdas:?}"
    );
}

#[test]
fn default_scene_colour_runs_red_to_blue_from_top_to_bottom() {
    let top = stscam_json(&["probe", "--pixel", "220,0", "--json"]);
    let mid = stscam_json(&["probe", "--pixel", "220,220", "--json"]);
    let bottom = stscam_json(&["probe", "--pixel", "220,439", "--json"]);
    let l = |v: &serde_json::Value| v["lambda_nm"].as_f64().unwrap();
    assert!(l(&top) > l(&mid) + 20.0 && l(&mid) > l(&bottom) + 20.0);
    // The centre is Bragg-matched near the recording wavelength (within the pixel's offset).
    assert!((l(&mid) - 532.0).abs() < 0.5);
}
