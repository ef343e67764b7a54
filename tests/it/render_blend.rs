//! The rendered source between storage directions (issue 38 item 2, issue 36 item 1): a camera ray
//! whose direction crosses a storage cell's boundary sees the source change by O(ε) for a turn by
//! ε, where taking the nearest cell's source jumped by O(1) — the straight seam a pinhole image
//! showed along a cell boundary. Isotropic images stay bitwise what they were, and `lpm render` of
//! an anisotropic solve is still bitwise the solve's own image.

use crate::common::{lpm_command, temp_dir, write_scene};
use glam::DVec3;
use lpm::quadrature::{Blend, PropagationSet, StorageSet};
use lpm::render::keep::RenderData;
use lpm::render::{render, render_solved, Background, Image, RenderInputs, VoxelFactors};
use lpm::scene::{Camera, Display, Medium, Projection};
use lpm::store::{BrickStore, Coverage, Field, BRICK_VOXELS};
use std::path::Path;

/// A 16³ store of density 1 (voxel size 1) and a source whose every voxel holds `value(d)` for
/// storage direction d (one channel).
fn volume(dir: &Path, storage: &StorageSet, value: impl Fn(usize) -> f32) -> (BrickStore, Field) {
    let store = BrickStore::create_with(&dir.join("store"), [16; 3], 1.0, |_, out| {
        out.fill(1.0);
        Ok(())
    })
    .expect("store");
    let n = storage.len();
    let mut source = store.create_field("source", n as u32, Coverage::Occupied).expect("field");
    for b in store.occupied_bricks().collect::<Vec<_>>() {
        let data = source.brick_mut(b).expect("occupied");
        for d in 0..n {
            // A little variation in space too, so the spatial interpolation takes part.
            for (i, x) in data[d * BRICK_VOXELS..(d + 1) * BRICK_VOXELS].iter_mut().enumerate() {
                *x = value(d) * (1.0 + 0.01 * (i % 7) as f32);
            }
        }
    }
    (store, source)
}

/// An orthographic 3×3 camera whose centre pixel sees light travelling along `travel` through the
/// volume's centre.
fn camera_seeing(travel: DVec3) -> Camera {
    let view = -travel.normalize();
    let centre = DVec3::splat(8.0);
    let up = if view.z.abs() < 0.9 { DVec3::Z } else { DVec3::X };
    Camera {
        projection: Projection::Orthographic { height: 1.0 },
        position: centre - view * 40.0,
        look_at: centre,
        up,
        width: 3,
        height: 3,
    }
}

const MEDIUM: Medium = Medium { sigma_t: [0.05; 3], albedo: [0.9; 3], g: 0.8, emission: [0.0; 3] };

fn data(prop: &PropagationSet, storage: &StorageSet, camera: &Camera) -> RenderData {
    RenderData::new([16; 3], 1.0, DVec3::ZERO, 1, prop, storage, &MEDIUM, &[], camera, &Display::default())
}

/// The centre pixel as `lpm render` makes it (blended in direction).
fn blended(prop: &PropagationSet, storage: &StorageSet, store: &BrickStore, source: &Field, travel: DVec3) -> f64 {
    let camera = camera_seeing(travel);
    let image = render_solved(
        &data(prop, storage, &camera),
        store,
        source,
        VoxelFactors::default(),
        None,
        &camera,
        Background::Transparent,
    );
    image.pixel(1, 1)[0] as f64
}

/// The centre pixel with the source of the one storage cell that holds the ray's direction (how
/// images were made before blending).
fn nearest(prop: &PropagationSet, storage: &StorageSet, store: &BrickStore, source: &Field, travel: DVec3) -> f64 {
    let camera = camera_seeing(travel);
    let lookup = |omega: DVec3| Blend::single(storage.owner[prop.containing(omega)]);
    let image = render(&RenderInputs {
        store,
        source,
        emission: None,
        albedo: None,
        channels: 1,
        storage_dirs: storage.len() as u32,
        storage_lookup: &lookup,
        medium: &MEDIUM,
        single: None,
        background: [0.0; 3],
        environment: None,
        camera: &camera,
    });
    image.pixel(1, 1)[0] as f64
}

