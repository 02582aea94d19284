//! `stscam demo`: the paper's experiment end to end, and the several-depths part.

use std::path::PathBuf;

use crate::analysis;
use stscam_tracer::render::RenderSettings;

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
    /// The full-colour camera instead: the scene's film (the paper's single grating) against
    /// the three-grating film of scenes/rgb-multiplex.toml (a scene whose film multiplexes
    /// several gratings: the paper's single grating against it), both with the colour LCD
    /// (`display.primaries = "lcd"`) and the rgb-bayer sensor, on colour targets: colour H,
    /// colour Hadamard calibration, CGM and colour ADMM-TV, colour PSNR and CIEDE2000, colour
    /// bands and the cross-talk between gratings (table.md, table.json, figure.png).
    #[arg(long)]
    pub colour: bool,
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
    let set = stscam_studies::demo::DemoSettings {
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
    let renders = 1 + stscam_studies::demo::DEMO_TARGETS.len() as u64;
    stscam_tracer::render::check_limits(
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
        .install(|| stscam_studies::demo::run_demo(&sys, &set))
        .map_err(bad_input)?;
    write_files(out, &res.files)?;
    con.out(format_args!(
        "{}",
        stscam_studies::demo::table_markdown(&res.rows)
    ));
    con.out(format_args!(
        "{}",
        stscam_studies::demo::depth_table_markdown(&res.depth_rows, &res.depth_coverage)
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
    if o.colour {
        return cmd_colour_demo(&o.scene, &o.out, &o.run, con);
    }
    cmd_demo(&o.scene, &o.out, &o.run, con)
}

/// `demo --colour`: the two designs, each framed on the object as `demo` frames its scene: the
/// scene's film against the built-in RGB multiplex, or, when the scene's film multiplexes
/// several gratings, the paper's single grating against the scene's film.
fn cmd_colour_demo(
    scene: &SceneArgs,
    out: &std::path::Path,
    run: &RunArgs,
    con: &Console,
) -> Result<(), Failure> {
    let (spp, seed, threads) = run.checked()?;
    check_out_dir(out)?;
    let pool = thread_pool(threads)?;
    let colour = [
        "display.primaries=lcd".to_string(),
        "sensor.response=rgb-bayer".to_string(),
    ];
    let paper_args = SceneArgs {
        scene: scene.scene.clone(),
        set: colour
            .iter()
            .cloned()
            .chain(scene.set.iter().cloned())
            .collect(),
    };
    // The user's film against the paper's single grating when it multiplexes several
    // gratings; else the scene's (single) grating against the built-in RGB multiplex.
    let user_gratings = pool
        .install(|| {
            crate::scene::load_scene(paper_args.scene.as_deref(), &paper_args.set)
                .map_err(|e| bad_input(e.to_string()))
                .and_then(|ls| {
                    crate::system::System::build(&ls).map_err(|e| bad_input(e.to_string()))
                })
        })?
        .waveguide
        .gratings
        .len();
    let user_name = scene
        .scene
        .as_deref()
        .and_then(|p| std::path::Path::new(p).file_stem())
        .map_or("scene".to_string(), |s| s.to_string_lossy().into_owned());
    // (name, source): None the user's scene, Some(None) the paper's, Some(Some(t)) TOML text.
    let sources: [(String, Option<Option<&str>>); 2] = if user_gratings > 1 {
        [("single-grating".into(), Some(None)), (user_name, None)]
    } else {
        [
            ("single-grating".into(), None),
            (
                "rgb-multiplex".into(),
                Some(Some(crate::scene::RGB_MULTIPLEX_TOML)),
            ),
        ]
    };
    let mut designs = Vec::new();
    for (name, source) in sources {
        let name = name.as_str();
        let build = |set: &[String]| -> Result<crate::system::System, Failure> {
            let ls = match source {
                None => crate::scene::load_scene(paper_args.scene.as_deref(), set),
                Some(None) => crate::scene::load_scene(None, set),
                Some(Some(t)) => crate::scene::load_scene_text(
                    Some((
                        t,
                        crate::scene::RGB_MULTIPLEX_NAME,
                        std::path::Path::new("."),
                    )),
                    set,
                ),
            }
            .map_err(|e| bad_input(e.to_string()))?;
            crate::system::System::build(&ls).map_err(|e| bad_input(e.to_string()))
        };
        let mut set = match source {
            None => paper_args.set.clone(),
            // The paper's grating with the colour display and the user's keys but the film's.
            Some(None) => paper_args
                .set
                .iter()
                .filter(|k| !k.starts_with("hoe."))
                .cloned()
                .collect(),
            Some(Some(_)) => scene.set.clone(),
        };
        let mut sys = pool.install(|| build(&set))?;
        if let Some(off) = analysis::framing_offset_px(&sys) {
            set.push(format!("sensor.crop_offset_px=[{},{}]", off[0], off[1]));
            con.err(format_args!(
                "demo --colour: {name}: framing the crop on the object with --set {}",
                set.last().map_or("", String::as_str)
            ));
            sys = pool.install(|| build(&set))?;
        }
        stscam_tracer::render::check_limits(
            &sys,
            &RenderSettings::lattice(spp, seed, false),
            1 + crate::colour_demo::COLOUR_TARGETS.len() as u64,
            "--spp",
        )
        .map_err(limit)?;
        warn_coverage(&sys, "", con);
        designs.push((name.to_string(), sys));
    }
    let set = stscam_studies::demo::DemoSettings {
        spp,
        seed,
        cg: crate::recon::cg::CgSettings {
            iters: crate::recon::cg::DEFAULT_CG_ITERS,
            tol: 0.0,
        },
        admm: crate::recon::admm::AdmmSettings::default(),
        progress: true,
    };
    let t0 = std::time::Instant::now();
    let res = pool
        .install(|| crate::colour_demo::run_colour_demo(&designs, &set))
        .map_err(bad_input)?;
    write_files(out, &res.files)?;
    con.out(format_args!(
        "{}",
        crate::colour_demo::table_markdown(&res.rows, &res.designs)
    ));
    con.err(format_args!(
        "wrote {} (table.md, table.json, figure.png); {:.1} s in total ({} threads)",
        out.display(),
        t0.elapsed().as_secs_f64(),
        pool.current_num_threads()
    ));
    Ok(())
}
