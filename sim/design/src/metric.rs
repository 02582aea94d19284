//! The metrics of a design that `evaluate` computes and a study optimises: their names (the
//! keys of `stscam evaluate --json` and of a study's objectives and constraints), what each
//! measures, and which of them carry a Monte Carlo error.
//!
//! A metric name is a base metric (`fov_capture_vertical_deg`, `psnr_db`, …) or a base metric
//! with the suffix `_q05`: its 5 % quantile over the study's fabrication-tolerance draws (the
//! value 95 % of the fabricated films reach). `yield` is the fraction of those draws that meet
//! every constraint of the study on a base metric that the draws evaluate.

use std::fmt;

/// A base metric (module notes). The set is closed: one variant per name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Base {
    /// Vertical throughput FOV in the captured image (the waveguide's FOV clipped to the
    /// field the sensor crop sees), degrees.
    FovCaptureVerticalDeg,
    /// Horizontal FOV in the captured image, degrees.
    FovCaptureHorizontalDeg,
    /// Vertical throughput FOV of the waveguide (no crop), degrees.
    FovWaveguideVerticalDeg,
    /// Horizontal throughput FOV of the waveguide, degrees.
    FovWaveguideHorizontalDeg,
    /// Vertical extent of the scene field on the object plane, mm.
    SceneFieldVerticalMm,
    /// Full angle the vertical scene field subtends at the bottom vHOE's centre, degrees.
    SceneFieldVerticalDeg,
    /// Replicas carrying ≥ 5 % of the strongest, chief ray of the crop's centre.
    Replicas5pct,
    /// Every out-coupling replica of that chief ray.
    ReplicasAll,
    /// Replica pitch on the display at the centre field, mm.
    ReplicaPitchMm,
    /// Peak field response T over both field scans.
    EfficiencyPeak,
    /// Mean field response T over a grid of the crop's chief rays.
    EfficiencyMean,
    /// Colour designs: fraction of the crop's field rows with a band in the red primary.
    BandCoverageR,
    /// Green primary.
    BandCoverageG,
    /// Blue primary.
    BandCoverageB,
    /// Mean PSNR (dB, peak 1) of the discrepancy-regularised ADMM-TV reconstructions over the
    /// target set and depths, fixed exposure.
    PsnrDb,
    /// The same for CGM stopped by the discrepancy principle.
    PsnrCgDb,
    /// Mean SSIM of the ADMM-TV reconstructions.
    Ssim,
    /// Stray light over the crop, % of the signal: every path through the plate that H does
    /// not model (`stscam stray`'s total), the scene's own display image, at the fidelity's
    /// binning and spp.
    StrayPercent,
    /// Fraction of the tolerance draws that meet the study's constraints (module notes).
    Yield,
}

impl Base {
    /// Every base metric, in the order reports list them.
    pub const ALL: [Base; 19] = [
        Base::FovCaptureVerticalDeg,
        Base::FovCaptureHorizontalDeg,
        Base::FovWaveguideVerticalDeg,
        Base::FovWaveguideHorizontalDeg,
        Base::SceneFieldVerticalMm,
        Base::SceneFieldVerticalDeg,
        Base::Replicas5pct,
        Base::ReplicasAll,
        Base::ReplicaPitchMm,
        Base::EfficiencyPeak,
        Base::EfficiencyMean,
        Base::BandCoverageR,
        Base::BandCoverageG,
        Base::BandCoverageB,
        Base::PsnrDb,
        Base::PsnrCgDb,
        Base::Ssim,
        Base::StrayPercent,
        Base::Yield,
    ];

    /// The metric's name.
    pub fn name(self) -> &'static str {
        match self {
            Base::FovCaptureVerticalDeg => "fov_capture_vertical_deg",
            Base::FovCaptureHorizontalDeg => "fov_capture_horizontal_deg",
            Base::FovWaveguideVerticalDeg => "fov_waveguide_vertical_deg",
            Base::FovWaveguideHorizontalDeg => "fov_waveguide_horizontal_deg",
            Base::SceneFieldVerticalMm => "scene_field_vertical_mm",
            Base::SceneFieldVerticalDeg => "scene_field_vertical_deg",
            Base::Replicas5pct => "replicas_5pct",
            Base::ReplicasAll => "replicas_all",
            Base::ReplicaPitchMm => "replica_pitch_mm",
            Base::EfficiencyPeak => "efficiency_peak",
            Base::EfficiencyMean => "efficiency_mean",
            Base::BandCoverageR => "band_coverage_r",
            Base::BandCoverageG => "band_coverage_g",
            Base::BandCoverageB => "band_coverage_b",
            Base::PsnrDb => "psnr_db",
            Base::PsnrCgDb => "psnr_cg_db",
            Base::Ssim => "ssim",
            Base::StrayPercent => "stray_percent",
            Base::Yield => "yield",
        }
    }

    /// The base metric of this name.
    pub fn from_name(name: &str) -> Option<Base> {
        Base::ALL.into_iter().find(|b| b.name() == name)
    }

    /// What the metric needs computed.
    pub fn kind(self) -> Kind {
        match self {
            Base::PsnrDb | Base::PsnrCgDb | Base::Ssim => Kind::Reconstruction,
            Base::BandCoverageR | Base::BandCoverageG | Base::BandCoverageB => Kind::Colour,
            Base::Yield => Kind::Tolerance,
            Base::StrayPercent => Kind::Stray,
            _ => Kind::Geometry,
        }
    }

    /// Whether the metric carries a Monte Carlo error (`<name>_error` in the output): the
    /// reconstruction metrics (rendered H and capture, sensor noise), the stray light (traced
    /// paths) and the yield (a finite number of draws). The geometry metrics are deterministic
    /// quadratures of chief rays.
    pub fn has_error(self) -> bool {
        matches!(
            self.kind(),
            Kind::Reconstruction | Kind::Stray | Kind::Tolerance
        )
    }
}

