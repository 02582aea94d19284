//! One design's metrics (`stscam evaluate`), the primitive a study's optimiser calls.
//!
//! # Model
//! - **Geometry metrics** (FOVs, scene field, replicas, pitch, efficiency): the design figures
//!   of `stscam sweep` (`sweep::design_figures`: chief rays traced at their Bragg wavelengths,
//!   field response quadratures; definitions in the `sweep` module header) of the design at
//!   its own scene (full sensor, full object): deterministic, no Monte Carlo error.
//! - **Colour band coverage** (designs with `display.primaries = "lcd"`): the fraction of the
//!   crop's field rows whose best grating has a band in the primary (`colour::field_bands`,
//!   one row per sensor row of the crop, sampled at [`BAND_ROWS`] rows).
//! - **Reconstruction metrics** (`psnr_db`, `psnr_cg_db`, `ssim`), at the evaluation's
//!   [`Fidelity`]: the scene with its object at `object_px`² pixels (the LCD pixels per object
//!   pixel scaled so the target keeps its size on the display) and the sensor binned by
//!   `binning` (pitch × b, sensor, crop and crop offset ÷ b: the same area, fewer pixels), at
//!   each depth of `depths_mm` (default: the scene's display distance). Per replicate r and
//!   depth: H by `matrix::compute_matrix` at `spp` with seed s_r, and a second H with an
//!   independent seed that makes the captures (H₂·f + offset: a Monte Carlo capture of the
//!   target independent of the H that reconstructs, so no inverse crime); the scene's sensor
//!   noise at a **fixed exposure** ([`Exposure`]): the electrons per capture unit are set from
//!   one all-white peak held across designs, so a design with less throughput has less signal
//!   and more relative noise, as on the bench; a noisy dark frame subtracted; ADMM-TV with τ by
//!   the discrepancy principle and CGM stopped by it (`recon::discrepancy`, the `demo`
//!   protocol); PSNR (peak 1) and SSIM against the linear target. The value is the mean over
//!   targets, depths and replicates; its Monte Carlo error the standard error of the mean of
//!   the replicates' values (`replicates` ≥ 2, each with its own H, capture and noise seeds).
//! - **Tolerance metrics**: `draws` fabrication draws of `hoe.*` keys (`tolerance::DrawSpec`,
//!   draw i's values a pure function of (seed, i, key)) applied to the design; per draw the
//!   geometry and colour metrics. `yield` = the fraction of draws meeting every requirement
//!   given ([`Requirement`]), error √(p(1−p)/n); `<metric>_q05` = the 5 % quantile (linear
//!   interpolation between order statistics), error half the spread of the quantiles at
//!   0.05 ± √(0.05·0.95/n). Reconstruction metrics are not drawn (seconds per draw; `stscam
//!   tolerance --psnr` does that), and asking for one is an error.
//!
//! Determinism: every random number comes from the seed (per replicate, depth, target, draw),
//! loops collect in order, so the metrics are bit-identical for any thread count.

use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;

use crate::metric::{Base, Kind, Metric};
use crate::scene::{LoadedScene, SceneSource};
use crate::system::System;
use crate::tolerance::DrawSpec;

pub use crate::sweep::BAND_ROWS;
/// Most tolerance draws of one evaluation.
pub const MAX_DRAWS: usize = 100_000;
/// Most replicates of the reconstruction metrics.
pub const MAX_REPLICATES: usize = 64;

/// An evaluation error: one line naming the key, flag or metric.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The scene (or an override) is wrong.
    #[error(transparent)]
    Scene(#[from] crate::scene::SceneError),
    /// The request is wrong (a metric, a target, a fidelity setting).
    #[error("{0}")]
    Input(String),
    /// The job was cancelled.
    #[error("cancelled")]
    Cancelled,
}

fn input(m: impl Into<String>) -> EvalError {
    EvalError::Input(m.into())
}

