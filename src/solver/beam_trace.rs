//! A sun's uncollided irradiance per voxel traced along its exact direction, at each voxel's centre
//! through the density the renderer sees: what the image's exact single scattering multiplies
//! ([`super::direct`], [`crate::render::march`]).
//!
//! **Why not the sweep's.** Order 0's beam sweep (the twin's `cpu_sweep`, [`super::sweep`])
//! carries a beam plane by plane over the lattice of voxel columns: one ray per column, and with
//! `spatial = "constant"` (the default where the medium scatters) each ray takes, in each plane,
//! the column nearest to it, a staircase up to half a voxel off its line. That is the solve's
//! discretisation and what its first scattering holds; for the image it is too coarse where the
//! light grazes the medium. Seen towards the sun, a cloud's rim is the edge of its own shadow,
//! where half a voxel sideways changes the optical depth to the sun a lot: on the 48³ cloud of
//! `tools/forward_image_table.sh` (σt 0.8 per voxel) the swept and the traced irradiance differ by
//! 23 % rms over the scattering voxels (weighted by ρ·E) (benches/RESULTS.md, "Render: the suns'
//! single scattering exact").
//!
//! **Why at the centres, through the render's density.** A camera ray samples the medium between
//! voxel centres, with the density interpolated trilinearly ([`crate::render::march`]); the
//! irradiance there falls exponentially along the sun's line, e^{−σ·ρ} per voxel with σ·ρ up to
//! 0.8 on that cloud, so interpolating a per-voxel value linearly overstates it between the
//! centres. Looking exactly towards the sun, where the camera ray runs along the sun's line and
//! every sample's light has crossed the same medium, the image's single scattering came out 15 %
//! too bright that way (session 33's chord averages, interpolated as ρ·E). So each voxel keeps the
//! irradiance at its centre, `B·e^{−σ·∫ρ}` with ∫ρ taken along the sun's line through the very
//! density model the camera rays see (trilinear between centres, held at the volume's edge;
//! summed over the line's voxel crossings at their midpoints, as a camera ray sums its
//! extinction), and the renderer interpolates the optical depth (the logarithm) between the
//! centres, exact in a uniform medium. Every voxel of an occupied brick is traced, the empty ones
//! too: a sample at a cloud's edge takes the light of the empty centres beside it.
//!
//! **What.** For every voxel of an occupied brick, the walk from its centre towards the sun to the
//! volume's boundary ([`crate::render::march::walk_voxels`], the renderer's own walk, and its
//! trilinear sampling, so the two integrate one density model); one walk serves every component
//! (channels, and the true and the δ-M scaled extinction). Each voxel is computed alone, so the
//! result is bitwise the same on any number of threads (rayon).
//!
//! **Cost.** One walk per traced voxel, as many crossings as voxels lie between it and the
//! boundary, eight density reads each: O(N^{4/3}) for N voxels where the sweep is O(N). Most of
//! a walk from a cloud to the volume's boundary crosses empty space, where the trilinear density
//! is exactly 0: the walk reads nothing in 8³-voxel cells with no density within a voxel of them
//! and stops once past the box of the cells that have some (`LiveCells`; the sum is bitwise the
//! full walk's, a unit test checks it). On the 2-core VM a 160³ cloud (161 occupied bricks of
//! 1000) takes 1.2 s that way, 8.0 s reading every crossing, beside 9.9 s for one order of its
//! solve at 2 × 2 directions per face (the chord averages through the voxels that scatter, before
//! the centres: 0.41 s). A medium that fills its volume gains nothing from the skipping. The
//! split estimates the steps first and keeps the sweep's irradiance past [`TRACE_LIMIT_STEPS`]
//! (logged, and said in `report.json`'s reasons, as is the trace's time when it runs).

use crate::render::march::{intersect_box, trilinear, walk_voxels};
use glam::DVec3;
use rayon::prelude::*;

/// Most steps ([`estimated_steps`]: the walks' voxel crossings) the trace may take; beyond, the
/// image keeps the sweep's irradiance. About a minute on two cores where every crossing reads the
/// density (1.8·10⁷ a second, measured on a 160³ cloud before the walks skipped dead cells), less
/// where many cross dead cells (the same cloud now: 5.3·10⁷ steps, 1.2 s) and on more cores.
pub const TRACE_LIMIT_STEPS: u64 = 1_000_000_000;

