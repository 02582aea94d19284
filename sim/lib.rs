//! stscam: a spectral Monte Carlo simulator of the see-through-screen camera built on a
//! holographic waveguide (Optics Express 2022). The model is in `docs/physics.md`, the layers in
//! `docs/design.md`; each module's header states its model, assumptions and sources.
//!
//! This crate is the facade: the library is the workspace's crates under `sim/`, one per layer
//! (`stscam-base` … `stscam-cli`), and this crate re-exports their modules under the paths the
//! binary, the Python module, the tests and users name (`stscam::render`, `stscam::scene`, …).
//! It adds no code of its own.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub use stscam_base::{
    VERSION, cancel, cie, limits, noise, numfmt, options, progress, sampler, sparse, spectra,
    store, suggest, targets,
};
pub use stscam_cli as jobs;
pub use stscam_dataset as dataset;
pub use stscam_design as design;
pub use stscam_io as io;
pub use stscam_io::plot;
pub use stscam_optics as optics;
pub use stscam_recon as recon;
pub use stscam_scene as scene;
pub use stscam_stray as stray;
pub use stscam_studies::{
    analytic, bench, capture, colour_demo, demo, grating_spectrum, hadamard, sweep, tolerance,
};
pub use stscam_tracer::{
    analysis, camera, colour, matrix, output, render, system, trace, waveguide, wavelength,
};
pub use stscam_world::display;

/// H stacks on disk (`stscam_io::stack`) and the layered offset of computed stacks.
pub mod stack {
    pub use stscam_io::stack::*;
    pub use stscam_tracer::matrix::layered_offset;
}

/// The user side (`stscam_world`) and the frontal ground truth seen from the screen
/// (`stscam_tracer::frontal`, which needs the camera's field).
pub mod world {
    pub use stscam_tracer::frontal;
    pub use stscam_world::*;
}
