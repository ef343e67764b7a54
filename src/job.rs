//! A solve job from start to finish: read the scene, build the brick store, solve, export the
//! fields, render the image, write the report. The CLI and the tests both run jobs through here.
//!
//! Nothing is left half-written: the scene is validated before anything is created; `OUT` is locked
//! for the whole run ([`output::DirLock`]: a second solve into it fails at once) and cleaned of what a
//! killed run left ([`output::recover`]); the disk space the outputs need at the least is checked
//! before the store is built; the brick store is built in `OUT/.lpm-work` and removed at the end;
//! every output is written into a staging directory and published with the others as one set
//! ([`output::Staging`]). A solve whose fluence or source holds a NaN or an infinity anywhere it was
//! solved fails ([`JobError::NonFinite`]) instead of reporting garbage. The GPU backend checkpoints
//! the store at the scene's cadence (`solver.checkpoint_every_*`, always after the last order); a
//! solve that is killed or fails after its first checkpoint keeps
//! `OUT/.lpm-work`, and `--resume` continues it (bitwise the same result as an uninterrupted
//! solve). A solve without `--resume` refuses to start over such a checkpoint unless `--fresh`
//! says to discard it ([`JobError::CheckpointExists`]).
//!
//! Over 450 lines because the job is one sequence (lock, scene, store, solve, export, render
//! data, image, report, publish) whose every step must leave `OUT` whole if the next one fails;
//! reading it in one place is what makes that property checkable.

