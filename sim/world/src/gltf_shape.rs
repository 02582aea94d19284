//! glTF morph targets at their default weights and skins at the scene's default pose
//! (Khronos glTF 2.0 specification 2.0.1, §3.7.2.2 "Morph Targets" and §3.7.3 "Skins").
//!
//! Morph targets: the rendered attribute is base + Σ_k w_k·Δ_k for POSITION and NORMAL, with
//! the weights of the node (`node.weights`) or else of the mesh (`mesh.weights`), 0 if
//! neither is given; TANGENT displacements are not applied (tangents are used only by normal
//! maps and are re-orthogonalised against the morphed normal there).
//!
//! Skins: each vertex is moved by Σ_i w_i·J_{j_i}·p with the joint matrices
//! J_j = G(joint_j)·IBM_j, G the joint node's global transform in the default pose (its
//! local transforms composed up its parents) and IBM_j the inverse bind matrix (identity if
//! the skin has none); normals by Σ_i w_i·(J_{j_i}⁻ᵀ n) (then renormalised), tangents by
//! Σ_i w_i·J_{j_i}·t. The skinned mesh node's own transform is ignored, as the specification
//! requires. Morphing comes first, then skinning. Animations are not played: the default pose
//! (the nodes' `translation`/`rotation`/`scale`/`matrix`) is what is rendered.
//!
//! Refused (one line naming the key): weights that are not finite or whose count differs from
//! the targets'; a target accessor whose count differs from the vertices'; a joint index out
//! of range; vertex weights that are negative, not finite or do not sum to 1 (±0.01, the
//! rounding of normalised integers); an `inverseBindMatrices` count other than the joints';
//! `JOINTS_1`/`WEIGHTS_1` (more than four influences); a non-invertible joint matrix.

use glam::{DMat3, DMat4, DVec3, DVec4};

/// The morph weights of a mesh instanced by `node` (node weights override mesh weights).
pub fn morph_weights(node: &gltf::Node, mesh: &gltf::Mesh) -> Vec<f64> {
    node.weights()
        .or_else(|| mesh.weights())
        .map(|w| w.iter().map(|v| f64::from(*v)).collect())
        .unwrap_or_default()
}

/// Checks the weights of every mesh and node against the morph target counts.
pub fn check_weights(doc: &gltf::Document) -> Result<(), String> {
    let check = |what: String, w: &[f32], targets: usize| {
        if let Some(v) = w.iter().find(|v| !v.is_finite()) {
            return Err(format!("weights ({what}): {v} is not a finite number"));
        }
        if w.len() != targets {
            return Err(format!(
                "weights ({what}): {} weights for {targets} morph targets",
                w.len()
            ));
        }
        Ok(())
    };
    for mesh in doc.meshes() {
        let targets = mesh
            .primitives()
            .map(|p| p.morph_targets().len())
            .max()
            .unwrap_or(0);
        if let Some(w) = mesh.weights() {
            check(format!("mesh {}", mesh.index()), w, targets)?;
        }
        for node in doc
            .nodes()
            .filter(|n| n.mesh().map(|m| m.index()) == Some(mesh.index()))
        {
            if let Some(w) = node.weights() {
                check(format!("node {}", node.index()), w, targets)?;
            }
        }
    }
    Ok(())
}

/// Adds w·Δ (one morph target's displacements) to `values`.
pub fn apply_morph(values: &mut [DVec3], w: f64, delta: &[DVec3]) {
    for (v, dv) in values.iter_mut().zip(delta) {
        *v += *dv * w;
    }
}

/// The global transform of every node in the default pose (local transforms composed up the
/// parents; `local` gives a node's own). Errors on a hierarchy deeper than `max_depth` (a
/// cycle).
pub fn node_globals(
    doc: &gltf::Document,
    local: impl Fn(&gltf::Node) -> DMat4,
    max_depth: usize,
) -> Result<Vec<DMat4>, String> {
    let n = doc.nodes().len();
    let mut parent = vec![None; n];
    for node in doc.nodes() {
        for c in node.children() {
            if let Some(p) = parent.get_mut(c.index()) {
                *p = Some(node.index());
            }
        }
    }
    let locals: Vec<DMat4> = doc.nodes().map(|nd| local(&nd)).collect();
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let (mut g, mut at, mut depth) = (locals[i], parent[i], 0);
        while let Some(p) = at {
            depth += 1;
            if depth > max_depth {
                return Err(format!(
                    "node {i}: node hierarchy deeper than {max_depth} (a cycle?)"
                ));
            }
            g = locals[p] * g;
            at = parent[p];
        }
        out.push(g);
    }
    Ok(out)
}

/// The joint matrices of a skin in the default pose, with their normal matrices.
#[derive(Clone, Debug)]
pub struct SkinPose {
    /// J_j = G(joint_j)·IBM_j.
    pub joints: Vec<DMat4>,
    /// J_j⁻ᵀ (3 × 3).
    pub normals: Vec<DMat3>,
}

