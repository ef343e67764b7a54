//! The same medium on a finer grid, for `lpm bench refine` ([`super::refine`]): a copy of a scene
//! file with its volume refined by an integer factor f (dims × f, voxel_size / f, the origin and
//! so the world extent unchanged) and the solver settings of one run of the study.
//!
//! How the medium is carried to the finer grid:
//! * a **procedural** volume is generated again at the finer dims: every shape is a function of
//!   voxel-normalised coordinates (`scene::procedural`), so it is the same continuous medium
//!   sampled more finely (the sphere's staircase and the cloud's voxel samples move with the grid),
//!   so the study measures the medium's sampling error with the solver's; or, asked to
//!   (`replicate`), replicated as a file volume is, which leaves the solver's error alone;
//! * any **file** volume (raw, OpenVDB, NanoVDB, NRRD) is read as the solver reads it and written as
//!   a raw file with each voxel replicated f³ times: a piecewise-constant medium, exactly the same
//!   medium on the finer grid;
//! * a per-voxel **emission, temperature or albedo** raw file is replicated f³ times in the same
//!   way; a per-voxel grid of the VDB file (`*_grid`) is refused with an error that says how to
//!   state it instead (as a raw file).
//!
//! Relative paths that stay in the copy (an environment map) are made absolute, since the copy
//! lives in the run's directory, not beside the scene.

use super::refine::RefineError;
use crate::scene::{AlbedoGrid, EmissionGrid, Scene, VolumeSource};
use std::path::{Path, PathBuf};
use toml::Value;

/// The solver keys one run of the refinement study sets (`None`: the scene's own).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SolverKeys {
    pub directions_per_face: Option<u32>,
    pub tolerance: f64,
    pub max_orders: Option<u32>,
    /// `solver.spatial`, by its scene-file name.
    pub spatial: Option<String>,
    /// `solver.diffusion_correction`, by its scene-file name.
    pub diffusion_correction: Option<String>,
}

/// `values` (x fastest, `dims`) with every voxel replicated `factor`³ times: the same
/// piecewise-constant field on a grid `factor` times finer along each axis.
pub fn replicate(values: &[f32], dims: [u32; 3], factor: u32) -> Vec<f32> {
    let [nx, ny, nz] = dims.map(|d| d as usize);
    let f = factor as usize;
    let mut out = Vec::with_capacity(values.len() * f * f * f);
    for z in 0..nz * f {
        for y in 0..ny * f {
            let row = &values[(z / f * ny + y / f) * nx..][..nx];
            for &v in row {
                out.extend(std::iter::repeat_n(v, f));
            }
        }
    }
    out
}

