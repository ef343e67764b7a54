//! Hard cases: extreme optical thickness, albedo and anisotropy, vacuum gaps, a single dense voxel, a
//! thin slanted sheet, a huge dynamic range of density and suns at awkward angles. Every case checks
//! that the fluence is finite and non-negative everywhere, that the GPU (f32) conserves energy
//! (`in + emitted = out + absorbed + unpropagated`), that the GPU agrees with its f64 CPU twin, and,
//! where one exists, the error against a closed form or the Monte-Carlo reference.
//!
//! GPU solves run with Vulkan validation on (a validation error fails the solve, hence the test).
use crate::common::*;
use lpm::reference::ReferenceOptions;
use lpm::scene::{Scene, Shape, SpatialScheme};
use lpm::solver::sweep::FaceSweep;
use lpm::solver::BackendKind::{Cpu, Gpu};
use std::f64::consts::PI;

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

fn assert_finite_non_negative(label: &str, s: &Solved) {
    for (i, phi) in s.fluence_all().iter().enumerate() {
        assert!(phi.is_finite() && *phi >= 0.0, "{label}: fluence component {i} is {phi}");
    }
}

/// Solves `scene` on both backends for exactly `orders` orders (so that a residual near the tolerance
/// cannot make them stop at different orders); checks both fields are finite and non-negative and
/// returns (gpu, cpu, relative L2 difference of the fluence).
fn gpu_and_cpu(name: &str, scene: &Scene, orders: u32) -> (Solved, Solved, f64) {
    let mut scene = scene.clone();
    scene.solver.max_orders = orders;
    scene.solver.tolerance = 1e-30;
    let gpu = solve(&format!("{name}-gpu"), &scene, Gpu);
    let cpu = solve(&format!("{name}-cpu"), &scene, Cpu);
    assert_eq!(gpu.run.outcome.orders, cpu.run.outcome.orders, "{name}");
    assert_finite_non_negative(&format!("{name} (GPU)"), &gpu);
    assert_finite_non_negative(&format!("{name} (CPU)"), &cpu);
    let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
    (gpu, cpu, err)
}

/// The GPU's energy balance, checked against `bound`; returns the relative imbalance.
fn assert_balance(label: &str, s: &Solved, bound: f64) -> f64 {
    let e = &s.run.outcome.energy;
    assert!(e.relative_imbalance < bound, "{label}: relative imbalance {} ≥ {bound}: {e:?}", e.relative_imbalance);
    e.relative_imbalance
}

/// Mean fluence (channel 0) over a box of voxels [lo, hi) .
fn mean_fluence(s: &Solved, lo: [u32; 3], hi: [u32; 3]) -> f64 {
    let (mut sum, mut n) = (0.0, 0.0);
    for z in lo[2]..hi[2] {
        for y in lo[1]..hi[1] {
            for x in lo[0]..hi[0] {
                sum += s.fluence([x, y, z], 0);
                n += 1.0;
            }
        }
    }
    sum / n
}

/// A small deterministic hash (splitmix64) for seeded per-voxel randomness.
fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

fn uniform01(seed: u64, v: [u32; 3]) -> f64 {
    let key = seed ^ ((v[0] as u64) << 42 | (v[1] as u64) << 21 | v[2] as u64);
    (splitmix(key) >> 11) as f64 / (1u64 << 53) as f64
}

// ---------------------------------------------------------------------------------------------
// 1. Optical thickness per voxel from 1e-6 to 1e4
// ---------------------------------------------------------------------------------------------

