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
//!    power of two chosen per order from its largest value, undone exactly by the shader), and an
//!    x sweep's slabs are transposed to lateral-major order (y fastest, so that neighbouring rays
//!    read neighbouring words: `transpose` says why);
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
//! l computes. The gather of slice l+1 starts on the copy workers as soon as slice l is submitted
//! (with one slot too: only the upload staging must be free, not the device buffers), so the
//! submitting thread does not copy bricks itself; it waits for that gather only at slice l+1's
//! turn. This costs no device memory (the slot's own staging) and so nothing the planner must
//! count. Sub-slices that share bricks with a slice still in flight are gathered at their turn. When a whole slice does not fit the budget it is streamed as sub-slices of fewer
//! planes (each slot then holds that slab of each occupied brick). Only occupied bricks travel; a
//! (sub-)slice without any is vacuum: it takes no slot and no transfer, and its compute step only
//! moves the rays across it (and is left out for directions that do not move sideways there).
//! Transfer submissions go to a dedicated transfer queue when the device has one, else to the
//! compute queue as a second submission stream ordered by the same timeline semaphores; downloads go
//! to a second transfer queue when the device has one more (a second copy engine), so that a slice
//! comes home while the next one goes up.
//! With one slot each slice completes before the next starts. Slots are reused against timeline
//! values, never by idling the device. A long order logs its progress in passes now and then
//! (`progress`).
//!
//! **Device-resident mode.** When every occupied brick's density and fields fit the budget (the
//! planner decides, [`budget::Residency`]; `solver.device_residency = "streamed"` declines), they
//! live in resident buffers for the whole solve and a pass only computes: each slice's step writes
//! its slot table (store slots of its bricks) and runs the same kernels on the resident buffers.
//! The medium is loaded once; at the start of an order the previous source is loaded and the
//! accumulators are cleared on the device; at its end the new source and fluence come home, both
//! slice by slice through the slots' staging with the gather and scatter above. So the bus carries
//! each field once per order instead of once per pass, and the result is bitwise the streamed one
//! (the kernels read the same values). Around the x sweeps the resident fields are reordered on
//! the device to the lateral-major order a streamed x sweep's slabs have (`transpose`). Where the
//! plan allows, the passes between orders (the commit and the stop rule's tally) run on the device
//! as well ([`end_of_order`], bitwise the host's), and the fields stay there from the first load to
//! the last order: the next order's previous source is made from the new one on the device, and
//! the state comes home only for a checkpoint and at the end. The diffusion acceleration
//! (`accelerate`: restriction and prolongation on the device, the solve on the host's small grid)
//! and the diffusion correction (`sharpen`) run there too, and so does a per-voxel albedo's scaling;
//! a warm start's first commit runs on the host. On a device without f64 shaders the new source
//! and fluence come home every order for the host's passes.
//!
//! ## The pieces, bottom to top
//!
//! Each layer uses only the ones below it (no file imports one that imports it back: the
//! check is `python3 ../shared/tools/import_cycles.py`, which prints the cycles of a module
//! folder).
//!
//! 1. `layout` (the sweep's plain shared types), `owned` (who frees what), [`profile`]
//!    (timestamps), `submit` (the timelines, one-off submissions that wait, the byte counts):
//!    everything that submits outside the slice pipeline takes a `&mut Submitter`;
//! 2. [`kernels`]: every kernel once (SPIR-V, shared structs, bindings, workgroup size), the one
//!    table the pipelines and descriptor sets are made from and the reflection test checks;
//! 3. [`sizes`] (what the plan allocates, the slice extent it is sized for), [`cost`] (what a
//!    cut costs), [`budget`] (which cut fits, and where the passes between orders run:
//!    `EndOfOrder`);
//! 4. `tables` (a sweep's direction tables on the device), `copier` and `slice` (gathering and
//!    scattering a slice's bricks), `tally_sums` (what the rays carried out, summed on the
//!    device), [`face_maps`] (the per-face exitance maps, placed on the host from the side exits
//!    the kernel records where they happen and the far face's), [`buffers`] (the plain buffer structs and which buffer each sweep kernel binds
//!    where);
//! 5. `transpose` (the resident fields' reorder for the x sweeps), `sharpen` and `accelerate`
//!    (the diffusion correction's and acceleration's kernels): passes over [`buffers`];
//! 6. [`resources`]: everything made on the device for a solve, all-or-nothing, from the sizes
//!    [`budget`] planned; [`encoder`]: one slice's compute step as commands (push constants,
//!    bindings, dispatches);
//! 7. [`end_of_order`] (the resident mode's passes between orders on the device) and `streamer`
//!    (the schedule of slices through the slots against the timelines);
//! 8. `mode`: streamed, resident with the passes between orders on the host, or resident with
//!    them on the device, as a type whose variants own their buffers and kernels;
//! 9. this file: the order as sweeps and passes (the [`Backend`] the order loop drives), and the
//!    tallies read back after each pass (per face of the volume: only the device's sums come
//!    home, and on a periodic sweep axis what the rays carry to the next order; with the
//!    exitance maps, the far face's exits and the side exits' records, folded into the maps).

