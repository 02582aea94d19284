//! `stscam calibrate`: the paper's Hadamard calibration, simulated.

use std::path::PathBuf;
use std::time::Instant;

use super::*;

/// Simulate the paper's Hadamard calibration of H: DIR/H_est.npz and calibration.json.
#[derive(clap::Args, Debug, Clone)]
pub struct CalibrateOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Output directory.
    #[arg(long, default_value = "out/calibrate")]
    pub out: PathBuf,
    /// H_true to calibrate (scipy CSR .npz with its offset.npy); default: computed here.
    #[arg(long)]
    pub matrix: Option<PathBuf>,
    /// Object shape WxH of `--matrix` (default: from its H.json, else square).
    #[arg(long, value_name = "WxH")]
    pub object: Option<String>,
    /// Samples, seed and threads.
    #[command(flatten)]
    pub run: RunArgs,
    /// Sensor noise: `sensor` (the scene's [noise] section) or `none` (ideal camera).
    #[arg(long, value_enum, default_value = "sensor")]
    pub noise: crate::hadamard::CaptureNoise,
    /// Store the estimate with a dark frame subtracted from every frame (the report always
    /// gives the errors with and without it).
    #[arg(long)]
    pub dark_frame: bool,
    /// Render every pattern with the Monte Carlo tracer instead of applying H_true.
    #[arg(long)]
    pub render: bool,
    /// Keep entries of H_est above this many predicted noise standard deviations.
    #[arg(long, default_value_t = crate::hadamard::DEFAULT_THRESHOLD_SIGMA)]
    pub threshold_sigma: f64,
}

#[allow(clippy::too_many_arguments)]
fn cmd_calibrate(
    scene: &SceneArgs,
    out: &std::path::Path,
    matrix: Option<&std::path::Path>,
    object: Option<&str>,
    run: &RunArgs,
    noise: crate::hadamard::CaptureNoise,
    dark_frame: bool,
    render_frames: bool,
    threshold_sigma: f64,
    con: &Console,
) -> Result<(), Failure> {
    let (spp, seed, threads) = run.checked()?;
    use crate::hadamard::{CalibrationJob, CaptureNoise, TrueMatrix, calibrate_scene};
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
                con.err(format_args!(
                    "warning: no {} beside {}: the offset (all-black capture) is taken as 0",
                    stscam_tracer::matrix::default_offset_path(p).display(),
                    p.display()
                ));
            }
            Some(m)
        }
        None => None,
    };
    let job = CalibrationJob {
        matrix,
        spp,
        seed,
        noise,
        dark_frame,
        render_frames,
        threshold_sigma,
        progress: true,
    };
    let run = pool
        .install(|| calibrate_scene(&sys, &job))
        .map_err(bad_input)?;
    let (object, source_desc, sensor_noise) = (run.object, &run.source, &run.noise);
    let (matrix_s, render_s, calibrate_s) = (run.matrix_s, run.render_s, run.calibrate_s);
    let npz =
        crate::io::npz::encode_csr(&run.h_est, &out.join("H_est.npz")).map_err(write_failure)?;
    let names = stscam_tracer::matrix::PRIMARY_NAMES;
    let report = serde_json::json!({
        "stscam_version": crate::VERSION,
        "command": "calibrate",
        "scene_source": ls.source,
        "overrides": scene.set,
        "matrix": source_desc,
        "spp": spp,
        "seed": seed,
        "frames_from": if render_frames { "rendered patterns" } else { "H_true" },
        "noise": if noise == CaptureNoise::Sensor { serde_json::to_value(&sys.scene.noise).unwrap_or_default() } else { serde_json::Value::String("none".into()) },
        "exposure_electrons_per_unit": sensor_noise.as_ref().map(|s| s.electrons_per_unit),
        "stored_variant": if dark_frame { "dark frame subtracted" } else { "no dark frame (the paper's procedure)" },
        "threshold_sigma": threshold_sigma,
        "errors": "relative Frobenius norm ||H_est - H_true|| / ||H_true|| of the full (dense) estimate; column0 relative to ||H_true[:,0]||; stored_overall is the thresholded estimate written to H_est.npz",
        "report": if run.planes == 1 { serde_json::to_value(&run.reports[0]).unwrap_or_default() } else { serde_json::Value::Null },
        "report_per_primary": if run.planes == 1 { serde_json::Value::Null } else {
            serde_json::Value::Object(names.iter().zip(&run.reports).map(|(n, r)| (n.to_string(), serde_json::to_value(r).unwrap_or_default())).collect())
        },
        "object_primaries": if run.planes == 1 { serde_json::Value::Null } else { serde_json::json!(names) },
        "timings_s": {"matrix": matrix_s, "render_frames": render_s, "calibration": calibrate_s, "wall": start.elapsed().as_secs_f64()},
        "threads": pool.current_num_threads(),
    });
    // The scene rides along so that `stscam reconstruct` finds the sensor the frames had.
    let mut sidecar = serde_json::json!({"object_px": [object.0, object.1], "units": stscam_tracer::matrix::MATRIX_UNITS, "from": "stscam calibrate", "scene": sys.scene});
    if run.planes == 3 {
        sidecar["object_primaries"] = serde_json::json!(names);
        sidecar["columns"] = stscam_tracer::matrix::COLOUR_COLUMNS.into();
    }
    let report_bytes = serde_json::to_vec_pretty(&report).map_err(write_failure)?;
    let sidecar_bytes = serde_json::to_vec_pretty(&sidecar).map_err(write_failure)?;
    crate::io::write_all_atomic(
        out,
        &[
            ("H_est.npz", &npz),
            ("H_est.json", &sidecar_bytes),
            ("calibration.json", &report_bytes),
        ],
    )
    .map_err(write_failure)?;
    con.err(format_args!(
        "wrote {}/H_est.npz ({} entries) and calibration.json; {:.2} s calibration",
        out.display(),
        run.h_est.nnz(),
        calibrate_s
    ));
    for (i, r) in run.reports.iter().enumerate() {
        let who = if run.planes == 1 {
            String::new()
        } else {
            format!("primary {}: ", names[i])
        };
        con.err(format_args!(
            "{who}relative error {:.3e} without dark frame (column 0: {:.3e}), {:.3e} with (column 0: {:.3e})",
            r.without_dark_frame.overall,
            r.without_dark_frame.column0,
            r.with_dark_frame.overall,
            r.with_dark_frame.column0,
        ));
        if r.saturated_rows > 0 {
            con.err(format_args!(
                "warning: {who}{} rows had a saturated frame; lower noise.exposure_fraction",
                r.saturated_rows
            ));
        }
    }
    Ok(())
}

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`.
pub fn run(o: &CalibrateOptions, con: &Console) -> Result<(), JobError> {
    cmd_calibrate(
        &o.scene,
        &o.out,
        o.matrix.as_deref(),
        o.object.as_deref(),
        &o.run,
        o.noise,
        o.dark_frame,
        o.render,
        o.threshold_sigma,
        con,
    )
}
