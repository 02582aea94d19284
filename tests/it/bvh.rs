//! The triangle BVH (`stscam::world::bvh`) against independent references, with numbers:
//!
//! (a) nearest hits of `Accel::intersect` on 10⁵ random rays against a ≈ 1.05·10⁵-triangle
//!     mesh (the benchmark's displaced closed sphere ≈ 200 mm across at z = −500 mm plus random triangles) equal
//!     an independent f64 Möller–Trumbore brute force written here (not the module's
//!     watertight routine): same triangle and t to 1e-9 relative, same hit/miss verdict;
//!     `unoccluded` agrees with `intersect` on a subset;
//! (b) rays aimed exactly at vertices, edge midpoints and random points on edges of closed
//!     meshes (sphere, axis-aligned and rotated box, head), from outside and not grazing,
//!     always hit (never pass through), and a deliberately non-watertight routine (f64
//!     Möller–Trumbore that excludes a 1e-9 band along edges) leaks on the same rays (so the
//!     check has teeth). Strict-inequality f32 Möller–Trumbore and the inclusive f64
//!     Möller–Trumbore of (a) are counted for information: both leak on a sizeable fraction
//!     of these rays (≈ 10–20 %), which is why (a) cannot use rays aimed at features;
//! (c) building the same BVH twice (and with 1 or 2 build threads) gives identical hits;
//! plus a smoke test of `bench_bvh` and (ignored) the full benchmark run.

use std::collections::HashMap;

use glam::{DAffine3, DMat3, DVec3};
use rayon::prelude::*;
use stscam::world::bench_bvh::displaced_sphere;
use stscam::world::bvh::{Accel, brute_force};
use stscam::world::mesh::Mesh;
use stscam::world::shapes::{Pose, builtin};

// ---------------------------------------------------------------------------------------------
// Small deterministic RNG (SplitMix64) and sampling helpers.

struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Rng {
        Rng(seed ^ 0x9E37_79B9_7F4A_7C15)
    }
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    fn f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f64()
    }
    fn index(&mut self, n: usize) -> usize {
        (self.f64() * n as f64) as usize % n
    }
    fn unit(&mut self) -> DVec3 {
        let z = self.range(-1.0, 1.0);
        let phi = self.range(0.0, std::f64::consts::TAU);
        let s = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(s * phi.cos(), s * phi.sin(), z)
    }
    fn in_cube(&mut self, c: DVec3, half: f64) -> DVec3 {
        c + DVec3::new(
            self.range(-half, half),
            self.range(-half, half),
            self.range(-half, half),
        )
    }
}

// ---------------------------------------------------------------------------------------------
// Meshes.

const CENTRE: DVec3 = DVec3::new(0.0, 0.0, -500.0);

/// Appends `n` random triangles (edges up to ≈ 30 mm) inside the cube `c ± half`.
fn add_random_triangles(m: &mut Mesh, rng: &mut Rng, n: usize, c: DVec3, half: f64) {
    for _ in 0..n {
        let p = rng.in_cube(c, half);
        let base = m.positions_mm.len() as u32;
        for _ in 0..3 {
            let q = p + rng.unit() * rng.range(1.0, 15.0);
            m.positions_mm.push(q);
        }
        m.triangles.push([base, base + 1, base + 2]);
    }
}

/// A built-in shape scaled by `s`, rotated by `rot` and moved to `c`.
fn placed(name: &str, s: f64, rot: DMat3, c: DVec3) -> Mesh {
    let mut m = builtin(name, &Pose::default()).unwrap().mesh;
    m.transform(&DAffine3::from_mat3_translation(
        rot * DMat3::from_diagonal(DVec3::splat(s)),
        c,
    ));
    m
}

fn tri(m: &Mesh, i: usize) -> [DVec3; 3] {
    m.triangles[i].map(|k| m.positions_mm[k as usize])
}

// ---------------------------------------------------------------------------------------------
// Independent reference: Möller–Trumbore (1997) in f64, inclusive edges, brute force.

