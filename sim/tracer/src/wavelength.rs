//! Wavelength importance sampling around each path's Bragg wavelength.
//!
//! Model (docs/design.md "Estimator decisions"): the spectral integrand of a path is dominated by the
//! product of the in- and out-coupling efficiencies, a band a few nm wide centred on the
//! path's exact Bragg wavelength λ_B (docs/physics.md §3.2, closed form), with side lobes whose
//! positions and heights change across the field. The sampler draws λ = λ_B + Δ with Δ from a
//! tabulated, piecewise-constant density shaped like the measured end-to-end throughput of the
//! field whose λ_B is nearest the path's own (a set of tables, one per field row, each measured
//! once per scene by tracing), mixed with a uniform density over the simulation band:
//!   p(λ) = (1 − f_u)·p_table(λ − λ_B) + f_u/(λ_max − λ_min).
//! The table is chosen by λ_B alone, a deterministic function of the camera ray, so the
//! estimator f/p is unbiased; the uniform part keeps p > 0 wherever the integrand can be
//! non-zero, and samples outside the band carry zero. Paths without a Bragg wavelength use the
//! uniform density alone. Inversion is monotone in u (a guide table makes it O(1)), so
//! stratified (quasi-random) inputs stay stratified in λ.
//!
//! Multiplexed films (several gratings, `optics::multiplex`): each grating j has its own Bragg
//! wavelength λ_B,j for the path and its own set of tables, and the density is the mixture
//!   p(λ) = (1 − f_u)·(1/M)·Σ_j p_table,j(λ − λ_B,j) + f_u/(λ_max − λ_min)
//! over the M gratings that have a Bragg wavelength for the path (and a non-zero index
//! modulation), with equal weights. One uniform number picks the component (the part of u above
//! f_u is split into M equal intervals, each inverted within its component, so stratification
//! carries over) and the estimator divides by the whole mixture's density, so every grating's
//! replicas are weighted correctly whichever component drew λ (the one-sample mixture estimator,
//! equivalent to the balance heuristic; Veach 1997, §9.2). With one grating the draws and the
//! density are computed by exactly the single-band code of before (bit-identical).

/// One piecewise-constant density of Δλ.
#[derive(Clone, Debug)]
struct Table {
    /// Density per nm of each bin (integrates to 1).
    density: Vec<f64>,
    /// Cumulative distribution at bin edges (len = bins + 1).
    cdf: Vec<f64>,
    /// `guide[j]` is the first bin whose upper CDF edge exceeds j/len.
    guide: Vec<u32>,
}

impl Table {
    fn new(shape: &[f64], bin_nm: f64) -> Table {
        let mut shape: Vec<f64> = shape
            .iter()
            .map(|&v| if v.is_finite() && v > 0.0 { v } else { 0.0 })
            .collect();
        if shape.iter().sum::<f64>() <= 0.0 {
            shape.iter_mut().for_each(|v| *v = 1.0);
        }
        let total: f64 = shape.iter().sum();
        let mut cdf = Vec::with_capacity(shape.len() + 1);
        let mut acc = 0.0;
        cdf.push(0.0);
        for v in &shape {
            acc += v / total;
            cdf.push(acc);
        }
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        let density: Vec<f64> = shape.iter().map(|v| v / total / bin_nm).collect();
        let n = density.len();
        let mut guide = Vec::with_capacity(n);
        let mut i = 0usize;
        for j in 0..n {
            let v = j as f64 / n as f64;
            while i + 1 < n && cdf[i + 1] <= v {
                i += 1;
            }
            guide.push(i as u32);
        }
        Table {
            density,
            cdf,
            guide,
        }
    }

    /// Bin index and fraction within it for v ∈ [0, 1).
    #[inline]
    fn invert(&self, v: f64) -> (usize, f64) {
        let n = self.density.len();
        let mut i = self.guide[((v * n as f64) as usize).min(n - 1)] as usize;
        while i + 1 < n && self.cdf[i + 1] <= v {
            i += 1;
        }
        let span = self.cdf[i + 1] - self.cdf[i];
        (
            i,
            if span > 0.0 {
                ((v - self.cdf[i]) / span).clamp(0.0, 1.0)
            } else {
                0.5
            },
        )
    }
}

