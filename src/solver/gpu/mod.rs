//! The GPU driver: sweeps the faces slice of bricks by slice of bricks on Vulkan.
//!
//! For every sweep (a sun beam, or the k² directions of one face in one order) the ray state of all
//! its directions stays on the device from the first slice to the last. Each slice goes through the
//! same steps: its bricks are gathered from the store into a host-visible staging buffer (medium,
//! previous source, the new source and fluence accumulated so far), copied to device buffers,
//! `propagate.comp` marches the rays through the slice's planes writing segment averages into the
//! deposit buffer, `collect.comp` folds them into fluence and the next source, and the two
//! accumulators are copied back and scattered into the store. A face's directions are dispatched in
//! groups small enough that the deposit buffer respects `maxStorageBufferRange`.
//!
//! This driver runs the steps of a slice one after another on the compute queue, waiting on a
//! timeline value before touching the staging memory again; the pipelined form overlaps them.

pub mod budget;
mod copier;
mod layout;
mod tables;

use super::energy::Tallies;
use super::fields::StoreFields;
use super::orders::Backend;
use super::plan::{Plan, SweepDirection};
use super::sweep::{FaceSweep, SliceRange};
use super::SolveError;
use crate::store::{BrickStore, BRICK_EDGE, BRICK_VOXELS};
use crate::vk::{Buffer, BufferRange, ComputePipeline, Context, Recorder, TimelineSemaphore};
use ash::vk;
use gpu_allocator::MemoryLocation;
use layout::*;
use std::sync::Arc;
use budget::MemoryPlan;
use tables::SweepTables;

const PROPAGATE_SPV: &[u8] = include_bytes!("../../../spirv/propagate.spv");
const COLLECT_SPV: &[u8] = include_bytes!("../../../spirv/collect.spv");
const BRICK_BYTES: u64 = BRICK_VOXELS as u64 * 4;
const WAIT_FOREVER: u64 = u64::MAX;

/// Device buffers sized for the largest slice of any face.
struct DeviceBuffers {
    slot_table: Buffer,
    density: Buffer,
    source_prev: Buffer,
    source_next: Buffer,
    fluence: Buffer,
    rays: Buffer,
    rays_in: Buffer,
    rays_out: Buffer,
    deposit: Buffer,
    upload: Buffer,
    download: Buffer,
}

impl DeviceBuffers {
    fn all(self) -> [Buffer; 11] {
        [
            self.slot_table,
            self.density,
            self.source_prev,
            self.source_next,
            self.fluence,
            self.rays,
            self.rays_in,
            self.rays_out,
            self.deposit,
            self.upload,
            self.download,
        ]
    }
}

pub struct GpuBackend<'a> {
    ctx: Arc<Context>,
    plan: &'a Plan,
    store: &'a BrickStore,
    fields: &'a mut StoreFields,
    propagate: Option<ComputePipeline>,
    collect: Option<ComputePipeline>,
    timeline: Option<TimelineSemaphore>,
    timeline_value: u64,
    buffers: Option<DeviceBuffers>,
    face_tables: Vec<SweepTables>,
    beam_tables: Vec<SweepTables>,
    memory: MemoryPlan,
}

