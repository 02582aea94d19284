//! Image textures on meshes: linear RGB texels, glTF wrap modes, bilinear filtering.
//!
//! Model: colour textures (base colour, emission) are stored in sRGB code values by glTF 2.0
//! (§3.9.2) and by common OBJ practice; they are decoded to linear RGB with the IEC 61966-2-1
//! sRGB transfer function once on load. EXR textures are already linear. Lookup at texture
//! coordinate (u, v) (glTF convention: (0, 0) = top-left of the image) maps to texel space
//! x = u·W − ½, y = v·H − ½ and interpolates bilinearly between the four nearest texels after
//! wrapping each index (repeat, mirrored repeat or clamp to edge, glTF sampler modes).
//! Alpha (glTF base colour alpha, a coverage) is linear in every format (glTF §3.9.2: only
//! the RGB channels are sRGB-encoded) and is filtered the same way; it is kept only when
//! some texel is below 1.

use std::path::Path;

use glam::DVec2;

use crate::io::IoError;

/// Largest texture file read.
pub const MAX_TEXTURE_BYTES: u64 = 1 << 30;

/// How coordinates outside [0, 1] are folded back (glTF sampler `wrapS`/`wrapT`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Wrap {
    /// Tile (glTF 10497, the default).
    #[default]
    Repeat,
    /// Clamp to the edge texel (glTF 33071).
    ClampToEdge,
    /// Tile with every other copy mirrored (glTF 33648).
    MirroredRepeat,
}

impl Wrap {
    /// The wrap mode of a glTF sampler enum value (repeat for unknown values).
    pub fn from_gltf(code: u32) -> Wrap {
        match code {
            33071 => Wrap::ClampToEdge,
            33648 => Wrap::MirroredRepeat,
            _ => Wrap::Repeat,
        }
    }

    #[inline]
    fn index(self, i: i64, n: usize) -> usize {
        let n = n as i64;
        let k = match self {
            Wrap::Repeat => i.rem_euclid(n),
            Wrap::ClampToEdge => i.clamp(0, n - 1),
            Wrap::MirroredRepeat => {
                let m = i.rem_euclid(2 * n);
                if m < n { m } else { 2 * n - 1 - m }
            }
        };
        k as usize
    }
}

/// An RGB texture in linear values, row 0 at the top.
#[derive(Clone, Debug)]
pub struct Texture {
    /// Width in texels.
    pub width: usize,
    /// Height in texels.
    pub height: usize,
    /// Linear RGB texels, row-major.
    pub texels: Vec<[f32; 3]>,
    /// Wrap mode along u.
    pub wrap_s: Wrap,
    /// Wrap mode along v.
    pub wrap_t: Wrap,
    /// Linear alpha per texel, row-major; empty where the image is opaque.
    pub alpha: Vec<f32>,
}

/// IEC 61966-2-1 sRGB decoding of a code value in [0, 1].
#[inline]
pub fn srgb_to_linear(c: f64) -> f64 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

impl Texture {
    /// Builds a texture from decoded pixels: `channels` (1 or 3) values per pixel, code values
    /// decoded with the sRGB curve unless `linear`.
    pub fn from_pixels(
        width: usize,
        height: usize,
        channels: usize,
        values: &[f32],
        linear: bool,
    ) -> Texture {
        let dec = |v: f32| {
            if linear {
                f64::from(v).max(0.0) as f32
            } else {
                srgb_to_linear(f64::from(v)) as f32
            }
        };
        let texels = values
            .chunks_exact(channels.max(1))
            .map(|px| {
                if px.len() >= 3 {
                    [dec(px[0]), dec(px[1]), dec(px[2])]
                } else {
                    let g = dec(px[0]);
                    [g, g, g]
                }
            })
            .collect();
        Texture {
            width,
            height,
            texels,
            wrap_s: Wrap::Repeat,
            wrap_t: Wrap::Repeat,
            alpha: Vec::new(),
        }
    }

    /// The same texture with a linear alpha channel (one value a texel, clamped to [0, 1]);
    /// an alpha of another length, or one that is 1 everywhere, is not kept.
    pub fn with_alpha(mut self, alpha: Vec<f32>) -> Texture {
        if alpha.len() == self.texels.len() && alpha.iter().any(|a| !(*a >= 1.0)) {
            self.alpha = alpha
                .into_iter()
                .map(|a| if a.is_nan() { 0.0 } else { a.clamp(0.0, 1.0) })
                .collect();
        }
        self
    }

