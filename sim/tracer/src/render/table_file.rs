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

use super::camera_table::{CameraTable, REP_BYTES, Rep, TableError, TableSettings, digest128};
use crate::io::IoError;
use crate::system::System;

/// The file format's version (part of every file's name).
pub const FORMAT_VERSION: u64 = 1;

const MAGIC: &[u8; 8] = b"STSCAMCT";

/// Header words after the magic.
const HEADER_WORDS: usize = 10;

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
    table_path_keyed(sys, super::camera_table::design_key(sys), ts, dir)
}

/// [`table_path`] for `sys` whose design key is `key`.
fn table_path_keyed(sys: &System, key: [u64; 2], ts: &TableSettings, dir: &Path) -> PathBuf {
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
    let key = super::camera_table::design_key(sys);
    let path = table_path_keyed(sys, key, ts, dir);
    let (table, origin, path, note) = read_or_build(
        path,
        dir,
        |p| read_keyed(p, sys, key, ts),
        || super::camera_table::build_keyed(sys, key, ts, progress),
        to_bytes,
    )?;
    Ok(Cached {
        table,
        origin,
        path,
        note,
    })
}

/// One cache file: read with `read` when it is there and valid; else (missing, or failing its
/// checks: `IoError::Format`, noted) drawn with `build` and written (`bytes`) under a
/// temporary name and renamed, the directory made and checked writable first.
fn read_or_build<T>(
    path: PathBuf,
    dir: &Path,
    read: impl FnOnce(&Path) -> Result<T, TableError>,
    build: impl FnOnce() -> Result<T, TableError>,
    bytes: impl FnOnce(&T) -> Vec<u8>,
) -> Result<(T, TableOrigin, PathBuf, Option<String>), TableError> {
    let (mut origin, mut note) = (TableOrigin::Built, None);
    if path.exists() {
        match read(&path) {
            Ok(t) => return Ok((t, TableOrigin::Read, path, None)),
            Err(TableError::Io(e @ IoError::Format { .. })) => {
                origin = TableOrigin::Rebuilt;
                note = Some(e.to_string());
            }
            Err(e) => return Err(e),
        }
    }
    writable_dir(dir)?;
    let t = build()?;
    crate::io::atomic::write_atomic(&path, &bytes(&t))?;
    Ok((t, origin, path, note))
}

/// The cache file at `path`, parsed by `parse`, after the checks every table file gets: a size
/// the limits allow, a whole number of 8-byte words, the magic `magic`, and the check word
/// (the last word: the first 64 bits of the SHA-256 of everything before it). The check word
/// is computed while `parse` runs (the SHA-256 of a 30 MB H takes tens of milliseconds, as long
/// as the parse); a mismatch is reported whatever the parse found.
fn read_checked<T: Send>(
    path: &Path,
    magic: &[u8; 8],
    parse: impl FnOnce(&[u8]) -> Result<T, TableError> + Send,
) -> Result<T, TableError> {
    let len = std::fs::metadata(path)
        .map_err(|e| IoError::io(path, e))?
        .len();
    crate::limits::check_bytes(
        "--camera-table",
        "the camera-side table",
        u128::from(len) * 2,
    )?;
    // Read as every input is: a regular file (a FIFO or a device is refused from its
    // metadata, without opening it) of the size just checked.
    let b = crate::io::input::read_input(path, len)?;
    if b.len() < 16 || b.len() % 8 != 0 || &b[..8] != magic {
        return Err(
            IoError::format(path, "not a camera-side table of this kind (magic or size)").into(),
        );
    }
    let body = b.len() - 8;
    let (check, parsed) = rayon::join(|| digest128(&b[..body])[0], || parse(&b));
    if check.to_le_bytes() != b[body..] {
        return Err(
            IoError::format(path, "check word mismatch (damaged or partly written)").into(),
        );
    }
    parsed
}

/// Little-endian 64-bit word `i` of a table file `b` (0 past its end; callers check sizes).
fn word_at(b: &[u8], i: usize) -> u64 {
    b.get(8 * i..8 * i + 8)
        .and_then(|w| w.try_into().ok())
        .map_or(0, u64::from_le_bytes)
}

