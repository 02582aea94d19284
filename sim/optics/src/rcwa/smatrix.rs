//! Scattering matrices of the RCWA in a common zero-thickness gap medium (Rumpf 2011,
//! "Improved formulation of scattering matrices for semi-analytical methods that is consistent
//! with convention", PIER B 35, 241): a layer's S-matrix maps the gap-mode amplitudes entering
//! it (from the left going +z, from the right going −z) to those leaving it, and two S-matrices
//! combine with the Redheffer star product. Fields of a layer are ψ = [W W; V −V]·[c⁺; c⁻]
//! (E_x, E_y on top, h = η0·H tangential below), forward modes e^{+iqz}; the gap has W0 = I.

use faer::Mat;
use faer::linalg::solvers::DenseSolveCore;
use num_complex::Complex64 as C;

/// Dense complex matrix.
pub(crate) type CMat = Mat<C>;

/// Inverse by LU with partial pivoting.
pub(crate) fn inv(a: &CMat) -> CMat {
    a.partial_piv_lu().inverse()
}

/// `a − b`.
pub(crate) fn sub(a: &CMat, b: &CMat) -> CMat {
    a - b
}

/// `a + b`.
pub(crate) fn add(a: &CMat, b: &CMat) -> CMat {
    a + b
}

/// `s·a`.
pub(crate) fn scale(a: &CMat, s: f64) -> CMat {
    CMat::from_fn(a.nrows(), a.ncols(), |i, j| a[(i, j)] * s)
}

/// diag(d)·a (rows scaled).
pub(crate) fn diag_left(d: &[C], a: &CMat) -> CMat {
    CMat::from_fn(a.nrows(), a.ncols(), |i, j| d[i] * a[(i, j)])
}

/// a·diag(d) (columns scaled).
pub(crate) fn diag_right(a: &CMat, d: &[C]) -> CMat {
    CMat::from_fn(a.nrows(), a.ncols(), |i, j| a[(i, j)] * d[j])
}

/// Scattering matrix with 2N×2N blocks.
#[derive(Clone, Debug)]
pub(crate) struct SMatrix {
    pub s11: CMat,
    pub s12: CMat,
    pub s21: CMat,
    pub s22: CMat,
}

impl SMatrix {
    /// The S-matrix of nothing (zero thickness): full transmission.
    pub fn identity(n: usize) -> Self {
        SMatrix {
            s11: CMat::zeros(n, n),
            s12: CMat::identity(n, n),
            s21: CMat::identity(n, n),
            s22: CMat::zeros(n, n),
        }
    }

    /// Redheffer star product `self ⊗ b` (`self` on the left, light from the left).
    pub fn star(&self, b: &SMatrix) -> SMatrix {
        let n = self.s11.nrows();
        let id = CMat::identity(n, n);
        let d = &self.s12 * inv(&sub(&id, &(&b.s11 * &self.s22)));
        let f = &b.s21 * inv(&sub(&id, &(&self.s22 * &b.s11)));
        SMatrix {
            s11: add(&self.s11, &(&d * &(&b.s11 * &self.s21))),
            s12: &d * &b.s12,
            s21: &f * &self.s21,
            s22: add(&b.s22, &(&f * &(&self.s22 * &b.s12))),
        }
    }

    /// The S-matrix of the same structure shifted laterally: every block conjugated by the
    /// diagonal phase `w` (per row/column index), entry (i, j) times w_i·conj(w_j); `w` has
    /// unit modulus.
    pub fn conjugated(&self, w: &[C]) -> SMatrix {
        let f =
            |a: &CMat| CMat::from_fn(a.nrows(), a.ncols(), |i, j| a[(i, j)] * w[i] * w[j].conj());
        SMatrix {
            s11: f(&self.s11),
            s12: f(&self.s12),
            s21: f(&self.s21),
            s22: f(&self.s22),
        }
    }
}

/// S-matrix of a homogeneous-in-z layer of normalised thickness `dz` (k0·d) with modes W, V
/// and propagation constants q, in the gap basis with mode matrix `v0` (W0 = I).
/// Symmetric: S22 = S11, S21 = S12 (Rumpf Eqs. 2.92–2.93 with our e^{+iqz} convention).
pub(crate) fn layer(w: &CMat, v: &CMat, q: &[C], v0: &CMat, dz: f64) -> SMatrix {
    let wi = inv(w);
    let vi = inv(v);
    let viv0 = &vi * v0;
    let a = add(&wi, &viv0);
    let b = sub(&wi, &viv0);
    let x: Vec<C> = q.iter().map(|&q| (C::i() * q * dz).exp()).collect();
    let ai = inv(&a);
    let xb = diag_left(&x, &b);
    let xbai = &xb * &ai;
    let m = sub(&a, &(&xbai * &xb));
    let mi = inv(&m);
    let s11 = &mi * &sub(&(&xbai * &diag_left(&x, &a)), &b);
    let s12 = &mi * &diag_left(&x, &sub(&a, &(&(&b * &ai) * &b)));
    SMatrix {
        s22: s11.clone(),
        s21: s12.clone(),
        s11,
        s12,
    }
}

/// S-matrix of the half-space the light comes from (mode matrix `v_ref`, W = I), joined to
/// the gap (Rumpf Eq. 2.100).
pub(crate) fn reflection_side(v_ref: &CMat, v0i: &CMat) -> SMatrix {
    let n = v_ref.nrows();
    let id = CMat::identity(n, n);
    let t = v0i * v_ref;
    let a = add(&id, &t);
    let b = sub(&id, &t);
    let ai = inv(&a);
    SMatrix {
        s11: scale(&(&ai * &b), -1.0),
        s12: scale(&ai, 2.0),
        s21: scale(&sub(&a, &(&(&b * &ai) * &b)), 0.5),
        s22: &b * &ai,
    }
}

/// S-matrix of the half-space the light leaves into (mode matrix `v_trn`, W = I), joined to
/// the gap (Rumpf Eq. 2.105).
pub(crate) fn transmission_side(v_trn: &CMat, v0i: &CMat) -> SMatrix {
    let n = v_trn.nrows();
    let id = CMat::identity(n, n);
    let t = v0i * v_trn;
    let a = add(&id, &t);
    let b = sub(&id, &t);
    let ai = inv(&a);
    SMatrix {
        s11: &b * &ai,
        s12: scale(&sub(&a, &(&(&b * &ai) * &b)), 0.5),
        s21: scale(&ai, 2.0),
        s22: scale(&(&ai * &b), -1.0),
    }
}
