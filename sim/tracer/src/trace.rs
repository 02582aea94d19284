//! One backward path from the camera through the waveguide to the display, with deterministic
//! splitting over every bottom-vHOE contact.
//!
//! Model (docs/design.md "One camera sample, end to end"; docs/physics.md §0.3, §2.3, §5): a camera ray
//! (air, tangential direction cosines u) crosses the back face (Fresnel), the plate
//! (Beer–Lambert), and meets the front face. Inside the top vHOE it splits into
//! - the diffracted branch: the guided wave u_g = u − (λ/2π)K_t that the top vHOE out-couples
//!   into u (order −1, Kogelnik efficiency η_top), traced backward down the plate by TIR;
//! - the straight branch (1 − Σ η) through the film to the user side, absorbed by the cover
//!   when `covered`.
//!
//! Along the guided zig-zag (each leg shifts by w·u_g/√(n² − |u_g|²)):
//! - at a back-face contact inside the bottom vHOE, the in-coupled branch (order +1 from u to
//!   u_g, efficiency η_in) crosses the plate and leaves the front face toward the display with
//!   the camera's own direction (the periscope property); the guided branch continues with the
//!   two-pass factor (1 − Σ η_pass1)·R_TIR·(1 − Σ η_pass2) (pass 2 contains the out-coupling
//!   loss ≈ η_in per bounce, docs/physics.md §2.3);
//! - at a front-face contact under the top vHOE the guided wave loses its out-coupled part
//!   (and everything, if the cover frustrates TIR);
//! - elsewhere the faces reflect with Fresnel R (1 under TIR).
//!
//! Every replica is summed (no Russian roulette). A path stops when it can no longer reach the
//! bottom vHOE, when its guided weight falls below `min_weight` (what is left is reported as
//! truncated, an upper bound on the bias), or at `max_contacts`.
//! Weights are energy fractions per polarisation [TE, TM]; radiance/n² is invariant at the
//! interfaces, and the grating's η already includes the obliquity factors, so a branch's weight
//! multiplies the object radiance directly.

use std::ops::ControlFlow;

use glam::{DVec2, DVec3};
use wide::f64x4;

use crate::optics::interface::{lateral_shift, path_length, reflectance, transmittance};
use crate::optics::multiplex::MAX_GRATINGS;
use crate::optics::packet::{self, Incident4, LANES, Vec2x4};
use crate::optics::rcwa::coupling::{Coupling, RcwaCouplings};
use crate::waveguide::Waveguide;

/// Which kind of branch reached the display.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BranchKind {
    /// Straight through the plate (no diffraction).
    Direct,
    /// Through the waveguide, in-coupled at the given bottom-vHOE contact (0 = first, nearest
    /// the top vHOE).
    Replica(u32),
}

/// One branch of a path that reached the display plane.
#[derive(Clone, Copy, Debug)]
pub struct Branch {
    /// Branch kind.
    pub kind: BranchKind,
    /// Bottom-vHOE contact (x, y) on the back face, for replicas.
    pub bottom_contact_mm: Option<DVec2>,
    /// Where the branch crosses the front face (x, y).
    pub exit_point_mm: DVec2,
    /// Where it meets the display plane (x, y).
    pub object_point_mm: DVec2,
    /// Energy fraction [TE, TM] carried to the object along this branch.
    pub weight: [f64; 2],
    /// Plate contacts along the guided path before this branch left it (1 = the first back-face
    /// contact below the top vHOE; 0 for direct branches). Unlike the replica index this
    /// changes continuously with the ray, so it identifies a replica across the field.
    pub contact: u32,
    /// The grating (index in the film's list) that coupled this branch in and out (0 for
    /// direct branches). A replica is identified by (grating, contact): [`Self::replica_key`].
    pub grating: u32,
}

impl Branch {
    /// The replica's identity (grating, contact) as one number: `contact` for grating 0 (the
    /// single-grating keys of before), the grating index in the high 32 bits otherwise, so
    /// two gratings' replicas never share a key (random streams, padded sets, resampling).
    #[inline]
    pub fn replica_key(&self) -> u64 {
        replica_key(self.grating, self.contact)
    }
}

/// The key of replica (grating, contact): see [`Branch::replica_key`].
#[inline]
pub fn replica_key(grating: u32, contact: u32) -> u64 {
    u64::from(contact) | (u64::from(grating) << 32)
}

