//! `stscam reconstruct`: CGM or ADMM-TV with one H, joint ADMM-TV or depth estimation with a depth stack.

use std::path::PathBuf;
use std::time::Instant;

use super::*;

/// `stscam reconstruct`'s arguments.
#[derive(Args, Debug)]
pub struct ReconstructOptions {
    /// System matrix (scipy CSR .npz); its offset.npy is used when present. A depth stack's
    /// H_stack.npz (its H_stack.json lists the depths) selects the stack methods.
    #[arg(long)]
    pub matrix: PathBuf,
    /// Capture: EXR (channels in H's row order) or float .npy.
    #[arg(long)]
    pub capture: PathBuf,
    /// Method (default: admm-tv with one H, joint with a depth stack).
    #[arg(long, value_enum)]
    pub method: Option<MethodArg>,
    /// How the regularisation is chosen: `discrepancy` (the default with one H: ADMM-TV's τ
    /// and CGM's stopping iteration from the sensor model's noise, as the demo) or `fixed`
    /// (`--tau`, `--iters`; the default with a depth stack).
    #[arg(long, value_enum)]
    pub regularisation: Option<Regularisation>,
    /// Iterations: ADMM-TV's per solve (default 50, the paper's count); CGM's cap with the
    /// discrepancy principle (default 100) or its count with `fixed` (default 30).
    #[arg(long)]
    pub iters: Option<usize>,
    /// ADMM-TV weight τ relative to ‖Hᵀg‖_∞ (scale-free) with `--regularisation fixed`
    /// (default 0.001).
    #[arg(long)]
    pub tau: Option<f64>,
    /// The discrepancy principle's sensor: a scene whose `[noise]` measured the capture
    /// (default: the scene recorded in the matrix's .json, else the default scene).
    #[arg(long, value_name = "SCENE")]
    pub sensor: Option<PathBuf>,
    /// The discrepancy principle's exposure: the brightest value of the all-white capture
    /// (default: the capture's sidecar `noise.white_peak`, as `render --noise sensor` writes
    /// it, else max(H·1 + offset)).
    #[arg(long, value_name = "X")]
    pub white_peak: Option<f64>,
    /// A measured dark frame (capture units with the sensor's dark offset, as `demo` writes
    /// `dark.npy`) subtracted from the capture instead of the offset; its noise counts in the
    /// discrepancy principle.
    #[arg(long, value_name = "FILE")]
    pub dark_frame: Option<PathBuf>,
    /// Joint: weight μ of the group sparsity across depth, relative to ‖Hᵀg‖_∞.
    #[arg(long, default_value_t = crate::recon::joint::DEFAULT_MU_REL)]
    pub mu: f64,
    /// Total variation.
    #[arg(long, value_enum, default_value = "iso")]
    pub tv: crate::recon::admm::TvKind,
    /// Object shape WxH (default: from H.json, else square).
    #[arg(long, value_name = "WxH")]
    pub object: Option<String>,
    /// Offset to subtract from the capture (default: offset.npy beside the matrix, if any).
    #[arg(long)]
    pub offset: Option<PathBuf>,
    /// Ground truth for PSNR/SSIM: a PNG (display code values), an EXR (linear) or a
    /// built-in target spec.
    #[arg(long)]
    pub truth: Option<String>,
    /// Display gamma used to linearise a PNG or built-in truth.
    #[arg(long, default_value_t = 2.2)]
    pub gamma: f64,
    /// Output directory.
    #[arg(long, default_value = "out/reconstruct")]
    pub out: PathBuf,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// How `reconstruct` chooses its regularisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Regularisation {
    /// From the sensor model's noise (Morozov's discrepancy principle).
    Discrepancy,
    /// `--tau` and `--iters` as given.
    Fixed,
}

/// Method of `reconstruct --method`: a solver of one H ([`crate::recon::Method`]) or of a depth
/// stack ([`crate::recon::layered::StackMethod`]). The names and help lines are those enums'
/// (one definition for clap and the Python module); this type only joins the two lists.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MethodArg {
    /// A method of one H.
    One(crate::recon::Method),
    /// A method of a depth stack.
    Stack(crate::recon::layered::StackMethod),
}

