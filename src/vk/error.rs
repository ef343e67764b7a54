//! Typed errors of the Vulkan layer.
//!
//! Every failing Vulkan call is reported with the operation that failed, so a message read by a user
//! ("allocating the command buffer of `sweep`: out of device memory") says what was being done, not
//! only which `VkResult` came back.

use ash::vk;
use thiserror::Error;

/// An error from the Vulkan layer.
#[derive(Debug, Error)]
pub enum VkError {
    /// `libvulkan.so.1` could not be loaded at all.
    #[error(
        "the Vulkan loader could not be loaded ({0}); install the Debian packages `libvulkan1` and \
         `mesa-vulkan-drivers` (or your GPU vendor's Vulkan driver)"
    )]
    LoaderMissing(String),

    /// Validation was requested but `VK_LAYER_KHRONOS_validation` is not installed.
    #[error(
        "Vulkan validation was requested but the layer VK_LAYER_KHRONOS_validation is not installed; \
         install the Debian package `vulkan-validationlayers`, or turn validation off (LPM_VALIDATION=0)"
    )]
    ValidationLayerMissing,

    /// No physical device fits (none at all, a bad `LPM_DEVICE` index, or none with the features we need).
    #[error("no usable Vulkan device: {0}")]
    NoDevice(String),

    /// The chosen device lacks something lpm requires (API version, feature, queue).
    #[error("the Vulkan device `{device}` cannot run lpm: {reason}")]
    Unsupported { device: String, reason: String },

    /// A request would exceed a device limit; checked before any Vulkan call is made.
    #[error("device limit exceeded: {0}")]
    LimitExceeded(String),

    /// A request that is wrong regardless of the device (bad SPIR-V, range out of a buffer, ...).
    #[error("invalid request: {0}")]
    InvalidArgument(String),

    /// The device ran out of memory (host or device) during `op`.
    #[error("out of memory while {op} ({result})")]
    OutOfMemory { op: String, result: vk::Result },

    /// The device was lost; nothing more can be done with this context.
    #[error("the Vulkan device was lost while {op}")]
    DeviceLost { op: String },

    /// A wait ran out of time.
    #[error("timed out after {timeout_ns} ns waiting for timeline `{name}` to reach {value}")]
    Timeout { name: String, value: u64, timeout_ns: u64 },

    /// The memory allocator refused an allocation.
    #[error("allocating {size} bytes for `{name}`: {source}")]
    Allocation {
        name: String,
        size: u64,
        #[source]
        source: gpu_allocator::AllocationError,
    },

    /// Any other failing Vulkan call.
    #[error("Vulkan call failed while {op}: {result}")]
    Call { op: String, result: vk::Result },
}

impl VkError {
    /// Classifies a `vk::Result` returned while doing `op`.
    pub fn from_vk(op: impl Into<String>, result: vk::Result) -> Self {
        let op = op.into();
        match result {
            vk::Result::ERROR_OUT_OF_HOST_MEMORY
            | vk::Result::ERROR_OUT_OF_DEVICE_MEMORY
            | vk::Result::ERROR_OUT_OF_POOL_MEMORY => VkError::OutOfMemory { op, result },
            vk::Result::ERROR_DEVICE_LOST => VkError::DeviceLost { op },
            _ => VkError::Call { op, result },
        }
    }
}

/// Attaches the name of the operation to a raw `VkResult`.
pub(crate) trait VkResultExt<T> {
    /// `op` is a gerund phrase ("creating the command pool of `fill`").
    fn op(self, op: &str) -> Result<T, VkError>;
    /// Like [`VkResultExt::op`] but builds the phrase only on failure.
    fn op_with(self, op: impl FnOnce() -> String) -> Result<T, VkError>;
}

impl<T> VkResultExt<T> for Result<T, vk::Result> {
    fn op(self, op: &str) -> Result<T, VkError> {
        self.map_err(|r| VkError::from_vk(op, r))
    }
    fn op_with(self, op: impl FnOnce() -> String) -> Result<T, VkError> {
        self.map_err(|r| VkError::from_vk(op(), r))
    }
}
