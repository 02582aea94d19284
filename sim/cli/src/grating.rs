//! `stscam grating`: every propagating order of one vHOE film over a wavelength range, from
//! Kogelnik's model or the RCWA (`grating_spectrum`), as text, JSON and a plot.

use std::collections::BTreeMap;
use std::path::PathBuf;

use crate::grating_spectrum::{self as gs, GratingSpec, Model, OrderKey, StackKind};
use crate::optics::rcwa::{self, Settings};
use crate::plot::{LinePlot, Series};

use super::*;

/// Most wavelengths of `--lambda-nm`.
pub const MAX_WAVELENGTHS: usize = 100_000;

/// Efficiency of every diffracted order of one vHOE film over a wavelength range.
#[derive(clap::Args, Debug, Clone)]
pub struct GratingOptions {
    /// The scene and its overrides (the film and grating from `[hoe]`, the glass from `[plate]`).
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Grating model.
    #[arg(long, value_enum, default_value = "rcwa")]
    pub model: Model,
    /// Layer stack: `bulk` (film between half-spaces of its mean index) or `contact`
    /// (glass | film | air, light from the glass).
    #[arg(long, value_enum, default_value = "bulk")]
    pub stack: StackKind,
    /// Wavelengths START:STOP:N (N evenly spaced values, inclusive).
    #[arg(
        long = "lambda-nm",
        value_name = "START:STOP:N",
        default_value = "500:560:61"
    )]
    pub lambda_nm: String,
    /// Field angles X,Y in degrees, as every command's: the camera looks along
    /// (tan X, tan Y, −1)/‖·‖, so the light from the user travels along (−tan X, −tan Y, 1)/‖·‖.
    #[arg(
        long = "field-deg",
        value_name = "X,Y",
        default_value = "0,0",
        allow_hyphen_values = true
    )]
    pub field_deg: String,
    /// Replace the scene's grating by this list (repeatable; all in the scene's film):
    /// recording wavelength in nm, reference angle inside the film in degrees, index modulation.
    #[arg(long = "grating", value_name = "NM,DEG,N1")]
    pub gratings: Vec<String>,
    /// RCWA: half-width M of the harmonic set (orders −M…M of the common period).
    #[arg(long, default_value_t = rcwa::DEFAULT_HARMONICS)]
    pub harmonics: usize,
    /// RCWA: slices per z-period of the grating.
    #[arg(long = "slices-per-period", default_value_t = rcwa::DEFAULT_SLICES_PER_PERIOD)]
    pub slices_per_period: usize,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also write grating.json, grating.png and grating.svg (η(λ) per order and polarisation).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// One order over the wavelengths (JSON).
#[derive(serde::Serialize, Debug, Clone)]
pub struct OrderCurve {
    /// `reflected` (back through the entrance side) or `transmitted`.
    pub side: &'static str,
    /// Kogelnik: the grating (0-based) of the order; RCWA: absent (orders of the whole film).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub grating: Option<usize>,
    /// Order index m (tangential k = k_inc − m·G·ê; for one grating Kogelnik's σ = ρ − mK).
    pub order: i32,
    /// Unit direction per wavelength in the medium it leaves into (null: evanescent or trapped).
    pub direction: Vec<Option<[f64; 3]>>,
    /// TE efficiency per wavelength.
    pub eta_te: Vec<f64>,
    /// TM efficiency per wavelength.
    pub eta_tm: Vec<f64>,
}

