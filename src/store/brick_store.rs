//! [`BrickStore`]: creating the density bricks once, reopening them, and making fields beside them.

use super::atomic::write_atomic_io;
use super::field::{Coverage, Field};
use super::grid::{BrickGrid, BRICK_VOXELS};
use super::resident::{PageHolding, Residency};
use super::table::{BrickTable, DENSITY_FILE};
use super::StoreError;
use memmap2::Mmap;
use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

const TABLE_FILE: &str = "bricks.json";
/// Bricks filled per worker between two writes: large enough to amortise spawning the workers,
/// small enough (64 × 16 KiB) that the batch buffer stays small.
const BRICKS_PER_WORKER: usize = 64;

/// The density volume in bricks, memory-mapped read-only, and the directory its fields live in.
pub struct BrickStore {
    dir: PathBuf,
    table: Arc<BrickTable>,
    /// Whether passes keep the pages of the store and its fields resident ([`super::resident`]).
    pages: Arc<PageHolding>,
    /// `density.bricks`: the occupied bricks, 4096 f32 each, in slot order.
    density: Mmap,
}

impl BrickStore {
    /// Creates the store's files in `dir` (created if missing). `fill(brick_coords, out)` is called
    /// for every brick, in parallel, with `out` = 4096 zeros to overwrite (local x fastest); voxels
    /// beyond `dims` are forced back to zero afterwards. All-zero bricks are recorded as empty and take
    /// no space in `density.bricks`. Both files are written atomically: on error neither is left
    /// half-written.
    pub fn create_with(
        dir: &Path,
        dims: [u32; 3],
        voxel_size: f64,
        fill: impl Fn([u32; 3], &mut [f32]) -> Result<(), StoreError> + Sync,
    ) -> Result<BrickStore, StoreError> {
        Self::create_keeping(dir, dims, voxel_size, |_| false, fill)
    }

    /// [`BrickStore::create_with`], where every brick whose index `keep` accepts is recorded as
    /// occupied even when all its voxels are zero: it is stored and solved, so its vacuum voxels
    /// get their light. (The doubled volume of `solver::unfold` keeps so the bricks it folds back
    /// into occupied bricks of the volume: an empty brick there would read as zero fluence.)
    pub fn create_keeping(
        dir: &Path,
        dims: [u32; 3],
        voxel_size: f64,
        keep: impl Fn(usize) -> bool,
        fill: impl Fn([u32; 3], &mut [f32]) -> Result<(), StoreError> + Sync,
    ) -> Result<BrickStore, StoreError> {
        if dims.contains(&0) {
            return Err(StoreError::BadDims { dims, reason: "every dimension must be at least 1" });
        }
        if !(voxel_size.is_finite() && voxel_size > 0.0) {
            return Err(StoreError::BadVoxelSize { voxel_size });
        }
        fs::create_dir_all(dir).map_err(StoreError::io(dir, "create the store directory"))?;
        let grid = BrickGrid::new(dims);
        let density_path = dir.join(DENSITY_FILE);
        let table_path = dir.join(TABLE_FILE);
        // An older store here is invalidated first: if this one fails half-way, what remains cannot
        // be opened as a mix of the old table and the new densities.
        match fs::remove_file(&table_path) {
            Err(e) if e.kind() != io::ErrorKind::NotFound => {
                return Err(StoreError::Io { path: table_path, action: "remove the previous table", source: e })
            }
            _ => {}
        }

        // The writer closure can only return io errors; a fill error is parked here and returned.
        let mut fill_error = None;
        let mut occupancy = Vec::with_capacity(grid.brick_count());
        write_atomic_io(&density_path, |w| {
            let r = fill_all(&grid, &density_path, &fill, &mut |out: &[f32]| {
                // The sink sees the bricks in index order (fill_all).
                let occupied = keep(occupancy.len()) || out.iter().any(|&v| v != 0.0);
                occupancy.push(occupied);
                if occupied {
                    w.write_all(bytemuck::cast_slice(out))?;
                }
                Ok(())
            });
            match r {
                Ok(()) => Ok(()),
                Err(FillAllError::Io(e)) => Err(e),
                Err(FillAllError::Store(e)) => {
                    fill_error = Some(e);
                    Err(io::Error::other("filling the bricks failed"))
                }
            }
        })
        .map_err(|(action, source)| match fill_error.take() {
            Some(e) => e,
            None => StoreError::Io { path: density_path.clone(), action, source },
        })?;

        let table = BrickTable::from_occupancy(grid, voxel_size, &occupancy);
        tracing::debug!(
            dir = %dir.display(),
            bricks = grid.brick_count(),
            occupied = table.occupied(),
            "density bricks written"
        );
        let json = table.to_json().map_err(|source| StoreError::Json { path: table_path.clone(), source })?;
        write_atomic_io(&table_path, |w| w.write_all(&json)).map_err(|(action, source)| StoreError::Io {
            path: table_path.clone(),
            action,
            source,
        })?;
        Self::open(dir)
    }

