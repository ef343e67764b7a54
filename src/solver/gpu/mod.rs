//! The GPU driver: sweeps the faces slice of bricks by slice of bricks on Vulkan, streaming the
//! slices through the device so that a volume far larger than device memory is solved.
//!
//! For every sweep (a sun beam, or the k² directions of one face in one order) the ray state stays
//! on the device from the first slice to the last; a face whose directions do not fit at once is
//! swept in passes. Each slice goes through five steps:
//!
//! 1. **gather** (host copy workers): its bricks (medium, previous source, the new source and fluence
//!    accumulated so far) from the memory-mapped store into the pinned upload staging of a slot;
//!    the previous source is rounded to f16 on the way when the plan stores it so (scaled by a
//!    power of two chosen per order from its largest value, undone exactly by the shader);
//! 2. **upload** (transfer queue): staging → the slot's device buffers; signals `upload = v`;
//! 3. **compute** (compute queue, waits `upload ≥ v`): `propagate.comp` marches the rays through the
//!    slice's planes writing segment averages into the deposit buffer, `collect.comp` folds them into
//!    fluence and the next source; signals `compute = v`;
//! 4. **download** (transfer queue, waits `compute ≥ v`): the two accumulators → download staging;
//!    signals `download = v`;
//! 5. **scatter** (host copy workers, after `download ≥ v`): staging → store.
//!
//! With two slots (the memory plan decides, see [`budget`]) the steps of neighbouring slices
//! overlap: slice l+1 is gathered and uploaded, and slice l−1 downloaded and scattered, while slice
//! l computes. When a whole slice does not fit the budget it is streamed as sub-slices of fewer
//! planes (each slot then holds that slab of each occupied brick). Only occupied bricks travel; a
//! (sub-)slice without any is vacuum: it takes no slot and no transfer, and its compute step only
//! moves the rays across it (and is left out for directions that do not move sideways there). Transfer submissions go to a dedicated transfer queue when the device has one, else
//! to the compute queue as a second submission stream ordered by the same timeline semaphores.
//! With one slot each slice completes before the next starts. Slots are reused against timeline
//! values, never by idling the device. A long order logs its progress in passes now and then
//! ([`progress`]).

pub mod budget;
mod copier;
mod layout;
pub mod profile;
mod progress;
mod slice;
mod tables;

use super::energy::Tallies;
use super::fields::StoreFields;
use super::orders::Backend;
use super::plan::{half_scale_exponent, power_of_two, Plan, Precision, SweepDirection};
use super::sweep::FaceSweep;
use super::SolveError;
use crate::store::{BrickStore, BRICK_EDGE};
use crate::vk::{Buffer, BufferRange, ComputePipeline, Context, Recorder, TimelineSemaphore};
use ash::vk;
use budget::MemoryPlan;
use copier::{Copier, Ticket};
use gpu_allocator::MemoryLocation;
use layout::*;
use slice::SliceLayout;
use std::sync::Arc;
use tables::SweepTables;

const PROPAGATE_SPV: &[u8] = include_bytes!("../../../spirv/propagate.spv");
const COLLECT_SPV: &[u8] = include_bytes!("../../../spirv/collect.spv");
const WAIT_FOREVER: u64 = u64::MAX;

/// How the GPU backend runs.
#[derive(Clone, Copy, Debug)]
pub struct GpuOptions {
    /// Device memory budget in bytes; `None`: a safe fraction of the device heap.
    pub budget: Option<u64>,
    /// At most this many slices in flight: 2 lets transfers overlap compute, 1 forces one slice
    /// at a time (the single-queue schedule).
    pub max_slices_in_flight: u32,
    /// Write a checkpoint into the store after every completed order (for `--resume`).
    pub checkpoints: bool,
    /// Bracket every submission with GPU timestamps (for `lpm bench stream`).
    pub profile: bool,
}

impl Default for GpuOptions {
    fn default() -> Self {
        GpuOptions { budget: None, max_slices_in_flight: 2, checkpoints: false, profile: false }
    }
}

/// The device buffers and staging of one slice in flight.
struct Slot {
    slot_table: Buffer,
    density: Buffer,
    source_prev: Buffer,
    source_next: Buffer,
    fluence: Buffer,
    upload: Buffer,
    download: Buffer,
    /// The slice whose download into this slot's staging is not yet scattered back.
    pending: Option<(u64, SliceLayout)>,
    /// The scatter of this slot's download staging still being copied, and its slice.
    scattering: Option<(Ticket, SliceLayout)>,
}

