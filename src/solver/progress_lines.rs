//! Progress lines for long stretches of work that report nothing else meanwhile: an order of a
//! large volume on the GPU (minutes, hours on a CPU Vulkan device), the emission's trace (inside
//! the plan's stage). A scripted job's log should show that it is moving; a line is logged at most
//! every [`LOG_EVERY`], so small solves stay quiet.

use std::time::{Duration, Instant};

/// The least time between two progress lines.
pub const LOG_EVERY: Duration = Duration::from_secs(15);

/// A count of steps towards a known total, logged now and then with a rough time left (steps
/// differ in cost: vacuum slices, sun beams, bricks far from or near the emitters).
pub struct StepProgress {
    what: String,
    unit: &'static str,
    total: u32,
    done: u32,
    started: Instant,
    last_line: Instant,
}

impl StepProgress {
    /// `total` steps of `what` (the line's head, e.g. "order 3") counted in `unit` (plural),
    /// starting now.
    pub fn new(what: impl Into<String>, unit: &'static str, total: u32) -> StepProgress {
        let now = Instant::now();
        StepProgress { what: what.into(), unit, total: total.max(1), done: 0, started: now, last_line: now }
    }

    /// Counts one finished step; logs a line when the last one is old enough.
    pub fn step_done(&mut self) {
        self.done = (self.done + 1).min(self.total);
        let now = Instant::now();
        if now.duration_since(self.last_line) < LOG_EVERY {
            return;
        }
        self.last_line = now;
        let elapsed = now.duration_since(self.started).as_secs_f64();
        let left = elapsed / self.done as f64 * (self.total - self.done) as f64;
        tracing::info!(
            "{}: {} of {} {} ({:.0} %), {:.0} s so far, about {:.0} s left",
            self.what,
            self.done,
            self.total,
            self.unit,
            100.0 * self.done as f64 / self.total as f64,
            elapsed,
            left
        );
    }
}
