//! Adaptive sample counts: a pilot finds where a render's noise is, and the pixels get their
//! samples in proportion to it.
//!
//! Model. A pixel's estimate from n samples has variance σ²/n. For a fixed total N·P samples
//! over P pixels, the squared error Σ σ²ₚ/nₚ is least with nₚ ∝ σₚ (Neyman allocation; e.g.
//! Cochran, *Sampling Techniques*, 3rd ed., §5.5). In the paper's scene the replicas of the
//! object hold nearly all the noise (a fifth of the pixels, 99.99 % of the variance, measured at
//! 64 spp), so the same samples spent there give an error of about a third.
//!
//! Method, for a mean of N samples per pixel:
//! 1. Pilot: two independent renders of h = max(1, ⌊N/16⌋) samples per pixel (seeds derived
//!    from the render's). Per pixel d = Σ_channels (A − B)², whose expectation is 2σ²/h; it is
//!    averaged over the 5 × 5 pixels around (a single pixel's d is itself very noisy, and the
//!    noise varies smoothly over a replica), giving s = √d̄ ∝ σ.
//! 2. Counts: nₚ = clamp(2^round(log₂(c·sₚ)), n_min, n_max) with n_min = max(1, ⌊N/16⌋),
//!    n_max = max(min(64·N, 2²⁰), N − 2h), and the largest c whose counts sum to at most
//!    (N − 2h)·P; then what rounding left of that budget goes to doubling counts, the pixels with the most
//!    noise per sample first. Powers of two are where the lattice sampler has its best rules,
//!    and a render searches one rule per distinct count (integer counts took 4–17× the time);
//!    rounding in log space costs about 4 % of the ideal allocation's efficiency. An image
//!    without noise in the pilot takes N − 2h everywhere. A few pixels may leave part of the
//!    budget unspent (a 1 × 1 crop at N = 16: 8 of 14).
//! 3. The render proper: pixel p takes nₚ samples of the render's own seed and sampler.
//!
//! Unbiased: the pilot's samples are not part of the image, and the counts depend only on the
//! pilot, whose streams are independent of the render's, so each pixel's value is the mean of
//! nₚ samples drawn after nₚ was fixed. Deterministic: the pilot images are (for any thread
//! count), and the counts are a sequential function of them.

use super::{Capture, RenderSettings};

/// Pilot samples per pixel of each of the two pilot renders for a mean of `spp` (≥ 1).
pub fn pilot_spp(spp: u32) -> u32 {
    (spp / 16).max(1)
}

/// The smallest mean sample count an adaptive render takes ([`check`]; below it
/// [`render`] is one plain pass): the pilot then takes 1/8 of the samples.
pub const MIN_ADAPTIVE_SPP: u32 = 16;

/// Why a render cannot be adaptive.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum AdaptiveError {
    /// Too few samples per pixel to share out.
    #[error(
        "--adaptive needs --spp of at least {MIN_ADAPTIVE_SPP} (got {0}): its pilot takes 1/8 of the samples"
    )]
    TooFewSamples(u32),
    /// A display-only scene's capture from a camera-side table is H·f: no samples.
    #[error(
        "--adaptive: a display-only scene's camera-side table is H, and its capture H·f + offset draws no samples"
    )]
    NothingToAllot,
}

/// That a render of `sys` with `set` (adaptive) and, if `tabled`, a camera-side table can
/// share out its samples.
pub fn check(
    sys: &crate::system::System,
    set: &RenderSettings,
    tabled: bool,
) -> Result<(), AdaptiveError> {
    if !set.adaptive {
        return Ok(());
    }
    if tabled && sys.world.is_none() {
        return Err(AdaptiveError::NothingToAllot);
    }
    if set.spp < MIN_ADAPTIVE_SPP {
        return Err(AdaptiveError::TooFewSamples(set.spp));
    }
    Ok(())
}

/// Radius of the square over which the pilot's squared differences are averaged.
const SMOOTH_RADIUS: usize = 2;

/// Largest count as a multiple of the mean.
const MAX_COUNT_FACTOR: u32 = 64;

/// Largest count of any pixel (bounds the per-pixel memory of a render from a camera-side
/// table, which lists a pixel's paths).
const MAX_COUNT: u32 = 1 << 20;

