//! Compute pipelines. Each has one descriptor set whose bindings 0..n are all storage buffers, and
//! an optional push-constant block: that is all the solver's kernels use, and keeping one shape
//! lets the recorder allocate and write descriptor sets without per-pipeline metadata.
//!
//! Several pipelines may share one [`PipelineLayout`] (the solver's two kernels do): a descriptor
//! set bound once then serves each of them, and switching pipelines does not disturb it (Vulkan's
//! pipeline-layout compatibility).

use std::io::Cursor;

use ash::vk;

use super::context::Context;
use super::error::{VkError, VkResultExt};

/// SPIR-V magic number (first word of every module).
const SPIRV_MAGIC: u32 = 0x0723_0203;

/// A pipeline layout: one descriptor set of `storage_buffers` storage-buffer bindings (set 0,
/// bindings 0..n) and a push-constant block, shareable by several pipelines.
pub struct PipelineLayout {
    pub(crate) raw: vk::PipelineLayout,
    pub(crate) set_layout: vk::DescriptorSetLayout,
    pub(crate) storage_buffers: u32,
    pub(crate) push_constant_bytes: u32,
    name: String,
}

impl PipelineLayout {
    /// The name given at creation.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// How many storage buffers a descriptor set of this layout binds.
    pub fn storage_buffers(&self) -> u32 {
        self.storage_buffers
    }
}

/// A compute pipeline with its layout and descriptor-set layout.
pub struct ComputePipeline {
    pub(crate) raw: vk::Pipeline,
    pub(crate) layout: vk::PipelineLayout,
    pub(crate) set_layout: vk::DescriptorSetLayout,
    pub(crate) storage_buffers: u32,
    pub(crate) push_constant_bytes: u32,
    /// The layout was made for this pipeline alone (and is destroyed with it), not shared.
    owns_layout: bool,
    name: String,
}

impl ComputePipeline {
    /// The name given at creation.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// How many storage buffers a dispatch must bind.
    pub fn storage_buffers(&self) -> u32 {
        self.storage_buffers
    }
    /// How many bytes of push constants a dispatch must supply.
    pub fn push_constant_bytes(&self) -> u32 {
        self.push_constant_bytes
    }
    /// The Vulkan pipeline handle.
    pub fn raw(&self) -> vk::Pipeline {
        self.raw
    }
}

/// Checks the SPIR-V blob and turns it into aligned words.
fn spirv_words(name: &str, spirv: &[u8]) -> Result<Vec<u32>, VkError> {
    let bad = |reason: String| VkError::InvalidArgument(format!("SPIR-V of `{name}`: {reason}"));
    if spirv.is_empty() || spirv.len() % 4 != 0 {
        return Err(bad(format!("length {} is not a positive multiple of 4", spirv.len())));
    }
    // read_spv accepts either byte order; we only emit little-endian, so require it exactly.
    let magic = u32::from_le_bytes([spirv[0], spirv[1], spirv[2], spirv[3]]);
    if magic != SPIRV_MAGIC {
        return Err(bad(format!("bad magic number {magic:#010x} (expected {SPIRV_MAGIC:#010x})")));
    }
    ash::util::read_spv(&mut Cursor::new(spirv)).map_err(|e| bad(e.to_string()))
}

