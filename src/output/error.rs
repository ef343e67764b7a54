//! Errors while writing or reading output files; each names the file.

use crate::store::StoreError;
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("{}: cannot {action}: {source}", path.display())]
    Io { path: PathBuf, action: &'static str, source: std::io::Error },

    #[error("{}: invalid JSON: {source}", path.display())]
    Json { path: PathBuf, source: serde_json::Error },

    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },

    #[error(transparent)]
    Store(#[from] StoreError),

    #[error(transparent)]
    Input(#[from] crate::input::InputError),

    #[error("{}: another lpm run is writing to this directory (it holds {}/.lpm-lock); wait for it to finish or choose another --out", dir.display(), dir.display())]
    Locked { dir: PathBuf },

    /// Stopped on request (SIGTERM) while writing; what was written is removed.
    #[error("the export was cancelled")]
    Cancelled,

    #[error("{}: not enough disk space for {what}: {} needed, {} free", path.display(), super::space::human_bytes(*needed), super::space::human_bytes(*free))]
    NoSpace { path: PathBuf, needed: u64, free: u64, what: String },
}
