//! A sun's forward light on a cone of directions, transported with the real geometry so that
//! it spreads sideways: the correction the render adds to [`super::peak`]'s chains and lobes
//! under δ-M.
//!
//! **Why.** The chains and lobes count the light the sun scatters forward along its straight
//! line (Poisson amounts `E·τₛⁿ/n!` with lobes HG(gⁿ⁺¹)). Against Monte Carlo that puts 1.3, 1.6
//! and 2.1 times too much light of orders 2, 3 and 4–6 into a cloud's thin rim seen towards the
//! sun (the real light, deflected by a few degrees at each scattering, leaves a thin fringe
//! sideways) and too little of the low orders deep in its core (benches/RESULTS.md, "What the
//! g 0.95 backlit view misses, order by order").
//!
//! **What.** The directions within a cone of half-angle Θ about the sun's direction of travel,
//! cut into K cells (squares of side δ ≈ 1.2·(1 − g) on the plane tangent to the cone's axis),
//! each carrying the radiance L_k(x) of the sun's light that has scattered once or more and
//! always into the cone; Θ holds of one scattering the share δ-M takes as not scattered (f). The
//! cone's light alone, in place of the chains and lobes, leaves a backlit g 0.95 cloud's core
//! 14 % dark (light that once left the cone and came back is the solve's, binned). So the render
//! keeps the chains and lobes and adds what the geometry changes: the same march run twice, once
//! with each cell's light travelling along its own direction and once with every cell's light
//! held on the sun's line (the straight line of the chains and lobes, with the same cells,
//! scattering and steps), and the camera takes `σs·Σ_k W_k(ω)·(L_k − L_k^line)` with `W_k(ω) =
//! ∫_cell k HG(g; ω'·ω) dω'` the true phase towards it. The two marches' numerical errors (the
//! grid's spacing, the entry into the medium between two slices) cancel in the difference; a
//! closed-form straight line against the march instead left errors as large as the effect
//! (benches/RESULTS.md).
//!
//! **How.** On a grid aligned with the sun (axes u, v across it, w along its travel, spacing h =
//! ½ voxel, coarser where `MOST_VALUES` demands) every direction of the cone advances from slice
//! to slice along w, so the cone is one march through the slices, every order at once. Each
//! cell's light is carried along its own rays (a lattice of long characteristics that moves
//! sideways by the cell's tangent each slice), so the carried light is never re-interpolated
//! (short characteristics would spread it sideways numerically by ~√(L·tan θ·h) voxels, as much as
//! the physical spread). At each slice the cells' light is read back at the grid points,
//! scattered into every cell with the cell-averaged HG(g) (`P_kj`), and the rays take that source
//! with a predictor–corrector step that integrates an exponentially varying source exactly
//! (`step_source`). The sun's own light enters as the source `σs·E·P_k,sun` with E from the
//! render data (interpolated in optical depth, as the single scattering reads it); the
//! difference is kept relative to E* at the grid points and multiplied by E* where the camera
//! reads it.
//!
//! **Measured** (benches/RESULTS.md, "The sun's forward light on a cone"): the cone's light of
//! orders 2, 3 and 4–6 is within 0–4 % of `lpm reference --orders` at a g 0.95 cloud's centre and
//! thin rim seen towards the sun; with the correction the backlit g 0.95 views' whole images go
//! from 7.3 / 6.8 % to 3.1 / 2.7 % against the Monte-Carlo reference (4 × 4-pixel blocks), every
//! view of `tools/forward_image_table.sh` is within 5 %, and side- and front-lit views move by
//! 0.1 % at most. Cost: on the 48³ cloud the two marches hold 150 MB each (the difference is
//! kept); a 512 × 512 render of it takes 13.9 s on two cores where it took 4.1 s without.
//!
//! No library does this (a discrete-ordinates sweep restricted to a cone, on a sun-aligned grid);
//! the arithmetic is small and kept here.

use super::march::{beam_irradiance, corner_bricks, trilinear};
use super::DirectBeam;
use crate::quadrature::phase::henyey_greenstein;
use crate::scene::Medium;
use crate::store::{BrickStore, Field};
use glam::DVec3;
use rayon::prelude::*;

