//! Deterministic analysis of a design: the chief ray of one pixel at its exact Bragg wavelength
//! (`probe`) and the design summary of `info` (critical and guided angles, replica pitch and
//! count, Bragg wavelengths across the field, field of view and what limits it).
//!
//! Everything here is traced with the same `trace` code as the renderer, with no randomness:
//! chief rays through the lens centre at the exact Bragg wavelength of docs/physics.md §3.2. The FOV
//! is found by scanning the field angle in air (0.05° steps) and naming the first element that
//! stops the chief ray at each end: the sensor crop, the top-vHOE aperture, the Bragg band
//! falling outside the simulated spectrum, the guided wave not being trapped by TIR, or no
//! contact inside the bottom vHOE.

use glam::{DVec2, DVec3};
use serde::Serialize;

use crate::camera::Camera;
use crate::optics::interface::critical_angle;
use crate::system::System;
use crate::trace::{Branch, BranchKind, plate_crossing, trace_camera_path};

/// One replica of a probed chief ray: (grating, contact).
#[derive(Clone, Debug, Serialize)]
pub struct ProbeReplica {
    /// The grating (index in the film's list) that couples this replica.
    pub grating: u32,
    /// Index among this grating's replicas (0 = nearest the top vHOE).
    pub index: u32,
    /// Plate contacts along the guided path before the replica left it (identifies it across
    /// the field, with the grating).
    pub contact: u32,
    /// The wavelength it was traced at: this grating's Bragg wavelength for the ray, nm.
    pub lambda_nm: f64,
    /// Bottom-vHOE contact on the back face (x, y, z = w), mm.
    pub bottom_contact_mm: [f64; 3],
    /// Where the branch leaves the front face toward the user (x, y, 0), mm.
    pub exit_point_mm: [f64; 3],
    /// Where it meets the display plane, mm.
    pub object_point_mm: [f64; 3],
    /// Energy fraction carried to the object (display polarisation applied).
    pub weight: f64,
    /// TE part of the weight.
    pub weight_te: f64,
    /// TM part of the weight.
    pub weight_tm: f64,
}

/// What one grating does with a probed chief ray.
#[derive(Clone, Debug, Serialize)]
pub struct ProbeGrating {
    /// Grating index in the film's list.
    pub grating: u32,
    /// Exact Bragg wavelength of the chief ray for this grating, nm.
    pub lambda_nm: f64,
    /// Polar angle of this grating's guided ray inside the glass, degrees.
    pub guided_angle_deg: f64,
    /// Its replica pitch 2w·tanΘ', mm.
    pub replica_pitch_mm: f64,
    /// Its replicas (entries of [`ProbeResult::replicas`] with this grating).
    pub replicas: usize,
    /// Its total weight to the object (display polarisation).
    pub weight: f64,
}

/// Result of `probe`. The top-level wavelength, guided angle and pitch are those of the first
/// grating with a Bragg wavelength for the ray (the only one in a single-grating film);
/// `gratings` has every grating's, and `replicas` every (grating, contact), each traced at its
/// own grating's Bragg wavelength.
#[derive(Clone, Debug, Serialize)]
pub struct ProbeResult {
    /// Pixel (col, row) in the crop.
    pub pixel: [usize; 2],
    /// Exact Bragg wavelength of the chief ray, nm (first grating).
    pub lambda_nm: f64,
    /// Unit direction leaving the lens toward the screen.
    pub camera_ray_dir: [f64; 3],
    /// Field angles of the chief ray in air: [horizontal, vertical], degrees.
    pub field_angle_deg: [f64; 2],
    /// Polar angle of the guided ray from the plate normal inside the glass, degrees.
    pub guided_angle_deg: f64,
    /// Glass index at `lambda_nm`.
    pub n_glass: f64,
    /// Replica pitch 2w·tanΘ', mm.
    pub replica_pitch_mm: f64,
    /// Replicas, grating by grating, in contact order.
    pub replicas: Vec<ProbeReplica>,
    /// Per grating: Bragg wavelength, guided angle, pitch, replica count.
    pub gratings: Vec<ProbeGrating>,
    /// Weight of the straight-through branch (0 when the top vHOE is covered).
    pub direct_weight: f64,
    /// Guided weight left when the path stopped on its weight limit (bias bound).
    pub truncated_weight: f64,
}

