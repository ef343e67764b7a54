//! Every kernel lpm runs, once: its SPIR-V, the structs the host shares with it (push constants
//! and the structs it reads or writes in buffers), its storage buffers by binding, and its
//! workgroup size. The rest of the driver makes pipelines and descriptor sets through these
//! entries ([`Kernel::pipeline`], [`Kernel::set`], which refuses buffers named for other
//! bindings), and dispatches with their workgroup sizes; `tests/it/shader_interface.rs` iterates
//! [`ALL`] and checks each entry against the committed SPIR-V: every `glsl/*.comp` has an entry,
//! every push-constant and buffer struct member sits at the Rust struct's offset under the same
//! name, every binding is the block the host binds there, every workgroup size is the one the
//! host dispatches with. Change either side alone and that test fails.
//!
//! This is the bottom of the driver's layers: it imports nothing of it but the plain shared types
//! of [`super::layout`], and the modules that run the kernels import their structs from here.

use super::layout::{GpuDirection, SweepPush};
use super::owned::Owned;
use crate::solver::SolveError;
use crate::vk::{Buffer, BufferRange, ComputePipeline, Context, DescriptorSet, Recorder};
use bytemuck::{Pod, Zeroable};
use std::mem::{offset_of, size_of};
use std::sync::Arc;

/// A struct the host shares with a kernel: its members as (name, byte offset) in declaration
/// order, and its size.
#[derive(Clone, Copy, Debug)]
pub struct Members {
    pub fields: &'static [(&'static str, usize)],
    pub size: usize,
}

/// The members of a `#[repr(C)]` struct, by name and `offset_of!`.
macro_rules! members {
    ($ty:ty { $($field:ident),* $(,)? }) => {
        Members { fields: &[$((stringify!($field), offset_of!($ty, $field))),*], size: size_of::<$ty>() }
    };
}

/// One kernel: `glsl/<name>.comp`, compiled to `spirv/<name>.spv`.
#[derive(Clone, Copy, Debug)]
pub struct Kernel {
    pub name: &'static str,
    pub spirv: &'static [u8],
    /// The push-constant block.
    pub push: Members,
    /// The storage buffers it declares, as (binding in set 0, GLSL block name).
    pub bindings: &'static [(u32, &'static str)],
    /// Bindings of its pipeline layout: its own bindings, or, for the two sweep kernels, the one
    /// layout they share ([`SWEEP_BINDINGS`]).
    pub layout_bindings: u32,
    /// Structs in its buffers the host writes or reads, as (GLSL struct or block name, members).
    pub structs: &'static [(&'static str, Members)],
    /// `local_size` (x, y, z), as the host dispatches it.
    pub local_size: [u32; 3],
    /// Only the test suite runs it.
    pub test_only: bool,
}

impl Kernel {
    /// The pipeline, with a layout of its own ([`Kernel::layout_bindings`] storage buffers and its
    /// push constants).
    pub fn pipeline(&self, ctx: &Arc<Context>) -> Result<Owned<ComputePipeline>, SolveError> {
        let pipeline =
            ctx.create_compute_pipeline(self.name, self.spirv, self.layout_bindings, self.push.size as u32)?;
        Ok(Owned::new(ctx, pipeline))
    }

    /// A descriptor set of `pipeline` (made by [`Kernel::pipeline`]) binding `buffers`, each named
    /// by the GLSL block it is for, in binding order: a buffer named for another binding than the
    /// table's is refused, so the host cannot bind what the kernel does not expect there.
    pub fn set(
        &self,
        ctx: &Arc<Context>,
        name: &str,
        pipeline: &ComputePipeline,
        buffers: &[(&str, &Buffer)],
    ) -> Result<Owned<DescriptorSet>, SolveError> {
        let expected: Vec<&str> = self.bindings.iter().map(|&(_, block)| block).collect();
        let given: Vec<&str> = buffers.iter().map(|&(block, _)| block).collect();
        if expected != given || self.bindings.iter().enumerate().any(|(i, &(b, _))| b as usize != i) {
            tracing::error!(kernel = self.name, ?expected, ?given, "descriptor set does not match the kernel table");
            return Err(SolveError::Internal("a descriptor set's buffers do not match its kernel's bindings"));
        }
        let ranges: Vec<BufferRange> = buffers.iter().map(|&(_, b)| BufferRange::from(b)).collect();
        Ok(Owned::new(ctx, ctx.create_descriptor_set(name, pipeline, &ranges)?))
    }

