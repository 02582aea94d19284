//! The depth stack of H: one system matrix per object-plane depth, and the block matrix
//! [H₁ … H_N] of the layered model g = Σ_d (H_d f_d + o_d) + n.
//!
//! Model: the paper's H holds at one distance (its §5: "for the reconstruction of objects at
//! multiple depths, it is necessary to characterize the system matrix at different
//! distances"). A depth stack moves the object plane (the display's extent and pixel grid, in
//! mm) along the camera ray's direction beyond the front face, keeping the camera focus and
//! everything else of the scene; `matrix::compute_matrix_stack` computes all depths in one pass.
//! The layered model treats the planes as additive emitters without occlusion (each a display
//! at its depth with its own black level), the usual model of layered lensless 3-D imaging;
//! `offset_stack.npy` is then Σ_d o_d, the capture with every layer black.
//!
//! Files (in one directory): per depth `H_<D>mm.npz`, `offset_<D>mm.npy`, `H_<D>mm.json`
//! (each exactly what `stscam matrix --depth-mm D` writes under the plain names), and
//! `H_stack.npz` (the N·K-column block matrix, scipy CSR), `offset_stack.npy` and
//! `H_stack.json` (depths, object and crop shapes, the block layout, per-depth coverage).

use std::path::{Path, PathBuf};

use crate::IoError;
use crate::sparse::CsrMatrix;

/// Most depths one stack may hold.
pub const MAX_DEPTHS: usize = 256;

/// Name of the block matrix file of a stack.
pub const STACK_MATRIX: &str = "H_stack.npz";
/// Name of the layered offset file of a stack.
pub const STACK_OFFSET: &str = "offset_stack.npy";
/// Name of the stack's sidecar.
pub const STACK_SIDECAR: &str = "H_stack.json";

/// Nearest object-plane depth accepted, mm (1 µm; a depth label keeps 6 significant digits).
pub const MIN_DEPTH_MM: f64 = 1e-3;
/// Farthest object-plane depth accepted, mm: the working range of the user side
/// ([`crate::limits::MAX_COORD_MM`], 10 km).
pub const MAX_DEPTH_MM: f64 = crate::limits::MAX_COORD_MM;

/// True for a finite depth within [[`MIN_DEPTH_MM`], [`MAX_DEPTH_MM`]].
pub fn depth_in_range(d: f64) -> bool {
    (MIN_DEPTH_MM..=MAX_DEPTH_MM).contains(&d)
}

/// Parses `D`, `D1,D2,…` or `START:STOP:STEPS` (inclusive, evenly spaced) into depths in mm,
/// sorted ascending. Every depth must be finite and positive, with no repeats.
pub fn parse_depths(spec: &str) -> Result<Vec<f64>, String> {
    let num = |t: &str| {
        t.trim()
            .parse::<f64>()
            .map_err(|_| format!("{t:?} is not a number"))
    };
    let mut depths: Vec<f64> = if let Some((a, rest)) = spec.split_once(':') {
        let (b, n) = rest
            .split_once(':')
            .ok_or("expected START:STOP:STEPS, e.g. 300:650:8")?;
        let (a, b) = (num(a)?, num(b)?);
        let n: usize = n
            .trim()
            .parse()
            .map_err(|_| format!("STEPS {n:?} is not a whole number"))?;
        if n == 0 || n > MAX_DEPTHS || (n == 1 && a != b) || (n > 1 && a >= b) {
            return Err(format!(
                "START:STOP:STEPS needs START < STOP and 2 to {MAX_DEPTHS} steps (or START = STOP and 1 step)"
            ));
        }
        (0..n)
            .map(|i| {
                if i + 1 == n {
                    b
                } else {
                    a + (b - a) * i as f64 / (n - 1) as f64
                }
            })
            .collect()
    } else {
        spec.split(',').map(num).collect::<Result<_, _>>()?
    };
    if depths.len() > MAX_DEPTHS {
        return Err(format!("more than {MAX_DEPTHS} depths"));
    }
    if let Some(d) = depths.iter().find(|d| !depth_in_range(**d)) {
        return Err(format!(
            "depth {d} mm: must be a distance in [{MIN_DEPTH_MM}, {MAX_DEPTH_MM}] mm"
        ));
    }
    depths.sort_by(f64::total_cmp);
    if let Some(w) = depths.windows(2).find(|w| w[0] == w[1]) {
        return Err(format!("depth {} mm is given twice", w[0]));
    }
    Ok(depths)
}

