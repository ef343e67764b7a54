//! OpenVDB input, checked against the reference implementation: tests/vdb/write_vdb.py writes the
//! files with OpenVDB's Python module (Debian's python3-openvdb, installed by tools/setup.sh) and
//! dumps what OpenVDB reads back; lpm's reader must give the same values voxel for voxel, place the
//! volume where the transform says, refuse what it cannot read with a clear error (never a panic,
//! at every truncation and under flipped bytes), and solve a VDB scene to bitwise the fluence of the
//! same density given as a raw file.

use crate::common::temp_dir;
use lpm::scene::{Scene, VolumeSource};
use lpm::solver::BackendKind;
use lpm::store::vdb::{read_all, VdbError, VdbReader};
use serde_json::Value;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Runs the generator once per test binary; returns its output directory.
fn files() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = temp_dir("vdb-files");
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/vdb/write_vdb.py");
        // /usr/bin/python3 explicitly: a python3 earlier on PATH may lack the module.
        let out = std::process::Command::new("/usr/bin/python3")
            .arg(&script)
            .arg(&dir)
            .output()
            .expect("run /usr/bin/python3 (install python3-openvdb: tools/setup.sh)");
        assert!(
            out.status.success(),
            "write_vdb.py failed (is python3-openvdb installed? tools/setup.sh installs it):\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        dir
    })
}

fn json(case: &str) -> Value {
    let text = std::fs::read_to_string(files().join(format!("{case}.json"))).expect("json");
    serde_json::from_str(&text).expect("parse json")
}

fn ivec(v: &Value) -> [i32; 3] {
    std::array::from_fn(|i| v[i].as_i64().expect("int") as i32)
}

fn fvec(v: &Value) -> [f64; 3] {
    std::array::from_fn(|i| v[i].as_f64().expect("number"))
}

fn reader(case: &str) -> VdbReader<BufReader<File>> {
    let f = File::open(files().join(format!("{case}.vdb"))).expect("open vdb");
    VdbReader::new(BufReader::new(f)).expect("read header")
}

/// Checks every grid of `case` against what OpenVDB read back: bounding box, transform, sample
/// values, and (where dumped) every voxel of the box, bit for bit.
fn check_case(case: &str, expect_half: bool) -> usize {
    let info = json(case);
    let mut r = reader(case);
    let mut dense_checked = 0;
    for (name, e) in info.as_object().expect("object") {
        let g = r.read_grid(name, true).unwrap_or_else(|err| panic!("{case}/{name}: {err}"));
        assert_eq!(g.half, expect_half, "{case}/{name}: half flag");
        let [lo, hi] = g.tree.active_bbox().expect("active voxels");
        assert_eq!(lo.map(|v| v as i32), ivec(&e["bbox_min"]), "{case}/{name}: bbox min");
        assert_eq!(hi.map(|v| v as i32), ivec(&e["bbox_max"]), "{case}/{name}: bbox max");
        assert_eq!(g.placement.voxel_size, fvec(&e["voxel_size"])[0], "{case}/{name}: voxel size");
        assert_eq!(g.placement.translation, fvec(&e["index0_world"]), "{case}/{name}: translation");
        assert_eq!(g.tree.leaf_count() as i64, e["leaves"].as_i64().expect("leaves"), "{case}/{name}: leaves");
        for s in e["samples"].as_array().expect("samples") {
            let p = ivec(&s[0]);
            let want = s[1].as_f64().expect("value") as f32;
            assert_eq!(g.tree.value(p).to_bits(), want.to_bits(), "{case}/{name}: value at {p:?}");
        }
        if let Some(raw) = e.get("raw").and_then(Value::as_str) {
            let bytes = std::fs::read(files().join(raw)).expect("raw");
            let dims: [i64; 3] = std::array::from_fn(|i| hi[i] - lo[i] + 1);
            let mut k = 0;
            for z in 0..dims[2] {
                for y in 0..dims[1] {
                    for x in 0..dims[0] {
                        let want = f32::from_le_bytes([bytes[k], bytes[k + 1], bytes[k + 2], bytes[k + 3]]);
                        let p = [lo[0] + x, lo[1] + y, lo[2] + z].map(|v| v as i32);
                        let got = g.tree.value(p);
                        assert!(
                            got.to_bits() == want.to_bits(),
                            "{case}/{name}: voxel {p:?} is {got}, OpenVDB reads {want}"
                        );
                        k += 4;
                    }
                }
            }
            assert_eq!(k, bytes.len());
            dense_checked += 1;
        }
    }
    dense_checked
}

