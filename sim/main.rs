//! `stscam` command line: the parser and exit codes live in `stscam::jobs::cli` (shared with
//! the Python package's `stscam` command); bad input (scene, overrides, images, arguments)
//! prints one line and exits with code 2; nothing is written to `--out` unless the whole job
//! succeeded (the one exception: `matrix --check` writes H and then exits 1 if the check
//! fails, so the files can be inspected).

use std::process::ExitCode;

fn main() -> ExitCode {
    ExitCode::from(stscam::jobs::cli::run(std::env::args_os()))
}
