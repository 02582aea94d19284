//! Colour bands of a design: which display primary each field of the capture can see.
//!
//! Model: a camera pixel's chief ray meets grating j of the film at one Bragg wavelength
//! λ_B,j (closed form, `optics::grating`, docs/physics.md §3.2), and the replicas of that
//! grating carry light in a narrow band around it (a few nm to ~15 nm, Kogelnik). The pixel
//! sees primary p of the display through grating j in proportion to P_p(λ_B,j); this module
//! reports, per field row of the crop, each grating's λ_B and each primary's level
//! P_p(λ_B,j)/max_λ P_p at its best grating. A field **has a band in primary p** when that
//! level is at least [`BAND_LEVEL`]: some grating passes light within the primary's
//! half-maximum width. The band's finite width and the sensor's response are left out (they
//! change the level by a smooth factor, not which primary a band falls in).

use serde::Serialize;

use crate::spectra::Spectrum;
use crate::system::System;

/// Level (of the primary's peak) from which a grating's Bragg wavelength counts as a band
/// of that primary: its half maximum.
pub const BAND_LEVEL: f64 = 0.5;

/// One field row of the crop.
#[derive(Clone, Debug, Serialize)]
pub struct FieldBands {
    /// Crop row of the chief ray (0 = top).
    pub crop_row: usize,
    /// Vertical field angle of the chief ray in air, degrees (+ = up).
    pub field_deg: f64,
    /// Each grating's Bragg wavelength for the chief ray (None: no Bragg match).
    pub bragg_nm: Vec<Option<f64>>,
    /// Per primary [R, G, B]: the best grating's level P_p(λ_B)/max P_p.
    pub level: [f64; 3],
    /// Per primary: the grating giving that level (None: no grating has a Bragg match).
    pub grating: [Option<usize>; 3],
}

impl FieldBands {
    /// Whether primary `p` has a band in this field (level ≥ [`BAND_LEVEL`]).
    pub fn has_band(&self, p: usize) -> bool {
        self.level[p] >= BAND_LEVEL
    }
}

/// The display primaries of `sys`, or those of the LCD model on its backlight when the
/// display is monochrome (so a monochrome design can be asked which colours it would pass).
pub fn primaries_of(sys: &System) -> [Spectrum; 3] {
    match &sys.display.primaries {
        Some(p) => (**p).clone(),
        None => crate::spectra::display_primaries(&sys.display.spectrum).0,
    }
}

/// The colour bands of `rows` field rows spread evenly over the crop (centre column), top to
/// bottom.
pub fn field_bands(sys: &System, rows: usize) -> Vec<FieldBands> {
    let prim = primaries_of(sys);
    let peak: [f64; 3] = std::array::from_fn(|p| prim[p].max_value());
    let cam = &sys.camera;
    let gratings = &sys.waveguide.gratings;
    let (w, h) = (cam.width_px, cam.height_px);
    (0..rows.max(1))
        .map(|i| {
            let row = if rows <= 1 {
                h / 2
            } else {
                (i * (h.max(1) - 1)) / (rows - 1)
            };
            let ray = cam.chief_ray(w / 2, row);
            let field_deg = ray.dir.y.atan2(-ray.dir.z).to_degrees();
            let bragg_nm: Vec<Option<f64>> = (0..gratings.len())
                .map(|j| gratings.get(j).bragg_wavelength_nm(-ray.dir.truncate()))
                .collect();
            let mut level = [0.0; 3];
            let mut best = [None; 3];
            for (j, lb) in bragg_nm.iter().enumerate() {
                let Some(lb) = lb else { continue };
                for p in 0..3 {
                    let v = if peak[p] > 0.0 {
                        prim[p].eval(*lb) / peak[p]
                    } else {
                        0.0
                    };
                    if best[p].is_none() || v > level[p] {
                        level[p] = v;
                        best[p] = Some(j);
                    }
                }
            }
            FieldBands {
                crop_row: row,
                field_deg,
                bragg_nm,
                level,
                grating: best,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sys(extra: &[&str], file: Option<&str>) -> System {
        let ov: Vec<String> = extra.iter().map(|s| s.to_string()).collect();
        let path = file.map(|f| stscam_base::repo_dir().join(f));
        System::build(&crate::scene::load_scene(path.as_deref(), &ov).unwrap()).unwrap()
    }

    #[test]
    fn bragg_wavelengths_scale_with_the_recording_and_bands_follow_the_primaries() {
        let rgb = sys(&[], Some("scenes/rgb-multiplex.toml"));
        let bands = field_bands(&rgb, 9);
        for b in &bands {
            // Same beam geometry: λ_B,j / λ_j is the same for every grating (to the film's
            // closed form's rounding).
            let r: Vec<f64> = (b.bragg_nm.iter().zip([460.0, 532.0, 630.0]))
                .map(|(l, l0)| l.unwrap() / l0)
                .collect();
            assert!(
                (r[0] - r[1]).abs() < 1e-9 && (r[2] - r[1]).abs() < 1e-9,
                "{r:?}"
            );
            // A grating whose Bragg wavelength lies within 8 nm of a primary's peak is inside
            // that primary's half-maximum band (every primary is at least 16 nm wide at half
            // maximum: the narrowest, blue, is the 20 nm FWHM pump).
            for p in 0..3 {
                let peak_nm = argmax(&primaries_of(&rgb)[p]);
                if b.bragg_nm
                    .iter()
                    .any(|l| (l.unwrap() - peak_nm).abs() <= 8.0)
                {
                    assert!(b.has_band(p), "{p} {b:?}");
                }
            }
        }
        // The centre row sees all three primaries' bands through their own gratings.
        let centre = &field_bands(&rgb, 1)[0];
        assert_eq!(centre.grating, [Some(2), Some(1), Some(0)]);
        assert!((0..3).all(|p| centre.has_band(p)), "{centre:?}");
        // The paper's single grating: λ_B stays below 590 nm (the red filter's 50 % edge,
        // where the red primary is under half its peak) over the crop, so no field passes red.
        let paper = sys(&["display.primaries=lcd"], None);
        for b in field_bands(&paper, 9) {
            assert!(b.bragg_nm[0].unwrap() < 590.0);
            assert!(!b.has_band(0), "{b:?}");
        }
        // It can fail: the same check on the RGB design finds red bands.
        assert!(bands.iter().any(|b| b.has_band(0)));
    }

    fn argmax(s: &Spectrum) -> f64 {
        (380..=780).map(f64::from).fold(
            380.0,
            |best, l| if s.eval(l) > s.eval(best) { l } else { best },
        )
    }
}
