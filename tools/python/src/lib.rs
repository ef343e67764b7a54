//! `lpm._lpm`: the native half of the `lpm` Python package (`tools/python/python/lpm`).
//!
//! Why the split: what must run in Rust — the solve with the GIL released and Ctrl-C turned into
//! the CLI's resumable cancellation, the render, the Monte-Carlo reference, the comparison, the VDB
//! writer, and the library's typed errors turned into Python exceptions — is here, as thin calls
//! into the same functions the `lpm` binary calls (`lpm::job::run`, `lpm::render::keep`,
//! `lpm::reference::job::run`, `lpm::compare::compare_dirs`), so a Python solve *is* the CLI's
//! solve, its output files bitwise the same. What is bookkeeping — scenes as dicts, NumPy volumes
//! written as the raw files a scene names, the output fields memory-mapped as NumPy arrays — is
//! Python (`lpm/_scene.py`, `lpm/_result.py`), where NumPy does it without copies.
//!
//! Errors: every library error becomes an instance of one of the classes of `lpm/errors.py`
//! (`SceneError`, `InputFileError`, `DeviceError`, `OutputError`, `Cancelled`, else the base
//! `Error`), carrying the CLI's one-line message (the error and its causes, as `lpm: …` prints
//! it) and, where the library knows them, the file (`path`) and the scene key (`key`).

use crossbeam_channel::RecvTimeoutError;
use lpm::compare::{CompareError, CompareOptions, CoreMask};
use lpm::job::{JobError, SolveJob};
use lpm::output::{self, OutputError, VdbPlacement, VdbPrecision};
use lpm::reference::job::{ReferenceJob, ReferenceJobError};
use lpm::render::{self, Background};
use lpm::scene::{Scene, SceneError};
use lpm::solver::cancel::CancelFlag;
use lpm::solver::{BackendKind, SolveError};
use lpm::store::StoreError;
use lpm::vk::ContextOptions;
use numpy::{PyArray1, PyArray3, PyArrayMethods, PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How often the thread waiting for a solve looks for Ctrl-C (Python runs its signal handlers
/// only when asked, in the main thread) and hands progress to the callback.
const POLL: Duration = Duration::from_millis(50);

// ---------------------------------------------------------------------------------------------
// Errors

/// Which Python class an error becomes (`lpm/errors.py`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Class {
    Base,
    Scene,
    InputFile,
    Device,
    Output,
    Cancelled,
}

impl Class {
    fn name(self) -> &'static str {
        match self {
            Class::Base => "Error",
            Class::Scene => "SceneError",
            Class::InputFile => "InputFileError",
            Class::Device => "DeviceError",
            Class::Output => "OutputError",
            Class::Cancelled => "Cancelled",
        }
    }
}

/// A library error, classified and worded while the GIL is released; raised later.
#[derive(Debug)]
struct Failure {
    class: Class,
    message: String,
    path: Option<PathBuf>,
    key: Option<String>,
    resumable: Option<bool>,
}

