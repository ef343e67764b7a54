//! Accuracy of one output directory against another (`lpm compare A B`): A is the candidate (say an
//! `lpm solve` output), B the reference (say an `lpm reference` output).
//!
//! **Fluence.** `fluence.json` / `fluence.raw` of both are read ([`output::read_raw_field`]); their
//! dims and components must match, except that a grey reference (one component named "grey") is
//! compared with each channel of an r, g, b candidate: a grey scene solved with `solver.plan =
//! "full"` against a reference of the same scene, which models it with one channel. When B has `fluence_stderr.*` (a Monte-Carlo reference), only the
//! voxels where every component of the reference is > 0 with a relative standard error ≤
//! [`CompareOptions::max_relative_stderr`] are compared: elsewhere the reference is too noisy to
//! judge the candidate by. Otherwise every voxel is compared. Voxels either side left unsolved are
//! skipped and counted apart: those of a 16³ brick that is NaN throughout, in a field whose json
//! carries the `not_solved` note (`lpm solve` does not solve empty bricks). Any other NaN or
//! infinity is garbage in a solved voxel and fails the comparison ([`CompareError::NonFinite`]):
//! it is never passed off as "not solved".
//! Over the compared values (all
//! components): relative L2 ‖a−b‖/‖b‖, RMSE, max relative error |a−b|/|b| and mean bias
//! mean(a−b)/mean(b) ([`Metrics`]).
//!
//! **Dense core.** Given the scene's density ([`CompareOptions::core`]), the same metrics are also
//! computed over the voxels at or above a density quantile (the densest 10 % of the medium by
//! default): the whole-medium figure is dominated by thin, easy voxels.
//!
//! **Images.** When both have `image.exr` of the same size, the same metrics over all pixels and
//! r, g, b, over the means of 4 × 4-pixel blocks, and over the blocks the medium covers (the
//! candidate's alpha, 1 − transmittance, averaging ≥ 0.5 there); otherwise a note says why the
//! images were not compared.
//!
//! [`Comparison`] serialises to JSON ([`write_comparison_json`]) and displays as a short text table.

mod image;
mod metrics;
mod text;

pub use metrics::Metrics;

use crate::output::{self, OutputError};
use metrics::Accumulator;
use serde::Serialize;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// What [`compare_dirs`] counts.
#[derive(Clone, Debug, PartialEq)]
pub struct CompareOptions {
    /// Reference values with a larger relative standard error are left out (when the reference has
    /// `fluence_stderr.*`). Must be ≥ 0; infinity keeps every voxel with fluence > 0.
    pub max_relative_stderr: f64,
    /// The dense core: when set, the voxels whose density is at or above this quantile of the
    /// medium's (non-zero) densities are also compared on their own ([`CoreComparison`]). A
    /// whole-medium figure is dominated by the many thin, easy voxels and hides the core's error.
    pub core: Option<CoreMask>,
}

/// The density of every voxel (x fastest) and the quantile that starts the dense core.
#[derive(Clone, Debug, PartialEq)]
pub struct CoreMask {
    pub density: Vec<f32>,
    /// In [0, 1): 0.9 takes the densest 10 % of the medium's voxels.
    pub quantile: f64,
}

impl Default for CompareOptions {
    fn default() -> Self {
        CompareOptions { max_relative_stderr: 0.05, core: None }
    }
}

/// The default core quantile of `lpm compare --scene` and `lpm bench accuracy`.
pub const DEFAULT_CORE_QUANTILE: f64 = 0.9;

#[derive(Debug, Error)]
pub enum CompareError {
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error("{} and {} cannot be compared: {message}", a.display(), b.display())]
    Mismatch { a: PathBuf, b: PathBuf, message: String },
    #[error("{}: cannot read the EXR image: {message}", path.display())]
    Image { path: PathBuf, message: String },
    #[error("the maximum relative standard error must be a number ≥ 0, not {0}")]
    BadThreshold(f64),
    #[error("the core quantile must be in [0, 1), not {0}")]
    BadQuantile(f64),
    #[error("{}: {count} non-finite value(s) in solved voxels, the first at voxel ({}, {}, {}): {value}; \
             the field is garbage and cannot be compared", path.display(), voxel[0], voxel[1], voxel[2])]
    NonFinite { path: PathBuf, count: u64, voxel: [u32; 3], value: f32 },
}

