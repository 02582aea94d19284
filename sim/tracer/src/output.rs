//! Writing a capture: `capture.exr` (linear float32, `Y` or `R`,`G`,`B`, optional spectral
//! channels `S0.<nm>,<frac>nm`), `capture.png` (16-bit sRGB-encoded preview scaled to the
//! 99.9th percentile) and `capture.json` (scene after overrides, seed, spp, version, timings).
//!
//! Every file is encoded in memory first; the three are written under temporary names and
//! renamed into place only when all writes succeeded, so a failure leaves nothing new behind. The EXR holds no timestamps or timings: equal inputs give
//! byte-identical EXR files.

use std::path::Path;

use crate::io::{
    ExrAttr, ExrChannel, IoError, PngTransfer, encode_exr, encode_png16, preview_u16,
    spectral_channel_name, write_all_atomic,
};
use crate::render::Capture;

/// What one pixel value means (recorded in the EXR header and the JSON sidecar).
pub const CAPTURE_UNITS: &str = "relative irradiance: 1 = a white display pixel seen by an on-axis pixel through lossless optics with a vanishing aperture (flat spectrum and response); the finite aperture and the field angle add the cos^4 falloff. Spectral channels S0.<nm> (--spectral) hold the same relative quantity per nm, before the sensor response (no absolute W.m^-2.sr^-1.nm^-1)";

/// EXR channels from names and data (cloned).
fn named_channels(names: &[&str], data: &[Vec<f32>]) -> Vec<ExrChannel> {
    names
        .iter()
        .zip(data)
        .map(|(n, d)| ExrChannel {
            name: (*n).to_string(),
            data: d.clone(),
        })
        .collect()
}

/// The header attributes every stscam EXR carries: version, seed, units and the scene.
fn header_attrs(seed: u64, units: &str, scene_json: &str) -> Vec<(String, ExrAttr)> {
    vec![
        (
            "stscam.version".to_string(),
            ExrAttr::Text(crate::VERSION.to_string()),
        ),
        ("stscam.seed".to_string(), ExrAttr::Text(seed.to_string())),
        ("stscam.units".to_string(), ExrAttr::Text(units.to_string())),
        (
            "stscam.scene".to_string(),
            ExrAttr::Text(scene_json.to_string()),
        ),
    ]
}

/// Encodes the capture as an EXR file in memory.
pub fn encode_capture_exr(
    cap: &Capture,
    scene_json: &str,
    seed: u64,
    spp: u32,
) -> Result<Vec<u8>, String> {
    let mut channels = named_channels(&cap.channel_names, &cap.channels);
    for (lambda, data) in &cap.spectral {
        channels.push(ExrChannel {
            name: spectral_channel_name(*lambda),
            data: data.clone(),
        });
    }
    let mut attrs = header_attrs(seed, CAPTURE_UNITS, scene_json);
    attrs.insert(
        2,
        (
            "stscam.spp".to_string(),
            ExrAttr::I32(i32::try_from(spp).unwrap_or(i32::MAX)),
        ),
    );
    encode_exr(cap.width, cap.height, channels, &attrs)
}

/// Encodes the 16-bit PNG preview (grey for one channel, RGB for three).
pub fn encode_capture_png(cap: &Capture) -> Result<Vec<u8>, String> {
    let refs: Vec<&[f32]> = cap.channels.iter().map(|c| c.as_slice()).collect();
    let samples = preview_u16(&refs, 0.999);
    encode_png16(
        cap.width,
        cap.height,
        refs.len(),
        &samples,
        PngTransfer::Srgb,
    )
}

/// Writes `capture.exr`, `capture.png` and `capture.json` into `dir` (created if needed).
pub fn write_capture(
    dir: &Path,
    cap: &Capture,
    scene_json: &str,
    seed: u64,
    spp: u32,
    sidecar: &serde_json::Value,
) -> Result<(), IoError> {
    write_capture_with(dir, cap, scene_json, seed, spp, sidecar, None)
}

/// What the frontal ground truth's pixels mean.
pub const FRONTAL_UNITS: &str = "spectral radiance weighted by the sensor response, in the capture unit (1 = a white display pixel), seen by an ideal pinhole at the front face at the bottom vHOE's centre over the capture's angular field; no waveguide, lens falloff or noise";

