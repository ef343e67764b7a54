//! The typed scene: what `Scene::load` produces after validation. Every value here has been checked
//! (finite, in range), so the solver never re-validates.

pub use super::environment::{EnvironmentLight, EnvironmentMap, MapUp};
use glam::DVec3;
use std::path::PathBuf;

/// A whole job description: the medium volume, its optical properties, the lights, the solver
/// settings and an optional camera.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// The file the scene was read from (used in messages and to resolve relative paths).
    pub path: PathBuf,
    pub volume: Volume,
    pub medium: Medium,
    pub lights: Vec<Light>,
    pub solver: SolverSettings,
    /// `None`: the renderer picks a default view of the whole volume.
    pub camera: Option<Camera>,
    /// How light crosses the volume's faces.
    pub boundary: Boundary,
    /// How the PNG preview turns radiance into display values (`[camera]`'s `exposure` and
    /// `view`); the EXR is linear whatever it says.
    pub display: Display,
}

/// How an image's linear radiance becomes the 8-bit display values of its PNG preview: scaled by
/// the exposure, then through the view transform (see `render::tone`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Display {
    pub view: View,
    pub exposure: Exposure,
}

/// The view transform (tone curve) of the PNG preview.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum View {
    /// Reinhard's `x / (1 + x)` per channel, then sRGB: the mapping of lpm before the choice
    /// existed (flat: mid tones sit high and the contrast between lit and shaded sides is small).
    Standard,
    /// A film-like curve per channel: a log2 encoding of 16.5 stops around mid grey through an
    /// S-shaped contrast curve. Highlights roll off into white instead of clipping; saturated
    /// highlights skew in hue (toward the primaries' yellows and cyans) as each channel saturates.
    Filmic,
    /// The same curve applied in AgX's inset space (Troy Sobotka's AgX, as in Blender 4): bright
    /// saturated light desaturates toward white as film and eyes do, instead of skewing in hue.
    #[default]
    Agx,
}

/// `View` names as written in scenes and on the command line.
pub const VIEW_NAMES: &str = "\"standard\", \"filmic\", \"agx\"";

impl View {
    pub fn name(self) -> &'static str {
        match self {
            View::Standard => "standard",
            View::Filmic => "filmic",
            View::Agx => "agx",
        }
    }
    /// The view named `name` (see [`VIEW_NAMES`]), if any.
    pub fn from_name(name: &str) -> Option<View> {
        [View::Standard, View::Filmic, View::Agx].into_iter().find(|v| v.name() == name)
    }
}

/// Largest |exposure| in stops (EV): 2^±32 spans any radiance an f32 image holds.
pub const MAX_EXPOSURE_EV: f64 = 32.0;

/// How bright the preview is exposed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Exposure {
    /// Radiance × 2^EV (0: as is).
    Ev(f64),
    /// From the image itself: the exposure that puts the log-average luminance of the medium (the
    /// pixels weighted by their alpha) at mid grey, 0.18 (see `render::tone::auto_exposure`).
    Auto,
}

impl Default for Exposure {
    fn default() -> Self {
        Exposure::Ev(0.0)
    }
}

impl std::str::FromStr for Exposure {
    type Err = String;
    /// `"auto"` or a number of stops in ±[`MAX_EXPOSURE_EV`].
    fn from_str(s: &str) -> Result<Self, String> {
        if s.trim() == "auto" {
            return Ok(Exposure::Auto);
        }
        let ev: f64 =
            s.trim().parse().map_err(|_| format!("expected a number of stops (EV) or \"auto\", got {s:?}"))?;
        Exposure::ev(ev)
    }
}

