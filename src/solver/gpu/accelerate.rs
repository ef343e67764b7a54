//! The diffusion acceleration of the resident mode's orders on the device ([`crate::solver::acceleration`]),
//! so an accelerated solve (the default at high albedo) keeps its fields there between orders too.
//!
//! The fold of an order has three steps (`Acceleration::fold`): the restriction of the order's
//! new source to the diffusion grid (per cell, its scattered moment), the diffusion solve, and the
//! prolongation of the correction's change back onto every medium voxel's fluence and source. The
//! first and the last touch every voxel, so they run here as kernels over the resident fields
//! (`glsl/diffusion_moments.comp`, `glsl/diffusion_prolong.comp`); the solve works on the cells
//! only (at most [`crate::solver::acceleration::MAX_CELLS`] per channel: a few MB), so the host
//! keeps it, with the grid and the last correction (which checkpoints save). Per order the
//! moments come home and the change goes up: 8 bytes per cell and channel each way, instead of
//! the whole source and fluence.
//!
//! Bitwise the host's: the moments kernel sums each cell's voxels in the host's order (its bricks
//! in slot order, given by the tables built here, each brick's voxels of the cell in index order,
//! the components in theirs), one invocation per cell; the prolongation adds in f64 and rounds to
//! f32 from the bits as the host's `as f32` does (`glsl/exact.glsl`). So an accelerated resident
//! solve is the streamed one to the bit (`tests/it/resident.rs`).

use super::buffers::{DiffusionBuffers, ResidentBuffers, TotalBuffers};
pub use super::kernels::DiffusionPush;
use super::kernels::{self, dispatch_linear, readback};
use super::owned::Owned;
use super::submit::Submitter;
use crate::solver::acceleration::{self, Acceleration};
use crate::solver::plan::Plan;
use crate::solver::SolveError;
use crate::store::{BRICK_EDGE, BRICK_VOXELS};
use crate::vk::{Buffer, ComputePipeline, Context, DescriptorSet, HostBuffer, Recorder};
use ash::vk;
use std::sync::Arc;

/// Loop iterations one invocation of the moments kernel may run per round (about) on a CPU
/// implementation: the rounds keep every invocation's loops far below llvmpipe's 65535 (see
/// glsl/diffusion_moments.comp). A GPU runs one round.
const ROUND_ITERATIONS: u32 = 16384;

/// The two kernels, their sets over the resident fields and the diffusion buffers, and what the
/// grid's tables fixed once they went up.
pub struct DeviceAcceleration {
    moments_set: Owned<DescriptorSet>,
    prolong_set: Owned<DescriptorSet>,
    /// The grid's figures, once its tables are on the device (`None` before the first fold), and
    /// the moments kernel's rounds.
    push: Option<(DiffusionPush, u32)>,
    /// Voxels of the occupied bricks (the prolongation's invocations).
    voxels: u32,
    /// Declared after the sets, so freed after them.
    moments_pipeline: Owned<ComputePipeline>,
    prolong_pipeline: Owned<ComputePipeline>,
}

impl DeviceAcceleration {
    /// The pipelines and sets over `resident` and `totals` (`occupied` bricks) and the diffusion
    /// buffers `d` (which the driver's mode owns beside these kernels).
    pub fn new(
        ctx: &Arc<Context>,
        resident: &ResidentBuffers,
        totals: &TotalBuffers,
        d: &DiffusionBuffers,
        occupied: u64,
    ) -> Result<Self, SolveError> {
        let moments_pipeline = kernels::DIFFUSION_MOMENTS.pipeline(ctx)?;
        let prolong_pipeline = kernels::DIFFUSION_PROLONG.pipeline(ctx)?;
        let voxels = u32::try_from(occupied * BRICK_VOXELS as u64)
            .map_err(|_| SolveError::Internal("more resident voxels than a dispatch can reach"))?;
        Ok(DeviceAcceleration {
            moments_set: kernels::DIFFUSION_MOMENTS.set(
                ctx,
                "diffusion moments",
                &moments_pipeline,
                &[
                    ("Density", &resident.density),
                    ("Source", &resident.source_next),
                    ("SolidAngles", &d.solid_angles),
                    ("CellOfUnknown", &d.cell_of_unknown),
                    ("BrickStart", &d.brick_start),
                    ("Bricks", &d.bricks),
                    ("Origins", &totals.origins),
                    ("Moments", &d.moments),
                ],
            )?,
            prolong_set: kernels::DIFFUSION_PROLONG.set(
                ctx,
                "diffusion prolong",
                &prolong_pipeline,
                &[
                    ("Density", &resident.density),
                    ("Source", &resident.source_next),
                    ("Fluence", &resident.fluence),
                    ("UnknownOf", &d.unknown_of),
                    ("Origins", &totals.origins),
                    ("Change", &d.change),
                    // Unread without an albedo grid: any buffer will do.
                    ("Albedo", totals.albedo.as_deref().unwrap_or(&resident.density)),
                ],
            )?,
            push: None,
            voxels,
            moments_pipeline,
            prolong_pipeline,
        })
    }