/// A reconstruction target.
#[derive(Clone, Debug, PartialEq)]
pub enum Target {
    /// A built-in target spec without size (`letter:A`, `siemens:12`, …).
    Builtin(String),
    /// An image (a file, a numpy array): linear intensities in [0, 1], row-major, one plane
    /// (grey) or three (R, G, B, plane-major), area-resampled to the object size.
    Image {
        /// Name in reports.
        name: String,
        /// Width, pixels.
        width: usize,
        /// Height, pixels.
        height: usize,
        /// Planes: 1 or 3.
        planes: usize,
        /// Values, `planes` × `height` × `width`.
        values: Vec<f64>,
    },
}

/// Whether `spec` (without size) names a built-in target rather than a file.
pub fn is_builtin(spec: &str) -> bool {
    crate::targets::builtin_image(&format!("{spec}@8")).is_ok()
}

/// The demo's four targets (a glyph, a shape, a Siemens star and a smooth field).
pub fn default_targets() -> Vec<Target> {
    crate::demo::DEMO_TARGETS
        .iter()
        .map(|t| Target::Builtin(t.2.to_string()))
        .collect()
}

impl Target {
    /// A target from a CLI or study string: a built-in spec, or a PNG/EXR path (relative to
    /// `dir`) loaded as display code values (PNG, gamma `gamma`) or linear values (EXR).
    pub fn parse(spec: &str, dir: &std::path::Path, gamma: f64) -> Result<Target, String> {
        if spec.contains('@') {
            return Err(format!(
                "target {spec:?}: give it without @SIZE (the size is the fidelity's object_px)"
            ));
        }
        if is_builtin(spec) {
            return Ok(Target::Builtin(spec.to_string()));
        }
        let path = dir.join(spec);
        if !path.is_file() {
            return Err(format!(
                "target {spec:?} is neither a built-in target nor an image file ({})",
                path.display()
            ));
        }
        let img = crate::io::image_load::load_image_rgb(&path)
            .map_err(|e| format!("target {spec:?}: {e}"))?;
        let planes = if img.channels >= 3 { 3 } else { 1 };
        let values = crate::display::Display::planes_of(
            &img.values,
            img.channels,
            img.linear,
            gamma,
            planes,
        );
        Ok(Target::Image {
            name: spec.to_string(),
            width: img.width,
            height: img.height,
            planes,
            values,
        })
    }

    /// Name in reports.
    pub fn name(&self) -> &str {
        match self {
            Target::Builtin(s) => s,
            Target::Image { name, .. } => name,
        }
    }

    /// The target as `planes` planes of `n`×`n` linear intensities (grey in every plane of a
    /// colour object; a colour image's luminance-free mean for a grey one).
    pub fn planes(&self, n: usize, planes: usize, gamma: f64) -> Result<Vec<f64>, String> {
        match self {
            Target::Builtin(spec) => {
                crate::capture::planes_of_spec(&format!("{spec}@{n}"), gamma, planes)
                    .map(|t| t.2)
                    .map_err(|e| format!("target {spec:?}: {e}"))
            }
            Target::Image {
                width,
                height,
                planes: p,
                values,
                name,
            } => {
                let len = width * height;
                if *width == 0 || *height == 0 || values.len() != len * p {
                    return Err(format!(
                        "target {name:?}: {} values are not {p} planes of {width}x{height}",
                        values.len()
                    ));
                }
                if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                    return Err(format!("target {name:?}: value {i} is not a finite number"));
                }
                let plane = |k: usize| {
                    crate::demo::resample(&values[k * len..(k + 1) * len], *width, *height, n, n)
                };
                Ok(match (p, planes) {
                    (1, 3) => (0..3).flat_map(|_| plane(0)).collect(),
                    (3, 1) => {
                        let (r, g, b) = (plane(0), plane(1), plane(2));
                        (0..n * n).map(|i| (r[i] + g[i] + b[i]) / 3.0).collect()
                    }
                    (_, _) => (0..planes).flat_map(plane).collect(),
                })
            }
        }
    }
}

