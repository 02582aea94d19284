//! Optical constants of the waveguide glass: refractive index n(λ), extinction
//! coefficient k(λ), intensity absorption and Beer–Lambert transmittance.
//!
//! Model and sources (physics reference §4.2, via the refractiveindex.info database):
//! - **Soda-lime** clear window glass, Rubin, Sol. Energy Mater. 12, 275 (1985)
//!   (`data-nk/glass/misc/soda-lime/Rubin-clear.yml`):
//!   n(λ) = 1.5130 − 0.003169 λ² + 0.003962 λ⁻² (λ in µm, valid 0.31–4.6 µm);
//!   k tabulated at 450, 500, 530, 550, 600 nm.
//! - **N-BK7**, SCHOTT catalogue Sellmeier formula (`data-nk/glass/schott/N-BK7.yml`),
//!   valid 0.3–2.5 µm; k ≈ 1e−8 (negligible absorption).
//! - **Constant**: a non-dispersive, lossless medium of fixed index.
//!
//! Assumptions:
//! - Wavelengths outside a formula's validity range are clamped to that range, so every
//!   finite input gives a finite output (a NaN wavelength propagates as NaN).
//! - The soda-lime k table is interpolated linearly in λ and held constant outside
//!   450–600 nm (no data there; the true k rises towards the UV and the near-IR iron band).
//! - Intensity absorption α_int = 4πk/λ; bulk glass only (no surface or film losses).
//! - Which glass the paper used is not stated; soda-lime is the safer default.

use crate::spectra::interp_clamped;

/// Soda-lime extinction table (λ in nm, k), Rubin (1985).
const SODA_LIME_K: [(f64, f64); 5] = [
    (450.0, 1.925e-7),
    (500.0, 1.492e-7),
    (530.0, 1.769e-7),
    (550.0, 2.200e-7),
    (600.0, 4.548e-7),
];

/// N-BK7 Sellmeier B coefficients (dimensionless), SCHOTT.
const BK7_B: [f64; 3] = [1.039_612_12, 0.231_792_344, 1.010_469_45];
/// N-BK7 Sellmeier C coefficients (µm²), SCHOTT.
const BK7_C: [f64; 3] = [0.006_000_698_67, 0.020_017_914_4, 103.560_653];

/// Waveguide glass material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Glass {
    /// Clear soda-lime window glass (Rubin 1985): dispersive and weakly absorbing.
    SodaLime,
    /// SCHOTT N-BK7 borosilicate crown: dispersive, negligible absorption.
    NBk7,
    /// Non-dispersive, lossless medium of fixed refractive index `n`.
    Constant {
        /// Refractive index (wavelength independent).
        n: f64,
    },
}

impl Glass {
    /// Validity range of the dispersion formula in nm; inputs are clamped to it.
    fn valid_range_nm(&self) -> (f64, f64) {
        match self {
            Glass::SodaLime => (310.0, 4600.0),
            Glass::NBk7 => (300.0, 2500.0),
            Glass::Constant { .. } => (1.0, 1.0e6),
        }
    }

    /// Wavelength clamped to the validity range (NaN stays NaN).
    fn clamp_nm(&self, lambda_nm: f64) -> f64 {
        let (lo, hi) = self.valid_range_nm();
        lambda_nm.clamp(lo, hi)
    }

    /// Real refractive index n at vacuum wavelength `lambda_nm` (nm).
    ///
    /// Soda-lime: Rubin (1985) Cauchy-type fit; N-BK7: SCHOTT Sellmeier formula;
    /// Constant: `n`. The wavelength is clamped to the formula's validity range.
    #[inline]
    pub fn index(&self, lambda_nm: f64) -> f64 {
        let l_um = self.clamp_nm(lambda_nm) * 1e-3;
        let l2 = l_um * l_um;
        match self {
            Glass::SodaLime => 1.5130 - 0.003169 * l2 + 0.003962 / l2,
            Glass::NBk7 => {
                let n2 = 1.0
                    + BK7_B
                        .iter()
                        .zip(BK7_C)
                        .map(|(b, c)| b * l2 / (l2 - c))
                        .sum::<f64>();
                n2.max(0.0).sqrt()
            }
            Glass::Constant { n } => *n,
        }
    }

