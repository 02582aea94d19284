//! Emitters of the user side: rectangles, spheres, points, spots, the environment, and the
//! display (LCD) as an area light, each with a spectrum, sampled for next-event estimation.
//!
//! Models (pbrt-v4 §12, "Light Sources"): a `rect` is a one-sided Lambertian emitter of
//! constant radiance, sampled uniformly by area (solid-angle density p_A·d²/cos θ_l); it is
//! seen and blocks light only from its emitting side, and is transparent from behind, like
//! the emitting layer of a see-through screen. A `sphere` emits constant radiance outward and
//! is sampled uniformly inside the cone it subtends (pbrt-v4 `Sphere::Sample` with a
//! reference point). Rects that subtend between 3·10⁻⁴ and 6.22 sr from the shading point are
//! sampled uniformly in solid angle (Ureña, Fajardo & King 2013, "An Area-Preserving
//! Parametrization for Spherical Rectangles", as in pbrt-v4 `SampleSphericalRectangle`),
//! others by area; this removes the r²/cos θ variance of a large, close light such as a
//! screen 60 mm from a hand. `point` and `spot` are delta lights of radiant intensity I, giving
//! irradiance I·cos θ/d²; the spot's falloff is pbrt's smoothstep between the falloff and cone
//! half-angles. The `environment` is radiance at infinity, constant or from an
//! equirectangular map (u = ½ + atan2(x, −z)/2π, v = acos(y)/π; row 0 is straight up),
//! sampled uniformly over the sphere. The display emits its relative radiance × backlight
//! spectrum toward +z over the LCD; it is sampled from a mixture: half the samples uniform
//! over the LCD, half proportional to the target pixels' radiance.
//!
//! Spectra are normalised to mean 1 over 380–780 nm, so `scale` is in the capture unit (the
//! radiance of display white); RGB maps are upsampled as RGB × the light's spectrum.

use std::sync::Arc;

use glam::{DVec2, DVec3};

use super::bsdf::Frame;
use super::texture::Texture;
use crate::display::Display;
use crate::spectra::Spectrum;

/// An emitter with a finite or delta extent (not the environment, not the display).
#[derive(Clone, Debug)]
pub enum Light {
    /// One-sided rectangle.
    Rect {
        /// Centre, mm.
        center: DVec3,
        /// Half-width vector, mm.
        ex: DVec3,
        /// Half-height vector, mm.
        ey: DVec3,
        /// Unit normal (emitting side).
        normal: DVec3,
        /// Area, mm².
        area: f64,
        /// Spectral radiance scale × spectrum.
        spectrum: Spectrum,
    },
    /// Sphere.
    Sphere {
        /// Centre, mm.
        center: DVec3,
        /// Radius, mm.
        radius: f64,
        /// Radiance spectrum (scaled).
        spectrum: Spectrum,
    },
    /// Point (or spot) light.
    Point {
        /// Position, mm.
        position: DVec3,
        /// Spot axis and (cos cone, cos falloff), None for a point light.
        spot: Option<(DVec3, f64, f64)>,
        /// Intensity spectrum (scaled).
        spectrum: Spectrum,
    },
}

/// The environment: radiance at infinity.
#[derive(Clone, Debug)]
pub struct Environment {
    /// Spectrum × scale.
    pub spectrum: Spectrum,
    /// Optional equirectangular RGB map.
    pub map: Option<Arc<Texture>>,
}

/// Equirectangular texture coordinate of a unit direction.
pub fn equirect_uv(d: DVec3) -> DVec2 {
    let u = 0.5 + d.x.atan2(-d.z) / (2.0 * std::f64::consts::PI);
    let v = d.y.clamp(-1.0, 1.0).acos() / std::f64::consts::PI;
    DVec2::new(u, v)
}

impl Environment {
    /// Spectral radiance arriving from direction `d` (unit, pointing away from the scene).
    pub fn radiance(&self, d: DVec3, lambda_nm: f64) -> f64 {
        let s = self.spectrum.eval(lambda_nm);
        match &self.map {
            None => s,
            Some(m) => {
                s * super::spectra3d::rgb_emission_factor(m.lookup(equirect_uv(d)), lambda_nm)
            }
        }
    }
}

/// A sampled direction toward an emitter.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the shading point.
    pub wi: DVec3,
    /// Distance to the emitter point (infinite for the environment).
    pub dist: f64,
    /// Incident spectral radiance (or irradiance factor I/d² for delta lights).
    pub li: f64,
    /// Solid-angle density (1 for delta lights).
    pub pdf: f64,
    /// Delta light (no MIS).
    pub delta: bool,
}

