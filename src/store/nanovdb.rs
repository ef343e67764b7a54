//! NanoVDB (`.nvdb`) input: a float grid of a NanoVDB file, read into the same sparse tree the
//! OpenVDB reader builds ([`crate::store::vdb::Tree`]), so placement and brick filling are shared
//! ([`crate::store::vdb::import`] picks this reader when a file starts with NanoVDB's magic).
//!
//! Why our own reader: no Rust crate reads NanoVDB, and a NanoVDB grid is its in-memory layout
//! written out, so reading is following byte offsets. Read here, with every offset and count
//! checked against the buffer (a bad file is an error naming what was read and where, never a
//! panic or an unbounded allocation):
//!
//! - the file: segments (`nanovdb_convert` writes one per grid), each a 16-byte header (magic
//!   `NanoVDB0`, version, grid count, codec), then per grid a 176-byte metadata record, its name,
//!   and the grid's buffer;
//! - the grid buffer: `GridData` (672 bytes: magic, version, name, the index-to-world map, class,
//!   type), `TreeData` (64 bytes: byte offsets of each level's first node, node counts), the root
//!   (background, then 32-byte tiles: a packed 4096³ key, a child offset, an active state, a value),
//!   32³ and 16³ internal nodes (masks, then 8-byte slots: a tile value or a child offset), and
//!   8³ leaves (active mask, then 512 values);
//! - only version 32.4 (OpenVDB 10's NanoVDB, Debian's `nanovdb_convert`), float grids (`Float`;
//!   quantised Fp4/8/16/N, half and other types are refused, as are zip or Blosc compressed
//!   files: write them uncompressed, e.g. `nanovdb_convert in.vdb out.nvdb`), and maps that are a
//!   uniform scale and a translation. Other versions are refused with a message: the layout moves
//!   between NanoVDB versions, and only this one is tested (against `nanovdb_convert`'s output of
//!   files OpenVDB wrote, in `tests/it/nanovdb_input.rs`).
//!
//! The grid's buffer is read into memory once (NanoVDB grids are in-memory images), then converted
//! to the sparse tree leaf by leaf. What the grid says of its size — active voxels and their
//! bounding box in the file's metadata, node, tile and voxel counts in `TreeData`, the bounding box
//! in the root — is then checked against what its nodes hold (`check_claims`): NanoVDB writes all
//! of them from the nodes, so a disagreement is a corrupt file (a few changed bytes can make a
//! grid describe a far larger volume), never a volume to solve. A grid written without statistics
//! has NanoVDB's empty bounding box, which claims nothing.

use crate::store::vdb::{Placement, Tree, VdbError, VdbGrid};
use std::io::Read;
use std::path::Path;

/// The first 8 bytes of a NanoVDB file (and of each grid buffer).
pub const MAGIC: [u8; 8] = *b"NanoVDB0";
/// The one NanoVDB version read (major, minor).
pub const VERSION: (u32, u32) = (32, 4);

const FILE_HEADER: usize = 16;
const FILE_METADATA: usize = 176;
const GRID_DATA: usize = 672;
const ROOT_DATA: usize = 64;
const ROOT_TILE: usize = 32;
/// Header bytes of a 32³ / 16³ node before its slot table, and of a leaf before its values.
const UPPER_TABLE: usize = 8256;
const LOWER_TABLE: usize = 1088;
const LEAF_VALUES: usize = 96;
const UPPER_SIZE: usize = UPPER_TABLE + 8 * 32768;
const LOWER_SIZE: usize = LOWER_TABLE + 8 * 4096;
const LEAF_SIZE: usize = LEAF_VALUES + 4 * 512;
/// NanoVDB's `GridType::Float`.
const GRID_TYPE_FLOAT: u32 = 1;

/// True when `path` starts with NanoVDB's magic number.
pub fn is_nanovdb(path: &Path) -> bool {
    let mut magic = [0u8; 8];
    // Through the input checks: a FIFO must not block here either (it is refused when read).
    crate::input::open(path).is_ok_and(|mut f| f.read_exact(&mut magic).is_ok()) && magic == MAGIC
}

