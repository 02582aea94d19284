//! NumPy `.npy` arrays: the preamble written and parsed, `float32` arrays encoded and
//! decoded, and the typed reading of array data that the `.npz` reader uses.

use std::borrow::Cow;
use std::path::Path;

use super::literal::{Literal, parse_literal};
use super::shape_repr;
use crate::IoError;

/// Magic string that opens every `.npy` file.
const NPY_MAGIC: &[u8; 6] = b"\x93NUMPY";

/// Alignment of the start of the array data in a `.npy` file.
const NPY_ALIGN: usize = 64;

// ---------------------------------------------------------------------------
// Public API
// ---------------------------------------------------------------------------

/// Encodes a `float32` array of the given shape (C order) as the bytes of a
/// `.npy` file (`descr` `<f4`); `shape = &[]` gives a 0-d array holding one
/// value.
///
/// `path` is only used in error messages. Returns [`IoError::Format`] if the
/// product of `shape` is not `data.len()`.
pub fn encode_npy_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<Vec<u8>, IoError> {
    let count = shape_product(shape)
        .ok_or_else(|| IoError::format(path, format!("npy shape {shape:?} is too large")))?;
    if count != data.len() {
        return Err(IoError::format(
            path,
            format!(
                "npy shape {shape:?} holds {count} values but {} were given",
                data.len()
            ),
        ));
    }
    let header = npy_header("<f4", shape);
    let mut out = Vec::with_capacity(header.len() + 4 * data.len());
    out.extend_from_slice(&header);
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    Ok(out)
}

/// Reads a `.npy` file holding a floating-point array and returns its shape
/// and its values in C order.
///
/// See [`decode_npy_f32`] for what is accepted. A file that cannot be read
/// gives [`IoError::Io`]; any problem with its contents gives
/// [`IoError::Format`].
pub fn read_npy_f32(path: &Path) -> Result<(Vec<usize>, Vec<f32>), IoError> {
    let bytes = crate::input::read_input(path, crate::input::MAX_BINARY_BYTES)?;
    decode_npy_f32(path, &bytes)
}

/// Decodes the bytes of a `.npy` file (format version 1.0, 2.0 or 3.0)
/// holding a little-endian `<f4` or `<f8` array (the latter converted to
/// `f32`) and returns its shape and its values in C order.
///
/// Fortran-order arrays of two or more dimensions are rejected. `path` is only
/// used in error messages; every problem gives [`IoError::Format`].
pub fn decode_npy_f32(path: &Path, bytes: &[u8]) -> Result<(Vec<usize>, Vec<f32>), IoError> {
    let decode = || -> Result<(Vec<usize>, Vec<f32>), String> {
        let arr = parse_npy(bytes)?;
        let data = decode_floats(&arr)?;
        Ok((arr.shape, data))
    };
    decode().map_err(|m| IoError::format(path, format!("npy: {m}")))
}

// ---------------------------------------------------------------------------
// NPY encoding
// ---------------------------------------------------------------------------

/// Product of the dimensions, `None` on overflow.
fn shape_product(shape: &[usize]) -> Option<usize> {
    shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))
}

/// The complete `.npy` preamble (magic, version, header length, header dict)
/// for a C-order array, padded so that the data starts at a multiple of 64.
pub(super) fn npy_header(descr: &str, shape: &[usize]) -> Vec<u8> {
    let dict = format!(
        "{{'descr': '{descr}', 'fortran_order': False, 'shape': {}, }}",
        shape_repr(shape)
    );
    // Version 1.0 has a u16 header length after 8 bytes, 2.0 a u32.
    let build = |prefix_len: usize| {
        let unpadded = prefix_len + dict.len() + 1;
        let pad = (NPY_ALIGN - unpadded % NPY_ALIGN) % NPY_ALIGN;
        dict.len() + pad + 1
    };
    let v1_len = build(10);
    let (major, prefix_len, header_len) = if v1_len <= usize::from(u16::MAX) {
        (1u8, 10, v1_len)
    } else {
        (2u8, 12, build(12))
    };
    let mut out = Vec::with_capacity(prefix_len + header_len);
    out.extend_from_slice(NPY_MAGIC);
    out.push(major);
    out.push(0);
    if major == 1 {
        out.extend_from_slice(&(header_len as u16).to_le_bytes());
    } else {
        out.extend_from_slice(&(header_len as u32).to_le_bytes());
    }
    out.extend_from_slice(dict.as_bytes());
    out.resize(prefix_len + header_len - 1, b' ');
    out.push(b'\n');
    out
}

