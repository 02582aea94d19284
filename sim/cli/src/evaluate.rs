//! `stscam evaluate`: one design's metrics (the primitive `optimize` calls).

use std::path::Path;

use crate::scene::SceneSource;

use stscam_design::evaluate::{
    Evaluation, Exposure, Fidelity, Request, Requirement, Target, evaluate,
};
use stscam_design::metric::Metric;

use super::*;

/// One design's metrics as text or one JSON object (`<name>` and `<name>_error`).
#[derive(clap::Args, Debug, Clone)]
pub struct EvaluateOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Metrics, comma-separated (e.g. `fov_capture_vertical_deg,psnr_db`); `_q05` after a
    /// geometry metric: its 5 % quantile over the tolerance draws.
    #[arg(long, value_name = "LIST", required = true)]
    pub metrics: String,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
    /// Reconstruction metrics: object size in pixels per side (the target keeps its size on
    /// the display).
    #[arg(long, default_value_t = 32)]
    pub object_px: u32,
    /// Reconstruction and stray-light metrics: sensor binning (the same sensor area in fewer, larger pixels).
    #[arg(long, default_value_t = 2)]
    pub binning: u32,
    /// Reconstruction and stray-light metrics: samples per pixel (of H and of the capture H; of the stray-light trace).
    #[arg(long, default_value_t = 8)]
    pub spp: u32,
    /// Reconstruction and stray-light metrics: independent replicates (their spread gives the error).
    #[arg(long, default_value_t = 2)]
    pub replicates: usize,
    /// Reconstruction targets, comma-separated: built-in specs without size or PNG/EXR files
    /// (default: the demo's four).
    #[arg(long, value_name = "LIST")]
    pub targets: Option<String>,
    /// Object depths in mm, comma-separated (default: the scene's display distance).
    #[arg(long, value_name = "LIST")]
    pub depth_mm: Option<String>,
    /// Fixed exposure: the all-white peak (capture units, at the same fidelity) that sets the
    /// electrons per unit (default: the design's own; `optimize` holds its base design's).
    #[arg(long)]
    pub white_peak: Option<f64>,
    /// Tolerance draw `KEY=normal(M,SD)` or `KEY=uniform(LO,HI)` (repeatable; hoe.* keys).
    #[arg(long = "draw", value_name = "KEY=DIST")]
    pub draw: Vec<String>,
    /// Number of tolerance draws.
    #[arg(long, default_value_t = 64)]
    pub draws: usize,
    /// Requirement of the yield, `METRIC>=V` or `METRIC<=V` (repeatable).
    #[arg(long = "require", value_name = "METRIC>=V")]
    pub require: Vec<String>,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// Splits a comma-separated list, dropping empty items.
fn items(s: &str) -> impl Iterator<Item = &str> {
    s.split(',').map(str::trim).filter(|t| !t.is_empty())
}

