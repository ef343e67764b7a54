//! Diffusion synthetic acceleration of the order series (`solver.acceleration`).
//!
//! **Why.** Each order propagates the light the previous one scattered, so the orders form a
//! series whose terms shrink by the spectral radius of one scattering-and-transport step. In a
//! thick medium of albedo a that radius tends to a: at 0.999 the series needs thousands of orders,
//! and what converges slowly is light diffusing through the medium over many mean free paths —
//! smooth in space, nearly isotropic. Diffusion theory describes exactly those modes, at a cost
//! of one sparse linear solve per order, so it is used to estimate them and add them at once
//! (Alcouffe 1977; Adams and Larsen 2002 review the method).
//!
//! **What.** After order m's sweeps, the change of the fluence the series made in this order is
//! r = c_m − f_{m−1} (the order's fluence less the correction the previous order added, which
//! this order's source already contained), and its scattered moment σs·r is the source of the
//! error that remains. The correction f_m solves the diffusion equation for that source,
//!
//! ```text
//!   −∇·D∇f_m + σa f_m = σs·(c_m − f_{m−1}),   D = 1 / (3 (σt − ḡ σs)),
//! ```
//!
//! (ḡ the mean cosine of the discrete scattering, the plan's `effective_g`), with Marshak's vacuum
//! condition where the medium ends. The order then commits c_m + (f_m − f_{m−1}) as its fluence
//! and its scattered source plus the isotropic σs·(f_m − f_{m−1})/4π in every storage direction:
//! the series now continues from the corrected iterate. Once the series has converged, c_m = f_{m−1}
//! and f_m = 0: the answer is the transport solution, not the diffusion one; diffusion only
//! changes how fast it is reached. The fold is linear, so the stop rule, the checkpoints and the
//! energy books go on as before with the corrected order as "the order".
//!
//! **Energy.** Every order's transport balances (source power = escaped + absorbed + scattered).
//! Summed over the orders with the corrections folded in, the books close with one extra term:
//! the light the last correction added that no transport has carried yet, σt·f_N. The loop counts
//! it with the unpropagated source ([`Acceleration::pending_power`]), so the balance stays exact.
//!
//! **Grid.** The diffusion unknowns are cells of e³ voxels holding medium, e the smallest power of
//! two that keeps the cell grid within `solver.diffusion_cells` cells (by default [`MAX_CELLS`]:
//! e = 1 up to 2²⁰ voxels, about 101³): their σt, σs are the means over the cell, the correction
//! is prolonged piecewise constant onto the cell's medium voxels. Cells without medium, and the volume's faces, are vacuum to the diffusion (light that
//! crosses a hole and comes back is left to the transport). The equation is solved per channel
//! with Jacobi-preconditioned conjugate gradients in f64.
//!
//! **Deterministic.** Sums over cells run in a fixed order (per chunk, then the chunks in order);
//! the fold writes each voxel from its own values; nothing depends on the thread count, and the
//! twin and the store run the same code over their units.

use super::antidiffusion::VoxelUnits;
use super::passes::{FieldPlanes, Medium, Value, RELEASE_UNITS};
use super::plan::Plan;
use rayon::prelude::*;

/// No neighbour (a vacuum face).
const NONE: u32 = u32::MAX;
/// The most cells the diffusion grid may have by default (the cells grow until it fits;
/// `solver.diffusion_cells` sets another bound): at most ~100 MB of coefficients (RGB), and a
/// solve per order that stays small beside a sweep of the same volume.
pub const MAX_CELLS: usize = 1 << 20;
/// The conjugate gradients stop at this relative residual: the correction need only be good to a
/// small fraction of itself; later orders take out what it leaves.
const CG_TOLERANCE: f64 = 1e-6;
/// ... or after this many iterations (the correction is still usable when it stops short).
const CG_MAX_ITERATIONS: usize = 2000;
/// Voxels thicker than this (σt·h, mean free paths per voxel, in any channel) are left out of the
/// diffusion grid: there the lattice's transport and this diffusion discretisation disagree enough
/// that the corrected series diverges (a uniform 16³ box at albedo 0.999 converged fast at
/// σt·h = 1.5, slowly at 2, and diverged at 2.5 and above; a cloud whose core reaches 2 converged in
/// 12 orders). Light there converges as the plain series does.
pub const MAX_VOXEL_DEPTH: f64 = 2.0;
/// Cells per task of the parallel sums (fixed: the partial sums must not depend on the threads).
const CHUNK: usize = 4096;

