//! Host copy workers: move bricks between the memory-mapped store and the pinned staging buffers
//! on worker threads, so that the thread submitting GPU work does not stall on memcpy or on the
//! page faults of a memory-mapped file.
//!
//! The submitting thread describes a copy as a list of regions (source, destination, length) and
//! hands it to the pool through a crossbeam channel; it gets back a [`Ticket`] to wait on only when
//! it needs the bytes (before submitting the upload, before handing the store to the next pass).
//!
//! A region may convert while it copies ([`Convert`]): the previous order's source travels to the
//! device as f16 when the plan says so, rounded here, on the workers, during the gather.
//!
//! Safety model: a region is a pair of raw pointers into memory that outlives the copy (a mapped
//! staging buffer or a memory-mapped field owned by the backend, neither freed nor remapped while
//! a ticket is outstanding), and the pipeline never has two copies in flight that touch the same
//! bytes: a slice's gather and the previous slice's scatter cover different bricks, and every
//! ticket of a pass is waited for before the next pass starts.

use crate::solver::SolveError;
use crossbeam_channel::{bounded, unbounded, Receiver, Sender};
use std::thread::JoinHandle;

/// What a region does to the bytes it moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Convert {
    /// A plain copy.
    Copy,
    /// f32 values in, each multiplied by `scale` (a power of two: exact) and rounded to the nearest
    /// f16 out; a run then writes half the bytes it reads.
    F32ToF16 { scale: f32 },
}

/// `runs` copies of `len` contiguous source bytes, run i from `src + i·src_stride` to
/// `dst + i·dst_stride` (one run: a plain contiguous copy). Strided runs cut a slab of planes out of
/// a brick. With [`Convert::F32ToF16`] a run writes `len / 2` bytes.
#[derive(Clone, Copy, Debug)]
pub struct Region {
    pub src: *const u8,
    pub dst: *mut u8,
    pub len: usize,
    pub runs: usize,
    pub src_stride: usize,
    pub dst_stride: usize,
    pub convert: Convert,
}

impl Region {
    /// Performs the copy.
    ///
    /// # Safety
    /// Every run must be valid to read at the source and to write at the destination, and no run
    /// may overlap another region being copied at the same time (see the module docs).
    unsafe fn perform(&self) {
        if self.len == 4 && self.runs > 1 {
            // One voxel a run (an x sweep's lateral-major slab): a loop over the voxels, not a
            // memcpy call for each.
            let (src, dst) = (self.src, self.dst);
            match self.convert {
                Convert::Copy => {
                    for i in 0..self.runs {
                        // SAFETY: the caller's contract (4 bytes at each run); no alignment needed.
                        unsafe {
                            let v = (src.wrapping_add(i * self.src_stride) as *const u32).read_unaligned();
                            (dst.wrapping_add(i * self.dst_stride) as *mut u32).write_unaligned(v);
                        }
                    }
                }
                // SAFETY: the caller's contract (4 bytes readable, 2 writable at each run).
                Convert::F32ToF16 { scale } => unsafe {
                    to_f16(src, self.src_stride, dst, self.dst_stride, self.runs, scale)
                },
            }
            return;
        }
        for i in 0..self.runs {
            let (src, dst) = (self.src.wrapping_add(i * self.src_stride), self.dst.wrapping_add(i * self.dst_stride));
            match self.convert {
                // SAFETY: the caller's contract.
                Convert::Copy => unsafe { std::ptr::copy_nonoverlapping(src, dst, self.len) },
                // SAFETY: the caller's contract (`len` bytes readable at src, `len / 2` writable at dst).
                Convert::F32ToF16 { scale } => unsafe { to_f16(src, 4, dst, 2, self.len / 4, scale) },
            }
        }
    }
}

