//! `lpm bench refine`: the grid-refinement study. Does the solver's error fall at the order its
//! scheme promises when the voxels shrink?
//!
//! The scene's medium is solved at voxel sizes h, h/2, h/4, … (`levels` of them; the volume refined
//! by 2, 4, … as [`super::refine_scene`] describes, everything else unchanged) for every spatial
//! scheme and diffusion-correction setting asked for, each to a tight tolerance so that what is
//! measured is the discretisation. Every finer fluence is averaged down onto the coarsest grid
//! (blocks of f³ voxels: the cell averages of the same coarse voxels), and each level's error is
//! measured on that grid, as a relative L2 over the whole medium (coarse voxels with density > 0)
//! and over its dense core (at or above the density quantile `core_quantile`, as in
//! `lpm bench accuracy`):
//! * (a) against the finest level, and
//! * (b) against the Richardson extrapolation of the last three levels: the observed order
//!   p = log₂(‖φ_{h/2} − φ_h‖ / ‖φ_{h/4} − φ_{h/2}‖) from the successive changes (whole medium), and
//!   φ∞ = φ_{h/4} + (φ_{h/4} − φ_{h/2}) / (2^p − 1) voxel by voxel.
//!
//! The slope of log error against log h is fitted by least squares ([`fit_slope`]). (b) is what
//! `refine.svg` plots (when it exists: three levels or more, and changes that shrink); it is the
//! better estimate of the true error: against the finest level a p-th order error reads too steep
//! (the two coarser levels' errors are 2^p + 1 apart, not 2^p). The two finest points of (b) are a
//! ratio 2^p apart by construction, so its slope mostly restates p; the coarsest point is the
//! independent check. The outputs are `refine.json`, `refine.csv` and `refine.svg` (`refine_outputs`).

pub use super::refine_measure::{average_down, fit_slope, observed_order, relative_l2, richardson};
use super::refine_scene::{write_refined_scene, SolverKeys};
use crate::job::{self, SolveJob};
use crate::scene::{DiffusionCorrection, Scene, SpatialScheme};
use crate::solver::BackendKind;
use crate::vk::ContextOptions;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Clone, Debug)]
pub struct RefineOptions {
    /// Grids solved: h, h/2, …, h/2^(levels−1); in 2..=[`MAX_LEVELS`].
    pub levels: u32,
    /// `solver.directions_per_face` of every run; `None`: the scene's own.
    pub directions_per_face: Option<u32>,
    /// `solver.tolerance` of every run (tight: the study measures the discretisation).
    pub tolerance: f64,
    /// `solver.max_orders` of every run; `None`: the scene's own.
    pub max_orders: Option<u32>,
    /// Refine a procedural volume by replicating its voxels (the same piecewise-constant medium:
    /// the solver's error alone) rather than generating it at the finer dims (the default: the
    /// same continuous medium, sampled more finely).
    pub replicate_procedural: bool,
    /// `solver.spatial` schemes, one line each; empty: the scene's own.
    pub spatial: Vec<SpatialScheme>,
    /// `solver.diffusion_correction` settings, one line each; empty: the scene's own.
    pub diffusion_correction: Vec<DiffusionCorrection>,
    /// The density quantile where the dense core starts.
    pub core_quantile: f64,
    pub backend: BackendKind,
    pub vk: ContextOptions,
}

/// The most levels a study may ask for: the finest grid has 8³ = 512 times the coarsest's voxels
/// at 4 levels already.
pub const MAX_LEVELS: u32 = 4;

/// One level (grid) of one line of the study. Errors are relative L2 norms on the coarsest grid.
#[derive(Clone, Debug, Serialize)]
pub struct RefineLevel {
    /// The refinement factor (1, 2, 4, …) and the voxel size h / factor.
    pub factor: u32,
    pub voxel_size: f64,
    pub dims: [u32; 3],
    pub orders: u32,
    pub residual: f64,
    pub seconds: f64,
    /// ‖φ_this − φ_coarser‖ / ‖φ_this‖ over the whole medium; `None` at the coarsest level.
    pub change_from_coarser: Option<f64>,
    /// (a) against the finest level; `None` at the finest level itself.
    pub error_vs_finest: Option<f64>,
    pub core_error_vs_finest: Option<f64>,
    /// (b) against the Richardson extrapolation; `None` without one.
    pub error_vs_extrapolated: Option<f64>,
    pub core_error_vs_extrapolated: Option<f64>,
}

