//! Scenes and helpers shared by the integration tests.
#![allow(dead_code)]

use glam::DVec3;
use lpm::scene::*;
use std::path::PathBuf;

/// A scene built in code (no file), with a procedural volume.
pub fn scene(shape: Shape, dims: [u32; 3], sigma_t: [f64; 3], albedo: [f64; 3], lights: Vec<Light>) -> Scene {
    Scene {
        path: PathBuf::from("test.toml"),
        volume: Volume {
            source: VolumeSource::Procedural { shape, seed: 7 },
            dims,
            voxel_size: 1.0,
            origin: glam::DVec3::ZERO,
            emission: None,
            albedo: None,
        },
        medium: Medium { sigma_t, albedo, g: 0.0, emission: [0.0; 3] },
        lights,
        solver: SolverSettings {
            directions_per_face: 3,
            storage_directions_per_face: None,
            sky_directions_per_face: Some(0), // the sky on the k×k directions, whatever k a test sets
            scattered_directions_per_face: None,
            max_orders: 200,
            tolerance: 1e-6,
            device_memory_budget: None,
            host_memory_budget: None,
            extrapolate_tail: false,
            storage_precision: StoragePrecision::Auto,
            plan: PlanMode::Auto,
            spatial: Some(SpatialScheme::Linear),
            forward_peak: ForwardPeak::Auto,
            emission_uncollided: Default::default(),
            diffusion_correction: DiffusionCorrection::Off,
            acceleration: Acceleration::Auto,
            diffusion_cells: None,
            checkpoint: Default::default(),
            device_residency: Default::default(),
        },
        camera: None,
        boundary: Boundary::default(),
        display: Default::default(),
    }
}

pub fn sky(r: f64) -> Light {
    Light::Sky { radiance: [r; 3] }
}

pub fn sun(dir: [f64; 3], e: [f64; 3]) -> Light {
    Light::Sun { direction: DVec3::from_array(dir).normalize(), irradiance: e }
}

use lpm::solver::fields::StoreFields;
use lpm::solver::plan::{Plan, SweepDirection};
use lpm::solver::segment::e1;
use lpm::solver::sweep::{lattice_column, FaceSweep};
use lpm::solver::{BackendKind, SolveRun};
use lpm::store::BrickStore;
use lpm::vk::ContextOptions;

/// A fresh directory under cargo's per-test temporary area.
pub fn temp_dir(name: &str) -> PathBuf {
    static SWEEP: std::sync::Once = std::sync::Once::new();
    SWEEP.call_once(remove_dead_runs_dirs);
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// Removes the temporary directories of earlier test runs (named `…-PID` by [`temp_dir`]) whose
/// process is gone: each run leaves a gigabyte or so behind, which filled a disk once.
fn remove_dead_runs_dirs() {
    // Whether a process lives is read from /proc.
    if !cfg!(target_os = "linux") {
        return;
    }
    let Ok(entries) = std::fs::read_dir(env!("CARGO_TARGET_TMPDIR")) else { return };
    let me = std::process::id();
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name.to_str().and_then(|n| n.rsplit_once('-')).and_then(|(_, p)| p.parse::<u32>().ok()) else {
            continue;
        };
        if pid != me && !std::path::Path::new(&format!("/proc/{pid}")).exists() && entry.path().is_dir() {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

/// Vulkan options for tests: validation (and synchronization validation) always on.
pub fn validated() -> ContextOptions {
    ContextOptions { validation: true, ..ContextOptions::default() }
}

pub struct Solved {
    pub run: SolveRun,
    pub fields: StoreFields,
    pub store: BrickStore,
}

impl Solved {
    /// The bits of the committed fluence, then of the committed source (for bitwise comparisons).
    pub fn field_bits(&self) -> Vec<u32> {
        let f = &self.fields;
        f.fluence_total.as_slice().iter().chain(f.source_total.as_slice()).map(|v| v.to_bits()).collect()
    }

    pub fn fluence(&self, v: [u32; 3], ch: u32) -> f64 {
        self.fields.fluence_total.value(v, ch) as f64
    }

    /// All fluence values, voxel by voxel (x fastest), channels innermost.
    pub fn fluence_all(&self) -> Vec<f64> {
        let [nx, ny, nz] = self.run.plan.dims;
        let c = self.run.plan.channels;
        let mut out = Vec::new();
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    for ch in 0..c {
                        out.push(self.fluence([x, y, z], ch));
                    }
                }
            }
        }
        out
    }
}

/// Builds the store for `scene` in a temp dir and solves it on `backend` (validation on).
pub fn solve(name: &str, scene: &Scene, backend: BackendKind) -> Solved {
    let dir = temp_dir(name);
    let store = lpm::solver::build_store(scene, &dir.join("store")).expect("store");
    let (run, fields) = lpm::solver::solve(scene, &store, backend, validated(), |_, _| {}).expect("solve");
    Solved { run, fields, store }
}

