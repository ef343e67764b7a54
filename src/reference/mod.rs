//! # An independent Monte-Carlo reference
//!
//! This module is the project's ground truth for accuracy figures. It solves the same transport
//! problem as [`crate::solver`] (DESIGN.md §2: voxels of constant density ρ, σt = ρ·σt₁, σs = α·σt,
//! Henyey–Greenstein scattering, emission σa·Le, a uniform sky and collimated suns outside a box of
//! vacuum, point lights inside or outside it) with an entirely different method, and shares **no transport code** with the solver: it
//! only reads the typed [`Scene`]. Directions, phase sampling, ray traversal,
//! attenuation and tallies are all written here from the textbook definitions, so a bug in the
//! discrete-ordinates solver (quadrature, sweep geometry, segment formulas, collect matrices) cannot
//! be reproduced by this code, and vice versa; where they agree, both are right to within the
//! statistical error reported here.
//!
//! ## Fluence: forward light tracing with a track-length estimator
//!
//! Photons leave the lights, with the source picked with probability ∝ its power so that every
//! photon carries the same power P/N (P = total power of the channel's sources):
//! - **sky** of radiance L: a point uniform on the box surface (face ∝ area), a cosine-weighted
//!   inward direction; the power entering the box is P = π·L·A (A the box's surface area);
//! - **environment map**: a direction toward the sky with density ∝ L (a pixel ∝ L·Ω, then uniform
//!   in its solid angle: the map is constant per pixel), then a point uniform on a disk of radius R
//!   (the box's half diagonal) facing it, outside the box, travelling away from the sky; kept only
//!   if the ray hits the box; P = π·R²·∫L dΩ. The lat-long mapping is written again in
//!   `reference/environment.rs` from its definition, not taken from the scene module;
//! - **sun** of irradiance E toward `direction`: a point uniform on a rectangle perpendicular to the
//!   beam that covers the box's projection (outside the box), travelling along −`direction`; kept only
//!   if the ray hits the box (misses still count in N); P = E·A_rect;
//! - **point light** of intensity I at q: an isotropic direction from q, moved on to where it
//!   meets the box when q lies outside (misses count in N); P = 4π·I;
//! - **emission**: a voxel with probability ∝ σa·Le·h³ (∝ ρ·e_c(v) per channel c, e the per-voxel
//!   emission factor: 1, a grey grid's value, or a temperature's blackbody factor for that
//!   channel; times 1 − albedo·a(v) with a per-voxel albedo factor, whose σa varies per voxel), a
//!   uniform point in it, an isotropic direction; P = 4π·Σ σa·Le·h³.
//!
//! Free flights are sampled by **delta (Woodcock) tracking** against a per-brick majorant grid
//! (16³-voxel bricks, majorant σ·ρ_max; bricks are crossed with a DDA, tracking restarts at each brick
//! face, bricks with majorant 0 are skipped), which samples the exact free-flight distribution of the
//! piecewise-constant medium whatever its dynamic range. A brick whose majorant exceeds 2 per voxel
//! while it is heterogeneous (max > 2·min) — say one voxel of τ = 10⁴ among thin ones, where delta
//! tracking would take ~10⁵ null collisions per crossing — is crossed by regular tracking instead
//! (an exponential optical depth consumed voxel by voxel along the exact DDA): the same exact
//! distribution at a cost bounded by the voxels crossed. Every segment between two real events (or
//! to the box exit) is walked through the voxels with an exact 3D DDA and w·ℓ is tallied in each
//! voxel it crosses; φ = Σ w·ℓ / V_voxel is an unbiased estimate of the fluence (all orders,
//! uncollided light included). At a real collision the weight is multiplied by the albedo (implicit
//! absorption; with a per-voxel albedo factor a(v), `volume.albedo_*`, by `albedo·a(v)` of the voxel
//! collided in, which also sets that voxel's σa for the emission), Russian roulette applies below relative weight 0.1 (unbiased: survivors are
//! re-weighted), and the new direction is sampled from HG.
//!
//! **Boundaries** (`[boundary]`): a photon leaving through a periodic face comes back in through
//! the opposite one at the same lateral position; one reaching a mirror face is reflected
//! specularly there (the direction's component across the face changes sign) and goes on; no
//! outside light enters through either kind, so the sky and suns emit through the open faces only
//! (their power through those faces' areas). A photon that meets no medium between such faces is
//! cut off after 10 000 crossings. A photon that leaves through an open face adds its weight to that
//! face's tally: the power out per face (`report.json` `faces`), which gives a slab's reflectance
//! and transmittance independently of the solver's books.
//!
//! Photons run in batches; batch b of channel c uses its own random stream keyed by (seed, b, c);
//! threads take whole batches and the batch estimates are combined (Welford) in batch order, so the
//! result is bitwise identical for any thread count. The reported standard error is that of the mean
//! of the batch estimates.
//!
//! ## Images: path tracing from the camera
//!
//! Camera rays (pinhole with vertical field of view, or orthographic; `up` is the world up, top row
//! first, ray through a jittered point of the pixel) are delta tracked; at each real collision the
//! collision estimator adds (1 − α)·Le (= σa·Le/σt, the emission), the throughput is multiplied by α
//! and next-event estimation adds each sun (transmittance × phase × E) and the sky (one direction
//! sampled from the phase function: transmittance × the sky's and the map's radiance from there,
//! since phase/pdf = 1). The point lights' light is added per ray rather than per collision: along
//! each ray of the path (the camera's, and each one after a scattering), one point per light by
//! equiangular sampling (its density ∝ 1/r² from the light, so I/r² cancels: transmittance in ×
//! σs × phase × transmittance to the point × I, over the pdf), which estimates the same in-scattered
//! light as next-event estimation at the ray's collision without its infinite variance near the
//! light (two 256-path references of `tools/scenes/lantern_in_fog.toml` differed by 25 % over
//! their 4 × 4-pixel blocks that way, by 12 % now). Transmittances
//! are estimated by residual ratio tracking (the brick minimum integrated exactly; exact optical depth
//! in regular-tracked bricks). The path then continues in an
//! HG-sampled direction with Russian roulette. Only a primary ray that escapes adds the sky (after a
//! scattering event the sky is covered by next-event estimation); suns and point lights are never
//! seen directly.

