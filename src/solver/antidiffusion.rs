//! Taking the lattice's numerical diffusion back out of the scattered source
//! (`solver.diffusion_correction`).
//!
//! **Why.** In every plane a ray meets the voxels at a lateral offset from where it really is: the
//! nearest column, off by e ∈ [−½, ½] (`spatial = "constant"`), or the two columns around it with
//! weights (1 − w, w) (`"linear"`), both when it gathers the source and when collect pulls its
//! deposit ([`super::sweep`]). So the light scattered in one order arrives spread sideways by a
//! variance the physics does not have. One order's spread is small, but in a thick medium of high
//! albedo the light scatters tens to hundreds of times and the spreads add up like a diffusion:
//! light leaks into dense cores too easily and they read bright (+3 to +6 % at one mean free path
//! per voxel against Monte Carlo, `benches/RESULTS.md`), while the error falls like h² with the
//! voxel size h, as a diffusion of variance ∝ h² per order does.
//!
//! **What.** The spread is known from the lattice alone. Per swept direction and lateral axis it is
//! the mean over the direction's planes of the gather's and the deposit's variances, 2e² or
//! 2w(1 − w) (in voxels²); weighted by the directions' fluence weights this gives a variance V_a
//! per volume axis a ([`lattice_spread`]). To leading order the order's scattered source S comes
//! out as (1 + Σ_a (V_a/2)·∂²_a)·S. After each order's sweeps, before the source is committed,
//! this pass applies the inverse to leading order, S ← (1 − Σ_a κ_a·Δ_a)·S with κ_a = V_a/2, as
//! *anti-diffusive fluxes* between face-neighbouring voxels of the medium: voxel i hands
//! κ_a·(S_j − S_i) to a neighbour j along a that holds more than it (the exchange a diffusion would
//! run the other way).
//!
//! **Properties.**
//! - *Conservative*: every flux leaves one voxel and enters another (and no flux crosses into a
//!   voxel without medium), so the order's total scattered power is unchanged and the energy books
//!   ([`super::energy`]) are untouched.
//! - *Positive*: a flux is at most a sixth of the smaller of its two voxels' values, so a voxel
//!   that gives to all six neighbours still keeps a value of its sign. The cap is met only across
//!   jumps of several times (edges of a medium, a shadow's border), where sharpening further would
//!   ring; it is what keeps the pass from creating negative light.
//! - *Deterministic*: each voxel's new value is its old one plus its six fluxes in a fixed order,
//!   computed from the old field only (read from `src`, written to `dst`): bitwise the same at any
//!   thread count, and written once for both backends (the store's bricks and the twin's voxels
//!   are both [`VoxelUnits`]).
//! - *Second order*: the correction is κ·Δ with κ ∝ (lattice spread in voxels), i.e. O(h²) against
//!   a smooth field, so it changes the constant of the scheme's h² error, not its order.

use super::passes::{FieldPlanes, Medium, StoreMedium, Value, VoxelMedium, RELEASE_UNITS};
use super::plan::SweepDirection;
use crate::quadrature::FACES;
use crate::scene::SpatialScheme;
use crate::store::BRICK_EDGE;
use rayon::prelude::*;

/// The fields' units as voxels of the volume: which unit and which voxel of it hold voxel `v`,
/// and the medium's density there. Implemented by the store's medium (a unit is an occupied
/// brick) and the twin's (a unit is a voxel).
pub trait VoxelUnits: Sync {
    type V: Value;
    fn dims(&self) -> [u32; 3];
    /// (unit, voxel within the unit) of voxel `v` (inside the volume), or `None` where no unit
    /// holds it (an empty brick: no medium).
    fn unit_of(&self, v: [u32; 3]) -> Option<(usize, usize)>;
    /// The volume coordinates of voxel `local` of unit `unit`.
    fn voxel_of(&self, unit: usize, local: usize) -> [u32; 3];
    /// The density of voxel `local` of unit `unit`.
    fn density_at(&self, unit: usize, local: usize) -> Self::V;
}

/// The lateral spread per order the lattice adds, per volume axis (voxels²): the fluence-weighted
/// mean over the swept directions of 2e² (constant) or 2w(1 − w) (linear) over their planes, for
/// the axes each direction moves across.
pub fn lattice_spread(faces: &[Vec<SweepDirection>], spatial: SpatialScheme) -> [f64; 3] {
    let mut spread = [0.0f64; 3];
    let mut total_weight = 0.0;
    for dir in faces.iter().flatten() {
        let face = FACES[dir.face];
        total_weight += dir.fluence_weight;
        let planes = dir.weights.len().max(1) as f64;
        for (i, &axis) in face.lateral.iter().enumerate() {
            let per_plane = |t: usize| -> f64 {
                match spatial {
                    SpatialScheme::Linear => {
                        let w = dir.weights[t][i];
                        2.0 * w * (1.0 - w)
                    }
                    SpatialScheme::Constant => {
                        // The exact lateral displacement at the middle of plane t is δ·(t + ½)
                        // voxels; the ray meets the nearest column.
                        let d = dir.omega[axis] / dir.omega[face.axis].abs() * (t as f64 + 0.5);
                        let e = d - d.round();
                        2.0 * e * e
                    }
                }
            };
            let mean = (0..dir.weights.len()).map(per_plane).sum::<f64>() / planes;
            spread[axis] += dir.fluence_weight * mean;
        }
    }
    if total_weight > 0.0 {
        spread.map(|s| s / total_weight)
    } else {
        [0.0; 3]
    }
}

