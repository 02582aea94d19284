//! glTF alpha coverage and sides rendered faithfully (`world::coverage`): a cut-out, a 50 %
//! blend and a single-sided quad, each in a file the test writes, rendered through the real
//! binary (capture, frontal image, depth and mask), each against an independent construction
//! and each with a deliberately wrong handling that fails.
//!
//! The set-up: a black (base colour 0) quad 400 mm wide at 400 mm fills the frame; behind it,
//! at 800 mm, a 2 m emissive quad (black, emission 1). Nothing else emits, so a pixel reads the
//! back emitter's radiance where its rays pass the front quad and 0 where they stop on it.

use std::path::Path;

use super::asset_features::{b64, quad_gltf};
use super::mesh_scenes::{exr, read_mask, render};

/// A small crop (the paper's field at 24 × 24 px) and 4 spp.
const FAST: [&str; 6] = [
    "--set",
    "sensor.crop_px=[24,24]",
    "--set",
    "sensor.pitch_um=88",
    "--spp",
    "4",
];

/// An 8-bit RGBA PNG of `w`×`h` white pixels with the given alpha codes (row-major).
fn alpha_png(w: u32, h: u32, alpha: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc.write_header().unwrap();
    let data: Vec<u8> = alpha.iter().flat_map(|a| [255, 255, 255, *a]).collect();
    wr.write_image_data(&data).unwrap();
    wr.finish().unwrap();
    out
}

/// The scene: `front` (TOML lines of the first object) before the back emitter.
fn scene(dir: &Path, name: &str, front: &str) -> std::path::PathBuf {
    let toml = format!(
        "[display]\nenabled = false\n[[object]]\n{front}\n\
         [[object]]\nmesh = \"quad\"\nscale = 2000.0\nposition_mm = [0.0, 0.0, -800.0]\n\
         [object.material]\nbase_color = [0.0, 0.0, 0.0]\nemission = [1.0, 1.0, 1.0]\n"
    );
    let p = dir.join(name);
    std::fs::write(&p, toml).unwrap();
    p
}

/// The front object lines for mesh `mesh` (the glTF unit quad, or an OBJ in mm of the same
/// size), black; `extra` places it.
fn front(mesh: &str, extra: &str) -> String {
    format!(
        "mesh = \"{mesh}\"\n{extra}\n[object.material]\nbase_color = [0.0, 0.0, 0.0]\n\
         roughness = 1.0\nmetallic = 0.0\ntexture_filter = \"nearest\"\n"
    )
}

/// The outputs of one render: capture channels, frontal channels, depth, mask.
struct Out {
    capture: Vec<f32>,
    frontal: Vec<f32>,
    depth: Vec<f32>,
    mask: Vec<u16>,
}

fn run(dir: &Path, name: &str, front_lines: &str) -> Out {
    let s = scene(dir, &format!("{name}.toml"), front_lines);
    let out = dir.join(name);
    render(Some(&s), &out, &FAST);
    let all = |f: &str| -> Vec<f32> {
        exr(&out.join(f))
            .2
            .into_iter()
            .flat_map(|c| c.data)
            .collect()
    };
    Out {
        capture: all("capture.exr"),
        frontal: all("frontal.exr"),
        depth: all("depth.exr"),
        mask: read_mask(&out.join("mask.png")).2,
    }
}

fn mean(v: &[f32]) -> f64 {
    v.iter().map(|x| f64::from(*x)).sum::<f64>() / v.len() as f64
}

fn max_rel_diff(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-30);
    a.iter()
        .zip(b)
        .map(|(x, y)| f64::from((x - y).abs() / scale))
        .fold(0.0, f64::max)
}

