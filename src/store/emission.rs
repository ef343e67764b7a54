//! The per-voxel emission field (`volume.emission_raw` or `volume.emission_grid`): imported once
//! into the store beside the density, as field `emission` (one f32 per voxel, occupied bricks only:
//! where there is no medium nothing absorbs, so nothing emits), and opened again by the solver and
//! the renderer.
//!
//! The importers are the density's (raw files read brick by brick, VDB grids leaf by leaf), so a
//! sparse emission grid never becomes a dense array in memory; a bad value is reported as an
//! emission value, naming the file and the voxel.

use super::{BrickStore, Coverage, Field, StoreError};
use crate::scene::{EmissionGrid, VolumeSource};

/// Fills one brick (local x fastest) from an importer.
type FillBrick = Box<dyn Fn([u32; 3], &mut [f32]) -> Result<(), StoreError>>;

/// Name of the emission field in the store.
pub const EMISSION_FIELD: &str = "emission";

/// Fills the store's emission field from `grid` (over the volume `source` of the store's dims).
pub fn import_emission(store: &BrickStore, grid: &EmissionGrid, source: &VolumeSource) -> Result<Field, StoreError> {
    let dims = store.grid().dims;
    let mut field = store.create_field(EMISSION_FIELD, 1, Coverage::Occupied)?;
    let fill: FillBrick = match (grid, source) {
        (EmissionGrid::Raw { path }, _) => {
            let raw = super::import::raw_density(path, dims)?;
            Box::new(move |b, out| raw.fill_brick(b, out))
        }
        (EmissionGrid::Vdb { grid }, VolumeSource::Vdb { path, index_min, .. }) => {
            let vdb = super::vdb::vdb_grid_over(path, grid, dims, *index_min)?;
            Box::new(move |b, out| vdb.fill_brick(b, out))
        }
        (EmissionGrid::Vdb { grid }, _) => {
            return Err(StoreError::Corrupt {
                path: store.dir().to_path_buf(),
                message: format!("emission grid \"{grid}\" needs a `vdb` volume"),
            })
        }
    };
    let bricks: Vec<usize> = store.occupied_bricks().collect();
    let mut values = vec![0f32; crate::store::BRICK_VOXELS];
    for brick in bricks {
        let coords = store.grid().brick_coords(brick);
        fill(coords, &mut values).map_err(StoreError::into_emission)?;
        if let Some(dst) = field.brick_mut(brick) {
            dst.copy_from_slice(&values);
        }
    }
    field.flush()?;
    Ok(field)
}

/// Opens the emission field a previous [`import_emission`] wrote.
pub fn open_emission(store: &BrickStore) -> Result<Field, StoreError> {
    store.open_field(EMISSION_FIELD, 1, Coverage::Occupied)
}
