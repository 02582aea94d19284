//! Addressable, stateless sample generator: every random number is a pure function of
//! (seed, pixel, sample index, dimension), so images are bit-identical for any thread count
//! and any sample can be regenerated alone.
//!
//! Two kinds:
//! - `Lattice` (default): a rank-1 Kronecker lattice in the 5 camera dimensions (pixel x, y,
//!   lens u, v, wavelength) with the R_d generator of Roberts (α_k = g⁻ᵏ, gᵈ⁺¹ = g + 1), and a
//!   per-pixel, per-dimension Cranley–Patterson shift from a hash of (seed, pixel, dimension).
//!   Each sample is marginally uniform (unbiased); within a pixel the points are well spread
//!   (quasi-Monte Carlo), which cuts the noise at edges and across the Bragg band.
//!   When the sample count N is known (a render), the lattice is instead a rank-1 Korobov
//!   lattice z = (1, a, a², a³, a⁴) mod N (Korobov 1959), found by searching a. Its worst
//!   two-dimensional projection must reach a Zaremba index (the smallest
//!   max(1,|h_j|)·max(1,|h_k|) over its dual vectors; Zaremba 1966, Niederreiter 1992 ch. 5,
//!   Sloan & Joe 1994) of 0.095 N; among the rules that do, the one whose worst 3-D projection
//!   has the largest Zaremba index is used. Its 2-D projections integrate edges (vHOE and target
//!   boundaries) more accurately than those of R_5 (paper scene, relative RMSE against a
//!   4096-spp reference: 2.2 % against 3.2 % at N = 64, 0.86 % against 1.11 % at 256, 0.58 %
//!   against 0.82 % at 512). The 3-D step changes the rule only at N = 1024 and 2048 of the
//!   powers of two, and renders better there (at 1024 the best 2-D rule lost to R_5; paper
//!   scene, 128 × 128 crop, seeds 1–3, against an 8192-spp reference: 1024 points 0.84–0.90 %
//!   with it, 0.69–0.75 % with R_5, 0.63–0.71 % with the 3-D choice; 2048 points 0.36–0.42 %,
//!   0.52–0.54 %, 0.32–0.34 %). Where no Korobov rule reaches 0.095 N (N = 16, 32, odd powers
//!   of small primes, …) and above `MAX_KOROBOV_N` samples, R_5 is used.
//! - `Independent`: every number an independent hash of (seed, pixel, index, dimension).
//!
//! Hash: the splitmix64/Murmur3 finaliser, applied to a chained combination of the inputs.
//!
//! Lattice sources: N. M. Korobov, Dokl. Akad. Nauk SSSR 124, 1207 (1959) (the rules
//! (1, a, a², …)); S. K. Zaremba, Ann. Mat. Pura Appl. 73, 293 (1966) (the index);
//! H. Niederreiter, Random Number Generation and Quasi-Monte Carlo Methods (SIAM 1992), ch. 5;
//! I. H. Sloan & S. Joe, Lattice Methods for Multiple Integration (Oxford 1994).

mod path_rng;
pub use path_rng::PathRng;

/// Number of dimensions a camera sample uses.
pub const DIMS: usize = 5;

/// Which sequence to use (`render --sampler`, Python's `sampler=`: one definition for clap,
/// serde and the Python module, see [`crate::options`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum SamplerKind {
    /// Cranley–Patterson-rotated rank-1 lattice: a Korobov rule searched for the spp, or R_5.
    Lattice,
    /// Independent hashed random numbers.
    Independent,
    /// Owen-scrambled 5-D Sobol' points (`sampler::sobol`).
    Sobol,
}

/// Owen-scrambled Sobol' points in 5 dimensions (Sobol' 1967 with the direction numbers of
/// Joe & Kuo 2008, `new-joe-kuo-6.21201`, dimensions 1–5; the nested uniform scramble of Owen
/// 1995 in the hash-based form of Burley 2020, "Practical Hash-based Owen Scrambling", JCGT
/// 9(4), with the permutation constants of Vegdahl 2021). One Owen scramble of the index (it
/// maps every aligned block of 2^m indices onto an aligned block) and one of each coordinate,
/// all seeded from (seed, pixel): the first 2^m samples of a pixel are a scrambled (t, m, 5)-net,
/// the pixel pair (dimensions 0, 1) a (0, m, 2)-net, and each sample is marginally uniform on
/// [0, 1)^5. Unlike padding independent 2-D sets, the joint pixel–lens projections are
/// stratified too, which matters here: where a ray meets the plate depends on both.
pub mod sobol {
    use super::DIMS;

    /// Direction numbers (32-bit) from the degree `s`, coefficients `a` and initial `m` of a
    /// primitive polynomial, by the Sobol'/Bratley–Fox recurrence.
    const fn directions(s: usize, a: u32, m: [u32; 3]) -> [u32; 32] {
        let mut v = [0u32; 32];
        let mut k = 0;
        while k < 32 {
            if k < s {
                v[k] = m[k] << (31 - k);
            } else {
                v[k] = v[k - s] ^ (v[k - s] >> s);
                let mut j = 1;
                while j < s {
                    if (a >> (s - 1 - j)) & 1 != 0 {
                        v[k] ^= v[k - j];
                    }
                    j += 1;
                }
            }
            k += 1;
        }
        v
    }

