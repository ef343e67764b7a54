//! The solver: the plan, the discretisation shared by both backends, the CPU twin, the GPU driver
//! and the order loop.
pub mod cpu;
pub mod energy;
pub mod orders;
pub mod plan;
pub mod segment;
pub mod sweep;

use thiserror::Error;

#[derive(Debug, Error)]
pub enum SolveError {
    #[error("the CPU backend keeps the whole volume in memory and would need {} MiB; use the GPU backend", bytes >> 20)]
    TooLargeForCpu { bytes: u64 },
}
