//! Hostile and faulty inputs (issue 13), one test per class of defect: sizes a user controls
//! are bounded before work starts, archives and files are checked before they are read,
//! non-finite data is refused with the file and the first bad index, write errors exit 1 and
//! a dataset folder is locked, messages blame the key the user set, and progress shows
//! without a terminal.

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use crate::common::write;
use crate::common::{files_in, stscam};
use crate::dataset::recipe;

/// A finished run's exit code and stderr, asserting that it took under `limit_s` seconds
/// (a hang on a FIFO or a read of a device fails here instead of blocking the suite).
fn run_within(args: &[&str], limit_s: f64) -> (Option<i32>, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_stscam"))
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run stscam");
    let start = Instant::now();
    loop {
        if child.try_wait().expect("wait").is_some() {
            break;
        }
        if start.elapsed().as_secs_f64() > limit_s {
            let _ = child.kill();
            let _ = child.wait();
            panic!("stscam {args:?} did not finish within {limit_s} s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().expect("output");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).trim_end().to_string(),
    )
}

/// Asserts exit code 2 with a single stderr line containing every one of `expect`.
fn refused(args: &[&str], expect: &[&str]) -> String {
    let (code, err) = run_within(args, 60.0);
    assert_eq!(code, Some(2), "{args:?}: {err}");
    assert_eq!(err.lines().count(), 1, "{args:?}: not one line: {err}");
    for e in expect {
        assert!(err.contains(e), "{args:?}: {err:?} lacks {e:?}");
    }
    err
}

/// A temporary folder and the (not yet existing) output folder inside it.
fn scratch() -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    (dir, out)
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// A float32 `.npy` of the given values.
fn npy(path: &Path, values: &[f32]) {
    let bytes = stscam::io::encode_npy_f32(path, &[values.len()], values).unwrap();
    std::fs::write(path, bytes).unwrap();
}

/// A CSR `.npz` holding the diagonal matrix diag(values).
fn diagonal_npz(path: &Path, values: &[f32]) {
    let n = values.len();
    let indptr: Vec<u64> = (0..=n as u64).collect();
    let indices: Vec<u32> = (0..n as u32).collect();
    let bytes = stscam::io::encode_csr_npz(path, n, n, &indptr, &indices, values).unwrap();
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn sizes_users_control_are_bounded_before_work_starts() {
    let (dir, out) = scratch();
    let o = p(&out);
    // 100000 threads used to spawn for minutes; 4·10⁹ spp ran for ever.
    refused(
        &["render", "--threads", "100000", "--out", o],
        &["--threads: must be in 1..=1024, got 100000"],
    );
    refused(
        &["render", "--spp", "4000000000", "--out", o],
        &[
            "--spp: the job needs 774400000000000 camera paths",
            "1099511627776",
        ],
    );
    refused(
        &["matrix", "--spp", "4000000000", "--out", o],
        &["--spp: the job needs"],
    );
    refused(
        &[
            "sweep",
            "--vary",
            "bottom_hoe.height_mm=10:80:2",
            "--psnr",
            "letter:A",
            "--psnr-spp",
            "4000000000",
            "--out",
            o,
        ],
        &["--psnr-spp: the job needs"],
    );
    // Spectral bins over a wide band on the largest crop: 181 GiB of arrays.
    refused(
        &[
            "render",
            "--spectral",
            "--spp",
            "1",
            "--set",
            "sampling.lambda_min_nm=200",
            "--set",
            "sampling.lambda_max_nm=2000",
            "--set",
            "sensor.width_px=8192",
            "--set",
            "sensor.height_px=8192",
            "--set",
            "sensor.crop_px=8192",
            "--out",
            o,
        ],
        &[
            "sensor.crop_px: the capture (8192x8192 px, 181 channels",
            "16 GiB",
        ],
    );
    refused(
        &[
            "validate",
            "analytic",
            "--fields",
            "100000000000",
            "--out",
            o,
        ],
        &["--fields: must be in 50..=100000"],
    );
    refused(
        &["bench", "render", "--budget-s", "inf", "--out", o],
        &["--budget-s in (0, 86400]"],
    );
    // Datasets: 10⁸ samples used to abort on a failed allocation; 1000 distinct scenes
    // (one H each, all kept) likewise.
    let r = write(
        dir.path(),
        "many.toml",
        &recipe("many", 100_000_000, "matrix", "none", ""),
    );
    refused(
        &["dataset", p(&r), "--out", o],
        &["many.toml: samples: must be in 1..=2000000, got 100000000"],
    );
    let vary: String = [
        "display.distance_mm",
        "display.center_mm.0",
        "plate.thickness_mm",
    ]
    .iter()
    .map(|k| {
        let vals: Vec<String> = (1..=10).map(|i| format!("{}.0", i + 1)).collect();
        format!(
            "\n[[vary]]\nkey = \"{k}\"\nvalues = [{}]\n",
            vals.join(", ")
        )
    })
    .collect();
    let r = write(
        dir.path(),
        "scenes.toml",
        &recipe("scenes", 10, "matrix", "none", &vary),
    );
    refused(
        &["dataset", p(&r), "--out", o],
        &["scenes.toml: vary: the `values` lists give more than 256 distinct scenes"],
    );
    // A tiny archive whose single dense row makes HᵀH 2^32 entries (137 GiB): refused
    // before the set-up; the same matrix with 2^10 columns is reconstructed.
    let dense = |cols: usize| {
        let h = dir.path().join(format!("dense{cols}.npz"));
        let indices: Vec<u32> = (0..cols as u32).collect();
        let bytes =
            stscam::io::encode_csr_npz(&h, 1, cols, &[0, cols as u64], &indices, &vec![1.0; cols])
                .unwrap();
        std::fs::write(&h, bytes).unwrap();
        h
    };
    let cap = dir.path().join("g.npy");
    npy(&cap, &[1.0]);
    let h = dense(1 << 16);
    refused(
        &[
            "reconstruct",
            "--matrix",
            p(&h),
            "--capture",
            p(&cap),
            "--object",
            "256x256",
            "--out",
            o,
        ],
        &[
            "dense65536.npz: --matrix: the reconstruction set-up",
            "GiB, more than the 16 GiB",
        ],
    );
    assert!(files_in(&out).is_empty());
    let h = dense(1 << 10);
    let (code, err) = run_within(
        &[
            "reconstruct",
            "--matrix",
            p(&h),
            "--capture",
            p(&cap),
            "--object",
            "32x32",
            "--out",
            o,
        ],
        60.0,
    );
    assert_eq!(code, Some(0), "{err}");
}

#[test]
fn archives_are_checked_before_inflating_and_files_before_reading() {
    use std::io::Write as _;
    let (dir, out) = scratch();
    let o = p(&out);
    let cap = dir.path().join("g.npy");
    npy(&cap, &[1.0, 2.0]);
    // A zip bomb: data.npy declares 64 MiB (deflated to a few KiB) while indptr announces
    // 2 stored entries.
    let build = |name: &str, data_values: usize| {
        let path = dir.path().join(name);
        let good = dir.path().join("good.npz");
        diagonal_npz(&good, &[1.0, 1.0]);
        let mut src = zip::ZipArchive::new(std::fs::File::open(&good).unwrap()).unwrap();
        let mut z = zip::ZipWriter::new(std::fs::File::create(&path).unwrap());
        let opts = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Deflated);
        for i in 0..src.len() {
            let mut f = src.by_index(i).unwrap();
            let name = f.name().unwrap().to_string();
            z.start_file(name.as_str(), opts).unwrap();
            if name == "data.npy" {
                let zeros = vec![0f32; data_values];
                z.write_all(&stscam::io::encode_npy_f32(&path, &[data_values], &zeros).unwrap())
                    .unwrap();
            } else {
                std::io::copy(&mut f, &mut z).unwrap();
            }
        }
        z.finish().unwrap();
        path
    };
    let bomb = build("bomb.npz", 16 << 20);
    assert!(std::fs::metadata(&bomb).unwrap().len() < 1 << 20);
    refused(
        &[
            "reconstruct",
            "--matrix",
            p(&bomb),
            "--capture",
            p(&cap),
            "--object",
            "2x1",
            "--out",
            o,
        ],
        &[
            "bomb.npz: data.npy: declares 67108992 bytes uncompressed",
            "nnz = 2 values (the last entry of indptr.npy)",
            "refused before inflating",
        ],
    );
    // Control: the same construction with the right size is read (then fails on nothing).
    let fine = build("fine.npz", 2);
    let (code, err) = run_within(
        &[
            "reconstruct",
            "--matrix",
            p(&fine),
            "--capture",
            p(&cap),
            "--object",
            "2x1",
            "--out",
            o,
        ],
        60.0,
    );
    assert_eq!(code, Some(0), "{err}");

    // Devices, FIFOs and huge (sparse) files, as every kind of input.
    let fifo = dir.path().join("fifo");
    let made = Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .is_ok_and(|s| s.success());
    let big = dir.path().join("big.toml");
    std::fs::File::create(&big)
        .unwrap()
        .set_len(5 << 30)
        .unwrap();
    let f = p(&fifo);
    let mut cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["render", "/dev/zero", "--out", o],
            "/dev/zero: cannot read scene file: is a device",
        ),
        (
            vec!["render", p(&big), "--out", o],
            "is 5368709120 bytes, more than the 67108864 bytes",
        ),
        (
            vec!["dataset", "/dev/zero", "--out", o],
            "/dev/zero: is a device, not a regular file",
        ),
        (
            vec![
                "reconstruct",
                "--matrix",
                "/dev/zero",
                "--capture",
                p(&cap),
                "--out",
                o,
            ],
            "/dev/zero: is a device",
        ),
        (
            vec![
                "reconstruct",
                "--matrix",
                p(&fine),
                "--capture",
                "/dev/urandom",
                "--object",
                "2x1",
                "--out",
                o,
            ],
            "/dev/urandom: is a device",
        ),
        (
            vec!["compare", "/dev/zero", "/dev/zero"],
            "/dev/zero: is a device",
        ),
    ];
    if made {
        cases.extend([
            (
                vec!["render", f, "--out", o],
                "cannot read scene file: is a FIFO (named pipe)",
            ),
            (
                vec!["dataset", f, "--out", o],
                "is a FIFO (named pipe), not a regular file",
            ),
            (
                vec![
                    "reconstruct",
                    "--matrix",
                    p(&fine),
                    "--capture",
                    f,
                    "--object",
                    "2x1",
                    "--out",
                    o,
                ],
                "is a FIFO",
            ),
        ]);
    }
    for (args, expect) in &cases {
        let start = Instant::now();
        refused(args, &[expect]);
        // Refused from the metadata: well under the time a read of 5 GiB would take.
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "{args:?} was slow"
        );
    }
    assert!(!out.join("recon.exr").exists() || files_in(&out).len() == 3);
}

