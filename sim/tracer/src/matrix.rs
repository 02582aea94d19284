//! The system matrix H of g = H·f + o, computed in one pass over the sensor.
//!
//! Model: the same estimator as `render` (same camera rays, wavelengths and replica branches for
//! the same seed and spp), but each branch's contribution goes to the column of the object
//! (target) pixel it lands on instead of being multiplied by that pixel's radiance. With the
//! display relative radiance L = b + (1 − b)·f inside the target (b = black level), b on the
//! rest of the LCD and 0 beyond it,
//!
//!   render(f) = Σ_branches c·L(x) = H·f + o,
//!   H[m, k]  = (1 − b)·Σ_{branches of pixel m landing in object pixel k} c / spp,
//!   o[m]     = b·Σ_{branches of pixel m landing on the LCD} c / spp,
//!
//! where c = cos⁴θ·S(λ)·R(λ)/∫R·W/p(λ) is the branch's sample weight. So H maps the linear
//! object intensity f ∈ [0, 1] (display gamma applied; 0 = black, 1 = white pixel) to the
//! capture in the units of `render`, and o is the capture of an all-black target (LCD black
//! leakage). This is the contract between `matrix` and `render`, tested to float rounding.
//!
//! Rows are crop pixels, row-major (row 0 at the top); with several sensor channels (RGB) the
//! rows are channel-major: row = c·(W·H) + pixel. Columns are object pixels, row-major. A
//! monochrome display (its spectrum is the backlight's) has one column per object pixel
//! whatever the sensor. A colour display (`display.primaries`) has one column block per
//! primary, column = p·(W·H) + pixel for p = R, G, B: the branch's c is split over the
//! primaries by their shares w_p(λ) = P_p(λ)/W(λ) of white at the sample's wavelength
//! (`Display::primary_weights`), H[m, p·N + k] = (1 − b)·Σ c·w_p/spp, and the offset is the
//! black level on all primaries, b·Σ c/spp (Σ_p w_p = 1).
//!
//! Memory grows with the number of stored entries, never with rows × columns: each pixel
//! accumulates into a small open-addressing table keyed by column, summed in sample order
//! (deterministic for any thread count).

use rayon::prelude::*;

use crate::render::{
    CameraSample, RenderSettings, RenderStats, SampleConsumer, channel_weights, drive_pixel,
    lattice_rule,
};
use crate::sparse::CsrMatrix;
use crate::system::System;

/// What one unit of H means (recorded in `H.json`).
pub const MATRIX_UNITS: &str = "H[m,k] is the capture value of crop pixel m (units of `stscam render`: relative irradiance, 1 = a white display pixel seen on axis through lossless optics with a vanishing aperture) per unit linear intensity of object pixel k (0 = black, 1 = white, display gamma already applied); the capture of object f is H f + offset, offset = the capture of an all-black object (LCD black level)";

/// Names of a colour display's primaries, in the order of H's column blocks.
pub const PRIMARY_NAMES: [&str; 3] = ["R", "G", "B"];

/// The `columns` text of a colour H's sidecar.
pub const COLOUR_COLUMNS: &str = "object (target) pixels of the colour display, one block per primary (R, G, B, in `object_primaries` order): column = primary_index * width * height + pixel, pixels row-major in the same orientation; the value is the primary's linear intensity (0 = off, 1 = full), so an object is an (h, w, 3) image transposed to (3, h, w) and flattened";

/// H with its offset vector and the shapes that give its rows and columns meaning.
#[derive(Clone, Debug)]
pub struct SystemMatrix {
    /// H (rows = channels × crop pixels, columns = object pixels).
    pub h: CsrMatrix,
    /// Capture of an all-black object, one value per row of H.
    pub offset: Vec<f32>,
    /// Crop size (width, height) in pixels.
    pub crop: (usize, usize),
    /// Object size (width, height) in pixels.
    pub object: (usize, usize),
    /// Object planes (column blocks): 1 for a monochrome display, 3 (R, G, B primaries) for a
    /// colour one.
    pub planes: usize,
    /// Sensor channel names (row blocks, in order).
    pub channels: Vec<&'static str>,
    /// Counters of the pass.
    pub stats: RenderStats,
}

/// Per-pixel accumulator: columns → per-channel sums (`L` = 4 channel lanes, times 3
/// primaries for a colour display), in first-visit order.
struct ColumnTable<const L: usize> {
    slots: Vec<u32>,
    keys: Vec<u32>,
    sums: Vec<[f64; L]>,
}

