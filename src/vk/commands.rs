//! Command recording and submission: [`Recorder`], a one-shot command buffer.
//!
//! A recorder owns a transient command pool (one per recording: pools are cheap, and owning one
//! makes freeing trivially correct) and the descriptor pools its dispatches allocate from. After
//! `submit` these are retired against the submission's signal value and freed by garbage
//! collection; a recorder dropped without submitting frees them at once (the GPU never saw them).

use std::sync::Arc;

use ash::vk;

use super::context::Context;
use super::descriptors::{check_buffers, DescriptorSet};
use super::device::Queue;
use super::error::{VkError, VkResultExt};
use super::memory::Buffer;
use super::pipeline::ComputePipeline;
use super::query::TimestampQueryPool;
use super::retire::Garbage;
use super::sync::TimelineSemaphore;

/// Descriptor sets per descriptor pool; a recorder with more dispatches makes another pool.
const SETS_PER_POOL: u32 = 64;
/// Storage-buffer descriptors per pool (8 bindings per set on average).
const DESCRIPTORS_PER_POOL: u32 = SETS_PER_POOL * 8;

/// A range of a buffer bound to one storage-buffer binding.
#[derive(Clone, Copy, Debug)]
pub struct BufferRange<'a> {
    pub buffer: &'a Buffer,
    pub offset: u64,
    pub range: u64,
}

impl<'a> BufferRange<'a> {
    /// `range` bytes of `buffer` from `offset`.
    pub fn new(buffer: &'a Buffer, offset: u64, range: u64) -> Self {
        BufferRange { buffer, offset, range }
    }
}

impl<'a> From<&'a Buffer> for BufferRange<'a> {
    /// The whole buffer.
    fn from(buffer: &'a Buffer) -> Self {
        BufferRange { buffer, offset: 0, range: buffer.size() }
    }
}

/// The pools a recording used; freed when its submission completed.
pub(crate) struct CommandResources {
    name: String,
    command_pool: vk::CommandPool,
    descriptor_pools: Vec<vk::DescriptorPool>,
}

impl CommandResources {
    pub(crate) fn destroy(self, device: &ash::Device) {
        // SAFETY: the owner guarantees the command buffer is not pending (never submitted, or its
        // signal value was reached). Destroying a pool frees what was allocated from it.
        unsafe {
            for p in self.descriptor_pools {
                device.destroy_descriptor_pool(p, None);
            }
            device.destroy_command_pool(self.command_pool, None);
        }
        tracing::trace!(name = %self.name, "command resources freed");
    }
}

/// A one-shot command buffer: record, then [`Recorder::submit`].
pub struct Recorder {
    ctx: Arc<Context>,
    family: u32,
    cb: vk::CommandBuffer,
    /// `None` only after submit moved them to the retired list.
    resources: Option<CommandResources>,
}