fn v3(p: DVec2, z: f64) -> [f64; 3] {
    [p.x, p.y, z]
}

/// Traces the chief ray of `dir` from the lens centre at each grating's Bragg wavelength;
/// `None` if no grating has one.
pub fn probe_direction(
    sys: &System,
    origin: DVec3,
    dir: DVec3,
    pixel: [usize; 2],
) -> Option<ProbeResult> {
    let wg = &sys.waveguide;
    let mut result: Option<ProbeResult> = None;
    for j in 0..wg.gratings.len() {
        let Some(p) = probe_grating(sys, origin, dir, pixel, j) else {
            continue;
        };
        match &mut result {
            None => result = Some(p),
            Some(r) => {
                r.replicas.extend(p.replicas);
                r.gratings.extend(p.gratings);
            }
        }
    }
    result
}

/// The chief ray of `dir` traced at grating `j`'s Bragg wavelength, keeping that grating's
/// replicas.
pub fn probe_grating(
    sys: &System,
    origin: DVec3,
    dir: DVec3,
    pixel: [usize; 2],
    j: usize,
) -> Option<ProbeResult> {
    let wg = &sys.waveguide;
    let lambda = wg.gratings.get(j).bragg_wavelength_nm(-dir.truncate())?;
    let pol = sys.display.polarization_weights;
    let mut replicas = Vec::new();
    let mut direct_weight = 0.0;
    let w = wg.thickness_mm;
    // Geometry decides which contacts exist: no truncation by weight (the contact limit still
    // bounds the path), so a long, lossy path under a tall top vHOE is not mistaken for one
    // that never reaches the bottom vHOE.
    let limits = crate::trace::TraceLimits {
        min_weight: 0.0,
        max_contacts: sys.limits.max_contacts,
    };
    let summary = trace_camera_path(
        wg,
        sys.display.z_mm,
        limits,
        origin,
        dir,
        lambda,
        |b: &Branch| {
            let weight = pol[0] * b.weight[0] + pol[1] * b.weight[1];
            match b.kind {
                BranchKind::Direct => direct_weight += weight,
                BranchKind::Replica(index) if b.grating as usize == j => {
                    replicas.push(ProbeReplica {
                        grating: b.grating,
                        index,
                        contact: b.contact,
                        lambda_nm: lambda,
                        bottom_contact_mm: v3(b.bottom_contact_mm.unwrap_or_default(), w),
                        exit_point_mm: v3(b.exit_point_mm, 0.0),
                        object_point_mm: v3(b.object_point_mm, sys.display.z_mm),
                        weight,
                        weight_te: b.weight[0],
                        weight_tm: b.weight[1],
                    })
                }
                BranchKind::Replica(_) => {}
            }
        },
    );
    let n = summary.n_glass;
    // This grating's guided wave (what the trace out-couples at the top vHOE), if trapped.
    let ug = if replicas.is_empty() && summary.guided_u == DVec2::ZERO {
        0.0
    } else {
        (-dir.truncate() - wg.gratings.get(j).u_shift(lambda)).length()
    };
    let guided = if ug > 0.0 && ug < n {
        (ug / n).asin()
    } else {
        f64::NAN
    };
    let pitch = 2.0 * w * guided.tan();
    Some(ProbeResult {
        pixel,
        lambda_nm: lambda,
        camera_ray_dir: dir.to_array(),
        field_angle_deg: [
            dir.x.atan2(-dir.z).to_degrees(),
            dir.y.atan2(-dir.z).to_degrees(),
        ],
        guided_angle_deg: guided.to_degrees(),
        n_glass: n,
        replica_pitch_mm: pitch,
        gratings: vec![ProbeGrating {
            grating: j as u32,
            lambda_nm: lambda,
            guided_angle_deg: guided.to_degrees(),
            replica_pitch_mm: pitch,
            replicas: replicas.len(),
            weight: replicas.iter().map(|r| r.weight).sum(),
        }],
        replicas,
        direct_weight,
        truncated_weight: summary.truncated_weight,
    })
}

