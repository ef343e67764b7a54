//! `lpm sweep`: many solves from one manifest — the frames of an animation and/or a parameter
//! sweep — as numbered tasks that cluster jobs (Slurm arrays) run one each.
//!
//! # The manifest
//!
//! ```toml
//! scene = "cloud.toml"          # the base scene, relative to the manifest
//! dir = "cloud.tasks"           # where task directories go (default: MANIFEST-STEM.tasks beside it)
//! [frames]                      # optional: `{frame}` (or `{frame:04}`, zero-padded) in volume.raw
//! first = 1
//! last = 48
//! step = 1
//! warm_start = "previous"       # optional: start each frame from the previous frame's solution
//! [parameters]                  # optional: every combination, dotted scene keys → lists of values
//! "solver.directions_per_face" = [3, 4]
//! "medium.albedo" = [0.8, 0.9, 0.99]
//! "lights[1].irradiance" = [1.0, 2.0]
//! [solve]                       # optional: options of every task's solve
//! no_image = false
//! no_fields = false
//! device_memory_budget = "2G"
//! [slurm]                       # optional: the sbatch script's resources
//! time = "02:00:00"
//! gpus = 1
//! cpus_per_task = 4
//! mem = "32G"
//! partition = "gpu"
//! extra = ["--account=vis"]
//! ```
//!
//! Tasks are numbered from 0, frames outermost, then parameters in the order written (the last one
//! varies fastest). Task N lives in `DIR/task-NNNN/`: `scene.toml` (the base scene with the frame
//! and parameters substituted, validated like any scene), `task.json` (that frame and those
//! parameter values, which `--collect` labels the task's results with), `out/` (the solve's
//! outputs and its checkpoint while it runs), `status.json` (running / done / failed) and
//! `attempts.log` (one line per start, saying whether it resumed). See [`task`] for running one, [`slurm`] for the script and
//! [`collect`] for gathering every task's results into one table.
//!
//! `lpm sweep` over an existing `DIR` checks every task before it writes anything: a task already
//! started (it has `out/`, `status.json` or `attempts.log`) whose scene would change refuses the
//! whole sweep, nothing written; tasks not started are rewritten to the manifest as it reads now.
//!
//! `frames.warm_start = "previous"` starts each frame's solve from the solution of the previous
//! frame with the same parameters (its exported `source.raw`, see [`crate::solver::warm`]): the
//! answer is the cold solve's, within the tolerance, in fewer orders when the frames are alike. A
//! frame whose previous frame is not done when it starts (tasks running side by side) starts cold,
//! and `attempts.log` and its report say which; to chain the frames on a cluster, let them run in
//! order (`slurm.max_running` = the number of parameter combinations, or 1).

pub mod collect;
pub mod slurm;
pub mod task;

use crate::scene::{Scene, SceneError};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    #[error("{}: {message}", .path.display())]
    Manifest { path: PathBuf, message: String },
    #[error("task {task}: {source}")]
    Scene { task: usize, source: SceneError },
    #[error(transparent)]
    BaseScene(SceneError),
    #[error("there is no task {task}: the manifest has {count} (0 to {})", .count.saturating_sub(1))]
    NoTask { task: usize, count: usize },
    #[error(
        "task {task}{}: its scene changed since it was run; remove {} to run it again (nothing was written)",
        and_more(.more),
        .dir.display()
    )]
    Changed { task: usize, dir: PathBuf, more: usize },
    #[error("task {task} is already being solved by another process (lock {})", .lock.display())]
    Busy { task: usize, lock: PathBuf },
    #[error("{}: {source}", .path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    #[error(transparent)]
    Output(#[from] crate::output::OutputError),
    #[error(transparent)]
    Job(#[from] crate::job::JobError),
    #[error("{0}")]
    Slurm(String),
}

/// " (and N more)" after the first task refused, when more are.
fn and_more(more: &usize) -> String {
    if *more > 0 {
        format!(" (and {more} more)")
    } else {
        String::new()
    }
}

/// The most tasks one sweep may have (a Slurm array is far smaller; the manifest expands into one
/// scene file per task).
pub const MAX_TASKS: usize = 100_000;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawManifest {
    scene: PathBuf,
    dir: Option<PathBuf>,
    frames: Option<Frames>,
    #[serde(default)]
    parameters: toml::Table,
    #[serde(default)]
    solve: SolveSettings,
    #[serde(default)]
    slurm: slurm::SlurmSettings,
}

#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Frames {
    pub first: i64,
    pub last: i64,
    #[serde(default = "one")]
    pub step: i64,
    /// `"previous"`: each frame starts from the previous frame's solution; `"none"` (the default):
    /// every frame starts cold.
    #[serde(default)]
    pub warm_start: Option<String>,
}