use crate::output::{self, FieldMeta, OutputError};
use crate::progress::{self, Observer};
use crate::render;
use crate::scene::{Scene, SceneError};
use crate::solver::{self, BackendKind, SolveError, SolveRun};
use crate::vk::ContextOptions;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum JobError {
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error(transparent)]
    Solve(#[from] SolveError),
    /// A budget error, with where the budget came from (the flag or the scene key).
    #[error("{origin}: {inner}")]
    Budget { origin: String, inner: SolveError },
    #[error(transparent)]
    Output(#[from] OutputError),
    /// The image asked for cannot fit the memory left: refused before solving.
    #[error(transparent)]
    Image(#[from] render::memory::ImageTooLarge),
    #[error("cannot create output directory {}: {source}", path.display())]
    OutputDir { path: PathBuf, source: std::io::Error },
    #[error("{}: holds the checkpoint of an unfinished solve ({}); {RESUME_HINT}", out.display(), work_dir(out).display())]
    CheckpointExists { out: PathBuf },
    #[error("{}: the volume has no medium (every density is 0): there is nothing to solve", scene.display())]
    NoMedium { scene: PathBuf },
    #[error("the solve produced a non-finite {field} ({value}) at voxel ({}, {}, {}), component {component}; \
             the result is garbage and no output was written. Please report this with the scene file",
             voxel[0], voxel[1], voxel[2])]
    NonFinite { field: &'static str, voxel: [u32; 3], component: u32, value: f32 },
}

/// The one hint given wherever a checkpoint is in the way or can be used.
pub const RESUME_HINT: &str =
    "rerun the same command with --resume to continue it, or with --fresh to discard it and start over";

#[derive(Clone, Debug)]
pub struct SolveJob {
    pub scene: PathBuf,
    pub out: PathBuf,
    pub backend: BackendKind,
    pub vk: ContextOptions,
    /// Keep the brick store (medium and solver fields) in `out/store` after the solve.
    pub keep_store: bool,
    /// Skip rendering the image.
    pub no_image: bool,
    /// Skip exporting fluence.* and source.* as dense raw volumes (they take 4 bytes per voxel and
    /// component even where bricks are empty; with `keep_store` the solved fields stay in brick form).
    pub no_fields: bool,
    /// Device memory budget in bytes; overrides the scene's `solver.device_memory_budget`.
    pub device_memory_budget: Option<u64>,
    /// Continue from the checkpoint in `OUT/.lpm-work` if there is one.
    pub resume: bool,
    /// Discard a checkpoint in `OUT/.lpm-work` and start over (without it, a checkpoint there makes
    /// a solve without `resume` fail rather than silently lose the work).
    pub fresh: bool,
    /// Raised, the solve stops (`SolveError::Cancelled`, see [`solver::cancel`]): while its volume
    /// is read or decoded, at the next read or chunk; while the store is built, at the next brick;
    /// on the GPU at its next slice, keeping its last checkpoint; on the CPU twin, before the next
    /// direction's sweep; in the export, at the next row or write (the first two and the CPU twin
    /// keep nothing to resume from; the export keeps the last order's checkpoint where there is
    /// one). The renderer stops at the process's flag ([`solver::cancel::CancelFlag::process`]).
    pub cancel: Option<solver::cancel::CancelFlag>,
    /// Start from the solution in this output directory (its `source.raw`, e.g. the previous
    /// frame's) instead of from nothing; see [`solver::warm`].
    pub warm_start: Option<PathBuf>,
    /// Precision of `fluence.vdb` and `source.vdb`.
    pub vdb_precision: output::VdbPrecision,
    /// What the image shows where the camera sees through the volume.
    pub background: render::Background,
    /// Do not keep `OUT/render-data/` (what `lpm render` re-renders from).
    pub no_render_data: bool,
    /// The PNG's exposure and view transform where they differ from the scene's `[camera]`
    /// (`--exposure`, `--view`).
    pub display: render::keep::DisplayChange,
}

impl SolveJob {
    /// A solve of `scene` into `out` with the CLI's defaults: the GPU backend, the default Vulkan
    /// options, every output (fields, VDB files, image over the sky, render data), the scene's
    /// memory budget, no resume or warm start. Callers change what differs with `..`.
    pub fn new(scene: PathBuf, out: PathBuf) -> SolveJob {
        SolveJob {
            scene,
            out,
            backend: BackendKind::Gpu,
            vk: ContextOptions::default(),
            keep_store: false,
            no_image: false,
            no_fields: false,
            device_memory_budget: None,
            resume: false,
            fresh: false,
            cancel: None,
            warm_start: None,
            vdb_precision: Default::default(),
            background: Default::default(),
            no_render_data: false,
            display: Default::default(),
        }
    }
}

/// The work directory (brick store and checkpoint) of a solve writing to `out`.
pub fn work_dir(out: &Path) -> PathBuf {
    out.join(".lpm-work")
}

/// `report.json`.
#[derive(Debug, Serialize)]
pub struct Report {
    pub lpm_version: &'static str,
    pub scene: String,
    pub backend: &'static str,
    pub device: String,
    pub plan: solver::plan::PlanSummary,
    pub orders: u32,
    pub converged: bool,
    /// The output directory whose solution this solve started from (`warm_start`), if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warm_start: Option<String>,
    /// The estimated remaining relative error of the fluence over the medium's voxels after the
    /// last order (max and root mean square; see `solver::remaining`): what `converged` is decided on.
    pub remaining_error: Option<solver::remaining::RemainingError>,
    /// Scattered power of the last order over the total: what is left of the series, relatively.
    pub final_residual: f64,
    pub tolerance: f64,
    pub history: Vec<solver::orders::OrderRecord>,
    pub energy: solver::energy::EnergyBalance,
    /// The geometric tail added after the last order (`solver.extrapolate_tail`).
    pub tail: Option<solver::orders::TailEstimate>,
    /// Wall-clock seconds per phase, in order.
    pub seconds: Vec<Phase>,
    pub peak_device_bytes: u64,
    /// Peak resident memory of the process (VmHWM), when the system reports it: what the solve
    /// held in RAM at most, memory-mapped pages included.
    pub peak_resident_bytes: Option<u64>,
    /// Bytes of the brick store's files (density and solver fields; empty bricks take none).
    pub store_bytes: u64,
    /// The device memory plan: budget, planned bytes and how the sweeps were cut (GPU only).
    pub device_memory: Option<solver::gpu::budget::MemoryPlan>,
    /// Whether the store's pages stayed resident between passes, and why (the store's size against
    /// the host memory budget; see `store::resident`).
    pub host_memory: crate::store::resident::Residency,
    pub outputs: Vec<String>,
}

/// `progress.json`: the solve's state after its latest event (a stage started, an order done;
/// this run's orders only), with the [`progress::Estimator`]'s estimate: what `lpm serve` reports.
#[derive(Debug, Serialize)]
pub struct Progress<'a> {
    /// The stage under way.
    pub stage: progress::Stage,
    /// The last order done, if any.
    pub order: Option<u32>,
    /// Its residual (what `report.json` gives as `final_residual` if it is the last).
    pub residual: Option<f64>,
    /// The residual after each order of this run, oldest first.
    pub residuals: &'a [f64],
    pub max_orders: u32,
    pub tolerance: f64,
    /// Seconds since this run started.
    pub seconds: f64,
    /// The fraction of the job done, in [0, 1].
    pub fraction: f64,
    /// The estimated seconds left; absent while unknown.
    pub seconds_left: Option<f64>,
    /// The estimated orders left; absent while unknown.
    pub orders_left: Option<u32>,
}

