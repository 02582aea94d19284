//! Datasets over depth and over 3-D scenes: `meshes` samples with capture, frontal, depth and
//! mask aligned as documented, three shards merged byte-identical to one run (and to a
//! one-thread run), a SIGKILLed run resumed byte-identical; `[depth]` samples whose H is
//! exactly `stscam matrix --depth-mm D` and whose noiseless captures are H_D f + offset.

use std::path::Path;

use crate::common::{assert_same_tree, stscam, write};

/// A 3-D recipe on a black background (display off, no environment): the head and the hand,
/// a 48×48 crop with the paper's field of view, 24×24 frontal.
fn meshes_recipe(name: &str, samples: usize, spp: u32) -> String {
    format!(
        r#"name = "{name}"
seed = 5
samples = {samples}
mode = "render"
spp = {spp}
noise = "none"
[scene]
set = ["display.enabled=false", "sensor.crop_px=[48,48]", "sensor.pitch_um=44.0"]
[split]
train = 0.5
val = 0.25
test = 0.25
[objects]
size_px = 24
[[objects.sources]]
generator = "meshes"
builtin = ["head"]
distance_mm = [450.0, 650.0]
x_mm = [-60.0, 60.0]
y_mm = [-40.0, 10.0]
environment = [0.0, 0.0]
[[objects.sources]]
generator = "meshes"
builtin = ["hand"]
distance_mm = [70.0, 150.0]
y_mm = [-170.0, -110.0]
environment = [0.0, 0.0]
"#
    )
}

