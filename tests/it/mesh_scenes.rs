//! Mesh scenes end to end through the real `stscam` binary: the same textured quad from glTF
//! (external buffer + PNG), GLB and OBJ + MTL renders to the same bytes; nested glTF node
//! transforms place a small emitter where `probe`'s chief rays predict its replicas; the real
//! MediaPipe face mesh (cm, no normals, missing MTL) renders; bad mesh/light input fails with
//! one line naming the file and key; the shipped 3-D scenes are deterministic across threads.
//!
//! Every fixture is written into a temporary folder by the test itself.

use std::path::{Path, PathBuf};

use crate::common::{files_in, stscam, stscam_json, vec3};
use serde_json::json;
use stscam::io::{ExrChannel, read_exr};

const MANIFEST: &str = env!("CARGO_MANIFEST_DIR");

/// A 64×64 crop with the paper's field of view (440 × 4.8 µm = 64 × 33 µm).
const CROP64: [&str; 4] = [
    "--set",
    "sensor.crop_px=[64,64]",
    "--set",
    "sensor.pitch_um=33",
];

/// A 48×48 crop with the paper's field of view (440 × 4.8 µm = 48 × 44 µm).
const CROP48: [&str; 4] = [
    "--set",
    "sensor.crop_px=[48,48]",
    "--set",
    "sensor.pitch_um=44",
];

// ------------------------------------------------------------------------------------------
// Helpers

/// Runs `stscam render [scene] --out out extra...`, asserts success, returns the sidecar.
pub(super) fn render(scene: Option<&Path>, out: &Path, extra: &[&str]) -> serde_json::Value {
    let mut args: Vec<&str> = vec!["render"];
    if let Some(s) = scene {
        args.push(s.to_str().unwrap());
    }
    args.extend_from_slice(&["--out", out.to_str().unwrap()]);
    args.extend_from_slice(extra);
    let o = stscam(&args);
    assert!(
        o.status.success(),
        "stscam {args:?} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&std::fs::read(out.join("capture.json")).unwrap()).unwrap()
}

pub(super) fn exr(path: &Path) -> (usize, usize, Vec<ExrChannel>) {
    read_exr(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn channel<'a>(ch: &'a [ExrChannel], name: &str) -> &'a [f32] {
    &ch.iter()
        .find(|c| c.name == name)
        .unwrap_or_else(|| panic!("no channel {name}"))
        .data
}

/// A 16-bit grey PNG (mask.png) as values, with its size.
pub(super) fn read_mask(path: &Path) -> (usize, usize, Vec<u16>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Grayscale);
    assert_eq!(info.bit_depth, png::BitDepth::Sixteen);
    let v = buf[..info.buffer_size()]
        .chunks_exact(2)
        .map(|b| u16::from_be_bytes([b[0], b[1]]))
        .collect();
    (info.width as usize, info.height as usize, v)
}

fn write(path: &Path, bytes: impl AsRef<[u8]>) {
    std::fs::write(path, bytes).unwrap();
}

/// Every occurrence of `from` in `bytes` replaced by `to` (same length); and the count.
fn replace_bytes(bytes: &[u8], from: &[u8], to: &[u8]) -> (Vec<u8>, usize) {
    assert_eq!(from.len(), to.len());
    let mut out = bytes.to_vec();
    let mut n = 0;
    let mut i = 0;
    while i + from.len() <= out.len() {
        if &out[i..i + from.len()] == from {
            out[i..i + from.len()].copy_from_slice(to);
            n += 1;
            i += from.len();
        } else {
            i += 1;
        }
    }
    (out, n)
}

/// A 2×2 8-bit RGB PNG: red, green / blue, brown (sRGB codes).
fn png_bytes() -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, 2, 2);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().unwrap();
    w.write_image_data(&[255, 0, 0, 0, 255, 0, 0, 0, 255, 128, 64, 32])
        .unwrap();
    w.finish().unwrap();
    out
}

// The quad: 0.0625 m = 62.5 mm exactly; uv (0, 0) at the top-left (−, +) corner.
const QUAD_M: [[f32; 3]; 4] = [
    [-0.0625, -0.0625, 0.0],
    [0.0625, -0.0625, 0.0],
    [0.0625, 0.0625, 0.0],
    [-0.0625, 0.0625, 0.0],
];
const QUAD_UV: [[f32; 2]; 4] = [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]];
const QUAD_IDX: [u16; 6] = [0, 1, 2, 0, 2, 3];

/// Binary buffer of a quad: positions, normals (+z), uvs, indices (140 bytes).
fn quad_bin(pos: &[[f32; 3]; 4]) -> Vec<u8> {
    let mut b = Vec::new();
    for p in pos {
        p.iter().for_each(|v| b.extend(v.to_le_bytes()));
    }
    for _ in 0..4 {
        [0f32, 0.0, 1.0]
            .iter()
            .for_each(|v| b.extend(v.to_le_bytes()));
    }
    for t in QUAD_UV {
        t.iter().for_each(|v| b.extend(v.to_le_bytes()));
    }
    QUAD_IDX.iter().for_each(|v| b.extend(v.to_le_bytes()));
    b
}

fn bounds(pos: &[[f32; 3]; 4]) -> (serde_json::Value, serde_json::Value) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in pos {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (json!(lo), json!(hi))
}

