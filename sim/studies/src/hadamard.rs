//! The paper's Hadamard measurement of H (docs/physics.md §7), simulated.
//!
//! Patterns: Sylvester's Hadamard matrix of order N = object pixels (N must be 2^k), entry
//! h_i[k] = (−1)^popcount(i & k); row 0 is all ones and H_N H_Nᵀ = N·I. Row-major, pattern
//! i = a·W + b of a W×W object is the outer product of rows a and b of H_W (separable 2-D Walsh
//! patterns in natural order). The display shows u_i = (h_i + 1)/2 ∈ {0, 1} (black/white).
//!
//! Frames: v_i = H u_i + o, where o is the capture of an all-black display (LCD black leakage);
//! from H_true they are evaluated per sensor pixel m with one fast Walsh–Hadamard transform
//! (FWHT) of row m: (H u_i)[m] = (FWHT(H[m,:])_i + Σ_k H[m,k])/2. Or they are rendered.
//! The sensor noise model (`noise.rs`) then adds shot and read noise, the dark offset,
//! quantisation and saturation.
//!
//! Estimate (paper Eqs. 12–16 with the normalisation corrected, docs/physics.md §7.2):
//! v'_0 = v_0, v'_i = 2v_i − v_0, H_est = V'U'ᵀ/N, i.e. row m of H_est is FWHT(v'[m,:])/N.
//! Offsets are not cancelled (§7.3): with v_i = H u_i + c, H_est = H + c e_0ᵀ, so the whole
//! offset (LCD black + camera dark level) lands in column 0. Subtracting a dark frame (all-black
//! display) from every frame removes it; by linearity that changes column 0 only,
//! H_est,dark = H_est − d e_0ᵀ, so both variants come from one transform.
//!
//! H_est is dense (the noise floor covers every element). It is never stored dense: errors
//! against H_true are accumulated row by row on the full estimate, and the written H_est keeps
//! the entries above `threshold_sigma` times the noise standard deviation predicted by the noise
//! model for that row, σ_m² = (4/N²)·Σ_i Var(v_i[m]) (§7.3), and above 10⁻⁹ of the row's largest
//! entry (transform rounding). Column 0 is not multiplexed (H_est[m,0] = (2/N)Σ_{i≥1}v_i −
//! ((N − 2)/N)v_0, minus the dark frame if subtracted) and gets its own σ from that formula.

use rayon::prelude::*;

use crate::noise::{NoiseRng, SensorNoise};
use crate::sparse::CsrMatrix;

/// In-place fast Walsh–Hadamard transform in Sylvester (natural) order, unnormalised:
/// x ← H_N x. `x.len()` must be a power of two.
pub fn fwht(x: &mut [f64]) {
    let n = x.len();
    debug_assert!(n.is_power_of_two());
    let mut h = 1;
    while h < n {
        for block in x.chunks_exact_mut(2 * h) {
            let (a, b) = block.split_at_mut(h);
            for (p, q) in a.iter_mut().zip(b.iter_mut()) {
                let (u, v) = (*p, *q);
                *p = u + v;
                *q = u - v;
            }
        }
        h *= 2;
    }
}

/// Entry (i, k) of Sylvester's Hadamard matrix: (−1)^popcount(i & k).
#[inline]
pub fn sylvester(i: usize, k: usize) -> f64 {
    if (i & k).count_ones().is_multiple_of(2) {
        1.0
    } else {
        -1.0
    }
}

/// The displayed 0/1 pattern u_i = (h_i + 1)/2 of order `n`.
pub fn display_pattern(n: usize, i: usize) -> Vec<f64> {
    (0..n)
        .map(|k| if sylvester(i, k) > 0.0 { 1.0 } else { 0.0 })
        .collect()
}

