//! The URIs of a glTF file's buffers and images: `data:` URIs (base64) decoded, relative
//! and `file:` URIs resolved against the glTF file's folder.

use std::path::{Path, PathBuf};

use super::LoadError;

/// Standard base64 (RFC 4648 §4), padding optional, whitespace ignored.
fn base64_decode(s: &str) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(s.len() / 4 * 3 + 3);
    let (mut acc, mut bits) = (0u32, 0u32);
    for c in s.bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' => break,
            b' ' | b'\n' | b'\r' | b'\t' => continue,
            _ => return None,
        };
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Some(out)
}

/// Decodes `%XX` escapes of a relative URI; `None` if the result is not UTF-8.
fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        if b[i] == b'%'
            && i + 2 < b.len()
            && let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2]))
        {
            out.push((h * 16 + l) as u8);
            i += 3;
            continue;
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8(out).ok()
}

/// Where a glTF URI's bytes come from.
pub(super) enum UriData {
    /// A `data:` URI: its bytes and its media type.
    Inline(Vec<u8>, String),
    /// A file (relative URIs resolved against the glTF file's folder).
    File(PathBuf),
}

pub(super) fn resolve_uri(gltf_path: &Path, uri: &str) -> Result<UriData, LoadError> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (head, payload) = rest
            .split_once(',')
            .ok_or_else(|| LoadError::new(gltf_path, "malformed data URI (no comma)"))?;
        let Some(media) = head.strip_suffix(";base64") else {
            return Err(LoadError::new(gltf_path, "data URI is not base64-encoded"));
        };
        let bytes = base64_decode(payload)
            .ok_or_else(|| LoadError::new(gltf_path, "data URI has invalid base64"))?;
        return Ok(UriData::Inline(bytes, media.to_string()));
    }
    let rel = if let Some(rest) = uri.strip_prefix("file://") {
        rest
    } else if let Some(rest) = uri.strip_prefix("file:") {
        rest
    } else if uri.contains(':') {
        return Err(LoadError::new(
            gltf_path,
            format!("unsupported URI {uri:?} (only relative paths, file: and data: URIs)"),
        ));
    } else {
        uri
    };
    let decoded = percent_decode(rel)
        .ok_or_else(|| LoadError::new(gltf_path, format!("URI {uri:?} is not valid UTF-8")))?;
    let base = gltf_path.parent().unwrap_or(Path::new(""));
    Ok(UriData::File(base.join(decoded)))
}