/// σt·h = 1e-6 … 1e4 in a 12³ box under a sky. Measured (lavapipe): GPU vs CPU relative L2 ≤ 2.7e-7,
/// GPU imbalance ≤ 2.8e-7 (worst at τ = 1e-6, where out ≈ in and f32 round-off is all that is left),
/// pure absorber against Beer–Lambert over the direction set ≤ 4.3e-7.
#[test]
fn optical_thickness_from_1e_minus_6_to_1e4_per_voxel() {
    let n = 12;
    for tau in [1e-6, 1e-3, 1.0, 1e2, 1e4] {
        // Albedo 0.5 under a sky of radiance 1: GPU against the twin, energy, and the furnace bound
        // φ ≤ 4π·L (the albedo-1 converged solution is exactly 4π·L and the solution is monotone in
        // the albedo and the order count).
        let sc = scene(Shape::Box, [n; 3], [tau; 3], [0.5; 3], vec![sky(1.0)]);
        let (gpu, _, err) = gpu_and_cpu(&format!("tau{tau:e}"), &sc, 6);
        let imb = assert_balance(&format!("τ = {tau:e}"), &gpu, 1e-5);
        let max = gpu.fluence_all().into_iter().fold(0.0, f64::max);
        eprintln!(
            "τ = {tau:e}: GPU vs CPU relative L2 {err:.2e}, relative imbalance {imb:.2e}, max φ/4π {:.6}",
            max / (4.0 * PI)
        );
        assert!(err <= 1e-4, "τ = {tau:e}: relative L2 {err}");
        assert!(max <= 4.0 * PI * (1.0 + 1e-5), "τ = {tau:e}: max fluence {max} above the furnace value");

        // Pure absorber: the centre, a face voxel, a corner and an off-centre voxel against
        // Beer–Lambert over the direction set. Values below 1e-30 (e.g. e^{−500} at τ = 100 in the
        // centre) are physically zero; f32 flushes them, so they get an absolute tolerance.
        let mut ab = sc.clone();
        ab.medium.albedo = [0.0; 3];
        ab.solver.spatial = Some(SpatialScheme::Constant);
        let s = solve(&format!("tau{tau:e}-absorber"), &ab, Gpu);
        assert_finite_non_negative(&format!("absorber τ = {tau:e}"), &s);
        assert_balance(&format!("absorber τ = {tau:e}"), &s, 1e-5);
        let mut worst: f64 = 0.0;
        for v in [[6, 6, 6], [0, 6, 6], [0, 0, 0], [11, 5, 3], [3, 11, 7]] {
            let expected = beer_lambert_over_the_direction_set(tau, &s.run.plan, v);
            let got = s.fluence(v, 0);
            if expected > 1e-30 {
                worst = worst.max((got / expected - 1.0).abs());
            }
            assert!((got - expected).abs() <= 1e-5 * expected + 1e-30, "τ = {tau:e}, {v:?}: {got} vs {expected}");
        }
        eprintln!("τ = {tau:e}: absorber worst relative error against Beer–Lambert {worst:.2e}");
        if tau == 1e4 {
            // Light dies within the first voxel: the interior is exactly dark, never negative or NaN,
            // while the face voxels still see ~Σ Ω_i·E1(τ s_i) of the sky.
            let centre = s.fluence([6, 6, 6], 0);
            assert!((0.0..1e-30).contains(&centre), "{centre}");
            assert!(s.fluence([0, 6, 6], 0) > 1e-5, "{}", s.fluence([0, 6, 6], 0));
            // With scattering the centre is not exactly 0 (exact physics: e^{−10⁴·6}·…, i.e. 0).
            // Under the nearest-column scheme the voxel-uniform source lets each order carry
            // scattered light one voxel deeper with a factor ~α·E1(τ)/2 ≈ 2.5e-5, so after 6 orders
            // the centre holds ~(2.5e-5)^6: measured 1.9e-28 of the face. The linear scheme's rays
            // between two voxel centres gather and deposit the source of both, which moves a share
            // ~w(1 − w) of it one voxel sideways per order whatever τ: measured 1.5e-7 of the face
            // after 6 orders (its numerical diffusion in voxels far thicker than their size; the
            // constant scheme is the one for such unresolved media). Never negative or NaN.
            let face = gpu.fluence([0, 6, 6], 0);
            let g = gpu.fluence([6, 6, 6], 0);
            assert!(g >= 0.0 && g < 1e-6 * face, "scattering τ = 1e4 centre {g}, face {face}");
            let mut constant = sc.clone();
            constant.solver.spatial = Some(SpatialScheme::Constant);
            let c = solve("tau1e4-constant", &constant, Gpu);
            let (g, face) = (c.fluence([6, 6, 6], 0), c.fluence([0, 6, 6], 0));
            assert!(g >= 0.0 && g < 1e-20 * face, "constant scheme: scattering τ = 1e4 centre {g}, face {face}");
        }
    }
}

// ---------------------------------------------------------------------------------------------
// 2. Albedo from 0 to 0.9999, capped orders; furnace limit; Monte-Carlo at albedo 0.99
// ---------------------------------------------------------------------------------------------

