//! `stscam` command line: the parser and exit codes live in `stscam::jobs::cli` (shared with
//! the Python package's `stscam` command); bad input (scene, overrides, images, arguments)
//! prints one line and exits with code 2; nothing is written to `--out` unless the whole job
//! succeeded (the one exception: `matrix --check` writes H and then exits 1 if the check
//! fails, so the files can be inspected).

use std::process::ExitCode;

/// Restores the default action of SIGPIPE (the Rust runtime ignores it), so that a closed
/// standard output (`stscam probe … --json | head -1`) ends the process quietly, as it does
/// for other command-line tools, instead of failing writes.
#[cfg(unix)]
fn default_sigpipe() {
    unsafe extern "C" {
        fn signal(signum: i32, handler: usize) -> usize;
    }
    const SIGPIPE: i32 = 13;
    const SIG_DFL: usize = 0;
    // SAFETY: `signal` is async-signal-safe and called before any thread is started.
    unsafe {
        signal(SIGPIPE, SIG_DFL);
    }
}

fn main() -> ExitCode {
    #[cfg(unix)]
    default_sigpipe();
    ExitCode::from(stscam::jobs::cli::run(std::env::args_os()))
}
