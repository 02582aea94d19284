//! Stray light: every path light can take through the plate, not only the designed one. A
//! branching tracer of the camera's importance ([`paths`]: both Fresnel branches at every
//! face, orders ±1 of every grating of the film at both vHOEs including cross-coupling between
//! multiplexed gratings, repeated passes through a film, the cover, absorbing plate edges,
//! Russian roulette below a threshold), path classes named by their events ([`classes`]), and
//! the camera image split by class with `render`'s own samples ([`image`]), from which
//! `stscam stray` writes its report.
//!
//! May depend on: stscam-base, stscam-optics, stscam-world, stscam-tracer (docs/design.md,
//! "Crates"; checked by `tests/it/layers.rs`). No I/O: the report's files are the CLI's.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod classes;
pub mod image;
pub mod paths;

// The layers below, under the names this crate's modules use.
use stscam_base::{cancel, rows, sampler};
use stscam_optics as optics;
use stscam_tracer as tracer;
use stscam_world as world;
