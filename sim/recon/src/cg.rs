//! Conjugate gradients on the normal equations HᵀH f = Hᵀg (the paper's CGM, docs/physics.md §8.3).
//!
//! Plain CG (Hestenes & Stiefel 1952) with the Gram matrix G = HᵀH formed once, starting from
//! f = 0. In exact arithmetic this is CGLS/CGNR; forming G trades a one-time set-up for
//! per-iteration products that do not touch H. The iteration count regularises
//! (semi-convergence): stop at `iters` or when ‖Hᵀg − Gf‖ ≤ tol·‖Hᵀg‖.
//! The same routine, with a Jacobi preconditioner and a warm start, solves the ADMM f-update.

use super::{Problem, dot};
use crate::cancel::Token;

/// Default CGM iteration count (chosen on the demo's noisy targets; see docs/validation.md).
pub const DEFAULT_CG_ITERS: usize = 30;

/// CG settings.
#[derive(Clone, Copy, Debug)]
pub struct CgSettings {
    /// Maximum iterations.
    pub iters: usize,
    /// Relative residual at which to stop (0 = run all iterations).
    pub tol: f64,
}

/// Outcome of a CG solve.
#[derive(Clone, Debug)]
pub struct CgResult {
    /// The solution.
    pub f: Vec<f64>,
    /// Iterations done.
    pub iterations: usize,
    /// Final relative residual ‖b − Gf‖/‖b‖.
    pub relative_residual: f64,
}

/// Preconditioned CG for A x = b from the warm start `x`, with A given by `apply` and an
/// optional inverse diagonal preconditioner, stopped between iterations once `cancel` is set.
/// Returns (iterations, relative residual).
#[allow(clippy::too_many_arguments)]
pub(crate) fn pcg(
    apply: impl FnMut(&[f64], &mut [f64]),
    inv_diag: Option<&[f64]>,
    b: &[f64],
    x: &mut [f64],
    iters: usize,
    tol: f64,
    cancel: &Token,
) -> (usize, f64) {
    pcg_until(apply, inv_diag, b, x, iters, tol, cancel, |_, _| false)
}

/// [`pcg`] that also stops after the first iteration at which `stop(x, r)` holds (x the
/// iterate, r = b − A x its residual).
#[allow(clippy::too_many_arguments)]
pub(crate) fn pcg_until(
    mut apply: impl FnMut(&[f64], &mut [f64]),
    inv_diag: Option<&[f64]>,
    b: &[f64],
    x: &mut [f64],
    iters: usize,
    tol: f64,
    cancel: &Token,
    mut stop: impl FnMut(&[f64], &[f64]) -> bool,
) -> (usize, f64) {
    let n = b.len();
    let bnorm = dot(b, b).sqrt();
    if bnorm == 0.0 {
        x.iter_mut().for_each(|v| *v = 0.0);
        return (0, 0.0);
    }
    let mut q = vec![0.0; n];
    apply(x, &mut q);
    let mut r: Vec<f64> = b.iter().zip(&q).map(|(bi, qi)| bi - qi).collect();
    let precond = |r: &[f64], z: &mut Vec<f64>| match inv_diag {
        Some(d) => {
            z.clear();
            z.extend(r.iter().zip(d).map(|(a, b)| a * b));
        }
        None => {
            z.clear();
            z.extend_from_slice(r);
        }
    };
    let mut z = Vec::with_capacity(n);
    precond(&r, &mut z);
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let mut res = dot(&r, &r).sqrt() / bnorm;
    let mut k = 0;
    // A cancelled job (Ctrl-C in Python, `crate::cancel`) stops between iterations.
    while k < iters && res > tol {
        if cancel.is_cancelled() {
            break;
        }
        apply(&p, &mut q);
        let pq = dot(&p, &q);
        if pq <= 0.0 || !pq.is_finite() {
            break;
        }
        let alpha = rz / pq;
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * q[i];
        }
        k += 1;
        res = dot(&r, &r).sqrt() / bnorm;
        if stop(x, &r) {
            break;
        }
        precond(&r, &mut z);
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            p[i] = z[i] + beta * p[i];
        }
    }
    (k, res)
}

