//! Errors of the brick store and its importers. Each names the file and what is wrong with it.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("{}: cannot {action}: {source}", path.display())]
    Io { path: PathBuf, action: &'static str, source: std::io::Error },

    #[error("{}: invalid brick table: {source}", path.display())]
    Json { path: PathBuf, source: serde_json::Error },

    #[error("{}: {message}", path.display())]
    Corrupt { path: PathBuf, message: String },

    #[error("{}: expected {expected} bytes for a {}×{}×{} f32 volume, but the file has {actual} bytes",
        path.display(), dims[0], dims[1], dims[2])]
    RawSize { path: PathBuf, dims: [u32; 3], expected: u64, actual: u64 },

    #[error("{}: voxel ({}, {}, {}) has density {}; densities must be finite and non-negative",
        path.display(), voxel[0], voxel[1], voxel[2], short_f32(*value))]
    BadDensity { path: PathBuf, voxel: [u32; 3], value: f32 },

    #[error("{}: voxel ({}, {}, {}) has emission {}; emission values must be finite and non-negative",
        path.display(), voxel[0], voxel[1], voxel[2], short_f32(*value))]
    BadEmission { path: PathBuf, voxel: [u32; 3], value: f32 },

    /// A value that passes the limit every light value keeps ([`crate::scene::validate::MAX_LIGHT`],
    /// so that every field the solver forms stays finite in f32) once the scene's factor scales it:
    /// an emission factor × `medium.emission`, or a density × `medium.sigma_t`.
    #[error("{}: voxel ({}, {}, {}) has {what} {}; × {factor_key} ({}) that is {}, more than the limit of 1e12",
        path.display(), voxel[0], voxel[1], voxel[2], short_f32(*value), short_f32(*factor as f32), short_f32(*product as f32))]
    TooLarge {
        path: PathBuf,
        what: &'static str,
        voxel: [u32; 3],
        value: f32,
        factor_key: &'static str,
        factor: f64,
        product: f64,
    },

    #[error("{}: voxel ({}, {}, {}) has albedo factor {} ({field}); albedo factors must be finite and in [0, 1]",
        path.display(), voxel[0], voxel[1], voxel[2], short_f32(*value))]
    BadAlbedo { path: PathBuf, field: String, voxel: [u32; 3], value: f32 },

    #[error("{}: voxel ({}, {}, {}) has temperature {}; {problem}",
        path.display(), voxel[0], voxel[1], voxel[2], short_f32(*value))]
    BadTemperature { path: PathBuf, voxel: [u32; 3], value: f32, problem: String },

    #[error("volume dims {}×{}×{} are invalid: {reason}", dims[0], dims[1], dims[2])]
    BadDims { dims: [u32; 3], reason: &'static str },

    #[error("voxel size {voxel_size} is invalid: it must be a positive number")]
    BadVoxelSize { voxel_size: f64 },

    #[error("field name {name:?} is invalid: use letters, digits, '_', '-' and '.' only")]
    BadFieldName { name: String },

    #[error("{}: NRRD field `{field}`: {problem}", path.display())]
    Nrrd { path: PathBuf, field: String, problem: String },

    /// Stopped between bricks on request (SIGTERM while the store was built).
    #[error("the store's build was cancelled")]
    Cancelled,

    /// An input file refused or unreadable (not a regular file, outside a solve's confinement).
    #[error(transparent)]
    Input(#[from] crate::input::InputError),

    #[error("{}: {source}", path.display())]
    Vdb { path: PathBuf, source: super::vdb::VdbError },

    #[error("{}: {message}", path.display())]
    FieldShape { path: PathBuf, message: String },

    #[error("{}: not enough disk space: the file needs {needed} bytes, {} free{}", path.display(),
        free.map_or("unknown".to_string(), |f| format!("{f} bytes")),
        if *needed > 0 { "; free some space or choose another --out" } else { "" })]
    NoSpace { path: PathBuf, needed: u64, free: Option<u64> },

    #[error("{}: the file shrank while it was being read (expected {expected} bytes); was it modified by another program?", path.display())]
    Truncated { path: PathBuf, expected: u64 },
}

/// `v` for a message: plain for ordinary magnitudes, e-notation for huge or tiny ones (f32's
/// `Display` writes `-1e-40` as 41 digits and `3e38` as 39).
fn short_f32(v: f32) -> String {
    if v.is_finite() && v != 0.0 && !(1e-6..1e9).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

impl StoreError {
    /// The same error with a bad value reported as an emission value: the density importers read
    /// emission files too, and their messages must name what the file holds.
    pub(crate) fn into_emission(self) -> StoreError {
        match self {
            StoreError::BadDensity { path, voxel, value } => StoreError::BadEmission { path, voxel, value },
            other => other,
        }
    }

    /// The same error with a bad value reported as an albedo factor (see
    /// [`StoreError::into_emission`]); `field` says where the values came from.
    pub(crate) fn into_albedo(self, field: &str) -> StoreError {
        match self {
            StoreError::BadDensity { path, voxel, value } => {
                StoreError::BadAlbedo { path, field: field.to_string(), voxel, value }
            }
            other => other,
        }
    }

    /// The same error with a bad value reported as a temperature (see [`StoreError::into_emission`]).
    /// `field` says where the values came from (`volume.temperature_raw`, `grid "temperature"`).
    pub(crate) fn into_temperature(self, field: &str) -> StoreError {
        match self {
            StoreError::BadDensity { path, voxel, value } => StoreError::BadTemperature {
                path,
                voxel,
                value,
                problem: format!("temperatures ({field}) must be finite and non-negative"),
            },
            other => other,
        }
    }

    pub(crate) fn io(path: impl Into<PathBuf>, action: &'static str) -> impl FnOnce(std::io::Error) -> StoreError {
        let path = path.into();
        move |source| StoreError::Io { path, action, source }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 13, item 11: an out-of-range voxel's value was printed in full decimal.
    #[test]
    fn bad_density_values_print_short() {
        let e = |value| StoreError::BadDensity { path: "d.raw".into(), voxel: [1, 2, 3], value }.to_string();
        assert!(e(-1e-40).contains("density -1e-40;"), "{}", e(-1e-40));
        assert!(e(-3e38).contains("density -3e38;"), "{}", e(-3e38));
        assert!(e(-2.5).contains("density -2.5;"));
        assert!(e(f32::NAN).contains("density NaN;"));
    }
}
