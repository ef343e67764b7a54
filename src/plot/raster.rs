//! The raster renderer: the [`Layout`] drawn into an RGB8 buffer. No anti-aliasing: lines by
//! Bresenham with a square brush, filled shapes by pixel-centre tests, text from the bitmap font.

use super::font;
use super::layout::{
    Layout, Rect, Rgb, Shape, Text, BACKGROUND, GRID_MAJOR, GRID_MINOR, INK, LEGEND_BORDER, LINE_WIDTH, P,
};

/// Draws `layout` into a new row-major RGB8 buffer of `layout.width × layout.height` pixels.
pub(crate) fn render(layout: &Layout) -> Vec<u8> {
    let mut c = Canvas::new(layout.width, layout.height);
    let full = c.clip;
    let p = layout.plot;
    let plot_clip = [p.x0 as i64, p.y0 as i64, p.x1 as i64, p.y1 as i64];

    c.clip = plot_clip;
    for &(a, b) in &layout.minor_grid {
        c.line(a, b, 1, GRID_MINOR);
    }
    for &(a, b) in &layout.major_grid {
        c.line(a, b, 1, GRID_MAJOR);
    }
    c.clip = full;
    c.outline(p, INK);
    for &(a, b) in &layout.ticks {
        c.line(a, b, 1, INK);
    }

    c.clip = plot_clip;
    for s in &layout.series {
        if s.line {
            for pair in s.points.windows(2) {
                c.line(pair[0], pair[1], LINE_WIDTH, s.color);
            }
        }
        if s.markers {
            for &pt in &s.points {
                c.shape(&s.marker.shape(snap(pt)), s.color);
            }
        }
    }
    // Redraw the frame over series that touch it.
    c.clip = full;
    c.outline(p, INK);

    if let Some(legend) = &layout.legend {
        let r = legend.rect;
        c.fill(r, BACKGROUND);
        c.outline(r, LEGEND_BORDER);
        for e in &legend.entries {
            let s = &layout.series[e.series];
            let (a, b) = legend.sample;
            if s.line {
                c.line((a, e.y), (b, e.y), LINE_WIDTH, s.color);
            }
            if s.markers || !s.line {
                c.shape(&s.marker.shape(snap(((a + b) / 2.0, e.y))), s.color);
            }
        }
    }

    for t in &layout.texts {
        c.text(t);
    }
    c.rgb
}

struct Canvas {
    width: i64,
    height: i64,
    rgb: Vec<u8>,
    /// Inclusive pixel bounds [x0, y0, x1, y1] that drawing is limited to.
    clip: [i64; 4],
}

/// A marker centre on the pixel grid, so that all markers of a shape look alike.
fn snap((x, y): P) -> P {
    (x.round(), y.round())
}

fn round(v: f64) -> i64 {
    v.round() as i64
}

impl Canvas {
    fn new(width: u32, height: u32) -> Canvas {
        let (w, h) = (i64::from(width), i64::from(height));
        let mut rgb = Vec::with_capacity(width as usize * height as usize * 3);
        for _ in 0..width as usize * height as usize {
            rgb.extend_from_slice(&BACKGROUND);
        }
        Canvas { width: w, height: h, rgb, clip: [0, 0, w - 1, h - 1] }
    }

    fn put(&mut self, x: i64, y: i64, c: Rgb) {
        let [x0, y0, x1, y1] = self.clip;
        if x < x0.max(0) || y < y0.max(0) || x > x1.min(self.width - 1) || y > y1.min(self.height - 1) {
            return;
        }
        let i = ((y * self.width + x) * 3) as usize;
        self.rgb[i..i + 3].copy_from_slice(&c);
    }

    fn block(&mut self, x: i64, y: i64, size: i64, c: Rgb) {
        for dy in 0..size {
            for dx in 0..size {
                self.put(x + dx, y + dy, c);
            }
        }
    }

    fn fill(&mut self, r: Rect, c: Rgb) {
        let [x0, y0, x1, y1] = self.visible(r.x0, r.y0, r.x1, r.y1);
        for y in y0..=y1 {
            for x in x0..=x1 {
                self.put(x, y, c);
            }
        }
    }

    fn outline(&mut self, r: Rect, c: Rgb) {
        let (a, b, cc, d) = ((r.x0, r.y0), (r.x1, r.y0), (r.x1, r.y1), (r.x0, r.y1));
        self.line(a, b, 1, c);
        self.line(b, cc, 1, c);
        self.line(cc, d, 1, c);
        self.line(d, a, 1, c);
    }

    /// The pixel range of a float box, limited to the clip rectangle (empty when x1 < x0).
    fn visible(&self, x0: f64, y0: f64, x1: f64, y1: f64) -> [i64; 4] {
        let [cx0, cy0, cx1, cy1] = self.clip;
        let lim = |v: f64, lo: i64, hi: i64| (v.max(lo as f64 - 1.0).min(hi as f64 + 1.0)).round() as i64;
        [lim(x0.floor(), cx0, cx1), lim(y0.floor(), cy0, cy1), lim(x1.ceil(), cx0, cx1), lim(y1.ceil(), cy0, cy1)]
    }

