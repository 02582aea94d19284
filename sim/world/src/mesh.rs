//! Triangle meshes of the user-side scene and the materials their files carry.
//!
//! Model: a mesh is an indexed triangle list in world millimetres (f64), with one unit normal
//! and (optionally) one texture coordinate per vertex and one material index per triangle.
//! Texture coordinates follow glTF: (0, 0) is the top-left of the image, v grows downward
//! (OBJ's v is flipped on load). Materials are the glTF 2.0 metallic-roughness parameters
//! (Khronos glTF 2.0 specification §3.9), which also express OBJ's `Kd`/`map_Kd`/`Ke`.
//!
//! Assumptions: triangles only (polygons are triangulated on load); normals missing in a file
//! are computed as area-weighted averages of the faces around each vertex.

use std::sync::Arc;

use glam::{DAffine3, DVec2, DVec3, DVec4};

use super::coverage::AlphaMode;
use super::texture::Texture;

/// How a material scatters light.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SurfaceModel {
    /// Lambertian diffuse (OBJ `Kd`, built-in shapes unless told otherwise).
    Diffuse,
    /// glTF metallic-roughness: Lambertian base under a GGX dielectric coat, or a GGX metal.
    MetallicRoughness,
}

/// A material as an asset file (or a built-in shape) describes it.
#[derive(Clone, Debug)]
pub struct AssetMaterial {
    /// Name in the file (for messages and the JSON sidecar).
    pub name: String,
    /// Scattering model.
    pub model: SurfaceModel,
    /// Linear RGB base colour factor (multiplies the texture).
    pub base_color: [f64; 3],
    /// Base colour texture (linear RGB after decoding), if any.
    pub base_color_texture: Option<Arc<Texture>>,
    /// Linear RGB emission factor (multiplies the texture).
    pub emissive: [f64; 3],
    /// Emission texture (linear RGB), if any.
    pub emissive_texture: Option<Arc<Texture>>,
    /// `KHR_materials_emissive_strength` (1 if absent).
    pub emissive_strength: f64,
    /// GGX roughness (perceptual, α = roughness²).
    pub roughness: f64,
    /// Metalness in [0, 1].
    pub metallic: f64,
    /// glTF `alphaMode` (opaque for OBJ and built-in shapes).
    pub alpha_mode: AlphaMode,
    /// Base colour factor alpha (glTF `baseColorFactor[3]`), in [0, 1].
    pub alpha: f64,
    /// Seen from both sides (glTF `doubleSided`; always for OBJ and built-in shapes).
    pub double_sided: bool,
    /// Tangent-space normal map (linear RGB), if any (glTF `normalTexture`).
    pub normal_texture: Option<Arc<Texture>>,
    /// `normalTexture.scale` (finite).
    pub normal_scale: f64,
}

impl Default for AssetMaterial {
    fn default() -> Self {
        AssetMaterial {
            name: "default".into(),
            model: SurfaceModel::Diffuse,
            base_color: [0.8, 0.8, 0.8],
            base_color_texture: None,
            emissive: [0.0; 3],
            emissive_texture: None,
            emissive_strength: 1.0,
            roughness: 1.0,
            metallic: 0.0,
            alpha_mode: AlphaMode::Opaque,
            alpha: 1.0,
            double_sided: true,
            normal_texture: None,
            normal_scale: 1.0,
        }
    }
}

/// An indexed triangle mesh in millimetres.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Vertex positions, mm.
    pub positions_mm: Vec<DVec3>,
    /// Unit vertex normals (same length as `positions_mm`).
    pub normals: Vec<DVec3>,
    /// Texture coordinates (same length as `positions_mm`, or empty).
    pub uvs: Vec<DVec2>,
    /// Vertex indices of each triangle (counter-clockwise seen from the front).
    pub triangles: Vec<[u32; 3]>,
    /// Material index of each triangle, into the asset's `materials`.
    pub material_ids: Vec<u32>,
    /// Linear RGB vertex colours multiplying the base colour (glTF `COLOR_0`, OBJ
    /// `v x y z r g b`): same length as `positions_mm`, or empty (white).
    pub colors: Vec<DVec3>,
    /// Vertex alpha (glTF `COLOR_0`'s fourth component) multiplying the material's alpha:
    /// same length as `positions_mm`, or empty (1).
    pub alphas: Vec<f64>,
    /// Vertex tangents (xyz, handedness w = ±1; glTF `TANGENT`): same length as
    /// `positions_mm`, or empty (tangents from the texture coordinates, `normal_map`).
    pub tangents: Vec<DVec4>,
}

/// Appends the per-vertex attribute `src` of an appended mesh to `dst` (for `base` vertices
/// before and `total` after): nothing if neither has it, else the vertices without it get
/// `fill`.
fn append_attribute<T: Copy>(dst: &mut Vec<T>, src: &[T], base: usize, total: usize, fill: T) {
    if dst.is_empty() && src.is_empty() {
        return;
    }
    dst.resize(base, fill);
    if src.is_empty() {
        dst.resize(total, fill);
    } else {
        dst.extend_from_slice(src);
    }
}

/// A loaded mesh file or built-in shape.
#[derive(Clone, Debug, Default)]
pub struct Asset {
    /// All triangles of the file, with the file's node transforms applied (in mm).
    pub mesh: Mesh,
    /// Materials referenced by `mesh.material_ids`.
    pub materials: Vec<AssetMaterial>,
}

