//! The passes between orders on the device, for the resident mode: the fields stay there from the
//! first order to the last, and cross the bus only at checkpoints and at the end.
//!
//! In the streamed mode (and the CPU twin) the host commits each order ([`crate::solver::passes::OrderFieldSet::commit_order`]
//! and the stop rule's [`crate::solver::passes::OrderFieldSet::remaining_error`]), so the resident mode used to bring the
//! new source and the fluence home after every order. Here the committed totals are resident too,
//! and four kernels do the host's work:
//!
//! - `block_sums.comp`: per block (one component of one brick) Σ|J| and the largest |J| of the new
//!   source; the host turns the sums into the order's scattered power exactly as its commit does
//!   ([`block_power`]) and the largest value into the next order's f16 scale;
//! - `commit.comp`: `total += order`, for the source and the fluence;
//! - `to_half.comp`: the next order's previous source, the new one rounded to f16 (as the copy
//!   workers round it on the way up); at f32 it is a copy;
//! - `remaining.comp`: the stop rule's tally, brick by brick ([`super::super::remaining`]).
//!
//! Every value is bitwise what the host's passes give in the streamed mode (`glsl/exact.glsl` says
//! how: f32 values are read from their bits, so a device that flushes denormals does too; each
//! sum runs in the host's order, one invocation per block or brick), so the answer, the orders and
//! the stop decisions are the streamed mode's (`tests/it/resident.rs`). Vulkan promises correctly
//! rounded f64 +, − and ×, but not a correctly rounded f64 division (nor a fused fma), so every f64
//! division of these kernels (the remaining error's e_v, the acceleration's σs·g/4π, the diffusion
//! correction's fluxes and stability share) goes through `div_rn` (glsl/exact.glsl): Newton steps
//! with exact residuals from + − × alone, and the rounding decided between neighbours, so the
//! quotient is the host's on any conformant device (`tests/it/exact_division.rs`, which starts it
//! from quotients spoiled on purpose).
//!
//! Before the commit, when the plan asks for them: with a per-voxel albedo, `albedo_scale.comp`
//! multiplies the new source by each voxel's factor (resident from the first load); then the
//! diffusion acceleration's fold
//! (`super::accelerate`: its kernels restrict the order to the diffusion grid and prolong the
//! correction; the host solves on the grid) and the diffusion correction (`super::sharpen`: what
//! the next order propagates goes into a buffer of its own, which `to_half.comp` then reads; the
//! commit adds the raw source to the total, as the host's does).
//!
//! What stays on the host: a warm start's first commit (the fields come home for that order, and
//! stay on the device from the next one). A device without `shaderFloat64` and `shaderInt64`
//! keeps every pass there and brings the fields home every order, and says so ([`super::budget::EndOfOrder`]).
//! The energy books and the tail run once, after the fields come home at the end.

use super::buffers::{ResidentBuffers, TotalBuffers};
use super::kernels;
pub use super::kernels::{dispatch_linear, readback, BlockSum, EndPush, GpuUnitTally};
use super::owned::Owned;
use super::resources::DeviceResources;
use super::sharpen::DeviceSharpening;
use super::sizes::{BLOCK_SUM_BYTES, UNIT_TALLY_BYTES};
use super::submit::Submitter;
use crate::solver::passes::block_power;
use crate::solver::plan::{Plan, Precision};
use crate::solver::remaining::{self, RemainingError, UnitTally};
use crate::solver::SolveError;
use crate::store::Field;
use crate::vk::{Buffer, ComputePipeline, Context, DescriptorSet, Recorder};
use ash::vk;
use std::sync::Arc;

const _: () = assert!(std::mem::size_of::<BlockSum>() as u64 == BLOCK_SUM_BYTES);
const _: () = assert!(std::mem::size_of::<GpuUnitTally>() as u64 == UNIT_TALLY_BYTES);

/// The kernels and their descriptor sets over the resident buffers.
pub struct EndPasses {
    source_sums: Owned<DescriptorSet>,
    /// With the diffusion correction: the kernel that writes what the next order propagates,
    /// and the block sums over it (for its largest value).
    sharpening: Option<(DeviceSharpening, Owned<DescriptorSet>)>,
    commit_source: Owned<DescriptorSet>,
    commit_fluence: Owned<DescriptorSet>,
    /// `None` when the source is stored at f32 (the next order's previous source is a copy).
    to_half: Option<Owned<DescriptorSet>>,
    remaining: Owned<DescriptorSet>,
    /// With a per-voxel albedo: the new source scaled by it (`None`: uniform albedo).
    albedo_scale: Option<Owned<DescriptorSet>>,
    /// Values (source, fluence) and blocks of the source; bricks.
    source_values: u32,
    fluence_values: u32,
    blocks: u32,
    bricks: u32,
    /// Declared after the sets, so freed after them.
    block_sums_pipeline: Owned<ComputePipeline>,
    commit_pipeline: Owned<ComputePipeline>,
    to_half_pipeline: Owned<ComputePipeline>,
    remaining_pipeline: Owned<ComputePipeline>,
    albedo_scale_pipeline: Owned<ComputePipeline>,
}

