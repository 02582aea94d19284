//! The holographic waveguide device: a glass plate with two vHOE rectangles and a cover.
//!
//! Geometry (docs/design.md "Frame and units"): the plate fills 0 ≤ z ≤ w; the bottom vHOE is a
//! rectangle on the back face (z = w) centred at the origin; the top vHOE is a rectangle on the
//! front face (z = 0) above it, `gap` mm higher than the bottom vHOE's top edge; the optional
//! cover lies on the user side of the top vHOE. Both vHOEs carry the same film with the same
//! recorded gratings (one, or several multiplexed: `optics::multiplex`), so their grating
//! vectors match and the exit ray is parallel to the entry ray (the periscope). Glass dispersion and Beer–Lambert absorption come from
//! `optics::glass`.

use glam::DVec2;

use crate::optics::glass::Glass;
use crate::optics::multiplex::GratingSet;

/// An axis-aligned rectangle on one face of the plate (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rect {
    /// Minimum corner (x, y).
    pub min: DVec2,
    /// Maximum corner (x, y).
    pub max: DVec2,
}

impl Rect {
    /// Rectangle from its centre and size.
    pub fn centered(center: DVec2, size: DVec2) -> Self {
        Rect {
            min: center - 0.5 * size,
            max: center + 0.5 * size,
        }
    }

    /// Whether `p` lies inside (closed on min, open on max).
    #[inline]
    pub fn contains(&self, p: DVec2) -> bool {
        p.x >= self.min.x && p.y >= self.min.y && p.x < self.max.x && p.y < self.max.y
    }

    /// Centre point.
    pub fn center(&self) -> DVec2 {
        0.5 * (self.min + self.max)
    }

    /// Whether a point moving by `step` per contact can still enter the rectangle.
    #[inline]
    pub fn reachable(&self, p: DVec2, step: DVec2) -> bool {
        let ok = |v: f64, lo: f64, hi: f64, s: f64| (v >= lo || s > 0.0) && (v < hi || s < 0.0);
        ok(p.x, self.min.x, self.max.x, step.x) && ok(p.y, self.min.y, self.max.y, step.y)
    }
}

/// The runtime waveguide.
#[derive(Clone, Debug)]
pub struct Waveguide {
    /// Plate thickness w, mm.
    pub thickness_mm: f64,
    /// Glass model.
    pub glass: Glass,
    /// Override of the glass absorption (1/mm), if set.
    pub absorption_override_per_mm: Option<f64>,
    /// The gratings both vHOEs carry (one film).
    pub gratings: GratingSet,
    /// Bottom vHOE on the back face.
    pub bottom: Rect,
    /// Top vHOE on the front face.
    pub top: Rect,
    /// Cover on the user side of the top vHOE.
    pub covered: bool,
    /// Cover in optical contact: TIR under it is frustrated (absorbed).
    pub cover_frustrates_tir: bool,
    /// `hoe.model = "rcwa"`: the film's rigorous coupling tables (None: Kogelnik).
    pub rcwa: Option<std::sync::Arc<crate::optics::rcwa::coupling::RcwaCouplings>>,
}

impl Waveguide {
    /// Glass index at a wavelength.
    #[inline]
    pub fn n_glass(&self, lambda_nm: f64) -> f64 {
        self.glass.index(lambda_nm)
    }

    /// Intensity absorption of the glass in 1/mm.
    #[inline]
    pub fn absorption_per_mm(&self, lambda_nm: f64) -> f64 {
        self.absorption_override_per_mm
            .unwrap_or_else(|| self.glass.absorption_per_mm(lambda_nm))
    }
}