/// Checks a `--depth-mm` value: the object plane must be a positive distance in front of the
/// plate.
pub fn check_depth(depth_mm: f64) -> Result<(), String> {
    let spec = depth_label(depth_mm);
    parse_depths(&spec)
        .map(|_| ())
        .map_err(|m| format!("--depth-mm {spec}: {m}"))
}

/// A depth as it appears in file names: the shortest decimal that reads back exactly
/// (`550`, `412.5`).
pub fn depth_label(depth_mm: f64) -> String {
    format!("{depth_mm}")
}

/// The per-depth file names of a stack: (`H_<D>mm.npz`, `offset_<D>mm.npy`, `H_<D>mm.json`).
pub fn depth_file_names(depth_mm: f64) -> [String; 3] {
    let l = depth_label(depth_mm);
    [
        format!("H_{l}mm.npz"),
        format!("offset_{l}mm.npy"),
        format!("H_{l}mm.json"),
    ]
}

/// How much of the capture an object of the display's size fills at one depth, read off H.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Coverage {
    /// Fraction of H's rows (capture pixels × channels) with at least one stored entry: the
    /// part of the capture the object's replicas reach (1 = the object fills the capture).
    pub capture_filled: f64,
    /// Fraction of H's columns (object pixels) with at least one stored entry: the part of the
    /// object the capture sees (1 = the capture sees the whole object).
    pub object_seen: f64,
}

/// The [`Coverage`] of `h`.
pub fn coverage(h: &CsrMatrix) -> Coverage {
    let rows = (0..h.rows).filter(|&r| !h.row_range(r).is_empty()).count();
    let mut seen = vec![false; h.cols];
    for &c in &h.indices {
        seen[c as usize] = true;
    }
    let cols = seen.iter().filter(|&&s| s).count();
    Coverage {
        capture_filled: rows as f64 / h.rows.max(1) as f64,
        object_seen: cols as f64 / h.cols.max(1) as f64,
    }
}

/// A stack read back from disk.
#[derive(Clone, Debug)]
pub struct LoadedStack {
    /// Depths in mm, ascending.
    pub depths_mm: Vec<f64>,
    /// H_d, one per depth (the column blocks of the block matrix).
    pub blocks: Vec<CsrMatrix>,
    /// Object size (width, height) of one plane.
    pub object: (usize, usize),
    /// Per-depth offsets o_d (from the files the sidecar names), where present.
    pub offsets: Vec<Option<Vec<f32>>>,
    /// The offset of the layered model: `--offset` if given, else `offset_stack.npy`.
    pub joint_offset: Option<Vec<f32>>,
    /// Where the joint offset came from.
    pub joint_offset_path: Option<PathBuf>,
}

/// True if `path` is a stack: its sidecar (`<stem>.json`) lists `depths_mm`.
/// The sidecar is read like every input ([`crate::input::read_text`]: a regular file of at
/// most 64 MiB, so a FIFO or a device is never opened for reading).
/// A sidecar that exists but is not a readable regular file (a FIFO, a device, a folder, too
/// large) also counts as a stack's, so that [`load_stack`] reports it instead of the matrix
/// being read as a plain H.
pub fn is_stack(path: &Path) -> bool {
    let side = path.with_extension("json");
    match crate::input::read_text(&side) {
        Ok(t) => serde_json::from_str::<serde_json::Value>(&t)
            .ok()
            .is_some_and(|v| v.get("depths_mm").is_some()),
        Err(_) => std::fs::metadata(&side).is_ok(),
    }
}

