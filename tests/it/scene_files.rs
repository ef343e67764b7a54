//! Scene files: the shipped examples load, every validation rule reports the file, the key and the
//! problem, and the procedural densities behave as documented.

use lpm::scene::procedural::{density, fill_brick, BRICK_VOXELS};
use lpm::scene::{Camera, Light, Projection, Scene, SceneError, Shape, VolumeSource};
use std::path::{Path, PathBuf};

const FILE: &str = "scene.toml";

const VOLUME: &str = "[volume]\nprocedural = \"sphere\"\ndims = [8, 8, 8]\n";
const MEDIUM: &str = "[medium]\nsigma_t = 0.5\nalbedo = 0.9\n";

/// A valid scene with `extra` appended (extra tables, lights, solver, camera).
fn with(extra: &str) -> String {
    format!("{VOLUME}{MEDIUM}{extra}")
}

fn load(text: &str) -> Result<Scene, SceneError> {
    Scene::from_toml_str(text, Path::new(FILE))
}

/// Asserts that `text` is rejected with a message naming the file, `key` and `problem`.
#[track_caller]
fn rejects(text: &str, key: &str, problem: &str) -> SceneError {
    let err = match load(text) {
        Ok(s) => panic!("accepted:\n{text}\n=> {s:?}"),
        Err(e) => e,
    };
    let msg = err.to_string();
    assert!(msg.contains(FILE), "no file name in: {msg}");
    assert!(msg.contains(key), "no key `{key}` in: {msg}");
    assert!(msg.contains(problem), "no `{problem}` in: {msg}");
    err
}

/// A fresh directory under the system temp dir for one test.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lpm-scene-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("create temp dir");
    dir
}

fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/scenes")
}

// ---- shipped scenes -------------------------------------------------------------------------

/// A copy of a shipped scene that reads `fire.vdb` (`fire.toml`, `smoke_plume.toml`) in a temporary
/// directory beside the `fire.vdb` that `tools/fire_vdb.py` writes (with OpenVDB's Python module, as
/// tools/setup.sh installs it).
fn beside_generated_fire_vdb(scene: &Path) -> PathBuf {
    let name = scene.file_stem().and_then(|s| s.to_str()).unwrap_or("scene");
    let dir = temp_dir(&format!("shipped-{name}"));
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/fire_vdb.py");
    let status = std::process::Command::new("/usr/bin/python3")
        .arg(&script)
        .arg(dir.join("fire.vdb"))
        .arg("24")
        .status()
        .expect("run tools/fire_vdb.py");
    assert!(status.success(), "tools/fire_vdb.py failed");
    let copy = dir.join(scene.file_name().expect("a scene file name"));
    std::fs::copy(scene, &copy).expect("copy the scene");
    copy
}

#[test]
fn every_shipped_scene_loads() {
    let mut n = 0;
    for entry in std::fs::read_dir(scenes_dir()).expect("tools/scenes") {
        let path = entry.expect("dir entry").path();
        if path.extension().and_then(|e| e.to_str()) != Some("toml") {
            continue;
        }
        // fire.toml and smoke_plume.toml read a VDB file that tools/fire_vdb.py generates (it is
        // not committed): load a copy of the scene next to a freshly generated one.
        let text = std::fs::read_to_string(&path).expect("read");
        let path = if text.contains("vdb = \"fire.vdb\"") { beside_generated_fire_vdb(&path) } else { path };
        let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(scene.path, path);
        assert!(text.starts_with('#'), "{} should document itself in leading comments", path.display());
        n += 1;
    }
    assert!(n >= 4, "expected at least 4 scenes, found {n}");
}

