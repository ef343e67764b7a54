//! Exporting fields as OpenVDB files (`fluence.vdb`, `source.vdb`) that Houdini, Blender, Nuke and
//! OpenVDB's own tools load directly.
//!
//! Why our own writer: no well-kept Rust crate writes OpenVDB (the `vdb-rs` crate only reads, and
//! OpenVDB itself is a large C++ library with TBB, Boost-era build machinery and Blosc behind it).
//! Writing is much smaller than reading, because we choose the encoding: format version 224, one
//! tree 5-4-3 of `float` values (or half floats, `_HalfFloat`), no tiles, every value of every node
//! stored (`NO_MASK_AND_ALL_VALS`), each block zlib-compressed (`COMPRESS_ZIP`, stored plain when
//! zlib does not make it smaller, exactly as OpenVDB's `zipToStream` does). The layout is the one
//! [`crate::store::vdb`] reads (see that module for the format); OpenVDB's reader
//! (`python3-openvdb` in `tests/it/vdb_output.rs`) is the test that the files are right.
//!
//! Over 450 lines because the file is written top to bottom in the order its bytes appear (header,
//! grid descriptors, metadata, transform, topology, values): one format in one file reads against
//! the OpenVDB layout without jumping between modules.
//!
//! A field of several components (RGB fluence, a source per storage direction) is written as one
//! float grid per component (`fluence_r`, `fluence_g`, `fluence_b`), not as one `Vec3s` grid:
//! Houdini's and Blender's volume shaders read scalar float grids by name (a density-like field
//! goes into a multiply or an emission input per channel), every OpenVDB tool handles them, a
//! source with 72 components has no vector type at all, and a scalar grid compresses and
//! half-rounds each channel on its own.
//!
//! What is written, per grid:
//! - **topology**: only leaves (8³ voxels) that overlap a stored brick (a brick with medium); the
//!   voxels of stored bricks are *active*, every other voxel is inactive and holds the background 0
//!   (so a fluence grid's unsolved empty space, NaN in `fluence.raw`, is simply absent);
//! - **placement**: lpm voxel `v` is index coordinate `index_min + v`, and the transform is a
//!   `UniformScaleTranslateMap` putting index `ijk`'s centre at `translation + h·ijk`; for a VDB
//!   input `index_min` is the input's own active box corner, so the output lies on the input's
//!   index grid with the same transform;
//! - **metadata**: `name` and `is_saved_as_half_float` (OpenVDB reads the grid's name and half
//!   flag from there), `class = "fog volume"` (how Houdini and Blender recognise a density-like
//!   grid) and `lpm_quantity` / `lpm_units` (strings).
//!
//! Grids are written leaf by leaf in tree order straight from the memory-mapped field, so memory
//! grows with the number of leaves (a few words each), never with the volume. The file's UUID is a
//! hash of its content, so the same field gives the same bytes run after run.

use super::{write_atomic, FieldMeta, OutputError};
use crate::store::{BrickStore, Field, BRICK_VOXELS};
use std::io::{self, Seek, SeekFrom, Write};
use std::path::Path;

/// Precision of the values in an exported VDB (`--vdb-precision`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum VdbPrecision {
    /// 32-bit floats: exactly the values of `<base>.raw`.
    #[default]
    Float,
    /// 16-bit floats (OpenVDB's `saveFloatAsHalf`): half the size; relative rounding 2⁻¹¹, and values
    /// beyond ±65504 (half's largest) are clamped to it.
    Half,
}

/// Where the exported grid lies: lpm voxel `v` is VDB index `index_min + v`, whose centre is at
/// world `translation + voxel_size·(index_min + v)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VdbPlacement {
    pub index_min: [i32; 3],
    pub voxel_size: f64,
    pub translation: [f64; 3],
}

impl VdbPlacement {
    /// The placement of a volume whose low corner is at world `origin` with voxels of edge `h`,
    /// its voxel (0, 0, 0) being index `index_min` (a VDB input's box corner; else 0).
    pub fn new(origin: [f64; 3], voxel_size: f64, index_min: [i32; 3]) -> VdbPlacement {
        let translation = std::array::from_fn(|a| origin[a] + (0.5 - f64::from(index_min[a])) * voxel_size);
        VdbPlacement { index_min, voxel_size, translation }
    }
}