/// The bytes the smallest cut of `scene`'s GPU solve needs, from the error a budget of one byte
/// gives.
pub fn smallest_unit(scene: &Scene) -> u64 {
    let dir = temp_dir("budget-probe");
    let store = lpm::solver::build_store(scene, &dir.join("store")).expect("store");
    let mut s = scene.clone();
    s.solver.device_memory_budget = Some(1);
    match lpm::solver::solve(&s, &store, BackendKind::Gpu, validated(), |_, _| {}) {
        Err(lpm::solver::SolveError::BudgetTooSmall { needed, .. }) => needed,
        other => panic!("expected BudgetTooSmall, got {:?}", other.map(|_| ())),
    }
}

/// ‖a − b‖₂ / ‖b‖₂.
pub fn relative_l2(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    let den: f64 = b.iter().map(|y| y * y).sum();
    (num / den).sqrt()
}

/// A scene whose density comes from a raw file written here (grey medium, g = 0).
pub fn raw_scene(
    name: &str,
    dims: [u32; 3],
    sigma_t: f64,
    albedo: f64,
    lights: Vec<Light>,
    density: impl Fn([u32; 3]) -> f32,
) -> Scene {
    let path = temp_dir(name).join("density.raw");
    write_raw_field(&path, dims, density);
    let mut s = scene(Shape::Box, dims, [sigma_t; 3], [albedo; 3], lights);
    s.volume.source = VolumeSource::Raw { path };
    s
}

/// Where the discrete ray of `dir` that is in voxel `v` was born, under `solver.spatial =
/// "constant"` (each ray meets the one voxel of its lattice column): the plane of its last wrap (0
/// when it entered through the sweep's entry face), and the plane `t` of `v` itself.
pub fn birth_plane(dir: &SweepDirection, dims: [u32; 3], v: [u32; 3]) -> (u32, u32) {
    let sweep = FaceSweep::new(dir.face, dims);
    let f = sweep.geometry();
    let t = if f.sign > 0.0 { v[f.axis] } else { dims[f.axis] - 1 - v[f.axis] };
    let (vb, vc) = (v[f.lateral[0]] as i64, v[f.lateral[1]] as i64);
    let o = dir.offsets[t as usize];
    // Slot s sits at lattice column (s + o + 1) mod (n + 1) and meets that voxel column.
    let p = (vb - o[0] as i64 - 1).rem_euclid(sweep.n[1] as i64 + 1) as u32;
    let q = (vc - o[1] as i64 - 1).rem_euclid(sweep.n[2] as i64 + 1) as u32;
    let at = |t: u32| {
        let o = dir.offsets[t as usize];
        (lattice_column(p, o[0], sweep.n[1]), lattice_column(q, o[1], sweep.n[2]))
    };
    // Walk back while the same ray (no wrap) was inside the volume (a slot at lattice column n is
    // outside: it carries the boundary radiance unchanged until it moves in).
    let inside = |t: u32| {
        let ((cb, _), (cc, _)) = at(t);
        cb < sweep.n[1] && cc < sweep.n[2]
    };
    let wraps = |t: u32| {
        let ((_, wb), (_, wc)) = at(t);
        (wb, wc)
    };
    let mut born = t;
    while born > 0 && wraps(born - 1) == wraps(t) && inside(born - 1) {
        born -= 1;
    }
    (born, t)
}

/// Fluence of a pure absorber box (uniform density 1) under a uniform sky of radiance 1, from
/// Beer–Lambert along the discrete rays of the direction set (`solver.spatial = "constant"`): a ray born `m` planes before voxel v
/// arrives with e^{−σ s m} and its segment average there is e^{−σ s m}·E1(σ s).
pub fn beer_lambert_over_the_direction_set(sigma: f64, plan: &Plan, v: [u32; 3]) -> f64 {
    let mut phi = 0.0;
    for dir in plan.faces.iter().flatten() {
        let (born, t) = birth_plane(dir, plan.dims, v);
        let x = sigma * dir.path_length;
        phi += dir.fluence_weight * (-x * (t - born) as f64).exp() * e1(x);
    }
    phi
}

/// The `lpm` binary with validation on, quiet logs and no fault injection.
pub fn lpm_command(args: &[&str]) -> std::process::Command {
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_lpm"));
    cmd.args(args).env("LPM_VALIDATION", "1").env("LPM_LOG", "warn").env_remove("LPM_TEST_ABORT_AT_SLICE");
    cmd
}

/// Writes `text` as `dir/name` and returns its path.
pub fn write_scene_as(dir: &std::path::Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).expect("write scene");
    path
}

/// Writes `text` as `dir/scene.toml` and returns its path.
pub fn write_scene(dir: &std::path::Path, text: &str) -> PathBuf {
    write_scene_as(dir, "scene.toml", text)
}

