//! The slice streamer: schedules the (sub-)slices of a pass through the slots — gather on the copy
//! workers, upload, compute, download, scatter — against three timeline semaphores, so that with
//! two slots the transfers of one slice overlap the compute of another (see the module docs of
//! [`super`] for the five steps). The next occupied slice's gather is started on the copy workers
//! as soon as a slice is submitted (`SliceStreamer::gather_ahead`), so the host's copies overlap
//! the device's work instead of running on the submitting thread between submissions.
//!
//! In the resident mode ([`super::budget::Residency`]) a pass only computes: the order's fields
//! live in the resident buffers, loaded through the slots' staging at the start of the order
//! ([`SliceStreamer::load_resident`]: the previous source, and the medium the first time) and
//! brought home at its end ([`SliceStreamer::unload_resident`]: the new source and the fluence),
//! slice by slice with the same gather and scatter as a streamed pass.
//!
//! It owns the synchronisation state: the timelines and the last value submitted on each, the
//! slots' pending downloads and scatters, the copy workers, and the profiler's timestamps. Dropping
//! it waits for the last submission and the last copy, so it must be dropped before the
//! [`DeviceResources`] it streams through (the driver declares it first).

use super::budget::MemoryPlan;
use super::buffers::{ResidentBuffers, SweepSets};
use super::copier::{Copier, Ticket};
use super::encoder::{self, ComputeStep};
use super::layout::FLAG_GAIN;
use super::profile;
use super::resources::DeviceResources;
use super::sizes::BRICK_BYTES;
use super::slice::SliceLayout;
use super::submit::{Submitter, Timelines, WAIT_FOREVER};
use super::tables::SweepTables;
use crate::solver::cancel::CancelFlag;
use crate::solver::fields::StoreFields;
use crate::solver::plan::{power_of_two, Plan};
use crate::solver::sweep::{FaceSweep, SliceRange};
use crate::solver::SolveError;
use crate::store::{BrickStore, BRICK_EDGE};
use crate::vk::{Context, Recorder};
use ash::vk;
use std::ops::Range;
use std::sync::Arc;

/// What a slot is waiting for.
#[derive(Default)]
struct SlotState {
    /// The resident mode's load: the upload that last read this slot's staging, and its slice.
    loading: Option<(u64, SliceLayout)>,
    /// The slice whose download into this slot's staging is not yet scattered back.
    pending: Option<(u64, SliceLayout)>,
    /// The scatter of this slot's download staging still being copied, and its slice.
    scattering: Option<(Ticket, SliceLayout)>,
    /// The timeline value of the last upload that read this slot's upload staging: the staging
    /// may be gathered into again once the upload timeline has passed it.
    uploaded: u64,
}

/// A slice's gather started before its turn (`SliceStreamer::gather_ahead`): the slot whose
/// upload staging it fills, the slice's index in its pass, and the copies still running (which
/// the ticket waits for, also when dropped on an error).
struct GatherAhead {
    slot: usize,
    index: usize,
    ticket: Ticket,
}

/// One pass of one sweep: its directions streamed through every slice of the face.
pub struct Pass<'p> {
    pub tables: &'p SweepTables,
    pub sets: &'p SweepSets,
    pub sweep: &'p FaceSweep,
    pub dirs: Range<u32>,
    pub flags: u32,
    /// The f16 previous source's scale exponent for this order (`None`: f32).
    pub half_exponent: Option<i32>,
    /// Another pass of the same sweep follows, in the same order: its first slice may be gathered
    /// while this pass ends ([`SliceStreamer::stream_pass`]).
    pub another_follows: bool,
    /// The resident mode's buffers, which every slice computes on (nothing streams); `None`:
    /// streamed.
    pub resident: Option<&'p ResidentBuffers>,
}

/// What a pass streams between: the plan, the store and its fields, the device resources.
pub struct Stream<'s> {
    pub plan: &'s Plan,
    pub store: &'s BrickStore,
    pub fields: &'s mut StoreFields,
    pub res: &'s DeviceResources,
}