const EMPTY: u32 = u32::MAX;

/// Entries of the direct-mapped cache in front of each depth's column table (a power of two).
const RECENT: usize = 64;

/// The cache line of `key`.
#[inline(always)]
fn recent_slot(key: u32) -> usize {
    (key.wrapping_mul(0x9E37_79B1) >> 26) as usize & (RECENT - 1)
}

impl<const L: usize> ColumnTable<L> {
    fn new() -> Self {
        ColumnTable {
            slots: vec![EMPTY; 64],
            keys: Vec::new(),
            sums: Vec::new(),
        }
    }

    #[inline]
    fn slot_of(&self, key: u32) -> usize {
        let mask = self.slots.len() - 1;
        let mut s = (key.wrapping_mul(0x9E37_79B1) >> 7) as usize & mask;
        loop {
            let e = self.slots[s];
            if e == EMPTY || self.keys[e as usize] == key {
                return s;
            }
            s = (s + 1) & mask;
        }
    }

    /// The index of `key`'s entry in `keys`/`sums` (created if new; stable until `clear`).
    #[inline]
    fn index(&mut self, key: u32) -> usize {
        let s = self.slot_of(key);
        if self.slots[s] == EMPTY {
            if 2 * (self.keys.len() + 1) > self.slots.len() {
                self.grow();
                return self.index(key);
            }
            self.slots[s] = self.keys.len() as u32;
            self.keys.push(key);
            self.sums.push([0.0; L]);
        }
        self.slots[s] as usize
    }

    fn grow(&mut self) {
        let n = self.slots.len() * 2;
        self.slots = vec![EMPTY; n];
        for i in 0..self.keys.len() {
            let s = self.slot_of(self.keys[i]);
            self.slots[s] = i as u32;
        }
    }

    fn clear(&mut self) {
        // Find every slot before emptying any: emptying breaks later probe chains.
        let used: Vec<usize> = self.keys.iter().map(|&k| self.slot_of(k)).collect();
        for s in used {
            self.slots[s] = EMPTY;
        }
        self.keys.clear();
        self.sums.clear();
    }
}

/// `Display::pixel_at` with its constants computed once (the same arithmetic, so the same
/// pixel for every point).
struct PixelGrid {
    center: glam::DVec2,
    inv_pixel_mm: f64,
    half: glam::DVec2,
    size: glam::DVec2,
}

impl PixelGrid {
    fn of(d: &crate::display::Display) -> PixelGrid {
        let size = glam::DVec2::new(d.width_px as f64, d.height_px as f64);
        PixelGrid {
            center: d.center_mm,
            inv_pixel_mm: d.image_pixel_mm.recip(),
            half: 0.5 * size,
            size,
        }
    }

    #[inline(always)]
    fn pixel_at(&self, p: glam::DVec2) -> Option<(usize, usize)> {
        let fx = (p.x - self.center.x) * self.inv_pixel_mm + self.half.x;
        let fy = (self.center.y - p.y) * self.inv_pixel_mm + self.half.y;
        if fx >= 0.0 && fy >= 0.0 && fx < self.size.x && fy < self.size.y {
            // fx, fy ∈ [0, size) ⊂ i32: the same truncation as `as usize`, cheaper.
            Some((fx as i32 as usize, fy as i32 as usize))
        } else {
            None
        }
    }
}

/// One sensor row of H at one depth: per channel, the entries of each pixel (sorted by column).
struct RowBlock {
    /// Per channel: entry count per pixel.
    counts: Vec<Vec<u32>>,
    /// Per channel: columns and values.
    entries: Vec<(Vec<u32>, Vec<f32>)>,
    /// Per channel: offset per pixel.
    offset: Vec<Vec<f64>>,
}

/// One depth plane's per-pixel state while a row is traced.
struct DepthAccumulator<const L: usize> {
    depth_mm: f64,
    table: ColumnTable<L>,
    /// Direct-mapped cache of (column, entry index), by [`recent_slot`] of the column.
    recent: [(u32, u32); RECENT],
    off: [f64; 4],
    block: RowBlock,
}

