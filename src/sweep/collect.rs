//! `lpm sweep MANIFEST --collect`: one table of every task's frame and parameters against what its
//! solve found, gathered from the task directories: `DIR/results.csv` and `DIR/results.json`.
//!
//! Each row's frame and parameters are those the task was solved with (its `task.json`, written with
//! its `scene.toml`), not the manifest's as it reads now: a task run before the manifest changed
//! keeps its own labels. A task not started yet has the manifest's.
//!
//! Per task: its state (as `--status` says it), the orders run, whether they converged, the solve's
//! seconds (the sum of its phases), and per channel from `report.json`'s energy balance:
//! - `R` and `T`: the reflectance and transmittance of the **lit face**, the face the most power
//!   came in through (`energy.faces[].reflectance` / `.transmittance`): the slab's R and T when the
//!   light enters through one face (a sun or a sky on one side);
//! - `absorptance`: absorbed / (in + emitted + point lights).
//!
//! The CSV has one column per parameter (its dotted key, the value as TOML writes it) and, when any
//! task has three channels, `R_r`, `R_g`, `R_b` and so on (a grey task's one value in all three:
//! grey is the same in every channel), else `R`. Tasks not done have empty cells. The JSON holds the
//! same rows with per-channel arrays of the task's own length.

use super::task::{started, state, Record};
use super::{task_dir, toml_to_json, Sweep, SweepError, Task};
use serde::Serialize;
use std::fmt::Write;
use std::path::PathBuf;

/// One task's row.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub task: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame: Option<i64>,
    /// Dotted scene key → the value the task used.
    pub parameters: serde_json::Map<String, serde_json::Value>,
    /// "done", "running", "interrupted", "failed" or "pending".
    pub status: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    pub orders: Option<u64>,
    pub converged: Option<bool>,
    pub seconds: Option<f64>,
    /// The face the most power came in through ("-x" … "+z").
    pub lit_face: Option<String>,
    /// Per channel (one entry for a grey solve, three for r, g, b).
    #[serde(rename = "R")]
    pub r: Option<Vec<Option<f64>>>,
    #[serde(rename = "T")]
    pub t: Option<Vec<Option<f64>>>,
    pub absorptance: Option<Vec<f64>>,
}

/// The frame and parameter values of the task's row: for a task that has started, those it was
/// solved with — its record (`task.json`, written with its scene), else (a directory written
/// before there were records) the values its own `scene.toml` has at the manifest's keys — never
/// re-derived from the manifest, which may have changed since; for a task not started, the
/// manifest's, which it will be solved with.
fn labels(sweep: &Sweep, task: &Task) -> (Option<i64>, serde_json::Map<String, serde_json::Value>) {
    let dir = task_dir(&sweep.dir, task.index);
    let manifest = || task.parameters.iter().map(|(k, v)| (k.clone(), toml_to_json(v))).collect();
    if !started(&dir) {
        return (task.frame, manifest());
    }
    if let Some(record) = Record::read(&dir).filter(|r| r.task == task.index) {
        return (record.frame, record.parameters);
    }
    let scene =
        std::fs::read_to_string(dir.join("scene.toml")).ok().and_then(|t| toml::from_str::<toml::Table>(&t).ok());
    match scene {
        Some(scene) => (
            task.frame,
            task.parameters
                .iter()
                .filter_map(|(k, _)| Some((k.clone(), toml_to_json(super::get_key(&scene, k)?))))
                .collect(),
        ),
        None => (task.frame, manifest()),
    }
}

/// Reads every task's directory into a row.
pub fn rows(sweep: &Sweep) -> Vec<Row> {
    sweep
        .tasks
        .iter()
        .map(|task| {
            let (state, error) = state(sweep, task.index);
            let (frame, parameters) = labels(sweep, task);
            let mut row = Row {
                task: task.index,
                frame,
                parameters,
                status: state.name().to_string(),
                error,
                orders: None,
                converged: None,
                seconds: None,
                lit_face: None,
                r: None,
                t: None,
                absorptance: None,
            };
            if state == super::task::State::Done {
                let path = task_dir(&sweep.dir, task.index).join("out").join("report.json");
                match read_report(&path) {
                    Some(report) => fill(&mut row, &report),
                    None => row.error = Some(format!("{}: missing or not a report", path.display())),
                }
            }
            row
        })
        .collect()
}