/// `probe`: the chief ray of pixel (col, row) of the crop.
pub fn probe(sys: &System, col: usize, row: usize) -> Result<ProbeResult, String> {
    let cam = &sys.camera;
    if col >= cam.width_px || row >= cam.height_px {
        return Err(format!(
            "pixel {col},{row} is outside the {}x{} crop",
            cam.width_px, cam.height_px
        ));
    }
    let ray = cam.chief_ray(col, row);
    probe_direction(sys, ray.origin, ray.dir, [col, row]).ok_or_else(|| {
        format!("pixel {col},{row}: no wavelength is Bragg-matched for its chief ray")
    })
}

/// One end of a field-of-view interval.
#[derive(Clone, Debug, Serialize)]
pub struct FovEdge {
    /// Field angle in air, degrees.
    pub angle_deg: f64,
    /// What stops the field beyond this angle.
    pub limited_by: String,
}

/// Field of view along one axis.
#[derive(Clone, Debug, Serialize)]
pub struct Fov {
    /// Full angle, degrees.
    pub full_deg: f64,
    /// Lower edge (bottom or left).
    pub min: FovEdge,
    /// Upper edge (top or right).
    pub max: FovEdge,
}

/// Field summary at one point of the crop.
#[derive(Clone, Debug, Serialize)]
pub struct FieldPoint {
    /// Name ("centre", "top", ...).
    pub name: String,
    /// Pixel (col, row).
    pub pixel: [usize; 2],
    /// Bragg wavelength, nm.
    pub lambda_nm: f64,
    /// Guided angle in the glass, degrees.
    pub guided_angle_deg: f64,
    /// Replica pitch on the display side, mm.
    pub replica_pitch_mm: f64,
    /// Bottom-vHOE contacts (replicas available).
    pub replicas: usize,
    /// Replicas above 5 % of the brightest one.
    pub replicas_above_5pct: usize,
}

/// Result of `info`.
#[derive(Clone, Debug, Serialize)]
pub struct DesignInfo {
    /// Critical angle glass → air at the recording wavelength, degrees.
    pub critical_angle_deg: f64,
    /// Critical angle film → air, degrees.
    pub film_critical_angle_deg: f64,
    /// Glass index at the recording wavelength.
    pub n_glass_recording: f64,
    /// Grating period, nm.
    pub grating_period_nm: f64,
    /// Film thickness as fabricated (the `hoe.*` fabrication keys applied; the design's
    /// `hoe.film_thickness_um` when they are all 0), µm. Every figure here is for this film.
    pub film_thickness_um: f64,
    /// Mean index of the film as fabricated.
    pub film_mean_index: f64,
    /// Sensor rows (continuous, row 0 = top) at which a point at the display centre appears,
    /// one entry per replica, with the weights of the chief rays that see it.
    pub point_replicas: Vec<PointReplica>,
    /// Mean spacing, in pixels, between consecutive replicas of that point that carry at least
    /// 5 % of the brightest one's weight.
    pub replica_pitch_sensor_px: f64,
    /// Field points (centre and the four crop edges).
    pub field: Vec<FieldPoint>,
    /// Vertical FOV of the waveguide (without the sensor crop).
    pub fov_vertical_waveguide: Fov,
    /// Vertical FOV of the capture (with the crop).
    pub fov_vertical_capture: Fov,
    /// Horizontal FOV of the waveguide.
    pub fov_horizontal_waveguide: Fov,
    /// Horizontal FOV of the capture.
    pub fov_horizontal_capture: Fov,
    /// Focus distance used, mm.
    pub focus_distance_mm: f64,
    /// Lens-to-sensor distance, mm.
    pub sensor_distance_mm: f64,
    /// Which object rows and columns the crop sees through a strong replica.
    pub object_coverage: ObjectCoverage,
    /// Per grating of the film (one entry for a single-grating film): its recording, period,
    /// field points and the display centre's replicas through it. The top-level
    /// `grating_period_nm`, `field` and `replica_pitch_sensor_px` are the first grating's;
    /// `point_replicas` lists every grating's.
    pub gratings: Vec<GratingInfo>,
    /// A colour display only (`display.primaries`): per field row of the crop, each grating's
    /// Bragg wavelength and the level of each primary there (`colour::field_bands`, 9 rows).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub colour_bands: Option<Vec<crate::colour::FieldBands>>,
}