/// The grid names of a field's components in a VDB file: the field's name alone for one grey
/// component, else `<base>_<component>` with dots made underscores (`fluence_r`, `source_d3_g`).
pub fn vdb_grid_names(base: &str, components: &[String]) -> Vec<String> {
    if components.len() == 1 && components[0] == "grey" {
        return vec![base.to_string()];
    }
    components.iter().map(|c| format!("{base}_{}", c.replace('.', "_"))).collect()
}

/// Writes every component of `field` (a field of `store`) as one float grid of the VDB file
/// `path`, atomically; the grids are named by [`vdb_grid_names`] from `base` and `meta.components`.
pub fn export_vdb(
    field: &Field,
    store: &BrickStore,
    path: &Path,
    base: &str,
    meta: &FieldMeta,
    placement: VdbPlacement,
    precision: VdbPrecision,
) -> Result<(), OutputError> {
    export_vdb_until(field, store, path, base, meta, placement, precision, None)
}

/// [`export_vdb`], stopping with [`OutputError::Cancelled`] once `cancel` is raised (looked at at
/// every write; the temporary is removed).
#[allow(clippy::too_many_arguments)] // export_vdb's and the flag
pub fn export_vdb_until(
    field: &Field,
    store: &BrickStore,
    path: &Path,
    base: &str,
    meta: &FieldMeta,
    placement: VdbPlacement,
    precision: VdbPrecision,
    cancel: Option<crate::solver::cancel::CancelFlag>,
) -> Result<(), OutputError> {
    let invalid = |message: String| OutputError::Invalid { path: path.to_path_buf(), message };
    if field.grid() != store.grid() || meta.components.len() != field.components() as usize {
        return Err(invalid(format!(
            "field {} ({} components over {:?}) does not match its description ({} components) or the store ({:?})",
            field.name(),
            field.components(),
            field.grid().dims,
            meta.components.len(),
            store.grid().dims
        )));
    }
    let grid = *store.grid();
    let dims = grid.dims;
    let top: [i64; 3] = std::array::from_fn(|a| i64::from(placement.index_min[a]) + i64::from(dims[a]));
    if top.iter().any(|&t| t > i64::from(i32::MAX)) {
        return Err(invalid(format!(
            "the volume's index box {:?} + {dims:?} does not fit OpenVDB's 32-bit coordinates",
            placement.index_min
        )));
    }
    // The leaves overlapping a stored brick, in tree order.
    let mut leaves = Vec::new();
    for brick in 0..grid.brick_count() {
        if field.stored_index(brick).is_none() {
            continue;
        }
        let b = grid.brick_coords(brick);
        let (o, e) = (grid.brick_origin(b), grid.brick_extent(b));
        let lo: [i32; 3] = std::array::from_fn(|a| (placement.index_min[a] + o[a] as i32) >> 3);
        let hi: [i32; 3] = std::array::from_fn(|a| (placement.index_min[a] + (o[a] + e[a] - 1) as i32) >> 3);
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    leaves.push([x << 3, y << 3, z << 3]);
                }
            }
        }
    }
    leaves.sort_unstable_by_key(|&c| tree_order(c));
    leaves.dedup();

    // Leaf voxel n (x slowest) of the leaf at `origin`: its brick and index in the brick, when it
    // lies in a stored brick of the volume (an active voxel).
    let locate = |origin: [i32; 3], n: usize| -> Option<(usize, usize)> {
        let p = [origin[0] + (n >> 6) as i32, origin[1] + ((n >> 3) & 7) as i32, origin[2] + (n & 7) as i32];
        let v: [i64; 3] = std::array::from_fn(|a| i64::from(p[a]) - i64::from(placement.index_min[a]));
        if (0..3).any(|a| v[a] < 0 || v[a] >= i64::from(dims[a])) {
            return None;
        }
        let (brick, local) = grid.locate(v.map(|x| x as u32));
        field.stored_index(brick).map(|_| (brick, local))
    };
    let mask = |origin: [i32; 3]| {
        let mut mask = [0u64; 8];
        for n in 0..512 {
            if locate(origin, n).is_some() {
                mask[n >> 6] |= 1 << (n & 63);
            }
        }
        mask
    };
    let mut clamped = 0u64;
    let mut visited = 0u64;
    let mut values = |c: u32, origin: [i32; 3], out: &mut [f32; 512]| {
        for (n, o) in out.iter_mut().enumerate() {
            *o = match locate(origin, n) {
                Some((brick, local)) => field.brick(brick).map_or(0.0, |d| d[c as usize * BRICK_VOXELS + local]),
                None => 0.0,
            };
            if precision == VdbPrecision::Half && o.abs() > HALF_MAX {
                *o = HALF_MAX.copysign(*o);
                clamped += 1;
            }
        }
        visited += 1;
        if visited % 4096 == 0 {
            // Hand back the pages read so far (see `store::Field` on resident memory).
            field.release_all();
        }
    };
    let grids: Vec<GridOut> = vdb_grid_names(base, &meta.components)
        .into_iter()
        .zip(&meta.components)
        .enumerate()
        .map(|(c, (name, component))| GridOut {
            name,
            metadata: vec![
                ("class".to_string(), "fog volume".to_string()),
                ("lpm_quantity".to_string(), format!("{} ({component})", meta.quantity)),
                ("lpm_units".to_string(), meta.units.clone()),
            ],
            component: c as u32,
        })
        .collect();
    let written = write_atomic(path, |w| {
        let mut w = crate::solver::cancel::Stoppable { inner: w, cancel };
        write_vdb(&mut w, &leaves, &grids, placement, precision, &mask, &mut values)
    });
    super::export::cancelled_or(cancel, written)?;
    field.release_all();
    if clamped > 0 {
        tracing::warn!(
            "{}: {clamped} value(s) beyond ±{HALF_MAX} (the largest half float) were clamped to it; use --vdb-precision float to keep them",
            path.display()
        );
    }
    Ok(())
}