/// Tag of the pilot renders' seeds.
const PILOT_TAG: u64 = 0x7069_6c6f_745f_7370; // "pilot_sp"

/// What an adaptive render did with its samples (recorded in the capture's stats).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SampleCounts {
    /// Samples per pixel of each of the two pilot renders.
    pub pilot_spp: u32,
    /// The fewest samples a pixel took in the render proper.
    pub min_spp: u32,
    /// The most samples a pixel took.
    pub max_spp: u32,
    /// The mean over the pixels of the render proper (the pilot's 2·`pilot_spp` apart).
    pub mean_spp: f64,
}

/// Bytes per pixel that an adaptive render holds beyond a plain one's, for `values` values
/// (channels and spectral bins) per pixel, as a bound for the memory check
/// ([`super::check_limits`]): the two f32 pilot images, 8 bytes per value (the pilots draw no
/// spectral bins, so this bounds them), and 40 bytes for the allocation ([`allot`]: at most
/// 28 at once, the squared differences and the box mean's two passes in f64, then the u32
/// counts and their usize order, plus the counts kept through the render).
pub fn extra_bytes_per_pixel(values: u128) -> u128 {
    values * 8 + 40
}

/// The seed of pilot render `k` (0 or 1) of a render seeded `seed`.
pub(crate) fn pilot_seed(seed: u64, k: u64) -> u64 {
    crate::sampler::hash(&[seed, PILOT_TAG, k])
}

/// The render of `set` by `pass(settings, counts)`, which renders the image with each pixel's
/// count from `counts` (row major; `settings.spp` everywhere when `None`): with
/// `set.adaptive` (and `set.spp` at least [`MIN_ADAPTIVE_SPP`]) an adaptive render, `set.spp`
/// the mean samples per pixel, pilot included, the pilot's counters added to the image's;
/// otherwise one plain pass.
pub fn render(
    set: &RenderSettings,
    mut pass: impl FnMut(&RenderSettings, Option<&[u32]>) -> Capture,
) -> Capture {
    if !set.adaptive || set.spp < MIN_ADAPTIVE_SPP {
        return pass(set, None);
    }
    let h = pilot_spp(set.spp);
    let pilot = |k| RenderSettings {
        spp: h,
        seed: pilot_seed(set.seed, k),
        progress: false,
        spectral_bins: None,
        ..set.clone()
    };
    let a = pass(&pilot(0), None);
    let b = pass(&pilot(1), None);
    let counts = allot(&a, &b, set.spp, h);
    let mut cap = pass(set, Some(&counts));
    cap.stats.merge(&a.stats);
    cap.stats.merge(&b.stats);
    let n = counts.len().max(1) as f64;
    cap.stats.sample_counts = Some(SampleCounts {
        pilot_spp: h,
        min_spp: counts.iter().copied().min().unwrap_or(0),
        max_spp: counts.iter().copied().max().unwrap_or(0),
        mean_spp: counts.iter().map(|&c| f64::from(c)).sum::<f64>() / n,
    });
    cap
}

