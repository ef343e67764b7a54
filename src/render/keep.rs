//! What a solve keeps so that `lpm render OUT` can render its result again from another view without
//! solving again: `OUT/render-data/`.
//!
//! The renderer reads the density (for the extinction along each ray), the solved in-scattered
//! source, the medium as the plan models it (δ-M scaled where the plan says so), the channels and
//! the direction sets the source is stored for, the sky behind the volume, where the volume is in
//! the world, and the camera the solve rendered with. `render-data/` holds exactly that:
//!
//! | file | content |
//! |---|---|
//! | `bricks.json`, `density.bricks` | the brick store's table and density (see [`crate::store`]) |
//! | `source.field` | the in-scattered source summed over orders, in brick form, less the suns' first scattering where the renderer evaluates it exactly (below) |
//! | `direct_<b>.field` | sun b's uncollided irradiance per voxel, true extinction, then (δ-M solves) the scaled one, the solve's extinction (one per sun, see [`SingleScatteringData`]); traced to each voxel's centre along the sun, every voxel of an occupied brick ([`crate::solver::beam_trace`]) or, past the trace's limit, the sweep's voxel averages (0 where the density is 0) |
//! | `environment.exr` | the scene's environment map, when it has one (the background) |
//! | `render.json` | [`RenderData`]: everything else, written last |
//!
//! The brick files are hard links to the solve's own store files (no copy, no extra space while
//! `--keep-store` keeps them too), or copies where a link cannot be made. The directory is
//! published with the solve's other outputs as one set.
//!
//! **The suns' and point lights' single scattering** (format 2: suns; format 3: and point lights,
//! and under δ-M the scaled irradiance for the forward peak's chains, [`super::peak`]). Where the
//! solve could split it off ([`crate::solver::direct`]: every sun, an environment map's sun-like
//! peak and every point light, no periodic or mirror faces), `source.field` is the solve's source
//! total less their first scattering (exactly what order 0 put in: binned in storage directions,
//! with the δ-M scaled medium and phase), a field of its own rather than a link to the exported
//! total, and each light's uncollided irradiance is kept beside it (suns first, then point
//! lights); the renderer adds `σs·p_HG(g; ω_light·ω_camera)·E` along each camera ray with the
//! scene's true medium ([`super::march`]). The exported `source` of the solve is unchanged. Cost
//! per light: one f32 per voxel of the occupied bricks and channel (`4·channels·4096` bytes per
//! occupied brick), twice that under δ-M.

use super::peak::{peak_share, ForwardLobes};
use super::{render, Background, DirectBeam, Image, PointSource, RenderInputs, SingleScattering, VoxelFactors};
use crate::output::{write_json_atomic, OutputError};
use crate::quadrature::{PropagationSet, StorageBlend, StorageSet};
use crate::scene::{
    camera_from_keys, display_from_keys, Camera, CameraKeys, Display, EnvironmentLight, Exposure, Light, MapUp, Medium,
    Projection, SceneError, View, VolumeFrame,
};
use crate::store::{BrickStore, Coverage, Field};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The directory in `OUT` a solve keeps for `lpm render`.
pub const RENDER_DATA: &str = "render-data";
const DATA_FILE: &str = "render.json";
const SOURCE_FIELD: &str = "source";
/// [`RenderData::format`] of this version of lpm. 2: the image's source holds no suns' first
/// scattering where `single_scattering` is given (format 1's held it; it cannot be rendered by this
/// lpm without counting it twice or losing it). 3: under δ-M the suns' fields also hold the
/// scaled irradiance, and the point lights' first scattering is off the source too, their
/// irradiance kept after the suns' (`single_scattering.peak_chains`, `.points`). 4: the suns'
/// traced irradiance is kept at the voxels' centres and interpolated in optical depth
/// (`single_scattering.irradiance_at_centres`). Formats 2 and 3 are still read (rendered as
/// their lpm rendered them).
const FORMAT: u32 = 4;

