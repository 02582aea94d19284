//! Every path light can take through the plate: a branching tracer of the camera's importance.
//!
//! Model. A camera ray is followed from the lens into the plate as if it were light (the
//! adjoint, or importance, ray), and at every interaction **every** outgoing wave is a branch:
//! - at a face, Fresnel reflection and transmission (s and p, [`reflectance`]; R = 1 under
//!   total internal reflection), from the glass side or from the air side;
//! - at a film (the top vHOE on the front face, the bottom vHOE on the back face, each carrying
//!   every grating of the film), orders −1 and +1 of **every** grating (Kogelnik's two-wave
//!   efficiencies, `optics::grating`; directions by k-closure, reflection- or transmission-type
//!   as the closure gives them), so grating j's guided wave diffracted by grating k
//!   (cross-coupling) is a branch like any other, and the zero order (1 − Σ η) times the film's
//!   mean absorption;
//! - a film is the thin layer on the glass side of its face, index-matched to the glass (as in
//!   the designed-path tracer: glass–film reflections are neglected); a face's air interface
//!   has the glass index on its inner side. Light reflected at the air interface crosses the
//!   film again (the second pass), so multiple interactions with a film are traced;
//! - the cover of the top vHOE absorbs what leaves the front face there, and all of it when it
//!   frustrates total internal reflection;
//! - light that leaves the front face travels to the display plane (its radiance is read
//!   there); light that leaves the back face travels to the display behind the screen where
//!   the scene has one and its emitting area is, else to the camera side's sink
//!   (`CameraSide`: no source there);
//! - the plate's edges (when the plate is bounded) absorb, or, polished, reflect specularly:
//!   the normal component of the direction flips, with the Fresnel (or total) reflectance of
//!   the angle on the edge face, s and p kept in the faces' basis (an approximation: the edge's
//!   plane of incidence differs); on an absorbing or unbounded plate a guided wave (|u| ≥ 1,
//!   trapped by total internal reflection) that can reach neither film any more is absorbed at
//!   the edge (`Edge`); a wave that is not trapped is followed until it leaves;
//! - film haze (optional): a fraction of the light crossing a film undiffracted is scattered
//!   into a Henyey–Greenstein lobe about its direction, one direction drawn per crossing (the
//!   branch carries the fraction: the lobe's pdf cancels its phase function), forward through
//!   the film or back to the side it came from.
//!
//! Reciprocity makes the importance ray's weights the light's: for the reversed waves the
//! Fresnel coefficients are equal, and Kogelnik's efficiency of order m from wave A into B
//! equals that of the reversed B into the reversed A (the dephasing |Δk_z| and the product of
//! the obliquity factors are unchanged; a film's undiffracted fraction of a wave equals that of
//! its reversal). The importance ray's order m is the light's order m. So the designed paths
//! this tracer finds carry the designed-path tracer's weights (`stscam_tracer::trace`), to
//! rounding, which the tests check.
//!
//! Energy closes at every interaction by construction (R + T = 1, Σ η + zero + absorbed = 1;
//! when two gratings' orders sum past 1 they are scaled to 1, as the designed tracer scales
//! the top vHOE's out-coupled shares), so per camera ray the weights reaching the display and
//! every [`Sink`] sum to 1. Branches whose weight falls below a threshold play Russian
//! roulette (survive with probability w/threshold, weight divided by it: unbiased); what dies
//! is accounted as `Roulette`, what exceeds the event limit as `Truncated` (and, for checks
//! only, what falls below a deterministic cutoff as `Cutoff`).
//!
//! Sources: Fresnel equations (Born & Wolf, *Principles of Optics*, §1.5); H. Kogelnik, Bell
//! Syst. Tech. J. 48, 2909 (1969); Russian roulette and splitting: J. Spanier & E. M. Gelbard,
//! *Monte Carlo Principles and Neutron Transport Problems* (1969), ch. 2; the reciprocity of
//! the adjoint: E. Veach, PhD thesis, Stanford 1997, ch. 3–5.

use glam::{DVec2, DVec3};

use crate::optics::interface::{lateral_shift, path_length, reflectance};
use crate::optics::multiplex::MAX_GRATINGS;
use crate::sampler::PathRng;
use crate::tracer::waveguide::{Rect, Waveguide};

/// A face of the plate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Face {
    /// The user-side face (z = 0), carrying the top vHOE.
    Front,
    /// The camera-side face (z = w), carrying the bottom vHOE.
    Back,
}

impl Face {
    /// The other face.
    #[inline]
    pub fn other(self) -> Face {
        match self {
            Face::Front => Face::Back,
            Face::Back => Face::Front,
        }
    }

