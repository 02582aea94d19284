//! The display (LCD) as an emissive plane whose spectral radiance follows the target image.
//!
//! Model (`docs/physics.md` §6.1): the display plane z = −D carries the target image,
//! each target pixel shown as a square of `lcd_pixels_per_image_pixel`² LCD pixels. Relative
//! radiance at a point is L_black + (1 − L_black)·V^γ for display code value V (PNG and
//! built-in targets), or L_black + (1 − L_black)·V for linear (EXR) input; the rest of the LCD
//! shows black (L_black) and everything beyond the LCD is dark (0). Spectral radiance is the
//! relative radiance times the backlight spectrum S(λ) (normalised to mean 1 over 380–780 nm).
//! Emission is Lambertian (constant radiance) over the few degrees the screen subtends.
//! Polarisation: linearly polarised at angle ψ from x → TE weight cos²ψ, TM weight sin²ψ
//! (TE = E along x for the vertical diffraction plane); "none" → ½, ½.
//!
//! Colour (`display.primaries = "lcd"`): the pixel emits Σ_p L_p·P_p(λ) over three primaries
//! p = R, G, B with spectra P_p (`spectra::display_primaries`: backlight × colour filter,
//! white = P_R + P_G + P_B of mean 1), L_p = L_black + (1 − L_black)·f_p from the linear
//! intensity f_p of primary p (an RGB target's channels, each linearised; a grey target drives
//! the three primaries equally); the object is then three planes, primary-major. The
//! backlight spectrum S of the monochrome model becomes the white W = Σ_p P_p, and a sample at λ
//! sees the pixel as W(λ)·Σ_p w_p(λ)·L_p with w_p = P_p/W (Σ_p w_p = 1), so the monochrome
//! code path and its numbers are untouched when the key is off.
//!
//! Assumptions: no sub-pixel (RGB stripe) structure (the three primaries of a pixel share its
//! area), uniform backlight, no angular falloff.

use glam::DVec2;

use crate::spectra::Spectrum;

/// The runtime display built from the scene.
#[derive(Clone, Debug)]
pub struct Display {
    /// Plane position z in mm (negative).
    pub z_mm: f64,
    /// Centre of the image on the plane, mm.
    pub center_mm: DVec2,
    /// Size of one target pixel, mm.
    pub image_pixel_mm: f64,
    /// Target width in pixels.
    pub width_px: usize,
    /// Target height in pixels.
    pub height_px: usize,
    /// Linear intensity per target pixel in [0, 1] (0 = black, 1 = white; display gamma
    /// already applied), row-major, row 0 top. This is the object vector f of g = Hf. With
    /// colour primaries: three planes (R, G, B), primary-major, index p·W·H + pixel.
    pub intensity: Vec<f64>,
    /// Relative linear radiance per target pixel (and primary, as `intensity`):
    /// black + (1 − black)·intensity.
    pub radiance: Vec<f64>,
    /// Relative radiance of black LCD pixels.
    pub black_level: f64,
    /// Half extents of the LCD, mm.
    pub half_extent_mm: DVec2,
    /// Backlight spectrum (mean 1 over 380–780 nm); with colour primaries their sum, white.
    pub spectrum: Spectrum,
    /// Colour primaries [R, G, B] (spectra summing to `spectrum`), or None: monochrome.
    pub primaries: Option<Box<[Spectrum; 3]>>,
    /// Fractions of the emitted power in TE and TM.
    pub polarization_weights: [f64; 2],
}

impl Display {
    /// Converts code values (or linear values if `linear`) into relative radiance
    /// black + (1 − black)·[`Display::intensity_of`].
    pub fn linearise(
        values: &[f32],
        channels: usize,
        linear: bool,
        gamma: f64,
        black_level: f64,
    ) -> Vec<f64> {
        Self::intensity_of(values, channels, linear, gamma)
            .into_iter()
            .map(|l| black_level + (1.0 - black_level) * l)
            .collect()
    }

    /// Converts code values (or linear values if `linear`) into linear intensity in [0, 1].
    /// With three channels (an RGB target) each is linearised first and then combined with
    /// the Rec. 709 luminance weights (0.2126, 0.7152, 0.0722).
    pub fn intensity_of(values: &[f32], channels: usize, linear: bool, gamma: f64) -> Vec<f64> {
        const LUMINANCE: [f64; 3] = [0.2126, 0.7152, 0.0722];
        let lin = |v: f32| {
            let v = f64::from(v).clamp(0.0, 1.0);
            if linear { v } else { v.powf(gamma) }
        };
        values
            .chunks_exact(channels.max(1))
            .map(|px| {
                if px.len() == 3 {
                    px.iter().zip(LUMINANCE).map(|(&v, w)| w * lin(v)).sum()
                } else {
                    lin(px[0])
                }
            })
            .collect()
    }

