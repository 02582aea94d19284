//! Built-in, procedurally generated display targets.
//!
//! A target is chosen by a spec `NAME[:ARGS][@SIZE]`; the image is SIZE×SIZE
//! pixels (default 64, SIZE in 2..=4096) of display code values in `[0, 1]`.
//!
//! - `white`, `black`, `gray:V` — uniform fields (V in `[0, 1]`).
//! - `point`, `point:COL,ROW` — one lit pixel (default at the centre, SIZE/2).
//! - `checker:N` — checkerboard of N-pixel squares, top-left square lit.
//! - `hbars:N`, `vbars:N` — horizontal / vertical bars N pixels wide, first lit.
//! - `letter:X`, `text:STRING` — glyphs of an embedded 5×7 font (A–Z, 0–9;
//!   lowercase is drawn as uppercase, `text` also allows spaces), scaled by the
//!   largest integer factor that fits (`letter` keeps a one-glyph margin).
//! - `siemens:N` — binary Siemens star with N spoke pairs.
//! - `gradient` — horizontal ramp from 0 (left pixel centre) to 1 (right).
//! - `shape:NAME` — a filled binary shape: `disk`, `ring`, `triangle`, `star` (five-pointed),
//!   `cross`, `heart`; a pixel is lit when its centre is inside.
//! - `smooth:SEED` — smooth photo-like field from a seeded PRNG, in
//!   `[0.05, 0.95]`, bit-identical on every platform.
//!
//! Colour: `rgb:R+G+B` composes three of the above (each with its own `@SIZE`, all the same
//! size) into the red, green and blue channels of one image ([`builtin_image`]), e.g.
//! `rgb:letter:F+black+black` (a red F); a monochrome display shows its luminance.

use std::f64::consts::{LN_2, PI, TAU};

/// A display target: `values[row * width + col]`, row 0 at the top and column 0
/// at the left as seen by a viewer facing the display.
#[derive(Debug, Clone, PartialEq)]
pub struct Target {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Display code values in `[0, 1]`, row-major.
    pub values: Vec<f32>,
}

impl Target {
    fn from_fn(size: usize, f: impl Fn(usize, usize) -> f32) -> Self {
        let values = (0..size * size).map(|i| f(i % size, i / size)).collect();
        Target {
            width: size,
            height: size,
            values,
        }
    }
}

const DEFAULT_SIZE: usize = 64;
const MAX_SIZE: usize = 4096;
const NAMES: &[&str] = &[
    "white",
    "black",
    "gray:V",
    "point",
    "point:COL,ROW",
    "checker:N",
    "hbars:N",
    "vbars:N",
    "letter:X",
    "text:STRING",
    "siemens:N",
    "gradient",
    "smooth:SEED",
    "shape:disk|ring|triangle|star|cross|heart",
];

/// The name patterns accepted by [`builtin_target`], for help text.
pub fn builtin_names() -> &'static [&'static str] {
    NAMES
}

/// Builds the target described by `spec` (`NAME[:ARGS][@SIZE]`, see the module
/// documentation). The error is one line saying what is wrong and listing the
/// valid names.
pub fn builtin_target(spec: &str) -> Result<Target, String> {
    parse(spec).map_err(|msg| {
        format!(
            "invalid target {spec:?}: {msg}; valid targets: {} (optionally followed by @SIZE, \
             SIZE in 2..={MAX_SIZE}, default {DEFAULT_SIZE})",
            NAMES.join(", ")
        )
    })
}

/// A built-in image: (width, height, channels, values interleaved by pixel). Grey targets have
/// one channel; `rgb:R+G+B` has three (see the module documentation).
pub fn builtin_image(spec: &str) -> Result<(usize, usize, usize, Vec<f32>), String> {
    let Some(body) = spec.strip_prefix("rgb:") else {
        let t = builtin_target(spec)?;
        return Ok((t.width, t.height, 1, t.values));
    };
    let parts: Vec<&str> = body.split('+').collect();
    if parts.len() != 3 {
        return Err(format!(
            "invalid target {spec:?}: rgb: needs three targets joined by '+' (red+green+blue), e.g. rgb:letter:F+black+black"
        ));
    }
    let planes = parts
        .iter()
        .map(|p| builtin_target(p))
        .collect::<Result<Vec<_>, _>>()?;
    let (w, h) = (planes[0].width, planes[0].height);
    if planes.iter().any(|t| (t.width, t.height) != (w, h)) {
        return Err(format!(
            "invalid target {spec:?}: the three targets of rgb: must have the same size"
        ));
    }
    let values = (0..w * h)
        .flat_map(|i| planes.iter().map(move |t| t.values[i]))
        .collect();
    Ok((w, h, 3, values))
}