impl<'a> GpuBackend<'a> {
    /// Prepares the device for `plan` within `budget` bytes of device memory (None: the default
    /// fraction of the device heap); the solve accumulates into `fields` (in `store`).
    pub fn new(
        ctx: Arc<Context>,
        plan: &'a Plan,
        store: &'a BrickStore,
        fields: &'a mut StoreFields,
        budget: Option<u64>,
    ) -> Result<Self, SolveError> {
        let limits = ctx.limits();
        let budget = budget.unwrap_or_else(|| budget::default_budget(&limits));
        let memory = budget::plan_memory(plan, budget::slice_extent(plan, store), &limits, budget)?;
        let c = plan.channels as u64;
        let comps = plan.source_components() as u64;
        let extent = memory.slice;
        let pass = memory.directions_per_pass as u64;
        let ray_bytes = pass * c * extent.rays * 4;
        let device = MemoryLocation::GpuOnly;
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::TRANSFER_DST
            | vk::BufferUsageFlags::TRANSFER_SRC;
        let sizes = [
            ("slot table", extent.bricks * 4),
            ("density", extent.occupied * BRICK_BYTES),
            ("source prev", extent.occupied * comps * BRICK_BYTES),
            ("source next", extent.occupied * comps * BRICK_BYTES),
            ("fluence", extent.bricks * c * BRICK_BYTES),
            ("rays", ray_bytes),
            ("rays in", ray_bytes),
            ("rays out", ray_bytes),
            ("deposit", memory.deposit_bytes),
        ];
        let mut made = Vec::new();
        for (name, size) in sizes {
            match ctx.create_buffer(name, size.max(4), storage, device) {
                Ok(b) => made.push(b),
                Err(e) => {
                    made.into_iter().for_each(|b| ctx.destroy_buffer(b));
                    return Err(e.into());
                }
            }
        }
        let upload_bytes = memory.slice_bytes;
        let download_bytes = (extent.occupied * comps * BRICK_BYTES + extent.bricks * c * BRICK_BYTES).max(2 * ray_bytes);
        let upload = ctx.create_buffer(
            "upload staging",
            upload_bytes.max(4),
            vk::BufferUsageFlags::TRANSFER_SRC,
            MemoryLocation::CpuToGpu,
        )?;
        let download = ctx.create_buffer(
            "download staging",
            download_bytes.max(4),
            vk::BufferUsageFlags::TRANSFER_DST,
            MemoryLocation::GpuToCpu,
        )?;
        let mut it = made.into_iter();
        let mut next = || it.next().ok_or(SolveError::Internal("buffer list"));
        let buffers = DeviceBuffers {
            slot_table: next()?,
            density: next()?,
            source_prev: next()?,
            source_next: next()?,
            fluence: next()?,
            rays: next()?,
            rays_in: next()?,
            rays_out: next()?,
            deposit: next()?,
            upload,
            download,
        };
        let propagate = ctx.create_compute_pipeline("propagate", PROPAGATE_SPV, 9, std::mem::size_of::<SweepPush>() as u32)?;
        let collect = ctx.create_compute_pipeline("collect", COLLECT_SPV, 7, std::mem::size_of::<SweepPush>() as u32)?;
        let timeline = ctx.create_timeline("solver", 0)?;
        let mut backend = GpuBackend {
            ctx,
            plan,
            store,
            fields,
            propagate: Some(propagate),
            collect: Some(collect),
            timeline: Some(timeline),
            timeline_value: 0,
            buffers: Some(buffers),
            face_tables: Vec::new(),
            beam_tables: Vec::new(),
            memory,
        };
        for face in &plan.faces {
            let t = SweepTables::upload(&mut backend, face)?;
            backend.face_tables.push(t);
        }
        for beam in &plan.beams {
            let t = SweepTables::upload(&mut backend, std::slice::from_ref(beam))?;
            backend.beam_tables.push(t);
        }
        tracing::info!(
            device = backend.ctx.device_name(),
            budget = memory.budget_bytes,
            planned = memory.planned_bytes,
            directions_per_pass = memory.directions_per_pass,
            directions_per_dispatch = memory.directions_per_dispatch,
            planes_per_dispatch = memory.planes_per_dispatch,
            "GPU backend ready"
        );
        Ok(backend)
    }

    /// How the sweeps were cut to fit the device memory budget.
    pub fn memory_plan(&self) -> MemoryPlan {
        self.memory
    }

