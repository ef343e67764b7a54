//! A reference job from start to finish (`lpm reference`): read the scene, sample its densities, run
//! the Monte-Carlo reference ([`super::run`]) and write its outputs beside the same names `lpm solve`
//! uses, so the two directories can be compared file by file ([`crate::compare`]).
//!
//! Outputs (in `out`):
//! - `fluence.raw/.json/.nhdr`: the mean fluence, in the exported layout of [`crate::output`]
//!   (component fastest, then x, y, z; 1 component when the medium and every light are grey, else r, g, b);
//! - `fluence_stderr.raw/.json/.nhdr`: the standard error of each value of `fluence.raw`, same layout;
//! - `image.exr` / `image.png` when image samples are asked for, framed by the scene's camera or
//!   [`render::default_camera`] exactly like the image of `lpm solve`, the EXR's alpha the
//!   medium's opacity along each pixel's centre ray as lpm's renderer has it (what
//!   [`crate::compare`] takes the medium's blocks from);
//! - `report.json` ([`ReferenceReport`]).
//!
//! Nothing is left half-written: the scene is validated before anything is created, every file is
//! written into a staging directory inside `out` and only renamed into `out` once all of them are
//! complete; on failure the staging directory (and `out`, when this job created it) is removed, and
//! files already in `out` keep their old content.

use super::{Orders, ReferenceOptions, ReferenceResult};
use crate::output::{self, FieldMeta, OutputError};
use crate::render::{self, Image};
use crate::scene::{procedural, AlbedoGrid, EmissionGrid, Scene, SceneError, Shape, VolumeSource};
use crate::store::{self, BrickGrid, StoreError, BRICK_VOXELS};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;
use thiserror::Error;

/// What `lpm reference` runs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ReferenceJob {
    pub scene: PathBuf,
    pub out: PathBuf,
    /// Photons per channel (≥ 1), rounded up to a multiple of the batch count.
    pub photons: u64,
    pub seed: u64,
    /// Worker threads; 0 = all available.
    pub threads: usize,
    /// Camera samples per pixel; 0 = no image.
    pub image_samples_per_pixel: u32,
    /// The scattering orders the image counts ([`Orders::ALL`]: the whole image).
    pub image_orders: Orders,
}

#[derive(Debug, Error)]
pub enum ReferenceJobError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error("cannot create output directory {path}: {source}")]
    OutputDir { path: PathBuf, source: std::io::Error },
    #[error("the number of photons must be at least 1")]
    NoPhotons,
    #[error("scattering orders were chosen for the image, but no image is made (give camera paths per pixel)")]
    OrdersWithoutImage,
}

/// `report.json` of a reference job.
#[derive(Clone, Debug, Serialize)]
pub struct ReferenceReport {
    pub lpm_version: &'static str,
    pub scene: String,
    /// Always "monte-carlo".
    pub method: &'static str,
    pub dims: [u32; 3],
    /// Photons traced per channel.
    pub photons: u64,
    pub seed: u64,
    /// Independent batches behind the standard errors.
    pub batches: u32,
    pub image_samples_per_pixel: u32,
    /// The scattering orders the image counts (`last` null: no upper bound); absent: all of them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub image_orders: Option<Orders>,
    /// Wall-clock seconds of the whole job (sampling, transport, image, writing).
    pub seconds: f64,
    pub channels: u32,
    /// Mean of standard error / fluence over the values with fluence > 0; `None` when there are none.
    pub mean_relative_std_error: Option<f64>,
    /// Per face of the volume, the power (W) the photons carried out through it, per channel, with
    /// its standard error: what `lpm solve`'s `energy.faces[].power_out` gives (reflectance and
    /// transmittance of a slab follow from them and the light's power in).
    pub faces: Vec<FaceOut>,
    pub outputs: Vec<String>,
}

/// The faces in the order of `lpm solve`'s report (named here: the reference takes nothing from the
/// solver).
const FACES: [&str; 6] = ["-x", "+x", "-y", "+y", "-z", "+z"];

/// One face's outgoing power in a reference report.
#[derive(Clone, Debug, Serialize)]
pub struct FaceOut {
    /// "-x", "+x", "-y", "+y", "-z" or "+z".
    pub face: &'static str,
    /// Per channel.
    pub power_out: Vec<f64>,
    pub std_error: Vec<f64>,
}

