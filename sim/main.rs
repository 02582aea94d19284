//! `stscam` command line: a thin layer that parses arguments, calls the library and reports.
//! Bad input (scene, overrides, images, arguments) prints one line and exits with code 2;
//! nothing is written to `--out` unless the whole job succeeded (the one exception:
//! `matrix --check` writes H and then exits 1 if the check fails, so the files can be inspected).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use clap::{Args, Parser, Subcommand, ValueEnum};

use stscam::analysis;
use stscam::output::{CAPTURE_UNITS, write_capture_with};
use stscam::render::{RenderSettings, render};
use stscam::sampler::SamplerKind;
use stscam::scene::{LoadedScene, load_scene};
use stscam::system::System;

/// Spectral simulator of the holographic-waveguide see-through-screen camera.
#[derive(Parser, Debug)]
#[command(name = "stscam", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// Scene selection shared by every command.
#[derive(Args, Debug, Clone)]
struct SceneArgs {
    /// Scene file (TOML); keys it omits come from the embedded paper scene. Default: the
    /// embedded `scenes/paper-2022.toml`.
    scene: Option<PathBuf>,
    /// Override a scene key, e.g. `--set plate.thickness_mm=3` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
}

/// Monte Carlo and threading options shared by the commands that trace.
#[derive(Args, Debug, Clone)]
struct RunArgs {
    /// Samples (camera paths) per pixel.
    #[arg(long, default_value_t = 64)]
    spp: u32,
    /// Seed of the sampler (and of the sensor noise, where there is noise).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
}

impl RunArgs {
    /// (spp, seed, threads) after checking that spp is at least 1.
    fn checked(&self) -> Result<(u32, u64, Option<usize>), Failure> {
        if self.spp == 0 {
            return Err(bad_input("--spp: must be at least 1"));
        }
        Ok((self.spp, self.seed, self.threads))
    }
}

#[derive(ValueEnum, Clone, Copy, Debug)]
enum SamplerArg {
    /// Cranley–Patterson-rotated rank-1 lattice: a Korobov rule searched for the spp, or R_5.
    Lattice,
    /// Independent hashed random numbers.
    Independent,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render the capture: DIR/capture.exr, capture.png and capture.json.
    Render {
        #[command(flatten)]
        scene: SceneArgs,
        /// Output directory.
        #[arg(long, default_value = "out/render")]
        out: PathBuf,
        #[command(flatten)]
        run: RunArgs,
        /// Also write spectral channels (bins of about 10 nm tiling the sampling band) into the EXR.
        #[arg(long)]
        spectral: bool,
        /// Sample sequence.
        #[arg(long, value_enum, default_value = "lattice")]
        sampler: SamplerArg,
        /// 3-D scenes: size of frontal.exr, depth.exr and mask.png, `N` or `WxH` (default: the
        /// capture's crop size).
        #[arg(long, value_name = "N|WxH")]
        frontal_px: Option<String>,
    },
    /// Compute the system matrix H in one pass: DIR/H.npz (scipy CSR), H.json, offset.npy.
    Matrix {
        #[command(flatten)]
        scene: SceneArgs,
        /// Output directory.
        #[arg(long, default_value = "out/matrix")]
        out: PathBuf,
        #[command(flatten)]
        run: RunArgs,
        /// Object (display) distance in mm for this H; the camera focus stays as the scene
        /// sets it. Default: `display.distance_mm`. A list `D1,D2,...` or a range
        /// `START:STOP:STEPS` writes a depth stack in one pass: H_<D>mm.npz, offset_<D>mm.npy
        /// and H_<D>mm.json per depth, and the block matrix H_stack.npz.
        #[arg(long = "depth-mm", value_name = "D|D1,D2,...|START:STOP:STEPS")]
        depth_mm: Option<String>,
        /// Also render the scene's target with the same seed and spp and check that
        /// H·f + offset equals it to float rounding (the matrix–render contract); the
        /// difference is recorded in H.json, and a failure exits with code 1.
        #[arg(long)]
        check: bool,
    },
    /// Simulate the paper's Hadamard calibration of H: DIR/H_est.npz and calibration.json.
    Calibrate {
        #[command(flatten)]
        scene: SceneArgs,
        /// Output directory.
        #[arg(long, default_value = "out/calibrate")]
        out: PathBuf,
        /// H_true to calibrate (scipy CSR .npz with its offset.npy); default: computed here.
        #[arg(long)]
        matrix: Option<PathBuf>,
        /// Object shape WxH of `--matrix` (default: from its H.json, else square).
        #[arg(long, value_name = "WxH")]
        object: Option<String>,
        #[command(flatten)]
        run: RunArgs,
        /// Sensor noise: `sensor` (the scene's [noise] section) or `none` (ideal camera).
        #[arg(long, value_enum, default_value = "sensor")]
        noise: NoiseArg,
        /// Store the estimate with a dark frame subtracted from every frame (the report always
        /// gives the errors with and without it).
        #[arg(long)]
        dark_frame: bool,
        /// Render every pattern with the Monte Carlo tracer instead of applying H_true.
        #[arg(long)]
        render: bool,
        /// Keep entries of H_est above this many predicted noise standard deviations.
        #[arg(long, default_value_t = stscam::hadamard::DEFAULT_THRESHOLD_SIGMA)]
        threshold_sigma: f64,
    },
    /// Reconstruct the object from a capture with H (CGM or ADMM-TV), or with a depth stack
    /// (`H_stack.npz` from `matrix --depth-mm D1,D2,…`): joint multi-depth ADMM-TV or depth
    /// estimation.
    Reconstruct(ReconArgs),
    /// The paper's experiment end to end: targets, captures, H, calibration, CGM and ADMM-TV,
    /// a table like its Table 1 and a figure like its Fig. 9.
    Demo {
        #[command(flatten)]
        scene: SceneArgs,
        /// Output directory.
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
        #[command(flatten)]
        run: RunArgs,
    },
    /// Generate a dataset from a recipe (datasets/*.toml), or merge shards
    /// (`stscam dataset merge SHARD_DIR... --out DIR`).
    Dataset(DatasetArgs),
    /// Design sweep: FOV (and what limits it), scene field, replicas, pitch, light efficiency,
    /// Bragg range and optionally the ADMM-TV PSNR over a grid of scene-key values:
    /// DIR/sweep.{csv,json} and a PNG + SVG plot per quantity.
    Sweep {
        #[command(flatten)]
        scene: SceneArgs,
        /// Varied key and its grid, e.g. `bottom_hoe.height_mm=10:80:15` (STEPS points from START
        /// to STOP; repeatable: the Cartesian product, first axis slowest).
        #[arg(long, value_name = "KEY=START:STOP:STEPS", required = true)]
        vary: Vec<String>,
        /// Output directory.
        #[arg(long, default_value = "out/sweep")]
        out: PathBuf,
        /// FOV: field angles whose throughput is at least this fraction of the peak.
        #[arg(long, default_value_t = stscam::sweep::DEFAULT_FOV_FRACTION)]
        fov_fraction: f64,
        /// Also compute the ADMM-TV PSNR of this built-in target (H, capture and noise as in
        /// `demo`; seconds per grid point), e.g. `letter:A`.
        #[arg(long, value_name = "TARGET")]
        psnr: Option<String>,
        /// Samples per pixel of H and the capture for --psnr.
        #[arg(long, default_value_t = 64)]
        psnr_spp: u32,
        /// Print the rows as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
    },
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
    Info {
        #[command(flatten)]
        scene: SceneArgs,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Relative RMSE ‖a − b‖₂/‖b‖₂ of two captures (all shared channels), b the reference.
    Compare {
        /// Capture to assess (EXR).
        a: PathBuf,
        /// Reference capture (EXR).
        b: PathBuf,
        /// Also write a 16-bit PNG map of |a − b| (first shared channel).
        #[arg(long, value_name = "PNG")]
        map: Option<PathBuf>,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Trace the chief ray of one pixel at its exact Bragg wavelength.
    Probe {
        #[command(flatten)]
        scene: SceneArgs,
        /// Pixel of the crop as COL,ROW.
        #[arg(long, value_name = "COL,ROW")]
        pixel: String,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
}

/// `stscam dataset`.
#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
struct DatasetArgs {
    #[command(subcommand)]
    merge: Option<DatasetCommand>,
    /// Recipe (TOML).
    #[arg(required = true)]
    recipe: Option<PathBuf>,
    /// Output directory (default: out/datasets/NAME, or out/datasets/NAME-shard-III-of-NNN).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Make only shard I of N (0-based). Default: from SLURM_ARRAY_TASK_ID/_COUNT/_MIN, or
    /// from JOB_COMPLETION_INDEX and STSCAM_SHARD_COUNT (Kubernetes Indexed Job), else all.
    #[arg(long, value_name = "I/N")]
    shard: Option<String>,
    /// Continue a killed or finished run in --out: keep finished samples, redo the rest.
    #[arg(long)]
    resume: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
}

#[derive(Subcommand, Debug)]
enum DatasetCommand {
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

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq)]
enum ErrorArg {
    /// Relative RMSE against a high-spp reference.
    Reference,
    /// ‖A − B‖/‖A + B‖ of two independent half renders.
    Halves,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq)]
enum NoiseArg {
    /// The scene's [noise] section.
    Sensor,
    /// An ideal camera.
    None,
}

/// `stscam reconstruct`'s arguments.
#[derive(Args, Debug)]
struct ReconArgs {
    /// System matrix (scipy CSR .npz); its offset.npy is used when present. A depth stack's
    /// H_stack.npz (its H_stack.json lists the depths) selects the stack methods.
    #[arg(long)]
    matrix: PathBuf,
    /// Capture: EXR (channels in H's row order) or float .npy.
    #[arg(long)]
    capture: PathBuf,
    /// Method (default: admm-tv with one H, joint with a depth stack).
    #[arg(long, value_enum)]
    method: Option<MethodArg>,
    /// Iterations (default: 50 for ADMM-TV, the paper's count; for CG see the README).
    #[arg(long)]
    iters: Option<usize>,
    /// ADMM-TV weight τ relative to ‖Hᵀg‖_∞ (scale-free).
    #[arg(long, default_value_t = stscam::recon::admm::DEFAULT_TAU_REL)]
    tau: f64,
    /// Joint: weight μ of the group sparsity across depth, relative to ‖Hᵀg‖_∞.
    #[arg(long, default_value_t = stscam::recon::joint::DEFAULT_MU_REL)]
    mu: f64,
    /// Total variation.
    #[arg(long, value_enum, default_value = "iso")]
    tv: TvArg,
    /// Object shape WxH (default: from H.json, else square).
    #[arg(long, value_name = "WxH")]
    object: Option<String>,
    /// Offset to subtract from the capture (default: offset.npy beside the matrix, if any).
    #[arg(long)]
    offset: Option<PathBuf>,
    /// Ground truth for PSNR/SSIM: a PNG (display code values), an EXR (linear) or a
    /// built-in target spec.
    #[arg(long)]
    truth: Option<String>,
    /// Display gamma used to linearise a PNG or built-in truth.
    #[arg(long, default_value_t = 2.2)]
    gamma: f64,
    /// Output directory.
    #[arg(long, default_value = "out/reconstruct")]
    out: PathBuf,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq)]
