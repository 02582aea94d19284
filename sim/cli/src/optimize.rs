//! `stscam optimize`: a design study (TOML) optimised within a budget of evaluations.

use std::path::PathBuf;

use stscam_design::optimize::{Outcome, Progress, Role, RunSettings, optimize};
use stscam_design::report;
use stscam_design::study::Study;

use super::*;

/// Optimise a design study: DIR/history.{csv,jsonl}, pareto.csv, best.toml, summary.json,
/// report.md and plots.
#[derive(clap::Args, Debug, Clone)]
pub struct OptimizeOptions {
    /// The study file (TOML, docs/design-studies.md).
    pub study: PathBuf,
    /// Evaluations of the search (the base design's is extra).
    #[arg(long, default_value_t = 40)]
    pub budget: usize,
    /// Seed of the initial design, the optimiser and the evaluations.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output directory.
    #[arg(long, default_value = "out/optimize")]
    pub out: PathBuf,
    /// Continue the run whose checkpoint (DIR/history.jsonl) is in --out.
    #[arg(long)]
    pub resume: bool,
    /// Skip the final re-evaluation of the best and Pareto designs at the final fidelity.
    #[arg(long)]
    pub skip_final: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Evaluate shard I of N (0-based) of the step planned in --out by `--collect`, into
    /// DIR/shard-III-of-NNN.jsonl, and stop (a cluster's array task; resumable).
    #[arg(long, value_name = "I/N", value_parser = parse_shard, conflicts_with_all = ["collect", "resume"])]
    pub shard: Option<(usize, usize)>,
    /// Merge the shard files in --out into the checkpoint, then plan the next step for the
    /// shard tasks (DIR/step.json) or, with the budget spent, write the run's files.
    #[arg(long, conflicts_with = "resume")]
    pub collect: bool,
}

/// Parses `I/N` (0 <= I < N <= MAX_SHARDS).
fn parse_shard(s: &str) -> Result<(usize, usize), String> {
    let bad = || {
        format!(
            "`{s}`: expected I/N with 0 <= I < N <= {}, e.g. 0/4",
            stscam_design::optimize::MAX_SHARDS
        )
    };
    let (i, n) = s.split_once('/').ok_or_else(bad)?;
    let (i, n) = (
        i.trim().parse::<usize>().map_err(|_| bad())?,
        n.trim().parse::<usize>().map_err(|_| bad())?,
    );
    if i < n && n <= stscam_design::optimize::MAX_SHARDS {
        Ok((i, n))
    } else {
        Err(bad())
    }
}

impl OptimizeOptions {
    /// The options of a local run (no shards).
    pub fn local(study: PathBuf, budget: usize, seed: u64, out: PathBuf) -> Self {
        OptimizeOptions {
            study,
            budget,
            seed,
            out,
            resume: false,
            skip_final: false,
            threads: None,
            shard: None,
            collect: false,
        }
    }

    fn role(&self) -> Role {
        match (self.shard, self.collect) {
            (Some((index, count)), _) => Role::Shard { index, count },
            (None, true) => Role::Collect,
            (None, false) => Role::Local,
        }
    }
}

/// The files of a finished run.
fn files(
    study: &Study,
    o: &Outcome,
    seed: u64,
    budget: usize,
) -> Result<Vec<(String, Vec<u8>)>, Failure> {
    let mut f = vec![
        (
            "history.csv".to_string(),
            report::history_csv(study, o).into_bytes(),
        ),
        (
            "pareto.csv".to_string(),
            report::pareto_csv(study, o).into_bytes(),
        ),
        (
            "report.md".to_string(),
            report::report_md(study, o, seed, budget).into_bytes(),
        ),
    ];
    let mut jsonl = String::new();
    for r in &o.records {
        jsonl.push_str(&r.to_line());
        jsonl.push('\n');
    }
    f.push(("history.jsonl".to_string(), jsonl.into_bytes()));
    if let Some(b) = o.best {
        let r = report::record(o, b);
        let toml = report::scene_toml(study, &r.params).map_err(write_failure)?;
        f.push(("best.toml".to_string(), toml.into_bytes()));
    }
    let summary = serde_json::json!({
        "study": study.file,
        "seed": seed,
        "budget": budget,
        "version": crate::VERSION,
        "feasible": o.best.is_some(),
        "best": o.best,
        "least_violating": o.least_violating.as_ref().map(|(i, c)| serde_json::json!({"index": i, "binding_constraint": c})),
        "pareto": o.pareto,
        "white_peak": o.white_peak,
        "base": o.base,
        "finals": o.finals.iter().map(|(i, m)| serde_json::json!({"index": i, "metrics": m})).collect::<Vec<_>>(),
    });
    // NaN is not JSON: serde_json writes null.
    f.push(("summary.json".to_string(), to_json(&summary)?.into_bytes()));
    for (stem, plot) in report::plots(study, o) {
        f.push((format!("{stem}.svg"), plot.to_svg().into_bytes()));
        f.push((format!("{stem}.png"), plot.to_png().map_err(write_failure)?));
    }
    Ok(f)
}

