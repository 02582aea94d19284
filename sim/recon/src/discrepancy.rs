//! Regularisation chosen from the noise: Morozov's discrepancy principle (V. A. Morozov, Soviet
//! Math. Dokl. 7, 414 (1966); Engl, Hanke & Neubauer, *Regularization of Inverse Problems*, 1996,
//! §4.3 for Tikhonov-type parameters and §7.3 for CG as an iterative method).
//!
//! Model: g = H f + n with independent noise of known mean squares σᵢ² (the sensor model,
//! `noise::SensorNoise::mse_about`, at the noiseless value of a pilot fit: shot and read noise
//! and the ADC's rounding, exact for pixels at an integer black level). A reconstruction should
//! explain the data no better than the noise allows: choose the regularisation so that
//! ‖H f − g‖² = η·Σσᵢ² (η = 1 here; the "budget").
//! - ADMM-TV: the residual grows with τ; τ_rel is found by bisection in log τ_rel on
//!   [`TAU_REL_MIN`, `TAU_REL_MAX`] (each step a full ADMM-TV solve).
//! - CGM: stop at the first iteration whose residual is within the budget (the iteration count
//!   is CG's regulariser); the residual comes from CG's own vectors, r = Hᵀg − G f:
//!   ‖H f − g‖² = ‖g‖² − 2 fᵀHᵀg + fᵀG f = ‖g‖² − fᵀHᵀg − fᵀr.
//!
//! Assumptions: H is exact (model error — Monte Carlo noise in H, calibration noise — adds to the
//! residual, so when it dominates the budget cannot be reached and the least regularisation
//! allowed is returned, reported as `reached = false`); saturated pixels are not excluded.

use super::admm::{AdmmResult, AdmmSettings, admm_tv_from};
use super::cg::{CgResult, pcg_until};
use super::{Problem, dot};
use crate::noise::{NoiseRng, SensorNoise};

/// Smallest τ_rel the search tries.
pub const TAU_REL_MIN: f64 = 1e-5;
/// Largest τ_rel the search tries.
pub const TAU_REL_MAX: f64 = 1e-1;
/// Bisection steps in log τ_rel (after the two ends: the bracket shrinks to 10^(4/2⁶), 15 %).
pub const TAU_BISECTIONS: usize = 6;

/// What the discrepancy principle needs of one capture.
#[derive(Clone, Debug, serde::Serialize)]
pub struct NoiseLevel {
    /// ‖g‖² of the capture reconstructed (offset subtracted).
    pub g_norm2: f64,
    /// The target residual η·Σσᵢ².
    pub budget: f64,
    /// The least-squares fit, if computed (ADMM-TV starts from it).
    #[serde(skip)]
    pub f_ls: Option<Vec<f64>>,
}

impl NoiseLevel {
    /// The level of g = frame − dark (or g = frame − offset without a measured dark frame) for
    /// the sensor model `noise`: Σ E[(frameᵢ − μᵢ)²] (+ the same for the dark frame about its
    /// mean `dark_mean` when a measured dark frame was subtracted), each term
    /// `SensorNoise::mse_about` at the model's noiseless value μᵢ = `mean`ᵢ (a pilot fit
    /// H f̂ + offset: the ADC's rounding error depends on where μ falls between codes, which a
    /// noisy reading does not tell).
    pub fn of_model(
        g: &[f64],
        mean: &[f64],
        dark_mean: Option<&[f64]>,
        noise: &SensorNoise,
    ) -> Self {
        let mut budget: f64 = mean.iter().map(|&v| noise.mse_about(v)).sum();
        if let Some(d) = dark_mean {
            budget += d.iter().map(|&v| noise.mse_about(v)).sum::<f64>();
        }
        NoiseLevel {
            g_norm2: dot(g, g),
            budget,
            f_ls: None,
        }
    }

