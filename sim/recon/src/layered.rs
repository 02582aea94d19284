//! Reconstruction with a depth stack (`stscam reconstruct --matrix H_stack.npz`), the glue of
//! `depth.rs` and `joint.rs` over a [`LoadedStack`]:
//! - [`StackMethod::Joint`]: the layered model g = Σ_d (H_d f_d + o_d) + n solved for every plane
//!   at once (`joint.rs`), g minus the layered offset Σ_d o_d;
//! - [`StackMethod::Depth`]: one planar object at an unknown depth: the depth whose H leaves the
//!   smallest residual after a short CGM (`depth.rs`), g minus each depth's own offset o_d, then
//!   ADMM-TV with that depth's H (the plain `reconstruct`).

use super::admm::{AdmmSettings, TvKind, admm_tv};
use super::depth::{DepthEstimate, estimate_depth};
use super::joint::{JointSettings, joint_admm_tv};
use super::{Problem, setup_bytes_bound, setup_bytes_bound_blocks};
use crate::cancel::Token;
use crate::sparse::CsrMatrix;
use crate::stack::LoadedStack;

/// How a stack is used (`reconstruct --method joint|depth`, Python's `method=`: one definition
/// for clap and the Python module; the first paragraph of each variant's comment is its
/// `--help` line).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum StackMethod {
    /// Depth stack: joint multi-depth ADMM-TV with a sparsity prior across depth.
    ///
    /// The layered model, every plane at once (layered scenes).
    Joint,
    /// Depth stack: estimate the depth of one planar object, then ADMM-TV at that depth.
    ///
    /// The depth whose H leaves the smallest residual after a short CGM.
    Depth,
}

/// Options of [`solve_stack`].
#[derive(Clone, Debug)]
pub struct StackOptions {
    /// Joint or depth estimation.
    pub method: StackMethod,
    /// ADMM iterations (default: 100 joint, 50 at the estimated depth).
    pub iters: Option<usize>,
    /// τ relative to ‖Hᵀg‖_∞.
    pub tau_rel: f64,
    /// Joint: μ relative to ‖Hᵀg‖_∞ (group sparsity across depth).
    pub mu_rel: f64,
    /// TV kind.
    pub tv: TvKind,
    /// Depth: CGM iterations of the criterion.
    pub depth_cg_iters: usize,
    /// Stops the solves once set (the default is never set).
    pub cancel: Token,
}

impl Default for StackOptions {
    fn default() -> Self {
        StackOptions {
            method: StackMethod::Joint,
            iters: None,
            tau_rel: super::admm::DEFAULT_TAU_REL,
            mu_rel: super::joint::DEFAULT_MU_REL,
            tv: TvKind::Iso,
            depth_cg_iters: super::depth::DEFAULT_DEPTH_CG_ITERS,
            cancel: Token::default(),
        }
    }
}

/// The outcome of [`solve_stack`].
#[derive(Clone, Debug)]
pub struct StackSolution {
    /// (depth in mm, plane): every depth (joint) or the estimated one (depth).
    pub planes: Vec<(f64, Vec<f64>)>,
    /// The depth estimate (depth method).
    pub estimate: Option<DepthEstimate>,
    /// Method, parameters and residuals (`recon.json`'s `solver`).
    pub info: serde_json::Value,
}

/// An upper bound on the memory [`solve_stack`] needs, in bytes (before any set-up).
pub fn stack_setup_bytes(ls: &LoadedStack, method: StackMethod, threads: usize) -> u128 {
    match method {
        StackMethod::Joint => {
            // The block matrix is rebuilt from the blocks (its size again) and set up.
            let refs: Vec<&CsrMatrix> = ls.blocks.iter().collect();
            let nnz: usize = refs.iter().map(|b| b.nnz()).sum();
            setup_bytes_bound_blocks(&refs, threads).saturating_add(8 * nnz as u128)
        }
        StackMethod::Depth => ls
            .blocks
            .iter()
            .map(|b| setup_bytes_bound(b, threads))
            .max()
            .unwrap_or(0),
    }
}

