//! The plain-path-tracer estimator of `bench render` (uniform wavelengths, analog Russian
//! roulette) and stscam's default estimator estimate the same image.

use stscam::render::{Estimator, RenderSettings, render_with};
use stscam::sampler::SamplerKind;
use stscam::scene::load_scene;
use stscam::system::System;

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
    let set = |spp, seed| RenderSettings {
        spp,
        seed,
        sampler: SamplerKind::Independent,
        spectral_bins: None,
        progress: false,
    };
    let total = |e: Estimator, spp: u32, seed: u64| -> (f64, f64) {
        // Mean over the image and its standard error from 8 independent renders.
        let sums: Vec<f64> = (0..8)
            .map(|k| {
                render_with(&sys, &set(spp, seed + k), e).channels[0]
                    .iter()
                    .map(|&v| f64::from(v))
                    .sum::<f64>()
            })
            .collect();
        let m = sums.iter().sum::<f64>() / 8.0;
        let var = sums.iter().map(|s| (s - m).powi(2)).sum::<f64>() / 7.0;
        (m, (var / 8.0).sqrt())
    };
    let (a, sa) = total(Estimator::UniformAnalog, 1024, 100);
    let (b, sb) = total(Estimator::Bragg, 64, 200);
    let z = (a - b).abs() / (sa * sa + sb * sb).sqrt();
    assert!(z < 4.0, "analog {a} ± {sa}, bragg {b} ± {sb}: z = {z}");
    // The analog estimator is far noisier per path: that is what the benchmark measures.
    assert!(sa / a > 3.0 * sb / b);
}