/// Each pixel's sample count from the pilot images `a` and `b` (of `h` samples each) for a
/// mean of `spp` samples per pixel, pilot included (module docs, step 2).
pub fn allot(a: &Capture, b: &Capture, spp: u32, h: u32) -> Vec<u32> {
    let (w, ht) = (a.width, a.height);
    let p = w * ht;
    let mut d = vec![0.0f64; p];
    for (ca, cb) in a.channels.iter().zip(&b.channels) {
        for ((d, &x), &y) in d.iter_mut().zip(ca).zip(cb) {
            let e = f64::from(x) - f64::from(y);
            if e.is_finite() {
                *d += e * e;
            }
        }
    }
    let s: Vec<f64> = box_mean(&d, w, ht, SMOOTH_RADIUS)
        .into_iter()
        .map(f64::sqrt)
        .collect();
    let left = spp.saturating_sub(2 * h).max(1);
    // The floor is the pilot's count: a pixel without noise in the pilot takes as many again.
    let n_min = h.clamp(1, left);
    let n_max = spp
        .saturating_mul(MAX_COUNT_FACTOR)
        .min(MAX_COUNT)
        .max(left);
    let budget = u64::from(left) * p as u64;
    let count = |c: f64, sp: f64| -> u32 {
        let x = c * sp;
        let n = if x >= 1.0 {
            // The power of two nearest in log space, kept below 2^31.
            2f64.powi(x.log2().round().min(31.0) as i32) as u32
        } else {
            0
        };
        n.clamp(n_min, n_max)
    };
    let total = |c: f64| -> u64 { s.iter().map(|&sp| u64::from(count(c, sp))).sum() };
    let s_max = s.iter().copied().fold(0.0, f64::max);
    let s_min = s
        .iter()
        .copied()
        .filter(|&x| x > 0.0)
        .fold(f64::INFINITY, f64::min);
    if !(s_max > 0.0 && s_max.is_finite()) {
        // No noise seen: every pixel alike.
        return vec![left; p];
    }
    // Bisection in log c for the largest c whose counts fit the budget: from c at which every
    // count is n_min to c at which every pixel with noise is at n_max.
    let (mut lo, mut hi) = ((0.5 / s_max).ln(), (2.0 * f64::from(n_max) / s_min).ln());
    if total(hi.exp()) <= budget {
        lo = hi;
    }
    for _ in 0..64 {
        let mid = 0.5 * (lo + hi);
        if total(mid.exp()) <= budget {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let mut counts: Vec<u32> = s.iter().map(|&sp| count(lo.exp(), sp)).collect();
    // What the rounding left: counts doubled (to the next power of two), the pixels with the
    // most noise per sample first (ties by index), while the budget allows.
    let mut spent: u64 = counts.iter().map(|&n| u64::from(n)).sum();
    let mut order: Vec<usize> = (0..p)
        .filter(|&i| s[i] > 0.0 && counts[i] < n_max)
        .collect();
    let gain = |i: usize| s[i] / f64::from(counts[i]);
    order.sort_by(|&i, &j| gain(j).total_cmp(&gain(i)).then(i.cmp(&j)));
    for i in order {
        let n = counts[i];
        let next = if n.is_power_of_two() {
            n.saturating_mul(2)
        } else {
            n.next_power_of_two()
        }
        .min(n_max);
        let extra = u64::from(next - n);
        if spent + extra <= budget {
            counts[i] = next;
            spent += extra;
        }
    }
    counts
}

/// The mean of `v` (row major, `w` × `h`) over the square of radius `r` around each pixel,
/// clipped to the image (a pass along the rows, then one along the columns).
fn box_mean(v: &[f64], w: usize, h: usize, r: usize) -> Vec<f64> {
    let pass = |src: &[f64], len: usize, stride: usize, lines: usize, step: usize| {
        let mut out = vec![0.0; src.len()];
        for l in 0..lines {
            let at = |i: usize| l * step + i * stride;
            for i in 0..len {
                let (a, b) = (i.saturating_sub(r), (i + r).min(len - 1));
                let sum: f64 = (a..=b).map(|j| src[at(j)]).sum();
                out[at(i)] = sum / (b - a + 1) as f64;
            }
        }
        out
    };
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let rows = pass(v, w, 1, h, w);
    pass(&rows, h, w, w, 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn capture(w: usize, h: usize, v: Vec<f32>) -> Capture {
        Capture {
            width: w,
            height: h,
            channel_names: vec!["Y"],
            channels: vec![v],
            spectral: Vec::new(),
            stats: Default::default(),
        }
    }

    /// The box mean against a direct double loop, on a ramp with a spike.
    #[test]
    fn box_mean_is_the_clipped_square_mean() {
        let (w, h) = (7, 5);
        let v: Vec<f64> = (0..w * h).map(|i| (i * i % 13) as f64).collect();
        let m = box_mean(&v, w, h, 2);
        for y in 0..h {
            for x in 0..w {
                let (mut s, mut n) = (0.0, 0.0);
                for yy in y.saturating_sub(2)..=(y + 2).min(h - 1) {
                    for xx in x.saturating_sub(2)..=(x + 2).min(w - 1) {
                        s += v[yy * w + xx];
                        n += 1.0;
                    }
                }
                assert!((m[y * w + x] - s / n).abs() < 1e-12, "({x}, {y})");
            }
        }
    }

    /// The budget is spent where rounding would leave it: uniform noise (every pixel at the
    /// same power of two before the fill), one very noisy pixel among faint ones (its count
    /// capped, which once stopped the search early), and odd means; tiny and hostile pilots
    /// (one pixel, NaN, infinities, the largest floats) give counts within the budget without
    /// a panic.
    #[test]
    fn counts_spend_the_budget_and_survive_odd_pilots() {
        let spent = |a: &Capture, b: &Capture, spp: u32| {
            let h = pilot_spp(spp);
            let c = allot(a, b, spp, h);
            let budget = u64::from(spp - 2 * h) * c.len() as u64;
            let total: u64 = c.iter().map(|&n| u64::from(n)).sum();
            assert!(total <= budget, "{total} > {budget}");
            let cap = MAX_COUNT.max(spp - 2 * h);
            assert!(c.iter().all(|&n| n >= 1 && n <= cap));
            total as f64 / budget as f64
        };
        let (w, h) = (30, 20);
        let flat = capture(w, h, vec![0.0; w * h]);
        let noisy = |i: usize| ((i * 7919 % 17) as f32 - 8.0) * 0.01;
        let uniform = capture(w, h, (0..w * h).map(noisy).collect());
        let constant = capture(w, h, vec![0.5; w * h]);
        for spp in [16, 64, 100, 1000] {
            let f = spent(&uniform, &flat, spp);
            assert!(f > 0.9, "uniform noise at {spp}: {f}");
            // Every pixel alike: all round to one power of two, the fill takes the rest.
            let f = spent(&constant, &flat, spp);
            assert!(f > 0.95, "equal noise at {spp}: {f}");
        }
        let (w2, h2) = (200, 200);
        let mut hot: Vec<f32> = (0..w2 * h2).map(|i| 1e-4 * noisy(i)).collect();
        hot[w2 * 100 + 100] = 1e6;
        let f = spent(
            &capture(w2, h2, hot),
            &capture(w2, h2, vec![0.0; w2 * h2]),
            64,
        );
        assert!(f > 0.9, "one hot pixel: {f}");
        // One pixel: 16 spp leaves 14; the power of two below is all it can take.
        let one = allot(&capture(1, 1, vec![1.0]), &capture(1, 1, vec![0.0]), 16, 1);
        assert_eq!(one, vec![8]);
        let odd = vec![
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            -f32::MAX,
            0.0,
        ];
        let a = capture(3, 2, odd.clone());
        let b = capture(3, 2, odd.iter().rev().copied().collect());
        for spp in [16, 17, 31, u32::MAX] {
            spent(&a, &b, spp);
        }
        assert!(allot(&capture(0, 0, vec![]), &capture(0, 0, vec![]), 64, 4).is_empty());
    }

    /// The counts fit the budget, take most of it, are powers of two above the floor, and grow
    /// with the pilot's noise: a noisy half of the image gets the samples, the quiet half the
    /// floor; no noise gives every pixel the same count.
    #[test]
    fn counts_follow_the_noise_within_the_budget() {
        let (w, h) = (40, 20);
        let a = capture(w, h, vec![1.0; w * h]);
        let noisy: Vec<f32> = (0..w * h)
            .map(|i| {
                if i % w < w / 2 {
                    1.0
                } else {
                    1.0 + 0.1 * ((i * 7919 % 17) as f32 - 8.0)
                }
            })
            .collect();
        let b = capture(w, h, noisy);
        let spp = 64;
        let hp = pilot_spp(spp);
        let counts = allot(&a, &b, spp, hp);
        let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
        let budget = u64::from(spp - 2 * hp) * (w * h) as u64;
        assert!(
            total <= budget && total as f64 > 0.6 * budget as f64,
            "{total} of {budget}"
        );
        let n_min = spp / 16;
        for (i, &c) in counts.iter().enumerate() {
            assert!(c == n_min || c.is_power_of_two(), "{c}");
            // Quiet columns more than the smoothing radius from the noisy half: the floor.
            if i % w + SMOOTH_RADIUS < w / 2 {
                assert_eq!(c, n_min, "pixel {i}");
            }
            if i % w >= w / 2 + SMOOTH_RADIUS {
                assert!(c >= 64, "pixel {i}: {c}");
            }
        }
        let flat = allot(&a, &a, spp, hp);
        assert!(flat.iter().all(|&c| c == spp - 2 * hp));
    }
}
