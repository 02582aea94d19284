//! Validation of a loaded scene: ranges, names and the relations between keys; every failure
//! names its key and where the value came from.

use crate::error::SceneError;
use crate::numfmt::sig6;
use crate::scene::{
    AutoOr, GlassSpec, LoadedScene, MAX_GRATINGS, PolarizationSpec, SINGLE_GRATING_KEYS, blame,
};

/// Names of the glasses `plate.glass` accepts.
pub const GLASS_NAMES: &[&str] = &["soda-lime", "n-bk7"];
/// Names `sensor.response` accepts.
pub const RESPONSE_NAMES: &[&str] = &["mono-qe", "mono-bayer-y", "flat", "rgb-bayer"];
/// Names `display.primaries` accepts.
pub const PRIMARIES_NAMES: &[&str] = &["none", "lcd"];

/// Names `display.spectrum` accepts.
pub const SPECTRUM_NAMES: &[&str] = &["white-led", "flat", "ccfl"];

fn check(
    ls: &LoadedScene,
    ok: bool,
    key: &str,
    message: impl FnOnce() -> String,
) -> Result<(), SceneError> {
    if ok {
        Ok(())
    } else {
        Err(ls.key_error(key, message()))
    }
}

fn positive(ls: &LoadedScene, v: f64, key: &str) -> Result<(), SceneError> {
    check(ls, v.is_finite() && v > 0.0, key, || {
        format!("must be a positive finite number, got {}", sig6(v))
    })
}

fn in_range(ls: &LoadedScene, v: f64, lo: f64, hi: f64, key: &str) -> Result<(), SceneError> {
    check(ls, v.is_finite() && v >= lo && v <= hi, key, || {
        format!("must be in [{}, {}], got {}", sig6(lo), sig6(hi), sig6(v))
    })
}

/// Checks ranges and names; every failure names its key. The sections are checked in the
/// order of the scene file; the first failure is reported.
pub fn validate(ls: &LoadedScene) -> Result<(), SceneError> {
    validate_plate(ls)?;
    validate_hoe(ls)?;
    validate_hoe_areas(ls)?;
    validate_haze(ls)?;
    validate_camera(ls)?;
    validate_sensor(ls)?;
    validate_display(ls)?;
    validate_behind_display(ls)?;
    validate_sampling(ls)?;
    validate_noise(ls)?;
    let sm = &ls.scene.sampling;
    check(
        ls,
        (1..=64).contains(&sm.max_depth),
        "sampling.max_depth",
        || format!("must be in [1, 64], got {}", sm.max_depth),
    )?;
    crate::desc::validate_world(&ls.scene.object, &ls.scene.light)
        .map_err(|p| ls.key_error(&p.key, p.message))?;
    Ok(())
}

/// `[plate]`: thickness, glass and absorption.
fn validate_plate(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    positive(ls, s.plate.thickness_mm, "plate.thickness_mm")?;
    match &s.plate.glass {
        GlassSpec::Index(n) => in_range(ls, *n, 1.0, 4.0, "plate.glass")?,
        GlassSpec::Name(name) => check(
            ls,
            GLASS_NAMES.contains(&name.as_str()),
            "plate.glass",
            || format!("unknown glass {name:?}; expected one of {GLASS_NAMES:?} or a number"),
        )?,
    }
    match &s.plate.absorption_per_mm {
        AutoOr::Value(a) => in_range(ls, *a, 0.0, 1e3, "plate.absorption_per_mm")?,
        AutoOr::Word(w) => check(ls, w == "auto", "plate.absorption_per_mm", || {
            format!("expected \"auto\" or a number, got {w:?}")
        })?,
    }
    let edges = &s.plate.edges;
    check(
        ls,
        edges == "absorbing" || edges == "polished",
        "plate.edges",
        || format!("expected \"absorbing\" or \"polished\", got {edges:?}"),
    )?;
    check(
        ls,
        s.plate
            .size_mm
            .iter()
            .all(|v| v.is_finite() && *v > 0.0 && *v <= 1e4),
        "plate.size_mm",
        || "must be positive, at most 1e4 mm".into(),
    )?;
    check(
        ls,
        s.plate
            .center_mm
            .iter()
            .all(|v| v.is_finite() && v.abs() <= 1e4),
        "plate.center_mm",
        || "must be finite, within ±1e4 mm".into(),
    )?;
    Ok(())
}

