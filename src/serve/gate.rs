//! The front door: each connection's request head is read and checked here, within bounds, before
//! tiny_http (or the token check) sees a byte of it.
//!
//! tiny_http 0.12 reads a request head line by line into a buffer that grows without limit and
//! without a timeout (`ClientConnection::read_next_line`), and has no setting or hook to bound it:
//! one connection sending a header of hundreds of MiB grew the server by as much, before any token
//! was asked for. `Server::from_listener` takes only a listener (a TCP or Unix one), never a stream
//! with bytes already read. So the server listens on its own socket, and for each connection this
//! module
//!
//! 1. reads the head (the request line and the header lines, up to the empty line): at most
//!    [`MAX_HEAD_BYTES`] in all and [`MAX_LINE_BYTES`] a line, within [`HEAD_TIMEOUT`]; over a limit
//!    it answers `431` (`414` for the request line; `408` when too slow) and closes;
//! 2. refuses what tiny_http would read wrongly or unboundedly: an HTTP version other than 1.0 or
//!    1.1 (tiny_http answers `505` and then reads a next head), a `Content-Length` that is not one
//!    number, or one larger than any body the server accepts (`413`, before the token is checked:
//!    tiny_http allocates a buffer of the unread length to skip a body nobody read);
//! 3. passes the head, with `Connection: close` as its first header (the client's own `Connection`
//!    headers left out), and then the body, to tiny_http over a Unix socket in a directory of its
//!    own (mode 0700) that only this server's user can reach ([`Backend`]); and tiny_http's answer
//!    back to the client, with `Connection: close` added to its head.
//!
//! So each connection carries one request, and tiny_http reads exactly the one head checked here:
//! `Connection: close` makes it read no further head, which would reach it unchecked. The body
//! bytes passed on are bounded as well (the request-size budget of a connection): exactly the
//! `Content-Length`, or for a chunked body at most twice the largest body accepted (its framing
//! included), and none for a request with neither; and a body that stops arriving for
//! [`BODY_IDLE_TIMEOUT`] ends there (an upload cut short that way is refused by its handler). At
//! most [`MAX_HEADS_READ_AT_ONCE`] connections may be sending their head at a time (`503` beyond),
//! which bounds the memory of heads in all. Clients see `Connection: close` on every answer and
//! open a new connection for their next request: a job server's requests are few.