mod accelerate;
pub mod budget;
pub mod buffers;
mod copier;
pub mod cost;
pub mod encoder;
pub mod end_of_order;
pub mod face_maps;
pub mod kernels;
pub mod layout;
mod mode;
pub(crate) mod owned;
pub mod profile;
mod progress;
pub mod resources;
mod sharpen;
pub mod sizes;
mod slice;
mod streamer;
mod submit;
mod tables;
pub mod tally_sums;
mod transpose;

use super::antidiffusion::VoxelUnits;
use super::energy::Tallies;
use super::exitance::ExitMaps;
use super::fields::{LoopState, PendingCheckpoint, StoreFields};
use super::orders::Backend;
use super::passes::{OrderFieldSet, StoreMedium};
use super::periodic::{CarryOf, PeriodStep, PeriodicCarry, RayRadiance};
use super::plan::{half_scale_exponent, Plan, Precision, SweepDirection};
use super::progress_lines::StepProgress;
use super::remaining::RemainingError;
use super::sweep::{side_births, FaceSweep};
use super::SolveError;
use crate::scene::CheckpointCadence;
use crate::store::BrickStore;
use crate::vk::{Context, Recorder};
use ash::vk;
use budget::MemoryPlan;
use layout::{FLAG_BOUNDARY, FLAG_CARRY, FLAG_EMIT, FLAG_GAIN};
use mode::{DeviceEnd, DeviceState, Ends, Mode, Resident};
use resources::DeviceResources;
use std::sync::Arc;
use std::time::Instant;
use streamer::{Pass, SliceStreamer, Stream};
use submit::Submitter;

/// How the GPU backend runs.
#[derive(Clone, Copy, Debug)]
pub struct GpuOptions {
    /// Device memory budget in bytes; `None`: a safe fraction of the device heap.
    pub budget: Option<u64>,
    /// At most this many slices in flight: 2 lets transfers overlap compute, 1 forces one slice
    /// at a time (the single-queue schedule).
    pub max_slices_in_flight: u32,
    /// Write checkpoints into the store (for `--resume`), at the scene's cadence (`solver.checkpoint_every_*`).
    pub checkpoints: bool,
    /// Bracket every submission with GPU timestamps (for `lpm bench stream`).
    pub profile: bool,
    /// Stop at the next slice when raised ([`crate::solver::cancel`]).
    pub cancel: Option<crate::solver::cancel::CancelFlag>,
    /// Allow the resident mode (the medium and fields stay on the device when they fit the
    /// budget; see [`budget::Residency`]); `false` streams every pass.
    pub resident: bool,
    /// The cost model's figures the memory planner chooses a cut with ([`cost`]); `None`: the
    /// typical ones for the kind of device. Calibrated figures (from `tools/gpu-bench.sh`) go here.
    pub cost_figures: Option<cost::DeviceFigures>,
    /// Make the per-face exitance maps ([`face_maps`]) when the budget allows them.
    pub exit_maps: bool,
}

impl Default for GpuOptions {
    fn default() -> Self {
        GpuOptions {
            budget: None,
            max_slices_in_flight: 2,
            checkpoints: false,
            profile: false,
            cancel: None,
            resident: true,
            cost_figures: None,
            exit_maps: true,
        }
    }
}

impl GpuOptions {
    /// The defaults, with the scene's device memory budget and residency.
    pub fn for_scene(scene: &crate::scene::Scene) -> Self {
        GpuOptions {
            budget: scene.solver.device_memory_budget,
            resident: scene.solver.device_residency == crate::scene::DeviceResidency::Auto,
            ..GpuOptions::default()
        }
    }
}

/// Which sweep of an order: a face's directions, one sun beam, a face's share of the sky's own
/// directions (`Plan::sky_faces`, order 0 only) or of the scattered light's
/// (`Plan::scattered_faces`, orders 1 and 2 only).
#[derive(Clone, Copy)]
enum SweepOf {
    Face(usize),
    Beam(usize),
    Sky(usize),
    Scattered(usize),
}

pub struct GpuBackend<'a> {
    /// Declared first, so dropped first: it waits for the last submission and the last copy
    /// before the resources below are freed.
    streamer: SliceStreamer,
    resources: DeviceResources,
    /// Streamed or resident, with what each owns; after the resources, whose sets bind its
    /// buffers.
    mode: Mode,
    ctx: Arc<Context>,
    plan: &'a Plan,
    store: &'a BrickStore,
    fields: &'a mut StoreFields,
    /// The store's density as the host passes walk it.
    medium: StoreMedium<'a>,
    /// The scene digest checkpoints are written under and their cadence (the order loop
    /// schedules them); `None`: no checkpoints.
    checkpoints: Option<(String, CheckpointCadence)>,
    /// The state after the last completed order when the cadence skipped its checkpoint, with
    /// the exitance maps as they were then (a cancel checkpoints it after the next order has
    /// added some of its exits to the maps).
    pending: Option<(LoopState, Option<Vec<u8>>)>,
    /// The checkpoint being written in the background while the next order's sweeps run.
    writing: Option<PendingCheckpoint>,
    memory: MemoryPlan,
    /// The f16 previous source's scale exponent for the order being propagated (`None`: f32).
    half_exponent: Option<i32>,
    /// Passes done in the order being propagated (logged now and then).
    progress: Option<StepProgress>,
    /// What the rays of periodic-axis sweeps carried out last order ([`super::periodic`]).
    carry: PeriodicCarry,
    /// The exitance maps, summed pass by pass ([`face_maps`]); `None` when not made.
    exits: Option<ExitMaps>,
}

