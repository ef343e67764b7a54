//! The device resources of a solve, built all-or-nothing: the two kernels' pipelines on one shared
//! pipeline layout, the slots' buffers and staging, the buffers shared by the slots, every sweep's
//! tables, and one descriptor set per sweep and slot that serves both kernels (written once: the
//! buffers never change), so a compute step binds its set once. In the resident mode the slots
//! are staging only and each sweep has one set for the [`ResidentBuffers`] instead; those, and
//! the [`TotalBuffers`] of the passes between orders on the device, are made here too
//! ([`resident_buffers`], [`total_buffers`]) but owned by the mode that uses them (the driver's
//! `Mode`), so no code asks whether they exist.
//!
//! Every object is an `Owned` value, so a constructor that fails half-way frees what it made by
//! dropping it, and a finished [`DeviceResources`] frees everything when dropped. Whoever submits
//! work on these resources (the `SliceStreamer`) must be dropped first: it waits for the last
//! submission. Sizes come from [`super::sizes`], the figures the budget planner adds up.

use super::budget::MemoryPlan;
use super::buffers::{
    self, DiffusionBuffers, ResidentBuffers, SharedBuffers, SharpenBuffers, SlotBuffers, SweepSets, TotalBuffers,
    SWEEP_BINDING_COUNT,
};
use super::kernels;
use super::owned::Owned;
use super::sizes::{ResidentSizes, SharedSizes, SlotSizes};
use super::submit::Submitter;
use super::tables::SweepTables;
use super::tally_sums::DeviceTallySums;
use crate::solver::plan::Plan;
use crate::solver::SolveError;
use crate::vk::{Buffer, ComputePipeline, Context, HostBuffer, MemoryLocation, PipelineLayout};
use ash::vk;
use std::sync::Arc;

pub struct DeviceResources {
    /// Per face, then per beam, parallel to the tables.
    pub face_sets: Vec<SweepSets>,
    pub beam_sets: Vec<SweepSets>,
    pub sky_sets: Vec<SweepSets>,
    pub scattered_sets: Vec<SweepSets>,
    pub propagate: Owned<ComputePipeline>,
    pub collect: Owned<ComputePipeline>,
    /// The layout both pipelines share; declared after them, so freed after them.
    pub layout: Owned<PipelineLayout>,
    pub slots: Vec<SlotBuffers>,
    pub shared: SharedBuffers,
    pub face_tables: Vec<SweepTables>,
    pub beam_tables: Vec<SweepTables>,
    /// Per face, the sky's own directions (`Plan::sky_faces`; empty unless it has them).
    pub sky_tables: Vec<SweepTables>,
    /// Per face, the scattered light's own directions (`Plan::scattered_faces`; empty unless
    /// it has them).
    pub scattered_tables: Vec<SweepTables>,
}

fn host_buffer(
    ctx: &Arc<Context>,
    name: &str,
    size: u64,
    usage: vk::BufferUsageFlags,
    location: MemoryLocation,
) -> Result<Owned<HostBuffer>, SolveError> {
    Ok(Owned::new(ctx, ctx.create_host_buffer(name, size, usage, location)?))
}

fn buffer(
    ctx: &Arc<Context>,
    name: &str,
    size: u64,
    usage: vk::BufferUsageFlags,
    location: MemoryLocation,
) -> Result<Owned<Buffer>, SolveError> {
    Ok(Owned::new(ctx, ctx.create_buffer(name, size, usage, location)?))
}