// ---------------------------------------------------------------------------
// NPY decoding
// ---------------------------------------------------------------------------

/// Element type of an array, from its `descr` type string.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Dtype {
    /// Little-endian float of 4 or 8 bytes.
    Float(usize),
    /// Little-endian signed integer of 1, 2, 4 or 8 bytes.
    Int(usize),
    /// Little-endian unsigned integer of 1, 2, 4 or 8 bytes.
    Uint(usize),
    /// Boolean, one byte.
    Bool,
    /// Byte string of the given length (`|S<n>`).
    Bytes(usize),
    /// UCS-4 string of the given number of characters (`<U<n>`).
    Unicode(usize),
}

impl Dtype {
    /// Size of one element in bytes, `None` on overflow.
    fn item_size(self) -> Option<usize> {
        match self {
            Dtype::Float(n) | Dtype::Int(n) | Dtype::Uint(n) | Dtype::Bytes(n) => Some(n),
            Dtype::Bool => Some(1),
            Dtype::Unicode(n) => n.checked_mul(4),
        }
    }
}

/// A parsed `.npy` file: element type, shape and the raw data bytes (whose
/// length has been checked against the shape).
#[derive(Debug)]
pub(super) struct NpyArray<'a> {
    /// The `descr` string as written.
    pub(super) descr: String,
    /// Element type.
    dtype: Dtype,
    /// Shape, C order.
    pub(super) shape: Vec<usize>,
    /// Number of elements (product of `shape`).
    count: usize,
    /// Exactly `count * item_size` bytes of data.
    pub(super) payload: &'a [u8],
}

/// Parses the preamble of a `.npy` file and checks that the data that follows
/// has exactly the size the header announces.
pub(super) fn parse_npy(bytes: &[u8]) -> Result<NpyArray<'_>, String> {
    if bytes.len() < 8 || &bytes[..6] != NPY_MAGIC {
        return Err("not an npy array (bad magic string)".to_owned());
    }
    let (major, minor) = (bytes[6], bytes[7]);
    let (len_size, utf8) = match (major, minor) {
        (1, 0) => (2, false),
        (2, 0) => (4, false),
        (3, 0) => (4, true),
        _ => return Err(format!("unsupported npy format version {major}.{minor}")),
    };
    let prefix_len = 8 + len_size;
    let len_bytes = bytes
        .get(8..prefix_len)
        .ok_or("truncated npy header (no header length)")?;
    let header_len = if len_size == 2 {
        usize::from(u16::from_le_bytes([len_bytes[0], len_bytes[1]]))
    } else {
        let n = u32::from_le_bytes([len_bytes[0], len_bytes[1], len_bytes[2], len_bytes[3]]);
        usize::try_from(n).map_err(|_| "npy header length too large".to_owned())?
    };
    let data_start = prefix_len
        .checked_add(header_len)
        .ok_or("npy header length too large")?;
    let header_bytes = bytes.get(prefix_len..data_start).ok_or_else(|| {
        format!(
            "truncated npy header: {header_len} bytes announced, {} present",
            bytes.len() - prefix_len
        )
    })?;
    let header: Cow<'_, str> = if utf8 {
        Cow::Borrowed(
            std::str::from_utf8(header_bytes).map_err(|_| "npy header is not valid UTF-8")?,
        )
    } else {
        Cow::Owned(header_bytes.iter().map(|&b| char::from(b)).collect())
    };

    let dict = match parse_literal(&header)? {
        Literal::Dict(items) => items,
        _ => return Err("bad npy header: not a dict".to_owned()),
    };
    let mut descr = None;
    let mut fortran = None;
    let mut shape = None;
    for (key, value) in dict {
        match key.as_str() {
            "descr" if descr.is_none() => descr = Some(value),
            "fortran_order" if fortran.is_none() => fortran = Some(value),
            "shape" if shape.is_none() => shape = Some(value),
            _ => {
                return Err(format!(
                    "bad npy header: unexpected or repeated key {key:?}"
                ));
            }
        }
    }
    let (Some(descr), Some(fortran), Some(shape)) = (descr, fortran, shape) else {
        return Err("bad npy header: needs the keys 'descr', 'fortran_order' and 'shape'".into());
    };
    let descr = match descr {
        Literal::Str(s) => s,
        Literal::List(_) => return Err("structured dtypes are not supported".to_owned()),
        _ => return Err("bad npy header: 'descr' is not a string".to_owned()),
    };
    let fortran = match fortran {
        Literal::Bool(b) => b,
        _ => return Err("bad npy header: 'fortran_order' is not True or False".to_owned()),
    };
    let shape = match shape {
        Literal::Tuple(items) => items
            .into_iter()
            .map(|item| match item {
                Literal::Int(v) => usize::try_from(v)
                    .map_err(|_| format!("bad npy header: invalid dimension {v} in 'shape'")),
                _ => Err("bad npy header: 'shape' holds a non-integer".to_owned()),
            })
            .collect::<Result<Vec<usize>, String>>()?,
        _ => return Err("bad npy header: 'shape' is not a tuple".to_owned()),
    };
    if fortran && shape.len() > 1 {
        return Err(format!(
            "Fortran-order array of shape {} is not supported, only C order",
            shape_repr(&shape)
        ));
    }
    let dtype = parse_descr(&descr)?;
    let count = shape_product(&shape)
        .ok_or_else(|| format!("array shape {} is too large", shape_repr(&shape)))?;
    let needed = dtype
        .item_size()
        .and_then(|s| s.checked_mul(count))
        .ok_or_else(|| format!("array shape {} is too large", shape_repr(&shape)))?;
    let payload = &bytes[data_start..];
    if payload.len() < needed {
        return Err(format!(
            "truncated array data: shape {} of {} needs {needed} bytes, {} present",
            shape_repr(&shape),
            quoted(&descr),
            payload.len()
        ));
    }
    if payload.len() > needed {
        return Err(format!(
            "{} unexpected bytes after the array data of shape {} of {}",
            payload.len() - needed,
            shape_repr(&shape),
            quoted(&descr)
        ));
    }
    Ok(NpyArray {
        descr,
        dtype,
        shape,
        count,
        payload,
    })
}

