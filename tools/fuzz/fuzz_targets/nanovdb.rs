//! Any bytes as a NanoVDB file: the reader must return the grid or a typed error, never panic, and
//! never allocate more than the bytes can justify (every offset and count is checked against the
//! buffer).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = lpm::store::nanovdb::read_nanovdb_bytes(data, "density");
});
