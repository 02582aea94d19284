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

use std::cell::RefCell;
use std::collections::HashMap;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DAffine3, DMat4, DQuat, DVec2, DVec3, DVec4};

use super::coverage::AlphaMode;
use super::mesh::{Asset, AssetMaterial, Mesh, SurfaceModel};
use super::texture::{Texture, Wrap};
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

fn read_file(path: &Path) -> Result<Vec<u8>, LoadError> {
    check_regular_file(path)?;
    std::fs::read(path).map_err(|e| LoadError::new(path, e))
}

/// Reads at most the first `limit` bytes of a regular file (a glTF buffer: what lies beyond
/// its `byteLength` is never read).
fn read_prefix(path: &Path, limit: u64) -> Result<Vec<u8>, LoadError> {
    use std::io::Read;
    let meta = std::fs::metadata(path).map_err(|e| LoadError::new(path, e))?;
    if !meta.is_file() {
        return Err(LoadError::new(
            path,
            "is not a regular file (a folder, device, FIFO or socket)",
        ));
    }
    let len = meta.len();
    let file = std::fs::File::open(path).map_err(|e| LoadError::new(path, e))?;
    let mut data = Vec::new();
    data.try_reserve_exact(usize::try_from(len.min(limit)).unwrap_or(usize::MAX))
        .map_err(|e| LoadError::new(path, e))?;
    file.take(limit)
        .read_to_end(&mut data)
        .map_err(|e| LoadError::new(path, e))?;
    Ok(data)
}

/// Image type from the leading bytes.
fn sniff_image(bytes: &[u8]) -> Option<&'static str> {
    if bytes.starts_with(b"\x89PNG") {
        Some("png")
    } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        Some("jpg")
    } else if bytes.starts_with(&[0x76, 0x2F, 0x31, 0x01]) {
        Some("exr")
    } else {
        None
    }
}

fn ext_from_mime(mime: &str) -> Option<&'static str> {
    match mime.trim().to_ascii_lowercase().as_str() {
        "image/png" => Some("png"),
        "image/jpeg" | "image/jpg" => Some("jpg"),
        "image/x-exr" | "image/exr" => Some("exr"),
        _ => None,
    }
}

// ------------------------------------------------------------------------------------------
// URIs

/// Standard base64 (RFC 4648 §4), padding optional, whitespace ignored.
fn base64_decode(s: &str) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(s.len() / 4 * 3 + 3);
    let (mut acc, mut bits) = (0u32, 0u32);
    for c in s.bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' => break,
            b' ' | b'\n' | b'\r' | b'\t' => continue,
            _ => return None,
        };
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Some(out)
}

/// Decodes `%XX` escapes of a relative URI; `None` if the result is not UTF-8.
fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        if b[i] == b'%'
            && i + 2 < b.len()
            && let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2]))
        {
            out.push((h * 16 + l) as u8);
            i += 3;
            continue;
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8(out).ok()
}

/// Where a glTF URI's bytes come from.
enum UriData {
    /// A `data:` URI: its bytes and its media type.
    Inline(Vec<u8>, String),
    /// A file (relative URIs resolved against the glTF file's folder).
    File(PathBuf),
}

fn resolve_uri(gltf_path: &Path, uri: &str) -> Result<UriData, LoadError> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (head, payload) = rest
            .split_once(',')
            .ok_or_else(|| LoadError::new(gltf_path, "malformed data URI (no comma)"))?;
        let Some(media) = head.strip_suffix(";base64") else {
            return Err(LoadError::new(gltf_path, "data URI is not base64-encoded"));
        };
        let bytes = base64_decode(payload)
            .ok_or_else(|| LoadError::new(gltf_path, "data URI has invalid base64"))?;
        return Ok(UriData::Inline(bytes, media.to_string()));
    }
    let rel = if let Some(rest) = uri.strip_prefix("file://") {
        rest
    } else if let Some(rest) = uri.strip_prefix("file:") {
        rest
    } else if uri.contains(':') {
        return Err(LoadError::new(
            gltf_path,
            format!("unsupported URI {uri:?} (only relative paths, file: and data: URIs)"),
        ));
    } else {
        uri
    };
    let decoded = percent_decode(rel)
        .ok_or_else(|| LoadError::new(gltf_path, format!("URI {uri:?} is not valid UTF-8")))?;
    let base = gltf_path.parent().unwrap_or(Path::new(""));
    Ok(UriData::File(base.join(decoded)))
}

// ------------------------------------------------------------------------------------------
// glTF

/// Running state of a glTF load.
struct GltfCtx<'a> {
    path: &'a Path,
    buffers: Vec<Vec<u8>>,
    /// Decoded textures by (glTF texture index, read linearly).
    textures: HashMap<(usize, bool), Arc<Texture>>,
    materials: Vec<AssetMaterial>,
    material_ids: HashMap<Option<usize>, u32>,
    triangles: usize,
    vertices: usize,
    normal_plans: super::gltf_features::NormalPlans,
}

/// Reads a glTF / GLB file: the document checked, its buffers read ([`gltf_buffers`]), then
/// the meshes of the scene's node tree ([`gltf_scene_mesh`]) with the skins' default poses.
fn load_gltf(path: &Path) -> Result<Asset, LoadError> {
    let bytes = read_file(path)?;
    super::gltf_features::check_required_extensions(&bytes).map_err(|m| LoadError::new(path, m))?;
    let gltf::Gltf { document, mut blob } = gltf::Gltf::from_slice(&bytes)
        .map_err(|e| LoadError::new(path, format!("not a readable glTF file ({e})")))?;
    let normal_plans = super::gltf_features::normal_plans(&bytes);
    super::gltf_features::check_document(&document, &normal_plans)
        .map_err(|m| LoadError::new(path, m))?;
    drop(bytes);
    let buffers = gltf_buffers(path, &document, blob.take())?;
    let mut ctx = GltfCtx {
        path,
        buffers,
        textures: HashMap::new(),
        materials: Vec::new(),
        material_ids: HashMap::new(),
        triangles: 0,
        vertices: 0,
        normal_plans,
    };
    // Skins: their joint matrices in the default pose.
    let skin_poses = if document.skins().len() == 0 {
        Vec::new()
    } else {
        let globals = super::gltf_shape::node_globals(&document, local_matrix, MAX_NODE_DEPTH)
            .map_err(|m| LoadError::new(path, m))?;
        document
            .skins()
            .map(|s| skin_pose(&ctx, &s, &globals))
            .collect::<Result<Vec<_>, _>>()?
    };
    let mesh = gltf_scene_mesh(&mut ctx, &document, &skin_poses)?;
    Ok(Asset {
        mesh,
        materials: ctx.materials,
    })
}

