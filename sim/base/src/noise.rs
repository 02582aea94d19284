//! Sensor noise: what a real camera does to a noiseless capture (docs/physics.md §7.3).
//!
//! Model, per pixel and frame, for a noiseless value v in capture units:
//!   electrons   e = v·G, with the exposure gain G set once so that the brightest pixel of the
//!                 all-white capture reaches `exposure_fraction` of full scale;
//!   shot noise  Poisson(e) (exact inversion below 30 e⁻; above, the Gaussian N(e, e), whose
//!               error in the variance is nil and in the skewness below 0.2);
//!   read noise  N(0, σ_read²) electrons;
//!   ADC         DN = round(e_noisy / (FW / (2^bits − 1)) + dark offset), clipped to
//!               [0, 2^bits − 1] (saturation), and converted back to capture units with the
//!               same gain, the dark offset left in (the camera's black level).
//! Assumptions: no pixel cross-talk, linear response up to full scale (gamma, LUT,
//! auto-exposure and auto-gain disabled, as docs/physics.md §7.3 asks).
//!
//! EMVA 1288 terms (European Machine Vision Association, *Standard for Characterization of
//! Image Sensors and Cameras*, release 4.0, 2021: its linear camera model, §2): each off by
//! default (0), which is the model above bit for bit. Per pixel i a fixed pattern, drawn once
//! per sensor from `NoiseRng([sensor_seed, FPN_TAG, i])` and the same in every frame:
//!   PRNU        gain gᵢ = max(0, 1 + prnu·zᵢ), zᵢ ~ N(0, 1): e = v·G·gᵢ;
//!   dark current μ_d,i = dark_current_e_per_s · t_exp · 2^(ΔT / T_double) electrons (the
//!               temperature-doubling rule, EMVA 1288 §4.2), plus `hot_pixel_dark_e` for a
//!               fraction `hot_pixel_fraction` of the pixels (hot pixels); it adds to the
//!               signal before shot noise (dark-current shot noise);
//!   DSNU        a fixed offset oᵢ = dsnu_e·z'ᵢ electrons added after shot noise (the dark
//!               signal's spatial spread; it may be negative, the black level absorbs it);
//! so the temporal dark noise is σ_d² = σ_read² + μ_d (+ the ADC's 1/12 DN²) and the spatial
//! dark spread is dsnu_e (hot pixels aside).
//! The pixel index i is the capture's value index (the row of H: channel-major, then the crop's
//! pixels row by row), so a pixel keeps its pattern in every frame, capture and dataset sample.
//!
//! Random numbers come from small generators keyed by hashing (seed, stream, …): one per value,
//! or one per sensor pixel drawn through its frames in order (calibration); Gaussians come from
//! the Marsaglia–Tsang ziggurat (J. Stat. Softw. 5(8), 2000). No generator is shared between
//! threads, so noisy outputs are identical for any thread count.

use crate::sampler::{hash, mix64, to_unit};
use serde::{Deserialize, Serialize};

/// `[noise]`: the camera's sensor noise model, used when a command adds noise to captures or
/// calibration frames (`calibrate`, `reconstruct`, `demo`, datasets).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseDesc {
    /// Full-well capacity, electrons.
    pub full_well_e: f64,
    /// Exposure: the brightest pixel of the all-white capture reaches this fraction of full
    /// scale (the exposure is set once from the all-white frame and kept for every frame).
    pub exposure_fraction: f64,
    /// Read noise, electrons RMS.
    pub read_noise_e: f64,
    /// Dark offset (camera black level), digital numbers.
    pub dark_offset_dn: f64,
    /// ADC bit depth; full scale 2^bits − 1 DN maps to the full well.
    pub bit_depth: u32,
    /// Mean dark current at the reference temperature, electrons per second (EMVA 1288 μ_I).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub dark_current_e_per_s: f64,
    /// Exposure time, ms (what the dark current integrates over).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub exposure_time_ms: f64,
    /// Sensor temperature minus the dark current's reference temperature, K.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub temperature_above_reference_k: f64,
    /// Temperature rise that doubles the dark current, K.
    #[serde(
        default = "default_doubling_k",
        skip_serializing_if = "is_default_doubling_k"
    )]
    pub dark_current_doubling_k: f64,
    /// Dark signal non-uniformity: standard deviation of the dark signal across pixels,
    /// electrons (EMVA 1288 σ_o, in electrons).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub dsnu_e: f64,
    /// Photo-response non-uniformity: relative standard deviation of the pixel gain (0.01 =
    /// 1 %, EMVA 1288 PRNU₁₂₈₈ / 100).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub prnu: f64,
    /// Fraction of hot pixels.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub hot_pixel_fraction: f64,
    /// Extra dark signal of a hot pixel, electrons per frame.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub hot_pixel_dark_e: f64,
    /// Seed of the sensor's fixed patterns (another seed: another sensor of the same model).
    #[serde(default, skip_serializing_if = "is_zero_u64")]
    pub sensor_seed: u64,
}

