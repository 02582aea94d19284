//! The comparison of the closed forms with the tracer (module header of `analytic`,
//! "Comparison"): the compared rows by section, their summary, and the report as Markdown
//! and CSV.

use glam::{DVec2, DVec3};
use serde::Serialize;

use super::closed_forms::{ClosedForm, FieldGeometry, Limit, bisect_edge};
use crate::analysis::{info, point_replicas, probe_direction};
use crate::scene::Scene;
use crate::system::{System, build_camera, build_waveguide};
use crate::trace::{BranchKind, trace_camera_path};

/// Relative tolerance for the deterministic quantities.
pub const DETERMINISTIC_REL_TOL: f64 = 1e-6;

/// One compared value.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// Section ("field", "point", "height", "fov").
    pub section: String,
    /// What is compared (with its unit).
    pub quantity: String,
    /// Field index in the field list (field section), if any.
    pub field: Option<usize>,
    /// Horizontal field angle in air, degrees (NaN if not applicable).
    pub field_h_deg: f64,
    /// Vertical field angle in air, degrees (NaN if not applicable).
    pub field_v_deg: f64,
    /// Extra parameter (bottom-vHOE height in mm, contact number, ...), NaN if none.
    pub param: f64,
    /// Closed-form value.
    pub closed_form: f64,
    /// stscam's value.
    pub stscam: f64,
    /// |closed form − stscam|.
    pub abs_diff: f64,
    /// abs_diff / |stscam| (or / the stated scale).
    pub rel_diff: f64,
    /// Tolerance the row is checked against (on rel_diff, or abs_diff for counts and the
    /// info scan).
    pub tolerance: f64,
    /// Whether the row passes.
    pub pass: bool,
    /// Remark (limiting element names, ...).
    pub note: String,
    /// The grating of the film the row is about (0 in a single-grating film).
    pub grating: u32,
}

/// Maxima over the rows of one quantity.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// Quantity.
    pub quantity: String,
    /// Rows compared.
    pub rows: usize,
    /// Largest absolute difference.
    pub max_abs_diff: f64,
    /// Largest relative difference.
    pub max_rel_diff: f64,
    /// Tolerance and what it applies to.
    pub tolerance: String,
    /// All rows pass.
    pub pass: bool,
}

/// The comparison of closed forms with the tracer.
#[derive(Clone, Debug, Serialize)]
pub struct AnalyticReport {
    /// Field angles compared [h, v], degrees.
    pub fields_deg: Vec<[f64; 2]>,
    /// Closed-form inputs used.
    pub closed_form: ClosedForm,
    /// Every compared value.
    pub rows: Vec<Row>,
    /// Maxima per quantity.
    pub summary: Vec<Summary>,
    /// Every row passes.
    pub pass: bool,
}

/// Quantity names (also the keys of the summary).
pub mod quantity {
    /// Bragg wavelength.
    pub const LAMBDA_B: &str = "Bragg wavelength λ_B (nm)";
    /// Throughput peak.
    pub const LAMBDA_PEAK: &str = "λ of max traced throughput (n1 = 1e-4) − λ_B (nm)";
    /// Guided angle.
    pub const GUIDED: &str = "guided angle Θ' (deg)";
    /// Pitch.
    pub const PITCH: &str = "replica pitch 2w·tanΘ' (mm)";
    /// First replica's display point.
    pub const OBJECT0: &str = "replica-0 display point (mm, rel. to pitch)";
    /// Count.
    pub const COUNT: &str = "replica count";
    /// Point rows.
    pub const ROWS: &str = "sensor row of a display-centre point (px)";
    /// Count vs height.
    pub const COUNT_H: &str = "replica count vs bottom-vHOE height";
    /// Multiplexed film: a grating's Bragg wavelength against the grating alone.
    pub const MULTIPLEX_LAMBDA: &str = "multiplexed λ_B − the grating alone's (nm)";
    /// Multiplexed film: a grating's guided angle against the grating alone.
    pub const MULTIPLEX_GUIDED: &str = "multiplexed Θ' − the grating alone's (deg)";
    /// Multiplexed film: largest distance between replica exit points.
    pub const MULTIPLEX_EXIT: &str = "multiplexed replica exit points − the grating alone's (mm)";
    /// FOV edge, bisection.
    pub const FOV_TRACED: &str = "FOV edge, traced chief ray bisected (deg)";
    /// FOV edge vs info.
    pub const FOV_INFO: &str = "FOV edge vs `info` 0.05° scan (deg)";
    /// Critical angles.
    pub const CRITICAL: &str = "critical angle (deg)";
}

/// Index modulation of the weak-grating copy used for the throughput-peak search.
pub const WEAK_INDEX_MODULATION: f64 = 1e-4;