/// The diffusion grid of a medium, its operator per channel and the last correction.
pub struct Acceleration {
    /// Voxels per cell edge.
    edge: u32,
    cells: [u32; 3],
    /// Per cell of the grid (x fastest), its unknown, or [`NONE`] (no medium).
    unknown_of: Vec<u32>,
    /// Per unknown, the unknowns across its faces −x, +x, −y, +y, −z, +z ([`NONE`]: vacuum).
    neighbours: Vec<[u32; 6]>,
    channels: usize,
    /// Per channel, the operator's diagonal and its couplings to the six neighbours (A_ij = −off).
    diag: Vec<Vec<f64>>,
    off: Vec<Vec<[f64; 6]>>,
    /// Per channel and unknown, Σσs and Σσt over the cell's voxels (per unit length).
    scatter_sum: Vec<Vec<f64>>,
    extinction_sum: Vec<Vec<f64>>,
    /// Per channel and unknown, the correction f the last order added.
    correction: Vec<Vec<f64>>,
}

/// Where a voxel of a unit sits in the diffusion grid and what it scatters (per channel, per unit
/// length): read once per pass from the medium.
struct VoxelCoefficients {
    unknown: u32,
    scatter: [f64; 3],
}

impl Acceleration {
    /// Builds the diffusion grid of the medium over the fields' units (`units` units of
    /// `unit_voxels` voxels each), with the correction of a resumed solve when given (`None`: zero).
    pub fn build<U: VoxelUnits + Medium<V = <U as VoxelUnits>::V>>(
        plan: &Plan,
        medium: &U,
        units: usize,
        unit_voxels: usize,
        resumed: Option<Vec<f64>>,
    ) -> Result<Acceleration, String> {
        let (edge, cells) = grid_of(medium.dims(), plan.diffusion_cells);
        let n_cells = cells.iter().map(|&c| c as usize).product::<usize>();
        let c = plan.channels as usize;
        let mut unknown_of = vec![NONE; n_cells];
        let mut scatter_sum: Vec<Vec<f64>> = vec![Vec::new(); c];
        let mut extinction_sum: Vec<Vec<f64>> = vec![Vec::new(); c];
        let mut cell_of_unknown = Vec::new();
        for unit in 0..units {
            for local in 0..unit_voxels {
                let Some(v) = voxel(plan, medium, unit, local) else { continue };
                let cell = cell_index(cells, v.position.map(|p| p / edge));
                if unknown_of[cell] == NONE {
                    unknown_of[cell] = cell_of_unknown.len() as u32;
                    cell_of_unknown.push(cell);
                    for ch in 0..c {
                        scatter_sum[ch].push(0.0);
                        extinction_sum[ch].push(0.0);
                    }
                }
                let u = unknown_of[cell] as usize;
                for ch in 0..c {
                    scatter_sum[ch][u] += v.scatter[ch];
                    extinction_sum[ch][u] += v.extinction[ch];
                }
            }
        }
        medium.release_all();
        let n = cell_of_unknown.len();
        let neighbours: Vec<[u32; 6]> = cell_of_unknown
            .iter()
            .map(|&cell| {
                face_neighbours(cell_coords(cells, cell), cells)
                    .map(|w| w.map_or(NONE, |w| unknown_of[cell_index(cells, w)]))
            })
            .collect();
        let cell_voxels = f64::from(edge).powi(3);
        let size = f64::from(edge) * plan.voxel_size;
        let g = plan.effective_g;
        let mut diag = Vec::with_capacity(c);
        let mut off = Vec::with_capacity(c);
        for ch in 0..c {
            // D per unknown, at most the cell size (an optically thin cell diffuses no further than
            // across itself: keeps the operator well conditioned where diffusion means little).
            let d: Vec<f64> = (0..n)
                .map(|u| {
                    let (st, ss) = (extinction_sum[ch][u] / cell_voxels, scatter_sum[ch][u] / cell_voxels);
                    1.0 / (3.0 * (st - g * ss).max(1.0 / (3.0 * size)))
                })
                .collect();
            let mut dg = vec![0.0; n];
            let mut of = vec![[0.0; 6]; n];
            for u in 0..n {
                let absorb = ((extinction_sum[ch][u] - scatter_sum[ch][u]) / cell_voxels).max(0.0);
                let mut a = absorb;
                for (f, &nb) in neighbours[u].iter().enumerate() {
                    let k = if nb == NONE {
                        // Marshak: no light comes in; the face sits half a cell from the centre.
                        2.0 * d[u] / (size + 4.0 * d[u])
                    } else {
                        let (du, dn) = (d[u], d[nb as usize]);
                        let k = 2.0 * du * dn / (size * (du + dn));
                        of[u][f] = k / size;
                        k
                    };
                    a += k / size;
                }
                dg[u] = a;
            }
            diag.push(dg);
            off.push(of);
        }
        let correction = match resumed {
            None => vec![vec![0.0; n]; c],
            Some(values) if values.len() == n * c => (0..c).map(|ch| values[ch * n..(ch + 1) * n].to_vec()).collect(),
            Some(values) => {
                return Err(format!(
                    "the checkpoint's correction has {} values, the medium's diffusion grid {n} × {c} channels",
                    values.len()
                ))
            }
        };
        Ok(Acceleration {
            edge,
            cells,
            unknown_of,
            neighbours,
            channels: c,
            diag,
            off,
            scatter_sum,
            extinction_sum,
            correction,
        })
    }

