//! Write-then-rename: a file either has its old content or its complete new content, never half.
//!
//! Lives in the store (the lowest layer that writes files); `output::write_atomic` wraps it with
//! the output error type.
//!
//! The temporary is created by the `tempfile` crate in the target's own directory (so the rename is
//! atomic): `O_CREAT | O_EXCL` with an unpredictable name, so a symlink or file planted in a shared
//! directory is never followed or overwritten. Its name is `.<name>.<random>.lpm-tmp`: hidden, and
//! recognisable by [`is_temp_name`] so a later run can remove what a killed one left behind.

use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::Path;

/// Suffix of every temporary file lpm creates; see [`is_temp_name`].
pub(crate) const TEMP_SUFFIX: &str = ".lpm-tmp";

/// True for the name of a temporary file written by `write_atomic_io` (left behind only when the
/// process was killed while writing), or by lpm before 0.1's tempfile change (`<name>.tmp-<pid>`).
pub fn is_temp_name(name: &str) -> bool {
    let legacy = name
        .rsplit_once(".tmp-")
        .is_some_and(|(base, pid)| !base.is_empty() && !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()));
    (name.starts_with('.') && name.ends_with(TEMP_SUFFIX)) || legacy
}

/// Writes `path` through `write` into a fresh temporary file beside it, fsyncs it, renames it over
/// `path`. On any error the temporary is removed and `path` is untouched. The error says which step
/// failed.
pub(crate) fn write_atomic_io(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>,
) -> Result<(), (&'static str, io::Error)> {
    let dir = match path.parent().filter(|d| !d.as_os_str().is_empty()) {
        Some(d) => d,
        None => Path::new("."),
    };
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    // Dropping the NamedTempFile on any error path removes the temporary.
    let prefix = format!(".{name}.");
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(TEMP_SUFFIX);
    // tempfile's default is 0600; an output is an ordinary file (0666 less the umask), like `File::create`.
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
    let tmp = builder.tempfile_in(dir).map_err(|e| ("create the temporary file", e))?;
    let (file, tmp_path) = tmp.into_parts();
    let mut w = BufWriter::new(file);
    write(&mut w).map_err(|e| ("write", e))?;
    w.flush().map_err(|e| ("write", e))?;
    let file = w.into_inner().map_err(|e| ("write", e.into_error()))?;
    file.sync_all().map_err(|e| ("sync", e))?;
    drop(file);
    tmp_path.persist(path).map_err(|e| ("rename the temporary file into place", e.error))?;
    // Make the rename itself durable where the platform allows opening a directory.
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// Removes the temporaries ([`is_temp_name`]) a killed run left in `dir` (not recursive). Only
/// called while the directory's lock is held, so no live writer owns them. Returns how many.
pub fn remove_stale_temps(dir: &Path) -> io::Result<usize> {
    let mut removed = 0;
    for entry in fs::read_dir(dir)? {
        let entry = entry?;
        let name = entry.file_name();
        if is_temp_name(&name.to_string_lossy()) && entry.file_type()?.is_file() {
            fs::remove_file(entry.path())?;
            removed += 1;
        }
    }
    Ok(removed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_and_replaces_leaving_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        write_atomic_io(&p, |w| w.write_all(b"one")).unwrap();
        write_atomic_io(&p, |w| w.write_all(b"two")).unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"two");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn failed_write_keeps_old_content_and_removes_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        write_atomic_io(&p, |w| w.write_all(b"old")).unwrap();
        let e = write_atomic_io(&p, |_| Err(io::Error::other("boom"))).unwrap_err();
        assert_eq!(e.0, "write");
        assert_eq!(fs::read(&p).unwrap(), b"old");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    /// Defect 7: the old `<name>.tmp-<pid>` was opened with a plain create, following a planted
    /// symlink. Plant symlinks at every name the old scheme could use and at the target's temp
    /// pattern: the victim file must stay untouched.
    #[cfg(unix)]
    #[test]
    fn planted_symlink_is_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let victim = dir.path().join("victim");
        fs::write(&victim, b"precious").unwrap();
        let p = dir.path().join("out.json");
        std::os::unix::fs::symlink(&victim, dir.path().join(format!("out.json.tmp-{}", std::process::id()))).unwrap();
        write_atomic_io(&p, |w| w.write_all(b"new")).unwrap();
        assert_eq!(fs::read(&victim).unwrap(), b"precious");
        assert_eq!(fs::read(&p).unwrap(), b"new");
    }

    #[test]
    fn stale_temporaries_are_removed_and_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        fs::write(dir.path().join(".fluence.raw.Ab12Cd.lpm-tmp"), b"x").unwrap();
        fs::write(dir.path().join("source.raw.tmp-4242"), b"x").unwrap();
        fs::write(dir.path().join("fluence.raw"), b"keep").unwrap();
        fs::write(dir.path().join(".hidden"), b"keep").unwrap();
        assert_eq!(remove_stale_temps(dir.path()).unwrap(), 2);
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 2);
    }
}
