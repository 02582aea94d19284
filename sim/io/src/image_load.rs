//! Loading of display images from PNG or JPEG (display code values) or OpenEXR (linear
//! values) files.

use std::io::Cursor;
use std::path::Path;

use png::{BitDepth, ColorType, Decoder, Transformations};

use super::exr::decode_exr;
use super::{IoError, MAX_PIXELS};

/// Rec. 709 luma weights for R, G, B.
const LUMA: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// A grey or RGB image: `values[(y * width + x) * channels + c]`, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadedImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Channels per pixel: 1 (grey or luminance) or 3 (R, G, B code values of a PNG).
    pub channels: usize,
    /// Pixel values, row-major, channels interleaved.
    pub values: Vec<f32>,
    /// `true` for linear values (EXR); `false` for display code values in
    /// `[0, 1]` (PNG) to which the caller applies a display gamma.
    pub linear: bool,
    /// Alpha (coverage) per pixel in [0, 1], linear, row-major: a PNG's alpha channel or an
    /// EXR's `A` channel; empty if the image has none (opaque).
    pub alpha: Vec<f32>,
}

/// Loads a `.png`, `.jpg`/`.jpeg` or `.exr` file (extension matched case-insensitively).
///
/// PNG (any bit depth, gray/gray+alpha/RGB/RGBA/palette; alpha is returned apart, in `alpha`):
/// values are code value / maximum code, one channel for grey and three for
/// colour (the caller linearises each with its display gamma before forming
/// luminance), and `linear` is `false`. EXR: channel `Y` if present, else the
/// Rec. 709 luminance of the linear `R`, `G`, `B`, else the only channel, as
/// one channel; `linear` is `true`. JPEG (baseline or progressive, any colour space the
/// decoder converts to RGB): three channels of code value / 255, `linear` is `false`.
pub fn load_image(path: &Path) -> Result<LoadedImage, IoError> {
    load_with(path, exr_to_gray, MAX_PIXELS)
}

/// As [`load_image`], but an EXR with `R`, `G`, `B` channels keeps them (three linear
/// channels) instead of being reduced to luminance: for colour textures.
pub fn load_image_rgb(path: &Path) -> Result<LoadedImage, IoError> {
    load_with(path, exr_to_rgb, MAX_PIXELS)
}

/// As [`load_image_rgb`] for a texture or environment map: at most
/// [`crate::limits::MAX_TEXTURE_PIXELS`] pixels, checked from the header before any pixel
/// buffer is allocated.
pub fn load_texture_image(path: &Path) -> Result<LoadedImage, IoError> {
    load_with(path, exr_to_rgb, crate::limits::MAX_TEXTURE_PIXELS)
}

/// Decodes an image already in memory (for example embedded in a glTF buffer or data URI)
/// whose type is given by `ext` (`png`, `jpg`/`jpeg` or `exr`, case-insensitive), as
/// [`load_image_rgb`] decodes a file of that type, refusing more than `max_pixels` pixels
/// (checked from the header, before the pixels are decoded). `path_for_messages` names the
/// image in errors only; nothing is read from it.
pub fn decode_image_bytes(
    path_for_messages: &Path,
    ext: &str,
    bytes: Vec<u8>,
    max_pixels: usize,
) -> Result<LoadedImage, IoError> {
    let decode: Decode = match ext.to_ascii_lowercase().as_str() {
        "png" => decode_png,
        "jpg" | "jpeg" => decode_jpeg,
        "exr" => exr_to_rgb,
        _ => {
            return Err(IoError::format(
                path_for_messages,
                format!("unsupported image type {ext:?} (supported: png, jpeg, exr)"),
            ));
        }
    };
    let image = decode(path_for_messages, bytes, max_pixels)?;
    if image.width == 0 || image.height == 0 {
        return Err(IoError::format(path_for_messages, "image is empty"));
    }
    Ok(image)
}

type Decode = fn(&Path, Vec<u8>, usize) -> Result<LoadedImage, IoError>;