/// Everything `lpm compare` reports.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Comparison {
    /// Directory A.
    pub candidate: String,
    /// Directory B.
    pub reference: String,
    pub fluence: FluenceComparison,
    /// `None` when the images were not compared (see `notes`).
    pub image: Option<ImageComparison>,
    /// Why something was left out, in plain words.
    pub notes: Vec<String>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FluenceComparison {
    pub dims: [u32; 3],
    /// Components compared per voxel (the candidate's).
    pub components: u32,
    /// The threshold applied when the reference has standard errors; `None` when it has none.
    pub max_relative_stderr: Option<f64>,
    pub voxels_total: u64,
    pub voxels_used: u64,
    /// Left out: unsolved on either side, or the reference too noisy there.
    pub voxels_excluded: u64,
    /// Of the excluded: unsolved (NaN) in the candidate or the reference (empty bricks).
    #[serde(default)]
    pub voxels_not_solved: u64,
    pub metrics: Metrics,
    /// √(Σ σ²)/‖b‖ over the values compared: the relative L2 difference a perfect candidate would
    /// show from the reference's own Monte-Carlo noise (`None` without standard errors).
    pub reference_noise_relative_l2: Option<f64>,
    /// √(max(0, rel. L2² − noise²)): the relative L2 error with the reference's noise taken out
    /// (in expectation); meaningful when clearly above zero.
    pub noise_corrected_relative_l2: Option<f64>,
    /// The same over the dense core only (when a density was given).
    pub core: Option<CoreComparison>,
}

/// The comparison restricted to the dense core (see [`CompareOptions::core`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CoreComparison {
    pub quantile: f64,
    /// Voxels with at least this density are in the core.
    pub density_threshold: f32,
    /// Core voxels compared (the same exclusions as the whole medium apply).
    pub voxels_used: u64,
    pub metrics: Metrics,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImageComparison {
    pub width: u32,
    pub height: u32,
    /// Over every pixel and r, g, b.
    pub metrics: Metrics,
    /// Edge of the blocks below, in pixels.
    pub block: u32,
    /// Over the block × block means of r, g, b: what a Monte-Carlo reference's pixel noise does
    /// not swamp.
    pub blocks: Metrics,
    /// Over the blocks where the candidate's alpha averages ≥ 0.5: the medium, not the sky around
    /// it.
    pub medium_blocks: Metrics,
}

