//! The device memory plan: how the sweeps are cut so that everything the solver allocates on the
//! device (slice buffers, ray state, deposit, staging, tables) fits a byte budget.
//!
//! Five knobs; of the cuts that fit, the plan keeps the one the cost model ([`super::cost`]) says
//! makes an order quickest (ties go to the larger knobs, in the order below). What the model weighs:
//! a second slot hides the shorter of bus and kernels; another pass moves every byte over the bus
//! once more; thinner slices and smaller dispatches add submissions, dispatches and round trips of
//! the rays' state. So a bus-bound device gives up the second slot before it adds passes, and a
//! kernel-bound one adds passes before it thins slices.
//! - **slices in flight**: two slices' buffers and staging let the transfers of one slice overlap
//!   the compute of the other; one means each slice waits for the last (still correct);
//! - **directions per pass**: the ray state holds that many directions, and a face whose k²
//!   directions need several passes streams its slices once per pass (more bytes moved);
//! - **planes per slice** (sub-slices): a slice of bricks (16 planes) is streamed as sub-slices of
//!   8, 4, 2 or 1 planes, each slot holding that slab of every occupied brick; the same bytes move,
//!   in smaller pieces and with strided host copies;
//! - **directions per dispatch** and **planes per dispatch**: the deposit buffer holds that many
//!   directions and planes; smaller dispatches are more of them, and the rays' state makes a round
//!   trip through device memory per chunk of planes.
//!
//! The previous source (the one the rays gain) counts at its storage precision: half the bytes of
//! the new source when the plan stores it in f16, in the slot and in its upload staging.
//!
//! The exitance maps' side-exit records ([`super::face_maps`]) count with the staging: they grow
//! with the directions per pass like the ray state, so on a tight budget they may cost passes (or
//! thinner slices) the solve would not need without them; where no cut fits with them at all, the
//! plan drops them, not the solve ([`plan_memory_wanting`]).
//!
//! **Resident or streamed.** Before cutting anything, the planner tries the resident mode: every
//! occupied brick's density and fields stay on the device for the whole solve ([`ResidentSizes`]),
//! with whole slices and the slots reduced to their staging (through which the medium is loaded
//! once, the previous source once per order, and the order's new source and fluence come home
//! once per order; or, where the passes between orders run on the device, [`EndOfOrder`], the
//! committed totals are resident too and the fields come home only at checkpoints and at the
//! end). It is chosen when that fits the budget and every resident buffer fits one
//! storage-buffer binding; else the sweeps stream slice by slice through the slots, and the plan
//! says why ([`Residency`]).
//!
//! None of them changes the result: rays carry their radiance from plane to plane whatever the
//! cut, and every voxel receives each direction's contribution as its own addition, in direction
//! order (see `glsl/collect.comp`), so fluence and source are bitwise identical at any budget. The
//! smallest unit is a one-plane sub-slice with one direction: when even that does not fit, the
//! error says how much is needed.

use super::cost::{self, Cut, DeviceFigures};

use super::sizes::{self, ResidentSizes, SharedSizes, SliceExtent, SlotSizes};
use crate::solver::plan::Plan;
use crate::solver::sweep::FaceSweep;
use crate::solver::SolveError;
use crate::store::{BrickStore, BRICK_EDGE};
use crate::vk::Limits;
use serde::Serialize;
/// Sub-slice depths tried, in planes (each divides the brick edge).
const SLAB_PLANES: [u32; 5] = [BRICK_EDGE, 8, 4, 2, 1];

/// Fraction of the device-local heap used when no budget is given.
pub const DEFAULT_HEAP_FRACTION: f64 = 0.5;

/// Where the passes between orders run, and why.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EndOfOrder {
    /// On the device: the fields cross the bus at checkpoints and at the end only.
    Device,
    /// On the host: the sweeps stream, so the fields are on the host anyway.
    HostStreamed,
    /// On the host: the device lacks `shaderFloat64` or `shaderInt64`.
    HostNoFloat64,
}

impl EndOfOrder {
    /// For a resident solve on a device with `limits`: every pass a plan may have runs there.
    pub fn choose(limits: &Limits) -> EndOfOrder {
        if !limits.float64 {
            EndOfOrder::HostNoFloat64
        } else {
            EndOfOrder::Device
        }
    }