/// The estimated steps of [`trace_beam`] along `travel` over the traced `bricks` (each its first
/// voxel and extent; see [`TRACE_LIMIT_STEPS`]): per brick, its voxels times the crossings of the
/// walk from its centre, as far as the trace walks (to the boundary, or past the live cells' box),
/// every crossing counted as one step whether it reads the density or not.
pub fn estimated_steps(live: &LiveCells, bricks: &[([u32; 3], [u32; 3])], travel: DVec3) -> u64 {
    bricks
        .iter()
        .map(|&(first, extent)| {
            let centre = DVec3::from_array(std::array::from_fn(|a| f64::from(first[a]) + 0.5 * f64::from(extent[a])));
            let steps = live.walk(centre, -travel, |_, _, _| {});
            extent.iter().map(|&e| u64::from(e)).product::<u64>().saturating_mul(steps)
        })
        .fold(0u64, u64::saturating_add)
}

/// Where the density the renderer sees can be non-zero: 8³-voxel cells marked live when the
/// density is non-zero anywhere within one voxel of them (a sample in voxel v interpolates the
/// centres of v − 1 ..= v + 1), and the box around the live cells. A walk adds nothing in a dead
/// cell (ρ = 0 there exactly), so it skips their reads, and stops once it is past the box's far
/// side: the sum is bitwise what the full walk gives.
pub struct LiveCells {
    dims: [u32; 3],
    cells: [usize; 3],
    live: Vec<bool>,
    /// The live cells' box, from `lo` to `hi` (voxel units, the far corner of the last cell).
    lo: DVec3,
    hi: DVec3,
}

/// The side of a [`LiveCells`] cell, in voxels (a power of two: cells by shifting).
const CELL_SHIFT: u32 = 3;

impl LiveCells {
    /// The cells of a `dims` volume whose density (ρ per voxel, x fastest) is `density`.
    pub fn new(dims: [u32; 3], density: &[f64]) -> LiveCells {
        let [nx, ny, _] = dims.map(|d| d as usize);
        let cells = dims.map(|d| ((d as usize - 1) >> CELL_SHIFT) + 1);
        let mut live = vec![false; cells.iter().product()];
        for (i, _) in density.iter().enumerate().filter(|(_, &rho)| rho != 0.0) {
            let v = [i % nx, (i / nx) % ny, i / (nx * ny)];
            let range = |a: usize| {
                let lo = v[a].saturating_sub(1) >> CELL_SHIFT;
                let hi = (v[a] + 1).min(dims[a] as usize - 1) >> CELL_SHIFT;
                lo..=hi
            };
            for z in range(2) {
                for y in range(1) {
                    for x in range(0) {
                        live[x + cells[0] * (y + cells[1] * z)] = true;
                    }
                }
            }
        }
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for (i, _) in live.iter().enumerate().filter(|(_, &l)| l) {
            let c = DVec3::new(
                (i % cells[0]) as f64,
                ((i / cells[0]) % cells[1]) as f64,
                (i / (cells[0] * cells[1])) as f64,
            );
            lo = lo.min(c);
            hi = hi.max(c);
        }
        let side = f64::from(1u32 << CELL_SHIFT);
        LiveCells { dims, cells, live, lo: lo * side, hi: (hi + 1.0) * side }
    }

    fn is_live(&self, v: [u32; 3]) -> bool {
        let c = v.map(|x| (x >> CELL_SHIFT) as usize);
        self.live[c[0] + self.cells[0] * (c[1] + self.cells[1] * c[2])]
    }

    /// The ray's parameter past which it is outside the live cells' box for good (−∞: it never
    /// meets the box).
    fn leaves_at(&self, from: DVec3, towards: DVec3) -> f64 {
        if self.lo.x > self.hi.x {
            return f64::NEG_INFINITY;
        }
        match intersect_box(from - self.lo, towards, self.hi - self.lo) {
            Some((_, t1)) => t1,
            // Starting inside a box that the ray leaves at once, or missing it.
            None => f64::NEG_INFINITY,
        }
    }

    /// Walks the voxels from `from` along `towards` (unit) to the volume's boundary, or until a
    /// dead crossing starts past the live cells' box (nothing live lies further on), calling
    /// `live_crossing(voxel, start, length)` for each crossing of a live cell, in order; returns the
    /// crossings walked. The one walk of the trace ([`path_to_boundary`]) and of its estimate.
    fn walk(&self, from: DVec3, towards: DVec3, mut live_crossing: impl FnMut([u32; 3], f64, f64)) -> u64 {
        let size = DVec3::new(self.dims[0] as f64, self.dims[1] as f64, self.dims[2] as f64);
        let Some(span) = intersect_box(from, towards, size) else { return 0 };
        // A margin far above the round-off of the box's exit, far below a voxel.
        let past = self.leaves_at(from, towards) + 1e-6;
        let (mut t, mut steps) = (span.0, 0u64);
        walk_voxels(from, towards, span, self.dims, 1.0, |v, s| {
            let start = t;
            t += s;
            steps += 1;
            if !self.is_live(v) {
                return start <= past;
            }
            live_crossing(v, start, s);
            true
        });
        steps
    }
}

