//! The runtime system built from a scene description: waveguide, camera, sensor response,
//! display and wavelength sampler, with every derived quantity computed once.
//!
//! Geometry (docs/design.md): bottom vHOE centred at (0, 0) on the back face; top vHOE on the front
//! face with its bottom edge `gap` above the bottom vHOE's top edge; camera axis through the
//! top vHOE's centre at `camera.distance_mm` behind the back face; display plane at
//! z = −`display.distance_mm`.

use glam::{DVec2, DVec3};
use std::path::Path;

use crate::camera::{Camera, sensor_distance_mm};
use crate::display::Display;
use crate::io::image_load::{LoadedImage, load_image};
use crate::optics::glass::Glass;
use crate::optics::grating::VolumeGrating;
use crate::optics::multiplex::GratingSet;
use crate::scene::{AutoOr, GlassSpec, LoadedScene, PolarizationSpec, Scene, SceneError};
use crate::spectra::{self, DisplaySpectrumKind, SensorResponseKind, Spectrum};
use crate::trace::{TraceLimits, trace_camera_path};
use crate::waveguide::{Rect, Waveguide};
use crate::wavelength::WavelengthSampler;

/// Sensor spectral response, normalised per channel.
#[derive(Clone, Debug)]
pub struct Response {
    /// Channel names ("Y" or "R", "G", "B").
    pub names: Vec<&'static str>,
    /// Curves (absolute QE-like fractions).
    pub curves: Vec<Spectrum>,
    /// 1/∫R_c dλ over the band, per channel.
    pub inv_integral: Vec<f64>,
}

/// Everything a render needs.
#[derive(Clone, Debug)]
pub struct System {
    /// The description it was built from.
    pub scene: Scene,
    /// Waveguide.
    pub waveguide: Waveguide,
    /// Camera.
    pub camera: Camera,
    /// Display.
    pub display: Display,
    /// Sensor response.
    pub response: Response,
    /// Wavelength sampler.
    pub wavelengths: WavelengthSampler,
    /// Trace limits.
    pub limits: TraceLimits,
    /// The user-side 3-D scene (None for a display-only scene: the fast path).
    pub world: Option<std::sync::Arc<crate::world::World>>,
}

/// Glass model of a scene.
pub fn glass_of(spec: &GlassSpec) -> Glass {
    match spec {
        GlassSpec::Index(n) => Glass::Constant { n: *n },
        GlassSpec::Name(name) if name == "n-bk7" => Glass::NBk7,
        GlassSpec::Name(_) => Glass::SodaLime,
    }
}

fn response_kind(name: &str) -> SensorResponseKind {
    match name {
        "mono-qe" => SensorResponseKind::MonoQe,
        "flat" => SensorResponseKind::Flat,
        "rgb-bayer" => SensorResponseKind::RgbBayer,
        _ => SensorResponseKind::MonoBayerY,
    }
}

fn spectrum_kind(name: &str) -> DisplaySpectrumKind {
    match name {
        "flat" => DisplaySpectrumKind::Flat,
        "ccfl" => DisplaySpectrumKind::Ccfl,
        _ => DisplaySpectrumKind::WhiteLed,
    }
}

/// Builds the waveguide of a scene.
pub fn build_waveguide(s: &Scene) -> Waveguide {
    let h = &s.hoe;
    // The gratings as fabricated (every fabrication key 0: the recorded design, bit for bit).
    let list: Vec<VolumeGrating> = h.fabricated_gratings();
    // Validation bounds the list to 1..=MAX_GRATINGS and the film is shared by construction.
    let gratings = GratingSet::new(&list).unwrap_or_else(|| GratingSet::single(list[0]));
    let bottom = Rect::centered(
        DVec2::ZERO,
        DVec2::new(s.bottom_hoe.width_mm, s.bottom_hoe.height_mm),
    );
    let top_cy = 0.5 * s.bottom_hoe.height_mm + s.top_hoe.gap_mm + 0.5 * s.top_hoe.height_mm;
    let top = Rect::centered(
        DVec2::new(0.0, top_cy),
        DVec2::new(s.top_hoe.width_mm, s.top_hoe.height_mm),
    );
    Waveguide {
        thickness_mm: s.plate.thickness_mm,
        glass: glass_of(&s.plate.glass),
        absorption_override_per_mm: s.plate.absorption_per_mm.value(),
        gratings,
        bottom,
        top,
        covered: s.top_hoe.covered,
        cover_frustrates_tir: s.top_hoe.cover_frustrates_tir,
        rcwa: None,
    }
}

