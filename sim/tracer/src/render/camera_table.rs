//! The camera side of a design, paid once: a per-pixel table of the waveguide's exit rays
//! that every 3-D scene seen through the same design reuses, so that a further scene traces
//! only its user side.
//!
//! Model. Everything from the sensor to the plate's front face (thin lens, plate, vHOEs,
//! Bragg selection, replica weights) depends on the design, not on the scene. A pixel's value
//! is (1/N)·Σ_i Σ_b v_ib·L(x_ib) over its N camera samples i and their branches b, where the
//! branch's weight v_ib (TE/TM weights, cos⁴θ/p(λ), the channel responses at λ_i) comes from
//! the waveguide and L(x_ib) is the radiance arriving along its exit ray x_ib (front-face exit
//! point, direction, wavelength) from the scene. The table holds, per pixel, R representative
//! exit rays drawn from the branches of N_t camera samples (`--table-spp`, 1,024 by default)
//! exactly as the resampled user side draws them (`super::user_side::resample_group`):
//! replicas (grating, plate contact) get R·S_c/ΣS representatives for their selection weight
//! S_c (Russian roulette below one), and a replica's representatives are drawn by systematic
//! resampling in proportion to each branch's selection weight s_j. Representative r carries
//! its exit ray and the coefficients c_r = (S_c/K_c)/N_t·(w_display, w_other)/s_j·cos⁴θ/p(λ)
//! that turn the radiance along it into the pixel's value, so Σ_r c_r·L(x_r) has the
//! expectation of the direct estimator over the table's draw (docs/design.md, "The camera side
//! is scene-independent"). A render of a scene then traces M user-side paths per pixel
//! (`--spp`): path k takes representative ⌊(k + u)·R/M⌋ (systematic, one uniform u per pixel),
//! is weighted R/M, and draws its first-vertex numbers from padded sets over its replica's
//! paths, like the resampled user side. Each representative is taken M/R times in expectation
//! and each path's radiance is an unbiased path estimate, so the render is unbiased for any M.
//!
//! What the table costs: its noise is shared by every scene rendered with it (one draw of the
//! camera side, N_t samples per pixel, R exit rays), so a dataset's captures share that
//! fixed pattern; it is ≈ 1/√N_t of the waveguide's own noise and R exit rays of the pixel's
//! footprint. Its memory is 72 bytes per representative (f64 throughout).
//!
//! Sources: resampling, Douc, Cappé & Moulines (2005), "Comparison of resampling schemes for
//! particle filtering"; Russian roulette, Arvo & Kirk (1990); the precomputed light transport
//! of a fixed optical system is the idea of precomputed radiance transfer (Sloan, Kautz &
//! Snyder 2002), here as a sample set rather than a basis.

use std::ops::ControlFlow;

use super::samples::{CameraSample, PixelSums, SampleConsumer};
use super::user_side::{FirstHitCache, Gathered, resample_group, trace_exit};
use super::{PixelJob, RenderSettings, RenderStats};
use crate::sampler::{PathRng, SamplerKind};
use crate::system::System;
use crate::trace::Branch;
use crate::world::World;
use crate::world::integrator::branch_weights;

/// Camera samples per pixel of a table by default (`--table-spp`).
pub const DEFAULT_TABLE_SPP: u32 = 1024;

/// Representative exit rays per pixel by default (`--table-reps`).
pub const DEFAULT_TABLE_REPS: u32 = 32;

/// A replica whose share of the pixel's representatives is at least this gets one for sure;
/// below it, one with probability share/this (Russian roulette). Weak replicas then cost a
/// representative only when they matter, and a replica with a share near one is not left
/// out of the table by chance (that was the table's largest fixed error: 1.94 % at 32
/// representatives with roulette below a share of 1, eye contact at 128 × 128).
pub const TABLE_MIN_SHARE: f64 = 0.1;

/// Bytes of one representative in memory and on disk.
pub const REP_BYTES: usize = 72;

/// Tag of the table's random streams (keeps them apart from the renders' own).
const TABLE_TAG: u64 = 0x7AB1_E000_CA5E_0000;

/// How a camera-side table is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct TableSettings {
    /// Camera samples per pixel (lattice sequence).
    pub spp: u32,
    /// Representative exit rays per pixel (on average: each replica gets its share).
    pub reps: u32,
    /// Seed of the camera samples and of the draw.
    pub seed: u64,
}

