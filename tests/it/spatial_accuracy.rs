//! The spatial schemes against exact solutions (`solver.spatial`, see `lpm::solver::sweep`).
//!
//! A pure absorber box under a uniform sky has an exact fluence at every point (the solid-angle
//! integral of e^{−σ·d}); its voxel averages test what the discretisation does where it is hardest:
//! next to the faces, where light enters through a side at a grazing angle, and in the corners.

use crate::common::*;
use lpm::scene::{Shape, SpatialScheme};
use lpm::solver::BackendKind::Cpu;

/// The exact voxel-average fluence of voxel `v` of an absorber box (`sub`³ sub-points per voxel)
/// over a cube-face quadrature of `k`×`k` directions per face: with the solver's own k it is what
/// the direction set can do at best (every direction transported exactly), so the solver's
/// difference from it is its spatial error; with a fine k it is the exact solid-angle integral.
fn exact_voxel_average(sigma: f64, n: u32, v: [u32; 3], k: u32, sub: u32) -> f64 {
    let at = |c: u32, i: u32| c as f64 + (i as f64 + 0.5) / sub as f64;
    let mut sum = 0.0;
    for i in 0..sub {
        for j in 0..sub {
            for l in 0..sub {
                let x = [at(v[0], i), at(v[1], j), at(v[2], l)];
                sum += exact_absorber_fluence(sigma, [n as f64; 3], x, k);
            }
        }
    }
    sum / (sub * sub * sub) as f64
}

struct Worst {
    /// Largest |solver / exact over the same directions − 1| (the spatial error) and where.
    spatial: (f64, [u32; 3]),
    /// Largest |solver / exact solid-angle integral − 1| and where.
    total: (f64, [u32; 3]),
}

/// The worst relative errors over every voxel of a 32³ absorber box (σ = 0.1 per voxel, sky 1)
/// with k directions per face. By the box's symmetry every voxel's value equals that of a voxel
/// with x ≤ y ≤ z ≤ 15, so those are the ones compared (the solve is checked to be symmetric).
fn worst_absorber_errors(scheme: SpatialScheme, k: u32) -> Worst {
    worst_absorber_errors_with_sky(scheme, k, k)
}

/// [`worst_absorber_errors`] with the sky swept along `sky_k`×`sky_k` directions per face of its
/// own (`solver.sky_directions_per_face`; k: the sky on the k×k); the spatial error is then against
/// those directions.
fn worst_absorber_errors_with_sky(scheme: SpatialScheme, k: u32, sky_k: u32) -> Worst {
    let n = 32;
    let sigma = 0.1;
    let mut scene = scene(Shape::Box, [n; 3], [sigma; 3], [0.0; 3], vec![sky(1.0)]);
    scene.solver.directions_per_face = k;
    scene.solver.sky_directions_per_face = Some(sky_k);
    scene.solver.spatial = Some(scheme);
    let s = solve(&format!("absorber32-{}-{k}-{sky_k}", scheme.name()), &scene, Cpu);
    let k = sky_k;
    let mut worst = Worst { spatial: (0.0, [0; 3]), total: (0.0, [0; 3]) };
    for z in 0..n / 2 {
        for y in 0..=z {
            for x in 0..=y {
                let v = [x, y, z];
                let got = s.fluence(v, 0);
                // The mirror image through the far corner holds the same value (up to rounding).
                let mirror = s.fluence([n - 1 - z, n - 1 - x, n - 1 - y], 0);
                assert!((got / mirror - 1.0).abs() < 1e-9, "{v:?}: {got} vs mirror {mirror}");
                let spatial = (got / exact_voxel_average(sigma, n, v, k, 4) - 1.0).abs();
                if spatial > worst.spatial.0 {
                    worst.spatial = (spatial, v);
                }
                let total = (got / exact_voxel_average(sigma, n, v, 32, 3) - 1.0).abs();
                if total > worst.total.0 {
                    worst.total = (total, v);
                }
            }
        }
    }
    worst
}

/// The issue asks for the absorber box (32³, σt = 0.1, sky 1) within 1 % of the exact solid-angle
/// integral in every voxel at k ≥ 8, faces and corners included. Two errors add up there: the
/// direction set's own (even with every direction transported exactly, the k = 8 cube-face set is
/// 1.75 % off at the centre of a face, k = 16 0.4 %: `explore` numbers in benches/RESULTS.md) and
/// the spatial scheme's, which is what this test bounds. The linear scheme keeps the spatial error
/// below 1 % in every voxel; the nearest-column scheme does not (light entering through a side starts
/// a plane away from where it really enters).
#[test]
fn linear_scheme_keeps_the_spatial_error_of_an_absorber_box_below_one_percent_in_every_voxel() {
    let linear = worst_absorber_errors(SpatialScheme::Linear, 8);
    let constant = worst_absorber_errors(SpatialScheme::Constant, 8);
    eprintln!(
        "absorber 32³, k = 8, worst voxel: spatial error linear {:.3e} at {:?}, constant {:.3e} at {:?}; \
         against the exact integral linear {:.3e} at {:?}, constant {:.3e} at {:?}",
        linear.spatial.0,
        linear.spatial.1,
        constant.spatial.0,
        constant.spatial.1,
        linear.total.0,
        linear.total.1,
        constant.total.0,
        constant.total.1,
    );
    assert!(linear.spatial.0 < 0.01, "linear: {:?}", linear.spatial);
    assert!(
        constant.spatial.0 > 1.5 * linear.spatial.0,
        "constant {:?} vs linear {:?}",
        constant.spatial,
        linear.spatial
    );
}