/// What a path did besides its branches.
#[derive(Clone, Copy, Debug, Default)]
pub struct TraceSummary {
    /// Plate contacts visited by the guided part.
    pub contacts: u32,
    /// Front-face contacts of the guided part under the top vHOE after the out-coupling point
    /// (each loses the top vHOE's out-coupled share, docs/physics.md §5).
    pub top_contacts: u32,
    /// Guided weight left when the path stopped on `min_weight` or `max_contacts` (max of TE,
    /// TM): an upper bound on each missing replica's weight.
    pub truncated_weight: f64,
    /// True if `max_contacts` stopped the path.
    pub hit_max_contacts: bool,
    /// Tangential direction cosines of the first grating's guided wave that the top vHOE
    /// couples out (zero if none).
    pub guided_u: DVec2,
    /// Glass index at the path's wavelength.
    pub n_glass: f64,
}

/// Limits of one trace.
#[derive(Clone, Copy, Debug)]
pub struct TraceLimits {
    /// Stop when the guided weight falls below this.
    pub min_weight: f64,
    /// Hard contact limit.
    pub max_contacts: u32,
}

#[inline]
fn mul(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] * b[0], a[1] * b[1]]
}

#[inline]
fn scale(a: [f64; 2], s: f64) -> [f64; 2] {
    [a[0] * s, a[1] * s]
}

/// Where a camera ray (from `origin` behind the plate, `dir` with z < 0) meets the back face
/// and, refracted with glass index `n_glass`, the front face: (back, front) as (x, y) in mm.
#[inline]
pub fn plate_crossing(wg: &Waveguide, origin: DVec3, dir: DVec3, n_glass: f64) -> (DVec2, DVec2) {
    let p_back = origin.truncate() + dir.truncate() * ((origin.z - wg.thickness_mm) / -dir.z);
    (
        p_back,
        p_back - lateral_shift(-dir.truncate(), n_glass, wg.thickness_mm),
    )
}

/// Whether a camera ray also sees the user side straight through the plate (a broadband
/// contribution): it misses the top vHOE, or the top vHOE is not covered. Uses the glass index
/// at `lambda_nm` (the answer is needed before a wavelength is drawn; pass a fixed one).
pub fn sees_through(wg: &Waveguide, origin: DVec3, dir: DVec3, lambda_nm: f64) -> bool {
    sees_through_n(wg, origin, dir, wg.n_glass(lambda_nm))
}

/// [`sees_through`] with the glass index given (computed once for many rays).
#[inline]
pub fn sees_through_n(wg: &Waveguide, origin: DVec3, dir: DVec3, n_glass: f64) -> bool {
    if !wg.covered || dir.z >= 0.0 {
        return true;
    }
    !wg.top.contains(plate_crossing(wg, origin, dir, n_glass).1)
}

/// Traces one camera ray (lens point `origin`, unit direction `dir` toward the screen) at
/// `lambda_nm` backward to the display plane at `display_z_mm`, calling `visit` for every
/// branch that reaches it.
pub fn trace_camera_path(
    wg: &Waveguide,
    display_z_mm: f64,
    limits: TraceLimits,
    origin: DVec3,
    dir: DVec3,
    lambda_nm: f64,
    mut visit: impl FnMut(&Branch),
) -> TraceSummary {
    trace_camera_path_until(wg, display_z_mm, limits, origin, dir, lambda_nm, |b| {
        visit(b);
        ControlFlow::Continue(())
    })
}

/// As [`trace_camera_path`], but `visit` may stop the path early (`ControlFlow::Break`), as an
/// analog tracer that has chosen its branch does.
pub fn trace_camera_path_until(
    wg: &Waveguide,
    display_z_mm: f64,
    limits: TraceLimits,
    origin: DVec3,
    dir: DVec3,
    lambda_nm: f64,
    visit: impl FnMut(&Branch) -> ControlFlow<()>,
) -> TraceSummary {
    // The model is resolved here, once per path: the Kogelnik instantiation carries nothing of
    // the tables.
    let ray = (origin, dir, lambda_nm);
    match wg.rcwa.as_deref() {
        None => trace_path(wg, Kogelnik, display_z_mm, limits, ray, None, visit),
        Some(t) => trace_path(wg, t, display_z_mm, limits, ray, None, visit),
    }
}

