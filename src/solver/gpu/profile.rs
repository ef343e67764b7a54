//! Where the streaming time goes, from GPU timestamps: each upload, compute and download submission
//! is bracketed by two timestamps, and after each pass the intervals are read back and summed.
//!
//! The fraction of transfer time hidden behind compute is the length of the transfer intervals
//! that fall inside the union of the compute intervals, over the total transfer time. On a device
//! with a single queue (or a CPU implementation such as lavapipe) transfers and compute cannot run
//! at once, so that fraction is about zero there and says nothing about a GPU.

use super::owned::Owned;
use crate::vk::{Context, Recorder, TimestampQueryPool, VkError};
use ash::vk;
use serde::Serialize;
use std::sync::Arc;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Work {
    Upload,
    Compute,
    Download,
}

/// Totals over the passes profiled so far.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StreamStats {
    pub upload_seconds: f64,
    pub compute_seconds: f64,
    pub download_seconds: f64,
    pub upload_bytes: u64,
    pub download_bytes: u64,
    /// Transfer time spent while compute was running, in seconds.
    pub hidden_transfer_seconds: f64,
    /// Wall time from the first to the last timestamp of each pass, summed.
    pub device_seconds: f64,
    /// Slices gathered while the pass before ended (the first slice of a face's next pass).
    pub pregathered_slices: u64,
    /// Slices gathered on the copy workers while the slices before them computed, instead of on
    /// the submitting thread at their turn.
    pub gathered_ahead_slices: u64,
}

impl StreamStats {
    pub fn hidden_fraction(&self) -> f64 {
        let transfer = self.upload_seconds + self.download_seconds;
        if transfer > 0.0 {
            self.hidden_transfer_seconds / transfer
        } else {
            0.0
        }
    }
}

pub struct Profiler {
    pool: Owned<TimestampQueryPool>,
    period_ns: f64,
    compute_family: u32,
    transfer_timestamps: bool,
    used: u32,
    intervals: Vec<(Work, u32, u64)>,
    pub stats: StreamStats,
}

impl Profiler {
    pub fn new(ctx: &Arc<Context>, capacity: u32) -> Result<Profiler, VkError> {
        Ok(Profiler {
            pool: Owned::new(ctx, ctx.create_timestamp_pool("stream profile", capacity)?),
            period_ns: ctx.limits().timestamp_period_ns as f64,
            compute_family: ctx.compute_queue().family(),
            transfer_timestamps: ctx.limits().transfer_timestamps,
            used: 0,
            intervals: Vec::new(),
            stats: StreamStats::default(),
        })
    }

    /// Opens an interval at the start of `rec`; returns the query index to close it with, or
    /// `None` when the pool is full or `rec`'s queue family cannot write timestamps (the interval
    /// is then not measured). The queries were reset from the host when the pool was made or last
    /// read, so nothing but the timestamps goes into `rec` (a transfer queue may not reset queries).
    pub fn begin(&mut self, rec: &mut Recorder, work: Work, bytes: u64) -> Option<u32> {
        if self.used + 2 > self.pool.count() || (rec.family() != self.compute_family && !self.transfer_timestamps) {
            return None;
        }
        let i = self.used;
        self.used += 2;
        rec.write_timestamp(&self.pool, i, vk::PipelineStageFlags2::TOP_OF_PIPE);
        self.intervals.push((work, i, bytes));
        Some(i)
    }

    pub fn end(&mut self, rec: &mut Recorder, index: Option<u32>) {
        if let Some(i) = index {
            rec.write_timestamp(&self.pool, i + 1, vk::PipelineStageFlags2::BOTTOM_OF_PIPE);
        }
    }

    /// Reads the intervals recorded since the last call (every submission must have completed).
    pub fn collect(&mut self, ctx: &Context) -> Result<(), VkError> {
        if self.used == 0 {
            return Ok(());
        }
        let ticks = self.pool.read(ctx, 0, self.used)?;
        let seconds = |t: u64| t as f64 * self.period_ns * 1e-9;
        let mut compute: Vec<(u64, u64)> = Vec::new();
        let mut transfer: Vec<(u64, u64)> = Vec::new();
        let (mut first, mut last) = (u64::MAX, 0);
        for &(work, i, bytes) in &self.intervals {
            let (a, b) = (ticks[i as usize], ticks[i as usize + 1].max(ticks[i as usize]));
            first = first.min(a);
            last = last.max(b);
            let d = seconds(b - a);
            match work {
                Work::Upload => {
                    self.stats.upload_seconds += d;
                    self.stats.upload_bytes += bytes;
                    transfer.push((a, b));
                }
                Work::Download => {
                    self.stats.download_seconds += d;
                    self.stats.download_bytes += bytes;
                    transfer.push((a, b));
                }
                Work::Compute => {
                    self.stats.compute_seconds += d;
                    compute.push((a, b));
                }
            }
        }
        compute.sort_unstable();
        let hidden: u64 = transfer
            .iter()
            .map(|&(a, b)| compute.iter().map(|&(c, d)| b.min(d).saturating_sub(a.max(c))).sum::<u64>())
            .sum();
        self.stats.hidden_transfer_seconds += seconds(hidden);
        if last > first {
            self.stats.device_seconds += seconds(last - first);
        }
        // SAFETY: every submission that wrote these queries has completed (the caller's promise,
        // and the read above waited for each result).
        unsafe { self.pool.reset(ctx, 0, self.used) };
        self.used = 0;
        self.intervals.clear();
        Ok(())
    }
}
