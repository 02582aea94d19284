//! `stscam render`: the capture (EXR, PNG preview, JSON), and with 3-D objects the frontal image, depth and mask.

use std::path::PathBuf;
use std::time::Instant;

use crate::output::{CAPTURE_UNITS, write_capture_with};
use crate::sampler::SamplerKind;
use stscam_tracer::render::{RenderSettings, UserSideSampler, render};

use super::*;

/// Render the capture: DIR/capture.exr, capture.png and capture.json.
#[derive(clap::Args, Debug, Clone)]
pub struct RenderOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Output directory.
    #[arg(long, default_value = "out/render")]
    pub out: PathBuf,
    /// Samples, seed and threads.
    #[command(flatten)]
    pub run: RunArgs,
    /// Also write spectral channels (bins of about 10 nm tiling the sampling band) into the EXR.
    #[arg(long)]
    pub spectral: bool,
    /// Sample sequence.
    #[arg(long, value_enum, default_value = "lattice")]
    pub sampler: SamplerKind,
    /// 3-D scenes: which branches get user-side paths and how their first vertex draws its light and BSDF numbers.
    #[arg(long, value_enum, default_value = "auto")]
    pub user_side: UserSideSampler,
    /// 3-D scenes: size of frontal.exr, depth.exr and mask.png, `N` or `WxH` (default: the
    /// capture's crop size).
    #[arg(long, value_name = "N|WxH")]
    pub frontal_px: Option<String>,
    /// 3-D scenes: samples per pixel of frontal.exr (default: `--spp`; with `--camera-table`
    /// `--spp` counts user-side paths of the capture).
    #[arg(long, value_name = "N")]
    pub frontal_spp: Option<u32>,
    /// 3-D scenes: colour space of frontal.exr: `sensor` (the capture's response, raw camera
    /// RGB), `xyz` (CIE 1931 2°, Y = 1 for a flat radiance at display white) or `linear-srgb`
    /// (Rec. 709 primaries, D65 white).
    #[arg(long, value_enum, default_value = "sensor")]
    pub frontal_space: crate::world::colour::FrontalSpace,
    /// The camera-side table's options (3-D scenes).
    #[command(flatten)]
    pub table: TableArgs,
    /// Adaptive sample counts: `--spp` is the mean over the pixels, and a pilot (two renders
    /// at spp/16) finds where the noise is; each pixel then gets samples in proportion to
    /// its noise, in powers of two (docs/design.md, "Estimator decisions"). Unbiased. Needs
    /// --spp of at least 16.
    #[arg(long)]
    pub adaptive: bool,
    /// Sensor noise on the capture: `none` (the light the sensor receives, the Monte Carlo
    /// estimate) or `sensor` (measured by the scene's `[noise]` model from the stream of
    /// `--seed`; capture units with the mean dark offset removed, as datasets store captures).
    #[arg(long, value_enum, default_value = "none")]
    pub noise: crate::hadamard::CaptureNoise,
    /// With `--noise sensor`: the exposure, the brightest value of the all-white capture
    /// (capture units; default: from a 16-spp render of the scene with a white display, as
    /// Python's `sensor_noise`).
    #[arg(long, value_name = "X")]
    pub white_peak: Option<f64>,
}

/// The camera side paid once per design.
#[derive(clap::Args, Debug, Clone)]
pub struct TableArgs {
    /// Take the camera side (sensor to front face) from this design's table in the cache
    /// directory DIR, drawing and writing it there on first use; every later scene with the
    /// same design, crop, seed and table options reads it. In 3-D scenes the table holds each
    /// pixel's representative exit rays and `--spp` counts user-side paths per pixel; in a
    /// display-only scene it is H at `--table-spp` and a target's capture is H·f + offset. The
    /// sidecar records whether the table was read or built, and its time.
    #[arg(long, value_name = "DIR")]
    pub camera_table: Option<PathBuf>,
    /// Camera samples per pixel drawn for the table.
    #[arg(long, default_value_t = stscam_tracer::render::camera_table::DEFAULT_TABLE_SPP, requires = "camera_table")]
    pub table_spp: u32,
    /// 3-D scenes: representative exit rays per pixel kept in the table (72 bytes each).
    #[arg(long, default_value_t = stscam_tracer::render::camera_table::DEFAULT_TABLE_REPS, requires = "camera_table")]
    pub table_reps: u32,
}