/// Runs the job and returns what it wrote to `report.json`.
pub fn run(job: &ReferenceJob) -> Result<ReferenceReport, ReferenceJobError> {
    let start = Instant::now();
    if job.photons == 0 {
        return Err(ReferenceJobError::NoPhotons);
    }
    if job.image_orders != Orders::ALL && job.image_samples_per_pixel == 0 {
        return Err(ReferenceJobError::OrdersWithoutImage);
    }
    let scene = Scene::load(&job.scene)?;
    let created_out = !job.out.exists();
    std::fs::create_dir_all(&job.out)
        .map_err(|source| ReferenceJobError::OutputDir { path: job.out.clone(), source })?;
    let stage = job.out.join(format!(".reference.tmp-{}", std::process::id()));
    let result = std::fs::create_dir_all(&stage)
        .map_err(|source| ReferenceJobError::OutputDir { path: stage.clone(), source })
        .and_then(|()| run_in(job, &scene, &stage, start))
        .and_then(|report| {
            publish(&stage, &job.out, &report.outputs)?;
            Ok(report)
        });
    let _ = std::fs::remove_dir_all(&stage);
    if result.is_err() && created_out {
        // Only removes it when empty: never anything this job did not create.
        let _ = std::fs::remove_dir(&job.out);
    }
    result
}

/// Samples, runs and writes every output into `stage`.
fn run_in(
    job: &ReferenceJob,
    scene: &Scene,
    stage: &Path,
    start: Instant,
) -> Result<ReferenceReport, ReferenceJobError> {
    let dims = scene.volume.dims;
    let h = scene.volume.voxel_size;
    let grey = scene.is_grey();
    let channels = if grey { 1 } else { 3 };
    // The reference frames its image with the scene's camera; give it the renderer's default view so
    // the two images match pixel for pixel.
    let mut scene = scene.clone();
    if scene.camera.is_none() {
        scene.camera = Some(render::default_camera(dims, h));
    }
    let opts = ReferenceOptions {
        photons: job.photons,
        seed: job.seed,
        threads: job.threads,
        image_samples_per_pixel: job.image_samples_per_pixel,
        image_orders: job.image_orders,
        ..ReferenceOptions::default()
    };
    // A per-voxel emission, read from the scene's files as the densities are (not from lpm's store).
    let emission = match &scene.volume.emission {
        None => None,
        Some(grid) => Some(emission_factors(job, &scene, grid)?),
    };
    let emission = emission.as_ref().map(|values| dense_lookup_rgb(values, dims));
    let emission = emission.as_ref().map(|f| f as &(dyn Fn([u32; 3]) -> [f32; 3] + Sync));
    // A per-voxel albedo factor, read from the scene's files the same way.
    let albedo = match &scene.volume.albedo {
        None => None,
        Some(grid) => Some(albedo_factors(job, &scene, grid)?),
    };
    let albedo = albedo.map(|values| dense_lookup(values, dims));
    let albedo = albedo.as_ref().map(|f| f as &(dyn Fn([u32; 3]) -> f32 + Sync));
    let fields = super::VoxelFields { emission, albedo };
    let result = match &scene.volume.source {
        VolumeSource::Procedural { shape, seed } => {
            let (shape, seed): (Shape, u64) = (*shape, *seed);
            super::run_with_fields(&scene, &|v| procedural::density(shape, seed, dims, v), fields, channels, &opts)
        }
        VolumeSource::Raw { path } => {
            let at = dense_lookup(raw_densities(path, dims)?, dims);
            super::run_with_fields(&scene, &at, fields, channels, &opts)
        }
        VolumeSource::Vdb { path, grid, index_min } => {
            let vdb = crate::store::vdb::vdb_density(path, grid, dims, *index_min)?;
            let tree = &vdb.grid().tree;
            let at = |v: [u32; 3]| tree.value(std::array::from_fn(|i| index_min[i] + v[i] as i32));
            super::run_with_fields(&scene, &at, fields, channels, &opts)
        }
        VolumeSource::Nrrd { path } => {
            let header = store::nrrd_input::nrrd_header(path)?;
            let mut values = Vec::new();
            store::nrrd_input::decode(path, &header, |v| {
                values.extend_from_slice(v);
                Ok(())
            })?;
            let at = dense_lookup(values, dims);
            super::run_with_fields(&scene, &at, fields, channels, &opts)
        }
    };
    let outputs = write_outputs(&result, h, &scene, stage)?;
    let report = ReferenceReport {
        lpm_version: env!("CARGO_PKG_VERSION"),
        scene: job.scene.display().to_string(),
        method: "monte-carlo",
        dims,
        photons: result.photons,
        seed: job.seed,
        batches: opts.batches.max(2),
        image_samples_per_pixel: job.image_samples_per_pixel,
        image_orders: (job.image_orders != Orders::ALL).then_some(job.image_orders),
        seconds: start.elapsed().as_secs_f64(),
        channels: result.channels,
        mean_relative_std_error: mean_relative(&result.fluence, &result.std_error),
        faces: FACES
            .iter()
            .enumerate()
            .map(|(f, &face)| FaceOut {
                face,
                power_out: result.face_out.iter().map(|c| c[f].0).collect(),
                std_error: result.face_out.iter().map(|c| c[f].1).collect(),
            })
            .collect(),
        outputs,
    };
    output::write_json_atomic(&stage.join("report.json"), &report)?;
    Ok(report)
}

