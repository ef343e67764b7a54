//! Forward light tracing of one batch of photons for one channel, with the track-length estimator
//! of fluence.

use super::environment::EnvChannel;
use super::grid::{box_interval, Grid};
// The only thing taken from the rest of the crate: the typed scene.
use super::phase::{basis, cosine_hemisphere, sample_hg, uniform_sphere};
use super::rng::Rng;
use super::tracking::{exit_distance, free_flight, tally_segment};
use crate::scene as lpm_scene;
use glam::DVec3;
use std::f64::consts::PI;

/// Russian roulette: a photon whose relative weight drops below this survives with probability
/// weight / RR_WEIGHT and then carries RR_WEIGHT.
pub const RR_WEIGHT: f64 = 0.1;

/// One channel's optical constants and light sources, in grid units.
#[derive(Clone, Debug)]
pub struct ChannelSetup {
    /// The channel (0 = r): which per-voxel emission factor applies.
    pub ch: usize,
    /// σt at density 1 per grid unit (σt[ch] × voxel size).
    pub sigma: f64,
    pub albedo: f64,
    pub g: f64,
    /// Emitted radiance Le.
    pub le: f64,
    /// Sum of the sky radiances.
    pub sky: f64,
    /// The environment map's channel, if the scene has one.
    pub environment: Option<EnvChannel>,
    /// (unit direction toward the sun, irradiance) for each sun with irradiance > 0.
    pub suns: Vec<(DVec3, f64)>,
    /// (position in grid units, intensity in W/sr) for each point light with intensity > 0.
    pub points: Vec<(DVec3, f64)>,
    /// Photon sources with their power (world units, W) — the probabilities of picking them.
    pub sources: Vec<(Source, f64)>,
    /// Sum of the source powers.
    pub power: f64,
    /// Voxel edge in world units.
    pub h: f64,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Source {
    Sky,
    Environment,
    /// Index into `ChannelSetup::suns`.
    Sun(usize),
    /// Index into `ChannelSetup::points`.
    Point(usize),
    Emission,
}

/// The rectangle (in the basis (u, v) ⟂ beam) covering the box's projection along `d`: half extents.
fn sun_rectangle(extent: DVec3, d: DVec3) -> (DVec3, DVec3, f64, f64) {
    let (u, v) = basis(d);
    let eu = 0.5 * (u.x.abs() * extent.x + u.y.abs() * extent.y + u.z.abs() * extent.z);
    let ev = 0.5 * (v.x.abs() * extent.x + v.y.abs() * extent.y + v.z.abs() * extent.z);
    (u, v, eu, ev)
}

impl ChannelSetup {
    pub fn new(scene: &lpm_scene::Scene, grid: &Grid, ch: usize) -> ChannelSetup {
        let m = &scene.medium;
        let h = scene.volume.voxel_size;
        let sigma = m.sigma_t[ch] * h;
        let albedo = m.albedo[ch];
        let le = m.emission[ch];
        let mut sky = 0.0;
        let mut suns = Vec::new();
        let mut environment = None;
        let mut points = Vec::new();
        for light in &scene.lights {
            match light {
                lpm_scene::Light::Sky { radiance } => sky += radiance[ch],
                lpm_scene::Light::Sun { direction, irradiance } => {
                    let len = direction.length();
                    if irradiance[ch] > 0.0 && len > 0.0 && len.is_finite() {
                        suns.push((*direction / len, irradiance[ch]));
                    }
                }
                lpm_scene::Light::Environment(env) => environment = Some(EnvChannel::new(env, ch)),
                lpm_scene::Light::Point { position, intensity } => {
                    if intensity[ch] > 0.0 {
                        points.push((*position / h, intensity[ch]));
                    }
                }
            }
        }
        let e = grid.extent();
        let mut sources = Vec::new();
        if sky > 0.0 {
            let area = 2.0 * (e.x * e.y + e.y * e.z + e.z * e.x) * h * h;
            sources.push((Source::Sky, PI * sky * area));
        }
        if let Some(env) = environment.as_ref().filter(|env| env.power > 0.0) {
            // Through a disk of radius R (the box's half diagonal) facing each direction.
            let r = 0.5 * e.length();
            sources.push((Source::Environment, env.power * PI * r * r * h * h));
        }
        for (i, &(dir, irr)) in suns.iter().enumerate() {
            let (_, _, eu, ev) = sun_rectangle(e, -dir);
            sources.push((Source::Sun(i), irr * 4.0 * eu * ev * h * h));
        }
        for (i, &(_, intensity)) in points.iter().enumerate() {
            // Isotropic: 4π·I leaves the point (photons that miss the box still count in N).
            sources.push((Source::Point(i), 4.0 * PI * intensity));
        }
        let sigma_a_world = m.sigma_t[ch] * (1.0 - albedo);
        let emitted = 4.0 * PI * sigma_a_world * le * grid.emission_weight[ch] * h * h * h;
        if emitted > 0.0 {
            sources.push((Source::Emission, emitted));
        }
        let power = sources.iter().map(|s| s.1).sum();
        ChannelSetup { ch, sigma, albedo, g: m.g, le, sky, environment, suns, points, sources, power, h }
    }

    /// Radiance arriving from outside the box along the direction `toward` (unit): the sky plus
    /// the environment map.
    pub fn sky_radiance(&self, toward: DVec3) -> f64 {
        self.sky + self.environment.as_ref().map_or(0.0, |e| e.radiance(toward))
    }