    /// Direction numbers of the van der Corput sequence (bit reversal).
    const fn van_der_corput() -> [u32; 32] {
        let mut v = [0u32; 32];
        let mut k = 0;
        while k < 32 {
            v[k] = 1 << (31 - k);
            k += 1;
        }
        v
    }

    /// Dimension 1 is van der Corput's (every m = 1, no recurrence); then Joe & Kuo's
    /// dimensions 2–5: (s, a, m) = (1, 0, 1), (2, 1, 1 3), (3, 1, 1 3 1), (3, 2, 1 1 1).
    const DIRECTIONS: [[u32; 32]; DIMS] = [
        van_der_corput(),
        directions(1, 0, [1, 0, 0]),
        directions(2, 1, [1, 3, 0]),
        directions(3, 1, [1, 3, 1]),
        directions(3, 2, [1, 1, 1]),
    ];

    /// The first `D` (≤ 5) coordinates of the Sobol' point of `index` (natural order, not Gray
    /// code) as 32-bit fractions; `D` = 2 is a (0, 2)-sequence.
    #[inline]
    pub fn point<const D: usize>(index: u32) -> [u32; D] {
        const { assert!(D <= DIMS) };
        let mut x = [0u32; D];
        let mut i = index;
        while i != 0 {
            let k = i.trailing_zeros() as usize;
            for (xd, dir) in x.iter_mut().zip(&DIRECTIONS) {
                *xd ^= dir[k];
            }
            i &= i - 1;
        }
        x
    }

    /// Laine–Karras-style hash permutation with Vegdahl's constants: each bit is flipped by a
    /// function of the bits below it and the seed.
    #[inline]
    fn lk_permute(mut x: u32, seed: u32) -> u32 {
        x ^= x.wrapping_mul(0x3d20_adea);
        x = x.wrapping_add(seed);
        x = x.wrapping_mul((seed >> 16) | 1);
        x ^= x.wrapping_mul(0x0552_6c56);
        x ^= x.wrapping_mul(0x53a2_2864);
        x
    }

    /// Nested uniform (Owen) scramble of a 32-bit fraction: each bit flipped by a hash of the
    /// bits above it (more significant) and the seed.
    #[inline]
    pub fn owen_scramble(x: u32, seed: u32) -> u32 {
        lk_permute(x.reverse_bits(), seed).reverse_bits()
    }

    /// A 32-bit fraction to the midpoint of its cell in (0, 1).
    #[inline]
    pub fn to_unit(x: u32) -> f64 {
        (f64::from(x) + 0.5) * (1.0 / 4_294_967_296.0)
    }
}

/// Padded 2-D point sets for the user side of 3-D scenes (pbrt-v4's `PaddedSobolSampler`,
/// Pharr, Jakob & Humphreys 2023, §8.7): the `n` samples of one pixel draw a pair of numbers
/// for a given purpose (a light's area sample at the first vertex, the first BSDF direction)
/// from the first `n` points of a 2-D Sobol' (0, 2)-sequence, Owen-scrambled per coordinate
/// and visited in an order permuted per pair, both seeded from `key` (a hash of the pixel, the
/// branch and the pair's purpose). For `n` a power of two the `n` points are a scrambled
/// (0, m, 2)-net; each point is marginally uniform on (0, 1)² (unbiased), and the permutation
/// decorrelates the pair from the camera's dimensions and from the other pairs.
pub mod padded {
    use super::{mix64, sobol};

    /// A pseudo-random permutation of [0, n) indexed by `i`, seeded by `p` (Kensler 2013,
    /// "Correlated Multi-Jittered Sampling", Pixar Technical Memo 13-01: a hash that is a
    /// bijection on the next power of two, cycle-walked into [0, n)). `i` must be below `n`.
    #[inline]
    pub fn permute(mut i: u32, n: u32, p: u32) -> u32 {
        debug_assert!(i < n);
        let mut w = n - 1;
        w |= w >> 1;
        w |= w >> 2;
        w |= w >> 4;
        w |= w >> 8;
        w |= w >> 16;
        loop {
            i ^= p;
            i = i.wrapping_mul(0xe170_893d);
            i ^= p >> 16;
            i ^= (i & w) >> 4;
            i ^= p >> 8;
            i = i.wrapping_mul(0x0929_eb3f);
            i ^= p >> 23;
            i ^= (i & w) >> 1;
            i = i.wrapping_mul(1 | (p >> 27));
            i = i.wrapping_mul(0x6935_fa69);
            i ^= (i & w) >> 11;
            i = i.wrapping_mul(0x74dc_b303);
            i ^= (i & w) >> 2;
            i = i.wrapping_mul(0x9e50_1cc3);
            i ^= (i & w) >> 2;
            i = i.wrapping_mul(0xc860_a3df);
            i &= w;
            i ^= i >> 5;
            if i < n {
                break;
            }
        }
        ((u64::from(i) + u64::from(p)) % u64::from(n)) as u32
    }

    /// Point `index` (< `n`) of the padded pair seeded by `key`, in (0, 1)².
    #[inline]
    pub fn pair(key: u64, index: u32, n: u32) -> [f64; 2] {
        let h = mix64(key);
        let j = permute(index, n, h as u32);
        let x = sobol::point::<2>(j);
        let s = mix64(h);
        [
            sobol::to_unit(sobol::owen_scramble(x[0], s as u32)),
            sobol::to_unit(sobol::owen_scramble(x[1], (s >> 32) as u32)),
        ]
    }
}