#[test]
fn non_finite_data_is_refused_and_reconstruction_stays_in_float32() {
    let (dir, out) = scratch();
    let o = p(&out);
    let h = dir.path().join("H.npz");
    diagonal_npz(&h, &[1.0; 4]);
    let cap = dir.path().join("g.npy");
    npy(&cap, &[1.0, 1.0, f32::NAN, 1.0]);
    let args = |c: &Path| {
        vec![
            "reconstruct".to_string(),
            "--matrix".into(),
            p(&h).into(),
            "--capture".into(),
            p(c).into(),
            "--out".into(),
            o.into(),
        ]
    };
    let strs = |v: &[String]| {
        v.iter()
            .map(String::as_str)
            .collect::<Vec<_>>()
            .join("\u{1}")
    };
    let run = |v: Vec<String>, expect: &[&str]| {
        let joined = strs(&v);
        let a: Vec<&str> = joined.split('\u{1}').collect();
        refused(&a, expect)
    };
    run(args(&cap), &["g.npy: value 2 is NaN, not a finite float32"]);
    // float64 beyond float32's range.
    let cap64 = dir.path().join("g64.npy");
    let mut b = stscam::io::encode_npy_f32(&cap64, &[4], &[0.0; 4]).unwrap();
    let at = b.windows(3).position(|w| w == b"<f4").unwrap();
    b[at + 2] = b'8';
    b.truncate(b.len() - 16);
    for v in [1.0f64, 1.0, 1.0, 1e300] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(&cap64, &b).unwrap();
    run(
        args(&cap64),
        &["g64.npy: value 3 is inf", "beyond ±3.40282e38"],
    );
    // Offset and H.
    let good = dir.path().join("ok.npy");
    npy(&good, &[1.0; 4]);
    let off = dir.path().join("off.npy");
    npy(&off, &[0.0, f32::INFINITY, 0.0, 0.0]);
    let mut a = args(&good);
    a.extend(["--offset".into(), p(&off).into()]);
    run(a, &["off.npy: value 1 is inf"]);
    let hbad = dir.path().join("Hbad.npz");
    diagonal_npz(&hbad, &[1.0, f32::NAN, 1.0, 1.0]);
    let mut a = args(&good);
    a[2] = p(&hbad).into();
    run(a, &["Hbad.npz: data.npy: entry 1 is NaN"]);
    // Truth image with NaN (EXR).
    let truth = dir.path().join("t.exr");
    let exr = stscam::io::encode_exr(
        2,
        2,
        vec![stscam::io::ExrChannel {
            name: "Y".into(),
            data: vec![0.0, 0.0, 0.0, f32::NAN],
        }],
        &[],
    )
    .unwrap();
    std::fs::write(&truth, exr).unwrap();
    let mut a = args(&good);
    a.extend(["--truth".into(), p(&truth).into()]);
    run(a, &["--truth: ", "t.exr: value 3 is NaN"]);
    assert!(files_in(&out).is_empty());

    // H = 1e-30·I: a capture of 1e10 gives f = 1e40, beyond float32: refused, nothing
    // written; a capture of 1 gives 1e30, which is written and read back finite.
    let tiny = dir.path().join("tiny.npz");
    diagonal_npz(&tiny, &[1e-30; 4]);
    let big = dir.path().join("big.npy");
    npy(&big, &[1e10; 4]);
    let mut a = args(&big);
    a[2] = p(&tiny).into();
    a.extend(["--method".into(), "cg".into()]);
    let e = run(
        a.clone(),
        &[
            "big.npy: the reconstruction reaches 1e40 at object pixel 0",
            "outside float32's range",
        ],
    );
    assert!(e.contains("tiny.npz"), "{e}");
    assert!(files_in(&out).is_empty());
    a[4] = p(&good).into();
    let joined = strs(&a);
    let (code, err) = run_within(&joined.split('\u{1}').collect::<Vec<_>>(), 60.0);
    assert_eq!(code, Some(0), "{err}");
    let (_, _, ch) = stscam::io::read_exr(&out.join("recon.exr")).unwrap();
    assert!(
        ch[0]
            .data
            .iter()
            .all(|v| v.is_finite() && (*v - 1e30).abs() < 1e25),
        "{:?}",
        ch[0].data
    );
}

