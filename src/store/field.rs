//! [`Field`]: a per-voxel quantity with one or more components, in a memory-mapped file beside the
//! density. Per stored brick: `components × 4096` f32, component-major (`[c][local voxel]`), so one
//! component of one brick is a contiguous 16 KiB block, as the GPU kernels read it.
//!
//! Resident memory: pages of a memory-mapped file count in the process's resident set once touched,
//! and stay there while memory is plentiful. Passes over fields far larger than RAM therefore hand
//! back what they are done with ([`Field::release_stored`], [`Field::release_all`]): the pages leave
//! the resident set but stay in the page cache (dirty ones are written back as usual), so nothing
//! is lost and the next touch reads them again. Clearing ([`Field::fill_zero`]) punches a hole
//! instead of writing zeros, so it touches no page at all. Every field's blocks are allocated on
//! disk up front (see `allocate`): a write through the map never meets a full disk.

use super::grid::{BrickGrid, BRICK_VOXELS};
use super::resident::PageHolding;
use super::table::BrickTable;
use super::StoreError;
use memmap2::MmapMut;
use std::fs::{File, OpenOptions};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Which bricks a field stores.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Coverage {
    /// Every brick, in brick-index order.
    Dense,
    /// Only the occupied (non-empty) bricks, in slot order; empty bricks read as zero.
    Occupied,
}

pub struct Field {
    name: String,
    path: PathBuf,
    components: u32,
    coverage: Coverage,
    table: Arc<BrickTable>,
    /// The store's switch: set, releases are no-ops (see [`super::resident`]).
    pages: Arc<PageHolding>,
    file: File,
    map: MmapMut,
}

