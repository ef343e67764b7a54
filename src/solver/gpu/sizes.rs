//! The byte sizes of everything the GPU driver allocates, computed in one place: the budget
//! planner ([`super::budget`]) adds these figures up and the allocations ([`super::resources`],
//! `tables`) create buffers of exactly these sizes, so the plan cannot under-count what is
//! allocated (`tests/it/budget.rs` checks the sum against the buffers made for several plans).

use super::kernels::{self, tally_chunks};
use super::layout::GpuDirection;
use crate::solver::plan::{Plan, SweepDirection};
use crate::solver::sweep::FaceSweep;
use crate::store::{BRICK_EDGE, BRICK_VOXELS};
use serde::Serialize;

/// The largest slice of any face: bricks in all, and occupied (only occupied bricks travel); and
/// the occupied bricks of the whole volume (what the resident mode keeps on the device).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct SliceExtent {
    pub bricks: u64,
    pub occupied: u64,
    pub rays: u64,
    pub occupied_total: u64,
}

/// Bytes of one component of one brick (f32 values).
pub const BRICK_BYTES: u64 = BRICK_VOXELS as u64 * 4;

/// The stand-in bound for the slot buffers when a vacuum slice computes (never read).
pub const VACUUM_BYTES: u64 = 16;

/// Bytes of one component of one brick's slab of `planes` planes.
pub fn slab_bytes(planes: u32) -> u64 {
    BRICK_BYTES / BRICK_EDGE as u64 * planes as u64
}

/// Every buffer's size is a multiple of this. A driver rounds each buffer's memory up to its own
/// granularity (NVIDIA's H200 by 16 bytes or more, lavapipe not at all), and what it rounds
/// counts against the budget: sizes already a multiple of the largest granularity in use (256
/// bytes) are allocated exactly, so the plan's bytes are the device's on every driver.
pub const BUFFER_GRANULE: u64 = 256;

/// The size a buffer for `bytes` bytes is created with: never empty, a multiple of
/// [`BUFFER_GRANULE`].
pub fn buffer_bytes(bytes: u64) -> u64 {
    bytes.max(4).next_multiple_of(BUFFER_GRANULE)
}

/// The slot table's bytes: one i32 per brick of the slice, padded to 16 bytes (the upload staging
/// places the density right after it).
pub fn slot_table_bytes(bricks: u64) -> u64 {
    (bricks * 4).next_multiple_of(16)
}

/// The buffers of one slot: five device buffers and two staging buffers, for sub-slices of
/// `planes` planes of the largest slice.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SlotSizes {
    pub slot_table: u64,
    pub density: u64,
    /// The previous source at its storage precision.
    pub source_prev: u64,
    pub source_next: u64,
    pub fluence: u64,
    /// `[slot table][density][previous source][new source][fluence]` (see `slice.rs`).
    pub upload: u64,
    /// `[new source][fluence]`.
    pub download: u64,
}

impl SlotSizes {
    pub fn new(plan: &Plan, extent: &SliceExtent, planes: u32) -> SlotSizes {
        let per_component = extent.occupied * slab_bytes(planes);
        let source = per_component * plan.source_components() as u64;
        let prev = source / 4 * plan.source_precision.bytes();
        let fluence = per_component * plan.channels as u64;
        let table = slot_table_bytes(extent.bricks);
        SlotSizes {
            slot_table: buffer_bytes(table),
            density: buffer_bytes(per_component),
            source_prev: buffer_bytes(prev),
            source_next: buffer_bytes(source),
            fluence: buffer_bytes(fluence),
            upload: buffer_bytes(table + per_component + prev + source + fluence),
            download: buffer_bytes(source + fluence),
        }
    }

    /// A slot of the resident mode ([`ResidentSizes`]): staging only, for whole slices. The
    /// device buffers are the smallest Vulkan allows (the kernels bind the resident ones); the
    /// staging is a streamed whole slice's (a load may carry every field: the accumulators when
    /// the host seeded them).
    pub fn resident(plan: &Plan, extent: &SliceExtent) -> SlotSizes {
        let none = buffer_bytes(0);
        SlotSizes {
            slot_table: none,
            density: none,
            source_prev: none,
            source_next: none,
            fluence: none,
            ..SlotSizes::new(plan, extent, BRICK_EDGE)
        }
    }

    /// The slot's device buffers.
    pub fn device(&self) -> u64 {
        self.slot_table + self.density + self.source_prev + self.source_next + self.fluence
    }