/// With the sky on directions of its own (16×16 per face, order 0 only) the k = 8 solve of the
/// absorber box under `spatial = "linear"` comes within 1.1 % of the exact solid-angle integral in
/// every voxel, faces and corners included, where the shared k = 8 directions leave 1.8 %. (The
/// issue asks for 1 %: what is left is the lattice's own error next to a face, ~1 % at a face
/// centre. Under "constant" the sky's own directions do not help here: its side-entry error grows
/// with their grazing slopes, 2.7 % → 3.3 %, printed for the record.)
#[test]
fn with_its_own_directions_the_sky_brings_every_voxel_of_an_absorber_box_within_1_1_percent_of_exact() {
    let linear = worst_absorber_errors_with_sky(SpatialScheme::Linear, 8, 16);
    let constant = worst_absorber_errors_with_sky(SpatialScheme::Constant, 8, 16);
    let shared = worst_absorber_errors(SpatialScheme::Linear, 8);
    eprintln!(
        "absorber 32³, k = 8, sky 16: against the exact integral linear {:.3e} at {:?} (shared sky {:.3e} at {:?}), \
         constant {:.3e} at {:?}; spatial linear {:.3e} at {:?}, constant {:.3e} at {:?}",
        linear.total.0,
        linear.total.1,
        shared.total.0,
        shared.total.1,
        constant.total.0,
        constant.total.1,
        linear.spatial.0,
        linear.spatial.1,
        constant.spatial.0,
        constant.spatial.1,
    );
    assert!(linear.total.0 < 0.011, "linear: {:?}", linear.total);
    assert!(linear.total.0 < 0.65 * shared.total.0, "{:?} vs shared sky directions {:?}", linear.total, shared.total);
}

/// The bound itself: the 32³ absorber box (σt = 0.1 per voxel, sky 1) solved at k = 8 with
/// the plan's own choices is within 1 % of the exact solid-angle integral in every voxel, faces,
/// edges and corners included. Nothing scatters, so the plan chooses `spatial = "linear"` and the
/// sky on 32×32 directions per face of its own (order 0 is the whole answer; checked here, as is
/// that a scattering medium keeps "constant" and the k×k sky). The exact integral is taken by a cube-face
/// quadrature of 32×32 directions per face, and of 64×64 next to a face, where the integrand
/// changes fast across the grazing directions (there the two are compared, to show the
/// reference is good to far below the bound).
#[test]
fn by_default_every_voxel_of_the_absorber_box_is_within_one_percent_at_k_8() {
    let (n, sigma) = (32, 0.1);
    let mut sc = scene(Shape::Box, [n; 3], [sigma; 3], [0.0; 3], vec![sky(1.0)]);
    sc.solver.directions_per_face = 8;
    // What a scene file that names neither key gets: the plan's choice.
    (sc.solver.sky_directions_per_face, sc.solver.spatial) = (None, None);
    let mut scattering = sc.clone();
    scattering.medium.albedo = [0.5; 3];
    let plan = lpm::solver::plan::Plan::new(&scattering, 8, 0);
    assert_eq!((plan.spatial, plan.sky_directions_per_face()), (SpatialScheme::Constant, 8));
    let s = solve("absorber32-default", &sc, Cpu);
    assert_eq!((s.run.plan.spatial, s.run.plan.sky_directions_per_face()), (SpatialScheme::Linear, 32));
    let (mut worst, mut reference_spread) = ((0.0f64, [0; 3]), 0.0f64);
    for z in 0..n / 2 {
        for y in 0..=z {
            // x is the distance to the nearest face (x ≤ y ≤ z ≤ 15; the rest by symmetry).
            for x in 0..=y {
                let v = [x, y, z];
                let exact = if x <= 1 {
                    let (fine, coarse) =
                        (exact_voxel_average(sigma, n, v, 64, 3), exact_voxel_average(sigma, n, v, 32, 3));
                    reference_spread = reference_spread.max((coarse / fine - 1.0).abs());
                    fine
                } else {
                    exact_voxel_average(sigma, n, v, 32, 3)
                };
                let error = (s.fluence(v, 0) / exact - 1.0).abs();
                if error > worst.0 {
                    worst = (error, v);
                }
            }
        }
    }
    eprintln!(
        "absorber 32³, k = 8, the plan's choices (sky 32, linear): worst {:.3e} at {:?}; reference 32 vs 64 next to a face: {reference_spread:.1e}",
        worst.0, worst.1
    );
    assert!(reference_spread < 2e-3, "the reference itself moves by {reference_spread}");
    assert!(worst.0 < 0.01, "{worst:?}");
}
