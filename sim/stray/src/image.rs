//! The camera image split by path class: every camera sample of `render` traced through every
//! path ([`crate::paths`]), each branch's display radiance added to its class's image.
//!
//! Estimator: the samples are `render`'s own ([`stscam_tracer::render::draw_samples`]: the
//! same sensor and lens points and wavelengths, the same factor cos⁴θ·S(λ)/p(λ)), and a
//! branch's value is its weight averaged over the display's polarisation times the display's
//! radiance at its object point (the primaries' shares at λ for a colour display), split over
//! the sensor channels by their response, summed per class and divided by the sample count: the
//! `signal` class is `render`'s image to rounding (the tests check it), and the other classes
//! are what `render` leaves out. Russian roulette keeps every class unbiased.
//!
//! Assumptions: a display scene (no 3-D user side); the film by Kogelnik's model (an RCWA
//! scene's tables describe its designed orders only); on the camera side only the display
//! behind the screen (`[behind_display]`) emits, uniform white at its luminance with the front
//! display's spectrum and polarisation.

use std::collections::{BTreeMap, HashMap};

use crate::classes::{self, Token};
use crate::paths::{
    BehindPlane, Haze, Ledger, PathSettings, PlateEdges, SINKS, Sink, Source, Surround,
    trace_all_paths,
};
use crate::sampler::PathRng;
use crate::tracer::render::{
    CameraSample, RenderSettings, channel_weights, draw_samples, lattice_rule,
};
use crate::tracer::system::System;

/// Tag of the roulette's random numbers.
const STRAY_TAG: u64 = 0x5354_5241_5900;

/// Most path classes kept apart; rarer ones (by their total over the image) are summed into
/// [`OTHER`].
pub const MAX_CLASSES: usize = 64;

/// Classes (besides the signal) whose images are kept, the leading ones by total.
pub const IMAGED_CLASSES: usize = 6;

/// The name of the classes summed past [`MAX_CLASSES`] (and past [`ROW_CLASSES`] in a row).
pub const OTHER: &str = "other";

/// Most classes one image row keeps apart (later ones in that row go to [`OTHER`]): bounds
/// the memory to rows × `ROW_CLASSES` × columns × channels values ([`bytes_bound`]).
pub const ROW_CLASSES: usize = 256;

/// The most bytes [`stray_images`] holds for `sys`: every row's classes' values and every
/// path's sum (f64), the signal's, the leading classes' and the all-paths images (f32).
pub fn bytes_bound(sys: &System) -> u128 {
    let (w, h) = (sys.camera.width_px as u128, sys.camera.height_px as u128);
    let nch = sys.response.curves.len() as u128;
    h * w * nch * ((ROW_CLASSES as u128 + 1) * 8 + (IMAGED_CLASSES as u128 + 2) * 4)
}

/// One path class over the image.
#[derive(Clone, Debug)]
pub struct ClassImage {
    /// The class's name (`signal`, or its folded events).
    pub name: String,
    /// Its tokens' texts (empty for `signal` and `other`).
    pub events: Vec<String>,
    /// The short name of labels (`classes::short_name`; the name itself for `signal` and
    /// `other`).
    pub short: String,
    /// Sum of every pixel's value over the channels.
    pub total: f64,
    /// Largest pixel value over the channels.
    pub peak: f64,
    /// Sum per image row (row 0 at the top) over the columns and channels.
    pub row_sums: Vec<f64>,
    /// The image per channel (row-major, row 0 at the top), for the signal and the leading
    /// [`IMAGED_CLASSES`] classes.
    pub image: Option<Vec<Vec<f32>>>,
}

/// The image split by path class, with where the rest of the camera's importance went.
#[derive(Clone, Debug)]
pub struct StrayImages {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Sensor channel names.
    pub channel_names: Vec<&'static str>,
    /// The signal first, then the other classes by decreasing total ([`OTHER`] last).
    pub classes: Vec<ClassImage>,
    /// Distinct classes found (before [`MAX_CLASSES`] applied).
    pub distinct_classes: usize,
    /// Camera rays traced.
    pub rays: u64,
    /// Branches created.
    pub branches: u64,
    /// Sum over the rays of the weight (display polarisation average) that reached the display.
    pub exit_weight: f64,
    /// Sum over the rays of the weight (display polarisation average) per sink
    /// ([`Sink::ALL`] order).
    pub sinks: [f64; SINKS],
    /// The image of every path together, per channel (row-major, row 0 at the top): what the
    /// camera records, signal and stray light (each pixel's classes summed in the order the
    /// samples met them).
    pub all_paths: Vec<Vec<f32>>,
}