/// Writes `dir/scene.toml`: the scene at `scene_path` (loaded as `loaded`) refined by `factor`,
/// with `keys` set, and beside it the replicated raw files it needs. A procedural volume is
/// generated at the finer dims, or with `replicate` replicated like a file volume. Returns the
/// copy's path.
pub fn write_refined_scene(
    scene_path: &Path,
    loaded: &Scene,
    dir: &Path,
    factor: u32,
    replicate_procedural: bool,
    keys: &SolverKeys,
) -> Result<PathBuf, RefineError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| RefineError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    // The copy names the files written beside it by absolute path: the loader resolves a relative
    // one against the copy's own directory, not against the working directory.
    let dir = &std::path::absolute(dir).map_err(io(dir))?;
    let text = std::fs::read_to_string(scene_path).map_err(io(scene_path))?;
    let mut value: Value = text.parse().map_err(|e: toml::de::Error| RefineError::Scene {
        path: scene_path.to_path_buf(),
        key: String::new(),
        message: e.to_string(),
    })?;
    let unsupported = |key: &str, message: &str| RefineError::Scene {
        path: scene_path.to_path_buf(),
        key: key.to_string(),
        message: message.to_string(),
    };
    let Some(table) = value.as_table_mut() else {
        return Err(unsupported("", "the scene is not a TOML table"));
    };
    let v = &loaded.volume;
    let dims = v.dims.map(|d| d * factor);
    let volume = table
        .get_mut("volume")
        .and_then(Value::as_table_mut)
        .ok_or_else(|| unsupported("volume", "no [volume] table"))?;
    for key in ["emission_grid", "temperature_grid", "albedo_grid"] {
        if volume.contains_key(key) {
            return Err(unsupported(
                &format!("volume.{key}"),
                "a per-voxel grid of the VDB file cannot be refined: write it as a raw file \
                 (emission_raw, temperature_raw or albedo_raw) to run the refinement study",
            ));
        }
    }
    volume.insert("dims".into(), Value::Array(dims.iter().map(|&d| Value::Integer(d.into())).collect()));
    volume.insert("voxel_size".into(), Value::Float(v.voxel_size / factor as f64));
    volume.insert("origin".into(), Value::Array(v.origin.to_array().iter().map(|&o| Value::Float(o)).collect()));
    if replicate_procedural || !matches!(v.source, VolumeSource::Procedural { .. }) {
        // As the solver reads it, replicated into a raw file.
        let scratch = dir.join("density-scratch");
        let density = crate::solver::density_volume(loaded, &scratch).map_err(crate::job::JobError::from)?;
        let raw = dir.join("density.raw");
        write_raw(&raw, &replicate(&density, v.dims, factor))?;
        for key in ["procedural", "seed", "vdb", "nvdb", "nrrd", "grid", "raw"] {
            volume.remove(key);
        }
        volume.insert("raw".into(), Value::String(raw.display().to_string()));
    }
    let raw_grid = |key: &str, path: &Path| -> Result<Value, RefineError> {
        let values = read_raw(path, v.dims)?;
        let out = dir.join(format!("{key}.raw"));
        write_raw(&out, &replicate(&values, v.dims, factor))?;
        Ok(Value::String(out.display().to_string()))
    };
    match &v.emission {
        Some(EmissionGrid::Raw { path }) => {
            volume.insert("emission_raw".into(), raw_grid("emission", path)?);
        }
        Some(EmissionGrid::TemperatureRaw { path, .. }) => {
            volume.insert("temperature_raw".into(), raw_grid("temperature", path)?);
        }
        _ => {}
    }
    if let Some(AlbedoGrid::Raw { path }) = &v.albedo {
        volume.insert("albedo_raw".into(), raw_grid("albedo", path)?);
    }
    // An environment map named relative to the scene file: absolute, as the loader resolved it
    // (the volume's files were all rewritten above).
    let base = scene_path.parent().unwrap_or_else(|| Path::new(""));
    crate::scene::make_file_paths_absolute(table, base, &crate::scene::VOLUME_FILE_KEYS);
    let solver = table.entry("solver").or_insert_with(|| Value::Table(Default::default()));
    if let Some(solver) = solver.as_table_mut() {
        solver.insert("tolerance".into(), Value::Float(keys.tolerance));
        if let Some(k) = keys.directions_per_face {
            super::set_directions_per_face(solver, k);
        }
        if let Some(cap) = keys.max_orders {
            solver.insert("max_orders".into(), Value::Integer(cap.into()));
        }
        if let Some(s) = &keys.spatial {
            solver.insert("spatial".into(), Value::String(s.clone()));
        }
        if let Some(d) = &keys.diffusion_correction {
            solver.insert("diffusion_correction".into(), Value::String(d.clone()));
        }
    }
    let copy = dir.join("scene.toml");
    // `Value::to_string` writes an inline table; serialise as a document instead.
    let text = toml::to_string(&value).map_err(|e| RefineError::Scene {
        path: copy.clone(),
        key: String::new(),
        message: e.to_string(),
    })?;
    crate::output::write_atomic(&copy, |w| std::io::Write::write_all(w, text.as_bytes()))?;
    Ok(copy)
}

/// A raw little-endian f32 file of `dims` voxels (the validator has checked its size).
fn read_raw(path: &Path, dims: [u32; 3]) -> Result<Vec<f32>, RefineError> {
    let bytes = std::fs::read(path).map_err(|source| RefineError::Io { path: path.to_path_buf(), source })?;
    let voxels = dims.iter().map(|&d| d as usize).product::<usize>();
    if bytes.len() != voxels * 4 {
        return Err(RefineError::Scene {
            path: path.to_path_buf(),
            key: String::new(),
            message: format!("{} bytes, but {dims:?} voxels of f32 need {}", bytes.len(), voxels * 4),
        });
    }
    Ok(bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect())
}

/// Writes `values` as little-endian f32, atomically.
fn write_raw(path: &Path, values: &[f32]) -> Result<(), RefineError> {
    crate::output::write_atomic(path, |w| {
        values.iter().try_for_each(|v| std::io::Write::write_all(w, &v.to_le_bytes()))
    })?;
    Ok(())
}
