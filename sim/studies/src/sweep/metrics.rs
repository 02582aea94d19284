//! The geometry and colour metrics of one design by name: the deterministic part of `stscam
//! evaluate` (its metric names), also drawn per fabrication draw by `stscam tolerance` and a
//! study's yield. Every value comes from [`design_figures`](super::design_figures) with the
//! default [`SweepSettings`](super::SweepSettings) (definitions in the module notes of
//! `sweep`), except the colour band coverage: the fraction of the crop's field rows whose best
//! grating has a band in the primary (`colour::field_bands` at [`BAND_ROWS`] rows; NaN for a
//! monochrome display).

use crate::system::System;

/// Field rows sampled for the colour band coverage.
pub const BAND_ROWS: usize = 64;

/// The metric names, in the order [`geometry_metrics`] returns them.
pub const GEOMETRY_METRICS: [&str; 14] = [
    "fov_capture_vertical_deg",
    "fov_capture_horizontal_deg",
    "fov_waveguide_vertical_deg",
    "fov_waveguide_horizontal_deg",
    "scene_field_vertical_mm",
    "scene_field_vertical_deg",
    "replicas_5pct",
    "replicas_all",
    "replica_pitch_mm",
    "efficiency_peak",
    "efficiency_mean",
    "band_coverage_r",
    "band_coverage_g",
    "band_coverage_b",
];

/// The geometry and colour metrics of `sys`, named as [`GEOMETRY_METRICS`] and in its order.
pub fn geometry_metrics(sys: &System) -> Vec<(&'static str, f64)> {
    let f = super::design_figures(sys, &super::SweepSettings::default());
    let bands = if sys.display.planes() == 3 {
        crate::colour::field_bands(sys, BAND_ROWS)
    } else {
        Vec::new()
    };
    let coverage = |p: usize| {
        if bands.is_empty() {
            f64::NAN
        } else {
            bands.iter().filter(|r| r.has_band(p)).count() as f64 / bands.len() as f64
        }
    };
    let values = [
        f.fov_vertical_capture.full_deg,
        f.fov_horizontal_capture.full_deg,
        f.fov_vertical.full_deg,
        f.fov_horizontal.full_deg,
        f.scene_field_vertical.extent_mm,
        f.scene_field_vertical.full_deg,
        f.replicas_above_5pct as f64,
        f.replicas_total as f64,
        f.replica_pitch_mm,
        f.efficiency_peak,
        f.efficiency_crop_mean,
        coverage(0),
        coverage(1),
        coverage(2),
    ];
    GEOMETRY_METRICS.into_iter().zip(values).collect()
}
