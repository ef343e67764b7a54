//! Analytic checks of the discretisation on the CPU twin.
use crate::common::*;
use lpm::scene::Shape;
use lpm::solver::cpu::CpuTwin;
use lpm::solver::orders::run_orders;
use lpm::solver::plan::Plan;
use std::f64::consts::PI;

#[test]
fn furnace_fluence_is_four_pi() {
    let scene = scene(Shape::Box, [12, 10, 14], [0.2; 3], [1.0; 3], vec![sky(1.0)]);
    let plan = Plan::new(&scene, 8, 0);
    let mut twin = CpuTwin::new(&plan, |_| 1.0).unwrap();
    let out = run_orders(&plan, &mut twin, Default::default(), |_, _| {}).unwrap();
    assert!(out.converged, "{:?}", out.residual);
    for v in [[0, 0, 0], [5, 5, 7], [11, 9, 13]] {
        let phi = twin.fluence(v, 0);
        assert!((phi / (4.0 * PI) - 1.0).abs() < 1e-3, "{v:?}: {phi}");
    }
    assert!(out.energy.relative_imbalance < 1e-9, "{:?}", out.energy);
}

#[test]
fn energy_balances_with_sun_sky_and_absorption() {
    let mut scene = scene(
        Shape::Sphere,
        [9, 11, 8],
        [0.8, 0.5, 0.3],
        [0.9, 0.7, 0.5],
        vec![sky(0.7), sun([0.3, 1.0, 0.2], [2.0, 1.5, 1.0])],
    );
    scene.medium.emission = [0.2, 0.0, 0.1];
    scene.medium.g = 0.6;
    let plan = Plan::new(&scene, 1, 0);
    let dims = scene.volume.dims;
    let mut twin = CpuTwin::new(&plan, |v| lpm_density_sphere(dims, v)).unwrap();
    let out = run_orders(&plan, &mut twin, Default::default(), |_, _| {}).unwrap();
    assert!(out.energy.relative_imbalance < 1e-9, "{:?}", out.energy);
}

fn lpm_density_sphere(dims: [u32; 3], v: [u32; 3]) -> f32 {
    let r = 0.4 * *dims.iter().min().unwrap() as f64;
    let d2: f64 = (0..3).map(|a| (v[a] as f64 + 0.5 - dims[a] as f64 / 2.0).powi(2)).sum();
    if d2 <= r * r {
        1.0
    } else {
        0.0
    }
}
