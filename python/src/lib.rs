//! `stscam._native`: the Python extension behind the `stscam` package (python/stscam/). A thin
//! shell over the library, like the CLI: every function calls the library functions the CLI
//! calls, so the same inputs give the same numbers bit for bit. Arrays cross the boundary as
//! little-endian bytes (the pure-Python layer wraps them in numpy arrays without copying twice),
//! structured results as the JSON the CLI prints. Bad input raises `ValueError` with the CLI's
//! one-line message; long jobs run with the GIL released on a worker thread, and Ctrl-C (checked
//! every 100 ms) cancels them through `stscam::cancel` and raises `KeyboardInterrupt`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::RecvTimeoutError;
use std::time::Duration;

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use stscam::render::RenderSettings;
use stscam::sampler::SamplerKind;
use stscam::system::System;

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// Runs `job` on a worker thread inside a rayon pool of `threads` (default: all cores) with the
/// GIL released, polling for signals; on Ctrl-C the job is cancelled and the signal's exception
/// (KeyboardInterrupt) raised once the job has stopped.
fn run_job<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    job: impl FnOnce() -> T + Send,
) -> PyResult<T> {
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        if t == 0 {
            return Err(value_error("threads: must be at least 1"));
        }
        b = b.num_threads(t);
    }
    let pool = b
        .build()
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start worker threads: {e}")))?;
    let flag = Arc::new(AtomicBool::new(false));
    let (tx, rx) = std::sync::mpsc::channel();
    // Borrowed by the GIL-free closures below, which must be Send.
    let rx = std::sync::Mutex::new(rx);
    let wait = |timeout: Option<Duration>| {
        let rx = rx.lock().unwrap_or_else(|p| p.into_inner());
        match timeout {
            Some(t) => rx.recv_timeout(t),
            None => rx.recv().map_err(|_| RecvTimeoutError::Disconnected),
        }
    };
    std::thread::scope(|s| {
        let worker_flag = flag.clone();
        let pool = &pool;
        s.spawn(move || {
            let r = pool.install(|| stscam::cancel::with_flag(worker_flag, job));
            let _ = tx.send(r);
        });
        loop {
            match py.allow_threads(|| wait(Some(Duration::from_millis(100)))) {
                Ok(r) => return Ok(r),
                Err(RecvTimeoutError::Timeout) => {
                    if let Err(e) = py.check_signals() {
                        flag.store(true, Ordering::Relaxed);
                        py.allow_threads(|| {
                            let _ = wait(None);
                        });
                        return Err(e);
                    }
                }
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(PyRuntimeError::new_err("the worker thread failed"));
                }
            }
        }
    })
}

/// A scene as the Python layer passes it: (scene file or None, `--set KEY=VALUE` overrides).
type SceneArg = (Option<String>, Vec<String>);

fn load(scene: &SceneArg) -> Result<System, String> {
    let ls = stscam::scene::load_scene(scene.0.as_deref().map(Path::new), &scene.1)
        .map_err(|e| e.to_string())?;
    System::build(&ls).map_err(|e| e.to_string())
}

fn check_spp(spp: u32) -> PyResult<()> {
    if spp == 0 {
        return Err(value_error("--spp: must be at least 1"));
    }
    Ok(())
}

fn f32_bytes<'py>(py: Python<'py>, v: &[f32]) -> Bound<'py, PyBytes> {
    let b: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    PyBytes::new(py, &b)
}

fn f64_bytes<'py>(py: Python<'py>, v: &[f64]) -> Bound<'py, PyBytes> {
    let b: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    PyBytes::new(py, &b)
}

fn csr_dict<'py>(py: Python<'py>, h: &stscam::sparse::CsrMatrix) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("rows", h.rows)?;
    d.set_item("cols", h.cols)?;
    let ip: Vec<u8> = h.indptr.iter().flat_map(|x| x.to_le_bytes()).collect();
    let ix: Vec<u8> = h.indices.iter().flat_map(|x| x.to_le_bytes()).collect();
    d.set_item("indptr", PyBytes::new(py, &ip))?;
    d.set_item("indices", PyBytes::new(py, &ix))?;
    d.set_item("data", f32_bytes(py, &h.data))?;
    Ok(d)
}