impl<'a> GpuBackend<'a> {
    /// Prepares the device for `plan`; the solve accumulates into `fields` (in `store`). A plan
    /// with mirror faces is refused: the kernels hand nothing over at a mirror (a solve doubles
    /// the volume first, [`crate::solver::unfold`]).
    pub fn new(
        ctx: Arc<Context>,
        plan: &'a Plan,
        store: &'a BrickStore,
        fields: &'a mut StoreFields,
        options: GpuOptions,
    ) -> Result<Self, SolveError> {
        if !plan.mirrors.is_empty() {
            return Err(SolveError::MirrorsInTheDriver);
        }
        let limits = ctx.limits();
        let budget = options.budget.unwrap_or_else(|| budget::default_budget(&limits));
        if budget > limits.device_local_heap_bytes {
            return Err(SolveError::BudgetTooLarge { budget, device: limits.device_local_heap_bytes });
        }
        let memory = budget::plan_memory_wanting(
            plan,
            budget::slice_extent(plan, store),
            &limits,
            budget,
            options.max_slices_in_flight,
            options.resident,
            &options.cost_figures.unwrap_or_else(|| cost::DeviceFigures::for_device(&limits)),
            options.exit_maps,
        )?;
        if options.exit_maps && !memory.exit_maps {
            tracing::warn!("the exitance maps' records do not fit the device memory budget: no faces/ maps");
        }
        // The kill tests' hooks (tests/it/resume.rs): compiled only into builds with the
        // `test-hooks` cargo feature (tools/test.sh turns it on), never into a plain or release
        // build. Environment variables, not options: plumbing a test hook through the job API
        // would make it part of that API.
        #[cfg(feature = "test-hooks")]
        let hook = {
            let slice = |name: &str| std::env::var(name).ok().and_then(|v| v.parse().ok());
            streamer::SliceHook {
                abort_at: slice("LPM_TEST_ABORT_AT_SLICE"),
                cancel_at: slice("LPM_TEST_CANCEL_AT_SLICE"),
            }
        };
        #[cfg(not(feature = "test-hooks"))]
        let hook = streamer::SliceHook::default();
        let mut streamer = SliceStreamer::new(&ctx, plan, memory, options.profile, hook, options.cancel)?;
        let mode = Mode::new(&ctx, plan, &memory, store)?;
        let resources = DeviceResources::new(&ctx, plan, &memory, streamer.submitter(), mode.resident_buffers())?;
        tracing::info!(
            device = ctx.device_name(),
            transfer_queue = ctx.transfer_queue().is_some(),
            download_queue = ctx.download_queue().is_some(),
            budget = memory.budget_bytes,
            planned = memory.planned_bytes,
            residency = memory.residency.describe(),
            end_of_order = memory.end_of_order_reason,
            slices_in_flight = memory.slices_in_flight,
            directions_per_pass = memory.directions_per_pass,
            directions_per_dispatch = memory.directions_per_dispatch,
            planes_per_slice = memory.planes_per_slice,
            planes_per_dispatch = memory.planes_per_dispatch,
            "GPU backend ready"
        );
        let medium = StoreMedium::new(store, plan)?;
        // A resumed solve goes on with what its checkpoint's periodic sweeps carried over, and
        // adds on to the exitance maps of the orders its checkpoint holds.
        let carry = fields.resumed_carry.take().unwrap_or_else(|| PeriodicCarry::new(plan));
        let resumed_exits = fields.resumed_exits.take();
        let exits =
            memory.exit_maps.then(|| resumed_exits.unwrap_or_else(|| ExitMaps::new(plan.dims, plan.channels as usize)));
        Ok(GpuBackend {
            streamer,
            resources,
            mode,
            ctx,
            plan,
            store,
            fields,
            medium,
            checkpoints: None,
            pending: None,
            writing: None,
            memory,
            half_exponent: None,
            progress: None,
            carry,
            exits,
        })
    }

    /// Writes checkpoints into the store, after completed orders as `cadence` says.
    pub fn enable_checkpoints(&mut self, digest: String, cadence: CheckpointCadence) {
        self.checkpoints = Some((digest, cadence));
    }

    /// Streaming time and bytes measured so far (when profiling).
    pub fn stream_stats(&self) -> Option<profile::StreamStats> {
        self.streamer.stats()
    }

    /// How the sweeps were cut to fit the device memory budget.
    pub fn memory_plan(&self) -> MemoryPlan {
        self.memory
    }

    /// The bytes of every buffer the backend made (see [`DeviceResources::buffer_bytes`]): equal
    /// to the memory plan's `planned_bytes`.
    pub fn buffer_bytes(&self) -> u64 {
        self.resources.buffer_bytes() + self.mode.buffer_bytes()
    }

    /// The exitance maps of the orders swept so far ([`face_maps`]); `None` when the solve makes
    /// none (not asked for, or their records did not fit the budget).
    pub fn exit_maps(&self) -> Option<&ExitMaps> {
        self.exits.as_ref()
    }

    /// Takes the exitance maps out of the backend at the end of a solve (no copy: a 1024² face's
    /// map is tens of MB).
    pub fn take_exit_maps(&mut self) -> Option<ExitMaps> {
        self.exits.take()
    }

