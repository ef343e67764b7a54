//! The diffusion correction (`solver.diffusion_correction`, `lpm::solver::antidiffusion`): both
//! backends apply the same pass, it keeps the energy books and determinism, and it takes much of
//! the lattice's numerical diffusion out of a thick, high-albedo box. (A killed solve with it on
//! resumes to the same bits: `killable_cloud_scene` turns it on for tests/it/resume.rs.)

use crate::common::*;
use lpm::scene::{DiffusionCorrection, Scene, Shape};
use lpm::solver::BackendKind::{Cpu, Gpu};

/// A 20×18×22 sphere, albedo 0.95, sky and a slanted sun, k = 3: scattering everywhere, a medium
/// edge (where the positivity cap works) and empty bricks around it.
fn sphere_scene() -> Scene {
    let mut sc =
        scene(Shape::Sphere, [20, 18, 22], [0.9; 3], [0.95; 3], vec![sky(0.5), sun([0.3, -0.4, 0.8], [2.0; 3])]);
    sc.solver.directions_per_face = 3;
    sc.solver.max_orders = 400;
    // Loose (the pass runs every order all the same, and the books count the light not yet
    // propagated): the suite's time goes to what differs.
    sc.solver.tolerance = 1e-2;
    sc.solver.diffusion_correction = DiffusionCorrection::On;
    sc
}

#[test]
fn gpu_matches_the_twin_balances_and_repeats_bitwise() {
    let sc = sphere_scene();
    let gpu = solve("dc-gpu", &sc, Gpu);
    let again = solve("dc-gpu-again", &sc, Gpu);
    let twin = solve("dc-twin", &sc, Cpu);
    let kappa = gpu.run.plan.diffusion_correction;
    assert!(kappa.iter().all(|&k| k > 0.01 && k < 0.2), "κ = {kappa:?}");
    let diff = relative_l2(&gpu.fluence_all(), &twin.fluence_all());
    eprintln!(
        "κ = {kappa:?}: GPU vs twin {diff:.2e}, orders {} / {}, imbalance {:.1e} / {:.1e}",
        gpu.run.outcome.orders,
        twin.run.outcome.orders,
        gpu.run.outcome.energy.relative_imbalance,
        twin.run.outcome.energy.relative_imbalance
    );
    assert!(diff <= 1e-4, "GPU vs twin {diff}");
    for s in [&gpu, &twin] {
        assert!(s.run.outcome.energy.relative_imbalance < 1e-5, "{:?}", s.run.outcome.energy);
    }
    let bits = |s: &Solved| s.fluence_all().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&gpu), bits(&again), "two GPU runs differ");
    // The pass does change the answer (this medium scatters).
    let mut off = sc.clone();
    off.solver.diffusion_correction = DiffusionCorrection::Off;
    let raw = solve("dc-off", &off, Cpu);
    assert!(raw.run.plan.diffusion_correction == [0.0; 3]);
    let change = relative_l2(&twin.fluence_all(), &raw.fluence_all());
    assert!(change > 1e-4, "the correction changed nothing ({change:e})");
}

/// Nothing scatters: no correction even when asked for (the plan says κ = 0).
#[test]
fn an_absorber_gets_no_correction() {
    let mut sc = scene(Shape::Box, [8; 3], [0.5; 3], [0.0; 3], vec![sky(1.0)]);
    sc.solver.diffusion_correction = DiffusionCorrection::On;
    let s = solve("dc-absorber", &sc, Cpu);
    assert_eq!(s.run.plan.diffusion_correction, [0.0; 3]);
}