    /// Unknowns of the diffusion grid (cells holding medium).
    pub fn unknowns(&self) -> usize {
        self.neighbours.len()
    }

    /// The last correction, channel after channel (what a checkpoint saves).
    pub fn correction_values(&self) -> Vec<f64> {
        self.correction.concat()
    }

    /// Folds the correction into an order (see the module docs): from the order's fluence and
    /// scattered source, solves for the new correction f and adds f − f_prev to the fluence and
    /// σs·(f − f_prev)/4π to every storage direction of the source. Three steps, the first and
    /// the last of which the GPU's resident mode runs as kernels (`solver::gpu::accelerate`):
    /// [`Self::moments`], [`Self::solve`], [`Self::prolong`].
    pub fn fold<F: FieldPlanes + Sync + Send, U: VoxelUnits<V = F::V> + Medium<V = F::V>>(
        &mut self,
        plan: &Plan,
        medium: &U,
        fluence: &mut F,
        source: &mut F,
    ) {
        if self.unknowns() == 0 {
            return;
        }
        let moment = self.moments(plan, medium, source);
        let change = self.solve(&moment);
        self.prolong(plan, medium, fluence, source, &change);
    }

    /// Per channel and unknown, the scattered moment Σ_k J_k Ω_k of the order's source summed
    /// over the cell's medium voxels: unit by unit in unit order, each unit's voxels in their
    /// order, the components in theirs (a kernel that walks a cell's units in that order gives
    /// the same bits).
    pub fn moments<F: FieldPlanes, U: VoxelUnits<V = F::V> + Medium<V = F::V>>(
        &self,
        plan: &Plan,
        medium: &U,
        source: &F,
    ) -> Vec<Vec<f64>> {
        let (c, n) = (self.channels, self.unknowns());
        let comps = source.components();
        let unit_voxels = source.unit_voxels();
        let source_len = source.unit_len();
        let solid_angle = &plan.storage.solid_angle;
        let mut moment = vec![vec![0.0; n]; c];
        let values = source.values();
        for unit in 0..source.units() {
            let block = &values[unit * source_len..(unit + 1) * source_len];
            for local in 0..unit_voxels {
                let Some(u) = self.unknown_at(plan, medium, unit, local).map(|v| v.unknown as usize) else {
                    continue;
                };
                for k in 0..comps {
                    moment[k % c][u] += solid_angle[k / c] * block[k * unit_voxels + local].to_f64();
                }
            }
            if (unit + 1) % RELEASE_UNITS == 0 {
                source.release(unit + 1 - RELEASE_UNITS, RELEASE_UNITS);
            }
        }
        moment
    }