impl Failure {
    fn new(class: Class, e: &(dyn std::error::Error + 'static)) -> Failure {
        Failure { class, message: error_text(e), path: None, key: None, resumable: None }
    }

    fn at(mut self, path: Option<&Path>, key: Option<&str>) -> Failure {
        self.path = path.map(Path::to_path_buf);
        self.key = key.map(str::to_string);
        self
    }

    fn plain(class: Class, message: String) -> Failure {
        Failure { class, message, path: None, key: None, resumable: None }
    }

    fn into_pyerr(self, py: Python<'_>) -> PyErr {
        let build = || -> PyResult<PyErr> {
            let errors = py.import("lpm.errors")?;
            let e = errors.getattr(self.class.name())?.call1((self.message.clone(),))?;
            e.setattr("path", self.path.as_ref().map(|p| p.display().to_string()))?;
            e.setattr("key", self.key.clone())?;
            if let Some(r) = self.resumable {
                e.setattr("resumable", r)?;
            }
            Ok(PyErr::from_value(e))
        };
        build().unwrap_or_else(|e| e)
    }
}

/// The error and its causes in one line, each cause once: what `lpm` prints after `lpm: ` (the
/// same rule as `error_text` in `src/main.rs`, which is private to the binary).
fn error_text(e: &(dyn std::error::Error + 'static)) -> String {
    let mut text = String::new();
    let mut cause: Option<&(dyn std::error::Error + 'static)> = Some(e);
    while let Some(c) = cause {
        let full = c.to_string();
        cause = c.source();
        let part = match full.rfind(" (os error ") {
            Some(i) if full.ends_with(')') && text.contains(&full[..i]) => continue,
            _ => full,
        };
        if !text.contains(&part) {
            if !text.is_empty() {
                text.push_str(": ");
            }
            text.push_str(&part);
        }
    }
    text
}

fn scene_failure(e: &SceneError) -> Failure {
    let class = match e {
        SceneError::Parse { .. } | SceneError::Invalid { .. } => Class::Scene,
        SceneError::Read { .. } | SceneError::BadFile { .. } => Class::InputFile,
        SceneError::RawFile { raw_path, .. } | SceneError::RawSize { raw_path, .. } => {
            return Failure::new(Class::InputFile, e).at(Some(raw_path), e.key())
        }
        SceneError::Map { map_path, .. } => return Failure::new(Class::InputFile, e).at(Some(map_path), e.key()),
        _ => Class::Scene,
    };
    Failure::new(class, e).at(Some(e.path()), e.key())
}

fn store_failure(e: &StoreError) -> Failure {
    match e {
        StoreError::RawSize { path, .. }
        | StoreError::BadDensity { path, .. }
        | StoreError::BadEmission { path, .. }
        | StoreError::BadAlbedo { path, .. }
        | StoreError::BadTemperature { path, .. }
        | StoreError::Nrrd { path, .. }
        | StoreError::Vdb { path, .. }
        | StoreError::FieldShape { path, .. }
        | StoreError::Truncated { path, .. } => Failure::new(Class::InputFile, e).at(Some(path), None),
        StoreError::NoSpace { path, .. } => Failure::new(Class::Output, e).at(Some(path), None),
        _ => Failure::new(Class::Base, e),
    }
}

fn output_failure(e: &OutputError) -> Failure {
    match e {
        OutputError::Store(s) => store_failure(s),
        OutputError::Io { path, .. } | OutputError::Json { path, .. } | OutputError::Invalid { path, .. } => {
            Failure::new(Class::Output, e).at(Some(path), None)
        }
        _ => Failure::new(Class::Output, e),
    }
}

fn solve_failure(e: &SolveError) -> Failure {
    let class = match e {
        SolveError::Store(s) => return store_failure(s),
        SolveError::Checkpoint(o) => return output_failure(o),
        SolveError::Cancelled { resumable } => {
            return Failure { resumable: Some(*resumable), ..Failure::new(Class::Cancelled, e) }
        }
        SolveError::Vulkan(_)
        | SolveError::DeviceLimit { .. }
        | SolveError::BudgetTooSmall { .. }
        | SolveError::BudgetTooLarge { .. }
        | SolveError::Validation(_)
        | SolveError::MirrorsInTheDriver => Class::Device,
        SolveError::WarmStart(_) => Class::InputFile,
        _ => Class::Base,
    };
    Failure::new(class, e)
}

fn job_failure(e: &JobError) -> Failure {
    let mut f = match e {
        JobError::Scene(s) => return scene_failure(s),
        JobError::Solve(s) => return solve_failure(s),
        JobError::Budget { .. } => Failure::new(Class::Device, e),
        JobError::Output(o) => output_failure(o),
        JobError::OutputDir { path, .. } => Failure::new(Class::Output, e).at(Some(path), None),
        JobError::NoMedium { scene } => Failure::new(Class::Scene, e).at(Some(scene), Some("volume")),
        _ => Failure::new(Class::Base, e),
    };
    // The whole chain, worded as the CLI words it.
    f.message = error_text(e);
    f
}

fn reference_failure(e: &ReferenceJobError) -> Failure {
    match e {
        ReferenceJobError::Scene(s) => scene_failure(s),
        ReferenceJobError::Store(s) => store_failure(s),
        ReferenceJobError::Output(o) => output_failure(o),
        ReferenceJobError::OutputDir { path, .. } => Failure::new(Class::Output, e).at(Some(path), None),
        _ => Failure::new(Class::Base, e),
    }
}

fn compare_failure(e: &CompareError) -> Failure {
    match e {
        CompareError::Output(o) => output_failure(o),
        CompareError::Image { path, .. } | CompareError::NonFinite { path, .. } => {
            Failure::new(Class::InputFile, e).at(Some(path), None)
        }
        _ => Failure::new(Class::Base, e),
    }
}

// ---------------------------------------------------------------------------------------------
// Scenes

/// Validates scene `text` exactly as `lpm solve` would (`Scene::from_toml_str`), naming it
/// `nominal` in messages (a relative file it names resolves against `nominal`'s directory); with
/// `dest`, also writes it there with every file it names made absolute, for `lpm::job` to read.
#[pyfunction]
#[pyo3(signature = (text, nominal, base_dir, dest=None))]
fn prepare_scene(
    py: Python<'_>,
    text: &str,
    nominal: PathBuf,
    base_dir: PathBuf,
    dest: Option<PathBuf>,
) -> PyResult<()> {
    let result = py.detach(|| -> Result<(), Failure> {
        Scene::from_toml_str(text, &nominal).map_err(|e| scene_failure(&e))?;
        let Some(dest) = dest else { return Ok(()) };
        let mut table: toml::Table = toml::from_str(text).map_err(|e| {
            Failure::plain(Class::Scene, format!("{}: {}", nominal.display(), e.message())).at(Some(&nominal), None)
        })?;
        lpm::scene::make_file_paths_absolute(&mut table, &base_dir, &[]);
        let staged = toml::to_string(&table).map_err(|e| {
            Failure::plain(Class::Scene, format!("{}: cannot write it as TOML: {e}", nominal.display()))
        })?;
        output::write_atomic(&dest, |w| std::io::Write::write_all(w, staged.as_bytes())).map_err(|e| output_failure(&e))
    });
    result.map_err(|f| f.into_pyerr(py))
}

/// A scene given as a dict (passed as JSON: the keys and values of a scene file) as TOML text.
/// `nominal` names it in messages.
#[pyfunction]
fn dict_to_toml(py: Python<'_>, json: &str, nominal: &str) -> PyResult<String> {
    let fail = |m: String| Failure::plain(Class::Scene, format!("{nominal}: {m}")).into_pyerr(py);
    let value: serde_json::Value = serde_json::from_str(json).map_err(|e| fail(format!("not a scene table: {e}")))?;
    let table = match toml::Value::try_from(value) {
        Ok(toml::Value::Table(table)) => table,
        Ok(_) => return Err(fail("not a scene table".to_string())),
        Err(e) => return Err(fail(format!("not a scene table: {e}"))),
    };
    toml::to_string(&table).map_err(|e| fail(format!("cannot be written as TOML: {e}")))
}

/// Where the exported VDB grids of a solve of the scene file `scene` lie (`lpm::job::vdb_placement`):
/// `(index_min, voxel_size, translation)`.
#[pyfunction]
fn vdb_placement(py: Python<'_>, scene: PathBuf) -> PyResult<([i32; 3], f64, [f64; 3])> {
    let scene = py.detach(|| Scene::load(&scene)).map_err(|e| scene_failure(&e).into_pyerr(py))?;
    let p = lpm::job::vdb_placement(&scene);
    Ok((p.index_min, p.voxel_size, p.translation))
}

/// `"2G"`, `"256M"` (powers of 1024), as `--device-memory-budget` reads it.
#[pyfunction]
fn parse_byte_size(text: &str) -> PyResult<u64> {
    match lpm::scene::validate::parse_byte_size(text) {
        Ok(0) => Err(PyValueError::new_err("the budget must be more than 0 bytes")),
        Ok(n) => Ok(n),
        Err(e) => Err(PyValueError::new_err(e)),
    }
}

/// Creates `out` if missing and fails (`OutputError`, the CLI's message) while another lpm run
/// holds its lock: called before a scene is staged into `out/input`, so that a second solve into
/// a busy `out` changes nothing there.
#[pyfunction]
fn check_unlocked(py: Python<'_>, out: PathBuf) -> PyResult<()> {
    py.detach(|| -> Result<(), Failure> {
        std::fs::create_dir_all(&out).map_err(|e| {
            Failure::plain(Class::Output, format!("cannot create output directory {}: {e}", out.display()))
                .at(Some(&out), None)
        })?;
        output::DirLock::acquire(&out).map(drop).map_err(|e| output_failure(&e))
    })
    .map_err(|f| f.into_pyerr(py))
}

// ---------------------------------------------------------------------------------------------
// Solve

fn backend_kind(name: &str) -> PyResult<BackendKind> {
    match name {
        "gpu" => Ok(BackendKind::Gpu),
        "cpu" => Ok(BackendKind::Cpu),
        _ => Err(PyValueError::new_err(format!("backend must be \"gpu\" or \"cpu\", not {name:?}"))),
    }
}

fn background(name: &str) -> PyResult<Background> {
    match name {
        "sky" => Ok(Background::Sky),
        "transparent" => Ok(Background::Transparent),
        _ => Err(PyValueError::new_err(format!("background must be \"sky\" or \"transparent\", not {name:?}"))),
    }
}

/// `exposure` (stops, or "auto") and `view` ("standard", "filmic", "agx") as the CLI's flags take them.
fn display_change(exposure: Option<&str>, view: Option<&str>) -> PyResult<render::keep::DisplayChange> {
    let exposure = exposure
        .map(|e| e.parse::<lpm::scene::Exposure>().map_err(|m| PyValueError::new_err(format!("exposure {m}"))))
        .transpose()?;
    let view = view
        .map(|v| {
            lpm::scene::View::from_name(v).ok_or_else(|| {
                PyValueError::new_err(format!("view must be one of {}, not {v:?}", lpm::scene::VIEW_NAMES))
            })
        })
        .transpose()?;
    Ok(render::keep::DisplayChange { exposure, view })
}

fn vdb_precision(name: &str) -> PyResult<VdbPrecision> {
    match name {
        "float" => Ok(VdbPrecision::Float),
        "half" => Ok(VdbPrecision::Half),
        _ => Err(PyValueError::new_err(format!("vdb_precision must be \"float\" or \"half\", not {name:?}"))),
    }
}

/// The threads of one solve (0: one per core): a pool of its own, so that solves in several
/// Python threads each get theirs and the CLI's `--threads` is a per-call argument here.
fn thread_pool(py: Python<'_>, threads: usize) -> PyResult<rayon::ThreadPool> {
    let threads = checked_threads(threads)?;
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Failure::plain(Class::Base, format!("could not start the solver's threads: {e}")).into_pyerr(py))
}

/// `threads` if this machine takes it (`lpm::threads`: a few per core), else a ValueError naming
/// the limit.
fn checked_threads(threads: usize) -> PyResult<usize> {
    lpm::threads::checked(threads).map_err(|e| PyValueError::new_err(e.to_string().replace("--threads ", "threads=")))
}

/// An order done, with the job's estimate right after it (`lpm::progress::Estimator`: the one the
/// CLI's bar, `progress.json` and `lpm serve` show).
struct OrderEvent {
    order: u32,
    residual: f64,
    fraction: f64,
    seconds_left: Option<f64>,
}

/// Hands each order done to the waiting thread with the estimate the job makes right after it.
struct Orders {
    tx: crossbeam_channel::Sender<OrderEvent>,
    done: Option<lpm::progress::OrderDone>,
}

impl lpm::progress::Observer for Orders {
    fn order_done(&mut self, done: &lpm::progress::OrderDone) {
        self.done = Some(*done);
    }
    fn estimate(&mut self, estimate: &lpm::progress::Estimate) {
        // Only the estimates that follow an order (the job estimates after each stage as well).
        if let Some(done) = self.done.take() {
            let _ = self.tx.send(OrderEvent {
                order: done.order,
                residual: done.residual,
                fraction: estimate.fraction,
                seconds_left: estimate.seconds_left,
            });
        }
    }
}

/// Runs `lpm solve SCENE --out OUT …` (`lpm::job::run`) with the GIL released, and returns
/// `report.json`'s text. The solve runs on a thread of its own while this one waits: every 50 ms it
/// looks for Ctrl-C (a pending `KeyboardInterrupt`) and hands each finished order to `progress`.
/// Ctrl-C, or an exception raised by `progress`, raises the solve's cancel flag: the GPU backend
/// stops at its next slice keeping its last checkpoint, exactly as the CLI does on SIGINT, and
/// `lpm.Cancelled` (a `KeyboardInterrupt`) is raised, or the callback's exception. The CPU backend
/// stops before its next direction's sweep (it keeps no checkpoint), as the CLI's does.
#[pyfunction]
#[pyo3(signature = (scene, out, backend="gpu", device=None, device_memory_budget=None, threads=0, resume=false,
    fresh=false, keep_store=false, no_image=false, no_fields=false, no_render_data=false, vdb_precision="float",
    background="sky", warm_start=None, validation=false, progress=None))]
