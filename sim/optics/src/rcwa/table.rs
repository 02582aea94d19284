//! Efficiency tables for the tracer: RCWA efficiencies of one design computed once on a
//! regular grid over (λ, u_x, u_y) (vacuum wavelength and the incident wave's tangential
//! direction cosines, conserved through the plate), cached on disk, and interpolated.
//!
//! Interpolation: trilinear in (λ, u_x, u_y). For a film with one grating the table stores
//! the residual η_RCWA − η_Kogelnik per order and adds the exact Kogelnik value
//! (`optics::grating`, converted to the plane-of-incidence TE/TM basis by
//! [`super::kogelnik_in_incidence_basis`]) back at lookup: the Bragg peak's sharp shape is carried by the closed
//! form and only the smooth, small difference is interpolated. Several gratings: η itself.
//! The error is bounded by measurement, not assumed: [`RcwaTable::measure_error`] compares
//! lookups with direct RCWA at pseudo-random off-grid points and returns the largest |Δη|,
//! which the builder stores with the table ([`RcwaTable::max_error`]).
//!
//! Cache: one file per design, named by the SHA-256 of every input the values depend on (film,
//! gratings, media per wavelength node, grid, truncation, slicing, format version), written
//! under a temporary name and renamed into place (atomic; concurrent builders of the same
//! design each write a complete file and the last rename wins, with identical content). A file
//! read back is verified before use ([`decode_values`]: key, length, check word, every value
//! finite and within [−1, 1]); a file that fails is built again and replaced.
//!
//! How the tracer should call it: build once per render with [`RcwaTable::load_or_build`]
//! (the media per λ from the stack at the vHOE: glass | film | air at a bottom contact), then
//! per grating event call [`RcwaTable::efficiency`] with the ray's wavelength and tangential
//! direction cosines u (as `VolumeGrating::diffract` takes them) and read the order it follows
//! (reflected or transmitted, order m, TE and TM); `None` outside the grid means "fall back to
//! Kogelnik".

use std::path::PathBuf;

use stscam_base::store::BlobStore;

use glam::DVec2;
use rayon::prelude::*;
use sha2::{Digest, Sha256};

use super::{Film, RcwaError, Settings, Stack, solve};
use crate::grating::VolumeGrating;

/// Format version of the cache files (part of the key).
const FORMAT: &str = "stscam-rcwa-table-1";

/// Most grid nodes of a table.
pub const MAX_NODES: usize = 20_000_000;

/// A regular grid axis: `n` values from `start` to `stop` inclusive (n ≥ 2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Axis {
    /// First value.
    pub start: f64,
    /// Last value.
    pub stop: f64,
    /// Number of nodes.
    pub n: usize,
}

impl Axis {
    pub(super) fn value(&self, i: usize) -> f64 {
        self.start + (self.stop - self.start) * i as f64 / (self.n - 1) as f64
    }

    /// Cell index and weight of `x`, or `None` outside [start, stop].
    pub(super) fn locate(&self, x: f64) -> Option<(usize, f64)> {
        let t = (x - self.start) / (self.stop - self.start) * (self.n - 1) as f64;
        if !(t >= -1e-9 && t <= (self.n - 1) as f64 + 1e-9) {
            return None;
        }
        let i = (t.floor().max(0.0) as usize).min(self.n - 2);
        Some((i, (t - i as f64).clamp(0.0, 1.0)))
    }
}

/// The grid of a table and the orders it keeps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TableSpec {
    /// Vacuum wavelength axis, nm.
    pub lambda_nm: Axis,
    /// u_x axis.
    pub u_x: Axis,
    /// u_y axis.
    pub u_y: Axis,
    /// Orders −K…K are kept (reflected and transmitted).
    pub max_order: i32,
}

/// One order's interpolated efficiency.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TableOrder {
    /// True for an order leaving through the entrance side.
    pub reflected: bool,
    /// Order index m (as in [`super::Order`]).
    pub order: i32,
    /// TE and TM efficiency.
    pub eta: [f64; 2],
}