/// The data of every buffer of `document` (GLB's binary chunk `blob`, data URIs, files beside
/// `path`), each cut to its declared `byteLength`; the declared lengths are summed and checked
/// before any is read.
fn gltf_buffers(
    path: &Path,
    document: &gltf::Document,
    mut blob: Option<Vec<u8>>,
) -> Result<Vec<Vec<u8>>, LoadError> {
    // Every buffer's byteLength is summed before any is read.
    let declared_total = document
        .buffers()
        .fold(0u64, |t, b| t.saturating_add(b.length() as u64));
    if declared_total > MAX_FILE_BYTES {
        return Err(LoadError::new(
            path,
            format!(
                "the buffers declare {declared_total} bytes together, more than the {MAX_FILE_BYTES} accepted"
            ),
        ));
    }
    let mut buffers = Vec::new();
    for buffer in document.buffers() {
        let declared = buffer.length();
        let (mut data, name) = match buffer.source() {
            gltf::buffer::Source::Bin => (
                blob.take()
                    .ok_or_else(|| LoadError::new(path, "GLB has no binary chunk"))?,
                path.to_path_buf(),
            ),
            gltf::buffer::Source::Uri(uri) => match resolve_uri(path, uri)? {
                UriData::Inline(b, _) => (b, path.to_path_buf()),
                UriData::File(p) => {
                    let data = read_prefix(&p, declared as u64).map_err(|e| {
                        LoadError::new(
                            &e.path,
                            format!(
                                "cannot read buffer (used by {}): {}",
                                file_name(path),
                                e.message
                            ),
                        )
                    })?;
                    (data, p)
                }
            },
        };
        if data.len() < declared {
            return Err(LoadError::new(
                &name,
                format!(
                    "buffer {} holds {} bytes, the glTF file declares {declared}",
                    buffer.index(),
                    data.len()
                ),
            ));
        }
        // Bytes past `byteLength` (GLB padding, a longer file) are never used.
        data.truncate(declared);
        buffers.push(data);
    }
    Ok(buffers)
}

/// The root nodes of the default scene (else the first scene, else every node that is no
/// node's child).
fn gltf_roots(document: &gltf::Document) -> Vec<gltf::Node<'_>> {
    match document
        .default_scene()
        .or_else(|| document.scenes().next())
    {
        Some(scene) => scene.nodes().collect(),
        None => {
            let mut is_child = vec![false; document.nodes().len()];
            for n in document.nodes() {
                for c in n.children() {
                    if let Some(f) = is_child.get_mut(c.index()) {
                        *f = true;
                    }
                }
            }
            document.nodes().filter(|n| !is_child[n.index()]).collect()
        }
    }
}

/// Every primitive of every mesh in the node tree under [`gltf_roots`], placed by its node's
/// global transform (a skinned mesh by its joints) in mm, as one mesh; the walk is bounded in
/// depth and in node instances.
fn gltf_scene_mesh(
    ctx: &mut GltfCtx,
    document: &gltf::Document,
    skin_poses: &[super::gltf_shape::SkinPose],
) -> Result<Mesh, LoadError> {
    let path = ctx.path;
    let mut mesh = Mesh::default();
    let mut stack: Vec<(gltf::Node, DMat4, usize)> = gltf_roots(document)
        .into_iter()
        .rev()
        .map(|n| (n, DMat4::IDENTITY, 0))
        .collect();
    let mut visits = 0usize;
    while let Some((node, parent, depth)) = stack.pop() {
        visits += 1;
        if visits > MAX_NODE_VISITS {
            return Err(LoadError::new(
                path,
                format!(
                    "the node hierarchy has more than {MAX_NODE_VISITS} node instances (nodes shared by many parents?)"
                ),
            ));
        }
        if depth > MAX_NODE_DEPTH {
            return Err(LoadError::new(
                path,
                format!("node hierarchy deeper than {MAX_NODE_DEPTH} (a cycle?)"),
            ));
        }
        let world = parent * local_matrix(&node);
        if let Some(m) = node.mesh() {
            // A skinned mesh's node transform is ignored (glTF §3.7.3): the joints place it.
            let skin = node.skin().and_then(|s| skin_poses.get(s.index()));
            let to_mm = match skin {
                Some(_) => DAffine3::from_scale(DVec3::splat(1000.0)),
                None => DAffine3::from_scale(DVec3::splat(1000.0)) * DAffine3::from_mat4(world),
            };
            let weights = super::gltf_shape::morph_weights(&node, &m);
            for prim in m.primitives() {
                if let Some(part) = read_primitive(ctx, &prim, &to_mm, &weights, skin)? {
                    mesh.append(&part, 0);
                }
            }
        }
        let children: Vec<_> = node.children().collect();
        for c in children.into_iter().rev() {
            stack.push((c, world, depth + 1));
        }
    }
    Ok(mesh)
}

/// The joint matrices of a skin in the default pose (`globals`: every node's global
/// transform), its inverse bind matrices checked and read.
fn skin_pose(
    ctx: &GltfCtx,
    skin: &gltf::Skin,
    globals: &[DMat4],
) -> Result<super::gltf_shape::SkinPose, LoadError> {
    let joints: Vec<usize> = skin.joints().map(|j| j.index()).collect();
    let mut ibm = Vec::new();
    if let Some(acc) = skin.inverse_bind_matrices() {
        use gltf::accessor::{DataType as T, Dimensions as D};
        check_accessor(ctx, &acc, "inverseBindMatrices", D::Mat4, &[T::F32])?;
        let buffers = &ctx.buffers;
        let read = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let reader = skin.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
            reader.read_inverse_bind_matrices().map(|it| {
                it.map(|m| DMat4::from_cols_array_2d(&m.map(|c| c.map(f64::from))))
                    .collect::<Vec<_>>()
            })
        }));
        ibm = match read {
            Ok(Some(m)) => m,
            _ => {
                return Err(LoadError::new(
                    ctx.path,
                    format!(
                        "inverseBindMatrices (accessor {}): unreadable data",
                        acc.index()
                    ),
                ));
            }
        };
    }
    super::gltf_shape::SkinPose::new(&joints, globals, &ibm)
        .map_err(|m| LoadError::new(ctx.path, format!("{m} (skin {})", skin.index())))
}

/// A node's local transform in f64 (TRS composed as T · R · S, the quaternion normalised).
fn local_matrix(node: &gltf::Node) -> DMat4 {
    match node.transform() {
        gltf::scene::Transform::Matrix { matrix } => {
            DMat4::from_cols_array_2d(&matrix.map(|c| c.map(f64::from)))
        }
        gltf::scene::Transform::Decomposed {
            translation,
            rotation,
            scale,
        } => {
            let [x, y, z, w] = rotation.map(f64::from);
            let q = DQuat::from_xyzw(x, y, z, w);
            let q = if q.length_squared() > 0.0 {
                q.normalize()
            } else {
                DQuat::IDENTITY
            };
            DMat4::from_scale_rotation_translation(
                DVec3::from_array(scale.map(f64::from)),
                q,
                DVec3::from_array(translation.map(f64::from)),
            )
        }
    }
}

/// An accessor of a per-vertex attribute must have one element a vertex (`n`).
fn check_count(ctx: &GltfCtx, acc: &gltf::Accessor, what: &str, n: usize) -> Result<(), LoadError> {
    if acc.count() == n {
        return Ok(());
    }
    Err(LoadError::new(
        ctx.path,
        format!(
            "{what} (accessor {}): {} elements for {n} vertices",
            acc.index(),
            acc.count()
        ),
    ))
}