/// The colour calibration of a colour H (`planes` column blocks, one per display primary):
/// for each primary p the display shows the N Sylvester patterns in that primary only (the
/// others black), v_{p,i} = H_p u_i + o, and H_p is estimated from its own N frames (plus the
/// shared all-white-of-p frame u_0 and, with `dark_frame`, the dark frame) exactly as
/// [`calibrate`] does for a monochrome display: N·planes frames in all. The exposure of
/// `set.noise` is kept for every frame (set once, as for the monochrome camera); primary p's
/// noise comes from the stream of seed `set.seed + p`. Returns H_est (blocks side by side, the
/// shape of `h_true`) and one report per primary, whose
/// `with_dark_frame.other_columns` / `without_dark_frame.other_columns` against
/// `predicted_noise_other_columns` is the check "within the noise prediction, per primary".
pub fn calibrate_colour(
    h_true: &CsrMatrix,
    offset: &[f32],
    planes: usize,
    set: &CalibrationSettings,
) -> Result<(CsrMatrix, Vec<CalibrationReport>), HadamardError> {
    let blocks = h_true
        .hsplit(planes.max(1))
        .ok_or(HadamardError::NotPowerOfTwo(h_true.cols))?;
    let mut est = Vec::with_capacity(blocks.len());
    let mut reports = Vec::with_capacity(blocks.len());
    for (p, b) in blocks.iter().enumerate() {
        let c = calibrate(
            b,
            offset,
            FrameSource::Matrix,
            &CalibrationSettings {
                seed: set.seed.wrapping_add(p as u64),
                ..set.clone()
            },
        )?;
        est.push(c.h_est);
        reports.push(c.report);
    }
    let refs: Vec<&CsrMatrix> = est.iter().collect();
    let h_est = CsrMatrix::hstack(&refs).ok_or(HadamardError::NotPowerOfTwo(h_true.cols))?;
    Ok((h_est, reports))
}

/// Default threshold of stored H_est entries, in predicted noise standard deviations: at 5σ
/// a Gaussian floor leaves about 5.7·10⁻⁷ of the pure-noise elements (≈ 450 of the paper's
/// 7.9·10⁸), so H_est stays as sparse as H.
pub const DEFAULT_THRESHOLD_SIGMA: f64 = 5.0;

/// Renders the N Sylvester patterns of `sys`'s object (the display shows u_i = (h_i + 1)/2)
/// and then a dark frame (all black), each with the full Monte Carlo tracer; every frame is
/// one vector over the rows of H (channels concatenated). `on_frame` is called after each.
/// Once the job is cancelled ([`crate::cancel`]) the remaining frames are empty.
pub fn render_frames(
    sys: &crate::system::System,
    set: &crate::render::RenderSettings,
    mut on_frame: impl FnMut(),
) -> Vec<Vec<f32>> {
    let n = sys.display.width_px * sys.display.height_px;
    let cancel = crate::cancel::current();
    (0..=n)
        .map(|i| {
            if cancel.is_cancelled() {
                return Vec::new();
            }
            let mut s = sys.clone();
            let u = if i < n {
                display_pattern(n, i)
            } else {
                vec![0.0; n]
            };
            s.display.set_intensity(&u);
            let frame = crate::render::render(&s, set).channels.concat();
            on_frame();
            frame
        })
        .collect()
}

/// Where the noiseless frames come from.
pub enum FrameSource<'a> {
    /// From H_true and the offset (capture of an all-black display), one FWHT per row.
    Matrix,
    /// Rendered frames: `frames[i]` for pattern i (N of them), then the dark frame; each a
    /// vector over the rows of H.
    Rendered(&'a [Vec<f32>]),
}

/// Settings of a simulated calibration.
#[derive(Clone, Debug)]
pub struct CalibrationSettings {
    /// Sensor noise (exposure already fixed), or none for an ideal camera.
    pub noise: Option<SensorNoise>,
    /// Seed of the noise.
    pub seed: u64,
    /// Store the dark-frame-subtracted estimate (else the paper's procedure without it).
    pub dark_frame: bool,
    /// Keep stored entries above this many predicted noise standard deviations (0 keeps all
    /// entries above the rounding floor).
    pub threshold_sigma: f64,
    /// Show progress (rows of H estimated) on stderr.
    pub progress: bool,
}

/// Relative Frobenius errors ‖H_est − H_true‖/‖H_true‖ of one variant.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ErrorPair {
    /// Over the whole matrix (the full, dense estimate).
    pub overall: f64,
    /// Column 0 only (relative to ‖H_true[:,0]‖).
    pub column0: f64,
    /// All columns but 0 (relative to ‖H_true[:,1:]‖).
    pub other_columns: f64,
}

