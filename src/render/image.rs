//! [`Image`] and [`render`]: one ray per pixel, rows shared among threads.

use super::camera::RayGenerator;
use super::march::march_ray;
use crate::quadrature::Blend;
use crate::scene::{Camera, EnvironmentLight, Medium};
use crate::store::{BrickStore, Field};
use glam::DVec3;
use std::sync::Mutex;

/// Linear radiance, RGB per pixel, row-major, top row first, with an optional alpha.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<f32>,
    /// Per pixel, 1 − the transmittance along the camera ray (the mean of the three channels'):
    /// 0 where the ray meets no medium, → 1 where the volume is opaque. `None`: no alpha channel
    /// (an image that is opaque by construction, e.g. the Monte-Carlo reference's).
    pub alpha: Option<Vec<f32>>,
}

/// What a camera ray that leaves the volume sees (`--background`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Background {
    /// The scene's sky radiance and environment map, baked into the colour (alpha still says how opaque the medium is).
    #[default]
    Sky,
    /// Nothing: the colour is the medium's own light only, which is premultiplied by alpha (the
    /// volume composites over any background B as colour + (1 − alpha)·B).
    Transparent,
}

impl Image {
    /// RGB of pixel (x, y), y = 0 the top row.
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 3] {
        let i = 3 * (y as usize * self.width as usize + x as usize);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }
}

/// The per-voxel factors a solved volume may have besides its density: the emission factor and
/// the albedo factor (the store's `emission` and `albedo` fields), and the suns' uncollided
/// irradiance per voxel (one field per sun of [`crate::render::keep::RenderData::single_scattering`], in its
/// order; empty where the image's source still holds the suns' first scattering).
#[derive(Clone, Copy, Default)]
pub struct VoxelFactors<'a> {
    pub emission: Option<&'a Field>,
    pub albedo: Option<&'a Field>,
    pub direct: &'a [Field],
}

/// One sun's light as the renderer scatters it exactly (see [`SingleScattering`]).
#[derive(Clone, Copy)]
pub struct DirectBeam<'a> {
    /// The direction the sun's light travels (unit length).
    pub travel: DVec3,
    /// Its uncollided irradiance per voxel, attenuated by the true extinction (occupied bricks,
    /// `channels` components), followed by the δ-M scaled one when
    /// [`SingleScattering::peak_chains`].
    pub irradiance: &'a Field,
    /// `irradiance` holds the values at the voxels' centres (every voxel of an occupied brick),
    /// interpolated in optical depth; otherwise averages over each voxel, 0 where ρ = 0,
    /// interpolated as ρ·E (render data of format 3, or the sweep's irradiance).
    pub at_centres: bool,
}

/// One point light as the renderer scatters it exactly (see [`SingleScattering`]).
#[derive(Clone, Copy)]
pub struct PointSource<'a> {
    /// Its position, in voxel units (the volume's corner at 0).
    pub position: DVec3,
    /// Its irradiance per voxel as the beam's ([`DirectBeam::irradiance`]).
    pub irradiance: &'a Field,
}

/// The suns' and point lights' single scattering, evaluated exactly along each camera ray
/// (`σs(x)·p_HG(g; ω_sun·ω_camera)·E(x)`, attenuated towards the camera by the true extinction),
/// the source the image reads then holding everything else ([`crate::solver::direct`]).
pub struct SingleScattering<'a> {
    pub beams: Vec<DirectBeam<'a>>,
    /// The point lights, whose light arrives at x from `x − position`.
    pub points: Vec<PointSource<'a>>,
    /// The scene's medium, not δ-M scaled: its σt, albedo and Henyey–Greenstein g.
    pub medium: Medium,
    /// The fields hold the δ-M scaled irradiance too: the light the truncated peak kept in the
    /// beam is scattered towards the camera as well ([`super::peak`]).
    pub peak_chains: bool,
    /// Per beam, its forward lobes and what the solve's storage cells hold of them: the light it
    /// scatters twice or more, sharpened where the lobe exceeds the cells
    /// ([`super::peak::ForwardLobes`]).
    pub lobes: Vec<super::peak::ForwardLobes>,
    /// Per beam under δ-M, its forward light on a cone of directions ([`super::cone`]): how far
    /// the real geometry moves the chains' and lobes' light sideways, added to them (`None`: no
    /// cone for this sun, the chains and lobes alone).
    pub cones: Vec<Option<super::cone::ForwardCone>>,
}