    /// Solves for the new correction from the order's [`Self::moments`] and keeps it; returns
    /// per channel and unknown its change f − f_prev, what [`Self::prolong`] adds.
    pub fn solve(&mut self, moment: &[Vec<f64>]) -> Vec<Vec<f64>> {
        let (c, n) = (self.channels, self.unknowns());
        let started = std::time::Instant::now();
        let cell_voxels = f64::from(self.edge).powi(3);
        let mut change = Vec::with_capacity(c);
        let mut iterations = 0;
        for ch in 0..c {
            // The source of the remaining error: σs·(c_m − f_prev), as a mean over the cell.
            let rhs: Vec<f64> = (0..n)
                .map(|u| (moment[ch][u] - self.correction[ch][u] * self.scatter_sum[ch][u]) / cell_voxels)
                .collect();
            let (f, taken) = conjugate_gradients(&self.diag[ch], &self.off[ch], &self.neighbours, &rhs);
            iterations += taken;
            change.push(f.iter().zip(&self.correction[ch]).map(|(new, old)| new - old).collect::<Vec<f64>>());
            self.correction[ch] = f;
        }
        let seconds = started.elapsed().as_secs_f64();
        tracing::debug!(unknowns = n, cell_edge = self.edge, iterations, seconds, "diffusion correction solved");
        change
    }

    /// Adds `change` (per channel and unknown) to each medium voxel's fluence, and its scattered
    /// share σs·change/4π to every storage direction of the voxel's source.
    pub fn prolong<F: FieldPlanes + Sync + Send, U: VoxelUnits<V = F::V> + Medium<V = F::V>>(
        &self,
        plan: &Plan,
        medium: &U,
        fluence: &mut F,
        source: &mut F,
        change: &[Vec<f64>],
    ) {
        let c = self.channels;
        let comps = source.components();
        let unit_voxels = source.unit_voxels();
        let source_len = source.unit_len();
        let units = source.units();
        let four_pi = four_pi(plan);
        let fluence_len = fluence.unit_len();
        let mut first = 0;
        while first < units {
            let count = RELEASE_UNITS.min(units - first);
            let phi = &mut fluence.values_mut()[first * fluence_len..(first + count) * fluence_len];
            let src = &mut source.values_mut()[first * source_len..(first + count) * source_len];
            phi.par_chunks_mut(fluence_len).zip(src.par_chunks_mut(source_len)).enumerate().for_each(
                |(i, (phi, src))| {
                    let unit = first + i;
                    for local in 0..unit_voxels {
                        let Some(v) = self.unknown_at(plan, medium, unit, local) else { continue };
                        for ch in 0..c {
                            let g = change[ch][v.unknown as usize];
                            let at = ch * unit_voxels + local;
                            phi[at] = F::V::from_f64(phi[at].to_f64() + g);
                            let add = v.scatter[ch] * g / four_pi;
                            for k in (ch..comps).step_by(c) {
                                let at = k * unit_voxels + local;
                                src[at] = F::V::from_f64(src[at].to_f64() + add);
                            }
                        }
                    }
                },
            );
            fluence.release(first, count);
            source.release(first, count);
            first += count;
        }
        medium.release_all();
    }

    /// Voxels per cell edge.
    pub fn edge(&self) -> u32 {
        self.edge
    }

    /// Cells of the grid along each axis.
    pub fn cells(&self) -> [u32; 3] {
        self.cells
    }

    /// Per cell of the grid (x fastest), its unknown, or `u32::MAX` (no medium).
    pub fn unknown_of(&self) -> &[u32] {
        &self.unknown_of
    }

    /// Per channel, the power the last correction added that no transport has carried yet:
    /// Σ σt·f·h³ (see the module docs, "Energy").
    pub fn pending_power(&self, plan: &Plan) -> [f64; 3] {
        let h3 = plan.voxel_size.powi(3);
        let mut out = [0.0; 3];
        for (ch, o) in out.iter_mut().enumerate().take(self.channels) {
            *o = h3 * ordered_dot(&self.correction[ch], &self.extinction_sum[ch]);
        }
        out
    }

