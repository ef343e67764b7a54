//! The encoder: turns one (sub-)slice's compute step into commands: the push constants, the
//! buffers bound to each kernel, and the dispatches (directions in groups of
//! `directions_per_dispatch`, planes in chunks of `planes_per_dispatch`, each `propagate.comp`
//! followed by `collect.comp` unless the slice is vacuum).
//!
//! The buffers the kernels bind are listed here too ([`SWEEP_BINDINGS`], [`super::buffers::sweep_bindings`]): both
//! kernels share one pipeline layout, so one descriptor set per sweep and slot serves both. The
//! resources write the sets once per solve; a step binds its set once, by handle, and only
//! switches pipelines between the kernels (the command buffer is the step's own, so this is as
//! seldom as a set can be bound).
//!
//! It records into a [`Recorder`] and submits nothing: when to submit and what to wait for is the
//! streamer's business (`streamer`).

use super::budget::MemoryPlan;
use super::buffers::SweepSets;
use super::layout::{
    half_source_flags, SweepPush, FLAG_CARRY, FLAG_EXITS, FLAG_GAIN, FLAG_LATERAL_MAJOR, FLAG_VACUUM,
    LATERAL_PERIODIC_B, LATERAL_PERIODIC_C,
};
use super::resources::DeviceResources;
use super::slice::SliceLayout;
use super::tables::SweepTables;
use crate::solver::plan::Plan;
use crate::solver::sweep::FaceSweep;
use crate::solver::SolveError;
use crate::vk::{Buffer, Recorder};
use ash::vk;
use std::ops::Range;

/// Workgroup size of both kernels (`local_size_x`, `local_size_y` in glsl/common.glsl): rays
/// along the sweep's lateral axes b and c. `tests/it/shader_interface.rs` checks it against the
/// SPIR-V.
pub const LOCAL_SIZE: [u32; 2] = [super::kernels::SWEEP_LOCAL_SIZE[0], super::kernels::SWEEP_LOCAL_SIZE[1]];

/// One (sub-)slice's compute step.
pub struct ComputeStep<'s> {
    /// The slot holding the slice's buffers; `None`: a vacuum slice.
    pub slot: Option<usize>,
    pub layout: &'s SliceLayout,
    pub tables: &'s SweepTables,
    /// The sweep's descriptor sets.
    pub sets: &'s SweepSets,
    pub sweep: &'s FaceSweep,
    /// The directions of the pass, as indices into the sweep's tables.
    pub pass_dirs: Range<u32>,
    /// FLAG_BOUNDARY / FLAG_GAIN / FLAG_EMIT of the sweep.
    pub flags: u32,
    /// The f16 previous source's scale exponent (`None`: f32).
    pub half_exponent: Option<i32>,
    /// The first slice of the pass (the ray state starts from zero).
    pub first: bool,
    /// The resident mode: the slice's slot table (store slots of its bricks), written into the
    /// resident slot-table buffer (the second) before the kernels run. `None`: streamed (the
    /// upload brought it).
    pub resident_table: Option<(&'s [i32], &'s Buffer)>,
}

/// The workgroups of one `propagate.comp` dispatch over `sweep`'s rays (n + 1 per lateral axis:
/// see `solver::sweep`), `depth` directions along z.
pub fn ray_workgroups(sweep: &FaceSweep, depth: u32) -> [u32; 3] {
    let [lb, lc] = sweep.lattice();
    [lb.div_ceil(LOCAL_SIZE[0]), lc.div_ceil(LOCAL_SIZE[1]), depth]
}

/// The workgroups of one `collect.comp` dispatch over `sweep`'s voxels, `depth` planes along z.
pub fn voxel_workgroups(sweep: &FaceSweep, depth: u32) -> [u32; 3] {
    [sweep.n[1].div_ceil(LOCAL_SIZE[0]), sweep.n[2].div_ceil(LOCAL_SIZE[1]), depth]
}

/// The push constants of a step, with the dispatch-dependent fields (directions, planes, flags)
/// left to [`record_compute`].
pub fn push_constants(plan: &Plan, sweep: &FaceSweep, layout: &SliceLayout) -> SweepPush {
    let face = sweep.geometry();
    let coefficient = |ch: usize| plan.coefficients(ch.min(plan.channels as usize - 1));
    let vec4 = |f: &dyn Fn(usize) -> f64| [f(0) as f32, f(1) as f32, f(2) as f32, 0.0];
    SweepPush {
        na: sweep.n[0],
        nb: sweep.n[1],
        nc: sweep.n[2],
        t0: 0,
        t1: 0,
        axis_sign: face.axis as u32 | if face.sign < 0.0 { 4 } else { 0 },
        lateral: face.lateral[0] as u32
            | (face.lateral[1] as u32) << 2
            | if sweep.periodic[1] { LATERAL_PERIODIC_B } else { 0 }
            | if sweep.periodic[2] { LATERAL_PERIODIC_C } else { 0 },
        bricks_b: layout.bricks_b,
        bricks_c: layout.bricks_c,
        dir_count: 0,
        channels: plan.channels,
        storage: plan.storage.len() as u32,
        flags: 0,
        dir_base: 0,
        ray_base: 0,
        slab: layout.range.slab_lo | layout.range.slab_planes << 8,
        sigma_t: vec4(&|ch| coefficient(ch).0),
        sigma_s: vec4(&|ch| coefficient(ch).1),
        emission: vec4(&|ch| coefficient(ch).2 * plan.medium.emission[ch]),
    }
}

