//! The HTTP API under `/v1`: the dispatcher and the handlers (the route table and query parsing
//! are in `routes.rs`, re-exported here).
//!
//! [`ROUTES`] is the one list of what the server answers; the dispatcher matches requests against
//! it and a test checks it against the OpenAPI document (`openapi.json`) both ways. Handlers return
//! `Result<Reply, ApiError>`; [`ApiError::status`] is the one place errors become status codes, and
//! every error body is `{"error": "<one line>"}`.

use super::confine;
use super::db::{self, Cancel, Insert, Requeue};
use super::Shared;
use crate::scene::Scene;
use std::io::Read;
use std::path::Path;
use std::time::{Duration, Instant};
use tiny_http::{Header, Request, Response};

pub use super::prepare::{prepare_scene, prepare_scene_with, Uploads};
use super::routes::Query;
pub use super::routes::{route, Handler, Route, ROUTES};

/// The OpenAPI 3 document served at `/v1/openapi.json`.
pub const OPENAPI: &str = include_str!("openapi.json");

/// Every way a request fails.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    #[error("{0}")]
    BadRequest(String),
    #[error("missing or wrong token: send `Authorization: Bearer <token>`")]
    Unauthorized,
    #[error("{0}")]
    NotFound(String),
    #[error("{method} is not allowed on {path}")]
    MethodNotAllowed { method: String, path: String },
    #[error("{0}")]
    Conflict(String),
    #[error("{0}")]
    LengthRequired(String),
    #[error("the request body is larger than the limit of {0} bytes")]
    TooLarge(u64),
    #[error("{0}")]
    UnsupportedMediaType(String),
    #[error("the queue is full ({0} jobs waiting): try again later")]
    QueueFull(u64),
    #[error("{0}")]
    Internal(String),
}

impl ApiError {
    pub fn status(&self) -> u16 {
        match self {
            ApiError::BadRequest(_) => 400,
            ApiError::Unauthorized => 401,
            ApiError::NotFound(_) => 404,
            ApiError::MethodNotAllowed { .. } => 405,
            ApiError::Conflict(_) => 409,
            ApiError::LengthRequired(_) => 411,
            ApiError::TooLarge(_) => 413,
            ApiError::UnsupportedMediaType(_) => 415,
            ApiError::QueueFull(_) => 503,
            ApiError::Internal(_) => 500,
        }
    }

    pub(super) fn into_reply(self) -> Reply {
        let mut reply = Reply::json(self.status(), &serde_json::json!({ "error": self.to_string() }));
        if let ApiError::QueueFull(_) = self {
            reply.headers.push(header("Retry-After", &RETRY_AFTER_SECONDS.to_string()));
        }
        if let ApiError::Unauthorized = self {
            reply.headers.push(header("WWW-Authenticate", "Bearer"));
        }
        reply
    }
}

impl From<rusqlite::Error> for ApiError {
    fn from(e: rusqlite::Error) -> Self {
        ApiError::Internal(format!("job queue: {e}"))
    }
}

/// What a client is told to wait before retrying when the queue is full.
pub const RETRY_AFTER_SECONDS: u32 = 30;

/// The longest a long poll (`GET /v1/jobs/{id}?wait=S`) is held.
pub const MAX_WAIT_SECONDS: f64 = 60.0;

pub struct Reply {
    status: u16,
    headers: Vec<Header>,
    body: Body,
}

enum Body {
    Bytes(Vec<u8>),
    File(std::fs::File),
}

pub(super) fn header(name: &str, value: &str) -> Header {
    // Names and values here are ASCII chosen by this module, never by a client.
    Header::from_bytes(name.as_bytes(), value.as_bytes()).expect("ASCII header")
}

impl Reply {
    pub(super) fn json(status: u16, value: &impl serde::Serialize) -> Reply {
        let mut body = serde_json::to_vec_pretty(value).unwrap_or_default();
        body.push(b'\n');
        Reply { status, headers: vec![header("Content-Type", "application/json")], body: Body::Bytes(body) }
    }
}

/// Answers one request (called on its own thread).
pub fn handle(shared: &Shared, mut request: Request) {
    // The event stream writes its own response as it goes.
    let url = request.url().to_string();
    let path = url.split_once('?').map_or(url.as_str(), |(p, _)| p);
    if let Ok((Handler::Events, params)) = route(request.method().as_str(), path) {
        return super::events::stream(shared, request, &params[0]);
    }
    let reply = match respond(shared, &mut request) {
        Ok(reply) => reply,
        Err(e) => e.into_reply(),
    };
    send(request, reply)
}