impl Field {
    pub(crate) fn create(
        dir: &Path,
        table: Arc<BrickTable>,
        pages: Arc<PageHolding>,
        name: &str,
        components: u32,
        coverage: Coverage,
    ) -> Result<Field, StoreError> {
        let (path, len) = shape(dir, &table, name, components, coverage)?;
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&path)
            .map_err(StoreError::io(&path, "create"))?;
        file.set_len(len).map_err(|e| size_error(&path, len, e))?;
        allocate(&file, &path, len)?;
        Self::map(path, file, table, pages, name, components, coverage)
    }

    pub(crate) fn open(
        dir: &Path,
        table: Arc<BrickTable>,
        pages: Arc<PageHolding>,
        name: &str,
        components: u32,
        coverage: Coverage,
    ) -> Result<Field, StoreError> {
        let (path, len) = shape(dir, &table, name, components, coverage)?;
        let file = OpenOptions::new().read(true).write(true).open(&path).map_err(StoreError::io(&path, "open"))?;
        let actual = file.metadata().map_err(StoreError::io(&path, "read the size of"))?.len();
        if actual != len {
            return Err(StoreError::FieldShape {
                path,
                message: format!(
                    "{actual} bytes, but {components} component(s) over {coverage:?} bricks need {len} bytes"
                ),
            });
        }
        Self::map(path, file, table, pages, name, components, coverage)
    }

    fn map(
        path: PathBuf,
        file: File,
        table: Arc<BrickTable>,
        pages: Arc<PageHolding>,
        name: &str,
        components: u32,
        coverage: Coverage,
    ) -> Result<Field, StoreError> {
        // SAFETY: the field file belongs to the store directory; like every memory-mapped file it must
        // not be truncated by another process while mapped.
        let map = unsafe { MmapMut::map_mut(&file) }.map_err(StoreError::io(&path, "memory-map"))?;
        Ok(Field { name: name.to_string(), path, components, coverage, table, pages, file, map })
    }

    pub fn components(&self) -> u32 {
        self.components
    }

    pub fn coverage(&self) -> Coverage {
        self.coverage
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn grid(&self) -> &BrickGrid {
        &self.table.grid
    }

    /// Number of bricks held in the file.
    pub fn stored_bricks(&self) -> usize {
        stored_bricks(&self.table, self.coverage)
    }

    /// f32 values per stored brick (`components × 4096`).
    pub fn brick_len(&self) -> usize {
        self.components as usize * BRICK_VOXELS
    }

    /// Position of `brick` in the file; `None` for an empty brick under `Occupied` or out of range.
    pub fn stored_index(&self, brick: usize) -> Option<usize> {
        match self.coverage {
            Coverage::Dense => (brick < self.table.grid.brick_count()).then_some(brick),
            Coverage::Occupied => self.table.slot(brick).map(|s| s as usize),
        }
    }

    /// The `components × 4096` values of `brick`, component-major.
    pub fn brick(&self, brick: usize) -> Option<&[f32]> {
        let i = self.stored_index(brick)?;
        let n = self.brick_len();
        self.as_slice().get(i * n..(i + 1) * n)
    }

    pub fn brick_mut(&mut self, brick: usize) -> Option<&mut [f32]> {
        let i = self.stored_index(brick)?;
        let n = self.brick_len();
        self.as_mut_slice().get_mut(i * n..(i + 1) * n)
    }

    /// Component `c` at voxel `v`; 0 outside the volume, for `c` out of range and in unstored bricks.
    pub fn value(&self, v: [u32; 3], c: u32) -> f32 {
        if !self.grid().contains(v) || c >= self.components {
            return 0.0;
        }
        let (b, l) = self.grid().locate(v);
        self.brick(b).map_or(0.0, |d| d[c as usize * BRICK_VOXELS + l])
    }

    /// Sets every value to zero without touching a page: the file's blocks are deallocated
    /// (`FALLOC_FL_PUNCH_HOLE`, which also drops the mapped pages, so they read as zeros) and then
    /// allocated again (see `allocate`). The file keeps its length throughout, so a process killed
    /// in the middle leaves a field of the right size (a resumed solve reopens it). Where punching
    /// holes is not supported, the file is truncated and extended instead.
    pub fn fill_zero(&mut self) -> Result<(), StoreError> {
        let len = self.map.len() as u64;
        #[cfg(target_os = "linux")]
        {
            use std::os::unix::io::AsRawFd;
            let l = libc::off_t::try_from(len).unwrap_or(libc::off_t::MAX);
            // SAFETY: a plain system call on a descriptor the field owns; the map stays valid (the
            // length does not change) and `&mut self` means no reference into it is alive.
            let rc = unsafe {
                libc::fallocate(self.file.as_raw_fd(), libc::FALLOC_FL_PUNCH_HOLE | libc::FALLOC_FL_KEEP_SIZE, 0, l)
            };
            if rc == 0 {
                return allocate(&self.file, &self.path, len);
            }
        }
        // The map stays valid across the truncation: nothing touches it until the file has its
        // length back (`&mut self`), and then its pages read as zeros.
        self.file.set_len(0).map_err(StoreError::io(&self.path, "truncate"))?;
        self.file.set_len(len).map_err(|e| size_error(&self.path, len, e))?;
        allocate(&self.file, &self.path, len)
    }

    /// Drops the pages of stored bricks `first .. first + count` from the resident set (see the
    /// module docs; the values are kept).
    pub fn release_stored(&self, first: usize, count: usize) {
        if self.pages.holds() {
            return;
        }
        let brick_bytes = self.brick_len() * 4;
        release_mut(&self.map, first * brick_bytes, count * brick_bytes);
    }

    /// The largest |value| (0 for an empty field), read a few MiB at a time and handed back as it
    /// goes, so the scan keeps the resident set bounded.
    pub fn max_abs(&self) -> f32 {
        const BRICKS: usize = 1024;
        let per_brick = self.brick_len();
        let values = self.as_slice();
        let mut max = 0f32;
        for (n, chunk) in values.chunks(BRICKS * per_brick).enumerate() {
            max = chunk.iter().fold(max, |m, &v| m.max(v.abs()));
            self.release_stored(n * BRICKS, BRICKS);
        }
        max
    }

    /// Drops every page of the field from the resident set (the values are kept).
    pub fn release_all(&self) {
        if self.pages.holds() {
            return;
        }
        release_mut(&self.map, 0, self.map.len());
    }

    /// Writes the mapped pages back to the file (blocking).
    pub fn flush(&self) -> Result<(), StoreError> {
        self.map.flush().map_err(StoreError::io(&self.path, "flush"))
    }

    /// All stored bricks, in storage order.
    pub fn as_slice(&self) -> &[f32] {
        // The map is page-aligned; the cast only fails for an empty map (no stored bricks).
        bytemuck::try_cast_slice(&self.map[..]).unwrap_or(&[])
    }

    pub fn as_mut_slice(&mut self) -> &mut [f32] {
        bytemuck::try_cast_slice_mut(&mut self.map[..]).unwrap_or(&mut [])
    }

    /// Copies every value of `other`, which must have the same components, coverage and brick table.
    pub fn copy_from(&mut self, other: &Field) -> Result<(), StoreError> {
        if self.components != other.components || self.coverage != other.coverage || *self.table != *other.table {
            return Err(StoreError::FieldShape {
                path: self.path.clone(),
                message: format!(
                    "cannot copy from {}: {} component(s) over {:?} bricks of a {:?} volume, this field has {} over {:?} of {:?}",
                    other.path.display(),
                    other.components,
                    other.coverage,
                    other.table.grid.dims,
                    self.components,
                    self.coverage,
                    self.table.grid.dims
                ),
            });
        }
        self.as_mut_slice().copy_from_slice(other.as_slice());
        Ok(())
    }
}

