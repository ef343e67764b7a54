//! The brick store, its importers, and the exported field files.

use lpm::output::{
    export_field, read_field_json, read_raw_field, write_atomic, write_json_atomic, EmptyBricks, FieldMeta,
};
use lpm::store::{raw_density, BrickGrid, BrickStore, Coverage, StoreError, BRICK_EDGE, BRICK_VOXELS};
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

/// A fresh, empty directory for one test, removed when dropped.
struct TestDir(PathBuf);

impl std::ops::Deref for TestDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for TestDir {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

fn test_dir(name: &str) -> TestDir {
    let dir = std::env::temp_dir().join(format!("lpm-store-test-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).expect("create test dir");
    TestDir(dir)
}

/// Fills a brick from a function of the global voxel coordinates (evaluated on the padding too, so
/// the store's zeroing of voxels beyond dims is exercised).
fn fill_from(f: impl Fn([u32; 3]) -> f32 + Sync) -> impl Fn([u32; 3], &mut [f32]) -> Result<(), StoreError> + Sync {
    move |b, out| {
        for z in 0..16 {
            for y in 0..16 {
                for x in 0..16 {
                    out[x as usize + 16 * (y as usize + 16 * z as usize)] =
                        f([b[0] * 16 + x, b[1] * 16 + y, b[2] * 16 + z]);
                }
            }
        }
        Ok(())
    }
}

/// Nonzero only in a corner region, so some bricks of 37×20×53 are empty.
fn corner_density(v: [u32; 3]) -> f32 {
    if v[0] < 20 && v[2] < 30 {
        1.0 + v[0] as f32 + 0.01 * v[1] as f32 + 0.001 * v[2] as f32
    } else {
        0.0
    }
}

const DIMS: [u32; 3] = [37, 20, 53];

#[test]
fn brick_math_round_trips() {
    for dims in [[1, 1, 1], [16, 16, 16], [17, 1, 33], DIMS] {
        let g = BrickGrid::new(dims);
        assert_eq!(g.bricks, dims.map(|d| d.div_ceil(BRICK_EDGE)));
        assert_eq!(g.voxel_count(), dims.iter().map(|&d| d as u64).product::<u64>());
        for i in 0..g.brick_count() {
            let b = g.brick_coords(i);
            assert!(b.iter().zip(g.bricks).all(|(&c, n)| c < n));
            assert_eq!(g.brick_index(b), i);
        }
        // x fastest
        if g.bricks[0] > 1 {
            assert_eq!(g.brick_index([1, 0, 0]), 1);
        }
        for v in [[0, 0, 0], [dims[0] - 1, dims[1] - 1, dims[2] - 1], [dims[0] / 2, dims[1] / 3, dims[2] / 5]] {
            let (b, l) = g.locate(v);
            let bc = g.brick_coords(b);
            assert_eq!(l, (v[0] % 16 + 16 * (v[1] % 16) + 256 * (v[2] % 16)) as usize);
            assert_eq!(bc, v.map(|c| c / 16));
            assert!(l < BRICK_VOXELS);
        }
    }
}

#[test]
fn dims_not_multiple_of_16_and_empty_bricks_take_no_space() {
    let dir = test_dir("odd-dims");
    let store = BrickStore::create_with(&dir, DIMS, 0.5, fill_from(corner_density)).expect("create");
    let g = *store.grid();
    assert_eq!(g.bricks, [3, 2, 4]);
    // Occupied: bricks with x < 20 (bx 0, 1) and z < 30 (bz 0, 1), any by.
    let expected_occupied = 2 * 2 * 2;
    assert_eq!(store.occupied_count(), expected_occupied);
    let size = fs::metadata(dir.join("density.bricks")).expect("density file").len();
    assert_eq!(size, (expected_occupied * BRICK_VOXELS * 4) as u64);
    for b in 0..g.brick_count() {
        let c = g.brick_coords(b);
        let occupied = c[0] < 2 && c[2] < 2;
        assert_eq!(store.slot(b).is_some(), occupied, "brick {c:?}");
        assert_eq!(store.density_brick(b).is_some(), occupied);
    }
    // Slots follow brick order.
    let slots: Vec<u32> = store.occupied_bricks().filter_map(|b| store.slot(b)).collect();
    assert_eq!(slots, (0..expected_occupied as u32).collect::<Vec<_>>());
    for z in 0..DIMS[2] {
        for y in 0..DIMS[1] {
            for x in 0..DIMS[0] {
                assert_eq!(store.density_at([x, y, z]), corner_density([x, y, z]));
            }
        }
    }
    // Padding voxels (beyond dims) were forced to zero though fill wrote there.
    let fill_everywhere = BrickStore::create_with(&test_dir("padding"), DIMS, 1.0, fill_from(|_| 2.0)).expect("create");
    let last = g.brick_index([2, 1, 3]);
    let d = fill_everywhere.density_brick(last).expect("occupied");
    assert_eq!(d[0], 2.0);
    assert_eq!(d[5], 0.0, "x = 37 is beyond dims");
    assert_eq!(d[16 * 4], 0.0, "y = 20 is beyond dims");
    assert_eq!(fill_everywhere.density_at([37, 0, 0]), 0.0);
    assert_eq!(store.voxel_size(), 0.5);
    assert_eq!(store.dir(), &*dir);
}

#[test]
fn all_empty_volume() {
    let dir = test_dir("all-empty");
    let store = BrickStore::create_with(&dir, [20, 33, 5], 1.0, |_, _| Ok(())).expect("create");
    assert_eq!(store.occupied_count(), 0);
    assert_eq!(fs::metadata(dir.join("density.bricks")).expect("density").len(), 0);
    assert_eq!(store.density_at([3, 4, 1]), 0.0);
    assert!(store.density_brick(0).is_none());
    let mut f = store.create_field("src", 3, Coverage::Occupied).expect("field");
    assert!(f.as_slice().is_empty());
    assert!(f.brick_mut(0).is_none());
    assert_eq!(f.value([1, 1, 1], 2), 0.0);
    f.fill_zero().unwrap();
    f.flush().expect("flush");
    let reopened = BrickStore::open(&dir).expect("reopen");
    assert_eq!(reopened.occupied_count(), 0);
}

#[test]
fn reopen_gives_the_same_store_and_checks_sizes() {
    let dir = test_dir("reopen");
    let a = BrickStore::create_with(&dir, DIMS, 0.25, fill_from(corner_density)).expect("create");
    let b = BrickStore::open(&dir).expect("reopen");
    assert_eq!(a.grid(), b.grid());
    assert_eq!(a.voxel_size(), b.voxel_size());
    assert_eq!(a.occupied_count(), b.occupied_count());
    for i in 0..a.grid().brick_count() {
        assert_eq!(a.slot(i), b.slot(i));
        assert_eq!(a.density_brick(i), b.density_brick(i));
    }
    drop((a, b));
    // A truncated density file is refused, naming it.
    let path = dir.join("density.bricks");
    let file = fs::OpenOptions::new().write(true).open(&path).expect("open");
    file.set_len(1000).expect("truncate");
    let err = BrickStore::open(&dir).err().expect("must fail").to_string();
    assert!(err.contains("density.bricks") && err.contains("1000 bytes"), "{err}");
    // Creating again over a broken store replaces it.
    let c = BrickStore::create_with(&dir, DIMS, 0.25, fill_from(|_| 1.0)).expect("recreate");
    assert_eq!(c.occupied_count(), c.grid().brick_count());
    assert_eq!(BrickStore::open(&dir).expect("reopen").occupied_count(), c.grid().brick_count());
    // A missing table too.
    let err = BrickStore::open(&test_dir("nothing")).err().expect("must fail").to_string();
    assert!(err.contains("bricks.json"), "{err}");
}

fn write_raw(path: &Path, values: &[f32]) {
    let mut f = fs::File::create(path).expect("create raw");
    for v in values {
        f.write_all(&v.to_le_bytes()).expect("write raw");
    }
}

#[test]
fn raw_import_round_trips() {
    let dir = test_dir("raw");
    let dims = [19u32, 17, 3];
    let n = dims.iter().product::<u32>() as usize;
    let values: Vec<f32> = (0..n).map(|i| if i % 7 == 0 { 0.0 } else { i as f32 * 0.5 }).collect();
    let raw_path = dir.join("in.raw");
    write_raw(&raw_path, &values);
    let raw = raw_density(&raw_path, dims).expect("raw");
    let store =
        BrickStore::create_with(&dir.join("store"), dims, 1.0, |b, out| raw.fill_brick(b, out)).expect("import");
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let i = (x + dims[0] * (y + dims[1] * z)) as usize;
                assert_eq!(store.density_at([x, y, z]), values[i]);
            }
        }
    }
}