/// Compares candidate directory `a` against reference directory `b`.
pub fn compare_dirs(a: &Path, b: &Path, opts: &CompareOptions) -> Result<Comparison, CompareError> {
    let threshold = opts.max_relative_stderr;
    if threshold.is_nan() || threshold < 0.0 {
        return Err(CompareError::BadThreshold(threshold));
    }
    let (info_a, values_a) = output::read_raw_field(a, "fluence")?;
    let (info_b, values_b) = output::read_raw_field(b, "fluence")?;
    let mismatch = |what: &str, x: String, y: String, file_b: &str| CompareError::Mismatch {
        a: a.join("fluence.json"),
        b: b.join(file_b),
        message: format!("{what} {x} against {y}"),
    };
    if info_a.dims != info_b.dims {
        return Err(mismatch("dims", format!("{:?}", info_a.dims), format!("{:?}", info_b.dims), "fluence.json"));
    }
    let mut notes = Vec::new();
    let broadcast = grey_against_rgb(&info_a.component_names, &info_b.component_names);
    if broadcast {
        notes.push("the reference is grey: each of the candidate's r, g, b channels is compared with it".into());
    } else if info_a.components != info_b.components {
        let (x, y) = (info_a.components.to_string(), info_b.components.to_string());
        return Err(mismatch("components", x, y, "fluence.json"));
    }
    // Values per voxel in the candidate and the reference, and the reference value each candidate
    // component is compared with.
    let (ca, c) = (info_a.components as usize, info_b.components as usize);
    let ref_of = |k: usize| if broadcast { 0 } else { k };
    let voxels_total = values_b.len() as u64 / c as u64;

    let stderr = if b.join("fluence_stderr.json").exists() {
        let (info_s, se) = output::read_raw_field(b, "fluence_stderr")?;
        if info_s.dims != info_b.dims || info_s.components != info_b.components {
            return Err(CompareError::Mismatch {
                a: b.join("fluence.json"),
                b: b.join("fluence_stderr.json"),
                message: format!(
                    "the fluence is {:?} × {} component(s), its standard error {:?} × {}",
                    info_b.dims, info_b.components, info_s.dims, info_s.components
                ),
            });
        }
        Some(se)
    } else {
        None
    };
    let core_threshold = match &opts.core {
        Some(core) => {
            if core.density.len() as u64 != voxels_total {
                return Err(CompareError::Mismatch {
                    a: a.join("fluence.json"),
                    b: b.join("fluence.json"),
                    message: format!("the density has {} voxels, the fluence {voxels_total}", core.density.len()),
                });
            }
            if !(0.0..1.0).contains(&core.quantile) {
                return Err(CompareError::BadQuantile(core.quantile));
            }
            Some(density_quantile(&core.density, core.quantile))
        }
        None => None,
    };
    let mut core_acc = Accumulator::default();
    let mut core_used = 0u64;
    let mut acc = Accumulator::default();
    let mut used = 0u64;
    let mut not_solved = 0u64;
    let (unsolved_a, unsolved_b) = (not_solved_mask(&info_a, &values_a), not_solved_mask(&info_b, &values_b));
    let mut garbage: Option<CompareError> = None;
    let mut garbage_count = 0u64;
    let (mut noise_sq, mut ref_sq) = (0.0f64, 0.0f64);
    for (v, (va, vb)) in values_a.chunks_exact(ca).zip(values_b.chunks_exact(c)).enumerate() {
        if unsolved_a.get(v).copied().unwrap_or(false) || unsolved_b.get(v).copied().unwrap_or(false) {
            not_solved += 1;
            continue;
        }
        for (dir, values) in [(a, va), (b, vb)] {
            if let Some(&value) = values.iter().find(|x| !x.is_finite()) {
                garbage_count += 1;
                let [nx, ny, _] = info_b.dims.map(|d| d as usize);
                let voxel = [v % nx, (v / nx) % ny, v / (nx * ny)].map(|c| c as u32);
                garbage.get_or_insert(CompareError::NonFinite {
                    path: dir.join("fluence.raw"),
                    count: 0,
                    voxel,
                    value,
                });
            }
        }
        if garbage.is_some() {
            continue;
        }
        let keep = match &stderr {
            // A NaN standard error and a fluence ≤ 0 both exclude the voxel.
            Some(se) => (0..c).all(|k| vb[k] > 0.0 && (se[v * c + k] as f64) <= threshold * vb[k] as f64),
            None => true,
        };
        if keep {
            used += 1;
            va.iter().enumerate().for_each(|(k, &x)| acc.add(x, vb[ref_of(k)]));
            if let (Some(t), Some(core)) = (core_threshold, &opts.core) {
                if core.density[v] >= t && core.density[v] > 0.0 {
                    core_used += 1;
                    va.iter().enumerate().for_each(|(k, &x)| core_acc.add(x, vb[ref_of(k)]));
                }
            }
            if let Some(se) = &stderr {
                for k in 0..ca {
                    noise_sq += (se[v * c + ref_of(k)] as f64).powi(2);
                    ref_sq += (vb[ref_of(k)] as f64).powi(2);
                }
            }
        }
    }
    if let Some(CompareError::NonFinite { path, voxel, value, .. }) = garbage {
        return Err(CompareError::NonFinite { path, count: garbage_count, voxel, value });
    }
    if used == 0 {
        notes.push(
            "no voxel was compared: the reference has no voxel with fluence > 0 and a small enough standard error"
                .into(),
        );
    }
    let metrics = acc.finish();
    let noise = (stderr.is_some() && ref_sq > 0.0).then(|| (noise_sq / ref_sq).sqrt());
    let corrected = match (metrics.relative_l2, noise) {
        (Some(l2), Some(n)) => Some((l2 * l2 - n * n).max(0.0).sqrt()),
        _ => None,
    };
    let fluence = FluenceComparison {
        dims: info_b.dims,
        components: info_a.components,
        max_relative_stderr: stderr.is_some().then_some(threshold),
        voxels_total,
        voxels_used: used,
        voxels_excluded: voxels_total - used,
        voxels_not_solved: not_solved,
        metrics,
        reference_noise_relative_l2: noise,
        noise_corrected_relative_l2: corrected,
        core: match (&opts.core, core_threshold) {
            (Some(core), Some(t)) => Some(CoreComparison {
                quantile: core.quantile,
                density_threshold: t,
                voxels_used: core_used,
                metrics: core_acc.finish(),
            }),
            _ => None,
        },
    };
    let image = image::compare_images(a, b, &mut notes)?;
    Ok(Comparison { candidate: a.display().to_string(), reference: b.display().to_string(), fluence, image, notes })
}