/// Appends the check word of [`read_checked`] to `b`.
fn seal(mut b: Vec<u8>) -> Vec<u8> {
    let check = digest128(&b)[0];
    b.extend_from_slice(&check.to_le_bytes());
    b
}

/// Makes the cache directory `dir` (and its parents) and checks that a file can be created in
/// it, before minutes are spent drawing a table that could not be kept: a path that is not a
/// directory is bad input, an unwritable one an I/O error. A job that writes files of its
/// own (a dataset) calls it before it writes any.
pub fn writable_dir(dir: &Path) -> Result<(), TableError> {
    if dir.as_os_str().is_empty() || (dir.exists() && !dir.is_dir()) {
        return Err(TableError::Unsupported(format!(
            "{}: not a directory",
            dir.display()
        )));
    }
    std::fs::create_dir_all(dir).map_err(|e| IoError::io(dir, e))?;
    // The probe is created new (O_CREAT | O_EXCL): a name that exists, a link planted there
    // included, is never opened, so nothing outside the folder is truncated; another name is
    // tried instead (a folder shared by SLURM array tasks may hold other jobs' probes).
    for attempt in 0..PROBE_ATTEMPTS {
        let probe = dir.join(format!(
            ".camera-table-probe-{}-{attempt}",
            std::process::id()
        ));
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&probe)
        {
            Ok(_) => {
                std::fs::remove_file(&probe).map_err(|e| IoError::io(&probe, e))?;
                return Ok(());
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(IoError::io(dir, e).into()),
        }
    }
    Err(TableError::Unsupported(format!(
        "{}: {PROBE_ATTEMPTS} probe names are taken (.camera-table-probe-*): remove them",
        dir.display()
    )))
}

/// Names the writability probe of [`writable_dir`] tries before giving up.
const PROBE_ATTEMPTS: u32 = 16;

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
    seal(b)
}

/// Reads the table at `path`, checking it against `sys` (design key, crop) and `ts`. A file
/// in the wrong form gives `TableError::Io(IoError::Format)`.
pub fn read(path: &Path, sys: &System, ts: &TableSettings) -> Result<CameraTable, TableError> {
    read_keyed(path, sys, super::camera_table::design_key(sys), ts)
}

/// [`read`] for `sys` whose design key is `key`.
fn read_keyed(
    path: &Path,
    sys: &System,
    key: [u64; 2],
    ts: &TableSettings,
) -> Result<CameraTable, TableError> {
    let bad = |m: &str| TableError::Io(IoError::format(path, m));
    read_checked(path, MAGIC, |b| {
        let (w, h) = (sys.camera.width_px, sys.camera.height_px);
        let pixels = (w * h) as u64;
        let len = b.len() as u64;
        let fixed = 8 * (1 + HEADER_WORDS as u64 + pixels + 1 + 1);
        if len < fixed || (len - fixed) % REP_BYTES as u64 != 0 {
            return Err(bad("not a camera-side table of this sensor crop (size)"));
        }
        let n_reps = (len - fixed) / REP_BYTES as u64;
        let word = |i: usize| word_at(b, i);
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
            .collect::<Vec<Rep>>();
        // Values are checked before use (a resealed file could hold anything): finite, exit
        // points within the coordinate limit, unit directions, wavelengths in the scene keys'
        // range, coefficients finite and below 10¹² (a capture must fit float32).
        let rep_ok = |r: &Rep| {
            r.exit_mm
                .iter()
                .all(|v| v.abs() <= crate::limits::MAX_COORD_MM)
                && r.dir.iter().all(|v| v.is_finite())
                && ((r.dir[0] * r.dir[0] + r.dir[1] * r.dir[1] + r.dir[2] * r.dir[2]) - 1.0).abs()
                    <= 1e-6
                && (crate::scene::MIN_WAVELENGTH_NM..=crate::scene::MAX_WAVELENGTH_NM)
                    .contains(&r.lambda_nm)
                && r.coef.iter().all(|v| v.abs() <= 1e12)
        };
        if let Some(i) = reps.iter().position(|r| !rep_ok(r)) {
            return Err(bad(&format!(
                "representative ray {i} holds a value out of range (not finite, or beyond the geometry); the table is not used"
            )));
        }
        Ok(CameraTable {
            key,
            settings: *ts,
            width: w,
            height: h,
            offsets,
            reps,
            stats: Default::default(),
        })
    })
}