/// A camera path's film and interface quantities computed ahead of its trace, several paths
/// at once ([`prepare_paths`]): exactly what [`trace_camera_path_until`] computes for itself
/// (bit for bit, optics::packet), for waveguides where [`packets_apply`].
#[derive(Clone, Copy, Debug, Default)]
pub struct Prepared {
    n_g: f64,
    alpha: f64,
    t_face: [f64; 2],
    cross_shift: DVec2,
    cross_t: f64,
    /// The guided wave, where the top vHOE couples one out.
    guided: Option<PreparedGuided>,
}

/// The guided wave's quantities of a [`Prepared`] path.
#[derive(Clone, Copy, Debug)]
struct PreparedGuided {
    u_g: DVec2,
    top_eta: [f64; 2],
    leg: DVec2,
    leg_t: f64,
    r_face: [f64; 2],
    r_film: [f64; 2],
    toward_back: [f64; 2],
    toward_front: [f64; 2],
}

/// Whether [`prepare_paths`] serves this waveguide: one grating, Kogelnik's model, a lossless
/// film (the packet's forms, optics::packet); other films are traced by the scalar code alone.
pub(crate) fn packets_apply(wg: &Waveguide) -> bool {
    wg.rcwa.is_none() && wg.gratings.len() == 1 && wg.gratings.film().alpha0_per_nm == 0.0
}

/// The [`Prepared`] quantities of four camera rays (lens point, unit direction, wavelength) at
/// once, lane by lane in one SIMD packet (optics::packet). Only for waveguides where
/// [`packets_apply`]; any ray may be passed (a ray that does not reach the plate is traced as
/// such), so unused lanes can repeat a used one.
pub fn prepare_paths(wg: &Waveguide, rays: &[(DVec3, DVec3, f64); LANES]) -> [Prepared; LANES] {
    debug_assert!(packets_apply(wg));
    let w = wg.thickness_mm;
    let g = wg.gratings.film();
    let n_g: [f64; LANES] = rays.map(|r| wg.n_glass(r.2));
    let alpha: [f64; LANES] = rays.map(|r| wg.absorption_per_mm(r.2));
    let u: [DVec2; LANES] = rays.map(|r| -r.1.truncate());
    let u_g: [DVec2; LANES] = std::array::from_fn(|i| u[i] - g.u_shift(rays[i].2));
    let (nv, lv) = (f64x4::new(n_g), f64x4::new(rays.map(|r| r.2)));
    let uv = Vec2x4::from_lanes(u);
    let u2 = uv.length_squared();
    let t_face = packet::transmittance(f64x4::ONE, nv, u2);
    let (cross_f, cross_len) = packet::crossing(nv, u2, w);
    let ugv = Vec2x4::from_lanes(u_g);
    let ug2 = ugv.length_squared();
    // Lanes whose guided wave exists in the glass (as `top_coupling`); of those, the lanes
    // whose order −1 is reflection-type have a guided wave to trace.
    let in_glass = ug2.simd_lt(nv * nv);
    let top = Incident4::new(g, &ugv, -1.0, lv).masked(in_glass);
    let out = top.order(g, -1);
    let top = top.masked(out.reflection);
    let (leg_f, leg_len) = packet::crossing(nv, ug2, w);
    let r_face = packet::reflectance(nv, f64x4::ONE, ug2);
    let r_film = packet::reflectance(f64x4::splat(g.n_film), f64x4::ONE, ug2);
    let toward_back = top.reversed().undiffracted(g, None);
    let toward_front = top.undiffracted(g, Some(out.eta));
    let refl = out.reflection.to_bitmask();
    let lane = |v: f64x4, i: usize| v.as_array()[i];
    let pair = |v: &[f64x4; 2], i: usize| [lane(v[0], i), lane(v[1], i)];
    std::array::from_fn(|i| Prepared {
        n_g: n_g[i],
        alpha: alpha[i],
        t_face: pair(&t_face, i),
        cross_shift: u[i] * lane(cross_f, i),
        cross_t: (-alpha[i] * lane(cross_len, i)).exp(),
        // As `top_coupling`: a guided wave that exists in the glass, reflection-type order −1.
        guided: (refl >> i & 1 == 1).then(|| PreparedGuided {
            u_g: u_g[i],
            top_eta: pair(&out.eta, i),
            leg: u_g[i] * lane(leg_f, i),
            leg_t: (-alpha[i] * lane(leg_len, i)).exp(),
            r_face: pair(&r_face, i),
            r_film: pair(&r_film, i),
            toward_back: pair(&toward_back, i),
            toward_front: pair(&toward_front, i),
        }),
    })
}

