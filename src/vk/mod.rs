//! The thin Vulkan layer: just enough raw Vulkan (through `ash`) for compute-only streaming.
//!
//! ## What it gives the solver
//!
//! - a [`Context`] (instance, optional validation with synchronization validation, one physical and
//!   logical device, a compute [`Queue`] and where possible a separate transfer queue, and the
//!   `gpu-allocator` memory allocator);
//! - [`Buffer`]s, the only resource kind the solver needs (storage buffers and staging buffers);
//! - [`ComputePipeline`]s, each with one descriptor set of storage buffers plus push constants
//!   (several may share one [`PipelineLayout`], so a set bound once serves them all), and
//!   [`DescriptorSet`]s made once for buffers that do not change and bound by handle;
//! - [`TimelineSemaphore`]s, the only synchronisation primitive between submissions and with the host;
//! - [`Recorder`], a one-shot command buffer that records dispatches, copies and barriers and is
//!   submitted with `vkQueueSubmit2`, waiting on and signalling timeline values.
//!
//! ## Ownership and lifetimes
//!
//! Every Vulkan object has one owner. Destroy functions take the object by value, so it cannot be used
//! afterwards. Objects the GPU may still be using are not destroyed at once but *retired* against a
//! timeline value ([`Context::retire_buffer`], and every submitted [`Recorder`] retires its command and
//! descriptor pools against its signal value); [`Context::collect_garbage`] (also run on each submit)
//! frees whatever the GPU has finished with. Nothing on the data path waits for the device to go idle;
//! only dropping the [`Context`] does.
//!
//! ## Memory
//!
//! `GpuOnly` buffers are never mapped, even on lavapipe where all memory is host-visible, so code that
//! works here also works on a GPU whose device memory cannot be mapped. `CpuToGpu`/`GpuToCpu`
//! buffers are persistently mapped and coherent. When compute and transfer queues are in different
//! families, buffers are created with CONCURRENT sharing between the two, so no ownership transfer is
//! needed (a negligible cost for buffers).

mod commands;
mod context;
mod descriptors;
mod device;
mod error;
mod instance;
mod memory;
mod pipeline;
mod query;
mod retire;
mod sync;

use std::sync::{Mutex, MutexGuard};

pub use commands::{BufferRange, Recorder};
pub use context::{Context, ContextOptions};
pub use descriptors::DescriptorSet;
pub use device::{Limits, Queue};
pub use error::VkError;
pub use memory::{Buffer, HostBuffer};
pub use pipeline::{ComputePipeline, PipelineLayout};
pub use query::TimestampQueryPool;
pub use sync::TimelineSemaphore;

/// Re-exported so users need not depend on the same versions themselves.
pub use ash::vk;
pub use gpu_allocator::MemoryLocation;

/// Locks a mutex, recovering from poisoning: the data behind our mutexes (lists of handles, the
/// allocator) stays consistent across a panic in an unrelated thread, and refusing to free GPU
/// memory after a panic would only turn one failure into a leak.
pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

// The solver shares the context across threads (streamer, submitter) and moves buffers and
// recordings between them: keep these types thread-safe.
const _: () = {
    const fn send_sync<T: Send + Sync>() {}
    const fn send<T: Send>() {}
    send_sync::<Context>();
    send_sync::<Buffer>();
    send_sync::<HostBuffer>();
    send_sync::<TimelineSemaphore>();
    send_sync::<ComputePipeline>();
    send_sync::<DescriptorSet>();
    send_sync::<TimestampQueryPool>();
    send::<Recorder>();
};