/// Albedo 0, 0.5, 0.99, 0.9999 in a 13³ box, τ = 1 per voxel, 12 orders. Measured: imbalance ≤ 1.7e-7
/// even with 24 % of the incoming power still unpropagated (albedo 0.9999); centre φ/4π 0.00055,
/// 0.0033, 0.115, 0.124; converged (158 orders, tolerance 1e-5) albedo 0.9999 gives φ/4π = 0.9964.
#[test]
fn albedo_up_to_0_9999_with_capped_orders_balances_and_is_monotone() {
    // 13³ so that the centre is a voxel; σt = 1 per voxel (optical width 13).
    let n = 13;
    let c = [6, 6, 6];
    let mut centre = Vec::new();
    for a in [0.0, 0.5, 0.99, 0.9999] {
        let mut sc = scene(Shape::Box, [n; 3], [1.0; 3], [a; 3], vec![sky(1.0)]);
        sc.solver.max_orders = 12;
        sc.solver.tolerance = 1e-30;
        let s = solve(&format!("albedo{a}"), &sc, Gpu);
        assert_finite_non_negative(&format!("albedo {a}"), &s);
        let e = s.run.outcome.energy;
        let imb = assert_balance(&format!("albedo {a}"), &s, 1e-5);
        let tail = e.unpropagated[0] / e.boundary_in[0];
        eprintln!(
            "albedo {a}: {} orders, imbalance {imb:.2e}, unpropagated/in {tail:.3e}, centre φ/4π {:.5}",
            s.run.outcome.orders,
            s.fluence(c, 0) / (4.0 * PI)
        );
        if a >= 0.99 {
            // 12 orders do not converge here: the books only close because the truncated tail is
            // counted.
            assert!(!s.run.outcome.converged);
            assert!(tail > 1e-3, "albedo {a}: unpropagated/in {tail}");
        }
        assert!(s.fluence_all().iter().all(|&phi| phi <= 4.0 * PI * (1.0 + 1e-5)));
        centre.push(s.fluence(c, 0));
    }
    assert!(centre.windows(2).all(|w| w[1] > w[0]), "centre fluence should grow with the albedo: {centre:?}");

    // The albedo → 1 furnace limit: converged, albedo 0.9999 is within ~1 % of 4π·L at the centre.
    let mut sc = scene(Shape::Box, [n; 3], [1.0; 3], [0.9999; 3], vec![sky(1.0)]);
    sc.solver.max_orders = 2000;
    sc.solver.tolerance = 1e-5;
    let s = solve("albedo0.9999-converged", &sc, Gpu);
    assert!(s.run.outcome.converged);
    assert_balance("albedo 0.9999 converged", &s, 1e-5);
    let ratio = s.fluence(c, 0) / (4.0 * PI);
    eprintln!("albedo 0.9999 converged after {} orders: centre φ/4π = {ratio:.5}", s.run.outcome.orders);
    assert!(ratio < 1.0 && ratio > 0.98, "{ratio}");
}