#[test]
fn shipped_scenes_say_what_the_brief_says() {
    let s = |name: &str| Scene::load(&scenes_dir().join(name)).unwrap_or_else(|e| panic!("{e}"));

    let demo = s("demo_cloud.toml");
    assert_eq!(demo.volume.dims, [64; 3]);
    assert!(matches!(demo.volume.source, VolumeSource::Procedural { shape: Shape::Cloud, .. }));
    assert_eq!(demo.solver.directions_per_face, 4);
    assert!(demo.lights.iter().any(|l| matches!(l, Light::Sun { .. })));
    assert!(demo.lights.iter().any(|l| matches!(l, Light::Sky { .. })));
    assert!(matches!(demo.camera, Some(Camera { projection: Projection::Pinhole { .. }, .. })));

    let furnace = s("furnace_box.toml");
    assert_eq!(furnace.medium.albedo, [1.0; 3]);
    assert_eq!(furnace.lights, vec![Light::Sky { radiance: [1.0; 3] }]);
    assert!(matches!(furnace.volume.source, VolumeSource::Procedural { shape: Shape::Box, .. }));

    let absorber = s("absorber_sphere.toml");
    assert_eq!(absorber.medium.albedo, [0.0; 3]);
    assert_eq!(absorber.volume.dims, [32; 3]);

    let aniso = s("anisotropic_cloud.toml");
    assert_eq!(aniso.medium.g, 0.7);
    assert!(!aniso.medium.is_grey());
    assert_eq!(aniso.solver.device_memory_budget, Some(512 << 20));
}

// ---- defaults and normalisation -------------------------------------------------------------

#[test]
fn defaults_are_applied() {
    let s = load(&with("")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.path, Path::new(FILE));
    assert_eq!(s.volume.source, VolumeSource::Procedural { shape: Shape::Sphere, seed: 1 });
    assert_eq!(s.volume.voxel_size, 1.0);
    assert_eq!(s.medium.g, 0.0);
    assert_eq!(s.medium.emission, [0.0; 3]);
    assert_eq!(s.medium.sigma_t, [0.5; 3]);
    assert!(s.lights.is_empty());
    assert_eq!(s.solver.directions_per_face, 5);
    assert_eq!(s.solver.storage_directions_per_face, None);
    assert_eq!(s.solver.max_orders, 64);
    assert_eq!(s.solver.tolerance, 1e-4);
    assert_eq!(s.solver.device_memory_budget, None);
    assert_eq!(s.camera, None);
}

/// `solver.spatial` and `solver.sky_directions_per_face` left out (or "auto"): for a pure absorber
/// with open faces the plan takes the linear lattice and the sky on 4k×4k directions of its own
/// (at most 32), since order 0 is the whole answer; a scattering or emitting medium, a periodic or
/// mirror face, or a key the scene names keeps what it says.
#[test]
fn the_plan_chooses_the_spatial_scheme_and_the_skys_directions() {
    use lpm::scene::SpatialScheme::{Constant, Linear};
    let chosen = |text: &str| {
        let scene = load(text).unwrap_or_else(|e| panic!("{e}"));
        let plan = lpm::solver::plan::Plan::new(&scene, 1, 0);
        (plan.spatial, plan.sky_directions_per_face())
    };
    let sky = "[[lights]]\nkind = \"sky\"\nradiance = 1.0\n";
    let absorber = |extra: &str| format!("{VOLUME}[medium]\nsigma_t = 0.5\nalbedo = 0.0\n{sky}{extra}");
    assert_eq!(chosen(&with(sky)), (Constant, 5));
    assert_eq!(chosen(&absorber("")), (Linear, 20));
    assert_eq!(chosen(&absorber("[solver]\nspatial = \"auto\"\ndirections_per_face = 8\n")), (Linear, 32));
    assert_eq!(chosen(&absorber("[solver]\ndirections_per_face = 12\n")), (Linear, 32));
    assert_eq!(chosen(&absorber("[solver]\nsky_directions_per_face = 5\n")), (Linear, 5));
    assert_eq!(chosen(&absorber("[solver]\nsky_directions_per_face = 8\n")), (Linear, 8));
    assert_eq!(chosen(&absorber("[solver]\nspatial = \"constant\"\n")), (Constant, 5));
    assert_eq!(chosen(&absorber("[boundary]\nx = \"periodic\"\n")), (Constant, 5));
    assert_eq!(chosen(&absorber("[boundary]\nx = \"reflective\"\n")), (Constant, 5));
    // An emitter keeps its light where it is on the nearest-column lattice.
    let emitter = format!("{VOLUME}[medium]\nsigma_t = 0.5\nalbedo = 0.0\nemission = 1.0\n{sky}");
    assert_eq!(chosen(&emitter), (Constant, 5));
    // Without a sky there is nothing to refine.
    let dark = format!("{VOLUME}[medium]\nsigma_t = 0.5\nalbedo = 0.0\n");
    assert_eq!(chosen(&dark), (Linear, 5));
}