/// The command's result (JSON).
#[derive(serde::Serialize, Debug, Clone)]
pub struct GratingReport {
    /// Model.
    pub model: Model,
    /// Stack.
    pub stack: StackKind,
    /// How TE and TM are defined.
    pub polarisation: &'static str,
    /// Field angles X, Y in degrees.
    pub field_deg: [f64; 2],
    /// Incident tangential direction cosines u (conserved in every layer).
    pub u: [f64; 2],
    /// The gratings.
    pub gratings: Vec<GratingSpec>,
    /// Film thickness (µm) as fabricated (the film the curves are for).
    pub film_thickness_um: f64,
    /// Mean index of the film as fabricated.
    pub mean_index: f64,
    /// True if any fabrication key differs from the design (`hoe.shrinkage`, …): the film
    /// then differs from the designed one, whose thickness and index follow.
    pub fabricated: bool,
    /// Film thickness as designed (µm).
    pub design_film_thickness_um: f64,
    /// Mean index as designed.
    pub design_mean_index: f64,
    /// RCWA harmonic half-width and slices per period (as requested).
    pub harmonics: usize,
    /// RCWA slices per z-period.
    pub slices_per_period: usize,
    /// Wavelengths.
    pub lambda_nm: Vec<f64>,
    /// Entrance and exit media indices per wavelength.
    pub n_in: Vec<f64>,
    /// Exit medium index per wavelength.
    pub n_out: Vec<f64>,
    /// Every order that propagates at some wavelength.
    pub orders: Vec<OrderCurve>,
    /// Σ η of all leaving orders per wavelength, TE.
    pub energy_te: Vec<f64>,
    /// Σ η of all leaving orders per wavelength, TM.
    pub energy_tm: Vec<f64>,
}

const POLARISATION: &str = "TE: incident E perpendicular to the plane of incidence (incident \
wave vector and film normal), TM: in it; at normal incidence TE is E along the grating lines; \
each efficiency sums both outgoing polarisations";

/// Parses `START:STOP:N`.
pub fn parse_lambdas(spec: &str) -> Result<Vec<f64>, Failure> {
    let err = |m: &str| bad_input(format!("--lambda-nm {spec}: {m}"));
    let parts: Vec<&str> = spec.split(':').map(str::trim).collect();
    let [a, b, n] = parts[..] else {
        return Err(err("expected START:STOP:N, e.g. 500:560:61"));
    };
    let (lo, hi) = (
        crate::scene::MIN_WAVELENGTH_NM,
        crate::scene::MAX_WAVELENGTH_NM,
    );
    let num = |s: &str| s.parse::<f64>().ok().filter(|v| (lo..=hi).contains(v));
    let (Some(a), Some(b)) = (num(a), num(b)) else {
        return Err(err(&format!(
            "START and STOP must be wavelengths in {lo}..={hi} nm (the scene keys' range)"
        )));
    };
    let n: usize = n
        .parse()
        .ok()
        .filter(|n| (1..=MAX_WAVELENGTHS).contains(n))
        .ok_or_else(|| err(&format!("N must be an integer in 1..={MAX_WAVELENGTHS}")))?;
    if n == 1 && a != b {
        return Err(err("N = 1 needs START = STOP"));
    }
    Ok((0..n)
        .map(|i| {
            if n == 1 {
                a
            } else {
                a + (b - a) * i as f64 / (n - 1) as f64
            }
        })
        .collect())
}

fn parse_field(spec: &str) -> Result<[f64; 2], Failure> {
    let parsed = spec.split_once(',').and_then(|(x, y)| {
        let x: f64 = x.trim().parse().ok()?;
        let y: f64 = y.trim().parse().ok()?;
        (x.abs() < 89.0 && y.abs() < 89.0).then_some([x, y])
    });
    parsed.ok_or_else(|| {
        bad_input(format!(
            "--field-deg {spec}: expected X,Y in degrees, each in (-89, 89)"
        ))
    })
}

