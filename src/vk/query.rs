//! GPU timestamp queries, for benchmarks.

use ash::vk;

use super::context::Context;
use super::error::{VkError, VkResultExt};

/// A pool of timestamp queries, reset from the host (`hostQueryReset`): when created, and with
/// [`TimestampQueryPool::reset`] after each read. Write with [`super::Recorder::write_timestamp`],
/// read after the submission completed. Resets are never recorded into command buffers:
/// `vkCmdResetQueryPool` is not allowed on a transfer-only queue, where uploads are recorded.
pub struct TimestampQueryPool {
    pub(crate) raw: vk::QueryPool,
    count: u32,
}

impl TimestampQueryPool {
    /// Number of queries.
    pub fn count(&self) -> u32 {
        self.count
    }
    /// Reads `count` raw tick values from `first`, waiting for them to be available. Multiply
    /// differences by [`super::Limits::timestamp_period_ns`] for nanoseconds.
    pub fn read(&self, ctx: &Context, first: u32, count: u32) -> Result<Vec<u64>, VkError> {
        let in_range = matches!(first.checked_add(count), Some(end) if end <= self.count);
        if !in_range {
            return Err(VkError::InvalidArgument(format!(
                "timestamps {first}..+{count} outside a pool of {}",
                self.count
            )));
        }
        let mut data = vec![0u64; count as usize];
        // SAFETY: live pool, range checked, u64 results.
        unsafe {
            ctx.device().get_query_pool_results(
                self.raw,
                first,
                &mut data,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
            )
        }
        .op("reading timestamp queries")?;
        Ok(data)
    }
    /// Resets `count` queries from `first` from the host, so they can be written again.
    ///
    /// # Safety
    /// No pending or executing command buffer may write those queries.
    pub unsafe fn reset(&self, ctx: &Context, first: u32, count: u32) {
        let end = first.saturating_add(count).min(self.count);
        if end > first {
            // SAFETY: live pool, range clamped; by the caller's guarantee nothing uses the queries.
            unsafe { ctx.device().reset_query_pool(self.raw, first, end - first) };
        }
    }
}

impl Context {
    /// Creates a pool of `count` timestamp queries; fails if the device cannot time compute work.
    pub fn create_timestamp_pool(&self, name: &str, count: u32) -> Result<TimestampQueryPool, VkError> {
        if !self.limits().timestamps_supported {
            return Err(VkError::Unsupported {
                device: self.device_name().to_owned(),
                reason: "timestamps are not supported on its compute queue".into(),
            });
        }
        let info = vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(count);
        // SAFETY: valid create info.
        let raw = unsafe { self.device().create_query_pool(&info, None) }
            .op_with(|| format!("creating query pool `{name}`"))?;
        self.set_name(raw, name);
        let pool = TimestampQueryPool { raw, count };
        // SAFETY: a new pool: nothing has recorded its queries yet.
        unsafe { pool.reset(self, 0, count) };
        Ok(pool)
    }

    /// Destroys a query pool.
    ///
    /// # Safety
    /// No pending command buffer may write or reset its queries.
    pub unsafe fn destroy_timestamp_pool(&self, pool: TimestampQueryPool) {
        // SAFETY: by the caller's guarantee.
        unsafe { self.device().destroy_query_pool(pool.raw, None) };
    }
}