/// Builds the camera of a scene (needs the waveguide for its position and auto focus).
pub fn build_camera(s: &Scene, wg: &Waveguide) -> Camera {
    let c = &s.camera;
    let n0 = wg.n_glass(s.hoe.primary_wavelength_nm());
    let focus = match c.focus_distance_mm {
        AutoOr::Value(v) => v,
        AutoOr::Word(_) => c.distance_mm + 2.0 * wg.thickness_mm / n0 + s.display.distance_mm,
    };
    let (cw, ch) = s.sensor.crop_px.size();
    Camera {
        lens_center_mm: DVec3::new(
            wg.top.center().x,
            wg.top.center().y,
            wg.thickness_mm + c.distance_mm,
        ),
        focal_length_mm: c.focal_length_mm,
        sensor_distance_mm: sensor_distance_mm(c.focal_length_mm, focus),
        focus_distance_mm: focus,
        aperture_radius_mm: 0.5 * c.focal_length_mm / c.f_number,
        pitch_mm: s.sensor.pitch_um * 1e-3,
        width_px: cw as usize,
        height_px: ch as usize,
        offset_px: DVec2::new(
            f64::from(s.sensor.crop_offset_px[0]),
            f64::from(s.sensor.crop_offset_px[1]),
        ),
    }
}

/// True if a `display.image` value names a file rather than a built-in target.
pub fn is_image_path(spec: &str) -> bool {
    let lower = spec.to_ascii_lowercase();
    lower.ends_with(".png") || lower.ends_with(".exr")
}

/// Loads the target as (width, height, values, linear).
fn load_target(ls: &LoadedScene) -> Result<LoadedImage, SceneError> {
    let spec = ls.scene.display.image.trim();
    if is_image_path(spec) {
        let path = if Path::new(spec).is_absolute() {
            Path::new(spec).to_path_buf()
        } else {
            ls.base_dir.join(spec)
        };
        let img = load_image(&path).map_err(|e| ls.key_error("display.image", e.to_string()))?;
        Ok(img)
    } else {
        let (width, height, channels, values) =
            crate::targets::builtin_image(spec).map_err(|e| ls.key_error("display.image", e))?;
        Ok(LoadedImage {
            width,
            height,
            channels,
            values,
            linear: false,
            alpha: Vec::new(),
        })
    }
}

/// Builds the display of a scene.
pub fn build_display(ls: &LoadedScene) -> Result<Display, SceneError> {
    let d = &ls.scene.display;
    let LoadedImage {
        width: w,
        height: h,
        channels,
        values,
        linear,
        ..
    } = load_target(ls)?;
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(ls.key_error(
            "display.image",
            format!(
                "pixel ({}, {}) is not a finite number",
                i % w.max(1),
                i / w.max(1)
            ),
        ));
    }
    let angle = match d.polarization {
        PolarizationSpec::AngleDeg(a) => Some(a),
        PolarizationSpec::Word(_) => None,
    };
    let backlight = spectra::display_spectrum(spectrum_kind(&d.spectrum));
    let (spectrum, primaries) = if d.primaries == "lcd" {
        let (p, white) = spectra::display_primaries(&backlight);
        (white, Some(Box::new(p)))
    } else {
        (backlight, None)
    };
    let planes = if primaries.is_some() { 3 } else { 1 };
    let intensity = Display::planes_of(&values, channels, linear, d.gamma, planes);
    let radiance = intensity
        .iter()
        .map(|l| d.black_level + (1.0 - d.black_level) * l)
        .collect();
    Ok(Display {
        z_mm: -d.distance_mm,
        center_mm: DVec2::new(d.center_mm[0], d.center_mm[1]),
        image_pixel_mm: d.pixel_pitch_mm * f64::from(d.lcd_pixels_per_image_pixel),
        width_px: w,
        height_px: h,
        intensity,
        radiance,
        black_level: d.black_level,
        half_extent_mm: DVec2::new(f64::from(d.size_px[0]), f64::from(d.size_px[1]))
            * (0.5 * d.pixel_pitch_mm),
        spectrum,
        primaries,
        polarization_weights: Display::polarization_weights(angle),
    })
}

/// Half-width (nm) of the table used for wavelength importance sampling.
const TABLE_HALF_WIDTH_NM: f64 = 40.0;
/// Bins of that table.
const TABLE_BINS: usize = 800;

/// Field rows at which the spectral throughput is tabulated.
const TABLE_FIELDS: usize = 48;

