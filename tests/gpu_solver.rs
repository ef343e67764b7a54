//! The GPU solver against its CPU twin and against closed forms, on lavapipe with validation and
//! synchronization validation on (a validation error fails the solve, hence the test).
mod common;
use common::*;
use lpm::scene::{Scene, Shape};
use lpm::solver::segment::e1;
use lpm::solver::sweep::{column, FaceSweep};
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
    let mut scene = scene(Shape::Cloud, [40, 36, 44], [0.9, 0.7, 0.5], [0.95, 0.9, 0.8], vec![sky(0.4), sun([0.3, 1.0, 0.2], [3.0, 2.8, 2.5])]);
    scene.solver.directions_per_face = 4;
    let err = gpu_vs_cpu("rgb-cloud", scene, 8);
    assert!(err <= 1e-4, "relative L2 {err}");
}

#[test]
fn gpu_matches_cpu_twin_on_anisotropic_cloud() {
    let mut scene = scene(Shape::Cloud, [32, 30, 34], [0.8; 3], [0.9; 3], vec![sky(0.3), sun([-0.5, 0.4, 1.0], [2.0; 3])]);
    scene.medium.g = 0.7;
    scene.solver.directions_per_face = 4;
    scene.solver.storage_directions_per_face = Some(2);
    let err = gpu_vs_cpu("aniso-cloud", scene, 6);
    assert!(err <= 1e-4, "relative L2 {err}");
}

#[test]
fn dims_not_multiple_of_sixteen_match_the_twin() {
    let mut scene = scene(Shape::Sphere, [37, 20, 53], [0.6; 3], [0.8; 3], vec![sky(1.0), sun([1.0, 1.0, 0.0], [1.0; 3])]);
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
    let mut scene = scene(Shape::Cloud, [30, 28, 26], [1.2, 0.9, 0.6], [0.9, 0.6, 0.3], vec![sky(0.5), sun([0.2, -0.4, 1.0], [2.0, 1.0, 3.0])]);
    scene.medium.emission = [0.0, 0.3, 0.1];
    scene.solver.tolerance = 1e-5;
    let s = solve("energy", &scene, Gpu);
    let e = &s.run.outcome.energy;
    assert!(e.relative_imbalance < 1e-5, "{e:?}");
    assert!(e.absorbed.iter().all(|&a| a > 0.0));
}

#[test]
fn two_gpu_solves_are_bitwise_identical() {
    let mut scene = scene(Shape::Cloud, [33, 17, 21], [0.7, 0.6, 0.5], [0.9; 3], vec![sky(1.0), sun([0.1, 0.2, 1.0], [2.0; 3])]);
    scene.medium.g = 0.4;
    scene.solver.max_orders = 4;
    let a = solve("det-a", &scene, Gpu).fluence_all();
    let b = solve("det-b", &scene, Gpu).fluence_all();
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}

/// A scene whose density comes from a raw file written here.
fn raw_scene(name: &str, dims: [u32; 3], density: impl Fn([u32; 3]) -> f32) -> Scene {
    let path = temp_dir(name).join("density.raw");
    let mut bytes = Vec::new();
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                bytes.extend_from_slice(&density([x, y, z]).to_le_bytes());
            }
        }
    }
    std::fs::write(&path, bytes).expect("write raw");
    let mut s = scene(Shape::Box, dims, [1.0; 3], [0.9; 3], vec![sky(2.0)]);
    s.volume.source = lpm::scene::VolumeSource::Raw { path };
    s
}

#[test]
fn empty_volume_sees_the_sky_everywhere() {
    let scene = raw_scene("empty-raw", [20, 18, 17], |_| 0.0);
    let s = solve("empty", &scene, Gpu);
    assert_eq!(s.run.plan.bricks_empty, s.run.plan.bricks_total);
    for phi in s.fluence_all() {
        assert!((phi - 8.0 * PI).abs() < 1e-4, "{phi}");
    }
    assert_eq!(s.run.outcome.orders, 1);
}

#[test]
fn single_dense_voxel_is_stable_and_matches_the_twin() {
    let mut scene = raw_scene("dense-voxel-raw", [17, 17, 17], |v| if v == [8, 8, 8] { 1e4 } else { 0.0 });
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

/// Fluence of a pure absorber box under a uniform sky, from Beer–Lambert along the discrete rays of
/// the direction set: a ray born `m` planes before voxel v arrives with e^{−σ s m} and its segment
/// average there is e^{−σ s m}·E1(σ s).
fn beer_lambert_over_the_direction_set(scene: &Scene, plan: &lpm::solver::plan::Plan, v: [u32; 3]) -> f64 {
    let sigma = scene.medium.sigma_t[0];
    let mut phi = 0.0;
    for dir in plan.faces.iter().flatten() {
        let sweep = FaceSweep::new(dir.face, plan.dims);
        let f = sweep.geometry();
        let t = if f.sign > 0.0 { v[f.axis] } else { plan.dims[f.axis] - 1 - v[f.axis] };
        // The ray in v at plane t, and the plane it was born in (its last wrap).
        let (vb, vc) = (v[f.lateral[0]] as i64, v[f.lateral[1]] as i64);
        let o = dir.offsets[t as usize];
        let p = (vb - o[0] as i64).rem_euclid(sweep.n[1] as i64) as u32;
        let q = (vc - o[1] as i64).rem_euclid(sweep.n[2] as i64) as u32;
        let wrap_at = |t: u32| {
            let o = dir.offsets[t as usize];
            (column(p, o[0], sweep.n[1]).1, column(q, o[1], sweep.n[2]).1)
        };
        let mut born = t;
        while born > 0 && wrap_at(born - 1) == wrap_at(t) {
            born -= 1;
        }
        let x = sigma * dir.path_length;
        phi += dir.fluence_weight * (-x * (t - born) as f64).exp() * e1(x);
    }
    phi
}

#[test]
fn pure_absorber_matches_beer_lambert_over_the_direction_set() {
    let mut scene = scene(Shape::Box, [21, 19, 23], [0.3; 3], [0.0; 3], vec![sky(1.0)]);
    scene.solver.directions_per_face = 3;
    let s = solve("absorber", &scene, Gpu);
    for v in [[10, 9, 11], [0, 0, 0], [20, 3, 17], [5, 18, 22]] {
        let expected = beer_lambert_over_the_direction_set(&scene, &s.run.plan, v);
        let got = s.fluence(v, 0);
        assert!((got / expected - 1.0).abs() < 1e-5, "{v:?}: {got} vs {expected}");
    }
}

/// ∫ e^{−σ d(x, −ω)} dω at point x of a box [0, n]³, by a fine cube-face quadrature.
fn exact_absorber_fluence(sigma: f64, n: [f64; 3], x: [f64; 3]) -> f64 {
    let fine = lpm::quadrature::PropagationSet::new(96);
    fine.directions
        .iter()
        .map(|d| {
            let w = d.omega.to_array();
            let dist = (0..3)
                .map(|a| if w[a] > 0.0 { x[a] / w[a] } else if w[a] < 0.0 { (x[a] - n[a]) / w[a] } else { f64::INFINITY })
                .fold(f64::INFINITY, f64::min);
            d.solid_angle * (-sigma * dist).exp()
        })
        .sum()
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
                exact += exact_absorber_fluence(0.2, [n as f64; 3], [sub(i), sub(j), sub(l)]) / 64.0;
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