/// What `info` reports for one grating of the film.
#[derive(Clone, Debug, Serialize)]
pub struct GratingInfo {
    /// Grating index in the film's list.
    pub grating: u32,
    /// Recording wavelength, nm.
    pub recording_wavelength_nm: f64,
    /// Reference-beam angle inside the film, degrees.
    pub reference_angle_deg: f64,
    /// Object-beam angle inside the film, degrees.
    pub object_angle_deg: f64,
    /// Index modulation n1.
    pub index_modulation: f64,
    /// Grating period, nm.
    pub grating_period_nm: f64,
    /// Field points (centre and the four crop edges) through this grating.
    pub field: Vec<FieldPoint>,
    /// Sensor rows of the display centre's replicas through this grating.
    pub point_replicas: Vec<PointReplica>,
    /// Mean spacing (px) of its replicas above 5 % of its brightest.
    pub replica_pitch_sensor_px: f64,
}

/// Where a point object appears on the sensor through one replica (grating, contact).
#[derive(Clone, Debug, Serialize)]
pub struct PointReplica {
    /// The grating that couples the replica.
    pub grating: u32,
    /// Plate contacts along the guided path (identifies the replica across the field, with
    /// the grating).
    pub contact: u32,
    /// Continuous sensor row (pixel centres at integers; row 0 = top of the crop).
    pub row: f64,
    /// Energy fraction of the chief ray that sees the point through this replica.
    pub weight: f64,
}

/// Rows of the crop's vertical midline at which the point `object_mm` on the display is seen,
/// one per replica, found by bisection on the chief rays' object points (deterministic, at each
/// ray's Bragg wavelength). The spacing differs between replicas: each extra round trip adds
/// an angle-dependent shift 2w·tanΘ'(θ), which acts like a replica-dependent object distance.
pub fn point_replicas(sys: &System, object_mm: DVec2) -> Vec<PointReplica> {
    let rows = sys.camera.height_px as f64;
    point_replicas_in(sys, object_mm, -0.5, rows - 0.5)
}

/// [`point_replicas`] over the continuous crop rows `row_lo..row_hi` (may extend beyond the
/// crop: rows < −0.5 are above it, rows > height − 0.5 below it, on the same sensor line).
pub fn point_replicas_in(
    sys: &System,
    object_mm: DVec2,
    row_lo: f64,
    row_hi: f64,
) -> Vec<PointReplica> {
    let cam = &sys.camera;
    let pitch = cam.pitch_mm;
    let v_of_row = |row: f64| (0.5 * cam.height_px as f64 - (row + 0.5) + cam.offset_px.y) * pitch;
    // Object y per replica key (grating, contact) for the chief ray at image height v, each
    // grating's replicas traced at that grating's Bragg wavelength.
    let objects = |v: f64| -> Vec<(u64, f64, f64)> {
        let ray = cam.ray_through(DVec2::new(cam.offset_px.x * pitch, v), DVec2::ZERO);
        let mut out = Vec::new();
        for (j, grating) in sys.waveguide.gratings.as_slice().iter().enumerate() {
            let Some(lambda) = grating.bragg_wavelength_nm(-ray.dir.truncate()) else {
                continue;
            };
            let pol = sys.display.polarization_weights;
            trace_camera_path(
                &sys.waveguide,
                sys.display.z_mm,
                sys.limits,
                ray.origin,
                ray.dir,
                lambda,
                |b| {
                    if matches!(b.kind, BranchKind::Replica(_)) && b.grating as usize == j {
                        out.push((
                            b.replica_key(),
                            b.object_point_mm.y,
                            pol[0] * b.weight[0] + pol[1] * b.weight[1],
                        ));
                    }
                },
            );
        }
        out
    };
    let find = |v: f64, k: u64| objects(v).into_iter().find(|o| o.0 == k);
    let steps = 4 * ((row_hi - row_lo).ceil() as usize).max(50);
    let mut found: Vec<PointReplica> = Vec::new();
    let v_start = v_of_row(row_lo);
    let v_end = v_of_row(row_hi);
    let mut prev = objects(v_start);
    let mut v_prev = v_start;
    for i in 1..=steps {
        let v = v_start + (v_end - v_start) * i as f64 / steps as f64;
        let cur = objects(v);
        for &(k, y1, _) in &cur {
            let Some(&(_, y0, _)) = prev.iter().find(|o| o.0 == k) else {
                continue;
            };
            // A crossing of the object's y (half-open, so each is found once).
            if (y0 > object_mm.y) == (y1 > object_mm.y) {
                continue;
            }
            // Bisection on v for this contact number.
            let (mut a, mut b) = (v_prev, v);
            let above0 = y0 > object_mm.y;
            for _ in 0..60 {
                let m = 0.5 * (a + b);
                match find(m, k) {
                    Some((_, ym, _)) if (ym > object_mm.y) == above0 => a = m,
                    Some(_) => b = m,
                    None => break,
                }
            }
            let v_hit = 0.5 * (a + b);
            if let Some((_, _, wgt)) = find(v_hit, k) {
                let row = 0.5 * cam.height_px as f64 + cam.offset_px.y - v_hit / pitch - 0.5;
                found.push(PointReplica {
                    grating: (k >> 32) as u32,
                    contact: k as u32,
                    row,
                    weight: wgt,
                });
            }
        }
        prev = cur;
        v_prev = v;
    }
    found.sort_by(|a, b| a.row.total_cmp(&b.row));
    found
}

