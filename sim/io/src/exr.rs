//! OpenEXR writing and reading: single-layer, scan-line, float32, ZIP
//! compressed images with custom header attributes, plus the channel naming of
//! the spectral-EXR layout (Fichet et al. 2021, as written by pbrt-v4).

use std::collections::BTreeSet;
use std::io::Cursor;
use std::path::Path;

use exr::prelude::{
    AnyChannel, AnyChannels, AttributeValue, Encoding, FlatSamples, Image, Layer, LayerAttributes,
    MetaData, ReadChannels, ReadLayers, SmallVec, Text, WritableImage, read,
};

use super::{IoError, MAX_PIXELS};

/// One image channel: `data[y * width + x]`, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct ExrChannel {
    /// Channel name, e.g. `"Y"` or `"S0.550,000nm"`.
    pub name: String,
    /// Samples in row-major order, `width * height` of them.
    pub data: Vec<f32>,
}

/// Value of a custom header attribute.
#[derive(Debug, Clone, PartialEq)]
pub enum ExrAttr {
    /// A Latin-1 text (`string` attribute).
    Text(String),
    /// A 64-bit float (`double` attribute).
    F64(f64),
    /// A 32-bit signed integer (`int` attribute).
    I32(i32),
}

/// Prefix of emissive spectral channels in the spectral-EXR layout.
const SPECTRAL_PREFIX: &str = "S0.";

/// Name of the emissive spectral channel for `lambda_nm`, as in the spectral-EXR
/// layout: `S0.` + wavelength with three decimals and a comma as decimal
/// separator + `nm`; e.g. 550.0 gives `S0.550,000nm`.
pub fn spectral_channel_name(lambda_nm: f64) -> String {
    format!(
        "{SPECTRAL_PREFIX}{}nm",
        format!("{lambda_nm:.3}").replace('.', ",")
    )
}

/// Encodes a single-layer, scan-line, float32, ZIP-compressed OpenEXR image in
/// memory.
///
/// Channels are stored sorted by name, as OpenEXR requires. `attrs` become
/// custom header attributes. If any channel name starts with `S0.`, the
/// spectral-EXR attribute `spectralLayoutVersion = "1.0"` is added. No
/// `emissiveUnits` is written: the layout reserves it for absolute radiance
/// (W·m⁻²·sr⁻¹·nm⁻¹), and stscam's values are relative (their unit is in the
/// `stscam.units` attribute); entries in `attrs` with the same names take
/// precedence. The output contains no timestamps and its header
/// attributes are stored in name order, so identical inputs give identical bytes.
pub fn encode_exr(
    width: usize,
    height: usize,
    channels: Vec<ExrChannel>,
    attrs: &[(String, ExrAttr)],
) -> Result<Vec<u8>, String> {
    if width == 0 || height == 0 {
        return Err(format!(
            "EXR image size must be non-zero, got {width}x{height}"
        ));
    }
    if channels.is_empty() {
        return Err("EXR image needs at least one channel".into());
    }
    let pixels = width
        .checked_mul(height)
        .ok_or_else(|| format!("EXR image size {width}x{height} is too large"))?;

    let mut names = BTreeSet::new();
    let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
    for channel in channels {
        if channel.data.len() != pixels {
            return Err(format!(
                "EXR channel '{}' has {} samples, expected {width}x{height} = {pixels}",
                channel.name,
                channel.data.len()
            ));
        }
        let name = latin1_text(&channel.name, "channel name")?;
        if !names.insert(channel.name.clone()) {
            return Err(format!("duplicate EXR channel name '{}'", channel.name));
        }
        list.push(AnyChannel::new(name, FlatSamples::F32(channel.data)));
    }

    let mut attributes = LayerAttributes::default();
    if names.iter().any(|n| n.starts_with(SPECTRAL_PREFIX)) {
        for (key, value) in [("spectralLayoutVersion", "1.0")] {
            attributes
                .other
                .insert(Text::from(key), AttributeValue::Text(Text::from(value)));
        }
    }
    for (key, value) in attrs {
        let value = match value {
            ExrAttr::Text(s) => {
                AttributeValue::Text(latin1_text(&escape_non_latin1(s), "attribute value")?)
            }
            ExrAttr::F64(v) => AttributeValue::F64(*v),
            ExrAttr::I32(v) => AttributeValue::I32(*v),
        };
        attributes
            .other
            .insert(latin1_text(key, "attribute name")?, value);
    }

    let layer = Layer::new(
        (width, height),
        attributes,
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(list),
    );
    let mut cursor = Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut cursor)
        .map_err(|e| format!("cannot encode EXR: {e}"))?;
    let mut bytes = cursor.into_inner();
    sort_header_attributes(&mut bytes)?;
    Ok(bytes)
}

