//! The `.npz` container: `scipy.sparse` CSR matrices ([`CsrParts`]) as zip archives of
//! `.npy` members, written and read (the member size limits, the CSR invariants).

use std::io::{Cursor, Read, Write};
use std::path::Path;

use zip::write::SimpleFileOptions;
use zip::{CompressionMethod, ZipArchive, ZipWriter};

use super::npy::{NpyArray, decode_floats, decode_ints, decode_text, npy_header, parse_npy};
use super::shape_repr;
use crate::IoError;

/// A CSR (compressed sparse row) matrix as plain parts, in the layout of
/// `scipy.sparse.csr_matrix`: the column indices and values of row `r` are
/// `indices[indptr[r]..indptr[r + 1]]` and `data[indptr[r]..indptr[r + 1]]`.
///
/// Column indices within a row need not be sorted and may repeat (scipy sums
/// duplicates when it needs to).
#[derive(Debug, Clone, PartialEq)]
pub struct CsrParts {
    /// Number of rows.
    pub rows: usize,
    /// Number of columns.
    pub cols: usize,
    /// Row pointers, `rows + 1` of them, starting at 0, non-decreasing, ending
    /// at the number of stored entries.
    pub indptr: Vec<u64>,
    /// Column index of each stored entry, each `< cols`.
    pub indices: Vec<u32>,
    /// Value of each stored entry.
    pub data: Vec<f32>,
}

/// Largest index value (and `nnz`) for which `indices`/`indptr` are written as
/// `<i4`.
const I4_INDEX_LIMIT: u64 = i32::MAX as u64;

/// Bytes converted per batch when streaming array data to a writer.
const WRITE_CHUNK_BYTES: usize = 1 << 16;

// ---------------------------------------------------------------------------
// Public API
// ---------------------------------------------------------------------------

/// Encodes a CSR matrix as the bytes of a `.npz` file that
/// `scipy.sparse.load_npz` reads as a `csr_matrix` of shape `(rows, cols)`
/// with `float32` data.
///
/// The archive holds `format.npy` (`|S3` `b"csr"`), `shape.npy` (`<i8`),
/// `data.npy` (`<f4`), `indices.npy` and `indptr.npy` (both `<i4` if
/// `nnz <= i32::MAX` and `cols <= i32::MAX`, else both `<i8`), stored
/// uncompressed with fixed timestamps, so equal inputs give equal bytes.
///
/// `path` is only used in error messages. Returns [`IoError::Format`] if the
/// parts do not form a valid CSR matrix: `indptr` must have `rows + 1`
/// entries, start at 0, be non-decreasing and end at
/// `indices.len() == data.len()`, and every index must be `< cols`.
pub fn encode_csr_npz(
    path: &Path,
    rows: usize,
    cols: usize,
    indptr: &[u64],
    indices: &[u32],
    data: &[f32],
) -> Result<Vec<u8>, IoError> {
    encode_csr_npz_with_limit(path, rows, cols, indptr, indices, data, I4_INDEX_LIMIT)
}

/// Reads a `.npz` file written by `scipy.sparse.save_npz` (or by
/// [`encode_csr_npz`]) holding a CSR matrix.
///
/// See [`decode_csr_npz`] for what is accepted. A file that cannot be read
/// gives [`IoError::Io`]; any problem with its contents gives
/// [`IoError::Format`].
pub fn read_csr_npz(path: &Path) -> Result<CsrParts, IoError> {
    let bytes = crate::input::read_input(path, crate::input::MAX_BINARY_BYTES)?;
    decode_csr_npz(path, &bytes)
}

/// Decodes the bytes of a `.npz` file holding a CSR matrix, as written by
/// `scipy.sparse.save_npz` (compressed or not) or [`encode_csr_npz`].
///
/// Requires the entries `format.npy` (a one-element `|S`/`<U` array equal to
/// `"csr"`), `shape.npy` (two non-negative integers), `data.npy` (`<f4`, or
/// `<f8` converted to `f32`), `indices.npy` and `indptr.npy` (any
/// little-endian integer type, e.g. `<i4`, `<i8`, `<u4`, `<u8`), all 1-D
/// except `format`; other entries such as `_is_array` are ignored. All CSR
/// invariants are checked (see [`CsrParts`]); indices need not be sorted.
///
/// `path` is only used in error messages. Every problem gives
/// [`IoError::Format`] with a message naming the entry concerned.
pub fn decode_csr_npz(path: &Path, bytes: &[u8]) -> Result<CsrParts, IoError> {
    decode_csr_inner(bytes).map_err(|m| IoError::format(path, m))
}

