//! The client side of `lpm serve`, for scripts: `lpm submit`, `lpm status`, `lpm fetch`.
//! A blocking HTTP client (ureq, no TLS: the server is on loopback or a cluster-internal network).

use std::path::{Path, PathBuf};
use std::time::Duration;

#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("{server}: {message} (HTTP {status})")]
    Server { server: String, status: u16, message: String },
    #[error("cannot reach the server {server}: {reason}")]
    Transport { server: String, reason: String },
    #[error("cannot read {}: {source}", .path.display())]
    Read { path: PathBuf, source: std::io::Error },
    #[error("{0}")]
    Output(#[from] crate::output::OutputError),
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    #[error("the server's answer is not what was expected: {0}")]
    Protocol(String),
}

/// A boundary unlikely to occur in a file: the clock and the process id, mixed.
fn rand_u64() -> u64 {
    let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64);
    let mut x = t ^ (u64::from(std::process::id()) << 32) ^ 0x9e37_79b9_7f4a_7c15;
    // splitmix64's finaliser.
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

/// Where the server is and how to authenticate.
pub struct Client {
    pub server: String,
    pub token: Option<String>,
    agent: ureq::Agent,
}

impl Client {
    pub fn new(server: &str, token: Option<String>) -> Client {
        let agent = ureq::AgentBuilder::new().timeout_connect(Duration::from_secs(10)).build();
        Client { server: server.trim_end_matches('/').to_string(), token, agent }
    }

    fn request(&self, method: &str, path: &str) -> ureq::Request {
        let r = self.agent.request(method, &format!("{}{path}", self.server));
        match &self.token {
            Some(t) => r.set("Authorization", &format!("Bearer {t}")),
            None => r,
        }
    }

    fn check(&self, result: Result<ureq::Response, ureq::Error>) -> Result<ureq::Response, ClientError> {
        match result {
            Ok(r) => Ok(r),
            Err(ureq::Error::Status(status, r)) => {
                let body = r.into_string().unwrap_or_default();
                let message = serde_json::from_str::<serde_json::Value>(&body)
                    .ok()
                    .and_then(|v| v["error"].as_str().map(String::from))
                    .unwrap_or(body);
                Err(ClientError::Server { server: self.server.clone(), status, message })
            }
            Err(e) => Err(ClientError::Transport { server: self.server.clone(), reason: e.to_string() }),
        }
    }

    fn json(&self, r: ureq::Response) -> Result<serde_json::Value, ClientError> {
        r.into_json().map_err(|e| ClientError::Protocol(e.to_string()))
    }

    /// Submits the scene file; `query` holds extra parameters (`priority=5`, …). Returns the job.
    pub fn submit(&self, scene: &Path, query: &[(&str, String)]) -> Result<serde_json::Value, ClientError> {
        let text = crate::input::read_text_capped(scene, crate::scene::validate::MAX_SCENE_BYTES, "a scene file")?;
        let mut r = self.request("POST", "/v1/jobs").set("Content-Type", "application/toml");
        for (k, v) in query {
            r = r.query(k, v);
        }
        let r = self.check(r.send_string(&text))?;
        self.json(r)
    }

