//! The plain-path-tracer estimator of `bench render` (uniform wavelengths, analog Russian
//! roulette) and stscam's default estimator estimate the same image.

use stscam::render::{Estimator, RenderSettings, render_with};
use stscam::sampler::SamplerKind;
use stscam::scene::load_scene;
use stscam::system::System;

/// Mean image total over 8 independent renders (seeds seed..seed+8) and its standard error.
fn total(sys: &System, e: Estimator, spp: u32, seed: u64) -> (f64, f64) {
    let sums: Vec<f64> = (0..8)
        .map(|k| {
            let set = RenderSettings {
                spp,
                seed: seed + k,
                sampler: SamplerKind::Independent,
                user_side: Default::default(),
                spectral_bins: None,
                progress: false,
                estimator: Default::default(),
                adaptive: false,
            };
            render_with(sys, &set, e).channels[0]
                .iter()
                .map(|&v| f64::from(v))
                .sum::<f64>()
        })
        .collect();
    let m = sums.iter().sum::<f64>() / 8.0;
    let var = sums.iter().map(|s| (s - m).powi(2)).sum::<f64>() / 7.0;
    (m, (var / 8.0).sqrt())
}

#[test]
fn analog_and_bragg_estimators_agree_on_the_total() {
    // 16×16 crop with the paper's field of view, a white target.
    let ls = load_scene(
        None,
        &[
            "sensor.crop_px=[16,16]".to_string(),
            "sensor.pitch_um=132.0".to_string(),
            "display.image=white".to_string(),
        ],
    )
    .unwrap();
    let sys = System::build(&ls).unwrap();
    let (a, sa) = total(&sys, Estimator::UniformAnalog, 1024, 100);
    let (b, sb) = total(&sys, Estimator::Bragg, 64, 200);
    let z = (a - b).abs() / (sa * sa + sb * sb).sqrt();
    assert!(z < 4.0, "analog {a} ± {sa}, bragg {b} ± {sb}: z = {z}");
    // The analog estimator is far noisier per path: that is what the benchmark measures.
    assert!(sa / a > 3.0 * sb / b);
}

/// The same for a 3-D scene (a head lit by a rect light and an environment, seen with a
/// polarised display behind it): the analog estimator picks one polarisation state and one
/// branch and traces only that branch on the user side; both estimate the same total.
#[test]
fn analog_and_bragg_estimators_agree_on_a_3d_scene() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.toml");
    std::fs::write(
        &p,
        "[display]\nimage = \"white\"\npolarization = 30.0\n[[object]]\nmesh = \"head\"\nposition_mm = [0.0, 0.0, -400.0]\n[[light]]\nkind = \"rect\"\nposition_mm = [0.0, 0.0, -1.0]\nsize_mm = [300.0, 300.0]\nnormal = [0.0, 0.0, -1.0]\n[[light]]\nkind = \"environment\"\nscale = 0.1\n",
    )
    .unwrap();
    let ls = load_scene(
        Some(&p),
        &[
            "sensor.crop_px=[16,16]".to_string(),
            "sensor.pitch_um=132.0".to_string(),
        ],
    )
    .unwrap();
    let sys = System::build(&ls).unwrap();
    let (a, sa) = total(&sys, Estimator::UniformAnalog, 512, 100);
    let (b, sb) = total(&sys, Estimator::Bragg, 32, 200);
    let z = (a - b).abs() / (sa * sa + sb * sb).sqrt();
    eprintln!("3-D: analog {a} ± {sa}, bragg {b} ± {sb}: z = {z}");
    assert!(z < 4.0, "analog {a} ± {sa}, bragg {b} ± {sb}: z = {z}");
}
