//! Run time against error: renders at increasing sample counts for each estimator, each timed
//! (wall clock, whole render) and compared with a high-spp reference by relative RMSE; the time
//! to 1 % error is read off each curve.
//!
//! Time to a target error: log-log interpolation between the two measurements that bracket it;
//! if a curve never reaches it within the budget, it is extrapolated from the last measurement
//! with the Monte Carlo rate RMSE ∝ t^(−1/2) (and marked as extrapolated).

use std::time::Instant;

use crate::render::camera_table::{CameraTable, TableSettings};
use crate::render::{Estimator, RenderSettings, UserSideSampler, relative_rmse, render};
use crate::sampler::SamplerKind;
use crate::system::System;

/// One measured point.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Point {
    /// Samples per pixel.
    pub spp: u32,
    /// Wall time of the render, s.
    pub seconds: f64,
    /// Relative RMSE against the reference.
    pub relative_rmse: f64,
}

/// A curve of one estimator (or renderer).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Curve {
    /// Name.
    pub name: String,
    /// Points in increasing spp.
    pub points: Vec<Point>,
    /// Time to the target error, s.
    pub seconds_to_target: Option<f64>,
    /// Whether that time was extrapolated.
    pub extrapolated: bool,
    /// Time spent once before the curve's renders (the camera-side table), s; not in the
    /// points' times, which are each further scene's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub precompute_seconds: Option<f64>,
}

/// Time at which a curve reaches `target` (interpolated in log-log, or extrapolated with
/// slope −1/2 from the last point).
pub fn time_to_error(points: &[Point], target: f64) -> Option<(f64, bool)> {
    let ok: Vec<&Point> = points
        .iter()
        .filter(|p| p.relative_rmse.is_finite() && p.relative_rmse > 0.0 && p.seconds > 0.0)
        .collect();
    for w in ok.windows(2) {
        let (a, b) = (w[0], w[1]);
        if a.relative_rmse > target && b.relative_rmse <= target {
            let (la, lb) = (a.relative_rmse.ln(), b.relative_rmse.ln());
            let t = (target.ln() - la) / (lb - la);
            return Some((
                (a.seconds.ln() + t * (b.seconds.ln() - a.seconds.ln())).exp(),
                false,
            ));
        }
    }
    if let Some(first) = ok.first()
        && first.relative_rmse <= target
    {
        return Some((first.seconds, false));
    }
    let last = ok.last()?;
    // RMSE ∝ t^(−1/2) ⇒ t = t_last · (e_last / target)².
    Some((last.seconds * (last.relative_rmse / target).powi(2), true))
}

/// How the error of a render is measured (`bench render --error`; one definition for clap and
/// serde).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ErrorMeasure {
    /// Relative RMSE against a high-spp reference of the same estimator family.
    Reference,
    /// From two independent renders A, B of spp/2 each: ‖A − B‖/‖A + B‖ estimates the relative
    /// RMS Monte Carlo error of their mean (unbiased estimators; needs no reference, and is the
    /// same measure the Mitsuba script uses).
    Halves,
}

fn timed_render(
    sys: &System,
    spp: u32,
    seed: u64,
    estimator: Estimator,
    (sampler, user_side, adaptive): (SamplerKind, UserSideSampler, bool),
    table: Option<&CameraTable>,
) -> (Vec<Vec<f32>>, f64) {
    let set = RenderSettings {
        spp,
        seed,
        sampler,
        user_side,
        spectral_bins: None,
        progress: false,
        estimator,
        adaptive,
    };
    let t0 = Instant::now();
    let cap = match table {
        // A table drawn for `sys` by `measure_curve` suits its renders.
        Some(t) => crate::render::camera_table::render_with_table(sys, &set, t)
            .map_or_else(|_| Vec::new(), |c| c.channels),
        None => render(sys, &set).channels,
    };
    (cap, t0.elapsed().as_secs_f64())
}