/// Most aligned-grid values (points × (cells + 1)) one march may hold: 6·10⁷ f32, 240 MB (the
/// two marches of a cone 480 MB while it is built). Past it the grid spacing grows; past
/// [`COARSEST`] there is no cone (the chains and lobes serve).
const MOST_VALUES: f64 = 6e7;

/// The finest grid spacing, in voxels: the sun's light falls by e^{−σt·h} between points, and
/// half a voxel keeps what the linear interpolation of the source between them overstates at
/// ~2 % for σt = 0.8 a voxel (benches/RESULTS.md).
const FINEST: f64 = 0.5;

/// The coarsest spacing, in voxels, at which a cone is still worth its cost.
const COARSEST: f64 = 2.0;

/// Sub-samples per cell side for the cell-averaged phase function.
const SUBSAMPLES: usize = 4;

/// A camera ray further than this (radians) beyond the cone's edge sees the whole cone under one
/// phase value: HG(g) hardly varies across the cone there.
const FAR: f64 = 0.7;

/// One cell of the cone: its sub-sample directions and their solid angles.
#[derive(Clone)]
struct Cell {
    tangent: (f64, f64),
    samples: Vec<(DVec3, f64)>,
}

/// The medium and the sun's light at a point (voxel units): (σt, σs) per voxel length, the
/// uncollided irradiance E and the δ-M scaled one E* (which the cone's light is kept relative
/// to: both fall alike along the sun's path, so their ratio interpolates linearly between the
/// grid points where either alone would be overstated).
pub struct MediumSample {
    pub sigma_t: f64,
    pub sigma_s: f64,
    pub irradiance: f64,
    pub scaled_irradiance: f64,
}

/// One sun's forward light on its cone, on the sun-aligned grid (module docs).
#[derive(Clone)]
pub struct ForwardCone {
    origin: DVec3,
    axes: [DVec3; 3],
    h: f64,
    n: [usize; 3],
    cells: Vec<Cell>,
    g: f64,
    cos_far: f64,
    /// Per grid point, over E* there: the K cells' radiance with the real geometry less the
    /// same with every cell's light held on the sun's line, and then the same difference of the
    /// cone's whole radiance times solid angle (its flux), `K + 1` values a point.
    light: Vec<f32>,
}

/// What a camera ray reads from the cone: per cell (index, `W_k`), or the flux under one phase.
pub struct ConeWeights {
    cells: Vec<(u32, f64)>,
}

impl ForwardCone {
    /// The cone of the sun whose light travels along `travel` (unit length) through a medium
    /// with phase HG(`g`) whose δ-M solve took the share `f` of every scattering as not
    /// scattered; `live` are the points (voxel units) where the medium has density, `medium`
    /// gives σt, σs (per voxel length) and the sun's uncollided irradiance anywhere (0 outside
    /// the volume). `None` where there is nothing to do (no density, f = 0) or the grid would be
    /// coarser than `COARSEST`.
    pub fn build(
        travel: DVec3,
        g: f64,
        f: f64,
        live: impl Iterator<Item = DVec3>,
        medium: &(dyn Fn(DVec3) -> MediumSample + Sync),
    ) -> Option<ForwardCone> {
        if !(f > 0.0 && f < 1.0 && g > 0.0 && g < 1.0) {
            return None;
        }
        let w = travel.normalize();
        let u = w.any_orthonormal_vector();
        let v = w.cross(u);
        let axes = [u, v, w];
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for p in live {
            let a = DVec3::new(p.dot(u), p.dot(v), p.dot(w));
            lo = lo.min(a);
            hi = hi.max(a);
        }
        if !lo.is_finite() {
            return None;
        }
        // The trilinear density reaches a voxel beyond the last centres with density.
        lo -= DVec3::splat(2.0);
        hi += DVec3::splat(2.0);
        let cells = cone_cells(g, f, axes);
        let k = cells.len();
        let extent = hi - lo;
        let volume = extent.x * extent.y * extent.z;
        let h = FINEST.max((volume * (k + 1) as f64 / MOST_VALUES).cbrt());
        if h > COARSEST || k == 0 {
            return None;
        }
        let n = [0, 1, 2].map(|i| (extent[i] / h).ceil() as usize + 1);
        let origin = u * lo.x + v * lo.y + w * lo.z;
        let tan_max = cells.iter().map(|c| c.tangent.0.hypot(c.tangent.1)).fold(0.0, f64::max);
        let mut cone = ForwardCone {
            origin,
            axes,
            h,
            n,
            cells,
            g,
            cos_far: (tan_max.atan() + FAR).min(std::f64::consts::PI).cos(),
            light: Vec::new(),
        };
        // The real geometry less the straight line, both by the same march (module docs).
        let sampled = cone.sample(medium);
        let coupling = cone.coupling();
        let mut light = cone.march(&sampled, &coupling, false);
        let straight = cone.march(&sampled, &coupling, true);
        light.iter_mut().zip(&straight).for_each(|(a, b)| *a -= b);
        cone.light = light;
        Some(cone)
    }

