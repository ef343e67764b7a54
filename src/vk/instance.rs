//! The Vulkan entry points, the instance, and (with validation on) the Khronos validation layer with
//! synchronization validation and a debug-utils messenger.
//!
//! The messenger forwards warnings to `tracing` and also records every ERROR-severity message, so
//! tests can assert that a whole run was validation-clean instead of scanning logs.

use std::ffi::{c_void, CStr};
use std::sync::Mutex;

use ash::vk;

use super::error::{VkError, VkResultExt};
use super::lock;

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// What the debug callback writes into. Boxed so its address stays fixed while the messenger
/// (which holds a raw pointer to it) is alive.
#[derive(Default)]
pub(crate) struct DebugState {
    pub(crate) errors: Mutex<Vec<String>>,
}

/// Owns the entry, the instance and the messenger; destroys them in that reverse order on drop.
pub(crate) struct Instance {
    pub(crate) entry: ash::Entry,
    pub(crate) raw: ash::Instance,
    /// The instance's highest usable API version (min of loader and what we asked for).
    pub(crate) api_version: u32,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    /// Must outlive `debug`; dropped after it because `Drop::drop` destroys the messenger first.
    pub(crate) debug_state: Box<DebugState>,
}

impl Instance {
    pub(crate) fn new(validation: bool) -> Result<Self, VkError> {
        // SAFETY: loading the system loader library; we trust libvulkan.so.1 to be a Vulkan loader.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| VkError::LoaderMissing(e.to_string()))?;

        // SAFETY: plain query on a loaded entry.
        let loader_version = unsafe { entry.try_enumerate_instance_version() }
            .op("querying the instance version")?
            .unwrap_or(vk::API_VERSION_1_0);
        if loader_version < vk::API_VERSION_1_2 {
            return Err(VkError::NoDevice(format!(
                "the Vulkan loader only supports API {}; lpm needs Vulkan 1.2 or newer",
                version_string(loader_version)
            )));
        }
        // Ask for 1.3 (core synchronization2); devices that only have 1.2 still work through the
        // KHR extension, see device.rs.
        let api_version = loader_version.min(vk::API_VERSION_1_3);

        let mut layers: Vec<*const std::ffi::c_char> = Vec::new();
        let mut extensions: Vec<*const std::ffi::c_char> = Vec::new();
        if validation {
            // SAFETY: plain query.
            let available = unsafe { entry.enumerate_instance_layer_properties() }.op("listing the instance layers")?;
            let has_layer = available.iter().any(|l| l.layer_name_as_c_str().is_ok_and(|n| n == VALIDATION_LAYER));
            if !has_layer {
                return Err(VkError::ValidationLayerMissing);
            }
            layers.push(VALIDATION_LAYER.as_ptr());
            // VK_EXT_validation_features is provided by the layer itself; VK_EXT_debug_utils by the
            // loader (and the layer). Both are required for what validation is for here.
            // SAFETY: plain query.
            let layer_exts = unsafe { entry.enumerate_instance_extension_properties(Some(VALIDATION_LAYER)) }
                .op("listing the validation layer's extensions")?;
            let has = |name: &CStr| layer_exts.iter().any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == name));
            if !has(ash::ext::validation_features::NAME) || !has(ash::ext::debug_utils::NAME) {
                return Err(VkError::ValidationLayerMissing);
            }
            extensions.push(ash::ext::validation_features::NAME.as_ptr());
            extensions.push(ash::ext::debug_utils::NAME.as_ptr());
        }

        let app_info = vk::ApplicationInfo::default()
            .application_name(c"lpm")
            .application_version(1)
            .engine_name(c"lpm")
            .api_version(api_version);

        let debug_state = Box::<DebugState>::default();
        let user_data = &*debug_state as *const DebugState as *mut c_void;
        // Sync validation catches missing barriers and semaphore waits, the bugs that matter in a
        // streamer; best practices stays off (it warns about things that are deliberate here).
        let enabled_features = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
        let disabled_features: [vk::ValidationFeatureDisableEXT; 0] = [];
        let mut validation_features = vk::ValidationFeaturesEXT::default()
            .enabled_validation_features(&enabled_features)
            .disabled_validation_features(&disabled_features);
        let mut messenger_info = messenger_create_info(user_data);

        let mut create_info = vk::InstanceCreateInfo::default()
            .application_info(&app_info)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&extensions);
        if validation {
            // The messenger in the chain also reports problems of vkCreateInstance/vkDestroyInstance.
            create_info = create_info.push_next(&mut validation_features).push_next(&mut messenger_info);
        }

        // SAFETY: every pointer in create_info points to a local that outlives this call.
        let raw = unsafe { entry.create_instance(&create_info, None) }.op("creating the Vulkan instance")?;

        let debug = if validation {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &raw);
            let info = messenger_create_info(user_data);
            // SAFETY: `user_data` points into `debug_state`, which this struct owns and keeps alive
            // until after the messenger is destroyed.
            match unsafe { loader.create_debug_utils_messenger(&info, None) } {
                Ok(m) => Some((loader, m)),
                Err(r) => {
                    // SAFETY: nothing else was created from this instance yet.
                    unsafe { raw.destroy_instance(None) };
                    return Err(VkError::from_vk("creating the debug messenger", r));
                }
            }
        } else {
            None
        };

        tracing::info!(
            api = %version_string(api_version),
            validation,
            "Vulkan instance created"
        );
        Ok(Instance { entry, raw, api_version, debug, debug_state })
    }

    pub(crate) fn validation_enabled(&self) -> bool {
        self.debug.is_some()
    }

    pub(crate) fn error_messages(&self) -> Vec<String> {
        lock(&self.debug_state.errors).clone()
    }
}

impl Drop for Instance {
    fn drop(&mut self) {
        // SAFETY: the owner (Context) has destroyed the device and everything made from it before
        // this runs; the messenger goes before the instance it belongs to.
        unsafe {
            if let Some((loader, messenger)) = self.debug.take() {
                loader.destroy_debug_utils_messenger(messenger, None);
            }
            self.raw.destroy_instance(None);
        }
    }
}

fn messenger_create_info<'a>(user_data: *mut c_void) -> vk::DebugUtilsMessengerCreateInfoEXT<'a> {
    vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR)
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(debug_callback))
        .user_data(user_data)
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user_data: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the layer passes a valid callback-data pointer (or null, handled) for the call's duration.
    let message = unsafe { data.as_ref() }
        .and_then(|d| unsafe { d.message_as_c_str() })
        .map(|m| m.to_string_lossy().into_owned())
        .unwrap_or_else(|| "(no message)".to_owned());
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        tracing::error!(target: "lpm::vk::validation", ?types, "{message}");
        // SAFETY: user_data is the DebugState owned by Instance, alive while the messenger is.
        if let Some(state) = unsafe { (user_data as *const DebugState).as_ref() } {
            lock(&state.errors).push(message);
        }
    } else {
        tracing::warn!(target: "lpm::vk::validation", ?types, "{message}");
    }
    // Never abort the call that triggered the message: we want to see the real behaviour.
    vk::FALSE
}

/// "1.3.230" from a packed version number.
pub(crate) fn version_string(v: u32) -> String {
    format!("{}.{}.{}", vk::api_version_major(v), vk::api_version_minor(v), vk::api_version_patch(v))
}
