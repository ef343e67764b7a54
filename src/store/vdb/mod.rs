//! OpenVDB (`.vdb`) input: a reader for the file format written for lpm, and the importer that
//! streams a grid into the brick store.
//!
//! Why our own reader: the `vdb-rs` crate (0.6, checked on crates.io) mis-reads or refuses what
//! simulation tools write — it ignores root and internal tiles and the background, binds the
//! Blosc C library, and panics (`todo!`, `unwrap`, `assert!`) on versions, transforms and corrupt
//! input — and OpenVDB itself is a large C++ library. The format, for the grids lpm needs (scalar
//! float / half / double, tree 5-4-3), is small. One purpose per file:
//!
//! | file | reads |
//! |---|---|
//! | `stream` | bounds-checked little-endian reads; truncation and corrupt lengths become errors |
//! | `header` | magic, format version, file metadata, grid descriptors |
//! | `transform` | the grid's map: uniform scale + translation, or a clear refusal |
//! | `tree` | topology (root table, 32³ and 16³ nodes, tiles at every level) and leaf buffers |
//! | `values` | a node's value buffer: active-mask compression, inactive values, half/float/double |
//! | `codec` | none / zip (zlib via `flate2`) / Blosc 1 (LZ4 via `lz4_flex`, or zlib) chunks |
//! | [`import`] | the grid as a density source for [`crate::store::BrickStore::create_with`] |
//!
//! The file is read with plain reads (not memory-mapped): a file that shrinks while it is read gives
//! a [`VdbError::Truncated`], not a SIGBUS. The reader never panics on bad bytes; [`read_all`] over
//! a byte slice is the entry point for fuzzing.
//!
//! Placement: OpenVDB puts the centre of index voxel `ijk` at world `translation + voxel_size·ijk`;
//! lpm's voxel `i` spans `[origin + i·h, origin + (i+1)·h]`. The imported volume is the inclusive
//! index bounding box `[lo, hi]` of the active voxels and tiles, so `dims = hi − lo + 1`,
//! `h = voxel_size` and `origin = translation + (lo − ½)·h`. Values inside that box are read as
//! OpenVDB's `getValue` gives them, inactive voxels included (they hold the background, usually 0).

mod codec;
mod error;
mod header;
pub mod import;
mod stream;
mod transform;
mod tree;
mod values;

pub use error::VdbError;
pub use header::{MAX_VERSION, MIN_VERSION};
pub use import::{vdb_density, vdb_density_until, vdb_grid_over, vdb_info, VdbDensity, VdbVolumeInfo};
pub use transform::Placement;
pub use tree::Tree;

use header::{read_header, skip_metadata, GridDescriptor, Header};
use std::io::{Cursor, Read, Seek};
use stream::Stream;
use values::{Encoding, ValueType};

/// One grid as read: its name, transform and tree (with or without leaf values, see `read_grid`).
pub struct VdbGrid {
    pub name: String,
    pub placement: Placement,
    /// Values were saved as 16-bit floats.
    pub half: bool,
    pub tree: Tree,
}

/// A grid's entry in the file: name and value type (read without reading the grid).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GridInfo {
    pub name: String,
    pub grid_type: String,
    pub half: bool,
}

/// A VDB file opened for reading: its header and grid list.
pub struct VdbReader<S> {
    s: Stream<S>,
    header: Header,
}

impl<S: Read + Seek> VdbReader<S> {
    pub fn new(source: S) -> Result<Self, VdbError> {
        let mut s = Stream::new(source)?;
        let header = read_header(&mut s)?;
        Ok(VdbReader { s, header })
    }

    /// The file format version (222 to 224).
    pub fn version(&self) -> u32 {
        self.header.version
    }

    /// The OpenVDB library version (major, minor) that wrote the file.
    pub fn library_version(&self) -> (u32, u32) {
        self.header.library
    }

    pub fn grids(&self) -> Vec<GridInfo> {
        self.header
            .grids
            .iter()
            .map(|g| GridInfo { name: g.name.clone(), grid_type: g.grid_type.clone(), half: g.half })
            .collect()
    }

    /// Reads the first grid named `name`. With `values` false only the topology is read (the
    /// bounding box and tile values, enough to place the volume), and leaf values read as the
    /// background.
    pub fn read_grid(&mut self, name: &str, values: bool) -> Result<VdbGrid, VdbError> {
        let Some(gd) = self.header.grids.iter().find(|g| g.name == name).cloned() else {
            let available = self.header.grids.iter().map(|g| format!("\"{}\"", g.name)).collect::<Vec<_>>();
            let available = if available.is_empty() { "none".to_string() } else { available.join(", ") };
            return Err(VdbError::NoGrid { name: name.to_string(), available });
        };
        self.read_descriptor(&gd, values)
    }

    fn read_descriptor(&mut self, gd: &GridDescriptor, values: bool) -> Result<VdbGrid, VdbError> {
        let value_type = match gd.grid_type.as_str() {
            "Tree_float_5_4_3" => ValueType::Float,
            "Tree_double_5_4_3" => ValueType::Double,
            other => return Err(VdbError::GridType { name: gd.name.clone(), grid_type: other.to_string() }),
        };
        if !gd.instance_parent.is_empty() {
            return Err(VdbError::Instance { name: gd.name.clone(), parent: gd.instance_parent.clone() });
        }
        let s = &mut self.s;
        s.seek(gd.grid_pos, "a grid")?;
        let at = s.pos();
        let compression = s.u32("the grid's compression flags")?;
        if compression & !0x7 != 0 {
            return Err(s.malformed("the grid's compression flags", at, format!("unknown flags {compression:#x}")));
        }
        skip_metadata(s, "the grid metadata")?;
        let placement = transform::read_transform(s, &gd.name)?;
        let mut enc = Encoding { value_type, half: gd.half, compression, background: 0.0 };
        let mut tree = tree::read_topology(s, &mut enc)?;
        if values {
            let at = s.pos();
            if at != gd.block_pos {
                return Err(s.malformed(
                    "the tree topology",
                    at,
                    format!(
                        "it ends at byte {at} but the grid descriptor puts the leaf values at byte {}",
                        gd.block_pos
                    ),
                ));
            }
            tree::read_buffers(s, &enc, &mut tree)?;
            let at = s.pos();
            if at != gd.end_pos {
                return Err(s.malformed(
                    "the leaf values",
                    at,
                    format!("they end at byte {at} but the grid descriptor says {}", gd.end_pos),
                ));
            }
        }
        Ok(VdbGrid { name: gd.name.clone(), placement, half: gd.half, tree })
    }
}

/// Reads every scalar grid of a VDB file held in memory (grids of other types are skipped). The
/// entry point for fuzzing: any input gives `Ok` or a [`VdbError`], never a panic.
pub fn read_all(bytes: &[u8]) -> Result<Vec<VdbGrid>, VdbError> {
    let mut r = VdbReader::new(Cursor::new(bytes))?;
    let mut grids = Vec::new();
    for gd in r.header.grids.clone() {
        match r.read_descriptor(&gd, true) {
            Ok(g) => grids.push(g),
            Err(VdbError::GridType { .. }) => {}
            Err(e) => return Err(e),
        }
    }
    Ok(grids)
}