    /// The unknown of voxel `local` of `unit` and its scattering, `None` without medium.
    fn unknown_at<U: VoxelUnits + Medium<V = <U as VoxelUnits>::V>>(
        &self,
        plan: &Plan,
        medium: &U,
        unit: usize,
        local: usize,
    ) -> Option<VoxelCoefficients> {
        let v = voxel(plan, medium, unit, local)?;
        let cell = cell_index(self.cells, v.position.map(|p| p / self.edge));
        let unknown = self.unknown_of[cell];
        (unknown != NONE).then_some(VoxelCoefficients { unknown, scatter: v.scatter })
    }
}

/// A voxel holding medium: where it is, its σt and σs per channel (per unit length).
struct MediumVoxel {
    position: [u32; 3],
    extinction: [f64; 3],
    scatter: [f64; 3],
}

fn voxel<U: VoxelUnits + Medium<V = <U as VoxelUnits>::V>>(
    plan: &Plan,
    medium: &U,
    unit: usize,
    local: usize,
) -> Option<MediumVoxel> {
    let rho = medium.density_at(unit, local).to_f64();
    if !in_grid(plan, rho) {
        return None;
    }
    let a = Medium::albedo(medium, unit).map_or(1.0, |a| a[local].to_f64());
    let mut extinction = [0.0; 3];
    let mut scatter = [0.0; 3];
    for ch in 0..plan.channels as usize {
        let (st, ss, _) = plan.coefficients(ch);
        extinction[ch] = rho * st;
        scatter[ch] = rho * ss * a;
    }
    Some(MediumVoxel { position: medium.voxel_of(unit, local), extinction, scatter })
}

/// The cell edge (voxels, a power of two) and the cells per axis of the diffusion grid of a volume
/// of `dims` voxels: the smallest edge that keeps the grid within `max_cells` (the plan's
/// `diffusion_cells`, by default [`MAX_CELLS`]).
pub fn grid_of(dims: [u32; 3], max_cells: usize) -> (u32, [u32; 3]) {
    let mut edge = 1u32;
    let cells_for = |e: u32| dims.map(|d| d.div_ceil(e));
    while cells_for(edge).iter().map(|&c| c as usize).product::<usize>() > max_cells {
        edge *= 2;
    }
    (edge, cells_for(edge))
}

/// Σ Ω over the storage directions (4π up to rounding), summed in their order.
pub fn four_pi(plan: &Plan) -> f64 {
    plan.storage.solid_angle.iter().sum()
}

/// Whether a voxel of density `rho` takes part in the diffusion grid: it holds medium and is no
/// thicker than [`MAX_VOXEL_DEPTH`] in any channel. (`glsl/diffusion_moments.comp` and
/// `diffusion_prolong.comp` test it alike.)
pub fn in_grid(plan: &Plan, rho: f64) -> bool {
    rho > 0.0
        && !(0..plan.channels as usize).any(|ch| rho * plan.coefficients(ch).0 * plan.voxel_size > MAX_VOXEL_DEPTH)
}

pub(crate) fn cell_index(cells: [u32; 3], at: [u32; 3]) -> usize {
    let [nx, ny, _] = cells.map(|c| c as usize);
    at[0] as usize + nx * (at[1] as usize + ny * at[2] as usize)
}

fn cell_coords(cells: [u32; 3], cell: usize) -> [u32; 3] {
    let [nx, ny, _] = cells.map(|c| c as usize);
    [(cell % nx) as u32, ((cell / nx) % ny) as u32, (cell / (nx * ny)) as u32]
}

/// Σ a·b, in chunks of [`CHUNK`] summed in order: the same bits at any thread count.
fn ordered_dot(a: &[f64], b: &[f64]) -> f64 {
    let parts: Vec<f64> =
        a.par_chunks(CHUNK).zip(b.par_chunks(CHUNK)).map(|(x, y)| x.iter().zip(y).map(|(p, q)| p * q).sum()).collect();
    parts.iter().sum()
}