/// Where the frontal ground truth is seen from (the part of [`FRONTAL_UNITS`] after the unit).
const FRONTAL_VIEW: &str = "seen by an ideal pinhole at the front face at the bottom vHOE's centre over the capture's angular field; no waveguide, lens falloff or noise";

/// What the frontal ground truth's pixels mean in `space` ([`FRONTAL_UNITS`] for the sensor's).
pub fn frontal_units(space: crate::world::colour::FrontalSpace) -> String {
    format!("{}, {FRONTAL_VIEW}", space.units())
}

fn fmt_err(path: std::path::PathBuf) -> impl Fn(String) -> IoError {
    move |m| IoError::Format {
        path: path.clone(),
        message: m,
    }
}

/// Linear sRGB channels for the preview of an XYZ frontal image (None: preview the channels).
fn frontal_preview_channels(f: &crate::frontal::Frontal) -> Option<Vec<Vec<f32>>> {
    use crate::world::colour::{FrontalSpace, XYZ_TO_LINEAR_SRGB, mat3};
    if f.space != FrontalSpace::Xyz || f.channels.len() != 3 {
        return None;
    }
    let rgb: Vec<[f64; 3]> = (0..f.width * f.height)
        .map(|i| {
            mat3(
                &XYZ_TO_LINEAR_SRGB,
                [0, 1, 2].map(|k| f64::from(f.channels[k][i])),
            )
        })
        .collect();
    Some(
        (0..3)
            .map(|k| rgb.iter().map(|v| v[k] as f32).collect())
            .collect(),
    )
}

/// As [`write_capture`], plus (for 3-D scenes) `frontal.exr`, `frontal.png`, `depth.exr` and
/// `mask.png` (16-bit grey: object index + 1, 65535 the display, 0 nothing), all or nothing.
pub fn write_capture_with(
    dir: &Path,
    cap: &Capture,
    scene_json: &str,
    seed: u64,
    spp: u32,
    sidecar: &serde_json::Value,
    frontal: Option<&crate::frontal::Frontal>,
) -> Result<(), IoError> {
    let exr =
        encode_capture_exr(cap, scene_json, seed, spp).map_err(fmt_err(dir.join("capture.exr")))?;
    let png = encode_capture_png(cap).map_err(fmt_err(dir.join("capture.png")))?;
    let json = serde_json::to_vec_pretty(sidecar).map_err(|e| IoError::Format {
        path: dir.join("capture.json"),
        message: e.to_string(),
    })?;
    let mut files: Vec<(&str, Vec<u8>)> = vec![
        ("capture.exr", exr),
        ("capture.png", png),
        ("capture.json", json),
    ];
    if let Some(f) = frontal {
        let attrs = |units: &str| header_attrs(seed, units, scene_json);
        let chans = named_channels(&f.channel_names, &f.channels);
        let fexr = encode_exr(f.width, f.height, chans, &attrs(&frontal_units(f.space)))
            .map_err(fmt_err(dir.join("frontal.exr")))?;
        let srgb = frontal_preview_channels(f);
        let refs: Vec<&[f32]> = srgb
            .as_ref()
            .unwrap_or(&f.channels)
            .iter()
            .map(|c| c.as_slice())
            .collect();
        let fpng = encode_png16(
            f.width,
            f.height,
            refs.len(),
            &preview_u16(&refs, 0.999),
            PngTransfer::Srgb,
        )
        .map_err(fmt_err(dir.join("frontal.png")))?;
        let dexr = encode_exr(
            f.width,
            f.height,
            vec![ExrChannel {
                name: "Z".to_string(),
                data: f.depth_mm.clone(),
            }],
            &attrs("distance from the plate's front face along -z, mm; +inf where nothing is hit"),
        )
        .map_err(fmt_err(dir.join("depth.exr")))?;
        let mpng = encode_png16(f.width, f.height, 1, &f.mask, PngTransfer::Labels)
            .map_err(fmt_err(dir.join("mask.png")))?;
        files.push(("frontal.exr", fexr));
        files.push(("frontal.png", fpng));
        files.push(("depth.exr", dexr));
        files.push(("mask.png", mpng));
    }
    let refs: Vec<(&str, &[u8])> = files.iter().map(|(n, b)| (*n, b.as_slice())).collect();
    write_all_atomic(dir, &refs)?;
    Ok(())
}