/// Storage cell boundaries of k = 4, k_s = 2 (24 storage directions): inside a face (u = 0 on +X),
/// across a cube edge (+X | +Y), and beside a cube corner (three faces). A turn by ε = 10⁻⁷ across
/// each changes the pixel by O(ε) blended; the nearest cell's source changes it by O(1) (the seam).
#[test]
fn a_ray_turning_across_a_storage_cell_boundary_sees_no_jump() {
    let dir = temp_dir("render-blend-seam");
    let prop = PropagationSet::new(4);
    let storage = StorageSet::per_face(&prop, 2);
    // Neighbouring cells hold very different values: a jump would be plain.
    let (store, source) = volume(&dir, &storage, |d| 1.0 + d as f32);
    let eps = 1e-7;
    let boundaries = [
        ("inside a face", DVec3::new(1.0, 0.0, 0.37), DVec3::Y),
        ("across a cube edge", DVec3::new(1.0, 1.0, 0.37), DVec3::Y),
        ("beside a cube corner", DVec3::new(1.0, 1.0, 0.999), DVec3::new(-1.0, 1.0, 0.0)),
    ];
    for (name, on, across) in boundaries {
        let (a, b) = (on - across * eps, on + across * eps);
        // The two sides do fall in different storage cells.
        assert_ne!(storage.owner[prop.containing(a)], storage.owner[prop.containing(b)], "{name}");
        let (na, nb) = (nearest(&prop, &storage, &store, &source, a), nearest(&prop, &storage, &store, &source, b));
        assert!((na - nb).abs() > 0.05 * na.abs(), "{name}: nearest cell {na} | {nb} (expected a jump)");
        let (ba, bb) = (blended(&prop, &storage, &store, &source, a), blended(&prop, &storage, &store, &source, b));
        assert!(ba > 0.0 && (ba - bb).abs() <= 1e-5 * ba, "{name}: blended {ba} | {bb}");
    }
}

/// Blending makes the pixel a continuous function of the ray's direction everywhere: over a sweep
/// of a camera across a whole face and into the next one (1° steps), no step changes the pixel by
/// more than a few per cent of the range, where the nearest cell's jumps take a large part of it.
#[test]
fn a_camera_sweep_changes_the_pixel_gradually() {
    let dir = temp_dir("render-blend-sweep");
    let prop = PropagationSet::new(4);
    let storage = StorageSet::per_face(&prop, 2);
    let (store, source) = volume(&dir, &storage, |d| 1.0 + d as f32);
    let sweep = |f: &dyn Fn(DVec3) -> f64| -> Vec<f64> {
        (0..=120).map(|deg| f64::from(deg).to_radians()).map(|a| f(DVec3::new(a.cos(), a.sin(), 0.3))).collect()
    };
    let largest_step = |v: &[f64]| {
        let range =
            v.iter().copied().fold(f64::NEG_INFINITY, f64::max) - v.iter().copied().fold(f64::INFINITY, f64::min);
        v.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max) / range
    };
    let smooth = largest_step(&sweep(&|t| blended(&prop, &storage, &store, &source, t)));
    let jumpy = largest_step(&sweep(&|t| nearest(&prop, &storage, &store, &source, t)));
    assert!(smooth < 0.05, "blended: largest 1° step {smooth} of the range");
    assert!(jumpy > 0.2, "nearest: largest 1° step {jumpy} of the range");
}

/// With one storage direction (an isotropic medium) the blend is a single weight of 1: the image is
/// bitwise the one the single direction's source gives directly.
#[test]
fn an_isotropic_image_is_bitwise_unchanged() {
    let dir = temp_dir("render-blend-iso");
    let prop = PropagationSet::new(4);
    let storage = StorageSet::isotropic(&prop);
    let (store, source) = volume(&dir, &storage, |_| 0.731);
    let camera = Camera {
        projection: Projection::Pinhole { fov_y_degrees: 40.0 },
        position: DVec3::new(-9.0, -20.0, 30.0),
        look_at: DVec3::splat(8.0),
        up: DVec3::Z,
        width: 24,
        height: 20,
    };
    let solved: Image = render_solved(
        &data(&prop, &storage, &camera),
        &store,
        &source,
        VoxelFactors::default(),
        None,
        &camera,
        Background::Sky,
    );
    let lookup = |_: DVec3| Blend::single(0);
    let direct = render(&RenderInputs {
        store: &store,
        source: &source,
        emission: None,
        albedo: None,
        channels: 1,
        storage_dirs: 1,
        storage_lookup: &lookup,
        medium: &MEDIUM,
        single: None,
        background: [0.0; 3],
        environment: None,
        camera: &camera,
    });
    assert!(solved.rgb.iter().any(|&v| v > 0.0));
    assert_eq!(solved, direct);
}

