//! The outputs of a sweep: `sweep.csv`, `sweep.json` (with the definitions) and one line plot
//! per quantity against the first axis (PNG and SVG), with their number formatting.

use std::fmt::Write as _;

use super::{
    DesignFigures, GratingFigures, REPLICA_FRACTION, SweepError, SweepRow, SweepSettings, VaryAxis,
};
use crate::analysis::Fov;
use crate::plot::{LinePlot, Series};
use crate::scene::SceneSource;

/// Definitions recorded in `sweep.json` (the module header in short).
pub const DEFINITIONS: &[(&str, &str)] = &[
    (
        "field_response",
        "T(d) = integral of S(lambda) Rbar(lambda) W(d, lambda) dlambda / integral over the sampling band of S Rbar dlambda, for the chief ray from the lens centre along d; W = sum over all out-coupled replica branches of the display-polarisation-weighted TE/TM branch weights (Fresnel, Kogelnik efficiencies of both vHOEs at every bounce, TIR, glass absorption); S = display spectrum, Rbar = mean of the sensor channel responses; straight-through light and the lens cos^4 falloff are excluded; midpoint sums over lambda_B +- bragg_half_width_nm (bragg_step_nm bins) or, without a Bragg wavelength, the whole band (broadband_step_nm bins)",
    ),
    (
        "fov",
        "vertical: d = (0, sin t, -cos t), horizontal: d = (sin t, 0, -cos t), t the field angle in air on a grid of angle_step_deg over +-angle_max_deg; the contiguous interval where T >= fov_fraction * max T containing 0 deg (else the first maximum), edges linearly interpolated; full_deg = max - min; limited_by, judged at the first grid angle beyond the edge (out) against the grid maximum (peak): the geometric blocker of `stscam info` at out if any; else with T_out/T_peak = s b, s = ratio of S Rbar at the Bragg wavelengths, b = waveguide ratio: the display spectrum x sensor response if s < b, else the top vHOE re-coupling if the guided path at out has more front-face contacts under the top vHOE than at peak, else the bottom vHOE if out has fewer replicas >= 5 %, else 'Bragg/Kogelnik efficiency falloff'",
    ),
    (
        "fov_capture",
        "the FOV intersected with the field angles whose chief rays land inside the sensor crop ('sensor crop' where the crop binds)",
    ),
    (
        "scene_field",
        "the part of the display plane the capture sees: chief rays of the capture FOV along the axis (angle_step_deg apart) traced at their Bragg wavelengths; object points of the replicas carrying >= 5 % of each ray's strongest; min_mm/max_mm from the bottom vHOE centre, extent_mm, and full_deg = the angle the extent subtends at the bottom vHOE centre at the display distance. Taller bottom vHOEs add replicas, which widen it: the paper's dilemma",
    ),
    (
        "geometric_fov",
        "full FOV of the waveguide from `stscam info` (chief rays at their Bragg wavelength, 0.05 deg steps, no throughput threshold)",
    ),
    (
        "replicas",
        "chief ray of the crop's centre pixel at its Bragg wavelength (`stscam info`, field 'centre'): replicas_total = out-coupling bottom-vHOE contacts, replicas_above_5pct = those with at least 5 % of the strongest's weight",
    ),
    (
        "replica_pitch",
        "replica_pitch_mm = 2 w tan(guided angle) of the centre field on the display side; replica_pitch_sensor_px = mean sensor spacing of the >= 5 % replicas of a point at the display centre (NaN with fewer than two)",
    ),
    (
        "efficiency",
        "fractions of the display light reaching the sensor through the waveguide: efficiency_peak = max T over both field scans, efficiency_on_axis = T(0 deg), efficiency_crop_mean = mean T over the chief rays of a crop_grid x crop_grid grid of cell centres over the sensor crop",
    ),
    (
        "bragg_range",
        "min and max exact Bragg wavelength (nm) over the same crop grid's chief rays",
    ),
    (
        "psnr",
        "the demo's protocol: H at spp and seed, the target rendered with seed + 1, sensor noise with the exposure from the all-white capture H 1 + o and a noisy dark frame subtracted, ADMM-TV (50 iterations) with tau by the discrepancy principle on the sensor noise (recon::discrepancy); PSNR (peak 1) of the reconstruction clipped to [0, 1] against the linear target",
    ),
];

