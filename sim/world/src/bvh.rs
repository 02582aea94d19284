//! Ray–triangle intersection for the user-side scene: one obvhs compressed wide BVH (CWBVH,
//! built in parallel with PLOC) over every triangle, traversed in f32, with each candidate
//! triangle tested in f64 by the watertight algorithm of Woop, Benthin & Wald (2013,
//! "Watertight Ray/Triangle Intersection", JCGT 2(1)).
//!
//! Why the candidate test is f64 and watertight: the BVH's boxes only cull (they are
//! conservative), so the hit, its distance and its barycentrics come from f64 arithmetic on
//! the original vertices (docs/design.md: f32 only inside the BVH). The shear-and-scale test makes
//! rays through shared edges and vertices of a closed mesh hit at least one of the triangles
//! sharing them (edge functions are evaluated identically for both neighbours and edges are
//! inclusive), so such rays never pass through.
//!
//! Caveat (reference/rust.md A1): obvhs's CWBVH node test clamps t ≥ 1e-4 scene units, i.e.
//! 100 nm in millimetres; hits closer than that to a ray origin are not reported. Rays leaving
//! a surface are offset by more than that anyway.

use std::time::Instant;

use glam::{DVec2, DVec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};

/// Most triangles with one identical bounding box that [`Accel::try_build`] accepts.
pub const MAX_COINCIDENT: usize = 64;

/// The largest group of identical boxes: (its first triangle, its size); None without boxes.
fn largest_coincident_group(boxes: &[Aabb]) -> Option<(u32, usize)> {
    let key = |b: &Aabb| {
        let (lo, hi) = (b.min.to_array(), b.max.to_array());
        [lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]].map(f32::to_bits)
    };
    let mut counts: std::collections::HashMap<[u32; 6], (u32, usize)> =
        std::collections::HashMap::with_capacity(boxes.len());
    for (i, b) in boxes.iter().enumerate() {
        counts.entry(key(b)).or_insert((i as u32, 0)).1 += 1;
    }
    counts
        .into_values()
        .max_by_key(|&(first, n)| (n, std::cmp::Reverse(first)))
}

/// A ray in f64 with the shear constants of the watertight test precomputed.
#[derive(Clone, Copy, Debug)]
pub struct WatertightRay {
    /// Origin, mm.
    pub origin: DVec3,
    /// Direction (need not be unit; t is in units of its length).
    pub dir: DVec3,
    k: [usize; 3],
    shear: DVec3,
}

impl WatertightRay {
    /// Precomputes the permutation and shear of Woop et al. §2.
    pub fn new(origin: DVec3, dir: DVec3) -> WatertightRay {
        let a = dir.abs();
        let kz = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        if dir[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let dz = dir[kz];
        WatertightRay {
            origin,
            dir,
            k: [kx, ky, kz],
            shear: DVec3::new(dir[kx] / dz, dir[ky] / dz, 1.0 / dz),
        }
    }

    /// Intersects triangle (a, b, c): `Some((t, [b0, b1, b2]))` with barycentric weights of
    /// a, b, c, for t in (tmin, tmax); edges and vertices count as inside.
    #[inline]
    pub fn intersect(
        &self,
        a: DVec3,
        b: DVec3,
        c: DVec3,
        tmin: f64,
        tmax: f64,
    ) -> Option<(f64, [f64; 3])> {
        let [kx, ky, kz] = self.k;
        let (sx, sy, sz) = (self.shear.x, self.shear.y, self.shear.z);
        let (a, b, c) = (a - self.origin, b - self.origin, c - self.origin);
        let ax = a[kx] - sx * a[kz];
        let ay = a[ky] - sy * a[kz];
        let bx = b[kx] - sx * b[kz];
        let by = b[ky] - sy * b[kz];
        let cx = c[kx] - sx * c[kz];
        let cy = c[ky] - sy * c[kz];
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let t_scaled = (u * a[kz] + v * b[kz] + w * c[kz]) * sz;
        let t = t_scaled / det;
        if !(t > tmin && t < tmax) {
            return None;
        }
        let inv = 1.0 / det;
        Some((t, [u * inv, v * inv, w * inv]))
    }
}

/// The nearest hit of a ray.
#[derive(Clone, Copy, Debug)]
pub struct TriHit {
    /// Distance along the ray (in units of the direction's length).
    pub t: f64,
    /// Triangle index (into the mesh's triangle list).
    pub triangle: u32,
    /// Barycentric weights of the triangle's three vertices.
    pub bary: [f64; 3],
}

/// A BVH over an indexed triangle list.
pub struct Accel {
    bvh: CwBvh,
    positions: Vec<DVec3>,
    /// Triangles in BVH order (vertex indices).
    tris: Vec<[u32; 3]>,
    /// BVH slot → original triangle index.
    order: Vec<u32>,
    /// Build time in seconds.
    pub build_s: f64,
}

impl std::fmt::Debug for Accel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Accel({} triangles)", self.tris.len())
    }
}