impl Slot {
    fn buffers(self) -> [Buffer; 7] {
        [self.slot_table, self.density, self.source_prev, self.source_next, self.fluence, self.upload, self.download]
    }
}

/// Buffers shared by all slots: ray state and the deposit.
struct Shared {
    rays: Buffer,
    rays_in: Buffer,
    rays_out: Buffer,
    deposit: Buffer,
    tallies: Buffer,
    /// Bound in place of the slot buffers when a vacuum slice computes (never read).
    vacuum: Buffer,
}

/// The three timelines of the pipeline; each slice gets the next value on all three.
struct Timelines {
    upload: TimelineSemaphore,
    compute: TimelineSemaphore,
    download: TimelineSemaphore,
}

pub struct GpuBackend<'a> {
    ctx: Arc<Context>,
    plan: &'a Plan,
    store: &'a BrickStore,
    fields: &'a mut StoreFields,
    propagate: Option<ComputePipeline>,
    collect: Option<ComputePipeline>,
    timelines: Option<Timelines>,
    /// The last value handed out on the timelines.
    value: u64,
    /// The last values submitted to signal the upload and the download timelines (vacuum slices
    /// skip both).
    upload_value: u64,
    download_value: u64,
    slots: Vec<Slot>,
    shared: Option<Shared>,
    face_tables: Vec<SweepTables>,
    beam_tables: Vec<SweepTables>,
    memory: MemoryPlan,
    copier: Copier,
    /// The scene digest checkpoints are written under; `None`: no checkpoints.
    checkpoint_digest: Option<String>,
    /// The f16 previous source's scale exponent for the order being propagated (`None`: f32).
    half_exponent: Option<i32>,
    /// Test hook: abort the process when this many slices have been submitted (simulates a kill).
    abort_at_slice: Option<u64>,
    profiler: Option<profile::Profiler>,
    /// Passes done in the order being propagated (logged now and then).
    progress: Option<progress::PassProgress>,
}

fn create_buffers(
    ctx: &Context,
    specs: &[(&str, u64, vk::BufferUsageFlags, MemoryLocation)],
) -> Result<Vec<Buffer>, SolveError> {
    let mut made = Vec::with_capacity(specs.len());
    for &(name, size, usage, location) in specs {
        match ctx.create_buffer(name, size.max(4), usage, location) {
            Ok(b) => made.push(b),
            Err(e) => {
                made.into_iter().for_each(|b| ctx.destroy_buffer(b));
                return Err(e.into());
            }
        }
    }
    Ok(made)
}