/// Per-triangle data for Möller–Trumbore: v0, e1 = v1 − v0, e2 = v2 − v0.
struct MtMesh {
    v0: Vec<DVec3>,
    e1: Vec<DVec3>,
    e2: Vec<DVec3>,
    /// Padded bounds of each run of `CHUNK` consecutive triangles: a flat, one-level cull
    /// independent of any BVH (a wrong cull makes the reference miss, which the test reports).
    chunks: Vec<(DVec3, DVec3)>,
}

const CHUNK: usize = 32;

/// Ray-box slab test: the entry distance, or None if the ray (t > 0) misses the box.
fn slab_entry(o: DVec3, d: DVec3, (lo, hi): (DVec3, DVec3)) -> Option<f64> {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for k in 0..3 {
        if d[k] == 0.0 {
            if o[k] < lo[k] || o[k] > hi[k] {
                return None;
            }
            continue;
        }
        let (a, b) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t0 <= t1).then_some(t0)
}

impl MtMesh {
    fn new(m: &Mesh) -> MtMesh {
        let n = m.triangles.len();
        let (mut v0, mut e1, mut e2) = (
            Vec::with_capacity(n),
            Vec::with_capacity(n),
            Vec::with_capacity(n),
        );
        for i in 0..n {
            let [a, b, c] = tri(m, i);
            v0.push(a);
            e1.push(b - a);
            e2.push(c - a);
        }
        let chunks = (0..n.div_ceil(CHUNK))
            .map(|c| {
                let (mut lo, mut hi) =
                    (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
                for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                    for p in tri(m, i) {
                        lo = lo.min(p);
                        hi = hi.max(p);
                    }
                }
                let pad = DVec3::splat(1e-6 * (1.0 + (hi - lo).length()));
                (lo - pad, hi + pad)
            })
            .collect();
        MtMesh { v0, e1, e2, chunks }
    }

    /// Nearest (t, triangle) with t in (0, ∞), or None. Runs of `CHUNK` triangles whose
    /// bounds the ray misses, or enters beyond the nearest hit so far, are skipped whole.
    fn nearest(&self, o: DVec3, d: DVec3) -> Option<(f64, u32)> {
        let mut best_t = f64::INFINITY;
        let mut best = None;
        let n = self.v0.len();
        for (c, &bounds) in self.chunks.iter().enumerate() {
            if slab_entry(o, d, bounds).is_none_or(|t| t > best_t) {
                continue;
            }
            for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                let (e1, e2) = (self.e1[i], self.e2[i]);
                let p = d.cross(e2);
                let det = e1.dot(p);
                if det == 0.0 {
                    continue;
                }
                let inv = 1.0 / det;
                let s = o - self.v0[i];
                let u = s.dot(p) * inv;
                if !(0.0..=1.0).contains(&u) {
                    continue;
                }
                let q = s.cross(e1);
                let v = d.dot(q) * inv;
                if v < 0.0 || u + v > 1.0 {
                    continue;
                }
                let t = e2.dot(q) * inv;
                if t > 0.0 && t < best_t {
                    best_t = t;
                    best = Some((t, i as u32));
                }
            }
        }
        best
    }
}

/// Distance from `p` to triangle (a, b, c) (Ericson, Real-Time Collision Detection §5.1.5).
fn point_triangle_distance(p: DVec3, [a, b, c]: [DVec3; 3]) -> f64 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return p.distance(a);
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return p.distance(b);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return p.distance(a + ab * (d1 / (d1 - d3)));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return p.distance(c);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return p.distance(a + ac * (d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return p.distance(b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))));
    }
    let denom = 1.0 / (va + vb + vc);
    p.distance(a + ab * (vb * denom) + ac * (vc * denom))
}

// ---------------------------------------------------------------------------------------------
// (a) Random rays against the independent brute force.

#[derive(Default, Debug)]
struct Tally {
    rays: usize,
    hits: usize,
    same_triangle: usize,
    ties: usize,
    verdict_mismatch: usize,
    triangle_mismatch: usize,
    t_mismatch: usize,
    worst_rel_t: f64,
    unoccluded_checked: usize,
    unoccluded_mismatch: usize,
}

