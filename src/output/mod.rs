//! Files the user reads: atomic writes, and fields exported as raw + json + NRRD header.
//!
//! Every file is written under a temporary name in its own directory, fsynced, then renamed over
//! its final name ([`write_atomic`]), so a crash or an error never leaves a half-written output.
//! A solve's outputs are staged and published as one set ([`Staging`]) under a lock on the
//! directory ([`DirLock`]); free space is checked up front ([`space`]).
//!
//! An exported field `<base>` is three files:
//! - `<base>.raw`: little-endian f32, all components of a voxel together (component fastest), then
//!   x, then y, then z, over the volume's own dims (no brick padding);
//! - `<base>.json`: what the raw file holds ([`FieldInfo`]), and, when NaN marks voxels that were
//!   not solved (the fluence of empty bricks), a `not_solved` note saying so;
//! - `<base>.nhdr`: a detached NRRD header so ParaView, 3D Slicer, teem … open the raw directly.
//!
//! and, beside them, `<base>.vdb`: the same values as sparse OpenVDB grids (only the leaves of
//! bricks with medium), placed where the input volume was, for Houdini, Blender and Nuke
//! ([`export_vdb`], written by our own writer: see `vdb.rs` for why).
//!
//! A CPU solve also writes `faces/`: per face of the volume, the outgoing power per boundary pixel
//! (`<face>.exr`, `.raw`, `.nhdr`; [`write_face_map`]).

mod atomic;
pub mod confine;
mod error;
mod export;
mod faces;
mod lock;
mod nrrd;
mod publish;
mod read;
pub mod space;
mod vdb;

pub use atomic::{write_atomic, write_json_atomic};
pub use confine::{confine, ConfineError};
pub use error::OutputError;
pub use export::{
    export_dense, export_field, export_field_until, EmptyBricks, FieldInfo, FieldMeta, LAYOUT, NOT_SOLVED,
};
pub use faces::{write_face_map, FaceMap, FacePlacement};
pub use lock::{DirLock, LOCK_FILE};
pub use publish::{finish_commit, recover, Recovery, Staging, KNOWN_OUTPUTS};
pub use read::{read_field_json, read_raw_field};
pub use vdb::{
    export_vdb, export_vdb_until, tree_order, vdb_grid_names, write_vdb, GridOut, VdbPlacement, VdbPrecision,
};
