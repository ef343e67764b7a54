//! Opening the files a user names — volumes, a NRRD header's data file, an environment map, a
//! scene, a camera, a token, a manifest, the outputs `lpm compare` reads — the one way every input
//! is opened.
//!
//! Three guarantees, each of which a plain `File::open` breaks:
//!
//! - **Only regular files.** Opening a FIFO for reading blocks until a writer comes (forever, and
//!   SIGTERM cannot interrupt `open()`), and a device such as `/dev/zero` never ends. The path is
//!   looked at before it is opened (links followed), opened non-blocking so that a FIFO swapped in
//!   between cannot block either, and the open file is looked at again; anything but a regular
//!   file is refused with [`InputError::NotRegular`].
//! - **Small inputs are small.** [`read_capped`] reads at most a limit and says so when the file
//!   holds more, instead of reading until memory runs out.
//! - **Confinement at the moment of reading.** A solve started by `lpm serve` is confined to the
//!   server's data root ([`confine_to`], once per process): every input is checked where it really
//!   is — the open file's own path, every symbolic link resolved, taken from the open descriptor so
//!   that nothing can be swapped between the check and the read — and refused outside the root.
//!   Checking the paths when a job is submitted is not enough: a NRRD header can be replaced after
//!   it was checked, and name a data file anywhere.

use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Why an input file was not opened or read. Shown as "path: what is wrong"; callers that name
/// the file themselves use [`InputError::words`].
#[derive(Debug)]
pub enum InputError {
    Io {
        path: PathBuf,
        action: &'static str,
        source: std::io::Error,
    },
    NotRegular {
        path: PathBuf,
        kind: &'static str,
    },
    /// `size` is the file's size where it was known before reading.
    TooLarge {
        path: PathBuf,
        what: &'static str,
        size: Option<u64>,
        limit: u64,
    },
    Outside {
        path: PathBuf,
        root: PathBuf,
    },
}

impl InputError {
    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            InputError::Io { path, .. }
            | InputError::NotRegular { path, .. }
            | InputError::TooLarge { path, .. }
            | InputError::Outside { path, .. } => path,
        }
    }

    /// What is wrong, without the file's name.
    pub fn words(&self) -> String {
        match self {
            InputError::Io { action, source, .. } => format!("cannot {action}: {source}"),
            InputError::NotRegular { kind, .. } => {
                format!("is {kind}, not a regular file; lpm reads its inputs from regular files only")
            }
            InputError::TooLarge { what, size, limit, .. } => format!(
                "{}more than the limit of {limit} bytes for {what}",
                size.map_or(String::new(), |s| format!("{s} bytes, "))
            ),
            InputError::Outside { root, .. } => {
                format!("outside the data root this solve is confined to ({})", root.display())
            }
        }
    }
}

impl std::fmt::Display for InputError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path().display(), self.words())
    }
}

impl std::error::Error for InputError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            InputError::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}

/// The most a small text input is read to (a camera file, a sweep manifest, a JSON description of
/// an exported field): far above any real one.
pub const MAX_TEXT_BYTES: u64 = 1 << 20;
/// The most a token file is read to.
pub const MAX_TOKEN_BYTES: u64 = 4096;

/// The canonical directory every input of this process must lie under, when confined.
static ROOT: OnceLock<PathBuf> = OnceLock::new();

/// Confines every later [`open`] of this process to `root` (canonicalized here). Called once, by a
/// solve the server starts (`lpm solve --confine-to DATA`); a second call with another root fails.
pub fn confine_to(root: &Path) -> Result<(), InputError> {
    let real = root.canonicalize().map_err(|source| InputError::Io {
        path: root.to_path_buf(),
        action: "resolve the data root",
        source,
    })?;
    let set = ROOT.get_or_init(|| real.clone());
    if *set == real {
        Ok(())
    } else {
        Err(InputError::Outside { path: real, root: set.clone() })
    }
}