/// Tolerance of the throughput-peak row, nm.
///
/// The traced throughput is not maximal exactly at λ_B: the Kogelnik coupling
/// ν = π n1 d/(λ√(c_R c_S)) itself depends on λ, so in the weak-grating limit the throughput
/// η_top·η_in ∝ ν⁴ sinc⁴ξ peaks where 4 d ln ν/dλ = −4 d ln sinc ξ/dλ, i.e. about
/// −3/(λ (∂ξ/∂λ)²) ≈ −0.01 nm from λ_B (∂ξ/∂λ ≈ 0.8 nm⁻¹, docs/physics.md §3.5). That is a physical
/// pull, not a disagreement; the row checks |peak − λ_B| ≤ 0.05 nm, 1 % of the ≈ 5 nm band.
pub fn peak_tolerance_nm(_lambda_nm: f64) -> f64 {
    0.05
}

#[allow(clippy::too_many_arguments)]
fn row(
    section: &str,
    q: &str,
    field: Option<usize>,
    hv: [f64; 2],
    param: f64,
    cf: f64,
    st: f64,
    scale: f64,
    tol: f64,
    on_abs: bool,
) -> Row {
    let abs = (cf - st).abs();
    let rel = abs / scale.abs();
    let pass = if on_abs { abs <= tol } else { rel <= tol } && abs.is_finite();
    Row {
        section: section.into(),
        quantity: q.into(),
        field,
        field_h_deg: hv[0],
        field_v_deg: hv[1],
        param,
        closed_form: cf,
        stscam: st,
        abs_diff: abs,
        rel_diff: rel,
        tolerance: tol,
        pass,
        note: String::new(),
        grating: 0,
    }
}

/// A copy of `sys` with a changed scene, its waveguide and camera rebuilt.
fn rebuilt(sys: &System, edit: impl FnOnce(&mut Scene)) -> System {
    let mut s = sys.clone();
    edit(&mut s.scene);
    s.waveguide = build_waveguide(&s.scene);
    s.camera = build_camera(&s.scene, &s.waveguide);
    s
}

/// Traced chief-ray throughput of the first replica (display polarisation) at `lambda_nm`.
/// (One replica: the sum over replicas jumps where a contact crosses a vHOE edge as the glass
/// index changes with λ.)
fn throughput(sys: &System, dir: DVec3, lambda_nm: f64) -> f64 {
    let pol = sys.display.polarization_weights;
    let mut t = 0.0;
    trace_camera_path(
        &sys.waveguide,
        sys.display.z_mm,
        sys.limits,
        sys.camera.lens_center_mm,
        dir,
        lambda_nm,
        |b| {
            if b.kind == BranchKind::Replica(0) {
                t += pol[0] * b.weight[0] + pol[1] * b.weight[1];
            }
        },
    );
    t
}

/// Golden-section search for the maximum of `f` on [a, b] to `tol`.
pub fn golden_max(f: impl Fn(f64) -> f64, mut a: f64, mut b: f64, tol: f64) -> f64 {
    let r = 0.5 * (5f64.sqrt() - 1.0);
    let mut c = b - r * (b - a);
    let mut d = a + r * (b - a);
    let (mut fc, mut fd) = (f(c), f(d));
    while (b - a).abs() > tol {
        if fc >= fd {
            b = d;
            d = c;
            fd = fc;
            c = b - r * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + r * (b - a);
            fd = f(d);
        }
        if c >= d {
            break;
        }
    }
    0.5 * (a + b)
}

/// Traced FOV edge: bisection of "the chief ray reaches the display through the waveguide,
/// in band, under TIR" evaluated with `analysis::probe_direction`.
fn traced_edge(sys: &System, vertical: bool, sign: f64) -> Option<f64> {
    let lens = sys.camera.lens_center_mm;
    let ok = |a: f64| {
        let dir = if vertical {
            ClosedForm::camera_dir(0.0, a)
        } else {
            ClosedForm::camera_dir(a, 0.0)
        };
        let Some(p) = probe_direction(sys, lens, DVec3::from_array(dir), [0, 0]) else {
            return false;
        };
        let ug = p.n_glass * p.guided_angle_deg.to_radians().sin();
        sys.wavelengths.in_band(p.lambda_nm)
            && ug > 1.0
            && p.replicas.iter().any(|r| r.weight > 0.0)
    };
    bisect_edge(sign, ok).map(|e| e.0)
}

