//! Free disk space: checked before large work starts, so a full disk is a clear error up front
//! rather than a failure (or, for a memory-mapped file, a signal) half-way through.

use super::OutputError;
use std::path::Path;

pub use crate::store::free_bytes;

/// Fails with [`OutputError::NoSpace`] when `dir`'s filesystem has fewer than `needed` bytes free.
/// `what` says what the bytes are for, in the message.
pub fn ensure_free(dir: &Path, needed: u64, what: &str) -> Result<(), OutputError> {
    match free_bytes(dir) {
        Some(free) if free < needed => {
            Err(OutputError::NoSpace { path: dir.to_path_buf(), needed, free, what: what.to_string() })
        }
        _ => Ok(()),
    }
}

/// `n` bytes in words: "123 bytes" or "4.0 TiB (4398046511104 bytes)".
pub fn human_bytes(n: u64) -> String {
    const UNITS: [&str; 5] = ["KiB", "MiB", "GiB", "TiB", "PiB"];
    if n < 1024 {
        return format!("{n} bytes");
    }
    let mut v = n as f64 / 1024.0;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    format!("{v:.1} {} ({n} bytes)", UNITS[u])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn free_space_is_reported_and_checked() {
        let dir = tempfile::tempdir().unwrap();
        let free = free_bytes(dir.path()).expect("statvfs works on a temp dir");
        assert!(free > 0);
        ensure_free(dir.path(), 1, "a byte").unwrap();
        let e = ensure_free(dir.path(), u64::MAX, "everything").unwrap_err();
        let text = e.to_string();
        assert!(text.contains(&u64::MAX.to_string()) && text.contains("free"), "{text}");
    }

    #[test]
    fn human_sizes() {
        assert_eq!(human_bytes(12), "12 bytes");
        assert_eq!(human_bytes(4 << 40), "4.0 TiB (4398046511104 bytes)");
    }
}