/// One sensor row of every depth's H, in one pass: each branch's front-face exit ray (the
/// camera ray's own direction: the periscope property) meets every depth plane. The object
/// point at depth D is computed exactly as the tracer computes it for a display at z = −D, so
/// each depth's row equals a single-depth pass at that depth bit for bit.
fn matrix_row(
    sys: &System,
    set: &RenderSettings,
    rule: Option<crate::sampler::LatticeRule>,
    depths_mm: &[f64],
    row: usize,
    pixels: std::ops::Range<usize>,
) -> (Vec<RowBlock>, RenderStats) {
    if sys.display.primaries.is_some() {
        matrix_row_lanes::<12>(sys, set, rule, depths_mm, row, pixels)
    } else {
        matrix_row_lanes::<4>(sys, set, rule, depths_mm, row, pixels)
    }
}

/// [`matrix_row`] with `L` lanes per column: 4 channel lanes (monochrome display), or 3
/// primaries × 4 channel lanes (lane p·4 + channel).
fn matrix_row_lanes<const L: usize>(
    sys: &System,
    set: &RenderSettings,
    rule: Option<crate::sampler::LatticeRule>,
    depths_mm: &[f64],
    row: usize,
    pixels: std::ops::Range<usize>,
) -> (Vec<RowBlock>, RenderStats) {
    let n_cols = pixels.len();
    let nch = sys.response.curves.len();
    let mut stats = RenderStats::default();
    let mut columns = MatrixColumns::<L> {
        sys,
        pol: sys.display.polarization_weights,
        grid: PixelGrid::of(&sys.display),
        acc: depths_mm
            .iter()
            .map(|&depth_mm| DepthAccumulator {
                depth_mm,
                table: ColumnTable::new(),
                recent: [(EMPTY, 0); RECENT],
                off: [0.0; 4],
                block: RowBlock {
                    counts: vec![Vec::with_capacity(n_cols); nch],
                    entries: vec![(Vec::new(), Vec::new()); nch],
                    offset: vec![vec![0.0; n_cols]; nch],
                },
            })
            .collect(),
        branches: Vec::with_capacity(64),
        total: 0.0,
        weighted: Vec::with_capacity(64),
    };
    let mut order: Vec<usize> = Vec::new();
    let first_col = pixels.start;
    for col in pixels {
        for a in &mut columns.acc {
            a.off = [0.0; 4];
        }
        drive_pixel(
            sys,
            set,
            (set.spp, rule),
            (col, row),
            &mut stats,
            &mut columns,
        );
        for a in &mut columns.acc {
            a.store_pixel(sys, set, col - first_col, &mut order);
        }
    }
    (columns.acc.into_iter().map(|a| a.block).collect(), stats)
}

/// The camera samples of a pixel summed into the columns of every depth's H
/// ([`matrix_row_lanes`]).
struct MatrixColumns<'a, const L: usize> {
    sys: &'a System,
    /// The display's polarisation fractions [TE, TM].
    pol: [f64; 2],
    grid: PixelGrid,
    acc: Vec<DepthAccumulator<L>>,
    /// The current sample's branches: (weight averaged over the display's polarisation,
    /// front-face exit point), and the sum of their weights.
    branches: Vec<(f64, glam::DVec2)>,
    total: f64,
    /// Per branch: its exit point, H contribution per lane and offset contribution per channel.
    weighted: Vec<(glam::DVec2, [f64; L], [f64; 4])>,
}

impl<const L: usize> SampleConsumer for MatrixColumns<'_, L> {
    #[inline(always)]
    fn begin(&mut self, _s: &CameraSample, _i: u64) {
        self.branches.clear();
        self.total = 0.0;
    }

    #[inline(always)]
    fn branch(&mut self, _s: &CameraSample, b: &crate::trace::Branch) -> std::ops::ControlFlow<()> {
        let wt = self.pol[0] * b.weight[0] + self.pol[1] * b.weight[1];
        if wt > 0.0 {
            self.branches.push((wt, b.exit_point_mm));
            self.total += wt;
        }
        std::ops::ControlFlow::Continue(())
    }

    // Out of line: the trace loop of the driver stays small (measured: inlined, the matrix
    // took 4.5 % more CPU time).
    #[inline(never)]
    fn end(&mut self, s: &CameraSample, _i: u64, stats: &mut RenderStats) {
        use crate::optics::interface::lateral_shift;
        let (sys, disp) = (self.sys, &self.sys.display);
        let nch = sys.response.curves.len();
        let bl = disp.black_level;
        // A non-finite sample is dropped at every depth alike: the decision uses all of
        // its branches, wherever they land (branch weights are finite and positive, so this
        // drops exactly the samples whose factor is not finite).
        if !(s.factor * self.total).is_finite() {
            stats.nonfinite_samples += 1;
            return;
        }
        let r = channel_weights(sys, s.lambda_nm);
        let wp = disp.primary_weights(s.lambda_nm);
        // Per branch, once for every depth: its H contribution c·r_ch (times w_p per
        // primary of a colour display) and its offset contribution c·r_ch·bl (unused
        // channels stay 0, so whole lanes add).
        self.weighted.clear();
        self.weighted
            .extend(self.branches.iter().map(|&(wt, exit)| {
                let c = s.factor * wt;
                let (mut cr, mut crb) = ([0.0f64; L], [0.0f64; 4]);
                for ch in 0..nch {
                    if L == 4 {
                        cr[ch] = c * r[ch];
                    } else {
                        for (p, w) in wp.iter().enumerate() {
                            cr[4 * p + ch] = c * r[ch] * w;
                        }
                    }
                    crb[ch] = c * r[ch] * bl;
                }
                (exit, cr, crb)
            }));
        // Physical light travels along −dir (as in `trace`): every branch of the sample
        // crosses the air gap to depth D with the same lateral shift.
        let u = -s.ray.dir.truncate();
        for a in &mut self.acc {
            let shift = lateral_shift(u, 1.0, a.depth_mm);
            for (exit, cr, crb) in &self.weighted {
                a.add(disp, &self.grid, *exit - shift, cr, crb);
            }
        }
    }
}