impl StrayImages {
    /// The signal class, if the image has one (it is first).
    pub fn signal(&self) -> Option<&ClassImage> {
        self.classes.first().filter(|c| c.name == classes::SIGNAL)
    }

    /// The signal's sum over the crop (0 without one).
    pub fn signal_total(&self) -> f64 {
        self.signal().map_or(0.0, |c| c.total)
    }

    /// Every other class's sum over the crop: the stray light.
    pub fn stray_total(&self) -> f64 {
        let skip = usize::from(self.signal().is_some());
        self.classes[skip..].iter().map(|c| c.total).sum()
    }
}

/// Settings of [`stray_images`].
#[derive(Clone, Debug)]
pub struct StraySettings {
    /// Samples per pixel.
    pub spp: u32,
    /// Seed (the render's: the same samples).
    pub seed: u64,
    /// The branching tracer's settings.
    pub paths: PathSettings,
    /// Progress on the terminal.
    pub progress: bool,
}

/// A multiply-rotate hasher for the class keys (short token lists hashed once per branch that
/// reaches the display; SipHash's protection against chosen keys is not needed here).
#[derive(Default, Clone, Copy)]
struct KeyHasher(u64);

impl std::hash::Hasher for KeyHasher {
    #[inline]
    fn finish(&self) -> u64 {
        self.0
    }

    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }

    #[inline]
    fn write_u64(&mut self, n: u64) {
        self.0 = (self.0.rotate_left(5) ^ n).wrapping_mul(0x517c_c1b7_2722_0a95);
    }

    #[inline]
    fn write_u8(&mut self, n: u8) {
        self.write_u64(u64::from(n));
    }

    #[inline]
    fn write_usize(&mut self, n: usize) {
        self.write_u64(n as u64);
    }
}

type KeyMap = HashMap<Vec<Token>, usize, std::hash::BuildHasherDefault<KeyHasher>>;

/// A row's classes: each class's values over the row (columns × channels), by folded key.
#[derive(Default)]
struct RowClasses {
    keys: KeyMap,
    values: Vec<Vec<f64>>,
    /// Every path's sum over the row (columns × channels).
    all: Vec<f64>,
    ledger: Ledger,
    exit_weight: f64,
    rays: u64,
}

/// The camera image of `sys` split by path class (module notes). Rows run in parallel on the
/// current pool; the result is the same for any thread count.
pub fn stray_images(sys: &System, set: &StraySettings) -> StrayImages {
    let (w, h) = (sys.camera.width_px, sys.camera.height_px);
    let nch = sys.response.curves.len();
    let render = RenderSettings::lattice(set.spp, set.seed, false);
    let rule = lattice_rule(&render, set.spp);
    let cancel = crate::cancel::current();
    let rows = crate::rows::par_rows(
        h,
        set.progress,
        "stray-light rows",
        &cancel,
        |row| {
            let mut rc = RowClasses::default();
            let mut samples = vec![None; set.spp as usize];
            let mut tokens = Vec::with_capacity(64);
            let inv = 1.0 / f64::from(set.spp.max(1));
            for col in 0..w {
                draw_samples(sys, &render, rule, (col, row), 0, &mut samples);
                let pixel = (row * w + col) as u64;
                for (i, s) in samples.iter().enumerate() {
                    let Some(s) = s else { continue };
                    let at = (pixel, i as u64, col);
                    trace_sample(sys, set, s, at, inv, &mut rc, &mut tokens);
                }
            }
            rc
        },
        |_| RowClasses::default(),
    );
    assemble(sys, rows, (w, h, nch))
}