/// LPM (k = 3, h = 1 mfp, converged to 1e-5) against the Monte-Carlo reference at the centre of a
/// 13³ box of albedo 0.99 under a sky. Measured: LPM 9.398, MC 9.053 ± 0.222 (6e5 photons, ~2 s):
/// +3.8 % (+1.6 se); 3³ block +3.4 %. With 4e6 photons the MC centre is 9.141 ± 0.093, so LPM is
/// ~+3 % high at k = 3. That excess is spatial, not angular: k = 2, 3, 4, 6, 8 give 9.52, 9.40,
/// 9.59, 9.46, 9.53 (no trend), while halving the voxel (26³, h = 0.5, k = 4) gives 9.23 (+0.9 %).
#[test]
fn albedo_0_99_centre_matches_the_monte_carlo_reference() {
    let n = 13;
    let c = [6u32, 6, 6];
    let mut sc = scene(Shape::Box, [n; 3], [1.0; 3], [0.99; 3], vec![sky(1.0)]);
    sc.solver.max_orders = 2000;
    sc.solver.tolerance = 1e-5;
    let s = solve("albedo0.99-mc", &sc, Gpu);
    assert!(s.run.outcome.converged);
    assert_balance("albedo 0.99 converged", &s, 1e-5);
    let lpm = s.fluence(c, 0);
    let opts = ReferenceOptions {
        photons: 600_000,
        seed: 11,
        batches: 16,
        threads: 0,
        image_samples_per_pixel: 0,
        ..ReferenceOptions::default()
    };
    let r = lpm::reference::run(&sc, &|_| 1.0, 1, &opts);
    let idx = |v: [u32; 3]| ((v[2] * n + v[1]) * n + v[0]) as usize;
    let (mc, se) = (r.fluence[idx(c)] as f64, r.std_error[idx(c)] as f64);
    // The central 3³ block, a less noisy measure of the discretisation error (its standard error is
    // bounded by the mean of the voxels' ones, the voxels being correlated).
    let (mut lpm_block, mut mc_block, mut se_block) = (0.0, 0.0, 0.0);
    for z in 5..8 {
        for y in 5..8 {
            for x in 5..8 {
                lpm_block += s.fluence([x, y, z], 0) / 27.0;
                mc_block += r.fluence[idx([x, y, z])] as f64 / 27.0;
                se_block += r.std_error[idx([x, y, z])] as f64 / 27.0;
            }
        }
    }
    eprintln!(
        "albedo 0.99 centre: LPM {lpm:.5}, MC {mc:.5} ± {se:.5} ({} photons, {:.1} s): LPM − MC = {:+.2} % = {:+.2} se; \
         3³ block: LPM {lpm_block:.5}, MC {mc_block:.5} ± ≤{se_block:.5}: {:+.2} %",
        r.photons,
        r.seconds,
        100.0 * (lpm - mc) / mc,
        (lpm - mc) / se,
        100.0 * (lpm_block - mc_block) / mc_block
    );
    assert!((lpm - mc).abs() <= 3.0 * se + 0.05 * mc, "LPM {lpm} vs MC {mc} ± {se}");
    assert!(
        (lpm_block - mc_block).abs() <= 3.0 * se_block + 0.05 * mc_block,
        "block: LPM {lpm_block} vs MC {mc_block} ± {se_block}"
    );
}

// ---------------------------------------------------------------------------------------------
// 3. Anisotropy g = −0.9 … 0.99
// ---------------------------------------------------------------------------------------------

/// g = −0.9, 0, 0.9, 0.99 with k = 4 and 2×2 storage directions per face. Measured: GPU vs CPU ≤ 9e-8,
/// imbalance ≤ 7.6e-8; far-side mean φ 0.414, 0.489, 1.211, 1.582; near-side 4.446, 3.915, 3.100,
/// 3.013.
#[test]
fn strong_anisotropy_balances_matches_the_twin_and_forward_scattering_transmits_more() {
    // A slab z ∈ [4, 8) of a 12³ volume lit by a sun from +z (slightly tilted): the far side is z < 4.
    let n = 12;
    let mut far = Vec::new();
    let mut near = Vec::new();
    let gs = [-0.9, 0.0, 0.9, 0.99];
    for g in gs {
        let mut sc = raw_scene(&format!("aniso{g}"), [n; 3], 1.0, 0.95, vec![sun([0.2, 0.1, 1.0], [3.0; 3])], |v| {
            if (4..8).contains(&v[2]) {
                1.0
            } else {
                0.0
            }
        });
        sc.medium.g = g;
        sc.solver.directions_per_face = 4;
        sc.solver.storage_directions_per_face = Some(2);
        let (gpu, _, err) = gpu_and_cpu(&format!("aniso{g}"), &sc, 6);
        let imb = assert_balance(&format!("g = {g}"), &gpu, 1e-5);
        let f = mean_fluence(&gpu, [0, 0, 0], [n, n, 3]);
        let b = mean_fluence(&gpu, [0, 0, 9], [n, n, n]);
        eprintln!("g = {g}: GPU vs CPU relative L2 {err:.2e}, imbalance {imb:.2e}, far-side mean φ {f:.5}, near-side mean φ {b:.5}");
        assert!(err <= 1e-4, "g = {g}: relative L2 {err}");
        far.push(f);
        near.push(b);
    }
    // Transmission grows with g, reflection falls (also from 0.9 to 0.99, where the peak is far
    // narrower than a storage cell).
    assert!(far.windows(2).all(|w| w[1] > w[0]), "far side {far:?}");
    assert!(near.windows(2).all(|w| w[1] < w[0]), "near side {near:?}");
}

