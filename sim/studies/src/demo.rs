//! The paper's experiment end to end (its §4, Fig. 9 and Table 1), on a simulated camera.
//!
//! 1. H of the scene (`matrix`, seed s) and its offset (LCD black leakage).
//! 2. Four built-in targets (two binary: a glyph and a shape; two grayscale: a Siemens star
//!    and a smooth photo-like field), each rendered by the Monte Carlo tracer with an
//!    *independent* seed (s + 1), so the captures do not share H's sampling noise (no
//!    "inverse crime"), then measured by the sensor noise model with the exposure set from the
//!    all-white capture; a noisy dark frame (all-black display) is subtracted.
//! 3. The Hadamard calibration (`hadamard.rs`) from H with the same noise model, with the dark
//!    frame subtracted, giving H_est.
//! 4. CGM and ADMM-TV with H and with H_est; PSNR and SSIM against the object (`metrics.rs`:
//!    linear intensities in [0, 1], reconstruction clipped, not rescaled).
//! 5. Several depths (the paper's limitation: its H holds at one distance). H is computed as
//!    part of a depth stack of 8 planes from 6/11 to 13/11 of the scene's distance D₀ (300,
//!    350, …, 650 mm for the paper's 550 mm) in one pass; H at D₀ is bit-identical to a plain
//!    `matrix`. The same targets are moved to the third plane (400 mm for the paper) and
//!    captured through an independently seeded H there (seed s + 1: H·f + o equals the
//!    tracer's render with that seed to float rounding, `matrix --check`), with the same noise.
//!    Each capture is reconstructed with the H of D₀ (what a camera calibrated at one distance
//!    does) and with the H of the depth estimated from the capture itself over the stack
//!    (`recon::depth`), each depth's model offset subtracted.
//!
//! Outputs: a Markdown and JSON table (like the paper's Table 1), a figure (object, capture,
//! CGM and ADMM-TV per row, for H and H_est), every image, H, H_est and the calibration report.

use std::time::Instant;

// The capture helpers live in `capture` (the other studies share them); they stay reachable
// here under their old paths.
pub use crate::capture::{
    DemoSettings, black_level_of, dark_frame, exposure_and_dark, intensity_of_spec,
    measured_capture, noisy_capture_of, planes_of_spec, white_peak_of,
};

use crate::hadamard::{CalibrationReport, CalibrationSettings, FrameSource, calibrate};
use crate::matrix::{SystemMatrix, compute_matrix_stack};
use crate::noise::SensorNoise;
use crate::recon::Problem;
use crate::recon::discrepancy::{NoiseLevel, admm_tv_discrepancy, cg_discrepancy};
use crate::recon::metrics::{psnr, ssim};
use crate::render::RenderSettings;
use crate::system::System;

/// The demo's targets: (name, kind, built-in spec without size).
pub const DEMO_TARGETS: [(&str, &str, &str); 4] = [
    ("glyph", "binary", "letter:A"),
    ("heart", "binary", "shape:heart"),
    ("siemens", "grayscale", "siemens:12"),
    ("smooth", "grayscale", "smooth:7"),
];

/// One row of the table.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DemoRow {
    /// Target name.
    pub target: String,
    /// "binary" or "grayscale".
    pub kind: String,
    /// Built-in spec.
    pub spec: String,
    /// "true" (the H of the model) or "calibrated" (H_est).
    pub matrix: String,
    /// "cgm" or "admm-tv".
    pub method: String,
    /// PSNR, dB.
    pub psnr_db: f64,
    /// SSIM.
    pub ssim: f64,
    /// Per-frame solve time (back-projection + iterations, and for the noise rule its
    /// least-squares fit, trace probes and τ search), ms.
    pub frame_ms: f64,
    /// Iterations done (CGM: where the discrepancy principle stopped it; ADMM-TV: per solve).
    pub iterations: usize,
    /// ADMM-TV: τ_rel chosen by the discrepancy principle (τ = τ_rel·‖Hᵀg‖∞).
    pub tau_rel: Option<f64>,
    /// Whether the discrepancy target was met inside the allowed range (CGM: before
    /// [`DEMO_CG_MAX_ITERS`]; ADMM-TV: τ_rel inside the search bracket).
    pub target_met: bool,
}

/// CGM's iteration cap in the demo's table (the discrepancy principle stops it earlier).
pub const DEMO_CG_MAX_ITERS: usize = crate::recon::discrepancy::CG_MAX_ITERS;

/// One target of the demo's several-depths part.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DepthRow {
    /// Target name.
    pub target: String,
    /// Where the object is, mm from the plate.
    pub true_depth_mm: f64,
    /// The distance H was made for (the scene's), mm.
    pub nominal_depth_mm: f64,
    /// The estimate over the stack.
    pub estimate: crate::recon::depth::DepthEstimate,
    /// PSNR (dB) and SSIM of CGM and ADMM-TV with the nominal H: [cgm, admm-tv].
    pub nominal: [(f64, f64); 2],
    /// The same with the H of the estimated depth.
    pub estimated: [(f64, f64); 2],
}

/// Number of planes of the demo's depth stack.
pub const DEMO_DEPTHS: usize = 8;
/// Index of the scene's own distance in the stack.
const NOMINAL: usize = 5;
/// Index of the plane the objects are moved to.
const NEAR: usize = 2;

