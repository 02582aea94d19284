//! `stscam tolerance`: Monte Carlo draws of fabrication errors and what they cost, or shards
//! merged.

use std::path::PathBuf;
use std::time::Instant;

use super::*;

/// `stscam tolerance`.
#[derive(Args, Debug, Clone)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct ToleranceOptions {
    /// `tolerance merge`, instead of a run.
    #[command(subcommand)]
    pub merge: Option<ToleranceCommand>,
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// A drawn key and its distribution: `KEY=normal(MEAN,SD)` or `KEY=uniform(LO,HI)`, KEY a
    /// hoe.* key (e.g. `hoe.shrinkage=normal(0.01,0.005)`); repeatable, drawn independently.
    #[arg(long, value_name = "KEY=DIST", required = true)]
    pub draw: Vec<String>,
    /// Number of draws.
    #[arg(long, required = true)]
    pub samples: Option<usize>,
    /// Seed of the draws (and of H and the captures with --psnr).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Make only shard I of N (0-based): DIR/draws.jsonl and shard.json, joined by
    /// `stscam tolerance merge`. Default: from SLURM_ARRAY_TASK_ID/_COUNT/_MIN, or from
    /// JOB_COMPLETION_INDEX and STSCAM_SHARD_COUNT, else all.
    #[arg(long, value_name = "I/N")]
    pub shard: Option<String>,
    /// Output directory.
    #[arg(long, default_value = "out/tolerance")]
    pub out: PathBuf,
    /// Vertical field angles (degrees in air) of the band centres, comma-separated.
    #[arg(long, value_name = "DEG,...", default_value = "-15,-10,-5,0,5,10,15")]
    pub field_deg: String,
    /// Also the PSNR with the nominal H (the calibration going stale): a render and an
    /// ADMM-TV solve per draw; keep the crop and --psnr-spp small.
    #[arg(long)]
    pub psnr: bool,
    /// Built-in target of --psnr, without @SIZE (the scene's display size is used).
    #[arg(long, default_value = "letter:F")]
    pub psnr_target: String,
    /// Samples per pixel of the nominal H and each capture for --psnr.
    #[arg(long, default_value_t = 4)]
    pub psnr_spp: u32,
    /// Yield: the vertical FOV must be at least this, degrees.
    #[arg(long)]
    pub min_fov_deg: Option<f64>,
    /// Yield: every grating's peak efficiency (on axis, display polarisation) at least this.
    #[arg(long)]
    pub min_efficiency: Option<f64>,
    /// Yield: no field's band centre may move more than this from nominal, nm.
    #[arg(long)]
    pub max_band_shift_nm: Option<f64>,
    /// Yield: the PSNR with the nominal H at least this, dB (needs --psnr).
    #[arg(long)]
    pub min_psnr_db: Option<f64>,
    /// Yield: a requirement on any scalar figure, `NAME>=VALUE` or `NAME<=VALUE` (repeatable):
    /// a figure of the summary or an `evaluate` geometry or colour metric, e.g.
    /// `fov_capture_vertical_deg>=30`, `efficiency_mean>=0.01`, `psnr_gain_db>=25` (--psnr).
    #[arg(long, value_name = "NAME>=V")]
    pub require: Vec<String>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// `stscam tolerance`'s subcommand.
#[derive(Subcommand, Debug, Clone)]
pub enum ToleranceCommand {
    /// Join finished shards into the outputs of one unsharded run (byte-identical).
    Merge {
        /// Shard folders.
        #[arg(required = true)]
        shards: Vec<PathBuf>,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
    },
}

fn fail(e: stscam_studies::tolerance::ToleranceError) -> Failure {
    bad_input(e.to_string())
}

fn report(con: &Console, s: &stscam_studies::tolerance::Summary) {
    for (name, st) in &s.figures {
        con.out(format_args!(
            "{name}: nominal {:.6}, mean {:.6}, sd {:.3e}, 5-95 % [{:.6}, {:.6}]",
            st.nominal, st.mean, st.sd, st.p05, st.p95
        ));
    }
    let y = &s.yield_;
    con.out(format_args!(
        "yield {}/{} = {:.4} (± {:.4}){}",
        y.passed,
        y.total,
        y.fraction,
        y.std_error,
        y.per_threshold
            .iter()
            .map(|(n, f)| format!(", {n} {f:.4}"))
            .collect::<String>()
    ));
    for (name, r) in &s.ranking {
        let top: Vec<String> = r
            .iter()
            .map(|k| format!("{} {:.2} (rho {:+.2})", k.key, k.share, k.rho))
            .collect();
        con.out(format_args!("ranking {name}: {}", top.join(", ")));
    }
}