/// `render-data/render.json`. Vectors and the camera are in the volume's frame (its corner at 0),
/// `origin` places it in the world.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderData {
    pub format: u32,
    pub dims: [u32; 3],
    pub voxel_size: f64,
    pub origin: [f64; 3],
    /// 1 (grey) or 3.
    pub channels: u32,
    /// k: the propagation directions are k×k per cube face.
    pub directions_per_face: u32,
    /// Storage cells per face edge of the source; 0: one storage direction (isotropic).
    pub storage_per_face: u32,
    pub medium: MediumData,
    /// Sky radiance (the background with `--background sky`).
    pub sky: [f64; 3],
    /// The camera the solve rendered with (the scene's, or the default view).
    pub camera: CameraData,
    /// The medium emits per voxel: `emission.field` (the store's emission factor: one grey
    /// component, or r, g, b from a temperature grid) is kept too and scales `medium.emission`
    /// voxel by voxel.
    #[serde(default)]
    pub emission_per_voxel: bool,
    /// The albedo varies per voxel: `albedo.field` (the store's albedo factor, one component) is
    /// kept too and scales `medium.albedo` voxel by voxel (it changes σa, hence the emission).
    #[serde(default)]
    pub albedo_per_voxel: bool,
    /// The scene's environment map, seen behind the volume with `--background sky`: its file is
    /// kept as `environment.exr` (linked or copied).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub environment: Option<EnvironmentData>,
    /// How the solve exposed and tone-mapped its PNG (`lpm render` does the same unless told
    /// otherwise). Absent (render data kept before the choice existed): `standard` at EV 0, the
    /// only mapping there was.
    #[serde(default = "DisplayData::before_views")]
    pub display: DisplayData,
    /// The suns whose single scattering the renderer evaluates exactly (their first scattering is
    /// not in `source.field`); absent: the source holds every order (no suns, or a scene whose
    /// beams cross periodic or mirror faces).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub single_scattering: Option<SingleScatteringData>,
}

/// The suns' exact single scattering in `render.json`: sun b's irradiance is `direct_<b>.field`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SingleScatteringData {
    /// The scene's medium, not δ-M scaled.
    pub medium: MediumData,
    /// Per sun, the direction its light travels (unit length, volume frame).
    pub travel: Vec<[f64; 3]>,
    /// The solve applied δ-M: each `direct_<b>.field` holds the δ-M scaled irradiance after the
    /// true one (2 × channels components), and the renderer scatters the peak's chains
    /// ([`crate::render::peak`]). Absent (false) in render data written before it.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub peak_chains: bool,
    /// Per point light, its position (voxel units, the volume's corner at 0); its irradiance is
    /// `direct_<b>.field` with b counting on after the suns' (format 3).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub points: Vec<[f64; 3]>,
    /// The suns' fields hold the irradiance at each voxel's centre, traced through the density
    /// the renderer sees, for every voxel of an occupied brick, and the renderer interpolates
    /// its logarithm ([`crate::solver::beam_trace`], format 4); absent (false): chord averages
    /// (format 3) or the sweep's segment averages (past the trace's limit), 0 where the density
    /// is 0, interpolated as ρ·E.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub irradiance_at_centres: bool,
}

/// The name, without `.field`, of sun b's irradiance in `render-data/`.
pub fn direct_field_name(b: usize) -> String {
    crate::solver::direct::irradiance_field_name(b)
}

/// [`Display`] as `render.json` stores it: `view` a name, `exposure` stops or "auto".
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DisplayData {
    pub view: String,
    pub exposure: serde_json::Value,
}

impl DisplayData {
    fn before_views() -> DisplayData {
        (&Display { view: View::Standard, exposure: Exposure::Ev(0.0) }).into()
    }