/// Unit of a scene key from its suffix, for axis labels.
fn key_unit(key: &str) -> Option<&'static str> {
    // `_per_mm` before `_mm`: the first matching suffix wins.
    [
        ("_per_mm", "1/mm"),
        ("_mm", "mm"),
        ("_deg", "deg"),
        ("_um", "um"),
        ("_nm", "nm"),
        ("_px", "px"),
        ("_e", "e-"),
        ("_dn", "DN"),
    ]
    .iter()
    .find(|(s, _)| key.ends_with(s))
    .map(|(_, u)| *u)
}

fn axis_label(key: &str) -> String {
    match key_unit(key) {
        Some(u) => format!("{key} ({u})"),
        None => key.to_string(),
    }
}

/// A float with six significant digits (fixed notation for 1e-4 ≤ |v| < 1e6), `NaN` for NaN.
fn fmt_num(v: f64) -> String {
    if v.is_nan() {
        return "NaN".into();
    }
    if v == 0.0 || v.is_infinite() {
        return format!("{v}");
    }
    let mag = v.abs().log10().floor() as i32;
    if (-4..6).contains(&mag) {
        format!("{v:.*}", (5 - mag).max(0) as usize)
    } else {
        format!("{v:.5e}")
    }
}

fn csv_text(s: &str) -> String {
    format!("\"{}\"", s.replace('"', "\"\""))
}

/// One numeric figure of a row.
type Figure = fn(&DesignFigures) -> f64;

/// Flattened CSV columns: (header, value of a row).
type Column = (String, Box<dyn Fn(&SweepRow) -> String>);

fn csv_columns(axes: &[VaryAxis], with_psnr: bool) -> Vec<Column> {
    let mut cols: Vec<Column> = Vec::new();
    for (i, a) in axes.iter().enumerate() {
        cols.push((
            a.key.clone(),
            Box::new(move |r| format!("{}", r.varied[i].value)),
        ));
    }
    type FovOf = fn(&DesignFigures) -> &Fov;
    let fovs: [(&str, FovOf); 4] = [
        ("fov_vertical", |f| &f.fov_vertical),
        ("fov_horizontal", |f| &f.fov_horizontal),
        ("fov_vertical_capture", |f| &f.fov_vertical_capture),
        ("fov_horizontal_capture", |f| &f.fov_horizontal_capture),
    ];
    for (name, get) in fovs {
        cols.push((
            format!("{name}_deg"),
            Box::new(move |r| fmt_num(get(&r.figures).full_deg)),
        ));
        cols.push((
            format!("{name}_min_deg"),
            Box::new(move |r| fmt_num(get(&r.figures).min.angle_deg)),
        ));
        cols.push((
            format!("{name}_max_deg"),
            Box::new(move |r| fmt_num(get(&r.figures).max.angle_deg)),
        ));
        cols.push((
            format!("{name}_min_limited_by"),
            Box::new(move |r| csv_text(&get(&r.figures).min.limited_by)),
        ));
        cols.push((
            format!("{name}_max_limited_by"),
            Box::new(move |r| csv_text(&get(&r.figures).max.limited_by)),
        ));
    }
    let nums: [(&str, Figure); 15] = [
        ("scene_field_vertical_mm", |f| {
            f.scene_field_vertical.extent_mm
        }),
        ("scene_field_vertical_deg", |f| {
            f.scene_field_vertical.full_deg
        }),
        ("scene_field_horizontal_mm", |f| {
            f.scene_field_horizontal.extent_mm
        }),
        ("scene_field_horizontal_deg", |f| {
            f.scene_field_horizontal.full_deg
        }),
        ("geometric_fov_vertical_deg", |f| {
            f.geometric_fov_vertical_deg
        }),
        ("geometric_fov_horizontal_deg", |f| {
            f.geometric_fov_horizontal_deg
        }),
        ("replica_pitch_mm", |f| f.replica_pitch_mm),
        ("replica_pitch_sensor_px", |f| f.replica_pitch_sensor_px),
        ("efficiency_peak", |f| f.efficiency_peak),
        ("efficiency_on_axis", |f| f.efficiency_on_axis),
        ("efficiency_crop_mean", |f| f.efficiency_crop_mean),
        ("bragg_min_nm", |f| f.bragg_min_nm),
        ("bragg_max_nm", |f| f.bragg_max_nm),
        ("psnr_db", |f| f.psnr_db.unwrap_or(f64::NAN)),
        ("psnr_nominal_h_db", |f| {
            f.psnr_nominal_h_db.unwrap_or(f64::NAN)
        }),
    ];
    cols.push((
        "replicas_above_5pct".into(),
        Box::new(|r| r.figures.replicas_above_5pct.to_string()),
    ));
    cols.push((
        "replicas_total".into(),
        Box::new(|r| r.figures.replicas_total.to_string()),
    ));
    for (name, get) in nums {
        if name.starts_with("psnr") && !with_psnr {
            continue;
        }
        cols.push((
            name.to_string(),
            Box::new(move |r| fmt_num(get(&r.figures))),
        ));
    }
    cols
}

