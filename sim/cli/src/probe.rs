//! `stscam probe`: the chief ray of one pixel.

use crate::analysis;

use super::*;

/// Trace the chief ray of one pixel at its exact Bragg wavelength (each grating's, in a
/// multiplexed film).
#[derive(clap::Args, Debug, Clone)]
pub struct ProbeOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Pixel of the crop as COL,ROW.
    #[arg(long, value_name = "COL,ROW")]
    pub pixel: String,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

fn cmd_probe(
    scene: &SceneArgs,
    pixel: &str,
    json: bool,
    con: &Console,
) -> Result<crate::analysis::ProbeResult, Failure> {
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
        con.out(format_args!("{}", to_json(&p)?));
        return Ok(p);
    }
    con.out(format_args!(
        "pixel {col},{row}: λ_B = {:.4} nm, guided angle {:.4}°, pitch {:.4} mm",
        p.lambda_nm, p.guided_angle_deg, p.replica_pitch_mm
    ));
    con.out(format_args!(
        "camera ray dir: [{:.6}, {:.6}, {:.6}]",
        p.camera_ray_dir[0], p.camera_ray_dir[1], p.camera_ray_dir[2]
    ));
    let multiplexed = p.gratings.len() > 1 || p.gratings.iter().any(|g| g.grating > 0);
    if multiplexed {
        for g in &p.gratings {
            con.out(format_args!(
                "grating {}: λ_B = {:.4} nm, guided angle {:.4}°, pitch {:.4} mm, {} replicas, weight {:.5}",
                g.grating, g.lambda_nm, g.guided_angle_deg, g.replica_pitch_mm, g.replicas, g.weight
            ));
        }
    }
    for r in &p.replicas {
        if multiplexed {
            con.out(format_args!(
                "grating {} replica {:>2} (λ {:.3} nm): contact ({:8.3}, {:8.3}) mm  object ({:8.3}, {:8.3}) mm  weight {:.5}",
                r.grating,
                r.index,
                r.lambda_nm,
                r.bottom_contact_mm[0],
                r.bottom_contact_mm[1],
                r.object_point_mm[0],
                r.object_point_mm[1],
                r.weight
            ));
            continue;
        }
        con.out(format_args!(
            "replica {:>2}: contact ({:8.3}, {:8.3}) mm  object ({:8.3}, {:8.3}) mm  weight {:.5}",
            r.index,
            r.bottom_contact_mm[0],
            r.bottom_contact_mm[1],
            r.object_point_mm[0],
            r.object_point_mm[1],
            r.weight
        ));
    }
    Ok(p)
}

/// Runs the job: the traced chief ray, returned and sent to `con`.
pub fn run(o: &ProbeOptions, con: &Console) -> Result<crate::analysis::ProbeResult, JobError> {
    cmd_probe(&o.scene, &o.pixel, o.json, con)
}