    /// The slot's upload and download staging.
    pub fn staging(&self) -> u64 {
        self.upload + self.download
    }

    /// The buffers bound whole to a kernel (each must fit `maxStorageBufferRange`), with names
    /// for the error that says which one does not.
    pub fn bound(&self) -> [(&'static str, u64); 3] {
        [
            ("one plane of the slice's source", self.source_next),
            ("one plane of the slice's fluence", self.fluence),
            ("one plane of the slice's density", self.density),
        ]
    }
}

/// The device buffers of the resident mode: every occupied brick's density, previous source, new
/// source and fluence for the whole solve (in the store's slot order, each brick laid out as in
/// the store), and the slot table of the slice being computed (written before each step). When the
/// end-of-order passes run on the device ([`super::end_of_order`]) the committed totals live there
/// too, with the per-brick sums those passes hand the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ResidentSizes {
    pub slot_table: u64,
    pub density: u64,
    /// The previous source at its storage precision.
    pub source_prev: u64,
    pub source_next: u64,
    pub fluence: u64,
    /// The committed totals (0: they stay on the host).
    pub source_total: u64,
    pub fluence_total: u64,
    /// Per brick block, the commit's sums; per brick, the stop rule's tally (read by the host).
    pub block_sums: u64,
    pub unit_tallies: u64,
    /// Per occupied brick, its first voxel (`uvec4`), for the kernels that ask where a voxel is.
    pub origins: u64,
    /// The per-voxel albedo factor, when the scene has one (0: none).
    pub albedo: u64,
    /// The diffusion acceleration's kernels' buffers, when the plan accelerates and the passes
    /// between orders run on the device.
    pub diffusion: Option<DiffusionSizes>,
    /// The diffusion correction's, when the plan corrects.
    pub sharpen: Option<SharpenSizes>,
}

/// The buffers of the diffusion correction's kernel (`sharpen`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SharpenSizes {
    /// What the next order propagates, C(T + S) − C(T): a source's size, in f32.
    pub sharpened: u64,
    /// Per brick of the volume, its slot or `u32::MAX` (empty).
    pub brick_slots: u64,
    /// The kernel's f64 constants.
    pub constants: u64,
    /// Per block of the sharpened source, its sums (read by the host for the largest value).
    pub sums: u64,
}

/// The f64 constants of the diffusion correction's kernel ([`kernels::SharpenConstants`]).
pub const SHARPEN_CONSTANTS: u64 = (std::mem::size_of::<kernels::SharpenConstants>() / 8) as u64;

impl SharpenSizes {
    pub fn new(plan: &Plan, occupied: u64) -> SharpenSizes {
        SharpenSizes {
            sharpened: buffer_bytes(occupied * BRICK_BYTES * plan.source_components() as u64),
            brick_slots: buffer_bytes(plan.bricks_total as u64 * 4),
            constants: buffer_bytes(SHARPEN_CONSTANTS * 8),
            sums: buffer_bytes((occupied * plan.source_components() as u64).max(1) * BLOCK_SUM_BYTES),
        }
    }

    pub fn device(&self) -> u64 {
        self.sharpened + self.brick_slots + self.constants + self.sums
    }
}

/// The buffers of the diffusion acceleration's kernels (`accelerate`), sized for the most
/// unknowns the grid of the volume can have (every cell holding medium, or every occupied voxel
/// a cell of its own): the grid is built at the first commit, the buffers with the rest.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DiffusionSizes {
    /// Per cell of the grid, its unknown.
    pub unknown_of: u64,
    /// Per unknown, its cell; where its bricks start in `bricks` (one more).
    pub cell_of_unknown: u64,
    pub brick_start: u64,
    /// The bricks overlapping each unknown's cell, unknown after unknown.
    pub bricks: u64,
    /// Per storage direction, its solid angle (f64).
    pub solid_angles: u64,
    /// Per channel and unknown (f64): the moments (read by the host), the change (written by it,
    /// through the staging, which also carries the tables up).
    pub moments: u64,
    pub change: u64,
    pub staging: u64,
}

