//! Design optimisation (`stscam optimize`): constrained Bayesian optimisation of a study's
//! objective over its free parameters, a Pareto front for several objectives, checkpointed
//! and resumable, the same history for any thread count.
//!
//! # Method
//! The search runs in the unit cube of the parameters (`study::Parameter::unit`; log scales
//! and integer or discrete choices mapped there). Step 0 is a Latin hypercube of `initial`
//! points (McKay, Beckman & Conover, Technometrics 21, 1979: each axis cut into `initial`
//! strata, each stratum used once; default 2·d + 2; stratum order and jitter from
//! `sampler::hash` of the seed). Each further step asks `egobox-ego`'s EGO service (Gaussian-process mixture
//! surrogates, expected-improvement infill, q-EI with the kriging believer for a batch) for
//! `batch` points given every evaluation so far: the first objective (negated to maximise),
//! and one modelled inequality c ≤ 0 per constraint (`study::Constraint::violation`,
//! normalised by its bound). The suggestion is a pure function of the history and the step's
//! seed, so a resumed run or any thread count proposes the same points.
//!
//! Several objectives: the ε-constraint method (Haimes et al. 1971; Miettinen, *Nonlinear
//! Multiobjective Optimization*, 1999, §4.1): each step optimises the first objective with
//! the others bounded at an ε level, cycling through `epsilon_levels` levels spread evenly
//! over the range of each other objective seen so far; the front is the non-dominated set of
//! the feasible evaluations.
//!
//! Designs are compared at a fixed exposure: the base design's all-white peak at the search
//! fidelity (and at the final fidelity for the final check) holds for every candidate.
//!
//! # Files (in `--out`)
//! `history.jsonl` is the checkpoint: one JSON line per finished evaluation, appended and
//! flushed as each ends; `--resume` reads it back (each line checked against the study's
//! digest and the parameters), skips the evaluations it holds and continues. At the end every
//! output is written from the records sorted by index: `history.csv`, `history.jsonl`,
//! `pareto.csv`, `best.toml`, `summary.json`, `report.md` and the plots. `base.json` holds the
//! base design's evaluation (its metrics and the exposure it fixes) so that a resumed run or a
//! shard task does not evaluate it again.
//!
//! # Shards (a cluster's array tasks)
//! A step's batch can be evaluated by separate processes ([`Role`]): `--collect` merges the
//! shard files into the checkpoint and plans the next step into `step.json` (its points, as
//! bit patterns); each of N tasks (`--shard I/N`) evaluates the planned points at positions
//! k ≡ I (mod N) into `shard-III-of-NNN.jsonl` (resumable the same way); the next `--collect`
//! merges them, and once the budget is spent writes the run's files as a local run does.
//! Every evaluation is a pure function of the study, the seed and its point, and every step's
//! points a pure function of the earlier records, so the history is the same for any split.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use ndarray::Array2;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::evaluate::{EvalError, Evaluation, Exposure, Fidelity, evaluate};
use crate::scene::SceneSource;
use crate::study::{Bounded, Goal, Study, scene_value};

/// An optimisation error.
#[derive(Debug, thiserror::Error)]
pub enum OptimizeError {
    /// Bad input (study, settings, a checkpoint that does not belong to the study).
    #[error("{0}")]
    Input(String),
    /// An evaluation failed.
    #[error(transparent)]
    Eval(#[from] EvalError),
    /// A file could not be written.
    #[error("{0}")]
    Write(String),
    /// Cancelled.
    #[error("cancelled")]
    Cancelled,
}

/// Settings of a run.
#[derive(Clone, Debug)]
pub struct RunSettings {
    /// Evaluations of the search (the base design's is not counted).
    pub budget: usize,
    /// Seed of the design of experiments, the optimiser and the evaluations.
    pub seed: u64,
    /// Continue from the checkpoint in the output directory.
    pub resume: bool,
    /// Skip the final re-evaluation at full fidelity.
    pub skip_final: bool,
    /// How this process takes part (module notes, "Shards").
    pub role: Role,
}

/// How a process takes part in a run (module notes, "Shards").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// Evaluates every step itself, on the threads of its pool.
    Local,
    /// Merges the shard files into the checkpoint, then plans the next step into `step.json`
    /// or, with the budget spent, finishes as a local run.
    Collect,
    /// Shard `index` of `count`: evaluates its share of the planned step and stops.
    Shard {
        /// 0-based.
        index: usize,
        /// Number of shards (tasks).
        count: usize,
    },
}

/// Most shard tasks of a run.
pub const MAX_SHARDS: usize = 4096;

