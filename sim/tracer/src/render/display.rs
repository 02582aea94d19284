//! The display seen through the camera: the pixel estimators of scenes without a 3-D user side.
//!
//! A sample's value is its factor cos⁴θ·S(λ)/p(λ) times Σ_branches w_b·L_rel(x_b), with w_b the
//! branch's weight averaged over the display's polarisation and L_rel the display's relative
//! radiance at the branch's object point x_b (for a colour display, the primaries' shares of
//! white at λ weighting each primary's image). Every replica is summed: the branches are
//! deterministic splits of the path (replica weights: docs/physics.md §5; why splitting rather
//! than choosing: docs/design.md, "Estimator decisions").

use std::ops::ControlFlow;

use super::RenderStats;
use super::samples::{CameraSample, PixelEstimator, PixelSums, SampleConsumer, display_weight};
use crate::system::System;
use crate::trace::Branch;

/// A monochrome display (or one colour display seen as a whole: see [`Primaries`]).
pub(super) struct Monochrome<'a> {
    sys: &'a System,
    sums: PixelSums<'a>,
    radiance: f64,
}

impl<'a> Monochrome<'a> {
    pub(super) fn new(sys: &'a System, set: &super::RenderSettings) -> Self {
        Monochrome {
            sys,
            sums: PixelSums::new(sys, set),
            radiance: 0.0,
        }
    }
}

impl SampleConsumer for Monochrome<'_> {
    #[inline(always)]
    fn begin(&mut self, _s: &CameraSample, _i: u64) {
        self.radiance = 0.0;
    }

    #[inline(always)]
    fn branch(&mut self, _s: &CameraSample, b: &Branch) -> ControlFlow<()> {
        let wt = display_weight(self.sys, b);
        if wt > 0.0 {
            self.radiance += wt * self.sys.display.radiance_at(b.object_point_mm);
        }
        ControlFlow::Continue(())
    }

    #[inline(always)]
    fn end(&mut self, s: &CameraSample, _i: u64, stats: &mut RenderStats) {
        self.sums.add(s.factor * self.radiance, s.lambda_nm, stats);
    }
}

/// A colour display: the shares of white of its primaries at the sample's wavelength, once
/// per sample, weight the primaries' images.
pub(super) struct Primaries<'a> {
    inner: Monochrome<'a>,
    shares: [f64; 3],
}

impl<'a> Primaries<'a> {
    pub(super) fn new(sys: &'a System, set: &super::RenderSettings) -> Self {
        Primaries {
            inner: Monochrome::new(sys, set),
            shares: [0.0; 3],
        }
    }
}

impl SampleConsumer for Primaries<'_> {
    #[inline(always)]
    fn begin(&mut self, s: &CameraSample, i: u64) {
        self.inner.begin(s, i);
        self.shares = self.inner.sys.display.primary_weights(s.lambda_nm);
    }

    #[inline(always)]
    fn branch(&mut self, _s: &CameraSample, b: &Branch) -> ControlFlow<()> {
        let sys = self.inner.sys;
        let wt = display_weight(sys, b);
        if wt > 0.0 {
            self.inner.radiance += wt
                * sys
                    .display
                    .radiance_weighted_at(b.object_point_mm, &self.shares);
        }
        ControlFlow::Continue(())
    }

    #[inline(always)]
    fn end(&mut self, s: &CameraSample, i: u64, stats: &mut RenderStats) {
        self.inner.end(s, i, stats);
    }
}

impl<'a> PixelEstimator<'a> for Monochrome<'a> {
    #[inline]
    fn sums(&mut self) -> &mut PixelSums<'a> {
        &mut self.sums
    }
}

impl<'a> PixelEstimator<'a> for Primaries<'a> {
    #[inline]
    fn sums(&mut self) -> &mut PixelSums<'a> {
        self.inner.sums()
    }
}