/// What the calibration reports.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct CalibrationReport {
    /// Number of patterns N (object pixels).
    pub patterns: usize,
    /// Frames taken (N patterns, plus the dark frame).
    pub frames: usize,
    /// Rows (sensor pixels × channels).
    pub rows: usize,
    /// Errors without dark-frame subtraction (the paper's procedure).
    pub without_dark_frame: ErrorPair,
    /// Errors with a dark frame subtracted from every frame.
    pub with_dark_frame: ErrorPair,
    /// Error of the stored (thresholded) estimate, for the stored variant.
    pub stored_overall: f64,
    /// Stored entries.
    pub stored_nnz: usize,
    /// Rows with at least one saturated frame.
    pub saturated_rows: usize,
    /// Median over rows of the predicted noise standard deviation of an H_est element.
    pub median_sigma: f64,
    /// Predicted error of the columns other than 0 from noise alone,
    /// √(Σ_m (N − 1)·σ_m²)/‖H_true[:,1:]‖ with σ_m² = (4/N²)·Σ_i Var(v_i[m]) (§7.3).
    pub predicted_noise_other_columns: f64,
    /// Predicted column-0 error from offsets, ‖c‖/‖H_true[:,0]‖ with c = mean offset per row
    /// (LCD black + dark offset), for the variant without dark frame.
    pub predicted_column0: f64,
}

/// Result: the stored estimate and the report.
pub struct Calibration {
    /// H_est (thresholded), same shape as H_true.
    pub h_est: CsrMatrix,
    /// Errors and counts.
    pub report: CalibrationReport,
}

/// An error of the calibration set-up.
#[derive(Debug, thiserror::Error)]
pub enum HadamardError {
    /// The object size is not a power of two.
    #[error(
        "the object has {0} pixels, not a power of two; Sylvester's Hadamard construction needs N = 2^k (e.g. a 64x64 object)"
    )]
    NotPowerOfTwo(usize),
    /// Rendered frames do not fit.
    #[error("expected {expected} rendered frames of {rows} values, got {got}")]
    FrameShape {
        /// Frames expected (N + 1).
        expected: usize,
        /// Values per frame.
        rows: usize,
        /// Frames given.
        got: usize,
    },
}

struct RowOut {
    cols: Vec<u32>,
    vals: Vec<f32>,
    // Sums: err² without dark (col 0, others), err² with dark (col 0), true² (col 0, others),
    // stored err², offset².
    e0_nodark: f64,
    e_rest: f64,
    e0_dark: f64,
    t0: f64,
    t_rest: f64,
    e_stored: f64,
    c2: f64,
    saturated: bool,
    sigma: f64,
}

/// Rows per task.
const CHUNK: usize = 64;

/// Simulates the calibration of `h_true` (with `offset`, the all-black capture per row): per
/// row its frames ([`row_frames`]), measured ([`measure_row`]) and transformed back
/// ([`estimate_row`]), in parallel; then H_est and the report ([`assemble`]).
pub fn calibrate(
    h_true: &CsrMatrix,
    offset: &[f32],
    source: FrameSource<'_>,
    set: &CalibrationSettings,
) -> Result<Calibration, HadamardError> {
    let n = h_true.cols;
    if !n.is_power_of_two() {
        return Err(HadamardError::NotPowerOfTwo(n));
    }
    if let FrameSource::Rendered(fr) = &source
        && (fr.len() != n + 1 || fr.iter().any(|f| f.len() != h_true.rows))
    {
        return Err(HadamardError::FrameShape {
            expected: n + 1,
            rows: h_true.rows,
            got: fr.len(),
        });
    }
    let pb = crate::progress::Progress::new(set.progress, h_true.rows as u64, "calibration rows");
    let rows: Vec<RowOut> = (0..h_true.rows)
        .into_par_iter()
        .with_min_len(CHUNK)
        .map_init(
            || (vec![0.0f64; n], vec![0.0f64; n]),
            |(truth, v), m| {
                h_true.row_dense_into(m, truth);
                let o = f64::from(offset[m]);
                let mut d = row_frames(truth, v, o, m, &source);
                let noise = measure_row(v, &mut d, set, m);
                let r = estimate_row(truth, v, d, o, &noise, set);
                pb.inc(1);
                r
            },
        )
        .collect();
    pb.finish_and_clear();
    Ok(assemble(&rows, h_true.rows, n))
}

/// What the camera did to one row's frames: the summed variance of the frames (electrons and
/// read noise converted to units, plus quantisation), that of frame 0 and of the dark frame,
/// and whether a frame saturated (all 0 without noise).
struct RowNoise {
    var_sum: f64,
    var0: f64,
    var_dark: f64,
    saturated: bool,
}

