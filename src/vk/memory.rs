//! Buffers and their memory, from `gpu-allocator`.

use std::ptr::NonNull;
use std::sync::atomic::Ordering;

use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;

use super::context::Context;
use super::error::{VkError, VkResultExt};

/// A buffer and the memory bound to it. Free it with [`Context::destroy_buffer`] (`unsafe`: the GPU must be done with it)
/// or [`Context::retire_buffer`] (once a timeline value is reached); a dropped `Buffer` leaks and is
/// reported by name when the context is dropped.
pub struct Buffer {
    raw: vk::Buffer,
    allocation: Allocation,
    size: u64,
    name: String,
    location: MemoryLocation,
}

impl Buffer {
    /// The Vulkan handle.
    pub fn raw(&self) -> vk::Buffer {
        self.raw
    }
    /// The size requested at creation, in bytes.
    pub fn size(&self) -> u64 {
        self.size
    }
    /// The name given at creation.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// Where the memory lives.
    pub fn location(&self) -> MemoryLocation {
        self.location
    }
    /// Host view of a `CpuToGpu`/`GpuToCpu` buffer (coherent: no flush needed, but a host read must
    /// follow a GPU→host barrier and a wait). `GpuOnly` buffers give `None` even where the memory
    /// happens to be mappable (lavapipe), so that code tested there does not map on a real GPU.
    pub fn mapped(&self) -> Option<&[u8]> {
        if !self.host_visible_by_contract() {
            return None;
        }
        let len = usize::try_from(self.size).ok()?;
        self.allocation.mapped_slice().and_then(|s| s.get(..len))
    }
    /// Mutable host view; see [`Buffer::mapped`].
    pub fn mapped_mut(&mut self) -> Option<&mut [u8]> {
        if !self.host_visible_by_contract() {
            return None;
        }
        let len = usize::try_from(self.size).ok()?;
        self.allocation.mapped_slice_mut().and_then(|s| s.get_mut(..len))
    }
    fn host_visible_by_contract(&self) -> bool {
        matches!(self.location, MemoryLocation::CpuToGpu | MemoryLocation::GpuToCpu)
    }
}

/// A host-visible buffer (`CpuToGpu` or `GpuToCpu`), persistently mapped: the mapping is checked
/// once, when it is made ([`Context::create_host_buffer`]), so "not mapped" cannot happen later.
/// It dereferences to its [`Buffer`] for copies; free it with [`Context::destroy_host_buffer`].
pub struct HostBuffer {
    buffer: Buffer,
    ptr: NonNull<u8>,
    len: usize,
}

// SAFETY: the pointer is to the buffer's persistent mapping, which lives as long as the buffer
// (itself Send + Sync); `HostBuffer` hands out `&[u8]` for `&self` and `&mut [u8]` for `&mut self`
// only, and raw pointers whose use is the caller's `unsafe` business.
unsafe impl Send for HostBuffer {}
// SAFETY: as above.
unsafe impl Sync for HostBuffer {}

impl HostBuffer {
    /// The mapped bytes (a read after a GPU write must follow a GPU→host barrier and a wait).
    pub fn bytes(&self) -> &[u8] {
        // SAFETY: `len` bytes are mapped for the buffer's lifetime; shared borrow of self.
        unsafe { std::slice::from_raw_parts(self.ptr.as_ptr(), self.len) }
    }
    /// The mapped bytes, to write.
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        // SAFETY: as above, with an exclusive borrow of self.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.as_ptr(), self.len) }
    }
    /// The start of the mapping, for copies done through raw pointers (by other threads); writing
    /// through it is the caller's `unsafe` contract (no reference to the bytes alive meanwhile).
    pub fn as_mut_ptr(&self) -> *mut u8 {
        self.ptr.as_ptr()
    }
}

impl std::ops::Deref for HostBuffer {
    type Target = Buffer;
    fn deref(&self) -> &Buffer {
        &self.buffer
    }
}

impl std::fmt::Debug for Buffer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Buffer")
            .field("name", &self.name)
            .field("size", &self.size)
            .field("location", &self.location)
            .finish_non_exhaustive()
    }
}

