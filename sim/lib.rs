//! stscam: a spectral Monte Carlo simulator of the see-through-screen camera built on a
//! holographic waveguide (Optics Express 2022). The model is in `docs/physics.md`, the layers in
//! `docs/design.md`; each module's header states its model, assumptions and sources.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod analysis;
pub mod analytic;
pub mod bench;
pub mod camera;
pub mod cancel;
pub mod colour;
pub mod colour_demo;
pub mod dataset;
pub mod demo;
pub mod display;
pub mod grating_spectrum;
pub mod hadamard;
pub mod io;
pub mod jobs;
pub mod limits;
pub mod matrix;
pub mod noise;
pub mod numfmt;
pub mod optics;
pub mod options;
pub mod output;
pub mod plot;
pub mod progress;
pub mod recon;
pub mod render;
pub mod sampler;
pub mod scene;
pub mod sparse;
pub mod spectra;
pub mod stack;
pub mod suggest;
pub mod sweep;
pub mod system;
pub mod targets;
pub mod tolerance;
pub mod trace;
pub mod waveguide;
pub mod wavelength;
pub mod world;

/// The crate version, recorded in every output.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
