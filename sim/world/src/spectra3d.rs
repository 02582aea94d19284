//! Spectra of 3-D scenes: named and tabulated emission spectra, measured reflectance spectra,
//! and the spectral upsampling of RGB colours.
//!
//! Model, assumptions and sources:
//! - Every **emission** spectrum is normalised to mean 1 over [`NORM_LO_NM`]–[`NORM_HI_NM`]
//!   (380–780 nm), so the `scale` keys of a scene are in units of mean spectral radiance.
//!   Names: `d65` = CIE standard illuminant D65, the official 5 nm table 300–830 nm of
//!   CIE 015:2018 / ISO 11664-2 (relative, D65(560 nm) = 100), read by linear interpolation;
//!   `white-led`, `ccfl`, `flat` = the display models of [`crate::spectra::display_spectrum`];
//!   `blackbody:T` = Planck's law B(λ, T) ∝ λ⁻⁵/(exp(c₂/(λT)) − 1), c₂ = hc/k (CODATA 2018),
//!   T in kelvin within [500, 50000]; anything else is a CSV path relative to the scene folder.
//! - **CSV** spectra: two columns (wavelength in nm, value) separated by a comma, semicolon or
//!   whitespace; blank lines and lines starting with `#` are skipped; the first remaining line
//!   is a header if its first field is not a number; wavelengths strictly ascending; values
//!   finite and non-negative; 2 to 1 000 000 rows. The piecewise-linear interpolant of the rows
//!   is resampled onto the standard 1 nm grid (360–830 nm) by averaging it over each 1 nm bin
//!   (so lines narrower than 1 nm keep their area). Emission CSVs are 0 outside their
//!   wavelength range; reflectance CSVs hold their end values outside it (clamp-extension) and
//!   must lie in [0, 1]; reflectances are not normalised.
//! - **RGB reflectance** upsampling: Jakob & Hanika 2019, "A Low-Dimensional Function Space
//!   for Efficient Spectral Upsampling" (Computer Graphics Forum 38(2), Eurographics): ρ(λ) =
//!   S(c₀λ² + c₁λ + c₂), S(x) = ½ + x/(2√(1 + x²)), coefficients trilinearly interpolated in a
//!   table optimised for linear sRGB (D65 white, CIE 1931 2° observer). The table (resolution
//!   32) was generated once with the `rgb2spec` crate 0.1.1 (`optimize(Gamut::SRGB, 32)`, a port
//!   of mitsuba-renderer/rgb2spec) and is embedded as `rgb2spec_srgb_32.bin` in the original
//!   binary format; a test regenerates it and compares bytes. Inputs are clamped to [0, 1]
//!   (the model represents reflectances only). The coefficients act on λ in nm (the crate's
//!   `optimize` converts them from its normalised-λ fit), valid over 360–830 nm. Grey colours
//!   (r = g = b = v) return the constant v exactly, as pbrt-v4's `RGBToSpectrumTable` does,
//!   because the table's top slice is not flat: (1, 1, 1) would dip to 0.956 at 600 nm.
//!   Colours with a component at 1 but not grey still use that slice (a few-percent ripple).
//! - **RGB emission** follows Mitsuba 3's spectral variants (its `srgb_d65` spectrum: an RGB
//!   emitter is the upsampled colour times the D65 illuminant): with m = max(r, g, b),
//!   e(λ) = m·ρ_{rgb/m}(λ)·D65(λ), D65 normalised here to mean 1 over 380–780 nm (Mitsuba
//!   instead scales D65 to unit luminance), so white (1, 1, 1) emits D65 with mean 1.

use std::path::Path;
use std::sync::LazyLock;

use rgb2spec::RGB2Spec;

use crate::spectra::{
    DisplaySpectrumKind, GRID_END_NM, GRID_START_NM, GRID_STEP_NM, NORM_HI_NM, NORM_LO_NM,
    Spectrum, display_spectrum,
};

/// Lowest accepted blackbody temperature (K).
pub const BLACKBODY_MIN_K: f64 = 500.0;
/// Highest accepted blackbody temperature (K).
pub const BLACKBODY_MAX_K: f64 = 50_000.0;
/// Most data rows accepted in a spectrum CSV.
pub const MAX_CSV_ROWS: usize = 1_000_000;
/// Largest spectrum CSV file accepted (bytes).
pub const MAX_CSV_BYTES: u64 = 64 << 20;
/// Second radiation constant c₂ = hc/k in nm·K (CODATA 2018: 1.438776877e−2 m·K).
pub const PLANCK_C2_NM_K: f64 = 1.438_776_877e7;