impl<const L: usize> DepthAccumulator<L> {
    /// Adds one branch landing at `x` on this depth's plane: its offset contribution `crb` if
    /// it is on the display, and its H contribution `cr` to the object pixel it hits.
    #[inline(always)]
    fn add(
        &mut self,
        disp: &crate::display::Display,
        grid: &PixelGrid,
        x: glam::DVec2,
        cr: &[f64; L],
        crb: &[f64; 4],
    ) {
        // `Display::on_lcd`, with the pixel lookup done once.
        let k = grid.pixel_at(x);
        if k.is_none() && !disp.within_extent(x) {
            return;
        }
        for (o, v) in self.off.iter_mut().zip(crb) {
            *o += v;
        }
        if let Some((kc, kr)) = k {
            let key = (kr * disp.width_px + kc) as u32;
            // A pixel's samples land on a few object pixels per depth: a small
            // direct-mapped cache finds most entries without probing the table.
            let slot = recent_slot(key);
            let idx = if self.recent[slot].0 == key {
                self.recent[slot].1 as usize
            } else {
                let idx = self.table.index(key);
                self.recent[slot] = (key, idx as u32);
                idx
            };
            let e = &mut self.table.sums[idx];
            for (e, v) in e.iter_mut().zip(cr) {
                *e += v;
            }
        }
    }

    /// Stores the finished pixel (index `i` in the row block): its entries sorted by column
    /// and its offset, each divided by the spp, then empties the table for the next pixel.
    fn store_pixel(
        &mut self,
        sys: &System,
        set: &RenderSettings,
        i: usize,
        order: &mut Vec<usize>,
    ) {
        let disp = &sys.display;
        let (nch, bl) = (sys.response.curves.len(), disp.black_level);
        let inv_spp = 1.0 / f64::from(set.spp.max(1));
        let planes = L / 4;
        let n_obj = (disp.width_px * disp.height_px) as u32;
        let table = &mut self.table;
        order.clear();
        order.extend(0..table.keys.len());
        order.sort_unstable_by_key(|&i| table.keys[i]);
        for ch in 0..nch {
            let (cols, vals) = &mut self.block.entries[ch];
            let mut n = 0u32;
            // Columns increase: primary blocks in order, object pixels sorted within.
            for p in 0..planes {
                for &k in order.iter() {
                    let v = (table.sums[k][4 * p + ch] * (1.0 - bl) * inv_spp) as f32;
                    if v != 0.0 {
                        cols.push(p as u32 * n_obj + table.keys[k]);
                        vals.push(v);
                        n += 1;
                    }
                }
            }
            self.block.counts[ch].push(n);
        }
        for (o, &v) in self.block.offset.iter_mut().zip(&self.off) {
            o[i] = v * inv_spp;
        }
        table.clear();
        self.recent = [(EMPTY, 0); RECENT];
    }
}

/// Moves the object (display) plane to `depth_mm` in front of the plate, keeping the camera
/// focus (`stscam matrix --depth-mm`); check the value with [`crate::stack::check_depth`] first.
pub fn place_object(sys: &mut System, depth_mm: f64) {
    sys.display.z_mm = -depth_mm;
}

