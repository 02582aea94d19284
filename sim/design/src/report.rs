//! The files of an optimisation run: `history.csv` and `history.jsonl` (every evaluation:
//! parameters, metrics, violations, feasibility, fidelity, time), `pareto.csv`, `best.toml`
//! (the best design as a complete scene that `render`, `demo`, `info` and `evaluate` accept
//! unchanged), `summary.json`, `report.md` (the base and the best designs side by side) and
//! the plots (best feasible value against evaluations, the Pareto front with the base design
//! marked, each parameter against the objective), PNG and SVG.

use std::fmt::Write as _;

use crate::optimize::{Outcome, Record};
use crate::plot::{LinePlot, Series};
use crate::scene::SceneSource;
use crate::study::{Goal, Study};

/// Columns of `history.csv` that hold timings (the only ones that differ between runs).
pub const TIMING_COLUMNS: &[&str] = &["seconds"];

/// A number as CSV/Markdown text (shortest round trip; empty for NaN).
fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v}")
    } else {
        String::new()
    }
}

/// Every metric name in the records, sorted.
fn metric_names(outcome: &Outcome) -> Vec<String> {
    let mut names: Vec<String> = outcome
        .records
        .iter()
        .flat_map(|r| r.metrics.keys().cloned())
        .collect();
    names.extend(outcome.base.keys().cloned());
    names.sort();
    names.dedup();
    names
}

/// `history.csv`.
pub fn history_csv(study: &Study, outcome: &Outcome) -> String {
    let names = metric_names(outcome);
    let mut s = String::from("index,step,fidelity");
    for p in &study.parameters {
        let _ = write!(s, ",{}", p.keys[0]);
    }
    for n in &names {
        let _ = write!(s, ",{n}");
    }
    for (i, _) in study.constraints.iter().enumerate() {
        let _ = write!(s, ",violation_{i}");
    }
    s.push_str(",feasible,seconds\n");
    for r in &outcome.records {
        let _ = write!(s, "{},{},search", r.index, r.step);
        for v in &r.params {
            let _ = write!(s, ",{}", num(*v));
        }
        for n in &names {
            let _ = write!(
                s,
                ",{}",
                r.metrics.get(n).map_or(String::new(), |v| num(*v))
            );
        }
        for v in &r.violations {
            let _ = write!(s, ",{}", num(*v));
        }
        let _ = writeln!(s, ",{},{:.3}", r.feasible, r.seconds);
    }
    s
}

/// `pareto.csv`: the front's evaluations, best first objective first.
pub fn pareto_csv(study: &Study, outcome: &Outcome) -> String {
    let mut s = String::from("index");
    for p in &study.parameters {
        let _ = write!(s, ",{}", p.keys[0]);
    }
    for o in &study.objectives {
        let _ = write!(s, ",{}", o.metric);
    }
    s.push('\n');
    for &i in &outcome.pareto {
        let r = record(outcome, i);
        let _ = write!(s, "{i}");
        for v in &r.params {
            let _ = write!(s, ",{}", num(*v));
        }
        for o in &study.objectives {
            let _ = write!(
                s,
                ",{}",
                r.metrics
                    .get(&o.metric.to_string())
                    .map_or(String::new(), |v| num(*v))
            );
        }
        s.push('\n');
    }
    s
}

/// The record of evaluation `i`.
pub fn record(outcome: &Outcome, i: usize) -> &Record {
    &outcome.records[outcome
        .records
        .iter()
        .position(|r| r.index == i)
        .unwrap_or(0)]
}