    /// Reopens a store written by [`BrickStore::create_with`], checking the table and that
    /// `density.bricks` has exactly one brick per occupied slot.
    pub fn open(dir: &Path) -> Result<BrickStore, StoreError> {
        let table_path = dir.join(TABLE_FILE);
        let bytes = fs::read(&table_path).map_err(StoreError::io(&table_path, "read"))?;
        let table = BrickTable::from_json(&table_path, &bytes)?;

        let density_path = dir.join(DENSITY_FILE);
        let file = File::open(&density_path).map_err(StoreError::io(&density_path, "open"))?;
        let actual = file.metadata().map_err(StoreError::io(&density_path, "read the size of"))?.len();
        let expected = table.occupied() as u64 * (BRICK_VOXELS * 4) as u64;
        if actual != expected {
            return Err(StoreError::Corrupt {
                path: density_path,
                message: format!("{actual} bytes, but {} occupied bricks need {expected} bytes", table.occupied()),
            });
        }
        // SAFETY: the mapping is read-only and the store owns its directory; like every memory-mapped
        // file, it must not be truncated by another process while mapped.
        let density = unsafe { Mmap::map(&file) }.map_err(StoreError::io(&density_path, "memory-map"))?;
        Ok(BrickStore { dir: dir.to_path_buf(), table: Arc::new(table), pages: Arc::default(), density })
    }

    pub fn grid(&self) -> &BrickGrid {
        &self.table.grid
    }

    pub fn voxel_size(&self) -> f64 {
        self.table.voxel_size
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Slot of `brick` among the occupied bricks; `None` for an empty brick (or one out of range).
    pub fn slot(&self, brick: usize) -> Option<u32> {
        self.table.slot(brick)
    }

    pub fn is_empty_brick(&self, brick: usize) -> bool {
        self.slot(brick).is_none()
    }

    pub fn occupied_count(&self) -> usize {
        self.table.occupied()
    }

    /// Indices of the occupied bricks, in increasing order (= slot order).
    pub fn occupied_bricks(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.grid().brick_count()).filter(|&b| self.slot(b).is_some())
    }

    /// The 4096 densities of `brick` (local x fastest); `None` when the brick is empty.
    pub fn density_brick(&self, brick: usize) -> Option<&[f32]> {
        let s = self.slot(brick)? as usize;
        self.density_slice().get(s * BRICK_VOXELS..(s + 1) * BRICK_VOXELS)
    }

    /// Density of voxel `v`; 0 outside the volume and in empty bricks.
    pub fn density_at(&self, v: [u32; 3]) -> f32 {
        if !self.grid().contains(v) {
            return 0.0;
        }
        let (b, l) = self.grid().locate(v);
        self.density_brick(b).map_or(0.0, |d| d[l])
    }

    /// Drops the density pages of occupied slots `first .. first + count` from the resident set
    /// (the values are kept; see [`Field`]'s docs on resident memory).
    pub fn release_density(&self, first: usize, count: usize) {
        if self.pages.holds() {
            return;
        }
        let brick = BRICK_VOXELS * 4;
        super::field::release_read_only(&self.density, first * brick, count * brick);
    }

    /// Drops every density page from the resident set.
    pub fn release_all_density(&self) {
        self.release_density(0, self.occupied_count());
    }

    /// Decides, once the solve's fields exist, whether the pages of the store and of every field
    /// mapped from it stay resident between passes (the store's files fit `budget`, else half of
    /// the available memory) or are handed back after each pass (the default); see
    /// [`super::resident`]. Values are never affected.
    pub fn keep_pages_if_they_fit(&self, budget: Option<u64>) -> Residency {
        let residency = Residency::decide(self.file_bytes(), budget, super::resident::available_memory());
        self.pages.set(residency.kept_resident);
        tracing::info!("{}", residency.describe());
        residency
    }

