//! Issue 29, item 1: the 3-D, depth-stack and sidecar inputs held to the old rules. Each hostile
//! input is refused with exit 2 and one line naming the file and the key, nothing written, and
//! within a time limit (a hang or a superquadratic build fails the test), or handled within the
//! documented bound (docs/limits.md).
//!
//! Every fixture is written into a temporary folder by the test itself.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::{files_in, stscam, stscam_ok};
use serde_json::json;

/// Runs stscam with a time limit; returns (exit code, stderr, seconds).
fn run_timed(args: &[&str], limit_s: u64) -> (Option<i32>, String, f64) {
    let start = Instant::now();
    let mut child = Command::new(env!("CARGO_BIN_EXE_stscam"))
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(limit_s) {
            child.kill().unwrap();
            let _ = child.wait();
            panic!("stscam {args:?} ran longer than {limit_s} s");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
    (status.code(), err, start.elapsed().as_secs_f64())
}

/// A render of `scene` into `out` that must be refused: exit 2, one line holding every word of
/// `expect`, no output folder. Returns the line and the seconds it took.
fn refused(scene: &Path, out: &Path, expect: &[&str], limit_s: u64) -> (String, f64) {
    let (code, err, secs) = run_timed(
        &[
            "render",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--spp",
            "1",
            "--set",
            "sensor.crop_px=[16,16]",
        ],
        limit_s,
    );
    assert_eq!(code, Some(2), "{}: {err}", scene.display());
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    for w in expect {
        assert!(err.contains(w), "{:?} lacks {w:?}", err.trim_end());
    }
    assert!(!out.exists(), "wrote {:?}", files_in(out));
    (err.trim_end().to_string(), secs)
}

fn scene_with(dir: &Path, name: &str, mesh: &str, extra: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(
        &p,
        format!(
            "[display]\nenabled = false\n[[object]]\nmesh = \"{mesh}\"\nposition_mm = [0.0, 0.0, -400.0]\n{extra}"
        ),
    )
    .unwrap();
    p
}

const TRI_OBJ: &str = "v 0 0 0\nv 10 0 0\nv 0 10 0\nf 1 2 3\n";

/// A glTF quad (one mesh) with the given nodes and scene roots, buffer as a data URI.
fn gltf_with_nodes(nodes: serde_json::Value, roots: serde_json::Value) -> String {
    let mut bin = Vec::new();
    for p in [
        [0f32, 0.0, 0.0],
        [0.01, 0.0, 0.0],
        [0.01, 0.01, 0.0],
        [0.0, 0.01, 0.0],
    ] {
        for c in p {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let b64 = base64(&bin);
    json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": roots}],
        "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": bin.len(), "uri": format!("data:application/octet-stream;base64,{b64}")}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 12}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [0.0, 0.0, 0.0], "max": [0.01, 0.01, 0.0]},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ]
    })
    .to_string()
}

