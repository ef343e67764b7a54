//! The sky on directions of its own (`solver.sky_directions_per_face`, `lpm::solver::plan`, "The
//! sky's own directions"): order 0 sweeps the sky along k_sky×k_sky directions per face, the
//! scattered light keeps to the k×k. Both backends, the same answer; the books still close; asking
//! for k_sky = k changes nothing. (The accuracy it buys next to the faces is
//! `spatial_accuracy::with_its_own_directions_…`.)

use crate::common::*;
use lpm::scene::Shape;
use lpm::solver::BackendKind::{Cpu, Gpu};

/// An RGB cloud with a forward-scattering medium (storage directions and collect rows of the sky's
/// own directions in play), a sky and a sun, solved a few orders on both backends.
#[test]
fn the_gpu_matches_the_twin_and_the_books_close_with_the_skys_own_directions() {
    let mut sc = scene(
        Shape::Cloud,
        [20, 18, 22],
        [1.2, 1.0, 0.8],
        [0.9, 0.85, 0.8],
        vec![sky(0.7), sun([0.3, -0.4, 1.0], [2.0; 3])],
    );
    sc.medium.g = 0.4;
    sc.solver.directions_per_face = 3;
    sc.solver.sky_directions_per_face = Some(7);
    sc.solver.max_orders = 5;
    let (g, c) = (solve("sky-own-gpu", &sc, Gpu), solve("sky-own-cpu", &sc, Cpu));
    assert_eq!(c.run.plan.sky_faces.iter().map(Vec::len).sum::<usize>(), 6 * 49);
    assert!(
        c.run.plan.reasons.iter().any(|r| r.starts_with("sky: its light enters along 7×7")),
        "{:?}",
        c.run.plan.reasons
    );
    for s in [&g, &c] {
        assert!(s.run.outcome.energy.relative_imbalance < 1e-5, "{:?}", s.run.outcome.energy);
    }
    let err = relative_l2(&g.fluence_all(), &c.fluence_all());
    assert!(err <= 1e-4, "GPU vs twin {err}");
    // The same light, integrated over other directions: close to the sky on the shared ones.
    sc.solver.sky_directions_per_face = None;
    let shared = solve("sky-shared-cpu", &sc, Cpu);
    let apart = relative_l2(&c.fluence_all(), &shared.fluence_all());
    assert!(apart > 1e-4 && apart < 0.05, "own vs shared sky directions: {apart}");
}

/// k_sky = k is no refinement: the plan has no sky directions of its own and the fields are the
/// very bits of a scene that leaves the option out.
#[test]
fn asking_for_as_many_sky_directions_as_the_others_changes_nothing() {
    let mut sc = scene(Shape::Sphere, [12, 12, 12], [0.8; 3], [0.9; 3], vec![sky(1.0)]);
    sc.solver.max_orders = 4;
    let plain = solve("sky-same-none", &sc, Cpu);
    sc.solver.sky_directions_per_face = Some(sc.solver.directions_per_face);
    let same = solve("sky-same-k", &sc, Cpu);
    assert!(same.run.plan.sky_faces.is_empty());
    assert_eq!(same.run.plan.summary().sky_directions_per_face, sc.solver.directions_per_face);
    assert_eq!(plain.field_bits(), same.field_bits());
}

/// The sky's own directions go through the same passes as a face's: resident, or streamed at the
/// smallest budget (one direction per pass, one plane per slice), the bits are the same, and the
/// budget holds with their tables counted.
#[test]
fn resident_or_streamed_at_the_smallest_budget_the_skys_own_directions_give_the_same_bits() {
    let mut sc = scene(Shape::Sphere, [18, 16, 20], [1.0; 3], [0.8; 3], vec![sky(1.0)]);
    sc.solver.directions_per_face = 2;
    sc.solver.sky_directions_per_face = Some(5);
    sc.solver.max_orders = 3;
    let resident = solve("sky-resident", &sc, Gpu);
    assert!(resident.run.memory.expect("memory plan").is_resident());
    sc.solver.device_residency = lpm::scene::DeviceResidency::Streamed;
    let needed = smallest_unit(&sc);
    sc.solver.device_memory_budget = Some(needed);
    let tight = solve("sky-tight", &sc, Gpu);
    let m = tight.run.memory.expect("memory plan");
    assert!(!m.is_resident() && m.directions_per_pass == 1 && m.planes_per_slice == 1, "{m:?}");
    assert!(tight.run.peak_device_bytes <= needed, "peak {} over budget {needed}", tight.run.peak_device_bytes);
    assert!(tight.field_bits() == resident.field_bits(), "streamed at the smallest budget changed the result");
}
