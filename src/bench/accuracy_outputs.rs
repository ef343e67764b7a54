//! The outputs of `lpm bench accuracy` ([`super::accuracy`]): the report as `accuracy.json`, one
//! CSV row per run in `accuracy.csv`, and the log-log plot of seconds against relative L2 error,
//! `accuracy.svg` (one series per directions per face, precision and plan, its points the
//! tolerances; one for Monte Carlo, its points the photon counts).

use super::accuracy::{AccuracyError, AccuracyReport, AccuracyRow};
use crate::plot::{Figure, Series, Style};
use std::path::Path;

/// Writes `accuracy.json`, `accuracy.csv` and `accuracy.svg` into `out`, each atomically.
pub(super) fn write(out: &Path, report: &AccuracyReport) -> Result<(), AccuracyError> {
    crate::output::write_json_atomic(&out.join("accuracy.json"), report)?;
    let opt = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:e}"));
    let mut csv = String::from(
        "method,setting,seconds,relative_l2,rmse,max_relative_error,mean_bias,reference_noise_l2,noise_corrected_l2,voxels_compared,orders,residual,storage_precision,peak_device_bytes,planned_device_bytes,plan,channels,storage_directions,core_relative_l2,core_mean_bias,core_voxels_compared,spatial,forward_peak\n",
    );
    for r in &report.rows {
        csv.push_str(&format!(
            "{},{},{:e},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            r.method,
            r.setting,
            r.seconds,
            opt(r.relative_l2),
            opt(r.rmse),
            opt(r.max_relative_error),
            opt(r.mean_bias),
            opt(r.reference_noise_l2),
            opt(r.noise_corrected_l2),
            r.voxels_compared,
            r.orders.map_or(String::new(), |o| o.to_string()),
            opt(r.residual),
            r.storage_precision.as_deref().unwrap_or(""),
            r.peak_device_bytes.map_or(String::new(), |b| b.to_string()),
            r.planned_device_bytes.map_or(String::new(), |b| b.to_string()),
            r.plan.as_deref().unwrap_or(""),
            r.channels.map_or(String::new(), |c| c.to_string()),
            r.storage_directions.map_or(String::new(), |d| d.to_string()),
            opt(r.core_relative_l2),
            opt(r.core_mean_bias),
            r.core_voxels_compared,
            r.spatial.as_deref().unwrap_or(""),
            r.forward_peak.as_deref().unwrap_or("")
        ));
    }
    crate::output::write_atomic(&out.join("accuracy.csv"), |w| std::io::Write::write_all(w, csv.as_bytes()))?;

    // One series per directions-per-face, precision and plan (its points are the tolerances), one
    // for Monte Carlo. A setting reads "k=… tol=… precision[ plan=…]".
    let point = |r: &AccuracyRow| r.relative_l2.map(|e| (r.seconds, e));
    let line_of = |r: &AccuracyRow| {
        let words: Vec<&str> = r.setting.split(' ').collect();
        words
            .iter()
            .filter(|w| !w.starts_with("tol=") && !w.starts_with("max_orders="))
            .copied()
            .collect::<Vec<_>>()
            .join(" ")
    };
    let mut series: Vec<Series> = Vec::new();
    let mut lines: Vec<String> = Vec::new();
    for r in report.rows.iter().filter(|r| r.method == "lpm") {
        let line = line_of(r);
        if !lines.contains(&line) {
            lines.push(line);
        }
    }
    for line in lines {
        let points = report.rows.iter().filter(|r| r.method == "lpm" && line_of(r) == line).filter_map(point).collect();
        series.push(Series { name: format!("LPM {line}, tolerances"), points, style: Style::LineAndMarkers });
    }
    series.push(Series {
        name: "Monte Carlo, photon counts".into(),
        points: report.rows.iter().filter(|r| r.method == "monte-carlo").filter_map(point).collect(),
        style: Style::LineAndMarkers,
    });
    let name = Path::new(&report.scene).file_name().map_or(report.scene.clone(), |n| n.to_string_lossy().into_owned());
    let figure = Figure {
        title: format!("Time against error: {name}"),
        x_label: "seconds".into(),
        y_label: "relative L2 error of fluence".into(),
        log_x: true,
        log_y: true,
        series,
        width: 900,
        height: 600,
    };
    let svg = out.join("accuracy.svg");
    figure.write_svg(&svg).map_err(|source| AccuracyError::Write { path: svg, source })?;
    Ok(())
}