// `!(x > 0.0)` is used on purpose throughout: it is true for NaN as well.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod environment;
mod fluence;
mod grid;
mod image;
pub mod job;
mod phase;
mod rng;
mod tracking;

pub use image::Orders;
pub use phase::sample_hg;

use crate::scene::Scene;
use fluence::{emission_cdf, trace_batch, ChannelSetup};
use grid::Grid;
use image::{opacity, radiance, View};
use rng::Rng;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

/// Random-stream tag of the photon batches.
const TAG_PHOTONS: u64 = 0;
/// Random-stream tag of the image rows.
const TAG_IMAGE: u64 = 1;

/// How much work the reference does.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ReferenceOptions {
    /// Photons per channel, in total over the batches (rounded up to a multiple of `batches`).
    pub photons: u64,
    pub seed: u64,
    /// Independent batches for the standard error; at least 2 (smaller values are raised to 2).
    pub batches: u32,
    /// Worker threads; 0 = `std::thread::available_parallelism`.
    pub threads: usize,
    /// Camera samples per pixel; 0 = no image.
    pub image_samples_per_pixel: u32,
    /// The scattering orders the image counts ([`Orders::ALL`]: the whole image).
    pub image_orders: Orders,
}

impl Default for ReferenceOptions {
    fn default() -> Self {
        ReferenceOptions {
            photons: 1_000_000,
            seed: 0,
            batches: 16,
            threads: 0,
            image_samples_per_pixel: 0,
            image_orders: Orders::ALL,
        }
    }
}

/// A rendered image: row-major, top row first, 3 floats (r, g, b) per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct RefImage {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<f32>,
    /// Per pixel, how opaque the medium is along its centre ray (1 − its transmittance, averaged
    /// over the channels, exactly): 0 where the ray meets no medium, as the renderer's alpha.
    pub alpha: Vec<f32>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceResult {
    pub dims: [u32; 3],
    pub channels: u32,
    /// Mean fluence, `[voxel (x fastest)][channel]`.
    pub fluence: Vec<f32>,
    /// Standard error of the mean from the batch estimates, same layout.
    pub std_error: Vec<f32>,
    /// Per channel, the power (W) that left through each open face of the volume
    /// (`-x, +x, -y, +y, -z, +z`): the mean over the batches and its standard error.
    pub face_out: Vec<[(f64, f64); 6]>,
    pub image: Option<RefImage>,
    /// Photons traced per channel (`photons` rounded up to a multiple of the batch count).
    pub photons: u64,
    pub seconds: f64,
}

/// Batch estimates combined in batch order (Welford), whatever order they finish in.
struct Combiner {
    next: usize,
    pending: BTreeMap<usize, Vec<f64>>,
    count: Vec<u32>,
    mean: Vec<Vec<f64>>,
    m2: Vec<Vec<f64>>,
}

impl Combiner {
    fn submit(&mut self, job: usize, batches: usize, estimate: Vec<f64>) {
        self.pending.insert(job, estimate);
        while let Some(x) = self.pending.remove(&self.next) {
            let ch = self.next / batches;
            self.count[ch] += 1;
            let k = self.count[ch] as f64;
            for ((m, s), &v) in self.mean[ch].iter_mut().zip(self.m2[ch].iter_mut()).zip(&x) {
                let delta = v - *m;
                *m += delta / k;
                *s += delta * (v - *m);
            }
            self.next += 1;
        }
    }
}