/// Intersection of a ray with a sphere: smallest t > tmin.
pub fn ray_sphere(o: DVec3, d: DVec3, c: DVec3, r: f64, tmin: f64) -> Option<f64> {
    let oc = o - c;
    let a = d.length_squared();
    let b = oc.dot(d);
    // Stable discriminant (pbrt-v4 §6.2.2): b² − a(|oc|² − r²) = a(r² − |oc − (b/a)d|²).
    let perp = oc - d * (b / a);
    let disc = a * (r * r - perp.length_squared());
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    let q = if b > 0.0 { -(b + sq) } else { -(b - sq) };
    let (t0, t1) = {
        let x = q / a;
        let y = if q != 0.0 {
            (oc.length_squared() - r * r) / q
        } else {
            x
        };
        if x < y { (x, y) } else { (y, x) }
    };
    if t0 > tmin {
        Some(t0)
    } else if t1 > tmin {
        Some(t1)
    } else {
        None
    }
}

/// Solid-angle range in which a rect is sampled as a spherical rectangle (pbrt-v4's bounds).
const SPHERICAL_MIN_SR: f64 = 3e-4;
const SPHERICAL_MAX_SR: f64 = 6.22;

/// A rectangle as seen from a point (Ureña et al. 2013 §3), in the rectangle's local frame.
struct SphRect {
    x: DVec3,
    y: DVec3,
    z: DVec3,
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    z0: f64,
    b0: f64,
    b1: f64,
    k: f64,
    g0g1: f64,
    solid_angle: f64,
}

fn angle_between(a: DVec3, b: DVec3) -> f64 {
    // Numerically robust angle between unit vectors (pbrt-v4 AngleBetween).
    if a.dot(b) < 0.0 {
        std::f64::consts::PI - 2.0 * ((a + b).length() * 0.5).clamp(-1.0, 1.0).asin()
    } else {
        2.0 * ((b - a).length() * 0.5).clamp(-1.0, 1.0).asin()
    }
}

impl SphRect {
    /// The rect (centre c, half extents ex, ey) seen from p; None if degenerate.
    fn new(p: DVec3, c: DVec3, ex: DVec3, ey: DVec3) -> Option<SphRect> {
        let corner = c - ex - ey;
        let (exl, eyl) = (2.0 * ex.length(), 2.0 * ey.length());
        let x = ex.normalize();
        let y = ey.normalize();
        let mut z = x.cross(y);
        let d = corner - p;
        let mut z0 = d.dot(z);
        if z0 > 0.0 {
            z = -z;
            z0 = -z0;
        }
        if z0 == 0.0 {
            return None;
        }
        let (x0, y0) = (d.dot(x), d.dot(y));
        let (x1, y1) = (x0 + exl, y0 + eyl);
        let v00 = DVec3::new(x0, y0, z0);
        let v01 = DVec3::new(x0, y1, z0);
        let v10 = DVec3::new(x1, y0, z0);
        let v11 = DVec3::new(x1, y1, z0);
        let n0 = v00.cross(v10).normalize();
        let n1 = v10.cross(v11).normalize();
        let n2 = v11.cross(v01).normalize();
        let n3 = v01.cross(v00).normalize();
        let g0 = angle_between(-n0, n1);
        let g1 = angle_between(-n1, n2);
        let g2 = angle_between(-n2, n3);
        let g3 = angle_between(-n3, n0);
        let k = 2.0 * std::f64::consts::PI - g2 - g3;
        let solid_angle = g0 + g1 - k;
        (solid_angle.is_finite() && solid_angle > 0.0).then_some(SphRect {
            x,
            y,
            z,
            x0,
            x1,
            y0,
            y1,
            z0,
            b0: n0.z,
            b1: n2.z,
            k,
            g0g1: g0 + g1,
            solid_angle,
        })
    }

