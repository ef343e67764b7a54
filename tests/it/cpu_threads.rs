//! The CPU backend on every core: the same bits at any thread count, the GPU's answer, and the
//! empty bricks skipped as the GPU skips them.
use crate::common::*;
use lpm::scene::{Scene, Shape, SpatialScheme};
use lpm::solver::BackendKind::{Cpu, Gpu};

/// Solves `scene` on the CPU backend inside a rayon pool of `threads` threads.
fn solve_on_threads(name: &str, scene: &Scene, threads: usize) -> Solved {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
    pool.install(|| solve(&format!("{name}-{threads}"), scene, Cpu))
}

/// Fluence and summed source of every occupied brick, as bits.
fn field_bits(s: &Solved) -> Vec<u32> {
    let mut bits = Vec::new();
    for brick in s.store.occupied_bricks() {
        for field in [&s.fields.fluence_total, &s.fields.source_total] {
            bits.extend(field.brick(brick).expect("occupied brick").iter().map(|v| v.to_bits()));
        }
    }
    bits
}

/// Two clouds with a brick-wide vacuum gap between them (so whole planes are skipped), an RGB
/// anisotropic medium with 2×2 storage directions, sun and sky: 3×2×2 bricks, the first blob in
/// the first brick column (x < 16), the second in the third (x ≥ 32), the middle one empty.
fn gapped_cloud(name: &str) -> Scene {
    let dims = [48, 20, 20];
    let mut sc = raw_scene(name, dims, 0.9, 0.9, vec![sky(0.4), sun([0.3, -0.5, 1.0], [2.0; 3])], |v| {
        let blob = |c: [f64; 3], r: f64| {
            let d2: f64 = (0..3).map(|i| (v[i] as f64 + 0.5 - c[i]).powi(2)).sum();
            (1.0 - d2 / (r * r)).max(0.0) as f32
        };
        blob([8.0, 10.0, 10.0], 8.0) + blob([40.0, 9.5, 10.5], 7.5)
    });
    sc.medium.sigma_t = [0.9, 0.7, 0.5];
    sc.medium.albedo = [0.95, 0.9, 0.8];
    sc.medium.g = 0.6;
    sc.solver.directions_per_face = 3;
    sc.solver.storage_directions_per_face = Some(2);
    sc.solver.max_orders = 4;
    sc.solver.tolerance = 1e-30;
    sc
}

#[test]
fn cpu_backend_is_bitwise_identical_at_every_thread_count() {
    for spatial in [SpatialScheme::Constant, SpatialScheme::Linear] {
        let mut sc = gapped_cloud("cpu-threads");
        sc.solver.spatial = Some(spatial);
        let one = solve_on_threads("cpu-threads", &sc, 1);
        assert!(one.run.plan.bricks_empty >= 2, "the scene must have empty bricks: {}", one.run.plan.bricks_empty);
        let reference = field_bits(&one);
        assert!(reference.iter().any(|&b| f32::from_bits(b) > 0.0));
        for threads in [2, 5] {
            let many = solve_on_threads("cpu-threads", &sc, threads);
            assert_eq!(many.run.outcome.orders, one.run.outcome.orders);
            assert!(field_bits(&many) == reference, "{spatial:?}: {threads} threads differ from 1");
            assert_eq!(
                many.run.outcome.energy.relative_imbalance.to_bits(),
                one.run.outcome.energy.relative_imbalance.to_bits()
            );
        }
    }
}

#[test]
fn cpu_backend_matches_the_gpu_across_a_vacuum_gap() {
    let sc = gapped_cloud("cpu-gpu-gap");
    let cpu = solve_on_threads("cpu-gpu-gap", &sc, 2);
    let gpu = solve("cpu-gpu-gap-gpu", &sc, Gpu);
    assert_eq!(gpu.run.outcome.orders, cpu.run.outcome.orders);
    let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
    assert!(err <= 1e-4, "relative L2 {err}");
    assert!(cpu.run.outcome.energy.relative_imbalance < 1e-9, "{:?}", cpu.run.outcome.energy);
}

#[test]
fn cpu_backend_skips_empty_bricks_but_solves_an_all_occupied_box() {
    // A box fills every brick: nothing is skipped, and the furnace still holds (4π everywhere).
    let mut sc = scene(Shape::Box, [20, 18, 17], [0.2; 3], [1.0; 3], vec![sky(1.0)]);
    sc.solver.tolerance = 1e-6;
    let s = solve_on_threads("cpu-furnace", &sc, 2);
    assert_eq!(s.run.plan.bricks_empty, 0);
    for (i, phi) in s.fluence_all().iter().enumerate() {
        assert!((phi / (4.0 * std::f64::consts::PI) - 1.0).abs() < 1e-3, "voxel {i}: {phi}");
    }
}
