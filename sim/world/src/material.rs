//! Runtime materials of mesh surfaces: spectral reflectance (an RGB colour or texture
//! upsampled by Jakob & Hanika 2019, or a measured reflectance spectrum), emission, and the
//! BSDF at a hit.
//!
//! Emission follows Mitsuba 3's spectral variants: an RGB emission e becomes
//! max(e)·ρ(e/max(e))(λ)·D65(λ), i.e. the reflectance-upsampled colour times the D65
//! illuminant (normalised to mean 1 over 380–780 nm), so an asset's white emitter of value 1
//! has the radiance of display white with a D65 spectrum. A named emission spectrum S gives
//! scale·S(λ)·Y(texture) (Y = Rec. 709 luminance of the emission texture, 1 without one).

use std::sync::Arc;

use glam::DVec2;

use super::bsdf::Bsdf;
use super::mesh::SurfaceModel;
use super::spectra3d::{RgbSpectrum, emission_from_rgb, reflectance_from_rgb};
use super::texture::Texture;
use crate::spectra::Spectrum;

/// Rec. 709 luminance weights.
const LUMA: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// Where a surface's reflectance comes from.
#[derive(Clone, Debug)]
pub enum Reflectance {
    /// A constant colour, upsampled once.
    Rgb(RgbSpectrum),
    /// A texture × factor, upsampled per lookup.
    Texture(Arc<Texture>, [f64; 3]),
    /// A measured spectrum.
    Spectral(Spectrum),
}

/// Where a surface's emission comes from.
#[derive(Clone, Debug)]
pub enum Emission {
    /// Not emissive.
    None,
    /// RGB (× optional texture) × scale, times the D65 illuminant.
    Rgb {
        /// RGB factor × strength × scale.
        rgb: [f64; 3],
        /// Texture multiplying the factor.
        texture: Option<Arc<Texture>>,
    },
    /// A spectrum × scale × luminance of an optional texture.
    Spectral {
        /// Spectrum × scale.
        spectrum: Spectrum,
        /// Texture whose luminance modulates it.
        texture: Option<Arc<Texture>>,
    },
}

/// A runtime material.
#[derive(Clone, Debug)]
pub struct Material {
    /// Name (for the sidecar).
    pub name: String,
    /// Scattering model.
    pub model: SurfaceModel,
    /// Reflectance (base colour).
    pub reflectance: Reflectance,
    /// Roughness.
    pub roughness: f64,
    /// Metalness.
    pub metallic: f64,
    /// Emission.
    pub emission: Emission,
    /// Nearest-texel texture lookups instead of bilinear.
    pub nearest: bool,
    /// The linear RGB behind `Reflectance::Rgb` (for vertex colours), if it is one.
    pub base_rgb: Option<[f64; 3]>,
    /// Which hits count (alpha mode, single-sided).
    pub coverage: super::coverage::Coverage,
    /// Tangent-space normal map and its scale ([`super::normal_map`]).
    pub normal_map: Option<(Arc<Texture>, f64)>,
}

fn lookup(t: &Texture, uv: DVec2, nearest: bool) -> [f64; 3] {
    if nearest {
        t.lookup_nearest(uv)
    } else {
        t.lookup(uv)
    }
}

impl Material {
    /// Reflectance at wavelength `lambda_nm` and texture coordinate `uv`.
    pub fn base(&self, uv: DVec2, lambda_nm: f64) -> f64 {
        match &self.reflectance {
            Reflectance::Rgb(s) => s.eval(lambda_nm),
            Reflectance::Texture(t, f) => {
                let c = lookup(t, uv, self.nearest);
                reflectance_from_rgb([c[0] * f[0], c[1] * f[1], c[2] * f[2]]).eval(lambda_nm)
            }
            Reflectance::Spectral(s) => s.eval(lambda_nm).clamp(0.0, 1.0),
        }
    }

    /// True if the surface emits.
    pub fn emits(&self) -> bool {
        !matches!(self.emission, Emission::None)
    }

    /// Emitted spectral radiance (front side) at `uv`, wavelength `lambda_nm`.
    pub fn emitted(&self, uv: DVec2, lambda_nm: f64) -> f64 {
        match &self.emission {
            Emission::None => 0.0,
            Emission::Rgb { rgb, texture } => {
                let c = match texture {
                    Some(t) => {
                        let c = lookup(t, uv, self.nearest);
                        [c[0] * rgb[0], c[1] * rgb[1], c[2] * rgb[2]]
                    }
                    None => *rgb,
                };
                emission_from_rgb(c, lambda_nm)
            }
            Emission::Spectral { spectrum, texture } => {
                let y = match texture {
                    Some(t) => {
                        let c = lookup(t, uv, self.nearest);
                        LUMA[0] * c[0] + LUMA[1] * c[1] + LUMA[2] * c[2]
                    }
                    None => 1.0,
                };
                spectrum.eval(lambda_nm) * y
            }
        }
    }

    /// Reflectance at `uv` with the base colour multiplied by a vertex colour `tint` (linear
    /// RGB, upsampled per lookup); a measured spectrum is not tinted (it replaces the base
    /// colour).
    pub fn base_tinted(&self, uv: DVec2, tint: Option<[f64; 3]>, lambda_nm: f64) -> f64 {
        let Some(k) = tint else {
            return self.base(uv, lambda_nm);
        };
        let rgb = match (&self.reflectance, self.base_rgb) {
            (Reflectance::Rgb(_), Some(c)) => c,
            (Reflectance::Texture(t, f), _) => {
                let c = lookup(t, uv, self.nearest);
                [c[0] * f[0], c[1] * f[1], c[2] * f[2]]
            }
            _ => return self.base(uv, lambda_nm),
        };
        reflectance_from_rgb([rgb[0] * k[0], rgb[1] * k[1], rgb[2] * k[2]]).eval(lambda_nm)
    }

    /// The BSDF at a hit.
    pub fn bsdf(&self, uv: DVec2, lambda_nm: f64) -> Bsdf {
        self.bsdf_tinted(uv, None, lambda_nm)
    }

    /// The BSDF at a hit whose base colour is multiplied by the vertex colour `tint`.
    pub fn bsdf_tinted(&self, uv: DVec2, tint: Option<[f64; 3]>, lambda_nm: f64) -> Bsdf {
        let base = self.base_tinted(uv, tint, lambda_nm);
        match self.model {
            SurfaceModel::Diffuse => Bsdf::Diffuse { albedo: base },
            SurfaceModel::MetallicRoughness => Bsdf::MetallicRoughness {
                base,
                metallic: self.metallic,
                roughness: self.roughness,
            },
        }
    }
}