impl DiffusionSizes {
    pub fn new(plan: &Plan, occupied: u64) -> DiffusionSizes {
        let (_, cells) = crate::solver::acceleration::grid_of(plan.dims, plan.diffusion_cells);
        let cells: u64 = cells.iter().map(|&c| c as u64).product();
        let unknowns = cells.min(occupied * BRICK_VOXELS as u64);
        let per_unknown = unknowns * plan.channels as u64 * 8;
        DiffusionSizes {
            unknown_of: buffer_bytes(cells * 4),
            cell_of_unknown: buffer_bytes(unknowns * 4),
            brick_start: buffer_bytes((unknowns + 1) * 4),
            // A cell lies in one brick when cells are no larger than bricks, else a brick in one cell.
            bricks: buffer_bytes(unknowns.max(occupied) * 4),
            solid_angles: buffer_bytes(plan.storage.len() as u64 * 8),
            moments: buffer_bytes(per_unknown),
            change: buffer_bytes(per_unknown),
            // At least 1 MiB, so that the tables go up in few copies.
            staging: buffer_bytes(per_unknown.max(1 << 20)),
        }
    }

    pub fn device(&self) -> u64 {
        self.unknown_of
            + self.cell_of_unknown
            + self.brick_start
            + self.bricks
            + self.solid_angles
            + self.moments
            + self.change
            + self.staging
    }
}

/// Bytes of one block's sums and one brick's tally ([`kernels::BlockSum`], [`kernels::GpuUnitTally`]).
pub const BLOCK_SUM_BYTES: u64 = std::mem::size_of::<kernels::BlockSum>() as u64;
pub const UNIT_TALLY_BYTES: u64 = std::mem::size_of::<kernels::GpuUnitTally>() as u64;

impl ResidentSizes {
    /// With `totals`, the committed totals and the end-of-order sums are on the device too.
    pub fn new(plan: &Plan, extent: &SliceExtent, totals: bool) -> ResidentSizes {
        let per_component = extent.occupied_total * BRICK_BYTES;
        let source = per_component * plan.source_components() as u64;
        let fluence = per_component * plan.channels as u64;
        let blocks = extent.occupied_total * plan.source_components() as u64;
        let only = |bytes: u64| if totals { buffer_bytes(bytes) } else { 0 };
        ResidentSizes {
            slot_table: buffer_bytes(slot_table_bytes(extent.bricks)),
            density: buffer_bytes(per_component),
            source_prev: buffer_bytes(source / 4 * plan.source_precision.bytes()),
            source_next: buffer_bytes(source),
            fluence: buffer_bytes(fluence),
            source_total: only(source),
            fluence_total: only(fluence),
            block_sums: only(blocks.max(1) * BLOCK_SUM_BYTES),
            unit_tallies: only(extent.occupied_total.max(1) * UNIT_TALLY_BYTES),
            origins: only(extent.occupied_total * 16),
            albedo: if totals && plan.albedo_field { buffer_bytes(per_component) } else { 0 },
            diffusion: (totals && plan.acceleration).then(|| DiffusionSizes::new(plan, extent.occupied_total)),
            sharpen: (totals && plan.diffusion_correction.iter().any(|&k| k > 0.0))
                .then(|| SharpenSizes::new(plan, extent.occupied_total)),
        }
    }

    pub fn device(&self) -> u64 {
        self.slot_table
            + self.density
            + self.source_prev
            + self.source_next
            + self.fluence
            + self.source_total
            + self.fluence_total
            + self.block_sums
            + self.unit_tallies
            + self.origins
            + self.albedo
            + self.diffusion.map_or(0, |d| d.device())
            + self.sharpen.map_or(0, |d| d.device())
    }

    /// The buffers bound whole to a kernel, named for the reason the plan gives when one is larger
    /// than a binding may be (the totals are the size of the new source and the fluence).
    pub fn bound(&self) -> [(&'static str, u64); 4] {
        [
            ("the source of all occupied bricks", self.source_next),
            ("the previous source of all occupied bricks", self.source_prev),
            ("the fluence of all occupied bricks", self.fluence),
            ("the density of all occupied bricks", self.density),
        ]
    }
}

/// The buffers shared by the slots: ray state, deposit, the tallies' staging and sums, and the
/// vacuum stand-in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SharedSizes {
    /// Each of the three ray buffers (radiance, then what left through the far face; what left
    /// through a side of axis b; of axis c): `pass` directions × channels × rays.
    pub ray_buffer: u64,
    /// `group` directions × channels × `planes` planes × rays.
    pub deposit: u64,
    /// Host-visible staging for the rays after a pass: with the sums on the device, the far
    /// face's exits (what a periodic sweep axis carries) and the radiance the rays of such a
    /// pass start with; else all three ray buffers come home through it (the tallies by face).
    pub tallies: u64,
    /// Host-visible: the sums of what the rays carried out, per chunk of rays
    /// ([`super::tally_sums`]); 0 where the host sums (a device without f64 shaders).
    pub tally_sums: u64,
    /// Host-visible: where `propagate.comp` records the side exits of a pass for the exitance
    /// maps ([`super::face_maps`]), `pass` directions × channels × [`side_exit_cells`]; 0 when
    /// the solve makes no maps (the vacuum stand-in is bound in its place).
    pub side_exits: u64,
    pub vacuum: u64,
}

