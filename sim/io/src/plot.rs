//! Line plots as SVG (text, scalable) and PNG (RGB, labels in the embedded 5×7 font), with
//! linear or logarithmic axes. Enough for benchmark curves and design sweeps without a plotting
//! dependency; both outputs are deterministic.

use std::fmt::Write as _;

/// One named curve.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend name.
    pub name: String,
    /// (x, y) points, drawn in order; non-finite points (and non-positive ones on a log axis)
    /// break the line.
    pub points: Vec<(f64, f64)>,
}

/// A line plot.
#[derive(Clone, Debug)]
pub struct LinePlot {
    /// Title.
    pub title: String,
    /// X axis label (with units).
    pub x_label: String,
    /// Y axis label (with units).
    pub y_label: String,
    /// Logarithmic x axis.
    pub log_x: bool,
    /// Logarithmic y axis.
    pub log_y: bool,
    /// Curves.
    pub series: Vec<Series>,
    /// Optional horizontal reference line (value, label).
    pub h_line: Option<(f64, String)>,
}

const W: usize = 800;
const H: usize = 520;
const LEFT: f64 = 90.0;
const RIGHT: f64 = 200.0;
const TOP: f64 = 40.0;
const BOTTOM: f64 = 60.0;
/// Dash pattern (on, off, … in px; empty = solid) of series i: with the colour, the marker
/// and a line width that shrinks with i (earlier curves drawn wider, underneath), curves that
/// coincide stay distinguishable.
const DASHES: [&[f64]; 4] = [&[], &[10.0, 5.0], &[3.0, 4.0], &[10.0, 4.0, 3.0, 4.0]];
/// PNG label font: pixels per character at scale 1 (5 + 1 spacing).
const CHAR_PX: f64 = 6.0;
/// Characters of a legend line that fit the right margin at scale 1.
const LEGEND_CHARS: usize = ((RIGHT - 40.0) / CHAR_PX) as usize;

/// Marker shapes, by series index.
#[derive(Clone, Copy)]
enum Marker {
    Disc,
    Square,
    Triangle,
    Diamond,
}

/// A series' marker at (`px`, `py`) in colour `(r, g, b)`.
fn svg_marker(s: &mut String, marker: Marker, (r, g, b): (u8, u8, u8), px: f64, py: f64) {
    let fill = format!("rgb({r},{g},{b})");
    let _ = match marker {
        Marker::Disc => write!(
            s,
            r#"<circle cx="{px:.1}" cy="{py:.1}" r="3.5" fill="{fill}"/>"#
        ),
        Marker::Square => write!(
            s,
            r#"<rect x="{:.1}" y="{:.1}" width="7" height="7" fill="{fill}"/>"#,
            px - 3.5,
            py - 3.5
        ),
        Marker::Triangle => write!(
            s,
            r#"<polygon points="{:.1},{:.1} {:.1},{:.1} {:.1},{:.1}" fill="{fill}"/>"#,
            px,
            py - 4.5,
            px - 4.0,
            py + 3.5,
            px + 4.0,
            py + 3.5
        ),
        Marker::Diamond => write!(
            s,
            r#"<polygon points="{:.1},{:.1} {:.1},{:.1} {:.1},{:.1} {:.1},{:.1}" fill="{fill}"/>"#,
            px,
            py - 4.5,
            px + 4.5,
            py,
            px,
            py + 4.5,
            px - 4.5,
            py
        ),
    };
}

fn series_style(i: usize, n: usize) -> ((u8, u8, u8), &'static [f64], Marker, f64) {
    let marker = [
        Marker::Disc,
        Marker::Square,
        Marker::Triangle,
        Marker::Diamond,
    ][i % 4];
    let width = 2.0 + 2.0 * (n.saturating_sub(1 + i)).min(3) as f64;
    (
        COLOURS[i % COLOURS.len()],
        DASHES[i % DASHES.len()],
        marker,
        width,
    )
}

/// Splits `text` into lines of at most `max` characters, at spaces where possible.
fn wrap(text: &str, max: usize) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    let mut cur = String::new();
    for word in text.split(' ') {
        let mut word = word.to_string();
        while word.chars().count() > max {
            if !cur.is_empty() {
                lines.push(std::mem::take(&mut cur));
            }
            let head: String = word.chars().take(max).collect();
            word = word.chars().skip(max).collect();
            lines.push(head);
        }
        if cur.is_empty() {
            cur = word;
        } else if cur.chars().count() + 1 + word.chars().count() <= max {
            cur.push(' ');
            cur.push_str(&word);
        } else {
            lines.push(std::mem::replace(&mut cur, word));
        }
    }
    if !cur.is_empty() || lines.is_empty() {
        lines.push(cur);
    }
    lines
}

const COLOURS: [(u8, u8, u8); 6] = [
    (31, 119, 180),
    (214, 39, 40),
    (44, 160, 44),
    (148, 103, 189),
    (255, 127, 14),
    (23, 190, 207),
];

struct Axis {
    lo: f64,
    hi: f64,
    log: bool,
}

