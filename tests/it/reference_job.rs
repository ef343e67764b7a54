//! `lpm::reference::job`: the reference run from a scene file to its output directory, then compared
//! with a solve of the same scene.
use crate::common::{lpm_command, temp_dir, validated, write_scene, write_scene_as};
use lpm::compare::{compare_dirs, CompareOptions};
use lpm::job::SolveJob;
use lpm::reference::job::{run, ReferenceJob, ReferenceJobError};
use lpm::reference::Orders;
use lpm::solver::BackendKind;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

/// A furnace: a non-absorbing box under a uniform sky of radiance 1, so the fluence is 4π
/// everywhere and every pixel sees radiance 1. Small (4³), so that few photons give a tight estimate.
const FURNACE: &str = r#"
[volume]
procedural = "box"
dims = [4, 4, 4]
voxel_size = 1.0
[medium]
sigma_t = 0.3
albedo = 1.0
[[lights]]
kind = "sky"
radiance = 1.0
[solver]
directions_per_face = 3
max_orders = 200
tolerance = 1e-6
[camera]
position = [10, 8, 12]
look_at = [2, 2, 2]
width = 12
height = 9
"#;

fn job(scene: PathBuf, out: PathBuf, photons: u64, spp: u32) -> ReferenceJob {
    ReferenceJob {
        scene,
        out,
        photons,
        seed: 3,
        threads: 0,
        image_samples_per_pixel: spp,
        image_orders: lpm::reference::Orders::ALL,
    }
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn furnace_reference_writes_its_outputs_and_agrees_with_the_solver() {
    let dir = temp_dir("refjob-furnace");
    let scene = write_scene(&dir, FURNACE);
    let reference = dir.join("reference");
    let report = run(&job(scene.clone(), reference.clone(), 2_000_000, 16)).expect("reference job");

    let files = [
        "fluence.raw",
        "fluence.json",
        "fluence.nhdr",
        "fluence_stderr.raw",
        "fluence_stderr.json",
        "fluence_stderr.nhdr",
        "image.exr",
        "image.png",
        "report.json",
    ];
    for f in files {
        assert!(reference.join(f).is_file(), "{f} missing");
    }
    let names: Vec<String> =
        std::fs::read_dir(&reference).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert_eq!(names.len(), files.len(), "unexpected files: {names:?}");
    for base in ["fluence", "fluence_stderr"] {
        assert_eq!(std::fs::metadata(reference.join(format!("{base}.raw"))).unwrap().len(), 64 * 4);
        let info = json(&reference.join(format!("{base}.json")));
        assert_eq!(info["dims"], serde_json::json!([4, 4, 4]));
        assert_eq!(info["components"], 1);
        let nhdr = std::fs::read_to_string(reference.join(format!("{base}.nhdr"))).unwrap();
        assert!(nhdr.contains("sizes: 4 4 4") && nhdr.contains(&format!("data file: {base}.raw")), "{nhdr}");
    }
    let r = json(&reference.join("report.json"));
    assert_eq!(r["method"], "monte-carlo");
    assert!(r.get("image_orders").is_none(), "every order: no image_orders in the report");
    assert_eq!(r["channels"], 1);
    assert_eq!(r["seed"], 3);
    assert_eq!(r["photons"].as_u64(), Some(report.photons));
    assert!(report.photons >= 2_000_000);
    assert_eq!(r["outputs"].as_array().unwrap().len(), files.len());
    let rel_se = report.mean_relative_std_error.expect("fluence > 0");
    assert!(rel_se > 0.0 && rel_se < 0.02, "{rel_se}");

    // Fluence ≈ 4π everywhere.
    let (_, fluence) = lpm::output::read_raw_field(&reference, "fluence").unwrap();
    let mean = fluence.iter().map(|&v| v as f64).sum::<f64>() / fluence.len() as f64;
    assert!((mean / (4.0 * PI) - 1.0).abs() < 5e-3, "mean fluence {mean}");
    for (i, &v) in fluence.iter().enumerate() {
        assert!((v as f64 / (4.0 * PI) - 1.0).abs() < 0.05, "voxel {i}: {v}");
    }

    // The solver (CPU twin) on the same scene, compared against the reference.
    let solved = dir.join("solve");
    let solve = SolveJob {
        backend: BackendKind::Cpu,
        // Validation on, as every test's Vulkan (ContextOptions::default() no longer reads
        // LPM_VALIDATION: the CLI does).
        vk: validated(),
        ..SolveJob::new(scene, solved.clone())
    };
    lpm::job::run(&solve, |_, _| {}).expect("solve job");
    let c = compare_dirs(&solved, &reference, &CompareOptions::default()).expect("compare");
    eprintln!("{c}");
    assert_eq!(c.fluence.voxels_used, 64);
    let rel_l2 = c.fluence.metrics.relative_l2.unwrap();
    assert!(rel_l2 < 1e-2, "{c}");
    assert!(c.fluence.metrics.mean_bias.unwrap().abs() < 5e-3, "{c}");
    // Same framing, so the images are compared; both see radiance 1 everywhere.
    let image = c.image.as_ref().expect("images compared");
    assert_eq!((image.width, image.height), (12, 9));
    assert!(image.metrics.relative_l2.unwrap() < 0.1, "{c}");
}

#[test]
fn no_image_unless_asked_and_grey_or_rgb_by_the_scene() {
    let dir = temp_dir("refjob-rgb");
    let scene = write_scene(&dir, &FURNACE.replace("sigma_t = 0.3", "sigma_t = [0.3, 0.2, 0.1]"));
    let out = dir.join("out");
    let report = run(&job(scene, out.clone(), 2_000, 0)).expect("reference job");
    assert_eq!(report.channels, 3);
    assert!(!out.join("image.exr").exists() && !out.join("image.png").exists());
    assert_eq!(std::fs::metadata(out.join("fluence.raw")).unwrap().len(), 64 * 3 * 4);
    assert_eq!(std::fs::metadata(out.join("fluence_stderr.raw")).unwrap().len(), 64 * 3 * 4);
    assert_eq!(json(&out.join("fluence.json"))["component_names"], serde_json::json!(["r", "g", "b"]));
}

#[test]
fn a_raw_volume_is_read_like_the_solver_reads_it() {
    let dir = temp_dir("refjob-raw");
    let text = FURNACE.replace("procedural = \"box\"\ndims = [4, 4, 4]", "raw = \"density.raw\"\ndims = [4, 3, 2]");
    let scene = write_scene(&dir, &text);
    // Density 1 in the x < 2 half, 0 elsewhere: the empty half stays at the sky's 4π too.
    let values: Vec<f32> = (0..24).map(|i| if i % 4 < 2 { 1.0 } else { 0.0 }).collect();
    std::fs::write(dir.join("density.raw"), values.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>()).unwrap();
    let out = dir.join("out");
    run(&job(scene.clone(), out.clone(), 20_000, 0)).expect("reference job");
    let (info, fluence) = lpm::output::read_raw_field(&out, "fluence").unwrap();
    assert_eq!(info.dims, [4, 3, 2]);
    let mean = fluence.iter().map(|&v| v as f64).sum::<f64>() / 24.0;
    assert!((mean / (4.0 * PI) - 1.0).abs() < 0.02, "{mean}");

    // A NaN density: an error naming the file and the voxel, and nothing left behind.
    let mut bad = values.clone();
    bad[5] = f32::NAN;
    std::fs::write(dir.join("density.raw"), bad.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>()).unwrap();
    let out2 = dir.join("out2");
    let err = run(&job(scene, out2.clone(), 1_000, 0)).unwrap_err();
    assert!(matches!(err, ReferenceJobError::Store(_)), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains("density.raw") && msg.contains("(1, 1, 0)"), "{msg}");
    assert!(!out2.exists(), "output directory left behind");
}

#[test]
fn a_bad_scene_is_an_error_and_leaves_nothing_behind() {
    let dir = temp_dir("refjob-bad");
    let scene = write_scene_as(&dir, "bad.toml", &FURNACE.replace("albedo = 1.0", "albedo = 1.5"));
    let out = dir.join("out");
    let err = run(&job(scene.clone(), out.clone(), 1_000, 0)).unwrap_err();
    assert!(matches!(err, ReferenceJobError::Scene(_)), "{err:?}");
    assert!(err.to_string().contains("bad.toml") && err.to_string().contains("medium.albedo"), "{err}");
    assert!(!out.exists());

    // Zero photons is refused before anything is created.
    let good = write_scene(&dir, FURNACE);
    assert!(matches!(run(&job(good.clone(), out.clone(), 0, 0)), Err(ReferenceJobError::NoPhotons)));
    assert!(!out.exists());
    // So are scattering orders without an image to count them in.
    let orders =
        ReferenceJob { image_orders: Orders { first: 1, last: Some(1) }, ..job(good.clone(), out.clone(), 1_000, 0) };
    assert!(matches!(run(&orders), Err(ReferenceJobError::OrdersWithoutImage)));
    assert!(!out.exists());
    // On the command line: orders that are not N, N..M or N.. are refused, naming what was written.
    for (bad, says) in [("3..1", "below the first"), ("one", "\"one\" is not a whole number"), ("1..x", "\"x\"")] {
        let o = lpm_command(&["reference", good.to_str().unwrap(), "--out", out.to_str().unwrap(), "--samples", "16"])
            .args(["--image-spp", "1", "--orders", bad])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && stderr.contains(says), "--orders {bad}: {stderr}");
        assert!(!out.exists());
    }
    // The orders an image counts are in its report.
    let counted = dir.join("counted");
    let o = lpm_command(&["reference", good.to_str().unwrap(), "--out", counted.to_str().unwrap(), "--samples", "16"])
        .args(["--image-spp", "1", "--orders", "2.."])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(json(&counted.join("report.json"))["image_orders"], serde_json::json!({"first": 2, "last": null}));

    // A failure with an existing output directory leaves its files untouched.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("fluence.raw"), b"earlier").unwrap();
    assert!(run(&job(scene, out.clone(), 1_000, 0)).is_err());
    assert_eq!(std::fs::read(out.join("fluence.raw")).unwrap(), b"earlier");
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 1);
}

