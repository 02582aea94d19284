//! ADMM for ½‖Hf − g‖² + τ·TV(f) (docs/physics.md §8.1–8.2; Boyd et al. 2011, §6.4.1; Wang, Yang,
//! Yin & Zhang 2008). TV is of the object f (not of g, a typo of the paper; docs/physics.md §0.4).
//!
//! Split z = Df (forward differences, Neumann boundaries: the last difference of each row and
//! column is 0), scaled dual u, penalty ρ:
//!   f ← argmin ½‖Hf − g‖² + ρ/2‖Df − z + u‖²  ⇔ (HᵀH + ρDᵀD) f = Hᵀg + ρDᵀ(z − u),
//!       solved inexactly by Jacobi-preconditioned CG warm-started at the previous f
//!       (`inner_iters` iterations; inexact ADMM converges when the inner errors are summable,
//!       Eckstein & Bertsekas 1992, and warm starts make a few iterations enough);
//!   z ← soft(Df + u, τ/ρ) (anisotropic) or the 2-vector shrinkage per pixel (isotropic);
//!   u ← u + Df − z.
//! Scale-free parameters: τ = τ_rel·‖Hᵀg‖_∞ (the data gradient at f = 0; a large τ_rel drives f
//! toward the best constant image, which TV does not penalise) and ρ = ρ_rel·mean(diag HᵀH), so
//! neither depends on the units of H or g.

use super::{Problem, cg::pcg, dot};

/// Which total variation (`reconstruct --tv`, Python's `tv=`: one definition for clap, serde
/// and the Python module).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum TvKind {
    /// Isotropic TV: Σ_p √((D_x f)_p² + (D_y f)_p²).
    Iso,
    /// Anisotropic TV: Σ_p |(D_x f)_p| + |(D_y f)_p|.
    Aniso,
}

/// ADMM settings.
#[derive(Clone, Copy, Debug)]
pub struct AdmmSettings {
    /// Outer iterations.
    pub iters: usize,
    /// τ relative to ‖Hᵀg‖_∞.
    pub tau_rel: f64,
    /// ρ relative to mean(diag HᵀH).
    pub rho_rel: f64,
    /// TV kind.
    pub tv: TvKind,
    /// CG iterations per f-update.
    pub inner_iters: usize,
    /// Record the objective after every iteration (costs one Gram product each).
    pub record_objective: bool,
}

impl Default for AdmmSettings {
    fn default() -> Self {
        AdmmSettings {
            iters: 50,
            tau_rel: DEFAULT_TAU_REL,
            rho_rel: 1.0,
            tv: TvKind::Iso,
            inner_iters: 3,
            record_objective: false,
        }
    }
}

/// Default τ_rel (chosen on the demo's targets with noise; see docs/validation.md).
pub const DEFAULT_TAU_REL: f64 = 1e-3;

/// Outcome of ADMM.
#[derive(Clone, Debug)]
pub struct AdmmResult {
    /// The reconstruction.
    pub f: Vec<f64>,
    /// τ used (absolute).
    pub tau: f64,
    /// ρ used (absolute).
    pub rho: f64,
    /// Objective after each iteration (if recorded), without the constant ½‖g‖².
    pub objective: Vec<f64>,
    /// Final primal residual ‖Df − z‖.
    pub primal_residual: f64,
    /// Final dual residual ρ‖Dᵀ(z − z_prev)‖.
    pub dual_residual: f64,
}

/// z = Df: x differences in z[..n], y differences in z[n..].
pub fn grad(f: &[f64], w: usize, h: usize, z: &mut [f64]) {
    let n = w * h;
    for r in 0..h {
        for c in 0..w {
            let p = r * w + c;
            z[p] = if c + 1 < w { f[p + 1] - f[p] } else { 0.0 };
            z[n + p] = if r + 1 < h { f[p + w] - f[p] } else { 0.0 };
        }
    }
}