/// Mean spacing (px) between consecutive replicas above `frac` of the brightest.
pub fn strong_replica_spacing_px(reps: &[PointReplica], frac: f64) -> f64 {
    let max = reps.iter().map(|r| r.weight).fold(0.0, f64::max);
    let strong: Vec<f64> = reps
        .iter()
        .filter(|r| r.weight >= frac * max && max > 0.0)
        .map(|r| r.row)
        .collect();
    if strong.len() < 2 {
        return f64::NAN;
    }
    (strong[strong.len() - 1] - strong[0]) / (strong.len() - 1) as f64
}

/// A replica counts as strong when it carries at least this fraction of the weight of the
/// strongest replica of the same object point (in or out of the crop).
pub const STRONG_REPLICA_FRACTION: f64 = 0.25;

/// Which rows and columns of the object (the display image) are seen inside the crop through
/// at least one strong replica ([`STRONG_REPLICA_FRACTION`]): the rows from the chief-ray
/// replicas of each row's centre point, scanned over three crop heights (so a strongest replica
/// outside the crop is found); the columns from the object points of the strongest replica at
/// the crop's left and right edges.
#[derive(Clone, Debug, Serialize)]
pub struct ObjectCoverage {
    /// Object size in image pixels [cols, rows].
    pub object_px: [usize; 2],
    /// The strong-replica threshold used.
    pub strong_fraction: f64,
    /// Object rows with no strong replica inside the crop.
    pub rows_unseen: Vec<usize>,
    /// Object columns outside the horizontal field of the crop.
    pub cols_unseen: Vec<usize>,
}

impl ObjectCoverage {
    /// True when every row and column is seen.
    pub fn complete(&self) -> bool {
        self.rows_unseen.is_empty() && self.cols_unseen.is_empty()
    }

    /// One-line warning naming the unseen rows and columns, or None when all are seen.
    pub fn warning(&self) -> Option<String> {
        if self.complete() {
            return None;
        }
        let mut parts = Vec::new();
        if !self.rows_unseen.is_empty() {
            parts.push(format!(
                "object rows {} (of 0-{})",
                ranges(&self.rows_unseen),
                self.object_px[1] - 1
            ));
        }
        if !self.cols_unseen.is_empty() {
            parts.push(format!(
                "object columns {} (of 0-{})",
                ranges(&self.cols_unseen),
                self.object_px[0] - 1
            ));
        }
        Some(format!(
            "warning: {} have no replica inside the crop with at least {} % of their strongest \
             replica's weight: they are barely measured and cannot be reconstructed well \
             (move sensor.crop_offset_px or display.center_mm, or enlarge sensor.crop_px)",
            parts.join(" and "),
            self.strong_fraction * 100.0
        ))
    }
}