    fn point(&self, a: usize, b: usize, c: usize) -> DVec3 {
        self.origin + (self.axes[0] * a as f64 + self.axes[1] * b as f64 + self.axes[2] * c as f64) * self.h
    }

    /// The medium on the grid, slice by slice: σt·h, σs·h (per grid step), σs·E·h and E*.
    fn sample(&self, medium: &(dyn Fn(DVec3) -> MediumSample + Sync)) -> Vec<(f32, f32, f32, f32)> {
        let [n0, n1, n2] = self.n;
        let slice = n0 * n1;
        (0..slice * n2)
            .into_par_iter()
            .map(|i| {
                let m = medium(self.point(i % n0, (i / n0) % n1, i / slice));
                let s = (m.sigma_s * self.h) as f32;
                ((m.sigma_t * self.h) as f32, s, (m.sigma_s * self.h * m.irradiance) as f32, m.scaled_irradiance as f32)
            })
            .collect()
    }

    /// Every cell's light (over E*) at every grid point: the march of the module docs through the
    /// `samples` of [`sample`](Self::sample) with the cells' `coupling`, each cell's light along
    /// its own direction or, `straight`, held on the sun's line.
    fn march(&self, samples: &[(f32, f32, f32, f32)], coupling: &[f64], straight: bool) -> Vec<f32> {
        let [n0, n1, n2] = self.n;
        let k = self.cells.len();
        let slice = n0 * n1;
        let travel = self.axes[2];
        let sun_share: Vec<f64> = self.cells.iter().map(|c| cell_phase(self.g, c, travel)).collect();
        let solid_angle: Vec<f64> = self.cells.iter().map(|c| c.samples.iter().map(|s| s.1).sum()).collect();
        let mut rays: Vec<Rays> =
            self.cells.iter().map(|c| Rays::new(if straight { (0.0, 0.0) } else { c.tangent }, self.n)).collect();
        let mut light = vec![0f32; slice * n2 * (k + 1)];
        let mut scattered = vec![vec![0f32; slice]; k];
        for c in 0..n2 {
            let at = &samples[c * slice..(c + 1) * slice];
            // Predictor: the scattered source held from the previous slice.
            let predicted: Vec<Vec<f32>> =
                rays.par_iter_mut().enumerate().map(|(j, r)| r.step(c, at, sun_share[j], None)).collect();
            // The cells' light scattered into every cell at this slice's points.
            scattered.par_iter_mut().enumerate().for_each(|(j, out)| {
                for (p, o) in out.iter_mut().enumerate() {
                    let sigma_s = at[p].1;
                    *o = if sigma_s > 0.0 {
                        let row = &coupling[j * k..(j + 1) * k];
                        (sigma_s as f64 * row.iter().zip(&predicted).map(|(c, l)| c * l[p] as f64).sum::<f64>()) as f32
                    } else {
                        0.0
                    };
                }
            });
            // Corrector: the trapezoid with this slice's scattered source.
            let corrected: Vec<Vec<f32>> = rays
                .par_iter_mut()
                .enumerate()
                .map(|(j, r)| r.step(c, at, sun_share[j], Some(&scattered[j])))
                .collect();
            for p in 0..slice {
                let scale = at[p].3 as f64;
                if !(scale > 0.0) {
                    continue;
                }
                let out = &mut light[(c * slice + p) * (k + 1)..(c * slice + p + 1) * (k + 1)];
                let mut flux = 0.0;
                for (j, cell) in corrected.iter().enumerate() {
                    out[j] = (cell[p] as f64 / scale) as f32;
                    flux += cell[p] as f64 * solid_angle[j];
                }
                out[k] = (flux / scale) as f32;
            }
        }
        light
    }