/// A scene's per-voxel emission factors, every voxel (x fastest): a grey grid's values in every
/// channel, or a temperature grid's blackbody factors (with the store's checks and messages).
fn emission_factors(
    job: &ReferenceJob,
    scene: &Scene,
    grid: &EmissionGrid,
) -> Result<Vec<[f32; 3]>, ReferenceJobError> {
    let dims = scene.volume.dims;
    let label = store::emission::field_label(grid);
    let bad = |e: StoreError| if grid.blackbody().is_some() { e.into_temperature(&label) } else { e.into_emission() };
    let (values, path) = match (grid.raw_path(), grid.vdb_grid(), &scene.volume.source) {
        (Some(path), _, _) => (raw_densities(path, dims).map_err(bad)?, path.to_path_buf()),
        (None, Some(name), VolumeSource::Vdb { path, index_min, .. }) => {
            let values = vdb_grid_values(path, name, dims, *index_min)?;
            if let Some((i, &value)) = values.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v >= 0.0)) {
                let e = StoreError::BadDensity { path: path.clone(), voxel: voxel_of(i, dims), value };
                return Err(bad(e).into());
            }
            (values, path.clone())
        }
        (None, name, _) => {
            return Err(StoreError::Corrupt {
                path: job.scene.clone(),
                message: format!("emission grid \"{}\" needs a `vdb` volume", name.unwrap_or_default()),
            }
            .into())
        }
    };
    let Some(blackbody) = grid.blackbody() else {
        return Ok(values.into_iter().map(|e| [e; 3]).collect());
    };
    let map = crate::scene::blackbody::BlackbodyMap::new(blackbody);
    let max_emission = scene.medium.emission.iter().fold(0f64, |m, &v| m.max(v));
    values
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            store::emission::temperature_factors(&map, max_emission, t, voxel_of(i, dims), &path).map_err(Into::into)
        })
        .collect()
}

/// Every voxel's value (x fastest) of grid `name` in the VDB file `path`, over the volume's `dims`
/// from `index_min`.
fn vdb_grid_values(
    path: &Path,
    name: &str,
    dims: [u32; 3],
    index_min: [i32; 3],
) -> Result<Vec<f32>, ReferenceJobError> {
    let vdb = crate::store::vdb::vdb_grid_over(path, name, dims, index_min)?;
    let tree = &vdb.grid().tree;
    let mut values = Vec::with_capacity(dims.iter().map(|&d| d as usize).product());
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                values.push(tree.value(std::array::from_fn(|i| index_min[i] + [x, y, z][i] as i32)));
            }
        }
    }
    Ok(values)
}

/// The voxel at index `i` of an x-fastest array over `dims`.
fn voxel_of(i: usize, dims: [u32; 3]) -> [u32; 3] {
    let (nx, ny) = (dims[0] as usize, dims[1] as usize);
    [(i % nx) as u32, (i / nx % ny) as u32, (i / (nx * ny)) as u32]
}

/// A scene's per-voxel albedo factors, every voxel (x fastest), checked as the store checks them
/// (finite, in [0, 1]; the error names the file, the key or grid, and the voxel).
fn albedo_factors(job: &ReferenceJob, scene: &Scene, grid: &AlbedoGrid) -> Result<Vec<f32>, ReferenceJobError> {
    let dims = scene.volume.dims;
    let label = grid.label();
    let (values, path) = match (grid.raw_path(), grid.vdb_grid(), &scene.volume.source) {
        (Some(path), _, _) => (raw_densities(path, dims).map_err(|e| e.into_albedo(&label))?, path.to_path_buf()),
        (None, Some(name), VolumeSource::Vdb { path, index_min, .. }) => {
            (vdb_grid_values(path, name, dims, *index_min)?, path.clone())
        }
        (None, name, _) => {
            return Err(StoreError::Corrupt {
                path: job.scene.clone(),
                message: format!("albedo grid \"{}\" needs a `vdb` volume", name.unwrap_or_default()),
            }
            .into())
        }
    };
    for (i, &a) in values.iter().enumerate() {
        store::albedo::check_albedo(a, voxel_of(i, dims), &path, &label)?;
    }
    Ok(values)
}

