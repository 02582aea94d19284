//! `stscam sweep`: a design sweep over a grid of scene-key values.

use std::path::PathBuf;
use std::time::Instant;

use super::*;

/// Design sweep: FOV (and what limits it), scene field, replicas, pitch, light efficiency, Bragg range and optionally the ADMM-TV PSNR over a grid of scene-key values: DIR/sweep.{csv,json} and a PNG + SVG plot per quantity.
#[derive(clap::Args, Debug, Clone)]
pub struct SweepOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Varied key and its grid, e.g. `bottom_hoe.height_mm=10:80:15` (STEPS points from START
    /// to STOP; repeatable: the Cartesian product, first axis slowest).
    #[arg(long, value_name = "KEY=START:STOP:STEPS", required = true)]
    pub vary: Vec<String>,
    /// Output directory.
    #[arg(long, default_value = "out/sweep")]
    pub out: PathBuf,
    /// FOV: field angles whose throughput is at least this fraction of the peak.
    #[arg(long, default_value_t = stscam_studies::sweep::DEFAULT_FOV_FRACTION)]
    pub fov_fraction: f64,
    /// Also compute the ADMM-TV PSNR of this built-in target (H, capture and noise as in
    /// `demo`; seconds per grid point), e.g. `letter:A`.
    #[arg(long, value_name = "TARGET")]
    pub psnr: Option<String>,
    /// Samples per pixel of H and the capture for --psnr.
    #[arg(long, default_value_t = 64)]
    pub psnr_spp: u32,
    /// Print the rows as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
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
    con: &Console,
) -> Result<(), Failure> {
    use stscam_studies::sweep::{PsnrSettings, SweepSettings, VaryAxis, run_sweep};
    let axes = vary
        .iter()
        .map(|v| VaryAxis::parse(v))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| bad_input(e.to_string()))?;
    if psnr_spp == 0 {
        return Err(bad_input("--psnr-spp: must be at least 1"));
    }
    if let Some(t) = psnr {
        crate::targets::builtin_target(t).map_err(|e| bad_input(format!("--psnr: {e}")))?;
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
        con.out(format_args!("{}", to_json(&res.rows)?));
    } else {
        for r in &res.rows {
            let f = &r.figures;
            let key: Vec<String> = r
                .varied
                .iter()
                .map(|v| format!("{}={}", v.key, v.value))
                .collect();
            con.out(format_args!(
                "{}: FOV captured {:.2}° x {:.2}°, waveguide {:.2}° x {:.2}° (V x H), scene field {:.1} mm ({:.2}°) vertically, replicas {} (>= 5 %) / {}, pitch {:.3} mm, efficiency {:.4} (crop mean), Bragg {:.1}-{:.1} nm{}",
                key.join(" "),
                f.fov_vertical_capture.full_deg,
                f.fov_horizontal_capture.full_deg,
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
            ));
        }
    }
    let mut secs = res.point_seconds.clone();
    secs.sort_by(f64::total_cmp);
    con.err(format_args!(
        "wrote {} ({} grid points, {} files) in {:.1} s; median {:.2} s per point ({} threads)",
        out.display(),
        res.rows.len(),
        res.files.len(),
        t0.elapsed().as_secs_f64(),
        secs.get(secs.len() / 2).copied().unwrap_or(f64::NAN),
        pool.current_num_threads()
    ));
    Ok(())
}

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`.
pub fn run(o: &SweepOptions, con: &Console) -> Result<(), JobError> {
    cmd_sweep(
        &o.scene,
        &o.vary,
        &o.out,
        o.fov_fraction,
        o.psnr.as_deref(),
        o.psnr_spp,
        o.json,
        o.threads,
        con,
    )
}