fn one() -> i64 {
    1
}

/// Options of every task's solve.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolveSettings {
    #[serde(default)]
    pub no_image: bool,
    #[serde(default)]
    pub no_fields: bool,
    pub device_memory_budget: Option<String>,
}

/// A manifest, read and expanded.
#[derive(Debug)]
pub struct Sweep {
    pub manifest: PathBuf,
    pub dir: PathBuf,
    pub tasks: Vec<Task>,
    pub solve: SolveSettings,
    pub slurm: slurm::SlurmSettings,
    /// Frames start from the previous frame's solution (`frames.warm_start = "previous"`).
    pub warm_start: bool,
}

/// One task: its frame, its parameter values and its scene text.
#[derive(Debug)]
pub struct Task {
    pub index: usize,
    pub frame: Option<i64>,
    /// The task of the previous frame with the same parameters (none for the first frame).
    pub previous: Option<usize>,
    pub parameters: Vec<(String, toml::Value)>,
    pub scene: String,
}

impl Sweep {
    /// Reads `manifest` and expands it into tasks, each scene validated.
    pub fn load(manifest: &Path) -> Result<Sweep, SweepError> {
        let bad = |message: String| SweepError::Manifest { path: manifest.to_path_buf(), message };
        let text = crate::input::read_text_capped(manifest, crate::input::MAX_TEXT_BYTES, "a sweep manifest")?;
        let raw: RawManifest = toml::from_str(&text).map_err(|e| bad(e.message().to_string()))?;
        let base_dir = manifest.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let base_dir =
            base_dir.canonicalize().map_err(|source| SweepError::Io { path: base_dir.to_path_buf(), source })?;
        let scene_path = base_dir.join(&raw.scene);
        let scene_text =
            crate::input::read_text_capped(&scene_path, crate::scene::validate::MAX_SCENE_BYTES, "a scene file")?;
        // A syntax error is worded by the scene loader, as for `lpm solve`.
        let base: toml::Table =
            toml::from_str(&scene_text).map_err(|e| match Scene::from_toml_str(&scene_text, &scene_path) {
                Err(source) => SweepError::BaseScene(source),
                Ok(_) => SweepError::Manifest { path: scene_path.clone(), message: e.message().to_string() },
            })?;
        let scene_dir = scene_path.parent().unwrap_or(&base_dir).to_path_buf();
        let dir = base_dir.join(raw.dir.clone().unwrap_or_else(|| {
            PathBuf::from(format!(
                "{}.tasks",
                manifest.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "sweep".into())
            ))
        }));

        let mut axes: Vec<(String, Vec<toml::Value>)> = Vec::new();
        for (key, values) in &raw.parameters {
            match values {
                toml::Value::Array(v) if !v.is_empty() => axes.push((key.clone(), v.clone())),
                _ => return Err(bad(format!("parameters.\"{key}\": expected a non-empty list of values"))),
            }
        }
        // Counted before anything is listed: `last = 9223372036854775807` would list frames until
        // memory ran out.
        let frame_count = match &raw.frames {
            None => 1,
            Some(f) => {
                if f.step <= 0 || f.last < f.first {
                    return Err(bad("frames: need first ≤ last and step > 0".into()));
                }
                (i128::from(f.last) - i128::from(f.first)) / i128::from(f.step) + 1
            }
        };
        let combinations = axes.iter().try_fold(1i128, |n, (_, v)| n.checked_mul(v.len() as i128)).unwrap_or(i128::MAX);
        let task_count = frame_count.saturating_mul(combinations);
        if task_count > MAX_TASKS as i128 {
            return Err(bad(format!(
                "{frame_count} frame(s) × {combinations} parameter combination(s) is {task_count} tasks, more than \
                 the {MAX_TASKS} a sweep may have"
            )));
        }
        let combinations = combinations as usize;
        let frames: Vec<Option<i64>> = match &raw.frames {
            None => vec![None],
            Some(f) => (f.first..=f.last).step_by(f.step as usize).map(Some).collect(),
        };
        let warm_start = match raw.frames.as_ref().and_then(|f| f.warm_start.as_deref()) {
            None | Some("none") => false,
            Some("previous") => true,
            Some(other) => {
                return Err(bad(format!("frames.warm_start: expected \"previous\" or \"none\", got {other:?}")))
            }
        };
        if warm_start && raw.solve.no_fields {
            return Err(bad(
                "frames.warm_start = \"previous\" starts from the previous frame's exported source: it needs solve.no_fields = false".into(),
            ));
        }