/// The largest finite half float.
const HALF_MAX: f32 = 65504.0;

/// Fills a leaf's 512 values (x slowest) for a grid's component: `(component, leaf origin, values)`.
pub type LeafValues<'a> = dyn FnMut(u32, [i32; 3], &mut [f32; 512]) + 'a;

/// One grid to write: its name, string metadata, and which component of the leaf source it is.
pub struct GridOut {
    pub name: String,
    pub metadata: Vec<(String, String)>,
    pub component: u32,
}

/// Sort key putting leaf origins in the order OpenVDB's tree iterates them: root children by
/// origin (x, then y, then z), then 32³ node slots (x slowest), then 16³ node slots.
pub fn tree_order(c: [i32; 3]) -> ([i32; 3], [i32; 3], [i32; 3]) {
    (c.map(|v| v >> 12), c.map(|v| v >> 7), c.map(|v| v >> 3))
}

// Format constants (see `store::vdb`).
const MAGIC: [u8; 8] = [0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0];
const FILE_VERSION: u32 = 224;
/// The OpenVDB library version the file claims to come from: the oldest whose format it is.
const LIBRARY_VERSION: (u32, u32) = (10, 0);
const COMPRESS_ZIP: u32 = 0x1;
const NO_MASK_AND_ALL_VALS: u8 = 6;

/// A writer that counts bytes and hashes them (for the content UUID).
struct Counting<'w, W> {
    inner: &'w mut W,
    pos: u64,
    hash: [u64; 2],
}

impl<W: Write> Counting<'_, W> {
    fn put(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.inner.write_all(bytes)?;
        self.pos += bytes.len() as u64;
        // FNV-1a, twice with different offsets: a stable 128-bit fingerprint.
        for &b in bytes {
            for h in &mut self.hash {
                *h = (*h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3);
            }
        }
        Ok(())
    }
    fn u8(&mut self, v: u8) -> io::Result<()> {
        self.put(&[v])
    }
    fn u32(&mut self, v: u32) -> io::Result<()> {
        self.put(&v.to_le_bytes())
    }
    fn i32(&mut self, v: i32) -> io::Result<()> {
        self.put(&v.to_le_bytes())
    }
    fn i64(&mut self, v: i64) -> io::Result<()> {
        self.put(&v.to_le_bytes())
    }
    fn f64(&mut self, v: f64) -> io::Result<()> {
        self.put(&v.to_le_bytes())
    }
    fn string(&mut self, s: &str) -> io::Result<()> {
        self.u32(s.len() as u32)?;
        self.put(s.as_bytes())
    }
    fn coord(&mut self, c: [i32; 3]) -> io::Result<()> {
        c.iter().try_for_each(|&v| self.i32(v))
    }
    fn vec3d(&mut self, v: [f64; 3]) -> io::Result<()> {
        v.iter().try_for_each(|&x| self.f64(x))
    }
    fn mask(&mut self, words: &[u64]) -> io::Result<()> {
        words.iter().try_for_each(|w| self.put(&w.to_le_bytes()))
    }
}