/// The demo's depth grid for a scene at `d0_mm`: d0·(6 + i)/11 for i = 0..8, the sixth exactly
/// d0 (300, 350, …, 650 mm for 550 mm).
pub fn demo_depth_grid(d0_mm: f64) -> Vec<f64> {
    (0..DEMO_DEPTHS)
        .map(|i| {
            if i == NOMINAL {
                d0_mm
            } else {
                d0_mm * (6 + i) as f64 / 11.0
            }
        })
        .collect()
}

/// Everything the demo produced, in memory: files (name, bytes) and the summary.
pub struct DemoOutput {
    /// Files to write, flat names.
    pub files: Vec<(String, Vec<u8>)>,
    /// Table rows.
    pub rows: Vec<DemoRow>,
    /// The several-depths part, one row per target.
    pub depth_rows: Vec<DepthRow>,
    /// What the crop sees of an object at the near plane (`analysis::object_coverage`).
    pub depth_coverage: crate::analysis::ObjectCoverage,
    /// Calibration report.
    pub calibration: CalibrationReport,
    /// Summary JSON (timings, settings).
    pub summary: serde_json::Value,
}

/// One demo target and its simulated capture.
struct Shot {
    /// Target name.
    name: &'static str,
    /// "binary" or "grayscale".
    kind: &'static str,
    /// Built-in spec at the object size.
    spec: String,
    /// Linear object intensities.
    truth: Vec<f64>,
    /// The capture minus the measured dark frame (what the solvers get).
    g: Vec<f64>,
    /// The noisy capture as measured.
    noisy: Vec<f64>,
}

/// What the demo's steps share: the scene, the settings, the depth stack with the nominal H
/// and the sensor model calibrated on it.
struct DemoRun<'a> {
    sys: &'a System,
    set: &'a DemoSettings,
    /// Object size (square), pixels.
    obj: (usize, usize),
    /// Display gamma of the targets.
    gamma: f64,
    /// The scene's own object distance, mm.
    d0: f64,
    /// The depth grid ([`demo_depth_grid`]) and H at each of its depths.
    grid: Vec<f64>,
    stack: Vec<SystemMatrix>,
    /// H at the scene's distance (`stack[NOMINAL]`).
    m: SystemMatrix,
    /// Sensor model and measured dark frame.
    noise: SensorNoise,
    dark: Vec<f64>,
}

/// The several-depths part: the objects moved to the near plane, reconstructed with the
/// nominal H and with the H of the estimated depth.
struct DepthPart {
    /// Where the objects are, mm.
    near: f64,
    /// Their noisy captures.
    frames: Vec<Vec<f64>>,
    rows: Vec<DepthRow>,
    /// ADMM-TV reconstructions per target: [nominal H, estimated H].
    recons: Vec<Vec<Vec<f64>>>,
}

/// Wall times of the demo's steps, s.
struct DemoTimings {
    matrix: f64,
    captures: f64,
    calibration: f64,
    setup: f64,
    recon: f64,
    depth: f64,
}

/// The CGM / ADMM-TV columns of the table and figure, in the order of [`DemoRun::table`].
const RECON_NAMES: [&str; 4] = [
    "cgm_true",
    "admm-tv_true",
    "cgm_calibrated",
    "admm-tv_calibrated",
];

/// Runs the demo on `sys` (its display target fixes the object size, which must be square):
/// H as part of a depth stack, captures, calibration, the reconstruction table, several depths,
/// then the files.
pub fn run_demo(sys: &System, set: &DemoSettings) -> Result<DemoOutput, String> {
    let t_all = Instant::now();
    let (ow, oh) = (sys.display.width_px, sys.display.height_px);
    if ow != oh {
        return Err(format!(
            "display.image: the demo needs a square object, got {ow}x{oh}"
        ));
    }
    // 1. H, as part of the depth stack (5.).
    let t0 = Instant::now();
    let d0 = -sys.display.z_mm;
    let grid = demo_depth_grid(d0);
    let stack = compute_matrix_stack(
        sys,
        &RenderSettings::lattice(set.spp, set.seed, set.progress),
        &grid,
    );
    let m: SystemMatrix = stack[NOMINAL].clone();
    let matrix = t0.elapsed().as_secs_f64();
    let (noise, dark) = exposure_and_dark(sys, &m, set.seed);
    let run = DemoRun {
        sys,
        set,
        obj: (ow, oh),
        gamma: sys.scene.display.gamma,
        d0,
        grid,
        stack,
        m,
        noise,
        dark,
    };
    // 2. Captures.
    let t0 = Instant::now();
    let shots = run.captures()?;
    let captures = t0.elapsed().as_secs_f64();
    // 3. Calibration.
    let t0 = Instant::now();
    let cal = run.calibrate()?;
    let calibration = t0.elapsed().as_secs_f64();
    // 4. Reconstructions.
    let t0 = Instant::now();
    let p_true = Problem::with_cancel(&run.m.h, ow, oh, crate::cancel::current());
    let p_est = Problem::with_cancel(&cal.h_est, ow, oh, crate::cancel::current());
    let setup = t0.elapsed().as_secs_f64();
    let (table, recons) = run.table(&shots, &p_true, &p_est);
    let recon = t0.elapsed().as_secs_f64();
    // 5. Several depths.
    let t0 = Instant::now();
    let depth = run.several_depths(&shots);
    let times = DemoTimings {
        matrix,
        captures,
        calibration,
        setup,
        recon,
        depth: t0.elapsed().as_secs_f64(),
    };
    let coverage = run.coverage_at(depth.near);
    // Files.
    let mut files = run.image_files(&shots, &recons, &depth)?;
    let markdown = table_markdown(&table) + "\n" + &depth_table_markdown(&depth.rows, &coverage);
    files.push(("table.md".to_string(), markdown.into_bytes()));
    files.push(("table.json".to_string(), json_bytes(&table)?));
    files.push(("table_depth.json".to_string(), json_bytes(&depth.rows)?));
    let mut summary = run.summary(&cal, (&p_true, &p_est), &depth, &coverage);
    summary["timings_s"] = serde_json::json!({"matrix": times.matrix, "captures": times.captures, "calibration": times.calibration, "reconstruction_setup": times.setup, "reconstructions": times.recon, "several_depths": times.depth, "total": t_all.elapsed().as_secs_f64()});
    run.data_files(&mut files, &cal, &shots)?;
    files.push(("demo.json".to_string(), json_bytes(&summary)?));
    Ok(DemoOutput {
        files,
        rows: table,
        depth_rows: depth.rows,
        depth_coverage: coverage,
        calibration: cal.report,
        summary,
    })
}