// ---------------------------------------------------------------------------------------------
// 4. Vacuum gaps between dense regions
// ---------------------------------------------------------------------------------------------

/// Measured: GPU vs CPU 1.2e-7, imbalance 6.7e-8.
#[test]
fn vacuum_gap_between_dense_slabs() {
    // x ∈ [2, 12) and x ∈ [32, 38) dense (τ = 4 per voxel), everything between empty: the brick
    // x ∈ [16, 32) holds no medium at all.
    let dims = [40, 12, 12];
    let sc = raw_scene("gap", dims, 4.0, 0.9, vec![sky(1.0), sun([0.6, 0.3, 0.5], [2.0; 3])], |v| {
        if (2..12).contains(&v[0]) || (32..38).contains(&v[0]) {
            1.0
        } else {
            0.0
        }
    });
    let (gpu, cpu, err) = gpu_and_cpu("gap", &sc, 6);
    assert!(gpu.run.plan.bricks_empty >= 1, "{}", gpu.run.plan.bricks_empty);
    let imb = assert_balance("gap", &gpu, 1e-5);
    eprintln!(
        "vacuum gap: GPU vs CPU relative L2 {err:.2e}, imbalance {imb:.2e}, {} of {} bricks empty",
        gpu.run.plan.bricks_empty, gpu.run.plan.bricks_total
    );
    assert!(err <= 1e-4, "relative L2 {err}");
    // The empty brick is not solved: no fluence and no source stored (light crosses it all the
    // same: the far slab matches the twin, which solves every voxel). Empty voxels inside occupied
    // bricks (x ∈ 12..16, next to the slab) are solved and lit.
    let grid = *gpu.store.grid();
    for z in 0..12 {
        for y in 0..12 {
            for x in 12..32 {
                let v = [x, y, z];
                if x < 16 {
                    assert!(gpu.fluence(v, 0) > 0.0, "{v:?}");
                } else {
                    let brick = grid.locate(v).0;
                    assert!(gpu.fields.fluence_total.brick(brick).is_none(), "{v:?}");
                }
                assert_eq!(gpu.fields.source_total.value(v, 0), 0.0, "{v:?}");
                assert_eq!(cpu.fields.source_total.value(v, 0), 0.0, "{v:?}");
            }
        }
    }
}

/// The driver leaves out the dispatches of a vacuum stretch whose rays do not move sideways (all
/// of them with k = 1, whose directions are the face normals): the far slab must still get exactly
/// the light the twin gives it, and the energy must balance.
#[test]
fn vacuum_gap_crossed_by_axis_aligned_rays() {
    let dims = [56, 12, 12];
    for k in [1, 2] {
        let mut sc = raw_scene("gap-axis", dims, 2.0, 0.8, vec![sky(1.0)], |v| {
            if (2..12).contains(&v[0]) || (48..54).contains(&v[0]) {
                1.0
            } else {
                0.0
            }
        });
        sc.solver.directions_per_face = k;
        let (gpu, _cpu, err) = gpu_and_cpu("gap-axis", &sc, 3);
        assert!(gpu.run.plan.bricks_empty >= 2, "{}", gpu.run.plan.bricks_empty);
        let imb = assert_balance("gap-axis", &gpu, 1e-5);
        eprintln!("vacuum gap, k = {k}: GPU vs CPU relative L2 {err:.2e}, imbalance {imb:.2e}");
        assert!(err <= 1e-5, "k = {k}: relative L2 {err}");
    }
}

// ---------------------------------------------------------------------------------------------
// 5. A single dense voxel in vacuum, sun + sky
// ---------------------------------------------------------------------------------------------

