//! Depth of a planar object from one capture, over the depths of an H stack.
//!
//! Criterion: for every depth d, a short CGM (`cg_iters` iterations of CG on H_dᵀH_d f = H_dᵀg_d
//! from f = 0, g_d = capture − o_d) and its residual R_d = ‖H_d f_d − g_d‖²; the estimate is
//! the depth with the smallest relative residual r_d = R_d/‖g_d‖² (the H that explains the
//! capture best with the same small number of degrees of freedom spent). A planar object at
//! depth D is explained well only by an H whose replica spacing on the sensor (∝ pitch/D) and
//! magnification (∝ 1/D) match; a wrong depth leaves the replicas' misregistration in the
//! residual.
//!
//! Reported with it:
//! - a refined depth: the vertex of the parabola through the residuals of the best depth and its
//!   two neighbours (in mm; the grid depth itself at either end of the stack);
//! - a confidence: the posterior probability of the chosen depth under a Gaussian noise model
//!   with uniform prior over the grid, p_d ∝ exp(−(R_d − R_best)/(2σ̂²)), σ̂² = R_best/(M − K)
//!   (M capture values, K object pixels). It ignores model error (CG semi-convergence, a depth
//!   between grid planes), so read it together with the residual ratio r_second/r_best − 1.
//!
//! Assumption: one planar object at one depth, every depth's H of the same object shape.

use super::{Problem, cg::CgSettings, cg::cg_normal, dot};

/// Default CG iterations of the depth criterion.
pub const DEFAULT_DEPTH_CG_ITERS: usize = 10;

/// A depth estimate.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DepthEstimate {
    /// The grid depths, mm.
    pub depths_mm: Vec<f64>,
    /// Relative residual ‖H_d f_d − g_d‖²/‖g_d‖² per depth.
    pub relative_residuals: Vec<f64>,
    /// Index of the chosen depth.
    pub best: usize,
    /// The chosen grid depth, mm.
    pub depth_mm: f64,
    /// The parabola vertex through the best residual and its neighbours, mm.
    pub refined_depth_mm: f64,
    /// Posterior probability of the chosen depth (module header).
    pub confidence: f64,
    /// Second-smallest relative residual over the smallest, minus 1 (0: two depths tie).
    pub residual_margin: f64,
    /// The CGM reconstruction at the chosen depth.
    #[serde(skip)]
    pub f: Vec<f64>,
}

/// Estimates the depth of a planar object: `problems[d]` is depth `depths_mm[d]`'s problem,
/// `captures[d]` its g_d (capture minus that depth's offset), `cg_iters` the CGM length.
pub fn estimate_depth(
    problems: &[Problem],
    captures: &[Vec<f64>],
    depths_mm: &[f64],
    cg_iters: usize,
) -> DepthEstimate {
    let set = CgSettings {
        iters: cg_iters,
        tol: 0.0,
    };
    let mut residuals = Vec::with_capacity(problems.len());
    let mut relative = Vec::with_capacity(problems.len());
    let mut recons = Vec::with_capacity(problems.len());
    for (p, g) in problems.iter().zip(captures) {
        let htg = p.back_project(g);
        let g2 = dot(g, g);
        let f = cg_normal(p, &htg, &set).f;
        let mut gf = vec![0.0; f.len()];
        p.gram_mul(&f, &mut gf);
        // ‖Hf − g‖² = fᵀGf − 2fᵀHᵀg + ‖g‖² (never below 0 but for rounding).
        let r = (dot(&f, &gf) - 2.0 * dot(&f, &htg) + g2).max(0.0);
        residuals.push(r);
        relative.push(if g2 > 0.0 { r / g2 } else { 0.0 });
        recons.push(f);
    }
    let best = (0..relative.len())
        .min_by(|&a, &b| relative[a].total_cmp(&relative[b]))
        .unwrap_or(0);
    let m = captures.first().map_or(0, Vec::len);
    let k = problems.first().map_or(0, Problem::n);
    let sigma2 = residuals.get(best).copied().unwrap_or(0.0) / m.saturating_sub(k).max(1) as f64;
    let weights: Vec<f64> = residuals
        .iter()
        .map(|r| {
            if sigma2 > 0.0 {
                (-(r - residuals[best]) / (2.0 * sigma2)).exp()
            } else {
                f64::from(u8::from(*r == residuals[best]))
            }
        })
        .collect();
    let wsum: f64 = weights.iter().sum();
    let second = relative
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != best)
        .map(|(_, &r)| r)
        .fold(f64::INFINITY, f64::min);
    let refined = if best > 0 && best + 1 < relative.len() {
        parabola_vertex(
            [depths_mm[best - 1], depths_mm[best], depths_mm[best + 1]],
            [relative[best - 1], relative[best], relative[best + 1]],
        )
    } else {
        depths_mm.get(best).copied().unwrap_or(f64::NAN)
    };
    DepthEstimate {
        depths_mm: depths_mm.to_vec(),
        relative_residuals: relative.clone(),
        best,
        depth_mm: depths_mm.get(best).copied().unwrap_or(f64::NAN),
        refined_depth_mm: refined,
        confidence: if wsum > 0.0 { weights[best] / wsum } else { 0.0 },
        residual_margin: if relative[best] > 0.0 {
            second / relative[best] - 1.0
        } else {
            f64::INFINITY
        },
        f: recons.swap_remove(best),
    }
}

/// The vertex of the parabola through (x_i, y_i), clamped to [x₀, x₂] (x₁ if the points are
/// not convex).
fn parabola_vertex(x: [f64; 3], y: [f64; 3]) -> f64 {
    // Divided differences: y = y₀ + a(x − x₀) + b(x − x₀)(x − x₁).
    let a = (y[1] - y[0]) / (x[1] - x[0]);
    let b = ((y[2] - y[1]) / (x[2] - x[1]) - a) / (x[2] - x[0]);
    if b > 0.0 {
        (0.5 * (x[0] + x[1]) - 0.5 * a / b).clamp(x[0], x[2])
    } else {
        x[1]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vertex_of_a_known_parabola() {
        // y = (x − 470)² + 3 on an uneven grid.
        let x = [400.0, 450.0, 550.0];
        let y = x.map(|v: f64| (v - 470.0).powi(2) + 3.0);
        assert!((parabola_vertex(x, y) - 470.0).abs() < 1e-9);
        // Not convex: the middle point.
        assert_eq!(parabola_vertex(x, [1.0, 2.0, 1.0]), 450.0);
    }
}
