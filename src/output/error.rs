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
}
