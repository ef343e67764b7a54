//! The solver: the plan, the discretisation shared by both backends, the CPU twin, the GPU driver
//! and the order loop.
//!
//! - [`plan`] decides what the scene needs and derives the per-direction tables;
//! - [`sweep`] and [`segment`] are the discretisation (voxels walked, exact segment solution);
//! - [`cpu`] is the f64 twin of the GPU kernels, [`gpu`] the Vulkan driver;
//! - [`orders`] runs scattering orders until [`remaining`] says every voxel of the medium is within
//!   the tolerance of its converged value; [`energy`] keeps the books (per face of the volume too),
//!   [`exitance`] the outgoing power per boundary pixel of each face (placed by the twin's rules;
//!   the GPU's records folded by [`gpu::face_maps`]);
//! - [`periodic`] closes periodic boundaries (wrapping lattices, carried rays between orders);
//!   [`mirror`] closes reflective ones on the twin (hand-overs to the mirror-image directions),
//!   [`unfold`] on the GPU, and on the twin for a traced emission's scattered light's directions
//!   (the volume doubled by its images, solved and folded back);
//! - [`passes`] are the host passes between orders, written once over both backends' fields;
//! - [`acceleration`] follows each order with a diffusion solve of the light still to come
//!   (diffusion synthetic acceleration: orders nearly independent of the albedo);
//! - [`fields`] holds the solver's fields in the brick store, and checkpoints;
//! - [`cancel`] is the request to stop a solve at the next slice, its checkpoint kept;
//! - [`point`] computes point lights' uncollided light exactly on the host and writes it, with its
//!   first scattering, into order 0's fields (before order 0, and only in a fresh solve);
//! - [`direct`] splits the suns' first scattering off the source an image is made from (the
//!   renderer evaluates it exactly, from the suns' irradiance [`beam_trace`] traces to each voxel's
//!   centre);
//! - [`progress_lines`] logs long stretches of work (a GPU order, the emission's trace) now and then;
//! - [`warm`] starts a solve from a guess (the previous frame's solution) and still converges to
//!   the cold solve's answer.

pub mod acceleration;
pub mod antidiffusion;
pub mod beam_trace;
pub mod cancel;
pub mod cpu;
mod cpu_sweep;
pub mod direct;
pub mod emission;
pub mod energy;
pub mod environment;
pub mod exitance;
pub mod fields;
pub mod gpu;
pub mod mirror;
pub mod orders;
pub mod passes;
pub mod periodic;
pub mod plan;
pub mod point;
pub mod progress_lines;
pub mod remaining;
pub mod segment;
pub mod slow_mode;
pub mod sweep;
pub mod uncollided;
pub mod unfold;
pub mod warm;