impl Exposure {
    /// `Ev(ev)` when `ev` is finite and within ±[`MAX_EXPOSURE_EV`].
    pub fn ev(ev: f64) -> Result<Exposure, String> {
        if ev.is_finite() && ev.abs() <= MAX_EXPOSURE_EV {
            Ok(Exposure::Ev(ev))
        } else {
            Err(format!("must be a finite number of stops (EV) in [-{MAX_EXPOSURE_EV}, {MAX_EXPOSURE_EV}], got {ev}"))
        }
    }
    /// `"auto"` or the number of stops, as written in scenes.
    pub fn describe(self) -> String {
        match self {
            Exposure::Auto => "auto".to_string(),
            Exposure::Ev(ev) => format!("{ev}"),
        }
    }
}

/// How light crosses the faces of the volume, per axis (x, y, z): `open` (the default: the lights
/// enter, what leaves is gone), `periodic` (the volume repeats along the axis: what leaves
/// through one face enters through the opposite one, as in a cloud field tiled without end; see
/// `solver::periodic`) or `reflective` per face (a mirror: what reaches the face comes back with
/// its direction mirrored, as across a symmetry plane; see `solver::mirror`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Boundary {
    pub periodic: [bool; 3],
    /// Per axis, whether its low face (coordinate 0) and its high face are mirrors.
    pub reflective: [[bool; 2]; 3],
}

impl Boundary {
    /// Whether any axis is periodic.
    pub fn any_periodic(&self) -> bool {
        self.periodic.iter().any(|&p| p)
    }

    /// Whether any face is a mirror.
    pub fn any_reflective(&self) -> bool {
        self.reflective.iter().flatten().any(|&r| r)
    }

    /// Whether outside light enters through the face of `axis` (0 x, 1 y, 2 z) at its low or
    /// `high` side: the face is neither periodic nor a mirror.
    pub fn is_open(&self, axis: usize, high: bool) -> bool {
        !self.periodic[axis] && !self.reflective[axis][high as usize]
    }

    /// Whether every face is open.
    pub fn all_open(&self) -> bool {
        !self.any_periodic() && !self.any_reflective()
    }

    /// The scene file's words for an axis: "open", "periodic", "reflective" (both faces),
    /// "reflective low" or "reflective high".
    pub fn axis_name(&self, axis: usize) -> &'static str {
        match (self.periodic[axis], self.reflective[axis]) {
            (true, _) => "periodic",
            (_, [true, true]) => "reflective",
            (_, [true, false]) => "reflective low",
            (_, [false, true]) => "reflective high",
            _ => "open",
        }
    }
}

/// The density grid: dims in voxels, the voxel edge in world units, and where densities come from.
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    pub source: VolumeSource,
    /// Voxels along x, y, z; each in 1..=65536 and the product below 2^40.
    pub dims: [u32; 3],
    /// World units per voxel edge (> 0).
    pub voxel_size: f64,
    /// World position of the volume's low corner: voxel (i, j, k) spans
    /// `origin + [i, j, k]·voxel_size` to `origin + [i+1, j+1, k+1]·voxel_size`. The solver works in
    /// the volume's own frame (corner at 0); only the camera is placed in the world, and the
    /// validator moves it into the volume's frame (see [`Camera`]).
    pub origin: DVec3,
    /// Per-voxel emission `e(v)` (≥ 0): the medium's emitted radiance in voxel v is
    /// `Le(v) = e(v)·medium.emission` (the colour, 1 when not given), its source `σa(v)·Le(v)`;
    /// from a temperature grid `e(v)` has a value per channel, the blackbody's (see
    /// [`super::blackbody`]). `None`: the medium emits `medium.emission` uniformly (where it
    /// absorbs).
    pub emission: Option<EmissionGrid>,
    /// Per-voxel albedo factor `a(v)` in [0, 1]: the single-scattering albedo of voxel v in
    /// channel c is `medium.albedo[c]·a(v)` (so σs(v) = ρσt·albedo·a(v), σa(v) = ρσt·(1 −
    /// albedo·a(v))). `None`: `medium.albedo` everywhere.
    pub albedo: Option<AlbedoGrid>,
}

