//! Progress inside an order, for long solves: an order of a large volume can take many minutes
//! (hours on a CPU Vulkan device), and a scripted job's log should show that it is moving. The
//! unit is the pass (one streaming of a face's slices for some of its directions); a line is
//! logged at most every [`LOG_EVERY`], so small solves stay quiet.

use std::time::{Duration, Instant};

/// The least time between two progress lines.
pub const LOG_EVERY: Duration = Duration::from_secs(15);

pub struct PassProgress {
    order: u32,
    total: u32,
    done: u32,
    started: Instant,
    last_line: Instant,
}

impl PassProgress {
    /// An order of `total` passes starting now.
    pub fn new(order: u32, total: u32) -> PassProgress {
        let now = Instant::now();
        PassProgress { order, total: total.max(1), done: 0, started: now, last_line: now }
    }

    /// Counts one finished pass; logs a line when the last one is old enough.
    pub fn pass_done(&mut self) {
        self.done = (self.done + 1).min(self.total);
        let now = Instant::now();
        if now.duration_since(self.last_line) < LOG_EVERY {
            return;
        }
        self.last_line = now;
        let elapsed = now.duration_since(self.started).as_secs_f64();
        // Passes differ in cost (vacuum slices, the sun beams), so the estimate is rough.
        let left = elapsed / self.done as f64 * (self.total - self.done) as f64;
        tracing::info!(
            "order {}: {} of {} passes ({:.0} %), {:.0} s so far, about {:.0} s left",
            self.order,
            self.done,
            self.total,
            100.0 * self.done as f64 / self.total as f64,
            elapsed,
            left
        );
    }
}

/// Passes in one order of a plan: every face's directions in groups of `directions_per_pass`,
/// plus one pass per sun beam swept in it (`beams`: all in order 0, those along a periodic axis
/// later, `Plan::beam_swept_in`).
pub fn passes_per_order(faces: &[usize], beams: usize, directions_per_pass: u32) -> u32 {
    let per_pass = directions_per_pass.max(1) as usize;
    let face_passes: usize = faces.iter().map(|&n| n.div_ceil(per_pass)).sum();
    (face_passes + beams) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_face_passes_and_beams() {
        assert_eq!(passes_per_order(&[25; 6], 1, 15), 6 * 2 + 1);
        assert_eq!(passes_per_order(&[25; 6], 0, 15), 12);
        assert_eq!(passes_per_order(&[25; 6], 2, 15), 14);
        assert_eq!(passes_per_order(&[1; 6], 0, 1), 6);
    }
}