    /// Workgroups along x for `count` invocations of a one-dimensional kernel.
    pub fn groups_for(&self, count: u32) -> u32 {
        count.div_ceil(self.local_size[0]).max(1)
    }
}

// ---- dispatching the one-dimensional kernels ----

/// Workgroups along x of one dispatch at most (the least `maxComputeWorkGroupCount` a device may
/// have); more go along y.
pub const MAX_GROUPS_X: u32 = 65535;

/// Records one dispatch of `count` invocations of a kernel indexed as [`linear_groups`] says, with
/// the push constants `push(count, groups_x)`.
pub fn dispatch_linear<P: Pod>(
    rec: &mut Recorder,
    pipeline: &ComputePipeline,
    set: &DescriptorSet,
    count: u32,
    push: impl FnOnce(u32, u32) -> P,
) -> Result<(), SolveError> {
    let groups = linear_groups(count);
    let push = push(count, groups[0]);
    rec.bind(pipeline, set)?;
    rec.dispatch_bound(pipeline, bytemuck::bytes_of(&push), groups)?;
    Ok(())
}

/// The workgroups of a dispatch of `count` invocations, [`LINEAR_GROUP`] to a workgroup, at most
/// [`MAX_GROUPS_X`] along x and the rest along y (the kernels index `(y·groups_x + x)·LINEAR_GROUP + i`).
pub fn linear_groups(count: u32) -> [u32; 3] {
    let groups = count.div_ceil(LINEAR_GROUP).max(1);
    let groups_x = groups.min(MAX_GROUPS_X);
    [groups_x, groups.div_ceil(groups_x), 1]
}

/// The first `n` values of a buffer the kernels wrote, as the host sees it (after a wait).
pub fn readback<T: Pod>(buffer: &Buffer, n: usize) -> Result<&[T], SolveError> {
    let bytes = buffer.mapped().ok_or(SolveError::Internal("an end-of-order sum buffer is not host-visible"))?;
    let bytes = bytes
        .get(..n * std::mem::size_of::<T>())
        .ok_or(SolveError::Internal("an end-of-order sum buffer is smaller than its values"))?;
    Ok(bytemuck::cast_slice(bytes))
}

// ---- the sweep: propagate.comp and collect.comp share one pipeline layout ----

/// The sweep kernels' shared set, by binding: what the host binds where (the GLSL block names).
pub const SWEEP_BINDINGS: [&str; 13] = [
    "Directions",
    "Offsets",
    "SlotTable",
    "Density",
    "SourcePrev",
    "Rays",
    "RaysOutB",
    "RaysOutC",
    "Deposit",
    "CollectRows",
    "SourceNext",
    "Fluence",
    "SideExits",
];

const SWEEP_PUSH: Members = members!(SweepPush {
    na,
    nb,
    nc,
    t0,
    t1,
    axis_sign,
    lateral,
    bricks_b,
    bricks_c,
    dir_count,
    channels,
    storage,
    flags,
    dir_base,
    ray_base,
    slab,
    sigma_t,
    sigma_s,
    emission
});
const DIRECTION: Members = members!(GpuDirection { boundary, path_length, fluence_weight, gain_storage, pad });

/// Both sweep kernels' workgroup: lateral b × c.
pub const SWEEP_LOCAL_SIZE: [u32; 3] = [16, 4, 1];

pub const PROPAGATE: Kernel = Kernel {
    name: "propagate",
    spirv: include_bytes!("../../../spirv/propagate.spv"),
    push: SWEEP_PUSH,
    bindings: &[
        (0, "Directions"),
        (1, "Offsets"),
        (2, "SlotTable"),
        (3, "Density"),
        (4, "SourcePrev"),
        (5, "Rays"),
        (6, "RaysOutB"),
        (7, "RaysOutC"),
        (8, "Deposit"),
        (12, "SideExits"),
    ],
    layout_bindings: SWEEP_BINDINGS.len() as u32,
    structs: &[("Direction", DIRECTION)],
    local_size: SWEEP_LOCAL_SIZE,
    test_only: false,
};

