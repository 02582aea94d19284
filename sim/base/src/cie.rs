//! Colour spaces of the frontal ground truth: the sensor's own RGB, CIE 1931 XYZ or linear sRGB.
//!
//! Model: a frontal pixel holds linear functionals of the spectral radiance L(λ) over
//! the scene's sampling band [λ₀, λ₁]:
//! - `sensor`: channel k = ∫ L R_k dλ / ∫ R_k dλ (the capture's response R_k);
//! - `xyz`: (X, Y, Z) = ∫ L (x̄, ȳ, z̄) dλ / ∫ ȳ dλ with the CIE 1931 2° standard observer,
//!   so a spectrally flat radiance equal to the display's white level (L = 1, the unit every
//!   emission spectrum's mean is normalised to) reads Y = 1, like the sensor's channels;
//! - `linear-srgb`: M·(X, Y, Z) with M the XYZ → linear sRGB matrix of IEC 61966-2-1:1999
//!   (Rec. 709 primaries, D65 white; the standard's 4-decimal values), so a D65 spectrum reads
//!   R = G = B (to the matrix's rounding, ≈ 1e−4) and Y is unchanged.
//!
//! Assumptions: the CMFs are read by linear interpolation of the 5 nm table and are 0 outside
//! 360–830 nm; the integrals run over the sampling band only (for the default 380–780 nm band
//! the missing tails hold < 0.01 % of ∫ ȳ), as the sensor's do.
//!
//! Source: the CMF values are CIE 015:2018 / ISO 11664-1 (CIE 1931 2° observer, 5 nm,
//! 360–830 nm), copied from the table `OBSERVER_X/Y/Z` in `src/optimize/cie1931.rs` of the
//! `rgb2spec` crate 0.1.1 (already a dependency), which carries this notice:
//! "Copyright (c) 2022 Nathan van der Kamp (rust port); Copyright (c) 2020 Wenzel Jakob
//! <wenzel.jakob@epfl.ch>, All rights reserved." under the BSD 3-Clause licence
//! (redistributions of source code must retain that copyright notice, the list of conditions
//! and the disclaimer; see the crate's LICENSE file).

use crate::spectra::Spectrum;

/// The colour space of the frontal ground truth.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum FrontalSpace {
    /// The capture's sensor response (raw camera RGB, or `Y` for a monochrome sensor).
    #[default]
    Sensor,
    /// CIE 1931 XYZ (2° observer), Y = 1 for a flat unit radiance.
    Xyz,
    /// Linear sRGB / Rec. 709 primaries, D65 white, from XYZ by IEC 61966-2-1.
    LinearSrgb,
}

impl FrontalSpace {
    /// The CLI spelling.
    pub fn name(self) -> &'static str {
        match self {
            FrontalSpace::Sensor => "sensor",
            FrontalSpace::Xyz => "xyz",
            FrontalSpace::LinearSrgb => "linear-srgb",
        }
    }

    /// Parses the CLI spelling (`sensor`, `xyz`, `linear-srgb`).
    pub fn parse(s: &str) -> Option<FrontalSpace> {
        match s {
            "sensor" => Some(FrontalSpace::Sensor),
            "xyz" => Some(FrontalSpace::Xyz),
            "linear-srgb" => Some(FrontalSpace::LinearSrgb),
            _ => None,
        }
    }

    /// Channel names of a standard space (None for `sensor`, whose names are the sensor's).
    pub fn channel_names(self) -> Option<Vec<&'static str>> {
        match self {
            FrontalSpace::Sensor => None,
            FrontalSpace::Xyz => Some(vec!["X", "Y", "Z"]),
            FrontalSpace::LinearSrgb => Some(vec!["R", "G", "B"]),
        }
    }

    /// What a pixel's channels mean (without the geometry), for capture.json and the EXR.
    pub fn units(self) -> &'static str {
        match self {
            FrontalSpace::Sensor => {
                "spectral radiance weighted by the sensor response, in the capture unit (1 = a white display pixel)"
            }
            FrontalSpace::Xyz => {
                "CIE 1931 XYZ (2-degree observer) of the spectral radiance over the sampling band, (X, Y, Z) = integral of L (xbar, ybar, zbar) / integral of ybar, so a spectrally flat radiance at the display's white level reads Y = 1"
            }
            FrontalSpace::LinearSrgb => {
                "linear sRGB (Rec. 709 primaries, D65 white; XYZ to RGB matrix of IEC 61966-2-1) of the CIE 1931 XYZ with Y = 1 for a spectrally flat radiance at the display's white level"
            }
        }
    }
}