    /// The face's name in path classes (`front`, `back`).
    pub fn name(self) -> &'static str {
        match self {
            Face::Front => "front",
            Face::Back => "back",
        }
    }

    /// The vHOE on this face in path classes (`top`, `bottom`).
    pub fn film_name(self) -> &'static str {
        match self {
            Face::Front => "top",
            Face::Back => "bottom",
        }
    }

    /// The sign of z along which a wave travels when it leaves the plate through this face
    /// (the user side is z < 0).
    #[inline]
    fn outward(self) -> f64 {
        match self {
            Face::Front => -1.0,
            Face::Back => 1.0,
        }
    }
}

/// An edge of the plate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Side {
    /// x = minimum.
    Left,
    /// x = maximum.
    Right,
    /// y = minimum.
    Bottom,
    /// y = maximum.
    Top,
}

impl Side {
    /// The edge's name in path classes.
    pub fn name(self) -> &'static str {
        match self {
            Side::Left => "left",
            Side::Right => "right",
            Side::Bottom => "bottom",
            Side::Top => "top",
        }
    }
}

/// The plate's edges: the plate's extent (x, y) and whether the edges reflect.
#[derive(Clone, Copy, Debug)]
pub struct PlateEdges {
    /// The plate's extent.
    pub extent: Rect,
    /// Polished (specular: Fresnel or total reflection) rather than absorbing.
    pub polished: bool,
}

/// One interaction of a path.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Event {
    /// Fresnel transmission through a face (either way).
    T(Face),
    /// Fresnel reflection at a face (partial: not total), from either side.
    R(Face),
    /// Total internal reflection at a face.
    Tir(Face),
    /// Reflection at a polished edge of the plate (Fresnel or total).
    Edge(Side),
    /// Scattering by the haze of the film on a face (front: top vHOE; back: bottom vHOE).
    Scatter(Face),
    /// Diffraction by grating `grating` (0-based, scene order) of the film on `face` into
    /// `order` (−1 or +1, the light's order).
    D {
        /// The film's face (front: top vHOE; back: bottom vHOE).
        face: Face,
        /// The grating's index in the film.
        grating: u8,
        /// The order.
        order: i8,
        /// True for a transmission-type order (it leaves the film through the side opposite
        /// to the one it entered; a reflection hologram's designed orders are reflection-type).
        transmitted: bool,
    },
}

/// Where weight that does not reach the display goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sink {
    /// Left the back face toward the camera side (no source there in this scene).
    CameraSide,
    /// Absorbed by the top vHOE's cover.
    Cover,
    /// A trapped wave that can reach neither film: absorbed at the plate's edge.
    Edge,
    /// Absorbed in the glass or a film.
    Absorbed,
    /// Removed by Russian roulette (its weight before the roulette).
    Roulette,
    /// Stopped at the event limit.
    Truncated,
    /// Below the cutoff weight (a deterministic, biased stop: for checks that need every
    /// weight accounted without roulette).
    Cutoff,
}

/// Number of [`Sink`] kinds.
pub const SINKS: usize = 7;

impl Sink {
    /// Every sink, in ledger order.
    pub const ALL: [Sink; SINKS] = [
        Sink::CameraSide,
        Sink::Cover,
        Sink::Edge,
        Sink::Absorbed,
        Sink::Roulette,
        Sink::Truncated,
        Sink::Cutoff,
    ];

    /// The sink's name (snake case).
    pub fn name(self) -> &'static str {
        match self {
            Sink::CameraSide => "camera_side",
            Sink::Cover => "cover",
            Sink::Edge => "edge",
            Sink::Absorbed => "absorbed",
            Sink::Roulette => "roulette",
            Sink::Truncated => "truncated",
            Sink::Cutoff => "cutoff",
        }
    }
}

/// Settings of the branching tracer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathSettings {
    /// Branches whose larger polarisation weight falls below this play Russian roulette
    /// (0: never).
    pub roulette_threshold: f64,
    /// Branches whose larger polarisation weight falls below this are stopped without
    /// roulette (biased; 0: never, the default).
    pub cutoff_weight: f64,
    /// At most this many events per path.
    pub max_events: usize,
}

/// The default roulette threshold: a branch below 10⁻⁴ of the camera ray's weight survives
/// with probability w/10⁻⁴.
pub const DEFAULT_ROULETTE_THRESHOLD: f64 = 1e-4;

/// The default event limit (a guided wave makes about 2 events per millimetre of plate it
/// crosses at the paper's design; 400 covers every reachable contact of the paper's films).
pub const DEFAULT_MAX_EVENTS: usize = 400;