impl MethodArg {
    /// The name on the command line (`cg`, `admm-tv`, `joint`, `depth`).
    fn name(self) -> String {
        self.to_possible_value()
            .map(|p| p.get_name().to_string())
            .unwrap_or_default()
    }
}

impl ValueEnum for MethodArg {
    fn value_variants<'a>() -> &'a [Self] {
        use crate::recon::{Method, layered::StackMethod};
        &[
            Self::One(Method::Cg),
            Self::One(Method::AdmmTv),
            Self::Stack(StackMethod::Joint),
            Self::Stack(StackMethod::Depth),
        ]
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        match self {
            Self::One(m) => m.to_possible_value(),
            Self::Stack(m) => m.to_possible_value(),
        }
    }
}

/// `stscam reconstruct`: options checked, the method chosen for the matrix (one H or a depth
/// stack), then one H's reconstruction with its metrics and files.
fn cmd_reconstruct(a: &ReconstructOptions, con: &Console) -> Result<(), Failure> {
    use crate::recon::{Problem, Solution, SolveOptions};
    let ReconstructOptions {
        matrix,
        capture,
        method,
        regularisation,
        iters,
        tau,
        sensor,
        white_peak,
        dark_frame,
        mu,
        tv,
        object,
        offset,
        truth,
        gamma,
        out,
        threads,
    } = a;
    let (matrix, capture, out) = (matrix.as_path(), capture.as_path(), out.as_path());
    let (iters, gamma) = (*iters, *gamma);
    let tau = tau.unwrap_or(crate::recon::admm::DEFAULT_TAU_REL);
    let (object, offset, truth) = (object.as_deref(), offset.as_deref(), truth.as_deref());
    check_numbers(a)?;
    let method = resolve_method(*method, matrix)?;
    let tv = *tv;
    let method = match method {
        MethodArg::Stack(method) => {
            check_stack_rule(a)?;
            let opts = crate::recon::layered::StackOptions {
                method,
                iters,
                tau_rel: tau,
                mu_rel: *mu,
                tv,
                cancel: stscam_base::cancel::current(),
                ..Default::default()
            };
            return reconstruct_stack(
                matrix, capture, offset, truth, gamma, out, *threads, &opts, con,
            );
        }
        MethodArg::One(method) => method,
    };
    let rule = regularisation.unwrap_or(Regularisation::Discrepancy);
    check_rule(a, rule)?;
    check_out_dir(out)?;
    let object = object.map(parse_object).transpose()?;
    let pool = thread_pool(*threads)?;
    let (lm, raw) = load_problem(matrix, capture, object, offset)?;
    // The matrix's offset (0 without one); the capture less it, or less a measured dark frame.
    let zero_offset;
    let offset: &[f32] = match &lm.offset {
        Some(o) => o,
        None => {
            zero_offset = vec![0.0f32; raw.len()];
            &zero_offset
        }
    };
    let dark = dark_frame
        .as_deref()
        .map(|d| load_dark(d, raw.len()))
        .transpose()?;
    let g: Vec<f64> = match &dark {
        Some(d) => raw.iter().zip(d).map(|(x, d)| x - d).collect(),
        None => raw
            .iter()
            .zip(offset)
            .map(|(x, &o)| x - f64::from(o))
            .collect(),
    };
    // Warnings are printed once the reconstruction is written (a refusal stays one line).
    let mut warnings = Vec::new();
    let (sensor_model, fallback) = match rule {
        Regularisation::Discrepancy => {
            match sensor_of(
                (matrix, capture),
                sensor.as_deref(),
                *white_peak,
                (&lm.h, offset),
                &mut warnings,
            )? {
                Ok(m) => (Some(m), None),
                Err(reason) => {
                    warnings.push(format!("warning: {reason}"));
                    (None, Some(reason))
                }
            }
        }
        Regularisation::Fixed => (None, None),
    };
    let (w, h) = lm.object;
    let planes = lm.planes;
    let truth_v = truth
        .map(|t| load_truth(t, gamma, w, h, planes))
        .transpose()?;
    crate::limits::check_bytes(
        "--matrix",
        "the reconstruction set-up (H transposed and the Gram matrix HᵀH)",
        crate::recon::setup_bytes_bound(&lm.h, pool.current_num_threads()),
    )
    .map_err(|e| bad_input(format!("{}: {e}", matrix.display())))?;
    let t0 = Instant::now();
    let problem =
        pool.install(|| Problem::with_cancel(&lm.h, w, planes * h, stscam_base::cancel::current()));
    let setup_s = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let opts = SolveOptions {
        method,
        iters,
        tau_rel: tau,
        tv,
    };
    let Solution { f, info } = pool.install(|| match &sensor_model {
        None => crate::recon::solve_planes(&problem, planes, &g, &opts),
        Some(sm) => {
            // The black level each value sits at: a measured dark frame less the sensor's dark
            // offset, else the matrix's offset.
            let black = dark
                .as_ref()
                .map(|d| crate::capture::black_level_of(d, &sm.noise));
            let sensor = crate::recon::discrepancy::Sensor {
                noise: &sm.noise,
                offset: black.as_deref().unwrap_or(offset),
                dark_subtracted: dark.is_some(),
            };
            crate::recon::discrepancy::solve_discrepancy(&problem, planes, &g, &opts, &sensor)
        }
    });
    let solve_s = t0.elapsed().as_secs_f64();
    // Computed in f64; stored as float32, which must hold every value.
    check_f32_range(&f, capture, matrix)?;
    let metrics = truth_v
        .as_ref()
        .map(|t| recon_metrics(&f, t, w, h, planes, gamma));
    let json = serde_json::json!({
        "stscam_version": crate::VERSION,
        "command": "reconstruct",
        "matrix": matrix.display().to_string(),
        "capture": capture.display().to_string(),
        "offset": lm.offset_path.as_ref().map(|p| p.display().to_string()),
        "object_px": [w, h],
        "object_planes": planes,
        "solver": info,
        "regularisation": match &sensor_model {
            None => serde_json::json!({"rule": "fixed", "tau_rel": tau, "iters": iters, "instead_of_discrepancy": fallback}),
            Some(sm) => sm.json(dark_frame.as_deref()),
        },
        "gram_layout": problem.gram_layout(),
        "setup_time_s": setup_s,
        "frame_time_s": solve_s,
        "metrics": metrics,
        "units": "linear object intensity (0 = black, 1 = white display pixel)",
        "png_scale": preview_scale(w, h),
        "files": {"recon.exr": "the object, linear float32, one pixel per object pixel", "recon.png": "preview in display code values, each object pixel a png_scale x png_scale block (nearest neighbour)"},
    });
    write_recon(out, &f, (w, h, planes), gamma, &json)?;
    for w in &warnings {
        con.err(format_args!("{w}"));
    }
    let m = metrics
        .map(|m| {
            format!(
                ", PSNR {:.2} dB, SSIM {:.3}",
                m["psnr_db"].as_f64().unwrap_or(f64::NAN),
                m["ssim"].as_f64().unwrap_or(f64::NAN)
            )
        })
        .unwrap_or_default();
    con.err(format_args!(
        "wrote {}/recon.{{exr,png,json}}: {}x{}, set-up {:.3} s, frame {:.2} ms{m}",
        out.display(),
        w,
        h,
        setup_s,
        solve_s * 1e3
    ));
    Ok(())
}