fn cmd_tolerance(o: &ToleranceOptions, con: &Console) -> Result<(), Failure> {
    use stscam_studies::tolerance::{
        Requirement, Thresholds, ToleranceSettings, merge, run_tolerance,
    };
    if let Some(ToleranceCommand::Merge { shards, out }) = &o.merge {
        check_out_dir(out)?;
        let (files, summary) = merge(shards).map_err(fail)?;
        write_files(out, &files)?;
        report(con, &summary);
        con.err(format_args!(
            "merged {} shards into {} ({} draws)",
            shards.len(),
            out.display(),
            summary.yield_.total
        ));
        return Ok(());
    }
    let field_deg: Vec<f64> = o
        .field_deg
        .split(',')
        .map(|s| s.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect::<Option<_>>()
        .ok_or_else(|| {
            bad_input(format!(
                "--field-deg {}: expected numbers separated by commas",
                o.field_deg
            ))
        })?;
    if o.min_psnr_db.is_some() && !o.psnr {
        return Err(bad_input("--min-psnr-db: needs --psnr"));
    }
    for (flag, v) in [
        ("--min-fov-deg", o.min_fov_deg),
        ("--min-efficiency", o.min_efficiency),
        ("--max-band-shift-nm", o.max_band_shift_nm),
        ("--min-psnr-db", o.min_psnr_db),
    ] {
        if v.is_some_and(|v| !v.is_finite()) {
            return Err(bad_input(format!("{flag}: must be a finite number")));
        }
    }
    if o.psnr {
        crate::targets::builtin_target(&o.psnr_target)
            .map_err(|e| bad_input(format!("--psnr-target: {e}")))?;
    }
    let shard = match &o.shard {
        Some(s) => {
            Some(stscam_dataset::Shard::parse(s).map_err(|m| bad_input(format!("--shard: {m}")))?)
        }
        None => stscam_dataset::Shard::from_env(|k| std::env::var(k).ok()).map_err(bad_input)?,
    };
    check_out_dir(&o.out)?;
    let pool = thread_pool(o.threads)?;
    let set = ToleranceSettings {
        draws: o.draw.clone(),
        samples: o
            .samples
            .ok_or_else(|| bad_input("--samples: give the number of draws"))?,
        seed: o.seed,
        field_deg,
        psnr: o.psnr.then(|| stscam_studies::sweep::PsnrSettings {
            target: o.psnr_target.clone(),
            spp: o.psnr_spp,
            seed: o.seed,
        }),
        thresholds: Thresholds {
            min_fov_deg: o.min_fov_deg,
            min_efficiency: o.min_efficiency,
            max_band_shift_nm: o.max_band_shift_nm,
            min_psnr_db: o.min_psnr_db,
            require: o
                .require
                .iter()
                .map(|r| Requirement::parse(r))
                .collect::<Result<_, _>>()
                .map_err(fail)?,
        },
    };
    let t0 = Instant::now();
    let res = pool
        .install(|| run_tolerance(o.scene.scene.as_deref(), &o.scene.set, &set, shard, true))
        .map_err(fail)?;
    let secs = t0.elapsed().as_secs_f64();
    write_files(&o.out, &res.files)?;
    if let Some(s) = &res.summary {
        report(con, s);
    }
    con.err(format_args!(
        "wrote {} ({} draws{}, {} files) in {:.1} s, {:.1} draws/s ({} threads)",
        o.out.display(),
        res.draws.len(),
        shard.map_or(String::new(), |s| format!(
            ", shard {}/{}",
            s.index, s.count
        )),
        res.files.len(),
        secs,
        res.draws.len() as f64 / secs,
        pool.current_num_threads()
    ));
    Ok(())
}

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`.
pub fn run(o: &ToleranceOptions, con: &Console) -> Result<(), JobError> {
    cmd_tolerance(o, con)
}