/// The glTF JSON of the textured, emissive quad: buffer 0 given by `buffer`, image 0 by
/// `image`; base colour and emissive texture are image 0 (default sampler: repeat, as OBJ).
fn quad_json(
    buffer: serde_json::Value,
    image: serde_json::Value,
    extra_views: serde_json::Value,
) -> serde_json::Value {
    let mut views = vec![
        json!({"buffer": 0, "byteOffset": 0, "byteLength": 48}),
        json!({"buffer": 0, "byteOffset": 48, "byteLength": 48}),
        json!({"buffer": 0, "byteOffset": 96, "byteLength": 32}),
        json!({"buffer": 0, "byteOffset": 128, "byteLength": 12}),
    ];
    if let Some(v) = extra_views.as_array() {
        views.extend(v.iter().cloned());
    }
    let (lo, hi) = bounds(&QUAD_M);
    json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
            "indices": 3, "material": 0}]}],
        "materials": [{"name": "tex",
            "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0},
            "emissiveTexture": {"index": 0},
            "emissiveFactor": [1.0, 1.0, 1.0]}],
        "textures": [{"source": 0}],
        "images": [image],
        "buffers": [buffer],
        "bufferViews": views,
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": lo, "max": hi},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ]
    })
}

/// A binary glTF (GLB) of `json` with `bin` as its BIN chunk.
fn glb(json: &serde_json::Value, bin: &[u8]) -> Vec<u8> {
    let mut j = serde_json::to_vec(json).unwrap();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    while !b.len().is_multiple_of(4) {
        b.push(0);
    }
    let total = 12 + 8 + j.len() + 8 + b.len();
    let mut out = Vec::new();
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((j.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(j);
    out.extend((b.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(b);
    out
}

// ------------------------------------------------------------------------------------------
// 1. Formats

/// The textured quad at 550 mm in front of the bottom vHOE, emissive (texture × D65) and lit
/// by a rect light in front of it (base colour texture; roughness/metallic given in the scene
/// so that glTF and OBJ use the same surface model).
fn quad_scene(mesh: &str) -> String {
    format!(
        r#"
[display]
enabled = false
[[object]]
mesh = "{mesh}"
position_mm = [0.0, 0.0, -550.0]
[object.material]
roughness = 1.0
metallic = 0.0
[[light]]
kind = "rect"
position_mm = [0.0, 0.0, -150.0]
size_mm = [300.0, 300.0]
normal = [0.0, 0.0, -1.0]
spectrum = "d65"
scale = 0.5
"#
    )
}

/// The same quad as .gltf (external .bin + PNG), .glb (PNG in the BIN chunk) and
/// .obj, .mtl and PNG (mm; 0.0625 m = 62.5 mm exactly) renders to identical files. The EXR headers carry
/// the scene (with the mesh file name), so the mesh names have equal length and the EXR bytes
/// must be identical once the name is masked; the PNGs (no metadata) must be identical as is.
#[test]
fn same_quad_from_gltf_glb_and_obj_renders_identically() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let png = png_bytes();
    let bin = quad_bin(&QUAD_M);
    write(&d.join("tex.png"), &png);
    // (a) .gltf with an external buffer and an external PNG.
    write(&d.join("quad.bin"), &bin);
    let a = quad_json(
        json!({"uri": "quad.bin", "byteLength": bin.len()}),
        json!({"uri": "tex.png"}),
        json!(null),
    );
    write(&d.join("quad.gltf"), serde_json::to_vec(&a).unwrap());
    // (b) .glb with the PNG in a buffer view after the geometry.
    let mut glb_bin = bin.clone();
    glb_bin.extend(&png);
    let b = quad_json(
        json!({"byteLength": glb_bin.len()}),
        json!({"bufferView": 4, "mimeType": "image/png"}),
        json!([{"buffer": 0, "byteOffset": bin.len(), "byteLength": png.len()}]),
    );
    write(&d.join("quad1.glb"), glb(&b, &glb_bin));
    // (c) OBJ + MTL in mm, same vertex and triangle order, v flipped.
    write(
        &d.join("quad2.obj"),
        "mtllib quad2.mtl\nv -62.5 -62.5 0\nv 62.5 -62.5 0\nv 62.5 62.5 0\nv -62.5 62.5 0\n\
         vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nusemtl tex\n\
         f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n",
    );
    write(
        &d.join("quad2.mtl"),
        "newmtl tex\nKd 1 1 1\nKe 1 1 1\nmap_Kd tex.png\nmap_Ke tex.png\n",
    );
    // Names of equal length, so that the EXR headers differ only in these bytes.
    let names = ["quad.gltf", "quad1.glb", "quad2.obj"];
    let mut outs = Vec::new();
    for n in names {
        let scene = d.join(format!("{n}.toml"));
        write(&scene, quad_scene(n));
        let out = d.join(format!("out-{n}"));
        let mut args = vec!["--spp", "4", "--seed", "7", "--threads", "2"];
        args.extend_from_slice(&CROP64);
        let side = render(Some(&scene), &out, &args);
        let obj = &side["world"]["objects"][0];
        assert_eq!(obj["triangles"], 2, "{n}");
        assert_eq!(
            obj["bounds_mm"],
            json!([[-62.5, -62.5, -550.0], [62.5, 62.5, -550.0]]),
            "{n}"
        );
        assert_eq!(side["stats"]["nonfinite_samples"], 0, "{n}");
        outs.push(out);
    }
    for f in ["capture.exr", "frontal.exr", "depth.exr"] {
        let (r, nr) = replace_bytes(
            &std::fs::read(outs[0].join(f)).unwrap(),
            names[0].as_bytes(),
            b"#########",
        );
        assert!(nr >= 1, "{f}: the scene in the header names the mesh");
        for (k, n) in names.iter().enumerate().skip(1) {
            let (x, nx) = replace_bytes(
                &std::fs::read(outs[k].join(f)).unwrap(),
                n.as_bytes(),
                b"#########",
            );
            assert_eq!(nx, nr, "{f} of {n}");
            assert!(
                x == r,
                "{f} of {n} differs from {} beyond the mesh name",
                names[0]
            );
        }
    }
    for f in ["capture.png", "frontal.png", "mask.png"] {
        let r = std::fs::read(outs[0].join(f)).unwrap();
        for (k, n) in names.iter().enumerate().skip(1) {
            assert!(std::fs::read(outs[k].join(f)).unwrap() == r, "{f} of {n}");
        }
    }
    // The quad is seen through the waveguide, and the texture shows in the frontal view.
    let (w, h, cap) = exr(&outs[0].join("capture.exr"));
    assert_eq!((w, h), (64, 64));
    let y = channel(&cap, "Y");
    assert!(y.iter().all(|v| v.is_finite() && *v >= 0.0));
    let lit = y.iter().filter(|v| **v > 1e-3).count();
    let max = y.iter().cloned().fold(0.0f32, f32::max);
    eprintln!("capture: {lit} of {} pixels > 1e-3, max {max}", w * h);
    // Capture unit: 1 = display white through lossless optics; the emitter is white × texture
    // (luminance 0.07–0.72) and the brightest replica carries ≈ 8 % of the light.
    assert!(lit > w * h / 5 && max > 2e-3, "{lit} lit pixels, max {max}");
    let (_, _, fr) = exr(&outs[0].join("frontal.exr"));
    let fy = channel(&fr, "Y");
    // Texel centres at ±31.25 mm at 550 mm: ±3.25° = ±10.6 px of 19.6°/64 from the centre.
    let quads: Vec<f32> = [(21, 21), (42, 21), (21, 42), (42, 42)]
        .iter()
        .map(|&(c, r)| fy[r * 64 + c])
        .collect();
    let (qmin, qmax) = quads
        .iter()
        .fold((f32::INFINITY, 0.0f32), |(a, b), v| (a.min(*v), b.max(*v)));
    eprintln!("frontal at the four texel centres: {quads:?}");
    assert!(
        qmin > 0.0 && qmax > 3.0 * qmin,
        "texture not visible: {quads:?}"
    );
    // Green (top right, uv (0.75, 0.25)) is the brightest texel, brown (bottom right) the
    // dimmest: the texture is seen upright, as uv (0, 0) = top-left prescribes.
    assert!(
        quads[1] == qmax && quads[3] == qmin,
        "texture orientation: {quads:?}"
    );
    let (mw, mh, mask) = read_mask(&outs[0].join("mask.png"));
    assert_eq!((mw, mh), (64, 64));
    assert_eq!(mask[32 * 64 + 32], 1);
    assert_eq!(mask[0], 0);
    let (_, _, dep) = exr(&outs[0].join("depth.exr"));
    let z = channel(&dep, "Z");
    assert!(
        (z[32 * 64 + 32] - 550.0).abs() < 1e-3,
        "depth {}",
        z[32 * 64 + 32]
    );
    assert_eq!(z[0], f32::INFINITY);
}

// ------------------------------------------------------------------------------------------
// 2. Nested transforms

/// Depth of the emitter plane (mm) and the emitter's centre height (mm), exact in binary.
const EMITTER_Z_MM: f64 = 312.5;
const EMITTER_Y_MM: f64 = 7.8125;
/// Half size of the square emitter, 2^-11 m = 0.48828125 mm.
const EMITTER_HALF_M: f32 = 1.0 / 2048.0;

/// A glTF of an emissive (white × D65) quad `pos` (metres) under `nodes` (node 0 the root).
fn emitter_gltf(pos: &[[f32; 3]; 4], nodes: serde_json::Value) -> Vec<u8> {
    let bin = quad_bin(pos);
    let (lo, hi) = bounds(pos);
    let b64 = {
        const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut s = String::new();
        for c in bin.chunks(3) {
            let n = (u32::from(c[0]) << 16)
                | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
                | u32::from(*c.get(2).unwrap_or(&0));
            for k in 0..4 {
                if k <= c.len() {
                    s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
                } else {
                    s.push('=');
                }
            }
        }
        s
    };
    let doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": nodes,
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
            "indices": 3, "material": 0}]}],
        "materials": [{"name": "glow", "emissiveFactor": [1.0, 1.0, 1.0]}],
        "buffers": [{"uri": format!("data:application/octet-stream;base64,{b64}"),
                     "byteLength": bin.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 48},
            {"buffer": 0, "byteOffset": 96, "byteLength": 32},
            {"buffer": 0, "byteOffset": 128, "byteLength": 12}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": lo, "max": hi},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ]
    });
    serde_json::to_vec(&doc).unwrap()
}

