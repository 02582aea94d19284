//! Thin-lens camera and sensor geometry (pixel area, crop, aperture, focus).
//!
//! Model (`docs/physics.md` §6.2; the standard physically based thin-lens camera of
//! pbrt): lens of focal length f at distance d1 behind the back face, optical axis along −z
//! through the centre of the top vHOE; sensor at d0 = f·s_o/(s_o − f) behind the lens for a
//! focus distance s_o (1/f = 1/d0 + 1/s_o). A sample picks a point on the pixel and a point on
//! the aperture disc (radius f/(2N)) and aims at the in-focus conjugate point. Each sample
//! carries the cos⁴θ irradiance factor (θ between the sensor→lens ray and the axis), so that
//! an on-axis pixel looking at a uniform radiance L reads L.
//!
//! Image convention (docs/design.md): row 0 is the top (+y), column 0 the left (−x) as seen from
//! the camera looking at the user. The lens inverts the image on the sensor; pixel coordinates
//! refer to the upright image.
//!
//! Assumptions: ideal aberration-free thin lens, no vignetting other than cos⁴ and the
//! aperture, 100 % fill factor (the pixel's whole area is sensitive).

use glam::{DVec2, DVec3};

/// A camera ray leaving the lens toward the screen.
#[derive(Clone, Copy, Debug)]
pub struct CameraRay {
    /// Point on the lens (world mm).
    pub origin: DVec3,
    /// Unit direction toward the screen (z < 0).
    pub dir: DVec3,
    /// Irradiance weight cos⁴θ.
    pub cos4: f64,
}

/// The runtime camera built from the scene.
#[derive(Clone, Debug)]
pub struct Camera {
    /// Lens centre in world mm.
    pub lens_center_mm: DVec3,
    /// Focal length, mm.
    pub focal_length_mm: f64,
    /// Lens-to-sensor distance d0, mm.
    pub sensor_distance_mm: f64,
    /// Focus distance s_o, mm.
    pub focus_distance_mm: f64,
    /// Aperture radius, mm.
    pub aperture_radius_mm: f64,
    /// Pixel pitch, mm.
    pub pitch_mm: f64,
    /// Crop width in pixels.
    pub width_px: usize,
    /// Crop height in pixels.
    pub height_px: usize,
    /// Crop centre offset from the optical axis in pixels (+x right, +y up).
    pub offset_px: DVec2,
}

/// Concentric (Shirley–Chiu) map of the unit square to the unit disc.
#[inline]
pub fn concentric_disk(u: [f64; 2]) -> DVec2 {
    let a = 2.0 * u[0] - 1.0;
    let b = 2.0 * u[1] - 1.0;
    if a == 0.0 && b == 0.0 {
        return DVec2::ZERO;
    }
    let (r, phi) = if a.abs() > b.abs() {
        (a, std::f64::consts::FRAC_PI_4 * (b / a))
    } else {
        (
            b,
            std::f64::consts::FRAC_PI_2 - std::f64::consts::FRAC_PI_4 * (a / b),
        )
    };
    DVec2::new(r * phi.cos(), r * phi.sin())
}

impl Camera {
    /// Position (mm) of a point in pixel (col, row) with in-pixel offsets `f` ∈ [0,1)², in the
    /// upright image plane centred on the optical axis (+x right, +y up).
    #[inline]
    pub fn image_point_mm(&self, col: usize, row: usize, f: [f64; 2]) -> DVec2 {
        let x = col as f64 + f[0] - 0.5 * self.width_px as f64 + self.offset_px.x;
        let y = 0.5 * self.height_px as f64 - (row as f64 + f[1]) + self.offset_px.y;
        DVec2::new(x, y) * self.pitch_mm
    }

    /// Ray for a pixel sample `pixel_u` ∈ [0,1)² and aperture sample `lens_u` ∈ [0,1)².
    #[inline]
    pub fn generate_ray(
        &self,
        col: usize,
        row: usize,
        pixel_u: [f64; 2],
        lens_u: [f64; 2],
    ) -> CameraRay {
        let img = self.image_point_mm(col, row, pixel_u);
        let lens = concentric_disk(lens_u) * self.aperture_radius_mm;
        self.ray_through(img, lens)
    }

