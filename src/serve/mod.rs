//! `lpm serve`: a job server with a durable queue, and the `submit` / `status` / `fetch` clients.
//!
//! # Pieces
//!
//! | file | what it owns |
//! |---|---|
//! | [`gate`] | the listening socket: each request head read within limits before tiny_http sees it |
//! | [`api`] | the `/v1` routes, request parsing, handlers, errors → status codes |
//! | [`db`] + `schema.sql` | the durable queue in SQLite (WAL, `synchronous = FULL`) |
//! | [`worker`] | runs each job as a child `lpm solve` process, watches progress, cancels |
//! | [`events`] | `GET /v1/jobs/{id}/events`: progress pushed as server-sent events |
//! | [`upload`] + [`multipart`] | `POST /v1/jobs` as `multipart/form-data`: the scene with its volume file(s) |
//! | [`confine`] | keeps client-named paths inside the data root |
//! | [`client`] | the blocking HTTP client behind `lpm submit`, `lpm status`, `lpm fetch` |
//! | `openapi.json` | the API described for other programs; a test keeps it equal to [`api::ROUTES`] |
//!
//! Why tiny_http and ureq rather than an async stack: a job server's requests are few and small
//! (a scene, a status, a file streamed back) while its work is in child processes, so a thread per
//! request costs nothing that matters, and the two crates build in seconds where hyper/tokio/axum
//! take minutes on a small build machine. tiny_http reads a request head without any bound, so
//! clients reach it only through [`gate`], one request per connection. SQLite (rusqlite) is the
//! queue because it gives a durable, transactional store in one file with no server to run.
//!
//! # The queue's state machine
//!
//! ```text
//!            submit                 worker claims              child exits 0
//!   (none) ─────────▶ queued ─────────────────────▶ running ─────────────────▶ done
//!                      │  ▲                          │  │  child fails
//!                      │  └──── server restarts ─────┘  └────────────────────▶ failed
//!                      │        (resume from checkpoint)│
//!                      │ DELETE                         │ DELETE (SIGTERM: the solve stops at its
//!                      └──────────────▶ cancelled ◀─────┘  next slice, checkpoint kept)
//!   cancelled | failed ── POST …/resume ──▶ queued (the solve resumes from its checkpoint)
//!   done | failed | cancelled ── DELETE or retention ──▶ (row and files removed)
//! ```
//!
//! A job is committed to the database before `201 Created` is sent, so an accepted job is never lost.
//! At start-up every job still marked `running` (its server was killed) goes back to `queued`; its
//! child died with the server (`PR_SET_PDEATHSIG`), and the next worker to take it runs the solve
//! with `--resume`, which continues after the last checkpointed order and gives bitwise the result
//! of an uninterrupted solve. Jobs are taken by priority (higher first), then in order of arrival.
//!
//! # Files under the data root
//!
//! `DATA/lpm.sqlite` (the queue), `DATA/jobs/ID/{scene.toml, solve.log, out/, inputs/}` (one
//! directory per job: the solve's outputs, `progress.json`, and its checkpoint in `out/.lpm-work`
//! until it ends; `inputs/` holds the volume files sent with a multipart submission),
//! `DATA/volumes/` (volumes uploaded with `PUT`), `DATA/uploads/` (multipart uploads while they
//! arrive), `DATA/.lpm-gate-XXXX/http.sock` (the gate's socket to tiny_http, in a directory only
//! the server's user can enter). Scenes may name volumes only under `DATA`.

pub mod api;
pub mod client;
pub mod confine;
pub mod db;
pub mod events;
pub mod gate;
pub mod multipart;
mod prepare;
mod routes;
pub mod upload;
pub mod worker;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

/// The most jobs run at once per device: each is a process with a Vulkan device of its own (and
/// a thread here watching it), far past what a device can share usefully.
pub const MAX_WORKERS_PER_DEVICE: usize = 64;
/// The most devices one server runs jobs on.
pub const MAX_DEVICES: usize = 64;
/// The longest retention: about eleven years, in hours (a longer one is as good as none).
pub const MAX_RETENTION_HOURS: f64 = 100_000.0;