fn parse(spec: &str) -> Result<Target, String> {
    let (body, size) = match spec.rsplit_once('@') {
        Some((body, s)) => match s.parse::<usize>() {
            Ok(n) if (2..=MAX_SIZE).contains(&n) => (body, n),
            _ => return Err(format!("size {s:?} is not an integer in 2..={MAX_SIZE}")),
        },
        None => (spec, DEFAULT_SIZE),
    };
    let (name, args) = match body.split_once(':') {
        Some((name, args)) => (name, Some(args)),
        None => (body, None),
    };
    let uniform = |v: f32| Target::from_fn(size, |_, _| v);
    let bars = |a: &str| {
        a.parse::<usize>()
            .ok()
            .filter(|&n| n >= 1)
            .ok_or(format!("{a:?} is not a positive integer"))
    };
    let lit = |on: bool| if on { 1.0 } else { 0.0 };
    Ok(match (name, args) {
        ("white", None) => uniform(1.0),
        ("black", None) => uniform(0.0),
        ("gray", Some(a)) => match a.parse::<f32>() {
            Ok(v) if (0.0..=1.0).contains(&v) => uniform(v),
            _ => return Err(format!("gray level {a:?} is not a number in [0, 1]")),
        },
        ("point", None) => point(size, size / 2, size / 2),
        ("point", Some(a)) => {
            let coord = |s: &str| s.trim().parse::<usize>().ok().filter(|&v| v < size);
            match a.split_once(',').map(|(c, r)| (coord(c), coord(r))) {
                Some((Some(col), Some(row))) => point(size, col, row),
                _ => return Err(format!("point {a:?} is not COL,ROW with both in 0..{size}")),
            }
        }
        ("checker", Some(a)) => {
            let n = bars(a)?;
            Target::from_fn(size, |x, y| lit((x / n + y / n).is_multiple_of(2)))
        }
        ("hbars", Some(a)) => {
            let n = bars(a)?;
            Target::from_fn(size, |_, y| lit((y / n).is_multiple_of(2)))
        }
        ("vbars", Some(a)) => {
            let n = bars(a)?;
            Target::from_fn(size, |x, _| lit((x / n).is_multiple_of(2)))
        }
        ("letter", Some(a)) if a.chars().count() == 1 && a != " " => draw_text(size, a, true)?,
        ("letter", Some(a)) => {
            return Err(format!(
                "letter {a:?} must be a single character A-Z or 0-9"
            ));
        }
        ("text", Some(a)) if !a.is_empty() => draw_text(size, a, false)?,
        ("siemens", Some(a)) => siemens(size, bars(a)?),
        ("gradient", None) => Target::from_fn(size, |x, _| (x as f64 / (size - 1) as f64) as f32),
        ("shape", Some(a)) => shape(size, a)?,
        ("smooth", Some(a)) => match a.parse::<u64>() {
            Ok(seed) => smooth(size, seed),
            Err(_) => return Err(format!("seed {a:?} is not an unsigned integer")),
        },
        (name, Some(_)) if NAMES.contains(&name) => {
            return Err(format!("'{name}' takes no arguments"));
        }
        (name, _) if NAMES.iter().any(|p| p.split(':').next() == Some(name)) => {
            return Err(format!("'{name}' needs an argument"));
        }
        (name, _) => return Err(format!("unknown target name {name:?}")),
    })
}

fn point(size: usize, col: usize, row: usize) -> Target {
    Target::from_fn(size, |x, y| if (x, y) == (col, row) { 1.0 } else { 0.0 })
}

/// Draws `text` in one row (one blank column between glyphs), scaled by the
/// largest integer factor that fits and centred. With `margin`, a blank border
/// one glyph cell wide is kept when the size allows it.
fn draw_text(size: usize, text: &str, margin: bool) -> Result<Target, String> {
    let glyphs = text.chars().map(glyph).collect::<Result<Vec<_>, _>>()?;
    let (cols, rows) = (glyphs.len() * (GLYPH_W + 1) - 1, GLYPH_H);
    let fit = |w: usize, h: usize| (size / w).min(size / h);
    let with_margin = if margin {
        fit(cols + 2 * GLYPH_W, rows + 2 * GLYPH_H)
    } else {
        0
    };
    let scale = if with_margin > 0 {
        with_margin
    } else {
        fit(cols, rows)
    };
    if scale == 0 {
        return Err(format!(
            "{text:?} ({cols}x{rows} font pixels) does not fit in {size}x{size}"
        ));
    }
    let (x0, y0) = ((size - cols * scale) / 2, (size - rows * scale) / 2);
    Ok(Target::from_fn(size, |x, y| {
        if x < x0 || y < y0 || x >= x0 + cols * scale || y >= y0 + rows * scale {
            return 0.0;
        }
        let (fx, fy) = ((x - x0) / scale, (y - y0) / scale);
        let (index, col) = (fx / (GLYPH_W + 1), fx % (GLYPH_W + 1));
        let on = col < GLYPH_W && (glyphs[index][fy] >> (GLYPH_W - 1 - col)) & 1 == 1;
        if on { 1.0 } else { 0.0 }
    }))
}

