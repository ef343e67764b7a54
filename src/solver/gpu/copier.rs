//! Host copy workers: move bricks between the memory-mapped store and the pinned staging buffers
//! on worker threads, so that the thread submitting GPU work does not stall on memcpy or on the
//! page faults of a memory-mapped file.
//!
//! The submitting thread describes a copy as a list of regions (source, destination, length) and
//! hands it to the pool through a crossbeam channel; it gets back a [`Ticket`] to wait on only when
//! it needs the bytes (before submitting the upload, before handing the store to the next pass).
//!
//! Safety model: a region is a pair of raw pointers into memory that outlives the copy (a mapped
//! staging buffer or a memory-mapped field owned by the backend, neither freed nor remapped while
//! a ticket is outstanding), and the pipeline never has two copies in flight that touch the same
//! bytes: a slice's gather and the previous slice's scatter cover different bricks, and every
//! ticket of a pass is waited for before the next pass starts.

use crossbeam_channel::{bounded, unbounded, Receiver, Sender};
use std::thread::JoinHandle;

/// `runs` copies of `len` contiguous bytes, run i from `src + i·src_stride` to `dst + i·dst_stride`
/// (one run: a plain contiguous copy). Strided runs cut a slab of planes out of a brick.
#[derive(Clone, Copy, Debug)]
pub struct Region {
    pub src: *const u8,
    pub dst: *mut u8,
    pub len: usize,
    pub runs: usize,
    pub src_stride: usize,
    pub dst_stride: usize,
}

impl Region {
    /// Performs the copy.
    ///
    /// # Safety
    /// Every run must be valid to read at the source and to write at the destination, and no run
    /// may overlap another region being copied at the same time (see the module docs).
    unsafe fn perform(&self) {
        for i in 0..self.runs {
            // SAFETY: the caller's contract.
            unsafe {
                std::ptr::copy_nonoverlapping(
                    self.src.wrapping_add(i * self.src_stride),
                    self.dst.wrapping_add(i * self.dst_stride),
                    self.len,
                )
            };
        }
    }
}

// SAFETY: see the module docs: regions point into memory that outlives the copy, and concurrent
// regions never overlap.
unsafe impl Send for Region {}

struct Job {
    regions: Vec<Region>,
    done: Sender<()>,
}

/// Waits for a batch of copies.
#[must_use = "a copy must be waited for before its bytes are used"]
pub struct Ticket {
    parts: usize,
    done: Receiver<()>,
}

impl Ticket {
    /// Blocks until every region of the batch has been copied.
    pub fn wait(self) {
        for _ in 0..self.parts {
            // A worker that died drops its sender; there is nothing left to wait for then.
            if self.done.recv().is_err() {
                break;
            }
        }
    }
}

pub struct Copier {
    jobs: Option<Sender<Job>>,
    workers: Vec<JoinHandle<()>>,
}

impl Copier {
    pub fn new(threads: usize) -> Copier {
        let (tx, rx) = unbounded::<Job>();
        let workers = (0..threads.max(1))
            .map(|i| {
                let rx = rx.clone();
                std::thread::Builder::new()
                    .name(format!("lpm-copy-{i}"))
                    .spawn(move || {
                        for job in rx {
                            for r in &job.regions {
                                // SAFETY: the module's invariants: valid, non-overlapping regions.
                                unsafe { r.perform() };
                            }
                            let _ = job.done.send(());
                        }
                    })
                    .expect("spawning a copy worker thread")
            })
            .collect();
        Copier { jobs: Some(tx), workers }
    }

    /// Queues the regions, split into about one job per worker; returns the ticket to wait on.
    pub fn copy(&self, regions: Vec<Region>) -> Ticket {
        let parts = self.workers.len().min(regions.len()).max(1);
        let (done_tx, done_rx) = bounded(parts);
        let per = regions.len().div_ceil(parts).max(1);
        let mut sent = 0;
        let mut chunks = regions.chunks(per);
        for _ in 0..parts {
            let chunk = chunks.next().map(<[Region]>::to_vec).unwrap_or_default();
            let job = Job { regions: chunk, done: done_tx.clone() };
            match self.jobs.as_ref().map(|tx| tx.send(job)) {
                Some(Ok(())) => sent += 1,
                // No worker left: copy here rather than lose the bytes.
                Some(Err(e)) => {
                    for r in &e.0.regions {
                        // SAFETY: as above.
                        unsafe { r.perform() };
                    }
                }
                None => {}
            }
        }
        Ticket { parts: sent, done: done_rx }
    }
}

impl Drop for Copier {
    fn drop(&mut self) {
        self.jobs = None;
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn copies_every_region_once() {
        let copier = Copier::new(3);
        let src: Vec<u8> = (0..=255).cycle().take(10_000).collect();
        let mut dst = vec![0u8; 10_000];
        let regions: Vec<Region> = (0..100)
            .map(|i| Region { src: src[i * 100..].as_ptr(), dst: dst[i * 100..].as_mut_ptr(), len: 100, runs: 1, src_stride: 0, dst_stride: 0 })
            .collect();
        copier.copy(regions).wait();
        assert_eq!(src, dst);
        copier.copy(Vec::new()).wait();
    }

    #[test]
    fn strided_runs_gather_a_column() {
        // Column 2 of a 4×4 row-major byte matrix.
        let copier = Copier::new(1);
        let src: Vec<u8> = (0..16).collect();
        let mut dst = vec![0u8; 4];
        let region = Region { src: src[2..].as_ptr(), dst: dst.as_mut_ptr(), len: 1, runs: 4, src_stride: 4, dst_stride: 1 };
        copier.copy(vec![region]).wait();
        assert_eq!(dst, [2, 6, 10, 14]);
    }
}