/// Reads a stack from its block matrix (`H_stack.npz`) and sidecar (`H_stack.json`, which
/// gives `depths_mm`, `object_px` and the per-depth offset files). Checks that the column
/// count is depths × object pixels and that every offset has one value per row.
pub fn load_stack(path: &Path, offset: Option<&Path>) -> Result<LoadedStack, IoError> {
    let side_path = path.with_extension("json");
    let text = crate::input::read_text(&side_path)?;
    let side: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| IoError::format(&side_path, e))?;
    let bad = |key: &str, what: &str| IoError::format(&side_path, format!("{key}: {what}"));
    let depths_mm: Vec<f64> = side
        .get("depths_mm")
        .and_then(|v| v.as_array())
        .ok_or_else(|| bad("depths_mm", "missing (not a depth stack)"))?
        .iter()
        .map(|v| v.as_f64().filter(|d| depth_in_range(*d)))
        .collect::<Option<_>>()
        .ok_or_else(|| {
            bad(
                "depths_mm",
                &format!("every depth must be a number in [{MIN_DEPTH_MM}, {MAX_DEPTH_MM}] mm"),
            )
        })?;
    if depths_mm.len() > MAX_DEPTHS {
        return Err(bad("depths_mm", &format!("more than {MAX_DEPTHS} depths")));
    }
    if depths_mm.is_empty() || depths_mm.windows(2).any(|w| w[0] >= w[1]) {
        return Err(bad(
            "depths_mm",
            "must be non-empty and strictly increasing",
        ));
    }
    let object = side
        .get("object_px")
        .and_then(|o| Some((o.get(0)?.as_u64()? as usize, o.get(1)?.as_u64()? as usize)))
        .ok_or_else(|| bad("object_px", "missing or not [width, height]"))?;
    let h = crate::hfile::read_checked_csr(path)?;
    let k = object.0.checked_mul(object.1).unwrap_or(0);
    if k == 0 || k.checked_mul(depths_mm.len()) != Some(h.cols) {
        return Err(IoError::format(
            path,
            format!(
                "{} columns, but {} depths of a {}x{} object need {}",
                h.cols,
                depths_mm.len(),
                object.0,
                object.1,
                k.saturating_mul(depths_mm.len())
            ),
        ));
    }
    let blocks = h
        .hsplit(depths_mm.len())
        .ok_or_else(|| IoError::format(path, "cannot split the columns into depth blocks"))?;
    let read_offset = |p: &Path| -> Result<Vec<f32>, IoError> {
        let (_, v) = crate::npz::read_npy_f32(p)?;
        // As the 2-D path (`io::hfile::load_matrix`): a NaN or infinite offset is refused.
        crate::check_finite(p, "value", &v)?;
        if v.len() != h.rows {
            return Err(IoError::format(
                p,
                format!("has {} values but H has {} rows", v.len(), h.rows),
            ));
        }
        Ok(v)
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut offsets = Vec::with_capacity(depths_mm.len());
    for &d in &depths_mm {
        let p = dir.join(&depth_file_names(d)[1]);
        offsets.push(if p.exists() {
            Some(read_offset(&p)?)
        } else {
            None
        });
    }
    let joint_offset_path = match offset {
        Some(p) => Some(p.to_path_buf()),
        None => Some(dir.join(STACK_OFFSET)).filter(|p| p.exists()),
    };
    let joint_offset = joint_offset_path.as_deref().map(read_offset).transpose()?;
    Ok(LoadedStack {
        depths_mm,
        blocks,
        object,
        offsets,
        joint_offset,
        joint_offset_path,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_depth_says_what_the_cli_says() {
        assert_eq!(check_depth(412.5), Ok(()));
        assert_eq!(
            check_depth(-5.0).unwrap_err(),
            "--depth-mm -5: depth -5 mm: must be a distance in [0.001, 10000000] mm"
        );
        assert!(check_depth(1e300).is_err());
        assert!(check_depth(5e-324).is_err());
        assert_eq!(check_depth(1e7), Ok(()));
        assert!(check_depth(f64::NAN).is_err());
        assert!(check_depth(0.0).is_err());
    }

    #[test]
    fn depth_lists_and_ranges() {
        assert_eq!(parse_depths("550").unwrap(), vec![550.0]);
        assert_eq!(
            parse_depths("600, 400,500").unwrap(),
            vec![400.0, 500.0, 600.0]
        );
        assert_eq!(
            parse_depths("300:650:8").unwrap(),
            vec![300.0, 350.0, 400.0, 450.0, 500.0, 550.0, 600.0, 650.0]
        );
        assert_eq!(parse_depths("400:400:1").unwrap(), vec![400.0]);
        for bad in [
            "",
            "a",
            "0",
            "-5",
            "400,400",
            "650:300:8",
            "300:650:1",
            "300:650",
            "1:2:x",
        ] {
            assert!(parse_depths(bad).is_err(), "{bad}");
        }
        assert_eq!(depth_file_names(412.5)[0], "H_412.5mm.npz");
        assert_eq!(depth_file_names(550.0)[1], "offset_550mm.npy");
    }
}
