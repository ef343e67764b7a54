//! The 16³ brick store: the volume on disk, in memory-mapped files.
//!
//! A volume of `dims` voxels (any size, not only multiples of 16) is tiled into 16³ bricks
//! ([`BrickGrid`]). The density is written once, by [`BrickStore::create_with`], into
//! `density.bricks`; a brick whose voxels are all zero is *empty*: it is recorded in the brick table
//! (`bricks.json`) and takes no space on disk, and the solver skips it. Every other per-voxel
//! quantity (sources, fluence, accumulators) is a [`Field`]: a memory-mapped file holding, for each
//! stored brick, `components × 4096` f32 values, component-major. A field either covers every brick
//! ([`Coverage::Dense`]) or only the occupied ones ([`Coverage::Occupied`], indexed by slot). The
//! solver's fields are all `Occupied`. Passes over the fields of a store larger than the host memory
//! budget hand their pages back to keep the resident set bounded (see [`Field`] and [`resident`]).
//!
//! Files in a store directory:
//!
//! | file | content |
//! |---|---|
//! | `bricks.json` | dims, voxel size, the brick table (slot of each brick or `null`), occupied count |
//! | `density.bricks` | the occupied bricks' densities, in brick-index order, 4096 f32 (native = little-endian) each |
//! | `<name>.field` | a field, see [`Field`] (the per-voxel `emission` and `albedo` factors, [`emission`] and [`albedo`], are fields too) |
//!
//! Importers that feed [`BrickStore::create_with`] live in [`import`] (raw f32), [`vdb`] (OpenVDB
//! grids, read by our own reader; NanoVDB grids through [`nanovdb`] into the same sparse tree) and
//! [`nrrd_input`] (NRRD volumes, decoded to raw first).

pub mod albedo;
mod atomic;
mod brick_store;
pub mod emission;
mod error;
mod field;
mod grid;
pub mod import;
pub mod nanovdb;
pub mod nrrd_input;
pub mod resident;
mod space;
mod table;
pub mod vdb;

pub(crate) use atomic::write_atomic_io;
pub use atomic::{is_temp_name, remove_stale_temps};
pub use brick_store::BrickStore;
pub use error::StoreError;
pub use field::{Coverage, Field};
pub use grid::{brick_voxel, local_index, BrickGrid, BRICK_EDGE, BRICK_VOXELS};
pub use import::{raw_density, RawDensity};
pub use space::free_bytes;

// Brick and field files hold native f32 and are mapped as such; they are specified little-endian.
#[cfg(target_endian = "big")]
compile_error!("the lpm brick store requires a little-endian host");
