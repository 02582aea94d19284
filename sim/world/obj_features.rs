//! OBJ faces and vertex attributes beyond what `tobj` converts itself: polygons are read as
//! polygons and triangulated by ear clipping ([`super::polygon`]; `tobj`'s own triangulation
//! fans them, which fills concave faces), and vertex colours (`v x y z r g b`), which stscam
//! does not render, are refused in one line unless they are all white (the neutral colour,
//! which changes nothing).

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

/// Refuses vertex colours other than white: the message names the feature first.
pub fn check_vertex_colours(m: &tobj::Mesh) -> Result<(), String> {
    if m.vertex_color.iter().any(|c| *c != 1.0) {
        return Err(
            "vertex colours (v x y z r g b): not supported (bake them into a map_Kd texture)"
                .to_string(),
        );
    }
    Ok(())
}
