//! Image quality against a known object (physics.md §8.4).
//!
//! Normalisation: both images are linear object intensities in [0, 1] (the units H maps from:
//! 0 = black, 1 = white display pixel, display gamma removed); the reconstruction is clipped to
//! [0, 1] and not rescaled, so a wrong overall scale (e.g. from a mis-calibrated H) counts as
//! error. PSNR = 10·log₁₀(1/MSE). SSIM follows Wang, Bovik, Sheikh & Simoncelli (IEEE TIP 13,
//! 600, 2004): Gaussian window σ = 1.5 truncated to 11×11, K1 = 0.01, K2 = 0.03, L = 1, the mean
//! over the pixels where the whole window fits (as scikit-image's `structural_similarity` with
//! `gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1`).

/// PSNR in dB of `x` (clipped to [0, 1]) against `truth`, peak 1.
pub fn psnr(x: &[f64], truth: &[f64]) -> f64 {
    let mse = x
        .iter()
        .zip(truth)
        .map(|(a, b)| (a.clamp(0.0, 1.0) - b).powi(2))
        .sum::<f64>()
        / truth.len().max(1) as f64;
    if mse > 0.0 {
        -10.0 * mse.log10()
    } else {
        f64::INFINITY
    }
}

/// Mean SSIM of `x` (clipped to [0, 1]) against `truth`, both `w`×`h`.
pub fn ssim(x: &[f64], truth: &[f64], w: usize, h: usize) -> f64 {
    const RADIUS: usize = 5;
    const SIGMA: f64 = 1.5;
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let k: Vec<f64> = (0..=2 * RADIUS)
        .map(|i| {
            let d = i as f64 - RADIUS as f64;
            (-d * d / (2.0 * SIGMA * SIGMA)).exp()
        })
        .collect();
    let ks: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|v| v / ks).collect();
    if w < 2 * RADIUS + 1 || h < 2 * RADIUS + 1 {
        return f64::NAN;
    }
    let xs: Vec<f64> = x.iter().map(|v| v.clamp(0.0, 1.0)).collect();
    let mut total = 0.0;
    let mut count = 0usize;
    for r in RADIUS..h - RADIUS {
        for c in RADIUS..w - RADIUS {
            let (mut mx, mut my, mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for (i, ki) in k.iter().enumerate() {
                for (j, kj) in k.iter().enumerate() {
                    let p = (r + i - RADIUS) * w + (c + j - RADIUS);
                    let wt = ki * kj;
                    let (a, b) = (xs[p], truth[p]);
                    mx += wt * a;
                    my += wt * b;
                    sxx += wt * a * a;
                    syy += wt * b * b;
                    sxy += wt * a * b;
                }
            }
            let (vx, vy, cov) = (sxx - mx * mx, syy - my * my, sxy - mx * my);
            total += ((2.0 * mx * my + c1) * (2.0 * cov + c2))
                / ((mx * mx + my * my + c1) * (vx + vy + c2));
            count += 1;
        }
    }
    total / count as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_and_ssim_values() {
        let (w, h) = (32, 32);
        let t: Vec<f64> = (0..w * h).map(|i| (i % w) as f64 / w as f64).collect();
        assert_eq!(psnr(&t, &t), f64::INFINITY);
        assert!((ssim(&t, &t, w, h) - 1.0).abs() < 1e-12);
        // A uniform error of 0.1 gives 20 dB.
        let x: Vec<f64> = t.iter().map(|v| (v + 0.1).min(1.0)).collect();
        let p = psnr(&x, &t.iter().map(|v| v.min(0.9)).collect::<Vec<_>>());
        assert!((p - 20.0).abs() < 1e-9, "{p}");
        // A constant shift keeps the structure: SSIM = luminance term only, < 1.
        let s = ssim(&x, &t, w, h);
        assert!(s > 0.8 && s < 1.0, "{s}");
        // Inverted image: negative correlation → SSIM < 0.
        let inv: Vec<f64> = t.iter().map(|v| 1.0 - v).collect();
        assert!(ssim(&inv, &t, w, h) < 0.0);
    }
}