/// Where a call of [`optimize`] stopped.
#[derive(Debug)]
pub enum Progress {
    /// The run is complete.
    Finished(Box<Outcome>),
    /// `Collect`: the step `step` with `points` evaluations to do is planned in `step.json`.
    Planned {
        /// The step.
        step: usize,
        /// Its evaluations still to do.
        points: usize,
    },
    /// `Shard`: this shard's share of step `step` is done (`evaluated` now, `kept` from an
    /// earlier attempt of the same task).
    ShardDone {
        /// The step.
        step: usize,
        /// Evaluated by this call.
        evaluated: usize,
        /// Found already in the shard's file.
        kept: usize,
    },
}

/// One evaluation of the search.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Record {
    /// Index (0-based, the order of proposal).
    pub index: usize,
    /// Step (0: the initial design).
    pub step: usize,
    /// Unit coordinates.
    pub unit: Vec<f64>,
    /// Parameter values.
    pub params: Vec<f64>,
    /// Metrics (and their errors).
    pub metrics: BTreeMap<String, f64>,
    /// Each constraint's normalised violation (≤ 0 met).
    pub violations: Vec<f64>,
    /// All constraints met.
    pub feasible: bool,
    /// Seconds.
    pub seconds: f64,
    /// The study's digest (checked on resume).
    pub study: String,
}

impl Record {
    /// The record's numbers in a fixed order (unit, params, violations, metrics by name):
    /// the ones its checkpoint line also holds as bit patterns.
    fn numbers(&self) -> impl Iterator<Item = f64> + '_ {
        self.unit
            .iter()
            .chain(&self.params)
            .chain(&self.violations)
            .chain(self.metrics.values())
            .copied()
    }

    /// The record as one JSON line: its fields, and `bits`, the IEEE-754 bit patterns of its
    /// numbers, so that [`Record::from_line`] gives back the numbers written exactly (a JSON
    /// reader's decimal parsing may be off by an ulp, and NaN is written as null).
    pub fn to_line(&self) -> String {
        let mut v = serde_json::to_value(self).unwrap_or_default();
        if let serde_json::Value::Object(m) = &mut v {
            m.insert(
                "bits".into(),
                self.numbers()
                    .map(|x| x.to_bits())
                    .collect::<Vec<u64>>()
                    .into(),
            );
        }
        v.to_string()
    }

    /// Reads a line of [`Record::to_line`]; the numbers come from its bit patterns.
    pub fn from_line(line: &str) -> Result<Record, String> {
        use serde_json::Value;
        let v: Value = serde_json::from_str(line).map_err(|e| e.to_string())?;
        let len = |k: &str| v[k].as_array().map(Vec::len).ok_or(format!("no {k}"));
        let (nu, np, nv) = (len("unit")?, len("params")?, len("violations")?);
        let names: Vec<String> = v["metrics"]
            .as_object()
            .ok_or("no metrics")?
            .keys()
            .cloned()
            .collect();
        let bits: Vec<u64> = v["bits"]
            .as_array()
            .ok_or("no bits")?
            .iter()
            .map(|b| b.as_u64().ok_or("a bit pattern is not an integer"))
            .collect::<Result<_, _>>()?;
        if bits.len() != nu + np + nv + names.len() {
            return Err(format!(
                "{} bit patterns for {} numbers",
                bits.len(),
                nu + np + nv + names.len()
            ));
        }
        let mut x = bits.into_iter().map(f64::from_bits);
        let mut take = |n: usize| x.by_ref().take(n).collect::<Vec<f64>>();
        let (unit, params, violations) = (take(nu), take(np), take(nv));
        let metrics = names.into_iter().zip(take(usize::MAX)).collect();
        let int = |k: &str| v[k].as_u64().map(|i| i as usize).ok_or(format!("no {k}"));
        Ok(Record {
            index: int("index")?,
            step: int("step")?,
            unit,
            params,
            metrics,
            violations,
            feasible: v["feasible"].as_bool().ok_or("no feasible")?,
            seconds: v["seconds"].as_f64().unwrap_or(f64::NAN),
            study: v["study"].as_str().ok_or("no study")?.to_string(),
        })
    }
}

/// What a run found.
#[derive(Clone, Debug, Serialize)]
pub struct Outcome {
    /// Every evaluation, by index.
    pub records: Vec<Record>,
    /// The base design's metrics at the search fidelity.
    pub base: BTreeMap<String, f64>,
    /// The fixed exposure (white peak) of the search.
    pub white_peak: f64,
    /// Index of the best feasible evaluation (None: infeasible study).
    pub best: Option<usize>,
    /// Infeasible study: the least-violating evaluation and the constraint that binds.
    pub least_violating: Option<(usize, String)>,
    /// Indices of the Pareto front (feasible, non-dominated), by the first objective.
    pub pareto: Vec<usize>,
    /// Final re-evaluations at the final fidelity: (index, metrics); the base design first
    /// (index None).
    pub finals: Vec<(Option<usize>, BTreeMap<String, f64>)>,
}