impl<'a> GpuBackend<'a> {
    /// Prepares the device for `plan`; the solve accumulates into `fields` (in `store`).
    pub fn new(
        ctx: Arc<Context>,
        plan: &'a Plan,
        store: &'a BrickStore,
        fields: &'a mut StoreFields,
        options: GpuOptions,
    ) -> Result<Self, SolveError> {
        let limits = ctx.limits();
        let budget = options.budget.unwrap_or_else(|| budget::default_budget(&limits));
        if budget > limits.device_local_heap_bytes {
            return Err(SolveError::BudgetTooLarge { budget, device: limits.device_local_heap_bytes });
        }
        let memory = budget::plan_memory(
            plan,
            budget::slice_extent(plan, store),
            &limits,
            budget,
            options.max_slices_in_flight,
        )?;
        let c = plan.channels as u64;
        let comps = plan.source_components() as u64;
        let extent = memory.slice;
        let ray_bytes = memory.directions_per_pass as u64 * c * extent.rays * 4;
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::TRANSFER_DST
            | vk::BufferUsageFlags::TRANSFER_SRC;
        let gpu = MemoryLocation::GpuOnly;
        let per_component = extent.occupied * slice::slab_bytes(memory.planes_per_slice);
        let source_bytes = per_component * comps;
        let prev_bytes = source_bytes / 4 * plan.source_precision.bytes();
        let fluence_bytes = per_component * c;
        let upload_bytes =
            (extent.bricks * 4).next_multiple_of(16) + per_component + prev_bytes + source_bytes + fluence_bytes;

        let shared = create_buffers(
            &ctx,
            &[
                ("rays", ray_bytes, storage, gpu),
                ("rays in", ray_bytes, storage, gpu),
                ("rays out", ray_bytes, storage, gpu),
                ("deposit", memory.deposit_bytes, storage, gpu),
                ("tally staging", 2 * ray_bytes, vk::BufferUsageFlags::TRANSFER_DST, MemoryLocation::GpuToCpu),
                ("vacuum", 16, storage, gpu),
            ],
        )?;
        let mut it = shared.into_iter();
        let shared = match (it.next(), it.next(), it.next(), it.next(), it.next(), it.next()) {
            (Some(rays), Some(rays_in), Some(rays_out), Some(deposit), Some(tallies), Some(vacuum)) => {
                Shared { rays, rays_in, rays_out, deposit, tallies, vacuum }
            }
            _ => return Err(SolveError::Internal("shared buffers")),
        };
        let mut backend = GpuBackend {
            ctx: ctx.clone(),
            plan,
            store,
            fields,
            propagate: None,
            collect: None,
            timelines: None,
            value: 0,
            upload_value: 0,
            download_value: 0,
            slots: Vec::new(),
            shared: Some(shared),
            face_tables: Vec::new(),
            beam_tables: Vec::new(),
            memory,
            copier: Copier::new(std::thread::available_parallelism().map_or(2, |n| n.get()).min(8)),
            checkpoint_digest: None,
            half_exponent: None,
            abort_at_slice: std::env::var("LPM_TEST_ABORT_AT_SLICE").ok().and_then(|v| v.parse().ok()),
            profiler: None,
            progress: None,
        };
        if options.profile {
            // Three intervals per sub-slice; a pass never has more slices than the longest axis has
            // bricks, each cut into sub-slices of `planes_per_slice` planes.
            let bricks = plan.dims.iter().map(|d| d.div_ceil(BRICK_EDGE)).max().unwrap_or(1);
            let slices = bricks * (BRICK_EDGE / memory.planes_per_slice);
            backend.profiler = Some(profile::Profiler::new(&ctx, 6 * slices + 6)?);
        }
        // From here on, `backend` owns everything made and frees it on drop if a step fails.
        for i in 0..memory.slices_in_flight {
            let made = create_buffers(
                &ctx,
                &[
                    (&format!("slot {i} slot table"), extent.bricks * 4, storage, gpu),
                    (&format!("slot {i} density"), per_component, storage, gpu),
                    (&format!("slot {i} source prev"), prev_bytes, storage, gpu),
                    (&format!("slot {i} source next"), source_bytes, storage, gpu),
                    (&format!("slot {i} fluence"), fluence_bytes, storage, gpu),
                    (
                        &format!("slot {i} upload staging"),
                        upload_bytes,
                        vk::BufferUsageFlags::TRANSFER_SRC,
                        MemoryLocation::CpuToGpu,
                    ),
                    (
                        &format!("slot {i} download staging"),
                        source_bytes + fluence_bytes,
                        vk::BufferUsageFlags::TRANSFER_DST,
                        MemoryLocation::GpuToCpu,
                    ),
                ],
            )?;
            let mut it = made.into_iter();
            match (it.next(), it.next(), it.next(), it.next(), it.next(), it.next(), it.next()) {
                (
                    Some(slot_table),
                    Some(density),
                    Some(source_prev),
                    Some(source_next),
                    Some(fluence),
                    Some(upload),
                    Some(download),
                ) => backend.slots.push(Slot {
                    slot_table,
                    density,
                    source_prev,
                    source_next,
                    fluence,
                    upload,
                    download,
                    pending: None,
                    scattering: None,
                }),
                _ => return Err(SolveError::Internal("slot buffers")),
            }
        }
        let push_bytes = std::mem::size_of::<SweepPush>() as u32;
        backend.propagate = Some(ctx.create_compute_pipeline("propagate", PROPAGATE_SPV, 9, push_bytes)?);
        backend.collect = Some(ctx.create_compute_pipeline("collect", COLLECT_SPV, 8, push_bytes)?);
        backend.timelines = Some(Timelines {
            upload: ctx.create_timeline("upload", 0)?,
            compute: ctx.create_timeline("compute", 0)?,
            download: ctx.create_timeline("download", 0)?,
        });
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
            transfer_queue = backend.ctx.transfer_queue().is_some(),
            budget = memory.budget_bytes,
            planned = memory.planned_bytes,
            slices_in_flight = memory.slices_in_flight,
            directions_per_pass = memory.directions_per_pass,
            directions_per_dispatch = memory.directions_per_dispatch,
            planes_per_slice = memory.planes_per_slice,
            planes_per_dispatch = memory.planes_per_dispatch,
            "GPU backend ready"
        );
        Ok(backend)
    }

    /// Writes a checkpoint into the store after every completed order.
    pub fn enable_checkpoints(&mut self, digest: String) {
        self.checkpoint_digest = Some(digest);
    }

    /// Streaming time and bytes measured so far (when profiling).
    pub fn stream_stats(&self) -> Option<profile::StreamStats> {
        self.profiler.as_ref().map(|p| p.stats.clone())
    }

    /// How the sweeps were cut to fit the device memory budget.
    pub fn memory_plan(&self) -> MemoryPlan {
        self.memory
    }

    /// The Vulkan context the backend runs on.
    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }

    fn timelines(&self) -> Result<&Timelines, SolveError> {
        self.timelines.as_ref().ok_or(SolveError::Internal("timelines released"))
    }

    fn shared(&self) -> Result<&Shared, SolveError> {
        self.shared.as_ref().ok_or(SolveError::Internal("shared buffers released"))
    }

    /// Submits a one-off command buffer on the compute queue and waits for it (setup and the
    /// per-pass tallies, not the slice pipeline).
    fn submit_and_wait(&mut self, rec: Recorder) -> Result<(), SolveError> {
        self.value += 1;
        let v = self.value;
        let t = self.timelines()?;
        // The upload, compute and download timelines all advance to v, so the slice pipeline's
        // values stay one sequence.
        rec.submit(self.ctx.compute_queue(), &[], (&t.compute, v))?;
        t.compute.wait(&self.ctx, v, WAIT_FOREVER)?;
        t.upload.signal(&self.ctx, v)?;
        t.download.signal(&self.ctx, v)?;
        (self.upload_value, self.download_value) = (v, v);
        self.ctx.collect_garbage()?;
        Ok(())
    }

    /// One sweep of a face (or a beam): its directions in passes of at most `directions_per_pass`,
    /// each pass streaming every slice of the face in sweep order.
    fn sweep(&mut self, tables: &SweepTables, dirs: &[SweepDirection], flags: u32) -> Result<Tallies, SolveError> {
        let sweep = FaceSweep::new(dirs[0].face, self.plan.dims);
        let pass = self.memory.directions_per_pass as usize;
        let mut tallies = Tallies::default();
        for first in (0..dirs.len()).step_by(pass) {
            let pass_dirs = first as u32..(first + pass).min(dirs.len()) as u32;
            self.stream_pass(tables, &sweep, pass_dirs.clone(), flags)?;
            if let Some(p) = self.progress.as_mut() {
                p.pass_done();
            }
            tallies.add(&self.read_tallies(&sweep, &dirs[pass_dirs.start as usize..pass_dirs.end as usize])?);
        }
        Ok(tallies)
    }

    /// Streams every slice of the face through the slots for the directions `pass_dirs`.
    fn stream_pass(
        &mut self,
        tables: &SweepTables,
        sweep: &FaceSweep,
        pass_dirs: std::ops::Range<u32>,
        flags: u32,
    ) -> Result<(), SolveError> {
        let slices = sweep.slices(BRICK_EDGE, self.memory.planes_per_slice);
        let n_slots = self.slots.len();
        let mut filled = 0;
        let gain = flags & FLAG_GAIN != 0;
        let (c, comps) = (self.plan.channels as u64, self.plan.source_components() as u64);
        // The slot of the slice computed in the previous iteration: its download is submitted after
        // this iteration's upload, so the transfer queue can upload the next slice while it computes.
        let mut to_download: Option<usize> = None;
        for (i, range) in slices.iter().enumerate() {
            let (first, last) = (i == 0, i + 1 == slices.len());
            let half = if gain { self.half_exponent.map(power_of_two) } else { None };
            let layout = SliceLayout::new(self.store, sweep, *range, gain, c, comps, half);
            if layout.is_vacuum() {
                self.value += 1;
                let v = self.value;
                self.submit_compute(None, &layout, tables, sweep, pass_dirs.clone(), flags, first, last, v)?;
                continue;
            }
            let s = filled % n_slots;
            filled += 1;
            self.retire_slot(s)?;
            self.gather(s, &layout)?;
            self.value += 1;
            let v = self.value;
            if self.abort_at_slice == Some(v) {
                tracing::error!("LPM_TEST_ABORT_AT_SLICE={v}: aborting as a kill would");
                std::process::abort();
            }
            self.submit_upload(s, &layout, v)?;
            self.submit_compute(Some(s), &layout, tables, sweep, pass_dirs.clone(), flags, first, last, v)?;
            self.slots[s].pending = Some((v, layout));
            if n_slots == 1 {
                self.submit_download(s)?;
            } else if let Some(prev) = to_download.replace(s) {
                self.submit_download(prev)?;
            }
        }
        if let Some(prev) = to_download {
            self.submit_download(prev)?;
        }
        // Drain: every slice back in the store before the next pass reads it.
        let mut order: Vec<usize> = (0..n_slots).collect();
        order.sort_by_key(|&s| self.slots[s].pending.as_ref().map_or(0, |p| p.0));
        for s in order {
            self.retire_slot(s)?;
        }
        for s in 0..n_slots {
            self.finish_scatter(s);
        }
        if let Some(p) = self.profiler.as_mut() {
            p.collect(&self.ctx)?;
        }
        self.ctx.collect_garbage()?;
        Ok(())
    }

    /// Makes slot `s` free: waits for its last slice's download and scatters it back to the store.
    fn retire_slot(&mut self, s: usize) -> Result<(), SolveError> {
        self.finish_scatter(s);
        let Some((v, layout)) = self.slots[s].pending.take() else { return Ok(()) };
        self.timelines()?.download.wait(&self.ctx, v, WAIT_FOREVER)?;
        let staging =
            self.slots[s].download.mapped().ok_or(SolveError::Internal("download staging is not mapped"))?.as_ptr();
        let regions = layout.scatter(self.fields, staging);
        self.slots[s].scattering = Some((self.copier.copy(regions), layout));
        Ok(())
    }

    /// Waits for slot `s`'s scatter, then hands the pages of its slice's bricks back (they are
    /// done with until the next pass: this keeps the resident memory to the slices in flight).
    fn finish_scatter(&mut self, s: usize) {
        let Some((ticket, layout)) = self.slots[s].scattering.take() else { return };
        ticket.wait();
        let fields = &*self.fields;
        let mut slots = layout.occupied.iter().filter_map(|&b| self.store.slot(b)).map(|k| k as usize).peekable();
        // Runs of consecutive slots, one release each.
        while let Some(first) = slots.next() {
            let mut count = 1;
            while slots.peek() == Some(&(first + count)) {
                slots.next();
                count += 1;
            }
            self.store.release_density(first, count);
            for field in [&fields.source_prev, &fields.source_next, &fields.fluence] {
                field.release_stored(first, count);
            }
        }
    }

    /// Fills slot `s`'s upload staging with the slice's bricks (waits for the copies).
    fn gather(&mut self, s: usize, layout: &SliceLayout) -> Result<(), SolveError> {
        let store = self.store;
        let staging = self.slots[s].upload.mapped_mut().ok_or(SolveError::Internal("upload staging is not mapped"))?;
        if (staging.len() as u64) < layout.upload_bytes() {
            return Err(SolveError::Internal("upload staging smaller than the slice"));
        }
        let table: &[u8] = bytemuck::cast_slice(&layout.slots);
        staging[..table.len()].copy_from_slice(table);
        let base = staging.as_mut_ptr();
        let regions = layout.gather(store, self.fields, base);
        self.copier.copy(regions).wait();
        Ok(())
    }

    fn submit_upload(&mut self, s: usize, layout: &SliceLayout, v: u64) -> Result<(), SolveError> {
        let queue = self.ctx.transfer_queue().unwrap_or(self.ctx.compute_queue());
        let slot = &self.slots[s];
        let mut rec = Recorder::begin(&self.ctx, queue.family(), "upload")?;
        let mark = self.profiler.as_mut().and_then(|p| p.begin(&mut rec, profile::Work::Upload, layout.upload_bytes()));
        let copy = |src: u64, size: u64| [vk::BufferCopy { src_offset: src, dst_offset: 0, size }];
        rec.copy_buffer(&slot.upload, &slot.slot_table, &copy(0, layout.slot_table_bytes()));
        rec.copy_buffer(&slot.upload, &slot.density, &copy(layout.density_offset(), layout.density_bytes()));
        if layout.gain {
            rec.copy_buffer(&slot.upload, &slot.source_prev, &copy(layout.prev_offset(), layout.prev_bytes()));
        }
        rec.copy_buffer(&slot.upload, &slot.source_next, &copy(layout.next_offset(), layout.source_bytes()));
        rec.copy_buffer(&slot.upload, &slot.fluence, &copy(layout.fluence_offset(), layout.fluence_bytes()));
        if let Some(p) = self.profiler.as_mut() {
            p.end(&mut rec, mark);
        }
        rec.submit(queue, &[], (&self.timelines()?.upload, v))?;
        self.upload_value = v;
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    fn submit_compute(
        &mut self,
        s: Option<usize>,
        layout: &SliceLayout,
        tables: &SweepTables,
        sweep: &FaceSweep,
        pass_dirs: std::ops::Range<u32>,
        flags: u32,
        first: bool,
        last: bool,
        v: u64,
    ) -> Result<(), SolveError> {
        let plan = self.plan;
        let slot = s.map(|s| &self.slots[s]);
        let shared = self.shared.as_ref().ok_or(SolveError::Internal("shared buffers released"))?;
        // A vacuum slice binds a dummy in place of the slot buffers its kernel never reads.
        let (slot_table, density, source_prev) = match slot {
            Some(slot) => (&slot.slot_table, &slot.density, &slot.source_prev),
            None => (&shared.vacuum, &shared.vacuum, &shared.vacuum),
        };
        let vacuum = if slot.is_none() { FLAG_VACUUM } else { 0 };
        let half = match self.half_exponent {
            Some(e) if flags & FLAG_GAIN != 0 => half_source_flags(e),
            _ => 0,
        };
        let propagate = self.propagate.as_ref().ok_or(SolveError::Internal("pipeline released"))?;
        let collect = self.collect.as_ref().ok_or(SolveError::Internal("pipeline released"))?;
        let queue = self.ctx.compute_queue();
        let mut rec = Recorder::begin(&self.ctx, queue.family(), "compute")?;
        let mark = self.profiler.as_mut().and_then(|p| p.begin(&mut rec, profile::Work::Compute, 0));
        // Earlier compute submissions wrote the ray state and the deposit this one uses.
        rec.compute_to_compute();
        if first {
            for b in [&shared.rays, &shared.rays_in, &shared.rays_out] {
                rec.fill_buffer(b, 0, vk::WHOLE_SIZE, 0);
            }
            rec.transfer_to_compute();
        }
        let face = sweep.geometry();
        let coefficient = |ch: usize| plan.coefficients(ch.min(plan.channels as usize - 1));
        let vec4 = |f: &dyn Fn(usize) -> f64| [f(0) as f32, f(1) as f32, f(2) as f32, 0.0];
        let mut push = SweepPush {
            na: sweep.n[0],
            nb: sweep.n[1],
            nc: sweep.n[2],
            t0: 0,
            t1: 0,
            axis_sign: face.axis as u32 | if face.sign < 0.0 { 4 } else { 0 },
            lateral: face.lateral[0] as u32 | (face.lateral[1] as u32) << 2,
            bricks_b: layout.bricks_b,
            bricks_c: layout.bricks_c,
            dir_count: 0,
            channels: plan.channels,
            storage: plan.storage.len() as u32,
            flags,
            dir_base: 0,
            ray_base: 0,
            slab: layout.range.slab_lo | layout.range.slab_planes << 8,
            sigma_t: vec4(&|ch| coefficient(ch).0),
            sigma_s: vec4(&|ch| coefficient(ch).1),
            emission: vec4(&|ch| coefficient(ch).2 * plan.medium.emission[ch]),
        };
        let range = layout.range;
        let group = self.memory.directions_per_dispatch;
        let chunk = self.memory.planes_per_dispatch;
        let mut base = pass_dirs.start;
        while base < pass_dirs.end {
            let n = group.min(pass_dirs.end - base);
            push.dir_base = base;
            push.ray_base = base - pass_dirs.start;
            push.dir_count = n;
            let mut t0 = range.t0;
            while t0 < range.t1 {
                let t1 = (t0 + chunk).min(range.t1);
                push.t0 = t0;
                push.t1 = t1;
                let last_chunk = last && t1 == range.t1;
                push.flags = flags | vacuum | half | if last_chunk { FLAG_LAST_SLICE } else { 0 };
                // Across vacuum, rays that do not move sideways keep everything: the kernel would
                // only read and write back the ray state (a big share of a sparse volume's time).
                if slot.is_none() && !last_chunk && tables.still(base..base + n, t0, t1) {
                    t0 = t1;
                    continue;
                }
                rec.dispatch(
                    propagate,
                    &[
                        BufferRange::from(&tables.directions),
                        BufferRange::from(&tables.offsets),
                        BufferRange::from(slot_table),
                        BufferRange::from(density),
                        BufferRange::from(source_prev),
                        BufferRange::from(&shared.rays),
                        BufferRange::from(&shared.rays_in),
                        BufferRange::from(&shared.rays_out),
                        BufferRange::from(&shared.deposit),
                    ],
                    bytemuck::bytes_of(&push),
                    [(sweep.n[1] + 1).div_ceil(16), (sweep.n[2] + 1).div_ceil(4), n],
                )?;
                rec.compute_to_compute();
                if let Some(slot) = slot {
                    rec.dispatch(
                        collect,
                        &[
                            BufferRange::from(&tables.directions),
                            BufferRange::from(&tables.rows),
                            BufferRange::from(&slot.slot_table),
                            BufferRange::from(&slot.density),
                            BufferRange::from(&shared.deposit),
                            BufferRange::from(&slot.source_next),
                            BufferRange::from(&slot.fluence),
                            BufferRange::from(&tables.offsets),
                        ],
                        bytemuck::bytes_of(&push),
                        [sweep.n[1].div_ceil(16), sweep.n[2].div_ceil(4), t1 - t0],
                    )?;
                    rec.compute_to_compute();
                }
                t0 = t1;
            }
            base += n;
        }
        if let Some(p) = self.profiler.as_mut() {
            p.end(&mut rec, mark);
        }
        let t = self.timelines.as_ref().ok_or(SolveError::Internal("timelines released"))?;
        let waits = [(&t.upload, v, vk::PipelineStageFlags2::COMPUTE_SHADER)];
        // A vacuum slice waits for no upload: the compute queue's own order is enough.
        rec.submit(queue, if slot.is_some() { &waits } else { &[] }, (&t.compute, v))?;
        Ok(())
    }

    /// Submits the download of the slice pending in slot `s`.
    fn submit_download(&mut self, s: usize) -> Result<(), SolveError> {
        // The staging is free once the scatter of its previous contents is done.
        self.finish_scatter(s);
        let queue = self.ctx.transfer_queue().unwrap_or(self.ctx.compute_queue());
        let slot = &self.slots[s];
        let Some((v, layout)) = slot.pending.as_ref() else { return Ok(()) };
        let v = *v;
        let mut rec = Recorder::begin(&self.ctx, queue.family(), "download")?;
        let next = layout.source_bytes();
        let bytes = next + layout.fluence_bytes();
        let mark = self.profiler.as_mut().and_then(|p| p.begin(&mut rec, profile::Work::Download, bytes));
        rec.copy_buffer(
            &slot.source_next,
            &slot.download,
            &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size: next }],
        );
        rec.copy_buffer(
            &slot.fluence,
            &slot.download,
            &[vk::BufferCopy { src_offset: 0, dst_offset: next, size: layout.fluence_bytes() }],
        );
        rec.transfer_to_host();
        if let Some(p) = self.profiler.as_mut() {
            p.end(&mut rec, mark);
        }
        let t = self.timelines.as_ref().ok_or(SolveError::Internal("timelines released"))?;
        rec.submit(queue, &[(&t.compute, v, vk::PipelineStageFlags2::TRANSFER)], (&t.download, v))?;
        self.download_value = v;
        Ok(())
    }

    /// Downloads the rays' birth and exit tallies of the pass just finished, as powers.
    fn read_tallies(&mut self, sweep: &FaceSweep, dirs: &[SweepDirection]) -> Result<Tallies, SolveError> {
        let c = self.plan.channels as usize;
        let rays = sweep.rays();
        let bytes = (dirs.len() * c * rays * 4) as u64;
        let shared = self.shared()?;
        let mut rec = Recorder::begin(&self.ctx, self.ctx.compute_queue().family(), "tallies")?;
        rec.compute_to_transfer();
        let region = |dst| [vk::BufferCopy { src_offset: 0, dst_offset: dst, size: bytes }];
        rec.copy_buffer(&shared.rays_in, &shared.tallies, &region(0));
        rec.copy_buffer(&shared.rays_out, &shared.tallies, &region(bytes));
        rec.transfer_to_host();
        self.submit_and_wait(rec)?;
        let staging = self.shared()?.tallies.mapped().ok_or(SolveError::Internal("tally staging is not mapped"))?;
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
        if let Some(t) = self.timelines.as_ref() {
            let last = [(&t.upload, self.upload_value), (&t.compute, self.value), (&t.download, self.download_value)];
            for (timeline, value) in last {
                if let Err(e) = timeline.wait(&self.ctx, value, WAIT_FOREVER) {
                    tracing::warn!("waiting for the last submission failed: {e}");
                }
            }
        }
        for slot in &mut self.slots {
            if let Some((t, _)) = slot.scattering.take() {
                t.wait();
            }
        }
        for tables in self.face_tables.drain(..).chain(self.beam_tables.drain(..)) {
            tables.destroy(&self.ctx);
        }
        for slot in self.slots.drain(..) {
            for b in slot.buffers() {
                self.ctx.destroy_buffer(b);
            }
        }
        if let Some(shared) = self.shared.take() {
            for b in [shared.rays, shared.rays_in, shared.rays_out, shared.deposit, shared.tallies, shared.vacuum] {
                self.ctx.destroy_buffer(b);
            }
        }
        if let Some(p) = self.propagate.take() {
            self.ctx.destroy_pipeline(p);
        }
        if let Some(p) = self.collect.take() {
            self.ctx.destroy_pipeline(p);
        }
        if let Some(p) = self.profiler.take() {
            p.destroy(&self.ctx);
        }
        if let Some(t) = self.timelines.take() {
            self.ctx.destroy_timeline(t.upload);
            self.ctx.destroy_timeline(t.compute);
            self.ctx.destroy_timeline(t.download);
        }
    }
}