fn json<T: serde::Serialize>(v: &T) -> PyResult<String> {
    serde_json::to_string(v).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// The scene after overrides as JSON (raises ValueError on a bad scene or override).
#[pyfunction]
#[pyo3(signature = (scene))]
fn scene_json(scene: SceneArg) -> PyResult<String> {
    let sys = load(&scene).map_err(value_error)?;
    json(&sys.scene)
}

/// Renders the capture (and, with objects, the frontal image, depth and mask).
#[pyfunction]
#[pyo3(signature = (scene, spp, seed, threads, sampler, spectral, frontal_px, user_side))]
#[allow(clippy::too_many_arguments)]
fn render<'py>(
    py: Python<'py>,
    scene: SceneArg,
    spp: u32,
    seed: u64,
    threads: Option<usize>,
    sampler: &str,
    spectral: bool,
    frontal_px: Option<(usize, usize)>,
    user_side: &str,
) -> PyResult<Bound<'py, PyDict>> {
    check_spp(spp)?;
    let user_side = match user_side {
        "auto" => stscam::render::UserSideSampler::Auto,
        "resampled" => stscam::render::UserSideSampler::Resampled,
        "padded" => stscam::render::UserSideSampler::Padded,
        "hashed" => stscam::render::UserSideSampler::Hashed,
        other => {
            return Err(value_error(format!(
                "user_side {other:?}: expected \"auto\", \"resampled\", \"padded\" or \"hashed\""
            )));
        }
    };
    let sampler = match sampler {
        "lattice" => SamplerKind::Lattice,
        "r5" => SamplerKind::R5,
        "independent" => SamplerKind::Independent,
        "sobol" => SamplerKind::Sobol,
        other => {
            return Err(value_error(format!(
                "sampler {other:?}: expected \"lattice\", \"r5\", \"independent\" or \"sobol\""
            )));
        }
    };
    if let Some((w, h)) = frontal_px
        && !((1..=8192).contains(&w) && (1..=8192).contains(&h))
    {
        return Err(value_error(format!(
            "--frontal-px: expected N or WxH (1..=8192 each), got {w}x{h}"
        )));
    }
    let (cap, frontal, render_s) = run_job(py, threads, || {
        let sys = load(&scene)?;
        let settings = RenderSettings {
            spp,
            seed,
            sampler,
            user_side,
            spectral_bins: spectral.then(|| stscam::render::spectral_bins(&sys.scene.sampling)),
            progress: false,
        };
        let t0 = std::time::Instant::now();
        let cap = stscam::render::render(&sys, &settings);
        let render_s = t0.elapsed().as_secs_f64();
        let (fw, fh) = frontal_px.unwrap_or((cap.width, cap.height));
        let frontal = stscam::world::frontal::render_frontal(&sys, fw, fh, spp, seed);
        Ok::<_, String>((cap, frontal, render_s))
    })?
    .map_err(value_error)?;
    let d = PyDict::new(py);
    d.set_item("width", cap.width)?;
    d.set_item("height", cap.height)?;
    d.set_item("channels", cap.channel_names.clone())?;
    d.set_item("image", f32_bytes(py, &cap.channels.concat()))?;
    let bins: Vec<f64> = cap.spectral.iter().map(|(l, _)| *l).collect();
    let spec: Vec<f32> = cap
        .spectral
        .iter()
        .flat_map(|(_, v)| v.iter().copied())
        .collect();
    d.set_item("spectral_bins_nm", bins)?;
    d.set_item("spectral", f32_bytes(py, &spec))?;
    d.set_item("stats", json(&cap.stats)?)?;
    d.set_item("render_time_s", render_s)?;
    if let Some(f) = frontal {
        let fd = PyDict::new(py);
        fd.set_item("width", f.width)?;
        fd.set_item("height", f.height)?;
        fd.set_item("channels", f.channel_names.clone())?;
        fd.set_item("image", f32_bytes(py, &f.channels.concat()))?;
        fd.set_item("depth", f32_bytes(py, &f.depth_mm))?;
        let m: Vec<u8> = f.mask.iter().flat_map(|x| x.to_le_bytes()).collect();
        fd.set_item("mask", PyBytes::new(py, &m))?;
        d.set_item("frontal", fd)?;
    }
    Ok(d)
}

