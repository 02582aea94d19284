//! `stscam info`: the design summary.

use crate::analysis;

use super::*;

/// Design summary: angles, replica pitch and count, Bragg wavelengths, field of view.
#[derive(clap::Args, Debug, Clone)]
pub struct InfoOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

fn fmt_fov(name: &str, f: &analysis::Fov) -> String {
    format!(
        "{name}: {:.2}° (from {:.2}°, limited by {}, to {:.2}°, limited by {})",
        f.full_deg, f.min.angle_deg, f.min.limited_by, f.max.angle_deg, f.max.limited_by
    )
}

/// `stscam info`: the design summary as JSON, or as text: critical angles, each grating's
/// fields ([`print_grating`]), the fields of view, the colour bands ([`print_colour_bands`])
/// and the object coverage.
fn cmd_info(
    scene: &SceneArgs,
    json: bool,
    con: &Console,
) -> Result<crate::analysis::DesignInfo, Failure> {
    let (_, sys) = load(scene)?;
    let info = analysis::info(&sys);
    if json {
        con.out(format_args!("{}", to_json(&info)?));
        return Ok(info);
    }
    con.out(format_args!(
        "critical angle glass→air at λ0: {:.3}° (n_glass = {:.5}); film→air {:.3}°",
        info.critical_angle_deg, info.n_glass_recording, info.film_critical_angle_deg
    ));
    con.out(format_args!(
        "grating period: {:.2} nm; focus {:.1} mm, lens–sensor {:.4} mm",
        info.grating_period_nm, info.focus_distance_mm, info.sensor_distance_mm
    ));
    let h = &sys.scene.hoe;
    if h.is_fabricated() {
        con.out(format_args!(
            "film as fabricated (hoe.* fabrication keys): {:.4} um, n = {:.5} (designed {} um, n = {}); every figure below is for this film",
            info.film_thickness_um, info.film_mean_index, h.film_thickness_um, h.mean_index
        ));
    }
    let multiplexed = info.gratings.len() > 1;
    for g in &info.gratings {
        print_grating(g, multiplexed, con);
    }
    con.out(format_args!(
        "{}",
        fmt_fov("vertical FOV, waveguide", &info.fov_vertical_waveguide)
    ));
    con.out(format_args!(
        "{}",
        fmt_fov("vertical FOV, capture", &info.fov_vertical_capture)
    ));
    con.out(format_args!(
        "{}",
        fmt_fov("horizontal FOV, waveguide", &info.fov_horizontal_waveguide)
    ));
    con.out(format_args!(
        "{}",
        fmt_fov("horizontal FOV, capture", &info.fov_horizontal_capture)
    ));
    if let Some(bands) = &info.colour_bands {
        print_colour_bands(bands, con);
    }
    let cov = &info.object_coverage;
    match cov.warning() {
        _ if !sys.scene.display.enabled => {}
        None => con.out(format_args!(
            "object ({}x{} px): every row and column seen through a replica with >= {} % of its strongest",
            cov.object_px[0],
            cov.object_px[1],
            cov.strong_fraction * 100.0
        )),
        Some(w) => con.out(format_args!("{w}")),
    }
    Ok(info)
}

/// One grating's table of fields and the sensor rows of a point at the display centre (with
/// its recording set-up where there are several gratings).
fn print_grating(g: &analysis::GratingInfo, multiplexed: bool, con: &Console) {
    if multiplexed {
        con.out(format_args!(
            "grating {}: recorded at {} nm, reference {}°, object {}°, n1 = {}; period {:.2} nm",
            g.grating,
            g.recording_wavelength_nm,
            g.reference_angle_deg,
            g.object_angle_deg,
            g.index_modulation,
            g.grating_period_nm
        ));
    }
    con.out(format_args!(
        "{:<8} {:>10} {:>10} {:>12} {:>9} {:>10}",
        "field", "λ_B (nm)", "Θ' (deg)", "pitch (mm)", "replicas", ">5% peak"
    ));
    for f in &g.field {
        con.out(format_args!(
            "{:<8} {:>10.2} {:>10.2} {:>12.3} {:>9} {:>10}",
            f.name,
            f.lambda_nm,
            f.guided_angle_deg,
            f.replica_pitch_mm,
            f.replicas,
            f.replicas_above_5pct
        ));
    }
    let rows: Vec<String> = g
        .point_replicas
        .iter()
        .map(|r| format!("{:.1} ({:.4})", r.row, r.weight))
        .collect();
    con.out(format_args!(
        "a point at the display centre appears at rows (weight){}: {}",
        if multiplexed {
            format!(" through grating {}", g.grating)
        } else {
            String::new()
        },
        rows.join(", ")
    ));
    con.out(format_args!(
        "replica spacing on the sensor (replicas above 5 % of the brightest): {:.2} px",
        g.replica_pitch_sensor_px
    ));
}

/// The colour band of each field row (the level of each primary at the best grating's Bragg
/// wavelength) and the primaries some row has no band in.
fn print_colour_bands(bands: &[crate::colour::FieldBands], con: &Console) {
    con.out(format_args!(
        "colour bands (level = primary's spectrum at the best grating's Bragg wavelength / its peak; a band needs >= {}):",
        crate::colour::BAND_LEVEL
    ));
    con.out(format_args!(
        "{:>8} {:>10} {:>28} {:>12} {:>12} {:>12}",
        "crop row",
        "field (°)",
        "λ_B per grating (nm)",
        "R (grating)",
        "G (grating)",
        "B (grating)"
    ));
    for b in bands {
        let lb: Vec<String> = b
            .bragg_nm
            .iter()
            .map(|l| l.map_or("-".into(), |v| format!("{v:.1}")))
            .collect();
        let lv = |p: usize| match b.grating[p] {
            Some(j) => format!(
                "{:.2} ({j}){}",
                b.level[p],
                if b.has_band(p) { "" } else { "!" }
            ),
            None => "- !".into(),
        };
        con.out(format_args!(
            "{:>8} {:>10.2} {:>28} {:>12} {:>12} {:>12}",
            b.crop_row,
            b.field_deg,
            lb.join(" "),
            lv(0),
            lv(1),
            lv(2)
        ));
    }
    let missing: Vec<String> = (0..3)
        .filter_map(|p| {
            let n = bands.iter().filter(|b| !b.has_band(p)).count();
            (n > 0).then(|| {
                format!(
                    "{} in {n} of {} rows",
                    stscam_tracer::matrix::PRIMARY_NAMES[p],
                    bands.len()
                )
            })
        })
        .collect();
    if missing.is_empty() {
        con.out(format_args!("every field row has a band in each primary"));
    } else {
        con.out(format_args!("no band (marked !): {}", missing.join(", ")));
    }
}

/// Runs the job: the design summary, returned and sent to `con`.
pub fn run(o: &InfoOptions, con: &Console) -> Result<crate::analysis::DesignInfo, JobError> {
    cmd_info(&o.scene, o.json, con)
}
