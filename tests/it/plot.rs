//! The plot module: SVG structure, PNG round trip, colours and text present, ticks, skipped
//! points, determinism, atomic writes; and an example figure rendered to `target/plot-example.png`.

use lpm::plot::axes::{linear_ticks, log_ticks};
use lpm::plot::{series_colour, Figure, Series, Style, PALETTE};
use std::fs;
use std::path::{Path, PathBuf};

fn accuracy_figure() -> Figure {
    let mut fig = Figure::new("Time against error", "wall time [s]", "relative L2 error");
    fig.log_x = true;
    fig.log_y = true;
    let lpm = |k: f64| -> Vec<(f64, f64)> {
        (0..6)
            .map(|i| {
                let n = 2f64.powi(i);
                (0.4 * n * k, 0.08 / (n * k).powf(0.9) + 2e-4)
            })
            .collect()
    };
    fig.series.push(Series::new("LPM k=4", lpm(1.0), Style::LineAndMarkers));
    fig.series.push(Series::new("LPM k=8", lpm(3.0), Style::LineAndMarkers));
    fig.series.push(Series::new(
        "Monte-Carlo",
        (0..7)
            .map(|i| {
                let t = 0.3 * 3f64.powi(i);
                (t, 0.3 / t.sqrt())
            })
            .collect(),
        Style::LineAndMarkers,
    ));
    fig.series.push(Series::new("CPU twin", vec![(30.0, 3e-3), (120.0, 8e-4), (480.0, 3e-4)], Style::Markers));
    fig.series.push(Series::new("target", vec![(0.3, 1e-3), (500.0, 1e-3)], Style::Line));
    fig
}

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("plot-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).expect("create scratch dir");
    dir
}

fn decode(path: &Path) -> (png::OutputInfo, Vec<u8>) {
    let decoder = png::Decoder::new(fs::File::open(path).expect("open png"));
    let mut reader = decoder.read_info().expect("png header");
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).expect("png frame");
    buf.truncate(info.buffer_size());
    (info, buf)
}

#[test]
fn svg_has_title_labels_legend_and_one_group_per_series() {
    let fig = accuracy_figure();
    let svg = fig.to_svg();
    for text in ["Time against error", "wall time [s]", "relative L2 error", "LPM k=4", "Monte-Carlo", "CPU twin"] {
        assert!(svg.contains(&format!(">{text}</text>")), "missing text {text}");
    }
    assert_eq!(svg.matches("<g class=\"series\"").count(), fig.series.len());
    // Line series carry a polyline, marker series a marker group.
    let lines = fig.series.iter().filter(|s| s.style != Style::Markers).count();
    let markers = fig.series.iter().filter(|s| s.style != Style::Line).count();
    assert_eq!(svg.matches("<polyline").count(), lines);
    assert_eq!(svg.matches("<g class=\"markers\"").count(), markers);
    for i in 0..fig.series.len() {
        let c = series_colour(i);
        assert!(svg.contains(&format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])));
    }
    for label in ["1e-3", "0.1", "1", "10", "100"] {
        assert!(svg.contains(&format!(">{label}</text>")), "missing tick label {label}");
    }
}

#[test]
fn svg_is_well_formed_enough() {
    let mut fig = accuracy_figure();
    fig.title = "a < b & \"c\"".to_string();
    let svg = fig.to_svg();
    assert!(svg.starts_with("<svg"));
    assert!(svg.trim_end().ends_with("</svg>"));
    assert!(svg.contains("a &lt; b &amp; &quot;c&quot;"));
    let opens = svg.matches('<').count() - svg.matches("</").count();
    let self_closed = svg.matches("/>").count();
    let closes = svg.matches("</").count();
    assert_eq!(opens - self_closed, closes, "unbalanced tags");
    // Every element name closes in the right count.
    for name in ["svg", "g", "text", "defs", "clipPath"] {
        let open = svg.matches(&format!("<{name} ")).count() + svg.matches(&format!("<{name}>")).count();
        assert_eq!(open, svg.matches(&format!("</{name}>")).count(), "<{name}> unbalanced");
    }
}

