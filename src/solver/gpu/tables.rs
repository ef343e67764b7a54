//! Per-sweep direction tables on the device: the directions, their per-plane lattice offsets and
//! weights, and their collect rows, uploaded once per solve (they do not change between orders).

use super::layout::GpuDirection;
use super::GpuBackend;
use crate::solver::plan::SweepDirection;
use crate::solver::SolveError;
use crate::vk::{Buffer, Context, Recorder};
use ash::vk;
use gpu_allocator::MemoryLocation;

pub struct SweepTables {
    pub directions: Buffer,
    pub offsets: Buffer,
    pub rows: Buffer,
    /// The offsets again, on the host: `offsets_host[dir]` per plane (see [`SweepTables::still`]).
    offsets_host: Vec<Vec<[i32; 2]>>,
}

impl SweepTables {
    pub fn upload(backend: &mut GpuBackend, dirs: &[SweepDirection]) -> Result<SweepTables, SolveError> {
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

        let ctx = backend.ctx.clone();
        let total: u64 = parts.iter().map(|p| p.len() as u64).sum();
        let mut staging =
            ctx.create_buffer("tables staging", total, vk::BufferUsageFlags::TRANSFER_SRC, MemoryLocation::CpuToGpu)?;
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_DST;
        let mut made = Vec::new();
        let mut result = (|| -> Result<(), SolveError> {
            let mapped = staging.mapped_mut().ok_or(SolveError::Internal("tables staging is not mapped"))?;
            let mut offset = 0;
            for part in parts {
                mapped[offset..offset + part.len()].copy_from_slice(part);
                offset += part.len();
            }
            for (name, part) in ["directions", "offsets", "collect rows"].iter().zip(parts) {
                made.push(ctx.create_buffer(name, (part.len() as u64).max(4), usage, MemoryLocation::GpuOnly)?);
            }
            let mut rec = Recorder::begin(&ctx, ctx.compute_queue().family(), "tables")?;
            let mut src = 0;
            for (buffer, part) in made.iter().zip(parts) {
                let size = part.len() as u64;
                if size > 0 {
                    rec.copy_buffer(&staging, buffer, &[vk::BufferCopy { src_offset: src, dst_offset: 0, size }]);
                }
                src += size;
            }
            rec.transfer_to_compute();
            backend.submit_and_wait(rec)
        })();
        ctx.destroy_buffer(staging);
        if result.is_ok() && made.len() != 3 {
            result = Err(SolveError::Internal("table buffers"));
        }
        if let Err(e) = result {
            made.into_iter().for_each(|b| ctx.destroy_buffer(b));
            return Err(e);
        }
        let mut it = made.into_iter();
        match (it.next(), it.next(), it.next()) {
            (Some(directions), Some(offsets), Some(rows)) => {
                Ok(SweepTables { directions, offsets, rows, offsets_host })
            }
            _ => Err(SolveError::Internal("table buffers")),
        }
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

    pub fn destroy(self, ctx: &Context) {
        ctx.destroy_buffer(self.directions);
        ctx.destroy_buffer(self.offsets);
        ctx.destroy_buffer(self.rows);
    }
}