#[allow(clippy::too_many_arguments)]
fn solve(
    py: Python<'_>,
    scene: PathBuf,
    out: PathBuf,
    backend: &str,
    device: Option<usize>,
    device_memory_budget: Option<u64>,
    threads: usize,
    resume: bool,
    fresh: bool,
    keep_store: bool,
    no_image: bool,
    no_fields: bool,
    no_render_data: bool,
    vdb_precision: &str,
    background: &str,
    warm_start: Option<PathBuf>,
    validation: bool,
    progress: Option<Py<PyAny>>,
) -> PyResult<String> {
    if let Some(cb) = &progress {
        if !cb.bind(py).is_callable() {
            return Err(pyo3::exceptions::PyTypeError::new_err(
                "progress must be callable (it is called with a dict per event)",
            ));
        }
    }
    if device_memory_budget == Some(0) {
        return Err(PyValueError::new_err("device_memory_budget must be more than 0 bytes"));
    }
    // Read once here for the progress estimate (the job reads it again, as the CLI does).
    let loaded = py.detach(|| Scene::load(&scene)).map_err(|e| scene_failure(&e).into_pyerr(py))?;
    let (max_orders, tolerance) = (loaded.solver.max_orders, loaded.solver.tolerance);
    let cancel = CancelFlag::new();
    let job = SolveJob {
        backend: backend_kind(backend)?,
        vk: ContextOptions { validation, device_index: device, ..ContextOptions::default() },
        keep_store,
        no_image,
        no_fields,
        device_memory_budget,
        resume,
        fresh,
        cancel: Some(cancel),
        warm_start,
        vdb_precision: self::vdb_precision(vdb_precision)?,
        background: self::background(background)?,
        no_render_data,
        ..SolveJob::new(scene, out)
    };
    let pool = thread_pool(py, threads)?;
    let (tx, rx) = crossbeam_channel::unbounded::<OrderEvent>();
    let started = Instant::now();
    // The first exception met while waiting (Ctrl-C, or one raised by the callback).
    let mut pending: Option<PyErr> = None;
    let call = |pending: &mut Option<PyErr>, event: Bound<'_, PyDict>| {
        if let (None, Some(cb)) = (pending.as_ref(), progress.as_ref()) {
            if let Err(e) = cb.bind(py).call1((event,)) {
                cancel.raise();
                *pending = Some(e);
            }
        }
    };
    let joined = std::thread::scope(|s| {
        let (job, pool) = (&job, &pool);
        let handle = s.spawn(move || pool.install(|| lpm::job::run(job, Orders { tx, done: None })));
        let event = PyDict::new(py);
        let _ = event.set_item("phase", "store");
        let _ = event.set_item("message", "building the brick store");
        let _ = event.set_item("max_orders", max_orders);
        let _ = event.set_item("tolerance", tolerance);
        call(&mut pending, event);
        loop {
            match py.detach(|| rx.recv_timeout(POLL)) {
                Ok(OrderEvent { order, residual, fraction, seconds_left }) => {
                    let seconds = started.elapsed().as_secs_f64();
                    let event = PyDict::new(py);
                    let _ = event.set_item("phase", "orders");
                    let _ = event.set_item("message", format!("order {order} done, residual {residual:.3e}"));
                    let _ = event.set_item("order", order);
                    let _ = event.set_item("residual", residual);
                    let _ = event.set_item("max_orders", max_orders);
                    let _ = event.set_item("tolerance", tolerance);
                    let _ = event.set_item("seconds", seconds);
                    let _ = event.set_item("fraction", fraction);
                    let _ = event.set_item("seconds_left", seconds_left);
                    call(&mut pending, event);
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            if pending.is_none() {
                if let Err(e) = py.check_signals() {
                    cancel.raise();
                    pending = Some(e);
                }
            }
        }
        py.detach(|| handle.join())
    });
    let result = match joined {
        Ok(result) => result,
        Err(panic) => {
            let why = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            return Err(
                Failure::plain(Class::Base, format!("internal error: the solve panicked: {why}")).into_pyerr(py)
            );
        }
    };
    let interrupted = pending.as_ref().is_some_and(|e| e.is_instance_of::<pyo3::exceptions::PyKeyboardInterrupt>(py));
    match (result, pending) {
        // Ctrl-C stopped the solve: the CLI's cancellation, as `lpm.Cancelled` (a KeyboardInterrupt).
        (Err(JobError::Solve(e @ SolveError::Cancelled { .. })), Some(_)) if interrupted => {
            Err(solve_failure(&e).into_pyerr(py))
        }
        // The callback's own exception (the solve stopped, or ended, because of it); or Ctrl-C
        // during a solve that could not be stopped (the CPU backend), raised after it ended.
        (_, Some(e)) => Err(e),
        (Err(e), None) => Err(job_failure(&e).into_pyerr(py)),
        (Ok(report), None) => serde_json::to_string(&report)
            .map_err(|e| Failure::plain(Class::Base, format!("cannot serialise the report: {e}")).into_pyerr(py)),
    }
}

// ---------------------------------------------------------------------------------------------
// Render, reference, compare

/// `lpm render OUT [--camera FILE] [--width …] …`: renders the solved result in `out` again from
/// its `render-data/` and returns the image as RGBA f32, shape (height, width, 4), top row first
/// (colour linear; alpha = 1 − transmittance). With `image`, also writes it there (.exr or .png),
/// as `--image` does.
#[pyfunction]
#[pyo3(name = "render", signature = (out, camera=None, width=None, height=None, eye=None, target=None, up=None, fov=None,
    background="sky", image=None, exposure=None, view=None))]
