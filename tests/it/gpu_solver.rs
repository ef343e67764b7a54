//! The GPU solver against its CPU twin and against closed forms, on lavapipe with validation and
//! synchronization validation on (a validation error fails the solve, hence the test).
use crate::common::*;
use lpm::scene::{Scene, Shape, SpatialScheme};
use lpm::solver::BackendKind::{Cpu, Gpu};
use std::f64::consts::PI;

/// Runs both backends for a fixed number of orders (so that a residual near the tolerance cannot
/// make them stop at different orders) and returns the relative L2 difference of the fluence.
fn gpu_vs_cpu(name: &str, mut scene: Scene, orders: u32) -> f64 {
    scene.solver.max_orders = orders;
    scene.solver.tolerance = 1e-30;
    let gpu = solve(&format!("{name}-gpu"), &scene, Gpu);
    let cpu = solve(&format!("{name}-cpu"), &scene, Cpu);
    assert_eq!(gpu.run.outcome.orders, cpu.run.outcome.orders);
    let (g, c) = (gpu.fluence_all(), cpu.fluence_all());
    assert!(g.iter().all(|v| v.is_finite() && *v >= 0.0));
    relative_l2(&g, &c)
}

#[test]
fn gpu_matches_cpu_twin_on_rgb_cloud_with_sun_and_sky() {
    let mut scene = scene(
        Shape::Cloud,
        [34, 26, 30],
        [0.9, 0.7, 0.5],
        [0.95, 0.9, 0.8],
        vec![sky(0.4), sun([0.3, 1.0, 0.2], [3.0, 2.8, 2.5])],
    );
    scene.solver.directions_per_face = 4;
    let err = gpu_vs_cpu("rgb-cloud", scene, 4);
    assert!(err <= 1e-4, "relative L2 {err}");
}

#[test]
fn gpu_matches_cpu_twin_on_anisotropic_cloud() {
    let mut scene =
        scene(Shape::Cloud, [24, 22, 26], [0.8; 3], [0.9; 3], vec![sky(0.3), sun([-0.5, 0.4, 1.0], [2.0; 3])]);
    scene.medium.g = 0.7;
    scene.solver.directions_per_face = 4;
    scene.solver.storage_directions_per_face = Some(2);
    let err = gpu_vs_cpu("aniso-cloud", scene, 6);
    assert!(err <= 1e-4, "relative L2 {err}");
}

#[test]
fn dims_not_multiple_of_sixteen_match_the_twin() {
    let mut scene =
        scene(Shape::Sphere, [37, 20, 53], [0.6; 3], [0.8; 3], vec![sky(1.0), sun([1.0, 1.0, 0.0], [1.0; 3])]);
    scene.solver.directions_per_face = 2;
    let err = gpu_vs_cpu("odd-dims", scene, 5);
    assert!(err <= 1e-4, "relative L2 {err}");
}

#[test]
fn furnace_fluence_is_four_pi_on_the_gpu() {
    let mut scene = scene(Shape::Box, [24, 24, 24], [0.1; 3], [1.0; 3], vec![sky(1.0)]);
    scene.solver.tolerance = 1e-5;
    let s = solve("furnace", &scene, Gpu);
    assert!(s.run.outcome.converged);
    for (i, phi) in s.fluence_all().iter().enumerate() {
        assert!((phi / (4.0 * PI) - 1.0).abs() < 1e-3, "voxel {i}: {phi}");
    }
}

#[test]
fn energy_balances_on_the_gpu() {
    let mut scene = scene(
        Shape::Cloud,
        [30, 28, 26],
        [1.2, 0.9, 0.6],
        [0.9, 0.6, 0.3],
        vec![sky(0.5), sun([0.2, -0.4, 1.0], [2.0, 1.0, 3.0])],
    );
    scene.medium.emission = [0.0, 0.3, 0.1];
    // The books close at any order count (what is left is counted as unpropagated): a few orders
    // show it as well as the converged solve.
    scene.solver.tolerance = 1e-5;
    scene.solver.max_orders = 8;
    let s = solve("energy", &scene, Gpu);
    let e = &s.run.outcome.energy;
    assert!(e.relative_imbalance < 1e-5, "{e:?}");
    assert!(e.absorbed.iter().all(|&a| a > 0.0));
}

#[test]
fn two_gpu_solves_are_bitwise_identical() {
    let mut scene =
        scene(Shape::Cloud, [33, 17, 21], [0.7, 0.6, 0.5], [0.9; 3], vec![sky(1.0), sun([0.1, 0.2, 1.0], [2.0; 3])]);
    scene.medium.g = 0.4;
    scene.solver.max_orders = 4;
    let a = solve("det-a", &scene, Gpu).fluence_all();
    let b = solve("det-b", &scene, Gpu).fluence_all();
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}

