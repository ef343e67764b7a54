//! solver (to be written)