impl Default for TableSettings {
    fn default() -> Self {
        TableSettings {
            spp: DEFAULT_TABLE_SPP,
            reps: DEFAULT_TABLE_REPS,
            seed: 1,
        }
    }
}

/// One representative exit ray of a pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Rep {
    /// Front-face exit point (x, y), mm.
    pub(crate) exit_mm: [f64; 2],
    /// Direction of the exit ray (the camera ray's, unit).
    pub(crate) dir: [f64; 3],
    /// Wavelength, nm.
    pub(crate) lambda_nm: f64,
    /// Coefficients of the display seen directly (polarised) and of all other radiance.
    pub(crate) coef: [f64; 2],
    /// The replica (grating, contact), as [`crate::trace::replica_key`].
    pub(crate) replica: u64,
}

/// A design's camera side: per pixel, its representative exit rays ([`Rep`]), for the
/// sensor crop and the settings it was drawn with.
#[derive(Clone, Debug)]
pub struct CameraTable {
    /// The design's key ([`design_key`]).
    pub(crate) key: [u64; 2],
    /// How it was drawn.
    pub settings: TableSettings,
    /// Crop width, px.
    pub width: usize,
    /// Crop height, px.
    pub height: usize,
    /// Pixel p's representatives are `reps[offsets[p]..offsets[p + 1]]`.
    pub(crate) offsets: Vec<u64>,
    /// Every pixel's representatives, pixel after pixel.
    pub(crate) reps: Vec<Rep>,
    /// The build's counters (zero for a table read from disk).
    pub stats: RenderStats,
}

/// Why a table cannot be built, read or used.
#[derive(Debug, thiserror::Error)]
pub enum TableError {
    /// The table or its render is too big, or the settings are out of range.
    #[error(transparent)]
    Limit(#[from] crate::limits::LimitError),
    /// The scene or render cannot use a table.
    #[error("{0}")]
    Unsupported(String),
    /// The table's file could not be read or written.
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    /// The job was cancelled ([`crate::cancel`]) while the table was drawn: nothing is kept.
    #[error("interrupted")]
    Cancelled,
}

impl CameraTable {
    /// Representatives in all.
    pub fn len(&self) -> usize {
        self.reps.len()
    }

    /// True when no pixel has a representative (no light reaches the front face).
    pub fn is_empty(&self) -> bool {
        self.reps.is_empty()
    }

    /// Pixel `p`'s representatives (row-major index).
    #[inline]
    pub(crate) fn pixel(&self, p: usize) -> &[Rep] {
        &self.reps[self.offsets[p] as usize..self.offsets[p + 1] as usize]
    }

    /// Whether the table was drawn for `sys`'s design and crop.
    pub fn matches(&self, sys: &System) -> bool {
        self.matches_keyed(sys, design_key(sys))
    }