fn version_of(v: u32) -> (u32, u32, u32) {
    (v >> 21, (v >> 10) & 0x7ff, v & 0x3ff)
}

/// Bounds-checked little-endian reads from a buffer that starts at file offset `base`.
struct Buf<'a> {
    bytes: &'a [u8],
    base: u64,
}

impl Buf<'_> {
    fn get<const N: usize>(&self, at: usize, what: &'static str) -> Result<[u8; N], VdbError> {
        at.checked_add(N).and_then(|end| self.bytes.get(at..end)).map(|b| b.try_into().unwrap_or([0; N])).ok_or(
            VdbError::Truncated { what, offset: self.base + at as u64, len: self.base + self.bytes.len() as u64 },
        )
    }
    fn u16(&self, at: usize, what: &'static str) -> Result<u16, VdbError> {
        self.get(at, what).map(u16::from_le_bytes)
    }
    fn u32(&self, at: usize, what: &'static str) -> Result<u32, VdbError> {
        self.get(at, what).map(u32::from_le_bytes)
    }
    fn u64(&self, at: usize, what: &'static str) -> Result<u64, VdbError> {
        self.get(at, what).map(u64::from_le_bytes)
    }
    fn i64(&self, at: usize, what: &'static str) -> Result<i64, VdbError> {
        self.get(at, what).map(i64::from_le_bytes)
    }
    fn f32(&self, at: usize, what: &'static str) -> Result<f32, VdbError> {
        self.get(at, what).map(f32::from_le_bytes)
    }
    fn f64(&self, at: usize, what: &'static str) -> Result<f64, VdbError> {
        self.get(at, what).map(f64::from_le_bytes)
    }
    fn words<const N: usize>(&self, at: usize, what: &'static str) -> Result<Vec<u64>, VdbError> {
        (0..N).map(|i| self.u64(at + 8 * i, what)).collect()
    }
    fn malformed(&self, what: &'static str, at: usize, message: String) -> VdbError {
        VdbError::Malformed { what, offset: self.base + at as u64, message }
    }
    /// `node + offset` as a position of a whole node of `size` bytes in the buffer.
    fn child(&self, node: usize, offset: i64, size: usize, what: &'static str) -> Result<usize, VdbError> {
        let at = (node as i64).checked_add(offset).filter(|&a| a >= 0).map(|a| a as usize);
        match at.filter(|&a| a.checked_add(size).is_some_and(|end| end <= self.bytes.len())) {
            Some(a) => Ok(a),
            None => Err(self.malformed(what, node, format!("child offset {offset} points outside the grid"))),
        }
    }
}

fn bit(words: &[u64], n: usize) -> bool {
    words[n >> 6] >> (n & 63) & 1 == 1
}