/// `v` as pretty JSON.
fn json_bytes<T: serde::Serialize + ?Sized>(v: &T) -> Result<Vec<u8>, String> {
    serde_json::to_vec_pretty(v).map_err(|e| e.to_string())
}

/// Each caption row of a figure: the PSNR of each reconstruction of a target.
fn psnr_captions(shots: &[Shot], rec: &[Vec<Vec<f64>>]) -> Vec<Vec<String>> {
    shots
        .iter()
        .zip(rec)
        .map(|(s, per)| {
            per.iter()
                .map(|f| format!("{:.2} DB", psnr(f, &s.truth)))
                .collect()
        })
        .collect()
}

impl DemoRun<'_> {
    /// The first channel's rows of a capture (the figures show it).
    fn rows_per_channel(&self) -> usize {
        self.m.crop.0 * self.m.crop.1
    }

    /// Step 2: each demo target at the object size and its noisy capture with H.
    fn captures(&self) -> Result<Vec<Shot>, String> {
        let mut shots = Vec::new();
        for (ti, (name, kind, spec)) in DEMO_TARGETS.iter().enumerate() {
            let spec = format!("{spec}@{}", self.obj.0);
            let (_, _, truth) = intensity_of_spec(&spec, self.gamma)?;
            let (noisy, g) = measured_capture(
                self.sys,
                &truth,
                self.set,
                &self.noise,
                &self.dark,
                ti as u64,
            );
            shots.push(Shot {
                name,
                kind,
                spec,
                truth,
                g,
                noisy,
            });
        }
        Ok(shots)
    }

    /// Step 3: the Hadamard calibration of H with the sensor model, dark frame subtracted.
    fn calibrate(&self) -> Result<crate::hadamard::Calibration, String> {
        calibrate(
            &self.m.h,
            &self.m.offset,
            FrameSource::Matrix,
            &CalibrationSettings {
                noise: Some(self.noise.clone()),
                seed: self.set.seed,
                dark_frame: true,
                threshold_sigma: crate::hadamard::DEFAULT_THRESHOLD_SIGMA,
                progress: self.set.progress,
            },
        )
        .map_err(|e| format!("display.image: {e}"))
    }

    /// Step 4: every target reconstructed by CGM and ADMM-TV with H true and H calibrated: the
    /// table rows and per target the reconstructions in [`RECON_NAMES`]' order.
    ///
    /// Both methods regularise by the discrepancy principle on the sensor model
    /// (`recon::discrepancy`); the black level each pixel sits at comes from the measured dark
    /// frame (a camera knows its dark frame, not the simulator's offset).
    fn table(
        &self,
        shots: &[Shot],
        p_true: &Problem,
        p_est: &Problem,
    ) -> (Vec<DemoRow>, Vec<Vec<Vec<f64>>>) {
        let mut table = Vec::new();
        let mut recons: Vec<Vec<Vec<f64>>> = Vec::new();
        let dark_level = black_level_of(&self.dark, &self.noise);
        let pb = crate::progress::Progress::new(
            self.set.progress,
            4 * shots.len() as u64,
            "demo reconstructions",
        );
        for shot in shots {
            let mut per = Vec::new();
            for (mname, p) in [("true", p_true), ("calibrated", p_est)] {
                let t_level = Instant::now();
                let level = NoiseLevel::of_capture(p, &shot.g, &dark_level, true, &self.noise);
                let level_ms = 1e3 * t_level.elapsed().as_secs_f64();
                for method in ["cgm", "admm-tv"] {
                    let (row, f) = self.table_cell(shot, p, &level, method, level_ms);
                    pb.inc(1);
                    table.push(DemoRow {
                        matrix: mname.to_string(),
                        ..row
                    });
                    per.push(f);
                }
            }
            recons.push(per);
        }
        (table, recons)
    }

    /// One reconstruction of the table (`method` "cgm" or "admm-tv") with its row (`matrix`
    /// left empty); `level_ms` is the time the noise level took, counted in the frame time.
    fn table_cell(
        &self,
        shot: &Shot,
        p: &Problem,
        level: &NoiseLevel,
        method: &str,
        level_ms: f64,
    ) -> (DemoRow, Vec<f64>) {
        let (ow, oh) = self.obj;
        let t = Instant::now();
        let htg = p.back_project(&shot.g);
        let (f, iterations, tau_rel, target_met) = if method == "cgm" {
            let r = cg_discrepancy(p, &htg, level, DEMO_CG_MAX_ITERS);
            let met = r.iterations < DEMO_CG_MAX_ITERS;
            (r.f, r.iterations, None, met)
        } else {
            let c = admm_tv_discrepancy(p, &htg, level, &self.set.admm);
            (c.result.f, self.set.admm.iters, Some(c.tau_rel), c.reached)
        };
        let frame_ms = level_ms + 1e3 * t.elapsed().as_secs_f64();
        let row = DemoRow {
            target: shot.name.to_string(),
            kind: shot.kind.to_string(),
            spec: shot.spec.clone(),
            matrix: String::new(),
            method: method.to_string(),
            psnr_db: psnr(&f, &shot.truth),
            ssim: ssim(&f, &shot.truth, ow, oh),
            frame_ms,
            iterations,
            tau_rel,
            target_met,
        };
        (row, f)
    }

    /// Step 5: the targets moved to the near plane (H of a second seed), their depth estimated
    /// over the stack, and each reconstructed with the nominal H and with the estimated depth's.
    fn several_depths(&self, shots: &[Shot]) -> DepthPart {
        let (set, (ow, oh), grid) = (self.set, self.obj, &self.grid);
        let near = grid[NEAR];
        let near_m = compute_matrix_stack(
            self.sys,
            &RenderSettings::lattice(set.spp, set.seed.wrapping_add(1), set.progress),
            &[near],
        )
        .swap_remove(0);
        // Measured frames with the sensor's mean dark offset removed (the black level left is
        // the optics' offset of the object's depth, which each depth's H brings along).
        let dark_units = self.noise.dark_offset_units();
        let frames: Vec<Vec<f64>> = shots
            .iter()
            .enumerate()
            .map(|(ti, shot)| {
                noisy_capture_of(&near_m, &shot.truth, &self.noise, set.seed, 16 + ti as u64)
                    .into_iter()
                    .map(|v| v - dark_units)
                    .collect()
            })
            .collect();
        let blocks: Vec<&crate::sparse::CsrMatrix> = self.stack.iter().map(|m| &m.h).collect();
        let offsets: Vec<Option<&[f32]>> = self.stack.iter().map(|m| Some(&m.offset[..])).collect();
        let estimates = crate::recon::depth::estimate_depths(
            &blocks,
            &offsets,
            (ow, oh),
            &frames,
            grid,
            crate::recon::depth::DEFAULT_DEPTH_CG_ITERS,
            &crate::cancel::current(),
        );
        let mut rows = Vec::new();
        let mut recons: Vec<Vec<Vec<f64>>> = Vec::new();
        let mut problems: Vec<Option<Problem>> = vec![None; grid.len()];
        let pb = crate::progress::Progress::new(
            set.progress,
            2 * shots.len() as u64,
            "demo several-depths reconstructions",
        );
        for ((shot, frame), est) in shots.iter().zip(&frames).zip(estimates) {
            let mut scores = [[(0.0, 0.0); 2]; 2];
            let mut per = Vec::new();
            for (k, d) in [NOMINAL, est.best].into_iter().enumerate() {
                let p = problems[d].get_or_insert_with(|| {
                    Problem::with_cancel(&self.stack[d].h, ow, oh, crate::cancel::current())
                });
                let g: Vec<f64> = frame
                    .iter()
                    .zip(&self.stack[d].offset)
                    .map(|(a, &o)| a - f64::from(o))
                    .collect();
                let htg = p.back_project(&g);
                // The discrepancy principle on the sensor model, as the table.
                let level =
                    NoiseLevel::of_capture(p, &g, &self.stack[d].offset, false, &self.noise);
                let cg = cg_discrepancy(p, &htg, &level, DEMO_CG_MAX_ITERS).f;
                let admm = admm_tv_discrepancy(p, &htg, &level, &set.admm).result.f;
                pb.inc(1);
                for (j, f) in [cg, admm].into_iter().enumerate() {
                    scores[k][j] = (psnr(&f, &shot.truth), ssim(&f, &shot.truth, ow, oh));
                    if j == 1 {
                        per.push(f);
                    }
                }
            }
            rows.push(DepthRow {
                target: shot.name.to_string(),
                true_depth_mm: near,
                nominal_depth_mm: self.d0,
                estimate: est,
                nominal: scores[0],
                estimated: scores[1],
            });
            recons.push(per);
        }
        DepthPart {
            near,
            frames,
            rows,
            recons,
        }
    }

    /// What the crop sees of an object moved to `near` mm.
    fn coverage_at(&self, near: f64) -> crate::analysis::ObjectCoverage {
        let mut moved = self.sys.clone();
        crate::matrix::place_object(&mut moved, near);
        crate::analysis::object_coverage(&moved)
    }

    /// The pictures: each target, its capture and reconstructions, and the two figures.
    fn image_files(
        &self,
        shots: &[Shot],
        recons: &[Vec<Vec<f64>>],
        depth: &DepthPart,
    ) -> Result<Vec<(String, Vec<u8>)>, String> {
        let ((ow, oh), gamma, m) = (self.obj, self.gamma, &self.m);
        let rows_per_channel = self.rows_per_channel();
        let mut files: Vec<(String, Vec<u8>)> = Vec::new();
        let png = |f: &[f64]| crate::output::encode_object_png(f, ow, oh, gamma);
        for (shot, per) in shots.iter().zip(recons) {
            files.push((format!("object_{}.png", shot.name), png(&shot.truth)?));
            let cap_png = crate::io::encode_png16(
                m.crop.0,
                m.crop.1,
                1,
                &crate::io::preview_u16(
                    &[&shot.noisy[..rows_per_channel]
                        .iter()
                        .map(|&v| v as f32)
                        .collect::<Vec<f32>>()],
                    0.999,
                ),
                crate::io::PngTransfer::Srgb,
            )?;
            files.push((format!("capture_{}.png", shot.name), cap_png));
            for (f, n) in per.iter().zip(RECON_NAMES) {
                files.push((format!("recon_{}_{n}.png", shot.name), png(f)?));
            }
        }
        files.push((
            "figure.png".to_string(),
            figure(
                &FIGURE_COLUMNS,
                &shots
                    .iter()
                    .map(|s| (s.name, &s.truth[..], &s.noisy[..rows_per_channel]))
                    .collect::<Vec<_>>(),
                recons,
                &psnr_captions(shots, recons),
                (ow, oh),
                m.crop,
                gamma,
            )?,
        ));
        let mm = crate::numfmt::sig6;
        let mut depth_captions = psnr_captions(shots, &depth.recons);
        for (c, r) in depth_captions.iter_mut().zip(&depth.rows) {
            c[1] += &format!(" AT {}", mm(r.estimate.depth_mm));
        }
        files.push((
            "figure_depth.png".to_string(),
            figure(
                &[
                    "OBJECT",
                    &format!("CAPTURE {} MM", mm(depth.near)),
                    &format!("ADMM H {} MM", mm(self.d0)),
                    "ADMM H EST",
                ],
                &shots
                    .iter()
                    .zip(&depth.frames)
                    .map(|(s, f)| (s.name, &s.truth[..], &f[..rows_per_channel]))
                    .collect::<Vec<_>>(),
                &depth.recons,
                &depth_captions,
                (ow, oh),
                m.crop,
                gamma,
            )?,
        ));
        Ok(files)
    }

    /// `demo.json` without its `timings_s` (the caller adds them): settings, noise, matrix
    /// sizes, the calibration report and the several-depths set-up.
    fn summary(
        &self,
        cal: &crate::hadamard::Calibration,
        (p_true, p_est): (&Problem, &Problem),
        depth: &DepthPart,
        coverage: &crate::analysis::ObjectCoverage,
    ) -> serde_json::Value {
        let (set, (ow, oh), m, sys) = (self.set, self.obj, &self.m, self.sys);
        serde_json::json!({
            "stscam_version": crate::VERSION,
            "command": "demo",
            "spp": set.spp,
            "seed": set.seed,
            "capture_seed": set.seed.wrapping_add(1),
            "object_px": [ow, oh],
            "crop_px": [m.crop.0, m.crop.1],
            "targets": DEMO_TARGETS.iter().map(|t| format!("{}@{ow}", t.2)).collect::<Vec<_>>(),
            "noise": sys.scene.noise,
            "exposure_electrons_per_unit": self.noise.electrons_per_unit,
            "cgm": {"table": {"stopping": "discrepancy principle in the range of H (recon::discrepancy)", "max_iters": DEMO_CG_MAX_ITERS}, "several_depths": {"stopping": "discrepancy principle in the range of H (recon::discrepancy), the black level the depth's offset", "max_iters": DEMO_CG_MAX_ITERS}},
            "admm_tv": {"iters": set.admm.iters, "table": {"tau": "discrepancy principle in the range of H (recon::discrepancy), bisection in log tau_rel", "tau_rel_bracket": [crate::recon::discrepancy::TAU_REL_MIN, crate::recon::discrepancy::TAU_REL_MAX]}, "several_depths": {"tau": "discrepancy principle, as the table"}, "rho_rel": set.admm.rho_rel, "tv": set.admm.tv, "inner_iters": set.admm.inner_iters},
            "noise_conditions": noise_conditions(&sys.scene.noise, &self.noise),
            "metrics": "linear object intensity in [0,1] (display gamma removed), reconstruction clipped to [0,1], not rescaled; PSNR peak 1; SSIM of Wang et al. 2004 (Gaussian sigma 1.5, 11x11, K1 0.01, K2 0.03), mean over the pixels where the window fits",
            "matrix_nnz": m.h.nnz(),
            "h_est_nnz": cal.h_est.nnz(),
            "gram_layout": {"true": p_true.gram_layout(), "calibrated": p_est.gram_layout()},
            "timings_s": null,
            "calibration": cal.report,
            "several_depths": {"grid_mm": self.grid, "nominal_mm": self.d0, "object_mm": depth.near, "capture_seed": set.seed.wrapping_add(1), "noise_streams": "16 + target index", "black_level": "the sensor's mean dark offset and the depth's offset subtracted", "criterion": "smallest relative residual after a short CGM per depth (recon::depth)", "cg_iterations": crate::recon::depth::DEFAULT_DEPTH_CG_ITERS, "object_coverage_at_object_mm": coverage},
        })
    }

    /// The data files: the calibration report, H (with its offset) and H_est with their
    /// sidecars (the scene included), the dark frame and the captures (float32 .npy).
    fn data_files(
        &self,
        files: &mut Vec<(String, Vec<u8>)>,
        cal: &crate::hadamard::Calibration,
        shots: &[Shot],
    ) -> Result<(), String> {
        let ((ow, oh), m) = (self.obj, &self.m);
        files.push(("calibration.json".to_string(), json_bytes(&cal.report)?));
        let h_npz = crate::io::npz::encode_csr(&m.h, std::path::Path::new("H.npz"))
            .map_err(|e| e.to_string())?;
        files.push(("H.npz".to_string(), h_npz));
        let npy = |name: &str, v: &[f64]| {
            let v32: Vec<f32> = v.iter().map(|&x| x as f32).collect();
            crate::io::npz::encode_npy_f32(std::path::Path::new(name), &[v32.len()], &v32)
                .map_err(|e| e.to_string())
        };
        files.push(("dark.npy".to_string(), npy("dark.npy", &self.dark)?));
        let offset = crate::io::npz::encode_npy_f32(
            std::path::Path::new("offset.npy"),
            &[m.offset.len()],
            &m.offset,
        )
        .map_err(|e| e.to_string())?;
        files.push(("offset.npy".to_string(), offset));
        for shot in shots {
            let name = format!("capture_{}.npy", shot.name);
            files.push((name.clone(), npy(&name, &shot.noisy)?));
        }
        let est = crate::io::npz::encode_csr(&cal.h_est, std::path::Path::new("H_est.npz"))
            .map_err(|e| e.to_string())?;
        files.push(("H_est.npz".to_string(), est));
        // The scene rides along so that `stscam reconstruct` finds its sensor model.
        let sidecar = serde_json::json!({"object_px": [ow, oh], "crop_px": [m.crop.0, m.crop.1], "units": crate::matrix::MATRIX_UNITS, "scene": self.sys.scene});
        let sc = json_bytes(&sidecar)?;
        files.push(("H.json".to_string(), sc.clone()));
        files.push(("H_est.json".to_string(), sc));
        Ok(())
    }
}

