//! NanoVDB input against independent writers: OpenVDB's Python module (python3-openvdb) writes a
//! `.vdb`, NanoVDB's own converter (`nanovdb_convert`, Debian's libnanovdb-tools, installed by
//! tools/setup.sh) turns it into a `.nvdb`, and lpm's NanoVDB reader must give the same grid as its
//! OpenVDB reader (itself checked against OpenVDB in vdb_input.rs): bounding box, transform and
//! every voxel bitwise; a scene naming the `.nvdb` solves to bitwise the fluence of the `.vdb`; and
//! files it cannot read (truncated, quantised, compressed) are clear errors, never panics.

use crate::common::{temp_dir, write_scene_as};
use lpm::job::SolveJob;
use lpm::solver::BackendKind;
use lpm::store::nanovdb::read_nanovdb_bytes;
use lpm::store::vdb::VdbReader;
use std::path::{Path, PathBuf};
use std::process::Command;

fn err(r: Result<lpm::store::vdb::VdbGrid, lpm::store::vdb::VdbError>) -> String {
    match r {
        Ok(g) => panic!("grid {} read, an error was expected", g.name),
        Err(e) => e.to_string(),
    }
}

fn run(cmd: &mut Command, what: &str) {
    let out = cmd.output().unwrap_or_else(|e| panic!("{what}: cannot run ({e}); tools/setup.sh installs it"));
    assert!(out.status.success(), "{what} failed:\n{}", String::from_utf8_lossy(&out.stderr));
}

/// smoke.vdb (OpenVDB) with a blob at negative coordinates, an 8³ and a 128³ active tile, a
/// second grid and a transform; smoke.nvdb converted from it by nanovdb_convert.
fn files(name: &str) -> PathBuf {
    let dir = temp_dir(name);
    let vdb = dir.join("smoke.vdb");
    let script = format!(
        "import numpy as np, pyopenvdb as vdb\n\
         n = (29, 21, 25)\n\
         x, y, z = np.meshgrid(*(np.linspace(-1, 1, k) for k in n), indexing='ij')\n\
         r2 = x*x + y*y + z*z\n\
         a = (np.clip(1 - r2, 0, None) * (1 + 0.3*np.sin(7*x + 3*y))).astype(np.float32)\n\
         g = vdb.FloatGrid(); g.name = 'density'\n\
         g.copyFromArray(a, ijk=(-37, 5, -9), tolerance=0.0)\n\
         g.fill((-64, 40, -16), (-57, 47, -9), 0.75, True)\n\
         g.fill((128, 0, 0), (255, 127, 127), 0.25, True)\n\
         g.transform = vdb.createLinearTransform(voxelSize=0.2)\n\
         g.transform.translate((0.3, -1.1, 2.0))\n\
         t = vdb.FloatGrid(); t.name = 'temperature'\n\
         t.copyFromArray((a * 900).astype(np.float32), ijk=(-37, 5, -9), tolerance=0.0)\n\
         t.transform = g.transform\n\
         vdb.write('{}', grids=[g, t])\n",
        vdb.display()
    );
    // /usr/bin/python3 explicitly: a python3 earlier on PATH may lack the module.
    run(Command::new("/usr/bin/python3").args(["-c", &script]), "python3-openvdb");
    run(Command::new("nanovdb_convert").arg("-f").arg(&vdb).arg(dir.join("smoke.nvdb")), "nanovdb_convert");
    dir
}

#[test]
fn nanovdb_converted_by_nanovdb_convert_reads_like_the_vdb_it_came_from() {
    let dir = files("nvdb-read");
    let nvdb = std::fs::read(dir.join("smoke.nvdb")).unwrap();
    for grid in ["density", "temperature"] {
        let mut r =
            VdbReader::new(std::io::BufReader::new(std::fs::File::open(dir.join("smoke.vdb")).unwrap())).unwrap();
        let want = r.read_grid(grid, true).unwrap();
        let got = read_nanovdb_bytes(&nvdb, grid).unwrap_or_else(|e| panic!("{grid}: {e}"));
        assert_eq!(got.name, grid);
        assert!(!got.half);
        assert_eq!(got.placement, want.placement, "{grid}: transform");
        assert_eq!(got.tree.background, want.tree.background);
        let [lo, hi] = want.tree.active_bbox().expect("active voxels");
        assert_eq!(got.tree.active_bbox(), Some([lo, hi]), "{grid}: active box");
        let mut checked = 0u64;
        for x in lo[0] - 1..=hi[0] + 1 {
            for y in lo[1] - 1..=hi[1] + 1 {
                for z in lo[2] - 1..=hi[2] + 1 {
                    let p = [x, y, z].map(|v| v as i32);
                    let (a, b) = (got.tree.value(p), want.tree.value(p));
                    assert!(a.to_bits() == b.to_bits(), "{grid}: voxel {p:?} is {a} in the .nvdb, {b} in the .vdb");
                    checked += 1;
                }
            }
        }
        if grid == "density" {
            assert!(checked > 2_000_000, "the box includes the 128³ tile: {checked}");
        }
    }
    let e = err(read_nanovdb_bytes(&nvdb, "flame"));
    assert!(e.contains("\"density\", \"temperature\""), "{e}");
}

