//! Stopping a solve on request, at a slice boundary, with its checkpoint kept.
//!
//! A [`CancelFlag`] is raised from outside the solve (the `lpm` binary raises it on SIGTERM or
//! SIGINT; `lpm serve` cancels a running job by sending its solve SIGTERM) and looked at by the GPU
//! streamer before each slice it streams, by the store's build before each brick
//! ([`super::build_store_until`]) and by the CPU twin before each direction's sweep (it keeps no
//! checkpoint: nothing is kept to resume from). A raised flag makes the solve return
//! [`super::SolveError::Cancelled`] there: the order in progress is abandoned, and what the last
//! completed order's checkpoint names is untouched (nothing a checkpoint names is written before
//! the next checkpoint, see [`super::fields`]), so `--resume` continues from it to bitwise the
//! result of an uninterrupted solve — exactly as after a kill at the same moment, only without
//! waiting for a kill.
//!
//! Why a `&'static AtomicBool`: a signal handler can only reach statics, and a `'static` reference
//! keeps [`super::gpu::GpuOptions`] `Copy`. Flags made with [`CancelFlag::new`] are leaked (one
//! byte each): make one per solve, not one per slice.

use std::sync::atomic::{AtomicBool, Ordering};

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

    /// Asks the solve to stop at its next slice.
    pub fn raise(&self) {
        self.0.store(true, Ordering::SeqCst);
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
}