/// Builds the wavelength sampler from measured spectral throughput curves: for the chief rays
/// of `TABLE_FIELDS` rows along the crop's vertical midline (λ_B varies along y), the
/// end-to-end throughput (all replicas, display polarisation) is traced across
/// Δλ = λ − λ_B and given a floor of 10⁻³ of its peak (robustness against the field-dependent
/// side-lobe zeros of neighbouring rows). A multiplexed film gets one set of tables per
/// grating, around that grating's Bragg wavelength and from its own replicas.
fn build_wavelength_sampler(
    s: &Scene,
    wg: &Waveguide,
    cam: &Camera,
    display: &Display,
    limits: TraceLimits,
) -> WavelengthSampler {
    use rayon::prelude::*;
    let sm = &s.sampling;
    let bin = 2.0 * TABLE_HALF_WIDTH_NM / TABLE_BINS as f64;
    let pol = display.polarization_weights;
    let half_y = 0.5 * cam.height_px as f64 * cam.pitch_mm;
    let n_gratings = wg.gratings.len();
    let per_grating: Vec<(Vec<(f64, Vec<f64>)>, bool)> = (0..n_gratings)
        .map(|j| {
            let grating = wg.gratings.get(j);
            let shapes: Vec<(f64, Vec<f64>)> = (0..TABLE_FIELDS)
                .into_par_iter()
                .filter_map(|k| {
                    let y = half_y * (2.0 * k as f64 / (TABLE_FIELDS - 1) as f64 - 1.0);
                    let chief = cam.ray_through(
                        DVec2::new(0.0, y) + cam.offset_px * cam.pitch_mm,
                        DVec2::ZERO,
                    );
                    let lb = grating.bragg_wavelength_nm(-chief.dir.truncate())?;
                    let mut curve: Vec<f64> = (0..TABLE_BINS)
                        .map(|i| {
                            let lam = lb - TABLE_HALF_WIDTH_NM + (i as f64 + 0.5) * bin;
                            let mut total = 0.0;
                            trace_camera_path(
                                wg,
                                display.z_mm,
                                limits,
                                chief.origin,
                                chief.dir,
                                lam,
                                |b| {
                                    // One grating: every branch, as always; several: this
                                    // grating's replicas.
                                    if n_gratings == 1 || b.grating as usize == j {
                                        total += pol[0] * b.weight[0] + pol[1] * b.weight[1];
                                    }
                                },
                            );
                            total
                        })
                        .collect();
                    let peak = curve.iter().cloned().fold(0.0, f64::max);
                    curve.iter_mut().for_each(|v| *v = v.max(1e-3 * peak));
                    Some((lb, curve))
                })
                .collect();
            let active = n_gratings == 1 || grating.n1 > 0.0;
            (shapes, active)
        })
        .collect();
    // Without index modulation nothing is Bragg-selective: sample the band uniformly.
    let fu = if wg.gratings.as_slice().iter().any(|g| g.n1 > 0.0) {
        sm.uniform_fraction
    } else {
        1.0
    };
    WavelengthSampler::new_multiplexed(
        sm.lambda_min_nm,
        sm.lambda_max_nm,
        fu,
        -TABLE_HALF_WIDTH_NM,
        bin,
        &per_grating,
    )
}

/// Where RCWA tables are cached: `$STSCAM_CACHE_DIR`, else `$XDG_CACHE_HOME/stscam`, else
/// `$HOME/.cache/stscam` (None if none is set: tables are then built for every run).
pub fn rcwa_cache_dir() -> Option<std::path::PathBuf> {
    let var = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
    var("STSCAM_CACHE_DIR")
        .map(Into::into)
        .or_else(|| var("XDG_CACHE_HOME").map(|d| std::path::PathBuf::from(d).join("stscam")))
        .or_else(|| var("HOME").map(|d| std::path::PathBuf::from(d).join(".cache/stscam")))
}

/// Off-grid points per grating at which a new RCWA table's interpolation error is measured.
pub const RCWA_ERROR_PROBES: usize = 200;

/// The RCWA coupling grid of a camera: over its field (every crop corner through the
/// aperture's edge, plus a margin of 0.01 in u), with [`CouplingGrid::for_field`]'s spacing.
pub fn rcwa_grid(cam: &Camera) -> crate::optics::rcwa::coupling::CouplingGrid {
    let (hw, hh) = (
        0.5 * cam.width_px as f64 * cam.pitch_mm,
        0.5 * cam.height_px as f64 * cam.pitch_mm,
    );
    let r = cam.aperture_radius_mm;
    let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    for sx in [-hw, hw] {
        for sy in [-hh, hh] {
            for lens in [
                DVec2::ZERO,
                DVec2::new(r, 0.0),
                DVec2::new(-r, 0.0),
                DVec2::new(0.0, r),
                DVec2::new(0.0, -r),
            ] {
                let ray = cam.ray_through(DVec2::new(sx, sy) + cam.offset_px * cam.pitch_mm, lens);
                let u = -ray.dir.truncate();
                lo = lo.min(u);
                hi = hi.max(u);
            }
        }
    }
    crate::optics::rcwa::coupling::CouplingGrid::for_field(lo - 0.01, hi + 0.01)
}