/// One line of the study: a spatial scheme and diffusion-correction setting at every level.
#[derive(Clone, Debug, Serialize)]
pub struct RefineLine {
    /// E.g. "spatial=linear dc=off", or "scene's settings" when nothing was set.
    pub name: String,
    /// What the solver used, from its report.
    pub spatial: String,
    pub diffusion_correction: String,
    pub levels: Vec<RefineLevel>,
    /// The observed order p from the last three levels' changes (whole medium, and the core's own).
    pub observed_order: Option<f64>,
    pub core_observed_order: Option<f64>,
    /// Fitted slopes of log error against log h.
    pub slope_vs_extrapolated: Option<f64>,
    pub core_slope_vs_extrapolated: Option<f64>,
    pub slope_vs_finest: Option<f64>,
    pub core_slope_vs_finest: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct RefineReport {
    pub scene: String,
    pub backend: String,
    pub tolerance: f64,
    /// How a procedural volume was refined: "resampled" or "replicated" (a file volume is always
    /// replicated).
    pub procedural: String,
    pub coarse_dims: [u32; 3],
    pub coarse_voxel_size: f64,
    pub core_quantile: f64,
    pub core_density_threshold: f32,
    /// Coarse voxels measured (medium, solved at every level) and those in the core.
    pub voxels_compared: u64,
    pub core_voxels_compared: u64,
    /// Which errors refine.svg plots: "extrapolated" (b) or "finest" (a).
    pub plotted: String,
    pub lines: Vec<RefineLine>,
}

#[derive(Debug, thiserror::Error)]
pub enum RefineError {
    #[error(transparent)]
    Solve(#[from] job::JobError),
    #[error(transparent)]
    Output(#[from] crate::output::OutputError),
    #[error("{}{}{message}", path.display(), if key.is_empty() { ": ".to_string() } else { format!(": {key}: ") })]
    Scene { path: PathBuf, key: String, message: String },
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("--levels must be in 2..={MAX_LEVELS}, not {0}")]
    Levels(u32),
    #[error("the core quantile must be in [0, 1), not {0}")]
    CoreQuantile(f64),
    #[error("{}: the fluence has dims {found:?} and {components} component(s), expected {expected:?} (the scene refined by {factor})", path.display())]
    Fluence { path: PathBuf, found: [u32; 3], expected: [u32; 3], components: u32, factor: u32 },
    #[error("no coarse voxel holds medium that every level solved: nothing to measure")]
    NothingToMeasure,
}

/// Runs the whole study into `out` (the runs in `out/runs`); `log(line)` reports progress.
pub fn run(
    scene_path: &Path,
    out: &Path,
    opts: &RefineOptions,
    mut log: impl FnMut(&str),
) -> Result<RefineReport, RefineError> {
    if !(2..=MAX_LEVELS).contains(&opts.levels) {
        return Err(RefineError::Levels(opts.levels));
    }
    if !(0.0..1.0).contains(&opts.core_quantile) {
        return Err(RefineError::CoreQuantile(opts.core_quantile));
    }
    let loaded = Scene::load(scene_path).map_err(job::JobError::from)?;
    let runs = out.join("runs");
    let density = crate::solver::density_volume(&loaded, &runs.join("density-scratch")).map_err(job::JobError::from)?;
    let threshold = crate::compare::density_quantile(&density, opts.core_quantile);
    let spatials: Vec<Option<SpatialScheme>> =
        if opts.spatial.is_empty() { vec![None] } else { opts.spatial.iter().map(|&s| Some(s)).collect() };
    let corrections: Vec<Option<DiffusionCorrection>> = if opts.diffusion_correction.is_empty() {
        vec![None]
    } else {
        opts.diffusion_correction.iter().map(|&d| Some(d)).collect()
    };
    let coarse = loaded.volume.dims;
    let mut solved_lines = Vec::new();
    for &spatial in &spatials {
        for &correction in &corrections {
            let keys = SolverKeys {
                directions_per_face: opts.directions_per_face,
                tolerance: opts.tolerance,
                max_orders: opts.max_orders,
                spatial: spatial.map(|s| s.name().to_string()),
                diffusion_correction: correction.map(|d| d.name().to_string()),
            };
            let name = line_name(&keys);
            let mut levels = Vec::new();
            for level in 0..opts.levels {
                let factor = 1u32 << level;
                log(&format!("{name}: h/{factor}"));
                levels.push(solve_level(scene_path, &loaded, &runs, &name, factor, &keys, opts)?);
            }
            solved_lines.push((name, levels));
        }
    }
    // Coarse voxels measured: medium, and every level solved all of its block.
    let voxels = density.len();
    let mut whole = vec![true; voxels];
    for (_, levels) in &solved_lines {
        for l in levels {
            for (v, m) in whole.iter_mut().enumerate() {
                *m &= l.coarse[v * l.components..][..l.components].iter().all(|x| x.is_finite());
            }
        }
    }
    for (m, &d) in whole.iter_mut().zip(&density) {
        *m &= d > 0.0;
    }
    let core: Vec<bool> = whole.iter().zip(&density).map(|(&m, &d)| m && d >= threshold).collect();
    let count = |mask: &[bool]| mask.iter().filter(|&&m| m).count() as u64;
    if count(&whole) == 0 {
        return Err(RefineError::NothingToMeasure);
    }
    let lines: Vec<RefineLine> =
        solved_lines.into_iter().map(|(name, levels)| measure(name, levels, &whole, &core)).collect();
    let plotted = if lines.iter().all(|l| l.observed_order.is_some()) { "extrapolated" } else { "finest" };
    let report = RefineReport {
        scene: scene_path.display().to_string(),
        backend: match opts.backend {
            BackendKind::Gpu => "gpu".into(),
            BackendKind::Cpu => "cpu".into(),
        },
        tolerance: opts.tolerance,
        procedural: if opts.replicate_procedural { "replicated".into() } else { "resampled".into() },
        coarse_dims: coarse,
        coarse_voxel_size: loaded.volume.voxel_size,
        core_quantile: opts.core_quantile,
        core_density_threshold: threshold,
        voxels_compared: count(&whole),
        core_voxels_compared: count(&core),
        plotted: plotted.into(),
        lines,
    };
    super::refine_outputs::write(out, &report)?;
    Ok(report)
}

/// "spatial=linear dc=on" for what was set, "scene's settings" when nothing was.
fn line_name(keys: &SolverKeys) -> String {
    let mut words = Vec::new();
    if let Some(s) = &keys.spatial {
        words.push(format!("spatial={s}"));
    }
    if let Some(d) = &keys.diffusion_correction {
        words.push(format!("dc={d}"));
    }
    if words.is_empty() {
        "scene's settings".into()
    } else {
        words.join(" ")
    }
}

/// One solved level: what its report says and its fluence averaged down onto the coarsest grid.
struct SolvedLevel {
    level: RefineLevel,
    spatial: String,
    diffusion_correction: String,
    /// Component fastest, then x, y, z, on the coarsest grid.
    coarse: Vec<f64>,
    components: usize,
}

fn solve_level(
    scene_path: &Path,
    loaded: &Scene,
    runs: &Path,
    name: &str,
    factor: u32,
    keys: &SolverKeys,
    opts: &RefineOptions,
) -> Result<SolvedLevel, RefineError> {
    let dir_name: String = name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '=' { c } else { '-' }).collect();
    let dir = runs.join(format!("{dir_name}-h{factor}"));
    let copy = write_refined_scene(scene_path, loaded, &dir.join("scene"), factor, opts.replicate_procedural, keys)?;
    let t = Instant::now();
    let report = job::run(
        &SolveJob {
            backend: opts.backend,
            vk: opts.vk.clone(),
            no_image: true,
            fresh: true,
            no_render_data: true,
            ..SolveJob::new(copy, dir.clone())
        },
        |_, _| {},
    )?;
    let seconds = t.elapsed().as_secs_f64();
    let (info, values) = crate::output::read_raw_field(&dir, "fluence")?;
    let expected = loaded.volume.dims.map(|d| d * factor);
    if info.dims != expected {
        return Err(RefineError::Fluence {
            path: dir.join("fluence.json"),
            found: info.dims,
            expected,
            components: info.components,
            factor,
        });
    }
    let components = info.components as usize;
    Ok(SolvedLevel {
        level: RefineLevel {
            factor,
            voxel_size: loaded.volume.voxel_size / factor as f64,
            dims: expected,
            orders: report.orders,
            residual: report.final_residual,
            seconds,
            change_from_coarser: None,
            error_vs_finest: None,
            core_error_vs_finest: None,
            error_vs_extrapolated: None,
            core_error_vs_extrapolated: None,
        },
        spatial: report.plan.spatial.clone(),
        diffusion_correction: if report.plan.diffusion_correction.iter().any(|&k| k > 0.0) {
            "on".into()
        } else {
            "off".into()
        },
        coarse: average_down(&values, expected, components, factor),
        components,
    })
}

/// The errors of one line's levels, its observed orders and slopes.
fn measure(name: String, solved: Vec<SolvedLevel>, whole: &[bool], core: &[bool]) -> RefineLine {
    let c = solved.first().map_or(1, |s| s.components);
    let n = solved.len();
    let fields: Vec<&[f64]> = solved.iter().map(|s| s.coarse.as_slice()).collect();
    let l2 = |a: &[f64], b: &[f64], mask: &[bool]| relative_l2(a, b, mask, c);
    let extrapolated = (n >= 3).then(|| richardson(fields[n - 3], fields[n - 2], fields[n - 1], whole, c)).flatten();
    let core_order = (n >= 3).then(|| observed_order(fields[n - 3], fields[n - 2], fields[n - 1], core, c)).flatten();
    let (spatial, diffusion_correction) =
        solved.first().map_or((String::new(), String::new()), |s| (s.spatial.clone(), s.diffusion_correction.clone()));
    let mut levels = Vec::with_capacity(n);
    for (i, s) in solved.iter().enumerate() {
        let mut l = s.level.clone();
        if i > 0 {
            l.change_from_coarser = l2(fields[i - 1], fields[i], whole);
        }
        if i + 1 < n {
            l.error_vs_finest = l2(fields[i], fields[n - 1], whole);
            l.core_error_vs_finest = l2(fields[i], fields[n - 1], core);
        }
        if let Some((_, limit)) = &extrapolated {
            l.error_vs_extrapolated = l2(fields[i], limit, whole);
            l.core_error_vs_extrapolated = l2(fields[i], limit, core);
        }
        levels.push(l);
    }
    let slope = |e: fn(&RefineLevel) -> Option<f64>| {
        fit_slope(&levels.iter().filter_map(|l| e(l).map(|e| (l.voxel_size, e))).collect::<Vec<_>>())
    };
    RefineLine {
        name,
        spatial,
        diffusion_correction,
        observed_order: extrapolated.as_ref().map(|(p, _)| *p),
        core_observed_order: core_order,
        slope_vs_extrapolated: slope(|l| l.error_vs_extrapolated),
        core_slope_vs_extrapolated: slope(|l| l.core_error_vs_extrapolated),
        slope_vs_finest: slope(|l| l.error_vs_finest),
        core_slope_vs_finest: slope(|l| l.core_error_vs_finest),
        levels,
    }
}