#[test]
fn empty_volume_is_streamed_but_not_solved() {
    // Every brick empty: the rays cross vacuum slices only, nothing is stored or solved.
    let scene = raw_scene("empty-raw", [20, 18, 17], 1.0, 0.9, vec![sky(2.0)], |_| 0.0);
    let s = solve("empty", &scene, Gpu);
    assert_eq!(s.run.plan.bricks_empty, s.run.plan.bricks_total);
    assert_eq!(s.fields.fluence_total.stored_bricks(), 0);
    assert_eq!(s.run.outcome.orders, 1);
    let e = &s.run.outcome.energy;
    assert!(e.relative_imbalance.abs() < 1e-6, "{e:?}");
}

#[test]
fn empty_voxels_of_an_occupied_brick_see_the_sky() {
    // One faint voxel makes its brick occupied; its empty voxels are solved (and see the whole sky),
    // the other bricks are not.
    let scene =
        raw_scene("faint-raw", [20, 18, 17], 1.0, 0.9, vec![sky(2.0)], |v| if v == [0, 0, 0] { 1e-9 } else { 0.0 });
    let s = solve("faint", &scene, Gpu);
    assert_eq!(s.run.plan.bricks_empty + 1, s.run.plan.bricks_total);
    for (b, v) in [(0, [3u32, 9, 15]), (1, [17, 2, 2])] {
        let stored = s.fields.fluence_total.brick(s.store.grid().locate(v).0).is_some();
        assert_eq!(stored, b == 0, "{v:?}");
        if stored {
            assert!((s.fluence(v, 0) - 8.0 * PI).abs() < 1e-4, "{}", s.fluence(v, 0));
        }
    }
}

#[test]
fn single_dense_voxel_is_stable_and_matches_the_twin() {
    let mut scene =
        raw_scene(
            "dense-voxel-raw",
            [17, 17, 17],
            1.0,
            0.9,
            vec![sky(2.0)],
            |v| if v == [8, 8, 8] { 1e4 } else { 0.0 },
        );
    scene.solver.max_orders = 6;
    scene.solver.tolerance = 1e-30;
    scene.lights.push(sun([0.2, 0.3, 1.0], [5.0; 3]));
    let gpu = solve("dense-voxel-gpu", &scene, Gpu);
    let cpu = solve("dense-voxel-cpu", &scene, Cpu);
    let (g, c) = (gpu.fluence_all(), cpu.fluence_all());
    assert!(g.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!(relative_l2(&g, &c) <= 1e-4);
    assert!(gpu.run.outcome.energy.relative_imbalance < 1e-5, "{:?}", gpu.run.outcome.energy);
    // The dense voxel's fluence is tiny (light barely enters) but positive.
    assert!(gpu.fluence([8, 8, 8], 0) > 0.0 && gpu.fluence([8, 8, 8], 0) < gpu.fluence([0, 0, 0], 0));
}

#[test]
fn pure_absorber_matches_beer_lambert_over_the_direction_set() {
    let mut scene = scene(Shape::Box, [21, 19, 23], [0.3; 3], [0.0; 3], vec![sky(1.0)]);
    scene.solver.directions_per_face = 3;
    scene.solver.spatial = Some(SpatialScheme::Constant);
    let s = solve("absorber", &scene, Gpu);
    for v in [[10, 9, 11], [0, 0, 0], [20, 3, 17], [5, 18, 22]] {
        let expected = beer_lambert_over_the_direction_set(scene.medium.sigma_t[0], &s.run.plan, v);
        let got = s.fluence(v, 0);
        assert!((got / expected - 1.0).abs() < 1e-5, "{v:?}: {got} vs {expected}");
    }
}

#[test]
fn pure_absorber_approaches_the_exact_integral_as_directions_grow() {
    // The exact voxel-average fluence of the centre voxel (4³ sub-points), against k = 1, 2, 4, 8, 16.
    // The direction error falls fast with k until the spatial discretisation (one ray per voxel,
    // nearest voxel per plane) is what remains.
    let n = 15;
    let centre = [7, 7, 7];
    let sub = |i: u32| 7.0 + (i as f64 + 0.5) / 4.0;
    let mut exact = 0.0;
    for i in 0..4 {
        for j in 0..4 {
            for l in 0..4 {
                exact += exact_absorber_fluence(0.2, [n as f64; 3], [sub(i), sub(j), sub(l)], 96) / 64.0;
            }
        }
    }
    let mut errors = Vec::new();
    for k in [1, 2, 4, 8, 16] {
        let mut scene = scene(Shape::Box, [n; 3], [0.2; 3], [0.0; 3], vec![sky(1.0)]);
        scene.solver.directions_per_face = k;
        let s = solve(&format!("absorber-k{k}"), &scene, Cpu);
        errors.push(((s.fluence(centre, 0) - exact) / exact).abs());
    }
    eprintln!("relative error against the exact integral for k = 1, 2, 4, 8, 16: {errors:?}");
    assert!(errors.windows(2).all(|w| w[1] < w[0]), "errors should fall as k grows: {errors:?}");
    assert!(errors[4] < 2e-3 && errors[0] > 100.0 * errors[4], "{errors:?}");
}
