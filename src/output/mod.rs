//! output (to be written)