    /// The Vulkan context the backend runs on.
    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }

    fn buffers(&self) -> Result<&DeviceBuffers, SolveError> {
        self.buffers.as_ref().ok_or(SolveError::Internal("device buffers already released"))
    }

    fn timeline(&self) -> Result<&TimelineSemaphore, SolveError> {
        self.timeline.as_ref().ok_or(SolveError::Internal("timeline already released"))
    }

    /// Submits a recorded command buffer on the compute queue and waits for it on the timeline.
    fn submit_and_wait(&mut self, rec: Recorder) -> Result<(), SolveError> {
        self.timeline_value += 1;
        let value = self.timeline_value;
        let timeline = self.timeline()?;
        rec.submit(self.ctx.compute_queue(), &[], (timeline, value))?;
        timeline.wait(&self.ctx, value, WAIT_FOREVER)?;
        self.ctx.collect_garbage()?;
        Ok(())
    }

    /// One sweep of a face (or a beam): its directions in passes of at most `directions_per_pass`,
    /// each pass streaming every slice of the face in sweep order.
    fn sweep(&mut self, tables: &SweepTables, dirs: &[SweepDirection], flags: u32) -> Result<Tallies, SolveError> {
        let plan = self.plan;
        let sweep = FaceSweep::new(dirs[0].face, plan.dims);
        let slices = sweep.slices(BRICK_EDGE);
        let pass = self.memory.directions_per_pass as usize;
        let mut tallies = Tallies::default();
        for first in (0..dirs.len()).step_by(pass) {
            let pass_dirs = first as u32..(first + pass).min(dirs.len()) as u32;
            for (i, slice) in slices.iter().enumerate() {
                self.slice(tables, &sweep, slice, pass_dirs.clone(), flags, i == 0, i + 1 == slices.len())?;
            }
            tallies.add(&self.read_tallies(&sweep, &dirs[pass_dirs.start as usize..pass_dirs.end as usize])?);
        }
        Ok(tallies)
    }

    #[allow(clippy::too_many_arguments)]
    fn slice(
        &mut self,
        tables: &SweepTables,
        sweep: &FaceSweep,
        slice: &SliceRange,
        pass_dirs: std::ops::Range<u32>,
        flags: u32,
        first: bool,
        last: bool,
    ) -> Result<(), SolveError> {
        let plan = self.plan;
        let grid = *self.store.grid();
        let face = sweep.geometry();
        let bricks_b = grid.bricks[face.lateral[0]];
        let bricks_c = grid.bricks[face.lateral[1]];
        let c = plan.channels as u64;
        let comps = plan.source_components() as u64;
        let gain = flags & FLAG_GAIN != 0;

        // The slice's bricks in slice order (c slowest) and their medium slots.
        let mut bricks = Vec::with_capacity((bricks_b * bricks_c) as usize);
        for bc in 0..bricks_c {
            for bb in 0..bricks_b {
                let mut b = [0; 3];
                b[face.axis] = slice.brick_a;
                b[face.lateral[0]] = bb;
                b[face.lateral[1]] = bc;
                bricks.push(grid.brick_index(b));
            }
        }
        let mut slots = Vec::with_capacity(bricks.len());
        let mut occupied = Vec::new();
        for &b in &bricks {
            if self.store.slot(b).is_some() {
                slots.push(occupied.len() as i32);
                occupied.push(b);
            } else {
                slots.push(-1);
            }
        }
        let n_dense = bricks.len() as u64;
        let n_occ = occupied.len() as u64;

        // Gather into the upload staging buffer: slot table, density, prev source, next source, fluence.
        let off_density = (n_dense * 4).next_multiple_of(16);
        let off_prev = off_density + n_occ * BRICK_BYTES;
        let off_next = off_prev + if gain { n_occ * comps * BRICK_BYTES } else { 0 };
        let off_fluence = off_next + n_occ * comps * BRICK_BYTES;
        let upload_end = off_fluence + n_dense * c * BRICK_BYTES;
        {
            let store = self.store;
            let fields = &*self.fields;
            let buffers = self.buffers.as_mut().ok_or(SolveError::Internal("device buffers released"))?;
            let staging = buffers.upload.mapped_mut().ok_or(SolveError::Internal("upload staging is not mapped"))?;
            let staging = &mut staging[..upload_end as usize];
            put(staging, 0, bytemuck::cast_slice(&slots));
            for (i, &b) in occupied.iter().enumerate() {
                let o = off_density as usize + i * BRICK_BYTES as usize;
                put(staging, o, bytemuck::cast_slice(store.density_brick(b).unwrap_or(&[])));
                let block = (comps * BRICK_BYTES) as usize;
                if gain {
                    let src = fields.source_prev.brick(b).unwrap_or(&[]);
                    put(staging, off_prev as usize + i * block, bytemuck::cast_slice(src));
                }
                let src = fields.source_next.brick(b).unwrap_or(&[]);
                put(staging, off_next as usize + i * block, bytemuck::cast_slice(src));
            }
            for (i, &b) in bricks.iter().enumerate() {
                let block = (c * BRICK_BYTES) as usize;
                let src = fields.fluence.brick(b).unwrap_or(&[]);
                put(staging, off_fluence as usize + i * block, bytemuck::cast_slice(src));
            }
        }

        let buffers = self.buffers()?;
        let propagate = self.propagate.as_ref().ok_or(SolveError::Internal("pipeline released"))?;
        let collect = self.collect.as_ref().ok_or(SolveError::Internal("pipeline released"))?;
        let mut rec = Recorder::begin(&self.ctx, self.ctx.compute_queue().family(), "slice")?;
        if first {
            for b in [&buffers.rays, &buffers.rays_in, &buffers.rays_out] {
                rec.fill_buffer(b, 0, vk::WHOLE_SIZE, 0);
            }
        }
        let copy = |src: u64, dst: u64, size: u64| vk::BufferCopy { src_offset: src, dst_offset: dst, size };
        rec.copy_buffer(&buffers.upload, &buffers.slot_table, &[copy(0, 0, n_dense * 4)]);
        if n_occ > 0 {
            rec.copy_buffer(&buffers.upload, &buffers.density, &[copy(off_density, 0, n_occ * BRICK_BYTES)]);
            if gain {
                rec.copy_buffer(&buffers.upload, &buffers.source_prev, &[copy(off_prev, 0, n_occ * comps * BRICK_BYTES)]);
            }
            rec.copy_buffer(&buffers.upload, &buffers.source_next, &[copy(off_next, 0, n_occ * comps * BRICK_BYTES)]);
        }
        rec.copy_buffer(&buffers.upload, &buffers.fluence, &[copy(off_fluence, 0, n_dense * c * BRICK_BYTES)]);
        rec.transfer_to_compute();

        let (st, ss, emit) = (0..3).fold(([0f32; 4], [0f32; 4], [0f32; 4]), |(mut st, mut ss, mut em), ch| {
            let (t, s, a) = plan.coefficients(ch.min(plan.channels as usize - 1));
            st[ch] = t as f32;
            ss[ch] = s as f32;
            em[ch] = (a * plan.medium.emission[ch]) as f32;
            (st, ss, em)
        });
        let mut push = SweepPush {
            na: sweep.n[0],
            nb: sweep.n[1],
            nc: sweep.n[2],
            t0: slice.t0,
            t1: slice.t1,
            axis_sign: face.axis as u32 | if face.sign < 0.0 { 4 } else { 0 },
            lateral: face.lateral[0] as u32 | (face.lateral[1] as u32) << 2,
            bricks_b,
            bricks_c,
            dir_count: 0,
            channels: plan.channels,
            storage: plan.storage.len() as u32,
            flags,
            dir_base: 0,
            ray_base: 0,
            pad2: 0,
            sigma_t: st,
            sigma_s: ss,
            emission: emit,
        };
        let group = self.memory.directions_per_dispatch;
        let chunk = self.memory.planes_per_dispatch;
        let mut base = pass_dirs.start;
        while base < pass_dirs.end {
            let n = group.min(pass_dirs.end - base);
            push.dir_base = base;
            push.ray_base = base - pass_dirs.start;
            push.dir_count = n;
            let mut t0 = slice.t0;
            while t0 < slice.t1 {
                let t1 = (t0 + chunk).min(slice.t1);
                push.t0 = t0;
                push.t1 = t1;
                push.flags = flags | if last && t1 == slice.t1 { FLAG_LAST_SLICE } else { 0 };
                rec.dispatch(
                    propagate,
                    &[
                        BufferRange::from(&tables.directions),
                        BufferRange::from(&tables.offsets),
                        BufferRange::from(&buffers.slot_table),
                        BufferRange::from(&buffers.density),
                        BufferRange::from(&buffers.source_prev),
                        BufferRange::from(&buffers.rays),
                        BufferRange::from(&buffers.rays_in),
                        BufferRange::from(&buffers.rays_out),
                        BufferRange::from(&buffers.deposit),
                    ],
                    bytemuck::bytes_of(&push),
                    [sweep.n[1].div_ceil(16), sweep.n[2].div_ceil(4), n],
                )?;
                rec.compute_to_compute();
                rec.dispatch(
                    collect,
                    &[
                        BufferRange::from(&tables.directions),
                        BufferRange::from(&tables.rows),
                        BufferRange::from(&buffers.slot_table),
                        BufferRange::from(&buffers.density),
                        BufferRange::from(&buffers.deposit),
                        BufferRange::from(&buffers.source_next),
                        BufferRange::from(&buffers.fluence),
                    ],
                    bytemuck::bytes_of(&push),
                    [sweep.n[1].div_ceil(16), sweep.n[2].div_ceil(4), t1 - t0],
                )?;
                rec.compute_to_compute();
                t0 = t1;
            }
            base += n;
        }
        rec.compute_to_transfer();
        let next_bytes = n_occ * comps * BRICK_BYTES;
        if n_occ > 0 {
            rec.copy_buffer(&buffers.source_next, &buffers.download, &[copy(0, 0, next_bytes)]);
        }
        rec.copy_buffer(&buffers.fluence, &buffers.download, &[copy(0, next_bytes, n_dense * c * BRICK_BYTES)]);
        rec.transfer_to_host();
        self.submit_and_wait(rec)?;

        // Scatter the accumulators back into the store.
        let buffers = self.buffers.as_ref().ok_or(SolveError::Internal("device buffers released"))?;
        let staging = buffers.download.mapped().ok_or(SolveError::Internal("download staging is not mapped"))?;
        let fields = &mut *self.fields;
        for (i, &b) in occupied.iter().enumerate() {
            let block = (comps * BRICK_BYTES) as usize;
            if let Some(dst) = fields.source_next.brick_mut(b) {
                dst.copy_from_slice(bytemuck::cast_slice(&staging[i * block..(i + 1) * block]));
            }
        }
        for (i, &b) in bricks.iter().enumerate() {
            let block = (c * BRICK_BYTES) as usize;
            let o = next_bytes as usize + i * block;
            if let Some(dst) = fields.fluence.brick_mut(b) {
                dst.copy_from_slice(bytemuck::cast_slice(&staging[o..o + block]));
            }
        }
        Ok(())
    }

    /// Downloads the rays' birth and exit tallies of the sweep just finished, as powers.
    fn read_tallies(&mut self, sweep: &FaceSweep, dirs: &[SweepDirection]) -> Result<Tallies, SolveError> {
        let c = self.plan.channels as usize;
        let rays = sweep.rays();
        let bytes = (dirs.len() * c * rays * 4) as u64;
        let buffers = self.buffers()?;
        let mut rec = Recorder::begin(&self.ctx, self.ctx.compute_queue().family(), "tallies")?;
        rec.compute_to_transfer();
        let region = |dst| [vk::BufferCopy { src_offset: 0, dst_offset: dst, size: bytes }];
        rec.copy_buffer(&buffers.rays_in, &buffers.download, &region(0));
        rec.copy_buffer(&buffers.rays_out, &buffers.download, &region(bytes));
        rec.transfer_to_host();
        self.submit_and_wait(rec)?;
        let staging = self.buffers()?.download.mapped().ok_or(SolveError::Internal("download staging is not mapped"))?;
        let values: &[f32] = bytemuck::cast_slice(&staging[..2 * bytes as usize]);
        let (born, left) = values.split_at(values.len() / 2);
        let mut tallies = Tallies::default();
        for (d, dir) in dirs.iter().enumerate() {
            for ch in 0..c {
                let range = (d * c + ch) * rays..(d * c + ch + 1) * rays;
                let sum_in: f64 = born[range.clone()].iter().map(|&v| v as f64).sum();
                let sum_out: f64 = left[range].iter().map(|&v| v as f64).sum();
                tallies.boundary_in[ch] += sum_in * dir.power_per_radiance;
                tallies.boundary_out[ch] += sum_out * dir.power_per_radiance;
            }
        }
        Ok(tallies)
    }

    /// Frees every device resource (waits for the last submission first).
    fn release(&mut self) {
        if let Some(timeline) = self.timeline.as_ref() {
            if let Err(e) = timeline.wait(&self.ctx, self.timeline_value, WAIT_FOREVER) {
                tracing::warn!("waiting for the last submission failed: {e}");
            }
        }
        for tables in self.face_tables.drain(..).chain(self.beam_tables.drain(..)) {
            tables.destroy(&self.ctx);
        }
        if let Some(buffers) = self.buffers.take() {
            for b in buffers.all() {
                self.ctx.destroy_buffer(b);
            }
        }
        if let Some(p) = self.propagate.take() {
            self.ctx.destroy_pipeline(p);
        }
        if let Some(p) = self.collect.take() {
            self.ctx.destroy_pipeline(p);
        }
        if let Some(t) = self.timeline.take() {
            self.ctx.destroy_timeline(t);
        }
    }
}