/// Checks an accessor before the `gltf` reader touches it: type, count and byte range.
fn check_accessor(
    ctx: &GltfCtx,
    acc: &gltf::Accessor,
    what: &str,
    dims: gltf::accessor::Dimensions,
    types: &[gltf::accessor::DataType],
) -> Result<(), LoadError> {
    let bad = |m: String| {
        Err(LoadError::new(
            ctx.path,
            format!("accessor {} ({what}): {m}", acc.index()),
        ))
    };
    if acc.dimensions() != dims || !types.contains(&acc.data_type()) {
        return bad(format!(
            "unexpected type {:?} {:?}",
            acc.dimensions(),
            acc.data_type()
        ));
    }
    if acc.count() == 0 {
        return bad("is empty".into());
    }
    if acc.count() > 3 * MAX_TRIANGLES {
        return bad(format!("has {} elements, more than accepted", acc.count()));
    }
    if acc.sparse().is_some() {
        // The reader checks sparse ranges itself (failures become errors below).
        return Ok(());
    }
    let Some(view) = acc.view() else {
        return bad("has no buffer view".into());
    };
    let size = acc.size();
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return bad(format!(
            "stride {stride} is smaller than the element size {size}"
        ));
    }
    let end = stride
        .checked_mul(acc.count() - 1)
        .and_then(|v| v.checked_add(size))
        .and_then(|v| v.checked_add(acc.offset()));
    let view_end = view.offset().checked_add(view.length());
    let buf_len = ctx.buffers.get(view.buffer().index()).map_or(0, Vec::len);
    match (end, view_end) {
        (Some(e), Some(ve)) if e <= view.length() && ve <= buf_len => Ok(()),
        _ => bad("data lies outside its buffer".into()),
    }
}

/// Reads one primitive into a mesh in mm (material ids already resolved), or `None` if it has
/// no triangles (points, lines, empty): its accessors checked ([`check_primitive`]), its
/// vertex data read ([`read_vertex_data`]), posed, and its triangles assembled.
fn read_primitive(
    ctx: &mut GltfCtx,
    prim: &gltf::Primitive,
    to_mm: &DAffine3,
    morph_weights: &[f64],
    skin: Option<&super::gltf_shape::SkinPose>,
) -> Result<Option<Mesh>, LoadError> {
    use gltf::mesh::Mode;
    let mode = prim.mode();
    if !matches!(
        mode,
        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
    ) {
        return Ok(None);
    }
    let Some(plan) = check_primitive(ctx, prim, morph_weights, skin)? else {
        return Ok(None);
    };
    // The checks above keep the reader within its buffers; a panic on a malformed sparse
    // accessor is still turned into an error rather than aborting the run.
    let read = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        read_vertex_data(&ctx.buffers, prim, &plan, morph_weights, skin)
    }));
    let Ok(Some(PrimData {
        mut positions,
        mut normals,
        uvs,
        indices,
        mut tangents,
        influences,
    })) = read
    else {
        return Err(LoadError::new(
            ctx.path,
            format!(
                "mesh primitive {} has unreadable accessor data",
                prim.index()
            ),
        ));
    };
    if let (Some(pose), Some((j, w))) = (skin, &influences) {
        pose.apply(&mut positions, &mut normals, &mut tangents, j, w)
            .map_err(|m| LoadError::new(ctx.path, m))?;
    }
    if let Some(i) = indices.iter().find(|&&i| i as usize >= positions.len()) {
        return Err(LoadError::new(
            ctx.path,
            format!("index {i} is out of range ({} vertices)", positions.len()),
        ));
    }
    let triangles = assemble_triangles(mode, &indices, plan.tris);
    if triangles.is_empty() {
        return Ok(None);
    }
    let material = material_id(ctx, &prim.material())?;
    let (colors, alphas) = super::gltf_features::vertex_colors(&ctx.buffers, prim, plan.n)
        .map_err(|m| LoadError::new(ctx.path, m))?;
    let mut mesh = Mesh {
        positions_mm: positions,
        normals,
        uvs,
        material_ids: vec![material; triangles.len()],
        triangles,
        colors,
        alphas,
        tangents,
    };
    transform_mesh(&mut mesh, to_mm);
    if !plan.has_normals {
        mesh.compute_normals();
    }
    Ok(Some(mesh))
}

/// What [`check_primitive`] found of a primitive: its vertex count, triangle count, and which
/// attributes [`read_vertex_data`] reads.
struct PrimPlan {
    n: usize,
    tris: usize,
    has_normals: bool,
    has_uv: bool,
    has_tangents: bool,
    uv_plan: super::gltf_features::UvPlan,
    /// Morph targets with a non-zero weight apply.
    morphing: bool,
}

/// A primitive's vertex data, read and morphed (not yet posed).
struct PrimData {
    positions: Vec<DVec3>,
    normals: Vec<DVec3>,
    uvs: Vec<DVec2>,
    indices: Vec<u32>,
    tangents: Vec<DVec4>,
    /// Joints and weights of a skinned primitive.
    influences: Option<Influences>,
}

/// The joints and weights of each vertex of a skinned primitive.
type Influences = (Vec<[u16; 4]>, Vec<[f64; 4]>);

/// Checks the accessors of a triangle primitive (positions, normals, tangents, texture
/// coordinates, indices, skin and non-zero morph targets) against their buffers and counts its
/// triangles and vertices against the asset's limits; `None` without positions.
fn check_primitive(
    ctx: &mut GltfCtx,
    prim: &gltf::Primitive,
    morph_weights: &[f64],
    skin: Option<&super::gltf_shape::SkinPose>,
) -> Result<Option<PrimPlan>, LoadError> {
    use gltf::accessor::{DataType as T, Dimensions as D};
    use gltf::mesh::Mode;
    let mode = prim.mode();
    let Some(pos_acc) = prim.get(&gltf::Semantic::Positions) else {
        return Ok(None);
    };
    check_accessor(ctx, &pos_acc, "POSITION", D::Vec3, &[T::F32])?;
    let n = pos_acc.count();
    let normals_acc = prim
        .get(&gltf::Semantic::Normals)
        .filter(|a| a.count() == n);
    if let Some(a) = &normals_acc {
        check_accessor(ctx, a, "NORMAL", D::Vec3, &[T::F32])?;
    }
    let tangents_acc = prim
        .get(&gltf::Semantic::Tangents)
        .filter(|a| a.count() == n && prim.material().normal_texture().is_some());
    if let Some(a) = &tangents_acc {
        check_accessor(ctx, a, "TANGENT", D::Vec4, &[T::F32])?;
    }
    let uv_plan =
        super::gltf_features::uv_plan(&prim.material(), &ctx.normal_plans).unwrap_or_default();
    let uv_acc = prim
        .get(&gltf::Semantic::TexCoords(uv_plan.set))
        .filter(|a| a.count() == n);
    if let Some(a) = &uv_acc {
        check_accessor(ctx, a, "TEXCOORD_0", D::Vec2, &[T::F32, T::U8, T::U16])?;
    }
    let n_idx = match prim.indices() {
        Some(a) => {
            check_accessor(ctx, &a, "indices", D::Scalar, &[T::U8, T::U16, T::U32])?;
            a.count()
        }
        None => n,
    };
    let tris = match mode {
        Mode::Triangles => n_idx / 3,
        _ => n_idx.saturating_sub(2),
    };
    ctx.triangles += tris;
    ctx.vertices += n;
    if ctx.triangles > MAX_TRIANGLES || ctx.vertices > MAX_VERTICES {
        return Err(LoadError::new(
            ctx.path,
            format!("more than {MAX_TRIANGLES} triangles or {MAX_VERTICES} vertices"),
        ));
    }
    if skin.is_some() {
        for (sem, what, types) in [
            (gltf::Semantic::Joints(0), "JOINTS_0", &[T::U8, T::U16][..]),
            (
                gltf::Semantic::Weights(0),
                "WEIGHTS_0",
                &[T::F32, T::U8, T::U16][..],
            ),
        ] {
            let Some(acc) = prim.get(&sem) else {
                return Err(LoadError::new(
                    ctx.path,
                    format!("{what}: a skinned primitive needs JOINTS_0 and WEIGHTS_0"),
                ));
            };
            check_count(ctx, &acc, what, n)?;
            check_accessor(ctx, &acc, what, D::Vec4, types)?;
        }
    }
    // Morph targets with a non-zero weight: their displacement accessors, checked.
    let morphing = morph_weights.iter().any(|w| *w != 0.0);
    if morphing {
        for (k, t) in prim.morph_targets().enumerate() {
            if morph_weights.get(k).is_none_or(|w| *w == 0.0) {
                continue;
            }
            let targets = [(t.positions(), "POSITION"), (t.normals(), "NORMAL")];
            for (acc, what) in targets
                .iter()
                .filter_map(|(a, w)| a.as_ref().map(|a| (a, w)))
            {
                let what = format!("morph target {k} {what}");
                check_count(ctx, acc, &what, n)?;
                check_accessor(ctx, acc, &what, D::Vec3, &[T::F32])?;
            }
        }
    }
    Ok(Some(PrimPlan {
        n,
        tris,
        has_normals: normals_acc.is_some(),
        has_uv: uv_acc.is_some(),
        has_tangents: tangents_acc.is_some(),
        uv_plan,
        morphing,
    }))
}

