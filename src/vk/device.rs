//! Physical device choice, queue families, and the logical device.
//!
//! lpm needs Vulkan ≥ 1.2 with `timelineSemaphore` (all ordering between submissions is by timeline
//! values) and `synchronization2` (core in 1.3, `VK_KHR_synchronization2` on 1.2 devices).
//! It uses one compute queue, and when the device has one, a second queue for transfers so uploads
//! of the next slice overlap the sweep of the current one.

use std::ffi::CStr;
use std::sync::{Mutex, MutexGuard};

use ash::vk;

use super::error::{VkError, VkResultExt};
use super::instance::{version_string, Instance};
use super::lock;

/// A device queue. Vulkan requires external synchronisation of `vkQueueSubmit*` on one queue, so
/// every submission takes `lock`.
pub struct Queue {
    raw: vk::Queue,
    family: u32,
    index: u32,
    lock: Mutex<()>,
}

impl Queue {
    /// The queue family index (what command pools and ownership transfers are keyed by).
    pub fn family(&self) -> u32 {
        self.family
    }
    /// The index of this queue inside its family.
    pub fn index(&self) -> u32 {
        self.index
    }
    /// The raw handle. Submitting to it directly bypasses the lock this layer takes around
    /// `vkQueueSubmit2`; use [`super::Recorder::submit`].
    pub fn raw(&self) -> vk::Queue {
        self.raw
    }
    /// Holds the queue for a submission (or a queue-level wait).
    pub(crate) fn lock(&self) -> MutexGuard<'_, ()> {
        lock(&self.lock)
    }
}

/// The device numbers the solver plans with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Largest range one storage-buffer binding may cover (lavapipe: 128 MiB).
    pub max_storage_buffer_range: u64,
    /// Largest dispatch, per dimension, in workgroups.
    pub max_workgroup_count: [u32; 3],
    /// Largest number of invocations in one workgroup.
    pub max_workgroup_invocations: u32,
    /// The default subgroup size (8 on lavapipe, 32 on NVIDIA): never assume a value.
    pub subgroup_size: u32,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period_ns: f32,
    /// Whether compute queues can write timestamps (`timestampComputeAndGraphics`, valid bits on
    /// the compute family) and queries can be reset from the host (`hostQueryReset`, enabled).
    pub timestamps_supported: bool,
    /// Whether the transfer (and download) queues' family writes timestamps too
    /// (`timestampValidBits` > 0 there); where not, transfers go untimed.
    pub transfer_timestamps: bool,
    /// The memory lpm may plan with on the device: the largest DEVICE_LOCAL heap (an NVIDIA BAR
    /// window or a second small heap is never added to it), capped by what `VK_EXT_memory_budget`
    /// says this process may use of it where the device has that extension.
    pub device_local_heap_bytes: u64,
    /// A CPU implementation (lavapipe, SwiftShader): memory is host memory, "GPU-only" is a fiction.
    pub is_cpu: bool,
    /// Required alignment of a storage-buffer binding's offset.
    pub min_storage_buffer_offset_alignment: u64,
    /// Largest push-constant block in bytes.
    pub max_push_constants_size: u32,
    /// `shaderFloat64` and `shaderInt64` (both enabled when the device has them): the
    /// device-resident mode's end-of-order passes need them (`solver::gpu::end_of_order`).
    pub float64: bool,
}

/// synchronization2 is reached through core 1.3 entry points or the KHR extension's; the rest of the
/// layer calls these and does not care which.
pub(crate) enum Sync2 {
    Core,
    Khr(ash::khr::synchronization2::Device),
}