/// A crop offset (pixels, the `sensor.crop_offset_px` convention) that frames the object: the
/// crop moved vertically so that the strongest replica of the display centre lands on the
/// crop's centre row. `None` when the scene's own crop already sees every object row and
/// column, or when the moved crop would not see more of them.
pub fn framing_offset_px(sys: &System) -> Option<[f64; 2]> {
    let before = object_coverage(sys);
    if before.complete() {
        return None;
    }
    let cam = &sys.camera;
    let h = cam.height_px as f64;
    let strongest = point_replicas_in(sys, sys.display.center_mm, -h - 0.5, 2.0 * h - 0.5)
        .into_iter()
        .max_by(|a, b| a.weight.total_cmp(&b.weight))?;
    let shift = (0.5 * h - 0.5 - strongest.row).round();
    if shift == 0.0 {
        return None;
    }
    let offset = [cam.offset_px.x, cam.offset_px.y + shift];
    let mut moved = sys.clone();
    moved.camera.offset_px.y = offset[1];
    let after = object_coverage(&moved);
    let unseen = |c: &ObjectCoverage| c.rows_unseen.len() + c.cols_unseen.len();
    (unseen(&after) < unseen(&before)).then_some(offset)
}

/// Compact "0-3, 7, 9-12" form of sorted indices.
pub fn ranges(idx: &[usize]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && idx[j + 1] == idx[j] + 1 {
            j += 1;
        }
        out.push(if j > i {
            format!("{}-{}", idx[i], idx[j])
        } else {
            idx[i].to_string()
        });
        i = j + 1;
    }
    out.join(", ")
}

/// The object coverage of the scene's crop (see [`ObjectCoverage`]).
pub fn object_coverage(sys: &System) -> ObjectCoverage {
    let disp = &sys.display;
    let cam = &sys.camera;
    let (ow, oh) = (disp.width_px, disp.height_px);
    let pix = disp.image_pixel_mm;
    let crop_h = cam.height_px as f64;
    let strong_inside = |reps: &[PointReplica]| {
        let max = reps.iter().map(|r| r.weight).fold(0.0, f64::max);
        max > 0.0
            && reps.iter().any(|r| {
                r.weight >= STRONG_REPLICA_FRACTION * max && r.row >= -0.5 && r.row <= crop_h - 0.5
            })
    };
    let rows_unseen: Vec<usize> = (0..oh)
        .filter(|&r| {
            let y = disp.center_mm.y + (0.5 * oh as f64 - r as f64 - 0.5) * pix;
            let reps = point_replicas_in(
                sys,
                DVec2::new(disp.center_mm.x, y),
                -crop_h - 0.5,
                2.0 * crop_h - 0.5,
            );
            !strong_inside(&reps)
        })
        .collect();
    // Horizontal field: the object x seen by the strongest replica at the crop's left and
    // right edges, on the row where the display centre's strongest replica lies (clamped to
    // the crop).
    let centre = point_replicas_in(sys, disp.center_mm, -0.5, crop_h - 0.5);
    let row = centre
        .iter()
        .max_by(|a, b| a.weight.total_cmp(&b.weight))
        .map_or(0.5 * crop_h - 0.5, |r| r.row);
    let pitch = cam.pitch_mm;
    let v = (0.5 * crop_h + cam.offset_px.y - row - 0.5) * pitch;
    let edge_x = |col_edge: f64| -> Option<f64> {
        let u = (col_edge - 0.5 * cam.width_px as f64 + cam.offset_px.x) * pitch;
        let ray = cam.ray_through(DVec2::new(u, v), DVec2::ZERO);
        let p = probe_direction(sys, ray.origin, ray.dir, [0, 0])?;
        p.replicas
            .iter()
            .max_by(|a, b| a.weight.total_cmp(&b.weight))
            .map(|r| r.object_point_mm[0])
    };
    let cols_unseen: Vec<usize> = match (edge_x(0.0), edge_x(cam.width_px as f64)) {
        (Some(a), Some(b)) => {
            let (lo, hi) = (a.min(b), a.max(b));
            (0..ow)
                .filter(|&c| {
                    let x = disp.center_mm.x + (c as f64 + 0.5 - 0.5 * ow as f64) * pix;
                    x < lo || x > hi
                })
                .collect()
        }
        _ => (0..ow).collect(),
    };
    ObjectCoverage {
        object_px: [ow, oh],
        strong_fraction: STRONG_REPLICA_FRACTION,
        rows_unseen,
        cols_unseen,
    }
}

fn count_above(p: &ProbeResult, frac: f64) -> usize {
    let max = p.replicas.iter().map(|r| r.weight).fold(0.0, f64::max);
    p.replicas
        .iter()
        .filter(|r| max > 0.0 && r.weight >= frac * max)
        .count()
}

