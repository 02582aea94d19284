//! One library function per `stscam` command. Each takes typed options (the structs the CLI
//! parses with clap, so a caller can also build them field by field), computes with the
//! library's modules, writes its files (under temporary names, renamed into place only when
//! all of them were written) and sends its report lines to a [`Console`]; failures are a typed
//! [`JobError`] whose code is the CLI's exit code (2 bad input, 1 a failed write or check).
//! Argument parsing and exit codes are in [`cli`], shared by the binary (`sim/main.rs`) and
//! the Python package's `stscam` command.
//!
//! Layer: one job per command: typed options (clap), reports, exit codes.
//! May depend on: every layer below (docs/design.md, "Crates"; checked by `tests/it/layers.rs`).
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod bench;
pub mod calibrate;
pub mod cli;
pub mod compare;
pub mod dataset;
pub mod demo;
pub mod evaluate;
pub mod grating;
pub mod info;
pub mod matrix;
pub mod optimize;
pub mod probe;
pub mod reconstruct;
pub mod render;
pub mod stray;
pub mod sweep;
pub mod tolerance;
pub mod validate;
// The layers below, under the names this crate's modules use (`crate::io::…`).
use stscam_base::noise;
#[cfg(test)]
use stscam_base::options;
use stscam_base::{VERSION, limits, numfmt, sampler, sparse, spectra, targets};
use stscam_io as io;
use stscam_io::{plot, stack};
use stscam_optics as optics;
use stscam_recon as recon;
use stscam_scene as scene;
use stscam_studies::{analytic, capture, colour_demo, grating_spectrum, hadamard};
use stscam_tracer::{analysis, colour, output, system};
use stscam_world as world;
use stscam_world::display;

use std::path::PathBuf;

use clap::{Args, Subcommand, ValueEnum};

use crate::scene::{LoadedScene, load_scene};
use crate::system::System;

/// Where a job's report goes: standard output (tables, JSON) and standard error (warnings,
/// the closing "wrote …" line).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Console {
    /// Print to the terminal (the CLI).
    Terminal,
    /// Drop every line (library callers that read the files or the returned values).
    Silent,
}

impl Console {
    /// One line of the job's output proper (a table, JSON).
    pub fn out(&self, line: std::fmt::Arguments) {
        if *self == Console::Terminal {
            // A closed pipe (`stscam probe … --json | head -1`) is not an error of the job:
            // the line is dropped instead of panicking in `println!`. Any other failure (a
            // full disk, `> /dev/full`) is kept and fails the command once the job is done
            // ([`stdout_failure`]), so a report that was lost never exits 0.
            use std::io::Write;
            if let Err(e) = writeln!(std::io::stdout().lock(), "{line}") {
                note_stdout_error(&e);
            }
        }
    }

    /// One line of report or warning.
    pub fn err(&self, line: std::fmt::Arguments) {
        if *self == Console::Terminal {
            eprintln!("{line}");
        }
    }
}

/// The first failure to write the report to standard output (other than a closed pipe).
static STDOUT_ERROR: std::sync::Mutex<Option<String>> = std::sync::Mutex::new(None);

/// Keeps `e`, a failed write to standard output, unless it is a closed pipe (`| head`), which
/// is the reader's choice, or an earlier failure is kept already.
fn note_stdout_error(e: &std::io::Error) {
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        return;
    }
    let mut kept = STDOUT_ERROR.lock().unwrap_or_else(|p| p.into_inner());
    kept.get_or_insert_with(|| format!("cannot write the report to standard output: {e}"));
}

/// Flushes standard output and returns the first failure to write the report there (a
/// closed pipe is not one), as the one-line message the CLI prints before exiting 1.
pub fn stdout_failure() -> Option<String> {
    use std::io::Write;
    if let Err(e) = std::io::stdout().lock().flush() {
        note_stdout_error(&e);
    }
    STDOUT_ERROR
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .clone()
}

/// A job that did not finish: the CLI's exit code (2 bad input, 1 a failed write or check)
/// and one line naming the file, key or argument and the problem.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct JobError {
    /// Exit code of the CLI.
    pub code: u8,
    /// The one-line message (without the `error: ` prefix).
    pub message: String,
}