/// `best.toml`: the complete scene of evaluation `index` (the study's base scene with its
/// overrides and the design's parameter values), asset paths made absolute so the file works
/// from anywhere.
pub fn scene_toml(study: &Study, params: &[f64]) -> Result<String, String> {
    let ls = SceneSource::File(study.scene.as_deref())
        .load(&study.overrides(params))
        .map_err(|e| e.to_string())?;
    let mut scene = ls.scene.clone();
    let img = std::path::Path::new(&scene.display.image);
    if crate::targets::builtin_image(&format!("{}@8", scene.display.image)).is_err()
        && img.is_relative()
    {
        scene.display.image = ls.base_dir.join(img).display().to_string();
    }
    let body = toml::to_string(&scene).map_err(|e| e.to_string())?;
    let values: Vec<String> = study
        .parameters
        .iter()
        .zip(params)
        .map(|(p, v)| format!("# {} = {v}", p.keys.join(", ")))
        .collect();
    Ok(format!(
        "# The design stscam optimize found for {} (a complete scene; render, demo, info and evaluate take it).\n{}\n\n{body}",
        study.file,
        values.join("\n")
    ))
}

/// A scatter series (points apart: NaN between them breaks the line).
fn scatter(name: &str, pts: impl Iterator<Item = (f64, f64)>) -> Series {
    let mut points = Vec::new();
    for p in pts {
        points.push(p);
        points.push((f64::NAN, f64::NAN));
    }
    Series {
        name: name.into(),
        points,
    }
}

/// The plots: (file stem, plot).
pub fn plots(study: &Study, outcome: &Outcome) -> Vec<(String, LinePlot)> {
    let o0 = &study.objectives[0];
    let name0 = o0.metric.to_string();
    let get = |r: &Record, n: &str| r.metrics.get(n).copied().unwrap_or(f64::NAN);
    let better = |a: f64, b: f64| match o0.goal {
        Goal::Maximize => a > b,
        Goal::Minimize => a < b,
    };
    let mut best = f64::NAN;
    let mut curve = Vec::new();
    for r in &outcome.records {
        let v = get(r, &name0);
        if r.feasible && v.is_finite() && (best.is_nan() || better(v, best)) {
            best = v;
        }
        curve.push(((r.index + 1) as f64, best));
    }
    let base0 = outcome.base.get(&name0).copied().unwrap_or(f64::NAN);
    // An infeasible study has no best feasible value: its convergence plot is the least total
    // normalised constraint violation so far (what the search drove down), not an empty frame.
    let least_violation = || {
        let mut least = f64::INFINITY;
        let points = outcome
            .records
            .iter()
            .map(|r| {
                let v: f64 = r.violations.iter().map(|v| v.max(0.0)).sum();
                if v.is_finite() {
                    least = least.min(v);
                }
                ((r.index + 1) as f64, least)
            })
            .collect();
        LinePlot {
            title: "No feasible design: least total constraint violation against evaluations"
                .into(),
            x_label: "evaluations".into(),
            y_label: "sum of normalised violations".into(),
            log_x: false,
            log_y: false,
            series: vec![Series {
                name: "least violation".into(),
                points,
            }],
            h_line: None,
        }
    };
    let mut out = vec![(
        "convergence".to_string(),
        if outcome.best.is_none() && !outcome.records.is_empty() {
            least_violation()
        } else {
            LinePlot {
                title: format!("Best feasible {name0} against evaluations"),
                x_label: "evaluations".into(),
                y_label: name0.clone(),
                log_x: false,
                log_y: false,
                series: vec![Series {
                    name: "best feasible".into(),
                    points: curve,
                }],
                h_line: base0
                    .is_finite()
                    .then(|| (base0, "base design".to_string())),
            }
        },
    )];
    if study.objectives.len() >= 2 {
        let n1 = study.objectives[1].metric.to_string();
        let xy = |r: &Record| (get(r, &n1), get(r, &name0));
        let mut front: Vec<(f64, f64)> = outcome
            .pareto
            .iter()
            .map(|&i| xy(record(outcome, i)))
            .collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        out.push((
            "pareto".to_string(),
            LinePlot {
                title: format!("Pareto front: {name0} against {n1}"),
                x_label: n1.clone(),
                y_label: name0.clone(),
                log_x: false,
                log_y: false,
                series: vec![
                    scatter(
                        "feasible",
                        outcome.records.iter().filter(|r| r.feasible).map(xy),
                    ),
                    scatter(
                        "infeasible",
                        outcome.records.iter().filter(|r| !r.feasible).map(xy),
                    ),
                    Series {
                        name: "front".into(),
                        points: front,
                    },
                    scatter(
                        "base design",
                        std::iter::once((
                            outcome.base.get(&n1).copied().unwrap_or(f64::NAN),
                            base0,
                        )),
                    ),
                ],
                h_line: None,
            },
        ));
    }
    for (j, p) in study.parameters.iter().enumerate() {
        out.push((
            format!("parameter_{j}"),
            LinePlot {
                title: format!("{name0} against {}", p.name()),
                x_label: p.keys[0].clone(),
                y_label: name0.clone(),
                // A parameter searched in log space is plotted on a log axis.
                log_x: matches!(p.domain, crate::study::Domain::Range { log: true, .. }),
                log_y: false,
                series: vec![
                    scatter(
                        "feasible",
                        outcome
                            .records
                            .iter()
                            .filter(|r| r.feasible)
                            .map(|r| (r.params[j], get(r, &name0))),
                    ),
                    scatter(
                        "infeasible",
                        outcome
                            .records
                            .iter()
                            .filter(|r| !r.feasible)
                            .map(|r| (r.params[j], get(r, &name0))),
                    ),
                ],
                h_line: base0
                    .is_finite()
                    .then(|| (base0, "base design".to_string())),
            },
        ));
    }
    out
}

