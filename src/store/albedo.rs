//! The per-voxel albedo factor (`volume.albedo_raw` / `albedo_grid`): imported once into the store
//! beside the density, as field `albedo` (one component, occupied bricks only), and opened again by
//! the solver (which multiplies each order's scattered source by it, and counts absorption with
//! it), the renderer (the emission term σa(v)·Le) and checkpoints' resumes.
//!
//! The field holds `a(v)` ∈ [0, 1]: voxel v's albedo in channel c is `medium.albedo[c]·a(v)`. The
//! importers are the density's (raw files brick by brick, VDB grids leaf by leaf), so a sparse
//! albedo grid never becomes a dense array in memory; a value that is not finite or lies outside
//! [0, 1] is an error naming the file, the source of the values and the voxel.

use super::{BrickStore, Coverage, Field, StoreError, BRICK_VOXELS};
use crate::scene::{AlbedoGrid, VolumeSource};

/// Fills one brick (local x fastest) from an importer.
type FillBrick = Box<dyn Fn([u32; 3], &mut [f32]) -> Result<(), StoreError>>;

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
    let (fill, path): (FillBrick, std::path::PathBuf) = match (grid.raw_path(), grid.vdb_grid(), source) {
        (Some(path), _, _) => {
            let raw = super::import::raw_density(path, dims).map_err(|e| e.into_albedo(&label))?;
            (Box::new(move |b, out| raw.fill_brick(b, out)), path.to_path_buf())
        }
        (None, Some(name), VolumeSource::Vdb { path, index_min, .. }) => {
            let vdb = super::vdb::vdb_grid_over(path, name, dims, *index_min)?;
            (Box::new(move |b, out| vdb.fill_brick(b, out)), path.clone())
        }
        (None, name, _) => {
            return Err(StoreError::Corrupt {
                path: store.dir().to_path_buf(),
                message: format!("albedo grid \"{}\" needs a `vdb` volume", name.unwrap_or_default()),
            })
        }
    };
    let bricks: Vec<usize> = store.occupied_bricks().collect();
    let mut values = vec![0f32; BRICK_VOXELS];
    for brick in bricks {
        let coords = store.grid().brick_coords(brick);
        fill(coords, &mut values).map_err(|e| e.into_albedo(&label))?;
        let origin = store.grid().brick_origin(coords);
        for (l, &a) in values.iter().enumerate() {
            // Local index l = x + 16·(y + 16·z) (see store::grid::local_index).
            let voxel = [origin[0] + (l % 16) as u32, origin[1] + (l / 16 % 16) as u32, origin[2] + (l / 256) as u32];
            check_albedo(a, voxel, &path, &label)?;
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