/// Point-in-polygon by the crossing rule.
fn inside_polygon(p: (f64, f64), poly: &[(f64, f64)]) -> bool {
    let mut inside = false;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[j]);
        if (a.1 > p.1) != (b.1 > p.1) && p.0 < (b.0 - a.0) * (p.1 - a.1) / (b.1 - a.1) + a.0 {
            inside = !inside;
        }
        j = i;
    }
    inside
}

fn shape(size: usize, name: &str) -> Result<Target, String> {
    // Normalised coordinates: x right, y up, the image spans [-1, 1]².
    let star: Vec<(f64, f64)> = (0..10)
        .map(|k| {
            let r = if k % 2 == 0 { 0.85 } else { 0.34 };
            let a = PI / 2.0 + k as f64 * PI / 5.0;
            (r * a.cos(), r * a.sin() - 0.05)
        })
        .collect();
    let test: Box<dyn Fn(f64, f64) -> bool> = match name {
        "disk" => Box::new(|x, y| x * x + y * y < 0.75 * 0.75),
        "ring" => Box::new(|x, y| (0.45 * 0.45..0.8 * 0.8).contains(&(x * x + y * y))),
        "triangle" => {
            Box::new(|x, y| inside_polygon((x, y), &[(-0.8, -0.6), (0.8, -0.6), (0.0, 0.78)]))
        }
        "star" => Box::new(move |x, y| inside_polygon((x, y), &star)),
        "cross" => {
            Box::new(|x, y| (x.abs() < 0.22 && y.abs() < 0.8) || (y.abs() < 0.22 && x.abs() < 0.8))
        }
        "heart" => Box::new(|x, y| {
            let (x, y) = (x / 0.8, (y + 0.1) / 0.8);
            (x * x + y * y - 1.0).powi(3) - x * x * y * y * y < 0.0
        }),
        _ => {
            return Err(format!(
                "shape {name:?} is not one of disk, ring, triangle, star, cross, heart"
            ));
        }
    };
    let s = size as f64;
    Ok(Target::from_fn(size, |c, r| {
        let x = (c as f64 + 0.5) / s * 2.0 - 1.0;
        let y = 1.0 - (r as f64 + 0.5) / s * 2.0;
        if test(x, y) { 1.0 } else { 0.0 }
    }))
}

/// Renders `text` with the embedded 5×7 font at `scale` pixels per font pixel, as a
/// (width, height, values) image with one font pixel of margin; ASCII letters are drawn upper
/// case and characters the font lacks as a hollow box ([`has_label_glyph`]). For labels in
/// figures.
pub fn label(text: &str, scale: usize) -> (usize, usize, Vec<f32>) {
    let glyphs: Vec<[u8; GLYPH_H]> = text
        .chars()
        .map(|c| {
            glyph(c)
                .ok()
                .or_else(|| punctuation(c))
                .unwrap_or(MISSING_GLYPH)
        })
        .collect();
    let scale = scale.max(1);
    let cols = (glyphs.len() * (GLYPH_W + 1)).max(1) + 1;
    let rows = GLYPH_H + 2;
    let (w, h) = (cols * scale, rows * scale);
    let mut v = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let (fx, fy) = (x / scale, y / scale);
            if fx == 0 || fy == 0 || fy > GLYPH_H {
                continue;
            }
            let (index, col) = ((fx - 1) / (GLYPH_W + 1), (fx - 1) % (GLYPH_W + 1));
            if index < glyphs.len()
                && col < GLYPH_W
                && (glyphs[index][fy - 1] >> (GLYPH_W - 1 - col)) & 1 == 1
            {
                v[y * w + x] = 1.0;
            }
        }
    }
    (w, h, v)
}

/// Binary Siemens star: lit where `floor(n * angle / pi)` is even, with the
/// angle measured counter-clockwise from the +x axis at pixel centres; zero
/// outside the disc of radius `size / 2 - 1`.
fn siemens(size: usize, n: usize) -> Target {
    let c = size as f64 / 2.0;
    let radius = c - 1.0;
    Target::from_fn(size, |x, y| {
        let (dx, dy) = (x as f64 + 0.5 - c, c - (y as f64 + 0.5));
        if dx.hypot(dy) > radius {
            return 0.0;
        }
        let angle = dy.atan2(dx).rem_euclid(TAU);
        if ((n as f64 * angle / PI).floor() as u64).is_multiple_of(2) {
            1.0
        } else {
            0.0
        }
    })
}