/// How the server runs (`lpm serve` flags).
#[derive(Clone, Debug)]
pub struct ServeOptions {
    pub listen: SocketAddr,
    pub data: PathBuf,
    /// Required in `Authorization: Bearer` on every request but `/v1/health`; mandatory when
    /// `listen` is not a loopback address.
    pub token: Option<String>,
    /// Vulkan device indices to run jobs on (none: the solve's default device).
    pub devices: Vec<usize>,
    /// Workers (jobs at a time) per device.
    pub workers_per_device: usize,
    /// Most jobs waiting in the queue; one more is refused with 503 and `Retry-After`.
    pub max_queued: u64,
    /// Largest scene accepted.
    pub max_body_bytes: u64,
    /// Largest volume upload accepted.
    pub max_upload_bytes: u64,
    /// Device memory budget of a job that names none.
    pub device_memory_budget: Option<u64>,
    /// Ended jobs older than this are deleted with their files.
    pub retention: Option<Duration>,
}

impl ServeOptions {
    pub fn new(listen: SocketAddr, data: PathBuf) -> ServeOptions {
        ServeOptions {
            listen,
            data,
            token: None,
            devices: Vec::new(),
            workers_per_device: 1,
            max_queued: 256,
            max_body_bytes: 1 << 20,
            max_upload_bytes: 4 << 30,
            device_memory_budget: None,
            retention: None,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("listening on {listen} needs a token: pass --token-file FILE or set LPM_SERVE_TOKEN (only loopback addresses may go without)")]
    TokenRequired { listen: SocketAddr },
    #[error("the token is empty")]
    EmptyToken,
    #[error("cannot create the data root {}: {source}", .path.display())]
    DataRoot { path: PathBuf, source: std::io::Error },
    #[error("cannot open the job queue {}: {source}", .path.display())]
    Queue { path: PathBuf, source: rusqlite::Error },
    #[error("cannot listen on {listen}: {reason}")]
    Listen { listen: SocketAddr, reason: String },
    /// An option out of its bounds (named as the `lpm serve` flag that sets it).
    #[error("{option}: {problem}")]
    Option { option: &'static str, problem: String },
}

impl ServeOptions {
    /// Checks the counts and durations against the bounds above (a count too large would start
    /// threads until the process fails).
    pub fn check(&self) -> Result<(), ServeError> {
        let bad = |option, problem: String| Err(ServeError::Option { option, problem });
        if self.workers_per_device > MAX_WORKERS_PER_DEVICE {
            return bad(
                "--workers",
                format!(
                    "{} jobs at once per device is more than the {MAX_WORKERS_PER_DEVICE} allowed",
                    self.workers_per_device
                ),
            );
        }
        if self.devices.len() > MAX_DEVICES {
            return bad("--devices", format!("{} devices is more than the {MAX_DEVICES} allowed", self.devices.len()));
        }
        Ok(())
    }

    /// A retention of `hours` (`--retention-hours`): positive, finite and at most
    /// [`MAX_RETENTION_HOURS`].
    pub fn retention_of_hours(hours: f64) -> Result<Duration, ServeError> {
        if !(hours.is_finite() && hours > 0.0 && hours <= MAX_RETENTION_HOURS) {
            return Err(ServeError::Option {
                option: "--retention-hours",
                problem: format!("must be a positive number of hours up to {MAX_RETENTION_HOURS}, got {hours}"),
            });
        }
        Ok(Duration::from_secs_f64(hours * 3600.0))
    }
}

/// What the handlers and workers share.
pub struct Shared {
    pub db: db::Db,
    /// The data root, canonical.
    pub data: PathBuf,
    pub opts: ServeOptions,
    /// Bumped on every change of a job; workers wait on it for work, long polls for changes.
    changes: (Mutex<u64>, Condvar),
    last_expiry: Mutex<Option<std::time::Instant>>,
}

impl Shared {
    pub fn job_dir(&self, id: i64) -> PathBuf {
        self.data.join("jobs").join(id.to_string())
    }

    pub fn notify(&self) {
        let (lock, cvar) = &self.changes;
        *lock.lock().unwrap_or_else(|p| p.into_inner()) += 1;
        cvar.notify_all();
    }

    fn wait(&self, limit: Duration) {
        let (lock, cvar) = &self.changes;
        let guard = lock.lock().unwrap_or_else(|p| p.into_inner());
        let seen = *guard;
        let _ = cvar.wait_timeout_while(guard, limit, |n| *n == seen);
    }

    pub fn wait_for_work(&self, limit: Duration) {
        self.wait(limit)
    }

    pub fn wait_for_change(&self, limit: Duration) {
        self.wait(limit)
    }

    pub fn remove_job_files(&self, id: i64) {
        let _ = std::fs::remove_dir_all(self.job_dir(id));
    }

    /// Deletes ended jobs past the retention limit (looked at every quarter of the limit, at most
    /// once a minute).
    pub fn expire_old_jobs(&self) {
        let Some(retention) = self.opts.retention else { return };
        {
            let mut last = self.last_expiry.lock().unwrap_or_else(|p| p.into_inner());
            if last.is_some_and(|t| t.elapsed() < (retention / 4).min(Duration::from_secs(60))) {
                return;
            }
            *last = Some(std::time::Instant::now());
        }
        let before = db::now() - retention.as_secs_f64();
        if let Ok(ids) = self.db.ended_before(before) {
            for id in ids {
                if let Ok(true) = self.db.delete(id) {
                    self.remove_job_files(id);
                    tracing::info!("job {id}: deleted (older than the retention limit)");
                }
            }
        }
    }
}

/// Reads the token from `file`, else takes `from_env` (the CLI reads `LPM_SERVE_TOKEN`: the
/// library reads no environment).
pub fn load_token(file: Option<&Path>, from_env: Option<String>) -> Result<Option<String>, String> {
    let token = match file {
        Some(f) => Some(
            crate::input::read_text_capped(f, crate::input::MAX_TOKEN_BYTES, "a token file")
                .map_err(|e| format!("cannot read the token file {}: {}", f.display(), e.words()))?,
        ),
        None => from_env,
    };
    Ok(token.map(|t| t.trim().to_string()))
}

/// Opens the queue, requeues jobs a killed server left running, starts the workers and answers
/// requests until the process ends.
pub fn serve(opts: ServeOptions) -> Result<(), ServeError> {
    opts.check()?;
    match &opts.token {
        Some(t) if t.is_empty() => return Err(ServeError::EmptyToken),
        None if !opts.listen.ip().is_loopback() => return Err(ServeError::TokenRequired { listen: opts.listen }),
        _ => {}
    }
    std::fs::create_dir_all(opts.data.join("jobs"))
        .map_err(|source| ServeError::DataRoot { path: opts.data.clone(), source })?;
    let data = opts.data.canonicalize().map_err(|source| ServeError::DataRoot { path: opts.data.clone(), source })?;
    let db_path = data.join("lpm.sqlite");
    let db = db::Db::open(&db_path).map_err(|source| ServeError::Queue { path: db_path.clone(), source })?;
    upload::remove_stale_staging(&data);
    let requeued = db.requeue_running().map_err(|source| ServeError::Queue { path: db_path.clone(), source })?;
    if requeued > 0 {
        tracing::info!(
            "{requeued} job(s) left running by the previous server: queued again, they resume from their checkpoints"
        );
    }
    // Clients connect to the gate, which passes each checked request on to tiny_http.
    let listener = std::net::TcpListener::bind(opts.listen)
        .map_err(|e| ServeError::Listen { listen: opts.listen, reason: e.to_string() })?;
    let bound = listener.local_addr().unwrap_or(opts.listen);
    let (backend, server) =
        gate::Backend::start(&data).map_err(|reason| ServeError::Listen { listen: opts.listen, reason })?;
    let shared = Arc::new(Shared {
        db,
        data,
        opts: opts.clone(),
        changes: (Mutex::new(0), Condvar::new()),
        last_expiry: Mutex::new(None),
    });
    let devices: Vec<Option<usize>> =
        if opts.devices.is_empty() { vec![None] } else { opts.devices.iter().map(|&d| Some(d)).collect() };
    for device in devices {
        for _ in 0..opts.workers_per_device {
            let shared = Arc::clone(&shared);
            std::thread::spawn(move || worker::run(shared, device));
        }
    }
    let largest_body = opts.max_body_bytes.max(opts.max_upload_bytes);
    let backend = Arc::new(backend);
    {
        let backend = Arc::clone(&backend);
        std::thread::spawn(move || gate::accept(listener, backend, largest_body));
    }
    // Printed on stdout, for scripts and tests that wait for the server to be up.
    println!("lpm serve: listening on http://{bound} with data in {}", shared.data.display());
    for request in server.incoming_requests() {
        let shared = Arc::clone(&shared);
        std::thread::spawn(move || api::handle(&shared, request));
    }
    Ok(())
}