    fn display(&self, path: &Path) -> Result<Display, OutputError> {
        let invalid = |m: String| OutputError::Invalid { path: path.to_path_buf(), message: m };
        let view = View::from_name(&self.view)
            .ok_or_else(|| invalid(format!("display.view: unknown view transform {:?}", self.view)))?;
        let exposure = match &self.exposure {
            serde_json::Value::String(s) if s == "auto" => Exposure::Auto,
            serde_json::Value::Number(n) => n
                .as_f64()
                .ok_or_else(|| invalid("display.exposure: not a number".to_string()))
                .and_then(|ev| Exposure::ev(ev).map_err(|m| invalid(format!("display.exposure: {m}"))))?,
            other => return Err(invalid(format!("display.exposure: expected stops or \"auto\", got {other}"))),
        };
        Ok(Display { view, exposure })
    }
}

impl From<&Display> for DisplayData {
    fn from(d: &Display) -> Self {
        let exposure = match d.exposure {
            Exposure::Auto => serde_json::Value::from("auto"),
            Exposure::Ev(ev) => serde_json::Value::from(ev),
        };
        DisplayData { view: d.view.name().to_string(), exposure }
    }
}

/// How the kept `environment.exr` lies around the volume (`[[lights]] kind = "environment"`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvironmentData {
    pub intensity: [f64; 3],
    /// "z" or "y".
    pub up: String,
    pub rotation: f64,
}

/// The name of the kept environment map in `render-data/`.
const ENVIRONMENT_FILE: &str = "environment.exr";

