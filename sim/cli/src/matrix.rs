//! `stscam matrix`: H and its offset in one pass, or a depth stack.

use std::path::PathBuf;
use std::time::Instant;

use crate::sampler::SamplerKind;
use crate::scene::LoadedScene;
use crate::system::System;
use stscam_tracer::render::RenderSettings;

use super::*;

/// Compute the system matrix H in one pass: DIR/H.npz (scipy CSR), H.json, offset.npy.
#[derive(clap::Args, Debug, Clone)]
pub struct MatrixOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Output directory.
    #[arg(long, default_value = "out/matrix")]
    pub out: PathBuf,
    /// Samples, seed and threads.
    #[command(flatten)]
    pub run: RunArgs,
    /// Object (display) distance in mm for this H; the camera focus stays as the scene
    /// sets it. Default: `display.distance_mm`. A list `D1,D2,...` or a range
    /// `START:STOP:STEPS` writes a depth stack in one pass: H_<D>mm.npz, offset_<D>mm.npy
    /// and H_<D>mm.json per depth, and the block matrix H_stack.npz.
    #[arg(long = "depth-mm", value_name = "D|D1,D2,...|START:STOP:STEPS")]
    pub depth_mm: Option<String>,
    /// Also render the scene's target with the same seed and spp and check that
    /// H·f + offset equals it to float rounding (the matrix–render contract); the
    /// difference is recorded in H.json, and a failure exits with code 1.
    #[arg(long)]
    pub check: bool,
}

/// How `matrix --depth-mm` was given: one depth (the plain file names) or a stack.
enum DepthSpec {
    Single(f64),
    Stack(Vec<f64>),
}

fn parse_depth_spec(spec: &str) -> Result<DepthSpec, Failure> {
    let depths = crate::stack::parse_depths(spec)
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
    m: &stscam_tracer::matrix::SystemMatrix,
    depth_mm: f64,
    [npz, offset, _]: [&str; 3],
    linearity: Option<f64>,
) -> serde_json::Value {
    let mut v = serde_json::json!({
        "stscam_version": crate::VERSION,
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
        "units": stscam_tracer::matrix::MATRIX_UNITS,
        "offset_file": offset,
        "files": {npz: "scipy.sparse CSR (float32 data, int32 indices and indptr while they fit)", offset: "float32 vector, one value per row of H"},
    });
    if m.planes == 3 {
        v["columns"] = stscam_tracer::matrix::COLOUR_COLUMNS.into();
        v["object_primaries"] = serde_json::json!(stscam_tracer::matrix::PRIMARY_NAMES);
    }
    v
}

/// `matrix --check`: renders `sys`'s target and returns max |H f + offset − render(f)| over the
/// capture's peak.
fn linearity_check(
    pool: &rayon::ThreadPool,
    sys: &System,
    settings: &RenderSettings,
    m: &stscam_tracer::matrix::SystemMatrix,
    con: &Console,
) -> f64 {
    let cap = pool.install(|| stscam_tracer::render::render(sys, settings));
    let pred = m.capture_of(&sys.display.intensity);
    let (mut diff, mut peak) = (0.0f64, 0.0f64);
    for (p, c) in pred.iter().zip(&cap.channels) {
        for (a, &b) in p.iter().zip(c) {
            diff = diff.max((a - f64::from(b)).abs());
            peak = peak.max(f64::from(b).abs());
        }
    }
    let rel = if peak > 0.0 { diff / peak } else { diff };
    con.err(format_args!(
        "linearity check at {} mm: max |H f + offset - render(f)| = {rel:.3e} of the capture's peak",
        -sys.display.z_mm
    ));
    rel
}