/// The grid named `name` of a NanoVDB file read from `bytes_of` (`file_len` bytes long), and the
/// names of all its grids.
pub fn read_nanovdb(bytes_of: &mut impl Read, file_len: u64, name: &str) -> Result<(VdbGrid, Vec<String>), VdbError> {
    let mut pos = 0u64;
    let mut names = Vec::new();
    let mut found = None;
    // A file is one or more segments (nanovdb_convert writes one per grid), each a header and its
    // grids.
    while pos < file_len || pos == 0 {
        let mut header = [0u8; FILE_HEADER];
        bytes_of.read_exact(&mut header).map_err(|_| VdbError::Truncated {
            what: "a NanoVDB segment header",
            offset: pos,
            len: file_len,
        })?;
        let h = Buf { bytes: &header, base: pos };
        if h.get::<8>(0, "the magic number")? != MAGIC {
            return Err(h.malformed(
                "a NanoVDB segment header",
                0,
                "it does not start with NanoVDB's magic number".into(),
            ));
        }
        check_version(h.u32(8, "the file version")?, pos + 8)?;
        let count = h.u16(12, "the grid count")?;
        let codec = h.u16(14, "the codec")?;
        if codec != 0 {
            return Err(codec_error(codec, pos + 14));
        }
        pos += FILE_HEADER as u64;
        if count == 0 {
            return Err(h.malformed("a NanoVDB segment header", 12, "a segment of no grids".into()));
        }
        for _ in 0..count {
            let mut meta = [0u8; FILE_METADATA];
            bytes_of.read_exact(&mut meta).map_err(|_| VdbError::Truncated {
                what: "a grid's metadata",
                offset: pos,
                len: file_len,
            })?;
            let m = Buf { bytes: &meta, base: pos };
            let grid_size = m.u64(0, "a grid's size")?;
            let file_size = m.u64(8, "a grid's size in the file")?;
            let name_size = m.u32(136, "a grid's name size")? as u64;
            let claims = Claims {
                voxels: m.u64(24, "a grid's voxel count")?,
                bbox: bbox_at(&m, 88, "a grid's bounding box")?,
                at: pos,
            };
            let codec = m.u16(168, "a grid's codec")?;
            if codec != 0 {
                return Err(codec_error(codec, pos + 168));
            }
            check_version(m.u32(172, "a grid's version")?, pos + 172)?;
            pos += FILE_METADATA as u64;
            if name_size > 256 || grid_size != file_size {
                return Err(m.malformed(
                    "a grid's metadata",
                    0,
                    format!("name size {name_size}, grid size {grid_size}, size in the file {file_size}"),
                ));
            }
            if pos.saturating_add(name_size).saturating_add(file_size) > file_len {
                return Err(VdbError::Truncated { what: "a grid", offset: pos, len: file_len });
            }
            let mut raw_name = vec![0u8; name_size as usize];
            bytes_of.read_exact(&mut raw_name).map_err(|_| VdbError::Truncated {
                what: "a grid's name",
                offset: pos,
                len: file_len,
            })?;
            let grid_name =
                String::from_utf8_lossy(raw_name.split(|&b| b == 0).next().unwrap_or_default()).into_owned();
            pos += name_size;
            if found.is_none() && grid_name == name {
                // The grid is read whole: a size the file claims (a sparse file can be any length)
                // is checked against the memory there is before anything is allocated, and the
                // buffer grows with the bytes really read.
                if let Some(available) = crate::store::resident::available_memory().filter(|&a| file_size > a) {
                    return Err(VdbError::Claimed {
                        what: "a grid",
                        offset: pos,
                        claimed: file_size,
                        limit: format!(
                            "more than the {available} bytes of memory available (lpm reads a NanoVDB grid whole)"
                        ),
                    });
                }
                let mut buffer = Vec::new();
                let read = bytes_of.by_ref().take(file_size).read_to_end(&mut buffer);
                if read.ok() != Some(file_size as usize) {
                    return Err(VdbError::Truncated { what: "a grid", offset: pos, len: file_len });
                }
                found = Some(read_grid(&Buf { bytes: &buffer, base: pos }, &grid_name, &claims)?);
            } else {
                let skipped = std::io::copy(&mut bytes_of.by_ref().take(file_size), &mut std::io::sink());
                if skipped.ok() != Some(file_size) {
                    return Err(VdbError::Truncated { what: "a grid", offset: pos, len: file_len });
                }
            }
            pos += file_size;
            names.push(grid_name);
        }
    }
    match found {
        Some(g) => Ok((g, names)),
        None => Err(VdbError::NoGrid {
            name: name.to_string(),
            available: if names.is_empty() {
                "none".into()
            } else {
                names.iter().map(|n| format!("\"{n}\"")).collect::<Vec<_>>().join(", ")
            },
        }),
    }
}

fn check_version(v: u32, at: u64) -> Result<(), VdbError> {
    let (major, minor, patch) = version_of(v);
    if (major, minor) != VERSION {
        return Err(VdbError::Malformed {
            what: "the NanoVDB version",
            offset: at,
            message: format!(
                "NanoVDB {major}.{minor}.{patch} is not supported: lpm reads NanoVDB {}.{} (OpenVDB 10); read the .vdb it came from, or convert it with OpenVDB 10's nanovdb_convert",
                VERSION.0, VERSION.1
            ),
        });
    }
    Ok(())
}

