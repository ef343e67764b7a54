//! Any bytes as an attached NRRD file (`.nrrd`: the header, a blank line, the samples): the header
//! parser must return a header or a (field, problem) error, never panic; a header it accepts must
//! describe a 3-D volume; and the samples of an accepted small volume must decode or fail with a
//! typed error. A detached header's data file is not read (it would name files on this host).
#![no_main]
use libfuzzer_sys::fuzz_target;
use lpm::store::nrrd_input::{decode, header};
use std::io::Write;
use std::path::Path;

/// Samples decoded at most (gzip can promise any count; the fuzzer's time goes to the parser).
const MAX_SAMPLES: u64 = 1 << 16;

fuzz_target!(|data: &[u8]| {
    let Ok(h) = header::parse(Path::new("fuzz.nrrd"), data) else { return };
    assert!(h.dims.iter().all(|&d| d > 0), "{h:?}");
    assert!(h.voxel_size.is_none_or(|v| v.is_finite() && v > 0.0), "{h:?}");
    let header::DataSource::Attached(_) = h.data else { return };
    if h.dims.iter().try_fold(1u64, |acc, &d| acc.checked_mul(d)).is_none_or(|n| n > MAX_SAMPLES) {
        return;
    }
    let mut file = tempfile::NamedTempFile::new().expect("temp file");
    file.write_all(data).expect("write");
    let mut count = 0u64;
    let r = decode(file.path(), &h, |v| {
        count += v.len() as u64;
        Ok(())
    });
    if r.is_ok() {
        assert_eq!(count, h.dims.iter().product::<u64>());
    }
});
