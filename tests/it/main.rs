//! All integration tests in one crate: one binary to build and link instead of one per file.

mod analytic_field;
mod bvh;
mod cancel;
mod cli_errors;
mod common;
mod coverage;
mod dataset;
mod dataset3d;
mod depth;
mod estimators;
mod hostile;
mod invariants;
mod jobs;
mod matrix_calibration;
mod mesh_scenes;
mod mitsuba_reference;
mod multiplex;
mod npz_independent;
mod probe_geometry;
mod reconstruction;
mod render_capture;
mod scenes3d_physics;
mod stress;
mod sweep;