    /// Loads a PNG, JPEG or EXR file as a colour texture (sRGB-decoded unless EXR).
    pub fn load(path: &Path) -> Result<Texture, IoError> {
        // Type- and size-check before reading whole: a FIFO would block, a device never end.
        let meta = std::fs::metadata(path).map_err(|e| IoError::io(path, e))?;
        if !meta.is_file() {
            return Err(IoError::format(path, "is not a regular file"));
        }
        if meta.len() > MAX_TEXTURE_BYTES {
            return Err(IoError::format(
                path,
                format!("texture file is larger than {MAX_TEXTURE_BYTES} bytes"),
            ));
        }
        let img = crate::io::image_load::load_texture_image(path)?;
        Ok(Texture::from_pixels(
            img.width,
            img.height,
            img.channels,
            &img.values,
            img.linear,
        ))
    }

    /// A 1×1 texture of one colour.
    pub fn constant(rgb: [f64; 3]) -> Texture {
        Texture::from_pixels(1, 1, 3, &rgb.map(|v| v as f32), true)
    }

    /// Linear RGB of the texel containing texture coordinate `uv` (no filtering).
    pub fn lookup_nearest(&self, uv: DVec2) -> [f64; 3] {
        match self.nearest_index(uv) {
            Some(i) => self.texels[i].map(f64::from),
            None => [0.0; 3],
        }
    }

    /// Bilinearly filtered linear RGB at texture coordinate `uv`.
    pub fn lookup(&self, uv: DVec2) -> [f64; 3] {
        self.bilinear(uv, |i| self.texels[i])
    }

    /// Alpha at `uv` (1 without an alpha channel), bilinear or of the nearest texel.
    pub fn alpha_at(&self, uv: DVec2, nearest: bool) -> f64 {
        if self.alpha.is_empty() {
            return 1.0;
        }
        if nearest {
            return match self.nearest_index(uv) {
                Some(i) => f64::from(self.alpha[i]),
                None => 0.0,
            };
        }
        self.bilinear(uv, |i| [self.alpha[i]])[0]
    }

    /// Index of the texel containing `uv` (None for a non-finite coordinate).
    fn nearest_index(&self, uv: DVec2) -> Option<usize> {
        let (x, y) = (
            (uv.x * self.width as f64).floor(),
            (uv.y * self.height as f64).floor(),
        );
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
        let xi = self.wrap_s.index(x as i64, self.width);
        let yi = self.wrap_t.index(y as i64, self.height);
        Some(yi * self.width + xi)
    }

    /// Bilinear interpolation of the `N` values `fetch` gives for a texel index.
    #[inline]
    fn bilinear<const N: usize>(&self, uv: DVec2, fetch: impl Fn(usize) -> [f32; N]) -> [f64; N] {
        let x = uv.x * self.width as f64 - 0.5;
        let y = uv.y * self.height as f64 - 0.5;
        if !(x.is_finite() && y.is_finite()) {
            return [0.0; N];
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let xs = [
            self.wrap_s.index(x0, self.width),
            self.wrap_s.index(x0 + 1, self.width),
        ];
        let ys = [
            self.wrap_t.index(y0, self.height),
            self.wrap_t.index(y0 + 1, self.height),
        ];
        let mut out = [0.0; N];
        for (j, &yy) in ys.iter().enumerate() {
            let wy = if j == 0 { 1.0 - fy } else { fy };
            for (i, &xx) in xs.iter().enumerate() {
                let wx = if i == 0 { 1.0 - fx } else { fx };
                let t = fetch(yy * self.width + xx);
                for c in 0..N {
                    out[c] += wx * wy * f64::from(t[c]);
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_modes_and_bilinear() {
        // 2×1: left black, right white (linear).
        let mut t = Texture::from_pixels(2, 1, 1, &[0.0, 1.0], true);
        // Texel centres give the texel values exactly.
        assert_eq!(t.lookup(DVec2::new(0.25, 0.5))[0], 0.0);
        assert_eq!(t.lookup(DVec2::new(0.75, 0.5))[0], 1.0);
        assert!((t.lookup(DVec2::new(0.5, 0.5))[0] - 0.5).abs() < 1e-12);
        // Repeat: u = 1.25 is u = 0.25.
        assert_eq!(t.lookup(DVec2::new(1.25, 0.5))[0], 0.0);
        t.wrap_s = Wrap::ClampToEdge;
        assert_eq!(t.lookup(DVec2::new(1.25, 0.5))[0], 1.0);
        t.wrap_s = Wrap::MirroredRepeat;
        assert_eq!(t.lookup(DVec2::new(1.25, 0.5))[0], 1.0);
        assert_eq!(t.lookup(DVec2::new(1.75, 0.5))[0], 0.0);
        // sRGB: code 0.5 → 0.21404 (IEC 61966-2-1).
        assert!((srgb_to_linear(0.5) - 0.214_041_140_482_232_5).abs() < 1e-12);
        assert_eq!(Wrap::from_gltf(33071), Wrap::ClampToEdge);
    }
}