/// The tables of one grating: piecewise-constant densities of Δλ keyed by the Bragg
/// wavelength of the field each was measured at.
#[derive(Clone, Debug)]
struct TableSet {
    /// Bragg wavelength each table was measured at, ascending.
    keys_nm: Vec<f64>,
    tables: Vec<Table>,
    /// Where to start looking up a key: `key_guide[c]` is the number of keys below the start
    /// of cell c of an even grid over [first key, last key] (a starting guess, corrected by a
    /// short walk, so the result is exactly that of a binary search).
    key_guide: Vec<u32>,
    /// Cells per nm of that grid.
    key_cells_per_nm: f64,
    /// Whether this grating's component takes part in the mixture (false for a grating without
    /// index modulation: it diffracts nothing).
    active: bool,
}

/// Tabulated densities of Δλ (keyed by λ_B, one set per grating) plus a uniform part over the
/// band.
#[derive(Clone, Debug)]
pub struct WavelengthSampler {
    lo_nm: f64,
    hi_nm: f64,
    uniform_fraction: f64,
    /// Δλ of the first bin edge, nm.
    table_start_nm: f64,
    /// Bin width, nm.
    bin_nm: f64,
    /// The first grating's tables, held inline (the single-grating hot path reads them without
    /// an indirection); a copy of `sets[0]`.
    first: TableSet,
    /// One table set per grating, in the film's order.
    sets: Vec<TableSet>,
}

/// Cells of the key guide per key.
const KEY_GUIDE_CELLS_PER_KEY: usize = 4;

impl TableSet {
    fn new(shapes: &[(f64, Vec<f64>)], bin_nm: f64, active: bool) -> TableSet {
        let mut sorted: Vec<&(f64, Vec<f64>)> = shapes
            .iter()
            .filter(|(k, s)| k.is_finite() && !s.is_empty())
            .collect();
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (keys_nm, tables): (Vec<f64>, Vec<Table>) = if sorted.is_empty() {
            (vec![0.0], vec![Table::new(&[1.0], bin_nm)])
        } else {
            sorted
                .iter()
                .map(|(k, s)| (*k, Table::new(s, bin_nm)))
                .unzip()
        };
        let cells = KEY_GUIDE_CELLS_PER_KEY * keys_nm.len();
        let span = keys_nm[keys_nm.len() - 1] - keys_nm[0];
        let key_cells_per_nm = if span > 0.0 { cells as f64 / span } else { 0.0 };
        let key_guide = (0..cells)
            .map(|c| {
                let start = keys_nm[0] + c as f64 / key_cells_per_nm.max(f64::MIN_POSITIVE);
                keys_nm.partition_point(|&k| k < start) as u32
            })
            .collect();
        TableSet {
            keys_nm,
            tables,
            key_guide,
            key_cells_per_nm,
            active,
        }
    }

    /// The number of keys below `lambda_nm` (`keys_nm.partition_point(|&k| k < lambda_nm)`),
    /// from the guide and a short walk.
    #[inline]
    fn keys_below(&self, lambda_nm: f64) -> usize {
        let keys = &self.keys_nm;
        let x = (lambda_nm - keys[0]) * self.key_cells_per_nm;
        // NaN and negative x go to cell 0; the walk corrects any cell.
        let c = if x > 0.0 {
            (x as usize).min(self.key_guide.len() - 1)
        } else {
            0
        };
        let mut i = self.key_guide[c] as usize;
        while i > 0 && !(keys[i - 1] < lambda_nm) {
            i -= 1;
        }
        while i < keys.len() && keys[i] < lambda_nm {
            i += 1;
        }
        i
    }

    /// The table whose key is nearest `lambda_bragg_nm`.
    #[inline]
    fn table_for(&self, lambda_bragg_nm: f64) -> &Table {
        let i = self.keys_below(lambda_bragg_nm);
        let j = if i == 0 {
            0
        } else if i == self.keys_nm.len()
            || lambda_bragg_nm - self.keys_nm[i - 1] <= self.keys_nm[i] - lambda_bragg_nm
        {
            i - 1
        } else {
            i
        };
        &self.tables[j]
    }
}

