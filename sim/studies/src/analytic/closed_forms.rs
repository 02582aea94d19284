//! The closed forms (module header of `analytic`, items 1 to 6): the plain design values of a
//! scene, the geometry of one field direction, what ends the field of view, and the
//! bisection of a field-of-view edge.

use glam::{DVec2, DVec3};
use serde::Serialize;

use crate::optics::glass::Glass;
use crate::scene::{AutoOr, Scene};
use crate::system::glass_of;

/// The plain design values the closed forms need (read from a scene description, never from
/// the runtime objects built from it). Fields may be changed to test the comparison.
#[derive(Clone, Debug, Serialize)]
pub struct ClosedForm {
    /// Recording wavelength λ0, nm (of the film as fabricated, [`recording_of`]).
    pub lambda0_nm: f64,
    /// The design's recording wavelength, nm: where the plate's index is taken when no
    /// wavelength is Bragg-matched (as the tracer takes it: the scene's primary wavelength).
    pub design_lambda_nm: f64,
    /// Reference angle θ_R inside the film, degrees.
    pub reference_angle_deg: f64,
    /// Film index n_f.
    pub n_film: f64,
    /// Plate thickness w, mm.
    pub thickness_mm: f64,
    /// Glass dispersion model.
    #[serde(skip)]
    pub glass: Glass,
    /// Bottom vHOE width and height, mm (centred at the origin of the back face).
    pub bottom_size_mm: [f64; 2],
    /// Top vHOE width and height, mm.
    pub top_size_mm: [f64; 2],
    /// Gap between the bottom vHOE's top edge and the top vHOE's bottom edge, mm.
    pub gap_mm: f64,
    /// Whether the top vHOE is covered (replicas entering under it are absorbed).
    pub covered: bool,
    /// Lens to back face d1, mm.
    pub camera_distance_mm: f64,
    /// Lens-to-sensor distance d0, mm (thin lens focused at the scene's focus distance).
    pub sensor_distance_mm: f64,
    /// Pixel pitch, mm.
    pub pixel_mm: f64,
    /// Crop size (width, height), pixels.
    pub crop_px: [usize; 2],
    /// Crop centre offset from the optical axis, pixels (+x right, +y up).
    pub crop_offset_px: [f64; 2],
    /// Display distance D from the front face, mm.
    pub display_distance_mm: f64,
    /// Sampled spectral band [λ_min, λ_max), nm.
    pub band_nm: [f64; 2],
}

/// What ends the field of view at an edge (labels as in `analysis::info`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Limit {
    /// The sensor crop.
    SensorCrop,
    /// The chief ray misses the top vHOE.
    TopAperture,
    /// λ_B is outside the sampled band.
    BraggBand,
    /// The guided wave is not trapped by TIR.
    Tir,
    /// No back-face contact inside the bottom vHOE.
    NoContact,
}

impl Limit {
    /// The label `analysis::info` uses for the same limit.
    pub fn label(self) -> &'static str {
        match self {
            Limit::SensorCrop => "sensor crop",
            Limit::TopAperture => "top vHOE aperture",
            Limit::BraggBand => "Bragg band outside the simulated spectrum",
            Limit::Tir => "TIR (guided angle below critical)",
            Limit::NoContact => "bottom vHOE (no contact)",
        }
    }
}

/// The closed-form geometry of one field direction.
#[derive(Clone, Debug, Serialize)]
pub struct FieldGeometry {
    /// Field angles in air [horizontal, vertical], degrees.
    pub field_deg: [f64; 2],
    /// Camera chief-ray direction (toward the screen).
    pub camera_dir: [f64; 3],
    /// Tangential direction cosines of the physical light in air.
    pub u_air: [f64; 2],
    /// Bragg wavelength λ_B, nm (NaN if none).
    pub lambda_bragg_nm: f64,
    /// Glass index at λ_B.
    pub n_glass: f64,
    /// Tangential direction cosines of the guided wave (physical direction, travelling up).
    pub u_guided: [f64; 2],
    /// Guided angle Θ' in the glass, degrees.
    pub guided_angle_deg: f64,
    /// Replica pitch 2w·tanΘ', mm.
    pub replica_pitch_mm: f64,
    /// Object-space shift from replica k to replica k + 1 (−p), mm.
    pub replica_step_mm: [f64; 2],
    /// Back-face crossing of the chief ray, mm.
    pub back_point_mm: [f64; 2],
    /// Front-face (top vHOE) point of the chief ray, mm.
    pub front_point_mm: [f64; 2],
    /// Plate-contact numbers (odd, back face) inside the bottom vHOE, in order.
    pub contacts: Vec<u32>,
    /// Display points of those replicas, mm.
    pub object_points_mm: Vec<[f64; 2]>,
}