/// Parses a NumPy type string such as `<f4`, `|S3` or `<i8`. Multi-byte
/// types must be little-endian.
fn parse_descr(descr: &str) -> Result<Dtype, String> {
    let mut chars = descr.chars();
    let (Some(order), Some(kind)) = (chars.next(), chars.next()) else {
        return Err(format!("unsupported dtype {}", quoted(descr)));
    };
    let size: usize = chars
        .as_str()
        .parse()
        .map_err(|_| format!("unsupported dtype {}", quoted(descr)))?;
    let dtype = match (kind, size) {
        ('f', 4 | 8) => Dtype::Float(size),
        ('i', 1 | 2 | 4 | 8) => Dtype::Int(size),
        ('u', 1 | 2 | 4 | 8) => Dtype::Uint(size),
        ('b', 1) => Dtype::Bool,
        ('S', _) => Dtype::Bytes(size),
        ('U', _) => Dtype::Unicode(size),
        _ => return Err(format!("unsupported dtype {}", quoted(descr))),
    };
    let multi_byte = matches!(dtype, Dtype::Unicode(_))
        || matches!(dtype, Dtype::Float(_) | Dtype::Int(_) | Dtype::Uint(_) if size > 1);
    match order {
        '<' => Ok(dtype),
        '|' | '=' if !multi_byte => Ok(dtype),
        '>' if !multi_byte => Ok(dtype),
        '>' => Err(format!(
            "big-endian dtype {} is not supported, only little-endian",
            quoted(descr)
        )),
        '|' | '=' => Err(format!(
            "dtype {} does not state its byte order",
            quoted(descr)
        )),
        _ => Err(format!("unsupported dtype {}", quoted(descr))),
    }
}

/// Converts a float array (`<f4` or `<f8`) to `f32` values.
pub(super) fn decode_floats(arr: &NpyArray<'_>) -> Result<Vec<f32>, String> {
    match arr.dtype {
        Dtype::Float(4) => Ok(arr
            .payload
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()),
        Dtype::Float(8) => Ok(arr
            .payload
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(le8(c)) as f32)
            .collect()),
        _ => Err(format!(
            "expected float32 or float64 data ('<f4' or '<f8'), got {}",
            quoted(&arr.descr)
        )),
    }
}