    /// Submits the scene file with its volume files as `multipart/form-data` (the scene names each
    /// volume by its file name); the files are streamed, not read into memory.
    pub fn submit_with_volumes(
        &self,
        scene: &Path,
        volumes: &[PathBuf],
        query: &[(&str, String)],
    ) -> Result<serde_json::Value, ClientError> {
        use std::io::{Cursor, Read};
        let read_err = |path: &Path| {
            let path = path.to_path_buf();
            move |source| ClientError::Read { path, source }
        };
        let text = crate::input::read_capped(scene, crate::scene::validate::MAX_SCENE_BYTES, "a scene file")?;
        let boundary = format!("lpm-{:016x}", rand_u64());
        let mut head = format!(
            "--{boundary}\r\nContent-Disposition: form-data; name=\"scene\"; filename=\"scene.toml\"\r\nContent-Type: application/toml\r\n\r\n"
        )
        .into_bytes();
        head.extend_from_slice(&text);
        let mut length = head.len() as u64;
        let mut body: Box<dyn Read + Send> = Box::new(Cursor::new(head));
        for v in volumes {
            let name =
                v.file_name().and_then(|n| n.to_str()).filter(|n| super::confine::plain_name(n)).ok_or_else(|| {
                    ClientError::Protocol(format!(
                        "{}: a volume sent to the server needs a plain file name (letters, digits, '.', '_', '-')",
                        v.display()
                    ))
                })?;
            // Regular files only: a FIFO would block here, a device never end.
            let file = crate::input::open(v)?;
            let size = file.metadata().map_err(read_err(v))?.len();
            let part = format!(
                "\r\n--{boundary}\r\nContent-Disposition: form-data; name=\"volume\"; filename=\"{name}\"\r\nContent-Type: application/octet-stream\r\n\r\n"
            );
            length += part.len() as u64 + size;
            body = Box::new(body.chain(Cursor::new(part.into_bytes())).chain(file.take(size)));
        }
        let tail = format!("\r\n--{boundary}--\r\n");
        length += tail.len() as u64;
        let body = body.chain(Cursor::new(tail.into_bytes()));
        let mut r = self
            .request("POST", "/v1/jobs")
            .set("Content-Type", &format!("multipart/form-data; boundary={boundary}"))
            .set("Content-Length", &length.to_string());
        for (k, v) in query {
            r = r.query(k, v);
        }
        let r = self.check(r.send(body))?;
        self.json(r)
    }

    /// One job (`wait`: hold until it changes, at most that many seconds), or all jobs.
    pub fn status(&self, id: Option<i64>, wait: Option<f64>) -> Result<serde_json::Value, ClientError> {
        let r = match id {
            Some(id) => {
                let r = self.request("GET", &format!("/v1/jobs/{id}"));
                match wait {
                    Some(w) => r.query("wait", &w.to_string()),
                    None => r,
                }
            }
            None => self.request("GET", "/v1/jobs"),
        };
        let r = self.check(r.call())?;
        self.json(r)
    }

    /// Waits until job `id` has ended (done, failed or cancelled) and returns it.
    pub fn wait_ended(
        &self,
        id: i64,
        mut on_change: impl FnMut(&serde_json::Value),
    ) -> Result<serde_json::Value, ClientError> {
        loop {
            let job = self.status(Some(id), Some(30.0))?;
            on_change(&job);
            if matches!(job["state"].as_str(), Some("done" | "failed" | "cancelled")) {
                return Ok(job);
            }
        }
    }

    /// Cancels job `id` (or deletes it once ended).
    pub fn cancel(&self, id: i64) -> Result<serde_json::Value, ClientError> {
        let r = self.check(self.request("DELETE", &format!("/v1/jobs/{id}")).call())?;
        self.json(r)
    }

    /// Queues a cancelled or failed job `id` again (it continues from its checkpoint).
    pub fn resume(&self, id: i64) -> Result<serde_json::Value, ClientError> {
        let r = self.check(self.request("POST", &format!("/v1/jobs/{id}/resume")).call())?;
        self.json(r)
    }

    /// Downloads outputs of job `id` into `dir` (each written atomically); all of them when `names`
    /// is empty. Returns the names written.
    pub fn fetch(&self, id: i64, dir: &Path, names: &[String]) -> Result<Vec<String>, ClientError> {
        let names = if names.is_empty() {
            let list = self.json(self.check(self.request("GET", &format!("/v1/jobs/{id}/outputs")).call())?)?;
            list["outputs"]
                .as_array()
                .ok_or_else(|| ClientError::Protocol("no outputs list".into()))?
                .iter()
                .filter_map(|v| v.as_str().map(String::from))
                .collect()
        } else {
            names.to_vec()
        };
        std::fs::create_dir_all(dir).map_err(|source| ClientError::Read { path: dir.to_path_buf(), source })?;
        for name in &names {
            if !super::confine::plain_name(name) {
                return Err(ClientError::Protocol(format!("refusing the output name {name:?}")));
            }
            let r = self.check(self.request("GET", &format!("/v1/jobs/{id}/outputs/{name}")).call())?;
            let mut reader = r.into_reader();
            crate::output::write_atomic(&dir.join(name), |w| std::io::copy(&mut reader, w).map(|_| ()))?;
        }
        Ok(names)
    }
}