fn rect_contains(min: DVec2, max: DVec2, p: DVec2) -> bool {
    p.x >= min.x && p.y >= min.y && p.x < max.x && p.y < max.y
}

/// Odd integers j = 2m + 1 ≥ 1 with a < j ≤ b, as the inclusive range of m (empty: `None`).
fn odd_in(a: f64, b: f64) -> Option<(u32, u32)> {
    let m_lo = (((a - 1.0) / 2.0).floor() + 1.0).max(0.0);
    let m_hi = ((b - 1.0) / 2.0).floor();
    (m_hi >= m_lo).then(|| (m_lo as u32, m_hi.min(1e6) as u32))
}

/// The recording the closed forms take for the scene's first grating: its design (recording
/// wavelength, reference angle, mean index) or, when the scene's fabrication keys change the
/// film (`hoe.shrinkage`, …), the recording that gives the fabricated grating's vector in the
/// fabricated film (`optics::fabrication::equivalent_recording`), so the closed forms describe
/// the film the tracer traces.
pub fn recording_of(s: &Scene) -> (f64, f64, f64) {
    let d = &s.hoe.gratings()[0];
    let design = (
        d.recording_wavelength_nm,
        d.reference_angle_deg,
        s.hoe.mean_index,
    );
    let fab = s.hoe.fabricated_gratings()[0];
    let nominal = crate::optics::grating::VolumeGrating::from_recording_beams(
        d.recording_wavelength_nm,
        d.reference_angle_deg,
        d.object_angle_deg,
        s.hoe.mean_index,
        s.hoe.film_thickness_um,
        d.index_modulation,
        s.hoe.amplitude_absorption_per_mm,
    );
    if fab.k_rad_per_nm == nominal.k_rad_per_nm && fab.n_film == nominal.n_film {
        return design;
    }
    match crate::optics::fabrication::equivalent_recording(&fab) {
        Some((l, t)) => (l, t, fab.n_film),
        None => design,
    }
}

impl ClosedForm {
    /// Reads the plain design values of a scene description (the film as fabricated,
    /// [`recording_of`]).
    pub fn from_scene(s: &Scene) -> ClosedForm {
        let glass = glass_of(&s.plate.glass);
        let w = s.plate.thickness_mm;
        let f = s.camera.focal_length_mm;
        let focus = match s.camera.focus_distance_mm {
            AutoOr::Value(v) => v,
            AutoOr::Word(_) => {
                s.camera.distance_mm
                    + 2.0 * w / glass.index(s.hoe.primary_wavelength_nm())
                    + s.display.distance_mm
            }
        };
        let (cw, ch) = s.sensor.crop_px.size();
        let (lambda0_nm, reference_angle_deg, n_film) = recording_of(s);
        ClosedForm {
            lambda0_nm,
            design_lambda_nm: s.hoe.primary_wavelength_nm(),
            reference_angle_deg,
            n_film,
            thickness_mm: w,
            glass,
            bottom_size_mm: [s.bottom_hoe.width_mm, s.bottom_hoe.height_mm],
            top_size_mm: [s.top_hoe.width_mm, s.top_hoe.height_mm],
            gap_mm: s.top_hoe.gap_mm,
            covered: s.top_hoe.covered,
            camera_distance_mm: s.camera.distance_mm,
            sensor_distance_mm: f * focus / (focus - f),
            pixel_mm: s.sensor.pitch_um * 1e-3,
            crop_px: [cw as usize, ch as usize],
            crop_offset_px: [
                f64::from(s.sensor.crop_offset_px[0]),
                f64::from(s.sensor.crop_offset_px[1]),
            ],
            display_distance_mm: s.display.distance_mm,
            band_nm: [s.sampling.lambda_min_nm, s.sampling.lambda_max_nm],
        }
    }

    /// Glass index at a wavelength.
    pub fn n_glass(&self, lambda_nm: f64) -> f64 {
        self.glass.index(lambda_nm)
    }

    fn theta_r(&self) -> f64 {
        self.reference_angle_deg.to_radians()
    }

    /// Bottom vHOE rectangle (min, max) on the back face.
    pub fn bottom_rect_mm(&self) -> ([f64; 2], [f64; 2]) {
        let [bw, bh] = self.bottom_size_mm;
        ([-0.5 * bw, -0.5 * bh], [0.5 * bw, 0.5 * bh])
    }

