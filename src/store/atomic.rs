//! Write-then-rename: a file either has its old content or its complete new content, never half.
//!
//! Lives in the store (the lowest layer that writes files); `output::write_atomic` wraps it with
//! the output error type.

use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// The temporary name used while `path` is being written: same directory (so the rename is atomic),
/// the process id in the name (so two processes do not write the same temporary).
pub(crate) fn temp_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().map(|n| n.to_os_string()).unwrap_or_default();
    name.push(format!(".tmp-{}", std::process::id()));
    path.with_file_name(name)
}

/// Writes `path` through `write` into a temporary file, fsyncs it, renames it over `path`. On any
/// error the temporary is removed and `path` is untouched. The error says which step failed.
pub(crate) fn write_atomic_io(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>,
) -> Result<(), (&'static str, io::Error)> {
    let tmp = temp_path(path);
    let result = write_then_rename(path, &tmp, write);
    if result.is_err() {
        // Best effort: the temporary may not exist if creating it failed.
        let _ = fs::remove_file(&tmp);
    }
    result
}

fn write_then_rename(
    path: &Path,
    tmp: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>,
) -> Result<(), (&'static str, io::Error)> {
    let file = File::create(tmp).map_err(|e| ("create the temporary file", e))?;
    let mut w = BufWriter::new(file);
    write(&mut w).map_err(|e| ("write", e))?;
    w.flush().map_err(|e| ("write", e))?;
    let file = w.into_inner().map_err(|e| ("write", e.into_error()))?;
    file.sync_all().map_err(|e| ("sync", e))?;
    drop(file);
    fs::rename(tmp, path).map_err(|e| ("rename the temporary file into place", e))?;
    // Make the rename itself durable where the platform allows opening a directory.
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        if let Ok(d) = File::open(dir) {
            let _ = d.sync_all();
        }
    }
    Ok(())
}