pub const COLLECT: Kernel = Kernel {
    name: "collect",
    spirv: include_bytes!("../../../spirv/collect.spv"),
    push: SWEEP_PUSH,
    bindings: &[
        (0, "Directions"),
        (1, "Offsets"),
        (2, "SlotTable"),
        (3, "Density"),
        (8, "Deposit"),
        (9, "CollectRows"),
        (10, "SourceNext"),
        (11, "Fluence"),
    ],
    layout_bindings: SWEEP_BINDINGS.len() as u32,
    structs: &[("Direction", DIRECTION)],
    local_size: SWEEP_LOCAL_SIZE,
    test_only: false,
};

// ---- the passes between orders (end_of_order) ----

/// Push constants of the end-of-order kernels (block_sums, commit, to_half, remaining,
/// albedo_scale).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct EndPush {
    pub count: u32,
    pub groups_x: u32,
    pub mode: u32,
    /// to_half: the f16 scale's exponent; remaining: the channels.
    pub param: i32,
    pub factor: [f64; 3],
    pub dark_floor: f64,
}

/// One block's sums (block_sums.comp's `BlockSum`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct BlockSum {
    pub abs_sum: f64,
    pub max_abs_bits: u32,
    pub pad: u32,
}

/// One brick's tally (remaining.comp's `UnitTally`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct GpuUnitTally {
    pub brightest: f64,
    pub sum_sq: f64,
    pub max_e_bits: u32,
    pub count: u32,
    pub pad0: u32,
    pub pad1: u32,
}

const END_PUSH: Members = members!(EndPush { count, groups_x, mode, param, factor, dark_floor });

/// The one-dimensional kernels' workgroup (every kernel below but transpose).
pub const LINEAR_GROUP: u32 = 64;
const LINEAR: [u32; 3] = [LINEAR_GROUP, 1, 1];

pub const BLOCK_SUMS: Kernel = Kernel {
    name: "block_sums",
    spirv: include_bytes!("../../../spirv/block_sums.spv"),
    push: END_PUSH,
    bindings: &[(0, "Field"), (1, "Sums")],
    layout_bindings: 2,
    structs: &[("BlockSum", members!(BlockSum { abs_sum, max_abs_bits, pad }))],
    local_size: LINEAR,
    test_only: false,
};

pub const COMMIT: Kernel = Kernel {
    name: "commit",
    spirv: include_bytes!("../../../spirv/commit.spv"),
    push: END_PUSH,
    bindings: &[(0, "Total"), (1, "Order")],
    layout_bindings: 2,
    structs: &[],
    local_size: LINEAR,
    test_only: false,
};

pub const TO_HALF: Kernel = Kernel {
    name: "to_half",
    spirv: include_bytes!("../../../spirv/to_half.spv"),
    push: END_PUSH,
    bindings: &[(0, "Half"), (1, "Full")],
    layout_bindings: 2,
    structs: &[],
    local_size: LINEAR,
    test_only: false,
};

pub const REMAINING: Kernel = Kernel {
    name: "remaining",
    spirv: include_bytes!("../../../spirv/remaining.spv"),
    push: END_PUSH,
    bindings: &[(0, "Density"), (1, "Total"), (2, "Newest"), (3, "Tallies")],
    layout_bindings: 4,
    structs: &[("UnitTally", members!(GpuUnitTally { brightest, sum_sq, max_e_bits, count, pad0, pad1 }))],
    local_size: LINEAR,
    test_only: false,
};

pub const ALBEDO_SCALE: Kernel = Kernel {
    name: "albedo_scale",
    spirv: include_bytes!("../../../spirv/albedo_scale.spv"),
    push: END_PUSH,
    bindings: &[(0, "Source"), (1, "Albedo")],
    layout_bindings: 2,
    structs: &[],
    local_size: LINEAR,
    test_only: false,
};

// ---- the diffusion acceleration (accelerate) ----

