//! The traced emission's uncollided light on the device: `glsl/uncollided_trace.comp` computes,
//! for every voxel of a batch of target bricks, what [`Clusters::receive`] computes on the host
//! (its CPU twin): the fluence per channel and the flux vector from every emitter, walking the
//! same octree with the same acceptance tests, the same near table, the same 2³ Gauss points and
//! the same exact 3-D DDA through the density of the frame unfolded by the mirrors, in f32. The
//! host's bookkeeping then takes those values as it takes the twin's ([`super::add_order0_on`]):
//! one copy of it for both.
//!
//! **What goes up.** The tree flattened ([`Clusters::flat`]: 84 bytes a node, about two nodes an
//! emitter, 4 bytes a child, 36 bytes an emitter), the near table (27 × 40 f32), the volume's
//! density as one dense f32 array over its dims (4 bytes a voxel: the DDA reads any cell of the
//! unfolded frame), the occupied bricks' origins, and per batch of [`BATCH_BRICKS`] target bricks
//! the per-voxel results (40 bytes a voxel, host-visible) and, on a CPU implementation, each
//! voxel's saved stack (4 bytes an entry). Every bound buffer must fit the device's
//! `maxStorageBufferRange` (128 MiB on lavapipe: a volume of at most 2²⁵ voxels), and the dense
//! density with its staging copy (8 bytes a voxel of host memory while they go up) half of the
//! memory the system reports available; the tree's
//! stack must fit the kernel's ([`UNCOLLIDED_STACK`] entries, sized on the host from the tree,
//! [`stack_need`]), and the optical thickness of a voxel the range of f32's exponential.
//! Otherwise [`DeviceTrace::for_store`] declines, saying why, and the trace runs on the host.
//!
//! **Rounds.** llvmpipe (lavapipe) leaves every loop of a shader once it has run 65535 loop
//! iterations in all, counted over all its loops and its SIMD lanes together. On a CPU
//! implementation each invocation therefore spends at most its lane's share of that
//! ([`LOOP_LIMIT`] / subgroup size) per dispatch, charging each node it takes its DDA steps and
//! a bound on its other loops, keeps its stack and sums for the next round, and the host
//! dispatches the batch again until every voxel is done. A GPU runs one round without a limit.
//!
//! **Precision.** f32 throughout (the twin is f64). Against the twin on a compact emitter beside a
//! mirror (160 emitters with their images) in a heterogeneous medium with a density step, three
//! channels, every voxel of a 20×14×12 volume (`tests/it/uncollided_gpu.rs`): where both walks
//! took the same pairs, the fluence within 7.1e-7 relative per voxel and channel and the flux
//! within 4.4e-7 of the fluence with 34 853 clusters taken whole, 7.8e-7 and 6.3e-7 with every
//! pair exact; the test holds 1e-5. Where an acceptance test (`KAPPA`, `TAU`, `SPREAD`) sits on
//! its threshold the f32 and f64 walks may take a cluster whole on one side and open it on the
//! other (none did there); that voxel then differs by the clustering's own error, within 0.5 %
//! ([`super::clusters`]'s tests), which the test allows where the walks part. The device's trace is bitwise the same run to run (each voxel's walk is
//! one invocation's sequential loop). Time on lavapipe (two cores, in rounds): 1.7 s for those
//! 3360 voxels, the twin 1.1 s.

use super::clusters::{Clusters, Received, Work, KAPPA, SPREAD, TAU};
use super::kernel::{NearTable, NEAR, SIGMA_MAX, SIGMA_NODES};
use super::Unfolded;
use crate::solver::gpu::kernels::{
    linear_groups, TraceEmitter, TraceNode, TraceReceived, TraceTarget, UncollidedPush, UNCOLLIDED_NODE_COST,
    UNCOLLIDED_SEGMENT_COST, UNCOLLIDED_STACK, UNCOLLIDED_TRACE,
};
use crate::solver::gpu::owned::Owned;
use crate::solver::point::optical_path_in;
use crate::solver::SolveError;
use crate::store::{BrickStore, BRICK_EDGE, BRICK_VOXELS};
use crate::vk::{vk, Buffer, ComputePipeline, Context, DescriptorSet, MemoryLocation, Recorder, TimelineSemaphore};
use glam::DVec3;
use std::sync::Arc;