impl Default for TableArgs {
    /// No table (the CLI's defaults for its settings).
    fn default() -> Self {
        TableArgs {
            camera_table: None,
            table_spp: stscam_tracer::render::camera_table::DEFAULT_TABLE_SPP,
            table_reps: stscam_tracer::render::camera_table::DEFAULT_TABLE_REPS,
        }
    }
}

impl TableArgs {
    /// The table's settings for a render with `seed`.
    pub fn settings(&self, seed: u64) -> stscam_tracer::render::camera_table::TableSettings {
        stscam_tracer::render::camera_table::TableSettings {
            spp: self.table_spp,
            reps: self.table_reps,
            seed,
        }
    }
}

/// `stscam render`: the capture, and in a 3-D scene the frontal view; written with their
/// sidecar, with warnings of non-finite or truncated paths.
#[allow(clippy::too_many_arguments)]
fn cmd_render(
    scene: &SceneArgs,
    out: &std::path::Path,
    run: &RunArgs,
    spectral: bool,
    sampler: SamplerKind,
    user_side: UserSideSampler,
    (frontal_px, frontal_spp): (Option<&str>, Option<u32>),
    frontal_space: crate::world::colour::FrontalSpace,
    (table, adaptive): (&TableArgs, bool),
    (noise, white_peak): (crate::hadamard::CaptureNoise, Option<f64>),
    con: &Console,
) -> Result<stscam_tracer::render::Capture, Failure> {
    let (spp, seed, threads) = run.checked()?;
    if white_peak.is_some() && noise != crate::hadamard::CaptureNoise::Sensor {
        return Err(bad_input(
            "--white-peak: sets the exposure of --noise sensor; add --noise sensor".to_string(),
        ));
    }
    let frontal_size = frontal_px.map(parse_frontal_px).transpose()?;
    if frontal_spp == Some(0) {
        return Err(bad_input("--frontal-spp: must be at least 1".to_string()));
    }
    let frontal_spp_given = frontal_spp.is_some();
    let frontal_spp = frontal_spp.unwrap_or(spp);
    let start = Instant::now();
    if out.exists() && !out.is_dir() {
        return Err(bad_input(format!(
            "{}: --out exists and is not a directory",
            out.display()
        )));
    }
    let pool = thread_pool(threads)?;
    let (ls, sys) = pool.install(|| load(scene))?;
    if let Some(w) = white_peak {
        crate::noise::SensorNoise::check_white_peak(&sys.scene.noise, w)
            .map_err(|e| bad_input(format!("--white-peak: {e}")))?;
    }
    let bins = spectral.then(|| stscam_tracer::render::spectral_bins(&sys.scene.sampling));
    let settings = RenderSettings {
        spp,
        seed,
        sampler,
        user_side,
        spectral_bins: bins,
        progress: true,
        estimator: Default::default(),
        adaptive,
    };
    stscam_tracer::render::check_limits(&sys, &settings, 1, "--spp").map_err(limit)?;
    stscam_tracer::render::adaptive::check(&sys, &settings, table.camera_table.is_some())
        .map_err(|e| bad_input(e.to_string()))?;
    check_frontal_paths(&sys, frontal_size, frontal_spp, frontal_spp_given).map_err(limit)?;
    let t0 = Instant::now();
    let (mut cap, table_info) = match &table.camera_table {
        None => (pool.install(|| render(&sys, &settings)), None),
        Some(dir) => pool.install(|| render_tabled(&sys, &settings, table, dir, con))?,
    };
    let render_s = t0.elapsed().as_secs_f64();
    let noise_info = match noise {
        crate::hadamard::CaptureNoise::None => serde_json::Value::String("none".into()),
        crate::hadamard::CaptureNoise::Sensor => {
            pool.install(|| measure_render(&sys, &mut cap, seed, white_peak, con))?
        }
    };
    let t1 = Instant::now();
    let (fw, fh) = frontal_size.unwrap_or((cap.width, cap.height));
    check_frontal_space(&sys, frontal_space)?;
    let frontal = pool.install(|| {
        stscam_tracer::frontal::render_frontal_in(&sys, fw, fh, frontal_spp, seed, frontal_space)
    });
    let frontal_s = t1.elapsed().as_secs_f64();
    let scene_json = serde_json::to_string(&sys.scene).map_err(|e| Failure {
        code: 1,
        message: e.to_string(),
    })?;
    let sidecar = serde_json::json!({
        "stscam_version": crate::VERSION,
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
        "noise": noise_info,
    });
    let mut sidecar = sidecar;
    if let Some(info) = table_info {
        sidecar["camera_table"] = info;
    }
    if let (Some(world), Some(f)) = (sys.world.as_deref(), frontal.as_ref()) {
        world_sidecar(
            &mut sidecar,
            &sys,
            world,
            &settings,
            (f, frontal_spp, frontal_s),
        );
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
    warn_stats(&cap.stats, con);
    // From a camera-side table no camera path is traced: the rate is the user side's.
    // A display target from H traces nothing at all.
    let rate = if cap.stats.camera_paths > 0 {
        format!(
            "{:.2} M paths/s",
            cap.stats.camera_paths as f64 / render_s / 1e6
        )
    } else if cap.stats.scene_paths > 0 {
        format!(
            "{:.2} M user-side paths/s",
            cap.stats.scene_paths as f64 / render_s / 1e6
        )
    } else {
        "H times the target".to_string()
    };
    let spp_text = match &cap.stats.sample_counts {
        Some(c) => format!(
            "{spp} spp (mean; pilot 2 x {}, then {}-{} per pixel)",
            c.pilot_spp, c.min_spp, c.max_spp
        ),
        None => format!("{spp} spp"),
    };
    con.err(format_args!(
        "wrote {}/{}: {}x{} px, {}, {:.3} s render, {} ({} threads)",
        out.display(),
        if frontal.is_some() {
            "capture.{exr,png,json}, frontal.{exr,png}, depth.exr, mask.png"
        } else {
            "capture.{exr,png,json}"
        },
        cap.width,
        cap.height,
        spp_text,
        render_s,
        rate,
        pool.current_num_threads()
    ));
    Ok(cap)
}

/// That a 3-D scene's frontal view (`size`, default the capture's crop, at `frontal_spp`
/// samples per pixel) stays within the path limit; the error names the flag(s) given: the
/// size, the samples per pixel or both (`--spp` sets the samples when `--frontal-spp` is
/// absent). Nothing to check without a 3-D user side. The CLI and the Python module share it.
pub fn check_frontal_paths(
    sys: &System,
    size: Option<(usize, usize)>,
    frontal_spp: u32,
    spp_given: bool,
) -> Result<(), crate::limits::LimitError> {
    if sys.world.is_none() {
        return Ok(());
    }
    let (fw, fh) = size.unwrap_or((sys.camera.width_px, sys.camera.height_px));
    let key = match (size.is_some(), spp_given) {
        (true, true) => "--frontal-px and --frontal-spp",
        (true, false) => "--frontal-px",
        _ => "--frontal-spp",
    };
    crate::limits::check_paths(key, fw as u128 * fh as u128 * u128::from(frontal_spp))
}

/// That the frontal view's colour space has a luminance over the sampling band (3-D scenes).
fn check_frontal_space(
    sys: &System,
    frontal_space: crate::world::colour::FrontalSpace,
) -> Result<(), Failure> {
    let sm = &sys.scene.sampling;
    if sys.world.is_some()
        && frontal_space != crate::world::colour::FrontalSpace::Sensor
        && crate::world::colour::ColourWeights::new(
            frontal_space,
            sm.lambda_min_nm,
            sm.lambda_max_nm,
        )
        .is_none()
    {
        return Err(bad_input(format!(
            "--frontal-space {}: the CIE luminance function is 0 over the sampling band {}-{} nm",
            frontal_space.name(),
            crate::numfmt::sig6(sm.lambda_min_nm),
            crate::numfmt::sig6(sm.lambda_max_nm)
        )));
    }
    Ok(())
}

/// The `world` and `frontal` entries of a 3-D render's sidecar.
fn world_sidecar(
    sidecar: &mut serde_json::Value,
    sys: &System,
    world: &crate::world::World,
    settings: &RenderSettings,
    (f, frontal_spp, frontal_s): (&stscam_tracer::frontal::Frontal, u32, f64),
) {
    sidecar["world"] = serde_json::json!({
        "objects": world.objects,
        "triangles": world.mesh.triangles.len(),
        "lights": sys.scene.light.len(),
        "bvh_build_s": world.accel.as_ref().map_or(0.0, |a| a.build_s),
        "display_enabled": sys.scene.display.enabled,
        "user_side": settings.user_side.resolve(Some(world)),
    });
    sidecar["frontal"] = serde_json::json!({
        "files": {
            "frontal.exr": format!("channels {:?}: {}", f.channel_names, crate::output::frontal_units(f.space)),
            "frontal.png": if f.space == crate::world::colour::FrontalSpace::Xyz {
                "16-bit preview of frontal.exr converted to linear sRGB (IEC 61966-2-1), sRGB-encoded, scaled to the 99.9th percentile"
            } else {
                "16-bit preview of frontal.exr (sRGB-encoded, scaled to the 99.9th percentile)"
            },
            "depth.exr": "channel Z: distance from the plate's front face along -z in mm, +inf where nothing is hit (pixel centre ray)",
            "mask.png": "16-bit grey: object index + 1 (see world.objects[].mask_value), 65535 the display, 0 nothing (pixel centre ray)",
        },
        "space": f.space.name(),
        "width": f.width,
        "height": f.height,
        "spp": frontal_spp,
        "camera": "pinhole at (0, 0, 0) mm (front face, bottom vHOE centre) looking along -z; pixel (c, r) looks along the capture's chief ray at crop position ((c + 0.5) * crop_w / w, (r + 0.5) * crop_h / h)",
        "rays": f.rays,
        "render_time_s": frontal_s,
    });
}

/// Warnings of samples zeroed as non-finite and of paths stopped with guided weight left.
fn warn_stats(stats: &stscam_tracer::render::RenderStats, con: &Console) {
    if stats.nonfinite_samples > 0 {
        con.err(format_args!(
            "warning: {} samples were NaN or infinite and were zeroed",
            stats.nonfinite_samples
        ));
    }
    if stats.max_truncated_weight > 1e-3 && stats.max_contacts_hits == 0 {
        con.err(format_args!(
            "warning: paths were stopped by sampling.min_guided_weight with up to {:.3e} of their guided weight left; lower it for this scene",
            stats.max_truncated_weight
        ));
    }
    if stats.max_contacts_hits > 0 {
        con.err(format_args!(
            "warning: {} paths hit sampling.max_contacts; up to {:.3e} of a path's guided weight was dropped",
            stats.max_contacts_hits, stats.max_truncated_weight
        ));
    }
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

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`; returns the capture (the values `capture.exr` holds, and the counters).
pub fn run(o: &RenderOptions, con: &Console) -> Result<stscam_tracer::render::Capture, JobError> {
    cmd_render(
        &o.scene,
        &o.out,
        &o.run,
        o.spectral,
        o.sampler,
        o.user_side,
        (o.frontal_px.as_deref(), o.frontal_spp),
        o.frontal_space,
        (&o.table, o.adaptive),
        (o.noise, o.white_peak),
        con,
    )
}

/// `render --noise sensor`: the capture `cap` measured by the scene's sensor model from the
/// stream of `seed` (`noise::measure_capture`, as datasets and Python's `sensor_noise`), the
/// exposure from `white_peak` or a white render; returns the sidecar's `noise` entry.
fn measure_render(
    sys: &System,
    cap: &mut stscam_tracer::render::Capture,
    seed: u64,
    white_peak: Option<f64>,
    con: &Console,
) -> Result<serde_json::Value, Failure> {
    let desc = &sys.scene.noise;
    let (peak, source) = match white_peak {
        Some(w) => (w, "--white-peak"),
        None => {
            con.err(format_args!(
                "--noise sensor: the exposure from a {}-spp render of a white display",
                crate::capture::WHITE_PEAK_SPP
            ));
            (
                crate::capture::white_peak_of_render(sys),
                "a 16-spp render (seed 1) of the scene with a white display",
            )
        }
    };
    let noise = crate::noise::SensorNoise::checked(desc, peak)
        .map_err(|e| bad_input(format!("--white-peak: {e}")))?;
    let clean: Vec<f64> = cap
        .channels
        .iter()
        .flatten()
        .map(|&v| f64::from(v))
        .collect();
    let mut noisy = crate::noise::measure_capture(&noise, &clean, seed).into_iter();
    for c in cap.channels.iter_mut() {
        for v in c.iter_mut() {
            *v = noisy.next().unwrap_or(0.0);
        }
    }
    Ok(serde_json::json!({
        "model": "sensor",
        "sensor": desc,
        "white_peak": peak,
        "white_peak_source": source,
        "seed": seed,
        "streams": "value i draws from NoiseRng([seed, 0x4E4F4953, i]) (noise::measure_capture)",
        "units": "capture units with the mean dark offset removed, as datasets store captures",
    }))
}

/// A render with the camera side from the design's table in `dir` (read, or drawn and
/// written): the capture and the sidecar's `camera_table` entry.
fn render_tabled(
    sys: &System,
    settings: &RenderSettings,
    table: &TableArgs,
    dir: &std::path::Path,
    con: &Console,
) -> Result<(stscam_tracer::render::Capture, Option<serde_json::Value>), Failure> {
    use stscam_tracer::render::camera_table::TableError;
    use stscam_tracer::render::table_file::{CachedTable, TableOrigin};
    let failure = |e: TableError| match e {
        TableError::Io(e @ crate::io::IoError::Io { .. }) => Failure {
            code: 1,
            message: e.to_string(),
        },
        TableError::Limit(l) => limit(l),
        other => bad_input(format!("--camera-table: {other}")),
    };
    // Refused before a table is drawn for nothing.
    stscam_tracer::render::camera_table::check_usable(settings).map_err(failure)?;
    let ts = table.settings(settings.seed);
    let t0 = Instant::now();
    let (t, info) =
        CachedTable::load_or_build(sys, &ts, dir, settings.progress).map_err(failure)?;
    let table_s = t0.elapsed().as_secs_f64();
    if let Some(note) = &info.note {
        con.err(format_args!("warning: camera-side table rebuilt: {note}"));
    }
    con.err(format_args!(
        "camera-side table {}: {} ({} {}, {:.3} s)",
        match info.origin {
            TableOrigin::Read => "read",
            TableOrigin::Built => "built",
            TableOrigin::Rebuilt => "rebuilt",
        },
        info.file.display(),
        info.entries,
        if info.kind == "matrix" {
            "entries of H"
        } else {
            "representatives"
        },
        table_s
    ));
    let t1 = Instant::now();
    let cap = t.render(sys, settings).map_err(failure)?;
    let out = serde_json::json!({
        "file": info.file,
        "kind": info.kind,
        "origin": info.origin,
        "settings": ts,
        "entries": info.entries,
        "table_time_s": table_s,
        "render_time_s": t1.elapsed().as_secs_f64(),
        "build_camera_paths": info.build_camera_paths,
    });
    Ok((cap, Some(out)))
}
