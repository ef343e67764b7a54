//! Exporting a [`Field`] (or a field held in memory) as `<base>.raw` + `<base>.json` + `<base>.nhdr`.

use super::{nrrd, write_atomic, write_json_atomic, OutputError};
use crate::solver::cancel::{self, CancelFlag, Stoppable};
use crate::store::{BrickStore, Field, BRICK_EDGE, BRICK_VOXELS};
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

/// What an exported field means, given by the caller.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldMeta {
    /// e.g. "fluence".
    pub quantity: String,
    /// e.g. "W/m^2".
    pub units: String,
    /// One name per component, e.g. `["r", "g", "b"]` or `["d0.r", "d0.g", …]`.
    pub components: Vec<String>,
    pub description: String,
    /// World position of the volume's low corner (the corner of voxel (0, 0, 0)): the scene's
    /// `volume.origin`.
    pub origin: [f64; 3],
}

/// The content of `<base>.json`: everything needed to read `<base>.raw` without lpm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FieldInfo {
    pub dims: [u32; 3],
    pub components: u32,
    pub component_names: Vec<String>,
    /// Always "f32".
    pub dtype: String,
    /// Always "little".
    pub endianness: String,
    /// Always [`LAYOUT`].
    pub layout: String,
    pub voxel_size: f64,
    /// World position of the volume's low corner (the corner of voxel (0, 0, 0), not its centre);
    /// voxel (i, j, k) spans `origin + [i, i+1) × voxel_size` along x, and so on. Absent in files
    /// written before it was recorded: read as 0.
    #[serde(default)]
    pub origin: [f64; 3],
    pub quantity: String,
    pub units: String,
    pub description: String,
    /// The raw file's name, relative to the json.
    pub file: String,
    /// Present when NaN marks voxels that were not solved (those of empty bricks), saying so.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub not_solved: Option<String>,
}

/// What the voxels of empty (unstored) bricks read as in an export.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EmptyBricks {
    /// Zero: the quantity is truly zero there (a source where nothing scatters).
    Zero,
    /// NaN: the quantity was not solved there (fluence where there is no medium).
    NotSolved,
}

/// The `not_solved` note of an export whose empty bricks read as NaN.
pub const NOT_SOLVED: &str = "NaN marks the voxels of empty 16³ bricks (no medium): the solver does not solve there";

/// The `layout` string of every exported field.
pub const LAYOUT: &str = "component fastest, then x, then y, then z";

/// Writes `field` (a field of `store`) into `out_dir` as `<base>.raw`, `<base>.json` and
/// `<base>.nhdr`, each atomically. The raw is streamed one voxel row at a time, so the volume is never
/// held in memory. The raw is written first: a json or header never describes a missing raw.
/// `empty` says what the voxels of bricks the field does not store read as.
pub fn export_field(
    field: &Field,
    store: &BrickStore,
    out_dir: &Path,
    base: &str,
    meta: &FieldMeta,
    empty: EmptyBricks,
) -> Result<(), OutputError> {
    export_field_until(field, store, out_dir, base, meta, empty, None)
}

/// [`export_field`], stopping with [`OutputError::Cancelled`] once `cancel` is raised (looked at
/// before every row written: a large field takes many seconds to write). What was written is a
/// temporary, removed.
pub fn export_field_until(
    field: &Field,
    store: &BrickStore,
    out_dir: &Path,
    base: &str,
    meta: &FieldMeta,
    empty: EmptyBricks,
    cancel: Option<CancelFlag>,
) -> Result<(), OutputError> {
    let invalid = |message: String| OutputError::Invalid { path: out_dir.join(format!("{base}.json")), message };
    if field.grid() != store.grid() {
        return Err(invalid(format!(
            "field {} covers a {:?} volume, the store a {:?} one",
            field.name(),
            field.grid().dims,
            store.grid().dims
        )));
    }
    if meta.components.len() != field.components() as usize {
        return Err(invalid(format!(
            "{} component names given for field {} of {} components",
            meta.components.len(),
            field.name(),
            field.components()
        )));
    }
    let fill = match empty {
        EmptyBricks::Zero => 0.0,
        EmptyBricks::NotSolved => f32::NAN,
    };
    let unstored = field.stored_bricks() < store.grid().brick_count();
    let note = (empty == EmptyBricks::NotSolved && unstored).then(|| NOT_SOLVED.to_string());
    let written = write_described(out_dir, base, store.grid().dims, store.voxel_size(), meta, note, |w| {
        write_raw(field, fill, &mut Stoppable { inner: w, cancel })
    });
    cancelled_or(cancel, written)
}

/// A failed write as [`OutputError::Cancelled`] when it failed because `cancel` was raised.
pub(crate) fn cancelled_or(cancel: Option<CancelFlag>, r: Result<(), OutputError>) -> Result<(), OutputError> {
    match r {
        Err(_) if cancel::raised(cancel) => Err(OutputError::Cancelled),
        r => r,
    }
}

