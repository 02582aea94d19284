//! glTF surface detail and shape rendered faithfully: normal maps, morph targets at their
//! default weights and skins at their default pose, each in a file the test writes, checked
//! against an independent construction, with a deliberately wrong handling that fails.

use std::path::Path;

use super::asset_features::{b64, load, quad_gltf};

/// Frontal image (mono, 24 × 24 px, 2 spp) of the scene with `object` (TOML lines after
/// `[[object]]`), direct light only, from a point light 10 m away in direction `light_dir`
/// from (0, 0, −400) mm (irradiance 1 there).
fn frontal_mean(dir: &Path, name: &str, object: &str, light_dir: [f64; 3]) -> (f64, Vec<u16>) {
    let p = [
        1e4 * light_dir[0],
        1e4 * light_dir[1],
        -400.0 + 1e4 * light_dir[2],
    ];
    let toml = format!(
        "[display]\nenabled = false\n[sampling]\nmax_depth = 1\n[[object]]\n{object}\n\
         [[light]]\nkind = \"point\"\nposition_mm = {p:?}\nscale = 1e8\nspectrum = \"flat\"\n"
    );
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, toml).unwrap();
    let sets = [
        "sensor.crop_px=[24,24]".to_string(),
        "sensor.pitch_um=35.2".to_string(),
    ];
    let ls = stscam::scene::load_scene(Some(&path), &sets).unwrap();
    let sys = stscam::system::System::build(&ls).unwrap();
    let f = stscam::world::frontal::render_frontal(&sys, 24, 24, 2, 3).unwrap();
    let ch = &f.channels[0];
    let m = ch.iter().map(|v| f64::from(*v)).sum::<f64>() / ch.len() as f64;
    (m, f.mask)
}

/// A constant normal map tilted by θ = 20° toward +u (texel (sin θ, 0, cos θ) encoded as
/// (2c − 1), 16-bit, read linearly) on a flat quad facing the camera renders like the same
/// quad without the map, turned by 20° about y so that its geometric normal is the tilted one
/// (same view and light directions in the shading frame), under a far point light 30° off
/// the axis (tolerance 0.2 %: the hit points differ by the tilt; measured 1e-5). Ignoring the map (cos 30° vs
/// cos 10° for a Lambertian, 12 %), tilting the wrong way (the tangent reversed, cos 50°) and
/// reading the map as sRGB all differ from the reference by more than 3 %.
#[test]
fn normal_map_tilts_the_shading_normal_like_tilted_geometry() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (s, c) = 20f64.to_radians().sin_cos();
    let code = |v: f64| ((v + 1.0) / 2.0 * 65535.0).round() as u16;
    let texel = [code(s), code(0.0), code(c)];
    let map = stscam::io::encode_png16(1, 1, 3, &texel, stscam::io::PngTransfer::Linear).unwrap();
    let mat_map = serde_json::json!({"normalTexture": {"index": 0},
                                     "pbrMetallicRoughness": {"metallicFactor": 0.0}});
    let mut doc = quad_gltf(mat_map, None);
    doc["images"][0]["uri"] = format!("data:image/png;base64,{}", b64(&map)).into();
    std::fs::write(d.join("mapped.gltf"), serde_json::to_vec(&doc).unwrap()).unwrap();
    let plain = quad_gltf(
        serde_json::json!({"pbrMetallicRoughness": {"metallicFactor": 0.0}}),
        None,
    );
    std::fs::write(d.join("plain.gltf"), serde_json::to_vec(&plain).unwrap()).unwrap();
    let material =
        "[object.material]\nbase_color = [0.8, 0.8, 0.8]\nroughness = 1.0\nmetallic = 0.0\n";
    // The 400 mm quad (glTF unit quad × 0.4) centred on (0, 0, −400) mm, turned by `deg`
    // about y (about its corner, then moved so that its centre stays there).
    let placed = |mesh: &str, deg: f64| {
        let (sd, cd) = deg.to_radians().sin_cos();
        let centre = [200.0 * cd, 200.0, -200.0 * sd];
        format!(
            "mesh = \"{mesh}\"\nscale = 0.4\nrotation_deg = [0.0, {deg}, 0.0]\n\
             position_mm = [{}, {}, {}]\n{material}",
            -centre[0],
            -centre[1],
            -400.0 - centre[2]
        )
    };
    let light = [30f64.to_radians().sin(), 0.0, 30f64.to_radians().cos()];
    let (mapped, mask) = frontal_mean(d, "mapped", &placed("mapped.gltf", 0.0), light);
    assert!(mask.iter().all(|m| *m == 1), "the quad fills the frame");
    let (tilted, mask_t) = frontal_mean(d, "tilted", &placed("plain.gltf", 20.0), light);
    assert!(mask_t.iter().all(|m| *m == 1));
    let (flat, _) = frontal_mean(d, "flat", &placed("plain.gltf", 0.0), light);
    let (wrong_way, _) = frontal_mean(d, "wrong", &placed("plain.gltf", -20.0), light);
    eprintln!(
        "normal map: {mapped}, tilted geometry {tilted}, flat {flat}, tilted the wrong way {wrong_way}"
    );
    let rel = |a: f64| (a - tilted).abs() / tilted;
    assert!(rel(mapped) < 0.002, "{mapped} vs {tilted}");
    assert!(rel(flat) > 0.03 && rel(wrong_way) > 0.03);
    // The map read as sRGB (a colour texture) tilts by another angle.
    let decoded = |v: f64| stscam::world::texture::srgb_to_linear(v) * 2.0 - 1.0;
    let t = [
        decoded(f64::from(texel[0]) / 65535.0),
        decoded(f64::from(texel[2]) / 65535.0),
    ];
    let srgb_deg = t[0].atan2(t[1]).to_degrees();
    let (as_srgb, _) = frontal_mean(d, "srgb", &placed("plain.gltf", srgb_deg), light);
    assert!(rel(as_srgb) > 0.03, "{srgb_deg}° {as_srgb}");
    // A hostile scale is refused naming the key (JSON has no NaN; 1e39 overflows f32).
    let mut bad = doc.clone();
    bad["materials"][0]["normalTexture"]["scale"] = 1e39.into();
    let e = load(d, "bad.gltf", &bad).unwrap_err();
    assert!(e.message.starts_with("normalTexture.scale"), "{e}");
}