#[test]
fn write_errors_exit_1_and_a_dataset_folder_is_locked() {
    let dir = tempfile::tempdir().unwrap();
    let r = write(
        dir.path(),
        "r.toml",
        &recipe("lock", 400, "render", "none", ""),
    );
    let rs = p(&r);
    // A file where the output folder should be: the folder cannot be created (exit 1),
    // while a bad recipe is exit 2.
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, "x").unwrap();
    let under = blocker.join("sub");
    let (code, err) = run_within(&["dataset", rs, "--out", p(&under)], 120.0);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("Not a directory"), "{err}");
    let (code, _) = run_within(&["render", "--spp", "1", "--out", p(&under)], 120.0);
    assert_eq!(code, Some(1));

    // Two runs in one folder: the second is refused while the first works.
    let out = dir.path().join("ds");
    let first = Command::new(env!("CARGO_BIN_EXE_stscam"))
        .args(["dataset", rs, "--out", p(&out)])
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let lock = out.join(".stscam-lock");
    let start = Instant::now();
    while !lock.exists() {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no lock file appeared"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let second: Output = stscam(&["dataset", rs, "--out", p(&out), "--resume"]);
    let first_pid = first.id();
    let first_out = first.wait_with_output().unwrap();
    assert!(
        first_out.status.success(),
        "{}",
        String::from_utf8_lossy(&first_out.stderr)
    );
    let err = String::from_utf8_lossy(&second.stderr)
        .trim_end()
        .to_string();
    assert_eq!(second.status.code(), Some(2), "{err}");
    assert!(
        err.contains(&format!("another stscam run (pid {first_pid} "))
            && err.contains(".stscam-lock if it is no longer running"),
        "{err}"
    );
    assert!(!lock.exists(), "the lock outlived the run");
    // A lock held by a live process (this test) refuses a resume; one left by a process
    // that has exited is stale and taken over.
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    std::fs::write(&lock, format!("{}\n{}\n", std::process::id(), host.trim())).unwrap();
    let (code, err) = run_within(&["dataset", rs, "--out", p(&out), "--resume"], 120.0);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains(&format!("pid {}", std::process::id())),
        "{err}"
    );
    let mut dead = Command::new("true").spawn().unwrap();
    let dead_pid = dead.id();
    dead.wait().unwrap();
    std::fs::write(&lock, format!("{dead_pid}\n{}\n", host.trim())).unwrap();
    let (code, err) = run_within(&["dataset", rs, "--out", p(&out), "--resume"], 120.0);
    assert_eq!(code, Some(0), "{err}");
    assert!(!lock.exists());
}