enum MethodArg {
    /// Conjugate gradients on the normal equations (the paper's CGM).
    Cg,
    /// ADMM with total variation.
    AdmmTv,
    /// Depth stack: joint multi-depth ADMM-TV with a sparsity prior across depth.
    Joint,
    /// Depth stack: estimate the depth of one planar object, then ADMM-TV at that depth.
    Depth,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq)]
enum TvArg {
    /// Isotropic TV.
    Iso,
    /// Anisotropic TV.
    Aniso,
}

#[derive(Subcommand, Debug)]
enum ValidateCommand {
    /// The tracer against closed forms across the whole field (Bragg wavelength, guided angle,
    /// replica pitch and count, FOV limits, replica count against bottom-vHOE height):
    /// DIR/analytic.{md,csv,json} and plots; exit code 1 if a comparison fails.
    Analytic {
        #[command(flatten)]
        scene: SceneArgs,
        /// Field angles to compare (at least 50).
        #[arg(long, default_value_t = 60)]
        fields: usize,
        /// Output directory.
        #[arg(long, default_value = "out/validate-analytic")]
        out: PathBuf,
    },
}

#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// Run time against error for each estimator (and other renderers' curves given as JSON):
    /// DIR/bench-render.{json,md,svg,png}.
    Render {
        #[command(flatten)]
        scene: SceneArgs,
        /// Output directory.
        #[arg(long, default_value = "out/bench-render-error")]
        out: PathBuf,
        /// Crop size N (N×N); the pixel pitch is scaled so the field of view stays that of the
        /// scene's crop.
        #[arg(long, default_value_t = 128)]
        crop: u32,
        /// Samples per pixel of the reference (default estimator, independent seed).
        #[arg(long, default_value_t = 4096)]
        ref_spp: u32,
        /// Time budget per estimator, s.
        #[arg(long, default_value_t = 60.0)]
        budget_s: f64,
        /// Target relative RMSE for the time-to-error figures.
        #[arg(long, default_value_t = 0.01)]
        target: f64,
        /// Error measure: against a high-spp reference, or from two independent half renders
        /// (no reference; what validation/mitsuba/bench.py measures for Mitsuba).
        #[arg(long, value_enum, default_value = "reference")]
        error: ErrorArg,
        /// Extra curves (JSON: {"name": ..., "points": [{"spp", "seconds", "relative_rmse"}]}),
        /// e.g. Mitsuba's from validation/mitsuba (repeatable).
        #[arg(long)]
        extra: Vec<PathBuf>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
        /// Only redraw the plots of DIR/bench-render.json (no rendering).
        #[arg(long)]
        replot: bool,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
    },
    /// BVH build time and closest-hit rays per second with 1 and 2 threads on a displaced
    /// sphere of at least TRIANGLES triangles (incoherent rays; medians over RUNS seeds).
    Bvh {
        /// Triangles of the test mesh.
        #[arg(long, default_value_t = 1_000_000)]
        triangles: usize,
        /// Rays per measurement.
        #[arg(long, default_value_t = 1_000_000)]
        rays: usize,
        /// Runs (seeds 1..=RUNS); medians are reported.
        #[arg(long, default_value_t = 3)]
        runs: u64,
    },
    /// H, calibration and reconstruction speed at the scene's size (medians).
    Recon {
        #[command(flatten)]
        scene: SceneArgs,
        /// Samples per pixel of H.
        #[arg(long, default_value_t = 64)]
        spp: u32,
        /// Timed runs per reconstruction figure.
        #[arg(long, default_value_t = 21)]
        runs: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
    },
}

/// Most timed runs of a benchmark figure (`bench recon --runs`).
const MAX_RUNS: usize = 1000;

/// Longest time budget per estimator of `bench render` (`--budget-s`): one day.
const MAX_BUDGET_S: f64 = 86_400.0;

/// Most field angles of `validate analytic --fields`.
const MAX_FIELDS: usize = 100_000;

/// Most iterations of `reconstruct --iters`.
const MAX_ITERS: usize = 1_000_000;

/// A CLI failure: exit code and one line.
struct Failure {
    code: u8,
    message: String,
}

fn bad_input(message: impl Into<String>) -> Failure {
    Failure {
        code: 2,
        message: message.into(),
    }
}

/// A job beyond a resource limit: bad input.
fn limit(e: stscam::limits::LimitError) -> Failure {
    bad_input(e.to_string())
}

fn load(args: &SceneArgs) -> Result<(LoadedScene, System), Failure> {
    let ls = load_scene(args.scene.as_deref(), &args.set).map_err(|e| bad_input(e.to_string()))?;
    let sys = System::build(&ls).map_err(|e| bad_input(e.to_string()))?;
    Ok((ls, sys))
}

fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool, Failure> {
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        stscam::limits::check_threads(t).map_err(limit)?;
        b = b.num_threads(t);
    }
    b.build().map_err(|e| Failure {
        code: 1,
        message: format!("cannot start worker threads: {e}"),
    })
}

fn to_json<T: serde::Serialize>(v: &T) -> Result<String, Failure> {
    serde_json::to_string_pretty(v).map_err(|e| Failure {
        code: 1,
        message: format!("cannot encode JSON: {e}"),
    })
}

#[allow(clippy::too_many_arguments)]
fn cmd_render(
    scene: &SceneArgs,
    out: &std::path::Path,
    run: &RunArgs,
    spectral: bool,
    sampler: SamplerArg,
    frontal_px: Option<&str>,
) -> Result<(), Failure> {
    let (spp, seed, threads) = run.checked()?;
    let frontal_size = frontal_px.map(parse_frontal_px).transpose()?;
    let start = Instant::now();
    if out.exists() && !out.is_dir() {
        return Err(bad_input(format!(
            "{}: --out exists and is not a directory",
            out.display()
        )));
    }
    let pool = thread_pool(threads)?;
    let (ls, sys) = pool.install(|| load(scene))?;
    let bins = spectral.then(|| stscam::render::spectral_bins(&sys.scene.sampling));
    let settings = RenderSettings {
        spp,
        seed,
        sampler: match sampler {
            SamplerArg::Lattice => SamplerKind::Lattice,
            SamplerArg::Independent => SamplerKind::Independent,
        },
        spectral_bins: bins,
        progress: true,
    };
    stscam::render::check_limits(&sys, &settings, 1, "--spp").map_err(limit)?;
    if let (Some((fw, fh)), true) = (frontal_size, sys.world.is_some()) {
        stscam::limits::check_paths("--frontal-px", fw as u128 * fh as u128 * u128::from(spp))
            .map_err(limit)?;
    }
    let t0 = Instant::now();
    let cap = pool.install(|| render(&sys, &settings));
    let render_s = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let (fw, fh) = frontal_size.unwrap_or((cap.width, cap.height));
    let frontal = pool.install(|| stscam::world::frontal::render_frontal(&sys, fw, fh, spp, seed));
    let frontal_s = t1.elapsed().as_secs_f64();
    let scene_json = serde_json::to_string(&sys.scene).map_err(|e| Failure {
        code: 1,
        message: e.to_string(),
    })?;
    let sidecar = serde_json::json!({
        "stscam_version": stscam::VERSION,
        "command": "render",
        "scene_source": ls.source,
        "overrides": scene.set,
        "scene": sys.scene,
        "seed": seed,
        "spp": spp,
        "sampler": settings.sampler,
        "threads": pool.current_num_threads(),
        "width": cap.width,
        "height": cap.height,
        "channels": cap.channel_names,
        "spectral_bins_nm": cap.spectral.iter().map(|(l, _)| *l).collect::<Vec<_>>(),
        "units": CAPTURE_UNITS,
        "render_time_s": render_s,
        "wall_time_s": start.elapsed().as_secs_f64(),
        "paths_per_second": cap.stats.camera_paths as f64 / render_s,
        "stats": cap.stats,
    });
    let mut sidecar = sidecar;
    if let (Some(world), Some(f)) = (sys.world.as_deref(), frontal.as_ref()) {
        sidecar["world"] = serde_json::json!({
            "objects": world.objects,
            "triangles": world.mesh.triangles.len(),
            "lights": sys.scene.light.len(),
            "bvh_build_s": world.accel.as_ref().map_or(0.0, |a| a.build_s),
            "display_enabled": sys.scene.display.enabled,
        });
        sidecar["frontal"] = serde_json::json!({
            "files": {
                "frontal.exr": format!("channels {:?}: {}", f.channel_names, stscam::output::FRONTAL_UNITS),
                "frontal.png": "16-bit preview of frontal.exr (sRGB-encoded, scaled to the 99.9th percentile)",
                "depth.exr": "channel Z: distance from the plate's front face along -z in mm, +inf where nothing is hit (pixel centre ray)",
                "mask.png": "16-bit grey: object index + 1 (see world.objects[].mask_value), 65535 the display, 0 nothing (pixel centre ray)",
            },
            "width": f.width,
            "height": f.height,
            "spp": spp,
            "camera": "pinhole at (0, 0, 0) mm (front face, bottom vHOE centre) looking along -z; pixel (c, r) looks along the capture's chief ray at crop position ((c + 0.5) * crop_w / w, (r + 0.5) * crop_h / h)",
            "rays": f.rays,
            "render_time_s": frontal_s,
        });
    }
    // A missing or unwritable output location is the user's to fix, but it is not bad input
    // to the simulator: exit 1.
    write_capture_with(
        out,
        &cap,
        &scene_json,
        seed,
        spp,
        &sidecar,
        frontal.as_ref(),
    )
    .map_err(|e| Failure {
        code: 1,
        message: e.to_string(),
    })?;
    if cap.stats.nonfinite_samples > 0 {
        eprintln!(
            "warning: {} samples were NaN or infinite and were zeroed",
            cap.stats.nonfinite_samples
        );
    }
    if cap.stats.max_truncated_weight > 1e-3 && cap.stats.max_contacts_hits == 0 {
        eprintln!(
            "warning: paths were stopped by sampling.min_guided_weight with up to {:.3e} of their guided weight left; lower it for this scene",
            cap.stats.max_truncated_weight
        );
    }
    if cap.stats.max_contacts_hits > 0 {
        eprintln!(
            "warning: {} paths hit sampling.max_contacts; up to {:.3e} of a path's guided weight was dropped",
            cap.stats.max_contacts_hits, cap.stats.max_truncated_weight
        );
    }
    eprintln!(
        "wrote {}/capture.{{exr,png,json}}: {}x{} px, {} spp, {:.3} s render, {:.2} M paths/s ({} threads)",
        out.display(),
        cap.width,
        cap.height,
        spp,
        render_s,
        cap.stats.camera_paths as f64 / render_s / 1e6,
        pool.current_num_threads()
    );
    Ok(())
}

/// `N` or `WxH` for `--frontal-px`.
fn parse_frontal_px(spec: &str) -> Result<(usize, usize), Failure> {
    let bad = || {
        bad_input(format!(
            "--frontal-px: expected N or WxH (1..=8192 each), got {spec:?}"
        ))
    };
    let (w, h) = match spec.split_once(['x', 'X']) {
        Some((a, b)) => (a.trim().parse::<usize>(), b.trim().parse::<usize>()),
        None => (spec.trim().parse::<usize>(), spec.trim().parse::<usize>()),
    };
    match (w, h) {
        (Ok(w), Ok(h)) if (1..=8192).contains(&w) && (1..=8192).contains(&h) => Ok((w, h)),
        _ => Err(bad()),
    }
}

