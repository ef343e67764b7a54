//! The rays' tallies summed on the device after each pass (`glsl/tally_sums.comp`).
//!
//! After a pass, the three ray buffers hold, per direction, channel and ray, what the rays carried
//! out through the far face and through the sides of the two lateral axes. The energy books need
//! only their sums per direction and channel. Bringing the buffers home to sum them cost three
//! ray buffers over the bus per pass (about 0.9 GB per order at 512³, k = 4) while the device
//! idled. Here a kernel sums each (buffer, direction·channel) segment in chunks of
//! [`TALLY_CHUNK`] rays, in f64, and only the chunk sums come home (8 bytes per 4096 rays); the
//! host adds each segment's chunks in chunk order ([`ChunkSums::segment`]). The result is the
//! same on every device and run to run; it differs from a plain sequential sum of the rays only
//! in the rounding of f64 additions (relative 1e-16 per addition).
//!
//! A periodic sweep axis still brings the far face's exits home (the next order's rays start
//! with them): one ray buffer instead of three. A device without `shaderFloat64` keeps the host's
//! sum of all three buffers (`SharedSizes::tally_sums` is then 0 and no kernel is made).

use super::kernels::{self, dispatch_linear, readback, tally_chunks, TallySumsPush, TALLY_CHUNK};
use super::owned::Owned;
use crate::solver::SolveError;
use crate::vk::{Buffer, ComputePipeline, Context, DescriptorSet, MemoryLocation, Recorder};
use ash::vk;
use std::sync::Arc;

/// The kernel, its set over the three ray buffers, and the host-readable sums it writes.
pub struct DeviceTallySums {
    set: Owned<DescriptorSet>,
    /// Declared after the set, so freed after it.
    pipeline: Owned<ComputePipeline>,
    /// `GpuToCpu`: f64 by buffer, segment and chunk, read after the pass's submission completed.
    sums: Owned<Buffer>,
}

impl DeviceTallySums {
    /// The kernel over `rays` (far, side b, side c) with a sums buffer of `bytes`
    /// (`SharedSizes::tally_sums`).
    pub fn new(ctx: &Arc<Context>, rays: [&Buffer; 3], bytes: u64) -> Result<Self, SolveError> {
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let sums = Owned::new(ctx, ctx.create_buffer("tally sums", bytes, storage, MemoryLocation::GpuToCpu)?);
        let pipeline = kernels::TALLY_SUMS.pipeline(ctx)?;
        let set = kernels::TALLY_SUMS.set(
            ctx,
            "tally sums",
            &pipeline,
            &[("Far", rays[0]), ("SideB", rays[1]), ("SideC", rays[2]), ("Sums", &sums)],
        )?;
        Ok(DeviceTallySums { set, pipeline, sums })
    }

    /// The sums buffer's bytes (for the budget's account).
    pub fn bytes(&self) -> u64 {
        self.sums.size()
    }

    /// The chunk sums a pass recorded with `layout`, after its submission completed.
    pub fn read(&self, layout: &ChunkSums) -> Result<&[f64], SolveError> {
        readback(&self.sums, layout.values())
    }

    /// Records the sums of `segments` segments of `rays` rays each, after the pass's kernels
    /// (which wrote the ray buffers) and before the host reads them.
    pub fn record(&self, rec: &mut Recorder, segments: usize, rays: usize) -> Result<ChunkSums, SolveError> {
        let chunks = tally_chunks(rays as u64);
        let too_many = || SolveError::Internal("more tally chunks than a dispatch can reach");
        let count = u32::try_from(3 * segments as u64 * chunks).map_err(|_| too_many())?;
        let (segments32, rays32, chunks32) = (
            u32::try_from(segments).map_err(|_| too_many())?,
            u32::try_from(rays).map_err(|_| too_many())?,
            u32::try_from(chunks).map_err(|_| too_many())?,
        );
        rec.compute_to_compute();
        dispatch_linear(rec, &self.pipeline, &self.set, count, |_, groups_x| TallySumsPush {
            segments: segments32,
            rays: rays32,
            chunks: chunks32,
            chunk: TALLY_CHUNK as u32,
            groups_x,
        })?;
        rec.compute_to_host();
        Ok(ChunkSums { segments, chunks: chunks as usize })
    }
}

/// How the chunk sums of one pass lie in the sums buffer: by buffer, then segment, then chunk.
#[derive(Clone, Copy, Debug)]
pub struct ChunkSums {
    segments: usize,
    chunks: usize,
}

impl ChunkSums {
    /// The values the host reads.
    pub fn values(&self) -> usize {
        3 * self.segments * self.chunks
    }

    /// The sum of `segment` of ray buffer `buffer` (0 far, 1 side b, 2 side c): its chunks added
    /// in chunk order.
    pub fn segment(&self, sums: &[f64], buffer: usize, segment: usize) -> f64 {
        let first = (buffer * self.segments + segment) * self.chunks;
        sums[first..first + self.chunks].iter().sum()
    }
}