/// [`trace_camera_path_until`] of the ray (lens point, unit direction, wavelength) whose film
/// quantities were [`prepare_paths`]'d: the same branches, bit for bit.
pub(crate) fn trace_prepared_until(
    wg: &Waveguide,
    display_z_mm: f64,
    limits: TraceLimits,
    ray: (DVec3, DVec3, f64),
    prepared: &Prepared,
    visit: impl FnMut(&Branch) -> ControlFlow<()>,
) -> TraceSummary {
    trace_path(
        wg,
        Kogelnik,
        display_z_mm,
        limits,
        ray,
        Some(prepared),
        visit,
    )
}

/// Where a path's film quantities come from: Kogelnik's closed form, or the RCWA tables
/// (`hoe.model = "rcwa"`, optics::rcwa::coupling) where they cover the ray. A closed set,
/// resolved at compile time ([`trace_camera_path_until`]).
trait FilmTables: Copy {
    /// The tables' values for one ray, per grating (nothing for Kogelnik).
    type Ray: Copy;
    /// The values for the ray (u, λ) and the first `n` gratings.
    fn ray(self, n: usize, lambda_nm: f64, u: DVec2) -> Self::Ray;
    /// Grating `j`'s values, if the tables cover the ray.
    fn get(ray: &Self::Ray, j: usize) -> Option<Coupling>;
    /// The straight-through fraction of (u, +z), if some grating's table covers the ray.
    fn t0(ray: &Self::Ray) -> Option<[f64; 2]>;
}

/// Kogelnik's closed form everywhere (the default model).
#[derive(Clone, Copy)]
struct Kogelnik;

impl FilmTables for Kogelnik {
    type Ray = ();
    #[inline(always)]
    fn ray(self, _: usize, _: f64, _: DVec2) {}
    #[inline(always)]
    fn get(_: &(), _: usize) -> Option<Coupling> {
        None
    }
    #[inline(always)]
    fn t0(_: &()) -> Option<[f64; 2]> {
        None
    }
}

impl FilmTables for &RcwaCouplings {
    type Ray = [Option<Coupling>; MAX_GRATINGS];
    #[inline(always)]
    fn ray(self, n: usize, lambda_nm: f64, u: DVec2) -> Self::Ray {
        let mut c = [None; MAX_GRATINGS];
        for (j, c) in c.iter_mut().enumerate().take(n) {
            *c = self.lookup(j, lambda_nm, u);
        }
        c
    }
    #[inline(always)]
    fn get(ray: &Self::Ray, j: usize) -> Option<Coupling> {
        ray[j]
    }
    #[inline(always)]
    fn t0(ray: &Self::Ray) -> Option<[f64; 2]> {
        ray.iter().flatten().next().map(|c| c.t0)
    }
}