    /// Some light arrives from outside the box along some direction (sky or map).
    pub fn has_sky(&self) -> bool {
        self.sky > 0.0 || self.environment.as_ref().is_some_and(|e| e.power > 0.0)
    }
}

/// Cumulative density × channel `ch`'s emission factor over voxels (x fastest), for sampling
/// emission positions.
pub fn emission_cdf(grid: &Grid, ch: usize) -> Vec<f64> {
    let mut acc = 0.0f64;
    grid.density
        .iter()
        .enumerate()
        .map(|(i, &d)| {
            acc += d as f64 * grid.emission_factor(i, ch);
            acc
        })
        .collect()
}

/// Start a photon: position (grid units, inside or on the box) and direction; `None` when a sun
/// photon misses the box (it still counts in N).
fn emit(grid: &Grid, setup: &ChannelSetup, cdf: &[f64], rng: &mut Rng) -> Option<(DVec3, DVec3)> {
    let e = grid.extent();
    // Pick the source with probability ∝ power.
    let mut x = rng.uniform() * setup.power;
    let mut source = setup.sources.last()?.0;
    for &(s, p) in &setup.sources {
        if x < p {
            source = s;
            break;
        }
        x -= p;
    }
    match source {
        Source::Sky => {
            // Face ∝ area, uniform point on it, cosine-weighted inward direction.
            let areas = [e.y * e.z, e.y * e.z, e.x * e.z, e.x * e.z, e.x * e.y, e.x * e.y];
            let total: f64 = areas.iter().sum();
            let mut y = rng.uniform() * total;
            let mut face = 5;
            for (i, a) in areas.iter().enumerate() {
                if y < *a {
                    face = i;
                    break;
                }
                y -= a;
            }
            let axis = face / 2;
            let high = face % 2 == 1;
            let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut p = DVec3::ZERO;
            p[axis] = if high { e[axis] } else { 0.0 };
            p[a1] = rng.uniform() * e[a1];
            p[a2] = rng.uniform() * e[a2];
            let mut n = DVec3::ZERO;
            n[axis] = if high { -1.0 } else { 1.0 };
            let d = cosine_hemisphere(n, rng.uniform(), rng.uniform());
            Some((p, d))
        }
        Source::Environment => {
            // A direction toward the sky ∝ L, then a point uniform on the disk of radius R facing
            // it (outside the box), travelling away from the sky; misses count in N.
            let d = -setup.environment.as_ref()?.sample(rng)?;
            let (u, v) = basis(d);
            let c = 0.5 * e;
            let r = 0.5 * e.length();
            let (rho, a) = (r * rng.uniform().sqrt(), 2.0 * PI * rng.uniform());
            let o = c - d * (r + 1.0) + u * (rho * a.cos()) + v * (rho * a.sin());
            let (t0, _) = box_interval(o, d, e)?;
            Some((o + d * t0.max(0.0), d))
        }
        Source::Sun(i) => {
            let d = -setup.suns.get(i)?.0;
            let (u, v, eu, ev) = sun_rectangle(e, d);
            let c = 0.5 * e;
            let r = 0.5 * e.length() + 1.0;
            let o = c - d * r + u * ((2.0 * rng.uniform() - 1.0) * eu) + v * ((2.0 * rng.uniform() - 1.0) * ev);
            let (t0, _) = box_interval(o, d, e)?;
            Some((o + d * t0.max(0.0), d))
        }
        Source::Point(i) => {
            // An isotropic direction from the light; from outside, on to where it meets the box.
            let q = setup.points.get(i)?.0;
            let d = uniform_sphere(rng.uniform(), rng.uniform());
            let (t0, _) = box_interval(q, d, e)?;
            Some((q + d * t0.max(0.0), d))
        }
        Source::Emission => {
            let total = *cdf.last()?;
            let y = rng.uniform() * total;
            let i = cdf.partition_point(|&c| c <= y).min(cdf.len() - 1);
            let nx = grid.dims[0] as usize;
            let ny = grid.dims[1] as usize;
            let v = DVec3::new((i % nx) as f64, ((i / nx) % ny) as f64, (i / (nx * ny)) as f64);
            let p = v + DVec3::new(rng.uniform(), rng.uniform(), rng.uniform());
            Some((p, uniform_sphere(rng.uniform(), rng.uniform())))
        }
    }
}

/// Trace `n` photons and return the batch's fluence estimate per voxel (world units, W/m²) in
/// `out` (resized to the voxel count).
pub fn trace_batch(grid: &Grid, setup: &ChannelSetup, cdf: &[f64], n: u64, rng: &mut Rng, out: &mut Vec<f64>) {
    out.clear();
    out.resize(grid.voxel_count(), 0.0);
    if n == 0 || !(setup.power > 0.0) {
        return;
    }
    for _ in 0..n {
        let Some((mut p, mut d)) = emit(grid, setup, cdf, rng) else {
            continue;
        };
        let mut w = 1.0f64;
        loop {
            let t_exit = exit_distance(grid, p, d);
            if !(t_exit > 0.0) {
                break;
            }
            let hit = free_flight(grid, setup.sigma, p, d, t_exit, rng);
            // The whole segment from the last real event to the next one (or the exit) is tallied,
            // null collisions included.
            tally_segment(grid, p, d, hit.unwrap_or(t_exit), w, out);
            let Some(t) = hit else { break };
            p += d * t;
            w *= setup.albedo;
            if w < RR_WEIGHT {
                if rng.uniform() * RR_WEIGHT < w {
                    w = RR_WEIGHT;
                } else {
                    break;
                }
            }
            d = sample_hg(setup.g, rng.uniform(), rng.uniform(), d);
        }
    }
    // Each photon carries power P/N; fluence = Σ w·ℓ / V with ℓ in world units: ℓ_grid·h / h³.
    let scale = setup.power / n as f64 / (setup.h * setup.h);
    for v in out.iter_mut() {
        *v *= scale;
    }
}