/// Reads the vertex data `plan` names from `buffers`, with the non-zero morph targets applied
/// one at a time (memory stays that of one attribute); `None` where an accessor cannot be read.
fn read_vertex_data(
    buffers: &[Vec<u8>],
    prim: &gltf::Primitive,
    plan: &PrimPlan,
    morph_weights: &[f64],
    skin: Option<&super::gltf_shape::SkinPose>,
) -> Option<PrimData> {
    let reader = prim.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
    let positions: Vec<DVec3> = reader
        .read_positions()?
        .map(|p| DVec3::from_array(p.map(f64::from)))
        .collect();
    let normals: Vec<DVec3> = if plan.has_normals {
        reader
            .read_normals()?
            .map(|p| DVec3::from_array(p.map(f64::from)))
            .collect()
    } else {
        Vec::new()
    };
    let uvs: Vec<DVec2> = if plan.has_uv {
        reader
            .read_tex_coords(plan.uv_plan.set)?
            .into_f32()
            .map(|p| {
                plan.uv_plan
                    .apply(DVec2::new(f64::from(p[0]), f64::from(p[1])))
            })
            .collect()
    } else {
        Vec::new()
    };
    let indices: Vec<u32> = match reader.read_indices() {
        Some(i) => i.into_u32().collect(),
        None => (0..positions.len() as u32).collect(),
    };
    let mut positions = positions;
    let mut normals = normals;
    if plan.morphing {
        // One target at a time: memory stays that of one attribute.
        let vec3 = |v: [f32; 3]| DVec3::from_array(v.map(f64::from));
        for (k, (p, q, _)) in reader.read_morph_targets().enumerate() {
            let Some(&w) = morph_weights.get(k).filter(|w| **w != 0.0) else {
                continue;
            };
            for (values, delta) in [
                (&mut positions, p.map(|i| i.map(vec3).collect::<Vec<_>>())),
                (&mut normals, q.map(|i| i.map(vec3).collect())),
            ] {
                if let Some(d) = delta {
                    if d.len() != values.len() && !values.is_empty() {
                        return None;
                    }
                    super::gltf_shape::apply_morph(values, w, &d);
                }
            }
        }
    }
    let tangents: Vec<DVec4> = if plan.has_tangents {
        reader
            .read_tangents()?
            .map(|t| {
                let v = DVec4::from_array(t.map(f64::from));
                let w = if v.w < 0.0 { -1.0 } else { 1.0 };
                if v.is_finite() {
                    v.truncate().extend(w)
                } else {
                    DVec4::ZERO
                }
            })
            .collect()
    } else {
        Vec::new()
    };
    let influences = match skin {
        Some(_) => {
            let j: Vec<[u16; 4]> = reader.read_joints(0)?.into_u16().collect();
            let w: Vec<[f64; 4]> = reader
                .read_weights(0)?
                .into_f32()
                .map(|w| w.map(f64::from))
                .collect();
            Some((j, w))
        }
        None => None,
    };
    Some(PrimData {
        positions,
        normals,
        uvs,
        indices,
        tangents,
        influences,
    })
}

/// The triangles of `indices` in primitive `mode` (lists, strips with alternating winding, fans
/// around the first index); strips and fans without their degenerate triangles.
fn assemble_triangles(mode: gltf::mesh::Mode, indices: &[u32], tris: usize) -> Vec<[u32; 3]> {
    use gltf::mesh::Mode;
    let mut triangles = Vec::with_capacity(tris);
    match mode {
        Mode::Triangles => {
            triangles.extend(indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]));
        }
        Mode::TriangleStrip => {
            for i in 0..indices.len().saturating_sub(2) {
                let t = if i % 2 == 0 {
                    [indices[i], indices[i + 1], indices[i + 2]]
                } else {
                    [indices[i + 1], indices[i], indices[i + 2]]
                };
                triangles.push(t);
            }
        }
        _ => {
            for i in 1..indices.len().saturating_sub(1) {
                triangles.push([indices[i], indices[i + 1], indices[0]]);
            }
        }
    }
    if mode != Mode::Triangles {
        triangles.retain(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2]);
    }
    triangles
}

/// Applies `m` to positions and (inverse transpose, renormalised) normals; a mirroring `m`
/// reverses the winding.
fn transform_mesh(mesh: &mut Mesh, m: &DAffine3) {
    let nm = m.matrix3.inverse().transpose();
    for p in &mut mesh.positions_mm {
        *p = m.transform_point3(*p);
    }
    for n in &mut mesh.normals {
        let t = nm * *n;
        let len = t.length();
        *n = if len > 0.0 && len.is_finite() {
            t / len
        } else {
            DVec3::ZERO
        };
    }
    mesh.transform_tangents(m);
    if m.matrix3.determinant() < 0.0 {
        for t in &mut mesh.triangles {
            t.swap(1, 2);
        }
    }
}