/// Compares the closed forms of `ClosedForm::from_scene(&sys.scene)` with the tracer over
/// `n_fields` (at least 50) field angles; see the module documentation.
///
/// A multiplexed film is compared grating by grating: each grating's closed forms (those of a
/// film holding that grating alone; they assume an object beam normal to the film, so a
/// grating with an object angle has no closed-form rows) against the tracer with that grating
/// alone, and then the multiplexed tracer's geometry for each grating (Bragg wavelength, guided
/// angle, replica exit points of the chief rays, section "multiplex") against the same
/// grating alone: the other gratings change weights, never geometry. Rows carry the grating.
pub fn compare(sys: &System, n_fields: usize) -> AnalyticReport {
    let descs = sys.scene.hoe.gratings();
    if descs.len() == 1 {
        return compare_with(sys, &ClosedForm::from_scene(&sys.scene), n_fields);
    }
    let mut merged: Option<AnalyticReport> = None;
    for (j, d) in descs.iter().enumerate() {
        let alone = rebuilt(sys, |s| s.hoe.grating = vec![d.clone()]);
        let mut rows = if d.object_angle_deg == 0.0 {
            let mut r = compare_with(&alone, &ClosedForm::from_scene(&alone.scene), n_fields);
            if let Some(m) = &merged {
                r.fields_deg.clear();
                r.closed_form = m.closed_form.clone();
            }
            let rows = std::mem::take(&mut r.rows);
            if merged.is_none() {
                merged = Some(r);
            }
            rows
        } else {
            Vec::new()
        };
        rows.extend(multiplex_rows(sys, &alone, j));
        rows.iter_mut().for_each(|r| r.grating = j as u32);
        match &mut merged {
            Some(m) => m.rows.extend(rows),
            None => {
                merged = Some(AnalyticReport {
                    fields_deg: Vec::new(),
                    closed_form: ClosedForm::from_scene(&sys.scene),
                    rows,
                    summary: Vec::new(),
                    pass: true,
                })
            }
        }
    }
    let mut m = merged.expect("a film holds at least one grating");
    m.summary = summarise(&m.rows);
    m.pass = m.rows.iter().all(|r| r.pass);
    m
}

/// Section "multiplex": grating `j` of the multiplexed `sys` against `alone` (the same scene
/// with grating j only), over chief rays of 41 vertical fields: Bragg wavelength, guided angle
/// and every replica's front-face exit point must agree to 1e-12 (relative; mm for points).
fn multiplex_rows(sys: &System, alone: &System, j: usize) -> Vec<Row> {
    let lens = sys.camera.lens_center_mm;
    let mut rows = Vec::new();
    let tol = 1e-12;
    for k in 0..41 {
        let v = -20.0 + k as f64;
        let dir = DVec3::from_array(ClosedForm::camera_dir(0.0, v));
        let multi = crate::analysis::probe_grating(sys, lens, dir, [0, 0], j);
        let single = crate::analysis::probe_grating(alone, lens, dir, [0, 0], 0);
        let (Some(m), Some(s)) = (multi, single) else {
            continue;
        };
        // Beyond the top vHOE's aperture neither has a guided wave (both NaN): nothing to
        // compare.
        if m.guided_angle_deg.is_nan() && s.guided_angle_deg.is_nan() && s.replicas.is_empty() {
            continue;
        }
        let exit_diff = if m.replicas.len() == s.replicas.len() {
            m.replicas
                .iter()
                .zip(&s.replicas)
                .map(|(a, b)| {
                    (DVec3::from_array(a.exit_point_mm) - DVec3::from_array(b.exit_point_mm))
                        .length()
                })
                .fold(0.0, f64::max)
        } else {
            f64::INFINITY
        };
        for (q, cf_value, st) in [
            (quantity::MULTIPLEX_LAMBDA, s.lambda_nm, m.lambda_nm),
            (
                quantity::MULTIPLEX_GUIDED,
                s.guided_angle_deg,
                m.guided_angle_deg,
            ),
            (quantity::MULTIPLEX_EXIT, 0.0, exit_diff),
        ] {
            let scale = if q == quantity::MULTIPLEX_EXIT {
                1.0
            } else {
                st
            };
            rows.push(row(
                "multiplex",
                q,
                Some(k),
                [0.0, v],
                f64::NAN,
                cf_value,
                st,
                scale,
                tol,
                false,
            ));
        }
    }
    rows
}