use crate::scene::{Scene, VolumeSource};
use crate::store::resident::Residency;
use crate::store::{import, BrickStore, StoreError};
use crate::vk::{Context, ContextOptions, VkError};
use fields::StoreFields;
use orders::OrderOutcome;
use plan::Plan;
use std::path::Path;
use std::time::Instant;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum SolveError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Vulkan(#[from] VkError),
    #[error("the CPU backend keeps the whole volume in memory and would need {} MiB; use the GPU backend", bytes >> 20)]
    TooLargeForCpu { bytes: u64 },
    #[error(
        "{what} needs {bytes} bytes in one buffer, but this device binds at most {limit} bytes per storage buffer"
    )]
    DeviceLimit { what: String, bytes: u64, limit: u64 },
    #[error("the device memory budget of {budget} bytes is too small: the smallest unit (one slice of bricks, one direction, one plane) needs {needed} bytes; raise --device-memory-budget to at least {needed}")]
    BudgetTooSmall { budget: u64, needed: u64 },
    #[error("the device memory budget of {budget} bytes is larger than the device's memory ({device} bytes in its device-local heap); give at most {device}, or leave the budget out for a safe default")]
    BudgetTooLarge { budget: u64, device: u64 },
    #[error("Vulkan validation reported {} error(s); the first: {}", .0.len(), .0.first().map(String::as_str).unwrap_or(""))]
    Validation(Vec<String>),
    #[error("{}: the checkpoint belongs to another scene or lpm version; rerun with --fresh instead of --resume to discard it and start over", path.display())]
    CheckpointMismatch { path: std::path::PathBuf },
    #[error("writing the checkpoint: {0}")]
    Checkpoint(crate::output::OutputError),
    #[error("the GPU driver does not hand light over at mirror faces: `lpm solve` solves such a scene on the volume doubled by its mirror images; this command does not (use a scene without reflective faces, or --backend cpu where it has one)")]
    MirrorsInTheDriver,
    #[error("--resume needs the GPU backend (the CPU twin keeps its fields in memory)")]
    ResumeNeedsGpu,
    #[error("a host copy worker thread died (it panicked) while copying bricks between the store and the staging")]
    CopyWorkerDied,
    /// `resumable`: whether a checkpoint is kept to resume from. None is when the solve was
    /// stopped before its first checkpoint (while its volume was read or its store built, or in its
    /// first orders), or writes none (the CPU twin; a GPU solve of mirror faces on its doubled
    /// volume): it starts afresh when rerun. Stopped at a slice of an order, or in the export or
    /// the render after the last order's checkpoint, the message is the same: what is kept is the
    /// last checkpoint, whatever the phase.
    #[error("{}", if *.resumable {
        "the solve was cancelled; its last checkpoint is kept: rerun the same command with --resume to continue it"
    } else {
        "the solve was cancelled; no checkpoint is kept (it stopped before its first, or writes none, as for mirror faces on the GPU, solved on a doubled volume): rerun the same command to solve it again"
    })]
    Cancelled { resumable: bool },
    #[error(transparent)]
    WarmStart(#[from] warm::WarmStartError),
    #[error(
        "the order series diverged at order {order}: {why}. Its fields are not a solution, so no output \
         was written. The accelerations are the only parts of the solver that can amplify light; rerun \
         with solver.acceleration = \"off\" and solver.diffusion_correction = \"off\", and please report \
         the scene"
    )]
    Diverged { order: u32, why: String },
    #[error("internal error: {0}")]
    Internal(&'static str),
}

/// Which implementation runs the sweeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BackendKind {
    Gpu,
    Cpu,
}

/// What a solve reports besides its fields.
#[derive(Debug)]
pub struct SolveRun {
    pub plan: Plan,
    pub outcome: OrderOutcome,
    /// The Vulkan device used, or "CPU twin (f64, N threads)".
    pub device: String,
    /// Peak device memory allocated by the solver's allocator (0 for the CPU backend).
    pub peak_device_bytes: u64,
    /// How the sweeps were cut to fit the device memory budget (GPU backend only).
    pub memory: Option<gpu::budget::MemoryPlan>,
    /// Seconds spent per phase, in order.
    pub phases: Vec<(String, f64)>,
    /// Whether the store's pages stayed resident between passes ([`crate::store::resident`]).
    pub residency: Residency,
    /// The outgoing power per boundary pixel of each face ([`exitance`]; on the GPU
    /// [`gpu::face_maps`]). `None` where the GPU makes none: mirror faces (solved as the doubled
    /// volume, whose faces are not the scene's), a budget their records do not fit, or a solve
    /// resumed from a checkpoint that kept no maps (a resumed solve adds on to its checkpoint's).
    pub exit_maps: Option<exitance::ExitMaps>,
}

/// Builds the brick store for the scene's volume in `dir`.
pub fn build_store(scene: &Scene, dir: &Path) -> Result<BrickStore, SolveError> {
    build_store_until(scene, dir, None)
}

/// [`build_store`], stopping once `cancel` is raised: while a VDB or NanoVDB file is read, while
/// a NRRD file is decoded, and between bricks (a sparse volume's box can hold hundreds of
/// thousands of bricks: a SIGTERM must not wait for all of them). A cancelled build returns
/// [`SolveError::Cancelled`] with nothing to resume from.
pub fn build_store_until(
    scene: &Scene,
    dir: &Path,
    cancel: Option<cancel::CancelFlag>,
) -> Result<BrickStore, SolveError> {
    let stopped = || cancel::raised(cancel);
    let store = build_density(scene, dir, cancel, &|| {
        if stopped() {
            Err(crate::store::StoreError::Cancelled)
        } else {
            Ok(())
        }
    })
    .map_err(|e| match e {
        SolveError::Store(crate::store::StoreError::Cancelled) => SolveError::Cancelled { resumable: false },
        e => e,
    })?;
    check_extinction(scene, &store)?;
    if let Some(grid) = &scene.volume.emission {
        crate::store::emission::import_emission(&store, grid, &scene.volume.source, &scene.medium)?;
    }
    if let Some(grid) = &scene.volume.albedo {
        crate::store::albedo::import_albedo(&store, grid, &scene.volume.source)?;
    }
    Ok(store)
}