/// [`trace_camera_path_until`] with the film model `tables`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn trace_path<T: FilmTables>(
    wg: &Waveguide,
    tables: T,
    display_z_mm: f64,
    limits: TraceLimits,
    (origin, dir, lambda_nm): (DVec3, DVec3, f64),
    pre: Option<&Prepared>,
    mut visit: impl FnMut(&Branch) -> ControlFlow<()>,
) -> TraceSummary {
    let w = wg.thickness_mm;
    let (n_g, alpha) = match pre {
        Some(p) => (p.n_g, p.alpha),
        None => (wg.n_glass(lambda_nm), wg.absorption_per_mm(lambda_nm)),
    };
    let gratings = &wg.gratings;
    let mut summary = TraceSummary {
        n_glass: n_g,
        ..Default::default()
    };
    if dir.z >= 0.0 || origin.z <= w {
        return summary;
    }
    // Physical light travels along −dir: its tangential direction cosines in air.
    let u = -dir.truncate();
    let p_back = origin.truncate() + dir.truncate() * ((origin.z - w) / -dir.z);
    let t_face = pre.map_or_else(|| transmittance(1.0, n_g, u), |p| p.t_face);
    // With RCWA tables (`hoe.model = "rcwa"`): every grating's film quantities for this ray,
    // where the tables cover it (optics::rcwa::coupling).
    let ray = tables.ray(gratings.len(), lambda_nm, u);
    let film_t0 = || film_t0::<T>(&ray, gratings, u, lambda_nm);
    let mut wt = t_face;
    if wg.bottom.contains(p_back) {
        wt = mul(wt, film_t0());
    }
    let (cross_shift, cross_t) = match pre {
        Some(p) => (p.cross_shift, p.cross_t),
        None => (
            lateral_shift(u, n_g, w),
            (-alpha * path_length(u, n_g, w)).exp(),
        ),
    };
    wt = scale(wt, cross_t);
    let p_top = p_back - cross_shift;
    let air_shift = lateral_shift(u, 1.0, -display_z_mm);
    let direct = |p: DVec2, weight: [f64; 2]| Branch {
        kind: BranchKind::Direct,
        bottom_contact_mm: None,
        exit_point_mm: p,
        object_point_mm: p - air_shift,
        weight,
        contact: 0,
        grating: 0,
    };
    if !wg.top.contains(p_top) {
        let _ = visit(&direct(p_top, mul(wt, t_face)));
        return summary;
    }
    if !wg.covered {
        let straight = mul(film_t0(), t_face);
        if visit(&direct(p_top, mul(wt, straight))).is_break() {
            return summary;
        }
    }
    // Out-coupling at the top vHOE, once per grating j: guided u_g = u − (λ/2π)K_j,t
    // (travelling −z) → u (order −1 of grating j). Each grating's guided wave is its own
    // zig-zag and its own replicas (grating, contact).
    let ctx: PathContext<T> = PathContext {
        wg,
        limits,
        lambda_nm,
        u,
        n_g,
        alpha,
        wt,
        t_face,
        cross_shift,
        cross_t,
        p_top,
        air_shift,
        ray: &ray,
        pre: pre.and_then(|p| p.guided.as_ref()),
    };
    if let Some(p) = pre {
        // Prepared: the top coupling and the guided wave's quantities are the packet's.
        if let Some(pg) = p.guided {
            let top = TopCoupling {
                u_g: pg.u_g,
                wave: None,
                eta: pg.top_eta,
                rcwa: None,
            };
            let _ = trace_guided(&ctx, 0, top, &mut summary, &mut visit);
        }
        return summary;
    }
    if gratings.len() == 1 {
        // The single-grating film: no arrays, the path as it always was.
        if let Some(top) = top_coupling(&ctx, 0) {
            let _ = trace_guided(&ctx, 0, top, &mut summary, &mut visit);
        }
        return summary;
    }
    let mut tops = [None; MAX_GRATINGS];
    for (j, t) in tops.iter_mut().enumerate().take(gratings.len()) {
        *t = top_coupling(&ctx, j);
    }
    // Independent gratings (optics::multiplex): should two be near Bragg for the same ray,
    // their out-coupled shares are scaled to sum to at most 1 (energy conservation).
    for p in 0..2 {
        let sum: f64 = tops.iter().flatten().map(|t| t.eta[p]).sum();
        if sum > 1.0 {
            tops.iter_mut().flatten().for_each(|t| t.eta[p] /= sum);
        }
    }
    for (j, top) in tops.iter().enumerate().take(gratings.len()) {
        if let Some(top) = *top {
            if trace_guided(&ctx, j, top, &mut summary, &mut visit).is_break() {
                break;
            }
        }
    }
    summary
}

/// The film's straight-through fraction [TE, TM] of the camera ray's wave (u, +z): from the RCWA
/// tables where they cover the ray, else Kogelnik's. (Recomputed at each use: caching it in a
/// `OnceCell` made the paper render 3 % slower, paired benchmark.)
#[inline(always)]
fn film_t0<T: FilmTables>(
    ray: &T::Ray,
    gratings: &crate::optics::multiplex::GratingSet,
    u: DVec2,
    lambda_nm: f64,
) -> [f64; 2] {
    match T::t0(ray) {
        Some(t) => t,
        None => gratings.undiffracted(u, 1.0, lambda_nm),
    }
}

