//! The per-voxel albedo factor (`volume.albedo_raw` / `albedo_grid`): imported once into the store
//! beside the density, as field `albedo` (one component, occupied bricks only), and opened again by
//! the solver (which multiplies each order's scattered source by it, and counts absorption with
//! it), the renderer (the emission term σa(v)·Le) and checkpoints' resumes.
//!
//! The field holds `a(v)` ∈ [0, 1]: voxel v's albedo in channel c is `medium.albedo[c]·a(v)`. The
//! importers are the density's (raw files brick by brick, VDB grids leaf by leaf), so a sparse
//! albedo grid never becomes a dense array in memory; a value that is not finite or lies outside
//! [0, 1] is an error naming the file, the source of the values and the voxel.

use super::import::voxel_grid_importer;
use super::{brick_voxel, BrickStore, Coverage, Field, StoreError, BRICK_VOXELS};
use crate::scene::{AlbedoGrid, VolumeSource};

/// Name of the albedo field in the store.
pub const ALBEDO_FIELD: &str = "albedo";

/// `value` checked as an albedo factor of `voxel` (finite, in [0, 1]).
pub fn check_albedo(value: f32, voxel: [u32; 3], path: &std::path::Path, label: &str) -> Result<f32, StoreError> {
    if (0.0..=1.0).contains(&value) {
        Ok(value)
    } else {
        Err(StoreError::BadAlbedo { path: path.to_path_buf(), field: label.to_string(), voxel, value })
    }
}

/// Fills the store's albedo field from `grid` (over the volume `source` of the store's dims).
pub fn import_albedo(store: &BrickStore, grid: &AlbedoGrid, source: &VolumeSource) -> Result<Field, StoreError> {
    let dims = store.grid().dims;
    let label = grid.label();
    let mut field = store.create_field(ALBEDO_FIELD, 1, Coverage::Occupied)?;
    let (fill, path) = voxel_grid_importer(grid.raw_path(), grid.vdb_grid(), source, dims, store.dir(), "albedo")
        .map_err(|e| e.into_albedo(&label))?;
    let bricks: Vec<usize> = store.occupied_bricks().collect();
    let mut values = vec![0f32; BRICK_VOXELS];
    for brick in bricks {
        let coords = store.grid().brick_coords(brick);
        fill(coords, &mut values).map_err(|e| e.into_albedo(&label))?;
        let origin = store.grid().brick_origin(coords);
        for (l, &a) in values.iter().enumerate() {
            check_albedo(a, brick_voxel(origin, l), &path, &label)?;
        }
        let Some(dst) = field.brick_mut(brick) else { continue };
        dst.copy_from_slice(&values);
    }
    field.flush()?;
    Ok(field)
}

/// Opens the albedo field a previous [`import_albedo`] wrote.
pub fn open_albedo(store: &BrickStore) -> Result<Field, StoreError> {
    store.open_field(ALBEDO_FIELD, 1, Coverage::Occupied)
}