/// [`compare`] with given closed-form inputs (e.g. perturbed, to check the comparison fails):
/// the per-field rows, the sensor rows of a point, the replica count against the bottom vHOE's
/// height and the field of view, then the summary.
pub fn compare_with(sys: &System, cf: &ClosedForm, n_fields: usize) -> AnalyticReport {
    let fields = field_list(cf, n_fields.max(50));
    let mut rows = Vec::new();
    // The tracer without its weight cut-off: every contact inside the bottom vHOE is a replica.
    let mut free = sys.clone();
    free.limits.min_weight = 0.0;
    // A weak-grating copy for the throughput-peak search: with n1 → 0 the losses (1 − η) at
    // the contacts before the first replica are ≈ 1, so its throughput is one Bragg lobe
    // η_top·η_in ∝ ν⁴ sinc⁴ξ.
    let weak = rebuilt(sys, |s| {
        s.hoe.index_modulation = Some(WEAK_INDEX_MODULATION);
        s.hoe
            .grating
            .iter_mut()
            .for_each(|g| g.index_modulation = WEAK_INDEX_MODULATION);
    });
    for (i, &hv) in fields.iter().enumerate() {
        field_rows(&mut rows, &free, &weak, cf, i, hv);
    }
    point_rows(&mut rows, sys, cf);
    height_rows(&mut rows, sys, cf);
    fov_section(&mut rows, sys, cf);
    let summary = summarise(&rows);
    let pass = rows.iter().all(|r| r.pass);
    AnalyticReport {
        fields_deg: fields,
        closed_form: cf.clone(),
        rows,
        summary,
        pass,
    }
}

/// The fields (h, v) in degrees compared by [`compare_with`]: `n_fields` spanning 97 % of the
/// closed-form edges, 3/5 vertical, 1/5 horizontal, the rest conical.
fn field_list(cf: &ClosedForm, n_fields: usize) -> Vec<[f64; 2]> {
    let (v_lo, _) = cf.fov_edge_deg(true, -1.0, false);
    let (v_hi, _) = cf.fov_edge_deg(true, 1.0, false);
    let (h_lo, _) = cf.fov_edge_deg(false, -1.0, false);
    let (h_hi, _) = cf.fov_edge_deg(false, 1.0, false);
    let span = |lo: f64, hi: f64, k: usize, n: usize| {
        0.97 * (lo + (hi - lo) * k as f64 / (n - 1).max(1) as f64)
    };
    let n_v = n_fields * 3 / 5;
    let n_h = n_fields / 5;
    let n_c = n_fields - n_v - n_h;
    let mut fields = Vec::new();
    for k in 0..n_v {
        fields.push([0.0, span(v_lo, v_hi, k, n_v)]);
    }
    for k in 0..n_h {
        fields.push([span(h_lo, h_hi, k, n_h), 0.0]);
    }
    for k in 0..n_c {
        // Conical: both angles at once, along the two diagonals of the field.
        let v = span(v_lo, v_hi, k, n_c);
        let h = span(h_lo, h_hi, k, n_c) * if k % 2 == 0 { 0.5 } else { -0.5 };
        fields.push([h, v]);
    }

    fields
}

/// The rows of field `i` at `[h, v]` degrees: Bragg wavelength, throughput peak (with the
/// weak-grating copy `weak`), guided angle, replica pitch, first object point and replica
/// count, traced with `free` (no weight cut-off).
fn field_rows(
    rows: &mut Vec<Row>,
    free: &System,
    weak: &System,
    cf: &ClosedForm,
    i: usize,
    [h, v]: [f64; 2],
) {
    let tol = DETERMINISTIC_REL_TOL;
    let f = cf.field(h, v);
    let dir = DVec3::from_array(f.camera_dir);
    let hv = [h, v];
    let Some(p) = probe_direction(free, free.camera.lens_center_mm, dir, [0, 0]) else {
        let mut r = row(
            "field",
            quantity::LAMBDA_B,
            Some(i),
            hv,
            f64::NAN,
            f.lambda_bragg_nm,
            f64::NAN,
            1.0,
            tol,
            false,
        );
        r.note = "tracer: no Bragg wavelength".into();
        rows.push(r);
        return;
    };
    let lb = p.lambda_nm;
    rows.push(row(
        "field",
        quantity::LAMBDA_B,
        Some(i),
        hv,
        f64::NAN,
        f.lambda_bragg_nm,
        lb,
        lb,
        tol,
        false,
    ));
    let peak = golden_max(|l| throughput(weak, dir, l), lb - 2.0, lb + 2.0, 1e-9);
    let mut r = row(
        "field",
        quantity::LAMBDA_PEAK,
        Some(i),
        hv,
        f64::NAN,
        0.0,
        peak - f.lambda_bragg_nm,
        f.lambda_bragg_nm,
        peak_tolerance_nm(lb),
        true,
    );
    r.note = format!("peak at {peak:.9} nm");
    rows.push(r);
    rows.push(row(
        "field",
        quantity::GUIDED,
        Some(i),
        hv,
        f64::NAN,
        f.guided_angle_deg,
        p.guided_angle_deg,
        p.guided_angle_deg,
        tol,
        false,
    ));
    replica_rows(rows, &f, &p, i, hv);
}