/// H and the offset (as `stscam matrix`).
#[pyfunction]
#[pyo3(signature = (scene, spp, seed, depth_mm, threads))]
fn matrix<'py>(
    py: Python<'py>,
    scene: SceneArg,
    spp: u32,
    seed: u64,
    depth_mm: Option<f64>,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    check_spp(spp)?;
    if let Some(d) = depth_mm {
        stscam::matrix::check_depth(d).map_err(value_error)?;
    }
    let m = run_job(py, threads, || {
        let mut sys = load(&scene)?;
        if let Some(d) = depth_mm {
            stscam::matrix::place_object(&mut sys, d);
        }
        Ok::<_, String>(stscam::matrix::compute_matrix(
            &sys,
            &RenderSettings::lattice(spp, seed, false),
        ))
    })?
    .map_err(value_error)?;
    let d = csr_dict(py, &m.h)?;
    d.set_item("offset", f32_bytes(py, &m.offset))?;
    d.set_item("object", m.object)?;
    d.set_item("crop", m.crop)?;
    d.set_item("channels", m.channels.clone())?;
    d.set_item("stats", json(&m.stats)?)?;
    Ok(d)
}

/// Every depth's H and offset of a depth stack, in one pass (as `stscam matrix --depth-mm
/// SPEC` with a list or range): one dict per depth, sorted by depth.
#[pyfunction]
#[pyo3(signature = (scene, spp, seed, depth_spec, threads))]
fn matrix_stack<'py>(
    py: Python<'py>,
    scene: SceneArg,
    spp: u32,
    seed: u64,
    depth_spec: &str,
    threads: Option<usize>,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    check_spp(spp)?;
    let depths = stscam::stack::parse_depths(depth_spec)
        .map_err(|m| value_error(format!("--depth-mm {depth_spec}: {m}")))?;
    // The CLI's bound on a stack's entries while the pass runs.
    let budget = (stscam::limits::MAX_JOB_BYTES / 4) as u64;
    let stack = run_job(py, threads, || {
        let sys = load(&scene)?;
        stscam::matrix::compute_matrix_stack_within(
            &sys,
            &RenderSettings::lattice(spp, seed, false),
            &depths,
            budget,
        )
        .map_err(|e| e.to_string())
    })?
    .map_err(value_error)?;
    let mut out = Vec::with_capacity(stack.len());
    for (m, d) in stack.iter().zip(&depths) {
        let dict = csr_dict(py, &m.h)?;
        dict.set_item("depth_mm", *d)?;
        dict.set_item("offset", f32_bytes(py, &m.offset))?;
        dict.set_item("object", m.object)?;
        out.push(dict);
    }
    Ok(out)
}

/// `stscam info --json`.
#[pyfunction]
#[pyo3(signature = (scene))]
fn info(scene: SceneArg) -> PyResult<String> {
    let sys = load(&scene).map_err(value_error)?;
    json(&stscam::analysis::info(&sys))
}

/// `stscam probe --pixel COL,ROW --json`.
#[pyfunction]
#[pyo3(signature = (scene, col, row))]
fn probe(scene: SceneArg, col: usize, row: usize) -> PyResult<String> {
    let sys = load(&scene).map_err(value_error)?;
    let p = stscam::analysis::probe(&sys, col, row)
        .map_err(|m| value_error(format!("--pixel {col},{row}: {m}")))?;
    json(&p)
}