    /// [`Self::matches`] for `sys` whose [`design_key`] is `key`.
    fn matches_keyed(&self, sys: &System, key: [u64; 2]) -> bool {
        self.key == key && self.width == sys.camera.width_px && self.height == sys.camera.height_px
    }
}

/// Branches per camera sample the memory check of a table's drawing allows for (the
/// paper's camera: 3-6 replicas with a weight; a design with many more weak replicas can pass
/// it and still reach the job's memory limit).
const GATHER_BRANCHES_PER_SAMPLE: usize = 16;

/// Checks a table's settings and size against [`crate::limits`] before it is drawn.
pub fn check_table_limits(sys: &System, ts: &TableSettings) -> Result<(), TableError> {
    let pixels = (sys.camera.width_px * sys.camera.height_px) as u128;
    if ts.spp == 0 || ts.reps == 0 {
        return Err(TableError::Unsupported(format!(
            "--table-spp and --table-reps must be at least 1 (got {} and {})",
            ts.spp, ts.reps
        )));
    }
    check_table_spp(sys, ts)?;
    // Drawing a pixel gathers all its camera samples with their branches (and a sorted copy
    // of the branches) before the representatives are chosen, in every worker thread.
    let per_sample = std::mem::size_of::<CameraSample>()
        + 2 * GATHER_BRANCHES_PER_SAMPLE * std::mem::size_of::<super::user_side::PendingBranch>();
    crate::limits::check_bytes(
        "--table-spp",
        "one pixel's camera samples and their branches, gathered in each worker thread while the table is drawn",
        rayon::current_num_threads() as u128 * u128::from(ts.spp) * per_sample as u128,
    )?;
    // A pixel holds about R representatives (rounding and the one-per-replica floor add up to
    // one per replica: 33.2 on average for R = 32 in the eye-contact scene); the estimate
    // allows 2R + 64.
    crate::limits::check_bytes(
        "--table-reps",
        "the camera-side table",
        pixels * (2 * u128::from(ts.reps) + 64) * REP_BYTES as u128,
    )?;
    Ok(())
}

/// Checks the camera samples a table of `sys` draws (`ts.spp`, at least 1) against
/// [`crate::limits`]: the part of [`check_table_limits`] that display tables (H) share.
pub(crate) fn check_table_spp(sys: &System, ts: &TableSettings) -> Result<(), TableError> {
    if ts.spp == 0 {
        return Err(TableError::Unsupported(
            "--table-spp must be at least 1".into(),
        ));
    }
    let pixels = (sys.camera.width_px * sys.camera.height_px) as u128;
    crate::limits::check_paths("--table-spp", pixels * u128::from(ts.spp))?;
    Ok(())
}

/// The key of everything the camera side depends on: the waveguide (plate, films, gratings
/// and their efficiency model), camera and sensor crop, sensor response, wavelength sampler,
/// trace limits, the object plane's distance and the display's polarisation, and the film's
/// recording (128 bits of the SHA-256 of their full `Debug` text, which prints every f64
/// exactly, followed by the wavelength sampler's numbers as bits).
pub fn design_key(sys: &System) -> [u64; 2] {
    let text = format!(
        "{:?}\n{:?}\n{:?}\n{:?}\n{:?}\n{:?}\n{:?}\n",
        sys.waveguide,
        sys.camera,
        sys.response,
        sys.limits,
        sys.display.z_mm,
        sys.display.polarization_weights,
        sys.scene.hoe,
    );
    // The wavelength sampler's tables as bits: their `Debug` text is megabytes (tens of
    // milliseconds a key), their bits a few hundred kilobytes.
    let mut bytes = text.into_bytes();
    sys.wavelengths.key_bytes(&mut bytes);
    digest128(&bytes)
}

/// The first 128 bits of the SHA-256 of `bytes` (FIPS 180-4), as two little-endian words:
/// the key of a table and the check word of its file.
pub(crate) fn digest128(bytes: &[u8]) -> [u64; 2] {
    use sha2::{Digest, Sha256};
    let d = Sha256::digest(bytes);
    let word = |i: usize| u64::from_le_bytes(d[8 * i..8 * i + 8].try_into().unwrap_or([0; 8]));
    [word(0), word(1)]
}

/// Gathers a pixel's camera samples and branches for the table.
struct TablePixel<'a> {
    gathered: Gathered<'a>,
}

impl SampleConsumer for TablePixel<'_> {
    #[inline]
    fn begin(&mut self, s: &CameraSample, _i: u64) {
        self.gathered.begin(s);
    }

    #[inline]
    fn branch(&mut self, _s: &CameraSample, b: &Branch) -> ControlFlow<()> {
        self.gathered.branch(b);
        ControlFlow::Continue(())
    }

    #[inline]
    fn end(&mut self, _s: &CameraSample, _i: u64, _stats: &mut RenderStats) {}
}

/// Draws `sys`'s camera-side table with `ts` (rows in parallel, collected in order: the same
/// table for any thread count). Shows a progress bar when `progress`.
pub fn build(sys: &System, ts: &TableSettings, progress: bool) -> Result<CameraTable, TableError> {
    build_keyed(sys, design_key(sys), ts, progress)
}

