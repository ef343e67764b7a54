//! Where everything goes, in pixels: the plot rectangle, grid lines, ticks, series (mapped to
//! pixels), legend and texts. The SVG renderer ([`super::svg`]) only writes this down.
//!
//! Coordinates are pixel centres: pixel (i, j) is centred on (i, j). Text is sized by simple
//! metrics ([`CAP_H`], [`ADVANCE`] per unit of text scale) that a sans-serif font of
//! [`super::svg`]'s size about fills; the layout reserves space by them, so long labels and legend
//! names never overlap.

use super::axes::Axis;
use super::figure::{visible, Figure};
use super::marker::{Marker, MARKERS, P};

/// An sRGB colour.
pub type Rgb = [u8; 3];

/// The series colours, in order: the Okabe–Ito colour-blind-safe palette (with olive in place of
/// its yellow, which is too pale on white).
pub const PALETTE: [Rgb; 8] = [
    [0x00, 0x72, 0xB2], // blue
    [0xD5, 0x5E, 0x00], // vermillion
    [0x00, 0x9E, 0x73], // bluish green
    [0xCC, 0x79, 0xA7], // reddish purple
    [0xE6, 0x9F, 0x00], // orange
    [0x56, 0xB4, 0xE9], // sky blue
    [0x99, 0x99, 0x33], // olive
    [0x00, 0x00, 0x00], // black
];

pub(crate) const BACKGROUND: Rgb = [0xFF, 0xFF, 0xFF];
pub(crate) const INK: Rgb = [0x22, 0x22, 0x22];
pub(crate) const NOTE_INK: Rgb = [0x66, 0x66, 0x66];
pub(crate) const GRID_MAJOR: Rgb = [0xDD, 0xDD, 0xDD];
pub(crate) const GRID_MINOR: Rgb = [0xF0, 0xF0, 0xF0];
pub(crate) const LEGEND_BORDER: Rgb = [0xAA, 0xAA, 0xAA];

/// Text scale for labels, ticks, legend and footnote; and for the title.
pub(crate) const TEXT_SCALE: u32 = 2;
pub(crate) const TITLE_SCALE: u32 = 3;
/// Cap height of text (height of a capital above the baseline) per unit of text scale, in pixels.
pub(crate) const CAP_H: u32 = 7;
/// Horizontal advance per character per unit of text scale, in pixels (a glyph 5 wide and a gap
/// of 1: the last character's gap is not counted in a text's width).
pub(crate) const ADVANCE: u32 = 6;
const GAP: u32 = 1;
/// Stroke width of series lines.
pub(crate) const LINE_WIDTH: u32 = 2;

const PAD: f64 = 14.0;
const TICK: f64 = 6.0;
const MINOR_TICK: f64 = 3.0;
const LABEL_GAP: f64 = 5.0;
const AXIS_LABEL_GAP: f64 = 12.0;
const TITLE_GAP: f64 = 16.0;
const NOTE_GAP: f64 = 10.0;
const LEGEND_INSET: f64 = 10.0;
const LEGEND_SAMPLE: f64 = 34.0;
const LEGEND_PAD: f64 = 8.0;
/// The farthest a pixel coordinate may lie from the origin.
const FAR: f64 = 1e6;