/// Runs `study` as the options say (budget, seed, `--out`, resume, shard or collect, final
/// re-evaluation) in the caller's thread pool and, when the run is complete, writes its files
/// into `--out` (all or nothing); `on_record` is called after each evaluation with its record
/// and the best feasible first objective so far; returns where the run stopped and the number
/// of files written. The CLI and the Python package both run studies through this.
pub fn run_study(
    study: &Study,
    o: &OptimizeOptions,
    on_record: &(dyn Fn(&stscam_design::optimize::Record, Option<f64>) + Sync),
) -> Result<(Progress, usize), JobError> {
    if o.budget == 0 || o.budget > stscam_design::study::MAX_BUDGET {
        return Err(bad_input(format!(
            "--budget {}: must be 1..={}",
            o.budget,
            stscam_design::study::MAX_BUDGET
        )));
    }
    check_out_dir(&o.out)?;
    let role = o.role();
    if role == Role::Local && !o.resume {
        use stscam_design::optimize::{BASE, HISTORY, STEP};
        if let Some(f) = [HISTORY, BASE, STEP]
            .into_iter()
            .find(|f| o.out.join(f).exists())
        {
            return Err(bad_input(format!(
                "{}: holds a run already ({f}); pass --resume to continue it or choose another --out",
                o.out.display()
            )));
        }
    }
    let set = RunSettings {
        budget: o.budget,
        seed: o.seed,
        resume: o.resume,
        skip_final: o.skip_final,
        role,
    };
    let progress = optimize(study, &set, &o.out, on_record).map_err(|e| match e {
        stscam_design::optimize::OptimizeError::Write(m) => write_failure(m),
        e => bad_input(e.to_string()),
    })?;
    let written = match &progress {
        Progress::Finished(outcome) => {
            let f = files(study, outcome, o.seed, o.budget)?;
            write_files(&o.out, &f)?;
            f.len()
        }
        _ => 0,
    };
    Ok((progress, written))
}

/// Runs the job.
pub fn run(o: &OptimizeOptions, con: &Console) -> Result<(), JobError> {
    let study = Study::load(&o.study).map_err(|e| bad_input(e.to_string()))?;
    let pool = thread_pool(o.threads)?;
    let goal = study.objectives[0].metric.to_string();
    let t0 = std::time::Instant::now();
    // Evaluations of a step finish in any order: the line counts what this run finished and
    // names the evaluation.
    let finished = std::sync::atomic::AtomicUsize::new(0);
    let on_record = |r: &stscam_design::optimize::Record, best: Option<f64>| {
        let v = r.metrics.get(&goal).copied().unwrap_or(f64::NAN);
        let k = finished.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        con.err(format_args!(
            "[{k} done] evaluation {} of {} (step {}): {goal} {v:.4}{} ({:.1} s); best feasible {}",
            r.index + 1,
            o.budget,
            r.step,
            if r.feasible { "" } else { ", infeasible" },
            r.seconds,
            best.map_or("none yet".to_string(), |b| format!("{b:.4}"))
        ));
    };
    let (progress, written) = pool.install(|| run_study(&study, o, &on_record))?;
    let outcome = match progress {
        Progress::Finished(outcome) => outcome,
        Progress::Planned { step, points } => {
            con.out(format_args!(
                "planned step {step}: {points} evaluations in {} for the shard tasks (--shard I/N), then --collect again",
                o.out.join(stscam_design::optimize::STEP).display()
            ));
            return Ok(());
        }
        Progress::ShardDone {
            step,
            evaluated,
            kept,
        } => {
            con.out(format_args!(
                "shard {}: step {step}: {evaluated} evaluations done{} in {:.1} s",
                o.shard.map_or(String::new(), |(i, n)| format!("{i}/{n}")),
                if kept > 0 {
                    format!(" ({kept} kept from an earlier attempt)")
                } else {
                    String::new()
                },
                t0.elapsed().as_secs_f64()
            ));
            return Ok(());
        }
    };
    match (outcome.best, &outcome.least_violating) {
        (Some(b), _) => {
            let r = report::record(&outcome, b);
            con.out(format_args!(
                "best feasible design: evaluation {b}, {goal} {:.4}: {}",
                r.metrics.get(&goal).copied().unwrap_or(f64::NAN),
                study.parameters.iter().zip(&r.params).map(|(p, v)| format!("{}={v}", p.keys[0])).collect::<Vec<_>>().join(" ")
            ));
        }
        (None, Some((i, c))) => con.out(format_args!(
            "infeasible: no evaluation met every constraint; the least-violating is evaluation {i}, where `{c}` binds most (no best.toml)"
        )),
        (None, None) => {}
    }
    con.err(format_args!(
        "wrote {} ({} evaluations, {} files) in {:.1} s ({} threads)",
        o.out.display(),
        outcome.records.len(),
        written,
        t0.elapsed().as_secs_f64(),
        pool.current_num_threads()
    ));
    Ok(())
}