/// The violations of every constraint of `study` at a point with scene `overrides` and
/// `metrics`.
pub fn violations(
    study: &Study,
    overrides: &[String],
    metrics: &BTreeMap<String, f64>,
) -> Result<Vec<f64>, OptimizeError> {
    let scene = SceneSource::File(study.scene.as_deref())
        .load(overrides)
        .map_err(|e| OptimizeError::Input(e.to_string()))?
        .scene;
    let value = |k: &str| scene_value(&scene, k).unwrap_or(f64::NAN);
    Ok(study
        .constraints
        .iter()
        .map(|c| {
            let v = match &c.what {
                Bounded::Metric(m) => metrics.get(&m.to_string()).copied().unwrap_or(f64::NAN),
                Bounded::Key(k) => value(k),
                Bounded::Sum(ks) => ks.iter().map(|k| value(k)).sum(),
            };
            c.violation(v)
        })
        .collect())
}

/// The Latin hypercube of `n` points in `d` dimensions (module notes).
pub fn latin_hypercube(n: usize, d: usize, seed: u64) -> Vec<Vec<f64>> {
    use crate::sampler::{hash, to_unit};
    let mut pts = vec![vec![0.0; d]; n];
    for a in 0..d {
        // A seeded permutation of the strata: sort by hash.
        let mut order: Vec<(u64, usize)> = (0..n)
            .map(|i| (hash(&[seed, 0x4C48_5300, a as u64, i as u64]), i))
            .collect();
        order.sort_unstable();
        for (stratum, &(_, i)) in order.iter().enumerate() {
            let jitter = to_unit(hash(&[seed, 0x4C48_5301, a as u64, i as u64]));
            pts[i][a] = (stratum as f64 + jitter) / n as f64;
        }
    }
    pts
}

/// The objective value of a record for the optimiser (minimised): NaN replaced by `worst`.
fn minimised(study: &Study, k: usize, r: &Record) -> f64 {
    let o = &study.objectives[k];
    let v = r
        .metrics
        .get(&o.metric.to_string())
        .copied()
        .unwrap_or(f64::NAN);
    match o.goal {
        Goal::Maximize => -v,
        Goal::Minimize => v,
    }
}

/// The points of step `step` (≥ 1) given the records of the earlier steps.
fn suggest(study: &Study, records: &[Record], step: usize, seed: u64) -> Vec<Vec<f64>> {
    use egobox_ego::EgorServiceBuilder;
    let d = study.parameters.len();
    let n_obj = study.objectives.len();
    let mut eps: Vec<f64> = Vec::new();
    // ε levels of the other objectives (minimised form: value ≤ ε).
    for k in 1..n_obj {
        let vals: Vec<f64> = records
            .iter()
            .map(|r| minimised(study, k, r))
            .filter(|v| v.is_finite())
            .collect();
        let (lo, hi) = vals
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        let l = (step + k) % study.epsilon_levels;
        eps.push(if lo.is_finite() {
            lo + (l as f64 + 0.5) / study.epsilon_levels as f64 * (hi - lo)
        } else {
            0.0
        });
    }
    let n_cstr = study.constraints.len() + eps.len();
    let xs = Array2::from_shape_fn((records.len(), d), |(i, j)| records[i].unit[j]);
    let obj: Vec<f64> = records.iter().map(|r| minimised(study, 0, r)).collect();
    let worst = obj
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(f64::NEG_INFINITY, f64::max);
    let worst = if worst.is_finite() { worst } else { 0.0 };
    let ys = Array2::from_shape_fn((records.len(), 1 + n_cstr), |(i, j)| {
        if j == 0 {
            let v = obj[i];
            if v.is_finite() { v } else { worst }
        } else if j <= study.constraints.len() {
            records[i].violations[j - 1].min(1.0)
        } else {
            let k = j - study.constraints.len();
            let v = minimised(study, k, &records[i]);
            let span = eps[k - 1].abs().max(1e-9);
            if v.is_finite() {
                ((v - eps[k - 1]) / span).min(1.0)
            } else {
                1.0
            }
        }
    });
    let mut limits = Array2::zeros((d, 2));
    for j in 0..d {
        limits[[j, 1]] = 1.0;
    }
    let batch = study.batch;
    let service = EgorServiceBuilder::optimize()
        .configure(|c| {
            c.n_cstr(n_cstr)
                .seed(crate::sampler::hash(&[seed, 0x5355_4747, step as u64]))
                .configure_qei(|q| q.batch(batch))
        })
        .min_within(&limits);
    let pts = match service {
        Ok(s) => s.suggest(&xs, &ys),
        Err(_) => Array2::zeros((0, d)),
    };
    let mut out: Vec<Vec<f64>> = pts
        .outer_iter()
        .map(|r| r.iter().map(|v| v.clamp(0.0, 1.0)).collect())
        .collect();
    // Fewer points than asked (or none): fill with Latin hypercube points of this step.
    let fill = latin_hypercube(
        batch,
        d,
        crate::sampler::hash(&[seed, 0x4649_4C4C, step as u64]),
    );
    out.extend(fill.into_iter().skip(out.len()));
    out.truncate(batch);
    out
}