impl Sync2 {
    /// # Safety
    /// As `vkCmdPipelineBarrier2`.
    pub(crate) unsafe fn cmd_pipeline_barrier2(
        &self,
        device: &ash::Device,
        cb: vk::CommandBuffer,
        info: &vk::DependencyInfo<'_>,
    ) {
        match self {
            Sync2::Core => unsafe { device.cmd_pipeline_barrier2(cb, info) },
            Sync2::Khr(k) => unsafe { k.cmd_pipeline_barrier2(cb, info) },
        }
    }
    /// # Safety
    /// As `vkCmdWriteTimestamp2`.
    pub(crate) unsafe fn cmd_write_timestamp2(
        &self,
        device: &ash::Device,
        cb: vk::CommandBuffer,
        stage: vk::PipelineStageFlags2,
        pool: vk::QueryPool,
        query: u32,
    ) {
        match self {
            Sync2::Core => unsafe { device.cmd_write_timestamp2(cb, stage, pool, query) },
            Sync2::Khr(k) => unsafe { k.cmd_write_timestamp2(cb, stage, pool, query) },
        }
    }
    /// # Safety
    /// As `vkQueueSubmit2`; the caller holds the queue's lock.
    pub(crate) unsafe fn queue_submit2(
        &self,
        device: &ash::Device,
        queue: vk::Queue,
        submits: &[vk::SubmitInfo2<'_>],
    ) -> Result<(), vk::Result> {
        match self {
            Sync2::Core => unsafe { device.queue_submit2(queue, submits, vk::Fence::null()) },
            Sync2::Khr(k) => unsafe { k.queue_submit2(queue, submits, vk::Fence::null()) },
        }
    }
}

/// What device selection produced; Context takes ownership of every part.
pub(crate) struct DeviceParts {
    pub(crate) physical: vk::PhysicalDevice,
    pub(crate) device: ash::Device,
    pub(crate) compute: Queue,
    pub(crate) transfer: Option<Queue>,
    pub(crate) download: Option<Queue>,
    pub(crate) sync2: Sync2,
    pub(crate) name: String,
    pub(crate) driver_description: String,
    pub(crate) driver_id: vk::DriverId,
    pub(crate) limits: Limits,
}

/// Everything we look at to decide whether and how to use a physical device.
struct Candidate {
    physical: vk::PhysicalDevice,
    name: String,
    device_type: vk::PhysicalDeviceType,
    api_version: u32,
}

fn type_rank(t: vk::PhysicalDeviceType) -> u32 {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 3,
        _ => 4,
    }
}

/// Picks a physical device (`device_index` if given, else the best type that is usable), then creates
/// the logical device and fetches the queues.
pub(crate) fn create(
    instance: &Instance,
    device_index: Option<usize>,
    force_single_queue: bool,
) -> Result<DeviceParts, VkError> {
    let inst = &instance.raw;
    // SAFETY: plain query on a live instance.
    let physicals = unsafe { inst.enumerate_physical_devices() }.op("listing the Vulkan devices")?;
    if physicals.is_empty() {
        return Err(VkError::NoDevice(
            "the loader found no Vulkan device; install `mesa-vulkan-drivers` for the CPU device (lavapipe) or your GPU's driver".into(),
        ));
    }
    let candidates: Vec<Candidate> = physicals
        .iter()
        .map(|&physical| {
            // SAFETY: `physical` came from this instance.
            let props = unsafe { inst.get_physical_device_properties(physical) };
            Candidate {
                physical,
                name: props.device_name_as_c_str().map(|c| c.to_string_lossy().into_owned()).unwrap_or_default(),
                device_type: props.device_type,
                api_version: props.api_version,
            }
        })
        .collect();
    for (i, c) in candidates.iter().enumerate() {
        tracing::debug!(index = i, name = %c.name, kind = ?c.device_type, api = %version_string(c.api_version), "Vulkan device found");
    }

    let chosen = match device_index {
        Some(i) => {
            let c = candidates.get(i).ok_or_else(|| {
                let names: Vec<String> =
                    candidates.iter().enumerate().map(|(i, c)| format!("{i}: {}", c.name)).collect();
                VkError::NoDevice(format!(
                    "LPM_DEVICE={i} but there are only {} devices ({})",
                    candidates.len(),
                    names.join(", ")
                ))
            })?;
            // An explicit choice that cannot work is an error, not a silent fallback.
            check_support(instance, c)?;
            c
        }
        None => {
            let mut order: Vec<&Candidate> = candidates.iter().collect();
            order.sort_by_key(|c| type_rank(c.device_type));
            let mut reasons = Vec::new();
            let mut found = None;
            for c in order {
                match check_support(instance, c) {
                    Ok(()) => {
                        found = Some(c);
                        break;
                    }
                    Err(e) => reasons.push(e.to_string()),
                }
            }
            found.ok_or_else(|| VkError::NoDevice(reasons.join("; ")))?
        }
    };
    tracing::info!(name = %chosen.name, kind = ?chosen.device_type, explicit = device_index.is_some(), "Vulkan device chosen");
    open(instance, chosen, force_single_queue)
}