impl Default for PathSettings {
    fn default() -> Self {
        PathSettings {
            roulette_threshold: DEFAULT_ROULETTE_THRESHOLD,
            cutoff_weight: 0.0,
            max_events: DEFAULT_MAX_EVENTS,
        }
    }
}

/// Where a branch that left the plate meets a source.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Source {
    /// The display in front of the screen (the user side).
    Display,
    /// The display behind the screen (the camera side).
    BehindDisplay,
}

/// The display behind the screen, as the tracer needs it: a plane `distance_mm` behind the
/// back face, its emitting `area` (x, y) on that plane.
#[derive(Clone, Copy, Debug)]
pub struct BehindPlane {
    /// Distance behind the back face, mm.
    pub distance_mm: f64,
    /// Emitting area on the plane.
    pub area: Rect,
}

/// What a path can meet besides the designed film: the display plane in front
/// (z = `display_z_mm` < 0), optionally the display behind the screen, the plate's edges (none:
/// an unbounded plate whose trapped waves are absorbed once they can reach neither film) and
/// the films' haze.
#[derive(Clone, Copy, Debug)]
pub struct Surround {
    /// z of the front display's plane, mm (< 0).
    pub display_z_mm: f64,
    /// The display behind the screen, if any.
    pub behind: Option<BehindPlane>,
    /// The plate's edges, if it is bounded.
    pub edges: Option<PlateEdges>,
    /// The films' haze, if any.
    pub haze: Option<Haze>,
}

/// The films' haze: the fraction of the undiffracted light a film crossing scatters, into a
/// Henyey–Greenstein lobe of asymmetry `asymmetry` about the light's direction.
#[derive(Clone, Copy, Debug)]
pub struct Haze {
    /// Fraction scattered per crossing.
    pub fraction: f64,
    /// The lobe's asymmetry g.
    pub asymmetry: f64,
}

impl Surround {
    /// The front display only, an unbounded plate.
    pub fn front(display_z_mm: f64) -> Surround {
        Surround {
            display_z_mm,
            behind: None,
            edges: None,
            haze: None,
        }
    }
}

/// A branch that left the plate toward a source.
#[derive(Clone, Copy, Debug)]
pub struct Exit<'a> {
    /// The source it meets.
    pub source: Source,
    /// The path's events, in order (the last is `T(front)` toward the display, `T(back)` or
    /// `R(back)` toward the display behind the screen).
    pub events: &'a [Event],
    /// Energy fraction [TE, TM] of the camera ray carried to the display.
    pub weight: [f64; 2],
    /// Where it leaves the plate (x, y), mm.
    pub exit_point_mm: DVec2,
    /// Where it meets the source's plane (x, y), mm.
    pub object_point_mm: DVec2,
}

/// Weight [TE, TM] of one camera ray that went to each sink.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Ledger {
    /// Per sink ([`Sink::ALL`] order), [TE, TM].
    pub sinks: [[f64; 2]; SINKS],
    /// Branches created.
    pub branches: u64,
}

impl Ledger {
    #[inline]
    fn add(&mut self, sink: Sink, w: [f64; 2]) {
        let s = &mut self.sinks[sink as usize];
        s[0] += w[0];
        s[1] += w[1];
    }

    /// The weight [TE, TM] that went to `sink`.
    pub fn get(&self, sink: Sink) -> [f64; 2] {
        self.sinks[sink as usize]
    }

    /// Adds another ledger.
    pub fn merge(&mut self, o: &Ledger) {
        for (a, b) in self.sinks.iter_mut().zip(&o.sinks) {
            a[0] += b[0];
            a[1] += b[1];
        }
        self.branches += o.branches;
    }
}

/// Where a branch is, and which way it is going.
#[derive(Clone, Copy, Debug)]
enum At {
    /// In air, arriving at `face` (the camera ray at the back face).
    FromAir(Face),
    /// In glass, having left `face` (or a polished edge on the way), crossing to the other
    /// face: the fraction of the crossing left (1 from a face).
    Crossing(Face, f64),
    /// In glass, arriving at `face` (its film, if any, then the air interface).
    FromGlass(Face),
    /// Inside `face`'s layers, meeting the air interface from inside.
    InterfaceFromInside(Face),
    /// Entering the film of `face`, from the glass side if `from_glass`, else from the air
    /// interface.
    Film(Face, bool),
}

#[derive(Clone, Copy, Debug)]
struct Node {
    at: At,
    p: DVec2,
    /// The importance ray's tangential direction cosines (n·ŝ_t), conserved at the faces.
    v: DVec2,
    w: [f64; 2],
    /// Length of the path's event list before this node's own event (the list is shared,
    /// depth-first).
    depth: usize,
    /// The event that made this node, if any.
    event: Option<Event>,
}

