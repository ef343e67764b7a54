//! Descriptor sets made once and bound many times: the solver's buffers do not change during a
//! solve, so each (pipeline, buffers) combination it dispatches with gets one set, written when it
//! is made and never updated, then bound by handle ([`Recorder::bind`](super::Recorder::bind)).
//! [`Recorder::dispatch`](super::Recorder::dispatch) still allocates a set per dispatch for
//! one-off work (tests, fills).

use ash::vk;

use super::commands::BufferRange;
use super::context::Context;
use super::error::{VkError, VkResultExt};
use super::pipeline::{ComputePipeline, PipelineLayout};

/// A descriptor set of one pipeline's layout, with its own pool. Free it with
/// [`Context::destroy_descriptor_set`] once no pending command buffer uses it.
pub struct DescriptorSet {
    pub(crate) raw: vk::DescriptorSet,
    pub(crate) set_layout: vk::DescriptorSetLayout,
    pool: vk::DescriptorPool,
    pub(crate) name: String,
}

impl Context {
    /// Makes a descriptor set of `p`'s layout with `buffers` bound to bindings 0.. (checked
    /// against the pipeline and the device limits first).
    pub fn create_descriptor_set(
        &self,
        name: &str,
        p: &ComputePipeline,
        buffers: &[BufferRange],
    ) -> Result<DescriptorSet, VkError> {
        check_buffers(self, p.name(), p.storage_buffers, buffers)?;
        self.make_set(name, p.set_layout, buffers)
    }

    /// Makes a descriptor set of a shared `layout` (for every pipeline made with it) with `buffers`
    /// bound to bindings 0.. (checked against the layout and the device limits first).
    pub fn create_descriptor_set_in(
        &self,
        name: &str,
        layout: &PipelineLayout,
        buffers: &[BufferRange],
    ) -> Result<DescriptorSet, VkError> {
        check_buffers(self, layout.name(), layout.storage_buffers, buffers)?;
        self.make_set(name, layout.set_layout, buffers)
    }

    fn make_set(
        &self,
        name: &str,
        set_layout: vk::DescriptorSetLayout,
        buffers: &[BufferRange],
    ) -> Result<DescriptorSet, VkError> {
        let device = self.device();
        let sizes = [vk::DescriptorPoolSize::default()
            .ty(vk::DescriptorType::STORAGE_BUFFER)
            .descriptor_count((buffers.len() as u32).max(1))];
        let pool_info = vk::DescriptorPoolCreateInfo::default().max_sets(1).pool_sizes(&sizes);
        // SAFETY: `sizes` outlives the call.
        let pool = unsafe { device.create_descriptor_pool(&pool_info, None) }
            .op_with(|| format!("creating the descriptor pool of `{name}`"))?;
        let set_layouts = [set_layout];
        let info = vk::DescriptorSetAllocateInfo::default().descriptor_pool(pool).set_layouts(&set_layouts);
        // SAFETY: live, empty pool sized for this layout.
        let raw = match unsafe { device.allocate_descriptor_sets(&info) } {
            Ok(sets) if !sets.is_empty() => sets[0],
            result => {
                // SAFETY: nothing allocated from it is in use.
                unsafe { device.destroy_descriptor_pool(pool, None) };
                let r = result.err().unwrap_or(vk::Result::ERROR_UNKNOWN);
                return Err(VkError::from_vk(format!("allocating descriptor set `{name}`"), r));
            }
        };
        let infos: Vec<[vk::DescriptorBufferInfo; 1]> = buffers
            .iter()
            .map(|r| [vk::DescriptorBufferInfo::default().buffer(r.buffer.raw()).offset(r.offset).range(r.range)])
            .collect();
        let writes: Vec<vk::WriteDescriptorSet> = infos
            .iter()
            .enumerate()
            .map(|(binding, info)| {
                vk::WriteDescriptorSet::default()
                    .dst_set(raw)
                    .dst_binding(binding as u32)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .buffer_info(info)
            })
            .collect();
        // SAFETY: `infos` outlives the call; the set is not in use yet.
        unsafe { device.update_descriptor_sets(&writes, &[]) };
        self.set_name(raw, name);
        Ok(DescriptorSet { raw, set_layout, pool, name: name.to_owned() })
    }

    /// Frees a descriptor set.
    ///
    /// # Safety
    /// No pending command buffer may use it (a set bound in a submitted command buffer must stay
    /// alive until that submission has completed).
    pub unsafe fn destroy_descriptor_set(&self, set: DescriptorSet) {
        // SAFETY: by the caller's guarantee; destroying the pool frees the set.
        unsafe { self.device().destroy_descriptor_pool(set.pool, None) };
    }
}

/// Checks buffers bound to bindings 0.. of `name`'s layout of `storage_buffers` bindings: their
/// count, their ranges against the buffers and the device limits. Makes no Vulkan call.
pub(crate) fn check_buffers(
    ctx: &Context,
    name: &str,
    storage_buffers: u32,
    buffers: &[BufferRange],
) -> Result<(), VkError> {
    let limits = ctx.limits();
    if buffers.len() != storage_buffers as usize {
        return Err(VkError::InvalidArgument(format!(
            "dispatch of `{name}` binds {} buffers; the pipeline has {storage_buffers} storage-buffer bindings",
            buffers.len(),
        )));
    }
    for (binding, r) in buffers.iter().enumerate() {
        let buf = r.buffer.name();
        if r.range > limits.max_storage_buffer_range {
            return Err(VkError::LimitExceeded(format!(
                    "dispatch of `{name}`: binding {binding} (`{buf}`) covers {} bytes, more than maxStorageBufferRange = {} bytes; bind a smaller range",
                    r.range, limits.max_storage_buffer_range
                )));
        }
        if r.range == 0 {
            return Err(VkError::InvalidArgument(format!(
                "dispatch of `{name}`: binding {binding} (`{buf}`) has an empty range"
            )));
        }
        let inside = matches!(r.offset.checked_add(r.range), Some(end) if end <= r.buffer.size());
        if !inside {
            return Err(VkError::InvalidArgument(format!(
                "dispatch of `{name}`: binding {binding} range {}..+{} is outside `{buf}` ({} bytes)",
                r.offset,
                r.range,
                r.buffer.size()
            )));
        }
        let align = limits.min_storage_buffer_offset_alignment.max(1);
        if r.offset % align != 0 {
            return Err(VkError::InvalidArgument(format!(
                    "dispatch of `{name}`: binding {binding} offset {} is not a multiple of minStorageBufferOffsetAlignment = {align}",
                    r.offset
                )));
        }
    }
    Ok(())
}