/// Measured: GPU vs CPU 1.05e-7, imbalance 4.4e-10; φ(dense) 0.0708, φ(behind) 10.481,
/// φ(beside) 17.566: the difference 7.085 is the sun (5) plus the sky the dense voxel hides from its
/// neighbour (≈ one cube face of directions, 4π/6 = 2.094).
#[test]
fn single_dense_voxel_casts_a_shadow_along_the_beam() {
    let dims = [13, 15, 11];
    let dense = [6, 7, 5];
    let e_sun = 5.0;
    let mut sc = raw_scene("dense1e3", dims, 1.0, 0.9, vec![sky(1.0), sun([0.3, -0.2, 1.0], [e_sun; 3])], |v| {
        if v == dense {
            1e3
        } else {
            0.0
        }
    });
    // The shadow is followed along the beam's nearest-column ray (the bilinear default spreads it).
    sc.solver.spatial = Some(SpatialScheme::Constant);
    let (gpu, _, err) = gpu_and_cpu("dense1e3", &sc, 6);
    let imb = assert_balance("dense voxel", &gpu, 1e-5);
    assert!(err <= 1e-4, "relative L2 {err}");
    // The dense voxel's fluence is tiny (light barely enters) but positive.
    let inside = gpu.fluence(dense, 0);
    assert!(inside > 0.0 && inside < gpu.fluence([0, 0, 0], 0), "{inside}");

    // Follow the beam's own discrete ray: the voxel it visits in the plane after the dense voxel is
    // in the shadow; a voxel 3 columns beside it in the same plane is in full sun.
    let beam = &gpu.run.plan.beams[0];
    let sweep = FaceSweep::new(beam.face, dims);
    let f = sweep.geometry();
    let (born, t0) = birth_plane(beam, dims, dense);
    assert_eq!(born, 0);
    let (b, c) = (f.lateral[0], f.lateral[1]);
    let o0 = beam.offsets[t0 as usize];
    let o1 = beam.offsets[t0 as usize + 1];
    let behind =
        sweep.voxel(t0 + 1, (dense[b] as i32 + o1[0] - o0[0]) as u32, (dense[c] as i32 + o1[1] - o0[1]) as u32);
    let mut beside = behind;
    beside[b] -= 3;
    let (phi_behind, phi_beside) = (gpu.fluence(behind, 0), gpu.fluence(beside, 0));
    eprintln!(
        "dense voxel: GPU vs CPU relative L2 {err:.2e}, imbalance {imb:.2e}, φ(dense {dense:?}) {inside:.3e}, φ(behind {behind:?}) {phi_behind:.4}, φ(beside {beside:?}) {phi_beside:.4}"
    );
    // The beside voxel gets the whole sun (E·E1(0) = E); the one behind gets e^{−1000} of it and
    // also loses some sky to the dense voxel.
    assert!(phi_beside - phi_behind > e_sun, "behind {phi_behind} vs beside {phi_beside}");
    assert!(phi_behind > 0.0);
}

// ---------------------------------------------------------------------------------------------
// 6. A thin slanted sheet
// ---------------------------------------------------------------------------------------------

/// Measured: GPU vs CPU 1.4e-7, imbalance 8.1e-9.
#[test]
fn thin_sheet_at_thirty_degrees() {
    // One voxel per (x, y) column: z = round(c + tan 30°·(x − c)), density 3.
    let n = 16;
    let cc = (n as f64 - 1.0) / 2.0;
    let t30 = (30.0f64).to_radians().tan();
    let sheet = move |v: [u32; 3]| (cc + t30 * (v[0] as f64 - cc)).round() as u32 == v[2];
    let sc = raw_scene("sheet", [n; 3], 3.0, 0.9, vec![sky(0.5), sun([0.3, 0.5, 1.0], [2.0; 3])], move |v| {
        if sheet(v) {
            1.0
        } else {
            0.0
        }
    });
    let (gpu, _, err) = gpu_and_cpu("sheet", &sc, 6);
    let imb = assert_balance("sheet", &gpu, 1e-5);
    eprintln!("slanted sheet: GPU vs CPU relative L2 {err:.2e}, imbalance {imb:.2e}");
    assert!(err <= 1e-4, "relative L2 {err}");
    assert!(gpu.run.outcome.energy.absorbed[0] > 0.0);
}

// ---------------------------------------------------------------------------------------------
// 7. Huge dynamic range of density
// ---------------------------------------------------------------------------------------------

