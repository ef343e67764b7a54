//! The file header (magic, format version, library version, UUID), the file's metadata (skipped),
//! and the grid descriptors (name, type, where each grid's bytes are). OpenVDB's `Archive::readHeader`
//! and `GridDescriptor::read`.

use super::error::{VdbError, R};
use super::stream::Stream;
use std::io::{Read, Seek};

/// The oldest and newest format versions read: 222 stores compression per grid and node masks
/// compressed; 224 (OpenVDB 4 to today) added multi-pass I/O, which float grids do not use.
pub const MIN_VERSION: u32 = 222;
pub const MAX_VERSION: u32 = 224;

/// OpenVDB separates a duplicate grid name from its index with ASCII record separator.
const NAME_SUFFIX_SEP: char = '\u{1e}';
const HALF_SUFFIX: &str = "_HalfFloat";

#[derive(Clone, Debug)]
pub struct Header {
    pub version: u32,
    pub library: (u32, u32),
    pub grids: Vec<GridDescriptor>,
}

#[derive(Clone, Debug)]
pub struct GridDescriptor {
    /// The grid's name as users see it (any "\x1e<n>" uniqueness suffix removed).
    pub name: String,
    /// The value type's name without the half suffix, e.g. "Tree_float_5_4_3".
    pub grid_type: String,
    /// Values saved as 16-bit floats.
    pub half: bool,
    pub instance_parent: String,
    pub grid_pos: u64,
    pub block_pos: u64,
    pub end_pos: u64,
}

pub(crate) fn read_header<S: Read + Seek>(s: &mut Stream<S>) -> R<Header> {
    let magic: [u8; 8] = match s.array("the magic number") {
        Ok(m) => m,
        Err(VdbError::Truncated { .. }) => return Err(VdbError::NotVdb),
        Err(e) => return Err(e),
    };
    if magic != [0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0] {
        return Err(VdbError::NotVdb);
    }
    let version = s.u32("the file format version")?;
    if !(MIN_VERSION..=MAX_VERSION).contains(&version) {
        return Err(VdbError::Version(version));
    }
    let library = (s.u32("the library version")?, s.u32("the library version")?);
    let at = s.pos();
    if s.u8("the grid-offsets flag")? == 0 {
        return Err(s.malformed(
            "the header",
            at,
            "the file has no grid offsets (it was written to a stream, not a file); re-save it as a file",
        ));
    }
    s.skip(36, "the file UUID")?;
    skip_metadata(s, "the file metadata")?;
    let at = s.pos();
    let count = s.i32("the grid count")?;
    // A descriptor takes at least 3 empty strings and 3 offsets.
    if count < 0 || count as u64 > s.remaining() / 36 {
        return Err(s.malformed("the grid count", at, format!("{count} grids cannot fit in the file")));
    }
    let mut grids = Vec::with_capacity(count as usize);
    for _ in 0..count {
        let gd = read_descriptor(s)?;
        s.seek(gd.end_pos, "the next grid descriptor")?;
        grids.push(gd);
    }
    Ok(Header { version, library, grids })
}

/// Skips a metadata map: a count, then (name, type name, byte size, bytes) per entry.
pub(crate) fn skip_metadata<S: Read + Seek>(s: &mut Stream<S>, what: &'static str) -> R<()> {
    let at = s.pos();
    let count = s.i32(what)?;
    if count < 0 || count as u64 > s.remaining() / 12 {
        return Err(s.malformed(what, at, format!("{count} entries cannot fit in the file")));
    }
    for _ in 0..count {
        s.string(what)?;
        s.string(what)?;
        let n = s.u32(what)?;
        s.skip(u64::from(n), what)?;
    }
    Ok(())
}

fn read_descriptor<S: Read + Seek>(s: &mut Stream<S>) -> R<GridDescriptor> {
    let what = "a grid descriptor";
    let unique = s.string(what)?;
    let name = unique.split(NAME_SUFFIX_SEP).next().unwrap_or_default().to_string();
    let mut grid_type = s.string(what)?;
    let half = grid_type.ends_with(HALF_SUFFIX);
    if half {
        grid_type.truncate(grid_type.len() - HALF_SUFFIX.len());
    }
    let instance_parent = s.string(what)?;
    let at = s.pos();
    let mut offsets = [0u64; 3];
    for o in &mut offsets {
        let v = s.i64(what)?;
        *o = u64::try_from(v).map_err(|_| s.malformed(what, at, format!("negative grid offset {v}")))?;
    }
    let [grid_pos, block_pos, end_pos] = offsets;
    let len = s.pos() + s.remaining();
    if grid_pos <= block_pos && block_pos <= end_pos && end_pos > len {
        return Err(VdbError::Truncated { what: "a grid", offset: grid_pos, len });
    }
    if !(s.pos() <= grid_pos && grid_pos <= block_pos && block_pos <= end_pos && end_pos <= len) {
        return Err(s.malformed(
            what,
            at,
            format!("grid \"{name}\" has offsets {grid_pos}, {block_pos}, {end_pos} out of order or past the end ({len} bytes)"),
        ));
    }
    Ok(GridDescriptor { name, grid_type, half, instance_parent, grid_pos, block_pos, end_pos })
}