/// A branch produced by one interaction: where it goes, its direction cosines, weight and
/// event.
type Child = (At, DVec2, DVec2, [f64; 2], Option<Event>);

/// A film's split of one wave: each order (direction cosines, reflection-type, efficiency
/// [TE, TM] after the multiplex scaling, grating, order) and the undiffracted remainder with
/// the film's mean transmission; `None` orders do not propagate. `enters` is false for a wave
/// that cannot enter the film (it crosses undiffracted).
#[derive(Clone, Copy, Debug)]
struct FilmSplit {
    enters: bool,
    orders: [Option<SplitOrder>; 2 * MAX_GRATINGS],
    rest: [f64; 2],
    att: f64,
}

/// One order of a [`FilmSplit`]: direction cosines, reflection-type, efficiency [TE, TM],
/// grating, order.
type SplitOrder = (DVec2, bool, [f64; 2], u8, i8);

/// What a path computes once per distinct wave (its direction cosines; the zig-zag of a guided
/// wave meets the same wave at every contact): the glass crossing, the inner Fresnel
/// reflectance and the film's split per direction along z. Entries hold exactly the values the
/// computation gives, so a path traces the same with or without them.
#[derive(Clone, Copy, Debug)]
struct WaveData {
    key: [u64; 2],
    cross: Option<(DVec2, f64)>,
    r_inside: Option<[f64; 2]>,
    film: [Option<FilmSplit>; 2],
}

/// Distinct waves a path remembers (later ones are computed each time).
const WAVE_MEMO: usize = 48;

/// The per-path memo of [`WaveData`] (linear search: a path has a few dozen waves).
#[derive(Default)]
struct WaveMemo {
    entries: Vec<WaveData>,
    last: usize,
}

impl WaveMemo {
    /// The entry of wave `v`, created if there is room.
    #[inline]
    fn entry(&mut self, v: DVec2) -> Option<&mut WaveData> {
        let key = [v.x.to_bits(), v.y.to_bits()];
        // The last wave asked for is the likeliest (a zig-zag asks for one wave in turn).
        if self.entries.get(self.last).is_some_and(|e| e.key == key) {
            return Some(&mut self.entries[self.last]);
        }
        if let Some(i) = self.entries.iter().position(|e| e.key == key) {
            self.last = i;
            return Some(&mut self.entries[i]);
        }
        self.last = self.entries.len();
        if self.entries.len() >= WAVE_MEMO {
            return None;
        }
        self.entries.push(WaveData {
            key,
            cross: None,
            r_inside: None,
            film: [None; 2],
        });
        self.entries.last_mut()
    }
}

/// What one path's branches share.
struct Ctx<'a> {
    wg: &'a Waveguide,
    lambda_nm: f64,
    n_g: f64,
    alpha: f64,
    surround: Surround,
}

/// Traces every path of the camera ray (lens point `origin`, unit `dir` toward the screen) at
/// `lambda_nm`, calling `visit` for every branch that reaches a source (the display plane in
/// front, the display behind the screen), and returns where the rest went. `rng` draws the roulette's numbers
/// (depth-first order, so the same ray and seed give the same branches).
pub fn trace_all_paths(
    wg: &Waveguide,
    surround: Surround,
    set: PathSettings,
    (origin, dir, lambda_nm): (DVec3, DVec3, f64),
    rng: &mut PathRng,
    mut visit: impl FnMut(&Exit),
) -> Ledger {
    let mut ledger = Ledger::default();
    let w = wg.thickness_mm;
    if dir.z >= 0.0 || origin.z <= w {
        return ledger;
    }
    let ctx = Ctx {
        wg,
        lambda_nm,
        n_g: wg.n_glass(lambda_nm),
        alpha: wg.absorption_per_mm(lambda_nm),
        surround,
    };
    let p_back = origin.truncate() + dir.truncate() * ((origin.z - w) / -dir.z);
    let mut events: Vec<Event> = Vec::with_capacity(64);
    let mut stack = vec![Node {
        at: At::FromAir(Face::Back),
        p: p_back,
        // The importance ray's direction cosines in air (the light's are the opposite).
        v: dir.truncate(),
        w: [1.0, 1.0],
        depth: 0,
        event: None,
    }];
    let mut children: Vec<Child> = Vec::with_capacity(16);
    let mut memo = WaveMemo::default();
    while let Some(node) = stack.pop() {
        events.truncate(node.depth);
        events.extend(node.event);
        if events.len() > set.max_events {
            ledger.add(Sink::Truncated, node.w);
            continue;
        }
        children.clear();
        ctx.step(
            &node,
            (&mut memo, &mut *rng),
            &mut children,
            &mut ledger,
            &mut events,
            &mut visit,
        );
        // Depth-first, children in the order produced (pushed reversed).
        for &(at, p, v, w, event) in children.iter().rev() {
            ledger.branches += 1;
            let big = w[0].max(w[1]);
            if big.is_nan() || big <= 0.0 {
                continue;
            }
            let mut w = w;
            if big < set.cutoff_weight {
                ledger.add(Sink::Cutoff, w);
                continue;
            }
            if big < set.roulette_threshold {
                let q = big / set.roulette_threshold;
                if rng.uniform() >= q {
                    ledger.add(Sink::Roulette, w);
                    continue;
                }
                w = [w[0] / q, w[1] / q];
            }
            stack.push(Node {
                at,
                p,
                v,
                w,
                depth: events.len(),
                event,
            });
        }
    }
    ledger
}