/// The sizes of the bottom and top vHOEs and the gap between them.
fn validate_hoe_areas(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    positive(ls, s.bottom_hoe.width_mm, "bottom_hoe.width_mm")?;
    positive(ls, s.bottom_hoe.height_mm, "bottom_hoe.height_mm")?;
    positive(ls, s.top_hoe.width_mm, "top_hoe.width_mm")?;
    positive(ls, s.top_hoe.height_mm, "top_hoe.height_mm")?;
    in_range(ls, s.top_hoe.gap_mm, 0.0, 1e4, "top_hoe.gap_mm")?;
    Ok(())
}

/// `[camera]`: distance, lens and focus.
fn validate_camera(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    positive(ls, s.camera.distance_mm, "camera.distance_mm")?;
    positive(ls, s.camera.focal_length_mm, "camera.focal_length_mm")?;
    positive(ls, s.camera.f_number, "camera.f_number")?;
    match &s.camera.focus_distance_mm {
        AutoOr::Value(v) => check(
            ls,
            v.is_finite() && *v > s.camera.focal_length_mm,
            blame(ls, &["camera.focus_distance_mm", "camera.focal_length_mm"]),
            || {
                format!(
                    "camera.focus_distance_mm ({} mm) must exceed camera.focal_length_mm ({} mm)",
                    sig6(*v),
                    sig6(s.camera.focal_length_mm)
                )
            },
        )?,
        AutoOr::Word(w) => check(ls, w == "auto", "camera.focus_distance_mm", || {
            format!("expected \"auto\" or a number, got {w:?}")
        })?,
    }
    Ok(())
}

/// `[sensor]`: size, pitch, the crop within the sensor and the response.
fn validate_sensor(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    check(
        ls,
        s.sensor.width_px > 0 && s.sensor.height_px > 0,
        "sensor.width_px",
        || "sensor size must be positive".into(),
    )?;
    positive(ls, s.sensor.pitch_um, "sensor.pitch_um")?;
    let (cw, ch) = s.sensor.crop_px.size();
    check(
        ls,
        cw > 0 && ch > 0 && cw <= 8192 && ch <= 8192,
        "sensor.crop_px",
        || format!("crop {cw}x{ch} must be 1..=8192 pixels each way"),
    )?;
    let [ox, oy] = s.sensor.crop_offset_px;
    let fits = |crop: u32, off: i32, full: u32| {
        i64::from(crop) + 2 * i64::from(off).abs() <= i64::from(full)
    };
    check(
        ls,
        fits(cw, ox, s.sensor.width_px) && fits(ch, oy, s.sensor.height_px),
        blame(
            ls,
            &[
                "sensor.crop_px",
                "sensor.crop_offset_px",
                "sensor.width_px",
                "sensor.height_px",
            ],
        ),
        || {
            format!(
                "crop {cw}x{ch} offset [{ox}, {oy}] does not fit the {}x{} sensor",
                s.sensor.width_px, s.sensor.height_px
            )
        },
    )?;
    check(
        ls,
        RESPONSE_NAMES.contains(&s.sensor.response.as_str()),
        "sensor.response",
        || {
            format!(
                "unknown response {:?}; expected one of {RESPONSE_NAMES:?}",
                s.sensor.response
            )
        },
    )?;
    Ok(())
}

/// The film's haze lobe.
fn validate_haze(ls: &LoadedScene) -> Result<(), SceneError> {
    let h = &ls.scene.hoe;
    in_range(ls, h.haze_fraction, 0.0, 0.5, "hoe.haze_fraction")?;
    in_range(ls, h.haze_asymmetry, -0.99, 0.99, "hoe.haze_asymmetry")
}

/// `[behind_display]`: a finite plate behind the back face with a finite area and radiance.
fn validate_behind_display(ls: &LoadedScene) -> Result<(), SceneError> {
    let b = &ls.scene.behind_display;
    in_range(ls, b.distance_mm, 1e-3, 1e4, "behind_display.distance_mm")?;
    check(
        ls,
        b.center_mm.iter().all(|v| v.is_finite() && v.abs() <= 1e4),
        "behind_display.center_mm",
        || "must be finite, within ±1e4 mm".into(),
    )?;
    check(
        ls,
        b.size_mm
            .iter()
            .all(|v| v.is_finite() && *v > 0.0 && *v <= 1e4),
        "behind_display.size_mm",
        || "must be positive, at most 1e4 mm".into(),
    )?;
    in_range(ls, b.luminance, 0.0, 1e6, "behind_display.luminance")
}

