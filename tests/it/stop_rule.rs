//! The stop rule (`solver::remaining`): a solve that says it converged at tolerance τ is within
//! about τ of its converged self in every voxel of the medium, the dark, dense core included.

use crate::common::*;
use lpm::scene::Shape;
use lpm::solver::BackendKind::{Cpu, Gpu};

/// A thick, high-albedo box: its core converges last. Solved at 1e-3 and at 1e-7 (the converged
/// self), every voxel with medium must agree to ~1e-3, and the report's estimate must be honest
/// (at least the largest error actually left, within a factor of a few).
#[test]
fn tolerance_holds_in_every_voxel_of_a_thick_high_albedo_box() {
    let n = 16;
    let mut sc = scene(Shape::Box, [n; 3], [1.5; 3], [0.98; 3], vec![sky(1.0)]);
    sc.solver.directions_per_face = 2;
    sc.solver.max_orders = 5000;
    sc.solver.tolerance = 1e-3;
    let loose = solve("stop-loose", &sc, Cpu);
    sc.solver.tolerance = 1e-7;
    let tight = solve("stop-tight", &sc, Cpu);
    assert!(loose.run.outcome.converged && tight.run.outcome.converged);
    let (a, b) = (loose.fluence_all(), tight.fluence_all());
    let worst = a.iter().zip(&b).map(|(x, y)| (x / y - 1.0).abs()).fold(0.0, f64::max);
    let estimate = loose.run.outcome.remaining.expect("remaining error estimate");
    // What the old rule (newest order's power over the total below the tolerance) would have
    // stopped at, from the loose solve's own history.
    let old_stop =
        loose.run.outcome.history.iter().position(|r| r.new_source_power <= 1e-3 * r.total_source_power).map(|i| i + 1);
    eprintln!(
        "tolerance 1e-3: {} orders (the power rule would stop after {old_stop:?}), worst voxel {worst:.2e}, \
         estimated max {:.2e} (L2 {:.2e}); converged self: {} orders",
        loose.run.outcome.orders, estimate.max, estimate.l2, tight.run.outcome.orders
    );
    assert!(worst <= 1.5e-3, "worst voxel {worst:.3e} off its converged value");
    assert!(estimate.max >= 0.5 * worst, "the estimate {estimate:?} understates the error {worst}");
    assert!(estimate.max <= 1e-3);
}

/// The GPU computes the same estimate from its f32 fields and stops at the same order. (Albedo
/// 0.9: 55 orders before the stop, against 79 at 0.95.)
#[test]
fn gpu_and_twin_stop_at_the_same_order() {
    let mut sc = scene(Shape::Sphere, [24, 20, 22], [1.0; 3], [0.9; 3], vec![sky(1.0)]);
    sc.solver.tolerance = 1e-3;
    let (g, c) = (solve("stop-gpu", &sc, Gpu), solve("stop-cpu", &sc, Cpu));
    let (rg, rc) = (g.run.outcome.remaining.expect("gpu"), c.run.outcome.remaining.expect("cpu"));
    eprintln!("orders GPU {} CPU {}; remaining GPU {rg:?} CPU {rc:?}", g.run.outcome.orders, c.run.outcome.orders);
    assert_eq!(g.run.outcome.orders, c.run.outcome.orders);
    assert!(g.run.outcome.converged && c.run.outcome.converged);
    assert!((rg.max / rc.max - 1.0).abs() < 1e-3, "{rg:?} vs {rc:?}");
}