/// Default of `noise.dark_current_doubling_k` (ASSUMED: a typical CMOS value, dark current
/// doubling every 6.5 K; no datasheet value for the paper's sensor).
pub const DEFAULT_DARK_CURRENT_DOUBLING_K: f64 = 6.5;

fn default_doubling_k() -> f64 {
    DEFAULT_DARK_CURRENT_DOUBLING_K
}
fn is_default_doubling_k(v: &f64) -> bool {
    *v == DEFAULT_DARK_CURRENT_DOUBLING_K
}
fn is_zero(v: &f64) -> bool {
    *v == 0.0
}
fn is_zero_u64(v: &u64) -> bool {
    *v == 0
}

impl NoiseDesc {
    /// The model of the ideal sensor: every EMVA 1288 term off.
    pub fn ideal(
        full_well_e: f64,
        exposure_fraction: f64,
        read_noise_e: f64,
        dark_offset_dn: f64,
        bit_depth: u32,
    ) -> Self {
        NoiseDesc {
            full_well_e,
            exposure_fraction,
            read_noise_e,
            dark_offset_dn,
            bit_depth,
            dark_current_e_per_s: 0.0,
            exposure_time_ms: 0.0,
            temperature_above_reference_k: 0.0,
            dark_current_doubling_k: DEFAULT_DARK_CURRENT_DOUBLING_K,
            dsnu_e: 0.0,
            prnu: 0.0,
            hot_pixel_fraction: 0.0,
            hot_pixel_dark_e: 0.0,
            sensor_seed: 0,
        }
    }

    /// Mean dark signal per frame, electrons: dark current × exposure time, doubled every
    /// `dark_current_doubling_k` above the reference temperature.
    pub fn mean_dark_e(&self) -> f64 {
        self.dark_current_e_per_s
            * self.exposure_time_ms
            * 1e-3
            * (self.temperature_above_reference_k / self.dark_current_doubling_k).exp2()
    }

    /// The fixed patterns of this sensor, or None when every term is off.
    fn fixed_pattern(&self) -> Option<FixedPattern> {
        let dark_e = self.mean_dark_e();
        let hot = self.hot_pixel_fraction > 0.0 && self.hot_pixel_dark_e > 0.0;
        (self.prnu > 0.0 || self.dsnu_e > 0.0 || dark_e > 0.0 || hot).then_some(FixedPattern {
            seed: self.sensor_seed,
            prnu: self.prnu,
            dsnu_e: self.dsnu_e,
            dark_e,
            hot_fraction: if hot { self.hot_pixel_fraction } else { 0.0 },
            hot_e: self.hot_pixel_dark_e,
        })
    }
}

/// Stream tag of the sensor's fixed patterns: pixel i draws from
/// `NoiseRng([sensor_seed, FPN_TAG, i])`.
pub const FPN_TAG: u64 = 0x4650_4E00;

/// A sensor's fixed patterns (module notes, "EMVA 1288 terms").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FixedPattern {
    /// Seed of the patterns.
    pub seed: u64,
    /// Relative standard deviation of the pixel gain.
    pub prnu: f64,
    /// Standard deviation of the dark signal across pixels, electrons.
    pub dsnu_e: f64,
    /// Mean dark signal per frame, electrons.
    pub dark_e: f64,
    /// Fraction of hot pixels.
    pub hot_fraction: f64,
    /// Extra dark signal of a hot pixel, electrons.
    pub hot_e: f64,
}

/// One pixel's fixed pattern.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pixel {
    /// Gain (1 for the ideal sensor).
    pub gain: f64,
    /// Mean dark current per frame, electrons (shot noise applies).
    pub dark_e: f64,
    /// Fixed offset (DSNU), electrons (no shot noise).
    pub offset_e: f64,
}

/// The ideal sensor's pixel.
pub const IDEAL_PIXEL: Pixel = Pixel {
    gain: 1.0,
    dark_e: 0.0,
    offset_e: 0.0,
};