/// The scene overrides of unit point `u`.
fn point(study: &Study, u: &[f64]) -> (Vec<f64>, Vec<String>) {
    let params: Vec<f64> = study
        .parameters
        .iter()
        .zip(u)
        .map(|(p, &x)| p.value(x))
        .collect();
    let o = study.overrides(&params);
    (params, o)
}

/// Evaluates the design of `overrides` for `study` at `fidelity`.
pub fn evaluate_design(
    study: &Study,
    overrides: &[String],
    fidelity: &Fidelity,
    exposure: Exposure,
) -> Result<Evaluation, EvalError> {
    let req = study.request(fidelity, exposure);
    evaluate(SceneSource::File(study.scene.as_deref()), overrides, &req)
}

/// Reads the checkpoint of a resumed run.
fn read_checkpoint(path: &Path, study: &Study, digest: &str) -> Result<Vec<Record>, OptimizeError> {
    let Some(text) = read_if_any(path)? else {
        return Ok(Vec::new());
    };
    let mut out: Vec<Record> = Vec::new();
    let lines: Vec<&str> = text.lines().collect();
    for (i, line) in lines.iter().enumerate() {
        let bad =
            |m: String| OptimizeError::Input(format!("{}: line {}: {m}", path.display(), i + 1));
        let r: Record = match Record::from_line(line) {
            Ok(r) => r,
            // A last line cut by a kill is dropped (it is evaluated again).
            Err(_) if i + 1 == lines.len() && !text.ends_with('\n') => break,
            Err(e) => return Err(bad(format!("not an evaluation record ({e})"))),
        };
        if r.study != digest {
            return Err(bad(format!(
                "written for another study or seed (digest {} against {digest}); use a new --out",
                r.study
            )));
        }
        if r.unit.len() != study.parameters.len() || r.violations.len() != study.constraints.len() {
            return Err(bad(
                "does not match the study's parameters and constraints".into()
            ));
        }
        if out.iter().any(|o| o.index == r.index) {
            return Err(bad(format!("evaluation {} twice", r.index)));
        }
        out.push(r);
    }
    out.sort_by_key(|r| r.index);
    Ok(out)
}

/// The checkpoint's file name.
pub const HISTORY: &str = "history.jsonl";
/// The base design's evaluation (metrics and exposure).
pub const BASE: &str = "base.json";
/// The step planned for shard tasks.
pub const STEP: &str = "step.json";

fn write_error(path: &Path, e: impl std::fmt::Display) -> OptimizeError {
    OptimizeError::Write(format!("{}: {e}", path.display()))
}

/// The bit patterns of `x` as a JSON array.
fn bits_of(x: impl Iterator<Item = f64>) -> serde_json::Value {
    x.map(f64::to_bits).collect::<Vec<u64>>().into()
}

/// The numbers of JSON array `v` of bit patterns.
fn numbers_of(v: &serde_json::Value) -> Option<Vec<f64>> {
    v.as_array()?
        .iter()
        .map(|b| b.as_u64().map(f64::from_bits))
        .collect()
}

/// Reads a text file of the run, checked as every input is (a regular file of at most
/// `MAX_TEXT_BYTES`, UTF-8); None if it does not exist.
fn read_if_any(path: &Path) -> Result<Option<String>, OptimizeError> {
    use crate::io::IoError;
    match crate::io::input::read_text(path) {
        Ok(t) => Ok(Some(t)),
        Err(IoError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
            Ok(None)
        }
        Err(e) => Err(OptimizeError::Input(e.to_string())),
    }
}

/// Reads a small JSON file of the run (`base.json`, `step.json`): None if it does not exist;
/// its `study` digest checked.
fn read_run_json(path: &Path, digest: &str) -> Result<Option<serde_json::Value>, OptimizeError> {
    let bad = |m: String| OptimizeError::Input(format!("{}: {m}", path.display()));
    let Some(text) = read_if_any(path)? else {
        return Ok(None);
    };
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad(format!("not JSON ({e})")))?;
    match v["study"].as_str() {
        Some(d) if d == digest => Ok(Some(v)),
        Some(d) => Err(bad(format!(
            "written for another study or seed (digest {d} against {digest}); use a new --out"
        ))),
        None => Err(bad("no study digest".into())),
    }
}