/// Where the segment from `p` (inside `extent`, edges included) by `seg` first leaves it: the
/// edge and the fraction of the segment there, if it does.
fn edge_hit(extent: &Rect, p: DVec2, seg: DVec2) -> Option<(Side, f64)> {
    let mut best: Option<(Side, f64)> = None;
    let mut consider = |side: Side, bound: f64, start: f64, d: f64| {
        if d == 0.0 {
            return;
        }
        let at = (bound - start) / d;
        // Leaving through this edge within the segment (not the edge it stands on).
        if at > 1e-12 && at < 1.0 && best.is_none_or(|(_, b)| at < b) {
            best = Some((side, at));
        }
    };
    if seg.x > 0.0 {
        consider(Side::Right, extent.max.x, p.x, seg.x);
    } else {
        consider(Side::Left, extent.min.x, p.x, seg.x);
    }
    if seg.y > 0.0 {
        consider(Side::Top, extent.max.y, p.y, seg.y);
    } else {
        consider(Side::Bottom, extent.min.y, p.y, seg.y);
    }
    best
}

#[inline]
fn mul(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] * b[0], a[1] * b[1]]
}

#[inline]
fn one_minus(a: [f64; 2]) -> [f64; 2] {
    [1.0 - a[0], 1.0 - a[1]]
}