impl FixedPattern {
    /// Pixel `i`'s pattern.
    #[inline]
    pub fn pixel(&self, i: u64) -> Pixel {
        let mut r = NoiseRng::new(&[self.seed, FPN_TAG, i]);
        let gain = (1.0 + self.prnu * r.normal()).max(0.0);
        let offset_e = self.dsnu_e * r.normal();
        let mut dark_e = self.dark_e;
        if self.hot_fraction > 0.0 && r.uniform() < self.hot_fraction {
            dark_e += self.hot_e;
        }
        Pixel {
            gain,
            dark_e,
            offset_e,
        }
    }
}

/// Below this mean (electrons) shot noise is drawn from the exact Poisson distribution.
pub const POISSON_EXACT_BELOW_E: f64 = 30.0;

/// A small deterministic generator for one noisy value (a SplitMix64 stream from a hashed key).
#[derive(Clone, Debug)]
pub struct NoiseRng {
    state: u64,
}

const ZIG_N: usize = 128;
const ZIG_R: f64 = 3.442_619_855_899;
const ZIG_V: f64 = 9.912_563_035_262_17e-3;

struct Ziggurat {
    k: [u32; ZIG_N],
    w: [f64; ZIG_N],
    f: [f64; ZIG_N],
}

fn ziggurat() -> &'static Ziggurat {
    static TABLES: std::sync::OnceLock<Ziggurat> = std::sync::OnceLock::new();
    TABLES.get_or_init(|| {
        let m1 = 2_147_483_648.0f64;
        let mut z = Ziggurat {
            k: [0; ZIG_N],
            w: [0.0; ZIG_N],
            f: [0.0; ZIG_N],
        };
        let mut dn = ZIG_R;
        let mut tn = dn;
        let q = ZIG_V / (-0.5 * dn * dn).exp();
        z.k[0] = ((dn / q) * m1) as u32;
        z.k[1] = 0;
        z.w[0] = q / m1;
        z.w[ZIG_N - 1] = dn / m1;
        z.f[0] = 1.0;
        z.f[ZIG_N - 1] = (-0.5 * dn * dn).exp();
        for i in (1..ZIG_N - 1).rev() {
            dn = (-2.0 * (ZIG_V / dn + (-0.5 * dn * dn).exp()).ln()).sqrt();
            z.k[i + 1] = ((dn / tn) * m1) as u32;
            tn = dn;
            z.f[i] = (-0.5 * dn * dn).exp();
            z.w[i] = dn / m1;
        }
        z
    })
}

impl NoiseRng {
    /// A generator keyed by `words` (e.g. seed, stream, frame, pixel).
    #[inline]
    pub fn new(words: &[u64]) -> Self {
        NoiseRng { state: hash(words) }
    }

    /// Next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix64(self.state)
    }

    /// Uniform in (0, 1).
    #[inline]
    pub fn uniform(&mut self) -> f64 {
        // to_unit gives [0, 1); shift by half an ulp of 2⁻⁵³ to exclude 0.
        to_unit(self.next_u64()) + 0.5 / 9_007_199_254_740_992.0
    }

    /// Standard normal deviate (ziggurat).
    #[inline(always)]
    pub fn normal(&mut self) -> f64 {
        let z = ziggurat();
        loop {
            let hz = (self.next_u64() >> 32) as u32 as i32;
            let iz = (hz as u32 & (ZIG_N as u32 - 1)) as usize;
            let x = f64::from(hz) * z.w[iz];
            if hz.unsigned_abs() < z.k[iz] {
                return x;
            }
            if iz == 0 {
                // Tail beyond R.
                loop {
                    let xt = -self.uniform().ln() / ZIG_R;
                    let y = -self.uniform().ln();
                    if y + y >= xt * xt {
                        return if hz > 0 { ZIG_R + xt } else { -ZIG_R - xt };
                    }
                }
            }
            if z.f[iz] + self.uniform() * (z.f[iz - 1] - z.f[iz]) < (-0.5 * x * x).exp() {
                return x;
            }
        }
    }

    /// Poisson deviate with mean `mean` (exact inversion; meant for small means).
    pub fn poisson(&mut self, mean: f64) -> f64 {
        if mean <= 0.0 {
            return 0.0;
        }
        let u = self.uniform();
        let mut p = (-mean).exp();
        let mut cdf = p;
        let mut k = 0.0;
        // The loop ends with probability 1; the bound guards against rounding at the tail.
        while u > cdf && k < 20.0 * mean + 100.0 {
            k += 1.0;
            p *= mean / k;
            cdf += p;
        }
        k
    }
}

