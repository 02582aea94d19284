//! Loading of mesh files (glTF 2.0, Wavefront OBJ + MTL) into [`Asset`]s in millimetres.
//!
//! Model: glTF 2.0 (Khronos specification 2.0.1): the default scene (else scene 0, else every
//! root node) is walked and each node's local transform (matrix, or translation · rotation ·
//! scale) is composed down the hierarchy in f64; glTF positions are metres, so a vertex p of a
//! node with world matrix M lands at S(1000) · M · p mm. Normals follow the inverse transpose
//! and are renormalised; a mirroring world matrix reverses the triangle order so front faces
//! stay counter-clockwise. Primitives of mode TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN are
//! read (strips and fans are converted to triangle lists per glTF §3.7.2.1, dropping triangles
//! that repeat an index); POINTS and LINE* primitives are skipped. Missing indices mean
//! sequential vertices; missing normals are computed (area-weighted) after the transform;
//! the texture coordinate set the material's textures use is read, with its
//! `KHR_texture_transform` applied (module [`super::gltf_features`], which also refuses the
//! features not rendered, naming them first). Materials: metallic-roughness base
//! colour factor and texture (their alpha, `alphaMode`, `alphaCutoff` and `doubleSided` for
//! [`super::coverage`]), the normal texture (read linearly, with `TANGENT` where present, for
//! [`super::normal_map`]), metallic and roughness factors, emissive factor
//! and texture, `KHR_materials_emissive_strength` (1 if absent); a primitive without a material
//! gets the glTF default material (base colour 1, metallic 1, roughness 1). Images are decoded
//! here (PNG, JPEG, EXR) from files next to the .gltf, data URIs or buffer views; colour
//! textures are sRGB-decoded (glTF §3.9.2). Sampler wrap modes are kept.
//!
//! OBJ + MTL (via `tobj`; polygons ear-clipped by [`super::obj_features`]; one index per
//! vertex): positions are
//! multiplied by the caller's `obj_unit_mm` (OBJ has no unit); texture coordinates are flipped
//! to the glTF convention (v ← 1 − v); materials are `Diffuse` with `Kd` as the linear base
//! colour (0.8 grey if absent), `map_Kd` as the base colour texture, `Ke`/`map_Ke` as emission;
//! texture paths are relative to the MTL file's folder (the last whitespace-separated word is
//! used if the whole string is not a file, which skips `-o`/`-s`-style options; backslashes
//! are folder separators, as Windows tools write them). Lines that are not UTF-8 are read as
//! Latin-1, and file names also as their Latin-1 bytes ([`resolve_reference`]). Faces without
//! a material get [`AssetMaterial::default`]. A material library that cannot be opened is an
//! error naming it, unless [`LoadOptions::allow_missing_mtl`] is set (then its materials are
//! default materials).
//!
//! Validation: at least one triangle, at most [`MAX_TRIANGLES`] triangles and [`MAX_VERTICES`]
//! vertices (checked before the arrays are built), every index in range, every position
//! finite; normals that come out zero or non-finite are replaced by computed ones. Files over
//! [`MAX_FILE_BYTES`] are refused, and image sizes are limited by [`crate::io`]'s decoders.
//! Errors are one line naming the offending file.
//!
//! [`AssetMaterial::default`]: super::mesh::AssetMaterial::default
//! [`resolve_reference`]: obj::resolve_reference

mod gltf;
mod obj;
mod uri;

use std::path::{Path, PathBuf};

use glam::{DVec2, DVec3};

use self::gltf::load_gltf;
use self::obj::load_obj;
use super::mesh::Asset;
use super::texture::Texture;
use crate::io::IoError;
use crate::io::image_load::{LoadedImage, decode_image_bytes};

/// Largest number of triangles accepted in one file (and in one scene,
/// [`crate::MAX_TRIANGLES`]): a loaded and placed triangle costs about
/// [`BYTES_PER_TRIANGLE`] until the BVH is built, so 10⁷ triangles stay within about 4 GB.
pub const MAX_TRIANGLES: usize = 10_000_000;
/// Largest number of vertices accepted in one file.
pub const MAX_VERTICES: usize = 10_000_000;
/// Peak memory of one triangle from the file to the built BVH, bytes (measured: an OBJ of
/// 500,000 separate quads, 10⁶ triangles and 2·10⁶ vertices, renders at 16×16 px with a peak
/// of 404 MB): f64 positions and normals, indices, material and object ids, the f32 boxes,
/// the BVH builder's nodes and the parser's own arrays.
pub const BYTES_PER_TRIANGLE: u64 = 400;
/// Largest mesh, buffer or image file read, bytes; also the most bytes all buffers of one glTF
/// file may declare together.
pub const MAX_FILE_BYTES: u64 = 2 << 30;
/// Deepest node hierarchy accepted (guards against cycles).
const MAX_NODE_DEPTH: usize = 256;
/// Most node visits of one glTF scene walk: a node shared by several parents is visited once
/// per path, so a diamond-shaped hierarchy of depth d has 2^d paths; the walk stops here
/// instead of running for ever.
pub const MAX_NODE_VISITS: usize = 1_000_000;

