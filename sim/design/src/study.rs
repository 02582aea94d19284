//! A design study file (TOML, docs/design-studies.md): the base scene and its overrides, the
//! free parameters (scene keys with bounds, log scale, integer or discrete choices, linked
//! keys), the objectives, the constraints on metrics and on parameters, the fidelity of the
//! search and of the final check, the tolerance draws and the optimiser's settings.
//!
//! Every error names the study file and the key (`study.toml: parameter[1].min: …`); a study
//! is checked completely (each parameter's bounds loaded into the scene) before anything is
//! evaluated.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::evaluate::{Fidelity, Requirement, Target};
use crate::metric::{Base, Kind, Metric};
use crate::tolerance::DrawSpec;

/// Most evaluations of one study.
pub const MAX_BUDGET: usize = 100_000;
/// Most free parameters.
pub const MAX_PARAMETERS: usize = 32;

/// A study error: one line naming the file and the key.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {key}: {message}")]
pub struct StudyError {
    /// The study file.
    pub file: String,
    /// The key (`parameter[0].min`).
    pub key: String,
    /// What is wrong.
    pub message: String,
}

/// `key = "a"` or `key = ["a", "b"]` (linked keys take one value).
#[derive(Clone, Debug, Deserialize)]
#[serde(untagged)]
enum Keys {
    One(String),
    Many(Vec<String>),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawParameter {
    key: Keys,
    min: Option<f64>,
    max: Option<f64>,
    #[serde(default)]
    log: bool,
    #[serde(default)]
    integer: bool,
    values: Option<Vec<f64>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawObjective {
    metric: String,
    goal: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConstraint {
    metric: Option<String>,
    key: Option<String>,
    sum: Option<Vec<String>>,
    min: Option<f64>,
    max: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFidelity {
    object_px: Option<u32>,
    binning: Option<u32>,
    spp: Option<u32>,
    replicates: Option<usize>,
    targets: Option<Vec<String>>,
    depths_mm: Option<Vec<f64>>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTolerance {
    #[serde(default)]
    draw: Vec<String>,
    draws: Option<usize>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawOptimizer {
    initial: Option<usize>,
    batch: Option<usize>,
    epsilon_levels: Option<usize>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStudy {
    scene: Option<String>,
    #[serde(default)]
    set: Vec<String>,
    #[serde(default)]
    parameter: Vec<RawParameter>,
    #[serde(default)]
    objective: Vec<RawObjective>,
    #[serde(default)]
    constraint: Vec<RawConstraint>,
    #[serde(default)]
    search: RawFidelity,
    #[serde(rename = "final", default)]
    final_: RawFidelity,
    #[serde(default)]
    tolerance: RawTolerance,
    #[serde(default)]
    optimizer: RawOptimizer,
}

/// The scale of a free parameter.
#[derive(Clone, Debug, PartialEq)]
pub enum Domain {
    /// [min, max], linear or log, optionally rounded to integers.
    Range {
        /// Lower bound.
        min: f64,
        /// Upper bound.
        max: f64,
        /// Searched in log space.
        log: bool,
        /// Rounded to an integer.
        integer: bool,
    },
    /// One of these values.
    Choice(Vec<f64>),
}

/// A free parameter: one value for every key it links.
#[derive(Clone, Debug, PartialEq)]
pub struct Parameter {
    /// Scene keys (more than one: linked).
    pub keys: Vec<String>,
    /// Its domain.
    pub domain: Domain,
}

impl Parameter {
    /// Name in reports: the first key (`+N` linked).
    pub fn name(&self) -> String {
        match self.keys.len() {
            1 => self.keys[0].clone(),
            n => format!("{} (+{} linked)", self.keys[0], n - 1),
        }
    }

    /// The value of unit coordinate `u` ∈ [0, 1].
    pub fn value(&self, u: f64) -> f64 {
        let u = u.clamp(0.0, 1.0);
        match &self.domain {
            Domain::Range {
                min,
                max,
                log,
                integer,
            } => {
                let v = if *log {
                    (min.ln() + u * (max.ln() - min.ln())).exp()
                } else {
                    min + u * (max - min)
                };
                let v = if *integer { v.round() } else { v };
                v.clamp(*min, *max)
            }
            Domain::Choice(vals) => {
                let i = ((u * vals.len() as f64).floor() as usize).min(vals.len() - 1);
                vals[i]
            }
        }
    }

    /// The unit coordinate of value `v` (inverse of [`Parameter::value`] on its range).
    pub fn unit(&self, v: f64) -> f64 {
        match &self.domain {
            Domain::Range { min, max, log, .. } => {
                let u = if *log {
                    (v.ln() - min.ln()) / (max.ln() - min.ln())
                } else {
                    (v - min) / (max - min)
                };
                if u.is_finite() {
                    u.clamp(0.0, 1.0)
                } else {
                    0.0
                }
            }
            Domain::Choice(vals) => {
                let i = vals.iter().position(|x| *x == v).unwrap_or(0);
                (i as f64 + 0.5) / vals.len() as f64
            }
        }
    }
}

/// Maximise or minimise.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Goal {
    /// Larger is better.
    Maximize,
    /// Smaller is better.
    Minimize,
}

/// An objective.
#[derive(Clone, Debug, PartialEq)]
pub struct Objective {
    /// The metric.
    pub metric: Metric,
    /// Its goal.
    pub goal: Goal,
}

/// What a constraint bounds.
#[derive(Clone, Debug, PartialEq)]
pub enum Bounded {
    /// A metric of the design.
    Metric(Metric),
    /// A scene key's value (a free parameter's or a fixed one's).
    Key(String),
    /// The sum of scene keys' values.
    Sum(Vec<String>),
}

/// A constraint: min ≤ value ≤ max.
#[derive(Clone, Debug, PartialEq)]
pub struct Constraint {
    /// What it bounds.
    pub what: Bounded,
    /// Lower bound.
    pub min: Option<f64>,
    /// Upper bound.
    pub max: Option<f64>,
}

impl Constraint {
    /// Name in reports.
    pub fn name(&self) -> String {
        let what = match &self.what {
            Bounded::Metric(m) => m.to_string(),
            Bounded::Key(k) => k.clone(),
            Bounded::Sum(ks) => format!("sum({})", ks.join(" + ")),
        };
        match (self.min, self.max) {
            (Some(a), Some(b)) => format!("{a} <= {what} <= {b}"),
            (Some(a), None) => format!("{what} >= {a}"),
            (None, Some(b)) => format!("{what} <= {b}"),
            (None, None) => what,
        }
    }

    /// The normalised violation of `v` (≤ 0 feasible; 1 for NaN): (min − v)/s or (v − max)/s,
    /// s = max(|bound|, 1e-9 + spread of the bounds).
    pub fn violation(&self, v: f64) -> f64 {
        if !v.is_finite() {
            return 1.0;
        }
        let scale = |b: f64| b.abs().max(1e-9);
        let lo = self.min.map_or(f64::NEG_INFINITY, |m| (m - v) / scale(m));
        let hi = self.max.map_or(f64::NEG_INFINITY, |m| (v - m) / scale(m));
        lo.max(hi)
    }
}

/// A study, checked.
#[derive(Clone, Debug)]
pub struct Study {
    /// The study file (for messages).
    pub file: String,
    /// The base scene file (None: the embedded paper scene).
    pub scene: Option<PathBuf>,
    /// Overrides of the base scene.
    pub set: Vec<String>,
    /// Free parameters.
    pub parameters: Vec<Parameter>,
    /// Objectives (the first is optimised; the others trace a Pareto front by ε-constraints).
    pub objectives: Vec<Objective>,
    /// Constraints.
    pub constraints: Vec<Constraint>,
    /// Fidelity of the search's evaluations.
    pub search: Fidelity,
    /// Fidelity of the final check.
    pub final_check: Fidelity,
    /// Tolerance draws.
    pub draws: Vec<DrawSpec>,
    /// Number of tolerance draws.
    pub draw_count: usize,
    /// Initial design points (Latin hypercube); None: 2·(parameters) + 2.
    pub initial: Option<usize>,
    /// Evaluations per step (evaluated in parallel).
    pub batch: usize,
    /// ε levels a multi-objective study cycles through.
    pub epsilon_levels: usize,
    /// The study's text (what the run records a digest of).
    pub text: String,
}

impl Study {
    /// Reads and checks the study at `path`.
    pub fn load(path: &Path) -> Result<Study, StudyError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| StudyError {
            file: file.clone(),
            key: "(file)".into(),
            message: e.to_string(),
        })?;
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Study::parse(&text, &file, &dir)
    }

    /// Parses and checks a study's `text` (`file` names it in messages, `dir` resolves its
    /// relative paths).
    pub fn parse(text: &str, file: &str, dir: &Path) -> Result<Study, StudyError> {
        let err = |key: &str, message: String| StudyError {
            file: file.to_string(),
            key: key.to_string(),
            message,
        };
        let raw: RawStudy = toml::from_str(text).map_err(|e| {
            let msg = e.message().to_string();
            let key = e
                .span()
                .map(|s| {
                    format!(
                        "line {}",
                        text[..s.start.min(text.len())].lines().count().max(1)
                    )
                })
                .unwrap_or_else(|| "(toml)".into());
            err(&key, msg)
        })?;
        let scene = raw.scene.as_ref().map(|s| dir.join(s));
        if let Some(p) = &scene
            && !p.is_file()
        {
            return Err(err("scene", format!("{} is not a file", p.display())));
        }
        let base = crate::scene::SceneSource::File(scene.as_deref())
            .load(&raw.set)
            .map_err(|e| err("set", e.to_string()))?;
        let gamma = base.scene.display.gamma;
        if raw.parameter.is_empty() {
            return Err(err("parameter", "give at least one [[parameter]]".into()));
        }
        if raw.parameter.len() > MAX_PARAMETERS {
            return Err(err(
                "parameter",
                format!("at most {MAX_PARAMETERS} parameters"),
            ));
        }
        let mut parameters = Vec::new();
        let mut all_keys: Vec<String> = Vec::new();
        for (i, p) in raw.parameter.iter().enumerate() {
            let at = |k: &str| format!("parameter[{i}].{k}");
            let keys = match &p.key {
                Keys::One(k) => vec![k.clone()],
                Keys::Many(ks) => ks.clone(),
            };
            if keys.is_empty() {
                return Err(err(&at("key"), "give at least one scene key".into()));
            }
            for k in &keys {
                if all_keys.contains(k) {
                    return Err(err(&at("key"), format!("{k:?} is already a parameter")));
                }
                all_keys.push(k.clone());
            }
            let finite = |k: &str, v: Option<f64>| match v {
                Some(x) if !x.is_finite() => {
                    Err(err(&at(k), format!("{x} is not a finite number")))
                }
                _ => Ok(v),
            };
            let (min, max) = (finite("min", p.min)?, finite("max", p.max)?);
            let domain = match (&p.values, min, max) {
                (Some(vals), None, None) => {
                    if vals.is_empty() || vals.iter().any(|v| !v.is_finite()) {
                        return Err(err(&at("values"), "give finite values".into()));
                    }
                    Domain::Choice(vals.clone())
                }
                (Some(_), _, _) => {
                    return Err(err(
                        &at("values"),
                        "give either values or min and max".into(),
                    ));
                }
                (None, Some(a), Some(b)) => {
                    if a >= b {
                        return Err(err(
                            &at("max"),
                            format!("max {b} must be greater than min {a}"),
                        ));
                    }
                    if p.log && a <= 0.0 {
                        return Err(err(&at("min"), format!("log scale needs min > 0, got {a}")));
                    }
                    if p.integer && a.ceil() > b.floor() {
                        return Err(err(&at("min"), format!("no integer in [{a}, {b}]")));
                    }
                    Domain::Range {
                        min: a,
                        max: b,
                        log: p.log,
                        integer: p.integer,
                    }
                }
                (None, None, _) => {
                    return Err(err(
                        &at("min"),
                        "missing (give min and max, or values)".into(),
                    ));
                }
                (None, _, None) => {
                    return Err(err(
                        &at("max"),
                        "missing (give min and max, or values)".into(),
                    ));
                }
            };
            let param = Parameter { keys, domain };
            // Both ends load into the scene (key exists, value accepted).
            for u in [0.0, 1.0] {
                let mut set = raw.set.clone();
                set.extend(param.keys.iter().map(|k| format!("{k}={}", param.value(u))));
                crate::scene::SceneSource::File(scene.as_deref())
                    .load(&set)
                    .and_then(|ls| crate::system::System::build(&ls).map(drop))
                    .map_err(|e| err(&at("key"), e.to_string()))?;
            }
            parameters.push(param);
        }
        if raw.objective.is_empty() {
            return Err(err("objective", "give at least one [[objective]]".into()));
        }
        let mut objectives = Vec::new();
        for (i, o) in raw.objective.iter().enumerate() {
            let metric =
                Metric::parse(&o.metric).map_err(|e| err(&format!("objective[{i}].metric"), e))?;
            let goal = match o.goal.as_str() {
                "maximize" | "maximise" | "max" => Goal::Maximize,
                "minimize" | "minimise" | "min" => Goal::Minimize,
                g => {
                    return Err(err(
                        &format!("objective[{i}].goal"),
                        format!("{g:?}: expected \"maximize\" or \"minimize\""),
                    ));
                }
            };
            if objectives.iter().any(|x: &Objective| x.metric == metric) {
                return Err(err(
                    &format!("objective[{i}].metric"),
                    format!("{metric} is already an objective"),
                ));
            }
            objectives.push(Objective { metric, goal });
        }
        let mut constraints = Vec::new();
        for (i, c) in raw.constraint.iter().enumerate() {
            let at = |k: &str| format!("constraint[{i}].{k}");
            let what = match (&c.metric, &c.key, &c.sum) {
                (Some(m), None, None) => {
                    Bounded::Metric(Metric::parse(m).map_err(|e| err(&at("metric"), e))?)
                }
                (None, Some(k), None) => Bounded::Key(k.clone()),
                (None, None, Some(ks)) if !ks.is_empty() => Bounded::Sum(ks.clone()),
                _ => {
                    return Err(err(
                        &at("metric"),
                        "give exactly one of metric, key or sum (a non-empty list of keys)".into(),
                    ));
                }
            };
            for (k, v) in [("min", c.min), ("max", c.max)] {
                if v.is_some_and(|v| !v.is_finite()) {
                    return Err(err(
                        &at(k),
                        format!("{} is not a finite number", v.unwrap_or(f64::NAN)),
                    ));
                }
            }
            match (c.min, c.max) {
                (None, None) => return Err(err(&at("min"), "give min and/or max".into())),
                (Some(a), Some(b)) if a > b => {
                    return Err(err(&at("max"), format!("max {b} is below min {a}")));
                }
                _ => {}
            }
            let keys: Vec<&String> = match &what {
                Bounded::Key(k) => vec![k],
                Bounded::Sum(ks) => ks.iter().collect(),
                Bounded::Metric(_) => Vec::new(),
            };
            for k in keys {
                if scene_value(&base.scene, k).is_none() {
                    return Err(err(&at("key"), format!("{k:?} is not a numeric scene key")));
                }
            }
            constraints.push(Constraint {
                what,
                min: c.min,
                max: c.max,
            });
        }
        let search = fidelity(&raw.search, Fidelity::default(), "search", &err, dir, gamma)?;
        let final_check = fidelity(
            &raw.final_,
            Fidelity {
                object_px: search.object_px.map(|n| n * 2),
                binning: 1.max(search.binning / 2),
                spp: search.spp * 4,
                replicates: search.replicates.max(2),
                targets: search.targets.clone(),
                depths_mm: search.depths_mm.clone(),
                seed: search.seed,
            },
            "final",
            &err,
            dir,
            gamma,
        )?;
        let draws = raw
            .tolerance
            .draw
            .iter()
            .enumerate()
            .map(|(i, d)| {
                DrawSpec::parse(d).map_err(|e| err(&format!("tolerance.draw[{i}]"), e.to_string()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let draw_count = raw
            .tolerance
            .draws
            .unwrap_or(if draws.is_empty() { 0 } else { 64 });
        if draw_count > crate::evaluate::MAX_DRAWS {
            return Err(err(
                "tolerance.draws",
                format!("at most {}", crate::evaluate::MAX_DRAWS),
            ));
        }
        let study = Study {
            file: file.to_string(),
            scene,
            set: raw.set,
            parameters,
            objectives,
            constraints,
            search,
            final_check,
            draws,
            draw_count,
            initial: raw.optimizer.initial,
            batch: raw.optimizer.batch.unwrap_or(2),
            epsilon_levels: raw.optimizer.epsilon_levels.unwrap_or(5),
            text: text.to_string(),
        };
        if !(1..=64).contains(&study.batch) {
            return Err(err(
                "optimizer.batch",
                format!("{}: must be 1..=64", study.batch),
            ));
        }
        if !(2..=100).contains(&study.epsilon_levels) {
            return Err(err("optimizer.epsilon_levels", "must be 2..=100".into()));
        }
        if study.initial == Some(0) {
            return Err(err("optimizer.initial", "must be at least 1".into()));
        }
        let needs_draws = study.metrics().iter().any(|m| m.needs_draws());
        if needs_draws && (study.draws.is_empty() || study.draw_count == 0) {
            return Err(err("tolerance.draw", "a yield or _q05 metric needs tolerance draws ([tolerance] draw = [\"hoe.…=normal(M,SD)\"])".into()));
        }
        if study.metrics().iter().any(|m| m.base == Base::Yield) && study.requirements().is_empty()
        {
            return Err(err(
                "constraint",
                "the yield counts draws that meet the constraints on geometry metrics: give one"
                    .into(),
            ));
        }
        // The request the search makes is valid (e.g. q05 of a reconstruction metric is not).
        study
            .request(&study.search, crate::evaluate::Exposure::Own)
            .check()
            .map_err(|e| err("objective", e.to_string()))?;
        Ok(study)
    }

    /// Every metric the study needs, objectives first.
    pub fn metrics(&self) -> Vec<Metric> {
        let mut ms: Vec<Metric> = self.objectives.iter().map(|o| o.metric).collect();
        for c in &self.constraints {
            if let Bounded::Metric(m) = c.what
                && !ms.contains(&m)
            {
                ms.push(m);
            }
        }
        ms
    }

    /// The yield's requirements: the constraints on nominal geometry and colour metrics.
    pub fn requirements(&self) -> Vec<Requirement> {
        self.constraints
            .iter()
            .filter_map(|c| match c.what {
                Bounded::Metric(m)
                    if !m.q05 && matches!(m.base.kind(), Kind::Geometry | Kind::Colour) =>
                {
                    Some(Requirement {
                        metric: m.base,
                        min: c.min,
                        max: c.max,
                    })
                }
                _ => None,
            })
            .collect()
    }

    /// The evaluation request at `fidelity`.
    pub fn request(
        &self,
        fidelity: &Fidelity,
        exposure: crate::evaluate::Exposure,
    ) -> crate::evaluate::Request {
        crate::evaluate::Request {
            metrics: self.metrics(),
            fidelity: fidelity.clone(),
            exposure,
            draws: self.draws.clone(),
            draw_count: self.draw_count,
            requirements: self.requirements(),
        }
    }

    /// The scene overrides of a point (one value per parameter).
    pub fn overrides(&self, values: &[f64]) -> Vec<String> {
        let mut set = self.set.clone();
        for (p, v) in self.parameters.iter().zip(values) {
            set.extend(p.keys.iter().map(|k| format!("{k}={v}")));
        }
        set
    }

    /// A digest of the study's text and `seed` (what a resumed run must match).
    pub fn digest(&self, seed: u64) -> String {
        let mut words: Vec<u64> = self.text.bytes().map(u64::from).collect();
        words.push(seed);
        format!("{:016x}", crate::sampler::hash(&words))
    }
}

/// The numeric value of dotted scene key `key` in `scene` (None: not a number there).
pub fn scene_value(scene: &crate::scene::Scene, key: &str) -> Option<f64> {
    let v = toml::Value::try_from(scene).ok()?;
    let mut cur = &v;
    for part in key.split('.') {
        cur = match cur {
            toml::Value::Table(t) => t.get(part)?,
            toml::Value::Array(a) => a.get(part.parse::<usize>().ok()?)?,
            _ => return None,
        };
    }
    match cur {
        toml::Value::Float(f) => Some(*f),
        toml::Value::Integer(i) => Some(*i as f64),
        _ => None,
    }
}

fn fidelity(
    raw: &RawFidelity,
    default: Fidelity,
    section: &str,
    err: &dyn Fn(&str, String) -> StudyError,
    dir: &Path,
    gamma: f64,
) -> Result<Fidelity, StudyError> {
    let targets = match &raw.targets {
        Some(ts) => ts
            .iter()
            .enumerate()
            .map(|(i, t)| {
                Target::parse(t, dir, gamma).map_err(|e| err(&format!("{section}.targets[{i}]"), e))
            })
            .collect::<Result<Vec<_>, _>>()?,
        None => default.targets,
    };
    if targets.is_empty() {
        return Err(err(
            &format!("{section}.targets"),
            "give at least one target".into(),
        ));
    }
    let f = Fidelity {
        object_px: raw.object_px.or(default.object_px),
        binning: raw.binning.unwrap_or(default.binning),
        spp: raw.spp.unwrap_or(default.spp),
        seed: default.seed,
        replicates: raw.replicates.unwrap_or(default.replicates),
        targets,
        depths_mm: raw.depths_mm.clone().unwrap_or(default.depths_mm),
    };
    let check = crate::evaluate::Request {
        metrics: vec![Metric::nominal(Base::PsnrDb)],
        fidelity: f.clone(),
        exposure: crate::evaluate::Exposure::Own,
        draws: Vec::new(),
        draw_count: 0,
        requirements: Vec::new(),
    };
    check.check().map_err(|e| err(section, e.to_string()))?;
    Ok(f)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
set = ["sensor.crop_px=[96,96]"]
[[parameter]]
key = "bottom_hoe.height_mm"
min = 10.0
max = 80.0
[[objective]]
metric = "psnr_db"
goal = "maximize"
[[constraint]]
metric = "fov_capture_vertical_deg"
min = 15.0
"#;

    fn parse(t: &str) -> Result<Study, StudyError> {
        Study::parse(t, "s.toml", Path::new("."))
    }

    #[test]
    fn the_issue_form_parses() {
        let s = parse(GOOD).unwrap();
        assert_eq!(s.parameters.len(), 1);
        assert_eq!(s.parameters[0].value(0.5), 45.0);
        assert_eq!(s.objectives[0].goal, Goal::Maximize);
        assert_eq!(s.constraints[0].violation(15.0), 0.0);
        assert!(s.constraints[0].violation(16.0) < 0.0 && s.constraints[0].violation(14.0) > 0.0);
        assert_eq!(s.requirements().len(), 1);
    }

    #[test]
    fn bad_studies_name_file_and_key() {
        let cases = [
            (
                GOOD.replace("bottom_hoe.height_mm", "bottom_hoe.nope_mm"),
                "parameter[0].key",
            ),
            (GOOD.replace("max = 80.0", "max = 5.0"), "parameter[0].max"),
            (GOOD.replace("min = 10.0", "min = nan"), "parameter[0].min"),
            (
                GOOD.replace("\"psnr_db\"", "\"psnr\""),
                "objective[0].metric",
            ),
            (GOOD.replace("\"maximize\"", "\"up\""), "objective[0].goal"),
            (GOOD.replace("min = 15.0", "colour = 1"), "line"),
        ];
        for (text, key) in cases {
            let e = parse(&text).unwrap_err();
            assert_eq!(e.file, "s.toml");
            assert!(e.key.starts_with(key), "{key}: {e}");
        }
    }

    #[test]
    fn units_invert_values() {
        let p = Parameter {
            keys: vec!["a".into()],
            domain: Domain::Range {
                min: 1.0,
                max: 100.0,
                log: true,
                integer: false,
            },
        };
        assert!((p.value(0.5) - 10.0).abs() < 1e-12);
        assert!((p.unit(10.0) - 0.5).abs() < 1e-12);
        let c = Parameter {
            keys: vec!["a".into()],
            domain: Domain::Choice(vec![1.0, 2.0, 4.0]),
        };
        assert_eq!(c.value(0.0), 1.0);
        assert_eq!(c.value(0.99), 4.0);
        assert_eq!(c.value(c.unit(2.0)), 2.0);
        let i = Parameter {
            keys: vec!["a".into()],
            domain: Domain::Range {
                min: 1.0,
                max: 4.0,
                log: false,
                integer: true,
            },
        };
        assert_eq!(i.value(0.49), 2.0);
    }
}