pub struct SliceStreamer {
    /// The timelines and their values, the one-off submissions and the profiler.
    sub: Submitter,
    memory: MemoryPlan,
    /// The resident mode: the upload value of the order's last load, which every compute step
    /// waits for.
    resident_ready: u64,
    slots: Vec<SlotState>,
    copier: Copier,
    /// Test hooks on the slice count: a kill, or a cancel.
    hook: SliceHook,
    /// Slices computed so far (what the kill test's hook counts).
    slices: u64,
    /// Looked at before each slice: raised, the pass returns `SolveError::Cancelled`.
    cancel: Option<CancelFlag>,
    /// The next pass's first slice, already in this slot's upload staging (gathered while the
    /// pass before ended).
    pregathered: Option<(usize, SliceLayout)>,
}

/// The kill tests' hooks on the count of slices computed (tests/it/resume.rs; set only in builds
/// with the `test-hooks` feature): abort the process there, as a kill would, or raise the solve's
/// cancel flag there, as SIGTERM would (the next slice then stops the pass).
#[derive(Clone, Copy, Debug, Default)]
pub struct SliceHook {
    pub abort_at: Option<u64>,
    pub cancel_at: Option<u64>,
}

impl SliceStreamer {
    pub fn new(
        ctx: &Arc<Context>,
        plan: &Plan,
        memory: MemoryPlan,
        profile: bool,
        hook: SliceHook,
        cancel: Option<CancelFlag>,
    ) -> Result<Self, SolveError> {
        // Three intervals per sub-slice; a pass never has more slices than the longest axis has
        // bricks, each cut into sub-slices of `planes_per_slice` planes.
        let profile_queries = profile.then(|| {
            let bricks = plan.dims.iter().map(|d| d.div_ceil(BRICK_EDGE)).max().unwrap_or(1);
            6 * bricks * (BRICK_EDGE / memory.planes_per_slice) + 6
        });
        Ok(SliceStreamer {
            sub: Submitter::new(ctx, profile_queries)?,
            memory,
            resident_ready: 0,
            slots: (0..memory.slices_in_flight).map(|_| SlotState::default()).collect(),
            copier: Copier::new(std::thread::available_parallelism().map_or(2, |n| n.get()).min(8)),
            hook,
            slices: 0,
            cancel,
            pregathered: None,
        })
    }

    pub fn context(&self) -> &Arc<Context> {
        &self.sub.ctx
    }

    /// The submit layer, for the one-off submissions between passes.
    pub fn submitter(&mut self) -> &mut Submitter {
        &mut self.sub
    }

    /// Streaming time and bytes measured so far (when profiling).
    pub fn stats(&self) -> Option<profile::StreamStats> {
        self.sub.stats()
    }

    /// The next value on the timelines for a slice's work. The kill test's hook counts the slices
    /// (not the one-off submissions between them, whose number changes with what the passes
    /// between orders do).
    fn next_slice_value(&mut self) -> u64 {
        self.sub.value += 1;
        self.slices += 1;
        if self.hook.abort_at == Some(self.slices) {
            tracing::error!("LPM_TEST_ABORT_AT_SLICE={}: aborting as a kill would", self.slices);
            std::process::abort();
        }
        if let (true, Some(cancel)) = (self.hook.cancel_at == Some(self.slices), self.cancel) {
            tracing::warn!("LPM_TEST_CANCEL_AT_SLICE={}: cancelling as SIGTERM would", self.slices);
            cancel.raise();
        }
        self.sub.value
    }

