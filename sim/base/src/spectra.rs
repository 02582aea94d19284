//! Tabulated spectra and the spectral models of the simulator: display (LCD backlight)
//! emission and camera-sensor responses.
//!
//! Model: every spectrum is a table on a uniform grid (the standard grid is 1 nm from
//! 360 to 830 nm) read back by linear interpolation, 0 outside the table; integrals are
//! exact for that piecewise-linear interpolant.
//!
//! Sources (physics reference §6) and assumptions:
//! - Display spectra are **illustrative**, not measured for the HP ZR2440W (whose
//!   backlight type is unverified). The white LED uses the Ohno (2005) LED shape as in
//!   colour-science `sd_single_led_Ohno2005`; the CCFL line positions (436, 487, 545, 587,
//!   611 nm) are standard Hg/rare-earth phosphor lines with UNVERIFIED relative heights.
//!   All display spectra are normalised to mean 1 over 380–780 nm.
//! - Mono QE: ON Semiconductor PYTHON 1300 (NOIP1SN1300A) NIR-mono datasheet trace as
//!   digitised in `utat-ss/HyperspectralImagerGUI` (`data/qe/python1300_nir_mono.csv`);
//!   the values outside 430–650 nm are assumptions.
//! - Colour-filter-array (CFA) and IR-cut curves are a generic dye-CFA model; the measured
//!   PYTHON 1300 colour curves were not found. "Monochrome mode" Y = R/4 + G/2 + B/4 is
//!   from the Point Grey Flea3 reference, UNVERIFIED for the Chameleon3.

/// First wavelength of the standard spectral grid (nm).
pub const GRID_START_NM: f64 = 360.0;
/// Last wavelength of the standard spectral grid (nm).
pub const GRID_END_NM: f64 = 830.0;
/// Step of the standard spectral grid (nm).
pub const GRID_STEP_NM: f64 = 1.0;
/// Lower bound of the band over which display spectra are normalised to mean 1 (nm).
pub const NORM_LO_NM: f64 = 380.0;
/// Upper bound of the band over which display spectra are normalised to mean 1 (nm).
pub const NORM_HI_NM: f64 = 780.0;
/// FWHM of the Ohno (2005) shape (g + 2g⁵)/3, g = exp(−((λ − λp)/Δλ½)²), in units of
/// its width parameter Δλ½: FWHM = 0.9218·Δλ½ (from (g + 2g⁵)/3 = ½ at g = 0.80861).
pub const OHNO_FWHM_PER_WIDTH: f64 = 0.921_823_119_649_820_4;

/// Upper bound on the number of samples of a table (guards against absurd grids).
const MAX_SAMPLES: usize = 1 << 24;

/// A spectrum tabulated on a uniform wavelength grid, read by linear interpolation.
#[derive(Clone, Debug)]
pub struct Spectrum {
    start_nm: f64,
    step_nm: f64,
    values: Vec<f64>,
}

impl Spectrum {
    /// Tabulates `f` at `start_nm + i·step_nm` for every sample not beyond `end_nm`
    /// (with a 1e−9-step tolerance). Non-finite values of `f` are stored as 0. An invalid
    /// grid (non-finite bounds, `step_nm <= 0` or `end_nm < start_nm`) gives a single
    /// sample at `start_nm` (or at 0 if `start_nm` is not finite).
    pub fn from_fn(start_nm: f64, end_nm: f64, step_nm: f64, f: impl Fn(f64) -> f64) -> Spectrum {
        let valid = start_nm.is_finite() && end_nm.is_finite() && step_nm > 0.0;
        let valid = valid && step_nm.is_finite() && end_nm >= start_nm;
        let start_nm = if start_nm.is_finite() { start_nm } else { 0.0 };
        let (step_nm, n) = if valid {
            let n = ((end_nm - start_nm) / step_nm + 1e-9).floor();
            (step_nm, (n.min(MAX_SAMPLES as f64) as usize) + 1)
        } else {
            (1.0, 1)
        };
        let values = (0..n)
            .map(|i| finite_or_zero(f(start_nm + i as f64 * step_nm)))
            .collect();
        Spectrum {
            start_nm,
            step_nm,
            values,
        }
    }