/// What a commit on the device found: the order's scattered power per channel, and the largest
/// |J| of its new source (the next order's f16 scale).
pub struct Committed {
    pub power: [f64; 3],
    pub max_abs: f32,
}

impl EndPasses {
    /// The pipelines and the sets over `resident` and `totals`, which hold `occupied` bricks of a
    /// volume of `bricks` bricks per axis.
    pub fn new(
        ctx: &Arc<Context>,
        plan: &Plan,
        resident: &ResidentBuffers,
        totals: &TotalBuffers,
        occupied: u64,
        bricks: [u32; 3],
    ) -> Result<Self, SolveError> {
        let block_sums_pipeline = kernels::BLOCK_SUMS.pipeline(ctx)?;
        let commit_pipeline = kernels::COMMIT.pipeline(ctx)?;
        let to_half_pipeline = kernels::TO_HALF.pipeline(ctx)?;
        let remaining_pipeline = kernels::REMAINING.pipeline(ctx)?;
        let albedo_scale_pipeline = kernels::ALBEDO_SCALE.pipeline(ctx)?;
        let TotalBuffers { source_total, fluence_total, block_sums, unit_tallies, .. } = totals;
        // What the next order propagates: the sharpened source with the diffusion correction.
        let propagated = propagated(resident, totals);
        let sharpening = match (DeviceSharpening::new(ctx, plan, resident, totals, occupied, bricks)?, &totals.sharpen)
        {
            (Some(kernel), Some(s)) => Some((
                kernel,
                kernels::BLOCK_SUMS.set(
                    ctx,
                    "sharpened sums",
                    &block_sums_pipeline,
                    &[("Field", propagated), ("Sums", &s.sums)],
                )?,
            )),
            _ => None,
        };
        let (comps, c) = (plan.source_components() as u64, plan.channels as u64);
        let count = |n: u64| {
            u32::try_from(n).map_err(|_| SolveError::Internal("more resident values than a dispatch can reach"))
        };
        let voxels = occupied * crate::store::BRICK_VOXELS as u64;
        Ok(EndPasses {
            source_sums: kernels::BLOCK_SUMS.set(
                ctx,
                "block sums",
                &block_sums_pipeline,
                &[("Field", &resident.source_next), ("Sums", block_sums)],
            )?,
            sharpening,
            commit_source: kernels::COMMIT.set(
                ctx,
                "commit source",
                &commit_pipeline,
                &[("Total", source_total), ("Order", &resident.source_next)],
            )?,
            commit_fluence: kernels::COMMIT.set(
                ctx,
                "commit fluence",
                &commit_pipeline,
                &[("Total", fluence_total), ("Order", &resident.fluence)],
            )?,
            to_half: match plan.source_precision {
                Precision::F16 => Some(kernels::TO_HALF.set(
                    ctx,
                    "to half",
                    &to_half_pipeline,
                    &[("Half", &resident.source_prev), ("Full", propagated)],
                )?),
                Precision::F32 => None,
            },
            remaining: kernels::REMAINING.set(
                ctx,
                "remaining",
                &remaining_pipeline,
                &[
                    ("Density", &resident.density),
                    ("Total", fluence_total),
                    ("Newest", &resident.fluence),
                    ("Tallies", unit_tallies),
                ],
            )?,
            source_values: count(voxels * comps)?,
            fluence_values: count(voxels * c)?,
            blocks: count(occupied * comps)?,
            bricks: count(occupied)?,
            block_sums_pipeline,
            commit_pipeline,
            to_half_pipeline,
            albedo_scale: match &totals.albedo {
                Some(albedo) => Some(kernels::ALBEDO_SCALE.set(
                    ctx,
                    "albedo scale",
                    &albedo_scale_pipeline,
                    &[("Source", &resident.source_next), ("Albedo", albedo)],
                )?),
                None => None,
            },
            remaining_pipeline,
            albedo_scale_pipeline,
        })
    }

