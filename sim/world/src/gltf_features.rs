//! glTF features beyond the loader's core (Khronos glTF 2.0 specification 2.0.1 and the
//! `KHR_texture_transform` extension): what is supported, and a clear refusal for what is not,
//! so that no feature is rendered silently wrong.
//!
//! Supported here:
//! - any texture coordinate set (`texCoord` of the base colour and emissive textures, which
//!   must agree, as the mesh carries one set);
//! - `KHR_texture_transform` on those textures (used or required): the affine map
//!   uv′ = T(offset)·R(rotation)·S(scale)·uv is applied to the vertices' coordinates on load,
//!   which is exact because texture coordinates are interpolated linearly over a triangle.
//!   R rotates the UVs counter-clockwise as seen in the image (v grows downward):
//!   u′ = cos r·u + sin r·v, v′ = −sin r·u + cos r·v (the extension's GLSL reference code,
//!   `mat3(cos, −sin, 0, sin, cos, 0)` read column-major);
//! - vertex colours `COLOR_0` (RGB or RGBA, float or normalised integers; alpha ignored),
//!   linear RGB multiplying the base colour factor and texture (glTF §3.7.2.1, §3.9.2);
//! - morph targets at their default weights and skins at the default pose (read and applied
//!   by [`super::gltf_shape`]);
//! - normal maps (`normalTexture` with a finite `scale`, on the same coordinates as the other
//!   textures; rendered by [`super::normal_map`]);
//! - `alphaMode` `MASK`/`BLEND` and `doubleSided` (read by the loader, rendered by
//!   [`super::coverage`]); `alphaCutoff` and the base colour alpha must lie in [0, 1].
//!
//! Refused, with one short line naming the feature first (a model is loaded faithfully or
//! not at all): a required extension the loader does not read (e.g.
//! `KHR_draco_mesh_compression`, `KHR_texture_basisu`, `EXT_meshopt_compression`);
//! more than four joint influences (`JOINTS_1`); base colour and emissive textures on different coordinate sets or transforms.

use glam::{DVec2, DVec3};

/// The glTF JSON of a `.gltf` or `.glb` file's bytes (None if it is not readable JSON: the
/// `gltf` crate then reports the problem).
fn document_json(bytes: &[u8]) -> Option<serde_json::Value> {
    let json = if bytes.starts_with(b"glTF") {
        let len = u32::from_le_bytes(bytes.get(12..16)?.try_into().ok()?) as usize;
        if bytes.get(16..20)? != b"JSON" {
            return None;
        }
        bytes.get(20..20usize.checked_add(len)?)?
    } else {
        bytes
    };
    serde_json::from_slice(json).ok()
}

/// Checks `extensionsRequired` before anything else is parsed: the first extension the loader
/// does not read is refused in one line that names it first.
pub fn check_required_extensions(bytes: &[u8]) -> Result<(), String> {
    // Most files require nothing: skip the JSON parse (a .gltf with data URIs can be large).
    let key = b"extensionsRequired";
    if !bytes.windows(key.len()).any(|w| w == key) {
        return Ok(());
    }
    let Some(doc) = document_json(bytes) else {
        return Ok(());
    };
    let Some(req) = doc.get("extensionsRequired").and_then(|v| v.as_array()) else {
        return Ok(());
    };
    for ext in req.iter().filter_map(|v| v.as_str()) {
        if !gltf::json::extensions::ENABLED_EXTENSIONS.contains(&ext) {
            return Err(format!(
                "{ext}: this required glTF extension is not supported (export the model \
                 without it, e.g. `gltf-transform copy` decompresses Draco and meshopt)"
            ));
        }
    }
    Ok(())
}

/// Refuses the features this loader does not render (module documentation), naming the
/// feature first.
pub fn check_document(doc: &gltf::Document, normals: &NormalPlans) -> Result<(), String> {
    for mat in doc.materials() {
        let name = mat.name().map_or_else(
            || format!("material {}", mat.index().unwrap_or(0)),
            |n| format!("material {n:?}"),
        );
        if let Some(c) = mat.alpha_cutoff()
            && !(0.0..=1.0).contains(&c)
        {
            return Err(format!(
                "alphaCutoff ({name}): {c} is not a number in [0, 1]"
            ));
        }
        let a = mat.pbr_metallic_roughness().base_color_factor()[3];
        if !(0.0..=1.0).contains(&a) {
            return Err(format!(
                "baseColorFactor ({name}): alpha {a} is not a number in [0, 1]"
            ));
        }
        if let Some(nt) = mat.normal_texture()
            && !nt.scale().is_finite()
        {
            return Err(format!(
                "normalTexture.scale ({name}): {} is not a finite number",
                nt.scale()
            ));
        }
        uv_plan(&mat, normals).map_err(|e| format!("{e} ({name})"))?;
    }
    super::gltf_shape::check_weights(doc)?;
    for mesh in doc.meshes() {
        for p in mesh.primitives() {
            if p.get(&gltf::Semantic::Joints(1)).is_some() {
                return Err(format!(
                    "JOINTS_1 (mesh {}): more than four joint influences per vertex are not \
                     supported",
                    mesh.index()
                ));
            }
        }
    }
    Ok(())
}