/// `[display]`: geometry, spectrum, primaries, polarisation, gamma, black level and image.
fn validate_display(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    positive(ls, s.display.distance_mm, "display.distance_mm")?;
    positive(ls, s.display.pixel_pitch_mm, "display.pixel_pitch_mm")?;
    check(
        ls,
        s.display.size_px[0] > 0 && s.display.size_px[1] > 0,
        "display.size_px",
        || "must be positive".into(),
    )?;
    check(
        ls,
        s.display.lcd_pixels_per_image_pixel > 0,
        "display.lcd_pixels_per_image_pixel",
        || "must be positive".into(),
    )?;
    check(
        ls,
        s.display.center_mm.iter().all(|v| v.is_finite()),
        "display.center_mm",
        || "must be finite".into(),
    )?;
    check(
        ls,
        SPECTRUM_NAMES.contains(&s.display.spectrum.as_str()),
        "display.spectrum",
        || {
            format!(
                "unknown spectrum {:?}; expected one of {SPECTRUM_NAMES:?}",
                s.display.spectrum
            )
        },
    )?;
    check(
        ls,
        PRIMARIES_NAMES.contains(&s.display.primaries.as_str()),
        "display.primaries",
        || {
            format!(
                "unknown primaries {:?}; expected one of {PRIMARIES_NAMES:?}",
                s.display.primaries
            )
        },
    )?;
    match &s.display.polarization {
        PolarizationSpec::AngleDeg(a) => check(ls, a.is_finite(), "display.polarization", || {
            "angle must be finite".into()
        })?,
        PolarizationSpec::Word(w) => check(ls, w == "none", "display.polarization", || {
            format!("expected \"none\" or an angle in degrees, got {w:?}")
        })?,
    }
    positive(ls, s.display.gamma, "display.gamma")?;
    check(
        ls,
        s.display.black_level >= 0.0 && s.display.black_level < 1.0,
        "display.black_level",
        || format!("must be in [0, 1), got {}", sig6(s.display.black_level)),
    )?;
    check(ls, s.display.image.trim() != "", "display.image", || {
        "must name a file or a built-in target".into()
    })?;
    Ok(())
}

/// Shortest wavelength a scene key (sampling band, recording wavelength) or a command's
/// wavelength argument may name, nm.
pub const MIN_WAVELENGTH_NM: f64 = 200.0;

/// Longest wavelength a scene key or a command's wavelength argument may name, nm.
pub const MAX_WAVELENGTH_NM: f64 = 2000.0;

/// `[sampling]`: the wavelength band, the sampling fractions and the contact limit (`max_depth` is checked last, after `[noise]`).
fn validate_sampling(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    let sm = &s.sampling;
    in_range(
        ls,
        sm.lambda_min_nm,
        MIN_WAVELENGTH_NM,
        MAX_WAVELENGTH_NM,
        "sampling.lambda_min_nm",
    )?;
    in_range(
        ls,
        sm.lambda_max_nm,
        MIN_WAVELENGTH_NM,
        MAX_WAVELENGTH_NM,
        "sampling.lambda_max_nm",
    )?;
    check(
        ls,
        sm.lambda_max_nm > sm.lambda_min_nm,
        blame(ls, &["sampling.lambda_max_nm", "sampling.lambda_min_nm"]),
        || "sampling.lambda_max_nm must exceed sampling.lambda_min_nm".into(),
    )?;
    check(
        ls,
        sm.uniform_fraction > 0.0 && sm.uniform_fraction <= 1.0,
        "sampling.uniform_fraction",
        || format!("must be in (0, 1], got {}", sig6(sm.uniform_fraction)),
    )?;
    check(
        ls,
        sm.min_guided_weight > 0.0 && sm.min_guided_weight < 1.0,
        "sampling.min_guided_weight",
        || format!("must be in (0, 1), got {}", sig6(sm.min_guided_weight)),
    )?;
    check(ls, sm.max_contacts >= 1, "sampling.max_contacts", || {
        "must be at least 1".into()
    })?;
    Ok(())
}

