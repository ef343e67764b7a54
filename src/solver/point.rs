//! Point lights (`[[lights]] kind = "point"`): their uncollided light, computed exactly on the
//! host, and its first scattering, order 0's share of the next source.
//!
//! A point light is a delta in position, so no fixed set of directions represents it (ray
//! effects), just as the sun is a delta in direction. Like the sun's beam sweep, its uncollided
//! light is computed exactly along its own rays, here from the point to every voxel: the
//! irradiance at voxel v is
//!
//! `E(v) = I·T(p → x_v)/|p − x_v|²`
//!
//! with `T` the exact transmittance of the straight segment from the light to the voxel's centre
//! through the piecewise-constant densities (a 3-D DDA over the voxels the segment crosses,
//! [`optical_path`]; outside the volume and in empty bricks there is no medium), with the plan's
//! σt (after δ-M scaling, as for the sun). Where the light sits inside or next to a voxel the
//! centre value says little about the voxel (1/r² is singular at the light), so a voxel whose
//! centre lies closer than [`NEAR_VOXELS`] voxel edges to the light takes the voxel's mean of
//! `I·T/r²` (what a track-length estimate of the fluence measures): the voxel is split into cells,
//! a cell split again in eight while the light is within [`NEAR_REFINE`] of its edges (at most
//! [`NEAR_DEPTH`] times), and each cell contributes its volume times the value at its centre; the
//! finest cell around the light itself, where 1/r² is singular but integrable, contributes
//! `4π·R·T` (the integral of 1/r² over a ball of the same volume, radius R, centred on the light).
//! A voxel [`NEAR_VOXELS`] or more away is one such cell: its centre value, which lies below the
//! voxel's mean by about `(h/r)²/4 + (σt·h)²/24` (1/r² and the attenuation are convex along the
//! ray): ~1 % six voxels from the light at σt·h = 0.25, measured against the Monte-Carlo
//! reference, which tallies voxel means.
//!
//! Written once here for both backends, before order 0, into the fields order 0 accumulates:
//! - the fluence: `E(v)` is the light's uncollided fluence, and goes into order 0's fluence (as the
//!   sun's beam sweep deposits its uncollided fluence there);
//! - the scattered source: `J_d(v) = ρ(v)·σs·E(v)·row_d(ω(v))`, with ω(v) the direction of travel
//!   light → voxel and `row` the discrete phase row of a beam travelling along ω
//!   ([`crate::quadrature::phase::BeamRows`], as the plan's sun beams use; for an anisotropic
//!   medium tabulated over directions and interpolated, `RowTable`; for an isotropic one `1/4π`),
//!   goes into order 0's new source, so order 1 propagates it as it propagates the sun's first
//!   scattering, and the source total (what the renderer integrates) holds it. Near the light the
//!   row is that of the cells' irradiance-weighted mean direction of travel, blended with the
//!   isotropic row by `1 − |mean flux|/E`: a light at the voxel's centre lights it from every side
//!   alike.
//!
//! The GPU driver's fields are the store's f32 files; the CPU twin copies the very same f32
//! values into its own (see [`super::cpu::CpuTwin::set_order0_accumulators`]).
//!
//! Energy: the power a point light gives the medium is `Σ_v ρσt·E·h³` per channel, counted from
//! the stored values — its σa part `Σ ρσa·E·h³` (absorbed through the fluence) and its σs part
//! `Σ_d Ω_d·J_d·h³` (order 0's new source) — and enters the energy books as an input
//! ([`super::energy::EnergyBalance::point_lights`]). Light that crosses the volume without
//! interacting, or never reaches it, is in neither side of the books, and the per-face tallies
//! do not hold the uncollided point light (it does not cross the faces as rays do).
//!
//! Computed brick by brick over the occupied bricks only, in parallel (rayon), straight into the
//! memory-mapped fields in groups of [`RELEASE_UNITS`] bricks whose pages are then handed back: a
//! store far larger than RAM never becomes a dense array. Each voxel's values depend on nothing
//! but the scene, so the fields are bitwise the same at any thread count. The cost is one segment
//! walk per voxel and light, ∝ N⁴ for an N³ volume (benches/RESULTS.md, "Point lights": 39 s for
//! two lights over 256³ on two shared cores).