impl SkinPose {
    /// The pose of `joints` (global transforms `globals[node]`) with inverse bind matrices
    /// `ibm` (empty: identity; otherwise one per joint).
    pub fn new(joints: &[usize], globals: &[DMat4], ibm: &[DMat4]) -> Result<SkinPose, String> {
        if !ibm.is_empty() && ibm.len() != joints.len() {
            return Err(format!(
                "inverseBindMatrices: {} matrices for {} joints",
                ibm.len(),
                joints.len()
            ));
        }
        let mut pose = SkinPose {
            joints: Vec::with_capacity(joints.len()),
            normals: Vec::with_capacity(joints.len()),
        };
        for (k, &j) in joints.iter().enumerate() {
            let g = globals
                .get(j)
                .ok_or_else(|| format!("joints: node {j} does not exist"))?;
            let m = *g * ibm.get(k).copied().unwrap_or(DMat4::IDENTITY);
            let m3 = DMat3::from_mat4(m);
            let det = m3.determinant();
            if !(det.is_finite() && det != 0.0 && m.is_finite()) {
                return Err(format!(
                    "joints: the joint matrix of joint {k} (node {j}) is not invertible"
                ));
            }
            pose.joints.push(m);
            pose.normals.push(m3.inverse().transpose());
        }
        Ok(pose)
    }

    /// Skins positions, normals and tangents in place with per-vertex joint indices and
    /// weights; an error names the first bad vertex.
    pub fn apply(
        &self,
        positions: &mut [DVec3],
        normals: &mut [DVec3],
        tangents: &mut [DVec4],
        joints: &[[u16; 4]],
        weights: &[[f64; 4]],
    ) -> Result<(), String> {
        if joints.len() != positions.len() || weights.len() != positions.len() {
            return Err(format!(
                "JOINTS_0/WEIGHTS_0: {} and {} elements for {} vertices",
                joints.len(),
                weights.len(),
                positions.len()
            ));
        }
        for (v, (j, w)) in joints.iter().zip(weights).enumerate() {
            let sum: f64 = w.iter().sum();
            if w.iter().any(|x| !(x.is_finite() && *x >= 0.0)) || (sum - 1.0).abs() > 0.01 {
                return Err(format!(
                    "WEIGHTS_0: vertex {v} has weights {w:?}, which do not sum to 1"
                ));
            }
            let (mut p, mut n, mut t) = (DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
            for (ji, wi) in j.iter().zip(w) {
                if *wi == 0.0 {
                    continue;
                }
                let k = usize::from(*ji);
                let (Some(m), Some(nm)) = (self.joints.get(k), self.normals.get(k)) else {
                    return Err(format!(
                        "JOINTS_0: vertex {v} names joint {k}, the skin has {}",
                        self.joints.len()
                    ));
                };
                p += m.transform_point3(positions[v]) * *wi;
                if let Some(nv) = normals.get(v) {
                    n += (*nm * *nv) * *wi;
                }
                if let Some(tv) = tangents.get(v) {
                    t += m.transform_vector3(tv.truncate()) * *wi;
                }
            }
            positions[v] = p;
            if let Some(nv) = normals.get_mut(v) {
                *nv = n.normalize_or_zero();
            }
            if let Some(tv) = tangents.get_mut(v) {
                *tv = t.normalize_or_zero().extend(tv.w);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two joints: the root at the origin, the second 1 up and turned 90° about z; a vertex
    /// at (0, 2, 0) bound to the second joint (bind pose: translation (0, 1, 0)) lands at
    /// (−1, 1, 0); split half and half with the root it lands halfway, at (−0.5, 1.5, 0).
    /// Forgetting the inverse bind matrix (J = G) puts it at (−2, 1, 0): the check fails.
    #[test]
    fn two_joint_skin_by_hand() {
        let g = [
            DMat4::IDENTITY,
            DMat4::from_translation(DVec3::Y) * DMat4::from_rotation_z(std::f64::consts::FRAC_PI_2),
        ];
        let ibm = [DMat4::IDENTITY, DMat4::from_translation(-DVec3::Y)];
        let pose = SkinPose::new(&[0, 1], &g, &ibm).unwrap();
        let mut p = vec![DVec3::new(0.0, 2.0, 0.0); 2];
        let mut n = vec![DVec3::X; 2];
        let w = [[0.0, 1.0, 0.0, 0.0], [0.5, 0.5, 0.0, 0.0]];
        pose.apply(&mut p, &mut n, &mut [], &[[0, 1, 0, 0]; 2], &w)
            .unwrap();
        assert!(
            (p[0] - DVec3::new(-1.0, 1.0, 0.0)).length() < 1e-12,
            "{}",
            p[0]
        );
        assert!(
            (p[1] - DVec3::new(-0.5, 1.5, 0.0)).length() < 1e-12,
            "{}",
            p[1]
        );
        assert!((n[0] - DVec3::Y).length() < 1e-12, "{}", n[0]);
        let no_ibm = SkinPose::new(&[0, 1], &g, &[]).unwrap();
        let mut q = vec![DVec3::new(0.0, 2.0, 0.0)];
        no_ibm
            .apply(&mut q, &mut [], &mut [], &[[0, 1, 0, 0]], &[w[0]])
            .unwrap();
        assert!((q[0] - p[0]).length() > 0.5);
        // Hostile input: a joint out of range, weights not summing to 1, too few matrices.
        let mut r = vec![DVec3::ZERO];
        assert!(
            pose.apply(
                &mut r,
                &mut [],
                &mut [],
                &[[5, 0, 0, 0]],
                &[[1.0, 0.0, 0.0, 0.0]]
            )
            .unwrap_err()
            .starts_with("JOINTS_0")
        );
        assert!(
            pose.apply(&mut r, &mut [], &mut [], &[[0; 4]], &[[0.6, 0.0, 0.0, 0.0]])
                .unwrap_err()
                .starts_with("WEIGHTS_0")
        );
        assert!(
            SkinPose::new(&[0, 1], &g, &ibm[..1])
                .unwrap_err()
                .starts_with("inverseBindMatrices")
        );
    }
}
