//! Out-of-core VDB import: a grid with a few leaves spread over a box whose dense f32 array would
//! be far larger than memory (1024³ = 4 GiB here; 4096³ = 256 GiB with LPM_VDB_SPARSE_EDGE=4096,
//! the figure in benches/RESULTS.md) is streamed into the brick store with a bounded resident set,
//! and its voxels land where OpenVDB says they are. The peak resident set (VmHWM) is a process's
//! and the test crate runs many tests in one process, so the import runs in a child process of
//! this test binary that runs this test alone: the peak it reports is the import's.

use lpm::scene::Scene;
use std::path::{Path, PathBuf};

fn peak_rss_bytes() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").expect("/proc/self/status");
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).expect("VmHWM");
    line.split_whitespace().nth(1).and_then(|k| k.parse::<u64>().ok()).expect("VmHWM value") * 1024
}

/// Set in the child process that does the measured import.
const CHILD: &str = "LPM_VDB_SPARSE_CHILD";

#[test]
fn sparse_vdb_far_larger_than_memory_imports_with_bounded_resident_set() {
    if std::env::var_os(CHILD).is_none() {
        let test = "vdb_sparse::sparse_vdb_far_larger_than_memory_imports_with_bounded_resident_set";
        let out = std::process::Command::new(std::env::current_exe().expect("test binary"))
            .args(["--exact", test, "--nocapture", "--test-threads", "1"])
            .env(CHILD, "1")
            .output()
            .expect("run the test binary for the measured import");
        let stdout = String::from_utf8_lossy(&out.stdout);
        println!("{stdout}");
        assert!(
            out.status.success(),
            "the measured import failed:\n{stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(stdout.contains("1 passed"), "the child ran no test:\n{stdout}");
        return;
    }
    let edge: u32 = std::env::var("LPM_VDB_SPARSE_EDGE").ok().and_then(|v| v.parse().ok()).unwrap_or(1024);
    assert!(edge == 1024 || edge == 4096, "LPM_VDB_SPARSE_EDGE must be 1024 or 4096");
    let dir: PathBuf = crate::common::temp_dir("vdb-sparse");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/vdb/write_vdb.py");
    let out = std::process::Command::new("/usr/bin/python3").arg(&script).arg(&dir).output().expect("run python3");
    assert!(out.status.success(), "write_vdb.py failed:\n{}", String::from_utf8_lossy(&out.stderr));

    let scene_path = dir.join("sparse.toml");
    std::fs::write(
        &scene_path,
        format!("[volume]\nvdb = \"sparse{edge}.vdb\"\n\n[medium]\nsigma_t = 1.0\nalbedo = 0.5\n"),
    )
    .expect("write scene");
    let scene = Scene::load(&scene_path).expect("scene");
    assert_eq!(scene.volume.dims, [edge; 3]);

    let before = peak_rss_bytes();
    let start = std::time::Instant::now();
    let store = lpm::solver::build_store(&scene, &dir.join("store")).expect("store");
    let seconds = start.elapsed().as_secs_f64();
    let peak = peak_rss_bytes();
    let dense = u64::from(edge).pow(3) * 4;
    println!(
        "sparse VDB {edge}³ (dense {:.1} GiB): import {seconds:.1} s, {} occupied bricks, peak RSS {:.1} MiB (before the import {:.1} MiB)",
        dense as f64 / (1u64 << 30) as f64,
        store.occupied_count(),
        peak as f64 / (1u64 << 20) as f64,
        before as f64 / (1u64 << 20) as f64
    );
    assert!(peak < 512 << 20, "peak resident set {peak} bytes for a {dense}-byte dense volume");
    assert!(store.occupied_count() >= 4 && store.occupied_count() <= 16);

    // The voxels are where OpenVDB put them.
    let text = std::fs::read_to_string(dir.join(format!("sparse{edge}.json"))).expect("json");
    let info: serde_json::Value = serde_json::from_str(&text).expect("json");
    let e = &info["density"];
    let lo: Vec<i64> = (0..3).map(|i| e["bbox_min"][i].as_i64().expect("int")).collect();
    assert_eq!(lo, [0, 0, 0]);
    let mut nonzero = 0;
    for s in e["samples"].as_array().expect("samples") {
        let p: Vec<i64> = (0..3).map(|i| s[0][i].as_i64().expect("int")).collect();
        if p.iter().any(|&c| c < 0 || c >= i64::from(edge)) {
            continue;
        }
        let want = s[1].as_f64().expect("value") as f32;
        let got = store.density_at([p[0] as u32, p[1] as u32, p[2] as u32]);
        assert_eq!(got.to_bits(), want.to_bits(), "density at {p:?}");
        nonzero += (want != 0.0) as usize;
    }
    assert!(nonzero >= 1, "no sample hit a leaf");
}