/// `s` with every character outside Latin-1 written as a JSON escape `\uXXXX` (a UTF-16
/// surrogate pair above U+FFFF), since EXR `string` attributes hold Latin-1 bytes. A JSON text
/// (the `stscam.scene` attribute) stays valid JSON with the same value, because such
/// characters can only occur inside its strings; Latin-1 text is unchanged.
pub fn escape_non_latin1(s: &str) -> std::borrow::Cow<'_, str> {
    if s.chars().all(|c| u32::from(c) <= 0xFF) {
        return std::borrow::Cow::Borrowed(s);
    }
    let mut out = String::with_capacity(s.len() + 16);
    for c in s.chars() {
        if u32::from(c) <= 0xFF {
            out.push(c);
        } else {
            let mut units = [0u16; 2];
            for u in c.encode_utf16(&mut units) {
                out.push_str(&format!("\\u{:04x}", u));
            }
        }
    }
    std::borrow::Cow::Owned(out)
}

/// Converts a non-empty Latin-1 string to an EXR `Text`.
fn latin1_text(s: &str, what: &str) -> Result<Text, String> {
    Text::new_or_none(s)
        .filter(|_| !s.is_empty())
        .ok_or_else(|| format!("invalid EXR {what} '{s}': must be non-empty Latin-1"))
}

/// Reorders the header attributes of a single-part EXR file by name.
///
/// The `exr` crate keeps custom attributes in a `HashMap` and writes them in its
/// (randomised) iteration order; sorting makes the output deterministic. The
/// header keeps its length, so the offset table after it stays valid.
fn sort_header_attributes(bytes: &mut [u8]) -> Result<(), String> {
    let bad = || "internal error: unexpected OpenEXR header layout".to_string();
    let nul = |from: usize| -> Option<usize> {
        Some(from + bytes.get(from..)?.iter().position(|&b| b == 0)?)
    };
    let version = bytes.get(4..8).ok_or_else(bad)?;
    let multipart = u32::from_le_bytes([version[0], version[1], version[2], version[3]]) & 0x1000;
    if bytes.get(..4) != Some(&[0x76, 0x2f, 0x31, 0x01]) || multipart != 0 {
        return Err(bad());
    }
    // Each attribute is: name NUL, type NUL, i32 size (little-endian), value.
    let mut spans = Vec::new();
    let mut pos = 8;
    loop {
        let name_end = nul(pos).ok_or_else(bad)?;
        if name_end == pos {
            break;
        }
        let type_end = nul(name_end + 1).ok_or_else(bad)?;
        let size = bytes.get(type_end + 1..type_end + 5).ok_or_else(bad)?;
        let size = i32::from_le_bytes([size[0], size[1], size[2], size[3]]);
        let end = type_end + 5 + usize::try_from(size).map_err(|_| bad())?;
        if end > bytes.len() {
            return Err(bad());
        }
        spans.push((pos, name_end, end));
        pos = end;
    }
    spans.sort_by(|a, b| bytes[a.0..a.1].cmp(&bytes[b.0..b.1]));
    let sorted: Vec<u8> = spans
        .iter()
        .flat_map(|&(s, _, e)| bytes[s..e].to_vec())
        .collect();
    bytes[8..pos].copy_from_slice(&sorted);
    Ok(())
}

/// Reads the first layer of an OpenEXR file.
///
/// Returns `(width, height, channels)` with every channel converted to `f32`,
/// row-major with row 0 at the top, in the file's (name-sorted) channel order.
pub fn read_exr(path: &Path) -> Result<(usize, usize, Vec<ExrChannel>), IoError> {
    let bytes = super::input::read_input(path, super::input::MAX_BINARY_BYTES)?;
    decode_exr(path, bytes, MAX_PIXELS)
}