/// Target bricks per dispatch at most (4096 invocations each): a bounded result buffer (5.2 MB).
pub const BATCH_BRICKS: usize = 32;

/// Loop iterations one shader call may run on llvmpipe (its limit is 65535, over all loops and
/// SIMD lanes): what a batch's invocations share per round on a CPU implementation.
pub const LOOP_LIMIT: u32 = 60000;

/// A voxel's σt·h at most for the kernel (f32's exponential reaches e^88; the target's end factor
/// takes sinh(σ/2)³).
const THICKEST: f64 = 64.0;

/// What the trace reads: the tree, the near table, the frame, the volume's density (x fastest,
/// over `frame.dims`), σt·h at density 1, the channels, the voxel edge, and whether every pair is
/// taken exactly (tests).
#[derive(Clone, Copy)]
pub struct Inputs<'a> {
    pub tree: &'a Clusters,
    pub table: &'a NearTable,
    pub frame: Unfolded,
    pub density: &'a [f32],
    pub extinction: [f64; 3],
    pub channels: usize,
    pub h: f64,
    pub exact: bool,
}

impl Inputs<'_> {
    /// The density of the volume's cell that cell `c` of the unfolded frame images.
    fn density_at(&self, c: [i64; 3]) -> f32 {
        let s = self.frame.source(c);
        let d = self.frame.dims;
        self.density[s[0] as usize + d[0] as usize * (s[1] as usize + d[1] as usize * s[2] as usize)]
    }
}

/// The CPU twin at one target voxel `cell` of the volume: [`Clusters::receive`] with the exact
/// DDA through `inputs`' density, as the host's trace calls it.
pub fn receive_on_host(inputs: &Inputs, cell: [i64; 3], work: &mut Work) -> Received {
    let density = |c: [i64; 3]| inputs.density_at(c);
    let path = |a: DVec3, b: DVec3| optical_path_in(inputs.frame.lo, inputs.frame.hi, &density, a, b);
    let rho = density(cell) as f64;
    let sigma_v = std::array::from_fn(|ch| inputs.extinction[ch] * rho);
    inputs.tree.receive(
        cell,
        sigma_v,
        inputs.channels,
        inputs.extinction,
        inputs.h,
        inputs.table,
        &path,
        inputs.exact,
        work,
    )
}

/// The volume's density as one dense array, x fastest (empty bricks 0, as `density_at` reads them).
pub fn dense_density(store: &BrickStore) -> Vec<f32> {
    let grid = *store.grid();
    let dims = grid.dims.map(|n| n as usize);
    let mut out = vec![0.0f32; dims[0] * dims[1] * dims[2]];
    for brick in store.occupied_bricks() {
        let Some(rho) = store.density_brick(brick) else { continue };
        let b = grid.brick_coords(brick);
        let origin = grid.brick_origin(b).map(|v| v as usize);
        let extent = grid.brick_extent(b).map(|v| v as usize);
        for lz in 0..extent[2] {
            for ly in 0..extent[1] {
                let from = BRICK_EDGE as usize * (ly + BRICK_EDGE as usize * lz);
                let to = origin[0] + dims[0] * (origin[1] + ly + dims[1] * (origin[2] + lz));
                out[to..to + extent[0]].copy_from_slice(&rho[from..from + extent[0]]);
            }
        }
    }
    store.release_all_density();
    out
}

/// The target bricks `bricks` of `store`'s grid as the kernel reads them.
pub fn targets(store: &BrickStore, bricks: &[usize]) -> Vec<TraceTarget> {
    let grid = store.grid();
    bricks
        .iter()
        .map(|&brick| {
            let b = grid.brick_coords(brick);
            TraceTarget { origin: grid.brick_origin(b), extent: grid.brick_extent(b) }
        })
        .collect()
}

/// The traversal stack's largest size over every walk of `tree` (every node opened): a popped
/// inner node's k children go on, and the i-th of them is walked above the k − 1 − i after it.
pub fn stack_need(tree: &Clusters) -> usize {
    let Some(flat) = tree.flat() else { return 0 };
    // `build` makes a node after its children: a child's index is below its parent's, so the
    // peaks fill in index order.
    let mut peak = vec![0usize; flat.nodes.len()];
    for (n, node) in flat.nodes.iter().enumerate() {
        let kids = &flat.children[node.children.clone()];
        let k = kids.len();
        peak[n] = kids.iter().enumerate().map(|(i, &c)| k - 1 - i + peak[c]).fold(k, usize::max);
    }
    peak[flat.root].max(1)
}