/// A rectangle of pixel centres, x0 ≤ x1, y0 ≤ y1 (inclusive).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Rect {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl Rect {
    fn contains(&self, (x, y): P, margin: f64) -> bool {
        x >= self.x0 - margin && x <= self.x1 + margin && y >= self.y0 - margin && y <= self.y1 + margin
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Anchor {
    Start,
    Middle,
    End,
}

/// A text item. Horizontal: `x` is the anchor and `y` the top of the capitals. Vertical (reading
/// upwards): `x` is the left edge (the top of the capitals) and `y` the anchor, measured upwards.
pub(crate) struct Text {
    pub text: String,
    pub x: f64,
    pub y: f64,
    pub anchor: Anchor,
    pub scale: u32,
    pub color: Rgb,
    pub vertical: bool,
    pub bold: bool,
    pub class: &'static str,
}

impl Text {
    /// Horizontal extent (or vertical, for vertical text) reserved for the text: (start, end).
    pub(crate) fn extent(&self) -> (f64, f64) {
        let w = width(&self.text, self.scale);
        let at = if self.vertical { self.y } else { self.x };
        let start = match (self.anchor, self.vertical) {
            (Anchor::Start, false) => at,
            (Anchor::Middle, _) => (at - w / 2.0).round(),
            (Anchor::End, false) => at - w,
            (Anchor::Start, true) => at - w,
            (Anchor::End, true) => at,
        };
        (start, start + w)
    }
}

pub(crate) struct SeriesLayout {
    pub name: String,
    pub color: Rgb,
    pub marker: Marker,
    pub line: bool,
    pub markers: bool,
    /// The drawable points, in pixels.
    pub points: Vec<P>,
}

pub(crate) struct LegendEntry {
    pub series: usize,
    /// Vertical centre of the row.
    pub y: f64,
}

pub(crate) struct Legend {
    pub rect: Rect,
    /// Horizontal span of the line sample; the marker sits in its middle.
    pub sample: (f64, f64),
    pub entries: Vec<LegendEntry>,
}

pub(crate) struct Layout {
    pub width: u32,
    pub height: u32,
    pub plot: Rect,
    pub minor_grid: Vec<(P, P)>,
    pub major_grid: Vec<(P, P)>,
    pub ticks: Vec<(P, P)>,
    pub series: Vec<SeriesLayout>,
    pub legend: Option<Legend>,
    pub texts: Vec<Text>,
}

fn text(text: &str, x: f64, y: f64, anchor: Anchor, class: &'static str) -> Text {
    Text { text: text.to_string(), x, y, anchor, scale: TEXT_SCALE, color: INK, vertical: false, bold: false, class }
}

fn cap(scale: u32) -> f64 {
    f64::from(CAP_H * scale)
}

/// Width in pixels reserved for `text` at `scale` (no trailing gap).
fn width(text: &str, scale: u32) -> f64 {
    let n = text.chars().count() as u32;
    if n == 0 {
        0.0
    } else {
        f64::from((n * ADVANCE - GAP) * scale)
    }
}

/// The footnote for skipped points, if any.
fn footnote(fig: &Figure) -> Option<String> {
    let (mut non_positive, mut non_finite) = (0usize, 0usize);
    for &(x, y) in fig.series.iter().flat_map(|s| s.points.iter()) {
        if !(x.is_finite() && y.is_finite()) {
            non_finite += 1;
        } else if !visible(x, fig.log_x) || !visible(y, fig.log_y) {
            non_positive += 1;
        }
    }
    let plural = |n: usize| if n == 1 { "point" } else { "points" };
    let mut parts = Vec::new();
    if non_positive > 0 {
        parts.push(format!("{non_positive} non-positive {} (log axis)", plural(non_positive)));
    }
    if non_finite > 0 {
        parts.push(format!("{non_finite} non-finite {}", plural(non_finite)));
    }
    (!parts.is_empty()).then(|| format!("Not shown: {}.", parts.join(", ")))
}

/// Every `k`-th label is kept so that neighbouring labels keep `gap` between them.
fn thin_labels(extents: &[(f64, f64)], gap: f64) -> usize {
    let mut k = 1;
    while k < extents.len() {
        let clear = extents.iter().step_by(k).zip(extents.iter().step_by(k).skip(1)).all(|(a, b)| {
            let (lo_end, hi_start) = if a.0 <= b.0 { (a.1, b.0) } else { (b.1, a.0) };
            hi_start - lo_end >= gap
        });
        if clear {
            break;
        }
        k += 1;
    }
    k
}

impl Layout {
    pub(crate) fn new(fig: &Figure) -> Layout {
        let shown = |&&(x, y): &&(f64, f64)| visible(x, fig.log_x) && visible(y, fig.log_y);
        let all = || fig.series.iter().flat_map(|s| s.points.iter()).filter(shown);
        let x_axis = Axis::fit(all().map(|p| p.0), fig.log_x);
        let y_axis = Axis::fit(all().map(|p| p.1), fig.log_y);
        let note = footnote(fig);

        let (w, h) = (f64::from(fig.width), f64::from(fig.height));
        let text_cap = cap(TEXT_SCALE);
        let descent = f64::from(TEXT_SCALE);

        // Margins around the plot rectangle.
        let top = if fig.title.is_empty() { PAD + text_cap / 2.0 } else { PAD + cap(TITLE_SCALE) + TITLE_GAP };
        let y_tick_w = y_axis.labels.iter().map(|l| width(l, TEXT_SCALE)).fold(0.0, f64::max);
        let y_label_w = if fig.y_label.is_empty() { 0.0 } else { text_cap + descent + AXIS_LABEL_GAP };
        let left = (PAD + y_label_w + y_tick_w + LABEL_GAP + TICK).round();
        let x_label_h = if fig.x_label.is_empty() { 0.0 } else { AXIS_LABEL_GAP + text_cap + descent };
        let note_h = if note.is_some() { NOTE_GAP + text_cap + descent } else { 0.0 };
        let bottom = (TICK + LABEL_GAP + text_cap + x_label_h + note_h + PAD).round();
        let last_half = x_axis.labels.last().map_or(0.0, |l| width(l, TEXT_SCALE) / 2.0);
        let right = (PAD + 6.0).max(last_half + 6.0).round();

        let x0 = left;
        let y0 = top.round();
        let x1 = (w - 1.0 - right).max(x0 + 1.0);
        let y1 = (h - 1.0 - bottom).max(y0 + 1.0);
        let plot = Rect { x0, y0, x1, y1 };
        // Far-off points (an axis that could not span the data, as with ±1e308) are pulled in to
        // finite pixels well outside the plot, where the clip path hides them: an SVG coordinate
        // must be a finite number.
        let finite = |t: f64| if t.is_nan() { -FAR } else { t.clamp(-FAR, FAR) };
        let px = |v: f64| finite(x0 + x_axis.frac(v) * (x1 - x0));
        let py = |v: f64| finite(y1 - y_axis.frac(v) * (y1 - y0));

        let mut layout = Layout {
            width: fig.width,
            height: fig.height,
            plot,
            minor_grid: Vec::new(),
            major_grid: Vec::new(),
            ticks: Vec::new(),
            series: Vec::new(),
            legend: None,
            texts: Vec::new(),
        };

        // Grid, ticks and tick labels.
        let inside_x = |t: f64| t > x0 && t < x1;
        let inside_y = |t: f64| t > y0 && t < y1;
        for &v in &x_axis.minor {
            let t = px(v).round();
            if inside_x(t) {
                layout.minor_grid.push(((t, y0), (t, y1)));
            }
            layout.ticks.push(((t, y1), (t, y1 + MINOR_TICK)));
        }
        for &v in &y_axis.minor {
            let t = py(v).round();
            if inside_y(t) {
                layout.minor_grid.push(((x0, t), (x1, t)));
            }
            layout.ticks.push(((x0 - MINOR_TICK, t), (x0, t)));
        }
        let x_labels: Vec<Text> = x_axis
            .major
            .iter()
            .zip(&x_axis.labels)
            .map(|(&v, label)| text(label, px(v).round(), y1 + TICK + LABEL_GAP, Anchor::Middle, "tick-label"))
            .collect();
        let keep_x = thin_labels(&x_labels.iter().map(Text::extent).collect::<Vec<_>>(), 8.0);
        for (i, (label, &v)) in x_labels.into_iter().zip(&x_axis.major).enumerate() {
            let t = px(v).round();
            if inside_x(t) {
                layout.major_grid.push(((t, y0), (t, y1)));
            }
            layout.ticks.push(((t, y1), (t, y1 + TICK)));
            if i % keep_x == 0 {
                layout.texts.push(label);
            }
        }
        let y_extents: Vec<(f64, f64)> =
            y_axis.major.iter().map(|&v| (py(v) - text_cap / 2.0, py(v) + text_cap / 2.0)).collect();
        let keep_y = thin_labels(&y_extents, 6.0);
        for (i, (&v, label)) in y_axis.major.iter().zip(&y_axis.labels).enumerate() {
            let t = py(v).round();
            if inside_y(t) {
                layout.major_grid.push(((x0, t), (x1, t)));
            }
            layout.ticks.push(((x0 - TICK, t), (x0, t)));
            if i % keep_y == 0 {
                let y_top = (t - text_cap / 2.0).round();
                layout.texts.push(text(label, x0 - TICK - LABEL_GAP, y_top, Anchor::End, "tick-label"));
            }
        }

        // Title, axis labels, footnote.
        let mid_x = ((x0 + x1) / 2.0).round();
        let mid_y = ((y0 + y1) / 2.0).round();
        if !fig.title.is_empty() {
            let half = width(&fig.title, TITLE_SCALE) / 2.0;
            let cx = mid_x.min(w - PAD - half).max(PAD + half).round();
            let mut t = text(&fig.title, cx, PAD, Anchor::Middle, "title");
            t.scale = TITLE_SCALE;
            t.bold = true;
            layout.texts.push(t);
        }
        if !fig.x_label.is_empty() {
            let y = y1 + TICK + LABEL_GAP + text_cap + AXIS_LABEL_GAP;
            layout.texts.push(text(&fig.x_label, mid_x, y, Anchor::Middle, "x-label"));
        }
        if !fig.y_label.is_empty() {
            let mut t = text(&fig.y_label, PAD, mid_y, Anchor::Middle, "y-label");
            t.vertical = true;
            layout.texts.push(t);
        }
        if let Some(note) = note {
            let mut t = text(&note, PAD, h - 1.0 - PAD - text_cap, Anchor::Start, "footnote");
            t.color = NOTE_INK;
            if width(&note, TEXT_SCALE) > w - 2.0 * PAD {
                t.scale = 1;
            }
            layout.texts.push(t);
        }

        // Series.
        for (i, s) in fig.series.iter().enumerate() {
            layout.series.push(SeriesLayout {
                name: s.name.clone(),
                color: PALETTE[i % PALETTE.len()],
                marker: MARKERS[(i + i / PALETTE.len()) % MARKERS.len()],
                line: s.style.line(),
                markers: s.style.markers(),
                points: s.points.iter().filter(shown).map(|&(x, y)| (px(x), py(y))).collect(),
            });
        }

        layout.legend = layout.place_legend();
        if let Some(legend) = &layout.legend {
            let text_x = legend.sample.1 + LEGEND_PAD;
            let texts: Vec<Text> = legend
                .entries
                .iter()
                .map(|e| {
                    let name = &layout.series[e.series].name;
                    text(name, text_x, (e.y - text_cap / 2.0).round(), Anchor::Start, "legend-label")
                })
                .collect();
            layout.texts.extend(texts);
        }
        layout
    }

    /// The legend box in the plot corner that covers the fewest data (top-right on a tie).
    fn place_legend(&self) -> Option<Legend> {
        if self.series.is_empty() {
            return None;
        }
        let row = f64::from(11 * TEXT_SCALE);
        let names_w = self.series.iter().map(|s| width(&s.name, TEXT_SCALE)).fold(0.0, f64::max);
        let w = (LEGEND_PAD + LEGEND_SAMPLE + LEGEND_PAD + names_w + LEGEND_PAD + 2.0).round();
        let h = (LEGEND_PAD * 1.5 + row * self.series.len() as f64).round();
        let p = self.plot;
        let corners = [
            (p.x1 - LEGEND_INSET - w, p.y0 + LEGEND_INSET),
            (p.x0 + LEGEND_INSET, p.y0 + LEGEND_INSET),
            (p.x1 - LEGEND_INSET - w, p.y1 - LEGEND_INSET - h),
            (p.x0 + LEGEND_INSET, p.y1 - LEGEND_INSET - h),
        ];
        let samples = self.data_samples();
        let mut best = (usize::MAX, corners[0]);
        for &(x, y) in &corners {
            let rect = Rect { x0: x, y0: y, x1: x + w, y1: y + h };
            let covered = samples.iter().filter(|&&s| rect.contains(s, 6.0)).count();
            if covered < best.0 {
                best = (covered, (x, y));
            }
        }
        let (x, y) = (best.1 .0.round(), best.1 .1.round());
        let rect = Rect { x0: x, y0: y, x1: x + w, y1: y + h };
        let entries = (0..self.series.len())
            .map(|i| LegendEntry { series: i, y: (y + LEGEND_PAD * 0.75 + row * (i as f64 + 0.5)).round() })
            .collect();
        Some(Legend { rect, sample: (x + LEGEND_PAD, x + LEGEND_PAD + LEGEND_SAMPLE), entries })
    }

    /// Points standing for the drawn data: the points themselves and samples along the lines.
    fn data_samples(&self) -> Vec<P> {
        let mut out = Vec::new();
        for s in &self.series {
            out.extend_from_slice(&s.points);
            if s.line {
                for pair in s.points.windows(2) {
                    let (a, b) = (pair[0], pair[1]);
                    let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt();
                    let n = (len / 4.0).ceil().min(1000.0) as usize;
                    for k in 1..n {
                        let t = k as f64 / n as f64;
                        out.push((a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)));
                    }
                }
            }
        }
        out
    }
}