    /// Streams every slice of the face through the slots for the pass's directions; returns when
    /// every slice is back in the store. In the resident mode the slices only compute.
    ///
    /// When another pass of the sweep follows, its first slice (this pass's first, with this
    /// pass's sums in it) is gathered into the free slot while the last slices compute and come
    /// home, so the next pass starts with an upload instead of a gather. Not when that slice is
    /// one of those still in flight (a sweep of one or two slices): its bytes are not final yet.
    pub fn stream_pass(&mut self, io: &mut Stream, pass: &Pass) -> Result<(), SolveError> {
        // Taken whatever happens: staging gathered for another pass is never used.
        let pregathered = self.pregathered.take();
        if let Some(resident) = pass.resident {
            return self.compute_resident_pass(io, pass, resident);
        }
        let plan = io.plan;
        let store = io.store;
        let gain = pass.flags & FLAG_GAIN != 0;
        let (c, comps) = (plan.channels as u64, plan.source_components() as u64);
        let half = if gain { pass.half_exponent.map(power_of_two) } else { None };
        let slices = pass.sweep.slices(BRICK_EDGE, self.memory.planes_per_slice);
        let layout_at = |j: usize| SliceLayout::new(store, pass.sweep, slices[j], gain, c, comps, half);
        // The next occupied slice's layout, made when the loop looked ahead to gather it (only it
        // and the slices in flight are kept: a huge volume's pass has millions of bricks).
        let mut next: Option<(usize, SliceLayout)> = None;
        let n_slots = self.slots.len();
        // The first occupied slice goes to the slot it was gathered into, if it was.
        let first_slot = pregathered.as_ref().map_or(0, |(s, _)| *s);
        let mut filled = first_slot;
        let mut first_occupied: Option<SliceRange> = None;
        // The slot of the slice computed in the previous iteration: its download is submitted after
        // this iteration's upload, so the transfer queue can upload the next slice while it computes.
        let mut to_download: Option<usize> = None;
        // The next occupied slice's gather, started once the slice before it was submitted.
        let mut ahead: Option<GatherAhead> = None;
        for (i, range) in slices.iter().enumerate() {
            // A cancelled solve stops here; what is in flight is waited for when the streamer drops.
            if self.cancel.is_some_and(|c| c.is_raised()) {
                return Err(SolveError::Cancelled { resumable: true });
            }
            let layout = match next.take() {
                Some((j, layout)) if j == i => layout,
                later => {
                    next = later;
                    layout_at(i)
                }
            };
            let step = |slot| ComputeStep {
                slot,
                layout: &layout,
                tables: pass.tables,
                sets: pass.sets,
                sweep: pass.sweep,
                pass_dirs: pass.dirs.clone(),
                flags: pass.flags,
                half_exponent: pass.half_exponent,
                first: i == 0,
                resident_table: None,
            };
            if layout.is_vacuum() {
                self.sub.value += 1;
                let v = self.sub.value;
                self.submit_compute(io, &step(None), v)?;
                continue;
            }
            let s = filled % n_slots;
            filled += 1;
            self.retire_slot(io, s)?;
            let gathered = match ahead.take() {
                Some(a) if a.slot == s && a.index == i => {
                    a.ticket.wait()?;
                    true
                }
                // Not this slice's (the ticket waits as it drops): gathered below.
                _ => first_occupied.is_none() && pregathered.as_ref().is_some_and(|(p, l)| *p == s && *l == layout),
            };
            if !gathered {
                self.gather(io, s, &layout)?;
            }
            first_occupied.get_or_insert(*range);
            let v = self.next_slice_value();
            self.submit_upload(io.res, s, &layout, v)?;
            self.submit_compute(io, &step(Some(s)), v)?;
            self.slots[s].pending = Some((v, layout));
            if n_slots == 1 {
                self.submit_download(io, s)?;
            } else if let Some(prev) = to_download.replace(s) {
                self.submit_download(io, prev)?;
            }
            if next.is_none() {
                next = (i + 1..slices.len()).map(|j| (j, layout_at(j))).find(|(_, l)| !l.is_vacuum());
            }
            if let Some((j, layout)) = &next {
                ahead = self.gather_ahead(io, filled % n_slots, *j, layout)?;
            }
        }
        if let Some(prev) = to_download {
            self.submit_download(io, prev)?;
        }
        if let (true, Some(range)) = (pass.another_follows && n_slots > 1, first_occupied) {
            let next = SliceLayout::new(store, pass.sweep, range, gain, c, comps, half);
            self.pregather(io, filled % n_slots, next)?;
        }
        self.drain(io)
    }

    /// The slices whose bricks the device or a copy worker may still be using: those computed
    /// and not yet downloaded, and those whose scatter is still being copied.
    fn in_flight(&self) -> impl Iterator<Item = &SliceLayout> {
        self.slots.iter().flat_map(|slot| {
            let pending = slot.pending.as_ref().map(|(_, l)| l);
            pending.into_iter().chain(slot.scattering.as_ref().map(|(_, l)| l))
        })
    }