/// Writes a VDB file of `grids` over `leaves` (leaf origins, multiples of 8, sorted by
/// [`tree_order`], no duplicates) to `w`. `mask(origin)` is the active mask of the leaf at
/// `origin` (bit n for voxel n, x slowest, z fastest), the same for every grid;
/// `values(component, origin, out)` fills the leaf's 512 values for a grid's component.
pub fn write_vdb<W: Write + Seek>(
    w: &mut W,
    leaves: &[[i32; 3]],
    grids: &[GridOut],
    placement: VdbPlacement,
    precision: VdbPrecision,
    mask: &dyn Fn([i32; 3]) -> [u64; 8],
    values: &mut LeafValues,
) -> io::Result<()> {
    debug_assert!(leaves.windows(2).all(|p| tree_order(p[0]) < tree_order(p[1])));
    let mut s = Counting { inner: w, pos: 0, hash: [0xcbf2_9ce4_8422_2325, 0x8422_2325_cbf2_9ce4] };
    s.put(&MAGIC)?;
    s.u32(FILE_VERSION)?;
    s.u32(LIBRARY_VERSION.0)?;
    s.u32(LIBRARY_VERSION.1)?;
    s.u8(1)?; // the file has grid offsets
    let uuid_at = s.pos;
    s.put(&[b'0'; 36])?; // the UUID, filled in at the end
    s.i32(0)?; // no file metadata
    s.i32(grids.len() as i32)?;
    for g in grids {
        // The grid descriptor: unique name, type, instance parent, then three offsets.
        s.string(&g.name)?;
        s.string(match precision {
            VdbPrecision::Float => "Tree_float_5_4_3",
            VdbPrecision::Half => "Tree_float_5_4_3_HalfFloat",
        })?;
        s.string("")?;
        let offsets_at = s.pos;
        s.put(&[0; 24])?;
        let grid_pos = s.pos;
        s.u32(COMPRESS_ZIP)?;
        // OpenVDB takes a grid's name and its half flag from these two entries of its metadata
        // (the descriptor's copies only find the grid), so they are always written.
        s.i32(g.metadata.len() as i32 + 2)?;
        s.string("name")?;
        s.string("string")?;
        s.string(&g.name)?;
        s.string("is_saved_as_half_float")?;
        s.string("bool")?;
        s.u32(1)?;
        s.u8(u8::from(precision == VdbPrecision::Half))?;
        for (key, value) in &g.metadata {
            s.string(key)?;
            s.string("string")?;
            s.string(value)?;
        }
        write_transform(&mut s, placement)?;
        write_topology(&mut s, leaves, precision, mask)?;
        let block_pos = s.pos;
        // `Tree::writeBuffers`: per leaf, its value mask again, then its values.
        let mut leaf = [0.0f32; 512];
        for &origin in leaves {
            values(g.component, origin, &mut leaf);
            s.mask(&mask(origin))?;
            write_values(&mut s, &leaf, precision)?;
        }
        let end_pos = s.pos;
        s.inner.seek(SeekFrom::Start(offsets_at))?;
        for p in [grid_pos, block_pos, end_pos] {
            s.inner.write_all(&(p as i64).to_le_bytes())?;
        }
        s.inner.seek(SeekFrom::Start(end_pos))?;
    }
    // A UUID from the content (OpenVDB writes a random one; ours makes the same field give the same
    // bytes). 8-4-4-4-12 hexadecimal digits.
    let hex: String = s.hash.iter().map(|h| format!("{h:016x}")).collect();
    let uuid = format!("{}-{}-{}-{}-{}", &hex[0..8], &hex[8..12], &hex[12..16], &hex[16..20], &hex[20..32]);
    let end = s.pos;
    s.inner.seek(SeekFrom::Start(uuid_at))?;
    s.inner.write_all(uuid.as_bytes())?;
    s.inner.seek(SeekFrom::Start(end))?;
    Ok(())
}