fn base64(bytes: &[u8]) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k)) as usize & 63] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// Coordinates beyond the working range (±1e7 mm) are refused before the BVH: a 1e38 vertex,
/// a node translation or scale of 1e38, an object position of 1e37 or 1e300. Within the range
/// (a vertex at 1e6 mm) the same files render.
#[test]
fn coordinates_beyond_the_working_range_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out");
    std::fs::write(d.join("big.obj"), "v 0 0 0\nv 1e38 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let s = scene_with(d, "big.toml", "big.obj", "");
    refused(&s, &out, &["big.obj", "object.0.mesh", "working range"], 30);
    for (name, node) in [
        (
            "t.gltf",
            json!({"mesh": 0, "translation": [1e38, 0.0, 0.0]}),
        ),
        ("s.gltf", json!({"mesh": 0, "scale": [1e38, 1e38, 1e38]})),
    ] {
        std::fs::write(d.join(name), gltf_with_nodes(json!([node]), json!([0]))).unwrap();
        let s = scene_with(d, "g.toml", name, "");
        refused(&s, &out, &[name, "object.0.mesh", "working range"], 30);
    }
    for z in ["-1e37", "-1e300"] {
        let p = d.join("p.toml");
        std::fs::write(
            &p,
            format!("[display]\nenabled = false\n[[object]]\nmesh = \"quad\"\nposition_mm = [0.0, 0.0, {z}]\n"),
        )
        .unwrap();
        refused(
            &p,
            &out,
            &["p.toml", "object.0.position_mm", "working range"],
            30,
        );
    }
    // Within the range: a far vertex renders (exit 0).
    std::fs::write(d.join("far.obj"), "v 0 0 0\nv 1e6 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let s = scene_with(d, "far.toml", "far.obj", "");
    let o = stscam(&[
        "render",
        s.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--spp",
        "1",
        "--set",
        "sensor.crop_px=[16,16]",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// MTL colour lines with one or two values are refused with the line named (the parser used to
/// panic); a library that is a folder, a FIFO or /dev/zero is reported even though a missing
/// one is tolerated; an OBJ of lines only has no triangles.
#[test]
fn material_lines_and_libraries_are_checked() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out");
    for (i, line) in ["Ke 1", "Kd 0.5 0.5", "Ks 1 1"].iter().enumerate() {
        let mtl = format!("m{i}.mtl");
        std::fs::write(d.join(&mtl), format!("newmtl a\n{line}\n")).unwrap();
        let obj = format!("o{i}.obj");
        std::fs::write(d.join(&obj), format!("mtllib {mtl}\nusemtl a\n{TRI_OBJ}")).unwrap();
        let s = scene_with(d, "m.toml", &obj, "");
        refused(&s, &out, &[&mtl, "object.0.mesh", "line 2", line], 30);
    }
    std::fs::create_dir(d.join("dir.mtl")).unwrap();
    let mut libs = vec![("dir.mtl".to_string(), "directory")];
    if Command::new("mkfifo")
        .arg(d.join("fifo.mtl"))
        .status()
        .is_ok_and(|s| s.success())
    {
        libs.push(("fifo.mtl".into(), "not a regular file"));
    }
    std::os::unix::fs::symlink("/dev/zero", d.join("zero.mtl")).unwrap();
    libs.push(("zero.mtl".into(), "not a regular file"));
    for (lib, what) in libs {
        std::fs::write(
            d.join("l.obj"),
            format!("mtllib {lib}\nusemtl a\n{TRI_OBJ}"),
        )
        .unwrap();
        let s = scene_with(d, "l.toml", "l.obj", "");
        refused(&s, &out, &[&lib, "object.0.mesh", what], 20);
    }
    // A missing library is still tolerated (the shipped face mesh has none).
    std::fs::write(
        d.join("n.obj"),
        format!("mtllib none.mtl\nusemtl a\n{TRI_OBJ}"),
    )
    .unwrap();
    let s = scene_with(d, "n.toml", "n.obj", "");
    let o = stscam(&[
        "render",
        s.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--spp",
        "1",
        "--set",
        "sensor.crop_px=[16,16]",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::remove_dir_all(&out).unwrap();
    std::fs::write(
        d.join("lines.obj"),
        "v 0 0 0\nv 10 0 0\nv 0 10 0\nl 1 2\nl 2 3\n",
    )
    .unwrap();
    let s = scene_with(d, "li.toml", "lines.obj", "");
    refused(
        &s,
        &out,
        &["lines.obj", "object.0.mesh", "no triangles"],
        20,
    );
}

/// A huge emission from the mesh file (MTL Ke 1e30) is refused instead of writing non-finite
/// pixels.
#[test]
fn absurd_emission_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("e.mtl"), "newmtl a\nKe 1e30 1e30 1e30\n").unwrap();
    std::fs::write(
        d.join("e.obj"),
        format!("mtllib e.mtl\nusemtl a\n{TRI_OBJ}"),
    )
    .unwrap();
    let s = scene_with(d, "e.toml", "e.obj", "");
    refused(
        &s,
        &d.join("out"),
        &["object.0.mesh", "emission", "1e12"],
        30,
    );
}

fn copies_obj(path: &Path, copies: usize) {
    let mut s = String::from("v -10 -10 0\nv 10 -10 0\nv 10 10 0\nv -10 10 0\n");
    for _ in 0..copies {
        s.push_str("f 1 2 3 4\n");
    }
    std::fs::write(path, s).unwrap();
}

/// Coincident triangles: 30,000 (which overflowed the stack) and 6,000 or 25,000 copies of one
/// quad (a superquadratic build: 6.6 s and 179 s) are refused at once, before the BVH; a
/// 60-level diamond node DAG (2^60 paths) is refused at the node-instance bound.
#[test]
fn coincident_triangles_and_node_dags_are_refused_quickly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out");
    std::fs::write(
        d.join("same.obj"),
        format!(
            "v 0 0 0\nv 10 0 0\nv 0 10 0\n{}",
            "f 1 2 3\n".repeat(30_000)
        ),
    )
    .unwrap();
    let s = scene_with(d, "same.toml", "same.obj", "");
    refused(
        &s,
        &out,
        &["object.0.mesh", "30000 triangles share one bounding box"],
        30,
    );
    let mut secs = Vec::new();
    for copies in [6_000, 25_000] {
        copies_obj(&d.join("q.obj"), copies);
        let s = scene_with(d, "q.toml", "q.obj", "");
        let (line, t) = refused(&s, &out, &["object.0.mesh", "share one bounding box"], 30);
        assert!(
            line.contains(&format!("{} triangles", 2 * copies)),
            "{line}"
        );
        secs.push(t);
    }
    assert!(secs.iter().all(|&t| t < 10.0), "{secs:?}");
    // 32 copies (64 triangles, the bound) still render.
    copies_obj(&d.join("q.obj"), 32);
    let s = scene_with(d, "q.toml", "q.obj", "");
    stscam_ok(&[
        "render",
        s.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--spp",
        "1",
        "--set",
        "sensor.crop_px=[16,16]",
    ]);
    std::fs::remove_dir_all(&out).unwrap();
    // Diamond DAG: the paths to the mesh double at every level.
    let levels = 60;
    let mut nodes = Vec::new();
    for l in 0..levels {
        // Level l: node 3l has children 3l+1 and 3l+2, both of which have child 3(l+1).
        let next = 3 * (l + 1);
        nodes.push(json!({"children": [3 * l + 1, 3 * l + 2]}));
        nodes.push(json!({"children": [next]}));
        nodes.push(json!({"children": [next]}));
    }
    nodes.push(json!({"mesh": 0}));
    std::fs::write(
        d.join("dag.gltf"),
        gltf_with_nodes(json!(nodes), json!([0])),
    )
    .unwrap();
    let s = scene_with(d, "dag.toml", "dag.gltf", "");
    refused(
        &s,
        &out,
        &["dag.gltf", "object.0.mesh", "node instances"],
        30,
    );
}

/// A PNG of 16,384² pixels in a few hundred KB, given as a texture or an environment map, is
/// refused from its header (before the 1 GiB decode buffer); a mesh file with more than 10⁷
/// triangles is refused before it is parsed; glTF buffers are read only to their byteLength and
/// at most 2 GiB in total.
#[test]
fn sizes_are_bounded_before_allocation() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out");
    {
        let f = std::fs::File::create(d.join("huge.png")).unwrap();
        let mut enc = png::Encoder::new(std::io::BufWriter::new(f), 16_384, 16_384);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::High);
        let mut w = enc.write_header().unwrap().into_stream_writer().unwrap();
        let row = vec![0u8; 16_384];
        for _ in 0..16_384 {
            std::io::Write::write_all(&mut w, &row).unwrap();
        }
        w.finish().unwrap();
    }
    let size = std::fs::metadata(d.join("huge.png")).unwrap().len();
    assert!(size < 1 << 20, "{size}");
    let tex = scene_with(
        d,
        "tex.toml",
        "quad",
        "[object.material]\nbase_color = \"huge.png\"\n",
    );
    let (_, t) = refused(
        &tex,
        &out,
        &["huge.png", "object.0.material.base_color", "16384x16384"],
        30,
    );
    assert!(t < 5.0, "{t} s");
    let env = d.join("env.toml");
    std::fs::write(
        &env,
        "[display]\nenabled = false\n[[light]]\nkind = \"environment\"\nmap = \"huge.png\"\n",
    )
    .unwrap();
    refused(&env, &out, &["huge.png", "light.0.map", "16384x16384"], 30);

    // 10,000,003 triangles in one face line (20 MB): refused before parsing.
    let mut s = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\nf");
    s.push_str(&" 1".repeat(10_000_005));
    s.push('\n');
    std::fs::write(d.join("many.obj"), s).unwrap();
    let m = scene_with(d, "many.toml", "many.obj", "");
    refused(
        &m,
        &out,
        &["many.obj", "object.0.mesh", "10000003 triangles"],
        30,
    );

    // A buffer file far longer than its byteLength (a 3 GB sparse file after the quad's 60
    // bytes): only byteLength bytes are read, and the quad renders.
    let g: serde_json::Value =
        serde_json::from_str(&gltf_with_nodes(json!([{"mesh": 0}]), json!([0]))).unwrap();
    let uri = g["buffers"][0]["uri"].as_str().unwrap().to_string();
    let bin = {
        let b64 = uri.split(',').nth(1).unwrap();
        decode_b64(b64)
    };
    {
        let f = std::fs::File::create(d.join("long.bin")).unwrap();
        std::io::Write::write_all(&mut &f, &bin).unwrap();
        f.set_len(3 << 30).unwrap();
    }
    let mut g1 = g.clone();
    g1["buffers"][0]["uri"] = json!("long.bin");
    std::fs::write(d.join("long.gltf"), g1.to_string()).unwrap();
    let s = scene_with(d, "long.toml", "long.gltf", "");
    let (code, err, t) = run_timed(
        &[
            "render",
            s.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--spp",
            "1",
            "--set",
            "sensor.crop_px=[16,16]",
        ],
        60,
    );
    assert_eq!(code, Some(0), "{err}");
    assert!(t < 10.0, "{t} s");
    std::fs::remove_dir_all(&out).unwrap();
    // Four buffers each declaring 1.9 GB of that file: refused before reading (2 GiB in all).
    let mut g4 = g.clone();
    g4["buffers"] = json!([
        {"byteLength": 1_900_000_000u64, "uri": "long.bin"},
        {"byteLength": 1_900_000_000u64, "uri": "long.bin"},
        {"byteLength": 1_900_000_000u64, "uri": "long.bin"},
        {"byteLength": 1_900_000_000u64, "uri": "long.bin"}
    ]);
    std::fs::write(d.join("four.gltf"), g4.to_string()).unwrap();
    let s = scene_with(d, "four.toml", "four.gltf", "");
    let (_, t) = refused(
        &s,
        &out,
        &["four.gltf", "object.0.mesh", "7600000000 bytes together"],
        30,
    );
    assert!(t < 5.0, "{t} s");
}