#[test]
fn raw_import_rejects_truncated_files_and_bad_values() {
    let dir = test_dir("raw-bad");
    let dims = [10u32, 10, 10];
    let path = dir.join("short.raw");
    write_raw(&path, &vec![1.0; 999]);
    let Err(err) = raw_density(&path, dims) else { panic!("truncated must fail") };
    let err = err.to_string();
    assert!(err.contains("short.raw") && err.contains("4000") && err.contains("3996"), "{err}");

    let mut values = vec![1.0f32; 1000];
    values[3 + 10 * (4 + 10 * 5)] = f32::NAN;
    let path = dir.join("nan.raw");
    write_raw(&path, &values);
    let raw = raw_density(&path, dims).expect("size is right");
    let store_dir = dir.join("store");
    let err = BrickStore::create_with(&store_dir, dims, 1.0, |b, out| raw.fill_brick(b, out))
        .err()
        .expect("NaN must fail")
        .to_string();
    assert!(err.contains("nan.raw") && err.contains("(3, 4, 5)") && err.contains("NaN"), "{err}");
    // Nothing half-written.
    assert!(!store_dir.join("bricks.json").exists());
    assert!(!store_dir.join("density.bricks").exists());
    let leftovers: Vec<_> = fs::read_dir(&store_dir).expect("dir").collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");

    values[3 + 10 * (4 + 10 * 5)] = -2.0;
    write_raw(&path, &values);
    let raw = raw_density(&path, dims).expect("size is right");
    let mut out = vec![0.0; BRICK_VOXELS];
    let err = raw.fill_brick([0, 0, 0], &mut out).expect_err("negative must fail").to_string();
    assert!(err.contains("-2"), "{err}");
}