/// A narrow full-height crop (9 columns; column 4 on the vertical midline) at 4× the pitch:
/// the paper's vertical field over 110 rows, ≈ 0.98 mm per pixel at 312.5 mm.
fn emitter_scene(mesh: &str, position: [f64; 3]) -> String {
    format!(
        r#"
[display]
enabled = false
distance_mm = {EMITTER_Z_MM}
[sensor]
crop_px = [9, 110]
pitch_um = 19.2
[[object]]
mesh = "{mesh}"
position_mm = {position:?}
"#
    )
}

/// A 0.98 mm square emitter placed at (0, 7.8125, −312.5) mm by a glTF hierarchy — parent:
/// 90° about z and a translation; child: non-uniform scale [2, 0.5, 1] and a translation —
/// lights exactly the sensor pixels where `probe`'s chief rays (display plane moved to the
/// emitter's depth) meet the emitter, one spot per replica; and renders like the same emitter
/// placed by `position_mm`.
#[test]
fn nested_gltf_emitter_lands_on_the_probed_replica_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Local quad x ∈ ±2^-12 m, y ∈ ±2^-10 m; child S = (2, 0.5, 1) makes it 2^-11 × 2^-12...
    // ...rotated by the parent's 90° about z: x' = −0.5·y, y' = 2·x, both ±2^-11 m.
    let (ax, by) = (EMITTER_HALF_M / 2.0, EMITTER_HALF_M * 2.0);
    let local = [
        [-ax, -by, 0.0],
        [ax, -by, 0.0],
        [ax, by, 0.0],
        [-ax, by, 0.0],
    ];
    let (s, c) = (
        std::f32::consts::FRAC_PI_4.sin(),
        std::f32::consts::FRAC_PI_4.cos(),
    );
    // World = T(0, 0, −0.25) · Rz(90°) · T(0.0078125, 0, −0.0625) · S(2, 0.5, 1):
    // the centre goes to (0, 0.0078125, −0.3125) m.
    let nested = json!([
        {"children": [1], "rotation": [0.0, 0.0, s, c], "translation": [0.0, 0.0, -0.25]},
        {"mesh": 0, "translation": [0.0078125, 0.0, -0.0625], "scale": [2.0, 0.5, 1.0]}
    ]);
    write(&d.join("nested.gltf"), emitter_gltf(&local, nested));
    let e = EMITTER_HALF_M;
    let flat = [[-e, -e, 0.0], [e, -e, 0.0], [e, e, 0.0], [-e, e, 0.0]];
    write(
        &d.join("flat.gltf"),
        emitter_gltf(&flat, json!([{"mesh": 0}])),
    );
    let sn = d.join("nested.toml");
    write(&sn, emitter_scene("nested.gltf", [0.0; 3]));
    let sf = d.join("flat.toml");
    write(
        &sf,
        emitter_scene("flat.gltf", [0.0, EMITTER_Y_MM, -EMITTER_Z_MM]),
    );
    let args = ["--spp", "64", "--seed", "5", "--threads", "2"];
    let on = d.join("nested");
    let side = render(Some(&sn), &on, &args);
    // The hierarchy composed: bounds (x, y) = ±0.48828125 mm about (0, 7.8125), z = −312.5.
    let b = &side["world"]["objects"][0]["bounds_mm"];
    let h = f64::from(EMITTER_HALF_M) * 1000.0;
    let want = [
        [-h, EMITTER_Y_MM - h, -EMITTER_Z_MM],
        [h, EMITTER_Y_MM + h, -EMITTER_Z_MM],
    ];
    for i in 0..2 {
        let got = vec3(&b[i]);
        for k in 0..3 {
            assert!((got[k] - want[i][k]).abs() < 1e-6, "bounds {b} vs {want:?}");
        }
    }
    let of = d.join("flat");
    render(Some(&sf), &of, &args);
    let (w, hgt, cn) = exr(&on.join("capture.exr"));
    assert_eq!((w, hgt), (9, 110));
    let yn = channel(&cn, "Y").to_vec();
    let (_, _, cf) = exr(&of.join("capture.exr"));
    let yf = channel(&cf, "Y");
    let rel = stscam::render::relative_rmse(&[(&yn, yf)]);
    let max_abs = yn
        .iter()
        .zip(yf)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    eprintln!("nested vs position_mm: relative RMSE {rel:e}, max |diff| {max_abs:e}");
    assert!(rel < 1e-5, "nested vs position_mm: relative RMSE {rel}");

    // Where the chief rays of every pixel meet the emitter plane (the display plane, moved to
    // the emitter's depth by display.distance_mm in the scene).
    let ls = stscam::scene::load_scene(Some(&sn), &[]).unwrap();
    let sys = stscam::system::System::build(&ls).unwrap();
    let probes: Vec<Vec<stscam::analysis::ProbeResult>> = (0..hgt)
        .map(|r| {
            (0..w)
                .map(|c| stscam::analysis::probe(&sys, c, r).unwrap())
                .collect()
        })
        .collect();
    // The library agrees with `stscam probe --json` of the same scene.
    let cli = stscam_json(&["probe", sn.to_str().unwrap(), "--pixel", "4,60", "--json"]);
    let reps = cli["replicas"].as_array().unwrap();
    assert_eq!(reps.len(), probes[60][4].replicas.len());
    for (a, b) in reps.iter().zip(&probes[60][4].replicas) {
        // (serde_json's default float parsing may be off by one ulp)
        let (p, q) = (vec3(&a["object_point_mm"]), b.object_point_mm);
        assert!((0..3).all(|k| (p[k] - q[k]).abs() < 1e-9), "{p:?} vs {q:?}");
        assert_eq!(b.object_point_mm[2], -EMITTER_Z_MM);
    }
    // A pixel is predicted to see the emitter when one of its replica chief rays meets the
    // plane within the emitter's half size plus half a pixel footprint of the emitter centre,
    // in x and in y. The footprint is the step to the nearest object point of the neighbouring
    // pixel (replicas of one pixel are 5–9 mm apart). Replica indices are not used:
    // they count contacts inside the bottom vHOE, so one index is not one bounce on every row.
    let h = f64::from(EMITTER_HALF_M) * 1000.0;
    let step = |p: [f64; 3], c2: usize, r2: usize| -> Option<f64> {
        probes
            .get(r2)?
            .get(c2)?
            .replicas
            .iter()
            .map(|q| {
                let o = q.object_point_mm;
                ((p[0] - o[0]).powi(2) + (p[1] - o[1]).powi(2)).sqrt()
            })
            .min_by(f64::total_cmp)
    };
    // Footprints: medians of the steps to the next row and column (steps over 2.5 mm are a
    // replica that has no counterpart on the neighbouring pixel).
    let median_step = |dc: usize, dr: usize| -> f64 {
        let mut v: Vec<f64> = Vec::new();
        for (r, row) in probes.iter().enumerate() {
            for (c, p) in row.iter().enumerate() {
                for rep in &p.replicas {
                    if let Some(s) = step(rep.object_point_mm, c + dc, r + dr)
                        && s < 2.5
                    {
                        v.push(s);
                    }
                }
            }
        }
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (fx, fy) = (median_step(1, 0), median_step(0, 1));
    eprintln!("pixel footprint on the emitter plane: {fx} × {fy} mm");
    assert!((0.5..2.0).contains(&fx) && (0.5..2.0).contains(&fy));
    let mut predicted: Vec<(usize, usize, f64)> = Vec::new(); // (col, row, weight)
    for (r, row) in probes.iter().enumerate() {
        for (c, p) in row.iter().enumerate() {
            for rep in &p.replicas {
                let o = rep.object_point_mm;
                if o[0].abs() <= h + 0.5 * fx && (o[1] - EMITTER_Y_MM).abs() <= h + 0.5 * fy {
                    predicted.push((c, r, rep.weight));
                }
            }
        }
    }
    eprintln!("predicted (col, row, chief-ray weight): {predicted:?}");
    let rows: std::collections::BTreeSet<usize> = predicted.iter().map(|p| p.1).collect();
    // Replicas 5–9 rows apart: at least 5 separate spots, all on the midline column.
    let spots = rows.iter().filter(|r| !rows.contains(&(**r + 1))).count();
    assert!(spots >= 5, "{rows:?}");
    assert!(predicted.iter().all(|p| p.0 == 4), "{predicted:?}");
    let near = |c: usize, r: usize| {
        predicted
            .iter()
            .any(|&(pc, pr, _)| c.abs_diff(pc) <= 1 && r.abs_diff(pr) <= 1)
    };
    let total: f64 = yn.iter().map(|v| f64::from(*v)).sum();
    let inside: f64 = (0..hgt)
        .flat_map(|r| (0..w).map(move |c| (c, r)))
        .filter(|&(c, r)| near(c, r))
        .map(|(c, r)| f64::from(yn[r * w + c]))
        .sum();
    let peak = yn.iter().cloned().fold(0.0f32, f32::max);
    let bright: Vec<(usize, usize, f32)> = (0..hgt)
        .flat_map(|r| (0..w).map(move |c| (c, r)))
        .map(|(c, r)| (c, r, yn[r * w + c]))
        .filter(|&(_, _, v)| v >= 0.1 * peak)
        .collect();
    eprintln!(
        "{:.1} % of the light within ±1 px of predicted pixels; pixels ≥ 10 % of the peak \
         {peak}: {bright:?}",
        100.0 * inside / total
    );
    // Nothing is seen off the midline column (the emitter is 1 px wide, centred on it).
    for (i, v) in yn.iter().enumerate() {
        assert!(
            i % w == 4 || *v == 0.0,
            "pixel ({}, {}) = {v}",
            i % w,
            i / w
        );
    }
    // Every pixel ≥ 10 % of the peak lies within one pixel of a predicted pixel. (Below that:
    // the dispersion haze of off-Bragg wavelengths between replicas, measured ≤ 7 %.)
    for &(c, r, v) in &bright {
        assert!(
            near(c, r),
            "pixel ({c}, {r}) = {v} is bright but no chief ray predicts it"
        );
    }
    // Most of the light lands on the predicted pixels.
    assert!(
        inside > 0.7 * total,
        "{inside} of {total} on the predicted pixels"
    );
    // Every predicted pixel whose chief-ray weight is ≥ 10 % of the heaviest is seen there.
    let wmax = predicted.iter().map(|p| p.2).fold(0.0, f64::max);
    let mut seen = 0;
    for &(pc, pr, wgt) in &predicted {
        if wgt < 0.1 * wmax {
            continue;
        }
        let lit = bright
            .iter()
            .any(|&(c, r, _)| c.abs_diff(pc) <= 1 && r.abs_diff(pr) <= 1);
        assert!(
            lit,
            "predicted pixel ({pc}, {pr}) with weight {wgt} is dark"
        );
        seen += 1;
    }
    assert!(seen >= 3, "{seen} replicas seen");
    // The brightest pixel is the heaviest replica's (the one that left the guide first).
    let (bc, br, _) = bright
        .iter()
        .cloned()
        .max_by(|a, b| a.2.total_cmp(&b.2))
        .unwrap();
    let heavy = predicted
        .iter()
        .cloned()
        .max_by(|a, b| a.2.total_cmp(&b.2))
        .unwrap();
    assert!(
        bc.abs_diff(heavy.0) <= 1 && br.abs_diff(heavy.1) <= 1,
        "brightest pixel ({bc}, {br}), heaviest replica {heavy:?}"
    );
}

