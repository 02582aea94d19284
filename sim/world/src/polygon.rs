//! Triangulation of the polygons of OBJ faces by ear clipping (Meisters 1975, "Polygons have
//! ears"; the O(n²) algorithm of Eberly, "Triangulation by Ear Clipping", Geometric Tools
//! 2002): a convex polygon is split into the fan (v0, vk, vk+1), the triangles the OBJ
//! reader produced before; a concave one (an L-shape, a ring given as one face with a
//! keyhole bridge) by repeatedly cutting off an ear, a convex corner whose triangle holds no
//! other vertex of the remaining polygon, so no triangle covers area outside the polygon.
//!
//! Model: the polygon is projected onto the plane of its Newell normal (Newell's method,
//! Sutherland et al. 1974), dropping the normal's dominant axis; the triangles keep the
//! face's winding. Assumptions: the face is planar enough for the projection and its boundary
//! does not cross itself; where no ear is found (a self-intersecting or degenerate face) the
//! rest is fanned, as before.

use glam::{DVec2, DVec3};

/// Triangles (vertex indices, the face's winding) of the polygon `face`, whose vertex
/// positions are `pos(index)`.
pub fn triangulate(face: &[u32], pos: impl Fn(u32) -> DVec3) -> Vec<[u32; 3]> {
    let n = face.len();
    if n < 3 {
        return Vec::new();
    }
    let fan = || {
        (1..n - 1)
            .map(|k| [face[0], face[k], face[k + 1]])
            .collect()
    };
    if n == 3 {
        return fan();
    }
    let p3: Vec<DVec3> = face.iter().map(|&i| pos(i)).collect();
    // Newell normal.
    let mut nrm = DVec3::ZERO;
    for k in 0..n {
        let (a, b) = (p3[k], p3[(k + 1) % n]);
        nrm += DVec3::new(
            (a.y - b.y) * (a.z + b.z),
            (a.z - b.z) * (a.x + b.x),
            (a.x - b.x) * (a.y + b.y),
        );
    }
    let ax = nrm.abs();
    // Project so that the polygon is counter-clockwise in 2-D when its winding is.
    let p: Vec<DVec2> = p3
        .iter()
        .map(|v| {
            if ax.z >= ax.x && ax.z >= ax.y {
                DVec2::new(v.x, v.y * nrm.z.signum())
            } else if ax.x >= ax.y {
                DVec2::new(v.y, v.z * nrm.x.signum())
            } else {
                DVec2::new(v.z, v.x * nrm.y.signum())
            }
        })
        .collect();
    let cross = |o: DVec2, a: DVec2, b: DVec2| (a - o).perp_dot(b - o);
    if (0..n).all(|k| cross(p[k], p[(k + 1) % n], p[(k + 2) % n]) >= 0.0) {
        return fan();
    }
    let scale = p
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs().max_element()))
        .max(f64::MIN_POSITIVE);
    let eps = 1e-12 * scale * scale;
    let mut idx: Vec<usize> = (0..n).collect();
    let mut out = Vec::with_capacity(n - 2);
    while idx.len() > 3 {
        let m = idx.len();
        let ear = (0..m).find(|&k| {
            let (a, b, c) = (idx[(k + m - 1) % m], idx[k], idx[(k + 1) % m]);
            if cross(p[a], p[b], p[c]) <= eps {
                return false;
            }
            idx.iter().all(|&j| {
                let q = p[j];
                if q == p[a] || q == p[b] || q == p[c] {
                    return true;
                }
                // Outside triangle abc (a vertex on its boundary blocks the ear).
                cross(p[a], p[b], q) < -eps
                    || cross(p[b], p[c], q) < -eps
                    || cross(p[c], p[a], q) < -eps
            })
        });
        let Some(k) = ear else {
            // No ear (a degenerate or self-intersecting face): fan the rest.
            for k in 1..idx.len() - 1 {
                out.push([face[idx[0]], face[idx[k]], face[idx[k + 1]]]);
            }
            return out;
        };
        let m = idx.len();
        out.push([
            face[idx[(k + m - 1) % m]],
            face[idx[k]],
            face[idx[(k + 1) % m]],
        ]);
        idx.remove(k);
    }
    out.push([face[idx[0]], face[idx[1]], face[idx[2]]]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(tris: &[[u32; 3]], p: &[DVec3]) -> (f64, f64) {
        let (mut signed, mut abs) = (0.0, 0.0);
        for t in tris {
            let [a, b, c] = t.map(|i| p[i as usize]);
            let z = (b - a).cross(c - a).z / 2.0;
            signed += z;
            abs += z.abs();
        }
        (signed, abs)
    }

    /// An L-shape (area 3 of unit squares) must be covered exactly once: signed and unsigned
    /// triangle areas both 3. The fan from the reflex corner's opposite vertex covers the
    /// notch (the wrong handling fails).
    #[test]
    fn l_shape_is_not_fanned() {
        let p: Vec<DVec3> = [[0., 0.], [2., 0.], [2., 1.], [1., 1.], [1., 2.], [0., 2.]]
            .iter()
            .map(|v| DVec3::new(v[0], v[1], 0.0))
            .collect();
        // Start the face at (2, 1) so that the fan from vertex 0 covers the missing square.
        let face = [2u32, 3, 4, 5, 0, 1];
        let t = triangulate(&face, |i| p[i as usize]);
        assert_eq!(t.len(), 4);
        let (s, a) = area(&t, &p);
        assert!(
            (s - 3.0).abs() < 1e-12 && (a - 3.0).abs() < 1e-12,
            "{s} {a}"
        );
        let fan: Vec<[u32; 3]> = (1..5).map(|k| [face[0], face[k], face[k + 1]]).collect();
        let (_, af) = area(&fan, &p);
        assert!((af - 3.0).abs() > 0.4, "the fan covers {af}");
        // Convex faces keep the fan the OBJ reader produced.
        let q = [0u32, 1, 2, 5];
        let pq: Vec<DVec3> = vec![p[0], p[1], DVec3::new(2., 2., 0.), p[3], p[4], p[5]];
        assert_eq!(
            triangulate(&q, |i| pq[i as usize]),
            vec![[0, 1, 2], [0, 2, 5]]
        );
    }
}