/// First wavelength of the D65 table (nm).
const D65_START_NM: f64 = 300.0;
/// Step of the D65 table (nm).
const D65_STEP_NM: f64 = 5.0;
/// CIE standard illuminant D65, relative spectral power, 300–830 nm in 5 nm steps
/// (CIE 015:2018 Table 5 / ISO 11664-2; the 360–830 nm part as tabulated in
/// mitsuba-renderer/rgb2spec `cie1931.rs`).
#[rustfmt::skip]
const D65_5NM: [f64; 107] = [
    0.0341, 1.6643, 3.2945, 11.7652, 20.236, 28.6447, 37.0535, 38.5011, 39.9488, 42.4302,
    44.9117, 45.775,
    46.6383, 49.3637, 52.0891, 51.0323, 49.9755, 52.3118, 54.6482, 68.7015, 82.7549, 87.1204,
    91.486, 92.4589, 93.4318, 90.057, 86.6823, 95.7736, 104.865, 110.936, 117.008, 117.41,
    117.812, 116.336, 114.861, 115.392, 115.923, 112.367, 108.811, 109.082, 109.354, 108.578,
    107.802, 106.296, 104.79, 106.239, 107.689, 106.047, 104.405, 104.225, 104.046, 102.023,
    100.0, 98.1671, 96.3342, 96.0611, 95.788, 92.2368, 88.6856, 89.3459, 90.0062, 89.8026,
    89.5991, 88.6489, 87.6987, 85.4936, 83.2886, 83.4939, 83.6992, 81.863, 80.0268, 80.1207,
    80.2146, 81.2462, 82.2778, 80.281, 78.2842, 74.0027, 69.7213, 70.6652, 71.6091, 72.979,
    74.349, 67.9765, 61.604, 65.7448, 69.8856, 72.4863, 75.087, 69.3398, 63.5927, 55.0054,
    46.4182, 56.6118, 66.8054, 65.0941, 63.3828, 63.8434, 64.304, 61.8779, 59.4519, 55.7054,
    51.959, 54.6998, 57.4406, 58.8765, 60.3125,
];

/// The Jakob–Hanika coefficient table for linear sRGB, resolution 32 (rgb2spec format).
static RGB2SPEC_SRGB_32: &[u8] = include_bytes!("rgb2spec_srgb_32.bin");

static RGB2SPEC: LazyLock<RGB2Spec> = LazyLock::new(|| {
    RGB2Spec::from_reader(&mut &RGB2SPEC_SRGB_32[..])
        .expect("embedded rgb2spec_srgb_32.bin is a valid table (checked by a test)")
});

static D65_NORMALISED: LazyLock<Spectrum> =
    LazyLock::new(|| normalised(d65_relative()).unwrap_or_else(|_| d65_relative()));

/// CIE D65 as tabulated (relative, 100 at 560 nm), 300–830 nm on its 5 nm grid.
pub fn d65_relative() -> Spectrum {
    let end = D65_START_NM + (D65_5NM.len() - 1) as f64 * D65_STEP_NM;
    Spectrum::from_fn(D65_START_NM, end, D65_STEP_NM, |l| {
        let i = ((l - D65_START_NM) / D65_STEP_NM).round() as usize;
        D65_5NM.get(i).copied().unwrap_or(0.0)
    })
}

/// CIE D65 normalised to mean 1 over 380–780 nm (shared, computed once).
pub fn d65_normalised() -> &'static Spectrum {
    &D65_NORMALISED
}

/// Planck spectral radiance shape λ⁻⁵/(exp(c₂/(λT)) − 1) (unnormalised; λ in nm, T in K).
pub fn planck_shape(lambda_nm: f64, temperature_k: f64) -> f64 {
    if !(lambda_nm > 0.0 && temperature_k > 0.0) {
        return 0.0;
    }
    // Scale λ to µm to keep λ⁻⁵ well inside the f64 range.
    let l_um = lambda_nm * 1e-3;
    let v = 1.0 / (l_um.powi(5) * (PLANCK_C2_NM_K / (lambda_nm * temperature_k)).exp_m1());
    if v.is_finite() { v } else { 0.0 }
}

/// `s` scaled to mean 1 over 380–780 nm; an error if that mean is 0 or not finite.
fn normalised(s: Spectrum) -> Result<Spectrum, String> {
    let mean = s.integral(NORM_LO_NM, NORM_HI_NM) / (NORM_HI_NM - NORM_LO_NM);
    if mean > 0.0 && mean.is_finite() {
        Ok(s.scaled(1.0 / mean))
    } else {
        Err(format!(
            "spectrum is zero over {NORM_LO_NM}–{NORM_HI_NM} nm and cannot be normalised"
        ))
    }
}