/// The report's per-face outgoing power, against closed forms: a slab periodic in x and y under an
/// overhead sun. Absorbing: only the direct beam leaves, through the bottom, e^{−τ} of what came in
/// (within four standard errors), and nothing through the top or the periodic sides. Conservative:
/// every photon leaves through the top or the bottom, so R + T = 1 to rounding.
#[test]
fn the_faces_outgoing_power_matches_closed_forms_for_a_slab() {
    let dir = temp_dir("reference-faces");
    let slab = |albedo: f64| {
        format!(
            "[volume]\nprocedural = \"box\"\ndims = [4, 4, 6]\nvoxel_size = 0.5\n[medium]\nsigma_t = 0.4\nalbedo = {albedo}\n\
             g = 0.6\n[[lights]]\nkind = \"sun\"\ndirection = [0.0, 0.0, 1.0]\nirradiance = 2.0\n[boundary]\nx = \"periodic\"\n\
             y = \"periodic\"\n"
        )
    };
    let power_in = 2.0 * (4.0 * 0.5) * (4.0 * 0.5);
    let faces = |albedo: f64, name: &str| {
        let scene = write_scene_as(&dir, &format!("{name}.toml"), &slab(albedo));
        let out = dir.join(name);
        run(&job(scene, out.clone(), 200_000, 0)).expect("reference");
        let report = json(&out.join("report.json"));
        let faces = report["faces"].as_array().unwrap().clone();
        let names: Vec<&str> = faces.iter().map(|f| f["face"].as_str().unwrap()).collect();
        assert_eq!(names, ["-x", "+x", "-y", "+y", "-z", "+z"]);
        faces
            .iter()
            .map(|f| (f["power_out"][0].as_f64().unwrap(), f["std_error"][0].as_f64().unwrap()))
            .collect::<Vec<_>>()
    };
    let absorbing = faces(0.0, "absorbing");
    let tau: f64 = 0.4 * 6.0 * 0.5;
    let (bottom, se) = absorbing[4];
    let exact = power_in * (-tau).exp();
    assert!(se > 0.0 && (bottom - exact).abs() <= 4.0 * se, "{bottom} ± {se}, exact {exact}");
    assert!(absorbing.iter().enumerate().all(|(f, &(p, _))| f == 4 || p == 0.0), "{absorbing:?}");
    let conservative = faces(1.0, "conservative");
    let (top, bottom) = (conservative[5], conservative[4]);
    assert!(top.0 > 0.05 * power_in && bottom.0 > 0.5 * power_in, "{conservative:?}");
    assert!(conservative[..4].iter().all(|&(p, _)| p == 0.0), "{conservative:?}");
    let sum = top.0 + bottom.0;
    assert!((sum / power_in - 1.0).abs() < 1e-9, "R + T = {}", sum / power_in);
}
