//! `stscam` command line: a thin layer that parses arguments, calls the library and reports.
//! Bad input (scene, overrides, images, arguments) prints one line and exits with code 2;
//! nothing is written to `--out` unless the whole job succeeded.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use clap::{Args, Parser, Subcommand, ValueEnum};

use stscam::analysis;
use stscam::output::{CAPTURE_UNITS, write_capture};
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
        /// Samples (camera paths) per pixel.
        #[arg(long, default_value_t = 64)]
        spp: u32,
        /// Sampler seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Also write spectral channels (bins of about 10 nm tiling the sampling band) into the EXR.
        #[arg(long)]
        spectral: bool,
        /// Sample sequence.
        #[arg(long, value_enum, default_value = "lattice")]
        sampler: SamplerArg,
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

fn load(args: &SceneArgs) -> Result<(LoadedScene, System), Failure> {
    let ls = load_scene(args.scene.as_deref(), &args.set).map_err(|e| bad_input(e.to_string()))?;
    let sys = System::build(&ls).map_err(|e| bad_input(e.to_string()))?;
    Ok((ls, sys))
}

fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool, Failure> {
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        if t == 0 {
            return Err(bad_input("--threads: must be at least 1"));
        }
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
    spp: u32,
    seed: u64,
    threads: Option<usize>,
    spectral: bool,
    sampler: SamplerArg,
) -> Result<(), Failure> {
    let start = Instant::now();
    if spp == 0 {
        return Err(bad_input("--spp: must be at least 1"));
    }
    if out.exists() && !out.is_dir() {
        return Err(bad_input(format!(
            "{}: --out exists and is not a directory",
            out.display()
        )));
    }
    let pool = thread_pool(threads)?;
    let (ls, sys) = pool.install(|| load(scene))?;
    let sm = &sys.scene.sampling;
    let bins = spectral.then(|| {
        // Bins of about 10 nm that tile the band exactly.
        let band = sm.lambda_max_nm - sm.lambda_min_nm;
        let n = (band / 10.0).round().max(1.0) as usize;
        (sm.lambda_min_nm, band / n as f64, n)
    });
    let settings = RenderSettings {
        spp,
        seed,
        sampler: match sampler {
            SamplerArg::Lattice => SamplerKind::Lattice,
            SamplerArg::Independent => SamplerKind::Independent,
        },
        spectral_bins: bins,
        progress: std::io::stderr().is_terminal(),
    };
    let t0 = Instant::now();
    let cap = pool.install(|| render(&sys, &settings));
    let render_s = t0.elapsed().as_secs_f64();
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
    // A missing or unwritable output location is the user's to fix, but it is not bad input
    // to the simulator: exit 1.
    write_capture(out, &cap, &scene_json, seed, spp, &sidecar).map_err(|e| Failure {
        code: 1,
        message: e.to_string(),
    })?;
    if cap.stats.nonfinite_samples > 0 {
        eprintln!(
            "warning: {} samples were NaN or infinite and were zeroed",
            cap.stats.nonfinite_samples
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
        let png = stscam::io::encode_png16(wa, ha, 1, &stscam::io::preview_u16(&[&diff], 0.999))
            .map_err(|m| Failure {
                code: 1,
                message: m,
            })?;
        stscam::io::write_atomic(path, &png).map_err(|e| bad_input(e.to_string()))?;
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

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return ExitCode::from(code);
        }
    };
    let result = match &cli.command {
        Command::Render {
            scene,
            out,
            spp,
            seed,
            threads,
            spectral,
            sampler,
        } => cmd_render(scene, out, *spp, *seed, *threads, *spectral, *sampler),
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