/// [`dense_lookup`] of per-channel emission factors.
fn dense_lookup_rgb(values: &[[f32; 3]], dims: [u32; 3]) -> impl Fn([u32; 3]) -> [f32; 3] + Sync + '_ {
    let (nx, ny) = (dims[0] as usize, dims[1] as usize);
    move |v| values.get((v[2] as usize * ny + v[1] as usize) * nx + v[0] as usize).copied().unwrap_or([0.0; 3])
}

/// Voxel v of `values` (x fastest, `dims`); 0 past the end (a short array is caught by its reader).
fn dense_lookup(values: Vec<f32>, dims: [u32; 3]) -> impl Fn([u32; 3]) -> f32 + Sync {
    let (nx, ny) = (dims[0] as usize, dims[1] as usize);
    move |v| values.get((v[2] as usize * ny + v[1] as usize) * nx + v[0] as usize).copied().unwrap_or(0.0)
}

/// The densities of a raw volume file (x fastest), checked by the same importer as the solver's
/// (NaN, infinite or negative values are errors naming the voxel).
fn raw_densities(path: &Path, dims: [u32; 3]) -> Result<Vec<f32>, StoreError> {
    let raw = store::raw_density(path, dims)?;
    let grid = BrickGrid::new(dims);
    let [nx, ny, nz] = dims.map(|d| d as usize);
    let mut values = vec![0.0f32; nx * ny * nz];
    let mut brick = vec![0.0f32; BRICK_VOXELS];
    for b in 0..grid.brick_count() {
        let coords = grid.brick_coords(b);
        raw.fill_brick(coords, &mut brick)?;
        let o = grid.brick_origin(coords).map(|c| c as usize);
        let e = grid.brick_extent(coords).map(|c| c as usize);
        for z in 0..e[2] {
            for y in 0..e[1] {
                for x in 0..e[0] {
                    let i = ((o[2] + z) * ny + o[1] + y) * nx + o[0] + x;
                    values[i] = brick[store::local_index([x, y, z])];
                }
            }
        }
    }
    Ok(values)
}

/// Writes the fields and the image into `dir`; returns the names written, `report.json` last.
fn write_outputs(
    result: &ReferenceResult,
    voxel_size: f64,
    scene: &Scene,
    dir: &Path,
) -> Result<Vec<String>, OutputError> {
    let names: Vec<String> =
        if result.channels == 1 { vec!["grey".into()] } else { ["r", "g", "b"].map(String::from).to_vec() };
    let photons = result.photons;
    let fields = [
        (
            "fluence",
            &result.fluence,
            FieldMeta {
                quantity: "fluence".into(),
                units: "radiance units × sr (W/m² for radiance in W/m²/sr)".into(),
                components: names.clone(),
                description: format!(
                    "fluence φ = ∫L dω, all orders: Monte-Carlo reference (track-length estimator, {photons} photons per channel)"
                ),
                origin: scene.volume.origin.to_array(),
            },
        ),
        (
            "fluence_stderr",
            &result.std_error,
            FieldMeta {
                quantity: "fluence standard error".into(),
                units: "radiance units × sr (W/m² for radiance in W/m²/sr)".into(),
                components: names,
                description: "standard error of each value of fluence.raw, from the spread of the batch estimates".into(),
                origin: scene.volume.origin.to_array(),
            },
        ),
    ];
    let mut outputs = Vec::new();
    for (base, values, meta) in &fields {
        output::export_dense(values, result.dims, voxel_size, dir, base, meta)?;
        outputs.extend(["raw", "json", "nhdr"].map(|ext| format!("{base}.{ext}")));
    }
    if let Some(img) = &result.image {
        let image =
            Image { width: img.width, height: img.height, rgb: img.rgb.clone(), alpha: Some(img.alpha.clone()) };
        render::write_exr(&dir.join("image.exr"), &image)?;
        render::write_png(&dir.join("image.png"), &image, &scene.display)?;
        outputs.extend(["image.exr", "image.png"].map(String::from));
    }
    outputs.push("report.json".into());
    Ok(outputs)
}

/// Moves every staged output over its final name (each rename is atomic).
fn publish(stage: &Path, out: &Path, names: &[String]) -> Result<(), OutputError> {
    for name in names {
        let to = out.join(name);
        std::fs::rename(stage.join(name), &to).map_err(|source| OutputError::Io {
            path: to,
            action: "move into place",
            source,
        })?;
    }
    Ok(())
}

/// Mean of `se / value` over the values > 0.
fn mean_relative(values: &[f32], se: &[f32]) -> Option<f64> {
    let (sum, n) = values
        .iter()
        .zip(se)
        .filter(|(v, _)| **v > 0.0)
        .fold((0.0f64, 0usize), |(s, n), (v, e)| (s + *e as f64 / *v as f64, n + 1));
    (n > 0).then(|| sum / n as f64)
}
