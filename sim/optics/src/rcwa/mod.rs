//! Rigorous coupled-wave analysis (RCWA, Fourier modal method) of a volume-grating film:
//! any number of superposed slanted gratings, both polarisations, conical (3-D) incidence.
//!
//! Model:
//! - Film of thickness d between two homogeneous half-spaces (index n_in on the side the light
//!   comes from, n_out beyond), permittivity ε(r) = (n + iκ + Σ_i n1_i cos(K_i·r))², with
//!   κ = α0/k0 from the amplitude absorption α0 (Kogelnik's α0 for normal passage). r is
//!   measured from the film's entrance face; K_i from the recording (as in `optics::grating`).
//! - Every K_i,t (the part in the film plane) must be parallel to one direction ê; the
//!   structure is then periodic along ê with the common period L = 2π/G, G the largest value
//!   with K_i,t·ê = p_i·G for integers p_i (the first grating's |K_t| divided by q = 1…12,
//!   ratios integral to 1e−6). Incommensurate periods are refused (no supercell approximation).
//! - Fields are expanded in 2M+1 Floquet harmonics of tangential wave vector
//!   k_t,m = k_t,inc − m·G·ê (order m: for one grating this is Kogelnik's order, σ = ρ − mK).
//!   The full-vector formulation (E_x, E_y, H_x, H_y with k_x, k_y) handles conical incidence
//!   (Moharam, Grann, Pommet & Gaylord, JOSA A 12, 1077 (1995); Rumpf, PIER B 35, 241 (2011)).
//!   ε is continuous along ê, so Laurent's rule is used for every product (Li, JOSA A 13, 1870
//!   (1996): the inverse rule is needed only across discontinuities).
//! - z is sliced into layers of thickness d/N_s ("staircase", ε sampled at each slice's
//!   middle), N_s = ⌈d·slices_per_period/Λ_z,min⌉. Superposed gratings are handled exactly as in
//!   Glytsis & Gaylord, Appl. Opt. 28, 2401 (1989): the sum of cosines enters the Fourier
//!   coefficients of ε; no approximation beyond truncation and slicing.
//! - Slanted-grating speed-up: when every grating has the same ratio r = K_z,i/p_i (one
//!   grating always does), slice j is slice 0 shifted laterally, so its S-matrix is slice 0's
//!   conjugated by the diagonal phase diag(e^{−i m r z_j}); one eigendecomposition serves the
//!   film, and the film's S-matrix of N_s slices is built by binary doubling
//!   (A_{j+k} = A_j ⊗ D^j A_k D^{−j}) in ≤ 2·log2 N_s Redheffer star products. Otherwise every
//!   slice gets its own eigendecomposition.
//! - Efficiencies: η = Re(k_z,m)/Re(k_z,inc)·|E_m|² for unit incident |E| per incident
//!   polarisation, summed over both diffracted polarisations. TE: E ⟂ plane of incidence
//!   (incident k and the film normal); at normal incidence TE is E along the grating lines
//!   (ẑ × ê).
//!
//! Assumptions: isotropic non-magnetic media, no dispersion of the film index, the film and
//! fringes unchanged since recording (no shrinkage), flat parallel interfaces.

pub mod coupling;
mod smatrix;
pub mod table;

use glam::{DVec2, DVec3};
use num_complex::Complex64 as C;
use std::f64::consts::PI;

use smatrix::{CMat, SMatrix, diag_right, inv};

/// Default half-width M of the harmonic set (2M+1 orders of the common period): on the paper
/// film (n1 0.015 and 0.05, normal incidence and field (10°, −5°), 520–540 nm) the order +1
/// efficiencies at M = 3 differ from M = 10 by ≤ 3e−6 (M = 2: ≤ 3e−6 too at 0.015, 2e−6 at
/// 0.05); the low index contrast couples the evanescent orders weakly.
pub const DEFAULT_HARMONICS: usize = 3;

/// Default slices per z-period of the shortest grating: on the paper film (n1 = 0.015) η_TM at
/// Bragg changes by 9.6e−4 from 32 to 128 slices per period (staircase error ∝ 1/N²), by
/// < 5e−4 from 64 to 256 (`tests::truncation_and_slicing_converge_on_the_paper_film`); the
/// cost grows only with log2 of the slice count.
pub const DEFAULT_SLICES_PER_PERIOD: usize = 64;