impl Ctx<'_> {
    /// The film on `face` at `p`, if any.
    #[inline]
    fn film_at(&self, face: Face, p: DVec2) -> bool {
        let r: &Rect = match face {
            Face::Front => &self.wg.top,
            Face::Back => &self.wg.bottom,
        };
        r.contains(p)
    }

    /// One interaction of `node`: its branches into `out`, its losses into `ledger`, and a
    /// branch that reaches the display to `visit`.
    fn step(
        &self,
        node: &Node,
        (memo, rng): (&mut WaveMemo, &mut PathRng),
        out: &mut Vec<Child>,
        ledger: &mut Ledger,
        events: &mut Vec<Event>,
        visit: &mut impl FnMut(&Exit),
    ) {
        let Node { at, p, v, w, .. } = *node;
        match at {
            At::FromAir(face) => {
                // Air → glass (the film, if any, lies behind the interface).
                let r = reflectance(1.0, self.n_g, v);
                let t = one_minus(r);
                // Reflected back into the air on the camera side.
                self.camera_side(p, v, mul(w, r), Event::R(face), ledger, events, visit);
                let next = if self.film_at(face, p) {
                    At::Film(face, false)
                } else {
                    At::Crossing(face, 1.0)
                };
                out.push((next, p, v, mul(w, t), Some(Event::T(face))));
            }
            At::Crossing(face, frac) => {
                let (n, thick) = (self.n_g, self.wg.thickness_mm);
                if v.length_squared() >= n * n {
                    // Cannot exist in the glass (never produced; kept for safety).
                    ledger.add(Sink::Absorbed, w);
                    return;
                }
                let compute = || {
                    (
                        lateral_shift(v, n, thick),
                        (-self.alpha * path_length(v, n, thick)).exp(),
                    )
                };
                let (shift, t_full) = match memo.entry(v) {
                    Some(e) => *e.cross.get_or_insert_with(compute),
                    None => compute(),
                };
                // The rest of the crossing (all of it from a face: the values as computed).
                let (seg, t) = if frac == 1.0 {
                    (shift, t_full)
                } else {
                    (shift * frac, t_full.powf(frac))
                };
                if let Some(edges) = self.surround.edges
                    && let Some((side, at)) = edge_hit(&edges.extent, p, seg)
                {
                    let t_part = t.powf(at);
                    ledger.add(
                        Sink::Absorbed,
                        [w[0] * (1.0 - t_part), w[1] * (1.0 - t_part)],
                    );
                    let w = [w[0] * t_part, w[1] * t_part];
                    if !edges.polished {
                        ledger.add(Sink::Edge, w);
                        return;
                    }
                    // Specular at the edge: the normal component of v flips; Fresnel (or total)
                    // reflection for the angle on the edge face.
                    let (c, flipped) = match side {
                        Side::Left | Side::Right => (v.x, DVec2::new(-v.x, v.y)),
                        Side::Bottom | Side::Top => (v.y, DVec2::new(v.x, -v.y)),
                    };
                    let r = reflectance(n, 1.0, DVec2::new((n * n - c * c).max(0.0).sqrt(), 0.0));
                    ledger.add(Sink::Edge, mul(w, one_minus(r)));
                    let rest = At::Crossing(face, frac * (1.0 - at));
                    out.push((
                        rest,
                        p + seg * at,
                        flipped,
                        mul(w, r),
                        Some(Event::Edge(side)),
                    ));
                    return;
                }
                let q = p + seg;
                ledger.add(Sink::Absorbed, [w[0] * (1.0 - t), w[1] * (1.0 - t)]);
                let w = [w[0] * t, w[1] * t];
                // On an absorbing or unbounded plate, a trapped wave that can reach neither film
                // goes to the plate's edge.
                let trapped = v.length_squared() >= 1.0;
                let polished = self.surround.edges.is_some_and(|e| e.polished);
                if trapped
                    && !polished
                    && !self.wg.top.reachable(q, 2.0 * shift)
                    && !self.wg.bottom.reachable(q, 2.0 * shift)
                    && !self.film_at(face.other(), q)
                {
                    ledger.add(Sink::Edge, w);
                    return;
                }
                out.push((At::FromGlass(face.other()), q, v, w, None));
            }
            At::FromGlass(face) => {
                let next = if self.film_at(face, p) {
                    At::Film(face, true)
                } else {
                    At::InterfaceFromInside(face)
                };
                out.push((next, p, v, w, None));
            }
            At::InterfaceFromInside(face) => {
                let covered = face == Face::Front && self.wg.covered && self.wg.top.contains(p);
                if covered && self.wg.cover_frustrates_tir {
                    ledger.add(Sink::Cover, w);
                    return;
                }
                let compute = || reflectance(self.n_g, 1.0, v);
                let r = match memo.entry(v) {
                    Some(e) => *e.r_inside.get_or_insert_with(compute),
                    None => compute(),
                };
                let tir = r == [1.0, 1.0];
                let back = if self.film_at(face, p) {
                    At::Film(face, false)
                } else {
                    At::Crossing(face, 1.0)
                };
                let event = if tir {
                    Event::Tir(face)
                } else {
                    Event::R(face)
                };
                out.push((back, p, v, mul(w, r), Some(event)));
                if tir {
                    return;
                }
                let t = mul(w, one_minus(r));
                match face {
                    Face::Back => self.camera_side(p, v, t, Event::T(face), ledger, events, visit),
                    Face::Front if covered => ledger.add(Sink::Cover, t),
                    Face::Front => {
                        let air = lateral_shift(v, 1.0, -self.surround.display_z_mm);
                        events.push(Event::T(Face::Front));
                        visit(&Exit {
                            source: Source::Display,
                            events,
                            weight: t,
                            exit_point_mm: p,
                            object_point_mm: p + air,
                        });
                        events.pop();
                    }
                }
            }
            At::Film(face, from_glass) => {
                self.film(face, from_glass, node, (memo, rng), out, ledger)
            }
        }
    }

    /// Weight `w` leaving the back face at `p` toward the camera side (by `event`): to the
    /// display behind the screen where its plane's emitting area is, else to the camera side's
    /// sink (no source there).
    #[allow(clippy::too_many_arguments)]
    fn camera_side(
        &self,
        p: DVec2,
        v: DVec2,
        w: [f64; 2],
        event: Event,
        ledger: &mut Ledger,
        events: &mut Vec<Event>,
        visit: &mut impl FnMut(&Exit),
    ) {
        let hit = self.surround.behind.and_then(|b| {
            let q = p + lateral_shift(v, 1.0, b.distance_mm);
            b.area.contains(q).then_some(q)
        });
        let Some(q) = hit else {
            ledger.add(Sink::CameraSide, w);
            return;
        };
        events.push(event);
        visit(&Exit {
            source: Source::BehindDisplay,
            events,
            weight: w,
            exit_point_mm: p,
            object_point_mm: q,
        });
        events.pop();
    }

    /// The film's split of the wave `v` travelling along `z_sign`: every grating's orders ±1
    /// (scaled to sum to at most 1) and the undiffracted rest.
    fn film_split(&self, v: DVec2, z_sign: f64) -> FilmSplit {
        let gratings = &self.wg.gratings;
        let mut split = FilmSplit {
            enters: false,
            orders: [None; 2 * MAX_GRATINGS],
            rest: [1.0, 1.0],
            att: 1.0,
        };
        let Some(wave) = gratings.incident(v, z_sign, self.lambda_nm) else {
            return split;
        };
        split.enters = true;
        let mut sum = [0.0f64; 2];
        for (k, g) in gratings.as_slice().iter().enumerate() {
            for (o, order) in [-1i32, 1].into_iter().enumerate() {
                if let Some(d) = wave.order(g, order) {
                    sum[0] += d.eta[0];
                    sum[1] += d.eta[1];
                    split.orders[2 * k + o] =
                        Some((d.u, d.reflection, d.eta, k as u8, order as i8));
                }
            }
        }
        // Independent gratings whose orders sum past 1 are scaled to 1 (energy conservation).
        let scale = [
            if sum[0] > 1.0 { 1.0 / sum[0] } else { 1.0 },
            if sum[1] > 1.0 { 1.0 / sum[1] } else { 1.0 },
        ];
        for (_, _, eta, _, _) in split.orders.iter_mut().flatten() {
            *eta = [eta[0] * scale[0], eta[1] * scale[1]];
        }
        split.rest = [
            (1.0 - sum[0] * scale[0]).max(0.0),
            (1.0 - sum[1] * scale[1]).max(0.0),
        ];
        split.att = gratings.film().film_attenuation(v);
        split
    }

    /// The film of `face` crossed by `node`'s wave (from the glass side if `from_glass`):
    /// every grating's orders ±1 and the zero order.
    fn film(
        &self,
        face: Face,
        from_glass: bool,
        node: &Node,
        (memo, rng): (&mut WaveMemo, &mut PathRng),
        out: &mut Vec<Child>,
        ledger: &mut Ledger,
    ) {
        let Node { p, v, w, .. } = *node;
        // The wave's direction along z inside the film.
        let z_sign = if from_glass {
            face.outward()
        } else {
            -face.outward()
        };
        let compute = || self.film_split(v, z_sign);
        let mut local = None;
        let split: &FilmSplit = match memo.entry(v) {
            Some(e) => e.film[usize::from(z_sign > 0.0)].get_or_insert_with(compute),
            None => local.insert(compute()),
        };
        // Where a wave leaving the film toward the glass or the air side goes next.
        let to_glass = At::Crossing(face, 1.0);
        let to_air = At::InterfaceFromInside(face);
        let straight = if from_glass { to_air } else { to_glass };
        if !split.enters {
            // It cannot enter the film (|u| ≥ n_film): it crosses undiffracted, as in the
            // designed tracer.
            out.push((straight, p, v, w, None));
            return;
        }
        for &(u, reflection, eta, grating, order) in split.orders.iter().flatten() {
            // A reflection-type order leaves on the side it entered.
            let at = if reflection == from_glass {
                to_glass
            } else {
                to_air
            };
            let event = Event::D {
                face,
                grating,
                order,
                transmitted: !reflection,
            };
            out.push((at, p, u, mul(w, eta), Some(event)));
        }
        let (rest, att) = (split.rest, split.att);
        ledger.add(
            Sink::Absorbed,
            [w[0] * rest[0] * (1.0 - att), w[1] * rest[1] * (1.0 - att)],
        );
        let zero = [w[0] * rest[0] * att, w[1] * rest[1] * att];
        let Some(haze) = self.surround.haze.filter(|h| h.fraction > 0.0) else {
            out.push((straight, p, v, zero, None));
            return;
        };
        // Haze: a fraction of the undiffracted light scattered into the lobe around its
        // direction (one direction drawn from the lobe: its pdf cancels the phase function).
        let n_f = self.wg.gratings.film().n_film;
        let d = crate::optics::interface::direction(v, n_f, z_sign);
        let (cos_t, phi) = sample_hg(haze.asymmetry, [rng.uniform(), rng.uniform()]);
        let s = rotate_about(d, cos_t, phi);
        let scattered = s.truncate() * n_f;
        // Forward of the film (the side the zero order leaves by) or back to the entry side.
        let at = if (s.z > 0.0) == (z_sign > 0.0) {
            straight
        } else if from_glass {
            to_glass
        } else {
            to_air
        };
        let h = haze.fraction;
        out.push((
            straight,
            p,
            v,
            [zero[0] * (1.0 - h), zero[1] * (1.0 - h)],
            None,
        ));
        out.push((
            at,
            p,
            scattered,
            [zero[0] * h, zero[1] * h],
            Some(Event::Scatter(face)),
        ));
    }
}