/// An error while loading a mesh file or one of the files it references; its message is one
/// line and names the file concerned.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{}: {message}", path.display())]
pub struct LoadError {
    /// The file concerned (the mesh, its material library, a buffer or a texture).
    pub path: PathBuf,
    /// What is wrong, on one line.
    pub message: String,
}

impl LoadError {
    fn new(path: &Path, message: impl std::fmt::Display) -> Self {
        LoadError {
            path: path.to_path_buf(),
            message: message
                .to_string()
                .split_whitespace()
                .collect::<Vec<_>>()
                .join(" "),
        }
    }

    /// A texture error: names the texture file and the mesh that references it.
    fn texture(e: IoError, referenced_by: &Path) -> Self {
        let by = referenced_by.file_name().map_or_else(
            || referenced_by.display().to_string(),
            |n| n.to_string_lossy().into(),
        );
        match e {
            IoError::Io { path, source } => LoadError::new(
                &path,
                format!("cannot read texture (used by {by}): {source}"),
            ),
            IoError::Format { path, message } => LoadError::new(
                &path,
                format!("cannot read texture (used by {by}): {message}"),
            ),
        }
    }
}

/// Options of [`load_asset_with`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoadOptions {
    /// Millimetres per OBJ unit (OBJ files carry no unit): 1 for mm, 10 for cm, 1000 for m.
    pub obj_unit_mm: f64,
    /// Treat an OBJ `mtllib` that cannot be opened as having no materials (its faces get the
    /// default material) instead of failing. Off by default.
    pub allow_missing_mtl: bool,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            obj_unit_mm: 1.0,
            allow_missing_mtl: false,
        }
    }
}

/// Loads a `.gltf`, `.glb` or `.obj` file (extension matched case-insensitively) into an
/// [`Asset`] in millimetres; `obj_unit_mm` is the OBJ unit in mm (ignored for glTF, which is in
/// metres). A missing OBJ material library is an error.
pub fn load_asset(path: &Path, obj_unit_mm: f64) -> Result<Asset, LoadError> {
    load_asset_with(
        path,
        &LoadOptions {
            obj_unit_mm,
            ..LoadOptions::default()
        },
    )
}

/// As [`load_asset`], with all options.
pub fn load_asset_with(path: &Path, options: &LoadOptions) -> Result<Asset, LoadError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let kind = match ext.as_deref() {
        Some(k @ ("gltf" | "glb" | "obj")) => k,
        _ => {
            return Err(LoadError::new(
                path,
                "unsupported mesh file type (supported extensions: .gltf, .glb, .obj)",
            ));
        }
    };
    check_regular_file(path)?;
    let mut asset = if kind == "obj" {
        if !(options.obj_unit_mm.is_finite() && options.obj_unit_mm > 0.0) {
            return Err(LoadError::new(
                path,
                format!(
                    "OBJ unit must be a positive number of mm, not {}",
                    options.obj_unit_mm
                ),
            ));
        }
        load_obj(path, options)?
    } else {
        load_gltf(path)?
    };
    validate(path, &mut asset)?;
    Ok(asset)
}

/// Decodes an in-memory PNG, JPEG or EXR image of type `ext` into a colour texture (sRGB
/// decoded unless EXR); `name_for_messages` names it in errors.
pub fn texture_from_encoded_bytes(
    bytes: Vec<u8>,
    ext: &str,
    name_for_messages: &Path,
) -> Result<Texture, IoError> {
    decode_image_bytes(
        name_for_messages,
        ext,
        bytes,
        crate::limits::MAX_TEXTURE_PIXELS,
    )
    .map(texture_from_image)
}

fn texture_from_image(img: LoadedImage) -> Texture {
    Texture::from_pixels(img.width, img.height, img.channels, &img.values, img.linear)
        .with_alpha(img.alpha)
}

