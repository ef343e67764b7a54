//! Importers: sources of density that fill bricks for [`BrickStore::create_with`](super::BrickStore::create_with).

use super::grid::{local_index, BrickGrid, BRICK_EDGE};
use super::StoreError;
use std::fs::File;
use std::io;
use std::path::{Path, PathBuf};

/// A raw density file (little-endian f32, x fastest, then y, then z), read brick by brick so a
/// volume larger than memory can be imported.
///
/// The file is read with positioned `read` calls (`pread`), not memory-mapped: an input file is not
/// ours, and if another program truncates a mapped file while it is read, the access kills the
/// process with SIGBUS; with `read` a shrinking file is an error naming it ([`StoreError::Truncated`]).
/// Reads go through the page cache, so the cost over a map is one copy of each row.
#[derive(Debug)]
pub struct RawDensity {
    path: PathBuf,
    grid: BrickGrid,
    file: File,
}

/// Opens `path`, checking that it is a regular file holding exactly `dims` f32 values.
pub fn raw_density(path: &Path, dims: [u32; 3]) -> Result<RawDensity, StoreError> {
    let file = crate::input::open(path)?;
    let meta = file.metadata().map_err(StoreError::io(path, "read the size of"))?;
    let actual = meta.len();
    let expected = dims.iter().try_fold(4u64, |acc, &d| acc.checked_mul(d as u64));
    if expected != Some(actual) {
        return Err(StoreError::RawSize {
            path: path.to_path_buf(),
            dims,
            expected: expected.unwrap_or(u64::MAX),
            actual,
        });
    }
    Ok(RawDensity { path: path.to_path_buf(), grid: BrickGrid::new(dims), file })
}

impl RawDensity {
    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn dims(&self) -> [u32; 3] {
        self.grid.dims
    }

    /// Copies brick `brick`'s voxels into `out` (4096 values, local x fastest); voxels beyond the
    /// volume are set to 0. Rejects NaN, infinite and negative densities, naming the voxel, and a
    /// file that shrank since it was opened.
    pub fn fill_brick(&self, brick: [u32; 3], out: &mut [f32]) -> Result<(), StoreError> {
        out.fill(0.0);
        let [nx, ny, _] = self.grid.dims.map(|d| d as u64);
        let o = self.grid.brick_origin(brick);
        let e = self.grid.brick_extent(brick);
        debug_assert!(e.iter().all(|&e| e <= BRICK_EDGE));
        let mut bytes = [0u8; 4 * BRICK_EDGE as usize];
        let bytes = &mut bytes[..4 * e[0] as usize];
        for z in 0..e[2] {
            for y in 0..e[1] {
                let row = (o[2] + z) as u64 * ny * nx + (o[1] + y) as u64 * nx + o[0] as u64;
                self.read_at(bytes, row * 4)?;
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
        Ok(())
    }

    fn read_at(&self, buf: &mut [u8], offset: u64) -> Result<(), StoreError> {
        #[cfg(unix)]
        let r = std::os::unix::fs::FileExt::read_exact_at(&self.file, buf, offset);
        #[cfg(windows)]
        let r = {
            let mut done = 0;
            let mut r = Ok(());
            while done < buf.len() {
                match std::os::windows::fs::FileExt::seek_read(&self.file, &mut buf[done..], offset + done as u64) {
                    Ok(0) => {
                        r = Err(io::Error::from(io::ErrorKind::UnexpectedEof));
                        break;
                    }
                    Ok(n) => done += n,
                    Err(e) => {
                        r = Err(e);
                        break;
                    }
                }
            }
            r
        };
        r.map_err(|e| match e.kind() {
            io::ErrorKind::UnexpectedEof => {
                StoreError::Truncated { path: self.path.clone(), expected: self.grid.voxel_count() * 4 }
            }
            _ => StoreError::Io { path: self.path.clone(), action: "read", source: e },
        })
    }
}

/// Fills one brick (local x fastest) from an importer.
pub(crate) type FillBrick = Box<dyn Fn([u32; 3], &mut [f32]) -> Result<(), StoreError>>;

/// The importer of a per-voxel grid beside the density (`what`: "emission", "albedo", for the
/// message) and the file it reads: a raw file of the volume's `dims`, or grid `vdb_grid` of the
/// volume's own VDB file (the only kind of volume a named grid can come from).
pub(crate) fn voxel_grid_importer(
    raw_path: Option<&Path>,
    vdb_grid: Option<&str>,
    source: &crate::scene::VolumeSource,
    dims: [u32; 3],
    store_dir: &Path,
    what: &str,
) -> Result<(FillBrick, PathBuf), StoreError> {
    match (raw_path, vdb_grid, source) {
        (Some(path), _, _) => {
            let raw = raw_density(path, dims)?;
            Ok((Box::new(move |b, out| raw.fill_brick(b, out)), path.to_path_buf()))
        }
        (None, Some(name), crate::scene::VolumeSource::Vdb { path, index_min, .. }) => {
            let vdb = super::vdb::vdb_grid_over(path, name, dims, *index_min)?;
            Ok((Box::new(move |b, out| vdb.fill_brick(b, out)), path.clone()))
        }
        (None, name, _) => Err(StoreError::Corrupt {
            path: store_dir.to_path_buf(),
            message: format!("{what} grid \"{}\" needs a `vdb` volume", name.unwrap_or_default()),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Defect 2: the importer used to map the file; truncating it under the import raised SIGBUS
    /// (this test process would die). Now the read fails with an error naming the file.
    #[test]
    fn a_file_truncated_after_opening_is_an_error_not_a_signal() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("d.raw");
        let dims = [20, 20, 20];
        std::fs::write(&p, vec![0u8; 20 * 20 * 20 * 4]).unwrap();
        let raw = raw_density(&p, dims).unwrap();
        let mut out = vec![0f32; 4096];
        raw.fill_brick([0, 0, 0], &mut out).unwrap();
        std::fs::OpenOptions::new().write(true).open(&p).unwrap().set_len(100).unwrap();
        let e = raw.fill_brick([1, 1, 1], &mut out).unwrap_err();
        assert!(matches!(e, StoreError::Truncated { .. }), "{e}");
        assert!(e.to_string().contains("d.raw") && e.to_string().contains("shrank"), "{e}");
    }

    #[test]
    fn a_device_file_is_refused() {
        let e = raw_density(Path::new("/dev/zero"), [1, 1, 1]).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
    }
}