/// Sends `reply` as the answer to `request`.
pub(super) fn send(request: Request, reply: Reply) {
    let result = match reply.body {
        Body::Bytes(bytes) => {
            let mut r = Response::from_data(bytes).with_status_code(reply.status);
            for h in reply.headers {
                r.add_header(h);
            }
            request.respond(r)
        }
        Body::File(file) => {
            let mut r = Response::from_file(file).with_status_code(reply.status);
            for h in reply.headers {
                r.add_header(h);
            }
            request.respond(r)
        }
    };
    if let Err(e) = result {
        tracing::debug!("cannot send a reply: {e}");
    }
}

fn respond(shared: &Shared, request: &mut Request) -> Result<Reply, ApiError> {
    let url = request.url().to_string();
    let (path, query) = url.split_once('?').unwrap_or((&url, ""));
    let method = request.method().as_str().to_string();
    let (handler, params) = route(&method, path)?;
    if handler != Handler::Health {
        authorize(shared, request)?;
    }
    let query = Query(query);
    let id = || -> Result<i64, ApiError> {
        params[0].parse().map_err(|_| ApiError::NotFound(format!("no job {}", params[0])))
    };
    match handler {
        Handler::Health => health(shared),
        Handler::OpenApi => Ok(Reply {
            status: 200,
            headers: vec![header("Content-Type", "application/json")],
            body: Body::Bytes(OPENAPI.as_bytes().to_vec()),
        }),
        Handler::Submit => submit(shared, request, &query),
        Handler::List => Ok(Reply::json(200, &serde_json::json!({ "jobs": shared.db.list()? }))),
        Handler::Get => get(shared, id()?, &query),
        Handler::Cancel => cancel(shared, id()?),
        Handler::Resume => resume(shared, id()?),
        Handler::Events => Err(ApiError::Internal("the event stream is answered by handle".into())),
        Handler::Outputs => Ok(Reply::json(200, &serde_json::json!({ "outputs": outputs(shared, id()?)? }))),
        Handler::Output => output(shared, id()?, &params[1]),
        Handler::Upload => upload(shared, request, &params[0]),
    }
}

pub(super) fn authorize(shared: &Shared, request: &Request) -> Result<(), ApiError> {
    let Some(token) = &shared.opts.token else { return Ok(()) };
    let sent = request
        .headers()
        .iter()
        .find(|h| h.field.equiv("Authorization"))
        .and_then(|h| h.value.as_str().strip_prefix("Bearer ").map(str::trim).map(str::to_string));
    match sent {
        Some(sent) if constant_time_eq(sent.as_bytes(), token.as_bytes()) => Ok(()),
        _ => Err(ApiError::Unauthorized),
    }
}

/// Compares without stopping at the first difference, so timing does not reveal the token.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// The whole body, at most `limit` bytes. A body that ends before its `Content-Length` is refused:
/// tiny_http's reader just ends early when the client closes, which must not read as a complete
/// (shorter) body.
pub(super) fn read_body(request: &mut Request, limit: u64) -> Result<Vec<u8>, ApiError> {
    if request.body_length().is_some_and(|n| n as u64 > limit) {
        return Err(ApiError::TooLarge(limit));
    }
    let mut body = Vec::new();
    request
        .as_reader()
        .take(limit + 1)
        .read_to_end(&mut body)
        .map_err(|e| ApiError::BadRequest(format!("cannot read the request body: {e}")))?;
    if body.len() as u64 > limit {
        return Err(ApiError::TooLarge(limit));
    }
    if let Some(expected) = request.body_length() {
        if body.len() != expected {
            return Err(cut_short(body.len() as u64, expected as u64));
        }
    }
    Ok(body)
}

fn cut_short(received: u64, expected: u64) -> ApiError {
    ApiError::BadRequest(format!(
        "the request body ended after {received} of the {expected} bytes its Content-Length announced"
    ))
}

fn content_type(request: &Request) -> String {
    request
        .headers()
        .iter()
        .find(|h| h.field.equiv("Content-Type"))
        .map(|h| h.value.as_str().split(';').next().unwrap_or("").trim().to_ascii_lowercase())
        .unwrap_or_default()
}

fn health(shared: &Shared) -> Result<Reply, ApiError> {
    let counts: serde_json::Map<String, serde_json::Value> =
        shared.db.counts()?.into_iter().map(|(k, v)| (k, v.into())).collect();
    Ok(Reply::json(200, &serde_json::json!({ "status": "ok", "version": env!("CARGO_PKG_VERSION"), "jobs": counts })))
}