    /// Converts code values (or linear values if `linear`) into `planes` planes of linear
    /// intensity (planar, primary-major): 1 plane is [`Display::intensity_of`]; 3 planes are an
    /// RGB image's channels, each linearised, or a grey image's values in all three.
    pub fn planes_of(
        values: &[f32],
        channels: usize,
        linear: bool,
        gamma: f64,
        planes: usize,
    ) -> Vec<f64> {
        if planes != 3 {
            return Self::intensity_of(values, channels, linear, gamma);
        }
        let c = channels.max(1);
        let n = values.len() / c;
        let lin = |v: f32| {
            let v = f64::from(v).clamp(0.0, 1.0);
            if linear { v } else { v.powf(gamma) }
        };
        (0..3)
            .flat_map(|p| {
                let ch = if c == 3 { p } else { 0 };
                (0..n).map(move |i| lin(values[i * c + ch]))
            })
            .collect()
    }

    /// Relative radiance of target pixel `k` (row-major), summed over the primaries of a
    /// colour display.
    #[inline]
    pub fn pixel_radiance(&self, k: usize) -> f64 {
        let n = self.width_px * self.height_px;
        (0..self.planes()).map(|p| self.radiance[p * n + k]).sum()
    }

    /// Object planes: 1 (monochrome) or 3 (colour primaries R, G, B).
    pub fn planes(&self) -> usize {
        if self.primaries.is_some() { 3 } else { 1 }
    }

    /// Object pixels, planes × width × height (the columns of H).
    pub fn object_len(&self) -> usize {
        self.planes() * self.width_px * self.height_px
    }

    /// Shows a new object: linear intensities in [0, 1] (clamped), row-major, one per target
    /// pixel and plane ([`Display::object_len`] values); a colour display also takes one plane,
    /// shown on all three primaries (grey). The target size does not change.
    pub fn set_intensity(&mut self, intensity: &[f64]) {
        let n = self.width_px * self.height_px;
        debug_assert!(intensity.len() == n || intensity.len() == self.object_len());
        let bl = self.black_level;
        let reps = if intensity.len() == n {
            self.planes()
        } else {
            1
        };
        self.intensity = (0..reps)
            .flat_map(|_| intensity.iter().map(|v| v.clamp(0.0, 1.0)))
            .collect();
        self.radiance = self.intensity.iter().map(|l| bl + (1.0 - bl) * l).collect();
    }

    /// The primaries' shares w_p(λ) = P_p(λ)/W(λ) of white at `lambda_nm` (0 where W is 0);
    /// [1, 0, 0] for a monochrome display.
    #[inline]
    pub fn primary_weights(&self, lambda_nm: f64) -> [f64; 3] {
        match &self.primaries {
            None => [1.0, 0.0, 0.0],
            Some(p) => {
                let w = self.spectrum.eval(lambda_nm);
                if w > 0.0 {
                    let inv = 1.0 / w;
                    std::array::from_fn(|k| p[k].eval(lambda_nm) * inv)
                } else {
                    [0.0; 3]
                }
            }
        }
    }

    /// Relative radiance at `p` of a colour display for primary shares `w`
    /// ([`Display::primary_weights`]): Σ_k w_k·L_k, black on the rest of the LCD, 0 beyond.
    /// For a monochrome display this is [`Display::radiance_at`].
    #[inline]
    pub fn radiance_weighted_at(&self, p: DVec2, w: &[f64; 3]) -> f64 {
        if self.primaries.is_none() {
            return self.radiance_at(p);
        }
        if let Some((c, r)) = self.pixel_at(p) {
            let n = self.width_px * self.height_px;
            let k = r * self.width_px + c;
            return w[0] * self.radiance[k]
                + w[1] * self.radiance[n + k]
                + w[2] * self.radiance[2 * n + k];
        }
        let d = (p - self.center_mm).abs();
        if d.x <= self.half_extent_mm.x && d.y <= self.half_extent_mm.y {
            self.black_level
        } else {
            0.0
        }
    }

    /// Spectral radiance (relative, white's spectrum of mean 1) at `p` and `lambda_nm`: the
    /// backlight spectrum times [`Display::radiance_at`] for a monochrome display, Σ_k L_k·P_k(λ)
    /// for a colour one.
    #[inline]
    pub fn spectral_radiance_at(&self, p: DVec2, lambda_nm: f64) -> f64 {
        if self.primaries.is_none() {
            return self.radiance_at(p) * self.spectrum.eval(lambda_nm);
        }
        let w = self.primary_weights(lambda_nm);
        self.radiance_weighted_at(p, &w) * self.spectrum.eval(lambda_nm)
    }

