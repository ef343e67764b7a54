//! The resident mode's change of order for the x sweeps.
//!
//! The kernels march one ray per thread; neighbouring threads are neighbouring rays along the
//! sweep's first lateral axis b. In a brick's own order (x fastest) that is neighbouring words for
//! the y and z sweeps (b = x), but 64 bytes apart for the x sweeps (b = y): a GPU would fetch a
//! whole memory sector for every value the x sweeps read. So the x sweeps run on lateral-major
//! slabs (`FLAG_LATERAL_MAJOR`, y fastest). A streamed pass gets them from the copy workers, who
//! transpose while they gather ([`super::slice`]). The resident buffers hold every brick for the
//! whole solve, so they are reordered on the device instead: `glsl/transpose.comp` permutes each
//! brick block in place (no buffer of its own, bitwise: a permutation), before the first x sweep
//! and back before the first sweep along y or z, and before the order's fields come home. The
//! faces sweep x first ([`crate::quadrature::cube_face::FACES`]), so an order reorders twice (a
//! few times more in order 0, whose beams and sky sweep between).

use super::buffers::ResidentBuffers;
use super::kernels;
pub use super::kernels::TransposePush;
use super::owned::Owned;
use crate::solver::plan::Plan;
use crate::solver::SolveError;
use crate::vk::{ComputePipeline, Context, DescriptorSet, Recorder};
use std::sync::Arc;

/// Workgroups along x of one dispatch at most (the smallest `maxComputeWorkGroupCount` a device
/// may have); more blocks go along y.
const MAX_GROUPS_X: u32 = 65535;

const _: () = assert!(std::mem::size_of::<TransposePush>() == 16);

/// One resident field's set and its shape.
struct Field {
    set: Owned<DescriptorSet>,
    /// Brick blocks of 4096 values.
    blocks: u32,
    half_values: bool,
}

/// The transpose pipeline and one descriptor set per resident field.
pub struct Transposer {
    fields: Vec<Field>,
    /// Declared after the sets, so freed after them.
    pipeline: Owned<ComputePipeline>,
}

impl Transposer {
    /// The pipeline and the sets for `resident`, whose fields hold `occupied` bricks.
    pub fn new(ctx: &Arc<Context>, plan: &Plan, resident: &ResidentBuffers, occupied: u64) -> Result<Self, SolveError> {
        let pipeline = kernels::TRANSPOSE.pipeline(ctx)?;
        let comps = plan.source_components() as u64;
        let half = plan.source_precision.bytes() == 2;
        let shapes = [
            (&*resident.density, "density", 1, false),
            (&*resident.source_prev, "source prev", comps, half),
            (&*resident.source_next, "source next", comps, false),
            (&*resident.fluence, "fluence", plan.channels as u64, false),
        ];
        let mut fields = Vec::with_capacity(shapes.len());
        for (buffer, name, components, half_values) in shapes {
            let blocks = u32::try_from(occupied * components)
                .map_err(|_| SolveError::Internal("more resident brick blocks than a dispatch can reach"))?;
            let set = kernels::TRANSPOSE.set(ctx, &format!("transpose {name}"), &pipeline, &[("Field", buffer)])?;
            fields.push(Field { set, blocks, half_values });
        }
        Ok(Transposer { fields, pipeline })
    }

    /// Records the reorder of every resident field: into the x sweeps' lateral-major order when
    /// `to_lateral`, else back into brick order. Barriers on both sides: the kernels (and the
    /// load's copies) before wrote these buffers, those after read them.
    pub fn record(&self, rec: &mut Recorder, to_lateral: bool) -> Result<(), SolveError> {
        rec.compute_to_compute();
        rec.transfer_to_compute();
        for field in self.fields.iter().filter(|f| f.blocks > 0) {
            let groups_x = field.blocks.min(MAX_GROUPS_X);
            let push = TransposePush {
                blocks: field.blocks,
                half_values: field.half_values as u32,
                to_lateral: to_lateral as u32,
                groups_x,
            };
            rec.bind(&self.pipeline, &field.set)?;
            rec.dispatch_bound(
                &self.pipeline,
                bytemuck::bytes_of(&push),
                [groups_x, field.blocks.div_ceil(groups_x), 1],
            )?;
        }
        rec.compute_to_compute();
        rec.compute_to_transfer();
        Ok(())
    }
}
