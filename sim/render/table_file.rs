//! The camera-side table on disk: one file per (design, crop, table settings) in a cache
//! directory, named by the key, so that every run and every shard of a dataset with the same
//! design reads the same table.
//!
//! Format (little-endian): the magic `STSCAMCT`, the format version (u64), the design key
//! (2 × u64), width, height, camera samples, representatives per pixel, seed and the number
//! of representatives (u64 each), the pixel offsets (width·height + 1 × u64), the
//! representatives (9 × 8 bytes each: exit point x, y; direction x, y, z; wavelength; the two
//! coefficients, as f64 bits; the replica key) and a check word over everything before it.
//! A file is written under a temporary name and renamed when complete
//! ([`crate::io::atomic::write_atomic`]), so concurrent runs that build the same table race
//! harmlessly (the tables are identical, the last rename wins) and a reader never sees half a
//! file. A file that fails its checks (size, key, check word) is rebuilt and replaced.

use std::path::{Path, PathBuf};

use super::camera_table::{CameraTable, REP_BYTES, Rep, TableError, TableSettings, hash_bytes};
use crate::io::IoError;
use crate::system::System;

/// The file format's version (part of every file's name).
pub const FORMAT_VERSION: u64 = 1;

const MAGIC: &[u8; 8] = b"STSCAMCT";

/// Header words after the magic.
const HEADER_WORDS: usize = 10;

/// Seed of the check word.
const CHECK_SEED: u64 = 0x5EED_C4EC_0000_0001;

/// Where a table came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum TableOrigin {
    /// Read from the cache.
    Read,
    /// Drawn now and written to the cache (none was there).
    Built,
    /// The cached file failed its checks; drawn again and replaced.
    Rebuilt,
}

/// A table from the cache ([`cached`]).
#[derive(Debug)]
pub struct Cached {
    /// The table.
    pub table: CameraTable,
    /// Where it came from.
    pub origin: TableOrigin,
    /// Its file.
    pub path: PathBuf,
    /// Why a cached file was rebuilt.
    pub note: Option<String>,
}

/// The cache file of `sys`'s table with `ts` in `dir`.
pub fn table_path(sys: &System, ts: &TableSettings, dir: &Path) -> PathBuf {
    let key = super::camera_table::design_key(sys);
    dir.join(format!(
        "camera-table-v{FORMAT_VERSION}-{:016x}{:016x}-{}x{}-spp{}-reps{}-seed{}.bin",
        key[0], key[1], sys.camera.width_px, sys.camera.height_px, ts.spp, ts.reps, ts.seed
    ))
}

/// `sys`'s table with `ts` from the cache directory `dir`: read when a valid file is there,
/// else drawn ([`super::camera_table::build`]) and written (the directory is created).
pub fn cached(
    sys: &System,
    ts: &TableSettings,
    dir: &Path,
    progress: bool,
) -> Result<Cached, TableError> {
    super::camera_table::check_table_limits(sys, ts)?;
    let path = table_path(sys, ts, dir);
    let (mut origin, mut note) = (TableOrigin::Built, None);
    if path.exists() {
        match read(&path, sys, ts) {
            Ok(table) => {
                return Ok(Cached {
                    table,
                    origin: TableOrigin::Read,
                    path,
                    note,
                });
            }
            Err(TableError::Io(e @ IoError::Format { .. })) => {
                origin = TableOrigin::Rebuilt;
                note = Some(e.to_string());
            }
            Err(e) => return Err(e),
        }
    }
    let table = super::camera_table::build(sys, ts, progress)?;
    std::fs::create_dir_all(dir).map_err(|e| IoError::io(dir, e))?;
    crate::io::atomic::write_atomic(&path, &to_bytes(&table))?;
    Ok(Cached {
        table,
        origin,
        path,
        note,
    })
}

