//! Objects of a dataset: per-sample random draws from the recipe's sources, and the object
//! image they give.
//!
//! A draw ([`ObjectSpec`]) is a pure function of the sample seed, so metadata can be written
//! without rendering and any sample can be regenerated alone. Procedural patterns are made in
//! display code values (0 = black, 1 = white) by the built-in targets (`targets.rs`), warped by
//! a random similarity transform (scale, rotation, shift; 4×4 supersampled nearest-pixel
//! lookups, zero outside), optionally given random dark/bright levels, and then converted to linear intensity
//! with the scene's display gamma — the vector f of g = H f. Images are converted to luminance
//! in linear light (each channel linearised with the display gamma, then Rec. 709 weights; EXR
//! is already linear) and resized by exact area averaging (box filter with fractional pixel
//! coverage) after an optional centred square crop.

use std::path::{Path, PathBuf};

use crate::display::Display;
use crate::noise::NoiseRng;
use crate::targets::builtin_target;

use super::recipe::{Objects, Resize, Source};

/// Random similarity transform of a pattern: the pattern is scaled about the centre, rotated
/// and shifted (shift in fractions of the image size).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Warp {
    /// Scale factor.
    pub scale: f64,
    /// Rotation, degrees, counter-clockwise.
    pub angle_deg: f64,
    /// Shift right, fraction of the width.
    pub shift_x: f64,
    /// Shift down, fraction of the height.
    pub shift_y: f64,
}

/// One object draw.
#[derive(Clone, Debug, PartialEq)]
pub enum ObjectSpec {
    /// A glyph string.
    Glyphs {
        /// The text.
        text: String,
        /// Warp.
        warp: Warp,
    },
    /// A filled shape.
    Shape {
        /// Shape name.
        name: &'static str,
        /// Warp.
        warp: Warp,
    },
    /// A Siemens star.
    Siemens {
        /// Spoke pairs.
        spokes: usize,
        /// Rotation, degrees.
        angle_deg: f64,
    },
    /// Three resolution bars.
    Bars {
        /// Bar width, pixels.
        period_px: usize,
        /// Bars side by side along x (vertical bars) or along y.
        vertical: bool,
        /// Top-left corner of the group, pixels.
        origin_px: [usize; 2],
        /// Bar length, pixels.
        length_px: usize,
    },
    /// A smooth random field.
    Smooth {
        /// Its seed.
        seed: u64,
    },
    /// An image file.
    Image {
        /// The file.
        path: PathBuf,
        /// Path as recorded (relative to the recipe folder).
        name: String,
        /// Mirrored left–right.
        flip: bool,
    },
    /// A 3-D scene (`meshes`): drawn by `meshes.rs`, it has no 2-D object.
    Mesh,
    /// Object `index` of the arrays given to [`super::plan_with_objects`] (sample `index`).
    Array {
        /// Its index, equal to the sample id.
        index: usize,
    },
}

/// A draw with the index of its source and its levels.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectDraw {
    /// Index into `objects.sources`.
    pub source: usize,
    /// What to draw.
    pub spec: ObjectSpec,
    /// Dark and bright code values of a binary pattern (None: 0 and 1, or not binary).
    pub levels: Option<[f64; 2]>,
}

const SHAPES: [&str; 6] = ["disk", "ring", "triangle", "star", "cross", "heart"];
/// Domain tag of the object random stream.
const OBJECT_TAG: u64 = 0x4F42_4A45;

fn pick(rng: &mut NoiseRng, n: usize) -> usize {
    ((rng.uniform() * n as f64) as usize).min(n - 1)
}

fn between(rng: &mut NoiseRng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.uniform()
}

fn warp(rng: &mut NoiseRng, max_angle_deg: f64) -> Warp {
    let scale = between(rng, 0.55, 1.0);
    let room = 0.5 * (1.0 - scale);
    Warp {
        scale,
        angle_deg: between(rng, -max_angle_deg, max_angle_deg),
        shift_x: between(rng, -room, room),
        shift_y: between(rng, -room, room),
    }
}