    /// `P_kj`, row k: the cell-averaged HG(g) from cell j's light into cell k, times cell j's
    /// solid angle (so that `Σ_j P_kj·L_j` is the radiance scattered into cell k per unit σs).
    fn coupling(&self) -> Vec<f64> {
        let k = self.cells.len();
        (0..k * k)
            .into_par_iter()
            .map(|i| {
                let (into, from) = (&self.cells[i / k], &self.cells[i % k]);
                let omega: f64 = into.samples.iter().map(|s| s.1).sum();
                let mut sum = 0.0;
                for &(a, wa) in &into.samples {
                    for &(b, wb) in &from.samples {
                        sum += henyey_greenstein(self.g, a.dot(b)) * wa * wb;
                    }
                }
                sum / omega
            })
            .collect()
    }

    /// The weights a camera ray whose light reaches the camera travelling along `towards` reads
    /// the cone with.
    pub fn weights(&self, towards: DVec3) -> ConeWeights {
        let mu = self.axes[2].dot(towards);
        let k = self.cells.len();
        if mu < self.cos_far {
            return ConeWeights { cells: vec![(k as u32, henyey_greenstein(self.g, mu))] };
        }
        let cells: Vec<(u32, f64)> = self
            .cells
            .iter()
            .enumerate()
            .map(|(j, c)| {
                (j as u32, c.samples.iter().map(|&(d, s)| henyey_greenstein(self.g, d.dot(towards)) * s).sum())
            })
            .collect();
        ConeWeights { cells }
    }

    /// How far the cone's light towards the camera at `p` (voxel units), with the real geometry,
    /// differs from the same cone's held on the sun's straight line: what the render adds to the
    /// chains and lobes (module docs). `scaled` is the sun's δ-M scaled irradiance E* there times
    /// the interpolated ρ·a, as the march reads it.
    pub fn lateral(&self, p: DVec3, weights: &ConeWeights, scaled: f64) -> f64 {
        scaled * self.light(p, weights)
    }

    /// `Σ_k W_k·ΔL_k/E*` at `p` (voxel units), trilinear between the grid points; 0 off the grid.
    fn light(&self, p: DVec3, weights: &ConeWeights) -> f64 {
        let d = p - self.origin;
        let q = DVec3::new(d.dot(self.axes[0]), d.dot(self.axes[1]), d.dot(self.axes[2])) / self.h;
        let base = q.floor();
        let frac = q - base;
        let stride = self.cells.len() + 1;
        let mut sum = 0.0;
        for corner in 0..8 {
            let o = [corner & 1, (corner >> 1) & 1, corner >> 2];
            let idx: [i64; 3] = std::array::from_fn(|i| base[i] as i64 + o[i] as i64);
            if (0..3).any(|i| idx[i] < 0 || idx[i] >= self.n[i] as i64) {
                continue;
            }
            let wt: f64 = (0..3).map(|i| if o[i] == 1 { frac[i] } else { 1.0 - frac[i] }).product();
            if wt == 0.0 {
                continue;
            }
            let at = (idx[0] as usize + self.n[0] * (idx[1] as usize + self.n[1] * idx[2] as usize)) * stride;
            let values = &self.light[at..at + stride];
            sum += wt * weights.cells.iter().map(|&(j, w)| w * values[j as usize] as f64).sum::<f64>();
        }
        sum
    }
}