impl Axis {
    fn new(values: impl Iterator<Item = f64>, log: bool) -> Axis {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in values.filter(|v| v.is_finite() && (!log || *v > 0.0)) {
            let t = if log { v.log10() } else { v };
            lo = lo.min(t);
            hi = hi.max(t);
        }
        if !lo.is_finite() {
            (lo, hi) = (0.0, 1.0);
        }
        if hi - lo < 1e-12 {
            lo -= 0.5;
            hi += 0.5;
        }
        if log {
            lo = lo.floor();
            hi = hi.ceil();
        } else {
            let pad = 0.05 * (hi - lo);
            lo -= pad;
            hi += pad;
        }
        Axis { lo, hi, log }
    }

    fn t(&self, v: f64) -> Option<f64> {
        if !v.is_finite() || (self.log && v <= 0.0) {
            return None;
        }
        let t = if self.log { v.log10() } else { v };
        Some((t - self.lo) / (self.hi - self.lo))
    }

    /// Tick values (data units).
    fn ticks(&self) -> Vec<f64> {
        if self.log {
            (self.lo as i32..=self.hi as i32)
                .map(|e| 10f64.powi(e))
                .collect()
        } else {
            let span = self.hi - self.lo;
            let raw = span / 6.0;
            let mag = 10f64.powf(raw.log10().floor());
            let step = [1.0, 2.0, 5.0, 10.0]
                .iter()
                .map(|m| m * mag)
                .find(|s| *s >= raw)
                .unwrap_or(10.0 * mag);
            let mut v = (self.lo / step).ceil() * step;
            let mut out = Vec::new();
            while v <= self.hi + 1e-9 * step && out.len() < 100 {
                out.push(if v.abs() < 1e-12 * step { 0.0 } else { v });
                v += step;
            }
            out
        }
    }
}

fn fmt_tick(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{v:.0e}")
    } else if (v - v.round()).abs() < 1e-9 {
        format!("{v:.0}")
    } else if a >= 1.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.3}").trim_end_matches('0').to_string()
    }
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