fn codec_error(codec: u16, at: u64) -> VdbError {
    VdbError::Malformed {
        what: "the NanoVDB codec",
        offset: at,
        message: format!(
            "the grids are compressed (codec {}); lpm reads uncompressed NanoVDB files: write it without -z/-b",
            match codec {
                1 => "zip".to_string(),
                2 => "blosc".to_string(),
                c => c.to_string(),
            }
        ),
    }
}

/// What a grid's file metadata says of it: its active voxel count and their index bounding box,
/// and where the metadata starts in the file.
struct Claims {
    voxels: u64,
    bbox: [i32; 6],
    at: u64,
}

/// The bounding box NanoVDB writes when its statistics are off (`nanovdb_convert -s none`): empty.
const UNSET_BBOX: [i32; 6] = [i32::MAX, i32::MAX, i32::MAX, i32::MIN, i32::MIN, i32::MIN];

fn bbox_at(b: &Buf, at: usize, what: &'static str) -> Result<[i32; 6], VdbError> {
    let mut bbox = [0i32; 6];
    for (i, v) in bbox.iter_mut().enumerate() {
        *v = i32::from_le_bytes(b.get::<4>(at + 4 * i, what)?);
    }
    Ok(bbox)
}

/// What a grid's tree (`TreeData`) and root say of it: node counts (leaves, 16³, 32³), active
/// tile counts, active voxels, and the root's bounding box of the active voxels.
struct TreeClaims {
    nodes: [u64; 3],
    tiles: [u64; 3],
    voxels: u64,
    root_bbox: [i32; 6],
}

/// What the nodes of a grid really hold, counted as they are read.
#[derive(Default)]
struct Seen {
    /// Leaves, 16³ and 32³ nodes.
    nodes: [u64; 3],
    /// Active tiles in 16³ nodes (8³ voxels each), in 32³ nodes (128³) and in the root (4096³).
    tiles: [u64; 3],
    /// Active voxels, those of active tiles included.
    voxels: u64,
}

/// Voxels of an active tile at each level (8³, 128³, 4096³).
const TILE_VOXELS: [u64; 3] = [1 << 9, 1 << 21, 1 << 36];

fn describe_bbox(b: &[i32; 6]) -> String {
    if *b == UNSET_BBOX {
        return "no bounding box".into();
    }
    let dims: [i64; 3] = std::array::from_fn(|i| i64::from(b[i + 3]) - i64::from(b[i]) + 1);
    format!("{} × {} × {} voxels from {:?}", dims[0], dims[1], dims[2], [b[0], b[1], b[2]])
}

/// A grid's sizes as its metadata, tree and root claim them against what its nodes hold: a few
/// changed bytes (a flipped mask bit, a moved tile) make a grid describe another, far larger
/// volume, which would be solved (or its disk and memory claimed) as if it were the file's.
/// NanoVDB writes each of these claims from the nodes, so in a sound file they all agree.
fn check_claims(b: &Buf, tree: &Tree, seen: &Seen, t: &TreeClaims, claims: &Claims) -> Result<(), VdbError> {
    let (counts, tree_tiles, tree_voxels, root_bbox) = (t.nodes, t.tiles, t.voxels, t.root_bbox);
    let held = match tree.active_bbox() {
        Some([lo, hi]) => [lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]].map(|v| v as i32),
        None => UNSET_BBOX,
    };
    let corrupt = |what: &'static str, at: u64, message: String| VdbError::Malformed {
        what,
        offset: at,
        message: format!(
            "{message}; the file is corrupt (NanoVDB writes these from the nodes, so they agree in a sound file)"
        ),
    };
    if seen.nodes != counts || seen.tiles != tree_tiles {
        return Err(corrupt(
            "the tree",
            b.base + GRID_DATA as u64 + 32,
            format!(
                "it counts {counts:?} leaves, 16³ and 32³ nodes and {tree_tiles:?} active tiles, its nodes hold {:?} and {:?}",
                seen.nodes, seen.tiles
            ),
        ));
    }
    if seen.voxels != tree_voxels || seen.voxels != claims.voxels {
        return Err(corrupt(
            "the grid's voxel count",
            claims.at + 24,
            format!(
                "the grid claims {} active voxels (its tree {tree_voxels}), its nodes hold {}",
                claims.voxels, seen.voxels
            ),
        ));
    }
    if root_bbox != claims.bbox || (root_bbox != UNSET_BBOX && root_bbox != held) {
        return Err(corrupt(
            "the grid's bounding box",
            claims.at + 88,
            format!(
                "the grid claims {} (its root {}), its nodes' active voxels span {}",
                describe_bbox(&claims.bbox),
                describe_bbox(&root_bbox),
                describe_bbox(&held)
            ),
        ));
    }
    Ok(())
}

