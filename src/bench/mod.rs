//! `lpm bench`: throughput measurements that print JSON, the time-against-error study
//! ([`accuracy`]) and the grid-refinement study ([`refine`]).
//!
//! `stream` runs a few scattering orders of a scene on the GPU backend with every upload, compute
//! and download submission bracketed by GPU timestamps, and reports per order the time in each, the
//! fraction of transfer time hidden behind compute, bytes moved per second each way, and
//! voxel·direction updates per second. On a CPU Vulkan device (lavapipe) transfers and compute run
//! on the same cores one after the other, so the overlap figures mean nothing there: the report
//! says so.

pub mod accuracy;
mod accuracy_outputs;
pub mod refine;
mod refine_measure;
mod refine_outputs;
pub mod refine_scene;

use crate::job::JobError;
use crate::scene::Scene;
use crate::solver::fields::StoreFields;
use crate::solver::gpu::{budget::MemoryPlan, profile::StreamStats, GpuBackend, GpuOptions};
use crate::solver::orders::Backend;
use crate::solver::plan::Plan;
use crate::solver::{self, SolveError};
use crate::store::resident::Residency;
use crate::vk::{Context, ContextOptions};
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// Sets `solver.directions_per_face = k` in a scene's `[solver]` table and keeps the keys bounded
/// by it valid: storage directions above k come down to k, sky directions below k come up to k
/// (the sky then travels on the k×k directions; dropping the key would let the plan choose), and
/// scattered light's own directions that are no multiple of k go (the plan chooses).
fn set_directions_per_face(solver: &mut toml::map::Map<String, toml::Value>, k: u32) {
    let k = i64::from(k);
    solver.insert("directions_per_face".into(), toml::Value::Integer(k));
    if solver.get("storage_directions_per_face").and_then(toml::Value::as_integer).is_some_and(|ks| ks > k) {
        solver.insert("storage_directions_per_face".into(), toml::Value::Integer(k));
    }
    if solver.get("sky_directions_per_face").and_then(toml::Value::as_integer).is_some_and(|n| n < k) {
        solver.insert("sky_directions_per_face".into(), toml::Value::Integer(k));
    }
    // The scattered light's own directions must be a multiple of k: one that is not any more
    // goes, and the plan chooses for the new k.
    if solver
        .get("scattered_directions_per_face")
        .and_then(toml::Value::as_integer)
        .is_some_and(|n| n < k || n % k != 0)
    {
        solver.remove("scattered_directions_per_face");
    }
}

#[derive(Debug, Serialize)]
pub struct StreamOrder {
    pub order: u32,
    pub wall_seconds: f64,
    pub upload_seconds: f64,
    pub compute_seconds: f64,
    pub download_seconds: f64,
    /// Wall time the device's own timestamps do not cover: the host's gathers and scatters, the
    /// end-of-order passes, waits. Exact where transfers and compute run one after the other (one
    /// queue, lavapipe); where they overlap on a device it is a lower bound.
    pub host_seconds: f64,
    /// Transfer time spent while compute was running, over all transfer time.
    pub hidden_transfer_fraction: f64,
    pub upload_bytes_per_second: f64,
    pub download_bytes_per_second: f64,
    /// Bytes moved to and from the device in the order (the resident mode moves each field once).
    pub upload_bytes: u64,
    pub download_bytes: u64,
    /// Voxel·direction updates per wall-clock second (every channel counted once).
    pub updates_per_second: f64,
    /// Slices gathered while the pass before ended (a face's later passes start with an upload).
    pub pregathered_slices: u64,
    /// Slices gathered on the copy workers while the slices before them computed.
    pub gathered_ahead_slices: u64,
}

#[derive(Debug, Serialize)]
pub struct StreamReport {
    pub scene: String,
    pub device: String,
    pub device_is_cpu: bool,
    pub dedicated_transfer_queue: bool,
    /// Downloads have a queue of their own beside the uploads' (a second copy engine).
    pub dedicated_download_queue: bool,
    pub note: String,
    pub dims: [u32; 3],
    pub channels: u32,
    pub directions: usize,
    pub memory: MemoryPlan,
    /// Whether the store's pages stayed resident between passes ([`crate::store::resident`]).
    pub host_memory: Residency,
    pub orders: Vec<StreamOrder>,
}