fn parse_grating(spec: &str, mean_index: f64) -> Result<GratingSpec, Failure> {
    let v: Vec<Option<f64>> = spec
        .split(',')
        .map(|s| s.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect();
    match v[..] {
        [Some(l), Some(a), Some(n1)]
            if (crate::scene::MIN_WAVELENGTH_NM..=crate::scene::MAX_WAVELENGTH_NM).contains(&l)
                && a > 0.0
                && a < 90.0
                && (0.0..mean_index).contains(&n1) =>
        {
            Ok(GratingSpec {
                recording_wavelength_nm: l,
                reference_angle_deg: a,
                object_angle_deg: 0.0,
                index_modulation: n1,
                index_modulation_shortfall: 0.0,
                reference_angle_error_deg: 0.0,
            })
        }
        _ => Err(bad_input(format!(
            "--grating {spec}: expected NM,DEG,N1 with NM in {}..={} (the scene keys' range), DEG in (0, 90), N1 in [0, {mean_index})",
            crate::scene::MIN_WAVELENGTH_NM,
            crate::scene::MAX_WAVELENGTH_NM
        ))),
    }
}

/// Computes the report (no output).
pub fn compute(o: &GratingOptions) -> Result<GratingReport, Failure> {
    let lambdas = parse_lambdas(&o.lambda_nm)?;
    let field = parse_field(&o.field_deg)?;
    let (ls, _) = load(&o.scene)?;
    let s = &ls.scene;
    let gratings = if o.gratings.is_empty() {
        gs::scene_gratings(s)
    } else {
        o.gratings
            .iter()
            .map(|g| parse_grating(g, s.hoe.mean_index))
            .collect::<Result<_, _>>()?
    };
    if !(1..=rcwa::MAX_HARMONICS).contains(&o.harmonics) {
        return Err(bad_input(format!(
            "--harmonics {}: must be in 1..={}",
            o.harmonics,
            rcwa::MAX_HARMONICS
        )));
    }
    if !(1..=4096).contains(&o.slices_per_period) {
        return Err(bad_input(format!(
            "--slices-per-period {}: must be in 1..=4096",
            o.slices_per_period
        )));
    }
    let settings = Settings {
        harmonics: o.harmonics,
        slices_per_period: o.slices_per_period,
    };
    let u = gs::field_u(field);
    let pool = thread_pool(o.threads)?;
    let points = pool
        .install(|| gs::spectrum(s, &gratings, o.model, o.stack, &lambdas, u, &settings))
        .map_err(|e| bad_input(format!("grating: {e}")))?;

    let mut curves: BTreeMap<OrderKey, OrderCurve> = BTreeMap::new();
    for (i, p) in points.iter().enumerate() {
        for v in &p.orders {
            let c = curves.entry(v.key).or_insert_with(|| OrderCurve {
                side: if v.key.reflected {
                    "reflected"
                } else {
                    "transmitted"
                },
                grating: v.key.grating,
                order: v.key.order,
                direction: vec![None; lambdas.len()],
                eta_te: vec![0.0; lambdas.len()],
                eta_tm: vec![0.0; lambdas.len()],
            });
            c.direction[i] = v.direction.map(|d| d.to_array());
            c.eta_te[i] = v.eta[0];
            c.eta_tm[i] = v.eta[1];
        }
    }
    // Reflected orders first, then by grating and order.
    let mut orders: Vec<(OrderKey, OrderCurve)> = curves.into_iter().collect();
    orders.sort_by_key(|(k, _)| (!k.reflected, k.grating, k.order));
    let media: Vec<_> = lambdas
        .iter()
        .map(|&l| gs::stack_media(s, o.stack, l))
        .collect();
    let film_thickness_um = gs::film(s, &gratings).thickness_nm * 1e-3;
    let fabricated = fabricated(s, &gratings);
    Ok(GratingReport {
        model: o.model,
        stack: o.stack,
        polarisation: POLARISATION,
        field_deg: field,
        u: u.to_array(),
        gratings,
        film_thickness_um,
        mean_index: gs::fabricated_mean_index(s),
        fabricated,
        design_film_thickness_um: s.hoe.film_thickness_um,
        design_mean_index: s.hoe.mean_index,
        harmonics: o.harmonics,
        slices_per_period: o.slices_per_period,
        n_in: media.iter().map(|m| m.n_in).collect(),
        n_out: media.iter().map(|m| m.n_out).collect(),
        lambda_nm: lambdas,
        orders: orders.into_iter().map(|(_, c)| c).collect(),
        energy_te: points.iter().map(|p| p.total[0]).collect(),
        energy_tm: points.iter().map(|p| p.total[1]).collect(),
    })
}

/// η(λ) of every order and polarisation that reaches 1e−4 somewhere.
pub fn plot(r: &GratingReport) -> LinePlot {
    let mut series = Vec::new();
    for c in &r.orders {
        for (pol, eta) in [("TE", &c.eta_te), ("TM", &c.eta_tm)] {
            if eta.iter().all(|&e| e < 1e-4) {
                continue;
            }
            let g = c.grating.map_or(String::new(), |g| format!(" g{}", g + 1));
            series.push(Series {
                name: format!("{} {:+}{g} {pol}", &c.side[..1].to_uppercase(), c.order),
                points: r
                    .lambda_nm
                    .iter()
                    .copied()
                    .zip(eta.iter().copied())
                    .collect(),
            });
        }
    }
    LinePlot {
        title: format!(
            "{:?} {:?}, field ({}, {}) deg",
            r.model, r.stack, r.field_deg[0], r.field_deg[1]
        )
        .to_lowercase(),
        x_label: "wavelength (nm)".into(),
        y_label: "efficiency".into(),
        log_x: false,
        log_y: false,
        series,
        h_line: None,
    }
}

/// True if the fabricated film differs from the design (any fabrication key of the scene or
/// any grating's own error is non-zero).
fn fabricated(s: &crate::scene::Scene, gratings: &[GratingSpec]) -> bool {
    crate::optics::fabrication::is_fabricated(&s.hoe.fabrication(), gratings)
}

fn print_text(r: &GratingReport, con: &Console) {
    con.out(format_args!(
        "model {:?}, stack {:?}: film {} um, n = {}{}; field ({}, {}) deg, u = ({:.6}, {:.6})",
        r.model,
        r.stack,
        r.film_thickness_um,
        r.mean_index,
        if r.fabricated {
            format!(
                " as fabricated (designed {} um, n = {})",
                r.design_film_thickness_um, r.design_mean_index
            )
        } else {
            String::new()
        },
        r.field_deg[0],
        r.field_deg[1],
        r.u[0],
        r.u[1]
    ));
    for (i, g) in r.gratings.iter().enumerate() {
        con.out(format_args!(
            "grating {}: recorded at {} nm, reference {} deg, n1 = {}",
            i + 1,
            g.recording_wavelength_nm,
            g.reference_angle_deg,
            g.index_modulation
        ));
    }
    con.out(format_args!("{POLARISATION}"));
    for (i, l) in r.lambda_nm.iter().enumerate() {
        con.out(format_args!(
            "lambda {l:.3} nm (n_in {:.5}, n_out {:.5}): sum eta TE {:.6} TM {:.6}",
            r.n_in[i], r.n_out[i], r.energy_te[i], r.energy_tm[i]
        ));
        for c in &r.orders {
            let Some(d) = c.direction[i] else {
                if c.eta_te[i] > 0.0 || c.eta_tm[i] > 0.0 {
                    con.out(format_args!(
                        "  {:<11} {:+} trapped: TE {:.6} TM {:.6}",
                        c.side, c.order, c.eta_te[i], c.eta_tm[i]
                    ));
                }
                continue;
            };
            let g = c
                .grating
                .map_or(String::new(), |g| format!(" (grating {})", g + 1));
            con.out(format_args!(
                "  {:<11} {:+}{g} dir [{:+.6}, {:+.6}, {:+.6}]: TE {:.6} TM {:.6}",
                c.side, c.order, d[0], d[1], d[2], c.eta_te[i], c.eta_tm[i]
            ));
        }
    }
}

/// Runs the job: the report to `con` (text or JSON) and, with `--out`, the files.
pub fn run(o: &GratingOptions, con: &Console) -> Result<GratingReport, JobError> {
    if let Some(out) = &o.out {
        check_out_dir(out)?;
    }
    let r = compute(o)?;
    let json = to_json(&r)?;
    if o.json {
        con.out(format_args!("{json}"));
    } else {
        print_text(&r, con);
    }
    if let Some(out) = &o.out {
        let p = plot(&r);
        let png = p.to_png().map_err(write_failure)?;
        write_files(
            out,
            &[
                ("grating.json".into(), json.into_bytes()),
                ("grating.svg".into(), p.to_svg().into_bytes()),
                ("grating.png".into(), png),
            ],
        )?;
        con.err(format_args!(
            "wrote {}/grating.{{json,svg,png}}",
            out.display()
        ));
    }
    Ok(r)
}