#[test]
fn fields_dense_and_occupied() {
    let dir = test_dir("fields");
    let store = BrickStore::create_with(&dir, DIMS, 1.0, fill_from(corner_density)).expect("create");
    let g = *store.grid();
    let empty = (0..g.brick_count()).find(|&b| store.slot(b).is_none()).expect("an empty brick");
    let full = (0..g.brick_count()).find(|&b| store.slot(b).is_some()).expect("an occupied brick");

    let mut occ = store.create_field("source", 2, Coverage::Occupied).expect("field");
    assert_eq!((occ.components(), occ.coverage(), occ.name()), (2, Coverage::Occupied, "source"));
    assert_eq!(occ.as_slice().len(), store.occupied_count() * 2 * BRICK_VOXELS);
    assert!(occ.as_slice().iter().all(|&v| v == 0.0));
    assert!(occ.brick(empty).is_none());
    assert!(occ.brick_mut(empty).is_none());
    let brick = occ.brick_mut(full).expect("occupied brick is stored");
    assert_eq!(brick.len(), 2 * BRICK_VOXELS);
    brick[BRICK_VOXELS + 5] = 7.0; // component 1, local voxel 5
    let v = g.brick_coords(full).map(|c| c * 16);
    assert_eq!(occ.value([v[0] + 5, v[1], v[2]], 1), 7.0);
    assert_eq!(occ.value([v[0] + 5, v[1], v[2]], 0), 0.0);
    assert_eq!(occ.value([1000, 0, 0], 1), 0.0);
    occ.flush().expect("flush");
    drop(occ);

    let reopened = store.open_field("source", 2, Coverage::Occupied).expect("open");
    assert_eq!(reopened.value([v[0] + 5, v[1], v[2]], 1), 7.0);
    let err = store.open_field("source", 3, Coverage::Occupied).err().expect("wrong shape").to_string();
    assert!(err.contains("source.field"), "{err}");
    assert!(store.open_field("missing", 1, Coverage::Dense).is_err());
    assert!(store.create_field("../escape", 1, Coverage::Dense).is_err());

    let mut copy = store.create_field("copy", 2, Coverage::Occupied).expect("field");
    copy.copy_from(&reopened).expect("same shape");
    assert_eq!(copy.as_slice(), reopened.as_slice());
    copy.fill_zero().unwrap();
    assert!(copy.as_slice().iter().all(|&v| v == 0.0));

    let mut dense = store.create_field("fluence", 1, Coverage::Dense).expect("dense");
    assert_eq!(dense.as_slice().len(), g.brick_count() * BRICK_VOXELS);
    assert!(dense.brick_mut(empty).is_some());
    assert!(dense.copy_from(&reopened).is_err());
    // Creating again truncates to zeros.
    let again = store.create_field("source", 2, Coverage::Occupied).expect("recreate");
    assert!(again.as_slice().iter().all(|&v| v == 0.0));
}

