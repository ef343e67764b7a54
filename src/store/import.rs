//! Importers: sources of density that fill bricks for [`BrickStore::create_with`](super::BrickStore::create_with).

use super::grid::{local_index, BrickGrid, BRICK_EDGE};
use super::StoreError;
use memmap2::Mmap;
use std::fs::File;
use std::path::{Path, PathBuf};

/// A raw density file (little-endian f32, x fastest, then y, then z), memory-mapped so a volume
/// larger than memory can be imported brick by brick.
pub struct RawDensity {
    path: PathBuf,
    grid: BrickGrid,
    map: Mmap,
}

/// Opens and maps `path`, checking that it holds exactly `dims` f32 values.
pub fn raw_density(path: &Path, dims: [u32; 3]) -> Result<RawDensity, StoreError> {
    let file = File::open(path).map_err(StoreError::io(path, "open the raw density file"))?;
    let actual = file.metadata().map_err(StoreError::io(path, "read the size of"))?.len();
    let expected = dims.iter().try_fold(4u64, |acc, &d| acc.checked_mul(d as u64));
    if expected != Some(actual) {
        return Err(StoreError::RawSize {
            path: path.to_path_buf(),
            dims,
            expected: expected.unwrap_or(u64::MAX),
            actual,
        });
    }
    // SAFETY: read-only mapping of an input file; it must not be truncated while the import runs.
    let map = unsafe { Mmap::map(&file) }.map_err(StoreError::io(path, "memory-map"))?;
    Ok(RawDensity { path: path.to_path_buf(), grid: BrickGrid::new(dims), map })
}

impl RawDensity {
    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn dims(&self) -> [u32; 3] {
        self.grid.dims
    }

    /// Copies brick `brick`'s voxels into `out` (4096 values, local x fastest); voxels beyond the
    /// volume are set to 0. Rejects NaN, infinite and negative densities, naming the voxel.
    pub fn fill_brick(&self, brick: [u32; 3], out: &mut [f32]) -> Result<(), StoreError> {
        out.fill(0.0);
        let [nx, ny, _] = self.grid.dims.map(|d| d as u64);
        let o = self.grid.brick_origin(brick);
        let e = self.grid.brick_extent(brick);
        for z in 0..e[2] {
            for y in 0..e[1] {
                let row = (o[2] + z) as u64 * ny * nx + (o[1] + y) as u64 * nx + o[0] as u64;
                let start = (row * 4) as usize;
                let bytes = &self.map[start..start + 4 * e[0] as usize];
                for (x, b) in bytes.chunks_exact(4).enumerate() {
                    let value = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                    if !(value.is_finite() && value >= 0.0) {
                        return Err(StoreError::BadDensity {
                            path: self.path.clone(),
                            voxel: [o[0] + x as u32, o[1] + y, o[2] + z],
                            value,
                        });
                    }
                    out[local_index([x, y as usize, z as usize])] = value;
                }
            }
        }
        debug_assert!(e.iter().all(|&e| e <= BRICK_EDGE));
        if brick[0] + 1 == self.grid.bricks[0] && brick[1] + 1 == self.grid.bricks[1] {
            self.release_layer(brick[2]);
        }
        Ok(())
    }

    /// Hands back the pages of brick layer `bz` (16 planes of z) once its last brick is read, so an
    /// import of a file larger than RAM keeps a bounded resident set (the pages stay in the page
    /// cache; a brick of the layer still being read elsewhere faults them back in).
    fn release_layer(&self, bz: u32) {
        let plane = self.grid.dims[0] as usize * self.grid.dims[1] as usize * 4;
        let (first, planes) = (bz as usize * BRICK_EDGE as usize, BRICK_EDGE as usize);
        super::field::release_read_only(&self.map, first * plane, planes * plane);
    }
}