impl DeviceResources {
    /// Makes everything `memory` plans for `plan` but the resident mode's own buffers (see
    /// [`resident_buffers`], [`total_buffers`]: the mode that uses them owns them); a resident
    /// solve's sweeps bind `resident`. The tables are uploaded through `sub`.
    pub fn new(
        ctx: &Arc<Context>,
        plan: &Plan,
        memory: &MemoryPlan,
        sub: &mut Submitter,
        resident: Option<&ResidentBuffers>,
    ) -> Result<Self, SolveError> {
        let (storage, gpu) = (STORAGE, MemoryLocation::GpuOnly);
        let s = SharedSizes::new(
            plan,
            memory.slice.rays,
            memory.directions_per_pass,
            memory.directions_per_dispatch,
            memory.planes_per_dispatch,
            ctx.limits().float64,
            memory.exit_maps,
        );
        let mut shared = SharedBuffers {
            rays: buffer(ctx, "rays", s.ray_buffer, storage, gpu)?,
            rays_out_b: buffer(ctx, "rays out b", s.ray_buffer, storage, gpu)?,
            rays_out_c: buffer(ctx, "rays out c", s.ray_buffer, storage, gpu)?,
            deposit: buffer(ctx, "deposit", s.deposit, storage, gpu)?,
            tallies: host_buffer(
                ctx,
                "tally staging",
                s.tallies,
                // Also the source of the rays' starting radiance on a periodic axis.
                vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC,
                MemoryLocation::GpuToCpu,
            )?,
            tally_sums: None,
            // Written by the kernel only where a ray wraps, read by the host after the pass
            // (`face_maps`): host-visible, so nothing is copied.
            side_exits: match s.side_exits {
                0 => None,
                bytes => Some(buffer(ctx, "side exits", bytes, storage, MemoryLocation::GpuToCpu)?),
            },
            vacuum: buffer(ctx, "vacuum", s.vacuum, storage, gpu)?,
        };
        if s.tally_sums > 0 {
            let rays = [&*shared.rays, &*shared.rays_out_b, &*shared.rays_out_c];
            shared.tally_sums = Some(DeviceTallySums::new(ctx, rays, s.tally_sums)?);
        }
        let z = if memory.is_resident() {
            SlotSizes::resident(plan, &memory.slice)
        } else {
            SlotSizes::new(plan, &memory.slice, memory.planes_per_slice)
        };
        let mut slots = Vec::with_capacity(memory.slices_in_flight as usize);
        for i in 0..memory.slices_in_flight {
            let name = |what: &str| format!("slot {i} {what}");
            slots.push(SlotBuffers {
                slot_table: buffer(ctx, &name("slot table"), z.slot_table, storage, gpu)?,
                density: buffer(ctx, &name("density"), z.density, storage, gpu)?,
                source_prev: buffer(ctx, &name("source prev"), z.source_prev, storage, gpu)?,
                source_next: buffer(ctx, &name("source next"), z.source_next, storage, gpu)?,
                fluence: buffer(ctx, &name("fluence"), z.fluence, storage, gpu)?,
                upload: host_buffer(
                    ctx,
                    &name("upload staging"),
                    z.upload,
                    vk::BufferUsageFlags::TRANSFER_SRC,
                    MemoryLocation::CpuToGpu,
                )?,
                download: host_buffer(
                    ctx,
                    &name("download staging"),
                    z.download,
                    vk::BufferUsageFlags::TRANSFER_DST,
                    MemoryLocation::GpuToCpu,
                )?,
            });
        }
        // Both kernels share one layout (and so one set per slot): the table's push block.
        let push_bytes = kernels::PROPAGATE.push.size as u32;
        let layout = Owned::new(ctx, ctx.create_pipeline_layout("sweep", SWEEP_BINDING_COUNT, push_bytes)?);
        let pipeline = |k: &kernels::Kernel| -> Result<Owned<ComputePipeline>, SolveError> {
            Ok(Owned::new(ctx, ctx.create_compute_pipeline_with_layout(k.name, k.spirv, &layout)?))
        };
        let propagate = pipeline(&kernels::PROPAGATE)?;
        let collect = pipeline(&kernels::COLLECT)?;
        let face_tables =
            plan.faces.iter().map(|face| SweepTables::upload(ctx, sub, face)).collect::<Result<Vec<_>, _>>()?;
        let beam_tables = plan
            .beams
            .iter()
            .map(|beam| SweepTables::upload(ctx, sub, std::slice::from_ref(beam)))
            .collect::<Result<Vec<_>, _>>()?;
        let sky_tables =
            plan.sky_faces.iter().map(|face| SweepTables::upload(ctx, sub, face)).collect::<Result<Vec<_>, _>>()?;
        let scattered_tables = plan
            .scattered_faces
            .iter()
            .map(|face| SweepTables::upload(ctx, sub, face))
            .collect::<Result<Vec<_>, _>>()?;
        let sets = |tables: &[SweepTables], what: &str| -> Result<Vec<SweepSets>, SolveError> {
            let mut all = Vec::with_capacity(tables.len());
            for (i, t) in tables.iter().enumerate() {
                let mut sets = Vec::with_capacity(slots.len() + 1);
                if let Some(r) = resident {
                    let bindings = buffers::sweep_bindings(t, r.all(), &shared);
                    let name = format!("{what} {i} resident");
                    sets.push(Owned::new(ctx, ctx.create_descriptor_set_in(&name, &layout, &bindings)?));
                } else {
                    for (s, slot) in slots.iter().enumerate() {
                        let buffers =
                            [&slot.slot_table, &slot.density, &slot.source_prev, &slot.source_next, &slot.fluence];
                        let bindings = buffers::sweep_bindings(t, buffers.map(|b| &**b), &shared);
                        let name = format!("{what} {i} slot {s}");
                        sets.push(Owned::new(ctx, ctx.create_descriptor_set_in(&name, &layout, &bindings)?));
                    }
                }
                let v = &*shared.vacuum;
                let bindings = buffers::sweep_bindings(t, [v; 5], &shared);
                let name = format!("{what} {i} vacuum");
                sets.push(Owned::new(ctx, ctx.create_descriptor_set_in(&name, &layout, &bindings)?));
                all.push(SweepSets { slots: sets });
            }
            Ok(all)
        };
        let face_sets = sets(&face_tables, "face")?;
        let beam_sets = sets(&beam_tables, "beam")?;
        let sky_sets = sets(&sky_tables, "sky")?;
        let scattered_sets = sets(&scattered_tables, "scattered")?;
        Ok(DeviceResources {
            face_sets,
            beam_sets,
            sky_sets,
            scattered_sets,
            propagate,
            collect,
            layout,
            slots,
            shared,
            face_tables,
            beam_tables,
            sky_tables,
            scattered_tables,
        })
    }