/// A MASK cut-out: the quad's 4 × 4 alpha texture (nearest texels) is 0 in its central 2 × 2
/// texels, so the centre square u, v ∈ [¼, ¾) is a hole. Rendered, it must equal (capture,
/// frontal: relative 1e-6; mask exactly; depth 1e-6) the same quad built as geometry with that
/// square missing (an OBJ ring of four rectangles): the hole's rays see the back emitter, in
/// the capture, frontal image, depth and mask. Ignoring alpha (the quad opaque) fails: the
/// hole's pixels see the quad (mask 1, black).
#[test]
fn mask_cut_out_renders_like_the_geometric_hole() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut alpha = [255u8; 16];
    for (y, x) in [(1, 1), (1, 2), (2, 1), (2, 2)] {
        alpha[y * 4 + x] = 0;
    }
    let mat = |mode: &str| {
        serde_json::json!({"alphaMode": mode, "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 0}, "metallicFactor": 0.0}})
    };
    for (name, mode) in [("cut.gltf", "MASK"), ("opaque.gltf", "OPAQUE")] {
        let mut doc = quad_gltf(mat(mode), None);
        doc["images"][0]["uri"] =
            format!("data:image/png;base64,{}", b64(&alpha_png(4, 4, &alpha))).into();
        std::fs::write(d.join(name), serde_json::to_vec(&doc).unwrap()).unwrap();
    }
    // The same quad in mm (glTF metres × 1000) without the centre square.
    let mut obj = String::new();
    for y in [0, 250, 750, 1000] {
        for x in [0, 250, 750, 1000] {
            obj += &format!("v {x} {y} 0\n");
        }
    }
    // Vertex (i, j) of the 4 × 4 grid is 1 + 4j + i; the ring is every cell but (1, 1).
    for (i, j) in [
        (0, 0),
        (1, 0),
        (2, 0),
        (0, 1),
        (2, 1),
        (0, 2),
        (1, 2),
        (2, 2),
    ] {
        let v = |a: usize, b: usize| 1 + 4 * b + a;
        obj += &format!(
            "f {} {} {} {}\n",
            v(i, j),
            v(i + 1, j),
            v(i + 1, j + 1),
            v(i, j + 1)
        );
    }
    std::fs::write(d.join("ring.obj"), obj).unwrap();
    // A 120 mm quad at 400 mm: the frame (about 160 mm wide there) sees the ring, the hole
    // and the back around the quad.
    let place = "scale = 0.12\nposition_mm = [-60.0, -60.0, -400.0]";
    let cut = run(d, "cut", &front("cut.gltf", place));
    let ring = run(d, "ring", &front("ring.obj", place));
    let opaque = run(d, "opaque", &front("opaque.gltf", place));
    let seen_back = cut.mask.iter().filter(|m| **m == 2).count();
    eprintln!(
        "cut-out: {seen_back} of {} pixels see the back; frontal mean {} (ring {}, opaque {})",
        cut.mask.len(),
        mean(&cut.frontal),
        mean(&ring.frontal),
        mean(&opaque.frontal)
    );
    let on_ring = cut.mask.iter().filter(|m| **m == 1).count();
    assert!(on_ring > cut.mask.len() / 8, "{on_ring}");
    assert!(cut.mask.iter().all(|m| *m == 1 || *m == 2));
    assert_eq!(cut.mask, ring.mask);
    assert!(max_rel_diff(&cut.depth, &ring.depth) < 1e-6);
    assert!(max_rel_diff(&cut.frontal, &ring.frontal) < 1e-6);
    assert!(max_rel_diff(&cut.capture, &ring.capture) < 1e-6);
    assert!(mean(&cut.capture) > 0.0 && mean(&cut.frontal) > 0.0);
    // Wrong handling: alpha ignored (the hole's pixels see the quad).
    let opaque_back = opaque.mask.iter().filter(|m| **m == 2).count();
    assert!(
        seen_back > opaque_back + cut.mask.len() / 16,
        "{seen_back} vs {opaque_back}"
    );
    assert!(mean(&opaque.frontal) < 0.9 * mean(&cut.frontal));
    assert!(max_rel_diff(&opaque.capture, &ring.capture) > 0.1);
}

/// BLEND at alpha 0.5 (baseColorFactor alpha, no texture): the mean transmission — the
/// frontal image over the same render without the front quad (moved out of view, so the
/// hashed paths are the same) — is 0.5 within 4 SEM (per-pixel ratios; each pixel's 4
/// samples are independent draws), and so is the fraction of depth/mask rays that see the
/// back. An opaque quad (transmission 0) and an ignored quad (1) fail.
#[test]
fn blend_at_half_alpha_transmits_half() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mat = serde_json::json!({"alphaMode": "BLEND", "pbrMetallicRoughness": {
        "baseColorFactor": [0.0, 0.0, 0.0, 0.5], "metallicFactor": 0.0}});
    std::fs::write(
        d.join("half.gltf"),
        serde_json::to_vec(&quad_gltf(mat, None)).unwrap(),
    )
    .unwrap();
    let blend = run(
        d,
        "blend",
        &front(
            "half.gltf",
            "scale = 0.4\nposition_mm = [-200.0, -200.0, -400.0]",
        ),
    );
    let gone = run(
        d,
        "gone",
        &front(
            "half.gltf",
            "scale = 0.4\nposition_mm = [-200.0, -200.0, 4000.0]",
        ),
    );
    let r: Vec<f64> = blend
        .frontal
        .iter()
        .zip(&gone.frontal)
        .map(|(a, b)| f64::from(*a) / f64::from(*b))
        .collect();
    let n = r.len() as f64;
    let m = r.iter().sum::<f64>() / n;
    let sem = (r.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0) / n).sqrt();
    eprintln!("blend 0.5: transmission {m} ± {sem} over {n} pixels");
    assert!((m - 0.5).abs() < 4.0 * sem, "{m} ± {sem}");
    assert!(sem < 0.05, "{sem}");
    for wrong in [0.0, 1.0] {
        assert!((m - wrong).abs() > 4.0 * sem);
    }
    let k = blend.mask.iter().filter(|v| **v == 2).count() as f64;
    let nm = blend.mask.len() as f64;
    let f = k / nm;
    let sem_f = (0.25 / nm).sqrt();
    eprintln!("blend 0.5: {f} of the depth/mask rays see the back");
    assert!((f - 0.5).abs() < 4.0 * sem_f, "{f}");
    assert!(blend.mask.iter().all(|v| *v == 1 || *v == 2));
}

