//! Camera images by path tracing with delta tracking and next-event estimation, optionally
//! counting only the light scattered a chosen number of times ([`Orders`]).

use super::fluence::{ChannelSetup, RR_WEIGHT};
use super::grid::{box_interval, Dda, Grid};
use super::phase::{hg_eval, sample_hg};
use super::rng::Rng;
use super::tracking::{exit_distance, free_flight, transmittance};
use crate::scene::{Camera, Projection};
use glam::DVec3;

/// Which scattering orders an image counts: the light that reached the camera after `first` to
/// `last` scatterings (inclusive). Order 0 is the light seen unscattered (the sky through the
/// medium, the medium's own emission), order 1 the lights' single scattering; light emitted by
/// the medium counts the scatterings after its emission. Images of orders 0..=1 and 2.. with the
/// same seed add up to the whole image (to rounding): every estimate is made whatever the orders,
/// only counted or not, so the random numbers are the same. What a part of an image made by
/// another method is checked against (benches/RESULTS.md, "the rim taken apart by light and by
/// order").
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Orders {
    pub first: u32,
    /// `None`: no upper bound.
    pub last: Option<u32>,
}

impl Orders {
    /// Every order: the whole image.
    pub const ALL: Orders = Orders { first: 0, last: None };

    pub fn contains(&self, order: u32) -> bool {
        order >= self.first && self.last.is_none_or(|last| order <= last)
    }
}

impl std::str::FromStr for Orders {
    type Err = String;

    /// `N` (that order alone), `N..M` (N to M, inclusive) or `N..` (N and above).
    fn from_str(text: &str) -> Result<Orders, String> {
        let number = |t: &str| {
            t.trim().parse::<u32>().map_err(|_| {
                format!("scattering orders \"{text}\": \"{t}\" is not a whole number (write N, N..M or N..)")
            })
        };
        let orders = match text.split_once("..") {
            None => {
                let n = number(text)?;
                Orders { first: n, last: Some(n) }
            }
            Some((first, "")) => Orders { first: number(first)?, last: None },
            Some((first, last)) => Orders { first: number(first)?, last: Some(number(last)?) },
        };
        match orders.last {
            Some(last) if last < orders.first => {
                Err(format!("scattering orders \"{text}\": the last order is below the first"))
            }
            _ => Ok(orders),
        }
    }
}

/// A camera reduced to what ray generation needs, in world units.
#[derive(Clone, Debug)]
pub struct View {
    pub projection: Projection,
    pub position: DVec3,
    pub forward: DVec3,
    pub right: DVec3,
    pub up: DVec3,
    pub width: u32,
    pub height: u32,
}

impl View {
    /// The view through `cam` (the scene's camera, or [`crate::render::default_camera`]: the one
    /// default view, shared with the renderer so that `lpm compare` can compare their images).
    pub fn new(cam: &Camera) -> View {
        let mut forward = (cam.look_at - cam.position).normalize_or_zero();
        if forward == DVec3::ZERO {
            forward = DVec3::NEG_Z;
        }
        let mut right = forward.cross(cam.up).normalize_or_zero();
        if right == DVec3::ZERO {
            // `up` parallel to the view direction: any perpendicular will do.
            right = forward.any_orthonormal_vector();
        }
        let up = right.cross(forward);
        View {
            projection: cam.projection,
            position: cam.position,
            forward,
            right,
            up,
            width: cam.width.max(1),
            height: cam.height.max(1),
        }
    }

    /// The world-space ray through image point (x, y) in pixels (0,0 = top-left corner of the image).
    pub fn ray(&self, x: f64, y: f64) -> (DVec3, DVec3) {
        let aspect = self.width as f64 / self.height as f64;
        let sx = 2.0 * x / self.width as f64 - 1.0;
        let sy = 1.0 - 2.0 * y / self.height as f64;
        match self.projection {
            Projection::Pinhole { fov_y_degrees } => {
                let t = (0.5 * fov_y_degrees.to_radians()).tan();
                let d = (self.forward + self.right * (sx * t * aspect) + self.up * (sy * t)).normalize();
                (self.position, d)
            }
            Projection::Orthographic { height } => {
                let half = 0.5 * height;
                let o = self.position + self.right * (sx * half * aspect) + self.up * (sy * half);
                (o, self.forward)
            }
        }
    }
}

/// How opaque the medium is along the ray o + t·d (grid units) from o on: 1 − the transmittance,
/// averaged over the channels' extinctions `sigmas` (per grid unit at density 1), exactly through
/// the piecewise-constant voxels. What an image's alpha is, as lpm's renderer has it (1 − the mean
/// of its channels' transmittance), so that a comparison can tell the medium's pixels from the
/// sky's in a reference image too. No random numbers: the image's colour is the same with or
/// without it.
pub fn opacity(grid: &Grid, sigmas: &[f64], o: DVec3, d: DVec3) -> f64 {
    let Some((t0, t1)) = box_interval(o, d, grid.extent()) else {
        return 0.0;
    };
    let start = o + d * t0.max(0.0);
    let depth: f64 = Dda::new(start, d, t1 - t0.max(0.0), 1.0, grid.dims)
        .map(|(v, a, b)| grid.density[grid.voxel_index(v)] as f64 * (b - a))
        .sum();
    1.0 - sigmas.iter().map(|s| (-s * depth).exp()).sum::<f64>() / sigmas.len().max(1) as f64
}

