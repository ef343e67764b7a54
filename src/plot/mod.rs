//! Small dependency-free 2-D plots (the "time against error" figure of `lpm bench accuracy`),
//! written as SVG. (The data behind a plot is written beside it as CSV by its caller.)
//!
//! A [`Figure`] holds a title, axis labels, linear or log10 axes and several [`Series`] (line,
//! markers or both), laid out in pixels and written down as SVG:
//!
//! * **Axes.** The range is the data range padded by 5 % (a single value is widened around
//!   itself). Log axes label every decade (`1e-3`, `1e-2`, `0.1`, `1`, `10`, `100`, `1e3`) and put
//!   unlabelled minor ticks at 2..9; linear axes put about five ticks at 1/2/5 × 10^k. Major ticks
//!   carry light grid lines. Points that cannot be drawn (non-positive on a log axis, or not finite)
//!   are skipped and counted in a footnote ([`Figure::skipped_points`]).
//! * **Series.** Colour *i* is [`PALETTE`]\[i mod 8\] (Okabe–Ito, colour-blind safe), and each
//!   series gets its own marker shape (circle, square, triangle, diamond, cross, plus, down
//!   triangle, star). Lines are 2 px wide, drawn in the order of the points.
//! * **Legend.** A boxed legend in the plot corner that covers the fewest data points (top-right
//!   on a tie).
//! * **Text.** `<text>` in a sans-serif font; the layout reserves room for it by simple metrics
//!   (7 px cap height and 6 px per character at 1×; labels at 2×, the title at 3× bold).
//!
//! Output is deterministic (same figure, same bytes) and written atomically (a temporary file
//! `<path>.tmp-<pid>` renamed over the target; removed on error). A hand-written rasteriser and
//! bitmap font for a PNG twin were removed (issue 10): viewers and browsers draw SVG, and
//! `accuracy.csv` holds the numbers for any other plotting tool.
//!
//! ```
//! use lpm::plot::{Figure, Series, Style};
//! let mut fig = Figure::new("Accuracy", "time [s]", "relative error");
//! fig.log_x = true;
//! fig.log_y = true;
//! fig.series.push(Series::new("LPM", vec![(0.5, 0.1), (2.0, 0.02), (9.0, 0.004)], Style::LineAndMarkers));
//! let svg = fig.to_svg();
//! assert!(svg.starts_with("<svg") && svg.contains("Accuracy"));
//! ```

pub mod axes;
mod figure;
mod layout;
mod marker;
mod svg;

pub use figure::{Figure, Series, Style};
pub use layout::{Rgb, PALETTE};

/// The colour of series number `index` (the palette cycles after eight series).
pub fn series_colour(index: usize) -> Rgb {
    PALETTE[index % PALETTE.len()]
}