    /// The Vulkan context the backend runs on.
    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }

    /// One sweep of a face (or a beam): its directions in passes of at most `directions_per_pass`,
    /// each pass streaming every slice of the face in sweep order.
    fn sweep(&mut self, which: SweepOf, flags: u32) -> Result<Tallies, SolveError> {
        let plan = self.plan;
        let dirs: &[SweepDirection] = match which {
            SweepOf::Face(i) => &plan.faces[i],
            SweepOf::Beam(i) => std::slice::from_ref(&plan.beams[i]),
            SweepOf::Sky(i) => &plan.sky_faces[i],
            SweepOf::Scattered(i) => &plan.scattered_faces[i],
        };
        let sweep = FaceSweep::for_plan(dirs[0].face, plan);
        self.reorder_resident(sweep.geometry().axis == 0)?;
        let pass = self.memory.directions_per_pass as usize;
        let boundary = flags & FLAG_BOUNDARY != 0;
        let carry_of = |d: usize| match which {
            SweepOf::Face(face) => Some(CarryOf::Face { face, dir: d }),
            SweepOf::Beam(b) => Some(CarryOf::Beam(b)),
            // Own directions only in scenes without periodic or mirror faces: nothing carried.
            SweepOf::Sky(_) | SweepOf::Scattered(_) => None,
        };
        let mut tallies = Tallies::default();
        for first in (0..dirs.len()).step_by(pass) {
            let pass_dirs = first as u32..(first + pass).min(dirs.len()) as u32;
            let pass_directions = &dirs[pass_dirs.start as usize..pass_dirs.end as usize];
            // A periodic sweep axis: the rays start with what they carried out last order, put
            // where the first step copies the ray state from (the tally staging buffer).
            let mut flags = flags;
            let entries: Option<Vec<RayRadiance>> = sweep.periodic[0].then(|| {
                pass_directions
                    .iter()
                    .enumerate()
                    .map(|(i, dir)| {
                        let birth = if boundary { dir.boundary } else { [0.0; 3] };
                        carry_of(first + i).and_then(|of| self.carry.entry(plan, of, dir, birth)).unwrap_or_default()
                    })
                    .collect()
            });
            if let Some(entries) = &entries {
                write_entries(&mut self.resources, plan.channels as usize, entries);
                flags |= FLAG_CARRY;
            }
            let res = &self.resources;
            let (tables, sets) = match which {
                SweepOf::Face(i) => (&res.face_tables[i], &res.face_sets[i]),
                SweepOf::Beam(i) => (&res.beam_tables[i], &res.beam_sets[i]),
                SweepOf::Sky(i) => (&res.sky_tables[i], &res.sky_sets[i]),
                SweepOf::Scattered(i) => (&res.scattered_tables[i], &res.scattered_sets[i]),
            };
            let mut io = Stream { plan, store: self.store, fields: &mut *self.fields, res };
            let job = Pass {
                tables,
                sets,
                sweep: &sweep,
                dirs: pass_dirs.clone(),
                flags,
                half_exponent: self.half_exponent,
                another_follows: pass_dirs.end < dirs.len() as u32,
                resident: self.mode.resident_buffers(),
            };
            self.streamer.stream_pass(&mut io, &job)?;
            if let Some(p) = self.progress.as_mut() {
                p.step_done();
            }
            let births = Births { boundary, entries: entries.as_deref() };
            let maps = self.exits.as_mut();
            let (pass_tallies, exits) =
                read_tallies(self.streamer.submitter(), &self.resources, plan, &sweep, pass_directions, births, maps)?;
            tallies.add(&pass_tallies);
            for (i, (dir, exit)) in pass_directions.iter().zip(exits).enumerate() {
                if let Some(of) = carry_of(first + i) {
                    self.carry.store_exit(plan, of, dir, exit);
                }
            }
        }
        Ok(tallies)
    }
}

/// Puts the radiance the rays of a pass start with ([`super::periodic`]) into the tally staging
/// buffer, laid out as the ray buffer: [direction][channel][ray], f32 (the values came from the
/// f32 ray buffer, so the round trip is exact).
fn write_entries(res: &mut DeviceResources, channels: usize, entries: &[RayRadiance]) {
    let staging: &mut [f32] = bytemuck::cast_slice_mut(res.shared.tallies.bytes_mut());
    let mut i = 0;
    for entry in entries {
        for ch in 0..channels {
            for l in entry {
                staging[i] = l[ch] as f32;
                i += 1;
            }
        }
    }
}

/// The passes and resident buffers when the passes between orders run on the device.
/// Per occupied brick in slot order, its first voxel (`uvec4`): the resident origins table, and
/// what the acceleration's tables are built from.
fn brick_origins(medium: &StoreMedium, occupied: u64) -> Vec<[u32; 4]> {
    (0..occupied as usize)
        .map(|slot| {
            let o = medium.voxel_of(slot, 0);
            [o[0], o[1], o[2], 0]
        })
        .collect()
}

/// The start of an order after a commit on the device: the new source becomes the previous one
/// there (at the order's f16 scale, `half_exponent`), the accumulators are cleared.
fn advance_on_device(
    sub: &mut Submitter,
    end: &DeviceEnd,
    resident: &buffers::ResidentBuffers,
    half_exponent: Option<i32>,
) -> Result<(), SolveError> {
    let ctx = Arc::clone(sub.context());
    let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "next order on the device")?;
    end.passes.record_advance(&mut rec, resident, &end.totals, half_exponent)?;
    sub.submit_and_wait(rec)
}

