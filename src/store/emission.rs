//! The per-voxel emission field (`volume.emission_raw` / `emission_grid`, or a temperature:
//! `volume.temperature_raw` / `temperature_grid`): imported once into the store beside the
//! density, as field `emission`, and opened again by the solver and the renderer. Occupied bricks
//! only: where there is no medium nothing absorbs, so nothing emits.
//!
//! The field holds the emission factor `e(v)` that scales `medium.emission`: one component (a
//! grey factor, the same for r, g and b) for a radiance grid, three (r, g, b) for a temperature
//! grid, whose values are turned into blackbody factors here, once ([`crate::scene::blackbody`]),
//! so that the solver, the energy balance and the renderer only ever see factors. Readers take
//! component `min(ch, components − 1)` for channel `ch`, and [`open_emission`] finds the number of
//! components from the file's size, so a grey field stays one component.
//!
//! The importers are the density's (raw files read brick by brick, VDB grids leaf by leaf), so a
//! sparse emission grid never becomes a dense array in memory; a bad value is reported as an
//! emission value or a temperature, naming the file and the voxel.

use super::import::voxel_grid_importer;
use super::{brick_voxel, BrickStore, Coverage, Field, StoreError, BRICK_VOXELS};
use crate::scene::blackbody::BlackbodyMap;
use crate::scene::validate::MAX_LIGHT;
use crate::scene::{EmissionGrid, Medium, VolumeSource};

/// Name of the emission field in the store.
pub const EMISSION_FIELD: &str = "emission";

/// Where the values of `grid` come from, for messages: the scene key or the VDB grid.
pub fn field_label(grid: &EmissionGrid) -> String {
    match (grid.vdb_grid(), grid.blackbody()) {
        (Some(name), _) => format!("grid \"{name}\""),
        (None, Some(_)) => "volume.temperature_raw".into(),
        (None, None) => "volume.emission_raw".into(),
    }
}

/// The emission factors `f_c(T)` (f32, as stored) of a temperature grid's value `t` at `voxel`,
/// refused when the radiance `medium.emission · f` they give would pass [`MAX_LIGHT`] (the bound
/// that keeps every field the solver forms finite in f32). `path` names the file in the error.
pub fn temperature_factors(
    map: &BlackbodyMap,
    max_emission: f64,
    t: f32,
    voxel: [u32; 3],
    path: &std::path::Path,
) -> Result<[f32; 3], StoreError> {
    let f = map.factors(t);
    let peak = f.iter().fold(0f64, |m, &v| m.max(v));
    if !(peak * max_emission <= MAX_LIGHT) {
        return Err(StoreError::BadTemperature {
            path: path.to_path_buf(),
            voxel,
            value: t,
            problem: format!(
                "at {:.4e} K its blackbody radiance is {:.3e} × medium.emission, above the limit of {MAX_LIGHT:e}: \
                 lower medium.temperature_scale or raise medium.temperature_reference",
                map.kelvin(t),
                peak
            ),
        });
    }
    Ok(f.map(|v| v as f32))
}

/// Fills the store's emission field from `grid` (over the volume `source` of the store's dims);
/// `medium` bounds a temperature's radiance (see [`temperature_factors`]).
pub fn import_emission(
    store: &BrickStore,
    grid: &EmissionGrid,
    source: &VolumeSource,
    medium: &Medium,
) -> Result<Field, StoreError> {
    let dims = store.grid().dims;
    let components = grid.components();
    let mut field = store.create_field(EMISSION_FIELD, components, Coverage::Occupied)?;
    let (fill, path) = voxel_grid_importer(grid.raw_path(), grid.vdb_grid(), source, dims, store.dir(), "emission")?;
    let label = field_label(grid);
    let blackbody = grid.blackbody().map(BlackbodyMap::new);
    let max_emission = medium.emission.iter().fold(0f64, |m, &v| m.max(v));
    let bricks: Vec<usize> = store.occupied_bricks().collect();
    let mut values = vec![0f32; BRICK_VOXELS];
    for brick in bricks {
        let coords = store.grid().brick_coords(brick);
        fill(coords, &mut values).map_err(|e| match blackbody {
            Some(_) => e.into_temperature(&label),
            None => e.into_emission(),
        })?;
        let Some(dst) = field.brick_mut(brick) else { continue };
        match &blackbody {
            None => {
                // The radiance a factor gives, f · medium.emission, stays within the limit every
                // light value keeps (issue 57: 1e30 was accepted, 3.4e38 diverged late).
                if let Some(l) = values.iter().position(|&f| !(f as f64 * max_emission <= MAX_LIGHT)) {
                    let origin = store.grid().brick_origin(coords);
                    return Err(StoreError::TooLarge {
                        path,
                        what: "emission",
                        voxel: brick_voxel(origin, l),
                        value: values[l],
                        factor_key: "medium.emission",
                        factor: max_emission,
                        product: values[l] as f64 * max_emission,
                    });
                }
                dst.copy_from_slice(&values)
            }
            Some(map) => {
                let origin = store.grid().brick_origin(coords);
                for (l, &t) in values.iter().enumerate() {
                    let f = temperature_factors(map, max_emission, t, brick_voxel(origin, l), &path)?;
                    for (c, v) in f.into_iter().enumerate() {
                        dst[c * BRICK_VOXELS + l] = v;
                    }
                }
            }
        }
    }
    field.flush()?;
    Ok(field)
}

/// Opens the emission field a previous [`import_emission`] wrote, with its 1 or 3 components
/// (found from the file's size).
pub fn open_emission(store: &BrickStore) -> Result<Field, StoreError> {
    let path = store.dir().join(format!("{EMISSION_FIELD}.field"));
    let len = std::fs::metadata(&path).map_err(StoreError::io(&path, "read the size of"))?.len();
    let per_component = (store.occupied_count() * BRICK_VOXELS * 4) as u64;
    let components = if per_component > 0 && len == 3 * per_component { 3 } else { 1 };
    store.open_field(EMISSION_FIELD, components, Coverage::Occupied)
}

/// The emission factor of channel `ch` in a brick of the emission field (its `components × 4096`
/// values): component `ch`, or the one grey component.
pub fn channel_block(brick: &[f32], ch: usize) -> &[f32] {
    let c = (brick.len() / BRICK_VOXELS).max(1);
    let k = ch.min(c - 1);
    &brick[k * BRICK_VOXELS..(k + 1) * BRICK_VOXELS]
}