    /// Records one dispatch over `count` invocations.
    fn dispatch(
        rec: &mut Recorder,
        pipeline: &ComputePipeline,
        set: &DescriptorSet,
        count: u32,
        push: EndPush,
    ) -> Result<(), SolveError> {
        dispatch_linear(rec, pipeline, set, count, |count, groups_x| EndPush { count, groups_x, ..push })
    }

    /// Commits the order the sweeps just finished: with the diffusion correction first what the
    /// next order propagates (from the total before this order joins it); the new source's block
    /// sums (and the sharpened one's); then the new source and the fluence added into the totals.
    /// One submission; waits, and returns the power and the next order's largest value.
    pub fn commit(&self, sub: &mut Submitter, plan: &Plan, totals: &TotalBuffers) -> Result<Committed, SolveError> {
        let ctx = Arc::clone(sub.context());
        let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "commit on the device")?;
        rec.compute_to_compute();
        rec.transfer_to_compute();
        if let Some((kernel, _)) = &self.sharpening {
            // From the total before this order's source joins it.
            kernel.record(&mut rec)?;
            rec.compute_to_compute();
        }
        let push = EndPush::default();
        Self::dispatch(&mut rec, &self.block_sums_pipeline, &self.source_sums, self.blocks, push)?;
        if let Some((_, sharpened_sums)) = &self.sharpening {
            Self::dispatch(&mut rec, &self.block_sums_pipeline, sharpened_sums, self.blocks, push)?;
        }
        Self::dispatch(&mut rec, &self.commit_pipeline, &self.commit_source, self.source_values, push)?;
        Self::dispatch(&mut rec, &self.commit_pipeline, &self.commit_fluence, self.fluence_values, push)?;
        rec.compute_to_host();
        sub.submit_and_wait(rec)?;
        let sums: &[BlockSum] = readback(&totals.block_sums, self.blocks as usize)?;
        let mut power = [0.0; 3];
        let mut max_bits = 0u32;
        for (block, s) in sums.iter().enumerate() {
            block_power(plan, &mut power, block, s.abs_sum);
            max_bits = max_bits.max(s.max_abs_bits);
        }
        if let Some(s) = &totals.sharpen {
            // The power is the raw source's (what the total took), the next order's f16 scale
            // the sharpened one's (what it propagates).
            max_bits =
                readback::<BlockSum>(&s.sums, self.blocks as usize)?.iter().fold(0, |m, s| m.max(s.max_abs_bits));
        }
        Ok(Committed { power, max_abs: f32::from_bits(max_bits) })
    }

    /// With a per-voxel albedo, multiplies the order's new source by each voxel's factor, as the
    /// host's commit first does (the sweeps scatter with the medium's albedo). Waits.
    pub fn scale_by_albedo(&self, sub: &mut Submitter, plan: &Plan) -> Result<(), SolveError> {
        let Some(set) = &self.albedo_scale else { return Ok(()) };
        let ctx = Arc::clone(sub.context());
        let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "albedo scale on the device")?;
        rec.compute_to_compute();
        rec.transfer_to_compute();
        let push = EndPush { mode: plan.source_components(), ..EndPush::default() };
        Self::dispatch(&mut rec, &self.albedo_scale_pipeline, set, self.source_values, push)?;
        sub.submit_and_wait(rec)
    }

    /// Records the start of an order after a commit on the device: the new source becomes the
    /// previous one (rounded to f16 with 2^`half_exponent` when stored so), and the order's
    /// accumulators are cleared.
    pub fn record_advance(
        &self,
        rec: &mut Recorder,
        resident: &ResidentBuffers,
        totals: &TotalBuffers,
        half_exponent: Option<i32>,
    ) -> Result<(), SolveError> {
        rec.compute_to_compute();
        rec.compute_to_transfer();
        match (&self.to_half, half_exponent) {
            (Some(set), Some(exponent)) => {
                let push = EndPush { param: exponent, ..EndPush::default() };
                Self::dispatch(rec, &self.to_half_pipeline, set, self.source_values / 2, push)?;
                rec.compute_to_transfer();
            }
            (None, None) => {
                let size = resident.source_next.size();
                rec.copy_buffer(
                    propagated(resident, totals),
                    &resident.source_prev,
                    &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size }],
                );
                rec.transfer_to_transfer();
            }
            _ => return Err(SolveError::Internal("the f16 scale does not match the plan's precision")),
        }
        rec.fill_buffer(&resident.source_next, 0, vk::WHOLE_SIZE, 0);
        rec.fill_buffer(&resident.fluence, 0, vk::WHOLE_SIZE, 0);
        rec.transfer_to_compute();
        Ok(())
    }

    /// The stop rule's remaining error after a commit on the device, for the tail `factor` per
    /// channel: the brightest fluence brick by brick, then each brick's tally under its dark floor,
    /// added up in brick order as the host's pass adds its units.
    pub fn remaining(
        &self,
        sub: &mut Submitter,
        plan: &Plan,
        totals: &TotalBuffers,
        factor: [f64; 3],
    ) -> Result<RemainingError, SolveError> {
        let ctx = Arc::clone(sub.context());
        let push = EndPush { param: plan.channels as i32, factor, ..EndPush::default() };
        let mut run = |mode: u32, dark_floor: f64| -> Result<Vec<GpuUnitTally>, SolveError> {
            let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "remaining error on the device")?;
            rec.compute_to_compute();
            let push = EndPush { mode, dark_floor, ..push };
            Self::dispatch(&mut rec, &self.remaining_pipeline, &self.remaining, self.bricks, push)?;
            rec.compute_to_host();
            sub.submit_and_wait(rec)?;
            Ok(readback::<GpuUnitTally>(&totals.unit_tallies, self.bricks as usize)?.to_vec())
        };
        let brightest = run(0, 0.0)?.iter().map(|t| t.brightest).fold(0.0, f64::max);
        let tallies = run(1, remaining::dark_floor(brightest))?;
        Ok(remaining::finish(tallies.iter().map(|t| UnitTally {
            sum_sq: t.sum_sq,
            max: f32::from_bits(t.max_e_bits) as f64,
            count: t.count as u64,
        })))
    }
}