#[allow(clippy::too_many_arguments)]
fn render_again<'py>(
    py: Python<'py>,
    out: PathBuf,
    camera: Option<PathBuf>,
    width: Option<u32>,
    height: Option<u32>,
    eye: Option<[f64; 3]>,
    target: Option<[f64; 3]>,
    up: Option<[f64; 3]>,
    fov: Option<f64>,
    background: &str,
    image: Option<PathBuf>,
    exposure: Option<&str>,
    view: Option<&str>,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let background = self::background(background)?;
    let display = display_change(exposure, view)?;
    let (exr, png) = match &image {
        None => (None, None),
        Some(p) => match p.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
            Some("exr") => (Some(p.clone()), None),
            Some("png") => (None, Some(p.clone())),
            _ => {
                return Err(PyValueError::new_err(format!("image {}: the name must end in .exr or .png", p.display())))
            }
        },
    };
    let change = render::keep::ViewChange { width, height, eye, target, up, fov_y: fov };
    let img = py
        .detach(|| -> Result<render::Image, Failure> {
            let _lock = output::DirLock::acquire(&out).map_err(|e| output_failure(&e))?;
            let kept = render::keep::open(&out).map_err(|e| output_failure(&e))?;
            let display =
                render::keep::view_display(&kept, camera.as_deref(), &display).map_err(|e| scene_failure(&e))?;
            let camera = render::keep::view_camera(&kept, camera.as_deref(), &change).map_err(|e| scene_failure(&e))?;
            render::memory::check_image_fits(camera.width, camera.height)
                .map_err(|e| Failure::plain(Class::Base, e.to_string()))?;
            let img = kept.render(&camera, background);
            render::write_images(exr.as_deref(), png.as_deref(), &img, background, &display)
                .map_err(|e| output_failure(&e))?;
            Ok(img)
        })
        .map_err(|f| f.into_pyerr(py))?;
    let pixels = img.width as usize * img.height as usize;
    let mut rgba = Vec::with_capacity(4 * pixels);
    for p in 0..pixels {
        rgba.extend_from_slice(&img.rgb[3 * p..3 * p + 3]);
        rgba.push(img.alpha.as_ref().map_or(1.0, |a| a[p]));
    }
    PyArray1::from_vec(py, rgba).reshape([img.height as usize, img.width as usize, 4])
}