/// Refuses a density whose extinction, density × `medium.sigma_t`, passes the limit of every
/// light value (`scene::validate::MAX_LIGHT`): the fields formed from it would not stay finite in
/// f32 (issue 57: 3.4e38 × 1e12 passed the CPU backend and diverged on the GPU). One pass over the
/// occupied bricks, which the store build has just written.
fn check_extinction(scene: &Scene, store: &BrickStore) -> Result<(), SolveError> {
    use crate::scene::validate::MAX_LIGHT;
    let sigma = scene.medium.sigma_t.iter().fold(0f64, |m, &v| m.max(v));
    let grid = *store.grid();
    for brick in store.occupied_bricks() {
        let Some(density) = store.density_brick(brick) else { continue };
        if let Some(l) = density.iter().position(|&d| !(d as f64 * sigma <= MAX_LIGHT)) {
            let origin = grid.brick_origin(grid.brick_coords(brick));
            let path = match &scene.volume.source {
                VolumeSource::Raw { path } | VolumeSource::Vdb { path, .. } | VolumeSource::Nrrd { path } => {
                    path.clone()
                }
                VolumeSource::Procedural { .. } => scene.path.clone(),
            };
            let value = density[l];
            return Err(crate::store::StoreError::TooLarge {
                path,
                what: "density",
                voxel: crate::store::brick_voxel(origin, l),
                value,
                factor_key: "medium.sigma_t",
                factor: sigma,
                product: value as f64 * sigma,
            }
            .into());
        }
    }
    store.release_all_density();
    Ok(())
}

/// The density bricks of the scene's volume; `check` is asked before each brick whether to go on,
/// and a file read or decoded first stops once `cancel` is raised.
fn build_density(
    scene: &Scene,
    dir: &Path,
    cancel: Option<cancel::CancelFlag>,
    check: &(dyn Fn() -> Result<(), crate::store::StoreError> + Sync),
) -> Result<BrickStore, SolveError> {
    let dims = scene.volume.dims;
    let h = scene.volume.voxel_size;
    Ok(match &scene.volume.source {
        VolumeSource::Procedural { shape, seed } => {
            let (shape, seed) = (*shape, *seed);
            BrickStore::create_with(dir, dims, h, move |brick, out| {
                check()?;
                crate::scene::procedural::fill_brick(shape, seed, dims, brick, out);
                Ok(())
            })?
        }
        VolumeSource::Raw { path } => {
            let raw = import::raw_density(path, dims)?;
            BrickStore::create_with(dir, dims, h, |brick, out| check().and_then(|()| raw.fill_brick(brick, out)))?
        }
        VolumeSource::Vdb { path, grid, index_min } => {
            let vdb = crate::store::vdb::vdb_density_until(path, grid, dims, *index_min, cancel)?;
            BrickStore::create_with(dir, dims, h, |brick, out| check().and_then(|()| vdb.fill_brick(brick, out)))?
        }
        VolumeSource::Nrrd { path } => {
            // Decoded once into a raw f32 file beside the store, imported like `raw`, then removed.
            let header = crate::store::nrrd_input::nrrd_header(path)?;
            if header.dims != dims.map(u64::from) {
                return Err(crate::store::StoreError::Corrupt {
                    path: path.clone(),
                    message: format!(
                        "the header now says {:?} voxels, the scene was validated with {dims:?}: the file changed",
                        header.dims
                    ),
                }
                .into());
            }
            std::fs::create_dir_all(dir).map_err(crate::store::StoreError::io(dir, "create the store directory"))?;
            let decoded = dir.join("nrrd-density.raw");
            crate::store::nrrd_input::convert_to_raw(path, &header, &decoded, cancel)?;
            let raw = import::raw_density(&decoded, dims)?;
            // A bad density is reported against the NRRD file, not the temporary.
            let store = BrickStore::create_with(dir, dims, h, |brick, out| {
                check()?;
                raw.fill_brick(brick, out).map_err(|e| match e {
                    crate::store::StoreError::BadDensity { voxel, value, .. } => {
                        crate::store::StoreError::BadDensity { path: path.clone(), voxel, value }
                    }
                    e => e,
                })
            });
            drop(raw);
            let _ = std::fs::remove_file(&decoded);
            store?
        }
    })
}

