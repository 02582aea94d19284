//! `stscam dataset`: shards merged equal one run byte for byte, a SIGKILLed run resumed equals
//! an uninterrupted one, captures equal H·f + offset when noiseless, image folders (PNG, JPEG)
//! are read, and bad recipes are refused with one line, exit code 2 and nothing written.

use std::path::Path;
use std::process::Command;

use crate::common::{assert_same_tree, stscam, write};

/// A small scene: 48×48 crop with the paper's field of view, so runs take a fraction of a
/// second.
const SMALL_SCENE: &str = r#"
[scene]
set = ["sensor.crop_px=[48,48]", "sensor.pitch_um=44.0"]
"#;

/// A recipe of the small scene (also used by `hostile.rs`).
pub(crate) fn recipe(name: &str, samples: usize, mode: &str, noise: &str, extra: &str) -> String {
    format!(
        r#"name = "{name}"
seed = 7
samples = {samples}
mode = "{mode}"
spp = 4
noise = "{noise}"
{SMALL_SCENE}
[split]
train = 0.6
val = 0.2
test = 0.2

[objects]
size_px = 16
random_levels = true

[[objects.sources]]
generator = "glyphs"

[[objects.sources]]
generator = "shapes"

[[objects.sources]]
generator = "siemens"
max_spokes = 8

[[objects.sources]]
generator = "bars"
max_period_px = 3

[[objects.sources]]
generator = "smooth"
{extra}"#
    )
}