    /// Folds the correction into the order the sweeps just finished, on the resident fields
    /// (see the module docs): moments on the device, the solve on the host (`grid` keeps the new
    /// correction), the change added on the device. `origins()` gives each occupied brick's first
    /// voxel, in slot order (wanted once, for the grid's tables). Waits.
    pub fn fold(
        &mut self,
        sub: &mut Submitter,
        plan: &Plan,
        buffers: &mut DiffusionBuffers,
        grid: &mut Acceleration,
        origins: impl FnOnce() -> Vec<[u32; 4]>,
    ) -> Result<(), SolveError> {
        let n = grid.unknowns();
        if n == 0 {
            return Ok(());
        }
        let (push, rounds) = match self.push {
            Some(loaded) => loaded,
            None => {
                let loaded = self.load_grid(sub, plan, buffers, grid, &origins())?;
                self.push = Some(loaded);
                loaded
            }
        };
        let c = plan.channels as usize;
        let ctx = Arc::clone(sub.context());
        let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "diffusion moments")?;
        // The last order's moments were read on the host after a wait; the sweeps wrote the source.
        rec.compute_to_transfer();
        rec.fill_buffer(&buffers.moments, 0, vk::WHOLE_SIZE, 0);
        rec.transfer_to_compute();
        rec.compute_to_compute();
        for round in 0..rounds {
            let push = DiffusionPush { first: round * push.round_voxels, ..push };
            dispatch(&mut rec, &self.moments_pipeline, &self.moments_set, push.unknowns, push)?;
            rec.compute_to_compute();
        }
        rec.compute_to_host();
        sub.submit_and_wait(rec)?;
        sub.count_transfer(0, (n * c * 8) as u64);
        let moments: Vec<Vec<f64>> = readback::<f64>(&buffers.moments, n * c)?.chunks(n).map(<[f64]>::to_vec).collect();
        let change: Vec<f64> = grid.solve(&moments).concat();
        let bytes: &[u8] = bytemuck::cast_slice(&change);
        let staged = buffers
            .staging
            .bytes_mut()
            .get_mut(..bytes.len())
            .ok_or(SolveError::Internal("the diffusion change is larger than its staging"))?;
        staged.copy_from_slice(bytes);
        let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "diffusion prolong")?;
        // The last order's prolongation read the change this copy overwrites.
        rec.compute_to_transfer();
        let size = bytes.len() as u64;
        rec.copy_buffer(&buffers.staging, &buffers.change, &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size }]);
        rec.transfer_to_compute();
        dispatch(&mut rec, &self.prolong_pipeline, &self.prolong_set, self.voxels, push)?;
        sub.submit_and_wait(rec)?;
        sub.count_transfer(size, 0);
        Ok(())
    }

    /// Puts the grid's tables on the device (once: the grid does not change during a solve) and
    /// returns the kernels' push constants and the moments kernel's rounds.
    fn load_grid(
        &self,
        sub: &mut Submitter,
        plan: &Plan,
        buffers: &mut DiffusionBuffers,
        grid: &Acceleration,
        origins: &[[u32; 4]],
    ) -> Result<(DiffusionPush, u32), SolveError> {
        let tables = GridTables::new(grid, origins);
        let solid_angles = &plan.storage.solid_angle;
        let staging = &mut buffers.staging;
        for (bytes, dst) in [
            (bytemuck::cast_slice::<u32, u8>(grid.unknown_of()), &buffers.unknown_of),
            (bytemuck::cast_slice(&tables.cell_of_unknown), &buffers.cell_of_unknown),
            (bytemuck::cast_slice(&tables.brick_start), &buffers.brick_start),
            (bytemuck::cast_slice(&tables.bricks), &buffers.bricks),
            (bytemuck::cast_slice(solid_angles), &buffers.solid_angles),
        ] {
            upload(sub, staging, dst, bytes)?;
        }
        let count = |v: usize| u32::try_from(v).map_err(|_| SolveError::Internal("a diffusion grid too large"));
        // Each cell's voxels: a box of min(e, 16)³ in each of its bricks, walked in rounds.
        let box_voxels = grid.edge().min(BRICK_EDGE).pow(3);
        let most_bricks = tables.brick_start.windows(2).map(|w| w[1] - w[0]).max().unwrap_or(0);
        // Rounds only where a CPU implementation (llvmpipe) limits an invocation's loops; a GPU
        // walks every cell's voxels in one dispatch. The same additions in the same order either
        // way: the same bits.
        let round_voxels = if sub.context().limits().is_cpu {
            (ROUND_ITERATIONS / (1 + plan.channels + plan.source_components())).max(1)
        } else {
            (box_voxels * most_bricks).max(1)
        };
        let rounds = (box_voxels * most_bricks).div_ceil(round_voxels);
        let mut push = DiffusionPush {
            unknowns: count(grid.unknowns())?,
            comps: plan.source_components(),
            channels: plan.channels,
            edge: grid.edge(),
            cells: grid.cells(),
            round_voxels,
            albedo_grid: u32::from(plan.albedo_field),
            voxel_size: plan.voxel_size,
            four_pi: acceleration::four_pi(plan),
            ..DiffusionPush::default()
        };
        for ch in 0..plan.channels as usize {
            let (st, ss, _) = plan.coefficients(ch);
            push.extinction[ch] = st;
            push.scatter[ch] = ss;
        }
        Ok((push, rounds))
    }
}

