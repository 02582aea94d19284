//! Helpers shared by the integration tests: run the real `stscam` binary.

#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

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

/// Writes `text` to `dir/name` and returns the path.
pub fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Every file under `root` (relative path → bytes).
pub fn tree(root: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

/// Asserts that two folders hold the same files with the same bytes.
pub fn assert_same_tree(a: &Path, b: &Path) {
    let (ta, tb) = (tree(a), tree(b));
    assert_eq!(
        ta.keys().collect::<Vec<_>>(),
        tb.keys().collect::<Vec<_>>(),
        "different file lists"
    );
    for (k, v) in &ta {
        assert!(v == &tb[k], "{k} differs");
    }
}

/// Starts `stscam dataset RECIPE --out OUT`, waits until `OUT/train` holds at least
/// `min_files` files (at most 120 s), SIGKILLs it and asserts that it had not finished.
pub fn dataset_killed_midway(recipe: &Path, out: &Path, min_files: usize) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_stscam"))
        .args([
            "dataset",
            recipe.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = std::time::Instant::now();
    loop {
        let n = files_in(&out.join("train")).len();
        if n >= min_files || t0.elapsed().as_secs() > 120 {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    child.kill().unwrap(); // SIGKILL on Unix
    let status = child.wait().unwrap();
    assert!(!status.success(), "the run finished before it was killed");
    assert!(out.join(".stscam-run.json").is_file());
    assert!(!out.join("dataset.json").exists());
}

/// `stscam dataset merge SHARDS... --out OUT`, asserted to succeed.
pub fn merge_shards(shards: &[PathBuf], out: &Path) {
    let mut args = vec!["dataset", "merge"];
    args.extend(shards.iter().map(|d| d.to_str().unwrap()));
    args.extend(["--out", out.to_str().unwrap()]);
    stscam_ok(&args);
}

/// `scene` (relative to the repository) at a `crop`×`crop` crop with the paper's field of view,
/// with further `--set` overrides.
pub fn crop_system(scene: &str, crop: u32, extra: &[&str]) -> stscam::system::System {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(scene);
    let mut sets = vec![
        format!("sensor.crop_px=[{crop},{crop}]"),
        format!("sensor.pitch_um={}", 4.8 * 440.0 / f64::from(crop)),
    ];
    sets.extend(extra.iter().map(|s| s.to_string()));
    let ls = stscam::scene::load_scene(Some(&path), &sets).expect("scene");
    stscam::system::System::build(&ls).expect("system")
}

/// Mean and standard error of the mean.
pub fn mean_sem(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// `f` run in a pool of `threads` threads.
pub fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}
