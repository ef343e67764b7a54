//! [`DirLock`]: an advisory lock on an output directory, so two runs never write into one `--out`.
//!
//! The lock is `flock(LOCK_EX | LOCK_NB)` on `OUT/.lpm-lock`, held for the whole run and released by
//! the kernel when the process ends however it ends (so a `kill -9` never leaves a stale lock; the
//! empty file it leaves is harmless). A run that ends normally removes the file while still holding
//! the lock; so that a process which opened the file just before its removal cannot then lock the
//! removed file and think it holds the lock, [`DirLock::acquire`] checks after locking that the path
//! still names the file it locked, and tries again if not. `flock` through libc rather than `File::try_lock` because
//! the crate's minimum Rust (1.80) predates that API.

use super::OutputError;
use std::fs::{File, OpenOptions};
use std::path::{Path, PathBuf};

/// The lock file's name inside the locked directory.
pub const LOCK_FILE: &str = ".lpm-lock";

/// Holds the lock on a directory until dropped.
#[derive(Debug)]
pub struct DirLock {
    path: PathBuf,
    file: Option<File>,
}

impl Drop for DirLock {
    /// Removes the lock file while still holding the lock, then releases it (see the module docs).
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
        self.file.take();
    }
}

impl DirLock {
    /// Locks `dir` (which must exist), or fails at once with [`OutputError::Locked`] when another
    /// process holds it.
    pub fn acquire(dir: &Path) -> Result<DirLock, OutputError> {
        let path = dir.join(LOCK_FILE);
        let mut options = OpenOptions::new();
        options.read(true).write(true).create(true).truncate(false);
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt;
            // A symlink planted at the lock's name is not followed.
            options.custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC);
        }
        for _ in 0..16 {
            let file = options.open(&path).map_err(|source| OutputError::Io {
                path: path.clone(),
                action: "open the lock file",
                source,
            })?;
            #[cfg(unix)]
            {
                use std::os::unix::fs::MetadataExt;
                use std::os::unix::io::AsRawFd;
                // SAFETY: flock on a file descriptor this function owns; no memory is passed.
                if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
                    let source = std::io::Error::last_os_error();
                    return Err(if source.raw_os_error() == Some(libc::EWOULDBLOCK) {
                        OutputError::Locked { dir: dir.to_path_buf() }
                    } else {
                        OutputError::Io { path, action: "lock", source }
                    });
                }
                let same = match (file.metadata(), std::fs::symlink_metadata(&path)) {
                    (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
                    _ => false,
                };
                if !same {
                    // The holder removed it between our open and our lock: open the new one.
                    continue;
                }
            }
            return Ok(DirLock { path, file: Some(file) });
        }
        Err(OutputError::Locked { dir: dir.to_path_buf() })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn second_lock_fails_until_the_first_is_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let first = DirLock::acquire(dir.path()).unwrap();
        // flock locks belong to the open file description: a second open in the same process
        // conflicts exactly as another process would.
        let e = DirLock::acquire(dir.path()).unwrap_err();
        assert!(matches!(e, OutputError::Locked { .. }), "{e}");
        assert!(e.to_string().contains("another lpm run"), "{e}");
        drop(first);
        assert!(!dir.path().join(LOCK_FILE).exists(), "the lock file is removed with the lock");
        DirLock::acquire(dir.path()).unwrap();
    }
}