/// Measured: GPU vs CPU 1.3e-7, imbalance 1.7e-7.
#[test]
fn density_from_1e_minus_6_to_1e3_in_one_volume() {
    // Log-uniform random density per voxel, 10^(−6 … 3), seeded; σt = 1, so τ per voxel spans 9
    // decades in neighbouring voxels.
    let n = 16;
    let density = |v: [u32; 3]| 10f64.powf(-6.0 + 9.0 * uniform01(42, v)) as f32;
    let (mut lo, mut hi) = (f32::MAX, 0.0f32);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                lo = lo.min(density([x, y, z]));
                hi = hi.max(density([x, y, z]));
            }
        }
    }
    assert!(lo < 2e-6 && hi > 5e2, "range {lo} … {hi}");
    let sc = raw_scene("range", [n; 3], 1.0, 0.9, vec![sky(1.0), sun([-0.4, 1.0, 0.3], [3.0; 3])], density);
    let (gpu, _, err) = gpu_and_cpu("range", &sc, 6);
    let imb = assert_balance("dynamic range", &gpu, 1e-5);
    eprintln!("density 1e-6 … 1e3: GPU vs CPU relative L2 {err:.2e}, imbalance {imb:.2e}");
    assert!(err <= 1e-4, "relative L2 {err}");
}

// ---------------------------------------------------------------------------------------------
// 8. Suns at awkward angles: uncollided beam against the exact geometry
// ---------------------------------------------------------------------------------------------

/// Gauss–Legendre nodes and weights on [0, 1] (5 points).
const GL5: [(f64, f64); 5] = [
    (0.5, 0.284_444_444_444_444_4),
    (0.5 - 0.5 * 0.538_469_310_105_683_1, 0.239_314_335_249_683_3),
    (0.5 + 0.5 * 0.538_469_310_105_683_1, 0.239_314_335_249_683_3),
    (0.5 - 0.5 * 0.906_179_845_938_664, 0.118_463_442_528_094_5),
    (0.5 + 0.5 * 0.906_179_845_938_664, 0.118_463_442_528_094_5),
];

/// Distance from point x to the boundary of the box [0, n] toward the sun (along `s`), and the
/// axis through whose face it leaves.
fn distance_to_sun_side(s: [f64; 3], n: [f64; 3], x: [f64; 3]) -> (f64, usize) {
    (0..3)
        .filter(|&a| s[a] != 0.0)
        .map(|a| (if s[a] > 0.0 { (n[a] - x[a]) / s[a] } else { -x[a] / s[a] }, a))
        .fold((f64::INFINITY, 3), |m, d| if d.0 < m.0 { d } else { m })
}

/// Whether every point of voxel v reaches the sun side through the face of `axis` (the distances are
/// affine in x, so checking the 8 corners decides it for the whole voxel).
fn unambiguous_through(s: [f64; 3], n: [f64; 3], v: [u32; 3], axis: usize) -> bool {
    (0..8).all(|k| {
        let x = [0, 1, 2].map(|a| v[a] as f64 + ((k >> a) & 1) as f64);
        let da = if s[axis] > 0.0 { (n[axis] - x[axis]) / s[axis] } else { -x[axis] / s[axis] };
        (0..3).filter(|&b| b != axis && s[b] != 0.0).all(|b| {
            let db = if s[b] > 0.0 { (n[b] - x[b]) / s[b] } else { -x[b] / s[b] };
            da <= db
        })
    })
}

/// Exact voxel-average fluence of the uncollided beam E·e^{−σ·d(x)} over voxel v, by 5³-point
/// Gauss–Legendre (the integrand is smooth where the voxel is unambiguous).
fn exact_beam_average(s: [f64; 3], n: [f64; 3], sigma: f64, e: f64, v: [u32; 3]) -> f64 {
    let mut sum = 0.0;
    for &(a, wa) in &GL5 {
        for &(b, wb) in &GL5 {
            for &(c, wc) in &GL5 {
                let x = [v[0] as f64 + a, v[1] as f64 + b, v[2] as f64 + c];
                sum += wa * wb * wc * (-sigma * distance_to_sun_side(s, n, x).0).exp();
            }
        }
    }
    e * sum
}