/// Row `m`'s noiseless frames v_i (Sylvester patterns applied to its `truth`, or the rendered
/// frames) into `v`; returns its dark frame d (the offset `o`, or the rendered dark frame).
fn row_frames(truth: &[f64], v: &mut [f64], o: f64, m: usize, source: &FrameSource<'_>) -> f64 {
    let n = v.len();
    let mut d = o;
    match source {
        FrameSource::Matrix => {
            v.copy_from_slice(truth);
            fwht(v);
            let s = v[0];
            for x in v.iter_mut() {
                *x = 0.5 * (*x + s) + o;
            }
        }
        FrameSource::Rendered(fr) => {
            for (i, x) in v.iter_mut().enumerate() {
                *x = f64::from(fr[i][m]);
            }
            d = f64::from(fr[n][m]);
        }
    }
    d
}

/// The camera: row `m`'s frames `v` and dark frame `d` measured with the sensor model (one
/// random stream per row, frames in order, dark frame last), or left as they are.
fn measure_row(v: &mut [f64], d: &mut f64, set: &CalibrationSettings, m: usize) -> RowNoise {
    let n = v.len();
    let mut var_sum = 0.0;
    let mut var0 = 0.0;
    let mut var_dark = 0.0;
    let mut saturated = false;
    if let Some(nz) = &set.noise {
        // One random stream per row, frames in order (dark frame last).
        let mut rng = NoiseRng::new(&[set.seed, 0x4841, m as u64]);
        let inv_g = 1.0 / nz.electrons_per_unit;
        let read2 = nz.read_noise_e * nz.read_noise_e;
        let q = 1.0 / (12.0 * nz.dn_per_unit().powi(2));
        let sat = (nz.full_scale_dn - nz.dark_offset_dn) / nz.dn_per_unit();
        // The pixel's fixed pattern: it collects x·gain + dark/G in capture units (its
        // shot-noisy electrons over G); the ideal sensor's pixel collects x.
        let px = nz.pixel(m as u64);
        let ideal = nz.fixed.is_none();
        let collected = |x: f64| {
            if ideal {
                x.max(0.0)
            } else {
                x.max(0.0) * px.gain + px.dark_e * inv_g
            }
        };
        let var_of = |x: f64| (collected(x) * nz.electrons_per_unit + read2) * inv_g * inv_g + q;
        let mut e_sum = 0.0;
        var0 = var_of(v[0]);
        var_dark = var_of(*d);
        for x in v.iter_mut() {
            saturated |= collected(*x) > sat;
            e_sum += collected(*x);
            *x = nz.measure_at(*x, m as u64, &mut rng);
        }
        var_sum = (e_sum * nz.electrons_per_unit + n as f64 * read2) * inv_g * inv_g + n as f64 * q;
        *d = nz.measure_at(*d, m as u64, &mut rng);
    }
    RowNoise {
        var_sum,
        var0,
        var_dark,
        saturated,
    }
}

/// One row of H_est from its measured frames `v` (transformed back in place), with its
/// predicted noise, thresholded, and its squared errors against `truth`.
fn estimate_row(
    truth: &[f64],
    v: &mut [f64],
    d: f64,
    o: f64,
    noise: &RowNoise,
    set: &CalibrationSettings,
) -> RowOut {
    let n = v.len();
    let inv_n = 1.0 / n as f64;
    let RowNoise {
        var_sum,
        var0,
        var_dark,
        saturated,
    } = *noise;
    // Element k ≠ 0: v_0 enters with coefficient 2/N like every other frame, so
    // Var = (4/N²)ΣVar(v_i). Column 0 is not multiplexed: H_est[m,0] =
    // (2/N)Σ_{i≥1}v_i − ((N − 2)/N)v_0 (− d with the dark frame).
    let sigma = (4.0 * var_sum).sqrt() * inv_n;
    let nn = n as f64;
    let sigma0 = (((nn - 2.0) * inv_n).powi(2) * var0
        + 4.0 * inv_n * inv_n * (var_sum - var0)
        + if set.dark_frame { var_dark } else { 0.0 })
    .max(0.0)
    .sqrt();
    // v' and the inverse transform.
    let v0 = v[0];
    for x in v.iter_mut().skip(1) {
        *x = 2.0 * *x - v0;
    }
    fwht(v);
    v.iter_mut().for_each(|x| *x *= inv_n);
    // Errors: columns other than 0 are the same in both variants.
    let mut e_rest = 0.0;
    let mut t_rest = 0.0;
    for k in 1..n {
        let e = v[k] - truth[k];
        e_rest += e * e;
        t_rest += truth[k] * truth[k];
    }
    let e0_nodark = (v[0] - truth[0]).powi(2);
    let e0_dark = (v[0] - d - truth[0]).powi(2);
    if set.dark_frame {
        v[0] -= d;
    }
    let peak = v.iter().fold(0.0f64, |a, x| a.max(x.abs()));
    let thr = (set.threshold_sigma * sigma).max(1e-9 * peak);
    let thr0 = (set.threshold_sigma * sigma0).max(1e-9 * peak);
    let mut cols = Vec::new();
    let mut vals = Vec::new();
    let mut e_stored = 0.0;
    for k in 0..n {
        let kept = v[k].abs() > if k == 0 { thr0 } else { thr };
        let est = if kept { v[k] as f32 } else { 0.0 };
        if kept && est != 0.0 {
            cols.push(k as u32);
            vals.push(est);
        }
        let e = f64::from(est) - truth[k];
        e_stored += e * e;
    }
    let c = o + set.noise.as_ref().map_or(0.0, |nz| nz.dark_offset_units());
    RowOut {
        cols,
        vals,
        e0_nodark,
        e_rest,
        e0_dark,
        t0: truth[0] * truth[0],
        t_rest,
        e_stored,
        c2: c * c,
        saturated,
        sigma,
    }
}