#[inline]
fn to_f32(p: DVec3) -> Vec3A {
    p.as_vec3a()
}

impl Accel {
    /// Builds the BVH (in parallel) over `triangles` of `positions` (mm).
    ///
    /// The boxes are built from the f64 vertices padded by 2⁻²⁰ of the scene's scale (at
    /// least 1 m): obvhs rounds vertices to f32, pads nothing and tests boxes in f32, so an
    /// unpadded flat box (a face of an axis-aligned cube) could be culled for a ray through
    /// its edge although the f64 watertight test hits the triangle. The padding only widens
    /// culling; hits still come from the f64 test.
    pub fn build(positions: &[DVec3], triangles: &[[u32; 3]]) -> Accel {
        let start = Instant::now();
        let boxes = Self::boxes(positions, triangles);
        Self::build_from(positions, triangles, boxes, start)
    }

    /// As [`Accel::build`], but first refuses a triangle list in which more than
    /// [`MAX_COINCIDENT`] triangles have the same (f32, padded) bounding box: the builder
    /// handles identical boxes one merge at a time, so its time grows with the size of the
    /// largest such group times the triangle count, and its tree depth (recursed into while
    /// compressing) with the group's size. The error is (a triangle of the largest group, the
    /// group's size).
    pub fn try_build(positions: &[DVec3], triangles: &[[u32; 3]]) -> Result<Accel, (u32, usize)> {
        let start = Instant::now();
        let boxes = Self::boxes(positions, triangles);
        if let Some(worst) = largest_coincident_group(&boxes)
            && worst.1 > MAX_COINCIDENT
        {
            return Err(worst);
        }
        Ok(Self::build_from(positions, triangles, boxes, start))
    }