    /// Starts gathering the pass's slice `index` (`layout`) into slot `s`'s upload staging on the
    /// copy workers, and returns without waiting: the copies run while the device computes the
    /// slices before it, so the submitting thread's next turn finds them done instead of doing
    /// them (on a GPU the host's gathers, not the bus, otherwise set a streamed order's pace).
    /// It costs no device memory (the slot's own staging, free once its last upload has read
    /// it) and no more host memory than one slice's pages mapped a little earlier.
    ///
    /// Not when a slice in flight shares a brick with it (sub-slices of one slice of bricks:
    /// its bricks' pages may be handed back under the gather); it is then gathered at its turn.
    fn gather_ahead(
        &mut self,
        io: &mut Stream,
        s: usize,
        index: usize,
        layout: &SliceLayout,
    ) -> Result<Option<GatherAhead>, SolveError> {
        if self.in_flight().any(|other| other.shares_bricks(layout)) {
            return Ok(None);
        }
        self.sub.timelines.upload.wait(&self.sub.ctx, self.slots[s].uploaded, WAIT_FOREVER)?;
        let ticket = self.start_gather(io, s, layout)?;
        if let Some(p) = self.sub.profiler.as_mut() {
            p.stats.gathered_ahead_slices += 1;
        }
        Ok(Some(GatherAhead { slot: s, index, ticket }))
    }

    /// Gathers `layout` (the next pass's first slice) into slot `s`'s upload staging, unless a
    /// slice still in flight shares a brick with it.
    fn pregather(&mut self, io: &mut Stream, s: usize, layout: SliceLayout) -> Result<(), SolveError> {
        if self.in_flight().any(|other| other.shares_bricks(&layout)) {
            return Ok(());
        }
        // The staging is free once the slot's last upload has read it.
        self.sub.timelines.upload.wait(&self.sub.ctx, self.slots[s].uploaded, WAIT_FOREVER)?;
        self.gather(io, s, &layout)?;
        if let Some(p) = self.sub.profiler.as_mut() {
            p.stats.pregathered_slices += 1;
        }
        self.pregathered = Some((s, layout));
        Ok(())
    }

    /// Waits for every slot's pending download and scatters it: every slice is back in the store
    /// (before the next pass, or the next order's passes, read it).
    fn drain(&mut self, io: &mut Stream) -> Result<(), SolveError> {
        let n_slots = self.slots.len();
        let mut order: Vec<usize> = (0..n_slots).collect();
        order.sort_by_key(|&s| self.slots[s].pending.as_ref().map_or(0, |p| p.0));
        for s in order {
            self.retire_slot(io, s)?;
        }
        for s in 0..n_slots {
            self.finish_scatter(io, s)?;
        }
        if let Some(p) = self.sub.profiler.as_mut() {
            p.collect(&self.sub.ctx)?;
        }
        self.sub.ctx.collect_garbage()?;
        Ok(())
    }

    /// A pass of the resident mode: every slice computes on the resident buffers (after the
    /// order's load), nothing moves.
    fn compute_resident_pass(
        &mut self,
        io: &mut Stream,
        pass: &Pass,
        resident: &ResidentBuffers,
    ) -> Result<(), SolveError> {
        let plan = io.plan;
        let gain = pass.flags & FLAG_GAIN != 0;
        let (c, comps) = (plan.channels as u64, plan.source_components() as u64);
        let half = if gain { pass.half_exponent.map(power_of_two) } else { None };
        for (i, range) in pass.sweep.slices(BRICK_EDGE, BRICK_EDGE).iter().enumerate() {
            if self.cancel.is_some_and(|c| c.is_raised()) {
                return Err(SolveError::Cancelled { resumable: true });
            }
            let layout = SliceLayout::new(io.store, pass.sweep, *range, gain, c, comps, half);
            let vacuum = layout.is_vacuum();
            let table = if vacuum { Vec::new() } else { layout.resident_slots(io.store) };
            let v = if vacuum { self.sub.value + 1 } else { self.next_slice_value() };
            self.sub.value = v;
            let step = ComputeStep {
                slot: (!vacuum).then_some(0),
                layout: &layout,
                tables: pass.tables,
                sets: pass.sets,
                sweep: pass.sweep,
                pass_dirs: pass.dirs.clone(),
                flags: pass.flags,
                half_exponent: pass.half_exponent,
                first: i == 0,
                resident_table: (!vacuum).then_some((&table[..], &*resident.slot_table)),
            };
            self.submit_compute(io, &step, v)?;
        }
        if let Some(p) = self.sub.profiler.as_mut() {
            p.collect(&self.sub.ctx)?;
        }
        self.sub.ctx.collect_garbage()?;
        Ok(())
    }

