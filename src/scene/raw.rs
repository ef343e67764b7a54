//! Stage one: the scene file exactly as written, deserialised by serde. Nothing here is checked
//! beyond TOML syntax, types and key names (`deny_unknown_fields` everywhere); ranges, consistency
//! and defaults are the business of [`super::validate`]. Integers are read as `i64` (TOML's integer
//! type) so that out-of-range values get our own message with the key, rather than serde's.

use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::Deserialize;
use std::fmt;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawScene {
    pub volume: RawVolume,
    pub medium: RawMedium,
    #[serde(default)]
    pub lights: Vec<RawLight>,
    pub solver: Option<RawSolver>,
    pub camera: Option<super::validate::CameraKeys>,
    pub boundary: Option<RawBoundary>,
}

/// `[boundary]`: per axis, how light crosses the two faces across it: one word for both faces
/// ("open", "periodic", "reflective") or a pair `[low, high]` ("open" or "reflective" each).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawBoundary {
    pub x: Option<RawFaces>,
    pub y: Option<RawFaces>,
    pub z: Option<RawFaces>,
}

/// One axis of `[boundary]`: a word for both faces, or one per face (low, high).
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub(crate) enum RawFaces {
    Both(String),
    Each(Vec<String>),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawVolume {
    pub procedural: Option<String>,
    pub raw: Option<String>,
    /// An OpenVDB file; `grid` names the density grid in it (default "density").
    pub vdb: Option<String>,
    pub grid: Option<String>,
    /// A NanoVDB file (read like `vdb`; a `.nvdb` named by `vdb` works too).
    pub nvdb: Option<String>,
    /// An NRRD file (`.nhdr` or `.nrrd`).
    pub nrrd: Option<String>,
    /// Required for `procedural` and `raw`; a VDB grid's comes from its active bounding box.
    #[serde(default, deserialize_with = "exactly3_opt")]
    pub dims: Option<[i64; 3]>,
    pub voxel_size: Option<f64>,
    /// World position of the volume's low corner; a VDB grid's comes from its transform.
    #[serde(default, deserialize_with = "exactly3_opt")]
    pub origin: Option<[f64; 3]>,
    pub seed: Option<i64>,
    /// Per-voxel emission: a raw f32 file of the volume's dims, or a grid of the `vdb` file.
    pub emission_raw: Option<String>,
    pub emission_grid: Option<String>,
    /// Per-voxel temperature (blackbody emission): a raw f32 file or a grid of the `vdb` file.
    pub temperature_raw: Option<String>,
    pub temperature_grid: Option<String>,
    /// Per-voxel albedo factor in [0, 1]: a raw f32 file or a grid of the `vdb` file.
    pub albedo_raw: Option<String>,
    pub albedo_grid: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawMedium {
    pub sigma_t: Channels,
    pub albedo: Channels,
    pub g: Option<f64>,
    pub emission: Option<Channels>,
    /// How a temperature grid becomes blackbody emission (see `scene::blackbody`).
    pub temperature_scale: Option<f64>,
    pub temperature_reference: Option<f64>,
    pub temperature_cutoff: Option<f64>,
}

/// One `[[lights]]` entry. Kept flat (rather than a serde-tagged enum) so that an unknown `kind`
/// or a key that belongs to the other kind is reported with its exact key by the validator;
/// serde's internally tagged enums buffer their content and lose the position.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawLight {
    pub kind: String,
    pub radiance: Option<Channels>,
    #[serde(default, deserialize_with = "exactly3_opt")]
    pub direction: Option<[f64; 3]>,
    pub irradiance: Option<Channels>,
    /// `environment`: the lat-long EXR file, its scale, zenith axis and turn about it (degrees).
    pub map: Option<String>,
    pub intensity: Option<Channels>,
    pub up: Option<String>,
    pub rotation: Option<f64>,
    /// `point`: where the light is, in world units (the frame of `volume.origin`).
    #[serde(default, deserialize_with = "exactly3_opt")]
    pub position: Option<[f64; 3]>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawSolver {
    pub directions_per_face: Option<i64>,
    pub storage_directions_per_face: Option<i64>,
    pub sky_directions_per_face: Option<i64>,
    pub scattered_directions_per_face: Option<i64>,
    pub max_orders: Option<i64>,
    pub tolerance: Option<f64>,
    pub device_memory_budget: Option<ByteSize>,
    pub host_memory_budget: Option<ByteSize>,
    pub extrapolate_tail: Option<bool>,
    pub storage_precision: Option<String>,
    pub plan: Option<String>,
    pub spatial: Option<String>,
    pub forward_peak: Option<String>,
    pub emission_uncollided: Option<String>,
    pub diffusion_correction: Option<String>,
    pub acceleration: Option<String>,
    pub diffusion_cells: Option<i64>,
    pub device_residency: Option<String>,
    pub checkpoint_every_orders: Option<i64>,
    pub checkpoint_every_seconds: Option<f64>,
}

/// A 3-vector written as an array of exactly 3 values. serde's own `[T; 3]` reads the first three
/// elements of a longer TOML array and ignores the rest, so `dims = [16, 16, 16, 16]` was silently
/// a 16³ volume; here a longer (or shorter) array is an error naming its length.
fn exactly3<'de, D: Deserializer<'de>, T: Deserialize<'de>>(d: D) -> Result<[T; 3], D::Error> {
    let v: Vec<T> = Vec::deserialize(d)?;
    let n = v.len();
    v.try_into().map_err(|_| de::Error::invalid_length(n, &"an array of exactly 3 values"))
}

pub(crate) fn exactly3_opt<'de, D: Deserializer<'de>, T: Deserialize<'de>>(d: D) -> Result<Option<[T; 3]>, D::Error> {
    exactly3(d).map(Some)
}

/// A per-channel quantity written either as one number (grey) or as `[r, g, b]`. The form is kept
/// so that messages can name `medium.albedo` or `medium.albedo[1]` as written.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Channels {
    Scalar(f64),
    Rgb([f64; 3]),
}

impl<'de> Deserialize<'de> for Channels {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Channels;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number or an [r, g, b] array of 3 numbers")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Channels, E> {
                Ok(Channels::Scalar(v))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Channels, E> {
                Ok(Channels::Scalar(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Channels, E> {
                Ok(Channels::Scalar(v as f64))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Channels, A::Error> {
                let mut rgb = [0.0; 3];
                for (i, c) in rgb.iter_mut().enumerate() {
                    *c = seq.next_element::<f64>()?.ok_or_else(|| de::Error::invalid_length(i, &self))?;
                }
                let mut extra = 0;
                while seq.next_element::<de::IgnoredAny>()?.is_some() {
                    extra += 1;
                }
                if extra > 0 {
                    return Err(de::Error::invalid_length(3 + extra, &self));
                }
                Ok(Channels::Rgb(rgb))
            }
        }
        d.deserialize_any(V)
    }
}

/// `device_memory_budget`: an integer number of bytes or a string such as `"256M"`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum ByteSize {
    Int(i64),
    Text(String),
}

impl<'de> Deserialize<'de> for ByteSize {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = ByteSize;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an integer number of bytes or a string such as \"256M\"")
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<ByteSize, E> {
                Ok(ByteSize::Int(v))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<ByteSize, E> {
                Ok(ByteSize::Int(i64::try_from(v).unwrap_or(i64::MAX)))
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<ByteSize, E> {
                Ok(ByteSize::Text(v.to_string()))
            }
        }
        d.deserialize_any(V)
    }
}