/// Opens `path` for reading: a regular file (after following links), within the confinement root
/// when there is one. Never blocks in `open()`.
pub fn open(path: &Path) -> Result<File, InputError> {
    use std::os::unix::fs::OpenOptionsExt;
    let io = |action: &'static str| move |source| InputError::Io { path: path.to_path_buf(), action, source };
    // Refused before opening: opening a device can have effects of its own.
    let meta = std::fs::metadata(path).map_err(io("open"))?;
    regular(path, &meta)?;
    // O_NONBLOCK: a FIFO put in the file's place since the check opens at once instead of blocking
    // (and is then refused below); for a regular file the flag changes nothing.
    let file = std::fs::OpenOptions::new().read(true).custom_flags(libc::O_NONBLOCK).open(path).map_err(io("open"))?;
    regular(path, &file.metadata().map_err(io("look at"))?)?;
    if let Some(root) = ROOT.get() {
        let real = real_path(&file, path).map_err(io("resolve the real path of"))?;
        if !real.starts_with(root) {
            return Err(InputError::Outside { path: path.to_path_buf(), root: root.clone() });
        }
    }
    Ok(file)
}

/// Reads all of `path` ([`open`]'s checks), refusing a file of more than `limit` bytes. `what`
/// names the input in the message ("a camera file").
pub fn read_capped(path: &Path, limit: u64, what: &'static str) -> Result<Vec<u8>, InputError> {
    let file = open(path)?;
    let size = file.metadata().map(|m| m.len()).ok();
    let too_large = |size| InputError::TooLarge { path: path.to_path_buf(), what, size, limit };
    if size.is_some_and(|s| s > limit) {
        return Err(too_large(size));
    }
    let mut bytes = Vec::new();
    // `take`: the file may have grown since it was looked at.
    file.take(limit + 1).read_to_end(&mut bytes).map_err(|source| InputError::Io {
        path: path.to_path_buf(),
        action: "read",
        source,
    })?;
    if bytes.len() as u64 > limit {
        return Err(too_large(None));
    }
    Ok(bytes)
}

/// [`read_capped`] as UTF-8 text.
pub fn read_text_capped(path: &Path, limit: u64, what: &'static str) -> Result<String, InputError> {
    String::from_utf8(read_capped(path, limit, what)?).map_err(|_| InputError::Io {
        path: path.to_path_buf(),
        action: "read",
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, "not UTF-8 text"),
    })
}

fn regular(path: &Path, meta: &std::fs::Metadata) -> Result<(), InputError> {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_file() {
        return Ok(());
    }
    let kind = if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "not a file"
    };
    Err(InputError::NotRegular { path: path.to_path_buf(), kind })
}

/// Where the open `file` really is: its descriptor's link in /proc (no race with a rename or a
/// swapped symlink), or the canonical `path` where /proc is not mounted.
fn real_path(file: &File, path: &Path) -> std::io::Result<PathBuf> {
    use std::os::fd::AsRawFd;
    match std::fs::read_link(format!("/proc/self/fd/{}", file.as_raw_fd())) {
        Ok(p) => Ok(p),
        Err(_) => path.canonicalize(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_fifos_devices_and_directories_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: mkfifo on a NUL-terminated path in a fresh temporary directory.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let link = dir.path().join("link");
        std::os::unix::fs::symlink(&fifo, &link).unwrap();
        for (p, kind) in [
            (fifo.as_path(), "FIFO"),
            (link.as_path(), "FIFO"),
            (Path::new("/dev/zero"), "character device"),
            (dir.path(), "directory"),
        ] {
            let e = open(p).unwrap_err();
            assert!(matches!(e, InputError::NotRegular { .. }), "{e}");
            assert!(e.to_string().contains(kind), "{e}");
        }
    }

    #[test]
    fn caps_what_it_reads() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("camera.toml");
        std::fs::write(&p, vec![b'x'; 100]).unwrap();
        assert_eq!(read_capped(&p, 100, "a camera file").unwrap().len(), 100);
        let e = read_capped(&p, 99, "a camera file").unwrap_err();
        assert!(matches!(e, InputError::TooLarge { size: Some(100), limit: 99, .. }), "{e}");
        assert!(e.to_string().contains("100 bytes, more than the limit of 99 bytes for a camera file"), "{e}");
    }
}