/// The effective API version (device's, capped by the instance's).
fn effective_api(instance: &Instance, c: &Candidate) -> u32 {
    c.api_version.min(instance.api_version)
}

fn device_extensions(instance: &Instance, physical: vk::PhysicalDevice) -> Result<Vec<String>, VkError> {
    // SAFETY: plain query.
    let exts =
        unsafe { instance.raw.enumerate_device_extension_properties(physical) }.op("listing device extensions")?;
    Ok(exts.iter().filter_map(|e| e.extension_name_as_c_str().ok().map(|n| n.to_string_lossy().into_owned())).collect())
}

fn has_ext(exts: &[String], name: &CStr) -> bool {
    let name = name.to_string_lossy();
    exts.iter().any(|e| *e == name)
}

fn check_support(instance: &Instance, c: &Candidate) -> Result<(), VkError> {
    let unsupported = |reason: String| VkError::Unsupported { device: c.name.clone(), reason };
    let api = effective_api(instance, c);
    if api < vk::API_VERSION_1_2 {
        return Err(unsupported(format!(
            "it supports Vulkan {} only; lpm needs 1.2 or newer",
            version_string(c.api_version)
        )));
    }
    if api < vk::API_VERSION_1_3
        && !has_ext(&device_extensions(instance, c.physical)?, ash::khr::synchronization2::NAME)
    {
        return Err(unsupported("it has neither Vulkan 1.3 nor VK_KHR_synchronization2".into()));
    }
    let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut sync2 = vk::PhysicalDeviceSynchronization2Features::default();
    let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f12).push_next(&mut sync2);
    // SAFETY: the chained structs are valid for a ≥1.2 device (sync2 checked above).
    unsafe { instance.raw.get_physical_device_features2(c.physical, &mut f2) };
    if f12.timeline_semaphore == vk::FALSE {
        return Err(unsupported("the timelineSemaphore feature is missing".into()));
    }
    if sync2.synchronization2 == vk::FALSE {
        return Err(unsupported("the synchronization2 feature is missing".into()));
    }
    // SAFETY: plain query.
    let families = unsafe { instance.raw.get_physical_device_queue_family_properties(c.physical) };
    if !families.iter().any(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE)) {
        return Err(unsupported("it has no compute queue".into()));
    }
    Ok(())
}

/// The queues a device is opened with, as (family, index) pairs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct QueueChoice {
    compute: u32,
    /// A queue beside the compute queue for transfers (uploads, and downloads without `download`).
    transfer: Option<(u32, u32)>,
    /// A second transfer queue, for downloads, so that a slice comes home while the next goes up
    /// (NVIDIA: the second copy engine).
    download: Option<(u32, u32)>,
}

