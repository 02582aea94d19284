//! OBJ faces and vertex attributes beyond what `tobj` converts itself: polygons are read as
//! polygons and triangulated by ear clipping ([`super::polygon`]; `tobj`'s own triangulation
//! fans them, which fills concave faces), and vertex colours (`v x y z r g b`), which multiply
//! the base colour.

use glam::DVec3;

/// Replaces the polygon list of a mesh read with `triangulate: false` (indices grouped by
/// `face_arities`; empty arities mean triangles only) by a triangle list.
pub fn triangulate_faces(m: &mut tobj::Mesh) {
    if m.face_arities.is_empty() {
        return;
    }
    let pos = |i: u32| {
        let k = 3 * i as usize;
        match m.positions.get(k..k + 3) {
            Some(p) => DVec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])),
            None => DVec3::ZERO,
        }
    };
    let mut out = Vec::with_capacity(m.indices.len() * 3 / 2);
    let mut start = 0usize;
    for &a in &m.face_arities {
        let end = (start + a as usize).min(m.indices.len());
        for t in super::polygon::triangulate(&m.indices[start..end], pos) {
            out.extend_from_slice(&t);
        }
        start = end;
    }
    m.indices = out;
    m.face_arities.clear();
}

/// The vertex colours of a mesh (`v x y z r g b`, read as linear RGB like glTF's `COLOR_0`;
/// negative or non-finite components read as 0), or none if the file has none or they are all
/// white (neutral: the mesh renders exactly as without colours).
pub fn vertex_colours(m: &tobj::Mesh) -> Vec<DVec3> {
    if m.vertex_color.len() != m.positions.len() || m.vertex_color.iter().all(|c| *c == 1.0) {
        return Vec::new();
    }
    let f = |v: f32| {
        let v = f64::from(v);
        if v.is_finite() { v.max(0.0) } else { 0.0 }
    };
    m.vertex_color
        .chunks_exact(3)
        .map(|c| DVec3::new(f(c[0]), f(c[1]), f(c[2])))
        .collect()
}
