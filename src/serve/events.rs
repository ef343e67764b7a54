//! `GET /v1/jobs/{id}/events`: a job's progress pushed as server-sent events (`text/event-stream`).
//!
//! One `job` event carries the job (the JSON of `GET /v1/jobs/{id}`) as the stream opens and again
//! whenever its state or order changes; after an event whose state is `done`, `failed` or
//! `cancelled` the stream ends. A comment line (`: keep-alive`) every [`KEEP_ALIVE`] keeps proxies
//! from closing a quiet stream, and tells the server when the client has gone.
//!
//! tiny_http buffers a streamed body until it has a whole chunk of several KiB, which would hold
//! events back; so this handler takes the connection (`Request::into_writer`) and writes the
//! response itself: the head, then each event as one HTTP chunk, flushed at once, then the last
//! (empty) chunk. The gate adds `Connection: close` to the head and closes the connection after
//! the last chunk, as after every answer ([`super::gate`]).

use super::api::{self, ApiError};
use super::Shared;
use std::io::Write;
use std::time::{Duration, Instant};
use tiny_http::Request;

/// Longest quiet time on the stream.
pub const KEEP_ALIVE: Duration = Duration::from_secs(15);

/// Answers `GET /v1/jobs/{id}/events` (`id` is the path's segment).
pub fn stream(shared: &Shared, request: Request, id: &str) {
    let opened = (|| -> Result<(i64, super::db::Job), ApiError> {
        api::authorize(shared, &request)?;
        let id: i64 = id.parse().map_err(|_| ApiError::NotFound(format!("no job {id}")))?;
        let job = shared.db.get(id)?.ok_or_else(|| ApiError::NotFound(format!("no job {id}")))?;
        Ok((id, job))
    })();
    let (id, mut job) = match opened {
        Ok(v) => v,
        Err(e) => return api::send(request, e.into_reply()),
    };
    let mut w = request.into_writer();
    let head = "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-cache\r\n\
                Transfer-Encoding: chunked\r\nX-Accel-Buffering: no\r\n\r\n";
    if w.write_all(head.as_bytes()).and_then(|()| w.flush()).is_err() {
        return;
    }
    let mut sent = 0u64;
    let result = (|| -> std::io::Result<()> {
        loop {
            sent += 1;
            let data = serde_json::to_string(&job).unwrap_or_default();
            chunk(&mut w, &format!("id: {sent}\nevent: job\ndata: {data}\n\n"))?;
            if matches!(job.state.as_str(), "done" | "failed" | "cancelled") {
                return Ok(());
            }
            let mut quiet = Instant::now();
            loop {
                shared.wait_for_change(Duration::from_millis(500));
                match shared.db.get(id) {
                    Ok(Some(now)) if now.state != job.state || now.order != job.order => {
                        job = now;
                        break;
                    }
                    Ok(Some(_)) => {}
                    // Deleted meanwhile (or the queue failed): end the stream.
                    _ => return Ok(()),
                }
                if quiet.elapsed() >= KEEP_ALIVE {
                    chunk(&mut w, ": keep-alive\n\n")?;
                    quiet = Instant::now();
                }
            }
        }
    })();
    if result.is_ok() {
        let _ = w.write_all(b"0\r\n\r\n").and_then(|()| w.flush());
    } else {
        tracing::debug!("job {id}: the event stream's client went away");
    }
}

/// Writes `text` as one HTTP/1.1 chunk and flushes it.
fn chunk(w: &mut dyn Write, text: &str) -> std::io::Result<()> {
    write!(w, "{:x}\r\n{text}\r\n", text.len())?;
    w.flush()
}
