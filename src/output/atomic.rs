//! Atomic file writes for every output.

use super::OutputError;
use serde::Serialize;
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

/// Writes `path` through `write` into a fresh `.<name>.<random>.lpm-tmp` in the same directory
/// (`O_EXCL`, never following a planted symlink), fsyncs it and
/// renames it over `path`. On any error the temporary is removed and `path` keeps its old content
/// (or stays absent).
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>,
) -> Result<(), OutputError> {
    crate::store::write_atomic_io(path, write).map_err(|(action, source)| OutputError::Io {
        path: path.to_path_buf(),
        action,
        source,
    })
}

/// Writes `value` as pretty-printed JSON (with a final newline), atomically.
pub fn write_json_atomic(path: &Path, value: &impl Serialize) -> Result<(), OutputError> {
    let mut bytes =
        serde_json::to_vec_pretty(value).map_err(|source| OutputError::Json { path: path.to_path_buf(), source })?;
    bytes.push(b'\n');
    write_atomic(path, |w| w.write_all(&bytes))
}