#[test]
fn sun_direction_is_normalised_and_channels_expand() {
    let s = load(&with(
        "[[lights]]\nkind = \"sun\"\ndirection = [0, 3, 4]\nirradiance = [1, 2, 3]\n\
         [[lights]]\nkind = \"sky\"\nradiance = 2\n",
    ))
    .unwrap_or_else(|e| panic!("{e}"));
    match &s.lights[0] {
        Light::Sun { direction, irradiance } => {
            assert!((direction.length() - 1.0).abs() < 1e-12);
            assert!((direction.y - 0.6).abs() < 1e-12 && (direction.z - 0.8).abs() < 1e-12);
            assert_eq!(*irradiance, [1.0, 2.0, 3.0]);
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(s.lights[1], Light::Sky { radiance: [2.0; 3] });
}

#[test]
fn budgets_and_camera_defaults() {
    let s = load(&with(
        "[solver]\ndevice_memory_budget = \"256M\"\nstorage_directions_per_face = 2\n\
         [camera]\nposition = [4, -20, 4]\nlook_at = [4, 4, 4]\n",
    ))
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.solver.device_memory_budget, Some(256 * 1024 * 1024));
    assert_eq!(s.solver.storage_directions_per_face, Some(2));
    let cam = s.camera.expect("camera");
    assert_eq!(cam.projection, Projection::Pinhole { fov_y_degrees: 40.0 });
    assert_eq!((cam.width, cam.height), (512, 512));
    assert_eq!(cam.up, glam::DVec3::Z);

    let s = load(&with("[solver]\ndevice_memory_budget = 1000\n")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.solver.device_memory_budget, Some(1000));

    let s = load(&with("[camera]\nprojection = \"orthographic\"\nposition = [4, -20, 4]\nlook_at = [4, 4, 4]\n"))
        .unwrap_or_else(|e| panic!("{e}"));
    match s.camera.map(|c| c.projection) {
        // The default fits the whole 8³ volume: its diagonal.
        Some(Projection::Orthographic { height }) => {
            assert!((height - 8.0 * 3f64.sqrt()).abs() < 1e-9)
        }
        other => panic!("{other:?}"),
    }
}

// ---- parse errors ---------------------------------------------------------------------------

#[test]
fn missing_scene_file() {
    let err = Scene::load(Path::new("/nonexistent/dir/missing_scene.toml")).expect_err("missing file");
    assert_eq!(
        err.to_string(),
        "cannot read scene file /nonexistent/dir/missing_scene.toml: No such file or directory"
    );
}

#[test]
fn syntax_error_names_file_and_line() {
    let err = rejects(&format!("{VOLUME}[medium\nsigma_t = 1\n"), "line 4", "invalid table header");
    assert!(matches!(err, SceneError::Parse { line: Some(4), .. }), "{err:?}");
}

#[test]
fn unknown_key() {
    let err = rejects(&with("colour = 3\n"), "medium.colour", "unknown field `colour`");
    assert!(err.to_string().contains("line 7"), "{err}");
    rejects(&with("[lighting]\nkind = 1\n"), "lighting", "unknown field `lighting`");
    rejects(
        &with("[[lights]]\nkind = \"sky\"\nradiance = 1\nbrightness = 2\n"),
        "lights[0].brightness",
        "unknown field",
    );
    rejects(&with("[camera]\nposition = [0,0,0]\nlook_at = [1,0,0]\nfov = 30\n"), "camera.fov", "unknown field `fov`");
}

#[test]
fn wrong_type() {
    let text = format!("{VOLUME}[medium]\nsigma_t = 0.5\nalbedo = \"high\"\n");
    let err = rejects(&text, "medium.albedo", "invalid type: string \"high\"");
    assert!(err.to_string().contains("line 6"), "{err}");
    rejects(&format!("{VOLUME}[medium]\nsigma_t = [1, 2]\nalbedo = 1\n"), "medium.sigma_t", "invalid length 2");
    rejects(
        &format!("[volume]\nprocedural = \"box\"\ndims = [8, \"8\", 8]\n{MEDIUM}"),
        "volume.dims",
        "invalid type: string",
    );
    rejects(&with("[solver]\nmax_orders = 1.5\n"), "solver.max_orders", "invalid type: floating point");
}

#[test]
fn missing_required_keys() {
    rejects(&format!("[volume]\nprocedural = \"box\"\n{MEDIUM}"), "volume.dims", "missing field `dims`");
    rejects(VOLUME, "medium", "missing field `medium`");
    rejects(&with("[[lights]]\nkind = \"sun\"\nirradiance = 1\n"), "lights[0].direction", "is required");
}

// ---- value errors ---------------------------------------------------------------------------

#[test]
fn nan_and_inf_are_rejected() {
    rejects(&format!("{VOLUME}[medium]\nsigma_t = nan\nalbedo = 1\n"), "medium.sigma_t", "finite");
    rejects(&format!("{VOLUME}[medium]\nsigma_t = 1\nalbedo = [0.5, inf, 0.5]\n"), "medium.albedo[1]", "finite");
    rejects(&with("g = -nan\n"), "medium.g", "finite");
    rejects(
        &with("[[lights]]\nkind = \"sun\"\ndirection = [0, inf, 1]\nirradiance = 1\n"),
        "lights[0].direction[1]",
        "finite",
    );
    rejects(&with("[[lights]]\nkind = \"sky\"\nradiance = inf\n"), "lights[0].radiance", "finite");
    rejects(
        &format!("[volume]\nprocedural = \"box\"\ndims = [8,8,8]\nvoxel_size = nan\n{MEDIUM}"),
        "volume.voxel_size",
        "finite",
    );
}

#[test]
fn negative_sigma_t() {
    rejects(&format!("{VOLUME}[medium]\nsigma_t = -0.5\nalbedo = 1\n"), "medium.sigma_t", "must be ≥ 0, got -0.5");
    rejects(&format!("{VOLUME}[medium]\nsigma_t = 1e13\nalbedo = 1\n"), "medium.sigma_t", "must be ≤");
}

#[test]
fn albedo_above_one() {
    let err = load(&format!("{VOLUME}[medium]\nsigma_t = 1\nalbedo = [0.5, 1.5, 0.5]\n")).expect_err("albedo");
    assert_eq!(err.to_string(), "scene.toml: medium.albedo[1]: must be in [0, 1], got 1.5");
    assert_eq!(err.key(), Some("medium.albedo[1]"));
    rejects(&format!("{VOLUME}[medium]\nsigma_t = 1\nalbedo = -0.1\n"), "medium.albedo", "must be in [0, 1]");
}

#[test]
fn g_must_be_open_interval() {
    rejects(&with("g = 1\n"), "medium.g", "must be in (-1, 1), got 1");
    rejects(&with("g = -1.0\n"), "medium.g", "must be in (-1, 1), got -1");
    assert!(load(&with("g = 0.99\n")).is_ok());
}

#[test]
fn emission_and_lights_non_negative() {
    rejects(&with("emission = [0, -1, 0]\n"), "medium.emission[1]", "must be ≥ 0");
    rejects(&with("[[lights]]\nkind = \"sky\"\nradiance = -1\n"), "lights[0].radiance", "must be ≥ 0");
    rejects(
        &with("[[lights]]\nkind = \"sky\"\nradiance = 1\n[[lights]]\nkind = \"sun\"\ndirection = [0,0,1]\nirradiance = [1, 1, -2]\n"),
        "lights[1].irradiance[2]",
        "must be ≥ 0",
    );
}

#[test]
fn zero_sun_direction() {
    rejects(
        &with("[[lights]]\nkind = \"sky\"\nradiance = 1\n[[lights]]\nkind = \"sun\"\ndirection = [0, 0, 0]\nirradiance = 1\n"),
        "lights[1].direction",
        "must not be the zero vector",
    );
}

#[test]
fn unknown_light_kind_lists_valid_kinds() {
    rejects(&with("[[lights]]\nkind = \"moon\"\n"), "lights[0].kind", "\"sky\", \"sun\"");
    rejects(
        &with("[[lights]]\nkind = \"sky\"\nradiance = 1\ndirection = [0,0,1]\n"),
        "lights[0].direction",
        "does not apply to a sky light",
    );
}

#[test]
fn volume_source_exactly_one() {
    rejects(
        &format!("[volume]\nprocedural = \"box\"\nraw = \"d.raw\"\ndims = [8, 8, 8]\n{MEDIUM}"),
        "volume",
        "both are set",
    );
    rejects(&format!("[volume]\ndims = [8, 8, 8]\n{MEDIUM}"), "volume", "neither is set");
    rejects(
        &format!("[volume]\nprocedural = \"torus\"\ndims = [8, 8, 8]\n{MEDIUM}"),
        "volume.procedural",
        "unknown shape \"torus\", expected one of \"sphere\", \"box\", \"cloud\"",
    );
}

#[test]
fn dims_limits() {
    rejects(
        &format!("[volume]\nprocedural = \"box\"\ndims = [8, 0, 8]\n{MEDIUM}"),
        "volume.dims[1]",
        "must be in 1..=65536, got 0",
    );
    rejects(
        &format!("[volume]\nprocedural = \"box\"\ndims = [100000, 8, 8]\n{MEDIUM}"),
        "volume.dims[0]",
        "got 100000",
    );
    rejects(&format!("[volume]\nprocedural = \"box\"\ndims = [-8, 8, 8]\n{MEDIUM}"), "volume.dims[0]", "got -8");
    rejects(
        &format!("[volume]\nprocedural = \"box\"\ndims = [65536, 65536, 65536]\n{MEDIUM}"),
        "volume.dims",
        "more than the limit of 2^40",
    );
    // Exactly 2^40 is allowed (the check is on the voxel count, not on memory).
    assert!(load(&format!("[volume]\nprocedural = \"box\"\ndims = [65536, 65536, 256]\n{MEDIUM}")).is_ok());
    rejects(
        &format!("[volume]\nprocedural = \"box\"\ndims = [8, 8, 8]\nvoxel_size = 0\n{MEDIUM}"),
        "volume.voxel_size",
        "must be > 0",
    );
}

#[test]
fn bad_budget_string() {
    rejects(
        &with("[solver]\ndevice_memory_budget = \"lots\"\n"),
        "solver.device_memory_budget",
        "invalid byte size \"lots\"",
    );
    rejects(&with("[solver]\ndevice_memory_budget = \"12X\"\n"), "solver.device_memory_budget", "unknown suffix");
    rejects(&with("[solver]\ndevice_memory_budget = 0\n"), "solver.device_memory_budget", "must be > 0");
    rejects(&with("[solver]\ndevice_memory_budget = \"0G\"\n"), "solver.device_memory_budget", "must be > 0");
    rejects(&with("[solver]\nhost_memory_budget = \"lots\"\n"), "solver.host_memory_budget", "invalid byte size");
    rejects(&with("[solver]\nhost_memory_budget = -5\n"), "solver.host_memory_budget", "must be > 0");
}

/// The host memory budget and the checkpoint cadence: read, defaulted, and bad values refused.
#[test]
fn host_memory_and_checkpoint_keys() {
    let s = load(&with(
        "[solver]\nhost_memory_budget = \"2G\"\ncheckpoint_every_orders = 4\ncheckpoint_every_seconds = 0\n",
    ))
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.solver.host_memory_budget, Some(2 << 30));
    assert_eq!(s.solver.checkpoint, lpm::scene::CheckpointCadence { every_orders: Some(4), every_seconds: 0.0 });
    let s = load(&with("")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.solver.host_memory_budget, None);
    assert_eq!(s.solver.checkpoint, lpm::scene::CheckpointCadence { every_orders: None, every_seconds: 300.0 });
    // The cadence: the first of N orders or T seconds; always the last order.
    let c = lpm::scene::CheckpointCadence { every_orders: Some(3), every_seconds: 60.0 };
    assert!(!c.due(1, 1.0, false) && c.due(3, 1.0, false) && c.due(1, 60.0, false));
    assert!(c.due(1, 0.0, true));
    rejects(&with("[solver]\ncheckpoint_every_orders = 0\n"), "solver.checkpoint_every_orders", "at least 1");
    rejects(&with("[solver]\ncheckpoint_every_seconds = -1\n"), "solver.checkpoint_every_seconds", "≥ 0");
    rejects(&with("[solver]\ncheckpoint_every_seconds = nan\n"), "solver.checkpoint_every_seconds", "finite");
}