/// `[noise]`: full well, exposure, read noise, bit depth and the dark offset within the ADC range.
fn validate_noise(ls: &LoadedScene) -> Result<(), SceneError> {
    let s = &ls.scene;
    let nz = &s.noise;
    positive(ls, nz.full_well_e, "noise.full_well_e")?;
    check(
        ls,
        nz.exposure_fraction > 0.0 && nz.exposure_fraction <= 1.0,
        "noise.exposure_fraction",
        || format!("must be in (0, 1], got {}", sig6(nz.exposure_fraction)),
    )?;
    in_range(ls, nz.read_noise_e, 0.0, 1e6, "noise.read_noise_e")?;
    check(
        ls,
        (1..=24).contains(&nz.bit_depth),
        "noise.bit_depth",
        || format!("must be in [1, 24], got {}", nz.bit_depth),
    )?;
    let full_scale = f64::from((1u32 << nz.bit_depth) - 1);
    check(
        ls,
        nz.dark_offset_dn.is_finite() && nz.dark_offset_dn >= 0.0 && nz.dark_offset_dn < full_scale,
        blame(ls, &["noise.dark_offset_dn", "noise.bit_depth"]),
        || {
            format!(
                "noise.dark_offset_dn must be in [0, {full_scale}) (the ADC range of noise.bit_depth = {}), got {}",
                nz.bit_depth,
                sig6(nz.dark_offset_dn)
            )
        },
    )?;
    // EMVA 1288 terms (all 0: the ideal sensor).
    in_range(
        ls,
        nz.dark_current_e_per_s,
        0.0,
        1e9,
        "noise.dark_current_e_per_s",
    )?;
    in_range(ls, nz.exposure_time_ms, 0.0, 1e7, "noise.exposure_time_ms")?;
    check(
        ls,
        nz.dark_current_e_per_s == 0.0 || nz.exposure_time_ms > 0.0,
        blame(
            ls,
            &["noise.exposure_time_ms", "noise.dark_current_e_per_s"],
        ),
        || {
            format!(
                "noise.dark_current_e_per_s = {} needs noise.exposure_time_ms > 0 (the time the dark current integrates over)",
                sig6(nz.dark_current_e_per_s)
            )
        },
    )?;
    in_range(
        ls,
        nz.temperature_above_reference_k,
        -100.0,
        100.0,
        "noise.temperature_above_reference_k",
    )?;
    in_range(
        ls,
        nz.dark_current_doubling_k,
        0.5,
        100.0,
        "noise.dark_current_doubling_k",
    )?;
    in_range(ls, nz.dsnu_e, 0.0, 1e6, "noise.dsnu_e")?;
    in_range(ls, nz.prnu, 0.0, 0.5, "noise.prnu")?;
    in_range(
        ls,
        nz.hot_pixel_fraction,
        0.0,
        1.0,
        "noise.hot_pixel_fraction",
    )?;
    in_range(ls, nz.hot_pixel_dark_e, 0.0, 1e9, "noise.hot_pixel_dark_e")?;
    check(
        ls,
        nz.mean_dark_e() <= 1e9,
        blame(
            ls,
            &[
                "noise.dark_current_e_per_s",
                "noise.exposure_time_ms",
                "noise.temperature_above_reference_k",
            ],
        ),
        || {
            format!(
                "the mean dark signal (dark current x exposure time, doubled per noise.dark_current_doubling_k) is {} electrons; at most 1e9",
                sig6(nz.mean_dark_e())
            )
        },
    )?;
    Ok(())
}

/// Checks `[hoe]`: the film, and each grating with its key named (`hoe.index_modulation`, or
/// `hoe.grating[1].index_modulation` in a list).
fn validate_hoe(ls: &LoadedScene) -> Result<(), SceneError> {
    let h = &ls.scene.hoe;
    if h.grating.is_empty() {
        for k in SINGLE_GRATING_KEYS {
            let given = match *k {
                "recording_wavelength_nm" => h.recording_wavelength_nm,
                "reference_angle_deg" => h.reference_angle_deg,
                _ => h.index_modulation,
            };
            check(ls, given.is_some(), &format!("hoe.{k}"), || {
                "missing: give it, or list [[hoe.grating]] entries".into()
            })?;
        }
    }
    check(ls, h.grating.len() <= MAX_GRATINGS, "hoe.grating", || {
        format!(
            "{} gratings; a film holds at most {MAX_GRATINGS}",
            h.grating.len()
        )
    })?;
    positive(ls, h.film_thickness_um, "hoe.film_thickness_um")?;
    in_range(ls, h.mean_index, 1.0, 4.0, "hoe.mean_index")?;
    let mut total_n1 = 0.0;
    for (i, g) in h.gratings().iter().enumerate() {
        let key = |f: &str| h.key_of(i, f);
        in_range(
            ls,
            g.recording_wavelength_nm,
            MIN_WAVELENGTH_NM,
            MAX_WAVELENGTH_NM,
            &key("recording_wavelength_nm"),
        )?;
        let ref_key = key("reference_angle_deg");
        check(
            ls,
            g.reference_angle_deg > 0.0 && g.reference_angle_deg < 90.0,
            &ref_key,
            || {
                format!(
                    "must be in (0, 90) degrees, got {}",
                    sig6(g.reference_angle_deg)
                )
            },
        )?;
        let obj_key = key("object_angle_deg");
        check(
            ls,
            g.object_angle_deg > -90.0 && g.object_angle_deg < 90.0,
            &obj_key,
            || {
                format!(
                    "must be in (-90, 90) degrees, got {}",
                    sig6(g.object_angle_deg)
                )
            },
        )?;
        let n1_key = key("index_modulation");
        check(
            ls,
            g.index_modulation >= 0.0 && g.index_modulation < h.mean_index,
            blame(ls, &[n1_key.as_str(), "hoe.mean_index"]),
            || {
                format!(
                    "{n1_key} must be in [0, hoe.mean_index = {}), got {}",
                    sig6(h.mean_index),
                    sig6(g.index_modulation)
                )
            },
        )?;
        total_n1 += g.index_modulation;
        check(
            ls,
            total_n1 < h.mean_index,
            blame(ls, &[n1_key.as_str(), "hoe.mean_index"]),
            || {
                format!(
                    "the gratings' index modulations add up to {} (up to {n1_key}), which must stay below hoe.mean_index = {}",
                    sig6(total_n1),
                    sig6(h.mean_index)
                )
            },
        )?;
    }
    in_range(
        ls,
        h.amplitude_absorption_per_mm,
        0.0,
        1e4,
        "hoe.amplitude_absorption_per_mm",
    )?;
    validate_fabrication(ls)
}