/// The quad of `quad_gltf` with one morph target moving vertex 2 by (0, 0, 0.25) m (a second,
/// data-URI buffer), `mesh_weights` and `node_weights` if given.
fn morph_quad(
    mesh_weights: Option<serde_json::Value>,
    node_weights: Option<serde_json::Value>,
) -> serde_json::Value {
    let mut doc = quad_gltf(serde_json::json!({}), None);
    let mut bin = Vec::new();
    for k in 0..4 {
        let z = if k == 2 { 0.25f32 } else { 0.0 };
        for v in [0.0f32, 0.0, z] {
            bin.extend(v.to_le_bytes());
        }
    }
    doc["buffers"]
        .as_array_mut()
        .unwrap()
        .push(serde_json::json!({"byteLength": 48,
        "uri": format!("data:application/octet-stream;base64,{}", b64(&bin))}));
    doc["bufferViews"]
        .as_array_mut()
        .unwrap()
        .push(serde_json::json!({"buffer": 1, "byteLength": 48}));
    doc["accessors"]
        .as_array_mut()
        .unwrap()
        .push(serde_json::json!({"bufferView": 5,
        "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [0, 0, 0.25]}));
    doc["meshes"][0]["primitives"][0]["targets"] = serde_json::json!([{"POSITION": 5}]);
    if let Some(w) = mesh_weights {
        doc["meshes"][0]["weights"] = w;
    }
    if let Some(w) = node_weights {
        doc["nodes"][0]["weights"] = w;
    }
    doc
}

/// A morph target at its default weight moves its vertex: mesh weight 1 puts vertex 2 (the
/// corner (1, 1, 0) m) at z = 250 mm, a node weight of 0.5 overrides it (125 mm), no weights
/// leave the base shape; the other vertices stay at z = 0. Ignoring the weights (the base
/// shape) fails the first two. Weights of another count than the targets, and a target
/// accessor with another count than the vertices, are refused naming the key.
#[test]
fn morph_target_default_weights_move_the_vertex() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let z_of = |doc: &serde_json::Value, name: &str| -> Vec<f64> {
        let a = load(d, name, doc).unwrap();
        a.mesh.positions_mm.iter().map(|p| p.z).collect()
    };
    let cases = [
        (Some(serde_json::json!([1.0])), None, 250.0),
        (
            Some(serde_json::json!([1.0])),
            Some(serde_json::json!([0.5])),
            125.0,
        ),
        (None, None, 0.0),
    ];
    for (k, (mw, nw, z2)) in cases.into_iter().enumerate() {
        let z = z_of(&morph_quad(mw, nw), &format!("m{k}.gltf"));
        assert_eq!(z.len(), 4);
        for (i, zi) in z.iter().enumerate() {
            let want = if i == 2 { z2 } else { 0.0 };
            assert!(
                (zi - want).abs() < 1e-9,
                "case {k}, vertex {i}: {zi} vs {want}"
            );
            if i == 2 && z2 != 0.0 {
                assert!(zi.abs() > 100.0, "weights ignored");
            }
        }
    }
    let e = load(
        d,
        "w2.gltf",
        &morph_quad(Some(serde_json::json!([1.0, 0.0])), None),
    )
    .unwrap_err();
    assert!(e.message.starts_with("weights"), "{e}");
    let mut short = morph_quad(Some(serde_json::json!([1.0])), None);
    short["accessors"][5]["count"] = 3.into();
    let e = load(d, "short.gltf", &short).unwrap_err();
    assert!(e.message.starts_with("morph target 0 POSITION"), "{e}");
}

/// A skinned limb: a strip 0.1 m wide and 1 m long (vertices at y = 0, 0.5, 1) on two joints,
/// the root at the origin and a child 0.5 m up, turned 90° about z in the default pose; the
/// bottom pair follows the root, the middle pair half and half, the top pair the child.
/// `edit` changes the document (hostile variants).
fn limb(edit: impl FnOnce(&mut serde_json::Value, &mut Vec<u8>)) -> serde_json::Value {
    let pos: [[f32; 3]; 6] = [
        [0., 0., 0.],
        [0.1, 0., 0.],
        [0., 0.5, 0.],
        [0.1, 0.5, 0.],
        [0., 1., 0.],
        [0.1, 1., 0.],
    ];
    let joints: [[u16; 4]; 6] = [[0, 1, 0, 0]; 6];
    let weights: [[f32; 4]; 6] = [
        [1., 0., 0., 0.],
        [1., 0., 0., 0.],
        [0.5, 0.5, 0., 0.],
        [0.5, 0.5, 0., 0.],
        [0., 1., 0., 0.],
        [0., 1., 0., 0.],
    ];
    let ibm: [[f32; 16]; 2] = [
        [
            1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.,
        ],
        [
            1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., -0.5, 0., 1.,
        ],
    ];
    let mut bin = Vec::new();
    pos.iter()
        .flatten()
        .for_each(|v| bin.extend(v.to_le_bytes())); // 0..72
    joints
        .iter()
        .flatten()
        .for_each(|v| bin.extend(v.to_le_bytes())); // 72..120
    weights
        .iter()
        .flatten()
        .for_each(|v| bin.extend(v.to_le_bytes())); // 120..216
    ibm.iter()
        .flatten()
        .for_each(|v| bin.extend(v.to_le_bytes())); // 216..344
    for i in [0u16, 1, 3, 0, 3, 2, 2, 3, 5, 2, 5, 4] {
        bin.extend(i.to_le_bytes()); // 344..368
    }
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let mut doc = serde_json::json!({
        "asset": {"version": "2.0"},
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 72},
            {"buffer": 0, "byteOffset": 72, "byteLength": 48},
            {"buffer": 0, "byteOffset": 120, "byteLength": 96},
            {"buffer": 0, "byteOffset": 216, "byteLength": 128},
            {"buffer": 0, "byteOffset": 344, "byteLength": 24}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 6, "type": "VEC3",
             "min": [0, 0, 0], "max": [0.1, 1, 0]},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "VEC4"},
            {"bufferView": 2, "componentType": 5126, "count": 6, "type": "VEC4"},
            {"bufferView": 3, "componentType": 5126, "count": 2, "type": "MAT4"},
            {"bufferView": 4, "componentType": 5123, "count": 12, "type": "SCALAR"}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "JOINTS_0": 1,
                                                   "WEIGHTS_0": 2}, "indices": 4}]}],
        // The skinned mesh node's own translation must be ignored.
        "nodes": [
            {"mesh": 0, "skin": 0, "translation": [5.0, 5.0, 5.0]},
            {"children": [2]},
            {"translation": [0.0, 0.5, 0.0], "rotation": [0.0, 0.0, h, h]}
        ],
        "skins": [{"joints": [1, 2], "inverseBindMatrices": 3}],
        "scenes": [{"nodes": [0, 1]}],
        "scene": 0
    });
    edit(&mut doc, &mut bin);
    doc["buffers"] = serde_json::json!([{"byteLength": bin.len(),
        "uri": format!("data:application/octet-stream;base64,{}", b64(&bin))}]);
    doc
}