/// Smooth random field: 12 Gaussian blobs plus 2 low-frequency cosines,
/// normalised to `[0.05, 0.95]`. Only IEEE basic operations are used (with
/// self-written `exp`/`cos`), so the result is bit-identical everywhere.
fn smooth(size: usize, seed: u64) -> Target {
    let mut state = seed;
    let mut unit = move || {
        // splitmix64
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    // Blob: centre u, centre v, sigma, amplitude.
    let blobs: Vec<[f64; 4]> = (0..12)
        .map(|_| [unit(), unit(), 0.05 + 0.2 * unit(), 2.0 * unit() - 1.0])
        .collect();
    // Wave: cycles per image along u and v, phase, amplitude.
    let waves: Vec<[f64; 4]> = (0..2)
        .map(|_| {
            [
                4.0 * unit() - 2.0,
                4.0 * unit() - 2.0,
                TAU * unit(),
                0.2 + 0.3 * unit(),
            ]
        })
        .collect();
    let field: Vec<f64> = (0..size * size)
        .map(|i| {
            let u = ((i % size) as f64 + 0.5) / size as f64;
            let v = ((i / size) as f64 + 0.5) / size as f64;
            let b: f64 = blobs
                .iter()
                .map(|&[cu, cv, s, a]| {
                    a * det_exp(-((u - cu) * (u - cu) + (v - cv) * (v - cv)) / (2.0 * s * s))
                })
                .sum();
            let w: f64 = waves
                .iter()
                .map(|&[fu, fv, p, a]| a * det_cos(TAU * (fu * u + fv * v) + p))
                .sum();
            b + w
        })
        .collect();
    let (lo, hi) = field
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &f| {
            (lo.min(f), hi.max(f))
        });
    let values = field
        .iter()
        .map(|&f| {
            let t = if hi > lo { (f - lo) / (hi - lo) } else { 0.5 };
            (0.05 + 0.9 * t).clamp(0.05, 0.95) as f32
        })
        .collect();
    Target {
        width: size,
        height: size,
        values,
    }
}

/// `exp(x)` from basic IEEE operations only (range reduction + Taylor series),
/// for cross-platform bit-identical results. Relative error ~1e-16.
fn det_exp(x: f64) -> f64 {
    if x < -700.0 {
        return 0.0;
    }
    let x = x.min(700.0);
    let k = (x / LN_2).round();
    let r = x - k * LN_2;
    let (mut term, mut sum) = (1.0, 1.0);
    for i in 1..=13 {
        term *= r / f64::from(i);
        sum += term;
    }
    // 2^k, built exactly from the exponent bits (|k| <= 1010).
    sum * f64::from_bits(((k as i64 + 1023) as u64) << 52)
}

/// `cos(x)` from basic IEEE operations only (reduction to `[-pi, pi]` + Taylor
/// series), for cross-platform bit-identical results.
fn det_cos(x: f64) -> f64 {
    let t = x - (x / TAU).round() * TAU;
    let t2 = t * t;
    let (mut term, mut sum) = (1.0, 1.0);
    for i in 1..=14 {
        term *= -t2 / f64::from((2 * i - 1) * (2 * i));
        sum += term;
    }
    sum
}

const GLYPH_W: usize = 5;
const GLYPH_H: usize = 7;

/// 5×7 glyph rows, top to bottom; bit 4 is the leftmost column.
fn glyph(c: char) -> Result<[u8; GLYPH_H], String> {
    let c = c.to_ascii_uppercase();
    if c == ' ' {
        return Ok([0; GLYPH_H]);
    }
    FONT.iter()
        .find(|(k, _)| *k == c)
        .map(|(_, g)| *g)
        .ok_or_else(|| format!("character {c:?} is not in the built-in font (A-Z, 0-9)"))
}

/// Punctuation for figure labels only (targets keep to A–Z, 0–9 and space).
fn punctuation(c: char) -> Option<[u8; GLYPH_H]> {
    PUNCT.iter().find(|(k, _)| *k == c).map(|(_, g)| *g)
}

