//! H on disk: the scipy CSR `.npz` of a system matrix, its offset `.npy` and its JSON
//! sidecar, read back and checked (structure, finite values, object shape, offset length).
//! Written by `output.rs`; read by `reconstruct`, `calibrate --matrix`, depth stacks and
//! datasets.

use crate::sparse::CsrMatrix;

/// An H read back from disk with what is known about its shape.
#[derive(Clone, Debug)]
pub struct LoadedMatrix {
    /// H.
    pub h: CsrMatrix,
    /// Object size (width, height).
    pub object: (usize, usize),
    /// Object planes: 1, or 3 for a colour H (column blocks R, G, B).
    pub planes: usize,
    /// Offset vector (capture of an all-black object), if found.
    pub offset: Option<Vec<f32>>,
    /// Where the offset came from.
    pub offset_path: Option<std::path::PathBuf>,
}

/// The offset file that belongs to a matrix file: `H.npz` → `offset.npy`,
/// `H_est.npz` → `offset_est.npy` (same directory; the part of the stem after "H" is kept).
pub fn default_offset_path(matrix: &std::path::Path) -> std::path::PathBuf {
    let stem = matrix.file_stem().and_then(|s| s.to_str()).unwrap_or("H");
    let suffix = stem.strip_prefix('H').unwrap_or("");
    matrix.with_file_name(format!("offset{suffix}.npy"))
}

/// Reads a scipy CSR `.npz` and checks its structure and that every value is finite.
pub fn read_checked_csr(path: &std::path::Path) -> Result<CsrMatrix, crate::IoError> {
    use crate::IoError;
    let parts = crate::npz::read_csr_npz(path)?;
    let h = CsrMatrix {
        rows: parts.rows,
        cols: parts.cols,
        indptr: parts.indptr,
        indices: parts.indices,
        data: parts.data,
    };
    h.check().map_err(|m| IoError::format(path, m))?;
    crate::check_finite(path, "data.npy: entry", &h.data)?;
    Ok(h)
}

/// Reads H from a scipy CSR `.npz`. The object shape comes from `object` if given, else from
/// the JSON sidecar (`object_px` in `<stem>.json`), else a square object is assumed if the
/// column count is a perfect square. The offset is read from `offset` if given, else from
/// [`default_offset_path`] if that file exists.
pub fn load_matrix(
    path: &std::path::Path,
    object: Option<(usize, usize)>,
    offset: Option<&std::path::Path>,
) -> Result<LoadedMatrix, crate::IoError> {
    use crate::IoError;
    let h = read_checked_csr(path)?;
    let sidecar = || -> Option<serde_json::Value> {
        let text = crate::read_text(&path.with_extension("json")).ok()?;
        serde_json::from_str(&text).ok()
    };
    let sidecar_shape = || -> Option<(usize, usize)> {
        let v = sidecar()?;
        let o = v.get("object_px")?.as_array()?;
        Some((o.first()?.as_u64()? as usize, o.get(1)?.as_u64()? as usize))
    };
    // A colour H says so in its sidecar (`object_primaries`); without one, an object shape
    // given with a third of H's columns means three planes.
    let sidecar_planes = sidecar()
        .and_then(|v| v.get("object_primaries")?.as_array().map(|a| a.len()))
        .filter(|&n| n > 0);
    let planes_of = |o: (usize, usize)| {
        sidecar_planes.unwrap_or_else(|| {
            let px = o.0.saturating_mul(o.1);
            if px > 0 && h.cols == 3 * px { 3 } else { 1 }
        })
    };
    let object = match object.or_else(sidecar_shape) {
        Some(o) => o,
        None => {
            let s = (h.cols as f64).sqrt().round() as usize;
            if s * s != h.cols {
                return Err(IoError::format(
                    path,
                    format!(
                        "{} columns are not a square object and no sidecar gives object_px; pass --object WxH",
                        h.cols
                    ),
                ));
            }
            (s, s)
        }
    };
    let planes = planes_of(object);
    if object
        .0
        .checked_mul(object.1)
        .and_then(|n| n.checked_mul(planes))
        != Some(h.cols)
    {
        return Err(IoError::format(
            path,
            format!(
                "the object {}x{}{} has {} pixels but H has {} columns",
                object.0,
                object.1,
                if planes > 1 {
                    format!("x{planes}")
                } else {
                    String::new()
                },
                object.0.saturating_mul(object.1).saturating_mul(planes),
                h.cols
            ),
        ));
    }
    let off_path = match offset {
        Some(p) => Some(p.to_path_buf()),
        None => Some(default_offset_path(path)).filter(|p| p.exists()),
    };
    let offset = match &off_path {
        Some(p) => {
            let (_, v) = crate::npz::read_npy_f32(p)?;
            crate::check_finite(p, "value", &v)?;
            if v.len() != h.rows {
                return Err(IoError::format(
                    p,
                    format!("has {} values but H has {} rows", v.len(), h.rows),
                ));
            }
            Some(v)
        }
        None => None,
    };
    Ok(LoadedMatrix {
        h,
        object,
        planes,
        offset,
        offset_path: off_path,
    })
}