impl WavelengthSampler {
    /// Appends every number of the sampler to `out`, exactly (f64 as their bits, little
    /// endian, with the lengths of its arrays): what a cache key of the camera side hashes
    /// (`render::camera_table::design_key`). `first` is a copy of `sets[0]` and is left out.
    pub fn key_bytes(&self, out: &mut Vec<u8>) {
        let f = |out: &mut Vec<u8>, v: f64| out.extend_from_slice(&v.to_bits().to_le_bytes());
        let n = |out: &mut Vec<u8>, v: usize| out.extend_from_slice(&(v as u64).to_le_bytes());
        let floats = |out: &mut Vec<u8>, v: &[f64]| {
            n(out, v.len());
            v.iter().for_each(|&x| f(out, x));
        };
        let words = |out: &mut Vec<u8>, v: &[u32]| {
            n(out, v.len());
            v.iter()
                .for_each(|&x| out.extend_from_slice(&x.to_le_bytes()));
        };
        floats(
            out,
            &[
                self.lo_nm,
                self.hi_nm,
                self.uniform_fraction,
                self.table_start_nm,
                self.bin_nm,
            ],
        );
        n(out, self.sets.len());
        for set in &self.sets {
            out.push(u8::from(set.active));
            f(out, set.key_cells_per_nm);
            floats(out, &set.keys_nm);
            words(out, &set.key_guide);
            for t in &set.tables {
                floats(out, &t.density);
                floats(out, &t.cdf);
                words(out, &t.guide);
            }
        }
    }

    /// Builds the sampler of a one-grating film from non-negative shapes, each tabulated on
    /// equal bins starting at Δλ = `table_start_nm` and measured for a field whose Bragg
    /// wavelength is the key. A shape that sums to zero falls back to a flat table; no shapes
    /// at all gives one flat table.
    pub fn new(
        lo_nm: f64,
        hi_nm: f64,
        uniform_fraction: f64,
        table_start_nm: f64,
        bin_nm: f64,
        shapes: &[(f64, Vec<f64>)],
    ) -> Self {
        Self::new_multiplexed(
            lo_nm,
            hi_nm,
            uniform_fraction,
            table_start_nm,
            bin_nm,
            &[(shapes.to_vec(), true)],
        )
    }

    /// Builds the sampler of a multiplexed film: one (shapes, active) pair per grating, in the
    /// film's order (see [`Self::new`] for the shapes; an inactive grating takes no part in
    /// the mixture).
    pub fn new_multiplexed(
        lo_nm: f64,
        hi_nm: f64,
        uniform_fraction: f64,
        table_start_nm: f64,
        bin_nm: f64,
        per_grating: &[(Vec<(f64, Vec<f64>)>, bool)],
    ) -> Self {
        let mut sets: Vec<TableSet> = per_grating
            .iter()
            .map(|(shapes, active)| TableSet::new(shapes, bin_nm, *active))
            .collect();
        if sets.is_empty() {
            sets.push(TableSet::new(&[], bin_nm, true));
        }
        WavelengthSampler {
            lo_nm,
            hi_nm,
            uniform_fraction,
            table_start_nm,
            bin_nm,
            first: sets[0].clone(),
            sets,
        }
    }

    /// The band's width in nm.
    pub fn band_nm(&self) -> f64 {
        self.hi_nm - self.lo_nm
    }

    /// Number of tables (over all gratings).
    pub fn table_count(&self) -> usize {
        self.sets.iter().map(|s| s.tables.len()).sum()
    }

    /// Number of gratings (table sets).
    pub fn grating_count(&self) -> usize {
        self.sets.len()
    }

    /// Draws a wavelength from one uniform number `u` ∈ [0,1) for a one-grating path with
    /// Bragg wavelength `lambda_bragg_nm`; returns (λ in nm, pdf per nm).
    #[inline]
    pub fn sample(&self, u: f64, lambda_bragg_nm: Option<f64>) -> (f64, f64) {
        self.sample_mixed(u, lambda_bragg_nm, self.uniform_fraction)
    }

    /// As [`Self::sample`] with the uniform fraction `fu` chosen by the caller (e.g. larger for
    /// paths that also see the scene straight through the plate, a broadband contribution). The
    /// choice must depend only on the camera ray, never on the wavelength drawn. Uses the first
    /// grating's tables.
    #[inline]
    pub fn sample_mixed(&self, u: f64, lambda_bragg_nm: Option<f64>, fu: f64) -> (f64, f64) {
        let set = &self.first;
        let Some(lb) = lambda_bragg_nm else {
            return (self.lo_nm + u * self.band_nm(), 1.0 / self.band_nm());
        };
        let table = set.table_for(lb);
        let lambda = if u < fu {
            self.lo_nm + (u / fu) * self.band_nm()
        } else {
            let v = ((u - fu) / (1.0 - fu)).min(1.0 - 1e-16);
            let (i, frac) = table.invert(v);
            lb + self.table_start_nm + (i as f64 + frac) * self.bin_nm
        };
        (lambda, self.pdf_in(table, lambda, lb, fu))
    }