/// The replica rows of field `i` at `hv`: the worst replica pitch, the first object point and
/// the replica count of the traced probe `p` against the closed form `f`.
fn replica_rows(
    rows: &mut Vec<Row>,
    f: &FieldGeometry,
    p: &crate::analysis::ProbeResult,
    i: usize,
    hv: [f64; 2],
) {
    let tol = DETERMINISTIC_REL_TOL;
    // Pitch: the worst spacing of consecutive traced display points.
    let obj: Vec<DVec2> = p
        .replicas
        .iter()
        .map(|r| DVec3::from_array(r.object_point_mm).truncate())
        .collect();
    let traced_pitch = obj
        .windows(2)
        .map(|w| (w[1] - w[0]).length())
        .max_by(|a, b| {
            (a - f.replica_pitch_mm)
                .abs()
                .total_cmp(&(b - f.replica_pitch_mm).abs())
        })
        // One replica only (edge of the field): the tracer's own 2w·tanΘ'.
        .unwrap_or(p.replica_pitch_mm);
    rows.push(row(
        "field",
        quantity::PITCH,
        Some(i),
        hv,
        f64::NAN,
        f.replica_pitch_mm,
        traced_pitch,
        traced_pitch,
        tol,
        false,
    ));
    if let (Some(o), Some(c)) = (obj.first(), f.object_points_mm.first()) {
        let d = (*o - DVec2::from_array(*c)).length();
        let mut r = row(
            "field",
            quantity::OBJECT0,
            Some(i),
            hv,
            f64::NAN,
            0.0,
            d,
            f.replica_pitch_mm,
            tol,
            false,
        );
        r.note = format!("y = {:.6} mm", o.y);
        rows.push(r);
    }
    rows.push(row(
        "field",
        quantity::COUNT,
        Some(i),
        hv,
        f64::NAN,
        f.contacts.len() as f64,
        p.replicas.len() as f64,
        1.0,
        0.0,
        true,
    ));
}

/// The sensor rows of a point at the display centre (deterministic, `analysis::point_replicas`)
/// and, where their numbers differ, a count row.
fn point_rows(rows: &mut Vec<Row>, sys: &System, cf: &ClosedForm) {
    let tol = DETERMINISTIC_REL_TOL;
    let centre = sys.display.center_mm;
    let traced_rows = point_replicas(sys, centre);
    let cf_rows = cf.point_rows(centre.y);
    for (j, r_cf) in &cf_rows {
        let st = traced_rows
            .iter()
            .find(|r| r.contact == *j)
            .map_or(f64::NAN, |r| r.row);
        rows.push(row(
            "point",
            quantity::ROWS,
            None,
            [f64::NAN; 2],
            f64::from(*j),
            *r_cf,
            st,
            st,
            tol,
            false,
        ));
    }
    if traced_rows.len() != cf_rows.len() {
        let mut r = row(
            "point",
            quantity::COUNT,
            None,
            [f64::NAN; 2],
            f64::NAN,
            cf_rows.len() as f64,
            traced_rows.len() as f64,
            1.0,
            0.0,
            true,
        );
        r.note = "number of replica rows".into();
        rows.push(r);
    }
}

/// The replica count of seven fields against the bottom vHOE's height (10 to 80 mm).
fn height_rows(rows: &mut Vec<Row>, sys: &System, cf: &ClosedForm) {
    let (_, half_v) = {
        let d0 = cf.sensor_distance_mm;
        (
            0.0,
            (0.5 * cf.crop_px[1] as f64 * cf.pixel_mm / d0)
                .atan()
                .to_degrees(),
        )
    };
    let hv_list = [
        [0.0, -0.99 * half_v],
        [0.0, -0.5 * half_v],
        [0.0, 0.0],
        [0.0, 0.5 * half_v],
        [0.0, 0.99 * half_v],
        [0.5 * half_v, 0.5 * half_v],
        [-0.9 * half_v, -0.7 * half_v],
    ];
    for height in [10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0] {
        let mut s = rebuilt(sys, |s| s.bottom_hoe.height_mm = height);
        s.limits.min_weight = 0.0;
        let c = cf.with_bottom_height(height);
        for hv in hv_list {
            let f = c.field(hv[0], hv[1]);
            let n = probe_direction(
                &s,
                s.camera.lens_center_mm,
                DVec3::from_array(f.camera_dir),
                [0, 0],
            )
            .map_or(f64::NAN, |p| p.replicas.len() as f64);
            rows.push(row(
                "height",
                quantity::COUNT_H,
                None,
                hv,
                height,
                f.contacts.len() as f64,
                n,
                1.0,
                0.0,
                true,
            ));
        }
    }
}

