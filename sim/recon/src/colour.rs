//! Colour error metrics of a reconstructed colour object: colour PSNR and CIEDE2000.
//!
//! Model: an object of a colour display is three planes of linear primary intensity
//! f_p ∈ [0, 1] (p = R, G, B). What the display emits for (f_R, f_G, f_B) has CIE 1931 XYZ
//! (2° observer) X = M·f, with column p of M the tristimulus values of primary p's spectrum,
//! M[i][p] = ∫ P_p(λ) c̄_i(λ) dλ (`world::colour::cmf`, 380–780 nm), so colour differences are
//! those of the simulated display itself, not of an assumed standard gamut. CIELAB
//! (CIE 015:2018) is taken relative to the display's white M·(1, 1, 1), and ΔE₀₀ is CIEDE2000
//! with k_L = k_C = k_H = 1 as given by Sharma, Wu & Dalal, "The CIEDE2000 color-difference
//! formula: implementation notes, supplementary test data, and mathematical observations",
//! Color Res. Appl. 30, 21–30 (2005), Eqs. (1)–(17), tested against the paper's Table 1.
//!
//! Colour PSNR is the PSNR over all three planes together (peak 1, reconstruction clipped to
//! [0, 1], as `metrics::psnr`).

use crate::spectra::Spectrum;

/// What the colour metrics' CIELAB is relative to (for JSON reports).
pub const LAB_NOTE: &str = "CIELAB of the display's emission (XYZ = M f, M from the LCD primaries' spectra and the CIE 1931 2-degree observer), white = all primaries at 1; CIEDE2000 per pixel (Sharma, Wu & Dalal 2005), both images clipped to [0, 1]";

/// The 3 × 3 matrix from linear primary intensities to XYZ, `m[i][p]` = ∫ P_p c̄_i dλ over
/// 380–780 nm on the primaries' 1 nm grid (the integrand tabulated and integrated exactly as a
/// piecewise-linear function).
pub fn primaries_to_xyz(primaries: &[Spectrum; 3]) -> [[f64; 3]; 3] {
    let cmf: [Spectrum; 3] = std::array::from_fn(crate::cie::cmf);
    std::array::from_fn(|i| {
        std::array::from_fn(|p| {
            Spectrum::on_grid(|l| primaries[p].eval(l) * cmf[i].eval(l)).integral(380.0, 780.0)
        })
    })
}

