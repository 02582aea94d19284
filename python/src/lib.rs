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

use pyo3::exceptions::{PyOSError, PyRuntimeError, PyValueError};
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
    run_job_with(py, threads, None, job)
}

/// [`run_job`] reporting progress: every 100 ms, when the count of the job's outermost
/// progress (`stscam::progress::Observer`) has changed, `progress(done, total, unit)` is
/// called on this thread (and once more at the end). An exception from it cancels the job and
/// is raised.
fn run_job_with<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    progress: Option<&Bound<'_, PyAny>>,
    job: impl FnOnce() -> T + Send,
) -> PyResult<T> {
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        stscam::limits::check_threads(t).map_err(value_error)?;
        b = b.num_threads(t);
    }
    let pool = b
        .build()
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start worker threads: {e}")))?;
    let flag = Arc::new(AtomicBool::new(false));
    let observer = Arc::new(stscam::progress::Observer::default());
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
    let mut last: Option<(u64, u64, String)> = None;
    let mut report = || -> PyResult<()> {
        let (Some(cb), Some((done, total, unit))) = (progress, observer.get()) else {
            return Ok(());
        };
        let now = Some((done, total, unit.clone()));
        if last != now {
            last = now;
            cb.call1((done.min(total), total, unit))?;
        }
        Ok(())
    };
    std::thread::scope(|s| {
        let worker_flag = flag.clone();
        let worker_observer = observer.clone();
        let pool = &pool;
        s.spawn(move || {
            let r = pool.install(|| {
                stscam::progress::with_observer(worker_observer, || {
                    stscam::cancel::with_flag(worker_flag, job)
                })
            });
            let _ = tx.send(r);
        });
        loop {
            match py.allow_threads(|| wait(Some(Duration::from_millis(100)))) {
                Ok(r) => {
                    report()?;
                    return Ok(r);
                }
                Err(RecvTimeoutError::Timeout) => {
                    if let Err(e) = py.check_signals().and_then(|()| report()) {
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

/// A target image held in memory, as the Python layer passes it: (width, height, channels 1
/// or 3, float32 little-endian values row-major with channels interleaved, linear).
/// `linear` false means display code values in [0, 1] (the display gamma is applied, as for
/// a PNG); true means linear intensity (as for an EXR).
type ImageArg = (usize, usize, usize, Vec<u8>, bool);

/// A scene held as TOML text: (text, the name messages blame, the directory relative asset
/// paths resolve against).
type TextArg = (String, String, String);

/// A scene as the Python layer passes it: (scene file or None, `--set KEY=VALUE` overrides,
/// a target image in memory replacing `display.image` or None, the scene as TOML text
/// instead of a file or None).
type SceneArg = (
    Option<String>,
    Vec<String>,
    Option<ImageArg>,
    Option<TextArg>,
);

/// Decoded and checked target values of an [`ImageArg`] (the CLI's checks on an image file:
/// size within the built-in targets' range, finite values); `what` names it in messages.
fn image_values(img: &ImageArg, what: &str) -> Result<Vec<f32>, String> {
    let (w, h, c, b, _) = img;
    if !(1..=16384).contains(w) || !(1..=16384).contains(h) || !(*c == 1 || *c == 3) {
        return Err(format!(
            "{what}: an array target must be 1..=16384 pixels each way with 1 or 3 channels, got {h}x{w}x{c} (h x w x channels)"
        ));
    }
    if b.len() != w * h * c * 4 {
        return Err(format!(
            "{what}: {} bytes do not hold {h}x{w}x{c} float32 values",
            b.len()
        ));
    }
    let v: Vec<f32> = b
        .chunks_exact(4)
        .map(|q| f32::from_le_bytes([q[0], q[1], q[2], q[3]]))
        .collect();
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        let px = i / c;
        return Err(format!(
            "{what}: pixel ({}, {}) is not a finite number",
            px % w,
            px / w
        ));
    }
    Ok(v)
}

/// Shows `values` (see [`ImageArg`]) on the display of `sys`, exactly as `System::build` does
/// for an image file: the target's size, linear intensity and radiance are replaced.
fn show_image(sys: &mut System, img: &ImageArg, values: &[f32]) {
    use stscam::display::Display;
    let (w, h, c, _, linear) = *img;
    let d = &sys.scene.display;
    let (gamma, black) = (d.gamma, d.black_level);
    // A linear RGB target is reduced to luminance in f32 first, as the EXR loader does
    // (`io::image_load`), so an array equals the same image written as an EXR bit for bit.
    let luma: Vec<f32>;
    let planes = sys.display.planes();
    let (values, c) = if linear && c == 3 && planes == 1 {
        luma = values
            .chunks_exact(3)
            .map(|p| {
                (0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2]))
                    as f32
            })
            .collect();
        (&luma[..], 1)
    } else {
        (values, c)
    };
    sys.display.width_px = w;
    sys.display.height_px = h;
    // A colour display (`display.primaries`) keeps an RGB array's channels as its primaries.
    sys.display.intensity = Display::planes_of(values, c, linear, gamma, planes);
    sys.display.radiance = (sys.display.intensity.iter())
        .map(|l| black + (1.0 - black) * l)
        .collect();
}

/// The CLI's warning (`stscam matrix`, `dataset`, `demo`) when part of the object has no
/// strong replica inside the crop, prefixed by `what`; None when all of it is seen or the
/// display is off.
fn coverage_warning(sys: &System, what: &str) -> Option<String> {
    if !sys.scene.display.enabled {
        return None;
    }
    stscam::analysis::object_coverage(sys)
        .warning()
        .map(|w| format!("{what}{}", w.trim_start_matches("warning: ")))
}

/// Where a [`SceneArg`]'s scene comes from: its TOML text, else its file (or the paper scene).
fn scene_source(scene: &SceneArg) -> stscam::scene::SceneSource<'_> {
    match &scene.3 {
        Some((text, name, dir)) => stscam::scene::SceneSource::Text(text, name, Path::new(dir)),
        None => stscam::scene::SceneSource::File(scene.0.as_deref().map(Path::new)),
    }
}

fn load(scene: &SceneArg) -> Result<System, String> {
    let ls = scene_source(scene)
        .load(&scene.1)
        .map_err(|e| e.to_string())?;
    let mut sys = System::build(&ls).map_err(|e| e.to_string())?;
    if let Some(img) = &scene.2 {
        let v = image_values(img, "display.image")?;
        show_image(&mut sys, img, &v);
    }
    Ok(sys)
}

/// [`load`] as a job: the GIL released and Ctrl-C honoured (building a design's RCWA tables
/// can take tens of seconds).
fn load_job(py: Python<'_>, scene: &SceneArg) -> PyResult<System> {
    run_job(py, None, || load(scene))?.map_err(value_error)
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
fn scene_json(py: Python<'_>, scene: SceneArg) -> PyResult<String> {
    let sys = load_job(py, &scene)?;
    json(&sys.scene)
}

/// Renders the capture (and, with objects, the frontal image, depth and mask).
#[pyfunction]
#[pyo3(signature = (scene, spp, seed, threads, sampler, spectral, frontal_px, user_side, batch, frontal_space, progress=None, camera_table=None, frontal_spp=None, adaptive=false))]
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
    batch: Vec<ImageArg>,
    frontal_space: &str,
    progress: Option<Bound<'_, PyAny>>,
    camera_table: Option<(std::path::PathBuf, u32, u32)>,
    frontal_spp: Option<u32>,
    adaptive: bool,
) -> PyResult<Bound<'py, PyDict>> {
    check_spp(spp)?;
    if frontal_spp == Some(0) {
        return Err(value_error("--frontal-spp: must be at least 1"));
    }
    let frontal_spp_given = frontal_spp.is_some();
    let frontal_spp = frontal_spp.unwrap_or(spp);
    let frontal_space =
        stscam::world::colour::FrontalSpace::parse(frontal_space).ok_or_else(|| {
            value_error(format!(
                "frontal_space {frontal_space:?}: expected \"sensor\", \"xyz\" or \"linear-srgb\""
            ))
        })?;
    let user_side: stscam::render::UserSideSampler =
        stscam::options::parse("user_side", user_side).map_err(value_error)?;
    let sampler: SamplerKind = stscam::options::parse("sampler", sampler).map_err(value_error)?;
    if let Some((w, h)) = frontal_px
        && !((1..=8192).contains(&w) && (1..=8192).contains(&h))
    {
        return Err(value_error(format!(
            "--frontal-px: expected N or WxH (1..=8192 each), got {w}x{h}"
        )));
    }
    let values = batch
        .iter()
        .enumerate()
        .map(|(i, img)| match batch.len() {
            1 => image_values(img, "target"),
            _ => image_values(img, &format!("targets[{i}]")),
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(value_error)?;
    let (cap, frontal, render_s, more) = run_job_with(py, threads, progress.as_ref(), || {
        let mut sys = load(&scene)?;
        let settings = RenderSettings {
            spp,
            seed,
            sampler,
            user_side,
            spectral_bins: spectral.then(|| stscam::render::spectral_bins(&sys.scene.sampling)),
            progress: false,
            estimator: Default::default(),
            adaptive,
        };
        // The CLI's limits (run time and memory), for every render of the call.
        let renders = batch.len().max(1) as u64;
        stscam::render::check_limits(&sys, &settings, renders, "--spp")
            .map_err(|e| e.to_string())?;
        stscam::render::adaptive::check(&sys, &settings, camera_table.is_some())
            .map_err(|e| e.to_string())?;
        stscam::jobs::render::check_frontal_paths(&sys, frontal_px, frontal_spp, frontal_spp_given)
            .map_err(|e| e.to_string())?;
        // The camera side from the design's table (read, or drawn and written), for every
        // render of the call.
        let table = match &camera_table {
            None => None,
            Some((dir, tspp, treps)) => {
                use stscam::render::camera_table::{TableSettings, check_usable};
                check_usable(&settings).map_err(|e| format!("camera_table: {e}"))?;
                let ts = TableSettings {
                    spp: *tspp,
                    reps: *treps,
                    seed,
                };
                let (t, _) =
                    stscam::render::table_file::CachedTable::load_or_build(&sys, &ts, dir, false)
                        .map_err(|e| format!("camera_table: {e}"))?;
                Some(t)
            }
        };
        let render_one = |s: &stscam::system::System| match &table {
            Some(t) => t
                .render(s, &settings)
                .map_err(|e| format!("camera_table: {e}")),
            None => Ok(stscam::render::render(s, &settings)),
        };
        let t0 = std::time::Instant::now();
        let mut more = Vec::new();
        if let Some((first, rest)) = batch.split_first() {
            show_image(&mut sys, first, &values[0]);
            for (img, v) in rest.iter().zip(&values[1..]) {
                let mut s = sys.clone();
                show_image(&mut s, img, v);
                more.push(render_one(&s)?);
            }
        }
        let cap = render_one(&sys)?;
        let render_s = t0.elapsed().as_secs_f64();
        let (fw, fh) = frontal_px.unwrap_or((cap.width, cap.height));
        let frontal = stscam::world::frontal::render_frontal_in(
            &sys,
            fw,
            fh,
            frontal_spp,
            seed,
            frontal_space,
        );
        Ok::<_, String>((cap, frontal, render_s, more))
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
    let more_images: Vec<Bound<'py, PyBytes>> = more
        .iter()
        .map(|c| f32_bytes(py, &c.channels.concat()))
        .collect();
    d.set_item("batch_rest", more_images)?;
    if let Some(f) = frontal {
        let fd = PyDict::new(py);
        fd.set_item("width", f.width)?;
        fd.set_item("height", f.height)?;
        fd.set_item("channels", f.channel_names.clone())?;
        fd.set_item("space", f.space.name())?;
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
#[pyo3(signature = (scene, spp, seed, depth_mm, threads, progress=None))]
fn matrix<'py>(
    py: Python<'py>,
    scene: SceneArg,
    spp: u32,
    seed: u64,
    depth_mm: Option<f64>,
    threads: Option<usize>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    check_spp(spp)?;
    if let Some(d) = depth_mm {
        stscam::stack::check_depth(d).map_err(value_error)?;
    }
    let m = run_job_with(py, threads, progress.as_ref(), || {
        let mut sys = load(&scene)?;
        if let Some(d) = depth_mm {
            stscam::matrix::place_object(&mut sys, d);
        }
        let settings = RenderSettings::lattice(spp, seed, false);
        stscam::render::check_limits(&sys, &settings, 1, "--spp").map_err(|e| e.to_string())?;
        let warning = coverage_warning(&sys, "");
        Ok::<_, String>((stscam::matrix::compute_matrix(&sys, &settings), warning))
    })?
    .map_err(value_error)?;
    let (m, warning) = m;
    let d = csr_dict(py, &m.h)?;
    d.set_item("warning", warning)?;
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
#[pyo3(signature = (scene, spp, seed, depth_spec, threads, progress=None))]
fn matrix_stack<'py>(
    py: Python<'py>,
    scene: SceneArg,
    spp: u32,
    seed: u64,
    depth_spec: &str,
    threads: Option<usize>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    check_spp(spp)?;
    let depths = stscam::stack::parse_depths(depth_spec)
        .map_err(|m| value_error(format!("--depth-mm {depth_spec}: {m}")))?;
    // The CLI's bound on a stack's peak memory, estimated before the pass and kept during it.
    let budget = stscam::limits::MAX_JOB_BYTES;
    let stack = run_job_with(py, threads, progress.as_ref(), || {
        let sys = load(&scene)?;
        stscam::render::check_limits(&sys, &RenderSettings::lattice(spp, seed, false), 1, "--spp")
            .map_err(|e| e.to_string())?;
        stscam::matrix::compute_matrix_stack_within(
            &sys,
            &RenderSettings::lattice(spp, seed, false),
            &depths,
            budget,
        )
        .map(|(stack, _)| stack)
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

/// The coverage warning of a scene (as `stscam matrix` prints it, without `warning: `), or None.
#[pyfunction]
#[pyo3(signature = (scene))]
fn coverage(py: Python<'_>, scene: SceneArg) -> PyResult<Option<String>> {
    let sys = load_job(py, &scene)?;
    Ok(coverage_warning(&sys, ""))
}

/// `stscam info --json`.
#[pyfunction]
#[pyo3(signature = (scene))]
fn info(py: Python<'_>, scene: SceneArg) -> PyResult<String> {
    let sys = load_job(py, &scene)?;
    json(&stscam::analysis::info(&sys))
}

/// `stscam probe --pixel COL,ROW --json`.
#[pyfunction]
#[pyo3(signature = (scene, col, row))]
fn probe(py: Python<'_>, scene: SceneArg, col: usize, row: usize) -> PyResult<String> {
    let sys = load_job(py, &scene)?;
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
    use stscam::recon::layered::{StackMethod, StackOptions, solve_stack, stack_setup_bytes};
    let method: StackMethod = stscam::options::parse("method", method).map_err(value_error)?;
    let tv = tv_kind(tv)?;
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
    let (depths_mm, hs, offsets) = stack_blocks(&blocks, object)?;
    let rows = hs[0].rows;
    let g = stack_capture(capture, rows)?;
    let joint_offset = stack_joint_offset(joint_offset, &offsets, rows)?;
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
    // The token is the job's: read inside `run_job`, on the thread whose flag Ctrl-C sets.
    let sol = run_job(py, threads, || {
        let opts = StackOptions {
            cancel: stscam::cancel::current(),
            ..opts
        };
        solve_stack(&ls, &g, &opts)
    })?
    .map_err(value_error)?;
    let planes = sol
        .planes
        .iter()
        .map(|(d, f)| (*d, f64_bytes(py, f)))
        .collect();
    let estimate = sol.estimate.as_ref().map(json).transpose()?;
    Ok((planes, estimate, json(&sol.info)?))
}

/// Each depth's H and offset of `reconstruct_stack`'s `blocks`, checked: depths positive and
/// ascending, every H of the object's columns and the same rows, offsets finite and of H's
/// length.
#[allow(clippy::type_complexity)]
fn stack_blocks(
    blocks: &[StackBlock<'_>],
    object: (usize, usize),
) -> PyResult<(
    Vec<f64>,
    Vec<stscam::sparse::CsrMatrix>,
    Vec<Option<Vec<f32>>>,
)> {
    let mut depths_mm = Vec::with_capacity(blocks.len());
    let mut hs = Vec::with_capacity(blocks.len());
    let mut offsets = Vec::with_capacity(blocks.len());
    for (d, rows, cols, ip, ix, data, off) in blocks {
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
        if let Some(i) = off
            .as_ref()
            .and_then(|o| o.iter().position(|v| !v.is_finite()))
        {
            return Err(value_error(format!(
                "{what}: offset value {i} is not a finite number"
            )));
        }
        if off.as_ref().is_some_and(|o| o.len() != h.rows) {
            return Err(value_error(format!(
                "{what}: its offset has the wrong length"
            )));
        }
        depths_mm.push(*d);
        hs.push(h);
        offsets.push(off);
    }
    Ok((depths_mm, hs, offsets))
}

/// The capture of `reconstruct_stack` (little-endian f64), `rows` finite values.
fn stack_capture(capture: &[u8], rows: usize) -> PyResult<Vec<f64>> {
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
    Ok(g)
}

/// The offset of the layered capture: `joint_offset` (little-endian f32), else the sum of the
/// depths' offsets where each has one; `rows` finite values.
fn stack_joint_offset(
    joint_offset: Option<&[u8]>,
    offsets: &[Option<Vec<f32>>],
    rows: usize,
) -> PyResult<Option<Vec<f32>>> {
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
    if let Some(i) = joint_offset
        .as_ref()
        .and_then(|o| o.iter().position(|v| !v.is_finite()))
    {
        return Err(value_error(format!(
            "offset: value {i} is not a finite number"
        )));
    }
    Ok(joint_offset)
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
#[pyo3(signature = (rows, cols, indptr, indices, data, object, capture, offset, method, iters, tau, tv, threads, sensor=None, white_peak=None, planes=1))]
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
    sensor: Option<SceneArg>,
    white_peak: Option<f64>,
    planes: usize,
) -> PyResult<(Bound<'py, PyBytes>, String)> {
    use stscam::recon::Problem;
    let opts = solve_options(method, iters, tau, tv)?;
    let h = csr_from(rows, cols, indptr, indices, data, "H")?;
    check_object(object, planes, cols)?;
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
    let offset = match offset {
        Some(o) => decode_offset(o, rows)?,
        None => vec![0.0f32; rows],
    };
    for (x, &v) in g.iter_mut().zip(&offset) {
        *x -= f64::from(v);
    }
    let noise = sensor
        .map(|s| {
            let h_ones = h.mul_vec(&vec![1.0; h.cols]);
            discrepancy_sensor(py, &s, white_peak, &h_ones, &offset)
        })
        .transpose()?;
    stscam::limits::check_bytes(
        "H",
        "the reconstruction set-up (H transposed and the Gram matrix HᵀH)",
        stscam::recon::setup_bytes_bound(&h, threads.unwrap_or_else(rayon::current_num_threads)),
    )
    .map_err(value_error)?;
    let sol = run_job(py, threads, || {
        let problem =
            Problem::with_cancel(&h, object.0, planes * object.1, stscam::cancel::current());
        solve_one(&problem, planes, &g, &opts, noise.as_ref(), &offset)
    })?;
    Ok((f64_bytes(py, &sol.f), json(&sol.info)?))
}

/// One capture's reconstruction: by the discrepancy principle on `noise` (the black level
/// `offset`, no dark frame subtracted) when given, else with the fixed `opts`.
fn solve_one(
    problem: &stscam::recon::Problem,
    planes: usize,
    g: &[f64],
    opts: &stscam::recon::SolveOptions,
    noise: Option<&stscam::noise::SensorNoise>,
    offset: &[f32],
) -> stscam::recon::Solution {
    match noise {
        None => stscam::recon::solve_planes(problem, planes, g, opts),
        Some(noise) => stscam::recon::discrepancy::solve_discrepancy(
            problem,
            planes,
            g,
            opts,
            &stscam::recon::discrepancy::Sensor {
                noise,
                offset,
                dark_subtracted: false,
            },
        ),
    }
}

/// That an object of `object` = (width, height) pixels and `planes` planes (1, or 3 for a
/// colour H) matches H's `cols` columns.
fn check_object(object: (usize, usize), planes: usize, cols: usize) -> PyResult<()> {
    if !(planes == 1 || planes == 3) {
        return Err(value_error(format!("planes {planes}: expected 1 or 3")));
    }
    let n = object
        .0
        .checked_mul(object.1)
        .and_then(|n| n.checked_mul(planes));
    if n != Some(cols) {
        return Err(value_error(format!(
            "the object {}x{}{} has {} values but H has {cols} columns",
            object.0,
            object.1,
            if planes == 3 { "x3" } else { "" },
            object.0.saturating_mul(object.1).saturating_mul(planes)
        )));
    }
    Ok(())
}

/// An offset (float32 bytes) of `rows` finite values.
fn decode_offset(o: &[u8], rows: usize) -> PyResult<Vec<f32>> {
    let o: Vec<f32> = decode(o, "offset", f32::from_le_bytes)?;
    if o.len() != rows {
        return Err(value_error(format!(
            "offset: {} values but H has {rows} rows",
            o.len()
        )));
    }
    if let Some(i) = o.iter().position(|v| !v.is_finite()) {
        return Err(value_error(format!(
            "offset: value {i} is not a finite number"
        )));
    }
    Ok(o)
}

/// The discrepancy principle's sensor model: `scene`'s `[noise]` with the exposure from
/// `white_peak`, else from the all-white capture max(H·1 + offset) (as `stscam reconstruct`).
fn discrepancy_sensor(
    py: Python<'_>,
    scene: &SceneArg,
    white_peak: Option<f64>,
    h_ones: &[f64],
    offset: &[f32],
) -> PyResult<stscam::noise::SensorNoise> {
    let sys = load_job(py, scene)?;
    let peak = white_peak
        .unwrap_or_else(|| stscam::recon::discrepancy::white_peak_of_sums(h_ones, offset));
    stscam::noise::SensorNoise::checked(&sys.scene.noise, peak)
        .map_err(|e| value_error(format!("white_peak: {e}")))
}

/// A reconstruction problem set up once (Hᵀ and the Gram matrix HᵀH, as `stscam reconstruct`
/// builds them) for many captures: the Python `Operator`'s solver.
#[pyclass(frozen, module = "stscam._native")]
struct Solver {
    /// The set-up; each `solve` installs its own job's cancellation token in it (the token of
    /// the set-up's job is never set again, so a solve with it could not be interrupted).
    problem: std::sync::Mutex<stscam::recon::Problem>,
    rows: usize,
    /// Object planes: 1, or 3 for a colour H.
    planes: usize,
    /// H·1 (row sums), for the default exposure of the discrepancy principle.
    h_ones: Vec<f64>,
}

#[pymethods]
impl Solver {
    /// Sets up H (arrays as for `reconstruct`) for an object of `object` = (width, height).
    #[new]
    #[pyo3(signature = (rows, cols, indptr, indices, data, object, threads, planes=1))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        rows: usize,
        cols: usize,
        indptr: &[u8],
        indices: &[u8],
        data: &[u8],
        object: (usize, usize),
        threads: Option<usize>,
        planes: usize,
    ) -> PyResult<Self> {
        let h = csr_from(rows, cols, indptr, indices, data, "H")?;
        check_object(object, planes, cols)?;
        let threads_n = threads.unwrap_or_else(rayon::current_num_threads);
        stscam::limits::check_bytes(
            "H",
            "the reconstruction set-up (H transposed and the Gram matrix HᵀH)",
            stscam::recon::setup_bytes_bound(&h, threads_n),
        )
        .map_err(value_error)?;
        let problem = run_job(py, threads, || {
            stscam::recon::Problem::with_cancel(
                &h,
                object.0,
                planes * object.1,
                stscam::cancel::current(),
            )
        })?;
        Ok(Solver {
            problem: std::sync::Mutex::new(problem),
            rows,
            planes,
            h_ones: h.mul_vec(&vec![1.0; h.cols]),
        })
    }

    /// Solves for each of `frames` captures (float64 bytes, frame-major, the offset already
    /// subtracted) as `stscam reconstruct` does: the objects (float64 bytes, frame-major) and
    /// each frame's solver report (JSON).
    #[pyo3(signature = (capture, frames, method, iters, tau, tv, threads, offset=None, sensor=None, white_peak=None))]
    #[allow(clippy::too_many_arguments)]
    fn solve<'py>(
        &self,
        py: Python<'py>,
        capture: &[u8],
        frames: usize,
        method: &str,
        iters: Option<usize>,
        tau: f64,
        tv: &str,
        threads: Option<usize>,
        offset: Option<&[u8]>,
        sensor: Option<SceneArg>,
        white_peak: Option<f64>,
    ) -> PyResult<(Bound<'py, PyBytes>, Vec<String>)> {
        let opts = solve_options(method, iters, tau, tv)?;
        let offset = match offset {
            Some(o) => decode_offset(o, self.rows)?,
            None => vec![0.0f32; self.rows],
        };
        let noise = sensor
            .map(|s| discrepancy_sensor(py, &s, white_peak, &self.h_ones, &offset))
            .transpose()?;
        let g: Vec<f64> = decode(capture, "capture", f64::from_le_bytes)?;
        if Some(g.len()) != frames.checked_mul(self.rows) || frames == 0 {
            return Err(value_error(format!(
                "capture: {} values are not {frames} frames of H's {} rows",
                g.len(),
                self.rows
            )));
        }
        if let Some(i) = g.iter().position(|v| !v.is_finite()) {
            return Err(value_error(format!(
                "capture: value {i} is not a finite number"
            )));
        }
        let rows = self.rows;
        let sols = run_job(py, threads, || {
            // One solve at a time per set-up, each stopped by its own job's Ctrl-C.
            let mut problem = self.problem.lock().unwrap_or_else(|p| p.into_inner());
            problem.cancel = stscam::cancel::current();
            let sols = g
                .chunks_exact(rows)
                .map(|gi| solve_one(&problem, self.planes, gi, &opts, noise.as_ref(), &offset))
                .collect::<Vec<_>>();
            problem.cancel = stscam::cancel::Token::default();
            sols
        })?;
        let f: Vec<f64> = sols.iter().flat_map(|s| s.f.iter().copied()).collect();
        let infos = sols
            .iter()
            .map(|s| json(&s.info))
            .collect::<PyResult<_>>()?;
        Ok((f64_bytes(py, &f), infos))
    }
}

/// The TV kind of a `tv` argument (`"iso"` or `"aniso"`), as the CLI's `--tv`.
fn tv_kind(tv: &str) -> PyResult<stscam::recon::admm::TvKind> {
    stscam::options::parse("tv", tv).map_err(value_error)
}

/// The solver options of `reconstruct`'s arguments, checked as the CLI checks its flags.
fn solve_options(
    method: &str,
    iters: Option<usize>,
    tau: f64,
    tv: &str,
) -> PyResult<stscam::recon::SolveOptions> {
    use stscam::recon::{Method, SolveOptions};
    let method: Method = stscam::options::parse("method", method).map_err(value_error)?;
    let tv = tv_kind(tv)?;
    if !(tau.is_finite() && tau >= 0.0) {
        return Err(value_error(format!(
            "--tau {tau}: must be a non-negative number"
        )));
    }
    if iters == Some(0) {
        return Err(value_error("--iters: must be at least 1"));
    }
    Ok(SolveOptions {
        method,
        iters,
        tau_rel: tau,
        tv,
    })
}

/// The simulated Hadamard calibration (as `stscam calibrate`): H_est and the report.
#[pyfunction]
#[pyo3(signature = (scene, spp, seed, matrix, object, noise, dark_frame, render, threshold_sigma, threads, progress=None))]
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
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    use stscam::hadamard::{CalibrationJob, CaptureNoise, TrueMatrix, calibrate_scene};
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
        noise: if noise {
            CaptureNoise::Sensor
        } else {
            CaptureNoise::None
        },
        dark_frame,
        render_frames: render,
        threshold_sigma,
        progress: false,
    };
    let run = run_job_with(py, threads, progress.as_ref(), || {
        let sys = load(&scene)?;
        calibrate_scene(&sys, &job)
    })?
    .map_err(value_error)?;
    let d = csr_dict(py, &run.h_est)?;
    d.set_item("object", run.object)?;
    d.set_item("planes", run.planes)?;
    if run.planes == 1 {
        d.set_item("report", json(&run.reports[0])?)?;
    } else {
        let per: serde_json::Map<String, serde_json::Value> = stscam::matrix::PRIMARY_NAMES
            .iter()
            .zip(&run.reports)
            .map(|(n, r)| (n.to_string(), serde_json::to_value(r).unwrap_or_default()))
            .collect();
        d.set_item("report", json(&per)?)?;
    }
    Ok(d)
}

/// A design sweep (as `stscam sweep --json`): the rows as JSON.
#[pyfunction]
#[pyo3(signature = (scene, vary, fov_fraction, psnr, psnr_spp, threads, progress=None))]
#[allow(clippy::too_many_arguments)]
fn sweep(
    py: Python<'_>,
    scene: SceneArg,
    vary: Vec<String>,
    fov_fraction: f64,
    psnr: Option<String>,
    psnr_spp: u32,
    threads: Option<usize>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<String> {
    use stscam::sweep::{PsnrSettings, SweepSettings, VaryAxis, run_sweep_from};
    if scene.2.is_some() {
        return Err(value_error(
            "sweep: a scene with an array target cannot be swept (the sweep's PSNR uses a built-in target: --psnr)",
        ));
    }
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
    let res = run_job_with(py, threads, progress.as_ref(), || {
        run_sweep_from(scene_source(&scene), &scene.1, &axes, &set)
    })?
    .map_err(value_error)?;
    json(&res.rows)
}

/// Builds a dataset from a recipe into `out` (as `stscam dataset RECIPE --out OUT`), one
/// shard `I/N` of it if given; returns the run summary as JSON.
#[pyfunction]
#[pyo3(signature = (recipe, out, shard, resume, threads, progress=None, objects=None))]
fn build_dataset(
    py: Python<'_>,
    recipe: PathBuf,
    out: PathBuf,
    shard: Option<String>,
    resume: bool,
    threads: Option<usize>,
    progress: Option<Bound<'_, PyAny>>,
    objects: Option<(usize, usize, Vec<u8>, bool)>,
) -> PyResult<(String, Vec<String>)> {
    use stscam::dataset::{ObjectArrays, RunOptions, Shard, generate, plan_with_objects};
    let shard = shard
        .map(|s| Shard::parse(&s).map_err(|m| value_error(format!("--shard: {m}"))))
        .transpose()?;
    // Objects as arrays: (count, side, float32 little-endian values, linear).
    let arrays = objects
        .map(|(n, size, bytes, linear)| {
            let v = decode(&bytes, "objects", f32::from_le_bytes)?;
            ObjectArrays::new(v, n, size, linear).map_err(value_error)
        })
        .transpose()?;
    let (s, warnings) = run_job_with(py, threads, progress.as_ref(), || {
        let p = plan_with_objects(&recipe, arrays)?;
        let s = generate(
            &p,
            &RunOptions {
                out: out.clone(),
                shard,
                resume,
                progress: false,
            },
        )?;
        let w: Vec<String> = p
            .scenes
            .iter()
            .filter_map(|sc| coverage_warning(&sc.system, &format!("{}: ", sc.id)))
            .collect();
        Ok::<_, stscam::dataset::DatasetError>((s, w))
    })?
    .map_err(value_error)?;
    Ok((json(&s)?, warnings))
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

/// A built-in target (`stscam.target("letter:F@32")`): (width, height, display code values as
/// float32 bytes, row-major).
#[pyfunction]
fn target<'py>(py: Python<'py>, spec: &str) -> PyResult<(usize, usize, Bound<'py, PyBytes>)> {
    let t = stscam::targets::builtin_target(spec)
        .map_err(|e| value_error(format!("display.image: {e}")))?;
    Ok((t.width, t.height, f32_bytes(py, &t.values)))
}

/// The sensor noise model of `scene` applied to a clean capture (float64 bytes, capture
/// units), with the exposure fixed by `white_peak` (the all-white capture's brightest value),
/// exactly as datasets store a noisy capture (`stscam::noise::measure_capture`): float32 bytes.
#[pyfunction]
#[pyo3(signature = (scene, clean, seed, white_peak))]
fn sensor_noise<'py>(
    py: Python<'py>,
    scene: SceneArg,
    clean: &[u8],
    seed: u64,
    white_peak: f64,
) -> PyResult<Bound<'py, PyBytes>> {
    if !(white_peak.is_finite() && white_peak > 0.0) {
        return Err(value_error(format!(
            "white_peak {white_peak}: must be a positive number"
        )));
    }
    let clean: Vec<f64> = decode(clean, "clean", f64::from_le_bytes)?;
    if let Some(i) = clean.iter().position(|v| !v.is_finite()) {
        return Err(value_error(format!(
            "clean: value {i} is not a finite number"
        )));
    }
    let sys = load_job(py, &scene)?;
    let noise =
        stscam::noise::SensorNoise::checked(&sys.scene.noise, white_peak).map_err(value_error)?;
    let out = run_job(py, None, || {
        stscam::noise::measure_capture(&noise, &clean, seed)
    })?;
    Ok(f32_bytes(py, &out))
}

/// Writes float32 channels (name, bytes) of `width` x `height` as an EXR file, as stscam
/// writes its images (no timing attributes).
#[pyfunction]
fn write_exr(
    path: PathBuf,
    width: usize,
    height: usize,
    channels: Vec<(String, Vec<u8>)>,
) -> PyResult<()> {
    let mut chans = Vec::with_capacity(channels.len());
    for (name, b) in &channels {
        let data: Vec<f32> = decode(b, name, f32::from_le_bytes)?;
        if Some(data.len()) != width.checked_mul(height) {
            return Err(value_error(format!(
                "channel {name}: {} values, expected {height}x{width}",
                data.len()
            )));
        }
        chans.push(stscam::io::exr::ExrChannel {
            name: name.clone(),
            data,
        });
    }
    let bytes = stscam::io::exr::encode_exr(width, height, chans, &[]).map_err(value_error)?;
    stscam::io::write_atomic(&path, &bytes).map_err(|e| PyOSError::new_err(e.to_string()))
}

/// Reads a 16-bit grey or RGB PNG written by stscam (dataset captures, frontal images,
/// masks): (width, height, channels, little-endian u16 samples, channels interleaved). The
/// file is checked like every input (a regular file of bounded size) and the decoder's memory
/// is bounded before decoding.
#[pyfunction]
fn read_png16<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(usize, usize, usize, Bound<'py, PyBytes>)> {
    let bytes = stscam::io::input::read_input(&path, stscam::io::input::MAX_BINARY_BYTES)
        .map_err(value_error)?;
    let bad = |m: String| value_error(format!("{}: {m}", path.display()));
    let limits = png::Limits { bytes: 1 << 30 };
    let dec = png::Decoder::new_with_limits(std::io::Cursor::new(&bytes), limits);
    let mut reader = dec
        .read_info()
        .map_err(|e| bad(format!("not a PNG stscam reads: {e}")))?;
    let info = reader.info();
    let (w, h) = (info.width as usize, info.height as usize);
    let ch = match (info.color_type, info.bit_depth) {
        (png::ColorType::Grayscale, png::BitDepth::Sixteen) => 1,
        (png::ColorType::Rgb, png::BitDepth::Sixteen) => 3,
        (c, b) => return Err(bad(format!("{c:?} {b:?}: expected 16-bit grey or RGB"))),
    };
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| bad("too large".into()))?;
    let mut buf = vec![0u8; size];
    reader
        .next_frame(&mut buf)
        .map_err(|e| bad(format!("cannot decode: {e}")))?;
    buf.truncate(w * h * ch * 2);
    let le: Vec<u8> = buf.chunks_exact(2).flat_map(|b| [b[1], b[0]]).collect();
    Ok((w, h, ch, PyBytes::new(py, &le)))
}

/// Runs the `stscam` command line (`argv` with the program name first) as the binary does,
/// with the GIL released: its exit code.
#[pyfunction]
fn cli(py: Python<'_>, argv: Vec<std::ffi::OsString>) -> u8 {
    py.allow_threads(|| stscam::jobs::cli::run(argv))
}

/// Targets held in memory for `evaluate`: (name, image) pairs, converted with the scene's
/// display `gamma` into the linear planes the metrics compare (as a PNG or EXR target file).
fn image_targets(
    images: &[(String, ImageArg)],
    gamma: f64,
) -> PyResult<Vec<stscam::design::evaluate::Target>> {
    images
        .iter()
        .enumerate()
        .map(|(i, (name, img))| {
            let v = image_values(img, &format!("targets[{i}]")).map_err(value_error)?;
            // `image_values` checked that the channels are 1 or 3: one object plane each.
            let (w, h, c, _, linear) = *img;
            Ok(stscam::design::evaluate::Target::Image {
                name: name.clone(),
                width: w,
                height: h,
                planes: c,
                values: stscam::display::Display::planes_of(&v, c, linear, gamma, c),
            })
        })
        .collect()
}

/// One design's metrics (as `stscam evaluate --json`): (the JSON object, warnings). `images`
/// are targets held in memory, evaluated after the `targets` list's (or alone when it is None).
#[pyfunction]
#[pyo3(signature = (scene, metrics, object_px, binning, spp, replicates, targets, images, depth_mm, white_peak, draw, draws, require, seed, threads, progress=None))]
#[allow(clippy::too_many_arguments)]
fn evaluate(
    py: Python<'_>,
    scene: SceneArg,
    metrics: String,
    object_px: u32,
    binning: u32,
    spp: u32,
    replicates: usize,
    targets: Option<String>,
    images: Vec<(String, ImageArg)>,
    depth_mm: Option<String>,
    white_peak: Option<f64>,
    draw: Vec<String>,
    draws: usize,
    require: Vec<String>,
    seed: u64,
    threads: Option<usize>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<(String, Vec<String>)> {
    use stscam::jobs::evaluate::{EvaluateOptions, evaluation, json_object};
    if scene.2.is_some() {
        return Err(value_error(
            "evaluate: the scene shows an array on its display; pass arrays as targets= instead (the metrics show each target in turn)",
        ));
    }
    let o = EvaluateOptions {
        scene: stscam::jobs::SceneArgs {
            scene: scene.0.as_ref().map(PathBuf::from),
            set: scene.1.clone(),
        },
        metrics,
        json: true,
        object_px,
        binning,
        spp,
        replicates,
        targets,
        depth_mm,
        white_peak,
        draw,
        draws,
        require,
        seed,
        threads,
    };
    let gamma = scene_source(&scene)
        .load(&scene.1)
        .map_err(value_error)?
        .scene
        .display
        .gamma;
    let images = image_targets(&images, gamma)?;
    let ev = run_job_with(py, threads, progress.as_ref(), || {
        evaluation(&o, scene_source(&scene), gamma, images)
    })?
    .map_err(value_error)?;
    let obj = json_object(&ev.1);
    Ok((json(&obj)?, ev.1.warnings))
}

/// A design study held as TOML text: (text, the name messages blame, the directory its
/// relative paths resolve against).
type StudyText = (String, String, String);

/// Optimises a design study (as `stscam optimize STUDY --out OUT`): the files are written
/// into `out` as the CLI writes them; returns the parameters' names (each one's first key, as
/// `history.csv` heads its column). Progress counts evaluations.
#[pyfunction]
#[pyo3(signature = (study, text, budget, seed, out, resume, skip_final, threads, progress=None))]
#[allow(clippy::too_many_arguments)]
fn optimize(
    py: Python<'_>,
    study: Option<PathBuf>,
    text: Option<StudyText>,
    budget: usize,
    seed: u64,
    out: PathBuf,
    resume: bool,
    skip_final: bool,
    threads: Option<usize>,
    progress: Option<Bound<'_, PyAny>>,
) -> PyResult<Vec<String>> {
    use stscam::design::study::Study;
    use stscam::jobs::optimize::{OptimizeOptions, run_study};
    let (s, path) = match (&study, &text) {
        (Some(p), None) => (Study::load(p), p.clone()),
        (None, Some((t, name, dir))) => {
            (Study::parse(t, name, Path::new(dir)), PathBuf::from(name))
        }
        _ => return Err(value_error("optimize: give a study file or a study dict")),
    };
    let s = s.map_err(value_error)?;
    let o = OptimizeOptions {
        study: path,
        budget,
        seed,
        out,
        resume,
        skip_final,
        threads,
        ..OptimizeOptions::local(PathBuf::new(), budget, seed, PathBuf::new())
    };
    run_job_with(py, threads, progress.as_ref(), || {
        let count = stscam::progress::Progress::new(false, budget as u64, "evaluations");
        run_study(&s, &o, &|_, _| count.inc(1))
    })?
    .map_err(value_error)?;
    Ok(s.parameters.iter().map(|p| p.keys[0].clone()).collect())
}

/// The shipped scenes: [(name, TOML text)].
#[pyfunction]
fn shipped_scenes() -> Vec<(&'static str, &'static str)> {
    stscam::scene::SHIPPED_SCENES.to_vec()
}

/// The extension module.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("VERSION", stscam::VERSION)?;
    // The limits the Python layer applies before it converts arrays (one job's memory, a
    // dataset's samples), so an oversized call is refused before it allocates.
    m.add(
        "MAX_JOB_BYTES",
        u64::try_from(stscam::limits::MAX_JOB_BYTES).unwrap_or(u64::MAX),
    )?;
    m.add("MAX_SAMPLES", stscam::dataset::recipe::MAX_SAMPLES)?;
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
    m.add_function(wrap_pyfunction!(evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(optimize, m)?)?;
    m.add_function(wrap_pyfunction!(build_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(merge_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(read_exr, m)?)?;
    m.add_function(wrap_pyfunction!(target, m)?)?;
    m.add_class::<Solver>()?;
    m.add_function(wrap_pyfunction!(shipped_scenes, m)?)?;
    m.add_function(wrap_pyfunction!(cli, m)?)?;
    m.add_function(wrap_pyfunction!(coverage, m)?)?;
    m.add_function(wrap_pyfunction!(sensor_noise, m)?)?;
    m.add_function(wrap_pyfunction!(write_exr, m)?)?;
    m.add_function(wrap_pyfunction!(read_png16, m)?)?;
    Ok(())
}