fn check_out_dir(out: &std::path::Path) -> Result<(), Failure> {
    if out.exists() && !out.is_dir() {
        return Err(bad_input(format!(
            "{}: --out exists and is not a directory",
            out.display()
        )));
    }
    Ok(())
}

/// Writes named in-memory files into `out` as one unit (all or nothing).
fn write_files(out: &std::path::Path, files: &[(String, Vec<u8>)]) -> Result<(), Failure> {
    let refs: Vec<(&str, &[u8])> = files
        .iter()
        .map(|(n, b)| (n.as_str(), b.as_slice()))
        .collect();
    stscam::io::write_all_atomic(out, &refs).map_err(write_failure)
}

fn write_failure(e: impl std::fmt::Display) -> Failure {
    Failure {
        code: 1,
        message: e.to_string(),
    }
}

/// How `matrix --depth-mm` was given: one depth (the plain file names) or a stack.
enum DepthSpec {
    Single(f64),
    Stack(Vec<f64>),
}

fn parse_depth_spec(spec: &str) -> Result<DepthSpec, Failure> {
    let depths = stscam::stack::parse_depths(spec)
        .map_err(|m| bad_input(format!("--depth-mm {spec}: {m}")))?;
    Ok(if spec.contains([',', ':']) {
        DepthSpec::Stack(depths)
    } else {
        DepthSpec::Single(depths[0])
    })
}

/// The H.json sidecar of one depth's matrix.
#[allow(clippy::too_many_arguments)]
fn matrix_sidecar(
    ls: &LoadedScene,
    scene: &SceneArgs,
    sys: &System,
    settings: &RenderSettings,
    m: &stscam::matrix::SystemMatrix,
    depth_mm: f64,
    [npz, offset, _]: [&str; 3],
    linearity: Option<f64>,
) -> serde_json::Value {
    serde_json::json!({
        "stscam_version": stscam::VERSION,
        "command": "matrix",
        "linearity_check_max_rel_diff": linearity,
        "scene_source": ls.source,
        "overrides": scene.set,
        "scene": sys.scene,
        "seed": settings.seed,
        "spp": settings.spp,
        "sampler": settings.sampler,
        "depth_mm": depth_mm,
        "focus_distance_mm": sys.camera.focus_distance_mm,
        "shape": [m.h.rows, m.h.cols],
        "nnz": m.h.nnz(),
        "density": m.h.nnz() as f64 / (m.h.rows as f64 * m.h.cols as f64),
        "crop_px": [m.crop.0, m.crop.1],
        "object_px": [m.object.0, m.object.1],
        "channels": m.channels,
        "rows": "crop pixels, row-major (row 0 at the top, column 0 at the left as seen from the camera); with several channels the rows are channel-major: row = channel_index * width * height + pixel",
        "columns": "object (target) pixels, row-major, same orientation; the display is monochrome, one column per object pixel",
        "units": stscam::matrix::MATRIX_UNITS,
        "offset_file": offset,
        "files": {npz: "scipy.sparse CSR (float32 data, int32 indices and indptr while they fit)", offset: "float32 vector, one value per row of H"},
    })
}

/// `matrix --check`: renders `sys`'s target and returns max |H f + offset − render(f)| over the
/// capture's peak.
fn linearity_check(
    pool: &rayon::ThreadPool,
    sys: &System,
    settings: &RenderSettings,
    m: &stscam::matrix::SystemMatrix,
) -> f64 {
    let cap = pool.install(|| stscam::render::render(sys, settings));
    let pred = m.capture_of(&sys.display.intensity);
    let (mut diff, mut peak) = (0.0f64, 0.0f64);
    for (p, c) in pred.iter().zip(&cap.channels) {
        for (a, &b) in p.iter().zip(c) {
            diff = diff.max((a - f64::from(b)).abs());
            peak = peak.max(f64::from(b).abs());
        }
    }
    let rel = if peak > 0.0 { diff / peak } else { diff };
    eprintln!(
        "linearity check at {} mm: max |H f + offset - render(f)| = {rel:.3e} of the capture's peak",
        -sys.display.z_mm
    );
    rel
}

#[allow(clippy::too_many_arguments)]
fn cmd_matrix(
    scene: &SceneArgs,
    out: &std::path::Path,
    run: &RunArgs,
    depth_mm: Option<&str>,
    check: bool,
) -> Result<(), Failure> {
    let (spp, seed, threads) = run.checked()?;
    let start = Instant::now();
    let spec = depth_mm.map(parse_depth_spec).transpose()?;
    check_out_dir(out)?;
    let pool = thread_pool(threads)?;
    let (ls, mut sys) = pool.install(|| load(scene))?;
    if let Some(DepthSpec::Single(d)) = spec {
        stscam::matrix::place_object(&mut sys, d);
    }
    let settings = RenderSettings {
        spp,
        seed,
        sampler: SamplerKind::Lattice,
        spectral_bins: None,
        progress: true,
    };
    stscam::render::check_limits(&sys, &settings, 1 + u64::from(check), "--spp").map_err(limit)?;
    warn_coverage(&sys, "");
    if let Some(DepthSpec::Stack(depths)) = &spec {
        return matrix_stack(
            &ls, scene, &sys, &settings, &pool, depths, check, out, start,
        );
    }
    let t0 = Instant::now();
    let m = pool.install(|| stscam::matrix::compute_matrix(&sys, &settings));
    let matrix_s = t0.elapsed().as_secs_f64();
    let linearity = check.then(|| linearity_check(&pool, &sys, &settings, &m));
    let mut sidecar = matrix_sidecar(
        &ls,
        scene,
        &sys,
        &settings,
        &m,
        -sys.display.z_mm,
        ["H.npz", "offset.npy", "H.json"],
        linearity,
    );
    sidecar["threads"] = pool.current_num_threads().into();
    sidecar["matrix_time_s"] = matrix_s.into();
    sidecar["wall_time_s"] = start.elapsed().as_secs_f64().into();
    sidecar["paths_per_second"] = (m.stats.camera_paths as f64 / matrix_s).into();
    sidecar["stats"] = serde_json::to_value(&m.stats).unwrap_or_default();
    stscam::output::write_matrix(out, &m, &sidecar).map_err(write_failure)?;
    linearity.map(check_linearity).transpose()?;
    eprintln!(
        "wrote {}/H.{{npz,json}} and offset.npy: {} x {}, {} stored entries ({:.3} % dense), {} spp, {:.3} s ({} threads)",
        out.display(),
        m.h.rows,
        m.h.cols,
        m.h.nnz(),
        100.0 * m.h.nnz() as f64 / (m.h.rows as f64 * m.h.cols as f64),
        spp,
        matrix_s,
        pool.current_num_threads()
    );
    Ok(())
}

/// Fails (exit 1) if the linearity check is off by more than f32 storage explains.
fn check_linearity(rel: f64) -> Result<(), Failure> {
    // f32 storage of H, the offset and the capture: a few ulps.
    if rel.is_nan() || rel >= 1e-5 {
        return Err(Failure {
            code: 1,
            message: format!(
                "linearity check failed: H f + offset differs from the render by {rel:.3e} of its peak"
            ),
        });
    }
    Ok(())
}

/// `matrix --depth-mm LIST`: the depth stack in one pass (`stscam::stack`).
#[allow(clippy::too_many_arguments)]
fn matrix_stack(
    ls: &LoadedScene,
    scene: &SceneArgs,
    sys: &System,
    settings: &RenderSettings,
    pool: &rayon::ThreadPool,
    depths: &[f64],
    check: bool,
    out: &std::path::Path,
    start: Instant,
) -> Result<(), Failure> {
    use stscam::stack::{
        STACK_MATRIX, STACK_OFFSET, STACK_SIDECAR, coverage, depth_file_names, layered_offset,
    };
    let t0 = Instant::now();
    // Each H is held about four times while written (the matrices, the block matrix and both
    // encoded): the pass stops once its entries pass a quarter of the job memory limit.
    let budget = (stscam::limits::MAX_JOB_BYTES / 4) as u64;
    let stack = pool
        .install(|| stscam::matrix::compute_matrix_stack_within(sys, settings, depths, budget))
        .map_err(limit)?;
    let matrix_s = t0.elapsed().as_secs_f64();
    let mut files: Vec<(String, Vec<u8>)> = Vec::new();
    let mut per_depth = Vec::new();
    let mut failed_check = None;
    for (&d, m) in depths.iter().zip(&stack) {
        let names = depth_file_names(d);
        let linearity = check.then(|| {
            let mut s = sys.clone();
            s.display.z_mm = -d;
            linearity_check(pool, &s, settings, m)
        });
        if let Some(rel) = linearity {
            failed_check = failed_check.or(check_linearity(rel).err());
        }
        let cov = coverage(&m.h);
        let mut side = matrix_sidecar(
            ls,
            scene,
            sys,
            settings,
            m,
            d,
            [&names[0], &names[1], &names[2]],
            linearity,
        );
        side["coverage"] = serde_json::to_value(cov).unwrap_or_default();
        side["stack"] = STACK_MATRIX.into();
        side["stats"] = serde_json::to_value(&m.stats).unwrap_or_default();
        // The matrices are encoded below, in parallel.
        files.push((names[0].clone(), Vec::new()));
        files.push((
            names[1].clone(),
            stscam::io::npz::encode_npy_f32(&out.join(&names[1]), &[m.offset.len()], &m.offset)
                .map_err(write_failure)?,
        ));
        files.push((
            names[2].clone(),
            serde_json::to_vec_pretty(&side).map_err(write_failure)?,
        ));
        per_depth.push(serde_json::json!({
            "depth_mm": d, "matrix": names[0], "offset": names[1], "sidecar": names[2],
            "nnz": m.h.nnz(), "coverage": cov,
        }));
    }
    let blocks: Vec<&stscam::sparse::CsrMatrix> = stack.iter().map(|m| &m.h).collect();
    let block = stscam::sparse::CsrMatrix::hstack(&blocks).ok_or_else(|| {
        bad_input(format!(
            "--depth-mm: {} depths of {} object pixels exceed 32-bit column indices",
            depths.len(),
            stack[0].h.cols
        ))
    })?;
    let offset = layered_offset(&stack);
    let m0 = &stack[0];
    let sidecar = serde_json::json!({
        "stscam_version": stscam::VERSION,
        "command": "matrix",
        "depths_mm": depths,
        "scene_source": ls.source,
        "overrides": scene.set,
        "scene": sys.scene,
        "seed": settings.seed,
        "spp": settings.spp,
        "sampler": settings.sampler,
        "focus_distance_mm": sys.camera.focus_distance_mm,
        "shape": [block.rows, block.cols],
        "nnz": block.nnz(),
        "crop_px": [m0.crop.0, m0.crop.1],
        "object_px": [m0.object.0, m0.object.1],
        "channels": m0.channels,
        "rows": "as each depth's H (crop pixels, row-major; channel-major with several channels)",
        "columns": "depth-major blocks [H_1 ... H_N]: column = depth_index * object_pixels + object pixel (row-major), depths as in depths_mm",
        "model": "layered scene: g = sum_d (H_d f_d + o_d) + noise; planes are additive emitters without occlusion, each a display of the scene's extent at its depth; the camera focus, wavelength sampling and display extent are the scene's at every depth",
        "units": stscam::matrix::MATRIX_UNITS,
        "offset_file": STACK_OFFSET,
        "files": {STACK_MATRIX: "scipy.sparse CSR block matrix [H_1 ... H_N]", STACK_OFFSET: "float32 vector: sum over depths of the per-depth offsets (the capture with every layer black)"},
        "depths": per_depth,
        "coverage": "capture_filled = fraction of capture pixels some object pixel reaches; object_seen = fraction of object pixels the capture sees",
        "threads": pool.current_num_threads(),
        "matrix_time_s": matrix_s,
        "wall_time_s": start.elapsed().as_secs_f64(),
        "paths_per_second": m0.stats.camera_paths as f64 / matrix_s,
        "stats": m0.stats,
    });
    // Every matrix file (each depth's and the block matrix) encoded in parallel.
    let mut mats: Vec<&stscam::sparse::CsrMatrix> = blocks.clone();
    mats.push(&block);
    let encoded: Vec<Result<Vec<u8>, String>> = pool.install(|| {
        use rayon::prelude::*;
        mats.par_iter()
            .enumerate()
            .map(|(i, h)| {
                let name = if i < depths.len() {
                    depth_file_names(depths[i])[0].clone()
                } else {
                    STACK_MATRIX.to_string()
                };
                h.encode_npz(&out.join(name)).map_err(|e| e.to_string())
            })
            .collect()
    });
    let mut encoded = encoded.into_iter();
    for i in 0..depths.len() {
        files[3 * i].1 = encoded
            .next()
            .unwrap_or(Ok(Vec::new()))
            .map_err(write_failure)?;
    }
    files.push((
        STACK_MATRIX.to_string(),
        encoded
            .next()
            .unwrap_or(Ok(Vec::new()))
            .map_err(write_failure)?,
    ));
    files.push((
        STACK_OFFSET.to_string(),
        stscam::io::npz::encode_npy_f32(&out.join(STACK_OFFSET), &[offset.len()], &offset)
            .map_err(write_failure)?,
    ));
    files.push((
        STACK_SIDECAR.to_string(),
        serde_json::to_vec_pretty(&sidecar).map_err(write_failure)?,
    ));
    write_files(out, &files)?;
    if let Some(f) = failed_check {
        return Err(f);
    }
    eprintln!(
        "wrote {}: H at {} depths ({}) and {STACK_MATRIX} ({} x {}, {} stored entries), {} spp, {:.3} s in one pass ({} threads)",
        out.display(),
        depths.len(),
        if depths.len() <= 8 {
            depths
                .iter()
                .map(|d| format!("{d} mm"))
                .collect::<Vec<_>>()
                .join(", ")
        } else {
            format!("{} mm to {} mm", depths[0], depths[depths.len() - 1])
        },
        block.rows,
        block.cols,
        block.nnz(),
        settings.spp,
        matrix_s,
        pool.current_num_threads()
    );
    Ok(())
}