#[rustfmt::skip]
const PUNCT: &[(char, [u8; GLYPH_H])] = &[
    ('.', [0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b01100, 0b01100]),
    (',', [0b00000, 0b00000, 0b00000, 0b00000, 0b01100, 0b00100, 0b01000]),
    ('-', [0b00000, 0b00000, 0b00000, 0b11111, 0b00000, 0b00000, 0b00000]),
    ('−', [0b00000, 0b00000, 0b00000, 0b11111, 0b00000, 0b00000, 0b00000]),
    ('–', [0b00000, 0b00000, 0b00000, 0b11111, 0b00000, 0b00000, 0b00000]),
    ('+', [0b00000, 0b00100, 0b00100, 0b11111, 0b00100, 0b00100, 0b00000]),
    ('±', [0b00100, 0b00100, 0b11111, 0b00100, 0b00100, 0b00000, 0b11111]),
    ('%', [0b11000, 0b11001, 0b00010, 0b00100, 0b01000, 0b10011, 0b00011]),
    ('(', [0b00010, 0b00100, 0b01000, 0b01000, 0b01000, 0b00100, 0b00010]),
    (')', [0b01000, 0b00100, 0b00010, 0b00010, 0b00010, 0b00100, 0b01000]),
    ('[', [0b01110, 0b01000, 0b01000, 0b01000, 0b01000, 0b01000, 0b01110]),
    (']', [0b01110, 0b00010, 0b00010, 0b00010, 0b00010, 0b00010, 0b01110]),
    ('{', [0b00010, 0b00100, 0b00100, 0b01000, 0b00100, 0b00100, 0b00010]),
    ('}', [0b01000, 0b00100, 0b00100, 0b00010, 0b00100, 0b00100, 0b01000]),
    (':', [0b00000, 0b01100, 0b01100, 0b00000, 0b01100, 0b01100, 0b00000]),
    (';', [0b00000, 0b01100, 0b01100, 0b00000, 0b01100, 0b00100, 0b01000]),
    ('/', [0b00000, 0b00001, 0b00010, 0b00100, 0b01000, 0b10000, 0b00000]),
    ('\\', [0b00000, 0b10000, 0b01000, 0b00100, 0b00010, 0b00001, 0b00000]),
    ('|', [0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100]),
    ('‖', [0b01010, 0b01010, 0b01010, 0b01010, 0b01010, 0b01010, 0b01010]),
    ('=', [0b00000, 0b00000, 0b11111, 0b00000, 0b11111, 0b00000, 0b00000]),
    ('<', [0b00001, 0b00010, 0b00100, 0b01000, 0b00100, 0b00010, 0b00001]),
    ('>', [0b10000, 0b01000, 0b00100, 0b00010, 0b00100, 0b01000, 0b10000]),
    ('≤', [0b00011, 0b01100, 0b10000, 0b01100, 0b00011, 0b00000, 0b11111]),
    ('≥', [0b11000, 0b00110, 0b00001, 0b00110, 0b11000, 0b00000, 0b11111]),
    ('→', [0b00000, 0b00100, 0b00010, 0b11111, 0b00010, 0b00100, 0b00000]),
    ('\'', [0b00100, 0b00100, 0b01000, 0b00000, 0b00000, 0b00000, 0b00000]),
    ('`', [0b01000, 0b00100, 0b00000, 0b00000, 0b00000, 0b00000, 0b00000]),
    ('"', [0b01010, 0b01010, 0b00000, 0b00000, 0b00000, 0b00000, 0b00000]),
    ('_', [0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b00000, 0b11111]),
    ('!', [0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b00000, 0b00100]),
    ('?', [0b01110, 0b10001, 0b00001, 0b00010, 0b00100, 0b00000, 0b00100]),
    ('*', [0b00000, 0b00100, 0b10101, 0b01110, 0b10101, 0b00100, 0b00000]),
    ('#', [0b01010, 0b01010, 0b11111, 0b01010, 0b11111, 0b01010, 0b01010]),
    ('&', [0b01100, 0b10010, 0b10100, 0b01000, 0b10101, 0b10010, 0b01101]),
    ('@', [0b01110, 0b10001, 0b10111, 0b10101, 0b10111, 0b10000, 0b01110]),
    ('^', [0b00100, 0b01010, 0b10001, 0b00000, 0b00000, 0b00000, 0b00000]),
    ('~', [0b00000, 0b00000, 0b01000, 0b10101, 0b00010, 0b00000, 0b00000]),
    ('°', [0b01100, 0b10010, 0b10010, 0b01100, 0b00000, 0b00000, 0b00000]),
    ('·', [0b00000, 0b00000, 0b00000, 0b01100, 0b01100, 0b00000, 0b00000]),
    ('×', [0b00000, 0b10001, 0b01010, 0b00100, 0b01010, 0b10001, 0b00000]),
    ('µ', [0b00000, 0b10001, 0b10001, 0b10001, 0b10011, 0b11101, 0b10000]),
    ('λ', [0b01000, 0b00100, 0b00100, 0b01010, 0b01010, 0b10001, 0b10001]),
    ('ν', [0b00000, 0b00000, 0b10001, 0b10001, 0b01010, 0b01010, 0b00100]),
    ('Θ', [0b01110, 0b10001, 0b10001, 0b11111, 0b10001, 0b10001, 0b01110]),
    ('ᵀ', [0b11111, 0b00100, 0b00100, 0b00000, 0b00000, 0b00000, 0b00000]),
    ('²', [0b01100, 0b00010, 0b00100, 0b01110, 0b00000, 0b00000, 0b00000]),
    ('³', [0b01110, 0b00010, 0b00110, 0b00010, 0b01110, 0b00000, 0b00000]),
];