/// The export test hook (`tests/it/hostile_inputs.rs`): with the `test-hooks` cargo feature only,
/// `LPM_TEST_EXPORT_ROW_DELAY_MS` slows every row written, so that a signal finds the export
/// running. Never in a plain or release build.
fn test_row_delay() {
    // Read once per process: this runs for every row.
    #[cfg(feature = "test-hooks")]
    {
        static DELAY: std::sync::OnceLock<Option<u64>> = std::sync::OnceLock::new();
        let delay = DELAY
            .get_or_init(|| std::env::var("LPM_TEST_EXPORT_ROW_DELAY_MS").ok().and_then(|v| v.parse::<u64>().ok()));
        if let Some(ms) = *delay {
            std::thread::sleep(std::time::Duration::from_millis(ms));
        }
    }
}

/// Writes a field held in memory (`values` in the exported layout: component fastest, then x, y, z;
/// `meta.components.len()` components per voxel over `dims`) into `out_dir` as `<base>.raw`,
/// `<base>.json` and `<base>.nhdr`, exactly as [`export_field`] lays them out, each atomically.
pub fn export_dense(
    values: &[f32],
    dims: [u32; 3],
    voxel_size: f64,
    out_dir: &Path,
    base: &str,
    meta: &FieldMeta,
) -> Result<(), OutputError> {
    let expected = dims.iter().try_fold(meta.components.len(), |acc, &d| acc.checked_mul(d as usize));
    if meta.components.is_empty() || expected != Some(values.len()) {
        return Err(OutputError::Invalid {
            path: out_dir.join(format!("{base}.json")),
            message: format!(
                "{} values given for {} component(s) over {:?} voxels",
                values.len(),
                meta.components.len(),
                dims
            ),
        });
    }
    write_described(out_dir, base, dims, voxel_size, meta, None, |w| {
        // Little-endian f32, in chunks so a large volume is not duplicated as bytes in memory.
        let mut bytes = Vec::with_capacity(values.len().min(1 << 16) * 4);
        for chunk in values.chunks(1 << 16) {
            bytes.clear();
            chunk.iter().for_each(|v| bytes.extend_from_slice(&v.to_le_bytes()));
            w.write_all(&bytes)?;
        }
        Ok(())
    })
}

/// The one writer of the exported layout: checks `base`, writes the raw through `write_raw`, then
/// the json and the NRRD header describing it.
fn write_described(
    out_dir: &Path,
    base: &str,
    dims: [u32; 3],
    voxel_size: f64,
    meta: &FieldMeta,
    not_solved: Option<String>,
    write_raw: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> Result<(), OutputError> {
    let json_path = out_dir.join(format!("{base}.json"));
    if base.is_empty() || base.contains(['/', '\\']) || base.starts_with('.') {
        return Err(OutputError::Invalid {
            path: json_path,
            message: format!("export name {base:?} must be a plain file name"),
        });
    }
    let info = FieldInfo {
        dims,
        components: meta.components.len() as u32,
        component_names: meta.components.clone(),
        dtype: "f32".to_string(),
        endianness: "little".to_string(),
        layout: LAYOUT.to_string(),
        voxel_size,
        origin: meta.origin,
        quantity: meta.quantity.clone(),
        units: meta.units.clone(),
        description: meta.description.clone(),
        file: format!("{base}.raw"),
        not_solved,
    };
    write_atomic(&out_dir.join(&info.file), write_raw)?;
    write_json_atomic(&json_path, &info)?;
    let header = nrrd::header(&info);
    write_atomic(&out_dir.join(format!("{base}.nhdr")), |w| w.write_all(header.as_bytes()))
}

/// Streams the field voxel row by voxel row (fixed y and z), in the exported layout; voxels of
/// unstored bricks read as `fill`.
fn write_raw(field: &Field, fill: f32, w: &mut impl Write) -> std::io::Result<()> {
    let grid = *field.grid();
    let [nx, ny, nz] = grid.dims;
    let c = field.components() as usize;
    let mut row = Vec::with_capacity(nx as usize * c * 4);
    for z in 0..nz {
        for y in 0..ny {
            row.clear();
            for bx in 0..grid.bricks[0] {
                let (brick, local) = grid.locate([bx * BRICK_EDGE, y, z]);
                let width = grid.brick_extent([bx, y / BRICK_EDGE, z / BRICK_EDGE])[0] as usize;
                match field.brick(brick) {
                    Some(data) => {
                        for x in 0..width {
                            for ch in 0..c {
                                row.extend_from_slice(&data[ch * BRICK_VOXELS + local + x].to_le_bytes());
                            }
                        }
                    }
                    None => (0..width * c).for_each(|_| row.extend_from_slice(&fill.to_le_bytes())),
                }
            }
            test_row_delay();
            w.write_all(&row)?;
        }
        if (z + 1) % BRICK_EDGE == 0 {
            // A layer of bricks is done: hand its pages back (see `store::Field` on resident memory).
            field.release_all();
        }
    }
    field.release_all();
    Ok(())
}