    /// The resident mode's start of an order: the previous source (at the order's precision:
    /// `half_exponent`) of every occupied brick, and the density when `with_density` (the first
    /// load of the solve), go from the store to the resident buffers through the slots' staging,
    /// slice by slice; the order's accumulators are filled with zeros on the device (what the
    /// store's cleared accumulators hold, bit for bit), or loaded too when `seeded` (the host
    /// wrote into them before the sweeps). Compute steps wait for the last upload.
    pub fn load_resident(
        &mut self,
        io: &mut Stream,
        resident: &ResidentBuffers,
        half_exponent: Option<i32>,
        with_density: bool,
        seeded: bool,
    ) -> Result<(), SolveError> {
        let plan = io.plan;
        let (c, comps) = (plan.channels as u64, plan.source_components() as u64);
        let half = half_exponent.map(power_of_two);
        let prev_brick = comps * BRICK_BYTES / 4 * plan.source_precision.bytes();
        let ctx = Arc::clone(&self.sub.ctx);
        let queue = ctx.upload_queue_or_fallback();
        // The previous order's kernels read and wrote the buffers the load overwrites, and its
        // unload read the accumulators the fill clears.
        let (computed, downloaded) = (self.sub.compute_value, self.sub.download_value);
        let submit = |rec: Recorder, t: &Timelines, v: u64| {
            let after = [
                (&*t.compute, computed, vk::PipelineStageFlags2::ALL_TRANSFER),
                (&*t.download, downloaded, vk::PipelineStageFlags2::ALL_TRANSFER),
            ];
            rec.submit(queue, &after, (&t.upload, v))
        };
        if !seeded {
            let v = self.next_slice_value();
            let mut rec = Recorder::begin(&ctx, queue.family(), "resident clear")?;
            rec.fill_buffer(&resident.source_next, 0, vk::WHOLE_SIZE, 0);
            rec.fill_buffer(&resident.fluence, 0, vk::WHOLE_SIZE, 0);
            submit(rec, &self.sub.timelines, v)?;
            self.sub.upload_value = v;
        }
        let sweep = FaceSweep::for_plan(0, plan);
        let n_slots = self.slots.len();
        let mut filled = 0;
        for range in sweep.slices(BRICK_EDGE, BRICK_EDGE) {
            let layout =
                SliceLayout::new(io.store, &sweep, range, true, c, comps, half).resident_load(with_density, seeded);
            if layout.is_vacuum() {
                continue;
            }
            let s = filled % n_slots;
            filled += 1;
            // The slot's staging is free once its last upload has read it.
            self.finish_load(io, s)?;
            self.gather(io, s, &layout)?;
            let v = self.next_slice_value();
            let slot = &io.res.slots[s];
            let mut rec = Recorder::begin(&ctx, queue.family(), "resident load")?;
            let mark = self
                .sub
                .profiler
                .as_mut()
                .and_then(|p| p.begin(&mut rec, profile::Work::Upload, layout.upload_bytes()));
            let place = |staging: u64, each: u64, brick_bytes: u64| -> Vec<vk::BufferCopy> {
                (layout.occupied.iter().enumerate())
                    .filter_map(|(i, &b)| io.store.slot(b).map(|k| (i as u64, k as u64)))
                    .map(|(i, k)| vk::BufferCopy {
                        src_offset: staging + i * each,
                        dst_offset: k * brick_bytes,
                        size: each,
                    })
                    .collect()
            };
            if with_density {
                rec.copy_buffer(
                    &slot.upload,
                    &resident.density,
                    &place(layout.density_offset(), BRICK_BYTES, BRICK_BYTES),
                );
            }
            rec.copy_buffer(&slot.upload, &resident.source_prev, &place(layout.prev_offset(), prev_brick, prev_brick));
            if seeded {
                let (next, fluence) = (comps * BRICK_BYTES, c * BRICK_BYTES);
                rec.copy_buffer(&slot.upload, &resident.source_next, &place(layout.next_offset(), next, next));
                rec.copy_buffer(&slot.upload, &resident.fluence, &place(layout.fluence_offset(), fluence, fluence));
            }
            if let Some(p) = self.sub.profiler.as_mut() {
                p.end(&mut rec, mark);
            }
            submit(rec, &self.sub.timelines, v)?;
            self.sub.upload_value = v;
            self.slots[s].loading = Some((v, layout));
        }
        self.resident_ready = self.sub.upload_value;
        for s in 0..n_slots {
            self.finish_load(io, s)?;
        }
        if let Some(p) = self.sub.profiler.as_mut() {
            p.collect(&self.sub.ctx)?;
        }
        Ok(())
    }