/// Decodes EXR `bytes` (read from `path`, which is used only in errors).
/// Images of more than `max_pixels` pixels are refused from the header, before decoding.
pub(crate) fn decode_exr(
    path: &Path,
    bytes: Vec<u8>,
    max_pixels: usize,
) -> Result<(usize, usize, Vec<ExrChannel>), IoError> {
    let not_exr =
        |e: exr::error::Error| IoError::format(path, format!("not a readable OpenEXR file ({e})"));
    let meta = MetaData::read_from_buffered(bytes.as_slice(), false).map_err(not_exr)?;
    let pixels =
        |h: &exr::meta::header::Header| h.layer_size.width().saturating_mul(h.layer_size.height());
    if meta.headers.iter().any(|h| pixels(h) > max_pixels) {
        return Err(IoError::format(
            path,
            format!("EXR image has more than the {max_pixels} pixels accepted"),
        ));
    }
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(not_exr)?;
    let layer = image.layer_data;
    let (width, height) = (layer.size.width(), layer.size.height());
    let mut channels = Vec::with_capacity(layer.channel_data.list.len());
    for channel in layer.channel_data.list {
        let name = channel.name.to_string();
        let data: Vec<f32> = match channel.sample_data {
            FlatSamples::F16(v) => v.into_iter().map(f32::from).collect(),
            FlatSamples::F32(v) => v,
            FlatSamples::U32(v) => v.into_iter().map(|x| x as f32).collect(),
        };
        if data.len() != width * height {
            return Err(IoError::format(
                path,
                format!("EXR channel '{name}' is subsampled, which is not supported"),
            ));
        }
        channels.push(ExrChannel { name, data });
    }
    Ok((width, height, channels))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::write_atomic;

    fn channel(name: &str, data: Vec<f32>) -> ExrChannel {
        ExrChannel {
            name: name.into(),
            data,
        }
    }

    fn sample_channels() -> Vec<ExrChannel> {
        let (w, h) = (5, 3);
        let make = |k: f32| {
            (0..w * h)
                .map(|i| (i as f32 * 0.37 + k).sin() * 1e3 + 1e-7 * k)
                .collect()
        };
        // Deliberately unsorted.
        vec![
            channel("R", make(1.0)),
            channel("G", make(2.0)),
            channel("B", make(3.0)),
        ]
    }

    #[test]
    fn round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rt.exr");
        let input = sample_channels();
        let attrs = [("note".to_string(), ExrAttr::Text("hello".into()))];
        write_atomic(&path, &encode_exr(5, 3, input.clone(), &attrs).unwrap()).unwrap();
        let (w, h, out) = read_exr(&path).unwrap();
        assert_eq!((w, h), (5, 3));
        let names: Vec<_> = out.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, ["B", "G", "R"]);
        for c in &input {
            let read_back = out.iter().find(|o| o.name == c.name).unwrap();
            assert_eq!(read_back.data, c.data);
        }
    }

    #[test]
    fn spectral_names() {
        assert_eq!(spectral_channel_name(550.0), "S0.550,000nm");
        assert_eq!(spectral_channel_name(400.0), "S0.400,000nm");
        assert_eq!(spectral_channel_name(1000.5), "S0.1000,500nm");
    }

    /// Non-Latin-1 characters become JSON escapes that parse back to the same text; the
    /// unescaped text is refused by the EXR `Text` type (the former failure).
    #[test]
    fn non_latin1_attribute_values_are_escaped() {
        let json = r#"{"name":"顔 😀 é"}"#;
        let e = escape_non_latin1(json);
        assert_eq!(e, r#"{"name":"\u9854 \ud83d\ude00 é"}"#);
        let v: serde_json::Value = serde_json::from_str(&e).unwrap();
        assert_eq!(v["name"], "顔 😀 é");
        assert!(latin1_text(json, "value").is_err());
        let attrs = [("stscam.scene".to_string(), ExrAttr::Text(json.into()))];
        let ch = vec![ExrChannel {
            name: "Y".into(),
            data: vec![0.0],
        }];
        assert!(encode_exr(1, 1, ch, &attrs).is_ok());
        assert!(matches!(
            escape_non_latin1("é"),
            std::borrow::Cow::Borrowed(_)
        ));
    }

    #[test]
    fn spectral_attributes_are_added_and_readable() {
        let chans = vec![channel(&spectral_channel_name(450.0), vec![1.0; 4])];
        let bytes = encode_exr(2, 2, chans, &[]).unwrap();
        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_buffered(Cursor::new(bytes))
            .unwrap();
        let other = &image.layer_data.attributes.other;
        assert_eq!(
            other.get(&Text::from("spectralLayoutVersion")),
            Some(&AttributeValue::Text(Text::from("1.0")))
        );
        // The values are relative: no absolute-radiance unit is claimed.
        assert_eq!(other.get(&Text::from("emissiveUnits")), None);
    }

    #[test]
    fn encoding_is_deterministic() {
        let mut chans = sample_channels();
        chans.push(channel(&spectral_channel_name(500.0), vec![0.5; 15]));
        let attrs: Vec<_> = (0..8)
            .map(|i| {
                (
                    format!("attr{i}"),
                    if i % 2 == 0 {
                        ExrAttr::F64(i as f64)
                    } else {
                        ExrAttr::I32(i)
                    },
                )
            })
            .collect();
        let first = encode_exr(5, 3, chans.clone(), &attrs).unwrap();
        for _ in 0..5 {
            assert_eq!(encode_exr(5, 3, chans.clone(), &attrs).unwrap(), first);
        }
    }

    #[test]
    fn invalid_inputs_are_errors() {
        assert!(encode_exr(2, 2, vec![channel("Y", vec![0.0; 3])], &[]).is_err());
        assert!(encode_exr(0, 2, vec![channel("Y", vec![])], &[]).is_err());
        assert!(
            encode_exr(
                1,
                1,
                vec![channel("Y", vec![0.0]), channel("Y", vec![0.0])],
                &[]
            )
            .is_err()
        );
        assert!(
            encode_exr(
                1,
                1,
                vec![channel("Y", vec![0.0])],
                &[("channels".into(), ExrAttr::I32(1))]
            )
            .is_err()
        );
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing.exr");
        assert!(matches!(read_exr(&missing), Err(IoError::Io { .. })));
        let junk = dir.path().join("junk.exr");
        std::fs::write(&junk, b"not an exr").unwrap();
        let err = read_exr(&junk).unwrap_err();
        assert!(matches!(err, IoError::Format { .. }));
        assert!(err.to_string().starts_with(&junk.display().to_string()));
    }
}