/// The exposure the reconstruction metrics are taken at.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Exposure {
    /// From the design's own all-white capture (each design re-normalised: throughput does not
    /// cost signal; the `demo`'s protocol).
    Own,
    /// Fixed: the all-white peak (capture units, at the same fidelity) that sets the
    /// electrons per unit for every design (a study takes its base design's).
    WhitePeak(f64),
}

/// The fidelity of the reconstruction metrics (module notes).
#[derive(Clone, Debug, PartialEq)]
pub struct Fidelity {
    /// Object size, pixels per side (None: the scene's, which must be square).
    pub object_px: Option<u32>,
    /// Sensor binning factor (1: the scene's sensor).
    pub binning: u32,
    /// Samples per pixel of H and of the capture H.
    pub spp: u32,
    /// Seed.
    pub seed: u64,
    /// Replicates (≥ 2 for an error).
    pub replicates: usize,
    /// Targets.
    pub targets: Vec<Target>,
    /// Object depths, mm from the plate (empty: the scene's display distance).
    pub depths_mm: Vec<f64>,
}

impl Default for Fidelity {
    fn default() -> Self {
        Fidelity {
            object_px: Some(32),
            binning: 2,
            spp: 8,
            seed: 1,
            replicates: 2,
            targets: default_targets(),
            depths_mm: Vec::new(),
        }
    }
}

/// A requirement on a geometry or colour metric that a tolerance draw must meet to count in
/// the yield.
#[derive(Clone, Debug, PartialEq)]
pub struct Requirement {
    /// The base metric.
    pub metric: Base,
    /// Smallest acceptable value.
    pub min: Option<f64>,
    /// Largest acceptable value.
    pub max: Option<f64>,
}

impl Requirement {
    /// Parses `METRIC>=V` or `METRIC<=V` (the CLI's `--require`; the syntax of
    /// `tolerance --require`, the name here a metric of this crate).
    pub fn parse(spec: &str) -> Result<Requirement, String> {
        let t = crate::tolerance::Requirement::parse(spec).map_err(|e| e.to_string())?;
        let m = Metric::parse(&t.figure).map_err(|e| format!("--require {spec:?}: {e}"))?;
        let r = Requirement {
            metric: m.base,
            min: t.min,
            max: t.max,
        };
        r.check().map_err(|e| format!("--require {spec:?}: {e}"))?;
        if m.q05 {
            return Err(format!(
                "--require {spec:?}: a requirement is on a draw's own value, not a quantile"
            ));
        }
        Ok(r)
    }

    /// Whether the requirement can be tested per draw.
    pub fn check(&self) -> Result<(), String> {
        match self.metric.kind() {
            Kind::Geometry | Kind::Colour => Ok(()),
            _ => Err(format!(
                "{} is not evaluated per tolerance draw (only geometry and colour metrics are)",
                self.metric.name()
            )),
        }
    }

    /// Whether `v` meets it.
    pub fn met_by(&self, v: f64) -> bool {
        self.min.is_none_or(|m| v >= m) && self.max.is_none_or(|m| v <= m)
    }
}

/// What to evaluate.
#[derive(Clone, Debug)]
pub struct Request {
    /// The metrics.
    pub metrics: Vec<Metric>,
    /// Fidelity of the reconstruction metrics.
    pub fidelity: Fidelity,
    /// Exposure of the reconstruction metrics.
    pub exposure: Exposure,
    /// Tolerance draws (`hoe.*` keys).
    pub draws: Vec<DrawSpec>,
    /// Number of tolerance draws.
    pub draw_count: usize,
    /// Requirements of the yield.
    pub requirements: Vec<Requirement>,
}