/// Drawn for a character the font lacks: a hollow box, so nothing is dropped silently.
const MISSING_GLYPH: [u8; GLYPH_H] = [
    0b11111, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b11111,
];

/// True if the figure-label font has a glyph for `c` (letters are drawn upper case).
pub fn has_label_glyph(c: char) -> bool {
    c == ' ' || glyph(c).is_ok() || punctuation(c).is_some()
}

#[rustfmt::skip]
const FONT: [(char, [u8; GLYPH_H]); 36] = [
    ('A', [0b01110, 0b10001, 0b10001, 0b11111, 0b10001, 0b10001, 0b10001]),
    ('B', [0b11110, 0b10001, 0b10001, 0b11110, 0b10001, 0b10001, 0b11110]),
    ('C', [0b01110, 0b10001, 0b10000, 0b10000, 0b10000, 0b10001, 0b01110]),
    ('D', [0b11100, 0b10010, 0b10001, 0b10001, 0b10001, 0b10010, 0b11100]),
    ('E', [0b11111, 0b10000, 0b10000, 0b11110, 0b10000, 0b10000, 0b11111]),
    ('F', [0b11111, 0b10000, 0b10000, 0b11110, 0b10000, 0b10000, 0b10000]),
    ('G', [0b01110, 0b10001, 0b10000, 0b10111, 0b10001, 0b10001, 0b01111]),
    ('H', [0b10001, 0b10001, 0b10001, 0b11111, 0b10001, 0b10001, 0b10001]),
    ('I', [0b01110, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110]),
    ('J', [0b00111, 0b00010, 0b00010, 0b00010, 0b00010, 0b10010, 0b01100]),
    ('K', [0b10001, 0b10010, 0b10100, 0b11000, 0b10100, 0b10010, 0b10001]),
    ('L', [0b10000, 0b10000, 0b10000, 0b10000, 0b10000, 0b10000, 0b11111]),
    ('M', [0b10001, 0b11011, 0b10101, 0b10101, 0b10001, 0b10001, 0b10001]),
    ('N', [0b10001, 0b10001, 0b11001, 0b10101, 0b10011, 0b10001, 0b10001]),
    ('O', [0b01110, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01110]),
    ('P', [0b11110, 0b10001, 0b10001, 0b11110, 0b10000, 0b10000, 0b10000]),
    ('Q', [0b01110, 0b10001, 0b10001, 0b10001, 0b10101, 0b10010, 0b01101]),
    ('R', [0b11110, 0b10001, 0b10001, 0b11110, 0b10100, 0b10010, 0b10001]),
    ('S', [0b01111, 0b10000, 0b10000, 0b01110, 0b00001, 0b00001, 0b11110]),
    ('T', [0b11111, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100, 0b00100]),
    ('U', [0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01110]),
    ('V', [0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b01010, 0b00100]),
    ('W', [0b10001, 0b10001, 0b10001, 0b10101, 0b10101, 0b10101, 0b01010]),
    ('X', [0b10001, 0b10001, 0b01010, 0b00100, 0b01010, 0b10001, 0b10001]),
    ('Y', [0b10001, 0b10001, 0b10001, 0b01010, 0b00100, 0b00100, 0b00100]),
    ('Z', [0b11111, 0b00001, 0b00010, 0b00100, 0b01000, 0b10000, 0b11111]),
    ('0', [0b01110, 0b10001, 0b10011, 0b10101, 0b11001, 0b10001, 0b01110]),
    ('1', [0b00100, 0b01100, 0b00100, 0b00100, 0b00100, 0b00100, 0b01110]),
    ('2', [0b01110, 0b10001, 0b00001, 0b00010, 0b00100, 0b01000, 0b11111]),
    ('3', [0b11111, 0b00010, 0b00100, 0b00010, 0b00001, 0b10001, 0b01110]),
    ('4', [0b00010, 0b00110, 0b01010, 0b10010, 0b11111, 0b00010, 0b00010]),
    ('5', [0b11111, 0b10000, 0b11110, 0b00001, 0b00001, 0b10001, 0b01110]),
    ('6', [0b00110, 0b01000, 0b10000, 0b11110, 0b10001, 0b10001, 0b01110]),
    ('7', [0b11111, 0b00001, 0b00010, 0b00100, 0b01000, 0b01000, 0b01000]),
    ('8', [0b01110, 0b10001, 0b10001, 0b01110, 0b10001, 0b10001, 0b01110]),
    ('9', [0b01110, 0b10001, 0b10001, 0b01111, 0b00001, 0b00010, 0b01100]),
];