#[test]
fn acceleration_key() {
    let s = load(&with("")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.solver.acceleration, lpm::scene::Acceleration::Auto);
    for (text, value) in [("off", lpm::scene::Acceleration::Off), ("diffusion", lpm::scene::Acceleration::Diffusion)] {
        let s = load(&with(&format!("[solver]\nacceleration = \"{text}\"\n"))).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(s.solver.acceleration, value);
    }
    rejects(&with("[solver]\nacceleration = \"dsa\"\n"), "solver.acceleration", "expected one of");
    rejects(
        &with("[solver]\nacceleration = \"diffusion\"\nspatial = \"linear\"\n"),
        "solver.acceleration",
        "can diverge with solver.spatial = \"linear\"",
    );
    rejects(
        &with("[solver]\nacceleration = \"diffusion\"\nextrapolate_tail = true\n"),
        "solver.acceleration",
        "choose one",
    );
    rejects(
        &with("[solver]\nacceleration = \"diffusion\"\n[boundary]\nx = \"periodic\"\n"),
        "solver.acceleration",
        "periodic",
    );
}

#[test]
fn solver_ranges() {
    rejects(&with("[solver]\ndirections_per_face = 33\n"), "solver.directions_per_face", "must be in 1..=32, got 33");
    rejects(
        &with("[solver]\ndirections_per_face = 3\nstorage_directions_per_face = 4\n"),
        "solver.storage_directions_per_face",
        "≤",
    );
    rejects(&with("[solver]\nmax_orders = 0\n"), "solver.max_orders", "must be in 1..=100000");
    rejects(&with("[solver]\ntolerance = 1\n"), "solver.tolerance", "must be in (0, 1), got 1");
    rejects(&with("[solver]\ndiffusion_cells = 0\n"), "solver.diffusion_cells", "must be in 1..=8388608, got 0");
}