/// The kernel's Vulkan objects, one owner: each [`Owned`] frees its object when dropped, and
/// dropping this first waits for the last submission (fields drop after `drop` returns, in
/// declaration order; destroying the timeline idles the queue first on lavapipe).
struct Objects {
    ctx: Arc<Context>,
    timeline: Owned<TimelineSemaphore>,
    /// The last value submitted on it.
    value: u64,
    /// Made by the kernel table (`Kernel::pipeline`, `Kernel::set`) once the inputs are up.
    set: Option<Owned<DescriptorSet>>,
    pipeline: Option<Owned<ComputePipeline>>,
    /// In binding order ([`BINDINGS`]).
    buffers: Vec<Owned<Buffer>>,
}

impl Objects {
    /// Submits `rec` and waits for it.
    fn submit_and_wait(&mut self, rec: Recorder) -> Result<(), SolveError> {
        self.value += 1;
        rec.submit(self.ctx.compute_queue(), &[], (&self.timeline, self.value))?;
        self.timeline.wait(&self.ctx, self.value, u64::MAX)?;
        Ok(())
    }

    /// Records one round of the kernel with `push` over `groups` workgroups, submits it and waits.
    fn dispatch(&mut self, push: &UncollidedPush, groups: [u32; 3]) -> Result<(), SolveError> {
        let mut rec = Recorder::begin(&self.ctx, self.ctx.compute_queue().family(), "emission trace")?;
        let (Some(pipeline), Some(set)) = (self.pipeline.as_deref(), self.set.as_deref()) else {
            return Err(SolveError::Internal("the emission trace has no pipeline"));
        };
        // The last round's (or batch's) writes before this round's reads and writes.
        rec.compute_to_compute();
        rec.bind(pipeline, set)?;
        rec.dispatch_bound(pipeline, bytemuck::bytes_of(push), groups)?;
        rec.compute_to_host();
        self.submit_and_wait(rec)
    }

    /// A device buffer of at least 4 bytes.
    fn buffer(&mut self, name: &str, bytes: u64, location: MemoryLocation) -> Result<usize, SolveError> {
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_DST;
        self.buffers.push(Owned::new(&self.ctx, self.ctx.create_buffer(name, bytes.max(4), usage, location)?));
        Ok(self.buffers.len() - 1)
    }
}

impl Drop for Objects {
    fn drop(&mut self) {
        // The only work using the objects is the last submission: wait for it before the fields
        // free them.
        if let Err(e) = self.timeline.wait(&self.ctx, self.value, u64::MAX) {
            tracing::warn!("waiting for the emission trace's last submission failed: {e}");
        }
    }
}

/// The kernel set up over one tree and volume: [`DeviceTrace::receive`] computes batches of
/// target bricks.
pub struct DeviceTrace {
    objects: Objects,
    /// Index of the result buffer in `objects.buffers`.
    received: usize,
    push: UncollidedPush,
    targets: usize,
    /// The tree's nodes (a bound on the rounds of a batch).
    nodes: usize,
    batch: usize,
    /// The device, in words.
    pub device: String,
}

/// The buffers in binding order, as the kernel's table names them.
const BINDINGS: [&str; 8] = ["Nodes", "Children", "Emitters", "NearLn", "Density", "Targets", "Received", "Stacks"];

