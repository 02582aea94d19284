//! `stscam dataset`: a dataset from a recipe, or shards merged.

use std::path::PathBuf;

use super::*;

/// `stscam dataset`.
#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct DatasetOptions {
    /// `dataset merge`, instead of a recipe.
    #[command(subcommand)]
    pub merge: Option<DatasetCommand>,
    /// Recipe (TOML).
    #[arg(required = true)]
    pub recipe: Option<PathBuf>,
    /// Output directory (default: out/datasets/NAME, or out/datasets/NAME-shard-III-of-NNN).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Make only shard I of N (0-based). Default: from SLURM_ARRAY_TASK_ID/_COUNT/_MIN, or
    /// from JOB_COMPLETION_INDEX and STSCAM_SHARD_COUNT (Kubernetes Indexed Job), else all.
    #[arg(long, value_name = "I/N")]
    pub shard: Option<String>,
    /// Continue a killed or finished run in --out: keep finished samples, redo the rest.
    #[arg(long)]
    pub resume: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// `stscam dataset`'s subcommand.
#[derive(Subcommand, Debug)]
pub enum DatasetCommand {
    /// Join finished shards into one dataset, checking them (byte-identical to an unsharded run).
    Merge {
        /// Shard folders.
        #[arg(required = true)]
        shards: Vec<PathBuf>,
        /// Output directory (must not exist or be empty).
        #[arg(long)]
        out: PathBuf,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
    },
}

fn cmd_dataset(args: &DatasetOptions, con: &Console) -> Result<(), Failure> {
    use stscam_dataset::{RunOptions, Shard, generate, merge, plan};
    let fail = |e: stscam_dataset::DatasetError| match e {
        stscam_dataset::DatasetError::Write(_) => write_failure(e),
        _ => bad_input(e.to_string()),
    };
    if let Some(DatasetCommand::Merge {
        shards,
        out,
        threads,
    }) = &args.merge
    {
        let pool = thread_pool(*threads)?;
        let s = pool.install(|| merge(shards, out)).map_err(fail)?;
        con.err(format_args!(
            "merged {} shards into {} ({} samples, checksums verified) in {:.1} s",
            shards.len(),
            out.display(),
            s.samples,
            s.finish_s
        ));
        return Ok(());
    }
    let recipe = args
        .recipe
        .as_deref()
        .ok_or_else(|| bad_input("dataset: give a RECIPE (or `merge`)"))?;
    let pool = thread_pool(args.threads)?;
    let shard = match &args.shard {
        Some(s) => Some(Shard::parse(s).map_err(|m| bad_input(format!("--shard: {m}")))?),
        None => Shard::from_env(|k| std::env::var(k).ok()).map_err(bad_input)?,
    };
    let p = pool.install(|| plan(recipe)).map_err(fail)?;
    let out = args.out.clone().unwrap_or_else(|| {
        let name = match shard {
            Some(s) => format!("{}-shard-{:03}-of-{:03}", p.recipe.name, s.index, s.count),
            None => p.recipe.name.clone(),
        };
        PathBuf::from("out/datasets").join(name)
    });
    let opts = RunOptions {
        out: out.clone(),
        shard,
        resume: args.resume,
        progress: true,
    };
    let s = pool.install(|| generate(&p, &opts)).map_err(fail)?;
    con.err(format_args!(
        "wrote {} ({} samples{}, {} generated now; H and exposure {:.1} s, samples {:.1} s = {:.1} samples/s, checksums and card {:.1} s; {} threads)",
        out.display(),
        s.samples,
        shard.map_or(String::new(), |s| format!(
            ", shard {}/{}",
            s.index, s.count
        )),
        s.generated,
        s.scenes_s,
        s.samples_s,
        s.samples_per_s,
        s.finish_s,
        pool.current_num_threads()
    ));
    for sc in &p.scenes {
        warn_coverage(&sc.system, &format!("{}: ", sc.id), con);
    }
    Ok(())
}

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`.
pub fn run(o: &DatasetOptions, con: &Console) -> Result<(), JobError> {
    cmd_dataset(o, con)
}