/// The asset material index of a glTF material (converted on first use).
fn material_id(ctx: &mut GltfCtx, mat: &gltf::Material) -> Result<u32, LoadError> {
    if let Some(&id) = ctx.material_ids.get(&mat.index()) {
        return Ok(id);
    }
    let pbr = mat.pbr_metallic_roughness();
    let bc = pbr.base_color_factor();
    let base_color_texture = match pbr.base_color_texture() {
        Some(info) => Some(gltf_texture(ctx, &info.texture())?),
        None => None,
    };
    let emissive_texture = match mat.emissive_texture() {
        Some(info) => Some(gltf_texture(ctx, &info.texture())?),
        None => None,
    };
    let normal_texture = match mat.normal_texture() {
        Some(n) => Some(gltf_texture_linear(ctx, &n.texture())?),
        None => None,
    };
    let name = match (mat.name(), mat.index()) {
        (Some(n), _) => n.to_string(),
        (None, Some(i)) => format!("material {i}"),
        (None, None) => "default".to_string(),
    };
    let f = |v: f32| f64::from(v);
    let m = AssetMaterial {
        name,
        model: SurfaceModel::MetallicRoughness,
        base_color: [f(bc[0]), f(bc[1]), f(bc[2])],
        base_color_texture,
        emissive: mat.emissive_factor().map(f),
        emissive_texture,
        emissive_strength: mat.emissive_strength().map_or(1.0, f),
        roughness: f(pbr.roughness_factor()),
        metallic: f(pbr.metallic_factor()),
        alpha_mode: match mat.alpha_mode() {
            gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
            gltf::material::AlphaMode::Mask => AlphaMode::Mask {
                cutoff: mat.alpha_cutoff().map_or(0.5, f),
            },
            gltf::material::AlphaMode::Blend => AlphaMode::Blend,
        },
        alpha: f(bc[3]),
        double_sided: mat.double_sided(),
        normal_scale: mat.normal_texture().map_or(1.0, |n| f(n.scale())),
        normal_texture,
    };
    let id = ctx.materials.len() as u32;
    ctx.materials.push(m);
    ctx.material_ids.insert(mat.index(), id);
    Ok(id)
}

/// Decodes (once) the image of a glTF colour texture (sRGB), with its sampler's wrap modes.
fn gltf_texture(ctx: &mut GltfCtx, tex: &gltf::Texture) -> Result<Arc<Texture>, LoadError> {
    gltf_texture_as(ctx, tex, false)
}

/// As [`gltf_texture`] for a texture of linear data (a normal map: no sRGB decoding).
fn gltf_texture_linear(ctx: &mut GltfCtx, tex: &gltf::Texture) -> Result<Arc<Texture>, LoadError> {
    gltf_texture_as(ctx, tex, true)
}

fn gltf_texture_as(
    ctx: &mut GltfCtx,
    tex: &gltf::Texture,
    linear: bool,
) -> Result<Arc<Texture>, LoadError> {
    if let Some(t) = ctx.textures.get(&(tex.index(), linear)) {
        return Ok(t.clone());
    }
    let image = tex.source();
    let label = || {
        let mut s = ctx.path.as_os_str().to_owned();
        s.push(format!("#image{}", image.index()));
        PathBuf::from(s)
    };
    let (bytes, mime, name) = match image.source() {
        gltf::image::Source::View { view, mime_type } => {
            let data = ctx
                .buffers
                .get(view.buffer().index())
                .and_then(|b| b.get(view.offset()..view.offset().checked_add(view.length())?));
            let Some(data) = data else {
                return Err(LoadError::new(
                    ctx.path,
                    format!("image {} lies outside its buffer", image.index()),
                ));
            };
            (data.to_vec(), Some(mime_type.to_string()), label())
        }
        gltf::image::Source::Uri { uri, mime_type } => match resolve_uri(ctx.path, uri)? {
            UriData::Inline(b, media) => {
                (b, mime_type.map(str::to_string).or(Some(media)), label())
            }
            UriData::File(p) => {
                check_regular_file(&p).map_err(|e| {
                    LoadError::new(
                        &e.path,
                        format!(
                            "cannot read texture (used by {}): {}",
                            file_name(ctx.path),
                            e.message
                        ),
                    )
                })?;
                let b = std::fs::read(&p).map_err(|e| {
                    LoadError::texture(
                        IoError::Io {
                            path: p.clone(),
                            source: e,
                        },
                        ctx.path,
                    )
                })?;
                (b, mime_type.map(str::to_string), p)
            }
        },
    };
    let ext = sniff_image(&bytes)
        .or_else(|| mime.as_deref().and_then(ext_from_mime))
        .or_else(|| {
            name.extension().and_then(|e| e.to_str()).map(|e| {
                if e.eq_ignore_ascii_case("exr") {
                    "exr"
                } else {
                    "png"
                }
            })
        })
        .unwrap_or("png");
    let mut texture = if linear {
        decode_image_bytes(&name, ext, bytes, crate::limits::MAX_TEXTURE_PIXELS)
            .map(|img| Texture::from_pixels(img.width, img.height, img.channels, &img.values, true))
    } else {
        texture_from_encoded_bytes(bytes, ext, &name)
    }
    .map_err(|e| LoadError::texture(e, ctx.path))?;
    let sampler = tex.sampler();
    texture.wrap_s = Wrap::from_gltf(sampler.wrap_s().as_gl_enum());
    texture.wrap_t = Wrap::from_gltf(sampler.wrap_t().as_gl_enum());
    let t = Arc::new(texture);
    ctx.textures.insert((tex.index(), linear), t.clone());
    Ok(t)
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into())
}

// ------------------------------------------------------------------------------------------
// OBJ

/// What the MTL loader callback saw.
#[derive(Default)]
struct MtlLog {
    /// Successfully parsed libraries: path and number of materials, in merge order.
    loaded: Vec<(PathBuf, usize)>,
    /// The first failure.
    error: Option<LoadError>,
}

/// Counts the vertices and the triangles (a face of k corners makes k − 2) of an OBJ file by
/// scanning its lines, without building anything: the size check before parsing.
fn obj_counts(path: &Path) -> Result<(u64, u64), LoadError> {
    use std::io::BufRead;
    let file = std::fs::File::open(path).map_err(|e| LoadError::new(path, e))?;
    let mut reader = BufReader::with_capacity(1 << 16, file);
    let (mut vertices, mut triangles) = (0u64, 0u64);
    let mut line = Vec::new();
    loop {
        line.clear();
        let n = reader
            .read_until(b'\n', &mut line)
            .map_err(|e| LoadError::new(path, e))?;
        if n == 0 {
            break;
        }
        let mut words = line
            .split(|c| c.is_ascii_whitespace())
            .filter(|w| !w.is_empty());
        match words.next() {
            Some(b"v") => vertices += 1,
            Some(b"f") => triangles += (words.count() as u64).saturating_sub(2),
            _ => {}
        }
    }
    Ok((vertices, triangles))
}

/// Reads a Wavefront OBJ file with its material libraries: counts checked before reading
/// ([`obj_counts`]), the models read and triangulated ([`read_obj_models`]), then each model a
/// part of one mesh with its converted material ([`obj_part`]).
fn load_obj(path: &Path, options: &LoadOptions) -> Result<Asset, LoadError> {
    let (nv, nt) = obj_counts(path)?;
    if nt > MAX_TRIANGLES as u64 || nv > MAX_VERTICES as u64 {
        return Err(LoadError::new(
            path,
            format!(
                "{nt} triangles and {nv} vertices: more than the {MAX_TRIANGLES} triangles or {MAX_VERTICES} vertices accepted (about {BYTES_PER_TRIANGLE} bytes a triangle)"
            ),
        ));
    }
    if nt == 0 {
        return Err(LoadError::new(
            path,
            "no triangles (no face has three corners)",
        ));
    }
    let (models, materials, log) = read_obj_models(path, options)?;
    // Which library each tobj material came from (for texture paths).
    let mut lib_of = Vec::with_capacity(materials.len());
    for (p, n) in &log.loaded {
        lib_of.extend(std::iter::repeat_n(p.as_path(), *n));
    }
    let mut asset = Asset::default();
    let mut converted: HashMap<Option<usize>, u32> = HashMap::new();
    let mut cache: HashMap<PathBuf, Arc<Texture>> = HashMap::new();
    for model in &models {
        let m = &model.mesh;
        let n = m.positions.len() / 3;
        if m.indices.is_empty() || n == 0 {
            continue;
        }
        let key = m.material_id.filter(|&i| i < materials.len());
        let mat_id = match converted.get(&key) {
            Some(&id) => id,
            None => {
                let mat = match key {
                    Some(i) => {
                        let mtl = lib_of.get(i).copied().unwrap_or(path);
                        obj_material(&materials[i], mtl, path, &mut cache)?
                    }
                    None => AssetMaterial::default(),
                };
                let id = asset.materials.len() as u32;
                asset.materials.push(mat);
                converted.insert(key, id);
                id
            }
        };
        if m.indices.len() % 3 != 0 {
            return Err(LoadError::new(path, "a face was not triangulated"));
        }
        if let Some(&i) = m.indices.iter().find(|&&i| i as usize >= n) {
            return Err(LoadError::new(
                path,
                format!("face index {i} is out of range"),
            ));
        }
        let part = obj_part(m, mat_id, options.obj_unit_mm);
        asset.mesh.append(&part, 0);
    }
    Ok(asset)
}