/// Computes H and the offset of `sys` for the object size of its display target.
/// Deterministic for a given seed, whatever the thread count.
pub fn compute_matrix(sys: &System, set: &RenderSettings) -> SystemMatrix {
    let mut stack = compute_matrix_stack(sys, set, &[-sys.display.z_mm]);
    stack.swap_remove(0)
}

/// Computes one H (and offset) per object-plane depth (mm from the plate's front face) in one
/// pass over the camera paths: every path is traced once and each of its branches meets every
/// plane. The camera, the wavelength sampling and the display's extent and pixel grid are those
/// of `sys`; only the plane moves, as `stscam matrix --depth-mm D` does. The H at depth D is
/// bit-identical to `compute_matrix` of `sys` with `display.z_mm = −D` (same seed and spp).
/// Each matrix's `stats` are the pass's counters. A sample whose value is not finite (its
/// factor, times the sum of all its branch weights) is dropped at every depth.
pub fn compute_matrix_stack(
    sys: &System,
    set: &RenderSettings,
    depths_mm: &[f64],
) -> Vec<SystemMatrix> {
    stack_pass(sys, set, depths_mm, u64::MAX).unwrap_or_default()
}

/// Peak bytes a stored entry of a depth stack costs while it is computed and written: 8 in the
/// pass's row blocks, up to 16 with their vectors' spare capacity (many small blocks: the
/// allocator keeps their memory after they are freed), then 8 in its depth's matrix, 8 in the
/// block matrix `H_stack.npz` and 8 + 8 in the two encoded files, all held until the output set
/// is committed: 48. Measured peaks (maximum resident set of `matrix --depth-mm`) are 41 bytes
/// an entry beyond the fixed bytes. Python's `matrix_stack` holds less (no encoded files).
pub const STACK_BYTES_PER_ENTRY: u64 = 48;

/// Most pilot sample-depths (pilot pixels × spp × depths) of [`estimate_stack_memory`]: about
/// 0.2 s on two cores; the pilot grid shrinks from 16 × 16 towards 8 × 8 pixels to keep it.
const PILOT_WORK: u64 = 1 << 21;

/// A depth stack's memory, estimated before its pass.
#[derive(Clone, Debug, PartialEq)]
pub struct StackMemory {
    /// Bytes that do not depend on the entries: per row and depth an entry count, an offset and
    /// a row pointer (in the pass, the matrices and the encoded files), and the block matrix's
    /// row pointers and offset.
    pub fixed_bytes: u128,
    /// Estimated stored entries of all depths together.
    pub entries: f64,
    /// Pixels traced for the estimate (0: the bound of `cols` entries per row and depth was low
    /// enough, nothing traced).
    pub pilot_pixels: usize,
}

impl StackMemory {
    /// The peak bytes of a stack of `entries` stored entries.
    pub fn peak_bytes(&self, entries: f64) -> u128 {
        self.fixed_bytes + (entries.max(0.0) * STACK_BYTES_PER_ENTRY as f64).ceil() as u128
    }

    /// The estimated peak bytes of the stack.
    pub fn estimated_peak_bytes(&self) -> u128 {
        self.peak_bytes(self.entries)
    }

    /// The most entries the pass may store for the peak to stay within `max_bytes`.
    pub fn entry_budget(&self, max_bytes: u128) -> u64 {
        (max_bytes.saturating_sub(self.fixed_bytes) / u128::from(STACK_BYTES_PER_ENTRY))
            .min(u128::from(u64::MAX)) as u64
    }
}