/// `report.md`.
pub fn report_md(study: &Study, outcome: &Outcome, seed: u64, budget: usize) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Design study {}\n", study.file);
    let _ = writeln!(
        s,
        "{budget} evaluations, seed {seed}; objectives: {}; constraints: {}.\n",
        study
            .objectives
            .iter()
            .map(|o| format!(
                "{} {}",
                if o.goal == Goal::Maximize {
                    "maximise"
                } else {
                    "minimise"
                },
                o.metric
            ))
            .collect::<Vec<_>>()
            .join(", "),
        if study.constraints.is_empty() {
            "none".to_string()
        } else {
            study
                .constraints
                .iter()
                .map(|c| c.name())
                .collect::<Vec<_>>()
                .join("; ")
        }
    );
    match (outcome.best, &outcome.least_violating) {
        (Some(b), _) => {
            let r = record(outcome, b);
            let _ = writeln!(
                s,
                "**Best feasible design**: evaluation {b} (step {}), `best.toml`:\n",
                r.step
            );
            for (p, v) in study.parameters.iter().zip(&r.params) {
                let _ = writeln!(s, "- `{}` = {v}", p.keys.join("`, `"));
            }
        }
        (None, Some((i, c))) => {
            let _ = writeln!(
                s,
                "**The study is infeasible** within its budget: no evaluation met every constraint. The least-violating design is evaluation {i}; the constraint that binds most there: `{c}`. `best.toml` is not written."
            );
        }
        (None, None) => {
            let _ = writeln!(s, "**No design was evaluated.**");
        }
    }
    let names: Vec<String> = study.metrics().iter().map(|m| m.to_string()).collect();
    let _ = writeln!(
        s,
        "\n## Search fidelity (object {} px, binning {}, {} spp, {} replicates, fixed exposure: white peak {:.6e})\n",
        study
            .search
            .object_px
            .map_or("scene".into(), |n| n.to_string()),
        study.search.binning,
        study.search.spp,
        study.search.replicates,
        outcome.white_peak
    );
    let _ = writeln!(s, "| metric | base | best |\n|---|---|---|");
    for n in &names {
        let b = outcome.base.get(n).copied().unwrap_or(f64::NAN);
        let e = |m: &std::collections::BTreeMap<String, f64>| {
            m.get(&format!("{n}_error"))
                .map_or(String::new(), |e| format!(" ± {}", fmt4(*e)))
        };
        let best = outcome.best.map(|i| record(outcome, i));
        let _ = writeln!(
            s,
            "| {n} | {}{} | {} |",
            fmt4(b),
            e(&outcome.base),
            best.map_or("-".into(), |r| format!(
                "{}{}",
                fmt4(r.metrics.get(n).copied().unwrap_or(f64::NAN)),
                e(&r.metrics)
            ))
        );
    }
    if !outcome.finals.is_empty() {
        let f = &study.final_check;
        let _ = writeln!(
            s,
            "\n## Final fidelity (object {} px, binning {}, {} spp, {} replicates)\n",
            f.object_px.map_or("scene".into(), |n| n.to_string()),
            f.binning,
            f.spp,
            f.replicates
        );
        let _ = write!(s, "| design |");
        for n in &names {
            let _ = write!(s, " {n} |");
        }
        let _ = write!(s, "\n|---|");
        for _ in &names {
            let _ = write!(s, "---|");
        }
        s.push('\n');
        for (i, m) in &outcome.finals {
            let label = match i {
                None => "base".to_string(),
                Some(i) if Some(*i) == outcome.best => format!("best ({i})"),
                Some(i) => format!("front ({i})"),
            };
            let _ = write!(s, "| {label} |");
            for n in &names {
                let v = m.get(n).copied().unwrap_or(f64::NAN);
                let e = m
                    .get(&format!("{n}_error"))
                    .map_or(String::new(), |e| format!(" ± {}", fmt4(*e)));
                let _ = write!(s, " {}{e} |", fmt4(v));
            }
            s.push('\n');
        }
    }
    if study.objectives.len() >= 2 {
        let _ = writeln!(
            s,
            "\n## Pareto front ({} designs, `pareto.csv`, `pareto.png`)\n",
            outcome.pareto.len()
        );
        if let Some(d) = dominating(study, outcome) {
            let r = record(outcome, d);
            let _ = writeln!(
                s,
                "The nearest evaluated design that dominates the base design (every objective at least as good, one better): evaluation {d}, {}.",
                study
                    .parameters
                    .iter()
                    .zip(&r.params)
                    .map(|(p, v)| format!("`{}` = {v}", p.keys[0]))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        } else {
            let _ = writeln!(s, "No evaluated feasible design dominates the base design.");
        }
    }
    let _ = writeln!(
        s,
        "\nPlots: `convergence.png`{}, `parameter_*.png`. Every evaluation: `history.csv`, `history.jsonl`.",
        if study.objectives.len() >= 2 {
            ", `pareto.png`"
        } else {
            ""
        }
    );
    s
}