/// An interpolated efficiency table of one design.
#[derive(Clone, Debug)]
pub struct RcwaTable {
    spec: TableSpec,
    film: Film,
    /// Media per λ node.
    media: Vec<Stack>,
    settings: Settings,
    /// Per node: orders (reflected −K…K, then transmitted −K…K) × [TE, TM].
    data: Vec<f64>,
    /// Largest |Δη| measured against direct RCWA at off-grid points (NaN if not measured).
    max_error: f64,
}

impl RcwaTable {
    fn per_node(spec: &TableSpec) -> usize {
        2 * (2 * spec.max_order as usize + 1) * 2
    }

    fn slot(spec: &TableSpec, reflected: bool, order: i32) -> usize {
        let k = spec.max_order;
        let side = if reflected { 0 } else { 1 };
        (side * (2 * k + 1) + order + k) as usize * 2
    }

    /// The cache key: SHA-256 over every input, as hex.
    pub fn key(film: &Film, media: &[Stack], spec: &TableSpec, settings: &Settings) -> String {
        let text = format!("{FORMAT}|{film:?}|{media:?}|{spec:?}|{settings:?}");
        let digest = Sha256::digest(text.as_bytes());
        digest.iter().map(|b| format!("{b:02x}")).collect()
    }

    /// The Kogelnik baseline of a one-grating film (zero for several gratings).
    fn baseline(film: &Film, spec: &TableSpec, lambda_nm: f64, u: DVec2, out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = 0.0);
        let [g] = film.gratings[..] else { return };
        let vg = VolumeGrating {
            k_rad_per_nm: g.k_rad_per_nm,
            n_film: film.mean_index,
            thickness_nm: film.thickness_nm,
            n1: g.n1,
            alpha0_per_nm: film.alpha0_per_nm,
        };
        for order in [-1i32, 1] {
            if order.abs() > spec.max_order {
                continue;
            }
            if let Some(d) = vg.diffract(u, 1.0, lambda_nm, order) {
                let s = Self::slot(spec, d.reflection, order);
                let eta =
                    super::kogelnik_in_incidence_basis(g.k_rad_per_nm, film.mean_index, u, d.eta);
                out[s] += eta[0];
                out[s + 1] += eta[1];
            }
        }
        let t = super::kogelnik_in_incidence_basis(
            g.k_rad_per_nm,
            film.mean_index,
            u,
            vg.undiffracted(u, 1.0, lambda_nm),
        );
        let s = Self::slot(spec, false, 0);
        out[s] = t[0];
        out[s + 1] = t[1];
    }

    /// Computes the table (in parallel over nodes; deterministic). `media` gives the stack at
    /// each λ node.
    pub fn build(
        film: &Film,
        media: &[Stack],
        spec: &TableSpec,
        settings: &Settings,
    ) -> Result<RcwaTable, RcwaError> {
        let axes = [spec.lambda_nm, spec.u_x, spec.u_y];
        let bad_axis =
            |a: &Axis| a.n < 2 || a.stop.partial_cmp(&a.start) != Some(std::cmp::Ordering::Greater);
        if axes.iter().any(bad_axis) || spec.max_order < 0 {
            return Err(RcwaError::BadInput(
                "table axes need at least 2 nodes and start < stop".into(),
            ));
        }
        let nodes = axes.iter().try_fold(1usize, |acc, a| acc.checked_mul(a.n));
        if nodes.is_none_or(|n| n > MAX_NODES) || media.len() != spec.lambda_nm.n {
            return Err(RcwaError::BadInput(format!(
                "table of more than {MAX_NODES} nodes, or media not one per wavelength node"
            )));
        }
        let nodes = nodes.unwrap_or(0);
        let per = Self::per_node(spec);
        let rows: Result<Vec<Vec<f64>>, RcwaError> = (0..nodes)
            .into_par_iter()
            .map(|idx| {
                let (il, rest) = (
                    idx / (spec.u_x.n * spec.u_y.n),
                    idx % (spec.u_x.n * spec.u_y.n),
                );
                let (ix, iy) = (rest / spec.u_y.n, rest % spec.u_y.n);
                let lam = spec.lambda_nm.value(il);
                let u = DVec2::new(spec.u_x.value(ix), spec.u_y.value(iy));
                let mut row = vec![0.0; per];
                let sol = match solve(film, &media[il], lam, u, settings) {
                    Ok(s) => s,
                    // A direction that cannot enter: no light, nothing to store.
                    Err(RcwaError::CannotEnter { .. }) => return Ok(row),
                    Err(e) => return Err(e),
                };
                for o in sol
                    .orders
                    .iter()
                    .filter(|o| o.order.abs() <= spec.max_order)
                {
                    let s = Self::slot(spec, o.reflected, o.order);
                    row[s] = o.eta[0];
                    row[s + 1] = o.eta[1];
                }
                let mut base = vec![0.0; per];
                Self::baseline(film, spec, lam, u, &mut base);
                row.iter_mut().zip(&base).for_each(|(r, b)| *r -= b);
                Ok(row)
            })
            .collect();
        Ok(RcwaTable {
            spec: *spec,
            film: film.clone(),
            media: media.to_vec(),
            settings: *settings,
            data: rows?.concat(),
            max_error: f64::NAN,
        })
    }

    /// Loads the table of this design from `cache_dir`, or builds it, measures its
    /// interpolation error at `probes` off-grid points, and stores it there (atomically).
    pub fn load_or_build(
        cache: &dyn BlobStore,
        film: &Film,
        media: &[Stack],
        spec: &TableSpec,
        settings: &Settings,
        probes: usize,
    ) -> Result<(RcwaTable, PathBuf, bool), RcwaError> {
        let key = Self::key(film, media, spec, settings);
        let name = format!("rcwa-table-{}.bin", &key[..32]);
        let path = cache.location(&name);
        if let Some(bytes) = cache.load(&name)
            && let Some(t) = Self::decode(&bytes, &key, film, media, spec, settings)
        {
            return Ok((t, path, true));
        }
        let mut t = Self::build(film, media, spec, settings)?;
        t.max_error = t.measure_error(probes, 1)?;
        let path = cache
            .save(&name, &t.encode(&key))
            .map_err(RcwaError::BadInput)?;
        Ok((t, path, false))
    }

    fn encode(&self, key: &str) -> Vec<u8> {
        encode_values(key, self.max_error, &self.data)
    }

    fn decode(
        bytes: &[u8],
        key: &str,
        film: &Film,
        media: &[Stack],
        spec: &TableSpec,
        settings: &Settings,
    ) -> Option<RcwaTable> {
        let nodes = spec.lambda_nm.n * spec.u_x.n * spec.u_y.n;
        let (max_error, data) = decode_values(bytes, key, nodes * Self::per_node(spec), false)?;
        Some(RcwaTable {
            spec: *spec,
            film: film.clone(),
            media: media.to_vec(),
            settings: *settings,
            data,
            max_error,
        })
    }

    /// Largest |η_table − η_RCWA| found at off-grid probe points when built (NaN if unmeasured).
    pub fn max_error(&self) -> f64 {
        self.max_error
    }

    /// The grid.
    pub fn spec(&self) -> &TableSpec {
        &self.spec
    }

    /// Interpolated efficiency of every kept order for a wave of vacuum wavelength `lambda_nm`
    /// and tangential direction cosines (u_x, u_y); `None` outside the grid.
    pub fn efficiency(&self, lambda_nm: f64, u_x: f64, u_y: f64) -> Option<Vec<TableOrder>> {
        let s = &self.spec;
        let (il, wl) = s.lambda_nm.locate(lambda_nm)?;
        let (ix, wx) = s.u_x.locate(u_x)?;
        let (iy, wy) = s.u_y.locate(u_y)?;
        let per = Self::per_node(s);
        let mut v = vec![0.0; per];
        for (dl, fl) in [(0, 1.0 - wl), (1, wl)] {
            for (dx, fx) in [(0, 1.0 - wx), (1, wx)] {
                for (dy, fy) in [(0, 1.0 - wy), (1, wy)] {
                    let w = fl * fx * fy;
                    if w == 0.0 {
                        continue;
                    }
                    let node = ((il + dl) * s.u_x.n + ix + dx) * s.u_y.n + iy + dy;
                    let row = &self.data[node * per..(node + 1) * per];
                    v.iter_mut().zip(row).for_each(|(a, b)| *a += w * b);
                }
            }
        }
        let mut base = vec![0.0; per];
        Self::baseline(&self.film, s, lambda_nm, DVec2::new(u_x, u_y), &mut base);
        let mut out = Vec::with_capacity(per / 2);
        for reflected in [true, false] {
            for order in -s.max_order..=s.max_order {
                let k = Self::slot(s, reflected, order);
                out.push(TableOrder {
                    reflected,
                    order,
                    eta: [(v[k] + base[k]).max(0.0), (v[k + 1] + base[k + 1]).max(0.0)],
                });
            }
        }
        Some(out)
    }

    /// Largest |η_table − η_RCWA| over `probes` pseudo-random points inside the grid (every kept
    /// order, both polarisations); the RCWA there is computed directly. Deterministic in `seed`.
    pub fn measure_error(&self, probes: usize, seed: u64) -> Result<f64, RcwaError> {
        let s = self.spec;
        let errs: Result<Vec<f64>, RcwaError> = (0..probes)
            .into_par_iter()
            .map(|i| {
                let r = |k: u64| unit_hash(seed, i as u64, k);
                let il = ((s.lambda_nm.n - 1) as f64 * r(0)) as usize;
                let lam_lo = s.lambda_nm.value(il);
                let lam_hi = s.lambda_nm.value(il + 1);
                // The media are tabulated per λ node: probe at a node's media, off-grid in u and
                // in λ within the cell (the media's own λ dependence is interpolated too).
                let lam = lam_lo + (lam_hi - lam_lo) * r(1);
                let ux = s.u_x.start + (s.u_x.stop - s.u_x.start) * r(2);
                let uy = s.u_y.start + (s.u_y.stop - s.u_y.start) * r(3);
                let w = (lam - lam_lo) / (lam_hi - lam_lo);
                let m0 = self.media[il];
                let m1 = self.media[il + 1];
                let media = Stack {
                    n_in: m0.n_in + w * (m1.n_in - m0.n_in),
                    n_out: m0.n_out + w * (m1.n_out - m0.n_out),
                };
                let direct =
                    match solve(&self.film, &media, lam, DVec2::new(ux, uy), &self.settings) {
                        Ok(d) => d,
                        Err(RcwaError::CannotEnter { .. }) => return Ok(0.0),
                        Err(e) => return Err(e),
                    };
                let table = self.efficiency(lam, ux, uy).unwrap_or_default();
                let mut worst: f64 = 0.0;
                for t in &table {
                    let d = direct
                        .orders
                        .iter()
                        .find(|o| o.reflected == t.reflected && o.order == t.order)
                        .map_or([0.0, 0.0], |o| o.eta);
                    worst = worst
                        .max((t.eta[0] - d[0]).abs())
                        .max((t.eta[1] - d[1]).abs());
                }
                Ok(worst)
            })
            .collect();
        Ok(errs?.into_iter().fold(0.0, f64::max))
    }
}

