//! [`SceneError`]: every way a scene file can be rejected. Each variant carries the scene file's
//! path, and every variant that concerns one value also carries its dotted key
//! (`medium.albedo[1]`, `lights[2].direction`), so the message can be acted upon without a debugger:
//!
//! ```text
//! scene.toml: medium.albedo[1]: must be in [0, 1], got 1.5
//! scene.toml: line 3, column 1: volume.dimz: unknown field `dimz`, expected one of `procedural`, ...
//! cannot read scene file missing.toml: No such file or directory
//! ```

use std::io;
use std::path::{Path, PathBuf};

/// Why a scene file was rejected.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SceneError {
    /// The scene file itself could not be read (missing, unreadable, not UTF-8).
    #[error("cannot read scene file {}: {}", .path.display(), io_reason(.source))]
    Read {
        path: PathBuf,
        #[source]
        source: io::Error,
    },

    /// The scene path is not something lpm reads as a scene: not a regular file (a FIFO, a device,
    /// a directory), larger than the limit, or not UTF-8.
    #[error("cannot read scene file {}: {problem}", .path.display())]
    BadFile { path: PathBuf, problem: String },

    /// The TOML could not be parsed, or a value has the wrong type, or a key is unknown or missing.
    /// `line`/`column` (1-based) and `key` are given whenever the TOML parser reports a position.
    #[error("{}: {}", .path.display(), parse_display(*.line, *.column, .key.as_deref(), .message))]
    Parse {
        path: PathBuf,
        line: Option<usize>,
        column: Option<usize>,
        /// Dotted key the error is about, recovered from the reported position.
        key: Option<String>,
        message: String,
    },

    /// A value parsed but is out of range or inconsistent with another value.
    #[error("{}: {key}: {problem}", .path.display())]
    Invalid { path: PathBuf, key: String, problem: String },

    /// The raw density file named by `volume.raw` cannot be read (usually: it does not exist).
    #[error("{}: {key}: cannot read raw density file {}: {}", .path.display(), .raw_path.display(), io_reason(.source))]
    RawFile {
        path: PathBuf,
        key: String,
        /// The resolved (absolute) path of the raw file.
        raw_path: PathBuf,
        #[source]
        source: io::Error,
    },

    /// The raw density file does not hold exactly dims product × 4 bytes.
    #[error(
        "{}: {key}: raw density file {} has {actual} bytes, expected {expected} ({} × {} × {} voxels × 4 bytes)",
        .path.display(), .raw_path.display(), .dims[0], .dims[1], .dims[2]
    )]
    RawSize { path: PathBuf, key: String, raw_path: PathBuf, dims: [u32; 3], expected: u64, actual: u64 },

    /// The environment map named by `lights[i].map` is missing, not an OpenEXR file, not a 2:1
    /// lat-long image, or holds a NaN, infinite or negative pixel.
    #[error("{}: {key}: environment map {}: {problem}", .path.display(), .map_path.display())]
    Map { path: PathBuf, key: String, map_path: PathBuf, problem: String },
}

impl SceneError {
    /// The scene file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            SceneError::Read { path, .. }
            | SceneError::BadFile { path, .. }
            | SceneError::Parse { path, .. }
            | SceneError::Invalid { path, .. }
            | SceneError::RawFile { path, .. }
            | SceneError::RawSize { path, .. }
            | SceneError::Map { path, .. } => path,
        }
    }

    /// The dotted key the error is about, when known.
    pub fn key(&self) -> Option<&str> {
        match self {
            SceneError::Read { .. } | SceneError::BadFile { .. } => None,
            SceneError::Parse { key, .. } => key.as_deref(),
            SceneError::Invalid { key, .. }
            | SceneError::RawFile { key, .. }
            | SceneError::RawSize { key, .. }
            | SceneError::Map { key, .. } => Some(key),
        }
    }
}

/// `io::Error`'s message without the trailing ` (os error N)`.
fn io_reason(e: &io::Error) -> String {
    let s = e.to_string();
    match s.rfind(" (os error ") {
        Some(i) if s.ends_with(')') => s[..i].to_string(),
        _ => s,
    }
}

fn parse_display(line: Option<usize>, column: Option<usize>, key: Option<&str>, message: &str) -> String {
    let mut out = String::new();
    match (line, column) {
        (Some(l), Some(c)) => out.push_str(&format!("line {l}, column {c}: ")),
        (Some(l), None) => out.push_str(&format!("line {l}: ")),
        _ => {}
    }
    if let Some(k) = key {
        out.push_str(k);
        out.push_str(": ");
    }
    out.push_str(message);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn io_reason_strips_os_error() {
        let e = io::Error::from_raw_os_error(2);
        assert_eq!(io_reason(&e), "No such file or directory");
        let e = io::Error::other("plain");
        assert_eq!(io_reason(&e), "plain");
    }

    #[test]
    fn invalid_display() {
        let e = SceneError::Invalid {
            path: "scene.toml".into(),
            key: "medium.albedo[1]".into(),
            problem: "must be in [0, 1], got 1.5".into(),
        };
        assert_eq!(e.to_string(), "scene.toml: medium.albedo[1]: must be in [0, 1], got 1.5");
        assert_eq!(e.key(), Some("medium.albedo[1]"));
    }

    #[test]
    fn parse_display_parts() {
        let e = SceneError::Parse {
            path: "s.toml".into(),
            line: Some(3),
            column: Some(1),
            key: Some("volume.dimz".into()),
            message: "unknown field `dimz`".into(),
        };
        assert_eq!(e.to_string(), "s.toml: line 3, column 1: volume.dimz: unknown field `dimz`");
    }
}