fn submit(shared: &Shared, request: &mut Request, query: &Query) -> Result<Reply, ApiError> {
    let kind = content_type(request);
    if kind == "multipart/form-data" {
        return super::upload::submit_multipart(shared, request, |scene_text, scene, finalize| {
            enqueue(shared, query, scene_text, &scene, finalize)
        });
    }
    if !matches!(kind.as_str(), "application/toml" | "text/toml") {
        return Err(ApiError::UnsupportedMediaType(format!(
            "send the scene as Content-Type: application/toml, or as multipart/form-data with its volume file (got {:?})",
            kind
        )));
    }
    let body = read_body(request, shared.opts.max_body_bytes)?;
    let text =
        String::from_utf8(body).map_err(|_| ApiError::BadRequest("scene.toml: the scene is not UTF-8".into()))?;
    let (scene_text, scene) = prepare_scene(&shared.data, &text)?;
    enqueue(shared, query, scene_text, &scene, None)
}

/// What turns an accepted job's scene into its final text once its id is known (multipart
/// uploads move into the job's directory): called inside the insert's transaction.
pub type Finalize<'a> = Option<&'a mut dyn FnMut(i64) -> Result<String, ApiError>>;

/// Queues a validated scene with the query's options.
fn enqueue(
    shared: &Shared,
    query: &Query,
    scene_text: String,
    scene: &Scene,
    finalize: Finalize,
) -> Result<Reply, ApiError> {
    let device_memory_budget = match query.get("device_memory_budget") {
        None => None,
        Some(v) => Some(match crate::scene::validate::parse_byte_size(&v) {
            Ok(0) => return Err(ApiError::BadRequest("device_memory_budget: must be more than 0 bytes".into())),
            Ok(n) => n,
            Err(e) => return Err(ApiError::BadRequest(format!("device_memory_budget: {e}"))),
        }),
    };
    let job = db::NewJob {
        scene: scene_text,
        priority: query.parse("priority")?.unwrap_or(0),
        device_memory_budget,
        no_image: query.flag("no_image")?,
        no_fields: query.flag("no_fields")?,
        max_orders: scene.solver.max_orders,
    };
    let inserted = match finalize {
        Some(f) => shared.db.insert_with(&job, shared.opts.max_queued, f)??,
        None => shared.db.insert(&job, shared.opts.max_queued)?,
    };
    match inserted {
        Insert::Accepted(job) => {
            shared.notify();
            tracing::info!("job {}: queued (priority {})", job.id, job.priority);
            let mut reply = Reply::json(201, &serde_json::json!({ "id": job.id, "state": job.state }));
            reply.headers.push(header("Location", &format!("/v1/jobs/{}", job.id)));
            Ok(reply)
        }
        Insert::Full(n) => Err(ApiError::QueueFull(n)),
    }
}

/// The job; with `?wait=S`, held until its state or order changes (at most S seconds).
fn get(shared: &Shared, id: i64, query: &Query) -> Result<Reply, ApiError> {
    let missing = || ApiError::NotFound(format!("no job {id}"));
    let first = shared.db.get(id)?.ok_or_else(missing)?;
    let wait: f64 = query.parse("wait")?.unwrap_or(0.0);
    if wait.is_nan() || wait < 0.0 {
        return Err(ApiError::BadRequest("query parameter wait: must be a number of seconds ≥ 0".into()));
    }
    let limit = Duration::from_secs_f64(wait.min(MAX_WAIT_SECONDS));
    let t = Instant::now();
    let mut job = first.clone();
    while t.elapsed() < limit && job.state == first.state && job.order == first.order {
        shared.wait_for_change(limit.saturating_sub(t.elapsed()).min(Duration::from_millis(250)));
        job = shared.db.get(id)?.ok_or_else(missing)?;
    }
    Ok(Reply::json(200, &job))
}

fn cancel(shared: &Shared, id: i64) -> Result<Reply, ApiError> {
    match shared.db.cancel(id)? {
        Cancel::Cancelled(job) => {
            shared.notify();
            tracing::info!("job {id}: cancel requested");
            Ok(Reply::json(200, &job))
        }
        // An ended job: DELETE removes it and its files.
        Cancel::Ended(job) => {
            shared.db.delete(id)?;
            shared.remove_job_files(id);
            tracing::info!("job {id}: deleted");
            Ok(Reply::json(200, &serde_json::json!({ "id": job.id, "state": "deleted" })))
        }
        Cancel::Missing => Err(ApiError::NotFound(format!("no job {id}"))),
    }
}

/// Queues a cancelled or failed job again; its solve continues from the checkpoint it kept (or
/// starts over when it stopped before its first one).
fn resume(shared: &Shared, id: i64) -> Result<Reply, ApiError> {
    match shared.db.requeue(id, shared.opts.max_queued)? {
        Requeue::Queued(job) => {
            shared.notify();
            let checkpoint = crate::job::work_dir(&shared.job_dir(id).join("out")).join("checkpoint.json");
            tracing::info!(
                "job {id}: queued again{}",
                if checkpoint.exists() {
                    " (it resumes from its checkpoint)"
                } else {
                    " (no checkpoint: from the start)"
                }
            );
            Ok(Reply::json(200, &job))
        }
        Requeue::NotStopped(job) => {
            Err(ApiError::Conflict(format!("job {id} is {}: only a cancelled or failed job can be resumed", job.state)))
        }
        Requeue::Full(n) => Err(ApiError::QueueFull(n)),
        Requeue::Missing => Err(ApiError::NotFound(format!("no job {id}"))),
    }
}