/// The noise model with its exposure fixed.
#[derive(Clone, Debug)]
pub struct SensorNoise {
    /// Electrons per capture unit (the exposure gain).
    pub electrons_per_unit: f64,
    /// Electrons per digital number.
    pub electrons_per_dn: f64,
    /// Full scale in DN (2^bits − 1).
    pub full_scale_dn: f64,
    /// Read noise, electrons RMS.
    pub read_noise_e: f64,
    /// Dark offset, DN.
    pub dark_offset_dn: f64,
    /// The sensor's fixed patterns (None: the ideal sensor).
    pub fixed: Option<FixedPattern>,
}

impl SensorNoise {
    /// Fixes the exposure so that `white_peak` (the brightest pixel of the all-white capture,
    /// capture units) reaches `exposure_fraction` of full scale.
    pub fn new(desc: &NoiseDesc, white_peak: f64) -> Self {
        let full_scale_dn = f64::from((1u32 << desc.bit_depth.min(31)) - 1);
        let electrons_per_dn = desc.full_well_e / full_scale_dn;
        let target_e = desc.exposure_fraction * full_scale_dn * electrons_per_dn;
        let electrons_per_unit = if white_peak > 0.0 {
            target_e / white_peak
        } else {
            0.0
        };
        SensorNoise {
            electrons_per_unit,
            electrons_per_dn,
            full_scale_dn,
            read_noise_e: desc.read_noise_e,
            dark_offset_dn: desc.dark_offset_dn,
            fixed: desc.fixed_pattern(),
        }
    }

    /// Checks that `white_peak` gives an exposure whose values fit float32, as captures are
    /// stored: the full scale in capture units (white_peak / exposure_fraction) at most 10³⁷
    /// and one DN in capture units at least 10⁻³⁰ (below, every value would round to 0 or a
    /// denormal; above, a saturated pixel would be stored as infinity). The message names the
    /// value and the range.
    pub fn check_white_peak(desc: &NoiseDesc, white_peak: f64) -> Result<(), String> {
        Self::checked(desc, white_peak).map(|_| ())
    }

    /// [`SensorNoise::new`] after [`SensorNoise::check_white_peak`]: the model, or the
    /// check's message.
    pub fn checked(desc: &NoiseDesc, white_peak: f64) -> Result<Self, String> {
        let n = SensorNoise::new(desc, white_peak);
        let full_scale_units = n.full_scale_dn / n.dn_per_unit();
        let dn_units = 1.0 / n.dn_per_unit();
        if white_peak.is_finite()
            && white_peak > 0.0
            && full_scale_units <= 1e37
            && dn_units >= 1e-30
        {
            Ok(n)
        } else {
            Err(format!(
                "white peak {white_peak}: must be a positive number that puts the sensor's full scale (white peak / exposure_fraction) at most 1e37 and one DN at least 1e-30 capture units, so that captures fit float32"
            ))
        }
    }

    /// One capture unit in DN.
    pub fn dn_per_unit(&self) -> f64 {
        self.electrons_per_unit / self.electrons_per_dn
    }

    /// The dark offset in capture units.
    pub fn dark_offset_units(&self) -> f64 {
        self.dark_offset_dn / self.dn_per_unit()
    }

    /// Pixel `i`'s fixed pattern ([`IDEAL_PIXEL`] for the ideal sensor).
    #[inline]
    pub fn pixel(&self, i: u64) -> Pixel {
        self.fixed.map_or(IDEAL_PIXEL, |f| f.pixel(i))
    }

    /// A noisy measurement of the noiseless value `v` (capture units) at pixel `i` (the
    /// capture's value index, module notes), in capture units with the dark offset included;
    /// `rng` supplies the randomness. With the ideal sensor this is [`measure`](Self::measure).
    #[inline(always)]
    pub fn measure_at(&self, v: f64, i: u64, rng: &mut NoiseRng) -> f64 {
        match self.fixed {
            None => self.measure(v, rng),
            Some(f) => {
                let p = f.pixel(i);
                self.measure_electrons(
                    v.max(0.0) * self.electrons_per_unit * p.gain + p.dark_e,
                    p.offset_e,
                    rng,
                )
            }
        }
    }