/// The anti-diffusion coefficients κ_a = V_a/2 of [`lattice_spread`].
pub fn coefficients(faces: &[Vec<SweepDirection>], spatial: SpatialScheme) -> [f64; 3] {
    lattice_spread(faces, spatial).map(|v| 0.5 * v)
}

/// Writes into `dst` the field `src` with the anti-diffusive fluxes of coefficients `kappa`
/// between face-neighbouring voxels of the medium (see the module docs). `dst` and `src` have
/// the same layout (the twin's or the store's); every value of `dst` is written.
pub fn sharpen<F: FieldPlanes + Sync, U: VoxelUnits<V = F::V>>(dst: &mut F, src: &F, units: &U, kappa: [f64; 3]) {
    let unit_len = src.unit_len();
    let unit_voxels = src.unit_voxels();
    let comps = src.components();
    let dims = units.dims();
    let old = src.values();
    let value = |unit: usize, k: usize, local: usize| old[unit * unit_len + k * unit_voxels + local].to_f64();
    // The new value of component k of voxel `local` of `unit`: the old one less its fluxes to the
    // face neighbours in the medium, summed in the fixed order −x, +x, −y, +y, −z, +z.
    let new_value = |unit: usize, local: usize, k: usize, neighbours: &[Option<(usize, usize)>; 6]| -> f64 {
        let s = value(unit, k, local);
        let mut change = 0.0;
        for (n, neighbour) in neighbours.iter().enumerate() {
            let Some((nu, nl)) = *neighbour else { continue };
            let other = value(nu, k, nl);
            // Anti-diffusion: from the smaller value to the larger, capped at a sixth of the
            // smaller magnitude (positivity; see the module docs).
            let flux =
                (kappa[n / 2] * (other - s)).clamp(-s.abs().min(other.abs()) / 6.0, s.abs().min(other.abs()) / 6.0);
            change -= flux;
        }
        s + change
    };
    let neighbours_of = |unit: usize, local: usize| -> [Option<(usize, usize)>; 6] {
        face_neighbours(units.voxel_of(unit, local), dims)
            .map(|w| w.and_then(|w| units.unit_of(w)).filter(|&(u, l)| units.density_at(u, l).to_f64() > 0.0))
    };
    let units_total = src.units();
    let group = RELEASE_UNITS.max(1);
    let mut first = 0;
    while first < units_total {
        let count = group.min(units_total - first);
        let out = &mut dst.values_mut()[first * unit_len..(first + count) * unit_len];
        out.par_chunks_mut(unit_len).enumerate().for_each(|(i, block)| {
            let unit = first + i;
            for local in 0..unit_voxels {
                let medium = units.density_at(unit, local).to_f64() > 0.0;
                let neighbours = if medium { neighbours_of(unit, local) } else { [None; 6] };
                for k in 0..comps {
                    let at = k * unit_voxels + local;
                    block[at] = if medium {
                        F::V::from_f64(new_value(unit, local, k, &neighbours))
                    } else {
                        old[unit * unit_len + at]
                    };
                }
            }
        });
        dst.release(first, count);
        src.release(first, count);
        first += count;
    }
}

/// The six face neighbours of `at` in a grid of `dims`, in the order −x, +x, −y, +y, −z, +z;
/// `None` beyond the grid's faces.
pub(super) fn face_neighbours(at: [u32; 3], dims: [u32; 3]) -> [Option<[u32; 3]>; 6] {
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

impl VoxelUnits for StoreMedium<'_> {
    type V = f32;
    fn dims(&self) -> [u32; 3] {
        self.store.grid().dims
    }
    fn unit_of(&self, v: [u32; 3]) -> Option<(usize, usize)> {
        let (brick, local) = self.store.grid().locate(v);
        Some((self.store.slot(brick)? as usize, local))
    }
    fn voxel_of(&self, unit: usize, local: usize) -> [u32; 3] {
        let grid = self.store.grid();
        let origin = grid.brick_origin(grid.brick_coords(self.bricks[unit]));
        let e = BRICK_EDGE as usize;
        [origin[0] + (local % e) as u32, origin[1] + ((local / e) % e) as u32, origin[2] + (local / (e * e)) as u32]
    }
    fn density_at(&self, unit: usize, local: usize) -> f32 {
        self.density(unit).map_or(0.0, |d| d[local])
    }
}

