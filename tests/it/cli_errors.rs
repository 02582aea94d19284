//! Bad input gives one line naming the file (or `--set`) and the key, exit code 2, and nothing
//! written to `--out`.

use crate::common::{files_in, stscam};

/// Runs a render expected to fail; returns its single stderr line.
fn fails(extra: &[&str], out: &std::path::Path) -> String {
    let out_s = out.to_str().unwrap();
    let mut args = vec!["render", "--out", out_s, "--spp", "1"];
    args.extend_from_slice(extra);
    let o = stscam(&args);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let err = String::from_utf8(o.stderr).unwrap();
    assert_eq!(
        err.trim_end().lines().count(),
        1,
        "more than one line: {err}"
    );
    assert!(
        files_in(out).is_empty(),
        "{args:?} wrote {:?}",
        files_in(out)
    );
    assert!(!out.exists(), "{args:?} created the output directory");
    err.trim_end().to_string()
}

#[test]
fn bad_scenes_and_overrides() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let scene = dir.path().join("scene.toml");
    let s = scene.to_str().unwrap();

    std::fs::write(&scene, "[plate]\nthickness_mm = = 2\n").unwrap();
    let e = fails(&[s], &out);
    assert!(
        e.starts_with(&format!("error: {s}: line 2")) && e.contains("malformed TOML"),
        "{e}"
    );

    std::fs::write(&scene, "[plate]\nthicknes_mm = 2.0\n").unwrap();
    assert_eq!(
        fails(&[s], &out),
        format!("error: {s}: plate.thicknes_mm: unknown key; did you mean plate.thickness_mm?")
    );

    std::fs::write(&scene, "[plate]\nthickness_mm = -2.0\n").unwrap();
    let e = fails(&[s], &out);
    assert!(
        e.starts_with(&format!(
            "error: {s}: plate.thickness_mm: must be a positive"
        )),
        "{e}"
    );

    std::fs::write(&scene, "[display]\nimage = \"missing.png\"\n").unwrap();
    let e = fails(&[s], &out);
    assert!(
        e.starts_with(&format!("error: {s}: display.image: ")) && e.contains("missing.png"),
        "{e}"
    );

    std::fs::write(&scene, "[sensor]\nresponse = \"infrared\"\n").unwrap();
    let e = fails(&[s], &out);
    assert!(e.contains("sensor.response: unknown response"), "{e}");

    let e = fails(&["--set", "plate.thicknes_mm=3"], &out);
    assert_eq!(
        e,
        "error: --set plate.thicknes_mm: plate.thicknes_mm: unknown key; did you mean plate.thickness_mm?"
    );
    let e = fails(&["--set", "camera.f_number=0"], &out);
    assert!(
        e.starts_with("error: --set camera.f_number: camera.f_number: must be a positive"),
        "{e}"
    );
    let e = fails(&["--set", "top_hoe.covered=maybe"], &out);
    assert!(
        e.starts_with("error: --set top_hoe.covered: top_hoe.covered:"),
        "{e}"
    );
    let e = fails(&["--set", "display.image=letter:@"], &out);
    assert!(e.contains("display.image"), "{e}");
    // Errors inside arrays and between keys name the key that was overridden.
    let e = fails(&["--set", "display.size_px=[1,-1]"], &out);
    assert!(
        e.starts_with("error: --set display.size_px[1]: display.size_px[1]:"),
        "{e}"
    );
    let e = fails(&["--set", "sampling.lambda_min_nm=900"], &out);
    assert!(
        e.starts_with("error: --set sampling.lambda_min_nm: sampling.lambda_min_nm:"),
        "{e}"
    );
    let e = fails(&["--set", "sensor.crop_offset_px=[600,0]"], &out);
    assert!(
        e.starts_with("error: --set sensor.crop_offset_px: sensor.crop_offset_px:"),
        "{e}"
    );
    // A focal length beyond the auto focus distance would flip the image: refused, and
    // blamed on the key the user set (not on the focus distance derived from it).
    let e = fails(&["--set", "camera.focal_length_mm=1000"], &out);
    assert!(
        e.starts_with(
            "error: --set camera.focal_length_mm: camera.focal_length_mm: the focus distance"
        ),
        "{e}"
    );
    let e = fails(&[dir.path().join("nope.toml").to_str().unwrap()], &out);
    assert!(e.contains("nope.toml: cannot read scene file"), "{e}");
}

