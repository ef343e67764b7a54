//! The outputs of `lpm bench refine` ([`super::refine`]): the report as `refine.json`, one CSV row
//! per line and level in `refine.csv`, and the log-log plot of error against voxel size,
//! `refine.svg`: per line, the whole medium and the dense core, the fitted slope in the legend,
//! and a slope-2 guide.

use super::refine::{RefineError, RefineLevel, RefineReport};
use crate::plot::{Figure, Series, Style};
use std::path::Path;

/// Writes `refine.json`, `refine.csv` and `refine.svg` into `out`, each atomically.
pub(super) fn write(out: &Path, report: &RefineReport) -> Result<(), RefineError> {
    crate::output::write_json_atomic(&out.join("refine.json"), report)?;
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:e}"));
    let mut csv = String::from(
        "line,spatial,diffusion_correction,factor,voxel_size,nx,ny,nz,orders,residual,seconds,change_from_coarser,error_vs_finest,core_error_vs_finest,error_vs_extrapolated,core_error_vs_extrapolated,observed_order,core_observed_order\n",
    );
    for line in &report.lines {
        for l in &line.levels {
            csv.push_str(&format!(
                "{},{},{},{},{:e},{},{},{},{},{:e},{:e},{},{},{},{},{},{},{}\n",
                line.name,
                line.spatial,
                line.diffusion_correction,
                l.factor,
                l.voxel_size,
                l.dims[0],
                l.dims[1],
                l.dims[2],
                l.orders,
                l.residual,
                l.seconds,
                opt(l.change_from_coarser),
                opt(l.error_vs_finest),
                opt(l.core_error_vs_finest),
                opt(l.error_vs_extrapolated),
                opt(l.core_error_vs_extrapolated),
                opt(line.observed_order),
                opt(line.core_observed_order),
            ));
        }
    }
    crate::output::write_atomic(&out.join("refine.csv"), |w| std::io::Write::write_all(w, csv.as_bytes()))?;

    let extrapolated = report.plotted == "extrapolated";
    type Pick = fn(&RefineLevel) -> Option<f64>;
    let (whole, core): (Pick, Pick) = if extrapolated {
        (|l| l.error_vs_extrapolated, |l| l.core_error_vs_extrapolated)
    } else {
        (|l| l.error_vs_finest, |l| l.core_error_vs_finest)
    };
    let slope_text = |s: Option<f64>| s.map_or("slope n/a".to_string(), |s| format!("slope {s:.2}"));
    let mut series = Vec::new();
    for line in &report.lines {
        let points = |pick: Pick| line.levels.iter().filter_map(|l| pick(l).map(|e| (l.voxel_size, e))).collect();
        let (s_whole, s_core) = if extrapolated {
            (line.slope_vs_extrapolated, line.core_slope_vs_extrapolated)
        } else {
            (line.slope_vs_finest, line.core_slope_vs_finest)
        };
        series.push(Series::new(
            format!("{}, whole medium: {}", line.name, slope_text(s_whole)),
            points(whole),
            Style::LineAndMarkers,
        ));
        series.push(Series::new(
            format!("{}, core: {}", line.name, slope_text(s_core)),
            points(core),
            Style::LineAndMarkers,
        ));
    }
    // A slope-2 guide through the first line's coarsest whole-medium point.
    if let Some(&(h, e)) = series.first().and_then(|s| s.points.first()) {
        let h_min = report.lines.iter().flat_map(|l| &l.levels).map(|l| l.voxel_size).fold(h, f64::min);
        series.push(Series::new("second order (slope 2)", vec![(h, e), (h_min, e * (h_min / h).powi(2))], Style::Line));
    }
    let name = Path::new(&report.scene).file_name().map_or(report.scene.clone(), |n| n.to_string_lossy().into_owned());
    let against = if extrapolated { "the Richardson extrapolation" } else { "the finest grid" };
    let figure = Figure {
        title: format!("Grid refinement: {name}, error against {against}"),
        x_label: "voxel size h".into(),
        y_label: "relative L2 error of fluence".into(),
        log_x: true,
        log_y: true,
        series,
        width: 900,
        height: 600,
    };
    let svg = out.join("refine.svg");
    figure.write_svg(&svg).map_err(|source| RefineError::Io { path: svg, source })?;
    Ok(())
}