/// Emission spectrum named by `spec`, normalised to mean 1 over 380–780 nm.
///
/// `spec` is `d65`, `white-led`, `ccfl`, `flat`, `blackbody:T` (T in kelvin, 500–50000;
/// names are case-insensitive) or the path of a CSV file (see the module notes), relative to
/// `base_dir` unless absolute. Errors are one line without the scene-file prefix.
pub fn emission_spectrum(spec: &str, base_dir: &Path) -> Result<Spectrum, String> {
    let name = spec.trim();
    let lower = name.to_ascii_lowercase();
    let raw = match lower.as_str() {
        "d65" => return Ok(d65_normalised().clone()),
        "white-led" => return Ok(display_spectrum(DisplaySpectrumKind::WhiteLed)),
        "ccfl" => return Ok(display_spectrum(DisplaySpectrumKind::Ccfl)),
        "flat" => return Ok(display_spectrum(DisplaySpectrumKind::Flat)),
        _ => {
            if let Some(t) = lower.strip_prefix("blackbody:") {
                let t_k: f64 = t.trim().parse().map_err(|_| {
                    format!(
                        "blackbody temperature {:?} is not a number (kelvin)",
                        t.trim()
                    )
                })?;
                if !(BLACKBODY_MIN_K..=BLACKBODY_MAX_K).contains(&t_k) {
                    return Err(format!(
                        "blackbody temperature {t_k} K is outside [{BLACKBODY_MIN_K}, {BLACKBODY_MAX_K}] K"
                    ));
                }
                Spectrum::on_grid(|l| planck_shape(l, t_k))
            } else {
                let path = base_dir.join(name);
                let looks_like_path = name.contains(['.', '/', '\\']);
                if name.is_empty() || (!path.is_file() && !looks_like_path) {
                    return Err(format!(
                        "unknown spectrum {name:?}; expected d65, white-led, ccfl, flat, blackbody:T or a CSV path"
                    ));
                }
                let rows = read_csv(&path, name, CsvKind::Emission)?;
                Spectrum::on_grid(|l| bin_average(&rows, l, false))
            }
        }
    };
    normalised(raw).map_err(|e| format!("{name}: {e}"))
}

/// Measured reflectance spectrum from a CSV file (see the module notes): values in [0, 1],
/// not normalised, end values held outside the tabulated range.
pub fn reflectance_csv(path: &Path) -> Result<Spectrum, String> {
    let shown = path.display().to_string();
    let rows = read_csv(path, &shown, CsvKind::Reflectance)?;
    Ok(Spectrum::on_grid(|l| {
        bin_average(&rows, l, true).clamp(0.0, 1.0)
    }))
}

#[derive(Clone, Copy, PartialEq)]
enum CsvKind {
    Emission,
    Reflectance,
}

/// Parses a two-column spectrum CSV; `shown` names the file in messages.
fn read_csv(path: &Path, shown: &str, kind: CsvKind) -> Result<Vec<(f64, f64)>, String> {
    let meta = std::fs::metadata(path).map_err(|e| format!("{shown}: cannot read: {e}"))?;
    if !meta.is_file() {
        return Err(format!("{shown}: not a file"));
    }
    if meta.len() > MAX_CSV_BYTES {
        return Err(format!("{shown}: larger than {MAX_CSV_BYTES} bytes"));
    }
    let bytes = std::fs::read(path).map_err(|e| format!("{shown}: cannot read: {e}"))?;
    let text = String::from_utf8(bytes).map_err(|_| format!("{shown}: not UTF-8 text"))?;
    parse_csv(&text, shown, kind)
}

fn parse_csv(text: &str, shown: &str, kind: CsvKind) -> Result<Vec<(f64, f64)>, String> {
    let mut rows: Vec<(f64, f64)> = Vec::new();
    let mut first = true;
    for (k, line) in text.lines().enumerate() {
        let n = k + 1;
        let line = line.trim().trim_start_matches('\u{feff}');
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line
            .split(|c: char| c == ',' || c == ';' || c.is_whitespace())
            .filter(|f| !f.is_empty())
            .collect();
        let is_header = first && fields.first().is_none_or(|f| f.parse::<f64>().is_err());
        first = false;
        if is_header {
            continue;
        }
        if fields.len() != 2 {
            return Err(format!(
                "{shown}: line {n}: expected 2 columns (nm, value), found {}",
                fields.len()
            ));
        }
        let num = |f: &str| -> Result<f64, String> {
            let v: f64 = f
                .parse()
                .map_err(|_| format!("{shown}: line {n}: not a number"))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(format!("{shown}: line {n}: not finite"))
            }
        };
        let (l, v) = (num(fields[0])?, num(fields[1])?);
        if l <= 0.0 {
            return Err(format!(
                "{shown}: line {n}: wavelength {l} nm is not positive"
            ));
        }
        if let Some(&(prev, _)) = rows.last()
            && l <= prev
        {
            return Err(format!(
                "{shown}: line {n}: wavelengths must be strictly ascending ({l} after {prev})"
            ));
        }
        if v < 0.0 {
            return Err(format!("{shown}: line {n}: value {v} is negative"));
        }
        if kind == CsvKind::Reflectance && v > 1.0 {
            return Err(format!("{shown}: line {n}: reflectance {v} is above 1"));
        }
        if rows.len() == MAX_CSV_ROWS {
            return Err(format!("{shown}: more than {MAX_CSV_ROWS} data rows"));
        }
        rows.push((l, v));
    }
    if rows.len() < 2 {
        return Err(format!(
            "{shown}: needs at least 2 data rows, found {}",
            rows.len()
        ));
    }
    Ok(rows)
}