/// out = Dᵀz (the adjoint of [`grad`]).
pub fn grad_adjoint(z: &[f64], w: usize, h: usize, out: &mut [f64]) {
    let n = w * h;
    for r in 0..h {
        for c in 0..w {
            let p = r * w + c;
            let mut v = 0.0;
            if c + 1 < w {
                v -= z[p];
            }
            if c > 0 {
                v += z[p - 1];
            }
            if r + 1 < h {
                v -= z[n + p];
            }
            if r > 0 {
                v += z[n + p - w];
            }
            out[p] = v;
        }
    }
}

/// TV(f) of the chosen kind.
pub fn total_variation(f: &[f64], w: usize, h: usize, kind: TvKind) -> f64 {
    let n = w * h;
    let mut z = vec![0.0; 2 * n];
    grad(f, w, h, &mut z);
    (0..n)
        .map(|p| match kind {
            TvKind::Iso => (z[p] * z[p] + z[n + p] * z[n + p]).sqrt(),
            TvKind::Aniso => z[p].abs() + z[n + p].abs(),
        })
        .sum()
}

/// The z-update of TV-ADMM for one image of n pixels (x differences in [..n], y differences in
/// [n..]): z = soft(Df + u, κ) elementwise (anisotropic) or the 2-vector shrinkage per pixel
/// (isotropic).
pub(crate) fn tv_shrink(df: &[f64], u: &[f64], kappa: f64, kind: TvKind, z: &mut [f64]) {
    let n = z.len() / 2;
    match kind {
        TvKind::Aniso => {
            for i in 0..2 * n {
                let v = df[i] + u[i];
                z[i] = v.signum() * (v.abs() - kappa).max(0.0);
            }
        }
        TvKind::Iso => {
            for q in 0..n {
                let (vx, vy) = (df[q] + u[q], df[n + q] + u[n + q]);
                let norm = (vx * vx + vy * vy).sqrt();
                let s = if norm > 0.0 {
                    (norm - kappa).max(0.0) / norm
                } else {
                    0.0
                };
                z[q] = s * vx;
                z[n + q] = s * vy;
            }
        }
    }
}

/// Number of forward differences at pixel q of a w×h image that involve it (the diagonal of
/// DᵀD).
pub(crate) fn grad_degree(q: usize, w: usize, h: usize) -> usize {
    let (r, c) = (q / w, q % w);
    usize::from(c + 1 < w) + usize::from(c > 0) + usize::from(r + 1 < h) + usize::from(r > 0)
}

/// ½‖Hf − g‖² − ½‖g‖² + τTV(f) = ½fᵀGf − fᵀHᵀg + τTV(f).
pub fn objective(p: &Problem, htg: &[f64], f: &[f64], tau: f64, kind: TvKind) -> f64 {
    let mut gf = vec![0.0; f.len()];
    p.gram_mul(f, &mut gf);
    0.5 * dot(f, &gf) - dot(f, htg) + tau * total_variation(f, p.width, p.height, kind)
}

/// ADMM-TV from f = 0, given the back-projection `htg` = Hᵀg.
pub fn admm_tv(p: &Problem, htg: &[f64], set: &AdmmSettings) -> AdmmResult {
    admm_tv_from(p, htg, set, None)
}