/// The base design's evaluation as `base.json` holds it: (metrics, white peak), read back
/// exactly from the bit patterns.
fn read_base(
    out: &Path,
    digest: &str,
) -> Result<Option<(BTreeMap<String, f64>, f64)>, OptimizeError> {
    let path = out.join(BASE);
    let Some(v) = read_run_json(&path, digest)? else {
        return Ok(None);
    };
    let bad = |m: &str| OptimizeError::Input(format!("{}: {m}", path.display()));
    let names: Vec<String> = v["metrics"]
        .as_object()
        .ok_or_else(|| bad("no metrics"))?
        .keys()
        .cloned()
        .collect();
    let x = numbers_of(&v["bits"]).ok_or_else(|| bad("no bit patterns"))?;
    if x.len() != names.len() + 1 {
        return Err(bad("the bit patterns do not match the metrics"));
    }
    Ok(Some((
        names.into_iter().zip(x[1..].iter().copied()).collect(),
        x[0],
    )))
}

fn base_json(digest: &str, metrics: &BTreeMap<String, f64>, white_peak: f64) -> String {
    serde_json::json!({
        "study": digest,
        "white_peak": white_peak,
        "metrics": metrics,
        "bits": bits_of(std::iter::once(white_peak).chain(metrics.values().copied())),
    })
    .to_string()
}

/// The planned step in `step.json`: (step, [(index, unit point)]), checked against the study
/// (digest, dimensions, indices below the budget, points in the unit cube).
fn read_step(
    out: &Path,
    study: &Study,
    digest: &str,
    budget: usize,
) -> Result<(usize, Vec<(usize, Vec<f64>)>), OptimizeError> {
    let path = out.join(STEP);
    let bad = |m: &str| OptimizeError::Input(format!("{}: {m}", path.display()));
    let v = read_run_json(&path, digest)?.ok_or_else(|| {
        OptimizeError::Input(format!(
            "{}: no step is planned: run `stscam optimize STUDY --out {} --collect` first",
            path.display(),
            out.display()
        ))
    })?;
    let step = v["step"].as_u64().ok_or_else(|| bad("no step"))? as usize;
    let indices = v["indices"].as_array().ok_or_else(|| bad("no indices"))?;
    let points = v["bits"].as_array().ok_or_else(|| bad("no bit patterns"))?;
    if indices.len() != points.len() {
        return Err(bad("the indices and the points differ in number"));
    }
    let d = study.parameters.len();
    indices
        .iter()
        .zip(points)
        .map(|(i, p)| {
            let i = i
                .as_u64()
                .filter(|&i| (i as usize) < budget)
                .ok_or_else(|| bad(&format!("an index is not below --budget {budget}")))?;
            let u = numbers_of(p)
                .filter(|u| u.len() == d && u.iter().all(|x| (0.0..=1.0).contains(x)))
                .ok_or_else(|| bad("a point is not in the study's unit cube"))?;
            Ok((i as usize, u))
        })
        .collect::<Result<_, _>>()
        .map(|p| (step, p))
}

/// The shard files in `out` (`shard-*.jsonl`), sorted.
fn shard_files(out: &Path) -> Result<Vec<std::path::PathBuf>, OptimizeError> {
    let mut v = Vec::new();
    let rd = match std::fs::read_dir(out) {
        Ok(rd) => rd,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(v),
        Err(e) => return Err(OptimizeError::Input(format!("{}: {e}", out.display()))),
    };
    for e in rd.flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        if n.starts_with("shard-") && n.ends_with(".jsonl") {
            v.push(e.path());
        }
    }
    v.sort();
    Ok(v)
}

/// Adds the records of every shard file to `records`; a record held twice must be the same
/// to the bit.
fn merge_shards(
    out: &Path,
    study: &Study,
    digest: &str,
    records: &mut Vec<Record>,
) -> Result<Vec<std::path::PathBuf>, OptimizeError> {
    let files = shard_files(out)?;
    for f in &files {
        for r in read_checkpoint(f, study, digest)? {
            match records.iter().find(|o| o.index == r.index) {
                Some(o)
                    if o.numbers()
                        .map(f64::to_bits)
                        .eq(r.numbers().map(f64::to_bits)) => {}
                Some(_) => {
                    return Err(OptimizeError::Input(format!(
                        "{}: evaluation {} differs from the one already recorded",
                        f.display(),
                        r.index
                    )));
                }
                None => records.push(r),
            }
        }
    }
    records.sort_by_key(|r| r.index);
    Ok(files)
}

/// Writes `records` as a fresh checkpoint file (dropping a cut last line), synced, and opens
/// it for appending.
fn rewrite_checkpoint(path: &Path, records: &[Record]) -> Result<std::fs::File, OptimizeError> {
    let mut file = std::fs::File::create(path).map_err(|e| write_error(path, e))?;
    for r in records {
        writeln!(file, "{}", r.to_line()).map_err(|e| write_error(path, e))?;
    }
    file.sync_data().map_err(|e| write_error(path, e))?;
    Ok(file)
}

