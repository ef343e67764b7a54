//! Whether a solve keeps the store's pages resident or hands them back after each pass.
//!
//! Passes over the store's files (the streamer's gathers and scatters, the host passes between
//! orders, the exports) hand back the pages they are done with (`MADV_DONTNEED`, see [`super::Field`])
//! so that a volume far larger than RAM is solved with a bounded resident set. When the store fits
//! in memory that is pure loss: every pass faults every page in again (on a 256³ RGB store, most of
//! a kernel-less order's host time). So the solve decides once, when its fields exist: a store no
//! larger than the host memory budget (`solver.host_memory_budget`, default half of the memory the
//! system reports available) keeps its pages, a larger one hands them back as before. The choice
//! changes where values live, never a value: results are bitwise the same either way.
//!
//! The decision is shared, through one [`PageHolding`], by the store and every field mapped from it.

use serde::Serialize;
use std::sync::atomic::{AtomicBool, Ordering};

/// The store-wide switch: `true` makes every page release of the store and its fields a no-op.
#[derive(Debug, Default)]
pub struct PageHolding {
    hold: AtomicBool,
}

impl PageHolding {
    pub fn holds(&self) -> bool {
        self.hold.load(Ordering::Relaxed)
    }

    pub fn set(&self, hold: bool) {
        self.hold.store(hold, Ordering::Relaxed);
    }
}

/// How a solve treats the store's pages, as `report.json` gives it (`host_memory`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Residency {
    /// Bytes of the store's files (density and every field) when the solve started.
    pub store_bytes: u64,
    /// The host memory budget the store was measured against; `None`: none known (no budget set
    /// and the system reports no available memory), so pages are handed back.
    pub budget_bytes: Option<u64>,
    /// Where the budget came from: `"solver.host_memory_budget"`, `"half of MemAvailable"` or `"none"`.
    pub budget_origin: &'static str,
    /// The pages stay resident between passes (the store fits the budget).
    pub kept_resident: bool,
}

impl Residency {
    /// Decides for a store of `store_bytes`: against the scene's budget if given, else half of
    /// `available` (the system's available memory), else hand pages back.
    pub fn decide(store_bytes: u64, scene_budget: Option<u64>, available: Option<u64>) -> Residency {
        let (budget_bytes, budget_origin) = match (scene_budget, available) {
            (Some(b), _) => (Some(b), "solver.host_memory_budget"),
            (None, Some(a)) => (Some(a / 2), "half of MemAvailable"),
            (None, None) => (None, "none"),
        };
        let kept_resident = budget_bytes.is_some_and(|b| store_bytes <= b);
        Residency { store_bytes, budget_bytes, budget_origin, kept_resident }
    }

    /// One line for the log.
    pub fn describe(&self) -> String {
        match (self.kept_resident, self.budget_bytes) {
            (true, Some(b)) => {
                format!("store pages kept resident ({} bytes ≤ {b} bytes, {})", self.store_bytes, self.budget_origin)
            }
            (false, Some(b)) => format!(
                "store pages handed back after each pass ({} bytes > {b} bytes, {})",
                self.store_bytes, self.budget_origin
            ),
            (_, None) => "store pages handed back after each pass (no host memory budget known)".to_string(),
        }
    }
}

/// The memory the system reports available to new work (`MemAvailable` of `/proc/meminfo`), where
/// it does.
pub fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    parse_mem_available(&text)
}

fn parse_mem_available(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let mut words = line.split_whitespace().skip(1);
    let value: u64 = words.next()?.parse().ok()?;
    match words.next() {
        Some("kB") => value.checked_mul(1024),
        None => Some(value),
        Some(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_budget_decides_and_the_scene_wins_over_the_system() {
        let r = Residency::decide(100, None, Some(400));
        assert!(r.kept_resident && r.budget_bytes == Some(200) && r.budget_origin == "half of MemAvailable");
        let r = Residency::decide(300, None, Some(400));
        assert!(!r.kept_resident);
        let r = Residency::decide(300, Some(300), Some(10));
        assert!(r.kept_resident && r.budget_origin == "solver.host_memory_budget");
        let r = Residency::decide(1, None, None);
        assert!(!r.kept_resident && r.budget_bytes.is_none());
        assert!(r.describe().contains("handed back"));
    }

    #[test]
    fn mem_available_is_read_in_bytes() {
        let text = "MemTotal:       24000000 kB\nMemFree:   100 kB\nMemAvailable:   20000000 kB\n";
        assert_eq!(parse_mem_available(text), Some(20_000_000 * 1024));
        assert_eq!(parse_mem_available("MemTotal: 5 kB\n"), None);
        assert_eq!(parse_mem_available("MemAvailable: x kB\n"), None);
    }

    #[test]
    fn the_switch_is_shared() {
        let h = std::sync::Arc::new(PageHolding::default());
        let other = std::sync::Arc::clone(&h);
        assert!(!h.holds());
        other.set(true);
        assert!(h.holds());
    }
}