impl LinePlot {
    fn axes(&self) -> (Axis, Axis) {
        let xs = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.0));
        let mut ys: Vec<f64> = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.1))
            .collect();
        if let Some((v, _)) = &self.h_line {
            ys.push(*v);
        }
        (
            Axis::new(xs, self.log_x),
            Axis::new(ys.into_iter(), self.log_y),
        )
    }

    fn to_px(ax: &Axis, ay: &Axis, p: (f64, f64)) -> Option<(f64, f64)> {
        let (tx, ty) = (ax.t(p.0)?, ay.t(p.1)?);
        let pw = W as f64 - LEFT - RIGHT;
        let ph = H as f64 - TOP - BOTTOM;
        Some((LEFT + tx * pw, TOP + (1.0 - ty) * ph))
    }

    /// The plot as an SVG document: title, grid, frame with labels and reference line, then
    /// each series with its legend entry.
    pub fn to_svg(&self) -> String {
        let (ax, ay) = self.axes();
        let mut s = String::new();
        // Taller than the plot when the legend needs it: a legend is never cut.
        let h = self.svg_height();
        let _ = write!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{h}" viewBox="0 0 {W} {h}" font-family="sans-serif" font-size="13">"#
        );
        let _ = write!(s, r#"<rect width="{W}" height="{h}" fill="white"/>"#);
        self.svg_title(&mut s);
        Self::svg_grid(&mut s, &ax, &ay);
        self.svg_frame(&mut s, &ax, &ay);
        let n = self.series.len();
        let mut ly = TOP + 10.0;
        for (i, ser) in self.series.iter().enumerate() {
            Self::svg_series(&mut s, &ax, &ay, ser, series_style(i, n), ly);
            ly += 20.0;
        }
        s.push_str("</svg>\n");
        s
    }

    /// The title: 16 px when it fits (about 0.55 em per character), else 12 px, wrapped.
    fn svg_title(&self, s: &mut String) {
        let fit16 = ((W as f64 - 20.0) / (0.55 * 16.0)) as usize;
        if self.title.chars().count() <= fit16 {
            let _ = write!(
                s,
                r#"<text x="{}" y="22" text-anchor="middle" font-size="16">{}</text>"#,
                W as f64 / 2.0,
                esc(&self.title)
            );
        } else {
            let fit12 = ((W as f64 - 20.0) / (0.55 * 12.0)) as usize;
            for (k, line) in wrap(&self.title, fit12).iter().take(2).enumerate() {
                let _ = write!(
                    s,
                    r#"<text x="{}" y="{}" text-anchor="middle" font-size="12">{}</text>"#,
                    W as f64 / 2.0,
                    14.0 + 13.0 * k as f64,
                    esc(line)
                );
            }
        }
    }

    /// The grid lines and tick labels of both axes.
    fn svg_grid(s: &mut String, ax: &Axis, ay: &Axis) {
        let (x0, x1, y0, y1) = (LEFT, W as f64 - RIGHT, TOP, H as f64 - BOTTOM);
        for v in ax.ticks() {
            if let Some((px, _)) =
                Self::to_px(ax, ay, (v, if ay.log { 10f64.powf(ay.lo) } else { ay.lo }))
            {
                let _ = write!(
                    s,
                    r##"<line x1="{px:.1}" y1="{y0}" x2="{px:.1}" y2="{y1}" stroke="#ddd"/>"##
                );
                let _ = write!(
                    s,
                    r#"<text x="{px:.1}" y="{}" text-anchor="middle">{}</text>"#,
                    y1 + 18.0,
                    fmt_tick(v)
                );
            }
        }
        for v in ay.ticks() {
            if let Some((_, py)) =
                Self::to_px(ax, ay, (if ax.log { 10f64.powf(ax.lo) } else { ax.lo }, v))
            {
                let _ = write!(
                    s,
                    r##"<line x1="{x0}" y1="{py:.1}" x2="{x1}" y2="{py:.1}" stroke="#ddd"/>"##
                );
                let _ = write!(
                    s,
                    r#"<text x="{}" y="{:.1}" text-anchor="end">{}</text>"#,
                    x0 - 6.0,
                    py + 4.0,
                    fmt_tick(v)
                );
            }
        }
    }

    /// The frame, the axis labels and the horizontal reference line with its label.
    fn svg_frame(&self, s: &mut String, ax: &Axis, ay: &Axis) {
        let (x0, x1, y0, y1) = (LEFT, W as f64 - RIGHT, TOP, H as f64 - BOTTOM);
        let _ = write!(
            s,
            r#"<rect x="{x0}" y="{y0}" width="{}" height="{}" fill="none" stroke="black"/>"#,
            x1 - x0,
            y1 - y0
        );
        let _ = write!(
            s,
            r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
            (x0 + x1) / 2.0,
            H as f64 - 18.0,
            esc(&self.x_label)
        );
        let _ = write!(
            s,
            r#"<text x="20" y="{}" text-anchor="middle" transform="rotate(-90 20 {})">{}</text>"#,
            (y0 + y1) / 2.0,
            (y0 + y1) / 2.0,
            esc(&self.y_label)
        );
        if let Some((v, label)) = &self.h_line
            && let Some((_, py)) =
                Self::to_px(ax, ay, (if ax.log { 10f64.powf(ax.lo) } else { ax.lo }, *v))
        {
            let _ = write!(
                s,
                r##"<line x1="{x0}" y1="{py:.1}" x2="{x1}" y2="{py:.1}" stroke="#888" stroke-dasharray="6 4"/>"##
            );
            let _ = write!(
                s,
                r##"<text x="{}" y="{:.1}" fill="#555">{}</text>"##,
                x1 + 6.0,
                py + 4.0,
                esc(label)
            );
        }
    }

    /// One series (`style` from [`series_style`]): its path and markers, and its legend entry
    /// at height `ly`.
    fn svg_series(
        s: &mut String,
        ax: &Axis,
        ay: &Axis,
        ser: &Series,
        style: ((u8, u8, u8), &[f64], Marker, f64),
        ly: f64,
    ) {
        let (x1, (r, g, b)) = (W as f64 - RIGHT, style.0);
        let (dash, marker, width) = (style.1, style.2, style.3);
        let dash_attr = if dash.is_empty() {
            String::new()
        } else {
            let d: Vec<String> = dash.iter().map(|v| v.to_string()).collect();
            format!(r#" stroke-dasharray="{}""#, d.join(" "))
        };
        let mark = |s: &mut String, px: f64, py: f64| svg_marker(s, marker, (r, g, b), px, py);
        let mut d = String::new();
        let mut pen_up = true;
        let mut marks = String::new();
        for &p in &ser.points {
            match Self::to_px(ax, ay, p) {
                Some((px, py)) => {
                    let _ = write!(d, "{}{px:.1},{py:.1} ", if pen_up { "M" } else { "L" });
                    pen_up = false;
                    mark(&mut marks, px, py);
                }
                None => pen_up = true,
            }
        }
        let _ = write!(
            s,
            r#"<path d="{}" fill="none" stroke="rgb({r},{g},{b})" stroke-width="{width}"{dash_attr}/>"#,
            d.trim_end()
        );
        s.push_str(&marks);
        let _ = write!(
            s,
            r#"<line x1="{}" y1="{ly}" x2="{}" y2="{ly}" stroke="rgb({r},{g},{b})" stroke-width="3"{dash_attr}/>"#,
            x1 + 8.0,
            x1 + 32.0
        );
        mark(s, x1 + 20.0, ly);
        // A name longer than the margin is squeezed to fit it (one element, still
        // searchable text), never clipped.
        let fit = if ser.name.chars().count() > LEGEND_CHARS {
            format!(
                r#" textLength="{}" lengthAdjust="spacingAndGlyphs""#,
                RIGHT - 44.0
            )
        } else {
            String::new()
        };
        let _ = write!(
            s,
            r#"<text x="{}" y="{}" font-size="11"{fit}>{}</text>"#,
            x1 + 36.0,
            ly + 4.0,
            esc(&ser.name)
        );
    }
    /// The plot as an 8-bit RGB PNG (labels drawn in the 5×7 font, upper case).
    pub fn to_png(&self) -> Result<Vec<u8>, String> {
        self.canvas().encode()
    }

    /// The SVG's height: the plot's, or more when the legend (20 px an entry) needs it.
    fn svg_height(&self) -> usize {
        H.max((TOP + 10.0 + 20.0 * self.series.len() as f64) as usize)
    }

    /// The PNG's height: the plot's, or more when the legend needs it (never cut).
    fn png_height(&self) -> usize {
        let legend: f64 = self
            .series
            .iter()
            .map(|s| 9.0 + 11.0 * wrap(&s.name, LEGEND_CHARS).len() as f64)
            .sum();
        H.max((TOP + 10.0 + legend) as usize)
    }

    /// The plot drawn (the PNG's pixels).
    fn canvas(&self) -> Canvas {
        let (ax, ay) = self.axes();
        let mut c = Canvas::new(W, self.png_height());
        let (x0, x1, y0, y1) = (LEFT, W as f64 - RIGHT, TOP, H as f64 - BOTTOM);
        let grey = (221, 221, 221);
        for v in ax.ticks() {
            if let Some((px, _)) = Self::to_px(
                &ax,
                &ay,
                (v, if ay.log { 10f64.powf(ay.lo) } else { ay.lo }),
            ) {
                c.line((px, y0), (px, y1), grey, 1.0);
                c.text(&fmt_tick(v), px, y1 + 10.0, 1, Align::Centre, (0, 0, 0));
            }
        }
        for v in ay.ticks() {
            if let Some((_, py)) = Self::to_px(
                &ax,
                &ay,
                (if ax.log { 10f64.powf(ax.lo) } else { ax.lo }, v),
            ) {
                c.line((x0, py), (x1, py), grey, 1.0);
                c.text(&fmt_tick(v), x0 - 6.0, py - 4.0, 1, Align::Right, (0, 0, 0));
            }
        }
        for ((a, b), (cc, d)) in [
            ((x0, y0), (x1, y0)),
            ((x1, y0), (x1, y1)),
            ((x1, y1), (x0, y1)),
            ((x0, y1), (x0, y0)),
        ] {
            c.line((a, b), (cc, d), (0, 0, 0), 1.0);
        }
        c.title(&self.title);
        c.text(
            &self.x_label,
            (x0 + x1) / 2.0,
            H as f64 - 28.0,
            1,
            Align::Centre,
            (0, 0, 0),
        );
        c.text(&self.y_label, 6.0, 26.0, 1, Align::Left, (0, 0, 0));
        if let Some((v, label)) = &self.h_line
            && let Some((_, py)) = Self::to_px(
                &ax,
                &ay,
                (if ax.log { 10f64.powf(ax.lo) } else { ax.lo }, *v),
            )
        {
            c.line((x0, py), (x1, py), (136, 136, 136), 1.0);
            c.text(label, x1 + 6.0, py - 4.0, 1, Align::Left, (85, 85, 85));
        }
        let n = self.series.len();
        let mut ly = y0 + 10.0;
        for (i, ser) in self.series.iter().enumerate() {
            let (col, dash, marker, width) = series_style(i, n);
            let mut last: Option<(f64, f64)> = None;
            let mut phase = 0.0;
            for &p in &ser.points {
                match Self::to_px(&ax, &ay, p) {
                    Some(q) => {
                        if let Some(l) = last {
                            phase = c.dashed_line(l, q, col, width, dash, phase);
                        }
                        c.marker(q, marker, col);
                        last = Some(q);
                    }
                    None => last = None,
                }
            }
            c.dashed_line((x1 + 8.0, ly), (x1 + 32.0, ly), col, 3.0, dash, 0.0);
            c.marker((x1 + 20.0, ly), marker, col);
            let lines = wrap(&ser.name, LEGEND_CHARS);
            for (k, line) in lines.iter().enumerate() {
                let y = ly - 4.0 + 11.0 * k as f64;
                c.text(line, x1 + 36.0, y, 1, Align::Left, (0, 0, 0));
            }
            ly += 9.0 + 11.0 * lines.len() as f64;
        }
        c
    }
}