/// The field of view: critical angles, the paper scene and a variant with a tall top vHOE whose
/// vertical field ends at TIR and at the Bragg band instead of the aperture.
fn fov_section(rows: &mut Vec<Row>, sys: &System, cf: &ClosedForm) {
    let tol = DETERMINISTIC_REL_TOL;
    let crit = info(sys);
    let n0 = cf.n_glass(cf.design_lambda_nm);
    rows.push(row(
        "fov",
        quantity::CRITICAL,
        None,
        [f64::NAN; 2],
        f64::NAN,
        (1.0 / n0).asin().to_degrees(),
        crit.critical_angle_deg,
        crit.critical_angle_deg,
        tol,
        false,
    ));
    rows.push(row(
        "fov",
        quantity::CRITICAL,
        None,
        [f64::NAN; 2],
        f64::NAN,
        (1.0 / cf.n_film).asin().to_degrees(),
        crit.film_critical_angle_deg,
        crit.film_critical_angle_deg,
        tol,
        false,
    ));
    fov_rows(rows, "paper scene", sys, cf, &crit);
    // Without the weight cut-off: under an 80 mm top vHOE the guided wave loses the
    // out-coupled part at every front contact and would otherwise be truncated (below
    // `min_guided_weight`) before it reaches the bottom vHOE.
    let mut tall = rebuilt(sys, |s| s.top_hoe.height_mm = 80.0);
    tall.limits.min_weight = 0.0;
    let mut cf_tall = cf.clone();
    cf_tall.top_size_mm[1] = 80.0;
    let tall_info = info(&tall);
    fov_rows(rows, "top vHOE 80 mm tall", &tall, &cf_tall, &tall_info);
    // The pure formulas of docs/physics.md §3.4 for the two in-plane edges of the tall variant.
    let tir = cf_tall.tir_edge_vertical_deg();
    let blue = cf_tall.bragg_edge_vertical_deg(cf_tall.band_nm[0])[0];
    for (name, formula, st) in [
        ("TIR formula, top edge", tir, traced_edge(&tall, true, 1.0)),
        (
            "Bragg-band formula, bottom edge",
            blue,
            traced_edge(&tall, true, -1.0),
        ),
    ] {
        let st = st.unwrap_or(f64::NAN);
        let mut r = row(
            "fov",
            quantity::FOV_TRACED,
            None,
            [f64::NAN; 2],
            f64::NAN,
            formula,
            st,
            st,
            tol,
            false,
        );
        r.note = format!("top vHOE 80 mm tall: {name}");
        rows.push(r);
    }
}

fn fov_rows(
    rows: &mut Vec<Row>,
    case: &str,
    sys: &System,
    cf: &ClosedForm,
    inf: &crate::analysis::DesignInfo,
) {
    let step = 0.05;
    let cases = [
        (
            "vertical, waveguide",
            true,
            false,
            &inf.fov_vertical_waveguide,
        ),
        ("vertical, capture", true, true, &inf.fov_vertical_capture),
        (
            "horizontal, waveguide",
            false,
            false,
            &inf.fov_horizontal_waveguide,
        ),
        (
            "horizontal, capture",
            false,
            true,
            &inf.fov_horizontal_capture,
        ),
    ];
    for (axis, vertical, crop, fov) in cases {
        for (sign, edge) in [(-1.0, &fov.min), (1.0, &fov.max)] {
            let (e, lim) = cf.fov_edge_deg(vertical, sign, crop);
            let label = lim.map_or("none", Limit::label);
            // The scan reports the last passing multiple of 0.05°: the closed-form edge lies
            // within one step outward of it.
            let outward = (e - edge.angle_deg) * sign;
            let mut r = row(
                "fov",
                quantity::FOV_INFO,
                None,
                [f64::NAN; 2],
                sign,
                e,
                edge.angle_deg,
                1.0,
                step,
                true,
            );
            r.pass = (-1e-9..step + 1e-9).contains(&outward) && label == edge.limited_by;
            r.note = format!(
                "{case}, {axis}, {} edge: closed form limited by {label}; info: {}",
                if sign < 0.0 { "lower" } else { "upper" },
                edge.limited_by
            );
            rows.push(r);
            if !crop {
                let st = traced_edge(sys, vertical, sign).unwrap_or(f64::NAN);
                let mut r = row(
                    "fov",
                    quantity::FOV_TRACED,
                    None,
                    [f64::NAN; 2],
                    sign,
                    e,
                    st,
                    st,
                    DETERMINISTIC_REL_TOL,
                    false,
                );
                r.note = format!(
                    "{case}, {axis}, {} edge ({label})",
                    if sign < 0.0 { "lower" } else { "upper" }
                );
                rows.push(r);
            }
        }
    }
}