    /// Draws a wavelength for a path whose Bragg wavelength for grating j is
    /// `lambda_bragg_nm[j]` (the mixture of the module notes); returns (λ in nm, pdf per nm).
    /// With one grating this is [`Self::sample_mixed`].
    #[inline]
    pub fn sample_multiplexed(
        &self,
        u: f64,
        lambda_bragg_nm: &[Option<f64>],
        fu: f64,
    ) -> (f64, f64) {
        if self.sets.len() == 1 {
            let lb = lambda_bragg_nm.first().copied().flatten();
            let lb = if self.first.active { lb } else { None };
            return self.sample_mixed(u, lb, fu);
        }
        let mut comps = [0usize; crate::scene::MAX_GRATINGS];
        let mut m = 0;
        for (j, (set, lb)) in self.sets.iter().zip(lambda_bragg_nm).enumerate() {
            if set.active && lb.is_some() && m < comps.len() {
                comps[m] = j;
                m += 1;
            }
        }
        if m == 0 {
            return (self.lo_nm + u * self.band_nm(), 1.0 / self.band_nm());
        }
        let comps = &comps[..m];
        let lambda = if u < fu {
            self.lo_nm + (u / fu) * self.band_nm()
        } else {
            let v = ((u - fu) / (1.0 - fu)).min(1.0 - 1e-16);
            let scaled = v * m as f64;
            let c = (scaled as usize).min(m - 1);
            let v = (scaled - c as f64).clamp(0.0, 1.0 - 1e-16);
            let j = comps[c];
            let lb = lambda_bragg_nm[j].unwrap_or_default();
            let (i, frac) = self.sets[j].table_for(lb).invert(v);
            lb + self.table_start_nm + (i as f64 + frac) * self.bin_nm
        };
        (lambda, self.pdf_mixture(comps, lambda, lambda_bragg_nm, fu))
    }

    /// Density of the mixture over the components `comps` (grating indices) at `lambda_nm`.
    fn pdf_mixture(
        &self,
        comps: &[usize],
        lambda_nm: f64,
        lambda_bragg_nm: &[Option<f64>],
        fu: f64,
    ) -> f64 {
        let uni = if self.in_band(lambda_nm) {
            fu / self.band_nm()
        } else {
            0.0
        };
        let mut tab = 0.0;
        for &j in comps {
            let lb = lambda_bragg_nm[j].unwrap_or_default();
            tab += self.table_density(self.sets[j].table_for(lb), lambda_nm, lb);
        }
        uni + (1.0 - fu) * tab / comps.len() as f64
    }

    /// Density (per nm) of drawing `lambda_nm` for a path with Bragg wavelengths
    /// `lambda_bragg_nm` per grating (the scene's uniform fraction).
    pub fn pdf_multiplexed(&self, lambda_nm: f64, lambda_bragg_nm: &[Option<f64>]) -> f64 {
        let fu = self.uniform_fraction;
        let comps: Vec<usize> = (0..self.sets.len())
            .filter(|&j| self.sets[j].active && lambda_bragg_nm.get(j).copied().flatten().is_some())
            .collect();
        if comps.is_empty() {
            return if self.in_band(lambda_nm) {
                1.0 / self.band_nm()
            } else {
                0.0
            };
        }
        self.pdf_mixture(&comps, lambda_nm, lambda_bragg_nm, fu)
    }

    /// The scene's uniform fraction.
    pub fn uniform_fraction(&self) -> f64 {
        self.uniform_fraction
    }

    #[inline]
    fn table_density(&self, table: &Table, lambda_nm: f64, lambda_bragg_nm: f64) -> f64 {
        let x = (lambda_nm - lambda_bragg_nm - self.table_start_nm) / self.bin_nm;
        if x >= 0.0 && x < table.density.len() as f64 {
            table.density[x as usize]
        } else {
            0.0
        }
    }

    #[inline]
    fn pdf_in(&self, table: &Table, lambda_nm: f64, lambda_bragg_nm: f64, fu: f64) -> f64 {
        let uni = if self.in_band(lambda_nm) {
            fu / self.band_nm()
        } else {
            0.0
        };
        uni + (1.0 - fu) * self.table_density(table, lambda_nm, lambda_bragg_nm)
    }

    /// Density (per nm) of drawing `lambda_nm` for a one-grating path with Bragg wavelength
    /// `lambda_bragg_nm`.
    pub fn pdf(&self, lambda_nm: f64, lambda_bragg_nm: f64) -> f64 {
        self.pdf_in(
            self.first.table_for(lambda_bragg_nm),
            lambda_nm,
            lambda_bragg_nm,
            self.uniform_fraction,
        )
    }

