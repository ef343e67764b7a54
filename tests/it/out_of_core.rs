//! Out of core: a volume far larger than what the solve keeps in memory is imported, planned and
//! streamed for one order with a bounded resident set. The input is a 1 GiB raw density file that is
//! sparse on disk (holes read as zeros) holding one small blob, so the run stays short; the import
//! still reads every byte of it, and the solve still sweeps every plane of the 1024 × 1024 × 256 grid
//! (a 1024² lattice of rays: the widest a z sweep of the suite's volumes has).
use crate::common::*;
use std::io::{Seek, SeekFrom, Write};

const DIMS: [u64; 3] = [1024, 1024, 256];
const BLOB: std::ops::Range<u64> = 500..520;

fn sparse_raw(path: &std::path::Path) -> u64 {
    let mut f = std::fs::File::create(path).expect("create raw");
    let bytes = DIMS.iter().product::<u64>() * 4;
    f.set_len(bytes).expect("size the raw");
    let row: Vec<u8> = std::iter::repeat_n(1.0f32.to_le_bytes(), (BLOB.end - BLOB.start) as usize).flatten().collect();
    for z in 120..140 {
        for y in BLOB {
            f.seek(SeekFrom::Start(((z * DIMS[1] + y) * DIMS[0] + BLOB.start) * 4)).expect("seek");
            f.write_all(&row).expect("write the blob");
        }
    }
    bytes
}

#[test]
fn a_volume_larger_than_the_resident_set_is_streamed_for_one_order() {
    let dir = temp_dir("out-of-core");
    let raw_bytes = sparse_raw(&dir.join("density.raw"));
    let scene = write_scene(
        &dir,
        "[volume]\nraw = \"density.raw\"\ndims = [1024, 1024, 256]\nvoxel_size = 1.0\n\n\
         [medium]\nsigma_t = 0.5\nalbedo = 0.8\n\n[[lights]]\nkind = \"sky\"\nradiance = 1.0\n\n\
         [solver]\ndirections_per_face = 1\nmax_orders = 1\n",
    );
    let out = dir.join("out");
    let status =
        lpm_command(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-image", "--no-fields"])
            .status()
            .expect("run lpm");
    assert!(status.success());
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).expect("report")).expect("json");
    assert_eq!(report["orders"], 1);
    assert!(report["energy"]["relative_imbalance"].as_f64().unwrap() < 1e-6, "{}", report["energy"]);
    // Only the blob's bricks are stored: 8 of 65536.
    assert_eq!(report["plan"]["bricks_total"], 65536);
    assert_eq!(report["plan"]["bricks_empty"], 65536 - 8);
    let store = report["store_bytes"].as_u64().unwrap();
    assert!(store < raw_bytes / 500, "store {store} bytes");
    // The process never held the volume: its peak resident set is well below the 1 GiB it read.
    let peak = report["peak_resident_bytes"].as_u64().expect("peak resident bytes on Linux");
    eprintln!("raw {raw_bytes} bytes, store {store} bytes, peak resident {peak} bytes");
    assert!(peak < raw_bytes / 3, "peak resident {peak} bytes for a {raw_bytes}-byte volume");
    // --no-fields: no dense exports.
    assert!(!out.join("fluence.raw").exists() && !out.join("source.raw").exists());
    let info = lpm_command(&["info", out.to_str().unwrap()]).output().expect("run lpm info");
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(info.status.success() && text.contains("fluence   not exported (solved with --no-fields)"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}
