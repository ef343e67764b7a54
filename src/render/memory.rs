//! Whether an image fits the memory this process can still allocate, checked before a solve or a
//! render starts (issue 57: `lpm render` at 16384² under a 4 GB address-space limit aborted with
//! "memory allocation of 1073741824 bytes failed" and a backtrace, after the solve).
//!
//! An image of w × h pixels holds its linear RGB and alpha in f32 (16 bytes a pixel) while it is
//! rendered, and the writers add the PNG's 8-bit pixels, its encoder's buffers and the EXR's
//! channels: [`BYTES_PER_PIXEL`] bounds the whole. What the process can still allocate is the
//! smaller of the memory the kernel says is available (`MemAvailable` + free swap) and, under an
//! address-space limit (`ulimit -v`), that limit less the address space already mapped. Where
//! neither can be read (not Linux), nothing is refused here.

/// The most bytes a pixel costs from the render to the written files.
pub const BYTES_PER_PIXEL: u64 = 48;

/// An image larger than the memory left for it.
#[derive(Debug, thiserror::Error)]
#[error(
    "a {width} × {height} image needs about {} MB to render and write, more than the {} MB this process can still \
     allocate ({limit}): make camera.width and camera.height (or lpm render's --width/--height) smaller",
    needed >> 20,
    available >> 20
)]
pub struct ImageTooLarge {
    pub width: u32,
    pub height: u32,
    /// Bytes the image needs ([`BYTES_PER_PIXEL`] each).
    pub needed: u64,
    /// Bytes this process can still allocate.
    pub available: u64,
    /// What set `available`: the available memory or the address-space limit.
    pub limit: &'static str,
}

/// The bytes an image of `width` × `height` needs, from the render to its files.
pub fn image_bytes(width: u32, height: u32) -> u64 {
    u64::from(width) * u64::from(height) * BYTES_PER_PIXEL
}

/// Refuses an image of `width` × `height` that cannot fit what this process can still allocate.
pub fn check_image_fits(width: u32, height: u32) -> Result<(), ImageTooLarge> {
    let needed = image_bytes(width, height);
    match allocatable() {
        Some((available, limit)) if needed > available => {
            Err(ImageTooLarge { width, height, needed, available, limit })
        }
        _ => Ok(()),
    }
}

/// The bytes this process can still allocate and what limits them, where known.
fn allocatable() -> Option<(u64, &'static str)> {
    let memory = available_memory().map(|b| (b, "the memory available"));
    let address = address_space_left().map(|b| (b, "its address-space limit, ulimit -v"));
    match (memory, address) {
        (Some(m), Some(a)) => Some(if a.0 < m.0 { a } else { m }),
        (m, a) => m.or(a),
    }
}

/// `MemAvailable` + `SwapFree` from /proc/meminfo, in bytes.
fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let field = |name: &str| -> Option<u64> {
        let line = text.lines().find(|l| l.starts_with(name))?;
        line.split_whitespace().nth(1)?.parse::<u64>().ok().map(|kb| kb * 1024)
    };
    Some(field("MemAvailable:")? + field("SwapFree:").unwrap_or(0))
}

/// The address-space limit less what is mapped, where a limit is set.
fn address_space_left() -> Option<u64> {
    let mut limit = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: getrlimit writes the one struct it is given.
    if unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut limit) } != 0 || limit.rlim_cur == libc::RLIM_INFINITY {
        return None;
    }
    // /proc/self/statm: the first field is the mapped size in pages.
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().next()?.parse().ok()?;
    // SAFETY: sysconf has no preconditions.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) }.max(4096) as u64;
    Some(limit.rlim_cur.saturating_sub(pages * page))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_images_fit_and_absurd_ones_are_refused_naming_the_sizes() {
        assert!(check_image_fits(64, 64).is_ok());
        // 10⁶ × 10⁶ pixels: 48 TB, more than any machine this runs on.
        let e = check_image_fits(1_000_000, 1_000_000).unwrap_err();
        assert_eq!(e.needed, image_bytes(1_000_000, 1_000_000));
        assert!(e.to_string().contains("1000000 × 1000000") && e.to_string().contains("camera.width"), "{e}");
    }
}