    /// A noisy measurement of the noiseless value `v` (capture units) by a pixel of the ideal
    /// sensor (gain 1, no dark signal), in capture units with the dark offset included; `rng`
    /// supplies the randomness.
    #[inline(always)]
    pub fn measure(&self, v: f64, rng: &mut NoiseRng) -> f64 {
        self.measure_electrons(v.max(0.0) * self.electrons_per_unit, 0.0, rng)
    }

    /// A noisy measurement of a pixel that collects `e` electrons on average (shot noise)
    /// with the fixed offset `offset_e` electrons.
    #[inline(always)]
    fn measure_electrons(&self, e: f64, offset_e: f64, rng: &mut NoiseRng) -> f64 {
        let electrons = if e < POISSON_EXACT_BELOW_E {
            rng.poisson(e) + self.read_noise_e * rng.normal()
        } else {
            // Shot and read noise are independent Gaussians: one deviate with the summed variance.
            e + (e + self.read_noise_e * self.read_noise_e).sqrt() * rng.normal()
        } + offset_e;
        // Round half up after clipping (the cast is exact for the clipped range and avoids a
        // libm call).
        let dn = (electrons * (1.0 / self.electrons_per_dn) + self.dark_offset_dn)
            .clamp(0.0, self.full_scale_dn);
        let dn = (dn + 0.5) as i64 as f64;
        let dn = dn.min(self.full_scale_dn);
        dn * (self.electrons_per_dn / self.electrons_per_unit)
    }

    /// The variance (capture units²) of [`measure`](Self::measure) for the noiseless value
    /// `v` below saturation: shot noise (mean e = v·G electrons), read noise σ_read² and the
    /// ADC's uniform rounding error (one DN)²/12, converted with the gain G:
    /// (e + σ_read²)/G² + (e⁻ per DN / G)²/12. Clipping at 0 and full scale is ignored (it only
    /// lowers the variance).
    pub fn variance(&self, v: f64) -> f64 {
        if self.electrons_per_unit <= 0.0 {
            return 0.0;
        }
        let g = self.electrons_per_unit;
        let e = v.max(0.0) * g;
        let q = self.electrons_per_dn / g;
        (e + self.read_noise_e * self.read_noise_e) / (g * g) + q * q / 12.0
    }

    /// The mean squared error E[(x − v − dark offset)²] of a measurement x of the noiseless
    /// value `v` (capture units²), the ADC's rounding taken exactly: the electrons are taken as
    /// Gaussian with the shot-plus-read variance s² (DN²) about the mean μ (DN, dark offset
    /// in), and E[(round(μ + sZ) − μ)²] = Σₖ (k − μ)² [Φ((k + ½ − μ)/s) − Φ((k − ½ − μ)/s)].
    /// Unlike [`variance`](Self::variance) (which assumes the rounding error uniform, true when
    /// s ≳ ½ DN or μ's fraction is random), this is right for a pixel that receives almost no
    /// light and sits at an integer black level: its rounding error is then nearly zero.
    pub fn mse_about(&self, v: f64) -> f64 {
        if self.electrons_per_unit <= 0.0 {
            return 0.0;
        }
        let g = self.electrons_per_unit;
        let e = v.max(0.0) * g;
        let s = (e + self.read_noise_e * self.read_noise_e).sqrt() / self.electrons_per_dn;
        let mu = (e / self.electrons_per_dn + self.dark_offset_dn).min(self.full_scale_dn);
        let to_units = (self.electrons_per_dn / g).powi(2);
        if s > 2.0 {
            // Sheppard's correction is exact to < 1e-30 relative here.
            return (s * s + 1.0 / 12.0) * to_units;
        }
        if s < 1e-12 {
            let r = mu.round() - mu;
            return r * r * to_units;
        }
        let lo = (mu - 10.0 * s - 1.0).floor().max(0.0) as i64;
        let hi = (mu + 10.0 * s + 1.0).ceil().min(self.full_scale_dn) as i64;
        let mut acc = 0.0;
        // Each code's upper edge is the next one's lower edge (k + 0.5 = (k + 1) − 0.5 exactly
        // in f64): one Φ per edge.
        let mut below = normal_cdf((lo as f64 - 0.5 - mu) / s);
        for k in lo..=hi {
            let k = k as f64;
            let above = normal_cdf((k + 0.5 - mu) / s);
            let p = above - below;
            below = above;
            acc += p * (k - mu) * (k - mu);
        }
        acc * to_units
    }

    /// True if the noiseless value `v` saturates the ADC (before noise).
    pub fn saturates(&self, v: f64) -> bool {
        v * self.dn_per_unit() + self.dark_offset_dn > self.full_scale_dn
    }
}