/// The discrepancy principle's sensor model with where each part came from.
struct SensorModel {
    /// The model with its exposure.
    noise: crate::noise::SensorNoise,
    /// The `[noise]` it was made from.
    desc: crate::scene::NoiseDesc,
    /// Where `desc` came from.
    desc_source: String,
    /// The exposure's white peak and where it came from.
    white_peak: (f64, String),
}

impl SensorModel {
    /// recon.json's `regularisation` entry.
    fn json(&self, dark_frame: Option<&std::path::Path>) -> serde_json::Value {
        serde_json::json!({
            "rule": "discrepancy",
            "sensor": self.desc,
            "sensor_source": self.desc_source,
            "white_peak": self.white_peak.0,
            "white_peak_source": self.white_peak.1,
            "black_level": match dark_frame {
                Some(d) => format!("the measured dark frame {} less the sensor's dark offset (its noise counted)", d.display()),
                None => "the matrix's offset (the capture taken as measured with the mean dark offset removed, as datasets and render --noise sensor store it)".into(),
            },
        })
    }
}

/// The sensor model of the discrepancy principle: `[noise]` from `--sensor`, else the scene
/// recorded in the matrix's sidecar, else the default scene; the exposure from
/// `--white-peak`, else the capture's sidecar, else max(H·1 + offset). `Ok(Err(reason))`
/// where that last default cannot set an exposure (the caller keeps fixed parameters).
fn sensor_of(
    (matrix, capture): (&std::path::Path, &std::path::Path),
    sensor: Option<&std::path::Path>,
    white_peak: Option<f64>,
    (h, offset): (&crate::sparse::CsrMatrix, &[f32]),
    warnings: &mut Vec<String>,
) -> Result<Result<SensorModel, String>, Failure> {
    let sidecar = |p: &std::path::Path| -> Option<serde_json::Value> {
        let j = p.with_extension("json");
        let text = crate::io::input::read_text(&j).ok()?;
        serde_json::from_str(&text).ok()
    };
    let (desc, desc_source) = match sensor {
        Some(p) => {
            let ls = load_scene(Some(p), &[]).map_err(|e| bad_input(format!("--sensor: {e}")))?;
            (ls.scene.noise, format!("--sensor {}", p.display()))
        }
        None => match sidecar(matrix).and_then(|j| j.get("scene")?.get("noise").cloned()) {
            Some(v) => {
                let hj = matrix.with_extension("json");
                let desc: crate::scene::NoiseDesc = serde_json::from_value(v)
                    .map_err(|e| bad_input(format!("{}: scene.noise: {e}", hj.display())))?;
                let mut ls = load_scene(None, &[]).map_err(|e| bad_input(e.to_string()))?;
                ls.scene.noise = desc;
                crate::scene::validate(&ls)
                    .map_err(|e| bad_input(format!("{}: scene.{e}", hj.display())))?;
                (ls.scene.noise, format!("{} (scene.noise)", hj.display()))
            }
            None => {
                let ls = load_scene(None, &[]).map_err(|e| bad_input(e.to_string()))?;
                (ls.scene.noise, "the default scene's [noise]".to_string())
            }
        },
    };
    let cap_json = sidecar(capture);
    if let Some(j) = &cap_json
        && j.get("noise").and_then(|n| n.as_str()) == Some("none")
    {
        warnings.push(format!(
            "warning: {}: the capture carries no sensor noise (its sidecar says \"noise\": \"none\"); the discrepancy principle assumes the sensor measured it and will over-smooth: render with --noise sensor, or pass --regularisation fixed",
            capture.display()
        ));
    }
    let from_sidecar = cap_json
        .as_ref()
        .and_then(|j| j.get("noise")?.get("white_peak")?.as_f64());
    // (value, where it came from, whether it is the matrix's own all-white capture)
    let (peak, source, from_matrix) = match (white_peak, from_sidecar) {
        (Some(w), _) => (w, "--white-peak".to_string(), false),
        (None, Some(w)) => (
            w,
            format!(
                "{} (noise.white_peak)",
                capture.with_extension("json").display()
            ),
            false,
        ),
        (None, None) => (
            crate::recon::discrepancy::white_peak(h, offset),
            "max(H·1 + offset), the all-white capture".to_string(),
            true,
        ),
    };
    let noise = match crate::noise::SensorNoise::checked(&desc, peak) {
        Ok(n) => n,
        // A matrix that cannot set a sensor's exposure (no light, or a scale float32
        // captures cannot hold) keeps the fixed parameters; a given exposure is refused.
        Err(e) if from_matrix => {
            return Ok(Err(format!(
                "{}: the all-white capture max(H·1 + offset) cannot set the sensor's exposure ({e}); fixed tau and iterations used (pass --white-peak, or --regularisation fixed)",
                matrix.display()
            )));
        }
        Err(e) => return Err(bad_input(format!("--white-peak ({source}): {e}"))),
    };
    Ok(Ok(SensorModel {
        noise,
        desc,
        desc_source,
        white_peak: (peak, source),
    }))
}