/// Converts an integer array of any supported width to `T`, element by
/// element via `conv(position, value)`.
pub(super) fn decode_ints<T>(
    arr: &NpyArray<'_>,
    conv: impl FnMut(usize, i128) -> Result<T, String>,
) -> Result<Vec<T>, String> {
    fn run<T, const N: usize>(
        payload: &[u8],
        count: usize,
        read: impl Fn([u8; N]) -> i128,
        mut conv: impl FnMut(usize, i128) -> Result<T, String>,
    ) -> Result<Vec<T>, String> {
        let mut out = Vec::with_capacity(count);
        for (k, c) in payload.chunks_exact(N).enumerate() {
            let mut b = [0u8; N];
            b.copy_from_slice(c);
            out.push(conv(k, read(b))?);
        }
        Ok(out)
    }
    let (p, n) = (arr.payload, arr.count);
    match arr.dtype {
        Dtype::Int(1) => run(p, n, |b: [u8; 1]| i128::from(i8::from_le_bytes(b)), conv),
        Dtype::Int(2) => run(p, n, |b: [u8; 2]| i128::from(i16::from_le_bytes(b)), conv),
        Dtype::Int(4) => run(p, n, |b: [u8; 4]| i128::from(i32::from_le_bytes(b)), conv),
        Dtype::Int(8) => run(p, n, |b: [u8; 8]| i128::from(i64::from_le_bytes(b)), conv),
        Dtype::Uint(1) => run(p, n, |b: [u8; 1]| i128::from(b[0]), conv),
        Dtype::Uint(2) => run(p, n, |b: [u8; 2]| i128::from(u16::from_le_bytes(b)), conv),
        Dtype::Uint(4) => run(p, n, |b: [u8; 4]| i128::from(u32::from_le_bytes(b)), conv),
        Dtype::Uint(8) => run(p, n, |b: [u8; 8]| i128::from(u64::from_le_bytes(b)), conv),
        _ => Err(format!(
            "expected integer data (e.g. '<i4' or '<i8'), got {}",
            quoted(&arr.descr)
        )),
    }
}