impl Request {
    /// Checks the request before anything is computed.
    pub fn check(&self) -> Result<(), EvalError> {
        let f = &self.fidelity;
        if self
            .metrics
            .iter()
            .any(|m| matches!(m.base.kind(), Kind::Reconstruction | Kind::Stray))
        {
            if f.spp == 0 {
                return Err(input("fidelity spp: must be at least 1"));
            }
            if f.binning == 0 || f.binning > 64 {
                return Err(input("fidelity binning: must be 1..=64"));
            }
            if f.replicates == 0 || f.replicates > MAX_REPLICATES {
                return Err(input(format!(
                    "fidelity replicates: must be 1..={MAX_REPLICATES}"
                )));
            }
            if f.targets.is_empty() {
                return Err(input("fidelity targets: give at least one target"));
            }
            if let Some(n) = f.object_px
                && !(4..=1024).contains(&n)
            {
                return Err(input(format!("fidelity object_px {n}: must be 4..=1024")));
            }
            if let Some(d) = f.depths_mm.iter().find(|d| !(d.is_finite() && **d > 0.0)) {
                return Err(input(format!("fidelity depths_mm {d}: must be positive")));
            }
            if let Exposure::WhitePeak(v) = self.exposure
                && !(v.is_finite() && v > 0.0)
            {
                return Err(input(format!(
                    "exposure white peak {v}: must be a positive number"
                )));
            }
        }
        for m in &self.metrics {
            if m.q05 && m.base.kind() != Kind::Geometry && m.base.kind() != Kind::Colour {
                return Err(input(format!(
                    "metric {m}: quantiles over the tolerance draws are computed for geometry and colour metrics only (a reconstruction per draw costs seconds; `stscam tolerance --psnr` draws the PSNR)"
                )));
            }
            if m.needs_draws() && (self.draws.is_empty() || self.draw_count == 0) {
                return Err(input(format!(
                    "metric {m}: needs tolerance draws (--draw KEY=normal(M,SD) and --draws N)"
                )));
            }
        }
        if self.metrics.iter().any(|m| m.base == Base::Yield) && self.requirements.is_empty() {
            return Err(input(
                "metric yield: needs requirements (--require METRIC>=VALUE)",
            ));
        }
        if self.draw_count > MAX_DRAWS {
            return Err(input(format!(
                "--draws {}: at most {MAX_DRAWS}",
                self.draw_count
            )));
        }
        for r in &self.requirements {
            r.check().map_err(input)?;
        }
        Ok(())
    }
}

/// One design's metrics.
#[derive(Clone, Debug, Serialize)]
pub struct Evaluation {
    /// Metric name → value, and `<name>_error` → its Monte Carlo error where it has one
    /// (NaN where a metric is undefined, e.g. the band coverage of a monochrome design).
    pub values: BTreeMap<String, f64>,
    /// The all-white peak of the design at the fidelity (what [`Exposure::Own`] would use; a
    /// study takes the base design's as its fixed exposure). NaN without reconstruction metrics.
    pub white_peak: f64,
    /// Warnings (e.g. part of the object that the crop cannot see).
    pub warnings: Vec<String>,
    /// Seconds the evaluation took.
    pub seconds: f64,
}