/// The table as Markdown: one row per target, PSNR / SSIM per method and matrix.
pub fn table_markdown(rows: &[DemoRow]) -> String {
    let mut s = String::from(
        "| target | kind | CGM, H true | ADMM-TV, H true | CGM, H calibrated | ADMM-TV, H calibrated |\n|---|---|---|---|---|---|\n",
    );
    let mut targets: Vec<&str> = rows.iter().map(|r| r.target.as_str()).collect();
    targets.dedup();
    for t in targets {
        let kind = rows
            .iter()
            .find(|r| r.target == t)
            .map_or("", |r| r.kind.as_str());
        let cell = |m: &str, method: &str| {
            rows.iter()
                .find(|r| r.target == t && r.matrix == m && r.method == method)
                .map_or("–".to_string(), |r| {
                    format!("{:.2} dB / {:.3}", r.psnr_db, r.ssim)
                })
        };
        s += &format!(
            "| {t} | {kind} | {} | {} | {} | {} |\n",
            cell("true", "cgm"),
            cell("true", "admm-tv"),
            cell("calibrated", "cgm"),
            cell("calibrated", "admm-tv")
        );
    }
    let mean = |m: &str, method: &str| {
        let v: Vec<f64> = rows
            .iter()
            .filter(|r| r.matrix == m && r.method == method)
            .map(|r| r.psnr_db)
            .collect();
        format!("{:.2} dB", v.iter().sum::<f64>() / v.len().max(1) as f64)
    };
    s += &format!(
        "| mean | | {} | {} | {} | {} |\n",
        mean("true", "cgm"),
        mean("true", "admm-tv"),
        mean("calibrated", "cgm"),
        mean("calibrated", "admm-tv")
    );
    let taus: Vec<String> = rows
        .iter()
        .filter(|r| r.method == "admm-tv")
        .map(|r| {
            let t = r.tau_rel.map_or("–".to_string(), |t| format!("{t:.2e}"));
            format!(
                "{} {}: {t}{}",
                r.target,
                r.matrix,
                if r.target_met { "" } else { " (bound)" }
            )
        })
        .collect();
    let its: Vec<String> = rows
        .iter()
        .filter(|r| r.method == "cgm")
        .map(|r| format!("{} {}: {}", r.target, r.matrix, r.iterations))
        .collect();
    s += "\nPSNR (peak 1) / SSIM of the reconstruction clipped to [0, 1] against the object, both in linear display intensity. Both methods are regularised by the discrepancy principle on the sensor noise model (in the range of H; docs/validation.md): ADMM-TV's tau_rel (tau = tau_rel·max |Hᵀg|) and CGM's stopping iteration.\n";
    if !taus.is_empty() {
        s += &format!("\nADMM-TV tau_rel: {}.\n", taus.join(", "));
    }
    if !its.is_empty() {
        s += &format!("\nCGM iterations: {}.\n", its.join(", "));
    }
    s
}