/// Chooses the compute family and the transfer queues: a dedicated transfer family (copy engines run
/// beside compute) is best, a second queue of the compute family next, else none; downloads get the
/// next queue of the transfer queue's family when it has one more.
fn choose_queues(families: &[vk::QueueFamilyProperties], force_single_queue: bool) -> Option<QueueChoice> {
    let compute = families.iter().position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE))? as u32;
    if force_single_queue {
        return Some(QueueChoice { compute, transfer: None, download: None });
    }
    let dedicated = families.iter().position(|f| {
        f.queue_count > 0
            && f.queue_flags.contains(vk::QueueFlags::TRANSFER)
            && !f.queue_flags.intersects(vk::QueueFlags::COMPUTE | vk::QueueFlags::GRAPHICS)
    });
    let transfer = match dedicated {
        Some(fam) => Some((fam as u32, 0)),
        None if families[compute as usize].queue_count >= 2 => Some((compute, 1)),
        None => None,
    };
    let download =
        transfer.and_then(|(fam, index)| (families[fam as usize].queue_count > index + 1).then_some((fam, index + 1)));
    Some(QueueChoice { compute, transfer, download })
}

fn open(instance: &Instance, c: &Candidate, force_single_queue: bool) -> Result<DeviceParts, VkError> {
    let inst = &instance.raw;
    let api = effective_api(instance, c);
    // SAFETY: plain query.
    let families = unsafe { inst.get_physical_device_queue_family_properties(c.physical) };
    let choice = choose_queues(&families, force_single_queue)
        .ok_or_else(|| VkError::Unsupported { device: c.name.clone(), reason: "it has no compute queue".into() })?;
    let compute_family = choice.compute;

    // Per family, the queues asked for are its first ones (the choice takes them in order): one
    // priority each. Both vectors outlive vkCreateDevice.
    let mut counts: Vec<(u32, usize)> = Vec::new();
    for (family, index) in [Some((compute_family, 0)), choice.transfer, choice.download].into_iter().flatten() {
        match counts.iter_mut().find(|(f, _)| *f == family) {
            Some((_, n)) => *n = (*n).max(index as usize + 1),
            None => counts.push((family, index as usize + 1)),
        }
    }
    let priorities: Vec<Vec<f32>> = counts.iter().map(|&(_, n)| vec![1.0; n]).collect();
    let queue_infos: Vec<vk::DeviceQueueCreateInfo> = counts
        .iter()
        .zip(&priorities)
        .map(|(&(family, _), p)| vk::DeviceQueueCreateInfo::default().queue_family_index(family).queue_priorities(p))
        .collect();

    let use_khr_sync2 = api < vk::API_VERSION_1_3;
    let mut extensions: Vec<*const std::ffi::c_char> = Vec::new();
    if use_khr_sync2 {
        extensions.push(ash::khr::synchronization2::NAME.as_ptr());
    }
    // hostQueryReset (core 1.2, optional): the profiler resets its timestamps from the host, since
    // vkCmdResetQueryPool is not allowed on a transfer-only queue, where uploads are recorded.
    let host_query_reset = {
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
        let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f12);
        // SAFETY: valid chain for a ≥1.2 device.
        unsafe { inst.get_physical_device_features2(c.physical, &mut f2) };
        f12.host_query_reset == vk::TRUE
    };
    let mut f12 =
        vk::PhysicalDeviceVulkan12Features::default().timeline_semaphore(true).host_query_reset(host_query_reset);
    let mut sync2_features = vk::PhysicalDeviceSynchronization2Features::default().synchronization2(true);
    // f64 and i64 in shaders where the device has both (the exact end-of-order passes use them).
    // SAFETY: plain query.
    let supported = unsafe { inst.get_physical_device_features(c.physical) };
    let float64 = supported.shader_float64 == vk::TRUE && supported.shader_int64 == vk::TRUE;
    let features = vk::PhysicalDeviceFeatures::default().shader_float64(float64).shader_int64(float64);
    let create_info = vk::DeviceCreateInfo::default()
        .queue_create_infos(&queue_infos)
        .enabled_extension_names(&extensions)
        .enabled_features(&features)
        .push_next(&mut f12)
        .push_next(&mut sync2_features);
    // SAFETY: all pointers in create_info point to locals alive for the call; support was checked.
    let device = unsafe { inst.create_device(c.physical, &create_info, None) }
        .op_with(|| format!("creating the logical device on `{}`", c.name))?;

    let get_queue = |family: u32, index: u32| {
        // SAFETY: this (family, index) was requested in queue_infos.
        let raw = unsafe { device.get_device_queue(family, index) };
        Queue { raw, family, index, lock: Mutex::new(()) }
    };
    let compute = get_queue(compute_family, 0);
    let transfer = choice.transfer.map(|(fam, idx)| get_queue(fam, idx));
    let download = choice.download.map(|(fam, idx)| get_queue(fam, idx));
    let sync2 =
        if use_khr_sync2 { Sync2::Khr(ash::khr::synchronization2::Device::new(inst, &device)) } else { Sync2::Core };

    // Properties for limits and reports.
    let mut p11 = vk::PhysicalDeviceVulkan11Properties::default();
    let mut driver = vk::PhysicalDeviceDriverProperties::default();
    let mut p2 = vk::PhysicalDeviceProperties2::default().push_next(&mut p11).push_next(&mut driver);
    // SAFETY: valid chain for a ≥1.2 device.
    unsafe { inst.get_physical_device_properties2(c.physical, &mut p2) };
    let props = p2.properties;
    // SAFETY: plain query.
    let mem = unsafe { inst.get_physical_device_memory_properties(c.physical) };
    let memory_budget = has_ext(&device_extensions(instance, c.physical)?, ash::ext::memory_budget::NAME).then(|| {
        let mut budget = vk::PhysicalDeviceMemoryBudgetPropertiesEXT::default();
        let mut m2 = vk::PhysicalDeviceMemoryProperties2::default().push_next(&mut budget);
        // SAFETY: the device has the extension, so the chained struct is valid to query.
        unsafe { inst.get_physical_device_memory_properties2(c.physical, &mut m2) };
        budget.heap_budget
    });
    let device_local_heap_bytes = planning_heap_bytes(&mem, memory_budget.as_ref());
    let l = props.limits;
    let limits = Limits {
        max_storage_buffer_range: u64::from(l.max_storage_buffer_range),
        max_workgroup_count: l.max_compute_work_group_count,
        max_workgroup_invocations: l.max_compute_work_group_invocations,
        subgroup_size: p11.subgroup_size,
        timestamp_period_ns: l.timestamp_period,
        timestamps_supported: host_query_reset
            && l.timestamp_compute_and_graphics == vk::TRUE
            && families[compute_family as usize].timestamp_valid_bits > 0,
        transfer_timestamps: [choice.transfer, choice.download]
            .into_iter()
            .flatten()
            .all(|(family, _)| families[family as usize].timestamp_valid_bits > 0),
        device_local_heap_bytes,
        is_cpu: props.device_type == vk::PhysicalDeviceType::CPU,
        min_storage_buffer_offset_alignment: l.min_storage_buffer_offset_alignment,
        max_push_constants_size: l.max_push_constants_size,
        float64,
    };
    let driver_name = driver.driver_name_as_c_str().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let driver_info = driver.driver_info_as_c_str().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let driver_description = format!(
        "{driver_name} {driver_info} (Vulkan {}, driver version {:#x})",
        version_string(props.api_version),
        props.driver_version
    );
    tracing::info!(
        compute_family,
        transfer = ?transfer.as_ref().map(|q| (q.family, q.index)),
        download = ?download.as_ref().map(|q| (q.family, q.index)),
        ?limits,
        driver = %driver_description,
        "Vulkan device opened"
    );
    Ok(DeviceParts {
        physical: c.physical,
        device,
        compute,
        transfer,
        download,
        sync2,
        name: c.name.clone(),
        driver_description,
        driver_id: driver.driver_id,
        limits,
    })
}