/// The RCWA coupling tables of `hoe.model = "rcwa"` over the camera's field ([`rcwa_grid`]),
/// loaded from the cache ([`rcwa_cache_dir`]) or built.
fn build_rcwa(
    ls: &LoadedScene,
    wg: &Waveguide,
    cam: &Camera,
) -> Result<crate::optics::rcwa::coupling::RcwaCouplings, SceneError> {
    let store = rcwa_cache_dir().map(crate::io::DirStore::new);
    crate::optics::rcwa::coupling::RcwaCouplings::load_or_build(
        store
            .as_ref()
            .map(|s| s as &dyn stscam_base::store::BlobStore),
        &wg.gratings,
        &rcwa_grid(cam),
        &crate::optics::rcwa::Settings::default(),
        RCWA_ERROR_PROBES,
        &crate::cancel::current(),
    )
    .map_err(|e| ls.relation_error(&["hoe.model"], format!("hoe.model = \"rcwa\": {e}")))
}

impl System {
    /// Builds the runtime system from a validated scene (loads the display image).
    pub fn build(ls: &LoadedScene) -> Result<System, SceneError> {
        let s = &ls.scene;
        let mut waveguide = build_waveguide(s);
        let camera = build_camera(s, &waveguide);
        if !(camera.focus_distance_mm > camera.focal_length_mm
            && camera.sensor_distance_mm.is_finite())
        {
            return Err(ls.relation_error(
                &[
                    "camera.focus_distance_mm",
                    "camera.focal_length_mm",
                    "display.distance_mm",
                    "camera.distance_mm",
                ],
                format!(
                    "the focus distance ({} mm) must exceed the focal length ({} mm)",
                    crate::numfmt::sig6(camera.focus_distance_mm),
                    crate::numfmt::sig6(camera.focal_length_mm)
                ),
            ));
        }
        let display = build_display(ls)?;
        if s.hoe.model == crate::optics::GratingModel::Rcwa {
            waveguide.rcwa = Some(std::sync::Arc::new(build_rcwa(ls, &waveguide, &camera)?));
        }
        let r = spectra::sensor_response(response_kind(&s.sensor.response));
        let (lo, hi) = (s.sampling.lambda_min_nm, s.sampling.lambda_max_nm);
        let inv_integral: Vec<f64> = r
            .curves
            .iter()
            .map(|c| {
                let i = c.integral(lo, hi);
                if i > 0.0 { 1.0 / i } else { 0.0 }
            })
            .collect();
        if inv_integral.contains(&0.0) {
            return Err(ls.relation_error(
                &[
                    "sensor.response",
                    "sampling.lambda_min_nm",
                    "sampling.lambda_max_nm",
                ],
                format!(
                    "sensor.response has no sensitivity in the band {}-{} nm",
                    crate::numfmt::sig6(lo),
                    crate::numfmt::sig6(hi)
                ),
            ));
        }
        let response = Response {
            names: r.channel_names,
            curves: r.curves,
            inv_integral,
        };
        let limits = TraceLimits {
            min_weight: s.sampling.min_guided_weight,
            max_contacts: s.sampling.max_contacts,
        };
        let wavelengths = build_wavelength_sampler(s, &waveguide, &camera, &display, limits);
        let world = if s.has_world() {
            Some(std::sync::Arc::new(crate::world::World::build(
                ls, &display,
            )?))
        } else {
            None
        };
        Ok(System {
            scene: s.clone(),
            waveguide,
            camera,
            display,
            response,
            wavelengths,
            limits,
            world,
        })
    }
}

/// Tests: the system of the repository's scene file `scene` (relative to the crate root, e.g.
/// `scenes/eye-contact.toml`) with the overrides `sets` (as `--set`); panics on an error, so
/// for tests only.
#[doc(hidden)]
pub fn repo_system(scene: &str, sets: &[&str]) -> System {
    let path = stscam_base::repo_dir().join(scene);
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    System::build(&crate::scene::load_scene(Some(&path), &sets).expect("scene")).expect("system")
}