/// Which sample sequence a curve renders with at each sample count.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CurveSampler {
    /// The same kind at every spp.
    Kind(SamplerKind),
    /// The default lattice with every branch of every camera sample traced on the user side
    /// (`UserSideSampler::Padded`: the previous 3-D default, CHANGELOG.md).
    EveryBranch,
    /// 3-D scenes: the camera side from a table drawn once with these settings (its seed
    /// replaced per render: 7 and, for `Halves`, 8), spp = user-side paths per pixel.
    CameraTable(TableSettings),
    /// The default lattice with adaptive sample counts (`render --adaptive`; spp = the mean,
    /// from [`crate::render::adaptive::MIN_ADAPTIVE_SPP`] on).
    Adaptive,
}

impl CurveSampler {
    /// The sampler kind, the user side's estimator and whether the counts are adaptive.
    pub fn kinds(self) -> (SamplerKind, UserSideSampler, bool) {
        match self {
            CurveSampler::Kind(k) => (k, UserSideSampler::Auto, false),
            CurveSampler::EveryBranch => (SamplerKind::Lattice, UserSideSampler::Padded, false),
            CurveSampler::CameraTable(_) => (SamplerKind::Lattice, UserSideSampler::Auto, false),
            CurveSampler::Adaptive => (SamplerKind::Lattice, UserSideSampler::Auto, true),
        }
    }
}

/// Renders `sys` at spp 1, 2, 4, … (2, 4, … for `Halves`) with `estimator` and `sampler` until `budget_s`
/// seconds have been spent (or `max_spp`), measuring each render's error. With `progress`,
/// the seconds of the budget spent are shown (see [`crate::progress`]).
#[allow(clippy::too_many_arguments)]
pub fn measure_curve(
    sys: &System,
    estimator: Estimator,
    sampler: CurveSampler,
    name: &str,
    reference: &[Vec<f32>],
    measure: ErrorMeasure,
    budget_s: f64,
    max_spp: u32,
    target: f64,
    progress: bool,
) -> Curve {
    let pb = crate::progress::Progress::new(
        progress,
        budget_s.ceil() as u64,
        &format!("{name}: seconds of the budget"),
    );
    // The camera-side tables, drawn before the curve (their time reported apart).
    let t_pre = Instant::now();
    // Tables per curve (one per half); a table curve whose tables could not be drawn has no
    // points (rather than the direct estimator's under its name).
    let wanted = match sampler {
        CurveSampler::CameraTable(_) if measure == ErrorMeasure::Halves => 2,
        CurveSampler::CameraTable(_) => 1,
        _ => 0,
    };
    let tables: Vec<CameraTable> = match sampler {
        CurveSampler::CameraTable(ts) => [7u64, 8]
            .iter()
            .take(wanted)
            .filter_map(|&seed| {
                crate::render::camera_table::build(sys, &TableSettings { seed, ..ts }, false).ok()
            })
            .collect(),
        _ => Vec::new(),
    };
    let precompute_seconds =
        (!tables.is_empty()).then(|| t_pre.elapsed().as_secs_f64() / tables.len() as f64);
    let (table_a, table_b) = (tables.first(), tables.get(1));
    let max_spp = if tables.len() < wanted { 0 } else { max_spp };
    let mut points = Vec::new();
    let mut spent = 0.0;
    let halves = if measure == ErrorMeasure::Halves {
        2u32
    } else {
        1
    };
    // An adaptive curve starts where renders are adaptive (below, they are the default's).
    let mut spp = if sampler == CurveSampler::Adaptive {
        halves * crate::render::adaptive::MIN_ADAPTIVE_SPP
    } else {
        halves
    };
    while spp <= max_spp && spent < budget_s {
        let (seconds, err) = match measure {
            ErrorMeasure::Reference => {
                let (img, t) = timed_render(sys, spp, 7, estimator, sampler.kinds(), table_a);
                let pairs: Vec<(&[f32], &[f32])> = img
                    .iter()
                    .zip(reference)
                    .map(|(a, b)| (a.as_slice(), b.as_slice()))
                    .collect();
                (t, relative_rmse(&pairs))
            }
            ErrorMeasure::Halves => {
                let (a, ta) = timed_render(sys, spp / 2, 7, estimator, sampler.kinds(), table_a);
                let (b, tb) = timed_render(sys, spp / 2, 8, estimator, sampler.kinds(), table_b);
                let (mut num, mut den) = (0.0f64, 0.0f64);
                for (ca, cb) in a.iter().zip(&b) {
                    for (x, y) in ca.iter().zip(cb) {
                        let (x, y) = (f64::from(*x), f64::from(*y));
                        num += (x - y) * (x - y);
                        den += (x + y) * (x + y);
                    }
                }
                (
                    ta + tb,
                    if den > 0.0 {
                        (num / den).sqrt()
                    } else {
                        f64::NAN
                    },
                )
            }
        };
        pb.inc((spent + seconds).floor() as u64 - spent.floor() as u64);
        spent += seconds;
        points.push(Point {
            spp,
            seconds,
            relative_rmse: err,
        });
        // Stop a curve once it is well below the target.
        if points
            .last()
            .is_some_and(|p| p.relative_rmse < 0.5 * target)
        {
            break;
        }
        spp *= 2;
    }
    pb.finish_and_clear();
    let t = time_to_error(&points, target);
    Curve {
        name: name.to_string(),
        points,
        seconds_to_target: t.map(|x| x.0),
        extrapolated: t.is_some_and(|x| x.1),
        precompute_seconds,
    }
}