/// The cone of one sun of a solved volume (`store`, its albedo factor `albedo`), `beam` its
/// uncollided irradiance kept at the voxels' centres, `medium` the true medium, `f` δ-M's
/// share, `channels` the irradiance's components: `None` unless the medium scatters alike in
/// every channel (one cone serves them all) and [`ForwardCone::build`] makes one.
pub fn sun_cone(
    store: &BrickStore,
    albedo: Option<&Field>,
    beam: &DirectBeam,
    medium: &Medium,
    f: f64,
    channels: u32,
) -> Option<ForwardCone> {
    let grey = (1..3).all(|ch| medium.sigma_t[ch] == medium.sigma_t[0] && medium.albedo[ch] == medium.albedo[0]);
    if !beam.at_centres || !grey {
        return None;
    }
    let grid = store.grid();
    let dims = grid.dims;
    let h = store.voxel_size();
    let (sigma_t, scatter) = (medium.sigma_t[0] * h, medium.sigma_t[0] * h * medium.albedo[0]);
    let live = store.occupied_bricks().flat_map(|b| {
        let origin = grid.brick_origin(grid.brick_coords(b));
        let data = store.density_brick(b).unwrap_or(&[]);
        data.iter().enumerate().filter(|(_, &r)| r > 0.0).map(move |(l, _)| {
            let local = [l % 16, (l / 16) % 16, l / 256];
            DVec3::new(
                (origin[0] as usize + local[0]) as f64 + 0.5,
                (origin[1] as usize + local[1]) as f64 + 0.5,
                (origin[2] as usize + local[2]) as f64 + 0.5,
            )
        })
    });
    let size = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
    let sample = |p: DVec3| {
        if p.cmplt(DVec3::ZERO).any() || p.cmpgt(size).any() {
            return MediumSample { sigma_t: 0.0, sigma_s: 0.0, irradiance: 0.0, scaled_irradiance: 0.0 };
        }
        // As the march reads them: ρ and ρ·a trilinear, E and E* in optical depth.
        let corners = trilinear(p, dims);
        let rho = corners.map(|(v, _)| store.density_at(v) as f64);
        let density: f64 = corners.iter().zip(&rho).map(|(&(_, w), r)| w * r).sum();
        let a = albedo.map_or([1.0; 8], |a| corners.map(|(v, _)| a.value(v, 0) as f64));
        let scattering: f64 = (0..8).map(|i| corners[i].1 * rho[i] * a[i]).sum();
        let weights: [f64; 8] = std::array::from_fn(|i| corners[i].1);
        let bricks = corner_bricks(beam.irradiance, &corners);
        let e = beam_irradiance(beam, &bricks, 0, channels, &corners, &weights)[0];
        let scaled = beam_irradiance(beam, &bricks, channels, channels, &corners, &weights)[0];
        MediumSample {
            sigma_t: sigma_t * density,
            sigma_s: scatter * scattering,
            irradiance: e,
            scaled_irradiance: scaled.max(e),
        }
    };
    ForwardCone::build(beam.travel, medium.g, f, live, &sample)
}

/// The cells of the cone for HG(g) with δ-M share f: its half-angle Θ holds the share f of one
/// scattering (HG's cumulative share within Θ), its cells squares of side δ on the tangent
/// plane, δ ≈ 1.2·(1 − g) (the forward lobe's width) between 0.06 and 0.12.
fn cone_cells(g: f64, f: f64, axes: [DVec3; 3]) -> Vec<Cell> {
    // ∫ within Θ of HG = (1 − g²)/(2g)·(1/(1 − g) − 1/√(1 + g² − 2g·cos Θ)) = f.
    let inv = 1.0 / (1.0 - g) - 2.0 * g * f / (1.0 - g * g);
    if inv <= 0.0 {
        return Vec::new();
    }
    let cos_theta = ((1.0 + g * g - 1.0 / (inv * inv)) / (2.0 * g)).clamp(-1.0, 1.0);
    let tan_max = cos_theta.acos().min(60f64.to_radians()).tan();
    let delta = (1.2 * (1.0 - g)).clamp(0.06, 0.12);
    let reach = (tan_max / delta).ceil() as i64;
    let [u, v, w] = axes;
    let mut cells = Vec::new();
    for i in -reach..=reach {
        for j in -reach..=reach {
            let (p, q) = (i as f64 * delta, j as f64 * delta);
            if p.hypot(q) > tan_max {
                continue;
            }
            let mut samples = Vec::with_capacity(SUBSAMPLES * SUBSAMPLES);
            for si in 0..SUBSAMPLES {
                for sj in 0..SUBSAMPLES {
                    let a = p + delta * ((si as f64 + 0.5) / SUBSAMPLES as f64 - 0.5);
                    let b = q + delta * ((sj as f64 + 0.5) / SUBSAMPLES as f64 - 0.5);
                    let r2 = 1.0 + a * a + b * b;
                    let solid = (delta / SUBSAMPLES as f64).powi(2) / (r2 * r2.sqrt());
                    samples.push(((w + u * a + v * b).normalize(), solid));
                }
            }
            cells.push(Cell { tangent: (p, q), samples });
        }
    }
    cells
}