    /// Tabulates `f` on the standard 1 nm grid from 360 to 830 nm.
    pub fn on_grid(f: impl Fn(f64) -> f64) -> Spectrum {
        Spectrum::from_fn(GRID_START_NM, GRID_END_NM, GRID_STEP_NM, f)
    }

    /// First wavelength of the table (nm).
    pub fn start_nm(&self) -> f64 {
        self.start_nm
    }

    /// Last wavelength of the table (nm).
    pub fn end_nm(&self) -> f64 {
        self.start_nm + self.last_index() as f64 * self.step_nm
    }

    /// Grid step of the table (nm).
    pub fn step_nm(&self) -> f64 {
        self.step_nm
    }

    /// The tabulated samples, at `start_nm() + i·step_nm()`.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    fn last_index(&self) -> usize {
        self.values.len().saturating_sub(1)
    }

    /// Value of segment `i` (between samples i and i+1) at fractional grid position `t`.
    fn seg_value(&self, i: usize, t: f64) -> f64 {
        match (self.values.get(i), self.values.get(i + 1)) {
            (Some(&a), Some(&b)) => a + (b - a) * (t - i as f64),
            (Some(&a), None) => a,
            _ => 0.0,
        }
    }

    /// Linearly interpolated value at `lambda_nm`; 0 outside the table (and for NaN).
    #[inline]
    pub fn eval(&self, lambda_nm: f64) -> f64 {
        let t = (lambda_nm - self.start_nm) / self.step_nm;
        let last = self.last_index();
        if t.is_nan() || t < 0.0 || t > last as f64 {
            return 0.0;
        }
        let i = (t.floor() as usize).min(last.saturating_sub(1));
        self.seg_value(i, t)
    }

    /// Exact integral (value × nm) of the piecewise-linear interpolant over
    /// [`lo_nm`, `hi_nm`] clipped to the table; 0 if the clipped interval is empty
    /// (including `hi_nm <= lo_nm`). A NaN bound is replaced by the table end.
    pub fn integral(&self, lo_nm: f64, hi_nm: f64) -> f64 {
        let last = self.last_index();
        let ta = ((lo_nm - self.start_nm) / self.step_nm).max(0.0);
        let tb = ((hi_nm - self.start_nm) / self.step_nm).min(last as f64);
        if last == 0 || tb <= ta {
            return 0.0;
        }
        let i0 = (ta.floor() as usize).min(last - 1);
        let i1 = (tb.ceil() as usize).clamp(i0 + 1, last);
        (i0..i1)
            .map(|i| {
                let u0 = ta.max(i as f64);
                let u1 = tb.min((i + 1) as f64);
                if u1 > u0 {
                    0.5 * (u1 - u0) * (self.seg_value(i, u0) + self.seg_value(i, u1))
                } else {
                    0.0
                }
            })
            .sum::<f64>()
            * self.step_nm
    }

    /// Copy with every sample multiplied by `s` (non-finite products become 0).
    pub fn scaled(&self, s: f64) -> Spectrum {
        Spectrum {
            values: self.values.iter().map(|v| finite_or_zero(v * s)).collect(),
            ..self.clone()
        }
    }

    /// Largest tabulated sample.
    pub fn max_value(&self) -> f64 {
        self.values
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max)
    }
}

fn finite_or_zero(v: f64) -> f64 {
    if v.is_finite() { v } else { 0.0 }
}

/// Gaussian of unit peak at `centre_nm` with full width at half maximum `fwhm_nm`.
fn gaussian_fwhm(lambda_nm: f64, centre_nm: f64, fwhm_nm: f64) -> f64 {
    let x = (lambda_nm - centre_nm) / fwhm_nm;
    (-4.0 * std::f64::consts::LN_2 * x * x).exp()
}

/// Ohno (2005) single-LED shape of unit peak, width parameter `width_nm` = Δλ½.
fn ohno_led(lambda_nm: f64, peak_nm: f64, width_nm: f64) -> f64 {
    let x = (lambda_nm - peak_nm) / width_nm;
    let g = (-x * x).exp();
    (g + 2.0 * g.powi(5)) / 3.0
}

