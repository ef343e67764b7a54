//! The SVG renderer: the [`Layout`] as a standalone SVG 1.1 document. Text stays text (`<text>`,
//! font-family sans-serif); everything is shifted by half a pixel so that 1 px lines on pixel
//! centres are crisp.

use super::layout::{
    Anchor, Layout, Rect, Rgb, Text, BACKGROUND, CAP_H, GRID_MAJOR, GRID_MINOR, INK, LEGEND_BORDER, LINE_WIDTH,
};
use super::marker::{Shape, P};
use std::fmt::Write;

/// SVG font size per text-scale step: a sans-serif capital is about 0.72 em, and the layout
/// reserves [`CAP_H`] = 7 pixels of cap height per scale step.
const FONT_SIZE_PER_SCALE: f64 = 9.5;

pub(crate) fn render(l: &Layout) -> String {
    let mut s = String::new();
    let (w, h) = (l.width, l.height);
    let p = l.plot;
    // Writing into a String cannot fail; the results of write! are ignored for that reason.
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" version="1.1" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif">"#
    );
    let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="{}"/>"#, hex(BACKGROUND));
    let _ = writeln!(
        s,
        r#"<defs><clipPath id="plot-area"><rect x="{}" y="{}" width="{}" height="{}"/></clipPath></defs>"#,
        num(p.x0),
        num(p.y0),
        num(p.x1 - p.x0),
        num(p.y1 - p.y0)
    );
    s.push_str("<g transform=\"translate(0.5 0.5)\">\n");

    segments(&mut s, "grid-minor", &l.minor_grid, GRID_MINOR);
    segments(&mut s, "grid-major", &l.major_grid, GRID_MAJOR);
    rect(&mut s, "frame", p, "none", INK);
    segments(&mut s, "ticks", &l.ticks, INK);

    for (i, series) in l.series.iter().enumerate() {
        let color = hex(series.color);
        let _ = writeln!(
            s,
            r#"<g class="series" data-index="{i}" data-name="{}" clip-path="url(#plot-area)">"#,
            escape(&series.name)
        );
        if series.line && !series.points.is_empty() {
            let points: Vec<String> = series.points.iter().map(|&(x, y)| format!("{},{}", num(x), num(y))).collect();
            let _ = writeln!(
                s,
                r#"<polyline fill="none" stroke="{color}" stroke-width="{LINE_WIDTH}" stroke-linejoin="round" stroke-linecap="round" points="{}"/>"#,
                points.join(" ")
            );
        }
        if series.markers {
            let _ = writeln!(s, r#"<g class="markers" fill="{color}" stroke="{color}">"#);
            for &pt in &series.points {
                shape(&mut s, &series.marker.shape(pt));
            }
            s.push_str("</g>\n");
        }
        s.push_str("</g>\n");
    }
    rect(&mut s, "frame", p, "none", INK);

    if let Some(legend) = &l.legend {
        s.push_str("<g class=\"legend\">\n");
        rect(&mut s, "legend-box", legend.rect, &hex(BACKGROUND), LEGEND_BORDER);
        for e in &legend.entries {
            let series = &l.series[e.series];
            let color = hex(series.color);
            let (a, b) = legend.sample;
            if series.line {
                let _ = writeln!(
                    s,
                    r#"<line x1="{}" y1="{}" x2="{}" y2="{}" stroke="{color}" stroke-width="{LINE_WIDTH}"/>"#,
                    num(a),
                    num(e.y),
                    num(b),
                    num(e.y)
                );
            }
            if series.markers || !series.line {
                let _ = writeln!(s, r#"<g fill="{color}" stroke="{color}">"#);
                shape(&mut s, &series.marker.shape(((a + b) / 2.0, e.y)));
                s.push_str("</g>\n");
            }
        }
        s.push_str("</g>\n");
    }

    for t in &l.texts {
        text(&mut s, t);
    }
    s.push_str("</g>\n</svg>\n");
    s
}

fn hex(c: Rgb) -> String {
    format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
}

/// A coordinate with at most two decimals, no trailing zeros, no "-0".
fn num(v: f64) -> String {
    let s = format!("{v:.2}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".to_string()
    } else {
        s.to_string()
    }
}

fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c if (c as u32) < 0x20 && c != '\t' && c != '\n' && c != '\r' => out.push('?'),
            c => out.push(c),
        }
    }
    out
}

fn segments(s: &mut String, class: &str, segs: &[(P, P)], color: Rgb) {
    if segs.is_empty() {
        return;
    }
    let d: Vec<String> =
        segs.iter().map(|&(a, b)| format!("M{} {}L{} {}", num(a.0), num(a.1), num(b.0), num(b.1))).collect();
    let _ = writeln!(
        s,
        r#"<path class="{class}" fill="none" stroke="{}" stroke-width="1" d="{}"/>"#,
        hex(color),
        d.join("")
    );
}

fn rect(s: &mut String, class: &str, r: Rect, fill: &str, stroke: Rgb) {
    let _ = writeln!(
        s,
        r#"<rect class="{class}" x="{}" y="{}" width="{}" height="{}" fill="{fill}" stroke="{}" stroke-width="1"/>"#,
        num(r.x0),
        num(r.y0),
        num(r.x1 - r.x0),
        num(r.y1 - r.y0),
        hex(stroke)
    );
}

fn shape(s: &mut String, shape: &Shape) {
    match shape {
        Shape::Circle { c, r } => {
            let _ = writeln!(s, r#"<circle cx="{}" cy="{}" r="{}" stroke="none"/>"#, num(c.0), num(c.1), num(*r));
        }
        Shape::Polygon(points) => {
            let pts: Vec<String> = points.iter().map(|&(x, y)| format!("{},{}", num(x), num(y))).collect();
            let _ = writeln!(s, r#"<polygon points="{}" stroke="none"/>"#, pts.join(" "));
        }
        Shape::Strokes(strokes) => {
            let d: Vec<String> =
                strokes.iter().map(|&(a, b)| format!("M{} {}L{} {}", num(a.0), num(a.1), num(b.0), num(b.1))).collect();
            let _ = writeln!(s, r#"<path d="{}" fill="none" stroke-width="{LINE_WIDTH}"/>"#, d.join(""));
        }
    }
}

fn text(s: &mut String, t: &Text) {
    let size = num(FONT_SIZE_PER_SCALE * f64::from(t.scale));
    let cap = f64::from(CAP_H * t.scale);
    let anchor = match t.anchor {
        Anchor::Start => "start",
        Anchor::Middle => "middle",
        Anchor::End => "end",
    };
    let weight = if t.bold { r#" font-weight="bold""# } else { "" };
    let (x, y, transform) = if t.vertical {
        let (bx, by) = (num(t.x + cap), num(t.y));
        let transform = format!(r#" transform="rotate(-90 {bx} {by})""#);
        (bx, by, transform)
    } else {
        (num(t.x), num(t.y + cap), String::new())
    };
    let _ = writeln!(
        s,
        r#"<text class="{}" x="{x}" y="{y}"{transform} font-size="{size}"{weight} text-anchor="{anchor}" fill="{}">{}</text>"#,
        t.class,
        hex(t.color),
        escape(&t.text)
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_svg_numbers_and_escapes() {
        assert_eq!(num(12.0), "12");
        assert_eq!(num(12.5), "12.5");
        assert_eq!(num(-0.001), "0");
        assert_eq!(num(1.234567), "1.23");
        assert_eq!(escape("a<b & \"c\""), "a&lt;b &amp; &quot;c&quot;");
    }
}