fn decode_b64(s: &str) -> Vec<u8> {
    let val = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        _ => 63,
    };
    let mut out = Vec::new();
    let (mut acc, mut bits) = (0u32, 0);
    for c in s.bytes().take_while(|&c| c != b'=') {
        acc = (acc << 6) | u32::from(val(c));
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    out
}

/// 1,100 heads in one scene: refused at the scene's triangle bound (10⁷) after at most the
/// objects that fit, within the memory that bound implies (it used to panic at 3.5 GB).
#[test]
fn many_heads_are_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut s = String::from("[display]\nenabled = false\n");
    for i in 0..1100 {
        s.push_str(&format!(
            "[[object]]\nmesh = \"head\"\nposition_mm = [{i}.0, 0.0, -600.0]\n"
        ));
    }
    let p = d.join("heads.toml");
    std::fs::write(&p, s).unwrap();
    refused(
        &p,
        &d.join("out"),
        &["heads.toml", ".mesh", "10000000 triangles"],
        120,
    );
}

/// Depth stacks: `--depth-mm` beyond [1e-3, 1e7] mm is bad input (exit 2, not a failed
/// write); a stack sidecar that is a FIFO or /dev/zero is refused at once; a NaN in a stack
/// offset is refused as on the 2-D path.
#[test]
fn stack_inputs_are_checked() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for depth in ["1e300", "5e-324", "400,1e300"] {
        let out = d.join("m");
        let (code, err, _) = run_timed(
            &[
                "matrix",
                "--out",
                out.to_str().unwrap(),
                "--spp",
                "1",
                "--set",
                "sensor.crop_px=16",
                "--depth-mm",
                depth,
            ],
            30,
        );
        assert_eq!(code, Some(2), "{depth}: {err}");
        assert!(
            err.contains("--depth-mm") && err.trim_end().lines().count() == 1,
            "{err}"
        );
        assert!(!out.exists());
    }
    let stack = d.join("stack");
    stscam_ok(&[
        "matrix",
        "--out",
        stack.to_str().unwrap(),
        "--spp",
        "1",
        "--set",
        "sensor.crop_px=24",
        "--set",
        "display.image=letter:F@8",
        "--depth-mm",
        "400,550",
    ]);
    let cap = d.join("cap");
    stscam_ok(&[
        "render",
        "--out",
        cap.to_str().unwrap(),
        "--spp",
        "1",
        "--set",
        "sensor.crop_px=24",
        "--set",
        "display.image=letter:F@8",
    ]);
    let recon = |out: &Path| {
        run_timed(
            &[
                "reconstruct",
                "--matrix",
                stack.join("H_stack.npz").to_str().unwrap(),
                "--capture",
                cap.join("capture.exr").to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ],
            30,
        )
    };
    // A NaN in the layered offset.
    let off = stack.join("offset_stack.npy");
    let good = std::fs::read(&off).unwrap();
    let mut bad = good.clone();
    let n = bad.len();
    bad[n - 4..].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&off, &bad).unwrap();
    let out = d.join("r");
    let (code, err, _) = recon(&out);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("offset_stack.npy") && err.contains("not finite") || err.contains("NaN"),
        "{err}"
    );
    assert!(!out.exists());
    std::fs::write(&off, &good).unwrap();
    let (code, err, _) = recon(&out);
    assert_eq!(code, Some(0), "the repaired stack must reconstruct: {err}");
    std::fs::remove_dir_all(&out).unwrap();
    // The sidecar as /dev/zero and as a FIFO.
    let side = stack.join("H_stack.json");
    std::fs::remove_file(&side).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &side).unwrap();
    let (code, err, t) = recon(&out);
    assert_ne!(code, Some(0), "{err}");
    assert!(code == Some(2) && err.contains("H_stack"), "{err}");
    assert!(t < 10.0);
    std::fs::remove_file(&side).unwrap();
    if Command::new("mkfifo")
        .arg(&side)
        .status()
        .is_ok_and(|s| s.success())
    {
        let (code, err, t) = recon(&out);
        assert_eq!(code, Some(2), "{err}");
        assert!(t < 10.0, "{t}");
    }
    assert!(!out.exists());
}