/// Runs `orders` orders of `scene_path` with the stream profiled.
pub fn stream(
    scene_path: &Path,
    orders: u32,
    budget: Option<u64>,
    vk: ContextOptions,
    work: &Path,
) -> Result<StreamReport, JobError> {
    let mut scene = Scene::load(scene_path)?;
    if budget.is_some() {
        scene.solver.device_memory_budget = budget;
    }
    let result = run_stream(&scene, scene_path, orders, vk, work);
    let _ = std::fs::remove_dir_all(work);
    result
}

fn run_stream(
    scene: &Scene,
    scene_path: &Path,
    orders: u32,
    vk: ContextOptions,
    work: &Path,
) -> Result<StreamReport, JobError> {
    let store = solver::build_store(scene, work)?;
    let total = store.grid().brick_count();
    let plan = Plan::new(scene, total, total - store.occupied_count());
    let mut fields = StoreFields::create(&store, &plan)?;
    let residency = store.keep_pages_if_they_fit(scene.solver.host_memory_budget);
    let ctx = Context::new(vk).map_err(SolveError::from)?;
    let limits = ctx.limits();
    let options = GpuOptions { profile: true, ..GpuOptions::for_scene(scene) };
    let mut gpu = GpuBackend::new(ctx.clone(), &plan, &store, &mut fields, options)?;
    let [nx, ny, nz] = plan.dims;
    let updates = nx as f64 * ny as f64 * nz as f64 * plan.propagation.len() as f64;
    let mut rows = Vec::new();
    let mut before = StreamStats::default();
    for order in 0..orders.max(1) {
        let t = Instant::now();
        gpu.propagate_order(order)?;
        // As the order loop commits: on the device where the plan lets the resident mode end its
        // orders there, else on the host.
        gpu.commit_order(&plan)?;
        let wall = t.elapsed().as_secs_f64();
        let now = gpu.stream_stats().unwrap_or_default();
        let upload = now.upload_seconds - before.upload_seconds;
        let download = now.download_seconds - before.download_seconds;
        let hidden = now.hidden_transfer_seconds - before.hidden_transfer_seconds;
        let per_second = |bytes: u64, seconds: f64| if seconds > 0.0 { bytes as f64 / seconds } else { 0.0 };
        rows.push(StreamOrder {
            order,
            wall_seconds: wall,
            upload_seconds: upload,
            compute_seconds: now.compute_seconds - before.compute_seconds,
            download_seconds: download,
            host_seconds: (wall - upload - download - (now.compute_seconds - before.compute_seconds)).max(0.0),
            hidden_transfer_fraction: if upload + download > 0.0 { hidden / (upload + download) } else { 0.0 },
            upload_bytes_per_second: per_second(now.upload_bytes - before.upload_bytes, upload),
            download_bytes_per_second: per_second(now.download_bytes - before.download_bytes, download),
            upload_bytes: now.upload_bytes - before.upload_bytes,
            download_bytes: now.download_bytes - before.download_bytes,
            updates_per_second: updates / wall,
            pregathered_slices: now.pregathered_slices - before.pregathered_slices,
            gathered_ahead_slices: now.gathered_ahead_slices - before.gathered_ahead_slices,
        });
        before = now;
    }
    let memory = gpu.memory_plan();
    drop(gpu);
    let note = if limits.is_cpu {
        "CPU Vulkan device (e.g. lavapipe): transfers and compute share the host's cores and run one after the other, so the overlap and bandwidth figures say nothing about a GPU; the updates/s figure is a CPU figure".to_string()
    } else if ctx.transfer_queue().is_none() {
        "no queue besides the compute queue: transfers are ordered after compute on one queue, so little can overlap"
            .to_string()
    } else {
        let downloads = if ctx.download_queue().is_some() { "; downloads on a second one" } else { "" };
        format!("transfers run on a dedicated queue{downloads}; hidden_transfer_fraction is the share of transfer time overlapped by compute")
    };
    Ok(StreamReport {
        scene: scene_path.display().to_string(),
        device: format!("{} ({})", ctx.device_name(), ctx.driver_description()),
        device_is_cpu: limits.is_cpu,
        dedicated_transfer_queue: ctx.transfer_queue().is_some(),
        dedicated_download_queue: ctx.download_queue().is_some(),
        note,
        dims: plan.dims,
        channels: plan.channels,
        directions: plan.propagation.len(),
        memory,
        host_memory: residency,
        orders: rows,
    })
}
