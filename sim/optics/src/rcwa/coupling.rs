//! RCWA couplings for the tracer (`hoe.model = "rcwa"`): the four film quantities one
//! camera path needs from each grating, computed rigorously once per design on a grid,
//! cached on disk and interpolated.
//!
//! Polarisation: TE and TM are taken relative to each wave's plane of diffraction by grating j
//! (TE ∥ ρ × K_j, [`super::solve_in_basis`]), the basis of Kogelnik's efficiencies and so of the
//! tracer's per-polarisation weights; in the plane-of-incidence basis TE and TM would swap
//! round the optical axis, where the plane of incidence turns with the ray's azimuth.
//!
//! Model: the film in its own mean index on both sides (the `bulk` stack: the tracer keeps the
//! glass and air faces as Fresnel factors and the guided contacts as the two-pass model of
//! docs/physics.md §2.3, exactly as with Kogelnik), solved by [`super::solve`] (all orders,
//! both polarisations, conical incidence, absorption, every grating of the film at once so
//! multiplexed gratings couple). For a camera ray of tangential direction cosines u at vacuum
//! wavelength λ and grating j (guided wave u_g = u − (λ/2π)K_j,t), the tracer needs
//! - `t0`: the zeroth transmitted order of the wave (u, +z) (the see-through part);
//! - `eta_in`: the reflected first order of grating j, (u, +z) → (u_g, −z) (the bottom vHOE's
//!   in-coupling). The top vHOE's out-coupling (u_g, −z) → (u, +z) has the same efficiency:
//!   the film (ε even in r about its centre, up to a lateral shift) is invariant under the
//!   point inversion r → −r, which maps the wave k to −k, and reciprocity maps (a → b) to
//!   (−b → −a); together η(a → b) = η(b → a) (exact for each polarisation where TE and TM do
//!   not mix; at conical fields the mixed part, O(10⁻³) on the paper film, is approximated);
//! - `t0_guided_up`: the zeroth order of (u_g, +z) (a guided wave crossing the film toward the
//!   back face), and `t0_guided_down`: of (u_g, −z), which by the same inversion equals the
//!   zeroth order of (−u_g, +z).
//!
//! Grid and interpolation: per grating j, nodes over (δ, u_x, u_y) with δ = λ − λ_B,j(u) the
//! detuning from the grating's in-coupling Bragg wavelength at u (the Bragg ridge runs along a
//! grid axis, so few u nodes are needed). Each node stores RCWA − a Kogelnik baseline and a
//! lookup adds the exact baseline at the query back: the sharp Bragg shape is carried by the closed form,
//! only the smooth difference is interpolated (trilinear). Outside the grid (|δ| beyond the
//! window, u outside the camera's field, a guided wave evanescent in the film) the lookup
//! returns `None` and the tracer uses Kogelnik for the whole path; far off Bragg the two
//! models agree (the difference at the window's edge is measured, [`RcwaCouplings::edge_jump`]).
//! The interpolation error is measured against direct RCWA at pseudo-random off-grid points
//! when the table is built and stored with it ([`RcwaCouplings::max_error`]).
//!
//! Cache: one file per design, named by a SHA-256 of every input (film, gratings, grid,
//! truncation, slicing, format), written atomically.

use std::path::PathBuf;

use stscam_base::cancel::Token;
use stscam_base::store::BlobStore;

use glam::DVec2;
use rayon::prelude::*;
use sha2::{Digest, Sha256};

use super::table::{Axis, decode_values, encode_values, unit_hash};
use super::{Film, RcwaError, Settings, Stack, grating_orders, solve_in_basis};
use crate::multiplex::GratingSet;

/// Format version of the cache files (part of the key).
const FORMAT: &str = "stscam-rcwa-coupling-3";

/// Values per node: [t0, eta_in, t0_guided_up, t0_guided_down] × [TE, TM].
const PER_NODE: usize = 8;

/// Most nodes per grating.
pub const MAX_NODES: usize = 2_000_000;