/// A mesh dataset folder holding an OBJ of more than 10⁷ triangles (a 20 MB file) is refused
/// before the file is parsed: exit 2, one line naming the recipe key and the file, no output.
#[test]
fn mesh_dataset_with_a_huge_mesh_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("meshes")).unwrap();
    let mut s = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\nf");
    s.push_str(&" 1".repeat(10_000_005));
    s.push('\n');
    std::fs::write(d.join("meshes/many.obj"), s).unwrap();
    let recipe = d.join("r.toml");
    std::fs::write(
        &recipe,
        "name = \"x\"\nseed = 5\nsamples = 2\nmode = \"render\"\nspp = 1\nnoise = \"none\"\n\
         [scene]\nset = [\"display.enabled=false\", \"sensor.crop_px=[16,16]\"]\n\
         [split]\ntrain = 0.5\nval = 0.25\ntest = 0.25\n[objects]\nsize_px = 8\n\
         [[objects.sources]]\ngenerator = \"meshes\"\nfolder = \"meshes\"\n\
         distance_mm = [450.0, 650.0]\nenvironment = [0.0, 0.0]\n",
    )
    .unwrap();
    let out = d.join("out");
    let (code, err, t) = run_timed(
        &[
            "dataset",
            recipe.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        60,
    );
    assert_eq!(code, Some(2), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains("objects.sources[0].folder") && err.contains("many.obj"),
        "{err}"
    );
    assert!(err.contains("10000003 triangles"), "{err}");
    assert!(t < 20.0, "{t} s");
    assert!(!out.exists());
}

