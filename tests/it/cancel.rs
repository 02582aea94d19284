//! Cooperative cancellation (`stscam::cancel`, used by the Python module on Ctrl-C): a job run
//! with a raised flag skips its work, a dataset run stops with `Cancelled` before writing
//! anything that a resume would trust, and the same job without a flag is unaffected.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use stscam::cancel::with_flag;
use stscam::render::{RenderSettings, render};
use stscam::scene::load_scene;
use stscam::system::System;

fn small() -> System {
    let sets = [
        "sensor.crop_px=[32,24]".to_string(),
        "display.image=letter:F@16".to_string(),
    ];
    System::build(&load_scene(None, &sets).unwrap()).unwrap()
}

fn raised() -> Arc<AtomicBool> {
    Arc::new(AtomicBool::new(true))
}

#[test]
fn a_cancelled_render_and_matrix_skip_their_work() {
    let sys = small();
    let set = RenderSettings::lattice(2, 1, false);
    let full = render(&sys, &set);
    let lit = full.channels[0].iter().filter(|&&v| v > 0.0).count();
    assert!(lit > 100, "the uncancelled render lights {lit} pixels");
    let cancelled = with_flag(raised(), || render(&sys, &set));
    assert_eq!(cancelled.channels[0].len(), full.channels[0].len());
    assert!(cancelled.channels[0].iter().all(|&v| v == 0.0));
    assert_eq!(cancelled.stats.camera_paths, 0);
    // A lowered flag changes nothing, bit for bit.
    let lowered = with_flag(Arc::new(AtomicBool::new(false)), || render(&sys, &set));
    assert_eq!(lowered.channels, full.channels);
    let m = stscam::matrix::compute_matrix(&sys, &set);
    assert!(m.h.nnz() > 0);
    let mc = with_flag(raised(), || stscam::matrix::compute_matrix(&sys, &set));
    assert_eq!((mc.h.rows, mc.h.cols, mc.h.nnz()), (m.h.rows, m.h.cols, 0));
}

#[test]
fn a_cancelled_dataset_run_writes_no_matrix_and_no_card() {
    use stscam::dataset::{DatasetError, RunOptions, generate, plan};
    let recipe =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("validation/python/noiseless.toml");
    let p = plan(&recipe).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d");
    let opts = RunOptions {
        out: out.clone(),
        shard: None,
        resume: false,
        progress: false,
    };
    let r = with_flag(raised(), || generate(&p, &opts));
    assert!(matches!(r, Err(DatasetError::Cancelled)), "{r:?}");
    assert!(!out.join("dataset.json").exists());
    assert!(!out.join("scene_000").join("H.npz").exists());
    // The run can be resumed to completion.
    let done = generate(
        &p,
        &RunOptions {
            resume: true,
            ..opts
        },
    )
    .unwrap();
    assert_eq!(done.samples, 30);
    assert!(out.join("dataset.json").is_file());
}