/// Longest estimated table build accepted by [`RcwaCouplings::load_or_build`], in seconds,
/// unless `STSCAM_RCWA_MAX_BUILD_S` says otherwise.
pub const DEFAULT_MAX_BUILD_S: f64 = 600.0;

fn max_build_s() -> f64 {
    std::env::var("STSCAM_RCWA_MAX_BUILD_S")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|v| *v >= 0.0)
        .unwrap_or(DEFAULT_MAX_BUILD_S)
}

/// The grid of every grating's table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CouplingGrid {
    /// Detuning δ = λ − λ_B,j(u) in nm.
    pub detuning_nm: Axis,
    /// u_x of the camera ray (physical light's tangential direction cosines).
    pub u_x: Axis,
    /// u_y of the camera ray.
    pub u_y: Axis,
}

impl CouplingGrid {
    /// The default grid for camera rays with u inside [`u_min`, `u_max`]: detuning ±30 nm in
    /// 1-nm steps, u nodes every 0.05 (at least 2 per axis). Spacings chosen from the
    /// measured interpolation error on the paper film (docs/rcwa.md "The tracer's tables").
    pub fn for_field(u_min: DVec2, u_max: DVec2) -> CouplingGrid {
        let axis = |lo: f64, hi: f64, step: f64| {
            let (lo, hi) = if hi > lo {
                (lo, hi)
            } else {
                (lo - 1e-3, lo + 1e-3)
            };
            Axis {
                start: lo,
                stop: hi,
                n: (((hi - lo) / step).ceil() as usize + 1).max(2),
            }
        };
        CouplingGrid {
            detuning_nm: Axis {
                start: -30.0,
                stop: 30.0,
                n: 61,
            },
            u_x: axis(u_min.x, u_max.x, 0.05),
            u_y: axis(u_min.y, u_max.y, 0.05),
        }
    }

    fn nodes(&self) -> usize {
        self.detuning_nm.n * self.u_x.n * self.u_y.n
    }
}

/// The rigorous film quantities of one (λ, u, grating), each [TE, TM] with TE normal to the
/// grating's plane of diffraction of its own wave (Kogelnik's basis, module notes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coupling {
    /// Zeroth transmitted order of (u, +z).
    pub t0: [f64; 2],
    /// In-coupling (u, +z) → (u_g, −z) = out-coupling (u_g, −z) → (u, +z).
    pub eta_in: [f64; 2],
    /// Zeroth order of the guided wave (u_g, +z).
    pub t0_guided_up: [f64; 2],
    /// Zeroth order of the guided wave (u_g, −z).
    pub t0_guided_down: [f64; 2],
}

impl Coupling {
    fn from_values(v: &[f64]) -> Coupling {
        let p = |i: usize| [v[2 * i], v[2 * i + 1]];
        Coupling {
            t0: p(0),
            eta_in: p(1),
            t0_guided_up: p(2),
            t0_guided_down: p(3),
        }
    }
}

/// Where a table came from.
#[derive(Clone, Debug, PartialEq)]
pub struct CacheInfo {
    /// The cache file (None when no cache directory was usable).
    pub path: Option<PathBuf>,
    /// True if every grating's table was read from the cache.
    pub from_cache: bool,
}

/// The RCWA coupling tables of one film (one per grating).
#[derive(Clone)]
pub struct RcwaCouplings {
    film: Film,
    set: GratingSet,
    grid: CouplingGrid,
    settings: Settings,
    /// Per grating: the RCWA order index of its first order.
    orders: Vec<i32>,
    /// Per grating: nodes × [`PER_NODE`] residuals (NaN where RCWA has no value).
    data: Vec<Vec<f64>>,
    max_error: f64,
    cache: CacheInfo,
}