impl Mesh {
    /// Appends `other` (its material ids shifted by `material_offset`).
    pub fn append(&mut self, other: &Mesh, material_offset: u32) {
        let base = self.positions_mm.len() as u32;
        let had_uv = !self.uvs.is_empty() || self.positions_mm.is_empty();
        self.positions_mm.extend_from_slice(&other.positions_mm);
        self.normals.extend_from_slice(&other.normals);
        if had_uv && !other.uvs.is_empty() {
            self.uvs.extend_from_slice(&other.uvs);
        } else if !self.uvs.is_empty() || !other.uvs.is_empty() {
            // Mixed: give the vertices without coordinates (0, 0).
            self.uvs.resize(base as usize, DVec2::ZERO);
            if other.uvs.is_empty() {
                self.uvs.resize(self.positions_mm.len(), DVec2::ZERO);
            } else {
                self.uvs.extend_from_slice(&other.uvs);
            }
        }
        // Vertices without colours are white (neutral), without alpha opaque, without tangents
        // zero (computed from the UVs when shaded).
        let total = self.positions_mm.len();
        append_attribute(
            &mut self.colors,
            &other.colors,
            base as usize,
            total,
            DVec3::ONE,
        );
        append_attribute(&mut self.alphas, &other.alphas, base as usize, total, 1.0);
        append_attribute(
            &mut self.tangents,
            &other.tangents,
            base as usize,
            total,
            DVec4::ZERO,
        );
        self.triangles
            .extend(other.triangles.iter().map(|t| t.map(|i| i + base)));
        self.material_ids
            .extend(other.material_ids.iter().map(|m| m + material_offset));
    }

    /// Applies an affine transform to positions and (by the inverse transpose) normals.
    pub fn transform(&mut self, m: &DAffine3) {
        let nm = m.matrix3.inverse().transpose();
        let flip = m.matrix3.determinant() < 0.0;
        for p in &mut self.positions_mm {
            *p = m.transform_point3(*p);
        }
        for n in &mut self.normals {
            *n = (nm * *n).normalize_or_zero();
        }
        self.transform_tangents(m);
        if flip {
            // A mirroring transform reverses the winding; keep front faces counter-clockwise.
            for t in &mut self.triangles {
                t.swap(1, 2);
            }
        }
    }

    /// Applies `m` to the tangents: surface directions follow the matrix itself; a mirroring
    /// `m` flips the handedness.
    pub fn transform_tangents(&mut self, m: &DAffine3) {
        let flip = m.matrix3.determinant() < 0.0;
        for t in &mut self.tangents {
            let d = (m.matrix3 * t.truncate()).normalize_or_zero();
            *t = d.extend(if flip { -t.w } else { t.w });
        }
    }

    /// Computes area-weighted vertex normals (replacing any there are).
    pub fn compute_normals(&mut self) {
        let mut acc = vec![DVec3::ZERO; self.positions_mm.len()];
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.positions_mm[i as usize]);
            let n = (b - a).cross(c - a); // length = twice the area
            for &i in t {
                acc[i as usize] += n;
            }
        }
        self.normals = acc.into_iter().map(DVec3::normalize_or_zero).collect();
    }

    /// Index of the first non-finite position, if any.
    pub fn first_nonfinite_vertex(&self) -> Option<usize> {
        self.positions_mm.iter().position(|p| !p.is_finite())
    }

    /// Index of the first vertex with a coordinate outside ±[`crate::limits::MAX_COORD_MM`]
    /// (or not finite), if any.
    pub fn first_vertex_out_of_range(&self) -> Option<usize> {
        let r = crate::limits::MAX_COORD_MM;
        self.positions_mm
            .iter()
            .position(|p| !(p.x.abs() <= r && p.y.abs() <= r && p.z.abs() <= r))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normals_transform_and_append() {
        let mut m = Mesh {
            positions_mm: vec![DVec3::ZERO, DVec3::X, DVec3::Y],
            triangles: vec![[0, 1, 2]],
            material_ids: vec![0],
            ..Default::default()
        };
        m.compute_normals();
        assert_eq!(m.normals, vec![DVec3::Z; 3]);
        // Non-uniform scale: normals follow the inverse transpose and stay unit.
        let mut s = m.clone();
        s.transform(&DAffine3::from_scale(DVec3::new(2.0, 1.0, 1.0)));
        assert_eq!(s.positions_mm[1], DVec3::new(2.0, 0.0, 0.0));
        assert!((s.normals[0] - DVec3::Z).length() < 1e-15);
        // A mirror keeps front faces front: the recomputed normal still points along +z.
        let mut r = m.clone();
        r.transform(&DAffine3::from_scale(DVec3::new(-1.0, 1.0, 1.0)));
        let mut rr = r.clone();
        rr.compute_normals();
        assert!((rr.normals[0] - DVec3::Z).length() < 1e-15);
        let mut a = m.clone();
        a.append(&m, 3);
        assert_eq!(a.triangles[1], [3, 4, 5]);
        assert_eq!(a.material_ids, vec![0, 3]);
        assert!(a.colors.is_empty());
        // Colours on one part only: the other part's vertices are white.
        let mut c = m.clone();
        c.colors = vec![DVec3::X; 3];
        let mut ac = m.clone();
        ac.append(&c, 0);
        assert_eq!(ac.colors, [vec![DVec3::ONE; 3], vec![DVec3::X; 3]].concat());
    }
}