impl JobError {
    /// Whether the input was at fault (exit code 2), not a write or a failed check.
    pub fn is_bad_input(&self) -> bool {
        self.code == 2
    }
}

impl std::fmt::Display for JobError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for JobError {}

/// The jobs' own name for [`JobError`].
type Failure = JobError;

/// Scene selection shared by every command.
#[derive(Args, Debug, Clone)]
pub struct SceneArgs {
    /// Scene file (TOML); keys it omits come from the embedded paper scene. Default: the
    /// embedded `scenes/paper-2022.toml`.
    pub scene: Option<PathBuf>,
    /// Override a scene key, e.g. `--set plate.thickness_mm=3` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

/// Monte Carlo and threading options shared by the commands that trace.
#[derive(Args, Debug, Clone)]
pub struct RunArgs {
    /// Samples (camera paths) per pixel.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Seed of the sampler (and of the sensor noise, where there is noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

impl RunArgs {
    /// (spp, seed, threads) after checking that spp is at least 1.
    pub fn checked(&self) -> Result<(u32, u64, Option<usize>), JobError> {
        if self.spp == 0 {
            return Err(bad_input("--spp: must be at least 1"));
        }
        Ok((self.spp, self.seed, self.threads))
    }
}

/// Most timed runs of a benchmark figure (`bench recon --runs`).
pub(crate) const MAX_RUNS: usize = 1000;

/// Longest time budget per estimator of `bench render` (`--budget-s`): one day.
pub(crate) const MAX_BUDGET_S: f64 = 86_400.0;

/// Most field angles of `validate analytic --fields`.
pub(crate) const MAX_FIELDS: usize = 100_000;

/// Most iterations of `reconstruct --iters`.
pub(crate) const MAX_ITERS: usize = 1_000_000;

pub(crate) fn bad_input(message: impl Into<String>) -> Failure {
    Failure {
        code: 2,
        message: message.into(),
    }
}

/// A job beyond a resource limit: bad input.
pub(crate) fn limit(e: crate::limits::LimitError) -> Failure {
    bad_input(e.to_string())
}

pub(crate) fn load(args: &SceneArgs) -> Result<(LoadedScene, System), Failure> {
    let ls = load_scene(args.scene.as_deref(), &args.set).map_err(|e| bad_input(e.to_string()))?;
    let t0 = std::time::Instant::now();
    let sys = System::build(&ls).map_err(|e| bad_input(e.to_string()))?;
    if let Some(r) = sys.waveguide.rcwa.as_deref() {
        let c = r.cache();
        let whence = match (&c.path, c.from_cache) {
            (Some(p), true) => format!("read from {}", p.display()),
            (Some(p), false) => format!(
                "built in {:.1} s, cached at {}",
                t0.elapsed().as_secs_f64(),
                p.display()
            ),
            (None, _) => format!(
                "built in {:.1} s (no cache directory)",
                t0.elapsed().as_secs_f64()
            ),
        };
        eprintln!(
            "stscam: hoe.model = rcwa: coupling tables {whence}; interpolation error <= {:.2e} (measured at {} off-grid points per grating), window edge step {:.2e}",
            r.max_error(),
            crate::system::RCWA_ERROR_PROBES,
            r.edge_jump()
        );
    }
    Ok((ls, sys))
}

pub(crate) fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool, Failure> {
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        crate::limits::check_threads(t).map_err(limit)?;
        b = b.num_threads(t);
    }
    b.build().map_err(|e| Failure {
        code: 1,
        message: format!("cannot start worker threads: {e}"),
    })
}

pub(crate) fn to_json<T: serde::Serialize>(v: &T) -> Result<String, Failure> {
    serde_json::to_string_pretty(v).map_err(|e| Failure {
        code: 1,
        message: format!("cannot encode JSON: {e}"),
    })
}

pub(crate) fn check_out_dir(out: &std::path::Path) -> Result<(), Failure> {
    if out.exists() && !out.is_dir() {
        return Err(bad_input(format!(
            "{}: --out exists and is not a directory",
            out.display()
        )));
    }
    Ok(())
}

/// Writes named in-memory files into `out` as one unit (all or nothing).
pub(crate) fn write_files(
    out: &std::path::Path,
    files: &[(String, Vec<u8>)],
) -> Result<(), Failure> {
    let refs: Vec<(&str, &[u8])> = files
        .iter()
        .map(|(n, b)| (n.as_str(), b.as_slice()))
        .collect();
    crate::io::write_all_atomic(out, &refs).map_err(write_failure)
}

pub(crate) fn write_failure(e: impl std::fmt::Display) -> Failure {
    Failure {
        code: 1,
        message: e.to_string(),
    }
}

/// Warns on stderr when part of the object has no strong replica inside the crop
/// (`analysis::object_coverage`); `what` names the scene in the message.
pub(crate) fn warn_coverage(sys: &System, what: &str, con: &Console) {
    if !sys.scene.display.enabled {
        return;
    }
    if let Some(w) = crate::analysis::object_coverage(sys).warning() {
        con.err(format_args!("{what}{w}"));
    }
}

pub(crate) fn parse_object(spec: &str) -> Result<(usize, usize), Failure> {
    let parsed = spec
        .split_once(['x', 'X'])
        .and_then(|(a, b)| Some((a.trim().parse().ok()?, b.trim().parse().ok()?)))
        .filter(|&(a, b): &(usize, usize)| a > 0 && b > 0 && a.checked_mul(b).is_some());
    parsed.ok_or_else(|| bad_input(format!("--object {spec}: expected WxH, e.g. 64x64")))
}

/// Reads a capture as one vector in H's row order (EXR channels in file order, or .npy).
pub(crate) fn load_capture(path: &std::path::Path) -> Result<Vec<f64>, Failure> {
    let is_npy = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("npy"));
    let values: Vec<f64> = if is_npy {
        let (_, v) = crate::io::npz::read_npy_f32(path).map_err(|e| bad_input(e.to_string()))?;
        crate::io::check_finite(path, "value", &v).map_err(|e| bad_input(e.to_string()))?;
        v.into_iter().map(f64::from).collect()
    } else {
        let (_, _, chans) = crate::io::read_exr(path).map_err(|e| bad_input(e.to_string()))?;
        // Sensor channels only (Y or R, G, B), in H's channel-major row order.
        let order = ["Y", "R", "G", "B"];
        let mut v = Vec::new();
        for name in order {
            if let Some(c) = chans.iter().find(|c| c.name == name) {
                crate::io::check_finite(path, &format!("channel {name}: value"), &c.data)
                    .map_err(|e| bad_input(e.to_string()))?;
                v.extend(c.data.iter().map(|&x| f64::from(x)));
            }
        }
        if v.is_empty() {
            return Err(bad_input(format!(
                "{}: no Y or R, G, B channel",
                path.display()
            )));
        }
        v
    };
    Ok(values)
}

/// Linear intensities of a truth image or built-in target (`planes` = 3: the object planes
/// R, G, B of a colour H, primary-major).
pub(crate) fn load_truth(
    spec: &str,
    gamma: f64,
    w: usize,
    h: usize,
    planes: usize,
) -> Result<Vec<f64>, Failure> {
    use crate::display::Display;
    let (tw, th, v) = if crate::system::is_image_path(spec) {
        let path = std::path::Path::new(spec);
        let img = crate::io::load_image(path).map_err(|e| bad_input(e.to_string()))?;
        crate::io::check_finite(path, "value", &img.values)
            .map_err(|e| bad_input(format!("--truth: {e}")))?;
        let v = Display::planes_of(&img.values, img.channels, img.linear, gamma, planes);
        (img.width, img.height, v)
    } else {
        let (tw, th, c, values) =
            crate::targets::builtin_image(spec).map_err(|e| bad_input(format!("--truth: {e}")))?;
        (tw, th, Display::planes_of(&values, c, false, gamma, planes))
    };
    if (tw, th) != (w, h) {
        return Err(bad_input(format!(
            "--truth {spec}: size {tw}x{th} differs from the object size {w}x{h}"
        )));
    }
    Ok(v)
}
