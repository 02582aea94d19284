//! Adaptive sample counts (`render --adaptive`): the image keeps its expectation, the counts
//! follow the noise within the budget, and the bytes do not depend on the thread count.

use stscam::render::{RenderSettings, render};
use stscam::system::System;

use crate::common::{crop_system, mean_sem, with_threads};

fn adaptive(spp: u32, seed: u64) -> RenderSettings {
    RenderSettings {
        adaptive: true,
        ..RenderSettings::lattice(spp, seed, false)
    }
}

fn image(sys: &System, set: &RenderSettings) -> Vec<f64> {
    render(sys, set).channels[0]
        .iter()
        .map(|&v| f64::from(v))
        .collect()
}

/// The paper scene, 48 × 48 over the whole field: the mean of four adaptive renders (mean 64
/// spp, seeds 1–4) against a 2,048-spp render of the default estimator, pixel by pixel. The
/// differences' mean is within 4 standard errors of zero, both over all pixels and over the
/// pixels that took the most samples (where a count that depended on the pixel's own samples
/// would bias it); the same renders 3 % too bright fail the rule. The adaptive renders'
/// error is at most half the default's at the same mean spp.
#[test]
fn adaptive_renders_keep_the_expectation() {
    let sys = crop_system("scenes/paper-2022.toml", 48, &[]);
    let reference = image(&sys, &RenderSettings::lattice(2048, 99, false));
    let runs: Vec<(Vec<f64>, Vec<u32>)> = (1..=4)
        .map(|seed| {
            let cap = render(&sys, &adaptive(64, seed));
            let counts = cap.stats.sample_counts.clone().expect("counts recorded");
            assert!(counts.max_spp >= 256, "{counts:?}");
            let img = cap.channels[0].iter().map(|&v| f64::from(v)).collect();
            (img, vec![counts.min_spp, counts.max_spp])
        })
        .collect();
    let mean: Vec<f64> = (0..reference.len())
        .map(|i| runs.iter().map(|r| r.0[i]).sum::<f64>() / runs.len() as f64)
        .collect();
    let level = reference.iter().sum::<f64>() / reference.len() as f64;
    assert!(level > 0.0);
    // The pixels whose reference value is in the top tenth: the replicas of the object, where
    // the adaptive counts are highest.
    let mut sorted = reference.clone();
    sorted.sort_by(f64::total_cmp);
    let bright = sorted[sorted.len() * 9 / 10];
    let check = |scale: f64, only_bright: bool| {
        let d: Vec<f64> = mean
            .iter()
            .zip(&reference)
            .filter(|(_, r)| !only_bright || **r >= bright)
            .map(|(a, r)| scale * a - r)
            .collect();
        let (m, sem) = mean_sem(&d);
        (m / level, sem / level)
    };
    for only_bright in [false, true] {
        let (m, sem) = check(1.0, only_bright);
        assert!(
            m.abs() < 4.0 * sem,
            "adaptive (bright only: {only_bright}): {m} ± {sem}"
        );
        let (m3, sem3) = check(1.03, only_bright);
        assert!(
            m3.abs() > 4.0 * sem3,
            "3 % too bright must fail (bright only: {only_bright}): {m3} ± {sem3}"
        );
    }
    // The point of it: at the same mean spp the error is smaller.
    let rmse = |img: &[f64]| {
        let num: f64 = img
            .iter()
            .zip(&reference)
            .map(|(a, r)| (a - r).powi(2))
            .sum();
        let den: f64 = reference.iter().map(|r| r * r).sum();
        (num / den).sqrt()
    };
    let plain = image(&sys, &RenderSettings::lattice(64, 1, false));
    let (e_plain, e_adaptive) = (rmse(&plain), rmse(&runs[0].0));
    assert!(
        e_adaptive < 0.5 * e_plain,
        "adaptive {e_adaptive} against plain {e_plain}"
    );
}

/// The counts spend the budget where the pilot saw noise: the render's camera paths (pilot
/// included) are at most the mean spp's and nearly all of them, the recorded counts span the
/// floor to many times the mean, and below 16 spp a render is one plain pass (the same bytes
/// as without the flag).
#[test]
fn counts_spend_the_budget_and_small_spp_is_plain() {
    let sys = crop_system("scenes/paper-2022.toml", 32, &[]);
    let cap = render(&sys, &adaptive(32, 5));
    let c = cap.stats.sample_counts.clone().unwrap();
    let pixels = 32 * 32;
    assert_eq!(c.pilot_spp, 2);
    assert_eq!(c.min_spp, 2);
    assert!(c.max_spp >= 8 * 32, "{c:?}");
    assert!(c.mean_spp <= f64::from(32 - 2 * c.pilot_spp), "{c:?}");
    assert!(c.mean_spp > 0.95 * f64::from(32 - 2 * c.pilot_spp), "{c:?}");
    // Camera paths drawn: the two pilots and the counts (a sample outside the band is drawn
    // but not traced, so the traced paths are at most that).
    let drawn = (2.0 * f64::from(c.pilot_spp) + c.mean_spp) * pixels as f64;
    assert!(cap.stats.camera_paths as f64 <= drawn + 0.5);
    // In this scene every drawn wavelength is in the band.
    assert!(cap.stats.camera_paths as f64 > 0.99 * drawn);
    let small = render(&sys, &adaptive(8, 5));
    assert!(small.stats.sample_counts.is_none());
    assert_eq!(
        small.channels,
        render(&sys, &RenderSettings::lattice(8, 5, false)).channels
    );
}

/// The same bytes for 1 and 2 threads: the display-only scene, and a 3-D scene through both of
/// its user-side estimators (the padded one sizes its point sets by the pixel's count) and
/// from a camera-side table.
#[test]
fn adaptive_renders_are_the_same_for_any_thread_count() {
    use stscam::render::UserSideSampler;
    use stscam::render::camera_table::{TableSettings, build, render_with_table};
    let paper = crop_system("scenes/paper-2022.toml", 24, &[]);
    let eye = crop_system("scenes/eye-contact.toml", 16, &[]);
    let table = build(
        &eye,
        &TableSettings {
            spp: 64,
            reps: 8,
            seed: 2,
        },
        false,
    )
    .unwrap();
    let run = |threads: usize| {
        with_threads(threads, || {
            let padded = RenderSettings {
                user_side: UserSideSampler::Padded,
                ..adaptive(16, 3)
            };
            vec![
                render(&paper, &adaptive(32, 3)).channels,
                render(&eye, &adaptive(16, 3)).channels,
                render(&eye, &padded).channels,
                render_with_table(&eye, &adaptive(16, 3), &table)
                    .unwrap()
                    .channels,
            ]
        })
    };
    let (one, two) = (run(1), run(2));
    for (k, (a, b)) in one.iter().zip(&two).enumerate() {
        let bits =
            |c: &Vec<Vec<f32>>| -> Vec<u32> { c.iter().flatten().map(|v| v.to_bits()).collect() };
        assert_eq!(bits(a), bits(b), "render {k}");
    }
}