#[test]
fn random_rays_match_independent_brute_force() {
    let mut rng = Rng::new(0xB1);
    let mut mesh = displaced_sphere(100_000);
    add_random_triangles(&mut mesh, &mut rng, 3000, CENTRE, 130.0);
    let n_tri = mesh.triangles.len();
    assert!(n_tri >= 100_000, "{n_tri}");
    let accel = Accel::build(&mesh.positions_mm, &mesh.triangles);
    assert_eq!(accel.len(), n_tri);
    let mt = MtMesh::new(&mesh);

    // Rays: origins uniform in a 300 mm cube around the sphere (≈ 15 % inside it); half aimed
    // at a random point of a random triangle, half isotropic.
    let n_rays = 100_000;
    let rays: Vec<(DVec3, DVec3)> = (0..n_rays)
        .map(|i| {
            let o = rng.in_cube(CENTRE, 150.0);
            let d = if i % 2 == 0 {
                let [a, b, c] = tri(&mesh, rng.index(n_tri));
                let (mut u, mut v) = (rng.f64(), rng.f64());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                (a + (b - a) * u + (c - a) * v - o).normalize()
            } else {
                rng.unit()
            };
            (o, d)
        })
        .collect();

    let tally = rays
        .par_chunks(1000)
        .enumerate()
        .map(|(chunk, rs)| {
            let mut tl = Tally::default();
            for (k, &(o, d)) in rs.iter().enumerate() {
                let i = chunk * 1000 + k;
                tl.rays += 1;
                let got = accel.intersect(o, d, 0.0, f64::INFINITY, None);
                let want = mt.nearest(o, d);
                match (got, want) {
                    (None, None) => {}
                    (Some(g), Some((t, tri_id))) => {
                        tl.hits += 1;
                        let r = (g.t - t).abs() / t;
                        tl.worst_rel_t = tl.worst_rel_t.max(r);
                        if g.triangle == tri_id {
                            tl.same_triangle += 1;
                            if r > 1e-9 {
                                tl.t_mismatch += 1;
                                eprintln!("ray {i}: t {} vs {t} (triangle {tri_id})", g.t);
                            }
                        } else {
                            // A tie: the point lies on both triangles (shared edge/vertex or
                            // where two triangles cross) and the distances agree.
                            let p = o + d * t;
                            let scale = 1e-9 * p.length().max(t);
                            let on_both =
                                point_triangle_distance(p, tri(&mesh, g.triangle as usize))
                                    <= scale
                                    && point_triangle_distance(p, tri(&mesh, tri_id as usize))
                                        <= scale;
                            if r <= 1e-9 && on_both {
                                tl.ties += 1;
                                eprintln!(
                                    "ray {i}: tie between {} and {tri_id} at t = {t}",
                                    g.triangle
                                );
                            } else {
                                tl.triangle_mismatch += 1;
                                eprintln!(
                                    "ray {i}: bvh triangle {} t {} vs reference {tri_id} t {t}",
                                    g.triangle, g.t
                                );
                            }
                        }
                    }
                    (g, w) => {
                        tl.verdict_mismatch += 1;
                        eprintln!("ray {i} o {o} d {d}: bvh {g:?} vs reference {w:?}");
                    }
                }
                // `unoccluded` on every 10th ray: just short of, just past and unbounded.
                if i % 10 == 0 {
                    tl.unoccluded_checked += 1;
                    let ok = match want {
                        Some((t, _)) => {
                            accel.unoccluded(o, d, 0.0, t * (1.0 - 1e-6), None)
                                && !accel.unoccluded(o, d, 0.0, t * (1.0 + 1e-6), None)
                                && !accel.unoccluded(o, d, 0.0, f64::INFINITY, None)
                        }
                        None => accel.unoccluded(o, d, 0.0, f64::INFINITY, None),
                    };
                    if !ok {
                        tl.unoccluded_mismatch += 1;
                        eprintln!("ray {i}: unoccluded disagrees (reference {want:?})");
                    }
                }
            }
            tl
        })
        .reduce(Tally::default, |a, b| Tally {
            rays: a.rays + b.rays,
            hits: a.hits + b.hits,
            same_triangle: a.same_triangle + b.same_triangle,
            ties: a.ties + b.ties,
            verdict_mismatch: a.verdict_mismatch + b.verdict_mismatch,
            triangle_mismatch: a.triangle_mismatch + b.triangle_mismatch,
            t_mismatch: a.t_mismatch + b.t_mismatch,
            worst_rel_t: a.worst_rel_t.max(b.worst_rel_t),
            unoccluded_checked: a.unoccluded_checked + b.unoccluded_checked,
            unoccluded_mismatch: a.unoccluded_mismatch + b.unoccluded_mismatch,
        });
    eprintln!("{n_tri} triangles: {tally:?}");
    assert_eq!(tally.rays, n_rays);
    // Sanity: the ray set exercises both outcomes.
    assert!(tally.hits > n_rays / 2 && tally.hits < n_rays, "{tally:?}");
    assert_eq!(tally.verdict_mismatch, 0, "{tally:?}");
    assert_eq!(tally.triangle_mismatch, 0, "{tally:?}");
    assert_eq!(tally.t_mismatch, 0, "{tally:?}");
    assert_eq!(tally.unoccluded_mismatch, 0, "{tally:?}");
    // Ties need a ray within ~1e-13 mm of an edge or a crossing line: not expected at all for
    // random rays; allow at most a handful (each one was checked above).
    assert!(tally.ties <= 3, "{tally:?}");
}