/// CIE 1931 2° colour-matching functions (x̄, ȳ, z̄), 360–830 nm in 5 nm steps.
#[rustfmt::skip]
#[allow(clippy::excessive_precision)]
const CMF_5NM: [[f64; 3]; 95] = [
    [0.0001299, 3.917e-06, 0.0006061], // 360 nm
    [0.0002321, 6.965e-06, 0.001086], // 365 nm
    [0.0004149, 1.239e-05, 0.001946], // 370 nm
    [0.0007416, 2.202e-05, 0.003486], // 375 nm
    [0.001368, 3.9e-05, 0.006450001], // 380 nm
    [0.002236, 6.4e-05, 0.01054999], // 385 nm
    [0.004243, 0.00012, 0.02005001], // 390 nm
    [0.00765, 0.000217, 0.03621], // 395 nm
    [0.01431, 0.000396, 0.06785001], // 400 nm
    [0.02319, 0.00064, 0.1102], // 405 nm
    [0.04351, 0.00121, 0.2074], // 410 nm
    [0.07763, 0.00218, 0.3713], // 415 nm
    [0.13438, 0.004, 0.6456], // 420 nm
    [0.21477, 0.0073, 1.0390501], // 425 nm
    [0.2839, 0.0116, 1.3856], // 430 nm
    [0.3285, 0.01684, 1.62296], // 435 nm
    [0.34828, 0.023, 1.74706], // 440 nm
    [0.34806, 0.0298, 1.7826], // 445 nm
    [0.3362, 0.038, 1.77211], // 450 nm
    [0.3187, 0.048, 1.7441], // 455 nm
    [0.2908, 0.06, 1.6692], // 460 nm
    [0.2511, 0.0739, 1.5281], // 465 nm
    [0.19536, 0.09098, 1.28764], // 470 nm
    [0.1421, 0.1126, 1.0419], // 475 nm
    [0.09564, 0.13902, 0.8129501], // 480 nm
    [0.05795001, 0.1693, 0.6162], // 485 nm
    [0.03201, 0.20802, 0.46518], // 490 nm
    [0.0147, 0.2586, 0.3533], // 495 nm
    [0.0049, 0.323, 0.272], // 500 nm
    [0.0024, 0.4073, 0.2123], // 505 nm
    [0.0093, 0.503, 0.1582], // 510 nm
    [0.0291, 0.6082, 0.1117], // 515 nm
    [0.06327, 0.71, 0.07824999], // 520 nm
    [0.1096, 0.7932, 0.05725001], // 525 nm
    [0.1655, 0.862, 0.04216], // 530 nm
    [0.2257499, 0.9148501, 0.02984], // 535 nm
    [0.2904, 0.954, 0.0203], // 540 nm
    [0.3597, 0.9803, 0.0134], // 545 nm
    [0.4334499, 0.9949501, 0.008749999], // 550 nm
    [0.5120501, 1.0, 0.005749999], // 555 nm
    [0.5945, 0.995, 0.0039], // 560 nm
    [0.6784, 0.9786, 0.002749999], // 565 nm
    [0.7621, 0.952, 0.0021], // 570 nm
    [0.8425, 0.9154, 0.0018], // 575 nm
    [0.9163, 0.87, 0.001650001], // 580 nm
    [0.9786, 0.8163, 0.0014], // 585 nm
    [1.0263, 0.757, 0.0011], // 590 nm
    [1.0567, 0.6949, 0.001], // 595 nm
    [1.0622, 0.631, 0.0008], // 600 nm
    [1.0456, 0.5668, 0.0006], // 605 nm
    [1.0026, 0.503, 0.00034], // 610 nm
    [0.9384, 0.4412, 0.00024], // 615 nm
    [0.8544499, 0.381, 0.00019], // 620 nm
    [0.7514, 0.321, 0.0001], // 625 nm
    [0.6424, 0.265, 4.999999e-05], // 630 nm
    [0.5419, 0.217, 3e-05], // 635 nm
    [0.4479, 0.175, 2e-05], // 640 nm
    [0.3608, 0.1382, 1e-05], // 645 nm
    [0.2835, 0.107, 0.0], // 650 nm
    [0.2187, 0.0816, 0.0], // 655 nm
    [0.1649, 0.061, 0.0], // 660 nm
    [0.1212, 0.04458, 0.0], // 665 nm
    [0.0874, 0.032, 0.0], // 670 nm
    [0.0636, 0.0232, 0.0], // 675 nm
    [0.04677, 0.017, 0.0], // 680 nm
    [0.0329, 0.01192, 0.0], // 685 nm
    [0.0227, 0.00821, 0.0], // 690 nm
    [0.01584, 0.005723, 0.0], // 695 nm
    [0.01135916, 0.004102, 0.0], // 700 nm
    [0.008110916, 0.002929, 0.0], // 705 nm
    [0.005790346, 0.002091, 0.0], // 710 nm
    [0.004109457, 0.001484, 0.0], // 715 nm
    [0.002899327, 0.001047, 0.0], // 720 nm
    [0.00204919, 0.00074, 0.0], // 725 nm
    [0.001439971, 0.00052, 0.0], // 730 nm
    [0.0009999493, 0.0003611, 0.0], // 735 nm
    [0.0006900786, 0.0002492, 0.0], // 740 nm
    [0.0004760213, 0.0001719, 0.0], // 745 nm
    [0.0003323011, 0.00012, 0.0], // 750 nm
    [0.0002348261, 8.48e-05, 0.0], // 755 nm
    [0.0001661505, 6e-05, 0.0], // 760 nm
    [0.000117413, 4.24e-05, 0.0], // 765 nm
    [8.307527e-05, 3e-05, 0.0], // 770 nm
    [5.870652e-05, 2.12e-05, 0.0], // 775 nm
    [4.150994e-05, 1.499e-05, 0.0], // 780 nm
    [2.935326e-05, 1.06e-05, 0.0], // 785 nm
    [2.067383e-05, 7.4657e-06, 0.0], // 790 nm
    [1.455977e-05, 5.2578e-06, 0.0], // 795 nm
    [1.025398e-05, 3.7029e-06, 0.0], // 800 nm
    [7.221456e-06, 2.6078e-06, 0.0], // 805 nm
    [5.085868e-06, 1.8366e-06, 0.0], // 810 nm
    [3.581652e-06, 1.2934e-06, 0.0], // 815 nm
    [2.522525e-06, 9.1093e-07, 0.0], // 820 nm
    [1.776509e-06, 6.4153e-07, 0.0], // 825 nm
    [1.251141e-06, 4.5181e-07, 0.0], // 830 nm
];

