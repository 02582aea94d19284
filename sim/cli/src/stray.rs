//! `stscam stray`: the stray-light report. Every camera sample of `render` traced through every
//! path (`stscam_stray`), the image split by path class: `stray.json`, `stray.md`, a ranked bar
//! chart, an image (EXR and PNG) of the signal and each leading class, and of every path
//! together (`all_paths`: what the camera records).

use std::path::PathBuf;
use std::time::Instant;

use stscam_stray::classes::SIGNAL;
use stscam_stray::image::{self as si, ClassImage, StrayImages, StraySettings};
use stscam_stray::paths::{DEFAULT_MAX_EVENTS, DEFAULT_ROULETTE_THRESHOLD, PathSettings, Sink};

use crate::plot::{Bar, BarChart};

use super::*;

/// Most events per path of `--max-events`.
pub const MAX_EVENTS: usize = 100_000;

/// `stscam stray`'s arguments.
#[derive(Args, Debug, Clone)]
pub struct StrayOptions {
    /// The scene and its overrides.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Samples, seed and threads (the samples are `render`'s for the same seed).
    #[command(flatten)]
    pub run: RunArgs,
    /// Branches below this weight (a fraction of the camera ray's) play Russian roulette:
    /// they survive with probability weight/threshold and carry weight/probability (unbiased).
    #[arg(long = "roulette", default_value_t = DEFAULT_ROULETTE_THRESHOLD)]
    pub roulette: f64,
    /// At most this many events (reflections, transmissions, diffractions) per path.
    #[arg(long = "max-events", default_value_t = DEFAULT_MAX_EVENTS)]
    pub max_events: usize,
    /// Output directory: stray.json, stray.md, stray.png and class_NN_*.{exr,png}.
    #[arg(long, default_value = "out/stray")]
    pub out: PathBuf,
}