#[test]
fn float_grid_with_tiles_inactive_values_and_negative_coordinates_matches_openvdb() {
    assert_eq!(check_case("float", false), 1);
}

#[test]
fn half_grid_matches_openvdb() {
    assert_eq!(check_case("half", true), 1);
}

#[test]
fn several_grids_and_a_transform_match_openvdb() {
    assert_eq!(check_case("multi", false), 3);
    let names: Vec<String> = reader("multi").grids().into_iter().map(|g| g.name).collect();
    assert_eq!(names, ["density", "temperature", "flame"]);
}

#[test]
fn root_tile_matches_openvdb_at_sample_points() {
    assert_eq!(check_case("root_tile", false), 0);
    let info = lpm::store::vdb::vdb_info(&files().join("root_tile.vdb"), "density").expect("info");
    assert_eq!(info.dims, [4096 + 6, 4096, 4096]);
    assert_eq!(info.index_min, [-4096, 0, 0]);
}

/// Writes a scene next to the generated files and loads it.
fn load_scene(name: &str, volume: &str) -> Result<Scene, lpm::scene::SceneError> {
    let path = files().join(format!("{name}.toml"));
    let text = format!(
        "[volume]\n{volume}\n\n[medium]\nsigma_t = 2.0\nalbedo = 0.8\n\n[[lights]]\nkind = \"sky\"\nradiance = 1.0\n\n\
         [[lights]]\nkind = \"sun\"\ndirection = [0.3, 1.0, 0.2]\nirradiance = 2.0\n\n\
         [solver]\ndirections_per_face = 2\nmax_orders = 6\ntolerance = 1e-3\n"
    );
    std::fs::write(&path, text).expect("write scene");
    Scene::load(&path)
}

#[test]
fn scene_places_the_volume_from_the_transform() {
    let e = &json("multi")["temperature"];
    let s = load_scene("placed", "vdb = \"multi.vdb\"\ngrid = \"temperature\"").expect("scene");
    let lo = ivec(&e["bbox_min"]);
    let hi = ivec(&e["bbox_max"]);
    assert_eq!(s.volume.dims, std::array::from_fn(|i| (hi[i] - lo[i] + 1) as u32));
    assert_eq!(s.volume.voxel_size, 0.25);
    let t = fvec(&e["index0_world"]);
    // Voxel centre of index lo is at t + lo·h; the volume's corner half a voxel below.
    for i in 0..3 {
        assert_eq!(s.volume.origin[i], t[i] + (lo[i] as f64 - 0.5) * 0.25);
    }
    match &s.volume.source {
        VolumeSource::Vdb { grid, index_min, .. } => {
            assert_eq!(grid, "temperature");
            assert_eq!(*index_min, lo);
        }
        other => panic!("expected a VDB volume, got {other:?}"),
    }
    // A scene-given origin and voxel size override the transform's.
    let s = load_scene("override", "vdb = \"multi.vdb\"\norigin = [1.0, 2.0, 3.0]\nvoxel_size = 0.5").expect("scene");
    assert_eq!(s.volume.origin.to_array(), [1.0, 2.0, 3.0]);
    assert_eq!(s.volume.voxel_size, 0.5);
}

