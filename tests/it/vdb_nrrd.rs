//! NRRD input (`[volume] nrrd = …`): headers written here by hand from the NRRD format description
//! (teem's format spec), data raw or gzip (flate2's encoder), float / double / uchar / ushort,
//! little and big endian, detached (`.nhdr`) and attached (`.nrrd`). The store must hold exactly
//! the samples, the geometry must come from the header, bad headers and short data must be clear
//! errors naming the file and the field, and a solve must match the same density given as raw.

use crate::common::temp_dir;
use lpm::scene::Scene;
use lpm::solver::BackendKind;
use std::io::Write;
use std::path::{Path, PathBuf};

const DIMS: [u32; 3] = [19, 12, 23];

fn density([x, y, z]: [u32; 3]) -> f32 {
    let r2 = [x as f32 - 9.0, y as f32 - 6.0, z as f32 - 11.0].iter().map(|d| d * d).sum::<f32>();
    (1.0 - r2 / 80.0).max(0.0) * 3.0 + if (x + y + z) % 7 == 0 { 0.25 } else { 0.0 }
}

fn samples() -> Vec<f32> {
    let mut v = Vec::new();
    for z in 0..DIMS[2] {
        for y in 0..DIMS[1] {
            for x in 0..DIMS[0] {
                v.push(density([x, y, z]));
            }
        }
    }
    v
}

fn gzip(data: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(data).unwrap();
    e.finish().unwrap()
}

fn scene(dir: &Path, name: &str, volume: &str) -> Result<Scene, lpm::scene::SceneError> {
    let path = dir.join(format!("{name}.toml"));
    let text = format!(
        "[volume]\n{volume}\n\n[medium]\nsigma_t = 1.5\nalbedo = 0.8\n\n[[lights]]\nkind = \"sky\"\nradiance = 1.0\n\n\
         [[lights]]\nkind = \"sun\"\ndirection = [0.3, 1.0, 0.2]\nirradiance = 2.0\n\n\
         [solver]\ndirections_per_face = 2\nmax_orders = 6\ntolerance = 1e-3\n"
    );
    std::fs::write(&path, text).unwrap();
    Scene::load(&path)
}

fn header(fields: &str) -> String {
    format!(
        "NRRD0004\n# written by hand for lpm's tests\ndimension: 3\nsizes: {} {} {}\n{fields}",
        DIMS[0], DIMS[1], DIMS[2]
    )
}

fn store_values(scene: &Scene, dir: &Path) -> Vec<f32> {
    let store = lpm::solver::build_store(scene, dir).expect("store");
    let mut v = Vec::new();
    for z in 0..DIMS[2] {
        for y in 0..DIMS[1] {
            for x in 0..DIMS[0] {
                v.push(store.density_at([x, y, z]));
            }
        }
    }
    v
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn every_type_encoding_and_layout_reads_the_samples() {
    let dir = temp_dir("nrrd-types");
    let s = samples();
    let f32_le: Vec<u8> = s.iter().flat_map(|v| v.to_le_bytes()).collect();
    let f32_be: Vec<u8> = s.iter().flat_map(|v| v.to_be_bytes()).collect();
    let f64_le: Vec<u8> = s.iter().flat_map(|v| (*v as f64).to_le_bytes()).collect();
    let u8s: Vec<u8> = s.iter().map(|v| (v * 50.0) as u8).collect();
    let u16_be: Vec<u8> = s.iter().flat_map(|v| ((v * 1000.0) as u16).to_be_bytes()).collect();
    let as_f32 = |v: &[f32], f: &dyn Fn(f32) -> f32| v.iter().map(|x| f(*x)).collect::<Vec<f32>>();

    // (name, header fields, data, attached, expected samples)
    type Case<'a> = (&'a str, String, Vec<u8>, bool, Vec<f32>);
    let cases: Vec<Case> = vec![
        ("float_raw", "type: float\nendian: little\nencoding: raw\n".into(), f32_le.clone(), false, s.clone()),
        ("float_big_gzip", "type: float\nendian: big\nencoding: gzip\n".into(), gzip(&f32_be), false, s.clone()),
        ("double_attached", "type: double\nendian: little\nencoding: raw\n".into(), f64_le, true, s.clone()),
        (
            "uchar_gzip_attached",
            "type: uchar\nencoding: gzip\n".into(),
            gzip(&u8s),
            true,
            as_f32(&s, &|v| ((v * 50.0) as u8) as f32),
        ),
        (
            "ushort_big_skip",
            "type: unsigned short\nendian: big\nencoding: raw\nbyte skip: 5\n".into(),
            [vec![7u8; 5], u16_be].concat(),
            false,
            as_f32(&s, &|v| ((v * 1000.0) as u16) as f32),
        ),
    ];
    for (name, fields, data, attached, want) in cases {
        let (file, text) = if attached {
            let p = dir.join(format!("{name}.nrrd"));
            let mut bytes = header(&fields).into_bytes();
            bytes.push(b'\n');
            bytes.extend_from_slice(&data);
            std::fs::write(&p, bytes).unwrap();
            (p, format!("nrrd = \"{name}.nrrd\""))
        } else {
            std::fs::write(dir.join(format!("{name}.data")), &data).unwrap();
            let p = dir.join(format!("{name}.nhdr"));
            std::fs::write(&p, header(&format!("{fields}data file: {name}.data\n"))).unwrap();
            (p, format!("nrrd = \"{name}.nhdr\""))
        };
        let sc = scene(&dir, name, &text).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(sc.volume.dims, DIMS, "{name}");
        let got = store_values(&sc, &dir.join(format!("{name}-store")));
        assert_eq!(bits(&got), bits(&want), "{name}: {}", file.display());
        // The decoded temporary is gone.
        assert!(!dir.join(format!("{name}-store/nrrd-density.raw")).exists());
    }
}