/// Everything that decides the tables' values, with the node data as the SHA-256 of their bits
/// (as text they are megabytes) and without where they came from (`cache`: tables read from
/// the cache are the same design as tables just built). The camera side's cache key
/// (`render::camera_table::design_key`) is made from this text.
impl std::fmt::Debug for RcwaCouplings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut h = Sha256::new();
        for d in &self.data {
            h.update((d.len() as u64).to_le_bytes());
            for v in d {
                h.update(v.to_bits().to_le_bytes());
            }
        }
        let digest = h.finalize();
        let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
        f.debug_struct("RcwaCouplings")
            .field("film", &self.film)
            .field("set", &self.set)
            .field("grid", &self.grid)
            .field("settings", &self.settings)
            .field("orders", &self.orders)
            .field("data_sha256", &hex)
            .field("max_error", &self.max_error)
            .finish()
    }
}

/// The baseline of a node or a query (module notes): what carries the sharp Bragg shape, from
/// one Kogelnik evaluation, the in-coupling order of grating j:
/// t0 ≈ att(u)·(1 − η), η_in ≈ η, the reversed guided wave ≈ att(u_g) (off Bragg), the guided
/// wave toward the top ≈ att(u_g)·(1 − η) (its out-coupling dip). Anything smooth the
/// baseline leaves out is in the interpolated residual.
#[inline]
fn baseline(set: &GratingSet, j: usize, lambda_nm: f64, u: DVec2) -> [f64; PER_NODE] {
    let g = set.get(j);
    let ug = u - g.u_shift(lambda_nm);
    let eta = g
        .diffract(u, 1.0, lambda_nm, 1)
        .filter(|d| d.reflection)
        .map_or([0.0, 0.0], |d| d.eta);
    let (au, ag) = (g.film_attenuation(u), g.film_attenuation(ug));
    [
        au * (1.0 - eta[0]),
        au * (1.0 - eta[1]),
        eta[0],
        eta[1],
        ag,
        ag,
        ag * (1.0 - eta[0]),
        ag * (1.0 - eta[1]),
    ]
}

impl RcwaCouplings {
    /// The film of a grating set (the tracer's gratings).
    pub fn film_of(set: &GratingSet) -> Film {
        let f = set.film();
        Film {
            mean_index: f.n_film,
            alpha0_per_nm: f.alpha0_per_nm,
            thickness_nm: f.thickness_nm,
            gratings: set.as_slice().iter().map(super::Grating::of).collect(),
        }
    }

    fn stack(&self) -> Stack {
        Stack {
            n_in: self.film.mean_index,
            n_out: self.film.mean_index,
        }
    }

    /// Direct RCWA of the four quantities at (λ, u) for grating j; `None` where a wave cannot
    /// enter the film (or no grating order exists).
    fn direct(
        &self,
        j: usize,
        lambda_nm: f64,
        u: DVec2,
    ) -> Result<Option<[f64; PER_NODE]>, RcwaError> {
        let stack = self.stack();
        let ug = u - self.set.get(j).u_shift(lambda_nm);
        let eta = |sol: &super::Solution, reflected: bool, order: i32| {
            sol.orders
                .iter()
                .find(|o| o.reflected == reflected && o.order == order)
                .map_or([0.0, 0.0], |o| o.eta)
        };
        let mut sols = Vec::with_capacity(3);
        let n = self.film.mean_index;
        let k = self.set.get(j).k_rad_per_nm;
        for v in [u, ug, -ug] {
            // TE normal to grating j's plane of diffraction (ρ × K), the tracer's basis.
            let rho = v.extend((n * n - v.length_squared()).max(0.0).sqrt());
            match solve_in_basis(
                &self.film,
                &stack,
                lambda_nm,
                v,
                &self.settings,
                rho.cross(k),
            ) {
                Ok(s) => sols.push(s),
                Err(RcwaError::CannotEnter { .. }) => return Ok(None),
                Err(e) => return Err(e),
            }
        }
        let [t0, eta_in, up, down] = [
            eta(&sols[0], false, 0),
            eta(&sols[0], true, self.orders[j]),
            eta(&sols[1], false, 0),
            eta(&sols[2], false, 0),
        ];
        Ok(Some([
            t0[0], t0[1], eta_in[0], eta_in[1], up[0], up[1], down[0], down[1],
        ]))
    }