/// `--dark-frame`: the measured dark frame, `rows` values like the capture.
fn load_dark(path: &std::path::Path, rows: usize) -> Result<Vec<f64>, Failure> {
    let dark = load_capture(path)?;
    if dark.len() != rows {
        return Err(bad_input(format!(
            "{}: --dark-frame has {} values but the capture has {rows}; they must match",
            path.display(),
            dark.len(),
        )));
    }
    Ok(dark)
}

/// The options that belong to one regularisation rule, checked against `rule`.
fn check_rule(a: &ReconstructOptions, rule: Regularisation) -> Result<(), Failure> {
    if a.dark_frame.is_some() && a.offset.is_some() {
        return Err(bad_input(
            "--dark-frame: is subtracted instead of the offset; give --dark-frame or --offset, not both",
        ));
    }
    match rule {
        Regularisation::Discrepancy if a.tau.is_some() => Err(bad_input(
            "--tau: sets tau of --regularisation fixed; the default, the discrepancy principle, chooses tau from the sensor noise",
        )),
        Regularisation::Fixed => {
            for (flag, given) in [
                ("--sensor", a.sensor.is_some()),
                ("--white-peak", a.white_peak.is_some()),
            ] {
                if given {
                    return Err(bad_input(format!(
                        "{flag}: sets the discrepancy principle's sensor model; --regularisation fixed does not use it"
                    )));
                }
            }
            Ok(())
        }
        Regularisation::Discrepancy => Ok(()),
    }
}