/// Everything a render reads.
pub struct RenderInputs<'a> {
    pub store: &'a BrickStore,
    /// In-scattered source J summed over orders; `Coverage::Occupied`; component
    /// `d·channels + ch` for storage direction d and channel ch.
    pub source: &'a Field,
    /// The per-voxel emission factor e(v) (occupied bricks; one grey component, or r, g, b from a
    /// temperature grid): the medium emits `e(v)·medium.emission`; `None`: it emits
    /// `medium.emission` everywhere.
    pub emission: Option<&'a Field>,
    /// The per-voxel albedo factor a(v) (occupied bricks, one component): the medium absorbs
    /// `σt·(1 − albedo·a(v))`, which scales its emission; `None`: `medium.albedo` everywhere.
    pub albedo: Option<&'a Field>,
    /// 1 (grey: channel 0 serves r, g and b) or 3.
    pub channels: u32,
    pub storage_dirs: u32,
    /// The storage directions, and their weights, that make up the source for a direction of
    /// light travel (see [`crate::quadrature::StorageBlend`]; [`Blend::single`] for one
    /// direction).
    pub storage_lookup: &'a (dyn Fn(DVec3) -> Blend + Sync),
    pub medium: &'a Medium,
    /// The suns' and point lights' single scattering, added exactly; `None`: the source holds it
    /// (binned).
    pub single: Option<&'a SingleScattering<'a>>,
    /// Radiance seen where a ray leaves the volume (zero for [`Background::Transparent`]).
    pub background: [f64; 3],
    /// An environment map seen behind the volume, on top of `background` (`None` for
    /// [`Background::Transparent`] or a scene without one).
    pub environment: Option<&'a EnvironmentLight>,
    pub camera: &'a Camera,
}

/// Image rows rendered between two hand-backs of the volume's pages.
const RELEASE_ROWS: usize = 16;

/// Renders `inputs.camera`'s view. Rows are handed out to `available_parallelism` threads; each pixel
/// depends only on its own ray, so the image is the same whatever the thread count or timing.
pub fn render(inputs: &RenderInputs) -> Image {
    // Caller contracts (the plan builds these together); a mismatch would read zeros, not crash.
    debug_assert_eq!(inputs.source.grid(), inputs.store.grid());
    debug_assert!(inputs.source.components() >= inputs.storage_dirs * inputs.channels);
    let rays = RayGenerator::new(inputs.camera);
    let (width, height) = (inputs.camera.width.max(1), inputs.camera.height.max(1));
    let mut rgb = vec![0.0f32; width as usize * height as usize * 3];
    let mut alpha = vec![0.0f32; width as usize * height as usize];
    let rows = Mutex::new(rgb.chunks_mut(width as usize * 3).zip(alpha.chunks_mut(width as usize)).enumerate());
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get()).min(height as usize);
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| loop {
                // A poisoned lock means another worker panicked; the scope re-raises that panic.
                let next = match rows.lock() {
                    Ok(mut it) => it.next(),
                    Err(_) => return,
                };
                let Some((y, (row, alpha_row))) = next else { return };
                // SIGTERM (the `lpm` binary's flag): stop before the next row; the caller, who
                // knows its own flag, reports the cancellation and drops the unfinished image.
                if crate::solver::cancel::CancelFlag::process().is_raised() {
                    return;
                }
                if y % RELEASE_ROWS == 0 {
                    // Hand back the pages the rows so far read (resident memory stays bounded on
                    // volumes larger than RAM; see `store::Field`). Other workers refault what they use.
                    inputs.store.release_all_density();
                    inputs.source.release_all();
                }
                for (x, (px, a)) in row.chunks_mut(3).zip(alpha_row.iter_mut()).enumerate() {
                    let (origin, dir) = rays.ray(x as u32, y as u32);
                    let (l, t) = march_ray(inputs, origin, dir);
                    let map = inputs.environment.map_or([0.0; 3], |env| env.radiance(dir));
                    for ch in 0..3 {
                        px[ch] = (l[ch] + t[ch] * (inputs.background[ch] + map[ch])) as f32;
                    }
                    *a = (1.0 - (t[0] + t[1] + t[2]) / 3.0) as f32;
                }
            });
        }
    });
    Image { width, height, rgb, alpha: Some(alpha) }
}

/// Display value in [0, 1] (before sRGB encoding) of a linear radiance scaled by `exposure` (a
/// factor): Reinhard's `x / (1 + x)`, the `standard` view's curve (see [`super::tone`]). Negative
/// or NaN maps to 0.
pub fn tone_map(radiance: f32, exposure: f64) -> f64 {
    let x = radiance as f64 * exposure;
    if x.is_nan() || x <= 0.0 {
        0.0
    } else if x.is_infinite() {
        1.0
    } else {
        x / (1.0 + x)
    }
}