/// Which texture coordinates a material reads: the set and the `KHR_texture_transform`
/// affine map (2 × 3, row-major: u′ = m[0]·(u, v, 1), v′ = m[1]·(u, v, 1)), if any.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UvPlan {
    /// The `TEXCOORD_n` set.
    pub set: u32,
    /// The texture transform (None: identity).
    pub transform: Option<[[f64; 3]; 2]>,
}

impl UvPlan {
    /// Applies the transform to a coordinate.
    #[inline]
    pub fn apply(&self, uv: DVec2) -> DVec2 {
        match self.transform {
            None => uv,
            Some(m) => DVec2::new(
                m[0][0] * uv.x + m[0][1] * uv.y + m[0][2],
                m[1][0] * uv.x + m[1][1] * uv.y + m[1][2],
            ),
        }
    }
}

/// The affine map of `KHR_texture_transform` (offset, rotation in radians, scale).
pub fn texture_transform(offset: [f64; 2], rotation: f64, scale: [f64; 2]) -> [[f64; 3]; 2] {
    let (s, c) = rotation.sin_cos();
    [
        [c * scale[0], s * scale[1], offset[0]],
        [-s * scale[0], c * scale[1], offset[1]],
    ]
}

fn info_plan(info: &gltf::texture::Info) -> UvPlan {
    let mut set = info.tex_coord();
    let transform = info.texture_transform().map(|t| {
        if let Some(s) = t.tex_coord() {
            set = s;
        }
        let f = |v: [f32; 2]| v.map(f64::from);
        texture_transform(f(t.offset()), f64::from(t.rotation()), f(t.scale()))
    });
    UvPlan { set, transform }
}

/// The texture coordinates of each material's normal texture, by material index: its
/// `texCoord` and `KHR_texture_transform`, read from the glTF JSON (the `gltf` crate does not
/// parse that extension on normal textures). Empty when the file has no normal texture.
pub fn normal_plans(bytes: &[u8]) -> NormalPlans {
    let key = b"normalTexture";
    if !bytes.windows(key.len()).any(|w| w == key) {
        return NormalPlans::default();
    }
    let Some(doc) = document_json(bytes) else {
        return NormalPlans::default();
    };
    let mut plans = NormalPlans::default();
    let materials = doc.get("materials").and_then(|m| m.as_array());
    for (i, m) in materials.into_iter().flatten().enumerate() {
        let Some(nt) = m.get("normalTexture") else {
            continue;
        };
        let num = |v: Option<&serde_json::Value>| v.and_then(serde_json::Value::as_f64);
        let mut set = num(nt.get("texCoord")).unwrap_or(0.0) as u32;
        let transform = nt
            .get("extensions")
            .and_then(|e| e.get("KHR_texture_transform"))
            .map(|t| {
                let pair = |k: &str, d: f64| -> [f64; 2] {
                    let v = t.get(k);
                    let at = |j: usize| num(v.and_then(|v| v.get(j)));
                    [at(0).unwrap_or(d), at(1).unwrap_or(d)]
                };
                if let Some(s) = num(t.get("texCoord")) {
                    set = s as u32;
                }
                let rotation = num(t.get("rotation")).unwrap_or(0.0);
                texture_transform(pair("offset", 0.0), rotation, pair("scale", 1.0))
            });
        plans.0.insert(i, UvPlan { set, transform });
    }
    plans
}

/// The texture coordinates of the materials' normal textures ([`normal_plans`]).
#[derive(Clone, Debug, Default)]
pub struct NormalPlans(std::collections::HashMap<usize, UvPlan>);

