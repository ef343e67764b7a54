//! Stage two: raw serde structs → typed, checked [`Scene`] values. Every check names the dotted key
//! of the value it rejects; defaults are applied here (and only here).
//!
//! Over 450 lines because every scene key is checked here, next to its default: one place to read
//! what a scene may say.

use super::raw::{ByteSize, Channels, RawBoundary, RawFaces, RawLight, RawMedium, RawScene, RawSolver, RawVolume};
use super::{
    Acceleration, Boundary, CheckpointCadence, DeviceResidency, DiffusionCorrection, EmissionUncollided,
    EnvironmentLight, ForwardPeak, Light, MapUp, Medium, PlanMode, Scene, SceneError, Shape, SolverSettings,
    SpatialScheme, StoragePrecision, Volume, VolumeSource,
};
use albedo::AlbedoKeys;
use emission::{BlackbodyKeys, EmissionKeys};
use glam::DVec3;
use std::path::{Path, PathBuf};

mod albedo;
mod camera;
mod emission;
mod nrrd_volume;
mod vdb_volume;

pub use camera::{
    camera_from_keys, default_camera, display_from_keys, fitted_default_camera, CameraKeys, ExposureKey, VolumeFrame,
    DEFAULT_FOV_Y_DEGREES, DEFAULT_IMAGE_SIZE,
};

/// Largest voxel count accepted (product of dims).
pub const MAX_VOXELS: u64 = 1 << 40;
/// Largest size of one dimension, in voxels.
pub const MAX_DIM: u32 = 65536;
/// Largest image width or height, in pixels.
pub const MAX_IMAGE_SIZE: u32 = 16384;
/// Upper bound for σt and voxel_size: anything larger is certainly a unit mistake.
pub const MAX_MAGNITUDE: f64 = 1e12;
/// Lower bound for voxel_size, the reciprocal of [`MAX_MAGNITUDE`]: anything smaller is as certainly
/// a unit mistake, and a subnormal one squares to 0 (a point light's irradiance one voxel away
/// became infinite and was blamed on the light).
pub const MIN_VOXEL_SIZE: f64 = 1.0 / MAX_MAGNITUDE;
/// Upper bound for every light value: sky radiance, sun irradiance and emitted radiance. Far above
/// any physical scene (sunlight is about 1e3 W/m²), and small enough that every intermediate the
/// solver forms (fluence up to 4π × the sum of the lights, sources up to σt × that, with σt ≤
/// [`MAX_MAGNITUDE`]) stays well inside f32 (≈ 3.4e38): a finite input can never make an infinite
/// or NaN field.
pub const MAX_LIGHT: f64 = 1e12;
/// Most lights a scene may have: each sun is one more sweep source; more is a generated file gone
/// wrong, not a scene.
pub const MAX_LIGHTS: usize = 256;
/// Largest |coordinate| of a camera position, target or up vector, in world units: far beyond any
/// volume (at most 65536 voxels of at most [`MAX_MAGNITUDE`]), small enough that differences and
/// squared lengths stay finite.
pub const MAX_COORDINATE: f64 = 1e18;
/// Largest scene file accepted, in bytes: a scene is a few hundred bytes of TOML; this stops a
/// mistaken path (a volume, a device) from being read into memory.
pub const MAX_SCENE_BYTES: u64 = 1 << 20;

pub const DEFAULT_DIRECTIONS_PER_FACE: u32 = 5;
pub const MAX_DIRECTIONS_PER_FACE: u32 = 32;
pub const DEFAULT_MAX_ORDERS: u32 = 64;
pub const MAX_MAX_ORDERS: u32 = 100_000;
pub const DEFAULT_TOLERANCE: f64 = 1e-4;
pub const DEFAULT_SEED: u64 = 1;

const SHAPES: &str = "\"sphere\", \"box\", \"cloud\"";
const LIGHT_KINDS: &str = "\"sky\", \"sun\", \"environment\", \"point\"";
const MAP_UPS: &str = "\"z\", \"y\"";
const PROJECTIONS: &str = "\"pinhole\", \"orthographic\"";
const PRECISIONS: &str = "\"auto\", \"f16\", \"f32\"";
const PLAN_MODES: &str = "\"auto\", \"full\"";
const SPATIAL_SCHEMES: &str = "\"auto\", \"constant\", \"linear\"";
const FORWARD_PEAKS: &str = "\"auto\", \"delta-m\", \"keep\"";
const DIFFUSION_CORRECTIONS: &str = "\"on\", \"off\"";
const ACCELERATIONS: &str = "\"auto\", \"diffusion\", \"off\"";
/// The most `solver.diffusion_cells` may ask for (8 × the default): the grid's operator and the
/// conjugate gradients' vectors take about 250 bytes a cell and channel on the host.
const MAX_DIFFUSION_CELLS: u32 = 1 << 23;
const DEVICE_RESIDENCIES: &str = "\"auto\", \"streamed\"";

pub(crate) struct Validator<'a> {
    pub path: &'a Path,
}

type R<T> = Result<T, SceneError>;