impl Context {
    /// Creates a pipeline layout with `storage_buffers` bindings in set 0 and a
    /// `push_constant_bytes` push-constant block (0 for none), for pipelines to share
    /// ([`Context::create_compute_pipeline_with_layout`]).
    pub fn create_pipeline_layout(
        &self,
        name: &str,
        storage_buffers: u32,
        push_constant_bytes: u32,
    ) -> Result<PipelineLayout, VkError> {
        let max_pc = self.limits().max_push_constants_size;
        if push_constant_bytes % 4 != 0 {
            return Err(VkError::InvalidArgument(format!(
                "`{name}`: push-constant size {push_constant_bytes} is not a multiple of 4"
            )));
        }
        if push_constant_bytes > max_pc {
            return Err(VkError::LimitExceeded(format!(
                "`{name}`: push-constant block of {push_constant_bytes} bytes exceeds maxPushConstantsSize {max_pc}"
            )));
        }
        let device = self.device();

        let bindings: Vec<vk::DescriptorSetLayoutBinding> = (0..storage_buffers)
            .map(|b| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(b)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        let set_info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings);
        // SAFETY: `bindings` outlives the call.
        let set_layout = unsafe { device.create_descriptor_set_layout(&set_info, None) }
            .op_with(|| format!("creating the descriptor-set layout of `{name}`"))?;

        let set_layouts = [set_layout];
        let ranges = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::COMPUTE)
            .offset(0)
            .size(push_constant_bytes)];
        let ranges: &[vk::PushConstantRange] = if push_constant_bytes > 0 { &ranges } else { &[] };
        let layout_info =
            vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts).push_constant_ranges(ranges);
        // SAFETY: arrays outlive the call.
        let raw = match unsafe { device.create_pipeline_layout(&layout_info, None) } {
            Ok(l) => l,
            Err(r) => {
                // SAFETY: unused.
                unsafe { device.destroy_descriptor_set_layout(set_layout, None) };
                return Err(VkError::from_vk(format!("creating the pipeline layout of `{name}`"), r));
            }
        };
        self.set_name(raw, name);
        self.set_name(set_layout, name);
        Ok(PipelineLayout { raw, set_layout, storage_buffers, push_constant_bytes, name: name.to_owned() })
    }

    /// Destroys a pipeline layout.
    ///
    /// # Safety
    /// No pipeline made with it may be alive ([`Context::destroy_pipeline`] them first), and no
    /// pending command buffer may use it.
    pub unsafe fn destroy_pipeline_layout(&self, layout: PipelineLayout) {
        // SAFETY: by the caller's guarantee nothing uses the layout any more.
        unsafe {
            self.device().destroy_pipeline_layout(layout.raw, None);
            self.device().destroy_descriptor_set_layout(layout.set_layout, None);
        }
    }

    /// Creates a compute pipeline from SPIR-V (entry point `main`) with `storage_buffers` bindings
    /// in set 0 and a `push_constant_bytes` push-constant block (0 for none), on a layout of its
    /// own.
    pub fn create_compute_pipeline(
        &self,
        name: &str,
        spirv: &[u8],
        storage_buffers: u32,
        push_constant_bytes: u32,
    ) -> Result<ComputePipeline, VkError> {
        let words = spirv_words(name, spirv)?;
        let layout = self.create_pipeline_layout(name, storage_buffers, push_constant_bytes)?;
        match self.pipeline_on(name, &words, &layout) {
            Ok(mut p) => {
                p.owns_layout = true;
                Ok(p)
            }
            Err(e) => {
                // SAFETY: no pipeline was made with the layout.
                unsafe { self.destroy_pipeline_layout(layout) };
                Err(e)
            }
        }
    }

    /// Creates a compute pipeline from SPIR-V (entry point `main`) on a shared `layout`, which
    /// must outlive it (see [`Context::destroy_pipeline_layout`]).
    pub fn create_compute_pipeline_with_layout(
        &self,
        name: &str,
        spirv: &[u8],
        layout: &PipelineLayout,
    ) -> Result<ComputePipeline, VkError> {
        let words = spirv_words(name, spirv)?;
        self.pipeline_on(name, &words, layout)
    }

    /// The pipeline of `words` on `layout` (not owning it).
    fn pipeline_on(&self, name: &str, words: &[u32], layout: &PipelineLayout) -> Result<ComputePipeline, VkError> {
        let device = self.device();
        let module_info = vk::ShaderModuleCreateInfo::default().code(words);
        // SAFETY: `words` is SPIR-V with a checked header and outlives the call.
        let module = unsafe { device.create_shader_module(&module_info, None) }
            .op_with(|| format!("creating the shader module of `{name}`"))?;
        let stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(c"main");
        let infos = [vk::ComputePipelineCreateInfo::default().stage(stage).layout(layout.raw)];
        // SAFETY: all handles alive; `infos` outlives the call.
        let created = unsafe { device.create_compute_pipelines(vk::PipelineCache::null(), &infos, None) };
        // The module is only needed while the pipeline is created.
        // SAFETY: no longer referenced.
        unsafe { device.destroy_shader_module(module, None) };
        let raw = match created {
            Ok(p) if !p.is_empty() => p[0],
            result => {
                let r = match result {
                    Err((_, r)) => r,
                    Ok(_) => vk::Result::ERROR_UNKNOWN,
                };
                return Err(VkError::from_vk(format!("creating compute pipeline `{name}`"), r));
            }
        };
        self.set_name(raw, name);
        let (storage_buffers, push_constant_bytes) = (layout.storage_buffers, layout.push_constant_bytes);
        tracing::debug!(name, storage_buffers, push_constant_bytes, layout = layout.name(), "compute pipeline created");
        Ok(ComputePipeline {
            raw,
            layout: layout.raw,
            set_layout: layout.set_layout,
            storage_buffers,
            push_constant_bytes,
            owns_layout: false,
            name: name.to_owned(),
        })
    }

    /// Destroys a pipeline (and its layout, unless that is shared).
    ///
    /// # Safety
    /// The device must no longer use the pipeline: command buffers that used it must have
    /// completed (a retired one only refers to it while executing).
    pub unsafe fn destroy_pipeline(&self, p: ComputePipeline) {
        // SAFETY: by the caller's guarantee no pending work uses it; a layout it owns is used by
        // no other pipeline.
        unsafe {
            self.device().destroy_pipeline(p.raw, None);
            if p.owns_layout {
                self.device().destroy_pipeline_layout(p.layout, None);
                self.device().destroy_descriptor_set_layout(p.set_layout, None);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spirv_checks() {
        assert!(spirv_words("x", &[]).is_err());
        assert!(spirv_words("x", &[3, 2, 0x23]).is_err());
        assert!(spirv_words("x", &[0, 0, 0, 0]).is_err());
        let ok = [0x03, 0x02, 0x23, 0x07, 0, 0, 1, 0];
        assert_eq!(spirv_words("x", &ok).ok(), Some(vec![SPIRV_MAGIC, 0x0001_0000]));
    }
}