    /// The bytes of every buffer made for the solve: those held now, plus the largest of the
    /// staging buffers the tables came through (the peak while they were uploaded). The budget
    /// planner's `planned_bytes` is this figure (tested).
    pub fn buffer_bytes(&self) -> u64 {
        let sh = &self.shared;
        let shared: [&Buffer; 6] = [&sh.rays, &sh.rays_out_b, &sh.rays_out_c, &sh.deposit, &sh.tallies, &sh.vacuum];
        let shared: u64 =
            shared.iter().map(|b| b.size()).sum::<u64>() + sh.tally_sums.as_ref().map_or(0, DeviceTallySums::bytes);
        let shared = shared + sh.side_exits.as_ref().map_or(0, |b| b.size());
        let slots: u64 = self
            .slots
            .iter()
            .flat_map(|s| -> [&Buffer; 7] {
                [&s.slot_table, &s.density, &s.source_prev, &s.source_next, &s.fluence, &s.upload, &s.download]
            })
            .map(|b| b.size())
            .sum();
        let tables =
            self.face_tables.iter().chain(&self.beam_tables).chain(&self.sky_tables).chain(&self.scattered_tables);
        let staging = tables.clone().map(|t| t.staging_bytes).max().unwrap_or(0);
        shared + slots + tables.map(SweepTables::device_bytes).sum::<u64>() + staging
    }
}

/// The storage usage of every device buffer here.
const STORAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    vk::BufferUsageFlags::STORAGE_BUFFER.as_raw()
        | vk::BufferUsageFlags::TRANSFER_DST.as_raw()
        | vk::BufferUsageFlags::TRANSFER_SRC.as_raw(),
);