impl EnvironmentData {
    fn new(env: &EnvironmentLight) -> EnvironmentData {
        EnvironmentData { intensity: env.intensity, up: env.up.name().to_string(), rotation: env.rotation_degrees }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MediumData {
    pub sigma_t: [f64; 3],
    pub albedo: [f64; 3],
    pub g: f64,
    pub emission: [f64; 3],
}

impl From<&Medium> for MediumData {
    fn from(m: &Medium) -> Self {
        MediumData { sigma_t: m.sigma_t, albedo: m.albedo, g: m.g, emission: m.emission }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraData {
    /// "pinhole" or "orthographic".
    pub projection: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fov_y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view_height: Option<f64>,
    pub position: [f64; 3],
    pub look_at: [f64; 3],
    pub up: [f64; 3],
    pub width: u32,
    pub height: u32,
}

impl From<&Camera> for CameraData {
    fn from(c: &Camera) -> Self {
        let (projection, fov_y, view_height) = match c.projection {
            Projection::Pinhole { fov_y_degrees } => ("pinhole", Some(fov_y_degrees), None),
            Projection::Orthographic { height } => ("orthographic", None, Some(height)),
        };
        CameraData {
            projection: projection.to_string(),
            fov_y,
            view_height,
            position: c.position.to_array(),
            look_at: c.look_at.to_array(),
            up: c.up.to_array(),
            width: c.width,
            height: c.height,
        }
    }
}

impl CameraData {
    fn camera(&self, path: &Path) -> Result<Camera, OutputError> {
        let invalid = |m: &str| OutputError::Invalid { path: path.to_path_buf(), message: m.to_string() };
        let projection = match (self.projection.as_str(), self.fov_y, self.view_height) {
            ("pinhole", Some(f), None) if f > 0.0 && f < 180.0 => Projection::Pinhole { fov_y_degrees: f },
            ("orthographic", None, Some(h)) if h > 0.0 && h.is_finite() => Projection::Orthographic { height: h },
            _ => return Err(invalid(
                "camera: a pinhole camera with fov_y in (0, 180) or an orthographic one with view_height > 0 expected",
            )),
        };
        let finite = [self.position, self.look_at, self.up].iter().flatten().all(|v| v.is_finite());
        if !finite || self.width == 0 || self.height == 0 {
            return Err(invalid("camera: non-finite vectors or a zero image size"));
        }
        Ok(Camera {
            projection,
            position: DVec3::from_array(self.position),
            look_at: DVec3::from_array(self.look_at),
            up: DVec3::from_array(self.up),
            width: self.width,
            height: self.height,
        })
    }
}

impl RenderData {
    /// What a solve of `medium` (as the plan models it) with these lights and sets keeps.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        dims: [u32; 3],
        voxel_size: f64,
        origin: DVec3,
        channels: u32,
        propagation: &PropagationSet,
        storage: &StorageSet,
        medium: &Medium,
        lights: &[Light],
        camera: &Camera,
        display: &Display,
    ) -> RenderData {
        RenderData {
            format: FORMAT,
            dims,
            voxel_size,
            origin: origin.to_array(),
            channels,
            directions_per_face: propagation.k,
            storage_per_face: storage.per_face,
            medium: medium.into(),
            sky: sky_radiance(lights),
            camera: camera.into(),
            emission_per_voxel: false,
            albedo_per_voxel: false,
            environment: environment_light(lights).map(EnvironmentData::new),
            display: display.into(),
            single_scattering: None,
        }
    }
}

/// The sum of the scene's sky radiances: what a camera ray sees where it leaves the volume.
pub fn sky_radiance(lights: &[Light]) -> [f64; 3] {
    let mut sky = [0.0; 3];
    for light in lights {
        if let Light::Sky { radiance } = light {
            (0..3).for_each(|c| sky[c] += radiance[c]);
        }
    }
    sky
}

/// The scene's environment light, if it has one (at most one: the validator says so).
pub fn environment_light(lights: &[Light]) -> Option<&EnvironmentLight> {
    lights.iter().find_map(|l| match l {
        Light::Environment(env) => Some(env),
        _ => None,
    })
}

/// Writes `dir` (a new directory, e.g. in a staging directory): links to `store`'s table and
/// density, to `source`'s file and to each of the suns' irradiance fields in `direct` (and the environment map's, when `environment` is given), then
/// `render.json`.
pub fn keep(
    dir: &Path,
    store: &BrickStore,
    source: &Field,
    direct: &[Field],
    environment: Option<&EnvironmentLight>,
    data: &RenderData,
) -> Result<(), OutputError> {
    let io = |path: &Path, action: &'static str| {
        let path = path.to_path_buf();
        move |source| OutputError::Io { path, action, source }
    };
    std::fs::create_dir(dir).map_err(io(dir, "create"))?;
    source.flush()?;
    let mut files = vec![
        (store.dir().join("bricks.json"), "bricks.json".to_string()),
        (store.dir().join("density.bricks"), "density.bricks".to_string()),
        (source.path().to_path_buf(), format!("{SOURCE_FIELD}.field")),
    ];
    for (b, field) in direct.iter().enumerate() {
        field.flush()?;
        files.push((field.path().to_path_buf(), format!("{}.field", direct_field_name(b))));
    }
    if data.emission_per_voxel {
        let name = format!("{}.field", crate::store::emission::EMISSION_FIELD);
        files.push((store.dir().join(&name), name));
    }
    if data.albedo_per_voxel {
        let name = format!("{}.field", crate::store::albedo::ALBEDO_FIELD);
        files.push((store.dir().join(&name), name));
    }
    if let Some(env) = environment {
        files.push((env.map.path.clone(), ENVIRONMENT_FILE.to_string()));
    }
    for (from, name) in files {
        let to = dir.join(name);
        if std::fs::hard_link(&from, &to).is_err() {
            std::fs::copy(&from, &to).map_err(io(&to, "copy the solved field into"))?;
        }
    }
    write_json_atomic(&dir.join(DATA_FILE), data)
}

/// A solved result opened for rendering.
pub struct Kept {
    pub data: RenderData,
    pub store: BrickStore,
    pub source: Field,
    /// The per-voxel emission factor, when the medium emits per voxel.
    pub emission: Option<Field>,
    /// The per-voxel albedo factor, when the albedo varies per voxel.
    pub albedo: Option<Field>,
    /// The suns' uncollided irradiance, one field per sun of `data.single_scattering`.
    pub direct: Vec<Field>,
    /// The camera the solve rendered with, in the volume's frame.
    pub camera: Camera,
    /// How the solve exposed and tone-mapped its PNG.
    pub display: Display,
    /// The environment map behind the volume, read back from `environment.exr`.
    pub environment: Option<EnvironmentLight>,
}

/// Opens `out/render-data` as the solve left it, checking that the pieces fit together.
pub fn open(out: &Path) -> Result<Kept, OutputError> {
    let dir = out.join(RENDER_DATA);
    let path = dir.join(DATA_FILE);
    let invalid = |message: String| OutputError::Invalid { path: path.clone(), message };
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(invalid(format!(
                "not found: {} holds no solve that can be rendered again (solved with --no-render-data, or by an lpm older than `lpm render`)",
                out.display()
            )))
        }
        Err(source) => return Err(OutputError::Io { path, action: "read", source }),
    };
    let data: RenderData =
        serde_json::from_str(&text).map_err(|source| OutputError::Json { path: path.clone(), source })?;
    if data.format == 1 {
        return Err(invalid(format!(
            "format 1: kept by an lpm whose image source still held the suns' first scattering, which this lpm \
             ({FORMAT}) adds exactly at render time from the suns' irradiance (not kept in format 1); solve again"
        )));
    }
    if !(2..=FORMAT).contains(&data.format) {
        return Err(invalid(format!("format {} is not the one this lpm reads ({FORMAT}); solve again", data.format)));
    }
    let k = data.directions_per_face;
    let valid = (1..=32).contains(&k)
        && data.storage_per_face <= k
        && matches!(data.channels, 1 | 3)
        && data.voxel_size > 0.0
        && data.voxel_size.is_finite()
        && data.origin.iter().all(|v| v.is_finite());
    if !valid {
        return Err(invalid(format!(
            "inconsistent: {k} directions per face, {} storage cells per face, {} channels, voxel size {}",
            data.storage_per_face, data.channels, data.voxel_size
        )));
    }
    let camera = data.camera.camera(&path)?;
    let display = data.display.display(&path)?;
    let store = BrickStore::open(&dir)?;
    if store.grid().dims != data.dims || store.voxel_size() != data.voxel_size {
        return Err(invalid(format!(
            "the brick store is {:?} voxels of {}, render.json says {:?} of {}",
            store.grid().dims,
            store.voxel_size(),
            data.dims,
            data.voxel_size
        )));
    }
    let storage_dirs = if data.storage_per_face == 0 { 1 } else { 6 * data.storage_per_face * data.storage_per_face };
    let source = store.open_field(SOURCE_FIELD, storage_dirs * data.channels, Coverage::Occupied)?;
    let emission = if data.emission_per_voxel { Some(crate::store::emission::open_emission(&store)?) } else { None };
    let albedo = if data.albedo_per_voxel { Some(crate::store::albedo::open_albedo(&store)?) } else { None };
    let mut direct = Vec::new();
    if let Some(single) = &data.single_scattering {
        let m = &single.medium;
        let fine = [m.sigma_t, m.albedo].iter().flatten().all(|v| v.is_finite() && *v >= 0.0)
            && m.g.is_finite()
            && m.g.abs() < 1.0
            && single.travel.iter().all(|t| t.iter().all(|v| v.is_finite()) && DVec3::from_array(*t).length() > 0.5)
            && single.points.iter().flatten().all(|v| v.is_finite());
        if !fine {
            return Err(invalid(
                "single_scattering: a non-finite or negative medium, |g| ≥ 1, a bad direction or position".into(),
            ));
        }
        let components = if single.peak_chains { 2 * data.channels } else { data.channels };
        for b in 0..single.travel.len() + single.points.len() {
            direct.push(store.open_field(&direct_field_name(b), components, Coverage::Occupied)?);
        }
    }
    let environment = match &data.environment {
        None => None,
        Some(e) => {
            let up = match e.up.as_str() {
                "z" => MapUp::Z,
                "y" => MapUp::Y,
                other => return Err(invalid(format!("environment: unknown up axis \"{other}\""))),
            };
            let fine = e.intensity.iter().all(|v| v.is_finite() && *v >= 0.0) && e.rotation.is_finite();
            if !fine {
                return Err(invalid("environment: a non-finite or negative intensity or rotation".into()));
            }
            let file = dir.join(ENVIRONMENT_FILE);
            let map = crate::scene::environment::read_map(&file)
                .map_err(|m| OutputError::Invalid { path: file.clone(), message: format!("environment map: {m}") })?;
            Some(EnvironmentLight {
                map: std::sync::Arc::new(map),
                intensity: e.intensity,
                up,
                rotation_degrees: e.rotation,
            })
        }
    };
    Ok(Kept { data, store, source, emission, albedo, direct, camera, display, environment })
}

