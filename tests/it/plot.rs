//! The plot module: SVG structure, colours and text present, ticks, skipped points, determinism,
//! atomic writes; and example figures rendered to `target/plot-example*.svg`.

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
fn every_series_colour_is_drawn_and_the_palette_is_distinct() {
    let fig = accuracy_figure();
    let svg = fig.to_svg();
    for i in 0..fig.series.len() {
        let c = series_colour(i);
        let hex = format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2]);
        // The series group draws in its colour (stroke for lines, fill and stroke for markers).
        assert!(svg.matches(&format!("\"{hex}\"")).count() >= 2, "series {i} colour {hex}");
    }
    // Eight series, eight distinct colours.
    let mut palette = PALETTE.to_vec();
    palette.sort();
    palette.dedup();
    assert_eq!(palette.len(), 8);
}

#[test]
fn title_is_drawn_in_the_title_band_and_a_blank_one_keeps_the_layout() {
    let fig = accuracy_figure();
    let svg = fig.to_svg();
    let title = svg.lines().find(|l| l.starts_with("<text class=\"title\"")).expect("title text");
    assert!(title.contains("font-weight=\"bold\"") && title.contains(">Time against error</text>"), "{title}");
    let y: f64 = title.split(" y=\"").nth(1).and_then(|r| r.split('"').next()).expect("y").parse().expect("number");
    assert!(y < 40.0, "title baseline at {y}");
    // A blank title keeps the same plot rectangle (the frame is where it was).
    let frame = |svg: &str| svg.lines().find(|l| l.starts_with("<rect class=\"frame\"")).map(str::to_string);
    let mut blank = fig.clone();
    blank.title = " ".to_string();
    assert_eq!(frame(&blank.to_svg()), frame(&svg));
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
        let svg = fig.to_svg();
        assert!(svg.contains("<circle") && svg.trim_end().ends_with("</svg>"), "{svg}");
    }
    let empty = Figure::new("", "", "");
    let svg = empty.to_svg();
    assert!(svg.trim_end().ends_with("</svg>") && !svg.contains("class=\"series\""));
    let tiny = Figure { width: 3, height: 2, ..accuracy_figure() };
    assert!(tiny.to_svg().contains(r#"width="3" height="2""#));
    let huge = Figure {
        series: vec![Series::new("wild", vec![(-1e308, 1e308), (1e308, -1e308), (0.0, 0.0)], Style::Line)],
        ..Figure::new("wild", "", "")
    };
    let svg = huge.to_svg();
    assert!(!svg.contains("NaN") && !svg.contains("inf"), "non-finite coordinates in {svg}");
}

#[test]
fn output_is_deterministic() {
    let dir = scratch("determinism");
    let fig = accuracy_figure();
    assert_eq!(fig.to_svg(), fig.to_svg());
    let (a, b) = (dir.join("a.svg"), dir.join("b.svg"));
    fig.write_svg(&a).expect("write a");
    fig.clone().write_svg(&b).expect("write b");
    assert_eq!(fs::read(&a).expect("read a"), fs::read(&b).expect("read b"));
}

#[test]
fn writes_are_atomic() {
    let dir = scratch("atomic");
    let fig = accuracy_figure();
    fig.write_svg(&dir.join("fig.svg")).expect("write svg");
    fig.write_svg(&dir.join("fig.svg")).expect("overwrite svg");
    let mut names: Vec<String> = fs::read_dir(&dir)
        .expect("list")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["fig.svg"]);
    assert_eq!(fs::read_to_string(dir.join("fig.svg")).expect("read svg"), fig.to_svg());
    // A failing write leaves nothing behind and says where.
    let missing = dir.join("no-such-dir").join("fig.svg");
    let err = fig.write_svg(&missing).expect_err("missing directory");
    assert!(err.to_string().contains("no-such-dir"), "{err}");
    let count = fs::read_dir(&dir).expect("list").count();
    assert_eq!(count, 1, "temporary left behind");
}

#[test]
fn example_figure_is_rendered_for_inspection() {
    let target = Path::new(env!("CARGO_MANIFEST_DIR")).join("target");
    fs::create_dir_all(&target).expect("target dir");
    let fig = accuracy_figure();
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
    lin.write_svg(&target.join("plot-example-linear.svg")).expect("write linear example");
    assert!(fs::read_to_string(target.join("plot-example-linear.svg")).expect("read").contains("Not shown: 1"));
}