/// Subtracts `offset` (if any) from `capture`.
fn minus(capture: &[f64], offset: Option<&Vec<f32>>) -> Vec<f64> {
    match offset {
        Some(o) => capture
            .iter()
            .zip(o)
            .map(|(g, &o)| g - f64::from(o))
            .collect(),
        None => capture.to_vec(),
    }
}

/// Reconstructs from `capture` (raw: offsets are subtracted here, as the method needs) with the
/// stack `ls`. `capture` must have one value per row of the stack's H.
pub fn solve_stack(
    ls: &LoadedStack,
    capture: &[f64],
    opts: &StackOptions,
) -> Result<StackSolution, String> {
    let (w, h) = ls.object;
    let rows = ls.blocks.first().map_or(0, |b| b.rows);
    if capture.len() != rows {
        return Err(format!(
            "the capture has {} values but the stack's H has {rows} rows",
            capture.len()
        ));
    }
    let n = ls.depths_mm.len();
    match opts.method {
        StackMethod::Joint => {
            let g = minus(capture, ls.joint_offset.as_ref());
            let refs: Vec<&CsrMatrix> = ls.blocks.iter().collect();
            let block = CsrMatrix::hstack(&refs).ok_or("the depth blocks differ in rows")?;
            let p = Problem::with_cancel(&block, w, h * n, opts.cancel.clone());
            drop(block);
            let set = JointSettings {
                iters: opts.iters.unwrap_or(JointSettings::default().iters),
                tau_rel: opts.tau_rel,
                mu_rel: opts.mu_rel,
                tv: opts.tv,
                ..JointSettings::default()
            };
            let r = joint_admm_tv(&p, n, &p.back_project(&g), &set);
            let info = serde_json::json!({
                "method": "joint", "depths_mm": ls.depths_mm, "iterations": set.iters,
                "tau_rel": set.tau_rel, "tau": r.tau, "mu_rel": set.mu_rel, "mu": r.mu,
                "rho": r.rho, "tv": set.tv, "inner_cg_iterations": set.inner_iters,
                "offset": "layered (sum of the per-depth offsets)",
            });
            Ok(StackSolution {
                planes: ls.depths_mm.iter().copied().zip(r.planes).collect(),
                estimate: None,
                info,
            })
        }
        StackMethod::Depth => {
            let refs: Vec<&CsrMatrix> = ls.blocks.iter().collect();
            let offsets: Vec<Option<&[f32]>> = ls.offsets.iter().map(|o| o.as_deref()).collect();
            let est = estimate_depth(
                &refs,
                &offsets,
                (w, h),
                capture,
                &ls.depths_mm,
                opts.depth_cg_iters,
                &opts.cancel,
            );
            let p = Problem::with_cancel(&ls.blocks[est.best], w, h, opts.cancel.clone());
            let g = minus(capture, ls.offsets[est.best].as_ref());
            let set = AdmmSettings {
                iters: opts.iters.unwrap_or(AdmmSettings::default().iters),
                tau_rel: opts.tau_rel,
                tv: opts.tv,
                ..AdmmSettings::default()
            };
            let r = admm_tv(&p, &p.back_project(&g), &set);
            let info = serde_json::json!({
                "method": "depth", "depth_estimate": est,
                "criterion": "smallest relative residual ||H_d f - g_d||^2/||g_d||^2 after a short CGM per depth",
                "cg_iterations": opts.depth_cg_iters,
                "reconstruction": {"method": "admm-tv", "iterations": set.iters, "tau_rel": set.tau_rel, "tau": r.tau, "rho": r.rho, "tv": set.tv},
            });
            Ok(StackSolution {
                planes: vec![(est.depth_mm, r.f)],
                estimate: Some(est),
                info,
            })
        }
    }
}