    /// In words, for the report's reader.
    pub fn describe(self) -> &'static str {
        match self {
            EndOfOrder::Device => {
                "on the device: the fields stay there between orders and come home at checkpoints and at the end (and for a warm start's first commit, which takes the guess back off on the host)"
            }
            EndOfOrder::HostStreamed => "on the host: the sweeps stream the fields through it",
            EndOfOrder::HostNoFloat64 => {
                "on the host, with the fields brought home every order: the device lacks shaderFloat64 or shaderInt64"
            }
        }
    }
}

/// Whether the medium and fields stay on the device for the whole solve, and why (or why not).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Residency {
    /// Resident: everything fits the budget; the bus carries a field once per order.
    Resident,
    /// Streamed because the caller asked for it (`solver.device_residency = "streamed"`, or
    /// `GpuOptions::resident`).
    StreamedOnRequest,
    /// Streamed: the resident working set is larger than the budget.
    StreamedOverBudget,
    /// Streamed: one resident field is larger than one storage-buffer binding may be.
    StreamedOverBindingLimit,
}

impl Residency {
    /// In words, for the report's reader.
    pub fn describe(self) -> &'static str {
        match self {
            Residency::Resident => {
                "resident: the medium and fields of every occupied brick stay on the device (fields cross the bus once per order at most)"
            }
            Residency::StreamedOnRequest => "streamed slice by slice, as asked",
            Residency::StreamedOverBudget => {
                "streamed slice by slice: the resident working set is larger than the device memory budget"
            }
            Residency::StreamedOverBindingLimit => {
                "streamed slice by slice: a resident field would be larger than the device's largest storage-buffer binding"
            }
        }
    }
}

#[derive(Clone, Copy, Debug, Serialize)]
pub struct MemoryPlan {
    pub budget_bytes: u64,
    pub planned_bytes: u64,
    /// 2: transfers overlap compute (pipelined); 1: one slice at a time.
    pub slices_in_flight: u32,
    pub directions_per_pass: u32,
    pub directions_per_dispatch: u32,
    /// Planes of a sub-slice (16: whole slices of bricks).
    pub planes_per_slice: u32,
    pub planes_per_dispatch: u32,
    pub slice: SliceExtent,
    /// Resident or streamed, and why (also in words, for the report's reader).
    pub residency: Residency,
    pub residency_reason: &'static str,
    /// Where the passes between orders run (commit, stop rule), and why: on the device only when
    /// resident ([`super::end_of_order`]).
    pub end_of_order: EndOfOrder,
    pub end_of_order_reason: &'static str,
    /// The cost model's seconds for one order under this cut ([`super::cost`]: orders of
    /// magnitude for the kind of device, by which the cut was chosen; not a measurement).
    pub estimated_order_seconds: f64,
    /// The resident mode's smallest working set (whether chosen or not): resident fields, tables,
    /// staging and ray state with one direction per pass.
    pub resident_bytes: u64,
    /// The resident field buffers (0 when streamed).
    pub resident_field_bytes: u64,
    /// The three ray buffers and the 16-byte stand-in bound for vacuum slices.
    pub ray_state_bytes: u64,
    pub deposit_bytes: u64,
    pub slice_bytes: u64,
    pub staging_bytes: u64,
    pub table_bytes: u64,
    /// The passes record their side exits for the exitance maps ([`super::face_maps`]; their
    /// records are counted in `staging_bytes`); false when the solve makes none or they did not
    /// fit the budget.
    pub exit_maps: bool,
}

/// The largest slice over the six faces.
pub fn slice_extent(plan: &Plan, store: &BrickStore) -> SliceExtent {
    let grid = *store.grid();
    let mut extent = SliceExtent { bricks: 0, occupied: 0, rays: 0, occupied_total: store.occupied_count() as u64 };
    for face in 0..6 {
        let sweep = FaceSweep::new(face, plan.dims);
        let f = sweep.geometry();
        let (nb, nc) = (grid.bricks[f.lateral[0]], grid.bricks[f.lateral[1]]);
        extent.bricks = extent.bricks.max(nb as u64 * nc as u64);
        extent.rays = extent.rays.max(sweep.rays() as u64);
        for ba in 0..grid.bricks[f.axis] {
            let mut occupied = 0;
            for bc in 0..nc {
                for bb in 0..nb {
                    let mut b = [0; 3];
                    b[f.axis] = ba;
                    b[f.lateral[0]] = bb;
                    b[f.lateral[1]] = bc;
                    occupied += u64::from(store.slot(grid.brick_index(b)).is_some());
                }
            }
            extent.occupied = extent.occupied.max(occupied);
        }
    }
    extent
}