/// Estimates a depth stack's memory before its pass. Rows = channels × crop pixels, N depths.
/// Every row of every depth stores at most one entry per object pixel: when that bound's peak
/// stays within `max_bytes`, it is the estimate and nothing is traced. Otherwise a pilot traces
/// a grid of 8 × 8 to 16 × 16 crop pixels spread evenly over the crop (fewer when spp × depths
/// is large, see `PILOT_WORK`), at the job's spp and depths
/// (each pilot pixel's entries are exactly those the pass will store for it), and scales their
/// mean entry count to the crop: an unbiased estimate of the total (a stratified sample of the
/// crop; measured within a few per cent of the true count, docs/limits.md). Its cost is about
/// 256 / (crop pixels) of the pass.
pub fn estimate_stack_memory(
    sys: &System,
    set: &RenderSettings,
    depths_mm: &[f64],
    max_bytes: u128,
) -> StackMemory {
    let (w, h) = (sys.camera.width_px, sys.camera.height_px);
    let nch = sys.response.curves.len() as u128;
    let n = depths_mm.len() as u128;
    let rows = nch * w as u128 * h as u128;
    let cols = sys.display.object_len() as u128;
    // Per row and depth 24 bytes at most at once: the pass's count (4) and offset (8) beside
    // the matrix's row pointer (8) and offset (4); later the matrix's beside their encoded
    // copies (at most 8 + 4). The block matrix: row pointer (8, encoded 8), offset (4 + 4).
    let fixed_bytes = rows * n * 24 + rows * 24;
    let bound = StackMemory {
        fixed_bytes,
        entries: (rows * n * cols) as f64,
        pilot_pixels: 0,
    };
    if bound.estimated_peak_bytes() <= max_bytes || w == 0 || h == 0 {
        return bound;
    }
    let rule = lattice_rule(set, set.spp);
    let per_pixel = u64::from(set.spp.max(1)) * depths_mm.len().max(1) as u64;
    let side = ((PILOT_WORK / per_pixel) as f64).sqrt().clamp(8.0, 16.0) as usize;
    let (gx, gy) = (w.min(side), h.min(side));
    let pixels: Vec<(usize, usize)> = (0..gy)
        .flat_map(|j| {
            (0..gx).map(move |i| ((2 * i + 1) * w / (2 * gx), (2 * j + 1) * h / (2 * gy)))
        })
        .collect();
    let entries: usize = pixels
        .par_iter()
        .map(|&(col, row)| {
            let (blocks, _) = matrix_row(sys, set, rule, depths_mm, row, col..col + 1);
            blocks
                .iter()
                .flat_map(|b| b.entries.iter().map(|e| e.0.len()))
                .sum::<usize>()
        })
        .sum();
    StackMemory {
        fixed_bytes,
        entries: entries as f64 * (w * h) as f64 / pixels.len() as f64,
        pilot_pixels: pixels.len(),
    }
}

/// [`compute_matrix_stack`] whose peak memory (the pass, the matrices, the block matrix and the
/// encoded files of `matrix --depth-mm`, [`STACK_BYTES_PER_ENTRY`] a stored entry plus the
/// fixed bytes) stays within `max_bytes` (the CLI and Python pass `limits::MAX_JOB_BYTES`):
/// refused before the pass when [`estimate_stack_memory`]'s peak passes it, and stopped during
/// the pass once the stored entries would (the estimate can be low), returning what went wrong
/// instead of matrices. Either error names `--depth-mm`. Returns the matrices with the estimate.
pub fn compute_matrix_stack_within(
    sys: &System,
    set: &RenderSettings,
    depths_mm: &[f64],
    max_bytes: u128,
) -> Result<(Vec<SystemMatrix>, StackMemory), crate::limits::LimitError> {
    let gib = |b: u128| crate::numfmt::sig6(b as f64 / f64::from(1u32 << 30));
    let mem = estimate_stack_memory(sys, set, depths_mm, max_bytes);
    let peak = mem.estimated_peak_bytes();
    let refuse = |message: String| crate::limits::LimitError {
        setting: "--depth-mm".into(),
        message,
    };
    if peak > max_bytes {
        return Err(refuse(format!(
            "the {} matrices would need about {} GiB at their peak (estimated from {} pilot pixels), more than the {} GiB accepted: use fewer depths, fewer --spp or a smaller crop",
            depths_mm.len(),
            gib(peak),
            mem.pilot_pixels,
            gib(max_bytes)
        )));
    }
    let stack = stack_pass(sys, set, depths_mm, mem.entry_budget(max_bytes)).ok_or_else(|| {
        refuse(format!(
            "the {} matrices would need more than the {} GiB accepted (stopped early, the estimate was {} GiB): use fewer depths, fewer --spp or a smaller crop",
            depths_mm.len(),
            gib(max_bytes),
            gib(peak)
        ))
    })?;
    Ok((stack, mem))
}