/// Where a per-voxel albedo factor comes from (`volume.albedo_raw` / `albedo_grid`).
#[derive(Clone, Debug, PartialEq)]
pub enum AlbedoGrid {
    /// Little-endian f32, x fastest, the volume's dims; an absolute path.
    Raw { path: PathBuf },
    /// Grid `grid` of the volume's OpenVDB file, read over the density's voxels (voxels its tree
    /// does not cover read its background value).
    Vdb { grid: String },
}

impl AlbedoGrid {
    /// The raw file the values come from, if any.
    pub fn raw_path(&self) -> Option<&std::path::Path> {
        match self {
            AlbedoGrid::Raw { path } => Some(path),
            AlbedoGrid::Vdb { .. } => None,
        }
    }

    /// The grid of the volume's VDB file the values come from, if any.
    pub fn vdb_grid(&self) -> Option<&str> {
        match self {
            AlbedoGrid::Vdb { grid } => Some(grid),
            AlbedoGrid::Raw { .. } => None,
        }
    }

    /// Where the values come from, for messages: the scene key or the VDB grid.
    pub fn label(&self) -> String {
        match self {
            AlbedoGrid::Vdb { grid } => format!("grid \"{grid}\""),
            AlbedoGrid::Raw { .. } => "volume.albedo_raw".into(),
        }
    }
}

/// Where a per-voxel emission comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum EmissionGrid {
    /// Little-endian f32, x fastest, the volume's dims; an absolute path.
    Raw { path: PathBuf },
    /// Grid `grid` of the volume's OpenVDB file, read over the density's voxels (its own active
    /// bounding box may be smaller: voxels outside it are 0).
    Vdb { grid: String },
    /// A temperature (`volume.temperature_raw`), read as [`EmissionGrid::Raw`], mapped to
    /// blackbody radiance per channel.
    TemperatureRaw { path: PathBuf, blackbody: Blackbody },
    /// A temperature grid of the volume's OpenVDB file (`volume.temperature_grid`), read as
    /// [`EmissionGrid::Vdb`], mapped to blackbody radiance per channel.
    TemperatureVdb { grid: String, blackbody: Blackbody },
}

/// How a temperature grid's values become blackbody emission (`[medium] temperature_*`; see
/// [`super::blackbody`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Blackbody {
    /// Kelvin per unit of the grid (`temperature_scale`, > 0; 1: the grid holds kelvin).
    pub scale: f64,
    /// The temperature (K) whose radiance has luminance `medium.emission` (`temperature_reference`).
    pub reference: f64,
    /// Voxels colder than this (K) emit nothing (`temperature_cutoff`, ≥ 0).
    pub cutoff: f64,
}

impl EmissionGrid {
    /// The raw file the values come from, if any.
    pub fn raw_path(&self) -> Option<&std::path::Path> {
        match self {
            EmissionGrid::Raw { path } | EmissionGrid::TemperatureRaw { path, .. } => Some(path),
            EmissionGrid::Vdb { .. } | EmissionGrid::TemperatureVdb { .. } => None,
        }
    }

    /// The grid of the volume's VDB file the values come from, if any.
    pub fn vdb_grid(&self) -> Option<&str> {
        match self {
            EmissionGrid::Vdb { grid } | EmissionGrid::TemperatureVdb { grid, .. } => Some(grid),
            EmissionGrid::Raw { .. } | EmissionGrid::TemperatureRaw { .. } => None,
        }
    }

    /// The temperature mapping, when the grid holds temperatures.
    pub fn blackbody(&self) -> Option<&Blackbody> {
        match self {
            EmissionGrid::TemperatureRaw { blackbody, .. } | EmissionGrid::TemperatureVdb { blackbody, .. } => {
                Some(blackbody)
            }
            EmissionGrid::Raw { .. } | EmissionGrid::Vdb { .. } => None,
        }
    }

