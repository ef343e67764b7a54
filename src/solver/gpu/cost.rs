//! The memory planner's cost model: about how long one order takes under a cut of the sweeps, so
//! that of the cuts that fit the budget the planner keeps the cheapest ([`super::budget`]).
//!
//! What a cut changes, and what the model counts for it:
//! - **bytes over the bus**: a streamed pass moves every occupied brick's slab of density and
//!   previous source up, and its new source and fluence up and down; a face in P passes moves it
//!   all P times. The resident mode moves the previous source up and the accumulators home once an
//!   order (nothing, where the passes between orders run on the device: the model keeps the
//!   upper bound, which decides nothing, since a resident cut is taken whenever one fits).
//! - **bytes the kernels move on the device**: per voxel and direction, the gathers of medium and
//!   source, the deposit written once and pulled four times, and the accumulators read and written
//!   once per dispatch of directions (fewer directions per dispatch: more of those); per ray, its
//!   state read and written once per dispatch of planes (fewer planes per dispatch: more of those).
//!   The deposit is the largest share (20 bytes a channel of every voxel and direction): when one
//!   dispatch's deposit fits half the device's last-level cache, `propagate.comp` writes it and
//!   `collect.comp` reads it back there, at the cache's speed. This is how the two kernels' round
//!   trip stays on the chip without fusing them: a fused kernel would have one workgroup own both
//!   the rays and the voxels they deposit into, but a direction's rays shift sideways plane by
//!   plane, so the voxels a workgroup's rays reach are not the ones it could collect in direction
//!   order (every voxel sums its directions in one fixed order, for bitwise results).
//! - **submissions and dispatches**: three submissions per (sub-)slice (upload, compute, download:
//!   one when resident) and two dispatches per group of directions and chunk of planes; thin
//!   sub-slices multiply both.
//!
//! With two slots the bus and the kernels overlap, and the longer of the two counts; with one they
//! add. The figures are orders of magnitude for the kind of device (a discrete GPU's PCIe bus and
//! memory, or a CPU device such as lavapipe, where both are the host's memory), not measurements:
//! what decides a cut is their ratios, which says whether halving the directions of a pass (twice
//! the bytes over the bus) costs more than thinner sub-slices (more submissions and ray-state
//! round trips). `tools/gpu-bench.sh`'s figures (upload and download bytes per second, kernel time
//! per order) are what to calibrate them with when a GPU is at hand.

use crate::solver::plan::Plan;
use crate::store::BRICK_EDGE;
use crate::vk::Limits;

use super::sizes::BRICK_BYTES;

/// Throughputs and overheads of the kind of device.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeviceFigures {
    /// Host ↔ device copies, bytes per second.
    pub bus_bytes_per_second: f64,
    /// What the kernels read and write in device memory, bytes per second.
    pub device_bytes_per_second: f64,
    /// One queue submission (recording, submit, timeline), seconds.
    pub submission_seconds: f64,
    /// One dispatch, seconds.
    pub dispatch_seconds: f64,
    /// The last-level cache on the device, bytes (0: not modelled), and what the kernels read
    /// and write there per second.
    pub cache_bytes: f64,
    pub cache_bytes_per_second: f64,
}

impl DeviceFigures {
    /// Typical figures for the kind of device `limits` describe.
    pub fn for_device(limits: &Limits) -> Self {
        if limits.is_cpu {
            // Both "bus" and "device memory" are the host's memory; the kernels run on its cores.
            // (There the copies and the kernels share the cores rather than overlap, but it is
            // planned as a GPU is, so that it runs the schedule a GPU runs.)
            DeviceFigures {
                bus_bytes_per_second: 4e9,
                device_bytes_per_second: 2e9,
                submission_seconds: 50e-6,
                dispatch_seconds: 20e-6,
                // llvmpipe's kernels are bound by their arithmetic, not by where the deposit is.
                cache_bytes: 0.0,
                cache_bytes_per_second: 2e9,
            }
        } else {
            // PCIe 4 ×16 with pinned staging; HBM or GDDR of a current card, conservatively.
            DeviceFigures {
                bus_bytes_per_second: 12e9,
                device_bytes_per_second: 1e12,
                submission_seconds: 20e-6,
                dispatch_seconds: 4e-6,
                // L2: 40–50 MB on data-centre cards (A100, H100), less on older ones.
                cache_bytes: 24e6,
                cache_bytes_per_second: 3e12,
            }
        }
    }
}