    /// The level of g for `noise` in the range of H: with many more capture values M than
    /// unknowns N (M = 193 600 against N = 4 096 at the paper's size) the residual of any
    /// reasonable f is dominated by the part of the noise no f can fit, ‖(I − P) n‖² (P the
    /// projection onto the range of H), whose fluctuation (≈ √(2M)·σ²) and any model error
    /// swamp the N-dimensional part regularisation controls. So the principle is applied to
    /// the data projected onto the range (the normal equations' problem): by Pythagoras
    /// ‖H f − g‖² = ‖H f_LS − g‖² + ‖H (f − f_LS)‖², and the target is
    /// ‖H f − g‖² = ‖H f_LS − g‖² + E‖P n‖², E‖P n‖² = tr(P Σ) (Σ = diag σᵢ²; for white noise
    /// N σ², the classical (M − N)σ² residual of least squares, e.g. Hansen, *Discrete Inverse
    /// Problems*, SIAM 2010, §5.2). f_LS is CG run to convergence; σᵢ² =
    /// `SensorNoise::mse_about` at μ = H·max(f_LS, 0) + `offset` (plus the dark frame's about
    /// `offset` when a measured dark frame was subtracted); tr(P Σ) is estimated from
    /// [`TRACE_PROBES`] draws n ~ N(0, Σ) as nᵀH (HᵀH)⁻¹Hᵀn (relative error ≈ √(2/(N·probes))).
    pub fn of_capture(
        p: &Problem,
        g: &[f64],
        offset: &[f32],
        dark_subtracted: bool,
        noise: &SensorNoise,
    ) -> Self {
        let htg = p.back_project(g);
        let f_ls = least_squares(p, &htg, false);
        let g_norm2 = dot(g, g);
        let floor = residual_norm2(p, &htg, g_norm2, &f_ls);
        let pos: Vec<f64> = f_ls.iter().map(|v| v.max(0.0)).collect();
        let var: Vec<f64> = forward(p, &pos)
            .iter()
            .zip(offset)
            .map(|(a, &o)| {
                let d = if dark_subtracted {
                    noise.mse_about(f64::from(o))
                } else {
                    0.0
                };
                noise.mse_about(a + f64::from(o)) + d
            })
            .collect();
        let mut trace = 0.0;
        for probe in 0..TRACE_PROBES {
            let n: Vec<f64> = var
                .iter()
                .enumerate()
                .map(|(i, v)| {
                    v.sqrt() * NoiseRng::new(&[0x5452_4143, probe as u64, i as u64]).normal()
                })
                .collect();
            let htn = p.back_project(&n);
            let x = least_squares(p, &htn, true);
            trace += dot(&x, &htn) / TRACE_PROBES as f64;
        }
        NoiseLevel {
            g_norm2,
            budget: floor + trace,
            f_ls: Some(f_ls),
        }
    }
}

/// The brightest value of the all-white capture H·1 + `offset` (every object pixel of every
/// primary white): what fixes the exposure of the sensor model (docs/physics.md §7.3).
pub fn white_peak(h: &crate::sparse::CsrMatrix, offset: &[f32]) -> f64 {
    white_peak_of_sums(&h.mul_vec(&vec![1.0; h.cols]), offset)
}

/// [`white_peak`] from H's row sums H·1.
pub fn white_peak_of_sums(h_ones: &[f64], offset: &[f32]) -> f64 {
    h_ones
        .iter()
        .zip(offset)
        .fold(0.0f64, |a, (&v, &o)| a.max(v + f64::from(o)))
}

/// Random probes of the trace estimate in [`NoiseLevel::of_capture`].
pub const TRACE_PROBES: usize = 2;

/// H f from the problem's Hᵀ (a scatter over its rows, fixed order).
fn forward(p: &Problem, f: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; p.ht.cols];
    for (a, &fa) in f.iter().enumerate() {
        if fa == 0.0 {
            continue;
        }
        for e in p.ht.row_range(a) {
            out[p.ht.indices[e] as usize] += f64::from(p.ht.data[e]) * fa;
        }
    }
    out
}

/// The least-squares solution of G f = `b` by CG from 0 to a relative residual of 10⁻¹⁰ (at
/// most 2000 iterations); `jacobi` preconditions it with diag G. Plain CG stays in the range
/// of G and keeps the directions H hardly measures small (ADMM-TV starts from this fit, so
/// `f_LS` is solved plainly); the trace probes need only ‖P n‖², a projection whatever the
/// conditioning, and take the Jacobi preconditioner, which cuts the iterations where the
/// columns differ in scale by orders of magnitude (a colour H: 700-900 instead of 2000).
fn least_squares(p: &Problem, b: &[f64], jacobi: bool) -> Vec<f64> {
    let inv_diag: Option<Vec<f64>> = jacobi.then(|| {
        p.gram_diag
            .iter()
            .map(|&d| if d > 0.0 { 1.0 / d } else { 1.0 })
            .collect()
    });
    let mut f = vec![0.0; b.len()];
    super::cg::pcg(
        |x, y| p.gram_mul(x, y),
        inv_diag.as_deref(),
        b,
        &mut f,
        2000,
        1e-10,
        &p.cancel,
    );
    f
}