#[test]
fn messages_blame_the_key_set_suggest_keys_and_stay_short() {
    let (_dir, out) = scratch();
    let o = p(&out);
    // A relation error names the key the user set, not the one derived from it.
    refused(
        &["render", "--set", "camera.focal_length_mm=1000", "--out", o],
        &[
            "error: --set camera.focal_length_mm: camera.focal_length_mm: the focus distance (584.621 mm) must exceed the focal length (1000 mm)",
        ],
    );
    refused(
        &["render", "--set", "noise.bit_depth=1", "--out", o],
        &["error: --set noise.bit_depth: noise.bit_depth: noise.dark_offset_dn must be in [0, 1)"],
    );
    // At most six significant digits.
    let e = refused(
        &[
            "render",
            "--set",
            "camera.focus_distance_mm=1.2345678901234",
            "--set",
            "camera.focal_length_mm=5.123456789",
            "--out",
            o,
        ],
        &["(1.23457 mm) must exceed camera.focal_length_mm (5.12346 mm)"],
    );
    assert!(!e.contains("1.234567"), "{e}");
    // Unknown keys get the nearest valid one (and unrelated words none).
    refused(
        &["render", "--set", "plate.thicknes_mm=3", "--out", o],
        &["plate.thicknes_mm: unknown key; did you mean plate.thickness_mm?"],
    );
    let e = refused(
        &["info", "--set", "plate.colour=3"],
        &["plate.colour: unknown key"],
    );
    assert!(!e.contains("did you mean"), "{e}");
    refused(
        &["sweep", "--vary", "bottom_hoe.heigth_mm=1:2:2", "--out", o],
        &[
            "--vary bottom_hoe.heigth_mm: bottom_hoe.heigth_mm: unknown key; did you mean bottom_hoe.height_mm?",
        ],
    );
    // Argument errors: one line and a one-line usage hint.
    let (code, err) = run_within(&["render", "--bogus"], 30.0);
    assert_eq!(code, Some(2));
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 2, "{err}");
    assert!(
        lines[0].starts_with("error: unexpected argument '--bogus'"),
        "{err}"
    );
    assert!(lines[1].starts_with("Usage: stscam render"), "{err}");
    let (code, err) = run_within(&["render", "--spp", "abc"], 30.0);
    assert_eq!(code, Some(2));
    assert_eq!(err.lines().count(), 1, "{err}");
}