/// One grid buffer (`GridData` onwards) into a sparse tree, its claims checked against its nodes.
fn read_grid(b: &Buf, name: &str, claims: &Claims) -> Result<VdbGrid, VdbError> {
    if b.get::<8>(0, "the grid's magic number")? != MAGIC {
        return Err(b.malformed("the grid", 0, "the grid does not start with NanoVDB's magic number".into()));
    }
    let grid_type = b.u32(636, "the grid type")?;
    if grid_type != GRID_TYPE_FLOAT {
        return Err(VdbError::GridType {
            name: name.to_string(),
            grid_type: format!(
                "NanoVDB grid type {grid_type} (lpm reads Float, type {GRID_TYPE_FLOAT}: not quantised or half)"
            ),
        });
    }
    let placement = read_map(b, name)?;
    let tree_at = GRID_DATA;
    let offset = |level: usize| b.u64(tree_at + 8 * level, "the tree's node offsets");
    let counts: Vec<u32> =
        (0..3).map(|l| b.u32(tree_at + 32 + 4 * l, "the tree's node counts")).collect::<Result<_, _>>()?;
    let root = b.child(tree_at, offset(3)? as i64, ROOT_DATA, "the tree")?;
    // Limits that bound the work whatever the offsets say: no more nodes than the buffer holds.
    let fits = |size: usize| (b.bytes.len() / size) as u64;
    let limits = [counts[0] as u64, counts[1] as u64, counts[2] as u64];
    if limits[0] > fits(LEAF_SIZE) || limits[1] > fits(LOWER_SIZE) || limits[2] > fits(UPPER_SIZE) {
        return Err(b.malformed("the tree", tree_at + 32, format!("node counts {counts:?} cannot fit in the grid")));
    }
    let mut tiles = [0u64; 3];
    for (l, t) in tiles.iter_mut().enumerate() {
        *t = u64::from(b.u32(tree_at + 44 + 4 * l, "the tree's tile counts")?);
    }
    let tree_claims = TreeClaims {
        nodes: limits,
        tiles,
        voxels: b.u64(tree_at + 56, "the tree's voxel count")?,
        root_bbox: bbox_at(b, root, "the root's bounding box")?,
    };
    let table = b.u32(root + 24, "the root table size")? as usize;
    let background = b.f32(root + 28, "the background")?;
    if table > (b.bytes.len() - root) / ROOT_TILE {
        return Err(b.malformed("the root", root + 24, format!("{table} root tiles cannot fit in the grid")));
    }
    let mut tree = Tree::with_background(background);
    let mut seen = Seen::default();
    for t in 0..table {
        let at = root + ROOT_DATA + ROOT_TILE * t;
        let key = b.u64(at, "a root tile")?;
        let origin =
            [(key >> 42) & 0x1f_ffff, (key >> 21) & 0x1f_ffff, key & 0x1f_ffff].map(|v| ((v as u32) << 12) as i32);
        let child = b.i64(at + 8, "a root tile")?;
        let active = b.u32(at + 16, "a root tile")? != 0;
        let value = b.f32(at + 20, "a root tile")?;
        if child == 0 {
            if !tree.add_root_tile(origin, value, active) {
                return Err(b.malformed("the root", at, format!("two entries at {origin:?}")));
            }
            if active {
                seen.tiles[2] += 1;
                seen.voxels = seen.voxels.saturating_add(TILE_VOXELS[2]);
            }
            continue;
        }
        seen.nodes[2] += 1;
        if seen.nodes[2] > limits[2] {
            return Err(b.malformed("the root", at, "more 32³ nodes than the tree counts".into()));
        }
        let upper = b.child(root, child, UPPER_SIZE, "a root tile")?;
        let Some(n5) = tree.add_node5(origin, background) else {
            return Err(b.malformed("the root", at, format!("two entries at {origin:?}")));
        };
        read_upper(b, &mut tree, upper, n5, origin, &mut seen, limits)?;
    }
    check_claims(b, &tree, &seen, &tree_claims, claims)?;
    Ok(VdbGrid { name: name.to_string(), placement, half: false, tree })
}