/// The models and materials of OBJ file `path` (faces triangulated by ear clipping) and the
/// log of its material libraries, with the sizes checked before any f64 array is built.
fn read_obj_models(
    path: &Path,
    options: &LoadOptions,
) -> Result<(Vec<tobj::Model>, Vec<tobj::Material>, MtlLog), LoadError> {
    let file = std::fs::File::open(path).map_err(|e| LoadError::new(path, e))?;
    let mut reader = Utf8Lines {
        inner: BufReader::new(file),
        line: Vec::new(),
        pos: 0,
    };
    let dir = path.parent().unwrap_or(Path::new("")).to_path_buf();
    let log = RefCell::new(MtlLog::default());
    let opts = tobj::LoadOptions {
        // Polygons are triangulated below by ear clipping (`obj_features`).
        triangulate: false,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let result = tobj::load_obj_buf(&mut reader, &opts, |mtl: &Path| {
        load_mtl(mtl, &dir, path, options, &mut log.borrow_mut())
    });
    let log = log.into_inner();
    if let Some(e) = log.error {
        return Err(e);
    }
    let (mut models, materials) =
        result.map_err(|e| LoadError::new(path, format!("not a readable OBJ file ({e})")))?;
    for m in &mut models {
        super::obj_features::triangulate_faces(&mut m.mesh);
    }
    let materials = materials.unwrap_or_default();
    // Size checks before building the f64 arrays.
    let (mut nv, mut nt) = (0usize, 0usize);
    for m in &models {
        nv += m.mesh.positions.len() / 3;
        nt += m.mesh.indices.len() / 3;
    }
    if nt > MAX_TRIANGLES || nv > MAX_VERTICES {
        return Err(LoadError::new(
            path,
            format!("more than {MAX_TRIANGLES} triangles or {MAX_VERTICES} vertices"),
        ));
    }
    Ok((models, materials, log))
}

/// Reads material library `mtl` (named in OBJ file `path`, resolved against its folder `dir`)
/// for tobj, noting it in `log`; a missing library is tolerated with
/// `options.allow_missing_mtl`, any other failure is logged (the first one) and fails the load.
fn load_mtl(
    mtl: &Path,
    dir: &Path,
    path: &Path,
    options: &LoadOptions,
    log: &mut MtlLog,
) -> tobj::MTLLoadResult {
    let full = mtl
        .to_str()
        .and_then(|s| resolve_reference(dir, s, false))
        .unwrap_or_else(|| dir.join(mtl));
    let opened = check_regular_file(&full).and_then(|_| read_mtl_text(&full));
    match opened {
        Err(e) => {
            // Only a library that does not exist is tolerated: a folder, FIFO, device or
            // broken file in its place is an error even then.
            let missing =
                std::fs::metadata(&full).is_err_and(|e| e.kind() == std::io::ErrorKind::NotFound);
            if options.allow_missing_mtl && missing {
                return Ok((Vec::new(), Default::default()));
            }
            if log.error.is_none() {
                log.error = Some(LoadError::new(
                    &e.path,
                    format!(
                        "cannot open material library (used by {}): {}",
                        file_name(path),
                        e.message
                    ),
                ));
            }
            Err(tobj::LoadError::OpenFileFailed)
        }
        Ok(text) => {
            let r = tobj::load_mtl_buf(&mut text.as_bytes());
            match &r {
                Ok((mats, _)) => log.loaded.push((full, mats.len())),
                Err(e) => {
                    if log.error.is_none() {
                        log.error = Some(LoadError::new(
                            &full,
                            format!("not a readable material library ({e})"),
                        ));
                    }
                }
            }
            r
        }
    }
}

/// One OBJ model's mesh with material `mat_id`, in mm (`unit` mm per OBJ unit): unit normals
/// where the model has one per vertex (else computed), v flipped to the texture's rows.
fn obj_part(m: &tobj::Mesh, mat_id: u32, unit: f64) -> Mesh {
    let n = m.positions.len() / 3;
    let positions_mm = m
        .positions
        .chunks_exact(3)
        .map(|p| DVec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])) * unit)
        .collect();
    let normals: Vec<DVec3> = if m.normals.len() == 3 * n {
        m.normals
            .chunks_exact(3)
            .map(|p| {
                let v = DVec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
                let len = v.length();
                if len > 0.0 && len.is_finite() {
                    v / len
                } else {
                    DVec3::ZERO
                }
            })
            .collect()
    } else {
        Vec::new()
    };
    let uvs = if m.texcoords.len() == 2 * n {
        m.texcoords
            .chunks_exact(2)
            .map(|t| DVec2::new(f64::from(t[0]), 1.0 - f64::from(t[1])))
            .collect()
    } else {
        Vec::new()
    };
    let triangles: Vec<[u32; 3]> = m
        .indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let mut part = Mesh {
        positions_mm,
        normals,
        uvs,
        material_ids: vec![mat_id; triangles.len()],
        triangles,
        colors: super::obj_features::vertex_colours(m),
        alphas: Vec::new(),
        tangents: Vec::new(),
    };
    if part.normals.is_empty() {
        part.compute_normals();
    }
    part
}

/// Largest material library read, bytes.
const MAX_MTL_BYTES: u64 = crate::io::input::MAX_TEXT_BYTES;

/// Reads a material library (a regular file of at most [`MAX_MTL_BYTES`]) and checks the arity
/// of its colour lines (`Ka`, `Kd`, `Ks`, `Ke`: three numbers r g b), which the parser
/// would otherwise panic on; an error names the line.
fn read_mtl_text(path: &Path) -> Result<String, LoadError> {
    let bytes = crate::io::input::read_input(path, MAX_MTL_BYTES).map_err(|e| match e {
        IoError::Io { source, .. } => LoadError::new(path, source),
        IoError::Format { message, .. } => LoadError::new(path, message),
    })?;
    let text = decode_text(&bytes).into_owned();
    check_mtl_arity(&text).map_err(|m| LoadError::new(path, m))?;
    Ok(text)
}

