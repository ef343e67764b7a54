//! Stopping a solve on request, at a slice boundary, with its checkpoint kept.
//!
//! A [`CancelFlag`] is raised from outside the solve (the `lpm` binary raises
//! [`CancelFlag::process`] on SIGTERM or SIGINT; `lpm serve` cancels a running job by sending its
//! solve SIGTERM) and looked at in every phase, often enough that a solve stops within a second:
//! while the volume is read (every read of a VDB, NanoVDB or NRRD file goes through [`Stoppable`],
//! and the NRRD decoder looks between chunks of samples), by the store's build before each brick
//! ([`super::build_store_until`]), by the GPU streamer before each slice it streams, by the CPU
//! twin before each direction's sweep (it keeps no checkpoint: nothing is kept to resume from), by
//! the export at every write ([`Stoppable`] again) and by the renderer before each row of the
//! image (it looks at [`CancelFlag::process`], the flag the binary's signals raise). A raised flag
//! makes the solve return
//! [`super::SolveError::Cancelled`] there: the order in progress is abandoned, and what the last
//! completed order's checkpoint names is untouched (nothing a checkpoint names is written before
//! the next checkpoint, see [`super::fields`]), so `--resume` continues from it to bitwise the
//! result of an uninterrupted solve — exactly as after a kill at the same moment, only without
//! waiting for a kill.
//!
//! Why a `&'static AtomicBool`: a signal handler can only reach statics, and a `'static` reference
//! keeps [`super::gpu::GpuOptions`] `Copy`. Flags made with [`CancelFlag::new`] are leaked (one
//! byte each): make one per solve, not one per slice.

use std::io::{Read, Seek, SeekFrom, Write};
use std::sync::atomic::{AtomicBool, Ordering};

/// The process's own flag: what the `lpm` binary raises on SIGTERM or SIGINT.
static PROCESS: AtomicBool = AtomicBool::new(false);

/// A request to stop the solve at the next slice (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct CancelFlag(&'static AtomicBool);

impl CancelFlag {
    /// A fresh flag, not raised.
    pub fn new() -> CancelFlag {
        CancelFlag(Box::leak(Box::new(AtomicBool::new(false))))
    }

    /// A flag over a static (for a signal handler to raise).
    pub const fn from_static(flag: &'static AtomicBool) -> CancelFlag {
        CancelFlag(flag)
    }

    /// The process's flag, raised by the `lpm` binary's SIGTERM and SIGINT handler (which can reach
    /// only statics). The renderer looks at this one: an image has no job to be handed a flag by.
    pub fn process() -> CancelFlag {
        CancelFlag(&PROCESS)
    }

    /// Asks the solve to stop at its next slice.
    pub fn raise(&self) {
        self.0.store(true, Ordering::SeqCst);
    }

    /// Raises the flag and says whether it was raised already (one atomic swap: safe in a signal
    /// handler, where the second signal ends the process).
    pub fn raise_again(&self) -> bool {
        self.0.swap(true, Ordering::SeqCst)
    }

    pub fn is_raised(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }
}

impl Default for CancelFlag {
    fn default() -> Self {
        CancelFlag::new()
    }
}

/// Whether an optional flag is raised.
pub fn raised(flag: Option<CancelFlag>) -> bool {
    flag.is_some_and(|f| f.is_raised())
}

/// A reader or writer that fails with a [`Stopped`] error at its next read or write once `cancel`
/// is raised: how a phase that reads or writes a file as it goes (a VDB tree, a NRRD's samples,
/// the exported fields) looks at the flag at every buffer without a check in each of its loops.
/// The caller tells a stop from a failure by the flag ([`raised`]) or by [`is_stopped`].
pub struct Stoppable<T> {
    pub inner: T,
    pub cancel: Option<CancelFlag>,
}

/// The error of a [`Stoppable`] read or write after the flag was raised.
#[derive(Debug)]
pub struct Stopped;

impl std::fmt::Display for Stopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("cancelled")
    }
}

impl std::error::Error for Stopped {}

/// Whether `e` is a [`Stoppable`]'s stop.
pub fn is_stopped(e: &std::io::Error) -> bool {
    e.get_ref().is_some_and(|inner| inner.is::<Stopped>())
}

impl<T> Stoppable<T> {
    fn go_on(&self) -> std::io::Result<()> {
        if raised(self.cancel) {
            Err(std::io::Error::other(Stopped))
        } else {
            Ok(())
        }
    }
}

impl<T: Read> Read for Stoppable<T> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.go_on()?;
        self.inner.read(buf)
    }
}

impl<T: Write> Write for Stoppable<T> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.go_on()?;
        self.inner.write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

impl<T: Seek> Seek for Stoppable<T> {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.inner.seek(pos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flag_is_raised_once_and_seen_by_its_copies() {
        let flag = CancelFlag::new();
        let copy = flag;
        assert!(!copy.is_raised());
        flag.raise();
        assert!(copy.is_raised());
        assert!(!CancelFlag::new().is_raised());
    }

    #[test]
    fn a_stoppable_reader_and_writer_stop_once_the_flag_is_raised() {
        let flag = CancelFlag::new();
        let mut r = Stoppable { inner: std::io::Cursor::new(vec![1u8; 8]), cancel: Some(flag) };
        let mut w = Stoppable { inner: Vec::new(), cancel: Some(flag) };
        let mut buf = [0u8; 4];
        r.read_exact(&mut buf).unwrap();
        w.write_all(&buf).unwrap();
        flag.raise();
        assert!(is_stopped(&r.read_exact(&mut buf).unwrap_err()));
        assert!(is_stopped(&w.write_all(&buf).unwrap_err()));
        assert_eq!(w.inner.len(), 4);
        let mut free = Stoppable { inner: std::io::Cursor::new(vec![1u8; 8]), cancel: None };
        free.read_exact(&mut buf).unwrap();
    }
}
