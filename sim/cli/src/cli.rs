//! The `stscam` command line: argument parsing and exit codes only, shared by the binary
//! (`sim/main.rs`) and the Python package's `stscam` command. Every command's work is a
//! library function in `crate::jobs` taking the options parsed here; bad input (scene,
//! overrides, images, arguments) prints one line and exits with code 2; nothing is written to
//! `--out` unless the whole job succeeded (the one exception: `matrix --check` writes H and
//! then exits 1 if the check fails, so the files can be inspected).

use std::ffi::OsString;

use clap::{Parser, Subcommand};

use crate::{self as jobs, Console};

/// Spectral simulator of the holographic-waveguide see-through-screen camera.
#[derive(Parser, Debug)]
#[command(name = "stscam", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render the capture: DIR/capture.exr, capture.png and capture.json.
    Render(jobs::render::RenderOptions),
    /// Compute the system matrix H in one pass: DIR/H.npz (scipy CSR), H.json, offset.npy.
    Matrix(jobs::matrix::MatrixOptions),
    /// Simulate the paper's Hadamard calibration of H: DIR/H_est.npz and calibration.json.
    Calibrate(jobs::calibrate::CalibrateOptions),
    /// Reconstruct the object from a capture with H (CGM or ADMM-TV), or with a depth stack
    /// (`H_stack.npz` from `matrix --depth-mm D1,D2,…`): joint multi-depth ADMM-TV or depth
    /// estimation.
    Reconstruct(jobs::reconstruct::ReconstructOptions),
    /// The paper's experiment end to end: targets, captures, H, calibration, CGM and ADMM-TV,
    /// a table like its Table 1 and a figure like its Fig. 9.
    Demo(jobs::demo::DemoOptions),
    /// Generate a dataset from a recipe (datasets/*.toml), or merge shards
    /// (`stscam dataset merge SHARD_DIR... --out DIR`).
    Dataset(jobs::dataset::DatasetOptions),
    /// Design sweep: FOV (and what limits it), scene field, replicas, pitch, light efficiency,
    /// Bragg range and optionally the ADMM-TV PSNR over a grid of scene-key values:
    /// DIR/sweep.{csv,json} and a PNG + SVG plot per quantity.
    Sweep(jobs::sweep::SweepOptions),
    /// Fabrication tolerances: Monte Carlo draws of hoe.* errors (`--draw KEY=normal(M,SD)` or
    /// `uniform(LO,HI)`), per draw FOV, peak efficiency, replica weights, band centres and
    /// optionally the PSNR with the nominal H; yield and sensitivity ranking: DIR/draws.{csv,jsonl},
    /// summary.json and PNG plots; or shards merged (`stscam tolerance merge SHARD_DIR... --out DIR`).
    Tolerance(jobs::tolerance::ToleranceOptions),
    /// One design's metrics (captured and waveguide FOV, replicas, efficiency, colour bands,
    /// reconstruction PSNR and SSIM at a fixed exposure, yield and tolerance quantiles): text
    /// or one JSON object with `<name>_error` beside each Monte Carlo metric.
    Evaluate(jobs::evaluate::EvaluateOptions),
    /// Optimise a design study (TOML: parameters, objectives, constraints, fidelity) by
    /// constrained Bayesian optimisation, a Pareto front for several objectives, resumable:
    /// DIR/history.{csv,jsonl}, pareto.csv, best.toml, report.md and plots.
    Optimize(jobs::optimize::OptimizeOptions),
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        which: BenchCommand,
    },
    /// Cross-checks against independent references.
    Validate {
        #[command(subcommand)]
        which: ValidateCommand,
    },
    /// Design summary: angles, replica pitch and count, Bragg wavelengths, field of view.
    Info(jobs::info::InfoOptions),
    /// Relative RMSE ‖a − b‖₂/‖b‖₂ of two captures (all shared channels), b the reference.
    Compare(jobs::compare::CompareOptions),
    /// Trace the chief ray of one pixel at its exact Bragg wavelength.
    Probe(jobs::probe::ProbeOptions),
    /// Efficiency of every diffracted order of one vHOE film (Kogelnik or RCWA, bulk or contact
    /// stack) over a wavelength range: text or JSON, and a plot with --out.
    Grating(jobs::grating::GratingOptions),
    /// Stray-light report: every path light can take through the plate (Fresnel ghosts, every
    /// grating's orders, cross-coupling, repeated film passes), the image split by path class,
    /// each class's share of the signal: DIR/stray.{json,md,png} and class images (EXR, PNG).
    Stray(jobs::stray::StrayOptions),
}