fn load_with(path: &Path, exr: Decode, max_pixels: usize) -> Result<LoadedImage, IoError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let decode = match ext.as_deref() {
        Some("png") => decode_png,
        Some("jpg" | "jpeg") => decode_jpeg,
        Some("exr") => exr,
        _ => {
            return Err(IoError::format(
                path,
                "unsupported image type (supported extensions: .png, .jpg, .jpeg, .exr)",
            ));
        }
    };
    let bytes = super::input::read_input(path, super::input::MAX_BINARY_BYTES)?;
    let image = decode(path, bytes, max_pixels)?;
    if image.width == 0 || image.height == 0 {
        return Err(IoError::format(path, "image is empty"));
    }
    Ok(image)
}

fn decode_png(path: &Path, bytes: Vec<u8>, max_pixels: usize) -> Result<LoadedImage, IoError> {
    let bad =
        |e: png::DecodingError| IoError::format(path, format!("not a readable PNG file ({e})"));
    let mut decoder = Decoder::new(Cursor::new(bytes));
    decoder.set_transformations(Transformations::EXPAND);
    let mut reader = decoder.read_info().map_err(bad)?;
    let (w, h) = (reader.info().width as usize, reader.info().height as usize);
    if w.saturating_mul(h) > max_pixels {
        return Err(IoError::format(
            path,
            format!("PNG image of {w}x{h} pixels has more than the {max_pixels} accepted"),
        ));
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| IoError::format(path, "PNG image is too large"))?;
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).map_err(bad)?;
    let (width, height) = (info.width as usize, info.height as usize);
    let channels = match info.color_type {
        ColorType::Grayscale => 1,
        ColorType::GrayscaleAlpha => 2,
        ColorType::Rgb => 3,
        ColorType::Rgba => 4,
        ColorType::Indexed => return Err(IoError::format(path, "PNG palette was not expanded")),
    };
    let (bytes_per_sample, max) = match info.bit_depth {
        BitDepth::Eight => (1, 255.0),
        BitDepth::Sixteen => (2, 65535.0),
        d => {
            return Err(IoError::format(
                path,
                format!("unsupported PNG bit depth {d:?}"),
            ));
        }
    };
    let sample = |row: &[u8], i: usize| -> f64 {
        if bytes_per_sample == 1 {
            f64::from(row[i])
        } else {
            f64::from(u16::from_be_bytes([row[2 * i], row[2 * i + 1]]))
        }
    };
    let row_bytes = width * channels * bytes_per_sample;
    if info.line_size < row_bytes || buf.len() < info.line_size * height {
        return Err(IoError::format(path, "PNG row size mismatch"));
    }
    let out_channels = if channels >= 3 { 3 } else { 1 };
    // Grey+alpha and RGBA carry alpha as their last sample (kept apart, linear).
    let has_alpha = channels == 2 || channels == 4;
    let mut values = Vec::with_capacity(width * height * out_channels);
    let mut alpha = Vec::new();
    if has_alpha {
        alpha.reserve_exact(width * height);
    }
    for row in buf.chunks_exact(info.line_size).take(height) {
        for x in 0..width {
            let base = x * channels;
            for c in 0..out_channels {
                values.push((sample(row, base + c) / max) as f32);
            }
            if has_alpha {
                alpha.push((sample(row, base + channels - 1) / max) as f32);
            }
        }
    }
    Ok(LoadedImage {
        width,
        height,
        channels: out_channels,
        values,
        linear: false,
        alpha,
    })
}