/// The stack pass; None when the stored entries passed `max_entries`.
fn stack_pass(
    sys: &System,
    set: &RenderSettings,
    depths_mm: &[f64],
    max_entries: u64,
) -> Option<Vec<SystemMatrix>> {
    use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
    let (w, h) = (sys.camera.width_px, sys.camera.height_px);
    let nch = sys.response.curves.len();
    let cols = sys.display.object_len();
    let what = if depths_mm.len() == 1 {
        "matrix rows".to_string()
    } else {
        format!("matrix rows ({} depths)", depths_mm.len())
    };
    let rule = lattice_rule(set, set.spp);
    let cancel = crate::cancel::current();
    let (stored, over) = (AtomicU64::new(0), AtomicBool::new(false));
    // A row skipped (cancelled, or past the entry budget): no entries.
    let empty_row = || {
        let empty = || RowBlock {
            counts: vec![vec![0; w]; nch],
            entries: vec![(Vec::new(), Vec::new()); nch],
            offset: vec![vec![0.0; w]; nch],
        };
        (
            depths_mm.iter().map(|_| empty()).collect::<Vec<_>>(),
            RenderStats::default(),
        )
    };
    let rows: Vec<(Vec<RowBlock>, RenderStats)> = crate::rows::par_rows(
        h,
        set.progress,
        &what,
        &cancel,
        |row| {
            if over.load(Ordering::Relaxed) {
                return empty_row();
            }
            let b = matrix_row(sys, set, rule, depths_mm, row, 0..w);
            let entries = (b.0.iter())
                .flat_map(|blk| blk.entries.iter().map(|e| e.0.len()))
                .sum::<usize>() as u64;
            if stored.fetch_add(entries, Ordering::Relaxed) + entries > max_entries {
                over.store(true, Ordering::Relaxed);
            }
            b
        },
        |_| empty_row(),
    );
    if over.load(Ordering::Relaxed) {
        return None;
    }
    let mut stats = RenderStats::default();
    for (_, s) in &rows {
        stats.merge(s);
    }
    Some(
        (0..depths_mm.len())
            .map(|d| {
                let blocks: Vec<&RowBlock> = rows.iter().map(|r| &r.0[d]).collect();
                let nnz: usize = blocks
                    .iter()
                    .map(|b| b.entries.iter().map(|e| e.0.len()).sum::<usize>())
                    .sum();
                let mut m = CsrMatrix {
                    rows: nch * w * h,
                    cols,
                    indptr: Vec::with_capacity(nch * w * h + 1),
                    indices: Vec::with_capacity(nnz),
                    data: Vec::with_capacity(nnz),
                };
                m.indptr.push(0);
                let mut offset = Vec::with_capacity(nch * w * h);
                let st = stats.clone();
                for ch in 0..nch {
                    for b in &blocks {
                        let mut last = *m.indptr.last().unwrap_or(&0);
                        for &n in &b.counts[ch] {
                            last += u64::from(n);
                            m.indptr.push(last);
                        }
                        m.indices.extend_from_slice(&b.entries[ch].0);
                        m.data.extend_from_slice(&b.entries[ch].1);
                        offset.extend(b.offset[ch].iter().map(|&v| v as f32));
                    }
                }
                SystemMatrix {
                    h: m,
                    offset,
                    crop: (w, h),
                    object: (sys.display.width_px, sys.display.height_px),
                    planes: sys.display.planes(),
                    channels: sys.response.names.clone(),
                    stats: st,
                }
            })
            .collect(),
    )
}

impl SystemMatrix {
    /// The capture H·f + offset of object `f` (linear intensities, row-major), as one vector
    /// per channel (row-major crop images).
    pub fn capture_of(&self, f: &[f64]) -> Vec<Vec<f64>> {
        let g = self.h.mul_vec(f);
        let p = self.crop.0 * self.crop.1;
        g.chunks(p.max(1))
            .zip(self.offset.chunks(p.max(1)))
            .map(|(gc, oc)| gc.iter().zip(oc).map(|(a, &b)| a + f64::from(b)).collect())
            .collect()
    }
}

pub use crate::io::hfile::{LoadedMatrix, default_offset_path, load_matrix, read_checked_csr};