/// Logistic step from 0 to 1 with its 50 % point at `edge_nm` and scale `width_nm`.
fn logistic(lambda_nm: f64, edge_nm: f64, width_nm: f64) -> f64 {
    1.0 / (1.0 + (-(lambda_nm - edge_nm) / width_nm).exp())
}

/// Emission-spectrum model of the display (LCD backlight through a white pixel).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DisplaySpectrumKind {
    /// Spectrally flat (equal-energy) emission.
    Flat,
    /// Blue-pumped YAG:Ce white LED (illustrative Ohno-shape model).
    WhiteLed,
    /// Cold-cathode fluorescent lamp: narrow Hg / rare-earth phosphor lines (illustrative).
    Ccfl,
}

/// Display emission spectrum on the standard grid, normalised to mean 1 over
/// 380–780 nm (integral over 380..780 nm = 400).
///
/// - `Flat`: constant.
/// - `WhiteLed`: blue pump = Ohno (2005) shape (g + 2g⁵)/3, g = exp(−((λ − 450)/Δλ½)²),
///   with Δλ½ = 20 nm / [`OHNO_FWHM_PER_WIDTH`] so the pump FWHM is 20 nm (Δλ½ is the
///   Gaussian width parameter of the formula, not the FWHM of the final shape); plus a
///   YAG:Ce phosphor band modelled as a Gaussian at 560 nm, FWHM 120 nm, peak 0.6× the
///   blue peak. Illustrative values, not measured for the HP ZR2440W; the model has a
///   dip near 480–485 nm.
/// - `Ccfl`: Gaussian lines of 2 nm FWHM at 436, 487, 545, 587, 611 nm with relative
///   heights 0.55, 0.35, 1.0, 0.25, 0.8 (UNVERIFIED, illustrative) on a flat floor of
///   1 % of the peak so that no band is exactly dark. The 1 nm grid only coarsely
///   resolves the 2 nm lines; line areas are preserved to well under 1 %.
pub fn display_spectrum(kind: DisplaySpectrumKind) -> Spectrum {
    const CCFL_LINES: [(f64, f64); 5] = [
        (436.0, 0.55),
        (487.0, 0.35),
        (545.0, 1.0),
        (587.0, 0.25),
        (611.0, 0.80),
    ];
    let raw = match kind {
        DisplaySpectrumKind::Flat => Spectrum::on_grid(|_| 1.0),
        DisplaySpectrumKind::WhiteLed => Spectrum::on_grid(|l| {
            ohno_led(l, 450.0, 20.0 / OHNO_FWHM_PER_WIDTH) + 0.6 * gaussian_fwhm(l, 560.0, 120.0)
        }),
        DisplaySpectrumKind::Ccfl => Spectrum::on_grid(|l| {
            0.01 + CCFL_LINES
                .iter()
                .map(|&(c, h)| h * gaussian_fwhm(l, c, 2.0))
                .sum::<f64>()
        }),
    };
    let mean = raw.integral(NORM_LO_NM, NORM_HI_NM) / (NORM_HI_NM - NORM_LO_NM);
    if mean > 0.0 && mean.is_finite() {
        raw.scaled(1.0 / mean)
    } else {
        raw
    }
}

