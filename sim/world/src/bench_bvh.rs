//! Benchmark of the user-side triangle BVH ([`super::bvh::Accel`]): build time and
//! closest-hit throughput with 1 and 2 rayon threads on a large procedural mesh.
//!
//! Model: a closed displaced sphere (mean radius 100 mm, ±8 % smooth relief, so ≈ 200 mm
//! across) centred at z = −500 mm — the scale and placement of a head in front of the screen —
//! tessellated into at least the requested number of triangles. Rays are incoherent: each
//! starts at a uniform point of the 300 mm cube around the sphere (≈ 15 % of them inside it)
//! and is aimed at a uniform point of a uniformly chosen triangle, so nearly all of them hit;
//! the traversal and the f64 watertight candidate tests are exactly those of
//! [`Accel::intersect`] (t ∈ (0, ∞), no skipped triangle).
//!
//! Method: for each thread count the BVH is built inside a `rayon` pool of that many threads
//! (the build is parallel) and timed by wall clock; then the same precomputed rays are traced
//! in that pool, split over rayon in chunks, and the closest-hit rate is rays / wall time.
//! Everything is deterministic for a given seed except the times.

use std::time::Instant;

use glam::DVec3;
use rayon::prelude::*;

use super::bvh::Accel;
use super::mesh::Mesh;
use crate::sampler::{hash, to_unit};

/// Figures measured with one thread count.
#[derive(Clone, Debug, serde::Serialize)]
pub struct BvhRun {
    /// Size of the rayon pool.
    pub threads: usize,
    /// Wall time of `Accel::build`, s.
    pub build_s: f64,
    /// Closest-hit queries per second (wall clock).
    pub rays_per_s: f64,
}

/// Result of [`bench_bvh`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct BvhBench {
    /// Triangles in the mesh.
    pub triangles: usize,
    /// Rays traced per thread count.
    pub rays: usize,
    /// Seed of the mesh-independent ray sampling.
    pub seed: u64,
    /// One entry per thread count (1, then 2).
    pub runs: Vec<BvhRun>,
    /// Fraction of the rays that hit a triangle.
    pub hit_fraction: f64,
}

/// Closed displaced sphere of mean radius 100 mm centred at (0, 0, −500) mm with at least
/// `triangles_min` triangles: two poles and `nv − 1` rings of `nu = 2·nv` vertices,
/// 2·nu·(nv − 1) triangles wound outward.
pub fn displaced_sphere(triangles_min: usize) -> Mesh {
    let centre = DVec3::new(0.0, 0.0, -500.0);
    let r = 100.0;
    let mut nv = 2usize;
    while 4 * nv * (nv - 1) < triangles_min.max(1) {
        nv += 1;
    }
    let nu = 2 * nv;
    let radius = |d: DVec3| {
        r * (1.0
            + 0.06 * (7.0 * d.x).sin() * (5.0 * d.y).sin() * (6.0 * d.z + 1.0).sin()
            + 0.02 * (23.0 * d.x + 17.0 * d.z).sin())
    };
    let mut m = Mesh::default();
    m.positions_mm.push(centre + DVec3::Y * radius(DVec3::Y));
    for k in 1..nv {
        let th = std::f64::consts::PI * k as f64 / nv as f64;
        for j in 0..nu {
            let ph = std::f64::consts::TAU * j as f64 / nu as f64;
            let d = DVec3::new(th.sin() * ph.sin(), th.cos(), th.sin() * ph.cos());
            m.positions_mm.push(centre + d * radius(d));
        }
    }
    let bottom = m.positions_mm.len() as u32;
    m.positions_mm.push(centre - DVec3::Y * radius(-DVec3::Y));
    let id = |k: usize, j: usize| (1 + k * nu + j % nu) as u32;
    for j in 0..nu {
        m.triangles.push([0, id(0, j), id(0, j + 1)]);
    }
    for k in 0..nv - 2 {
        for j in 0..nu {
            let (a, b, c, d) = (id(k, j), id(k + 1, j), id(k + 1, j + 1), id(k, j + 1));
            m.triangles.push([a, b, c]);
            m.triangles.push([a, c, d]);
        }
    }
    for j in 0..nu {
        m.triangles.push([id(nv - 2, j), bottom, id(nv - 2, j + 1)]);
    }
    m.material_ids = vec![0; m.triangles.len()];
    m
}

/// Builds a mesh of at least `triangles_min` triangles ([`displaced_sphere`]), then for 1 and
/// 2 rayon threads times `Accel::build` and traces `rays` incoherent closest-hit rays (sampled
/// from `seed`); see the module documentation. Suggested defaults: 10⁶ triangles, 10⁶ rays.
///
/// # Panics
/// If a rayon thread pool cannot be created.
pub fn bench_bvh(triangles_min: usize, rays: usize, seed: u64) -> BvhBench {
    let mesh = displaced_sphere(triangles_min);
    let n_tri = mesh.triangles.len();
    let centre = DVec3::new(0.0, 0.0, -500.0);
    let u = |i: u64, k: u64| to_unit(hash(&[seed, i, k]));
    let ray_set: Vec<(DVec3, DVec3)> = (0..rays as u64)
        .into_par_iter()
        .map(|i| {
            let o = centre + DVec3::new(u(i, 0) - 0.5, u(i, 1) - 0.5, u(i, 2) - 0.5) * 300.0;
            let t = mesh.triangles[((u(i, 3) * n_tri as f64) as usize).min(n_tri - 1)];
            let [a, b, c] = t.map(|k| mesh.positions_mm[k as usize]);
            let (mut s, mut w) = (u(i, 4), u(i, 5));
            if s + w > 1.0 {
                (s, w) = (1.0 - s, 1.0 - w);
            }
            let p = a + (b - a) * s + (c - a) * w;
            (o, (p - o).normalize_or(DVec3::Z))
        })
        .collect();
    let mut runs = Vec::new();
    let mut hit_fraction = 0.0;
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("rayon thread pool");
        let start = Instant::now();
        let accel = pool.install(|| Accel::build(&mesh.positions_mm, &mesh.triangles));
        let build_s = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let hits: usize = pool.install(|| {
            ray_set
                .par_chunks(4096)
                .map(|c| {
                    c.iter()
                        .filter(|&&(o, d)| {
                            accel.intersect(o, d, 0.0, f64::INFINITY, None).is_some()
                        })
                        .count()
                })
                .sum()
        });
        let trace_s = start.elapsed().as_secs_f64();
        hit_fraction = hits as f64 / rays.max(1) as f64;
        runs.push(BvhRun {
            threads,
            build_s,
            rays_per_s: rays as f64 / trace_s.max(1e-12),
        });
    }
    BvhBench {
        triangles: n_tri,
        rays,
        seed,
        runs,
        hit_fraction,
    }
}