/// Draws the object of the sample with seed `sample_seed`. `images[i]` lists the files of
/// source i (empty for procedural sources).
pub fn draw(objects: &Objects, images: &[Vec<(PathBuf, String)>], sample_seed: u64) -> ObjectDraw {
    let mut rng = NoiseRng::new(&[sample_seed, OBJECT_TAG]);
    let total: f64 = objects.sources.iter().map(Source::weight).sum();
    let mut u = rng.uniform() * total;
    let mut source = objects.sources.len() - 1;
    for (i, s) in objects.sources.iter().enumerate() {
        if u < s.weight() {
            source = i;
            break;
        }
        u -= s.weight();
    }
    let size = objects.size_px;
    let mut binary = true;
    let spec = match &objects.sources[source] {
        Source::Glyphs { chars, max_len, .. } => {
            let chars: Vec<char> = chars.chars().collect();
            let len = 1 + pick(&mut rng, *max_len);
            let text = (0..len)
                .map(|_| chars[pick(&mut rng, chars.len())])
                .collect();
            ObjectSpec::Glyphs {
                text,
                warp: warp(&mut rng, 20.0),
            }
        }
        Source::Shapes { .. } => ObjectSpec::Shape {
            name: SHAPES[pick(&mut rng, SHAPES.len())],
            warp: warp(&mut rng, 180.0),
        },
        Source::Siemens {
            min_spokes,
            max_spokes,
            ..
        } => ObjectSpec::Siemens {
            spokes: min_spokes + pick(&mut rng, max_spokes - min_spokes + 1),
            angle_deg: between(&mut rng, 0.0, 360.0),
        },
        Source::Bars {
            min_period_px,
            max_period_px,
            ..
        } => {
            let p = min_period_px + pick(&mut rng, max_period_px - min_period_px + 1);
            let length = (size / 2).max(5 * p).min(size);
            let vertical = rng.uniform() < 0.5;
            let across = pick(&mut rng, size - 5 * p + 1);
            let along = pick(&mut rng, size - length + 1);
            ObjectSpec::Bars {
                period_px: p,
                vertical,
                origin_px: if vertical {
                    [across, along]
                } else {
                    [along, across]
                },
                length_px: length,
            }
        }
        Source::Smooth { .. } => {
            binary = false;
            ObjectSpec::Smooth {
                seed: rng.next_u64() >> 11,
            }
        }
        Source::Images { flip, .. } => {
            binary = false;
            let files = &images[source];
            let (path, name) = files[pick(&mut rng, files.len())].clone();
            ObjectSpec::Image {
                path,
                name,
                flip: *flip && rng.uniform() < 0.5,
            }
        }
        Source::Meshes(_) => {
            binary = false;
            ObjectSpec::Mesh
        }
    };
    let levels = (binary && objects.random_levels)
        .then(|| [between(&mut rng, 0.0, 0.3), between(&mut rng, 0.6, 1.0)]);
    ObjectDraw {
        source,
        spec,
        levels,
    }
}

impl ObjectDraw {
    /// One-line description for the metadata, e.g. `glyphs text=AB scale=0.812 ...`.
    pub fn describe(&self) -> String {
        let w = |w: &Warp| {
            format!(
                "scale={:.4} angle_deg={:.3} shift=({:.4},{:.4})",
                w.scale, w.angle_deg, w.shift_x, w.shift_y
            )
        };
        let mut s = match &self.spec {
            ObjectSpec::Glyphs { text, warp } => format!("glyphs text={text} {}", w(warp)),
            ObjectSpec::Shape { name, warp } => format!("shapes shape={name} {}", w(warp)),
            ObjectSpec::Siemens { spokes, angle_deg } => {
                format!("siemens spokes={spokes} angle_deg={angle_deg:.3}")
            }
            ObjectSpec::Bars {
                period_px,
                vertical,
                origin_px,
                length_px,
            } => format!(
                "bars period_px={period_px} {} origin_px=({},{}) length_px={length_px}",
                if *vertical { "vertical" } else { "horizontal" },
                origin_px[0],
                origin_px[1]
            ),
            ObjectSpec::Smooth { seed } => format!("smooth seed={seed}"),
            ObjectSpec::Image { name, flip, .. } => format!("images file={name} flip={flip}"),
            ObjectSpec::Mesh => "meshes".to_string(),
            ObjectSpec::Array { index } => format!("array index={index}"),
        };
        if let Some([d, b]) = self.levels {
            s.push_str(&format!(" levels=({d:.4},{b:.4})"));
        }
        s
    }