/// `doubleSided: false` (absent: glTF's default) culls back faces: the quad seen from the
/// front stops every ray (mask 1), turned 180° about y (seen from behind) it is invisible (the
/// back emitter, mask 2, everywhere); with `doubleSided: true` it is seen from behind too.
/// Culling front faces instead (the wrong side) fails the first check, never culling the
/// second.
#[test]
fn single_sided_quad_is_invisible_from_behind() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (name, two) in [("one.gltf", None), ("two.gltf", Some(true))] {
        let mut mat = serde_json::json!({"pbrMetallicRoughness": {"metallicFactor": 0.0}});
        if let Some(t) = two {
            mat["doubleSided"] = t.into();
        }
        std::fs::write(
            d.join(name),
            serde_json::to_vec(&quad_gltf(mat, None)).unwrap(),
        )
        .unwrap();
    }
    let ahead = "scale = 0.4\nposition_mm = [-200.0, -200.0, -400.0]";
    let behind = "position_mm = [200.0, -200.0, -400.0]\nrotation_deg = [0.0, 180.0, 0.0]";
    let from_front = run(d, "front", &front("one.gltf", ahead));
    assert!(
        from_front.mask.iter().all(|m| *m == 1),
        "front faces are hit"
    );
    assert!(mean(&from_front.frontal) == 0.0);
    let from_behind = run(d, "behind", &front("one.gltf", behind));
    assert!(
        from_behind.mask.iter().all(|m| *m == 2),
        "back faces are culled"
    );
    let gone = run(
        d,
        "gone",
        &front(
            "one.gltf",
            "scale = 0.4\nposition_mm = [-200.0, -200.0, 4000.0]",
        ),
    );
    assert!(max_rel_diff(&from_behind.frontal, &gone.frontal) < 1e-6);
    assert!(max_rel_diff(&from_behind.capture, &gone.capture) < 1e-6);
    let two_behind = run(d, "two", &front("two.gltf", behind));
    assert!(two_behind.mask.iter().all(|m| *m == 1), "double-sided");
}

/// 10⁴ stacked cut-out layers (alpha 0 everywhere, MASK) are passed in one traversal: the
/// centre ray's first hit is the back emitter at 800 mm, found in well under a second (a
/// re-query loop bounded at fewer iterations would stop inside the stack).
#[test]
fn ten_thousand_cut_out_layers_are_passed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let n = 10_000usize;
    let mut bin = Vec::with_capacity(n * 72);
    for k in 0..n {
        let z = -(k as f32) * 1e-5;
        for [x, y] in [[0f32, 0.], [1., 0.], [1., 1.], [0., 1.]] {
            for v in [x, y, z] {
                bin.extend(v.to_le_bytes());
            }
        }
    }
    let pos_len = bin.len();
    for k in 0..n as u32 {
        for i in [0, 1, 2, 0, 2, 3] {
            bin.extend((4 * k + i).to_le_bytes());
        }
    }
    let doc = serde_json::json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": bin.len(),
                     "uri": format!("data:application/octet-stream;base64,{}", b64(&bin))}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": pos_len},
            {"buffer": 0, "byteOffset": pos_len, "byteLength": bin.len() - pos_len}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4 * n, "type": "VEC3",
             "min": [0.0, 0.0, -0.1], "max": [1.0, 1.0, 0.0]},
            {"bufferView": 1, "componentType": 5125, "count": 6 * n, "type": "SCALAR"}
        ],
        "materials": [{"alphaMode": "MASK", "pbrMetallicRoughness": {
            "baseColorFactor": [1.0, 1.0, 1.0, 0.0]}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1,
                                     "material": 0}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0
    });
    std::fs::write(d.join("stack.gltf"), serde_json::to_vec(&doc).unwrap()).unwrap();
    let p = scene(
        d,
        "stack.toml",
        &front(
            "stack.gltf",
            "scale = 0.4\nposition_mm = [-200.0, -200.0, -400.0]",
        ),
    );
    let ls = stscam::scene::load_scene(Some(&p), &[]).unwrap();
    let sys = stscam::system::System::build(&ls).unwrap();
    let world = sys.world.as_deref().unwrap();
    assert_eq!(world.objects[0].triangles, 2 * n);
    let d = glam::DVec3::new(0.01, 0.02, -1.0).normalize();
    let start = std::time::Instant::now();
    let hit = world.first_hit(&sys.display, glam::DVec3::ZERO, d, 1);
    let s = start.elapsed().as_secs_f64();
    eprintln!("{n} cut-out layers passed in {s} s: {hit:?}");
    // Without the cut-outs (the wrong handling) the first layer would be hit at 400 mm.
    let (t, mask) = hit.unwrap();
    assert_eq!(mask, 2);
    assert!((t * -d.z - 800.0).abs() < 1e-9, "{t}");
    assert!(s < 1.0, "{s} s");
}
