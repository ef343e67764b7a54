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
    #[error("the server's answer is not what was expected: {0}")]
    Protocol(String),
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
        let text =
            std::fs::read_to_string(scene).map_err(|source| ClientError::Read { path: scene.to_path_buf(), source })?;
        let mut r = self.request("POST", "/v1/jobs").set("Content-Type", "application/toml");
        for (k, v) in query {
            r = r.query(k, v);
        }
        let r = self.check(r.send_string(&text))?;
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
