//! The tracer: the camera side and its estimators: camera, waveguide, wavelength sampling, system, trace, render, H and depth stacks, frontal truth, design analysis, output sets. One camera sample is traced backward from the sensor
//! through the plate (docs/design.md, "One camera sample, end to end"); the user side beyond the
//! front face is `stscam_world`'s.
//!
//! May depend on: stscam-base, stscam-io, stscam-optics, stscam-scene, stscam-world (docs/design.md, "Crates"; checked by `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod analysis;
pub mod camera;
pub mod colour;
pub mod frontal;
pub mod matrix;
pub mod output;
pub mod render;
pub mod system;
pub mod trace;
pub mod waveguide;
pub mod wavelength;

// The layers below, under the names this crate's modules use (`crate::io::…`).
use stscam_base::{
    VERSION, cancel, limits, numfmt, progress, rows, sampler, sparse, spectra, targets,
};
use stscam_io as io;
use stscam_optics as optics;
use stscam_scene as scene;
use stscam_world as world;
use stscam_world::display;