fn read_report(path: &std::path::Path) -> Option<serde_json::Value> {
    let text = crate::input::read_text_capped(path, 64 << 20, "a report").ok()?;
    serde_json::from_str(&text).ok()
}

fn fill(row: &mut Row, report: &serde_json::Value) {
    use serde_json::Value;
    let numbers = |v: &Value| -> Option<Vec<f64>> { v.as_array()?.iter().map(Value::as_f64).collect() };
    let channels = report["plan"]["channels"].as_u64().unwrap_or(3).clamp(1, 3) as usize;
    // Reports written before grey arrays were cut to one entry have three: keep the solve's channels.
    let cut = |v: Vec<f64>| v.into_iter().take(channels).collect::<Vec<_>>();
    row.orders = report["orders"].as_u64();
    row.converged = report["converged"].as_bool();
    row.seconds = report["seconds"].as_array().map(|phases| phases.iter().filter_map(|p| p["seconds"].as_f64()).sum());
    let energy = &report["energy"];
    row.absorptance = numbers(&energy["absorptance"]).map(cut);
    let faces = energy["faces"].as_array().cloned().unwrap_or_default();
    let power_in = |f: &Value| numbers(&f["power_in"]).map_or(0.0, |v| v.iter().take(channels).sum());
    if let Some(lit) = faces.iter().filter(|f| power_in(f) > 0.0).max_by(|a, b| power_in(a).total_cmp(&power_in(b))) {
        row.lit_face = lit["face"].as_str().map(str::to_string);
        let ratios = |v: &Value| -> Option<Vec<Option<f64>>> {
            Some(v.as_array()?.iter().take(channels).map(Value::as_f64).collect())
        };
        row.r = ratios(&lit["reflectance"]);
        row.t = ratios(&lit["transmittance"]);
    }
}

/// A CSV cell: quoted when it holds a comma, a quote or a line break.
fn cell(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}

/// The rows as CSV (see the module docs for the columns).
pub fn csv(sweep: &Sweep, rows: &[Row]) -> String {
    // The manifest's keys, then any other a task was solved with (the manifest changed since).
    let mut keys: Vec<&str> =
        sweep.tasks.first().map_or(Vec::new(), |t| t.parameters.iter().map(|(k, _)| k.as_str()).collect());
    for row in rows {
        for k in row.parameters.keys() {
            if !keys.contains(&k.as_str()) {
                keys.push(k);
            }
        }
    }
    let has_frames = rows.iter().any(|r| r.frame.is_some());
    let rgb = rows.iter().any(|r| r.absorptance.as_ref().is_some_and(|a| a.len() == 3));
    let per_channel = |name: &str| -> Vec<String> {
        if rgb {
            ["r", "g", "b"].iter().map(|c| format!("{name}_{c}")).collect()
        } else {
            vec![name.to_string()]
        }
    };
    let mut header = vec!["task".to_string()];
    if has_frames {
        header.push("frame".into());
    }
    header.extend(keys.iter().map(|k| k.to_string()));
    header.extend(["status", "orders", "converged", "seconds", "lit_face"].map(String::from));
    for name in ["R", "T", "absorptance"] {
        header.extend(per_channel(name));
    }
    header.push("error".into());
    let mut out = header.iter().map(|h| cell(h)).collect::<Vec<_>>().join(",");
    out.push('\n');
    let width = if rgb { 3 } else { 1 };
    // A grey value stands for all three channels.
    let spread = |v: Option<Vec<Option<f64>>>| -> Vec<String> {
        let v = v.unwrap_or_default();
        (0..width)
            .map(|c| {
                let x = if v.len() == 1 { v[0] } else { v.get(c).copied().flatten() };
                x.map_or(String::new(), |x| format!("{x}"))
            })
            .collect()
    };
    for row in rows {
        let mut cells = vec![row.task.to_string()];
        if has_frames {
            cells.push(row.frame.map_or(String::new(), |f| f.to_string()));
        }
        for k in &keys {
            cells.push(match row.parameters.get(*k) {
                Some(serde_json::Value::String(s)) => s.clone(),
                Some(v) => v.to_string(),
                None => String::new(),
            });
        }
        cells.push(row.status.clone());
        cells.push(row.orders.map_or(String::new(), |o| o.to_string()));
        cells.push(row.converged.map_or(String::new(), |c| c.to_string()));
        cells.push(row.seconds.map_or(String::new(), |s| format!("{s:.3}")));
        cells.push(row.lit_face.clone().unwrap_or_default());
        cells.extend(spread(row.r.clone()));
        cells.extend(spread(row.t.clone()));
        cells.extend(spread(row.absorptance.clone().map(|a| a.into_iter().map(Some).collect())));
        cells.push(row.error.clone().unwrap_or_default());
        let line = cells.iter().map(|c| cell(c)).collect::<Vec<_>>().join(",");
        let _ = writeln!(out, "{line}");
    }
    out
}