/// The three primaries (R, G, B) of a colour LCD with backlight `backlight`: primary p
/// emits P_p(λ) = k·B(λ)·T_p(λ), with T_p the colour filter of sub-pixel p, and k chosen so
/// that white, P_R + P_G + P_B, has mean 1 over 380–780 nm (the unit of every display
/// spectrum). Returns ([P_R, P_G, P_B], white).
///
/// ASSUMPTION (no measured LCD filter data): the LCD's colour filters are the same
/// illustrative dye curves as the sensor's CFA model (`cfa_rgb`: B peak 0.8 at 460 nm, G 0.85
/// at 535 nm, both FWHM 100 nm, R a step through 590 nm to 0.9, 0.02 leakage floor); LCD and
/// image-sensor colour filters are both pigment-dispersed dye filters of similar shape. With
/// the white-LED backlight the blue primary is the 450 nm pump, green and red are the YAG:Ce
/// band cut by the filters, as in a typical sRGB-class white-LED LCD. White is backlight ×
/// (T_R + T_G + T_B) as physics reference §6.1 puts it; the sub-pixels' equal drive at code 1
/// (no white-balance scaling per primary) is part of the assumption.
pub fn display_primaries(backlight: &Spectrum) -> ([Spectrum; 3], Spectrum) {
    let raw: [Spectrum; 3] =
        std::array::from_fn(|p| Spectrum::on_grid(|l| backlight.eval(l) * cfa_rgb(l)[p]));
    let white_raw = Spectrum::on_grid(|l| raw.iter().map(|s| s.eval(l)).sum());
    let mean = white_raw.integral(NORM_LO_NM, NORM_HI_NM) / (NORM_HI_NM - NORM_LO_NM);
    let k = if mean > 0.0 && mean.is_finite() {
        1.0 / mean
    } else {
        1.0
    };
    let prim = raw.map(|s| s.scaled(k));
    let white = Spectrum::on_grid(|l| prim.iter().map(|s| s.eval(l)).sum());
    (prim, white)
}

/// Camera spectral-response model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SensorResponseKind {
    /// PYTHON 1300 monochrome QE (no CFA, no IR-cut).
    MonoQe,
    /// Colour PYTHON 1300 in Point Grey "monochrome mode": Y = R/4 + G/2 + B/4.
    MonoBayerY,
    /// Ideal flat response of 1.
    Flat,
    /// Colour PYTHON 1300: R, G, B = QE × CFA × IR-cut.
    RgbBayer,
}

/// Spectral responses of the camera channels, as absolute QE-like fractions in [0, 1].
#[derive(Clone, Debug)]
pub struct SensorResponse {
    /// Channel names, parallel to `curves` ("Y", or "R", "G", "B").
    pub channel_names: Vec<&'static str>,
    /// Response of each channel on the standard grid (fraction, not normalised).
    pub curves: Vec<Spectrum>,
}

/// PYTHON 1300 mono QE points (nm, fraction). 430–650 nm from the datasheet trace;
/// 380 nm (0.30) and 780 nm (0.45) are assumptions; held constant beyond them.
const PYTHON1300_QE: [(f64, f64); 9] = [
    (380.0, 0.30),
    (430.0, 0.49),
    (480.0, 0.56),
    (500.0, 0.56),
    (530.0, 0.58),
    (560.0, 0.60),
    (600.0, 0.62),
    (650.0, 0.62),
    (780.0, 0.45),
];

/// Piecewise-linear interpolation through sorted `(x, y)` points, held constant outside
/// the first/last point; NaN input returns the first value.
#[inline]
pub fn interp_clamped(points: &[(f64, f64)], x: f64) -> f64 {
    let (Some(&(x0, y0)), Some(&(xn, yn))) = (points.first(), points.last()) else {
        return 0.0;
    };
    if x.is_nan() || x <= x0 {
        return y0;
    }
    if x >= xn {
        return yn;
    }
    points.windows(2).find(|w| x <= w[1].0).map_or(yn, |w| {
        let ((xa, ya), (xb, yb)) = (w[0], w[1]);
        ya + (yb - ya) * (x - xa) / (xb - xa)
    })
}

/// Mono QE of the PYTHON 1300 at `lambda_nm` (fraction).
fn python1300_qe(lambda_nm: f64) -> f64 {
    interp_clamped(&PYTHON1300_QE, lambda_nm)
}

/// Illustrative dye-CFA transmissions [R, G, B] (0.02 floor each): B Gaussian peak 0.8
/// at 460 nm, G peak 0.85 at 535 nm (both FWHM 100 nm), R logistic step through 590 nm
/// (12 nm scale) to 0.9.
fn cfa_rgb(lambda_nm: f64) -> [f64; 3] {
    const FLOOR: f64 = 0.02;
    [
        FLOOR + (0.90 - FLOOR) * logistic(lambda_nm, 590.0, 12.0),
        FLOOR + (0.85 - FLOOR) * gaussian_fwhm(lambda_nm, 535.0, 100.0),
        FLOOR + (0.80 - FLOOR) * gaussian_fwhm(lambda_nm, 460.0, 100.0),
    ]
}