/// Push constants of both diffusion kernels (`Push` in glsl/diffusion.glsl).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct DiffusionPush {
    pub count: u32,
    pub groups_x: u32,
    pub unknowns: u32,
    pub comps: u32,
    pub channels: u32,
    pub edge: u32,
    pub cells: [u32; 3],
    pub first: u32,
    pub round_voxels: u32,
    /// 1 when the scene has a per-voxel albedo factor (the prolongation scales by it).
    pub albedo_grid: u32,
    pub extinction: [f64; 3],
    pub scatter: [f64; 3],
    pub voxel_size: f64,
    pub four_pi: f64,
}

const DIFFUSION_PUSH: Members = members!(DiffusionPush {
    count,
    groups_x,
    unknowns,
    comps,
    channels,
    edge,
    cells,
    first,
    round_voxels,
    albedo_grid,
    extinction,
    scatter,
    voxel_size,
    four_pi
});

pub const DIFFUSION_MOMENTS: Kernel = Kernel {
    name: "diffusion_moments",
    spirv: include_bytes!("../../../spirv/diffusion_moments.spv"),
    push: DIFFUSION_PUSH,
    bindings: &[
        (0, "Density"),
        (1, "Source"),
        (2, "SolidAngles"),
        (3, "CellOfUnknown"),
        (4, "BrickStart"),
        (5, "Bricks"),
        (6, "Origins"),
        (7, "Moments"),
    ],
    layout_bindings: 8,
    structs: &[],
    local_size: LINEAR,
    test_only: false,
};

pub const DIFFUSION_PROLONG: Kernel = Kernel {
    name: "diffusion_prolong",
    spirv: include_bytes!("../../../spirv/diffusion_prolong.spv"),
    push: DIFFUSION_PUSH,
    bindings: &[
        (0, "Density"),
        (1, "Source"),
        (2, "Fluence"),
        (3, "UnknownOf"),
        (4, "Origins"),
        (5, "Change"),
        (6, "Albedo"),
    ],
    layout_bindings: 7,
    structs: &[],
    local_size: LINEAR,
    test_only: false,
};

// ---- the diffusion correction (sharpen) ----

/// Push constants of glsl/sharpen.comp.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct SharpenPush {
    pub count: u32,
    pub groups_x: u32,
    pub comps: u32,
    pub channels: u32,
    pub dims: [u32; 3],
    /// Bit a: axis a is periodic; bit 3 + 2a + side: that face of axis a is a mirror; bit 9: a
    /// per-voxel albedo factor.
    pub flags: u32,
    /// Bricks of the volume along x and y (a brick's index is x + bx·(y + by·z)).
    pub bricks: [u32; 2],
}

/// The correction's f64 constants, computed on the host so that the shader parses no f64
/// literal (`Constants` in glsl/sharpen.comp).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct SharpenConstants {
    pub kappa_w: [f64; 3],
    pub thickness: [f64; 3],
    pub albedo: [f64; 3],
    pub two_thirds: f64,
    pub boost: f64,
    pub one_plus_boost: f64,
    pub growth: f64,
    pub small: f64,
    pub flux_share: f64,
    pub log2_e: f64,
    pub ln2_hi: f64,
    pub ln2_lo: f64,
    pub exp_limit: f64,
}

pub const SHARPEN: Kernel = Kernel {
    name: "sharpen",
    spirv: include_bytes!("../../../spirv/sharpen.spv"),
    push: members!(SharpenPush { count, groups_x, comps, channels, dims, flags, bricks }),
    bindings: &[
        (0, "Density"),
        (1, "Total"),
        (2, "Raw"),
        (3, "Sharpened"),
        (4, "BrickSlots"),
        (5, "Origins"),
        (6, "Constants"),
        (7, "Albedo"),
    ],
    layout_bindings: 8,
    structs: &[(
        "Constants",
        members!(SharpenConstants {
            kappa_w,
            thickness,
            albedo,
            two_thirds,
            boost,
            one_plus_boost,
            growth,
            small,
            flux_share,
            log2_e,
            ln2_hi,
            ln2_lo,
            exp_limit
        }),
    )],
    local_size: LINEAR,
    test_only: false,
};

// ---- the resident fields' reorder for the x sweeps (transpose) ----

/// Push constants of `transpose.comp`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct TransposePush {
    pub blocks: u32,
    pub half_values: u32,
    pub to_lateral: u32,
    pub groups_x: u32,
}