/// Feeds a job's events to the estimator, writes `progress.json` and passes events and estimate
/// on to the caller's observer.
struct Watch<'a, O: Observer> {
    estimator: progress::Estimator,
    started: Instant,
    path: &'a Path,
    residuals: Vec<f64>,
    settings: progress::Settings,
    inner: O,
}

impl<O: Observer> Watch<'_, O> {
    fn publish(&mut self) {
        let estimate = self.estimator.estimate(self.started.elapsed().as_secs_f64());
        let last = self.estimator.orders().last();
        // Best effort: a failed write only loses progress reporting, never the solve.
        let _ = output::write_json_atomic(
            self.path,
            &Progress {
                stage: estimate.stage,
                order: last.map(|o| o.order),
                residual: last.map(|o| o.residual),
                residuals: &self.residuals,
                max_orders: self.settings.max_orders,
                tolerance: self.settings.tolerance,
                seconds: estimate.elapsed,
                fraction: estimate.fraction,
                seconds_left: estimate.seconds_left,
                orders_left: estimate.orders_left,
            },
        );
        tracing::debug!(
            stage = %estimate.stage,
            elapsed = estimate.elapsed,
            fraction = estimate.fraction,
            seconds_left = estimate.seconds_left.unwrap_or(-1.0),
            orders_left = estimate.orders_left.map_or(-1, i64::from),
            "progress estimate"
        );
        self.inner.estimate(&estimate);
    }
}

impl<O: Observer> Observer for Watch<'_, O> {
    fn stage(&mut self, stage: progress::Stage) {
        self.estimator.stage(stage, self.started.elapsed().as_secs_f64());
        self.inner.stage(stage);
        self.publish();
    }
    fn decay_prior(&mut self, prior: &progress::DecayPrior) {
        self.estimator.decay_prior(*prior);
        tracing::debug!(accelerated = ?prior.accelerated, plain_ratio = ?prior.plain_ratio, "progress prior");
        self.inner.decay_prior(prior);
    }
    fn order_weights(&mut self, weights: &[f64]) {
        self.estimator.order_weights(weights);
        self.inner.order_weights(weights);
    }
    fn order_done(&mut self, done: &progress::OrderDone) {
        self.estimator.order_done(done, self.started.elapsed().as_secs_f64());
        self.residuals.push(done.residual);
        self.inner.order_done(done);
        self.publish();
    }
}

#[derive(Debug, Serialize)]
pub struct Phase {
    pub phase: String,
    pub seconds: f64,
}

