//! Per-sweep direction tables on the device: the directions, their per-plane lattice offsets and
//! weights, and their collect rows, uploaded once per solve (they do not change between orders).

use super::layout::GpuDirection;
use super::owned::Owned;
use super::sizes::TableSizes;
use super::submit::Submitter;
use crate::solver::plan::SweepDirection;
use crate::solver::SolveError;
use crate::vk::{Buffer, Context, MemoryLocation, Recorder};
use ash::vk;
use std::sync::Arc;

pub struct SweepTables {
    pub directions: Owned<Buffer>,
    pub offsets: Owned<Buffer>,
    pub rows: Owned<Buffer>,
    /// The offsets again, on the host: `offsets_host[dir]` per plane (see [`SweepTables::still`]).
    offsets_host: Vec<Vec<[i32; 2]>>,
    /// The size of the staging buffer the tables came through (freed once they were uploaded).
    pub staging_bytes: u64,
}

impl SweepTables {
    /// Uploads the tables of `dirs` (waits for the copy).
    pub fn upload(ctx: &Arc<Context>, sub: &mut Submitter, dirs: &[SweepDirection]) -> Result<SweepTables, SolveError> {
        let sizes = TableSizes::new(dirs);
        let gpu_dirs: Vec<GpuDirection> = dirs
            .iter()
            .map(|d| GpuDirection {
                boundary: [d.boundary[0] as f32, d.boundary[1] as f32, d.boundary[2] as f32, 0.0],
                path_length: d.path_length as f32,
                fluence_weight: d.fluence_weight as f32,
                gain_storage: d.gain_storage,
                pad: 0,
            })
            .collect();
        // Per plane: the lattice offsets and the weights' f32 bits (`ivec4` in the shaders).
        let offsets: Vec<[i32; 4]> = dirs
            .iter()
            .flat_map(|d| {
                d.offsets
                    .iter()
                    .zip(&d.weights)
                    .map(|(o, w)| [o[0], o[1], (w[0] as f32).to_bits() as i32, (w[1] as f32).to_bits() as i32])
            })
            .collect();
        let offsets_host = dirs.iter().map(|d| d.offsets.clone()).collect();
        let rows: Vec<f32> = dirs.iter().flat_map(|d| d.collect_row.iter().map(|&v| v as f32)).collect();
        let parts: [&[u8]; 3] =
            [bytemuck::cast_slice(&gpu_dirs), bytemuck::cast_slice(&offsets), bytemuck::cast_slice(&rows)];

        let usage = vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_DST;
        let buffer = |name: &str, size: u64| -> Result<Owned<Buffer>, SolveError> {
            Ok(Owned::new(ctx, ctx.create_buffer(name, size, usage, MemoryLocation::GpuOnly)?))
        };
        let tables = SweepTables {
            directions: buffer("directions", sizes.directions)?,
            offsets: buffer("offsets", sizes.offsets)?,
            rows: buffer("collect rows", sizes.rows)?,
            offsets_host,
            staging_bytes: sizes.staging,
        };
        // Dropped (freed) at the end of this function, after the copy was waited for.
        let mut staging = Owned::new(
            ctx,
            ctx.create_host_buffer(
                "tables staging",
                sizes.staging,
                vk::BufferUsageFlags::TRANSFER_SRC,
                MemoryLocation::CpuToGpu,
            )?,
        );
        let mapped = staging.bytes_mut();
        let mut offset = 0;
        for part in parts {
            mapped[offset..offset + part.len()].copy_from_slice(part);
            offset += part.len();
        }
        let mut rec = Recorder::begin(ctx, ctx.compute_queue().family(), "tables")?;
        let mut src = 0;
        for (buffer, part) in [&tables.directions, &tables.offsets, &tables.rows].into_iter().zip(parts) {
            let size = part.len() as u64;
            if size > 0 {
                rec.copy_buffer(&staging, buffer, &[vk::BufferCopy { src_offset: src, dst_offset: 0, size }]);
            }
            src += size;
        }
        rec.transfer_to_compute();
        sub.submit_and_wait(rec)?;
        Ok(tables)
    }

    /// The bytes of the three device buffers.
    pub fn device_bytes(&self) -> u64 {
        self.directions.size() + self.offsets.size() + self.rows.size()
    }

    /// True when none of the directions `dirs` moves laterally from plane `t0 − 1` to plane
    /// `t1 − 1` (`t0 > 0`): across a vacuum stretch no ray of theirs wraps, so nothing about them
    /// changes there and the dispatch can be left out (an axis-aligned direction never moves).
    pub fn still(&self, dirs: std::ops::Range<u32>, t0: u32, t1: u32) -> bool {
        t0 > 0
            && t1 > t0
            && dirs.into_iter().all(|d| {
                let o = &self.offsets_host[d as usize];
                matches!((o.get(t0 as usize - 1), o.get(t1 as usize - 1)), (Some(a), Some(b)) if a == b)
            })
    }
}
