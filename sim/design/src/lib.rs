//! Design evaluation and optimisation: the metrics of one design (`evaluate`: captured and
//! waveguide FOV, scene field, replicas, efficiency, colour band coverage, reconstruction PSNR
//! and SSIM at a fixed exposure, fabrication yield and tolerance quantiles), design study files
//! (`study`), constrained Bayesian optimisation with Pareto fronts by ε-constraints
//! (`optimize`, on `egobox-ego`) and the files of a run (`report`).
//!
//! May depend on: every layer below except the cli (docs/design.md, "Crates"; checked by
//! `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod evaluate;
pub mod metric;
pub mod optimize;
pub mod report;
pub mod study;

// The layers below, under the names this crate's modules use (`crate::io::…`).
use stscam_base::{cancel, limits, noise, sampler, targets};
use stscam_io as io;
use stscam_io::plot;
use stscam_recon as recon;
use stscam_scene as scene;
use stscam_studies::{capture, demo, sweep, tolerance};
use stscam_tracer::{analysis, matrix, render, system};
use stscam_world::display;