/// Writes `H.npz` (scipy CSR), `offset.npy` and `H.json` into `dir`, all or nothing.
pub fn write_matrix(
    dir: &Path,
    m: &crate::matrix::SystemMatrix,
    sidecar: &serde_json::Value,
) -> Result<(), IoError> {
    let npz = crate::io::npz::encode_csr(&m.h, &dir.join("H.npz"))?;
    let off =
        crate::io::npz::encode_npy_f32(&dir.join("offset.npy"), &[m.offset.len()], &m.offset)?;
    let json = serde_json::to_vec_pretty(sidecar).map_err(|e| IoError::Format {
        path: dir.join("H.json"),
        message: e.to_string(),
    })?;
    write_all_atomic(
        dir,
        &[("H.npz", &npz), ("offset.npy", &off), ("H.json", &json)],
    )
}

/// Encodes object intensities (linear, 0 = black, 1 = white display pixel) as a 16-bit grey
/// PNG of display code values V = clamp(f, 0, 1)^(1/γ): the PNG shown on the scene's display
/// reproduces the object.
pub fn encode_object_png(
    intensity: &[f64],
    width: usize,
    height: usize,
    gamma: f64,
) -> Result<Vec<u8>, String> {
    let samples: Vec<u16> = intensity
        .iter()
        .map(|&v| (v.clamp(0.0, 1.0).powf(1.0 / gamma) * 65535.0).round() as u16)
        .collect();
    encode_png16(width, height, 1, &samples, PngTransfer::DisplayGamma(gamma))
}

/// Encodes object intensities as a linear float32 EXR with one `Y` channel (not clipped).
pub fn encode_object_exr(
    intensity: &[f64],
    width: usize,
    height: usize,
    attrs: &[(String, ExrAttr)],
) -> Result<Vec<u8>, String> {
    encode_exr(
        width,
        height,
        vec![ExrChannel {
            name: "Y".to_string(),
            data: intensity.iter().map(|&v| v as f32).collect(),
        }],
        attrs,
    )
}

/// Encodes a colour object (three planes R, G, B, primary-major, `width`×`height` each) as a
/// 16-bit RGB PNG with the display gamma applied (clipped to [0, 1]).
pub fn encode_colour_object_png(
    planes: &[f64],
    width: usize,
    height: usize,
    gamma: f64,
) -> Result<Vec<u8>, String> {
    let n = width * height;
    let samples: Vec<u16> = (0..n)
        .flat_map(|k| (0..3).map(move |p| planes.get(p * n + k).copied().unwrap_or(0.0)))
        .map(|v| (v.clamp(0.0, 1.0).powf(1.0 / gamma) * 65535.0).round() as u16)
        .collect();
    encode_png16(width, height, 3, &samples, PngTransfer::DisplayGamma(gamma))
}

/// Encodes a colour object (three planes R, G, B, primary-major) as a linear float32 EXR with
/// channels `R`, `G`, `B` (not clipped).
pub fn encode_colour_object_exr(
    planes: &[f64],
    width: usize,
    height: usize,
) -> Result<Vec<u8>, String> {
    let n = width * height;
    let channels = crate::matrix::PRIMARY_NAMES
        .iter()
        .enumerate()
        .map(|(p, name)| ExrChannel {
            name: name.to_string(),
            data: (0..n)
                .map(|k| planes.get(p * n + k).copied().unwrap_or(0.0) as f32)
                .collect(),
        })
        .collect();
    encode_exr(width, height, channels, &[])
}

#[cfg(test)]
mod tests {
    #[test]
    fn sensor_units_keep_the_old_text() {
        assert_eq!(
            crate::output::frontal_units(crate::world::colour::FrontalSpace::Sensor),
            crate::output::FRONTAL_UNITS
        );
        assert_eq!(
            crate::world::colour::FrontalSpace::parse("linear-srgb"),
            Some(crate::world::colour::FrontalSpace::LinearSrgb)
        );
        assert_eq!(crate::world::colour::FrontalSpace::parse("rgb"), None);
    }
}