#[test]
fn camera_rules() {
    let cam = |body: &str| with(&format!("[camera]\n{body}"));
    rejects(&cam("position = [1,2,3]\nlook_at = [1,2,3]\n"), "camera.look_at", "must differ from camera.position");
    rejects(&cam("position = [0,0,0]\nlook_at = [0,0,5]\n"), "camera.up", "parallel");
    rejects(&cam("position = [0,0,0]\nlook_at = [1,0,0]\nwidth = 0\n"), "camera.width", "must be in 1..=16384, got 0");
    rejects(&cam("position = [0,0,0]\nlook_at = [1,0,0]\nheight = 20000\n"), "camera.height", "got 20000");
    rejects(&cam("position = [0,0,0]\nlook_at = [1,0,0]\nfov_y = 180\n"), "camera.fov_y", "must be in (0, 180)");
    rejects(
        &cam("projection = \"fisheye\"\nposition = [0,0,0]\nlook_at = [1,0,0]\n"),
        "camera.projection",
        "\"pinhole\", \"orthographic\"",
    );
    rejects(
        &cam("projection = \"orthographic\"\nposition = [0,0,0]\nlook_at = [1,0,0]\nview_height = -1\n"),
        "camera.view_height",
        "must be > 0",
    );
}

// ---- raw files ------------------------------------------------------------------------------