        let mut tasks = Vec::new();
        for frame in &frames {
            for c in 0..combinations {
                let index = tasks.len();
                let mut scene = base.clone();
                let mut rest = c;
                let mut parameters = Vec::new();
                for (key, values) in axes.iter().rev() {
                    let value = values[rest % values.len()].clone();
                    rest /= values.len();
                    set_key(&mut scene, key, value.clone()).map_err(|m| bad(format!("parameters.\"{key}\": {m}")))?;
                    parameters.push((key.clone(), value));
                }
                parameters.reverse();
                resolve_volume(&mut scene, &scene_dir, *frame).map_err(bad)?;
                let text = toml::to_string(&scene).map_err(|e| bad(e.to_string()))?;
                let task_scene = task_dir(&dir, index).join("scene.toml");
                Scene::from_toml_str(&text, &task_scene).map_err(|source| SweepError::Scene { task: index, source })?;
                let previous = (warm_start && index >= combinations).then(|| index - combinations);
                tasks.push(Task { index, frame: *frame, previous, parameters, scene: text });
            }
        }
        Ok(Sweep { manifest: manifest.to_path_buf(), dir, tasks, solve: raw.solve, slurm: raw.slurm, warm_start })
    }

    pub fn task(&self, index: usize) -> Result<&Task, SweepError> {
        self.tasks.get(index).ok_or(SweepError::NoTask { task: index, count: self.tasks.len() })
    }

    /// Writes every task's directory, scene and record, and `DIR/tasks.json` (the list of tasks).
    /// Every task is checked against its directory first: when the scene of a task already started
    /// changed, the sweep is refused with nothing written (a task's scene is the one its results
    /// are of, and never rewritten under them).
    pub fn write(&self) -> Result<(), SweepError> {
        let mut prepared = Vec::with_capacity(self.tasks.len());
        let mut changed: Option<(usize, PathBuf)> = None;
        let mut more = 0;
        for task in &self.tasks {
            match task::check(self, task) {
                Ok(p) => prepared.push(p),
                Err(SweepError::Changed { .. }) if changed.is_some() => more += 1,
                Err(SweepError::Changed { task, dir, .. }) => changed = Some((task, dir)),
                Err(e) => return Err(e),
            }
        }
        if let Some((task, dir)) = changed {
            return Err(SweepError::Changed { task, dir, more });
        }
        for p in prepared {
            p.write()?;
        }
        let list: Vec<_> = self
            .tasks
            .iter()
            .map(|t| {
                serde_json::json!({
                    "task": t.index,
                    "frame": t.frame,
                    "parameters": t.parameters.iter().map(|(k, v)| (k.clone(), toml_to_json(v))).collect::<BTreeMap<_, _>>(),
                    "dir": task_dir(&self.dir, t.index),
                })
            })
            .collect();
        crate::output::write_json_atomic(&self.dir.join("tasks.json"), &list)?;
        Ok(())
    }
}

/// A TOML value as JSON (a datetime as its text; a float JSON cannot hold as null).
pub(crate) fn toml_to_json(v: &toml::Value) -> serde_json::Value {
    match v {
        toml::Value::String(s) => s.clone().into(),
        toml::Value::Integer(i) => (*i).into(),
        toml::Value::Float(f) => serde_json::Number::from_f64(*f).map_or(serde_json::Value::Null, Into::into),
        toml::Value::Boolean(b) => (*b).into(),
        toml::Value::Datetime(d) => d.to_string().into(),
        toml::Value::Array(a) => a.iter().map(toml_to_json).collect::<Vec<_>>().into(),
        toml::Value::Table(t) => {
            t.iter().map(|(k, v)| (k.clone(), toml_to_json(v))).collect::<serde_json::Map<_, _>>().into()
        }
    }
}