/// The display's part of the key of a display-only scene's table: everything of the display
/// but its content (plane, image grid and size, black level, LCD extent, spectra,
/// polarisation), so that every target shown on it shares the table.
pub fn display_key(sys: &System) -> [u64; 2] {
    let d = &sys.display;
    let text = format!(
        "{:?}\n{:?}\n{:?}\n{:?}\n{:?}\n{:?}\n{:?}\n{:?}\n{:?}\n{:?}\n{:?}",
        super::camera_table::design_key(sys),
        d.z_mm,
        d.center_mm,
        d.image_pixel_mm,
        d.width_px,
        d.height_px,
        d.black_level,
        d.half_extent_mm,
        d.spectrum,
        d.primaries,
        d.polarization_weights,
    );
    digest128(text.as_bytes())
}

/// A display-only scene's table: its system matrix H and offset at `ts.spp` camera samples
/// per pixel ([`crate::matrix::compute_matrix`]), so that a target's capture is H·f + offset,
/// equal to a render of the same samples to float rounding. Cached in `dir` like the
/// representatives of 3-D scenes ([`cached`]; the representatives count is not used).
pub fn cached_display(
    sys: &System,
    ts: &TableSettings,
    dir: &Path,
    progress: bool,
) -> Result<
    (
        crate::matrix::SystemMatrix,
        TableOrigin,
        PathBuf,
        Option<String>,
    ),
    TableError,
> {
    super::camera_table::check_table_spp(sys, ts)?;
    let key = display_key(sys);
    let path = dir.join(format!(
        "display-table-v{FORMAT_VERSION}-{:016x}{:016x}-{}x{}-spp{}-seed{}.bin",
        key[0], key[1], sys.camera.width_px, sys.camera.height_px, ts.spp, ts.seed
    ));
    read_or_build(
        path,
        dir,
        |p| read_display(p, sys, key),
        || {
            let set = crate::render::RenderSettings::lattice(ts.spp, ts.seed, progress);
            let m = crate::matrix::compute_matrix(sys, &set);
            if crate::cancel::current().is_cancelled() {
                return Err(TableError::Cancelled);
            }
            Ok(m)
        },
        |m| display_bytes(m, key),
    )
}

const DISPLAY_MAGIC: &[u8; 8] = b"STSCAMCH";

/// The file's bytes of a display table: magic, version, key (2), rows, cols, nnz, crop w, h,
/// object w, h, planes (u64 each); indptr (u64), indices (u32), data (f32), offset (f32), each
/// padded to 8 bytes; the check word.
fn display_bytes(m: &crate::matrix::SystemMatrix, key: [u64; 2]) -> Vec<u8> {
    let h = &m.h;
    let mut b = Vec::with_capacity(8 * (13 + h.indptr.len()) + 8 * (h.nnz() + m.offset.len()));
    b.extend_from_slice(DISPLAY_MAGIC);
    for w in [
        FORMAT_VERSION,
        key[0],
        key[1],
        h.rows as u64,
        h.cols as u64,
        h.nnz() as u64,
        m.crop.0 as u64,
        m.crop.1 as u64,
        m.object.0 as u64,
        m.object.1 as u64,
        m.planes as u64,
    ] {
        b.extend_from_slice(&w.to_le_bytes());
    }
    let pad = |b: &mut Vec<u8>| b.resize(b.len().next_multiple_of(8), 0);
    h.indptr
        .iter()
        .for_each(|v| b.extend_from_slice(&v.to_le_bytes()));
    h.indices
        .iter()
        .for_each(|v| b.extend_from_slice(&v.to_le_bytes()));
    pad(&mut b);
    h.data
        .iter()
        .for_each(|v| b.extend_from_slice(&v.to_bits().to_le_bytes()));
    pad(&mut b);
    m.offset
        .iter()
        .for_each(|v| b.extend_from_slice(&v.to_bits().to_le_bytes()));
    pad(&mut b);
    seal(b)
}