/// The first colour line of an MTL text without exactly three numbers, as a message.
fn check_mtl_arity(text: &str) -> Result<(), String> {
    for (n, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        let Some(key @ ("Ka" | "Kd" | "Ks" | "Ke")) = words.next() else {
            continue;
        };
        let values = words.count();
        if values < 3 {
            return Err(format!(
                "line {}: {:?}: {key} needs three numbers (r g b), got {}",
                n + 1,
                line.trim(),
                values
            ));
        }
    }
    Ok(())
}

/// Decodes a text line or file: as UTF-8 when it is valid, otherwise as Latin-1 (each byte
/// to the code point of the same value), as files written by Windows tools often are.
fn decode_text(bytes: &[u8]) -> std::borrow::Cow<'_, str> {
    match std::str::from_utf8(bytes) {
        Ok(s) => s.into(),
        Err(_) => bytes
            .iter()
            .map(|&b| char::from(b))
            .collect::<String>()
            .into(),
    }
}

/// A reader handing each line on as UTF-8 ([`decode_text`]), for the OBJ parser, which
/// refuses other bytes.
struct Utf8Lines<R> {
    inner: R,
    line: Vec<u8>,
    pos: usize,
}

impl<R: std::io::BufRead> std::io::Read for Utf8Lines<R> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        use std::io::BufRead;
        let buf = self.fill_buf()?;
        let n = buf.len().min(out.len());
        out[..n].copy_from_slice(&buf[..n]);
        self.consume(n);
        Ok(n)
    }
}

impl<R: std::io::BufRead> std::io::BufRead for Utf8Lines<R> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        if self.pos >= self.line.len() {
            self.line.clear();
            self.pos = 0;
            self.inner.read_until(b'\n', &mut self.line)?;
            if let std::borrow::Cow::Owned(s) = decode_text(&self.line) {
                self.line = s.into_bytes();
            }
        }
        Ok(&self.line[self.pos..])
    }
    fn consume(&mut self, n: usize) {
        self.pos = (self.pos + n).min(self.line.len());
    }
}

/// Resolves a file reference of an MTL or OBJ file (`mtllib`, `map_Kd`) against `base`, the
/// folder of the referring file: the name as written if such a file exists, else with
/// backslashes read as folder separators (Windows tools write `.\tex.jpg`); with
/// `options_before_name`, also only the last word (`map_Kd -s 1 1 1 tex.png`); for an absolute
/// Windows path (`C:\maps\tex.png`), the file name in `base`. Each name is also tried as the
/// raw Latin-1 bytes of its characters (a file named in Latin-1 on disk). `None` if none exists.
fn resolve_reference(base: &Path, spec: &str, options_before_name: bool) -> Option<PathBuf> {
    let spec = spec.trim();
    let mut names = vec![spec.to_owned(), spec.replace('\\', "/")];
    if options_before_name && let Some(last) = spec.split_whitespace().last() {
        names.push(last.to_owned());
        names.push(last.replace('\\', "/"));
    }
    let windows_absolute = |n: &str| {
        let b = n.as_bytes();
        n.starts_with('/') || (b.len() > 2 && b[0].is_ascii_alphabetic() && b[1] == b':')
    };
    let tails: Vec<String> = names
        .iter()
        .filter(|n| n.contains('/') && windows_absolute(n))
        .filter_map(|n| n.rsplit('/').next().map(str::to_owned))
        .collect();
    names.extend(tails);
    names.into_iter().filter(|n| !n.is_empty()).find_map(|n| {
        let as_written = base.join(&n);
        if as_written.exists() {
            return Some(as_written);
        }
        latin1_path(&n)
            .map(|raw| base.join(raw))
            .filter(|p| p.exists())
    })
}

/// The path whose bytes are the Latin-1 codes of `name`'s characters, if `name` has a
/// character above ASCII and none above U+00FF (Unix only: elsewhere names are not bytes).
fn latin1_path(name: &str) -> Option<PathBuf> {
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStringExt;
        if name.is_ascii() || name.chars().any(|c| u32::from(c) > 0xFF) {
            return None;
        }
        let bytes = name.chars().map(|c| u32::from(c) as u8).collect();
        Some(PathBuf::from(std::ffi::OsString::from_vec(bytes)))
    }
    #[cfg(not(unix))]
    {
        let _ = name;
        None
    }
}