#[test]
fn png_round_trips_with_the_right_size() {
    let dir = scratch("roundtrip");
    let mut fig = accuracy_figure();
    fig.width = 700;
    fig.height = 450;
    let path = dir.join("fig.png");
    fig.write_png(&path).expect("write png");
    let (info, buf) = decode(&path);
    assert_eq!((info.width, info.height), (700, 450));
    assert_eq!(info.color_type, png::ColorType::Rgb);
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    let (w, h, rgb) = fig.to_rgb8();
    assert_eq!((w, h), (700, 450));
    assert_eq!(buf, rgb);
}

#[test]
fn every_series_colour_is_drawn() {
    let fig = accuracy_figure();
    let (_, _, rgb) = fig.to_rgb8();
    for i in 0..fig.series.len() {
        let c = series_colour(i);
        let n = rgb.chunks(3).filter(|p| *p == c).count();
        assert!(n > 50, "series {i} colour {c:?}: only {n} pixels");
    }
    // Eight series, eight distinct colours.
    let mut palette = PALETTE.to_vec();
    palette.dedup();
    assert_eq!(palette.len(), 8);
}

#[test]
fn title_text_is_drawn_in_the_title_band() {
    let fig = accuracy_figure();
    let (w, _, rgb) = fig.to_rgb8();
    let band =
        |rgb: &[u8]| -> usize { rgb[..(w * 40 * 3) as usize].chunks(3).filter(|p| *p != [255, 255, 255]).count() };
    let with_title = band(&rgb);
    assert!(with_title > 200, "{with_title} title pixels");
    // A blank title keeps the same layout and leaves the band empty.
    let mut blank = fig.clone();
    blank.title = " ".to_string();
    let (_, _, rgb) = blank.to_rgb8();
    assert_eq!(band(&rgb), 0);
}

#[test]
fn log_ticks_cover_the_decades_in_range() {
    assert_eq!(log_ticks(3e-4, 20.0), vec![1e-3, 1e-2, 1e-1, 1.0, 10.0]);
    let lin = linear_ticks(0.0, 47.0);
    assert_eq!(lin, vec![0.0, 10.0, 20.0, 30.0, 40.0]);
}

#[test]
fn non_positive_points_on_log_axes_are_skipped_and_noted() {
    let mut fig = accuracy_figure();
    fig.series[0].points.push((0.0, 1e-2));
    fig.series[1].points.push((1.0, -3.0));
    fig.series[2].points.push((f64::NAN, 1.0));
    assert_eq!(fig.skipped_points(), 3);
    let svg = fig.to_svg();
    assert!(svg.contains(">Not shown: 2 non-positive points (log axis), 1 non-finite point.</text>"), "{svg}");
    // On linear axes only the non-finite one is skipped.
    fig.log_x = false;
    fig.log_y = false;
    assert_eq!(fig.skipped_points(), 1);
    assert_eq!(accuracy_figure().skipped_points(), 0);
    assert!(!accuracy_figure().to_svg().contains("footnote"));
}

#[test]
fn degenerate_and_empty_figures_render() {
    let mut fig = Figure::new("one point", "x", "y");
    fig.series.push(Series::new("p", vec![(5.0, 5.0)], Style::LineAndMarkers));
    for (log_x, log_y) in [(false, false), (true, true)] {
        fig.log_x = log_x;
        fig.log_y = log_y;
        let (_, _, rgb) = fig.to_rgb8();
        assert!(rgb.chunks(3).any(|p| p == series_colour(0)));
        assert!(fig.to_svg().contains("</svg>"));
    }
    let empty = Figure::new("", "", "");
    let (w, h, rgb) = empty.to_rgb8();
    assert_eq!(rgb.len(), (w * h * 3) as usize);
    let tiny = Figure { width: 3, height: 2, ..accuracy_figure() };
    assert_eq!(tiny.to_rgb8().2.len(), 18);
    let huge = Figure {
        series: vec![Series::new("wild", vec![(-1e308, 1e308), (1e308, -1e308), (0.0, 0.0)], Style::Line)],
        ..Figure::new("wild", "", "")
    };
    let _ = huge.to_rgb8();
}