/// Stream tag of a dataset capture's noise: pixel i of the capture of sample seed s draws
/// from `NoiseRng([s, NOISE_TAG, i])`.
pub const NOISE_TAG: u64 = 0x4E4F_4953;

/// The standard normal distribution function Φ(x) = ½ erfc(−x/√2), erfc by the Chebyshev
/// fit of Numerical Recipes (3rd ed., §6.2.2, `erfccheb`; relative error < 1.2e-7 everywhere).
pub fn normal_cdf(x: f64) -> f64 {
    let z = (x / std::f64::consts::SQRT_2).abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let erfc = t * poly.exp();
    if x >= 0.0 {
        1.0 - 0.5 * erfc
    } else {
        0.5 * erfc
    }
}

/// The stored noisy capture of a clean one, as datasets store it: each value measured by
/// `noise` (pixel i with `NoiseRng([seed, NOISE_TAG, i])`) minus the mean dark offset, in
/// capture units, as f32.
pub fn measure_capture(noise: &SensorNoise, clean: &[f64], seed: u64) -> Vec<f32> {
    let dark = noise.dark_offset_units();
    clean
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            (noise.measure_at(
                v,
                i as u64,
                &mut NoiseRng::new(&[seed, NOISE_TAG, i as u64]),
            ) - dark) as f32
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// White peaks that would store infinities or zeros are refused; ordinary ones pass, and
    /// at the edge of the range a saturated pixel is still a finite float32.
    #[test]
    fn white_peaks_outside_float32_are_refused() {
        let d = desc();
        for bad in [1e300, 1e-300, 0.0, -1.0, f64::NAN, f64::INFINITY, 1e38] {
            assert!(SensorNoise::check_white_peak(&d, bad).is_err(), "{bad}");
        }
        for good in [1e-3, 1.0, 2.5e4, 1e36] {
            assert!(SensorNoise::check_white_peak(&d, good).is_ok(), "{good}");
            let n = SensorNoise::new(&d, good);
            let v = n.measure(1e300, &mut NoiseRng::new(&[1]));
            assert!((v as f32).is_finite() && v > 0.0, "{good}: {v}");
        }
    }

    fn normal_cdf(x: f64) -> f64 {
        // Abramowitz & Stegun 7.1.26 for erf, |error| < 1.5e-7.
        let z = x.abs() / std::f64::consts::SQRT_2;
        let t = 1.0 / (1.0 + 0.327_591_1 * z);
        let y = 1.0
            - (((((1.061_405_429 * t - 1.453_152_027) * t) + 1.421_413_741) * t - 0.284_496_736)
                * t
                + 0.254_829_592)
                * t
                * (-z * z).exp();
        if x >= 0.0 {
            0.5 * (1.0 + y)
        } else {
            0.5 * (1.0 - y)
        }
    }

    #[test]
    fn normal_cdf_against_abramowitz_stegun() {
        for i in -60..=60 {
            let x = f64::from(i) * 0.1;
            assert!((super::normal_cdf(x) - normal_cdf(x)).abs() < 3e-7, "{x}");
        }
        assert!((super::normal_cdf(1.0) - 0.841_344_746).abs() < 1e-7);
    }

    #[test]
    fn ziggurat_is_standard_normal() {
        // Chi-square over 40 equiprobable-ish bins on [-4, 4] plus two tails, 400k deviates.
        let n = 400_000;
        let edges: Vec<f64> = (0..=40).map(|i| -4.0 + 0.2 * i as f64).collect();
        let mut counts = vec![0u64; 42];
        let (mut s1, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let x = NoiseRng::new(&[7, i]).normal();
            s1 += x;
            s2 += x * x;
            let b = if x < -4.0 {
                0
            } else if x >= 4.0 {
                41
            } else {
                1 + ((x + 4.0) / 0.2) as usize
            };
            counts[b] += 1;
        }
        let mut chi2 = 0.0;
        for b in 0..42 {
            let (lo, hi) = match b {
                0 => (f64::NEG_INFINITY, -4.0),
                41 => (4.0, f64::INFINITY),
                _ => (edges[b - 1], edges[b]),
            };
            let p = normal_cdf(hi) - normal_cdf(lo);
            let e = p * n as f64;
            if e > 5.0 {
                chi2 += (counts[b] as f64 - e).powi(2) / e;
            }
        }
        // ~39 degrees of freedom: the 99.9 % point is 72.
        assert!(chi2 < 72.0, "chi2 = {chi2}");
        let mean = s1 / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(
            mean.abs() < 0.01 && (var - 1.0).abs() < 0.01,
            "{mean} {var}"
        );
        // The tail beyond R is reached.
        let far = (0..2_000_000u64)
            .filter(|&i| NoiseRng::new(&[9, i]).normal().abs() > ZIG_R)
            .count();
        // P(|x| > 3.4426) = 5.76e-4 → 1152 expected.
        assert!((1000..1300).contains(&far), "{far}");
    }

    #[test]
    fn poisson_mean_and_variance() {
        for &m in &[0.3, 4.0, 25.0] {
            let n = 200_000u64;
            let (mut s1, mut s2) = (0.0, 0.0);
            for i in 0..n {
                let k = NoiseRng::new(&[3, i]).poisson(m);
                s1 += k;
                s2 += k * k;
            }
            let mean = s1 / n as f64;
            let var = s2 / n as f64 - mean * mean;
            let se = (m / n as f64).sqrt();
            assert!((mean - m).abs() < 5.0 * se, "mean {mean} vs {m}");
            assert!((var / m - 1.0).abs() < 0.03, "var {var} vs {m}");
        }
    }

    /// The EMVA 1288 terms: every term off is the ideal sensor bit for bit; a pixel keeps its
    /// pattern in every frame; over 200k pixels the gains spread by `prnu`, the offsets by
    /// `dsnu_e`, the dark mean is dark current × time doubled per `dark_current_doubling_k`,
    /// and the fraction of hot pixels is `hot_pixel_fraction` (each within 4 standard errors).
    #[test]
    fn emva_fixed_patterns() {
        let ideal = SensorNoise::new(&desc(), 2.0);
        let mut off = desc();
        off.sensor_seed = 5;
        off.dark_current_doubling_k = 3.0;
        let off = SensorNoise::new(&off, 2.0);
        assert!(off.fixed.is_none());
        for i in 0..1000u64 {
            let v = i as f64 * 0.003;
            let a = ideal.measure(v, &mut NoiseRng::new(&[1, i]));
            let b = off.measure_at(v, i, &mut NoiseRng::new(&[1, i]));
            assert_eq!(a.to_bits(), b.to_bits());
        }
        let mut d = desc();
        d.prnu = 0.02;
        d.dsnu_e = 3.0;
        d.dark_current_e_per_s = 40.0;
        d.exposure_time_ms = 250.0;
        d.temperature_above_reference_k = 13.0;
        d.hot_pixel_fraction = 0.01;
        d.hot_pixel_dark_e = 500.0;
        d.sensor_seed = 11;
        assert!((d.mean_dark_e() - 40.0 * 0.25 * 4.0).abs() < 1e-12);
        let nz = SensorNoise::new(&d, 2.0);
        let f = nz.fixed.unwrap();
        let n = 200_000u64;
        let (mut g1, mut g2, mut o1, mut o2, mut hot) = (0.0, 0.0, 0.0, 0.0, 0u64);
        for i in 0..n {
            let p = f.pixel(i);
            assert_eq!(p, nz.pixel(i));
            g1 += p.gain;
            g2 += p.gain * p.gain;
            o1 += p.offset_e;
            o2 += p.offset_e * p.offset_e;
            if p.dark_e > 40.0 + 1e-9 {
                assert!((p.dark_e - 540.0).abs() < 1e-9);
                hot += 1;
            } else {
                assert!((p.dark_e - 40.0).abs() < 1e-9);
            }
        }
        let nf = n as f64;
        let sd = |s1: f64, s2: f64| (s2 / nf - (s1 / nf).powi(2)).sqrt();
        // Standard error of a standard deviation: sd/sqrt(2n) (0.16 %).
        assert!(
            (sd(g1, g2) / 0.02 - 1.0).abs() < 4.0 / (2.0 * nf).sqrt(),
            "{}",
            sd(g1, g2)
        );
        assert!((g1 / nf - 1.0).abs() < 4.0 * 0.02 / nf.sqrt());
        assert!((sd(o1, o2) / 3.0 - 1.0).abs() < 4.0 / (2.0 * nf).sqrt());
        let p_hot = hot as f64 / nf;
        assert!(
            (p_hot - 0.01).abs() < 4.0 * (0.01 * 0.99 / nf).sqrt(),
            "{p_hot}"
        );
        // Doubled PRNU is outside the band (the check can fail).
        assert!((sd(g1, g2) / 0.04 - 1.0).abs() > 0.4);
        // A pixel keeps its pattern in every frame: the mean of 4000 frames of one pixel at
        // v = 0.5 is G·v·g + dark (+ offset), in capture units with the dark offset.
        let i = 12_345u64;
        let p = nz.pixel(i);
        let m: f64 = (0..4000u64)
            .map(|k| nz.measure_at(0.5, i, &mut NoiseRng::new(&[9, k])))
            .sum::<f64>()
            / 4000.0;
        let g = nz.electrons_per_unit;
        let want = (0.5 * g * p.gain + p.dark_e + p.offset_e) / g + nz.dark_offset_units();
        let se = ((0.5 * g * p.gain + p.dark_e + 49.0).sqrt() / g) / 4000f64.sqrt();
        assert!((m - want).abs() < 4.0 * se, "{m} {want} {se}");
    }

    fn desc() -> NoiseDesc {
        NoiseDesc::ideal(10000.0, 0.8, 7.0, 4.0, 12)
    }

    #[test]
    fn measurement_statistics() {
        let nz = SensorNoise::new(&desc(), 2.0);
        // White peak at 80 % of 4095 DN.
        assert!((2.0 * nz.dn_per_unit() - 0.8 * 4095.0).abs() < 1e-9);
        // Mean = v + dark offset; variance = (e + read²)/G² + quantisation 1/12 DN².
        let v = 0.5;
        let n = 100_000u64;
        let (mut s1, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let x = nz.measure(v, &mut NoiseRng::new(&[1, i]));
            s1 += x;
            s2 += x * x;
        }
        let mean = s1 / n as f64;
        let var = s2 / n as f64 - mean * mean;
        let g = nz.electrons_per_unit;
        let e = v * g;
        let expect_var = (e + 49.0) / (g * g) + 1.0 / 12.0 / nz.dn_per_unit().powi(2);
        assert!((mean - v - nz.dark_offset_units()).abs() < 4.0 * (expect_var / n as f64).sqrt());
        assert!((var / expect_var - 1.0).abs() < 0.02, "{var} {expect_var}");
        // `variance` states the same model (used by the discrepancy principle); at twice the
        // signal it is outside the sampled variance's 2 % band (the check can fail).
        assert!((nz.variance(v) / var - 1.0).abs() < 0.02);
        assert!((nz.variance(2.0 * v) / var - 1.0).abs() > 0.2);
        // mse_about agrees there (s ≫ ½ DN) and, for a dark pixel of an 8-bit sensor at its
        // integer black level (s ≈ 0.18 DN), matches the sampled mean squared error, which
        // is far below the uniform-rounding variance.
        assert!((nz.mse_about(v) / var - 1.0).abs() < 0.02);
        let mut d8 = desc();
        d8.bit_depth = 8;
        let nz8 = SensorNoise::new(&d8, 2.0);
        let off = nz8.dark_offset_units();
        let n = 400_000u64;
        let mut mse = 0.0;
        for i in 0..n {
            let x = nz8.measure(0.0, &mut NoiseRng::new(&[6, i])) - off;
            mse += x * x / n as f64;
        }
        let m = nz8.mse_about(0.0);
        assert!((m / mse - 1.0).abs() < 0.1, "{m} {mse}");
        assert!(nz8.variance(0.0) > 5.0 * m);
        // A dimly lit pixel: s = 0.3 DN (89 e⁻), its rounding error neither uniform nor nil.
        let v =
            (0.09 * nz8.electrons_per_dn * nz8.electrons_per_dn - 49.0) / nz8.electrons_per_unit;
        let mut mse = 0.0;
        for i in 0..n {
            let x = nz8.measure(v, &mut NoiseRng::new(&[7, i])) - off - v;
            mse += x * x / n as f64;
        }
        assert!(
            (nz8.mse_about(v) / mse - 1.0).abs() < 0.03,
            "{} {mse}",
            nz8.mse_about(v)
        );
        // Saturation clips at full scale.
        let x = nz.measure(10.0, &mut NoiseRng::new(&[2]));
        assert!((x * nz.dn_per_unit() - 4095.0).abs() < 1e-9);
        assert!(nz.saturates(10.0) && !nz.saturates(1.0));
        // Zero light: only read noise and the offset, never negative.
        let x = nz.measure(0.0, &mut NoiseRng::new(&[5]));
        assert!(x >= 0.0);
    }
}