    /// TE/TM power fractions for a polariser at `angle_deg` from x, or unpolarised (`None`).
    pub fn polarization_weights(angle_deg: Option<f64>) -> [f64; 2] {
        match angle_deg {
            None => [0.5, 0.5],
            Some(a) => {
                let c = a.to_radians().cos();
                [c * c, 1.0 - c * c]
            }
        }
    }

    /// Target pixel (col, row) containing point `p` on the plane, if inside the image.
    #[inline]
    pub fn pixel_at(&self, p: DVec2) -> Option<(usize, usize)> {
        let inv = self.image_pixel_mm.recip();
        let fx = (p.x - self.center_mm.x) * inv + 0.5 * self.width_px as f64;
        let fy = (self.center_mm.y - p.y) * inv + 0.5 * self.height_px as f64;
        if fx >= 0.0 && fy >= 0.0 && fx < self.width_px as f64 && fy < self.height_px as f64 {
            Some((fx as usize, fy as usize))
        } else {
            None
        }
    }

    /// True if `p` lies on the lit LCD (the target or the black surround around it).
    #[inline]
    pub fn on_lcd(&self, p: DVec2) -> bool {
        self.within_extent(p) || self.pixel_at(p).is_some()
    }

    /// True if `p` lies within the LCD's extent (the target may reach beyond it).
    #[inline]
    pub fn within_extent(&self, p: DVec2) -> bool {
        let d = (p - self.center_mm).abs();
        d.x <= self.half_extent_mm.x && d.y <= self.half_extent_mm.y
    }

    /// Relative radiance (white = 1) at point `p` on the display plane (monochrome; the red
    /// plane of a colour display: use [`Display::radiance_weighted_at`] there).
    #[inline]
    pub fn radiance_at(&self, p: DVec2) -> f64 {
        if let Some((c, r)) = self.pixel_at(p) {
            return self.radiance[r * self.width_px + c];
        }
        let d = (p - self.center_mm).abs();
        if d.x <= self.half_extent_mm.x && d.y <= self.half_extent_mm.y {
            self.black_level
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spectra::{DisplaySpectrumKind, display_spectrum};

    fn disp() -> Display {
        // 2×2 target: top-left white, others code 0.5 / 0 / 0.
        Display {
            z_mm: -550.0,
            center_mm: DVec2::new(0.0, 0.0),
            image_pixel_mm: 2.7,
            width_px: 2,
            height_px: 2,
            intensity: Display::intensity_of(&[1.0, 0.5, 0.0, 0.0], 1, false, 2.2),
            radiance: Display::linearise(&[1.0, 0.5, 0.0, 0.0], 1, false, 2.2, 0.001),
            black_level: 0.001,
            half_extent_mm: DVec2::new(259.2, 162.0),
            spectrum: display_spectrum(DisplaySpectrumKind::Flat),
            primaries: None,
            polarization_weights: Display::polarization_weights(None),
        }
    }

    #[test]
    fn orientation_and_levels() {
        let d = disp();
        // Top-left pixel is at −x, +y.
        assert_eq!(d.pixel_at(DVec2::new(-1.0, 1.0)), Some((0, 0)));
        assert_eq!(d.radiance_at(DVec2::new(-1.0, 1.0)), 1.0);
        let half = 0.001 + 0.999 * 0.5f64.powf(2.2);
        assert!((d.radiance_at(DVec2::new(1.0, 1.0)) - half).abs() < 1e-12);
        assert_eq!(d.radiance_at(DVec2::new(-1.0, -1.0)), 0.001);
        // Outside the target but on the LCD: black; beyond the LCD: dark.
        assert_eq!(d.radiance_at(DVec2::new(100.0, 0.0)), 0.001);
        assert_eq!(d.radiance_at(DVec2::new(300.0, 0.0)), 0.0);
        assert_eq!(Display::polarization_weights(Some(0.0)), [1.0, 0.0]);
        // RGB: each channel is linearised before the luminance sum.
        let rgb = Display::linearise(&[0.5, 0.5, 0.5, 1.0, 0.0, 0.0], 3, false, 2.2, 0.0);
        assert!((rgb[0] - 0.5f64.powf(2.2)).abs() < 1e-12);
        assert!((rgb[1] - 0.2126).abs() < 1e-12);
        let w = Display::polarization_weights(Some(90.0));
        assert!(w[0] < 1e-30 && (w[1] - 1.0).abs() < 1e-15);
    }
}