fn summarise(rows: &[Row]) -> Vec<Summary> {
    let mut names: Vec<&str> = Vec::new();
    for r in rows {
        if !names.contains(&r.quantity.as_str()) {
            names.push(&r.quantity);
        }
    }
    names
        .into_iter()
        .map(|q| {
            let rs: Vec<&Row> = rows.iter().filter(|r| r.quantity == q).collect();
            let max_abs = rs.iter().map(|r| r.abs_diff).fold(0.0, f64::max);
            let max_rel = rs.iter().map(|r| r.rel_diff).fold(0.0, f64::max);
            let tolerance = match q {
                quantity::COUNT | quantity::COUNT_H => "exact".to_string(),
                quantity::FOV_INFO => "within one 0.05° scan step outward, same limit".into(),
                quantity::LAMBDA_PEAK => "abs diff ≤ 0.05 nm (physical pull of ν(λ))".into(),
                _ => format!("rel ≤ {DETERMINISTIC_REL_TOL:e}"),
            };
            Summary {
                quantity: q.to_string(),
                rows: rs.len(),
                max_abs_diff: max_abs,
                max_rel_diff: max_rel,
                tolerance,
                pass: rs.iter().all(|r| r.pass),
            }
        })
        .collect()
}

fn fmt(x: f64) -> String {
    if x.is_nan() {
        "–".into()
    } else if x == 0.0 {
        "0".into()
    } else if x.abs() < 1e-3 || x.abs() >= 1e5 {
        format!("{x:.2e}")
    } else {
        format!("{x:.6}")
    }
}

impl AnalyticReport {
    /// Maxima per quantity, then one line per field, the point rows, the heights and the FOV
    /// edges, as Markdown tables.
    pub fn to_markdown(&self) -> String {
        let mut s = String::new();
        self.summary_markdown(&mut s);
        self.fields_markdown(&mut s);
        self.point_markdown(&mut s);
        self.heights_markdown(&mut s);
        self.fov_markdown(&mut s);
        s
    }

    /// The verdict and the maxima per quantity.
    fn summary_markdown(&self, s: &mut String) {
        s.push_str(&format!(
            "Analytic comparison over {} field angles: {}\n\n",
            self.fields_deg.len(),
            if self.pass { "PASS" } else { "FAIL" }
        ));
        s.push_str("| quantity | rows | max abs diff | max rel diff | tolerance | pass |\n");
        s.push_str("|---|---:|---:|---:|---|---|\n");
        for q in &self.summary {
            s.push_str(&format!(
                "| {} | {} | {} | {} | {} | {} |\n",
                q.quantity,
                q.rows,
                fmt(q.max_abs_diff),
                fmt(q.max_rel_diff),
                q.tolerance,
                if q.pass { "yes" } else { "NO" }
            ));
        }
    }

    /// One line per field: the closed form and the largest relative difference.
    fn fields_markdown(&self, s: &mut String) {
        s.push_str(
            "\n### Per field (closed form; max rel diff of λ_B, Θ', pitch against the tracer)\n\n",
        );
        s.push_str("| # | h (°) | v (°) | λ_B (nm) | peak − λ_B (nm) | Θ' (°) | pitch (mm) | replicas cf/traced | max rel diff |\n");
        s.push_str("|---:|---:|---:|---:|---:|---:|---:|---|---:|\n");
        for (i, hv) in self.fields_deg.iter().enumerate() {
            let rs: Vec<&Row> = self.rows.iter().filter(|r| r.field == Some(i)).collect();
            let get = |q: &str| rs.iter().find(|r| r.quantity == q);
            let cfv = |q: &str| get(q).map_or(f64::NAN, |r| r.closed_form);
            let stv = |q: &str| get(q).map_or(f64::NAN, |r| r.stscam);
            let maxrel = rs
                .iter()
                .filter(|r| {
                    [
                        quantity::LAMBDA_B,
                        quantity::GUIDED,
                        quantity::PITCH,
                        quantity::OBJECT0,
                    ]
                    .contains(&r.quantity.as_str())
                })
                .map(|r| r.rel_diff)
                .fold(0.0, f64::max);
            s.push_str(&format!(
                "| {i} | {:.3} | {:.3} | {:.6} | {} | {:.6} | {:.6} | {}/{} | {} |\n",
                hv[0],
                hv[1],
                cfv(quantity::LAMBDA_B),
                fmt(stv(quantity::LAMBDA_PEAK)),
                cfv(quantity::GUIDED),
                cfv(quantity::PITCH),
                cfv(quantity::COUNT),
                stv(quantity::COUNT),
                fmt(maxrel)
            ));
        }
    }

