//! `lpm bench accuracy`: time against error for the solver and the Monte-Carlo reference, on the
//! same axes.
//!
//! A long Monte-Carlo run is the reference. The solver runs across directions per face, tolerances,
//! order caps (optional: `--max-orders`, else the scene's own cap),
//! storage precisions of the gained source (f32 against f16 at otherwise equal settings, with the
//! device bytes each used) and plans (`solver.plan`: "auto" models only what the scene needs,
//! "full" turns those reductions off, so each auto run can be set against its full twin); the
//! Monte-Carlo reference runs again across photon counts (other seeds). Every run is timed and
//! compared with the reference over the voxels where the reference's relative standard error is
//! small ([`crate::compare`]). The results go to `accuracy.json`, `accuracy.csv` and a log-log plot
//! `accuracy.svg` of seconds against relative L2 error, one line per directions per face,
//! precision and plan (written by `accuracy_outputs`).

use crate::compare::{compare_dirs, CompareOptions, Comparison, CoreMask};
use crate::job::{self, SolveJob};
use crate::reference::job::{self as reference_job, ReferenceJob};
use crate::scene::{ForwardPeak, PlanMode, SpatialScheme, StoragePrecision};
use crate::solver::BackendKind;
use crate::vk::ContextOptions;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Clone, Debug)]
pub struct AccuracyOptions {
    pub directions_per_face: Vec<u32>,
    pub tolerances: Vec<f64>,
    /// `solver.max_orders` values to run each (k, tolerance) with; empty: the scene's own cap.
    pub max_orders: Vec<u32>,
    /// `solver.storage_precision` values to run each (k, tolerance) with.
    pub precisions: Vec<StoragePrecision>,
    /// `solver.plan` values to run each (k, tolerance, precision) with.
    pub plans: Vec<PlanMode>,
    /// `solver.spatial` schemes to run each setting with; empty: the scene's own.
    pub spatial: Vec<SpatialScheme>,
    /// `solver.forward_peak` treatments to run each setting with; empty: the scene's own.
    pub forward_peaks: Vec<ForwardPeak>,
    /// `solver.sky_directions_per_face` values to run each setting with (0, or any value up to
    /// the run's k: the sky on the k×k directions); empty: the scene's own.
    pub sky_directions: Vec<u32>,
    /// The density quantile where the dense core starts (the `core_*` columns).
    pub core_quantile: f64,
    pub photons: Vec<u64>,
    pub reference_photons: u64,
    pub backend: BackendKind,
    pub vk: ContextOptions,
    pub max_relative_stderr: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct AccuracyRow {
    /// "lpm" or "monte-carlo".
    pub method: String,
    /// The setting, e.g. "k=5 tol=1e-4 f16" or "photons=1000000".
    pub setting: String,
    /// Solver only: the storage precision of the gained source the plan used ("f16" or "f32").
    pub storage_precision: Option<String>,
    /// Solver only: `solver.plan` ("auto" or "full"), and the channels and storage directions the
    /// plan modelled with it.
    pub plan: Option<String>,
    pub channels: Option<u32>,
    pub storage_directions: Option<u32>,
    pub seconds: f64,
    pub relative_l2: Option<f64>,
    pub rmse: Option<f64>,
    pub max_relative_error: Option<f64>,
    pub mean_bias: Option<f64>,
    /// The relative L2 the reference's own noise accounts for, and the error with it taken out.
    pub reference_noise_l2: Option<f64>,
    pub noise_corrected_l2: Option<f64>,
    pub voxels_compared: u64,
    /// The same over the dense core (voxels at or above the density quantile `core_quantile`): the
    /// whole-medium figures above are dominated by thin, easy voxels.
    pub core_relative_l2: Option<f64>,
    pub core_mean_bias: Option<f64>,
    pub core_voxels_compared: u64,
    /// Solver only: the spatial scheme and forward-peak treatment used.
    pub spatial: Option<String>,
    pub forward_peak: Option<String>,
    /// Solver only: orders run and the final residual.
    pub orders: Option<u32>,
    pub residual: Option<f64>,
    /// Solver on the GPU only: the peak device allocation and the memory plan's bytes.
    pub peak_device_bytes: Option<u64>,
    pub planned_device_bytes: Option<u64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct AccuracyReport {
    pub scene: String,
    pub reference_photons: u64,
    pub reference_seconds: f64,
    pub reference_mean_relative_std_error: Option<f64>,
    pub max_relative_stderr: f64,
    pub rows: Vec<AccuracyRow>,
}

#[derive(Debug, thiserror::Error)]
pub enum AccuracyError {
    #[error(transparent)]
    Solve(#[from] job::JobError),
    #[error(transparent)]
    Reference(#[from] reference_job::ReferenceJobError),
    #[error(transparent)]
    Compare(#[from] crate::compare::CompareError),
    #[error(transparent)]
    Output(#[from] crate::output::OutputError),
    #[error("{path}: {message}")]
    Scene { path: PathBuf, message: String },
    #[error("writing {path}: {source}")]
    Write { path: PathBuf, source: std::io::Error },
}

/// Runs the whole study; `log(line)` reports progress.
pub fn run(
    scene: &Path,
    out: &Path,
    opts: &AccuracyOptions,
    mut log: impl FnMut(&str),
) -> Result<AccuracyReport, AccuracyError> {
    let runs = out.join("runs");
    let reference_dir = runs.join("reference");
    log(&format!("reference: Monte Carlo with {} photons per channel", opts.reference_photons));
    let reference = reference_job::run(&ReferenceJob {
        scene: scene.to_path_buf(),
        out: reference_dir.clone(),
        photons: opts.reference_photons,
        seed: 0xACC,
        threads: 0,
        image_samples_per_pixel: 0,
        image_orders: crate::reference::Orders::ALL,
    })?;
    let loaded = crate::scene::Scene::load(scene).map_err(job::JobError::from)?;
    let density = crate::solver::density_volume(&loaded, &runs.join("density-scratch")).map_err(job::JobError::from)?;
    let core = Some(CoreMask { density, quantile: opts.core_quantile });
    let compare_options = CompareOptions { max_relative_stderr: opts.max_relative_stderr, core };
    let spatials: Vec<Option<SpatialScheme>> =
        if opts.spatial.is_empty() { vec![None] } else { opts.spatial.iter().map(|&s| Some(s)).collect() };
    let peaks: Vec<Option<ForwardPeak>> =
        if opts.forward_peaks.is_empty() { vec![None] } else { opts.forward_peaks.iter().map(|&p| Some(p)).collect() };
    let skies: Vec<Option<u32>> = if opts.sky_directions.is_empty() {
        vec![None]
    } else {
        opts.sky_directions.iter().map(|&n| Some(n)).collect()
    };
    let mut rows = Vec::new();

    // Name the plan in settings and run directories only when it varies from the default, so a
    // study without `--plans` reads as before.
    let name_plans = opts.plans.iter().any(|&p| p != PlanMode::Auto);
    let caps: Vec<Option<u32>> =
        if opts.max_orders.is_empty() { vec![None] } else { opts.max_orders.iter().map(|&c| Some(c)).collect() };
    for &k in &opts.directions_per_face {
        for &tolerance in &opts.tolerances {
            for &max_orders in &caps {
                for &precision in &opts.precisions {
                    for &plan in &opts.plans {
                        for &spatial in &spatials {
                            for &forward_peak in &peaks {
                                for &sky in &skies {
                                    let run = SolverRun {
                                        k,
                                        tolerance,
                                        max_orders,
                                        precision,
                                        plan,
                                        name_plan: name_plans,
                                        spatial,
                                        forward_peak,
                                        sky,
                                    };
                                    log(&format!("lpm {}", run.setting()));
                                    rows.push(solver_row(scene, &runs, &reference_dir, &run, opts, &compare_options)?);
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    for (i, &photons) in opts.photons.iter().enumerate() {
        let setting = format!("photons={photons}");
        log(&format!("monte-carlo {setting}"));
        let dir = runs.join(format!("mc-{photons}"));
        let t = Instant::now();
        reference_job::run(&ReferenceJob {
            scene: scene.to_path_buf(),
            out: dir.clone(),
            photons,
            seed: 1 + i as u64,
            threads: 0,
            image_samples_per_pixel: 0,
            image_orders: crate::reference::Orders::ALL,
        })?;
        let seconds = t.elapsed().as_secs_f64();
        let c = compare_dirs(&dir, &reference_dir, &compare_options)?;
        rows.push(row("monte-carlo", setting, seconds, &c, None, None));
    }
    let report = AccuracyReport {
        scene: scene.display().to_string(),
        reference_photons: reference.photons,
        reference_seconds: reference.seconds,
        reference_mean_relative_std_error: reference.mean_relative_std_error,
        max_relative_stderr: opts.max_relative_stderr,
        rows,
    };
    super::accuracy_outputs::write(out, &report)?;
    Ok(report)
}

/// One solver run of the study: its settings.
struct SolverRun {
    k: u32,
    tolerance: f64,
    /// `None`: the scene's own order cap.
    max_orders: Option<u32>,
    precision: StoragePrecision,
    plan: PlanMode,
    /// Whether the setting and the run's directory name the plan.
    name_plan: bool,
    /// `None`: the scene's own.
    spatial: Option<SpatialScheme>,
    forward_peak: Option<ForwardPeak>,
    /// `solver.sky_directions_per_face`: `None` the scene's own; a value up to k the sky on the
    /// k×k directions.
    sky: Option<u32>,
}

impl SolverRun {
    /// E.g. "k=3 tol=1e-3 f16", "k=3 tol=1e-3 max_orders=4 f16" or "k=3 tol=1e-3 auto plan=full".
    fn setting(&self) -> String {
        let (k, tolerance, precision) = (self.k, self.tolerance, precision_name(self.precision));
        let cap = self.max_orders.map_or(String::new(), |c| format!(" max_orders={c}"));
        let plan = if self.name_plan { format!(" plan={}", self.plan.name()) } else { String::new() };
        format!("k={k} tol={tolerance:e}{cap} {precision}{plan}{}", self.variant(" ", "="))
    }

    /// " spatial=linear peak=delta-m sky=16" (with `sep` and `eq`), for what was set explicitly.
    fn variant(&self, sep: &str, eq: &str) -> String {
        let mut s = String::new();
        if let Some(sp) = self.spatial {
            s += &format!("{sep}spatial{eq}{}", sp.name());
        }
        if let Some(p) = self.forward_peak {
            s += &format!("{sep}peak{eq}{}", p.name());
        }
        if let Some(n) = self.sky {
            s += &format!("{sep}sky{eq}{}", if n > self.k { n } else { self.k });
        }
        s
    }

    fn dir_name(&self) -> String {
        let (k, tolerance, precision) = (self.k, self.tolerance, precision_name(self.precision));
        let cap = self.max_orders.map_or(String::new(), |c| format!("-orders{c}"));
        let plan = if self.name_plan { format!("-{}", self.plan.name()) } else { String::new() };
        format!("lpm-k{k}-tol{tolerance:e}{cap}-{precision}{plan}{}", self.variant("-", ""))
    }
}

/// Solves the scene with `run`'s settings, times it and compares it with the reference.
fn solver_row(
    scene: &Path,
    runs: &Path,
    reference_dir: &Path,
    run: &SolverRun,
    opts: &AccuracyOptions,
    compare_options: &CompareOptions,
) -> Result<AccuracyRow, AccuracyError> {
    let dir = runs.join(run.dir_name());
    let scene_copy = with_solver_settings(scene, &dir, run)?;
    let t = Instant::now();
    let report = job::run(
        &SolveJob {
            backend: opts.backend,
            vk: opts.vk.clone(),
            no_image: true,
            fresh: true,
            no_render_data: true,
            ..SolveJob::new(scene_copy, dir.clone())
        },
        |_, _| {},
    )?;
    let seconds = t.elapsed().as_secs_f64();
    let c = compare_dirs(&dir, reference_dir, compare_options)?;
    let mut r = row("lpm", run.setting(), seconds, &c, Some(report.orders), Some(report.final_residual));
    r.storage_precision = Some(report.plan.storage_precision.name().to_string());
    r.plan = Some(report.plan.mode.clone());
    r.channels = Some(report.plan.channels);
    r.storage_directions = Some(report.plan.storage_directions as u32);
    r.spatial = Some(report.plan.spatial.clone());
    r.forward_peak = Some(match report.plan.delta_m_fraction {
        Some(f) => format!("delta-m f={f:.3}"),
        None => "kept".to_string(),
    });
    if let Some(m) = &report.device_memory {
        r.peak_device_bytes = Some(report.peak_device_bytes);
        r.planned_device_bytes = Some(m.planned_bytes);
    }
    Ok(r)
}

/// One row of the study from a run's comparison with the reference.
fn row(
    method: &str,
    setting: String,
    seconds: f64,
    c: &Comparison,
    orders: Option<u32>,
    residual: Option<f64>,
) -> AccuracyRow {
    let m = &c.fluence.metrics;
    AccuracyRow {
        method: method.into(),
        setting,
        storage_precision: None,
        plan: None,
        channels: None,
        storage_directions: None,
        seconds,
        relative_l2: m.relative_l2,
        rmse: m.rmse,
        max_relative_error: m.max_relative_error,
        mean_bias: m.mean_bias,
        reference_noise_l2: c.fluence.reference_noise_relative_l2,
        noise_corrected_l2: c.fluence.noise_corrected_relative_l2,
        voxels_compared: c.fluence.voxels_used,
        core_relative_l2: c.fluence.core.as_ref().and_then(|k| k.metrics.relative_l2),
        core_mean_bias: c.fluence.core.as_ref().and_then(|k| k.metrics.mean_bias),
        core_voxels_compared: c.fluence.core.as_ref().map_or(0, |k| k.voxels_used),
        spatial: None,
        forward_peak: None,
        orders,
        residual,
        peak_device_bytes: None,
        planned_device_bytes: None,
    }
}

/// The scene file's spelling of a storage precision.
pub fn precision_name(p: StoragePrecision) -> &'static str {
    match p {
        StoragePrecision::Auto => "auto",
        StoragePrecision::F16 => "f16",
        StoragePrecision::F32 => "f32",
    }
}

/// A copy of the scene with its solver settings replaced, written next to the run. Every file the
/// scene names (the volume, its emission, temperature and albedo grids, an environment map) is
/// rewritten to the absolute path the loader resolved, so the copy reads the same data.
fn with_solver_settings(scene: &Path, dir: &Path, run: &SolverRun) -> Result<PathBuf, AccuracyError> {
    let (k, tolerance, precision) = (run.k, run.tolerance, run.precision);
    // Loaded first so that a bad scene is reported as such, not as a failed run.
    crate::scene::Scene::load(scene).map_err(job::JobError::from)?;
    let text =
        std::fs::read_to_string(scene).map_err(|source| AccuracyError::Write { path: scene.to_path_buf(), source })?;
    let mut value: toml::Value = text
        .parse()
        .map_err(|e: toml::de::Error| AccuracyError::Scene { path: scene.to_path_buf(), message: e.to_string() })?;
    if let Some(table) = value.as_table_mut() {
        let solver = table.entry("solver").or_insert_with(|| toml::Value::Table(Default::default()));
        if let Some(solver) = solver.as_table_mut() {
            solver.insert("tolerance".into(), toml::Value::Float(tolerance));
            solver.insert("storage_precision".into(), toml::Value::String(precision_name(precision).into()));
            solver.insert("plan".into(), toml::Value::String(run.plan.name().into()));
            if let Some(cap) = run.max_orders {
                solver.insert("max_orders".into(), toml::Value::Integer(cap as i64));
            }
            if let Some(sp) = run.spatial {
                solver.insert("spatial".into(), toml::Value::String(sp.name().into()));
            }
            if let Some(p) = run.forward_peak {
                solver.insert("forward_peak".into(), toml::Value::String(p.name().into()));
            }
            match run.sky {
                Some(n) if n > k => {
                    solver.insert("sky_directions_per_face".into(), toml::Value::Integer(n.into()));
                }
                Some(_) => {
                    solver.insert("sky_directions_per_face".into(), toml::Value::Integer(k.into()));
                }
                None => {}
            }
            super::set_directions_per_face(solver, k);
        }
        let base = scene.parent().unwrap_or_else(|| Path::new(""));
        crate::scene::make_file_paths_absolute(table, base, &[]);
    }
    std::fs::create_dir_all(dir).map_err(|source| AccuracyError::Write { path: dir.to_path_buf(), source })?;
    let copy = dir.join("scene.toml");
    // `Value::to_string` writes an inline table; serialise as a document instead.
    let text =
        toml::to_string(&value).map_err(|e| AccuracyError::Scene { path: copy.clone(), message: e.to_string() })?;
    crate::output::write_atomic(&copy, |w| std::io::Write::write_all(w, text.as_bytes()))?;
    Ok(copy)
}
