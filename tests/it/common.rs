//! Helpers shared by the integration tests: run the real `stscam` binary.

#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};

/// Runs `stscam` with `args`.
pub fn stscam(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_stscam"))
        .args(args)
        .output()
        .expect("run stscam")
}

/// Runs `stscam`, asserts success and returns stdout.
pub fn stscam_ok(args: &[&str]) -> String {
    let out = stscam(args);
    assert!(
        out.status.success(),
        "stscam {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("utf-8")
}

/// Runs `stscam ... --json` and parses stdout.
pub fn stscam_json(args: &[&str]) -> serde_json::Value {
    serde_json::from_str(&stscam_ok(args)).expect("json")
}

/// Lists the files under `dir` (empty if it does not exist).
pub fn files_in(dir: &Path) -> Vec<String> {
    match std::fs::read_dir(dir) {
        Ok(rd) => rd
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect(),
        Err(_) => Vec::new(),
    }
}

/// A JSON array of numbers as a Vec.
pub fn vec3(v: &serde_json::Value) -> [f64; 3] {
    let a = v.as_array().expect("array");
    [
        a[0].as_f64().unwrap(),
        a[1].as_f64().unwrap(),
        a[2].as_f64().unwrap(),
    ]
}