/// The bytes of device memory to plan with: the largest DEVICE_LOCAL heap, capped by its
/// `VK_EXT_memory_budget` budget when one is given (a budget of 0 means the driver gave none).
/// Summing the heaps would count an NVIDIA BAR window (a second, small DEVICE_LOCAL heap that is
/// the same memory seen through the bus) twice.
fn planning_heap_bytes(mem: &vk::PhysicalDeviceMemoryProperties, budgets: Option<&[u64; vk::MAX_MEMORY_HEAPS]>) -> u64 {
    (0..mem.memory_heap_count as usize)
        .filter(|&i| mem.memory_heaps[i].flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
        .map(|i| {
            let size = mem.memory_heaps[i].size;
            match budgets.map(|b| b[i]) {
                Some(budget) if budget > 0 => size.min(budget),
                _ => size,
            }
        })
        .max()
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fam(flags: vk::QueueFlags, count: u32) -> vk::QueueFamilyProperties {
        vk::QueueFamilyProperties { queue_flags: flags, queue_count: count, ..Default::default() }
    }

    #[test]
    fn queue_choice() {
        let gct = vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE | vk::QueueFlags::TRANSFER;
        let choice = |compute, transfer, download| Some(QueueChoice { compute, transfer, download });
        // lavapipe: one family, one queue.
        assert_eq!(choose_queues(&[fam(gct, 1)], false), choice(0, None, None));
        // Two queues in the only family: the second one transfers; a third one downloads.
        assert_eq!(choose_queues(&[fam(gct, 2)], false), choice(0, Some((0, 1)), None));
        assert_eq!(choose_queues(&[fam(gct, 3)], false), choice(0, Some((0, 1)), Some((0, 2))));
        // NVIDIA-like: dedicated transfer family preferred over a 2nd compute queue; its second
        // queue downloads.
        let fams = [
            fam(gct, 16),
            fam(vk::QueueFlags::TRANSFER, 2),
            fam(vk::QueueFlags::COMPUTE | vk::QueueFlags::TRANSFER, 8),
        ];
        assert_eq!(choose_queues(&fams, false), choice(0, Some((1, 0)), Some((1, 1))));
        assert_eq!(choose_queues(&fams, true), choice(0, None, None));
        // One copy engine: uploads and downloads share it.
        let one = [fam(gct, 16), fam(vk::QueueFlags::TRANSFER, 1)];
        assert_eq!(choose_queues(&one, false), choice(0, Some((1, 0)), None));
        assert_eq!(choose_queues(&[fam(vk::QueueFlags::GRAPHICS, 1)], false), None);
    }

    #[test]
    fn the_planning_heap_is_the_largest_device_local_one_capped_by_its_budget() {
        let mut mem = vk::PhysicalDeviceMemoryProperties { memory_heap_count: 3, ..Default::default() };
        let gib = 1u64 << 30;
        mem.memory_heaps[0] = vk::MemoryHeap { size: 80 * gib, flags: vk::MemoryHeapFlags::DEVICE_LOCAL };
        mem.memory_heaps[1] = vk::MemoryHeap { size: 64 * gib, flags: vk::MemoryHeapFlags::empty() };
        // An NVIDIA BAR window: the same memory through the bus, never added to the first.
        mem.memory_heaps[2] = vk::MemoryHeap { size: gib / 4, flags: vk::MemoryHeapFlags::DEVICE_LOCAL };
        assert_eq!(planning_heap_bytes(&mem, None), 80 * gib);
        let mut budgets = [0u64; vk::MAX_MEMORY_HEAPS];
        budgets[0] = 70 * gib;
        budgets[2] = gib / 8;
        assert_eq!(planning_heap_bytes(&mem, Some(&budgets)), 70 * gib);
        // A budget of 0 means the driver gave none: the heap's size stands.
        budgets[0] = 0;
        assert_eq!(planning_heap_bytes(&mem, Some(&budgets)), 80 * gib);
    }
}