/// A CSR matrix from the Python layer's little-endian arrays (int64 indptr and indices, float32
/// data), checked: every problem raises ValueError naming `what`.
fn csr_from(
    rows: usize,
    cols: usize,
    indptr: &[u8],
    indices: &[u8],
    data: &[u8],
    what: &str,
) -> PyResult<stscam::sparse::CsrMatrix> {
    // Negative or too large indices become values that `check` rejects.
    let indptr: Vec<u64> = decode(indptr, "indptr", |c| {
        u64::try_from(i64::from_le_bytes(c)).unwrap_or(u64::MAX)
    })?;
    let indices: Vec<u32> = decode(indices, "indices", |c| {
        u32::try_from(i64::from_le_bytes(c)).unwrap_or(u32::MAX)
    })?;
    let data: Vec<f32> = decode(data, "data", f32::from_le_bytes)?;
    let h = stscam::sparse::CsrMatrix {
        rows,
        cols,
        indptr,
        indices,
        data,
    };
    h.check().map_err(|m| value_error(format!("{what}: {m}")))?;
    if let Some(i) = h.data.iter().position(|v| !v.is_finite()) {
        return Err(value_error(format!(
            "{what}: entry {i} is not a finite number"
        )));
    }
    Ok(h)
}

/// One depth of a stack as the Python layer passes it: (depth_mm, rows, cols, indptr, indices,
/// data, offset or None).
type StackBlock<'py> = (
    f64,
    usize,
    usize,
    Bound<'py, PyBytes>,
    Bound<'py, PyBytes>,
    Bound<'py, PyBytes>,
    Option<Bound<'py, PyBytes>>,
);

