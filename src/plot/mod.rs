//! Small dependency-free 2-D plots (the "time against error" figure of `lpm bench accuracy`),
//! written as SVG and as PNG.
//!
//! A [`Figure`] holds a title, axis labels, linear or log10 axes and several [`Series`] (line,
//! markers or both). Both outputs are drawn from one pixel layout, so they show the same picture:
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
//! * **Text.** The SVG uses `<text>` in a sans-serif font. The PNG needs no font files: text is
//!   drawn from a 5×7 bitmap font embedded in [`font`], at 2× (3× bold for the title).
//!
//! Output is deterministic (same figure, same bytes) and written atomically (a temporary file
//! `<path>.tmp-<pid>` renamed over the target; removed on error). There is no anti-aliasing.
//!
//! ```
//! use lpm::plot::{Figure, Series, Style};
//! let mut fig = Figure::new("Accuracy", "time [s]", "relative error");
//! fig.log_x = true;
//! fig.log_y = true;
//! fig.series.push(Series::new("LPM", vec![(0.5, 0.1), (2.0, 0.02), (9.0, 0.004)], Style::LineAndMarkers));
//! let svg = fig.to_svg();
//! assert!(svg.starts_with("<svg") && svg.contains("Accuracy"));
//! let (w, h, rgb) = fig.to_rgb8();
//! assert_eq!(rgb.len(), (w * h * 3) as usize);
//! ```

pub mod axes;
mod figure;
pub mod font;
mod layout;
mod raster;
mod svg;

pub use figure::{Figure, Series, Style};
pub use layout::{Rgb, PALETTE};

/// The colour of series number `index` (the palette cycles after eight series).
pub fn series_colour(index: usize) -> Rgb {
    PALETTE[index % PALETTE.len()]
}