#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// Run time against error for each estimator (and other renderers' curves given as JSON):
    /// DIR/bench-render.{json,md,svg,png}.
    Render(jobs::bench::BenchRenderOptions),
    /// BVH build time and closest-hit rays per second with 1 and 2 threads on a displaced
    /// sphere of at least TRIANGLES triangles (incoherent rays; medians over RUNS seeds).
    Bvh(jobs::bench::BenchBvhOptions),
    /// H, calibration and reconstruction speed at the scene's size (medians).
    Recon(jobs::bench::BenchReconOptions),
    /// RCWA time per point on one core (medians) and the efficiency-table build time and
    /// measured interpolation error for the scene's film, as JSON.
    Grating(jobs::bench::BenchGratingOptions),
}

#[derive(Subcommand, Debug)]
enum ValidateCommand {
    /// The tracer against closed forms across the whole field (Bragg wavelength, guided angle,
    /// replica pitch and count, FOV limits, replica count against bottom-vHOE height):
    /// DIR/analytic.{md,csv,json} and plots; exit code 1 if a comparison fails.
    Analytic(jobs::validate::AnalyticOptions),
}

/// An argument error as one line (clap's `error:` line) plus its one-line usage hint, if any.
fn argument_error(rendered: &str) -> String {
    let lines: Vec<&str> = rendered.lines().map(str::trim).collect();
    let error = lines
        .iter()
        .find(|l| l.starts_with("error:"))
        .copied()
        .unwrap_or_else(|| lines.first().copied().unwrap_or("error: bad arguments"));
    match lines.iter().find(|l| l.starts_with("Usage:")) {
        Some(usage) => format!("{error}\n{usage}"),
        None => error.to_string(),
    }
}

/// Runs the command line `args` (the program name first, as `std::env::args_os` gives it):
/// the exit code (0 success, 1 a failed write or check, 2 bad input or arguments).
pub fn run<I, T>(args: I) -> u8
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let cli = match Cli::try_parse_from(args) {
        Ok(c) => c,
        Err(e) if e.use_stderr() => {
            eprintln!("{}", argument_error(&e.render().to_string()));
            return 2;
        }
        Err(e) => {
            // --help and --version: a text that cannot be written fails (a closed pipe does not).
            if let Err(w) = e.print()
                && w.kind() != std::io::ErrorKind::BrokenPipe
            {
                eprintln!("error: cannot write the help to standard output: {w}");
                return 1;
            }
            return 0;
        }
    };
    let con = &Console::Terminal;
    let result = match &cli.command {
        Command::Render(o) => jobs::render::run(o, con).map(drop),
        Command::Matrix(o) => jobs::matrix::run(o, con),
        Command::Calibrate(o) => jobs::calibrate::run(o, con),
        Command::Reconstruct(o) => jobs::reconstruct::run(o, con),
        Command::Demo(o) => jobs::demo::run(o, con),
        Command::Dataset(o) => jobs::dataset::run(o, con),
        Command::Sweep(o) => jobs::sweep::run(o, con),
        Command::Tolerance(o) => jobs::tolerance::run(o, con),
        Command::Evaluate(o) => jobs::evaluate::run(o, con),
        Command::Optimize(o) => jobs::optimize::run(o, con),
        Command::Bench { which } => match which {
            BenchCommand::Bvh(o) => jobs::bench::run_bvh(o, con),
            BenchCommand::Recon(o) => jobs::bench::run_recon(o, con),
            BenchCommand::Grating(o) => jobs::bench::run_grating(o, con),
            BenchCommand::Render(o) => jobs::bench::run_render(o, con),
        },
        Command::Validate {
            which: ValidateCommand::Analytic(o),
        } => jobs::validate::run_analytic(o, con),
        Command::Info(o) => jobs::info::run(o, con).map(drop),
        Command::Compare(o) => jobs::compare::run(o, con).map(drop),
        Command::Probe(o) => jobs::probe::run(o, con).map(drop),
        Command::Grating(o) => jobs::grating::run(o, con).map(drop),
        Command::Stray(o) => jobs::stray::run(o, con).map(drop),
    };
    match result {
        Ok(()) => match jobs::stdout_failure() {
            Some(m) => {
                eprintln!("error: {m}");
                1
            }
            None => 0,
        },
        Err(e) => {
            eprintln!("error: {}", e.message);
            e.code
        }
    }
}