/// Reconstruction with a depth stack (as `stscam reconstruct --matrix H_stack.npz`): joint
/// multi-depth ADMM-TV or depth estimation then ADMM-TV at the estimated depth. Returns the
/// planes (depth, little-endian f64 values), the estimate (JSON or None) and the solver report.
#[pyfunction]
#[pyo3(signature = (blocks, object, capture, joint_offset, method, iters, tau, mu, tv, threads))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn reconstruct_stack<'py>(
    py: Python<'py>,
    blocks: Vec<StackBlock<'py>>,
    object: (usize, usize),
    capture: &[u8],
    joint_offset: Option<&[u8]>,
    method: &str,
    iters: Option<usize>,
    tau: f64,
    mu: f64,
    tv: &str,
    threads: Option<usize>,
) -> PyResult<(Vec<(f64, Bound<'py, PyBytes>)>, Option<String>, String)> {
    use stscam::recon::admm::TvKind;
    use stscam::recon::layered::{StackMethod, StackOptions, solve_stack, stack_setup_bytes};
    let method = match method {
        "joint" => StackMethod::Joint,
        "depth" => StackMethod::Depth,
        m => {
            return Err(value_error(format!(
                "method {m:?}: expected \"joint\" or \"depth\""
            )));
        }
    };
    let tv = match tv {
        "iso" => TvKind::Iso,
        "aniso" => TvKind::Aniso,
        t => {
            return Err(value_error(format!(
                "tv {t:?}: expected \"iso\" or \"aniso\""
            )));
        }
    };
    for (name, v) in [("--tau", tau), ("--mu", mu)] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(value_error(format!(
                "{name} {v}: must be a non-negative number"
            )));
        }
    }
    if iters == Some(0) {
        return Err(value_error("--iters: must be at least 1"));
    }
    if blocks.is_empty() {
        return Err(value_error("stack: no depths"));
    }
    let mut depths_mm = Vec::with_capacity(blocks.len());
    let mut hs = Vec::with_capacity(blocks.len());
    let mut offsets = Vec::with_capacity(blocks.len());
    for (d, rows, cols, ip, ix, data, off) in &blocks {
        let what = format!("H at {d} mm");
        if !(d.is_finite() && *d > 0.0) || depths_mm.last().is_some_and(|p| p >= d) {
            return Err(value_error(format!(
                "stack: depth {d} mm: depths must be positive and ascending"
            )));
        }
        let h = csr_from(
            *rows,
            *cols,
            ip.as_bytes(),
            ix.as_bytes(),
            data.as_bytes(),
            &what,
        )?;
        if h.rows
            != hs
                .first()
                .map_or(h.rows, |f: &stscam::sparse::CsrMatrix| f.rows)
            || object.0.checked_mul(object.1) != Some(h.cols)
        {
            return Err(value_error(format!(
                "{what}: {}x{} does not match the other depths' rows or the object {}x{}",
                h.rows, h.cols, object.0, object.1
            )));
        }
        let off = off
            .as_ref()
            .map(|o| decode(o.as_bytes(), "offset", f32::from_le_bytes))
            .transpose()?;
        if off.as_ref().is_some_and(|o| o.len() != h.rows) {
            return Err(value_error(format!(
                "{what}: its offset has the wrong length"
            )));
        }
        depths_mm.push(*d);
        hs.push(h);
        offsets.push(off);
    }
    let rows = hs[0].rows;
    let g: Vec<f64> = decode(capture, "capture", f64::from_le_bytes)?;
    if g.len() != rows {
        return Err(value_error(format!(
            "capture: the capture has {} values but H has {rows} rows (crop pixels x channels); they must match",
            g.len()
        )));
    }
    if let Some(i) = g.iter().position(|v| !v.is_finite()) {
        return Err(value_error(format!(
            "capture: value {i} is not a finite number"
        )));
    }
    // Default: Σ_d o_d summed as `offset_stack.npy` is (f64 over the depths, then f32).
    let joint_offset = match joint_offset {
        Some(o) => Some(decode(o, "offset", f32::from_le_bytes)?),
        None if offsets.iter().all(Option::is_some) => Some(
            (0..rows)
                .map(|i| {
                    offsets
                        .iter()
                        .flatten()
                        .map(|o| f64::from(o[i]))
                        .sum::<f64>() as f32
                })
                .collect(),
        ),
        None => None,
    };
    if joint_offset.as_ref().is_some_and(|o| o.len() != rows) {
        return Err(value_error("offset: its length is not H's row count"));
    }
    let ls = stscam::stack::LoadedStack {
        depths_mm,
        blocks: hs,
        object,
        offsets,
        joint_offset,
        joint_offset_path: None,
    };
    let opts = StackOptions {
        method,
        iters,
        tau_rel: tau,
        mu_rel: mu,
        tv,
        ..StackOptions::default()
    };
    let threads_n = threads.unwrap_or_else(rayon::current_num_threads);
    stscam::limits::check_bytes(
        "stack",
        "the reconstruction set-up (H transposed and the Gram matrix HᵀH)",
        stack_setup_bytes(&ls, method, threads_n),
    )
    .map_err(value_error)?;
    let sol = run_job(py, threads, || solve_stack(&ls, &g, &opts))?.map_err(value_error)?;
    let planes = sol
        .planes
        .iter()
        .map(|(d, f)| (*d, f64_bytes(py, f)))
        .collect();
    let estimate = sol.estimate.as_ref().map(json).transpose()?;
    Ok((planes, estimate, json(&sol.info)?))
}

/// Little-endian values of `N` bytes each from `b`, converted by `f`.
fn decode<const N: usize, T>(b: &[u8], what: &str, f: impl Fn([u8; N]) -> T) -> PyResult<Vec<T>> {
    if b.len() % N != 0 {
        return Err(value_error(format!(
            "{what}: {} bytes is not a whole number of {N}-byte values",
            b.len()
        )));
    }
    Ok(b.chunks_exact(N)
        .map(|c| {
            let mut a = [0u8; N];
            a.copy_from_slice(c);
            f(a)
        })
        .collect())
}