use super::passes::RELEASE_UNITS;
use super::plan::Plan;
use super::SolveError;
use crate::quadrature::phase::BeamRows;
use crate::store::{BrickStore, Field, BRICK_EDGE, BRICK_VOXELS};
use glam::DVec3;
use rayon::prelude::*;

/// Voxel centres closer to the light than this many voxel edges take the voxel's mean.
pub const NEAR_VOXELS: f64 = NEAR_REFINE;
/// A cell of the near voxel's mean is split in eight while its centre is closer to the light than
/// this many cell edges: the midpoint rule's relative error on 1/r² is about (edge/r)²/12, below
/// 0.5 % per cell.
pub const NEAR_REFINE: f64 = 4.0;
/// Most halvings of a near voxel's cells (cells down to 2⁻¹⁰ voxel edges around the light).
pub const NEAR_DEPTH: u32 = 10;

/// A point light in the solver's frame: `position` in voxel units (volume corner at 0),
/// `intensity` in W/sr per channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointLight {
    pub position: DVec3,
    pub intensity: [f64; 3],
}

/// ∫ρ ds along the straight segment from `a` to `b` (voxel units, both anywhere), through the
/// voxels of a `dims` volume whose densities `density` gives: the segment is clipped to the
/// volume and its voxels walked with an exact 3-D DDA (Amanatides–Woo); the result is in voxel
/// units (multiply by σt·h for the optical depth).
pub fn optical_path(dims: [u32; 3], density: &impl Fn([u32; 3]) -> f32, a: DVec3, b: DVec3) -> f64 {
    let cells = |c: [i64; 3]| density([c[0] as u32, c[1] as u32, c[2] as u32]);
    optical_path_in([0; 3], dims.map(|n| n as i64), &cells, a, b)
}