/// `UniformScaleTranslateMap`: translation, scale, then the derived values OpenVDB stores with it
/// (voxel size, inverse scale, its square, half of it).
fn write_transform<W: Write>(s: &mut Counting<W>, p: VdbPlacement) -> io::Result<()> {
    let h = p.voxel_size;
    s.string("UniformScaleTranslateMap")?;
    s.vec3d(p.translation)?;
    for v in [h, h, 1.0 / h, 1.0 / (h * h), 0.5 / h] {
        s.vec3d([v; 3])?;
    }
    Ok(())
}

/// The tree's topology (`Tree::writeTopology`): one buffer per leaf, the background (0, at full
/// precision even for half grids), a root table of no tiles and one child per 4096³ block holding
/// leaves; each 32³ node's child mask, empty value mask and (zero) tile values, then its 16³ nodes
/// likewise, each followed by its leaves' value masks.
fn write_topology<W: Write>(
    s: &mut Counting<W>,
    leaves: &[[i32; 3]],
    precision: VdbPrecision,
    mask: &dyn Fn([i32; 3]) -> [u64; 8],
) -> io::Result<()> {
    s.i32(1)?;
    s.put(&0f32.to_le_bytes())?;
    let roots = group(leaves, 12);
    s.u32(0)?;
    s.u32(roots.len() as u32)?;
    for root in roots {
        s.coord(root[0].map(|v| v >> 12 << 12))?;
        let nodes4 = group(root, 7);
        let mut child = vec![0u64; 512];
        for n in &nodes4 {
            set_bit(&mut child, slot(n[0], 5, 7));
        }
        s.mask(&child)?;
        s.mask(&[0; 512])?;
        write_values(s, &[0.0; 1 << 15], precision)?;
        for n4 in nodes4 {
            let mut child = vec![0u64; 64];
            for l in n4 {
                set_bit(&mut child, slot(*l, 4, 3));
            }
            s.mask(&child)?;
            s.mask(&[0; 64])?;
            write_values(s, &[0.0; 1 << 12], precision)?;
            for &l in n4 {
                s.mask(&mask(l))?;
            }
        }
    }
    Ok(())
}

/// Splits `leaves` (in tree order) into runs sharing the same `c >> shift`.
fn group(leaves: &[[i32; 3]], shift: u32) -> Vec<&[[i32; 3]]> {
    let mut out = Vec::new();
    let mut start = 0;
    for i in 1..=leaves.len() {
        if i == leaves.len() || leaves[i].map(|v| v >> shift) != leaves[start].map(|v| v >> shift) {
            out.push(&leaves[start..i]);
            start = i;
        }
    }
    out
}

/// Slot of coordinate `c` in a node of 2^`log2` children per axis of 2^`child_log2` voxels each
/// (x slowest).
fn slot(c: [i32; 3], log2: u32, child_log2: u32) -> usize {
    let m = (1 << log2) - 1;
    let i = c.map(|v| ((v >> child_log2) & m) as usize);
    (i[0] << (2 * log2)) | (i[1] << log2) | i[2]
}

fn set_bit(words: &mut [u64], n: usize) {
    words[n >> 6] |= 1 << (n & 63);
}

/// A node's values (`io::writeCompressedValues` without mask compression): the metadata byte, then
/// every value, as f32 or half, through zlib.
fn write_values<W: Write>(s: &mut Counting<W>, values: &[f32], precision: VdbPrecision) -> io::Result<()> {
    s.u8(NO_MASK_AND_ALL_VALS)?;
    let mut bytes = Vec::with_capacity(values.len() * 4);
    match precision {
        VdbPrecision::Float => values.iter().for_each(|v| bytes.extend_from_slice(&v.to_le_bytes())),
        VdbPrecision::Half => {
            values.iter().for_each(|v| bytes.extend_from_slice(&half::f16::from_f32(*v).to_le_bytes()))
        }
    }
    zip_block(s, &bytes)
}