/// Checks the fabrication keys of `[hoe]` and of each grating: ranges, and that the film as
/// fabricated is a film (positive thickness, index in [1, 4], the modulations below it).
fn validate_fabrication(ls: &LoadedScene) -> Result<(), SceneError> {
    let h = &ls.scene.hoe;
    in_range(ls, h.shrinkage, -0.5, 0.5, "hoe.shrinkage")?;
    in_range(ls, h.mean_index_change, -0.5, 0.5, "hoe.mean_index_change")?;
    check(
        ls,
        h.thickness_error_um.is_finite() && h.film_thickness_um + h.thickness_error_um > 0.0,
        blame(ls, &["hoe.thickness_error_um", "hoe.film_thickness_um"]),
        || {
            format!(
                "hoe.film_thickness_um + hoe.thickness_error_um must be positive, got {} + {}",
                sig6(h.film_thickness_um),
                sig6(h.thickness_error_um)
            )
        },
    )?;
    in_range(
        ls,
        h.temperature_change_k,
        -200.0,
        200.0,
        "hoe.temperature_change_k",
    )?;
    for (v, key) in [
        (h.film_expansion_per_k, "hoe.film_expansion_per_k"),
        (h.substrate_expansion_per_k, "hoe.substrate_expansion_per_k"),
        (h.index_change_per_k, "hoe.index_change_per_k"),
    ] {
        in_range(ls, v, -1e-3, 1e-3, key)?;
    }
    let n_eff = h.mean_index + h.mean_index_change + h.index_change_per_k * h.temperature_change_k;
    check(
        ls,
        (1.0..=4.0).contains(&n_eff),
        blame(
            ls,
            &[
                "hoe.mean_index_change",
                "hoe.temperature_change_k",
                "hoe.mean_index",
            ],
        ),
        || {
            format!(
                "the fabricated mean index hoe.mean_index + hoe.mean_index_change + hoe.index_change_per_k * hoe.temperature_change_k = {} must be in [1, 4]",
                sig6(n_eff)
            )
        },
    )?;
    let mut total = 0.0;
    for (i, g) in h.gratings().iter().enumerate() {
        let key = |f: &str| h.key_of(i, f);
        in_range(
            ls,
            g.index_modulation_shortfall,
            -1.0,
            1.0,
            &key("index_modulation_shortfall"),
        )?;
        let err_key = key("reference_angle_error_deg");
        let theta = g.reference_angle_deg + g.reference_angle_error_deg;
        check(
            ls,
            g.reference_angle_error_deg.is_finite() && theta > 0.0 && theta < 90.0,
            &err_key,
            || {
                format!(
                    "the recorded reference angle {} + {} must be in (0, 90) degrees",
                    sig6(g.reference_angle_deg),
                    sig6(g.reference_angle_error_deg)
                )
            },
        )?;
        total += g.index_modulation * (1.0 - g.index_modulation_shortfall);
    }
    check(
        ls,
        total < n_eff,
        blame(
            ls,
            &["hoe.mean_index_change", "hoe.index_modulation_shortfall"],
        ),
        || {
            format!(
                "the fabricated index modulations add up to {}, which must stay below the fabricated mean index {}",
                sig6(total),
                sig6(n_eff)
            )
        },
    )
}