use std::io::{self, ErrorKind, Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The largest request head (request line, header lines and the empty line).
pub const MAX_HEAD_BYTES: usize = 64 * 1024;
/// The longest line of a request head (without its CRLF).
pub const MAX_LINE_BYTES: usize = 8 * 1024;
/// The time a client has to send its whole request head.
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(30);
/// The longest pause inside a request body.
pub const BODY_IDLE_TIMEOUT: Duration = Duration::from_secs(300);
/// The most connections sending their request head at once.
pub const MAX_HEADS_READ_AT_ONCE: usize = 256;
/// After refusing a request, what of the client's bytes is still read (and dropped) so that it
/// reads the answer rather than a reset: at most this long, at most [`LINGER_BYTES`].
const LINGER: Duration = Duration::from_secs(2);
const LINGER_BYTES: usize = 1 << 20;
/// Name of the directories holding the socket between the gate and tiny_http.
const DIR_PREFIX: &str = ".lpm-gate-";
const SOCKET_NAME: &str = "http.sock";

/// tiny_http's side of the gate: a Unix socket in a fresh directory of mode 0700, under the data
/// root (or the system's temporary directory where the data root's path is too long for a socket
/// address); removed with this value, or by the next server started after a kill.
pub struct Backend {
    path: PathBuf,
    _dir: tempfile::TempDir,
}

impl Backend {
    /// Makes the socket (after removing the ones killed servers left) and a tiny_http server on it.
    pub fn start(data: &Path) -> Result<(Backend, tiny_http::Server), String> {
        let places = [data.to_path_buf(), std::env::temp_dir()];
        for place in &places {
            remove_stale(place);
        }
        let mut failures = Vec::new();
        for place in &places {
            match Self::bind_in(place) {
                Ok((backend, listener)) => {
                    let server = tiny_http::Server::from_listener(listener, None).map_err(|e| e.to_string())?;
                    return Ok((backend, server));
                }
                Err(e) => failures.push(format!("{}: {e}", place.display())),
            }
        }
        Err(format!("cannot make the server's internal socket ({})", failures.join("; ")))
    }

    fn bind_in(place: &Path) -> io::Result<(Backend, UnixListener)> {
        // tempfile makes the directory with mode 0700 under a name nobody can guess.
        let dir = tempfile::Builder::new().prefix(DIR_PREFIX).tempdir_in(place)?;
        let path = dir.path().join(SOCKET_NAME);
        let listener = UnixListener::bind(&path)?;
        Ok((Backend { path, _dir: dir }, listener))
    }
}

/// Removes the gate directories in `place` whose socket no server listens on (a killed server's).
fn remove_stale(place: &Path) {
    let Ok(entries) = std::fs::read_dir(place) else { return };
    for e in entries.flatten() {
        let is_gate = e.file_name().to_string_lossy().starts_with(DIR_PREFIX);
        if !is_gate || !e.file_type().is_ok_and(|t| t.is_dir()) {
            continue;
        }
        // Another user's directory, or a live server's, refuses differently or answers.
        if let Err(err) = UnixStream::connect(e.path().join(SOCKET_NAME)) {
            if matches!(err.kind(), ErrorKind::ConnectionRefused | ErrorKind::NotFound) {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
}

/// Takes the connections on `listener`, each on a thread of its own, until the process ends.
pub fn accept(listener: TcpListener, backend: Arc<Backend>, max_body: u64) {
    let heads = Arc::new(AtomicUsize::new(0));
    for conn in listener.incoming() {
        match conn {
            Ok(client) => {
                let backend = Arc::clone(&backend);
                let heads = Arc::clone(&heads);
                let spawned = std::thread::Builder::new()
                    .name("lpm-gate".into())
                    .spawn(move || connection(client, &backend.path, max_body, &heads));
                if let Err(e) = spawned {
                    tracing::warn!("cannot start a thread for a connection: {e}");
                }
            }
            Err(e) => {
                // Out of file descriptors, say: wait a little rather than spin.
                tracing::warn!("cannot accept a connection: {e}");
                std::thread::sleep(Duration::from_millis(50));
            }
        }
    }
}

/// One of the [`MAX_HEADS_READ_AT_ONCE`] places for a connection reading its head.
struct HeadSlot<'a>(&'a AtomicUsize);

impl<'a> HeadSlot<'a> {
    fn take(count: &'a AtomicUsize) -> Option<HeadSlot<'a>> {
        let taken = count.fetch_add(1, Ordering::AcqRel);
        let slot = HeadSlot(count);
        (taken < MAX_HEADS_READ_AT_ONCE).then_some(slot)
    }
}

impl Drop for HeadSlot<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Why a head is not passed on: the status and the message answered.
#[derive(Debug, PartialEq, Eq)]
pub struct Refusal {
    pub status: u16,
    pub message: String,
}

fn refusal(status: u16, message: impl Into<String>) -> Refusal {
    Refusal { status, message: message.into() }
}

/// How much body follows a head.
#[derive(Debug, PartialEq, Eq)]
pub enum Body {
    None,
    Length(u64),
    Chunked,
}

/// What ended the reading of a head early.
#[derive(Debug)]
enum HeadError {
    /// The client closed (or failed) before its head ended: nothing to answer.
    Gone,
    Refused(Refusal),
}

fn connection(mut client: TcpStream, backend: &Path, max_body: u64, heads: &AtomicUsize) {
    let _ = client.set_nodelay(true);
    let read = match HeadSlot::take(heads) {
        Some(_slot) => read_head(&mut client, Instant::now() + HEAD_TIMEOUT),
        None => Err(HeadError::Refused(refusal(
            503,
            "too many connections are sending their request at once: try again later",
        ))),
    };
    let (buf, head_len) = match read {
        Ok(v) => v,
        Err(HeadError::Gone) => return,
        Err(HeadError::Refused(r)) => return refuse(client, &r),
    };
    let (head, body) = match check_head(&buf[..head_len], max_body) {
        Ok(v) => v,
        Err(r) => return refuse(client, &r),
    };
    let mut left = match body {
        Body::None => 0,
        Body::Length(n) => n,
        Body::Chunked => max_body.saturating_mul(2).saturating_add(MAX_HEAD_BYTES as u64),
    };
    let mut server = match UnixStream::connect(backend) {
        Ok(s) => s,
        Err(e) => {
            tracing::error!("cannot reach the request handler at {}: {e}", backend.display());
            return refuse(client, &refusal(503, "the server cannot take requests now: try again later"));
        }
    };
    // The head and the start of the body that came with it, in one write.
    let early = &buf[head_len..];
    let early = &early[..early.len().min(usize::try_from(left).unwrap_or(usize::MAX))];
    left -= early.len() as u64;
    let mut first = head;
    first.extend_from_slice(early);
    let (Ok(to_client), Ok(from_server)) = (client.try_clone(), server.try_clone()) else { return };
    if client.set_read_timeout(Some(BODY_IDLE_TIMEOUT)).is_err() || server.write_all(&first).is_err() {
        return;
    }
    let answering =
        std::thread::Builder::new().name("lpm-gate-answer".into()).spawn(move || answer(from_server, to_client));
    if answering.is_err() {
        return;
    }
    // The body: client → tiny_http, at most `left` bytes; then tiny_http reads an end.
    let mut chunk = vec![0u8; 1 << 16];
    while left > 0 {
        let want = chunk.len().min(usize::try_from(left).unwrap_or(usize::MAX));
        match client.read(&mut chunk[..want]) {
            Ok(0) => break,
            Ok(n) => {
                if server.write_all(&chunk[..n]).is_err() {
                    // tiny_http answered without reading the rest (a 411, say): what the client
                    // still sends is read and dropped a while, so that closing with it unread does
                    // not reset the connection before the client has read the answer.
                    let _ = server.shutdown(Shutdown::Write);
                    return linger(&mut client);
                }
                left -= n as u64;
            }
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            // Timed out, or reset: the body ends here.
            Err(_) => break,
        }
    }
    let _ = server.shutdown(Shutdown::Write);
}

/// Copies tiny_http's answer to the client, adding `Connection: close` to its head (interim `1xx`
/// heads, `100 Continue`, go as they are).
fn answer(mut from: UnixStream, mut to: TcpStream) {
    let mut buf = vec![0u8; 1 << 16];
    let mut head: Option<Vec<u8>> = Some(Vec::new());
    loop {
        let n = match from.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == ErrorKind::Interrupted => continue,
            Err(_) => break,
        };
        let sent = match head.as_mut() {
            None => to.write_all(&buf[..n]),
            Some(pending) => {
                pending.extend_from_slice(&buf[..n]);
                let (out, done) = take_heads(pending);
                if done {
                    head = None;
                }
                to.write_all(&out)
            }
        };
        if sent.is_err() {
            // The client is gone: tell tiny_http (an event stream stops at its next write).
            let _ = from.shutdown(Shutdown::Both);
            return;
        }
    }
    if let Some(rest) = head {
        let _ = to.write_all(&rest);
    }
    let _ = to.flush();
    let _ = to.shutdown(Shutdown::Write);
}

/// Takes the complete answer heads from the start of `pending`: returns what to send now and
/// whether the final (non-`1xx`) head is among it (then all of `pending` is sent, the rest being
/// body).
fn take_heads(pending: &mut Vec<u8>) -> (Vec<u8>, bool) {
    let mut out = Vec::new();
    loop {
        let Some(end) = find(pending, b"\r\n\r\n").map(|i| i + 4) else {
            if pending.len() > MAX_HEAD_BYTES {
                // Not a head tiny_http writes: pass it on untouched.
                out.append(pending);
                return (out, true);
            }
            return (out, false);
        };
        let interim = pending.get(9) == Some(&b'1');
        let status_end = find(pending, b"\r\n").map_or(end, |i| i + 2);
        out.extend_from_slice(&pending[..status_end]);
        if !interim {
            out.extend_from_slice(b"Connection: close\r\n");
        }
        out.extend_from_slice(&pending[status_end..end]);
        pending.drain(..end);
        if !interim {
            out.append(pending);
            return (out, true);
        }
    }
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

/// Reads from `client` until the empty line that ends the head, by `deadline`. Returns the bytes
/// read and the length of the head among them (what follows is the start of the body). Lines end
/// at CRLF, as tiny_http reads them.
fn read_head(client: &mut TcpStream, deadline: Instant) -> Result<(Vec<u8>, usize), HeadError> {
    let mut buf: Vec<u8> = Vec::with_capacity(4096);
    let mut chunk = [0u8; 4096];
    let mut line_start = 0;
    let mut scanned = 0;
    let mut first_line = true;
    let too_long = |first_line: bool| {
        HeadError::Refused(if first_line {
            refusal(414, format!("the request line is longer than {MAX_LINE_BYTES} bytes"))
        } else {
            refusal(431, format!("a header line is longer than {MAX_LINE_BYTES} bytes"))
        })
    };
    let too_large =
        || HeadError::Refused(refusal(431, format!("the request head is larger than {MAX_HEAD_BYTES} bytes")));
    loop {
        while scanned < buf.len() {
            scanned += 1;
            if buf[scanned - 1] != b'\n' || scanned - line_start < 2 || buf[scanned - 2] != b'\r' {
                continue;
            }
            let len = scanned - 2 - line_start;
            if len > MAX_LINE_BYTES {
                return Err(too_long(first_line));
            }
            if len == 0 {
                if first_line {
                    return Err(HeadError::Refused(refusal(400, "the request line is empty")));
                }
                if scanned > MAX_HEAD_BYTES {
                    return Err(too_large());
                }
                return Ok((buf, scanned));
            }
            first_line = false;
            line_start = scanned;
        }
        // The line still open (a CR at its end may be the start of its CRLF).
        if buf.len() - line_start > MAX_LINE_BYTES + 1 {
            return Err(too_long(first_line));
        }
        if buf.len() > MAX_HEAD_BYTES {
            return Err(too_large());
        }
        let now = Instant::now();
        if now >= deadline {
            return Err(HeadError::Refused(refusal(
                408,
                format!("the request head did not arrive within {} seconds", HEAD_TIMEOUT.as_secs()),
            )));
        }
        if client.set_read_timeout(Some(deadline - now)).is_err() {
            return Err(HeadError::Gone);
        }
        match client.read(&mut chunk) {
            Ok(0) => return Err(HeadError::Gone),
            Ok(n) => buf.extend_from_slice(&chunk[..n]),
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            // Checked again at the top: past the deadline, it is answered.
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(_) => return Err(HeadError::Gone),
        }
    }
}

/// Checks a complete head (ending with its empty line) and returns the head to pass to tiny_http
/// and how much body follows it.
pub fn check_head(head: &[u8], max_body: u64) -> Result<(Vec<u8>, Body), Refusal> {
    let text = std::str::from_utf8(head)
        .ok()
        .filter(|t| t.is_ascii())
        .ok_or_else(|| refusal(400, "the request head is not ASCII"))?;
    let text = text.strip_suffix("\r\n\r\n").ok_or_else(|| refusal(400, "the request head has no end"))?;
    let mut lines = text.split("\r\n");
    let request_line = lines.next().unwrap_or_default();
    // tiny_http takes the third word of the trimmed request line as the version.
    match request_line.trim().split(' ').nth(2) {
        Some("HTTP/1.0" | "HTTP/1.1") => {}
        Some(v) if v.starts_with("HTTP/") => {
            return Err(refusal(505, format!("{v} is not served: use HTTP/1.1 (or 1.0)")));
        }
        _ => return Err(refusal(400, "the request line is not METHOD PATH HTTP/1.1")),
    }
    let mut out = Vec::with_capacity(head.len() + 32);
    out.extend_from_slice(request_line.as_bytes());
    out.extend_from_slice(b"\r\nConnection: close\r\n");
    let mut lengths: Vec<&str> = Vec::new();
    let mut chunked = false;
    for line in lines {
        let (name, value) = line.trim().split_once(':').unwrap_or((line.trim(), ""));
        if name.eq_ignore_ascii_case("Connection") {
            continue;
        }
        if name.eq_ignore_ascii_case("Content-Length") {
            lengths.push(value.trim());
        }
        if name.eq_ignore_ascii_case("Transfer-Encoding") {
            chunked = true;
        }
        out.extend_from_slice(line.as_bytes());
        out.extend_from_slice(b"\r\n");
    }
    out.extend_from_slice(b"\r\n");
    // tiny_http ignores the Content-Length of a request with a Transfer-Encoding, as HTTP says.
    let body = if chunked {
        Body::Chunked
    } else if let Some(first) = lengths.first() {
        if lengths.iter().any(|l| l != first) {
            return Err(refusal(400, "the request has Content-Length headers that differ"));
        }
        let n: u64 = first.parse().map_err(|_| refusal(400, format!("Content-Length {first:?} is not a number")))?;
        if n > max_body {
            return Err(refusal(413, format!("the request body is larger than the limit of {max_body} bytes")));
        }
        Body::Length(n)
    } else {
        Body::None
    };
    Ok((out, body))
}

/// Answers `refusal` and closes the connection (after reading a little more of what the client is
/// still sending, so that it reads the answer).
fn refuse(mut client: TcpStream, refusal: &Refusal) {
    let reason = match refusal.status {
        400 => "Bad Request",
        408 => "Request Timeout",
        413 => "Payload Too Large",
        414 => "URI Too Long",
        431 => "Request Header Fields Too Large",
        503 => "Service Unavailable",
        505 => "HTTP Version Not Supported",
        _ => "Error",
    };
    let mut body = serde_json::to_vec_pretty(&serde_json::json!({ "error": refusal.message })).unwrap_or_default();
    body.push(b'\n');
    let mut answer = format!(
        "HTTP/1.1 {} {reason}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        refusal.status,
        body.len()
    )
    .into_bytes();
    answer.extend_from_slice(&body);
    let _ = client.set_write_timeout(Some(LINGER));
    if client.write_all(&answer).is_err() {
        return;
    }
    let _ = client.shutdown(Shutdown::Write);
    linger(&mut client);
}

/// Reads and drops what the client still sends, until it closes, at most [`LINGER`] and
/// [`LINGER_BYTES`]: a connection closed with bytes unread is reset, and a reset can reach the
/// client before it has read the answer.
fn linger(client: &mut TcpStream) {
    let end = Instant::now() + LINGER;
    let mut left = LINGER_BYTES;
    let mut chunk = [0u8; 16 * 1024];
    while left > 0 {
        let now = Instant::now();
        if now >= end || client.set_read_timeout(Some(end - now)).is_err() {
            break;
        }
        match client.read(&mut chunk) {
            Ok(0) => break,
            Ok(n) => left = left.saturating_sub(n),
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(_) => break,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn head(lines: &[&str]) -> Vec<u8> {
        format!("{}\r\n\r\n", lines.join("\r\n")).into_bytes()
    }

    #[test]
    fn a_head_gets_connection_close_first_and_loses_the_clients_own() {
        let (out, body) =
            check_head(&head(&["GET /v1/health HTTP/1.1", "Host: x", "connection: keep-alive"]), 100).unwrap();
        assert_eq!(out, b"GET /v1/health HTTP/1.1\r\nConnection: close\r\nHost: x\r\n\r\n");
        assert_eq!(body, Body::None);
    }

    #[test]
    fn bodies_are_sized_and_bounded() {
        let put = |extra: &[&str]| {
            let mut lines = vec!["PUT /v1/volumes/a.raw HTTP/1.1"];
            lines.extend_from_slice(extra);
            check_head(&head(&lines), 1000)
        };
        assert_eq!(put(&["Content-Length: 1000"]).unwrap().1, Body::Length(1000));
        assert_eq!(put(&["Content-Length: 1001"]).unwrap_err().status, 413);
        assert_eq!(put(&["Content-Length: 5", "Content-Length: 6"]).unwrap_err().status, 400);
        assert_eq!(put(&["Content-Length: x"]).unwrap_err().status, 400);
        assert_eq!(put(&["Transfer-Encoding: chunked", "Content-Length: 99999"]).unwrap().1, Body::Chunked);
    }

    #[test]
    fn versions_tiny_http_would_read_on_after_are_refused() {
        assert_eq!(check_head(&head(&["GET / HTTP/2.0"]), 0).unwrap_err().status, 505);
        assert_eq!(check_head(&head(&["GET /"]), 0).unwrap_err().status, 400);
        assert_eq!(check_head(&head(&["GET / HTTP/1.0"]), 0).unwrap().1, Body::None);
        assert_eq!(check_head("GET / HTTP/1.1\r\nX: é\r\n\r\n".as_bytes(), 0).unwrap_err().status, 400);
    }

    #[test]
    fn the_final_answer_head_gets_connection_close_and_interim_ones_do_not() {
        let mut pending = b"HTTP/1.1 100 Continue\r\n\r\nHTTP/1.1 201 Created\r\nA: b\r\n\r\nbody".to_vec();
        let (out, done) = take_heads(&mut pending);
        assert!(done);
        assert_eq!(
            out,
            b"HTTP/1.1 100 Continue\r\n\r\nHTTP/1.1 201 Created\r\nConnection: close\r\nA: b\r\n\r\nbody".to_vec()
        );
        let mut partial = b"HTTP/1.1 200 OK\r\nA: b\r\n".to_vec();
        assert_eq!(take_heads(&mut partial), (Vec::new(), false));
    }

    /// Over a loopback socket: a head line without end is refused after [`MAX_LINE_BYTES`], a head
    /// too large in all after [`MAX_HEAD_BYTES`], and a complete head comes back with its length.
    #[test]
    fn heads_are_read_within_their_limits() {
        let read_from = |bytes: Vec<u8>| {
            let listener = TcpListener::bind("127.0.0.1:0").unwrap();
            let addr = listener.local_addr().unwrap();
            let sender = std::thread::spawn(move || {
                let mut s = TcpStream::connect(addr).unwrap();
                let _ = s.write_all(&bytes);
                s
            });
            let (mut stream, _) = listener.accept().unwrap();
            let result = read_head(&mut stream, Instant::now() + Duration::from_secs(10));
            // Closed first: a sender still writing what was not read stops with an error.
            drop(stream);
            drop(sender.join());
            result
        };
        let status = |r: Result<(Vec<u8>, usize), HeadError>| match r {
            Err(HeadError::Refused(r)) => r.status,
            other => panic!("{other:?}"),
        };
        let mut long_line = b"GET /v1/health HTTP/1.1\r\nX: ".to_vec();
        long_line.resize(long_line.len() + 4 * MAX_LINE_BYTES, b'a');
        assert_eq!(status(read_from(long_line)), 431);
        let mut long_request_line = b"GET /".to_vec();
        long_request_line.resize(2 * MAX_LINE_BYTES, b'a');
        assert_eq!(status(read_from(long_request_line)), 414);
        let mut many = b"GET /v1/health HTTP/1.1\r\n".to_vec();
        while many.len() <= 2 * MAX_HEAD_BYTES {
            many.extend_from_slice(b"X-Header: some value\r\n");
        }
        assert_eq!(status(read_from(many)), 431);
        let (buf, len) = read_from(b"PUT /x HTTP/1.1\r\nContent-Length: 2\r\n\r\nab".to_vec()).unwrap();
        assert_eq!(len, buf.len() - 2);
    }
}