    /// The object as linear intensities in [0, 1] (row-major, `size`²), using the display
    /// `gamma` for code values.
    pub fn intensity(&self, size: usize, gamma: f64, resize: Resize) -> Result<Vec<f64>, String> {
        let code: Vec<f32> = match &self.spec {
            ObjectSpec::Glyphs { text, warp } => {
                let spec = if text.chars().count() == 1 {
                    format!("letter:{text}@{size}")
                } else {
                    format!("text:{text}@{size}")
                };
                warped(&builtin_target(&spec)?.values, size, warp)
            }
            ObjectSpec::Shape { name, warp } => warped(
                &builtin_target(&format!("shape:{name}@{size}"))?.values,
                size,
                warp,
            ),
            ObjectSpec::Siemens { spokes, angle_deg } => {
                let base = builtin_target(&format!("siemens:{spokes}@{size}"))?.values;
                warped(
                    &base,
                    size,
                    &Warp {
                        scale: 1.0,
                        angle_deg: *angle_deg,
                        shift_x: 0.0,
                        shift_y: 0.0,
                    },
                )
            }
            ObjectSpec::Bars {
                period_px,
                vertical,
                origin_px,
                length_px,
            } => {
                let (p, [x0, y0], len) = (*period_px, *origin_px, *length_px);
                (0..size * size)
                    .map(|i| {
                        let (x, y) = (i % size, i / size);
                        let (a, b, a0, b0) = if *vertical {
                            (x, y, x0, y0)
                        } else {
                            (y, x, y0, x0)
                        };
                        let lit = a >= a0
                            && a < a0 + 5 * p
                            && ((a - a0) / p).is_multiple_of(2)
                            && b >= b0
                            && b < b0 + len;
                        if lit { 1.0 } else { 0.0 }
                    })
                    .collect()
            }
            ObjectSpec::Smooth { seed } => builtin_target(&format!("smooth:{seed}@{size}"))?.values,
            ObjectSpec::Image { path, flip, .. } => {
                return load_resized(path, size, gamma, resize, *flip);
            }
            ObjectSpec::Mesh => return Err("a 3-D scene has no 2-D object".to_string()),
            ObjectSpec::Array { .. } => {
                return Err("an array object is held by the plan (Plan::object_of)".to_string());
            }
        };
        let code: Vec<f32> = match self.levels {
            Some([d, b]) => code
                .iter()
                .map(|&v| (d + (b - d) * f64::from(v)) as f32)
                .collect(),
            None => code,
        };
        Ok(Display::intensity_of(&code, 1, false, gamma))
    }
}

/// Nearest-pixel sample of `img` (size², zero outside) at continuous pixel coordinates.
fn nearest(img: &[f32], size: usize, x: f64, y: f64) -> f64 {
    if x < 0.0 || y < 0.0 || x >= size as f64 || y >= size as f64 {
        0.0
    } else {
        f64::from(img[y as usize * size + x as usize])
    }
}

/// Sub-samples per pixel side of the warp (4×4 per pixel: anti-aliased edges, exact for the
/// identity and for whole-pixel shifts).
const SUPERSAMPLE: usize = 4;

