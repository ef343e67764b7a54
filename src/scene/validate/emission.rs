//! `[volume] emission_raw` / `emission_grid` (radiance per voxel) and `temperature_raw` /
//! `temperature_grid` (temperature per voxel, blackbody emission), with the `[medium]
//! temperature_*` keys that say how temperatures become radiance (see [`crate::scene::blackbody`]).

use super::{Validator, MAX_MAGNITUDE, R};
use crate::scene::blackbody::{DEFAULT_CUTOFF, DEFAULT_REFERENCE, REFERENCE_RANGE};
use crate::scene::raw::{RawMedium, RawVolume};
use crate::scene::{Blackbody, EmissionGrid, Volume, VolumeSource};

/// The `[volume]` keys naming a per-voxel emission, taken out of the raw volume before its source
/// is validated.
pub(super) struct EmissionKeys {
    emission_raw: Option<String>,
    emission_grid: Option<String>,
    temperature_raw: Option<String>,
    temperature_grid: Option<String>,
}

impl EmissionKeys {
    pub(super) fn take(v: &mut RawVolume) -> EmissionKeys {
        EmissionKeys {
            emission_raw: v.emission_raw.take(),
            emission_grid: v.emission_grid.take(),
            temperature_raw: v.temperature_raw.take(),
            temperature_grid: v.temperature_grid.take(),
        }
    }
}

/// The `[medium] temperature_*` keys, as written.
pub(super) struct BlackbodyKeys {
    scale: Option<f64>,
    reference: Option<f64>,
    cutoff: Option<f64>,
}

impl BlackbodyKeys {
    pub(super) fn take(m: &mut RawMedium) -> BlackbodyKeys {
        BlackbodyKeys {
            scale: m.temperature_scale.take(),
            reference: m.temperature_reference.take(),
            cutoff: m.temperature_cutoff.take(),
        }
    }

    fn given(&self) -> Option<&'static str> {
        [
            ("medium.temperature_scale", self.scale.is_some()),
            ("medium.temperature_reference", self.reference.is_some()),
            ("medium.temperature_cutoff", self.cutoff.is_some()),
        ]
        .into_iter()
        .find_map(|(key, set)| set.then_some(key))
    }
}

/// Where a grid's values come from: a raw file or a grid of the volume's VDB file.
pub(super) enum Values {
    Raw(std::path::PathBuf),
    Vdb(String),
}

impl Validator<'_> {
    /// The volume's per-voxel emission, once its dims are known.
    pub(super) fn emission(&self, keys: EmissionKeys, bb: BlackbodyKeys, volume: &Volume) -> R<Option<EmissionGrid>> {
        let radiance = keys.emission_raw.is_some() || keys.emission_grid.is_some();
        let temperature = keys.temperature_raw.is_some() || keys.temperature_grid.is_some();
        if radiance && temperature {
            let key = if keys.temperature_raw.is_some() { "volume.temperature_raw" } else { "volume.temperature_grid" };
            return Err(self.err(
                key,
                "emission comes either as radiance (`emission_raw` / `emission_grid`) or as temperature \
                 (`temperature_raw` / `temperature_grid`), but both are set",
            ));
        }
        if !temperature {
            if let Some(key) = bb.given() {
                return Err(self.err(key, "only applies with `volume.temperature_raw` or `volume.temperature_grid`"));
            }
            let values = self.values(keys.emission_raw, keys.emission_grid, "emission", volume)?;
            return Ok(values.map(|v| match v {
                Values::Raw(path) => EmissionGrid::Raw { path },
                Values::Vdb(grid) => EmissionGrid::Vdb { grid },
            }));
        }
        let blackbody = self.blackbody(bb)?;
        let values = self.values(keys.temperature_raw, keys.temperature_grid, "temperature", volume)?;
        Ok(values.map(|v| match v {
            Values::Raw(path) => EmissionGrid::TemperatureRaw { path, blackbody },
            Values::Vdb(grid) => EmissionGrid::TemperatureVdb { grid, blackbody },
        }))
    }

    /// `volume.<what>_raw` / `volume.<what>_grid` (also read by [`super::albedo`]).
    pub(super) fn values(
        &self,
        raw: Option<String>,
        grid: Option<String>,
        what: &str,
        volume: &Volume,
    ) -> R<Option<Values>> {
        let (raw_key, grid_key) = (format!("volume.{what}_raw"), format!("volume.{what}_grid"));
        match (raw, grid) {
            (None, None) => Ok(None),
            (Some(_), Some(_)) => {
                Err(self.err(grid_key, format!("set at most one of `{what}_raw` and `{what}_grid`, but both are set")))
            }
            (Some(raw), None) => {
                let voxels = volume.dims.iter().map(|&d| u64::from(d)).product::<u64>();
                Ok(Some(Values::Raw(self.raw_file_at(&raw_key, &raw, volume.dims, voxels)?)))
            }
            (None, Some(grid)) => {
                let VolumeSource::Vdb { path, .. } = &volume.source else {
                    return Err(self.err(
                        grid_key,
                        format!(
                            "only applies to a `vdb` volume (use `{what}_raw` for a raw file of the volume's dims)"
                        ),
                    ));
                };
                if grid.trim().is_empty() {
                    return Err(self.err(grid_key, "must name a grid, got an empty string"));
                }
                crate::store::vdb::vdb_info(path, &grid).map_err(|e| self.err(&grid_key, e.to_string()))?;
                Ok(Some(Values::Vdb(grid)))
            }
        }
    }

    /// `medium.temperature_scale`, `temperature_reference` and `temperature_cutoff`, defaulted.
    fn blackbody(&self, bb: BlackbodyKeys) -> R<Blackbody> {
        let (lo, hi) = REFERENCE_RANGE;
        let scale = match bb.scale {
            None => 1.0,
            Some(s) => self.positive("medium.temperature_scale", s, MAX_MAGNITUDE)?,
        };
        let reference = match bb.reference {
            None => DEFAULT_REFERENCE,
            Some(t) => {
                let t = self.finite("medium.temperature_reference", t)?;
                if !(lo..=hi).contains(&t) {
                    return Err(
                        self.err("medium.temperature_reference", format!("must be in [{lo}, {hi:e}] kelvin, got {t}"))
                    );
                }
                t
            }
        };
        let cutoff = match bb.cutoff {
            None => DEFAULT_CUTOFF,
            Some(t) => self.non_negative("medium.temperature_cutoff", t, Some(hi))?,
        };
        Ok(Blackbody { scale, reference, cutoff })
    }
}