/// A depth stack's methods take fixed parameters (the discrepancy principle is for one H).
fn check_stack_rule(a: &ReconstructOptions) -> Result<(), Failure> {
    if a.regularisation == Some(Regularisation::Discrepancy) {
        return Err(bad_input(
            "--regularisation discrepancy: is for one H; a depth stack's joint and depth methods take --tau and --mu (--regularisation fixed)",
        ));
    }
    for (flag, given) in [
        ("--sensor", a.sensor.is_some()),
        ("--white-peak", a.white_peak.is_some()),
        ("--dark-frame", a.dark_frame.is_some()),
    ] {
        if given {
            return Err(bad_input(format!(
                "{flag}: is for the discrepancy principle with one H, not a depth stack"
            )));
        }
    }
    Ok(())
}

/// Checks `--tau`, `--mu`, `--gamma` and `--iters`.
fn check_numbers(a: &ReconstructOptions) -> Result<(), Failure> {
    let (tau, mu, gamma, iters) = (
        a.tau.unwrap_or(crate::recon::admm::DEFAULT_TAU_REL),
        &a.mu,
        a.gamma,
        a.iters,
    );
    if !(tau.is_finite() && tau >= 0.0) {
        return Err(bad_input(format!(
            "--tau {tau}: must be a non-negative number"
        )));
    }
    if !(mu.is_finite() && *mu >= 0.0) {
        return Err(bad_input(format!(
            "--mu {mu}: must be a non-negative number"
        )));
    }
    if !(gamma.is_finite() && gamma > 0.0) {
        return Err(bad_input(format!("--gamma {gamma}: must be positive")));
    }
    if let Some(n) = iters
        && !(1..=MAX_ITERS).contains(&n)
    {
        return Err(bad_input(format!(
            "--iters: must be in 1..={MAX_ITERS}, got {n}"
        )));
    }
    Ok(())
}