/// CGM: CG on HᵀH f = Hᵀg from f = 0, given the back-projection `htg` = Hᵀg.
pub fn cg_normal(p: &Problem, htg: &[f64], set: &CgSettings) -> CgResult {
    let mut f = vec![0.0; htg.len()];
    let (iterations, relative_residual) = pcg(
        |x, y| p.gram_mul(x, y),
        None,
        htg,
        &mut f,
        set.iters,
        set.tol,
        &p.cancel,
    );
    CgResult {
        f,
        iterations,
        relative_residual,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sparse::CsrMatrix;

    /// A random sparse, well-conditioned tall matrix (identity block plus noise).
    pub(crate) fn synthetic(rows: usize, cols: usize, seed: u64) -> CsrMatrix {
        let mut indptr = vec![0u64];
        let mut indices = Vec::new();
        let mut data = Vec::new();
        for r in 0..rows {
            let mut entries: Vec<(u32, f32)> = Vec::new();
            if r < cols {
                entries.push((r as u32, 2.0));
            }
            for j in 0..3u64 {
                let h = crate::sampler::hash(&[seed, r as u64, j]);
                let c = (h % cols as u64) as u32;
                let v = (crate::sampler::to_unit(h >> 11) - 0.5) as f32 * 0.5;
                if !entries.iter().any(|e| e.0 == c) {
                    entries.push((c, v));
                }
            }
            entries.sort_by_key(|e| e.0);
            for (c, v) in entries {
                indices.push(c);
                data.push(v);
            }
            indptr.push(indices.len() as u64);
        }
        CsrMatrix {
            rows,
            cols,
            indptr,
            indices,
            data,
        }
    }

    /// Least squares by dense Cholesky of the normal equations (independent of CG).
    fn dense_lstsq(h: &CsrMatrix, g: &[f64]) -> Vec<f64> {
        let n = h.cols;
        let mut a = vec![0.0f64; n * n];
        let mut b = vec![0.0f64; n];
        let mut row = vec![0.0; n];
        for m in 0..h.rows {
            h.row_dense_into(m, &mut row);
            for i in 0..n {
                if row[i] == 0.0 {
                    continue;
                }
                b[i] += row[i] * g[m];
                for j in 0..n {
                    a[i * n + j] += row[i] * row[j];
                }
            }
        }
        // Cholesky A = L Lᵀ.
        for j in 0..n {
            let mut d = a[j * n + j];
            for k in 0..j {
                d -= a[j * n + k] * a[j * n + k];
            }
            let d = d.sqrt();
            a[j * n + j] = d;
            for i in j + 1..n {
                let mut s = a[i * n + j];
                for k in 0..j {
                    s -= a[i * n + k] * a[j * n + k];
                }
                a[i * n + j] = s / d;
            }
        }
        let mut y = b;
        for i in 0..n {
            for k in 0..i {
                y[i] -= a[i * n + k] * y[k];
            }
            y[i] /= a[i * n + i];
        }
        for i in (0..n).rev() {
            for k in i + 1..n {
                y[i] -= a[k * n + i] * y[k];
            }
            y[i] /= a[i * n + i];
        }
        y
    }

    #[test]
    fn cg_reaches_the_least_squares_solution() {
        let (rows, w, h) = (500, 16, 16);
        let m = synthetic(rows, w * h, 11);
        let g: Vec<f64> = (0..rows)
            .map(|r| crate::sampler::to_unit(crate::sampler::hash(&[5, r as u64])) - 0.3)
            .collect();
        let p = Problem::new(&m, w, h);
        let htg = p.back_project(&g);
        let res = cg_normal(
            &p,
            &htg,
            &CgSettings {
                iters: 500,
                tol: 1e-14,
            },
        );
        let exact = dense_lstsq(&m, &g);
        let err = res
            .f
            .iter()
            .zip(&exact)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt()
            / exact.iter().map(|b| b * b).sum::<f64>().sqrt();
        assert!(
            err < 1e-8,
            "relative error {err}, {} iterations",
            res.iterations
        );
        assert!(res.iterations < 200);
    }
}
