//! The buffers of a solve's device resources, as plain owned structs, and the one table of
//! which buffer each sweep kernel binds where ([`sweep_bindings`]).
//!
//! They live apart from [`super::resources`], which makes them, so that the passes that only use
//! them (the transposer, the diffusion passes, the end-of-order passes, the encoder) depend on
//! this file and not on the whole resource builder: the driver's files form layers without an
//! import cycle (see the layer list in [`super`]).

use super::kernels;
use super::owned::Owned;
use super::tables::SweepTables;
use super::tally_sums::DeviceTallySums;
use crate::vk::{Buffer, BufferRange, DescriptorSet, HostBuffer};

/// Storage buffers in the descriptor set both sweep kernels share ([`kernels::SWEEP_BINDINGS`]).
pub const SWEEP_BINDING_COUNT: u32 = kernels::SWEEP_BINDINGS.len() as u32;

/// The device buffers and staging of one slice in flight.
pub struct SlotBuffers {
    pub slot_table: Owned<Buffer>,
    pub density: Owned<Buffer>,
    pub source_prev: Owned<Buffer>,
    pub source_next: Owned<Buffer>,
    pub fluence: Owned<Buffer>,
    pub upload: Owned<HostBuffer>,
    pub download: Owned<HostBuffer>,
}

/// Buffers shared by all slots: ray state and the deposit.
pub struct SharedBuffers {
    pub rays: Owned<Buffer>,
    /// What rays carried out through a side of lateral axis b, and of axis c (per ray).
    pub rays_out_b: Owned<Buffer>,
    pub rays_out_c: Owned<Buffer>,
    pub deposit: Owned<Buffer>,
    /// The staging the rays' tallies (or, with `tally_sums`, the far face's exits) come home
    /// through; also where a periodic pass's starting radiance goes up from.
    pub tallies: Owned<HostBuffer>,
    /// The device's sums of what the rays carried out ([`super::tally_sums`]); `None` on a
    /// device without f64 shaders, where the host sums the ray buffers.
    pub tally_sums: Option<DeviceTallySums>,
    /// Host-readable (`GpuToCpu`): the side exits a pass recorded for the exitance maps
    /// ([`super::face_maps`]); `None` when the solve makes none (the vacuum stand-in is bound).
    pub side_exits: Option<Owned<Buffer>>,
    /// Bound in place of the slot buffers when a vacuum slice computes (never read).
    pub vacuum: Owned<Buffer>,
}

/// The resident mode's device buffers ([`super::sizes::ResidentSizes`]): every occupied brick's fields for the
/// whole solve, and the slot table of the slice being computed.
pub struct ResidentBuffers {
    pub slot_table: Owned<Buffer>,
    pub density: Owned<Buffer>,
    pub source_prev: Owned<Buffer>,
    pub source_next: Owned<Buffer>,
    pub fluence: Owned<Buffer>,
}

/// The buffers of the passes between orders on the device ([`super::end_of_order`];
/// [`super::sizes::ResidentSizes`]): the committed totals, the sums the host reads, and what the diffusion
/// acceleration and correction use when the plan has them.
pub struct TotalBuffers {
    pub source_total: Owned<Buffer>,
    pub fluence_total: Owned<Buffer>,
    /// Host-readable (`GpuToCpu`): written by the kernels, read after a wait.
    pub block_sums: Owned<Buffer>,
    pub unit_tallies: Owned<Buffer>,
    /// Per occupied brick, its first voxel (`uvec4`; written with the first load).
    pub origins: Owned<Buffer>,
    /// The per-voxel albedo factor, when the scene has one (written with the first load).
    pub albedo: Option<Owned<Buffer>>,
    /// The diffusion correction's, when the plan corrects (`sharpen`).
    pub sharpen: Option<SharpenBuffers>,
}

/// The diffusion correction's kernel's buffers ([`super::sizes::SharpenSizes`]).
pub struct SharpenBuffers {
    pub sharpened: Owned<Buffer>,
    /// Host-readable (`GpuToCpu`): the block sums of the sharpened source.
    pub sums: Owned<Buffer>,
    pub brick_slots: Owned<Buffer>,
    pub constants: Owned<Buffer>,
}

/// The diffusion acceleration's kernels' buffers ([`super::sizes::DiffusionSizes`]).
pub struct DiffusionBuffers {
    pub unknown_of: Owned<Buffer>,
    pub cell_of_unknown: Owned<Buffer>,
    pub brick_start: Owned<Buffer>,
    pub bricks: Owned<Buffer>,
    pub solid_angles: Owned<Buffer>,
    /// Host-readable (`GpuToCpu`).
    pub moments: Owned<Buffer>,
    pub change: Owned<Buffer>,
    /// `CpuToGpu`: the change, and the tables once, go up through it.
    pub staging: Owned<HostBuffer>,
}

impl DiffusionBuffers {
    pub(super) fn every(&self) -> [&Buffer; 8] {
        [
            &self.unknown_of,
            &self.cell_of_unknown,
            &self.brick_start,
            &self.bricks,
            &self.solid_angles,
            &self.moments,
            &self.change,
            &self.staging,
        ]
    }
}

impl ResidentBuffers {
    /// The five buffers a sweep binds.
    pub(super) fn all(&self) -> [&Buffer; 5] {
        [&self.slot_table, &self.density, &self.source_prev, &self.source_next, &self.fluence]
    }
}

impl TotalBuffers {
    /// Every buffer, for the byte count.
    pub(super) fn every(&self) -> Vec<&Buffer> {
        let mut every = vec![&*self.source_total, &*self.fluence_total, &*self.block_sums, &*self.unit_tallies];
        every.push(&self.origins);
        every.extend(self.albedo.as_deref());
        every.extend(self.sharpen.iter().flat_map(|s| [&*s.sharpened, &*s.brick_slots, &*s.constants, &*s.sums]));
        every
    }
}

/// One sweep's descriptor sets of the shared layout, written once: `slots[s]` binds slot s (in the
/// resident mode `slots[0]` binds the resident buffers), and the last one the vacuum stand-in.
pub struct SweepSets {
    pub slots: Vec<Owned<DescriptorSet>>,
}

/// The buffers of a sweep's descriptor set, in [`kernels::SWEEP_BINDINGS`] order: the sweep's `tables`, a
/// slot's `[slot_table, density, source_prev, source_next, fluence]` (the vacuum stand-in five
/// times for a vacuum slice) and the shared ray state, deposit and side exits (the vacuum stand-in
/// when there are none: the kernel then writes none).
pub fn sweep_bindings<'b>(
    tables: &'b SweepTables,
    slot: [&'b Buffer; 5],
    shared: &'b SharedBuffers,
) -> [BufferRange<'b>; SWEEP_BINDING_COUNT as usize] {
    let [slot_table, density, source_prev, source_next, fluence] = slot;
    [
        BufferRange::from(&*tables.directions),
        BufferRange::from(&*tables.offsets),
        BufferRange::from(slot_table),
        BufferRange::from(density),
        BufferRange::from(source_prev),
        BufferRange::from(&*shared.rays),
        BufferRange::from(&*shared.rays_out_b),
        BufferRange::from(&*shared.rays_out_c),
        BufferRange::from(&*shared.deposit),
        BufferRange::from(&*tables.rows),
        BufferRange::from(source_next),
        BufferRange::from(fluence),
        BufferRange::from(shared.side_exits.as_deref().unwrap_or(&shared.vacuum)),
    ]
}