/// What the rays of a pass were born with at plane 0: the direction's boundary radiance
/// (`boundary`; else zero) or, on a periodic sweep axis, their carried `entries`.
#[derive(Clone, Copy)]
struct Births<'e> {
    boundary: bool,
    entries: Option<&'e [RayRadiance]>,
}

/// Reads what the rays of the pass just finished carried out, as powers per face (summed on the
/// device where it has f64 shaders, [`tally_sums`]; else downloaded and summed here): the ray
/// buffer holds the radiance leaving through the far face, the two side buffers what left through
/// the sides of each lateral axis ([`FaceSweep::face_roles`]). What came in needs no download:
/// every ray is born at plane 0 (with `births`) and wherever its slot wraps, with the direction's
/// boundary radiance when `births.boundary` (else zero), so the births follow from the offsets
/// ([`side_births`]). Also returns, per direction, the radiance each slot left the far face with
/// (empty unless the sweep axis is periodic: what the next order carries in). With `maps`, adds
/// the pass's exits to them ([`face_maps`]: the far face's from the ray buffer, which then comes
/// home too, the sides' from the records the kernel wrote).
fn read_tallies(
    sub: &mut Submitter,
    res: &DeviceResources,
    plan: &Plan,
    sweep: &FaceSweep,
    dirs: &[SweepDirection],
    births_at: Births,
    maps: Option<&mut ExitMaps>,
) -> Result<(Tallies, Vec<RayRadiance>), SolveError> {
    let boundary = births_at.boundary;
    let c = plan.channels as usize;
    let rays = sweep.rays();
    let bytes = (dirs.len() * c * rays * 4) as u64;
    let shared = &res.shared;
    let ctx = Arc::clone(sub.context());
    let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "tallies")?;
    let region = |dst| [vk::BufferCopy { src_offset: 0, dst_offset: dst, size: bytes }];
    // With the sums on the device, only they come home, and the far face's exits where a
    // periodic sweep axis carries them to the next order; else all three ray buffers.
    let device_sums = match &shared.tally_sums {
        Some(kernel) => Some(kernel.record(&mut rec, dirs.len() * c, rays)?),
        None => None,
    };
    let buffers_home = match device_sums {
        Some(_) => usize::from(sweep.periodic[0] || maps.is_some()),
        None => 3,
    };
    if maps.is_some() {
        // The side exits' records are read where the kernel wrote them.
        rec.compute_to_host();
    }
    if buffers_home > 0 {
        rec.compute_to_transfer();
        for (i, b) in [&shared.rays, &shared.rays_out_b, &shared.rays_out_c].into_iter().take(buffers_home).enumerate()
        {
            rec.copy_buffer(b, &shared.tallies, &region(i as u64 * bytes));
        }
        rec.transfer_to_host();
    }
    sub.submit_and_wait(rec)?;
    let values: &[f32] = bytemuck::cast_slice(&shared.tallies.bytes()[..buffers_home * bytes as usize]);
    let per_buffer = bytes as usize / 4;
    let chunk_sums = match (&shared.tally_sums, &device_sums) {
        (Some(kernel), Some(layout)) => Some((kernel.read(layout)?, layout)),
        _ => None,
    };
    // The sum over the rays of `buffer` (0 far, 1 side b, 2 side c) for segment `d·c + ch`.
    let ray_sum = |buffer: usize, segment: usize| -> f64 {
        match &chunk_sums {
            Some((sums, layout)) => layout.segment(sums, buffer, segment),
            None => values[buffer * per_buffer..][segment * rays..(segment + 1) * rays].iter().map(|&v| v as f64).sum(),
        }
    };
    let mut tallies = Tallies::default();
    for (d, dir) in dirs.iter().enumerate() {
        let roles = sweep.face_roles(&dir.offsets);
        let period = sweep.periodic[0].then(|| PeriodStep::new(sweep, dir));
        let births = side_births(&dir.offsets, sweep.lattice(), [sweep.periodic[1], sweep.periodic[2]]);
        let power = dir.power_per_radiance;
        for ch in 0..c {
            let range = (d * c + ch) * rays..(d * c + ch + 1) * rays;
            let sum = |buffer: usize| -> f64 { ray_sum(buffer, d * c + ch) * power };
            let far = sum(0);
            tallies.boundary_out[ch] += far;
            let birth = if boundary { dir.boundary[ch] * power } else { 0.0 };
            let near = match births_at.entries {
                Some(entries) => entries[d].iter().map(|l| l[ch]).sum::<f64>() * power,
                None => birth * rays as f64,
            };
            tallies.boundary_in[ch] += near;
            match &period {
                // A periodic sweep axis: the slots that cross a side in the step between periods
                // count there ([`PeriodStep`]), the rest through the far and near faces.
                Some(step) => {
                    let lb = sweep.lattice()[0] as usize;
                    let exits = &values[range.clone()];
                    let entries = births_at.entries.map(|e| &e[d]);
                    for i in 0..rays {
                        let (p, q) = (i % lb, i / lb);
                        step.count_exit(&mut tallies.face_out, roles.far, p, q, ch, exits[i] as f64 * power);
                        let came = entries.map_or(birth, |e| e[i][ch] * power);
                        step.count_entry(&mut tallies.face_in, roles.near, p, q, ch, came);
                    }
                }
                None => {
                    tallies.face_out[roles.far][ch] += far;
                    tallies.face_in[roles.near][ch] += near;
                }
            }
            for (k, side) in roles.sides.iter().enumerate() {
                let Some((exit, entry)) = *side else { continue };
                let out = sum(1 + k);
                tallies.face_out[exit][ch] += out;
                tallies.boundary_out[ch] += out;
                tallies.face_in[entry][ch] += birth * births[k];
                tallies.boundary_in[ch] += birth * births[k];
            }
        }
    }
    if let Some(maps) = maps {
        let side_exits = shared.side_exits.as_deref().ok_or(SolveError::Internal("exitance maps without records"))?;
        let records = kernels::readback::<f32>(side_exits, dirs.len() * c * face_maps::record_stride(sweep))?;
        face_maps::add_pass(maps, sweep, dirs, c, records, &values[..per_buffer]);
    }
    let exits = if sweep.periodic[0] {
        (0..dirs.len())
            .map(|d| {
                let mut exit = vec![[0.0; 3]; rays];
                for ch in 0..c {
                    for (e, &v) in exit.iter_mut().zip(&values[(d * c + ch) * rays..][..rays]) {
                        e[ch] = v as f64;
                    }
                }
                exit
            })
            .collect()
    } else {
        Vec::new()
    };
    Ok((tallies, exits))
}