/// Which bricks each unknown's cell overlaps, in slot order (the order the host's moments visit
/// them), as offsets into one list.
struct GridTables {
    cell_of_unknown: Vec<u32>,
    /// Unknown u's bricks are `bricks[brick_start[u]..brick_start[u + 1]]`.
    brick_start: Vec<u32>,
    bricks: Vec<u32>,
}

impl GridTables {
    fn new(grid: &Acceleration, origins: &[[u32; 4]]) -> GridTables {
        let (edge, cells, unknown_of) = (grid.edge(), grid.cells(), grid.unknown_of());
        let n = grid.unknowns();
        // The unknowns a brick overlaps, in any order: each brick is listed once per unknown.
        let overlapped = |o: &[u32; 4]| {
            let lo = [o[0] / edge, o[1] / edge, o[2] / edge];
            let hi = [0, 1, 2].map(|a| ((o[a] + BRICK_EDGE - 1) / edge).min(cells[a] - 1));
            (lo[2]..=hi[2]).flat_map(move |z| {
                (lo[1]..=hi[1]).flat_map(move |y| {
                    (lo[0]..=hi[0]).filter_map(move |x| {
                        let u = unknown_of[acceleration::cell_index(cells, [x, y, z])];
                        (u != u32::MAX).then_some(u as usize)
                    })
                })
            })
        };
        let mut brick_start = vec![0u32; n + 1];
        for o in origins {
            for u in overlapped(o) {
                brick_start[u + 1] += 1;
            }
        }
        for u in 0..n {
            brick_start[u + 1] += brick_start[u];
        }
        let mut next: Vec<u32> = brick_start[..n].to_vec();
        let mut bricks = vec![0u32; brick_start[n] as usize];
        for (slot, o) in origins.iter().enumerate() {
            for u in overlapped(o) {
                bricks[next[u] as usize] = slot as u32;
                next[u] += 1;
            }
        }
        let mut cell_of_unknown = vec![0u32; n];
        for (cell, &u) in unknown_of.iter().enumerate() {
            if u != u32::MAX {
                cell_of_unknown[u as usize] = cell as u32;
            }
        }
        GridTables { cell_of_unknown, brick_start, bricks }
    }
}

/// Records one dispatch of `count` invocations.
fn dispatch(
    rec: &mut Recorder,
    pipeline: &ComputePipeline,
    set: &DescriptorSet,
    count: u32,
    push: DiffusionPush,
) -> Result<(), SolveError> {
    dispatch_linear(rec, pipeline, set, count, |count, groups_x| DiffusionPush { count, groups_x, ..push })
}

/// Copies `bytes` into the start of `dst` through `staging`, a chunk at a time (waits).
fn upload(sub: &mut Submitter, staging: &mut HostBuffer, dst: &Buffer, bytes: &[u8]) -> Result<(), SolveError> {
    if bytes.len() as u64 > dst.size() {
        return Err(SolveError::Internal("a diffusion table is larger than its buffer"));
    }
    let chunk = staging.size() as usize;
    let ctx = Arc::clone(sub.context());
    for (i, part) in bytes.chunks(chunk).enumerate() {
        staging.bytes_mut()[..part.len()].copy_from_slice(part);
        let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "diffusion tables")?;
        rec.compute_to_transfer();
        let region = vk::BufferCopy { src_offset: 0, dst_offset: (i * chunk) as u64, size: part.len() as u64 };
        rec.copy_buffer(staging, dst, &[region]);
        rec.transfer_to_compute();
        sub.submit_and_wait(rec)?;
        sub.count_transfer(region.size, 0);
    }
    Ok(())
}