/// The unit direction (leaving the lens toward the screen) of the chief ray at field angle
/// `deg` in air: (0, sin θ, −cos θ) when `vertical`, else (sin θ, 0, −cos θ).
pub fn field_direction(deg: f64, vertical: bool) -> DVec3 {
    let t = deg.to_radians();
    if vertical {
        DVec3::new(0.0, t.sin(), -t.cos())
    } else {
        DVec3::new(t.sin(), 0.0, -t.cos())
    }
}

/// Centre and half size (mm) of the sensor crop in the image plane (+x right, +y up).
fn crop_bounds_mm(cam: &Camera) -> (DVec2, DVec2) {
    (
        cam.offset_px * cam.pitch_mm,
        DVec2::new(cam.width_px as f64, cam.height_px as f64) * (0.5 * cam.pitch_mm),
    )
}

/// Field angles in air (degrees, [low, high]) of the chief rays along one axis
/// ([`field_direction`]) that land inside the sensor crop, or `None` if that line of fields
/// misses the crop altogether.
pub fn crop_field_range_deg(cam: &Camera, vertical: bool) -> Option<[f64; 2]> {
    let (centre, half) = crop_bounds_mm(cam);
    let (along_c, along_h, across_c, across_h) = if vertical {
        (centre.y, half.y, centre.x, half.x)
    } else {
        (centre.x, half.x, centre.y, half.y)
    };
    // The chief ray at angle θ meets the image plane at d0·tan θ along the axis, 0 across.
    if across_c.abs() > across_h {
        return None;
    }
    let d0 = cam.sensor_distance_mm;
    Some([
        ((along_c - along_h) / d0).atan().to_degrees(),
        ((along_c + along_h) / d0).atan().to_degrees(),
    ])
}

/// Why the chief ray at a field angle fails, or `None` if it reaches the display.
pub fn field_blocker(sys: &System, dir: DVec3, with_crop: bool) -> Option<&'static str> {
    let cam = &sys.camera;
    let wg = &sys.waveguide;
    if with_crop {
        let d0 = cam.sensor_distance_mm;
        let img = DVec2::new(dir.x, dir.y) * (d0 / -dir.z);
        let (centre, half) = crop_bounds_mm(cam);
        let off = (img - centre).abs();
        if off.x > half.x || off.y > half.y {
            return Some("sensor crop");
        }
    }
    // A multiplexed film sees the field if any of its gratings does; otherwise the first
    // grating's reason is given.
    let mut first = None;
    for j in 0..wg.gratings.len() {
        match grating_blocker(sys, dir, j) {
            None => return None,
            Some(why) => {
                first.get_or_insert(why);
            }
        }
    }
    first
}

/// Why grating `j` does not bring the chief ray along `dir` to the display, or `None`.
fn grating_blocker(sys: &System, dir: DVec3, j: usize) -> Option<&'static str> {
    let cam = &sys.camera;
    let wg = &sys.waveguide;
    let grating = wg.gratings.get(j);
    let u = -dir.truncate();
    let lambda = grating.bragg_wavelength_nm(u);
    let n = wg.n_glass(lambda.unwrap_or(sys.scene.hoe.gratings()[j].recording_wavelength_nm));
    let (_, p_top) = plate_crossing(wg, cam.lens_center_mm, dir, n);
    if !wg.top.contains(p_top) {
        return Some("top vHOE aperture");
    }
    let Some(lambda) = lambda.filter(|&l| sys.wavelengths.in_band(l)) else {
        return Some("Bragg band outside the simulated spectrum");
    };
    let ug = u - grating.u_shift(lambda);
    if ug.length_squared() <= 1.0 {
        return Some("TIR (guided angle below critical)");
    }
    let p = probe_grating(sys, cam.lens_center_mm, dir, [0, 0], j)?;
    if p.replicas.iter().all(|r| r.weight <= 0.0) {
        return Some("bottom vHOE (no contact)");
    }
    None
}