/// [`build`] for `sys` whose [`design_key`] is `key`.
pub(crate) fn build_keyed(
    sys: &System,
    key: [u64; 2],
    ts: &TableSettings,
    progress: bool,
) -> Result<CameraTable, TableError> {
    check_table_limits(sys, ts)?;
    let (w, h) = (sys.camera.width_px, sys.camera.height_px);
    let set = RenderSettings::lattice(ts.spp, ts.seed, false);
    let rule = (ts.spp, super::lattice_rule(&set, ts.spp));
    let pol = sys.display.polarization_weights;
    let inv_n = 1.0 / f64::from(ts.spp);
    let cancel = crate::cancel::current();
    let rows: Vec<(Vec<u64>, Vec<Rep>, RenderStats)> = crate::rows::par_rows(
        h,
        progress,
        "camera-side table rows",
        &cancel,
        |row| {
            let mut stats = RenderStats::default();
            let mut counts = Vec::with_capacity(w);
            let mut reps = Vec::new();
            let mut px = TablePixel {
                gathered: Gathered::new(sys, false),
            };
            for col in 0..w {
                let pixel = (row * w + col) as u64;
                let before = reps.len();
                px.gathered.clear();
                super::drive_pixel(sys, &set, rule, (col, row), &mut stats, &mut px);
                let samples = std::mem::take(&mut px.gathered.samples);
                px.gathered.by_replica(|group, total| {
                    let replica = group[0].replica;
                    let s_c: f64 = group.iter().map(|p| p.sel).sum();
                    let q = f64::from(ts.reps) * s_c / total;
                    let hsh = crate::sampler::hash(&[ts.seed, pixel, TABLE_TAG, replica]);
                    resample_group(group, s_c, q, TABLE_MIN_SHARE, hsh, |_, _, share, p| {
                        let s = &samples[p.sample as usize];
                        let (wd, wo) = branch_weights(p.weight, pol);
                        let scale = share / p.sel * s.ray.cos4 / s.pdf * inv_n;
                        reps.push(Rep {
                            exit_mm: p.exit.to_array(),
                            dir: s.ray.dir.to_array(),
                            lambda_nm: s.lambda_nm,
                            coef: [scale * wd, scale * wo],
                            replica,
                        });
                    });
                });
                px.gathered.samples = samples;
                counts.push((reps.len() - before) as u64);
            }
            (counts, reps, stats)
        },
        |_| (vec![0; w], Vec::new(), RenderStats::default()),
    );
    if cancel.is_cancelled() {
        return Err(TableError::Cancelled);
    }
    let mut offsets = Vec::with_capacity(w * h + 1);
    offsets.push(0u64);
    let mut all = Vec::with_capacity(rows.iter().map(|r| r.1.len()).sum());
    let mut stats = RenderStats::default();
    for (counts, reps, st) in rows {
        for c in counts {
            offsets.push(offsets[offsets.len() - 1] + c);
        }
        all.extend(reps);
        stats.merge(&st);
    }
    Ok(CameraTable {
        key,
        settings: *ts,
        width: w,
        height: h,
        offsets,
        reps: all,
        stats,
    })
}

/// That a render with `set` can take its camera side from a table (not with spectral bins).
pub fn check_usable(set: &RenderSettings) -> Result<(), TableError> {
    if set.spectral_bins.is_some() {
        return Err(TableError::Unsupported(
            "--spectral cannot use a camera-side table (it is drawn for the sensor's channels)"
                .into(),
        ));
    }
    Ok(())
}

/// Renders `sys` (a 3-D scene) with its camera side taken from `table`: `set.spp` user-side
/// paths per pixel (module docs). Deterministic for a given seed and table, whatever the
/// thread count. (A display-only scene's table is its H: [`super::table_file::CachedTable`].)
pub fn render_with_table(
    sys: &System,
    set: &RenderSettings,
    table: &CameraTable,
) -> Result<super::Capture, TableError> {
    render_with_table_keyed(sys, design_key(sys), set, table)
}