/// OpenVDB's `zipToStream`: the zlib stream's length then the stream, or, when zlib does not make
/// the block smaller, minus the block's length then the plain bytes.
fn zip_block<W: Write>(s: &mut Counting<W>, bytes: &[u8]) -> io::Result<()> {
    let mut z = flate2::write::ZlibEncoder::new(Vec::with_capacity(bytes.len() / 2), flate2::Compression::fast());
    z.write_all(bytes)?;
    let zipped = z.finish()?;
    if zipped.len() < bytes.len() {
        s.i64(zipped.len() as i64)?;
        s.put(&zipped)
    } else {
        s.i64(-(bytes.len() as i64))?;
        s.put(bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::vdb::read_all;

    /// What lpm's own reader makes of a file written here (OpenVDB's reader is the test in
    /// tests/it/vdb_output.rs): the values, the active box, the transform, the names, both
    /// precisions, negative coordinates and leaves under different root nodes.
    #[test]
    fn written_grids_read_back_through_the_vdb_reader() {
        let mut leaves = vec![[-8, 0, 0], [0, 0, 0], [0, 8, 16], [4096, -4096, 8], [120, 0, 0], [128, 0, 0]];
        leaves.sort_unstable_by_key(|&c| tree_order(c));
        let value = |c: u32, p: [i32; 3]| (p[0] * 7 + p[1] * 3 - p[2]) as f32 * 0.25 + c as f32;
        let active = |p: [i32; 3]| (p[0] + p[1] + p[2]).rem_euclid(3) != 0;
        let mask = |o: [i32; 3]| {
            let mut m = [0u64; 8];
            for n in 0..512 {
                if active([o[0] + (n >> 6) as i32, o[1] + ((n >> 3) & 7) as i32, o[2] + (n & 7) as i32]) {
                    set_bit(&mut m, n);
                }
            }
            m
        };
        let placement = VdbPlacement::new([1.0, -2.0, 0.5], 0.25, [-3, 4, 5]);
        for precision in [VdbPrecision::Float, VdbPrecision::Half] {
            let grids: Vec<GridOut> = ["a", "b"]
                .iter()
                .enumerate()
                .map(|(c, n)| GridOut { name: n.to_string(), metadata: vec![], component: c as u32 })
                .collect();
            let mut bytes = io::Cursor::new(Vec::new());
            let mut values = |c: u32, o: [i32; 3], out: &mut [f32; 512]| {
                for (n, v) in out.iter_mut().enumerate() {
                    let p = [o[0] + (n >> 6) as i32, o[1] + ((n >> 3) & 7) as i32, o[2] + (n & 7) as i32];
                    *v = if active(p) { value(c, p) } else { 0.0 };
                }
            };
            write_vdb(&mut bytes, &leaves, &grids, placement, precision, &mask, &mut values).unwrap();
            let read = read_all(bytes.get_ref()).unwrap();
            assert_eq!(read.iter().map(|g| g.name.as_str()).collect::<Vec<_>>(), ["a", "b"]);
            for (c, g) in read.iter().enumerate() {
                assert_eq!(g.half, precision == VdbPrecision::Half);
                assert_eq!(g.placement.voxel_size, 0.25);
                assert_eq!(g.placement.translation, placement.translation);
                assert_eq!(g.tree.leaf_count(), leaves.len());
                for &o in &leaves {
                    for n in 0..512usize {
                        let p = [o[0] + (n >> 6) as i32, o[1] + ((n >> 3) & 7) as i32, o[2] + (n & 7) as i32];
                        let want = if active(p) { value(c as u32, p) } else { 0.0 };
                        let want = match precision {
                            VdbPrecision::Float => want,
                            VdbPrecision::Half => half::f16::from_f32(want).to_f32(),
                        };
                        assert_eq!(g.tree.value(p).to_bits(), want.to_bits(), "grid {c} at {p:?}");
                    }
                }
                let [lo, hi] = g.tree.active_bbox().unwrap();
                assert_eq!((lo, hi), ([-8, -4096, 0], [4103, 15, 23]));
            }
            // The same content gives the same bytes (the UUID is a content hash).
            let mut again = io::Cursor::new(Vec::new());
            write_vdb(&mut again, &leaves, &grids, placement, precision, &mask, &mut values).unwrap();
            assert_eq!(again.get_ref(), bytes.get_ref());
        }
        // Centre of index ijk at translation + h·ijk: the corner of index_min is the volume's origin.
        assert_eq!(placement.translation[0] + 0.25 * (-3.0 - 0.5), 1.0);
    }

    #[test]
    fn grid_names_follow_the_components() {
        assert_eq!(vdb_grid_names("fluence", &["grey".into()]), ["fluence"]);
        assert_eq!(
            vdb_grid_names("fluence", &["r".into(), "g".into(), "b".into()]),
            ["fluence_r", "fluence_g", "fluence_b"]
        );
        assert_eq!(vdb_grid_names("source", &["d0.r".into(), "d1.b".into()]), ["source_d0_r", "source_d1_b"]);
    }
}