impl DeviceTrace {
    /// The kernel over `store`'s density and the target bricks `bricks`; `Ok(Err(why))` where the
    /// device cannot take it (a buffer beyond its binding range, a tree deeper than the kernel's
    /// stack, a voxel too thick for f32): the host traces instead.
    #[allow(clippy::too_many_arguments)]
    pub fn for_store(
        ctx: &Arc<Context>,
        store: &BrickStore,
        tree: &Clusters,
        table: &NearTable,
        frame: Unfolded,
        extinction: [f64; 3],
        channels: usize,
        h: f64,
        exact: bool,
        bricks: &[usize],
    ) -> Result<Result<DeviceTrace, String>, SolveError> {
        let limit = ctx.limits().max_storage_buffer_range;
        let voxels: u64 = frame.dims.iter().map(|&n| n as u64).product();
        if 4 * voxels > limit {
            return Ok(Err(format!(
                "the volume's density ({} bytes) is more than the device binds in one buffer ({limit} bytes)",
                4 * voxels
            )));
        }
        // The dense array and its staging copy live in host memory together while it goes up:
        // more than half of what the system has free, and the host walks instead (it reads the
        // store's bricks in place).
        let host_bytes = 8 * voxels;
        if let Some(available) = crate::store::resident::available_memory().filter(|&a| host_bytes > a / 2) {
            return Ok(Err(format!(
                "the volume's dense density and its staging copy ({host_bytes} bytes) are more than half the \
                 memory available ({available} bytes)"
            )));
        }
        let density = dense_density(store);
        let inputs = Inputs { tree, table, frame, density: &density, extinction, channels, h, exact };
        DeviceTrace::new(ctx, &inputs, &targets(store, bricks))
    }

