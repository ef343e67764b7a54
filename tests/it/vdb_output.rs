//! `fluence.vdb` and `source.vdb`, read back by the reference implementation: tests/vdb/read_vdb.py
//! reads them with OpenVDB's Python module (Debian's python3-openvdb, installed by tools/setup.sh)
//! and dumps every voxel of a box around the volume, with its active state. The grids must hold
//! exactly the values of `fluence.raw` / `source.raw` (bitwise for float, rounded to half for
//! half), be active exactly where the volume was solved (no leaves in empty bricks), and lie where
//! the volume lies: on the input VDB's own index grid and transform, or at `origin` with voxel size
//! `h`.

use crate::common::{temp_dir, write_scene};
use lpm::job::SolveJob;
use lpm::output::VdbPrecision;
use lpm::solver::BackendKind;
use serde_json::Value;
use std::path::{Path, PathBuf};

fn solve(scene: PathBuf, out: &Path, precision: VdbPrecision) -> lpm::job::Report {
    let job = SolveJob {
        backend: BackendKind::Cpu,
        no_image: true,
        vdb_precision: precision,
        no_render_data: true,
        ..SolveJob::new(scene, out.to_path_buf())
    };
    lpm::job::run(&job, |_, _| {}).expect("solve")
}

fn python(args: &[&str]) {
    // /usr/bin/python3 explicitly: a python3 earlier on PATH may lack the module.
    let out = std::process::Command::new("/usr/bin/python3")
        .args(args)
        .output()
        .expect("run /usr/bin/python3 (install python3-openvdb: tools/setup.sh)");
    assert!(
        out.status.success(),
        "python failed (is python3-openvdb installed? tools/setup.sh installs it):\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// What OpenVDB reads from `vdb` over the index box `lo .. lo + n`: the json summary and, per
/// grid, (values, active flags), x fastest.
struct Read {
    info: Value,
    prefix: PathBuf,
}

impl Read {
    fn new(vdb: &Path, lo: [i32; 3], n: [u32; 3]) -> Read {
        let prefix = vdb.with_extension("openvdb");
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/vdb/read_vdb.py");
        let mut args =
            vec![script.to_str().unwrap().to_string(), vdb.to_str().unwrap().into(), prefix.to_str().unwrap().into()];
        args.extend(lo.iter().map(|v| v.to_string()));
        args.extend(n.iter().map(|v| v.to_string()));
        python(&args.iter().map(String::as_str).collect::<Vec<_>>());
        let info = serde_json::from_str(&std::fs::read_to_string(prefix.with_extension("openvdb.json")).unwrap())
            .expect("json");
        Read { info, prefix }
    }

    fn grid(&self, name: &str) -> (Vec<f32>, Vec<u8>) {
        let p = |ext: &str| PathBuf::from(format!("{}.{name}.{ext}", self.prefix.display()));
        let bytes = std::fs::read(p("raw")).expect("values");
        let values = bytes.chunks(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        (values, std::fs::read(p("active")).expect("active"))
    }
}

fn raw(path: &Path) -> Vec<f32> {
    std::fs::read(path).unwrap().chunks(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
}

/// Checks grid `name` (component `c` of `components` of the raw export over `dims`), read over
/// the box `dims + 2` around the volume starting one voxel before it, against `raw`.
fn check_grid(read: &Read, name: &str, raw: &[f32], c: usize, components: usize, dims: [u32; 3], half: bool) -> usize {
    let (values, active) = read.grid(name);
    let e = &read.info[name];
    assert_eq!(e["type"], "float", "{name}");
    assert_eq!(e["half"], half, "{name}");
    assert_eq!(e["class"], "fog volume", "{name}");
    let n = dims.map(|d| d as usize + 2);
    let mut solved = 0;
    for z in 0..n[2] {
        for y in 0..n[1] {
            for x in 0..n[0] {
                let k = x + n[0] * (y + n[1] * z);
                let inside = (1..=dims[0] as usize).contains(&x)
                    && (1..=dims[1] as usize).contains(&y)
                    && (1..=dims[2] as usize).contains(&z);
                let want = if inside {
                    let v = [x - 1, y - 1, z - 1];
                    raw[c + components * (v[0] + dims[0] as usize * (v[1] + dims[1] as usize * v[2]))]
                } else {
                    f32::NAN
                };
                if want.is_nan() {
                    // Unsolved (an empty brick) or outside the volume: no voxel there.
                    assert_eq!((active[k], values[k]), (0, 0.0), "{name}: voxel {:?} should be inactive", [x, y, z]);
                } else {
                    let want = if half { half::f16::from_f32(want).to_f32() } else { want };
                    assert_eq!(active[k], 1, "{name}: voxel {:?} should be active", [x, y, z]);
                    assert_eq!(
                        values[k].to_bits(),
                        want.to_bits(),
                        "{name}: voxel {:?}: {} against {want}",
                        [x, y, z],
                        values[k]
                    );
                    solved += 1;
                }
            }
        }
    }
    assert_eq!(e["active"].as_u64().unwrap() as usize, solved, "{name}: active count");
    solved
}

/// An RGB solve of a sphere with empty bricks, a volume not a multiple of 16 and an origin: three
/// float grids per file (fluence_r/g/b, source_r/g/b), equal to the raw exports voxel for voxel,
/// active exactly where the fluence was solved, placed at `origin` with voxel size `h`.
#[test]
fn float_grids_equal_the_raw_exports_in_openvdb() {
    let dir = temp_dir("vdb-out-float");
    let dims = [40u32, 20, 24];
    let scene = write_scene(
        &dir,
        "[volume]\nprocedural = \"sphere\"\ndims = [40, 20, 24]\nvoxel_size = 0.5\norigin = [1.5, -2.0, 0.25]\n\
         [medium]\nsigma_t = [1.0, 0.8, 0.6]\nalbedo = 0.8\n[[lights]]\nkind = \"sky\"\nradiance = 1.0\n\
         [[lights]]\nkind = \"sun\"\ndirection = [0.3, 1.0, 0.2]\nirradiance = 2.0\n[solver]\ndirections_per_face = 2\nmax_orders = 4\n",
    );
    let out = dir.join("out");
    let report = solve(scene, &out, VdbPrecision::Float);
    assert!(report.outputs.contains(&"fluence.vdb".to_string()) && report.outputs.contains(&"source.vdb".to_string()));
    assert!(report.plan.bricks_empty > 0, "the test needs empty bricks");
    let fluence = raw(&out.join("fluence.raw"));
    assert!(fluence.iter().any(|v| v.is_nan()), "empty bricks export as NaN");
    let read = Read::new(&out.join("fluence.vdb"), [-1; 3], dims.map(|d| d + 2));
    let mut solved = 0;
    for (c, ch) in ["r", "g", "b"].iter().enumerate() {
        solved = check_grid(&read, &format!("fluence_{ch}"), &fluence, c, 3, dims, false);
    }
    assert_eq!(solved, fluence.iter().filter(|v| !v.is_nan()).count() / 3);
    let e = &read.info["fluence_r"];
    for a in 0..3 {
        let want = [1.5, -2.0, 0.25][a] + 0.25;
        assert!((e["index0_world"][a].as_f64().unwrap() - want).abs() < 1e-12, "{e}");
        assert!((e["index1_world"][a].as_f64().unwrap() - want - 0.5).abs() < 1e-12, "{e}");
    }
    assert_eq!(e["bbox_min"], serde_json::json!([0, 0, 0]));
    assert!(e["lpm_quantity"].as_str().unwrap().starts_with("fluence"), "{e}");

    // The source: zero (not NaN) in empty bricks, but those bricks are not stored either.
    let source = raw(&out.join("source.raw"));
    let masked: Vec<f32> =
        source.iter().zip(fluence.iter()).map(|(&s, &f)| if f.is_nan() { f32::NAN } else { s }).collect();
    let read = Read::new(&out.join("source.vdb"), [-1; 3], dims.map(|d| d + 2));
    for (c, ch) in ["r", "g", "b"].iter().enumerate() {
        check_grid(&read, &format!("source_{ch}"), &masked, c, 3, dims, false);
    }
}

/// A VDB input at negative index coordinates with its own transform, exported in half precision:
/// one grid per file (grey), on the input's index grid (same active box corner, same transform),
/// values rounded to half as OpenVDB rounds them.
#[test]
fn half_grids_lie_on_the_input_vdb_grid_in_openvdb() {
    let dir = temp_dir("vdb-out-half");
    let input = dir.join("smoke.vdb");
    python(&[
        "-c",
        &format!(
            "import numpy as np, pyopenvdb as vdb\n\
             n = (21, 18, 19)\n\
             x, y, z = np.meshgrid(*(np.linspace(-1, 1, k) for k in n), indexing='ij')\n\
             a = np.clip(1 - (x*x + y*y + z*z), 0, None).astype(np.float32)\n\
             g = vdb.FloatGrid(); g.name = 'density'\n\
             g.copyFromArray(a, ijk=(-37, 5, -9), tolerance=0.0)\n\
             g.transform = vdb.createLinearTransform(voxelSize=0.2)\n\
             g.transform.translate((0.3, -1.1, 2.0))\n\
             vdb.write('{}', grids=[g])\n",
            input.display()
        ),
    ]);
    let scene = write_scene(
        &dir,
        "[volume]\nvdb = \"smoke.vdb\"\n[medium]\nsigma_t = 5.0\nalbedo = 0.9\n[[lights]]\nkind = \"sky\"\nradiance = 1.0\n\
         [solver]\ndirections_per_face = 2\nmax_orders = 4\n",
    );
    let out = dir.join("out");
    let report = solve(scene, &out, VdbPrecision::Half);
    let dims = report.plan.dims;
    let input_info = {
        // The input's active box and transform, as OpenVDB reads them.
        let r = Read::new(&input, [0; 3], [1, 1, 1]);
        r.info["density"].clone()
    };
    let lo: [i32; 3] = std::array::from_fn(|a| input_info["bbox_min"][a].as_i64().unwrap() as i32);
    assert_eq!(
        dims.map(|d| d as i64),
        std::array::from_fn(|a| input_info["bbox_max"][a].as_i64().unwrap() - lo[a] as i64 + 1)
    );
    let fluence = raw(&out.join("fluence.raw"));
    let read = Read::new(&out.join("fluence.vdb"), lo.map(|v| v - 1), dims.map(|d| d + 2));
    check_grid(&read, "fluence", &fluence, 0, 1, dims, true);
    let e = &read.info["fluence"];
    assert_eq!(e["bbox_min"], input_info["bbox_min"]);
    for key in ["index0_world", "index1_world"] {
        for a in 0..3 {
            let (got, want) = (e[key][a].as_f64().unwrap(), input_info[key][a].as_f64().unwrap());
            assert!((got - want).abs() < 1e-12, "{key}: {got} against the input's {want}");
        }
    }
    let source = raw(&out.join("source.raw"));
    let read = Read::new(&out.join("source.vdb"), lo.map(|v| v - 1), dims.map(|d| d + 2));
    let masked: Vec<f32> =
        source.iter().zip(fluence.iter()).map(|(&s, &f)| if f.is_nan() { f32::NAN } else { s }).collect();
    check_grid(&read, "source", &masked, 0, 1, dims, true);
}