/// The file's bytes of `t`.
pub fn to_bytes(t: &CameraTable) -> Vec<u8> {
    let mut b =
        Vec::with_capacity(8 * (1 + HEADER_WORDS + t.offsets.len() + 1) + REP_BYTES * t.len());
    b.extend_from_slice(MAGIC);
    let s = &t.settings;
    for w in [
        FORMAT_VERSION,
        t.key[0],
        t.key[1],
        t.width as u64,
        t.height as u64,
        u64::from(s.spp),
        u64::from(s.reps),
        s.seed,
        t.reps.len() as u64,
        0,
    ] {
        b.extend_from_slice(&w.to_le_bytes());
    }
    for o in &t.offsets {
        b.extend_from_slice(&o.to_le_bytes());
    }
    for r in &t.reps {
        for v in [
            r.exit_mm[0],
            r.exit_mm[1],
            r.dir[0],
            r.dir[1],
            r.dir[2],
            r.lambda_nm,
            r.coef[0],
            r.coef[1],
        ] {
            b.extend_from_slice(&v.to_bits().to_le_bytes());
        }
        b.extend_from_slice(&r.replica.to_le_bytes());
    }
    let check = hash_bytes(&b, CHECK_SEED);
    b.extend_from_slice(&check.to_le_bytes());
    b
}

/// Reads the table at `path`, checking it against `sys` (design key, crop) and `ts`; sizes are
/// checked before anything is allocated. A file in the wrong form gives
/// `TableError::Io(IoError::Format)`.
pub fn read(path: &Path, sys: &System, ts: &TableSettings) -> Result<CameraTable, TableError> {
    let bad = |m: &str| TableError::Io(IoError::format(path, m));
    let len = std::fs::metadata(path)
        .map_err(|e| IoError::io(path, e))?
        .len();
    let (w, h) = (sys.camera.width_px, sys.camera.height_px);
    let pixels = (w * h) as u64;
    let fixed = 8 * (1 + HEADER_WORDS as u64 + pixels + 1 + 1);
    if len < fixed || (len - fixed) % REP_BYTES as u64 != 0 {
        return Err(bad("not a camera-side table of this sensor crop (size)"));
    }
    let n_reps = (len - fixed) / REP_BYTES as u64;
    crate::limits::check_bytes(
        "--camera-table",
        "the camera-side table",
        u128::from(len) * 2,
    )?;
    let b = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
    if b.len() as u64 != len || &b[..8] != MAGIC {
        return Err(bad("not a camera-side table (magic)"));
    }
    let word = |i: usize| u64::from_le_bytes(b[8 * i..8 * i + 8].try_into().unwrap_or([0; 8]));
    let body = b.len() - 8;
    if hash_bytes(&b[..body], CHECK_SEED) != word(body / 8) {
        return Err(bad("check word mismatch (damaged or partly written)"));
    }
    let key = crate::render::camera_table::design_key(sys);
    let expect = [
        FORMAT_VERSION,
        key[0],
        key[1],
        w as u64,
        h as u64,
        u64::from(ts.spp),
        u64::from(ts.reps),
        ts.seed,
        n_reps,
        0,
    ];
    if (0..HEADER_WORDS).any(|i| word(1 + i) != expect[i]) {
        return Err(bad("drawn for another design, crop or table settings"));
    }
    let first = 1 + HEADER_WORDS;
    let offsets: Vec<u64> = (0..=pixels as usize).map(|i| word(first + i)).collect();
    if offsets[0] != 0
        || offsets.windows(2).any(|p| p[1] < p[0])
        || offsets[pixels as usize] != n_reps
    {
        return Err(bad("pixel offsets out of order"));
    }
    let base = first + pixels as usize + 1;
    let f = |i: usize| f64::from_bits(word(i));
    let reps = (0..n_reps as usize)
        .map(|r| {
            let o = base + r * (REP_BYTES / 8);
            Rep {
                exit_mm: [f(o), f(o + 1)],
                dir: [f(o + 2), f(o + 3), f(o + 4)],
                lambda_nm: f(o + 5),
                coef: [f(o + 6), f(o + 7)],
                replica: word(o + 8),
            }
        })
        .collect();
    Ok(CameraTable {
        key,
        settings: *ts,
        width: w,
        height: h,
        offsets,
        reps,
        stats: Default::default(),
    })
}
