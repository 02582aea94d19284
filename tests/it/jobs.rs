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
        noise: stscam::hadamard::CaptureNoise::None,
        white_peak: None,
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

/// `render --noise sensor` is the clean capture measured by the scene's sensor model exactly as
/// datasets and Python's `sensor_noise` measure it (`noise::measure_capture` with the seed and
/// the exposure given), and its sidecar records the exposure; without `--noise sensor`,
/// `--white-peak` is refused. Failing input: another seed's noise differs.
#[test]
fn render_with_sensor_noise_is_the_clean_capture_measured() {
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, extra: &[&str]| -> Vec<f32> {
        let out = dir.path().join(name);
        let mut args = vec![
            "render",
            "--spp",
            "4",
            "--seed",
            "3",
            "--out",
            out.to_str().unwrap(),
        ];
        for s in &SMALL {
            args.extend(["--set", s]);
        }
        args.extend(extra);
        stscam_ok(&args);
        let (_, _, ch) = stscam::io::read_exr(&out.join("capture.exr")).unwrap();
        ch[0].data.clone()
    };
    let clean = run("clean", &[]);
    let noisy = run("noisy", &["--noise", "sensor", "--white-peak", "0.002"]);
    let sys = stscam::system::System::build(
        &stscam::scene::load_scene(None, &SMALL.map(String::from)).unwrap(),
    )
    .unwrap();
    let noise = stscam::noise::SensorNoise::new(&sys.scene.noise, 0.002);
    let c64: Vec<f64> = clean.iter().map(|&v| f64::from(v)).collect();
    assert_eq!(noisy, stscam::noise::measure_capture(&noise, &c64, 3));
    assert_ne!(noisy, stscam::noise::measure_capture(&noise, &c64, 4));
    assert_ne!(noisy, clean);
    let side: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("noisy/capture.json")).unwrap())
            .unwrap();
    assert_eq!(side["noise"]["white_peak"], 0.002);
    assert_eq!(side["noise"]["seed"], 3);
    let side: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("clean/capture.json")).unwrap())
            .unwrap();
    assert_eq!(side["noise"], "none");
    let out = stscam(&[
        "render",
        "--white-peak",
        "1",
        "--out",
        dir.path().join("x").to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains("--white-peak: sets the exposure of --noise sensor")
    );
    assert!(!dir.path().join("x").exists());
}
