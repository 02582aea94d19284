//! Reconstruction of the object f from a capture g = H·f + n (docs/physics.md §8).
//!
//! Set-up (once per H, reported separately from the per-frame cost): Hᵀ in CSR form for the
//! back-projection Hᵀg, and the Gram matrix G = HᵀH (N×N, sparse: two object pixels interact
//! only if their replicas overlap on the sensor). G is stored by diagonals when that is compact
//! (the replica structure makes G nearly shift-invariant, so few distinct offsets carry all
//! entries and the product runs as contiguous multiply-adds), else in CSR form.
//! Per frame: one back-projection Hᵀg, then CG (`cg.rs`) or ADMM-TV (`admm.rs`) iterating
//! with G only, never with H.
//!
//! Layer: reconstruction of f from g = Hf + n: CG, ADMM-TV, the discrepancy rule, depth and joint solves, metrics; never the tracer.
//! May depend on: stscam-base, stscam-io (docs/design.md, "Crates"; checked by `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod admm;
pub mod cg;
pub mod colour;
pub mod depth;
pub mod discrepancy;
pub mod joint;
pub mod layered;
pub mod metrics;
// The layers below, under the names this crate's modules use (`crate::io::…`).
use stscam_base::cancel::Token;
#[cfg(test)]
use stscam_base::sampler;
use stscam_base::{cancel, cie, noise, sparse, spectra};
use stscam_io::stack;

use rayon::prelude::*;

use crate::sparse::CsrMatrix;

/// The Gram matrix G = HᵀH in the faster of two layouts.
#[derive(Clone, Debug)]
pub enum Gram {
    /// By diagonals: `diags[j][a]` = G[a, a + offsets[j]] (0 outside the matrix).
    Diagonal {
        /// Offsets b − a of the stored diagonals, increasing.
        offsets: Vec<isize>,
        /// One length-N vector per offset.
        diags: Vec<Vec<f64>>,
    },
    /// Compressed rows (f64 values).
    Rows {
        /// Row pointers.
        indptr: Vec<usize>,
        /// Columns.
        indices: Vec<u32>,
        /// Values.
        data: Vec<f64>,
    },
}

/// A reconstruction problem: H's transpose, its Gram matrix and the object shape.
#[derive(Clone, Debug)]
pub struct Problem {
    /// Hᵀ (rows = object pixels).
    pub ht: CsrMatrix,
    /// G = HᵀH.
    pub gram: Gram,
    /// Diagonal of G.
    pub gram_diag: Vec<f64>,
    /// Object width in pixels.
    pub width: usize,
    /// Object height in pixels.
    pub height: usize,
    /// Stored entries of G.
    pub gram_nnz: usize,
    /// Stops the solvers between iterations once set (the set-up checks it between rows of
    /// G); a problem made by [`Problem::new`] has a token that is never set.
    pub cancel: Token,
}

/// Rows of G per parallel task.
const GRAM_CHUNK: usize = 64;

/// An upper bound on the memory [`Problem::new`] needs for `h` with `threads` workers, in
/// bytes, computed in O(rows) before any allocation: G has at most min(Σₘ nnzₘ², N²)
/// entries (row m of H couples each pair of its columns), each held about three times
/// during the set-up (row lists, offsets, final layout: 32 bytes), plus Hᵀ and two length-N
/// work rows per thread.
pub fn setup_bytes_bound(h: &CsrMatrix, threads: usize) -> u128 {
    setup_bytes_bound_blocks(&[h], threads)
}

/// [`setup_bytes_bound`] of the block matrix [H₁ … H_N] (same rows), from the blocks.
pub fn setup_bytes_bound_blocks(blocks: &[&CsrMatrix], threads: usize) -> u128 {
    let n: u128 = blocks.iter().map(|b| b.cols as u128).sum();
    let rows = blocks.first().map_or(0, |b| b.rows);
    let pairs: u128 = (0..rows)
        .map(|m| {
            let k: u128 = blocks.iter().map(|b| b.row_range(m).len() as u128).sum();
            k * k
        })
        .sum();
    let nnz: u128 = blocks.iter().map(|b| b.nnz() as u128).sum();
    pairs.min(n * n) * 32 + nnz * 8 + n * 9 * threads as u128
}

impl Problem {
    /// Prepares H (rows = captures values, columns = object pixels, object `width`×`height`),
    /// never cancelled.
    pub fn new(h: &CsrMatrix, width: usize, height: usize) -> Problem {
        Self::with_cancel(h, width, height, Token::default())
    }