fn read_upper(
    b: &Buf,
    tree: &mut Tree,
    at: usize,
    n5: u32,
    origin: [i32; 3],
    seen: &mut Seen,
    limits: [u64; 3],
) -> Result<(), VdbError> {
    let value_mask = b.words::<512>(at + 32, "a 32³ node's value mask")?;
    let child_mask = b.words::<512>(at + 32 + 4096, "a 32³ node's child mask")?;
    for slot in 0..32768usize {
        let entry = at + UPPER_TABLE + 8 * slot;
        let o = [slot >> 10, (slot >> 5) & 31, slot & 31].map(|v| (v as i32) << 7);
        let child_origin = [origin[0] + o[0], origin[1] + o[1], origin[2] + o[2]];
        if !bit(&child_mask, slot) {
            let value = b.f32(entry, "a 32³ node's tile")?;
            let active = bit(&value_mask, slot);
            tree.set_node5_tile(n5, origin, slot, value, active);
            if active {
                seen.tiles[1] += 1;
                seen.voxels = seen.voxels.saturating_add(TILE_VOXELS[1]);
            }
            continue;
        }
        seen.nodes[1] += 1;
        if seen.nodes[1] > limits[1] {
            return Err(b.malformed("a 32³ node", entry, "more 16³ nodes than the tree counts".into()));
        }
        let lower = b.child(at, b.i64(entry, "a 32³ node's child")?, LOWER_SIZE, "a 32³ node's child")?;
        let n4 = tree.add_node4(n5, slot, tree.background);
        read_lower(b, tree, lower, n4, child_origin, seen, limits)?;
    }
    Ok(())
}

fn read_lower(
    b: &Buf,
    tree: &mut Tree,
    at: usize,
    n4: u32,
    origin: [i32; 3],
    seen: &mut Seen,
    limits: [u64; 3],
) -> Result<(), VdbError> {
    let value_mask = b.words::<64>(at + 32, "a 16³ node's value mask")?;
    let child_mask = b.words::<64>(at + 32 + 512, "a 16³ node's child mask")?;
    for slot in 0..4096usize {
        let entry = at + LOWER_TABLE + 8 * slot;
        if !bit(&child_mask, slot) {
            let value = b.f32(entry, "a 16³ node's tile")?;
            let active = bit(&value_mask, slot);
            tree.set_node4_tile(n4, origin, slot, value, active);
            if active {
                seen.tiles[0] += 1;
                seen.voxels = seen.voxels.saturating_add(TILE_VOXELS[0]);
            }
            continue;
        }
        seen.nodes[0] += 1;
        if seen.nodes[0] > limits[0] {
            return Err(b.malformed("a 16³ node", entry, "more leaves than the tree counts".into()));
        }
        let leaf = b.child(at, b.i64(entry, "a 16³ node's child")?, LEAF_SIZE, "a 16³ node's child")?;
        let o = [slot >> 8, (slot >> 4) & 15, slot & 15].map(|v| (v as i32) << 3);
        let leaf_origin = [origin[0] + o[0], origin[1] + o[1], origin[2] + o[2]];
        let words = b.words::<8>(leaf + 16, "a leaf's value mask")?;
        let mask: [u64; 8] = std::array::from_fn(|i| words[i]);
        seen.voxels = seen.voxels.saturating_add(mask.iter().map(|w| u64::from(w.count_ones())).sum::<u64>());
        let mut values = [0.0f32; 512];
        for (i, v) in values.iter_mut().enumerate() {
            *v = b.f32(leaf + LEAF_VALUES + 4 * i, "a leaf's values")?;
        }
        tree.add_leaf(n4, slot, leaf_origin, mask, values);
    }
    Ok(())
}