fn encode_csv(axes: &[VaryAxis], rows: &[SweepRow], with_psnr: bool) -> Vec<u8> {
    let mut cols = csv_columns(axes, with_psnr);
    // A multiplexed film: per-grating columns NAME_gJ.
    let n_gratings = rows
        .iter()
        .map(|r| r.figures.per_grating.len())
        .max()
        .unwrap_or(0);
    type PerGrating = fn(&GratingFigures) -> f64;
    let per: [(&str, PerGrating); 4] = [
        ("bragg_min_nm", |g| g.bragg_min_nm),
        ("bragg_max_nm", |g| g.bragg_max_nm),
        ("efficiency_on_axis", |g| g.efficiency_on_axis),
        ("efficiency_crop_mean", |g| g.efficiency_crop_mean),
    ];
    for j in 0..n_gratings {
        for (name, get) in per {
            cols.push((
                format!("{name}_g{j}"),
                Box::new(move |r: &SweepRow| {
                    r.figures
                        .per_grating
                        .get(j)
                        .map_or(String::new(), |g| fmt_num(get(g)))
                }),
            ));
        }
    }
    let mut s = cols
        .iter()
        .map(|c| c.0.as_str())
        .collect::<Vec<_>>()
        .join(",");
    s.push('\n');
    for r in rows {
        let line: Vec<String> = cols.iter().map(|c| (c.1)(r)).collect();
        let _ = writeln!(s, "{}", line.join(","));
    }
    s.into_bytes()
}