/// The best feasible first objective among `rs`, in the objective's own sign.
fn best_of(study: &Study, rs: &[Record]) -> Option<f64> {
    let sign = if study.objectives[0].goal == Goal::Maximize {
        1.0
    } else {
        -1.0
    };
    rs.iter()
        .filter(|r| r.feasible)
        .map(|r| -minimised(study, 0, r))
        .filter(|v| v.is_finite())
        .fold(None, |b: Option<f64>, v| Some(b.map_or(v, |b| b.max(v))))
        .map(|b| b * sign)
}

/// What evaluations of a step need besides their points.
struct StepContext<'a> {
    study: &'a Study,
    step: usize,
    search: &'a Fidelity,
    exposure: Exposure,
    digest: &'a str,
    /// The file each record is appended to (and synced) as it ends.
    file: std::sync::Mutex<std::fs::File>,
    path: &'a Path,
    /// Records so far (for the progress line's best value).
    live: std::sync::Mutex<Vec<Record>>,
    on_record: &'a (dyn Fn(&Record, Option<f64>) + Sync),
}

impl StepContext<'_> {
    /// Evaluates `todo` in parallel, each record appended to the file as it ends.
    fn evaluate(&self, todo: &[&(usize, Vec<f64>)]) -> Result<Vec<Record>, OptimizeError> {
        let cancel = crate::cancel::current();
        let study = self.study;
        todo.par_iter()
            .map(|(index, u)| {
                if cancel.is_cancelled() {
                    return Err(OptimizeError::Cancelled);
                }
                let (params, overrides) = point(study, u);
                let ev = evaluate_design(study, &overrides, self.search, self.exposure)?;
                let violations = violations(study, &overrides, &ev.values)?;
                let r = Record {
                    index: *index,
                    step: self.step,
                    unit: u.clone(),
                    params,
                    feasible: violations.iter().all(|v| *v <= 0.0),
                    metrics: ev.values,
                    violations,
                    seconds: ev.seconds,
                    study: self.digest.to_string(),
                };
                let mut f = self.file.lock().unwrap_or_else(|p| p.into_inner());
                writeln!(f, "{}", r.to_line())
                    .and_then(|()| f.sync_data())
                    .map_err(|e| write_error(self.path, e))?;
                // One progress line as each evaluation finishes (under the file's lock, so
                // lines never interleave).
                let mut done = self.live.lock().unwrap_or_else(|p| p.into_inner());
                done.push(r.clone());
                (self.on_record)(&r, best_of(study, &done));
                Ok(r)
            })
            .collect()
    }
}

fn exposure_of(white_peak: f64) -> Exposure {
    if white_peak.is_finite() {
        Exposure::WhitePeak(white_peak)
    } else {
        Exposure::Own
    }
}

/// A shard task: evaluates its share of the planned step (module notes, "Shards").
fn run_shard(
    study: &Study,
    set: &RunSettings,
    out: &Path,
    digest: &str,
    (index, count): (usize, usize),
    on_record: &(dyn Fn(&Record, Option<f64>) + Sync),
) -> Result<Progress, OptimizeError> {
    if count == 0 || count > MAX_SHARDS || index >= count {
        return Err(OptimizeError::Input(format!(
            "--shard {index}/{count}: needs 0 <= I < N <= {MAX_SHARDS}"
        )));
    }
    let (step, plan) = read_step(out, study, digest, set.budget)?;
    let (_, white_peak) = read_base(out, digest)?.ok_or_else(|| {
        OptimizeError::Input(format!(
            "{}: missing; run `stscam optimize STUDY --out {} --collect` first",
            out.join(BASE).display(),
            out.display()
        ))
    })?;
    let mut search = study.search.clone();
    search.seed = set.seed;
    let path = out.join(format!("shard-{index:03}-of-{count:03}.jsonl"));
    let kept = read_checkpoint(&path, study, digest)?;
    let file = rewrite_checkpoint(&path, &kept)?;
    let todo: Vec<&(usize, Vec<f64>)> = plan
        .iter()
        .enumerate()
        .filter(|(k, (i, _))| k % count == index && !kept.iter().any(|r| r.index == *i))
        .map(|(_, p)| p)
        .collect();
    let n_kept = plan
        .iter()
        .enumerate()
        .filter(|(k, (i, _))| k % count == index && kept.iter().any(|r| r.index == *i))
        .count();
    let ctx = StepContext {
        study,
        step,
        search: &search,
        exposure: exposure_of(white_peak),
        digest,
        file: std::sync::Mutex::new(file),
        path: &path,
        live: std::sync::Mutex::new(kept),
        on_record,
    };
    let evaluated = ctx.evaluate(&todo)?.len();
    Ok(Progress::ShardDone {
        step,
        evaluated,
        kept: n_kept,
    })
}