/// The files the finished solve wrote (the names in its report.json, and report.json).
fn outputs(shared: &Shared, id: i64) -> Result<Vec<String>, ApiError> {
    let job = shared.db.get(id)?.ok_or_else(|| ApiError::NotFound(format!("no job {id}")))?;
    if job.state != "done" {
        return Err(ApiError::Conflict(format!("job {id} is {}: outputs are there once it is done", job.state)));
    }
    let path = shared.job_dir(id).join("out/report.json");
    let report: serde_json::Value = std::fs::read(&path)
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok())
        .ok_or_else(|| ApiError::Internal(format!("job {id}: cannot read its report.json")))?;
    let mut names: Vec<String> =
        report["outputs"].as_array().into_iter().flatten().filter_map(|v| v.as_str().map(String::from)).collect();
    if !names.iter().any(|n| n == "report.json") {
        names.push("report.json".into());
    }
    Ok(names)
}

fn output(shared: &Shared, id: i64, name: &str) -> Result<Reply, ApiError> {
    let names = outputs(shared, id)?;
    if !names.iter().any(|n| n == name) {
        return Err(ApiError::NotFound(format!("job {id} has no output {name:?} (it has {})", names.join(", "))));
    }
    let path = shared.job_dir(id).join("out").join(name);
    let file = std::fs::File::open(&path).map_err(|e| ApiError::Internal(format!("job {id}: {name}: {e}")))?;
    let kind = match Path::new(name).extension().and_then(|e| e.to_str()) {
        Some("json") => "application/json",
        Some("png") => "image/png",
        Some("nhdr") => "text/plain",
        _ => "application/octet-stream",
    };
    Ok(Reply { status: 200, headers: vec![header("Content-Type", kind)], body: Body::File(file) })
}

/// Stores a volume file as `DATA/volumes/NAME` for scenes to name in `volume.raw`.
///
/// The body is streamed (never held in memory) into a temporary file beside `NAME`
/// ([`crate::output::write_atomic`]), which replaces `NAME` only once all of the `Content-Length`
/// has arrived: a body cut short (the client closed or half-closed early) is a 400 and `NAME` keeps
/// its old content. A chunked upload is refused (411): tiny_http's chunked decoder reads a body cut
/// off inside a chunk as its end, so its completeness could not be told.
fn upload(shared: &Shared, request: &mut Request, name: &str) -> Result<Reply, ApiError> {
    if !confine::plain_name(name) {
        return Err(ApiError::BadRequest(format!(
            "volume name {name:?}: use letters, digits, '.', '_' and '-' only, not starting with '.'"
        )));
    }
    let limit = shared.opts.max_upload_bytes;
    // tiny_http gives no length for a chunked body (nor for none at all).
    let Some(expected) = request.body_length().map(|n| n as u64) else {
        return Err(ApiError::LengthRequired(
            "send the volume with a Content-Length (a chunked upload cannot be told complete)".into(),
        ));
    };
    if expected > limit {
        return Err(ApiError::TooLarge(limit));
    }
    let dir = shared.data.join("volumes");
    std::fs::create_dir_all(&dir).map_err(|e| ApiError::Internal(format!("cannot create {}: {e}", dir.display())))?;
    let path = dir.join(name);
    // A failure of the body (not of the disk) is the client's: 400.
    let mut body_error: Option<ApiError> = None;
    let mut received = 0u64;
    let written = crate::output::write_atomic(&path, |w| {
        let mut reader = request.as_reader().take(expected);
        let mut buf = vec![0u8; 1 << 16];
        loop {
            let n = match reader.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    body_error = Some(ApiError::BadRequest(format!(
                        "cannot read the request body after {received} of its {expected} bytes: {e}"
                    )));
                    return Err(e);
                }
            };
            std::io::Write::write_all(w, &buf[..n])?;
            received += n as u64;
        }
        if received != expected {
            body_error = Some(cut_short(received, expected));
            return Err(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "the body was cut short"));
        }
        Ok(())
    });
    if let Some(e) = body_error {
        return Err(e);
    }
    written.map_err(|e| ApiError::Internal(e.to_string()))?;
    Ok(Reply::json(201, &serde_json::json!({ "path": format!("volumes/{name}"), "bytes": received })))
}