impl Kept {
    /// Renders the kept result through `camera` (volume frame) over `background`.
    pub fn render(&self, camera: &Camera, background: Background) -> Image {
        render_solved(
            &self.data,
            &self.store,
            &self.source,
            VoxelFactors { emission: self.emission.as_ref(), albedo: self.albedo.as_ref(), direct: &self.direct },
            self.environment.as_ref(),
            camera,
            background,
        )
    }
}

/// Renders a solved `source` (with its `store` and, where the medium emits or scatters per voxel,
/// the store's `emission` and `albedo` fields) as `data` describes it, through `camera` (volume frame) over `background`
/// (with `environment`, the scene's map, behind the volume for [`Background::Sky`]):
/// the one path both `lpm solve` and `lpm render` take, so a render of the kept data from the
/// solve's view is bitwise the solve's image.
pub fn render_solved(
    data: &RenderData,
    store: &BrickStore,
    source: &Field,
    factors: VoxelFactors,
    environment: Option<&EnvironmentLight>,
    camera: &Camera,
    background: Background,
) -> Image {
    let propagation = PropagationSet::new(data.directions_per_face);
    let storage = if data.storage_per_face == 0 {
        StorageSet::isotropic(&propagation)
    } else {
        StorageSet::per_face(&propagation, data.storage_per_face)
    };
    let m = &data.medium;
    let medium = Medium { sigma_t: m.sigma_t, albedo: m.albedo, g: m.g, emission: m.emission };
    let blend = StorageBlend::new(&storage);
    let lookup = |omega: DVec3| blend.weights(omega);
    // The suns' exact single scattering, when the source was kept without their first scattering
    // (a caller without their fields renders the source alone: the contract is the caller's).
    debug_assert_eq!(
        data.single_scattering.as_ref().map_or(0, |s| s.travel.len() + s.points.len()),
        factors.direct.len()
    );
    let single = data.single_scattering.as_ref().map(|s| {
        let beams: Vec<DirectBeam> = s
            .travel
            .iter()
            .zip(factors.direct)
            .map(|(t, field)| DirectBeam {
                travel: DVec3::from_array(*t).normalize(),
                irradiance: field,
                at_centres: s.irradiance_at_centres,
            })
            .collect();
        let true_medium =
            Medium { sigma_t: s.medium.sigma_t, albedo: s.medium.albedo, g: s.medium.g, emission: [0.0; 3] };
        // δ-M's peak share depends on g alone: any channel that scatters gives it.
        let f =
            (0..3).map(|ch| peak_share(s.medium.sigma_t[ch], s.medium.albedo[ch], m.sigma_t[ch])).fold(0.0, f64::max);
        // Under δ-M: the sideways spread of the light the peak keeps in each sun's beam.
        let cones = if s.peak_chains {
            beams
                .iter()
                .map(|b| super::cone::sun_cone(store, factors.albedo, b, &true_medium, f, data.channels))
                .collect()
        } else {
            beams.iter().map(|_| None).collect()
        };
        // Only under δ-M: the lobes' amounts come from the scaled irradiance's peak depth.
        let lobes = if s.peak_chains {
            let travels: Vec<DVec3> = beams.iter().map(|b| b.travel).collect();
            ForwardLobes::for_suns(&propagation, &storage, s.medium.g, m.g, f, &travels)
        } else {
            Vec::new()
        };
        let points = s
            .points
            .iter()
            .zip(factors.direct.iter().skip(s.travel.len()))
            .map(|(p, field)| PointSource { position: DVec3::from_array(*p), irradiance: field })
            .collect();
        SingleScattering { beams, points, medium: true_medium, peak_chains: s.peak_chains, lobes, cones }
    });
    render(&RenderInputs {
        store,
        source,
        emission: factors.emission,
        albedo: factors.albedo,
        channels: data.channels,
        storage_dirs: storage.len() as u32,
        storage_lookup: &lookup,
        medium: &medium,
        single: single.as_ref(),
        background: match background {
            Background::Sky => data.sky,
            Background::Transparent => [0.0; 3],
        },
        environment: match background {
            Background::Sky => environment,
            Background::Transparent => None,
        },
        camera,
    })
}