/// The layered offset Σ_d o_d (f64 sums, stored as f32).
pub fn layered_offset(stack: &[SystemMatrix]) -> Vec<f32> {
    let n = stack.first().map_or(0, |m| m.offset.len());
    (0..n)
        .map(|i| stack.iter().map(|m| f64::from(m.offset[i])).sum::<f64>() as f32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// max |H f + offset − render| over the render's peak.
    fn rel_diff(m: &SystemMatrix, f: &[f64], cap: &crate::render::Capture) -> f64 {
        let pred = m.capture_of(f);
        let (mut d, mut peak) = (0.0f64, 0.0f64);
        for (p, c) in pred.iter().zip(&cap.channels) {
            for (a, &b) in p.iter().zip(c) {
                d = d.max((a - f64::from(b)).abs());
                peak = peak.max(f64::from(b).abs());
            }
        }
        d / peak
    }

    #[test]
    fn colour_h_reproduces_the_render_of_a_colour_target() {
        let ov = [
            "sensor.crop_px=24".to_string(),
            "sensor.pitch_um=60".to_string(),
            "sensor.response=rgb-bayer".to_string(),
            "display.primaries=lcd".to_string(),
            "display.image=rgb:letter:F@8+shape:disk@8+checker:2@8".to_string(),
        ];
        let sys = System::build(&crate::scene::load_scene(None, &ov).unwrap()).unwrap();
        let set = RenderSettings::lattice(4, 3, false);
        let m = compute_matrix(&sys, &set);
        assert_eq!((m.h.rows, m.h.cols, m.planes), (3 * 24 * 24, 3 * 64, 3));
        m.h.check().unwrap();
        // Every primary's block holds light.
        let blocks = m.h.hsplit(3).unwrap();
        for b in &blocks {
            assert!(b.frobenius_sq() > 0.0);
        }
        let cap = crate::render::render(&sys, &set);
        let f = &sys.display.intensity;
        assert_eq!(f.len(), 3 * 64);
        // The contract to float rounding (f32 storage of H, offset and capture: 1e-5).
        let ok = rel_diff(&m, f, &cap);
        assert!(ok < 1e-5, "{ok}");
        // It can fail: the same object with its red and blue planes swapped.
        let mut swapped = f.clone();
        swapped[..64].copy_from_slice(&f[128..]);
        swapped[128..].copy_from_slice(&f[..64]);
        let bad = rel_diff(&m, &swapped, &cap);
        assert!(bad > 1e-2, "{bad}");
        // A grey target drives the three primaries equally: its H f is H's blocks summed.
        let mut grey = sys.clone();
        grey.display.set_intensity(&vec![0.5; 64]);
        assert_eq!(grey.display.intensity, vec![0.5; 192]);
        let g = crate::render::render(&grey, &set);
        assert!(rel_diff(&m, &grey.display.intensity, &g) < 1e-5);
    }

    #[test]
    fn a_stack_beyond_its_memory_budget_stops() {
        let ov = [
            "sensor.crop_px=24".to_string(),
            "sensor.pitch_um=60".to_string(),
            "display.image=letter:F@8".to_string(),
        ];
        let sys = System::build(&crate::scene::load_scene(None, &ov).unwrap()).unwrap();
        let set = RenderSettings::lattice(2, 3, false);
        let depths = [400.0, 550.0];
        let full = compute_matrix_stack(&sys, &set, &depths);
        let bytes: u64 = full.iter().map(|m| 8 * m.h.nnz() as u64).sum();
        assert!(bytes > 64, "{bytes}");
        let entries = bytes / 8;
        // The pass: just enough entries gives the same matrices; one entry short stops it.
        let ok = stack_pass(&sys, &set, &depths, entries).expect("within");
        assert_eq!(ok[1].h, full[1].h);
        assert!(stack_pass(&sys, &set, &depths, entries - 1).is_none());
        // The library call: the true peak as the limit runs (the pilot traces 256 of these
        // 24 x 24 pixels, so its estimate may differ from the count: allow 2x), a
        // quarter of it is refused, naming --depth-mm.
        let mem = estimate_stack_memory(&sys, &set, &depths, 0);
        assert_eq!(mem.pilot_pixels, 256);
        let rel = mem.entries / entries as f64;
        assert!((0.5..2.0).contains(&rel), "{rel}");
        let peak = mem.peak_bytes(entries as f64);
        assert_eq!(mem.entry_budget(peak), entries);
        let limit = 2 * peak.max(mem.estimated_peak_bytes());
        let (ok, _) = compute_matrix_stack_within(&sys, &set, &depths, limit).expect("within");
        assert_eq!(ok[0].h, full[0].h);
        let e = compute_matrix_stack_within(&sys, &set, &depths, peak / 4).unwrap_err();
        assert_eq!(e.setting, "--depth-mm");
        assert!(e.message.contains("pilot pixels"), "{e}");
        // Below the bound of one entry per object pixel nothing is traced.
        let none = estimate_stack_memory(&sys, &set, &depths, u128::MAX);
        assert_eq!(none.pilot_pixels, 0);
        assert_eq!(none.entries, (24 * 24 * 2 * 64) as f64);
    }
}