    /// Whether λ lies in the simulation band.
    #[inline]
    pub fn in_band(&self, lambda_nm: f64) -> bool {
        lambda_nm >= self.lo_nm && lambda_nm < self.hi_nm
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The key bytes hold every number: equal samplers give equal bytes; one density value
    /// changed by one ulp, a shifted key or another bin width give other bytes.
    #[test]
    fn key_bytes_see_every_number() {
        let shape = |k: f64, bump: f64| (k, vec![1.0, 2.0 + bump, 3.0, 0.5]);
        let make = |k: f64, bump: f64, bin: f64| {
            let s = WavelengthSampler::new(400.0, 700.0, 0.1, -1.0, bin, &[shape(k, bump)]);
            let mut b = Vec::new();
            s.key_bytes(&mut b);
            b
        };
        let base = make(532.0, 0.0, 0.5);
        assert_eq!(base, make(532.0, 0.0, 0.5));
        let ulp = f64::from_bits(2.0f64.to_bits() + 1) - 2.0;
        assert_ne!(base, make(532.0, ulp, 0.5));
        assert_ne!(base, make(532.5, 0.0, 0.5));
        assert_ne!(base, make(532.0, 0.0, 0.25));
    }

    fn sampler() -> WavelengthSampler {
        // Triangle shapes over Δλ ∈ [−10, 10) nm in 0.5 nm bins, for two fields.
        let tri: Vec<f64> = (0..40).map(|i| 20.0 - (i as f64 - 19.5).abs()).collect();
        let lopsided: Vec<f64> = (0..40).map(|i| if i < 20 { 1.0 } else { 3.0 }).collect();
        WavelengthSampler::new(
            380.0,
            780.0,
            0.1,
            -10.0,
            0.5,
            &[(540.0, tri), (500.0, lopsided)],
        )
    }

    #[test]
    fn pdf_integrates_to_one() {
        let s = sampler();
        for lb in [531.3, 497.0] {
            let n = 400_000;
            let (a, b) = (300.0, 800.0);
            let integral: f64 = (0..n)
                .map(|i| s.pdf(a + (b - a) * (i as f64 + 0.5) / n as f64, lb))
                .sum::<f64>()
                * (b - a)
                / n as f64;
            assert!((integral - 1.0).abs() < 1e-3, "{integral}");
        }
    }

    /// χ² test: histogram of sampled λ against the pdf, for both tables.
    #[test]
    fn samples_follow_pdf() {
        let s = sampler();
        for lb in [540.0, 501.0] {
            let n = 200_000usize;
            let lo = lb - 20.0;
            let mut counts = vec![0u64; 40];
            for i in 0..n {
                // Golden-ratio sequence: uniform in [0, 1) and well spread.
                let u = (0.5 + i as f64 * 0.618_033_988_749_894_9).fract();
                let (lam, pdf) = s.sample(u, Some(lb));
                assert!((pdf - s.pdf(lam, lb)).abs() < 1e-15);
                if lam >= lo && lam < lo + 40.0 {
                    counts[(lam - lo) as usize] += 1;
                }
            }
            let mut chi2 = 0.0;
            for (k, &c) in counts.iter().enumerate() {
                let m = 200;
                let p: f64 = (0..m)
                    .map(|j| s.pdf(lo + k as f64 + (j as f64 + 0.5) / m as f64, lb))
                    .sum::<f64>()
                    / m as f64;
                let expect = p * n as f64;
                chi2 += (c as f64 - expect).powi(2) / expect.max(1.0);
            }
            // 39 dof, 99.9 % critical value ≈ 72.
            assert!(chi2 < 72.0, "λ_B {lb}: χ² = {chi2}");
        }
    }

    #[test]
    fn key_guide_matches_binary_search() {
        let shapes: Vec<(f64, Vec<f64>)> = [500.0, 501.0, 503.5, 520.0, 520.0, 560.25, 561.0]
            .iter()
            .map(|&k| (k, vec![1.0; 4]))
            .collect();
        for n in [1, 2, shapes.len()] {
            let s = WavelengthSampler::new(380.0, 780.0, 0.1, -1.0, 0.5, &shapes[..n]);
            for j in 0..20_000 {
                let l = 480.0 + j as f64 * 0.005;
                for l in [l, 500.0, 520.0, 561.0, 100.0, 900.0, f64::NAN, -0.0] {
                    let set = &s.sets[0];
                    let want = set.keys_nm.partition_point(|&k| k < l);
                    assert_eq!(set.keys_below(l), want, "{n} keys, λ {l}");
                }
            }
        }
    }

    #[test]
    fn nearest_table_is_used() {
        let s = sampler();
        // Lopsided table (key 500): density 3× higher above λ_B than below.
        let below = s.pdf(498.0, 500.0) - 0.1 / 400.0;
        let above = s.pdf(502.0, 500.0) - 0.1 / 400.0;
        assert!((above / below - 3.0).abs() < 1e-9);
        // Key 540 is the triangle: symmetric.
        assert!((s.pdf(535.25, 540.0) - s.pdf(544.75, 540.0)).abs() < 1e-15);
        assert_eq!(s.table_count(), 2);
    }

    /// A two-grating mixture: one set of (lopsided) tables per grating.
    fn two() -> WavelengthSampler {
        let tri: Vec<f64> = (0..40).map(|i| 20.0 - (i as f64 - 19.5).abs()).collect();
        let lopsided: Vec<f64> = (0..40).map(|i| if i < 20 { 1.0 } else { 3.0 }).collect();
        WavelengthSampler::new_multiplexed(
            380.0,
            780.0,
            0.1,
            -10.0,
            0.5,
            &[
                (vec![(540.0, tri.clone()), (500.0, lopsided.clone())], true),
                (vec![(460.0, lopsided), (440.0, tri)], true),
            ],
        )
    }

    /// One grating: the mixture's draws are the single-band sampler's, bit for bit.
    #[test]
    fn one_grating_mixture_is_the_single_band_sampler() {
        let s = sampler();
        for i in 0..10_000 {
            let u = (0.5 + i as f64 * 0.618_033_988_749_894_9).fract();
            for lb in [Some(531.3), Some(497.0), None] {
                let a = s.sample_mixed(u, lb, 0.1);
                let b = s.sample_multiplexed(u, &[lb], 0.1);
                assert_eq!(
                    (a.0.to_bits(), a.1.to_bits()),
                    (b.0.to_bits(), b.1.to_bits())
                );
            }
        }
    }

    /// Two gratings: the mixture density integrates to 1, the draws follow it (χ² over both
    /// bands) and each draw's pdf is the density; a density missing one component (the failing
    /// input: what the estimator would use if it forgot the other grating) fails the χ² test.
    #[test]
    fn two_grating_mixture_follows_its_density() {
        let s = two();
        let lb = [Some(538.0), Some(451.0)];
        let (a, b, n) = (300.0, 800.0, 400_000);
        let integral: f64 = (0..n)
            .map(|i| s.pdf_multiplexed(a + (b - a) * (i as f64 + 0.5) / n as f64, &lb))
            .sum::<f64>()
            * (b - a)
            / n as f64;
        assert!((integral - 1.0).abs() < 1e-3, "{integral}");
        let draws = 200_000usize;
        let lo = 430.0;
        let bins = 130; // 1 nm bins over 430–560 nm: both bands.
        let mut counts = vec![0u64; bins];
        for i in 0..draws {
            let u = (0.5 + i as f64 * 0.618_033_988_749_894_9).fract();
            let (lam, pdf) = s.sample_multiplexed(u, &lb, 0.1);
            assert!((pdf - s.pdf_multiplexed(lam, &lb)).abs() < 1e-15);
            if lam >= lo && lam < lo + bins as f64 {
                counts[(lam - lo) as usize] += 1;
            }
        }
        let chi2 = |pdf: &dyn Fn(f64) -> f64| -> f64 {
            let mut chi2 = 0.0;
            for (k, &c) in counts.iter().enumerate() {
                let m = 200;
                let p: f64 = (0..m)
                    .map(|j| pdf(lo + k as f64 + (j as f64 + 0.5) / m as f64))
                    .sum::<f64>()
                    / m as f64;
                let expect = p * draws as f64;
                chi2 += (c as f64 - expect).powi(2) / expect.max(1.0);
            }
            chi2
        };
        // 129 dof, 99.9 % critical value ≈ 181.
        let good = chi2(&|l| s.pdf_multiplexed(l, &lb));
        assert!(good < 181.0, "χ² = {good}");
        let only_first = chi2(&|l| s.pdf_multiplexed(l, &[lb[0], None]));
        assert!(only_first > 181.0, "one component only: χ² = {only_first}");
    }
}