/// Decodes a one-element byte-string (`|S<n>`) or unicode (`<U<n>`) array,
/// dropping trailing NULs as NumPy does.
pub(super) fn decode_text(arr: &NpyArray<'_>) -> Result<String, String> {
    if arr.count != 1 {
        return Err(format!(
            "expected a single string, got shape {}",
            shape_repr(&arr.shape)
        ));
    }
    let text = match arr.dtype {
        Dtype::Bytes(_) => arr.payload.iter().map(|&b| char::from(b)).collect(),
        Dtype::Unicode(_) => arr
            .payload
            .chunks_exact(4)
            .map(|c| {
                char::from_u32(u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .ok_or("invalid character in unicode string")
            })
            .collect::<Result<String, _>>()?,
        _ => {
            return Err(format!(
                "expected a string ('|S' or '<U'), got {}",
                quoted(&arr.descr)
            ));
        }
    };
    Ok(text.trim_end_matches('\0').to_owned())
}

/// `s` in single quotes, as Python prints it, with control characters escaped.
fn quoted(s: &str) -> String {
    format!("'{}'", s.escape_debug())
}

/// The first 8 bytes of `c` (which has exactly 8) as an array.
fn le8(c: &[u8]) -> [u8; 8] {
    let mut b = [0u8; 8];
    b.copy_from_slice(c);
    b
}

#[cfg(test)]
mod tests {
    use super::super::test_support::{Rng, p};
    use super::*;

    #[test]
    fn header_alignment() {
        for shape in [
            &[][..],
            &[0],
            &[7],
            &[123_456_789],
            &[3, 4],
            &[1, 2, 3, 4, 5],
        ] {
            for descr in ["<f4", "<i8", "|S3"] {
                let h = npy_header(descr, shape);
                assert_eq!(h.len() % 64, 0, "{descr} {shape:?}");
                assert_eq!(*h.last().unwrap(), b'\n');
                assert_eq!(&h[..8], b"\x93NUMPY\x01\x00");
                let hlen = u16::from_le_bytes([h[8], h[9]]) as usize;
                assert_eq!(10 + hlen, h.len());
                let text = std::str::from_utf8(&h[10..]).unwrap();
                assert!(text.starts_with(&format!(
                    "{{'descr': '{descr}', 'fortran_order': False, 'shape': {}, }}",
                    shape_repr(shape)
                )));
            }
        }
        assert_eq!(shape_repr(&[]), "()");
        assert_eq!(shape_repr(&[5]), "(5,)");
        assert_eq!(shape_repr(&[2, 3]), "(2, 3)");
    }

    #[test]
    fn npy_round_trip() {
        let v1: Vec<f32> = (0..17).map(|i| i as f32 * 0.5 - 3.0).collect();
        let bytes = encode_npy_f32(p(), &[17], &v1).unwrap();
        assert_eq!(decode_npy_f32(p(), &bytes).unwrap(), (vec![17], v1));

        let v2: Vec<f32> = (0..12).map(|i| (i * i) as f32).collect();
        let bytes = encode_npy_f32(p(), &[3, 4], &v2).unwrap();
        assert_eq!(decode_npy_f32(p(), &bytes).unwrap(), (vec![3, 4], v2));

        let bytes = encode_npy_f32(p(), &[], &[2.5]).unwrap();
        assert_eq!(decode_npy_f32(p(), &bytes).unwrap(), (vec![], vec![2.5]));

        let bytes = encode_npy_f32(p(), &[0, 5], &[]).unwrap();
        assert_eq!(decode_npy_f32(p(), &bytes).unwrap(), (vec![0, 5], vec![]));

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.npy");
        std::fs::write(
            &path,
            encode_npy_f32(p(), &[2, 2], &[1.0, 2.0, 3.0, 4.0]).unwrap(),
        )
        .unwrap();
        assert_eq!(
            read_npy_f32(&path).unwrap(),
            (vec![2, 2], vec![1.0, 2.0, 3.0, 4.0])
        );

        assert!(matches!(
            encode_npy_f32(p(), &[2, 3], &[1.0]),
            Err(IoError::Format { .. })
        ));
    }

    #[test]
    fn npy_reads_numpy_variants() {
        // <f8 data, double quotes, keys in another order, no trailing comma,
        // version 2.0 header, 1-D Fortran flag.
        let header = "{\"shape\": (2, 2), 'fortran_order': False, 'descr': '<f8'}";
        let mut bytes = b"\x93NUMPY\x02\x00".to_vec();
        bytes.extend_from_slice(&((header.len() + 1) as u32).to_le_bytes());
        bytes.extend_from_slice(header.as_bytes());
        bytes.push(b'\n');
        for v in [1.0f64, -2.0, 0.5, 1e10] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        assert_eq!(
            decode_npy_f32(p(), &bytes).unwrap(),
            (vec![2, 2], vec![1.0, -2.0, 0.5, 1e10])
        );

        let header = "{'descr': '<f4', 'fortran_order': True, 'shape': (1L,), }\n";
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
        bytes.extend_from_slice(header.as_bytes());
        bytes.extend_from_slice(&7.0f32.to_le_bytes());
        assert_eq!(decode_npy_f32(p(), &bytes).unwrap(), (vec![1], vec![7.0]));

        // 2-D Fortran order is rejected, as are extra keys and trailing bytes.
        for (header, extra) in [
            (
                "{'descr': '<f4', 'fortran_order': True, 'shape': (1, 1), }\n",
                0,
            ),
            (
                "{'descr': '<f4', 'fortran_order': False, 'shape': (1,), 'x': 1}\n",
                0,
            ),
            (
                "{'descr': '<f4', 'fortran_order': False, 'shape': (1,), }\n",
                1,
            ),
            (
                "{'descr': [('a', '<f4')], 'fortran_order': False, 'shape': (1,), }\n",
                0,
            ),
            (
                "{'descr': '<f4', 'fortran_order': False, 'shape': 1, }\n",
                0,
            ),
            (
                "{'descr': '<c8', 'fortran_order': False, 'shape': (1,), }\n",
                0,
            ),
        ] {
            let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
            bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
            bytes.extend_from_slice(header.as_bytes());
            bytes.extend_from_slice(&7.0f32.to_le_bytes());
            bytes.extend(std::iter::repeat_n(0u8, extra));
            assert!(
                matches!(decode_npy_f32(p(), &bytes), Err(IoError::Format { .. })),
                "{header}"
            );
        }
    }

    #[test]
    fn random_npy_bytes_never_panic() {
        let good = encode_npy_f32(p(), &[3, 2], &[1.0; 6]).unwrap();
        let mut rng = Rng(42);
        for _ in 0..2000 {
            let mut bytes = good.clone();
            for _ in 0..1 + rng.below(4) {
                let k = rng.below(bytes.len() as u64) as usize;
                bytes[k] = rng.next() as u8;
            }
            let cut = rng.below(bytes.len() as u64 + 1) as usize;
            let _ = decode_npy_f32(p(), &bytes[..cut]);
        }
    }
}