// ------------------------------------------------------------------------------------------
// 3. The real face mesh

/// The MediaPipe canonical face model (OBJ in cm, no normals, its .mtl missing) at 500 mm,
/// lit by a rect light in front of it: finite output, object pixels in the middle of the mask,
/// their depths within the placed mesh's z range (file z ∈ [−2.44, 7.59] cm → 424–525 mm).
#[test]
fn canonical_face_mesh_renders() {
    let path = Path::new(MANIFEST).join("scenes/assets/canonical_face_model.obj");
    if !path.is_file() {
        println!("skipped: {} is absent", path.display());
        return;
    }
    let path: PathBuf = path.canonicalize().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("face.toml");
    write(
        &scene,
        format!(
            r#"
[display]
enabled = false
[[object]]
mesh = "{}"
name = "face"
units = "cm"
position_mm = [0.0, 0.0, -500.0]
[[light]]
kind = "rect"
position_mm = [0.0, 100.0, -150.0]
size_mm = [300.0, 300.0]
normal = [0.0, -0.3, -1.0]
spectrum = "d65"
scale = 2.0
"#,
            path.display()
        ),
    );
    let out = dir.path().join("out");
    let mut args = vec!["--spp", "2", "--seed", "1", "--threads", "2"];
    args.extend_from_slice(&CROP64);
    let side = render(Some(&scene), &out, &args);
    let obj = &side["world"]["objects"][0];
    assert_eq!(obj["name"], "face");
    assert_eq!(obj["triangles"], 898);
    assert_eq!(obj["mask_value"], 1);
    let lo = vec3(&obj["bounds_mm"][0]);
    let hi = vec3(&obj["bounds_mm"][1]);
    eprintln!("face bounds {lo:?} .. {hi:?}");
    // cm → mm and placement: z from −500 − 24.36 to −500 + 75.87 mm.
    assert!(
        (lo[2] + 524.36).abs() < 0.01 && (hi[2] + 424.13).abs() < 0.01,
        "{lo:?} {hi:?}"
    );
    assert!(
        (140.0..=170.0).contains(&(hi[0] - lo[0])),
        "width {}",
        hi[0] - lo[0]
    );
    assert_eq!(side["stats"]["nonfinite_samples"], 0);
    for f in ["capture.exr", "frontal.exr"] {
        let (w, h, ch) = exr(&out.join(f));
        assert_eq!((w, h), (64, 64));
        let y = channel(&ch, "Y");
        assert!(y.iter().all(|v| v.is_finite() && *v >= 0.0), "{f}");
        assert!(y.iter().any(|v| *v > 0.0), "{f} is black");
    }
    let (_, _, mask) = read_mask(&out.join("mask.png"));
    let (_, _, dep) = exr(&out.join("depth.exr"));
    let z = channel(&dep, "Z");
    // The face (about 150 × 170 mm at 424–525 mm) fills the middle of the ±9.8° view
    // (±86 mm at 500 mm).
    let mut middle = 0;
    for r in 24..40 {
        for c in 24..40 {
            middle += usize::from(mask[r * 64 + c] == 1);
        }
    }
    assert_eq!(
        middle,
        16 * 16,
        "object pixels in the middle 16×16: {middle}"
    );
    let object: Vec<f32> = (0..64 * 64)
        .filter(|&i| mask[i] == 1)
        .map(|i| z[i])
        .collect();
    let (zmin, zmax) = object
        .iter()
        .fold((f32::INFINITY, 0.0f32), |(a, b), v| (a.min(*v), b.max(*v)));
    eprintln!("{} object pixels, depth {zmin}..{zmax} mm", object.len());
    assert!(object.len() > 64 * 64 / 3);
    assert!(
        zmin >= (-hi[2]) as f32 - 1e-3 && zmax <= (-lo[2]) as f32 + 1e-3,
        "object depths {zmin}..{zmax} outside the mesh's z range"
    );
    assert!(zmin > 420.0 && zmax < 600.0);
    // Background pixels (mask 0) have infinite depth: nothing else is in the scene.
    assert!((0..64 * 64).all(|i| (mask[i] == 0) == z[i].is_infinite()));
    assert!(mask.iter().all(|m| *m <= 1));
}