pub const TRANSPOSE: Kernel = Kernel {
    name: "transpose",
    spirv: include_bytes!("../../../spirv/transpose.spv"),
    push: members!(TransposePush { blocks, half_values, to_lateral, groups_x }),
    bindings: &[(0, "Field")],
    layout_bindings: 1,
    structs: &[],
    // One workgroup per block of 4096 values.
    local_size: [256, 1, 1],
    test_only: false,
};

// ---- the rays' tallies (tally_sums) ----

/// The tally kernel's push constants.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct TallySumsPush {
    /// Directions × channels of the pass.
    pub segments: u32,
    /// Rays per segment.
    pub rays: u32,
    /// Chunks per segment.
    pub chunks: u32,
    /// Rays to a chunk.
    pub chunk: u32,
    /// Workgroups along x of the dispatch.
    pub groups_x: u32,
}

/// Rays to a chunk of the device's tally sums (`glsl/tally_sums.comp`'s `CHUNK`: a loop of at most
/// this many iterations per invocation, well under llvmpipe's limit).
pub const TALLY_CHUNK: u64 = 4096;

/// Chunks of [`TALLY_CHUNK`] rays a segment of `rays` rays is summed in.
pub fn tally_chunks(rays: u64) -> u64 {
    rays.div_ceil(TALLY_CHUNK).max(1)
}

pub const TALLY_SUMS: Kernel = Kernel {
    name: "tally_sums",
    spirv: include_bytes!("../../../spirv/tally_sums.spv"),
    push: members!(TallySumsPush { segments, rays, chunks, chunk, groups_x }),
    bindings: &[(0, "Far"), (1, "SideB"), (2, "SideC"), (3, "Sums")],
    layout_bindings: 4,
    structs: &[],
    local_size: LINEAR,
    test_only: false,
};

// ---- the traced emission's uncollided light (crate::solver::uncollided::gpu) ----

/// Push constants of `uncollided_trace.comp`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct UncollidedPush {
    /// The unfolded frame: cells `lo .. hi` per axis.
    pub lo: [i32; 3],
    /// Invocations: [`crate::store::BRICK_VOXELS`] per target brick of the batch.
    pub count: u32,
    pub hi: [i32; 3],
    pub groups_x: u32,
    /// The volume's.
    pub dims: [u32; 3],
    pub channels: u32,
    /// σt·h at density 1.
    pub extinction: [f32; 3],
    pub h: f32,
    pub kappa: f32,
    pub tau: f32,
    pub spread: f32,
    pub root: u32,
    /// 1: every pair exact (tests).
    pub exact: u32,
    /// The batch's first target brick.
    pub first: u32,
    pub sigma_nodes: u32,
    pub table_sigma_max: f32,
    /// `(sigma_nodes − 1) / ln(table_sigma_max + 1)`.
    pub node_scale: f32,
    pub near_reach: i32,
    /// A DDA's steps at most.
    pub max_steps: u32,
    pub round_index: u32,
    /// Loop iterations per invocation and round; 0: no limit.
    pub budget: u32,
    /// Entries of each invocation's saved stack.
    pub stack_stride: u32,
}

/// One node of the emitters' octree (`TraceNode`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct TraceNode {
    pub centre: [f32; 3],
    pub radius: f32,
    pub j: [f32; 3],
    pub weight: f32,
    /// xx, yy, zz, xy, xz, yz.
    pub cov: [f32; 6],
    /// The members' source-weighted σt·h per channel.
    pub sigma: [f32; 3],
    pub sigma_max: f32,
    /// Bit 0: a member is on a face of the medium; bit 1: a leaf.
    pub flags: u32,
    /// A leaf: its emitter; else its first child in the children list.
    pub first: u32,
    pub count: u32,
}

/// One emitter (`TraceEmitter`): its cell in the unfolded frame, J and σt·h per channel.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct TraceEmitter {
    pub cell: [i32; 3],
    pub j: [f32; 3],
    pub sigma: [f32; 3],
}

/// One target brick (`TraceTarget`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct TraceTarget {
    pub origin: [u32; 3],
    pub extent: [u32; 3],
}