impl Validator<'_> {
    fn err(&self, key: impl Into<String>, problem: impl Into<String>) -> SceneError {
        SceneError::Invalid { path: self.path.to_path_buf(), key: key.into(), problem: problem.into() }
    }

    pub fn scene(&self, mut raw: RawScene) -> R<Scene> {
        let blackbody = BlackbodyKeys::take(&mut raw.medium);
        let volume = self.volume(raw.volume, blackbody)?;
        let emission_given = raw.medium.emission.is_some();
        let mut medium = self.medium(raw.medium)?;
        if volume.emission.is_some() && !emission_given {
            // A per-voxel emission grid without a colour emits its own values in every channel (a
            // temperature grid its blackbody colour, luminance 1 at the reference temperature).
            medium.emission = [1.0; 3];
        }
        if raw.lights.len() > MAX_LIGHTS {
            return Err(
                self.err("lights", format!("{} lights is more than the limit of {MAX_LIGHTS}", raw.lights.len()))
            );
        }
        let lights =
            raw.lights.into_iter().enumerate().map(|(i, l)| self.light(i, l, &volume)).collect::<R<Vec<_>>>()?;
        let maps: Vec<usize> =
            lights.iter().enumerate().filter(|(_, l)| matches!(l, Light::Environment(_))).map(|(i, _)| i).collect();
        if let [_, second, ..] = maps[..] {
            return Err(self.err(
                format!("lights[{second}].kind"),
                "a scene has at most one environment light (combine the maps into one image)",
            ));
        }
        let solver = self.solver(raw.solver)?;
        self.albedo_with_forward_peak(&volume, solver.forward_peak)?;
        // The solver and renderer work in the volume's frame (its corner at 0): the camera comes
        // back in it.
        let frame = VolumeFrame { dims: volume.dims, voxel_size: volume.voxel_size, origin: volume.origin };
        let display = raw.camera.as_ref().map(|c| self.display(c)).transpose()?.unwrap_or_default();
        let camera = raw.camera.map(|c| self.camera(c, &frame)).transpose()?;
        let boundary = self.boundary(raw.boundary)?;
        if boundary.any_periodic() {
            if let Some(i) = lights.iter().position(|l| matches!(l, Light::Point { .. })) {
                return Err(self.err(
                    format!("lights[{i}].kind"),
                    "a point light in a periodic volume would repeat with it; periodic boundaries take \
                     sky, sun and environment light only",
                ));
            }
            if solver.acceleration == Acceleration::Diffusion {
                return Err(self.err(
                    "solver.acceleration",
                    "\"diffusion\" does not support periodic boundaries yet (part of each order's light \
                     travels on in the rays, unseen by the correction); use \"auto\" or \"off\" with [boundary]",
                ));
            }
        }
        if boundary.any_reflective() {
            self.reflective_fits(&boundary, &lights, &solver)?;
        }
        if solver.sky_directions_per_face.is_some_and(|n| n > solver.directions_per_face)
            && (boundary.any_periodic() || boundary.any_reflective())
        {
            return Err(self.err(
                "solver.sky_directions_per_face",
                "is not supported with periodic or reflective faces (they hand the sky's rays on to the next \
                 order, which its own directions do not have)",
            ));
        }
        if solver.scattered_directions_per_face.is_some_and(|n| n > solver.directions_per_face)
            && (boundary.any_periodic() || boundary.reflective.iter().any(|axis| axis[0] && axis[1]))
        {
            return Err(self.err(
                "solver.scattered_directions_per_face",
                "is not supported with periodic faces or mirrors on both faces of an axis (they hand the rays \
                 on to the next order, which sweeps the k×k directions)",
            ));
        }
        Ok(Scene { path: self.path.to_path_buf(), volume, medium, lights, solver, camera, boundary, display })
    }

    /// What a scene with mirror faces may hold (see `solver::mirror`): the lights must look the
    /// same in the mirror (a sky; a sun travelling parallel to every mirror), and the solver must
    /// use the scheme and passes the mirrors are exact for.
    fn reflective_fits(&self, boundary: &Boundary, lights: &[Light], solver: &SolverSettings) -> R<()> {
        if boundary.any_periodic() {
            return Err(self.err("boundary", "periodic and reflective faces in one scene are not supported yet"));
        }
        let mirrored: Vec<usize> = (0..3).filter(|&a| boundary.reflective[a].contains(&true)).collect();
        for (i, light) in lights.iter().enumerate() {
            let refused = match light {
                Light::Point { .. } => {
                    Some("a point light with mirror faces would need its mirror images; use open faces")
                }
                Light::Environment(_) => {
                    Some("an environment map with mirror faces would need its mirror image; use a sky or open faces")
                }
                Light::Sun { direction, .. } if mirrored.iter().any(|&a| direction[a].abs() > 1e-12) => Some(
                    "the sun's light reaches a mirror face (its direction has a component across it), whose \
                     reflection is not modelled yet: use open faces, or a sun parallel to the mirrors",
                ),
                _ => None,
            };
            if let Some(why) = refused {
                return Err(self.err(format!("lights[{i}].kind"), why));
            }
        }
        if solver.spatial == Some(SpatialScheme::Linear) {
            return Err(self.err(
                "solver.spatial",
                "reflective faces need solver.spatial = \"constant\" (a \"linear\" ray straddles the mirror)",
            ));
        }
        if solver.acceleration == Acceleration::Diffusion {
            return Err(self.err(
                "solver.acceleration",
                "\"diffusion\" does not support reflective faces yet; use \"auto\" or \"off\"",
            ));
        }
        Ok(())
    }

    fn boundary(&self, b: Option<RawBoundary>) -> R<Boundary> {
        let Some(b) = b else { return Ok(Boundary::default()) };
        let mut boundary = Boundary::default();
        for (axis, (name, value)) in [("x", b.x), ("y", b.y), ("z", b.z)].into_iter().enumerate() {
            let key = format!("boundary.{name}");
            let unknown = |word: &str, expected: &str| {
                self.err(&key, format!("unknown boundary \"{word}\", expected {expected}"))
            };
            match value {
                None => {}
                Some(RawFaces::Both(word)) => match word.as_str() {
                    "open" => {}
                    "periodic" => boundary.periodic[axis] = true,
                    "reflective" => boundary.reflective[axis] = [true, true],
                    other => return Err(unknown(other, "\"open\", \"periodic\" or \"reflective\"")),
                },
                Some(RawFaces::Each(words)) => {
                    let [low, high] = &words[..] else {
                        return Err(self.err(
                            &key,
                            format!(
                                "{} faces given; a pair is [low, high], e.g. [\"reflective\", \"open\"]",
                                words.len()
                            ),
                        ));
                    };
                    for (side, word) in [low, high].into_iter().enumerate() {
                        boundary.reflective[axis][side] = match word.as_str() {
                            "open" => false,
                            "reflective" => true,
                            "periodic" => {
                                return Err(
                                    self.err(&key, "periodic joins both faces of an axis: write `periodic` alone")
                                )
                            }
                            other => return Err(unknown(other, "\"open\" or \"reflective\" per face")),
                        };
                    }
                }
            }
        }
        Ok(boundary)
    }

    // ---- scalar helpers -------------------------------------------------------------------

    fn finite(&self, key: &str, v: f64) -> R<f64> {
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err(key, format!("must be a finite number, got {v}")))
        }
    }

    /// Finite, ≥ 0 and (when given) ≤ `max`.
    fn non_negative(&self, key: &str, v: f64, max: Option<f64>) -> R<f64> {
        let v = self.finite(key, v)?;
        if v < 0.0 {
            return Err(self.err(key, format!("must be ≥ 0, got {v}")));
        }
        if let Some(m) = max {
            if v > m {
                return Err(self.err(key, format!("must be ≤ {m:e}, got {}", short(v))));
            }
        }
        Ok(v)
    }

    fn positive(&self, key: &str, v: f64, max: f64) -> R<f64> {
        let v = self.finite(key, v)?;
        if v <= 0.0 {
            return Err(self.err(key, format!("must be > 0, got {}", short(v))));
        }
        if v > max {
            return Err(self.err(key, format!("must be ≤ {max:e}, got {}", short(v))));
        }
        Ok(v)
    }

    fn int_range(&self, key: &str, v: i64, lo: u32, hi: u32) -> R<u32> {
        if v < i64::from(lo) || v > i64::from(hi) {
            return Err(self.err(key, format!("must be in {lo}..={hi}, got {v}")));
        }
        // In range, so the conversion cannot fail.
        u32::try_from(v).map_err(|_| self.err(key, format!("must be in {lo}..={hi}, got {v}")))
    }

    /// Applies `check` to each channel, naming `key` (scalar) or `key[i]` (rgb) on failure.
    fn channels(&self, key: &str, c: Channels, check: impl Fn(&str, f64) -> R<f64>) -> R<[f64; 3]> {
        match c {
            Channels::Scalar(v) => {
                let v = check(key, v)?;
                Ok([v; 3])
            }
            Channels::Rgb(rgb) => {
                let mut out = [0.0; 3];
                for i in 0..3 {
                    out[i] = check(&format!("{key}[{i}]"), rgb[i])?;
                }
                Ok(out)
            }
        }
    }

    fn vec3(&self, key: &str, v: [f64; 3]) -> R<DVec3> {
        for (i, c) in v.iter().enumerate() {
            self.finite(&format!("{key}[{i}]"), *c)?;
        }
        Ok(DVec3::from_array(v))
    }

    /// A finite vector with every |component| ≤ [`MAX_COORDINATE`].
    fn coordinates(&self, key: &str, v: [f64; 3]) -> R<DVec3> {
        let d = self.vec3(key, v)?;
        for (i, c) in v.iter().enumerate() {
            if c.abs() > MAX_COORDINATE {
                return Err(self.err(format!("{key}[{i}]"), format!("must be within ±{MAX_COORDINATE:e}, got {c}")));
            }
        }
        Ok(d)
    }

    // ---- sections -------------------------------------------------------------------------

    fn volume(&self, mut v: RawVolume, blackbody: BlackbodyKeys) -> R<Volume> {
        let keys = EmissionKeys::take(&mut v);
        let albedo = AlbedoKeys::take(&mut v);
        let mut volume = self.volume_source(v)?;
        volume.emission = self.emission(keys, blackbody, &volume)?;
        volume.albedo = self.albedo(albedo, &volume)?;
        Ok(volume)
    }

    fn volume_source(&self, mut v: RawVolume) -> R<Volume> {
        let origin = match v.origin {
            None => DVec3::ZERO,
            Some(o) => self.vec3("volume.origin", o)?,
        };
        if let Some(file) = v.nvdb.take() {
            if v.vdb.is_some() {
                return Err(self.err("volume.nvdb", "set either `vdb` or `nvdb`, not both"));
            }
            v.vdb = Some(file);
            return self.vdb_volume(v, origin, "volume.nvdb");
        }
        if v.vdb.is_some() {
            return self.vdb_volume(v, origin, "volume.vdb");
        }
        if v.nrrd.is_some() {
            return self.nrrd_volume(v, origin);
        }
        if v.grid.is_some() {
            return Err(self.err("volume.grid", "only applies to a `vdb` volume"));
        }
        let Some(raw_dims) = v.dims else {
            return Err(
                self.err("volume.dims", "missing field `dims`: it is required for a `procedural` or `raw` volume")
            );
        };
        let dims = self.dims(raw_dims)?;
        let voxels = dims.iter().map(|&d| u64::from(d)).product::<u64>();
        let voxel_size = match v.voxel_size {
            Some(s) => {
                let s = self.positive("volume.voxel_size", s, MAX_MAGNITUDE)?;
                if s < MIN_VOXEL_SIZE {
                    return Err(
                        self.err("volume.voxel_size", format!("must be ≥ {MIN_VOXEL_SIZE:e}, got {}", short(s)))
                    );
                }
                s
            }
            None => 1.0,
        };
        let source = match (v.procedural, v.raw) {
            (Some(_), Some(_)) => return Err(self.err(
                "volume",
                "set exactly one of `procedural`, `raw`, `vdb` and `nrrd`, but both are set (`procedural` and `raw`)",
            )),
            (None, None) => {
                return Err(
                    self.err("volume", "set exactly one of `procedural`, `raw`, `vdb` and `nrrd`, but neither is set")
                )
            }
            (Some(name), None) => {
                let shape = match name.as_str() {
                    "sphere" => Shape::Sphere,
                    "box" => Shape::Box,
                    "cloud" => Shape::Cloud,
                    other => {
                        return Err(self
                            .err("volume.procedural", format!("unknown shape \"{other}\", expected one of {SHAPES}")))
                    }
                };
                let seed = match v.seed {
                    None => DEFAULT_SEED,
                    Some(s) => {
                        u64::try_from(s).map_err(|_| self.err("volume.seed", format!("must be ≥ 0, got {s}")))?
                    }
                };
                VolumeSource::Procedural { shape, seed }
            }
            (None, Some(raw)) => {
                if v.seed.is_some() {
                    return Err(self.err("volume.seed", "only applies to a procedural volume, not to `raw`"));
                }
                VolumeSource::Raw { path: self.raw_file(&raw, dims, voxels)? }
            }
        };
        Ok(Volume { source, dims, voxel_size, origin, emission: None, albedo: None })
    }

    /// Checks a volume's size: each of `d` in 1..=MAX_DIM and the product at most MAX_VOXELS.
    fn dims(&self, d: [i64; 3]) -> R<[u32; 3]> {
        let mut dims = [0u32; 3];
        for i in 0..3 {
            dims[i] = self.int_range(&format!("volume.dims[{i}]"), d[i], 1, MAX_DIM)?;
        }
        let voxels = dims.iter().map(|&d| u64::from(d)).product::<u64>();
        if voxels > MAX_VOXELS {
            return Err(self.err(
                "volume.dims",
                format!(
                    "{} × {} × {} = {voxels} voxels is more than the limit of 2^40 = {MAX_VOXELS}",
                    dims[0], dims[1], dims[2]
                ),
            ));
        }
        Ok(dims)
    }

    /// Resolves `raw` against the scene file's directory and checks the file's size.
    fn raw_file(&self, raw: &str, dims: [u32; 3], voxels: u64) -> R<PathBuf> {
        self.raw_file_at("volume.raw", raw, dims, voxels)
    }

    /// A raw f32 file named by `key`, resolved against the scene file, of exactly `voxels` values.
    fn raw_file_at(&self, key: &str, raw: &str, dims: [u32; 3], voxels: u64) -> R<PathBuf> {
        if raw.trim().is_empty() {
            return Err(self.err(key, "must name a file, got an empty string"));
        }
        let base = self.path.parent().unwrap_or_else(|| Path::new(""));
        let joined = base.join(raw);
        let resolved = std::path::absolute(&joined).unwrap_or(joined);
        let meta = std::fs::metadata(&resolved).map_err(|source| SceneError::RawFile {
            path: self.path.to_path_buf(),
            key: key.into(),
            raw_path: resolved.clone(),
            source,
        })?;
        if !meta.is_file() {
            return Err(self.err(key, format!("{} is not a regular file", resolved.display())));
        }
        let expected = voxels * 4;
        if meta.len() != expected {
            return Err(SceneError::RawSize {
                path: self.path.to_path_buf(),
                key: key.into(),
                raw_path: resolved,
                dims,
                expected,
                actual: meta.len(),
            });
        }
        Ok(resolved)
    }

    fn medium(&self, m: RawMedium) -> R<Medium> {
        let sigma_t =
            self.channels("medium.sigma_t", m.sigma_t, |k, v| self.non_negative(k, v, Some(MAX_MAGNITUDE)))?;
        let albedo = self.channels("medium.albedo", m.albedo, |k, v| {
            let v = self.finite(k, v)?;
            if (0.0..=1.0).contains(&v) {
                Ok(v)
            } else {
                Err(self.err(k, format!("must be in [0, 1], got {v}")))
            }
        })?;
        let g = match m.g {
            None => 0.0,
            Some(g) => {
                let g = self.finite("medium.g", g)?;
                if g <= -1.0 || g >= 1.0 {
                    return Err(self.err("medium.g", format!("must be in (-1, 1), got {g}")));
                }
                g
            }
        };
        let emission = match m.emission {
            None => [0.0; 3],
            Some(e) => self.channels("medium.emission", e, |k, v| self.non_negative(k, v, Some(MAX_LIGHT)))?,
        };
        Ok(Medium { sigma_t, albedo, g, emission })
    }

    fn light(&self, i: usize, l: RawLight, volume: &Volume) -> R<Light> {
        let key = |name: &str| format!("lights[{i}].{name}");
        let reject_extra = |name: &str, present: bool, kind: &str| -> R<()> {
            if present {
                Err(self.err(key(name), format!("does not apply to a {kind} light")))
            } else {
                Ok(())
            }
        };
        let missing = |name: &str, kind: &str| self.err(key(name), format!("is required for a {kind} light"));
        if l.kind != "point" {
            reject_extra("position", l.position.is_some(), &l.kind)?;
        }
        if l.kind == "sky" || l.kind == "sun" {
            for (name, present) in [
                ("map", l.map.is_some()),
                ("intensity", l.intensity.is_some()),
                ("up", l.up.is_some()),
                ("rotation", l.rotation.is_some()),
            ] {
                reject_extra(name, present, &l.kind)?;
            }
        }
        match l.kind.as_str() {
            "point" => {
                for (name, present) in [
                    ("radiance", l.radiance.is_some()),
                    ("direction", l.direction.is_some()),
                    ("irradiance", l.irradiance.is_some()),
                    ("map", l.map.is_some()),
                    ("up", l.up.is_some()),
                    ("rotation", l.rotation.is_some()),
                ] {
                    reject_extra(name, present, "point")?;
                }
                let position = l.position.ok_or_else(|| missing("position", "point"))?;
                let position = self.coordinates(&key("position"), position)?;
                let intensity = l.intensity.ok_or_else(|| missing("intensity", "point"))?;
                let intensity =
                    self.channels(&key("intensity"), intensity, |k, v| self.non_negative(k, v, Some(MAX_LIGHT)))?;
                // The light's irradiance one voxel edge away, I/h², bounds what any voxel receives
                // (up to the near-light average's factor, `solver::point`): kept within the limit of
                // every light value so that the fields stay finite.
                let h2 = volume.voxel_size * volume.voxel_size;
                if let Some(c) = (0..3).find(|&c| intensity[c] / h2 > MAX_LIGHT) {
                    return Err(self.err(
                        key("intensity"),
                        format!(
                            "{:e} W/sr gives {:e} W/m² one voxel ({} world units) away, more than the limit of {MAX_LIGHT:e}",
                            intensity[c],
                            intensity[c] / h2,
                            short(volume.voxel_size)
                        ),
                    ));
                }
                // The solver works in the volume's frame (its corner at 0), as for the camera.
                let position = position - volume.origin;
                if !position.is_finite() || position.abs().max_element() > MAX_COORDINATE {
                    return Err(self.err(
                        key("position"),
                        format!("lies more than {MAX_COORDINATE:e} world units from volume.origin"),
                    ));
                }
                Ok(Light::Point { position, intensity })
            }
            "environment" => {
                reject_extra("radiance", l.radiance.is_some(), "environment")?;
                reject_extra("direction", l.direction.is_some(), "environment")?;
                reject_extra("irradiance", l.irradiance.is_some(), "environment")?;
                let file = l.map.ok_or_else(|| missing("map", "environment"))?;
                self.environment(i, &file, l.intensity, l.up, l.rotation)
            }
            "sky" => {
                reject_extra("direction", l.direction.is_some(), "sky")?;
                reject_extra("irradiance", l.irradiance.is_some(), "sky")?;
                let radiance = l.radiance.ok_or_else(|| missing("radiance", "sky"))?;
                let radiance =
                    self.channels(&key("radiance"), radiance, |k, v| self.non_negative(k, v, Some(MAX_LIGHT)))?;
                Ok(Light::Sky { radiance })
            }
            "sun" => {
                reject_extra("radiance", l.radiance.is_some(), "sun")?;
                let direction = l.direction.ok_or_else(|| missing("direction", "sun"))?;
                let dkey = key("direction");
                let d = self.vec3(&dkey, direction)?;
                let direction = safe_normalize(d)
                    .ok_or_else(|| self.err(dkey.clone(), "must not be the zero vector (it points toward the sun)"))?;
                let irradiance = l.irradiance.ok_or_else(|| missing("irradiance", "sun"))?;
                let irradiance =
                    self.channels(&key("irradiance"), irradiance, |k, v| self.non_negative(k, v, Some(MAX_LIGHT)))?;
                Ok(Light::Sun { direction, irradiance })
            }
            other => {
                Err(self.err(key("kind"), format!("unknown light kind \"{other}\", expected one of {LIGHT_KINDS}")))
            }
        }
    }

    /// `lights[i]` of kind "environment": reads and checks the map (see [`super::environment`]).
    fn environment(
        &self,
        i: usize,
        file: &str,
        intensity: Option<Channels>,
        up: Option<String>,
        rotation: Option<f64>,
    ) -> R<Light> {
        let key = |name: &str| format!("lights[{i}].{name}");
        let intensity = match intensity {
            None => [1.0; 3],
            Some(c) => self.channels(&key("intensity"), c, |k, v| self.non_negative(k, v, Some(MAX_LIGHT)))?,
        };
        let up = match up.as_deref() {
            None | Some("z") => MapUp::Z,
            Some("y") => MapUp::Y,
            Some(other) => {
                return Err(self.err(key("up"), format!("unknown up axis \"{other}\", expected one of {MAP_UPS}")))
            }
        };
        let rotation_degrees = match rotation {
            None => 0.0,
            Some(r) => {
                let r = self.finite(&key("rotation"), r)?;
                if r.abs() > 360.0 {
                    return Err(self.err(key("rotation"), format!("must be within ±360 degrees, got {r}")));
                }
                r
            }
        };
        if file.trim().is_empty() {
            return Err(self.err(key("map"), "must name a file, got an empty string"));
        }
        let base = self.path.parent().unwrap_or_else(|| Path::new(""));
        let joined = base.join(file);
        let map_path = std::path::absolute(&joined).unwrap_or(joined);
        let map_err = |problem: String| SceneError::Map {
            path: self.path.to_path_buf(),
            key: key("map"),
            map_path: map_path.clone(),
            problem,
        };
        let map = super::environment::read_map(&map_path).map_err(map_err)?;
        let brightest = map.rgb.iter().flatten().fold(0.0f32, |m, &v| m.max(v)) as f64;
        for c in 0..3 {
            if brightest * intensity[c] > MAX_LIGHT {
                return Err(map_err(format!(
                    "its brightest pixel ({brightest:e}) × lights[{i}].intensity ({:e}) is more than the limit of {MAX_LIGHT:e}",
                    intensity[c]
                )));
            }
        }
        Ok(Light::Environment(EnvironmentLight { map: std::sync::Arc::new(map), intensity, up, rotation_degrees }))
    }

    fn solver(&self, s: Option<RawSolver>) -> R<SolverSettings> {
        let Some(s) = s else {
            return Ok(SolverSettings {
                directions_per_face: DEFAULT_DIRECTIONS_PER_FACE,
                storage_directions_per_face: None,
                sky_directions_per_face: None,
                scattered_directions_per_face: None,
                max_orders: DEFAULT_MAX_ORDERS,
                tolerance: DEFAULT_TOLERANCE,
                device_memory_budget: None,
                host_memory_budget: None,
                extrapolate_tail: false,
                storage_precision: StoragePrecision::Auto,
                plan: PlanMode::Auto,
                spatial: None,
                forward_peak: ForwardPeak::default(),
                emission_uncollided: EmissionUncollided::default(),
                diffusion_correction: DiffusionCorrection::default(),
                acceleration: Acceleration::default(),
                diffusion_cells: None,
                checkpoint: CheckpointCadence::default(),
                device_residency: DeviceResidency::default(),
            });
        };
        let k = match s.directions_per_face {
            None => DEFAULT_DIRECTIONS_PER_FACE,
            Some(k) => self.int_range("solver.directions_per_face", k, 1, MAX_DIRECTIONS_PER_FACE)?,
        };
        let ks = match s.storage_directions_per_face {
            None => None,
            Some(ks) => {
                if ks > i64::from(k) {
                    return Err(self.err(
                        "solver.storage_directions_per_face",
                        format!("must be ≤ solver.directions_per_face = {k}, got {ks}"),
                    ));
                }
                Some(self.int_range("solver.storage_directions_per_face", ks, 1, k)?)
            }
        };
        let sky_k = match s.sky_directions_per_face {
            None => None,
            Some(n) if n < i64::from(k) => {
                return Err(self.err(
                    "solver.sky_directions_per_face",
                    format!(
                        "must be ≥ solver.directions_per_face = {k} (the sky's directions refine the others), got {n}"
                    ),
                ))
            }
            Some(n) => Some(self.int_range("solver.sky_directions_per_face", n, 1, MAX_DIRECTIONS_PER_FACE)?),
        };
        let scattered_k = match s.scattered_directions_per_face {
            None => None,
            Some(n) if n < i64::from(k) || n % i64::from(k) != 0 => {
                return Err(self.err(
                    "solver.scattered_directions_per_face",
                    format!(
                        "must be a multiple of solver.directions_per_face = {k} (each of its directions lies in \
                         one of the k×k), got {n}"
                    ),
                ))
            }
            Some(n) => Some(self.int_range("solver.scattered_directions_per_face", n, 1, MAX_DIRECTIONS_PER_FACE)?),
        };
        let max_orders = match s.max_orders {
            None => DEFAULT_MAX_ORDERS,
            Some(n) => self.int_range("solver.max_orders", n, 1, MAX_MAX_ORDERS)?,
        };
        let tolerance = match s.tolerance {
            None => DEFAULT_TOLERANCE,
            Some(t) => {
                let t = self.finite("solver.tolerance", t)?;
                if t <= 0.0 || t >= 1.0 {
                    return Err(self.err("solver.tolerance", format!("must be in (0, 1), got {t}")));
                }
                t
            }
        };
        let device_memory_budget = match s.device_memory_budget {
            None => None,
            Some(b) => Some(self.byte_size("solver.device_memory_budget", &b)?),
        };
        let host_memory_budget = match s.host_memory_budget {
            None => None,
            Some(b) => Some(self.byte_size("solver.host_memory_budget", &b)?),
        };
        let storage_precision = match s.storage_precision.as_deref() {
            None | Some("auto") => StoragePrecision::Auto,
            Some("f16") => StoragePrecision::F16,
            Some("f32") => StoragePrecision::F32,
            Some(other) => {
                return Err(self.err(
                    "solver.storage_precision",
                    format!("unknown storage precision \"{other}\", expected one of {PRECISIONS}"),
                ))
            }
        };
        let plan = match s.plan.as_deref() {
            None | Some("auto") => PlanMode::Auto,
            Some("full") => PlanMode::Full,
            Some(other) => {
                return Err(self.err("solver.plan", format!("unknown plan \"{other}\", expected one of {PLAN_MODES}")))
            }
        };
        let spatial = match s.spatial.as_deref() {
            None | Some("auto") => None,
            Some("linear") => Some(SpatialScheme::Linear),
            Some("constant") => Some(SpatialScheme::Constant),
            Some(other) => {
                return Err(self.err(
                    "solver.spatial",
                    format!("unknown spatial scheme \"{other}\", expected one of {SPATIAL_SCHEMES}"),
                ))
            }
        };
        let forward_peak = match s.forward_peak.as_deref() {
            None | Some("auto") => ForwardPeak::Auto,
            Some("delta-m") => ForwardPeak::DeltaM,
            Some("keep") => ForwardPeak::Keep,
            Some(other) => {
                return Err(self.err(
                    "solver.forward_peak",
                    format!("unknown forward peak treatment \"{other}\", expected one of {FORWARD_PEAKS}"),
                ))
            }
        };
        let emission_uncollided = match s.emission_uncollided.as_deref() {
            None | Some("auto") => EmissionUncollided::Auto,
            Some("traced") => EmissionUncollided::Traced,
            Some("swept") => EmissionUncollided::Swept,
            Some(other) => {
                return Err(self.err(
                    "solver.emission_uncollided",
                    format!("unknown treatment \"{other}\", expected one of \"auto\", \"traced\", \"swept\""),
                ))
            }
        };
        let diffusion_correction = match s.diffusion_correction.as_deref() {
            None => DiffusionCorrection::default(),
            Some("on") => DiffusionCorrection::On,
            Some("off") => DiffusionCorrection::Off,
            Some(other) => {
                return Err(self.err(
                    "solver.diffusion_correction",
                    format!("unknown diffusion correction \"{other}\", expected one of {DIFFUSION_CORRECTIONS}"),
                ))
            }
        };
        let acceleration = match s.acceleration.as_deref() {
            None | Some("auto") => Acceleration::Auto,
            Some("diffusion") => Acceleration::Diffusion,
            Some("off") => Acceleration::Off,
            Some(other) => {
                return Err(self.err(
                    "solver.acceleration",
                    format!("unknown acceleration \"{other}\", expected one of {ACCELERATIONS}"),
                ))
            }
        };
        if acceleration == Acceleration::Diffusion && spatial == Some(SpatialScheme::Linear) {
            return Err(self.err(
                "solver.acceleration",
                "\"diffusion\" can diverge with solver.spatial = \"linear\" (its bilinear lattice spreads \
                 light unlike diffusion); use spatial = \"constant\" (what \"auto\" takes for a scattering \
                 medium) or acceleration = \"off\"",
            ));
        }
        if acceleration == Acceleration::Diffusion && s.extrapolate_tail == Some(true) {
            return Err(self.err(
                "solver.acceleration",
                "\"diffusion\" and solver.extrapolate_tail = true are two ways to the same end; choose one",
            ));
        }
        let diffusion_cells = match s.diffusion_cells {
            None => None,
            Some(n) => Some(self.int_range("solver.diffusion_cells", n, 1, MAX_DIFFUSION_CELLS)?),
        };
        let device_residency = match s.device_residency.as_deref() {
            None | Some("auto") => DeviceResidency::Auto,
            Some("streamed") => DeviceResidency::Streamed,
            Some(other) => {
                return Err(self.err(
                    "solver.device_residency",
                    format!("unknown device residency \"{other}\", expected one of {DEVICE_RESIDENCIES}"),
                ))
            }
        };
        let every_orders = match s.checkpoint_every_orders {
            None => None,
            Some(n) if (1..=i64::from(u32::MAX)).contains(&n) => Some(n as u32),
            Some(n) => return Err(self.err("solver.checkpoint_every_orders", format!("must be at least 1, got {n}"))),
        };
        let every_seconds = match s.checkpoint_every_seconds {
            None => CheckpointCadence::default().every_seconds,
            Some(t) if t.is_finite() && t >= 0.0 => t,
            Some(t) => {
                return Err(self.err(
                    "solver.checkpoint_every_seconds",
                    format!("must be a finite number of seconds ≥ 0 (0: after every order), got {}", short(t)),
                ))
            }
        };
        Ok(SolverSettings {
            directions_per_face: k,
            storage_directions_per_face: ks,
            sky_directions_per_face: sky_k,
            scattered_directions_per_face: scattered_k,
            max_orders,
            tolerance,
            device_memory_budget,
            host_memory_budget,
            extrapolate_tail: s.extrapolate_tail.unwrap_or(false),
            storage_precision,
            plan,
            spatial,
            forward_peak,
            emission_uncollided,
            diffusion_correction,
            acceleration,
            diffusion_cells,
            checkpoint: CheckpointCadence { every_orders, every_seconds },
            device_residency,
        })
    }

    fn byte_size(&self, key: &str, b: &ByteSize) -> R<u64> {
        match b {
            ByteSize::Int(n) => {
                if *n <= 0 {
                    Err(self.err(key, format!("must be > 0 bytes, got {n}")))
                } else {
                    Ok(n.unsigned_abs())
                }
            }
            ByteSize::Text(s) => parse_byte_size(s).map_err(|why| {
                self.err(
                    key,
                    format!(
                        "invalid byte size \"{s}\" ({why}): expected a positive byte count such as \
                         1073741824, \"512M\" or \"4G\" (suffixes K, M, G, T are powers of 1024)"
                    ),
                )
            }),
        }
    }
}