/// Evaluates the design of `scene` with `overrides` (module notes).
pub fn evaluate(
    scene: SceneSource<'_>,
    overrides: &[String],
    req: &Request,
) -> Result<Evaluation, EvalError> {
    req.check()?;
    let t0 = Instant::now();
    let loaded = scene.load(overrides)?;
    let sys = System::build(&loaded)?;
    let mut values = BTreeMap::new();
    let mut warnings = Vec::new();
    let want = |k: Kind| {
        req.metrics
            .iter()
            .any(|m| !m.q05 && m.base.kind() == k && m.base != Base::Yield)
    };
    if want(Kind::Geometry) || want(Kind::Colour) {
        let g = geometry(&sys);
        for m in req.metrics.iter().filter(|m| !m.q05) {
            if let Some(v) = g.get(&m.base) {
                values.insert(m.base.name().to_string(), *v);
            }
        }
    }
    let mut white_peak = f64::NAN;
    if want(Kind::Reconstruction) {
        let r = reconstruction(scene, overrides, &loaded, &sys, req, &mut warnings)?;
        white_peak = r.white_peak;
        for m in req
            .metrics
            .iter()
            .filter(|m| m.base.kind() == Kind::Reconstruction)
        {
            let (v, e) = r.values[&m.base];
            values.insert(m.base.name().to_string(), v);
            values.insert(format!("{}_error", m.base.name()), e);
        }
    }
    if want(Kind::Stray) {
        let (v, e) = stray_percent(scene, overrides, &loaded, &sys, &req.fidelity)?;
        let name = Base::StrayPercent.name();
        values.insert(name.to_string(), v);
        values.insert(format!("{name}_error"), e);
    }
    if req.metrics.iter().any(|m| m.needs_draws()) {
        tolerance(scene, overrides, req, &mut values)?;
    }
    if crate::cancel::current().is_cancelled() {
        return Err(EvalError::Cancelled);
    }
    Ok(Evaluation {
        values,
        white_peak,
        warnings,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The geometry and colour metrics of `sys` (`sweep::geometry_metrics`, by [`Base`]).
pub fn geometry(sys: &System) -> BTreeMap<Base, f64> {
    crate::sweep::geometry_metrics(sys)
        .into_iter()
        .filter_map(|(name, v)| Some((Base::from_name(name)?, v)))
        .collect()
}

/// The overrides that put a scene (`loaded`, built as `sys`) at the fidelity (module notes),
/// after the design's own.
pub fn fidelity_overrides(
    loaded: &LoadedScene,
    sys: &System,
    f: &Fidelity,
) -> Result<Vec<String>, EvalError> {
    let s = &loaded.scene;
    let mut o = Vec::new();
    if let Some(n) = f.object_px {
        // The target keeps its size on the display: n × ppi' = n₀ × ppi₀.
        let (w0, h0) = (sys.display.width_px, sys.display.height_px);
        if w0 != h0 {
            return Err(input(format!(
                "display.image: the reconstruction metrics need a square object, got {w0}x{h0}"
            )));
        }
        let extent = w0 as u64 * u64::from(s.display.lcd_pixels_per_image_pixel);
        if !extent.is_multiple_of(u64::from(n)) {
            return Err(input(format!(
                "fidelity object_px {n}: the target spans {extent} LCD pixels, which {n} object pixels do not divide"
            )));
        }
        o.push(format!(
            "display.lcd_pixels_per_image_pixel={}",
            extent / u64::from(n)
        ));
        // The object grid (the targets replace its values).
        o.push(format!("display.image=\"white@{n}\""));
    }
    let b = f.binning;
    if b > 1 {
        let crop = s.sensor.crop_px.size();
        let div = |v: u32, what: &str| {
            if v.is_multiple_of(b) {
                Ok(v / b)
            } else {
                Err(input(format!(
                    "fidelity binning {b}: {what} {v} is not a multiple of it"
                )))
            }
        };
        o.push(format!(
            "sensor.width_px={}",
            div(s.sensor.width_px, "sensor.width_px")?
        ));
        o.push(format!(
            "sensor.height_px={}",
            div(s.sensor.height_px, "sensor.height_px")?
        ));
        o.push(format!(
            "sensor.pitch_um={}",
            s.sensor.pitch_um * f64::from(b)
        ));
        o.push(format!(
            "sensor.crop_px=[{},{}]",
            div(crop.0, "the crop width")?,
            div(crop.1, "the crop height")?
        ));
        let [ox, oy] = s.sensor.crop_offset_px;
        o.push(format!(
            "sensor.crop_offset_px=[{},{}]",
            ox.div_euclid(b as i32),
            oy.div_euclid(b as i32)
        ));
    }
    Ok(o)
}

/// The stray light of the design, % of the signal, and its standard error: `stscam stray`'s
/// total over the crop at the fidelity's sensor binning (the scene's own display image) and
/// spp, once per replicate (seeds `seed`, `seed + 1`, …; one replicate: error NaN).
fn stray_percent(
    scene: SceneSource<'_>,
    overrides: &[String],
    loaded: &LoadedScene,
    sys: &System,
    f: &Fidelity,
) -> Result<(f64, f64), EvalError> {
    use stscam_stray::image::{StraySettings, bytes_bound, stray_images};
    let binning_only = Fidelity {
        object_px: None,
        ..f.clone()
    };
    let mut set: Vec<String> = overrides.to_vec();
    set.extend(fidelity_overrides(loaded, sys, &binning_only)?);
    let sys = System::build(&scene.load(&set)?)?;
    if sys.world.is_some() {
        return Err(input(
            "metric stray_percent: display scenes only (the stray tracer does not follow a 3-D user side)",
        ));
    }
    crate::render::check_limits(
        &sys,
        &crate::render::RenderSettings::lattice(f.spp, 0, false),
        f.replicates as u64,
        "fidelity spp",
    )
    .map_err(|e| input(e.to_string()))?;
    crate::limits::check_bytes(
        "sensor.crop_px",
        "the stray-light classes' images",
        bytes_bound(&sys),
    )
    .map_err(|e| input(e.to_string()))?;
    let mut xs = Vec::with_capacity(f.replicates);
    for r in 0..f.replicates {
        let st = stray_images(
            &sys,
            &StraySettings {
                spp: f.spp,
                seed: f.seed.wrapping_add(r as u64),
                paths: Default::default(),
                progress: false,
            },
        );
        xs.push(100.0 * st.stray_total() / st.signal_total());
    }
    Ok(mean_and_error(&xs))
}

/// Reconstruction metrics: (value, error) per base metric and the design's white peak.
struct Recon {
    values: BTreeMap<Base, (f64, f64)>,
    white_peak: f64,
}

fn reconstruction(
    scene: SceneSource<'_>,
    overrides: &[String],
    loaded: &LoadedScene,
    sys: &System,
    req: &Request,
    warnings: &mut Vec<String>,
) -> Result<Recon, EvalError> {
    use crate::recon::discrepancy::{NoiseLevel, admm_tv_discrepancy, cg_discrepancy};
    let f = &req.fidelity;
    let mut base_set: Vec<String> = overrides.to_vec();
    base_set.extend(fidelity_overrides(loaded, sys, f)?);
    let depths: Vec<Option<f64>> = if f.depths_mm.is_empty() {
        vec![None]
    } else {
        f.depths_mm.iter().map(|&d| Some(d)).collect()
    };
    // The system at each depth, built and checked once for every replicate.
    let mut systems = Vec::with_capacity(depths.len());
    for d in &depths {
        let mut set = base_set.clone();
        if let Some(d) = d {
            set.push(format!("display.distance_mm={d}"));
        }
        let sys = System::build(&scene.load(&set)?)?;
        let (ow, oh) = (sys.display.width_px, sys.display.height_px);
        if ow != oh {
            return Err(input(format!(
                "display.image: the reconstruction metrics need a square object, got {ow}x{oh}"
            )));
        }
        crate::render::check_limits(
            &sys,
            &crate::render::RenderSettings::lattice(f.spp, 0, false),
            2,
            "fidelity spp",
        )
        .map_err(|e| input(e.to_string()))?;
        if let Some(w) = crate::analysis::object_coverage(&sys).warning() {
            let at = d.map_or(String::new(), |d| format!(" (object at {d} mm)"));
            warnings.push(format!("{w}{at}"));
        }
        systems.push(sys);
    }
    let cancel = crate::cancel::current();
    // Per replicate: (PSNR ADMM, PSNR CG, SSIM) means over depths and targets.
    let mut reps: Vec<[f64; 3]> = Vec::with_capacity(f.replicates);
    let mut white_peak = f64::NAN;
    for r in 0..f.replicates {
        let seed = crate::sampler::hash(&[f.seed, 0x4556_414C, r as u64]);
        let mut acc = [0.0; 3];
        let mut n = 0usize;
        for (di, sys) in systems.iter().enumerate() {
            let (ow, oh, planes) = (
                sys.display.width_px,
                sys.display.height_px,
                sys.display.planes(),
            );
            let m = crate::matrix::compute_matrix(
                sys,
                &crate::render::RenderSettings::lattice(f.spp, seed, false),
            );
            let m2 = crate::matrix::compute_matrix(
                sys,
                &crate::render::RenderSettings::lattice(f.spp, seed ^ 0x9E37_79B9_7F4A_7C15, false),
            );
            if cancel.is_cancelled() {
                return Err(EvalError::Cancelled);
            }
            let own_peak = crate::capture::white_peak_of(&m);
            if r == 0 && di == 0 {
                white_peak = own_peak;
            }
            let peak = match req.exposure {
                Exposure::Own => own_peak,
                Exposure::WhitePeak(v) => v,
            };
            let noise =
                crate::noise::SensorNoise::checked(&sys.scene.noise, peak).map_err(input)?;
            let dark = crate::capture::dark_frame(&m2, &noise, seed);
            let black = crate::capture::black_level_of(&dark, &noise);
            let problem = crate::recon::Problem::with_cancel(&m.h, ow, planes * oh, cancel.clone());
            let admm = crate::recon::admm::AdmmSettings::default();
            for (ti, t) in f.targets.iter().enumerate() {
                let truth = t
                    .planes(ow, planes, sys.scene.display.gamma)
                    .map_err(input)?;
                let frame = crate::capture::noisy_capture_of(
                    &m2,
                    &truth,
                    &noise,
                    seed,
                    (di * 1000 + ti) as u64,
                );
                let g: Vec<f64> = frame.iter().zip(&dark).map(|(a, b)| a - b).collect();
                let level = NoiseLevel::of_capture(&problem, &g, &black, true, &noise);
                let htg = problem.back_project(&g);
                let fa = admm_tv_discrepancy(&problem, &htg, &level, &admm).result.f;
                let fc =
                    cg_discrepancy(&problem, &htg, &level, crate::recon::cg::DEFAULT_CG_ITERS).f;
                acc[0] += crate::recon::metrics::psnr(&fa, &truth);
                acc[1] += crate::recon::metrics::psnr(&fc, &truth);
                acc[2] += (0..planes)
                    .map(|p| {
                        let s = p * ow * oh..(p + 1) * ow * oh;
                        crate::recon::metrics::ssim(&fa[s.clone()], &truth[s], ow, oh)
                    })
                    .sum::<f64>()
                    / planes as f64;
                n += 1;
                if cancel.is_cancelled() {
                    return Err(EvalError::Cancelled);
                }
            }
        }
        reps.push(acc.map(|a| a / n as f64));
    }
    let mut values = BTreeMap::new();
    for (k, b) in [Base::PsnrDb, Base::PsnrCgDb, Base::Ssim]
        .into_iter()
        .enumerate()
    {
        let xs: Vec<f64> = reps.iter().map(|r| r[k]).collect();
        values.insert(b, mean_and_error(&xs));
    }
    Ok(Recon { values, white_peak })
}

/// The mean of `xs` and its standard error (NaN with fewer than two values).
pub fn mean_and_error(xs: &[f64]) -> (f64, f64) {
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    if xs.len() < 2 {
        return (mean, f64::NAN);
    }
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// The quantile `q` of sorted `xs` (linear between order statistics).
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let (i, t) = (pos.floor() as usize, pos.fract());
    let j = (i + 1).min(sorted.len() - 1);
    sorted[i] + t * (sorted[j] - sorted[i])
}

fn tolerance(
    scene: SceneSource<'_>,
    overrides: &[String],
    req: &Request,
    values: &mut BTreeMap<String, f64>,
) -> Result<(), EvalError> {
    use rayon::prelude::*;
    let n = req.draw_count;
    let seed = req.fidelity.seed;
    let sets: Vec<Vec<String>> = (0..n as u64)
        .map(|i| {
            let mut s = overrides.to_vec();
            s.extend(
                req.draws
                    .iter()
                    .enumerate()
                    .map(|(k, d)| format!("{}={}", d.key, d.sample(seed, i, k))),
            );
            s
        })
        .collect();
    // Check every draw's scene before the figures.
    for s in &sets {
        System::build(&scene.load(s)?)?;
    }
    let cancel = crate::cancel::current();
    let per_draw: Vec<BTreeMap<Base, f64>> = sets
        .par_iter()
        .map(|s| {
            if cancel.is_cancelled() {
                return BTreeMap::new();
            }
            scene
                .load(s)
                .ok()
                .and_then(|ls| System::build(&ls).ok())
                .map(|sys| geometry(&sys))
                .unwrap_or_default()
        })
        .collect();
    if cancel.is_cancelled() {
        return Err(EvalError::Cancelled);
    }
    for m in &req.metrics {
        if m.base == Base::Yield {
            let ok = per_draw
                .iter()
                .filter(|d| {
                    req.requirements
                        .iter()
                        .all(|r| d.get(&r.metric).is_some_and(|&v| r.met_by(v)))
                })
                .count();
            let p = ok as f64 / n as f64;
            values.insert("yield".into(), p);
            values.insert("yield_error".into(), (p * (1.0 - p) / n as f64).sqrt());
        } else if m.q05 {
            let mut xs: Vec<f64> = per_draw
                .iter()
                .filter_map(|d| d.get(&m.base).copied())
                .collect();
            xs.sort_by(f64::total_cmp);
            let se = (0.05 * 0.95 / n as f64).sqrt();
            values.insert(m.to_string(), quantile(&xs, 0.05));
            values.insert(
                format!("{m}_error"),
                0.5 * (quantile(&xs, 0.05 + se) - quantile(&xs, (0.05 - se).max(0.0))),
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantile_and_standard_error_by_hand() {
        let xs = [1.0, 2.0, 3.0, 4.0, 5.0];
        assert_eq!(quantile(&xs, 0.0), 1.0);
        assert_eq!(quantile(&xs, 0.5), 3.0);
        assert!((quantile(&xs, 0.05) - 1.2).abs() < 1e-12);
        let (m, e) = mean_and_error(&[1.0, 3.0]);
        assert_eq!(m, 2.0);
        // s = √2, s/√2 = 1.
        assert!((e - 1.0).abs() < 1e-12);
        assert!(mean_and_error(&[1.0]).1.is_nan());
    }

    #[test]
    fn requirements_parse_and_refuse() {
        let r = Requirement::parse("fov_capture_vertical_deg>=30").unwrap();
        assert_eq!(r.min, Some(30.0));
        assert!(r.met_by(30.0) && !r.met_by(29.9));
        assert!(Requirement::parse("psnr_db>=20").is_err());
        assert!(Requirement::parse("fov_capture_vertical_deg=30").is_err());
        assert!(Requirement::parse("nope>=1").is_err());
        assert!(Requirement::parse("efficiency_mean<=nan").is_err());
    }

    #[test]
    fn image_targets_resample_and_check_their_values() {
        let t = Target::Image {
            name: "ramp".into(),
            width: 4,
            height: 4,
            planes: 1,
            values: (0..16).map(|i| f64::from(i % 4) / 3.0).collect(),
        };
        let p = t.planes(2, 1, 2.2).unwrap();
        // Box means of columns (0,1) and (2,3): 1/6 and 5/6.
        assert!(
            (p[0] - 1.0 / 6.0).abs() < 1e-12 && (p[1] - 5.0 / 6.0).abs() < 1e-12,
            "{p:?}"
        );
        assert_eq!(t.planes(2, 3, 2.2).unwrap().len(), 12);
        let bad = Target::Image {
            name: "bad".into(),
            width: 2,
            height: 2,
            planes: 1,
            values: vec![0.0, f64::NAN, 0.0, 0.0],
        };
        assert!(bad.planes(2, 1, 2.2).unwrap_err().contains("value 1"));
    }
}