/// The shared descriptor set's bindings, by the name of the buffer block each kernel declares
/// there: `propagate.comp` uses 0..=8 and 12, `collect.comp` 0..=3 and 8..=11. `tests/it/shader_interface.rs`
/// checks these names and numbers against both kernels' SPIR-V.
pub use super::kernels::SWEEP_BINDINGS;

/// Records a step's dispatches into `rec` (the barriers between them included).
pub fn record_compute(
    rec: &mut Recorder,
    res: &DeviceResources,
    plan: &Plan,
    memory: &MemoryPlan,
    step: &ComputeStep,
) -> Result<(), SolveError> {
    let shared = &res.shared;
    let vacuum = if step.slot.is_none() { FLAG_VACUUM } else { 0 };
    let half = match step.half_exponent {
        Some(e) if step.flags & FLAG_GAIN != 0 => half_source_flags(e),
        _ => 0,
    };
    // An x sweep's slabs are lateral-major (the resident buffers too: the driver reorders them
    // before the x sweeps, super::transpose).
    let order = if step.layout.lateral_major { FLAG_LATERAL_MAJOR } else { 0 };
    // The side exits are recorded where they happen when the solve makes exitance maps.
    let exits = if memory.exit_maps { FLAG_EXITS } else { 0 };
    // Earlier compute submissions wrote the ray state and the deposit this one uses.
    rec.compute_to_compute();
    if let Some((table, buffer)) = step.resident_table {
        // The previous step's kernels read the table this write replaces.
        rec.compute_to_transfer();
        rec.update_buffer(buffer, 0, bytemuck::cast_slice(table));
        rec.transfer_to_compute();
    }
    if step.first {
        if step.flags & FLAG_CARRY != 0 {
            // The rays start with what the host put in the staging buffer (solver::periodic): the
            // pass's directions, [dir][ch][ray], as the ray buffer holds them.
            let bytes = step.pass_dirs.len() as u64 * plan.channels as u64 * step.sweep.rays() as u64 * 4;
            rec.copy_buffer(
                &shared.tallies,
                &shared.rays,
                &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size: bytes }],
            );
        } else {
            rec.fill_buffer(&shared.rays, 0, vk::WHOLE_SIZE, 0);
        }
        for b in [&shared.rays_out_b, &shared.rays_out_c] {
            rec.fill_buffer(b, 0, vk::WHOLE_SIZE, 0);
        }
        rec.transfer_to_compute();
    }
    let tables = step.tables;
    let sets = &step.sets.slots;
    // The slot's set, or the vacuum's (the last; a vacuum slice collects nothing), bound once for
    // both kernels: they share the pipeline layout, so switching pipelines keeps it bound.
    let set = &sets[step.slot.unwrap_or(sets.len() - 1)];
    let collect = step.slot.is_some();
    rec.bind(&res.propagate, set)?;
    let mut on_collect = false;
    let mut push = push_constants(plan, step.sweep, step.layout);
    let range = step.layout.range;
    let group = memory.directions_per_dispatch;
    let chunk = memory.planes_per_dispatch;
    let dirs = step.pass_dirs.clone();
    let mut base = dirs.start;
    while base < dirs.end {
        let n = group.min(dirs.end - base);
        push.dir_base = base;
        push.ray_base = base - dirs.start;
        push.dir_count = n;
        let mut t0 = range.t0;
        while t0 < range.t1 {
            let t1 = (t0 + chunk).min(range.t1);
            push.t0 = t0;
            push.t1 = t1;
            push.flags = step.flags | vacuum | half | order | exits;
            // Across vacuum, rays that do not move sideways keep everything: the kernel would
            // only read and write back the ray state (a big share of a sparse volume's time).
            // After the last slice the ray buffer holds what leaves through the far face.
            if step.slot.is_none() && tables.still(base..base + n, t0, t1) {
                t0 = t1;
                continue;
            }
            let bytes = bytemuck::bytes_of(&push);
            if on_collect {
                rec.switch_pipeline(&res.propagate, set)?;
                on_collect = false;
            }
            rec.dispatch_bound(&res.propagate, bytes, ray_workgroups(step.sweep, n))?;
            rec.compute_to_compute();
            if collect {
                rec.switch_pipeline(&res.collect, set)?;
                on_collect = true;
                rec.dispatch_bound(&res.collect, bytes, voxel_workgroups(step.sweep, t1 - t0))?;
                rec.compute_to_compute();
            }
            t0 = t1;
        }
        base += n;
    }
    Ok(())
}