/// The file must exist, be a regular file and be at most [`MAX_FILE_BYTES`] long.
fn check_regular_file(path: &Path) -> Result<u64, LoadError> {
    let meta = std::fs::metadata(path).map_err(|e| LoadError::new(path, e))?;
    if meta.is_dir() {
        return Err(LoadError::new(path, "is a directory, not a mesh file"));
    }
    if !meta.is_file() {
        return Err(LoadError::new(
            path,
            "is not a regular file (a device, FIFO or socket)",
        ));
    }
    if meta.len() > MAX_FILE_BYTES {
        return Err(LoadError::new(
            path,
            format!("file is larger than {MAX_FILE_BYTES} bytes"),
        ));
    }
    Ok(meta.len())
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into())
}

// ------------------------------------------------------------------------------------------
// Validation

fn validate(path: &Path, asset: &mut Asset) -> Result<(), LoadError> {
    let m = &mut asset.mesh;
    if m.triangles.is_empty() {
        return Err(LoadError::new(path, "no triangles"));
    }
    if m.triangles.len() > MAX_TRIANGLES || m.positions_mm.len() > MAX_VERTICES {
        return Err(LoadError::new(
            path,
            format!("more than {MAX_TRIANGLES} triangles or {MAX_VERTICES} vertices"),
        ));
    }
    if let Some(i) = m.first_nonfinite_vertex() {
        return Err(LoadError::new(path, format!("vertex {i} is not finite")));
    }
    if let Some(i) = m.first_vertex_out_of_range() {
        return Err(LoadError::new(
            path,
            format!(
                "vertex {i} lies at {:?} mm, outside the working range of ±{:e} mm (check the node transforms and the unit)",
                m.positions_mm[i].to_array(),
                crate::limits::MAX_COORD_MM
            ),
        ));
    }
    let n = m.positions_mm.len();
    if m.triangles.iter().flatten().any(|&i| i as usize >= n) {
        return Err(LoadError::new(path, "a triangle index is out of range"));
    }
    if m.material_ids.len() != m.triangles.len()
        || m.material_ids
            .iter()
            .any(|&i| i as usize >= asset.materials.len())
    {
        return Err(LoadError::new(path, "a triangle has no material"));
    }
    if !m.uvs.is_empty() && m.uvs.len() != n {
        m.uvs.resize(n, DVec2::ZERO);
    }
    if !m.uvs.iter().all(|uv| uv.is_finite()) {
        return Err(LoadError::new(path, "a texture coordinate is not finite"));
    }
    let bad_normal = |v: &DVec3| !(v.is_finite() && (v.length() - 1.0).abs() < 1e-6);
    if m.normals.len() != n || m.normals.iter().any(bad_normal) {
        let mut computed = m.clone();
        computed.compute_normals();
        m.normals.resize(n, DVec3::ZERO);
        for (v, c) in m.normals.iter_mut().zip(&computed.normals) {
            if bad_normal(v) {
                // A vertex of only degenerate triangles keeps some unit normal.
                *v = if bad_normal(c) { DVec3::Z } else { *c };
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::SurfaceModel;
    use crate::texture::Wrap;
    use serde_json::json;

    /// A 2×2 8-bit RGB PNG.
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

    fn b64(bytes: &[u8]) -> String {
        const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut s = String::new();
        for c in bytes.chunks(3) {
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

    /// Binary buffer of the quad: positions, normals, uvs, indices (140 bytes).
    fn quad_bin() -> Vec<u8> {
        let mut b = Vec::new();
        for p in QUAD_M {
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

    /// The glTF JSON of the quad with buffer 0 given by `buffer` and `image` as image 0.
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
        json!({
            "asset": {"version": "2.0"},
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{
                "attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
                "indices": 3, "material": 0}]}],
            "materials": [{"name": "tex", "pbrMetallicRoughness": {
                "baseColorTexture": {"index": 0}, "metallicFactor": 0.0}}],
            "textures": [{"source": 0, "sampler": 0}],
            "samplers": [{"wrapS": 33071, "wrapT": 33648}],
            "images": [image],
            "buffers": [buffer],
            "bufferViews": views,
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                 "min": [-0.0625, -0.0625, 0.0], "max": [0.0625, 0.0625, 0.0]},
                {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
                {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
                {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}
            ]
        })
    }

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

    pub(super) fn write(path: &Path, bytes: impl AsRef<[u8]>) {
        std::fs::write(path, bytes).unwrap();
    }

    #[test]
    fn same_quad_from_four_formats() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let png = png_bytes();
        let bin = quad_bin();
        write(&d.join("tex.png"), &png);
        // (a) external .bin and PNG.
        write(&d.join("quad.bin"), &bin);
        let a = quad_json(
            json!({"uri": "quad.bin", "byteLength": bin.len()}),
            json!({"uri": "tex.png"}),
            json!(null),
        );
        write(&d.join("a.gltf"), serde_json::to_vec(&a).unwrap());
        // (b) embedded data URI buffer, image as a data URI too.
        let b = quad_json(
            json!({"uri": format!("data:application/octet-stream;base64,{}", b64(&bin)),
                   "byteLength": bin.len()}),
            json!({"uri": format!("data:image/png;base64,{}", b64(&png))}),
            json!(null),
        );
        write(&d.join("b.gltf"), serde_json::to_vec(&b).unwrap());
        // (c) GLB with the PNG in a buffer view after the geometry.
        let mut glb_bin = bin.clone();
        glb_bin.extend(&png);
        let c = quad_json(
            json!({"byteLength": glb_bin.len()}),
            json!({"bufferView": 4, "mimeType": "image/png"}),
            json!([{"buffer": 0, "byteOffset": bin.len(), "byteLength": png.len()}]),
        );
        write(&d.join("c.GLB"), glb(&c, &glb_bin));
        // (d) OBJ + MTL in mm, same vertex and triangle order, v flipped.
        write(
            &d.join("d.obj"),
            "mtllib d.mtl\nv -62.5 -62.5 0\nv 62.5 -62.5 0\nv 62.5 62.5 0\nv -62.5 62.5 0\n\
             vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nusemtl tex\n\
             f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n",
        );
        write(&d.join("d.mtl"), "newmtl tex\nKd 1 1 1\nmap_Kd tex.png\n");

        let assets: Vec<Asset> = ["a.gltf", "b.gltf", "c.GLB", "d.obj"]
            .iter()
            .map(|n| load_asset(&d.join(n), 1.0).unwrap_or_else(|e| panic!("{e}")))
            .collect();
        let r = &assets[0];
        assert_eq!(r.mesh.positions_mm[1], DVec3::new(62.5, -62.5, 0.0));
        assert_eq!(r.mesh.uvs[3], DVec2::ZERO);
        assert_eq!(r.mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(r.materials[0].model, SurfaceModel::MetallicRoughness);
        assert_eq!(r.materials[0].metallic, 0.0);
        let tex = r.materials[0].base_color_texture.as_ref().unwrap();
        assert_eq!(
            (tex.wrap_s, tex.wrap_t),
            (Wrap::ClampToEdge, Wrap::MirroredRepeat)
        );
        assert_eq!(tex.texels[0], [1.0, 0.0, 0.0]);
        for (k, x) in assets.iter().enumerate() {
            assert_eq!(x.mesh.positions_mm, r.mesh.positions_mm, "asset {k}");
            assert_eq!(x.mesh.normals, r.mesh.normals, "asset {k}");
            assert_eq!(x.mesh.uvs, r.mesh.uvs, "asset {k}");
            assert_eq!(x.mesh.triangles, r.mesh.triangles, "asset {k}");
            assert_eq!(x.mesh.material_ids, vec![0, 0], "asset {k}");
            let t = x.materials[0].base_color_texture.as_ref().unwrap();
            assert_eq!((t.width, t.height), (2, 2));
            assert_eq!(t.texels, tex.texels, "asset {k}");
            assert_eq!(x.materials[0].base_color, [1.0; 3]);
        }
        assert_eq!(assets[3].materials[0].model, SurfaceModel::Diffuse);
        assert_eq!(assets[0].mesh.normals[0], DVec3::Z);
    }

    /// A one-triangle glTF whose mesh hangs under `parent` → `child` nodes.
    pub(super) fn nested_gltf(dir: &Path, name: &str, parent: serde_json::Value) -> PathBuf {
        let tri: [[f32; 3]; 3] = [[0.0625, 0.0, 0.0], [0.0, 0.0625, 0.0], [0.0, 0.0, 0.0625]];
        let mut bin = Vec::new();
        tri.iter()
            .flatten()
            .for_each(|v| bin.extend(v.to_le_bytes()));
        let mut parent = parent;
        parent["children"] = json!([1]);
        let doc = json!({
            "asset": {"version": "2.0"},
            "scenes": [{"nodes": [0]}],
            "nodes": [parent,
                      {"mesh": 0, "translation": [0.25, 0.5, 0.0], "scale": [2.0, 3.0, 4.0]}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "buffers": [{"uri": format!("data:application/octet-stream;base64,{}", b64(&bin)),
                         "byteLength": 36}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                           "min": [0.0, 0.0, 0.0], "max": [0.0625, 0.0625, 0.0625]}]
        });
        let p = dir.join(name);
        write(&p, serde_json::to_vec(&doc).unwrap());
        p
    }

    fn err(path: &Path) -> String {
        let e = load_asset(path, 1.0).unwrap_err().to_string();
        assert!(!e.contains('\n'), "{e}");
        e
    }

    #[test]
    fn errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let e = err(&d.join("nope.glb"));
        assert!(e.contains("nope.glb"), "{e}");
        std::fs::create_dir(d.join("folder.obj")).unwrap();
        let e = err(&d.join("folder.obj"));
        assert!(e.contains("folder.obj") && e.contains("directory"), "{e}");
        let e = err(&d.join("mesh.stl"));
        assert!(e.contains("mesh.stl") && e.contains(".gltf"), "{e}");
        // Points only: no triangles.
        let bin: Vec<u8> = [0f32; 9].iter().flat_map(|v| v.to_le_bytes()).collect();
        let doc = json!({
            "asset": {"version": "2.0"},
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": 0}]}],
            "buffers": [{"uri": format!("data:application/octet-stream;base64,{}", b64(&bin)),
                         "byteLength": 36}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                           "min": [0.0, 0.0, 0.0], "max": [0.0, 0.0, 0.0]}]
        });
        write(&d.join("points.gltf"), serde_json::to_vec(&doc).unwrap());
        let e = err(&d.join("points.gltf"));
        assert!(
            e.contains("points.gltf") && e.contains("no triangles"),
            "{e}"
        );
        // Missing texture (glTF and OBJ).
        let bin = quad_bin();
        write(&d.join("quad.bin"), &bin);
        let j = quad_json(
            json!({"uri": "quad.bin", "byteLength": bin.len()}),
            json!({"uri": "missing.png"}),
            json!(null),
        );
        write(&d.join("t.gltf"), serde_json::to_vec(&j).unwrap());
        let e = err(&d.join("t.gltf"));
        assert!(e.contains("missing.png") && e.contains("t.gltf"), "{e}");
        write(&d.join("m.mtl"), "newmtl a\nmap_Kd gone.jpg\n");
        write(
            &d.join("m.obj"),
            "mtllib m.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        );
        let e = err(&d.join("m.obj"));
        assert!(e.contains("gone.jpg"), "{e}");
        // Missing buffer file.
        let j = quad_json(
            json!({"uri": "lost.bin", "byteLength": 140}),
            json!({"uri": "x.png"}),
            json!(null),
        );
        write(&d.join("b.gltf"), serde_json::to_vec(&j).unwrap());
        let e = err(&d.join("b.gltf"));
        assert!(e.contains("lost.bin") && e.contains("b.gltf"), "{e}");
        // NaN vertex.
        write(&d.join("bad.obj"), "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n");
        let e = err(&d.join("bad.obj"));
        assert!(
            e.contains("bad.obj") && e.contains("vertex 1 is not finite"),
            "{e}"
        );
        // OBJ without faces, garbage glTF, missing MTL (strict by default, lenient on request).
        write(&d.join("faces.obj"), "v 0 0 0\n");
        assert!(err(&d.join("faces.obj")).contains("faces.obj: no triangles"));
        write(&d.join("junk.glb"), b"glTF\x02\0\0\0garbage");
        assert!(err(&d.join("junk.glb")).contains("junk.glb"));
        let p = d.join("nomtl.obj");
        write(
            &p,
            "mtllib absent.mtl\nusemtl x\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        );
        let e = err(&p);
        assert!(e.contains("absent.mtl") && e.contains("nomtl.obj"), "{e}");
        let opts = LoadOptions {
            obj_unit_mm: 1.0,
            allow_missing_mtl: true,
        };
        let a = load_asset_with(&p, &opts).unwrap();
        assert_eq!(a.materials[0].base_color, [0.8; 3]);
        // An index out of range in a glTF accessor.
        let mut j = quad_json(
            json!({"uri": "quad.bin", "byteLength": bin.len()}),
            json!({"uri": "tex.png"}),
            json!(null),
        );
        j["accessors"][3]["count"] = json!(60);
        write(&d.join("range.gltf"), serde_json::to_vec(&j).unwrap());
        assert!(err(&d.join("range.gltf")).contains("range.gltf"));
    }
}
