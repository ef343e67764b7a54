//! The diffusion synthetic acceleration (`solver.acceleration`, `solver::acceleration`): at albedo
//! 0.999 a thick medium converges in about as many orders as at 0.9, to the same answer the plain
//! series converges to; the books close; the GPU driver and the twin agree; the bits do not depend
//! on the thread count.
use crate::common::*;
use lpm::scene::{Acceleration, Scene, Shape, SpatialScheme};
use lpm::solver::BackendKind::{Cpu, Gpu};

/// A thick grey box (σt = 1.5 per voxel: about 20 mean free paths across), sky and sun.
fn thick(albedo: f64, acceleration: Acceleration, tolerance: f64) -> Scene {
    let mut s = scene(Shape::Box, [13, 12, 14], [1.5; 3], [albedo; 3], vec![sky(1.0), sun([0.3, 0.2, 1.0], [2.0; 3])]);
    s.solver.directions_per_face = 2;
    s.solver.max_orders = 20_000;
    s.solver.tolerance = tolerance;
    s.solver.acceleration = acceleration;
    // The default scheme; the tests' scenes otherwise use "linear", which the correction refuses.
    s.solver.spatial = Some(SpatialScheme::Constant);
    s
}

#[test]
fn orders_at_albedo_0_999_stay_within_twice_those_at_0_9_and_reach_the_plain_answer() {
    let tol = 1e-4;
    let mut orders = Vec::new();
    for albedo in [0.9, 0.999] {
        let fast = solve(&format!("dsa-fast-{albedo}"), &thick(albedo, Acceleration::Diffusion, tol), Cpu);
        assert!(fast.run.plan.acceleration);
        // The plain series, converged far below the tolerance: the answer the acceleration must
        // reach (it changes how fast the series gets there, not where).
        let truth = solve(&format!("dsa-truth-{albedo}"), &thick(albedo, Acceleration::Off, 1e-9), Cpu);
        let plain = solve(&format!("dsa-plain-{albedo}"), &thick(albedo, Acceleration::Off, tol), Cpu);
        let o = &fast.run.outcome;
        let err = relative_l2(&fast.fluence_all(), &truth.fluence_all());
        let plain_err = relative_l2(&plain.fluence_all(), &truth.fluence_all());
        eprintln!(
            "albedo {albedo}: accelerated {} orders (error {err:.2e}), plain {} orders (error {plain_err:.2e}), \
             converged plain {} orders",
            o.orders, plain.run.outcome.orders, truth.run.outcome.orders
        );
        assert!(o.converged);
        assert!(err < 10.0 * tol, "albedo {albedo}: accelerated answer {err:.2e} from the converged one");
        assert!(
            err <= plain_err.max(tol),
            "albedo {albedo}: accelerated error {err:.2e} above the plain series' {plain_err:.2e}"
        );
        assert!(o.energy.relative_imbalance < 1e-5, "{:?}", o.energy);
        assert!(
            o.orders * 4 < plain.run.outcome.orders,
            "albedo {albedo}: {} vs {} orders",
            o.orders,
            plain.run.outcome.orders
        );
        orders.push(o.orders);
    }
    assert!(orders[1] <= 2 * orders[0], "orders at 0.999 ({}) more than twice those at 0.9 ({})", orders[1], orders[0]);
}

/// A heterogeneous RGB cloud (empty bricks, per-channel coefficients, anisotropic with 2×2 storage
/// directions): the GPU driver and the twin fold the same corrections. 3×2×2 bricks, 8 occupied: the
/// last x bricks (x ≥ 32) are empty, the cloud vanishing within 10 % of each face.
fn cloud() -> Scene {
    let mut s = scene(
        Shape::Cloud,
        [34, 26, 24],
        [2.0, 1.6, 1.2],
        [0.999, 0.99, 0.95],
        vec![sky(0.5), sun([0.4, -0.3, 1.0], [2.0; 3])],
    );
    s.medium.g = 0.4;
    s.solver.directions_per_face = 2;
    s.solver.storage_directions_per_face = Some(2);
    s.solver.max_orders = 60;
    s.solver.tolerance = 1e-4;
    s.solver.spatial = Some(SpatialScheme::Constant);
    s
}

#[test]
fn the_gpu_and_the_twin_fold_the_same_corrections() {
    let s = cloud();
    let gpu = solve("dsa-gpu", &s, Gpu);
    let cpu = solve("dsa-cpu", &s, Cpu);
    assert!(gpu.run.plan.acceleration, "the plan should accelerate at albedo 0.999: {:?}", gpu.run.plan.reasons);
    assert!(gpu.run.plan.bricks_empty > 0, "the cloud should leave bricks empty");
    assert!(gpu.run.outcome.converged && cpu.run.outcome.converged);
    assert_eq!(gpu.run.outcome.orders, cpu.run.outcome.orders);
    let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
    assert!(err < 1e-4, "GPU against twin: {err:.2e}");
    for o in [&gpu.run.outcome, &cpu.run.outcome] {
        assert!(o.energy.relative_imbalance < 1e-5, "{:?}", o.energy);
    }
    // Run to run, the GPU path gives the same bits.
    let again = solve("dsa-gpu-again", &s, Gpu);
    let bits = |s: &Solved| s.fluence_all().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert!(bits(&again) == bits(&gpu), "two GPU solves differ");
}

#[test]
fn the_accelerated_twin_gives_the_same_bits_on_any_number_of_threads() {
    let s = cloud();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        let solved = pool.install(|| solve(&format!("dsa-threads-{threads}"), &s, Cpu));
        (solved.run.outcome.orders, solved.fluence_all().iter().map(|v| v.to_bits()).collect::<Vec<_>>())
    };
    let one = run(1);
    for threads in [2, 3] {
        assert!(run(threads) == one, "{threads} threads differ from 1");
    }
}

#[test]
fn the_plan_says_when_it_accelerates() {
    let plan_of = |albedo: f64, acceleration: Acceleration| {
        let s = thick(albedo, acceleration, 1e-3);
        lpm::solver::plan::Plan::new(&s, 1, 0)
    };
    let on = plan_of(0.99, Acceleration::Auto);
    assert!(on.acceleration);
    assert!(on.reasons.iter().any(|r| r.starts_with("acceleration diffusion")), "{:?}", on.reasons);
    let low = plan_of(0.5, Acceleration::Auto);
    assert!(!low.acceleration);
    assert!(low.reasons.iter().any(|r| r.contains("shrink fast by themselves")), "{:?}", low.reasons);
    assert!(!plan_of(0.999, Acceleration::Off).acceleration);
    assert!(plan_of(0.5, Acceleration::Diffusion).acceleration);
    let mut linear = thick(0.99, Acceleration::Auto, 1e-3);
    linear.solver.spatial = Some(SpatialScheme::Linear);
    let plan = lpm::solver::plan::Plan::new(&linear, 1, 0);
    assert!(!plan.acceleration, "{:?}", plan.reasons);
    assert_eq!(plan_of(0.99, Acceleration::Auto).summary().acceleration, "diffusion");
}
