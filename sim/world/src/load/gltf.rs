//! glTF 2.0 and GLB loading: the buffers, the scene's node tree with its transforms, skins
//! and morph targets, the triangle primitives, and the materials with their textures.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DAffine3, DMat4, DQuat, DVec2, DVec3, DVec4};

use super::uri::{UriData, resolve_uri};
use super::{
    LoadError, MAX_FILE_BYTES, MAX_NODE_DEPTH, MAX_NODE_VISITS, MAX_TRIANGLES, MAX_VERTICES,
    check_regular_file, file_name, texture_from_encoded_bytes,
};
use crate::coverage::AlphaMode;
use crate::io::IoError;
use crate::io::image_load::decode_image_bytes;
use crate::mesh::{Asset, AssetMaterial, Mesh, SurfaceModel};
use crate::texture::{Texture, Wrap};

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
    normal_plans: crate::gltf_features::NormalPlans,
}

/// Reads a glTF / GLB file: the document checked, its buffers read ([`gltf_buffers`]), then
/// the meshes of the scene's node tree ([`gltf_scene_mesh`]) with the skins' default poses.
pub(super) fn load_gltf(path: &Path) -> Result<Asset, LoadError> {
    let bytes = read_file(path)?;
    crate::gltf_features::check_required_extensions(&bytes).map_err(|m| LoadError::new(path, m))?;
    let gltf::Gltf { document, mut blob } = gltf::Gltf::from_slice(&bytes)
        .map_err(|e| LoadError::new(path, format!("not a readable glTF file ({e})")))?;
    let normal_plans = crate::gltf_features::normal_plans(&bytes);
    crate::gltf_features::check_document(&document, &normal_plans)
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
        let globals = crate::gltf_shape::node_globals(&document, local_matrix, MAX_NODE_DEPTH)
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
    skin_poses: &[crate::gltf_shape::SkinPose],
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
            let weights = crate::gltf_shape::morph_weights(&node, &m);
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
) -> Result<crate::gltf_shape::SkinPose, LoadError> {
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
    crate::gltf_shape::SkinPose::new(&joints, globals, &ibm)
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
    skin: Option<&crate::gltf_shape::SkinPose>,
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
    let (colors, alphas) = crate::gltf_features::vertex_colors(&ctx.buffers, prim, plan.n)
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
    uv_plan: crate::gltf_features::UvPlan,
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
    skin: Option<&crate::gltf_shape::SkinPose>,
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
        crate::gltf_features::uv_plan(&prim.material(), &ctx.normal_plans).unwrap_or_default();
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
    skin: Option<&crate::gltf_shape::SkinPose>,
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
                    crate::gltf_shape::apply_morph(values, w, &d);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load::load_asset;
    use crate::load::tests::nested_gltf;
    use serde_json::json;

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
}
