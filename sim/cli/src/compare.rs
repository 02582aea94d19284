//! `stscam compare`: relative RMSE of two captures.

use std::path::PathBuf;

use super::*;

/// Relative RMSE ‖a − b‖₂/‖b‖₂ of two captures (all shared channels), b the reference.
#[derive(clap::Args, Debug, Clone)]
pub struct CompareOptions {
    /// Capture to assess (EXR).
    pub a: PathBuf,
    /// Reference capture (EXR).
    pub b: PathBuf,
    /// Also write a 16-bit PNG map of |a − b| (first shared channel).
    #[arg(long, value_name = "PNG")]
    pub map: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

fn cmd_compare(
    a: &std::path::Path,
    b: &std::path::Path,
    map: Option<&std::path::Path>,
    json: bool,
    con: &Console,
) -> Result<f64, Failure> {
    let (wa, ha, ca) = crate::io::read_exr(a).map_err(|e| bad_input(e.to_string()))?;
    let (wb, hb, cb) = crate::io::read_exr(b).map_err(|e| bad_input(e.to_string()))?;
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
    let rel = stscam_tracer::render::relative_rmse(&pairs);
    if let Some(path) = map {
        let (x, y) = pairs[0];
        let diff: Vec<f32> = x.iter().zip(y).map(|(p, q)| (p - q).abs()).collect();
        let png = crate::io::encode_png16(
            wa,
            ha,
            1,
            &crate::io::preview_u16(&[&diff], 0.999),
            crate::io::PngTransfer::Srgb,
        )
        .map_err(|m| Failure {
            code: 1,
            message: m,
        })?;
        crate::io::write_atomic(path, &png).map_err(write_failure)?;
    }
    if json {
        con.out(format_args!(
            "{}",
            serde_json::json!({ "relative_rmse": rel, "channels": pairs.len() })
        ));
    } else {
        con.out(format_args!("relative RMSE: {rel:.6}"));
    }
    Ok(rel)
}

/// Runs the job: the relative RMSE (returned and sent to `con`), and the map if asked for.
pub fn run(o: &CompareOptions, con: &Console) -> Result<f64, JobError> {
    cmd_compare(&o.a, &o.b, o.map.as_deref(), o.json, con)
}
