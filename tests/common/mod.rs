//! Scenes and helpers shared by the integration tests.
#![allow(dead_code)]

use glam::DVec3;
use lpm::scene::*;
use std::path::PathBuf;

/// A scene built in code (no file), with a procedural volume.
pub fn scene(shape: Shape, dims: [u32; 3], sigma_t: [f64; 3], albedo: [f64; 3], lights: Vec<Light>) -> Scene {
    Scene {
        path: PathBuf::from("test.toml"),
        volume: Volume { source: VolumeSource::Procedural { shape, seed: 7 }, dims, voxel_size: 1.0 },
        medium: Medium { sigma_t, albedo, g: 0.0, emission: [0.0; 3] },
        lights,
        solver: SolverSettings {
            directions_per_face: 3,
            storage_directions_per_face: None,
            max_orders: 200,
            tolerance: 1e-6,
            device_memory_budget: None,
            extrapolate_tail: false,
        },
        camera: None,
    }
}

pub fn sky(r: f64) -> Light {
    Light::Sky { radiance: [r; 3] }
}

pub fn sun(dir: [f64; 3], e: [f64; 3]) -> Light {
    Light::Sun { direction: DVec3::from_array(dir).normalize(), irradiance: e }
}

use lpm::solver::fields::StoreFields;
use lpm::solver::{BackendKind, SolveRun};
use lpm::store::BrickStore;
use lpm::vk::ContextOptions;

/// A fresh directory under cargo's per-test temporary area.
pub fn temp_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
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

/// ‖a − b‖₂ / ‖b‖₂.
pub fn relative_l2(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    let den: f64 = b.iter().map(|y| y * y).sum();
    (num / den).sqrt()
}