/// The grid's map: index `ijk` is at world `matrix·ijk + translation`; only a uniform positive
/// scale (a diagonal matrix) is accepted, as for OpenVDB grids.
fn read_map(b: &Buf, name: &str) -> Result<Placement, VdbError> {
    let mut m = [0.0f64; 9];
    for (i, v) in m.iter_mut().enumerate() {
        *v = b.f64(384 + 8 * i, "the grid's map")?;
    }
    let mut t = [0.0f64; 3];
    for (i, v) in t.iter_mut().enumerate() {
        *v = b.f64(528 + 8 * i, "the grid's map")?;
    }
    let refuse = |message: String| VdbError::Transform { name: name.to_string(), message };
    if [1, 2, 3, 5, 6, 7].iter().any(|&i| m[i] != 0.0) {
        return Err(refuse(format!(
            "its map rotates or shears the voxels (matrix {m:?}); lpm needs axis-aligned cubic voxels: resample the grid"
        )));
    }
    let scale = [m[0], m[4], m[8]];
    if !scale.iter().chain(&t).all(|v| v.is_finite()) || scale.iter().any(|&v| v <= 0.0) {
        return Err(refuse(format!("its map has a scale of {scale:?} and a translation of {t:?}; the scale must be positive and all values finite")));
    }
    let (lo, hi) = (scale.iter().cloned().fold(f64::MAX, f64::min), scale.iter().cloned().fold(0.0, f64::max));
    if hi - lo > 1e-9 * hi {
        return Err(refuse(format!(
            "its voxels are not cubes (voxel size {scale:?}); lpm needs a uniform scale: resample the grid"
        )));
    }
    Ok(Placement { voxel_size: scale[0], translation: t })
}

/// Reads every float grid of a NanoVDB file held in memory: the entry point for fuzzing (any input
/// gives `Ok` or an error, never a panic).
pub fn read_nanovdb_bytes(bytes: &[u8], name: &str) -> Result<VdbGrid, VdbError> {
    read_nanovdb(&mut std::io::Cursor::new(bytes), bytes.len() as u64, name).map(|(g, _)| g)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file whose one grid claims `size` bytes, of which only the headers are present: the
    /// length is claimed too (as a sparse file's would be).
    fn claiming(size: u64) -> Vec<u8> {
        let version = (VERSION.0 << 21) | (VERSION.1 << 10);
        let mut f = Vec::new();
        f.extend_from_slice(&MAGIC);
        f.extend_from_slice(&version.to_le_bytes());
        f.extend_from_slice(&1u16.to_le_bytes());
        f.extend_from_slice(&0u16.to_le_bytes());
        let mut meta = vec![0u8; FILE_METADATA];
        meta[0..8].copy_from_slice(&size.to_le_bytes());
        meta[8..16].copy_from_slice(&size.to_le_bytes());
        meta[136..140].copy_from_slice(&7u32.to_le_bytes());
        meta[172..176].copy_from_slice(&version.to_le_bytes());
        f.extend_from_slice(&meta);
        f.extend_from_slice(b"density");
        f
    }

    #[test]
    fn a_grid_size_beyond_memory_is_refused_before_it_is_allocated() {
        let bytes = claiming(1 << 40);
        let len = bytes.len() as u64 + (1 << 40);
        // Before the check, this allocated the terabyte (an abort: "memory allocation failed").
        let Err(e) = read_nanovdb(&mut std::io::Cursor::new(&bytes), len, "density") else { panic!("read") };
        assert!(matches!(e, VdbError::Claimed { claimed: 1099511627776, .. }), "{e}");
        assert!(e.to_string().contains("of memory available"), "{e}");
        // A claim within memory but beyond the bytes really there (a file that shrank) is a
        // truncated file.
        let bytes = claiming(4096);
        let Err(e) = read_nanovdb(&mut std::io::Cursor::new(&bytes), bytes.len() as u64 + 4096, "density") else {
            panic!("read")
        };
        assert!(matches!(e, VdbError::Truncated { what: "a grid", .. }), "{e}");
    }
}
