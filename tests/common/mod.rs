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
