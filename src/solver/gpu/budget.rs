//! The device memory plan: how the sweeps are cut so that everything the solver allocates on the
//! device (slice buffers, ray state, deposit, staging, tables) fits a byte budget.
//!
//! Four knobs, tried from the cheapest in time to the costliest:
//! - **slices in flight**: two slices' buffers and staging let the transfers of one slice overlap
//!   the compute of the other; one means each slice waits for the last (still correct);
//! - **planes per dispatch** (a sub-slice in depth): the deposit buffer holds that many planes; free;
//! - **directions per dispatch**: the deposit buffer holds that many directions; free;
//! - **directions per pass**: the ray state holds that many directions, and a face whose k²
//!   directions need several passes streams its slices once per pass.
//!
//! None of them changes the result: every voxel receives each direction's contribution as its own
//! addition, in direction order, whatever the cut (see `glsl/collect.comp`), so fluence and source
//! are bitwise identical at any budget. The slice itself (one brick deep, the whole face wide) is
//! the smallest unit: when even one direction and one plane do not fit beside it, the error says
//! how much is needed.

use crate::solver::plan::Plan;
use crate::solver::sweep::FaceSweep;
use crate::solver::SolveError;
use crate::store::{BrickStore, BRICK_EDGE, BRICK_VOXELS};
use crate::vk::Limits;
use serde::Serialize;

const BRICK_BYTES: u64 = BRICK_VOXELS as u64 * 4;

/// Fraction of the device-local heap used when no budget is given.
pub const DEFAULT_HEAP_FRACTION: f64 = 0.5;

/// The largest slice of any face: bricks in all, and occupied.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct SliceExtent {
    pub bricks: u64,
    pub occupied: u64,
    pub rays: u64,
}

#[derive(Clone, Copy, Debug, Serialize)]
pub struct MemoryPlan {
    pub budget_bytes: u64,
    pub planned_bytes: u64,
    /// 2: transfers overlap compute (pipelined); 1: one slice at a time.
    pub slices_in_flight: u32,
    pub directions_per_pass: u32,
    pub directions_per_dispatch: u32,
    pub planes_per_dispatch: u32,
    pub slice: SliceExtent,
    pub ray_state_bytes: u64,
    pub deposit_bytes: u64,
    pub slice_bytes: u64,
    pub staging_bytes: u64,
    pub table_bytes: u64,
}

/// The largest slice over the six faces.
pub fn slice_extent(plan: &Plan, store: &BrickStore) -> SliceExtent {
    let grid = *store.grid();
    let mut extent = SliceExtent { bricks: 0, occupied: 0, rays: 0 };
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

/// Chooses the cut of the sweeps for `budget` bytes.
/// `max_slots` caps the slices in flight (1 forces the serial schedule).
pub fn plan_memory(
    plan: &Plan,
    extent: SliceExtent,
    limits: &Limits,
    budget: u64,
    max_slots: u32,
) -> Result<MemoryPlan, SolveError> {
    let c = plan.channels as u64;
    let comps = plan.source_components() as u64;
    let per_face = plan.propagation.per_face() as u32;
    let max_range = limits.max_storage_buffer_range;
    let rays = extent.rays;

    // The tables live on the device for the whole solve; each set is uploaded once through a
    // staging buffer of its own size, which briefly adds the largest set again.
    let table_set = |dirs: &[crate::solver::plan::SweepDirection]| -> u64 {
        dirs.iter().map(|d| 32 + 8 * d.offsets.len() as u64 + 4 * d.collect_row.len() as u64).sum()
    };
    let sets: Vec<u64> =
        plan.faces.iter().map(|f| table_set(f)).chain(plan.beams.iter().map(|b| table_set(std::slice::from_ref(b)))).collect();
    let table_bytes = sets.iter().sum::<u64>() + sets.iter().copied().max().unwrap_or(0);
    let slot_bytes = (extent.bricks * 4).next_multiple_of(16);
    let source_bytes = extent.occupied * comps * BRICK_BYTES;
    let fluence_bytes = extent.bricks * c * BRICK_BYTES;
    let density_bytes = extent.occupied * BRICK_BYTES;
    let slice_bytes = slot_bytes + density_bytes + 2 * source_bytes + fluence_bytes;
    for (what, bytes) in [
        ("the slice's source", source_bytes),
        ("the slice's fluence", fluence_bytes),
        ("the slice's density", density_bytes),
    ] {
        if bytes > max_range {
            return Err(SolveError::DeviceLimit { what: what.to_string(), bytes, limit: max_range });
        }
    }
    let upload = slice_bytes;
    let download = source_bytes + fluence_bytes;

    let cost = |slots: u32, pass: u32, group: u32, planes: u32| -> (u64, u64, u64, u64) {
        let ray_buffer = pass as u64 * c * rays * 4;
        let ray_state = 3 * ray_buffer;
        let deposit = group as u64 * c * planes as u64 * rays * 4;
        // Per slot: the device slice buffers and their upload and download staging; plus the
        // staging the rays' tallies come home through.
        let staging = slots as u64 * (upload + download) + 2 * ray_buffer;
        let total = table_bytes + slots as u64 * slice_bytes + ray_state + deposit + staging;
        (ray_state, deposit, staging, total)
    };
    let fits_range = |pass: u32, group: u32, planes: u32| {
        pass as u64 * c * rays * 4 <= max_range && group as u64 * c * planes as u64 * rays * 4 <= max_range
    };
    for slots in [2, 1].into_iter().filter(|&s| s <= max_slots.max(1)) {
        for pass in (1..=per_face).rev() {
            for group in (1..=pass).rev() {
                for planes in [BRICK_EDGE, 8, 4, 2, 1] {
                    let (ray_state, deposit, staging, total) = cost(slots, pass, group, planes);
                    if total <= budget && fits_range(pass, group, planes) {
                        return Ok(MemoryPlan {
                            budget_bytes: budget,
                            planned_bytes: total,
                            slices_in_flight: slots,
                            directions_per_pass: pass,
                            directions_per_dispatch: group,
                            planes_per_dispatch: planes,
                            slice: extent,
                            ray_state_bytes: ray_state,
                            deposit_bytes: deposit,
                            slice_bytes: slots as u64 * slice_bytes,
                            staging_bytes: staging,
                            table_bytes,
                        });
                    }
                }
            }
        }
    }
    let (_, _, _, needed) = cost(1, 1, 1, 1);
    Err(SolveError::BudgetTooSmall { budget, needed })
}