/// The scene's density at every voxel (x fastest), read through a brick store built in `scratch`
/// (removed afterwards): what `lpm compare --scene` and `lpm bench accuracy` use to find the dense
/// core.
pub fn density_volume(scene: &Scene, scratch: &Path) -> Result<Vec<f32>, SolveError> {
    let store = build_store(scene, scratch);
    let result = store.map(|store| {
        let [nx, ny, nz] = scene.volume.dims;
        let mut density = Vec::with_capacity(nx as usize * ny as usize * nz as usize);
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    density.push(store.density_at([x, y, z]));
                }
            }
        }
        density
    });
    let _ = std::fs::remove_dir_all(scratch);
    result
}

/// Solves `scene` over `store`: plans, runs the orders on the chosen backend, and leaves the
/// fluence and the summed source in the returned fields. The device memory budget is the scene's.
pub fn solve(
    scene: &Scene,
    store: &BrickStore,
    backend: BackendKind,
    vk_options: ContextOptions,
    progress: impl crate::progress::Observer,
) -> Result<(SolveRun, StoreFields), SolveError> {
    let gpu = gpu::GpuOptions::for_scene(scene);
    solve_with(scene, store, backend, vk_options, gpu, false, progress)
}

/// Identifies a scene for checkpoints: a resumed solve must be the same job.
pub fn scene_digest(scene: &Scene) -> String {
    // FNV-1a over the validated scene and the crate version: stable across runs and platforms.
    // Only what affects the solve is digested: the memory budgets, the device residency and the checkpoint cadence are
    // left out (any gives bitwise the same result, so a solve may resume under another), and so is the camera
    // (it only affects the image, rendered after the solve).
    let mut scene = scene.clone();
    scene.solver.device_memory_budget = None;
    scene.solver.host_memory_budget = None;
    scene.solver.device_residency = crate::scene::DeviceResidency::default();
    scene.solver.checkpoint = crate::scene::CheckpointCadence::default();
    scene.camera = None;
    fnv1a(&format!("{}|{:?}", env!("CARGO_PKG_VERSION"), scene))
}

/// Identifies a solve for checkpoints: the scene ([`scene_digest`]) and what its plan chose for it
/// (the phase function discretised, the spatial scheme, the sky's and the scattered light's own
/// directions), so that a build
/// whose choices differ (the same crate version between releases) refuses to continue another
/// build's orders instead of mixing two.
fn checkpoint_digest(scene: &Scene, plan: &Plan) -> String {
    let chosen = format!(
        "{:?}|{:?}|{}|{}",
        plan.phase,
        plan.spatial,
        plan.sky_directions_per_face(),
        plan.scattered_directions_per_face()
    );
    format!("{}-{}", scene_digest(scene), fnv1a(&chosen))
}