/// 64-bit finaliser (splitmix64).
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Hash of a tuple of words.
#[inline]
pub fn hash(words: &[u64]) -> u64 {
    words
        .iter()
        .fold(0x6A09_E667_F3BC_C909u64, |h, &w| mix64(h ^ mix64(w)))
}

/// Uniform double in [0, 1) from the top 53 bits of a hash.
#[inline]
pub fn to_unit(h: u64) -> f64 {
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// R_d generator for d = 5: g is the positive root of x⁶ = x + 1.
const G5: f64 = 1.134_724_138_401_519_4;

fn alphas() -> [f64; DIMS] {
    let mut a = [0.0; DIMS];
    let mut p = 1.0;
    for v in a.iter_mut() {
        p /= G5;
        *v = p;
    }
    a
}

/// Largest sample count for which a Korobov lattice is searched (the search costs O(N²)).
pub const MAX_KOROBOV_N: u64 = 4096;

/// Smallest worst-projection Zaremba index, relative to N, for which a Korobov rule is used.
/// Measured on the paper scene (440 × 440, relative RMSE against a 4096-spp reference, seeds
/// 1–3): the best rules at N = 256 (index 0.098 N) and 512 (0.117 N) beat R_5 by 1.3× and 1.4×
/// in error, the one at 128 (0.117 N) ties with it (1.55–1.57 % against 1.50–1.59 %); N = 32
/// (0.094 N) and 16 (0.062 N), where R_5 renders better, stay below. At N = 4 and 8 the best
/// rule repeats dimensions (z = (1, 3, 1, 3, 1)), which its independent per-dimension shifts keep
/// unbiased; at 8 it still renders better than R_5 (12.0 % against 15.3 % at 440 × 440). It was 0.15
/// before (CHANGELOG.md), which admitted, of the powers of two, only 4 and 64.
pub const KOROBOV_MIN_QUALITY: f64 = 0.095;

/// A rank-1 Korobov lattice rule with N points in `DIMS` dimensions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LatticeRule {
    /// Number of points.
    pub n: u64,
    /// Generating vector (1, a, a², …) mod N.
    pub z: [u64; DIMS],
}

fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

fn mod_inverse(a: u64, n: u64) -> Option<u64> {
    let (mut t, mut new_t, mut r, mut new_r) = (0i128, 1i128, i128::from(n), i128::from(a % n));
    while new_r != 0 {
        let q = r / new_r;
        (t, new_t) = (new_t, t - q * new_t);
        (r, new_r) = (new_r, r - q * new_r);
    }
    (r == 1).then(|| (if t < 0 { t + i128::from(n) } else { t }) as u64)
}

/// `r` (in 0..n) as the representative of its residue class in (−N/2, N/2].
#[inline]
fn centred(r: u64, n: u64) -> i64 {
    if r > n / 2 {
        r as i64 - n as i64
    } else {
        r as i64
    }
}

/// Zaremba index of the 2-D lattice {(i·zj, i·zk) mod N}: the smallest
/// max(1,|h_j|)·max(1,|h_k|) over nonzero dual vectors h (h_j·zj + h_k·zk ≡ 0 mod N).
fn zaremba_2d(zj: u64, zk: u64, n: u64) -> u64 {
    let Some(inv) = mod_inverse(zk, n) else {
        return 1;
    };
    let mut best = n;
    let half = n as i64 / 2;
    for hj in 1..=half {
        // h_k ≡ −h_j·zj·zk⁻¹ (mod N), taken in (−N/2, N/2].
        let r = ((n - (hj as u64 * zj % n) % n) % n) * inv % n;
        let hk = centred(r, n);
        best = best.min(hj as u64 * hk.unsigned_abs().max(1));
    }
    best
}

/// Zaremba index of the 3-D lattice {i·(za, zb, zc) mod N}: the smallest product of
/// max(1,|h|) over nonzero dual vectors h (h·z ≡ 0 mod N), or `cap` if none is below it (the
/// search stops at `cap`).
fn zaremba_3d(z: [u64; 3], n: u64, cap: u64) -> u64 {
    let Some(inv) = mod_inverse(z[2], n) else {
        return 1;
    };
    let half = n as i64 / 2;
    let mut best = cap.min(n);
    // h = (h0, h1, h2) and −h are both dual vectors: take h0 ≥ 0, and h1 > 0 when h0 = 0.
    for h0 in 0..=half {
        let m0 = h0.max(1) as u64;
        if m0 > best {
            break;
        }
        let lim = (best / m0).min(half as u64) as i64;
        for h1 in -lim..=lim {
            if h0 == 0 && h1 <= 0 {
                continue;
            }
            let m01 = m0 * h1.unsigned_abs().max(1);
            if m01 > best {
                continue;
            }
            let s = (h0 as u64 * z[0] % n + h1.rem_euclid(n as i64) as u64 * z[1] % n) % n;
            let h2 = centred((n - s) % n * inv % n, n);
            best = best.min(m01 * h2.unsigned_abs().max(1));
        }
    }
    best
}