/// The method of `--method` (default: ADMM-TV with one H, joint with a depth stack), checked
/// against the kind of `matrix`.
fn resolve_method(
    method: Option<MethodArg>,
    matrix: &std::path::Path,
) -> Result<MethodArg, Failure> {
    use crate::recon::Method;
    let stack = crate::stack::is_stack(matrix);
    Ok(match (method, stack) {
        (None, false) => MethodArg::One(Method::AdmmTv),
        (None, true) => MethodArg::Stack(crate::recon::layered::StackMethod::Joint),
        (Some(m @ MethodArg::Stack(_)), false) => {
            return Err(bad_input(format!(
                "{}: --method {}: needs a depth stack (H_stack.npz from matrix --depth-mm D1,D2,...)",
                matrix.display(),
                m.name()
            )));
        }
        (Some(m @ MethodArg::One(_)), true) => {
            return Err(bad_input(format!(
                "{}: --method {}: a depth stack takes --method joint or depth (or pass one depth's H_<D>mm.npz)",
                matrix.display(),
                m.name()
            )));
        }
        (Some(m), _) => m,
    })
}

/// The matrix (with its offset) and the capture, their sizes checked.
fn load_problem(
    matrix: &std::path::Path,
    capture: &std::path::Path,
    object: Option<(usize, usize)>,
    offset: Option<&std::path::Path>,
) -> Result<(stscam_tracer::matrix::LoadedMatrix, Vec<f64>), Failure> {
    let lm = stscam_tracer::matrix::load_matrix(matrix, object, offset)
        .map_err(|e| bad_input(e.to_string()))?;
    let g = load_capture(capture)?;
    if g.len() != lm.h.rows {
        return Err(bad_input(format!(
            "{}: the capture has {} values but {} has {} rows (crop pixels x channels); they must match",
            capture.display(),
            g.len(),
            matrix.display(),
            lm.h.rows
        )));
    }
    Ok((lm, g))
}

/// PSNR and SSIM of the reconstruction `f` against the truth `t` (linear, `w`×`h`×`planes`),
/// and for colour the CIEDE2000 errors and energy shares.
fn recon_metrics(
    f: &[f64],
    t: &[f64],
    w: usize,
    h: usize,
    planes: usize,
    gamma: f64,
) -> serde_json::Value {
    let mut m = serde_json::json!({
        "psnr_db": crate::recon::metrics::psnr(f, t),
        "ssim": crate::recon::metrics::ssim(f, t, w, planes * h),
        "normalisation": "linear object intensity in [0,1] (display gamma removed), reconstruction clipped to [0,1], not rescaled; PSNR peak 1; SSIM Wang et al. 2004, Gaussian sigma 1.5",
    });
    if planes == 3 {
        let xyz = colour_matrix(gamma);
        let e = crate::recon::colour::colour_errors(f, t, &xyz);
        m["ssim_note"] = "SSIM of the three planes stacked vertically".into();
        m["ciede2000_mean"] = e.ciede2000_mean.into();
        m["ciede2000_p95"] = e.ciede2000_p95.into();
        m["energy_share_rgb"] = serde_json::json!(e.energy_share);
        m["colour_space"] = crate::recon::colour::LAB_NOTE.into();
    }
    m
}

/// Writes recon.exr, recon.png (grey or colour by `planes`) and recon.json into `out`.
fn write_recon(
    out: &std::path::Path,
    f: &[f64],
    (w, h, planes): (usize, usize, usize),
    gamma: f64,
    json: &serde_json::Value,
) -> Result<(), Failure> {
    // The PNG is a preview: each object pixel a k × k block, so a 64-pixel object is 512
    // pixels wide (`png_scale` in recon.json); the EXR holds the object itself.
    let k = preview_scale(w, h);
    let (wu, hu) = (w * k, h * k);
    // Box resampling by an integer factor repeats each pixel (nearest neighbour).
    let fu: Vec<f64> = f
        .chunks(w * h)
        .flat_map(|plane| stscam_studies::demo::resample(plane, w, h, wu, hu))
        .collect();
    let (exr, png) = if planes == 3 {
        (
            crate::output::encode_colour_object_exr(f, w, h).map_err(write_failure)?,
            crate::output::encode_colour_object_png(&fu, wu, hu, gamma).map_err(write_failure)?,
        )
    } else {
        (
            crate::output::encode_object_exr(f, w, h, &[]).map_err(write_failure)?,
            crate::output::encode_object_png(&fu, wu, hu, gamma).map_err(write_failure)?,
        )
    };
    let jb = serde_json::to_vec_pretty(json).map_err(write_failure)?;
    crate::io::write_all_atomic(
        out,
        &[
            ("recon.exr", &exr),
            ("recon.png", &png),
            ("recon.json", &jb),
        ],
    )
    .map_err(write_failure)
}

