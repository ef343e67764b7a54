//! solver
pub mod segment;