/// What one voxel received (`TraceReceived`), and its walk's state between rounds.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct TraceReceived {
    pub fluence: [f32; 3],
    pub flux: [f32; 3],
    pub clusters: u32,
    pub near_pairs: u32,
    pub far_pairs: u32,
    /// Entries left on its stack: 0 when done.
    pub depth: u32,
}

/// `uncollided_trace.comp`'s traversal stack (`STACK`): the host refuses a deeper tree.
pub const UNCOLLIDED_STACK: u32 = 128;
/// Loop iterations `uncollided_trace.comp` charges per node besides its segments (`NODE_COST`),
/// and per segment besides its DDA steps (`SEGMENT_COST`).
pub const UNCOLLIDED_NODE_COST: u32 = 128;
pub const UNCOLLIDED_SEGMENT_COST: u32 = 8;

pub const UNCOLLIDED_TRACE: Kernel = Kernel {
    name: "uncollided_trace",
    spirv: include_bytes!("../../../spirv/uncollided_trace.spv"),
    push: members!(UncollidedPush {
        lo,
        count,
        hi,
        groups_x,
        dims,
        channels,
        extinction,
        h,
        kappa,
        tau,
        spread,
        root,
        exact,
        first,
        sigma_nodes,
        table_sigma_max,
        node_scale,
        near_reach,
        max_steps,
        round_index,
        budget,
        stack_stride
    }),
    bindings: &[
        (0, "Nodes"),
        (1, "Children"),
        (2, "Emitters"),
        (3, "NearLn"),
        (4, "Density"),
        (5, "Targets"),
        (6, "Received"),
        (7, "Stacks"),
    ],
    layout_bindings: 8,
    structs: &[
        ("TraceNode", members!(TraceNode { centre, radius, j, weight, cov, sigma, sigma_max, flags, first, count })),
        ("TraceEmitter", members!(TraceEmitter { cell, j, sigma })),
        ("TraceTarget", members!(TraceTarget { origin, extent })),
        ("TraceReceived", members!(TraceReceived { fluence, flux, clusters, near_pairs, far_pairs, depth })),
    ],
    local_size: LINEAR,
    test_only: false,
};

// ---- kernels only the tests run ----

/// `fill.comp`'s push constants (the Vulkan layer's smoke test).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct FillPush {
    pub count: u32,
    pub value: u32,
}

pub const FILL: Kernel = Kernel {
    name: "fill",
    spirv: include_bytes!("../../../spirv/fill.spv"),
    push: members!(FillPush { count, value }),
    bindings: &[(0, "Data")],
    layout_bindings: 1,
    structs: &[],
    local_size: LINEAR,
    test_only: true,
};

/// The GLSL segment functions against `solver::segment` (the sweep's push block, `na` values).
pub const SEGMENT_TEST: Kernel = Kernel {
    name: "segment_test",
    spirv: include_bytes!("../../../spirv/segment_test.spv"),
    push: SWEEP_PUSH,
    bindings: &[(0, "Depths"), (1, "Values")],
    layout_bindings: 2,
    structs: &[],
    local_size: LINEAR,
    test_only: true,
};

/// `division_test.comp`'s push constants.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct DivisionTestPush {
    /// Cases.
    pub count: u32,
    /// 1: start from the device's own quotient.
    pub own: u32,
}

/// `div_rn` of glsl/exact.glsl against the host's division.
pub const DIVISION_TEST: Kernel = Kernel {
    name: "division_test",
    spirv: include_bytes!("../../../spirv/division_test.spv"),
    push: members!(DivisionTestPush { count, own }),
    bindings: &[(0, "Cases"), (1, "Quotients")],
    layout_bindings: 2,
    structs: &[],
    local_size: LINEAR,
    test_only: true,
};

/// Every kernel in `glsl/`.
pub const ALL: [&Kernel; 16] = [
    &PROPAGATE,
    &COLLECT,
    &BLOCK_SUMS,
    &COMMIT,
    &TO_HALF,
    &REMAINING,
    &ALBEDO_SCALE,
    &DIFFUSION_MOMENTS,
    &DIFFUSION_PROLONG,
    &SHARPEN,
    &TRANSPOSE,
    &TALLY_SUMS,
    &UNCOLLIDED_TRACE,
    &FILL,
    &SEGMENT_TEST,
    &DIVISION_TEST,
];
