//! [`confine`]: keeps a user-given path inside a root directory. The local CLI lets a scene name any
//! file it can read; a service that takes paths from others must not (`/etc/…`, `../..`, a symlink
//! planted to point out of its data directory). Reusable by any caller that must stay in a root.

use std::path::{Component, Path, PathBuf};

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ConfineError {
    #[error("{}: `..` is not allowed in a confined path", .path.display())]
    ParentComponent { path: PathBuf },
    #[error("{}: is outside {}", .path.display(), .root.display())]
    Outside { path: PathBuf, root: PathBuf },
    #[error("{}: cannot resolve the root directory: {reason}", .root.display())]
    Root { root: PathBuf, reason: String },
    #[error("{}: cannot resolve: {reason}", .path.display())]
    Resolve { path: PathBuf, reason: String },
    #[error("{}: an empty path names nothing", .root.display())]
    Empty { root: PathBuf },
}

/// Resolves `path` (relative to `root`, or absolute) and returns it as an absolute path that lies
/// inside `root` after every symlink is followed. The path need not exist: the part that exists is
/// resolved (symlinks included), the rest must be plain names. Rejects `..` anywhere (even when it
/// would stay inside: a confined name has no reason to climb) and anything resolving outside.
/// Checks the path as it is now: a caller that then opens it should do so before anyone else can
/// replace a component (the service owns its root, so nobody else can).
pub fn confine(root: &Path, path: &Path) -> Result<PathBuf, ConfineError> {
    let root_c =
        root.canonicalize().map_err(|e| ConfineError::Root { root: root.to_path_buf(), reason: e.to_string() })?;
    if path.as_os_str().is_empty() {
        return Err(ConfineError::Empty { root: root.to_path_buf() });
    }
    if path.components().any(|c| c == Component::ParentDir) {
        return Err(ConfineError::ParentComponent { path: path.to_path_buf() });
    }
    let joined = root.join(path);
    // The longest prefix that exists, resolved; the rest appended as plain names.
    let mut existing = joined.clone();
    let mut rest = Vec::new();
    while existing.symlink_metadata().is_err() {
        match (existing.file_name(), existing.parent()) {
            (Some(name), Some(parent)) => {
                rest.push(name.to_os_string());
                existing = parent.to_path_buf();
            }
            _ => break,
        }
    }
    let mut resolved = existing
        .canonicalize()
        .map_err(|e| ConfineError::Resolve { path: path.to_path_buf(), reason: e.to_string() })?;
    for name in rest.into_iter().rev() {
        resolved.push(name);
    }
    if !resolved.starts_with(&root_c) {
        return Err(ConfineError::Outside { path: path.to_path_buf(), root: root.to_path_buf() });
    }
    Ok(resolved)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_names_inside_are_accepted_existing_or_not() {
        let root = tempfile::tempdir().unwrap();
        std::fs::create_dir(root.path().join("a")).unwrap();
        std::fs::write(root.path().join("a/x.raw"), b"").unwrap();
        let r = root.path().canonicalize().unwrap();
        assert_eq!(confine(root.path(), Path::new("a/x.raw")).unwrap(), r.join("a/x.raw"));
        assert_eq!(confine(root.path(), Path::new("a/new/y.raw")).unwrap(), r.join("a/new/y.raw"));
        assert_eq!(confine(root.path(), &r.join("a/x.raw")).unwrap(), r.join("a/x.raw"));
    }

    #[test]
    fn parent_components_absolute_paths_outside_and_empty_are_refused() {
        let root = tempfile::tempdir().unwrap();
        let e = confine(root.path(), Path::new("../etc/passwd")).unwrap_err();
        assert!(matches!(e, ConfineError::ParentComponent { .. }), "{e}");
        assert!(matches!(confine(root.path(), Path::new("a/../b")), Err(ConfineError::ParentComponent { .. })));
        assert!(matches!(confine(root.path(), Path::new("/etc/passwd")), Err(ConfineError::Outside { .. })));
        assert!(matches!(confine(root.path(), Path::new("")), Err(ConfineError::Empty { .. })));
    }

    #[cfg(unix)]
    #[test]
    fn symlinks_that_escape_are_refused_and_those_inside_followed() {
        let root = tempfile::tempdir().unwrap();
        let outside = tempfile::tempdir().unwrap();
        std::fs::write(outside.path().join("secret"), b"").unwrap();
        std::os::unix::fs::symlink(outside.path(), root.path().join("link")).unwrap();
        std::os::unix::fs::symlink("/etc/passwd", root.path().join("pw")).unwrap();
        assert!(matches!(confine(root.path(), Path::new("link/secret")), Err(ConfineError::Outside { .. })));
        assert!(matches!(confine(root.path(), Path::new("link/not-yet")), Err(ConfineError::Outside { .. })));
        assert!(matches!(confine(root.path(), Path::new("pw")), Err(ConfineError::Outside { .. })));
        std::fs::create_dir(root.path().join("d")).unwrap();
        std::os::unix::fs::symlink("d", root.path().join("inner")).unwrap();
        let r = root.path().canonicalize().unwrap();
        assert_eq!(confine(root.path(), Path::new("inner/f")).unwrap(), r.join("d/f"));
    }

    #[test]
    fn a_missing_root_is_an_error() {
        let e = confine(Path::new("/nonexistent-lpm-root"), Path::new("a")).unwrap_err();
        assert!(matches!(e, ConfineError::Root { .. }), "{e}");
    }
}
