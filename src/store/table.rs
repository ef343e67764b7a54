//! The brick table: which bricks are empty, and where each occupied brick is stored (its slot).
//! Serialised as `bricks.json`; shared (via `Arc`) by the store and every field mapped from it.

use super::grid::{BrickGrid, BRICK_EDGE};
use super::StoreError;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Marks an empty brick in [`BrickTable::slots`].
const EMPTY: u32 = u32::MAX;

#[derive(Debug, PartialEq)]
pub(crate) struct BrickTable {
    pub grid: BrickGrid,
    pub voxel_size: f64,
    /// Slot of each brick among the occupied ones, or `EMPTY`. Slots increase with the brick index.
    slots: Vec<u32>,
    occupied: usize,
}

/// What `bricks.json` holds. `table[i]` is the slot of brick i, `null` for an empty brick.
#[derive(Serialize, Deserialize)]
struct BricksJson {
    format: String,
    version: u32,
    dims: [u32; 3],
    voxel_size: f64,
    brick_edge: u32,
    bricks: [u32; 3],
    occupied: usize,
    density_file: String,
    table: Vec<Option<u32>>,
}

const FORMAT: &str = "lpm brick store";
const VERSION: u32 = 1;
pub(crate) const DENSITY_FILE: &str = "density.bricks";

impl BrickTable {
    /// Builds the table from one flag per brick (true: occupied), slots in brick order.
    pub fn from_occupancy(grid: BrickGrid, voxel_size: f64, occupied: &[bool]) -> Self {
        let mut next = 0u32;
        let slots = occupied
            .iter()
            .map(|&o| {
                if o {
                    next += 1;
                    next - 1
                } else {
                    EMPTY
                }
            })
            .collect();
        BrickTable { grid, voxel_size, slots, occupied: next as usize }
    }

    pub fn slot(&self, brick: usize) -> Option<u32> {
        self.slots.get(brick).copied().filter(|&s| s != EMPTY)
    }

    pub fn occupied(&self) -> usize {
        self.occupied
    }

    pub fn to_json(&self) -> serde_json::Result<Vec<u8>> {
        let json = BricksJson {
            format: FORMAT.to_string(),
            version: VERSION,
            dims: self.grid.dims,
            voxel_size: self.voxel_size,
            brick_edge: BRICK_EDGE,
            bricks: self.grid.bricks,
            occupied: self.occupied,
            density_file: DENSITY_FILE.to_string(),
            table: (0..self.slots.len()).map(|b| self.slot(b)).collect(),
        };
        serde_json::to_vec(&json)
    }

    /// Parses and checks `bricks.json` (read from `path`, used in messages).
    pub fn from_json(path: &Path, bytes: &[u8]) -> Result<Self, StoreError> {
        let j: BricksJson =
            serde_json::from_slice(bytes).map_err(|source| StoreError::Json { path: path.to_path_buf(), source })?;
        let bad = |message: String| StoreError::Corrupt { path: path.to_path_buf(), message };
        if j.format != FORMAT || j.version != VERSION {
            return Err(bad(format!(
                "format {:?} version {} is not a {FORMAT:?} version {VERSION}",
                j.format, j.version
            )));
        }
        if j.brick_edge != BRICK_EDGE {
            return Err(bad(format!("brick edge {} is not {BRICK_EDGE}", j.brick_edge)));
        }
        if j.dims.contains(&0) {
            return Err(bad(format!("dims {:?} contain a zero", j.dims)));
        }
        if !(j.voxel_size.is_finite() && j.voxel_size > 0.0) {
            return Err(bad(format!("voxel size {} is not a positive number", j.voxel_size)));
        }
        let grid = BrickGrid::new(j.dims);
        if grid.bricks != j.bricks || j.table.len() != grid.brick_count() {
            return Err(bad(format!(
                "the table has {} entries and bricks {:?}, but dims {:?} need {} ({:?})",
                j.table.len(),
                j.bricks,
                j.dims,
                grid.brick_count(),
                grid.bricks
            )));
        }
        let occupancy: Vec<bool> = j.table.iter().map(Option::is_some).collect();
        let table = BrickTable::from_occupancy(grid, j.voxel_size, &occupancy);
        // Slots must be exactly 0, 1, 2 … in brick order: that is how density.bricks is laid out.
        let consistent = j.table.iter().enumerate().all(|(b, s)| *s == table.slot(b));
        if !consistent || table.occupied != j.occupied {
            return Err(bad("the slots are not numbered 0, 1, 2 … in brick order".to_string()));
        }
        Ok(table)
    }
}