/// Integral of the piecewise-linear interpolant of `rows` over [a, b] (a ≤ b). Outside the
/// rows it is 0, or the end value with `extend`.
fn pl_integral(rows: &[(f64, f64)], a: f64, b: f64, extend: bool) -> f64 {
    let (l0, v0) = rows[0];
    let (l1, v1) = rows[rows.len() - 1];
    let mut s = 0.0;
    if extend {
        s += v0 * (b.min(l0) - a).max(0.0) + v1 * (b - a.max(l1)).max(0.0);
    }
    let (a, b) = (a.max(l0), b.min(l1));
    if b <= a {
        return s;
    }
    // First segment whose right end is beyond a.
    let start = rows.partition_point(|&(l, _)| l <= a).saturating_sub(1);
    for w in rows[start..].windows(2) {
        let ((xa, ya), (xb, yb)) = (w[0], w[1]);
        if xa >= b {
            break;
        }
        let (u0, u1) = (xa.max(a), xb.min(b));
        if u1 > u0 {
            let at = |x: f64| ya + (yb - ya) * (x - xa) / (xb - xa);
            s += 0.5 * (u1 - u0) * (at(u0) + at(u1));
        }
    }
    s
}

/// Mean of the interpolant of `rows` over the grid bin centred on `lambda_nm`.
fn bin_average(rows: &[(f64, f64)], lambda_nm: f64, extend: bool) -> f64 {
    let h = 0.5 * GRID_STEP_NM;
    // The end bins of the standard grid are half bins.
    let a = (lambda_nm - h).max(GRID_START_NM);
    let b = (lambda_nm + h).min(GRID_END_NM);
    if b > a {
        pl_integral(rows, a, b, extend) / (b - a)
    } else {
        0.0
    }
}

/// A reflectance spectrum upsampled from an RGB colour (Jakob & Hanika 2019 coefficients).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RgbSpectrum {
    repr: Repr,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Repr {
    /// Sigmoid-polynomial coefficients (c₀, c₁, c₂) of λ in nm.
    Sigmoid([f32; 3]),
    /// A grey (r = g = b) colour: this constant.
    Constant(f64),
}

impl RgbSpectrum {
    /// Reflectance in [0, 1] at `lambda_nm` (valid over 360–830 nm).
    #[inline]
    pub fn eval(&self, lambda_nm: f64) -> f64 {
        match self.repr {
            Repr::Sigmoid(c) => {
                f64::from(rgb2spec::eval_precise(c, lambda_nm as f32)).clamp(0.0, 1.0)
            }
            Repr::Constant(v) => v,
        }
    }
}

/// Smooth reflectance spectrum of linear sRGB `rgb` (each component clamped to [0, 1]; NaN
/// read as 0). Grey colours (r = g = b = v) give the constant v exactly, as pbrt-v4's
/// `RGBToSpectrumTable` does: the table's entries for white are not flat (the optimiser's
/// coefficient cap leaves a dip to 0.956 at 600 nm for (1, 1, 1)) and black is up to 0.006.
pub fn reflectance_from_rgb(rgb: [f64; 3]) -> RgbSpectrum {
    let c = rgb.map(|v| if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) });
    let repr = if c[0] == c[1] && c[1] == c[2] {
        Repr::Constant(c[0])
    } else {
        Repr::Sigmoid(RGB2SPEC.fetch(c.map(|v| v as f32)))
    };
    RgbSpectrum { repr }
}

/// Spectral radiance at `lambda_nm` of an RGB emitter (linear sRGB, any non-negative scale):
/// m·ρ_{rgb/m}(λ)·D65(λ), m = max(r, g, b), D65 normalised to mean 1 over 380–780 nm
/// (Mitsuba 3's RGB × illuminant rule). 0 if m ≤ 0 or not finite; negative components count
/// as 0.
pub fn emission_from_rgb(rgb: [f64; 3], lambda_nm: f64) -> f64 {
    rgb_emission_factor(rgb, lambda_nm) * d65_normalised().eval(lambda_nm)
}

