//! Wavelength importance sampling around each path's Bragg wavelength.
//!
//! Model (DESIGN.md "Estimator decisions"): the spectral integrand of a path is dominated by the
//! product of the in- and out-coupling efficiencies, a band a few nm wide centred on the
//! path's exact Bragg wavelength λ_B (physics.md §3.2, closed form). The sampler draws
//! λ = λ_B + Δ with Δ from a tabulated, piecewise-constant density shaped like the end-to-end
//! spectral throughput of the centre field (measured once per scene by tracing), mixed with a
//! uniform density over the simulation band:
//!   p(λ) = (1 − f_u)·p_table(λ − λ_B) + f_u/(λ_max − λ_min).
//! The uniform part keeps p > 0 wherever the integrand can be non-zero, so the estimator is
//! unbiased; samples outside the band carry zero. Paths without a Bragg wavelength use the
//! uniform density alone.

/// Piecewise-constant density of Δλ plus a uniform part over the band.
#[derive(Clone, Debug)]
pub struct WavelengthSampler {
    lo_nm: f64,
    hi_nm: f64,
    uniform_fraction: f64,
    /// Δλ of the first bin edge, nm.
    table_start_nm: f64,
    /// Bin width, nm.
    bin_nm: f64,
    /// Density per nm of each bin (integrates to 1).
    density: Vec<f64>,
    /// Cumulative distribution at bin edges (len = bins + 1).
    cdf: Vec<f64>,
}

impl WavelengthSampler {
    /// Builds the sampler from a non-negative shape tabulated on `bins` equal bins starting at
    /// Δλ = `table_start_nm`. A shape that sums to zero falls back to a flat table.
    pub fn new(
        lo_nm: f64,
        hi_nm: f64,
        uniform_fraction: f64,
        table_start_nm: f64,
        bin_nm: f64,
        shape: &[f64],
    ) -> Self {
        let mut shape: Vec<f64> = shape
            .iter()
            .map(|&v| if v.is_finite() && v > 0.0 { v } else { 0.0 })
            .collect();
        let total: f64 = shape.iter().sum();
        if total <= 0.0 {
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
        let density = shape.iter().map(|v| v / total / bin_nm).collect();
        WavelengthSampler {
            lo_nm,
            hi_nm,
            uniform_fraction,
            table_start_nm,
            bin_nm,
            density,
            cdf,
        }
    }

    /// The band's width in nm.
    pub fn band_nm(&self) -> f64 {
        self.hi_nm - self.lo_nm
    }

    /// Draws a wavelength from one uniform number `u` ∈ [0,1); returns (λ in nm, pdf per nm).
    #[inline]
    pub fn sample(&self, u: f64, lambda_bragg_nm: Option<f64>) -> (f64, f64) {
        let Some(lb) = lambda_bragg_nm else {
            return (self.lo_nm + u * self.band_nm(), 1.0 / self.band_nm());
        };
        let fu = self.uniform_fraction;
        let lambda = if u < fu {
            self.lo_nm + (u / fu) * self.band_nm()
        } else {
            let v = ((u - fu) / (1.0 - fu)).min(1.0 - 1e-16);
            // First bin whose upper CDF edge exceeds v.
            let i = self.cdf[1..]
                .partition_point(|&c| c <= v)
                .min(self.density.len() - 1);
            let span = self.cdf[i + 1] - self.cdf[i];
            let frac = if span > 0.0 {
                (v - self.cdf[i]) / span
            } else {
                0.5
            };
            lb + self.table_start_nm + (i as f64 + frac) * self.bin_nm
        };
        (lambda, self.pdf(lambda, lb))
    }

    /// Density (per nm) of drawing `lambda_nm` for a path with Bragg wavelength `lambda_bragg_nm`.
    #[inline]
    pub fn pdf(&self, lambda_nm: f64, lambda_bragg_nm: f64) -> f64 {
        let uni = if lambda_nm >= self.lo_nm && lambda_nm < self.hi_nm {
            self.uniform_fraction / self.band_nm()
        } else {
            0.0
        };
        let x = (lambda_nm - lambda_bragg_nm - self.table_start_nm) / self.bin_nm;
        let tab = if x >= 0.0 && x < self.density.len() as f64 {
            self.density[x as usize]
        } else {
            0.0
        };
        uni + (1.0 - self.uniform_fraction) * tab
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

    fn sampler() -> WavelengthSampler {
        // Triangle shape over Δλ ∈ [−10, 10) nm in 0.5 nm bins.
        let shape: Vec<f64> = (0..40).map(|i| 20.0 - (i as f64 - 19.5).abs()).collect();
        WavelengthSampler::new(380.0, 780.0, 0.1, -10.0, 0.5, &shape)
    }

    #[test]
    fn pdf_integrates_to_one() {
        let s = sampler();
        let lb = 531.3;
        let n = 400_000;
        let (a, b) = (300.0, 800.0);
        let integral: f64 = (0..n)
            .map(|i| s.pdf(a + (b - a) * (i as f64 + 0.5) / n as f64, lb))
            .sum::<f64>()
            * (b - a)
            / n as f64;
        assert!((integral - 1.0).abs() < 1e-3, "{integral}");
    }

    /// χ² test: histogram of sampled λ against the pdf.
    #[test]
    fn samples_follow_pdf() {
        let s = sampler();
        let lb = 540.0;
        let n = 200_000usize;
        let edges: Vec<f64> = (0..=40).map(|i| 520.0 + i as f64 * 1.0).collect();
        let mut counts = vec![0u64; 40];
        for i in 0..n {
            // Golden-ratio sequence: uniform in [0, 1) and well spread.
            let u = (0.5 + i as f64 * 0.618_033_988_749_894_9).fract();
            let (lam, pdf) = s.sample(u, Some(lb));
            assert!((pdf - s.pdf(lam, lb)).abs() < 1e-15);
            if lam >= 520.0 && lam < 560.0 {
                counts[(lam - 520.0) as usize] += 1;
            }
        }
        let mut chi2 = 0.0;
        for k in 0..40 {
            let m = 200;
            let p: f64 = (0..m)
                .map(|j| s.pdf(edges[k] + (j as f64 + 0.5) / m as f64, lb))
                .sum::<f64>()
                / m as f64;
            let expect = p * n as f64;
            chi2 += (counts[k] as f64 - expect).powi(2) / expect.max(1.0);
        }
        // 39 dof, 99.9 % critical value ≈ 72.
        assert!(chi2 < 72.0, "χ² = {chi2}");
    }
}