fn solve(scene: PathBuf, out: &Path) -> Vec<u8> {
    let job = SolveJob {
        backend: BackendKind::Cpu,
        no_image: true,
        no_render_data: true,
        ..SolveJob::new(scene, out.to_path_buf())
    };
    lpm::job::run(&job, |_, _| {}).expect("solve");
    std::fs::read(out.join("fluence.raw")).unwrap()
}

/// The same volume named as `.nvdb` (by `nvdb` or by `vdb`) and as `.vdb` solves to bitwise the
/// same fluence, placed the same way. (Only the 29×21×25 blob grid: the tiles make the box large.)
#[test]
fn a_nanovdb_scene_solves_like_its_vdb() {
    let dir = temp_dir("nvdb-solve");
    let vdb = dir.join("blob.vdb");
    let script = format!(
        "import numpy as np, pyopenvdb as vdb\n\
         n = (21, 18, 19)\n\
         x, y, z = np.meshgrid(*(np.linspace(-1, 1, k) for k in n), indexing='ij')\n\
         g = vdb.FloatGrid(); g.name = 'density'\n\
         g.copyFromArray(np.clip(1 - (x*x + y*y + z*z), 0, None).astype(np.float32), ijk=(-7, 3, 40), tolerance=0.0)\n\
         g.transform = vdb.createLinearTransform(voxelSize=0.25)\n\
         vdb.write('{}', grids=[g])\n",
        vdb.display()
    );
    run(Command::new("/usr/bin/python3").args(["-c", &script]), "python3-openvdb");
    run(Command::new("nanovdb_convert").arg("-f").arg(&vdb).arg(dir.join("blob.nvdb")), "nanovdb_convert");
    let body = "[medium]\nsigma_t = 6.0\nalbedo = 0.9\n[[lights]]\nkind = \"sun\"\ndirection = [0.3, 1.0, 0.2]\nirradiance = 2.0\n\
                [solver]\ndirections_per_face = 2\nmax_orders = 5\n";
    let scene = |name: &str, volume: &str| write_scene_as(&dir, name, &format!("[volume]\n{volume}\n{body}"));
    let from_vdb = solve(scene("a.toml", "vdb = \"blob.vdb\""), &dir.join("a"));
    let from_nvdb = solve(scene("b.toml", "nvdb = \"blob.nvdb\""), &dir.join("b"));
    let by_vdb_key = solve(scene("c.toml", "vdb = \"blob.nvdb\""), &dir.join("c"));
    assert!(from_vdb.len() > 4000 * 4, "{} bytes", from_vdb.len());
    assert!(from_nvdb == from_vdb, "the .nvdb solves to a different fluence");
    assert!(by_vdb_key == from_vdb);
    let a = lpm::scene::Scene::load(&dir.join("a.toml")).unwrap();
    let b = lpm::scene::Scene::load(&dir.join("b.toml")).unwrap();
    assert_eq!(
        (a.volume.dims, a.volume.voxel_size, a.volume.origin),
        (b.volume.dims, b.volume.voxel_size, b.volume.origin)
    );
    let e = lpm::scene::Scene::load(&write_scene_as(
        &dir,
        "both.toml",
        &format!("[volume]\nvdb = \"blob.vdb\"\nnvdb = \"blob.nvdb\"\n{body}"),
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("volume.nvdb") && e.contains("not both"), "{e}");
}

/// Truncated at any point, with flipped bytes, quantised (`--fp16`) or compressed (`-z`): an error
/// that says what, never a panic.
#[test]
fn unreadable_nanovdb_files_are_clear_errors() {
    let dir = files("nvdb-bad");
    let good = std::fs::read(dir.join("smoke.nvdb")).unwrap();
    let step = (good.len() / 97).max(1);
    for cut in (0..good.len()).step_by(step) {
        let e = err(read_nanovdb_bytes(&good[..cut], "density"));
        assert!(e.contains("truncated") || e.contains("magic"), "cut at {cut}: {e}");
    }
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    for _ in 0..300 {
        let mut bad = good.clone();
        for _ in 0..4 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let i = (state % bad.len() as u64) as usize;
            bad[i] ^= (state >> 32) as u8 | 1;
        }
        let _ = read_nanovdb_bytes(&bad, "density"); // Ok or Err, never a panic
    }
    run(
        Command::new("nanovdb_convert").args(["-f", "--fp16"]).arg(dir.join("smoke.vdb")).arg(dir.join("q.nvdb")),
        "nanovdb_convert",
    );
    let e = err(read_nanovdb_bytes(&std::fs::read(dir.join("q.nvdb")).unwrap(), "density"));
    assert!(e.contains("grid type") && e.contains("Float"), "{e}");
    run(
        Command::new("nanovdb_convert").args(["-f", "-z"]).arg(dir.join("smoke.vdb")).arg(dir.join("z.nvdb")),
        "nanovdb_convert",
    );
    let e = err(read_nanovdb_bytes(&std::fs::read(dir.join("z.nvdb")).unwrap(), "density"));
    assert!(e.contains("compressed") && e.contains("zip"), "{e}");
}