    /// The kernel over `inputs` and the target bricks `targets` (see [`DeviceTrace::for_store`]).
    pub fn new(
        ctx: &Arc<Context>,
        inputs: &Inputs,
        targets: &[TraceTarget],
    ) -> Result<Result<DeviceTrace, String>, SolveError> {
        let Some(flat) = inputs.tree.flat() else {
            return Err(SolveError::Internal("the emission trace was asked for no emitters"));
        };
        let limits = ctx.limits();
        let limit = limits.max_storage_buffer_range;
        // What the kernel reads, f32.
        let f = |v: f64| v as f32;
        let nodes: Vec<TraceNode> = flat
            .nodes
            .iter()
            .map(|n| TraceNode {
                centre: n.centroid.to_array().map(f),
                radius: f(n.radius),
                j: n.j.map(f),
                weight: f(n.weight),
                cov: n.cov.map(f),
                sigma: n.sigma.map(f),
                sigma_max: f(n.sigma_max),
                flags: n.edge as u32 | (n.leaf.is_some() as u32) << 1,
                first: n.leaf.unwrap_or(n.children.start) as u32,
                count: n.children.len() as u32,
            })
            .collect();
        let children: Vec<u32> = flat.children.iter().map(|&c| c as u32).collect();
        let emitters: Vec<TraceEmitter> = flat
            .emitters
            .iter()
            .map(|e| TraceEmitter { cell: e.cell.map(|c| c as i32), j: e.j.map(f), sigma: e.sigma.map(f) })
            .collect();
        let near: Vec<f32> = inputs.table.ln_values().iter().flatten().map(|&v| v as f32).collect();
        let need = stack_need(inputs.tree);
        let thickest = inputs.density.iter().cloned().fold(0.0f32, f32::max) as f64
            * inputs.extinction[..inputs.channels].iter().cloned().fold(0.0, f64::max);
        let frame = inputs.frame;
        let extent: i64 = (0..3).map(|a| frame.hi[a] - frame.lo[a]).sum();
        let max_steps = extent + 8;
        // Per round and lane on a CPU implementation; 0 (no limit) on a GPU.
        let budget = if limits.is_cpu { LOOP_LIMIT / limits.subgroup_size.max(1) } else { 0 };
        let reserve = need as u64 + UNCOLLIDED_NODE_COST as u64;
        let worst_node = UNCOLLIDED_NODE_COST as u64 + 9 * (max_steps as u64 + UNCOLLIDED_SEGMENT_COST as u64);
        let stride = if budget == 0 { 0 } else { need };
        let batch = (BATCH_BRICKS as u64)
            .min(limit / (BRICK_VOXELS as u64 * std::mem::size_of::<TraceReceived>() as u64))
            .min(if stride > 0 { limit / (BRICK_VOXELS as u64 * 4 * stride as u64) } else { u64::MAX })
            .min(targets.len() as u64) as usize;
        let sizes = [
            ("tree", std::mem::size_of_val(nodes.as_slice()) as u64),
            ("children", 4 * children.len() as u64),
            ("emitters", std::mem::size_of_val(emitters.as_slice()) as u64),
            ("target bricks", std::mem::size_of_val(targets) as u64),
        ];
        if let Some((what, bytes)) = sizes.iter().find(|(_, b)| *b > limit) {
            return Ok(Err(format!(
                "the {what} ({bytes} bytes) is more than the device binds in one buffer ({limit} bytes)"
            )));
        }
        if need > UNCOLLIDED_STACK as usize {
            return Ok(Err(format!(
                "the tree's walk needs a stack of {need} entries, the kernel's holds {UNCOLLIDED_STACK}"
            )));
        }
        if !(thickest <= THICKEST) {
            return Ok(Err(format!(
                "a voxel's σt·h of {thickest:.3e} is beyond f32's exponential (at most {THICKEST})"
            )));
        }
        if budget != 0 && (2 * reserve + worst_node) > budget as u64 {
            return Ok(Err(format!(
                "the unfolded frame's {extent} cells along its axes make a node cost more loop iterations than a round of \
                 this CPU implementation allows ({budget} per invocation)"
            )));
        }
        if batch == 0 {
            return Ok(Err("no target brick's results fit one buffer of the device".into()));
        }
        if i32::try_from(frame.lo.iter().chain(&frame.hi).map(|v| v.abs()).max().unwrap_or(0)).is_err() {
            return Ok(Err("the unfolded frame's cells are beyond 32-bit integers".into()));
        }
        let k = UNCOLLIDED_TRACE;
        let mut objects = Objects {
            ctx: Arc::clone(ctx),
            timeline: Owned::new(ctx, ctx.create_timeline("emission trace", 0)?),
            value: 0,
            set: None,
            pipeline: None,
            buffers: Vec::new(),
        };
        let parts: [(&str, &[u8]); 6] = [
            ("trace nodes", bytemuck::cast_slice(&nodes)),
            ("trace children", bytemuck::cast_slice(&children)),
            ("trace emitters", bytemuck::cast_slice(&emitters)),
            ("trace near table", bytemuck::cast_slice(&near)),
            ("trace density", bytemuck::cast_slice(inputs.density)),
            ("trace targets", bytemuck::cast_slice(targets)),
        ];
        for (name, bytes) in parts {
            objects.buffer(name, bytes.len() as u64, MemoryLocation::GpuOnly)?;
        }
        let batch_voxels = (batch * BRICK_VOXELS) as u64;
        let received = objects.buffer(
            "trace received",
            batch_voxels * std::mem::size_of::<TraceReceived>() as u64,
            MemoryLocation::GpuToCpu,
        )?;
        objects.buffer("trace stacks", batch_voxels * 4 * stride as u64, MemoryLocation::GpuOnly)?;
        // The inputs go up through a staging buffer, freed once the copy was waited for.
        let total: u64 = parts.iter().map(|(_, b)| b.len() as u64).sum();
        let mut staging = ctx.create_host_buffer(
            "trace staging",
            total.max(4),
            vk::BufferUsageFlags::TRANSFER_SRC,
            MemoryLocation::CpuToGpu,
        )?;
        let uploaded = (|| -> Result<(), SolveError> {
            let mapped = staging.bytes_mut();
            let mut offset = 0;
            for (_, bytes) in parts {
                mapped[offset..offset + bytes.len()].copy_from_slice(bytes);
                offset += bytes.len();
            }
            let mut rec = Recorder::begin(ctx, ctx.compute_queue().family(), "emission trace upload")?;
            let mut src = 0u64;
            for (i, (_, bytes)) in parts.iter().enumerate() {
                let size = bytes.len() as u64;
                if size > 0 {
                    let region = vk::BufferCopy { src_offset: src, dst_offset: 0, size };
                    rec.copy_buffer(&staging, &objects.buffers[i], &[region]);
                }
                src += size;
            }
            rec.transfer_to_compute();
            objects.submit_and_wait(rec)
        })();
        // SAFETY: the copy was waited for (or never submitted).
        unsafe { ctx.destroy_host_buffer(staging) };
        uploaded?;
        // The kernel table makes both, and refuses buffers named for other bindings than its own.
        let pipeline = k.pipeline(ctx)?;
        let named: Vec<(&str, &Buffer)> = BINDINGS.iter().copied().zip(objects.buffers.iter().map(|b| &**b)).collect();
        let set = k.set(ctx, "emission trace", &pipeline, &named)?;
        (objects.set, objects.pipeline) = (Some(set), Some(pipeline));

        let push = UncollidedPush {
            lo: frame.lo.map(|v| v as i32),
            hi: frame.hi.map(|v| v as i32),
            dims: frame.dims,
            channels: inputs.channels as u32,
            extinction: inputs.extinction.map(f),
            h: f(inputs.h),
            kappa: f(KAPPA),
            tau: f(TAU),
            spread: f(SPREAD),
            root: flat.root as u32,
            exact: inputs.exact as u32,
            sigma_nodes: SIGMA_NODES as u32,
            table_sigma_max: f(SIGMA_MAX),
            node_scale: f((SIGMA_NODES - 1) as f64 / (SIGMA_MAX + 1.0).ln()),
            near_reach: NEAR as i32,
            max_steps: max_steps as u32,
            budget,
            stack_stride: stride as u32,
            ..UncollidedPush::default()
        };
        let device = format!("{} ({})", ctx.device_name(), ctx.driver_description());
        Ok(Ok(DeviceTrace { objects, received, push, targets: targets.len(), nodes: nodes.len(), batch, device }))
    }