impl Context {
    /// Creates a buffer with memory in `location`. `usage` is what the buffer is used for
    /// (STORAGE_BUFFER, TRANSFER_SRC, TRANSFER_DST ...).
    pub fn create_buffer(
        &self,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
    ) -> Result<Buffer, VkError> {
        if size == 0 {
            return Err(VkError::InvalidArgument(format!("buffer `{name}` has size 0")));
        }
        let families = self.queue_families();
        let mut info = vk::BufferCreateInfo::default().size(size).usage(usage);
        info = if families.len() > 1 {
            info.sharing_mode(vk::SharingMode::CONCURRENT).queue_family_indices(&families)
        } else {
            info.sharing_mode(vk::SharingMode::EXCLUSIVE)
        };
        let device = self.device();
        // SAFETY: valid create info; `families` outlives the call.
        let raw = unsafe { device.create_buffer(&info, None) }
            .op_with(|| format!("creating buffer `{name}` ({size} bytes)"))?;
        // SAFETY: `raw` is a live buffer.
        let requirements = unsafe { device.get_buffer_memory_requirements(raw) };
        let allocation = self.allocator().allocate(&AllocationCreateDesc {
            name,
            requirements,
            location,
            linear: true,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        });
        let allocation = match allocation {
            Ok(a) => a,
            Err(source) => {
                // SAFETY: never used.
                unsafe { device.destroy_buffer(raw, None) };
                return Err(VkError::Allocation { name: name.to_owned(), size, source });
            }
        };
        // SAFETY: the allocation satisfies `requirements` of this buffer.
        if let Err(r) = unsafe { device.bind_buffer_memory(raw, allocation.memory(), allocation.offset()) } {
            // SAFETY: never used by the GPU.
            unsafe { device.destroy_buffer(raw, None) };
            if let Err(e) = self.allocator().free(allocation) {
                tracing::error!(name, %e, "freeing the memory of a buffer that failed to bind");
            }
            return Err(VkError::from_vk(format!("binding memory to buffer `{name}`"), r));
        }
        let bytes = allocation.size();
        let now = self.allocated.fetch_add(bytes, Ordering::Relaxed) + bytes;
        self.peak_allocated.fetch_max(now, Ordering::Relaxed);
        self.set_name(raw, name);
        tracing::trace!(name, size, ?location, "buffer created");
        Ok(Buffer { raw, allocation, size, name: name.to_owned(), location })
    }

    /// Creates a host-visible buffer, `location` `CpuToGpu` (staging to the device) or `GpuToCpu`
    /// (staging from it).
    pub fn create_host_buffer(
        &self,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        location: MemoryLocation,
    ) -> Result<HostBuffer, VkError> {
        if !matches!(location, MemoryLocation::CpuToGpu | MemoryLocation::GpuToCpu) {
            return Err(VkError::InvalidArgument(format!("host buffer `{name}` must be CpuToGpu or GpuToCpu")));
        }
        let buffer = self.create_buffer(name, size, usage, location)?;
        let mapping = buffer.allocation.mapped_ptr().map(|p| p.cast::<u8>());
        match (mapping, usize::try_from(size)) {
            (Some(ptr), Ok(len)) => Ok(HostBuffer { buffer, ptr, len }),
            _ => {
                // SAFETY: just made; never submitted.
                unsafe { self.destroy_buffer(buffer) };
                Err(VkError::InvalidArgument(format!("host buffer `{name}` ({size} bytes) could not be mapped")))
            }
        }
    }

    /// Destroys a host buffer now.
    ///
    /// # Safety
    /// As for [`Context::destroy_buffer`]: no pending submission may refer to it.
    pub unsafe fn destroy_host_buffer(&self, buffer: HostBuffer) {
        // SAFETY: the caller's contract.
        unsafe { self.destroy_buffer(buffer.buffer) }
    }

    /// Destroys a buffer now (else use [`Context::retire_buffer`]).
    ///
    /// # Safety
    /// The device must no longer use the buffer: no submission that refers to it may be pending.
    pub unsafe fn destroy_buffer(&self, buffer: Buffer) {
        let Buffer { raw, allocation, name, .. } = buffer;
        let bytes = allocation.size();
        // SAFETY: by the caller's guarantee the GPU is done with `raw`.
        unsafe { self.device().destroy_buffer(raw, None) };
        if let Err(e) = self.allocator().free(allocation) {
            tracing::error!(name = %name, %e, "freeing buffer memory");
        }
        self.allocated.fetch_sub(bytes, Ordering::Relaxed);
        tracing::trace!(name = %name, "buffer destroyed");
    }

    /// Bytes of device memory currently allocated for our buffers.
    pub fn allocated_bytes(&self) -> u64 {
        self.allocated.load(Ordering::Relaxed)
    }
    /// The most bytes ever allocated at once.
    pub fn peak_allocated_bytes(&self) -> u64 {
        self.peak_allocated.load(Ordering::Relaxed)
    }
}
