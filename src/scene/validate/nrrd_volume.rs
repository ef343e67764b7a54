//! `[volume] nrrd = "density.nhdr"`: a volume read from an NRRD file. The header gives `dims`, and,
//! when it has them, the voxel size (`spacings` / `space directions`) and the corner (`space
//! origin` / `axis mins`); the scene's `voxel_size` and `origin` override them.

use super::{Validator, R};
use crate::scene::raw::RawVolume;
use crate::scene::{Volume, VolumeSource};
use crate::store::nrrd_input::nrrd_header;
use glam::DVec3;
use std::path::Path;

impl Validator<'_> {
    pub(super) fn nrrd_volume(&self, v: RawVolume, origin: DVec3) -> R<Volume> {
        for (key, set) in [("volume.procedural", v.procedural.is_some()), ("volume.raw", v.raw.is_some())] {
            if set {
                return Err(
                    self.err(key, "set exactly one of `procedural`, `raw`, `vdb` and `nrrd`, but `nrrd` is set too")
                );
            }
        }
        if v.dims.is_some() {
            return Err(self.err("volume.dims", "does not apply to an `nrrd` volume: its size is the header's `sizes`"));
        }
        if v.seed.is_some() {
            return Err(self.err("volume.seed", "only applies to a procedural volume, not to `nrrd`"));
        }
        if v.grid.is_some() {
            return Err(self.err("volume.grid", "only applies to a `vdb` volume"));
        }
        let key = "volume.nrrd";
        let file = v.nrrd.unwrap_or_default();
        if file.trim().is_empty() {
            return Err(self.err(key, "must name a file, got an empty string"));
        }
        let base = self.path.parent().unwrap_or_else(|| Path::new(""));
        let joined = base.join(&file);
        let path = std::path::absolute(&joined).unwrap_or(joined);
        let h = nrrd_header(&path).map_err(|e| self.err(key, e.to_string()))?;
        let written = h.dims.map(|d| i64::try_from(d).unwrap_or(i64::MAX));
        let dims =
            self.dims(written).map_err(|e| self.err(key, format!("the header's sizes are too large for lpm ({e})")))?;
        let voxel_size = match (v.voxel_size, h.voxel_size) {
            (Some(s), _) => self.positive("volume.voxel_size", s, super::MAX_MAGNITUDE)?,
            (None, Some(s)) => self.positive(key, s, super::MAX_MAGNITUDE)?,
            (None, None) => 1.0,
        };
        let origin = match (v.origin.is_some(), h.corner) {
            (false, Some(c)) => DVec3::from_array(c),
            _ => origin,
        };
        Ok(Volume { source: VolumeSource::Nrrd { path }, dims, voxel_size, origin, emission: None, albedo: None })
    }
}