fn parse_object(spec: &str) -> Result<(usize, usize), Failure> {
    let parsed = spec
        .split_once(['x', 'X'])
        .and_then(|(a, b)| Some((a.trim().parse().ok()?, b.trim().parse().ok()?)))
        .filter(|&(a, b): &(usize, usize)| a > 0 && b > 0 && a.checked_mul(b).is_some());
    parsed.ok_or_else(|| bad_input(format!("--object {spec}: expected WxH, e.g. 64x64")))
}

/// Reads a capture as one vector in H's row order (EXR channels in file order, or .npy).
fn load_capture(path: &std::path::Path) -> Result<Vec<f64>, Failure> {
    let is_npy = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("npy"));
    let values: Vec<f64> = if is_npy {
        let (_, v) = stscam::io::npz::read_npy_f32(path).map_err(|e| bad_input(e.to_string()))?;
        stscam::io::check_finite(path, "value", &v).map_err(|e| bad_input(e.to_string()))?;
        v.into_iter().map(f64::from).collect()
    } else {
        let (_, _, chans) = stscam::io::read_exr(path).map_err(|e| bad_input(e.to_string()))?;
        // Sensor channels only (Y or R, G, B), in H's channel-major row order.
        let order = ["Y", "R", "G", "B"];
        let mut v = Vec::new();
        for name in order {
            if let Some(c) = chans.iter().find(|c| c.name == name) {
                stscam::io::check_finite(path, &format!("channel {name}: value"), &c.data)
                    .map_err(|e| bad_input(e.to_string()))?;
                v.extend(c.data.iter().map(|&x| f64::from(x)));
            }
        }
        if v.is_empty() {
            return Err(bad_input(format!(
                "{}: no Y or R, G, B channel",
                path.display()
            )));
        }
        v
    };
    Ok(values)
}

/// Linear intensities of a truth image or built-in target.
fn load_truth(spec: &str, gamma: f64, w: usize, h: usize) -> Result<Vec<f64>, Failure> {
    let (tw, th, v) = if stscam::system::is_image_path(spec) {
        let path = std::path::Path::new(spec);
        let img = stscam::io::load_image(path).map_err(|e| bad_input(e.to_string()))?;
        stscam::io::check_finite(path, "value", &img.values)
            .map_err(|e| bad_input(format!("--truth: {e}")))?;
        let v =
            stscam::display::Display::intensity_of(&img.values, img.channels, img.linear, gamma);
        (img.width, img.height, v)
    } else {
        let t = stscam::targets::builtin_target(spec)
            .map_err(|e| bad_input(format!("--truth: {e}")))?;
        let v = stscam::display::Display::intensity_of(&t.values, 1, false, gamma);
        (t.width, t.height, v)
    };
    if (tw, th) != (w, h) {
        return Err(bad_input(format!(
            "--truth {spec}: size {tw}x{th} differs from the object size {w}x{h}"
        )));
    }
    Ok(v)
}