#[test]
fn scene_errors_name_the_file_and_the_problem() {
    let e = load_scene("nogrid", "vdb = \"multi.vdb\"\ngrid = \"smoke\"").expect_err("missing grid");
    let msg = e.to_string();
    assert!(msg.contains("volume.vdb") && msg.contains("multi.vdb"), "{msg}");
    assert!(msg.contains("\"smoke\"") && msg.contains("\"density\", \"temperature\", \"flame\""), "{msg}");

    let e = load_scene("rotated", "vdb = \"rotated.vdb\"").expect_err("rotated");
    let msg = e.to_string();
    assert!(msg.contains("rotated.vdb") && msg.contains("rotation"), "{msg}");

    let e = load_scene("dims", "vdb = \"multi.vdb\"\ndims = [4, 4, 4]").expect_err("dims");
    assert!(e.to_string().contains("volume.dims"), "{e}");

    std::fs::write(files().join("notvdb.vdb"), b"hello, this is not a VDB file").expect("write");
    let e = load_scene("notvdb", "vdb = \"notvdb.vdb\"").expect_err("not vdb");
    assert!(e.to_string().contains("not an OpenVDB file"), "{e}");

    let e = load_scene("absent", "vdb = \"absent.vdb\"").expect_err("absent");
    assert!(e.to_string().contains("absent.vdb"), "{e}");
}

#[test]
fn every_truncation_is_a_clear_error() {
    for case in ["multi", "half", "float"] {
        let bytes = std::fs::read(files().join(format!("{case}.vdb"))).expect("read");
        assert!(read_all(&bytes).is_ok());
        for k in 0..50 {
            let cut = bytes.len() * k / 50;
            match read_all(&bytes[..cut]) {
                Ok(_) => panic!("{case}: a file cut at {cut} of {} bytes was accepted", bytes.len()),
                Err(VdbError::Truncated { .. } | VdbError::NotVdb | VdbError::Malformed { .. }) => {}
                Err(e) => panic!("{case}: cut at {cut}: unexpected error {e}"),
            }
        }
        // Through the file path too: the message names the file and says it is truncated.
        let path = files().join(format!("{case}-cut.vdb"));
        std::fs::write(&path, &bytes[..bytes.len() * 3 / 4]).expect("write");
        let store_err = lpm::store::vdb::vdb_density(&path, "density", [1, 1, 1], [0, 0, 0]).err().expect("error");
        let msg = store_err.to_string();
        assert!(msg.contains(&path.display().to_string()) && msg.contains("truncated"), "{msg}");
    }
}

#[test]
fn flipped_bytes_never_panic() {
    for case in ["multi", "half"] {
        let bytes = std::fs::read(files().join(format!("{case}.vdb"))).expect("read");
        let step = (bytes.len() / 1500).max(1);
        let mut rejected = 0;
        for (n, at) in (0..bytes.len()).step_by(step).enumerate() {
            let mut b = bytes.clone();
            b[at] ^= [0xff, 0x01, 0x80][n % 3];
            // Ok or a typed error; a panic fails the test.
            if read_all(&b).is_err() {
                rejected += 1;
            }
        }
        assert!(rejected > 0, "{case}: no flipped byte was noticed");
    }
}

#[test]
fn vdb_scene_solves_bitwise_like_the_same_density_as_raw() {
    let e = &json("solve")["density"];
    let lo = ivec(&e["bbox_min"]);
    let hi = ivec(&e["bbox_max"]);
    let dims: [u32; 3] = std::array::from_fn(|i| (hi[i] - lo[i] + 1) as u32);
    let vdb = load_scene("solve-vdb", "vdb = \"solve.vdb\"").expect("vdb scene");
    let raw = load_scene(
        "solve-raw",
        &format!("raw = \"solve.density.raw\"\ndims = [{}, {}, {}]", dims[0], dims[1], dims[2]),
    )
    .expect("raw scene");
    assert_eq!(vdb.volume.dims, raw.volume.dims);
    let a = crate::common::solve("vdb-solve-vdb", &vdb, BackendKind::Cpu);
    let b = crate::common::solve("vdb-solve-raw", &raw, BackendKind::Cpu);
    // The stores hold the same densities, voxel for voxel.
    let mut nonzero = 0;
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let (da, db) = (a.store.density_at([x, y, z]), b.store.density_at([x, y, z]));
                assert_eq!(da.to_bits(), db.to_bits(), "density at {:?}", [x, y, z]);
                nonzero += (da != 0.0) as usize;
            }
        }
    }
    assert!(nonzero > 1000);
    let (fa, fb) = (a.fluence_all(), b.fluence_all());
    assert!(fa.iter().any(|&v| v > 0.0));
    assert!(fa.iter().zip(&fb).all(|(x, y)| x.to_bits() == y.to_bits()), "fluence differs");
}