/// The demo's noise conditions as numbers (demo.json `noise_conditions`): the sensor model's
/// parameters and what they mean for the all-white frame.
fn noise_conditions(desc: &crate::scene::NoiseDesc, noise: &SensorNoise) -> serde_json::Value {
    let white_e = desc.exposure_fraction * desc.full_well_e;
    let mut v = serde_json::json!({
        "bit_depth": desc.bit_depth,
        "full_well_e": desc.full_well_e,
        "read_noise_e": desc.read_noise_e,
        "dark_offset_dn": desc.dark_offset_dn,
        "white_peak_e": white_e,
        "white_peak_dn": white_e / noise.electrons_per_dn,
        "white_peak_snr": white_e / (white_e + desc.read_noise_e * desc.read_noise_e).sqrt(),
        "frames_averaged": 1,
    });
    // The EMVA 1288 fixed patterns, when the sensor has them (absent for the ideal sensor).
    if let (Some(f), Some(m)) = (noise.fixed, v.as_object_mut()) {
        m.insert(
            "fixed_pattern".into(),
            serde_json::json!({
                "prnu": f.prnu,
                "dsnu_e": f.dsnu_e,
                "mean_dark_e": f.dark_e,
                "hot_pixel_fraction": f.hot_fraction,
                "hot_pixel_dark_e": f.hot_e,
                "sensor_seed": f.seed,
            }),
        );
    }
    v
}