/// What one path's guided waves share: the camera ray's quantities up to the top vHOE.
struct PathContext<'a, T: FilmTables> {
    wg: &'a Waveguide,
    limits: TraceLimits,
    lambda_nm: f64,
    /// The camera ray's tangential direction cosines in air (physical light).
    u: DVec2,
    n_g: f64,
    alpha: f64,
    /// Weight [TE, TM] arriving at the top vHOE.
    wt: [f64; 2],
    t_face: [f64; 2],
    cross_shift: DVec2,
    cross_t: f64,
    p_top: DVec2,
    air_shift: DVec2,
    /// The tables' film quantities for this ray (nothing for Kogelnik).
    ray: &'a T::Ray,
    /// The guided wave's quantities, computed ahead ([`prepare_paths`]).
    pre: Option<&'a PreparedGuided>,
}

/// The top vHOE's out-coupling by grating `j`.
#[derive(Clone, Copy)]
struct TopCoupling {
    /// The guided wave's tangential direction cosines u_g.
    u_g: DVec2,
    /// Its incident wave travelling −z in the film (Kogelnik).
    wave: Option<crate::optics::grating::Incident>,
    /// η [TE, TM] of the out-coupling order.
    eta: [f64; 2],
    /// The film's rigorous quantities for this path (`hoe.model = "rcwa"` inside its tables).
    rcwa: Option<Coupling>,
}

/// The top vHOE's out-coupling by grating `j`, or `None` if the guided wave cannot exist or
/// the order is not reflection-type. With RCWA tables covering the path, every film quantity
/// of the path comes from them (optics::rcwa::coupling), else from Kogelnik.
#[inline(always)]
fn top_coupling<T: FilmTables>(ctx: &PathContext<T>, j: usize) -> Option<TopCoupling> {
    let gratings = &ctx.wg.gratings;
    let grating = gratings.get(j);
    let u_g = ctx.u - grating.u_shift(ctx.lambda_nm);
    if u_g.length_squared() >= ctx.n_g * ctx.n_g {
        return None;
    }
    if let Some(c) = T::get(ctx.ray, j) {
        return Some(TopCoupling {
            u_g,
            wave: None,
            eta: c.eta_in,
            rcwa: Some(c),
        });
    }
    // Only a reflection-type order sends the guided light back toward the camera (+z); where
    // the same order is transmission-type (far off Bragg) it leaves toward the user instead.
    let top_wave = gratings.incident(u_g, -1.0, ctx.lambda_nm);
    top_wave
        .and_then(|w| w.order(grating, -1))
        .filter(|d| d.reflection)
        .map(|d| TopCoupling {
            u_g,
            wave: top_wave,
            eta: d.eta,
            rcwa: None,
        })
}