/// Small multiples: `panels` side by side, `cols` to a row, under one title; each panel is a
/// whole [`LinePlot`] (its own axes and legend). For sweeps over three or more keys, where one
/// plot would hold too many curves to tell apart.
pub fn grid_png(title: &str, panels: &[LinePlot], cols: usize) -> Result<Vec<u8>, String> {
    let cols = cols.clamp(1, panels.len().max(1));
    let canvases: Vec<Canvas> = panels.iter().map(LinePlot::canvas).collect();
    let ph = canvases.iter().map(|c| c.h).max().unwrap_or(H);
    let rows = panels.len().div_ceil(cols).max(1);
    let head = 34;
    let mut c = Canvas::new(cols * W, head + rows * ph);
    c.text(
        title,
        (cols * W) as f64 / 2.0,
        8.0,
        2,
        Align::Centre,
        (0, 0, 0),
    );
    for (k, p) in canvases.iter().enumerate() {
        let (x0, y0) = ((k % cols) * W, head + (k / cols) * ph);
        for y in 0..p.h {
            let dst = (y0 + y) * c.w + x0;
            c.px[dst..dst + p.w].copy_from_slice(&p.px[y * p.w..(y + 1) * p.w]);
        }
    }
    c.encode()
}

/// The SVG of [`grid_png`]: each panel's own SVG nested at its place.
pub fn grid_svg(title: &str, panels: &[LinePlot], cols: usize) -> String {
    let cols = cols.clamp(1, panels.len().max(1));
    let svgs: Vec<String> = panels.iter().map(LinePlot::to_svg).collect();
    let ph = panels.iter().map(LinePlot::svg_height).max().unwrap_or(H);
    let rows = panels.len().div_ceil(cols).max(1);
    let (w, h) = (cols * W, 34 + rows * ph);
    let mut s = String::new();
    let _ = write!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="13"><rect width="{w}" height="{h}" fill="white"/><text x="{}" y="24" text-anchor="middle" font-size="18">{}</text>"#,
        w as f64 / 2.0,
        esc(title)
    );
    for (k, p) in svgs.iter().enumerate() {
        let (x0, y0) = ((k % cols) * W, 34 + (k / cols) * ph);
        s.push_str(
            &p.trim_end()
                .replacen("<svg ", &format!(r#"<svg x="{x0}" y="{y0}" "#), 1),
        );
    }
    s.push_str("</svg>\n");
    s
}

/// One bar of a [`BarChart`].
#[derive(Clone, Debug)]
pub struct Bar {
    /// Label left of the bar.
    pub label: String,
    /// Length (data units, ≥ 0 drawn rightwards, < 0 leftwards).
    pub value: f64,
    /// Text written after the bar's end (e.g. the value and a sign).
    pub note: String,
}

/// A horizontal bar chart: one labelled bar per item, top to bottom in the given order, each
/// with its note at its end; the height grows with the number of bars so labels never
/// overlap. PNG only (the tolerance rankings).
#[derive(Clone, Debug)]
pub struct BarChart {
    /// Title.
    pub title: String,
    /// Axis label under the bars (with units).
    pub x_label: String,
    /// Bars.
    pub bars: Vec<Bar>,
}

/// Bar chart layout: label column, room for the notes, row height (px).
const BAR_LABEL: f64 = 230.0;
const BAR_NOTE: f64 = 130.0;
const BAR_ROW: f64 = 26.0;

impl BarChart {
    /// The chart's width and height, pixels.
    pub fn size(&self) -> (usize, usize) {
        let rows = self.bars.len().max(1) as f64;
        (W, (TOP + 10.0 + rows * BAR_ROW + 45.0) as usize)
    }

    /// The x pixel of value `v`, and the axis (lo, hi) in data units.
    fn scale(&self) -> (f64, f64) {
        let finite = self.bars.iter().map(|b| b.value).filter(|v| v.is_finite());
        let lo = finite.clone().fold(0.0, f64::min);
        let hi = finite.fold(0.0, f64::max);
        if hi - lo > 0.0 { (lo, hi) } else { (0.0, 1.0) }
    }

    /// The chart as PNG bytes.
    pub fn to_png(&self) -> Result<Vec<u8>, String> {
        let (w, h) = self.size();
        let mut c = Canvas::new(w, h);
        let (x0, x1) = (BAR_LABEL, w as f64 - BAR_NOTE);
        let y0 = TOP + 10.0;
        let y1 = y0 + self.bars.len().max(1) as f64 * BAR_ROW;
        let (lo, hi) = self.scale();
        let px = |v: f64| x0 + (v - lo) / (hi - lo) * (x1 - x0);
        let axis = Axis { lo, hi, log: false };
        for v in axis.ticks() {
            let x = px(v);
            c.line((x, y0), (x, y1), (221, 221, 221), 1.0);
            c.text(&fmt_tick(v), x, y1 + 8.0, 1, Align::Centre, (0, 0, 0));
        }
        c.title(&self.title);
        c.text(
            &self.x_label,
            (x0 + x1) / 2.0,
            y1 + 24.0,
            1,
            Align::Centre,
            (0, 0, 0),
        );
        let label_chars = ((BAR_LABEL - 14.0) / CHAR_PX) as usize;
        let note_chars = ((BAR_NOTE - 8.0) / CHAR_PX) as usize;
        for (i, b) in self.bars.iter().enumerate() {
            let top = y0 + i as f64 * BAR_ROW;
            let (a, z) = (px(0.0), px(if b.value.is_finite() { b.value } else { 0.0 }));
            let col = COLOURS[i % COLOURS.len()];
            for y in (top + 5.0) as i64..(top + BAR_ROW - 5.0) as i64 {
                for x in a.min(z).round() as i64..z.max(a).round() as i64 {
                    c.blend(x, y, col, 1.0);
                }
            }
            let mid = top + BAR_ROW / 2.0 - 4.0;
            let label: String = b.label.chars().take(label_chars).collect();
            c.text(&label, x0 - 8.0, mid, 1, Align::Right, (0, 0, 0));
            let note: String = b.note.chars().take(note_chars).collect();
            c.text(&note, z.max(a) + 6.0, mid, 1, Align::Left, (0, 0, 0));
        }
        c.line((px(0.0), y0), (px(0.0), y1), (0, 0, 0), 1.0);
        c.encode()
    }
}

enum Align {
    Left,
    Centre,
    Right,
}

struct Canvas {
    w: usize,
    h: usize,
    px: Vec<[f64; 3]>,
}

impl Canvas {
    fn new(w: usize, h: usize) -> Canvas {
        Canvas {
            w,
            h,
            px: vec![[1.0; 3]; w * h],
        }
    }

    fn blend(&mut self, x: i64, y: i64, col: (u8, u8, u8), a: f64) {
        if x < 0 || y < 0 || x >= self.w as i64 || y >= self.h as i64 || a <= 0.0 {
            return;
        }
        let p = &mut self.px[y as usize * self.w + x as usize];
        let c = [col.0, col.1, col.2].map(|v| f64::from(v) / 255.0);
        for k in 0..3 {
            p[k] = p[k] * (1.0 - a.min(1.0)) + c[k] * a.min(1.0);
        }
    }

    /// Anti-aliased thick line by distance to the segment.
    fn line(&mut self, a: (f64, f64), b: (f64, f64), col: (u8, u8, u8), width: f64) {
        let r = 0.5 * width;
        let (minx, maxx) = (a.0.min(b.0) - r - 1.0, a.0.max(b.0) + r + 1.0);
        let (miny, maxy) = (a.1.min(b.1) - r - 1.0, a.1.max(b.1) + r + 1.0);
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let len2 = dx * dx + dy * dy;
        for y in miny.floor() as i64..=maxy.ceil() as i64 {
            for x in minx.floor() as i64..=maxx.ceil() as i64 {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let t = if len2 > 0.0 {
                    (((px - a.0) * dx + (py - a.1) * dy) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let (qx, qy) = (a.0 + t * dx - px, a.1 + t * dy - py);
                let d = (qx * qx + qy * qy).sqrt();
                self.blend(x, y, col, (r + 0.5 - d).clamp(0.0, 1.0));
            }
        }
    }

    /// A line with dash pattern `dash` (on, off, … px; empty = solid) starting `phase` px into
    /// the pattern; returns the phase at the end, so a polyline's dashes run on.
    fn dashed_line(
        &mut self,
        a: (f64, f64),
        b: (f64, f64),
        col: (u8, u8, u8),
        width: f64,
        dash: &[f64],
        phase: f64,
    ) -> f64 {
        let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt();
        let period: f64 = dash.iter().sum();
        if dash.is_empty() || period <= 0.0 || len == 0.0 {
            self.line(a, b, col, width);
            return phase;
        }
        let at = |t: f64| (a.0 + (b.0 - a.0) * t / len, a.1 + (b.1 - a.1) * t / len);
        let mut t = 0.0;
        let mut ph = phase % period;
        while t < len {
            // Which dash element the phase is in, and how much of it is left.
            let (mut k, mut acc) = (0, 0.0);
            while acc + dash[k] <= ph {
                acc += dash[k];
                k = (k + 1) % dash.len();
            }
            let step = (acc + dash[k] - ph).min(len - t);
            if k % 2 == 0 {
                self.line(at(t), at(t + step), col, width);
            }
            t += step;
            ph = (ph + step) % period;
        }
        ph
    }

    /// A filled marker of about 8 px at `c`.
    fn marker(&mut self, c: (f64, f64), m: Marker, col: (u8, u8, u8)) {
        match m {
            Marker::Disc => self.disc(c, 3.5, col),
            Marker::Square | Marker::Triangle | Marker::Diamond => {
                for y in (c.1 - 5.0).floor() as i64..=(c.1 + 5.0).ceil() as i64 {
                    for x in (c.0 - 5.0).floor() as i64..=(c.0 + 5.0).ceil() as i64 {
                        let (dx, dy) = (x as f64 + 0.5 - c.0, y as f64 + 0.5 - c.1);
                        let inside = match m {
                            Marker::Square => dx.abs() <= 3.5 && dy.abs() <= 3.5,
                            Marker::Diamond => dx.abs() + dy.abs() <= 4.5,
                            _ => dy <= 3.5 && dy >= -4.5 && dx.abs() <= (dy + 4.5) * 0.5,
                        };
                        if inside {
                            self.blend(x, y, col, 1.0);
                        }
                    }
                }
            }
        }
    }

    fn disc(&mut self, c: (f64, f64), r: f64, col: (u8, u8, u8)) {
        for y in (c.1 - r - 1.0).floor() as i64..=(c.1 + r + 1.0).ceil() as i64 {
            for x in (c.0 - r - 1.0).floor() as i64..=(c.0 + r + 1.0).ceil() as i64 {
                let d = ((x as f64 + 0.5 - c.0).powi(2) + (y as f64 + 0.5 - c.1).powi(2)).sqrt();
                self.blend(x, y, col, (r + 0.5 - d).clamp(0.0, 1.0));
            }
        }
    }

    /// A plot's title centred at the top: double size when it fits the width, else single
    /// size, wrapped onto at most two lines; always above the y label (y = 26) and the plot
    /// (y = TOP).
    fn title(&mut self, title: &str) {
        let fit = ((self.w as f64 - 60.0) / CHAR_PX) as usize;
        let x = self.w as f64 / 2.0;
        if title.chars().count() * 2 <= fit {
            self.text(title, x, 4.0, 2, Align::Centre, (0, 0, 0));
        } else {
            for (k, line) in wrap(title, fit).iter().take(2).enumerate() {
                self.text(line, x, 4.0 + 10.0 * k as f64, 1, Align::Centre, (0, 0, 0));
            }
        }
    }

    fn text(&mut self, s: &str, x: f64, y: f64, scale: usize, align: Align, col: (u8, u8, u8)) {
        let (w, h, v) = crate::targets::label(&s.to_ascii_uppercase(), scale);
        let x0 = match align {
            Align::Left => x,
            Align::Centre => x - w as f64 / 2.0,
            Align::Right => x - w as f64,
        } as i64;
        for r in 0..h {
            for c in 0..w {
                if v[r * w + c] > 0.5 {
                    self.blend(x0 + c as i64, y as i64 + r as i64, col, 1.0);
                }
            }
        }
    }

    fn encode(&self) -> Result<Vec<u8>, String> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.w as u32, self.h as u32);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            // The colours are sRGB values.
            enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
            enc.set_source_gamma(png::ScaledFloat::from_scaled(45455));
            let mut wr = enc.write_header().map_err(|e| e.to_string())?;
            let data: Vec<u8> = self
                .px
                .iter()
                .flat_map(|p| p.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8))
                .collect();
            wr.write_image_data(&data).map_err(|e| e.to_string())?;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A legend longer than the plot makes the image taller instead of running off it: the
    /// last entry's text is inside the PNG and the SVG.
    #[test]
    fn a_long_legend_grows_the_image_instead_of_being_cut() {
        let plot = |n: usize| LinePlot {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            log_x: false,
            log_y: false,
            series: (0..n)
                .map(|i| Series {
                    name: format!("curve {i} with a name long enough to wrap onto two lines"),
                    points: vec![(0.0, i as f64), (1.0, i as f64)],
                })
                .collect(),
            h_line: None,
        };
        assert_eq!(plot(3).png_height(), H);
        let p = plot(30);
        let last = TOP + 10.0 + 29.0 * (9.0 + 22.0) + 22.0;
        assert!(p.png_height() as f64 >= last, "{} < {last}", p.png_height());
        let dec = png::Decoder::new(std::io::Cursor::new(p.to_png().unwrap()));
        assert_eq!(
            dec.read_info().unwrap().info().height as usize,
            p.png_height()
        );
        let svg = p.to_svg();
        let h: f64 = svg
            .split("height=\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!(h >= TOP + 10.0 + 20.0 * 29.0 + 4.0, "{h}");
    }

    #[test]
    fn bar_lengths_follow_the_values_and_rows_grow_with_the_bars() {
        let chart = |values: &[f64]| BarChart {
            title: "what costs most".into(),
            x_label: "share".into(),
            bars: values
                .iter()
                .enumerate()
                .map(|(i, &v)| Bar {
                    label: format!("key {i}"),
                    value: v,
                    note: format!("{v:.2}"),
                })
                .collect(),
        };
        let c = chart(&[0.8, 0.2, 0.0]);
        let png = c.to_png().unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(png));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size().unwrap()];
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!((info.width as usize, info.height as usize), c.size());
        // Bar i's length: its colour's pixels along its middle row.
        let w = info.width as usize;
        let length = |i: usize| {
            let y = (TOP + 10.0 + (i as f64 + 0.5) * BAR_ROW) as usize;
            let col = COLOURS[i];
            (0..w)
                .filter(|&x| buf[3 * (y * w + x)..3 * (y * w + x) + 3] == [col.0, col.1, col.2])
                .count() as f64
        };
        let full = (W as f64 - BAR_NOTE - BAR_LABEL) as f64;
        assert!((length(0) - full).abs() <= 2.0, "{}", length(0));
        assert!((length(1) - 0.25 * full).abs() <= 2.0, "{}", length(1));
        assert_eq!(length(2), 0.0);
        // A wrong value (0.4 instead of 0.2) would fail the check above by 4x its tolerance.
        assert!((0.5 * full - 0.25 * full).abs() > 8.0);
        assert!(chart(&[1.0; 12]).size().1 > chart(&[1.0; 3]).size().1 + 8 * BAR_ROW as usize);
    }

    #[test]
    fn log_axes_and_outputs() {
        let p = LinePlot {
            title: "RMSE against time".into(),
            x_label: "wall time (s)".into(),
            y_label: "relative RMSE".into(),
            log_x: true,
            log_y: true,
            series: vec![Series {
                name: "a".into(),
                points: vec![(0.1, 0.2), (1.0, 0.05), (10.0, 0.012), (f64::NAN, 1.0)],
            }],
            h_line: Some((0.01, "1 %".into())),
        };
        let (ax, ay) = p.axes();
        assert_eq!((ax.lo, ax.hi), (-1.0, 1.0));
        assert_eq!((ay.lo, ay.hi), (-2.0, 0.0));
        assert_eq!(ax.ticks(), vec![0.1, 1.0, 10.0]);
        let svg = p.to_svg();
        assert!(
            svg.starts_with("<svg") && svg.contains("RMSE against time") && svg.contains("1 %")
        );
        // One path with three points (the NaN point is skipped), plus the legend's marker.
        assert_eq!(svg.matches("<circle").count(), 4);
        let png = p.to_png().unwrap();
        assert_eq!(&png[1..4], b"PNG");
        // Linear ticks are round numbers.
        let a = Axis::new([0.0, 7.3].into_iter(), false);
        assert_eq!(a.ticks(), vec![0.0, 2.0, 4.0, 6.0]);
    }

    /// Every character of every string literal in the modules that build plots and figures
    /// has a glyph in the PNG font (an unknown one would be drawn as a box).
    #[test]
    fn every_label_character_has_a_glyph() {
        let sources = [
            include_str!("../../studies/src/sweep/mod.rs"),
            include_str!("../../studies/src/sweep/scan.rs"),
            include_str!("../../studies/src/sweep/figures.rs"),
            include_str!("../../studies/src/analytic/mod.rs"),
            include_str!("../../studies/src/analytic/closed_forms.rs"),
            include_str!("../../studies/src/analytic/report.rs"),
            include_str!("../../studies/src/bench.rs"),
            include_str!("../../main.rs"),
            include_str!("../../cli/src/cli.rs"),
            include_str!("../../cli/src/bench.rs"),
            include_str!("../../cli/src/demo.rs"),
            include_str!("../../cli/src/info.rs"),
            include_str!("../../cli/src/matrix.rs"),
            include_str!("../../cli/src/reconstruct.rs"),
            include_str!("../../cli/src/sweep.rs"),
            include_str!("../../cli/src/validate.rs"),
            include_str!("../../studies/src/demo.rs"),
            include_str!("../../studies/src/capture.rs"),
            include_str!("plot.rs"),
        ];
        let mut missing = std::collections::BTreeSet::new();
        for src in sources {
            // String literals, roughly: text between unescaped double quotes on one line.
            for line in src.lines() {
                let mut inside = false;
                let mut prev = ' ';
                for c in line.chars() {
                    if c == '"' && prev != '\\' && prev != '\'' {
                        inside = !inside;
                    } else if inside && !c.is_control() && !crate::targets::has_label_glyph(c) {
                        missing.insert(c);
                    }
                    prev = c;
                }
            }
        }
        assert!(missing.is_empty(), "no glyph for {missing:?}");
        assert!(!crate::targets::has_label_glyph('☃'), "the check can fail");
    }

    /// Two curves on top of each other both show (the earlier one is drawn wider, underneath,
    /// and the later one dashed), and long titles and legend names are wrapped inside the image.
    #[test]
    fn coinciding_curves_and_long_labels_stay_readable() {
        let pts: Vec<(f64, f64)> = (0..20).map(|i| (i as f64, (i as f64).sqrt())).collect();
        let long = "a very long legend entry that would run off the right edge of the image";
        let p = LinePlot {
            title: "a title far too long for one line at double size: ".repeat(3),
            x_label: "x".into(),
            y_label: "y".into(),
            log_x: false,
            log_y: false,
            series: vec![
                Series {
                    name: long.into(),
                    points: pts.clone(),
                },
                Series {
                    name: "same".into(),
                    points: pts,
                },
            ],
            h_line: None,
        };
        let png = p.to_png().unwrap();
        let mut reader = png::Decoder::new(std::io::Cursor::new(png))
            .read_info()
            .unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut buf).unwrap();
        let count = |col: (u8, u8, u8)| {
            buf.chunks_exact(3)
                .filter(|p| p[0] == col.0 && p[1] == col.1 && p[2] == col.2)
                .count()
        };
        // Both series' colours appear well beyond their legend swatches.
        assert!(count(COLOURS[0]) > 150, "{}", count(COLOURS[0]));
        assert!(count(COLOURS[1]) > 100, "{}", count(COLOURS[1]));
        // Wrapped lines fit: legend lines in the right margin, title lines across the width.
        let x1 = W as f64 - RIGHT;
        for line in wrap(long, LEGEND_CHARS) {
            assert!(
                x1 + 36.0 + CHAR_PX * line.chars().count() as f64 <= W as f64,
                "{line}"
            );
        }
        let fit = ((W as f64 - 60.0) / CHAR_PX) as usize;
        assert!(wrap(&p.title, fit).iter().all(|l| l.chars().count() <= fit));
        assert_eq!(wrap("ab cd", 2), vec!["ab", "cd"]);
        assert_eq!(wrap("abcde", 2), vec!["ab", "cd", "e"]);
    }
}