#[test]
fn bad_arguments() {
    let dir = tempfile::tempdir().unwrap();
    let o = stscam(&["probe", "--pixel", "999,0"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("outside the 440x440 crop"));
    let o = stscam(&["probe", "--pixel", "a,b"]);
    assert_eq!(o.status.code(), Some(2));
    let o = stscam(&[
        "render",
        "--spp",
        "0",
        "--out",
        dir.path().join("x").to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    let o = stscam(&["render", "--bogus"]);
    assert_eq!(o.status.code(), Some(2));
    // --out that is a file.
    let f = dir.path().join("file");
    std::fs::write(&f, "x").unwrap();
    let o = stscam(&["render", "--spp", "1", "--out", f.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(std::fs::read_to_string(&f).unwrap(), "x");
}

/// `--adaptive` with too few samples to share out, or with a display-only scene's camera-side
/// table (H·f draws no samples): one line, exit 2, nothing written (not even the table).
#[test]
fn adaptive_needs_samples_to_share() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    assert_eq!(
        fails(&["--adaptive"], &out),
        "error: --adaptive needs --spp of at least 16 (got 1): its pilot takes 1/8 of the samples"
    );
    let table = dir.path().join("table");
    let e = fails(
        &["--adaptive", "--camera-table", table.to_str().unwrap()],
        &out,
    );
    assert!(
        e.contains("display-only scene's camera-side table is H"),
        "{e}"
    );
    assert!(!table.exists());
}

#[test]
fn failed_write_leaves_nothing_new() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir_all(out.join("capture.png")).unwrap();
    std::fs::write(out.join("keep.txt"), "x").unwrap();
    let o = stscam(&[
        "render",
        "--spp",
        "1",
        "--set",
        "sensor.crop_px=8",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let mut names = files_in(&out);
    names.sort();
    assert_eq!(
        names,
        vec!["capture.png".to_string(), "keep.txt".to_string()]
    );
}

/// `render --frontal-spp`: 0 and a count past the path limit are refused in one line naming
/// the flag (both flags when `--frontal-px` is given too), with nothing written; a valid count is recorded as the sidecar's `frontal.spp`
/// while the capture keeps `--spp`.
#[test]
fn frontal_spp_is_checked_and_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let scene = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/gesture.toml");
    let s = scene.to_str().unwrap();
    let out = dir.path().join("out");
    for n in ["0", "4294967295"] {
        let e = fails(&[s, "--frontal-spp", n], &out);
        assert!(e.contains("--frontal-spp"), "{n}: {e}");
    }
    // Both flags given: the message names both (the product is what exceeds the limit).
    let e = fails(
        &[s, "--frontal-px", "4096", "--frontal-spp", "100000"],
        &out,
    );
    assert!(e.contains("--frontal-px and --frontal-spp"), "{e}");
    let ok = dir.path().join("ok");
    let o = stscam(&[
        "render",
        s,
        "--spp",
        "1",
        "--frontal-spp",
        "3",
        "--set",
        "sensor.crop_px=[16,16]",
        "--out",
        ok.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let side: serde_json::Value =
        serde_json::from_slice(&std::fs::read(ok.join("capture.json")).unwrap()).unwrap();
    assert_eq!(side["frontal"]["spp"], 3);
    assert_eq!(side["spp"], 1);
}

/// A report that cannot be written (standard output on `/dev/full`) exits 1 with one line on
/// stderr; a closed pipe is the reader's choice and stays exit 0. Before the check, `info`,
/// `grating`, `evaluate --json` and `--help` lost their report and exited 0.
#[test]
fn a_report_that_cannot_be_written_exits_1() {
    let full = match std::fs::OpenOptions::new().write(true).open("/dev/full") {
        Ok(f) => f,
        Err(_) => return, // no /dev/full on this system: nothing to check
    };
    let cases: [&[&str]; 4] = [
        &["info"],
        &["grating"],
        &[
            "evaluate",
            "--metrics",
            "fov_capture_vertical_deg",
            "--json",
        ],
        &["--help"],
    ];
    for args in cases {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_stscam"))
            .args(args)
            .stdout(full.try_clone().unwrap())
            .output()
            .expect("run stscam");
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.lines()
                .any(|l| l.starts_with("error: cannot write the") && l.contains("standard output")),
            "{args:?}: {err}"
        );
    }
    // A pipe closed by its reader: the process ends quietly (SIGPIPE, as other command-line
    // tools do; or exit 0 where the signal is ignored), no error line.
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_stscam"))
        .arg("info")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run stscam");
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    use std::os::unix::process::ExitStatusExt;
    assert!(
        o.status.code() == Some(0) || o.status.signal() == Some(13),
        "{:?}: {}",
        o.status,
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!String::from_utf8_lossy(&o.stderr).contains("cannot write"));
}