/// The RGB part of [`emission_from_rgb`], m·ρ_{rgb/m}(λ), to multiply by an illuminant
/// (an environment map's RGB × the light's spectrum uses it with another illuminant).
pub fn rgb_emission_factor(rgb: [f64; 3], lambda_nm: f64) -> f64 {
    let rgb = rgb.map(|v| if v > 0.0 { v } else { 0.0 });
    let m = rgb[0].max(rgb[1]).max(rgb[2]);
    if !(m > 0.0 && m.is_finite()) {
        return 0.0;
    }
    m * reflectance_from_rgb(rgb.map(|v| v / m)).eval(lambda_nm)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn mean_380_780(s: &Spectrum) -> f64 {
        s.integral(NORM_LO_NM, NORM_HI_NM) / (NORM_HI_NM - NORM_LO_NM)
    }

    #[test]
    fn d65_published_values() {
        // CIE 015:2018 Table 5.
        let d = d65_relative();
        for (l, v) in [
            (560.0, 100.0),
            (500.0, 109.354),
            (600.0, 90.0062),
            (300.0, 0.0341),
            (830.0, 60.3125),
        ] {
            assert!((d.eval(l) - v).abs() < 1e-9, "D65({l}) = {}", d.eval(l));
        }
        // Linear interpolation between table rows (CIE-recommended for D65 at 1 nm).
        assert!((d.eval(562.0) - (100.0 + 0.4 * (98.1671 - 100.0))).abs() < 1e-9);
        let n = emission_spectrum("D65", Path::new(".")).unwrap();
        assert!((mean_380_780(&n) - 1.0).abs() < 1e-12);
        assert!((n.eval(500.0) / n.eval(560.0) - 1.093_54).abs() < 1e-9);
        assert!(n.eval(300.0) > 0.0);
    }

    #[test]
    fn named_spectra_have_mean_one() {
        for name in [
            "d65",
            "white-led",
            "ccfl",
            "flat",
            "blackbody:2856",
            "Blackbody:6500",
        ] {
            let s = emission_spectrum(name, Path::new(".")).unwrap();
            assert!((mean_380_780(&s) - 1.0).abs() < 1e-12, "{name}");
        }
        assert_eq!(
            emission_spectrum("flat", Path::new("."))
                .unwrap()
                .eval(555.0),
            1.0
        );
    }

    #[test]
    fn blackbody_planck() {
        // Wien displacement: λ_max = b/T, b = 2.897771955e6 nm·K (CODATA 2018).
        let t = 5000.0;
        let s = emission_spectrum("blackbody:5000", Path::new(".")).unwrap();
        let (imax, _) = s
            .values()
            .iter()
            .enumerate()
            .fold((0, 0.0), |m, (i, &v)| if v > m.1 { (i, v) } else { m });
        let peak = s.start_nm() + imax as f64 * s.step_nm();
        assert!((peak - 2.897_771_955e6 / t).abs() <= 0.5, "peak {peak}");
        // Ratio at two wavelengths vs the closed form.
        let r = |l: f64| l.powi(-5) / ((PLANCK_C2_NM_K / (l * 3000.0)).exp() - 1.0);
        let s3 = emission_spectrum("blackbody:3000", Path::new(".")).unwrap();
        assert!((s3.eval(500.0) / s3.eval(700.0) - r(500.0) / r(700.0)).abs() < 1e-12);
        for bad in [
            "blackbody:499",
            "blackbody:50001",
            "blackbody:nan",
            "blackbody:",
            "blackbody:inf",
        ] {
            let e = emission_spectrum(bad, Path::new(".")).unwrap_err();
            assert!(e.starts_with("blackbody temperature"), "{e}");
        }
        assert!(emission_spectrum("blackbody:500", Path::new(".")).is_ok());
        assert!(emission_spectrum("blackbody:50000", Path::new(".")).is_ok());
    }

    #[test]
    fn unknown_name_error() {
        let e = emission_spectrum("d75", Path::new("/nonexistent")).unwrap_err();
        assert_eq!(
            e,
            "unknown spectrum \"d75\"; expected d65, white-led, ccfl, flat, blackbody:T or a CSV path"
        );
        let e = emission_spectrum("missing.csv", Path::new("/nonexistent")).unwrap_err();
        assert!(e.starts_with("missing.csv: cannot read:"), "{e}");
        assert!(!e.contains('\n'));
    }

    fn write(dir: &Path, name: &str, text: &str) {
        std::fs::File::create(dir.join(name))
            .unwrap()
            .write_all(text.as_bytes())
            .unwrap();
    }

    #[test]
    fn csv_emission() {
        let dir = tempfile::tempdir().unwrap();
        write(
            dir.path(),
            "lamp.csv",
            "nm,value\n# comment\n500, 1\n\n600 ,1\n",
        );
        let s = emission_spectrum("lamp.csv", dir.path()).unwrap();
        // Non-zero over 500–600 only: mean 1 over 400 nm ⇒ level 4.
        assert!((s.eval(550.0) - 4.0).abs() < 1e-12);
        assert_eq!(s.eval(450.0), 0.0);
        assert!((mean_380_780(&s) - 1.0).abs() < 1e-12);
        // A narrow line between grid points keeps its area: triangle of half-width 0.2 nm.
        write(
            dir.path(),
            "line.csv",
            "540,0\n550.1,0\n550.3,1\n550.5,0\n560,0\n",
        );
        let s = emission_spectrum("line.csv", dir.path()).unwrap();
        assert!((s.integral(540.0, 560.0) - 400.0).abs() < 1e-9);
        let cases = [
            (
                "a.csv",
                "nm,value\n500,1\n510,1\n520,x\n",
                "a.csv: line 4: not a number",
            ),
            (
                "b.csv",
                "500,1\n",
                "b.csv: needs at least 2 data rows, found 1",
            ),
            (
                "c.csv",
                "500,1\n490,1\n",
                "c.csv: line 2: wavelengths must be strictly ascending (490 after 500)",
            ),
            (
                "d.csv",
                "500,1\n510,-1\n",
                "d.csv: line 2: value -1 is negative",
            ),
            (
                "e.csv",
                "500,1,2\n",
                "e.csv: line 1: expected 2 columns (nm, value), found 3",
            ),
            (
                "f.csv",
                "500,0\n600,0\n",
                "f.csv: spectrum is zero over 380–780 nm and cannot be normalised",
            ),
            ("g.csv", "500,inf\n600,1\n", "g.csv: line 1: not finite"),
            (
                "h.csv",
                "nm,value\n",
                "h.csv: needs at least 2 data rows, found 0",
            ),
        ];
        for (name, text, msg) in cases {
            write(dir.path(), name, text);
            assert_eq!(emission_spectrum(name, dir.path()).unwrap_err(), msg);
        }
        std::fs::create_dir(dir.path().join("sub.csv")).unwrap();
        assert_eq!(
            emission_spectrum("sub.csv", dir.path()).unwrap_err(),
            "sub.csv: not a file"
        );
    }

    #[test]
    fn csv_reflectance() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("paint.csv");
        write(dir.path(), "paint.csv", "400,0.2\n700,0.8\n");
        let s = reflectance_csv(&p).unwrap();
        assert!((s.eval(550.0) - 0.5).abs() < 1e-12);
        assert!((s.eval(380.0) - 0.2).abs() < 1e-12); // clamp-extended
        assert!((s.eval(800.0) - 0.8).abs() < 1e-12);
        write(dir.path(), "paint.csv", "400,0.2\n700,1.5\n");
        let e = reflectance_csv(&p).unwrap_err();
        assert!(
            e.ends_with("paint.csv: line 2: reflectance 1.5 is above 1"),
            "{e}"
        );
    }

    #[test]
    fn embedded_table_parses() {
        let t = RGB2Spec::from_reader(&mut &RGB2SPEC_SRGB_32[..]).unwrap();
        assert!(format!("{t:?}").contains("resolution: 32"));
        assert_eq!(
            RGB2SPEC_SRGB_32.len(),
            8 + 4 * 32 + 4 * 3 * 3 * 32 * 32 * 32
        );
    }

    /// Regenerates the res-32 sRGB table (≈ 6 s; rgb2spec is built at opt-level 3 even in the
    /// dev profile) and checks the committed file byte for byte.
    #[test]
    fn embedded_table_regenerates() {
        let t = rgb2spec::optimize::optimize(rgb2spec::optimize::gamut::Gamut::SRGB, 32).unwrap();
        let mut bytes = Vec::new();
        t.to_writer(&mut bytes).unwrap();
        assert!(
            bytes == RGB2SPEC_SRGB_32,
            "rgb2spec_srgb_32.bin differs from a fresh optimisation"
        );
    }

    #[test]
    fn upsampled_reflectance_values() {
        // Tolerances: white within 1 % and grey within 1 % over 400–700 nm (exact by the grey
        // special case); near-grey colours go through the table.
        let white = reflectance_from_rgb([1.0; 3]);
        let grey = reflectance_from_rgb([0.5; 3]);
        for l in (400..=700).map(f64::from) {
            assert!(
                (white.eval(l) - 1.0).abs() < 0.01,
                "white({l}) = {}",
                white.eval(l)
            );
            assert!(
                (grey.eval(l) - 0.5).abs() < 0.005,
                "grey({l}) = {}",
                grey.eval(l)
            );
        }
        let c = reflectance_from_rgb([0.8, 0.5, 0.3]).eval(550.0);
        assert!((c / 0.5222 - 1.0).abs() < 0.005, "ρ(550) = {c}");
        // Clamping and NaN.
        assert_eq!(reflectance_from_rgb([2.0, 5.0, 1.0]), white);
        assert_eq!(
            reflectance_from_rgb([f64::NAN, 0.0, -1.0]),
            reflectance_from_rgb([0.0; 3])
        );
        assert_eq!(reflectance_from_rgb([0.0; 3]).eval(550.0), 0.0);
        let near_grey = reflectance_from_rgb([0.5, 0.5, 0.501]);
        for l in (400..=700).map(f64::from) {
            assert!((near_grey.eval(l) - 0.5).abs() < 0.005, "near grey({l})");
        }
        let near_white = reflectance_from_rgb([0.99, 0.99, 0.995]);
        for l in (400..=700).map(f64::from) {
            assert!((near_white.eval(l) - 0.99).abs() < 0.01, "near white({l})");
        }
        // Red is high at 650 nm and low at 450 nm.
        let red = reflectance_from_rgb([1.0, 0.0, 0.0]);
        assert!(red.eval(650.0) > 0.9 && red.eval(450.0) < 0.1);
    }

    #[test]
    fn rgb_emission_rule() {
        let d65 = d65_normalised();
        for l in [400.0, 550.0, 700.0] {
            let e = emission_from_rgb([2.0, 1.0, 0.5], l);
            let expect = 2.0 * reflectance_from_rgb([1.0, 0.5, 0.25]).eval(l) * d65.eval(l);
            assert!((e - expect).abs() < 1e-12);
            // White of value 3 ≈ 3 × D65 (within the 1 % of the white upsampling).
            assert!((emission_from_rgb([3.0; 3], l) / (3.0 * d65.eval(l)) - 1.0).abs() < 0.01);
        }
        assert_eq!(emission_from_rgb([0.0; 3], 550.0), 0.0);
        assert_eq!(emission_from_rgb([-1.0, f64::NAN, 0.0], 550.0), 0.0);
        assert_eq!(emission_from_rgb([f64::INFINITY, 0.0, 0.0], 550.0), 0.0);
    }

    /// CIE 1931 2° colour-matching functions, 360–830 nm in 5 nm steps (CIE 015:2018, as
    /// tabulated in mitsuba-renderer/rgb2spec `cie1931.rs`).
    mod cmf {
        #[rustfmt::skip]
        pub const X_BAR: [f64; 95] = [
            0.0001299, 0.0002321, 0.0004149, 0.0007416, 0.001368, 0.002236, 0.004243, 0.00765,
            0.01431, 0.02319, 0.04351, 0.07763, 0.13438, 0.21477, 0.2839, 0.3285,
            0.34828, 0.34806, 0.3362, 0.3187, 0.2908, 0.2511, 0.19536, 0.1421,
            0.09564, 0.05795001, 0.03201, 0.0147, 0.0049, 0.0024, 0.0093, 0.0291,
            0.06327, 0.1096, 0.1655, 0.2257499, 0.2904, 0.3597, 0.4334499, 0.5120501,
            0.5945, 0.6784, 0.7621, 0.8425, 0.9163, 0.9786, 1.0263, 1.0567,
            1.0622, 1.0456, 1.0026, 0.9384, 0.8544499, 0.7514, 0.6424, 0.5419,
            0.4479, 0.3608, 0.2835, 0.2187, 0.1649, 0.1212, 0.0874, 0.0636,
            0.04677, 0.0329, 0.0227, 0.01584, 0.01135916, 0.008110916, 0.005790346, 0.004109457,
            0.002899327, 0.00204919, 0.001439971, 0.0009999493, 0.0006900786, 0.0004760213, 0.0003323011, 0.0002348261,
            0.0001661505, 0.000117413, 8.307527e-5, 5.870652e-5, 4.150994e-5, 2.935326e-5, 2.067383e-5, 1.455977e-5,
            1.025398e-5, 7.221456e-6, 5.085868e-6, 3.581652e-6, 2.522525e-6, 1.776509e-6, 1.251141e-6,
        ];
        #[rustfmt::skip]
        pub const Y_BAR: [f64; 95] = [
            3.917e-6, 6.965e-6, 1.239e-5, 2.202e-5, 3.9e-5, 6.4e-5, 0.00012, 0.000217,
            0.000396, 0.00064, 0.00121, 0.00218, 0.004, 0.0073, 0.0116, 0.01684,
            0.023, 0.0298, 0.038, 0.048, 0.06, 0.0739, 0.09098, 0.1126,
            0.13902, 0.1693, 0.20802, 0.2586, 0.323, 0.4073, 0.503, 0.6082,
            0.71, 0.7932, 0.862, 0.9148501, 0.954, 0.9803, 0.9949501, 1.0,
            0.995, 0.9786, 0.952, 0.9154, 0.87, 0.8163, 0.757, 0.6949,
            0.631, 0.5668, 0.503, 0.4412, 0.381, 0.321, 0.265, 0.217,
            0.175, 0.1382, 0.107, 0.0816, 0.061, 0.04458, 0.032, 0.0232,
            0.017, 0.01192, 0.00821, 0.005723, 0.004102, 0.002929, 0.002091, 0.001484,
            0.001047, 0.00074, 0.00052, 0.0003611, 0.0002492, 0.0001719, 0.00012, 8.48e-5,
            6e-5, 4.24e-5, 3e-5, 2.12e-5, 1.499e-5, 1.06e-5, 7.4657e-6, 5.2578e-6,
            3.7029e-6, 2.6078e-6, 1.8366e-6, 1.2934e-6, 9.1093e-7, 6.4153e-7, 4.5181e-7,
        ];
        #[rustfmt::skip]
        pub const Z_BAR: [f64; 95] = [
            0.0006061, 0.001086, 0.001946, 0.003486, 0.006450001, 0.01054999, 0.02005001, 0.03621,
            0.06785001, 0.1102, 0.2074, 0.3713, 0.6456, 1.0390501, 1.3856, 1.62296,
            1.74706, 1.7826, 1.77211, 1.7441, 1.6692, 1.5281, 1.28764, 1.0419,
            0.8129501, 0.6162, 0.46518, 0.3533, 0.272, 0.2123, 0.1582, 0.1117,
            0.07824999, 0.05725001, 0.04216, 0.02984, 0.0203, 0.0134, 0.008749999, 0.005749999,
            0.0039, 0.002749999, 0.0021, 0.0018, 0.001650001, 0.0014, 0.0011, 0.001,
            0.0008, 0.0006, 0.00034, 0.00024, 0.00019, 0.0001, 4.999999e-5, 3e-5,
            2e-5, 1e-5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ];
    }

    /// Linear sRGB of reflectance `rho` under D65 with the CIE 1931 observer (white → (1,1,1)).
    fn rgb_of(rho: impl Fn(f64) -> f64) -> [f64; 3] {
        let d65 = d65_relative();
        let cmf = |t: &[f64; 95], l: f64| {
            let x = (l - 360.0) / 5.0;
            let i = (x.floor() as usize).min(93);
            let f = x - i as f64;
            t[i] * (1.0 - f) + t[i + 1] * f
        };
        let (mut xyz, mut yw) = ([0.0; 3], 0.0);
        for k in 0..=470 {
            let l = 360.0 + k as f64;
            let w = if k == 0 || k == 470 { 0.5 } else { 1.0 } * d65.eval(l);
            let r = rho(l);
            for (j, t) in [&cmf::X_BAR, &cmf::Y_BAR, &cmf::Z_BAR]
                .into_iter()
                .enumerate()
            {
                xyz[j] += w * r * cmf(t, l);
            }
            yw += w * cmf(&cmf::Y_BAR, l);
        }
        let [x, y, z] = xyz.map(|v| v / yw);
        // IEC 61966-2-1 XYZ → linear sRGB.
        [
            3.240_454_2 * x - 1.537_138_5 * y - 0.498_531_4 * z,
            -0.969_266_0 * x + 1.876_010_8 * y + 0.041_556_0 * z,
            0.055_643_4 * x - 0.204_025_9 * y + 1.057_225_2 * z,
        ]
    }

    /// Tolerance: each linear-sRGB component within 0.01 of the input (table interpolation and
    /// the optimiser's CIELAB residual); a deliberately swapped colour must miss by > 0.1.
    #[test]
    fn upsampling_round_trip() {
        let colours = [
            [0.8, 0.5, 0.3],
            [0.2, 0.6, 0.9],
            [0.5, 0.5, 0.5],
            [0.9, 0.9, 0.1],
            [0.05, 0.3, 0.05],
            [1.0, 1.0, 1.0],
        ];
        for c in colours {
            let s = reflectance_from_rgb(c);
            let back = rgb_of(|l| s.eval(l));
            for j in 0..3 {
                assert!((back[j] - c[j]).abs() < 0.01, "{c:?} → {back:?}");
            }
        }
        let flat = rgb_of(|_| 1.0);
        assert!(flat.iter().all(|v| (v - 1.0).abs() < 1e-3), "{flat:?}");
        let s = reflectance_from_rgb([0.3, 0.5, 0.8]);
        let back = rgb_of(|l| s.eval(l));
        assert!((back[0] - 0.8).abs() > 0.1);
    }
    #[test]
    fn d65_white_point_and_srgb_white() {
        // D65's chromaticity (CIE 015: x = 0.31272, y = 0.32903) from the table, tolerance
        // 5e-4 (5 nm table and linear interpolation); a wrong CMF order fails it.
        let d65 = d65_relative();
        let w = crate::colour::ColourWeights::new(crate::colour::FrontalSpace::Xyz, 360.0, 830.0)
            .unwrap();
        let mut xyz = [0.0; 3];
        let mut swapped = [0.0; 3];
        for i in 0..47_000 {
            let l = 360.0 + (i as f64 + 0.5) * 0.01;
            let a = w.at(l);
            let e = d65.eval(l) * 0.01;
            for k in 0..3 {
                xyz[k] += a[k] * e;
                swapped[k] += a[2 - k] * e;
            }
        }
        let chroma = |v: [f64; 3]| (v[0] / v.iter().sum::<f64>(), v[1] / v.iter().sum::<f64>());
        let (x, y) = chroma(xyz);
        assert!(
            (x - 0.31272).abs() < 5e-4 && (y - 0.32903).abs() < 5e-4,
            "{x} {y}"
        );
        let (xs, ys) = chroma(swapped);
        assert!((xs - 0.31272).abs() > 5e-3 || (ys - 0.32903).abs() > 5e-3);
        let rgb = crate::colour::mat3(&crate::colour::XYZ_TO_LINEAR_SRGB, xyz);
        for c in rgb {
            assert!((c / rgb[1] - 1.0).abs() < 2e-3, "{rgb:?}");
        }
    }
}