/// Rounds `n` f32 values, `src_step` bytes apart from `src`, times `scale`, to f16 values
/// `dst_step` bytes apart from `dst` (round to nearest even), in blocks through the stack so that
/// `half` can use the CPU's conversion instructions.
///
/// # Safety
/// 4 bytes readable at each source value, 2 writable at each destination, not overlapping (no
/// alignment needed).
unsafe fn to_f16(src: *const u8, src_step: usize, dst: *mut u8, dst_step: usize, n: usize, scale: f32) {
    use half::slice::HalfFloatSliceExt;
    const BLOCK: usize = 256;
    let mut values = [0f32; BLOCK];
    let mut halves = [half::f16::ZERO; BLOCK];
    let mut done = 0;
    while done < n {
        let m = BLOCK.min(n - done);
        for (k, v) in values[..m].iter_mut().enumerate() {
            // SAFETY: 4 bytes readable at each source value.
            *v = unsafe { (src.add(src_step * (done + k)) as *const f32).read_unaligned() } * scale;
        }
        halves[..m].convert_from_f32_slice(&values[..m]);
        if dst_step == 2 {
            // SAFETY: within the 2n bytes at dst; u8 needs no alignment.
            unsafe { std::ptr::copy_nonoverlapping(halves.as_ptr() as *const u8, dst.add(2 * done), 2 * m) };
        } else {
            for (k, h) in halves[..m].iter().enumerate() {
                // SAFETY: 2 bytes writable at each destination value.
                unsafe { (dst.add(dst_step * (done + k)) as *mut half::f16).write_unaligned(*h) };
            }
        }
        done += m;
    }
}

// SAFETY: see the module docs: regions point into memory that outlives the copy, and concurrent
// regions never overlap.
unsafe impl Send for Region {}

struct Job {
    regions: Vec<Region>,
    done: Sender<()>,
}

/// Waits for a batch of copies; dropping it waits too, so the memory a copy writes cannot be
/// freed or reused while the copy runs.
#[must_use = "a copy must be waited for before its bytes are used"]
pub struct Ticket {
    /// Jobs not yet reported done.
    parts: usize,
    done: Receiver<()>,
}

impl Ticket {
    /// Blocks until every region of the batch has been copied; an error when a worker died (it
    /// panicked) before finishing its part.
    pub fn wait(mut self) -> Result<(), SolveError> {
        self.wait_parts()
    }

    fn wait_parts(&mut self) -> Result<(), SolveError> {
        while self.parts > 0 {
            // A worker that died drops its sender: once every live one is done, recv fails.
            self.done.recv().map_err(|_| SolveError::CopyWorkerDied)?;
            self.parts -= 1;
        }
        Ok(())
    }
}