/// Runs the study (module notes) as `set.role` says, writing the checkpoint into `out`;
/// `on_record` is called after each evaluation with the record and the best feasible first
/// objective so far.
pub fn optimize(
    study: &Study,
    set: &RunSettings,
    out: &Path,
    on_record: &(dyn Fn(&Record, Option<f64>) + Sync),
) -> Result<Progress, OptimizeError> {
    if set.budget == 0 || set.budget > crate::study::MAX_BUDGET {
        return Err(OptimizeError::Input(format!(
            "--budget {}: must be 1..={}",
            set.budget,
            crate::study::MAX_BUDGET
        )));
    }
    let digest = study.digest(set.seed);
    if let Role::Shard { index, count } = set.role {
        return run_shard(study, set, out, &digest, (index, count), on_record);
    }
    let collect = set.role == Role::Collect;
    let continuing = set.resume || collect;
    let ckpt = out.join(HISTORY);
    let mut records = if continuing {
        read_checkpoint(&ckpt, study, &digest)?
    } else {
        Vec::new()
    };
    let merged = if continuing {
        merge_shards(out, study, &digest, &mut records)?
    } else {
        Vec::new()
    };
    let mut search = study.search.clone();
    search.seed = set.seed;
    // The base design fixes the exposure.
    let cached = if continuing {
        read_base(out, &digest)?
    } else {
        None
    };
    let (base_values, white_peak, fresh) = match cached {
        Some((m, w)) => (m, w, false),
        None => {
            let b = evaluate_design(study, &study.set, &search, Exposure::Own)?;
            (b.values, b.white_peak, true)
        }
    };
    let exposure = exposure_of(white_peak);
    std::fs::create_dir_all(out).map_err(|e| write_error(out, e))?;
    if fresh {
        let p = out.join(BASE);
        crate::io::atomic::write_atomic(
            &p,
            base_json(&digest, &base_values, white_peak).as_bytes(),
        )
        .map_err(|e| write_error(&p, e))?;
    }
    // Rewrite the checkpoint with the records kept and merged (drops a cut last line); the
    // shard files merged are removed once it is on disk.
    let file = rewrite_checkpoint(&ckpt, &records)?;
    for f in merged {
        std::fs::remove_file(&f).map_err(|e| write_error(&f, e))?;
    }
    let d = study.parameters.len();
    let initial = study.initial.unwrap_or(2 * d + 2).min(set.budget);
    let cancel = crate::cancel::current();
    let mut ctx_file = std::sync::Mutex::new(file);
    let mut step = 0;
    let mut next = 0usize;
    while next < set.budget {
        let pts = if step == 0 {
            latin_hypercube(initial, d, set.seed)
        } else {
            let done: Vec<Record> = records.iter().filter(|r| r.step < step).cloned().collect();
            suggest(study, &done, step, set.seed)
        };
        let pts: Vec<(usize, Vec<f64>)> = pts
            .into_iter()
            .enumerate()
            .map(|(k, u)| (next + k, u))
            .filter(|(i, _)| *i < set.budget)
            .collect();
        next += pts.len();
        let todo: Vec<&(usize, Vec<f64>)> = pts
            .iter()
            .filter(|(i, _)| !records.iter().any(|r| r.index == *i))
            .collect();
        if collect && !todo.is_empty() {
            let p = out.join(STEP);
            let plan = serde_json::json!({
                "study": digest,
                "step": step,
                "indices": todo.iter().map(|(i, _)| *i).collect::<Vec<usize>>(),
                "bits": todo.iter().map(|(_, u)| bits_of(u.iter().copied())).collect::<Vec<_>>(),
            });
            crate::io::atomic::write_atomic(&p, plan.to_string().as_bytes())
                .map_err(|e| write_error(&p, e))?;
            return Ok(Progress::Planned {
                step,
                points: todo.len(),
            });
        }
        // Finished records in completion order, for the progress line only (the run's records
        // are collected in index order below).
        let ctx = StepContext {
            study,
            step,
            search: &search,
            exposure,
            digest: &digest,
            file: ctx_file,
            path: &ckpt,
            live: std::sync::Mutex::new(records.clone()),
            on_record,
        };
        records.extend(ctx.evaluate(&todo)?);
        records.sort_by_key(|r| r.index);
        ctx_file = ctx.file;
        step += 1;
    }
    match std::fs::remove_file(out.join(STEP)) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(write_error(&out.join(STEP), e));
        }
        _ => {}
    }
    records.sort_by_key(|r| r.index);
    let best = records
        .iter()
        .filter(|r| r.feasible && minimised(study, 0, r).is_finite())
        .min_by(|a, b| {
            minimised(study, 0, a)
                .total_cmp(&minimised(study, 0, b))
                .then(a.index.cmp(&b.index))
        })
        .map(|r| r.index);
    let least_violating = if best.is_none() {
        records
            .iter()
            .map(|r| {
                (
                    r.index,
                    r.violations.iter().map(|v| v.max(0.0)).sum::<f64>(),
                    r,
                )
            })
            .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
            .map(|(i, _, r)| {
                let k = (0..r.violations.len())
                    .max_by(|&a, &b| r.violations[a].total_cmp(&r.violations[b]))
                    .unwrap_or(0);
                (
                    i,
                    study
                        .constraints
                        .get(k)
                        .map_or_else(String::new, |c| c.name()),
                )
            })
    } else {
        None
    };
    let pareto = pareto_front(study, &records);
    let mut finals = Vec::new();
    if !set.skip_final && !cancel.is_cancelled() {
        let mut fin = study.final_check.clone();
        fin.seed = set.seed;
        let base_final = evaluate_design(study, &study.set, &fin, Exposure::Own)?;
        let fexp = if base_final.white_peak.is_finite() {
            Exposure::WhitePeak(base_final.white_peak)
        } else {
            Exposure::Own
        };
        finals.push((None, base_final.values));
        let mut chosen: Vec<usize> = best.into_iter().collect();
        for &p in pareto.iter() {
            if chosen.len() >= 8 {
                break;
            }
            if !chosen.contains(&p) {
                chosen.push(p);
            }
        }
        for i in chosen {
            let r = &records[records.iter().position(|r| r.index == i).unwrap_or(0)];
            let ev = evaluate_design(study, &study.overrides(&r.params), &fin, fexp)?;
            finals.push((Some(i), ev.values));
        }
    }
    Ok(Progress::Finished(Box::new(Outcome {
        records,
        base: base_values,
        white_peak,
        best,
        least_violating,
        pareto,
        finals,
    })))
}