fn ok(args: &[&str]) -> String {
    let out = stscam(args);
    assert!(
        out.status.success(),
        "stscam {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// `stscam dataset RECIPE --out OUT` (plus `extra`), asserted to succeed; returns stderr.
fn build(recipe: &Path, out: &Path, extra: &[&str]) -> String {
    let mut args = vec![
        "dataset",
        recipe.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend(extra);
    ok(&args)
}

fn metadata(root: &Path) -> Vec<(String, serde_json::Value)> {
    let mut out = Vec::new();
    for split in ["train", "val", "test"] {
        if let Ok(text) = std::fs::read_to_string(root.join(split).join("metadata.jsonl")) {
            for line in text.lines() {
                out.push((split.to_string(), serde_json::from_str(line).unwrap()));
            }
        }
    }
    out
}

fn npy(p: &Path) -> (Vec<usize>, Vec<f32>) {
    stscam::io::read_npy_f32(p).unwrap()
}

/// 16-bit grey PNG samples.
fn mask(p: &Path) -> Vec<u16> {
    let img = stscam::io::load_image(p).unwrap();
    assert_eq!(img.channels, 1);
    img.values
        .iter()
        .map(|&v| (f64::from(v) * 65535.0).round() as u16)
        .collect()
}

/// Horizontal centroid of an image (columns weighted by their sum), in fractions of the width.
fn column_centroid(v: &[f32], w: usize) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (i, &x) in v.iter().enumerate() {
        let c = (i % w) as f64 + 0.5;
        num += c * f64::from(x);
        den += f64::from(x);
    }
    num / den / w as f64
}

/// One 3-D sample's alignment (see docs/datasets.md); returns
/// (mesh in view, |capture centroid − frontal centroid|, the same with the frontal mirrored).
fn check_sample(dir: &Path, v: &serde_json::Value) -> (bool, f64, f64) {
    let f = |k: &str| dir.join(v[k].as_str().unwrap());
    let (cs, cap) = npy(&f("capture_npy"));
    let (fs, fr) = npy(&f("frontal_npy"));
    let (ds, depth) = npy(&f("depth_npy"));
    let m = mask(&f("mask_file_name"));
    assert_eq!(cs, vec![48, 48]);
    assert_eq!(fs, vec![24, 24]);
    assert_eq!(ds, vec![24, 24]);
    assert_eq!(m.len(), 24 * 24);
    let value = v["mask_value"].as_u64().unwrap() as u16;
    assert_eq!(value, 1, "the scene has no objects of its own");
    let b = &v["bounds_mm"];
    let (zlo, zhi) = (-b[1][2].as_f64().unwrap(), -b[0][2].as_f64().unwrap());
    assert!(
        zlo >= 5.0 - 1e-9,
        "the mesh keeps 5 mm from the plate: {zlo}"
    );
    let n = 24;
    for i in 0..n * n {
        // The mask is nonzero exactly where the centre ray hits something: no light is seen
        // (the key light turns its back to the camera, the glow is transparent from behind).
        assert_eq!(
            m[i] != 0,
            depth[i].is_finite(),
            "pixel {i}: {} {}",
            m[i],
            depth[i]
        );
        if m[i] == value {
            let z = f64::from(depth[i]);
            assert!(
                z >= zlo * (1.0 - 1e-6) && z <= zhi * (1.0 + 1e-6),
                "pixel {i}: depth {z} outside the mesh's bounds [{zlo}, {zhi}]"
            );
        } else {
            assert_eq!(m[i], 0);
        }
        // Black background: a pixel whose 3×3 neighbourhood is all background gets no light
        // (its area samples cannot reach the mesh).
        let (r, c) = ((i / n) as isize, (i % n) as isize);
        let far = (-1..=1).all(|dr| {
            (-1..=1).all(|dc| {
                let (rr, cc) = (r + dr, c + dc);
                rr < 0
                    || cc < 0
                    || rr >= n as isize
                    || cc >= n as isize
                    || m[(rr * n as isize + cc) as usize] == 0
            })
        });
        if far {
            assert_eq!(fr[i], 0.0, "pixel {i}: light outside the mask");
        }
        assert!(fr[i].is_finite() && fr[i] >= 0.0);
    }
    let seen = m.contains(&value);
    if !seen {
        return (false, 0.0, 0.0);
    }
    // Capture and frontal cover the same field: the replicas shift the subject vertically
    // only, so their horizontal centroids agree.
    let mirrored: Vec<f32> = (0..n * n)
        .map(|i| fr[(i / n) * n + (n - 1 - i % n)])
        .collect();
    let cc = column_centroid(&cap, 48);
    (
        true,
        (cc - column_centroid(&fr, n)).abs(),
        (cc - column_centroid(&mirrored, n)).abs(),
    )
}

#[test]
fn meshes_samples_align_capture_frontal_depth_and_mask() {
    let dir = tempfile::tempdir().unwrap();
    let r = write(dir.path(), "r.toml", &meshes_recipe("align", 10, 8));
    let out = dir.path().join("ds");
    build(&r, &out, &[]);
    let card: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(card["object_shape"], serde_json::json!([24, 24]));
    assert_eq!(card["capture_shape"], serde_json::json!([48, 48]));
    let files = card["files"].as_object().unwrap();
    // Six files per sample, the metadata of three splits and scene.json; no H for 3-D scenes.
    assert_eq!(files.len(), 10 * 6 + 3 + 1, "{:?}", files.keys());
    assert!(!files.keys().any(|k| k.ends_with("H.npz")));
    let meta = metadata(&out);
    assert_eq!(meta.len(), 10);
    let (mut seen, mut meshes) = (0, std::collections::BTreeSet::new());
    // Tolerance of the centroid check: 4 % of the width (measured up to 1.8 % for the head).
    // It applies to the head, 450-650 mm away, near the camera's 550 mm focus: the hand,
    // 70-150 mm away, is strongly defocused and its replicas bring parts from above and below
    // the frontal field into the capture (measured up to 17 %). A mirrored frontal must fail
    // it where the head is off-centre.
    let tol = 0.04;
    let mut mirrored_fails = 0;
    for (split, v) in &meta {
        for k in [
            "file_name",
            "capture_npy",
            "frontal_npy",
            "frontal_file_name",
            "depth_npy",
            "mask_file_name",
        ] {
            let rel = format!("{split}/{}", v[k].as_str().unwrap());
            assert!(files.contains_key(&rel), "{rel} not in the card");
        }
        meshes.insert(v["mesh"].as_str().unwrap().to_string());
        let (in_view, d, d_mirrored) = check_sample(&out.join(split), v);
        if in_view {
            seen += 1;
        }
        if in_view && v["mesh"] == "head" {
            assert!(d < tol, "sample {}: centroids differ by {d:.3}", v["id"]);
            if d_mirrored > tol {
                mirrored_fails += 1;
            }
        }
    }
    assert!(seen >= 6, "only {seen} of 10 samples show their mesh");
    assert!(
        mirrored_fails >= 2,
        "a mirrored frontal passes the centroid check"
    );
    assert_eq!(meshes.len(), 2, "{meshes:?}");
}

#[test]
fn meshes_shards_merged_and_thread_counts_give_one_runs_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let r = write(dir.path(), "r.toml", &meshes_recipe("shards3d", 6, 4));
    let r = r.to_str().unwrap();
    let whole = dir.path().join("whole");
    ok(&["dataset", r, "--out", whole.to_str().unwrap()]);
    let one = dir.path().join("one");
    ok(&[
        "dataset",
        r,
        "--out",
        one.to_str().unwrap(),
        "--threads",
        "1",
    ]);
    assert_same_tree(&whole, &one);
    let mut shards = Vec::new();
    for i in 0..3 {
        let d = dir.path().join(format!("s{i}"));
        let spec = format!("{i}/3");
        ok(&["dataset", r, "--out", d.to_str().unwrap(), "--shard", &spec]);
        shards.push(d);
    }
    let merged = dir.path().join("merged");
    crate::common::merge_shards(&shards, &merged);
    assert_same_tree(&whole, &merged);
    // Another seed gives other draws (the bytes depend on the seed, not only on the recipe's
    // shape).
    let r2 = write(
        dir.path(),
        "r2.toml",
        &meshes_recipe("shards3d", 6, 4).replace("seed = 5", "seed = 6"),
    );
    let other = dir.path().join("other");
    build(&r2, &other, &[]);
    let (a, b) = (metadata(&whole), metadata(&other));
    assert_ne!(a[0].1["position_mm"], b[0].1["position_mm"]);
}

#[test]
fn meshes_sigkill_and_resume_give_the_uninterrupted_files() {
    let dir = tempfile::tempdir().unwrap();
    let r = write(dir.path(), "r.toml", &meshes_recipe("kill3d", 12, 64));
    let whole = dir.path().join("whole");
    build(&r, &whole, &[]);
    let killed = dir.path().join("killed");
    crate::common::dataset_killed_midway(&r, &killed, 12);
    let msg = build(&r, &killed, &["--resume"]);
    assert!(
        !msg.contains(" 12 generated now"),
        "nothing was kept: {msg}"
    );
    assert_same_tree(&whole, &killed);
}

/// A `[depth]` recipe: 3 depths, noiseless, matrix mode, 16×16 objects.
fn depth_recipe(depth: &str) -> String {
    format!(
        r#"name = "depths"
seed = 9
samples = 12
mode = "matrix"
spp = 4
noise = "none"
[scene]
set = ["sensor.crop_px=[48,48]", "sensor.pitch_um=44.0"]
[split]
train = 1.0
val = 0.0
test = 0.0
[depth]
{depth}
[objects]
size_px = 16
[[objects.sources]]
generator = "glyphs"
[[objects.sources]]
generator = "smooth"
"#
    )
}

#[test]
fn depth_samples_use_the_h_of_matrix_depth_mm_at_their_depth() {
    let dir = tempfile::tempdir().unwrap();
    let r = write(
        dir.path(),
        "r.toml",
        &depth_recipe("grid_mm = \"300:700:3\""),
    );
    let out = dir.path().join("ds");
    build(&r, &out, &[]);
    let card: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("dataset.json")).unwrap()).unwrap();
    let scenes = card["scenes"].as_array().unwrap();
    assert_eq!(scenes.len(), 3);
    let depths: Vec<f64> = scenes
        .iter()
        .map(|s| s["params"]["depth_mm"].as_f64().unwrap())
        .collect();
    assert_eq!(depths, vec![300.0, 500.0, 700.0]);
    // The depths of one scene share H's seed (one-pass depth stack semantics).
    assert_eq!(scenes[0]["matrix_seed"], scenes[2]["matrix_seed"]);
    let seed = scenes[0]["matrix_seed"].as_u64().unwrap().to_string();
    // H of each depth is byte for byte `stscam matrix --depth-mm D` with the same scene, seed
    // and spp; the H of another depth is not (the cross-check can fail).
    let matrix = |d: f64| {
        let m = dir.path().join(format!("m{d}"));
        ok(&[
            "matrix",
            "--out",
            m.to_str().unwrap(),
            "--spp",
            "4",
            "--seed",
            &seed,
            "--depth-mm",
            &d.to_string(),
            "--set",
            "sensor.crop_px=[48,48]",
            "--set",
            "sensor.pitch_um=44.0",
            "--set",
            "display.image=black@16",
        ]);
        std::fs::read(m.join("H.npz")).unwrap()
    };
    let h500 = std::fs::read(out.join("scene_001/H.npz")).unwrap();
    assert!(h500 == matrix(500.0), "scene_001 is not H at 500 mm");
    assert!(h500 != matrix(700.0), "H does not depend on the depth");
    // Every sample records a grid depth and its scene; its noiseless capture is H_D f + offset.
    let meta = metadata(&out);
    assert_eq!(meta.len(), 12);
    let mut used = std::collections::BTreeSet::new();
    for (split, v) in &meta {
        let d = v["depth_mm"].as_f64().unwrap();
        let k = depths.iter().position(|&x| x == d).unwrap();
        assert_eq!(v["scene"], scenes[k]["id"]);
        used.insert(k);
        let id = v["scene"].as_str().unwrap();
        let m = stscam::matrix::load_matrix(&out.join(id).join("H.npz"), None, None).unwrap();
        let offset = m.offset.unwrap();
        let (_, obj) = npy(&out.join(split).join(v["object_npy"].as_str().unwrap()));
        let (_, cap) = npy(&out.join(split).join(v["capture_npy"].as_str().unwrap()));
        let g =
            m.h.mul_vec(&obj.iter().map(|&x| f64::from(x)).collect::<Vec<_>>());
        let peak = g.iter().cloned().fold(0.0, f64::max);
        assert!(peak > 0.0);
        for ((gi, oi), ci) in g.iter().zip(&offset).zip(&cap) {
            assert!((gi + f64::from(*oi) - f64::from(*ci)).abs() <= 1e-6 * peak);
        }
    }
    assert!(used.len() >= 2, "12 samples drew only {used:?}");
    // values_mm gives the same grid and so the same bytes.
    let r2 = write(
        dir.path(),
        "r2.toml",
        &depth_recipe("values_mm = [300.0, 500.0, 700.0]"),
    );
    let out2 = dir.path().join("ds2");
    build(&r2, &out2, &[]);
    for rel in [
        "train/metadata.jsonl",
        "scene_002/H.npz",
        "train/000003_capture.npy",
    ] {
        assert!(
            std::fs::read(out.join(rel)).unwrap() == std::fs::read(out2.join(rel)).unwrap(),
            "{rel}"
        );
    }
}