#[test]
fn raw_file_relative_to_scene_and_checked() {
    let dir = temp_dir("raw");
    std::fs::write(dir.join("density.raw"), vec![0u8; 4 * 2 * 4 * 8]).expect("write raw");
    std::fs::write(dir.join("short.raw"), vec![0u8; 100]).expect("write raw");
    let scene = |raw: &str| format!("[volume]\nraw = \"{raw}\"\ndims = [2, 4, 8]\n{MEDIUM}");
    let path = dir.join(FILE);

    // Relative paths resolve against the scene file's directory.
    std::fs::write(&path, scene("density.raw")).expect("write scene");
    let s = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.volume.source, VolumeSource::Raw { path: dir.join("density.raw") });

    // Missing file: named, with the reason.
    std::fs::write(&path, scene("nope.raw")).expect("write scene");
    let err = Scene::load(&path).expect_err("missing raw");
    let msg = err.to_string();
    assert!(msg.contains(FILE) && msg.contains("volume.raw"), "{msg}");
    assert!(msg.contains("nope.raw") && msg.contains("No such file or directory"), "{msg}");
    assert!(matches!(err, SceneError::RawFile { .. }));

    // Wrong size: expected vs actual bytes.
    std::fs::write(&path, scene("short.raw")).expect("write scene");
    let err = Scene::load(&path).expect_err("short raw");
    let msg = err.to_string();
    assert!(msg.contains(FILE) && msg.contains("volume.raw") && msg.contains("short.raw"), "{msg}");
    assert!(msg.contains("has 100 bytes, expected 256"), "{msg}");
    assert!(matches!(err, SceneError::RawSize { expected: 256, actual: 100, .. }));

    // A seed makes no sense for raw data.
    rejects(&format!("[volume]\nraw = \"x.raw\"\nseed = 3\ndims = [2, 4, 8]\n{MEDIUM}"), "volume.seed", "only applies");
    let _ = std::fs::remove_dir_all(&dir);
}