    /// Target bricks per [`DeviceTrace::receive`] at most.
    pub fn batch(&self) -> usize {
        self.batch
    }

    /// What every voxel of the target bricks `first .. first + count` (at most [`Self::batch`])
    /// receives, [`BRICK_VOXELS`] values per brick (local x fastest; zeros beyond a brick's
    /// extent), and the pairs their walks took.
    pub fn receive(&mut self, first: usize, count: usize) -> Result<(Vec<Received>, Work), SolveError> {
        if count == 0 || count > self.batch || first + count > self.targets {
            return Err(SolveError::Internal("an emission trace batch outside its target bricks"));
        }
        let invocations = (count * BRICK_VOXELS) as u32;
        let groups = linear_groups(invocations);
        let mut push = UncollidedPush { count: invocations, groups_x: groups[0], first: first as u32, ..self.push };
        loop {
            self.objects.dispatch(&push, groups)?;
            let values = values(&self.objects.buffers[self.received], invocations as usize)?;
            if values.iter().any(|v| v.depth == u32::MAX) {
                return Err(SolveError::Internal("the emission trace's stack overflowed on the device"));
            }
            if push.budget == 0 || values.iter().all(|v| v.depth == 0) {
                break;
            }
            // Each round takes at least one node off every walk not done (the host sized the rounds
            // so that a walk's first node fits), and a walk takes each node at most once.
            if push.round_index as usize > self.nodes {
                return Err(SolveError::Internal("the emission trace on the device took more rounds than nodes"));
            }
            push.round_index += 1;
        }
        let values = values(&self.objects.buffers[self.received], invocations as usize)?;
        let mut work = Work::default();
        let received = values
            .iter()
            .map(|v| {
                work.clusters += v.clusters as u64;
                work.near += v.near_pairs as u64;
                work.far += v.far_pairs as u64;
                Received {
                    fluence: v.fluence.map(|x| x as f64),
                    flux: DVec3::new(v.flux[0] as f64, v.flux[1] as f64, v.flux[2] as f64),
                }
            })
            .collect();
        Ok((received, work))
    }

    /// The pairs each voxel's walk took in the last [`DeviceTrace::receive`] of `count` bricks
    /// (tests: where the device's walk and the twin's part).
    pub fn walks(&self, count: usize) -> Result<Vec<Work>, SolveError> {
        let values = values(&self.objects.buffers[self.received], count * BRICK_VOXELS)?;
        Ok(values
            .iter()
            .map(|v| Work { clusters: v.clusters as u64, near: v.near_pairs as u64, far: v.far_pairs as u64 })
            .collect())
    }
}

/// The first `n` results in `buffer`, after a wait.
fn values(buffer: &Buffer, n: usize) -> Result<&[TraceReceived], SolveError> {
    let bytes = buffer.mapped().ok_or(SolveError::Internal("the emission trace's results are not host-visible"))?;
    let bytes = bytes
        .get(..n * std::mem::size_of::<TraceReceived>())
        .ok_or(SolveError::Internal("the emission trace's result buffer is smaller than its batch"))?;
    Ok(bytemuck::cast_slice(bytes))
}