/// The cell average of HG(g) from a beam along `travel` into `cell`.
fn cell_phase(g: f64, cell: &Cell, travel: DVec3) -> f64 {
    let omega: f64 = cell.samples.iter().map(|s| s.1).sum();
    cell.samples.iter().map(|&(d, s)| henyey_greenstein(g, d.dot(travel)) * s).sum::<f64>() / omega
}

/// One cell's rays: a lattice across the sun's direction that moves sideways by the cell's
/// tangent each slice, each ray carrying its radiance and the medium it saw at the last slice.
struct Rays {
    tangent: (f64, f64),
    margin: i64,
    size: [usize; 2],
    grid: [usize; 2],
    radiance: Vec<f64>,
    /// Per ray: (σt·h, total source per step) at the previous slice, and the scattered part of it.
    previous: Vec<(f64, f64, f64)>,
    started: bool,
}

impl Rays {
    fn new(tangent: (f64, f64), n: [usize; 3]) -> Rays {
        let margin = (tangent.0.abs().max(tangent.1.abs()) * n[2] as f64).ceil() as i64 + 2;
        let size = [n[0] + 2 * margin as usize, n[1] + 2 * margin as usize];
        Rays {
            tangent,
            margin,
            size,
            grid: [n[0], n[1]],
            radiance: vec![0.0; size[0] * size[1]],
            previous: vec![(0.0, 0.0, 0.0); size[0] * size[1]],
            started: false,
        }
    }

    /// The rays' position on slice `c` (grid units across the sun) of ray (i, j).
    fn position(&self, i: usize, j: usize, c: usize) -> (f64, f64) {
        (
            i as f64 - self.margin as f64 + self.tangent.0 * c as f64,
            j as f64 - self.margin as f64 + self.tangent.1 * c as f64,
        )
    }

    /// Advances every ray to slice `c` (`at`: the slice's (σt·h, σs·h, σs·E·h) per point), with
    /// the cell's share of the sun's scattering `sun` and the scattered source per point
    /// `scattered` (None: the predictor, which holds the previous slice's scattered source), and
    /// returns the cell's radiance at the slice's grid points. The corrector's call keeps the
    /// new state; the predictor's leaves it as it was.
    fn step(&mut self, c: usize, at: &[(f32, f32, f32, f32)], sun: f64, scattered: Option<&[f32]>) -> Vec<f32> {
        let [g0, g1] = self.grid;
        let mut next = vec![0f64; self.radiance.len()];
        let mut state = vec![(0.0, 0.0, 0.0); self.radiance.len()];
        let slope = (1.0 + self.tangent.0 * self.tangent.0 + self.tangent.1 * self.tangent.1).sqrt();
        for j in 0..self.size[1] {
            for i in 0..self.size[0] {
                let r = i + self.size[0] * j;
                let (x, y) = self.position(i, j, c);
                let sigma = bilinear(g0, g1, x, y, |p| at[p].0 as f64);
                let sun_source = bilinear(g0, g1, x, y, |p| at[p].2 as f64);
                let scat = match scattered {
                    Some(q) => bilinear(g0, g1, x, y, |p| q[p] as f64),
                    None => self.previous[r].2,
                };
                let sigma = sigma * slope;
                let source = (sun_source * sun + scat) * slope;
                let (prev_sigma, prev_source, _) = self.previous[r];
                next[r] = if self.started {
                    let tau = 0.5 * (prev_sigma + sigma);
                    self.radiance[r] * (-tau).exp() + step_source(prev_source, source, tau)
                } else {
                    0.0
                };
                state[r] = (sigma, source, scat);
            }
        }
        // The cell's light at the grid points from the rays around each.
        let mut out = vec![0f32; g0 * g1];
        for b in 0..g1 {
            for a in 0..g0 {
                let x = a as f64 + self.margin as f64 - self.tangent.0 * c as f64;
                let y = b as f64 + self.margin as f64 - self.tangent.1 * c as f64;
                let (i0, j0) = (x.floor(), y.floor());
                let (fx, fy) = (x - i0, y - j0);
                let (i0, j0) = (i0 as usize, j0 as usize);
                let ray = |i: usize, j: usize| next.get(i + self.size[0] * j).copied().unwrap_or(0.0);
                let v = ray(i0, j0) * (1.0 - fx) * (1.0 - fy)
                    + ray(i0 + 1, j0) * fx * (1.0 - fy)
                    + ray(i0, j0 + 1) * (1.0 - fx) * fy
                    + ray(i0 + 1, j0 + 1) * fx * fy;
                out[a + g0 * b] = v as f32;
            }
        }
        if scattered.is_some() {
            self.radiance = next;
            self.previous = state;
            self.started = true;
        }
        out
    }
}