/// Converts a material of the library `mtl` (used by `obj`).
fn obj_material(
    m: &tobj::Material,
    mtl: &Path,
    obj: &Path,
    cache: &mut HashMap<PathBuf, Arc<Texture>>,
) -> Result<AssetMaterial, LoadError> {
    let base = mtl.parent().unwrap_or(Path::new(""));
    let mut load = |key: &str, spec: &str| -> Result<Arc<Texture>, LoadError> {
        let Some(p) = resolve_reference(base, spec, true) else {
            return Err(LoadError::new(
                mtl,
                format!(
                    "material {:?}: {key} \"{}\": no such texture file next to it (used by {})",
                    m.name,
                    spec.trim(),
                    file_name(obj)
                ),
            ));
        };
        if let Some(t) = cache.get(&p) {
            return Ok(t.clone());
        }
        if p.is_dir() {
            return Err(LoadError::new(
                &p,
                format!("texture (used by {}) is a directory", file_name(obj)),
            ));
        }
        let t = Arc::new(Texture::load(&p).map_err(|e| LoadError::texture(e, obj))?);
        cache.insert(p, t.clone());
        Ok(t)
    };
    let parse3 = |s: &str| -> Option<[f64; 3]> {
        let v: Vec<f64> = s
            .split_whitespace()
            .map(str::parse)
            .collect::<Result<_, _>>()
            .ok()?;
        match v.as_slice() {
            [r, g, b] => Some([*r, *g, *b]),
            [g] => Some([*g; 3]),
            _ => None,
        }
    };
    let f3 = |v: [f32; 3]| v.map(f64::from);
    let emissive = m
        .emissive
        .map(f3)
        .or_else(|| m.unknown_param.get("Ke").and_then(|s| parse3(s)))
        .unwrap_or([0.0; 3]);
    let base_color = m
        .diffuse
        .map(f3)
        .unwrap_or(AssetMaterial::default().base_color);
    for (what, v) in [("Kd", base_color), ("Ke", emissive)] {
        if v.iter().any(|c| !c.is_finite() || *c < 0.0) {
            return Err(LoadError::new(
                obj,
                format!(
                    "material {:?}: {what} must be finite and non-negative",
                    m.name
                ),
            ));
        }
    }
    let base_color_texture = match &m.diffuse_texture {
        Some(s) => Some(load("map_Kd", s)?),
        None => None,
    };
    let emissive_texture = match m.unknown_param.get("map_Ke") {
        Some(s) => Some(load("map_Ke", s)?),
        None => None,
    };
    Ok(AssetMaterial {
        name: m.name.clone(),
        model: SurfaceModel::Diffuse,
        base_color,
        base_color_texture,
        emissive,
        emissive_texture,
        ..AssetMaterial::default()
    })
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

    fn write(path: &Path, bytes: impl AsRef<[u8]>) {
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
    fn nested_gltf(dir: &Path, name: &str, parent: serde_json::Value) -> PathBuf {
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

    #[test]
    fn nested_node_transforms_compose() {
        let dir = tempfile::tempdir().unwrap();
        // Parent: 90° about y (x → −z, z → x) as a matrix, translated by 0.125 m along x.
        let m = json!({"matrix": [0.0, 0.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0,
                                  0.125, 0.0, 0.0, 1.0]});
        let a = load_asset(&nested_gltf(dir.path(), "m.gltf", m), 1.0).unwrap();
        // Child: (x, y, z) → (0.25 + 2x, 0.5 + 3y, 4z); parent: (a, b, c) → (c + 0.125, b, −a).
        let expect = |p: DVec3| {
            let c = DVec3::new(0.25 + 2.0 * p.x, 0.5 + 3.0 * p.y, 4.0 * p.z);
            1000.0 * DVec3::new(c.z + 0.125, c.y, -c.x)
        };
        let local = [
            DVec3::new(0.0625, 0.0, 0.0),
            DVec3::new(0.0, 0.0625, 0.0),
            DVec3::new(0.0, 0.0, 0.0625),
        ];
        for (i, &p) in local.iter().enumerate() {
            let got = a.mesh.positions_mm[i];
            assert!((got - expect(p)).length() < 1e-9, "{got} vs {}", expect(p));
        }
        assert_eq!(a.mesh.positions_mm[0], DVec3::new(125.0, 500.0, -375.0));
        // Computed normals are unit and agree with the transformed face.
        let [p, q, r] = a.mesh.triangles[0].map(|i| a.mesh.positions_mm[i as usize]);
        let face = (q - p).cross(r - p).normalize();
        assert!((a.mesh.normals[0] - face).length() < 1e-12);
        // The same parent as a quaternion (TRS): equal to the glam composition, and to the
        // exact rotation within the f32 rounding of the quaternion.
        let (s, c) = (
            std::f32::consts::FRAC_PI_4.sin(),
            std::f32::consts::FRAC_PI_4.cos(),
        );
        let q = json!({"rotation": [0.0, s, 0.0, c], "translation": [0.125, 0.0, 0.0]});
        let b = load_asset(&nested_gltf(dir.path(), "q.gltf", q), 1.0).unwrap();
        let quat = DQuat::from_xyzw(0.0, f64::from(s), 0.0, f64::from(c)).normalize();
        let world = DMat4::from_rotation_translation(quat, DVec3::new(0.125, 0.0, 0.0))
            * DMat4::from_scale_rotation_translation(
                DVec3::new(2.0, 3.0, 4.0),
                DQuat::IDENTITY,
                DVec3::new(0.25, 0.5, 0.0),
            );
        for (i, &p) in local.iter().enumerate() {
            let want = 1000.0 * world.transform_point3(p);
            assert!((b.mesh.positions_mm[i] - want).length() < 1e-9);
            assert!((b.mesh.positions_mm[i] - expect(p)).length() < 1e-3);
        }
    }

    #[test]
    fn obj_units_and_default_material() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cm.obj");
        write(&p, "v 0 0 0\nv 1.5 0 0\nv 0 2 0\nf 1 2 3\n");
        let a = load_asset(&p, 10.0).unwrap();
        assert_eq!(a.mesh.positions_mm[1], DVec3::new(15.0, 0.0, 0.0));
        assert_eq!(a.mesh.positions_mm[2], DVec3::new(0.0, 20.0, 0.0));
        assert_eq!(a.mesh.normals, vec![DVec3::Z; 3]);
        assert!(a.mesh.uvs.is_empty());
        assert_eq!(a.materials.len(), 1);
        assert_eq!(a.materials[0].model, SurfaceModel::Diffuse);
        assert_eq!(a.materials[0].base_color, [0.8; 3]);
        let m = load_asset(&p, 1000.0).unwrap();
        assert_eq!(m.mesh.positions_mm[1].x, 1500.0);
        assert!(
            load_asset(&p, 0.0)
                .unwrap_err()
                .to_string()
                .contains("cm.obj")
        );
        // Emission from Ke, and a glTF primitive without material gets the glTF default.
        write(
            &dir.path().join("e.mtl"),
            "newmtl glow\nKd 0.5 0.25 0.125\nKe 2 3 4\n",
        );
        let p = dir.path().join("e.obj");
        write(
            &p,
            "mtllib e.mtl\nusemtl glow\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n",
        );
        let e = load_asset(&p, 1.0).unwrap();
        assert_eq!(e.mesh.triangles.len(), 2);
        assert_eq!(e.materials[0].emissive, [2.0, 3.0, 4.0]);
        assert_eq!(e.materials[0].base_color, [0.5, 0.25, 0.125]);
        let g = load_asset(&nested_gltf(dir.path(), "n.gltf", json!({})), 1.0).unwrap();
        let d = &g.materials[0];
        assert_eq!(
            (d.model, d.base_color, d.metallic, d.roughness),
            (SurfaceModel::MetallicRoughness, [1.0; 3], 1.0, 1.0)
        );
    }

    fn err(path: &Path) -> String {
        let e = load_asset(path, 1.0).unwrap_err().to_string();
        assert!(!e.contains('\n'), "{e}");
        e
    }

    /// UTF-8 lines pass unchanged, other lines are Latin-1 (0xE9 → 'é', not U+FFFD as a lossy
    /// reading gives), line by line, through the reader the OBJ parser gets.
    #[cfg(unix)]
    #[test]
    fn text_decodes_as_utf8_or_latin1() {
        use std::io::BufRead;
        use std::os::unix::ffi::OsStrExt;
        assert_eq!(decode_text("tête".as_bytes()), "tête");
        assert_eq!(decode_text(b"t\xe9te"), "téte");
        assert_ne!(String::from_utf8_lossy(b"t\xe9te"), "téte");
        let r = Utf8Lines {
            inner: &b"usemtl \xe9\nusemtl \xc3\xa9\n"[..],
            line: Vec::new(),
            pos: 0,
        };
        let lines: Vec<String> = r.lines().map(Result::unwrap).collect();
        assert_eq!(lines, ["usemtl é", "usemtl é"]);
        assert_eq!(
            latin1_path("é"),
            Some(PathBuf::from(std::ffi::OsStr::from_bytes(b"\xe9")))
        );
        assert_eq!(latin1_path("e"), None);
        assert_eq!(latin1_path("頭"), None);
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

    #[test]
    fn loads_the_shipped_face_mesh() {
        let path =
            stscam_base::repo_dir().join("scenes/assets/canonical_face_model.obj");
        if !path.is_file() {
            println!("skipped: {} is absent", path.display());
            return;
        }
        // The file names a material library that is not shipped.
        let strict = load_asset(&path, 10.0).unwrap_err().to_string();
        assert!(strict.contains("canonical_face_model.mtl"), "{strict}");
        let opts = LoadOptions {
            obj_unit_mm: 10.0,
            allow_missing_mtl: true,
        };
        let a = load_asset_with(&path, &opts).unwrap();
        assert_eq!(a.mesh.triangles.len(), 898);
        assert_eq!(a.mesh.uvs.len(), a.mesh.positions_mm.len());
        let (lo, hi) = a.mesh.positions_mm.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let size = hi - lo;
        assert!((150.0..=250.0).contains(&size.y), "height {size}");
        assert!((140.0..=170.0).contains(&size.x), "width {size}");
        // Faces toward +z: most vertex normals point forward.
        let forward = a.mesh.normals.iter().filter(|n| n.z > 0.0).count();
        assert!(forward * 2 > a.mesh.normals.len());
        assert!(
            a.mesh
                .normals
                .iter()
                .all(|n| (n.length() - 1.0).abs() < 1e-9)
        );
    }
}