/// ‖H f − g‖² from Hᵀg, ‖g‖² and G (one Gram product).
pub fn residual_norm2(p: &Problem, htg: &[f64], g_norm2: f64, f: &[f64]) -> f64 {
    let mut gf = vec![0.0; f.len()];
    p.gram_mul(f, &mut gf);
    g_norm2 - 2.0 * dot(f, htg) + dot(f, &gf)
}

/// CGM from f = 0 stopped by the discrepancy principle, at most `max_iters` iterations.
pub fn cg_discrepancy(p: &Problem, htg: &[f64], level: &NoiseLevel, max_iters: usize) -> CgResult {
    let mut f = vec![0.0; htg.len()];
    let (iterations, relative_residual) = pcg_until(
        |x, y| p.gram_mul(x, y),
        None,
        htg,
        &mut f,
        max_iters,
        0.0,
        &p.cancel,
        |x, r| level.g_norm2 - dot(x, htg) - dot(x, r) <= level.budget,
    );
    CgResult {
        f,
        iterations,
        relative_residual,
    }
}

/// ADMM-TV with τ from the discrepancy principle.
#[derive(Clone, Debug)]
pub struct TauChoice {
    /// The reconstruction at the chosen τ.
    pub result: AdmmResult,
    /// The chosen τ_rel.
    pub tau_rel: f64,
    /// Its residual ‖H f − g‖².
    pub residual: f64,
    /// False if the budget lies outside the residuals at [`TAU_REL_MIN`] and [`TAU_REL_MAX`]
    /// (the nearer end is returned).
    pub reached: bool,
    /// ADMM-TV solves done.
    pub solves: usize,
}

/// ADMM-TV (settings `set`, its `tau_rel` ignored; started from `level.f_ls` when known) with τ_rel chosen so that ‖H f − g‖² meets
/// `level.budget`: bisection in log τ_rel on [`TAU_REL_MIN`, `TAU_REL_MAX`].
pub fn admm_tv_discrepancy(
    p: &Problem,
    htg: &[f64],
    level: &NoiseLevel,
    set: &AdmmSettings,
) -> TauChoice {
    let (result, choice) = choose_tau(level.budget, |tau_rel| {
        let r = admm_tv_from(
            p,
            htg,
            &AdmmSettings { tau_rel, ..*set },
            level.f_ls.as_deref(),
        );
        let res = residual_norm2(p, htg, level.g_norm2, &r.f);
        (r, res)
    });
    TauChoice {
        result,
        tau_rel: choice.tau_rel,
        residual: choice.residual,
        reached: choice.reached,
        solves: choice.solves,
    }
}

/// Where the τ search of [`choose_tau`] ended.
#[derive(Clone, Copy, Debug)]
pub struct TauSearch {
    /// The chosen τ_rel.
    pub tau_rel: f64,
    /// Its residual ‖H f − g‖².
    pub residual: f64,
    /// False if the budget lies outside the residuals at the bracket's ends.
    pub reached: bool,
    /// Solves done.
    pub solves: usize,
}

/// Morozov's rule for any solver whose residual grows with τ: `solve(τ_rel)` returns a
/// reconstruction and its residual ‖H f − g‖²; the largest τ_rel (within the bisection's
/// resolution, in log τ_rel on [`TAU_REL_MIN`, `TAU_REL_MAX`]) whose residual stays within
/// `budget` is chosen. A budget below the residual at [`TAU_REL_MIN`] or above the one at
/// [`TAU_REL_MAX`] returns that end, `reached = false`.
pub fn choose_tau<R>(budget: f64, mut solve: impl FnMut(f64) -> (R, f64)) -> (R, TauSearch) {
    let end = |r: R, tau_rel: f64, residual: f64, solves: usize| {
        (
            r,
            TauSearch {
                tau_rel,
                residual,
                reached: false,
                solves,
            },
        )
    };
    let (mut lo, mut hi) = (TAU_REL_MIN.ln(), TAU_REL_MAX.ln());
    let (r_lo, res_lo) = solve(TAU_REL_MIN);
    if res_lo >= budget {
        return end(r_lo, TAU_REL_MIN, res_lo, 1);
    }
    let (r_hi, res_hi) = solve(TAU_REL_MAX);
    if res_hi <= budget {
        return end(r_hi, TAU_REL_MAX, res_hi, 2);
    }
    // Keep the end whose residual is below the budget (the less regularised side).
    let mut best = (r_lo, res_lo, TAU_REL_MIN);
    for _ in 0..TAU_BISECTIONS {
        let mid = 0.5 * (lo + hi);
        let (r, res) = solve(mid.exp());
        if res <= budget {
            lo = mid;
            best = (r, res, mid.exp());
        } else {
            hi = mid;
        }
    }
    (
        best.0,
        TauSearch {
            tau_rel: best.2,
            residual: best.1,
            reached: true,
            solves: 2 + TAU_BISECTIONS,
        },
    )
}