#[cfg(test)]
mod tests {
    use super::*;

    fn t(spec: &str) -> Target {
        builtin_target(spec).unwrap_or_else(|e| panic!("{e}"))
    }

    fn lit_indices(t: &Target) -> Vec<usize> {
        t.values
            .iter()
            .enumerate()
            .filter(|(_, v)| **v != 0.0)
            .map(|(i, _)| i)
            .collect()
    }

    #[test]
    fn uniform_and_size() {
        let w = t("white");
        assert_eq!((w.width, w.height, w.values.len()), (64, 64, 64 * 64));
        assert!(w.values.iter().all(|&v| v == 1.0));
        assert!(t("black@2").values.iter().all(|&v| v == 0.0));
        assert!(t("gray:0.25@3").values.iter().all(|&v| v == 0.25));
    }

    #[test]
    fn point_has_one_pixel() {
        assert_eq!(lit_indices(&t("point")), [32 * 64 + 32]);
        assert_eq!(lit_indices(&t("point:3,5@16")), [5 * 16 + 3]);
        assert_eq!(lit_indices(&t("point@5")), [2 * 5 + 2]);
    }

    #[test]
    fn checker_and_bars() {
        let c = t("checker:8");
        assert_eq!(lit_indices(&c).len(), 64 * 64 / 2);
        assert_eq!(
            (
                c.values[0],
                c.values[7],
                c.values[8],
                c.values[8 * 64],
                c.values[8 * 64 + 8]
            ),
            (1.0, 1.0, 0.0, 0.0, 1.0)
        );
        let h = t("hbars:3@12");
        let rows: Vec<f32> = (0..12).map(|y| h.values[y * 12 + 5]).collect();
        assert_eq!(
            rows,
            [1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
        );
        let v = t("vbars:2@8");
        assert_eq!(
            &v.values[8 * 3..8 * 4],
            &[1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0]
        );
    }

    #[test]
    fn letter_f_shape() {
        let f = t("letter:F");
        let n = f.width;
        let lit: Vec<(usize, usize)> = lit_indices(&f).iter().map(|i| (i % n, i / n)).collect();
        let (x0, x1) = (
            lit.iter().map(|p| p.0).min().unwrap(),
            lit.iter().map(|p| p.0).max().unwrap(),
        );
        let (y0, y1) = (
            lit.iter().map(|p| p.1).min().unwrap(),
            lit.iter().map(|p| p.1).max().unwrap(),
        );
        // Scale 3 (64 / 21) with the 15x21 glyph centred.
        assert_eq!((x0, x1, y0, y1), (24, 38, 21, 41));
        // Top stroke fully lit across the whole bounding box.
        assert!((x0..=x1).all(|x| f.values[y0 * n + x] == 1.0));
        // Bottom-right region (below the middle bar, right of the stem) dark.
        assert!((y0 + 12..=y1).all(|y| (x0 + 3..=x1).all(|x| f.values[y * n + x] == 0.0)));
        // Not left-right symmetric.
        let mirrored = (0..n * n).all(|i| f.values[i] == f.values[(i / n) * n + (n - 1 - i % n)]);
        assert!(!mirrored);
    }

    #[test]
    fn text_fits_and_centres() {
        let h = t("text:HI@32");
        // "HI" is 11x7 font pixels: scale 2 -> 22x14 at offset (5, 9).
        let lit = lit_indices(&h);
        assert_eq!(lit.iter().map(|i| i % 32).min(), Some(5));
        assert_eq!(lit.iter().map(|i| i / 32).min(), Some(9));
        // The rightmost lit column of "I" (0b01110) is its font column 3.
        assert_eq!(lit.iter().map(|i| i % 32).max(), Some(5 + (6 + 3) * 2 + 1));
        assert_eq!(t("text:hi@32"), h);
        assert!(builtin_target("text:ABCDEF@16").is_err());
    }

    #[test]
    fn siemens_star_is_half_lit() {
        let s = t("siemens:8");
        let c = 32.0;
        let (mut inside, mut lit) = (0, 0);
        for y in 0..64 {
            for x in 0..64 {
                let (dx, dy) = (x as f64 + 0.5 - c, y as f64 + 0.5 - c);
                let v = s.values[y * 64 + x];
                if dx.hypot(dy) <= 31.0 {
                    inside += 1;
                    lit += (v == 1.0) as usize;
                } else {
                    assert_eq!(v, 0.0);
                }
            }
        }
        let fraction = lit as f64 / inside as f64;
        assert!((fraction - 0.5).abs() < 0.02, "{fraction}");
        // Just above the centre on the right: angle ~0, sector 0, lit.
        assert_eq!(s.values[31 * 64 + 60], 1.0);
        // Just below the centre on the right: angle ~2pi, sector 15, dark.
        assert_eq!(s.values[32 * 64 + 60], 0.0);
    }

    #[test]
    fn gradient_endpoints() {
        let g = t("gradient@5");
        assert_eq!(&g.values[..5], &[0.0, 0.25, 0.5, 0.75, 1.0]);
        assert_eq!(&g.values[20..], &[0.0, 0.25, 0.5, 0.75, 1.0]);
    }

    #[test]
    fn smooth_is_deterministic_and_bounded() {
        let a = t("smooth:1");
        assert_eq!(a, t("smooth:1"));
        assert_ne!(a, t("smooth:2"));
        let (lo, hi) = a
            .values
            .iter()
            .fold((1.0f32, 0.0f32), |(l, h), &v| (l.min(v), h.max(v)));
        assert_eq!((lo, hi), (0.05, 0.95));
        // Smooth: neighbouring pixels differ little.
        let max_step = a
            .values
            .chunks(64)
            .flat_map(|row| row.windows(2))
            .map(|w| (w[0] - w[1]).abs())
            .fold(0.0, f32::max);
        assert!(max_step < 0.1, "{max_step}");
        // Cross-platform golden checksum of the exact bits.
        let hash = a.values.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, v| {
            (h ^ u64::from(v.to_bits())).wrapping_mul(0x100_0000_01b3)
        });
        assert_eq!(hash, GOLDEN_SMOOTH_1);
    }