    /// [`Problem::new`] that stops once `cancel` is set (Ctrl-C in Python): the set-up skips
    /// its remaining rows and the solvers stop between iterations; the meaningless result is
    /// discarded by the front end.
    pub fn with_cancel(h: &CsrMatrix, width: usize, height: usize, cancel: Token) -> Problem {
        assert_eq!(width * height, h.cols, "object shape does not match H");
        let ht = h.transpose();
        let n = h.cols;
        // Row a of G: Σ_m H[m,a]·H[m,:], accumulated in a fixed order (m increasing).
        let rows: Vec<(Vec<u32>, Vec<f64>)> = (0..n)
            .into_par_iter()
            .with_min_len(GRAM_CHUNK)
            .map_init(
                || (vec![0.0f64; n], vec![false; n], Vec::<u32>::new()),
                |(acc, seen, touched), a| {
                    if cancel.is_cancelled() {
                        return (Vec::new(), Vec::new());
                    }
                    for e in ht.row_range(a) {
                        let m = ht.indices[e] as usize;
                        let va = f64::from(ht.data[e]);
                        for f in h.row_range(m) {
                            let b = h.indices[f] as usize;
                            if !seen[b] {
                                seen[b] = true;
                                touched.push(b as u32);
                            }
                            acc[b] += va * f64::from(h.data[f]);
                        }
                    }
                    touched.sort_unstable();
                    let vals: Vec<f64> = touched.iter().map(|&b| acc[b as usize]).collect();
                    for &b in touched.iter() {
                        acc[b as usize] = 0.0;
                        seen[b as usize] = false;
                    }
                    let cols = std::mem::take(touched);
                    (cols, vals)
                },
            )
            .collect();
        let gram_nnz: usize = rows.iter().map(|r| r.0.len()).sum();
        let mut gram_diag = vec![0.0; n];
        for (a, (c, v)) in rows.iter().enumerate() {
            if let Ok(p) = c.binary_search(&(a as u32)) {
                gram_diag[a] = v[p];
            }
        }
        let mut offsets: Vec<isize> = rows
            .iter()
            .enumerate()
            .flat_map(|(a, (c, _))| c.iter().map(move |&b| b as isize - a as isize))
            .collect();
        offsets.sort_unstable();
        offsets.dedup();
        // Diagonal storage costs offsets·N multiply-adds on contiguous data; CSR costs
        // nnz gathers, each about three times as expensive.
        let gram = if offsets.len() * n <= 3 * gram_nnz {
            let mut diags = vec![vec![0.0; n]; offsets.len()];
            for (a, (c, v)) in rows.iter().enumerate() {
                for (&b, &x) in c.iter().zip(v) {
                    let j = offsets
                        .binary_search(&(b as isize - a as isize))
                        .unwrap_or(0);
                    diags[j][a] = x;
                }
            }
            Gram::Diagonal { offsets, diags }
        } else {
            let mut indptr = Vec::with_capacity(n + 1);
            indptr.push(0);
            let mut indices = Vec::with_capacity(gram_nnz);
            let mut data = Vec::with_capacity(gram_nnz);
            for (c, v) in rows {
                indices.extend(c);
                data.extend(v);
                indptr.push(indices.len());
            }
            Gram::Rows {
                indptr,
                indices,
                data,
            }
        };
        Problem {
            ht,
            gram,
            gram_diag,
            width,
            height,
            gram_nnz,
            cancel,
        }
    }

    /// Number of unknowns (object pixels).
    pub fn n(&self) -> usize {
        self.width * self.height
    }

    /// Hᵀg.
    pub fn back_project(&self, g: &[f64]) -> Vec<f64> {
        self.ht.mul_vec(g)
    }

    /// y = G·x.
    pub fn gram_mul(&self, x: &[f64], y: &mut [f64]) {
        match &self.gram {
            Gram::Diagonal { offsets, diags } => {
                let n = x.len();
                y.par_chunks_mut(512).enumerate().for_each(|(chunk, ys)| {
                    let a0 = chunk * 512;
                    let a1 = a0 + ys.len();
                    ys.iter_mut().for_each(|v| *v = 0.0);
                    for (&d, diag) in offsets.iter().zip(diags) {
                        // Rows a with 0 ≤ a + d < n.
                        let lo = a0.max((-d).max(0) as usize);
                        let hi = a1.min((n as isize - d).max(0) as usize);
                        if lo >= hi {
                            continue;
                        }
                        let xs = &x[(lo as isize + d) as usize..(hi as isize + d) as usize];
                        let ds = &diag[lo..hi];
                        for ((yv, &dv), &xv) in ys[lo - a0..hi - a0].iter_mut().zip(ds).zip(xs) {
                            *yv += dv * xv;
                        }
                    }
                });
            }
            Gram::Rows {
                indptr,
                indices,
                data,
            } => {
                y.par_chunks_mut(512).enumerate().for_each(|(chunk, ys)| {
                    for (k, yv) in ys.iter_mut().enumerate() {
                        let a = chunk * 512 + k;
                        let mut acc = 0.0;
                        for e in indptr[a]..indptr[a + 1] {
                            acc += data[e] * x[indices[e] as usize];
                        }
                        *yv = acc;
                    }
                });
            }
        }
    }