/// The default budget: a safe fraction of the device-local heap.
pub fn default_budget(limits: &Limits) -> u64 {
    (limits.device_local_heap_bytes as f64 * DEFAULT_HEAP_FRACTION) as u64
}

/// Chooses resident or streamed, and the cut of the sweeps, for `budget` bytes: of the cuts that
/// fit, the quickest by the cost model with the device's `figures`. `max_slots` caps the slices in
/// flight (1 forces the serial schedule); `resident` allows the resident mode.
pub fn plan_memory(
    plan: &Plan,
    extent: SliceExtent,
    limits: &Limits,
    budget: u64,
    max_slots: u32,
    resident: bool,
    figures: &DeviceFigures,
) -> Result<MemoryPlan, SolveError> {
    plan_memory_wanting(plan, extent, limits, budget, max_slots, resident, figures, true)
}

/// [`plan_memory`], with the exitance maps' side-exit records ([`super::face_maps`]) counted
/// when `maps`. They are host-visible and grow with the directions per pass like the ray state;
/// when no cut fits the budget with them, the plan is made without them (`exit_maps` false: the
/// solve writes no maps) rather than refused, and a solve that fits no cut either way is refused
/// with the smaller need.
#[allow(clippy::too_many_arguments)]
pub fn plan_memory_wanting(
    plan: &Plan,
    extent: SliceExtent,
    limits: &Limits,
    budget: u64,
    max_slots: u32,
    resident: bool,
    figures: &DeviceFigures,
    maps: bool,
) -> Result<MemoryPlan, SolveError> {
    let cut = |maps| plan_cut(plan, extent, limits, budget, max_slots, resident, figures, maps);
    match cut(maps) {
        Err(_) if maps => cut(false),
        planned => planned,
    }
}

