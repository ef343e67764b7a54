//! [`Context`]: the owner of the instance, device, queues and allocator, and of the list of retired
//! resources waiting for the GPU to finish with them.

use std::ffi::CString;
use std::mem::ManuallyDrop;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};

use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use gpu_allocator::{AllocationSizes, AllocatorDebugSettings};

use super::device::{self, Limits, Queue, Sync2};
use super::error::VkError;
use super::instance::Instance;
use super::lock;
use super::retire::Retired;

/// How to open the device.
#[derive(Clone, Debug)]
pub struct ContextOptions {
    /// Enable the Khronos validation layer with synchronization validation.
    pub validation: bool,
    /// Index into the loader's device list; `None` picks the best device (discrete > integrated >
    /// virtual > cpu).
    pub device_index: Option<usize>,
    /// Use the compute queue for everything even if a separate transfer queue exists.
    pub force_single_queue: bool,
}

impl Default for ContextOptions {
    /// No validation, the device chosen automatically, two queues where the device has them. The
    /// library reads no environment variable: the CLI fills these from `--validation` and
    /// `--device` (or `LPM_VALIDATION` and `LPM_DEVICE`, through clap).
    fn default() -> Self {
        ContextOptions { validation: false, device_index: None, force_single_queue: false }
    }
}

/// The Vulkan context. Shared as `Arc<Context>`; all methods take `&self`.
///
/// Fields are dropped after `Drop::drop` has idled the device, freed retired resources, dropped the
/// allocator and destroyed the device; `instance` is last so the messenger sees all of it.
pub struct Context {
    pub(crate) garbage: Mutex<Vec<Retired>>,
    /// `ManuallyDrop` because the allocator must be dropped before the device is destroyed.
    allocator: ManuallyDrop<Mutex<Allocator>>,
    pub(crate) allocated: AtomicU64,
    pub(crate) peak_allocated: AtomicU64,
    debug_utils: Option<ash::ext::debug_utils::Device>,
    pub(crate) sync2: Sync2,
    compute: Queue,
    transfer: Option<Queue>,
    download: Option<Queue>,
    device: ash::Device,
    physical: vk::PhysicalDevice,
    name: String,
    driver_description: String,
    driver_id: vk::DriverId,
    limits: Limits,
    instance: Instance,
}