impl LatticeRule {
    /// The Korobov rule the lattice sampler uses for `n` points, or `None` where no rule has a
    /// worst 2-D Zaremba index of at least `KOROBOV_MIN_QUALITY`·N (and for n < 2 or
    /// n > `MAX_KOROBOV_N`). Among the rules that pass, the one whose worst 3-D projection has
    /// the largest Zaremba index is chosen, ties going to the larger worst 2-D index and then
    /// to the smallest a (deterministic).
    ///
    /// The search costs O(N²) (≈ 0.25 s at N = 4096), so its result is kept for the process:
    /// datasets and sweeps render many times at one spp.
    pub fn korobov(n: u64) -> Option<LatticeRule> {
        use std::collections::HashMap;
        use std::sync::{Mutex, OnceLock};
        static FOUND: OnceLock<Mutex<HashMap<u64, Option<LatticeRule>>>> = OnceLock::new();
        let found = FOUND.get_or_init(Default::default);
        // A panic elsewhere while the lock was held leaves the map valid: use it anyway.
        if let Some(&rule) = found.lock().unwrap_or_else(|e| e.into_inner()).get(&n) {
            return rule;
        }
        let rule = Self::korobov_search(n);
        found
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(n, rule);
        rule
    }

    /// The search behind [`Self::korobov`].
    fn korobov_search(n: u64) -> Option<LatticeRule> {
        let min_index = KOROBOV_MIN_QUALITY * n as f64;
        // `min_by_key` keeps the first of equal keys: ties go to the smallest a.
        korobov_rules(n)
            .filter(|&(_, worst2)| worst2 as f64 >= min_index)
            .map(|(rule, worst2)| (rule, worst2, rule.worst_zaremba_3d()))
            .min_by_key(|&(_, worst2, worst3)| std::cmp::Reverse((worst3, worst2)))
            .map(|(rule, _, _)| rule)
    }

    /// The Korobov rule for `n` points maximising the worst 2-D Zaremba index alone (ties to
    /// the smallest a), with that index relative to N (its quality), whether or not
    /// [`Self::korobov`] would use it; `None` for n < 2 or n > `MAX_KOROBOV_N`.
    pub fn korobov_best(n: u64) -> Option<(LatticeRule, f64)> {
        korobov_rules(n)
            .min_by_key(|&(_, worst2)| std::cmp::Reverse(worst2))
            .map(|(r, w)| (r, w as f64 / n as f64))
    }

    /// The smallest Zaremba index over the rule's 3-D projections.
    pub fn worst_zaremba_3d(&self) -> u64 {
        let z = self.z;
        let mut worst = self.n;
        for i in 0..DIMS {
            for j in i + 1..DIMS {
                for k in j + 1..DIMS {
                    worst = worst.min(zaremba_3d([z[i], z[j], z[k]], self.n, worst));
                }
            }
        }
        worst
    }
}

/// Every Korobov rule (1, a, a², …) mod n with a coprime to n, in increasing a, with the
/// Zaremba index of its worst 2-D projection. Empty for n < 2 or n > `MAX_KOROBOV_N`. Small
/// powers of two have no good 5-D Korobov rule (a⁴ ≡ 1 mod 16 collapses two dimensions).
fn korobov_rules(n: u64) -> impl Iterator<Item = (LatticeRule, u64)> {
    let range = if (2..=MAX_KOROBOV_N).contains(&n) {
        2..n
    } else {
        2..2
    };
    range.filter(move |&a| gcd(a, n) == 1).map(move |a| {
        let mut z = [1u64; DIMS];
        for d in 1..DIMS {
            z[d] = z[d - 1] * a % n;
        }
        let mut worst = u64::MAX;
        for j in 0..DIMS {
            for k in j + 1..DIMS {
                worst = worst.min(zaremba_2d(z[j], z[k], n));
            }
        }
        (LatticeRule { n, z }, worst)
    })
}

/// The sample stream of one pixel.
#[derive(Clone, Copy, Debug)]
pub struct PixelSampler {
    kind: SamplerKind,
    seed: u64,
    pixel: u64,
    shift: [f64; DIMS],
    alpha: [f64; DIMS],
    rule: Option<LatticeRule>,
    /// Owen-scramble seeds: the index's, then one per dimension.
    owen: [u32; 1 + DIMS],
}

impl PixelSampler {
    /// Starts the stream of `pixel` for `seed`.
    pub fn new(kind: SamplerKind, seed: u64, pixel: u64) -> Self {
        let mut shift = [0.0; DIMS];
        for (d, s) in shift.iter_mut().enumerate() {
            *s = to_unit(hash(&[seed, pixel, d as u64, 0x0053_4849_4654]));
        }
        let mut owen = [0u32; 1 + DIMS];
        if kind == SamplerKind::Sobol {
            let h = hash(&[seed, pixel, 0x0053_4F42_4F4C]);
            for (k, o) in owen.iter_mut().enumerate() {
                *o = (mix64(h ^ k as u64) >> 32) as u32;
            }
        }
        PixelSampler {
            kind,
            seed,
            pixel,
            shift,
            alpha: alphas(),
            rule: None,
            owen,
        }
    }

    /// Uses a Korobov lattice rule instead of R_5 (for `Lattice` only).
    pub fn with_rule(mut self, rule: Option<LatticeRule>) -> Self {
        self.rule = rule;
        self
    }