/// Largest harmonic half-width accepted.
pub const MAX_HARMONICS: usize = 100;

/// Most slices with one eigendecomposition per slice (several gratings of different slant).
pub const MAX_GENERAL_SLICES: usize = 100_000;

/// One grating of a film.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grating {
    /// Grating vector K in rad/nm (scene frame, z normal to the film).
    pub k_rad_per_nm: DVec3,
    /// Index modulation n1 (peak-to-mean).
    pub n1: f64,
}

impl Grating {
    /// The grating of a Kogelnik [`super::grating::VolumeGrating`] (same K and n1).
    pub fn of(g: &super::grating::VolumeGrating) -> Self {
        Grating {
            k_rad_per_nm: g.k_rad_per_nm,
            n1: g.n1,
        }
    }
}

/// A hologram film holding one or more superposed gratings.
#[derive(Clone, Debug, PartialEq)]
pub struct Film {
    /// Mean index n of the film.
    pub mean_index: f64,
    /// Mean amplitude absorption α0 in 1/nm.
    pub alpha0_per_nm: f64,
    /// Thickness in nm.
    pub thickness_nm: f64,
    /// The gratings (at least one; n1 = 0 allowed).
    pub gratings: Vec<Grating>,
}

/// The media around the film.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stack {
    /// Index of the half-space the light comes from.
    pub n_in: f64,
    /// Index of the half-space beyond the film.
    pub n_out: f64,
}

/// Truncation and slicing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// Half-width M: orders −M…M of the common period.
    pub harmonics: usize,
    /// Slices per z-period of the shortest grating period along z.
    pub slices_per_period: usize,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            harmonics: DEFAULT_HARMONICS,
            slices_per_period: DEFAULT_SLICES_PER_PERIOD,
        }
    }
}

/// One propagating diffracted order leaving the film.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Order {
    /// Order index m (k_t = k_t,inc − m·G·ê).
    pub order: i32,
    /// True if it leaves through the entrance side (back into n_in).
    pub reflected: bool,
    /// Unit direction vector (scene frame).
    pub direction: DVec3,
    /// Efficiency for TE and TM incident light.
    pub eta: [f64; 2],
}

/// The diffraction of one plane wave.
#[derive(Clone, Debug, PartialEq)]
pub struct Solution {
    /// Propagating orders, reflected first, by order index.
    pub orders: Vec<Order>,
    /// Σ over all propagating orders of η, TE and TM (1 for a lossless film).
    pub total: [f64; 2],
    /// Number of slices used.
    pub slices: usize,
    /// Half-width of the harmonic set used.
    pub harmonics: usize,
    /// The common lateral period L in nm (infinite when no grating has a tangential K).
    pub period_nm: f64,
}

/// Why an RCWA computation was refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RcwaError {
    /// The job was cancelled (`crate::cancel`) while the tables were being built.
    #[error("cancelled while building the RCWA tables")]
    Cancelled,
    /// A grating's tangential K is not parallel to the others'.
    #[error(
        "grating {0}: its in-plane grating vector is not parallel to grating 1's (1-D gratings only)"
    )]
    NotParallel(usize),
    /// No common lateral period with a small supercell.
    #[error(
        "grating {0}: in-plane period incommensurate with grating 1's (no common period up to 12x)"
    )]
    Incommensurate(usize),
    /// The incident wave is evanescent in the entrance medium.
    #[error(
        "the incident wave (|u| = {u:.4}) cannot propagate in the entrance medium (n = {n:.4})"
    )]
    CannotEnter {
        /// |u| of the incident wave.
        u: f64,
        /// Index of the entrance medium.
        n: f64,
    },
    /// Input out of range.
    #[error("{0}")]
    BadInput(String),
    /// The eigensolver failed.
    #[error("eigendecomposition failed")]
    Eigen,
}

/// The film's lateral lattice: direction ê, G in rad/nm and the integers p_i.
#[derive(Clone, Debug)]
struct Lattice {
    e: DVec2,
    g_rad_per_nm: f64,
    p: Vec<i64>,
    supercell: usize,
}