/// What surrounds the plate of `sys` for the tracer: the display plane, the display behind the
/// screen when the scene enables it, and the plate's edges.
pub fn surround(sys: &System) -> Surround {
    let b = &sys.scene.behind_display;
    let plate = &sys.scene.plate;
    Surround {
        edges: Some(PlateEdges {
            extent: crate::tracer::waveguide::Rect::centered(
                glam::DVec2::from_array(plate.center_mm),
                glam::DVec2::from_array(plate.size_mm),
            ),
            polished: plate.edges == "polished",
        }),
        display_z_mm: sys.display.z_mm,
        haze: (sys.scene.hoe.haze_fraction > 0.0).then(|| Haze {
            fraction: sys.scene.hoe.haze_fraction,
            asymmetry: sys.scene.hoe.haze_asymmetry,
        }),
        behind: b.enabled.then(|| BehindPlane {
            distance_mm: b.distance_mm,
            area: crate::tracer::waveguide::Rect::centered(
                glam::DVec2::from_array(b.center_mm),
                glam::DVec2::from_array(b.size_mm),
            ),
        }),
    }
}

/// Traces sample `i` of pixel `pixel` (in column `col` of its row) through every path and adds
/// each branch, times `inv` (1/spp), to its class in `rc`.
#[inline]
fn trace_sample(
    sys: &System,
    set: &StraySettings,
    s: &CameraSample,
    (pixel, i, col): (u64, u64, usize),
    inv: f64,
    rc: &mut RowClasses,
    tokens: &mut Vec<Token>,
) {
    let (w, nch) = (sys.camera.width_px, sys.response.curves.len());
    let pol = sys.display.polarization_weights;
    let disp = &sys.display;
    let shares = disp
        .primaries
        .is_some()
        .then(|| disp.primary_weights(s.lambda_nm));
    let cw = channel_weights(sys, s.lambda_nm);
    let mut rng = PathRng::new(&[set.seed, pixel, i, STRAY_TAG]);
    let ray = (s.ray.origin, s.ray.dir, s.lambda_nm);
    let ledger = trace_all_paths(
        &sys.waveguide,
        surround(sys),
        set.paths,
        ray,
        &mut rng,
        |exit| {
            let wt = pol[0] * exit.weight[0] + pol[1] * exit.weight[1];
            rc.exit_weight += wt;
            let radiance = match (exit.source, &shares) {
                // Uniform white at its luminance (the primaries' shares of white sum to 1).
                (Source::BehindDisplay, _) => sys.scene.behind_display.luminance,
                (Source::Display, Some(sh)) => disp.radiance_weighted_at(exit.object_point_mm, sh),
                (Source::Display, None) => disp.radiance_at(exit.object_point_mm),
            };
            let base = s.factor * wt * radiance;
            if !(base.is_finite() && base != 0.0) {
                return;
            }
            classes::fold(exit.events, exit.source, tokens);
            if rc.values.len() >= ROW_CLASSES && !rc.keys.contains_key(tokens.as_slice()) {
                // The row's overflow class (empty key): named OTHER.
                tokens.clear();
            }
            let k = match rc.keys.get(tokens.as_slice()) {
                Some(&k) => k,
                None => {
                    let k = rc.values.len();
                    rc.keys.insert(tokens.clone(), k);
                    rc.values.push(vec![0.0; w * nch]);
                    k
                }
            };
            if rc.all.is_empty() {
                rc.all = vec![0.0; w * nch];
            }
            let row = &mut rc.values[k];
            for c in 0..nch {
                let v = base * cw[c] * inv;
                row[col * nch + c] += v;
                rc.all[col * nch + c] += v;
            }
        },
    );
    rc.ledger.merge(&ledger);
    rc.rays += 1;
}

/// A class's event texts and short name.
type Labels = (Vec<String>, String);

/// A class's values per image row (columns × channels; `None` where the row has none).
type ClassRows = Vec<Option<Vec<f64>>>;