/// ADMM-TV from the start `f0` (z = D f0, u = 0), or from f = 0 if `None`. A start near the
/// solution (e.g. the least-squares fit when τ is small) lets the fixed iteration count
/// converge where 50 iterations from 0 do not.
pub fn admm_tv_from(
    p: &Problem,
    htg: &[f64],
    set: &AdmmSettings,
    f0: Option<&[f64]>,
) -> AdmmResult {
    let (w, h) = (p.width, p.height);
    let n = w * h;
    let tau = set.tau_rel * htg.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let mean_diag = p.gram_diag.iter().sum::<f64>() / n.max(1) as f64;
    let rho = (set.rho_rel * mean_diag).max(f64::MIN_POSITIVE);
    let kappa = tau / rho;
    // Jacobi preconditioner of G + ρDᵀD.
    let inv_diag: Vec<f64> = (0..n)
        .map(|q| {
            let d = p.gram_diag[q] + rho * grad_degree(q, w, h) as f64;
            if d > 0.0 { 1.0 / d } else { 1.0 }
        })
        .collect();
    let mut f = f0.map_or_else(|| vec![0.0; n], <[f64]>::to_vec);
    let mut z = vec![0.0; 2 * n];
    if f0.is_some() {
        grad(&f, w, h, &mut z);
    }
    let mut z_prev = vec![0.0; 2 * n];
    let mut u = vec![0.0; 2 * n];
    let mut df = vec![0.0; 2 * n];
    let mut tmp = vec![0.0; 2 * n];
    let mut rhs = vec![0.0; n];
    let mut dtz = vec![0.0; n];
    let mut objective_log = Vec::new();
    let (mut r_pri, mut r_dual) = (0.0, 0.0);
    let mut gz = vec![0.0; 2 * n];
    let mut dd = vec![0.0; n];
    let mut apply = |x: &[f64], y: &mut [f64]| {
        p.gram_mul(x, y);
        grad(x, w, h, &mut gz);
        grad_adjoint(&gz, w, h, &mut dd);
        for (yv, d) in y.iter_mut().zip(&dd) {
            *yv += rho * d;
        }
    };
    // A cancelled job (Ctrl-C in Python, `crate::cancel`) stops between iterations.
    let cancel = &p.cancel;
    for _ in 0..set.iters {
        if cancel.is_cancelled() {
            break;
        }
        // f-update.
        for i in 0..2 * n {
            tmp[i] = z[i] - u[i];
        }
        grad_adjoint(&tmp, w, h, &mut dtz);
        for i in 0..n {
            rhs[i] = htg[i] + rho * dtz[i];
        }
        pcg(
            &mut apply,
            Some(&inv_diag),
            &rhs,
            &mut f,
            set.inner_iters,
            0.0,
            cancel,
        );
        // z-update.
        grad(&f, w, h, &mut df);
        z_prev.copy_from_slice(&z);
        tv_shrink(&df, &u, kappa, set.tv, &mut z);
        // u-update and residuals.
        let mut rp = 0.0;
        for i in 0..2 * n {
            let d = df[i] - z[i];
            u[i] += d;
            rp += d * d;
            tmp[i] = z[i] - z_prev[i];
        }
        r_pri = rp.sqrt();
        grad_adjoint(&tmp, w, h, &mut dtz);
        r_dual = rho * dot(&dtz, &dtz).sqrt();
        if set.record_objective {
            objective_log.push(objective(p, htg, &f, tau, set.tv));
        }
    }
    AdmmResult {
        f,
        tau,
        rho,
        objective: objective_log,
        primal_residual: r_pri,
        dual_residual: r_dual,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adjoint_of_grad() {
        let (w, h) = (7, 5);
        let f: Vec<f64> = (0..w * h).map(|i| ((i * 13) % 11) as f64).collect();
        let z: Vec<f64> = (0..2 * w * h).map(|i| ((i * 7) % 5) as f64 - 2.0).collect();
        let mut df = vec![0.0; 2 * w * h];
        grad(&f, w, h, &mut df);
        let mut dtz = vec![0.0; w * h];
        grad_adjoint(&z, w, h, &mut dtz);
        // ⟨Df, z⟩ = ⟨f, Dᵀz⟩ where z is restricted to the non-boundary differences.
        let mut zr = z.clone();
        for r in 0..h {
            zr[r * w + w - 1] = 0.0;
        }
        for c in 0..w {
            zr[w * h + (h - 1) * w + c] = 0.0;
        }
        assert!((dot(&df, &zr) - dot(&f, &dtz)).abs() < 1e-9);
        // TV of a step: one edge of height 3 across 5 rows.
        let step: Vec<f64> = (0..w * h)
            .map(|i| if i % w < 3 { 0.0 } else { 3.0 })
            .collect();
        assert_eq!(total_variation(&step, w, h, TvKind::Aniso), 15.0);
        assert_eq!(total_variation(&step, w, h, TvKind::Iso), 15.0);
    }
}