// ---------------------------------------------------------------------------
// CSR encoding
// ---------------------------------------------------------------------------

/// Whether `indices` and `indptr` fit `<i4` for a matrix with `nnz` stored
/// entries and `cols` columns, given the largest allowed value `limit`
/// (`i32::MAX` outside tests).
fn index_fits_i4(nnz: usize, cols: usize, limit: u64) -> bool {
    nnz as u64 <= limit && cols as u64 <= limit
}

/// [`encode_csr_npz`] with the `<i4` index limit as a parameter, so that tests
/// can exercise the `<i8` branch with small matrices.
fn encode_csr_npz_with_limit(
    path: &Path,
    rows: usize,
    cols: usize,
    indptr: &[u64],
    indices: &[u32],
    data: &[f32],
    i4_limit: u64,
) -> Result<Vec<u8>, IoError> {
    validate_csr(rows, cols, indptr, indices, data.len())
        .map_err(|m| IoError::format(path, format!("cannot write CSR npz: {m}")))?;
    let rows_i8 = i64::try_from(rows)
        .map_err(|_| IoError::format(path, format!("CSR row count {rows} exceeds int64")))?;
    let cols_i8 = i64::try_from(cols)
        .map_err(|_| IoError::format(path, format!("CSR column count {cols} exceeds int64")))?;
    let nnz = data.len();
    let use_i4 = index_fits_i4(nnz, cols, i4_limit);

    // The archive's size is known up to its headers: one allocation instead of a doubling
    // buffer (for a depth stack's block matrix, hundreds of MB copied and faulted in again).
    let index_bytes = if use_i4 { 4 } else { 8 };
    let capacity = (nnz * (index_bytes + 4))
        .saturating_add(indptr.len() * index_bytes)
        .saturating_add(4096);
    let build = || -> Result<Vec<u8>, String> {
        let mut zw = ZipWriter::new(Cursor::new(Vec::with_capacity(capacity)));
        let opts = entry_options();
        let start = |zw: &mut ZipWriter<Cursor<Vec<u8>>>, name: &str| {
            zw.start_file(name, opts)
                .map_err(|e| format!("writing entry {name}: {e}"))
        };
        let io_err =
            |name: &'static str| move |e: std::io::Error| format!("writing entry {name}: {e}");

        // Entry order as in scipy's save_npz: indices, indptr, format, shape, data.
        start(&mut zw, "indices.npy")?;
        if use_i4 {
            zw.write_all(&npy_header("<i4", &[nnz]))
                .map_err(io_err("indices.npy"))?;
            write_le(&mut zw, indices, |&v| (v as i32).to_le_bytes())
                .map_err(io_err("indices.npy"))?;
        } else {
            zw.write_all(&npy_header("<i8", &[nnz]))
                .map_err(io_err("indices.npy"))?;
            write_le(&mut zw, indices, |&v| i64::from(v).to_le_bytes())
                .map_err(io_err("indices.npy"))?;
        }

        start(&mut zw, "indptr.npy")?;
        let np = indptr.len();
        if use_i4 {
            zw.write_all(&npy_header("<i4", &[np]))
                .map_err(io_err("indptr.npy"))?;
            write_le(&mut zw, indptr, |&v| (v as i32).to_le_bytes())
                .map_err(io_err("indptr.npy"))?;
        } else {
            zw.write_all(&npy_header("<i8", &[np]))
                .map_err(io_err("indptr.npy"))?;
            write_le(&mut zw, indptr, |&v| (v as i64).to_le_bytes())
                .map_err(io_err("indptr.npy"))?;
        }

        start(&mut zw, "format.npy")?;
        zw.write_all(&npy_header("|S3", &[]))
            .map_err(io_err("format.npy"))?;
        zw.write_all(b"csr").map_err(io_err("format.npy"))?;

        start(&mut zw, "shape.npy")?;
        zw.write_all(&npy_header("<i8", &[2]))
            .map_err(io_err("shape.npy"))?;
        zw.write_all(&rows_i8.to_le_bytes())
            .map_err(io_err("shape.npy"))?;
        zw.write_all(&cols_i8.to_le_bytes())
            .map_err(io_err("shape.npy"))?;

        start(&mut zw, "data.npy")?;
        zw.write_all(&npy_header("<f4", &[nnz]))
            .map_err(io_err("data.npy"))?;
        write_le(&mut zw, data, |&v| v.to_le_bytes()).map_err(io_err("data.npy"))?;

        let cursor = zw
            .finish()
            .map_err(|e| format!("finishing zip archive: {e}"))?;
        Ok(cursor.into_inner())
    };
    build().map_err(|m| IoError::format(path, format!("cannot write CSR npz: {m}")))
}