/// `img` after the warp: each output pixel averages `SUPERSAMPLE`² sub-samples, each mapped by
/// the inverse transform to the nearest source pixel.
fn warped(img: &[f32], size: usize, w: &Warp) -> Vec<f32> {
    let s = size as f64;
    let (sin, cos) = w.angle_deg.to_radians().sin_cos();
    let k = SUPERSAMPLE as f64;
    (0..size * size)
        .map(|i| {
            let (x, y) = ((i % size) as f64, (i / size) as f64);
            let mut acc = 0.0;
            for j in 0..SUPERSAMPLE * SUPERSAMPLE {
                let (ox, oy) = (
                    ((j % SUPERSAMPLE) as f64 + 0.5) / k,
                    ((j / SUPERSAMPLE) as f64 + 0.5) / k,
                );
                // Centred coordinates (x right, y down), then undo shift, rotation, scale.
                let u = (x + ox) / s - 0.5 - w.shift_x;
                let v = (y + oy) / s - 0.5 - w.shift_y;
                // Counter-clockwise on screen (y down) is a clockwise rotation of (u, v).
                let (ru, rv) = (cos * u - sin * v, sin * u + cos * v);
                acc += nearest(
                    img,
                    size,
                    (ru / w.scale + 0.5) * s,
                    (rv / w.scale + 0.5) * s,
                );
            }
            (acc / (k * k)) as f32
        })
        .collect()
}

/// Area-average resampling of `n_in` samples over [lo, lo + len) to `n_out` samples: weights
/// (input index, weight) per output sample, summing to 1.
fn area_weights(lo: f64, len: f64, n_out: usize) -> Vec<Vec<(usize, f64)>> {
    let step = len / n_out as f64;
    (0..n_out)
        .map(|o| {
            let (a, b) = (lo + o as f64 * step, lo + (o + 1) as f64 * step);
            let mut w = Vec::new();
            let mut i = a.floor() as usize;
            while (i as f64) < b {
                let overlap = (b.min(i as f64 + 1.0) - a.max(i as f64)).max(0.0);
                if overlap > 0.0 {
                    w.push((i, overlap / step));
                }
                i += 1;
            }
            w
        })
        .collect()
}

/// Loads an image, converts it to linear luminance and resizes it to `size`².
pub fn load_resized(
    path: &Path,
    size: usize,
    gamma: f64,
    resize: Resize,
    flip: bool,
) -> Result<Vec<f64>, String> {
    let img = crate::io::load_image(path).map_err(|e| e.to_string())?;
    let lin = Display::intensity_of(&img.values, img.channels, img.linear, gamma);
    let (w, h) = (img.width, img.height);
    let (x0, y0, cw, ch) = match resize {
        Resize::CenterCrop => {
            let side = w.min(h);
            (
                (w - side) as f64 / 2.0,
                (h - side) as f64 / 2.0,
                side as f64,
                side as f64,
            )
        }
        Resize::Stretch => (0.0, 0.0, w as f64, h as f64),
    };
    let wx = area_weights(x0, cw, size);
    let wy = area_weights(y0, ch, size);
    // Rows first: h × size.
    let mut rows = vec![0.0; h * size];
    for y in 0..h {
        for (o, ws) in wx.iter().enumerate() {
            rows[y * size + o] = ws.iter().map(|&(i, k)| k * lin[y * w + i.min(w - 1)]).sum();
        }
    }
    let mut out = vec![0.0; size * size];
    for (oy, ws) in wy.iter().enumerate() {
        for ox in 0..size {
            let v: f64 = ws
                .iter()
                .map(|&(i, k)| k * rows[i.min(h - 1) * size + ox])
                .sum();
            let col = if flip { size - 1 - ox } else { ox };
            out[oy * size + col] = v.clamp(0.0, 1.0);
        }
    }
    Ok(out)
}