    /// A direction (unit) uniformly distributed over the spherical rectangle, and the distance
    /// to the rectangle along it.
    #[inline]
    fn sample(&self, u: [f64; 2]) -> (DVec3, f64) {
        let au = u[0] * (self.g0g1 - 2.0 * std::f64::consts::PI)
            + (u[0] - 1.0) * (2.0 * std::f64::consts::PI - self.k);
        let fu = (au.cos() * self.b0 - self.b1) / au.sin();
        let mut cu = (1.0 / (fu * fu + self.b0 * self.b0).sqrt()).copysign(fu);
        cu = cu.clamp(-1.0 + 1e-16, 1.0 - 1e-16);
        let z0 = self.z0;
        let xu = (-(cu * z0) / (1.0 - cu * cu).max(0.0).sqrt()).clamp(self.x0, self.x1);
        let dd = (xu * xu + z0 * z0).sqrt();
        let h0 = self.y0 / (dd * dd + self.y0 * self.y0).sqrt();
        let h1 = self.y1 / (dd * dd + self.y1 * self.y1).sqrt();
        let hv = h0 + u[1] * (h1 - h0);
        let hv2 = hv * hv;
        let yv = if hv2 < 1.0 - 1e-12 {
            (hv * dd) / (1.0 - hv2).sqrt()
        } else {
            self.y1
        };
        let local = self.x * xu + self.y * yv + self.z * z0;
        let dist = local.length();
        (local / dist, dist)
    }
}

/// The spherical-rectangle view of a rect light from `p`, when its solid angle is in the range
/// where it is sampled that way.
fn spherical(p: DVec3, center: DVec3, ex: DVec3, ey: DVec3) -> Option<SphRect> {
    SphRect::new(p, center, ex, ey)
        .filter(|r| (SPHERICAL_MIN_SR..=SPHERICAL_MAX_SR).contains(&r.solid_angle))
}

impl Light {
    /// Intersects a camera or BSDF ray with the emitter's shape: (t, radiance) for the
    /// emitting side, or `None` (delta lights are never hit).
    pub fn hit(&self, o: DVec3, d: DVec3, tmax: f64, lambda_nm: f64) -> Option<(f64, f64)> {
        match self {
            Light::Rect {
                center,
                ex,
                ey,
                normal,
                spectrum,
                ..
            } => {
                let denom = d.dot(*normal);
                if denom >= 0.0 {
                    return None; // from behind: transparent
                }
                let t = (*center - o).dot(*normal) / denom;
                if !(t > 0.0 && t < tmax) {
                    return None;
                }
                let p = o + d * t - *center;
                let (a, b) = (
                    p.dot(*ex) / ex.length_squared(),
                    p.dot(*ey) / ey.length_squared(),
                );
                (a.abs() <= 1.0 && b.abs() <= 1.0).then(|| (t, spectrum.eval(lambda_nm)))
            }
            Light::Sphere {
                center,
                radius,
                spectrum,
            } => ray_sphere(o, d, *center, *radius, 0.0)
                .filter(|t| *t < tmax)
                .map(|t| (t, spectrum.eval(lambda_nm))),
            Light::Point { .. } => None,
        }
    }

    /// Solid-angle density with which [`Light::sample`] from `p` would produce direction `wi`
    /// hitting this light at distance `t` (0 for delta lights).
    pub fn pdf(&self, p: DVec3, wi: DVec3, t: f64) -> f64 {
        match self {
            Light::Rect {
                center,
                ex,
                ey,
                normal,
                area,
                ..
            } => {
                let cos_l = (-wi.dot(*normal)).max(0.0);
                if cos_l <= 0.0 {
                    0.0
                } else if let Some(r) = spherical(p, *center, *ex, *ey) {
                    1.0 / r.solid_angle
                } else {
                    t * t / (cos_l * area)
                }
            }
            Light::Sphere { center, radius, .. } => {
                let d2 = (*center - p).length_squared();
                let r2 = radius * radius;
                if d2 <= r2 {
                    sphere_area_pdf(p, wi, t, *center, *radius)
                } else {
                    1.0 / (2.0 * std::f64::consts::PI * sphere_cone_one_minus_cos(r2, d2))
                }
            }
            Light::Point { .. } => 0.0,
        }
    }