impl Recorder {
    /// Starts recording for a queue of `queue_family`.
    pub fn begin(ctx: &Arc<Context>, queue_family: u32, name: &str) -> Result<Recorder, VkError> {
        let device = ctx.device();
        let pool_info = vk::CommandPoolCreateInfo::default()
            .flags(vk::CommandPoolCreateFlags::TRANSIENT)
            .queue_family_index(queue_family);
        // SAFETY: valid create info.
        let command_pool = unsafe { device.create_command_pool(&pool_info, None) }
            .op_with(|| format!("creating the command pool of `{name}`"))?;
        // From here on, Drop frees the pool on any early return.
        let mut rec = Recorder {
            ctx: Arc::clone(ctx),
            family: queue_family,
            cb: vk::CommandBuffer::null(),
            resources: Some(CommandResources { name: name.to_owned(), command_pool, descriptor_pools: Vec::new() }),
        };
        let alloc_info = vk::CommandBufferAllocateInfo::default()
            .command_pool(command_pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: live pool.
        let cbs = unsafe { device.allocate_command_buffers(&alloc_info) }
            .op_with(|| format!("allocating the command buffer of `{name}`"))?;
        rec.cb = cbs.first().copied().ok_or_else(|| {
            VkError::from_vk(format!("allocating the command buffer of `{name}`"), vk::Result::ERROR_UNKNOWN)
        })?;
        let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
        // SAFETY: freshly allocated command buffer.
        unsafe { device.begin_command_buffer(rec.cb, &begin) }
            .op_with(|| format!("beginning command buffer `{name}`"))?;
        ctx.set_name(command_pool, name);
        ctx.set_name(rec.cb, name);
        Ok(rec)
    }

    /// The command buffer being recorded, for commands this layer does not wrap.
    pub fn raw(&self) -> vk::CommandBuffer {
        self.cb
    }

    /// The queue family this recording is for.
    pub fn family(&self) -> u32 {
        self.family
    }

    fn name(&self) -> &str {
        self.resources.as_ref().map_or("", |r| r.name.as_str())
    }

    /// Checks a dispatch against the pipeline's shape and the device limits. Makes no Vulkan call.
    fn check_dispatch(&self, p: &ComputePipeline, push_constants: &[u8], groups: [u32; 3]) -> Result<(), VkError> {
        let limits = self.ctx.limits();
        let name = p.name();
        if push_constants.len() != p.push_constant_bytes as usize {
            return Err(VkError::InvalidArgument(format!(
                "dispatch of `{name}` pushes {} bytes of constants; the pipeline declares {}",
                push_constants.len(),
                p.push_constant_bytes
            )));
        }
        for (axis, (&g, &max)) in groups.iter().zip(limits.max_workgroup_count.iter()).enumerate() {
            if g > max {
                return Err(VkError::LimitExceeded(format!(
                    "dispatch of `{name}`: {g} workgroups along axis {axis} exceeds maxComputeWorkGroupCount[{axis}] = {max}; split the dispatch"
                )));
            }
        }
        Ok(())
    }

    /// Allocates one descriptor set of `p`'s layout, making a new descriptor pool when the current
    /// one is full.
    fn allocate_set(&mut self, p: &ComputePipeline) -> Result<vk::DescriptorSet, VkError> {
        let device = self.ctx.device();
        let set_layouts = [p.set_layout];
        if let Some(&pool) = self.resources.as_ref().and_then(|r| r.descriptor_pools.last()) {
            let info = vk::DescriptorSetAllocateInfo::default().descriptor_pool(pool).set_layouts(&set_layouts);
            // SAFETY: live pool and layout.
            match unsafe { device.allocate_descriptor_sets(&info) } {
                Ok(sets) if !sets.is_empty() => return Ok(sets[0]),
                Ok(_) | Err(vk::Result::ERROR_OUT_OF_POOL_MEMORY) | Err(vk::Result::ERROR_FRAGMENTED_POOL) => {}
                Err(r) => return Err(VkError::from_vk(format!("allocating a descriptor set for `{}`", p.name()), r)),
            }
        }
        let sizes = [vk::DescriptorPoolSize::default()
            .ty(vk::DescriptorType::STORAGE_BUFFER)
            .descriptor_count(DESCRIPTORS_PER_POOL.max(p.storage_buffers))];
        let pool_info = vk::DescriptorPoolCreateInfo::default().max_sets(SETS_PER_POOL).pool_sizes(&sizes);
        // SAFETY: `sizes` outlives the call.
        let pool = unsafe { device.create_descriptor_pool(&pool_info, None) }
            .op_with(|| format!("creating a descriptor pool for `{}`", self.name()))?;
        if let Some(r) = self.resources.as_mut() {
            r.descriptor_pools.push(pool);
        }
        let info = vk::DescriptorSetAllocateInfo::default().descriptor_pool(pool).set_layouts(&set_layouts);
        // SAFETY: live, empty pool sized for this layout.
        let sets = unsafe { device.allocate_descriptor_sets(&info) }
            .op_with(|| format!("allocating a descriptor set for `{}`", p.name()))?;
        sets.first().copied().ok_or_else(|| {
            VkError::from_vk(format!("allocating a descriptor set for `{}`", p.name()), vk::Result::ERROR_UNKNOWN)
        })
    }

    /// Records a dispatch of `groups` workgroups of `p` with `buffers` bound to bindings 0.. and
    /// `push_constants`. Shape and limits are checked first; nothing is recorded on error.
    pub fn dispatch(
        &mut self,
        p: &ComputePipeline,
        buffers: &[BufferRange],
        push_constants: &[u8],
        groups: [u32; 3],
    ) -> Result<(), VkError> {
        self.check_dispatch(p, push_constants, groups)?;
        check_buffers(&self.ctx, p.name(), p.storage_buffers, buffers)?;
        let set = if buffers.is_empty() { None } else { Some(self.allocate_set(p)?) };
        let device = self.ctx.device();
        if let Some(set) = set {
            let infos: Vec<[vk::DescriptorBufferInfo; 1]> = buffers
                .iter()
                .map(|r| [vk::DescriptorBufferInfo::default().buffer(r.buffer.raw()).offset(r.offset).range(r.range)])
                .collect();
            let writes: Vec<vk::WriteDescriptorSet> = infos
                .iter()
                .enumerate()
                .map(|(binding, info)| {
                    vk::WriteDescriptorSet::default()
                        .dst_set(set)
                        .dst_binding(binding as u32)
                        .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                        .buffer_info(info)
                })
                .collect();
            // SAFETY: `infos` outlives the call; the set is not in use yet.
            unsafe { device.update_descriptor_sets(&writes, &[]) };
        }
        // SAFETY: recording into our command buffer; all handles are alive.
        unsafe {
            device.cmd_bind_pipeline(self.cb, vk::PipelineBindPoint::COMPUTE, p.raw);
            if let Some(set) = set {
                device.cmd_bind_descriptor_sets(self.cb, vk::PipelineBindPoint::COMPUTE, p.layout, 0, &[set], &[]);
            }
            if !push_constants.is_empty() {
                device.cmd_push_constants(self.cb, p.layout, vk::ShaderStageFlags::COMPUTE, 0, push_constants);
            }
            device.cmd_dispatch(self.cb, groups[0], groups[1], groups[2]);
        }
        Ok(())
    }

    /// Binds `p` and its descriptor set `set` (made once with [`Context::create_descriptor_set`])
    /// for the [`Recorder::dispatch_bound`] calls that follow.
    pub fn bind(&mut self, p: &ComputePipeline, set: &DescriptorSet) -> Result<(), VkError> {
        if set.set_layout != p.set_layout {
            return Err(VkError::InvalidArgument(format!(
                "descriptor set `{}` was made for another pipeline than `{}`",
                set.name,
                p.name()
            )));
        }
        let device = self.ctx.device();
        // SAFETY: recording into our command buffer; the pipeline and the set are alive, and the
        // set is never updated after it was made.
        unsafe {
            device.cmd_bind_pipeline(self.cb, vk::PipelineBindPoint::COMPUTE, p.raw);
            device.cmd_bind_descriptor_sets(self.cb, vk::PipelineBindPoint::COMPUTE, p.layout, 0, &[set.raw], &[]);
        }
        Ok(())
    }

    /// Binds pipeline `p` alone, keeping the descriptor set bound before: `p` must share the layout
    /// of the pipeline that set was bound with ([`Context::create_compute_pipeline_with_layout`]),
    /// else the set is not compatible (checked against the set, as in [`Recorder::bind`]).
    ///
    /// [`Context::create_compute_pipeline_with_layout`]: super::Context::create_compute_pipeline_with_layout
    pub fn switch_pipeline(&mut self, p: &ComputePipeline, set: &DescriptorSet) -> Result<(), VkError> {
        if set.set_layout != p.set_layout {
            return Err(VkError::InvalidArgument(format!(
                "pipeline `{}` does not share the layout descriptor set `{}` was made for",
                p.name(),
                set.name
            )));
        }
        // SAFETY: recording into our command buffer; the pipeline is alive.
        unsafe { self.ctx.device().cmd_bind_pipeline(self.cb, vk::PipelineBindPoint::COMPUTE, p.raw) };
        Ok(())
    }

    /// Records a dispatch of `groups` workgroups of `p`, bound before with [`Recorder::bind`], with
    /// `push_constants`. Nothing is recorded on error.
    pub fn dispatch_bound(
        &mut self,
        p: &ComputePipeline,
        push_constants: &[u8],
        groups: [u32; 3],
    ) -> Result<(), VkError> {
        self.check_dispatch(p, push_constants, groups)?;
        let device = self.ctx.device();
        // SAFETY: recording into our command buffer; all handles are alive.
        unsafe {
            if !push_constants.is_empty() {
                device.cmd_push_constants(self.cb, p.layout, vk::ShaderStageFlags::COMPUTE, 0, push_constants);
            }
            device.cmd_dispatch(self.cb, groups[0], groups[1], groups[2]);
        }
        Ok(())
    }

    /// Copies regions from `src` to `dst` (needs TRANSFER_SRC / TRANSFER_DST usage).
    pub fn copy_buffer(&mut self, src: &Buffer, dst: &Buffer, regions: &[vk::BufferCopy]) {
        // SAFETY: recording; regions are checked by validation.
        unsafe { self.ctx.device().cmd_copy_buffer(self.cb, src.raw(), dst.raw(), regions) };
    }

    /// Fills `size` bytes of `dst` from `offset` with the 32-bit `value` (offsets and size multiples
    /// of 4; `vk::WHOLE_SIZE` for the rest of the buffer). Counts as a transfer (clear) write.
    pub fn fill_buffer(&mut self, dst: &Buffer, offset: u64, size: u64, value: u32) {
        // SAFETY: recording.
        unsafe { self.ctx.device().cmd_fill_buffer(self.cb, dst.raw(), offset, size, value) };
    }

    /// Writes `data` into `dst` from `offset` through the command buffer itself
    /// (`vkCmdUpdateBuffer`: offset and length multiples of 4; longer data goes in pieces of at
    /// most 65536 bytes, the command's limit). Counts as a transfer write.
    pub fn update_buffer(&mut self, dst: &Buffer, offset: u64, data: &[u8]) {
        const MAX_UPDATE: usize = 65536;
        for (i, piece) in data.chunks(MAX_UPDATE).enumerate() {
            let at = offset + (i * MAX_UPDATE) as u64;
            // SAFETY: recording; the data is copied into the command buffer by the call.
            unsafe { self.ctx.device().cmd_update_buffer(self.cb, dst.raw(), at, piece) };
        }
    }

    /// A global memory barrier between the given stages and accesses.
    pub fn barrier(
        &mut self,
        src_stage: vk::PipelineStageFlags2,
        src_access: vk::AccessFlags2,
        dst_stage: vk::PipelineStageFlags2,
        dst_access: vk::AccessFlags2,
    ) {
        let barriers = [vk::MemoryBarrier2::default()
            .src_stage_mask(src_stage)
            .src_access_mask(src_access)
            .dst_stage_mask(dst_stage)
            .dst_access_mask(dst_access)];
        let dep = vk::DependencyInfo::default().memory_barriers(&barriers);
        // SAFETY: `barriers` outlives the call.
        unsafe { self.ctx.sync2.cmd_pipeline_barrier2(self.ctx.device(), self.cb, &dep) };
    }

    /// Compute writes → later compute reads and writes.
    pub fn compute_to_compute(&mut self) {
        self.barrier(
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_WRITE,
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_READ | vk::AccessFlags2::SHADER_STORAGE_WRITE,
        );
    }
    /// Copies/fills → compute reads and writes.
    pub fn transfer_to_compute(&mut self) {
        self.barrier(
            vk::PipelineStageFlags2::ALL_TRANSFER,
            vk::AccessFlags2::TRANSFER_WRITE,
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_READ | vk::AccessFlags2::SHADER_STORAGE_WRITE,
        );
    }
    /// Compute writes → copies/fills (reads and writes).
    pub fn compute_to_transfer(&mut self) {
        self.barrier(
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_WRITE,
            vk::PipelineStageFlags2::ALL_TRANSFER,
            vk::AccessFlags2::TRANSFER_READ | vk::AccessFlags2::TRANSFER_WRITE,
        );
    }
    /// Copies/fills → later copies/fills.
    pub fn transfer_to_transfer(&mut self) {
        self.barrier(
            vk::PipelineStageFlags2::ALL_TRANSFER,
            vk::AccessFlags2::TRANSFER_WRITE,
            vk::PipelineStageFlags2::ALL_TRANSFER,
            vk::AccessFlags2::TRANSFER_READ | vk::AccessFlags2::TRANSFER_WRITE,
        );
    }
    /// Copies into a mapped buffer → host reads (after waiting on the submission's timeline).
    pub fn transfer_to_host(&mut self) {
        self.barrier(
            vk::PipelineStageFlags2::ALL_TRANSFER,
            vk::AccessFlags2::TRANSFER_WRITE,
            vk::PipelineStageFlags2::HOST,
            vk::AccessFlags2::HOST_READ,
        );
    }
    /// Compute writes into a mapped buffer → host reads.
    pub fn compute_to_host(&mut self) {
        self.barrier(
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_STORAGE_WRITE,
            vk::PipelineStageFlags2::HOST,
            vk::AccessFlags2::HOST_READ,
        );
    }
    // No host_to_* barrier: submitting a batch already makes earlier host writes to coherent memory
    // visible to it (Vulkan spec, "host write ordering guarantees").

    /// Writes a timestamp into query `index` when all earlier commands have passed `stage`.
    pub fn write_timestamp(&mut self, pool: &TimestampQueryPool, index: u32, stage: vk::PipelineStageFlags2) {
        // SAFETY: recording.
        unsafe { self.ctx.sync2.cmd_write_timestamp2(self.ctx.device(), self.cb, stage, pool.raw, index) };
    }

    /// Ends recording and submits to `queue`, waiting on each `(timeline, value, stage)` before
    /// `stage` and signalling `signal` when all commands are done. The command and descriptor pools
    /// are retired against `signal` and freed by a later garbage collection.
    pub fn submit(
        mut self,
        queue: &Queue,
        waits: &[(&TimelineSemaphore, u64, vk::PipelineStageFlags2)],
        signal: (&TimelineSemaphore, u64),
    ) -> Result<(), VkError> {
        let name = self.name().to_owned();
        if queue.family() != self.family {
            return Err(VkError::InvalidArgument(format!(
                "`{name}` was recorded for queue family {} but submitted to family {}",
                self.family,
                queue.family()
            )));
        }
        let device = self.ctx.device();
        // SAFETY: recording state.
        unsafe { device.end_command_buffer(self.cb) }.op_with(|| format!("ending command buffer `{name}`"))?;

        let wait_infos: Vec<vk::SemaphoreSubmitInfo> = waits
            .iter()
            .map(|(t, value, stage)| {
                vk::SemaphoreSubmitInfo::default().semaphore(t.raw()).value(*value).stage_mask(*stage)
            })
            .collect();
        let signal_infos = [vk::SemaphoreSubmitInfo::default()
            .semaphore(signal.0.raw())
            .value(signal.1)
            .stage_mask(vk::PipelineStageFlags2::ALL_COMMANDS)];
        let cb_infos = [vk::CommandBufferSubmitInfo::default().command_buffer(self.cb)];
        let submits = [vk::SubmitInfo2::default()
            .wait_semaphore_infos(&wait_infos)
            .command_buffer_infos(&cb_infos)
            .signal_semaphore_infos(&signal_infos)];
        {
            let _guard = queue.lock();
            // SAFETY: we hold the queue lock; every array outlives the call.
            unsafe { self.ctx.sync2.queue_submit2(device, queue.raw(), &submits) }
                .op_with(|| format!("submitting `{name}`"))?;
        }
        tracing::trace!(name = %name, signal = signal.1, "submitted");
        if let Some(res) = self.resources.take() {
            self.ctx.retire(Garbage::Commands(res), signal.0.raw(), signal.1);
        }
        // Submission is the natural moment to free what earlier submissions are done with.
        if let Err(e) = self.ctx.collect_garbage() {
            tracing::warn!(%e, "collecting garbage after submitting `{name}`");
        }
        Ok(())
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        // Not submitted (or submit failed before reaching the queue): the GPU never saw it.
        if let Some(res) = self.resources.take() {
            res.destroy(self.ctx.device());
        }
    }
}