/// The resident mode's buffers ([`ResidentSizes`]): every occupied brick's fields.
pub fn resident_buffers(ctx: &Arc<Context>, plan: &Plan, memory: &MemoryPlan) -> Result<ResidentBuffers, SolveError> {
    let (storage, gpu) = (STORAGE, MemoryLocation::GpuOnly);
    let r = ResidentSizes::new(plan, &memory.slice, memory.ends_on_device());
    Ok(ResidentBuffers {
        slot_table: buffer(ctx, "resident slot table", r.slot_table, storage, gpu)?,
        density: buffer(ctx, "resident density", r.density, storage, gpu)?,
        source_prev: buffer(ctx, "resident source prev", r.source_prev, storage, gpu)?,
        source_next: buffer(ctx, "resident source next", r.source_next, storage, gpu)?,
        fluence: buffer(ctx, "resident fluence", r.fluence, storage, gpu)?,
    })
}

/// The buffers of the passes between orders on the device ([`ResidentSizes`] with totals).
pub fn total_buffers(ctx: &Arc<Context>, plan: &Plan, memory: &MemoryPlan) -> Result<TotalBuffers, SolveError> {
    let (storage, gpu) = (STORAGE, MemoryLocation::GpuOnly);
    let r = ResidentSizes::new(plan, &memory.slice, true);
    let readback = MemoryLocation::GpuToCpu;
    Ok(TotalBuffers {
        source_total: buffer(ctx, "resident source total", r.source_total, storage, gpu)?,
        fluence_total: buffer(ctx, "resident fluence total", r.fluence_total, storage, gpu)?,
        block_sums: buffer(ctx, "end-of-order block sums", r.block_sums, storage, readback)?,
        unit_tallies: buffer(ctx, "end-of-order brick tallies", r.unit_tallies, storage, readback)?,
        origins: buffer(ctx, "resident brick origins", r.origins, storage, gpu)?,
        albedo: match r.albedo {
            0 => None,
            bytes => Some(buffer(ctx, "resident albedo factor", bytes, storage, gpu)?),
        },
        sharpen: match r.sharpen {
            Some(d) => Some(SharpenBuffers {
                sharpened: buffer(ctx, "resident sharpened source", d.sharpened, storage, gpu)?,
                sums: buffer(ctx, "sharpened source sums", d.sums, storage, readback)?,
                brick_slots: buffer(ctx, "resident brick slots", d.brick_slots, storage, gpu)?,
                constants: buffer(ctx, "diffusion correction constants", d.constants, storage, gpu)?,
            }),
            None => None,
        },
    })
}

/// The diffusion acceleration's buffers on the device ([`ResidentSizes`]), when the plan
/// accelerates and the passes between orders run there.
pub fn diffusion_buffers(
    ctx: &Arc<Context>,
    plan: &Plan,
    memory: &MemoryPlan,
) -> Result<Option<DiffusionBuffers>, SolveError> {
    let (storage, gpu, readback) = (STORAGE, MemoryLocation::GpuOnly, MemoryLocation::GpuToCpu);
    let r = ResidentSizes::new(plan, &memory.slice, true);
    Ok(match r.diffusion {
        Some(d) => Some(DiffusionBuffers {
            unknown_of: buffer(ctx, "diffusion unknown of cell", d.unknown_of, storage, gpu)?,
            cell_of_unknown: buffer(ctx, "diffusion cell of unknown", d.cell_of_unknown, storage, gpu)?,
            brick_start: buffer(ctx, "diffusion brick start", d.brick_start, storage, gpu)?,
            bricks: buffer(ctx, "diffusion bricks", d.bricks, storage, gpu)?,
            solid_angles: buffer(ctx, "diffusion solid angles", d.solid_angles, storage, gpu)?,
            moments: buffer(ctx, "diffusion moments", d.moments, storage, readback)?,
            change: buffer(ctx, "diffusion change", d.change, storage, gpu)?,
            staging: host_buffer(
                ctx,
                "diffusion staging",
                d.staging,
                vk::BufferUsageFlags::TRANSFER_SRC,
                MemoryLocation::CpuToGpu,
            )?,
        }),
        None => None,
    })
}