/// y = A·x for the operator of one channel.
fn apply(diag: &[f64], off: &[[f64; 6]], neighbours: &[[u32; 6]], x: &[f64], y: &mut [f64]) {
    y.par_iter_mut().enumerate().with_min_len(CHUNK).for_each(|(i, out)| {
        let mut v = diag[i] * x[i];
        for (f, &nb) in neighbours[i].iter().enumerate() {
            if nb != NONE {
                v -= off[i][f] * x[nb as usize];
            }
        }
        *out = v;
    });
}

/// Solves A·x = b by conjugate gradients with the Jacobi preconditioner (A is symmetric positive
/// definite: diagonally dominant, strictly where a cell absorbs or meets vacuum, and every
/// connected piece of medium meets vacuum somewhere). Returns x and the iterations taken.
fn conjugate_gradients(diag: &[f64], off: &[[f64; 6]], neighbours: &[[u32; 6]], b: &[f64]) -> (Vec<f64>, usize) {
    let n = b.len();
    let mut x = vec![0.0; n];
    let norm_b = ordered_dot(b, b).sqrt();
    if !(norm_b > 0.0) || !norm_b.is_finite() {
        return (x, 0);
    }
    let mut r = b.to_vec();
    let mut z: Vec<f64> = r.iter().zip(diag).map(|(r, d)| r / d).collect();
    let mut p = z.clone();
    let mut ap = vec![0.0; n];
    let mut rz = ordered_dot(&r, &z);
    for iteration in 1..=CG_MAX_ITERATIONS {
        apply(diag, off, neighbours, &p, &mut ap);
        let pap = ordered_dot(&p, &ap);
        if !(pap > 0.0) {
            return (x, iteration);
        }
        let alpha = rz / pap;
        x.par_iter_mut().zip(&p).with_min_len(CHUNK).for_each(|(x, p)| *x += alpha * p);
        r.par_iter_mut().zip(&ap).with_min_len(CHUNK).for_each(|(r, ap)| *r -= alpha * ap);
        if ordered_dot(&r, &r).sqrt() <= CG_TOLERANCE * norm_b {
            return (x, iteration);
        }
        z.par_iter_mut().zip(&r).zip(diag).with_min_len(CHUNK).for_each(|((z, r), d)| *z = r / d);
        let rz_new = ordered_dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        p.par_iter_mut().zip(&z).with_min_len(CHUNK).for_each(|(p, z)| *p = z + beta * *p);
    }
    (x, CG_MAX_ITERATIONS)
}

/// The six face neighbours of `at` in a grid of `dims`, in the order −x, +x, −y, +y, −z, +z;
/// `None` beyond the grid's faces.
fn face_neighbours(at: [u32; 3], dims: [u32; 3]) -> [Option<[u32; 3]>; 6] {
    let mut out = [None; 6];
    for axis in 0..3 {
        for (side, step) in [(0usize, -1i64), (1, 1)] {
            let c = at[axis] as i64 + step;
            if c >= 0 && c < dims[axis] as i64 {
                let mut w = at;
                w[axis] = c as u32;
                out[2 * axis + side] = Some(w);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conjugate_gradients_solve_a_one_dimensional_diffusion() {
        // −f'' + σa f = 1 on a line of cells with vacuum ends: symmetric, and the residual is small.
        let n = 50;
        let neighbours: Vec<[u32; 6]> = (0..n)
            .map(|i| {
                let left = if i > 0 { i as u32 - 1 } else { NONE };
                let right = if i + 1 < n { i as u32 + 1 } else { NONE };
                [left, right, NONE, NONE, NONE, NONE]
            })
            .collect();
        let off: Vec<[f64; 6]> = neighbours.iter().map(|nb| nb.map(|x| if x == NONE { 0.0 } else { 1.0 })).collect();
        let diag = vec![2.01; n];
        let b = vec![1.0; n];
        let (x, iterations) = conjugate_gradients(&diag, &off, &neighbours, &b);
        assert!(iterations < CG_MAX_ITERATIONS);
        let mut ax = vec![0.0; n];
        apply(&diag, &off, &neighbours, &x, &mut ax);
        let err = ax.iter().zip(&b).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(err < 1e-5, "residual {err}");
        for i in 0..n {
            assert!((x[i] - x[n - 1 - i]).abs() < 1e-8 * x[n / 2], "not symmetric at {i}");
        }
    }
}
