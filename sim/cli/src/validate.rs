//! `stscam validate analytic`: the tracer against closed forms.

use std::path::PathBuf;

use super::*;

/// The tracer against closed forms across the whole field (Bragg wavelength, guided angle, replica pitch and count, FOV limits, replica count against bottom-vHOE height): DIR/analytic.{md,csv,json} and plots; exit code 1 if a comparison fails.
#[derive(clap::Args, Debug, Clone)]
pub struct AnalyticOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Field angles to compare (at least 50).
    #[arg(long, default_value_t = 60)]
    pub fields: usize,
    /// Output directory.
    #[arg(long, default_value = "out/validate-analytic")]
    pub out: PathBuf,
}

fn cmd_validate_analytic(
    scene: &SceneArgs,
    fields: usize,
    out: &std::path::Path,
    con: &Console,
) -> Result<(), Failure> {
    use crate::analytic::{compare, quantity};
    use crate::plot::{LinePlot, Series};
    if !(50..=MAX_FIELDS).contains(&fields) {
        return Err(bad_input(format!(
            "--fields: must be in 50..={MAX_FIELDS}, got {fields}"
        )));
    }
    check_out_dir(out)?;
    let (_, sys) = load(scene)?;
    let report = compare(&sys, fields);
    let series = |q: &str, vertical_only: bool, by_param: bool| -> Vec<Series> {
        let rows: Vec<_> = report
            .rows
            .iter()
            .filter(|r| r.quantity == q && (!vertical_only || r.field_h_deg == 0.0))
            .collect();
        let x = |r: &crate::analytic::Row| if by_param { r.param } else { r.field_v_deg };
        vec![
            Series {
                name: "closed form".into(),
                points: rows.iter().map(|r| (x(r), r.closed_form)).collect(),
            },
            Series {
                name: "stscam tracer".into(),
                points: rows.iter().map(|r| (x(r), r.stscam)).collect(),
            },
        ]
    };
    let plot = |title: &str, xl: &str, yl: &str, s: Vec<Series>| LinePlot {
        title: title.into(),
        x_label: xl.into(),
        y_label: yl.into(),
        log_x: false,
        log_y: false,
        series: s,
        h_line: None,
    };
    let plots = [
        (
            "bragg",
            plot(
                "Bragg wavelength across the field",
                "vertical field angle (deg)",
                "lambda_B (nm)",
                series(quantity::LAMBDA_B, true, false),
            ),
        ),
        (
            "pitch",
            plot(
                "Replica pitch across the field",
                "vertical field angle (deg)",
                "pitch 2w tan(theta') (mm)",
                series(quantity::PITCH, true, false),
            ),
        ),
        (
            "count",
            plot(
                "Replica count against bottom vHOE height",
                "bottom vHOE height (mm)",
                "replicas at the field centre",
                series(quantity::COUNT_H, false, true),
            ),
        ),
    ];
    let mut files: Vec<(String, Vec<u8>)> = vec![
        ("analytic.md".into(), report.to_markdown().into_bytes()),
        ("analytic.csv".into(), report.to_csv().into_bytes()),
        (
            "analytic.json".into(),
            serde_json::to_vec_pretty(&report).map_err(write_failure)?,
        ),
    ];
    for (name, p) in &plots {
        files.push((format!("{name}.svg"), p.to_svg().into_bytes()));
        files.push((format!("{name}.png"), p.to_png().map_err(write_failure)?));
    }
    write_files(out, &files)?;
    con.out(format_args!("{}", report.to_markdown()));
    if !report.pass {
        return Err(Failure {
            code: 1,
            message: "analytic comparison failed (see analytic.md)".into(),
        });
    }
    Ok(())
}

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`.
pub fn run_analytic(o: &AnalyticOptions, con: &Console) -> Result<(), JobError> {
    cmd_validate_analytic(&o.scene, o.fields, &o.out, con)
}