    /// Emission factors per voxel: 1 (a grey factor scaling `medium.emission`) or 3 (r, g, b: a
    /// temperature's blackbody colour).
    pub fn components(&self) -> u32 {
        if self.blackbody().is_some() {
            3
        } else {
            1
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub enum VolumeSource {
    Procedural {
        shape: Shape,
        seed: u64,
    },
    /// Little-endian f32, x fastest, then y, then z; an absolute path (resolved against the scene file).
    Raw {
        path: PathBuf,
    },
    /// Grid `grid` of an OpenVDB file (an absolute path). `index_min` is the index coordinate of
    /// the volume's voxel (0, 0, 0): the low corner of the grid's active bounding box.
    Vdb {
        path: PathBuf,
        grid: String,
        index_min: [i32; 3],
    },
    /// An NRRD file (`.nhdr` or `.nrrd`, an absolute path): its samples, x fastest, as f32.
    Nrrd {
        path: PathBuf,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// Density 1 inside a ball of radius 0.4·min(dims) voxels centred in the volume, 0 outside.
    Sphere,
    /// Density 1 everywhere.
    Box,
    /// Seeded fBm noise cloud, density in [0, 1], mostly empty near the border.
    Cloud,
}

/// Optical properties at density 1 (scaled linearly by the voxel density).
#[derive(Clone, Debug, PartialEq)]
pub struct Medium {
    /// Extinction per world unit at density 1, per channel (≥ 0).
    pub sigma_t: [f64; 3],
    /// Single-scattering albedo per channel, in [0, 1].
    pub albedo: [f64; 3],
    /// Henyey–Greenstein anisotropy, in (−1, 1).
    pub g: f64,
    /// Emitted radiance Le per channel (≥ 0); the source term is σa·Le.
    pub emission: [f64; 3],
}

#[derive(Clone, Debug, PartialEq)]
pub enum Light {
    /// Uniform radiance arriving from every direction outside the volume.
    Sky { radiance: [f64; 3] },
    /// Directional light. `direction` is unit length and points toward the sun; `irradiance` is
    /// measured on a plane perpendicular to the beam.
    Sun { direction: DVec3, irradiance: [f64; 3] },
    /// A lat-long environment map: the radiance arriving from each direction outside the volume
    /// (see [`super::environment`] for its orientation). At most one per scene.
    Environment(EnvironmentLight),
    /// An isotropic point light (`kind = "point"`). `position` is in the volume's frame (corner
    /// at 0, world units): the scene file gives a world position and the validator subtracts
    /// `volume.origin`, as for the camera. It may lie inside or outside the volume. `intensity` is
    /// the radiant intensity in W/sr per channel (the light emits 4π·intensity in all).
    Point { position: DVec3, intensity: [f64; 3] },
}

#[derive(Clone, Debug, PartialEq)]
pub struct SolverSettings {
    /// k: k×k propagation directions per cube face (6k² in all), 1..=32.
    pub directions_per_face: u32,
    /// Storage directions per face for anisotropic media (k_s×k_s per face, k_s ≤ k). `None`: the
    /// plan chooses (1 storage direction in all when the medium is isotropic).
    pub storage_directions_per_face: Option<u32>,
    /// k_sky ≥ k: the sky's light is swept into the medium along k_sky×k_sky directions per face
    /// in order 0 (its uncollided light and first scattering), the scattered light along the k×k
    /// (`solver.sky_directions_per_face`; see `solver::plan`, "The sky's own directions"); k
    /// itself: the sky travels with the other light. `None`: the plan chooses (4k, at most 32, for
    /// a pure absorber on the linear lattice, else k).
    pub sky_directions_per_face: Option<u32>,
    /// k_1, a multiple of k: where the emission is traced and the medium scatters, orders 1 and 2
    /// sweep the light the emission scatters first and second along k_1×k_1 directions per face of
    /// their own (`solver.scattered_directions_per_face`; see `solver::plan`, "The scattered
    /// light's own directions"); k itself: along the k×k. `None`: the plan chooses (the smallest
    /// multiple of k from 12 on, when k < 12).
    pub scattered_directions_per_face: Option<u32>,
    /// Cap on the number of scattering orders propagated (≥ 1).
    pub max_orders: u32,
    /// Stop when the newest order's scattered power is below this fraction of the total (in (0, 1)).
    pub tolerance: f64,
    /// Device memory budget in bytes; `None`: a safe fraction of the device's heap.
    pub device_memory_budget: Option<u64>,
    /// Host memory the store may keep resident between passes, in bytes; `None`: half of what the
    /// system reports available ([`crate::store::resident`]).
    pub host_memory_budget: Option<u64>,
    /// Estimate the orders not propagated as a geometric series and add them (for high albedo),
    /// stopping once that estimate is within the tolerance.
    pub extrapolate_tail: bool,
    /// Precision of the source the rays gain, as stored on the device (`solver.storage_precision`).
    pub storage_precision: StoragePrecision,
    /// Whether the plan may reduce what it models to what the scene needs (`solver.plan`).
    pub plan: PlanMode,
    /// How a ray samples the voxels around it (`solver.spatial`). `None` ("auto"): the plan
    /// chooses ("linear" for a pure absorber with open faces, else "constant").
    pub spatial: Option<SpatialScheme>,
    /// What to do with a strong forward peak of the phase function (`solver.forward_peak`).
    pub forward_peak: ForwardPeak,
    /// How an emission's uncollided light reaches the volume (`solver.emission_uncollided`).
    pub emission_uncollided: EmissionUncollided,
    /// Whether the lattice's numerical diffusion is taken back out of each order's scattered
    /// source (`solver.diffusion_correction`, see `solver::antidiffusion`).
    pub diffusion_correction: DiffusionCorrection,
    /// Whether the order series is accelerated by a diffusion correction (`solver.acceleration`,
    /// see `solver::acceleration`).
    pub acceleration: Acceleration,
    /// The most cells the acceleration's diffusion grid may have (`solver.diffusion_cells`; the
    /// cells grow by powers of two until the grid fits). `None`: `solver::acceleration::MAX_CELLS`.
    pub diffusion_cells: Option<u32>,
    /// When the GPU backend checkpoints (`solver.checkpoint_every_orders`, `…_seconds`).
    pub checkpoint: CheckpointCadence,
    /// Whether the GPU backend may keep the medium and fields on the device for the whole solve
    /// (`solver.device_residency`).
    pub device_residency: DeviceResidency,
}

/// `solver.device_residency`: `auto` (the default) keeps every occupied brick's medium and fields on
/// the device when they fit the memory budget, so that only the fields cross the bus, once per
/// order; `streamed` streams every pass slice by slice (as a volume larger than the budget is).
/// The result is bitwise the same either way.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DeviceResidency {
    #[default]
    Auto,
    Streamed,
}

/// `solver.acceleration`: at high albedo in a thick medium the orders shrink slowly (by about the
/// albedo each), because light diffuses through many mean free paths. `diffusion` estimates that
/// slow part from a diffusion equation after every order and adds it at once (diffusion synthetic
/// acceleration); the converged answer is the transport one either way. `auto` (the default) lets
/// the plan turn it on where it pays (see `solver::plan`), `off` never.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Acceleration {
    #[default]
    Auto,
    Diffusion,
    Off,
}

/// When a solve writes a checkpoint (the order loop schedules them, `solver::orders`; the GPU
/// backend keeps them): after an order when `every_orders` orders have passed
/// since the last one, or `every_seconds`, whichever comes first; and always after the last order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CheckpointCadence {
    pub every_orders: Option<u32>,
    pub every_seconds: f64,
}

impl Default for CheckpointCadence {
    /// Every five minutes: a killed solve loses at most that much, and a store that takes seconds
    /// to flush is flushed rarely.
    fn default() -> Self {
        CheckpointCadence { every_orders: None, every_seconds: 300.0 }
    }
}

impl CheckpointCadence {
    /// Whether to checkpoint now, `orders` orders and `seconds` after the last checkpoint (or the
    /// start), `last` when the solve ends with this order.
    pub fn due(&self, orders: u32, seconds: f64, last: bool) -> bool {
        last || self.every_orders.is_some_and(|n| orders >= n) || seconds >= self.every_seconds
    }
}

/// `solver.diffusion_correction`: every order, the discretisation spreads the scattered light a
/// little: the rays meet the voxels at a lateral offset from their true positions, and each ray
/// segment takes its voxel's source as one constant and deposits its average. In thick,
/// high-albedo media these spreads add up like a diffusion and light reaches dense cores too
/// easily (+6 % in a cloud's core at 0.8 mean free paths per voxel, +10 % at 1). `on` (the
/// default) takes the spread the direction set is known to add back out of the scattered source
/// with conservative anti-diffusive fluxes between voxels two apart (when the medium scatters;
/// each capped so that no voxel gives more than it has, and thinned out in optically thick
/// voxels, where they would destabilise the series): the core comes within 0.6 % of Monte Carlo
/// (benches/RESULTS.md, "Diffusion correction"). `off` solves the plain scheme.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum DiffusionCorrection {
    #[default]
    On,
    Off,
}