/// Side-exit records per direction and channel ([`super::face_maps`]): the most over the faces'
/// sweeps of planes × (lattice columns along b + along c).
pub fn side_exit_cells(plan: &Plan) -> u64 {
    (0..6)
        .map(|face| {
            let sweep = FaceSweep::for_plan(face, plan);
            let [lb, lc] = sweep.lattice();
            sweep.n[0] as u64 * (lb as u64 + lc as u64)
        })
        .max()
        .unwrap_or(0)
}

impl SharedSizes {
    /// For `pass` directions of `rays` rays, `group` directions and `planes` planes to a
    /// dispatch; `device_sums`: the rays' tallies are summed on the device; `maps`: the pass
    /// records its side exits for the exitance maps.
    pub fn new(
        plan: &Plan,
        rays: u64,
        pass: u32,
        group: u32,
        planes: u32,
        device_sums: bool,
        maps: bool,
    ) -> SharedSizes {
        let c = plan.channels as u64;
        let ray_buffer = pass as u64 * c * rays * 4;
        let segments = pass as u64 * c;
        SharedSizes {
            ray_buffer: buffer_bytes(ray_buffer),
            deposit: buffer_bytes(group as u64 * c * planes as u64 * rays * 4),
            tallies: buffer_bytes(if device_sums { ray_buffer } else { 3 * ray_buffer }),
            tally_sums: if device_sums { buffer_bytes(3 * segments * tally_chunks(rays) * 8) } else { 0 },
            side_exits: if maps { buffer_bytes(segments * side_exit_cells(plan) * 4) } else { 0 },
            vacuum: buffer_bytes(VACUUM_BYTES),
        }
    }

    /// What comes home after a pass: the tallies' staging, the sums and the side exits.
    pub fn readback(&self) -> u64 {
        self.tallies + self.tally_sums + self.side_exits
    }

    /// The three ray buffers and the vacuum stand-in.
    pub fn ray_state(&self) -> u64 {
        3 * self.ray_buffer + self.vacuum
    }
}

/// One sweep's tables (a face's directions or one beam): three device buffers and the staging
/// they are uploaded through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TableSizes {
    pub directions: u64,
    pub offsets: u64,
    pub rows: u64,
    pub staging: u64,
}

impl TableSizes {
    pub fn new(dirs: &[SweepDirection]) -> TableSizes {
        let directions = dirs.len() as u64 * std::mem::size_of::<GpuDirection>() as u64;
        // Per plane: the lattice offsets and the weights' bits (`ivec4`).
        let offsets: u64 = dirs.iter().map(|d| 16 * d.offsets.len() as u64).sum();
        let rows: u64 = dirs.iter().map(|d| 4 * d.collect_row.len() as u64).sum();
        TableSizes {
            directions: buffer_bytes(directions),
            offsets: buffer_bytes(offsets),
            rows: buffer_bytes(rows),
            staging: buffer_bytes(directions + offsets + rows),
        }
    }

    pub fn device(&self) -> u64 {
        self.directions + self.offsets + self.rows
    }
}

/// Every sweep's tables: the faces', the beams', the sky's and the scattered light's own.
pub fn all_tables(plan: &Plan) -> Vec<TableSizes> {
    plan.faces
        .iter()
        .map(|f| TableSizes::new(f))
        .chain(plan.beams.iter().map(|b| TableSizes::new(std::slice::from_ref(b))))
        .chain(plan.sky_faces.iter().map(|f| TableSizes::new(f)))
        .chain(plan.scattered_faces.iter().map(|f| TableSizes::new(f)))
        .collect()
}

/// The tables on the device for the whole solve, plus the largest staging (each set is uploaded
/// through a staging buffer of its own, freed before the next is made).
pub fn table_bytes(plan: &Plan) -> u64 {
    let sets = all_tables(plan);
    sets.iter().map(TableSizes::device).sum::<u64>() + sets.iter().map(|t| t.staging).max().unwrap_or(0)
}