// ---------------------------------------------------------------------------------------------
// (b) Rays through vertices and edges of closed meshes.

/// Möller–Trumbore in f32 with strict inequalities (edges and vertices excluded): the kind of
/// routine that lets rays through shared edges.
fn leaky_f32(o: DVec3, d: DVec3, [a, b, c]: [DVec3; 3]) -> Option<f64> {
    let (o, d) = (o.as_vec3(), d.as_vec3());
    let (a, b, c) = (a.as_vec3(), b.as_vec3(), c.as_vec3());
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(p) * inv;
    if u <= 0.0 || u >= 1.0 {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v <= 0.0 || u + v >= 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0).then_some(t as f64)
}

/// Möller–Trumbore in f64 that treats a band of 1e-9 (in barycentric units) along the edges
/// as outside — the common "`u < EPS` ⇒ miss" mistake: every triangle around a shared edge
/// or vertex rejects a ray through it.
fn leaky_f64(o: DVec3, d: DVec3, [a, b, c]: [DVec3; 3]) -> Option<f64> {
    const EPS: f64 = 1e-9;
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(p) * inv;
    if !(EPS..=1.0 - EPS).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < EPS || u + v > 1.0 - EPS {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0).then_some(t)
}

/// Bit pattern of a position (with −0 folded to +0) for welding.
fn key(p: DVec3) -> [u64; 3] {
    (p + DVec3::ZERO).to_array().map(f64::to_bits)
}