    fn node_point(&self, j: usize, node: usize) -> Option<(f64, DVec2)> {
        let g = &self.grid;
        let (id, rest) = (node / (g.u_x.n * g.u_y.n), node % (g.u_x.n * g.u_y.n));
        let (ix, iy) = (rest / g.u_y.n, rest % g.u_y.n);
        let u = DVec2::new(g.u_x.value(ix), g.u_y.value(iy));
        let lb = self.set.get(j).bragg_wavelength_nm(u)?;
        let lam = lb + g.detuning_nm.value(id);
        (lam > 0.0).then_some((lam, u))
    }

    /// The cache key: SHA-256 over every input, as hex.
    fn key(film: &Film, grid: &CouplingGrid, settings: &Settings, probes: usize) -> String {
        let text = format!("{FORMAT}|{film:?}|{grid:?}|{settings:?}|{probes}");
        Sha256::digest(text.as_bytes())
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    }

    /// Builds the tables of `set` on `grid` (in parallel over nodes; deterministic) and
    /// measures their interpolation error at `probes` off-grid points; once `cancel` is set
    /// the build stops at the next node with [`RcwaError::Cancelled`].
    pub fn build(
        set: &GratingSet,
        grid: &CouplingGrid,
        settings: &Settings,
        probes: usize,
        cancel: &Token,
    ) -> Result<RcwaCouplings, RcwaError> {
        Self::empty(set, grid, settings)?.fill(probes, cancel)
    }

    /// Computes the tables of an [`Self::empty`] set-up and measures their error.
    fn fill(mut self, probes: usize, cancel: &Token) -> Result<RcwaCouplings, RcwaError> {
        let c = &mut self;
        let nodes = c.grid.nodes();
        // A cancelled job (Ctrl-C in Python) stops at the next node; nothing is cached.
        for j in 0..c.set.len() {
            let rows: Result<Vec<[f64; PER_NODE]>, RcwaError> = (0..nodes)
                .into_par_iter()
                .map(|node| {
                    if cancel.is_cancelled() {
                        return Err(RcwaError::Cancelled);
                    }
                    let Some((lam, u)) = c.node_point(j, node) else {
                        return Ok([f64::NAN; PER_NODE]);
                    };
                    let Some(mut v) = c.direct(j, lam, u)? else {
                        return Ok([f64::NAN; PER_NODE]);
                    };
                    let b = baseline(&c.set, j, lam, u);
                    v.iter_mut().zip(b).for_each(|(a, b)| *a -= b);
                    Ok(v)
                })
                .collect();
            let rows = rows?.concat();
            c.data.push(rows);
        }
        c.max_error = c.measure_error(probes, 1)?;
        Ok(self)
    }

    fn empty(
        set: &GratingSet,
        grid: &CouplingGrid,
        settings: &Settings,
    ) -> Result<RcwaCouplings, RcwaError> {
        let axes = [grid.detuning_nm, grid.u_x, grid.u_y];
        let bad = |a: &Axis| {
            a.n < 2
                || !a.start.is_finite()
                || !a.stop.is_finite()
                || a.stop.partial_cmp(&a.start) != Some(std::cmp::Ordering::Greater)
        };
        if axes.iter().any(bad) || grid.nodes() > MAX_NODES {
            return Err(RcwaError::BadInput(format!(
                "coupling grid: axes need at least 2 nodes and start < stop, at most {MAX_NODES} nodes"
            )));
        }
        let film = Self::film_of(set);
        let orders = grating_orders(&film)?;
        Ok(RcwaCouplings {
            film,
            set: *set,
            grid: *grid,
            settings: *settings,
            orders,
            data: Vec::new(),
            max_error: f64::NAN,
            cache: CacheInfo {
                path: None,
                from_cache: false,
            },
        })
    }