fn lattice(gratings: &[Grating]) -> Result<Lattice, RcwaError> {
    let kt = |g: &Grating| g.k_rad_per_nm.truncate();
    let scale = gratings
        .iter()
        .map(|g| g.k_rad_per_nm.length())
        .fold(0.0, f64::max);
    let tiny = 1e-12 * scale.max(1e-300);
    let Some(first) = gratings.iter().find(|g| kt(g).length() > tiny) else {
        return Ok(Lattice {
            e: DVec2::X,
            g_rad_per_nm: 0.0,
            p: vec![0; gratings.len()],
            supercell: 1,
        });
    };
    let g1 = kt(first).length();
    let e = kt(first) / g1;
    let e_perp = DVec2::new(-e.y, e.x);
    for (i, g) in gratings.iter().enumerate() {
        if kt(g).dot(e_perp).abs() > 1e-9 * g1 {
            return Err(RcwaError::NotParallel(i + 1));
        }
    }
    'q: for q in 1..=12usize {
        let g = g1 / q as f64;
        let mut p = Vec::with_capacity(gratings.len());
        for gr in gratings {
            let ratio = kt(gr).dot(e) / g;
            let r = ratio.round();
            if (ratio - r).abs() > 1e-6 {
                continue 'q;
            }
            p.push(r as i64);
        }
        return Ok(Lattice {
            e,
            g_rad_per_nm: g,
            p,
            supercell: q,
        });
    }
    let bad = gratings
        .iter()
        .position(|gr| {
            let r = kt(gr).dot(e) / g1;
            (r - r.round()).abs() > 1e-6
        })
        .unwrap_or(0);
    Err(RcwaError::Incommensurate(bad + 1))
}

/// The order index m (as in [`Order`]) of each grating's first order (Kogelnik's order +1,
/// σ = ρ − K_i): the integer p_i with K_i,t = p_i·G·ê on the film's common lateral lattice.
/// Fails as [`solve`] does for gratings that are not parallel or commensurate.
pub fn grating_orders(film: &Film) -> Result<Vec<i32>, RcwaError> {
    let l = lattice(&film.gratings)?;
    l.p.iter()
        .map(|&p| {
            i32::try_from(p).map_err(|_| RcwaError::BadInput("grating order out of range".into()))
        })
        .collect()
}

/// Square root on the branch of a wave travelling or decaying toward +z (Im ≥ 0, and
/// Re ≥ 0 for a propagating wave).
fn forward_sqrt(x: C) -> C {
    let mut q = x.sqrt();
    if q.im < -1e-10 * q.norm() {
        q = -q;
    }
    if q.norm() < 1e-12 {
        q = C::new(1e-12, 0.0);
    }
    q
}

/// Everything of one (film, stack, λ, u) that does not depend on z.
struct Problem<'a> {
    film: &'a Film,
    lat: Lattice,
    /// Orders −M…M.
    m: Vec<i64>,
    /// Normalised k_x of each order (along ê) and the common k_y (along ẑ × ê).
    kx: Vec<f64>,
    ky: f64,
    /// k0 in rad/nm.
    k0: f64,
    /// Complex film index n + iκ.
    n_film: C,
}

