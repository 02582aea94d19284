//! `stscam bench`: BVH, reconstruction and render (run time against error) benchmarks.

use std::path::PathBuf;
use std::time::Instant;

use crate::sampler::SamplerKind;
use stscam_tracer::render::RenderSettings;

use super::*;

/// Run time against error for each estimator (and other renderers' curves given as JSON): DIR/bench-render.{json,md,svg,png}.
#[derive(clap::Args, Debug, Clone)]
pub struct BenchRenderOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Output directory.
    #[arg(long, default_value = "out/bench-render-error")]
    pub out: PathBuf,
    /// Crop size N (N×N); the pixel pitch is scaled so the field of view stays that of the
    /// scene's crop.
    #[arg(long, default_value_t = 128)]
    pub crop: u32,
    /// Samples per pixel of the reference (default estimator, independent seed).
    #[arg(long, default_value_t = 4096)]
    pub ref_spp: u32,
    /// Time budget per estimator, s.
    #[arg(long, default_value_t = 60.0)]
    pub budget_s: f64,
    /// Target relative RMSE for the time-to-error figures.
    #[arg(long, default_value_t = 0.01)]
    pub target: f64,
    /// Error measure: against a high-spp reference, or from two independent half renders
    /// (no reference; what validation/mitsuba/bench.py measures for Mitsuba).
    #[arg(long, value_enum, default_value = "reference")]
    pub error: stscam_studies::bench::ErrorMeasure,
    /// Extra curves (JSON: {"name": ..., "points": [{"spp", "seconds", "relative_rmse"}]}),
    /// e.g. Mitsuba's from validation/mitsuba (repeatable).
    #[arg(long)]
    pub extra: Vec<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Only redraw the plots of DIR/bench-render.json (no rendering).
    #[arg(long)]
    pub replot: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// BVH build time and closest-hit rays per second with 1 and 2 threads on a displaced sphere of at least TRIANGLES triangles (incoherent rays; medians over RUNS seeds).
#[derive(clap::Args, Debug, Clone)]
pub struct BenchBvhOptions {
    /// Triangles of the test mesh.
    #[arg(long, default_value_t = 1_000_000)]
    pub triangles: usize,
    /// Rays per measurement.
    #[arg(long, default_value_t = 1_000_000)]
    pub rays: usize,
    /// Runs (seeds 1..=RUNS); medians are reported.
    #[arg(long, default_value_t = 3)]
    pub runs: u64,
}