impl Context {
    /// Creates the instance, picks and opens a device, and creates the allocator.
    pub fn new(opts: ContextOptions) -> Result<Arc<Context>, VkError> {
        let instance = Instance::new(opts.validation)?;
        let parts = device::create(&instance, opts.device_index, opts.force_single_queue)?;
        // We report leaks ourselves through tracing (gpu-allocator logs through `log`).
        let mut debug_settings = AllocatorDebugSettings::default();
        debug_settings.log_leaks_on_shutdown = false;
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.raw.clone(),
            device: parts.device.clone(),
            physical_device: parts.physical,
            debug_settings,
            buffer_device_address: false,
            allocation_sizes: AllocationSizes::default(),
        });
        let allocator = match allocator {
            Ok(a) => a,
            Err(source) => {
                // SAFETY: nothing was created from the device yet.
                unsafe { parts.device.destroy_device(None) };
                return Err(VkError::Allocation { name: "allocator".into(), size: 0, source });
            }
        };
        let debug_utils =
            instance.validation_enabled().then(|| ash::ext::debug_utils::Device::new(&instance.raw, &parts.device));
        Ok(Arc::new(Context {
            garbage: Mutex::new(Vec::new()),
            allocator: ManuallyDrop::new(Mutex::new(allocator)),
            allocated: AtomicU64::new(0),
            peak_allocated: AtomicU64::new(0),
            debug_utils,
            sync2: parts.sync2,
            compute: parts.compute,
            transfer: parts.transfer,
            download: parts.download,
            device: parts.device,
            physical: parts.physical,
            name: parts.name,
            driver_description: parts.driver_description,
            driver_id: parts.driver_id,
            limits: parts.limits,
            instance,
        }))
    }

    /// The logical device, for calls this layer does not wrap.
    pub fn device(&self) -> &ash::Device {
        &self.device
    }
    /// The loaded Vulkan entry points (kept alive as long as the instance: it owns the loader library).
    pub fn entry(&self) -> &ash::Entry {
        &self.instance.entry
    }
    /// The instance.
    pub fn instance(&self) -> &ash::Instance {
        &self.instance.raw
    }
    /// The physical device.
    pub fn physical_device(&self) -> vk::PhysicalDevice {
        self.physical
    }
    /// The device name as the driver reports it, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)".
    pub fn device_name(&self) -> &str {
        &self.name
    }
    /// Driver name, driver info and API version, for reports.
    pub fn driver_description(&self) -> String {
        self.driver_description.clone()
    }
    /// The driver (to tell lavapipe's quirks apart from real behaviour).
    pub fn driver_id(&self) -> vk::DriverId {
        self.driver_id
    }
    /// The limits the solver plans with.
    pub fn limits(&self) -> Limits {
        self.limits
    }
    /// The queue for compute work (and transfers when there is no separate transfer queue).
    pub fn compute_queue(&self) -> &Queue {
        &self.compute
    }
    /// A queue distinct from the compute queue, if the device has one (never on lavapipe).
    pub fn transfer_queue(&self) -> Option<&Queue> {
        self.transfer.as_ref()
    }
    /// A second queue beside the transfer queue, in its family, for downloads, if the device has
    /// one (NVIDIA: the second copy engine; never on lavapipe).
    pub fn download_queue(&self) -> Option<&Queue> {
        self.download.as_ref()
    }
    /// The queue downloads go to: the download queue, else the transfer queue, else the compute
    /// queue (then transfers are a second submission stream on it, ordered by timelines).
    pub fn download_queue_or_fallback(&self) -> &Queue {
        self.download.as_ref().or(self.transfer.as_ref()).unwrap_or(&self.compute)
    }
    /// The queue uploads go to: the transfer queue, else the compute queue.
    pub fn upload_queue_or_fallback(&self) -> &Queue {
        self.transfer.as_ref().unwrap_or(&self.compute)
    }
    /// The queue families buffers may be used on (one or two distinct indices).
    pub(crate) fn queue_families(&self) -> Vec<u32> {
        let mut f = vec![self.compute.family()];
        if let Some(t) = &self.transfer {
            if t.family() != self.compute.family() {
                f.push(t.family());
            }
        }
        f
    }
    /// Every ERROR-severity validation message seen so far (always empty with validation off).
    pub fn validation_messages(&self) -> Vec<String> {
        self.instance.error_messages()
    }
    /// Whether the validation layer is on.
    pub fn validation_enabled(&self) -> bool {
        self.instance.validation_enabled()
    }

    pub(crate) fn allocator(&self) -> std::sync::MutexGuard<'_, Allocator> {
        lock(&self.allocator)
    }

    /// Names an object for validation messages and debuggers (no-op without validation).
    pub(crate) fn set_name<H: vk::Handle>(&self, handle: H, name: &str) {
        let Some(du) = &self.debug_utils else { return };
        let cname = CString::new(name.replace('\0', " ")).unwrap_or_default();
        let info = vk::DebugUtilsObjectNameInfoEXT::default().object_handle(handle).object_name(&cname);
        // SAFETY: the handle is a live object of this device; cname outlives the call.
        if let Err(e) = unsafe { du.set_debug_utils_object_name(&info) } {
            tracing::debug!(name, %e, "could not name a Vulkan object");
        }
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: we own the device; after idling nothing is in flight, so every retired resource
        // can be freed, then the allocator dropped, then the device destroyed.
        unsafe {
            if let Err(e) = self.device.device_wait_idle() {
                tracing::error!(%e, "waiting for the device to idle at shutdown");
            }
            let retired = std::mem::take(&mut *lock(&self.garbage));
            for r in retired {
                self.free_now(r.item);
            }
            let report = self.allocator().generate_report();
            for a in &report.allocations {
                tracing::warn!(name = %a.name, size = a.size, "GPU memory leaked: allocation still alive when the context was dropped");
            }
            ManuallyDrop::drop(&mut self.allocator);
            self.device.destroy_device(None);
        }
        let errors = self.instance.error_messages();
        if !errors.is_empty() {
            tracing::warn!(count = errors.len(), "Vulkan validation reported errors during this run");
        }
    }
}