/// The k×k-per-face direction set, made once per k for the whole test process: the exact
/// references below evaluate it at many thousands of points (made per point, building a 32×32 set
/// took most of the spatial-accuracy tests' time).
pub fn propagation_set(k: u32) -> std::sync::Arc<lpm::quadrature::PropagationSet> {
    use std::collections::HashMap;
    use std::sync::{Arc, Mutex, OnceLock};
    static SETS: OnceLock<Mutex<HashMap<u32, Arc<lpm::quadrature::PropagationSet>>>> = OnceLock::new();
    let mut sets = SETS.get_or_init(Default::default).lock().unwrap_or_else(|e| e.into_inner());
    Arc::clone(sets.entry(k).or_insert_with(|| Arc::new(lpm::quadrature::PropagationSet::new(k))))
}

/// ∫ e^{−σ d(x, −ω)} dω at point x of a box [0, n]³ (d: the distance from x back to the box's
/// surface along −ω), by a fine cube-face quadrature of `k`×`k` directions per face.
pub fn exact_absorber_fluence(sigma: f64, n: [f64; 3], x: [f64; 3], k: u32) -> f64 {
    let fine = propagation_set(k);
    fine.directions
        .iter()
        .map(|d| {
            let w = d.omega.to_array();
            let dist = (0..3)
                .map(|a| {
                    if w[a] > 0.0 {
                        x[a] / w[a]
                    } else if w[a] < 0.0 {
                        (x[a] - n[a]) / w[a]
                    } else {
                        f64::INFINITY
                    }
                })
                .fold(f64::INFINITY, f64::min);
            d.solid_angle * (-sigma * dist).exp()
        })
        .sum()
}

/// An RGB cloud under sky and sun (k = 3, tolerance 1e-12 so it runs all `max_orders`): slow enough
/// per order to be killed between two checkpoints, which the kill-and-resume tests need.
pub fn killable_cloud_scene(dims: [u32; 3], max_orders: u32) -> String {
    format!(
        r#"
[volume]
procedural = "cloud"
dims = [{}, {}, {}]
seed = 3
[medium]
sigma_t = [0.9, 0.7, 0.5]
albedo = 0.9
[[lights]]
kind = "sky"
radiance = 0.5
[[lights]]
kind = "sun"
direction = [0.4, -0.3, 1.0]
irradiance = 2.0
[solver]
directions_per_face = 3
max_orders = {max_orders}
tolerance = 1e-12
# A checkpoint after every order, so that a kill lands between two.
checkpoint_every_orders = 1
# On so that the kill tests also cover the third source file the correction writes into, and the
# diffusion correction file every checkpoint of an accelerated solve writes.
diffusion_correction = "on"
acceleration = "diffusion"
"#,
        dims[0], dims[1], dims[2]
    )
}

/// The image of a solve of the scene file `scene` into `out` (CPU backend, transparent
/// background, no field exports), as RGBA pixels.
pub fn image_of(scene: PathBuf, out: &std::path::Path) -> Vec<[f32; 4]> {
    let job = lpm::job::SolveJob {
        backend: lpm::solver::BackendKind::Cpu,
        no_fields: true,
        background: lpm::render::Background::Transparent,
        ..lpm::job::SolveJob::new(scene, out.to_path_buf())
    };
    lpm::job::run(&job, |_, _| {}).expect("solve");
    read_exr_rgba(&out.join("image.exr"))
}

/// An EXR's RGBA pixels, row-major.
pub fn read_exr_rgba(path: &std::path::Path) -> Vec<[f32; 4]> {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |res, _| (res.width(), vec![[0.0f32; 4]; res.width() * res.height()]),
        |img: &mut (usize, Vec<[f32; 4]>), pos, (r, g, b, a): (f32, f32, f32, f32)| {
            let w = img.0;
            img.1[pos.y() * w + pos.x()] = [r, g, b, a];
        },
    )
    .expect("read exr");
    image.layer_data.channel_data.pixels.1
}

/// Writes `f` over a `dims` volume as a headerless raw f32 file (x fastest, little endian).
pub fn write_raw_field(path: &std::path::Path, dims: [u32; 3], f: impl Fn([u32; 3]) -> f32) {
    let mut bytes = Vec::new();
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                bytes.extend_from_slice(&f([x, y, z]).to_le_bytes());
            }
        }
    }
    std::fs::write(path, bytes).expect("write raw");
}

/// `lpm render OUT --background transparent --image IMAGE`: the solved result in `out` rendered
/// again from its kept render data, as RGBA pixels.
pub fn rerender_transparent(out: &std::path::Path, image: &std::path::Path) -> Vec<[f32; 4]> {
    let status = lpm_command(&[
        "render",
        out.to_str().expect("utf-8"),
        "--background",
        "transparent",
        "--image",
        image.to_str().expect("utf-8"),
    ])
    .status()
    .expect("run lpm render");
    assert!(status.success(), "lpm render failed");
    read_exr_rgba(image)
}