#[test]
fn geometry_comes_from_the_header() {
    let dir = temp_dir("nrrd-geometry");
    let data: Vec<u8> = samples().iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.join("d.raw"), &data).unwrap();
    let base = "type: float\nendian: little\nencoding: raw\ndata file: d.raw\n";
    let cases = [
        ("none", "", 1.0, [0.0, 0.0, 0.0]),
        ("spacings", "spacings: 0.5 0.5 0.5\n", 0.5, [0.0, 0.0, 0.0]),
        (
            "space",
            "space: right-anterior-superior\nspace directions: (0.25,0,0) (0,0.25,0) (0,0,0.25)\nspace origin: (1,2,3)\n",
            0.25,
            [0.875, 1.875, 2.875],
        ),
        ("axis_mins", "spacings: 2 2 2\naxis mins: -4 0 6\ncenters: cell cell cell\n", 2.0, [-4.0, 0.0, 6.0]),
    ];
    for (name, fields, h, origin) in cases {
        std::fs::write(dir.join(format!("{name}.nhdr")), header(&format!("{base}{fields}"))).unwrap();
        let sc = scene(&dir, name, &format!("nrrd = \"{name}.nhdr\"")).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(sc.volume.voxel_size, h, "{name}");
        assert_eq!(sc.volume.origin.to_array(), origin, "{name}");
    }
    // The scene's keys override the header's.
    let sc = scene(&dir, "override", "nrrd = \"space.nhdr\"\nvoxel_size = 3.0\norigin = [9, 9, 9]").unwrap();
    assert_eq!((sc.volume.voxel_size, sc.volume.origin.to_array()), (3.0, [9.0; 3]));
}

#[test]
fn bad_headers_and_short_data_are_clear_errors() {
    let dir = temp_dir("nrrd-errors");
    let data: Vec<u8> = samples().iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.join("d.raw"), &data).unwrap();
    std::fs::write(dir.join("short.raw"), &data[..data.len() - 10]).unwrap();
    std::fs::write(dir.join("d.gz"), gzip(&[data.clone(), vec![0u8; 8]].concat())).unwrap();
    let ok = "endian: little\nencoding: raw\ndata file: d.raw\n";
    let header_cases: [(&str, String, &str); 8] = [
        ("notype", header(ok), "`type`"),
        ("int", header(&format!("type: int\n{ok}")), "not supported"),
        ("dim4", "NRRD0004\ntype: float\ndimension: 4\nsizes: 1 2 3 4\n".to_string() + ok, "dimension"),
        ("enc", header("type: float\nendian: little\nencoding: bzip2\ndata file: d.raw\n"), "encoding"),
        ("aniso", header(&format!("type: float\n{ok}spacings: 1 1 2\n")), "cubes"),
        (
            "rotated",
            header(&format!("type: float\n{ok}space directions: (0.7,0.7,0) (-0.7,0.7,0) (0,0,1)\n")),
            "axis-aligned",
        ),
        ("magic", "P6\n".to_string(), "not an NRRD file"),
        ("endian", header("type: float\nencoding: raw\ndata file: d.raw\n"), "`endian`"),
    ];
    for (name, text, want) in header_cases {
        std::fs::write(dir.join(format!("{name}.nhdr")), text).unwrap();
        let e = scene(&dir, name, &format!("nrrd = \"{name}.nhdr\"")).expect_err(name);
        let msg = e.to_string();
        assert!(
            msg.contains("volume.nrrd") && msg.contains(&format!("{name}.nhdr")) && msg.contains(want),
            "{name}: {msg}"
        );
    }
    // Data problems show when the store is built, named against the NRRD file.
    let mut negative = data.clone();
    negative[4 * (2 + 19 * 3)..4 * (3 + 19 * 3)].copy_from_slice(&(-1.0f32).to_le_bytes());
    std::fs::write(dir.join("neg.raw"), negative).unwrap();
    for (name, fields, want) in [
        (
            "neg",
            "type: float\nendian: little\nencoding: raw\ndata file: neg.raw\n",
            "neg.nhdr: voxel (2, 3, 0) has density -1",
        ),
        ("short", "type: float\nendian: little\nencoding: raw\ndata file: short.raw\n", "ends after"),
        ("long_gz", "type: float\nendian: little\nencoding: gzip\ndata file: d.gz\n", "more than"),
        ("missing", "type: float\nendian: little\nencoding: raw\ndata file: absent.raw\n", "absent.raw"),
    ] {
        std::fs::write(dir.join(format!("{name}.nhdr")), header(fields)).unwrap();
        let sc = scene(&dir, name, &format!("nrrd = \"{name}.nhdr\"")).expect(name);
        let e = lpm::solver::build_store(&sc, &dir.join(format!("{name}-store"))).err().expect(name);
        assert!(e.to_string().contains(want), "{name}: {e}");
    }
}