/// Changes to the kept view asked for on `lpm render`'s command line (world coordinates).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ViewChange {
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub eye: Option<[f64; 3]>,
    pub target: Option<[f64; 3]>,
    pub up: Option<[f64; 3]>,
    pub fov_y: Option<f64>,
}

impl ViewChange {
    pub fn is_empty(&self) -> bool {
        *self == ViewChange::default()
    }
}

/// The camera `lpm render` renders with, in the volume's frame: the solve's own camera, or the one
/// a camera file describes (`[camera]` keys, completed as a scene's are: see
/// [`crate::scene::camera_from_keys`]), with `change` applied on top. A width or height given alone
/// keeps the view's aspect ratio. With no file and no change, the solve's camera exactly (so the
/// image is bitwise the solve's).
pub fn view_camera(kept: &Kept, file: Option<&Path>, change: &ViewChange) -> Result<Camera, SceneError> {
    let d = &kept.data;
    let frame = VolumeFrame { dims: d.dims, voxel_size: d.voxel_size, origin: DVec3::from_array(d.origin) };
    let base = match file {
        Some(path) => camera_from_keys(read_camera_keys(path)?, path, &frame)?,
        None => kept.camera.clone(),
    };
    if change.is_empty() {
        return Ok(base);
    }
    let (fov_y, view_height) = match base.projection {
        Projection::Pinhole { fov_y_degrees } => (Some(fov_y_degrees), None),
        Projection::Orthographic { height } => (None, Some(height)),
    };
    let aspect = base.width as f64 / base.height as f64;
    let keep = |v: f64| (v.round().max(1.0)) as i64;
    let (width, height) = match (change.width, change.height) {
        (Some(w), Some(h)) => (i64::from(w), i64::from(h)),
        (Some(w), None) => (i64::from(w), keep(w as f64 / aspect)),
        (None, Some(h)) => (keep(h as f64 * aspect), i64::from(h)),
        (None, None) => (i64::from(base.width), i64::from(base.height)),
    };
    let keys = CameraKeys {
        projection: Some(if fov_y.is_some() { "pinhole" } else { "orthographic" }.to_string()),
        fov_y: change.fov_y.or(fov_y),
        view_height,
        position: Some(change.eye.unwrap_or((base.position + frame.origin).to_array())),
        look_at: Some(change.target.unwrap_or((base.look_at + frame.origin).to_array())),
        up: Some(change.up.unwrap_or(base.up.to_array())),
        width: Some(width),
        height: Some(height),
        exposure: None,
        view: None,
    };
    camera_from_keys(keys, Path::new("the command line"), &frame)
}