    /// The resident mode's end of an order: the new source and the fluence of every occupied
    /// brick come home through the slots' download staging, slice by slice (pipelined like a
    /// streamed pass's downloads); returns when all are in the store.
    pub fn unload_resident(&mut self, io: &mut Stream, resident: &ResidentBuffers) -> Result<(), SolveError> {
        let plan = io.plan;
        let (c, comps) = (plan.channels as u64, plan.source_components() as u64);
        let ctx = Arc::clone(&self.sub.ctx);
        let queue = ctx.download_queue_or_fallback();
        let sweep = FaceSweep::for_plan(0, plan);
        let n_slots = self.slots.len();
        let mut filled = 0;
        for range in sweep.slices(BRICK_EDGE, BRICK_EDGE) {
            let layout = SliceLayout::new(io.store, &sweep, range, false, c, comps, None).resident_unload();
            if layout.is_vacuum() {
                continue;
            }
            let s = filled % n_slots;
            filled += 1;
            // The slot's download staging is free once its last slice is scattered.
            self.retire_slot(io, s)?;
            self.finish_scatter(io, s)?;
            let v = self.next_slice_value();
            let slot = &io.res.slots[s];
            let mut rec = Recorder::begin(&ctx, queue.family(), "resident unload")?;
            let (next, fluence) = (layout.source_bytes(), layout.fluence_bytes());
            let mark =
                self.sub.profiler.as_mut().and_then(|p| p.begin(&mut rec, profile::Work::Download, next + fluence));
            let gather = |staging: u64, each: u64| -> Vec<vk::BufferCopy> {
                (layout.occupied.iter().enumerate())
                    .filter_map(|(i, &b)| io.store.slot(b).map(|k| (i as u64, k as u64)))
                    .map(|(i, k)| vk::BufferCopy { src_offset: k * each, dst_offset: staging + i * each, size: each })
                    .collect()
            };
            rec.copy_buffer(&resident.source_next, &slot.download, &gather(0, comps * BRICK_BYTES));
            rec.copy_buffer(&resident.fluence, &slot.download, &gather(next, c * BRICK_BYTES));
            rec.transfer_to_host();
            if let Some(p) = self.sub.profiler.as_mut() {
                p.end(&mut rec, mark);
            }
            let t = &self.sub.timelines;
            rec.submit(
                queue,
                &[(&*t.compute, self.sub.compute_value, vk::PipelineStageFlags2::ALL_TRANSFER)],
                (&t.download, v),
            )?;
            self.sub.download_value = v;
            self.slots[s].pending = Some((v, layout));
        }
        self.drain(io)
    }

    /// Waits for the load upload that last read slot `s`'s staging, then hands the store's pages
    /// of its slice back (done with until the unload).
    fn finish_load(&mut self, io: &mut Stream, s: usize) -> Result<(), SolveError> {
        let Some((v, layout)) = self.slots[s].loading.take() else { return Ok(()) };
        self.sub.timelines.upload.wait(&self.sub.ctx, v, WAIT_FOREVER)?;
        release_pages(io, &layout.occupied, &[&io.fields.source_prev]);
        Ok(())
    }

