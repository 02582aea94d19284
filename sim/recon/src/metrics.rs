//! Image quality against a known object (docs/physics.md §8.4).
//!
//! Normalisation: both images are linear object intensities in [0, 1] (the units H maps from:
//! 0 = black, 1 = white display pixel, display gamma removed); the reconstruction is clipped to
//! [0, 1] and not rescaled, so a wrong overall scale (e.g. from a mis-calibrated H) counts as
//! error. PSNR = 10·log₁₀(1/MSE). SSIM follows Wang, Bovik, Sheikh & Simoncelli (IEEE TIP 13,
//! 600, 2004): Gaussian window σ = 1.5 truncated to 11×11, K1 = 0.01, K2 = 0.03, L = 1, the mean
//! over **every** pixel of the object. Where the window reaches past the border it is cut to the
//! image and its weights renormalised to sum to 1 (no padding values are invented), so the
//! border rows and columns count like any other: the mean over only the pixels where the whole
//! window fits (scikit-image's `structural_similarity` with `gaussian_weights=True, sigma=1.5,
//! use_sample_covariance=False, data_range=1`) ignores a 5-pixel frame, and hid a band of bad
//! rows at the bottom of the paper scene's reconstructions. Away from the border both agree.

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

/// Mean SSIM of `x` (clipped to [0, 1]) against `truth`, both `w`×`h`, over every pixel
/// (window cut at the border and renormalised; see the module notes). NaN if the image is
/// smaller than the 11×11 window.
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
    if w < 2 * RADIUS + 1 || h < 2 * RADIUS + 1 || x.len() != w * h || truth.len() != w * h {
        return f64::NAN;
    }
    let xs: Vec<f64> = x.iter().map(|v| v.clamp(0.0, 1.0)).collect();
    let mut total = 0.0;
    for r in 0..h {
        let (r0, r1) = (r.saturating_sub(RADIUS), (r + RADIUS).min(h - 1));
        for c in 0..w {
            let (c0, c1_) = (c.saturating_sub(RADIUS), (c + RADIUS).min(w - 1));
            let (mut sw, mut mx, mut my, mut sxx, mut syy, mut sxy) =
                (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
            for rr in r0..=r1 {
                let ki = k[rr + RADIUS - r];
                for cc in c0..=c1_ {
                    let wt = ki * k[cc + RADIUS - c];
                    let p = rr * w + cc;
                    let (a, b) = (xs[p], truth[p]);
                    sw += wt;
                    mx += wt * a;
                    my += wt * b;
                    sxx += wt * a * a;
                    syy += wt * b * b;
                    sxy += wt * a * b;
                }
            }
            let (mx, my, sxx, syy, sxy) = (mx / sw, my / sw, sxx / sw, syy / sw, sxy / sw);
            let (vx, vy, cov) = (sxx - mx * mx, syy - my * my, sxy - mx * my);
            total += ((2.0 * mx * my + c1) * (2.0 * cov + c2))
                / ((mx * mx + my * my + c1) * (vx + vy + c2));
        }
    }
    total / (w * h) as f64
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

    /// The border counts: a band of wrong rows at the bottom (inside the 5-pixel frame an
    /// interior-only mean ignores) lowers SSIM by about its share of the image, and an interior
    /// pixel's value equals the direct formula with the full window.
    #[test]
    fn ssim_counts_the_border() {
        let (w, h) = (40, 40);
        let t: Vec<f64> = (0..w * h)
            .map(|i| {
                if (i % w / 4 + i / w / 4) % 2 == 0 {
                    0.9
                } else {
                    0.1
                }
            })
            .collect();
        let mut x = t.clone();
        for v in &mut x[(h - 4) * w..] {
            *v = 0.5;
        }
        let s = ssim(&x, &t, w, h);
        // 4 of 40 rows are flat grey: SSIM there is near 0, and the window spreads it a little.
        assert!(s < 0.93 && s > 0.80, "{s}");
        // Independent: the mean of per-pixel SSIM, each computed directly with a renormalised
        // window, at one interior and one corner pixel.
        let direct = |r: i64, c: i64| {
            let (mut sw, mut m) = (0.0, [0.0; 5]);
            for dr in -5i64..=5 {
                for dc in -5i64..=5 {
                    let (rr, cc) = (r + dr, c + dc);
                    if rr < 0 || cc < 0 || rr >= h as i64 || cc >= w as i64 {
                        continue;
                    }
                    let g = (-((dr * dr + dc * dc) as f64) / 4.5).exp();
                    let p = rr as usize * w + cc as usize;
                    let (a, b) = (x[p], t[p]);
                    sw += g;
                    for (acc, v) in m.iter_mut().zip([a, b, a * a, b * b, a * b]) {
                        *acc += g * v;
                    }
                }
            }
            let [mx, my, sxx, syy, sxy] = m.map(|v| v / sw);
            let (c1, c2) = (1e-4, 9e-4);
            ((2.0 * mx * my + c1) * (2.0 * (sxy - mx * my) + c2))
                / ((mx * mx + my * my + c1) * (sxx - mx * mx + syy - my * my + c2))
        };
        // A one-pixel image difference at (r, c) changes the mean by (per-pixel change)/(w h):
        // compare the mean over all pixels computed directly.
        let mut mean = 0.0;
        for r in 0..h as i64 {
            for c in 0..w as i64 {
                mean += direct(r, c);
            }
        }
        mean /= (w * h) as f64;
        assert!((mean - s).abs() < 1e-12, "{mean} vs {s}");
        assert!(direct(39, 39) < 0.5, "corner in the grey band");
    }
}