/// `v` as written in a message: plain for ordinary magnitudes, in e-notation for huge or tiny
/// ones (`1e308` rather than 309 digits).
fn short(v: f64) -> String {
    if v != 0.0 && !(1e-6..1e15).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// `v / |v|` for any finite `v`, however large or small its components (`[1e308; 3]` would
/// overflow the length to infinity and normalise to zero; `[1e-310; 3]` would underflow it):
/// scaled by its largest component first. `None` for the zero vector.
pub fn safe_normalize(v: DVec3) -> Option<DVec3> {
    let m = v.abs().max_element();
    if !(m > 0.0 && m.is_finite()) {
        return None;
    }
    let u = (v / m).normalize();
    u.is_finite().then_some(u)
}

/// The orthographic view height that fits the whole volume whatever the view direction: the
/// length of the volume's diagonal in world units.
pub fn default_orthographic_height(volume: &Volume) -> f64 {
    camera::diagonal(volume.dims, volume.voxel_size)
}

/// Parses `"256M"`, `"1.5G"`, `"4GiB"`, `"512 KB"`, `"1048576"` into bytes (K/M/G/T = powers of
/// 1024, case-insensitive, optional `B`/`iB`). Fractions are rounded down to whole bytes.
pub fn parse_byte_size(text: &str) -> Result<u64, String> {
    let s = text.trim();
    let split = s.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(s.len());
    let (number, suffix) = s.split_at(split);
    if number.is_empty() {
        return Err("no number".into());
    }
    let suffix = suffix.trim().to_ascii_uppercase();
    let shift = match suffix.as_str() {
        "" | "B" => 0,
        "K" | "KB" | "KIB" => 10,
        "M" | "MB" | "MIB" => 20,
        "G" | "GB" | "GIB" => 30,
        "T" | "TB" | "TIB" => 40,
        _ => return Err(format!("unknown suffix \"{}\"", suffix)),
    };
    let bytes = if number.contains('.') {
        let v: f64 = number.parse().map_err(|_| format!("\"{number}\" is not a number"))?;
        let b = v * (1u64 << shift) as f64;
        if !(b < u64::MAX as f64) {
            return Err("too large".into());
        }
        b.floor() as u64
    } else {
        let v: u64 = number.parse().map_err(|_| "too large".to_string())?;
        v.checked_mul(1u64 << shift).ok_or_else(|| "too large".to_string())?
    };
    if bytes == 0 {
        return Err("must be > 0".into());
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_sizes() {
        assert_eq!(parse_byte_size("256M"), Ok(256 << 20));
        assert_eq!(parse_byte_size("4g"), Ok(4 << 30));
        assert_eq!(parse_byte_size("1.5G"), Ok(3 << 29));
        assert_eq!(parse_byte_size(" 2 TiB "), Ok(2 << 40));
        assert_eq!(parse_byte_size("512KB"), Ok(512 << 10));
        assert_eq!(parse_byte_size("1000"), Ok(1000));
        assert!(parse_byte_size("0M").is_err());
        assert!(parse_byte_size("lots").is_err());
        assert!(parse_byte_size("12Q").is_err());
        assert!(parse_byte_size("1.2.3M").is_err());
        assert!(parse_byte_size("99999999999T").is_err());
        assert!(parse_byte_size("").is_err());
    }
}