#[test]
fn bad_depth_and_meshes_keys_are_refused_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [(String, &str); 9] = [
        (depth_recipe("grid_mm = \"300:700\""), "depth.grid_mm"),
        (depth_recipe("values_mm = [300.0, -1.0]"), "depth.values_mm"),
        (
            depth_recipe("grid_mm = \"300:700:3\"").replace("\"matrix\"", "\"render\""),
            "depth",
        ),
        (
            meshes_recipe("b", 3, 2)
                .replace("distance_mm = [70.0, 150.0]", "distance_mm = [150.0, 70.0]"),
            "objects.sources[1].distance_mm",
        ),
        (
            meshes_recipe("b", 3, 2).replace("builtin = [\"hand\"]", "builtin = [\"foot\"]"),
            "objects.sources[1].builtin",
        ),
        (
            meshes_recipe("b", 3, 2).replace("\"render\"", "\"matrix\""),
            "objects.sources[0].generator",
        ),
        (
            meshes_recipe("b", 3, 2).replace("size_px = 24", "size_px = 24\nfrontal_spp = 0"),
            "objects.frontal_spp",
        ),
        (
            meshes_recipe("b", 3, 2)
                .replace("size_px = 24", "size_px = 1024\nfrontal_spp = 4000000000"),
            "objects.frontal_spp",
        ),
        (
            depth_recipe("values_mm = [300.0]")
                .replace("size_px = 16", "size_px = 16\nfrontal_spp = 4"),
            "objects.frontal_spp",
        ),
    ];
    for (i, (text, key)) in cases.iter().enumerate() {
        let r = write(dir.path(), &format!("r{i}.toml"), text);
        let o = dir.path().join(format!("o{i}"));
        let out = stscam(&["dataset", r.to_str().unwrap(), "--out", o.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{key}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(
            err.contains(&format!("r{i}.toml")) && err.contains(key),
            "{key}: {err}"
        );
        assert!(!o.exists(), "{key}: something was written");
    }
}

/// `objects.frontal_space` writes the 3-D ground truth in a standard colour space with the
/// library function of `render --frontal-space`: with `xyz` and `linear-srgb` the frontal
/// arrays have three channels ([3, h, w]) and `metadata.jsonl` records the space, the
/// captures (mono), depths and masks keep the bytes of the sensor run, and the linear-sRGB
/// frontal image is the IEC 61966-2-1 matrix times the XYZ one (the same samples, weighted by
/// M·cmf; tolerance 1e-5 of the largest value). An explicit `"sensor"` gives the default
/// run's sample files; another spelling is refused in one line naming the key.
#[test]
fn meshes_frontal_space_writes_xyz_and_linear_srgb() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let run = |space: Option<&str>| {
        let mut text = meshes_recipe("fs", 2, 2);
        if let Some(s) = space {
            text = text.replace(
                "size_px = 24\n",
                &format!("size_px = 24\nfrontal_space = \"{s}\"\n"),
            );
        }
        let tag = space.unwrap_or("default");
        let r = write(d, &format!("{tag}.toml"), &text);
        let out = d.join(tag);
        build(&r, &out, &[]);
        out
    };
    let (base, sensor, xyz, srgb) = (
        run(None),
        run(Some("sensor")),
        run(Some("xyz")),
        run(Some("linear-srgb")),
    );
    // The same files, except that the recipe recorded in dataset.json names the key.
    let (mut ts, mut tb) = (crate::common::tree(&sensor), crate::common::tree(&base));
    let (js, jb) = (
        ts.remove("dataset.json").unwrap(),
        tb.remove("dataset.json").unwrap(),
    );
    assert!(ts == tb, "an explicit \"sensor\" changes the sample files");
    assert!(String::from_utf8_lossy(&js).contains("frontal_space"));
    assert!(!String::from_utf8_lossy(&jb).contains("frontal_space"));
    let m = metadata(&base);
    assert_eq!(m.len(), 2);
    let file = |root: &Path, split: &str, v: &serde_json::Value, k: &str| {
        root.join(split).join(v[k].as_str().unwrap())
    };
    for (split, v) in &m {
        assert!(v.get("frontal_space").is_none());
        let (shape, _) = npy(&file(&base, split, v, "frontal_npy"));
        assert_eq!(shape, vec![24, 24]);
        let (_, fx) = npy(&file(&xyz, split, v, "frontal_npy"));
        let (shape_s, fs) = npy(&file(&srgb, split, v, "frontal_npy"));
        assert_eq!(shape_s, vec![3, 24, 24], "frontal_space ignored");
        for k in ["capture_npy", "depth_npy", "mask_file_name"] {
            for other in [&xyz, &srgb] {
                assert_eq!(
                    std::fs::read(file(&base, split, v, k)).unwrap(),
                    std::fs::read(file(other, split, v, k)).unwrap(),
                    "{k}"
                );
            }
        }
        let mx = stscam::world::colour::XYZ_TO_LINEAR_SRGB;
        let n = 24 * 24;
        let big = fx.iter().fold(0f32, |a, b| a.max(b.abs())).max(1e-30);
        assert!(big > 0.0);
        for i in 0..n {
            for r in 0..3 {
                let want: f64 = (0..3).map(|c| mx[r][c] * f64::from(fx[c * n + i])).sum();
                let got = f64::from(fs[r * n + i]);
                assert!(
                    (got - want).abs() <= 1e-5 * f64::from(big),
                    "pixel {i} ch {r}: {got} vs {want}"
                );
            }
        }
    }
    for (root, name) in [(&xyz, "xyz"), (&srgb, "linear-srgb")] {
        for (split, v) in metadata(root) {
            assert_eq!(v["frontal_space"], name, "{split}");
        }
    }
    let bad = write(
        d,
        "bad.toml",
        &meshes_recipe("fs", 2, 2)
            .replace("size_px = 24\n", "size_px = 24\nfrontal_space = \"srgb\"\n"),
    );
    let out = stscam(&[
        "dataset",
        bad.to_str().unwrap(),
        "--out",
        d.join("bad").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("objects.frontal_space"), "{err}");
}

/// `[camera_table]`: the run draws the design's camera-side table once and renders every
/// capture from it; two shards merged give the whole run's bytes (the table is seeded by the
/// recipe), the captures differ from the direct estimator's, and a zero count or an unknown
/// key in the section is refused naming the key.
#[test]
fn meshes_with_a_camera_table_keep_shards_and_refuse_bad_keys() {
    let dir = tempfile::tempdir().unwrap();
    let table = "\n[camera_table]\nspp = 16\nreps = 8\n";
    let text = meshes_recipe("table3d", 4, 4) + table;
    let r = write(dir.path(), "r.toml", &text);
    let whole = dir.path().join("whole");
    build(&r, &whole, &[]);
    let mut shards = Vec::new();
    for i in 0..2 {
        let d = dir.path().join(format!("s{i}"));
        build(&r, &d, &["--shard", &format!("{i}/2")]);
        shards.push(d);
    }
    let merged = dir.path().join("merged");
    crate::common::merge_shards(&shards, &merged);
    assert_same_tree(&whole, &merged);
    // With a cache directory the first run writes the table and a later one reads it: the
    // same samples either way.
    let cached_text = text.replace("reps = 8", "reps = 8\ndir = \"tables\"");
    let rc = write(dir.path(), "rc.toml", &cached_text);
    for out in ["c1", "c2"] {
        build(&rc, &dir.path().join(out), &[]);
    }
    assert_eq!(crate::common::files_in(&dir.path().join("tables")).len(), 1);
    let (c1, c2) = (metadata(&dir.path().join("c1")), metadata(&whole));
    assert_eq!(c1.len(), c2.len());
    let file = c1[0].1["capture_npy"].as_str().unwrap().to_string();
    let cap_at = |root: &Path| npy(&root.join(&c1[0].0).join(&file)).1;
    assert_eq!(cap_at(&dir.path().join("c1")), cap_at(&whole));
    assert_eq!(cap_at(&dir.path().join("c2")), cap_at(&whole));
    let plain = dir.path().join("plain");
    build(
        &write(dir.path(), "p.toml", &meshes_recipe("table3d", 4, 4)),
        &plain,
        &[],
    );
    let (a, b) = (metadata(&whole), metadata(&plain));
    assert_eq!(a[0].1["position_mm"], b[0].1["position_mm"]);
    let file = a[0].1["capture_npy"].as_str().unwrap().to_string();
    let cap = |root: &Path| npy(&root.join(&a[0].0).join(&file)).1;
    assert_ne!(cap(&whole), cap(&plain));
    for (i, (bad, key)) in [
        (text.replace("spp = 16", "spp = 0"), "camera_table.spp"),
        (text.replace("reps = 8", "reps = 0"), "camera_table.reps"),
        (text.replace("reps = 8", "repz = 8"), "repz"),
        // A cache folder that is a file or a device: refused before anything is written (the
        // run marker and scene_000/scene.json were written first).
        (
            text.replace("reps = 8", "reps = 8\ndir = \"r.toml\""),
            "camera_table.dir",
        ),
        (
            text.replace("reps = 8", "reps = 8\ndir = \"/dev/null\""),
            "camera_table.dir",
        ),
    ]
    .iter()
    .enumerate()
    {
        let r = write(dir.path(), &format!("b{i}.toml"), bad);
        let o = dir.path().join(format!("b{i}"));
        let out = stscam(&["dataset", r.to_str().unwrap(), "--out", o.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{key}: {err}");
        assert!(err.contains(key), "{key}: {err}");
        assert!(!o.exists());
    }
}

/// `objects.frontal_spp` sets the frontal ground truth's samples apart from the capture's:
/// the captures keep the bytes of the run without it, the frontal images change, and at 8
/// samples against 2 they lie closer to 32-sample ones (their error is about half: the test
/// asks for less than 0.75 of it); the card's recipe records the key.
#[test]
fn meshes_frontal_spp_changes_only_the_frontal() {
    let dir = tempfile::tempdir().unwrap();
    let base = meshes_recipe("fspp", 4, 2);
    let with = |n: u32| base.replace("size_px = 24", &format!("size_px = 24\nfrontal_spp = {n}"));
    let mut outs = Vec::new();
    for (name, text) in [("plain", base.clone()), ("f8", with(8)), ("f32", with(32))] {
        let r = write(dir.path(), &format!("{name}.toml"), &text);
        let out = dir.path().join(name);
        build(&r, &out, &[]);
        outs.push(out);
    }
    let card: serde_json::Value =
        serde_json::from_slice(&std::fs::read(outs[1].join("dataset.json")).unwrap()).unwrap();
    assert_eq!(card["recipe"]["objects"]["frontal_spp"], 8);
    let meta = metadata(&outs[0]);
    assert_eq!(meta.len(), 4);
    let (mut err2, mut err8, mut seen) = (0.0, 0.0, 0);
    for (split, v) in &meta {
        let file = |out: &Path, k: &str| npy(&out.join(split).join(v[k].as_str().unwrap())).1;
        let caps: Vec<_> = outs.iter().map(|o| file(o, "capture_npy")).collect();
        assert_eq!(caps[0], caps[1]);
        assert_eq!(caps[0], caps[2]);
        let fr: Vec<_> = outs.iter().map(|o| file(o, "frontal_npy")).collect();
        // A sample whose mesh is outside the frontal field is black at any spp.
        if fr[2].iter().all(|&x| x == 0.0) {
            continue;
        }
        seen += 1;
        assert!(fr[0] != fr[1], "{split}: the frontal did not change");
        let sq = |a: &[f32], b: &[f32]| -> f64 {
            a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum()
        };
        err2 += sq(&fr[0], &fr[2]);
        err8 += sq(&fr[1], &fr[2]);
    }
    assert!(seen >= 2, "{seen} samples with a visible mesh");
    assert!(err2 > 0.0 && err8 < 0.75 * err2, "{err8} vs {err2}");
}
