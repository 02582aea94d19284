//! 16-bit PNG encoding and a simple tone map that turns linear float channels
//! into sRGB-encoded 16-bit preview samples.

use png::{BitDepth, ColorType, Encoder};

/// How a PNG's samples encode light, written as the colour chunks viewers read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PngTransfer {
    /// sRGB-encoded previews: an `sRGB` chunk (perceptual) and its fallback `gAMA` 1/2.2
    /// (45455).
    Srgb,
    /// Linear values (e.g. dataset captures scaled to full scale): `gAMA` 1.0 (100000).
    Linear,
    /// Display code values of a display with this gamma (object targets): `gAMA` 1/γ.
    DisplayGamma(f64),
    /// Integer labels (masks), not light: no colour chunk.
    Labels,
}

/// Encodes a 16-bit grayscale (`channels == 1`) or RGB (`channels == 3`) PNG in
/// memory. `samples` are interleaved pixel-major, row 0 at the top; `transfer` says how they
/// encode light (`sRGB`/`gAMA` chunks). The output has no time or other optional chunks, so it
/// is deterministic.
pub fn encode_png16(
    width: usize,
    height: usize,
    channels: usize,
    samples: &[u16],
    transfer: PngTransfer,
) -> Result<Vec<u8>, String> {
    let color = match channels {
        1 => ColorType::Grayscale,
        3 => ColorType::Rgb,
        _ => {
            return Err(format!(
                "PNG needs 1 (gray) or 3 (RGB) channels, got {channels}"
            ));
        }
    };
    let (w, h) = match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h)) if w > 0 && h > 0 => (w, h),
        _ => return Err(format!("invalid PNG size {width}x{height}")),
    };
    let expected = width
        .checked_mul(height)
        .and_then(|n| n.checked_mul(channels))
        .ok_or_else(|| format!("PNG size {width}x{height} is too large"))?;
    if samples.len() != expected {
        return Err(format!(
            "PNG {width}x{height}x{channels} needs {expected} samples, got {}",
            samples.len()
        ));
    }
    let data: Vec<u8> = samples.iter().flat_map(|s| s.to_be_bytes()).collect();
    let mut out = Vec::new();
    let mut encoder = Encoder::new(&mut out, w, h);
    encoder.set_color(color);
    encoder.set_depth(BitDepth::Sixteen);
    match transfer {
        PngTransfer::Srgb => {
            encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
            encoder.set_source_gamma(png::ScaledFloat::from_scaled(45455));
        }
        PngTransfer::Linear => encoder.set_source_gamma(png::ScaledFloat::from_scaled(100_000)),
        PngTransfer::DisplayGamma(g) if g.is_finite() && g > 0.0 => {
            // gAMA stores round(100000 / γ).
            encoder.set_source_gamma(png::ScaledFloat::from_scaled((1e5 / g).round() as u32));
        }
        PngTransfer::DisplayGamma(_) | PngTransfer::Labels => {}
    }
    // fdeflate: several times faster than the default level (datasets write a 440×440 capture
    // PNG per sample) for files about 10–20 % larger.
    encoder.set_compression(png::Compression::Fast);
    let mut writer = encoder
        .write_header()
        .map_err(|e| format!("cannot encode PNG: {e}"))?;
    writer
        .write_image_data(&data)
        .and_then(|()| writer.finish())
        .map_err(|e| format!("cannot encode PNG: {e}"))?;
    Ok(out)
}

/// Tone-maps linear float channels to sRGB-encoded 16-bit preview samples,
/// interleaved pixel-major (`r, g, b, r, g, b, …` for three channels).
///
/// The scale maps the `percentile` (in `[0, 1]`, e.g. `0.999`) of all finite
/// values over all channels to 1.0; the percentile is the sorted value at index
/// `round(percentile * (n - 1))`. If that value is not positive the maximum is
/// used instead; if that is not positive either, the output is all zeros.
/// Scaled values are clamped to `[0, 1]`, passed through the sRGB OETF and
/// rounded to `0..=65535`. Non-finite values map to 0. If the channels differ
/// in length, the shortest length is used.
pub fn preview_u16(channels: &[&[f32]], percentile: f64) -> Vec<u16> {
    let n = channels.iter().map(|c| c.len()).min().unwrap_or(0);
    let mut finite: Vec<f32> = channels
        .iter()
        .flat_map(|c| c[..n].iter().copied())
        .filter(|v| v.is_finite())
        .collect();
    let mut reference = 0.0_f64;
    if !finite.is_empty() {
        let p = if percentile.is_nan() {
            1.0
        } else {
            percentile.clamp(0.0, 1.0)
        };
        let index = (p * (finite.len() - 1) as f64).round() as usize;
        let (_, value, _) = finite.select_nth_unstable_by(index, f32::total_cmp);
        reference = f64::from(*value);
        if reference <= 0.0 {
            reference = finite
                .iter()
                .copied()
                .fold(0.0_f64, |m, v| m.max(f64::from(v)));
        }
    }
    if reference <= 0.0 {
        return vec![0; n * channels.len()];
    }
    let scale = 1.0 / reference;
    (0..n)
        .flat_map(|i| channels.iter().map(move |c| c[i]))
        .map(|v| {
            if !v.is_finite() {
                return 0;
            }
            let x = (f64::from(v) * scale).clamp(0.0, 1.0);
            (srgb_oetf(x) * 65535.0).round() as u16
        })
        .collect()
}