impl DiffusionCorrection {
    /// The scene file's spelling: "on" or "off".
    pub fn name(self) -> &'static str {
        match self {
            DiffusionCorrection::On => "on",
            DiffusionCorrection::Off => "off",
        }
    }
}

/// `solver.emission_uncollided`: how an emission's uncollided light reaches the volume (see
/// `solver::uncollided`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum EmissionUncollided {
    /// Traced when the emission is compact and its light leaves its voxels, else swept.
    #[default]
    Auto,
    /// Traced from every emitting voxel to every voxel (a first-collision source).
    Traced,
    /// Swept along the propagation directions as an order-0 source.
    Swept,
}

impl EmissionUncollided {
    /// The scene file's spelling.
    pub fn name(self) -> &'static str {
        match self {
            EmissionUncollided::Auto => "auto",
            EmissionUncollided::Traced => "traced",
            EmissionUncollided::Swept => "swept",
        }
    }
}

/// `solver.forward_peak`: how a phase function with a strong forward peak is modelled. A few storage
/// directions per face cannot hold a peak of width ~(1 − g): the discrete phase function comes out
/// too wide (g = 0.8 behaves like ~0.7), which sends light sideways that should go on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ForwardPeak {
    /// δ-M scaling when g ≥ 0.5, else keep.
    #[default]
    Auto,
    /// δ-M scaling: a fraction f of the scattering, from the forward peak, is treated as not
    /// scattered at all (σs' = (1 − f)·σs, σt' = σt − f·σs); the rest keeps HG(g)'s shape outside a
    /// forward cone ([`crate::quadrature::phase::Truncation`]).
    DeltaM,
    /// Scatter with the Henyey–Greenstein phase function as it is.
    Keep,
}