impl Drop for GpuBackend<'_> {
    fn drop(&mut self) {
        self.release();
    }
}

impl Backend for GpuBackend<'_> {
    fn propagate_order(&mut self, order: u32) -> Result<Tallies, SolveError> {
        let plan = self.plan;
        self.fields.begin_order()?;
        // The scale of this order's f16 source, from its largest value (exact: a power of two).
        self.half_exponent =
            (plan.source_precision == Precision::F16).then(|| half_scale_exponent(self.fields.source_prev.max_abs()));
        let face_dirs: Vec<usize> = plan.faces.iter().map(Vec::len).collect();
        let passes = progress::passes_per_order(order, &face_dirs, plan.beams.len(), self.memory.directions_per_pass);
        self.progress = Some(progress::PassProgress::new(order, passes));
        let mut tallies = Tallies::default();
        if order == 0 {
            let beams = std::mem::take(&mut self.beam_tables);
            let mut result = Ok(());
            for (tables, beam) in beams.iter().zip(&plan.beams) {
                match self.sweep(tables, std::slice::from_ref(beam), FLAG_BOUNDARY) {
                    Ok(t) => tallies.add(&t),
                    Err(e) => {
                        result = Err(e);
                        break;
                    }
                }
            }
            self.beam_tables = beams;
            result?;
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
        Ok(self.fields.commit_order(self.plan))
    }

    fn apply_tail(&mut self, factor: [f64; 3]) -> Result<(), SolveError> {
        self.fields.apply_tail(self.plan, factor);
        Ok(())
    }

    fn checkpoint(&mut self, state: &super::fields::LoopState) -> Result<(), SolveError> {
        match &self.checkpoint_digest {
            Some(digest) => self.fields.write_checkpoint(self.store.dir(), digest, state),
            None => Ok(()),
        }
    }

    fn emitted_and_absorbed(&mut self) -> Result<([f64; 3], [f64; 3]), SolveError> {
        Ok(self.fields.emitted_and_absorbed(self.store, self.plan))
    }

    fn remaining_error(&mut self, factor: [f64; 3]) -> Result<crate::solver::remaining::RemainingError, SolveError> {
        Ok(self.fields.remaining_error(self.store, self.plan, factor))
    }
}
