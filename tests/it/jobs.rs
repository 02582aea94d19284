//! The library's job API (`stscam::jobs`) against the CLI: the same options give the same
//! files, values and messages; a silent console prints nothing the caller has to parse.

use std::path::PathBuf;

use stscam::jobs::{self, Console, RunArgs, SceneArgs};
use stscam::sampler::SamplerKind;

use crate::common::{stscam, stscam_json, stscam_ok};

fn scene(set: &[&str]) -> SceneArgs {
    SceneArgs {
        scene: None,
        set: set.iter().map(|s| s.to_string()).collect(),
    }
}

const SMALL: [&str; 3] = [
    "sensor.crop_px=[48,40]",
    "sensor.pitch_um=60",
    "display.image=letter:F@16",
];

#[test]
fn render_job_returns_what_the_cli_writes() {
    let dir = tempfile::tempdir().unwrap();
    let opts = jobs::render::RenderOptions {
        scene: scene(&SMALL),
        out: dir.path().join("lib"),
        run: RunArgs {
            spp: 4,
            seed: 3,
            threads: Some(2),
        },
        spectral: false,
        sampler: SamplerKind::Lattice,
        user_side: Default::default(),
        frontal_px: None,
        frontal_spp: None,
        frontal_space: Default::default(),
        table: Default::default(),
        adaptive: false,
    };
    let cap = jobs::render::run(&opts, &Console::Silent).expect("render job");
    let cli_out = dir.path().join("cli");
    let mut args = vec!["render", "--spp", "4", "--seed", "3", "--out"];
    let cli_str = cli_out.to_str().unwrap();
    args.push(cli_str);
    for s in &SMALL {
        args.extend(["--set", s]);
    }
    stscam_ok(&args);
    // The same EXR bytes, and the returned values are the EXR's.
    let lib_exr = std::fs::read(opts.out.join("capture.exr")).unwrap();
    assert_eq!(lib_exr, std::fs::read(cli_out.join("capture.exr")).unwrap());
    let (w, h, ch) = stscam::io::read_exr(&cli_out.join("capture.exr")).unwrap();
    assert_eq!((w, h), (cap.width, cap.height));
    assert_eq!((w, h), (48, 40));
    assert_eq!(ch[0].data, cap.channels[0]);
    assert!(cap.channels[0].iter().any(|&v| v > 0.0));
}

#[test]
fn info_and_probe_jobs_equal_the_cli_json() {
    let info = jobs::info::run(
        &jobs::info::InfoOptions {
            scene: scene(&SMALL),
            json: true,
        },
        &Console::Silent,
    )
    .unwrap();
    let mut args = vec!["info", "--json"];
    for s in &SMALL {
        args.extend(["--set", s]);
    }
    // The CLI prints the returned value's JSON, byte for byte.
    assert_eq!(
        serde_json::to_string_pretty(&info).unwrap() + "\n",
        stscam_ok(&args)
    );
    let p = jobs::probe::run(
        &jobs::probe::ProbeOptions {
            scene: scene(&SMALL),
            pixel: "10,20".into(),
            json: true,
        },
        &Console::Silent,
    )
    .unwrap();
    let mut args = vec!["probe", "--pixel", "10,20", "--json"];
    for s in &SMALL {
        args.extend(["--set", s]);
    }
    assert_eq!(
        serde_json::to_string_pretty(&p).unwrap() + "\n",
        stscam_ok(&args)
    );
    assert_eq!(
        stscam_json(&args)["lambda_nm"].as_f64().map(f64::is_finite),
        Some(true)
    );
}

#[test]
fn job_errors_carry_the_cli_exit_code_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let out: PathBuf = dir.path().join("m");
    let opts = jobs::matrix::MatrixOptions {
        scene: scene(&["plate.thickness_mmm=3"]),
        out: out.clone(),
        run: RunArgs {
            spp: 1,
            seed: 1,
            threads: None,
        },
        depth_mm: None,
        check: false,
    };
    let e = jobs::matrix::run(&opts, &Console::Silent).unwrap_err();
    assert!(e.is_bad_input(), "{e:?}");
    let cli = stscam(&[
        "matrix",
        "--set",
        "plate.thickness_mmm=3",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(cli.status.code(), Some(i32::from(e.code)));
    let line = String::from_utf8_lossy(&cli.stderr);
    assert_eq!(line.trim_end(), format!("error: {e}"));
    assert!(!out.exists(), "a refused job writes nothing");
    // A bad depth list: the same line again.
    let opts = jobs::matrix::MatrixOptions {
        scene: scene(&SMALL),
        depth_mm: Some("400,400".into()),
        ..opts
    };
    let e = jobs::matrix::run(&opts, &Console::Silent).unwrap_err();
    assert_eq!(e.code, 2);
    assert_eq!(e.message, "--depth-mm 400,400: depth 400 mm is given twice");
}
