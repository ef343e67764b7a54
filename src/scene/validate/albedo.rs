//! `[volume] albedo_raw` / `albedo_grid`: a per-voxel albedo factor `a(v)` in [0, 1] that
//! multiplies `[medium] albedo`. Here only where the values come from is checked (the file's size,
//! the grid's presence); the values themselves are checked by the importer
//! ([`crate::store::albedo`]), which names the voxel.

use super::emission::Values;
use super::{Validator, R};
use crate::scene::raw::RawVolume;
use crate::scene::{AlbedoGrid, ForwardPeak, Volume};

/// The `[volume]` keys naming a per-voxel albedo, taken out of the raw volume before its source is
/// validated.
pub(super) struct AlbedoKeys {
    raw: Option<String>,
    grid: Option<String>,
}

impl AlbedoKeys {
    pub(super) fn take(v: &mut RawVolume) -> AlbedoKeys {
        AlbedoKeys { raw: v.albedo_raw.take(), grid: v.albedo_grid.take() }
    }
}

impl Validator<'_> {
    /// The volume's per-voxel albedo, once its dims are known.
    pub(super) fn albedo(&self, keys: AlbedoKeys, volume: &Volume) -> R<Option<AlbedoGrid>> {
        Ok(self.values(keys.raw, keys.grid, "albedo", volume)?.map(|v| match v {
            Values::Raw(path) => AlbedoGrid::Raw { path },
            Values::Vdb(grid) => AlbedoGrid::Vdb { grid },
        }))
    }

    /// δ-M scaling changes σt by the voxel's own albedo (σt' = σt·(1 − f·albedo)): with an albedo
    /// grid that would be a per-voxel extinction, which the sweeps do not have. An explicit
    /// `forward_peak = "delta-m"` is refused; `auto` keeps the phase function (see the plan).
    pub(super) fn albedo_with_forward_peak(&self, volume: &Volume, peak: ForwardPeak) -> R<()> {
        if volume.albedo.is_some() && peak == ForwardPeak::DeltaM {
            return Err(self.err(
                "solver.forward_peak",
                "\"delta-m\" does not combine with a per-voxel albedo (`volume.albedo_raw` / `albedo_grid`): \
                 δ-M scaling would make the extinction depend on each voxel's albedo; use \"keep\" or \"auto\"",
            ));
        }
        Ok(())
    }
}