#[allow(clippy::too_many_arguments)]
fn cmd_matrix(
    scene: &SceneArgs,
    out: &std::path::Path,
    run: &RunArgs,
    depth_mm: Option<&str>,
    check: bool,
    con: &Console,
) -> Result<(), Failure> {
    let (spp, seed, threads) = run.checked()?;
    let start = Instant::now();
    let spec = depth_mm.map(parse_depth_spec).transpose()?;
    check_out_dir(out)?;
    let pool = thread_pool(threads)?;
    let (ls, mut sys) = pool.install(|| load(scene))?;
    if let Some(DepthSpec::Single(d)) = spec {
        stscam_tracer::matrix::place_object(&mut sys, d);
    }
    let settings = RenderSettings {
        spp,
        seed,
        sampler: SamplerKind::Lattice,
        user_side: Default::default(),
        spectral_bins: None,
        progress: true,
        estimator: Default::default(),
        adaptive: false,
    };
    stscam_tracer::render::check_limits(&sys, &settings, 1 + u64::from(check), "--spp")
        .map_err(limit)?;
    warn_coverage(&sys, "", con);
    if let Some(DepthSpec::Stack(depths)) = &spec {
        return matrix_stack(
            &ls, scene, &sys, &settings, &pool, depths, check, out, start, con,
        );
    }
    let t0 = Instant::now();
    let m = pool.install(|| stscam_tracer::matrix::compute_matrix(&sys, &settings));
    let matrix_s = t0.elapsed().as_secs_f64();
    let linearity = check.then(|| linearity_check(&pool, &sys, &settings, &m, con));
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
    crate::output::write_matrix(out, &m, &sidecar).map_err(write_failure)?;
    linearity.map(check_linearity).transpose()?;
    con.err(format_args!(
        "wrote {}/H.{{npz,json}} and offset.npy: {} x {}, {} stored entries ({:.3} % dense), {} spp, {:.3} s ({} threads)",
        out.display(),
        m.h.rows,
        m.h.cols,
        m.h.nnz(),
        100.0 * m.h.nnz() as f64 / (m.h.rows as f64 * m.h.cols as f64),
        spp,
        matrix_s,
        pool.current_num_threads()
    ));
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

/// `matrix --depth-mm LIST`: the depth stack in one pass (`crate::stack`): each depth's H,
/// offset and sidecar ([`StackJob::depth_files`]), the block matrix with the layered offset and
/// its sidecar, every matrix encoded in parallel ([`StackJob::encode_matrices`]).
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
    con: &Console,
) -> Result<(), Failure> {
    use crate::stack::{STACK_MATRIX, STACK_OFFSET, STACK_SIDECAR};
    use stscam_tracer::matrix::layered_offset;
    let job = StackJob {
        ls,
        scene,
        sys,
        settings,
        pool,
        depths,
        out,
    };
    let t0 = Instant::now();
    // The stack's peak (the pass, the matrices, the block matrix and the encoded files) is
    // estimated before the pass and bounded during it by the job memory limit.
    let (stack, memory) = pool
        .install(|| {
            stscam_tracer::matrix::compute_matrix_stack_within(
                sys,
                settings,
                depths,
                crate::limits::MAX_JOB_BYTES,
            )
        })
        .map_err(limit)?;
    let matrix_s = t0.elapsed().as_secs_f64();
    let (mut files, per_depth, failed_check) = job.depth_files(&stack, check, con)?;
    let blocks: Vec<&crate::sparse::CsrMatrix> = stack.iter().map(|m| &m.h).collect();
    let block = crate::sparse::CsrMatrix::hstack(&blocks).ok_or_else(|| {
        bad_input(format!(
            "--depth-mm: {} depths of {} object pixels exceed 32-bit column indices",
            depths.len(),
            stack[0].h.cols
        ))
    })?;
    let offset = layered_offset(&stack);
    let mut sidecar = job.stack_sidecar(&stack[0], &block, &memory, matrix_s);
    sidecar["depths"] = per_depth.into();
    sidecar["wall_time_s"] = start.elapsed().as_secs_f64().into();
    job.encode_matrices(&blocks, &block, &mut files)?;
    files.push((
        STACK_OFFSET.to_string(),
        crate::io::npz::encode_npy_f32(&out.join(STACK_OFFSET), &[offset.len()], &offset)
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
    con.err(format_args!(
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
    ));
    Ok(())
}

/// What the steps of [`matrix_stack`] share.
struct StackJob<'a> {
    ls: &'a LoadedScene,
    scene: &'a SceneArgs,
    sys: &'a System,
    settings: &'a RenderSettings,
    pool: &'a rayon::ThreadPool,
    depths: &'a [f64],
    out: &'a std::path::Path,
}

impl StackJob<'_> {
    /// Each depth's files (its matrix left empty for [`Self::encode_matrices`], its offset and
    /// sidecar, with the linearity check where `check`), its entry of the stack's sidecar, and
    /// the first failed check.
    #[allow(clippy::type_complexity)]
    fn depth_files(
        &self,
        stack: &[stscam_tracer::matrix::SystemMatrix],
        check: bool,
        con: &Console,
    ) -> Result<
        (
            Vec<(String, Vec<u8>)>,
            Vec<serde_json::Value>,
            Option<Failure>,
        ),
        Failure,
    > {
        use crate::stack::{STACK_MATRIX, coverage, depth_file_names};
        let mut files: Vec<(String, Vec<u8>)> = Vec::new();
        let mut per_depth = Vec::new();
        let mut failed_check = None;
        for (&d, m) in self.depths.iter().zip(stack) {
            let names = depth_file_names(d);
            let linearity = check.then(|| {
                let mut s = self.sys.clone();
                s.display.z_mm = -d;
                linearity_check(self.pool, &s, self.settings, m, con)
            });
            if let Some(rel) = linearity {
                failed_check = failed_check.or(check_linearity(rel).err());
            }
            let cov = coverage(&m.h);
            let mut side = matrix_sidecar(
                self.ls,
                self.scene,
                self.sys,
                self.settings,
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
                crate::io::npz::encode_npy_f32(
                    &self.out.join(&names[1]),
                    &[m.offset.len()],
                    &m.offset,
                )
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
        Ok((files, per_depth, failed_check))
    }

    /// H_stack.json without `depths` and `wall_time_s` (the caller adds them).
    fn stack_sidecar(
        &self,
        m0: &stscam_tracer::matrix::SystemMatrix,
        block: &crate::sparse::CsrMatrix,
        memory: &stscam_tracer::matrix::StackMemory,
        matrix_s: f64,
    ) -> serde_json::Value {
        use crate::stack::{STACK_MATRIX, STACK_OFFSET};
        serde_json::json!({
            "stscam_version": crate::VERSION,
            "command": "matrix",
            "depths_mm": self.depths,
            "scene_source": self.ls.source,
            "overrides": self.scene.set,
            "scene": self.sys.scene,
            "seed": self.settings.seed,
            "spp": self.settings.spp,
            "sampler": self.settings.sampler,
            "focus_distance_mm": self.sys.camera.focus_distance_mm,
            "shape": [block.rows, block.cols],
            "nnz": block.nnz(),
            "crop_px": [m0.crop.0, m0.crop.1],
            "object_px": [m0.object.0, m0.object.1],
            "channels": m0.channels,
            "rows": "as each depth's H (crop pixels, row-major; channel-major with several channels)",
            "columns": "depth-major blocks [H_1 ... H_N]: column = depth_index * object_pixels + object pixel (row-major), depths as in depths_mm",
            "model": "layered scene: g = sum_d (H_d f_d + o_d) + noise; planes are additive emitters without occlusion, each a display of the scene's extent at its depth; the camera focus, wavelength sampling and display extent are the scene's at every depth",
            "units": stscam_tracer::matrix::MATRIX_UNITS,
            "offset_file": STACK_OFFSET,
            "files": {STACK_MATRIX: "scipy.sparse CSR block matrix [H_1 ... H_N]", STACK_OFFSET: "float32 vector: sum over depths of the per-depth offsets (the capture with every layer black)"},
            "depths": null,
            "coverage": "capture_filled = fraction of capture pixels some object pixel reaches; object_seen = fraction of object pixels the capture sees",
            "threads": self.pool.current_num_threads(),
            "matrix_time_s": matrix_s,
            "wall_time_s": null,
            "paths_per_second": m0.stats.camera_paths as f64 / matrix_s,
            "stats": m0.stats,
            "memory": {
                "estimated_entries": memory.entries.round(),
                "pilot_pixels": memory.pilot_pixels,
                "estimated_peak_bytes": memory.estimated_peak_bytes() as f64,
                "peak_bytes_of_the_entries": memory.peak_bytes(block.nnz() as f64) as f64,
                "accepted_bytes": crate::limits::MAX_JOB_BYTES as f64,
            },
        })
    }

    /// Every matrix file (each depth's into its empty slot of `files`, then the block matrix
    /// appended) encoded in parallel.
    fn encode_matrices(
        &self,
        blocks: &[&crate::sparse::CsrMatrix],
        block: &crate::sparse::CsrMatrix,
        files: &mut Vec<(String, Vec<u8>)>,
    ) -> Result<(), Failure> {
        use crate::stack::{STACK_MATRIX, depth_file_names};
        let (depths, out) = (self.depths, self.out);
        let mut mats: Vec<&crate::sparse::CsrMatrix> = blocks.to_vec();
        mats.push(block);
        let encoded: Vec<Result<Vec<u8>, String>> = self.pool.install(|| {
            use rayon::prelude::*;
            mats.par_iter()
                .enumerate()
                .map(|(i, h)| {
                    let name = if i < depths.len() {
                        depth_file_names(depths[i])[0].clone()
                    } else {
                        STACK_MATRIX.to_string()
                    };
                    crate::io::npz::encode_csr(h, &out.join(name)).map_err(|e| e.to_string())
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
        Ok(())
    }
}

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`.
pub fn run(o: &MatrixOptions, con: &Console) -> Result<(), JobError> {
    cmd_matrix(
        &o.scene,
        &o.out,
        &o.run,
        o.depth_mm.as_deref(),
        o.check,
        con,
    )
}