/// `DIR/task-NNNN`.
pub fn task_dir(dir: &Path, index: usize) -> PathBuf {
    dir.join(format!("task-{index:04}"))
}

/// Substitutes `{frame}` / `{frame:0W}` in volume.raw and makes it, every other file the volume
/// names ([`crate::scene::VOLUME_FILE_KEYS`]: `vdb`, `emission_raw`, `albedo_raw`, …) and an
/// environment light's `map` absolute (relative to the base scene's directory, as for any scene),
/// so the task's scene can live anywhere.
fn resolve_volume(scene: &mut toml::Table, base: &Path, frame: Option<i64>) -> Result<(), String> {
    // An environment light's map and the volume's other files, like the volume, are named
    // relative to the base scene.
    crate::scene::make_file_paths_absolute(scene, base, &["raw"]);
    let Some(toml::Value::Table(volume)) = scene.get_mut("volume") else { return Ok(()) };
    let Some(toml::Value::String(raw)) = volume.get("raw") else {
        return match frame {
            Some(_) => Err("frames: the scene's volume.raw must name the frame's file with {frame}".into()),
            None => Ok(()),
        };
    };
    let mut path = raw.clone();
    if let Some(f) = frame {
        if !path.contains("{frame") {
            return Err(format!("frames: volume.raw {raw:?} has no {{frame}} to substitute"));
        }
        path = substitute_frame(&path, f)?;
    }
    let absolute = base.join(&path);
    volume.insert("raw".into(), toml::Value::String(absolute.to_string_lossy().into_owned()));
    Ok(())
}