/// Run the reference: fluence for every voxel and channel, and an image when asked.
///
/// `density` is called once per voxel; values that are not finite or negative are treated as 0 (with
/// a warning). `channels`: 1 uses channel 0 of every quantity, 3 (or more) uses r, g, b.
pub fn run(
    scene: &Scene,
    density: &(dyn Fn([u32; 3]) -> f32 + Sync),
    channels: u32,
    opts: &ReferenceOptions,
) -> ReferenceResult {
    run_with_emission(scene, density, None, channels, opts)
}

/// [`run`] with a per-voxel emission factor e(v) (the scene's `volume.emission_*`): the medium
/// emits `σa·Le·e(v)` instead of `σa·Le`.
pub fn run_with_emission(
    scene: &Scene,
    density: &(dyn Fn([u32; 3]) -> f32 + Sync),
    emission: Option<&(dyn Fn([u32; 3]) -> f32 + Sync)>,
    channels: u32,
    opts: &ReferenceOptions,
) -> ReferenceResult {
    match emission {
        Some(e) => run_with_emission_rgb(scene, density, Some(&|v| [e(v); 3]), channels, opts),
        None => run_with_emission_rgb(scene, density, None, channels, opts),
    }
}

/// [`run_with_emission`] with an emission factor per channel (r, g, b; a temperature grid's
/// blackbody factors, see [`crate::scene::blackbody`]): the medium emits `σa·Le_c·e_c(v)`.
pub fn run_with_emission_rgb(
    scene: &Scene,
    density: &(dyn Fn([u32; 3]) -> f32 + Sync),
    emission: Option<&(dyn Fn([u32; 3]) -> [f32; 3] + Sync)>,
    channels: u32,
    opts: &ReferenceOptions,
) -> ReferenceResult {
    run_with_fields(scene, density, VoxelFields { emission, albedo: None }, channels, opts)
}

/// The per-voxel fields a reference run may have besides the density (see [`run_with_fields`]).
#[derive(Clone, Copy, Default)]
pub struct VoxelFields<'a> {
    /// The emission factor per channel e_c(v) (the scene's `volume.emission_*` / temperature).
    pub emission: Option<&'a (dyn Fn([u32; 3]) -> [f32; 3] + Sync)>,
    /// The albedo factor a(v) in [0, 1] (the scene's `volume.albedo_*`): voxel v's albedo is
    /// `medium.albedo·a(v)` (collisions keep that fraction of the weight; σa(v) = σt·(1 −
    /// albedo·a(v)) emits).
    pub albedo: Option<&'a (dyn Fn([u32; 3]) -> f32 + Sync)>,
}