    /// Loads the tables of this design from `cache` (if given and it holds them) or builds
    /// them and stores them there (atomically; a cache that cannot be written is not an error,
    /// the tables are used all the same); `cancel` stops a build as in [`Self::build`].
    pub fn load_or_build(
        cache: Option<&dyn BlobStore>,
        set: &GratingSet,
        grid: &CouplingGrid,
        settings: &Settings,
        probes: usize,
        cancel: &Token,
    ) -> Result<RcwaCouplings, RcwaError> {
        let mut c = Self::empty(set, grid, settings)?;
        let key = Self::key(&c.film, grid, settings, probes);
        let name = format!("rcwa-coupling-{}.bin", &key[..32]);
        let len = set.len() * grid.nodes() * PER_NODE;
        if let Some(store) = cache {
            let path = store.location(&name);
            if let Some(bytes) = store.load(&name)
                && let Some((err, data)) = decode_values(&bytes, &key, len, true)
            {
                c.data = data
                    .chunks(grid.nodes() * PER_NODE)
                    .map(<[f64]>::to_vec)
                    .collect();
                c.max_error = err;
                c.cache = CacheInfo {
                    path: Some(path),
                    from_cache: true,
                };
                return Ok(c);
            }
        }
        let est = c.estimate_build_s(probes)?;
        let limit = max_build_s();
        if est > limit {
            return Err(RcwaError::BadInput(format!(
                "building the RCWA tables of this film would take about {:.0} min on {} threads \
                 (more than the {:.0} min accepted; set STSCAM_RCWA_MAX_BUILD_S to allow it): \
                 gratings of different slant need an eigensolution per slice; use \
                 hoe.model = \"kogelnik\" or gratings of one slant",
                est / 60.0,
                rayon::current_num_threads(),
                limit / 60.0
            )));
        }
        let mut c = c.fill(probes, cancel)?;
        if let Some(store) = cache {
            let bytes = encode_values(&key, c.max_error, &c.data.concat());
            if let Ok(path) = store.save(&name, &bytes) {
                c.cache.path = Some(path);
            }
        }
        Ok(c)
    }

    /// Estimated wall seconds of [`Self::build`] on the current thread pool: one node's solves
    /// timed here, times the nodes and probes of every grating, over the threads.
    fn estimate_build_s(&self, probes: usize) -> Result<f64, RcwaError> {
        let nodes = self.grid.nodes();
        let Some((lam, u)) = (0..nodes).find_map(|n| self.node_point(0, n)) else {
            return Ok(0.0);
        };
        let t0 = std::time::Instant::now();
        self.direct(0, lam, u)?;
        let per_node = t0.elapsed().as_secs_f64();
        let work = (nodes + probes) as f64 * self.set.len() as f64;
        Ok(per_node * work / rayon::current_num_threads().max(1) as f64)
    }

    /// Largest |interpolated − direct RCWA| over the probes of the build (every quantity,
    /// both polarisations; NaN if not measured).
    pub fn max_error(&self) -> f64 {
        self.max_error
    }

    /// Where the tables came from.
    pub fn cache(&self) -> &CacheInfo {
        &self.cache
    }

    /// The grid.
    pub fn grid(&self) -> &CouplingGrid {
        &self.grid
    }

    /// The trilinear cell of (λ, u) in grating `j`'s table: the first node and the weights.
    #[inline]
    fn cell(&self, j: usize, lambda_nm: f64, u: DVec2) -> Option<([usize; 8], [f64; 8])> {
        let g = &self.grid;
        let lb = self.set.get(j).bragg_wavelength_nm(u)?;
        let (id, wd) = g.detuning_nm.locate(lambda_nm - lb)?;
        let (ix, wx) = g.u_x.locate(u.x)?;
        let (iy, wy) = g.u_y.locate(u.y)?;
        let mut nodes = [0; 8];
        let mut weights = [0.0; 8];
        let mut k = 0;
        for (dd, fd) in [(0, 1.0 - wd), (1, wd)] {
            for (dx, fx) in [(0, 1.0 - wx), (1, wx)] {
                for (dy, fy) in [(0, 1.0 - wy), (1, wy)] {
                    nodes[k] = ((id + dd) * g.u_x.n + ix + dx) * g.u_y.n + iy + dy;
                    weights[k] = fd * fx * fy;
                    k += 1;
                }
            }
        }
        Some((nodes, weights))
    }

