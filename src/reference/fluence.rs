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
    /// The scene's boundary: which faces no outside light enters by, and what happens to a photon
    /// that reaches them (a periodic face: it comes back through the opposite one; a mirror: it is
    /// reflected specularly, the component of its direction across the face changing sign).
    pub boundary: lpm_scene::Boundary,
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
        let boundary = scene.boundary;
        let mut sources = Vec::new();
        if sky > 0.0 {
            let area: f64 = open_face_areas(e, boundary).iter().sum::<f64>() * h * h;
            sources.push((Source::Sky, PI * sky * area));
        }
        if let Some(env) = environment.as_ref().filter(|env| env.power > 0.0) {
            // Through a disk of radius R (the box's half diagonal) facing each direction.
            let r = 0.5 * e.length();
            sources.push((Source::Environment, env.power * PI * r * r * h * h));
        }
        for (i, &(dir, irr)) in suns.iter().enumerate() {
            let area = if !boundary.all_open() {
                // Through the open faces it lights, each with its projected area.
                projected_open_areas(e, boundary, -dir).iter().sum::<f64>()
            } else {
                let (_, _, eu, ev) = sun_rectangle(e, -dir);
                4.0 * eu * ev
            };
            sources.push((Source::Sun(i), irr * area * h * h));
        }
        for (i, &(_, intensity)) in points.iter().enumerate() {
            // Isotropic: 4π·I leaves the point (photons that miss the box still count in N).
            sources.push((Source::Point(i), 4.0 * PI * intensity));
        }
        let emitted = if grid.albedo.is_empty() {
            let sigma_a_world = m.sigma_t[ch] * (1.0 - albedo);
            4.0 * PI * sigma_a_world * le * grid.emission_weight[ch] * h * h * h
        } else {
            // σa varies per voxel: Σ ρ·e·(1 − albedo·a(v)) over the voxels, times σt.
            let weight: f64 = (0..grid.voxel_count()).filter_map(|i| grid.absorbing_weight(i, ch, albedo)).sum();
            4.0 * PI * m.sigma_t[ch] * le * weight * h * h * h
        };
        if emitted > 0.0 {
            sources.push((Source::Emission, emitted));
        }
        let power = sources.iter().map(|s| s.1).sum();
        ChannelSetup { ch, sigma, albedo, g: m.g, le, sky, environment, suns, points, sources, power, h, boundary }
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
/// emission positions (× 1 − albedo·a(v) with an albedo grid, whose σa varies per voxel;
/// `medium_albedo` is the channel's `medium.albedo`).
pub fn emission_cdf(grid: &Grid, ch: usize, medium_albedo: f64) -> Vec<f64> {
    let mut acc = 0.0f64;
    grid.density
        .iter()
        .enumerate()
        .map(|(i, &d)| {
            acc += grid.absorbing_weight(i, ch, medium_albedo).unwrap_or(d as f64 * grid.emission_factor(i, ch));
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
            // Open face ∝ area, uniform point on it, cosine-weighted inward direction.
            let areas = open_face_areas(e, setup.boundary);
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
            if !setup.boundary.all_open() {
                // Through the open faces only: accepted with probability (their projected area)
                // / (the disk's), the power being the disk's; then a point on them ∝ that area.
                let r = 0.5 * e.length();
                let areas = projected_open_areas(e, setup.boundary, d);
                if rng.uniform() * PI * r * r >= areas.iter().sum::<f64>() {
                    return None;
                }
                return Some((point_on_faces(e, &areas, rng), d));
            }
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
            if !setup.boundary.all_open() {
                return Some((point_on_faces(e, &projected_open_areas(e, setup.boundary, d), rng), d));
            }
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

/// Most times one photon crosses periodic faces or is reflected by mirrors before it is dropped
/// (only a photon that meets no medium between them gets near it).
const MAX_WRAPS: u32 = 10_000;

/// Areas of the six faces (−x, +x, −y, +y, −z, +z, grid units) of a box of extent `e`, zero for
/// periodic and mirror faces (no outside light enters there).
fn open_face_areas(e: DVec3, boundary: lpm_scene::Boundary) -> [f64; 6] {
    std::array::from_fn(|f| {
        let axis = f / 2;
        if boundary.is_open(axis, f % 2 == 1) {
            e[(axis + 1) % 3] * e[(axis + 2) % 3]
        } else {
            0.0
        }
    })
}

/// The open faces' areas projected across the travel direction `d`, for the faces `d` enters by
/// (zero for the others).
fn projected_open_areas(e: DVec3, boundary: lpm_scene::Boundary, d: DVec3) -> [f64; 6] {
    let areas = open_face_areas(e, boundary);
    std::array::from_fn(|f| {
        let (axis, high) = (f / 2, f % 2 == 1);
        // The −axis face is entered travelling +axis, the +axis face travelling −axis.
        let inward = if high { -d[axis] } else { d[axis] };
        areas[f] * inward.max(0.0)
    })
}

/// A point uniform on the faces, face f picked ∝ `weights[f]`.
fn point_on_faces(e: DVec3, weights: &[f64; 6], rng: &mut Rng) -> DVec3 {
    let mut y = rng.uniform() * weights.iter().sum::<f64>();
    let mut face = weights.iter().rposition(|&w| w > 0.0).unwrap_or(5);
    for (i, w) in weights.iter().enumerate() {
        if y < *w {
            face = i;
            break;
        }
        y -= w;
    }
    let (axis, high) = (face / 2, face % 2 == 1);
    let mut p = DVec3::ZERO;
    p[axis] = if high { e[axis] } else { 0.0 };
    p[(axis + 1) % 3] = rng.uniform() * e[(axis + 1) % 3];
    p[(axis + 2) % 3] = rng.uniform() * e[(axis + 2) % 3];
    p
}

/// Where and how a photon reaching the box's surface at `q` along `d` goes on: through a
/// periodic face, in through the opposite one; at a mirror, reflected where it is (its direction
/// across the face reversed); across an edge or corner, each face it reaches does its part.
/// `None` when it leaves for good through an open face.
fn cross_boundary(e: DVec3, boundary: lpm_scene::Boundary, q: DVec3, d: DVec3) -> Option<(DVec3, DVec3)> {
    let (mut p, mut d_next) = (q.clamp(DVec3::ZERO, e), d);
    let mut crossed = false;
    for axis in 0..3 {
        let tol = 1e-9 * e[axis].max(1.0);
        let out_high = d[axis] > 0.0 && p[axis] >= e[axis] - tol;
        let out_low = d[axis] < 0.0 && p[axis] <= tol;
        if out_high || out_low {
            if boundary.reflective[axis][out_high as usize] {
                p[axis] = if out_high { e[axis] } else { 0.0 };
                d_next[axis] = -d[axis];
            } else if boundary.periodic[axis] {
                p[axis] = if out_high { 0.0 } else { e[axis] };
            } else {
                return None;
            }
            crossed = true;
        }
    }
    crossed.then_some((p, d_next))
}

/// The face (`-x, +x, -y, +y, -z, +z`, the order of `lpm solve`'s report) a photon at `q` on the
/// box's surface leaves by along `d`: of the faces it lies on (to rounding) and heads out of, the
/// one it is closest to (an edge or corner, met with probability zero, goes to the first axis).
fn exit_face(e: DVec3, q: DVec3, d: DVec3) -> usize {
    let mut best = (f64::INFINITY, 0);
    for axis in 0..3 {
        let gap = if d[axis] > 0.0 {
            e[axis] - q[axis]
        } else if d[axis] < 0.0 {
            q[axis]
        } else {
            continue;
        };
        if gap.abs() < best.0 {
            best = (gap.abs(), 2 * axis + (d[axis] > 0.0) as usize);
        }
    }
    best.1
}

/// Trace `n` photons and return the batch's fluence estimate per voxel (world units, W/m²) in
/// `out[..voxels]`, and the power (W) that left through each open face of the volume in the six
/// entries after them (`-x, +x, -y, +y, -z, +z`): `out` is resized to the voxel count + 6.
pub fn trace_batch(grid: &Grid, setup: &ChannelSetup, cdf: &[f64], n: u64, rng: &mut Rng, out: &mut Vec<f64>) {
    let voxels = grid.voxel_count();
    out.clear();
    out.resize(voxels + 6, 0.0);
    if n == 0 || !(setup.power > 0.0) {
        return;
    }
    for _ in 0..n {
        let Some((mut p, mut d)) = emit(grid, setup, cdf, rng) else {
            continue;
        };
        let mut w = 1.0f64;
        let mut wraps = 0;
        loop {
            let t_exit = exit_distance(grid, p, d);
            if !(t_exit > 0.0) {
                break;
            }
            let hit = free_flight(grid, setup.sigma, p, d, t_exit, rng);
            // The whole segment from the last real event to the next one (or the exit) is tallied,
            // null collisions included.
            tally_segment(grid, p, d, hit.unwrap_or(t_exit), w, out);
            let Some(t) = hit else {
                // Out through a periodic face: back in through the opposite one; at a mirror,
                // reflected. (A photon that meets no medium between such faces would go on for
                // ever: cut it off.)
                let q = p + d * t_exit;
                match cross_boundary(grid.extent(), setup.boundary, q, d) {
                    Some((q, reflected)) if wraps < MAX_WRAPS => {
                        (p, d) = (q, reflected);
                        wraps += 1;
                        continue;
                    }
                    Some(_) => break,
                    None => {
                        // Out for good through an open face: its tally. (A point that rounding left
                        // short of every face also ends here; it is dropped, as it always was.)
                        let face = exit_face(grid.extent(), q, d);
                        let (axis, high) = (face / 2, face % 2);
                        if !setup.boundary.periodic[axis] && !setup.boundary.reflective[axis][high] {
                            out[voxels + face] += w;
                        }
                        break;
                    }
                }
            };
            p += d * t;
            w *= setup.albedo * grid.albedo_at(p);
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
    for v in &mut out[..voxels] {
        *v *= scale;
    }
    for v in &mut out[voxels..] {
        *v *= setup.power / n as f64;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn photons_are_reflected_wrapped_or_let_out_face_by_face() {
        let e = DVec3::new(4.0, 5.0, 6.0);
        let faces = lpm_scene::Boundary {
            periodic: [false, true, false],
            reflective: [[true, false], [false; 2], [false, true]],
        };
        let d = DVec3::new(-0.6, 0.0, 0.8);
        // At the low x mirror: reflected where it is.
        let (p, r) = cross_boundary(e, faces, DVec3::new(0.0, 2.0, 3.0), d).expect("reflected");
        assert_eq!((p, r), (DVec3::new(0.0, 2.0, 3.0), DVec3::new(0.6, 0.0, 0.8)));
        // Through the high x face, which is open: gone.
        assert_eq!(cross_boundary(e, faces, DVec3::new(4.0, 2.0, 3.0), DVec3::new(0.6, 0.0, 0.8)), None);
        // Through the periodic y faces: back in through the opposite one, direction kept.
        let up = DVec3::new(0.0, 1.0, 0.0);
        assert_eq!(cross_boundary(e, faces, DVec3::new(1.0, 5.0, 2.0), up), Some((DVec3::new(1.0, 0.0, 2.0), up)));
        // At the edge of the low x mirror and the high z mirror: reflected by both.
        let (p, r) = cross_boundary(e, faces, DVec3::new(0.0, 2.0, 6.0), d).expect("reflected twice");
        assert_eq!((p, r), (DVec3::new(0.0, 2.0, 6.0), DVec3::new(0.6, 0.0, -0.8)));
        // At the edge of a mirror and an open face: out through the open one.
        let low_z = DVec3::new(-0.6, 0.0, -0.8);
        assert_eq!(cross_boundary(e, faces, DVec3::new(0.0, 2.0, 0.0), low_z), None);
        // Mirror and periodic faces take no outside light; the open ones keep their areas.
        assert_eq!(open_face_areas(e, faces), [0.0, 30.0, 0.0, 0.0, 20.0, 0.0]);
    }
}