impl ForwardPeak {
    /// The scene file's spelling: "auto", "delta-m" or "keep".
    pub fn name(self) -> &'static str {
        match self {
            ForwardPeak::Auto => "auto",
            ForwardPeak::DeltaM => "delta-m",
            ForwardPeak::Keep => "keep",
        }
    }
}

/// `solver.spatial`: how a ray meets the voxel grid in each plane it crosses (see
/// `solver::sweep`). Both schemes are exact in energy and bitwise reproducible.
///
/// Measured (benches/RESULTS.md, "Spatial schemes"): "linear" halves the error next to the faces
/// of a thin medium (light entering through a side), but its bilinear gather and deposit smooth
/// the source sideways twice per order, which in thick, high-albedo media acts as extra diffusion
/// and brightens dense cores (+9 % against +5 % for "constant" in a 64³ cloud at σt·h = 0.8,
/// albedo 0.9). So "constant" is the plan's choice for scattering media (where the diffusion
/// correction takes its smoothing back out) and emitting ones, "linear" for a pure absorber (order
/// 0 is the whole answer and the entry through a side is what matters). `SolverSettings::spatial =
/// None` lets the plan choose; `Default` is what it chooses for a scattering medium.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SpatialScheme {
    /// The ray sits at its exact lateral position: it gathers the medium and the source bilinearly
    /// from the two-by-two voxels it lies between and deposits with the same weights; a ray
    /// entering through a side face enters continuously where it crosses it.
    Linear,
    /// The ray takes the medium and source of the one voxel under its mid-plane position (nearest
    /// column), and a ray entering through a side starts in the plane it wraps in.
    #[default]
    Constant,
}