/// A cut of the sweeps, as the planner tries them.
#[derive(Clone, Copy, Debug)]
pub struct Cut {
    pub resident: bool,
    pub slots: u32,
    pub pass: u32,
    pub slab: u32,
    pub group: u32,
    pub planes: u32,
}

/// The model's seconds for one order of `plan` under `cut`, with `occupied` bricks in the volume.
pub fn order_seconds(plan: &Plan, occupied: u64, cut: Cut, figures: &DeviceFigures) -> f64 {
    let c = plan.channels as f64;
    let comps = plan.source_components() as f64;
    let prev = comps * plan.source_precision.bytes() as f64 / 4.0;
    let per_face = plan.propagation.per_face().max(1) as f64;
    let passes = (per_face / cut.pass as f64).ceil();
    let brick = BRICK_BYTES as f64 * occupied as f64;
    let bus_bytes = if cut.resident {
        brick * (prev + comps + c)
    } else {
        // Six faces, each pass: density, previous source and the accumulators up; the
        // accumulators down.
        6.0 * passes * brick * ((1.0 + prev + comps + c) + (comps + c))
    };
    // Per voxel and direction: four gathers of density and source, and the accumulators once per
    // dispatch group, in device memory; the deposit written once and pulled four times, in the
    // cache when a dispatch's deposit fits half of it (the round trip between the two kernels then
    // never leaves the chip), else in device memory too.
    let source_value = plan.source_precision.bytes() as f64;
    let fixed = 4.0 * (4.0 + c * source_value) + 8.0 * (c + comps) / cut.group as f64;
    let deposit_traffic = 20.0 * c;
    let voxel_directions_per_axis = occupied as f64 * (BRICK_BYTES / 4) as f64 * 2.0 * per_face;
    let (mut device_bytes, mut cache_bytes) = (0.0, 0.0);
    let (mut submissions, mut dispatches) = (0.0, 0.0);
    for axis in 0..3 {
        let [a, b, cc] = [axis, (axis + 1) % 3, (axis + 2) % 3].map(|k| plan.dims[k] as f64);
        let slices = (a / BRICK_EDGE as f64).ceil() * (BRICK_EDGE / cut.slab) as f64;
        // Two faces per axis, each in `passes` passes of every (sub-)slice.
        let steps = 2.0 * passes * slices;
        submissions += steps * if cut.resident { 1.0 } else { 3.0 };
        let groups = (cut.pass as f64 / cut.group as f64).ceil();
        let chunks = (cut.slab as f64 / cut.planes as f64).ceil();
        dispatches += steps * groups * chunks * 2.0;
        let rays = (b + 1.0) * (cc + 1.0);
        device_bytes += voxel_directions_per_axis * fixed;
        let deposit = cut.group as f64 * c * cut.planes as f64 * rays * 4.0;
        if deposit <= figures.cache_bytes / 2.0 {
            cache_bytes += voxel_directions_per_axis * deposit_traffic;
        } else {
            device_bytes += voxel_directions_per_axis * deposit_traffic;
        }
        // Every ray's state read and written once per chunk of planes, for each direction.
        device_bytes += 2.0 * per_face * rays * c * 8.0 * slices * chunks;
    }
    let bus = bus_bytes / figures.bus_bytes_per_second;
    let kernels = device_bytes / figures.device_bytes_per_second + cache_bytes / figures.cache_bytes_per_second;
    let moving = if cut.slots >= 2 && !cut.resident { bus.max(kernels) } else { bus + kernels };
    moving + submissions * figures.submission_seconds + dispatches * figures.dispatch_seconds
}