/// [`run_with_emission_rgb`] with a per-voxel albedo factor too.
pub fn run_with_fields(
    scene: &Scene,
    density: &(dyn Fn([u32; 3]) -> f32 + Sync),
    fields: VoxelFields,
    channels: u32,
    opts: &ReferenceOptions,
) -> ReferenceResult {
    let emission = fields.emission;
    let start = Instant::now();
    let channels: usize = if channels >= 3 { 3 } else { 1 };
    let dims = scene.volume.dims;
    let (mut grid, bad) = Grid::new(dims, density);
    if bad > 0 {
        tracing::warn!(voxels = bad, "reference: non-finite or negative densities replaced by 0");
    }
    if let Some(emission) = emission {
        let bad = grid.set_emission(emission);
        if bad > 0 {
            tracing::warn!(voxels = bad, "reference: non-finite or negative emission values replaced by 0");
        }
    }
    if let Some(albedo) = fields.albedo {
        let bad = grid.set_albedo(albedo);
        if bad > 0 {
            tracing::warn!(voxels = bad, "reference: albedo factors outside [0, 1] clamped into it");
        }
    }
    let setups: Vec<ChannelSetup> = (0..channels).map(|c| ChannelSetup::new(scene, &grid, c)).collect();
    // Per channel: a temperature's emission differs between r, g and b, and so does where it is.
    let cdfs: Vec<Vec<f64>> = setups
        .iter()
        .map(|s| {
            if s.sources.iter().any(|x| x.0 == fluence::Source::Emission) {
                emission_cdf(&grid, s.ch, s.albedo)
            } else {
                Vec::new()
            }
        })
        .collect();
    let batches = opts.batches.max(2) as usize;
    let per_batch = opts.photons.div_ceil(batches as u64);
    let threads = if opts.threads == 0 {
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
    } else {
        opts.threads
    };
    let nvox = grid.voxel_count();

    // Fluence.
    let jobs = channels * batches;
    let combiner = Mutex::new(Combiner {
        next: 0,
        pending: BTreeMap::new(),
        count: vec![0; channels],
        // The voxels' fluence, then the six faces' outgoing power (`trace_batch`).
        mean: vec![vec![0.0; nvox + 6]; channels],
        m2: vec![vec![0.0; nvox + 6]; channels],
    });
    let counter = AtomicUsize::new(0);
    std::thread::scope(|scope| {
        for _ in 0..threads.clamp(1, jobs) {
            scope.spawn(|| loop {
                let job = counter.fetch_add(1, Ordering::Relaxed);
                if job >= jobs {
                    break;
                }
                let (ch, b) = (job / batches, job % batches);
                let mut rng = Rng::new(opts.seed, b as u64, ch as u64, TAG_PHOTONS);
                let mut est = Vec::new();
                trace_batch(&grid, &setups[ch], &cdfs[ch], per_batch, &mut rng, &mut est);
                // A poisoned lock means another worker panicked; that panic is re-raised by scope.
                if let Ok(mut c) = combiner.lock() {
                    c.submit(job, batches, est);
                }
            });
        }
    });
    let combined = match combiner.into_inner() {
        Ok(c) => c,
        Err(p) => p.into_inner(),
    };
    let mut fluence_out = vec![0.0f32; nvox * channels];
    let mut std_error = vec![0.0f32; nvox * channels];
    let bf = batches as f64;
    for ch in 0..channels {
        for v in 0..nvox {
            fluence_out[v * channels + ch] = combined.mean[ch][v] as f32;
            let var = (combined.m2[ch][v] / (bf - 1.0)).max(0.0);
            std_error[v * channels + ch] = (var / bf).sqrt() as f32;
        }
    }
    let face_out: Vec<[(f64, f64); 6]> = (0..channels)
        .map(|ch| {
            std::array::from_fn(|f| {
                let i = nvox + f;
                (combined.mean[ch][i], ((combined.m2[ch][i] / (bf - 1.0)).max(0.0) / bf).sqrt())
            })
        })
        .collect();

    // Image.
    let image = (opts.image_samples_per_pixel > 0).then(|| {
        let h = scene.volume.voxel_size;
        let camera = scene.camera.clone().unwrap_or_else(|| crate::render::default_camera(scene.volume.dims, h));
        let view = View::new(&camera);
        let (w, hgt) = (view.width as usize, view.height as usize);
        let spp = opts.image_samples_per_pixel;
        // Per row: its index, colour and alpha (the medium's opacity along the pixel's centre ray).
        type Row = (usize, Vec<f32>, Vec<f32>);
        let rows: Mutex<Vec<Row>> = Mutex::new(Vec::with_capacity(hgt));
        let sigmas: Vec<f64> = setups.iter().map(|s| s.sigma).collect();
        let next_row = AtomicUsize::new(0);
        std::thread::scope(|scope| {
            for _ in 0..threads.clamp(1, hgt) {
                scope.spawn(|| loop {
                    let y = next_row.fetch_add(1, Ordering::Relaxed);
                    if y >= hgt {
                        break;
                    }
                    let mut row = vec![0.0f32; w * 3];
                    for (ch, setup) in setups.iter().enumerate() {
                        let mut rng = Rng::new(opts.seed, y as u64, ch as u64, TAG_IMAGE);
                        for x in 0..w {
                            let mut sum = 0.0;
                            for _ in 0..spp {
                                let (o, d) = view.ray(x as f64 + rng.uniform(), y as f64 + rng.uniform());
                                sum += radiance(&grid, setup, opts.image_orders, o / h, d, &mut rng);
                            }
                            let value = (sum / spp as f64) as f32;
                            if channels == 1 {
                                row[3 * x..3 * x + 3].fill(value);
                            } else {
                                row[3 * x + ch] = value;
                            }
                        }
                    }
                    let alpha: Vec<f32> = (0..w)
                        .map(|x| {
                            let (o, d) = view.ray(x as f64 + 0.5, y as f64 + 0.5);
                            opacity(&grid, &sigmas, o / h, d) as f32
                        })
                        .collect();
                    if let Ok(mut r) = rows.lock() {
                        r.push((y, row, alpha));
                    }
                });
            }
        });
        let mut rows = match rows.into_inner() {
            Ok(r) => r,
            Err(p) => p.into_inner(),
        };
        rows.sort_by_key(|r| r.0);
        let alpha = rows.iter().flat_map(|r| r.2.iter().copied()).collect();
        let rgb = rows.into_iter().flat_map(|r| r.1).collect();
        RefImage { width: view.width, height: view.height, rgb, alpha }
    });

    ReferenceResult {
        dims,
        channels: channels as u32,
        fluence: fluence_out,
        std_error,
        face_out,
        image,
        photons: per_batch * batches as u64,
        seconds: start.elapsed().as_secs_f64(),
    }
}