/// Writes `DIR/results.csv` and `DIR/results.json` (atomically) and returns their paths and rows.
pub fn collect(sweep: &Sweep) -> Result<(Vec<PathBuf>, Vec<Row>), SweepError> {
    let rows = rows(sweep);
    std::fs::create_dir_all(&sweep.dir).map_err(|source| SweepError::Io { path: sweep.dir.clone(), source })?;
    let csv_path = sweep.dir.join("results.csv");
    let text = csv(sweep, &rows);
    crate::output::write_atomic(&csv_path, |w| std::io::Write::write_all(w, text.as_bytes()))?;
    let json_path = sweep.dir.join("results.json");
    crate::output::write_json_atomic(&json_path, &rows)?;
    Ok((vec![csv_path, json_path], rows))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_cells_are_quoted_only_when_needed() {
        assert_eq!(cell("0.5"), "0.5");
        assert_eq!(cell("a,b"), "\"a,b\"");
        assert_eq!(cell("say \"x\""), "\"say \"\"x\"\"\"");
    }

    /// The lit face is the one the most power entered; its R and T per channel; a grey report's
    /// arrays (one entry, or three from before they were cut) give one value.
    #[test]
    fn a_report_fills_the_row() {
        let face = |name: &str, pin: f64, r: f64, t: Option<f64>| serde_json::json!({"face": name, "power_in": [pin, 0.0, 0.0], "reflectance": [r, null, null], "transmittance": [t, null, null]});
        let report = serde_json::json!({
            "plan": {"channels": 1},
            "orders": 7, "converged": true,
            "seconds": [{"phase": "a", "seconds": 1.5}, {"phase": "b", "seconds": 0.25}],
            "energy": {"absorptance": [0.2, 0.0, 0.0], "faces": [face("-z", 1.0, 0.9, Some(0.05)), face("+z", 10.0, 0.3, Some(0.5))]}
        });
        let mut row = Row {
            task: 0,
            frame: None,
            parameters: Default::default(),
            status: "done".into(),
            error: None,
            orders: None,
            converged: None,
            seconds: None,
            lit_face: None,
            r: None,
            t: None,
            absorptance: None,
        };
        fill(&mut row, &report);
        assert_eq!(row.lit_face.as_deref(), Some("+z"));
        assert_eq!((row.r.clone(), row.t.clone()), (Some(vec![Some(0.3)]), Some(vec![Some(0.5)])));
        assert_eq!(row.absorptance, Some(vec![0.2]));
        assert_eq!((row.orders, row.converged, row.seconds), (Some(7), Some(true), Some(1.75)));
    }
}