/// One plotted quantity: file stem, title, y label and its curves (name, value of a row).
struct Quantity {
    stem: &'static str,
    title: &'static str,
    y_label: &'static str,
    parts: Vec<(&'static str, Figure)>,
}

fn quantities(with_psnr: bool) -> Vec<Quantity> {
    let mut q = vec![
        Quantity {
            stem: "fov",
            title: "Throughput FOV",
            y_label: "full angle (deg)",
            parts: vec![
                ("vertical", |f| f.fov_vertical.full_deg),
                ("horizontal", |f| f.fov_horizontal.full_deg),
            ],
        },
        Quantity {
            stem: "fov_capture",
            title: "Capture FOV (throughput FOV within the crop)",
            y_label: "full angle (deg)",
            parts: vec![
                ("vertical", |f| f.fov_vertical_capture.full_deg),
                ("horizontal", |f| f.fov_horizontal_capture.full_deg),
            ],
        },
        Quantity {
            stem: "scene_field",
            title: "Scene field: display region seen through strong replicas",
            y_label: "full angle at the plate (deg)",
            parts: vec![
                ("vertical", |f| f.scene_field_vertical.full_deg),
                ("horizontal", |f| f.scene_field_horizontal.full_deg),
            ],
        },
        Quantity {
            stem: "replicas",
            title: "Replicas of the centre field",
            y_label: "count",
            parts: vec![
                ("at least 5 % of the strongest", |f| {
                    f.replicas_above_5pct as f64
                }),
                ("total", |f| f.replicas_total as f64),
            ],
        },
        Quantity {
            stem: "replica_pitch_mm",
            title: "Replica pitch on the display (centre field)",
            y_label: "pitch (mm)",
            parts: vec![("2w tan(guided angle)", |f| f.replica_pitch_mm)],
        },
        Quantity {
            stem: "replica_pitch_px",
            title: "Replica pitch on the sensor",
            y_label: "pitch (px)",
            parts: vec![("replicas of at least 5 %", |f| f.replica_pitch_sensor_px)],
        },
        Quantity {
            stem: "efficiency",
            title: "Display-to-sensor efficiency",
            y_label: "fraction of display light",
            parts: vec![
                ("peak", |f| f.efficiency_peak),
                ("on axis", |f| f.efficiency_on_axis),
                ("crop mean", |f| f.efficiency_crop_mean),
            ],
        },
        Quantity {
            stem: "bragg_range",
            title: "Bragg wavelength across the capture field",
            y_label: "wavelength (nm)",
            parts: vec![("min", |f| f.bragg_min_nm), ("max", |f| f.bragg_max_nm)],
        },
    ];
    if with_psnr {
        q.push(Quantity {
            stem: "psnr",
            title: "ADMM-TV PSNR",
            y_label: "PSNR (dB)",
            parts: vec![
                ("ADMM-TV, H of the point", |f| f.psnr_db.unwrap_or(f64::NAN)),
                ("ADMM-TV, H of the base scene", |f| {
                    f.psnr_nominal_h_db.unwrap_or(f64::NAN)
                }),
            ],
        });
    }
    q
}

/// Most curves one panel holds: beyond it the colours and dashes would repeat.
const MAX_CURVES: usize = 12;
/// Most panels of one quantity's small multiples (the rest are in `sweep.csv`).
pub const MAX_PANELS: usize = 36;

/// The panels of one quantity against the first axis (docs/sweeps.md, "Plots"): with the
/// second axis as curves (one per value and part) when that stays within [`MAX_CURVES`], and
/// one panel per combination of the remaining axes; a sweep over one or two axes is one panel.
/// Returns the panels (at most [`MAX_PANELS`]) and how many there would be.
fn quantity_panels(axes: &[VaryAxis], rows: &[SweepRow], q: &Quantity) -> (Vec<LinePlot>, usize) {
    let n_first = axes[0].steps;
    let combos = rows.len() / n_first.max(1);
    let parts = q.parts.len();
    // The second axis as curves, or every other axis as panels.
    let curves_axis = axes.len() >= 2 && parts * axes[1].steps <= MAX_CURVES;
    let per_panel = if curves_axis { axes[1].steps } else { 1 };
    let n_panels = combos / per_panel.max(1);
    let panel_axes = if curves_axis { 2 } else { 1 };
    let label = |j: usize, from: usize, to: usize| -> Vec<String> {
        rows[j].varied[from..to]
            .iter()
            .map(|v| format!("{}={}", v.key, v.value))
            .collect()
    };
    let panels = (0..n_panels.min(MAX_PANELS))
        .map(|k| {
            let mut series = Vec::new();
            for c in 0..per_panel {
                // Combination index of the other axes (second axis slowest among them).
                let j = c * n_panels + k;
                let curve = if curves_axis {
                    label(j, 1, 2)
                } else {
                    Vec::new()
                };
                for (name, get) in &q.parts {
                    let mut l: Vec<String> = Vec::new();
                    if parts > 1 || curve.is_empty() {
                        l.push((*name).to_string());
                    }
                    l.extend(curve.iter().cloned());
                    series.push(Series {
                        name: l.join(", "),
                        points: (0..n_first)
                            .map(|i| {
                                let r = &rows[i * combos + j];
                                (r.varied[0].value, get(&r.figures))
                            })
                            .collect(),
                    });
                }
            }
            let rest = label(k, panel_axes, axes.len());
            LinePlot {
                title: if rest.is_empty() {
                    q.title.to_string()
                } else {
                    rest.join(", ")
                },
                x_label: axis_label(&axes[0].key),
                y_label: q.y_label.to_string(),
                log_x: false,
                log_y: false,
                series,
                h_line: None,
            }
        })
        .collect();
    (panels, n_panels)
}

pub(super) fn encode_outputs(
    scene: SceneSource<'_>,
    base_overrides: &[String],
    axes: &[VaryAxis],
    set: &SweepSettings,
    rows: &[SweepRow],
) -> Result<Vec<(String, Vec<u8>)>, SweepError> {
    let with_psnr = set.psnr.is_some();
    let mut files = vec![("sweep.csv".to_string(), encode_csv(axes, rows, with_psnr))];
    let json = serde_json::json!({
        "stscam_version": crate::VERSION,
        "command": "sweep",
        "scene": match scene {
            SceneSource::File(p) => p.map_or_else(|| crate::scene::EMBEDDED_NAME.to_string(), |p| p.display().to_string()),
            SceneSource::Text(_, name, _) => name.to_string(),
        },
        "base_overrides": base_overrides,
        "axes": axes.iter().map(|a| serde_json::json!({
            "key": a.key, "start": a.start, "stop": a.stop, "steps": a.steps, "values": a.values(),
        })).collect::<Vec<_>>(),
        "settings": {
            "fov_fraction": set.fov_fraction,
            "replica_fraction": REPLICA_FRACTION,
            "grid": set.grid,
            "psnr": set.psnr.as_ref().map(|p| serde_json::json!({
                "target": p.target, "spp": p.spp, "seed": p.seed, "capture_seed": p.seed.wrapping_add(1),
                "reconstruction": "admm-tv, default settings",
            })),
        },
        "definitions": DEFINITIONS.iter().map(|(k, v)| ((*k).to_string(), serde_json::Value::from(*v))).collect::<serde_json::Map<_, _>>(),
        "rows": rows,
    });
    files.push((
        "sweep.json".to_string(),
        serde_json::to_vec_pretty(&json).map_err(|e| SweepError::Output(e.to_string()))?,
    ));
    for q in quantities(with_psnr) {
        let (mut panels, n) = quantity_panels(axes, rows, &q);
        let mut title = q.title.to_string();
        if q.stem.starts_with("fov") {
            let _ = write!(title, " (T >= {} of peak)", set.fov_fraction);
        }
        let (png, svg) = if let [plot] = panels.as_mut_slice() {
            plot.title = title;
            (plot.to_png(), plot.to_svg())
        } else {
            if n > panels.len() {
                let _ = write!(
                    title,
                    " (first {} of {n} panels; all in sweep.csv)",
                    panels.len()
                );
            }
            let cols = (panels.len() as f64).sqrt().ceil() as usize;
            (
                crate::plot::grid_png(&title, &panels, cols),
                crate::plot::grid_svg(&title, &panels, cols),
            )
        };
        files.push((format!("{}.png", q.stem), png.map_err(SweepError::Output)?));
        files.push((format!("{}.svg", q.stem), svg.into_bytes()));
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn number_formatting_is_stable() {
        assert_eq!(fmt_num(33.4), "33.4000");
        assert_eq!(fmt_num(0.0123456789), "0.0123457");
        assert_eq!(fmt_num(-16.75), "-16.7500");
        assert_eq!(fmt_num(1.5e-7), "1.50000e-7");
        assert_eq!(fmt_num(f64::NAN), "NaN");
        assert_eq!(fmt_num(0.0), "0");
        assert_eq!(
            axis_label("bottom_hoe.height_mm"),
            "bottom_hoe.height_mm (mm)"
        );
        assert_eq!(
            axis_label("hoe.amplitude_absorption_per_mm"),
            "hoe.amplitude_absorption_per_mm (1/mm)"
        );
        assert_eq!(axis_label("hoe.index_modulation"), "hoe.index_modulation");
    }

    /// A 4 x 3 x 2 grid: the second axis becomes curves, the third panels, and each curve
    /// holds the values of its own grid points (a row index mixed up fails the point check).
    #[test]
    fn three_axes_make_small_multiples_with_the_right_points() {
        let sys =
            crate::system::System::build(&crate::scene::load_scene(None, &[]).unwrap()).unwrap();
        let base = super::super::design_figures(&sys, &SweepSettings::default());
        let axes: Vec<VaryAxis> = [("a", 4), ("b", 3), ("c", 2)]
            .iter()
            .map(|&(k, n)| VaryAxis {
                key: k.into(),
                start: 0.0,
                stop: (n - 1) as f64,
                steps: n,
            })
            .collect();
        let mut rows = Vec::new();
        for a in 0..4 {
            for b in 0..3 {
                for c in 0..2 {
                    let mut f = base.clone();
                    // The value encodes the grid point.
                    f.efficiency_peak = (100 * a + 10 * b + c) as f64;
                    rows.push(SweepRow {
                        varied: [("a", a), ("b", b), ("c", c)]
                            .iter()
                            .map(|&(k, v)| super::super::VariedValue {
                                key: k.into(),
                                value: v as f64,
                            })
                            .collect(),
                        figures: f,
                    });
                }
            }
        }
        let q = quantities(false)
            .into_iter()
            .find(|q| q.stem == "efficiency")
            .unwrap();
        let (panels, n) = quantity_panels(&axes, &rows, &q);
        assert_eq!((panels.len(), n), (2, 2));
        for (c, p) in panels.iter().enumerate() {
            assert_eq!(p.title, format!("c={c}"));
            assert_eq!(p.series.len(), 3 * 3);
            for (i, s) in p.series.iter().enumerate() {
                let b = i / 3;
                if i % 3 == 0 {
                    assert_eq!(s.name, format!("peak, b={b}"));
                    let want: Vec<(f64, f64)> = (0..4)
                        .map(|a| (a as f64, (100 * a + 10 * b + c) as f64))
                        .collect();
                    assert_eq!(s.points, want);
                }
            }
        }
        // Too many curves for the second axis (3 parts x 5 values > 12): every other axis
        // makes panels, one curve per part.
        let mut wide = axes.clone();
        wide[1].steps = 5;
        let rows5: Vec<SweepRow> = (0..4 * 5 * 2)
            .map(|i| rows[i % rows.len()].clone())
            .collect();
        let (panels, n) = quantity_panels(&wide, &rows5, &q);
        assert_eq!((n, panels[0].series.len()), (10, 3));
        assert_eq!(panels[0].title, "b=0, c=0");
    }
}