/// Reads only the header of a PNG or JPEG file and returns its (width, height): a cheap check
/// that a file [`load_image`] will be asked for later is an image of a supported kind (the
/// pixel data is not decoded).
pub fn probe_image(path: &Path) -> Result<(usize, usize), IoError> {
    use std::io::BufReader;
    super::input::check_input_file(path, super::input::MAX_BINARY_BYTES)?;
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let size = match ext.as_deref() {
        Some("png") => {
            let reader = Decoder::new(BufReader::new(file))
                .read_info()
                .map_err(|e| IoError::format(path, format!("not a readable PNG file ({e})")))?;
            (reader.info().width as usize, reader.info().height as usize)
        }
        Some("jpg" | "jpeg") => {
            let probed = std::panic::catch_unwind(move || {
                let mut d = zune_jpeg::JpegDecoder::new(BufReader::new(file));
                d.decode_headers().map_err(|e| format!("{e:?}"))?;
                let info = d.info().ok_or("no image header")?;
                Ok::<_, String>((usize::from(info.width), usize::from(info.height)))
            });
            jpeg_result(path, probed)?
        }
        _ => return Err(IoError::format(path, "not a .png, .jpg or .jpeg file")),
    };
    if size.0 == 0 || size.1 == 0 || size.0.saturating_mul(size.1) > MAX_PIXELS {
        return Err(IoError::format(
            path,
            format!("image size {}x{} is empty or too large", size.0, size.1),
        ));
    }
    Ok(size)
}

/// True if `path` has an extension [`load_image`] reads as display code values (PNG, JPEG).
pub fn is_code_value_image(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .is_some_and(|e| matches!(e.as_str(), "png" | "jpg" | "jpeg"))
}

/// The outcome of a JPEG decoder call run under `catch_unwind`: a decoder error or a panic on a
/// malformed file becomes a format error naming the file.
fn jpeg_result<T>(path: &Path, r: std::thread::Result<Result<T, String>>) -> Result<T, IoError> {
    match r {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(IoError::format(
            path,
            format!("not a readable JPEG file ({e})"),
        )),
        Err(_) => Err(IoError::format(
            path,
            "not a readable JPEG file (decoder failure)",
        )),
    }
}

fn decode_jpeg(path: &Path, bytes: Vec<u8>, max_pixels: usize) -> Result<LoadedImage, IoError> {
    use zune_core::bytestream::ZCursor;
    use zune_core::colorspace::ColorSpace;
    use zune_core::options::DecoderOptions;
    let side = (MAX_PIXELS as f64).sqrt() as usize;
    let options = DecoderOptions::default()
        .jpeg_set_out_colorspace(ColorSpace::RGB)
        .set_max_width(side)
        .set_max_height(side);
    // The decoder reports malformed streams as errors; a panic on a hostile file is caught and
    // reported the same way rather than aborting the whole run.
    let decoded = std::panic::catch_unwind(move || {
        let mut decoder = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(bytes), options);
        decoder.decode_headers().map_err(|e| format!("{e:?}"))?;
        let info = decoder.info().ok_or("no image header")?;
        let (w, h) = (usize::from(info.width), usize::from(info.height));
        if w.saturating_mul(h) > max_pixels {
            return Err(format!(
                "image of {w}x{h} pixels has more than the {max_pixels} accepted"
            ));
        }
        let pixels = decoder.decode().map_err(|e| format!("{e:?}"))?;
        let info = decoder.info().ok_or("no image header")?;
        Ok::<_, String>((usize::from(info.width), usize::from(info.height), pixels))
    });
    let (width, height, pixels) = jpeg_result(path, decoded)?;
    if pixels.len() != width * height * 3 {
        return Err(IoError::format(
            path,
            "JPEG decoder returned a buffer of the wrong size",
        ));
    }
    Ok(LoadedImage {
        width,
        height,
        channels: 3,
        values: pixels
            .iter()
            .map(|&v| (f64::from(v) / 255.0) as f32)
            .collect(),
        linear: false,
        alpha: Vec::new(),
    })
}