impl SpatialScheme {
    /// The scene file's spelling: "linear" or "constant".
    pub fn name(self) -> &'static str {
        match self {
            SpatialScheme::Linear => "linear",
            SpatialScheme::Constant => "constant",
        }
    }
}

/// `solver.plan`: whether the plan models only what the scene needs, or everything. `Full` exists
/// to measure what the reductions save and to show they cost no accuracy (`lpm bench accuracy
/// --plans auto,full`); a solve has no other reason to use it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PlanMode {
    /// 1 channel for a grey scene, 1 storage direction for an isotropic medium, f16 storage of the
    /// gained source when the tolerance allows (`storage_precision = "auto"`).
    #[default]
    Auto,
    /// None of those reductions: 3 channels, k_s×k_s storage directions per face, and f32 storage
    /// unless `storage_precision` names f16. Empty bricks are still skipped (that is exact).
    Full,
}

impl PlanMode {
    /// The scene file's spelling: "auto" or "full".
    pub fn name(self) -> &'static str {
        match self {
            PlanMode::Auto => "auto",
            PlanMode::Full => "full",
        }
    }
}

/// `solver.storage_precision`: how the previous order's source (the one the rays gain) is stored
/// on the device. Accumulators and the brick store stay f32 whatever the choice.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum StoragePrecision {
    /// The plan decides from the tolerance (f16 when f16's rounding is well below it).
    #[default]
    Auto,
    F16,
    F32,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub projection: Projection,
    /// Position of the eye (pinhole) or of the image centre (orthographic), in the volume's frame:
    /// the scene file gives world positions, and the validator subtracts `volume.origin` from
    /// `position` and `look_at`.
    pub position: DVec3,
    pub look_at: DVec3,
    pub up: DVec3,
    /// Image size in pixels (1..=16384 each).
    pub width: u32,
    pub height: u32,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Vertical field of view in degrees, in (0, 180).
    Pinhole { fov_y_degrees: f64 },
    /// Height of the view in world units (> 0).
    Orthographic { height: f64 },
}

impl Scene {
    /// True when one channel describes the scene: the medium, every light and the per-voxel
    /// emission (a temperature's blackbody colour is never grey) are the same in r, g and b.
    pub fn is_grey(&self) -> bool {
        self.medium.is_grey()
            && self.lights.iter().all(Light::is_grey)
            && self.volume.emission.as_ref().is_none_or(|e| e.components() == 1)
    }
}

impl Medium {
    /// True when every channel has the same σt, albedo and emission.
    pub fn is_grey(&self) -> bool {
        let same = |v: &[f64; 3]| v[0] == v[1] && v[1] == v[2];
        same(&self.sigma_t) && same(&self.albedo) && same(&self.emission)
    }
    pub fn has_emission(&self) -> bool {
        self.emission.iter().any(|&e| e > 0.0)
    }
}

impl Light {
    /// True when the light has the same value in every channel.
    pub fn is_grey(&self) -> bool {
        let v = match self {
            Light::Sky { radiance } => radiance,
            Light::Sun { irradiance, .. } => irradiance,
            Light::Point { intensity, .. } => intensity,
            Light::Environment(env) => return env.is_grey(),
        };
        v[0] == v[1] && v[1] == v[2]
    }
}