impl<'a> Backend for GpuBackend<'a> {
    fn propagate_order(&mut self, order: u32) -> Result<Tallies, SolveError> {
        let result = self.propagate(order);
        // The commit that follows may write what the checkpoint before the last one names: the
        // last one must be on disk first. (When the order itself failed, its error is the one
        // to report; a failed checkpoint is then only logged.)
        let settled = self.settle_checkpoint();
        match (&result, settled) {
            (_, Ok(())) => {}
            (Ok(_) | Err(SolveError::Cancelled { .. }), Err(e)) => return Err(e),
            (Err(_), Err(e)) => tracing::warn!("writing the last checkpoint failed: {e}"),
        }
        match result {
            // A cancelled solve keeps the checkpoint of its last completed order: the committed
            // fields and the previous source are intact (this order only wrote its own
            // accumulators), so a state the cadence skipped is checkpointed now.
            Err(e @ SolveError::Cancelled { .. }) => {
                // Unless periodic sweeps carry ray state over: the cancelled order has already
                // taken some of it, so the checkpoint before stands.
                // And unless the device committed it: its new source is gone from there (this
                // order's previous source took its place, at f16 perhaps).
                let on_host = !matches!(
                    self.mode.device_end().map(|e| e.state),
                    Some(DeviceState::Committed { home: false, .. })
                );
                if let Some((state, exits)) = self.pending.take().filter(|_| self.carry.is_empty() && on_host) {
                    self.write_checkpoint(&state, exits, false)?;
                }
                Err(e)
            }
            result => result,
        }
    }

    type Field = crate::store::Field;
    type Medium = StoreMedium<'a>;

    fn fields(&mut self) -> (&mut OrderFieldSet<crate::store::Field>, &StoreMedium<'a>) {
        (self.fields, &self.medium)
    }

    fn commit_order(&mut self, plan: &Plan) -> Result<[f64; 3], SolveError> {
        let initial_guess = self.fields.initial_guess;
        let end = match &mut self.mode {
            // Not a warm start's first commit: that takes the guess back off on the host (the
            // fields came home for it; from the next order on they stay).
            Mode::Resident(Resident { ends: Ends::OnDevice(end), .. }) if !initial_guess => end,
            _ => return self.fields.commit_order(plan, &self.medium),
        };
        let sub = self.streamer.submitter();
        // In the host's order: the albedo factor, the acceleration, then (in the commit) the
        // diffusion correction. The mode has the acceleration's kernels when the plan accelerates.
        end.passes.scale_by_albedo(sub, plan)?;
        if let Some(a) = end.acceleration.as_mut() {
            if self.fields.acceleration_due(plan, &self.medium)? {
                let grid = self.fields.acceleration.as_mut().ok_or(SolveError::Internal("no diffusion grid"))?;
                let (medium, occupied) = (&self.medium, self.memory.slice.occupied_total);
                a.kernels.fold(sub, plan, &mut a.buffers, grid, || brick_origins(medium, occupied))?;
            }
        }
        let committed = end.passes.commit(sub, plan, &end.totals)?;
        end.state = DeviceState::Committed { max_abs: committed.max_abs, home: false };
        Ok(committed.power)
    }

    fn remaining_error(&mut self, plan: &Plan, factor: [f64; 3]) -> Result<RemainingError, SolveError> {
        if let Some(end) = self.mode.device_end() {
            if let DeviceState::Committed { home: false, .. } = end.state {
                return end.passes.remaining(self.streamer.submitter(), plan, &end.totals, factor);
            }
        }
        Ok(self.fields.remaining_error(&self.medium, plan, factor))
    }

    fn carried_power(&self) -> [f64; 3] {
        self.carry.power(self.plan)
    }

    fn emission_field_power(&mut self) -> Result<Option<[f64; 3]>, SolveError> {
        if !self.plan.emission_field {
            return Ok(None);
        }
        Ok(Some(super::emission::emitted_power(self.store, self.plan)?))
    }