/// Runs the job. `observer` hears each stage as it starts and each order as it is done, and
/// after each the estimate of the fraction done and the seconds left ([`progress::Estimator`]);
/// a closure `|order, residual|` hears each order's residual.
pub fn run(job: &SolveJob, observer: impl Observer) -> Result<Report, JobError> {
    let started = Instant::now();
    if job.resume && job.backend == BackendKind::Cpu {
        return Err(SolveError::ResumeNeedsGpu.into());
    }
    // Loading a scene reads a VDB volume's topology, or a NanoVDB grid whole: stopped by SIGTERM
    // (the process's flag, see `store::vdb::vdb_info`), nothing is kept.
    let mut scene = match Scene::load(&job.scene) {
        Err(_) if solver::cancel::raised(job.cancel) || solver::cancel::CancelFlag::process().is_raised() => {
            return Err(SolveError::Cancelled { resumable: false }.into())
        }
        scene => scene?,
    };
    if job.device_memory_budget.is_some() {
        scene.solver.device_memory_budget = job.device_memory_budget;
    }
    let created_out = !job.out.exists();
    std::fs::create_dir_all(&job.out).map_err(|source| JobError::OutputDir { path: job.out.clone(), source })?;
    let lock = match output::DirLock::acquire(&job.out) {
        Ok(lock) => lock,
        Err(e) => {
            if created_out {
                let _ = std::fs::remove_dir(&job.out);
            }
            return Err(e.into());
        }
    };
    output::recover(&job.out)?;
    let work = work_dir(&job.out);
    let checkpointed_before = work.join("checkpoint.json").exists();
    if checkpointed_before && !job.resume && !job.fresh {
        return Err(JobError::CheckpointExists { out: job.out.clone() });
    }
    if !job.resume || !checkpointed_before {
        let _ = std::fs::remove_dir_all(&work);
    }
    // OUT/progress.json after each event, for programs watching the solve (`lpm serve`): written
    // atomically, so a reader sees the last complete state or nothing.
    let progress_path = job.out.join("progress.json");
    let _ = std::fs::remove_file(&progress_path);
    let render_work = if job.no_image {
        0.0
    } else {
        let camera =
            scene.camera.clone().unwrap_or_else(|| render::default_camera(scene.volume.dims, scene.volume.voxel_size));
        // Up front: an image that cannot fit is refused before the solve, not after it.
        render::memory::check_image_fits(camera.width, camera.height)?;
        let longest = scene.volume.dims.iter().copied().max().unwrap_or(0);
        f64::from(camera.width) * f64::from(camera.height) * f64::from(longest)
    };
    let settings = progress::Settings {
        tolerance: scene.solver.tolerance,
        max_orders: scene.solver.max_orders,
        export_values: if job.no_fields { 0.0 } else { export_values(&scene) },
        render_work,
    };
    let watch = Watch {
        estimator: progress::Estimator::new(settings),
        started,
        path: &progress_path,
        residuals: Vec::new(),
        settings,
        inner: observer,
    };
    let mut watch = watch;
    let result = check_space(job, &scene).and_then(|()| run_in(job, &scene, &work, &mut watch));
    let checkpointed = work.join("checkpoint.json").exists();
    // Cancelled before its first checkpoint: say so, not that a checkpoint is kept.
    let result = match result {
        Err(JobError::Solve(SolveError::Cancelled { resumable: true })) if !checkpointed => {
            Err(JobError::Solve(SolveError::Cancelled { resumable: false }))
        }
        r => r,
    };
    match (&result, job.keep_store) {
        (Ok(_), true) => {
            let keep = job.out.join("store");
            let _ = std::fs::remove_dir_all(&keep);
            let _ = std::fs::rename(&work, &keep);
        }
        // A failed solve that got past its first order keeps its store for `--resume`, unless the
        // checkpoint itself was refused (then resuming cannot help).
        (Err(JobError::Solve(SolveError::CheckpointMismatch { .. })), _) => {}
        (Err(_), _) if checkpointed => {
            tracing::warn!("the solve can be continued: {RESUME_HINT}");
        }
        _ => {
            let _ = std::fs::remove_dir_all(&work);
        }
    }
    // progress.json describes a run in progress: a finished solve has its report.json instead, and a
    // failed one with nothing to resume has nothing to report.
    if result.is_ok() || !checkpointed {
        let _ = std::fs::remove_file(&progress_path);
    }
    if result.is_err() && created_out && !checkpointed {
        drop(lock);
        let _ = std::fs::remove_dir(&job.out);
    }
    result
}

/// The values the export writes, as the progress estimate counts them: voxels times the fluence's
/// channels and the source's components, the source's storage directions as the plan chooses
/// them when it may reduce (1 for an isotropic medium, else k_s² per face; `solver::plan`).
fn export_values(scene: &Scene) -> f64 {
    let voxels: f64 = scene.volume.dims.iter().map(|&d| f64::from(d)).product();
    let channels = if scene.is_grey() { 1.0 } else { 3.0 };
    let storage = if scene.medium.g == 0.0 {
        1.0
    } else {
        let ks = scene.solver.storage_directions_per_face.unwrap_or(scene.solver.directions_per_face.min(2));
        6.0 * f64::from(ks * ks)
    };
    voxels * channels * (1.0 + storage)
}

/// Refuses a job whose volume or exported fields cannot fit on `OUT`'s disk, before anything is
/// built, naming what the bytes are for: the fluence and the source are dense volumes of at least
/// 4 bytes per voxel each (one channel; more for RGB and anisotropic plans), and a NRRD volume is
/// decoded into the store as a dense f32 copy (4 bytes per voxel, whatever its samples' type or
/// encoding: a gzip or a sparse file of a few KB can claim terabytes). The store's bricks are
/// checked as they are allocated (how many are occupied is known only once they are read).
fn check_space(job: &SolveJob, scene: &Scene) -> Result<(), JobError> {
    let voxels: u64 = scene.volume.dims.iter().map(|&d| u64::from(d)).product();
    let dims = scene.volume.dims;
    let mut needed = 0u64;
    let mut what = Vec::new();
    if !job.no_fields {
        let per_voxel = if scene.is_grey() { 4 } else { 12 };
        needed = voxels.saturating_mul(per_voxel).saturating_mul(2);
        what.push(format!(
            "fluence.raw and source.raw of {} × {} × {} voxels (at the least; --no-fields skips them)",
            dims[0], dims[1], dims[2]
        ));
    }
    if let crate::scene::VolumeSource::Nrrd { path } = &scene.volume.source {
        needed = needed.saturating_add(voxels.saturating_mul(4));
        what.push(format!(
            "the volume of {} decoded into the store ({} × {} × {} voxels as 32-bit floats)",
            path.display(),
            dims[0],
            dims[1],
            dims[2]
        ));
    }
    if what.is_empty() {
        return Ok(());
    }
    output::space::ensure_free(&job.out, needed, &what.join(" and "))?;
    Ok(())
}