/// `{frame}` → 7, `{frame:04}` → 0007.
pub fn substitute_frame(text: &str, frame: i64) -> Result<String, String> {
    let mut out = String::new();
    let mut rest = text;
    while let Some(start) = rest.find("{frame") {
        out.push_str(&rest[..start]);
        let end = rest[start..].find('}').ok_or_else(|| format!("unclosed {{frame in {text:?}"))? + start;
        let spec = &rest[start + 6..end];
        match spec.strip_prefix(':') {
            None if spec.is_empty() => out.push_str(&frame.to_string()),
            Some(w) if w.starts_with('0') && w[1..].parse::<usize>().is_ok() => {
                let width: usize = w[1..].parse().unwrap_or(0);
                out.push_str(&format!("{frame:0width$}"));
            }
            _ => {
                return Err(format!("unknown frame pattern {{frame{spec}}} in {text:?}: use {{frame}} or {{frame:04}}"))
            }
        }
        rest = &rest[end + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

/// Sets dotted `key` (segments may index arrays: `lights[1].irradiance`) to `value`, creating
/// tables on the way.
pub fn set_key(table: &mut toml::Table, key: &str, value: toml::Value) -> Result<(), String> {
    let segments: Vec<&str> = key.split('.').collect();
    let mut current = table;
    for (i, segment) in segments.iter().enumerate() {
        let last = i + 1 == segments.len();
        let (name, index) = match segment.split_once('[') {
            Some((name, idx)) => {
                let idx = idx.strip_suffix(']').and_then(|n| n.parse::<usize>().ok()).ok_or("bad index")?;
                (name, Some(idx))
            }
            None => (*segment, None),
        };
        if name.is_empty() {
            return Err("empty key segment".into());
        }
        let slot: &mut toml::Value = match index {
            None if last => {
                current.insert(name.to_string(), value);
                return Ok(());
            }
            None => current.entry(name.to_string()).or_insert_with(|| toml::Value::Table(toml::Table::new())),
            Some(idx) => {
                let array = match current.get_mut(name) {
                    Some(toml::Value::Array(a)) => a,
                    _ => return Err(format!("{name} is not a list in the scene")),
                };
                let len = array.len();
                let slot = array.get_mut(idx).ok_or(format!("{name} has {len} entries, no [{idx}]"))?;
                if last {
                    *slot = value;
                    return Ok(());
                }
                slot
            }
        };
        current = match slot {
            toml::Value::Table(t) => t,
            _ => return Err(format!("{name} is not a table in the scene")),
        };
    }
    Ok(())
}

/// The value at dotted `key` (as [`set_key`] names it), if the table has one.
pub fn get_key<'a>(table: &'a toml::Table, key: &str) -> Option<&'a toml::Value> {
    let mut current: Option<&toml::Value> = None;
    for segment in key.split('.') {
        let (name, index) = match segment.split_once('[') {
            Some((name, idx)) => (name, Some(idx.strip_suffix(']')?.parse::<usize>().ok()?)),
            None => (segment, None),
        };
        let parent = match current {
            None => table,
            Some(toml::Value::Table(t)) => t,
            Some(_) => return None,
        };
        let value = parent.get(name)?;
        current = Some(match index {
            None => value,
            Some(i) => value.as_array()?.get(i)?,
        });
    }
    current
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_substituted() {
        assert_eq!(substitute_frame("a/{frame}.raw", 7).unwrap(), "a/7.raw");
        assert_eq!(substitute_frame("a/{frame:04}_{frame}.raw", 7).unwrap(), "a/0007_7.raw");
        assert!(substitute_frame("a/{frame:x}.raw", 7).is_err());
        assert!(substitute_frame("a/{frame", 7).is_err());
    }

    #[test]
    fn keys_are_set() {
        let mut t: toml::Table =
            toml::from_str("[medium]\nalbedo = 0.5\n[[lights]]\nkind = \"sky\"\nradiance = 1.0\n").unwrap();
        set_key(&mut t, "medium.albedo", 0.9.into()).unwrap();
        set_key(&mut t, "solver.directions_per_face", 2.into()).unwrap();
        set_key(&mut t, "lights[0].radiance", 2.0.into()).unwrap();
        assert_eq!(t["medium"]["albedo"].as_float(), Some(0.9));
        assert_eq!(t["solver"]["directions_per_face"].as_integer(), Some(2));
        assert_eq!(t["lights"][0]["radiance"].as_float(), Some(2.0));
        assert!(set_key(&mut t, "lights[3].radiance", 2.0.into()).is_err());
        assert!(set_key(&mut t, "medium.albedo.x", 2.0.into()).is_err());
        assert_eq!(get_key(&t, "medium.albedo").and_then(toml::Value::as_float), Some(0.9));
        assert_eq!(get_key(&t, "lights[0].radiance").and_then(toml::Value::as_float), Some(2.0));
        assert_eq!(get_key(&t, "solver.directions_per_face").and_then(toml::Value::as_integer), Some(2));
        for missing in ["lights[3].radiance", "medium.albedo.x", "medium.g", "nothing", "lights[x]"] {
            assert!(get_key(&t, missing).is_none(), "{missing}");
        }
    }

    #[test]
    fn an_environment_map_is_named_from_the_base_scene() {
        let mut t: toml::Table =
            toml::from_str("[volume]\nraw = \"d.raw\"\n[[lights]]\nkind = \"environment\"\nmap = \"maps/sky.exr\"\n")
                .unwrap();
        resolve_volume(&mut t, Path::new("/scenes"), None).unwrap();
        assert_eq!(t["lights"][0]["map"].as_str(), Some("/scenes/maps/sky.exr"));
        assert_eq!(t["volume"]["raw"].as_str(), Some("/scenes/d.raw"));
    }

    #[test]
    fn every_file_the_volume_names_is_named_from_the_base_scene() {
        let mut t: toml::Table = toml::from_str(
            "[volume]\nvdb = \"sim/smoke.vdb\"\nalbedo_raw = \"a.raw\"\nemission_raw = \"/abs/e.raw\"\ngrid = \"density\"\n",
        )
        .unwrap();
        resolve_volume(&mut t, Path::new("/scenes"), None).unwrap();
        assert_eq!(t["volume"]["vdb"].as_str(), Some("/scenes/sim/smoke.vdb"));
        assert_eq!(t["volume"]["albedo_raw"].as_str(), Some("/scenes/a.raw"));
        assert_eq!(t["volume"]["emission_raw"].as_str(), Some("/abs/e.raw"));
        assert_eq!(t["volume"]["grid"].as_str(), Some("density"), "a grid name is not a file");
    }
}