    /// Interpolated residual of quantity `q` (0 t0, 1 eta_in, 2 up, 3 down) over a cell;
    /// NaN where a node with weight has no value.
    #[inline]
    fn residual(&self, j: usize, (nodes, weights): &([usize; 8], [f64; 8]), q: usize) -> [f64; 2] {
        let data = &self.data[j];
        let mut v = [0.0; 2];
        for (&node, &w) in nodes.iter().zip(weights) {
            if w == 0.0 {
                continue;
            }
            let at = node * PER_NODE + 2 * q;
            v[0] += w * data[at];
            v[1] += w * data[at + 1];
        }
        v
    }

    /// The film's four quantities for grating `j` at (λ, u) (module notes); `None` outside
    /// the grid, where the tracer uses Kogelnik.
    #[inline]
    pub fn lookup(&self, j: usize, lambda_nm: f64, u: DVec2) -> Option<Coupling> {
        let cell = self.cell(j, lambda_nm, u)?;
        let mut v = [0.0; PER_NODE];
        for q in 0..4 {
            let r = self.residual(j, &cell, q);
            v[2 * q] = r[0];
            v[2 * q + 1] = r[1];
        }
        if v.iter().any(|x| x.is_nan()) {
            return None;
        }
        let b = baseline(&self.set, j, lambda_nm, u);
        v.iter_mut()
            .zip(b)
            .for_each(|(a, b)| *a = (*a + b).clamp(0.0, 1.0));
        Some(Coupling::from_values(&v))
    }

    /// Largest |lookup − direct RCWA| over `probes` pseudo-random off-grid points per grating
    /// (deterministic in `seed`).
    pub fn measure_error(&self, probes: usize, seed: u64) -> Result<f64, RcwaError> {
        Ok(self
            .measure_errors(probes, seed)?
            .into_iter()
            .fold(0.0, f64::max))
    }

    /// [`Self::measure_error`] per quantity: [t0, eta_in, t0_guided_up, t0_guided_down].
    pub fn measure_errors(&self, probes: usize, seed: u64) -> Result<[f64; 4], RcwaError> {
        let g = self.grid;
        let errs: Result<Vec<[f64; 4]>, RcwaError> = (0..self.set.len() * probes)
            .into_par_iter()
            .map(|i| {
                let j = i / probes.max(1);
                let r = |k: u64| unit_hash(seed, i as u64, k);
                let at = |a: &Axis, x: f64| a.start + (a.stop - a.start) * x;
                let u = DVec2::new(at(&g.u_x, r(1)), at(&g.u_y, r(2)));
                let Some(lb) = self.set.get(j).bragg_wavelength_nm(u) else {
                    return Ok([0.0; 4]);
                };
                let lam = lb + at(&g.detuning_nm, r(0));
                let (Some(c), Some(d)) = (self.lookup(j, lam, u), self.direct(j, lam, u)?) else {
                    return Ok([0.0; 4]);
                };
                let v = [c.t0, c.eta_in, c.t0_guided_up, c.t0_guided_down];
                Ok([0, 1, 2, 3].map(|q| {
                    (v[q][0] - d[2 * q])
                        .abs()
                        .max((v[q][1] - d[2 * q + 1]).abs())
                }))
            })
            .collect();
        Ok(errs?
            .into_iter()
            .fold([0.0; 4], |a, b| [0, 1, 2, 3].map(|q| a[q].max(b[q]))))
    }