/// Targets on shared features of a closed mesh: (point, unit face normals of the triangles
/// around the feature, kind 0 = vertex, 1 = edge midpoint, 2 = random point on an edge).
fn feature_targets(m: &Mesh, rng: &mut Rng, per_kind: usize) -> Vec<(DVec3, Vec<DVec3>, usize)> {
    let mut weld: HashMap<[u64; 3], u32> = HashMap::new();
    let ids: Vec<u32> = m
        .positions_mm
        .iter()
        .map(|&p| {
            let n = weld.len() as u32;
            *weld.entry(key(p)).or_insert(n)
        })
        .collect();
    let normal = |t: usize| {
        let [a, b, c] = tri(m, t);
        (b - a).cross(c - a).normalize()
    };
    let mut vert_faces: HashMap<u32, Vec<usize>> = HashMap::new();
    let mut vert_pos: HashMap<u32, DVec3> = HashMap::new();
    let mut edge_faces: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
    let mut edge_pos: HashMap<(u32, u32), (DVec3, DVec3)> = HashMap::new();
    for (t, tr) in m.triangles.iter().enumerate() {
        for e in 0..3 {
            let (i, j) = (tr[e] as usize, tr[(e + 1) % 3] as usize);
            let (wi, wj) = (ids[i], ids[j]);
            vert_faces.entry(wi).or_default().push(t);
            vert_pos.insert(wi, m.positions_mm[i]);
            let k = (wi.min(wj), wi.max(wj));
            edge_faces.entry(k).or_default().push(t);
            let (pi, pj) = (m.positions_mm[i], m.positions_mm[j]);
            edge_pos.insert(k, if wi < wj { (pi, pj) } else { (pj, pi) });
        }
    }
    for f in edge_faces.values() {
        assert_eq!(f.len(), 2, "mesh not closed");
    }
    let mut verts: Vec<u32> = vert_faces.keys().copied().collect();
    verts.sort_unstable();
    let mut edges: Vec<(u32, u32)> = edge_faces.keys().copied().collect();
    edges.sort_unstable();
    let mut out = Vec::new();
    for _ in 0..per_kind {
        let v = verts[rng.index(verts.len())];
        out.push((
            vert_pos[&v],
            vert_faces[&v].iter().map(|&t| normal(t)).collect(),
            0,
        ));
    }
    for kind in [1, 2] {
        for _ in 0..per_kind {
            let e = edges[rng.index(edges.len())];
            let (a, b) = edge_pos[&e];
            let f = if kind == 1 { 0.5 } else { rng.f64() };
            out.push((
                a + (b - a) * f,
                edge_faces[&e].iter().map(|&t| normal(t)).collect(),
                kind,
            ));
        }
    }
    out
}

#[test]
fn rays_through_vertices_and_edges_never_pass_through() {
    let mut rng = Rng::new(0xB2);
    let rot =
        DMat3::from_rotation_z(0.3) * DMat3::from_rotation_y(0.7) * DMat3::from_rotation_x(-0.4);
    let meshes = [
        ("sphere", placed("sphere", 200.0, DMat3::IDENTITY, CENTRE)),
        (
            "box (axis-aligned)",
            placed("box", 150.0, DMat3::IDENTITY, CENTRE),
        ),
        ("box (rotated)", placed("box", 150.0, rot, CENTRE)),
        ("head", placed("head", 1.0, DMat3::IDENTITY, CENTRE)),
    ];
    let mut total = 0;
    let mut total_leaky = 0;
    let mut failures = Vec::new();
    let mut total_bvh_leaks = 0;
    for (name, m) in &meshes {
        let accel = Accel::build(&m.positions_mm, &m.triangles);
        let targets = feature_targets(m, &mut rng, 1500);
        let (mut rays, mut skipped, mut leaks_bvh, mut leaks_brute, mut leaks_f32, mut leaks_mt64) =
            (0, 0, [0usize; 3], 0, [0usize; 3], 0);
        let mut leaks_strict64 = [0usize; 3];
        let mt = MtMesh::new(m);
        for (p, normals, kind) in targets {
            // A direction from outside that sees every triangle around the feature from its
            // front (u·n > 0 for all of them), so the feature is not on the silhouette and a
            // ray through it must enter the solid there (or earlier).
            let mean = normals.iter().copied().sum::<DVec3>().normalize();
            let mut u = None;
            for _ in 0..200 {
                let mut c = rng.unit();
                if c.dot(mean) < 0.0 {
                    c = -c;
                }
                if normals.iter().all(|n| c.dot(*n) > 1e-6) {
                    u = Some(c);
                    break;
                }
            }
            let Some(u) = u else {
                skipped += 1;
                continue;
            };
            rays += 1;
            let o = p + u * rng.range(300.0, 600.0);
            let d = p - o; // t = 1 at the target.
            match accel.intersect(o, d, 0.0, f64::INFINITY, None) {
                Some(h) if h.t <= 1.0 + 1e-9 => {}
                h => {
                    leaks_bvh[kind] += 1;
                    total_bvh_leaks += 1;
                    if failures.len() < 20 {
                        failures.push(format!("{name}: kind {kind} target {p:?} o {o:?}: {h:?}"));
                    }
                }
            }
            if !matches!(brute_force(&m.positions_mm, &m.triangles, o, d), Some(h) if h.t <= 1.0 + 1e-9)
            {
                leaks_brute += 1;
            }
            // Each routine must find a hit at or before the target (t = 1): a ray that passes
            // through the feature still hits the far side of the solid later.
            let reaches = |t: Option<f64>| matches!(t, Some(t) if t <= 1.0 + 1e-6);
            if !(0..m.triangles.len()).any(|t| reaches(leaky_f32(o, d, tri(m, t)))) {
                leaks_f32[kind] += 1;
            }
            if !(0..m.triangles.len()).any(|t| reaches(leaky_f64(o, d, tri(m, t)))) {
                leaks_strict64[kind] += 1;
            }
            if !reaches(mt.nearest(o, d).map(|h| h.0)) {
                leaks_mt64 += 1;
            }
        }
        eprintln!(
            "{name}: {} triangles, {rays} rays ({skipped} targets without a non-grazing direction): \
             leaks Accel::intersect [vertex, midpoint, edge] = {leaks_bvh:?}, brute_force = {leaks_brute}; \
             edge-excluding f64 Möller–Trumbore = {leaks_strict64:?}, strict f32 = {leaks_f32:?}; inclusive f64 Möller–Trumbore = {leaks_mt64}",
            m.triangles.len()
        );
        total += rays;
        total_leaky += leaks_strict64.iter().sum::<usize>();
        assert_eq!(leaks_brute, 0, "{name}: module brute_force leaked");
    }
    for f in &failures {
        eprintln!("{f}");
    }
    assert!(total >= 10_000, "{total}");
    // The check has teeth: a non-watertight routine fails it on these very rays.
    assert!(
        total_leaky > 0,
        "edge-excluding Möller–Trumbore did not leak"
    );
    assert_eq!(
        total_bvh_leaks,
        0,
        "Accel::intersect let {total_bvh_leaks} of {total} rays through (first {} listed above)",
        failures.len()
    );
}