/// CGM's iteration cap when the discrepancy principle stops it (the demo's table and every
/// entry point's default; the principle stops it far earlier at the paper's noise).
pub const CG_MAX_ITERS: usize = 100;

/// The sensor a capture was measured with, as the discrepancy principle needs it.
#[derive(Clone, Copy, Debug)]
pub struct Sensor<'a> {
    /// The sensor model with its exposure.
    pub noise: &'a SensorNoise,
    /// The black level each capture value sits at (capture units, the sensor's dark offset
    /// removed): the matrix's offset, or a measured dark frame's.
    pub offset: &'a [f32],
    /// Whether a measured (noisy) dark frame was subtracted from the capture (its noise then
    /// counts too).
    pub dark_subtracted: bool,
}

/// Reconstructs the object from `g` (black level already subtracted) for a set-up `problem`
/// with the regularisation chosen by the discrepancy principle on `sensor`: CGM stopped at
/// the budget (at most `opts.iters`, default [`CG_MAX_ITERS`]), ADMM-TV with τ_rel chosen by
/// [`choose_tau`] (`opts.iters` iterations per solve, default 50; `opts.tau_rel` ignored; a
/// colour object of `planes` planes by the joint solver with TV per plane). What the demo's
/// table, `stscam reconstruct` and the Python module's `reconstruct` and `Operator` call.
pub fn solve_discrepancy(
    p: &Problem,
    planes: usize,
    g: &[f64],
    opts: &super::SolveOptions,
    sensor: &Sensor,
) -> super::Solution {
    let level = NoiseLevel::of_capture(p, g, sensor.offset, sensor.dark_subtracted, sensor.noise);
    let mut sol = solve_at_level(p, planes, g, opts, &level);
    sol.info["rule"]["dark_subtracted"] = sensor.dark_subtracted.into();
    sol
}