impl Drop for Ticket {
    fn drop(&mut self) {
        if self.wait_parts().is_err() {
            tracing::error!("a copy worker died during a copy");
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
    ///
    /// # Safety
    /// Every region must be valid to read at its source and to write at its destination until
    /// the ticket has been waited for (or dropped), and no two regions in flight at the same time
    /// may overlap (see the module docs).
    pub unsafe fn copy(&self, regions: Vec<Region>) -> Ticket {
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
            .map(|i| Region {
                src: src[i * 100..].as_ptr(),
                dst: dst[i * 100..].as_mut_ptr(),
                len: 100,
                runs: 1,
                src_stride: 0,
                dst_stride: 0,
                convert: Convert::Copy,
            })
            .collect();
        // SAFETY: the regions lie inside `src` and `dst`, which outlive the wait, and do not overlap.
        unsafe { copier.copy(regions) }.wait().unwrap();
        assert_eq!(src, dst);
        // SAFETY: no region.
        unsafe { copier.copy(Vec::new()) }.wait().unwrap();
    }

    #[test]
    fn a_ticket_whose_worker_died_says_so() {
        // Two jobs, one reported done; the other's worker died (its sender is gone).
        let (done, rx) = bounded(2);
        done.send(()).unwrap();
        drop(done);
        let ticket = Ticket { parts: 2, done: rx };
        assert!(matches!(ticket.wait(), Err(SolveError::CopyWorkerDied)));
    }

    #[test]
    fn strided_runs_gather_a_column() {
        // Column 2 of a 4×4 row-major byte matrix.
        let copier = Copier::new(1);
        let src: Vec<u8> = (0..16).collect();
        let mut dst = vec![0u8; 4];
        let region = Region {
            src: src[2..].as_ptr(),
            dst: dst.as_mut_ptr(),
            len: 1,
            runs: 4,
            src_stride: 4,
            dst_stride: 1,
            convert: Convert::Copy,
        };
        // SAFETY: the four runs lie inside `src` and `dst`.
        unsafe { copier.copy(vec![region]) }.wait().unwrap();
        assert_eq!(dst, [2, 6, 10, 14]);
    }

    #[test]
    fn strided_runs_convert_to_scaled_f16() {
        // Columns 1–2 of a 600×3 row-major f32 matrix (more than one conversion block), scaled by
        // 2^3 and rounded to f16 into a packed 600×2 matrix.
        let copier = Copier::new(2);
        let (rows, cols) = (600usize, 3usize);
        let src: Vec<f32> = (0..rows * cols).map(|i| 1.0 + i as f32 / 7.0).collect();
        let mut dst = vec![0u16; rows * 2];
        let region = Region {
            src: src[1..].as_ptr() as *const u8,
            dst: dst.as_mut_ptr() as *mut u8,
            len: 2 * 4,
            runs: rows,
            src_stride: cols * 4,
            dst_stride: 2 * 2,
            convert: Convert::F32ToF16 { scale: 8.0 },
        };
        // SAFETY: the runs lie inside `src` and `dst`.
        unsafe { copier.copy(vec![region]) }.wait().unwrap();
        for r in 0..rows {
            for c in 0..2 {
                let expected = half::f16::from_f32(src[r * cols + 1 + c] * 8.0);
                assert_eq!(dst[r * 2 + c], expected.to_bits(), "row {r} column {c}");
            }
        }
        // Round to nearest even: 1 + 2^-11 is a tie between 1 and 1 + 2^-10.
        assert_eq!(half::f16::from_f32(1.0 + 2f32.powi(-11)), half::f16::ONE);
    }

    #[test]
    fn voxel_runs_transpose_and_convert_as_whole_runs_do() {
        // A 16×300 row-major f32 matrix: its column 5 gathered one value a run (as an x sweep's
        // slab plane is), scattered back into another matrix, and rounded to f16 into every third
        // half of a buffer (the same values as the contiguous conversion gives).
        let copier = Copier::new(2);
        let (rows, cols) = (300usize, 16usize);
        let src: Vec<f32> = (0..rows * cols).map(|i| 0.1 + i as f32 / 3.0).collect();
        let mut column = vec![0f32; rows];
        let mut back = vec![0f32; rows * cols];
        let mut halves = vec![0u16; rows * 3];
        let voxel = |src: *const u8, dst: *mut u8, src_stride, dst_stride, convert| Region {
            src,
            dst,
            len: 4,
            runs: rows,
            src_stride,
            dst_stride,
            convert,
        };
        let src5 = src[5..].as_ptr() as *const u8;
        // SAFETY: every run lies inside its buffer; the three regions write different buffers.
        unsafe {
            copier.copy(vec![voxel(src5, column.as_mut_ptr() as *mut u8, cols * 4, 4, Convert::Copy)]).wait().unwrap();
            let scale = Convert::F32ToF16 { scale: 0.5 };
            copier.copy(vec![voxel(src5, halves.as_mut_ptr() as *mut u8, cols * 4, 6, scale)]).wait().unwrap();
            let to = back[5..].as_mut_ptr() as *mut u8;
            copier.copy(vec![voxel(column.as_ptr() as *const u8, to, 4, cols * 4, Convert::Copy)]).wait().unwrap();
        }
        for r in 0..rows {
            let v = src[r * cols + 5];
            assert_eq!(column[r].to_bits(), v.to_bits(), "row {r}");
            assert_eq!(back[r * cols + 5].to_bits(), v.to_bits(), "row {r}");
            assert_eq!(halves[3 * r], half::f16::from_f32(v * 0.5).to_bits(), "row {r}");
            assert_eq!([halves[3 * r + 1], halves[3 * r + 2]], [0, 0], "row {r}: only every third half");
        }
    }
}