/// The request of the options (checked); relative target files resolve against `dir`.
fn request(o: &EvaluateOptions, dir: &Path, gamma: f64) -> Result<Request, Failure> {
    let metrics =
        Metric::parse_list(&o.metrics).map_err(|e| bad_input(format!("--metrics: {e}")))?;
    let targets = match &o.targets {
        Some(t) => items(t)
            .map(|t| Target::parse(t, dir, gamma).map_err(|e| bad_input(format!("--targets: {e}"))))
            .collect::<Result<Vec<_>, _>>()?,
        None => stscam_design::evaluate::default_targets(),
    };
    let depths_mm = match &o.depth_mm {
        Some(d) => items(d)
            .map(|v| {
                v.parse::<f64>()
                    .map_err(|_| bad_input(format!("--depth-mm: {v:?} is not a number")))
            })
            .collect::<Result<Vec<_>, _>>()?,
        None => Vec::new(),
    };
    let draws = o
        .draw
        .iter()
        .map(|d| {
            stscam_studies::tolerance::DrawSpec::parse(d).map_err(|e| bad_input(e.to_string()))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let requirements = o
        .require
        .iter()
        .map(|r| Requirement::parse(r).map_err(bad_input))
        .collect::<Result<Vec<_>, _>>()?;
    let req = Request {
        metrics,
        fidelity: Fidelity {
            object_px: Some(o.object_px),
            binning: o.binning,
            spp: o.spp,
            seed: o.seed,
            replicates: o.replicates,
            targets,
            depths_mm,
        },
        exposure: o.white_peak.map_or(Exposure::Own, Exposure::WhitePeak),
        draws,
        draw_count: if o.draw.is_empty() { 0 } else { o.draws },
        requirements,
    };
    req.check().map_err(|e| bad_input(e.to_string()))?;
    Ok(req)
}

/// The evaluation the options ask for, of the design `source` (with the options' `--set`
/// overrides; its display gamma `gamma` reads PNG targets), with `images` (targets held in
/// memory, as Python passes them) after the `--targets` list's, or alone when the options
/// name none: (the checked request, the evaluation). Runs in the caller's thread pool.
pub fn evaluation(
    o: &EvaluateOptions,
    source: SceneSource<'_>,
    gamma: f64,
    images: Vec<Target>,
) -> Result<(Request, Evaluation), JobError> {
    let dir = match source {
        SceneSource::File(p) => p
            .and_then(Path::parent)
            .map(Path::to_path_buf)
            .unwrap_or_default(),
        SceneSource::Text(_, _, d) => d.to_path_buf(),
    };
    let mut req = request(o, &dir, gamma)?;
    if !images.is_empty() {
        if o.targets.is_none() {
            req.fidelity.targets.clear();
        }
        req.fidelity.targets.extend(images);
        req.check().map_err(|e| bad_input(e.to_string()))?;
    }
    let ev = evaluate(source, &o.scene.set, &req).map_err(|e| bad_input(e.to_string()))?;
    Ok((req, ev))
}

/// The evaluation as the JSON object `--json` prints: each metric and `<name>_error` by name
/// (NaN, an undefined metric, is null: NaN is not JSON).
pub fn json_object(ev: &Evaluation) -> serde_json::Map<String, serde_json::Value> {
    ev.values
        .iter()
        .map(|(k, v)| {
            (
                k.clone(),
                serde_json::Number::from_f64(*v)
                    .map_or(serde_json::Value::Null, serde_json::Value::Number),
            )
        })
        .collect()
}

/// Runs the job: the metrics on stdout (text or JSON), warnings and the time on stderr.
pub fn run(o: &EvaluateOptions, con: &Console) -> Result<(), JobError> {
    let (ls, _) = load(&o.scene)?;
    let pool = thread_pool(o.threads)?;
    let (req, ev) = pool.install(|| {
        evaluation(
            o,
            SceneSource::File(o.scene.scene.as_deref()),
            ls.scene.display.gamma,
            Vec::new(),
        )
    })?;
    for w in &ev.warnings {
        con.err(format_args!(
            "warning: {}",
            w.trim_start_matches("warning: ")
        ));
    }
    if o.json {
        con.out(format_args!("{}", to_json(&json_object(&ev))?));
    } else {
        for m in &req.metrics {
            let name = m.to_string();
            let v = ev.values.get(&name).copied().unwrap_or(f64::NAN);
            let e = ev
                .values
                .get(&format!("{name}_error"))
                .map_or(String::new(), |e| format!(" ± {e:.4}"));
            con.out(format_args!("{name}: {v:.4}{e}"));
        }
    }
    let recon = req
        .metrics
        .iter()
        .any(|m| m.base.kind() == stscam_design::metric::Kind::Reconstruction);
    con.err(format_args!(
        "evaluated {} metrics in {:.2} s ({} threads){}",
        req.metrics.len(),
        ev.seconds,
        pool.current_num_threads(),
        if recon {
            format!(
                "; reconstruction at object {0}x{0} px, binning {1}, {2} spp, {3} replicates, white peak {4:.6e}",
                o.object_px, o.binning, o.spp, o.replicates, o.white_peak.unwrap_or(ev.white_peak)
            )
        } else {
            String::new()
        }
    ));
    Ok(())
}