/// The preview PNG's integer scale: the smallest k ≥ 1 with k·max(w, h) ≥ 512 (1 from 512
/// pixels on).
fn preview_scale(w: usize, h: usize) -> usize {
    const PREVIEW_PX: usize = 512;
    PREVIEW_PX.div_ceil(w.max(h).max(1)).max(1)
}

/// The XYZ matrix of the colour display a colour H was made for: the default scene's LCD
/// primaries (white-LED backlight; `display.primaries = "lcd"`). `gamma` is unused: the
/// conversion is from linear intensities.
fn colour_matrix(_gamma: f64) -> [[f64; 3]; 3] {
    use crate::spectra::{DisplaySpectrumKind, display_primaries, display_spectrum};
    let (p, _) = display_primaries(&display_spectrum(DisplaySpectrumKind::WhiteLed));
    crate::recon::colour::primaries_to_xyz(&p)
}

/// Refuses a reconstruction f64 → float32 would not hold (H and the capture on incompatible
/// scales).
fn check_f32_range(
    f: &[f64],
    capture: &std::path::Path,
    matrix: &std::path::Path,
) -> Result<(), Failure> {
    if let Some(i) = f.iter().position(|v| !(v.abs() <= f64::from(f32::MAX))) {
        return Err(bad_input(format!(
            "{}: the reconstruction reaches {} at object pixel {i}, outside float32's range (±3.40282e38): H ({}) and the capture are on incompatible scales",
            capture.display(),
            crate::numfmt::sig6(f[i]),
            matrix.display()
        )));
    }
    Ok(())
}