/// The field of view along one axis from chief rays at their Bragg wavelengths (0.05° steps;
/// `with_crop`: the sensor crop limits it too), each edge with what stops it.
pub fn scan_fov(sys: &System, vertical: bool, with_crop: bool) -> Fov {
    let step = 0.05f64;
    let dir_of = |deg: f64| field_direction(deg, vertical);
    let edge = |sign: f64| -> FovEdge {
        let mut last_ok = f64::NAN;
        let mut k = 0;
        loop {
            let a = sign * step * k as f64;
            if a.abs() > 89.0 {
                return FovEdge {
                    angle_deg: last_ok,
                    limited_by: "none up to 89°".into(),
                };
            }
            if let Some(why) = field_blocker(sys, dir_of(a), with_crop) {
                return FovEdge {
                    angle_deg: last_ok,
                    limited_by: why.into(),
                };
            }
            last_ok = a;
            k += 1;
        }
    };
    let min = edge(-1.0);
    let max = edge(1.0);
    let full = if min.angle_deg.is_nan() || max.angle_deg.is_nan() {
        0.0
    } else {
        max.angle_deg - min.angle_deg
    };
    Fov {
        full_deg: full,
        min,
        max,
    }
}

/// `info`: the design summary.
pub fn info(sys: &System) -> DesignInfo {
    let wg = &sys.waveguide;
    let cam = &sys.camera;
    let lambda0 = sys.scene.hoe.primary_wavelength_nm();
    let n0 = wg.n_glass(lambda0);
    let (w, h) = (cam.width_px, cam.height_px);
    let points = [
        ("centre", w / 2, h / 2),
        ("top", w / 2, 0),
        ("bottom", w / 2, h - 1),
        ("left", 0, h / 2),
        ("right", w - 1, h / 2),
    ];
    let field_of = |j: usize| -> Vec<FieldPoint> {
        points
            .iter()
            .filter_map(|&(name, col, row)| {
                let ray = cam.chief_ray(col, row);
                probe_grating(sys, ray.origin, ray.dir, [col, row], j).map(|p| FieldPoint {
                    name: name.into(),
                    pixel: [col, row],
                    lambda_nm: p.lambda_nm,
                    guided_angle_deg: p.guided_angle_deg,
                    replica_pitch_mm: p.replica_pitch_mm,
                    replicas: p.replicas.len(),
                    replicas_above_5pct: count_above(&p, 0.05),
                })
            })
            .collect()
    };
    let point = point_replicas(sys, sys.display.center_mm);
    let gratings: Vec<GratingInfo> = sys
        .scene
        .hoe
        .gratings()
        .iter()
        .enumerate()
        .map(|(j, d)| {
            let reps: Vec<PointReplica> = point
                .iter()
                .filter(|r| r.grating as usize == j)
                .cloned()
                .collect();
            GratingInfo {
                grating: j as u32,
                recording_wavelength_nm: d.recording_wavelength_nm,
                reference_angle_deg: d.reference_angle_deg,
                object_angle_deg: d.object_angle_deg,
                index_modulation: d.index_modulation,
                grating_period_nm: wg.gratings.get(j).period_nm(),
                field: field_of(j),
                replica_pitch_sensor_px: strong_replica_spacing_px(&reps, 0.05),
                point_replicas: reps,
            }
        })
        .collect();
    DesignInfo {
        critical_angle_deg: critical_angle(n0, 1.0).to_degrees(),
        film_critical_angle_deg: critical_angle(wg.gratings.film().n_film, 1.0).to_degrees(),
        n_glass_recording: n0,
        grating_period_nm: wg.gratings.film().period_nm(),
        film_thickness_um: wg.gratings.film().thickness_nm * 1e-3,
        film_mean_index: wg.gratings.film().n_film,
        replica_pitch_sensor_px: gratings[0].replica_pitch_sensor_px,
        point_replicas: point,
        field: gratings[0].field.clone(),
        fov_vertical_waveguide: scan_fov(sys, true, false),
        fov_vertical_capture: scan_fov(sys, true, true),
        fov_horizontal_waveguide: scan_fov(sys, false, false),
        fov_horizontal_capture: scan_fov(sys, false, true),
        focus_distance_mm: cam.focus_distance_mm,
        sensor_distance_mm: cam.sensor_distance_mm,
        object_coverage: object_coverage(sys),
        gratings,
        colour_bands: sys
            .display
            .primaries
            .is_some()
            .then(|| crate::colour::field_bands(sys, COLOUR_BAND_ROWS)),
    }
}

/// Field rows of `info`'s colour bands.
pub const COLOUR_BAND_ROWS: usize = 9;