impl Problem<'_> {
    fn n(&self) -> usize {
        self.m.len()
    }

    /// Fourier coefficients c_p of ε at depth z (nm), p = −2M…2M (index p + 2M).
    fn eps_coeffs(&self, z_nm: f64) -> Vec<C> {
        let big_m = (self.n() - 1) / 2;
        let pf = self
            .lat
            .p
            .iter()
            .map(|p| p.unsigned_abs() as usize)
            .max()
            .unwrap_or(0);
        let mut f = vec![C::new(0.0, 0.0); 2 * pf + 1];
        f[pf] = self.n_film;
        for (g, &p) in self.film.gratings.iter().zip(&self.lat.p) {
            let phase = g.k_rad_per_nm.z * z_nm;
            let a = C::from_polar(0.5 * g.n1, phase);
            f[(pf as i64 + p) as usize] += a;
            f[(pf as i64 - p) as usize] += a.conj();
        }
        let mut c = vec![C::new(0.0, 0.0); 4 * big_m + 1];
        for (a, fa) in f.iter().enumerate() {
            for (b, fb) in f.iter().enumerate() {
                let p = a as i64 + b as i64 - 2 * pf as i64;
                if p.unsigned_abs() as usize <= 2 * big_m {
                    c[(p + 2 * big_m as i64) as usize] += fa * fb;
                }
            }
        }
        c
    }

    /// Eigenmodes (W, V, q) of the slice whose ε has Fourier coefficients `c`.
    fn modes(&self, c: &[C]) -> Result<(CMat, CMat, Vec<C>), RcwaError> {
        let n = self.n();
        let big_m = (n - 1) / 2;
        let e = CMat::from_fn(n, n, |i, j| c[j + 2 * big_m - i]);
        let ei = inv(&e);
        let (kx, ky) = (&self.kx, self.ky);
        let one = |i: usize, j: usize| if i == j { 1.0 } else { 0.0 };
        let p = CMat::from_fn(2 * n, 2 * n, |r, s| {
            let (i, j) = (r % n, s % n);
            match (r < n, s < n) {
                (true, true) => kx[i] * ei[(i, j)] * ky,
                (true, false) => one(i, j) - kx[i] * ei[(i, j)] * kx[j],
                (false, true) => ky * ei[(i, j)] * ky - one(i, j),
                (false, false) => -ky * ei[(i, j)] * kx[j],
            }
        });
        let q = CMat::from_fn(2 * n, 2 * n, |r, s| {
            let (i, j) = (r % n, s % n);
            let d = one(i, j);
            match (r < n, s < n) {
                (true, true) => C::from(-kx[i] * ky * d),
                (true, false) => kx[i] * kx[i] * d - e[(i, j)],
                (false, true) => e[(i, j)] - ky * ky * d,
                (false, false) => C::from(kx[i] * ky * d),
            }
        });
        let pq = &p * &q;
        let eig = pq.eigen().map_err(|_| RcwaError::Eigen)?;
        let w = eig.U().to_owned();
        let s = eig.S().column_vector();
        let qv: Vec<C> = (0..2 * n).map(|i| forward_sqrt(s[i])).collect();
        let inv_q: Vec<C> = qv.iter().map(|q| 1.0 / q).collect();
        let v = diag_right(&(&q * &w), &inv_q);
        Ok((w, v, qv))
    }

    /// k_z and the mode matrix V of a homogeneous medium of permittivity `eps` (W = I).
    fn homogeneous(&self, eps: C) -> (Vec<C>, CMat) {
        let n = self.n();
        let (kx, ky) = (&self.kx, self.ky);
        let kz: Vec<C> = kx
            .iter()
            .map(|&k| forward_sqrt(eps - k * k - ky * ky))
            .collect();
        let v = CMat::from_fn(2 * n, 2 * n, |r, s| {
            let (i, j) = (r % n, s % n);
            if i != j {
                return C::new(0.0, 0.0);
            }
            let qrs = match (r < n, s < n) {
                (true, true) => C::from(-kx[i] * ky),
                (true, false) => C::from(kx[i] * kx[i]) - eps,
                (false, true) => eps - ky * ky,
                (false, false) => C::from(kx[i] * ky),
            };
            qrs / kz[j]
        });
        (kz, v)
    }
}

/// Diffraction of a plane wave by `film` in `stack` at vacuum wavelength `lambda_nm`; `u` is
/// the incident wave's tangential optical direction cosines n·ŝ_t (scene frame, conserved
/// through planar interfaces), travelling toward +z.
pub fn solve(
    film: &Film,
    stack: &Stack,
    lambda_nm: f64,
    u: DVec2,
    settings: &Settings,
) -> Result<Solution, RcwaError> {
    solve_with(film, stack, lambda_nm, u, settings, false, None)
}

/// [`solve`] with TE defined along `te_dir` (scene frame; its part normal to the incident wave
/// vector is used) instead of normal to the plane of incidence, e.g. normal to a grating's
/// plane of diffraction (ρ × K, Kogelnik's basis, which the tracer's polarisation weights use).
/// Falls back to the plane-of-incidence basis where `te_dir` is (nearly) along the wave.
pub fn solve_in_basis(
    film: &Film,
    stack: &Stack,
    lambda_nm: f64,
    u: DVec2,
    settings: &Settings,
    te_dir: DVec3,
) -> Result<Solution, RcwaError> {
    solve_with(film, stack, lambda_nm, u, settings, false, Some(te_dir))
}