    /// Extinction coefficient k (imaginary part of the complex index) at `lambda_nm`.
    ///
    /// Soda-lime: Rubin (1985) table at 450, 500, 530, 550, 600 nm, linearly
    /// interpolated in λ. **Assumption:** k is held constant at the end values outside
    /// 450–600 nm (no data there). N-BK7: 1e−8 everywhere (negligible). Constant: 0.
    pub fn extinction_k(&self, lambda_nm: f64) -> f64 {
        match self {
            Glass::SodaLime => interp_clamped(&SODA_LIME_K, lambda_nm),
            Glass::NBk7 => 1e-8,
            Glass::Constant { .. } => 0.0,
        }
    }

    /// Intensity absorption coefficient α_int = 4πk/λ in 1/mm (λ converted to mm).
    ///
    /// Soda-lime at 530 nm gives ≈ 0.0042 /mm.
    #[inline]
    pub fn absorption_per_mm(&self, lambda_nm: f64) -> f64 {
        let k = self.extinction_k(lambda_nm);
        if k == 0.0 {
            return 0.0;
        }
        let lambda_mm = self.clamp_nm(lambda_nm) * 1e-6;
        4.0 * std::f64::consts::PI * k / lambda_mm
    }

    /// Beer–Lambert bulk transmittance exp(−α_int·path) for a geometric path of
    /// `path_mm` in the glass. Negative or NaN paths are treated as 0 (result 1).
    pub fn transmittance(&self, lambda_nm: f64, path_mm: f64) -> f64 {
        (-self.absorption_per_mm(lambda_nm) * path_mm.max(0.0)).exp()
    }

    /// Short human-readable label: "soda-lime", "n-bk7", or the constant index.
    pub fn label(&self) -> String {
        match self {
            Glass::SodaLime => "soda-lime".to_string(),
            Glass::NBk7 => "n-bk7".to_string(),
            Glass::Constant { n } => format!("{n}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn soda_lime_index_at_532() {
        assert!((Glass::SodaLime.index(532.0) - 1.5262).abs() <= 1e-4);
    }

    #[test]
    fn nbk7_index() {
        assert!((Glass::NBk7.index(532.0) - 1.51947).abs() <= 2e-5);
        assert!((Glass::NBk7.index(587.56) - 1.5168).abs() <= 1e-4);
    }

    #[test]
    fn constant_glass() {
        let g = Glass::Constant { n: 1.5 };
        assert_eq!(g.index(400.0), 1.5);
        assert_eq!(g.extinction_k(400.0), 0.0);
        assert_eq!(g.transmittance(500.0, 100.0), 1.0);
        assert_eq!(g.label(), "1.5");
    }

    #[test]
    fn soda_lime_k_table_and_clamp() {
        let g = Glass::SodaLime;
        assert_eq!(g.extinction_k(530.0), 1.769e-7);
        assert!((g.extinction_k(515.0) - 0.5 * (1.492e-7 + 1.769e-7)).abs() < 1e-15);
        assert_eq!(g.extinction_k(380.0), 1.925e-7);
        assert_eq!(g.extinction_k(780.0), 4.548e-7);
    }

    #[test]
    fn soda_lime_absorption_and_round_trip() {
        let g = Glass::SodaLime;
        assert!((g.absorption_per_mm(530.0) - 0.0042).abs() <= 1e-4);
        assert!((g.transmittance(530.0, 8.3) - 0.966).abs() <= 0.002);
        assert_eq!(g.transmittance(530.0, -1.0), 1.0);
    }

    #[test]
    fn labels() {
        assert_eq!(Glass::SodaLime.label(), "soda-lime");
        assert_eq!(Glass::NBk7.label(), "n-bk7");
    }

    #[test]
    fn finite_for_extreme_wavelengths() {
        for g in [Glass::SodaLime, Glass::NBk7] {
            for l in [0.0, -5.0, 1e-300, 1e300, f64::INFINITY] {
                assert!(g.index(l).is_finite());
                assert!(g.absorption_per_mm(l).is_finite());
                assert!(g.transmittance(l, 10.0).is_finite());
            }
        }
    }

    proptest! {
        #[test]
        fn index_physical_and_normal_dispersion(
            a in 360.0f64..830.0, b in 360.0f64..830.0, path in 0.0f64..200.0
        ) {
            for g in [Glass::SodaLime, Glass::NBk7] {
                let n = g.index(a);
                prop_assert!(n.is_finite() && (1.0..=3.0).contains(&n));
                if b - a > 1e-6 {
                    prop_assert!(g.index(a) > g.index(b));
                }
                let t = g.transmittance(a, path);
                prop_assert!(t > 0.0 && t <= 1.0);
            }
        }
    }
}