    /// Makes slot `s` free: waits for its last slice's download and scatters it back to the store.
    fn retire_slot(&mut self, io: &mut Stream, s: usize) -> Result<(), SolveError> {
        self.finish_scatter(io, s)?;
        let Some((v, layout)) = self.slots[s].pending.take() else { return Ok(()) };
        self.sub.timelines.download.wait(&self.sub.ctx, v, WAIT_FOREVER)?;
        let staging = io.res.slots[s].download.bytes().as_ptr();
        let regions = layout.scatter(io.fields, staging);
        // SAFETY: the regions run from this slot's download staging (alive as long as the
        // resources, which outlive this streamer; not written again before `finish_scatter`) into
        // the slice's bricks of the store's fields (mapped for the solve), which no other copy in
        // flight touches (module docs of `copier`).
        let ticket = unsafe { self.copier.copy(regions) };
        self.slots[s].scattering = Some((ticket, layout));
        Ok(())
    }

    /// Waits for slot `s`'s scatter, then hands the pages of its slice's bricks back (they are
    /// done with until the next pass: this keeps the resident memory to the slices in flight).
    fn finish_scatter(&mut self, io: &mut Stream, s: usize) -> Result<(), SolveError> {
        let Some((ticket, layout)) = self.slots[s].scattering.take() else { return Ok(()) };
        ticket.wait()?;
        let fields = &*io.fields;
        release_pages(io, &layout.occupied, &[&fields.source_prev, &fields.source_next, &fields.fluence]);
        Ok(())
    }

    /// Fills slot `s`'s upload staging with the slice's bricks (waits for the copies).
    fn gather(&mut self, io: &mut Stream, s: usize, layout: &SliceLayout) -> Result<(), SolveError> {
        self.start_gather(io, s, layout)?.wait()
    }

    /// Starts filling slot `s`'s upload staging with the slice's bricks on the copy workers; the
    /// ticket says when they are done. The caller has made sure that no upload still reads the
    /// staging and that no copy in flight writes the slice's bricks.
    fn start_gather(&mut self, io: &mut Stream, s: usize, layout: &SliceLayout) -> Result<Ticket, SolveError> {
        let upload = &io.res.slots[s].upload;
        if upload.size() < layout.upload_bytes() {
            return Err(SolveError::Internal("upload staging smaller than the slice"));
        }
        // The staging is written through a pointer: the copy workers write it while the
        // resources are shared. Only this slot's slice uses it, and its previous upload has
        // completed (the caller waited for it).
        let base = upload.as_mut_ptr();
        let table: &[u8] = bytemuck::cast_slice(&layout.slots);
        // SAFETY: `table.len()` bytes fit the staging (checked above: the table is its first part).
        unsafe { std::ptr::copy_nonoverlapping(table.as_ptr(), base, table.len()) };
        let regions = layout.gather(io.store, io.fields, base);
        // SAFETY: the regions run from the store (mapped for the solve) into this slot's staging,
        // which nothing else reads or writes until the upload is submitted after the ticket's
        // wait; the ticket waits as it drops, so the staging and the store outlive the copies.
        Ok(unsafe { self.copier.copy(regions) })
    }

    fn submit_upload(
        &mut self,
        res: &DeviceResources,
        s: usize,
        layout: &SliceLayout,
        v: u64,
    ) -> Result<(), SolveError> {
        let queue = self.sub.ctx.upload_queue_or_fallback();
        let slot = &res.slots[s];
        let mut rec = Recorder::begin(&self.sub.ctx, queue.family(), "upload")?;
        let mark =
            self.sub.profiler.as_mut().and_then(|p| p.begin(&mut rec, profile::Work::Upload, layout.upload_bytes()));
        let copy = |src: u64, size: u64| [vk::BufferCopy { src_offset: src, dst_offset: 0, size }];
        rec.copy_buffer(&slot.upload, &slot.slot_table, &copy(0, layout.slot_table_bytes()));
        rec.copy_buffer(&slot.upload, &slot.density, &copy(layout.density_offset(), layout.density_bytes()));
        if layout.gain {
            rec.copy_buffer(&slot.upload, &slot.source_prev, &copy(layout.prev_offset(), layout.prev_bytes()));
        }
        rec.copy_buffer(&slot.upload, &slot.source_next, &copy(layout.next_offset(), layout.source_bytes()));
        rec.copy_buffer(&slot.upload, &slot.fluence, &copy(layout.fluence_offset(), layout.fluence_bytes()));
        if let Some(p) = self.sub.profiler.as_mut() {
            p.end(&mut rec, mark);
        }
        // The slot's last download (on its own queue when the device has one) read the buffers
        // this upload overwrites: done already (the host waited for it before the gather), and
        // said here for the device.
        let t = &self.sub.timelines;
        rec.submit(
            queue,
            &[(&*t.download, self.sub.download_value, vk::PipelineStageFlags2::ALL_TRANSFER)],
            (&t.upload, v),
        )?;
        self.sub.upload_value = v;
        self.slots[s].uploaded = v;
        Ok(())
    }

