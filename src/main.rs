//! The `lpm` command line: a thin layer over the library that reports errors in plain words.
//!
//! Over 450 lines because clap's derive keeps every subcommand's flags and their help in one
//! `Command` enum; splitting it would scatter the CLI reference the help text is.

use anyhow::{bail, Context as _, Result};
use clap::{Parser, Subcommand, ValueEnum};
use lpm::job::{self, SolveJob};
use lpm::solver::BackendKind;
use lpm::vk::ContextOptions;
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "lpm",
    version,
    about = "Light transport in participating media: Light Propagation Maps streamed out of core on Vulkan",
    long_about = "Solves multiple scattering of light in a voxel volume of smoke, cloud or fog lit by a sky, \
                  an environment map, suns and point lights, and renders it. See README.md for the scene \
                  format and the outputs."
)]
struct Cli {
    /// Log detail: error, warn, info, debug or trace (RUST_LOG overrides).
    #[arg(long, global = true, default_value = "info", env = "LPM_LOG")]
    log: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Solve a scene: writes fluence.*, source.*, image.exr, image.png and report.json to --out.
    Solve {
        /// The scene file (TOML); with --task, a sweep manifest.
        scene: PathBuf,
        /// Output directory (created if missing; existing outputs are replaced atomically).
        #[arg(long, short, required_unless_present = "task")]
        out: Option<PathBuf>,
        /// Run task N of the sweep manifest SCENE into its own directory (see `lpm sweep`); without
        /// a value, N is taken from SLURM_ARRAY_TASK_ID. Safe to re-run (a done task is skipped, a
        /// killed one resumes from its checkpoint) and to run concurrently.
        #[arg(long, num_args = 0..=1, default_missing_value = "slurm", conflicts_with_all = ["out", "resume"])]
        task: Option<String>,
        /// Where the sweeps run: the Vulkan device, or the CPU (the GPU kernels' twin in f64, on
        /// every core; it keeps its fields in memory, so it suits volumes that fit in RAM).
        #[arg(long, value_enum, default_value_t = Backend::Gpu)]
        backend: Backend,
        /// Threads of the CPU backend (0: all cores). The result is bitwise the same at any count.
        #[arg(long, default_value_t = 0)]
        threads: usize,
        /// Vulkan physical device index (default: the first discrete GPU, else the best available).
        #[arg(long, env = "LPM_DEVICE")]
        device: Option<usize>,
        /// Enable the Khronos validation layer with synchronization validation.
        #[arg(long, env = "LPM_VALIDATION", value_parser = clap::builder::BoolishValueParser::new())]
        validation: Option<bool>,
        /// Keep the brick store (medium and solver fields) in OUT/store.
        #[arg(long)]
        keep_store: bool,
        /// Do not render image.exr / image.png.
        #[arg(long)]
        no_image: bool,
        /// Do not export fluence.* and source.* (dense raw volumes: 4 bytes per voxel and component,
        /// empty bricks included, which for a large sparse volume can dwarf the brick store). With
        /// --keep-store the solved fields are kept in brick form in OUT/store.
        #[arg(long)]
        no_fields: bool,
        /// Device memory the solver may allocate (slices, ray state, staging), e.g. 256M or 2G
        /// (K/M/G/T = powers of 1024). Default: the scene's solver.device_memory_budget, else half
        /// of the device's memory heap. Smaller budgets cut the sweeps finer; results are identical.
        #[arg(long, env = "LPM_DEVICE_MEMORY_BUDGET", value_parser = parse_budget)]
        device_memory_budget: Option<u64>,
        /// Continue a solve that was killed or failed: picks up after the last completed order
        /// checkpointed in OUT/.lpm-work (GPU backend). The result is bitwise the same.
        #[arg(long, conflicts_with = "fresh")]
        resume: bool,
        /// Discard the checkpoint of an unfinished solve in OUT/.lpm-work and start over. Without
        /// --resume or --fresh, a solve into an OUT holding such a checkpoint refuses to start.
        #[arg(long)]
        fresh: bool,
        /// Start from the solution in DIR (the output directory of an earlier solve of a scene of
        /// the same size, with its fields: e.g. the previous frame) instead of from nothing; the
        /// answer is the cold solve's, within the tolerance (GPU backend).
        #[arg(long, value_name = "DIR", conflicts_with = "task")]
        warm_start: Option<PathBuf>,
        /// Precision of fluence.vdb and source.vdb: float (exactly the raw values) or half (half
        /// the size; values beyond ±65504 are clamped).
        #[arg(long, value_enum, default_value_t = VdbPrecisionArg::Float)]
        vdb_precision: VdbPrecisionArg,
        /// What the image shows behind the volume: the sky (baked into the colour), or nothing
        /// (transparent: colour premultiplied by alpha = 1 − transmittance, for compositing).
        #[arg(long, value_enum, default_value_t = BackgroundArg::Sky)]
        background: BackgroundArg,
        #[command(flatten)]
        display: DisplayArgs,
        /// Do not keep OUT/render-data (the density and solved source in brick form, linked from
        /// the solver's store) that `lpm render OUT` renders new views from.
        #[arg(long)]
        no_render_data: bool,
        /// Read inputs only from under DIR (every symbolic link resolved, checked on each opened
        /// file): how `lpm serve` starts its solves, confined to its data root.
        #[arg(long, value_name = "DIR", hide = true)]
        confine_to: Option<PathBuf>,
    },
    /// Monte-Carlo reference solution of a scene (independent of the LPM solver): writes fluence.*,
    /// fluence_stderr.* (per-voxel standard error), image.* when --image-spp > 0, and report.json.
    Reference {
        /// The scene file (TOML).
        scene: PathBuf,
        /// Output directory (created if missing; written only when complete).
        #[arg(long, short)]
        out: PathBuf,
        /// Photons per channel (an RGB scene traces three times as many); rounded up to a multiple
        /// of the 16 batches the standard error is estimated from.
        #[arg(long)]
        samples: u64,
        /// Random seed: the same seed gives bitwise the same result, whatever the thread count.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Camera paths per pixel for image.exr/.png (0: no image). The default camera is 512 px wide.
        #[arg(long, default_value_t = 0)]
        image_spp: u32,
        /// Count in the image only the light scattered this many times: N, N..M (inclusive) or
        /// N.. (0: the sky and the medium's emission seen unscattered, 1: single scattering).
        /// Images of 0..1 and 2.. with one seed add up to the whole image. Default: every order.
        #[arg(long, value_name = "ORDERS")]
        orders: Option<lpm::reference::Orders>,
        /// Worker threads (0: all cores).
        #[arg(long, default_value_t = 0)]
        threads: usize,
    },
    /// Compare output directory A (e.g. a solve) against B (e.g. a reference): relative L2, RMSE,
    /// max relative error and mean bias of the fluence (voxels where B's standard error is small),
    /// and of the images when both have one.
    Compare {
        a: PathBuf,
        b: PathBuf,
        /// Also write the comparison as JSON to this file.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Use only voxels whose reference standard error is at most this fraction of its fluence.
        #[arg(long, default_value_t = 0.05)]
        max_rel_stderr: f64,
        /// The scene both were solved from: its density adds a "core" row (the densest voxels).
        #[arg(long)]
        scene: Option<PathBuf>,
        /// With --scene: the density quantile where the core starts (0.9: the densest 10 %).
        #[arg(long, default_value_t = lpm::compare::DEFAULT_CORE_QUANTILE)]
        core_quantile: f64,
        /// Exit with status 2 when the fluence's relative L2 error is above this (or no voxel could
        /// be compared), so scripts can use the comparison as a check.
        #[arg(long, value_parser = parse_limit)]
        fail_above: Option<f64>,
    },
    /// Benchmarks that print JSON (see README, "Benchmarks").
    Bench {
        #[command(subcommand)]
        what: BenchCommand,
    },
    /// Expand a sweep manifest (frames and/or parameters) into numbered tasks, each in its own
    /// directory; write a Slurm array script (--slurm), submit it (--submit), or summarise the
    /// tasks' states (--status). See README, "Cluster jobs with Slurm".
    Sweep {
        /// The manifest (TOML).
        manifest: PathBuf,
        /// Write DIR/sweep.sbatch, an `sbatch --array` script running one task per array index.
        #[arg(long)]
        slurm: bool,
        /// Also submit the script with sbatch (implies --slurm).
        #[arg(long)]
        submit: bool,
        /// Summarise done / running / interrupted / failed / pending tasks from their directories.
        #[arg(long, conflicts_with_all = ["slurm", "submit"])]
        status: bool,
        /// Gather every task's parameters, state, orders, seconds, R, T and absorptance into
        /// DIR/results.csv and DIR/results.json.
        #[arg(long, conflicts_with_all = ["slurm", "submit", "status"])]
        collect: bool,
    },
    /// Run the job server: an HTTP/JSON API under /v1 with a durable queue (see README, "Running
    /// lpm as a service").
    #[cfg(feature = "service")]
    Serve {
        /// Address to listen on. Any non-loopback address needs a token.
        #[arg(long, default_value = "127.0.0.1:8417")]
        listen: std::net::SocketAddr,
        /// The data root: the queue, the jobs' directories, uploaded volumes. Scenes may name
        /// volumes only under it.
        #[arg(long, default_value = "lpm-data")]
        data: PathBuf,
        /// File holding the bearer token clients must send (else the LPM_SERVE_TOKEN variable).
        #[arg(long)]
        token_file: Option<PathBuf>,
        /// Vulkan device indices to run jobs on, comma-separated (default: the solve's default device).
        #[arg(long, value_delimiter = ',')]
        devices: Vec<usize>,
        /// Jobs run at once per device (0: accept and queue jobs but run none, e.g. while the GPU is serviced).
        #[arg(long, default_value_t = 1)]
        workers: usize,
        /// Most jobs waiting; more are refused with 503 and Retry-After.
        #[arg(long, default_value_t = 256)]
        max_queued: u64,
        /// Largest scene accepted (K/M/G suffixes).
        #[arg(long, default_value = "1M", value_parser = parse_budget)]
        max_body: u64,
        /// Largest volume upload accepted (K/M/G suffixes).
        #[arg(long, default_value = "4G", value_parser = parse_budget)]
        max_upload: u64,
        /// Device memory budget of jobs that name none.
        #[arg(long, value_parser = parse_budget)]
        device_memory_budget: Option<u64>,
        /// Delete ended jobs (and their outputs) this many hours after they end.
        #[arg(long)]
        retention_hours: Option<f64>,
    },
    /// Submit a scene to a server; prints the job's id (with --wait, waits until it ends).
    #[cfg(feature = "service")]
    Submit {
        scene: PathBuf,
        /// Send this volume file with the scene (multipart upload; repeatable): the scene names it
        /// by its file name, e.g. `raw = "cloud.raw"`.
        #[arg(long)]
        volume: Vec<PathBuf>,
        #[command(flatten)]
        server: ServerArgs,
        /// Higher runs first.
        #[arg(long, default_value_t = 0)]
        priority: i64,
        /// Device memory budget of this job (K/M/G suffixes).
        #[arg(long)]
        device_memory_budget: Option<String>,
        #[arg(long)]
        no_image: bool,
        #[arg(long)]
        no_fields: bool,
        /// Wait until the job ends; exit 1 unless it is done.
        #[arg(long)]
        wait: bool,
    },
    /// Print a job's state as JSON (all jobs without ID); --cancel cancels it, --resume queues it again.
    #[cfg(feature = "service")]
    Status {
        id: Option<i64>,
        #[command(flatten)]
        server: ServerArgs,
        /// Hold until the job changes, at most this many seconds.
        #[arg(long)]
        wait: Option<f64>,
        /// Cancel the job (a running solve stops and keeps its checkpoint); an ended job is deleted.
        #[arg(long, requires = "id", conflicts_with = "resume")]
        cancel: bool,
        /// Queue a cancelled or failed job again: it continues from its checkpoint.
        #[arg(long, requires = "id")]
        resume: bool,
    },
    /// Download a done job's outputs (all, or the NAMEs given) into --out.
    #[cfg(feature = "service")]
    Fetch {
        id: i64,
        names: Vec<String>,
        #[command(flatten)]
        server: ServerArgs,
        #[arg(long, short)]
        out: PathBuf,
    },
    /// Render a solved result again from another view without solving: reads DIR/render-data (kept
    /// by `lpm solve`) and writes DIR/image.exr and DIR/image.png (or --image PATH), atomically.
    /// With no camera option the view is the solve's own (the same image, bitwise).
    Render {
        /// An output directory of `lpm solve`.
        dir: PathBuf,
        /// A camera file: a [camera] table as in a scene (or its keys at the top level); keys it
        /// omits take the defaults a scene's camera takes. The flags below apply on top of it.
        #[arg(long)]
        camera: Option<PathBuf>,
        /// Image width in pixels (given alone, the height follows the view's aspect ratio).
        #[arg(long)]
        width: Option<u32>,
        /// Image height in pixels (given alone, the width follows the view's aspect ratio).
        #[arg(long)]
        height: Option<u32>,
        /// Eye position X,Y,Z in world units.
        #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
        eye: Option<[f64; 3]>,
        /// Point looked at X,Y,Z in world units.
        #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
        target: Option<[f64; 3]>,
        /// Up vector X,Y,Z.
        #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
        up: Option<[f64; 3]>,
        /// Vertical field of view in degrees (pinhole cameras).
        #[arg(long)]
        fov: Option<f64>,
        /// What the image shows behind the volume (as for `solve`).
        #[arg(long, value_enum, default_value_t = BackgroundArg::Sky)]
        background: BackgroundArg,
        #[command(flatten)]
        display: DisplayArgs,
        /// Write this one file instead (its extension, .exr or .png, says which).
        #[arg(long)]
        image: Option<PathBuf>,
    },
    /// Print what a solve wrote to DIR: the plan, orders, residual, energy balance and the fields.
    Info {
        /// An output directory of `lpm solve`.
        dir: PathBuf,
        /// Print report.json as it is instead of a summary.
        #[arg(long)]
        json: bool,
    },
}

