//! `[volume] vdb = "file.vdb"` (or `nvdb = "file.nvdb"`): a volume read from an OpenVDB or
//! NanoVDB grid. The grid's active bounding box gives `dims` and its transform gives `voxel_size` and `origin` (either may be overridden in the
//! scene, e.g. to change units); only the topology is read here, the values when the store is built.

use super::{Validator, R};
use crate::scene::raw::RawVolume;
use crate::scene::{Volume, VolumeSource};
use crate::store::vdb::vdb_info;
use glam::DVec3;
use std::path::Path;

/// The grid read when the scene names none.
pub const DEFAULT_GRID: &str = "density";

impl Validator<'_> {
    /// `key` is `volume.vdb` or `volume.nvdb`: the file is read as NanoVDB when it starts with
    /// NanoVDB's magic number, whichever key named it.
    pub(super) fn vdb_volume(&self, v: RawVolume, origin: DVec3, key: &'static str) -> R<Volume> {
        for (key, set) in [("volume.procedural", v.procedural.is_some()), ("volume.raw", v.raw.is_some())] {
            if set {
                return Err(self.err(key, "set exactly one of `procedural`, `raw` and `vdb`, but `vdb` is set too"));
            }
        }
        if v.dims.is_some() {
            return Err(
                self.err("volume.dims", "does not apply to a `vdb` volume: its size is the grid's active bounding box")
            );
        }
        if v.seed.is_some() {
            return Err(self.err("volume.seed", "only applies to a procedural volume, not to `vdb`"));
        }
        let file = v.vdb.unwrap_or_default();
        if file.trim().is_empty() {
            return Err(self.err(key, "must name a file, got an empty string"));
        }
        let grid = v.grid.unwrap_or_else(|| DEFAULT_GRID.to_string());
        let base = self.path.parent().unwrap_or_else(|| Path::new(""));
        let joined = base.join(&file);
        let path = std::path::absolute(&joined).unwrap_or(joined);
        let info = vdb_info(&path, &grid).map_err(|e| self.err(key, e.to_string()))?;
        let written = info.dims.map(|d| i64::try_from(d).unwrap_or(i64::MAX));
        let dims = self
            .dims(written)
            .map_err(|e| self.err(key, format!("grid \"{grid}\"'s active bounding box is too large for lpm ({e})")))?;
        let voxel_size = match v.voxel_size {
            Some(s) => self.positive("volume.voxel_size", s, super::MAX_MAGNITUDE)?,
            None if info.voxel_size <= super::MAX_MAGNITUDE => info.voxel_size,
            None => {
                return Err(self.err(
                    key,
                    format!("grid \"{grid}\" has a voxel size of {}, more than lpm's limit", info.voxel_size),
                ))
            }
        };
        // An explicit origin wins; otherwise the transform places the volume (with the scene's voxel
        // size, if it overrides the file's, scaling about the index origin).
        let origin = if v.origin.is_some() {
            origin
        } else {
            let scale = voxel_size / info.voxel_size;
            DVec3::from_array(info.origin) * scale
        };
        Ok(Volume {
            source: VolumeSource::Vdb { path, grid, index_min: info.index_min },
            dims,
            voxel_size,
            origin,
            emission: None,
            albedo: None,
        })
    }
}