/// [`solve`] with one eigendecomposition per slice even where the shift trick applies (tests).
#[cfg(test)]
pub(crate) fn solve_per_slice(
    film: &Film,
    stack: &Stack,
    lambda_nm: f64,
    u: DVec2,
    settings: &Settings,
) -> Result<Solution, RcwaError> {
    solve_with(film, stack, lambda_nm, u, settings, true, None)
}

fn solve_with(
    film: &Film,
    stack: &Stack,
    lambda_nm: f64,
    u: DVec2,
    settings: &Settings,
    per_slice: bool,
    te_dir: Option<DVec3>,
) -> Result<Solution, RcwaError> {
    let finite_pos = |x: f64| x.is_finite() && x > 0.0;
    if !finite_pos(lambda_nm) || !finite_pos(film.thickness_nm) || !finite_pos(film.mean_index) {
        return Err(RcwaError::BadInput(
            "wavelength, film thickness and mean index must be positive".into(),
        ));
    }
    if !finite_pos(stack.n_in) || !finite_pos(stack.n_out) || !u.is_finite() {
        return Err(RcwaError::BadInput("media indices must be positive".into()));
    }
    if film.gratings.is_empty() {
        return Err(RcwaError::BadInput(
            "a film needs at least one grating".into(),
        ));
    }
    if !(1..=MAX_HARMONICS).contains(&settings.harmonics) || settings.slices_per_period == 0 {
        return Err(RcwaError::BadInput(format!(
            "harmonics must be in 1..={MAX_HARMONICS} and slices per period at least 1"
        )));
    }
    if u.length_squared() >= stack.n_in * stack.n_in {
        return Err(RcwaError::CannotEnter {
            u: u.length(),
            n: stack.n_in,
        });
    }
    let lat = lattice(&film.gratings)?;
    let big_m = if lat.g_rad_per_nm == 0.0 {
        0
    } else {
        settings.harmonics * lat.supercell
    };
    if big_m > MAX_HARMONICS * 12 {
        return Err(RcwaError::BadInput("too many harmonics".into()));
    }
    let k0 = 2.0 * PI / lambda_nm;
    let e_perp = DVec2::new(-lat.e.y, lat.e.x);
    let m: Vec<i64> = (-(big_m as i64)..=big_m as i64).collect();
    let kx0 = u.dot(lat.e);
    let ky = u.dot(e_perp);
    let kx: Vec<f64> = m
        .iter()
        .map(|&m| kx0 - m as f64 * lat.g_rad_per_nm / k0)
        .collect();
    let pb = Problem {
        film,
        lat,
        m,
        kx,
        ky,
        k0,
        n_film: C::new(film.mean_index, film.alpha0_per_nm / k0),
    };
    let n = pb.n();

    // Gap medium: real k_z ≥ 1 for every order (no Wood anomaly in the zero-thickness gap).
    let eps_gap = 1.0 + pb.kx.iter().map(|k| k * k).fold(0.0, f64::max) + ky * ky;
    let (_, v0) = pb.homogeneous(C::from(eps_gap));
    let v0i = inv(&v0);

    let film_s = film_smatrix(&pb, &v0, settings, per_slice)?;
    let (kz_in, v_in) = pb.homogeneous(C::from(stack.n_in * stack.n_in));
    let (kz_out, v_out) = pb.homogeneous(C::from(stack.n_out * stack.n_out));
    let global = smatrix::reflection_side(&v_in, &v0i)
        .star(&film_s.0)
        .star(&smatrix::transmission_side(&v_out, &v0i));

    // Incident polarisations in the (ê, ẑ×ê, ẑ) frame.
    let i0 = big_m;
    let kz_inc = kz_in[i0].re;
    let k_inc = DVec3::new(kx0, ky, kz_inc) / stack.n_in;
    let k_unit = k_inc.normalize();
    let wanted = te_dir.map(|t| {
        // Into the (ê, ẑ×ê, ẑ) frame, normal to the incident wave.
        let t = DVec3::new(t.truncate().dot(pb.lat.e), t.truncate().dot(e_perp), t.z);
        t - k_unit * t.dot(k_unit)
    });
    let s_hat = match wanted {
        Some(t) if t.length_squared() > 1e-20 => t.normalize(),
        _ if kx0 * kx0 + ky * ky < 1e-24 => DVec3::Y,
        _ => DVec3::new(-ky, kx0, 0.0).normalize(),
    };
    let p_hat = s_hat.cross(k_inc).normalize();
    let c_inc = CMat::from_fn(2 * n, 2, |r, pol| {
        let v = if pol == 0 { s_hat } else { p_hat };
        if r == i0 {
            C::from(v.x)
        } else if r == n + i0 {
            C::from(v.y)
        } else {
            C::new(0.0, 0.0)
        }
    });
    let c_ref = &global.s11 * &c_inc;
    let c_trn = &global.s21 * &c_inc;

    let to_scene = |kx: f64, kz: f64, n_med: f64| {
        let t = lat_dir(&pb.lat.e, e_perp, kx, ky);
        (t.extend(kz) / n_med).normalize()
    };
    let mut orders = Vec::new();
    let mut total = [0.0; 2];
    for (side, kz, c, n_med) in [
        (true, &kz_in, &c_ref, stack.n_in),
        (false, &kz_out, &c_trn, stack.n_out),
    ] {
        for i in 0..n {
            // Propagating: real k_z (up to rounding) in a lossless half-space.
            if kz[i].re <= 1e-9 || kz[i].im.abs() > 1e-9 * kz[i].re.max(1.0) {
                continue;
            }
            let mut eta = [0.0; 2];
            for (pol, e) in eta.iter_mut().enumerate() {
                let ex = c[(i, pol)];
                let ey = c[(n + i, pol)];
                let sgn = if side { 1.0 } else { -1.0 };
                let ez = (ex * pb.kx[i] + ey * ky) * sgn / kz[i];
                *e = kz[i].re / kz_inc * (ex.norm_sqr() + ey.norm_sqr() + ez.norm_sqr());
            }
            total[0] += eta[0];
            total[1] += eta[1];
            let kzs = if side { -kz[i].re } else { kz[i].re };
            orders.push(Order {
                order: pb.m[i] as i32,
                reflected: side,
                direction: to_scene(pb.kx[i], kzs, n_med),
                eta,
            });
        }
    }
    let period_nm = if pb.lat.g_rad_per_nm > 0.0 {
        2.0 * PI / pb.lat.g_rad_per_nm
    } else {
        f64::INFINITY
    };
    Ok(Solution {
        orders,
        total,
        slices: film_s.1,
        harmonics: big_m,
        period_nm,
    })
}