/// The 13³ box of albedo 0.99 at one mean free path per voxel under a sky (tests/it/hard_cases.rs),
/// k = 3, the tests' default spatial scheme ("linear"): its centre reads +5.6 % high without the
/// correction (9.605 against 9.10, the value the schemes reach refined to h/2 and h/4 and
/// extrapolated; Monte Carlo 9.141 ± 0.093). Measured with it: 9.350 (+2.7 %); the excess must fall
/// by at least 40 %.
#[test]
fn the_thick_box_centre_comes_down_to_its_refined_value() {
    let n = 13;
    let c = [6u32, 6, 6];
    let mut sc = scene(Shape::Box, [n; 3], [1.0; 3], [0.99; 3], vec![sky(1.0)]);
    sc.solver.max_orders = 2000;
    sc.solver.tolerance = 1e-5;
    let off = solve("dc-box-off", &sc, Cpu).fluence(c, 0);
    sc.solver.diffusion_correction = DiffusionCorrection::On;
    let on = solve("dc-box-on", &sc, Cpu).fluence(c, 0);
    let refined = 9.10;
    eprintln!(
        "13³ box centre: off {off:.4} ({:+.2} %), on {on:.4} ({:+.2} %)",
        100.0 * (off / refined - 1.0),
        100.0 * (on / refined - 1.0)
    );
    assert!(off / refined - 1.0 > 0.02, "the uncorrected excess moved: {off}");
    assert!((on / refined - 1.0).abs() < 0.6 * (off / refined - 1.0), "on {on} vs off {off}");
}

/// The case the property test (tests/it/property_solve.rs) found against the uncapped, linear
/// form: a 3³ box of 1000 mean free paths per voxel, albedo 0.39, under a sun of 10¹². The sunlit
/// layer is brighter than the one below it by many orders of magnitude, so uncapped
/// anti-diffusive fluxes took more light out of the dark voxels than they had (the property test
/// saw a fluence of −2.5·10⁷, −2·10⁻⁵ of the peak; this box, uncapped, −5.7·10⁶). Capped against
/// the committed total, every value stays ≥ 0.
#[test]
fn a_sunlit_layer_of_a_thousand_mean_free_paths_leaves_no_voxel_negative() {
    for (k, sun_direction) in [(1, [0.0, 0.0, -1.0]), (2, [0.3, -0.2, -0.9])] {
        let mut sc = scene(Shape::Box, [3; 3], [1000.0; 3], [0.39; 3], vec![sun(sun_direction, [1e12; 3])]);
        sc.solver.directions_per_face = k;
        sc.solver.max_orders = 4;
        sc.solver.diffusion_correction = DiffusionCorrection::On;
        let s = solve("dc-sunlit-layer", &sc, Cpu);
        assert!(s.run.plan.diffusion_correction.iter().all(|&kappa| kappa > 0.0));
        for (name, field) in [("fluence", &s.fields.fluence_total), ("source", &s.fields.source_total)] {
            let values = field.as_slice();
            let worst = values.iter().copied().fold(f32::INFINITY, f32::min);
            let peak = values.iter().copied().fold(0.0, f32::max);
            eprintln!("k = {k}: {name} from {worst:e} to {peak:e}");
            assert!(values.iter().all(|v| v.is_finite() && *v >= 0.0), "k = {k}: {name} reaches {worst:e}");
        }
    }
}

/// On unless the scene turns it off: a scene file that does not mention it gets the correction.
#[test]
fn the_correction_is_on_unless_the_scene_turns_it_off() {
    let text = |extra: &str| {
        format!(
            "[volume]\nprocedural = \"sphere\"\ndims = [8, 8, 8]\n[medium]\nsigma_t = 0.5\nalbedo = 0.9\n\
             [[lights]]\nkind = \"sky\"\nradiance = 1.0\n[solver]\n{extra}"
        )
    };
    let read =
        |extra: &str| Scene::from_toml_str(&text(extra), std::path::Path::new("default.toml")).expect("a valid scene");
    assert_eq!(read("").solver.diffusion_correction, DiffusionCorrection::On);
    assert_eq!(read("diffusion_correction = \"off\"\n").solver.diffusion_correction, DiffusionCorrection::Off);
    let solved = solve("dc-default", &read(""), Cpu);
    assert!(
        solved.run.plan.diffusion_correction.iter().all(|&k| k > 0.0),
        "{:?}",
        solved.run.plan.diffusion_correction
    );
}