/// The Markdown table of curves and their time-to-target ratios against the first curve.
pub fn curves_markdown(curves: &[Curve], target: f64) -> String {
    let mut s = format!(
        "| renderer / estimator | time to {:.0} % RMSE | ratio to `{}` | points (spp: seconds, RMSE) |\n|---|---|---|---|\n",
        100.0 * target,
        curves.first().map_or("", |c| c.name.as_str())
    );
    let base = curves.first().and_then(|c| c.seconds_to_target);
    for c in curves {
        let t = c.seconds_to_target.map_or("–".to_string(), |t| {
            format!(
                "{t:.3} s{}",
                if c.extrapolated {
                    " (extrapolated)"
                } else {
                    ""
                }
            ) + &c.precompute_seconds.map_or(String::new(), |p| {
                format!(" per further scene, after a {p:.1} s table")
            })
        });
        let ratio = match (c.seconds_to_target, base) {
            (Some(t), Some(b)) if b > 0.0 => format!("{:.1}×", t / b),
            _ => "–".to_string(),
        };
        let pts: Vec<String> = c
            .points
            .iter()
            .map(|p| {
                format!(
                    "{}: {:.3} s, {:.2} %",
                    p.spp,
                    p.seconds,
                    100.0 * p.relative_rmse
                )
            })
            .collect();
        s += &format!("| {} | {t} | {ratio} | {} |\n", c.name, pts.join("; "));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pt(seconds: f64, e: f64) -> Point {
        Point {
            spp: 1,
            seconds,
            relative_rmse: e,
        }
    }

    #[test]
    fn interpolation_and_extrapolation() {
        // Exactly e = 0.1/√t: 1 % at t = 100.
        let pts = vec![pt(1.0, 0.1), pt(4.0, 0.05), pt(400.0, 0.005)];
        let (t, ex) = time_to_error(&pts, 0.01).unwrap();
        assert!((t - 100.0).abs() < 1e-9 && !ex);
        let (t, ex) = time_to_error(&pts[..2], 0.01).unwrap();
        assert!((t - 100.0).abs() < 1e-9 && ex);
        assert_eq!(time_to_error(&[pt(1.0, 0.001)], 0.01), Some((1.0, false)));
        assert_eq!(time_to_error(&[], 0.01), None);
    }
}