impl VoxelUnits for VoxelMedium {
    type V = f64;
    fn dims(&self) -> [u32; 3] {
        self.dims
    }
    fn unit_of(&self, v: [u32; 3]) -> Option<(usize, usize)> {
        let [nx, ny, _] = self.dims.map(|d| d as usize);
        Some((v[0] as usize + nx * (v[1] as usize + ny * v[2] as usize), 0))
    }
    fn voxel_of(&self, unit: usize, _local: usize) -> [u32; 3] {
        let [nx, ny, _] = self.dims.map(|d| d as usize);
        [(unit % nx) as u32, ((unit / nx) % ny) as u32, (unit / (nx * ny)) as u32]
    }
    fn density_at(&self, unit: usize, _local: usize) -> f64 {
        self.density[unit]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::passes::MemField;

    fn field(dims: [u32; 3], comps: usize, f: impl Fn([u32; 3], usize) -> f64) -> MemField {
        let n = dims.iter().map(|&d| d as usize).product::<usize>();
        let layout = VoxelMedium { density: vec![], albedo: vec![], dims };
        let mut m = MemField::zeros(comps, n);
        for i in 0..n {
            let v = layout.voxel_of(i, 0);
            for k in 0..comps {
                m.values[i * comps + k] = f(v, k);
            }
        }
        m
    }

    fn medium(dims: [u32; 3], density: impl Fn([u32; 3]) -> f64) -> VoxelMedium {
        let f = field(dims, 1, |v, _| density(v));
        VoxelMedium { density: f.values, albedo: vec![], dims }
    }

    #[test]
    fn conserves_the_total_keeps_signs_and_leaves_uniform_fields_alone() {
        let dims = [9, 7, 5];
        // A medium with a hole (no exchange across it) and a source with sharp jumps and zeros.
        let med = medium(dims, |v| if v == [4, 3, 2] { 0.0 } else { 1.0 });
        let hole = med.unit_of([4, 3, 2]).map(|(u, _)| u);
        let src = field(dims, 2, |v, k| {
            let r = ((v[0] * 7 + v[1] * 3 + v[2] * 5 + k as u32) % 11) as f64;
            if v == [4, 3, 2] || r < 3.0 {
                0.0
            } else {
                r * r
            }
        });
        let mut dst = MemField::zeros(2, src.values.len() / 2);
        sharpen(&mut dst, &src, &med, [0.06, 0.05, 0.08]);
        for k in 0..2 {
            let before: f64 = src.values.iter().skip(k).step_by(2).sum();
            let after: f64 = dst.values.iter().skip(k).step_by(2).sum();
            assert!((before - after).abs() < 1e-12 * before, "component {k}: {before} → {after}");
        }
        assert!(dst.values.iter().all(|&v| v >= 0.0), "a value went negative");
        assert_ne!(dst.values, src.values, "nothing was sharpened");
        // Nothing flowed into the voxel without medium.
        assert_eq!(dst.values[hole.expect("inside") * 2], 0.0);

        let uniform = field(dims, 1, |_, _| 3.5);
        let mut out = MemField::zeros(1, uniform.values.len());
        sharpen(&mut out, &uniform, &med, [0.1; 3]);
        assert_eq!(out.values, uniform.values);
    }

    #[test]
    fn undoes_a_small_diffusion_to_leading_order() {
        // Smooth a smooth bump by one explicit diffusion step of coefficient κ and sharpen it back
        // with the same κ: what remains is O(κ²), far below the diffusion's own change.
        let dims = [24, 1, 1];
        let med = medium(dims, |_| 1.0);
        let bump = |x: f64| (-(x - 11.5).powi(2) / 18.0).exp();
        let exact = field(dims, 1, |v, _| bump(v[0] as f64));
        let kappa = 0.05;
        let n = exact.values.len();
        let mut smoothed = MemField::zeros(1, n);
        for i in 0..n {
            let left = if i > 0 { exact.values[i - 1] } else { exact.values[i] };
            let right = if i + 1 < n { exact.values[i + 1] } else { exact.values[i] };
            smoothed.values[i] = exact.values[i] + kappa * (left - 2.0 * exact.values[i] + right);
        }
        let mut back = MemField::zeros(1, n);
        sharpen(&mut back, &smoothed, &med, [kappa, 0.0, 0.0]);
        let err = |a: &MemField| a.values.iter().zip(&exact.values).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(err(&back) < 0.05 * err(&smoothed), "{} vs {}", err(&back), err(&smoothed));
    }
}