    /// The chief ray of a pixel: pixel centre through the lens centre.
    pub fn chief_ray(&self, col: usize, row: usize) -> CameraRay {
        self.ray_through(self.image_point_mm(col, row, [0.5, 0.5]), DVec2::ZERO)
    }

    /// Ray from the sensor point conjugate to image point `img` through lens point `lens`.
    #[inline]
    pub fn ray_through(&self, img: DVec2, lens: DVec2) -> CameraRay {
        let d0 = self.sensor_distance_mm;
        // In-focus point: along the chief ray (img, −d0) scaled to the focus distance.
        let focus = (img * (self.focus_distance_mm / d0)).extend(-self.focus_distance_mm);
        let start = lens.extend(0.0);
        let dir = (focus - start).normalize();
        // The physical sensor point is the inverted image point, d0 behind the lens.
        let to_lens = (lens + img).extend(-d0);
        let cos = d0 / to_lens.length();
        CameraRay {
            origin: self.lens_center_mm + start,
            dir,
            cos4: cos * cos * cos * cos,
        }
    }

    /// Half field of view of the crop (radians) vertically and horizontally, from the lens
    /// centre: (atan(h/2·p/d0), atan(w/2·p/d0)).
    pub fn half_fov_rad(&self) -> (f64, f64) {
        let d0 = self.sensor_distance_mm;
        (
            (0.5 * self.height_px as f64 * self.pitch_mm / d0).atan(),
            (0.5 * self.width_px as f64 * self.pitch_mm / d0).atan(),
        )
    }
}

/// Lens-to-sensor distance for a thin lens focused at `focus_mm`: d0 = f·s/(s − f).
pub fn sensor_distance_mm(focal_mm: f64, focus_mm: f64) -> f64 {
    focal_mm * focus_mm / (focus_mm - focal_mm)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        let f = 6.0;
        let s = 600.0;
        Camera {
            lens_center_mm: DVec3::new(0.0, 40.0, 34.0),
            focal_length_mm: f,
            sensor_distance_mm: sensor_distance_mm(f, s),
            focus_distance_mm: s,
            aperture_radius_mm: 0.75,
            pitch_mm: 0.0048,
            width_px: 440,
            height_px: 440,
            offset_px: DVec2::ZERO,
        }
    }

    #[test]
    fn rays_through_any_lens_point_meet_at_the_focus() {
        let c = cam();
        for &(col, row) in &[(0, 0), (439, 0), (220, 220), (17, 400)] {
            let chief = c.chief_ray(col, row);
            let focus = chief.origin + chief.dir * (c.focus_distance_mm / -chief.dir.z);
            for &lu in &[[0.1, 0.9], [0.5, 0.5], [0.99, 0.01]] {
                let r = c.generate_ray(col, row, [0.5, 0.5], lu);
                let p = r.origin + r.dir * ((r.origin.z - focus.z) / -r.dir.z);
                assert!((p - focus).length() < 1e-9, "{p} vs {focus}");
            }
        }
    }

    #[test]
    fn orientation_top_row_looks_up_left_column_looks_left() {
        let c = cam();
        let top_left = c.chief_ray(0, 0);
        assert!(top_left.dir.y > 0.0 && top_left.dir.x < 0.0 && top_left.dir.z < 0.0);
        let centre = c.chief_ray(220, 220).dir;
        assert!(centre.x.abs() < 1e-3 && centre.y.abs() < 1e-3);
        // Crop 440 px at 4.8 µm with f = 6 mm: half FOV ≈ 9.9°.
        let (v, h) = c.half_fov_rad();
        assert!((v.to_degrees() - 9.90).abs() < 0.05 && (h - v).abs() < 1e-15);
    }

    #[test]
    fn concentric_disk_is_area_preserving() {
        // Uniform grid on the square → fraction of points inside radius 0.5 should be 0.25.
        let n = 400;
        let mut inside = 0;
        for i in 0..n {
            for j in 0..n {
                let p = concentric_disk([(i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64]);
                assert!(p.length() <= 1.0 + 1e-12);
                if p.length() < 0.5 {
                    inside += 1;
                }
            }
        }
        let frac = inside as f64 / (n * n) as f64;
        assert!((frac - 0.25).abs() < 0.005, "{frac}");
    }
}