/// A failed `set_len` to `len` bytes: past a file size limit (`ulimit -f`: EFBIG, SIGXFSZ being
/// ignored) or a quota, reported as a full disk is, naming the bytes needed.
fn size_error(path: &Path, len: u64, e: std::io::Error) -> StoreError {
    match e.raw_os_error() {
        Some(libc::ENOSPC | libc::EFBIG | libc::EDQUOT) => StoreError::NoSpace {
            path: path.to_path_buf(),
            needed: len,
            free: path.parent().and_then(super::free_bytes),
        },
        _ => StoreError::Io { path: path.to_path_buf(), action: "size", source: e },
    }
}

/// Reserves the disk blocks of the whole file (`posix_fallocate`), so that a write through the map
/// can never meet a full disk: on a sparse file it would, and the kernel answers a failed write
/// into a mapped hole with SIGBUS, killing the process without a message. A full disk is thus an
/// error here, before the solve writes anything, naming the bytes needed and free. (`set_len`
/// alone only sets the length and leaves a hole.) Where the filesystem cannot preallocate
/// (EOPNOTSUPP on some network filesystems), glibc writes zeros instead; a platform without
/// `posix_fallocate` keeps the sparse file.
fn allocate(file: &File, path: &Path, len: u64) -> Result<(), StoreError> {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::io::AsRawFd;
        if len == 0 {
            return Ok(());
        }
        let too_big = || StoreError::NoSpace { path: path.to_path_buf(), needed: len, free: None };
        let l = libc::off_t::try_from(len).map_err(|_| too_big())?;
        // SAFETY: a plain system call on a descriptor `file` owns; no memory is passed.
        let rc = unsafe { libc::posix_fallocate(file.as_raw_fd(), 0, l) };
        match rc {
            0 => Ok(()),
            libc::ENOSPC | libc::EFBIG | libc::EDQUOT => Err(StoreError::NoSpace {
                path: path.to_path_buf(),
                needed: len,
                free: path.parent().and_then(super::free_bytes),
            }),
            e => Err(StoreError::Io {
                path: path.to_path_buf(),
                action: "allocate disk space for",
                source: std::io::Error::from_raw_os_error(e),
            }),
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (file, path, len);
        Ok(())
    }
}

fn stored_bricks(table: &BrickTable, coverage: Coverage) -> usize {
    match coverage {
        Coverage::Dense => table.grid.brick_count(),
        Coverage::Occupied => table.occupied(),
    }
}

/// The file path of field `name` and its size in bytes, after checking the name and shape.
fn shape(
    dir: &Path,
    table: &BrickTable,
    name: &str,
    components: u32,
    coverage: Coverage,
) -> Result<(PathBuf, u64), StoreError> {
    // The name becomes a file name: keep it to a safe alphabet so it cannot escape the directory.
    let ok = !name.is_empty()
        && !name.starts_with('.')
        && name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
    if !ok {
        return Err(StoreError::BadFieldName { name: name.to_string() });
    }
    let path = dir.join(format!("{name}.field"));
    if components == 0 {
        return Err(StoreError::FieldShape { path, message: "a field needs at least one component".to_string() });
    }
    let len = (stored_bricks(table, coverage) as u64)
        .checked_mul(components as u64 * BRICK_VOXELS as u64 * 4)
        .ok_or_else(|| StoreError::FieldShape {
            path: path.clone(),
            message: format!("{components} components make the file larger than 2^64 bytes"),
        })?;
    Ok((path, len))
}

/// Drops `len` bytes at `offset` of a shared file mapping from the resident set (clamped to the
/// map). The pages' contents live on in the page cache and the file (MADV_DONTNEED on a *shared
/// file* mapping never loses data, unlike on private or anonymous memory); a later access faults
/// them back in. Best effort: a failure only leaves the pages resident.
fn release_pages(advise: impl FnOnce(usize, usize) -> std::io::Result<()>, map_len: usize, offset: usize, len: usize) {
    let len = len.min(map_len.saturating_sub(offset));
    if len > 0 {
        if let Err(e) = advise(offset, len) {
            tracing::debug!(offset, len, "madvise(DONTNEED) failed, the pages stay resident: {e}");
        }
    }
}

/// `release_pages` for a read-only map (the density bricks, a raw volume being imported).
pub(crate) fn release_read_only(map: &memmap2::Mmap, offset: usize, len: usize) {
    #[cfg(unix)]
    release_pages(
        // SAFETY: a read-only shared file mapping keeps its contents under DONTNEED.
        |o, l| unsafe { map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, o, l) },
        map.len(),
        offset,
        len,
    );
}

/// `release_pages` for a writable map.
fn release_mut(map: &MmapMut, offset: usize, len: usize) {
    #[cfg(unix)]
    release_pages(
        // SAFETY: a shared file mapping keeps its contents under DONTNEED (see `release_pages`),
        // so no reference into the map ever sees a changed value.
        |o, l| unsafe { map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, o, l) },
        map.len(),
        offset,
        len,
    );
}