/// The first NaN or infinity of `field` (stored bricks only: those are the solved ones), as
/// [`JobError::NonFinite`]. Reads the field a brick at a time and hands the pages back.
fn check_finite(
    field: &crate::store::Field,
    store: &crate::store::BrickStore,
    name: &'static str,
    cancel: Option<solver::cancel::CancelFlag>,
) -> Result<(), JobError> {
    let grid = *store.grid();
    for (n, brick) in store.occupied_bricks().enumerate() {
        let Some(values) = field.brick(brick) else { continue };
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            let (component, local) = (i / crate::store::BRICK_VOXELS, i % crate::store::BRICK_VOXELS);
            let o = grid.brick_origin(grid.brick_coords(brick));
            let l = [local % 16, (local / 16) % 16, local / 256].map(|c| c as u32);
            return Err(JobError::NonFinite {
                field: name,
                voxel: [o[0] + l[0], o[1] + l[1], o[2] + l[2]],
                component: component as u32,
                value: values[i],
            });
        }
        if n % 1024 == 1023 {
            field.release_all();
            if solver::cancel::raised(cancel) {
                return Err(JobError::Solve(SolveError::Cancelled { resumable: true }));
            }
        }
    }
    field.release_all();
    Ok(())
}

fn run_in(job: &SolveJob, scene: &Scene, work: &Path, observer: &mut impl Observer) -> Result<Report, JobError> {
    observer.stage(progress::Stage::Store);
    let t = Instant::now();
    let reopen = job.resume && work.join("checkpoint.json").exists();
    let store = if reopen {
        let store = crate::store::BrickStore::open(work).map_err(SolveError::from)?;
        // A job killed in its render left the image's fields in the store (solver::direct): no
        // part of its checkpoint, made again after this solve, and not the store's bytes.
        solver::direct::remove_fields(&store);
        store
    } else {
        if job.resume {
            tracing::info!("nothing to resume in {}: starting from the beginning", work.display());
        }
        solver::build_store_until(scene, work, job.cancel)?
    };
    if store.occupied_count() == 0 {
        return Err(JobError::NoMedium { scene: job.scene.clone() });
    }
    let store_seconds = t.elapsed().as_secs_f64();
    // A resumed solve continues from its checkpoint: the guess was used by its first order.
    let warm = job.warm_start.as_deref().filter(|_| !reopen);
    let gpu = solver::gpu::GpuOptions {
        checkpoints: job.backend == BackendKind::Gpu,
        cancel: job.cancel,
        ..solver::gpu::GpuOptions::for_scene(scene)
    };
    let (run, fields) =
        solver::solve_from(scene, &store, job.backend, job.vk.clone(), gpu, reopen, warm, progress::Forward(observer))
            .map_err(|e| match e {
                SolveError::BudgetTooSmall { .. } | SolveError::BudgetTooLarge { .. } => JobError::Budget {
                    origin: match (job.device_memory_budget, scene.solver.device_memory_budget) {
                        (Some(_), _) => "--device-memory-budget".to_string(),
                        (None, Some(_)) => format!("{}: solver.device_memory_budget", job.scene.display()),
                        (None, None) => "the default device memory budget".to_string(),
                    },
                    inner: e,
                },
                e => JobError::Solve(e),
            })?;
    let SolveRun { mut plan, outcome, device, peak_device_bytes, memory, mut phases, residency, exit_maps } = run;
    let store_bytes = store.file_bytes();
    phases.insert(0, ("store".to_string(), store_seconds));
    // From here on a cancelled job keeps what the solve checkpointed (its last order, on the GPU):
    // `run` says that none is kept where there is none.
    let cancel = job.cancel;
    let stop = || {
        if solver::cancel::raised(cancel) {
            Err(JobError::Solve(SolveError::Cancelled { resumable: true }))
        } else {
            Ok(())
        }
    };
    let cancelled = |e: OutputError| match e {
        OutputError::Cancelled => JobError::Solve(SolveError::Cancelled { resumable: true }),
        e => JobError::Output(e),
    };
    stop()?;
    check_finite(&fields.fluence_total, &store, "fluence", cancel)?;
    check_finite(&fields.source_total, &store, "source", cancel)?;

    // Every output goes to a staging directory first and is published with the others as a set.
    observer.stage(progress::Stage::Export);
    let staging = output::Staging::new(&job.out)?;
    let stage = staging.path().to_path_buf();
    let t = Instant::now();
    let channel_names: Vec<String> =
        if plan.channels == 1 { vec!["grey".into()] } else { ["r", "g", "b"].iter().map(|s| s.to_string()).collect() };
    let mut outputs = Vec::new();
    if !job.no_fields {
        let fluence_meta = FieldMeta {
            quantity: "fluence".into(),
            units: "radiance units × sr (W/m² for radiance in W/m²/sr)".into(),
            components: channel_names.clone(),
            description: "fluence φ = ∫L dω over all scattering orders, per voxel".into(),
            origin: scene.volume.origin.to_array(),
        };
        output::export_field_until(
            &fields.fluence_total,
            &store,
            &stage,
            "fluence",
            &fluence_meta,
            output::EmptyBricks::NotSolved,
            cancel,
        )
        .map_err(cancelled)?;
        test_hook_at_stage("export");
        outputs.extend(["fluence.raw", "fluence.json", "fluence.nhdr"].map(String::from));
        let source_names: Vec<String> = if plan.storage.is_isotropic() {
            channel_names.clone()
        } else {
            (0..plan.storage.len()).flat_map(|d| channel_names.iter().map(move |c| format!("d{d}.{c}"))).collect()
        };
        let source_meta = FieldMeta {
            quantity: "in-scattered source".into(),
            units: "radiance per unit length".into(),
            components: source_names,
            description: if plan.storage.is_isotropic() {
                "in-scattered source J = σs∫p·L dω' summed over orders (isotropic: one value per channel)".into()
            } else {
                format!(
                    "in-scattered source J per storage direction summed over orders; {} storage directions ({}×{} cube-face cells per face), component = direction·channels + channel",
                    plan.storage.len(),
                    plan.storage.per_face,
                    plan.storage.per_face
                )
            },
            origin: scene.volume.origin.to_array(),
        };
        output::export_field_until(
            &fields.source_total,
            &store,
            &stage,
            "source",
            &source_meta,
            output::EmptyBricks::Zero,
            cancel,
        )
        .map_err(cancelled)?;
        outputs.extend(["source.raw", "source.json", "source.nhdr"].map(String::from));
        // The same fields as sparse OpenVDB grids, on the input's index grid and transform.
        let placement = vdb_placement(scene);
        for (field, base, meta) in
            [(&fields.fluence_total, "fluence", &fluence_meta), (&fields.source_total, "source", &source_meta)]
        {
            let name = format!("{base}.vdb");
            output::export_vdb_until(
                field,
                &store,
                &stage.join(&name),
                base,
                meta,
                placement,
                job.vdb_precision,
                cancel,
            )
            .map_err(cancelled)?;
            outputs.push(name);
        }
    }
    // Where the light leaves, per boundary pixel of each face (either backend's maps; none from
    // mirror faces on the GPU, a budget too small for their records, or a solve resumed from a
    // checkpoint that kept no maps, `SolveRun::exit_maps`): faces/, a directory published with
    // the set.
    let mut published = Vec::new();
    if let Some(maps) = &exit_maps {
        let dir = stage.join(solver::exitance::FACES_DIR);
        maps.write(&dir, scene.volume.origin.to_array(), plan.voxel_size)?;
        published.push(solver::exitance::FACES_DIR.to_string());
    }
    phases.push(("export".to_string(), t.elapsed().as_secs_f64()));

    // What `lpm render` needs to render this result again (render-data/, linked, not copied),
    // and the image, rendered from the same data by the same path.
    let camera = scene.camera.clone().unwrap_or_else(|| render::default_camera(plan.dims, plan.voxel_size));
    let display = job.display.apply(scene.display);
    let mut render_data = render::RenderData::new(
        plan.dims,
        plan.voxel_size,
        scene.volume.origin,
        plan.channels,
        &plan.propagation,
        &plan.storage,
        &plan.medium,
        &scene.lights,
        &camera,
        &display,
    );
    render_data.emission_per_voxel = plan.emission_grid;
    render_data.albedo_per_voxel = plan.albedo_field;
    let emission = if plan.emission_grid {
        Some(crate::store::emission::open_emission(&store).map_err(SolveError::from)?)
    } else {
        None
    };
    let albedo = if plan.albedo_field {
        Some(crate::store::albedo::open_albedo(&store).map_err(SolveError::from)?)
    } else {
        None
    };
    if !job.no_render_data || !job.no_image {
        observer.stage(progress::Stage::Render);
    }
    // The suns' first scattering split off the image's source, for the renderer to evaluate
    // exactly (solver::direct); the exported source above is the whole total.
    let split = if !job.no_render_data || !job.no_image {
        let split = solver::direct::split(&plan, &scene.medium, &store, &fields.source_total)?;
        // The trace's time among the phases, not in the plan's reasons: two solves of one scene
        // give equal plans.
        if let Some(solver::direct::BeamIrradiance::Traced { seconds }) = split.as_ref().map(|s| s.irradiance) {
            phases.push(("beam trace".to_string(), seconds));
        }
        match (&split, solver::direct::left_out_because(&plan)) {
            (Some(s), _) => {
                let irradiance = match s.irradiance {
                    solver::direct::BeamIrradiance::NoBeams => String::new(),
                    solver::direct::BeamIrradiance::Traced { .. } => {
                        "; the suns' irradiance traced to each voxel's centre along their exact direction".to_string()
                    }
                    solver::direct::BeamIrradiance::Swept { steps } => {
                        let why = format!(
                            "; the suns' irradiance is order 0's sweep's (tracing it per voxel would take ~{steps} \
                             steps, more than {})",
                            solver::beam_trace::TRACE_LIMIT_STEPS
                        );
                        tracing::info!("image: the suns' irradiance is not traced per voxel{why}");
                        why
                    }
                };
                plan.reasons.push(format!(
                    "image: the single scattering of {} sun(s) and {} point light(s) is evaluated exactly along \
                     each camera ray (true σs, HG g = {}, true extinction{}{irradiance}), their binned first \
                     scattering taken off the image's source (not off the exported source)",
                    s.travel.len(),
                    s.points.len(),
                    scene.medium.g,
                    if s.peak_chains {
                        "; the light δ-M kept in their beams by the forward peak's chains"
                    } else {
                        ""
                    }
                ))
            }
            (None, Some(why)) if !plan.beams.is_empty() || !plan.point_lights.is_empty() => {
                tracing::info!("image: the suns' single scattering is not split off: {why}");
                plan.reasons.push(format!("image: the suns' single scattering is not split off: {why}"));
            }
            (None, _) => {}
        }
        test_hook_at_stage("render");
        split
    } else {
        None
    };
    let (image_source, direct_fields): (&crate::store::Field, &[crate::store::Field]) = match &split {
        Some(s) => {
            render_data.single_scattering = Some(render::keep::SingleScatteringData {
                medium: (&s.medium).into(),
                travel: s.travel.iter().map(|t| t.to_array()).collect(),
                peak_chains: s.peak_chains,
                points: s.points.iter().map(|p| p.to_array()).collect(),
                irradiance_at_centres: matches!(s.irradiance, crate::solver::direct::BeamIrradiance::Traced { .. }),
            });
            (&s.render_source, &s.fields)
        }
        None => (&fields.source_total, &[]),
    };
    stop()?;
    if !job.no_render_data {
        render::keep::keep(
            &stage.join(render::RENDER_DATA),
            &store,
            image_source,
            direct_fields,
            render::keep::environment_light(&scene.lights),
            &render_data,
        )?;
        published.push(render::RENDER_DATA.to_string());
    }
    if !job.no_image {
        let t = Instant::now();
        let image = render::render_solved(
            &render_data,
            &store,
            image_source,
            render::VoxelFactors { emission: emission.as_ref(), albedo: albedo.as_ref(), direct: direct_fields },
            render::keep::environment_light(&scene.lights),
            &camera,
            job.background,
        );
        // The renderer stops at SIGTERM (the process's flag) with the image unfinished: never
        // written as if it were whole.
        if solver::cancel::CancelFlag::process().is_raised() {
            return Err(JobError::Solve(SolveError::Cancelled { resumable: true }));
        }
        stop()?;
        render::write_images(
            Some(&stage.join("image.exr")),
            Some(&stage.join("image.png")),
            &image,
            job.background,
            &display,
        )?;
        outputs.extend(["image.exr", "image.png"].map(String::from));
        phases.push(("render".to_string(), t.elapsed().as_secs_f64()));
    }
    stop()?;
    outputs.push("report.json".into());
    let report = Report {
        lpm_version: env!("CARGO_PKG_VERSION"),
        scene: job.scene.display().to_string(),
        backend: match job.backend {
            BackendKind::Gpu => "gpu",
            BackendKind::Cpu => "cpu",
        },
        device,
        plan: plan.summary(),
        orders: outcome.orders,
        converged: outcome.converged,
        warm_start: warm.map(|d| d.display().to_string()),
        remaining_error: outcome.remaining,
        final_residual: outcome.residual,
        tolerance: plan.tolerance,
        history: outcome.history,
        energy: outcome.energy,
        tail: outcome.tail,
        seconds: phases.into_iter().map(|(phase, seconds)| Phase { phase, seconds }).collect(),
        peak_device_bytes,
        peak_resident_bytes: peak_resident_bytes(),
        store_bytes,
        device_memory: memory,
        host_memory: residency,
        outputs,
    };
    output::write_json_atomic(&stage.join("report.json"), &report)?;
    // render-data/ and faces/ are published with the set but are not among the report's files
    // (directories).
    published.extend(report.outputs.iter().cloned());
    staging.commit(&published)?;
    observer.stage(progress::Stage::Done);
    Ok(report)
}

