//! Scene files (TOML): parsing and validation into [`Scene`].
mod types;
pub use types::*;