    /// A Bresenham line from `a` to `b` with a `width`×`width` square brush, clipped first (so far
    /// away end points cost nothing).
    fn line(&mut self, a: P, b: P, width: u32, c: Rgb) {
        let [x0, y0, x1, y1] = self.clip;
        let m = f64::from(width) + 1.0;
        let Some((a, b)) = clip_segment(a, b, x0 as f64 - m, y0 as f64 - m, x1 as f64 + m, y1 as f64 + m) else {
            return;
        };
        let (mut x, mut y) = (round(a.0), round(a.1));
        let (xe, ye) = (round(b.0), round(b.1));
        let (dx, dy) = ((xe - x).abs(), -(ye - y).abs());
        let (sx, sy) = (if x < xe { 1 } else { -1 }, if y < ye { 1 } else { -1 });
        let mut err = dx + dy;
        let w = i64::from(width.max(1));
        let off = (w - 1) / 2;
        loop {
            self.block(x - off, y - off, w, c);
            if x == xe && y == ye {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    fn shape(&mut self, shape: &Shape, c: Rgb) {
        match shape {
            &Shape::Circle { c: (cx, cy), r } => {
                let [x0, y0, x1, y1] = self.visible(cx - r, cy - r, cx + r, cy + r);
                for y in y0..=y1 {
                    for x in x0..=x1 {
                        let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                        if dx * dx + dy * dy <= r * r {
                            self.put(x, y, c);
                        }
                    }
                }
            }
            Shape::Polygon(points) => {
                let Some(&(px, py)) = points.first() else { return };
                let (mut bx0, mut by0, mut bx1, mut by1) = (px, py, px, py);
                for &(x, y) in points {
                    bx0 = bx0.min(x);
                    by0 = by0.min(y);
                    bx1 = bx1.max(x);
                    by1 = by1.max(y);
                }
                let [x0, y0, x1, y1] = self.visible(bx0, by0, bx1, by1);
                for y in y0..=y1 {
                    for x in x0..=x1 {
                        if inside(points, (x as f64, y as f64)) {
                            self.put(x, y, c);
                        }
                    }
                }
            }
            Shape::Strokes(strokes) => {
                for &(a, b) in strokes {
                    self.line((a.0.round(), a.1.round()), (b.0.round(), b.1.round()), LINE_WIDTH, c);
                }
            }
        }
    }

    fn text(&mut self, t: &Text) {
        let s = i64::from(t.scale.max(1));
        let (start, _) = t.extent();
        let start = round(start);
        let advance = i64::from(font::ADVANCE) * s;
        for (i, ch) in t.text.chars().enumerate() {
            let rows = font::glyph(ch);
            let i = i as i64;
            for (r, &bits) in rows.iter().enumerate() {
                for col in 0..i64::from(font::GLYPH_W) {
                    if bits & (1 << (i64::from(font::GLYPH_W) - 1 - col)) == 0 {
                        continue;
                    }
                    let r = r as i64;
                    let (x, y) = if t.vertical {
                        // Reading upwards: glyph rows go right, glyph columns go up.
                        let bottom = start + i64::from(font::text_width(&t.text, t.scale));
                        (round(t.x) + r * s, bottom - i * advance - (col + 1) * s)
                    } else {
                        (start + i * advance + col * s, round(t.y) + r * s)
                    };
                    self.block(x, y, s, t.color);
                    if t.bold {
                        let (bx, by) = if t.vertical { (x, y - 1) } else { (x + 1, y) };
                        self.block(bx, by, s, t.color);
                    }
                }
            }
        }
    }
}

/// Even-odd test of a point against a polygon.
fn inside(poly: &[P], (x, y): P) -> bool {
    if poly.is_empty() {
        return false;
    }
    let mut inside = false;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let ((xi, yi), (xj, yj)) = (poly[i], poly[j]);
        if (yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// Liang–Barsky: the part of segment `a`–`b` inside the box, if any.
fn clip_segment(a: P, b: P, x0: f64, y0: f64, x1: f64, y1: f64) -> Option<(P, P)> {
    if !(a.0.is_finite() && a.1.is_finite() && b.0.is_finite() && b.1.is_finite()) {
        return None;
    }
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [(-dx, a.0 - x0), (dx, x1 - a.0), (-dy, a.1 - y0), (dy, y1 - a.1)] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
            if t0 > t1 {
                return None;
            }
        }
    }
    Some(((a.0 + t0 * dx, a.1 + t0 * dy), (a.0 + t1 * dx, a.1 + t1 * dy)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_clip_segment() {
        assert_eq!(clip_segment((-10.0, 0.0), (10.0, 0.0), 0.0, -1.0, 5.0, 1.0), Some(((0.0, 0.0), (5.0, 0.0))));
        assert_eq!(clip_segment((-10.0, 5.0), (10.0, 5.0), 0.0, -1.0, 5.0, 1.0), None);
        assert_eq!(clip_segment((f64::NAN, 0.0), (1.0, 0.0), 0.0, 0.0, 5.0, 5.0), None);
    }

    #[test]
    fn plot_far_lines_are_clipped_not_walked() {
        let mut c = Canvas::new(10, 10);
        c.line((-1e300, 5.0), (1e300, 5.0), 2, INK);
        assert!(c.rgb.chunks(3).any(|p| p == INK));
    }

    #[test]
    fn plot_polygon_inside() {
        let sq = [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0)];
        assert!(inside(&sq, (1.0, 1.0)));
        assert!(!inside(&sq, (3.0, 1.0)));
    }
}