fn ok(args: &[&str]) {
    let out = stscam(args);
    assert!(
        out.status.success(),
        "stscam {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn three_shards_merged_equal_one_run_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let vary = "\n[[vary]]\nkey = \"display.distance_mm\"\nvalues = [500.0, 600.0]\n";
    let r = write(
        dir.path(),
        "r.toml",
        &recipe("shards", 23, "matrix", "sensor", vary),
    );
    let r = r.to_str().unwrap();
    let whole = dir.path().join("whole");
    ok(&["dataset", r, "--out", whole.to_str().unwrap()]);
    let mut shards = Vec::new();
    for i in 0..3 {
        let d = dir.path().join(format!("s{i}"));
        // Shard 0 from --shard, shard 1 from a SLURM job array (ids 1..3), shard 2 from a
        // Kubernetes Indexed Job.
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_stscam"));
        cmd.args(["dataset", r, "--out", d.to_str().unwrap()]);
        match i {
            0 => {
                // One worker thread here, all cores elsewhere: the bytes may not depend on it.
                cmd.args(["--shard", "0/3", "--threads", "1"]);
            }
            1 => {
                cmd.env("SLURM_ARRAY_TASK_ID", "2")
                    .env("SLURM_ARRAY_TASK_MIN", "1")
                    .env("SLURM_ARRAY_TASK_COUNT", "3");
            }
            _ => {
                cmd.env("JOB_COMPLETION_INDEX", "2")
                    .env("STSCAM_SHARD_COUNT", "3");
            }
        }
        let out = cmd.output().unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(String::from_utf8_lossy(&out.stderr).contains(&format!("shard {i}/3")));
        assert!(d.join("shard.json").is_file());
        assert!(!d.join("dataset.json").exists());
        shards.push(d);
    }
    let merged = dir.path().join("merged");
    crate::common::merge_shards(&shards, &merged);
    assert_same_tree(&whole, &merged);
    // The card lists every file with its checksum; both scenes have their H.
    let card: serde_json::Value =
        serde_json::from_slice(&std::fs::read(whole.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(card["samples"], 23);
    assert_eq!(card["counts"]["train"], 14);
    assert_eq!(card["counts"]["val"], 5);
    assert_eq!(card["counts"]["test"], 4);
    let files = card["files"].as_object().unwrap();
    assert_eq!(files.len(), 23 * 4 + 3 + 2 * 4, "{:?}", files.keys());
    assert!(files.contains_key("scene_001/H.npz"));
    // Shards from one run merged in another order or with one missing are checked.
    let again = dir.path().join("again");
    let out = stscam(&[
        "dataset",
        "merge",
        shards[2].to_str().unwrap(),
        shards[0].to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("each exactly once"));
    assert!(!again.exists());
    // A corrupted shard file is caught before anything is written.
    let victim = shards[1].join("val/000014_capture.npy");
    let mut bytes = std::fs::read(&victim).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    std::fs::write(&victim, bytes).unwrap();
    let mut args = vec!["dataset", "merge"];
    args.extend(shards.iter().map(|d| d.to_str().unwrap()));
    args.extend(["--out", again.to_str().unwrap()]);
    let out = stscam(&args);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("000014_capture.npy"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!again.exists());
}

#[test]
fn sigkill_and_resume_give_the_uninterrupted_files() {
    let dir = tempfile::tempdir().unwrap();
    // Render mode: each sample is a Monte Carlo render (tens of ms at 16 spp on 96 x 96), so
    // the run can be killed in the middle (the kill is asserted to come before the end).
    let r = write(
        dir.path(),
        "r.toml",
        &recipe("kill", 40, "render", "sensor", "")
            .replace("spp = 4", "spp = 16")
            .replace("[48,48]", "[96,96]")
            .replace("44.0", "22.0"),
    );
    let whole = dir.path().join("whole");
    ok(&[
        "dataset",
        r.to_str().unwrap(),
        "--out",
        whole.to_str().unwrap(),
    ]);
    let killed = dir.path().join("killed");
    // Wait until some samples are finished, then SIGKILL.
    crate::common::dataset_killed_midway(&r, &killed, 12);
    let n_before = crate::common::files_in(&killed.join("train")).len();
    assert!((12..4 * 24).contains(&n_before), "{n_before} files");
    // Without --resume the folder is refused.
    let out = stscam(&[
        "dataset",
        r.to_str().unwrap(),
        "--out",
        killed.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--resume"));
    let out = stscam(&[
        "dataset",
        r.to_str().unwrap(),
        "--out",
        killed.to_str().unwrap(),
        "--resume",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(
        !msg.contains(" 40 generated now"),
        "nothing was kept: {msg}"
    );
    assert_same_tree(&whole, &killed);
    // Resuming a finished run changes nothing.
    ok(&[
        "dataset",
        r.to_str().unwrap(),
        "--out",
        killed.to_str().unwrap(),
        "--resume",
    ]);
    assert_same_tree(&whole, &killed);
}

fn read_npy(p: &Path) -> (Vec<usize>, Vec<f32>) {
    stscam::io::read_npy_f32(p).unwrap()
}

#[test]
fn noiseless_captures_are_h_times_the_object_plus_offset() {
    noiseless_case(None);
}

/// A colour sensor: captures are [3, h, w], channel-major like H's rows, and the PNG is RGB.
#[test]
fn noiseless_colour_captures_are_h_times_the_object_plus_offset() {
    noiseless_case(Some("sensor.response=rgb-bayer"));
}

fn noiseless_case(sensor: Option<&str>) {
    let dir = tempfile::tempdir().unwrap();
    let mut text = recipe("clean", 12, "matrix", "none", "");
    if let Some(s) = sensor {
        text = text.replace(
            "\"sensor.pitch_um=44.0\"",
            &format!("\"sensor.pitch_um=44.0\", \"{s}\""),
        );
    }
    let channels = if sensor.is_some() { 3 } else { 1 };
    let r = write(dir.path(), "r.toml", &text);
    let out = dir.path().join("ds");
    ok(&[
        "dataset",
        r.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let m = stscam::matrix::load_matrix(&out.join("scene_000/H.npz"), None, None).unwrap();
    let offset = m.offset.unwrap();
    let card: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("dataset.json")).unwrap()).unwrap();
    let full_scale = card["exposure"]["capture_full_scale"].as_f64().unwrap();
    let meta = std::fs::read_to_string(out.join("train/metadata.jsonl")).unwrap();
    let mut n = 0;
    for line in meta.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let (os, obj) = read_npy(&out.join("train").join(v["object_npy"].as_str().unwrap()));
        let (cs, cap) = read_npy(&out.join("train").join(v["capture_npy"].as_str().unwrap()));
        assert_eq!(os, vec![16, 16]);
        if channels == 1 {
            assert_eq!(cs, vec![48, 48]);
        } else {
            assert_eq!(cs, vec![3, 48, 48]);
            assert_eq!(m.h.rows, 3 * 48 * 48);
        }
        // The capture PNG is the stated quantisation of the .npy (pixel-major, RGB interleaved).
        let png = stscam::io::load_image(&out.join("train").join(v["file_name"].as_str().unwrap()))
            .unwrap();
        assert_eq!((png.width, png.height, png.channels), (48, 48, channels));
        let p = 48 * 48;
        for (i, &q) in png.values.iter().enumerate() {
            let (px, c) = (i / channels, i % channels);
            let want = (f64::from(cap[c * p + px]) / full_scale).clamp(0.0, 1.0);
            assert!(
                (f64::from(q) - want).abs() <= 0.6 / 65535.0 + 1e-7,
                "{q} vs {want}"
            );
        }
        let f: Vec<f64> = obj.iter().map(|&x| f64::from(x)).collect();
        let g = m.h.mul_vec(&f);
        let peak = g.iter().cloned().fold(0.0, f64::max);
        for ((gi, oi), ci) in g.iter().zip(&offset).zip(&cap) {
            assert!((gi + f64::from(*oi) - f64::from(*ci)).abs() <= 1e-6 * peak);
        }
        assert!(peak > 0.0);
        n += 1;
    }
    assert_eq!(n, 7);
}

#[test]
fn noisy_captures_scatter_around_the_clean_ones_as_the_sensor_model_says() {
    let dir = tempfile::tempdir().unwrap();
    let clean = write(dir.path(), "c.toml", &recipe("c", 6, "matrix", "none", ""));
    let noisy = write(
        dir.path(),
        "n.toml",
        &recipe("c", 6, "matrix", "sensor", ""),
    );
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    ok(&[
        "dataset",
        clean.to_str().unwrap(),
        "--out",
        a.to_str().unwrap(),
    ]);
    ok(&[
        "dataset",
        noisy.to_str().unwrap(),
        "--out",
        b.to_str().unwrap(),
    ]);
    // The same objects (the seed does not depend on the noise).
    let (_, oa) = read_npy(&a.join("train/000000_object.npy"));
    let (_, ob) = read_npy(&b.join("train/000000_object.npy"));
    assert_eq!(oa, ob);
    let card: serde_json::Value =
        serde_json::from_slice(&std::fs::read(b.join("dataset.json")).unwrap()).unwrap();
    let e_per_unit = card["exposure"]["electrons_per_unit"].as_f64().unwrap();
    let full_scale = card["exposure"]["capture_full_scale"].as_f64().unwrap();
    let lsb = full_scale * 0.8 / 255.0; // capture units per DN (8 bits, 80 % exposure)
    let (mut sum_d, mut sum_d2, mut sum_var, mut n) = (0.0, 0.0, 0.0, 0.0);
    for id in 0..3 {
        let (_, ca) = read_npy(&a.join(format!("train/00000{id}_capture.npy")));
        let (_, cb) = read_npy(&b.join(format!("train/00000{id}_capture.npy")));
        for (&x, &y) in ca.iter().zip(&cb) {
            let (x, y) = (f64::from(x), f64::from(y));
            // Away from the clipped ends of the ADC.
            if x > 8.0 * lsb && x < 0.9 * full_scale {
                sum_d += y - x;
                sum_d2 += (y - x) * (y - x);
                sum_var += ((x * e_per_unit + 49.0) / (e_per_unit * e_per_unit)) + lsb * lsb / 12.0;
                n += 1.0;
            }
        }
    }
    assert!(n > 200.0, "{n}");
    // Mean difference ~ 0 (dark offset removed): within 5 standard errors.
    let se = (sum_var / n).sqrt() / n.sqrt();
    assert!((sum_d / n).abs() < 5.0 * se, "{} vs {se}", sum_d / n);
    // Variance as predicted (shot + read noise + quantisation), within 15 % (n > 200).
    let ratio = sum_d2 / sum_var;
    assert!((ratio - 1.0).abs() < 0.15, "variance ratio {ratio}");
}

#[test]
fn image_folders_png_and_jpeg_are_read_and_resized() {
    let dir = tempfile::tempdir().unwrap();
    let imgs = dir.path().join("imgs");
    std::fs::create_dir(&imgs).unwrap();
    // A 40×30 JPEG: left half black, right half white (RGB).
    let (w, h) = (40u16, 30u16);
    let rgb: Vec<u8> = (0..usize::from(w) * usize::from(h))
        .flat_map(|i| {
            let v = if i % usize::from(w) >= usize::from(w) / 2 {
                255
            } else {
                0
            };
            [v, v, v]
        })
        .collect();
    jpeg_encoder::Encoder::new_file(imgs.join("half.jpg"), 95)
        .unwrap()
        .encode(&rgb, w, h, jpeg_encoder::ColorType::Rgb)
        .unwrap();
    let extra = "\n[[objects.sources]]\ngenerator = \"images\"\nfolder = \"imgs\"\nflip = false\nweight = 1000.0\n";
    let r = write(
        dir.path(),
        "r.toml",
        &recipe("img", 5, "matrix", "none", extra),
    );
    let out = dir.path().join("ds");
    ok(&[
        "dataset",
        r.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let meta = std::fs::read_to_string(out.join("train/metadata.jsonl")).unwrap();
    let v: serde_json::Value = serde_json::from_str(meta.lines().next().unwrap()).unwrap();
    assert_eq!(v["source"], "images");
    assert_eq!(v["object_draw"], "images file=imgs/half.jpg flip=false");
    let (shape, f) = read_npy(&out.join("train/000000_object.npy"));
    assert_eq!(shape, vec![16, 16]);
    // Centre crop 30×30 of a 40-wide image split at x = 20: the crop spans x = 5..35, so the
    // split sits at half the crop: left 8 columns dark, right 8 bright (JPEG ringing aside).
    for y in 0..16 {
        assert!(f[y * 16 + 2] < 0.02, "{}", f[y * 16 + 2]);
        assert!(f[y * 16 + 13] > 0.95, "{}", f[y * 16 + 13]);
    }
}

/// Runs `stscam dataset RECIPE --out OUT`, expects exit code 2 with one line naming `expect`,
/// and returns that line.
fn fails_with_one_line(recipe: &Path, out_dir: &Path, expect: &str) -> String {
    let out = stscam(&[
        "dataset",
        recipe.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains(expect), "{err} lacks {expect}");
    err
}

fn refused(recipe_text: &str, setup: impl Fn(&Path), expect: &str) {
    let dir = tempfile::tempdir().unwrap();
    setup(dir.path());
    let r = write(dir.path(), "bad.toml", recipe_text);
    let out_dir = dir.path().join("out");
    let err = fails_with_one_line(&r, &out_dir, expect);
    assert!(err.contains("bad.toml"), "{err}");
    assert!(!out_dir.exists(), "something was written");
}

#[test]
fn bad_recipes_are_refused_with_one_line_and_nothing_written() {
    let good = recipe("bad", 5, "matrix", "sensor", "");
    refused(
        &good.replace("\"bars\"", "\"barz\""),
        |_| {},
        "unknown variant `barz`",
    );
    refused(
        &good.replace("test = 0.2", "test = 0.3"),
        |_| {},
        "sum to 1",
    );
    refused(
        &format!("{good}\n[[objects.sources]]\ngenerator = \"images\"\nfolder = \"empty\"\n"),
        |d| std::fs::create_dir(d.join("empty")).unwrap(),
        "no .png, .jpg or .jpeg files",
    );
    refused(
        &format!("{good}\n[[objects.sources]]\ngenerator = \"images\"\nfolder = \"bad\"\n"),
        |d| {
            std::fs::create_dir(d.join("bad")).unwrap();
            std::fs::write(d.join("bad/photo.jpg"), b"this is not a JPEG").unwrap();
        },
        "photo.jpg",
    );
    refused(
        &format!("{good}\n[[objects.sources]]\ngenerator = \"images\"\nfolder = \"missing\"\n"),
        |_| {},
        "is not a folder",
    );
    refused(
        &good.replace("mode = \"matrix\"", "mode = \"mtx\""),
        |_| {},
        "mode",
    );
    refused(
        &format!("{good}\n[[vary]]\nkey = \"plate.thickness_mm\"\nvalues = [-1.0]\n"),
        |_| {},
        "plate.thickness_mm",
    );
    refused(
        &good.replace("samples = 5", "samples = 5\nsmaples = 3"),
        |_| {},
        "smaples",
    );
    // An unwritable output: its parent is a regular file. A failed write, not bad input:
    // exit code 1 (issue 13), one line naming the folder.
    let dir = tempfile::tempdir().unwrap();
    let r = write(dir.path(), "r.toml", &good);
    std::fs::write(dir.path().join("file"), b"x").unwrap();
    let out = stscam(&[
        "dataset",
        r.to_str().unwrap(),
        "--out",
        dir.path().join("file/out").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("file/out"), "{err}");
    assert_eq!(std::fs::read(dir.path().join("file")).unwrap(), b"x");
    // A bad --shard.
    let out = stscam(&["dataset", r.to_str().unwrap(), "--shard", "3/3"]);
    assert_eq!(out.status.code(), Some(2));
}

/// `[[vary]] cycle = true` gives sample i the value i mod len (two cycled keys run through
/// their combinations, the last fastest), so each value gets its share; without it the values
/// are drawn at random (here not evenly). `cycle` on a `range` is refused naming the key.
#[test]
fn cycled_vary_values_take_turns() {
    let dir = tempfile::tempdir().unwrap();
    let vary = |cycle: bool| {
        format!(
            "\n[[vary]]\nkey = \"display.distance_mm\"\nvalues = [450.0, 550.0, 650.0]\ncycle = {cycle}\n\
             [[vary]]\nkey = \"plate.thickness_mm\"\nvalues = [2.0, 3.0]\ncycle = {cycle}\n"
        )
    };
    let path = write(
        dir.path(),
        "cycle.toml",
        &recipe("cycle", 12, "matrix", "none", &vary(true)),
    );
    let plan = stscam::dataset::plan(&path).unwrap();
    for i in 0..12 {
        let p = plan.sample(i).params;
        assert_eq!(
            p["display.distance_mm"],
            [450.0, 550.0, 650.0][(i / 2) % 3],
            "sample {i}"
        );
        assert_eq!(p["plate.thickness_mm"], [2.0, 3.0][i % 2], "sample {i}");
    }
    write(
        dir.path(),
        "cycle.toml",
        &recipe("cycle", 12, "matrix", "none", &vary(false)),
    );
    let plan = stscam::dataset::plan(&path).unwrap();
    let at_450 = (0..12)
        .filter(|&i| plan.sample(i).params["display.distance_mm"] == 450.0)
        .count();
    assert_ne!(
        at_450, 4,
        "random draws happen to be even: pick another seed for the check"
    );
    let bad = "\n[[vary]]\nkey = \"display.distance_mm\"\nrange = [450.0, 650.0]\ncycle = true\n";
    write(
        dir.path(),
        "cycle.toml",
        &recipe("cycle", 12, "render", "none", bad),
    );
    let e = stscam::dataset::plan(&path).unwrap_err().to_string();
    assert!(e.contains("vary[0].cycle"), "{e}");
}

/// `paths = "all"` (render mode): each noiseless capture is every path through the plate, so it
/// holds more light than the designed-path capture of the same sample and seed (the stray
/// light adds, everywhere the signal is: each capture's sum is larger, the excess at most a
/// few percent); a matrix-mode recipe with it is refused naming `paths`.
#[test]
fn all_paths_captures_carry_the_stray_light() {
    let dir = tempfile::tempdir().unwrap();
    // `paths` is a top-level key: it goes before the recipe's first table.
    let text = |name: &str, mode: &str, paths: &str| {
        recipe(name, 5, mode, "none", "").replacen(
            "noise = \"none\"",
            &format!("noise = \"none\"\npaths = \"{paths}\""),
            1,
        )
    };
    let make = |name: &str, paths: &str| {
        let r = write(
            dir.path(),
            &format!("{name}.toml"),
            &text(name, "render", paths),
        );
        let out = dir.path().join(name);
        ok(&[
            "dataset",
            r.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        out
    };
    let all = make("all", "all");
    let designed = make("designed", "designed");
    let mut n = 0;
    for split in ["train", "val", "test"] {
        let meta = std::fs::read_to_string(designed.join(split).join("metadata.jsonl"))
            .unwrap_or_default();
        for line in meta.lines() {
            let v: serde_json::Value = serde_json::from_str(line).unwrap();
            let f = v["capture_npy"].as_str().unwrap();
            let (_, d) = read_npy(&designed.join(split).join(f));
            let (_, a) = read_npy(&all.join(split).join(f));
            let (sd, sa): (f64, f64) = (
                d.iter().map(|&x| f64::from(x)).sum(),
                a.iter().map(|&x| f64::from(x)).sum(),
            );
            assert!(sa > sd && sa < 1.05 * sd, "{f}: all {sa} vs designed {sd}");
            n += 1;
        }
    }
    assert_eq!(n, 5);
    let bad = write(dir.path(), "bad.toml", &text("bad", "matrix", "all"));
    let o = stscam(&[
        "dataset",
        bad.to_str().unwrap(),
        "--out",
        dir.path().join("b").to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("paths"));
}