/// Runs `stscam stray`: the report's figures.
pub fn run(o: &StrayOptions, con: &Console) -> Result<StrayImages, JobError> {
    let (spp, seed, threads) = o.run.checked()?;
    if !(o.roulette.is_finite() && (0.0..=1.0).contains(&o.roulette)) {
        return Err(bad_input(format!(
            "--roulette {}: must be a weight in [0, 1] (0: no roulette)",
            o.roulette
        )));
    }
    if !(1..=MAX_EVENTS).contains(&o.max_events) {
        return Err(bad_input(format!(
            "--max-events {}: must be in 1..={MAX_EVENTS}",
            o.max_events
        )));
    }
    check_out_dir(&o.out)?;
    let start = Instant::now();
    let pool = thread_pool(threads)?;
    let (ls, sys) = pool.install(|| load(&o.scene))?;
    if sys.world.is_some() {
        return Err(bad_input(format!(
            "{}: stray traces display scenes only ([[object]] and [[light]] entries make a 3-D user side, which it does not follow yet)",
            ls.source
        )));
    }
    if sys.waveguide.rcwa.is_some() {
        con.err(format_args!(
            "stscam stray: hoe.model = rcwa: every order is taken from Kogelnik's model here (the RCWA tables hold the designed orders only), so the signal class differs from render by the two models' difference"
        ));
    }
    let render_set = stscam_tracer::render::RenderSettings::lattice(spp, seed, false);
    stscam_tracer::render::check_limits(&sys, &render_set, 1, "--spp").map_err(limit)?;
    crate::limits::check_bytes(
        "sensor.crop_px",
        "the stray-light classes' images",
        si::bytes_bound(&sys),
    )
    .map_err(limit)?;
    let set = StraySettings {
        spp,
        seed,
        paths: PathSettings {
            roulette_threshold: o.roulette,
            cutoff_weight: 0.0,
            max_events: o.max_events,
        },
        progress: true,
    };
    let t0 = Instant::now();
    let st = pool.install(|| si::stray_images(&sys, &set));
    let trace_s = t0.elapsed().as_secs_f64();
    if stscam_base::cancel::current().is_cancelled() {
        return Err(Failure {
            code: 1,
            message: "stray: cancelled; nothing written".into(),
        });
    }
    let scene_json = to_json(&sys.scene)?;
    let report = Report::new(&st);
    let json = serde_json::json!({
        "stscam_version": crate::VERSION,
        "command": "stray",
        "scene_source": ls.source,
        "overrides": o.scene.set,
        "scene": sys.scene,
        "seed": seed,
        "spp": spp,
        "threads": pool.current_num_threads(),
        "roulette_threshold": o.roulette,
        "max_events": o.max_events,
        "film_model": "kogelnik (orders -1 and +1 of every grating at both vHOEs)",
        "crop_px": [st.width, st.height],
        "channels": st.channel_names,
        "model": "every path of the camera's importance through the plate: both Fresnel branches at every face, orders -1 and +1 of every grating of the film at both vHOEs (cross-coupling included), repeated passes through a film, the cover, absorbing plate edges; the display in front of the screen is the only source (no source on the camera side)",
        "units": "fraction_of_signal: the class's sum over the crop's pixels and channels over the signal's; peak_ratio: its brightest pixel over the signal's; row_fraction: per image row (row 0 at the top), the class's row sum over the signal's row sum, 6 significant digits (null where the signal's row is 0)",
        "signal": {"name": SIGNAL, "definition": "the designed paths, which H models: straight through the plate, and T(back) D(top,gj,-1) [TIR×n | R]... D(bottom,gj,+1) T(front) with the same grating j at both vHOEs", "total": report.signal_total, "peak": report.signal_peak},
        "stray_fraction_of_signal": report.stray_total / report.signal_total,
        "signal_to_stray": report.signal_total / report.stray_total,
        "classes": report.classes_json(&st),
        "distinct_classes": st.distinct_classes,
        "max_classes": si::MAX_CLASSES,
        "camera_rays": st.rays,
        "branches": st.branches,
        "branches_per_ray": st.branches as f64 / st.rays.max(1) as f64,
        "importance_per_ray": {
            "display": st.exit_weight / st.rays.max(1) as f64,
            "sinks": Sink::ALL.iter().zip(st.sinks).map(|(s, v)| (s.name().to_string(), serde_json::json!(v / st.rays.max(1) as f64))).collect::<serde_json::Map<_, _>>(),
            "note": "where the camera's importance went, averaged over the display's polarisation: to the display in front of the screen, or a sink (the camera side holds no source; roulette is the weight of branches that lost it, returned on average by the survivors)",
        },
        "trace_time_s": trace_s,
        "wall_time_s": start.elapsed().as_secs_f64(),
    });
    let mut files: Vec<(String, Vec<u8>)> = Vec::new();
    for (i, c) in st.classes.iter().enumerate() {
        let Some(img) = &c.image else { continue };
        let stem = image_stem(i, &c.name);
        let cap = stscam_tracer::render::Capture {
            width: st.width,
            height: st.height,
            channel_names: st.channel_names.clone(),
            channels: img.clone(),
            spectral: Vec::new(),
            stats: Default::default(),
        };
        let exr = crate::output::encode_capture_exr(&cap, &scene_json, seed, spp)
            .map_err(write_failure)?;
        let png = crate::output::encode_capture_png(&cap).map_err(write_failure)?;
        files.push((format!("{stem}.exr"), exr));
        files.push((format!("{stem}.png"), png));
    }
    // Every path together: what the camera records (signal and stray light).
    let all = stscam_tracer::render::Capture {
        width: st.width,
        height: st.height,
        channel_names: st.channel_names.clone(),
        channels: st.all_paths.clone(),
        spectral: Vec::new(),
        stats: Default::default(),
    };
    files.push((
        "all_paths.exr".into(),
        crate::output::encode_capture_exr(&all, &scene_json, seed, spp).map_err(write_failure)?,
    ));
    files.push((
        "all_paths.png".into(),
        crate::output::encode_capture_png(&all).map_err(write_failure)?,
    ));
    let chart = report.chart(&st).to_png().map_err(write_failure)?;
    files.push(("stray.png".into(), chart));
    files.push(("stray.md".into(), report.markdown(&st, &json).into_bytes()));
    files.push(("stray.json".into(), to_json(&json)?.into_bytes()));
    write_files(&o.out, &files)?;
    for line in report.summary_lines(&st) {
        con.out(format_args!("{line}"));
    }
    con.err(format_args!(
        "wrote {}/stray.{{json,md,png}} and {} class images: {} classes, stray {:.3} % of the signal, {:.1} branches per camera ray, {:.1} s",
        o.out.display(),
        files.len().saturating_sub(5) / 2,
        st.classes.len(),
        100.0 * report.stray_total / report.signal_total,
        st.branches as f64 / st.rays.max(1) as f64,
        start.elapsed().as_secs_f64()
    ));
    Ok(st)
}

/// `x` to 6 significant digits (the row fractions: Monte Carlo estimates, kept short).
fn round6(x: f64) -> f64 {
    crate::numfmt::sig6(x).parse().unwrap_or(x)
}

/// A class image's file stem: its rank and a short name (`class_00_signal`, `class_03`).
fn image_stem(rank: usize, name: &str) -> String {
    if name == SIGNAL {
        format!("class_{rank:02}_signal")
    } else {
        format!("class_{rank:02}")
    }
}

/// The report's figures from the classes.
struct Report {
    signal_total: f64,
    signal_peak: f64,
    stray_total: f64,
}

impl Report {
    fn new(st: &StrayImages) -> Self {
        Report {
            signal_total: st.signal_total(),
            signal_peak: st.signal().map_or(0.0, |c| c.peak),
            stray_total: st.stray_total(),
        }
    }