#[test]
fn export_field_layout_json_and_nhdr() {
    let dir = test_dir("export");
    let store = BrickStore::create_with(&dir.join("store"), DIMS, 0.5, fill_from(corner_density)).expect("create");
    let g = *store.grid();
    let value = |v: [u32; 3], c: u32| (v[0] + 100 * v[1] + 10_000 * v[2]) as f32 + 0.25 * c as f32;
    let mut f = store.create_field("fluence", 3, Coverage::Occupied).expect("field");
    for b in 0..g.brick_count() {
        let o = g.brick_coords(b).map(|c| c * 16);
        if let Some(data) = f.brick_mut(b) {
            for c in 0..3u32 {
                for l in 0..BRICK_VOXELS as u32 {
                    let v = [o[0] + l % 16, o[1] + (l / 16) % 16, o[2] + l / 256];
                    data[(c * 4096 + l) as usize] = value(v, c);
                }
            }
        }
    }
    let out = dir.join("out");
    fs::create_dir_all(&out).expect("out dir");
    let meta = FieldMeta {
        quantity: "fluence".into(),
        units: "W/m^2".into(),
        components: vec!["r".into(), "g".into(), "b".into()],
        description: "test".into(),
        origin: [-2.0, 1.0, 0.5],
    };
    export_field(&f, &store, &out, "fluence", &meta, EmptyBricks::NotSolved).expect("export");
    let (info, data) = read_raw_field(&out, "fluence").expect("read back");
    assert_eq!(info.dims, DIMS);
    assert_eq!(info.components, 3);
    assert_eq!(info.file, "fluence.raw");
    assert_eq!(info.voxel_size, 0.5);
    assert_eq!(data.len(), g.voxel_count() as usize * 3);
    for z in 0..DIMS[2] {
        for y in 0..DIMS[1] {
            for x in 0..DIMS[0] {
                let occupied = store.slot(g.locate([x, y, z]).0).is_some();
                for c in 0..3 {
                    let i = c as usize + 3 * (x + DIMS[0] * (y + DIMS[1] * z)) as usize;
                    if occupied {
                        assert_eq!(data[i], value([x, y, z], c), "voxel ({x}, {y}, {z}) component {c}");
                    } else {
                        assert!(data[i].is_nan(), "voxel ({x}, {y}, {z}) of an empty brick must read as not solved");
                    }
                }
            }
        }
    }
    let nhdr = fs::read_to_string(out.join("fluence.nhdr")).expect("nhdr");
    for line in [
        "NRRD0004",
        "type: float",
        "dimension: 4",
        "sizes: 3 37 20 53",
        "space dimension: 3",
        "space directions: none (0.5,0,0) (0,0.5,0) (0,0,0.5)",
        // NRRD's origin is the first voxel's centre: the corner plus half a voxel.
        "space origin: (-1.75,1.25,0.75)",
        "kinds: vector domain domain domain",
        "endian: little",
        "encoding: raw",
        "data file: fluence.raw",
    ] {
        assert!(nhdr.lines().any(|l| l == line), "missing {line:?} in\n{nhdr}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(out.join("fluence.json")).expect("json")).expect("valid");
    assert_eq!(json["dtype"], "f32");
    assert_eq!(json["layout"], "component fastest, then x, then y, then z");
    assert_eq!(json["component_names"][2], "b");
    assert_eq!(json["not_solved"], lpm::output::NOT_SOLVED);
    assert_eq!(json["origin"], serde_json::json!([-2.0, 1.0, 0.5]), "the json gives the corner");

    // The same field with empty bricks as zeros (a source): no NaN, no note.
    export_field(&f, &store, &out, "source", &meta, EmptyBricks::Zero).expect("export");
    let (info, data) = read_raw_field(&out, "source").expect("read back");
    assert!(info.not_solved.is_none());
    assert!(data.iter().all(|v| v.is_finite()) && data.contains(&0.0));

    // One component: a 3-D NRRD.
    let one = store.create_field("phi", 1, Coverage::Dense).expect("field");
    let meta1 = FieldMeta { components: vec!["grey".into()], ..meta.clone() };
    export_field(&one, &store, &out, "phi", &meta1, EmptyBricks::NotSolved).expect("export");
    let nhdr = fs::read_to_string(out.join("phi.nhdr")).expect("nhdr");
    assert!(nhdr.contains("dimension: 3\n") && nhdr.contains("sizes: 37 20 53\n"), "{nhdr}");
    assert!(nhdr.contains("space directions: (0.5,0,0) (0,0.5,0) (0,0,0.5)\n"), "{nhdr}");
    // lpm's own NRRD reader places the exported field where it was.
    let back = lpm::store::nrrd_input::nrrd_header(&out.join("phi.nhdr")).expect("read the exported header");
    assert_eq!((back.voxel_size, back.corner), (Some(0.5), Some([-2.0, 1.0, 0.5])));
    // Names that do not match the components are refused.
    assert!(export_field(&one, &store, &out, "bad", &meta, EmptyBricks::Zero).is_err());

    // A raw whose size disagrees with its json is refused.
    fs::write(out.join("phi.raw"), [0u8; 8]).expect("clobber");
    let err = read_raw_field(&out, "phi").expect_err("must fail").to_string();
    assert!(err.contains("phi.raw"), "{err}");
    assert_eq!(read_field_json(&out.join("phi.json")).expect("json").components, 1);
}

#[test]
fn write_atomic_leaves_nothing_half_written() {
    let dir = test_dir("atomic");
    let path = dir.join("result.json");
    write_json_atomic(&path, &serde_json::json!({"a": 1})).expect("write");
    let before = fs::read_to_string(&path).expect("read");
    let err = write_atomic(&path, |w| {
        w.write_all(b"partial")?;
        Err(std::io::Error::other("boom"))
    })
    .expect_err("must fail")
    .to_string();
    assert!(err.contains("result.json") && err.contains("boom"), "{err}");
    assert_eq!(fs::read_to_string(&path).expect("read"), before);
    let names: Vec<_> = fs::read_dir(&*dir).expect("dir").map(|e| e.expect("entry").file_name()).collect();
    assert_eq!(names, vec![std::ffi::OsString::from("result.json")]);
}

/// Issue 13, defect 2: a raw file that shrinks while lpm reads it is an error naming it, not a
/// SIGBUS (the importer reads with `pread`, never through a memory map).
#[test]
fn a_raw_file_truncated_while_read_is_an_error_not_a_signal() {
    let dir = test_dir("raw-shrinks");
    let dims = [20u32, 20, 20];
    let path = dir.join("shrinks.raw");
    write_raw(&path, &vec![1.0; 8000]);
    let Ok(raw) = raw_density(&path, dims) else { panic!("a whole file opens") };
    // Another program truncates the file after it was opened and checked.
    std::fs::OpenOptions::new().write(true).open(&path).unwrap().set_len(100).unwrap();
    let mut out = vec![0f32; 4096];
    let err = raw.fill_brick([1, 1, 1], &mut out).expect_err("the shrunk file must be an error").to_string();
    assert!(err.contains("shrinks.raw"), "{err}");
}

/// Issue 13, defect 7: a symlink planted in the output directory under any name lpm might use for a
/// temporary never redirects a write: the target outside stays untouched and the output is complete.
#[test]
fn a_planted_symlink_never_redirects_an_atomic_write() {
    let dir = test_dir("planted-symlink");
    let victim = dir.join("victim.txt");
    std::fs::write(&victim, b"precious").unwrap();
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    // The old predictable name (`<name>.tmp-<pid>`) and the final name's neighbours.
    for name in [format!("report.json.tmp-{}", std::process::id()), "report.json.tmp".to_string()] {
        std::os::unix::fs::symlink(&victim, out.join(name)).unwrap();
    }
    lpm::output::write_atomic(&out.join("report.json"), |w| std::io::Write::write_all(w, b"{}")).unwrap();
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
    assert_eq!(std::fs::read(out.join("report.json")).unwrap(), b"{}");
}