/// The texture coordinates a material's base colour, emissive and normal textures read (set 0
/// and no transform without textures); an error if they differ (the mesh carries one set).
pub fn uv_plan(mat: &gltf::Material, normals: &NormalPlans) -> Result<UvPlan, String> {
    let plans = [
        mat.pbr_metallic_roughness()
            .base_color_texture()
            .map(|i| info_plan(&i)),
        mat.emissive_texture().map(|i| info_plan(&i)),
        mat.normal_texture().map(|n| {
            mat.index()
                .and_then(|i| normals.0.get(&i).copied())
                .unwrap_or(UvPlan {
                    set: n.tex_coord(),
                    transform: None,
                })
        }),
    ];
    let mut used = plans.into_iter().flatten();
    let Some(first) = used.next() else {
        return Ok(UvPlan::default());
    };
    if used.any(|p| p != first) {
        return Err(
            "texCoord/KHR_texture_transform: the base colour, emissive and normal textures \
             use different texture coordinates, which is not supported"
                .to_string(),
        );
    }
    Ok(first)
}

/// The `COLOR_0` vertex colours of a primitive with `n` vertices as linear RGB and their
/// alpha (both empty without them; the alpha also empty for RGB colours or when it is 1
/// everywhere). Errors (one line) if the accessor has another count or cannot be read.
pub fn vertex_colors(
    buffers: &[Vec<u8>],
    prim: &gltf::Primitive,
    n: usize,
) -> Result<(Vec<DVec3>, Vec<f64>), String> {
    let Some(acc) = prim.get(&gltf::Semantic::Colors(0)) else {
        return Ok((Vec::new(), Vec::new()));
    };
    if acc.count() != n {
        return Err(format!(
            "COLOR_0 (accessor {}) has {} elements for {n} vertices",
            acc.index(),
            acc.count()
        ));
    }
    let read = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let reader = prim.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
        reader.read_colors(0).map(|c| {
            let f = |v: f32| {
                let v = f64::from(v);
                if v.is_finite() { v.max(0.0) } else { 0.0 }
            };
            c.into_rgba_f32()
                .map(|p| (DVec3::new(f(p[0]), f(p[1]), f(p[2])), f(p[3]).min(1.0)))
                .unzip::<_, _, Vec<_>, Vec<_>>()
        })
    }));
    match read {
        Ok(Some((c, mut a))) if c.len() == n => {
            if a.iter().all(|v| *v >= 1.0) {
                a = Vec::new();
            }
            Ok((c, a))
        }
        _ => Err(format!(
            "COLOR_0 (accessor {}): unreadable data (type or range)",
            acc.index()
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The transform against the extension's composition T·R·S written out by hand for a
    /// quarter turn: scale (2, 3), rotation π/2, offset (0.5, 0.25) maps (1, 0) to
    /// (0.5, 0.25) + R·(2, 0) = (0.5, 0.25) + (0, −2) and (0, 1) to (0.5, 0.25) + R·(0, 3) =
    /// (0.5 + 3, 0.25). A transform built in the wrong order (S·R·T) fails.
    #[test]
    fn texture_transform_composes_t_r_s() {
        let p = UvPlan {
            set: 0,
            transform: Some(texture_transform(
                [0.5, 0.25],
                std::f64::consts::FRAC_PI_2,
                [2.0, 3.0],
            )),
        };
        let a = p.apply(DVec2::new(1.0, 0.0));
        let b = p.apply(DVec2::new(0.0, 1.0));
        assert!((a - DVec2::new(0.5, -1.75)).length() < 1e-12, "{a}");
        assert!((b - DVec2::new(3.5, 0.25)).length() < 1e-12, "{b}");
        // Wrong order: scale after the offset.
        let wrong = |uv: DVec2| (uv + DVec2::new(0.5, 0.25)) * DVec2::new(2.0, 3.0);
        assert!((wrong(DVec2::new(1.0, 0.0)) - a).length() > 0.1);
    }

    #[test]
    fn required_extension_is_named_first() {
        let j = br#"{"asset":{"version":"2.0"},"extensionsRequired":["KHR_materials_emissive_strength","KHR_draco_mesh_compression"]}"#;
        let e = check_required_extensions(j).unwrap_err();
        assert!(e.starts_with("KHR_draco_mesh_compression:"), "{e}");
        assert!(!e.contains('\n'));
        let ok = br#"{"asset":{"version":"2.0"},"extensionsRequired":["KHR_texture_transform"]}"#;
        assert!(check_required_extensions(ok).is_ok());
        // The same JSON inside a GLB container.
        let mut glb = b"glTF".to_vec();
        glb.extend(2u32.to_le_bytes());
        glb.extend(((20 + j.len()) as u32).to_le_bytes());
        glb.extend((j.len() as u32).to_le_bytes());
        glb.extend(b"JSON");
        glb.extend(j);
        assert!(
            check_required_extensions(&glb)
                .unwrap_err()
                .starts_with("KHR_draco")
        );
    }
}