/// Kogelnik's efficiencies [η_s, η_p] of one order, polarised relative to the plane of
/// diffraction (incident ρ and K; `optics::grating`), converted to TE/TM relative to the plane
/// of incidence (ρ and the film normal) as the RCWA reports them: with ψ the angle between the
/// two s directions, η_TE = cos²ψ·η_s + sin²ψ·η_p and η_TM = sin²ψ·η_s + cos²ψ·η_p (the s and p
/// parts leave in orthogonal polarisations, so their powers add). `u` is the incident wave's
/// tangential direction cosines, entering a film of index `n_film` toward +z; K in rad/nm.
/// At normal incidence the plane-of-incidence s is taken along ẑ × K̂_t (the grating lines),
/// as in [`solve`]. The two bases agree when the plane of incidence contains K.
pub fn kogelnik_in_incidence_basis(k: DVec3, n_film: f64, u: DVec2, eta: [f64; 2]) -> [f64; 2] {
    let rho = u.extend((n_film * n_film - u.length_squared()).max(0.0).sqrt());
    let s_g = rho.cross(k);
    let kt = k.truncate();
    let s_i = if u.length_squared() > 1e-24 {
        DVec3::new(-u.y, u.x, 0.0)
    } else if kt.length_squared() > 0.0 {
        DVec3::new(-kt.y, kt.x, 0.0)
    } else {
        return eta;
    };
    if s_g.length_squared() == 0.0 {
        return eta;
    }
    let c2 = s_g.normalize().dot(s_i.normalize()).powi(2).min(1.0);
    [
        c2 * eta[0] + (1.0 - c2) * eta[1],
        (1.0 - c2) * eta[0] + c2 * eta[1],
    ]
}