/// CIELAB (L*, a*, b*) of XYZ `xyz` relative to the white `white` (CIE 015:2018).
pub fn xyz_to_lab(xyz: [f64; 3], white: [f64; 3]) -> [f64; 3] {
    const D: f64 = 6.0 / 29.0;
    let f = |t: f64| {
        if t > D * D * D {
            t.cbrt()
        } else {
            t / (3.0 * D * D) + 4.0 / 29.0
        }
    };
    let [fx, fy, fz] = std::array::from_fn(|i| f(xyz[i] / white[i]));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// CIEDE2000 colour difference ΔE₀₀ between two CIELAB colours (k_L = k_C = k_H = 1;
/// Sharma, Wu & Dalal 2005, Eqs. 1–17).
pub fn ciede2000(lab1: [f64; 3], lab2: [f64; 3]) -> f64 {
    let [l1, a1, b1] = lab1;
    let [l2, a2, b2] = lab2;
    let pow25_7 = 25f64.powi(7);
    let c_bar = 0.5 * (a1.hypot(b1) + a2.hypot(b2));
    let c7 = c_bar.powi(7);
    let g = 0.5 * (1.0 - (c7 / (c7 + pow25_7)).sqrt());
    let (ap1, ap2) = ((1.0 + g) * a1, (1.0 + g) * a2);
    let (cp1, cp2) = (ap1.hypot(b1), ap2.hypot(b2));
    let hue = |b: f64, ap: f64| {
        if b == 0.0 && ap == 0.0 {
            0.0
        } else {
            b.atan2(ap).to_degrees().rem_euclid(360.0)
        }
    };
    let (hp1, hp2) = (hue(b1, ap1), hue(b2, ap2));
    let dl = l2 - l1;
    let dc = cp2 - cp1;
    let zero_chroma = cp1 * cp2 == 0.0;
    let dh = if zero_chroma {
        0.0
    } else {
        let d = hp2 - hp1;
        if d > 180.0 {
            d - 360.0
        } else if d < -180.0 {
            d + 360.0
        } else {
            d
        }
    };
    let d_big_h = 2.0 * (cp1 * cp2).sqrt() * (0.5 * dh).to_radians().sin();
    let l_bar = 0.5 * (l1 + l2);
    let cp_bar = 0.5 * (cp1 + cp2);
    let h_bar = if zero_chroma {
        hp1 + hp2
    } else if (hp1 - hp2).abs() <= 180.0 {
        0.5 * (hp1 + hp2)
    } else if hp1 + hp2 < 360.0 {
        0.5 * (hp1 + hp2 + 360.0)
    } else {
        0.5 * (hp1 + hp2 - 360.0)
    };
    let cosd = |x: f64| x.to_radians().cos();
    let t =
        1.0 - 0.17 * cosd(h_bar - 30.0) + 0.24 * cosd(2.0 * h_bar) + 0.32 * cosd(3.0 * h_bar + 6.0)
            - 0.20 * cosd(4.0 * h_bar - 63.0);
    let d_theta = 30.0 * (-((h_bar - 275.0) / 25.0).powi(2)).exp();
    let cp7 = cp_bar.powi(7);
    let r_c = 2.0 * (cp7 / (cp7 + pow25_7)).sqrt();
    let l50 = (l_bar - 50.0).powi(2);
    let s_l = 1.0 + 0.015 * l50 / (20.0 + l50).sqrt();
    let s_c = 1.0 + 0.045 * cp_bar;
    let s_h = 1.0 + 0.015 * cp_bar * t;
    let r_t = -(2.0 * d_theta).to_radians().sin() * r_c;
    let (x, y, z) = (dl / s_l, dc / s_c, d_big_h / s_h);
    (x * x + y * y + z * z + r_t * y * z).max(0.0).sqrt()
}

/// Colour errors of a reconstruction against the truth.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct ColourErrors {
    /// PSNR over the three planes together, dB (peak 1, reconstruction clipped to [0, 1]).
    pub psnr_db: f64,
    /// Mean CIEDE2000 over pixels.
    pub ciede2000_mean: f64,
    /// 95th percentile of CIEDE2000 over pixels.
    pub ciede2000_p95: f64,
    /// Fraction of the object's total intensity in each plane [R, G, B] (reconstruction
    /// clipped to [0, 1]).
    pub energy_share: [f64; 3],
}