/// Image files (`.png`, `.jpg`, `.jpeg`) in `folder` (and sub-folders if `recursive`), sorted
/// by path, each with its name relative to `folder`'s parent-independent form `FOLDER/...`.
pub fn list_images(
    folder: &Path,
    shown: &str,
    recursive: bool,
) -> Result<Vec<(PathBuf, String)>, String> {
    let mut out = Vec::new();
    let mut stack = vec![(
        folder.to_path_buf(),
        shown.trim_end_matches('/').to_string(),
    )];
    while let Some((dir, name)) = stack.pop() {
        let entries = std::fs::read_dir(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        for e in entries {
            let e = e.map_err(|e| format!("{}: {e}", dir.display()))?;
            let path = e.path();
            let child = format!("{name}/{}", e.file_name().to_string_lossy());
            if path.is_dir() {
                if recursive {
                    stack.push((path, child));
                }
            } else if crate::io::image_load::is_code_value_image(&path) {
                out.push((path, child));
            }
        }
    }
    out.sort_by(|a, b| a.1.cmp(&b.1));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn area_weights_sum_to_one_and_cover_the_input() {
        for (lo, len, n) in [(0.0, 100.0, 64), (12.5, 75.0, 64), (0.0, 3.0, 7)] {
            let w = area_weights(lo, len, n);
            for ws in &w {
                let s: f64 = ws.iter().map(|x| x.1).sum();
                assert!((s - 1.0).abs() < 1e-12, "{s}");
            }
            let total: f64 = w.iter().flatten().map(|x| x.1).sum::<f64>() * len / n as f64;
            assert!((total - len).abs() < 1e-9);
        }
    }

    #[test]
    fn identity_warp_keeps_the_pattern_and_a_shift_moves_it() {
        let size = 32;
        let base = builtin_target(&format!("shape:disk@{size}"))
            .unwrap()
            .values;
        let id = warped(
            &base,
            size,
            &Warp {
                scale: 1.0,
                angle_deg: 0.0,
                shift_x: 0.0,
                shift_y: 0.0,
            },
        );
        assert_eq!(id, base);
        let moved = warped(
            &base,
            size,
            &Warp {
                scale: 1.0,
                angle_deg: 0.0,
                shift_x: 0.25,
                shift_y: 0.0,
            },
        );
        // An 8-pixel shift right.
        for y in 0..size {
            for x in 8..size {
                assert_eq!(moved[y * size + x], base[y * size + x - 8]);
            }
        }
        // A half-size pattern has a quarter of the area (within edge effects).
        let half = warped(
            &base,
            size,
            &Warp {
                scale: 0.5,
                angle_deg: 30.0,
                shift_x: 0.0,
                shift_y: 0.0,
            },
        );
        let area = |v: &[f32]| v.iter().map(|&x| f64::from(x)).sum::<f64>();
        let r = area(&half) / area(&base);
        assert!((r - 0.25).abs() < 0.02, "{r}");
    }

    #[test]
    fn draws_are_reproducible_and_follow_the_weights() {
        let objects = Objects {
            size_px: 32,
            frontal_space: None,
            frontal_spp: None,
            random_levels: true,
            sources: vec![
                Source::Shapes { weight: 3.0 },
                Source::Bars {
                    weight: 1.0,
                    min_period_px: 1,
                    max_period_px: 4,
                },
            ],
        };
        let n = 4000;
        let mut shapes = 0;
        for s in 0..n {
            let d = draw(&objects, &[vec![], vec![]], s);
            assert_eq!(d, draw(&objects, &[vec![], vec![]], s));
            let f = d.intensity(32, 2.2, Resize::CenterCrop).unwrap();
            assert_eq!(f.len(), 32 * 32);
            assert!(f.iter().all(|v| (0.0..=1.0).contains(v)));
            shapes += usize::from(d.source == 0);
        }
        // Binomial(4000, 0.75): sd 27.
        assert!((shapes as f64 - 3000.0).abs() < 5.0 * 27.4, "{shapes}");
    }
}