    /// Top vHOE rectangle (min, max) on the front face.
    pub fn top_rect_mm(&self) -> ([f64; 2], [f64; 2]) {
        let y0 = 0.5 * self.bottom_size_mm[1] + self.gap_mm;
        let tw = self.top_size_mm[0];
        ([-0.5 * tw, y0], [0.5 * tw, y0 + self.top_size_mm[1]])
    }

    /// Lens centre (on the axis through the top vHOE centre, d1 behind the back face), mm.
    pub fn lens_mm(&self) -> [f64; 3] {
        let (lo, hi) = self.top_rect_mm();
        [
            0.5 * (lo[0] + hi[0]),
            0.5 * (lo[1] + hi[1]),
            self.thickness_mm + self.camera_distance_mm,
        ]
    }

    /// Closed-form Bragg wavelength (docs/physics.md §3.2) for light with air direction cosines
    /// `u`: λ0 (s_z − s_y tan(θ_R/2)) with ŝ inside the film; `None` if not positive.
    pub fn bragg_wavelength_nm(&self, u: [f64; 2]) -> Option<f64> {
        let nf = self.n_film;
        let cz2 = 1.0 - (u[0] * u[0] + u[1] * u[1]) / (nf * nf);
        if cz2 <= 0.0 {
            return None;
        }
        let lam = self.lambda0_nm * (cz2.sqrt() - (u[1] / nf) * (0.5 * self.theta_r()).tan());
        (lam > 0.0).then_some(lam)
    }

    /// Guided-wave direction cosines u_g = (u_x, u_y + n_f sin θ_R λ/λ0) (k_t − K_t).
    pub fn guided_u(&self, u: [f64; 2], lambda_nm: f64) -> [f64; 2] {
        [
            u[0],
            u[1] + self.n_film * self.theta_r().sin() * lambda_nm / self.lambda0_nm,
        ]
    }

    /// Camera chief-ray direction for field angles (h, v) in degrees.
    pub fn camera_dir(h_deg: f64, v_deg: f64) -> [f64; 3] {
        DVec3::new(h_deg.to_radians().tan(), v_deg.to_radians().tan(), -1.0)
            .normalize()
            .to_array()
    }

    /// Closed-form geometry of the field (h, v) in degrees.
    pub fn field(&self, h_deg: f64, v_deg: f64) -> FieldGeometry {
        self.field_dir(Self::camera_dir(h_deg, v_deg))
    }

    /// Closed-form geometry of the camera chief ray with direction `dir` (from the lens centre).
    pub fn field_dir(&self, dir: [f64; 3]) -> FieldGeometry {
        let d = DVec3::from_array(dir);
        let dt = d.truncate();
        let t = dt / -d.z;
        let u = -dt;
        let lam_opt = self.bragg_wavelength_nm(u.to_array());
        let lam = lam_opt.unwrap_or(f64::NAN);
        let n = self.n_glass(lam_opt.unwrap_or(self.design_lambda_nm));
        let w = self.thickness_mm;
        let lens = DVec3::from_array(self.lens_mm());
        let p_b = lens.truncate() + self.camera_distance_mm * t;
        let cross = dt * (w / (n * n - u.length_squared()).sqrt());
        let p_f = p_b + cross;
        let ug = DVec2::from_array(self.guided_u(u.to_array(), lam));
        let ug2 = ug.length_squared();
        let (guided_deg, g) = if ug2 < n * n {
            (
                (ug.length() / n).asin().to_degrees(),
                ug * (w / (n * n - ug2).sqrt()),
            )
        } else {
            (f64::NAN, DVec2::splat(f64::NAN))
        };
        let mut contacts = Vec::new();
        let mut objects = Vec::new();
        if lam_opt.is_some() && g.is_finite() {
            let (bmin, bmax) = self.bottom_rect_mm();
            let (bmin, bmax) = (DVec2::from_array(bmin), DVec2::from_array(bmax));
            // Interval of j per axis with min ≤ P_f − j g < max.
            let mut a = f64::NEG_INFINITY;
            let mut b = f64::INFINITY;
            for k in 0..2 {
                let (pf, gk, lo, hi) = (p_f[k], g[k], bmin[k], bmax[k]);
                if gk > 0.0 {
                    a = a.max((pf - hi) / gk);
                    b = b.min((pf - lo) / gk);
                } else if gk < 0.0 {
                    a = a.max((pf - lo) / gk);
                    b = b.min((pf - hi) / gk);
                } else if !(pf >= lo && pf < hi) {
                    b = f64::NEG_INFINITY;
                }
            }
            let (m_lo, m_end) = odd_in(a, b).map_or((0, 0), |(lo, hi)| (lo, hi + 1));
            for m in m_lo..m_end {
                let j = 2 * m + 1;
                let contact = p_f - f64::from(j) * g;
                // Guard the half-open edges exactly as the rectangle defines them.
                if !rect_contains(bmin, bmax, contact) {
                    continue;
                }
                let exit = contact + cross;
                contacts.push(j);
                objects.push((exit + self.display_distance_mm * t).to_array());
            }
        }
        FieldGeometry {
            field_deg: [d.x.atan2(-d.z).to_degrees(), d.y.atan2(-d.z).to_degrees()],
            camera_dir: dir,
            u_air: u.to_array(),
            lambda_bragg_nm: lam,
            n_glass: n,
            u_guided: ug.to_array(),
            guided_angle_deg: guided_deg,
            replica_pitch_mm: 2.0 * g.length(),
            replica_step_mm: (-2.0 * g).to_array(),
            back_point_mm: p_b.to_array(),
            front_point_mm: p_f.to_array(),
            contacts,
            object_points_mm: objects,
        }
    }

