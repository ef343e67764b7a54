//! A VDB grid as a density source for the brick store: [`vdb_info`] places the volume (for the scene
//! validator, reading only the topology) and [`vdb_density`] reads the whole grid and fills 16³
//! bricks from its 8³ leaves and tiles. The grid stays sparse in memory (see `super::tree`): a
//! few leaves spread over a 4096³ box cost a few leaves, and every brick is filled on its own.

use super::{VdbError, VdbGrid, VdbReader};
use crate::solver::cancel::{self, CancelFlag, Stoppable};
use crate::store::grid::{local_index, BrickGrid};
use crate::store::StoreError;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

/// Where a voxel's value is: in a leaf (leaf, index) or a constant (tile or background).
type Lookup = Result<(usize, usize), f32>;

/// Where a grid's volume sits and how large it is, in lpm's terms.
#[derive(Clone, Debug, PartialEq)]
pub struct VdbVolumeInfo {
    /// Voxels along x, y, z of the active index bounding box (each ≥ 1; may exceed lpm's limits,
    /// which the scene validator checks).
    pub dims: [u64; 3],
    /// The index coordinate of the volume's voxel (0, 0, 0).
    pub index_min: [i32; 3],
    /// World units per voxel edge.
    pub voxel_size: f64,
    /// World position of the volume's corner (the low corner of voxel (0, 0, 0)).
    pub origin: [f64; 3],
    /// Every grid in the file, by name.
    pub grids: Vec<String>,
}

/// `path` opened through the input checks, every read of it stopping once `cancel` is raised.
fn open(path: &Path, cancel: Option<CancelFlag>) -> Result<VdbReader<BufReader<Stoppable<File>>>, StoreError> {
    let file = crate::input::open(path)?;
    VdbReader::new(BufReader::with_capacity(1 << 16, Stoppable { inner: file, cancel }))
        .map_err(|e| stopped_or(cancel, vdb_error(path, e)))
}

/// A failed read as [`StoreError::Cancelled`] when it failed because `cancel` was raised.
fn stopped_or(cancel: Option<CancelFlag>, e: StoreError) -> StoreError {
    if cancel::raised(cancel) {
        StoreError::Cancelled
    } else {
        e
    }
}

pub(crate) fn vdb_error(path: &Path, source: VdbError) -> StoreError {
    StoreError::Vdb { path: path.to_path_buf(), source }
}

fn info_of(path: &Path, grid: &VdbGrid, grids: Vec<String>) -> Result<VdbVolumeInfo, StoreError> {
    let Some([lo, hi]) = grid.tree.active_bbox() else {
        return Err(vdb_error(
            path,
            VdbError::Transform {
                name: grid.name.clone(),
                message: "it has no active voxels: there is no volume to solve".into(),
            },
        ));
    };
    let h = grid.placement.voxel_size;
    let t = grid.placement.translation;
    Ok(VdbVolumeInfo {
        dims: std::array::from_fn(|i| (hi[i] - lo[i] + 1) as u64),
        // The bbox comes from i32 coordinates, so it fits.
        index_min: lo.map(|v| v as i32),
        voxel_size: h,
        origin: std::array::from_fn(|i| t[i] + (lo[i] as f64 - 0.5) * h),
        grids,
    })
}

/// Grid `grid` of the NanoVDB file `path` (see [`crate::store::nanovdb`]) and the file's grid names.
fn read_nanovdb(path: &Path, grid: &str, cancel: Option<CancelFlag>) -> Result<(VdbGrid, Vec<String>), StoreError> {
    let file = crate::input::open(path)?;
    let len = file.metadata().map_err(StoreError::io(path, "read the size of"))?.len();
    let mut reader = BufReader::with_capacity(1 << 16, Stoppable { inner: file, cancel });
    crate::store::nanovdb::read_nanovdb(&mut reader, len, grid).map_err(|e| stopped_or(cancel, vdb_error(path, e)))
}

/// Places grid `grid` of `path` (topology only: fast, and bounded by the file's node count). A
/// NanoVDB file (recognised by its magic number) is read whole. Called while a scene is loaded,
/// where no job has handed a flag yet: the reads stop at the process's own
/// ([`CancelFlag::process`], raised by the `lpm` binary's SIGTERM), as [`StoreError::Cancelled`].
pub fn vdb_info(path: &Path, grid: &str) -> Result<VdbVolumeInfo, StoreError> {
    let process = Some(CancelFlag::process());
    if crate::store::nanovdb::is_nanovdb(path) {
        let (g, grids) = read_nanovdb(path, grid, process)?;
        return info_of(path, &g, grids);
    }
    let mut r = open(path, process)?;
    let grids = r.grids().into_iter().map(|g| g.name).collect();
    let g = r.read_grid(grid, false).map_err(|e| stopped_or(process, vdb_error(path, e)))?;
    info_of(path, &g, grids)
}

/// A grid read into memory (sparse), ready to fill bricks.
pub struct VdbDensity {
    path: PathBuf,
    grid: VdbGrid,
    info: VdbVolumeInfo,
    bricks: BrickGrid,
}