/// `lpm render OUT` of an anisotropic solve (g = 0.6, 2×2 storage directions per face) from the
/// solve's own view writes bitwise the solve's image.
#[test]
fn lpm_render_of_an_anisotropic_solve_is_bitwise_the_solves_image() {
    let dir = temp_dir("render-blend-again");
    let scene = write_scene(
        &dir,
        "[volume]\nprocedural = \"sphere\"\ndims = [16, 16, 16]\nvoxel_size = 1.0\n\
         [medium]\nsigma_t = 1.0\nalbedo = 0.8\ng = 0.6\n[[lights]]\nkind = \"sky\"\nradiance = 0.5\n\
         [[lights]]\nkind = \"sun\"\ndirection = [0.3, 1.0, 0.2]\nirradiance = 2.0\n\
         [solver]\ndirections_per_face = 2\nstorage_directions_per_face = 2\nmax_orders = 2\n\
         forward_peak = \"keep\"\n[camera]\nwidth = 40\nheight = 32\n",
    );
    let out = dir.join("out");
    let out_s = out.to_str().expect("utf-8 path");
    let run = |args: &[&str]| {
        let o = lpm_command(args).output().expect("run lpm");
        assert!(o.status.success(), "lpm {args:?}: {}", String::from_utf8_lossy(&o.stderr));
    };
    run(&["solve", scene.to_str().expect("utf-8 path"), "--out", out_s, "--backend", "cpu", "--no-fields"]);
    let render_json = std::fs::read_to_string(out.join("render-data/render.json")).expect("render.json");
    assert!(render_json.contains("\"storage_per_face\": 2"), "{render_json}");
    let again = dir.join("again.exr");
    run(&["render", out_s, "--image", again.to_str().expect("utf-8 path")]);
    assert_eq!(std::fs::read(&again).expect("again"), std::fs::read(out.join("image.exr")).expect("solve's image"));
}

/// The renderer adds no voxel-scale stripes of its own, across bricks either: a 32³ volume (2×2×2
/// bricks) whose density rises linearly along x, with a uniform source, seen through a pinhole
/// camera along +y, gives a row of pixels whose relative second differences stay far below the
/// voxel-to-voxel zigzag (1–3 %) of the demo cloud's solved field. So the faint vertical stripes
/// of `tools/scenes/demo_cloud.toml` (isotropic: no storage bins) are in the solved field (the
/// sun's light; benches/RESULTS.md, "Render: smooth in direction"), not made by the march.
#[test]
fn a_smooth_volume_renders_without_stripes_across_voxels_and_bricks() {
    let dir = temp_dir("render-blend-stripes");
    let store = BrickStore::create_with(&dir.join("store"), [32; 3], 1.0, |b, out| {
        for (l, x) in out.iter_mut().enumerate() {
            *x = 0.5 + 0.02 * (b[0] * 16 + (l % 16) as u32) as f32;
        }
        Ok(())
    })
    .expect("store");
    let mut source = store.create_field("source", 1, Coverage::Occupied).expect("field");
    for b in store.occupied_bricks().collect::<Vec<_>>() {
        source.brick_mut(b).expect("occupied").fill(1.0);
    }
    let camera = Camera {
        projection: Projection::Pinhole { fov_y_degrees: 40.0 },
        position: DVec3::new(16.0, -40.0, 16.0),
        look_at: DVec3::splat(16.0),
        up: DVec3::Z,
        width: 64,
        height: 64,
    };
    let lookup = |_: DVec3| Blend::single(0);
    let medium = Medium { sigma_t: [0.1; 3], albedo: [0.9; 3], g: 0.0, emission: [0.0; 3] };
    let image = render(&RenderInputs {
        store: &store,
        source: &source,
        emission: None,
        albedo: None,
        channels: 1,
        storage_dirs: 1,
        storage_lookup: &lookup,
        medium: &medium,
        single: None,
        background: [0.0; 3],
        environment: None,
        camera: &camera,
    });
    // Columns whose rays enter through the front face and leave through the back one (no kink
    // where the exit face changes), in rows above, at and below the centre.
    for y in [20, 32, 44] {
        let row: Vec<f64> = (16..48).map(|x| image.pixel(x, y)[0] as f64).collect();
        assert!(row.iter().all(|&p| p > 0.1), "row {y}: {row:?}");
        let worst = row.windows(3).map(|w| (w[0] - 2.0 * w[1] + w[2]).abs() / w[1]).fold(0.0, f64::max);
        assert!(worst < 1e-3, "row {y}: relative second difference {worst}");
    }
}