// ---- procedural densities -------------------------------------------------------------------

fn cloud_volume(seed: u64, dims: [u32; 3]) -> Vec<f32> {
    let mut v = Vec::with_capacity(dims.iter().map(|&d| d as usize).product());
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                v.push(density(Shape::Cloud, seed, dims, [x, y, z]));
            }
        }
    }
    v
}

#[test]
fn cloud_is_deterministic_and_seeded() {
    let dims = [40, 36, 32];
    let a = cloud_volume(5, dims);
    let b = cloud_volume(5, dims);
    assert_eq!(a, b);
    let c = cloud_volume(6, dims);
    let differing = a.iter().zip(&c).filter(|(x, y)| (*x - *y).abs() > 0.05).count();
    assert!(differing > a.len() / 100, "seeds 5 and 6 give nearly the same cloud ({differing} voxels differ)");
    // Same values from another thread (no hidden per-thread state leaks into results).
    let d = std::thread::spawn(move || cloud_volume(5, dims)).join().expect("thread");
    assert_eq!(a, d);
}

#[test]
fn cloud_border_empty_and_middle_dense() {
    for (seed, dims) in [(1, [48, 48, 48]), (2, [64, 40, 32]), (3, [96, 96, 96])] {
        let v = cloud_volume(seed, dims);
        let mut max_middle = 0.0f32;
        let mut empty = 0usize;
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let d = v[(x + dims[0] * (y + dims[1] * z)) as usize];
                    assert!((0.0..=1.0).contains(&d));
                    let p = [x, y, z];
                    let near_border = (0..3).any(|a| {
                        let t = (p[a] as f64 + 0.5) / dims[a] as f64;
                        t.min(1.0 - t) <= 0.1
                    });
                    if near_border {
                        assert_eq!(d, 0.0, "seed {seed} dims {dims:?} voxel {p:?}");
                    }
                    let middle = (0..3).all(|a| {
                        let t = (p[a] as f64 + 0.5) / dims[a] as f64;
                        (0.3..0.7).contains(&t)
                    });
                    if middle {
                        max_middle = max_middle.max(d);
                    }
                    if d == 0.0 {
                        empty += 1;
                    }
                }
            }
        }
        assert!(max_middle > 0.3, "seed {seed}: middle max {max_middle}");
        assert!(empty > v.len() / 2, "seed {seed}: the cloud should leave most of the volume empty");
    }
}