/// Zip entry options of the writer: uncompressed, ZIP64-ready, fixed
/// timestamp, system and permissions, so the output is reproducible.
fn entry_options() -> SimpleFileOptions {
    SimpleFileOptions::default()
        .compression_method(CompressionMethod::Stored)
        .large_file(true)
        .last_modified_time(zip::DateTime::default())
        .system(zip::System::Unix)
        .unix_permissions(0o644)
}

/// Writes `items` to `w` as little-endian bytes produced by `to_bytes`,
/// converting in batches.
fn write_le<W: Write, T, const N: usize>(
    w: &mut W,
    items: &[T],
    to_bytes: impl Fn(&T) -> [u8; N],
) -> std::io::Result<()> {
    let per_chunk = (WRITE_CHUNK_BYTES / N).max(1);
    let mut buf = Vec::with_capacity(per_chunk * N);
    for chunk in items.chunks(per_chunk) {
        buf.clear();
        for item in chunk {
            buf.extend_from_slice(&to_bytes(item));
        }
        w.write_all(&buf)?;
    }
    Ok(())
}

/// Checks the CSR invariants; the message names the offending part.
fn validate_csr(
    rows: usize,
    cols: usize,
    indptr: &[u64],
    indices: &[u32],
    data_len: usize,
) -> Result<(), String> {
    let nnz = indices.len();
    if data_len != nnz {
        return Err(format!(
            "data.npy: {data_len} values but indices.npy has {nnz} entries"
        ));
    }
    let expected = rows
        .checked_add(1)
        .ok_or_else(|| format!("shape.npy: row count {rows} is too large"))?;
    if indptr.len() != expected {
        return Err(format!(
            "indptr.npy: {} entries, expected rows + 1 = {expected}",
            indptr.len()
        ));
    }
    if indptr[0] != 0 {
        return Err(format!("indptr.npy: starts at {}, expected 0", indptr[0]));
    }
    if let Some(r) = indptr.windows(2).position(|w| w[1] < w[0]) {
        return Err(format!(
            "indptr.npy: decreases from {} to {} at row {r}",
            indptr[r],
            indptr[r + 1]
        ));
    }
    let last = indptr[rows];
    if last != nnz as u64 {
        return Err(format!(
            "indptr.npy: ends at {last} but there are {nnz} stored entries"
        ));
    }
    if let Some(k) = indices.iter().position(|&c| c as usize >= cols) {
        return Err(format!(
            "indices.npy: column index {} at position {k} is out of range for {cols} columns",
            indices[k]
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------
// CSR decoding
// ---------------------------------------------------------------------------

/// Sparse formats that `scipy.sparse.save_npz` can write, other than CSR.
const OTHER_SPARSE_FORMATS: [&str; 3] = ["csc", "coo", "bsr"];

/// [`decode_csr_npz`] with plain-string errors.
///
/// No member is inflated before its declared size has been checked: `format` and `shape`
/// against [`SMALL_MEMBER_BYTES`], `indptr` against `rows + 1` integers of 8 bytes, and
/// `data` and `indices` against the `nnz` that `indptr` announces (8 bytes each at most),
/// all against [`MAX_MEMBER_BYTES`]; inflation itself stops at the declared size, so an
/// archive whose headers lie cannot exceed it either.
fn decode_csr_inner(bytes: &[u8]) -> Result<CsrParts, String> {
    let mut archive = ZipArchive::new(Cursor::new(bytes))
        .map_err(|e| format!("not a valid npz (zip) archive: {e}"))?;

    // format
    let name = "format.npy";
    let raw = read_entry(&mut archive, name, SMALL_MEMBER_BYTES, "a format string")?
        .ok_or_else(|| format!("missing entry {name} (not a scipy.sparse save_npz file?)"))?;
    let arr = parse_npy(&raw).map_err(|m| format!("{name}: {m}"))?;
    let fmt = decode_text(&arr).map_err(|m| format!("{name}: {m}"))?;
    if fmt != "csr" {
        return Err(if OTHER_SPARSE_FORMATS.contains(&fmt.as_str()) {
            format!("{name}: sparse matrix format is '{fmt}', only 'csr' is supported")
        } else {
            format!("{name}: unknown sparse matrix format {fmt:?}, only 'csr' is supported")
        });
    }

    // shape
    let name = "shape.npy";
    let raw = read_required(&mut archive, name, SMALL_MEMBER_BYTES, "two integers")?;
    let arr = parse_npy(&raw).map_err(|m| format!("{name}: {m}"))?;
    if arr.shape.len() != 1 || arr.shape[0] != 2 {
        return Err(format!(
            "{name}: expected 2 values, got shape {}",
            shape_repr(&arr.shape)
        ));
    }
    let dims = decode_ints(&arr, |k, v| {
        usize::try_from(v).map_err(|_| format!("dimension {k} is {v}, not a valid size"))
    })
    .map_err(|m| format!("{name}: {m}"))?;
    let (rows, cols) = (dims[0], dims[1]);

    // indptr: its size follows from the shape.
    let name = "indptr.npy";
    let most = member_bytes_for(rows as u128 + 1).ok_or_else(|| {
        format!(
            "shape.npy: {rows} rows need an indptr.npy of more than the {MAX_MEMBER_BYTES} bytes accepted"
        )
    })?;
    let raw = read_required(
        &mut archive,
        name,
        most,
        &format!("rows + 1 = {} integers (shape.npy)", rows as u128 + 1),
    )?;
    let arr = parse_npy(&raw).map_err(|m| format!("{name}: {m}"))?;
    require_1d(&arr).map_err(|m| format!("{name}: {m}"))?;
    let indptr = decode_ints(&arr, |k, v| {
        u64::try_from(v).map_err(|_| format!("negative row pointer {v} at position {k}"))
    })
    .map_err(|m| format!("{name}: {m}"))?;
    drop(raw);
    // The stored entries indptr announces (checked in full by validate_csr below).
    let nnz = indptr.last().copied().unwrap_or(0);
    let most = member_bytes_for(u128::from(nnz)).ok_or_else(|| {
        format!(
            "{name}: announces {nnz} stored entries, more than the {MAX_MEMBER_BYTES} bytes accepted per member allow"
        )
    })?;
    let why = format!("nnz = {nnz} values (the last entry of indptr.npy)");

    // data
    let name = "data.npy";
    let raw = read_required(&mut archive, name, most, &why)?;
    let arr = parse_npy(&raw).map_err(|m| format!("{name}: {m}"))?;
    require_1d(&arr).map_err(|m| format!("{name}: {m}"))?;
    let data = decode_floats(&arr).map_err(|m| format!("{name}: {m}"))?;
    drop(raw);

    // indices
    let name = "indices.npy";
    let raw = read_required(&mut archive, name, most, &why)?;
    let arr = parse_npy(&raw).map_err(|m| format!("{name}: {m}"))?;
    require_1d(&arr).map_err(|m| format!("{name}: {m}"))?;
    let indices = decode_ints(&arr, |k, v| {
        if v < 0 {
            Err(format!("negative column index {v} at position {k}"))
        } else {
            u32::try_from(v)
                .map_err(|_| format!("column index {v} at position {k} exceeds the u32 range"))
        }
    })
    .map_err(|m| format!("{name}: {m}"))?;
    drop(raw);

    validate_csr(rows, cols, &indptr, &indices, data.len())?;
    Ok(CsrParts {
        rows,
        cols,
        indptr,
        indices,
        data,
    })
}

/// Largest npz member inflated: 4 GiB.
pub const MAX_MEMBER_BYTES: u64 = 4 << 30;

/// Largest `format.npy` or `shape.npy` member: the npy preamble and a few values.
const SMALL_MEMBER_BYTES: u64 = NPY_PREAMBLE_BYTES + 1024;

/// Most bytes of an npy preamble (magic, version, header) accepted in an npz member.
const NPY_PREAMBLE_BYTES: u64 = 1 << 16;

/// Most bytes a 1-D npy member of `count` numbers of at most 8 bytes may hold, if within
/// [`MAX_MEMBER_BYTES`].
fn member_bytes_for(count: u128) -> Option<u64> {
    let bytes = count * 8 + u128::from(NPY_PREAMBLE_BYTES);
    u64::try_from(bytes).ok().filter(|&b| b <= MAX_MEMBER_BYTES)
}

/// Reads the whole (decompressed) entry `name`, or `None` if the archive has no such entry.
/// The entry's declared size is checked against `max_bytes` (what `why` allows) before it
/// is inflated, and inflation stops there whatever the archive declares.
fn read_entry(
    archive: &mut ZipArchive<Cursor<&[u8]>>,
    name: &str,
    max_bytes: u64,
    why: &str,
) -> Result<Option<Vec<u8>>, String> {
    let file = match archive.by_name(name) {
        Ok(file) => file,
        Err(zip::result::ZipError::FileNotFound) => return Ok(None),
        Err(e) => return Err(format!("{name}: cannot open zip entry: {e}")),
    };
    let declared = file.size();
    if declared > max_bytes {
        return Err(format!(
            "{name}: declares {declared} bytes uncompressed, more than the {max_bytes} that {why} can take; refused before inflating"
        ));
    }
    let mut buf = Vec::new();
    buf.try_reserve_exact(usize::try_from(declared).unwrap_or(usize::MAX))
        .map_err(|_| format!("{name}: cannot allocate {declared} bytes"))?;
    file.take(declared.saturating_add(1))
        .read_to_end(&mut buf)
        .map_err(|e| format!("{name}: cannot read zip entry: {e}"))?;
    if buf.len() as u64 > declared {
        return Err(format!(
            "{name}: inflates to more than the {declared} bytes it declares"
        ));
    }
    Ok(Some(buf))
}

/// [`read_entry`] for an entry that must be present.
fn read_required(
    archive: &mut ZipArchive<Cursor<&[u8]>>,
    name: &str,
    max_bytes: u64,
    why: &str,
) -> Result<Vec<u8>, String> {
    read_entry(archive, name, max_bytes, why)?.ok_or_else(|| format!("missing entry {name}"))
}

/// Requires a 1-D array.
fn require_1d(arr: &NpyArray<'_>) -> Result<(), String> {
    if arr.shape.len() == 1 {
        Ok(())
    } else {
        Err(format!(
            "expected a 1-D array, got shape {}",
            shape_repr(&arr.shape)
        ))
    }
}

/// Encodes `m` as a `scipy.sparse.load_npz` CSR file in memory (`path` names the file in error
/// messages).
pub fn encode_csr(
    m: &crate::sparse::CsrMatrix,
    path: &std::path::Path,
) -> Result<Vec<u8>, IoError> {
    encode_csr_npz(path, m.rows, m.cols, &m.indptr, &m.indices, &m.data)
}

// ---------------------------------------------------------------------------
// Tests
// ---------------------------------------------------------------------------

#[cfg(test)]
mod tests {
    use super::super::test_support::{Rng, p};
    use super::super::{decode_npy_f32, encode_npy_f32};
    use super::*;

    fn random_csr(rows: usize, cols: usize, seed: u64) -> CsrParts {
        let mut rng = Rng(seed);
        let mut indptr = vec![0u64];
        let mut indices = Vec::new();
        let mut data = Vec::new();
        for _ in 0..rows {
            let n = rng.below(8);
            for _ in 0..n {
                indices.push(rng.below(cols as u64) as u32);
                data.push((rng.next() >> 40) as f32 / 1000.0 - 5000.0);
            }
            indptr.push(indices.len() as u64);
        }
        CsrParts {
            rows,
            cols,
            indptr,
            indices,
            data,
        }
    }

    fn encode(m: &CsrParts) -> Vec<u8> {
        encode_csr_npz(p(), m.rows, m.cols, &m.indptr, &m.indices, &m.data).unwrap()
    }

    fn format_message(r: Result<CsrParts, IoError>) -> String {
        match r {
            Err(IoError::Format { message, .. }) => message,
            other => panic!("expected a format error, got {other:?}"),
        }
    }

    /// Entries of an npz archive, decompressed, in archive order.
    fn entries(bytes: &[u8]) -> Vec<(String, Vec<u8>)> {
        let mut a = ZipArchive::new(Cursor::new(bytes)).unwrap();
        (0..a.len())
            .map(|i| {
                let mut f = a.by_index(i).unwrap();
                let mut buf = Vec::new();
                f.read_to_end(&mut buf).unwrap();
                (f.name().unwrap().into_owned(), buf)
            })
            .collect()
    }

    /// Builds a zip from entries with the given compression method.
    fn build_zip(entries: &[(String, Vec<u8>)], method: CompressionMethod) -> Vec<u8> {
        let mut zw = ZipWriter::new(Cursor::new(Vec::new()));
        let opts = SimpleFileOptions::default().compression_method(method);
        for (name, bytes) in entries {
            zw.start_file(name.as_str(), opts).unwrap();
            zw.write_all(bytes).unwrap();
        }
        zw.finish().unwrap().into_inner()
    }

    /// Replaces one entry of an npz (or removes it if `bytes` is `None`).
    fn with_entry(npz: &[u8], name: &str, bytes: Option<Vec<u8>>) -> Vec<u8> {
        let mut list = entries(npz);
        let pos = list.iter().position(|(n, _)| n == name).unwrap();
        match bytes {
            Some(b) => list[pos].1 = b,
            None => {
                list.remove(pos);
            }
        }
        build_zip(&list, CompressionMethod::Stored)
    }

    fn npy_i8(values: &[i64]) -> Vec<u8> {
        let mut out = npy_header("<i8", &[values.len()]);
        for v in values {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    fn npy_i4(values: &[i32]) -> Vec<u8> {
        let mut out = npy_header("<i4", &[values.len()]);
        for v in values {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    fn small() -> CsrParts {
        // 4x5 with an empty first and third row.
        CsrParts {
            rows: 4,
            cols: 5,
            indptr: vec![0, 0, 2, 2, 4],
            indices: vec![4, 1, 0, 4],
            data: vec![1.5, -2.0, 3.25, 0.0],
        }
    }

    #[test]
    fn csr_round_trip_with_empty_rows() {
        let m = small();
        assert_eq!(decode_csr_npz(p(), &encode(&m)).unwrap(), m);
    }

    #[test]
    fn csr_round_trip_empty_matrix() {
        for (rows, cols) in [(0, 0), (3, 7), (0, 4)] {
            let m = CsrParts {
                rows,
                cols,
                indptr: vec![0; rows + 1],
                indices: vec![],
                data: vec![],
            };
            assert_eq!(decode_csr_npz(p(), &encode(&m)).unwrap(), m);
        }
    }

    #[test]
    fn csr_round_trip_random() {
        let m = random_csr(50, 70, 12345);
        assert!(m.data.len() > 100);
        assert_eq!(decode_csr_npz(p(), &encode(&m)).unwrap(), m);
    }

    #[test]
    fn csr_file_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.npz");
        let m = random_csr(9, 3, 7);
        std::fs::write(&path, encode(&m)).unwrap();
        assert_eq!(read_csr_npz(&path).unwrap(), m);
        let missing = dir.path().join("missing.npz");
        assert!(matches!(read_csr_npz(&missing), Err(IoError::Io { .. })));
    }

    #[test]
    fn csr_entries_and_dtypes() {
        let bytes = encode(&small());
        let list = entries(&bytes);
        let names: Vec<&str> = list.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(
            names,
            [
                "indices.npy",
                "indptr.npy",
                "format.npy",
                "shape.npy",
                "data.npy"
            ]
        );
        let get = |name: &str| &list.iter().find(|(n, _)| n == name).unwrap().1;
        let fmt = parse_npy(get("format.npy")).unwrap();
        assert_eq!((fmt.descr.as_str(), fmt.shape.len()), ("|S3", 0));
        assert_eq!(fmt.payload, b"csr");
        let shape = parse_npy(get("shape.npy")).unwrap();
        assert_eq!(
            (shape.descr.as_str(), shape.shape.clone()),
            ("<i8", vec![2])
        );
        assert_eq!(parse_npy(get("data.npy")).unwrap().descr, "<f4");
        assert_eq!(parse_npy(get("indices.npy")).unwrap().descr, "<i4");
        assert_eq!(parse_npy(get("indptr.npy")).unwrap().descr, "<i4");
        // No _is_array entry: scipy builds a csr_matrix.
        assert!(!names.contains(&"_is_array.npy"));
        // Stored, not deflated.
        let mut a = ZipArchive::new(Cursor::new(bytes.as_slice())).unwrap();
        for i in 0..a.len() {
            assert_eq!(
                a.by_index(i).unwrap().compression(),
                CompressionMethod::Stored
            );
        }
    }

    #[test]
    fn index_dtype_choice() {
        let limit = I4_INDEX_LIMIT;
        assert!(index_fits_i4(0, 0, limit));
        assert!(index_fits_i4(i32::MAX as usize, i32::MAX as usize, limit));
        assert!(!index_fits_i4(i32::MAX as usize + 1, 5, limit));
        assert!(!index_fits_i4(5, i32::MAX as usize + 1, limit));

        // Force <i8 with a tiny limit: nnz 4 > 3.
        let m = small();
        let bytes =
            encode_csr_npz_with_limit(p(), m.rows, m.cols, &m.indptr, &m.indices, &m.data, 3)
                .unwrap();
        let list = entries(&bytes);
        for name in ["indices.npy", "indptr.npy"] {
            let raw = &list.iter().find(|(n, _)| n == name).unwrap().1;
            assert_eq!(parse_npy(raw).unwrap().descr, "<i8", "{name}");
        }
        assert_eq!(decode_csr_npz(p(), &bytes).unwrap(), m);
        // cols 5 > 4 also forces <i8 even though nnz 4 <= 4.
        let bytes =
            encode_csr_npz_with_limit(p(), m.rows, m.cols, &m.indptr, &m.indices, &m.data, 4)
                .unwrap();
        let raw = &entries(&bytes)[0].1;
        assert_eq!(parse_npy(raw).unwrap().descr, "<i8");
        // Limit 5 allows <i4.
        let bytes =
            encode_csr_npz_with_limit(p(), m.rows, m.cols, &m.indptr, &m.indices, &m.data, 5)
                .unwrap();
        let raw = &entries(&bytes)[0].1;
        assert_eq!(parse_npy(raw).unwrap().descr, "<i4");
    }

    #[test]
    fn deflated_and_mixed_dtypes_are_read() {
        // As scipy's save_npz(compressed=True) would write it, with
        // _is_array, <f8 data, <i8 indices and <u4 indptr.
        let m = small();
        let mut data = npy_header("<f8", &[m.data.len()]);
        for v in &m.data {
            data.extend_from_slice(&f64::from(*v).to_le_bytes());
        }
        let mut indptr = npy_header("<u4", &[m.indptr.len()]);
        for v in &m.indptr {
            indptr.extend_from_slice(&(*v as u32).to_le_bytes());
        }
        let mut is_array = npy_header("|b1", &[]);
        is_array.push(1);
        let mut format = npy_header("|S3", &[]);
        format.extend_from_slice(b"csr");
        let list = vec![
            (
                "indices.npy".to_owned(),
                npy_i8(&m.indices.iter().map(|&v| i64::from(v)).collect::<Vec<_>>()),
            ),
            ("indptr.npy".to_owned(), indptr),
            ("format.npy".to_owned(), format),
            ("shape.npy".to_owned(), npy_i8(&[4, 5])),
            ("data.npy".to_owned(), data),
            ("_is_array.npy".to_owned(), is_array),
        ];
        let bytes = build_zip(&list, CompressionMethod::Deflated);
        let mut a = ZipArchive::new(Cursor::new(bytes.as_slice())).unwrap();
        assert_eq!(
            a.by_index(0).unwrap().compression(),
            CompressionMethod::Deflated
        );
        assert_eq!(decode_csr_npz(p(), &bytes).unwrap(), m);
    }

    #[test]
    fn unicode_format_string_is_accepted() {
        let m = small();
        let mut format = npy_header("<U3", &[]);
        for c in "csr".chars() {
            format.extend_from_slice(&(c as u32).to_le_bytes());
        }
        let bytes = with_entry(&encode(&m), "format.npy", Some(format));
        assert_eq!(decode_csr_npz(p(), &bytes).unwrap(), m);
    }

    #[test]
    fn encoding_is_deterministic() {
        let m = random_csr(50, 70, 99);
        let a = encode(&m);
        let b = encode(&m);
        assert_eq!(a, b);
        let x = encode_npy_f32(p(), &[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]).unwrap();
        let y = encode_npy_f32(p(), &[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]).unwrap();
        assert_eq!(x, y);
    }

    #[test]
    fn encoder_validates_inputs() {
        let m = small();
        let cases: Vec<(Vec<u64>, Vec<u32>, usize, &str)> = vec![
            (vec![0, 0, 2, 2], m.indices.clone(), 4, "indptr.npy"), // wrong length
            (vec![1, 1, 2, 2, 4], m.indices.clone(), 4, "indptr.npy"), // not starting at 0
            (vec![0, 3, 2, 2, 4], m.indices.clone(), 4, "indptr.npy"), // decreasing
            (vec![0, 0, 2, 2, 3], m.indices.clone(), 4, "indptr.npy"), // wrong end
            (m.indptr.clone(), vec![4, 1, 0, 5], 4, "indices.npy"), // index >= cols
            (m.indptr.clone(), m.indices.clone(), 3, "data.npy"),   // data length
        ];
        for (indptr, indices, ndata, entry) in cases {
            let data = vec![0.0f32; ndata];
            match encode_csr_npz(p(), m.rows, m.cols, &indptr, &indices, &data) {
                Err(IoError::Format { message, .. }) => {
                    assert!(message.contains(entry), "{message}");
                }
                other => panic!("expected format error, got {other:?}"),
            }
        }
    }

    #[test]
    fn corrupt_inputs_are_rejected() {
        let good = encode(&small());

        // Random bytes and an empty file.
        let mut rng = Rng(1);
        let junk: Vec<u8> = (0..1000).map(|_| rng.next() as u8).collect();
        let msg = format_message(decode_csr_npz(p(), &junk));
        assert!(msg.contains("zip"), "{msg}");
        let msg = format_message(decode_csr_npz(p(), &[]));
        assert!(msg.contains("zip"), "{msg}");

        // Truncated file at every length: never panics, always a format error.
        for len in 0..good.len() {
            let msg = format_message(decode_csr_npz(p(), &good[..len]));
            assert!(!msg.is_empty());
        }

        // Truncated npy entry inside a valid zip.
        let list = entries(&good);
        let data = &list.iter().find(|(n, _)| n == "data.npy").unwrap().1;
        let bytes = with_entry(&good, "data.npy", Some(data[..data.len() - 3].to_vec()));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(
            msg.contains("data.npy") && msg.contains("truncated"),
            "{msg}"
        );

        // indptr not monotone.
        let bytes = with_entry(&good, "indptr.npy", Some(npy_i4(&[0, 3, 2, 2, 4])));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(
            msg.contains("indptr.npy") && msg.contains("decreases"),
            "{msg}"
        );

        // indptr with the wrong length / wrong end / negative value.
        for bad in [&[0, 0, 2, 4][..], &[0, 0, 2, 2, 3], &[0, -1, 2, 2, 4]] {
            let bytes = with_entry(&good, "indptr.npy", Some(npy_i4(bad)));
            let msg = format_message(decode_csr_npz(p(), &bytes));
            assert!(msg.contains("indptr.npy"), "{msg}");
        }

        // Index >= cols, negative index.
        let bytes = with_entry(&good, "indices.npy", Some(npy_i4(&[4, 1, 5, 4])));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(
            msg.contains("indices.npy") && msg.contains("out of range"),
            "{msg}"
        );
        let bytes = with_entry(&good, "indices.npy", Some(npy_i4(&[4, -1, 0, 4])));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(
            msg.contains("indices.npy") && msg.contains("negative"),
            "{msg}"
        );

        // Wrong format string.
        let mut csc = npy_header("|S3", &[]);
        csc.extend_from_slice(b"csc");
        let bytes = with_entry(&good, "format.npy", Some(csc));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(msg.contains("format.npy") && msg.contains("'csc'"), "{msg}");

        // Missing entries.
        for name in [
            "data.npy",
            "format.npy",
            "shape.npy",
            "indices.npy",
            "indptr.npy",
        ] {
            let bytes = with_entry(&good, name, None);
            let msg = format_message(decode_csr_npz(p(), &bytes));
            assert!(msg.contains("missing") && msg.contains(name), "{msg}");
        }

        // Bad magic, bad header, wrong dtype, big-endian, negative shape.
        let list = entries(&good);
        let mut data = list
            .iter()
            .find(|(n, _)| n == "data.npy")
            .unwrap()
            .1
            .clone();
        data[1] = b'X';
        let bytes = with_entry(&good, "data.npy", Some(data));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(msg.contains("data.npy") && msg.contains("magic"), "{msg}");

        let mut data = list
            .iter()
            .find(|(n, _)| n == "data.npy")
            .unwrap()
            .1
            .clone();
        data[10] = b'[';
        let bytes = with_entry(&good, "data.npy", Some(data));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(msg.contains("data.npy") && msg.contains("header"), "{msg}");

        let bytes = with_entry(&good, "data.npy", Some(npy_i4(&[1, 2, 3, 4])));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(msg.contains("data.npy") && msg.contains("'<i4'"), "{msg}");

        let mut be = npy_header(">f4", &[4]);
        be.extend_from_slice(&[0u8; 16]);
        let bytes = with_entry(&good, "data.npy", Some(be));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(
            msg.contains("data.npy") && msg.contains("big-endian"),
            "{msg}"
        );

        let bytes = with_entry(&good, "shape.npy", Some(npy_i8(&[-4, 5])));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(msg.contains("shape.npy"), "{msg}");
    }

    #[test]
    fn absurd_header_shape_does_not_allocate() {
        // A header announcing 2^60 elements with only 16 bytes of data.
        let good = encode(&small());
        let mut huge = npy_header("<f4", &[1 << 60]);
        huge.extend_from_slice(&[0u8; 16]);
        let bytes = with_entry(&good, "data.npy", Some(huge));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(
            msg.contains("data.npy") && msg.contains("truncated"),
            "{msg}"
        );

        let mut overflow = npy_header("<f8", &[1 << 40, 1 << 40]);
        overflow.extend_from_slice(&[0u8; 16]);
        let bytes = with_entry(&good, "data.npy", Some(overflow));
        let msg = format_message(decode_csr_npz(p(), &bytes));
        assert!(
            msg.contains("data.npy") && msg.contains("too large"),
            "{msg}"
        );

        // Deeply nested header.
        let mut deep = b"\x93NUMPY\x01\x00".to_vec();
        let text = format!("{}\n", "(".repeat(5000));
        deep.extend_from_slice(&(text.len() as u16).to_le_bytes());
        deep.extend_from_slice(text.as_bytes());
        let Err(IoError::Format { message, .. }) = decode_npy_f32(p(), &deep) else {
            panic!("expected format error");
        };
        assert!(message.contains("deep"), "{message}");
    }
}