    /// The padded f32 box of every triangle (see [`Accel::build`]).
    fn boxes(positions: &[DVec3], triangles: &[[u32; 3]]) -> Vec<Aabb> {
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for p in positions {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        let scale = (lo.abs().max(hi.abs()).max_element() + (hi - lo).max_element()).max(1000.0);
        let pad = scale / 1_048_576.0;
        triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| positions[i as usize]);
                Aabb::new(to_f32(a.min(b).min(c) - pad), to_f32(a.max(b).max(c) + pad))
            })
            .collect()
    }

    fn build_from(
        positions: &[DVec3],
        triangles: &[[u32; 3]],
        boxes: Vec<Aabb>,
        start: Instant,
    ) -> Accel {
        let bvh = obvhs::cwbvh::builder::build_cwbvh(
            &boxes,
            BvhBuildParams::medium_build(),
            &mut std::time::Duration::default(),
        );
        let order = bvh.primitive_indices.clone();
        let tris = order.iter().map(|&i| triangles[i as usize]).collect();
        Accel {
            bvh,
            positions: positions.to_vec(),
            tris,
            order,
            build_s: start.elapsed().as_secs_f64(),
        }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// True if there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    fn f32_ray(o: DVec3, d: DVec3, tmax: f64) -> Ray {
        Ray::new(
            to_f32(o),
            to_f32(d),
            0.0,
            if tmax.is_finite() {
                tmax as f32 * 1.000_01 + 1e-3
            } else {
                f32::INFINITY
            },
        )
    }

    #[inline]
    fn test(
        &self,
        wr: &WatertightRay,
        slot: usize,
        tmin: f64,
        tmax: f64,
    ) -> Option<(f64, [f64; 3])> {
        let t = self.tris[slot];
        wr.intersect(
            self.positions[t[0] as usize],
            self.positions[t[1] as usize],
            self.positions[t[2] as usize],
            tmin,
            tmax,
        )
    }

    /// The hit of the triangle in BVH slot `slot` for t in (tmin, tmax), unless it is `skip`.
    #[inline]
    fn candidate(
        &self,
        wr: &WatertightRay,
        slot: usize,
        tmin: f64,
        tmax: f64,
        skip: Option<u32>,
    ) -> Option<TriHit> {
        let triangle = self.order[slot];
        if skip == Some(triangle) {
            return None;
        }
        let (t, bary) = self.test(wr, slot, tmin, tmax)?;
        Some(TriHit { t, triangle, bary })
    }

    /// Nearest hit with t in (tmin, tmax), skipping triangle `skip` (the one a ray leaves).
    pub fn intersect(
        &self,
        origin: DVec3,
        dir: DVec3,
        tmin: f64,
        tmax: f64,
        skip: Option<u32>,
    ) -> Option<TriHit> {
        self.intersect_where(origin, dir, tmin, tmax, skip, |_| true)
    }

    /// As [`Accel::intersect`], counting only the hits `accepts` keeps (an any-hit filter:
    /// alpha cut-outs, single-sided faces, `super::coverage`). A rejected candidate does not
    /// shorten the ray, so the nearest kept hit is found in the one traversal; `accepts` must
    /// depend only on the hit (not on the order of the calls).
    pub fn intersect_where(
        &self,
        origin: DVec3,
        dir: DVec3,
        tmin: f64,
        tmax: f64,
        skip: Option<u32>,
        mut accepts: impl FnMut(&TriHit) -> bool,
    ) -> Option<TriHit> {
        if self.tris.is_empty() {
            return None;
        }
        let wr = WatertightRay::new(origin, dir);
        let mut best: Option<TriHit> = None;
        let mut best_t = tmax;
        let mut hit = RayHit::none();
        self.bvh
            .ray_traverse(Self::f32_ray(origin, dir, tmax), &mut hit, |_, slot| {
                match self.candidate(&wr, slot, tmin, best_t, skip) {
                    Some(h) if accepts(&h) => {
                        best_t = h.t;
                        best = Some(h);
                        // Conservative in f32: never cull a box the f64 hit could lie before.
                        (h.t as f32) * 1.000_01 + 1e-3
                    }
                    _ => f32::INFINITY,
                }
            });
        best
    }

    /// True if nothing lies on the ray for t in (tmin, tmax) (skipping triangle `skip`).
    #[inline]
    pub fn unoccluded(
        &self,
        origin: DVec3,
        dir: DVec3,
        tmin: f64,
        tmax: f64,
        skip: Option<u32>,
    ) -> bool {
        self.unoccluded_where(origin, dir, tmin, tmax, skip, |_| true)
    }

    /// As [`Accel::unoccluded`], counting only the hits `accepts` keeps (see
    /// [`Accel::intersect_where`]).
    #[inline]
    pub fn unoccluded_where(
        &self,
        origin: DVec3,
        dir: DVec3,
        tmin: f64,
        tmax: f64,
        skip: Option<u32>,
        mut accepts: impl FnMut(&TriHit) -> bool,
    ) -> bool {
        if self.tris.is_empty() {
            return true;
        }
        let wr = WatertightRay::new(origin, dir);
        self.bvh
            .ray_traverse_miss(Self::f32_ray(origin, dir, tmax), |_, slot| {
                match self.candidate(&wr, slot, tmin, tmax, skip) {
                    Some(h) if accepts(&h) => 0.5 * tmax.min(1e30) as f32,
                    _ => f32::INFINITY,
                }
            })
    }
}

/// Brute-force nearest hit over every triangle (tests and cross-checks).
pub fn brute_force(
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    origin: DVec3,
    dir: DVec3,
) -> Option<TriHit> {
    let wr = WatertightRay::new(origin, dir);
    let mut best: Option<TriHit> = None;
    for (i, t) in triangles.iter().enumerate() {
        let tmax = best.map_or(f64::INFINITY, |b| b.t);
        if let Some((t, bary)) = wr.intersect(
            positions[t[0] as usize],
            positions[t[1] as usize],
            positions[t[2] as usize],
            0.0,
            tmax,
        ) {
            best = Some(TriHit {
                t,
                triangle: i as u32,
                bary,
            });
        }
    }
    best
}

/// Interpolates a per-vertex attribute with barycentric weights.
#[inline]
pub fn interp2(v: [DVec2; 3], b: [f64; 3]) -> DVec2 {
    v[0] * b[0] + v[1] * b[1] + v[2] * b[2]
}