    fn checkpoint_cadence(&self) -> Option<CheckpointCadence> {
        self.checkpoints.as_ref().map(|(_, cadence)| *cadence)
    }

    fn checkpoint(&mut self, state: &LoopState, due: bool, last: bool) -> Result<(), SolveError> {
        // The state the device committed comes home for a checkpoint and for the passes that
        // end the solve.
        if due || last {
            self.bring_home()?;
        }
        if self.checkpoints.is_none() {
            return Ok(());
        }
        // The maps as they are now, after this order: the next one adds to them at once.
        let exits = self.exits.as_ref().map(ExitMaps::to_bytes);
        if due {
            // Written while the next order's sweeps run; the last one before the solve ends.
            self.write_checkpoint(state, exits, !last)
        } else {
            self.pending = Some((state.clone(), exits));
            Ok(())
        }
    }
}

impl Drop for GpuBackend<'_> {
    /// A solve that ends in an error may leave a checkpoint being written: it completes (a resume
    /// wants it), and a failure is logged (the solve's own error is the one reported).
    fn drop(&mut self) {
        if let Some(writing) = self.writing.take() {
            if let Err(e) = writing.finish() {
                tracing::warn!("writing the last checkpoint failed: {e}");
            }
        }
    }
}

impl GpuBackend<'_> {
    /// Writes `state` as the checkpoint now (when checkpoints are on): in the `background`
    /// ([`OrderFieldSet::start_checkpoint`]), or waiting until it is on disk.
    fn write_checkpoint(
        &mut self,
        state: &LoopState,
        exits: Option<Vec<u8>>,
        background: bool,
    ) -> Result<(), SolveError> {
        self.settle_checkpoint()?;
        let Some((digest, _)) = &self.checkpoints else { return Ok(()) };
        let writing = self.fields.start_checkpoint(self.store.dir(), digest, state, Some(&self.carry), exits)?;
        self.writing = Some(writing);
        if !background {
            self.settle_checkpoint()?;
        }
        self.pending = None;
        Ok(())
    }

    /// Waits for the checkpoint being written, if any: then the one before it may be overwritten.
    fn settle_checkpoint(&mut self) -> Result<(), SolveError> {
        if let Some(writing) = self.writing.take() {
            let t = Instant::now();
            writing.finish()?;
            self.fields.checkpoint_on_disk();
            tracing::debug!(seconds = t.elapsed().as_secs_f64(), "waited for the checkpoint being written");
        }
        Ok(())
    }

    /// One order's sweeps (see [`Backend::propagate_order`]).
    fn propagate(&mut self, order: u32) -> Result<Tallies, SolveError> {
        let plan = self.plan;
        // The device committed the last order ([`end_of_order`]): its new source is on the device
        // and becomes this order's there; nothing on the host changes.
        let committed_on_device = match self.mode.device_end().map(|e| e.state) {
            Some(DeviceState::Committed { max_abs, .. }) => Some(max_abs),
            Some(DeviceState::OnHost) | None => None,
        };
        let resident = matches!(self.mode, Mode::Resident(_));
        if committed_on_device.is_none() {
            // Resident: the load clears the device's accumulators and the unload overwrites the host's.
            self.fields.begin_order(!resident)?;
        }
        // The scale of this order's f16 source, from its largest value (exact: a power of two).
        let max_abs = || committed_on_device.unwrap_or_else(|| self.fields.source_prev.max_abs());
        self.half_exponent = (plan.source_precision == Precision::F16).then(|| half_scale_exponent(max_abs()));
        // The sky's own directions sweep in order 0 only, in passes as a face's do; the
        // scattered light's in orders 1 and 2, instead of the faces' (plan docs).
        let sky_faces = if order == 0 { plan.sky_faces.len() } else { 0 };
        let scattered = plan.sweeps_scattered_in(order);
        let faces = if scattered { &plan.scattered_faces } else { &plan.faces };
        let face_dirs: Vec<usize> = faces.iter().chain(&plan.sky_faces[..sky_faces]).map(Vec::len).collect();
        let beams: Vec<usize> = (0..plan.beams.len()).filter(|&b| plan.beam_swept_in(b, order)).collect();
        let passes = progress::passes_per_order(&face_dirs, beams.len(), self.memory.directions_per_pass);
        self.progress = Some(StepProgress::new(format!("order {order}"), "passes", passes));
        let loads = match &mut self.mode {
            Mode::Resident(Resident { ends: Ends::OnDevice(end), buffers, .. }) if committed_on_device.is_some() => {
                advance_on_device(self.streamer.submitter(), end, buffers, self.half_exponent)?;
                false
            }
            Mode::Resident(r) => {
                let mut io = Stream { plan, store: self.store, fields: &mut *self.fields, res: &self.resources };
                let seeded = io.fields.seeded;
                self.streamer.load_resident(&mut io, &r.buffers, self.half_exponent, !r.density_loaded, seeded)?;
                r.density_loaded = true;
                true
            }
            Mode::Streamed => false,
        };
        if loads && self.commits_on_device() {
            self.load_totals()?;
        }
        let mut tallies = Tallies::default();
        // Beams in order 0; those along a periodic axis again in every order, carrying what they
        // carried out (super::periodic).
        for beam in beams {
            tallies.add(&self.sweep(SweepOf::Beam(beam), if order == 0 { FLAG_BOUNDARY } else { 0 })?);
        }
        for face in 0..sky_faces {
            tallies.add(&self.sweep(SweepOf::Sky(face), FLAG_BOUNDARY)?);
        }
        let mut flags = FLAG_GAIN;
        if order == 0 {
            flags |= FLAG_BOUNDARY;
            if plan.emission {
                flags |= FLAG_EMIT;
            }
        }
        for face in 0..plan.faces.len() {
            let which = if scattered { SweepOf::Scattered(face) } else { SweepOf::Face(face) };
            tallies.add(&self.sweep(which, flags)?);
        }
        // The fields come home (and the next order's load goes in) in brick order; so do the
        // device's passes between orders read them.
        self.reorder_resident(false)?;
        let commits = self.commits_on_device();
        if let Mode::Resident(r) = &self.mode {
            if !commits {
                let mut io = Stream { plan, store: self.store, fields: &mut *self.fields, res: &self.resources };
                self.streamer.unload_resident(&mut io, &r.buffers)?;
            }
        }
        Ok(tallies)
    }

    /// Whether the order being solved is committed on the device ([`end_of_order`]): when the plan
    /// lets the device end its orders, except a warm start's first order, whose commit takes the
    /// guess back off on the host (the fields come home for it; from the next order on they stay).
    fn commits_on_device(&self) -> bool {
        self.mode.device_end().is_some() && !self.fields.initial_guess
    }

    /// Puts the committed totals on the device, with the first load of a solve (a resumed one's
    /// are not zero); they come home with the rest of the device's state ([`Self::bring_home`]).
    fn load_totals(&mut self) -> Result<(), SolveError> {
        // Streamed, or the passes between orders on the host: nothing to load.
        let Some(end) = self.mode.device_end() else { return Ok(()) };
        let totals = &end.totals;
        // The tables of where each brick is (for the kernels that look at a voxel's
        // neighbourhood), and the diffusion correction's constants.
        let ctx = Arc::clone(self.streamer.context());
        let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "resident tables")?;
        rec.compute_to_transfer();
        let origins = brick_origins(&self.medium, self.memory.slice.occupied_total);
        rec.update_buffer(&totals.origins, 0, bytemuck::cast_slice(&origins));
        if let Some(s) = &totals.sharpen {
            let slots: Vec<u32> =
                (0..self.store.grid().brick_count()).map(|b| self.store.slot(b).unwrap_or(u32::MAX)).collect();
            rec.update_buffer(&s.brick_slots, 0, bytemuck::cast_slice(&slots));
            let constants = sharpen::SharpenConstants::of(self.plan);
            rec.update_buffer(&s.constants, 0, bytemuck::bytes_of(&constants));
        }
        rec.transfer_to_compute();
        self.streamer.submitter().submit_and_wait(rec)?;
        let fields = &*self.fields;
        let albedo = self.medium.albedo_field().zip(totals.albedo.as_deref());
        for (field, buffer) in
            [(&fields.source_total, &*totals.source_total), (&fields.fluence_total, &*totals.fluence_total)]
                .into_iter()
                .chain(albedo)
        {
            end_of_order::upload_field(self.streamer.submitter(), &self.resources, field, buffer)?;
        }
        Ok(())
    }

    /// Brings the state the device committed home, for a checkpoint or the end of the solve: the
    /// totals, the last new source and the last order's fluence take the roles the host's own
    /// commit would have given them ([`OrderFieldSet::take_device_commit`]).
    fn bring_home(&mut self) -> Result<(), SolveError> {
        // Streamed, or the passes between orders on the host: the fields are home already.
        let Some(DeviceState::Committed { max_abs, home: false }) = self.mode.device_end().map(|e| e.state) else {
            return Ok(());
        };
        // The checkpoint in flight names fields the roles below move: it must be on disk first.
        self.settle_checkpoint()?;
        let Mode::Resident(Resident { ends: Ends::OnDevice(end), buffers: resident, .. }) = &mut self.mode else {
            return Ok(());
        };
        let totals = &end.totals;
        let sub = self.streamer.submitter();
        let res = &self.resources;
        self.fields.take_device_commit(|source_total, fluence_total, source_next, fluence| {
            use end_of_order::download_field as to_host;
            to_host(sub, res, source_total, &totals.source_total)?;
            to_host(sub, res, fluence_total, &totals.fluence_total)?;
            // What the next order propagates (the sharpened source with the diffusion correction).
            to_host(sub, res, source_next, end_of_order::propagated(resident, totals))?;
            to_host(sub, res, fluence, &resident.fluence)
        })?;
        end.state = DeviceState::Committed { max_abs, home: true };
        Ok(())
    }

    /// The resident mode: puts the resident fields in the order the next sweep reads them,
    /// lateral-major for an x sweep (`lateral`), else brick order ([`transpose`]). Nothing to do
    /// when they are in it already, or when streamed (the copy workers order each slab).
    fn reorder_resident(&mut self, lateral: bool) -> Result<(), SolveError> {
        let Mode::Resident(r) = &mut self.mode else { return Ok(()) };
        if r.lateral == lateral {
            return Ok(());
        }
        let ctx = Arc::clone(self.streamer.context());
        let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "reorder resident fields")?;
        r.transposer.record(&mut rec, lateral)?;
        self.streamer.submitter().submit_and_wait(rec)?;
        r.lateral = lateral;
        Ok(())
    }
}