#[cfg(feature = "service")]
#[derive(clap::Args)]
struct ServerArgs {
    /// The server's URL.
    #[arg(long, env = "LPM_SERVER", default_value = "http://127.0.0.1:8417")]
    server: String,
    /// File holding the bearer token (else the LPM_TOKEN variable).
    #[arg(long)]
    token_file: Option<PathBuf>,
}

#[cfg(feature = "service")]
impl ServerArgs {
    fn client(&self) -> Result<lpm::serve::client::Client> {
        let token = match &self.token_file {
            Some(f) => Some(
                lpm::input::read_text_capped(f, lpm::input::MAX_TOKEN_BYTES, "a token file")
                    .with_context(|| format!("cannot read the token file {}", f.display()))?
                    .trim()
                    .to_string(),
            ),
            None => std::env::var("LPM_TOKEN").ok(),
        };
        Ok(lpm::serve::client::Client::new(&self.server, token))
    }
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Profile the slice stream with GPU timestamps: per order, seconds in upload, compute and
    /// download, the fraction of transfer time hidden behind compute, bytes/s each way and
    /// voxel·direction updates/s. JSON on stdout.
    Stream {
        /// The scene file (TOML).
        scene: PathBuf,
        /// Orders to run and report.
        #[arg(long, default_value_t = 2)]
        orders: u32,
        /// Device memory budget (K/M/G/T suffixes), as for `solve`.
        #[arg(long, value_parser = parse_budget)]
        device_memory_budget: Option<u64>,
        /// Vulkan physical device index.
        #[arg(long, env = "LPM_DEVICE")]
        device: Option<usize>,
        /// Enable the Khronos validation layer (slows the stream down: for checking, not timing).
        #[arg(long, env = "LPM_VALIDATION", value_parser = clap::builder::BoolishValueParser::new())]
        validation: Option<bool>,
        /// Also write the JSON to this file (atomically).
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Time against error: the solver across directions per face, tolerances, storage precisions and
    /// plans, and the Monte-Carlo reference across photon counts, each timed and compared with a long Monte-Carlo run; writes
    /// accuracy.json, accuracy.csv and accuracy.svg (a log-log plot) into --out.
    Accuracy {
        /// The scene file (TOML).
        scene: PathBuf,
        /// Output directory (the runs go to OUT/runs).
        #[arg(long, short)]
        out: PathBuf,
        /// Directions per face to try (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "2,3,4,5")]
        k: Vec<u32>,
        /// Solver tolerances to try (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "1e-2,1e-3,1e-4")]
        tolerances: Vec<f64>,
        /// Order caps (`solver.max_orders`) to run each (k, tolerance) with (comma-separated);
        /// default: the scene's own cap. A cap cuts the order series short: its error against the
        /// reference shows what each further order buys.
        #[arg(long, value_delimiter = ',')]
        max_orders: Vec<u32>,
        /// Storage precisions of the gained source to run each (k, tolerance) with (comma-separated:
        /// f32, f16, auto).
        #[arg(long, value_delimiter = ',', value_enum, default_value = "f32,f16")]
        precisions: Vec<PrecisionArg>,
        /// Plans to run each (k, tolerance, precision) with (comma-separated: auto, full). "full"
        /// sets `solver.plan = "full"`: 3 channels and per-face storage directions even for a grey,
        /// isotropic scene, f32 storage under `auto` precision; it shows what the plan saves.
        #[arg(long, value_delimiter = ',', value_enum, default_value = "auto")]
        plans: Vec<PlanArg>,
        /// Spatial schemes to run each setting with (comma-separated: constant, linear); default:
        /// the scene's own.
        #[arg(long, value_delimiter = ',', value_enum)]
        spatial: Vec<SpatialArg>,
        /// Forward-peak treatments to run each setting with (comma-separated: auto, delta-m,
        /// keep); default: the scene's own.
        #[arg(long, value_delimiter = ',', value_enum)]
        forward_peak: Vec<ForwardPeakArg>,
        /// Sky directions per face to run each setting with (comma-separated
        /// `solver.sky_directions_per_face` values; 0, or any value up to the run's k: the sky on
        /// the k×k directions); default: the scene's own.
        #[arg(long, value_delimiter = ',')]
        sky_directions: Vec<u32>,
        /// The density quantile where the dense core starts (0.9: the densest 10 % of the medium),
        /// for the core_* columns.
        #[arg(long, default_value_t = lpm::compare::DEFAULT_CORE_QUANTILE)]
        core_quantile: f64,
        /// Monte-Carlo photon counts per channel to try (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "100000,400000,1600000")]
        samples: Vec<f64>,
        /// Photons per channel of the reference run.
        #[arg(long, default_value_t = 16e6)]
        reference_samples: f64,
        /// Backend of the solver runs.
        #[arg(long, value_enum, default_value_t = Backend::Gpu)]
        backend: Backend,
        /// Vulkan physical device index of the solver runs.
        #[arg(long, env = "LPM_DEVICE")]
        device: Option<usize>,
        /// Enable the Khronos validation layer in the solver runs.
        #[arg(long, env = "LPM_VALIDATION", value_parser = clap::builder::BoolishValueParser::new())]
        validation: Option<bool>,
        /// Compare only voxels whose reference relative standard error is at most this.
        #[arg(long, default_value_t = 0.05)]
        max_rel_stderr: f64,
        /// Also run the grid-refinement study (as `bench refine`) with this many levels, into the
        /// same --out (refine.json, refine.csv, refine.svg): at the first --k, the finest
        /// --tolerances, each --spatial scheme.
        #[arg(long)]
        refine: Option<u32>,
    },
    /// Grid refinement: the scene's medium solved at voxel sizes h, h/2, h/4, each finer fluence
    /// averaged onto the coarsest grid, its error against the finest level and against the
    /// Richardson extrapolation, and the fitted slope (the observed order); writes refine.json,
    /// refine.csv and refine.svg (a log-log plot) into --out.
    Refine {
        /// The scene file (TOML): its grid is the coarsest level.
        scene: PathBuf,
        /// Output directory (the runs go to OUT/runs).
        #[arg(long, short)]
        out: PathBuf,
        /// Grids to solve: h, h/2, … (2 to 4; 3 gives the Richardson extrapolation).
        #[arg(long, default_value_t = 3)]
        levels: u32,
        /// Directions per face of every run; default: the scene's own.
        #[arg(long)]
        k: Option<u32>,
        /// Solver tolerance of every run (tight, so that the discretisation is what is measured).
        #[arg(long, default_value_t = 1e-5)]
        tolerance: f64,
        /// Order cap of every run; default: the scene's own.
        #[arg(long)]
        max_orders: Option<u32>,
        /// Refine a procedural volume by replicating its voxels (the same piecewise-constant
        /// medium: the solver's error alone), not by generating it at the finer dims (the same
        /// continuous medium sampled more finely: the default).
        #[arg(long)]
        replicate: bool,
        /// Spatial schemes, one line each (comma-separated: constant, linear); default: the
        /// scene's own.
        #[arg(long, value_delimiter = ',', value_enum)]
        spatial: Vec<SpatialArg>,
        /// Diffusion-correction settings, one line each (comma-separated: off, on); default: the
        /// scene's own.
        #[arg(long, value_delimiter = ',', value_enum)]
        diffusion_correction: Vec<DiffusionArg>,
        /// The density quantile where the dense core starts (0.9: the densest 10 % of the medium).
        #[arg(long, default_value_t = lpm::compare::DEFAULT_CORE_QUANTILE)]
        core_quantile: f64,
        /// Backend of the solver runs.
        #[arg(long, value_enum, default_value_t = Backend::Gpu)]
        backend: Backend,
        /// Vulkan physical device index of the solver runs.
        #[arg(long, env = "LPM_DEVICE")]
        device: Option<usize>,
        /// Enable the Khronos validation layer in the solver runs.
        #[arg(long, env = "LPM_VALIDATION", value_parser = clap::builder::BoolishValueParser::new())]
        validation: Option<bool>,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum DiffusionArg {
    Off,
    On,
}

#[derive(Clone, Copy, ValueEnum)]
enum PrecisionArg {
    F32,
    F16,
    Auto,
}

#[derive(Clone, Copy, ValueEnum)]
enum PlanArg {
    Auto,
    Full,
}

#[derive(Clone, Copy, ValueEnum)]
enum SpatialArg {
    Constant,
    Linear,
}

impl SpatialArg {
    fn scheme(self) -> lpm::scene::SpatialScheme {
        match self {
            SpatialArg::Constant => lpm::scene::SpatialScheme::Constant,
            SpatialArg::Linear => lpm::scene::SpatialScheme::Linear,
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum ForwardPeakArg {
    Auto,
    DeltaM,
    Keep,
}

#[derive(Clone, Copy, ValueEnum)]
enum Backend {
    Gpu,
    Cpu,
}

fn main() {
    // Past a file size limit (`ulimit -f`, a batch system's), a write would kill the process with
    // SIGXFSZ: no message, staging left behind. Ignored, the write fails with EFBIG instead, which
    // is reported (and cleaned up after) as a full disk is.
    // SAFETY: setting a signal's disposition to SIG_IGN, before any thread is started.
    unsafe { libc::signal(libc::SIGXFSZ, libc::SIG_IGN) };
    let cli = Cli::parse();
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(format!("lpm={}", cli.log)));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(|| LogWriter)
        .with_target(false)
        // Colour codes only for a person at a terminal, never into a pipe or a log file.
        .with_ansi(std::io::stderr().is_terminal())
        .init();
    if let Err(e) = run(cli) {
        eprintln!("lpm: {}", error_text(&e));
        std::process::exit(if was_cancelled(&e) { EXIT_CANCELLED } else { 1 });
    }
}

/// The progress bar while a solve runs on a terminal: log lines are written above it, not glued
/// to it ([`LogWriter`]).
static BAR: std::sync::Mutex<Option<indicatif::ProgressBar>> = std::sync::Mutex::new(None);

/// Where log lines go: stderr, with the progress bar (if any) taken off the screen meanwhile.
struct LogWriter;

impl std::io::Write for LogWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let bar = BAR.lock().unwrap_or_else(|e| e.into_inner()).clone();
        match bar {
            Some(bar) => bar.suspend(|| std::io::stderr().write_all(buf))?,
            None => std::io::stderr().write_all(buf)?,
        }
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

/// One bar for the whole solve: the stage, the percentage and the estimated time left.
fn progress_bar() -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(1000);
    let style = indicatif::ProgressStyle::with_template("{spinner} {elapsed:>4} [{bar:30}] {percent:>3}% {msg}")
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("=> ");
    bar.set_style(style);
    bar.set_message("building the brick store");
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    *BAR.lock().unwrap_or_else(|e| e.into_inner()) = Some(bar.clone());
    bar
}

/// A solve's progress: the bar on a terminal, else a log line per stage and per order, each with
/// the percentage done and the time left (the library's one estimator, [`lpm::progress`]).
struct SolveProgress {
    bar: Option<indicatif::ProgressBar>,
    /// The last order done, and whether it was done since the last estimate.
    last_order: Option<(lpm::progress::OrderDone, bool)>,
    /// The last stage a line was written for.
    logged: Option<lpm::progress::Stage>,
}

impl lpm::progress::Observer for SolveProgress {
    fn order_done(&mut self, done: &lpm::progress::OrderDone) {
        self.last_order = Some((*done, true));
    }

    fn estimate(&mut self, e: &lpm::progress::Estimate) {
        use lpm::progress::Stage;
        let just_done = self.last_order.as_ref().is_some_and(|&(_, fresh)| fresh);
        let order = self.last_order.as_mut().map(|(o, fresh)| {
            *fresh = false;
            let measure =
                if o.measure == o.residual { String::new() } else { format!(", remaining error {:.3e}", o.measure) };
            format!("order {} done: residual {:.3e}{measure}", o.order, o.residual)
        });
        match &self.bar {
            Some(bar) => {
                bar.set_position((e.fraction * 1000.0).round() as u64);
                let left = match e.seconds_left {
                    Some(s) => format!("about {} left", lpm::progress::human_seconds(s)),
                    None => "time left not known yet".to_string(),
                };
                let last = match (&order, e.stage) {
                    (Some(o), Stage::Order(_)) => format!(" ({o})"),
                    _ => String::new(),
                };
                bar.set_message(format!("{}{last} · {left}", e.stage));
            }
            None => {
                // A line per order done and per stage other than an order's start (those come as
                // "order k done" lines), none for the end (the summary follows).
                let what = match order {
                    Some(o) if just_done => o,
                    _ if matches!(e.stage, Stage::Order(_) | Stage::Done) || self.logged == Some(e.stage) => return,
                    _ => e.stage.to_string(),
                };
                self.logged = Some(e.stage);
                tracing::info!("{what} — {}", e.describe());
            }
        }
    }
}

/// The exit status of a solve stopped by SIGTERM or SIGINT at a slice, its checkpoint kept (what
/// `lpm serve`'s workers and scripts tell apart from a failure).
const EXIT_CANCELLED: i32 = 3;

extern "C" fn on_stop_signal(signal: libc::c_int) {
    // Only async-signal-safe calls here: an atomic swap, signal() and raise(). The process's flag
    // is the one every phase looks at (the renderer included, see `lpm::solver::cancel`).
    if lpm::solver::cancel::CancelFlag::process().raise_again() {
        // The second signal: end now, as without a handler.
        // SAFETY: signal and raise are async-signal-safe.
        unsafe {
            libc::signal(signal, libc::SIG_DFL);
            libc::raise(signal);
        }
    }
}

/// Makes SIGTERM and SIGINT stop the solve at its next slice, keeping its checkpoint (Slurm sends
/// SIGTERM before it preempts or times out a task; `lpm serve` sends it to cancel a job); a second
/// signal ends the process at once.
fn cancel_on_signals() -> lpm::solver::cancel::CancelFlag {
    let handler: extern "C" fn(libc::c_int) = on_stop_signal;
    for signal in [libc::SIGTERM, libc::SIGINT] {
        // SAFETY: the handler is a plain function doing only async-signal-safe work.
        unsafe { libc::signal(signal, handler as libc::sighandler_t) };
    }
    lpm::solver::cancel::CancelFlag::process()
}

/// Whether `e` is a solve that stopped because it was cancelled.
fn was_cancelled(e: &anyhow::Error) -> bool {
    use lpm::job::JobError;
    use lpm::solver::SolveError;
    let cancelled = |j: &JobError| matches!(j, JobError::Solve(SolveError::Cancelled { .. }));
    e.chain().any(|c| {
        matches!(c.downcast_ref::<SolveError>(), Some(SolveError::Cancelled { .. }))
            || c.downcast_ref::<JobError>().is_some_and(cancelled)
            || matches!(c.downcast_ref::<lpm::sweep::SweepError>(), Some(lpm::sweep::SweepError::Job(j)) if cancelled(j))
    })
}

/// The error and its causes in one line, each cause once: a library error that already quotes its
/// source (`… cannot open: No such file or directory`) is not followed by the same reason again.
/// Control characters (from file names, say: an escape sequence, or a newline, which would split
/// the one line that scripts and `lpm serve` take as the error) are escaped so they cannot garble
/// the terminal.
fn error_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let full = cause.to_string();
        // An OS error quoted above may have been shortened by the " (os error N)" it ends with.
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
    escape_controls(&text)
}

fn escape_controls(text: &str) -> String {
    text.chars().map(|c| if c.is_control() { c.escape_default().to_string() } else { c.to_string() }).collect()
}

fn parse_limit(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!("expected a finite number ≥ 0, got {text:?}")),
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum VdbPrecisionArg {
    Float,
    Half,
}

impl From<VdbPrecisionArg> for lpm::output::VdbPrecision {
    fn from(p: VdbPrecisionArg) -> Self {
        match p {
            VdbPrecisionArg::Float => lpm::output::VdbPrecision::Float,
            VdbPrecisionArg::Half => lpm::output::VdbPrecision::Half,
        }
    }
}

/// The PNG's exposure and view transform (the EXR stays linear), over the scene's `[camera]`
/// `exposure` and `view` (for `lpm render`: over the solve's).
#[derive(Clone, Copy, clap::Args)]
struct DisplayArgs {
    /// Exposure of the PNG in stops (EV: radiance × 2^EV), or "auto" (the medium's log-average
    /// luminance at mid grey). Default: the scene's camera.exposure, else 0 (render: the solve's).
    #[arg(long, value_name = "EV|auto", allow_hyphen_values = true, value_parser = parse_exposure)]
    exposure: Option<lpm::scene::Exposure>,
    /// The PNG's view transform: agx (default: highlights roll off to white), filmic (the same
    /// curve per channel) or standard (Reinhard, lpm's old flat mapping). Default: the scene's
    /// camera.view (render: the solve's).
    #[arg(long, value_enum)]
    view: Option<ViewArg>,
}

impl From<DisplayArgs> for lpm::render::keep::DisplayChange {
    fn from(d: DisplayArgs) -> Self {
        let view = d.view.map(|v| match v {
            ViewArg::Standard => lpm::scene::View::Standard,
            ViewArg::Filmic => lpm::scene::View::Filmic,
            ViewArg::Agx => lpm::scene::View::Agx,
        });
        lpm::render::keep::DisplayChange { exposure: d.exposure, view }
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum ViewArg {
    Standard,
    Filmic,
    Agx,
}

fn parse_exposure(text: &str) -> Result<lpm::scene::Exposure, String> {
    text.parse()
}

#[derive(Clone, Copy, ValueEnum)]
enum BackgroundArg {
    Sky,
    Transparent,
}

impl From<BackgroundArg> for lpm::render::Background {
    fn from(b: BackgroundArg) -> Self {
        match b {
            BackgroundArg::Sky => lpm::render::Background::Sky,
            BackgroundArg::Transparent => lpm::render::Background::Transparent,
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Solve {
            scene,
            out,
            backend,
            threads,
            device,
            validation,
            keep_store,
            no_image,
            no_fields,
            device_memory_budget,
            resume,
            task,
            fresh,
            warm_start,
            vdb_precision,
            background,
            display,
            no_render_data,
            confine_to,
        } => {
            if let Some(root) = &confine_to {
                lpm::input::confine_to(root)?;
            }
            // The CPU backend sweeps on rayon's global pool (0 threads: one per core).
            rayon::ThreadPoolBuilder::new()
                .num_threads(lpm::threads::checked(threads)?)
                .build_global()
                .context("could not start the CPU backend's threads")?;
            let vk = vk_options(device, validation);
            let backend_kind = match backend {
                Backend::Gpu => BackendKind::Gpu,
                Backend::Cpu => BackendKind::Cpu,
            };
            if let Some(task) = task {
                let template = SolveJob {
                    scene: scene.clone(),
                    out: PathBuf::new(),
                    backend: backend_kind,
                    vk,
                    keep_store,
                    no_image,
                    no_fields,
                    device_memory_budget,
                    resume: false,
                    fresh: false,
                    cancel: Some(cancel_on_signals()),
                    warm_start: None,
                    vdb_precision: vdb_precision.into(),
                    background: background.into(),
                    no_render_data,
                    display: display.into(),
                };
                return run_task(&scene, &task, &template);
            }
            let Some(out) = out else { bail!("--out is required") };
            let job = SolveJob {
                scene,
                out: out.clone(),
                backend: match backend {
                    Backend::Gpu => BackendKind::Gpu,
                    Backend::Cpu => BackendKind::Cpu,
                },
                vk,
                keep_store,
                no_image,
                no_fields,
                device_memory_budget,
                resume,
                fresh,
                cancel: Some(cancel_on_signals()),
                warm_start,
                vdb_precision: vdb_precision.into(),
                background: background.into(),
                no_render_data,
                display: display.into(),
            };
            let bar = std::io::stderr().is_terminal().then(progress_bar);
            let report = job::run(&job, SolveProgress { bar: bar.clone(), last_order: None, logged: None });
            if let Some(bar) = &bar {
                bar.finish_and_clear();
                *BAR.lock().unwrap_or_else(|e| e.into_inner()) = None;
            }
            let report = report?;
            println!(
                "solved {} in {} orders ({}), residual {:.3e}, energy imbalance {:.1e}; outputs in {}",
                report.scene,
                report.orders,
                if report.converged { "converged" } else { "order cap reached" },
                report.final_residual,
                report.energy.relative_imbalance,
                out.display()
            );
            Ok(())
        }
        Command::Info { dir, json } => info(&dir, json),
        Command::Sweep { manifest, slurm, submit, status, collect } => sweep(&manifest, slurm, submit, status, collect),
        #[cfg(feature = "service")]
        Command::Serve {
            listen,
            data,
            token_file,
            devices,
            workers,
            max_queued,
            max_body,
            max_upload,
            device_memory_budget,
            retention_hours,
        } => {
            let mut opts = lpm::serve::ServeOptions::new(listen, data);
            opts.token = lpm::serve::load_token(token_file.as_deref(), std::env::var("LPM_SERVE_TOKEN").ok())
                .map_err(anyhow::Error::msg)?;
            opts.devices = devices;
            opts.workers_per_device = workers;
            opts.max_queued = max_queued;
            opts.max_body_bytes = max_body;
            opts.max_upload_bytes = max_upload;
            opts.device_memory_budget = device_memory_budget;
            opts.check()?;
            if let Some(h) = retention_hours {
                opts.retention = Some(lpm::serve::ServeOptions::retention_of_hours(h)?);
            }
            lpm::serve::serve(opts)?;
            Ok(())
        }
        #[cfg(feature = "service")]
        Command::Submit { scene, volume, server, priority, device_memory_budget, no_image, no_fields, wait } => {
            let client = server.client()?;
            let mut query = vec![("priority", priority.to_string())];
            if let Some(b) = device_memory_budget {
                query.push(("device_memory_budget", b));
            }
            if no_image {
                query.push(("no_image", "true".into()));
            }
            if no_fields {
                query.push(("no_fields", "true".into()));
            }
            let job = if volume.is_empty() {
                client.submit(&scene, &query)?
            } else {
                client.submit_with_volumes(&scene, &volume, &query)?
            };
            let id = job["id"].as_i64().context("the server answered without a job id")?;
            println!("{id}");
            if wait {
                let job = client.wait_ended(id, |j| {
                    tracing::info!(
                        "job {id}: {} order {} residual {}",
                        j["state"].as_str().unwrap_or("?"),
                        j["order"],
                        j["residual"]
                    )
                })?;
                if job["state"] != "done" {
                    bail!("job {id} {}: {}", job["state"].as_str().unwrap_or("?"), job["error"].as_str().unwrap_or(""));
                }
            }
            Ok(())
        }
        #[cfg(feature = "service")]
        Command::Status { id, server, wait, cancel, resume } => {
            let client = server.client()?;
            let value = match (id, cancel, resume) {
                (Some(id), true, _) => client.cancel(id)?,
                (Some(id), _, true) => client.resume(id)?,
                _ => client.status(id, wait)?,
            };
            println!("{}", serde_json::to_string_pretty(&value)?);
            Ok(())
        }
        #[cfg(feature = "service")]
        Command::Fetch { id, names, server, out } => {
            let written = server.client()?.fetch(id, &out, &names)?;
            println!("fetched {} into {}", written.join(", "), out.display());
            Ok(())
        }
        Command::Render { dir, camera, width, height, eye, target, up, fov, background, display, image } => {
            let change = lpm::render::keep::ViewChange { width, height, eye, target, up, fov_y: fov };
            render_again(&dir, camera, change, background.into(), display.into(), image)
        }
        Command::Reference { scene, out, samples, seed, image_spp, orders, threads } => {
            let job = lpm::reference::job::ReferenceJob {
                scene,
                out: out.clone(),
                photons: samples,
                seed,
                threads: lpm::threads::checked(threads)?,
                image_samples_per_pixel: image_spp,
                image_orders: orders.unwrap_or(lpm::reference::Orders::ALL),
            };
            let report = lpm::reference::job::run(&job)?;
            println!(
                "reference of {} with {} photons per channel in {:.1} s, mean relative standard error {}; outputs in {}",
                report.scene,
                report.photons,
                report.seconds,
                report.mean_relative_std_error.map_or("n/a".to_string(), |e| format!("{e:.2e}")),
                out.display()
            );
            Ok(())
        }
        Command::Compare { a, b, json, max_rel_stderr, scene, core_quantile, fail_above } => {
            let core = match scene {
                Some(path) => {
                    let scene = lpm::scene::Scene::load(&path)?;
                    // A scratch store beside A with an unpredictable name (two compares may run at once).
                    let scratch = tempfile::Builder::new().prefix(".lpm-compare-density-").tempdir_in(&a)?;
                    let density = lpm::solver::density_volume(&scene, &scratch.path().join("store"))?;
                    Some(lpm::compare::CoreMask { density, quantile: core_quantile })
                }
                None => None,
            };
            let c = lpm::compare::compare_dirs(
                &a,
                &b,
                &lpm::compare::CompareOptions { max_relative_stderr: max_rel_stderr, core },
            )?;
            println!("{c}");
            if let Some(path) = json {
                lpm::compare::write_comparison_json(&path, &c)?;
            }
            if let Some(why) = fail_above.and_then(|max| c.exceeds(max)) {
                eprintln!("lpm: compare failed: {why}");
                std::process::exit(2);
            }
            Ok(())
        }
        Command::Bench {
            what:
                BenchCommand::Accuracy {
                    scene,
                    out,
                    k,
                    tolerances,
                    max_orders,
                    precisions,
                    plans,
                    spatial,
                    forward_peak,
                    sky_directions,
                    core_quantile,
                    samples,
                    reference_samples,
                    backend,
                    device,
                    validation,
                    max_rel_stderr,
                    refine,
                },
        } => {
            // The refinement study's settings, taken before the lists move into the options.
            let refine_options = refine.map(|levels| lpm::bench::refine::RefineOptions {
                levels,
                directions_per_face: k.first().copied(),
                tolerance: tolerances.iter().copied().fold(f64::INFINITY, f64::min),
                max_orders: None,
                replicate_procedural: false,
                spatial: spatial.iter().map(|s| s.scheme()).collect(),
                diffusion_correction: Vec::new(),
                core_quantile,
                backend: match backend {
                    Backend::Gpu => BackendKind::Gpu,
                    Backend::Cpu => BackendKind::Cpu,
                },
                vk: vk_options(device, validation),
            });
            let options = lpm::bench::accuracy::AccuracyOptions {
                directions_per_face: k,
                tolerances,
                max_orders,
                precisions: precisions
                    .iter()
                    .map(|p| match p {
                        PrecisionArg::F32 => lpm::scene::StoragePrecision::F32,
                        PrecisionArg::F16 => lpm::scene::StoragePrecision::F16,
                        PrecisionArg::Auto => lpm::scene::StoragePrecision::Auto,
                    })
                    .collect(),
                plans: plans
                    .iter()
                    .map(|p| match p {
                        PlanArg::Auto => lpm::scene::PlanMode::Auto,
                        PlanArg::Full => lpm::scene::PlanMode::Full,
                    })
                    .collect(),
                spatial: spatial.iter().map(|s| s.scheme()).collect(),
                forward_peaks: forward_peak
                    .iter()
                    .map(|p| match p {
                        ForwardPeakArg::Auto => lpm::scene::ForwardPeak::Auto,
                        ForwardPeakArg::DeltaM => lpm::scene::ForwardPeak::DeltaM,
                        ForwardPeakArg::Keep => lpm::scene::ForwardPeak::Keep,
                    })
                    .collect(),
                sky_directions,
                core_quantile,
                photons: samples.iter().map(|&s| s.max(1.0) as u64).collect(),
                reference_photons: reference_samples.max(1.0) as u64,
                backend: match backend {
                    Backend::Gpu => BackendKind::Gpu,
                    Backend::Cpu => BackendKind::Cpu,
                },
                vk: vk_options(device, validation),
                max_relative_stderr: max_rel_stderr,
            };
            let report = lpm::bench::accuracy::run(&scene, &out, &options, |line| tracing::info!("{line}"))?;
            println!(
                "{:<12} {:<31} {:>10} {:>12} {:>12} {:>12} {:>12} {:>12} {:>14}",
                "method",
                "setting",
                "seconds",
                "rel. L2",
                "noise-corr.",
                "bias",
                "core L2",
                "core bias",
                "device bytes"
            );
            for r in &report.rows {
                let f = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.3e}"));
                println!(
                    "{:<12} {:<31} {:>10.3} {:>12} {:>12} {:>12} {:>12} {:>12} {:>14}",
                    r.method,
                    r.setting,
                    r.seconds,
                    f(r.relative_l2),
                    f(r.noise_corrected_l2),
                    f(r.mean_bias),
                    f(r.core_relative_l2),
                    f(r.core_mean_bias),
                    r.peak_device_bytes.map_or("n/a".to_string(), |b| b.to_string())
                );
            }
            println!("wrote accuracy.json, accuracy.csv and accuracy.svg to {}", out.display());
            if let Some(options) = refine_options {
                let report = lpm::bench::refine::run(&scene, &out, &options, |line| tracing::info!("{line}"))?;
                print_refine(&report);
                println!("wrote refine.json, refine.csv and refine.svg to {}", out.display());
            }
            Ok(())
        }
        Command::Bench {
            what:
                BenchCommand::Refine {
                    scene,
                    out,
                    levels,
                    k,
                    tolerance,
                    max_orders,
                    replicate,
                    spatial,
                    diffusion_correction,
                    core_quantile,
                    backend,
                    device,
                    validation,
                },
        } => {
            let options = lpm::bench::refine::RefineOptions {
                levels,
                directions_per_face: k,
                tolerance,
                max_orders,
                replicate_procedural: replicate,
                spatial: spatial.iter().map(|s| s.scheme()).collect(),
                diffusion_correction: diffusion_correction
                    .iter()
                    .map(|d| match d {
                        DiffusionArg::Off => lpm::scene::DiffusionCorrection::Off,
                        DiffusionArg::On => lpm::scene::DiffusionCorrection::On,
                    })
                    .collect(),
                core_quantile,
                backend: match backend {
                    Backend::Gpu => BackendKind::Gpu,
                    Backend::Cpu => BackendKind::Cpu,
                },
                vk: vk_options(device, validation),
            };
            let report = lpm::bench::refine::run(&scene, &out, &options, |line| tracing::info!("{line}"))?;
            print_refine(&report);
            println!("wrote refine.json, refine.csv and refine.svg to {}", out.display());
            Ok(())
        }
        Command::Bench {
            what: BenchCommand::Stream { scene, orders, device_memory_budget, device, validation, json },
        } => {
            let vk = vk_options(device, validation);
            // A fresh directory with an unpredictable name (O_EXCL), removed when done.
            let work = tempfile::Builder::new().prefix("lpm-bench-stream-").tempdir()?;
            let report = lpm::bench::stream(&scene, orders, device_memory_budget, vk, work.path())?;
            let text = serde_json::to_string_pretty(&report)?;
            if let Some(path) = json {
                lpm::output::write_atomic(&path, |w| std::io::Write::write_all(w, text.as_bytes()))?;
            }
            println!("{text}");
            Ok(())
        }
    }
}

/// The refinement study as a table: per line and level, the change from the coarser level and the
/// errors (whole medium and core) against the finest level and the extrapolation; then the orders.
fn print_refine(report: &lpm::bench::refine::RefineReport) {
    let f = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.3e}"));
    println!(
        "{:<28} {:>10} {:>16} {:>7} {:>10} {:>11} {:>11} {:>11} {:>11} {:>11}",
        "line", "h", "dims", "orders", "seconds", "change", "vs finest", "core", "vs extrap.", "core"
    );
    for line in &report.lines {
        for l in &line.levels {
            println!(
                "{:<28} {:>10.4} {:>16} {:>7} {:>10.2} {:>11} {:>11} {:>11} {:>11} {:>11}",
                line.name,
                l.voxel_size,
                format!("{}x{}x{}", l.dims[0], l.dims[1], l.dims[2]),
                l.orders,
                l.seconds,
                f(l.change_from_coarser),
                f(l.error_vs_finest),
                f(l.core_error_vs_finest),
                f(l.error_vs_extrapolated),
                f(l.core_error_vs_extrapolated)
            );
        }
        let o = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.2}"));
        println!(
            "{:<28} observed order {} (core {}); slope vs extrapolation {} (core {}), vs finest {} (core {})",
            line.name,
            o(line.observed_order),
            o(line.core_observed_order),
            o(line.slope_vs_extrapolated),
            o(line.core_slope_vs_extrapolated),
            o(line.slope_vs_finest),
            o(line.core_slope_vs_finest)
        );
    }
    println!(
        "{} coarse voxels measured ({} in the core, density ≥ {}); refine.svg plots the errors against the {}",
        report.voxels_compared,
        report.core_voxels_compared,
        report.core_density_threshold,
        if report.plotted == "extrapolated" { "Richardson extrapolation" } else { "finest level" }
    );
}

fn render_again(
    dir: &std::path::Path,
    camera: Option<PathBuf>,
    change: lpm::render::keep::ViewChange,
    background: lpm::render::Background,
    display: lpm::render::keep::DisplayChange,
    image: Option<PathBuf>,
) -> Result<()> {
    let (exr, png) = match &image {
        None => (Some(dir.join("image.exr")), Some(dir.join("image.png"))),
        Some(p) => match p.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
            Some("exr") => (Some(p.clone()), None),
            Some("png") => (None, Some(p.clone())),
            _ => bail!("--image {}: the name must end in .exr or .png", p.display()),
        },
    };
    // Held while reading and writing: a solve into DIR cannot replace the data under us.
    let _lock = lpm::output::DirLock::acquire(dir)?;
    let kept = lpm::render::keep::open(dir)?;
    let display = lpm::render::keep::view_display(&kept, camera.as_deref(), &display)?;
    let camera = lpm::render::keep::view_camera(&kept, camera.as_deref(), &change)?;
    lpm::render::memory::check_image_fits(camera.width, camera.height)?;
    let img = kept.render(&camera, background);
    lpm::render::write_images(exr.as_deref(), png.as_deref(), &img, background, &display)?;
    let written: Vec<String> = [exr, png].into_iter().flatten().map(|p| p.display().to_string()).collect();
    println!("rendered {}×{} pixels: {}", img.width, img.height, written.join(", "));
    Ok(())
}

fn run_task(manifest: &std::path::Path, task: &str, template: &SolveJob) -> Result<()> {
    let index: usize = if task == "slurm" {
        let v = std::env::var("SLURM_ARRAY_TASK_ID")
            .context("--task without a number needs SLURM_ARRAY_TASK_ID (set by Slurm in an array job)")?;
        v.parse().with_context(|| format!("SLURM_ARRAY_TASK_ID is not a task number: {v:?}"))?
    } else {
        task.parse().with_context(|| format!("--task: not a task number: {task:?}"))?
    };
    let sweep = lpm::sweep::Sweep::load(manifest)?;
    let dir = lpm::sweep::task_dir(&sweep.dir, index);
    let slurm_job = std::env::var("SLURM_JOB_ID").ok();
    match lpm::sweep::task::run(&sweep, index, template, slurm_job.as_deref())? {
        lpm::sweep::task::RunOutcome::AlreadyDone => println!("task {index} is already done: {}", dir.display()),
        lpm::sweep::task::RunOutcome::Solved { orders, resumed } => println!(
            "task {index} solved in {orders} orders{}; outputs in {}",
            if resumed { " (resumed from its checkpoint)" } else { "" },
            dir.join("out").display()
        ),
    }
    Ok(())
}

fn sweep(manifest: &std::path::Path, slurm: bool, submit: bool, status: bool, collect: bool) -> Result<()> {
    let sweep = lpm::sweep::Sweep::load(manifest)?;
    if collect {
        let (written, rows) = lpm::sweep::collect::collect(&sweep)?;
        let done = rows.iter().filter(|r| r.status == "done").count();
        let names: Vec<String> = written.iter().map(|p| p.display().to_string()).collect();
        println!("{} tasks ({done} done): wrote {}", rows.len(), names.join(" and "));
        return Ok(());
    }
    if status {
        let mut counts = std::collections::BTreeMap::new();
        for t in &sweep.tasks {
            let (state, error) = lpm::sweep::task::state(&sweep, t.index);
            *counts.entry(state).or_insert(0usize) += 1;
            println!("task {:>4}  {:<11} {}", t.index, state.name(), error.unwrap_or_default());
        }
        let summary: Vec<String> = counts.iter().map(|(s, n)| format!("{n} {}", s.name())).collect();
        println!("{} tasks: {}", sweep.tasks.len(), summary.join(", "));
        return Ok(());
    }
    sweep.write()?;
    println!("{} tasks in {}", sweep.tasks.len(), sweep.dir.display());
    if slurm || submit {
        let exe = std::env::current_exe().context("cannot find the lpm executable")?;
        let script = lpm::sweep::slurm::write_script(&sweep, &exe)?;
        println!("wrote {}", script.display());
        if submit {
            let id = lpm::sweep::slurm::submit(&script)?;
            println!("submitted Slurm job {id}");
        }
    }
    Ok(())
}

/// "X,Y,Z" as three numbers.
fn parse_vec3(text: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = text
        .split(',')
        .map(|c| c.trim().parse::<f64>().map_err(|_| format!("{c:?} is not a number")))
        .collect::<Result<_, _>>()?;
    <[f64; 3]>::try_from(v).map_err(|v| format!("expected X,Y,Z (3 numbers), got {}", v.len()))
}

fn parse_budget(text: &str) -> Result<u64, String> {
    match lpm::scene::validate::parse_byte_size(text)? {
        0 => Err("the budget must be more than 0 bytes".to_string()),
        n => Ok(n),
    }
}

/// The keys `lpm info` and the programs reading `--json` rely on, each of its type: a report that
/// was cut short, edited or is some other JSON is refused naming the first key that is wrong.
fn check_report(r: &serde_json::Value) -> std::result::Result<(), String> {
    use serde_json::Value;
    /// A key, the test of its value and what the test asks for, in words.
    type Check = (&'static str, fn(&Value) -> bool, &'static str);
    let checks: [Check; 8] = [
        ("lpm_version", Value::is_string, "a string"),
        ("scene", Value::is_string, "a string"),
        ("plan", Value::is_object, "an object"),
        ("orders", Value::is_u64, "a whole number"),
        ("converged", Value::is_boolean, "true or false"),
        ("final_residual", Value::is_number, "a number"),
        ("energy", Value::is_object, "an object"),
        ("outputs", Value::is_array, "a list"),
    ];
    if !r.is_object() {
        return Err("it is not a JSON object".into());
    }
    for (key, ok, what) in checks {
        match r.get(key) {
            None => return Err(format!("it has no \"{key}\"")),
            Some(v) if !ok(v) => return Err(format!("\"{key}\" is not {what}")),
            Some(_) => {}
        }
    }
    Ok(())
}

fn info(dir: &std::path::Path, json: bool) -> Result<()> {
    let path = dir.join("report.json");
    // A report is a few kilobytes; 64 MiB leaves room for very long histories.
    let text = lpm::input::read_text_capped(&path, 64 << 20, "a report")?;
    // Checked before it is printed, --json included: a corrupt report is an error, not output.
    let r: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{} is not valid JSON", path.display()))?;
    check_report(&r).map_err(|why| anyhow::anyhow!("{}: not a report lpm wrote: {why}", path.display()))?;
    let plan = &r["plan"];
    if json {
        println!("{text}");
        return Ok(());
    }
    println!("scene     {}", r["scene"].as_str().unwrap_or("?"));
    println!("backend   {} on {}", r["backend"].as_str().unwrap_or("?"), r["device"].as_str().unwrap_or("?"));
    println!(
        "volume    {} voxels of {}, {} of {} bricks empty",
        plan["dims"], plan["voxel_size"], plan["bricks_empty"], plan["bricks_total"]
    );
    println!(
        "plan      {} channel(s), {} propagation and {} storage direction(s)",
        plan["channels"], plan["propagation_directions"], plan["storage_directions"]
    );
    if let Some(reasons) = plan["reasons"].as_array() {
        for reason in reasons {
            println!("          - {}", reason.as_str().unwrap_or(""));
        }
    }
    println!(
        "orders    {} ({}), final residual {} (tolerance {})",
        r["orders"],
        if r["converged"].as_bool() == Some(true) { "converged" } else { "cap reached" },
        r["final_residual"],
        r["tolerance"]
    );
    println!("energy    relative imbalance {}", r["energy"]["relative_imbalance"]);
    // The first channel's power through each face (reports written before faces existed have none).
    if let Some(faces) = r["energy"]["faces"].as_array() {
        let first = |v: &serde_json::Value| v[0].as_f64().map_or("-".to_string(), |x| format!("{x:.4e}"));
        let row: Vec<String> = faces
            .iter()
            .map(|f| {
                format!(
                    "{} in {} out {}",
                    f["face"].as_str().unwrap_or("?"),
                    first(&f["power_in"]),
                    first(&f["power_out"])
                )
            })
            .collect();
        println!("faces     {} (channel 0)", row.join("; "));
    }
    if let Some(t) = r.get("tail").filter(|t| !t.is_null()) {
        println!(
            "tail      geometric tail added: ratio {}, power {}, uncertainty {}",
            t["ratio"], t["power"], t["uncertainty"]
        );
    }
    println!("device    peak allocation {} bytes", r["peak_device_bytes"]);
    if let Some(m) = r.get("device_memory").filter(|m| !m.is_null()) {
        println!(
            "memory    budget {} bytes, planned {}; {} slice(s) in flight, {} direction(s) per pass, {} plane(s) per slice, {} direction(s) and {} plane(s) per dispatch",
            m["budget_bytes"],
            m["planned_bytes"],
            m["slices_in_flight"],
            m["directions_per_pass"],
            m["planes_per_slice"],
            m["directions_per_dispatch"],
            m["planes_per_dispatch"]
        );
        if let Some(reason) = m["residency_reason"].as_str() {
            println!("          {reason}");
        }
        if let Some(reason) = m["end_of_order_reason"].as_str() {
            println!("          passes between orders {reason}");
        }
    }
    if let Some(peak) = r.get("peak_resident_bytes").and_then(|p| p.as_u64()) {
        println!("host      peak resident {peak} bytes; brick store {} bytes", r["store_bytes"]);
    }
    if let Some(kept) = r["host_memory"]["kept_resident"].as_bool() {
        let budget = r["host_memory"]["budget_bytes"].as_u64().map_or("none".to_string(), |b| format!("{b} bytes"));
        println!(
            "          store pages {} (budget {budget}, {})",
            if kept { "kept resident" } else { "handed back after each pass" },
            r["host_memory"]["budget_origin"].as_str().unwrap_or("?")
        );
    }
    if let Some(phases) = r["seconds"].as_array() {
        let line: Vec<String> = phases
            .iter()
            .map(|p| format!("{} {:.3}s", p["phase"].as_str().unwrap_or("?"), p["seconds"].as_f64().unwrap_or(0.0)))
            .collect();
        println!("time      {}", line.join(", "));
    }
    let written = |name: &str| r["outputs"].as_array().is_none_or(|o| o.iter().any(|f| f.as_str() == Some(name)));
    for base in ["fluence", "source"] {
        if !written(&format!("{base}.json")) {
            println!("{base:<9} not exported (solved with --no-fields)");
            continue;
        }
        match lpm::output::read_field_json(&dir.join(format!("{base}.json"))) {
            Ok(info) => println!(
                "{base:<9} {} ({}): {}×{}×{} voxels × {} f32 [{}], {}",
                info.file,
                info.quantity,
                info.dims[0],
                info.dims[1],
                info.dims[2],
                info.components,
                info.component_names.join(", "),
                info.units
            ),
            Err(e) => println!("{base:<9} missing or unreadable: {e}"),
        }
    }
    for file in ["fluence.vdb", "source.vdb"] {
        if written(file) && dir.join(file).exists() {
            println!("vdb       {}", dir.join(file).display());
        }
    }
    for image in ["image.exr", "image.png"] {
        let p = dir.join(image);
        if p.exists() {
            println!("image     {}", p.display());
        }
    }
    if dir.join(lpm::render::RENDER_DATA).join("render.json").exists() {
        println!("render    {} kept: `lpm render {}` renders other views", lpm::render::RENDER_DATA, dir.display());
    }
    Ok(())
}

/// The Vulkan options from the command line (the only place `LPM_DEVICE` and `LPM_VALIDATION`
/// are read, through clap's `env`).
fn vk_options(device: Option<usize>, validation: Option<bool>) -> ContextOptions {
    ContextOptions { validation: validation.unwrap_or(false), device_index: device, ..ContextOptions::default() }
}