/// [`render_with_table`] for `sys` whose [`design_key`] is `key`: many scenes of one design
/// (a dataset's samples) compute the key once.
pub fn render_with_table_keyed(
    sys: &System,
    key: [u64; 2],
    set: &RenderSettings,
    table: &CameraTable,
) -> Result<super::Capture, TableError> {
    check_usable(set)?;
    let world = sys.world.as_deref().ok_or_else(|| {
        TableError::Unsupported(
            "representatives are for 3-D scenes; a display-only scene's table is its H".into(),
        )
    })?;
    if !table.matches_keyed(sys, key) {
        return Err(TableError::Unsupported(
            "the camera-side table was drawn for another design or sensor crop".into(),
        ));
    }
    crate::limits::check_paths(
        "--spp",
        (table.width * table.height) as u128 * u128::from(set.spp),
    )?;
    let pass = |set: &RenderSettings, counts: Option<&[u32]>| {
        super::job_rows(sys, set, counts, || TableJob {
            sys,
            world,
            table,
            seed: set.seed,
            padded: set.sampler != SamplerKind::Independent,
            sums: PixelSums::new(sys, set),
            picks: Vec::new(),
            first_hits: FirstHitCache::default(),
        })
    };
    Ok(super::adaptive::render(set, pass))
}

/// The user side of one pixel from the table ([`render_with_table`]).
struct TableJob<'a> {
    sys: &'a System,
    world: &'a World,
    table: &'a CameraTable,
    seed: u64,
    padded: bool,
    sums: PixelSums<'a>,
    /// The representative of each path.
    picks: Vec<u32>,
    /// The first hit of the last representative traced.
    first_hits: FirstHitCache,
}

impl<'a> PixelJob<'a> for TableJob<'a> {
    /// The pixel's sums over `paths` user-side paths, M.
    fn pixel(
        &mut self,
        (col, row): (usize, usize),
        paths: u32,
        stats: &mut RenderStats,
    ) -> &PixelSums<'a> {
        let p = row * self.table.width + col;
        self.sums.start(p as u64);
        let reps = self.table.pixel(p);
        if reps.is_empty() || paths == 0 {
            return &self.sums;
        }
        let (r, m) = (reps.len(), paths);
        let pixel = p as u64;
        // Systematic choice: path k takes representative ⌊(k + u)·R/M⌋.
        let u = crate::sampler::to_unit(crate::sampler::hash(&[self.seed, pixel, TABLE_TAG]));
        let ratio = r as f64 / f64::from(m);
        self.picks.clear();
        self.picks
            .extend((0..m).map(|k| (((f64::from(k) + u) * ratio) as usize).min(r - 1) as u32));
        // The paths of one replica are consecutive (representatives are sorted by replica).
        let mut k0 = 0usize;
        while k0 < self.picks.len() {
            let replica = reps[self.picks[k0] as usize].replica;
            let k1 = k0
                + self.picks[k0..]
                    .iter()
                    .take_while(|&&j| reps[j as usize].replica == replica)
                    .count();
            let n = (k1 - k0) as u32;
            let pad_key = PathRng::padded_key(&[self.seed, pixel, replica, TABLE_TAG]);
            for k in k0..k1 {
                let rep = &reps[self.picks[k] as usize];
                let mut rng = PathRng::new(&[self.seed, pixel, TABLE_TAG, k as u64]);
                if self.padded {
                    rng = rng.with_padded(pad_key, (k - k0) as u64, n);
                }
                // Paths that take the same representative start on the same ray (when M > R):
                // its first hit is traced once.
                let l = trace_exit(
                    self.sys,
                    self.world,
                    glam::DVec3::from_array(rep.dir),
                    rep.lambda_nm,
                    glam::DVec2::from_array(rep.exit_mm),
                    &mut rng,
                    stats,
                    Some(&mut self.first_hits),
                );
                let base = r as f64 * (rep.coef[0] * l.display + rep.coef[1] * l.other);
                self.sums.add(base, rep.lambda_nm, stats);
            }
            k0 = k1;
        }
        &self.sums
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The digest depends on every byte and on the length (a trailing zero byte changes it),
    /// and is SHA-256's: the standard test vector of "abc" (FIPS 180-4, appendix B.1) begins
    /// ba7816bf8f01cfea.
    #[test]
    fn digest_sees_every_byte_and_the_length() {
        let a = digest128(b"camera side");
        assert_ne!(a, digest128(b"camera sidf"));
        assert_ne!(a, digest128(b"camera side\0"));
        assert_ne!(digest128(b""), digest128(b"\0"));
        assert_eq!(a, digest128(&b"camera side".to_vec()));
        assert_eq!(
            digest128(b"abc")[0].to_le_bytes(),
            [0xba, 0x78, 0x16, 0xbf, 0x8f, 0x01, 0xcf, 0xea]
        );
    }
}