/// Reads a display table, checked against `sys` and `key`.
fn read_display(
    path: &Path,
    sys: &System,
    key: [u64; 2],
) -> Result<crate::matrix::SystemMatrix, TableError> {
    let bad = |m: &str| TableError::Io(IoError::format(path, m));
    read_checked(path, DISPLAY_MAGIC, |b| {
        if b.len() < 8 * 13 {
            return Err(bad("not a display table (size)"));
        }
        let word = |i: usize| word_at(b, i);
        let (rows, cols, nnz) = (word(4) as usize, word(5) as usize, word(6) as usize);
        // Counts the file cannot hold are refused before any size is computed from them.
        if rows > b.len() / 8 || nnz > b.len() / 4 {
            return Err(bad("not a display table (counts larger than the file)"));
        }
        let crop = (sys.camera.width_px, sys.camera.height_px);
        let channels = sys.response.names.clone();
        let r8 = |n: usize, size: usize| (n * size).next_multiple_of(8);
        let expect = 8 * 12 + 8 * (rows + 1) + r8(nnz, 4) + r8(nnz, 4) + r8(rows, 4) + 8;
        if word(1) != FORMAT_VERSION
            || [word(2), word(3)] != key
            || (word(7) as usize, word(8) as usize) != crop
            || rows != crop.0 * crop.1 * channels.len()
            || cols != sys.display.intensity.len()
            || b.len() != expect
        {
            return Err(bad("drawn for another design, display or crop (header)"));
        }
        let mut at = 8 * 12;
        let indptr: Vec<u64> = (0..=rows).map(|i| word(12 + i)).collect();
        at += 8 * (rows + 1);
        let u32s = |at: usize, n: usize| -> Vec<u32> {
            (0..n)
                .map(|i| {
                    u32::from_le_bytes(b[at + 4 * i..at + 4 * i + 4].try_into().unwrap_or([0; 4]))
                })
                .collect()
        };
        let indices = u32s(at, nnz);
        at += r8(nnz, 4);
        let data: Vec<f32> = u32s(at, nnz).into_iter().map(f32::from_bits).collect();
        at += r8(nnz, 4);
        let offset: Vec<f32> = u32s(at, rows).into_iter().map(f32::from_bits).collect();
        let h = crate::sparse::CsrMatrix {
            rows,
            cols,
            indptr,
            indices,
            data,
        };
        h.check().map_err(|e| bad(&e))?;
        Ok(crate::matrix::SystemMatrix {
            h,
            offset,
            crop,
            object: (word(9) as usize, word(10) as usize),
            planes: word(11) as usize,
            channels,
            stats: Default::default(),
        })
    })
}

/// A design's cached camera side, as a render uses it.
#[derive(Debug)]
pub enum CachedTable {
    /// 3-D scenes: each pixel's representative exit rays.
    Rays(CameraTable),
    /// Display-only scenes: H and the offset (a target's capture is H·f + offset).
    Display(crate::matrix::SystemMatrix),
}

/// Where a cached table came from, for the sidecar and the log.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TableInfo {
    /// `representatives` (3-D) or `matrix` (display only).
    pub kind: &'static str,
    /// Read, built or rebuilt.
    pub origin: TableOrigin,
    /// The file.
    pub file: PathBuf,
    /// Why a cached file was rebuilt.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// Representatives (3-D) or stored entries of H (display only).
    pub entries: usize,
    /// Camera paths traced to build it (0 when read).
    pub build_camera_paths: u64,
}

impl CachedTable {
    /// `sys`'s table with `ts` from the cache directory `dir` (read, or drawn and written):
    /// representatives for a 3-D scene ([`cached`]), H for a display-only one
    /// ([`cached_display`]).
    pub fn load_or_build(
        sys: &System,
        ts: &TableSettings,
        dir: &Path,
        progress: bool,
    ) -> Result<(CachedTable, TableInfo), TableError> {
        if sys.world.is_some() {
            let c = cached(sys, ts, dir, progress)?;
            let info = TableInfo {
                kind: "representatives",
                origin: c.origin,
                file: c.path,
                note: c.note,
                entries: c.table.len(),
                build_camera_paths: c.table.stats.camera_paths,
            };
            Ok((CachedTable::Rays(c.table), info))
        } else {
            let (m, origin, file, note) = cached_display(sys, ts, dir, progress)?;
            let info = TableInfo {
                kind: "matrix",
                origin,
                file,
                note,
                entries: m.h.nnz(),
                build_camera_paths: m.stats.camera_paths,
            };
            Ok((CachedTable::Display(m), info))
        }
    }