/// What a base metric needs computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Chief rays and quadratures only (milliseconds).
    Geometry,
    /// The colour bands of the crop's field rows.
    Colour,
    /// H, captures and reconstructions (seconds).
    Reconstruction,
    /// Every path through the plate (`stscam_stray`; seconds).
    Stray,
    /// Tolerance draws of the design.
    Tolerance,
}

/// A metric: a base metric, or its 5 % quantile over the tolerance draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Metric {
    /// The base metric.
    pub base: Base,
    /// The 5 % quantile over the draws (`_q05`) instead of the nominal value.
    pub q05: bool,
}

/// Suffix of a tolerance quantile.
pub const Q05_SUFFIX: &str = "_q05";

impl Metric {
    /// The nominal metric `base`.
    pub const fn nominal(base: Base) -> Metric {
        Metric { base, q05: false }
    }

    /// Parses a metric name (module notes); the error lists the names there are.
    pub fn parse(name: &str) -> Result<Metric, String> {
        let name = name.trim();
        let (stem, q05) = match name.strip_suffix(Q05_SUFFIX) {
            Some(s) => (s, true),
            None => (name, false),
        };
        let base = Base::ALL.iter().copied().find(|b| b.name() == stem);
        match base {
            Some(Base::Yield) if q05 => Err(format!(
                "metric {name:?}: the yield is already a fraction of the draws; it has no quantile"
            )),
            Some(base) => Ok(Metric { base, q05 }),
            None => Err(format!(
                "unknown metric {name:?}; expected one of {} (or any but yield with {Q05_SUFFIX}: its 5 % quantile over the tolerance draws)",
                Base::ALL.map(Base::name).join(", ")
            )),
        }
    }

    /// Parses a comma-separated list (`--metrics a,b`), each name once, in the given order.
    pub fn parse_list(list: &str) -> Result<Vec<Metric>, String> {
        let mut out: Vec<Metric> = Vec::new();
        for name in list.split(',').filter(|s| !s.trim().is_empty()) {
            let m = Metric::parse(name)?;
            if out.contains(&m) {
                return Err(format!("metric {:?} is listed twice", name.trim()));
            }
            out.push(m);
        }
        if out.is_empty() {
            return Err("no metric given".into());
        }
        Ok(out)
    }

    /// Whether the metric is computed from the tolerance draws.
    pub fn needs_draws(self) -> bool {
        self.q05 || self.base == Base::Yield
    }
}

impl fmt::Display for Metric {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.base.name())?;
        if self.q05 {
            f.write_str(Q05_SUFFIX)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_are_unique() {
        let mut seen = std::collections::BTreeSet::new();
        for b in Base::ALL {
            assert!(seen.insert(b.name()), "{} twice", b.name());
            let m = Metric::parse(b.name()).unwrap();
            assert_eq!(m, Metric::nominal(b));
            assert_eq!(m.to_string(), b.name());
            if b != Base::Yield {
                let q = Metric::parse(&format!("{}_q05", b.name())).unwrap();
                assert!(q.q05 && q.base == b && q.needs_draws());
            }
        }
        assert_eq!(seen.len(), Base::ALL.len());
    }

    #[test]
    fn the_geometry_metrics_below_are_exactly_the_geometry_and_colour_bases() {
        // `sweep::geometry_metrics` names its values; each name must be a base of that kind
        // and every such base must be there (a renamed metric fails here).
        let below: Vec<Base> = crate::sweep::GEOMETRY_METRICS
            .iter()
            .map(|n| Base::from_name(n).unwrap_or_else(|| panic!("{n} is not a metric")))
            .collect();
        let here: Vec<Base> = Base::ALL
            .into_iter()
            .filter(|b| matches!(b.kind(), Kind::Geometry | Kind::Colour))
            .collect();
        assert_eq!(below, here);
        assert_eq!(Base::from_name("psnr"), None);
    }

    #[test]
    fn bad_names_are_refused_with_the_list() {
        let e = Metric::parse("psnr").unwrap_err();
        assert!(
            e.contains("unknown metric \"psnr\"") && e.contains("psnr_db"),
            "{e}"
        );
        assert!(Metric::parse("yield_q05").is_err());
        assert!(Metric::parse_list("psnr_db,psnr_db").is_err());
        assert!(Metric::parse_list(" , ").is_err());
        assert_eq!(
            Metric::parse_list("ssim, yield").unwrap(),
            vec![Metric::nominal(Base::Ssim), Metric::nominal(Base::Yield)]
        );
    }
}