/// A cache file's bytes: the key, the measured interpolation error, the value count, the
/// values (little-endian f64) and a check word, the SHA-256 of everything before it.
pub(super) fn encode_values(key: &str, max_error: f64, data: &[f64]) -> Vec<u8> {
    let mut out = Vec::with_capacity(112 + 8 * data.len());
    out.extend_from_slice(key.as_bytes());
    out.extend_from_slice(&max_error.to_le_bytes());
    out.extend_from_slice(&(data.len() as u64).to_le_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let check = Sha256::digest(&out);
    out.extend_from_slice(&check);
    out
}

/// Largest |value| a cache file may hold: every value is an efficiency, a difference of two
/// efficiencies or an attenuation factor, all within [−1, 1] (with room for the solver's
/// rounding).
pub(super) const MAX_CACHED_ABS: f64 = 1.0 + 1e-6;

/// The (interpolation error, values) of a cache file written by [`encode_values`] under `key`
/// with `len` values; `None` for any other file: another key (another design or settings), a
/// truncated or foreign file, a check word that does not match (a flipped bit), or a value
/// that is not finite (NaN allowed only with `allow_nan`: "no value" in the coupling tables)
/// or beyond [`MAX_CACHED_ABS`]; the caller then builds the table again. The check word
/// protects against corruption and mix-ups, not against a writer who reseals a file (docs/limits.md).
pub(super) fn decode_values(
    bytes: &[u8],
    key: &str,
    len: usize,
    allow_nan: bool,
) -> Option<(f64, Vec<f64>)> {
    let (payload, check) = bytes.split_at_checked(bytes.len().checked_sub(32)?)?;
    if Sha256::digest(payload).as_slice() != check {
        return None;
    }
    let rest = payload.strip_prefix(key.as_bytes())?;
    let f = |b: &[u8]| -> Option<[u8; 8]> { b.get(..8)?.try_into().ok() };
    let max_error = f64::from_le_bytes(f(rest)?);
    let stored = u64::from_le_bytes(f(rest.get(8..)?)?);
    let body = rest.get(16..)?;
    if stored != len as u64
        || body.len() != 8 * len
        || !(max_error.is_nan() || (0.0..=2.0).contains(&max_error))
    {
        return None;
    }
    let data: Vec<f64> = body
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
        .collect();
    let ok = |v: &f64| v.abs() <= MAX_CACHED_ABS || (allow_nan && v.is_nan());
    data.iter().all(ok).then_some((max_error, data))
}

/// A uniform number in [0, 1) from (seed, i, k) (splitmix64).
pub(super) fn unit_hash(seed: u64, i: u64, k: u64) -> f64 {
    let mut z = seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(i.wrapping_mul(0xBF58_476D_1CE4_E5B9))
        .wrapping_add(k.wrapping_mul(0x94D0_49BB_1331_11EB));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rcwa::Grating;

    fn paper_film(d_um: f64) -> Film {
        let g = VolumeGrating::from_recording(532.0, 61.2, 1.50, d_um, 0.015, 0.0);
        Film {
            mean_index: 1.5,
            alpha0_per_nm: 0.0,
            thickness_nm: d_um * 1e3,
            gratings: vec![Grating::of(&g)],
        }
    }

    /// A cache file read back is verified: the file as written decodes; a flipped bit, another
    /// key, a cut file, and a file resealed with a valid check word around NaN, infinite or
    /// out-of-range values do not (the caller builds again).
    #[test]
    fn cache_files_are_verified() {
        let key = "k".repeat(64);
        let data = [0.25, -0.5, 1.0, 0.0];
        let good = encode_values(&key, 1e-4, &data);
        assert_eq!(
            decode_values(&good, &key, 4, false),
            Some((1e-4, data.to_vec()))
        );
        for i in [0, 70, 80, good.len() - 1] {
            let mut b = good.clone();
            b[i] ^= 0x10;
            assert!(decode_values(&b, &key, 4, false).is_none(), "bit {i}");
        }
        assert!(decode_values(&good, &"j".repeat(64), 4, false).is_none());
        assert!(decode_values(&good[..good.len() - 8], &key, 4, false).is_none());
        assert!(decode_values(&good, &key, 5, false).is_none());
        for bad in [f64::NAN, f64::INFINITY, 1e38, -1.5] {
            let b = encode_values(&key, 1e-4, &[0.25, bad]);
            assert!(decode_values(&b, &key, 2, false).is_none(), "{bad}");
        }
        // NaN is "no value" in the coupling tables.
        let b = encode_values(&key, 1e-4, &[0.25, f64::NAN]);
        assert!(decode_values(&b, &key, 2, true).is_some());
        let b = encode_values(&key, -1.0, &data);
        assert!(decode_values(&b, &key, 4, false).is_none());
    }

    #[test]
    fn table_interpolates_within_its_measured_bound_and_caches() {
        let film = paper_film(16.0);
        let spec = TableSpec {
            lambda_nm: Axis {
                start: 520.0,
                stop: 544.0,
                n: 13,
            },
            u_x: Axis {
                start: -0.1,
                stop: 0.1,
                n: 5,
            },
            u_y: Axis {
                start: -0.1,
                stop: 0.1,
                n: 9,
            },
            max_order: 1,
        };
        let media = vec![
            Stack {
                n_in: 1.5,
                n_out: 1.5
            };
            spec.lambda_nm.n
        ];
        let settings = Settings::default();
        let dir = tempfile::tempdir().unwrap();
        let (t, path, cached) = RcwaTable::load_or_build(
            &crate::TestDir(dir.path().to_path_buf()),
            &film,
            &media,
            &spec,
            &settings,
            40,
        )
        .unwrap();
        assert!(!cached && path.exists());
        // The bound is finite and small (Kogelnik residual interpolated).
        assert!(t.max_error() < 0.02, "measured bound {}", t.max_error());
        // An independent probe set stays within 2x the stored bound.
        let again = t.measure_error(40, 99).unwrap();
        assert!(
            again <= 2.0 * t.max_error() + 1e-6,
            "{again} vs {}",
            t.max_error()
        );
        // At a node the table is the RCWA to rounding.
        let at = t.efficiency(532.0, 0.0, 0.0).unwrap();
        let direct = solve(&film, &media[0], 532.0, DVec2::ZERO, &settings).unwrap();
        let r1 = at.iter().find(|o| o.reflected && o.order == 1).unwrap();
        let d1 = direct
            .orders
            .iter()
            .find(|o| o.reflected && o.order == 1)
            .unwrap();
        assert!((r1.eta[0] - d1.eta[0]).abs() < 1e-12);
        // Second call: loaded from the cache, same values.
        let (t2, _, cached2) = RcwaTable::load_or_build(
            &crate::TestDir(dir.path().to_path_buf()),
            &film,
            &media,
            &spec,
            &settings,
            40,
        )
        .unwrap();
        assert!(cached2);
        assert_eq!(
            t2.efficiency(530.3, 0.01, -0.02),
            t.efficiency(530.3, 0.01, -0.02)
        );
        assert_eq!(t2.max_error(), t.max_error());
        // Outside the grid: None. A different design has a different key.
        assert!(t.efficiency(600.0, 0.0, 0.0).is_none());
        let other = paper_film(15.0);
        assert_ne!(
            RcwaTable::key(&film, &media, &spec, &settings),
            RcwaTable::key(&other, &media, &spec, &settings)
        );
        // Without the Kogelnik baseline (a detuned zero-strength second grating makes it a
        // two-grating film) the same grid interpolates η itself, far worse: the baseline is what
        // keeps the bound small.
        let mut two = film.clone();
        let mut g2 = two.gratings[0];
        g2.n1 = 0.0;
        two.gratings.push(g2);
        let raw = RcwaTable::build(&two, &media, &spec, &settings).unwrap();
        assert!(raw.measure_error(40, 1).unwrap() > 2.0 * t.max_error());
    }
}
