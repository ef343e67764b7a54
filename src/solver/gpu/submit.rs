//! The submit layer, at the bottom of the driver: the three timelines and the last value submitted
//! on each, one-off submissions that wait ([`Submitter::submit_and_wait`]: setup, the tables'
//! upload, the tallies after a pass, the passes between orders), and the profile's byte counts.
//! Every part of the driver that submits outside the slice pipeline takes a `&mut Submitter`; the
//! slice streamer ([`super::streamer`]) owns the one of a solve and hands out the next values
//! of its pipeline from it.
//!
//! Dropping it waits for the last value submitted on each timeline, so nothing the device still
//! uses is freed under it.

use super::owned::Owned;
use super::profile::{self, Profiler};
use crate::solver::SolveError;
use crate::vk::{Context, Recorder, TimelineSemaphore};
use ash::vk;
use std::sync::Arc;

/// Waits that never time out: every wait here is for work already submitted.
pub const WAIT_FOREVER: u64 = u64::MAX;

/// The three timelines of the pipeline; each slice gets the next value on all three.
pub struct Timelines {
    pub upload: Owned<TimelineSemaphore>,
    pub compute: Owned<TimelineSemaphore>,
    pub download: Owned<TimelineSemaphore>,
}

pub struct Submitter {
    pub ctx: Arc<Context>,
    pub timelines: Timelines,
    /// The last value handed out on the timelines.
    pub value: u64,
    /// The last values submitted to signal the upload, compute and download timelines (vacuum
    /// slices skip the transfers; the resident mode's loads and unloads skip compute).
    pub upload_value: u64,
    pub compute_value: u64,
    pub download_value: u64,
    /// GPU timestamps of the slice pipeline's submissions (`lpm bench stream`).
    pub profiler: Option<Profiler>,
}

impl Submitter {
    /// The timelines of a solve on `ctx`, with a profiler of `profile_queries` timestamps when
    /// asked for.
    pub fn new(ctx: &Arc<Context>, profile_queries: Option<u32>) -> Result<Self, SolveError> {
        let timeline = |name: &str| -> Result<Owned<TimelineSemaphore>, SolveError> {
            Ok(Owned::new(ctx, ctx.create_timeline(name, 0)?))
        };
        let timelines =
            Timelines { upload: timeline("upload")?, compute: timeline("compute")?, download: timeline("download")? };
        let profiler = match profile_queries {
            Some(n) => Some(Profiler::new(ctx, n)?),
            None => None,
        };
        Ok(Submitter {
            ctx: Arc::clone(ctx),
            timelines,
            value: 0,
            upload_value: 0,
            compute_value: 0,
            download_value: 0,
            profiler,
        })
    }

    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }

    /// Streaming time and bytes measured so far (when profiling).
    pub fn stats(&self) -> Option<profile::StreamStats> {
        self.profiler.as_ref().map(|p| p.stats.clone())
    }

    /// Counts bytes moved outside the slice pipeline (the resident mode's field transfers, the
    /// diffusion acceleration's moments and change) in the profile's totals, when profiling:
    /// their time is inside the one-off submissions, not timestamped.
    pub fn count_transfer(&mut self, uploaded: u64, downloaded: u64) {
        if let Some(p) = self.profiler.as_mut() {
            p.stats.upload_bytes += uploaded;
            p.stats.download_bytes += downloaded;
        }
    }

    /// Submits a one-off command buffer on the compute queue and waits for it (setup, the
    /// per-pass tallies and the resident fields' reorder, not the slice pipeline). It runs after
    /// the last upload (the resident load's, when it reorders what that wrote).
    pub fn submit_and_wait(&mut self, rec: Recorder) -> Result<(), SolveError> {
        self.value += 1;
        let v = self.value;
        let t = &self.timelines;
        // The upload, compute and download timelines all advance to v, so the slice pipeline's
        // values stay one sequence.
        let after = [(&*t.upload, self.upload_value, vk::PipelineStageFlags2::ALL_COMMANDS)];
        rec.submit(self.ctx.compute_queue(), &after, (&t.compute, v))?;
        t.compute.wait(&self.ctx, v, WAIT_FOREVER)?;
        // A host signal may not pass a signal still pending on the device: a download on a queue
        // of its own may not have signalled its value yet (the compute work waited for the
        // uploads, so those are done).
        t.download.wait(&self.ctx, self.download_value, WAIT_FOREVER)?;
        t.upload.signal(&self.ctx, v)?;
        t.download.signal(&self.ctx, v)?;
        (self.upload_value, self.compute_value, self.download_value) = (v, v, v);
        self.ctx.collect_garbage()?;
        Ok(())
    }

    /// Waits for the last value submitted on each timeline.
    pub fn wait_idle(&self) {
        let t = &self.timelines;
        let last =
            [(&t.upload, self.upload_value), (&t.compute, self.compute_value), (&t.download, self.download_value)];
        for (timeline, value) in last {
            if let Err(e) = timeline.wait(&self.ctx, value, WAIT_FOREVER) {
                tracing::warn!("waiting for the last submission failed: {e}");
            }
        }
    }
}

impl Drop for Submitter {
    fn drop(&mut self) {
        self.wait_idle();
    }
}