    /// Bytes of the store's files on disk (density, table and every field), as allocated. Only
    /// those: what else a solve keeps beside them (its checkpoint, which names the directory, and
    /// the checkpoint's small files) would make the count depend on the path and on when the
    /// solve was resumed.
    pub fn file_bytes(&self) -> u64 {
        let store_file = |name: &std::ffi::OsStr| {
            name == DENSITY_FILE || name == TABLE_FILE || Path::new(name).extension().is_some_and(|e| e == "field")
        };
        std::fs::read_dir(&self.dir)
            .map(|entries| {
                entries
                    .flatten()
                    .filter(|e| store_file(&e.file_name()))
                    .filter_map(|e| e.metadata().ok())
                    .filter(|m| m.is_file())
                    .map(|m| m.len())
                    .sum()
            })
            .unwrap_or(0)
    }

    fn density_slice(&self) -> &[f32] {
        // The map is page-aligned, so the cast only fails for an empty map (all bricks empty).
        bytemuck::try_cast_slice(&self.density[..]).unwrap_or(&[])
    }

    /// Creates (or truncates) `<name>.field` in the store directory, zero-filled, and maps it.
    pub fn create_field(&self, name: &str, components: u32, coverage: Coverage) -> Result<Field, StoreError> {
        Field::create(&self.dir, Arc::clone(&self.table), Arc::clone(&self.pages), name, components, coverage)
    }

    /// Maps an existing `<name>.field`, checking its size against the shape asked for.
    pub fn open_field(&self, name: &str, components: u32, coverage: Coverage) -> Result<Field, StoreError> {
        Field::open(&self.dir, Arc::clone(&self.table), Arc::clone(&self.pages), name, components, coverage)
    }
}

enum FillAllError {
    Io(io::Error),
    Store(StoreError),
}

impl From<io::Error> for FillAllError {
    fn from(e: io::Error) -> Self {
        FillAllError::Io(e)
    }
}

/// Fills every brick in brick order, a batch at a time: the workers fill the batch in parallel,
/// then `sink` receives each brick in order. Only one batch is ever in memory.
fn fill_all(
    grid: &BrickGrid,
    density_path: &Path,
    fill: &(impl Fn([u32; 3], &mut [f32]) -> Result<(), StoreError> + Sync),
    sink: &mut dyn FnMut(&[f32]) -> io::Result<()>,
) -> Result<(), FillAllError> {
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    let batch = workers * BRICKS_PER_WORKER;
    let count = grid.brick_count();
    let mut buf = vec![0.0f32; batch.min(count) * BRICK_VOXELS];
    for start in (0..count).step_by(batch) {
        let n = batch.min(count - start);
        let bricks = &mut buf[..n * BRICK_VOXELS];
        let per_worker = n.div_ceil(workers);
        let results: Vec<Result<(), StoreError>> = std::thread::scope(|s| {
            let handles: Vec<_> = bricks
                .chunks_mut(per_worker * BRICK_VOXELS)
                .enumerate()
                .map(|(w, chunk)| {
                    s.spawn(move || {
                        for (k, out) in chunk.chunks_mut(BRICK_VOXELS).enumerate() {
                            fill_one(grid, density_path, start + w * per_worker + k, out, fill)?;
                        }
                        Ok(())
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p))).collect()
        });
        // The first error in brick order, so the message does not depend on thread timing.
        if let Some(e) = results.into_iter().find_map(Result::err) {
            return Err(FillAllError::Store(e));
        }
        for out in bricks.chunks(BRICK_VOXELS) {
            sink(out)?;
        }
    }
    Ok(())
}

/// Fills one brick, zeroes its voxels beyond `dims`, and rejects densities the solver cannot use.
fn fill_one(
    grid: &BrickGrid,
    density_path: &Path,
    brick: usize,
    out: &mut [f32],
    fill: &(impl Fn([u32; 3], &mut [f32]) -> Result<(), StoreError> + Sync),
) -> Result<(), StoreError> {
    let b = grid.brick_coords(brick);
    out.fill(0.0);
    fill(b, out)?;
    let e = grid.brick_extent(b).map(|e| e as usize);
    let o = grid.brick_origin(b);
    for z in 0..16 {
        for y in 0..16 {
            for x in 0..16 {
                let i = x + 16 * (y + 16 * z);
                if x >= e[0] || y >= e[1] || z >= e[2] {
                    out[i] = 0.0;
                } else if !(out[i].is_finite() && out[i] >= 0.0) {
                    return Err(StoreError::BadDensity {
                        path: density_path.to_path_buf(),
                        voxel: [o[0] + x as u32, o[1] + y as u32, o[2] + z as u32],
                        value: out[i],
                    });
                }
            }
        }
    }
    Ok(())
}