    fn submit_compute(&mut self, io: &Stream, step: &ComputeStep, v: u64) -> Result<(), SolveError> {
        let queue = self.sub.ctx.compute_queue();
        let mut rec = Recorder::begin(&self.sub.ctx, queue.family(), "compute")?;
        let mark = self.sub.profiler.as_mut().and_then(|p| p.begin(&mut rec, profile::Work::Compute, 0));
        encoder::record_compute(&mut rec, io.res, io.plan, &self.memory, step)?;
        if let Some(p) = self.sub.profiler.as_mut() {
            p.end(&mut rec, mark);
        }
        let t = &self.sub.timelines;
        // Streamed: the slice's own upload; resident: the order's load.
        let ready = if step.resident_table.is_some() { self.resident_ready } else { v };
        let waits = [(&*t.upload, ready, vk::PipelineStageFlags2::COMPUTE_SHADER)];
        // A vacuum slice waits for no upload: the compute queue's own order is enough.
        rec.submit(queue, if step.slot.is_some() { &waits } else { &[] }, (&t.compute, v))?;
        self.sub.compute_value = v;
        Ok(())
    }

    /// Submits the download of the slice pending in slot `s`.
    fn submit_download(&mut self, io: &mut Stream, s: usize) -> Result<(), SolveError> {
        // The staging is free once the scatter of its previous contents is done.
        self.finish_scatter(io, s)?;
        let queue = self.sub.ctx.download_queue_or_fallback();
        let slot = &io.res.slots[s];
        let Some((v, layout)) = self.slots[s].pending.as_ref() else { return Ok(()) };
        let v = *v;
        let mut rec = Recorder::begin(&self.sub.ctx, queue.family(), "download")?;
        let next = layout.source_bytes();
        let bytes = next + layout.fluence_bytes();
        let fluence_bytes = layout.fluence_bytes();
        let mark = self.sub.profiler.as_mut().and_then(|p| p.begin(&mut rec, profile::Work::Download, bytes));
        rec.copy_buffer(
            &slot.source_next,
            &slot.download,
            &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size: next }],
        );
        rec.copy_buffer(
            &slot.fluence,
            &slot.download,
            &[vk::BufferCopy { src_offset: 0, dst_offset: next, size: fluence_bytes }],
        );
        rec.transfer_to_host();
        if let Some(p) = self.sub.profiler.as_mut() {
            p.end(&mut rec, mark);
        }
        let t = &self.sub.timelines;
        rec.submit(queue, &[(&*t.compute, v, vk::PipelineStageFlags2::TRANSFER)], (&t.download, v))?;
        self.sub.download_value = v;
        Ok(())
    }
}

/// Hands the store's pages of the `occupied` bricks back: their density and `fields` (a no-op
/// while the store keeps its pages resident).
fn release_pages(io: &Stream, occupied: &[usize], fields: &[&crate::store::Field]) {
    let mut slots = occupied.iter().filter_map(|&b| io.store.slot(b)).map(|k| k as usize).peekable();
    // Runs of consecutive slots, one release each.
    while let Some(first) = slots.next() {
        let mut count = 1;
        while slots.peek() == Some(&(first + count)) {
            slots.next();
            count += 1;
        }
        io.store.release_density(first, count);
        for field in fields {
            field.release_stored(first, count);
        }
    }
}

impl Drop for SliceStreamer {
    /// Waits for the last submission on each timeline and for the copies still running, so that
    /// nothing the device or a copy worker uses is freed under it.
    fn drop(&mut self) {
        self.sub.wait_idle();
        // The tickets wait as they drop.
        self.slots.clear();
    }
}