/// The cheapest cut that fits `budget`, the side-exit records counted when `maps`.
#[allow(clippy::too_many_arguments)]
fn plan_cut(
    plan: &Plan,
    extent: SliceExtent,
    limits: &Limits,
    budget: u64,
    max_slots: u32,
    resident: bool,
    figures: &DeviceFigures,
    maps: bool,
) -> Result<MemoryPlan, SolveError> {
    let per_face = plan.propagation.per_face() as u32;
    let max_range = limits.max_storage_buffer_range;
    let rays = extent.rays;
    // Every figure below is a buffer size from `sizes`, the ones the allocations use.
    let table_bytes = sizes::table_bytes(plan);
    let ends = EndOfOrder::choose(limits);
    let fields = ResidentSizes::new(plan, &extent, ends == EndOfOrder::Device);
    // (slot device buffers, ray state, deposit, staging, resident fields, total)
    let cost = |mode: Residency, slots: u32, pass: u32, slab: u32, group: u32, planes: u32| {
        let (slot, resident) = match mode {
            Residency::Resident => (SlotSizes::resident(plan, &extent), fields.device()),
            _ => (SlotSizes::new(plan, &extent, slab), 0),
        };
        let shared = SharedSizes::new(plan, rays, pass, group, planes, limits.float64, maps);
        // Per slot: the device slice buffers and their upload and download staging; plus the
        // staging and sums the rays' tallies come home through.
        let staging = slots as u64 * slot.staging() + shared.readback();
        let total =
            table_bytes + resident + slots as u64 * slot.device() + shared.ray_state() + shared.deposit + staging;
        (slot.device(), shared.ray_state(), shared.deposit, staging, resident, total)
    };
    let shared_fits = |pass: u32, group: u32, planes: u32| {
        let shared = SharedSizes::new(plan, rays, pass, group, planes, limits.float64, maps);
        shared.ray_buffer <= max_range && shared.deposit <= max_range && shared.side_exits <= max_range
    };
    let fits_range = |mode: Residency, pass: u32, slab: u32, group: u32, planes: u32| {
        shared_fits(pass, group, planes)
            && match mode {
                Residency::Resident => fields.bound().iter().all(|&(_, b)| b <= max_range),
                _ => SlotSizes::new(plan, &extent, slab).bound().iter().all(|&(_, b)| b <= max_range),
            }
    };
    let resident_bytes = cost(Residency::Resident, 1, 1, BRICK_EDGE, 1, 1).5;
    let streamed = if !resident {
        Residency::StreamedOnRequest
    } else if fields.bound().iter().any(|&(_, b)| b > max_range) {
        Residency::StreamedOverBindingLimit
    } else {
        Residency::StreamedOverBudget
    };
    // Resident first (whole slices only), then streamed, each with the largest knobs that fit.
    let modes: &[(Residency, &[u32])] = if resident {
        &[(Residency::Resident, &[BRICK_EDGE]), (streamed, &SLAB_PLANES)]
    } else {
        &[(streamed, &SLAB_PLANES)]
    };
    // The cheapest cut that fits, by the cost model (ties: the first in the order below, largest
    // knobs first). Of the pass and group sizes that give the same number of passes (groups),
    // only the smallest is tried: the others cost the same and take more memory.
    for &(mode, slabs) in modes {
        let mut best: Option<(f64, MemoryPlan)> = None;
        for slots in [2, 1].into_iter().filter(|&s| s <= max_slots.max(1)) {
            for pass in fewest_for_each_count(per_face) {
                for &slab in slabs {
                    for group in fewest_for_each_count(pass) {
                        for planes in SLAB_PLANES.into_iter().filter(|&p| p <= slab) {
                            let (slice_bytes, ray_state, deposit, staging, resident_field_bytes, total) =
                                cost(mode, slots, pass, slab, group, planes);
                            if total > budget || !fits_range(mode, pass, slab, group, planes) {
                                continue;
                            }
                            let cut = Cut { resident: mode == Residency::Resident, slots, pass, slab, group, planes };
                            let end_of_order =
                                if mode == Residency::Resident { ends } else { EndOfOrder::HostStreamed };
                            let seconds = cost::order_seconds(plan, extent.occupied_total, cut, figures);
                            if best.as_ref().is_some_and(|(s, _)| *s <= seconds) {
                                continue;
                            }
                            let memory = MemoryPlan {
                                budget_bytes: budget,
                                planned_bytes: total,
                                slices_in_flight: slots,
                                directions_per_pass: pass,
                                directions_per_dispatch: group,
                                planes_per_slice: slab,
                                planes_per_dispatch: planes,
                                slice: extent,
                                residency: mode,
                                residency_reason: mode.describe(),
                                end_of_order,
                                end_of_order_reason: end_of_order.describe(),
                                estimated_order_seconds: seconds,
                                resident_bytes,
                                resident_field_bytes,
                                ray_state_bytes: ray_state,
                                deposit_bytes: deposit,
                                slice_bytes: slots as u64 * slice_bytes,
                                staging_bytes: staging,
                                table_bytes,
                                exit_maps: maps,
                            };
                            best = Some((seconds, memory));
                        }
                    }
                }
            }
        }
        if let Some((_, memory)) = best {
            return Ok(memory);
        }
    }
    // Nothing fits: name the device limit when that is what stands in the way, else the budget.
    for (what, bytes) in SlotSizes::new(plan, &extent, 1).bound() {
        if bytes > max_range {
            return Err(SolveError::DeviceLimit { what: what.to_string(), bytes, limit: max_range });
        }
    }
    let mut needed = cost(streamed, 1, 1, 1, 1, 1).5;
    if resident && fits_range(Residency::Resident, 1, BRICK_EDGE, 1, 1) {
        needed = needed.min(resident_bytes);
    }
    Err(SolveError::BudgetTooSmall { budget, needed })
}

/// For each count of parts `n` can be cut into (1, 2, … n), the smallest part size giving that
/// count, largest first: `⌈n / parts⌉`, without repeats.
fn fewest_for_each_count(n: u32) -> Vec<u32> {
    let mut sizes: Vec<u32> = (1..=n.max(1)).map(|parts| n.max(1).div_ceil(parts)).collect();
    sizes.dedup();
    sizes
}

impl MemoryPlan {
    /// Whether the medium and fields stay on the device for the whole solve.
    pub fn is_resident(&self) -> bool {
        self.residency == Residency::Resident
    }

    /// Whether the passes between orders run on the device (resident, and the plan allows).
    pub fn ends_on_device(&self) -> bool {
        self.end_of_order == EndOfOrder::Device
    }
}