/// Runs with stderr not a terminal and progress lines every `interval` seconds; returns
/// stderr.
fn with_progress(args: &[&str], interval: &str) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_stscam"))
        .args(args)
        .env(stscam::progress::INTERVAL_ENV, interval)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{args:?}: {err}");
    err
}

#[test]
fn progress_lines_without_a_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let out = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    let small = ["--set", "sensor.crop_px=16", "--set", "sensor.pitch_um=132"];
    let mut render = vec!["render", "--spp", "1"];
    render.extend(small);
    let ro = out("r");
    render.extend(["--out", ro.as_str()]);
    // Every update due: one line per row, numbered to the end.
    let err = with_progress(&render, "0");
    let rows: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("rendering rows: "))
        .collect();
    assert!(!rows.is_empty(), "{err}");
    assert!(err.contains("rendering rows: 16/16 (100.0 %)"), "{err}");
    // The default interval (10 s): a sub-second render prints no progress line.
    let err = with_progress(&render, "10");
    assert!(!err.contains("rendering rows"), "{err}");
    // Calibration (H, then the rendered pattern frames), sweep and dataset.
    let co = out("c");
    let mut cal = vec![
        "calibrate",
        "--render",
        "--spp",
        "1",
        "--noise",
        "none",
        "--set",
        "display.image=checker:2@4",
    ];
    cal.extend(small);
    cal.extend(["--out", co.as_str()]);
    let err = with_progress(&cal, "0");
    assert!(err.contains("matrix rows: 16/16"), "{err}");
    assert!(err.contains("calibration frames: 17/17"), "{err}");
    let so = out("s");
    let err = with_progress(
        &[
            "sweep",
            "--vary",
            "bottom_hoe.height_mm=10:20:2",
            "--out",
            so.as_str(),
        ],
        "0",
    );
    assert!(err.contains("sweep points: 2/2"), "{err}");
    let r = write(dir.path(), "r.toml", &recipe("p", 5, "matrix", "none", ""));
    let dout = out("d");
    let err = with_progress(&["dataset", p(&r), "--out", dout.as_str()], "0");
    assert!(err.contains("samples: 5/5 (100.0 %)"), "{err}");
}