/// Reconstructs the object from a capture (as `stscam reconstruct`); H's arrays as bytes
/// (indptr int64, indices int64, data float32), the capture as float64, the offset as float32.
#[pyfunction]
#[pyo3(signature = (rows, cols, indptr, indices, data, object, capture, offset, method, iters, tau, tv, threads))]
#[allow(clippy::too_many_arguments)]
fn reconstruct<'py>(
    py: Python<'py>,
    rows: usize,
    cols: usize,
    indptr: &[u8],
    indices: &[u8],
    data: &[u8],
    object: (usize, usize),
    capture: &[u8],
    offset: Option<&[u8]>,
    method: &str,
    iters: Option<usize>,
    tau: f64,
    tv: &str,
    threads: Option<usize>,
) -> PyResult<(Bound<'py, PyBytes>, String)> {
    use stscam::recon::{Method, Problem, SolveOptions, admm::TvKind};
    let method = match method {
        "cg" => Method::Cg,
        "admm-tv" => Method::AdmmTv,
        m => {
            return Err(value_error(format!(
                "method {m:?}: expected \"cg\" or \"admm-tv\""
            )));
        }
    };
    let tv = match tv {
        "iso" => TvKind::Iso,
        "aniso" => TvKind::Aniso,
        t => {
            return Err(value_error(format!(
                "tv {t:?}: expected \"iso\" or \"aniso\""
            )));
        }
    };
    if !(tau.is_finite() && tau >= 0.0) {
        return Err(value_error(format!(
            "--tau {tau}: must be a non-negative number"
        )));
    }
    if iters == Some(0) {
        return Err(value_error("--iters: must be at least 1"));
    }
    let h = csr_from(rows, cols, indptr, indices, data, "H")?;
    if object.0.checked_mul(object.1) != Some(cols) {
        return Err(value_error(format!(
            "the object {}x{} has {} pixels but H has {cols} columns",
            object.0,
            object.1,
            object.0.saturating_mul(object.1)
        )));
    }
    let mut g: Vec<f64> = decode(capture, "capture", f64::from_le_bytes)?;
    if g.len() != rows {
        return Err(value_error(format!(
            "capture: the capture has {} values but H has {rows} rows (crop pixels x channels); they must match",
            g.len()
        )));
    }
    if let Some(i) = g.iter().position(|v| !v.is_finite()) {
        return Err(value_error(format!(
            "capture: value {i} is not a finite number"
        )));
    }
    if let Some(o) = offset {
        let o: Vec<f32> = decode(o, "offset", f32::from_le_bytes)?;
        if o.len() != rows {
            return Err(value_error(format!(
                "offset: {} values but H has {rows} rows",
                o.len()
            )));
        }
        for (x, &v) in g.iter_mut().zip(&o) {
            *x -= f64::from(v);
        }
    }
    let opts = SolveOptions {
        method,
        iters,
        tau_rel: tau,
        tv,
    };
    let sol = run_job(py, threads, || {
        let problem = Problem::new(&h, object.0, object.1);
        stscam::recon::solve(&problem, &g, &opts)
    })?;
    Ok((f64_bytes(py, &sol.f), json(&sol.info)?))
}

/// The simulated Hadamard calibration (as `stscam calibrate`): H_est and the report.
#[pyfunction]
#[pyo3(signature = (scene, spp, seed, matrix, object, noise, dark_frame, render, threshold_sigma, threads))]
#[allow(clippy::too_many_arguments)]
fn calibrate<'py>(
    py: Python<'py>,
    scene: SceneArg,
    spp: u32,
    seed: u64,
    matrix: Option<PathBuf>,
    object: Option<(usize, usize)>,
    noise: bool,
    dark_frame: bool,
    render: bool,
    threshold_sigma: f64,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    use stscam::hadamard::{CalibrationJob, TrueMatrix, calibrate_scene};
    check_spp(spp)?;
    if !(threshold_sigma.is_finite() && threshold_sigma >= 0.0) {
        return Err(value_error(
            "--threshold-sigma: must be a non-negative number",
        ));
    }
    let matrix = match matrix {
        Some(p) => Some(TrueMatrix::load(&p, object).map_err(value_error)?.0),
        None => None,
    };
    let job = CalibrationJob {
        matrix,
        spp,
        seed,
        sensor_noise: noise,
        dark_frame,
        render_frames: render,
        threshold_sigma,
        progress: false,
    };
    let run = run_job(py, threads, || {
        let sys = load(&scene)?;
        calibrate_scene(&sys, &job)
    })?
    .map_err(value_error)?;
    let d = csr_dict(py, &run.calibration.h_est)?;
    d.set_item("object", run.object)?;
    d.set_item("report", json(&run.calibration.report)?)?;
    Ok(d)
}