/// ∫ρ ds (voxel units) from `from` to the boundary of the volume `live` was made for, along
/// `towards` (unit), through the density the renderer sees: `density` (ρ per voxel, x fastest)
/// interpolated trilinearly between the voxel centres, taken at the midpoint of each voxel
/// crossing (the dead cells' crossings, where it is exactly 0, skipped: [`LiveCells`]).
fn path_to_boundary(density: &[f64], live: &LiveCells, from: DVec3, towards: DVec3) -> f64 {
    let dims = live.dims;
    let [nx, ny, _] = dims.map(|d| d as usize);
    let mut sum = 0.0;
    live.walk(from, towards, |_, start, s| {
        let mid = from + towards * (start + 0.5 * s);
        let rho: f64 = trilinear(mid, dims)
            .iter()
            .map(|&(v, w)| w * density[v[0] as usize + nx * (v[1] as usize + ny * v[2] as usize)])
            .sum();
        sum += s * rho;
    });
    sum
}

/// Per voxel of the volume `live` was made for (x fastest, `density` ρ per voxel as the twin holds
/// it, the same `live` was made from) for which `traced` holds, the irradiance at its centre of a
/// beam travelling along `travel` (unit, voxel frame), one value per component k:
/// `boundary[k]·e^{−sigma[k]·∫ρ}` (`path_to_boundary` towards the sun), `sigma[k]` the extinction
/// per unit density and voxel length (σt·h). Written to `out[voxel·K + k]`, K = `sigma.len()`; 0
/// where `traced` does not hold.
pub fn trace_beam(
    density: &[f64],
    live: &LiveCells,
    traced: &(dyn Fn([u32; 3]) -> bool + Sync),
    travel: DVec3,
    boundary: &[f64],
    sigma: &[f64],
    out: &mut [f64],
) {
    let k = sigma.len();
    assert_eq!(boundary.len(), k, "one boundary irradiance per component");
    let dims = live.dims;
    let [nx, ny, _] = dims.map(|d| d as usize);
    assert_eq!(density.len(), dims.iter().map(|&d| d as usize).product::<usize>(), "one density per voxel");
    out.par_chunks_mut(k).enumerate().for_each(|(i, values)| {
        let v = [i % nx, (i / nx) % ny, i / (nx * ny)].map(|c| c as u32);
        if !traced(v) {
            values.iter_mut().for_each(|x| *x = 0.0);
            return;
        }
        let centre = DVec3::new(v[0] as f64 + 0.5, v[1] as f64 + 0.5, v[2] as f64 + 0.5);
        let path = path_to_boundary(density, live, centre, -travel);
        for ((value, &b), &s) in values.iter_mut().zip(boundary).zip(sigma) {
            *value = b * (-s * path).exp();
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A uniform volume lit obliquely, at a slope the sweep's staircase gets wrong (half a voxel
    /// per plane): held at the volume's edge, the density the renderer sees is uniform right up
    /// to the boundary, so every voxel's value is the closed form e^{−σ·ρ·d} at its centre (d the
    /// distance to the boundary along the sun's line), to round-off.
    #[test]
    fn a_uniform_volume_gets_the_closed_form_at_each_centre() {
        let dims = [12u32, 12, 10];
        let density = vec![0.5; 12 * 12 * 10];
        let travel = DVec3::new(0.0, 0.5, 1.0).normalize();
        let (b, sigma) = ([2.0, 3.0], [0.8, 0.3]);
        let mut out = vec![0.0; density.len() * 2];
        trace_beam(&density, &LiveCells::new(dims, &density), &|_| true, travel, &b, &sigma, &mut out);
        let mut checked = 0;
        for z in 0..10usize {
            for y in 0..12usize {
                for x in 0..12usize {
                    // Only voxels whose line towards the sun leaves through the top face (z = 0).
                    let reach = (z as f64 + 0.5) * travel.y / travel.z;
                    if (y as f64 + 0.5) - reach < 0.0 {
                        continue;
                    }
                    let i = x + 12 * (y + 12 * z);
                    let d = (z as f64 + 0.5) / travel.z;
                    for k in 0..2 {
                        let want = b[k] * (-sigma[k] * 0.5 * d).exp();
                        let got = out[i * 2 + k];
                        assert!((got / want - 1.0).abs() < 1e-12, "voxel {x},{y},{z} k {k}: {got} vs {want}");
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked > 1000, "{checked}");
    }

    /// Skipping the dead cells and stopping past the live box changes no bit: two small blobs in
    /// a larger empty volume (one touching the volume's edge), walked from every centre along
    /// oblique and axis-aligned directions, from inside, beside and beyond the blobs.
    #[test]
    fn skipping_empty_space_gives_the_full_walks_bits() {
        let dims = [37u32, 29, 23];
        let [nx, ny, nz] = dims.map(|d| d as usize);
        let mut density = vec![0.0; nx * ny * nz];
        let mut seed = 12345u64;
        let mut blob = |c: [usize; 3], r: usize, density: &mut Vec<f64>| {
            for z in c[2].saturating_sub(r)..(c[2] + r).min(nz) {
                for y in c[1].saturating_sub(r)..(c[1] + r).min(ny) {
                    for x in c[0].saturating_sub(r)..(c[0] + r).min(nx) {
                        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                        density[x + nx * (y + ny * z)] = (seed >> 40) as f64 / (1u64 << 24) as f64;
                    }
                }
            }
        };
        blob([9, 8, 6], 3, &mut density);
        blob([30, 25, 20], 4, &mut density);
        let live = LiveCells::new(dims, &density);
        assert!(live.live.iter().any(|&l| !l), "the test needs dead cells");
        // Every cell live: every crossing read, to the boundary (the walk before the skipping).
        let everywhere = LiveCells::new(dims, &vec![1.0; density.len()]);
        assert!(everywhere.live.iter().all(|&l| l));
        let directions = [
            DVec3::new(-0.55, -0.35, 0.75).normalize(),
            DVec3::new(0.3, 0.8, -0.2).normalize(),
            DVec3::X,
            -DVec3::Z,
            DVec3::new(1.0, 1.0, 1.0).normalize(),
        ];
        let mut non_zero = 0;
        for towards in directions {
            for i in 0..nx * ny * nz {
                let v = [i % nx, (i / nx) % ny, i / (nx * ny)];
                let from = DVec3::new(v[0] as f64 + 0.5, v[1] as f64 + 0.5, v[2] as f64 + 0.5);
                let want = path_to_boundary(&density, &everywhere, from, towards);
                let got = path_to_boundary(&density, &live, from, towards);
                assert_eq!(got.to_bits(), want.to_bits(), "voxel {v:?} towards {towards}");
                non_zero += usize::from(want > 0.0);
            }
        }
        assert!(non_zero > 1000, "{non_zero}");
    }

    /// The estimate counts a brick's walk to the boundary through a medium that fills the volume,
    /// and only as far as the live cells where the medium is that brick alone.
    #[test]
    fn the_estimate_walks_as_far_as_the_trace() {
        let dims = [64u32, 16, 16];
        let brick = ([48u32, 0, 0], [16u32, 16, 16]);
        let travel = DVec3::X; // the walks go towards −x, from the brick's centre at x = 56
        let full = LiveCells::new(dims, &vec![1.0; 64 * 16 * 16]);
        let steps = estimated_steps(&full, &[brick], travel) / 4096;
        assert!((56..=57).contains(&steps), "{steps}");
        let mut alone = vec![0.0; 64 * 16 * 16];
        for z in 0..16 {
            for y in 0..16 {
                for x in 48..64 {
                    alone[x + 64 * (y + 16 * z)] = 1.0;
                }
            }
        }
        // Live from the cell holding x = 47 (40..48) on: the walk stops at its second crossing
        // past x = 40 (and may start with an empty crossing on the centre's face).
        let steps = estimated_steps(&LiveCells::new(dims, &alone), &[brick], travel) / 4096;
        assert!((17..=19).contains(&steps), "{steps}");
    }

    /// The voxels `traced` leaves out read 0; the empty ones it names get their light too (a
    /// sample at a cloud's edge interpolates them), undimmed where the interpolated density is 0
    /// all the way to the sun, and a dense voxel's centre is dimmed by the half of the ramp towards
    /// its empty neighbour that the render's walk sees (midpoints at z = 3.25 and 2.5: ρ 0.75 and
    /// 0, over half a voxel and a whole one).
    #[test]
    fn empty_voxels_get_their_light_and_left_out_ones_read_zero() {
        let dims = [4u32, 4, 4];
        let mut density = vec![0.0; 64];
        let dense = 1 + 4 * (1 + 4 * 3);
        density[dense] = 1.0; // one voxel at z = 3, lit from z = 0 through empty space
        let mut out = vec![0.0; 64];
        trace_beam(&density, &LiveCells::new(dims, &density), &|v| v[0] != 3, DVec3::Z, &[1.0], &[0.4], &mut out);
        for (i, &e) in out.iter().enumerate() {
            let x = i % 4;
            if x == 3 {
                assert_eq!(e, 0.0, "voxel {i} is not traced");
            } else if i != dense && i / 16 < 3 {
                assert_eq!(e, 1.0, "voxel {i}: nothing between it and the sun");
            }
        }
        let want = (-0.4f64 * 0.375).exp();
        assert!((out[dense] - want).abs() < 1e-15, "{} vs {want}", out[dense]);
    }
}
