//! Real assets loaded faithfully or refused clearly: each test writes its own small glTF or
//! OBJ file showing one feature, checks what the loader makes of it against a computation
//! written out here, and shows that the former (wrong) handling fails the same check.

use std::path::Path;

use stscam::world::load::{LoadError, load_asset};

use super::common::stscam;

pub(super) fn b64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= c.len() {
                s.push(T[((n >> (18 - 6 * k)) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// A unit quad (metres) in z = 0 with two texture coordinate sets, as a glTF document with a
/// data-URI buffer; `material` and `extra` (primitive attributes) are spliced in.
pub(super) fn quad_gltf(
    material: serde_json::Value,
    extra_attr: Option<(&str, usize)>,
) -> serde_json::Value {
    let pos: [[f32; 3]; 4] = [[0., 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]];
    let uv0: [[f32; 2]; 4] = [[0., 0.], [1., 0.], [1., 1.], [0., 1.]];
    let uv1: [[f32; 2]; 4] = [[0.25, 0.5], [0.75, 0.5], [0.75, 0.0], [0.25, 0.0]];
    let col: [[f32; 4]; 4] = [[1., 0., 0., 1.]; 4];
    let mut bin = Vec::new();
    for p in pos {
        for v in p {
            bin.extend(v.to_le_bytes());
        }
    }
    for t in uv0.iter().chain(&uv1) {
        for v in t {
            bin.extend(v.to_le_bytes());
        }
    }
    for c in col {
        for v in c {
            bin.extend(v.to_le_bytes());
        }
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend(i.to_le_bytes());
    }
    let mut attrs = serde_json::json!({"POSITION": 0, "TEXCOORD_0": 1, "TEXCOORD_1": 2});
    if let Some((name, acc)) = extra_attr {
        attrs[name] = acc.into();
    }
    serde_json::json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": bin.len(),
                     "uri": format!("data:application/octet-stream;base64,{}", b64(&bin))}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 32},
            {"buffer": 0, "byteOffset": 80, "byteLength": 32},
            {"buffer": 0, "byteOffset": 112, "byteLength": 64},
            {"buffer": 0, "byteOffset": 176, "byteLength": 12}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 3, "componentType": 5126, "count": 4, "type": "VEC4"},
            {"bufferView": 4, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ],
        "images": [{"uri": format!("data:image/png;base64,{}", b64(&png_2x2()))}],
        "textures": [{"source": 0}],
        "materials": [material],
        "meshes": [{"primitives": [{"attributes": attrs, "indices": 4, "material": 0}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0
    })
}

fn png_2x2() -> Vec<u8> {
    stscam::io::encode_png16(2, 2, 3, &[65535; 12], stscam::io::PngTransfer::Srgb).unwrap()
}

pub(super) fn load(
    dir: &Path,
    name: &str,
    doc: &serde_json::Value,
) -> Result<stscam::world::mesh::Asset, LoadError> {
    let p = dir.join(name);
    std::fs::write(&p, serde_json::to_vec(doc).unwrap()).unwrap();
    load_asset(&p, 1.0)
}

/// `texCoord: 1` with `KHR_texture_transform` (used, not required): the loaded coordinates
/// are set 1 mapped by offset (0.1, 0.2), rotation π/2 and scale (2, 4), computed here from
/// the extension's definition u′ = cos r·s_u·u + sin r·s_v·v + o_u,
/// v′ = −sin r·s_u·u + cos r·s_v·v + o_v. Tolerance 1e-6 (f32 inputs). Reading set 0, or
/// set 1 without the transform (the former handling), fails.
#[test]
fn tex_coord_set_and_texture_transform() {
    let dir = tempfile::tempdir().unwrap();
    let mat = serde_json::json!({"pbrMetallicRoughness": {"baseColorTexture": {
        "index": 0, "texCoord": 1,
        "extensions": {"KHR_texture_transform": {"offset": [0.1, 0.2], "rotation": std::f64::consts::FRAC_PI_2, "scale": [2.0, 4.0]}}}}});
    let mut doc = quad_gltf(mat, None);
    doc["extensionsUsed"] = serde_json::json!(["KHR_texture_transform"]);
    let a = load(dir.path(), "tt.gltf", &doc).unwrap();
    let uv1 = [[0.25, 0.5], [0.75, 0.5], [0.75, 0.0], [0.25, 0.0]];
    let uv0 = [[0., 0.], [1., 0.], [1., 1.], [0., 1.]];
    let expect = |u: f64, v: f64| {
        [
            2.0 * 0.0 * u + 4.0 * 1.0 * v + 0.1,
            -2.0 * u + 0.0 * v + 0.2,
        ]
    };
    for (k, got) in a.mesh.uvs.iter().enumerate() {
        let e = expect(uv1[k][0], uv1[k][1]);
        assert!(
            (got.x - e[0]).abs() < 1e-6 && (got.y - e[1]).abs() < 1e-6,
            "vertex {k}: {got} vs {e:?}"
        );
        let w0 = expect(uv0[k][0], uv0[k][1]);
        let raw = uv1[k];
        let wrong_set = (got.x - w0[0]).abs() < 1e-6 && (got.y - w0[1]).abs() < 1e-6;
        let untransformed = (got.x - raw[0]).abs() < 1e-6 && (got.y - raw[1]).abs() < 1e-6;
        assert!(!wrong_set, "vertex {k} reads set 0");
        assert!(!untransformed, "vertex {k} is not transformed");
    }
    // Required is accepted too.
    doc["extensionsRequired"] = serde_json::json!(["KHR_texture_transform"]);
    assert!(load(dir.path(), "tt2.gltf", &doc).is_ok());
}

/// Features stscam does not render are refused in one line that names the feature first
/// (after the file), and the same file without the feature loads.
#[test]
fn unsupported_features_are_refused_naming_the_feature() {
    let dir = tempfile::tempdir().unwrap();
    let plain = serde_json::json!({"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1]}});
    assert!(load(dir.path(), "plain.gltf", &quad_gltf(plain.clone(), None)).is_ok());
    let mut cases: Vec<(&str, serde_json::Value)> = Vec::new();
    // Hostile alpha values.
    cases.push((
        "alphaCutoff",
        quad_gltf(
            serde_json::json!({"alphaMode": "MASK", "alphaCutoff": 1.5}),
            None,
        ),
    ));
    cases.push((
        "baseColorFactor",
        quad_gltf(
            serde_json::json!({"alphaMode": "BLEND",
                               "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, -0.5]}}),
            None,
        ),
    ));
    cases.push((
        "normalTexture.scale",
        quad_gltf(
            serde_json::json!({"normalTexture": {"index": 0, "scale": 1e39}}),
            None,
        ),
    ));
    let mut morph = quad_gltf(plain.clone(), None);
    morph["meshes"][0]["primitives"][0]["targets"] = serde_json::json!([{"POSITION": 0}]);
    morph["meshes"][0]["weights"] = serde_json::json!([0.5, 0.5]);
    cases.push(("weights", morph.clone()));
    let mut skin = quad_gltf(plain.clone(), None);
    skin["nodes"] = serde_json::json!([{"mesh": 0, "skin": 0}, {"name": "bone"}]);
    skin["skins"] = serde_json::json!([{"joints": [1]}]);
    skin["scenes"] = serde_json::json!([{"nodes": [0, 1]}]);
    cases.push(("JOINTS_0", skin));
    let mut draco = quad_gltf(plain.clone(), None);
    draco["extensionsUsed"] = serde_json::json!(["KHR_draco_mesh_compression"]);
    draco["extensionsRequired"] = serde_json::json!(["KHR_draco_mesh_compression"]);
    draco["meshes"][0]["primitives"][0]["attributes"] = serde_json::json!({});
    cases.push(("KHR_draco_mesh_compression", draco));
    let mut ktx = quad_gltf(plain.clone(), None);
    ktx["extensionsRequired"] = serde_json::json!(["KHR_texture_basisu"]);
    cases.push(("KHR_texture_basisu", ktx));
    for (k, (feature, doc)) in cases.iter().enumerate() {
        let e = load(dir.path(), &format!("f{k}.gltf"), doc).expect_err(feature);
        assert!(e.message.starts_with(feature), "{feature}: {}", e.message);
        assert!(
            e.to_string().lines().count() == 1 && e.to_string().len() < 200,
            "{e}"
        );
    }
    // Zero morph weights are the base shape: accepted.
    morph["meshes"][0]["weights"] = serde_json::json!([0.0]);
    assert!(load(dir.path(), "m0.gltf", &morph).is_ok());
}

fn obj_area(a: &stscam::world::mesh::Asset) -> (f64, f64) {
    let (mut s, mut u) = (0.0, 0.0);
    for t in &a.mesh.triangles {
        let [p, q, r] = t.map(|i| a.mesh.positions_mm[i as usize]);
        let z = (q - p).cross(r - p).z / 2.0;
        s += z;
        u += z.abs();
    }
    (s, u)
}

/// Concave OBJ faces are ear-clipped: an L-shape (area 3) and a square ring given as one face
/// with a keyhole bridge (area 16 − 4 = 12) are covered exactly once (signed and unsigned
/// triangle areas equal the polygon's) and no triangle covers the ring's hole; the fan of the
/// former handling covers area outside the polygon (computed here) and fails.
#[test]
fn concave_obj_faces_are_ear_clipped() {
    let dir = tempfile::tempdir().unwrap();
    let l = "v 2 1 0\nv 1 1 0\nv 1 2 0\nv 0 2 0\nv 0 0 0\nv 2 0 0\nf 1 2 3 4 5 6\n";
    let ring = "v 0 0 0\nv 4 0 0\nv 4 4 0\nv 0 4 0\nv 1 1 0\nv 1 3 0\nv 3 3 0\nv 3 1 0\n\
                f 1 2 3 4 1 5 6 7 8 5\n";
    for (name, text, area, verts) in [("l.obj", l, 3.0, 6usize), ("ring.obj", ring, 12.0, 8)] {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        let a = load_asset(&p, 1.0).unwrap();
        let (s, u) = obj_area(&a);
        assert!(
            (s - area).abs() < 1e-9 && (u - area).abs() < 1e-9,
            "{name}: {s} {u}"
        );
        assert_eq!(a.mesh.positions_mm.len(), verts);
        if name == "ring.obj" {
            // The hole's centre (2, 2) is inside no triangle.
            let c = glam::DVec3::new(2.0, 2.0, 0.0);
            for t in &a.mesh.triangles {
                let [p, q, r] = t.map(|i| a.mesh.positions_mm[i as usize]);
                let s = |a: glam::DVec3, b: glam::DVec3| (b - a).cross(c - a).z;
                let inside = s(p, q) > 0.0 && s(q, r) > 0.0 && s(r, p) > 0.0;
                assert!(!inside, "{t:?} covers the hole");
            }
        }
        // The fan over the face's vertices (the former triangulation) covers more.
        let face: Vec<usize> = text
            .lines()
            .find(|l| l.starts_with("f "))
            .unwrap()
            .split_whitespace()
            .skip(1)
            .map(|v| v.parse::<usize>().unwrap() - 1)
            .collect();
        let v: Vec<[f64; 2]> = text
            .lines()
            .filter(|l| l.starts_with("v "))
            .map(|l| {
                let w: Vec<f64> = l
                    .split_whitespace()
                    .skip(1)
                    .map(|x| x.parse().unwrap())
                    .collect();
                [w[0], w[1]]
            })
            .collect();
        let fan_abs: f64 = (1..face.len() - 1)
            .map(|k| {
                let (a, b, c) = (v[face[0]], v[face[k]], v[face[k + 1]]);
                (((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])) / 2.0).abs()
            })
            .sum();
        assert!(
            (fan_abs - area).abs() > 0.4,
            "{name}: the fan covers {fan_abs}"
        );
    }
}

/// Frontal image (rgb-bayer, 16×16, 8 spp) of a 200 mm quad at 400 mm in a flat white
/// environment, the object given by `object` (TOML lines after `[[object]]`).
fn frontal_rgb(dir: &Path, object: &str) -> Vec<Vec<f32>> {
    let toml = format!(
        "[display]\nenabled = false\n[sensor]\nresponse = \"rgb-bayer\"\n[[object]]\n{object}\n\
         [[light]]\nkind = \"environment\"\nspectrum = \"flat\"\n"
    );
    let p = dir.join("scene.toml");
    std::fs::write(&p, toml).unwrap();
    let sets = [
        "sensor.crop_px=[16,16]".to_string(),
        "sensor.pitch_um=52.8".to_string(),
    ];
    let ls = stscam::scene::load_scene(Some(&p), &sets).unwrap();
    let sys = stscam::system::System::build(&ls).unwrap();
    let f = stscam::world::frontal::render_frontal(&sys, 16, 16, 8, 5).unwrap();
    assert!(f.mask.iter().all(|m| *m == 1), "the quad fills the frame");
    f.channels
}

/// Vertex colours multiply the base colour: a quad whose OBJ vertices (`v x y z r g b`) or
/// glTF `COLOR_0` are (0.9, 0.2, 0.1) renders like the same quad with base colour
/// (0.9, 0.2, 0.1) given in the scene instead (an independent route through the material;
/// tolerance 1e-6 relative), and not like the white quad (the former handling ignored the
/// colours: its R/B ratio differs by > 50 %).
#[test]
fn vertex_colours_multiply_the_base_colour() {
    let dir = tempfile::tempdir().unwrap();
    let c = [0.9, 0.2, 0.1];
    let quad = |rgb: Option<[f64; 3]>| {
        let col = rgb.map_or(String::new(), |c| format!(" {} {} {}", c[0], c[1], c[2]));
        format!("v -1 -1 0{col}\nv 1 -1 0{col}\nv 1 1 0{col}\nv -1 1 0{col}\nf 1 2 3 4\n")
    };
    std::fs::write(dir.path().join("coloured.obj"), quad(Some(c))).unwrap();
    std::fs::write(dir.path().join("plain.obj"), quad(None)).unwrap();
    let place = "scale = 200.0\nposition_mm = [0.0, 0.0, -400.0]";
    let coloured = frontal_rgb(
        dir.path(),
        &format!(
            "mesh = \"coloured.obj\"\n{place}\n[object.material]\nbase_color = [1.0, 1.0, 1.0]"
        ),
    );
    let reference = frontal_rgb(
        dir.path(),
        &format!("mesh = \"plain.obj\"\n{place}\n[object.material]\nbase_color = [0.9, 0.2, 0.1]"),
    );
    let white = frontal_rgb(
        dir.path(),
        &format!("mesh = \"plain.obj\"\n{place}\n[object.material]\nbase_color = [1.0, 1.0, 1.0]"),
    );
    let mean = |ch: &[f32]| ch.iter().map(|v| f64::from(*v)).sum::<f64>() / ch.len() as f64;
    for k in 0..3 {
        let (a, b) = (mean(&coloured[k]), mean(&reference[k]));
        assert!(
            (a - b).abs() <= 1e-6 * b.abs().max(1e-9),
            "channel {k}: {a} vs {b}"
        );
    }
    let ratio = |ch: &[Vec<f32>]| mean(&ch[0]) / mean(&ch[2]);
    assert!(
        ratio(&coloured) > 1.5 * ratio(&white),
        "{} vs {}",
        ratio(&coloured),
        ratio(&white)
    );
    // glTF COLOR_0 (RGBA floats, alpha ignored) is read per vertex.
    let plain = serde_json::json!({"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1]}});
    let a = load(
        dir.path(),
        "c.gltf",
        &quad_gltf(plain, Some(("COLOR_0", 3))),
    )
    .unwrap();
    assert_eq!(a.mesh.colors, vec![glam::DVec3::X; 4]);
}

/// A mesh file and an object with non-Latin-1 names render (exit 0) and the names survive in
/// the sidecar (UTF-8 JSON) and in the EXR's scene attribute (JSON escapes, parsed back here).
/// The former handling exited 1 after rendering.
#[test]
fn non_latin1_names_render_and_survive() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("頭-ü.obj");
    std::fs::write(
        &mesh,
        "v -50 -50 0\nv 50 -50 0\nv 50 50 0\nv -50 50 0\nf 1 2 3 4\n",
    )
    .unwrap();
    let scene = dir.path().join("scène-顔.toml");
    std::fs::write(
        &scene,
        "[display]\nenabled = false\n[[object]]\nmesh = \"頭-ü.obj\"\nname = \"顔 😀\"\n\
         position_mm = [0.0, 0.0, -500.0]\n[[light]]\nkind = \"environment\"\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let o = stscam(&[
        "render",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--set",
        "sensor.crop_px=[16,16]",
        "--spp",
        "2",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let side = std::fs::read_to_string(out.join("capture.json")).unwrap();
    assert!(side.contains("顔 😀"), "sidecar: {side}");
    // The EXR header attribute: name NUL "string" NUL, i32 size, Latin-1 bytes.
    let bytes = std::fs::read(out.join("capture.exr")).unwrap();
    let key = b"stscam.scene\0string\0";
    let at = bytes
        .windows(key.len())
        .position(|w| w == key)
        .expect("scene attribute")
        + key.len();
    let n = i32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
    let text: String = bytes[at + 4..at + 4 + n]
        .iter()
        .map(|&b| char::from(b))
        .collect();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert!(
        v.to_string().contains("顔 😀") && v.to_string().contains("頭-ü.obj"),
        "{v}"
    );
}

/// `stscam probe … --json | head -1`: the reader closes the pipe (here before the first
/// line is written, so the write always meets a closed pipe); the process must end without a
/// panic (killed by SIGPIPE, or exiting normally). The binary before the fix panicked with
/// "failed printing to stdout: Broken pipe" and exit code 101 (set `STSCAM_BIN` to a binary
/// to check another build).
#[test]
fn closed_stdout_pipe_ends_quietly() {
    let bin = std::env::var("STSCAM_BIN").unwrap_or(env!("CARGO_BIN_EXE_stscam").to_string());
    let mut child = std::process::Command::new(bin)
        .args(["probe", "--pixel", "10,20", "--json"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !err.contains("panicked") && !err.contains("Broken pipe"),
        "{err}"
    );
    assert_ne!(o.status.code(), Some(101), "{err}");
}