    /// Samples a direction from shading point `p` toward the light.
    #[inline]
    pub fn sample(&self, p: DVec3, u: [f64; 2], lambda_nm: f64) -> Option<LightSample> {
        match self {
            Light::Rect {
                center,
                ex,
                ey,
                normal,
                area,
                spectrum,
            } => {
                if (p - *center).dot(*normal) <= 0.0 {
                    return None; // behind the emitting side
                }
                if let Some(r) = spherical(p, *center, *ex, *ey) {
                    let (wi, dist) = r.sample(u);
                    return (-wi.dot(*normal) > 0.0).then(|| LightSample {
                        wi,
                        dist,
                        li: spectrum.eval(lambda_nm),
                        pdf: 1.0 / r.solid_angle,
                        delta: false,
                    });
                }
                let q = *center + *ex * (2.0 * u[0] - 1.0) + *ey * (2.0 * u[1] - 1.0);
                let v = q - p;
                let dist = v.length();
                if dist <= 0.0 {
                    return None;
                }
                let wi = v / dist;
                let cos_l = -wi.dot(*normal);
                if cos_l <= 0.0 {
                    return None;
                }
                Some(LightSample {
                    wi,
                    dist,
                    li: spectrum.eval(lambda_nm),
                    pdf: dist * dist / (cos_l * area),
                    delta: false,
                })
            }
            Light::Sphere {
                center,
                radius,
                spectrum,
            } => {
                let to_c = *center - p;
                let d2 = to_c.length_squared();
                let r2 = radius * radius;
                let li = spectrum.eval(lambda_nm);
                if d2 <= r2 {
                    // Inside: uniform over the sphere's area.
                    let z = 1.0 - 2.0 * u[0];
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    let phi = 2.0 * std::f64::consts::PI * u[1];
                    let n = DVec3::new(r * phi.cos(), r * phi.sin(), z);
                    let q = *center + n * *radius;
                    let v = q - p;
                    let dist = v.length();
                    let wi = v / dist;
                    return Some(LightSample {
                        wi,
                        dist,
                        li,
                        pdf: sphere_area_pdf(p, wi, dist, *center, *radius),
                        delta: false,
                    });
                }
                let dc = d2.sqrt();
                let w = to_c / dc;
                let one_minus = sphere_cone_one_minus_cos(r2, d2);
                let cos_t = 1.0 - u[0] * one_minus;
                let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
                let phi = 2.0 * std::f64::consts::PI * u[1];
                let local = DVec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t);
                let wi = Frame::from_normal(w).to_world(local).normalize();
                let dist = ray_sphere(p, wi, *center, *radius, 0.0).unwrap_or(dc - radius);
                Some(LightSample {
                    wi,
                    dist,
                    li,
                    pdf: 1.0 / (2.0 * std::f64::consts::PI * one_minus),
                    delta: false,
                })
            }
            Light::Point {
                position,
                spot,
                spectrum,
            } => {
                let v = *position - p;
                let d2 = v.length_squared();
                if d2 <= 0.0 {
                    return None;
                }
                let dist = d2.sqrt();
                let wi = v / dist;
                let mut li = spectrum.eval(lambda_nm) / d2;
                if let Some((axis, cos_cone, cos_fall)) = spot {
                    let c = (-wi).dot(*axis);
                    li *= smoothstep(*cos_cone, *cos_fall, c);
                }
                (li > 0.0).then_some(LightSample {
                    wi,
                    dist,
                    li,
                    pdf: 1.0,
                    delta: true,
                })
            }
        }
    }
}