    /// The capture of `sys` (the design the table was drawn for) with `set`: a 3-D scene's
    /// user side from the representatives
    /// ([`super::camera_table::render_with_table`]), a display's H·f + offset.
    pub fn render(
        &self,
        sys: &System,
        set: &crate::render::RenderSettings,
    ) -> Result<crate::render::Capture, TableError> {
        super::camera_table::check_usable(set)?;
        match self {
            CachedTable::Rays(t) => super::camera_table::render_with_table(sys, set, t),
            CachedTable::Display(m) => {
                if sys.world.is_some()
                    || m.h.cols != sys.display.intensity.len()
                    || m.crop != (sys.camera.width_px, sys.camera.height_px)
                {
                    return Err(TableError::Unsupported(
                        "the display table was drawn for another scene kind, display or crop"
                            .into(),
                    ));
                }
                let channels = m
                    .capture_of(&sys.display.intensity)
                    .into_iter()
                    .map(|c| c.into_iter().map(|v| v as f32).collect())
                    .collect();
                Ok(crate::render::Capture {
                    width: m.crop.0,
                    height: m.crop.1,
                    channel_names: sys.response.names.clone(),
                    channels,
                    spectral: Vec::new(),
                    stats: Default::default(),
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Links planted at the writability probe's names, pointing at a file outside the folder:
    /// the probe never opens them (the target kept its bytes; it was truncated to 0 bytes when
    /// the probe was created with `File::create`), takes a free name, and with every name
    /// taken refuses in one line. The links stay where they were planted.
    #[cfg(unix)]
    #[test]
    fn the_probe_never_follows_a_planted_link() {
        let tmp = tempfile::tempdir().unwrap();
        let victim = tmp.path().join("victim");
        std::fs::write(&victim, b"keep me").unwrap();
        let dir = tmp.path().join("tables");
        std::fs::create_dir(&dir).unwrap();
        let plant = |k: u32| {
            let link = dir.join(format!(".camera-table-probe-{}-{k}", std::process::id()));
            std::os::unix::fs::symlink(&victim, &link).unwrap();
            link
        };
        let first: Vec<_> = (0..3).map(plant).collect();
        writable_dir(&dir).unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"keep me");
        assert!(first.iter().all(|l| l.symlink_metadata().is_ok()));
        for k in 3..PROBE_ATTEMPTS {
            plant(k);
        }
        let e = writable_dir(&dir).unwrap_err().to_string();
        assert!(e.contains("probe names are taken"), "{e}");
        assert_eq!(std::fs::read(&victim).unwrap(), b"keep me");
    }

    /// A display table whose header claims more entries than the file holds, sealed with a
    /// valid check word (a hostile file, not a damaged one), is refused with an error and
    /// not parsed: before the count check, a count of 2⁶² + nnz wrapped the size arithmetic
    /// to the true size and the parse asked for an impossible allocation. The untouched
    /// file reads.
    #[test]
    fn display_table_with_impossible_counts_is_refused() {
        let sys = crate::system::repo_system("scenes/paper-2022.toml", &["sensor.crop_px=8"]);
        let dir = tempfile::tempdir().unwrap();
        let ts = TableSettings {
            spp: 1,
            reps: 1,
            seed: 1,
        };
        let (_, _, file, _) = cached_display(&sys, &ts, dir.path(), false).unwrap();
        let key = display_key(&sys);
        assert!(read_display(&file, &sys, key).is_ok());
        let b = std::fs::read(&file).unwrap();
        let body = &b[..b.len() - 8];
        for (word, add) in [(6usize, 1u64 << 62), (4, 1 << 61)] {
            let mut evil = body.to_vec();
            let v = u64::from_le_bytes(evil[8 * word..8 * word + 8].try_into().unwrap());
            evil[8 * word..8 * word + 8].copy_from_slice(&v.wrapping_add(add).to_le_bytes());
            std::fs::write(&file, seal(evil)).unwrap();
            assert!(read_display(&file, &sys, key).is_err(), "word {word}");
        }
    }
}