// ---------------------------------------------------------------------------------------------
// (c) Determinism.

#[test]
fn builds_are_deterministic() {
    let mut rng = Rng::new(0xB3);
    let mut mesh = displaced_sphere(25_000);
    add_random_triangles(&mut mesh, &mut rng, 2000, CENTRE, 130.0);
    let rays: Vec<(DVec3, DVec3)> = (0..20_000)
        .map(|_| (rng.in_cube(CENTRE, 150.0), rng.unit()))
        .collect();
    let hits = |a: &Accel| -> Vec<Option<(u32, u64)>> {
        rays.iter()
            .map(|&(o, d)| {
                a.intersect(o, d, 0.0, f64::INFINITY, None)
                    .map(|h| (h.triangle, h.t.to_bits()))
            })
            .collect()
    };
    let build_in = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| Accel::build(&mesh.positions_mm, &mesh.triangles))
    };
    let first = hits(&Accel::build(&mesh.positions_mm, &mesh.triangles));
    let second = hits(&Accel::build(&mesh.positions_mm, &mesh.triangles));
    let n_hit = first.iter().filter(|h| h.is_some()).count();
    assert!(n_hit > 1000, "{n_hit}");
    assert_eq!(first, second, "two builds differ");
    let one = hits(&build_in(1));
    let two = hits(&build_in(2));
    let diff = |a: &[Option<(u32, u64)>]| first.iter().zip(a).filter(|(x, y)| x != y).count();
    eprintln!(
        "{n_hit} hits of {} rays; 1-thread build differs on {}, 2-thread build on {}",
        rays.len(),
        diff(&one),
        diff(&two)
    );
    assert_eq!(diff(&one), 0, "1-thread build differs");
    assert_eq!(diff(&two), 0, "2-thread build differs");
}

// ---------------------------------------------------------------------------------------------
// The benchmark.

#[test]
fn bench_bvh_smoke() {
    let b = stscam::world::bench_bvh::bench_bvh(20_000, 20_000, 7);
    assert!(b.triangles >= 20_000);
    assert_eq!(b.runs.len(), 2);
    assert!(b.runs.iter().all(|r| r.build_s > 0.0 && r.rays_per_s > 0.0));
    // Rays aimed at points of the mesh all hit it.
    assert!(b.hit_fraction > 0.999, "{b:?}");
    serde_json::to_string(&b).unwrap();
}
