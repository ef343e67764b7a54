//! The figure description (series, styles, axes options) and its entry points.

use super::layout::Layout;
use super::svg;
use std::io;
use std::path::Path;

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Style {
    /// A 2 px polyline through the points, in the given order.
    Line,
    /// One marker per point.
    Markers,
    /// Both.
    LineAndMarkers,
}

impl Style {
    pub(crate) fn line(self) -> bool {
        matches!(self, Style::Line | Style::LineAndMarkers)
    }

    pub(crate) fn markers(self) -> bool {
        matches!(self, Style::Markers | Style::LineAndMarkers)
    }
}

/// One named data series; its colour and marker shape come from its index in [`Figure::series`].
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    pub name: String,
    /// (x, y) points, drawn in this order.
    pub points: Vec<(f64, f64)>,
    pub style: Style,
}

impl Series {
    pub fn new(name: impl Into<String>, points: Vec<(f64, f64)>, style: Style) -> Series {
        Series { name: name.into(), points, style }
    }
}

/// A 2-D plot: title, axis labels, linear or log10 axes, several series and a legend.
#[derive(Clone, Debug, PartialEq)]
pub struct Figure {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub log_x: bool,
    pub log_y: bool,
    pub series: Vec<Series>,
    /// Size in pixels (the SVG's width, height and user units).
    pub width: u32,
    pub height: u32,
}

impl Figure {
    /// An empty figure with linear axes, 960×640.
    pub fn new(title: impl Into<String>, x_label: impl Into<String>, y_label: impl Into<String>) -> Figure {
        Figure {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            log_x: false,
            log_y: false,
            series: Vec::new(),
            width: 960,
            height: 640,
        }
    }

    /// How many points are not drawn: non-finite coordinates, or non-positive ones on a log axis.
    pub fn skipped_points(&self) -> usize {
        self.series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|&&(x, y)| !visible(x, self.log_x) || !visible(y, self.log_y))
            .count()
    }

    /// The figure as a standalone SVG document (text as `<text>`, font-family sans-serif).
    pub fn to_svg(&self) -> String {
        svg::render(&Layout::new(self))
    }

    /// Writes [`Figure::to_svg`] to `path`, atomically (temporary file, then rename).
    pub fn write_svg(&self, path: &Path) -> io::Result<()> {
        let text = self.to_svg();
        write_atomic(path, |w| io::Write::write_all(w, text.as_bytes()))
    }
}

/// Whether a coordinate can be drawn on a (log or linear) axis.
pub(crate) fn visible(v: f64, log: bool) -> bool {
    v.is_finite() && (!log || v > 0.0)
}

fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut io::BufWriter<std::fs::File>) -> io::Result<()>,
) -> io::Result<()> {
    crate::store::write_atomic_io(path, write).map_err(|(action, source)| {
        io::Error::new(source.kind(), format!("{}: cannot {action}: {source}", path.display()))
    })
}