#[allow(clippy::too_many_arguments)]
fn cmd_calibrate(
    scene: &SceneArgs,
    out: &std::path::Path,
    matrix: Option<&std::path::Path>,
    object: Option<&str>,
    run: &RunArgs,
    noise: NoiseArg,
    dark_frame: bool,
    render_frames: bool,
    threshold_sigma: f64,
) -> Result<(), Failure> {
    let (spp, seed, threads) = run.checked()?;
    use stscam::hadamard::{CalibrationJob, TrueMatrix, calibrate_scene};
    let start = Instant::now();
    if !(threshold_sigma.is_finite() && threshold_sigma >= 0.0) {
        return Err(bad_input(
            "--threshold-sigma: must be a non-negative number",
        ));
    }
    check_out_dir(out)?;
    let pool = thread_pool(threads)?;
    let (ls, sys) = pool.install(|| load(scene))?;
    let matrix = match matrix {
        Some(p) => {
            let shape = object.map(parse_object).transpose()?;
            let (m, offset_found) =
                TrueMatrix::load(p, shape).map_err(|e| bad_input(e.to_string()))?;
            if !offset_found {
                eprintln!(
                    "warning: no {} beside {}: the offset (all-black capture) is taken as 0",
                    stscam::matrix::default_offset_path(p).display(),
                    p.display()
                );
            }
            Some(m)
        }
        None => None,
    };
    let job = CalibrationJob {
        matrix,
        spp,
        seed,
        sensor_noise: noise == NoiseArg::Sensor,
        dark_frame,
        render_frames,
        threshold_sigma,
        progress: true,
    };
    let run = pool
        .install(|| calibrate_scene(&sys, &job))
        .map_err(bad_input)?;
    let (cal, object, source_desc, sensor_noise) =
        (&run.calibration, run.object, &run.source, &run.noise);
    let (matrix_s, render_s, calibrate_s) = (run.matrix_s, run.render_s, run.calibrate_s);
    let npz = cal
        .h_est
        .encode_npz(&out.join("H_est.npz"))
        .map_err(write_failure)?;
    let report = serde_json::json!({
        "stscam_version": stscam::VERSION,
        "command": "calibrate",
        "scene_source": ls.source,
        "overrides": scene.set,
        "matrix": source_desc,
        "spp": spp,
        "seed": seed,
        "frames_from": if render_frames { "rendered patterns" } else { "H_true" },
        "noise": if noise == NoiseArg::Sensor { serde_json::to_value(&sys.scene.noise).unwrap_or_default() } else { serde_json::Value::String("none".into()) },
        "exposure_electrons_per_unit": sensor_noise.as_ref().map(|s| s.electrons_per_unit),
        "stored_variant": if dark_frame { "dark frame subtracted" } else { "no dark frame (the paper's procedure)" },
        "threshold_sigma": threshold_sigma,
        "errors": "relative Frobenius norm ||H_est - H_true|| / ||H_true|| of the full (dense) estimate; column0 relative to ||H_true[:,0]||; stored_overall is the thresholded estimate written to H_est.npz",
        "report": cal.report,
        "timings_s": {"matrix": matrix_s, "render_frames": render_s, "calibration": calibrate_s, "wall": start.elapsed().as_secs_f64()},
        "threads": pool.current_num_threads(),
    });
    let sidecar = serde_json::json!({"object_px": [object.0, object.1], "units": stscam::matrix::MATRIX_UNITS, "from": "stscam calibrate"});
    let report_bytes = serde_json::to_vec_pretty(&report).map_err(write_failure)?;
    let sidecar_bytes = serde_json::to_vec_pretty(&sidecar).map_err(write_failure)?;
    stscam::io::write_all_atomic(
        out,
        &[
            ("H_est.npz", &npz),
            ("H_est.json", &sidecar_bytes),
            ("calibration.json", &report_bytes),
        ],
    )
    .map_err(write_failure)?;
    let r = &cal.report;
    eprintln!(
        "wrote {}/H_est.npz ({} entries) and calibration.json: relative error {:.3e} without dark frame (column 0: {:.3e}), {:.3e} with (column 0: {:.3e}); {:.2} s calibration",
        out.display(),
        r.stored_nnz,
        r.without_dark_frame.overall,
        r.without_dark_frame.column0,
        r.with_dark_frame.overall,
        r.with_dark_frame.column0,
        calibrate_s
    );
    if r.saturated_rows > 0 {
        eprintln!(
            "warning: {} rows had a saturated frame; lower noise.exposure_fraction",
            r.saturated_rows
        );
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn cmd_reconstruct(a: &ReconArgs) -> Result<(), Failure> {
    use stscam::recon::{Method, Problem, Solution, SolveOptions, admm};
    let ReconArgs {
        matrix,
        capture,
        method,
        iters,
        tau,
        mu,
        tv,
        object,
        offset,
        truth,
        gamma,
        out,
        threads,
    } = a;
    let (matrix, capture, out) = (matrix.as_path(), capture.as_path(), out.as_path());
    let (iters, tau, gamma) = (*iters, *tau, *gamma);
    let (object, offset, truth) = (object.as_deref(), offset.as_deref(), truth.as_deref());
    if !(tau.is_finite() && tau >= 0.0) {
        return Err(bad_input(format!(
            "--tau {tau}: must be a non-negative number"
        )));
    }
    if !(mu.is_finite() && *mu >= 0.0) {
        return Err(bad_input(format!(
            "--mu {mu}: must be a non-negative number"
        )));
    }
    if !(gamma.is_finite() && gamma > 0.0) {
        return Err(bad_input(format!("--gamma {gamma}: must be positive")));
    }
    if let Some(n) = iters
        && !(1..=MAX_ITERS).contains(&n)
    {
        return Err(bad_input(format!(
            "--iters: must be in 1..={MAX_ITERS}, got {n}"
        )));
    }
    let stack = stscam::stack::is_stack(matrix);
    let method = match (method, stack) {
        (None, false) => MethodArg::AdmmTv,
        (None, true) => MethodArg::Joint,
        (Some(m @ (MethodArg::Joint | MethodArg::Depth)), false) => {
            return Err(bad_input(format!(
                "{}: --method {}: needs a depth stack (H_stack.npz from matrix --depth-mm D1,D2,...)",
                matrix.display(),
                if *m == MethodArg::Joint {
                    "joint"
                } else {
                    "depth"
                }
            )));
        }
        (Some(m @ (MethodArg::Cg | MethodArg::AdmmTv)), true) => {
            return Err(bad_input(format!(
                "{}: --method {}: a depth stack takes --method joint or depth (or pass one depth's H_<D>mm.npz)",
                matrix.display(),
                if *m == MethodArg::Cg { "cg" } else { "admm-tv" }
            )));
        }
        (Some(m), _) => *m,
    };
    let tv = if *tv == TvArg::Iso {
        admm::TvKind::Iso
    } else {
        admm::TvKind::Aniso
    };
    if stack {
        let opts = stscam::recon::layered::StackOptions {
            method: if method == MethodArg::Joint {
                stscam::recon::layered::StackMethod::Joint
            } else {
                stscam::recon::layered::StackMethod::Depth
            },
            iters,
            tau_rel: tau,
            mu_rel: *mu,
            tv,
            ..Default::default()
        };
        return reconstruct_stack(matrix, capture, offset, truth, gamma, out, *threads, &opts);
    }
    check_out_dir(out)?;
    let object = object.map(parse_object).transpose()?;
    let pool = thread_pool(*threads)?;
    let lm = stscam::matrix::load_matrix(matrix, object, offset)
        .map_err(|e| bad_input(e.to_string()))?;
    let mut g = load_capture(capture)?;
    if g.len() != lm.h.rows {
        return Err(bad_input(format!(
            "{}: the capture has {} values but {} has {} rows (crop pixels x channels); they must match",
            capture.display(),
            g.len(),
            matrix.display(),
            lm.h.rows
        )));
    }
    if let Some(o) = &lm.offset {
        for (x, &v) in g.iter_mut().zip(o) {
            *x -= f64::from(v);
        }
    }
    let (w, h) = lm.object;
    let truth_v = truth.map(|t| load_truth(t, gamma, w, h)).transpose()?;
    stscam::limits::check_bytes(
        "--matrix",
        "the reconstruction set-up (H transposed and the Gram matrix HᵀH)",
        stscam::recon::setup_bytes_bound(&lm.h, pool.current_num_threads()),
    )
    .map_err(|e| bad_input(format!("{}: {e}", matrix.display())))?;
    let t0 = Instant::now();
    let problem = pool.install(|| Problem::new(&lm.h, w, h));
    let setup_s = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let opts = SolveOptions {
        method: if method == MethodArg::Cg {
            Method::Cg
        } else {
            Method::AdmmTv
        },
        iters,
        tau_rel: tau,
        tv,
    };
    let Solution { f, info } = pool.install(|| stscam::recon::solve(&problem, &g, &opts));
    let solve_s = t0.elapsed().as_secs_f64();
    // Computed in f64; stored as float32, which must hold every value.
    check_f32_range(&f, capture, matrix)?;
    let metrics = truth_v.as_ref().map(|t| {
        serde_json::json!({
            "psnr_db": stscam::recon::metrics::psnr(&f, t),
            "ssim": stscam::recon::metrics::ssim(&f, t, w, h),
            "normalisation": "linear object intensity in [0,1] (display gamma removed), reconstruction clipped to [0,1], not rescaled; PSNR peak 1; SSIM Wang et al. 2004, Gaussian sigma 1.5",
        })
    });
    let json = serde_json::json!({
        "stscam_version": stscam::VERSION,
        "command": "reconstruct",
        "matrix": matrix.display().to_string(),
        "capture": capture.display().to_string(),
        "offset": lm.offset_path.as_ref().map(|p| p.display().to_string()),
        "object_px": [w, h],
        "solver": info,
        "gram_layout": problem.gram_layout(),
        "setup_time_s": setup_s,
        "frame_time_s": solve_s,
        "metrics": metrics,
        "units": "linear object intensity (0 = black, 1 = white display pixel)",
    });
    let exr = stscam::output::encode_object_exr(&f, w, h, &[]).map_err(write_failure)?;
    let png = stscam::output::encode_object_png(&f, w, h, gamma).map_err(write_failure)?;
    let jb = serde_json::to_vec_pretty(&json).map_err(write_failure)?;
    stscam::io::write_all_atomic(
        out,
        &[
            ("recon.exr", &exr),
            ("recon.png", &png),
            ("recon.json", &jb),
        ],
    )
    .map_err(write_failure)?;
    let m = metrics
        .map(|m| {
            format!(
                ", PSNR {:.2} dB, SSIM {:.3}",
                m["psnr_db"].as_f64().unwrap_or(f64::NAN),
                m["ssim"].as_f64().unwrap_or(f64::NAN)
            )
        })
        .unwrap_or_default();
    eprintln!(
        "wrote {}/recon.{{exr,png,json}}: {}x{}, set-up {:.3} s, frame {:.2} ms{m}",
        out.display(),
        w,
        h,
        setup_s,
        solve_s * 1e3
    );
    Ok(())
}

/// Refuses a reconstruction f64 → float32 would not hold (H and the capture on incompatible
/// scales).
fn check_f32_range(
    f: &[f64],
    capture: &std::path::Path,
    matrix: &std::path::Path,
) -> Result<(), Failure> {
    if let Some(i) = f.iter().position(|v| !(v.abs() <= f64::from(f32::MAX))) {
        return Err(bad_input(format!(
            "{}: the reconstruction reaches {} at object pixel {i}, outside float32's range (±3.40282e38): H ({}) and the capture are on incompatible scales",
            capture.display(),
            stscam::numfmt::sig6(f[i]),
            matrix.display()
        )));
    }
    Ok(())
}

/// `reconstruct` with a depth stack: recon_<D>mm.{exr,png} per reconstructed plane and
/// recon.json (with the depth method also recon.{exr,png}, the plane at the estimated depth).
#[allow(clippy::too_many_arguments)]
fn reconstruct_stack(
    matrix: &std::path::Path,
    capture: &std::path::Path,
    offset: Option<&std::path::Path>,
    truth: Option<&str>,
    gamma: f64,
    out: &std::path::Path,
    threads: Option<usize>,
    opts: &stscam::recon::layered::StackOptions,
) -> Result<(), Failure> {
    use stscam::recon::layered::{StackMethod, solve_stack, stack_setup_bytes};
    if truth.is_some() && opts.method == StackMethod::Joint {
        return Err(bad_input(
            "--truth: compares one plane; with --method joint compare each recon_<D>mm.exr yourself (or use --method depth)",
        ));
    }
    if offset.is_some() && opts.method == StackMethod::Depth {
        return Err(bad_input(
            "--offset: the depth method subtracts each depth's own offset_<D>mm.npy; --offset applies to --method joint",
        ));
    }
    check_out_dir(out)?;
    let pool = thread_pool(threads)?;
    let ls = stscam::stack::load_stack(matrix, offset).map_err(|e| bad_input(e.to_string()))?;
    let g = load_capture(capture)?;
    let rows = ls.blocks[0].rows;
    if g.len() != rows {
        return Err(bad_input(format!(
            "{}: the capture has {} values but {} has {} rows (crop pixels x channels); they must match",
            capture.display(),
            g.len(),
            matrix.display(),
            rows
        )));
    }
    let (w, h) = ls.object;
    let truth_v = truth.map(|t| load_truth(t, gamma, w, h)).transpose()?;
    stscam::limits::check_bytes(
        "--matrix",
        "the reconstruction set-up (H transposed and the Gram matrix HᵀH)",
        stack_setup_bytes(&ls, opts.method, pool.current_num_threads()),
    )
    .map_err(|e| bad_input(format!("{}: {e}", matrix.display())))?;
    let t0 = Instant::now();
    let sol = pool
        .install(|| solve_stack(&ls, &g, opts))
        .map_err(|e| bad_input(format!("{}: {e}", matrix.display())))?;
    let time_s = t0.elapsed().as_secs_f64();
    let mut files: Vec<(String, Vec<u8>)> = Vec::new();
    let mut planes = Vec::new();
    for (d, f) in &sol.planes {
        check_f32_range(f, capture, matrix)?;
        let label = stscam::stack::depth_label(*d);
        let exr = stscam::output::encode_object_exr(f, w, h, &[]).map_err(write_failure)?;
        let png = stscam::output::encode_object_png(f, w, h, gamma).map_err(write_failure)?;
        files.push((format!("recon_{label}mm.exr"), exr));
        files.push((format!("recon_{label}mm.png"), png));
        planes.push(serde_json::json!({"depth_mm": d, "exr": format!("recon_{label}mm.exr"), "png": format!("recon_{label}mm.png")}));
    }
    let metrics = truth_v.as_ref().map(|t| {
        let f = &sol.planes[0].1;
        serde_json::json!({
            "psnr_db": stscam::recon::metrics::psnr(f, t),
            "ssim": stscam::recon::metrics::ssim(f, t, w, h),
            "normalisation": "linear object intensity in [0,1], reconstruction at the estimated depth clipped to [0,1]; PSNR peak 1",
        })
    });
    if let Some(est) = &sol.estimate {
        let f = &sol.planes[0].1;
        files.push((
            "recon.exr".into(),
            stscam::output::encode_object_exr(f, w, h, &[]).map_err(write_failure)?,
        ));
        files.push((
            "recon.png".into(),
            stscam::output::encode_object_png(f, w, h, gamma).map_err(write_failure)?,
        ));
        eprintln!(
            "estimated depth {} mm (refined {:.1} mm, confidence {:.3}) over {} depths",
            stscam::numfmt::sig6(est.depth_mm),
            est.refined_depth_mm,
            est.confidence,
            est.depths_mm.len()
        );
    }
    let json = serde_json::json!({
        "stscam_version": stscam::VERSION,
        "command": "reconstruct",
        "matrix": matrix.display().to_string(),
        "capture": capture.display().to_string(),
        "object_px": [w, h],
        "depths_mm": ls.depths_mm,
        "solver": sol.info,
        "planes": planes,
        "time_s": time_s,
        "metrics": metrics,
        "units": "linear object intensity (0 = black, 1 = white display pixel)",
    });
    files.push((
        "recon.json".into(),
        serde_json::to_vec_pretty(&json).map_err(write_failure)?,
    ));
    write_files(out, &files)?;
    eprintln!(
        "wrote {}: {} plane(s) of {}x{}, {:.2} s",
        out.display(),
        sol.planes.len(),
        w,
        h,
        time_s
    );
    Ok(())
}

/// Warns on stderr when part of the object has no strong replica inside the crop
/// (`analysis::object_coverage`); `what` names the scene in the message.
fn warn_coverage(sys: &System, what: &str) {
    if !sys.scene.display.enabled {
        return;
    }
    if let Some(w) = analysis::object_coverage(sys).warning() {
        eprintln!("{what}{w}");
    }
}

fn cmd_demo(scene: &SceneArgs, out: &std::path::Path, run: &RunArgs) -> Result<(), Failure> {
    let (spp, seed, threads) = run.checked()?;
    check_out_dir(out)?;
    let pool = thread_pool(threads)?;
    let (_, mut sys) = pool.install(|| load(scene))?;
    let set = stscam::demo::DemoSettings {
        spp,
        seed,
        cg: stscam::recon::cg::CgSettings {
            iters: stscam::recon::cg::DEFAULT_CG_ITERS,
            tol: 0.0,
        },
        admm: stscam::recon::admm::AdmmSettings::default(),
        progress: true,
    };
    // H and one capture per target.
    let renders = 1 + stscam::demo::DEMO_TARGETS.len() as u64;
    stscam::render::check_limits(
        &sys,
        &RenderSettings::lattice(spp, seed, false),
        renders,
        "--spp",
    )
    .map_err(limit)?;
    // The paper's experiment saw the whole target: frame the crop on it when the scene's crop
    // misses part of it (the embedded paper scene's centred crop loses the bottom rows).
    if let Some(off) = analysis::framing_offset_px(&sys) {
        let mut framed = scene.clone();
        let set = format!("sensor.crop_offset_px=[{},{}]", off[0], off[1]);
        eprintln!(
            "demo: the scene's crop misses part of the object; framing it with --set {set} (the crop moved onto the strongest replica of the display centre)"
        );
        framed.set.push(set);
        sys = pool.install(|| load(&framed))?.1;
    }
    warn_coverage(&sys, "");
    let res = pool
        .install(|| stscam::demo::run_demo(&sys, &set))
        .map_err(bad_input)?;
    write_files(out, &res.files)?;
    println!("{}", stscam::demo::table_markdown(&res.rows));
    println!(
        "{}",
        stscam::demo::depth_table_markdown(&res.depth_rows, &res.depth_coverage)
    );
    let t = &res.summary["timings_s"];
    eprintln!(
        "wrote {} ({} files: table.md, table.json, table_depth.json, figure.png, figure_depth.png, H.npz, H_est.npz, calibration.json, images); {:.1} s in total ({} threads)",
        out.display(),
        res.files.len(),
        t["total"].as_f64().unwrap_or(f64::NAN),
        pool.current_num_threads()
    );
    Ok(())
}

fn cmd_dataset(args: &DatasetArgs) -> Result<(), Failure> {
    use stscam::dataset::{RunOptions, Shard, generate, merge, plan};
    let fail = |e: stscam::dataset::DatasetError| match e {
        stscam::dataset::DatasetError::Write(_) => write_failure(e),
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
        eprintln!(
            "merged {} shards into {} ({} samples, checksums verified) in {:.1} s",
            shards.len(),
            out.display(),
            s.samples,
            s.finish_s
        );
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
    eprintln!(
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
    );
    for sc in &p.scenes {
        warn_coverage(&sc.system, &format!("{}: ", sc.id));
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn cmd_sweep(
    scene: &SceneArgs,
    vary: &[String],
    out: &std::path::Path,
    fov_fraction: f64,
    psnr: Option<&str>,
    psnr_spp: u32,
    json: bool,
    threads: Option<usize>,
) -> Result<(), Failure> {
    use stscam::sweep::{PsnrSettings, SweepSettings, VaryAxis, run_sweep};
    let axes = vary
        .iter()
        .map(|v| VaryAxis::parse(v))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| bad_input(e.to_string()))?;
    if psnr_spp == 0 {
        return Err(bad_input("--psnr-spp: must be at least 1"));
    }
    if let Some(t) = psnr {
        stscam::targets::builtin_target(t).map_err(|e| bad_input(format!("--psnr: {e}")))?;
    }
    check_out_dir(out)?;
    let pool = thread_pool(threads)?;
    let set = SweepSettings {
        fov_fraction,
        psnr: psnr.map(|t| PsnrSettings {
            target: t.to_string(),
            spp: psnr_spp,
            ..PsnrSettings::default()
        }),
        progress: true,
        ..SweepSettings::default()
    };
    let t0 = Instant::now();
    let res = pool
        .install(|| run_sweep(scene.scene.as_deref(), &scene.set, &axes, &set))
        .map_err(|e| bad_input(e.to_string()))?;
    write_files(out, &res.files)?;
    if json {
        println!("{}", to_json(&res.rows)?);
    } else {
        for r in &res.rows {
            let f = &r.figures;
            let key: Vec<String> = r
                .varied
                .iter()
                .map(|v| format!("{}={}", v.key, v.value))
                .collect();
            println!(
                "{}: FOV {:.2}° x {:.2}° (V x H), scene field {:.1} mm ({:.2}°) vertically, replicas {} (>= 5 %) / {}, pitch {:.3} mm, efficiency {:.4} (crop mean), Bragg {:.1}-{:.1} nm{}",
                key.join(" "),
                f.fov_vertical.full_deg,
                f.fov_horizontal.full_deg,
                f.scene_field_vertical.extent_mm,
                f.scene_field_vertical.full_deg,
                f.replicas_above_5pct,
                f.replicas_total,
                f.replica_pitch_mm,
                f.efficiency_crop_mean,
                f.bragg_min_nm,
                f.bragg_max_nm,
                f.psnr_db.map_or(String::new(), |p| format!(
                    ", PSNR {p:.2} dB ({:.2} dB with the base scene's H)",
                    f.psnr_nominal_h_db.unwrap_or(f64::NAN)
                ))
            );
        }
    }
    let mut secs = res.point_seconds.clone();
    secs.sort_by(f64::total_cmp);
    eprintln!(
        "wrote {} ({} grid points, {} files) in {:.1} s; median {:.2} s per point ({} threads)",
        out.display(),
        res.rows.len(),
        res.files.len(),
        t0.elapsed().as_secs_f64(),
        secs.get(secs.len() / 2).copied().unwrap_or(f64::NAN),
        pool.current_num_threads()
    );
    Ok(())
}

/// Peak resident memory of this process so far (VmHWM), MiB, where the OS reports it.
fn peak_rss_mib() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn median_ms(mut v: Vec<f64>) -> serde_json::Value {
    v.sort_by(f64::total_cmp);
    serde_json::json!({
        "median_ms": v[v.len() / 2] * 1e3,
        "min_ms": v[0] * 1e3,
        "max_ms": v[v.len() - 1] * 1e3,
        "runs": v.len(),
    })
}

/// `stscam bench bvh`: prints the medians over seeds 1..=runs as JSON.
fn cmd_bench_bvh(triangles: usize, rays: usize, runs: u64) -> Result<(), Failure> {
    // Measured peak: about 300 bytes per triangle (mesh and BVH) and 48 per ray, so the
    // largest run stays near 4 GiB.
    if !(1..=10_000_000).contains(&triangles)
        || !(1..=20_000_000).contains(&rays)
        || !(1..=99).contains(&runs)
    {
        return Err(bad_input(
            "bench bvh: --triangles must be 1..=10000000, --rays 1..=20000000, --runs 1..=99",
        ));
    }
    let results: Vec<_> = (1..=runs)
        .map(|seed| stscam::world::bench_bvh::bench_bvh(triangles, rays, seed))
        .collect();
    let median = |f: &dyn Fn(&stscam::world::bench_bvh::BvhBench) -> f64| {
        let mut v: Vec<f64> = results.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let per_threads: Vec<serde_json::Value> = (0..results[0].runs.len())
        .map(|k| {
            serde_json::json!({
                "threads": results[0].runs[k].threads,
                "build_s_median": median(&|b| b.runs[k].build_s),
                "rays_per_s_median": median(&|b| b.runs[k].rays_per_s),
            })
        })
        .collect();
    let out = serde_json::json!({
        "triangles": results[0].triangles,
        "rays": rays,
        "runs": runs,
        "hit_fraction": results[0].hit_fraction,
        "medians": per_threads,
        "all": results,
    });
    println!("{}", to_json(&out)?);
    Ok(())
}

fn cmd_bench_recon(
    scene: &SceneArgs,
    spp: u32,
    runs: usize,
    json: bool,
    threads: Option<usize>,
) -> Result<(), Failure> {
    use stscam::recon::{Problem, admm, cg};
    if spp == 0 || !(1..=MAX_RUNS).contains(&runs) {
        return Err(bad_input(format!(
            "--spp must be at least 1 and --runs in 1..={MAX_RUNS}"
        )));
    }
    let pool = thread_pool(threads)?;
    let (_, sys) = pool.install(|| load(scene))?;
    let rs = RenderSettings {
        spp,
        seed: 1,
        sampler: SamplerKind::Lattice,
        spectral_bins: None,
        progress: true,
    };
    stscam::render::check_limits(&sys, &rs, 1, "--spp").map_err(limit)?;
    let t0 = Instant::now();
    let m = pool.install(|| stscam::matrix::compute_matrix(&sys, &rs));
    let matrix_s = t0.elapsed().as_secs_f64();
    let matrix_peak = peak_rss_mib();
    let n = m.h.cols;
    let t0 = Instant::now();
    let cal = if n.is_power_of_two() {
        pool.install(|| {
            stscam::hadamard::calibrate(
                &m.h,
                &m.offset,
                stscam::hadamard::FrameSource::Matrix,
                &stscam::hadamard::CalibrationSettings {
                    noise: None,
                    seed: 1,
                    dark_frame: true,
                    threshold_sigma: 0.0,
                },
            )
            .ok()
        })
    } else {
        None
    };
    let calibration_s = cal.as_ref().map(|_| t0.elapsed().as_secs_f64());
    let t0 = Instant::now();
    let p = pool.install(|| Problem::new(&m.h, m.object.0, m.object.1));
    let setup_s = t0.elapsed().as_secs_f64();
    // One frame: the capture H f + o of the scene's target, offset removed.
    let g = m.h.mul_vec(&sys.display.intensity);
    let cg_set = cg::CgSettings {
        iters: cg::DEFAULT_CG_ITERS,
        tol: 0.0,
    };
    let admm_set = admm::AdmmSettings::default();
    let mut t_cg = Vec::new();
    let mut t_admm = Vec::new();
    let mut t_bp = Vec::new();
    for _ in 0..runs {
        let t = Instant::now();
        let htg = pool.install(|| p.back_project(&g));
        t_bp.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let f = pool.install(|| {
            let htg = p.back_project(&g);
            cg::cg_normal(&p, &htg, &cg_set).f
        });
        t_cg.push(t.elapsed().as_secs_f64());
        std::hint::black_box((f, htg));
        let t = Instant::now();
        let f = pool.install(|| {
            let htg = p.back_project(&g);
            admm::admm_tv(&p, &htg, &admm_set).f
        });
        t_admm.push(t.elapsed().as_secs_f64());
        std::hint::black_box(f);
    }
    let out = serde_json::json!({
        "stscam_version": stscam::VERSION,
        "threads": pool.current_num_threads(),
        "shape": [m.h.rows, m.h.cols],
        "matrix": {"seconds": matrix_s, "spp": spp, "nnz": m.h.nnz(), "peak_rss_mib": matrix_peak},
        "calibration": {"seconds": calibration_s, "frames_from": "H_true, no noise, dark frame, every entry kept"},
        "setup": {"seconds": setup_s, "gram_nnz": p.gram_nnz, "gram_layout": p.gram_layout()},
        "back_projection": median_ms(t_bp),
        "cgm": {"iters": cg_set.iters, "timing": median_ms(t_cg)},
        "admm_tv": {"iters": admm_set.iters, "inner_cg_iters": admm_set.inner_iters, "timing": median_ms(t_admm)},
        "peak_rss_mib": peak_rss_mib(),
    });
    if json {
        println!("{}", to_json(&out)?);
    } else {
        println!(
            "H {}x{} ({} entries): {:.2} s, peak memory {:.0} MiB",
            m.h.rows,
            m.h.cols,
            m.h.nnz(),
            matrix_s,
            matrix_peak.unwrap_or(f64::NAN)
        );
        if let Some(c) = calibration_s {
            println!("calibration (frames from H, transform, errors): {c:.2} s");
        }
        println!(
            "reconstruction set-up (H^T, H^T H with {} entries, {}): {:.3} s",
            p.gram_nnz,
            p.gram_layout(),
            setup_s
        );
        println!(
            "per frame (median of {runs}): back-projection {:.2} ms, CGM ({} it) {:.2} ms, ADMM-TV ({} it) {:.2} ms",
            out["back_projection"]["median_ms"]
                .as_f64()
                .unwrap_or(f64::NAN),
            cg_set.iters,
            out["cgm"]["timing"]["median_ms"]
                .as_f64()
                .unwrap_or(f64::NAN),
            admm_set.iters,
            out["admm_tv"]["timing"]["median_ms"]
                .as_f64()
                .unwrap_or(f64::NAN)
        );
    }
    Ok(())
}

/// The time-against-error plot of `bench render`.
fn bench_plot(curves: &[stscam::bench::Curve], target: f64) -> stscam::plot::LinePlot {
    stscam::plot::LinePlot {
        title: "Relative RMSE against render time".into(),
        x_label: "wall time of the render (s)".into(),
        y_label: "relative RMSE".into(),
        log_x: true,
        log_y: true,
        series: curves
            .iter()
            .map(|c| stscam::plot::Series {
                name: if c.name.contains("(default)") {
                    "stscam (default)".to_string()
                } else if c.name.contains("Russian roulette") {
                    "uniform + roulette".to_string()
                } else {
                    c.name.chars().take(26).collect()
                },
                points: c
                    .points
                    .iter()
                    .map(|p| (p.seconds, p.relative_rmse))
                    .collect(),
            })
            .collect(),
        h_line: Some((target, format!("{:.0} %", 100.0 * target))),
    }
}

/// Redraws the plots of a finished `bench render` from its JSON (no rendering).
fn replot_bench(dir: &std::path::Path) -> Result<(), Failure> {
    let path = dir.join("bench-render.json");
    let text = stscam::io::read_text(&path).map_err(|e| bad_input(e.to_string()))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad_input(format!("{}: {e}", path.display())))?;
    let target = v["target_relative_rmse"].as_f64().unwrap_or(0.01);
    let curves: Vec<stscam::bench::Curve> = v["curves"]
        .as_array()
        .ok_or_else(|| bad_input(format!("{}: no curves", path.display())))?
        .iter()
        .map(|c| stscam::bench::Curve {
            name: c["name"].as_str().unwrap_or("").to_string(),
            points: c["points"]
                .as_array()
                .map(|ps| {
                    ps.iter()
                        .map(|p| stscam::bench::Point {
                            spp: p["spp"].as_u64().unwrap_or(0) as u32,
                            seconds: p["seconds"].as_f64().unwrap_or(f64::NAN),
                            relative_rmse: p["relative_rmse"].as_f64().unwrap_or(f64::NAN),
                        })
                        .collect()
                })
                .unwrap_or_default(),
            seconds_to_target: c["seconds_to_target"].as_f64(),
            extrapolated: c["extrapolated"].as_bool().unwrap_or(false),
        })
        .collect();
    let plot = bench_plot(&curves, target);
    let png = plot.to_png().map_err(write_failure)?;
    stscam::io::write_all_atomic(
        dir,
        &[
            ("bench-render.svg", plot.to_svg().as_bytes()),
            ("bench-render.png", &png),
        ],
    )
    .map_err(write_failure)
}

#[allow(clippy::too_many_arguments)]
fn cmd_bench_render(
    scene: &SceneArgs,
    out: &std::path::Path,
    crop: u32,
    ref_spp: u32,
    budget_s: f64,
    target: f64,
    error: ErrorArg,
    extra: &[PathBuf],
    json: bool,
    replot: bool,
    threads: Option<usize>,
) -> Result<(), Failure> {
    use stscam::bench::{Curve, ErrorMeasure, curves_markdown, measure_curve, time_to_error};
    if replot {
        return replot_bench(out);
    }
    let measure = match error {
        ErrorArg::Reference => ErrorMeasure::Reference,
        ErrorArg::Halves => ErrorMeasure::Halves,
    };
    use stscam::render::Estimator;
    if crop == 0
        || ref_spp == 0
        || !(budget_s > 0.0 && budget_s <= MAX_BUDGET_S)
        || !(target > 0.0 && target < 1.0)
    {
        return Err(bad_input(format!(
            "--crop and --ref-spp must be positive, --budget-s in (0, {MAX_BUDGET_S}] and --target in (0, 1)"
        )));
    }
    check_out_dir(out)?;
    let mut extras: Vec<Curve> = Vec::new();
    for p in extra {
        let text = stscam::io::read_text(p).map_err(|e| bad_input(e.to_string()))?;
        let v: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| bad_input(format!("{}: {e}", p.display())))?;
        let name = v["name"].as_str().unwrap_or("extra").to_string();
        let points: Vec<stscam::bench::Point> = v["points"]
            .as_array()
            .ok_or_else(|| bad_input(format!("{}: no \"points\" array", p.display())))?
            .iter()
            .map(|q| stscam::bench::Point {
                spp: q["spp"].as_u64().unwrap_or(0) as u32,
                seconds: q["seconds"].as_f64().unwrap_or(f64::NAN),
                relative_rmse: q["relative_rmse"].as_f64().unwrap_or(f64::NAN),
            })
            .collect();
        let t = time_to_error(&points, target);
        extras.push(Curve {
            name,
            points,
            seconds_to_target: t.map(|x| x.0),
            extrapolated: t.is_some_and(|x| x.1),
        });
    }
    let pool = thread_pool(threads)?;
    // Same field of view on an N×N crop.
    let base =
        load_scene(scene.scene.as_deref(), &scene.set).map_err(|e| bad_input(e.to_string()))?;
    let (cw, ch) = base.scene.sensor.crop_px.size();
    let pitch = base.scene.sensor.pitch_um * f64::from(cw.max(ch)) / f64::from(crop);
    let mut set = scene.set.clone();
    set.push(format!("sensor.crop_px=[{crop},{crop}]"));
    set.push(format!("sensor.pitch_um={pitch}"));
    let args = SceneArgs {
        scene: scene.scene.clone(),
        set,
    };
    let (ls, sys) = pool.install(|| load(&args))?;
    stscam::render::check_limits(
        &sys,
        &RenderSettings::lattice(ref_spp, 0, false),
        1,
        "--ref-spp",
    )
    .map_err(limit)?;
    let t0 = Instant::now();
    let ref_spp = if measure == ErrorMeasure::Halves {
        0
    } else {
        ref_spp
    };
    let reference: Vec<Vec<f32>> = if ref_spp == 0 {
        Vec::new()
    } else {
        pool.install(|| {
            stscam::render::render(
                &sys,
                &RenderSettings {
                    spp: ref_spp,
                    seed: 1_000_003,
                    sampler: SamplerKind::Lattice,
                    spectral_bins: None,
                    progress: true,
                },
            )
            .channels
        })
    };
    let ref_s = t0.elapsed().as_secs_f64();
    let mut curves = Vec::new();
    for (est, name) in [
        (
            Estimator::Bragg,
            "stscam: Bragg sampling + replica splitting (default)",
        ),
        (
            Estimator::UniformAnalog,
            "stscam: uniform wavelengths + Russian roulette",
        ),
    ] {
        let c = pool.install(|| {
            measure_curve(
                &sys,
                est,
                name,
                &reference,
                measure,
                budget_s,
                1 << 20,
                target,
                true,
            )
        });
        eprintln!(
            "{name}: {} renders, time to {:.0} %: {}",
            c.points.len(),
            100.0 * target,
            c.seconds_to_target.map_or("-".into(), |t| format!(
                "{t:.3} s{}",
                if c.extrapolated {
                    " (extrapolated)"
                } else {
                    ""
                }
            ))
        );
        curves.push(c);
    }
    curves.extend(extras);
    let md = format!(
        "Scene: {} with a {crop}×{crop} crop (pitch {pitch:.3} µm, same field of view); {} threads; error: {}.\n\n{}",
        ls.source,
        pool.current_num_threads(),
        match measure {
            ErrorMeasure::Reference => format!("relative RMSE ‖a − b‖/‖b‖ against a {ref_spp}-spp reference of the default estimator ({ref_s:.1} s; other renderers against their own reference)"),
            ErrorMeasure::Halves => "‖A − B‖/‖A + B‖ of two independent renders of half the samples each (the relative RMS Monte Carlo error of their mean; time = both renders)".to_string(),
        },
        curves_markdown(&curves, target)
    );
    let plot = bench_plot(&curves, target);
    let report = serde_json::json!({
        "stscam_version": stscam::VERSION,
        "scene_source": ls.source,
        "overrides": args.set,
        "crop_px": crop,
        "pitch_um": pitch,
        "error_measure": measure,
        "reference_spp": ref_spp,
        "reference_seconds": ref_s,
        "threads": pool.current_num_threads(),
        "target_relative_rmse": target,
        "curves": curves,
        "ratios_to_default": curves.iter().map(|c| {
            let b = curves[0].seconds_to_target;
            serde_json::json!({"name": c.name, "ratio": c.seconds_to_target.zip(b).map(|(t, b)| t / b)})
        }).collect::<Vec<_>>(),
    });
    let jb = serde_json::to_vec_pretty(&report).map_err(write_failure)?;
    let png = plot.to_png().map_err(write_failure)?;
    stscam::io::write_all_atomic(
        out,
        &[
            ("bench-render.json", &jb),
            ("bench-render.md", md.as_bytes()),
            ("bench-render.svg", plot.to_svg().as_bytes()),
            ("bench-render.png", &png),
        ],
    )
    .map_err(write_failure)?;
    if json {
        println!("{}", to_json(&report)?);
    } else {
        println!("{md}");
    }
    Ok(())
}

fn cmd_validate_analytic(
    scene: &SceneArgs,
    fields: usize,
    out: &std::path::Path,
) -> Result<(), Failure> {
    use stscam::analytic::{compare, quantity};
    use stscam::plot::{LinePlot, Series};
    if !(50..=MAX_FIELDS).contains(&fields) {
        return Err(bad_input(format!(
            "--fields: must be in 50..={MAX_FIELDS}, got {fields}"
        )));
    }
    check_out_dir(out)?;
    let (_, sys) = load(scene)?;
    let report = compare(&sys, fields);
    let series = |q: &str, vertical_only: bool, by_param: bool| -> Vec<Series> {
        let rows: Vec<_> = report
            .rows
            .iter()
            .filter(|r| r.quantity == q && (!vertical_only || r.field_h_deg == 0.0))
            .collect();
        let x = |r: &stscam::analytic::Row| if by_param { r.param } else { r.field_v_deg };
        vec![
            Series {
                name: "closed form".into(),
                points: rows.iter().map(|r| (x(r), r.closed_form)).collect(),
            },
            Series {
                name: "stscam tracer".into(),
                points: rows.iter().map(|r| (x(r), r.stscam)).collect(),
            },
        ]
    };
    let plot = |title: &str, xl: &str, yl: &str, s: Vec<Series>| LinePlot {
        title: title.into(),
        x_label: xl.into(),
        y_label: yl.into(),
        log_x: false,
        log_y: false,
        series: s,
        h_line: None,
    };
    let plots = [
        (
            "bragg",
            plot(
                "Bragg wavelength across the field",
                "vertical field angle (deg)",
                "lambda_B (nm)",
                series(quantity::LAMBDA_B, true, false),
            ),
        ),
        (
            "pitch",
            plot(
                "Replica pitch across the field",
                "vertical field angle (deg)",
                "pitch 2w tan(theta') (mm)",
                series(quantity::PITCH, true, false),
            ),
        ),
        (
            "count",
            plot(
                "Replica count against bottom vHOE height",
                "bottom vHOE height (mm)",
                "replicas at the field centre",
                series(quantity::COUNT_H, false, true),
            ),
        ),
    ];
    let mut files: Vec<(String, Vec<u8>)> = vec![
        ("analytic.md".into(), report.to_markdown().into_bytes()),
        ("analytic.csv".into(), report.to_csv().into_bytes()),
        (
            "analytic.json".into(),
            serde_json::to_vec_pretty(&report).map_err(write_failure)?,
        ),
    ];
    for (name, p) in &plots {
        files.push((format!("{name}.svg"), p.to_svg().into_bytes()));
        files.push((format!("{name}.png"), p.to_png().map_err(write_failure)?));
    }
    write_files(out, &files)?;
    println!("{}", report.to_markdown());
    if !report.pass {
        return Err(Failure {
            code: 1,
            message: "analytic comparison failed (see analytic.md)".into(),
        });
    }
    Ok(())
}

fn fmt_fov(name: &str, f: &analysis::Fov) -> String {
    format!(
        "{name}: {:.2}° (from {:.2}°, limited by {}, to {:.2}°, limited by {})",
        f.full_deg, f.min.angle_deg, f.min.limited_by, f.max.angle_deg, f.max.limited_by
    )
}

fn cmd_info(scene: &SceneArgs, json: bool) -> Result<(), Failure> {
    let (_, sys) = load(scene)?;
    let info = analysis::info(&sys);
    if json {
        println!("{}", to_json(&info)?);
        return Ok(());
    }
    println!(
        "critical angle glass→air at λ0: {:.3}° (n_glass = {:.5}); film→air {:.3}°",
        info.critical_angle_deg, info.n_glass_recording, info.film_critical_angle_deg
    );
    println!(
        "grating period: {:.2} nm; focus {:.1} mm, lens–sensor {:.4} mm",
        info.grating_period_nm, info.focus_distance_mm, info.sensor_distance_mm
    );
    println!(
        "{:<8} {:>10} {:>10} {:>12} {:>9} {:>10}",
        "field", "λ_B (nm)", "Θ' (deg)", "pitch (mm)", "replicas", ">5% peak"
    );
    for f in &info.field {
        println!(
            "{:<8} {:>10.2} {:>10.2} {:>12.3} {:>9} {:>10}",
            f.name,
            f.lambda_nm,
            f.guided_angle_deg,
            f.replica_pitch_mm,
            f.replicas,
            f.replicas_above_5pct
        );
    }
    let rows: Vec<String> = info
        .point_replicas
        .iter()
        .map(|r| format!("{:.1} ({:.4})", r.row, r.weight))
        .collect();
    println!(
        "a point at the display centre appears at rows (weight): {}",
        rows.join(", ")
    );
    println!(
        "replica spacing on the sensor (replicas above 5 % of the brightest): {:.2} px",
        info.replica_pitch_sensor_px
    );
    println!(
        "{}",
        fmt_fov("vertical FOV, waveguide", &info.fov_vertical_waveguide)
    );
    println!(
        "{}",
        fmt_fov("vertical FOV, capture", &info.fov_vertical_capture)
    );
    println!(
        "{}",
        fmt_fov("horizontal FOV, waveguide", &info.fov_horizontal_waveguide)
    );
    println!(
        "{}",
        fmt_fov("horizontal FOV, capture", &info.fov_horizontal_capture)
    );
    let cov = &info.object_coverage;
    match cov.warning() {
        _ if !sys.scene.display.enabled => {}
        None => println!(
            "object ({}x{} px): every row and column seen through a replica with >= {} % of its strongest",
            cov.object_px[0],
            cov.object_px[1],
            cov.strong_fraction * 100.0
        ),
        Some(w) => println!("{w}"),
    }
    Ok(())
}

fn cmd_probe(scene: &SceneArgs, pixel: &str, json: bool) -> Result<(), Failure> {
    let parse = || -> Option<(usize, usize)> {
        let (c, r) = pixel.split_once(',')?;
        Some((c.trim().parse().ok()?, r.trim().parse().ok()?))
    };
    let Some((col, row)) = parse() else {
        return Err(bad_input(format!(
            "--pixel {pixel}: expected COL,ROW with non-negative integers"
        )));
    };
    let (_, sys) = load(scene)?;
    let p =
        analysis::probe(&sys, col, row).map_err(|m| bad_input(format!("--pixel {pixel}: {m}")))?;
    if json {
        println!("{}", to_json(&p)?);
        return Ok(());
    }
    println!(
        "pixel {col},{row}: λ_B = {:.4} nm, guided angle {:.4}°, pitch {:.4} mm",
        p.lambda_nm, p.guided_angle_deg, p.replica_pitch_mm
    );
    println!(
        "camera ray dir: [{:.6}, {:.6}, {:.6}]",
        p.camera_ray_dir[0], p.camera_ray_dir[1], p.camera_ray_dir[2]
    );
    for r in &p.replicas {
        println!(
            "replica {:>2}: contact ({:8.3}, {:8.3}) mm  object ({:8.3}, {:8.3}) mm  weight {:.5}",
            r.index,
            r.bottom_contact_mm[0],
            r.bottom_contact_mm[1],
            r.object_point_mm[0],
            r.object_point_mm[1],
            r.weight
        );
    }
    Ok(())
}

fn cmd_compare(
    a: &std::path::Path,
    b: &std::path::Path,
    map: Option<&std::path::Path>,
    json: bool,
) -> Result<(), Failure> {
    let (wa, ha, ca) = stscam::io::read_exr(a).map_err(|e| bad_input(e.to_string()))?;
    let (wb, hb, cb) = stscam::io::read_exr(b).map_err(|e| bad_input(e.to_string()))?;
    if (wa, ha) != (wb, hb) {
        return Err(bad_input(format!(
            "{}: size {wa}x{ha} differs from {} ({wb}x{hb})",
            a.display(),
            b.display()
        )));
    }
    let pairs: Vec<(&[f32], &[f32])> = ca
        .iter()
        .filter_map(|x| {
            cb.iter()
                .find(|y| y.name == x.name)
                .map(|y| (x.data.as_slice(), y.data.as_slice()))
        })
        .collect();
    if pairs.is_empty() {
        return Err(bad_input(format!(
            "{}: no channel in common with {}",
            a.display(),
            b.display()
        )));
    }
    let rel = stscam::render::relative_rmse(&pairs);
    if let Some(path) = map {
        let (x, y) = pairs[0];
        let diff: Vec<f32> = x.iter().zip(y).map(|(p, q)| (p - q).abs()).collect();
        let png = stscam::io::encode_png16(
            wa,
            ha,
            1,
            &stscam::io::preview_u16(&[&diff], 0.999),
            stscam::io::PngTransfer::Srgb,
        )
        .map_err(|m| Failure {
            code: 1,
            message: m,
        })?;
        stscam::io::write_atomic(path, &png).map_err(write_failure)?;
    }
    if json {
        println!(
            "{}",
            serde_json::json!({ "relative_rmse": rel, "channels": pairs.len() })
        );
    } else {
        println!("relative RMSE: {rel:.6}");
    }
    Ok(())
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

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) if e.use_stderr() => {
            eprintln!("{}", argument_error(&e.render().to_string()));
            return ExitCode::from(2);
        }
        Err(e) => {
            // --help and --version.
            let _ = e.print();
            return ExitCode::SUCCESS;
        }
    };
    let result = match &cli.command {
        Command::Render {
            scene,
            out,
            run,
            spectral,
            sampler,
            frontal_px,
        } => cmd_render(scene, out, run, *spectral, *sampler, frontal_px.as_deref()),
        Command::Matrix {
            scene,
            out,
            run,
            depth_mm,
            check,
        } => cmd_matrix(scene, out, run, depth_mm.as_deref(), *check),
        Command::Calibrate {
            scene,
            out,
            matrix,
            object,
            run,
            noise,
            dark_frame,
            render,
            threshold_sigma,
        } => cmd_calibrate(
            scene,
            out,
            matrix.as_deref(),
            object.as_deref(),
            run,
            *noise,
            *dark_frame,
            *render,
            *threshold_sigma,
        ),
        Command::Reconstruct(args) => cmd_reconstruct(args),
        Command::Demo { scene, out, run } => cmd_demo(scene, out, run),
        Command::Dataset(args) => cmd_dataset(args),
        Command::Sweep {
            scene,
            vary,
            out,
            fov_fraction,
            psnr,
            psnr_spp,
            json,
            threads,
        } => cmd_sweep(
            scene,
            vary,
            out,
            *fov_fraction,
            psnr.as_deref(),
            *psnr_spp,
            *json,
            *threads,
        ),
        Command::Bench { which } => match which {
            BenchCommand::Bvh {
                triangles,
                rays,
                runs,
            } => cmd_bench_bvh(*triangles, *rays, *runs),
            BenchCommand::Recon {
                scene,
                spp,
                runs,
                json,
                threads,
            } => cmd_bench_recon(scene, *spp, *runs, *json, *threads),
            BenchCommand::Render {
                scene,
                out,
                crop,
                ref_spp,
                budget_s,
                target,
                error,
                extra,
                json,
                replot,
                threads,
            } => cmd_bench_render(
                scene, out, *crop, *ref_spp, *budget_s, *target, *error, extra, *json, *replot,
                *threads,
            ),
        },
        Command::Validate {
            which: ValidateCommand::Analytic { scene, fields, out },
        } => cmd_validate_analytic(scene, *fields, out),
        Command::Info { scene, json } => cmd_info(scene, *json),
        Command::Compare { a, b, map, json } => cmd_compare(a, b, map.as_deref(), *json),
        Command::Probe { scene, pixel, json } => cmd_probe(scene, pixel, *json),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            eprintln!("error: {}", f.message);
            ExitCode::from(f.code)
        }
    }
}