fn exr_to_rgb(path: &Path, bytes: Vec<u8>, max_pixels: usize) -> Result<LoadedImage, IoError> {
    let (width, height, channels) = decode_exr(path, bytes, max_pixels)?;
    let find = |name: &str| channels.iter().find(|c| c.name == name);
    if let (Some(r), Some(g), Some(b)) = (find("R"), find("G"), find("B")) {
        let values = (0..width * height)
            .flat_map(|i| [r.data[i], g.data[i], b.data[i]])
            .collect();
        return Ok(LoadedImage {
            width,
            height,
            channels: 3,
            values,
            linear: true,
            alpha: find("A")
                .filter(|a| a.data.len() == width * height)
                .map(|a| a.data.clone())
                .unwrap_or_default(),
        });
    }
    gray_from_channels(path, width, height, channels)
}

fn exr_to_gray(path: &Path, bytes: Vec<u8>, max_pixels: usize) -> Result<LoadedImage, IoError> {
    let (width, height, channels) = decode_exr(path, bytes, max_pixels)?;
    gray_from_channels(path, width, height, channels)
}

fn gray_from_channels(
    path: &Path,
    width: usize,
    height: usize,
    mut channels: Vec<super::exr::ExrChannel>,
) -> Result<LoadedImage, IoError> {
    let position = |name: &str| channels.iter().position(|c| c.name == name);
    let values = if let Some(y) = position("Y") {
        channels.swap_remove(y).data
    } else if let (Some(r), Some(g), Some(b)) = (position("R"), position("G"), position("B")) {
        let (r, g, b) = (&channels[r].data, &channels[g].data, &channels[b].data);
        (0..width * height)
            .map(|i| {
                let luma = LUMA[0] * f64::from(r[i])
                    + LUMA[1] * f64::from(g[i])
                    + LUMA[2] * f64::from(b[i]);
                luma as f32
            })
            .collect()
    } else if channels.len() == 1 {
        channels.swap_remove(0).data
    } else {
        let names: Vec<_> = channels.iter().map(|c| c.name.as_str()).collect();
        return Err(IoError::format(
            path,
            format!(
                "EXR has no Y channel, no R,G,B channels and not exactly one channel (channels: {})",
                names.join(", ")
            ),
        ));
    };
    Ok(LoadedImage {
        width,
        height,
        channels: 1,
        values,
        linear: true,
        alpha: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ExrChannel, encode_exr, encode_png16, write_atomic};

    fn png8_gray(width: u32, height: u32, data: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, width, height);
        encoder.set_color(ColorType::Grayscale);
        encoder.set_depth(BitDepth::Eight);
        let mut writer = encoder.write_header().unwrap();
        writer.write_image_data(data).unwrap();
        writer.finish().unwrap();
        out
    }

    #[test]
    fn loads_8_bit_gray_png() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("gray.PNG");
        write_atomic(&path, &png8_gray(3, 2, &[0, 51, 255, 128, 1, 254])).unwrap();
        let img = load_image(&path).unwrap();
        assert_eq!((img.width, img.height, img.linear), (3, 2, false));
        let expected: Vec<f32> = [0, 51, 255, 128, 1, 254]
            .iter()
            .map(|&c| (c as f64 / 255.0) as f32)
            .collect();
        assert_eq!(img.values, expected);
    }

    #[test]
    fn loads_16_bit_rgb_png_as_three_channels() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rgb.png");
        let rgb: [u16; 6] = [65535, 0, 0, 1000, 30000, 65535];
        write_atomic(
            &path,
            &encode_png16(2, 1, 3, &rgb, crate::PngTransfer::Srgb).unwrap(),
        )
        .unwrap();
        let img = load_image(&path).unwrap();
        assert_eq!((img.width, img.height, img.channels), (2, 1, 3));
        let expect: Vec<f32> = rgb
            .iter()
            .map(|&v| (f64::from(v) / 65535.0) as f32)
            .collect();
        assert_eq!(img.values, expect);
    }

    #[test]
    fn loads_palette_png_ignoring_alpha() {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, 2, 1);
        encoder.set_color(ColorType::Indexed);
        encoder.set_depth(BitDepth::Eight);
        encoder.set_palette(vec![10, 20, 30, 255, 255, 255]);
        encoder.set_trns(vec![0, 255]);
        let mut writer = encoder.write_header().unwrap();
        writer.write_image_data(&[0, 1]).unwrap();
        writer.finish().unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pal.png");
        write_atomic(&path, &out).unwrap();
        let img = load_image(&path).unwrap();
        assert_eq!(img.channels, 3);
        let expect: Vec<f32> = [10.0, 20.0, 30.0, 255.0, 255.0, 255.0]
            .iter()
            .map(|v: &f64| (v / 255.0) as f32)
            .collect();
        assert_eq!(img.values, expect);
    }

    #[test]
    fn loads_exr_channels() {
        let dir = tempfile::tempdir().unwrap();
        let ch = |name: &str, data: &[f32]| ExrChannel {
            name: name.into(),
            data: data.to_vec(),
        };
        let path = dir.path().join("y.exr");
        let bytes =
            encode_exr(2, 1, vec![ch("Y", &[0.25, 3.5]), ch("Z", &[9.0, 9.0])], &[]).unwrap();
        write_atomic(&path, &bytes).unwrap();
        let img = load_image(&path).unwrap();
        assert_eq!((img.width, img.height, img.linear), (2, 1, true));
        assert_eq!(img.values, [0.25, 3.5]);

        let path = dir.path().join("rgb.Exr");
        let bytes = encode_exr(
            1,
            1,
            vec![ch("R", &[1.0]), ch("G", &[2.0]), ch("B", &[4.0])],
            &[],
        )
        .unwrap();
        write_atomic(&path, &bytes).unwrap();
        let expected = (0.2126 + 0.7152 * 2.0 + 0.0722 * 4.0) as f32;
        assert_eq!(load_image(&path).unwrap().values, [expected]);

        let path = dir.path().join("one.exr");
        write_atomic(
            &path,
            &encode_exr(1, 1, vec![ch("S0.550,000nm", &[7.0])], &[]).unwrap(),
        )
        .unwrap();
        assert_eq!(load_image(&path).unwrap().values, [7.0]);

        let path = dir.path().join("two.exr");
        write_atomic(
            &path,
            &encode_exr(1, 1, vec![ch("A", &[1.0]), ch("Q", &[2.0])], &[]).unwrap(),
        )
        .unwrap();
        let msg = load_image(&path).unwrap_err().to_string();
        assert!(msg.contains("two.exr") && msg.contains("A, Q"), "{msg}");
    }

    #[test]
    fn error_cases() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing.png");
        let err = load_image(&missing).unwrap_err();
        assert!(matches!(err, IoError::Io { ref path, .. } if path == &missing));

        let err = load_image(&dir.path().join("picture.tif")).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, IoError::Format { .. }));
        assert!(
            msg.contains("picture.tif") && msg.contains(".png") && msg.contains(".jpg"),
            "{msg}"
        );
        // A file with a JPEG name that is not a JPEG is a format error naming it.
        let fake = dir.path().join("fake.jpeg");
        std::fs::write(&fake, b"not a jpeg at all").unwrap();
        let err = load_image(&fake).unwrap_err();
        assert!(matches!(err, IoError::Format { .. }), "{err}");
        assert!(err.to_string().contains("fake.jpeg"), "{err}");

        for name in ["corrupt.png", "corrupt.exr"] {
            let path = dir.path().join(name);
            std::fs::write(&path, b"\x89PNG garbage garbage").unwrap();
            let msg = load_image(&path).unwrap_err().to_string();
            assert!(msg.contains(name) && !msg.contains('\n'), "{msg}");
        }
        // A valid PNG signature and header, truncated in the image data.
        let path = dir.path().join("truncated.png");
        let full = png8_gray(4, 4, &[7; 16]);
        std::fs::write(&path, &full[..full.len() - 20]).unwrap();
        assert!(matches!(load_image(&path), Err(IoError::Format { .. })));
    }
}
