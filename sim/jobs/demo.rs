//! `stscam demo`: the paper's experiment end to end, and the several-depths part.

use std::path::PathBuf;

use crate::analysis;
use crate::render::RenderSettings;

use super::*;

/// The paper's experiment end to end: targets, captures, H, calibration, CGM and ADMM-TV, a table like its Table 1 and a figure like its Fig. 9.
#[derive(clap::Args, Debug, Clone)]
pub struct DemoOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Output directory.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Samples, seed and threads.
    #[command(flatten)]
    pub run: RunArgs,
}

fn cmd_demo(
    scene: &SceneArgs,
    out: &std::path::Path,
    run: &RunArgs,
    con: &Console,
) -> Result<(), Failure> {
    let (spp, seed, threads) = run.checked()?;
    check_out_dir(out)?;
    let pool = thread_pool(threads)?;
    let (_, mut sys) = pool.install(|| load(scene))?;
    let set = crate::demo::DemoSettings {
        spp,
        seed,
        cg: crate::recon::cg::CgSettings {
            iters: crate::recon::cg::DEFAULT_CG_ITERS,
            tol: 0.0,
        },
        admm: crate::recon::admm::AdmmSettings::default(),
        progress: true,
    };
    // H and one capture per target.
    let renders = 1 + crate::demo::DEMO_TARGETS.len() as u64;
    crate::render::check_limits(
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
        con.err(format_args!(
            "demo: the scene's crop misses part of the object; framing it with --set {set} (the crop moved onto the strongest replica of the display centre)"
        ));
        framed.set.push(set);
        sys = pool.install(|| load(&framed))?.1;
    }
    warn_coverage(&sys, "", con);
    let res = pool
        .install(|| crate::demo::run_demo(&sys, &set))
        .map_err(bad_input)?;
    write_files(out, &res.files)?;
    con.out(format_args!("{}", crate::demo::table_markdown(&res.rows)));
    con.out(format_args!(
        "{}",
        crate::demo::depth_table_markdown(&res.depth_rows, &res.depth_coverage)
    ));
    let t = &res.summary["timings_s"];
    con.err(format_args!(
        "wrote {} ({} files: table.md, table.json, table_depth.json, figure.png, figure_depth.png, H.npz, H_est.npz, calibration.json, images); {:.1} s in total ({} threads)",
        out.display(),
        res.files.len(),
        t["total"].as_f64().unwrap_or(f64::NAN),
        pool.current_num_threads()
    ));
    Ok(())
}

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`.
pub fn run(o: &DemoOptions, con: &Console) -> Result<(), JobError> {
    cmd_demo(&o.scene, &o.out, &o.run, con)
}
