//! The analog reference ([`super::Estimator::UniformAnalog`]): what a plain spectral path
//! tracer does, kept to show what stscam's estimator gains. Wavelengths are uniform over the
//! band (the sample's factor is then cos⁴θ·S(λ)·band), and each path has one analog outcome:
//! its polarisation state and its branch (or its death) are drawn with their probabilities,
//! the branch weights being the outcome probabilities (they sum to ≤ 1). The path stops at the
//! chosen branch (Russian roulette at every interaction). Unbiased, with far more noise. This is
//! the analog (unweighted) simulation of Monte Carlo transport: J. Spanier & E. M. Gelbard,
//! Monte Carlo Principles and Neutron Transport Problems (Addison-Wesley 1969), ch. 2; its
//! estimates are the same in expectation as the weighted (split) estimator of
//! [`super::display`].

use std::ops::ControlFlow;

use super::RenderStats;
use super::samples::{CameraSample, PixelEstimator, PixelSums, SampleConsumer};
use crate::sampler::PathRng;
use crate::system::System;
use crate::trace::Branch;
use crate::world::World;

/// Tag of the analog outcome's random numbers.
const ANALOG_TAG: u64 = 0x00A4_A106;

/// The analog choice of a path's outcome: the branch whose cumulative weight in polarisation
/// state `pol` first exceeds the uniform number `u`, or none (the path dies).
#[derive(Default)]
struct Outcome {
    pol: usize,
    u: f64,
    cum: f64,
    chosen: Option<Branch>,
}

impl Outcome {
    /// Starts a path's draw in state `pol` with uniform number `u`.
    fn new(pol: usize, u: f64) -> Self {
        Outcome {
            pol,
            u,
            cum: 0.0,
            chosen: None,
        }
    }

    /// Offers the next branch; `Break` once the path's branch is chosen.
    #[inline]
    fn offer(&mut self, b: &Branch) -> ControlFlow<()> {
        self.cum += b.weight[self.pol];
        debug_assert!(self.cum <= 1.0 + 1e-9, "branch weights sum to {}", self.cum);
        if self.u < self.cum {
            self.chosen = Some(*b);
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    }
}

/// The analog estimator of the display seen through the camera: the display radiance the
/// path reaches, with weight 1.
pub(super) struct Display<'a> {
    sys: &'a System,
    seed: u64,
    sums: PixelSums<'a>,
    outcome: Outcome,
}

impl<'a> Display<'a> {
    pub(super) fn new(sys: &'a System, set: &super::RenderSettings) -> Self {
        Display {
            sys,
            seed: set.seed,
            sums: PixelSums::new(sys, set),
            outcome: Outcome::default(),
        }
    }
}

impl SampleConsumer for Display<'_> {
    fn begin(&mut self, _s: &CameraSample, i: u64) {
        let h = crate::sampler::hash(&[self.seed, self.sums.pixel, i, ANALOG_TAG]);
        let (u_pol, u_branch) = (
            crate::sampler::to_unit(h),
            crate::sampler::to_unit(crate::sampler::mix64(h)),
        );
        let pol = usize::from(u_pol >= self.sys.display.polarization_weights[0]);
        self.outcome = Outcome::new(pol, u_branch);
    }

    fn branch(&mut self, _s: &CameraSample, b: &Branch) -> ControlFlow<()> {
        self.outcome.offer(b)
    }

    fn end(&mut self, s: &CameraSample, _i: u64, stats: &mut RenderStats) {
        let disp = &self.sys.display;
        let value = self.outcome.chosen.map_or(0.0, |b| {
            let w = disp.primary_weights(s.lambda_nm);
            disp.radiance_weighted_at(b.object_point_mm, &w)
        });
        self.sums.add(s.factor * value, s.lambda_nm, stats);
    }
}

impl<'a> PixelEstimator<'a> for Display<'a> {
    fn sums(&mut self) -> &mut PixelSums<'a> {
        &mut self.sums
    }
}

/// The analog estimator of a 3-D scene: one polarisation state (TE or TM, even odds) and one
/// branch (or none) chosen with their probabilities, and only that branch traced on the user
/// side. Unpolarised light then has the right expectation; the display seen directly is
/// weighted by 2·f_state for its polarisation.
pub(super) struct Scene<'a> {
    sys: &'a System,
    world: &'a World,
    seed: u64,
    sums: PixelSums<'a>,
    outcome: Outcome,
    rng: PathRng,
}

impl<'a> Scene<'a> {
    pub(super) fn new(sys: &'a System, set: &super::RenderSettings, world: &'a World) -> Self {
        Scene {
            sys,
            world,
            seed: set.seed,
            sums: PixelSums::new(sys, set),
            outcome: Outcome::default(),
            rng: PathRng::new(&[]),
        }
    }
}

impl SampleConsumer for Scene<'_> {
    fn begin(&mut self, _s: &CameraSample, i: u64) {
        self.rng = PathRng::new(&[self.seed, self.sums.pixel, i, ANALOG_TAG]);
        let (u_pol, u_branch) = (self.rng.uniform(), self.rng.uniform());
        self.outcome = Outcome::new(usize::from(u_pol >= 0.5), u_branch);
    }

    fn branch(&mut self, _s: &CameraSample, b: &Branch) -> ControlFlow<()> {
        self.outcome.offer(b)
    }

    fn end(&mut self, s: &CameraSample, _i: u64, stats: &mut RenderStats) {
        let value = match self.outcome.chosen {
            None => 0.0,
            Some(b) => {
                let l = super::user_side::trace_exit(
                    self.sys,
                    self.world,
                    s.ray.dir,
                    s.lambda_nm,
                    b.exit_point_mm,
                    &mut self.rng,
                    stats,
                    None,
                );
                let pol = self.outcome.pol;
                2.0 * self.sys.display.polarization_weights[pol] * l.display + l.other
            }
        };
        self.sums
            .add(s.ray.cos4 * value / s.pdf, s.lambda_nm, stats);
    }
}

impl<'a> PixelEstimator<'a> for Scene<'a> {
    fn sums(&mut self) -> &mut PixelSums<'a> {
        &mut self.sums
    }
}