/// A direction drawn from the Henyey–Greenstein phase function of asymmetry `g` by inversion
/// of its cumulative distribution (L. G. Henyey & J. L. Greenstein, ApJ 93, 70 (1941); the
/// inversion as in M. Pharr et al., *Physically Based Rendering*, 4th ed., §11.3.1): the cosine
/// of the angle from the incident direction and the azimuth, from two uniform numbers.
pub fn sample_hg(g: f64, [u1, u2]: [f64; 2]) -> (f64, f64) {
    let cos_t = if g.abs() < 1e-3 {
        1.0 - 2.0 * u1
    } else {
        let sq = (1.0 - g * g) / (1.0 - g + 2.0 * g * u1);
        ((1.0 + g * g - sq * sq) / (2.0 * g)).clamp(-1.0, 1.0)
    };
    (cos_t, 2.0 * std::f64::consts::PI * u2)
}

/// The unit direction at angle acos(`cos_t`) from the unit `d`, at azimuth `phi` about it (in
/// the user side's orthonormal frame around `d`, `world::bsdf::Frame`).
fn rotate_about(d: DVec3, cos_t: f64, phi: f64) -> DVec3 {
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let local = DVec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t);
    crate::world::bsdf::Frame::from_normal(d)
        .to_world(local)
        .normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Henyey–Greenstein's cumulative distribution of μ = cos θ, written out independently of
    /// the sampler: F(μ) = (1 − g²)/(2g)·[(1 + g² − 2gμ)^(−1/2) − (1 + g)^(−1)], 1/2·(1 + μ) at
    /// g = 0.
    fn hg_cdf(g: f64, mu: f64) -> f64 {
        if g == 0.0 {
            return 0.5 * (1.0 + mu);
        }
        (1.0 - g * g) / (2.0 * g) * ((1.0 + g * g - 2.0 * g * mu).powf(-0.5) - 1.0 / (1.0 + g))
    }

    /// χ² of 200 000 draws of `sample_hg(g)` in 20 bins of μ against the distribution of `g_ref`.
    fn chi2(g: f64, g_ref: f64) -> f64 {
        let bins = 20;
        let n = 200_000;
        let mut counts = vec![0u64; bins];
        let mut rng = PathRng::new(&[42, g.to_bits()]);
        for _ in 0..n {
            let (mu, phi) = sample_hg(g, [rng.uniform(), rng.uniform()]);
            assert!((0.0..2.0 * std::f64::consts::PI).contains(&phi));
            let k = (((mu + 1.0) / 2.0 * bins as f64) as usize).min(bins - 1);
            counts[k] += 1;
        }
        (0..bins)
            .map(|k| {
                let lo = -1.0 + 2.0 * k as f64 / bins as f64;
                let hi = lo + 2.0 / bins as f64;
                let expect = n as f64 * (hg_cdf(g_ref, hi) - hg_cdf(g_ref, lo));
                (counts[k] as f64 - expect).powi(2) / expect
            })
            .sum()
    }

    /// The haze lobe's sampler draws Henyey–Greenstein: χ² over 20 bins below 45.3 (19 degrees
    /// of freedom, p = 0.0007) for g = 0.9, 0.5, 0 and −0.3; against g ± 0.05's distribution it
    /// is far above (the test can fail).
    #[test]
    fn henyey_greenstein_sampler_passes_chi_square() {
        for g in [0.9, 0.5, 0.0, -0.3] {
            let c = chi2(g, g);
            assert!(c < 45.3, "g {g}: chi2 {c}");
        }
        assert!(chi2(0.9, 0.85) > 200.0);
        assert!(chi2(-0.3, -0.25) > 100.0);
    }

    /// `rotate_about` turns by the angle asked: d·s = cos θ, |s| = 1, for any d.
    #[test]
    fn rotation_keeps_the_angle() {
        let mut rng = PathRng::new(&[7]);
        for _ in 0..1000 {
            let d = DVec3::new(
                rng.uniform() - 0.5,
                rng.uniform() - 0.5,
                rng.uniform() - 0.5,
            )
            .normalize();
            let (c, phi) = (2.0 * rng.uniform() - 1.0, 6.0 * rng.uniform());
            let s = rotate_about(d, c, phi);
            assert!((s.length() - 1.0).abs() < 1e-12 && (s.dot(d) - c).abs() < 1e-12);
        }
    }
}