impl Drop for GpuBackend<'_> {
    fn drop(&mut self) {
        self.release();
    }
}

/// Copies `bytes` into `staging` at `offset`.
fn put(staging: &mut [u8], offset: usize, bytes: &[u8]) {
    staging[offset..offset + bytes.len()].copy_from_slice(bytes);
}

impl Backend for GpuBackend<'_> {
    fn propagate_order(&mut self, order: u32) -> Result<Tallies, SolveError> {
        let plan = self.plan;
        let mut tallies = Tallies::default();
        if order == 0 {
            let beams = std::mem::take(&mut self.beam_tables);
            for (tables, beam) in beams.iter().zip(&plan.beams) {
                let r = self.sweep(tables, std::slice::from_ref(beam), FLAG_BOUNDARY);
                match r {
                    Ok(t) => tallies.add(&t),
                    Err(e) => {
                        self.beam_tables = beams;
                        return Err(e);
                    }
                }
            }
            self.beam_tables = beams;
        }
        let mut flags = FLAG_GAIN;
        if order == 0 {
            flags |= FLAG_BOUNDARY;
            if plan.emission {
                flags |= FLAG_EMIT;
            }
        }
        let faces = std::mem::take(&mut self.face_tables);
        let mut result = Ok(());
        for (tables, dirs) in faces.iter().zip(&plan.faces) {
            match self.sweep(tables, dirs, flags) {
                Ok(t) => tallies.add(&t),
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
        }
        self.face_tables = faces;
        result.map(|_| tallies)
    }

    fn finish_order(&mut self) -> Result<[f64; 3], SolveError> {
        Ok(self.fields.finish_order(self.plan))
    }

    fn emitted_and_absorbed(&mut self) -> Result<([f64; 3], [f64; 3]), SolveError> {
        Ok(self.fields.emitted_and_absorbed(self.store, self.plan))
    }
}