    /// The sensor rows of the point at the display centre.
    fn point_markdown(&self, s: &mut String) {
        s.push_str("\n### Sensor rows of a point at the display centre\n\n");
        s.push_str(
            "| contact | row closed form | row traced | abs diff (px) |\n|---:|---:|---:|---:|\n",
        );
        for r in self.rows.iter().filter(|r| r.section == "point") {
            s.push_str(&format!(
                "| {} | {:.6} | {:.6} | {} |\n",
                r.param,
                r.closed_form,
                r.stscam,
                fmt(r.abs_diff)
            ));
        }
    }

    /// The replica counts, one line per bottom-vHOE height, one column per field.
    fn heights_markdown(&self, s: &mut String) {
        s.push_str("\n### Replica count against bottom-vHOE height (closed form / traced)\n\n");
        let hv: Vec<[f64; 2]> = {
            let mut v: Vec<[f64; 2]> = Vec::new();
            for r in self.rows.iter().filter(|r| r.section == "height") {
                let k = [r.field_h_deg, r.field_v_deg];
                if !v.contains(&k) {
                    v.push(k);
                }
            }
            v
        };
        s.push_str("| height (mm) |");
        for k in &hv {
            s.push_str(&format!(" h {:.2}°, v {:.2}° |", k[0], k[1]));
        }
        s.push_str("\n|---:|");
        for _ in &hv {
            s.push_str("---|");
        }
        s.push('\n');
        let mut heights: Vec<f64> = Vec::new();
        for r in self.rows.iter().filter(|r| r.section == "height") {
            if !heights.contains(&r.param) {
                heights.push(r.param);
            }
        }
        for h in heights {
            s.push_str(&format!("| {h} |"));
            for k in &hv {
                if let Some(r) = self.rows.iter().find(|r| {
                    r.section == "height"
                        && r.param == h
                        && r.field_h_deg == k[0]
                        && r.field_v_deg == k[1]
                }) {
                    s.push_str(&format!(" {}/{} |", r.closed_form, r.stscam));
                }
            }
            s.push('\n');
        }
    }

    /// The field-of-view rows.
    fn fov_markdown(&self, s: &mut String) {
        s.push_str("\n### Field of view\n\n| what | closed form (°) | stscam (°) | abs diff (°) | pass |\n|---|---:|---:|---:|---|\n");
        for r in self.rows.iter().filter(|r| r.section == "fov") {
            let what = if r.note.is_empty() {
                r.quantity.clone()
            } else {
                format!("{}: {}", r.quantity, r.note)
            };
            s.push_str(&format!(
                "| {} | {:.9} | {:.9} | {} | {} |\n",
                what,
                r.closed_form,
                r.stscam,
                fmt(r.abs_diff),
                if r.pass { "yes" } else { "NO" }
            ));
        }
    }

    /// Every row as CSV (header line first).
    pub fn to_csv(&self) -> String {
        let mut s = String::from(
            "section,quantity,field,field_h_deg,field_v_deg,param,closed_form,stscam,abs_diff,rel_diff,tolerance,pass,note\n",
        );
        let q = |t: &str| format!("\"{}\"", t.replace('"', "\"\""));
        for r in &self.rows {
            s.push_str(&format!(
                "{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
                r.section,
                q(&r.quantity),
                r.field.map_or(String::new(), |f| f.to_string()),
                r.field_h_deg,
                r.field_v_deg,
                r.param,
                r.closed_form,
                r.stscam,
                r.abs_diff,
                r.rel_diff,
                r.tolerance,
                r.pass,
                q(&r.note)
            ));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_grating(sets: &[&str]) -> System {
        crate::system::repo_system("scenes/two-grating.toml", sets)
    }

    /// The "multiplex" rows: each grating of the film traced with the other present has the
    /// geometry of the grating alone (exactly); against a grating 0.01° off (the failing
    /// input) the same rows fail.
    #[test]
    fn multiplexed_geometry_is_each_grating_alone() {
        let sys = two_grating(&[]);
        for j in 0..2 {
            let d = sys.scene.hoe.gratings()[j].clone();
            let alone = rebuilt(&sys, |s| s.hoe.grating = vec![d.clone()]);
            let rows = multiplex_rows(&sys, &alone, j);
            assert!(rows.len() >= 60, "{}", rows.len());
            assert!(rows.iter().all(|r| r.pass), "grating {j}");
            let mut off = d.clone();
            off.reference_angle_deg += 0.01;
            let wrong = rebuilt(&sys, |s| s.hoe.grating = vec![off]);
            let rows = multiplex_rows(&sys, &wrong, j);
            assert!(
                rows.iter().filter(|r| !r.pass).count() > rows.len() / 2,
                "grating {j}: a 0.01° error must fail"
            );
        }
    }
}