/// Colour PSNR, CIEDE2000 (mean and 95th percentile over pixels) and the energy share per
/// plane of reconstruction `x` against `truth`, both three planes primary-major (3·N values),
/// with `m` from [`primaries_to_xyz`]. Both are clipped to [0, 1] before the conversion.
pub fn colour_errors(x: &[f64], truth: &[f64], m: &[[f64; 3]; 3]) -> ColourErrors {
    let n = truth.len() / 3;
    let white = crate::cie::mat3(m, [1.0; 3]);
    let rgb = |v: &[f64], k: usize| -> [f64; 3] {
        std::array::from_fn(|p| v.get(p * n + k).copied().unwrap_or(0.0).clamp(0.0, 1.0))
    };
    let mut de: Vec<f64> = (0..n)
        .map(|k| {
            let a = xyz_to_lab(crate::cie::mat3(m, rgb(x, k)), white);
            let b = xyz_to_lab(crate::cie::mat3(m, rgb(truth, k)), white);
            ciede2000(a, b)
        })
        .collect();
    let mean = de.iter().sum::<f64>() / n.max(1) as f64;
    de.sort_by(f64::total_cmp);
    let p95 = de
        .get(((0.95 * n as f64).ceil() as usize).saturating_sub(1))
        .copied()
        .unwrap_or(0.0);
    let sums: [f64; 3] = std::array::from_fn(|p| {
        (0..n)
            .map(|k| x.get(p * n + k).map_or(0.0, |v| v.clamp(0.0, 1.0)))
            .sum()
    });
    let total: f64 = sums.iter().sum();
    ColourErrors {
        psnr_db: super::metrics::psnr(x, truth),
        ciede2000_mean: mean,
        ciede2000_p95: p95,
        energy_share: sums.map(|s| if total > 0.0 { s / total } else { 0.0 }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sharma, Wu & Dalal (2005), Table 1: the 34 test pairs (L1, a1, b1, L2, a2, b2, ΔE00).
    const SHARMA_2005: [[f64; 7]; 34] = [
        [50.0000, 2.6772, -79.7751, 50.0000, 0.0000, -82.7485, 2.0425],
        [50.0000, 3.1571, -77.2803, 50.0000, 0.0000, -82.7485, 2.8615],
        [50.0000, 2.8361, -74.0200, 50.0000, 0.0000, -82.7485, 3.4412],
        [
            50.0000, -1.3802, -84.2814, 50.0000, 0.0000, -82.7485, 1.0000,
        ],
        [
            50.0000, -1.1848, -84.8006, 50.0000, 0.0000, -82.7485, 1.0000,
        ],
        [
            50.0000, -0.9009, -85.5211, 50.0000, 0.0000, -82.7485, 1.0000,
        ],
        [50.0000, 0.0000, 0.0000, 50.0000, -1.0000, 2.0000, 2.3669],
        [50.0000, -1.0000, 2.0000, 50.0000, 0.0000, 0.0000, 2.3669],
        [50.0000, 2.4900, -0.0010, 50.0000, -2.4900, 0.0009, 7.1792],
        [50.0000, 2.4900, -0.0010, 50.0000, -2.4900, 0.0010, 7.1792],
        [50.0000, 2.4900, -0.0010, 50.0000, -2.4900, 0.0011, 7.2195],
        [50.0000, 2.4900, -0.0010, 50.0000, -2.4900, 0.0012, 7.2195],
        [50.0000, -0.0010, 2.4900, 50.0000, 0.0009, -2.4900, 4.8045],
        [50.0000, -0.0010, 2.4900, 50.0000, 0.0010, -2.4900, 4.8045],
        [50.0000, -0.0010, 2.4900, 50.0000, 0.0011, -2.4900, 4.7461],
        [50.0000, 2.5000, 0.0000, 50.0000, 0.0000, -2.5000, 4.3065],
        [50.0000, 2.5000, 0.0000, 73.0000, 25.0000, -18.0000, 27.1492],
        [50.0000, 2.5000, 0.0000, 61.0000, -5.0000, 29.0000, 22.8977],
        [50.0000, 2.5000, 0.0000, 56.0000, -27.0000, -3.0000, 31.9030],
        [50.0000, 2.5000, 0.0000, 58.0000, 24.0000, 15.0000, 19.4535],
        [50.0000, 2.5000, 0.0000, 50.0000, 3.1736, 0.5854, 1.0000],
        [50.0000, 2.5000, 0.0000, 50.0000, 3.2972, 0.0000, 1.0000],
        [50.0000, 2.5000, 0.0000, 50.0000, 1.8634, 0.5757, 1.0000],
        [50.0000, 2.5000, 0.0000, 50.0000, 3.2592, 0.3350, 1.0000],
        [
            60.2574, -34.0099, 36.2677, 60.4626, -34.1751, 39.4387, 1.2644,
        ],
        [
            63.0109, -31.0961, -5.8663, 62.8187, -29.7946, -4.0864, 1.2630,
        ],
        [61.2901, 3.7196, -5.3901, 61.4292, 2.2480, -4.9620, 1.8731],
        [35.0831, -44.1164, 3.7933, 35.0232, -40.0716, 1.5901, 1.8645],
        [
            22.7233, 20.0904, -46.6940, 23.0331, 14.9730, -42.5619, 2.0373,
        ],
        [36.4612, 47.8580, 18.3852, 36.2715, 50.5065, 21.2231, 1.4146],
        [90.8027, -2.0831, 1.4410, 91.1528, -1.6435, 0.0447, 1.4441],
        [90.9257, -0.5406, -0.9208, 88.6381, -0.8985, -0.7239, 1.5381],
        [6.7747, -0.2908, -2.4247, 5.8714, -0.0985, -2.2286, 0.6377],
        [2.0776, 0.0795, -1.1350, 0.9033, -0.0636, -0.5514, 0.9082],
    ];

    #[test]
    fn ciede2000_matches_sharma_wu_dalal_table_1() {
        // The table gives 4 decimals: agreement within 5e-5 for all 34 pairs, both orders
        // (the formula is symmetric).
        for (i, r) in SHARMA_2005.iter().enumerate() {
            let (a, b) = ([r[0], r[1], r[2]], [r[3], r[4], r[5]]);
            let d = ciede2000(a, b);
            assert!((d - r[6]).abs() < 5e-5, "pair {}: {d} vs {}", i + 1, r[6]);
            assert!((ciede2000(b, a) - d).abs() < 1e-12, "pair {}", i + 1);
        }
        // The check can fail: the plain Euclidean ΔE*ab (CIE 1976) misses pair 1 by more
        // than the tolerance.
        let r = SHARMA_2005[0];
        let plain = ((r[0] - r[3]).powi(2) + (r[1] - r[4]).powi(2) + (r[2] - r[5]).powi(2)).sqrt();
        assert!((plain - r[6]).abs() > 0.1, "{plain}");
    }

    #[test]
    fn lab_of_white_grey_and_a_closed_form() {
        let w = [0.95, 1.0, 1.09];
        let lab = xyz_to_lab(w, w);
        assert!((lab[0] - 100.0).abs() < 1e-12 && lab[1].abs() < 1e-12 && lab[2].abs() < 1e-12);
        // Y/Yn = 0.18 (above the linear segment): L* = 116·0.18^(1/3) − 16.
        let g = xyz_to_lab([0.18 * 0.95, 0.18, 0.18 * 1.09], w);
        assert!((g[0] - (116.0 * 0.18f64.powf(1.0 / 3.0) - 16.0)).abs() < 1e-9);
        // Below (6/29)^3 the linear segment: L* = 903.2963·Y/Yn (= (29/3)^3).
        let d = xyz_to_lab([0.001 * 0.95, 0.001, 0.001 * 1.09], w);
        assert!(
            (d[0] - 0.001 * (29.0f64 / 3.0).powi(3)).abs() < 1e-9,
            "{}",
            d[0]
        );
    }

    #[test]
    fn colour_errors_of_a_swapped_object() {
        let bl = crate::spectra::display_spectrum(crate::spectra::DisplaySpectrumKind::WhiteLed);
        let (p, _) = crate::spectra::display_primaries(&bl);
        let m = primaries_to_xyz(&p);
        // Y of the green primary exceeds red's and blue's (the eye's sensitivity peaks at 555 nm).
        assert!(m[1][1] > m[1][0] && m[1][1] > m[1][2], "{m:?}");
        // A pure red object: exact reconstruction 0 error, all energy in R; the same object
        // put into G fails with a large ΔE.
        let n = 4;
        let mut red = vec![0.0; 3 * n];
        red[..n].fill(0.8);
        let e = colour_errors(&red, &red, &m);
        assert!(
            e.ciede2000_mean.abs() < 1e-12 && e.psnr_db.is_infinite(),
            "{e:?}"
        );
        assert_eq!(e.energy_share, [1.0, 0.0, 0.0]);
        let mut green = vec![0.0; 3 * n];
        green[n..2 * n].fill(0.8);
        let bad = colour_errors(&green, &red, &m);
        assert!(bad.ciede2000_mean > 50.0, "{bad:?}");
        assert_eq!(bad.energy_share, [0.0, 1.0, 0.0]);
    }
}
