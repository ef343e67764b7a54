//! Ownership of the driver's Vulkan objects: an [`Owned`] value frees its object when dropped, so a
//! struct made of them is built all-or-nothing (a constructor that fails half-way drops what it
//! made) and needs no `Option` fields and no hand-written release.
//!
//! The `vk` layer's destroy functions take objects by value and leave *when* to the caller (the GPU
//! must be done with them). Here that contract is kept by construction order: the driver's
//! [`Timelines`](super::resources::Timelines) are the first field of the resources and wait for the
//! last submitted values when dropped, before any buffer or pipeline after them is freed; a
//! temporary (the tables' staging) is dropped after its submission was waited for.

use crate::vk::{
    Buffer, ComputePipeline, Context, DescriptorSet, HostBuffer, PipelineLayout, TimelineSemaphore, TimestampQueryPool,
};
use std::mem::ManuallyDrop;
use std::ops::{Deref, DerefMut};
use std::sync::Arc;

/// A Vulkan object that `Context` destroys.
pub trait Destroy {
    /// Frees the object.
    ///
    /// # Safety
    /// The device must no longer use the object (no pending submission refers to it).
    unsafe fn destroy(self, ctx: &Context);
}

impl Destroy for Buffer {
    unsafe fn destroy(self, ctx: &Context) {
        // SAFETY: the caller's contract is destroy_buffer's.
        unsafe { ctx.destroy_buffer(self) }
    }
}

impl Destroy for HostBuffer {
    unsafe fn destroy(self, ctx: &Context) {
        // SAFETY: as above.
        unsafe { ctx.destroy_host_buffer(self) }
    }
}

impl Destroy for DescriptorSet {
    unsafe fn destroy(self, ctx: &Context) {
        // SAFETY: as above.
        unsafe { ctx.destroy_descriptor_set(self) }
    }
}

impl Destroy for ComputePipeline {
    unsafe fn destroy(self, ctx: &Context) {
        // SAFETY: as above.
        unsafe { ctx.destroy_pipeline(self) }
    }
}

impl Destroy for PipelineLayout {
    unsafe fn destroy(self, ctx: &Context) {
        // SAFETY: as above; and the pipelines made with it are declared (so dropped) before it.
        unsafe { ctx.destroy_pipeline_layout(self) }
    }
}

impl Destroy for TimelineSemaphore {
    unsafe fn destroy(self, ctx: &Context) {
        // SAFETY: as above.
        unsafe { ctx.destroy_timeline(self) }
    }
}

impl Destroy for TimestampQueryPool {
    unsafe fn destroy(self, ctx: &Context) {
        // SAFETY: as above.
        unsafe { ctx.destroy_timestamp_pool(self) }
    }
}

/// An object and the context that frees it on drop.
pub struct Owned<T: Destroy> {
    ctx: Arc<Context>,
    inner: ManuallyDrop<T>,
}

impl<T: Destroy> Owned<T> {
    pub fn new(ctx: &Arc<Context>, inner: T) -> Self {
        Owned { ctx: Arc::clone(ctx), inner: ManuallyDrop::new(inner) }
    }
}

impl<T: Destroy> Deref for Owned<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.inner
    }
}

impl<T: Destroy> DerefMut for Owned<T> {
    fn deref_mut(&mut self) -> &mut T {
        &mut self.inner
    }
}

impl<T: Destroy> Drop for Owned<T> {
    fn drop(&mut self) {
        // SAFETY: `inner` is taken once, here, and never used again. The device is done with it:
        // see the module docs (the timelines are waited for before the objects after them drop).
        unsafe { ManuallyDrop::take(&mut self.inner).destroy(&self.ctx) }
    }
}