/// One radiance sample along the ray o + t·d (grid units) for one channel, of the light that
/// scattered as many times as `orders` allows.
pub fn radiance(grid: &Grid, s: &ChannelSetup, orders: Orders, o: DVec3, d: DVec3, rng: &mut Rng) -> f64 {
    let extent = grid.extent();
    let mut l = 0.0;
    let mut beta = 1.0f64;
    let mut p;
    let mut d = d;
    // Bring the camera ray to the box.
    match box_interval(o, d, extent) {
        None => return if orders.contains(0) { s.sky_radiance(d) } else { 0.0 },
        Some((t0, _)) => p = o + d * t0.max(0.0),
    }
    let mut scattered = false;
    // Collisions so far: the lights' next-event estimates at collision k are light scattered k
    // times, the emission collected there k − 1 times.
    let mut collisions = 0u32;
    loop {
        // The point lights' light scattered into this ray anywhere along it, by equiangular
        // sampling (`point_in_scattering`): scattered once more than the path so far.
        let points = point_in_scattering(grid, s, p, d, rng);
        if orders.contains(collisions + 1) {
            l += beta * points;
        }
        let t_exit = exit_distance(grid, p, d);
        let hit = if t_exit > 0.0 { free_flight(grid, s.sigma, p, d, t_exit, rng) } else { None };
        let Some(t) = hit else {
            // Escaped. After a scattering event the sky was already counted by next-event
            // estimation (its direction sampled from the phase function), so only the primary ray
            // sees the sky here; the sun is a delta and never seen directly.
            if !scattered && orders.contains(0) {
                l += beta * s.sky_radiance(d);
            }
            break;
        };
        p += d * t;
        collisions += 1;
        let counted = orders.contains(collisions);
        // Collision estimator: at a real collision (pdf σt·T) the source term σa·Le/σt = (1 − α)·Le.
        // With an albedo grid, α is the medium's albedo times the voxel's factor a(v).
        let albedo = s.albedo * grid.albedo_at(p);
        if s.le > 0.0 && orders.contains(collisions - 1) {
            let v = [0, 1, 2].map(|a| (p[a].floor() as i64).clamp(0, grid.dims[a] as i64 - 1));
            l += beta * (1.0 - albedo) * s.le * grid.emission_factor(grid.voxel_index(v), s.ch);
        }
        beta *= albedo;
        if !(beta > 0.0) {
            break;
        }
        // Next-event estimation to each sun: light travelling along −sun scatters into −d, so the
        // scattering cosine is (−sun)·(−d) = sun·d.
        for &(sun, e) in &s.suns {
            let tr = transmittance(grid, s.sigma, p, sun, exit_distance(grid, p, sun), rng);
            if tr > 0.0 && counted {
                l += beta * tr * e * hg_eval(s.g, sun.dot(d));
            }
        }
        // Next-event estimation to the sky along a phase-sampled direction (phase / pdf = 1).
        if s.has_sky() {
            let w = sample_hg(s.g, rng.uniform(), rng.uniform(), d);
            let tr = transmittance(grid, s.sigma, p, w, exit_distance(grid, p, w), rng);
            if counted {
                l += beta * tr * s.sky_radiance(w);
            }
        }
        scattered = true;
        if beta < RR_WEIGHT {
            if rng.uniform() * RR_WEIGHT < beta {
                beta = RR_WEIGHT;
            } else {
                break;
            }
        }
        d = sample_hg(s.g, rng.uniform(), rng.uniform(), d);
    }
    l
}

/// The point lights' light scattered into the ray from `p` (on the box, or inside it) along `d`
/// towards its origin, for one channel: `∫ T(p → x)·σs(x)·HG(w·d)·I·T(x → q)/|x − q|² dt` over the
/// ray through the box, one sample per light by equiangular sampling (Kulla & Fajardo 2012): the
/// distance t with a density ∝ 1/|x − q|², so the light's 1/r² cancels. It stands for next-event
/// estimation at the ray's delta-tracked collision, which has the same mean but an infinite
/// variance in a medium around a point light (∫ (1/r²)² r² dr diverges at the light): paths that
/// collide close to it give rare, enormous samples, fireflies no number of paths averages away.
/// The transmittances are the tracking estimators' (unbiased); σs is the voxel's at x.
fn point_in_scattering(grid: &Grid, s: &ChannelSetup, p: DVec3, d: DVec3, rng: &mut Rng) -> f64 {
    let length = exit_distance(grid, p, d);
    let mut l = 0.0;
    for &(q, intensity) in &s.points {
        // The light's foot on the ray (Δ along it) and its distance D from it.
        let delta = (q - p).dot(d);
        let foot = (q - p - d * delta).length().max(1e-9);
        let (a, b) = ((-delta / foot).atan(), ((length - delta) / foot).atan());
        if !(length > 0.0 && b > a) {
            continue;
        }
        let u = rng.uniform();
        let t = delta + foot * (a + u * (b - a)).tan();
        let x = p + d * t.clamp(0.0, length);
        // pdf(t) = D / ((b − a)·r²): the estimate's 1/r² and the pdf's cancel.
        let to = q - x;
        let r2 = to.length_squared();
        let r = r2.sqrt();
        let v = [0, 1, 2].map(|k| (x[k].floor() as i64).clamp(0, grid.dims[k] as i64 - 1));
        let sigma_s = s.sigma * grid.density[grid.voxel_index(v)] as f64 * s.albedo * grid.albedo_at(x);
        if !(sigma_s > 0.0 && r > 0.0) {
            continue;
        }
        let w = to / r;
        let t_in = transmittance(grid, s.sigma, p, d, t, rng);
        let t_out = transmittance(grid, s.sigma, x, w, exit_distance(grid, x, w).min(r), rng);
        l += t_in * sigma_s * hg_eval(s.g, w.dot(d)) * intensity / (s.h * s.h) * t_out * (b - a) / foot;
    }
    l
}
