//! Tangent-space normal maps (glTF 2.0 `normalTexture`, Khronos specification 2.0.1 §3.9.3).
//!
//! Model: a texel's linear RGB c ∈ [0, 1]³ encodes the tangent-space normal
//! m = (2c − 1) with x and y multiplied by `scale` (§5.21 `normalTexture.scale`), then
//! normalised; +x follows the tangent T (the direction of increasing u), +y the bitangent
//! B = w·(N × T), +z the interpolated vertex normal N. The perturbed shading normal is
//! normalize(m.x·T + m.y·B + m.z·N) with T made orthogonal to N (Gram–Schmidt).
//! T and the handedness w come from the glTF `TANGENT` attribute when the primitive has one
//! (interpolated over the triangle); otherwise per triangle from its positions and texture
//! coordinates: T = ∂p/∂u solved from the two edges (Lengyel 2001, "Computing Tangent Space
//! Basis Vectors for an Arbitrary Mesh"; the per-triangle case of MikkTSpace, Mikkelsen 2008),
//! and w = +1 when ∂p/∂v points against N × T (glTF's texture v grows downward, so in the
//! usual mapping image-up is N × T), −1 for a mirrored mapping. The normal texture is read
//! linearly (no sRGB decoding). The result feeds the shading normal, which the folded BSDF
//! ([`super::shading`]) keeps energy-conserving.
//!
//! Assumption: per-triangle tangents make the tangent frame discontinuous across UV seams and
//! between triangles of a curved surface (MikkTSpace averages them per vertex); exporters that
//! care write `TANGENT`.

use glam::{DVec2, DVec3, DVec4};

use super::World;
use super::texture::Texture;

/// The tangent-space normal of a normal-map texel `rgb` with `scale` (unit; +z if degenerate).
#[inline]
pub fn decode(rgb: [f64; 3], scale: f64) -> DVec3 {
    let m = DVec3::new(
        (2.0 * rgb[0] - 1.0) * scale,
        (2.0 * rgb[1] - 1.0) * scale,
        2.0 * rgb[2] - 1.0,
    );
    m.try_normalize().unwrap_or(DVec3::Z)
}

/// Tangent ∂p/∂u and handedness of a triangle with positions `p` and texture coordinates
/// `uv` (module documentation); None where the UV map is degenerate.
pub fn triangle_tangent(p: [DVec3; 3], uv: [DVec2; 3], n: DVec3) -> Option<(DVec3, f64)> {
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let det = d1.x * d2.y - d2.x * d1.y;
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let dpdu = (e1 * d2.y - e2 * d1.y) / det;
    let dpdv = (e2 * d1.x - e1 * d2.x) / det;
    let w = if n.cross(dpdu).dot(dpdv) > 0.0 {
        -1.0
    } else {
        1.0
    };
    dpdu.is_finite().then_some((dpdu, w))
}

/// The shading normal `n` (unit) perturbed by the normal map `tex` × `scale` at `uv`, with
/// tangent `t` (any length, made orthogonal to `n` here) and handedness `w`; `n` unchanged if
/// the tangent is parallel to it.
pub fn perturb(n: DVec3, t: DVec3, w: f64, tex: &Texture, scale: f64, uv: DVec2) -> DVec3 {
    let Some(t) = (t - n * n.dot(t)).try_normalize() else {
        return n;
    };
    let b = n.cross(t) * w;
    let m = decode(tex.lookup(uv), scale);
    (t * m.x + b * m.y + n * m.z).try_normalize().unwrap_or(n)
}

impl World {
    /// The shading normal at a hit on triangle `tri` (barycentrics `bary`, texture coordinate
    /// `uv`), from the interpolated vertex normal `n` and the material's normal map, if any.
    pub fn mapped_normal(&self, tri: u32, bary: [f64; 3], uv: DVec2, n: DVec3) -> DVec3 {
        let mat = &self.materials[self.mesh.material_ids[tri as usize] as usize];
        let Some((tex, scale)) = &mat.normal_map else {
            return n;
        };
        let v = self.mesh.triangles[tri as usize];
        let interpolated = (!self.mesh.tangents.is_empty())
            .then(|| {
                let t: DVec4 = v
                    .iter()
                    .zip(bary)
                    .map(|(i, b)| self.mesh.tangents[*i as usize] * b)
                    .sum();
                (t.truncate(), if t.w < 0.0 { -1.0 } else { 1.0 })
            })
            .filter(|(t, _)| t.length_squared() > 0.0);
        let tangent = interpolated.or_else(|| {
            let p = v.map(|i| self.mesh.positions_mm[i as usize]);
            if self.mesh.uvs.is_empty() {
                return None;
            }
            let uv = v.map(|i| self.mesh.uvs[i as usize]);
            triangle_tangent(p, uv, n)
        });
        match tangent {
            Some((t, w)) => perturb(n, t, w, tex, *scale, uv),
            None => n,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A quad in the xy plane with u along +x and v growing toward −y (the usual glTF mapping:
    /// image up = +y): T = +x, w = +1, so the bitangent N × T = +y is image-up. A map with
    /// u mirrored gives w = −1. The texel (1, 0.5, 0.5) is a normal tilted fully to +T; with
    /// scale 0 the flat normal comes back.
    #[test]
    fn tangent_frame_and_decoding() {
        let p = [DVec3::ZERO, DVec3::X, DVec3::Y];
        let uv = [
            DVec2::new(0.0, 1.0),
            DVec2::new(1.0, 1.0),
            DVec2::new(0.0, 0.0),
        ];
        let (t, w) = triangle_tangent(p, uv, DVec3::Z).unwrap();
        assert!((t - DVec3::X).length() < 1e-12 && w == 1.0, "{t} {w}");
        let mirrored = uv.map(|q| DVec2::new(1.0 - q.x, q.y));
        let (t2, w2) = triangle_tangent(p, mirrored, DVec3::Z).unwrap();
        assert!((t2 + DVec3::X).length() < 1e-12 && w2 == -1.0);
        assert!((decode([1.0, 0.5, 0.5], 1.0) - DVec3::X).length() < 1e-12);
        assert!((decode([1.0, 0.5, 0.5], 0.0) - DVec3::Z).length() < 1e-12);
        // A tilt of 30° toward +T about the y axis.
        let (s, c) = 30f64.to_radians().sin_cos();
        let tex = Texture::from_pixels(
            1,
            1,
            3,
            &[(s + 1.0) as f32 / 2.0, 0.5, (c + 1.0) as f32 / 2.0],
            true,
        );
        let n = perturb(DVec3::Z, DVec3::X, 1.0, &tex, 1.0, DVec2::splat(0.5));
        assert!((n - DVec3::new(s, 0.0, c)).length() < 1e-6, "{n}");
        // Degenerate UVs give no tangent.
        assert!(triangle_tangent(p, [DVec2::ZERO; 3], DVec3::Z).is_none());
    }
}