fn fmt4(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.4}")
    } else {
        "NaN".into()
    }
}

/// The feasible evaluation dominating the base design nearest to it in unit coordinates.
pub fn dominating(study: &Study, outcome: &Outcome) -> Option<usize> {
    let val = |m: &std::collections::BTreeMap<String, f64>, k: usize| {
        let o = &study.objectives[k];
        let v = m.get(&o.metric.to_string()).copied().unwrap_or(f64::NAN);
        if o.goal == Goal::Maximize { v } else { -v }
    };
    let base = SceneSource::File(study.scene.as_deref())
        .load(&study.set)
        .ok();
    let base_unit: Vec<f64> = study
        .parameters
        .iter()
        .map(|p| {
            let v = base
                .as_ref()
                .and_then(|l| crate::study::scene_value(&l.scene, &p.keys[0]))
                .unwrap_or(f64::NAN);
            p.unit(v)
        })
        .collect();
    let k = study.objectives.len();
    outcome
        .records
        .iter()
        .filter(|r| r.feasible)
        .filter(|r| {
            (0..k).all(|j| val(&r.metrics, j) >= val(&outcome.base, j))
                && (0..k).any(|j| val(&r.metrics, j) > val(&outcome.base, j))
        })
        .min_by(|a, b| {
            let d = |r: &Record| {
                r.unit
                    .iter()
                    .zip(&base_unit)
                    .map(|(x, y)| (x - y).powi(2))
                    .sum::<f64>()
            };
            d(a).total_cmp(&d(b)).then(a.index.cmp(&b.index))
        })
        .map(|r| r.index)
}
