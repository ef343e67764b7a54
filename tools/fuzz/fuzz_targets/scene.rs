//! Any bytes as a scene file: parsing and validation must return Ok or a typed error, never panic,
//! and an accepted scene must satisfy the validator's promises (finite, in range, unit directions).
#![no_main]
use libfuzzer_sys::fuzz_target;
use lpm::scene::{Light, Scene};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    // A path in a fresh, empty directory: a `volume.raw` naming a relative file finds nothing.
    let Ok(scene) = Scene::from_toml_str(text, Path::new("/nonexistent-lpm-fuzz/scene.toml")) else { return };
    let finite = |v: &[f64; 3]| v.iter().all(|x| x.is_finite() && *x >= 0.0 && *x <= lpm::scene::validate::MAX_LIGHT);
    assert!(finite(&scene.medium.emission));
    assert!(scene.lights.len() <= lpm::scene::validate::MAX_LIGHTS);
    for l in &scene.lights {
        match l {
            Light::Sky { radiance } => assert!(finite(radiance)),
            Light::Sun { direction, irradiance } => {
                assert!(finite(irradiance));
                assert!((direction.length() - 1.0).abs() < 1e-12, "{direction}");
            }
            Light::Point { position, intensity } => {
                assert!(finite(intensity));
                assert!(position.is_finite() && position.abs().max_element() <= lpm::scene::validate::MAX_COORDINATE);
            }
            // The map is read when the scene loads; here its directory does not exist, so an
            // accepted environment light would mean a map was never checked.
            Light::Environment(env) => panic!("environment light accepted without its map: {:?}", env.intensity),
        }
    }
    assert!(scene.volume.dims.iter().all(|&d| d >= 1 && d <= lpm::scene::validate::MAX_DIM));
    assert!(scene.volume.voxel_size.is_finite() && scene.volume.voxel_size > 0.0);
});