    /// Replicas available to the field (h, v): back-face contacts inside the bottom vHOE.
    pub fn replica_count(&self, h_deg: f64, v_deg: f64) -> usize {
        self.field(h_deg, v_deg).contacts.len()
    }

    /// The same design with another bottom-vHOE height (the top vHOE and camera move with it).
    pub fn with_bottom_height(&self, height_mm: f64) -> ClosedForm {
        let mut c = self.clone();
        c.bottom_size_mm[1] = height_mm;
        c
    }

    /// The first element that stops the chief ray `dir` (closed form), or `None`; checked in
    /// the order crop, top aperture, Bragg band, TIR, bottom-vHOE contact.
    pub fn blocker(&self, dir: [f64; 3], with_crop: bool) -> Option<Limit> {
        let d = DVec3::from_array(dir);
        if with_crop {
            let img = d.truncate() * (self.sensor_distance_mm / -d.z);
            let off = DVec2::from_array(self.crop_offset_px) * self.pixel_mm;
            let half =
                DVec2::new(self.crop_px[0] as f64, self.crop_px[1] as f64) * (0.5 * self.pixel_mm);
            if (img.x - off.x).abs() > half.x || (img.y - off.y).abs() > half.y {
                return Some(Limit::SensorCrop);
            }
        }
        let f = self.field_dir(dir);
        let (tmin, tmax) = self.top_rect_mm();
        if !rect_contains(
            DVec2::from_array(tmin),
            DVec2::from_array(tmax),
            DVec2::from_array(f.front_point_mm),
        ) {
            return Some(Limit::TopAperture);
        }
        let lam = f.lambda_bragg_nm;
        if !(lam >= self.band_nm[0] && lam < self.band_nm[1]) {
            return Some(Limit::BraggBand);
        }
        if DVec2::from_array(f.u_guided).length_squared() <= 1.0 {
            return Some(Limit::Tir);
        }
        let usable = if self.covered {
            let (tmin, tmax) = (DVec2::from_array(tmin), DVec2::from_array(tmax));
            let cross = DVec2::from_array(f.front_point_mm) - DVec2::from_array(f.back_point_mm);
            let g = DVec2::from_array(f.replica_step_mm) * -0.5;
            let pf = DVec2::from_array(f.front_point_mm);
            f.contacts
                .iter()
                .any(|&j| !rect_contains(tmin, tmax, pf - f64::from(j) * g + cross))
        } else {
            !f.contacts.is_empty()
        };
        if !usable {
            return Some(Limit::NoContact);
        }
        None
    }

    /// In-plane (h = 0) vertical camera angle, degrees, at which the guided wave reaches the
    /// critical angle: v = asin(n_f sin(θ_R − asin(1/n_f))) (docs/physics.md §3.4). Above it TIR
    /// fails.
    pub fn tir_edge_vertical_deg(&self) -> f64 {
        let nf = self.n_film;
        (nf * (self.theta_r() - (1.0 / nf).asin()).sin())
            .asin()
            .to_degrees()
    }

    /// In-plane vertical camera angles, degrees, at which λ_B equals `lambda_nm` (two
    /// branches: the blue edge at negative v first); NaN where no real solution exists.
    pub fn bragg_edge_vertical_deg(&self, lambda_nm: f64) -> [f64; 2] {
        let half = 0.5 * self.theta_r();
        let c = lambda_nm * half.cos() / self.lambda0_nm;
        let nf = self.n_film;
        let angle = |theta_f: f64| (-nf * theta_f.sin()).asin().to_degrees();
        if c.abs() > 1.0 {
            return [f64::NAN, f64::NAN];
        }
        [angle(c.acos() - half), angle(-c.acos() - half)]
    }