/// `lpm reference SCENE --out OUT --samples N …` with the GIL released; returns `report.json`'s text.
#[pyfunction]
#[pyo3(signature = (scene, out, samples, seed=0, image_spp=0, threads=0, orders=None))]
#[allow(clippy::too_many_arguments)] // the CLI's options, one argument each
fn reference(
    py: Python<'_>,
    scene: PathBuf,
    out: PathBuf,
    samples: u64,
    seed: u64,
    image_spp: u32,
    threads: usize,
    orders: Option<&str>,
) -> PyResult<String> {
    let image_orders = match orders {
        None => lpm::reference::Orders::ALL,
        Some(text) => text.parse().map_err(PyValueError::new_err)?,
    };
    let job = ReferenceJob {
        scene,
        out,
        photons: samples,
        seed,
        threads: checked_threads(threads)?,
        image_samples_per_pixel: image_spp,
        image_orders,
    };
    let report = py.detach(|| lpm::reference::job::run(&job)).map_err(|e| reference_failure(&e).into_pyerr(py))?;
    serde_json::to_string(&report)
        .map_err(|e| Failure::plain(Class::Base, format!("cannot serialise the report: {e}")).into_pyerr(py))
}

/// `lpm compare A B [--scene SCENE] …` with the GIL released; returns the comparison as JSON (what
/// `--json` writes) and as the text the CLI prints.
#[pyfunction]
#[pyo3(signature = (a, b, max_rel_stderr=0.05, scene=None, core_quantile=lpm::compare::DEFAULT_CORE_QUANTILE, json=None))]
fn compare(
    py: Python<'_>,
    a: PathBuf,
    b: PathBuf,
    max_rel_stderr: f64,
    scene: Option<PathBuf>,
    core_quantile: f64,
    json: Option<PathBuf>,
) -> PyResult<(String, String)> {
    py.detach(|| -> Result<(String, String), Failure> {
        let core = match scene {
            Some(path) => {
                let scene = Scene::load(&path).map_err(|e| scene_failure(&e))?;
                // A scratch store beside A with an unpredictable name, as the CLI makes it.
                let scratch = tempfile_in(&a)?;
                let density = lpm::solver::density_volume(&scene, &scratch.join("store"));
                let _ = std::fs::remove_dir_all(&scratch);
                Some(CoreMask { density: density.map_err(|e| solve_failure(&e))?, quantile: core_quantile })
            }
            None => None,
        };
        let c = lpm::compare::compare_dirs(&a, &b, &CompareOptions { max_relative_stderr: max_rel_stderr, core })
            .map_err(|e| compare_failure(&e))?;
        if let Some(path) = json {
            lpm::compare::write_comparison_json(&path, &c).map_err(|e| output_failure(&e))?;
        }
        let text = serde_json::to_string(&c)
            .map_err(|e| Failure::plain(Class::Base, format!("cannot serialise the comparison: {e}")))?;
        Ok((text, c.to_string()))
    })
    .map_err(|f| f.into_pyerr(py))
}

