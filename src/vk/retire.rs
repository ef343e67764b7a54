//! Deferred destruction: resources the GPU may still use are retired against a timeline value and
//! freed once the semaphore has reached it (checked on every submit and by `collect_garbage`).

use std::collections::HashMap;

use ash::vk;

use super::commands::CommandResources;
use super::context::Context;
use super::error::{VkError, VkResultExt};
use super::lock;
use super::memory::Buffer;
use super::sync::TimelineSemaphore;

/// Something waiting to be freed.
pub(crate) enum Garbage {
    Buffer(Buffer),
    Commands(CommandResources),
}

pub(crate) struct Retired {
    /// Null once its semaphore was destroyed before reaching `value`: then it is only freed when
    /// the context is dropped (after the device idles).
    pub(crate) semaphore: vk::Semaphore,
    pub(crate) value: u64,
    pub(crate) item: Garbage,
}

impl Context {
    /// Frees `buffer` once `timeline` reaches `value` (at the next [`Context::collect_garbage`], on a
    /// later submit, or when the context is dropped).
    pub fn retire_buffer(&self, buffer: Buffer, timeline: &TimelineSemaphore, value: u64) {
        self.retire(Garbage::Buffer(buffer), timeline.raw(), value);
    }

    pub(crate) fn retire(&self, item: Garbage, semaphore: vk::Semaphore, value: u64) {
        lock(&self.garbage).push(Retired { semaphore, value, item });
    }

    /// Number of retired resources not yet freed.
    pub fn pending_garbage(&self) -> usize {
        lock(&self.garbage).len()
    }

    /// Frees every retired resource whose timeline value has been reached. Does not wait.
    pub fn collect_garbage(&self) -> Result<(), VkError> {
        let ready = {
            let mut list = lock(&self.garbage);
            if list.is_empty() {
                return Ok(());
            }
            // One counter query per semaphore, not per item.
            let mut reached: HashMap<vk::Semaphore, u64> = HashMap::new();
            for r in list.iter() {
                if r.semaphore != vk::Semaphore::null() && !reached.contains_key(&r.semaphore) {
                    // SAFETY: semaphores in the list are alive: destroy_timeline orphans entries first.
                    let v = unsafe { self.device().get_semaphore_counter_value(r.semaphore) }
                        .op("reading a timeline value to free retired resources")?;
                    reached.insert(r.semaphore, v);
                }
            }
            let (ready, pending): (Vec<Retired>, Vec<Retired>) = std::mem::take(&mut *list)
                .into_iter()
                .partition(|r| reached.get(&r.semaphore).is_some_and(|&v| v >= r.value));
            *list = pending;
            ready
        };
        for r in ready {
            // SAFETY: its semaphore reached the value it was retired against.
            unsafe { self.free_now(r.item) };
        }
        Ok(())
    }

    /// Called before `semaphore` is destroyed: whatever still waits on it can no longer be tracked,
    /// so it is kept until the context is dropped. Returns how many such items there were.
    pub(crate) fn orphan_retired_on(&self, semaphore: vk::Semaphore) -> usize {
        let mut list = lock(&self.garbage);
        let mut n = 0;
        for r in list.iter_mut().filter(|r| r.semaphore == semaphore) {
            r.semaphore = vk::Semaphore::null();
            n += 1;
        }
        n
    }

    /// The highest value anything retired on `semaphore` waits for.
    pub(crate) fn max_retired_value(&self, semaphore: vk::Semaphore) -> Option<u64> {
        lock(&self.garbage).iter().filter(|r| r.semaphore == semaphore).map(|r| r.value).max()
    }

    /// # Safety
    /// The device must be done with `item` (its timeline value reached, or the device idle).
    pub(crate) unsafe fn free_now(&self, item: Garbage) {
        match item {
            // SAFETY: the caller's contract.
            Garbage::Buffer(b) => unsafe { self.destroy_buffer(b) },
            Garbage::Commands(c) => c.destroy(self.device()),
        }
    }
}