/// [`optical_path`] through the box of cells `lo..hi` per axis (which may start below 0: the
/// frame a volume unfolded by its mirror images lives in, [`super::uncollided`]); `density` takes
/// the cell's index in that frame. With `lo` = 0 and `hi` = dims the same arithmetic, so the same
/// bits, as [`optical_path`].
pub(crate) fn optical_path_in(
    lo: [i64; 3],
    hi: [i64; 3],
    density: &impl Fn([i64; 3]) -> f32,
    a: DVec3,
    b: DVec3,
) -> f64 {
    let d = b - a;
    let len = d.length();
    if !(len > 0.0) {
        return 0.0;
    }
    let dir = d / len;
    let low = DVec3::new(lo[0] as f64, lo[1] as f64, lo[2] as f64);
    let size = DVec3::new(hi[0] as f64, hi[1] as f64, hi[2] as f64);
    let (mut t0, mut t1) = (0.0f64, len);
    for axis in 0..3 {
        if dir[axis] == 0.0 {
            if a[axis] < low[axis] || a[axis] > size[axis] {
                return 0.0;
            }
        } else {
            let (ta, tb) = ((low[axis] - a[axis]) / dir[axis], (size[axis] - a[axis]) / dir[axis]);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    if !(t0 < t1) {
        return 0.0;
    }
    let start = a + dir * t0;
    let mut cell = [0i64; 3];
    let mut t_max = [f64::INFINITY; 3];
    let mut t_delta = [f64::INFINITY; 3];
    let mut step = [0i64; 3];
    for axis in 0..3 {
        let mut c = start[axis].floor();
        // On a boundary and travelling down: the segment lies in the cell below.
        if dir[axis] < 0.0 && c == start[axis] {
            c -= 1.0;
        }
        cell[axis] = (c as i64).clamp(lo[axis], hi[axis] - 1);
        if dir[axis] > 0.0 {
            step[axis] = 1;
            t_max[axis] = (cell[axis] as f64 + 1.0 - a[axis]) / dir[axis];
            t_delta[axis] = 1.0 / dir[axis];
        } else if dir[axis] < 0.0 {
            step[axis] = -1;
            t_max[axis] = (cell[axis] as f64 - a[axis]) / dir[axis];
            t_delta[axis] = -1.0 / dir[axis];
        }
    }
    let mut t = t0;
    let mut sum = 0.0;
    loop {
        let axis = if t_max[0] <= t_max[1] && t_max[0] <= t_max[2] {
            0
        } else if t_max[1] <= t_max[2] {
            1
        } else {
            2
        };
        let t_next = t_max[axis].min(t1);
        if t_next > t {
            let rho = density(cell);
            sum += rho as f64 * (t_next - t);
            t = t_next;
        }
        if t >= t1 {
            break;
        }
        cell[axis] += step[axis];
        if cell[axis] < lo[axis] || cell[axis] >= hi[axis] {
            break;
        }
        t_max[axis] += t_delta[axis];
    }
    sum
}

/// What one light gives one voxel: the irradiance per channel (W/m²) and the direction of travel
/// with the weight of its row (1: a beam along it; 0: isotropic, see the module docs).
struct Arrival {
    irradiance: [f64; 3],
    travel: DVec3,
    directed: f64,
}

/// The light's arrival at the voxel whose centre is `x` (voxel units). `extinction[ch]` is σt·h
/// at density 1 (per voxel unit of length), `h` the voxel edge in world units.
fn arrival(
    light: &PointLight,
    x: DVec3,
    h: f64,
    extinction: [f64; 3],
    channels: usize,
    path: &impl Fn(DVec3, DVec3) -> f64,
) -> Arrival {
    let r = x - light.position;
    let at = |q: DVec3, r2: f64| {
        let tau = path(light.position, q);
        let mut e = [0.0; 3];
        for ch in 0..channels {
            e[ch] = light.intensity[ch] * (-extinction[ch] * tau).exp() / (r2 * h * h);
        }
        e
    };
    if r.length() >= NEAR_VOXELS {
        return Arrival { irradiance: at(x, r.length_squared()), travel: r.normalize(), directed: 1.0 };
    }
    // The voxel's mean of I·T/r² (the voxel has volume 1 in voxel units): cells refined around
    // the light, each a midpoint value times its volume.
    let mut sum = [0.0; 3];
    let mut flux = DVec3::ZERO;
    let mut stack = vec![(x, 1.0f64, 0u32)];
    while let Some((c, size, depth)) = stack.pop() {
        let rc = c - light.position;
        let d = rc.length();
        if d < NEAR_REFINE * size && depth < NEAR_DEPTH {
            let q = 0.25 * size;
            for k in [-q, q] {
                for j in [-q, q] {
                    for i in [-q, q] {
                        stack.push((c + DVec3::new(i, j, k), 0.5 * size, depth + 1));
                    }
                }
            }
            continue;
        }
        let volume = size * size * size;
        // ∫ dV/r² over the cell: its midpoint value, or, for the finest cell around the light
        // itself, that of the ball of the same volume centred on the light (4π·R).
        let weight = if d < 0.5 * size * 3f64.sqrt() {
            4.0 * std::f64::consts::PI * size * (3.0 / (4.0 * std::f64::consts::PI)).cbrt()
        } else {
            volume / (d * d)
        };
        let e = at(c, 1.0);
        for ch in 0..channels {
            sum[ch] += e[ch] * weight;
        }
        if d > 0.0 {
            flux += rc / d * e[..channels].iter().sum::<f64>() * weight;
        }
    }
    let irradiance = sum;
    let total: f64 = sum[..channels].iter().sum();
    let (travel, directed) = if total > 0.0 && flux.length() > 0.0 {
        (flux.normalize(), (flux.length() / total).min(1.0))
    } else {
        (DVec3::Z, 0.0)
    };
    Arrival { irradiance, travel, directed }
}

/// Most table values of [`RowTable`] (8 Mi f64: 64 MiB).
const ROW_TABLE_VALUES: usize = 1 << 23;

/// The phase row of a beam by its direction of travel, for an anisotropic medium: computed exactly
/// ([`BeamRows::row`], a fine quadrature of the sphere, thousands of phase evaluations) at the
/// nodes of an n×n grid on each cube face (n up to 65, fewer when there are many storage
/// directions), and interpolated bilinearly in between. A convex combination of rows is a row
/// (`Σ_d Ω_d·row_d = 1` holds for each), so the interpolation keeps the scattered power exact; it
/// makes a point light's first scattering cost a few multiplications per voxel instead of a
/// quadrature of the sphere.
pub(crate) struct RowTable {
    n: usize,
    s: usize,
    /// `[face][v][u][d]`, face = 2·axis + (direction positive).
    rows: Vec<f64>,
}

impl RowTable {
    pub(crate) fn new(exact: &BeamRows) -> RowTable {
        let s = exact.storage_len();
        let n = ((ROW_TABLE_VALUES / (6 * s)) as f64).sqrt().floor().clamp(5.0, 65.0) as usize;
        let nodes: Vec<(usize, usize, usize)> =
            (0..6).flat_map(|f| (0..n).flat_map(move |j| (0..n).map(move |i| (f, j, i)))).collect();
        let rows = nodes
            .par_iter()
            .flat_map_iter(|&(f, j, i)| {
                let at = |k: usize| -1.0 + 2.0 * k as f64 / (n - 1) as f64;
                exact.row(face_direction(f, at(i), at(j)))
            })
            .collect();
        RowTable { n, s, rows }
    }

    /// The interpolated row of a beam travelling along `travel` (unit length), into `out`.
    pub(crate) fn row_into(&self, travel: DVec3, out: &mut [f64]) {
        let (f, u, v) = face_coordinates(travel);
        let last = (self.n - 1) as f64;
        let (x, y) = ((u + 1.0) * 0.5 * last, (v + 1.0) * 0.5 * last);
        let (i, j) = ((x.floor().max(0.0) as usize).min(self.n - 2), (y.floor().max(0.0) as usize).min(self.n - 2));
        let (a, b) = ((x - i as f64).clamp(0.0, 1.0), (y - j as f64).clamp(0.0, 1.0));
        let node = |i: usize, j: usize| {
            let k = ((f * self.n + j) * self.n + i) * self.s;
            &self.rows[k..k + self.s]
        };
        let corners = [
            (node(i, j), (1.0 - a) * (1.0 - b)),
            (node(i + 1, j), a * (1.0 - b)),
            (node(i, j + 1), (1.0 - a) * b),
            (node(i + 1, j + 1), a * b),
        ];
        for (d, o) in out.iter_mut().enumerate() {
            *o = corners.iter().map(|(row, w)| w * row[d]).sum();
        }
    }
}

/// The unit direction at (u, v) ∈ [−1, 1]² of cube face `f` (2·axis + positive).
fn face_direction(f: usize, u: f64, v: f64) -> DVec3 {
    let axis = f / 2;
    let mut d = DVec3::ZERO;
    d[axis] = if f % 2 == 1 { 1.0 } else { -1.0 };
    d[(axis + 1) % 3] = u;
    d[(axis + 2) % 3] = v;
    d.normalize()
}

/// The cube face of `d` (its largest component) and the coordinates (u, v) of `d` on it:
/// the inverse of [`face_direction`].
fn face_coordinates(d: DVec3) -> (usize, f64, f64) {
    let a = d.abs();
    let axis = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    let m = a[axis];
    let f = 2 * axis + (d[axis] > 0.0) as usize;
    (f, d[(axis + 1) % 3] / m, d[(axis + 2) % 3] / m)
}

/// Writes the point lights' order-0 contributions ([module docs](self)) into `fluence` (order
/// 0's fluence) and `source_next` (order 0's new source), both fresh (zero), over the occupied
/// bricks. Returns the power the lights give the medium per channel, `Σ ρσt·E·h³`, counted from
/// the f32 values written.
pub fn write_order0(
    store: &BrickStore,
    plan: &Plan,
    fluence: &mut Field,
    source_next: &mut Field,
) -> Result<[f64; 3], SolveError> {
    if plan.point_lights.is_empty() {
        return Ok([0.0; 3]);
    }
    let c = plan.channels as usize;
    let comps = plan.source_components() as usize;
    let h = plan.voxel_size;
    let h3 = h * h * h;
    let grid = *store.grid();
    let dims = grid.dims;
    let coefficients: Vec<(f64, f64, f64)> = (0..c).map(|ch| plan.coefficients(ch)).collect();
    let mut extinction = [0.0; 3];
    for ch in 0..c {
        extinction[ch] = coefficients[ch].0 * h;
    }
    let exact = BeamRows::new(&plan.propagation, &plan.storage, &plan.phase);
    let isotropic = exact.isotropic_row();
    let table = (!exact.is_isotropic()).then(|| RowTable::new(&exact));
    let density = |v: [u32; 3]| store.density_at(v);
    let path = |a: DVec3, b: DVec3| optical_path(dims, &density, a, b);
    let storage = plan.storage.solid_angle.clone();
    let bricks: Vec<usize> = store.occupied_bricks().collect();
    let mut power = [0.0f64; 3];
    // One brick: its fluence and source blocks (component-major), and its power per channel.
    let brick_pass = |brick: usize, fl: &mut [f32], src: &mut [f32]| -> [f64; 3] {
        let mut p = [0.0f64; 3];
        let Some(rho) = store.density_brick(brick) else { return p };
        let b = grid.brick_coords(brick);
        let origin = grid.brick_origin(b);
        let extent = grid.brick_extent(b);
        let mut j = vec![0.0f64; comps];
        let mut directed = isotropic.clone();
        for lz in 0..extent[2] as usize {
            for ly in 0..extent[1] as usize {
                for lx in 0..extent[0] as usize {
                    let local = lx + BRICK_EDGE as usize * (ly + BRICK_EDGE as usize * lz);
                    let v = [origin[0] + lx as u32, origin[1] + ly as u32, origin[2] + lz as u32];
                    let x = DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64) + 0.5;
                    let density = rho[local] as f64;
                    let mut e = [0.0f64; 3];
                    j.iter_mut().for_each(|x| *x = 0.0);
                    for light in &plan.point_lights {
                        let a = arrival(light, x, h, extinction, c, &path);
                        for ch in 0..c {
                            e[ch] += a.irradiance[ch];
                        }
                        let scatters = (0..c).any(|ch| coefficients[ch].1 > 0.0 && a.irradiance[ch] > 0.0);
                        if density > 0.0 && scatters {
                            if let (Some(table), true) = (&table, a.directed > 0.0) {
                                table.row_into(a.travel, &mut directed);
                            }
                            for (d, (&rd, &ri)) in directed.iter().zip(&isotropic).enumerate() {
                                let row = a.directed * rd + (1.0 - a.directed) * ri;
                                for ch in 0..c {
                                    j[d * c + ch] += density * coefficients[ch].1 * a.irradiance[ch] * row;
                                }
                            }
                        }
                    }
                    for ch in 0..c {
                        let stored = e[ch] as f32;
                        fl[ch * BRICK_VOXELS + local] = stored;
                        p[ch] += density * coefficients[ch].2 * stored as f64 * h3;
                    }
                    for (k, &value) in j.iter().enumerate() {
                        let stored = value as f32;
                        src[k * BRICK_VOXELS + local] = stored;
                        p[k % c] += storage[k / c] * stored as f64 * h3;
                    }
                }
            }
        }
        p
    };
    let (fl_len, src_len) = (c * BRICK_VOXELS, comps * BRICK_VOXELS);
    for first in (0..bricks.len()).step_by(RELEASE_UNITS) {
        let last = (first + RELEASE_UNITS).min(bricks.len());
        let fl = &mut fluence.as_mut_slice()[first * fl_len..last * fl_len];
        let src = &mut source_next.as_mut_slice()[first * src_len..last * src_len];
        let powers: Vec<[f64; 3]> = fl
            .par_chunks_mut(fl_len)
            .zip(src.par_chunks_mut(src_len))
            .zip(&bricks[first..last])
            .map(|((fl, src), &brick)| brick_pass(brick, fl, src))
            .collect();
        // Summed in slot order: the same at any thread count.
        for p in powers {
            for ch in 0..c {
                power[ch] += p[ch];
            }
        }
        fluence.release_stored(first, RELEASE_UNITS);
        source_next.release_stored(first, RELEASE_UNITS);
        store.release_all_density();
    }
    fluence.flush()?;
    source_next.flush()?;
    Ok(power)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn uniform(dims: [u32; 3]) -> impl Fn([u32; 3]) -> f32 {
        move |v: [u32; 3]| {
            assert!(v[0] < dims[0] && v[1] < dims[1] && v[2] < dims[2], "{v:?} outside {dims:?}");
            1.0
        }
    }

    #[test]
    fn the_path_through_a_uniform_volume_is_the_clipped_length() {
        let dims = [7, 5, 9];
        let density = uniform(dims);
        // Inside to inside, slanted.
        let (a, b) = (DVec3::new(0.3, 0.2, 0.7), DVec3::new(6.1, 4.9, 8.5));
        assert!((optical_path(dims, &density, a, b) - (b - a).length()).abs() < 1e-12);
        // From outside: only the part inside counts. The segment enters x = 0 at t where
        // -3 + t·dx = 0.
        let (a, b) = (DVec3::new(-3.0, 2.5, 4.5), DVec3::new(3.5, 2.5, 4.5));
        assert!((optical_path(dims, &density, a, b) - 3.5).abs() < 1e-12);
        // Travelling down along an axis from a cell boundary, and both ends outside.
        let (a, b) = (DVec3::new(2.0, 3.0, 20.0), DVec3::new(2.0, 3.0, -4.0));
        assert!((optical_path(dims, &density, a, b) - 9.0).abs() < 1e-12);
        // Missing the volume.
        assert_eq!(optical_path(dims, &density, DVec3::new(-1.0, -1.0, 0.0), DVec3::new(-1.0, 9.0, 3.0)), 0.0);
        assert_eq!(optical_path(dims, &density, a, a), 0.0);
    }

    #[test]
    fn the_path_weights_each_crossed_voxel_by_its_length() {
        // Density x + 1 along x: a segment along x from 0.5 to 3.25 crosses 0.5 of voxel 0,
        // 1 of voxels 1 and 2 and 0.25 of voxel 3.
        let dims = [4, 1, 1];
        let density = |v: [u32; 3]| v[0] as f32 + 1.0;
        let got = optical_path(dims, &density, DVec3::new(0.5, 0.5, 0.5), DVec3::new(3.25, 0.5, 0.5));
        assert!((got - (0.5 * 1.0 + 2.0 + 3.0 + 0.25 * 4.0)).abs() < 1e-12, "{got}");
        // The same backwards, and diagonally across the cell corners of a uniform slab.
        let back = optical_path(dims, &density, DVec3::new(3.25, 0.5, 0.5), DVec3::new(0.5, 0.5, 0.5));
        assert!((back - got).abs() < 1e-12);
        let dims = [5, 5, 5];
        let diag = optical_path(dims, &uniform(dims), DVec3::ZERO, DVec3::splat(5.0));
        assert!((diag - 75f64.sqrt()).abs() < 1e-12, "{diag}");
    }

    #[test]
    fn the_row_table_keeps_the_power_and_follows_the_exact_rows() {
        use crate::quadrature::{phase::Phase, PropagationSet, StorageSet};
        let prop = PropagationSet::new(3);
        let storage = StorageSet::per_face(&prop, 2);
        let exact = BeamRows::new(&prop, &storage, &Phase::HenyeyGreenstein { g: 0.7 });
        let table = RowTable::new(&exact);
        let mut row = vec![0.0; storage.len()];
        for (i, travel) in
            [DVec3::new(0.3, -0.8, 0.2), DVec3::new(-1.0, 1.0, 1.0), DVec3::new(0.0, 0.01, -1.0), DVec3::X]
                .into_iter()
                .enumerate()
        {
            let travel = travel.normalize();
            let (f, u, v) = face_coordinates(travel);
            assert!((face_direction(f, u, v) - travel).length() < 1e-12, "{i}");
            table.row_into(travel, &mut row);
            let power: f64 = row.iter().zip(&storage.solid_angle).map(|(r, w)| r * w).sum();
            assert!((power - 1.0).abs() < 1e-12, "{i}: {power}");
            let want = exact.row(travel);
            let peak = want.iter().cloned().fold(0.0, f64::max);
            for (a, b) in row.iter().zip(&want) {
                assert!((a - b).abs() < 5e-3 * peak, "{i}: {row:?} vs {want:?}");
            }
        }
    }

    #[test]
    fn far_voxels_take_the_centre_value_and_near_ones_a_finite_mean() {
        let light = PointLight { position: DVec3::new(0.5, 0.5, 0.5), intensity: [2.0, 2.0, 2.0] };
        let vacuum = |_: DVec3, _: DVec3| 0.0;
        let far = arrival(&light, DVec3::new(4.5, 0.5, 0.5), 0.5, [0.0; 3], 1, &vacuum);
        assert!((far.irradiance[0] - 2.0 / (16.0 * 0.25)).abs() < 1e-15);
        assert_eq!(far.directed, 1.0);
        assert!((far.travel - DVec3::X).length() < 1e-15);
        // The light at the voxel's centre: the mean of 2/r² over the unit cube around it, which
        // by the divergence theorem (∇·(r/r²) = 1/r²) is 2 × 6 faces × ∫∫ ½/(¼ + x² + y²) dx dy.
        let at = arrival(&light, DVec3::new(0.5, 0.5, 0.5), 1.0, [0.0; 3], 1, &vacuum);
        let n = 1000;
        let mut face = 0.0;
        for i in 0..n {
            for j in 0..n {
                let (x, y) = ((i as f64 + 0.5) / n as f64 - 0.5, (j as f64 + 0.5) / n as f64 - 0.5);
                face += 0.5 / (0.25 + x * x + y * y) / (n * n) as f64;
            }
        }
        let exact = 2.0 * 6.0 * face;
        assert!((at.irradiance[0] / exact - 1.0).abs() < 5e-3, "{} vs {exact}", at.irradiance[0]);
        assert!(at.directed < 1e-9, "{}", at.directed);
        // Off centre inside the voxel: between the centred value and the corner's.
        let off = PointLight { position: DVec3::new(0.2, 0.3, 0.1), ..light };
        let e = arrival(&off, DVec3::new(0.5, 0.5, 0.5), 1.0, [0.0; 3], 1, &vacuum);
        assert!(e.irradiance[0] < exact && e.irradiance[0] > 0.5 * exact, "{}", e.irradiance[0]);
        assert!(e.directed > 0.0 && e.directed < 1.0);
        // One voxel over: the mean of 1/r² over the cube is above its centre value (convexity).
        let next = arrival(&light, DVec3::new(1.5, 0.5, 0.5), 1.0, [0.0; 3], 1, &vacuum);
        assert!(next.irradiance[0] > 2.0 && next.irradiance[0] < 2.0 * 1.2, "{}", next.irradiance[0]);
        assert!(next.directed > 0.9);
    }
}