#[test]
fn nrrd_scene_solves_bitwise_like_the_same_density_as_raw() {
    let dir: PathBuf = temp_dir("nrrd-solve");
    let data: Vec<u8> = samples().iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.join("d.raw"), &data).unwrap();
    std::fs::write(dir.join("d.gz"), gzip(&data)).unwrap();
    std::fs::write(dir.join("d.nhdr"), header("type: float\nendian: little\nencoding: gzip\ndata file: d.gz\n"))
        .unwrap();
    let a = scene(&dir, "nrrd", "nrrd = \"d.nhdr\"").unwrap();
    let b = scene(&dir, "raw", &format!("raw = \"d.raw\"\ndims = [{}, {}, {}]", DIMS[0], DIMS[1], DIMS[2])).unwrap();
    let sa = crate::common::solve("nrrd-solve-a", &a, BackendKind::Cpu);
    let sb = crate::common::solve("nrrd-solve-b", &b, BackendKind::Cpu);
    let (fa, fb) = (sa.fluence_all(), sb.fluence_all());
    assert!(fa.iter().any(|&v| v > 0.0));
    assert!(fa.iter().zip(&fb).all(|(x, y)| x.to_bits() == y.to_bits()), "fluence differs");
}

#[test]
fn origin_moves_the_volume_and_the_camera_stays_in_the_world() {
    // The same view of the same volume, once at the world origin and once moved by `origin`: the
    // camera, given in world units, lands at the same place in the volume's frame.
    let dir = temp_dir("origin-camera");
    let cam = |p: [f64; 3], l: [f64; 3]| {
        format!(
            "[camera]\nposition = [{}, {}, {}]\nlook_at = [{}, {}, {}]\nwidth = 8\nheight = 8\n",
            p[0], p[1], p[2], l[0], l[1], l[2]
        )
    };
    let at_zero = scene(
        &dir,
        "zero",
        &format!("procedural = \"sphere\"\ndims = [8, 8, 8]\n\n{}", cam([20.0, -10.0, 15.0], [4.0; 3])),
    )
    .expect("scene");
    let moved = scene(
        &dir,
        "moved",
        &format!(
            "procedural = \"sphere\"\ndims = [8, 8, 8]\norigin = [100.0, -50.0, 2.5]\n\n{}",
            cam([120.0, -60.0, 17.5], [104.0, -46.0, 6.5])
        ),
    )
    .expect("scene");
    assert_eq!(moved.volume.origin.to_array(), [100.0, -50.0, 2.5]);
    assert_eq!(at_zero.volume.origin.to_array(), [0.0; 3]);
    let (a, b) = (at_zero.camera.expect("camera"), moved.camera.expect("camera"));
    assert_eq!(a.position, b.position);
    assert_eq!(a.look_at, b.look_at);
    let e =
        scene(&dir, "nan", "procedural = \"box\"\ndims = [2, 2, 2]\norigin = [0.0, nan, 0.0]").expect_err("nan origin");
    assert!(e.to_string().contains("volume.origin[1]"), "{e}");
}