/// The skinned limb loads at its default pose, vertex by vertex as computed by hand from
/// J_j = G_j·IBM_j (mm, tolerance 1e-3: f32 inputs): bottom (0, 0) and (100, 0); middle
/// halfway between rest and the child's turn, (0, 500) and (50, 550); top turned to
/// (−500, 500) and (−500, 600); bounds x ∈ [−500, 100], y ∈ [0, 600]. The bind pose (skin
/// ignored: y up to 1000), the mesh node's transform applied (+5000 mm) and a joint index out
/// of range, weights not summing to 1 and too few inverse bind matrices (refused naming the
/// key) all fail.
#[test]
fn skinned_limb_takes_the_default_pose() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let a = load(d, "limb.gltf", &limb(|_, _| {})).unwrap();
    let want = [
        [0.0, 0.0],
        [100.0, 0.0],
        [0.0, 500.0],
        [50.0, 550.0],
        [-500.0, 500.0],
        [-500.0, 600.0],
    ];
    assert_eq!(a.mesh.positions_mm.len(), 6);
    for (p, w) in a.mesh.positions_mm.iter().zip(want) {
        assert!(
            (p.x - w[0]).abs() < 1e-3 && (p.y - w[1]).abs() < 1e-3 && p.z.abs() < 1e-3,
            "{p} vs {w:?}"
        );
    }
    let [lo, hi] = stscam::world::bounds_mm(&a.mesh);
    assert!((lo[0] + 500.0).abs() < 1e-3 && (hi[0] - 100.0).abs() < 1e-3);
    assert!(
        lo[1].abs() < 1e-3 && (hi[1] - 600.0).abs() < 1e-3,
        "{lo:?} {hi:?}"
    );
    // Wrong handlings: the bind pose reaches y = 1000 mm; the node transform adds 5000 mm.
    assert!(hi[1] < 1000.0 - 100.0 && hi[1] < 5000.0);
    // Hostile input.
    let bad_joint = limb(|_, bin| bin[72] = 7); // vertex 0's first joint: 7 of 2
    let e = load(d, "j.gltf", &bad_joint).unwrap_err();
    assert!(e.message.starts_with("JOINTS_0"), "{e}");
    let bad_weight = limb(|_, bin| bin[120..124].copy_from_slice(&0.7f32.to_le_bytes()));
    let e = load(d, "w.gltf", &bad_weight).unwrap_err();
    assert!(e.message.starts_with("WEIGHTS_0"), "{e}");
    let few = limb(|doc, _| doc["accessors"][3]["count"] = 1.into());
    let e = load(d, "i.gltf", &few).unwrap_err();
    assert!(e.message.starts_with("inverseBindMatrices"), "{e}");
}
