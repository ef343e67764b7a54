//! Any bytes as a raw density file of a small volume whose dims come from the first bytes: the
//! importer must fill every brick or return a typed error (wrong size, bad density), never panic,
//! and every density it accepts must be finite and ≥ 0.
#![no_main]
use libfuzzer_sys::fuzz_target;
use lpm::store::{raw_density, BrickGrid};
use std::io::Write;

fuzz_target!(|data: &[u8]| {
    if data.len() < 3 {
        return;
    }
    let dims = [data[0] % 40 + 1, data[1] % 40 + 1, data[2] % 40 + 1].map(u32::from);
    let mut file = tempfile::NamedTempFile::new().expect("temp file");
    file.write_all(&data[3..]).expect("write");
    let Ok(raw) = raw_density(file.path(), dims) else { return };
    let grid = BrickGrid::new(dims);
    let mut out = vec![0f32; 4096];
    for b in 0..grid.brick_count() {
        match raw.fill_brick(grid.brick_coords(b), &mut out) {
            Ok(()) => assert!(out.iter().all(|v| v.is_finite() && *v >= 0.0)),
            Err(_) => return,
        }
    }
});
