//! Any bytes as an OpenVDB file: the reader must return its grids or a typed error, never panic,
//! and never allocate more than the bytes can justify (every length is checked against what is left).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = lpm::store::vdb::read_all(data);
});