/// The feasible evaluations no other feasible one dominates (every objective at least as
/// good, one better), sorted by the first objective, best first.
pub fn pareto_front(study: &Study, records: &[Record]) -> Vec<usize> {
    let n_obj = study.objectives.len();
    let vals = |r: &Record| {
        (0..n_obj)
            .map(|k| minimised(study, k, r))
            .collect::<Vec<f64>>()
    };
    let cand: Vec<(&Record, Vec<f64>)> = records
        .iter()
        .filter(|r| r.feasible)
        .map(|r| (r, vals(r)))
        .filter(|(_, v)| v.iter().all(|x| x.is_finite()))
        .collect();
    let mut front: Vec<(&Record, &Vec<f64>)> = cand
        .iter()
        .filter(|(_, v)| {
            !cand.iter().any(|(_, w)| {
                w.iter().zip(v.iter()).all(|(a, b)| a <= b)
                    && w.iter().zip(v.iter()).any(|(a, b)| a < b)
            })
        })
        .map(|(r, v)| (*r, v))
        .collect();
    front.sort_by(|a, b| a.1[0].total_cmp(&b.1[0]).then(a.0.index.cmp(&b.0.index)));
    front.iter().map(|(r, _)| r.index).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checkpoint_lines_give_back_every_number_to_the_bit() {
        let r = Record {
            index: 3,
            step: 1,
            unit: vec![0.1 + 0.2, 1.0 / 3.0],
            params: vec![9.354450572158317, 1e-300],
            metrics: [
                ("a".to_string(), f64::NAN),
                ("b".to_string(), -0.0),
                ("c".to_string(), 2.0f64.sqrt()),
            ]
            .into(),
            violations: vec![f64::MIN_POSITIVE],
            feasible: true,
            seconds: 1.5,
            study: "x".into(),
        };
        let back = Record::from_line(&r.to_line()).unwrap();
        let bits = |r: &Record| r.numbers().map(f64::to_bits).collect::<Vec<_>>();
        assert_eq!(bits(&back), bits(&r));
        assert_eq!(
            (back.index, back.step, back.feasible, back.study.as_str()),
            (3, 1, true, "x")
        );
        // A line whose bit patterns were cut is refused.
        let cut = r
            .to_line()
            .replace(&format!("{},", (0.1f64 + 0.2).to_bits()), "");
        assert!(Record::from_line(&cut).is_err());
    }

    #[test]
    fn latin_hypercube_fills_every_stratum_once() {
        let n = 7;
        let pts = latin_hypercube(n, 3, 42);
        for a in 0..3 {
            let mut strata: Vec<usize> = pts
                .iter()
                .map(|p| (p[a] * n as f64).floor() as usize)
                .collect();
            strata.sort_unstable();
            assert_eq!(strata, (0..n).collect::<Vec<_>>());
        }
        assert_eq!(pts, latin_hypercube(n, 3, 42));
        assert_ne!(pts, latin_hypercube(n, 3, 43));
    }
}