    fn fraction(&self, c: &ClassImage) -> f64 {
        c.total / self.signal_total
    }

    fn peak_ratio(&self, c: &ClassImage) -> f64 {
        c.peak / self.signal_peak
    }

    /// The classes as JSON: name, events, fractions, row fractions, image file.
    fn classes_json(&self, st: &StrayImages) -> Vec<serde_json::Value> {
        let signal_rows = st
            .signal()
            .map(|c| c.row_sums.clone())
            .unwrap_or_else(|| vec![0.0; st.height]);
        st.classes
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let rows: Vec<Option<f64>> = c
                    .row_sums
                    .iter()
                    .zip(&signal_rows)
                    .map(|(a, b)| (*b > 0.0).then(|| round6(a / b)))
                    .collect();
                serde_json::json!({
                    "rank": i,
                    "name": c.name,
                    "events": c.events,
                    "short": c.short,
                    "fraction_of_signal": self.fraction(c),
                    "peak_ratio": self.peak_ratio(c),
                    "total": c.total,
                    "peak": c.peak,
                    "row_fraction": rows,
                    "image": c.image.as_ref().map(|_| format!("{}.exr", image_stem(i, &c.name))),
                })
            })
            .collect()
    }

    /// The ranked bar chart of the stray classes' share of the signal (log10 of the percent).
    fn chart(&self, st: &StrayImages) -> BarChart {
        let bars = st
            .classes
            .iter()
            .filter(|c| c.name != SIGNAL && c.total > 0.0)
            .take(20)
            .map(|c| {
                let pct = 100.0 * self.fraction(c);
                Bar {
                    label: c.short.clone(),
                    value: pct.log10() + 6.0,
                    note: format!("{pct:.3e} %"),
                }
            })
            .collect();
        BarChart {
            title: format!(
                "Stray light by path class: {:.3} % of the signal in all",
                100.0 * self.stray_total / self.signal_total
            ),
            x_label: "log10(% of the signal) + 6 (0 = 1e-6 %); labels in stray.md".into(),
            bars,
        }
    }

    /// The Markdown report.
    fn markdown(&self, st: &StrayImages, json: &serde_json::Value) -> String {
        let mut s = String::from("# Stray-light report\n\n");
        s += &format!(
            "Scene `{}`, {}x{} px, {} spp, seed {}, roulette below {}, at most {} events a path. \
             Every camera sample of `stscam render` (same seed) traced through every path of the \
             plate; the **signal** is what H models (the designed paths). The display in front of \
             the screen is the only source.\n\n",
            json["scene_source"].as_str().unwrap_or(""),
            st.width,
            st.height,
            json["spp"],
            json["seed"],
            json["roulette_threshold"],
            json["max_events"],
        );
        s += &format!(
            "Stray light in all: **{:.4} % of the signal** (signal-to-stray {:.1}); {} distinct classes, {:.1} branches per camera ray.\n\n",
            100.0 * self.stray_total / self.signal_total,
            self.signal_total / self.stray_total,
            st.distinct_classes,
            st.branches as f64 / st.rays.max(1) as f64
        );
        s += "| rank | class | short | % of signal | peak / signal peak | image |\n| ---: | --- | --- | ---: | ---: | --- |\n";
        for (i, c) in st.classes.iter().enumerate() {
            s += &format!(
                "| {i} | `{}` | `{}` | {:.4e} | {:.4e} | {} |\n",
                c.name,
                c.short,
                100.0 * self.fraction(c),
                self.peak_ratio(c),
                c.image
                    .as_ref()
                    .map(|_| format!("{}.png", image_stem(i, &c.name)))
                    .unwrap_or_default()
            );
        }
        s +=
            "\nWhere the camera's importance went per ray (display polarisation average): display ";
        s += &format!("{:.4}", st.exit_weight / st.rays.max(1) as f64);
        for (sink, v) in Sink::ALL.iter().zip(st.sinks) {
            s += &format!(", {} {:.4}", sink.name(), v / st.rays.max(1) as f64);
        }
        s += ".\n\nEach class image's PNG is scaled to its own 99.9th percentile (the EXR holds the values, in the capture's unit).\n";
        s
    }

    /// The terminal's lines: the leading classes.
    fn summary_lines(&self, st: &StrayImages) -> Vec<String> {
        let mut out = vec![format!(
            "stray light: {:.4} % of the signal over the {}x{} crop (signal-to-stray {:.1})",
            100.0 * self.stray_total / self.signal_total,
            st.width,
            st.height,
            self.signal_total / self.stray_total
        )];
        for c in st.classes.iter().filter(|c| c.name != SIGNAL).take(5) {
            out.push(format!(
                "  {:>10.4e} %  peak {:>9.3e}  {}",
                100.0 * self.fraction(c),
                self.peak_ratio(c),
                c.name
            ));
        }
        out
    }
}