/// Changes to the kept exposure and view transform asked for on `lpm render`'s command line.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DisplayChange {
    pub exposure: Option<Exposure>,
    pub view: Option<View>,
}

impl DisplayChange {
    /// `display` with what this changes.
    pub fn apply(&self, display: Display) -> Display {
        Display { view: self.view.unwrap_or(display.view), exposure: self.exposure.unwrap_or(display.exposure) }
    }
}

/// The exposure and view transform `lpm render` maps its PNG with: the solve's own, then the
/// camera file's `exposure` and `view` where it has them, then `change`.
pub fn view_display(kept: &Kept, file: Option<&Path>, change: &DisplayChange) -> Result<Display, SceneError> {
    let mut display = kept.display;
    if let Some(path) = file {
        let keys = read_camera_keys(path)?;
        let given = display_from_keys(&keys, path)?;
        if keys.exposure.is_some() {
            display.exposure = given.exposure;
        }
        if keys.view.is_some() {
            display.view = given.view;
        }
    }
    Ok(change.apply(display))
}

/// A camera file: a `[camera]` table, or the same keys at the top level.
fn read_camera_keys(path: &Path) -> Result<CameraKeys, SceneError> {
    // Capped and through the input checks: `--camera /dev/zero` or a FIFO is refused, not read
    // until memory runs out or waited on forever.
    let text =
        crate::input::read_text_capped(path, crate::input::MAX_TEXT_BYTES, "a camera file").map_err(|e| match e {
            crate::input::InputError::Io { source, .. } => SceneError::Read { path: path.to_path_buf(), source },
            e => SceneError::BadFile { path: path.to_path_buf(), problem: e.words() },
        })?;
    let parse =
        |message: String| SceneError::Parse { path: path.to_path_buf(), line: None, column: None, key: None, message };
    let table: toml::Table = toml::from_str(&text).map_err(|e| parse(e.message().to_string()))?;
    let keys = match table.get("camera") {
        Some(toml::Value::Table(t)) if table.len() == 1 => t.clone(),
        _ => table,
    };
    keys.try_into().map_err(|e: toml::de::Error| parse(format!("camera: {}", e.message())))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `render.json` of a solve from before the view could be chosen has no `display`: it reads as
    /// `standard` at EV 0, the mapping that solve's PNG was written with (so `lpm render` of it
    /// still gives that PNG); a new one round-trips, "auto" included; a bad one is an error naming
    /// the key.
    #[test]
    fn display_in_render_json_old_new_and_bad() {
        let camera = crate::scene::default_camera([4, 4, 4], 1.0);
        let medium = Medium { sigma_t: [1.0; 3], albedo: [0.5; 3], g: 0.0, emission: [0.0; 3] };
        let set = PropagationSet::new(2);
        let storage = StorageSet::isotropic(&set);
        let auto = Display { view: View::Filmic, exposure: Exposure::Auto };
        let data = RenderData::new([4, 4, 4], 1.0, DVec3::ZERO, 1, &set, &storage, &medium, &[], &camera, &auto);
        let mut json = serde_json::to_value(&data).expect("json");
        assert_eq!(json["display"], serde_json::json!({"view": "filmic", "exposure": "auto"}));
        let path = Path::new("render.json");
        let back: RenderData = serde_json::from_value(json.clone()).expect("read back");
        assert_eq!(back.display.display(path).expect("display"), auto);
        json.as_object_mut().expect("object").remove("display");
        let old: RenderData = serde_json::from_value(json.clone()).expect("old render.json");
        assert_eq!(
            old.display.display(path).expect("display"),
            Display { view: View::Standard, exposure: Exposure::Ev(0.0) }
        );
        json["display"] = serde_json::json!({"view": "aces", "exposure": 0.0});
        let bad: RenderData = serde_json::from_value(json).expect("parses");
        assert!(bad.display.display(path).unwrap_err().to_string().contains("display.view"));
    }
}