/// The several-depths table as Markdown: one row per target.
pub fn depth_table_markdown(
    rows: &[DepthRow],
    coverage: &crate::analysis::ObjectCoverage,
) -> String {
    let Some(first) = rows.first() else {
        return String::new();
    };
    let mm = crate::numfmt::sig6;
    let (d, d0) = (mm(first.true_depth_mm), mm(first.nominal_depth_mm));
    let mut s = format!(
        "Several depths: the object at {d} mm, H made for {d0} mm or for the depth estimated from the capture.\n\n| target | estimated depth (refined, confidence) | CGM, H {d0} mm | ADMM-TV, H {d0} mm | CGM, H estimated | ADMM-TV, H estimated |\n|---|---|---|---|---|---|\n"
    );
    let cell = |(p, q): (f64, f64)| format!("{p:.2} dB / {q:.3}");
    for r in rows {
        s += &format!(
            "| {} | {} mm ({:.1} mm, {:.2}) | {} | {} | {} | {} |\n",
            r.target,
            mm(r.estimate.depth_mm),
            r.estimate.refined_depth_mm,
            r.estimate.confidence,
            cell(r.nominal[0]),
            cell(r.nominal[1]),
            cell(r.estimated[0]),
            cell(r.estimated[1]),
        );
    }
    if !coverage.complete() {
        let mut parts = Vec::new();
        if !coverage.rows_unseen.is_empty() {
            parts.push(format!(
                "rows {}",
                crate::analysis::ranges(&coverage.rows_unseen)
            ));
        }
        if !coverage.cols_unseen.is_empty() {
            parts.push(format!(
                "columns {}",
                crate::analysis::ranges(&coverage.cols_unseen)
            ));
        }
        s += &format!(
            "\nThe crop was framed for {d0} mm; at {d} mm object {} have no replica in it with at least {} % of their strongest replica's weight, which limits even the right H.\n",
            parts.join(" and "),
            coverage.strong_fraction * 100.0
        );
    }
    s
}