/// `reconstruct` with a depth stack: recon_<D>mm.{exr,png} per reconstructed plane and
/// recon.json (with the depth method also recon.{exr,png}, the plane at the estimated depth).
#[allow(clippy::too_many_arguments)]
fn reconstruct_stack(
    matrix: &std::path::Path,
    capture: &std::path::Path,
    offset: Option<&std::path::Path>,
    truth: Option<&str>,
    gamma: f64,
    out: &std::path::Path,
    threads: Option<usize>,
    opts: &crate::recon::layered::StackOptions,
    con: &Console,
) -> Result<(), Failure> {
    use crate::recon::layered::{StackMethod, solve_stack, stack_setup_bytes};
    if truth.is_some() && opts.method == StackMethod::Joint {
        return Err(bad_input(
            "--truth: compares one plane; with --method joint compare each recon_<D>mm.exr yourself (or use --method depth)",
        ));
    }
    if offset.is_some() && opts.method == StackMethod::Depth {
        return Err(bad_input(
            "--offset: the depth method subtracts each depth's own offset_<D>mm.npy; --offset applies to --method joint",
        ));
    }
    check_out_dir(out)?;
    let pool = thread_pool(threads)?;
    let ls = crate::stack::load_stack(matrix, offset).map_err(|e| bad_input(e.to_string()))?;
    let g = load_capture(capture)?;
    let rows = ls.blocks[0].rows;
    if g.len() != rows {
        return Err(bad_input(format!(
            "{}: the capture has {} values but {} has {} rows (crop pixels x channels); they must match",
            capture.display(),
            g.len(),
            matrix.display(),
            rows
        )));
    }
    let (w, h) = ls.object;
    let truth_v = truth.map(|t| load_truth(t, gamma, w, h, 1)).transpose()?;
    crate::limits::check_bytes(
        "--matrix",
        "the reconstruction set-up (H transposed and the Gram matrix HᵀH)",
        stack_setup_bytes(&ls, opts.method, pool.current_num_threads()),
    )
    .map_err(|e| bad_input(format!("{}: {e}", matrix.display())))?;
    let t0 = Instant::now();
    let sol = pool
        .install(|| solve_stack(&ls, &g, opts))
        .map_err(|e| bad_input(format!("{}: {e}", matrix.display())))?;
    let time_s = t0.elapsed().as_secs_f64();
    let mut files: Vec<(String, Vec<u8>)> = Vec::new();
    let mut planes = Vec::new();
    for (d, f) in &sol.planes {
        check_f32_range(f, capture, matrix)?;
        let label = crate::stack::depth_label(*d);
        let exr = crate::output::encode_object_exr(f, w, h, &[]).map_err(write_failure)?;
        let png = crate::output::encode_object_png(f, w, h, gamma).map_err(write_failure)?;
        files.push((format!("recon_{label}mm.exr"), exr));
        files.push((format!("recon_{label}mm.png"), png));
        planes.push(serde_json::json!({"depth_mm": d, "exr": format!("recon_{label}mm.exr"), "png": format!("recon_{label}mm.png")}));
    }
    let metrics = truth_v.as_ref().map(|t| {
        let f = &sol.planes[0].1;
        serde_json::json!({
            "psnr_db": crate::recon::metrics::psnr(f, t),
            "ssim": crate::recon::metrics::ssim(f, t, w, h),
            "normalisation": "linear object intensity in [0,1], reconstruction at the estimated depth clipped to [0,1]; PSNR peak 1",
        })
    });
    if let Some(est) = &sol.estimate {
        let f = &sol.planes[0].1;
        files.push((
            "recon.exr".into(),
            crate::output::encode_object_exr(f, w, h, &[]).map_err(write_failure)?,
        ));
        files.push((
            "recon.png".into(),
            crate::output::encode_object_png(f, w, h, gamma).map_err(write_failure)?,
        ));
        con.err(format_args!(
            "estimated depth {} mm (refined {:.1} mm, confidence {:.3}) over {} depths",
            crate::numfmt::sig6(est.depth_mm),
            est.refined_depth_mm,
            est.confidence,
            est.depths_mm.len()
        ));
    }
    let json = serde_json::json!({
        "stscam_version": crate::VERSION,
        "command": "reconstruct",
        "matrix": matrix.display().to_string(),
        "capture": capture.display().to_string(),
        "object_px": [w, h],
        "depths_mm": ls.depths_mm,
        "solver": sol.info,
        "planes": planes,
        "time_s": time_s,
        "metrics": metrics,
        "units": "linear object intensity (0 = black, 1 = white display pixel)",
    });
    files.push((
        "recon.json".into(),
        serde_json::to_vec_pretty(&json).map_err(write_failure)?,
    ));
    write_files(out, &files)?;
    con.err(format_args!(
        "wrote {}: {} plane(s) of {}x{}, {:.2} s",
        out.display(),
        sol.planes.len(),
        w,
        h,
        time_s
    ));
    Ok(())
}

/// Runs the job: its files written (under temporary names, renamed when complete), its
/// report sent to `con`.
pub fn run(o: &ReconstructOptions, con: &Console) -> Result<(), JobError> {
    cmd_reconstruct(o, con)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::{Method, layered::StackMethod};

    #[test]
    fn methods_are_the_solvers_names_in_the_cli_order() {
        let names: Vec<String> = MethodArg::value_variants()
            .iter()
            .map(|m| m.name())
            .collect();
        assert_eq!(names, ["cg", "admm-tv", "joint", "depth"]);
        assert_eq!(
            MethodArg::from_str("admm-tv", false),
            Ok(MethodArg::One(Method::AdmmTv))
        );
        assert_eq!(
            MethodArg::from_str("depth", false),
            Ok(MethodArg::Stack(StackMethod::Depth))
        );
        // Python's messages (one H, then a stack) come from the same enums.
        assert_eq!(
            crate::options::parse::<Method>("method", "joint"),
            Err(r#"method "joint": expected "cg" or "admm-tv""#.into())
        );
        assert_eq!(
            crate::options::parse::<StackMethod>("method", "cg"),
            Err(r#"method "cg": expected "joint" or "depth""#.into())
        );
    }
}
