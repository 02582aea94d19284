//! Studies over the tracer and reconstruction: the demo and colour demo, the capture helpers they share (`capture`), Hadamard calibration, sweeps, tolerance, analytic checks, grating spectra, benchmarks.
//!
//! May depend on: every layer below except the cli (docs/design.md, "Crates"; checked by `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod analytic;
pub mod bench;
pub mod capture;
pub mod colour_demo;
pub mod demo;
pub mod grating_spectrum;
pub mod hadamard;
pub mod sweep;
pub mod tolerance;

// The layers below, under the names this crate's modules use (`crate::io::…`).
#[cfg(test)]
use stscam_base::options;
use stscam_base::{
    VERSION, cancel, limits, noise, numfmt, progress, rows, sampler, sparse, spectra, targets,
};
use stscam_dataset as dataset;
use stscam_io as io;
use stscam_io::plot;
use stscam_optics as optics;
use stscam_recon as recon;
use stscam_scene as scene;
use stscam_tracer::{analysis, colour, matrix, output, render, system, trace};
use stscam_world::display;