/// A fresh directory `dir/.lpm-compare-density-N` (created exclusively: two compares may run at once).
fn tempfile_in(dir: &Path) -> Result<PathBuf, Failure> {
    for n in 0..1000u32 {
        let path = dir.join(format!(".lpm-compare-density-{}-{n}", std::process::id()));
        match std::fs::create_dir(&path) {
            Ok(()) => return Ok(path),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => {
                return Err(Failure::plain(
                    Class::Output,
                    format!("{}: cannot create a scratch directory: {e}", path.display()),
                )
                .at(Some(&path), None))
            }
        }
    }
    Err(Failure::plain(Class::Output, format!("{}: no free scratch directory name", dir.display())))
}

// ---------------------------------------------------------------------------------------------
// VDB

/// One grid to write: its name, its string metadata, its values indexed [x, y, z].
type GridIn<'py> = (String, Vec<(String, String)>, PyReadonlyArray3<'py, f32>);

/// Writes `grids` (name, metadata, array indexed [x, y, z]) as float grids of one OpenVDB file at
/// `path`, atomically, with lpm's own writer (`lpm::output::write_vdb`, the one `fluence.vdb` is
/// written with). The voxels where `active` is finite are the active ones (for a fluence, NaN marks
/// the unsolved empty bricks); only 8³ leaves holding one are written; a NaN value is written as
/// the background 0. Voxel `v` is VDB index `index_min + v`, its centre at `translation + h·index`.
#[pyfunction]
#[pyo3(signature = (path, grids, active, index_min, voxel_size, translation, precision="float"))]
#[allow(clippy::too_many_arguments)]
fn write_vdb<'py>(
    py: Python<'py>,
    path: PathBuf,
    grids: Vec<GridIn<'py>>,
    active: PyReadonlyArray3<'py, f32>,
    index_min: [i32; 3],
    voxel_size: f64,
    translation: [f64; 3],
    precision: &str,
) -> PyResult<()> {
    let precision = vdb_precision(precision)?;
    let shape = active.shape().to_vec();
    let dims: [i64; 3] = [shape[0] as i64, shape[1] as i64, shape[2] as i64];
    for (name, _, g) in &grids {
        if g.shape() != shape.as_slice() {
            return Err(PyValueError::new_err(format!(
                "grid {name:?} has shape {:?}, but the active mask has {:?}",
                g.shape(),
                shape
            )));
        }
    }
    if grids.is_empty() {
        return Err(PyValueError::new_err("no grids to write"));
    }
    if (0..3).any(|a| i64::from(index_min[a]) + dims[a] > i64::from(i32::MAX)) {
        return Err(PyValueError::new_err("the volume's index box does not fit OpenVDB's 32-bit coordinates"));
    }
    let active = active.as_array();
    let views: Vec<_> = grids.iter().map(|(_, _, g)| g.as_array()).collect();
    let outs: Vec<output::GridOut> = grids
        .iter()
        .enumerate()
        .map(|(c, (name, metadata, _))| output::GridOut {
            name: name.clone(),
            metadata: metadata.clone(),
            component: c as u32,
        })
        .collect();
    let placement = VdbPlacement { index_min, voxel_size, translation };
    py.detach(|| -> Result<(), Failure> {
        // Leaf voxel n (x slowest, z fastest) of the leaf at `origin`, as a voxel of the arrays.
        let voxel = |origin: [i32; 3], n: usize| -> Option<[usize; 3]> {
            let p = [origin[0] + (n >> 6) as i32, origin[1] + ((n >> 3) & 7) as i32, origin[2] + (n & 7) as i32];
            let v: [i64; 3] = std::array::from_fn(|a| i64::from(p[a]) - i64::from(index_min[a]));
            ((0..3).all(|a| v[a] >= 0 && v[a] < dims[a])).then(|| v.map(|x| x as usize))
        };
        let is_active = |v: [usize; 3]| active[v].is_finite();
        let mut leaves = Vec::new();
        let lo: [i32; 3] = std::array::from_fn(|a| index_min[a] >> 3);
        let hi: [i32; 3] = std::array::from_fn(|a| (index_min[a] + dims[a] as i32 - 1) >> 3);
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    let origin = [x << 3, y << 3, z << 3];
                    if (0..512).any(|n| voxel(origin, n).is_some_and(is_active)) {
                        leaves.push(origin);
                    }
                }
            }
        }
        leaves.sort_unstable_by_key(|&c| output::tree_order(c));
        let mask = |origin: [i32; 3]| {
            let mut mask = [0u64; 8];
            for n in 0..512 {
                if voxel(origin, n).is_some_and(is_active) {
                    mask[n >> 6] |= 1 << (n & 63);
                }
            }
            mask
        };
        let mut values = |c: u32, origin: [i32; 3], out: &mut [f32; 512]| {
            for (n, o) in out.iter_mut().enumerate() {
                *o = match voxel(origin, n) {
                    Some(v) if is_active(v) => views[c as usize][v],
                    _ => 0.0,
                };
                if !o.is_finite() {
                    *o = 0.0;
                } else if precision == VdbPrecision::Half && o.abs() > 65504.0 {
                    *o = 65504.0f32.copysign(*o);
                }
            }
        };
        output::write_atomic(&path, |w| output::write_vdb(w, &leaves, &outs, placement, precision, &mask, &mut values))
            .map_err(|e| output_failure(&e))
    })
    .map_err(|f| f.into_pyerr(py))
}

#[pymodule]
fn _lpm(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(prepare_scene, m)?)?;
    m.add_function(wrap_pyfunction!(dict_to_toml, m)?)?;
    m.add_function(wrap_pyfunction!(vdb_placement, m)?)?;
    m.add_function(wrap_pyfunction!(parse_byte_size, m)?)?;
    m.add_function(wrap_pyfunction!(check_unlocked, m)?)?;
    m.add_function(wrap_pyfunction!(solve, m)?)?;
    m.add_function(wrap_pyfunction!(render_again, m)?)?;
    m.add_function(wrap_pyfunction!(reference, m)?)?;
    m.add_function(wrap_pyfunction!(compare, m)?)?;
    m.add_function(wrap_pyfunction!(write_vdb, m)?)?;
    Ok(())
}