/// A design sweep (as `stscam sweep --json`): the rows as JSON.
#[pyfunction]
#[pyo3(signature = (scene, vary, fov_fraction, psnr, psnr_spp, threads))]
#[allow(clippy::too_many_arguments)]
fn sweep(
    py: Python<'_>,
    scene: SceneArg,
    vary: Vec<String>,
    fov_fraction: f64,
    psnr: Option<String>,
    psnr_spp: u32,
    threads: Option<usize>,
) -> PyResult<String> {
    use stscam::sweep::{PsnrSettings, SweepSettings, VaryAxis, run_sweep};
    let axes = vary
        .iter()
        .map(|v| VaryAxis::parse(v))
        .collect::<Result<Vec<_>, _>>()
        .map_err(value_error)?;
    if psnr_spp == 0 {
        return Err(value_error("--psnr-spp: must be at least 1"));
    }
    if let Some(t) = &psnr {
        stscam::targets::builtin_target(t).map_err(|e| value_error(format!("--psnr: {e}")))?;
    }
    let set = SweepSettings {
        fov_fraction,
        psnr: psnr.map(|t| PsnrSettings {
            target: t,
            spp: psnr_spp,
            ..PsnrSettings::default()
        }),
        progress: false,
        ..SweepSettings::default()
    };
    let res = run_job(py, threads, || {
        run_sweep(scene.0.as_deref().map(Path::new), &scene.1, &axes, &set)
    })?
    .map_err(value_error)?;
    json(&res.rows)
}

/// Builds a dataset from a recipe into `out` (as `stscam dataset RECIPE --out OUT`), one
/// shard `I/N` of it if given; returns the run summary as JSON.
#[pyfunction]
#[pyo3(signature = (recipe, out, shard, resume, threads))]
fn build_dataset(
    py: Python<'_>,
    recipe: PathBuf,
    out: PathBuf,
    shard: Option<String>,
    resume: bool,
    threads: Option<usize>,
) -> PyResult<String> {
    use stscam::dataset::{RunOptions, Shard, generate, plan};
    let shard = shard
        .map(|s| Shard::parse(&s).map_err(|m| value_error(format!("--shard: {m}"))))
        .transpose()?;
    let s = run_job(py, threads, || {
        let p = plan(&recipe)?;
        generate(
            &p,
            &RunOptions {
                out: out.clone(),
                shard,
                resume,
                progress: false,
            },
        )
    })?
    .map_err(value_error)?;
    json(&s)
}

/// Joins finished shards into `out` (as `stscam dataset merge`); returns the summary as JSON.
#[pyfunction]
#[pyo3(signature = (shards, out, threads))]
fn merge_dataset(
    py: Python<'_>,
    shards: Vec<PathBuf>,
    out: PathBuf,
    threads: Option<usize>,
) -> PyResult<String> {
    let s = run_job(py, threads, || stscam::dataset::merge(&shards, &out))?.map_err(value_error)?;
    json(&s)
}

/// Reads an EXR file written by stscam: (width, height, [(name, float32 bytes)]).
#[pyfunction]
fn read_exr<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(usize, usize, Vec<(String, Bound<'py, PyBytes>)>)> {
    let (w, h, chans) = stscam::io::read_exr(&path).map_err(value_error)?;
    let out = chans
        .into_iter()
        .map(|c| (c.name, f32_bytes(py, &c.data)))
        .collect();
    Ok((w, h, out))
}

/// The extension module.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("VERSION", stscam::VERSION)?;
    m.add_function(wrap_pyfunction!(scene_json, m)?)?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(matrix, m)?)?;
    m.add_function(wrap_pyfunction!(matrix_stack, m)?)?;
    m.add_function(wrap_pyfunction!(info, m)?)?;
    m.add_function(wrap_pyfunction!(probe, m)?)?;
    m.add_function(wrap_pyfunction!(reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(reconstruct_stack, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(sweep, m)?)?;
    m.add_function(wrap_pyfunction!(build_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(merge_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(read_exr, m)?)?;
    Ok(())
}