/// Issue 35 item 4: a NanoVDB grid says how large it is in its file metadata (active voxels and
/// their bounding box), its tree (node, tile and voxel counts) and its root (bounding box); a few
/// changed bytes — a mask word of a 32³ node turning 32 empty 128³ tiles active, a leaf's mask, a
/// bounding box — made it describe another volume (a 644 KB file became a 767 × 2687 × 3968
/// volume), which was then solved, or its memory and disk claimed, as if it were the file's. Every
/// claim must agree with what the nodes hold; a grid converted without statistics (no bounding
/// box) still reads.
#[test]
fn a_nanovdb_grid_whose_claimed_size_disagrees_with_its_nodes_is_refused() {
    let dir = files("nvdb-claims");
    let good = std::fs::read(dir.join("smoke.nvdb")).unwrap();
    let sound = read_nanovdb_bytes(&good, "density").expect("the sound file reads");
    let [_, hi] = sound.tree.active_bbox().unwrap();
    let word = |at: usize| u64::from_le_bytes(good[at..at + 8].try_into().unwrap()) as usize;
    // The first grid ("density"): its metadata after the 16-byte segment header, then its name,
    // then its buffer: GridData (672 bytes), TreeData (node offsets from it), the nodes.
    let meta = 16;
    let name_size = u32::from_le_bytes(good[meta + 136..meta + 140].try_into().unwrap()) as usize;
    let tree = meta + 176 + name_size + 672;
    let (leaf, upper, root) = (tree + word(tree), tree + word(tree + 16), tree + word(tree + 24));
    let plus = |at: usize, by: i64| (i64::from(i32::from_le_bytes(good[at..at + 4].try_into().unwrap())) + by) as i32;
    let voxels = word(meta + 24) as u32;
    for (what, at, bytes, expect) in [
        ("a 32³ node's value mask", upper + 32 + 8 * 300 + 4, [0xff; 4], "active tiles"),
        ("a leaf's value mask", leaf + 16, [0xff; 4], "active voxels"),
        ("the root's bounding box", root + 12, plus(root + 12, 4096).to_le_bytes(), "bounding box"),
        ("the metadata's bounding box", meta + 88 + 16, (hi[1] as i32 + 2687).to_le_bytes(), "bounding box"),
        ("the metadata's voxel count", meta + 24, (voxels + 1).to_le_bytes(), "active voxels"),
    ] {
        let mut bad = good.clone();
        bad[at..at + 4].copy_from_slice(&bytes);
        assert_ne!(bad, good, "{what}: the bytes changed");
        let e = err(read_nanovdb_bytes(&bad, "density"));
        assert!(e.contains(expect) && e.contains("corrupt"), "{what}: {e}");
    }
    // Without statistics (`-s none`) the bounding boxes are NanoVDB's empty box: not a claim.
    run(
        Command::new("nanovdb_convert").args(["-f", "-s", "none"]).arg(dir.join("smoke.vdb")).arg(dir.join("n.nvdb")),
        "nanovdb_convert",
    );
    let plain = read_nanovdb_bytes(&std::fs::read(dir.join("n.nvdb")).unwrap(), "density").expect("-s none reads");
    assert_eq!(plain.tree.active_bbox(), sound.tree.active_bbox());
}

/// Issue 35 item 8: reading a VDB or NanoVDB grid (seconds for a large one) looks at the cancel
/// flag at every read of the file: raised, the read stops as a cancellation, not as an error.
#[test]
fn reading_a_vdb_or_nanovdb_grid_stops_once_cancelled() {
    let dir = files("nvdb-cancel");
    for file in ["smoke.vdb", "smoke.nvdb"] {
        let path = dir.join(file);
        let info = lpm::store::vdb::vdb_info(&path, "density").unwrap();
        let dims = info.dims.map(|d| d as u32);
        let flag = lpm::solver::cancel::CancelFlag::new();
        let read = |flag| lpm::store::vdb::vdb_density_until(&path, "density", dims, info.index_min, Some(flag));
        assert!(read(flag).is_ok(), "{file}");
        flag.raise();
        match read(flag) {
            Err(lpm::store::StoreError::Cancelled) => {}
            Err(e) => panic!("{file}: {e}"),
            Ok(_) => panic!("{file}: read whole after the flag was raised"),
        }
    }
}