/// Pure absorber (σ = 0.1 per voxel, 16³) lit by one sun: the fluence is the uncollided beam, checked
/// against the exact voxel average of E·e^{−σ·d} (d the exact distance to the sun side of the box)
/// at a stated voxel and at every voxel where both the exact path (enters through the sweep's entry
/// face for every point of the voxel) and the discrete ray (not wrapped) are unambiguous.
/// Measured worst relative error there: 8.3e-7 (grazing), 1.6e-7 (axis), 6.3e-7 (face diagonal),
/// 3.1e-7 (body diagonal), 3.7e-7 (generic); GPU vs CPU ≤ 2.7e-7; imbalance ≤ 3.9e-7. Elsewhere the
/// discretisation error is large by design (light entering through a side face the discrete ray does
/// not see, or a ray wrapped on the voxel diagonal): up to 31 % (grazing, top row y = 15), 2.2 %
/// (face diagonal), 4.1 % (body diagonal), 20 % (generic).
#[test]
fn sun_at_grazing_axial_and_diagonal_angles_matches_exact_beer_lambert() {
    let n = 16u32;
    let nf = [n as f64; 3];
    let (sigma, e) = (0.1, 2.0);
    // (sun direction, the stated voxel where the beam path is unambiguous)
    let cases: [([f64; 3], [u32; 3]); 5] = [
        // Grazing to the y faces (swept on −X with slope −0.02: the offsets never move in 16 planes);
        // voxel (2, 8, 8) leaves through x = 16 after 13.5 planes on average.
        ([1.0, 0.02, 0.0], [2, 8, 8]),
        // Along +z: the sweep is exact everywhere; voxel (5, 9, 3).
        ([0.0, 0.0, 1.0], [5, 9, 3]),
        // Face diagonal (the x/y tie goes to −X, slope −1: rays along voxel diagonals). Unambiguous
        // where x > y: (12, 5, 8) leaves through x = 16.
        ([1.0, 1.0, 0.0], [12, 5, 8]),
        // Body diagonal: unambiguous where x > y and x > z: (12, 5, 8).
        ([1.0, 1.0, 1.0], [12, 5, 8]),
        // A generic slant (swept on −Z): (6, 9, 4) leaves through z = 16.
        ([0.3, -0.5, 1.0], [6, 9, 4]),
    ];
    for (i, (dir, stated)) in cases.into_iter().enumerate() {
        let mut sc = scene(Shape::Box, [n; 3], [sigma; 3], [0.0; 3], vec![sun(dir, [e; 3])]);
        // The unambiguous voxels are those of the nearest-column discretisation.
        sc.solver.spatial = Some(SpatialScheme::Constant);
        let (gpu, _, err) = gpu_and_cpu(&format!("sun{i}"), &sc, 2);
        let imb = assert_balance(&format!("sun {dir:?}"), &gpu, 1e-5);
        assert!(err <= 1e-4, "sun {dir:?}: relative L2 {err}");
        let beam = &gpu.run.plan.beams[0];
        let axis = FaceSweep::new(beam.face, sc.volume.dims).geometry().axis;
        let s = glam::DVec3::from_array(dir).normalize().to_array();
        // Every voxel whose exact path is unambiguous (through the sweep's entry face) and whose
        // discrete ray entered through that face too: the discrete beam is exact there.
        let (mut count, mut worst, mut worst_other, mut others) = (0, 0.0f64, 0.0f64, 0);
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let v = [x, y, z];
                    let exact = exact_beam_average(s, nf, sigma, e, v);
                    let rel = (gpu.fluence(v, 0) / exact - 1.0).abs();
                    if unambiguous_through(s, nf, v, axis) && birth_plane(beam, sc.volume.dims, v).0 == 0 {
                        count += 1;
                        worst = worst.max(rel);
                    } else {
                        others += 1;
                        worst_other = worst_other.max(rel);
                    }
                }
            }
        }
        assert!(
            unambiguous_through(s, nf, stated, axis) && birth_plane(beam, sc.volume.dims, stated).0 == 0,
            "{stated:?}"
        );
        let (got, exact) = (gpu.fluence(stated, 0), exact_beam_average(s, nf, sigma, e, stated));
        let path = distance_to_sun_side(s, nf, stated.map(|c| c as f64 + 0.5)).0;
        eprintln!(
            "sun {dir:?} (face {}): GPU vs CPU {err:.2e}, imbalance {imb:.2e}; {stated:?}: φ {got:.7} vs exact {exact:.7} (centre path {path:.3}); \
             {count} unambiguous voxels worst {worst:.2e}; the {others} others (side entry, ray wrap) worst {worst_other:.2e}",
            beam.face
        );
        assert!((got / exact - 1.0).abs() < 1e-4, "sun {dir:?} at {stated:?}: {got} vs {exact}");
        assert!(worst < 1e-4, "sun {dir:?}: worst unambiguous voxel {worst}");
        assert!(count >= 16, "{count}");
    }
}