    /// Describes the Gram layout (for reports).
    pub fn gram_layout(&self) -> String {
        match &self.gram {
            Gram::Diagonal { offsets, .. } => format!("{} diagonals", offsets.len()),
            Gram::Rows { .. } => "compressed rows".to_string(),
        }
    }
}

/// Dot product in f64 (fixed order).
#[inline]
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    // Four partial sums in a fixed pattern: vectorisable and deterministic.
    let mut s = [0.0f64; 4];
    let chunks = a.len() / 4;
    for i in 0..chunks {
        for j in 0..4 {
            s[j] += a[4 * i + j] * b[4 * i + j];
        }
    }
    let mut t = (s[0] + s[1]) + (s[2] + s[3]);
    for i in 4 * chunks..a.len() {
        t += a[i] * b[i];
    }
    t
}

/// The solver of [`solve`] (`reconstruct --method cg|admm-tv`, Python's `method=`: one
/// definition for clap and the Python module; the first paragraph of each variant's comment is
/// its `--help` line).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Method {
    /// Conjugate gradients on the normal equations (the paper's CGM).
    ///
    /// HᵀHf = Hᵀg from f = 0 ([`cg::cg_normal`]).
    Cg,
    /// ADMM with total variation.
    ///
    /// ½‖Hf − g‖² + τ·TV(f) ([`admm::admm_tv`]).
    AdmmTv,
}

/// Options of [`solve`] (the `stscam reconstruct` flags).
#[derive(Clone, Copy, Debug)]
pub struct SolveOptions {
    /// The solver.
    pub method: Method,
    /// Iterations (default: [`cg::DEFAULT_CG_ITERS`] for CG, 50 for ADMM-TV).
    pub iters: Option<usize>,
    /// ADMM-TV: τ relative to ‖Hᵀg‖∞.
    pub tau_rel: f64,
    /// ADMM-TV: isotropic or anisotropic TV.
    pub tv: admm::TvKind,
}

/// A reconstruction with what the solver reports (`recon.json`'s `solver`).
#[derive(Clone, Debug)]
pub struct Solution {
    /// The object, linear intensities, row-major.
    pub f: Vec<f64>,
    /// Method, iterations and residuals.
    pub info: serde_json::Value,
}

/// Reconstructs the object from `g` (offset already subtracted) for a set-up `problem`: one
/// back-projection, then CG or ADMM-TV. The CLI's `reconstruct` and the Python module call this.
pub fn solve(problem: &Problem, g: &[f64], opts: &SolveOptions) -> Solution {
    let htg = problem.back_project(g);
    match opts.method {
        Method::Cg => {
            let set = cg::CgSettings {
                iters: opts.iters.unwrap_or(cg::DEFAULT_CG_ITERS),
                tol: 0.0,
            };
            let r = cg::cg_normal(problem, &htg, &set);
            let info = serde_json::json!({"method": "cg", "iterations": r.iterations, "relative_residual": r.relative_residual});
            Solution { f: r.f, info }
        }
        Method::AdmmTv => {
            let set = admm::AdmmSettings {
                iters: opts.iters.unwrap_or(50),
                tau_rel: opts.tau_rel,
                tv: opts.tv,
                ..Default::default()
            };
            let r = admm::admm_tv(problem, &htg, &set);
            let info = serde_json::json!({"method": "admm-tv", "iterations": set.iters, "tau_rel": opts.tau_rel, "tau": r.tau, "rho": r.rho, "tv": set.tv, "inner_cg_iterations": set.inner_iters, "primal_residual": r.primal_residual, "dual_residual": r.dual_residual});
            Solution { f: r.f, info }
        }
    }
}

/// [`solve`] for an object of `planes` planes (a colour H: planes R, G, B, primary-major, the
/// problem set up with height = `planes` × the object height, planes stacked along y). One
/// plane is [`solve`]. Several: CG as [`solve`] (it has no spatial prior); ADMM-TV jointly
/// over the planes with TV per plane and non-negativity ([`joint::joint_admm_tv`] without its
/// cross-plane group prior, μ = 0), so no difference is taken across a plane boundary.
pub fn solve_planes(problem: &Problem, planes: usize, g: &[f64], opts: &SolveOptions) -> Solution {
    if planes <= 1 || opts.method == Method::Cg {
        return solve(problem, g, opts);
    }
    let htg = problem.back_project(g);
    let set = joint::JointSettings {
        iters: opts.iters.unwrap_or(50),
        tau_rel: opts.tau_rel,
        mu_rel: 0.0,
        tv: opts.tv,
        ..Default::default()
    };
    let r = joint::joint_admm_tv(problem, planes, &htg, &set);
    let info = serde_json::json!({"method": "admm-tv", "planes": planes, "iterations": set.iters, "tau_rel": opts.tau_rel, "tau": r.tau, "rho": r.rho, "tv": set.tv, "inner_cg_iterations": set.inner_iters, "prior": "TV per plane, non-negative (joint ADMM, no cross-plane term)"});
    Solution {
        f: r.planes.concat(),
        info,
    }
}