/// [`solve_discrepancy`] with the noise level already known (one level serves every method
/// and setting of one capture and H: the demos compute it once per capture).
pub fn solve_at_level(
    p: &Problem,
    planes: usize,
    g: &[f64],
    opts: &super::SolveOptions,
    level: &NoiseLevel,
) -> super::Solution {
    let htg = p.back_project(g);
    let rule = serde_json::json!({
        "name": "discrepancy principle",
        "budget": level.budget,
        "g_norm2": level.g_norm2,
        "note": "the residual |Hf - g|^2 meets the sensor model's noise in the range of H (recon::discrepancy)",
    });
    match opts.method {
        super::Method::Cg => {
            let cap = opts.iters.unwrap_or(CG_MAX_ITERS);
            let r = cg_discrepancy(p, &htg, level, cap);
            let residual = residual_norm2(p, &htg, level.g_norm2, &r.f);
            let info = serde_json::json!({
                "method": "cg", "rule": rule, "iterations": r.iterations, "max_iters": cap,
                "reached": r.iterations < cap, "residual_norm2": residual,
                "relative_residual": r.relative_residual,
            });
            super::Solution { f: r.f, info }
        }
        super::Method::AdmmTv if planes <= 1 => {
            let set = AdmmSettings {
                iters: opts.iters.unwrap_or(50),
                tv: opts.tv,
                ..Default::default()
            };
            let c = admm_tv_discrepancy(p, &htg, level, &set);
            let info = serde_json::json!({
                "method": "admm-tv", "rule": rule, "iterations": set.iters, "tau_rel": c.tau_rel,
                "tau": c.result.tau, "rho": c.result.rho, "tv": set.tv, "inner_cg_iterations": set.inner_iters,
                "reached": c.reached, "solves": c.solves, "residual_norm2": c.residual,
                "tau_rel_bracket": [TAU_REL_MIN, TAU_REL_MAX],
            });
            super::Solution {
                f: c.result.f,
                info,
            }
        }
        super::Method::AdmmTv => {
            let set = super::joint::JointSettings {
                iters: opts.iters.unwrap_or(50),
                mu_rel: 0.0,
                tv: opts.tv,
                ..Default::default()
            };
            let (r, c) = choose_tau(level.budget, |tau_rel| {
                let r = super::joint::joint_admm_tv(
                    p,
                    planes,
                    &htg,
                    &super::joint::JointSettings { tau_rel, ..set },
                );
                let f = r.planes.concat();
                let res = residual_norm2(p, &htg, level.g_norm2, &f);
                ((r, f), res)
            });
            let info = serde_json::json!({
                "method": "admm-tv", "rule": rule, "planes": planes, "iterations": set.iters,
                "tau_rel": c.tau_rel, "tau": r.0.tau, "rho": r.0.rho, "tv": set.tv,
                "inner_cg_iterations": set.inner_iters, "reached": c.reached, "solves": c.solves,
                "residual_norm2": c.residual, "tau_rel_bracket": [TAU_REL_MIN, TAU_REL_MAX],
                "prior": "TV per plane, non-negative (joint ADMM, no cross-plane term)",
            });
            super::Solution { f: r.1, info }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cg::{CgSettings, cg_normal};

    /// A 1-D blur (three taps) of a 16×16 object, rows = pixels.
    fn blur_problem() -> (crate::sparse::CsrMatrix, usize) {
        let (w, h) = (16usize, 16usize);
        let n = w * h;
        let mut m = crate::sparse::CsrMatrix::zeros(n, n);
        m.indptr.clear();
        m.indptr.push(0);
        for r in 0..n {
            for (d, v) in [(-1i64, 0.3f32), (0, 0.5), (1, 0.3)] {
                let c = r as i64 + d;
                if (0..n as i64).contains(&c) {
                    m.indices.push(c as u32);
                    m.data.push(v);
                }
            }
            m.indptr.push(m.indices.len() as u64);
        }
        (m, w)
    }

    #[test]
    fn cg_residual_from_its_vectors_matches_a_direct_product() {
        let (m, w) = blur_problem();
        let p = Problem::new(&m, w, w);
        let g: Vec<f64> = (0..m.rows)
            .map(|i| NoiseRng::new(&[4, i as u64]).normal())
            .collect();
        let htg = p.back_project(&g);
        let g2 = dot(&g, &g);
        for k in [1, 3, 7] {
            let f = cg_normal(&p, &htg, &CgSettings { iters: k, tol: 0.0 }).f;
            let hf = m.mul_vec(&f);
            let direct: f64 = hf.iter().zip(&g).map(|(a, b)| (a - b) * (a - b)).sum();
            assert!((residual_norm2(&p, &htg, g2, &f) - direct).abs() < 1e-9 * g2);
            // The stopping rule at a budget just above the k-iteration residual stops at k
            // (at most: a residual a hair larger earlier is possible only if equal).
            let level = NoiseLevel {
                g_norm2: g2,
                budget: direct * (1.0 + 1e-9),
                f_ls: None,
            };
            let r = cg_discrepancy(&p, &htg, &level, 100);
            assert_eq!(r.iterations, k, "budget of iteration {k}");
        }
    }

    #[test]
    fn tau_meets_the_budget_and_grows_with_it() {
        let (m, w) = blur_problem();
        let p = Problem::new(&m, w, w);
        let f: Vec<f64> = (0..w * w)
            .map(|i| if (i % w) < 8 { 0.2 } else { 0.9 })
            .collect();
        let sigma = 0.05;
        let g: Vec<f64> = m
            .mul_vec(&f)
            .iter()
            .enumerate()
            .map(|(i, v)| v + sigma * NoiseRng::new(&[8, i as u64]).normal())
            .collect();
        let htg = p.back_project(&g);
        let g2 = dot(&g, &g);
        let set = AdmmSettings::default();
        let mut taus = Vec::new();
        for scale in [0.5, 0.75, 1.0] {
            let level = NoiseLevel {
                g_norm2: g2,
                budget: scale * sigma * sigma * g.len() as f64,
                f_ls: None,
            };
            let c = admm_tv_discrepancy(&p, &htg, &level, &set);
            assert!(c.reached, "budget x{scale}");
            // Within the budget, and not far below it (the bracket is 15 % wide in τ).
            assert!(c.residual <= level.budget && c.residual > 0.8 * level.budget);
            taus.push(c.tau_rel);
        }
        assert!(taus[0] < taus[1] && taus[1] < taus[2], "{taus:?}");
        // A budget above any residual is reported as not reached.
        let c = admm_tv_discrepancy(
            &p,
            &htg,
            &NoiseLevel {
                g_norm2: g2,
                budget: 10.0 * g2,
                f_ls: None,
            },
            &set,
        );
        assert!(!c.reached && c.tau_rel == TAU_REL_MAX);
    }
}