/// The `q`-quantile of the non-zero densities (the lower one of the two around it); 0 when the
/// volume is empty.
pub fn density_quantile(density: &[f32], q: f64) -> f32 {
    let mut medium: Vec<f32> = density.iter().copied().filter(|&d| d > 0.0).collect();
    if medium.is_empty() {
        return 0.0;
    }
    medium.sort_by(f32::total_cmp);
    let i = ((medium.len() - 1) as f64 * q).floor() as usize;
    medium[i]
}

/// Per voxel: true when it was not solved, i.e. the field's json carries the `not_solved` note and
/// the voxel's whole 16³ brick is NaN in every component (how `lpm solve` exports an empty brick).
/// A NaN anywhere else is not "not solved" but garbage.
fn not_solved_mask(info: &output::FieldInfo, values: &[f32]) -> Vec<bool> {
    if info.not_solved.is_none() {
        return Vec::new();
    }
    let grid = crate::store::BrickGrid::new(info.dims);
    let c = info.components as usize;
    let [nx, ny, _] = info.dims.map(|d| d as usize);
    let brick_of = |v: usize| {
        let (x, y, z) = (v % nx, (v / nx) % ny, v / (nx * ny));
        grid.brick_index([x, y, z].map(|q| (q / 16) as u32))
    };
    let mut all_nan = vec![true; grid.brick_count()];
    for (v, vals) in values.chunks_exact(c).enumerate() {
        if !vals.iter().all(|x| x.is_nan()) {
            all_nan[brick_of(v)] = false;
        }
    }
    (0..values.len() / c.max(1)).map(|v| all_nan[brick_of(v)]).collect()
}

impl Comparison {
    /// Why the comparison fails a `--fail-above max` check: the fluence's relative L2 error is
    /// above `max`, or no voxel could be compared; `None` when it passes.
    pub fn exceeds(&self, max: f64) -> Option<String> {
        match self.fluence.metrics.relative_l2 {
            None => Some("no voxel was compared, so the error is unknown".to_string()),
            Some(e) if e.is_nan() || e > max => {
                Some(format!("the fluence's relative L2 error {e:.3e} is above the limit {max:e}"))
            }
            Some(_) => None,
        }
    }
}

/// Writes `comparison` as pretty JSON to `path`, atomically.
pub fn write_comparison_json(path: &Path, comparison: &Comparison) -> Result<(), OutputError> {
    output::write_json_atomic(path, comparison)
}

/// True when the reference is grey and the candidate has r, g, b channels: a grey scene solved
/// with `solver.plan = "full"`, whose three channels each stand for the reference's one.
fn grey_against_rgb(candidate: &[String], reference: &[String]) -> bool {
    reference == ["grey"] && candidate == ["r", "g", "b"]
}