#[test]
fn output_is_deterministic() {
    let dir = scratch("determinism");
    let fig = accuracy_figure();
    assert_eq!(fig.to_svg(), fig.to_svg());
    let (a, b) = (dir.join("a.png"), dir.join("b.png"));
    fig.write_png(&a).expect("write a");
    fig.clone().write_png(&b).expect("write b");
    assert_eq!(fs::read(&a).expect("read a"), fs::read(&b).expect("read b"));
}

#[test]
fn writes_are_atomic() {
    let dir = scratch("atomic");
    let fig = accuracy_figure();
    fig.write_svg(&dir.join("fig.svg")).expect("write svg");
    fig.write_png(&dir.join("fig.png")).expect("write png");
    fig.write_png(&dir.join("fig.png")).expect("overwrite png");
    let mut names: Vec<String> = fs::read_dir(&dir)
        .expect("list")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["fig.png", "fig.svg"]);
    assert_eq!(fs::read_to_string(dir.join("fig.svg")).expect("read svg"), fig.to_svg());
    // A failing write leaves nothing behind and says where.
    let missing = dir.join("no-such-dir").join("fig.png");
    let err = fig.write_png(&missing).expect_err("missing directory");
    assert!(err.to_string().contains("no-such-dir"), "{err}");
    // A zero-sized figure cannot be a PNG: the error removes the temporary.
    let empty = Figure { width: 0, height: 0, ..accuracy_figure() };
    assert!(empty.write_png(&dir.join("zero.png")).is_err());
    let count = fs::read_dir(&dir).expect("list").count();
    assert_eq!(count, 2, "temporary left behind");
}

#[test]
fn example_figure_is_rendered_for_inspection() {
    let target = Path::new(env!("CARGO_MANIFEST_DIR")).join("target");
    fs::create_dir_all(&target).expect("target dir");
    let fig = accuracy_figure();
    fig.write_png(&target.join("plot-example.png")).expect("write example png");
    fig.write_svg(&target.join("plot-example.svg")).expect("write example svg");
    let mut lin = Figure::new("Linear axes, one skipped", "order", "fluence");
    lin.series.push(Series::new(
        "a",
        (0..12).map(|i| (i as f64, (i as f64 * 0.6).sin() * 3.0)).collect(),
        Style::LineAndMarkers,
    ));
    lin.series.push(Series::new(
        "b",
        (0..12).map(|i| (i as f64, (i as f64 * 0.3).cos() * 2.0 + 0.5)).collect(),
        Style::Markers,
    ));
    lin.series.push(Series::new("c", vec![(2.0, f64::NAN), (3.0, 1.0)], Style::Markers));
    lin.width = 640;
    lin.height = 420;
    lin.write_png(&target.join("plot-example-linear.png")).expect("write linear example");

    // Every glyph of the bitmap font, in the legend.
    let ascii: String = (32u8..127).map(char::from).collect();
    let mut specimen = Figure::new("Font specimen: 5x7 at 2x, title 3x bold", "x label", "y label");
    for (i, chunk) in ascii.as_bytes().chunks(24).enumerate() {
        let name = String::from_utf8_lossy(chunk).into_owned();
        specimen.series.push(Series::new(name, vec![(i as f64, 0.0), (i as f64 + 1.0, 1.0)], Style::Line));
    }
    specimen.width = 800;
    specimen.height = 360;
    specimen.write_png(&target.join("plot-font-specimen.png")).expect("write specimen");
}
