//! The forward peak (`solver.forward_peak`): δ-M scaling of a strongly forward-peaked phase function.

use crate::common::*;
use lpm::scene::{ForwardPeak, Shape};
use lpm::solver::plan::Plan;
use lpm::solver::BackendKind::{Cpu, Gpu};

#[test]
fn auto_applies_delta_m_from_g_one_half_and_keeps_absorption() {
    let mut sc = scene(Shape::Sphere, [16, 16, 16], [1.0, 0.8, 0.6], [0.9, 0.95, 0.99], vec![sky(1.0)]);
    for (g, applied) in [(0.0, false), (0.3, false), (0.5, true), (0.8, true), (0.95, true), (-0.8, false)] {
        sc.medium.g = g;
        let plan = Plan::new(&sc, 1, 0);
        assert_eq!(plan.delta_m.is_some(), applied, "g = {g}");
        let summary = plan.summary();
        assert_eq!(summary.phase_g, g);
        if let Some(f) = plan.delta_m {
            assert!((f - g * g).abs() < 1e-15);
            assert!((plan.medium.g - (g - f) / (1.0 - f)).abs() < 1e-12);
            for ch in 0..3 {
                let (st, ss) = (sc.medium.sigma_t[ch], sc.medium.sigma_t[ch] * sc.medium.albedo[ch]);
                let (st2, ss2, sa2) = plan.coefficients(ch);
                // σs' = (1 − f)σs, σt' = σt − fσs, σa unchanged.
                assert!((ss2 - (1.0 - f) * ss).abs() < 1e-12, "ch {ch}");
                assert!((st2 - (st - f * ss)).abs() < 1e-12, "ch {ch}");
                assert!((sa2 - (st - ss)).abs() < 1e-12, "ch {ch}");
            }
        } else {
            assert_eq!(plan.medium, sc.medium);
        }
    }
    // Forced on or off.
    sc.medium.g = 0.3;
    sc.solver.forward_peak = ForwardPeak::DeltaM;
    assert!(Plan::new(&sc, 1, 0).delta_m.is_some());
    sc.medium.g = 0.9;
    sc.solver.forward_peak = ForwardPeak::Keep;
    let plan = Plan::new(&sc, 1, 0);
    assert!(plan.delta_m.is_none());
    // Two storage directions per face cannot hold g = 0.9: the discrete scattering is much wider.
    assert!(plan.effective_g < 0.8, "{}", plan.effective_g);
}

/// With δ-M on, the solve still balances its energy and the GPU matches the twin.
#[test]
fn delta_m_solve_balances_and_gpu_matches_the_twin() {
    let mut sc =
        scene(Shape::Cloud, [24, 20, 28], [1.5; 3], [0.95; 3], vec![sky(1.0), sun([0.3, -0.4, 1.0], [2.0; 3])]);
    sc.medium.g = 0.85;
    sc.solver.max_orders = 8;
    let (g, c) = (solve("deltam-gpu", &sc, Gpu), solve("deltam-cpu", &sc, Cpu));
    assert!(g.run.plan.delta_m.is_some());
    assert!(g.run.outcome.energy.relative_imbalance < 1e-5, "{:?}", g.run.outcome.energy);
    let err = relative_l2(&g.fluence_all(), &c.fluence_all());
    assert!(err <= 1e-4, "GPU vs twin {err}");
}