/// Area (box) resampling of a `w`×`h` image to `tw`×`th`.
pub fn resample(src: &[f64], w: usize, h: usize, tw: usize, th: usize) -> Vec<f64> {
    let (sx, sy) = (w as f64 / tw as f64, h as f64 / th as f64);
    let mut out = vec![0.0; tw * th];
    for ty in 0..th {
        let (y0, y1) = (ty as f64 * sy, (ty + 1) as f64 * sy);
        for tx in 0..tw {
            let (x0, x1) = (tx as f64 * sx, (tx + 1) as f64 * sx);
            let (mut acc, mut area) = (0.0, 0.0);
            for y in y0.floor() as usize..(y1.ceil() as usize).min(h) {
                let wy = (y1.min(y as f64 + 1.0) - y0.max(y as f64)).max(0.0);
                for x in x0.floor() as usize..(x1.ceil() as usize).min(w) {
                    let wx = (x1.min(x as f64 + 1.0) - x0.max(x as f64)).max(0.0);
                    acc += wx * wy * src[y * w + x];
                    area += wx * wy;
                }
            }
            out[ty * tw + tx] = if area > 0.0 { acc / area } else { 0.0 };
        }
    }
    out
}

/// Tile size of the figure, pixels.
const TILE: usize = 192;
/// Gap between tiles, pixels.
const GAP: usize = 6;

/// Column labels of the demo's figure and of the colour demo's: object, capture, then CGM and
/// ADMM-TV with the true H and with the calibrated one.
pub(crate) const FIGURE_COLUMNS: [&str; 6] = [
    "OBJECT",
    "CAPTURE",
    "CGM H TRUE",
    "ADMM TV H TRUE",
    "CGM H CAL",
    "ADMM TV H CAL",
];