// ------------------------------------------------------------------------------------------
// 4. Bad input

/// Runs a render expected to fail as bad input; returns its single stderr line.
fn fails(args: &[&str], out: &Path) -> String {
    let mut all = vec!["render", "--out", out.to_str().unwrap(), "--spp", "1"];
    all.extend_from_slice(args);
    let o = stscam(&all);
    let err = String::from_utf8(o.stderr).unwrap();
    assert_eq!(o.status.code(), Some(2), "{all:?}: {err}");
    assert_eq!(
        err.trim_end().lines().count(),
        1,
        "{all:?}: not one line: {err}"
    );
    assert!(
        !out.exists(),
        "{all:?} created {} ({:?})",
        out.display(),
        files_in(out)
    );
    err.trim_end().to_string()
}

#[test]
fn bad_mesh_and_light_input_is_one_line_naming_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out");
    let scene = d.join("scene.toml");
    let s = scene.to_str().unwrap();
    let object = |mesh: &str, extra: &str| {
        format!(
            "[display]\nenabled = false\n[[object]]\nmesh = \"{mesh}\"\n\
             position_mm = [0.0, 0.0, -400.0]\n{extra}"
        )
    };
    let prefix = |key: &str| format!("error: {s}: {key}: ");

    // (a) A missing mesh file.
    write(&scene, object("nope.obj", ""));
    let e = fails(&[s], &out);
    assert!(
        e.starts_with(&prefix("object.0.mesh")) && e.contains("nope.obj"),
        "{e}"
    );

    // (b) A glTF with points only: no triangles.
    let bin: Vec<u8> = [0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    write(&d.join("points.bin"), &bin);
    let doc = json!({
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": 0}]}],
        "buffers": [{"uri": "points.bin", "byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]}]
    });
    write(&d.join("points.gltf"), serde_json::to_vec(&doc).unwrap());
    write(&scene, object("points.gltf", ""));
    let e = fails(&[s], &out);
    assert!(
        e.starts_with(&prefix("object.0.mesh"))
            && e.contains("points.gltf")
            && e.contains("no triangles"),
        "{e}"
    );

    // (c) Missing textures: an OBJ's map_Kd, a glTF image, and a base_color override.
    write(&d.join("m.mtl"), "newmtl a\nKd 1 1 1\nmap_Kd gone.png\n");
    write(
        &d.join("m.obj"),
        "mtllib m.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n\
         f 1/1 2/2 3/3\n",
    );
    write(&scene, object("m.obj", ""));
    let e = fails(&[s], &out);
    assert!(
        e.starts_with(&prefix("object.0.mesh")) && e.contains("gone.png"),
        "{e}"
    );
    let qbin = quad_bin(&QUAD_M);
    write(&d.join("quad.bin"), &qbin);
    let j = quad_json(
        json!({"uri": "quad.bin", "byteLength": qbin.len()}),
        json!({"uri": "missing.png"}),
        json!(null),
    );
    write(&d.join("t.gltf"), serde_json::to_vec(&j).unwrap());
    write(&scene, object("t.gltf", ""));
    let e = fails(&[s], &out);
    assert!(
        e.starts_with(&prefix("object.0.mesh"))
            && e.contains("missing.png")
            && e.contains("t.gltf"),
        "{e}"
    );
    write(
        &scene,
        object("quad", "[object.material]\nbase_color = \"lost.png\"\n"),
    );
    let e = fails(&[s], &out);
    assert!(
        e.starts_with(&prefix("object.0.material.base_color")) && e.contains("lost.png"),
        "{e}"
    );

    // (d) A NaN vertex in an OBJ.
    write(&d.join("nan.obj"), "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n");
    write(&scene, object("nan.obj", ""));
    let e = fails(&[s], &out);
    assert!(
        e.starts_with(&prefix("object.0.mesh"))
            && e.contains("nan.obj")
            && e.contains("not finite"),
        "{e}"
    );

    // (e) An unknown light kind.
    write(
        &scene,
        "[[light]]\nkind = \"laser\"\nposition_mm = [0.0, 0.0, -100.0]\n",
    );
    let e = fails(&[s], &out);
    assert!(
        e.starts_with(&prefix("light.0.kind")) && e.contains("laser"),
        "{e}"
    );

    // (f) A mesh path that is a folder.
    std::fs::create_dir(d.join("folder.obj")).unwrap();
    write(&scene, object("folder.obj", ""));
    let e = fails(&[s], &out);
    assert!(
        e.starts_with(&prefix("object.0.mesh"))
            && e.contains("folder.obj")
            && e.contains("directory"),
        "{e}"
    );

    // (g) Overrides: a NaN position (TOML accepts nan), an index out of range, and a missing
    // mesh set from the command line: the error names `--set KEY`.
    write(&scene, object("quad", ""));
    let e = fails(&[s, "--set", "object.0.position_mm=[0,0,nan]"], &out);
    assert!(
        e.starts_with("error: --set object.0.position_mm: object.0.position_mm: must be finite"),
        "{e}"
    );
    let e = fails(&[s, "--set", "object.3.mesh=\"quad\""], &out);
    assert!(
        e.starts_with("error: --set object.3.mesh: object.3.mesh: index 3 is out of range"),
        "{e}"
    );
    let e = fails(&[s, "--set", "object.0.mesh=\"elsewhere.glb\""], &out);
    assert!(
        e.starts_with("error: --set object.0.mesh: object.0.mesh: ") && e.contains("elsewhere.glb"),
        "{e}"
    );
    let e = fails(&[s, "--set", "light.0.kind=\"rect\""], &out);
    assert!(
        e.starts_with("error: --set light.0.kind: light.0.kind: "),
        "{e}"
    );
}

// ------------------------------------------------------------------------------------------
// 5. Determinism of the shipped 3-D scenes

/// The eye-contact and gesture scenes at a 48×48 crop (paper field of view), 2 spp: one and
/// two threads give byte-identical capture.exr, frontal.exr, depth.exr and mask.png; every
/// value is finite; capture and frontal are not black; the mask shows the object.
#[test]
fn shipped_3d_scenes_are_identical_for_one_and_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["eye-contact", "gesture"] {
        let scene = Path::new(MANIFEST).join(format!("scenes/{name}.toml"));
        let mut outs = Vec::new();
        for threads in ["1", "2"] {
            let out = dir.path().join(format!("{name}-{threads}"));
            let mut args = vec!["--spp", "2", "--seed", "3", "--threads", threads];
            args.extend_from_slice(&CROP48);
            let side = render(Some(&scene), &out, &args);
            assert_eq!(side["threads"].as_u64(), Some(threads.parse().unwrap()));
            assert_eq!(side["stats"]["nonfinite_samples"], 0, "{name}");
            outs.push(out);
        }
        for f in [
            "capture.exr",
            "frontal.exr",
            "depth.exr",
            "mask.png",
            "capture.png",
            "frontal.png",
        ] {
            let a = std::fs::read(outs[0].join(f)).unwrap();
            let b = std::fs::read(outs[1].join(f)).unwrap();
            assert!(a == b, "{name}: {f} differs between 1 and 2 threads");
        }
        for f in ["capture.exr", "frontal.exr"] {
            let (w, h, ch) = exr(&outs[0].join(f));
            assert_eq!((w, h), (48, 48));
            for c in &ch {
                assert!(
                    c.data.iter().all(|v| v.is_finite() && *v >= 0.0),
                    "{name}: {f} channel {} has NaN, Inf or negative values",
                    c.name
                );
            }
            let y = channel(&ch, "Y");
            let mean = y.iter().map(|v| f64::from(*v)).sum::<f64>() / y.len() as f64;
            eprintln!("{name}: {f} mean {mean}");
            assert!(mean > 1e-4, "{name}: {f} is black (mean {mean})");
        }
        let (_, _, dep) = exr(&outs[0].join("depth.exr"));
        let z = channel(&dep, "Z");
        assert!(z.iter().all(|v| !v.is_nan() && *v > 0.0), "{name}: depth");
        let (_, _, mask) = read_mask(&outs[0].join("mask.png"));
        let object = mask.iter().filter(|m| **m == 1).count();
        eprintln!("{name}: {object} object pixels");
        assert!(object > 48 * 48 / 10, "{name}: {object} object pixels");
        assert!(
            (0..48 * 48).all(|i| (mask[i] == 1) == z[i].is_finite()),
            "{name}: mask vs depth"
        );
    }
}

/// A FIFO given as a mesh or as a texture is refused at once (it would block a whole-file
/// read forever): exit 2, one line naming it, nothing written. The process is killed after
/// 20 s if it hangs, which fails the test.
#[test]
fn fifo_as_mesh_or_texture_is_refused_quickly() {
    let dir = tempfile::tempdir().unwrap();
    let made = std::process::Command::new("mkfifo")
        .arg(dir.path().join("pipe.obj"))
        .arg(dir.path().join("pipe.png"))
        .status();
    if !matches!(made, Ok(s) if s.success()) {
        eprintln!("mkfifo is not available; skipped");
        return;
    }
    for (name, body) in [
        ("mesh.toml", "[[object]]\nmesh = \"pipe.obj\"\n"),
        (
            "tex.toml",
            "[[object]]\nmesh = \"quad\"\n[object.material]\nbase_color = \"pipe.png\"\n",
        ),
    ] {
        let scene = dir.path().join(name);
        std::fs::write(&scene, body).unwrap();
        let out = dir.path().join(format!("out-{name}"));
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_stscam"))
            .args([
                "render",
                scene.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--spp",
                "1",
            ])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let start = std::time::Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            if start.elapsed().as_secs() > 20 {
                child.kill().unwrap();
                panic!("{name}: stscam hung on a FIFO");
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        };
        let mut err = String::new();
        std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
        assert_eq!(status.code(), Some(2), "{name}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{name}: {err}");
        assert!(
            err.contains("pipe.") && err.contains("not a regular file"),
            "{name}: {err}"
        );
        assert!(!out.exists(), "{name}: wrote {:?}", files_in(&out));
    }
}

/// `render` names every file it wrote: a 3-D scene's frontal view, depth and mask besides the
/// capture (it named the capture only); a display scene names the capture alone.
#[test]
fn render_names_every_file_it_wrote() {
    let dir = tempfile::tempdir().unwrap();
    let scene = Path::new(MANIFEST).join("scenes/eye-contact.toml");
    let out = dir.path().join("3d");
    let mut args = vec![
        "render",
        scene.to_str().unwrap(),
        "--spp",
        "1",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(&CROP48);
    let o = crate::common::stscam(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("/capture.{exr,png,json}, frontal.{exr,png}, depth.exr, mask.png:"),
        "{err}"
    );
    for f in ["frontal.exr", "frontal.png", "depth.exr", "mask.png"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let flat = dir.path().join("flat");
    let o = crate::common::stscam(&[
        "render",
        "--spp",
        "1",
        "--set",
        "sensor.crop_px=[32,32]",
        "--out",
        flat.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("/capture.{exr,png,json}:") && !err.contains("frontal"),
        "{err}"
    );
    assert!(!flat.join("frontal.exr").exists());
}
