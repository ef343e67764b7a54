//! Timeline semaphores: the one synchronisation primitive, between submissions and with the host.

use ash::vk;

use super::context::Context;
use super::error::{VkError, VkResultExt};

/// How long `destroy_timeline` waits for work still retired on the semaphore before giving up on it.
const DESTROY_WAIT_NS: u64 = 10_000_000_000;

/// A timeline semaphore (a monotonically increasing u64 shared by GPU and host).
pub struct TimelineSemaphore {
    raw: vk::Semaphore,
    name: String,
}

impl TimelineSemaphore {
    /// The Vulkan handle.
    pub fn raw(&self) -> vk::Semaphore {
        self.raw
    }
    /// The name given at creation.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The current value (non-blocking).
    pub fn value(&self, ctx: &Context) -> Result<u64, VkError> {
        // SAFETY: live semaphore of this device.
        unsafe { ctx.device().get_semaphore_counter_value(self.raw) }
            .op_with(|| format!("reading timeline `{}`", self.name))
    }
    /// Blocks until the value is ≥ `value`, or `timeout_ns` elapses ([`VkError::Timeout`]).
    pub fn wait(&self, ctx: &Context, value: u64, timeout_ns: u64) -> Result<(), VkError> {
        let semaphores = [self.raw];
        let values = [value];
        let info = vk::SemaphoreWaitInfo::default().semaphores(&semaphores).values(&values);
        // SAFETY: arrays outlive the call; live semaphore.
        match unsafe { ctx.device().wait_semaphores(&info, timeout_ns) } {
            Ok(()) => Ok(()),
            Err(vk::Result::TIMEOUT) => Err(VkError::Timeout { name: self.name.clone(), value, timeout_ns }),
            Err(r) => Err(VkError::from_vk(format!("waiting for timeline `{}` to reach {value}", self.name), r)),
        }
    }
    /// Sets the value from the host (it must be greater than the current value and than any pending
    /// signal) — releases GPU work waiting on it.
    pub fn signal(&self, ctx: &Context, value: u64) -> Result<(), VkError> {
        let info = vk::SemaphoreSignalInfo::default().semaphore(self.raw).value(value);
        // SAFETY: live semaphore.
        unsafe { ctx.device().signal_semaphore(&info) }
            .op_with(|| format!("signalling timeline `{}` to {value}", self.name))
    }
}

impl Context {
    /// Creates a timeline semaphore starting at `initial`.
    pub fn create_timeline(&self, name: &str, initial: u64) -> Result<TimelineSemaphore, VkError> {
        let mut type_info =
            vk::SemaphoreTypeCreateInfo::default().semaphore_type(vk::SemaphoreType::TIMELINE).initial_value(initial);
        let info = vk::SemaphoreCreateInfo::default().push_next(&mut type_info);
        // SAFETY: valid create info.
        let raw =
            unsafe { self.device().create_semaphore(&info, None) }.op_with(|| format!("creating timeline `{name}`"))?;
        self.set_name(raw, name);
        Ok(TimelineSemaphore { raw, name: name.to_owned() })
    }

    /// Destroys a timeline. Resources retired on it are freed first when it has reached their
    /// values (waiting a bounded time for that); any that cannot be are kept until the context is
    /// dropped, with a warning.
    ///
    /// # Safety
    /// No pending submission may wait on or signal it (Vulkan forbids destroying a semaphore a
    /// queue still uses; wait for the values submitted against it first).
    pub unsafe fn destroy_timeline(&self, t: TimelineSemaphore) {
        if let Err(e) = self.collect_garbage() {
            tracing::warn!(%e, "collecting garbage before destroying timeline `{}`", t.name);
        }
        if let Some(v) = self.max_retired_value(t.raw) {
            match t.wait(self, v, DESTROY_WAIT_NS) {
                Ok(()) => {
                    if let Err(e) = self.collect_garbage() {
                        tracing::warn!(%e, "collecting garbage before destroying timeline `{}`", t.name);
                    }
                }
                Err(e) => {
                    tracing::warn!(%e, "timeline `{}` destroyed with retired resources pending", t.name)
                }
            }
            let orphans = self.orphan_retired_on(t.raw);
            if orphans > 0 {
                tracing::warn!(
                    orphans,
                    "resources retired on timeline `{}` will be freed when the context is dropped",
                    t.name
                );
            }
        }
        if self.driver_id() == vk::DriverId::MESA_LLVMPIPE {
            // Mesa 22.3's lavapipe can still touch a timeline semaphore in its queue thread after a
            // wait on it returned, and crashes if it is destroyed right then. Idling our queues
            // (not the device) is cheap and only happens here, off the data path.
            for q in std::iter::once(self.compute_queue()).chain(self.transfer_queue()) {
                let _guard = q.lock();
                // SAFETY: we hold the queue's lock.
                if let Err(e) = unsafe { self.device().queue_wait_idle(q.raw()) } {
                    tracing::warn!(%e, "idling a queue before destroying timeline `{}`", t.name);
                }
            }
        }
        // SAFETY: by the caller's guarantee no pending work references it; no retired item does.
        unsafe { self.device().destroy_semaphore(t.raw, None) };
    }
}