/// The kill tests' hooks (tests/it/resume.rs), compiled only into `test-hooks` builds: once the
/// export has written its first field (`stage` = "export") or the render its fields in the store
/// ("render"), `LPM_TEST_ABORT_AT_STAGE` = that stage aborts the process as `kill -9` would, and
/// `LPM_TEST_CANCEL_AT_STAGE` raises the process's cancel flag as SIGTERM would.
fn test_hook_at_stage(stage: &str) {
    #[cfg(feature = "test-hooks")]
    {
        let at = |name: &str| std::env::var(name).is_ok_and(|s| s == stage);
        if at("LPM_TEST_ABORT_AT_STAGE") {
            tracing::error!("LPM_TEST_ABORT_AT_STAGE={stage}: aborting as a kill would");
            std::process::abort();
        }
        if at("LPM_TEST_CANCEL_AT_STAGE") {
            tracing::warn!("LPM_TEST_CANCEL_AT_STAGE={stage}: cancelling as SIGTERM would");
            solver::cancel::CancelFlag::process().raise();
        }
    }
    #[cfg(not(feature = "test-hooks"))]
    let _ = stage;
}

/// Where the exported VDB grids lie: on the input VDB's own index grid (its voxel (0, 0, 0) is the
/// input's active box corner), else with voxel (0, 0, 0) at index 0; the transform places them
/// where the volume is (`volume.origin`, `volume.voxel_size`).
pub fn vdb_placement(scene: &Scene) -> output::VdbPlacement {
    let index_min = match &scene.volume.source {
        crate::scene::VolumeSource::Vdb { index_min, .. } => *index_min,
        _ => [0; 3],
    };
    output::VdbPlacement::new(scene.volume.origin.to_array(), scene.volume.voxel_size, index_min)
}

/// The process's peak resident set (VmHWM in /proc/self/status), where the system has it.
pub fn peak_resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{BrickStore, Coverage};

    /// Issue 13, item 3: a non-finite value in a solved voxel fails the job, naming the voxel.
    #[test]
    fn a_non_finite_solved_value_is_an_error_naming_the_voxel() {
        let dir = tempfile::tempdir().unwrap();
        let store = BrickStore::create_with(dir.path(), [20, 20, 20], 1.0, |_, out| {
            out.fill(1.0);
            Ok(())
        })
        .unwrap();
        let mut field = store.create_field("f", 2, Coverage::Occupied).unwrap();
        check_finite(&field, &store, "fluence", None).unwrap();
        let (brick, local) = store.grid().locate([17, 3, 18]);
        field.brick_mut(brick).unwrap()[crate::store::BRICK_VOXELS + local] = f32::INFINITY;
        let e = check_finite(&field, &store, "fluence", None).unwrap_err();
        assert!(matches!(e, JobError::NonFinite { voxel: [17, 3, 18], component: 1, .. }), "{e}");
        assert!(e.to_string().contains("non-finite fluence"), "{e}");
    }
}