/// IR-cut filter: logistic edge, 50 % at 650 nm, 8 nm scale (0.2 % at 700 nm).
fn ir_cut(lambda_nm: f64) -> f64 {
    1.0 - logistic(lambda_nm, 650.0, 8.0)
}

/// Channel responses of the chosen sensor model on the standard grid.
///
/// - `MonoQe`: PYTHON 1300 mono QE, piecewise linear through ≈49 % (430 nm), 56 %
///   (480–500), 58 % (530), 60 % (560), 62 % (600–650). **Assumption:** linear to 30 % at
///   380 nm and 45 % at 780 nm, constant beyond. One channel "Y".
/// - `MonoBayerY`: QE·(T_R/4 + T_G/2 + T_B/4)·IR-cut, i.e. (R + 2G + B)/4 of `RgbBayer`
///   (Flea3 rule, UNVERIFIED for the Chameleon3; the IR-cut of the colour camera is
///   included, as in physics reference §6.2). One channel "Y".
/// - `Flat`: 1 everywhere. One channel "Y".
/// - `RgbBayer`: "R", "G", "B" = QE × CFA × IR-cut, with an illustrative generic dye CFA
///   (B peak 0.8 at 460 nm, G 0.85 at 535 nm, both FWHM 100 nm; R step through 590 nm to
///   0.9; 0.02 floor) and an IR-cut edge at 650 nm (50 %) reaching ≈0 by 700 nm. The
///   measured PYTHON 1300 colour curves were not found.
pub fn sensor_response(kind: SensorResponseKind) -> SensorResponse {
    let channel = |c: usize| {
        Spectrum::on_grid(move |l| {
            python1300_qe(l) * ir_cut(l) * cfa_rgb(l).get(c).copied().unwrap_or(0.0)
        })
    };
    let (channel_names, curves) = match kind {
        SensorResponseKind::MonoQe => (vec!["Y"], vec![Spectrum::on_grid(python1300_qe)]),
        SensorResponseKind::Flat => (vec!["Y"], vec![Spectrum::on_grid(|_| 1.0)]),
        SensorResponseKind::MonoBayerY => {
            let y = Spectrum::on_grid(|l| {
                let [r, g, b] = cfa_rgb(l);
                python1300_qe(l) * ir_cut(l) * (0.25 * r + 0.5 * g + 0.25 * b)
            });
            (vec!["Y"], vec![y])
        }
        SensorResponseKind::RgbBayer => (vec!["R", "G", "B"], (0..3).map(channel).collect()),
    };
    SensorResponse {
        channel_names,
        curves,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn grid() -> impl Iterator<Item = f64> {
        (360..=830).map(f64::from)
    }

    fn argmax(s: &Spectrum) -> f64 {
        grid().fold(GRID_START_NM, |best, l| {
            if s.eval(l) > s.eval(best) { l } else { best }
        })
    }

    #[test]
    fn from_fn_grid_and_eval() {
        let s = Spectrum::on_grid(|l| l);
        assert_eq!(s.values().len(), 471);
        assert_eq!((s.start_nm(), s.end_nm(), s.step_nm()), (360.0, 830.0, 1.0));
        assert!((s.eval(500.25) - 500.25).abs() < 1e-9);
        assert_eq!(s.eval(830.0), 830.0);
        assert_eq!(s.eval(359.9), 0.0);
        assert_eq!(s.eval(830.1), 0.0);
        assert_eq!(s.eval(f64::NAN), 0.0);
        assert_eq!(s.max_value(), 830.0);
        assert_eq!(s.scaled(2.0).eval(400.5), 801.0);
    }

    #[test]
    fn degenerate_grids_do_not_panic() {
        let bad = Spectrum::from_fn(500.0, 400.0, 1.0, |_| 3.0);
        assert_eq!(bad.values(), &[3.0]);
        assert_eq!(bad.eval(500.0), 3.0);
        assert_eq!(bad.integral(0.0, 1000.0), 0.0);
        let nan = Spectrum::from_fn(f64::NAN, 1.0, 0.0, |_| f64::INFINITY);
        assert_eq!(nan.values(), &[0.0]);
        assert_eq!(nan.scaled(f64::NAN).max_value(), 0.0);
    }

    #[test]
    fn integral_exact_on_linear_ramp() {
        // f = 2λ + 3  →  ∫ = λ² + 3λ.
        let s = Spectrum::from_fn(360.0, 830.0, 1.0, |l| 2.0 * l + 3.0);
        let prim = |l: f64| l * l + 3.0 * l;
        let (a, b) = (400.3, 512.7);
        assert!((s.integral(a, b) - (prim(b) - prim(a))).abs() < 1e-8);
        // Inside one segment, and clipped to the table.
        assert!((s.integral(450.2, 450.7) - (prim(450.7) - prim(450.2))).abs() < 1e-9);
        assert!((s.integral(0.0, 1e4) - (prim(830.0) - prim(360.0))).abs() < 1e-6);
        assert_eq!(s.integral(600.0, 500.0), 0.0);
        assert_eq!(s.integral(900.0, 1000.0), 0.0);
        // Coarse grid with non-integer step.
        let c = Spectrum::from_fn(0.0, 10.0, 2.5, |l| 2.0 * l + 3.0);
        assert!((c.integral(1.1, 9.3) - (prim(9.3) - prim(1.1))).abs() < 1e-9);
    }

    #[test]
    fn lcd_primaries_sum_to_a_unit_white_and_peak_in_their_colour() {
        let bl = display_spectrum(DisplaySpectrumKind::WhiteLed);
        let (p, white) = display_primaries(&bl);
        assert!((white.integral(380.0, 780.0) - 400.0).abs() < 1e-9);
        for l in [400.0, 450.0, 531.0, 612.0, 700.0] {
            // (grid wavelengths: between them the table interpolates the product)
            let sum: f64 = p.iter().map(|s| s.eval(l)).sum();
            assert!((sum - white.eval(l)).abs() < 1e-12 * white.eval(l), "{l}");
            // Each primary is the backlight times its filter, up to one common factor.
            let k = p[1].eval(l) / (bl.eval(l) * cfa_rgb(l)[1]);
            let k0 = p[1].eval(500.0) / (bl.eval(500.0) * cfa_rgb(500.0)[1]);
            assert!((k / k0 - 1.0).abs() < 1e-9);
        }
        // Peaks: blue at the 450 nm pump, green in the YAG band near the filter's 535 nm,
        // red beyond the 590 nm filter edge.
        assert!((argmax(&p[2]) - 450.0).abs() <= 2.0, "{}", argmax(&p[2]));
        assert!((520.0..560.0).contains(&argmax(&p[1])), "{}", argmax(&p[1]));
        assert!((595.0..640.0).contains(&argmax(&p[0])), "{}", argmax(&p[0]));
    }

    #[test]
    fn display_spectra_normalised_on_grid() {
        for kind in [
            DisplaySpectrumKind::Flat,
            DisplaySpectrumKind::WhiteLed,
            DisplaySpectrumKind::Ccfl,
        ] {
            let s = display_spectrum(kind);
            assert_eq!((s.start_nm(), s.end_nm(), s.step_nm()), (360.0, 830.0, 1.0));
            assert!((s.integral(380.0, 780.0) - 400.0).abs() < 1e-9, "{kind:?}");
            assert!(s.values().iter().all(|v| v.is_finite() && *v > 0.0));
        }
        let flat = display_spectrum(DisplaySpectrumKind::Flat);
        assert!(grid().all(|l| (flat.eval(l) - 1.0).abs() < 1e-12));
    }

    #[test]
    fn ohno_fwhm_constant() {
        let w = 10.0;
        let half = OHNO_FWHM_PER_WIDTH * w / 2.0;
        assert!((ohno_led(half, 0.0, w) - 0.5).abs() < 1e-12);
    }

    #[test]
    fn white_led_peak_and_dip() {
        let s = display_spectrum(DisplaySpectrumKind::WhiteLed);
        let peak = argmax(&s);
        assert!((peak - 450.0).abs() <= 5.0, "peak at {peak}");
        let has_local_min = (471..500).map(f64::from).any(|l| {
            let v = s.eval(l);
            v < s.eval(l - 1.0) && v <= s.eval(l + 1.0)
        });
        assert!(has_local_min);
        // Phosphor/blue peak ratio ≈ 0.6.
        let ratio = s.eval(560.0) / s.eval(450.0);
        assert!((0.5..0.7).contains(&ratio), "ratio {ratio}");
    }

    #[test]
    fn ccfl_lines_and_floor() {
        let s = display_spectrum(DisplaySpectrumKind::Ccfl);
        assert_eq!(argmax(&s), 545.0);
        for l in [436.0, 487.0, 587.0, 611.0] {
            assert!(s.eval(l) > 10.0 * s.eval(l + 5.0));
        }
        let floor = s.eval(700.0) / s.max_value();
        assert!((floor - 0.01 / 1.01).abs() < 1e-6);
    }

    #[test]
    fn sensor_channels_and_ranges() {
        for (kind, names) in [
            (SensorResponseKind::MonoQe, vec!["Y"]),
            (SensorResponseKind::MonoBayerY, vec!["Y"]),
            (SensorResponseKind::Flat, vec!["Y"]),
            (SensorResponseKind::RgbBayer, vec!["R", "G", "B"]),
        ] {
            let r = sensor_response(kind);
            assert_eq!(r.channel_names, names);
            assert_eq!(r.curves.len(), names.len());
            for c in &r.curves {
                assert_eq!((c.start_nm(), c.end_nm()), (360.0, 830.0));
                assert!(c.values().iter().all(|v| (0.0..=1.0).contains(v)));
            }
        }
        let flat = sensor_response(SensorResponseKind::Flat);
        assert!(flat.curves[0].values().iter().all(|&v| v == 1.0));
    }

    #[test]
    fn mono_qe_values() {
        let qe = &sensor_response(SensorResponseKind::MonoQe).curves[0];
        assert!((qe.eval(530.0) - 0.58).abs() <= 0.005);
        assert!((qe.eval(430.0) - 0.49).abs() <= 0.005);
        assert!((qe.eval(620.0) - 0.62).abs() <= 0.005);
    }

    #[test]
    fn rgb_bayer_shape() {
        let rgb = sensor_response(SensorResponseKind::RgbBayer);
        let [r, g, b] = [&rgb.curves[0], &rgb.curves[1], &rgb.curves[2]];
        let g_peak = argmax(g);
        assert!((520.0..=550.0).contains(&g_peak), "G peak {g_peak}");
        assert!(r.eval(620.0) > g.eval(620.0) && g.eval(620.0) > b.eval(620.0));
        assert!(b.eval(450.0) > g.eval(450.0) && g.eval(450.0) > r.eval(450.0));
        for c in [r, g, b] {
            assert!(c.eval(720.0) < 0.01);
        }
        let y = &sensor_response(SensorResponseKind::MonoBayerY).curves[0];
        for l in grid() {
            let expect = 0.25 * r.eval(l) + 0.5 * g.eval(l) + 0.25 * b.eval(l);
            assert!((y.eval(l) - expect).abs() < 1e-12);
        }
    }

    proptest! {
        #[test]
        fn integral_additive_and_bounded(
            a in 300.0f64..900.0, b in 300.0f64..900.0, c in 300.0f64..900.0
        ) {
            let s = display_spectrum(DisplaySpectrumKind::WhiteLed);
            let mut v = [a, b, c];
            v.sort_by(f64::total_cmp);
            let whole = s.integral(v[0], v[2]);
            let parts = s.integral(v[0], v[1]) + s.integral(v[1], v[2]);
            prop_assert!((whole - parts).abs() < 1e-9);
            prop_assert!(whole >= 0.0 && whole <= s.max_value() * (v[2] - v[0]) + 1e-9);
            let e = s.eval(a);
            prop_assert!(e >= 0.0 && e <= s.max_value());
        }
    }
}