/// Depth-stack memory: a 256-depth stack at paper size and 64 spp is refused from its estimate
/// (exit 2, one line naming `--depth-mm` with the estimate and the 16 GiB limit, nothing
/// written) in well under a second; through the library a test limit below a small stack's
/// estimated peak refuses it before the pass, and the job limit gives the unbounded pass's
/// matrices.
#[test]
fn stack_memory_is_estimated_before_the_pass() {
    use stscam::matrix::{compute_matrix_stack, compute_matrix_stack_within};
    use stscam::render::RenderSettings;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m");
    let (code, err, secs) = run_timed(
        &[
            "matrix",
            "--out",
            out.to_str().unwrap(),
            "--spp",
            "64",
            "--depth-mm",
            "300:650:256",
        ],
        30,
    );
    assert_eq!(code, Some(2), "{err}");
    let line = err.lines().find(|l| l.starts_with("error:")).unwrap_or("");
    assert!(
        line.starts_with("error: --depth-mm: the 256 matrices would need about ")
            && line.contains("more than the 16 GiB accepted"),
        "{err}"
    );
    assert!(secs < 3.0, "{secs} s");
    assert!(!out.exists());

    let ov = [
        "sensor.crop_px=[48,48]".to_string(),
        "sensor.pitch_um=60".to_string(),
        "display.image=letter:F@16".to_string(),
    ];
    let sys =
        stscam::system::System::build(&stscam::scene::load_scene(None, &ov).unwrap()).unwrap();
    let set = RenderSettings::lattice(4, 1, false);
    let depths = [350.0, 450.0, 550.0];
    // A limit below the bound of one entry per object pixel makes the pilot run; half the
    // estimated peak is refused before the pass, naming --depth-mm.
    let mem = stscam::matrix::estimate_stack_memory(&sys, &set, &depths, 0);
    assert_eq!(mem.pilot_pixels, 256);
    let t = Instant::now();
    let e = compute_matrix_stack_within(&sys, &set, &depths, mem.estimated_peak_bytes() / 2)
        .unwrap_err();
    assert_eq!(e.setting, "--depth-mm");
    assert!(e.message.contains("estimated from 256 pilot pixels"), "{e}");
    assert!(t.elapsed() < Duration::from_secs(2));
    // The estimate against the pass's true count (a stratified sample of 256 of 2304 pixels:
    // within 10 %), and the job limit runs the pass unchanged.
    let full = compute_matrix_stack(&sys, &set, &depths);
    let nnz: usize = full.iter().map(|m| m.h.nnz()).sum();
    let rel = mem.entries / nnz as f64;
    assert!((0.9..1.1).contains(&rel), "estimate / count = {rel}");
    let (within, m2) =
        compute_matrix_stack_within(&sys, &set, &depths, stscam::limits::MAX_JOB_BYTES).unwrap();
    assert_eq!(m2.pilot_pixels, 0, "the bound fits: nothing traced");
    for (a, b) in within.iter().zip(&full) {
        assert_eq!(a.h, b.h);
        assert_eq!(a.offset, b.offset);
    }
}
