//! Confining client-named paths to the server's data root.
//!
//! A scene sent to `lpm serve` may name its density volume by a path (`volume.raw`), and uploads are
//! named by the client. Such a path must not reach outside the data root: not by `..`, not by an
//! absolute path elsewhere, and not through a symbolic link inside the root that points outside.
//! The check is lexical first (no `..` at all, so the answer never depends on what exists where) and
//! then on the canonical path (every symlink resolved), which must lie under the canonical root.
//!
//! This is the check at submission, which lets the client know at once. It is not the guarantee:
//! a file can change between submission and solve (a NRRD header replaced by one naming a data
//! file elsewhere), so the solve a worker starts is itself confined to the root
//! (`lpm solve --confine-to`, [`crate::input`]) and checks every file it opens.

use std::path::{Component, Path, PathBuf};

/// Why a path was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfineError {
    #[error("{path}: `..` is not allowed in a path sent to the server")]
    ParentDir { path: String },
    #[error("{path}: outside the server's data root")]
    Outside { path: String },
    #[error("{path}: {reason}")]
    Unresolvable { path: String, reason: String },
}

/// The canonical form of `path` (relative paths are taken relative to `root`), provided it lies
/// under `root` once every symbolic link is resolved. The file must exist.
pub fn confine(root: &Path, path: &Path) -> Result<PathBuf, ConfineError> {
    let shown = path.display().to_string();
    if path.components().any(|c| matches!(c, Component::ParentDir)) {
        return Err(ConfineError::ParentDir { path: shown });
    }
    let root = root.canonicalize().map_err(|e| ConfineError::Unresolvable {
        path: root.display().to_string(),
        reason: format!("cannot resolve the data root: {e}"),
    })?;
    let joined = if path.is_absolute() { path.to_path_buf() } else { root.join(path) };
    let real = joined.canonicalize().map_err(|e| {
        // Do not tell a client whether a file outside the root exists.
        if joined.starts_with(&root) {
            ConfineError::Unresolvable { path: shown.clone(), reason: e.to_string() }
        } else {
            ConfineError::Outside { path: shown.clone() }
        }
    })?;
    if real.starts_with(&root) {
        Ok(real)
    } else {
        Err(ConfineError::Outside { path: shown })
    }
}

/// A single plain file name chosen by a client (an upload's name): letters, digits, `.`, `_`, `-`,
/// not starting with `.`, at most 128 bytes.
pub fn plain_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 128
        && !name.starts_with('.')
        && name.bytes().all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn root() -> PathBuf {
        let dir = std::env::temp_dir().join(format!("lpm-confine-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("root/sub")).unwrap();
        std::fs::write(dir.join("root/sub/a.raw"), b"x").unwrap();
        std::fs::write(dir.join("outside.raw"), b"x").unwrap();
        std::os::unix::fs::symlink(dir.join("outside.raw"), dir.join("root/escape.raw")).unwrap();
        std::os::unix::fs::symlink(dir.join("root/sub/a.raw"), dir.join("root/inside.raw")).unwrap();
        dir
    }

    #[test]
    fn inside_outside_and_symlinks() {
        let dir = root();
        let r = dir.join("root");
        let real = r.canonicalize().unwrap();
        assert_eq!(confine(&r, Path::new("sub/a.raw")).unwrap(), real.join("sub/a.raw"));
        assert_eq!(confine(&r, &r.join("sub/a.raw")).unwrap(), real.join("sub/a.raw"));
        assert_eq!(confine(&r, Path::new("inside.raw")).unwrap(), real.join("sub/a.raw"));
        assert!(matches!(confine(&r, Path::new("sub/../sub/a.raw")), Err(ConfineError::ParentDir { .. })));
        assert!(matches!(confine(&r, Path::new("../outside.raw")), Err(ConfineError::ParentDir { .. })));
        assert!(matches!(confine(&r, &dir.join("outside.raw")), Err(ConfineError::Outside { .. })));
        assert!(matches!(confine(&r, Path::new("escape.raw")), Err(ConfineError::Outside { .. })));
        assert!(matches!(confine(&r, Path::new("/etc/nonexistent")), Err(ConfineError::Outside { .. })));
        assert!(matches!(confine(&r, Path::new("missing.raw")), Err(ConfineError::Unresolvable { .. })));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn plain_names() {
        assert!(plain_name("cloud_01.raw"));
        for bad in ["", ".hidden", "a/b", "..", "a b", "x\0"] {
            assert!(!plain_name(bad), "{bad:?}");
        }
    }
}