/// pbrt-v4's `SmoothStep(a, b, x)`: 0 below a, 1 above b, cubic in between.
fn smoothstep(a: f64, b: f64, x: f64) -> f64 {
    if a == b {
        return if x < a { 0.0 } else { 1.0 };
    }
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Solid-angle density of uniform area sampling of a sphere of radius `r` about `c`, for the
/// point `p + wi·t` seen from `p` (used when `p` is inside the sphere).
fn sphere_area_pdf(p: DVec3, wi: DVec3, t: f64, c: DVec3, r: f64) -> f64 {
    let cos_l = ((p + wi * t) - c).normalize().dot(-wi).abs().max(1e-12);
    t * t / (cos_l * 4.0 * std::f64::consts::PI * r * r)
}

/// 1 − cos θmax of the cone a sphere subtends from outside, with sin²θmax = r²/d²; for tiny
/// spheres the series sin²/2 + sin⁴/8 avoids the cancellation.
fn sphere_cone_one_minus_cos(r2: f64, d2: f64) -> f64 {
    let sin2 = r2 / d2;
    if sin2 < 1e-4 {
        0.5 * sin2 + 0.125 * sin2 * sin2
    } else {
        1.0 - (1.0 - sin2).max(0.0).sqrt()
    }
}

/// Builds the rect light's half-extent vectors: width along the direction perpendicular to
/// `normal` closest to +x, height along normal × that.
pub fn rect_axes(normal: DVec3, size_mm: [f64; 2]) -> (DVec3, DVec3) {
    let n = normal.normalize();
    let mut x = DVec3::X - n * n.x;
    if x.length_squared() < 1e-12 {
        x = DVec3::Y - n * n.y;
    }
    let x = x.normalize();
    let y = n.cross(x);
    (x * (0.5 * size_mm[0]), y * (0.5 * size_mm[1]))
}

/// Sampling support for the display as an emitter of the 3-D scene.
#[derive(Clone, Debug)]
pub struct DisplayLight {
    /// CDF over target pixels (radiance summed over primaries × area), normalised to end at 1.
    cdf: Vec<f64>,
    /// Σ radiance (relative) over target pixels.
    total: f64,
    lcd_area: f64,
    pixel_area: f64,
}

/// Fraction of display samples drawn uniformly over the LCD (the rest follow the target).
const DISPLAY_UNIFORM: f64 = 0.5;

impl DisplayLight {
    /// Tabulates the display's target for sampling.
    pub fn new(d: &Display) -> DisplayLight {
        let mut acc = 0.0;
        let cdf: Vec<f64> = (0..d.width_px * d.height_px)
            .map(|k| {
                acc += d.pixel_radiance(k);
                acc
            })
            .collect();
        let total = acc;
        DisplayLight {
            cdf: if total > 0.0 {
                cdf.iter().map(|c| c / total).collect()
            } else {
                cdf
            },
            total,
            lcd_area: 4.0 * d.half_extent_mm.x * d.half_extent_mm.y,
            pixel_area: d.image_pixel_mm * d.image_pixel_mm,
        }
    }

    fn uniform_share(&self) -> f64 {
        if self.total > 0.0 {
            DISPLAY_UNIFORM
        } else {
            1.0
        }
    }

    /// Area density (1/mm²) of a point `q` on the display plane.
    pub fn pdf_area(&self, d: &Display, q: DVec2) -> f64 {
        let fu = self.uniform_share();
        let rel = q - d.center_mm;
        let mut p = 0.0;
        if rel.x.abs() <= d.half_extent_mm.x && rel.y.abs() <= d.half_extent_mm.y {
            p += fu / self.lcd_area;
        }
        if fu < 1.0
            && let Some((c, r)) = d.pixel_at(q)
        {
            p += (1.0 - fu) * d.pixel_radiance(r * d.width_px + c) / (self.total * self.pixel_area);
        }
        p
    }

    /// Samples a point on the display plane: (point, area density).
    pub fn sample_point(&self, d: &Display, u: [f64; 3]) -> DVec2 {
        let fu = self.uniform_share();
        if u[0] < fu {
            d.center_mm
                + DVec2::new(
                    (2.0 * u[1] - 1.0) * d.half_extent_mm.x,
                    (2.0 * u[2] - 1.0) * d.half_extent_mm.y,
                )
        } else {
            let v = (u[0] - fu) / (1.0 - fu);
            let k = self
                .cdf
                .partition_point(|c| *c <= v)
                .min(self.cdf.len() - 1);
            let (c, r) = (k % d.width_px, k / d.width_px);
            let x0 = d.center_mm.x + (c as f64 - 0.5 * d.width_px as f64) * d.image_pixel_mm;
            let y0 = d.center_mm.y + (0.5 * d.height_px as f64 - r as f64) * d.image_pixel_mm;
            DVec2::new(x0 + u[1] * d.image_pixel_mm, y0 - u[2] * d.image_pixel_mm)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_intersection_and_cone_pdf_integrate() {
        // Ray from outside hits the near side.
        let t = ray_sphere(DVec3::new(0.0, 0.0, 10.0), -DVec3::Z, DVec3::ZERO, 1.0, 0.0).unwrap();
        assert!((t - 9.0).abs() < 1e-12);
        // The cone density integrates to 1 over the subtended cone: p·Ω = 1.
        let l = Light::Sphere {
            center: DVec3::new(0.0, 0.0, -100.0),
            radius: 5.0,
            spectrum: Spectrum::on_grid(|_| 1.0),
        };
        let pdf = l.pdf(DVec3::ZERO, -DVec3::Z, 95.0);
        let omega = 2.0 * std::f64::consts::PI * (1.0 - (1.0 - 25.0 / 10000.0f64).sqrt());
        assert!((pdf * omega - 1.0).abs() < 1e-9);
        // Every sampled direction hits the sphere.
        for i in 0..100 {
            let s = l
                .sample(DVec3::ZERO, [(i as f64 + 0.5) / 100.0, 0.37], 550.0)
                .unwrap();
            assert!(
                ray_sphere(
                    DVec3::ZERO,
                    s.wi,
                    DVec3::new(0.0, 0.0, -100.0),
                    5.0 + 1e-9,
                    0.0
                )
                .is_some()
            );
            assert!((s.pdf - pdf).abs() < 1e-9 * pdf);
        }
    }

    /// Spherical-rectangle sampling: every direction hits the rect, the solid angle equals
    /// the closed form for a square seen on axis (4·asin(a²/(a²+d²)) for half side a at
    /// distance d), and the mean of 1/pdf·f over samples integrates cos θ over the rect to the
    /// area-sampling estimate (independent strategies agree within 3σ).
    #[test]
    fn spherical_rectangle_sampling() {
        let c = DVec3::new(0.0, 0.0, -60.0);
        let (ex, ey) = rect_axes(DVec3::Z, [518.0, 324.0]);
        let p = DVec3::ZERO - DVec3::new(0.0, 0.0, 0.0);
        let light = Light::Rect {
            center: c,
            ex,
            ey,
            normal: DVec3::Z,
            area: 518.0 * 324.0,
            spectrum: Spectrum::on_grid(|_| 1.0),
        };
        let q = DVec3::new(10.0, -20.0, -120.0);
        let r = SphRect::new(q, c, ex, ey).unwrap();
        // Square on axis: closed form.
        let (sx, sy) = rect_axes(DVec3::Z, [20.0, 20.0]);
        let sq = SphRect::new(DVec3::new(0.0, 0.0, 30.0), DVec3::ZERO, sx, sy).unwrap();
        let exact = 4.0 * (100.0f64 / (100.0 + 900.0)).asin();
        assert!(
            (sq.solid_angle - exact).abs() < 1e-12,
            "{} vs {exact}",
            sq.solid_angle
        );
        // Irradiance from the big rect at q (cosine about +z... q is below the rect: the rect
        // at z = -60 faces +z and q at z = -120 is behind it): no sample.
        assert!(light.sample(q, [0.3, 0.6], 550.0).is_none());
        let _ = p;
        // From in front (z = -30): ∫cos θ dω by both strategies.
        let q = DVec3::new(40.0, -25.0, -30.0);
        let r2 = SphRect::new(q, c, ex, ey).unwrap();
        let n = 200_000;
        let mut sph = Vec::with_capacity(n);
        let mut area = Vec::with_capacity(n);
        for i in 0..n {
            let u = [
                crate::sampler::to_unit(crate::sampler::hash(&[1, i as u64])),
                crate::sampler::to_unit(crate::sampler::hash(&[2, i as u64])),
            ];
            let (wi, dist) = r2.sample(u);
            let hitp = q + wi * dist;
            assert!(
                (hitp.z - c.z).abs() < 1e-6
                    && (hitp.x - c.x).abs() <= 259.0 + 1e-6
                    && (hitp.y - c.y).abs() <= 162.0 + 1e-6,
                "{hitp}"
            );
            sph.push((-wi.z).max(0.0) * r2.solid_angle);
            let pt = c + ex * (2.0 * u[0] - 1.0) + ey * (2.0 * u[1] - 1.0);
            let v = pt - q;
            let d2 = v.length_squared();
            let w = v / d2.sqrt();
            area.push((-w.z).max(0.0) * (-w.z).max(0.0) * (518.0 * 324.0) / d2);
        }
        let stats = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64;
            (m, (var / v.len() as f64).sqrt())
        };
        let (ms, ss) = stats(&sph);
        let (ma, sa) = stats(&area);
        assert!(
            (ms - ma).abs() < 3.0 * (ss * ss + sa * sa).sqrt(),
            "{ms}±{ss} vs {ma}±{sa}"
        );
        // The spherical estimate is far less noisy.
        assert!(ss < 0.5 * sa, "{ss} vs {sa}");
        assert!(r.solid_angle > 0.0);
    }

    #[test]
    fn rect_axes_are_orthogonal_and_sized() {
        let (x, y) = rect_axes(DVec3::new(0.0, -1.0, 0.0), [400.0, 200.0]);
        assert!((x.length() - 200.0).abs() < 1e-12 && (y.length() - 100.0).abs() < 1e-12);
        assert!(x.dot(y).abs() < 1e-9 && x.y.abs() < 1e-12 && y.y.abs() < 1e-12);
    }
}