/// The resident buffer that holds what the next order propagates: the sharpened source with the
/// diffusion correction, else the order's new source.
pub fn propagated<'b>(resident: &'b ResidentBuffers, totals: &'b TotalBuffers) -> &'b Buffer {
    match &totals.sharpen {
        Some(s) => &s.sharpened,
        None => &resident.source_next,
    }
}

/// Copies a whole field of the store into its resident buffer (both hold the occupied bricks in
/// slot order, laid out alike), through slot 0's upload staging, a chunk at a time. For the rare
/// moves: the committed totals and the albedo factor on the first load.
pub fn upload_field(
    sub: &mut Submitter,
    res: &DeviceResources,
    field: &Field,
    device: &Buffer,
) -> Result<(), SolveError> {
    let bytes: &[u8] = bytemuck::cast_slice(field.as_slice());
    if bytes.len() as u64 > device.size() {
        return Err(SolveError::Internal("a field is larger than its resident buffer"));
    }
    let staging = &res.slots.first().ok_or(SolveError::Internal("no slot staging for a field's transfer"))?.upload;
    let chunk = staging.size() as usize;
    let ctx = Arc::clone(sub.context());
    for (i, part) in bytes.chunks(chunk).enumerate() {
        let size = part.len() as u64;
        // SAFETY: the staging is mapped for `chunk` bytes, and no submission uses it now: the
        // pipeline is idle between orders (every earlier use was waited for).
        unsafe { std::ptr::copy_nonoverlapping(part.as_ptr(), staging.as_mut_ptr(), part.len()) };
        let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "resident field upload")?;
        rec.compute_to_transfer();
        rec.copy_buffer(staging, device, &[vk::BufferCopy { src_offset: 0, dst_offset: (i * chunk) as u64, size }]);
        rec.transfer_to_compute();
        sub.submit_and_wait(rec)?;
        sub.count_transfer(size, 0);
    }
    field.release_all();
    Ok(())
}

/// Copies a resident buffer home into its field of the store (the reverse of [`upload_field`]),
/// through slot 0's download staging: at checkpoints and at the end.
pub fn download_field(
    sub: &mut Submitter,
    res: &DeviceResources,
    field: &mut Field,
    device: &Buffer,
) -> Result<(), SolveError> {
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(field.as_mut_slice());
    if bytes.len() as u64 > device.size() {
        return Err(SolveError::Internal("a field is larger than its resident buffer"));
    }
    let staging = &res.slots.first().ok_or(SolveError::Internal("no slot staging for a field's transfer"))?.download;
    let chunk = staging.size() as usize;
    let ctx = Arc::clone(sub.context());
    for (i, part) in bytes.chunks_mut(chunk).enumerate() {
        let size = part.len() as u64;
        let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "resident field download")?;
        rec.compute_to_transfer();
        rec.copy_buffer(device, staging, &[vk::BufferCopy { src_offset: (i * chunk) as u64, dst_offset: 0, size }]);
        rec.transfer_to_host();
        sub.submit_and_wait(rec)?;
        part.copy_from_slice(&staging.bytes()[..part.len()]);
        sub.count_transfer(0, size);
    }
    field.release_all();
    Ok(())
}
