//! The diffusion correction of the resident mode's orders on the device ([`crate::solver::antidiffusion`]),
//! so a plan that corrects (the default for a scattering medium) keeps its fields there between
//! orders.
//!
//! After an order's sweeps (and the acceleration's fold), `glsl/sharpen.comp` writes into a
//! resident buffer of its own what the next order propagates, C(T + S) − C(T), from the committed
//! total T (before the commit adds S) and the order's raw source S; the commit then adds S to the
//! total as the host's does, and the next order's previous source is made from the sharpened
//! buffer instead of S. The kernel walks each voxel's partners two voxels away through a table of
//! the bricks' slots, across periodic axes and mirrors as the host does, and computes every value
//! with the host's f64 operations in the host's order — the stability limit's exponential too,
//! which is why the host uses a portable one ([`crate::solver::antidiffusion::exp_neg`]) — so the
//! answer is the streamed mode's to the bit (`tests/it/resident.rs`). A voxel's scattering weight
//! is its density times its albedo factor (the resident albedo grid's, 1 without one).

use super::buffers::{ResidentBuffers, SharpenBuffers, TotalBuffers};
use super::kernels::{self, dispatch_linear};
pub use super::kernels::{SharpenConstants, SharpenPush};
use super::owned::Owned;
use super::sizes::SHARPEN_CONSTANTS;
use crate::solver::antidiffusion::{self, Sharpening};
use crate::solver::plan::Plan;
use crate::solver::SolveError;
use crate::store::BRICK_VOXELS;
use crate::vk::{ComputePipeline, Context, DescriptorSet, Recorder};
use std::sync::Arc;

const _: () = assert!(std::mem::size_of::<SharpenConstants>() as u64 == SHARPEN_CONSTANTS * 8);

impl SharpenConstants {
    /// The plan's, as [`Sharpening::of`] and [`Sharpening::stable_share`] compute them.
    pub fn of(plan: &Plan) -> SharpenConstants {
        let how = Sharpening::of(plan);
        let boost: f64 = how.kappa.iter().sum();
        SharpenConstants {
            kappa_w: how.kappa.map(|k| antidiffusion::PARTNER_WEIGHT * k),
            thickness: how.thickness,
            albedo: how.albedo,
            two_thirds: 2.0 / 3.0,
            boost,
            one_plus_boost: 1.0 + boost,
            growth: antidiffusion::LARGEST_VOXEL_PATTERN_GROWTH,
            small: antidiffusion::SMALL_THICKNESS,
            flux_share: antidiffusion::LARGEST_FLUX_SHARE,
            log2_e: std::f64::consts::LOG2_E,
            ln2_hi: antidiffusion::LN2_HI,
            ln2_lo: antidiffusion::LN2_LO,
            exp_limit: antidiffusion::EXP_NEG_LIMIT,
        }
    }
}

/// The kernel and its set over the resident buffers.
pub struct DeviceSharpening {
    set: Owned<DescriptorSet>,
    push: SharpenPush,
    /// Declared after the set, so freed after it.
    pipeline: Owned<ComputePipeline>,
}

impl DeviceSharpening {
    /// The pipeline and set over `resident` and `totals` (`occupied` bricks of a volume of
    /// `bricks` bricks per axis); `None` when the plan does not correct (no buffers for it).
    pub fn new(
        ctx: &Arc<Context>,
        plan: &Plan,
        resident: &ResidentBuffers,
        totals: &TotalBuffers,
        occupied: u64,
        bricks: [u32; 3],
    ) -> Result<Option<Self>, SolveError> {
        let Some(SharpenBuffers { sharpened, brick_slots, constants, .. }) = totals.sharpen.as_ref() else {
            return Ok(None);
        };
        let pipeline = kernels::SHARPEN.pipeline(ctx)?;
        let set = kernels::SHARPEN.set(
            ctx,
            "sharpen",
            &pipeline,
            &[
                ("Density", &resident.density),
                ("Total", &totals.source_total),
                ("Raw", &resident.source_next),
                ("Sharpened", sharpened),
                ("BrickSlots", brick_slots),
                ("Origins", &totals.origins),
                ("Constants", constants),
                // Unread without an albedo grid: any buffer will do.
                ("Albedo", totals.albedo.as_ref().unwrap_or(&resident.density)),
            ],
        )?;
        let mut flags = if plan.albedo_field { 1 << 9 } else { 0 };
        for axis in 0..3 {
            if plan.periodic[axis] {
                flags |= 1 << axis;
            }
            for side in 0..2 {
                if plan.reflective[axis][side] {
                    flags |= 1 << (3 + 2 * axis + side);
                }
            }
        }
        let count = u32::try_from(occupied * BRICK_VOXELS as u64)
            .map_err(|_| SolveError::Internal("more resident voxels than a dispatch can reach"))?;
        let push = SharpenPush {
            count,
            comps: plan.source_components(),
            channels: plan.channels,
            dims: plan.dims,
            flags,
            bricks: [bricks[0], bricks[1]],
            ..SharpenPush::default()
        };
        Ok(Some(DeviceSharpening { set, push, pipeline }))
    }

    /// Records the pass over every voxel: the sharpened buffer takes C(T + S) − C(T) (the
    /// committed total T not yet holding the order's source S).
    pub fn record(&self, rec: &mut Recorder) -> Result<(), SolveError> {
        dispatch_linear(rec, &self.pipeline, &self.set, self.push.count, |count, groups_x| SharpenPush {
            count,
            groups_x,
            ..self.push
        })
    }
}