/// H_est (`rows`×`n`) from the rows in order and the report of their summed errors.
fn assemble(rows: &[RowOut], n_rows: usize, n: usize) -> Calibration {
    let mut h_est = CsrMatrix {
        rows: n_rows,
        cols: n,
        indptr: Vec::with_capacity(n_rows + 1),
        indices: Vec::new(),
        data: Vec::new(),
    };
    h_est.indptr.push(0);
    let (mut e0n, mut er, mut e0d, mut t0, mut tr, mut es, mut c2) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let mut saturated_rows = 0;
    let mut sigmas = Vec::with_capacity(rows.len());
    for r in rows {
        h_est.indices.extend_from_slice(&r.cols);
        h_est.data.extend_from_slice(&r.vals);
        h_est.indptr.push(h_est.indices.len() as u64);
        e0n += r.e0_nodark;
        er += r.e_rest;
        e0d += r.e0_dark;
        t0 += r.t0;
        tr += r.t_rest;
        es += r.e_stored;
        c2 += r.c2;
        saturated_rows += usize::from(r.saturated);
        sigmas.push(r.sigma);
    }
    let noise_sq: f64 = sigmas.iter().map(|s| (n - 1) as f64 * s * s).sum();
    sigmas.sort_by(f64::total_cmp);
    let rel = |e: f64, t: f64| if t > 0.0 { (e / t).sqrt() } else { f64::NAN };
    let report = CalibrationReport {
        patterns: n,
        frames: n + 1,
        rows: n_rows,
        without_dark_frame: ErrorPair {
            overall: rel(e0n + er, t0 + tr),
            column0: rel(e0n, t0),
            other_columns: rel(er, tr),
        },
        with_dark_frame: ErrorPair {
            overall: rel(e0d + er, t0 + tr),
            column0: rel(e0d, t0),
            other_columns: rel(er, tr),
        },
        stored_overall: rel(es, t0 + tr),
        stored_nnz: h_est.nnz(),
        saturated_rows,
        median_sigma: sigmas.get(sigmas.len() / 2).copied().unwrap_or(0.0),
        predicted_column0: rel(c2, t0),
        predicted_noise_other_columns: rel(noise_sq, tr),
    };
    Calibration { h_est, report }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn capture_noise_has_one_name_for_clap_serde_and_python() {
        use clap::ValueEnum;
        for v in CaptureNoise::value_variants() {
            let clap_name = v.to_possible_value().unwrap().get_name().to_string();
            assert_eq!(
                serde_json::to_value(v).unwrap(),
                serde_json::Value::String(clap_name)
            );
        }
        let parse = crate::options::parse::<CaptureNoise>;
        assert_eq!(parse("noise", "none"), Ok(CaptureNoise::None));
        assert_eq!(
            parse("noise", "loud"),
            Err(r#"noise "loud": expected "sensor" or "none""#.into())
        );
    }

    #[test]
    fn colour_calibration_recovers_each_primary_within_the_noise_prediction() {
        let ov: Vec<String> = [
            "sensor.crop_px=24",
            "sensor.pitch_um=60",
            "sensor.response=rgb-bayer",
            "display.primaries=lcd",
            "display.image=rgb:letter:F@8+shape:disk@8+checker:2@8",
            // 12-bit frames with a dark level clear of 0 (as tests/it/matrix_calibration.rs):
            // Mono8 quantisation and clipping at 0 are outside the Gaussian prediction.
            "noise.bit_depth=12",
            "noise.dark_offset_dn=8",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let sys =
            crate::system::System::build(&crate::scene::load_scene(None, &ov).unwrap()).unwrap();
        let m = crate::matrix::compute_matrix(
            &sys,
            &crate::render::RenderSettings::lattice(4, 3, false),
        );
        let (noise, _) = crate::capture::exposure_and_dark(&sys, &m, 5);
        let set = CalibrationSettings {
            noise: Some(noise),
            seed: 7,
            dark_frame: false,
            threshold_sigma: 0.0,
            progress: false,
        };
        let (h_est, reports) = calibrate_colour(&m.h, &m.offset, 3, &set).unwrap();
        assert_eq!((h_est.rows, h_est.cols), (m.h.rows, m.h.cols));
        assert_eq!(reports.len(), 3);
        // Per primary: the error of the multiplexed columns is the predicted noise
        // (docs/physics.md §7.3) within 10 % (about 10⁵ noisy elements each).
        for (p, r) in reports.iter().enumerate() {
            assert_eq!(r.patterns, 64);
            let ratio = r.without_dark_frame.other_columns / r.predicted_noise_other_columns;
            assert!((ratio - 1.0).abs() < 0.1, "primary {p}: {ratio} {r:?}");
        }
        // It can fail: primary R's estimate against primary G's true block is far outside it.
        let est = h_est.hsplit(3).unwrap();
        let tru = m.h.hsplit(3).unwrap();
        let mut a = vec![0.0; 64];
        let mut b = vec![0.0; 64];
        let (mut err, mut norm) = (0.0, 0.0);
        for i in 0..m.h.rows {
            est[0].row_dense_into(i, &mut a);
            tru[1].row_dense_into(i, &mut b);
            for k in 1..64 {
                err += (a[k] - b[k]).powi(2);
                norm += b[k] * b[k];
            }
        }
        let wrong = (err / norm).sqrt();
        assert!(
            wrong > 3.0 * reports[1].predicted_noise_other_columns,
            "{wrong}"
        );
    }

    #[test]
    fn fwht_matches_dense_product_and_is_orthogonal() {
        let n = 64;
        let x: Vec<f64> = (0..n).map(|i| ((i * 37 + 11) % 17) as f64 - 8.0).collect();
        let mut y = x.clone();
        fwht(&mut y);
        for i in 0..n {
            let d: f64 = (0..n).map(|k| sylvester(i, k) * x[k]).sum();
            assert!((y[i] - d).abs() < 1e-12);
        }
        // H H = N I: transforming twice gives N x.
        fwht(&mut y);
        for i in 0..n {
            assert!((y[i] - n as f64 * x[i]).abs() < 1e-9);
        }
    }

    #[test]
    fn patterns_are_orthogonal_and_separable() {
        // U Uᵀ = N I for the ±1 patterns of order 64 (an 8×8 object).
        let n = 64;
        for i in 0..n {
            for j in 0..n {
                let dot: f64 = (0..n).map(|k| sylvester(i, k) * sylvester(j, k)).sum();
                assert_eq!(dot, if i == j { n as f64 } else { 0.0 });
            }
        }
        assert!(display_pattern(n, 0).iter().all(|&u| u == 1.0));
        // The paper's order N = 4096 (64×64 object): U Uᵀ = N I, row by row as H_N h_i = N e_i.
        let n4 = 4096;
        let mut h = vec![0.0; n4];
        for i in 0..n4 {
            for (k, v) in h.iter_mut().enumerate() {
                *v = sylvester(i, k);
            }
            fwht(&mut h);
            for (k, &v) in h.iter().enumerate() {
                assert_eq!(v, if k == i { n4 as f64 } else { 0.0 }, "pattern {i}");
            }
        }
        // Pattern a·8 + b is the outer product of rows a and b of H_8.
        for a in 0..8 {
            for b in 0..8 {
                for r in 0..8 {
                    for c in 0..8 {
                        assert_eq!(
                            sylvester(a * 8 + b, r * 8 + c),
                            sylvester(a, r) * sylvester(b, c)
                        );
                    }
                }
            }
        }
    }
}

/// H_true and the offset a calibration starts from: a matrix loaded from disk, or `None` in
/// [`CalibrationJob::matrix`] to compute it from the scene.
pub struct TrueMatrix {
    /// H_true.
    pub h: CsrMatrix,
    /// Capture of an all-black object, one value per row.
    pub offset: Vec<f32>,
    /// Object size (width, height).
    pub object: (usize, usize),
    /// Object planes: 1, or 3 for a colour H (column blocks R, G, B).
    pub planes: usize,
    /// Where it came from (a path), named in error messages.
    pub source: String,
}

impl TrueMatrix {
    /// Reads H_true from a scipy CSR `.npz` ([`crate::matrix::load_matrix`]) with the offset
    /// beside it; a missing offset is taken as 0, and the flag returned says so.
    pub fn load(
        path: &std::path::Path,
        object: Option<(usize, usize)>,
    ) -> Result<(TrueMatrix, bool), crate::io::IoError> {
        let lm = crate::matrix::load_matrix(path, object, None)?;
        let found = lm.offset.is_some();
        let offset = lm.offset.unwrap_or_else(|| vec![0.0; lm.h.rows]);
        let m = TrueMatrix {
            h: lm.h,
            offset,
            object: lm.object,
            planes: lm.planes,
            source: path.display().to_string(),
        };
        Ok((m, found))
    }
}

/// The noise of the simulated captures (`calibrate --noise`; Python's `noise=`): one definition
/// for clap and the Python module, the first paragraph of each variant's comment its `--help`
/// line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum CaptureNoise {
    /// The scene's [noise] section.
    Sensor,
    /// An ideal camera.
    None,
}

/// A whole simulated calibration of a scene (`stscam calibrate`).
pub struct CalibrationJob {
    /// H_true from disk, or `None` to compute it from the scene at `spp` and `seed`.
    pub matrix: Option<TrueMatrix>,
    /// Samples per pixel of a computed H and of rendered frames.
    pub spp: u32,
    /// Seed of the tracer and of the noise.
    pub seed: u64,
    /// The scene's sensor noise model (exposure from the all-white frame), or none.
    pub noise: CaptureNoise,
    /// Store the dark-frame-subtracted estimate.
    pub dark_frame: bool,
    /// Render every pattern with the tracer instead of taking frames from H_true.
    pub render_frames: bool,
    /// Threshold of the stored entries in predicted noise σ.
    pub threshold_sigma: f64,
    /// Show progress on a terminal.
    pub progress: bool,
}

/// What [`calibrate_scene`] made.
pub struct CalibrationRun {
    /// H_est (thresholded), the shape of H_true (a colour H: blocks R, G, B).
    pub h_est: CsrMatrix,
    /// The report: one, or one per primary (R, G, B) for a colour H.
    pub reports: Vec<CalibrationReport>,
    /// Object planes: 1, or 3 for a colour H.
    pub planes: usize,
    /// Object size (width, height).
    pub object: (usize, usize),
    /// Where H_true came from: a path, or "computed".
    pub source: String,
    /// The noise model with its exposure, if any.
    pub noise: Option<SensorNoise>,
    /// Seconds spent computing H_true (0 when loaded).
    pub matrix_s: f64,
    /// Seconds spent rendering frames.
    pub render_s: f64,
    /// Seconds spent in the calibration transform.
    pub calibrate_s: f64,
}

/// Runs a calibration job on `sys` (the CLI's `calibrate` and the Python module call this):
/// H_true (loaded or computed), the exposure from its all-white frame, the frames (from H_true
/// or rendered) and [`calibrate`]; a colour H (a colour display, or a loaded H with three
/// column blocks) by [`calibrate_colour`], N patterns per primary from H_true, as `demo
/// --colour` calibrates. Errors are the user's to fix (one line).
pub fn calibrate_scene(
    sys: &crate::system::System,
    job: &CalibrationJob,
) -> Result<CalibrationRun, String> {
    use crate::render::RenderSettings;
    use std::time::Instant;
    let rs = RenderSettings::lattice(job.spp, job.seed, job.progress);
    let n_obj = sys.display.width_px * sys.display.height_px;
    // A colour H (a colour display, or a loaded H with three column blocks) is calibrated
    // per primary from H_true; rendered colour frames are not simulated. Refused before work.
    let colour = job
        .matrix
        .as_ref()
        .map_or(sys.display.primaries.is_some(), |m| m.planes > 1);
    if colour && job.render_frames {
        return Err(
            "--render: a colour H is calibrated per primary from H_true (hadamard::calibrate_colour); rendered colour frames are not simulated, leave out --render".into(),
        );
    }
    let t0 = Instant::now();
    let computed;
    let tm = match &job.matrix {
        Some(m) => m,
        None => {
            if !n_obj.is_power_of_two() {
                return Err(format!(
                    "display.image: the object is {}x{} = {n_obj} pixels, not a power of two; Sylvester's Hadamard patterns need N = 2^k (e.g. a 64x64 target, `@64`)",
                    sys.display.width_px, sys.display.height_px
                ));
            }
            // H, and with --render one frame per pattern plus the all-white one.
            let renders = 1 + if job.render_frames {
                n_obj as u64 + 1
            } else {
                0
            };
            crate::render::check_limits(sys, &rs, renders, "--spp").map_err(|e| e.to_string())?;
            let m = crate::matrix::compute_matrix(sys, &rs);
            computed = TrueMatrix {
                h: m.h,
                offset: m.offset,
                object: m.object,
                planes: m.planes,
                source: "computed".to_string(),
            };
            &computed
        }
    };
    let TrueMatrix {
        h: h_true,
        offset,
        object,
        planes,
        source: source_desc,
    } = tm;
    let (object, planes) = (*object, (*planes).max(1));
    let matrix_s = t0.elapsed().as_secs_f64();
    // The patterns of one primary (a colour H is calibrated a primary at a time).
    let n = h_true.cols / planes;
    // The calibration forms every frame value (rows x patterns) in f64, row by row.
    crate::limits::check_bytes(
        "--matrix",
        &format!("the calibration's {} x {n} frame values", h_true.rows),
        h_true.rows as u128 * n as u128 * 8,
    )
    .map_err(|e| format!("{source_desc}: {e}"))?;
    if !n.is_power_of_two() {
        return Err(format!(
            "{source_desc}: the object has {n} pixels, not a power of two; Sylvester's Hadamard patterns need N = 2^k"
        ));
    }
    let sensor_noise = if job.noise == CaptureNoise::Sensor {
        // The exposure from the all-white frame (every primary white for a colour display).
        let peak = crate::recon::discrepancy::white_peak(h_true, offset);
        if !(peak > 0.0 && peak.is_finite()) {
            return Err(format!(
                "{source_desc}: an all-white object gives no light on the sensor, so the exposure cannot be set (use --noise none)"
            ));
        }
        Some(SensorNoise::new(&sys.scene.noise, peak))
    } else {
        None
    };
    let t0 = Instant::now();
    let frames: Option<Vec<Vec<f32>>> = if job.render_frames {
        if object != (sys.display.width_px, sys.display.height_px) {
            return Err(format!(
                "--render: the matrix object {}x{} differs from the scene's display target {}x{}",
                object.0, object.1, sys.display.width_px, sys.display.height_px
            ));
        }
        let bytes = (n as u64 + 1) * h_true.rows as u64 * 4;
        if bytes > 4 << 30 {
            return Err(format!(
                "--render: {} frames of {} values need {:.1} GiB; use a smaller object (display.image=...@16) or crop (sensor.crop_px)",
                n + 1,
                h_true.rows,
                bytes as f64 / f64::from(1u32 << 30)
            ));
        }
        crate::render::check_limits(sys, &rs, n as u64 + 1, "--spp").map_err(|e| e.to_string())?;
        let pb = crate::progress::Progress::new(job.progress, n as u64 + 1, "calibration frames");
        let quiet = RenderSettings {
            progress: false,
            estimator: Default::default(),
            ..rs.clone()
        };
        let fr = render_frames(sys, &quiet, || pb.inc(1));
        pb.finish_and_clear();
        Some(fr)
    } else {
        None
    };
    let render_s = t0.elapsed().as_secs_f64();
    let source = match &frames {
        Some(f) => FrameSource::Rendered(f),
        None => FrameSource::Matrix,
    };
    let settings = CalibrationSettings {
        noise: sensor_noise.clone(),
        seed: job.seed,
        dark_frame: job.dark_frame,
        threshold_sigma: job.threshold_sigma,
        progress: job.progress,
    };
    let t0 = Instant::now();
    let (h_est, reports) = if planes > 1 {
        calibrate_colour(h_true, offset, planes, &settings)
            .map_err(|e| format!("{source_desc}: {e}"))?
    } else {
        let c = calibrate(h_true, offset, source, &settings)
            .map_err(|e| format!("{source_desc}: {e}"))?;
        (c.h_est, vec![c.report])
    };
    Ok(CalibrationRun {
        h_est,
        reports,
        planes,
        object,
        source: source_desc.clone(),
        noise: sensor_noise,
        matrix_s,
        render_s,
        calibrate_s: t0.elapsed().as_secs_f64(),
    })
}