/// Traces grating `j`'s guided wave (out-coupled at the top vHOE with `top`) down the plate,
/// visiting its replicas; `Break` if `visit` stopped the path.
///
/// Longer than the project's ~120-line guide on purpose: it is the zig-zag loop of the hot
/// path (one iteration per plate contact: face reflection, bottom-vHOE split, replica weight,
/// truncation), inlined into every caller, with the guided wave's state carried across
/// contacts; the per-contact physics is in the grating and interface functions it calls.
#[inline(always)]
fn trace_guided<T: FilmTables>(
    ctx: &PathContext<T>,
    j: usize,
    top: TopCoupling,
    summary: &mut TraceSummary,
    visit: &mut impl FnMut(&Branch) -> ControlFlow<()>,
) -> ControlFlow<()> {
    let PathContext {
        wg,
        limits,
        lambda_nm,
        u,
        n_g,
        alpha,
        wt,
        t_face,
        cross_shift,
        cross_t,
        p_top,
        air_shift,
        ray,
        pre,
    } = *ctx;
    let TopCoupling {
        u_g,
        wave: top_wave,
        eta: top_eta,
        rcwa,
    } = top;
    let w = wg.thickness_mm;
    let gratings = &wg.gratings;
    let grating = gratings.get(j);
    if summary.guided_u == DVec2::ZERO {
        summary.guided_u = u_g;
    }
    let mut g = mul(wt, top_eta);
    // In-coupling efficiency u → u_g (order +1), the same for every contact of this path; by
    // reciprocity it equals the out-coupling efficiency when the film is lossless.
    // (Both orders are reflection-type together: the on-shell conditions coincide.)
    let eta_in = if let Some(c) = rcwa {
        c.eta_in
    } else if grating.alpha0_per_nm == 0.0 {
        top_eta
    } else {
        grating
            .diffract(u, 1.0, lambda_nm, 1)
            .filter(|d| d.reflection)
            .map_or([0.0, 0.0], |d| d.eta)
    };
    let (leg, leg_t, r_face, r_film) = match pre {
        Some(p) => (p.leg, p.leg_t, p.r_face, p.r_film),
        None => (
            lateral_shift(u_g, n_g, w),
            (-alpha * path_length(u_g, n_g, w)).exp(),
            reflectance(n_g, 1.0, u_g),
            reflectance(gratings.film().n_film, 1.0, u_g),
        ),
    };
    // Two-pass factors at a vHOE contact (docs/physics.md §2.3): the guided wave crosses the film
    // toward the air face ("up" = toward the face it is about to reflect from) and back. The
    // wave travelling −z is the one the top vHOE out-couples (order −1 of grating j,
    // `top_eta`), the same at every contact; at the back face the wave toward the air face
    // travels +z and vice versa, so both faces see the same pair of passes in opposite order.
    // Every grating's orders leave the guided wave (a cross-grating order leaves at another
    // angle, not toward this pixel: lost, like other stray orders).
    let (toward_back, toward_front) = match (rcwa, pre) {
        (Some(c), _) => (c.t0_guided_up, c.t0_guided_down),
        (None, Some(p)) => (p.toward_back, p.toward_front),
        (None, None) => (
            gratings.undiffracted_from(top_wave.map(|w| w.reversed()), u_g, None),
            gratings.undiffracted_from(top_wave, u_g, Some((j, -1, top_eta))),
        ),
    };
    let cont_bottom = mul(mul(toward_back, r_film), toward_front);
    let cont_top = if wg.covered && wg.cover_frustrates_tir {
        [0.0, 0.0]
    } else {
        cont_bottom
    };
    let exit_t = scale(t_face, cross_t);
    let mut replica = 0u32;
    let mut p = p_top;
    let mut contact = 0u32;
    loop {
        if contact >= limits.max_contacts {
            summary.hit_max_contacts = true;
            summary.truncated_weight = summary.truncated_weight.max(g[0].max(g[1]));
            break;
        }
        contact += 1;
        p -= leg;
        g = scale(g, leg_t);
        if contact % 2 == 1 {
            // Back face.
            if wg.bottom.contains(p) {
                let entry = p - cross_shift;
                let mut wb = mul(mul(g, eta_in), exit_t);
                if wg.top.contains(entry) {
                    wb = if wg.covered {
                        [0.0, 0.0]
                    } else {
                        mul(wb, film_t0::<T>(ray, gratings, u, lambda_nm))
                    };
                }
                let flow = visit(&Branch {
                    kind: BranchKind::Replica(replica),
                    bottom_contact_mm: Some(p),
                    exit_point_mm: entry,
                    object_point_mm: entry - air_shift,
                    weight: wb,
                    contact,
                    grating: j as u32,
                });
                if flow.is_break() {
                    summary.contacts += contact;
                    return ControlFlow::Break(());
                }
                replica += 1;
                g = mul(g, cont_bottom);
            } else {
                g = mul(g, r_face);
            }
        } else if wg.top.contains(p) {
            g = mul(g, cont_top);
            summary.top_contacts += 1;
        } else {
            g = mul(g, r_face);
        }
        if !wg.bottom.reachable(p, -leg) {
            break;
        }
        if g[0].max(g[1]) < limits.min_weight {
            summary.truncated_weight = summary.truncated_weight.max(g[0].max(g[1]));
            break;
        }
    }
    summary.contacts += contact;
    ControlFlow::Continue(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A path traced from its packet-prepared quantities ([`prepare_paths`], four at a time)
    /// gives the scalar trace's branches and summary bit for bit: the paper design (covered top
    /// vHOE) and an uncovered one (straight-through branches), over random rays, wavelengths
    /// and lane fillings; films the packet does not serve are refused by [`packets_apply`].
    #[test]
    fn prepared_paths_trace_bit_for_bit() {
        let bits = |b: &Branch| {
            (
                b.kind,
                b.exit_point_mm.to_array().map(f64::to_bits),
                b.object_point_mm.to_array().map(f64::to_bits),
                b.bottom_contact_mm.map(|p| p.to_array().map(f64::to_bits)),
                b.weight.map(f64::to_bits),
                b.contact,
            )
        };
        let summary = |s: &TraceSummary| {
            (
                s.contacts,
                s.top_contacts,
                s.truncated_weight.to_bits(),
                s.hit_max_contacts,
                s.guided_u.to_array().map(f64::to_bits),
                s.n_glass.to_bits(),
            )
        };
        let mut state = 777u64;
        let mut next = || {
            state = crate::sampler::mix64(state);
            crate::sampler::to_unit(state)
        };
        let mut guided = 0;
        for over in [&[][..], &["top_hoe.covered=false"][..]] {
            let sys = crate::system::repo_system("scenes/paper-2022.toml", over);
            let wg = &sys.waveguide;
            assert!(packets_apply(wg));
            for _ in 0..2000 {
                let rays: [(DVec3, DVec3, f64); LANES] = std::array::from_fn(|_| {
                    let r = sys.camera.generate_ray(
                        (next() * sys.camera.width_px as f64) as usize,
                        (next() * sys.camera.height_px as f64) as usize,
                        [next(), next()],
                        [next(), next()],
                    );
                    (r.origin, r.dir, 420.0 + 240.0 * next())
                });
                let pre = prepare_paths(wg, &rays);
                for (&(o, d, l), p) in rays.iter().zip(&pre) {
                    let (mut a, mut b) = (Vec::new(), Vec::new());
                    let z = sys.display.z_mm;
                    let sa = trace_camera_path(wg, z, sys.limits, o, d, l, |x| a.push(bits(x)));
                    let sb = trace_prepared_until(wg, z, sys.limits, (o, d, l), p, |x| {
                        b.push(bits(x));
                        ControlFlow::Continue(())
                    });
                    assert_eq!(a, b, "{o} {d} {l}");
                    assert_eq!(summary(&sa), summary(&sb));
                    guided += usize::from(a.len() > 1);
                }
            }
        }
        assert!(guided > 1000, "{guided}");
        let lossy = crate::system::repo_system(
            "scenes/paper-2022.toml",
            &["hoe.amplitude_absorption_per_mm=0.1"],
        );
        assert!(!packets_apply(&lossy.waveguide));
        let two = crate::system::repo_system("scenes/two-grating.toml", &[]);
        assert!(!packets_apply(&two.waveguide));
    }

    /// A two-grating film (scenes/two-grating.toml, here with strong gratings n1 = 0.03 each
    /// so that both couple a lot): over random camera rays and wavelengths the branches carry
    /// at most the light that entered (Σ weights ≤ 1 per polarisation), both gratings' replicas
    /// occur, and no two branches of a path share a replica key.
    #[test]
    fn two_gratings_conserve_energy_and_keep_replicas_apart() {
        let sys = crate::system::repo_system(
            "scenes/two-grating.toml",
            &[
                "hoe.grating.0.index_modulation=0.03",
                "hoe.grating.1.index_modulation=0.03",
            ],
        );
        let mut seen = [0usize; 2];
        let mut state = 12345u64;
        let mut next = || {
            state = crate::sampler::mix64(state);
            crate::sampler::to_unit(state)
        };
        for _ in 0..4000 {
            let ray = sys.camera.generate_ray(
                (next() * sys.camera.width_px as f64) as usize,
                (next() * sys.camera.height_px as f64) as usize,
                [next(), next()],
                [next(), next()],
            );
            let lam = 420.0 + 180.0 * next();
            let mut sum = [0.0, 0.0];
            let mut keys = Vec::new();
            trace_camera_path(
                &sys.waveguide,
                sys.display.z_mm,
                sys.limits,
                ray.origin,
                ray.dir,
                lam,
                |b| {
                    sum[0] += b.weight[0];
                    sum[1] += b.weight[1];
                    if let BranchKind::Replica(_) = b.kind {
                        keys.push(b.replica_key());
                        if b.weight[0] > 1e-3 {
                            seen[b.grating as usize] += 1;
                        }
                    }
                },
            );
            assert!(
                sum[0] <= 1.0 + 1e-12 && sum[1] <= 1.0 + 1e-12,
                "{sum:?} at {lam} nm"
            );
            let n = keys.len();
            keys.sort_unstable();
            keys.dedup();
            assert_eq!(keys.len(), n, "replica keys collide");
        }
        assert!(seen[0] > 100 && seen[1] > 100, "{seen:?}");
        assert_eq!(replica_key(0, 7), 7);
        assert_ne!(replica_key(1, 7), replica_key(0, 7));
    }
}