    /// Samples `start`, `start + 1`, … into `out` (one per element), each equal to
    /// [`Self::get`] of its index. With a Korobov rule the lattice indices i·z_d mod N are
    /// stepped by adding z_d (no division per sample).
    #[inline]
    pub fn get_batch(&self, start: u64, out: &mut [[f64; DIMS]]) {
        match (self.kind, self.rule) {
            (SamplerKind::Lattice, Some(rule)) => {
                let n = rule.n;
                let inv_n = 1.0 / n as f64;
                let i0 = start % n;
                let mut k = [0u64; DIMS];
                for (kd, z) in k.iter_mut().zip(&rule.z) {
                    *kd = (i0 * z) % n;
                }
                for u in out.iter_mut() {
                    for d in 0..DIMS {
                        let v = self.shift[d] + k[d] as f64 * inv_n;
                        u[d] = if v >= 1.0 { v - 1.0 } else { v };
                        // z_d < N, so one subtraction keeps k_d in [0, N).
                        let next = k[d] + rule.z[d];
                        k[d] = if next >= n { next - n } else { next };
                    }
                }
            }
            _ => {
                for (j, u) in out.iter_mut().enumerate() {
                    *u = self.get(start + j as u64);
                }
            }
        }
    }

    /// Sample `index`, all dimensions, each in [0, 1).
    #[inline]
    pub fn get(&self, index: u64) -> [f64; DIMS] {
        let mut u = [0.0; DIMS];
        match (self.kind, self.rule) {
            (SamplerKind::Lattice, Some(rule)) => {
                let i = index % rule.n;
                let inv_n = 1.0 / rule.n as f64;
                for ((ud, shift), z) in u.iter_mut().zip(&self.shift).zip(&rule.z) {
                    let v = shift + ((i * z) % rule.n) as f64 * inv_n;
                    *ud = if v >= 1.0 { v - 1.0 } else { v };
                }
            }
            (SamplerKind::Lattice, None) => {
                let i = index as f64;
                for ((ud, shift), alpha) in u.iter_mut().zip(&self.shift).zip(&self.alpha) {
                    let v = shift + (i * alpha).fract();
                    *ud = if v >= 1.0 { v - 1.0 } else { v };
                }
            }
            (SamplerKind::Independent, _) => {
                for (d, v) in u.iter_mut().enumerate() {
                    *v = to_unit(hash(&[self.seed, self.pixel, index, d as u64]));
                }
            }
            (SamplerKind::Sobol, _) => {
                // The index's low 32 bits run through the sequence; higher bits (past 2^32
                // samples of one pixel) start an independently scrambled copy.
                let i = index as u32;
                let hi = index >> 32;
                let mut o = self.owen;
                if hi != 0 {
                    for (k, ok) in o.iter_mut().enumerate() {
                        *ok ^= (mix64(hi ^ ((k as u64) << 40)) >> 32) as u32;
                    }
                }
                let x = sobol::point::<DIMS>(sobol::owen_scramble(i, o[0]));
                for (d, (ud, v)) in u.iter_mut().zip(x).enumerate() {
                    *ud = sobol::to_unit(sobol::owen_scramble(v, o[1 + d]));
                }
            }
        }
        u
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn korobov_rule_stratifies_every_dimension() {
        for n in [16u64, 32] {
            assert_eq!(
                LatticeRule::korobov(n),
                None,
                "n = {n} has no good 5-D Korobov rule"
            );
        }
        // The rules the render uses at the sample counts of docs/performance.md's tables (the
        // indices found independently by an exhaustive search in Python: 64 → a = 19 with
        // worst index 11, 256 → 55 with 25, 512 → 115 with 60).
        for (n, a, index) in [(64u64, 19u64, 11u64), (256, 55, 25), (512, 115, 60)] {
            let (rule, q) = LatticeRule::korobov_best(n).unwrap();
            assert_eq!(
                (rule.z[1], (q * n as f64).round() as u64),
                (a, index),
                "n {n}"
            );
        }
        for n in [64u64, 100, 128, 256, 257, 512] {
            let rule = LatticeRule::korobov(n).unwrap();
            assert_eq!(rule.z[0], 1);
            for &z in &rule.z {
                // Each 1-D projection is a permutation of 0..n: one point per stratum.
                let mut seen = vec![false; n as usize];
                for i in 0..n {
                    seen[(i * z % n) as usize] = true;
                }
                assert!(seen.iter().all(|&s| s), "n {n}, z {z}");
            }
            // The chosen rule's worst 2-D projection beats the plain (1, 1, …) diagonal by far.
            let worst = (0..DIMS)
                .flat_map(|j| (j + 1..DIMS).map(move |k| (j, k)))
                .map(|(j, k)| zaremba_2d(rule.z[j], rule.z[k], n))
                .min()
                .unwrap();
            eprintln!("n {n}: a = {}, worst Zaremba index {worst}", rule.z[1]);
            assert!(
                worst as f64 >= KOROBOV_MIN_QUALITY * n as f64,
                "n {n}: Zaremba index {worst}"
            );
        }
        assert_eq!(LatticeRule::korobov(1), None);
        assert_eq!(LatticeRule::korobov(MAX_KOROBOV_N + 1), None);
        assert_eq!(zaremba_2d(1, 1, 64), 1);
    }

    #[test]
    fn korobov_prefers_the_best_worst_3d_projection() {
        // Rules found independently (exhaustive search in Python over every a coprime to N:
        // worst 2-D index ≥ 0.095 N, then the largest worst 3-D index, then the largest worst
        // 2-D index, then the smallest a). The 3-D step changes the rule only at 1024
        // (149 → 285) and 2048 (423 → 471), where it renders better (docs/performance.md).
        for (n, a, worst3) in [
            (8u64, 3u64, 1u64),
            (64, 19, 2),
            (128, 19, 2),
            (256, 55, 2),
            (512, 115, 4),
            (1024, 285, 6),
            (2048, 471, 8),
        ] {
            let rule = LatticeRule::korobov(n).unwrap();
            assert_eq!((rule.z[1], rule.worst_zaremba_3d()), (a, worst3), "n {n}");
        }
        assert_eq!(LatticeRule::korobov_best(1024).unwrap().0.z[1], 149);
        assert_eq!(LatticeRule::korobov_best(2048).unwrap().0.z[1], 423);
    }

    #[test]
    fn zaremba_3d_equals_a_brute_force_search() {
        let brute = |z: [u64; 3], n: u64| {
            let h = n as i64 / 2;
            let mut best = n;
            for a in -h..=h {
                for b in -h..=h {
                    for c in -h..=h {
                        let dot = a * z[0] as i64 + b * z[1] as i64 + c * z[2] as i64;
                        if (a, b, c) != (0, 0, 0) && dot.rem_euclid(n as i64) == 0 {
                            let m = |x: i64| x.unsigned_abs().max(1);
                            best = best.min(m(a) * m(b) * m(c));
                        }
                    }
                }
            }
            best
        };
        let mut checked = 0;
        for n in [31u64, 32, 45, 64] {
            for a in (2..n).step_by(3) {
                if gcd(a, n) != 1 {
                    continue;
                }
                let z = [1, a, a * a % n];
                assert_eq!(zaremba_3d(z, n, n), brute(z, n), "n {n} a {a}");
                checked += 1;
            }
        }
        assert!(checked > 30);
        // A rule with a short dual vector: (1, 1, 2) has h = (1, 1, −1).
        assert_eq!(zaremba_3d([1, 1, 2], 64, 64), 1);
        // The cap bounds the search from above.
        assert_eq!(zaremba_3d([1, 19, 41], 64, 1), 1);
    }

    #[test]
    fn batches_equal_single_draws() {
        for (kind, rule) in [
            (SamplerKind::Lattice, LatticeRule::korobov(64)),
            (SamplerKind::Lattice, LatticeRule::korobov(100)),
            (SamplerKind::Lattice, None),
            (SamplerKind::Independent, None),
            (SamplerKind::Sobol, None),
        ] {
            let s = PixelSampler::new(kind, 5, 777).with_rule(rule);
            // Across the end of the lattice (index ≥ N wraps) and from unaligned starts.
            for start in [0u64, 3, 57, 60, 63, 64, 99, 250] {
                let mut out = [[0.0; DIMS]; 16];
                s.get_batch(start, &mut out[..13]);
                for (j, u) in out[..13].iter().enumerate() {
                    assert_eq!(*u, s.get(start + j as u64), "{kind:?} start {start} j {j}");
                }
            }
        }
    }

    /// Without a rule the lattice is the R_5 sequence: point i is shift + i·α (mod 1),
    /// computed here independently of `get`.
    #[test]
    fn the_lattice_without_a_rule_is_r5() {
        let lat = PixelSampler::new(SamplerKind::Lattice, 3, 41);
        let a = alphas();
        let shift = lat.get(0);
        for i in [1u64, 63, 64, 1000] {
            let u = lat.get(i);
            for d in 0..DIMS {
                let want = (shift[d] + i as f64 * a[d]).rem_euclid(1.0);
                assert!(
                    (u[d] - want).abs() < 1e-9,
                    "i {i} d {d}: {} vs {want}",
                    u[d]
                );
            }
        }
        let kor = lat.with_rule(LatticeRule::korobov(64));
        assert_ne!(kor.get(1), lat.get(1));
    }

    #[test]
    fn generator_root() {
        assert!((G5.powi(6) - G5 - 1.0).abs() < 1e-14);
    }

    #[test]
    fn addressable_and_deterministic() {
        for kind in [
            SamplerKind::Lattice,
            SamplerKind::Independent,
            SamplerKind::Sobol,
        ] {
            let a = PixelSampler::new(kind, 7, 12345);
            let b = PixelSampler::new(kind, 7, 12345);
            assert_eq!(a.get(99), b.get(99));
            assert_ne!(a.get(99), PixelSampler::new(kind, 8, 12345).get(99));
            assert_ne!(a.get(99), PixelSampler::new(kind, 7, 12346).get(99));
        }
    }

    /// χ² test of uniformity of each dimension over many pixels (10 bins, 9 dof; the 99.9 %
    /// critical value is 27.9).
    #[test]
    fn marginals_are_uniform() {
        // The lattice with its Korobov rule and without (R_5).
        for (kind, ruled) in [
            (SamplerKind::Lattice, true),
            (SamplerKind::Lattice, false),
            (SamplerKind::Independent, true),
            (SamplerKind::Sobol, true),
        ] {
            let n_pix = 4000u64;
            let spp = 8u64;
            let mut bins = [[0u64; 10]; DIMS];
            for p in 0..n_pix {
                let rule = if ruled {
                    LatticeRule::korobov(spp)
                } else {
                    None
                };
                let s = PixelSampler::new(kind, 1, p).with_rule(rule);
                for i in 0..spp {
                    for (d, v) in s.get(i).iter().enumerate() {
                        assert!((0.0..1.0).contains(v));
                        bins[d][(v * 10.0) as usize] += 1;
                    }
                }
            }
            let expect = (n_pix * spp) as f64 / 10.0;
            for b in bins {
                let chi2: f64 = b
                    .iter()
                    .map(|&c| (c as f64 - expect).powi(2) / expect)
                    .sum();
                assert!(chi2 < 27.9, "{kind:?}: χ² = {chi2}");
            }
        }
    }

    /// The unscrambled Sobol' points equal the published sequence (Joe & Kuo's direction
    /// numbers: scipy.stats.qmc.Sobol(5, scramble=False).random(16), which runs in Gray-code
    /// order: its point k is index k ^ (k >> 1) here).
    #[test]
    fn sobol_points_equal_the_published_sequence() {
        let scipy: [[f64; DIMS]; 16] = [
            [0.0, 0.0, 0.0, 0.0, 0.0],
            [0.5, 0.5, 0.5, 0.5, 0.5],
            [0.75, 0.25, 0.25, 0.25, 0.75],
            [0.25, 0.75, 0.75, 0.75, 0.25],
            [0.375, 0.375, 0.625, 0.875, 0.375],
            [0.875, 0.875, 0.125, 0.375, 0.875],
            [0.625, 0.125, 0.875, 0.625, 0.625],
            [0.125, 0.625, 0.375, 0.125, 0.125],
            [0.1875, 0.3125, 0.9375, 0.4375, 0.5625],
            [0.6875, 0.8125, 0.4375, 0.9375, 0.0625],
            [0.9375, 0.0625, 0.6875, 0.1875, 0.3125],
            [0.4375, 0.5625, 0.1875, 0.6875, 0.8125],
            [0.3125, 0.1875, 0.3125, 0.5625, 0.9375],
            [0.8125, 0.6875, 0.8125, 0.0625, 0.4375],
            [0.5625, 0.4375, 0.0625, 0.8125, 0.1875],
            [0.0625, 0.9375, 0.5625, 0.3125, 0.6875],
        ];
        for (k, want) in scipy.iter().enumerate() {
            let g = (k ^ (k >> 1)) as u32;
            let got = sobol::point::<DIMS>(g).map(|v| f64::from(v) / 4_294_967_296.0);
            assert_eq!(&got, want, "point {k}");
        }
    }

    /// The smallest t for which `pts` (2^m points) is a (t, m, 2)-net: 2^t points in every
    /// elementary box of area 2^(t − m).
    fn net_quality(pts: &[(f64, f64)], m: u32) -> u32 {
        let is_net = |t: u32| {
            let k = m - t;
            (0..=k).all(|a| {
                let b = k - a;
                let mut count = vec![0u32; 1 << k];
                for &(x, y) in pts {
                    let i = (x * f64::from(1u32 << a)) as usize;
                    let j = (y * f64::from(1u32 << b)) as usize;
                    count[(i << b) | j] += 1;
                }
                count.iter().all(|&c| c == 1 << t)
            })
        };
        (0..=m).find(|&t| is_net(t)).unwrap_or(m + 1)
    }

    /// Every aligned block of 2^m scrambled samples of a pixel keeps the Sobol' net quality
    /// (scipy's unscrambled points give t = 0 for the pixel pair and t ≤ 3 for every pair up to
    /// m = 8): each coordinate one point per interval of 2^-m, every pair of dimensions a
    /// (t ≤ 3, m, 2)-net. Independent points and a wrong direction number fail it.
    #[test]
    fn sobol_blocks_are_nets() {
        let worst = |s: &PixelSampler, start: u64, m: u32| -> (u32, u32, u32) {
            let us: Vec<_> = (start..start + (1 << m)).map(|i| s.get(i)).collect();
            let mut one_d = 0;
            let mut pairs = 0;
            for d in 0..DIMS {
                // One point in each interval of 2^-m: count the intervals hit twice.
                let mut seen = vec![false; 1 << m];
                for u in &us {
                    let i = (u[d] * f64::from(1u32 << m)) as usize;
                    if std::mem::replace(&mut seen[i], true) {
                        one_d += 1;
                    }
                }
                for e in d + 1..DIMS {
                    let q: Vec<_> = us.iter().map(|u| (u[d], u[e])).collect();
                    pairs = pairs.max(net_quality(&q, m));
                }
            }
            let pix: Vec<_> = us.iter().map(|u| (u[0], u[1])).collect();
            (one_d, pairs, net_quality(&pix, m))
        };
        for pixel in 0..12u64 {
            let s = PixelSampler::new(SamplerKind::Sobol, 9, pixel);
            for m in 0..=8u32 {
                for block in [0u64, 1, 5] {
                    let (one_d, pairs, pix) = worst(&s, block << m, m);
                    assert_eq!(one_d, 0, "pixel {pixel} m {m} block {block}: 1-D strata");
                    assert!(pairs <= 3, "pixel {pixel} m {m} block {block}: t = {pairs}");
                    assert_eq!(pix, 0, "pixel {pixel} m {m} block {block}: pixel pair");
                }
            }
        }
        // Controls: independent points are not nets; neither is a flipped direction number.
        let ind = PixelSampler::new(SamplerKind::Independent, 9, 3);
        let (one_d, pairs, _) = worst(&ind, 0, 6);
        assert!(one_d > 0 && pairs > 3);
        let broken: Vec<_> = (0..64u32)
            .map(|i| {
                let x = sobol::point::<DIMS>(i);
                let y = if i & 4 != 0 {
                    x[1] ^ (1 << 29) ^ (1 << 30)
                } else {
                    x[1]
                };
                (
                    f64::from(x[0]) / 4_294_967_296.0,
                    f64::from(y) / 4_294_967_296.0,
                )
            })
            .collect();
        assert!(net_quality(&broken, 6) > 0);
    }

    /// Within a pixel the lattice is far better stratified than independent samples: the
    /// integration error of a smooth 5-D function at 64 samples is much lower.
    #[test]
    fn lattice_beats_independent_on_smooth_integrand() {
        let f = |u: [f64; DIMS]| {
            u.iter()
                .enumerate()
                .map(|(d, x)| ((d + 1) as f64 * x).cos() + x * x)
                .sum::<f64>()
        };
        let exact: f64 = (0..DIMS)
            .map(|d| ((d + 1) as f64).sin() / (d + 1) as f64 + 1.0 / 3.0)
            .sum();
        let rms = |kind, rule| {
            let mut e2 = 0.0;
            for p in 0..500u64 {
                let s = PixelSampler::new(kind, 3, p).with_rule(rule);
                let est: f64 = (0..64).map(|i| f(s.get(i))).sum::<f64>() / 64.0;
                e2 += (est - exact).powi(2);
            }
            (e2 / 500.0).sqrt()
        };
        let (lat, ind) = (
            rms(SamplerKind::Lattice, None),
            rms(SamplerKind::Independent, None),
        );
        let kor = rms(SamplerKind::Lattice, LatticeRule::korobov(64));
        let sob = rms(SamplerKind::Sobol, None);
        eprintln!("rms error: lattice {lat}, korobov {kor}, sobol {sob}, independent {ind}");
        assert!(sob < 0.25 * ind, "sobol {sob} independent {ind}");
        assert!(lat < 0.25 * ind, "lattice {lat} independent {ind}");
        assert!(kor < 0.25 * ind, "korobov {kor} independent {ind}");
    }

    #[test]
    fn padded_permutation_is_a_bijection_that_depends_on_the_seed() {
        for n in [1u32, 2, 3, 7, 16, 100, 1000, 1024] {
            let mut differs = false;
            for seed in [0u32, 1, 0xDEAD_BEEF, 0x8000_0001] {
                let mut seen = vec![false; n as usize];
                for i in 0..n {
                    let j = padded::permute(i, n, seed);
                    assert!(j < n, "n {n} seed {seed}: {i} -> {j}");
                    assert!(!seen[j as usize], "n {n} seed {seed}: {j} twice");
                    seen[j as usize] = true;
                    differs |= j != padded::permute(i, n, seed ^ 0x5555_5555);
                }
            }
            assert!(n < 3 || differs, "n {n}: the seed changes nothing");
        }
    }

    /// For n = 2^m the n points of a padded set are a (0, m, 2)-net: every elementary box of
    /// area 1/n (2^−a × 2^−b, a + b = m) holds exactly one point. Hashed points fail this.
    #[test]
    fn padded_pairs_are_nets_for_powers_of_two() {
        let one_per_box = |pts: &[[f64; 2]], m: u32| {
            (0..=m).all(|a| {
                let (nx, ny) = (1usize << a, 1usize << (m - a));
                let mut count = vec![0u32; nx * ny];
                for p in pts {
                    count[(p[0] * nx as f64) as usize * ny + (p[1] * ny as f64) as usize] += 1;
                }
                count.iter().all(|&c| c == 1)
            })
        };
        for m in [2u32, 5, 8] {
            let n = 1u32 << m;
            for key in [1u64, 2, 0xABCD] {
                let pts: Vec<[f64; 2]> = (0..n).map(|i| padded::pair(key, i, n)).collect();
                assert!(one_per_box(&pts, m), "m {m} key {key}");
                let other: Vec<[f64; 2]> = (0..n).map(|i| padded::pair(key + 7, i, n)).collect();
                assert_ne!(pts, other, "the key must change the set");
            }
            let hashed: Vec<[f64; 2]> = (0..n)
                .map(|i| {
                    [
                        to_unit(hash(&[9, u64::from(i), 0])),
                        to_unit(hash(&[9, u64::from(i), 1])),
                    ]
                })
                .collect();
            assert!(
                !one_per_box(&hashed, m),
                "m {m}: hashed points are not a net"
            );
        }
    }

    /// Each padded point is marginally uniform (over keys): χ² over an 8 × 8 grid of one
    /// point index of 20,000 keys, for n = 48 (not a power of two, so the cycle-walking path
    /// runs) and n = 64; 63 degrees of freedom, 99.9 % quantile 103.4. A point set squeezed
    /// into [0, 0.95)² fails.
    #[test]
    fn padded_points_are_uniform_over_keys_chi_square() {
        let chi2 = |f: &dyn Fn(u64) -> [f64; 2]| {
            let keys = 20_000u64;
            let mut count = [0u32; 64];
            for k in 0..keys {
                let p = f(k);
                count[(p[0] * 8.0) as usize * 8 + (p[1] * 8.0) as usize] += 1;
            }
            let e = keys as f64 / 64.0;
            count
                .iter()
                .map(|&c| (f64::from(c) - e).powi(2) / e)
                .sum::<f64>()
        };
        for (n, i) in [(48u32, 5u32), (48, 47), (64, 0), (64, 33)] {
            let x = chi2(&|k| padded::pair(k, i, n));
            assert!(x < 103.4, "n {n} index {i}: chi2 {x}");
            let squeezed = chi2(&|k| padded::pair(k, i, n).map(|v| 0.95 * v));
            assert!(
                squeezed > 103.4,
                "n {n} index {i}: squeezed chi2 {squeezed}"
            );
        }
    }
}