/// The rows' classes gathered by name, ranked, the rare ones summed, images kept for the
/// signal and the leading classes.
fn assemble(
    sys: &System,
    rows: Vec<RowClasses>,
    (w, h, nch): (usize, usize, usize),
) -> StrayImages {
    let pol = sys.display.polarization_weights;
    // Each class's per-row values, by name (BTreeMap: a fixed order for any thread count).
    let mut by_name: BTreeMap<String, (Labels, ClassRows)> = BTreeMap::new();
    let (mut ledger, mut exit_weight, mut rays) = (Ledger::default(), 0.0, 0u64);
    let mut all_paths = vec![vec![0.0f32; w * h]; nch];
    for (r, rc) in rows.into_iter().enumerate() {
        ledger.merge(&rc.ledger);
        exit_weight += rc.exit_weight;
        rays += rc.rays;
        if !rc.all.is_empty() {
            for (c, img) in all_paths.iter_mut().enumerate() {
                for col in 0..w {
                    img[r * w + col] = rc.all[col * nch + c] as f32;
                }
            }
        }
        let mut keyed: Vec<(Vec<Token>, usize)> = rc.keys.into_iter().collect();
        keyed.sort();
        let mut values: Vec<Option<Vec<f64>>> = rc.values.into_iter().map(Some).collect();
        for (tokens, k) in keyed {
            let name = if tokens.is_empty() {
                OTHER.to_string()
            } else {
                classes::name(&tokens)
            };
            let entry = by_name.entry(name.clone()).or_insert_with(|| {
                let labels = if name == classes::SIGNAL || name == OTHER {
                    (Vec::new(), name.clone())
                } else {
                    (
                        tokens.iter().map(|t| t.text()).collect(),
                        classes::short_name(&tokens),
                    )
                };
                (labels, vec![None; h])
            });
            let v = values[k].take().unwrap_or_default();
            match &mut entry.1[r] {
                Some(acc) => acc.iter_mut().zip(&v).for_each(|(a, b)| *a += b),
                slot => *slot = Some(v),
            }
        }
    }
    let distinct = by_name.len();
    let total_of =
        |rows: &[Option<Vec<f64>>]| -> f64 { rows.iter().flatten().flat_map(|r| r.iter()).sum() };
    let mut overflow = by_name.remove(OTHER).map(|(_, rows)| rows);
    type Ranked = (String, Labels, ClassRows, f64);
    let mut ranked: Vec<Ranked> = by_name
        .into_iter()
        .map(|(n, (e, rows))| {
            let t = total_of(&rows);
            (n, e, rows, t)
        })
        .collect();
    // The signal first, then by decreasing total (ties by name: the map's order is kept).
    ranked.sort_by(|a, b| {
        let sa = a.0 == classes::SIGNAL;
        let sb = b.0 == classes::SIGNAL;
        sb.cmp(&sa).then(b.3.total_cmp(&a.3))
    });
    let has_signal = ranked.first().is_some_and(|c| c.0 == classes::SIGNAL);
    let keep = MAX_CLASSES + usize::from(has_signal);
    if ranked.len() > keep || overflow.is_some() {
        let rest = ranked.split_off(keep.min(ranked.len()));
        let mut rows: Vec<Option<Vec<f64>>> = overflow.take().unwrap_or_else(|| vec![None; h]);
        for (_, _, r, _) in rest {
            for (acc, v) in rows.iter_mut().zip(r) {
                if let Some(v) = v {
                    match acc {
                        Some(a) => a.iter_mut().zip(&v).for_each(|(x, y)| *x += y),
                        None => *acc = Some(v),
                    }
                }
            }
        }
        let t = total_of(&rows);
        ranked.push((OTHER.to_string(), (Vec::new(), OTHER.to_string()), rows, t));
    }
    let classes = ranked
        .into_iter()
        .enumerate()
        .map(|(i, (name, (events, short), rows, total))| {
            let imaged = i <= IMAGED_CLASSES && name != OTHER;
            let row_sums: Vec<f64> = rows
                .iter()
                .map(|r| r.as_ref().map_or(0.0, |v| v.iter().sum()))
                .collect();
            let peak = rows
                .iter()
                .flatten()
                .flat_map(|r| r.iter().copied())
                .fold(0.0f64, f64::max);
            let image = imaged.then(|| {
                (0..nch)
                    .map(|c| {
                        let mut img = vec![0.0f32; w * h];
                        for (r, v) in rows.iter().enumerate() {
                            if let Some(v) = v {
                                for col in 0..w {
                                    img[r * w + col] = v[col * nch + c] as f32;
                                }
                            }
                        }
                        img
                    })
                    .collect()
            });
            ClassImage {
                name,
                events,
                short,
                total,
                peak,
                row_sums,
                image,
            }
        })
        .collect();
    let avg = |s: [f64; 2]| pol[0] * s[0] + pol[1] * s[1];
    let mut sinks = [0.0; SINKS];
    for (o, sink) in sinks.iter_mut().zip(Sink::ALL) {
        *o = avg(ledger.get(sink));
    }
    StrayImages {
        width: w,
        height: h,
        channel_names: sys.response.names.clone(),
        classes,
        distinct_classes: distinct,
        rays,
        branches: ledger.branches,
        exit_weight,
        sinks,
        all_paths,
    }
}