/// `∫₀¹ Q(s)·e^{−τ(1−s)} ds` over one step whose source goes from `q0` to `q1` (per step):
/// exponentially where both are positive (the sun's light falls so along its path, and a
/// trapezoid overstates each order's light by ~τ²/12, 1.3 % a step at τ = 0.4, compounding over
/// the orders), linearly otherwise; the optical depth τ of the step attenuates it on the way.
fn step_source(q0: f64, q1: f64, tau: f64) -> f64 {
    let fade = (-tau).exp();
    if q0 > 0.0 && q1 > 0.0 {
        let d = tau - (q0 / q1).ln();
        let growth = if d.abs() < 1e-9 { 1.0 } else { d.exp_m1() / d };
        return q0 * fade * growth;
    }
    // ∫ t·e^{−τt} dt and ∫ e^{−τt} dt over [0, 1].
    let (a, b) = if tau < 1e-4 {
        (0.5 - tau / 3.0, 1.0 - 0.5 * tau)
    } else {
        ((1.0 - fade * (1.0 + tau)) / (tau * tau), -(-tau).exp_m1() / tau)
    };
    q0 * a + q1 * (b - a)
}

/// Bilinear interpolation on a slice of `g0 × g1` points at grid position (x, y) of the values
/// `value(point index)`; 0 outside.
fn bilinear(g0: usize, g1: usize, x: f64, y: f64, value: impl Fn(usize) -> f64) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let mut out = 0.0;
    for (dx, dy, wt) in
        [(0, 0, (1.0 - fx) * (1.0 - fy)), (1, 0, fx * (1.0 - fy)), (0, 1, (1.0 - fx) * fy), (1, 1, fx * fy)]
    {
        let (a, b) = (x0 + dx, y0 + dy);
        if a < 0 || b < 0 || a >= g0 as i64 || b >= g1 as i64 || wt == 0.0 {
            continue;
        }
        out += wt * value(a as usize + g0 * b as usize);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sun along −z over a block of uniform medium (σt per voxel, albedo 1) `[0, wide]² ×
    /// [0, deep]` under irradiance 1, the cone of HG(0.8) with δ-M share 0.5.
    fn block(wide: f64, deep: f64, sigma: f64) -> (ForwardCone, impl Fn(DVec3) -> MediumSample) {
        let inside =
            move |p: DVec3| p.x >= 0.0 && p.y >= 0.0 && p.x <= wide && p.y <= wide && p.z >= 0.0 && p.z <= deep;
        let medium = move |p: DVec3| {
            let s = if inside(p) { sigma } else { 0.0 };
            // Depth below the top face along the sun's path, through the block only.
            let depth = if p.x >= 0.0 && p.y >= 0.0 && p.x <= wide && p.y <= wide {
                (deep - p.z).clamp(0.0, deep)
            } else {
                0.0
            };
            let e = (-sigma * depth).exp();
            MediumSample { sigma_t: s, sigma_s: s, irradiance: e, scaled_irradiance: (-0.5 * sigma * depth).exp() }
        };
        let mut live = Vec::new();
        for z in 0..deep as usize {
            for y in 0..wide as usize {
                for x in 0..wide as usize {
                    live.push(DVec3::new(x as f64 + 0.5, y as f64 + 0.5, z as f64 + 0.5));
                }
            }
        }
        let cone = ForwardCone::build(DVec3::NEG_Z, 0.8, 0.5, live.into_iter(), &medium).expect("a cone");
        (cone, medium)
    }

    /// The cone's light with the real geometry over the same held on the sun's line, looking up
    /// the sun's path at `p`: both marches, read at `p` with the camera's weights.
    fn real_over_line(cone: &ForwardCone, medium: &(dyn Fn(DVec3) -> MediumSample + Sync), p: DVec3) -> f64 {
        let weights = cone.weights(DVec3::Z);
        let read = |light: Vec<f32>| ForwardCone { light, ..cone.clone() }.light(p, &weights);
        let (sampled, coupling) = (cone.sample(medium), cone.coupling());
        read(cone.march(&sampled, &coupling, false)) / read(cone.march(&sampled, &coupling, true))
    }

    #[test]
    fn the_cone_holds_the_share_delta_m_takes_as_unscattered() {
        for (g, f) in [(0.8, 0.58), (0.95, 0.87)] {
            let cells = cone_cells(g, f, [DVec3::X, DVec3::Y, DVec3::Z]);
            let held: f64 =
                cells.iter().map(|c| cell_phase(g, c, DVec3::Z) * c.samples.iter().map(|s| s.1).sum::<f64>()).sum();
            // The square cells (δ = 0.12 at g 0.8) approximate the cone's circle to a few per cent.
            assert!((held / f - 1.0).abs() < 0.05, "g {g}: the cone holds {held} of a scattering, δ-M {f}");
        }
    }

    #[test]
    fn a_step_takes_an_exponential_source_exactly() {
        // q(s) = 2·e^{−0.7 s} under attenuation e^{−0.4 (1 − s)}: ∫₀¹ by a fine midpoint sum.
        let (q0, kappa, tau) = (2.0, 0.7, 0.4);
        let n = 100_000;
        let fine: f64 = (0..n)
            .map(|i| {
                let s = (i as f64 + 0.5) / n as f64;
                q0 * (-kappa * s).exp() * (-tau * (1.0 - s)).exp() / n as f64
            })
            .sum();
        let step = step_source(q0, q0 * (-kappa).exp(), tau);
        assert!((step / fine - 1.0).abs() < 1e-8, "{step} against {fine}");
        // A source that starts at 0 (entering the medium): linear, still close.
        let linear = step_source(0.0, 1.0, 0.3);
        assert!(linear > 0.0 && linear < 0.5);
    }

    #[test]
    fn deep_in_a_wide_block_the_geometry_changes_little_and_a_thin_column_loses_its_light_sideways() {
        let (cone, medium) = block(24.0, 12.0, 0.5);
        let centre = real_over_line(&cone, &medium, DVec3::new(12.0, 12.0, 4.0));
        // Far from the sides only the slanted paths (longer per depth: more scattering, more
        // extinction) differ from the straight line.
        assert!((0.97..1.03).contains(&centre), "wide block: real/line {centre}");
        let (column, medium) = block(2.0, 12.0, 0.5);
        let thin = real_over_line(&column, &medium, DVec3::new(1.0, 1.0, 4.0));
        assert!(thin < 0.8 * centre, "a 2-voxel column keeps {thin} of the straight line's light");
    }

    #[test]
    fn the_march_is_the_same_run_to_run() {
        let (a, _) = block(6.0, 6.0, 0.8);
        let (b, _) = block(6.0, 6.0, 0.8);
        assert!(a.light.iter().zip(&b.light).all(|(x, y)| x.to_bits() == y.to_bits()));
        assert!(a.light.iter().any(|&x| x > 0.0));
    }
}