/// FNV-1a of `text`, in hex: stable across runs and platforms.
fn fnv1a(text: &str) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in text.bytes() {
        h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// [`solve`] with explicit GPU options (budget, slices in flight).
pub fn solve_with(
    scene: &Scene,
    store: &BrickStore,
    backend: BackendKind,
    vk_options: ContextOptions,
    gpu_options: gpu::GpuOptions,
    resume: bool,
    progress: impl crate::progress::Observer,
) -> Result<(SolveRun, StoreFields), SolveError> {
    solve_from(scene, store, backend, vk_options, gpu_options, resume, None, progress)
}

/// [`solve_with`], starting from the solution exported in `warm_start` (an output directory, e.g.
/// the previous frame's) unless the solve resumes from a checkpoint; see [`warm`].
#[allow(clippy::too_many_arguments)]
pub fn solve_from(
    scene: &Scene,
    store: &BrickStore,
    backend: BackendKind,
    vk_options: ContextOptions,
    gpu_options: gpu::GpuOptions,
    resume: bool,
    warm_start: Option<&Path>,
    mut progress: impl crate::progress::Observer,
) -> Result<(SolveRun, StoreFields), SolveError> {
    progress.stage(crate::progress::Stage::Plan);
    let mut phases = Vec::new();
    let t = Instant::now();
    let total = store.grid().brick_count();
    let mut plan = Plan::new(scene, total, total - store.occupied_count());
    let choice = uncollided::choose(store, &plan, scene.solver.emission_uncollided)?;
    if choice.traced {
        plan.trace_emission(choice.reason);
    } else {
        plan.sweep_emission();
        if !choice.reason.is_empty() {
            plan.reasons.push(choice.reason);
        }
    }
    progress.decay_prior(&slow_mode::prior(&plan, store));
    // The orders that sweep more than an ordinary order's directions (at most the first few).
    let weights: Vec<f64> = (0..=plan::SCATTERED_OWN_ORDERS).map(|o| plan.order_weight(o)).collect();
    progress.order_weights(&weights);
    let digest = checkpoint_digest(scene, &plan);
    if resume && backend == BackendKind::Cpu {
        return Err(SolveError::ResumeNeedsGpu);
    }
    // Mirror faces on the GPU: the volume doubled by its images is seeded and solved in a store
    // of its own (super::unfold), which writes no checkpoint; these fields take its folded totals.
    // So are they on the CPU where a traced emission's scattered light takes directions of its
    // own, which the twin's mirror hand-overs do not have (Plan::unfolds_for_scattered).
    let doubled = !plan.mirrors.is_empty() && (backend == BackendKind::Gpu || plan.unfolds_for_scattered.is_some());
    let resumed = if resume { StoreFields::resume(store, &plan, &digest)? } else { None };
    let mut trace_note = None;
    let (mut fields, start) = match resumed {
        Some((fields, state)) => {
            tracing::info!("resuming after {} completed order(s)", state.orders_done);
            (fields, state)
        }
        None => {
            let mut fields = StoreFields::create(store, &plan)?;
            // Unfolded, the doubled volume is seeded in a store of its own (super::unfold): here
            // only the trace, in the volume with its images, whose order 0 that one images.
            if doubled && warm_start.is_some() {
                tracing::warn!(
                    "mirror faces unfolded: the doubled volume is solved cold, the warm start's guess unused"
                );
            }
            let warm_start = warm_start.filter(|_| !doubled);
            if let Some(dir) = warm_start {
                if backend == BackendKind::Cpu {
                    return Err(warm::WarmStartError::NeedsGpu.into());
                }
                if plan.emission_field || (plan.emission_traced && plan.emission_grid) {
                    return Err(warm::WarmStartError::WithEmissionGrid.into());
                }
                let power = warm::seed(store, &plan, &mut fields, dir)?;
                tracing::info!("warm start from {} (its source's power {power:.4e})", dir.display());
            } else if plan.emission_field && !doubled {
                emission::write_initial_source(store, &plan, &mut fields.source_prev)?;
            }
            // The point lights' uncollided fluence and first scattering go into order 0's own
            // accumulators (still zero), as a sun's beam sweep deposits them: only here, so a
            // resumed solve never adds them twice; their power travels in the loop state.
            let point_light_power = point::write_order0(store, &plan, &mut fields.fluence, &mut fields.source_next)?;
            // The traced emission's uncollided light joins them, the same way (super::uncollided).
            let traced =
                trace_emission(store, &plan, &mut fields, &mut phases, backend, &vk_options, gpu_options.cancel)?;
            trace_note = traced.note();
            // The host wrote order 0's accumulators whenever there are point lights or a traced
            // emission (the twin takes them on the same condition, `run_cpu`), whatever power
            // that light gives the medium: in a vacuum (σt = 0) it gives none, yet its
            // uncollided fluence I/r² is order 0's (issue 57: the GPU's resident order 0 cleared it).
            fields.seeded = !plan.point_lights.is_empty() || plan.emission_traced;
            let state = fields::LoopState {
                point_light_power,
                uncollided_emitted: traced.emitted,
                uncollided_escaped: traced.escaped(),
                ..fields::LoopState::default()
            };
            (fields, state)
        }
    };
    // Every field exists now: keep the store's pages resident if it fits the host memory budget.
    let residency = store.keep_pages_if_they_fit(scene.solver.host_memory_budget);
    phases.push(("plan".to_string(), t.elapsed().as_secs_f64()));
    for reason in &plan.reasons {
        tracing::info!("plan: {reason}");
    }
    let mut memory = None;
    let mut doubled_reason = None;
    let mut exit_maps = None;
    let (outcome, device, peak) = match backend {
        _ if doubled => {
            let (run, reason) = unfold::solve_doubled(
                scene,
                store,
                &plan,
                &mut fields,
                start,
                backend,
                vk_options,
                gpu_options,
                &mut progress,
            )?;
            phases.extend(run.phases);
            memory = run.memory;
            doubled_reason = Some(reason);
            (run.outcome, run.device, run.peak)
        }
        BackendKind::Cpu => {
            let run = run_cpu(&plan, store, &mut fields, start, gpu_options.cancel, &mut progress)?;
            phases.extend(run.phases);
            exit_maps = run.exit_maps;
            (run.outcome, run.device, run.peak)
        }
        BackendKind::Gpu => {
            let checkpoints = gpu_options.checkpoints.then(|| (digest.clone(), scene.solver.checkpoint));
            let run = run_gpu(&plan, store, &mut fields, start, vk_options, gpu_options, checkpoints, &mut progress)?;
            phases.extend(run.phases);
            memory = run.memory;
            exit_maps = run.exit_maps;
            (run.outcome, run.device, run.peak)
        }
    };
    fields.fluence_total.flush()?;
    fields.source_total.flush()?;
    plan.reasons.extend(trace_note);
    plan.reasons.extend(doubled_reason);
    Ok((SolveRun { plan, outcome, device, peak_device_bytes: peak, memory, phases, residency, exit_maps }, fields))
}

/// Traces the emission's uncollided light into order 0's accumulators when the plan says so
/// ([`uncollided`]), with its time among the phases and what it did among the plan's reasons: on
/// the GPU backend by the device kernel ([`uncollided::gpu`], on a context of its own for the
/// trace; the host's walk where the kernel declines), on the CPU backend by the host's walk.
fn trace_emission(
    store: &BrickStore,
    plan: &Plan,
    fields: &mut StoreFields,
    phases: &mut Vec<(String, f64)>,
    backend: BackendKind,
    vk_options: &ContextOptions,
    cancel: Option<cancel::CancelFlag>,
) -> Result<uncollided::Traced, SolveError> {
    if !plan.emission_traced {
        return Ok(uncollided::Traced::default());
    }
    let t = Instant::now();
    let traced = if backend == BackendKind::Gpu {
        let ctx = Context::new(vk_options.clone())?;
        let traced = uncollided::add_order0_on(
            store,
            plan,
            &mut fields.fluence,
            &mut fields.source_next,
            false,
            Some(&ctx),
            cancel,
        )?;
        // With validation on, any error it reported fails the solve, as the GPU run's do.
        let messages = ctx.validation_messages();
        if !messages.is_empty() {
            return Err(SolveError::Validation(messages));
        }
        traced
    } else {
        uncollided::add_order0_on(store, plan, &mut fields.fluence, &mut fields.source_next, false, None, cancel)?
    };
    let seconds = t.elapsed().as_secs_f64();
    phases.push(("emission trace".to_string(), seconds));
    tracing::info!(
        "emission traced in {seconds:.2} s {}: {} emitters (mirror images included), {} clusters taken whole, {} \
         exact near pairs, {} far pairs",
        traced.ran_on(),
        traced.emitters,
        traced.work.clusters,
        traced.work.near,
        traced.work.far
    );
    Ok(traced)
}

/// What a backend's solve hands back besides the fields.
struct BackendRun {
    outcome: orders::OrderOutcome,
    device: String,
    peak: u64,
    /// The GPU's memory plan (none on the CPU).
    memory: Option<gpu::budget::MemoryPlan>,
    phases: Vec<(String, f64)>,
    /// The exitance maps ([`gpu::face_maps`]), when made.
    exit_maps: Option<exitance::ExitMaps>,
}

/// Runs the orders of `plan` on the GPU over `store`'s `fields` from `start`, writing checkpoints
/// under `checkpoints` (digest, cadence) when given; a cancelled run without them says there is
/// nothing to resume.
#[allow(clippy::too_many_arguments)]
fn run_gpu(
    plan: &Plan,
    store: &BrickStore,
    fields: &mut StoreFields,
    start: fields::LoopState,
    vk_options: ContextOptions,
    mut gpu_options: gpu::GpuOptions,
    checkpoints: Option<(String, crate::scene::CheckpointCadence)>,
    progress: &mut dyn crate::progress::Observer,
) -> Result<BackendRun, SolveError> {
    // A resumed solve sweeps only the orders after its checkpoint: it adds them to the maps its
    // checkpoint kept, or makes none (maps of the later orders alone would not add up to the books).
    gpu_options.exit_maps &= start.orders_done == 0 || fields.resumed_exits.is_some();
    let mut phases = Vec::new();
    let t = Instant::now();
    let ctx = Context::new(vk_options)?;
    let device = format!("{} ({})", ctx.device_name(), ctx.driver_description());
    let mut gpu = gpu::GpuBackend::new(ctx.clone(), plan, store, fields, gpu_options)?;
    let memory = gpu.memory_plan();
    let resumable = checkpoints.is_some();
    if let Some((digest, cadence)) = checkpoints {
        gpu.enable_checkpoints(digest, cadence);
    }
    phases.push(("setup".to_string(), t.elapsed().as_secs_f64()));
    let t = Instant::now();
    let outcome =
        orders::run_orders(plan, &mut gpu, start, crate::progress::Forward(progress)).map_err(|e| match e {
            SolveError::Cancelled { .. } => SolveError::Cancelled { resumable },
            e => e,
        })?;
    phases.push(("orders".to_string(), t.elapsed().as_secs_f64()));
    let exit_maps = gpu.take_exit_maps();
    drop(gpu);
    let peak = ctx.peak_allocated_bytes();
    // With validation on, any error it reported fails the solve: a clean run is part of the
    // contract (tests rely on this).
    let messages = ctx.validation_messages();
    if !messages.is_empty() {
        return Err(SolveError::Validation(messages));
    }
    Ok(BackendRun { outcome, device, peak, memory: Some(memory), phases, exit_maps })
}

/// Runs the orders of `plan` on the CPU twin over `store`'s `fields` from `start` (which must be
/// a fresh solve's: the twin keeps no checkpoints), and writes its totals into `fields`.
fn run_cpu(
    plan: &Plan,
    store: &BrickStore,
    fields: &mut StoreFields,
    start: fields::LoopState,
    cancel: Option<cancel::CancelFlag>,
    progress: &mut dyn crate::progress::Observer,
) -> Result<BackendRun, SolveError> {
    let mut phases = Vec::new();
    let t = Instant::now();
    let mut twin = cpu::CpuTwin::new(plan, |v| store.density_at(v))?;
    twin.set_cancel(cancel);
    if plan.albedo_field {
        twin.set_albedo(&crate::store::albedo::open_albedo(store)?);
    }
    if plan.emission_field {
        // The same f32 order-0 source the GPU gains, and the power it emits.
        twin.set_initial_source(&fields.source_prev, emission::emitted_power(store, plan)?);
    }
    if !plan.point_lights.is_empty() || plan.emission_traced {
        // The same f32 values the GPU's order 0 starts from.
        twin.set_order0_accumulators(&fields.fluence, &fields.source_next);
    }
    phases.push(("setup".to_string(), t.elapsed().as_secs_f64()));
    let t = Instant::now();
    let outcome = orders::run_orders(plan, &mut twin, start, crate::progress::Forward(progress))?;
    phases.push(("orders".to_string(), t.elapsed().as_secs_f64()));
    twin.write_into(store, fields);
    let exit_maps = Some(twin.exit_maps().clone());
    let device = format!("CPU twin (f64, {} threads)", rayon::current_num_threads());
    Ok(BackendRun { outcome, device, peak: 0, memory: None, phases, exit_maps })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadrature::phase::Phase;

    #[test]
    fn a_checkpoint_names_the_phase_function_its_plan_discretises() {
        let text = "[volume]\nprocedural = \"sphere\"\ndims = [16, 16, 16]\n[medium]\nsigma_t = 1.0\nalbedo = 0.9\n\
                    g = 0.85\n[[lights]]\nkind = \"sky\"\nradiance = 1.0\n";
        let scene = Scene::from_toml_str(text, Path::new("t.toml")).expect("scene");
        let plan = Plan::new(&scene, 1, 0);
        assert!(matches!(plan.phase, Phase::Truncated(_)));
        let same = checkpoint_digest(&scene, &Plan::new(&scene, 1, 0));
        assert_eq!(checkpoint_digest(&scene, &plan), same);
        assert!(same.starts_with(&scene_digest(&scene)));
        // A build that truncates the forward peak otherwise (the same scene and crate version).
        let mut other = plan.clone();
        other.phase = Phase::HenyeyGreenstein { g: 0.85 };
        assert_ne!(checkpoint_digest(&scene, &other), same);
    }
}