/// Tangential vector kx·ê + ky·(ẑ × ê) in the scene frame.
fn lat_dir(e: &DVec2, e_perp: DVec2, kx: f64, ky: f64) -> DVec2 {
    *e * kx + e_perp * ky
}

/// The film's S-matrix and its number of slices.
fn film_smatrix(
    pb: &Problem,
    v0: &CMat,
    settings: &Settings,
    per_slice: bool,
) -> Result<(SMatrix, usize), RcwaError> {
    let film = pb.film;
    let d = film.thickness_nm;
    let dn = d * pb.k0;
    let n = pb.n();
    let kz_max = film
        .gratings
        .iter()
        .map(|g| g.k_rad_per_nm.z.abs())
        .fold(0.0, f64::max);
    if kz_max == 0.0 || film.gratings.iter().all(|g| g.n1 == 0.0) {
        // z-invariant: one layer of the whole thickness.
        let (w, v, q) = pb.modes(&pb.eps_coeffs(0.0))?;
        return Ok((smatrix::layer(&w, &v, &q, v0, dn), 1));
    }
    let slices_f = (d * kz_max / (2.0 * PI) * settings.slices_per_period as f64).ceil();
    if slices_f.is_nan() || slices_f > 1e9 {
        return Err(RcwaError::BadInput("film too thick for its slicing".into()));
    }
    let slices = (slices_f as usize).max(1);
    let dz_nm = d / slices as f64;

    // One common ratio r = K_z,i/p_i (nm⁻¹) makes every slice a lateral shift of slice 0.
    let mut ratio: Option<f64> = None;
    let mut shift = true;
    for (g, &p) in film.gratings.iter().zip(&pb.lat.p) {
        if g.n1 == 0.0 {
            continue;
        }
        if p == 0 {
            shift &= g.k_rad_per_nm.z == 0.0;
            continue;
        }
        let r = g.k_rad_per_nm.z / p as f64;
        match ratio {
            None => ratio = Some(r),
            Some(r0) => shift &= (r - r0).abs() <= 1e-9 * r0.abs().max(r.abs()),
        }
    }
    if let (true, Some(r)) = (shift && !per_slice, ratio) {
        let (w, v, q) = pb.modes(&pb.eps_coeffs(0.5 * dz_nm))?;
        let s0 = smatrix::layer(&w, &v, &q, v0, dz_nm * pb.k0);
        // Phase per slice and order: D = diag(e^{−i m r dz}) on both field blocks.
        let phase = |k: usize| -> Vec<C> {
            (0..2 * n)
                .map(|i| C::from_polar(1.0, -(pb.m[i % n] as f64) * r * dz_nm * k as f64))
                .collect()
        };
        let mut result: Option<(SMatrix, usize)> = None;
        let mut power = (s0, 1usize);
        let mut left = slices;
        loop {
            if left & 1 == 1 {
                result = Some(match result {
                    None => (power.0.clone(), power.1),
                    Some((s, len)) => (s.star(&power.0.conjugated(&phase(len))), len + power.1),
                });
            }
            left >>= 1;
            if left == 0 {
                break;
            }
            let doubled = power.0.star(&power.0.conjugated(&phase(power.1)));
            power = (doubled, power.1 * 2);
        }
        let (s, len) = result.expect("slices >= 1");
        debug_assert_eq!(len, slices);
        return Ok((s, slices));
    }
    if slices > MAX_GENERAL_SLICES {
        return Err(RcwaError::BadInput(format!(
            "{slices} slices with one eigendecomposition each (gratings of different slant): \
             more than {MAX_GENERAL_SLICES}; lower the slices per period"
        )));
    }
    let mut total = SMatrix::identity(2 * n);
    for j in 0..slices {
        let (w, v, q) = pb.modes(&pb.eps_coeffs((j as f64 + 0.5) * dz_nm))?;
        total = total.star(&smatrix::layer(&w, &v, &q, v0, dz_nm * pb.k0));
    }
    Ok((total, slices))
}

#[cfg(test)]
mod tests;