/// First wavelength of [`CMF_5NM`] (nm).
const CMF_START_NM: f64 = 360.0;
/// Step of [`CMF_5NM`] (nm).
const CMF_STEP_NM: f64 = 5.0;

/// XYZ → linear sRGB (IEC 61966-2-1:1999, equation (F.7) values), rows R, G, B.
pub const XYZ_TO_LINEAR_SRGB: [[f64; 3]; 3] = [
    [3.2406, -1.5372, -0.4986],
    [-0.9689, 1.8758, 0.0415],
    [0.0557, -0.2040, 1.0570],
];

/// One CIE colour-matching function as a [`Spectrum`] (0 outside 360–830 nm).
pub fn cmf(k: usize) -> Spectrum {
    let end = CMF_START_NM + (CMF_5NM.len() - 1) as f64 * CMF_STEP_NM;
    Spectrum::from_fn(CMF_START_NM, end, CMF_STEP_NM, |l| {
        let i = ((l - CMF_START_NM) / CMF_STEP_NM).round() as usize;
        CMF_5NM.get(i).map_or(0.0, |v| v[k.min(2)])
    })
}

/// `m`·`v`.
pub fn mat3(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    m.map(|row| row[0] * v[0] + row[1] * v[1] + row[2] * v[2])
}

/// Spectral weights of a standard space over a band: w(λ) such that a channel is ∫ L w dλ.
#[derive(Clone, Debug)]
pub struct ColourWeights {
    space: FrontalSpace,
    cmfs: [Spectrum; 3],
    /// 1 / ∫ ȳ over the band.
    inv_y: f64,
    /// 1 / ∫ x̄, ȳ, z̄ over the band (for the sampling density).
    inv_each: [f64; 3],
}

impl ColourWeights {
    /// Weights of `space` (`xyz` or `linear-srgb`; None for `sensor` or a band where ȳ is 0).
    pub fn new(space: FrontalSpace, lo_nm: f64, hi_nm: f64) -> Option<ColourWeights> {
        if space == FrontalSpace::Sensor {
            return None;
        }
        let cmfs = [cmf(0), cmf(1), cmf(2)];
        let ints = cmfs.clone().map(|c| c.integral(lo_nm, hi_nm));
        if ints[1].is_nan() || ints[1] <= 0.0 {
            return None;
        }
        let inv_each = ints.map(|i| if i > 0.0 { 1.0 / i } else { 0.0 });
        Some(ColourWeights {
            space,
            cmfs,
            inv_y: 1.0 / ints[1],
            inv_each,
        })
    }

    /// The three channel weights at `lambda_nm` (X, Y, Z or R, G, B).
    pub fn at(&self, lambda_nm: f64) -> [f64; 3] {
        let xyz = [0, 1, 2].map(|k| self.cmfs[k].eval(lambda_nm) * self.inv_y);
        match self.space {
            FrontalSpace::LinearSrgb => mat3(&XYZ_TO_LINEAR_SRGB, xyz),
            FrontalSpace::Xyz | FrontalSpace::Sensor => xyz,
        }
    }

    /// A sampling density shape ∝ Σ_k cmf_k(λ)/∫ cmf_k (non-negative, also for sRGB).
    pub fn density(&self, lambda_nm: f64) -> f64 {
        (0..3)
            .map(|k| self.cmfs[k].eval(lambda_nm) * self.inv_each[k])
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cmf_at_600_nm_matches_the_cie_table() {
        // CIE 1931 2° at 600 nm: 1.0622, 0.6310, 0.0008 (CIE 015:2018 Table).
        let v = [0, 1, 2].map(|k| cmf(k).eval(600.0));
        assert_eq!(v, [1.0622, 0.631, 0.0008]);
        // Linear interpolation between 600 and 605 nm.
        assert!((cmf(1).eval(602.5) - (0.631 + 0.5668) / 2.0).abs() < 1e-12);
        assert_eq!(cmf(1).eval(900.0), 0.0);
    }
}