#[test]
fn cloud_shape_is_resolution_independent() {
    // The same normalised point at two resolutions sees the same density (to interpolation).
    let lo = density(Shape::Cloud, 4, [32; 3], [16, 16, 14]);
    let hi = (density(Shape::Cloud, 4, [64; 3], [32, 32, 28]) + density(Shape::Cloud, 4, [64; 3], [31, 31, 27])) / 2.0;
    assert!((lo - hi).abs() < 0.2, "{lo} vs {hi}");
}

#[test]
fn sphere_occupancy() {
    let dims = [64, 64, 64];
    let mut inside = 0usize;
    let mut out = vec![0.0f32; BRICK_VOXELS];
    for bz in 0..4 {
        for by in 0..4 {
            for bx in 0..4 {
                fill_brick(Shape::Sphere, 1, dims, [bx, by, bz], &mut out);
                inside += out.iter().filter(|&&d| d == 1.0).count();
                assert!(out.iter().all(|&d| d == 0.0 || d == 1.0));
            }
        }
    }
    let fraction = inside as f64 / 64f64.powi(3);
    let expected = 4.0 / 3.0 * std::f64::consts::PI * 0.4f64.powi(3);
    assert!((fraction - expected).abs() < 0.005, "{fraction} vs {expected}");
}

#[test]
fn box_is_full_and_brick_edges_are_zero() {
    let mut out = vec![0.5f32; BRICK_VOXELS];
    fill_brick(Shape::Box, 1, [20, 16, 16], [1, 0, 0], &mut out);
    for z in 0..16 {
        for y in 0..16 {
            for x in 0..16 {
                let want = if x < 4 { 1.0 } else { 0.0 };
                assert_eq!(out[x + 16 * y + 256 * z], want);
            }
        }
    }
}

#[test]
fn sky_directions_key() {
    let s = load(&with("")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.solver.sky_directions_per_face, None);
    let s = load(&with("[solver]\ndirections_per_face = 4\nsky_directions_per_face = 12\n"))
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.solver.sky_directions_per_face, Some(12));
    let key = "solver.sky_directions_per_face";
    rejects(
        &with("[solver]\ndirections_per_face = 4\nsky_directions_per_face = 3\n"),
        key,
        "≥ solver.directions_per_face = 4",
    );
    rejects(&with("[solver]\nsky_directions_per_face = 33\n"), key, "");
    rejects(
        &with("[solver]\nsky_directions_per_face = 8\n[boundary]\nx = \"periodic\"\n"),
        key,
        "periodic or reflective",
    );
    rejects(
        &with("[solver]\nsky_directions_per_face = 8\n[boundary]\nz = [\"reflective\", \"open\"]\n"),
        key,
        "periodic or reflective",
    );
}