/// H, calibration and reconstruction speed at the scene's size (medians).
#[derive(clap::Args, Debug, Clone)]
pub struct BenchReconOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Samples per pixel of H.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Timed runs per reconstruction figure.
    #[arg(long, default_value_t = 21)]
    pub runs: usize,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
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
fn cmd_bench_bvh(triangles: usize, rays: usize, runs: u64, con: &Console) -> Result<(), Failure> {
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
        .map(|seed| crate::world::bench_bvh::bench_bvh(triangles, rays, seed))
        .collect();
    let median = |f: &dyn Fn(&crate::world::bench_bvh::BvhBench) -> f64| {
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
    con.out(format_args!("{}", to_json(&out)?));
    Ok(())
}

/// `stscam bench recon`: the times of H, its calibration, the reconstruction set-up and one
/// frame's back-projection, CGM and ADMM-TV (medians of `runs`), as JSON or text.
fn cmd_bench_recon(
    scene: &SceneArgs,
    spp: u32,
    runs: usize,
    json: bool,
    threads: Option<usize>,
    con: &Console,
) -> Result<(), Failure> {
    use crate::recon::{Problem, admm, cg};
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
        user_side: Default::default(),
        spectral_bins: None,
        progress: true,
        estimator: Default::default(),
        adaptive: false,
    };
    stscam_tracer::render::check_limits(&sys, &rs, 1, "--spp").map_err(limit)?;
    let t0 = Instant::now();
    let m = pool.install(|| stscam_tracer::matrix::compute_matrix(&sys, &rs));
    let matrix_s = t0.elapsed().as_secs_f64();
    let matrix_peak = peak_rss_mib();
    let t0 = Instant::now();
    let cal = bench_calibration(&pool, &m);
    let calibration_s = cal.as_ref().map(|_| t0.elapsed().as_secs_f64());
    let t0 = Instant::now();
    let p = pool.install(|| {
        Problem::with_cancel(&m.h, m.object.0, m.object.1, stscam_base::cancel::current())
    });
    let setup_s = t0.elapsed().as_secs_f64();
    // One frame: the capture H f + o of the scene's target, offset removed.
    let g = m.h.mul_vec(&sys.display.intensity);
    let cg_set = cg::CgSettings {
        iters: cg::DEFAULT_CG_ITERS,
        tol: 0.0,
    };
    let admm_set = admm::AdmmSettings::default();
    let [t_bp, t_cg, t_admm] = time_solvers(&pool, &p, &g, runs, &cg_set, &admm_set);
    let out = serde_json::json!({
        "stscam_version": crate::VERSION,
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
        con.out(format_args!("{}", to_json(&out)?));
    } else {
        print_recon_bench(con, &out, runs);
    }
    Ok(())
}

/// The Hadamard calibration of `m` (frames from H, no noise, every entry kept), timed by
/// `bench recon`; `None` where the object's pixel count is not a power of two.
fn bench_calibration(
    pool: &rayon::ThreadPool,
    m: &stscam_tracer::matrix::SystemMatrix,
) -> Option<crate::hadamard::Calibration> {
    let n = m.h.cols;
    if n.is_power_of_two() {
        pool.install(|| {
            crate::hadamard::calibrate(
                &m.h,
                &m.offset,
                crate::hadamard::FrameSource::Matrix,
                &crate::hadamard::CalibrationSettings {
                    noise: None,
                    seed: 1,
                    dark_frame: true,
                    threshold_sigma: 0.0,
                    progress: false,
                },
            )
            .ok()
        })
    } else {
        None
    }
}

/// The times (s) of `runs` back-projections, CGM and ADMM-TV solves of the frame `g`.
fn time_solvers(
    pool: &rayon::ThreadPool,
    p: &crate::recon::Problem,
    g: &[f64],
    runs: usize,
    cg_set: &crate::recon::cg::CgSettings,
    admm_set: &crate::recon::admm::AdmmSettings,
) -> [Vec<f64>; 3] {
    use crate::recon::{admm, cg};
    let mut t_bp = Vec::new();
    let mut t_cg = Vec::new();
    let mut t_admm = Vec::new();
    for _ in 0..runs {
        let t = Instant::now();
        let htg = pool.install(|| p.back_project(g));
        t_bp.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let f = pool.install(|| {
            let htg = p.back_project(g);
            cg::cg_normal(p, &htg, cg_set).f
        });
        t_cg.push(t.elapsed().as_secs_f64());
        std::hint::black_box((f, htg));
        let t = Instant::now();
        let f = pool.install(|| {
            let htg = p.back_project(g);
            admm::admm_tv(p, &htg, admm_set).f
        });
        t_admm.push(t.elapsed().as_secs_f64());
        std::hint::black_box(f);
    }
    [t_bp, t_cg, t_admm]
}

/// The text report of `bench recon` from its JSON `out`.
fn print_recon_bench(con: &Console, out: &serde_json::Value, runs: usize) {
    let f = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    let (matrix, setup) = (&out["matrix"], &out["setup"]);
    con.out(format_args!(
        "H {}x{} ({} entries): {:.2} s, peak memory {:.0} MiB",
        out["shape"][0],
        out["shape"][1],
        matrix["nnz"],
        f(&matrix["seconds"]),
        f(&matrix["peak_rss_mib"])
    ));
    if let Some(c) = out["calibration"]["seconds"].as_f64() {
        con.out(format_args!(
            "calibration (frames from H, transform, errors): {c:.2} s"
        ));
    }
    con.out(format_args!(
        "reconstruction set-up (H^T, H^T H with {} entries, {}): {:.3} s",
        setup["gram_nnz"],
        setup["gram_layout"].as_str().unwrap_or_default(),
        f(&setup["seconds"])
    ));
    con.out(format_args!(
        "per frame (median of {runs}): back-projection {:.2} ms, CGM ({} it) {:.2} ms, ADMM-TV ({} it) {:.2} ms",
        f(&out["back_projection"]["median_ms"]),
        out["cgm"]["iters"],
        f(&out["cgm"]["timing"]["median_ms"]),
        out["admm_tv"]["iters"],
        f(&out["admm_tv"]["timing"]["median_ms"])
    ));
}

/// The time-against-error plot of `bench render`.
fn bench_plot(curves: &[stscam_studies::bench::Curve], target: f64) -> crate::plot::LinePlot {
    crate::plot::LinePlot {
        title: "Relative RMSE against render time".into(),
        x_label: "wall time of the render (s)".into(),
        y_label: "relative RMSE".into(),
        log_x: true,
        log_y: true,
        series: curves
            .iter()
            .map(|c| crate::plot::Series {
                name: if c.name.contains("(default)") {
                    "stscam (default)".to_string()
                } else if c.name.contains("previous default") {
                    "previous default".to_string()
                } else if c.name.contains("every branch") {
                    "every branch traced".to_string()
                } else if c.name.contains("Sobol") {
                    "stscam, Sobol' points".to_string()
                } else if c.name.contains("Russian roulette") {
                    "uniform + roulette".to_string()
                } else if c.name.contains("per-design table") {
                    "camera-side table".to_string()
                } else if c.name.contains("adaptive sample counts") {
                    "adaptive counts".to_string()
                } else {
                    // An extra curve: its name up to any parenthesis (Mitsuba 3.9.1).
                    let head = c.name.split(" (").next().unwrap_or(&c.name);
                    head.chars().take(26).collect()
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
    let text = crate::io::read_text(&path).map_err(|e| bad_input(e.to_string()))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| bad_input(format!("{}: {e}", path.display())))?;
    let target = v["target_relative_rmse"].as_f64().unwrap_or(0.01);
    let curves: Vec<stscam_studies::bench::Curve> = v["curves"]
        .as_array()
        .ok_or_else(|| bad_input(format!("{}: no curves", path.display())))?
        .iter()
        .map(|c| stscam_studies::bench::Curve {
            name: c["name"].as_str().unwrap_or("").to_string(),
            points: curve_points(c).unwrap_or_default(),
            seconds_to_target: c["seconds_to_target"].as_f64(),
            extrapolated: c["extrapolated"].as_bool().unwrap_or(false),
            precompute_seconds: c["precompute_seconds"].as_f64(),
        })
        .collect();
    let plot = bench_plot(&curves, target);
    let png = plot.to_png().map_err(write_failure)?;
    crate::io::write_all_atomic(
        dir,
        &[
            ("bench-render.svg", plot.to_svg().as_bytes()),
            ("bench-render.png", &png),
        ],
    )
    .map_err(write_failure)
}

/// `stscam bench render`: time against error of each estimator on an N×N crop of the scene
/// (plus `extra` curves from files), written as JSON, Markdown, SVG and PNG.
#[allow(clippy::too_many_arguments)]
fn cmd_bench_render(
    scene: &SceneArgs,
    out: &std::path::Path,
    crop: u32,
    ref_spp: u32,
    budget_s: f64,
    target: f64,
    error: stscam_studies::bench::ErrorMeasure,
    extra: &[PathBuf],
    json: bool,
    replot: bool,
    threads: Option<usize>,
    con: &Console,
) -> Result<(), Failure> {
    use stscam_studies::bench::{ErrorMeasure, curves_markdown};
    if replot {
        return replot_bench(out);
    }
    let measure = error;
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
    let extras = read_extra_curves(extra, target)?;
    let pool = thread_pool(threads)?;
    let (ls, sys, args, pitch) = bench_scene(scene, crop, &pool)?;
    stscam_tracer::render::check_limits(
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
    let reference = reference_render(&pool, &sys, ref_spp);
    let ref_s = t0.elapsed().as_secs_f64();
    let mut curves = measure_curves(&pool, &sys, &reference, measure, budget_s, target, con);
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
        "stscam_version": crate::VERSION,
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
    crate::io::write_all_atomic(
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
        con.out(format_args!("{}", to_json(&report)?));
    } else {
        con.out(format_args!("{md}"));
    }
    Ok(())
}

/// The points of a curve's JSON (`points`: `spp`, `seconds`, `relative_rmse`; missing values
/// 0 or NaN), or `None` without a `points` array.
fn curve_points(v: &serde_json::Value) -> Option<Vec<stscam_studies::bench::Point>> {
    Some(
        v["points"]
            .as_array()?
            .iter()
            .map(|q| stscam_studies::bench::Point {
                spp: q["spp"].as_u64().unwrap_or(0) as u32,
                seconds: q["seconds"].as_f64().unwrap_or(f64::NAN),
                relative_rmse: q["relative_rmse"].as_f64().unwrap_or(f64::NAN),
            })
            .collect(),
    )
}

/// The curves of `bench render --extra` files (another renderer's measurements), each with
/// its time to `target`.
fn read_extra_curves(
    extra: &[PathBuf],
    target: f64,
) -> Result<Vec<stscam_studies::bench::Curve>, Failure> {
    let mut extras = Vec::new();
    for p in extra {
        let text = crate::io::read_text(p).map_err(|e| bad_input(e.to_string()))?;
        let v: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| bad_input(format!("{}: {e}", p.display())))?;
        let name = v["name"].as_str().unwrap_or("extra").to_string();
        let points = curve_points(&v)
            .ok_or_else(|| bad_input(format!("{}: no \"points\" array", p.display())))?;
        let t = stscam_studies::bench::time_to_error(&points, target);
        extras.push(stscam_studies::bench::Curve {
            name,
            points,
            seconds_to_target: t.map(|x| x.0),
            extrapolated: t.is_some_and(|x| x.1),
            precompute_seconds: None,
        });
    }
    Ok(extras)
}

/// The scene of `bench render`: the same field of view on a `crop`×`crop` crop (the pitch
/// scaled); returns it with its arguments and pitch (µm).
fn bench_scene(
    scene: &SceneArgs,
    crop: u32,
    pool: &rayon::ThreadPool,
) -> Result<(LoadedScene, System, SceneArgs, f64), Failure> {
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
    Ok((ls, sys, args, pitch))
}

/// The reference render of `bench render` (none for `ref_spp` 0).
fn reference_render(pool: &rayon::ThreadPool, sys: &System, ref_spp: u32) -> Vec<Vec<f32>> {
    if ref_spp == 0 {
        Vec::new()
    } else {
        pool.install(|| {
            stscam_tracer::render::render(
                sys,
                &RenderSettings {
                    spp: ref_spp,
                    seed: 1_000_003,
                    sampler: SamplerKind::Lattice,
                    user_side: Default::default(),
                    spectral_bins: None,
                    progress: true,
                    estimator: Default::default(),
                    adaptive: false,
                },
            )
            .channels
        })
    }
}

/// The time-against-error curves of stscam's estimators (the default first), each reported
/// on `con` as it finishes.
fn measure_curves(
    pool: &rayon::ThreadPool,
    sys: &System,
    reference: &[Vec<f32>],
    measure: stscam_studies::bench::ErrorMeasure,
    budget_s: f64,
    target: f64,
    con: &Console,
) -> Vec<stscam_studies::bench::Curve> {
    use stscam_studies::bench::{CurveSampler, measure_curve};
    use stscam_tracer::render::Estimator;
    let mut curves = Vec::new();
    // The user side's estimators differ only in 3-D scenes.
    let every_branch = sys.world.is_some().then_some((
        Estimator::Bragg,
        CurveSampler::EveryBranch,
        "stscam: the default with every branch traced on the user side (padded; the 3-D default until 2026-11-26)",
    ));
    // Adaptive counts pay where a few pixels hold the noise: the display's replicas.
    let adaptive = sys.world.is_none().then_some((
        Estimator::Bragg,
        CurveSampler::Adaptive,
        "stscam: the default with adaptive sample counts (--adaptive; spp = the mean, pilot included)",
    ));
    let table = sys.world.is_some().then_some((
        Estimator::Bragg,
        CurveSampler::CameraTable(Default::default()),
        "stscam: the camera side from a per-design table (--camera-table, 1024 camera samples and 32 exit rays per pixel); spp = user-side paths",
    ));
    for (est, sampler, name) in [
        (
            Estimator::Bragg,
            CurveSampler::Kind(SamplerKind::Lattice),
            "stscam: Bragg sampling + replica splitting (default)",
        ),
        (
            Estimator::Bragg,
            CurveSampler::Kind(SamplerKind::Sobol),
            "stscam: the default with Owen-scrambled Sobol' points",
        ),
        (
            Estimator::UniformAnalog,
            CurveSampler::Kind(SamplerKind::Lattice),
            "stscam: uniform wavelengths + Russian roulette",
        ),
    ]
    .into_iter()
    .chain(adaptive)
    .chain(table)
    .chain(every_branch)
    {
        let c = pool.install(|| {
            measure_curve(
                sys,
                est,
                sampler,
                name,
                reference,
                measure,
                budget_s,
                1 << 20,
                target,
                true,
            )
        });
        con.err(format_args!(
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
        ));
        curves.push(c);
    }
    curves
}

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`.
pub fn run_bvh(o: &BenchBvhOptions, con: &Console) -> Result<(), JobError> {
    cmd_bench_bvh(o.triangles, o.rays, o.runs, con)
}

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`.
pub fn run_recon(o: &BenchReconOptions, con: &Console) -> Result<(), JobError> {
    cmd_bench_recon(&o.scene, o.spp, o.runs, o.json, o.threads, con)
}

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`.
pub fn run_render(o: &BenchRenderOptions, con: &Console) -> Result<(), JobError> {
    cmd_bench_render(
        &o.scene, &o.out, o.crop, o.ref_spp, o.budget_s, o.target, o.error, &o.extra, o.json,
        o.replot, o.threads, con,
    )
}

/// Options of `stscam bench grating`.
#[derive(Args, Debug, Clone)]
pub struct BenchGratingOptions {
    /// The scene and its overrides (the film and grating from `[hoe]`, the glass from `[plate]`).
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Timed runs of the single-point figures.
    #[arg(long, default_value_t = 101)]
    pub runs: usize,
    /// Table grid: wavelengths START:STOP:N.
    #[arg(long = "table-lambda-nm", default_value = "500:560:61")]
    pub table_lambda_nm: String,
    /// Table grid: nodes along u_x and u_y, over ±`--table-u`.
    #[arg(long = "table-nodes", default_value = "13,31", value_name = "NX,NY")]
    pub table_nodes: String,
    /// Table grid half-width in u (both axes).
    #[arg(long = "table-u", default_value_t = 0.3)]
    pub table_u: f64,
    /// Off-grid probes measuring the table's interpolation error.
    #[arg(long, default_value_t = 200)]
    pub probes: usize,
    /// Worker threads of the table (default: all cores); single points always use one.
    #[arg(long)]
    pub threads: Option<usize>,
}

/// `stscam bench grating`: RCWA time per point on one core (medians) and the table time.
pub fn run_grating(o: &BenchGratingOptions, con: &Console) -> Result<(), JobError> {
    use crate::grating_spectrum as gs;
    use crate::optics::rcwa::{Settings, table};
    if !(1..=MAX_RUNS).contains(&o.runs) || !(1..=1_000_000).contains(&o.probes) {
        return Err(bad_input(format!(
            "--runs in 1..={MAX_RUNS}, --probes in 1..=1000000"
        )));
    }
    let lambdas = super::grating::parse_lambdas(&o.table_lambda_nm)?;
    let nodes = o
        .table_nodes
        .split_once(',')
        .and_then(|(a, b)| {
            Some((
                a.trim().parse::<usize>().ok()?,
                b.trim().parse::<usize>().ok()?,
            ))
        })
        .filter(|&(a, b)| a >= 2 && b >= 2 && a * b <= 1_000_000)
        .ok_or_else(|| {
            bad_input(format!(
                "--table-nodes {}: expected NX,NY >= 2",
                o.table_nodes
            ))
        })?;
    if lambdas.len() < 2 || !(o.table_u > 0.0 && o.table_u < 1.0) {
        return Err(bad_input(
            "--table-lambda-nm needs N >= 2 and --table-u must be in (0, 1)",
        ));
    }
    let (ls, _) = load(&o.scene)?;
    let s = &ls.scene;
    let gratings = gs::scene_gratings(s);
    let film = gs::film(s, &gratings);
    let settings = Settings::default();
    let lam_b = gs::volume_gratings(s, &gratings)[0]
        .bragg_wavelength_nm(glam::DVec2::ZERO)
        .unwrap_or(s.hoe.primary_wavelength_nm());
    let points = time_points(o.runs, s, &film, lam_b, &settings)?;
    let spec = table::TableSpec {
        lambda_nm: table::Axis {
            start: lambdas[0],
            stop: lambdas[lambdas.len() - 1],
            n: lambdas.len(),
        },
        u_x: table::Axis {
            start: -o.table_u,
            stop: o.table_u,
            n: nodes.0,
        },
        u_y: table::Axis {
            start: -o.table_u,
            stop: o.table_u,
            n: nodes.1,
        },
        max_order: 1,
    };
    let tables = time_tables(o, s, &film, &lambdas, &spec, &settings)?;
    let report = serde_json::json!({
        "point_at_bragg_lambda_nm": lam_b,
        "harmonics": settings.harmonics,
        "slices_per_period": settings.slices_per_period,
        "points_one_core": points,
        "table": {
            "lambda_nm": [spec.lambda_nm.start, spec.lambda_nm.stop, spec.lambda_nm.n],
            "u_half_width": o.table_u,
            "nodes_ux_uy": [nodes.0, nodes.1],
            "stacks": tables,
        },
    });
    con.out(format_args!("{}", to_json(&report)?));
    Ok(())
}

/// The single-point RCWA times of `bench grating` (medians of `runs` on one core) at the Bragg
/// wavelength `lam_b`: bulk at normal and conical incidence, the contact stack at normal.
fn time_points(
    runs: usize,
    s: &crate::scene::Scene,
    film: &crate::optics::rcwa::Film,
    lam_b: f64,
    settings: &crate::optics::rcwa::Settings,
) -> Result<serde_json::Map<String, serde_json::Value>, Failure> {
    use crate::grating_spectrum as gs;
    use crate::optics::rcwa;
    let mut points = serde_json::Map::new();
    for (name, kind, u) in [
        ("bulk_normal", gs::StackKind::Bulk, glam::DVec2::ZERO),
        (
            "bulk_conical",
            gs::StackKind::Bulk,
            glam::DVec2::new(0.15, 0.1),
        ),
        ("contact_normal", gs::StackKind::Contact, glam::DVec2::ZERO),
    ] {
        let media = gs::stack_media(s, kind, lam_b);
        let mut times = Vec::with_capacity(runs);
        let mut slices = 0;
        for _ in 0..runs {
            let t = std::time::Instant::now();
            let sol = rcwa::solve(film, &media, lam_b, u, settings)
                .map_err(|e| bad_input(format!("bench grating: {e}")))?;
            times.push(t.elapsed().as_secs_f64());
            slices = sol.slices;
        }
        let mut v = median_ms(times);
        v["slices"] = slices.into();
        v["note"] = "one solve gives TE and TM".into();
        points.insert(name.into(), v);
    }
    Ok(points)
}

/// The build time and interpolation error of the bulk and contact RCWA tables over `spec`
/// (wavelengths `lambdas`) on `o.threads` threads.
fn time_tables(
    o: &BenchGratingOptions,
    s: &crate::scene::Scene,
    film: &crate::optics::rcwa::Film,
    lambdas: &[f64],
    spec: &crate::optics::rcwa::table::TableSpec,
    settings: &crate::optics::rcwa::Settings,
) -> Result<serde_json::Map<String, serde_json::Value>, Failure> {
    use crate::grating_spectrum as gs;
    use crate::optics::rcwa::table;
    let nodes = (spec.u_x.n, spec.u_y.n);
    let pool = thread_pool(o.threads)?;
    let mut tables = serde_json::Map::new();
    for kind in [gs::StackKind::Bulk, gs::StackKind::Contact] {
        let media: Vec<_> = lambdas
            .iter()
            .map(|&l| gs::stack_media(s, kind, l))
            .collect();
        let t0 = std::time::Instant::now();
        let t = pool
            .install(|| table::RcwaTable::build(film, &media, spec, settings))
            .map_err(|e| bad_input(format!("bench grating: {e}")))?;
        let build_s = t0.elapsed().as_secs_f64();
        let err = pool
            .install(|| t.measure_error(o.probes, 1))
            .map_err(|e| bad_input(format!("bench grating: {e}")))?;
        tables.insert(
            format!("{kind:?}").to_lowercase(),
            serde_json::json!({
                "nodes": lambdas.len() * nodes.0 * nodes.1,
                "build_s": build_s,
                "threads": pool.current_num_threads(),
                "max_interpolation_error": err,
                "probes": o.probes,
            }),
        );
    }
    Ok(tables)
}