/// The Fig. 9-like figure: per target a row object | capture | CGM | ADMM-TV (H true) |
/// CGM | ADMM-TV (H calibrated), with column labels; grey 16-bit PNG, display code values.
#[allow(clippy::too_many_arguments)]
fn figure(
    labels: &[&str],
    shots: &[(&str, &[f64], &[f64])],
    recons: &[Vec<Vec<f64>>],
    captions: &[Vec<String>],
    object: (usize, usize),
    crop: (usize, usize),
    gamma: f64,
) -> Result<Vec<u8>, String> {
    let (w, h, img) = figure_canvas(labels, shots, recons, captions, object, crop, gamma, None);
    let samples: Vec<u16> = img
        .iter()
        .map(|&v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16)
        .collect();
    crate::io::encode_png16(
        w,
        h,
        1,
        &samples,
        crate::io::PngTransfer::DisplayGamma(gamma),
    )
}

/// The figure's canvas (width, height, display code values in [0, 1]) of [`figure`]; each
/// capture is scaled by `capture_peaks[row]` if given, else by its own 99.9th percentile, and
/// that scale is written under it (`WHITE 1.2e-3`: the capture value shown as white).
#[allow(clippy::too_many_arguments)]
pub(crate) fn figure_canvas(
    labels: &[&str],
    shots: &[(&str, &[f64], &[f64])],
    recons: &[Vec<Vec<f64>>],
    captions: &[Vec<String>],
    object: (usize, usize),
    crop: (usize, usize),
    gamma: f64,
    capture_peaks: Option<&[f64]>,
) -> (usize, usize, Vec<f64>) {
    let cols = labels.len();
    let label_h = 9 * 2 + 4;
    // Row labels (target names) in a left column; each reconstruction's PSNR under its tile.
    let row_label_w = shots
        .iter()
        .map(|s| crate::targets::label(&s.0.to_ascii_uppercase(), 2).0)
        .max()
        .unwrap_or(0)
        + GAP;
    let psnr_h = label_h;
    let row_h = TILE + psnr_h + GAP;
    let w = row_label_w + cols * TILE + (cols + 1) * GAP;
    let h = label_h + shots.len() * row_h + GAP;
    let mut img = vec![1.0f64; w * h];
    let mut blit = |tile: &[f64], x0: usize, y0: usize, tw: usize, th: usize| {
        for y in 0..th {
            for x in 0..tw {
                if x0 + x < w && y0 + y < h {
                    img[(y0 + y) * w + x0 + x] = tile[y * tw + x];
                }
            }
        }
    };
    let text = |blit: &mut dyn FnMut(&[f64], usize, usize, usize, usize),
                s: &str,
                x_centre: usize,
                y0: usize,
                max_w: usize| {
        let (lw, lh, v) = crate::targets::label(&s.to_ascii_uppercase(), 2);
        let inv: Vec<f64> = v.iter().map(|&p| 1.0 - f64::from(p)).collect();
        if lw <= max_w {
            blit(&inv, x_centre.saturating_sub(lw / 2), y0, lw, lh);
        }
    };
    let col_x = |c: usize| row_label_w + GAP + c * (TILE + GAP);
    for (c, l) in labels.iter().enumerate() {
        text(&mut blit, l, col_x(c) + TILE / 2, 2, TILE);
    }
    for (r, (name, _, _)) in shots.iter().enumerate() {
        let y0 = label_h + r * row_h + TILE / 2 - 9;
        text(&mut blit, name, row_label_w / 2, y0, row_label_w);
    }
    let code = |v: f64| v.clamp(0.0, 1.0).powf(1.0 / gamma);
    for (r, (((_, truth, capture), rec), caps)) in
        shots.iter().zip(recons).zip(captions).enumerate()
    {
        let y0 = label_h + r * row_h;
        for (k, cap) in caps.iter().enumerate() {
            text(&mut blit, cap, col_x(2 + k) + TILE / 2, y0 + TILE + 3, TILE);
        }
        let mut tiles: Vec<Vec<f64>> = Vec::new();
        tiles.push(resample(truth, object.0, object.1, TILE, TILE));
        let peak = match capture_peaks {
            Some(p) => p[r],
            None => percentile_peak(capture),
        };
        // The capture's scale, stated: the value shown as white (capture units, 1 = a white
        // display pixel through lossless optics), so a near-empty capture does not read as a
        // bright one.
        let scale = format!("WHITE {peak:.1e}");
        text(&mut blit, &scale, col_x(1) + TILE / 2, y0 + TILE + 3, TILE);
        let cap: Vec<f64> = capture.iter().map(|v| v / peak).collect();
        tiles.push(resample(&cap, crop.0, crop.1, TILE, TILE));
        for f in rec {
            tiles.push(resample(f, object.0, object.1, TILE, TILE));
        }
        for (c, t) in tiles.iter().enumerate() {
            let t: Vec<f64> = t.iter().map(|&v| code(v)).collect();
            blit(&t, col_x(c), y0, TILE, TILE);
        }
    }
    (w, h, img)
}

/// The 99.9th percentile of a capture (its display scale in the figures), at least the
/// smallest positive number.
pub(crate) fn percentile_peak(capture: &[f64]) -> f64 {
    let mut s: Vec<f64> = capture.to_vec();
    s.sort_by(f64::total_cmp);
    s[((s.len() as f64 - 1.0) * 0.999) as usize].max(f64::MIN_POSITIVE)
}