    /// Field-of-view edge along one axis (closed form): the outermost field angle (degrees,
    /// sign of `sign`) reached from 0 before a limit stops the chief ray, found by a 0.01°
    /// scan and bisection to 1e-13°, with the limit that stops it.
    pub fn fov_edge_deg(&self, vertical: bool, sign: f64, with_crop: bool) -> (f64, Option<Limit>) {
        let dir = |a: f64| {
            if vertical {
                Self::camera_dir(0.0, a)
            } else {
                Self::camera_dir(a, 0.0)
            }
        };
        let ok = |a: f64| self.blocker(dir(a), with_crop).is_none();
        match bisect_edge(sign, ok) {
            Some((edge, bad)) => (edge, self.blocker(dir(bad), with_crop)),
            None => (f64::NAN, None),
        }
    }

    /// Continuous sensor rows (row 0 = top of the crop, pixel centres at integers) at which a
    /// point on the display at height `y_obj_mm` (on the crop's vertical midline) appears,
    /// one per plate contact, found by solving the closed-form object point for the image
    /// height: (contact, row), sorted by row.
    pub fn point_rows(&self, y_obj_mm: f64) -> Vec<(u32, f64)> {
        let p = self.pixel_mm;
        let h = self.crop_px[1] as f64;
        let x_img = self.crop_offset_px[0] * p;
        let d0 = self.sensor_distance_mm;
        let v_of_row = |row: f64| (0.5 * h - (row + 0.5) + self.crop_offset_px[1]) * p;
        let obj = |v: f64, j: u32| -> Option<f64> {
            let f = self.field_dir(DVec3::new(x_img / d0, v / d0, -1.0).normalize().to_array());
            f.contacts
                .iter()
                .position(|&c| c == j)
                .map(|k| f.object_points_mm[k][1])
        };
        let steps = 4 * self.crop_px[1].max(50);
        let (v0, v1) = (v_of_row(-0.5), v_of_row(h - 0.5));
        let mut out = Vec::new();
        let mut prev: Option<FieldGeometry> = None;
        let mut v_prev = v0;
        for i in 0..=steps {
            let v = v0 + (v1 - v0) * i as f64 / steps as f64;
            let cur = self.field_dir(DVec3::new(x_img / d0, v / d0, -1.0).normalize().to_array());
            if let Some(pf) = &prev {
                for (k, &j) in cur.contacts.iter().enumerate() {
                    let Some(kp) = pf.contacts.iter().position(|&c| c == j) else {
                        continue;
                    };
                    let y0 = pf.object_points_mm[kp][1];
                    let y1 = cur.object_points_mm[k][1];
                    if (y0 > y_obj_mm) == (y1 > y_obj_mm) {
                        continue;
                    }
                    let above0 = y0 > y_obj_mm;
                    let (mut a, mut b) = (v_prev, v);
                    for _ in 0..200 {
                        let m = 0.5 * (a + b);
                        if m == a || m == b {
                            break;
                        }
                        match obj(m, j) {
                            Some(ym) if (ym > y_obj_mm) == above0 => a = m,
                            Some(_) => b = m,
                            None => break,
                        }
                    }
                    let vh = 0.5 * (a + b);
                    out.push((j, 0.5 * h + self.crop_offset_px[1] - vh / p - 0.5));
                }
            }
            prev = Some(cur);
            v_prev = v;
        }
        out.sort_by(|a, b| a.1.total_cmp(&b.1));
        out
    }
}

/// Outermost angle (sign `sign`) with `ok` true, scanning from 0 in 0.01° steps then
/// bisecting: (last ok, first bad). `None` if 0 itself fails or nothing fails up to 89°.
pub(super) fn bisect_edge(sign: f64, ok: impl Fn(f64) -> bool) -> Option<(f64, f64)> {
    if !ok(0.0) {
        return None;
    }
    let step = 0.01;
    let mut k = 1;
    let (mut a, mut b);
    loop {
        let x = sign * step * f64::from(k);
        if x.abs() > 89.0 {
            return None;
        }
        if !ok(x) {
            a = x - sign * step;
            b = x;
            break;
        }
        k += 1;
    }
    for _ in 0..200 {
        let m = 0.5 * (a + b);
        if m == a || m == b {
            break;
        }
        if ok(m) {
            a = m;
        } else {
            b = m;
        }
    }
    Some((a, b))
}