/// Reads grid `grid` of `path` whole. `dims` and `index_min` place the volume as the scene was
/// validated (from [`vdb_info`]); a file that changed since gives an error rather than a different
/// volume.
pub fn vdb_density(path: &Path, grid: &str, dims: [u32; 3], index_min: [i32; 3]) -> Result<VdbDensity, StoreError> {
    vdb_density_until(path, grid, dims, index_min, None)
}

/// [`vdb_density`], stopping with [`StoreError::Cancelled`] once `cancel` is raised: every read of
/// the file looks at it (a grid of many leaves takes seconds to read and decompress).
pub fn vdb_density_until(
    path: &Path,
    grid: &str,
    dims: [u32; 3],
    index_min: [i32; 3],
    cancel: Option<CancelFlag>,
) -> Result<VdbDensity, StoreError> {
    let g = if crate::store::nanovdb::is_nanovdb(path) {
        read_nanovdb(path, grid, cancel)?.0
    } else {
        open(path, cancel)?.read_grid(grid, true).map_err(|e| stopped_or(cancel, vdb_error(path, e)))?
    };
    let info = info_of(path, &g, Vec::new())?;
    if info.dims != dims.map(u64::from) || info.index_min != index_min {
        return Err(StoreError::Corrupt {
            path: path.to_path_buf(),
            message: format!(
                "grid \"{grid}\" now spans {:?} voxels from index {:?}, but the scene was validated with {dims:?} from {index_min:?}: the file changed",
                info.dims, info.index_min
            ),
        });
    }
    Ok(VdbDensity { path: path.to_path_buf(), grid: g, info, bricks: BrickGrid::new(dims) })
}

/// Grid `grid` of `path` read over another grid's voxels (`dims` from `index_min`, the density's),
/// whatever its own active bounding box: a per-voxel field such as emission, which usually covers
/// only part of the density. Voxels outside its active voxels read its background value.
pub fn vdb_grid_over(path: &Path, grid: &str, dims: [u32; 3], index_min: [i32; 3]) -> Result<VdbDensity, StoreError> {
    // A NanoVDB file named by `vdb`/`nvdb` holds its other grids too (as `vdb_density` reads it).
    let g = if crate::store::nanovdb::is_nanovdb(path) {
        read_nanovdb(path, grid, None)?.0
    } else {
        open(path, None)?.read_grid(grid, true).map_err(|e| vdb_error(path, e))?
    };
    let mut info = info_of(path, &g, Vec::new())?;
    info.dims = dims.map(u64::from);
    info.index_min = index_min;
    Ok(VdbDensity { path: path.to_path_buf(), grid: g, info, bricks: BrickGrid::new(dims) })
}

impl VdbDensity {
    pub fn info(&self) -> &VdbVolumeInfo {
        &self.info
    }

    pub fn grid(&self) -> &VdbGrid {
        &self.grid
    }

    /// Copies brick `brick`'s voxels into `out` (4096 values, local x fastest); voxels beyond the
    /// volume are 0. Rejects NaN, infinite and negative densities, naming the voxel (in volume
    /// coordinates).
    pub fn fill_brick(&self, brick: [u32; 3], out: &mut [f32]) -> Result<(), StoreError> {
        out.fill(0.0);
        let o = self.bricks.brick_origin(brick);
        let e = self.bricks.brick_extent(brick);
        let lo = self.info.index_min;
        let tree = &self.grid.tree;
        let first: [i32; 3] = std::array::from_fn(|i| lo[i] + o[i] as i32);
        let last: [i32; 3] = std::array::from_fn(|i| first[i] + e[i] as i32 - 1);
        if let Some(value) = tree.constant_over(first, last) {
            if !(value.is_finite() && value >= 0.0) {
                return Err(StoreError::BadDensity { path: self.path.clone(), voxel: o, value });
            }
            if value != 0.0 {
                for z in 0..e[2] as usize {
                    for y in 0..e[1] as usize {
                        for x in 0..e[0] as usize {
                            out[local_index([x, y, z])] = value;
                        }
                    }
                }
            }
            return Ok(());
        }
        for z in 0..e[2] {
            for y in 0..e[1] {
                // A row crosses at most 3 leaf-sized blocks: look each up once.
                let mut cached: Option<(i32, Lookup)> = None;
                for x in 0..e[0] {
                    let v = [o[0] + x, o[1] + y, o[2] + z];
                    let c = [lo[0] + v[0] as i32, lo[1] + v[1] as i32, lo[2] + v[2] as i32];
                    let block = c[0] >> 3;
                    let found = match cached {
                        Some((b, f)) if b == block => f,
                        _ => {
                            let f = tree.lookup(c);
                            cached = Some((block, f));
                            f
                        }
                    };
                    let value = match found {
                        Ok((leaf, _)) => {
                            let i = (((c[0] & 7) << 6) | ((c[1] & 7) << 3) | (c[2] & 7)) as usize;
                            tree.leaf(leaf).map_or(tree.background, |l| l[i])
                        }
                        Err(value) => value,
                    };
                    if !(value.is_finite() && value >= 0.0) {
                        return Err(StoreError::BadDensity { path: self.path.clone(), voxel: v, value });
                    }
                    out[local_index([x as usize, y as usize, z as usize])] = value;
                }
            }
        }
        Ok(())
    }
}