/// The sRGB opto-electronic transfer function (linear to encoded), on `[0, 1]`.
fn srgb_oetf(x: f64) -> f64 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    fn decode(bytes: Vec<u8>) -> (png::OutputInfo, Vec<u16>) {
        let mut reader = png::Decoder::new(Cursor::new(bytes)).read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        let samples = buf[..info.buffer_size()]
            .chunks_exact(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]))
            .collect();
        (info, samples)
    }

    #[test]
    fn round_trip_preserves_16_bit_values() {
        let rgb: Vec<u16> = (0..4 * 3 * 3)
            .map(|i| (i as u16).wrapping_mul(7919) ^ 0x8001)
            .collect();
        let bytes = encode_png16(4, 3, 3, &rgb, PngTransfer::Srgb).unwrap();
        assert_eq!(
            encode_png16(4, 3, 3, &rgb, PngTransfer::Srgb).unwrap(),
            bytes
        );
        let (info, back) = decode(bytes);
        assert_eq!(
            (info.width, info.height, info.color_type, info.bit_depth),
            (4, 3, ColorType::Rgb, BitDepth::Sixteen)
        );
        assert_eq!(back, rgb);

        let gray = [0, 1, 256, 65535, 40000, 12345];
        let (info, back) = decode(encode_png16(3, 2, 1, &gray, PngTransfer::Linear).unwrap());
        assert_eq!(info.color_type, ColorType::Grayscale);
        assert_eq!(back, gray);
    }

    /// (chunk type, data) of every chunk, read from the raw bytes (independent of the decoder).
    fn chunks(bytes: &[u8]) -> Vec<(String, Vec<u8>)> {
        let mut out = Vec::new();
        let mut i = 8;
        while i + 8 <= bytes.len() {
            let len = u32::from_be_bytes(bytes[i..i + 4].try_into().unwrap()) as usize;
            let kind = String::from_utf8_lossy(&bytes[i + 4..i + 8]).into_owned();
            out.push((kind, bytes[i + 8..i + 8 + len].to_vec()));
            i += 12 + len;
        }
        out
    }

    /// Each transfer writes the colour chunks that describe it, before the image data.
    #[test]
    fn colour_chunks_describe_the_encoding() {
        let gama = |t: PngTransfer| {
            let c = chunks(&encode_png16(2, 1, 1, &[0, 65535], t).unwrap());
            let idat = c.iter().position(|(k, _)| k == "IDAT").unwrap();
            let find = |name: &str| c.iter().position(|(k, _)| k == name);
            if let Some(p) = find("gAMA").or(find("sRGB")) {
                assert!(p < idat);
            }
            (
                find("sRGB").map(|p| c[p].1.clone()),
                find("gAMA").map(|p| u32::from_be_bytes(c[p].1[..4].try_into().unwrap())),
            )
        };
        assert_eq!(gama(PngTransfer::Srgb), (Some(vec![0]), Some(45455)));
        assert_eq!(gama(PngTransfer::Linear), (None, Some(100_000)));
        assert_eq!(gama(PngTransfer::DisplayGamma(2.2)), (None, Some(45455)));
        assert_eq!(gama(PngTransfer::DisplayGamma(1.8)), (None, Some(55556)));
        assert_eq!(gama(PngTransfer::Labels), (None, None));
    }

    #[test]
    fn encode_rejects_bad_arguments() {
        assert!(encode_png16(2, 2, 2, &[0; 8], PngTransfer::Labels).is_err());
        assert!(encode_png16(2, 2, 1, &[0; 3], PngTransfer::Labels).is_err());
        assert!(encode_png16(0, 2, 1, &[], PngTransfer::Labels).is_err());
    }

    #[test]
    fn srgb_half_and_extremes() {
        let out = preview_u16(&[&[0.5, 1.0, 0.0]], 1.0);
        assert!((i32::from(out[0]) - 48193).abs() <= 1, "{}", out[0]);
        assert_eq!(&out[1..], &[65535, 0]);
    }

    #[test]
    fn preview_is_monotonic_and_interleaved() {
        let ramp: Vec<f32> = (0..200).map(|i| i as f32 * 0.01).collect();
        let out = preview_u16(&[&ramp], 1.0);
        assert!(out.windows(2).all(|w| w[0] <= w[1]));
        assert!(out.windows(2).filter(|w| w[0] < w[1]).count() > 190);

        let (r, g, b) = ([1.0_f32, 0.0], [0.0_f32, 0.0], [0.0_f32, 1.0]);
        assert_eq!(preview_u16(&[&r, &g, &b], 1.0), [65535, 0, 0, 0, 0, 65535]);
    }

    #[test]
    fn percentile_sets_the_white_point() {
        // 1000 values 0..=999 and one huge outlier: the 0.999 percentile is 999.
        let mut values: Vec<f32> = (0..1000).map(|i| i as f32).collect();
        values.push(1e9);
        let out = preview_u16(&[&values], 0.999);
        assert_eq!(out[999], 65535);
        assert_eq!(out[1000], 65535);
        assert!(out[998] < 65535);
        let expected = (srgb_oetf(500.0 / 999.0) * 65535.0).round() as u16;
        assert_eq!(out[500], expected);
    }

    #[test]
    fn degenerate_inputs() {
        assert_eq!(preview_u16(&[&[0.0, 0.0]], 0.999), [0, 0]);
        // Percentile is zero but the maximum is positive: the maximum is used.
        let out = preview_u16(&[&[0.0, 0.0, 0.0, 2.0]], 0.5);
        assert_eq!(out, [0, 0, 0, 65535]);
        // Non-finite values are 0 and ignored for scaling.
        let out = preview_u16(&[&[f32::NAN, f32::INFINITY, 4.0, -1.0]], 1.0);
        assert_eq!(out, [0, 0, 65535, 0]);
        assert!(preview_u16(&[], 0.5).is_empty());
    }
}