    const GOLDEN_SMOOTH_1: u64 = 17_096_124_414_242_874_122;

    #[test]
    fn deterministic_math_matches_std() {
        for i in -400..=20 {
            let x = i as f64 * 0.731;
            assert!((det_exp(x) / x.exp() - 1.0).abs() < 1e-13, "exp {x}");
        }
        for i in -200..=200 {
            let x = i as f64 * 0.173;
            assert!((det_cos(x) - x.cos()).abs() < 1e-13, "cos {x}");
        }
    }

    #[test]
    fn invalid_specs() {
        for spec in [
            "letter:ä",
            "letter:AB",
            "letter:",
            "checker:0",
            "foo",
            "point:99,0@64",
            "point:1@8",
            "white:1",
            "checker",
            "gray:1.5",
            "gray:x",
            "siemens:0",
            "smooth:-1",
            "white@1",
            "white@4097",
            "white@",
            "text:",
            "text:A-B",
        ] {
            let err = builtin_target(spec).expect_err(spec);
            assert!(!err.contains('\n') && err.contains("siemens:N"), "{err}");
        }
        assert!(
            builtin_target("foo")
                .unwrap_err()
                .contains("unknown target name")
        );
        assert_eq!(builtin_names().len(), 14);
    }

    #[test]
    fn shapes_have_the_expected_area_and_symmetry() {
        let n = 256;
        let frac =
            |t: &Target| t.values.iter().filter(|&&v| v > 0.5).count() as f64 / (n * n) as f64;
        let disk = builtin_target("shape:disk@256").unwrap();
        // π·0.75²/4 of the square [-1, 1]².
        assert!((frac(&disk) - PI * 0.75 * 0.75 / 4.0).abs() < 0.005);
        let ring = builtin_target("shape:ring@256").unwrap();
        assert!((frac(&ring) - PI * (0.64 - 0.2025) / 4.0).abs() < 0.005);
        let tri = builtin_target("shape:triangle@256").unwrap();
        assert!((frac(&tri) - 0.5 * 1.6 * 1.38 / 4.0).abs() < 0.005);
        for name in ["star", "heart", "cross", "triangle"] {
            let t = builtin_target(&format!("shape:{name}@{n}")).unwrap();
            // Left-right mirror symmetry; the centre region is lit.
            for r in 0..n {
                for c in 0..n {
                    assert_eq!(t.values[r * n + c], t.values[r * n + n - 1 - c], "{name}");
                }
            }
            assert_eq!(t.values[(n / 2) * n + n / 2], 1.0, "{name}");
        }
        assert!(
            builtin_target("shape:blob")
                .unwrap_err()
                .contains("not one of")
        );
    }
}