    /// Largest |RCWA − Kogelnik| over the quantities at the window's two detuning edges
    /// (every u node, every grating): the step a path sees where the tracer leaves the table
    /// for Kogelnik.
    pub fn edge_jump(&self) -> f64 {
        let g = &self.grid;
        let per_layer = g.u_x.n * g.u_y.n;
        let mut worst: f64 = 0.0;
        for data in &self.data {
            for layer in [0, g.detuning_nm.n - 1] {
                for v in &data[layer * per_layer * PER_NODE..(layer + 1) * per_layer * PER_NODE] {
                    if v.is_finite() {
                        worst = worst.max(v.abs());
                    }
                }
            }
        }
        worst
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grating::VolumeGrating;
    use crate::rcwa::Grating;
    use crate::rcwa::solve;

    fn paper_set(n1: f64, alpha0_per_mm: f64) -> GratingSet {
        GratingSet::single(VolumeGrating::from_recording(
            532.0,
            61.2,
            1.50,
            16.0,
            n1,
            alpha0_per_mm,
        ))
    }

    fn small_grid() -> CouplingGrid {
        CouplingGrid {
            detuning_nm: Axis {
                start: -12.0,
                stop: 12.0,
                n: 25,
            },
            u_x: Axis {
                start: -0.05,
                stop: 0.05,
                n: 3,
            },
            u_y: Axis {
                start: -0.1,
                stop: 0.1,
                n: 5,
            },
        }
    }

    /// The symmetry the tracer relies on (module notes): the out-coupling (u_g, −z) → (u, +z)
    /// and the zeroth order of (u_g, −z), computed directly on the z-mirrored film (K_z → −K_z,
    /// incidence from the other side), equal the in-coupling (u, +z) → (u_g, −z) and the zeroth
    /// order of (−u_g, +z): per polarisation to 1e-9 at planar incidence; at a conical field
    /// TE and TM mix, and the equality holds for their sum (unpolarised light) to 1e-9 while
    /// the single polarisations differ (the tracer's diagonal approximation, module notes).
    /// The (u_g, +z) wave in place of the mirrored one fails.
    #[test]
    fn out_coupling_equals_in_coupling_by_inversion_and_reciprocity() {
        for alpha in [0.0, 0.5] {
            let set = paper_set(0.015, alpha);
            let film = RcwaCouplings::film_of(&set);
            let mut mirrored = film.clone();
            mirrored.gratings[0].k_rad_per_nm.z *= -1.0;
            let stack = Stack {
                n_in: 1.5,
                n_out: 1.5,
            };
            let s = Settings::default();
            for (u, planar) in [
                (DVec2::new(0.0, 0.05), true),
                (DVec2::new(0.12, -0.08), false),
            ] {
                let same = |a: [f64; 2], b: [f64; 2]| {
                    if planar {
                        (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9
                    } else {
                        (a[0] + a[1] - b[0] - b[1]).abs() < 1e-9
                    }
                };
                let g = set.get(0);
                let lam = g.bragg_wavelength_nm(u).unwrap() + 1.5;
                let ug = u - g.u_shift(lam);
                let fwd = solve(&film, &stack, lam, u, &s).unwrap();
                let back = solve(&mirrored, &stack, lam, ug, &s).unwrap();
                let find = |sol: &super::super::Solution, r: bool, m: i32| {
                    sol.orders
                        .iter()
                        .find(|o| o.reflected == r && o.order == m)
                        .unwrap()
                        .eta
                };
                let (a, b) = (find(&fwd, true, 1), find(&back, true, -1));
                assert!(a[0] > 0.3, "near Bragg: {a:?}");
                assert!(same(a, b), "{u} {alpha}: in {a:?} out {b:?}");
                if !planar {
                    assert!(
                        (a[0] - b[0]).abs() > 0.05,
                        "conical fields mix TE and TM: {a:?} {b:?}"
                    );
                }
                let down = find(&solve(&film, &stack, lam, -ug, &s).unwrap(), false, 0);
                let direct_down = find(&back, false, 0);
                assert!(same(down, direct_down), "{down:?} {direct_down:?}");
                // Without the mirror the (u_g, +z) wave is not the (u_g, −z) one: far apart.
                let wrong = find(&solve(&film, &stack, lam, ug, &s).unwrap(), true, -1);
                assert!((wrong[0] - a[0]).abs() > 0.1, "{wrong:?} vs {a:?}");
            }
        }
    }

    /// Lookups reproduce direct RCWA at the nodes (to rounding) and within the measured error
    /// off the nodes; the measured error is small on the paper film and grows past the bound
    /// when a node's value is corrupted.
    #[test]
    fn lookups_match_direct_rcwa() {
        let set = paper_set(0.015, 0.0);
        let mut c = RcwaCouplings::build(
            &set,
            &small_grid(),
            &Settings::default(),
            40,
            &Token::default(),
        )
        .unwrap();
        let err = c.max_error();
        assert!(err < 0.01, "interpolation error {err}");
        let (lam, u) = c.node_point(0, 7 * 15 + 4).unwrap();
        let d = c.direct(0, lam, u).unwrap().unwrap();
        let l = c.lookup(0, lam, u).unwrap();
        let v = [l.t0, l.eta_in, l.t0_guided_up, l.t0_guided_down].concat();
        for (a, b) in v.iter().zip(d) {
            assert!((a - b).abs() < 1e-12, "{v:?} {d:?}");
        }
        // Energy: in-coupling and the straight part never exceed the light that came in.
        assert!(l.t0[0] + l.eta_in[0] <= 1.0 + 1e-9);
        // Outside the window: Kogelnik's turn.
        assert!(c.lookup(0, lam + 30.0, u).is_none());
        for v in c.data[0].iter_mut().skip(2).step_by(PER_NODE) {
            *v += 0.05;
        }
        let bad = c.measure_error(40, 1).unwrap();
        assert!(bad > 0.04, "a corrupted table must fail: {bad}");
    }

    /// The cache: the second call reads the first call's file (same values, bit for bit); a
    /// foreign file under the same name is rebuilt, not trusted.
    #[test]
    fn cache_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let set = paper_set(0.015, 0.0);
        let grid = CouplingGrid {
            detuning_nm: Axis {
                start: -5.0,
                stop: 5.0,
                n: 3,
            },
            u_x: Axis {
                start: -0.02,
                stop: 0.02,
                n: 2,
            },
            u_y: Axis {
                start: -0.02,
                stop: 0.02,
                n: 2,
            },
        };
        let s = Settings::default();
        let a = RcwaCouplings::load_or_build(
            Some(&crate::TestDir(dir.path().to_path_buf())),
            &set,
            &grid,
            &s,
            4,
            &Token::default(),
        )
        .unwrap();
        assert!(!a.cache().from_cache);
        let path = a.cache().path.clone().unwrap();
        let b = RcwaCouplings::load_or_build(
            Some(&crate::TestDir(dir.path().to_path_buf())),
            &set,
            &grid,
            &s,
            4,
            &Token::default(),
        )
        .unwrap();
        assert!(b.cache().from_cache);
        let bits = |c: &RcwaCouplings| {
            c.data
                .concat()
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&a), bits(&b));
        // The text a design key is made from: the same for built and read tables (where they
        // came from is not the design), another for one node value changed by one ulp.
        assert_eq!(format!("{a:?}"), format!("{b:?}"));
        let mut e = b.clone();
        e.data[0][3] = f64::from_bits(e.data[0][3].to_bits() + 1);
        assert_ne!(format!("{e:?}"), format!("{b:?}"));
        std::fs::write(&path, b"not a table").unwrap();
        let c = RcwaCouplings::load_or_build(
            Some(&crate::TestDir(dir.path().to_path_buf())),
            &set,
            &grid,
            &s,
            4,
            &Token::default(),
        )
        .unwrap();
        assert!(!c.cache().from_cache);
        assert_eq!(bits(&a), bits(&c));
        // Another design is another file.
        let other = paper_set(0.02, 0.0);
        let d = RcwaCouplings::load_or_build(
            Some(&crate::TestDir(dir.path().to_path_buf())),
            &other,
            &grid,
            &s,
            4,
            &Token::default(),
        )
        .unwrap();
        assert!(!d.cache().from_cache);
        let _ = Grating::of(other.get(0));
    }
}
