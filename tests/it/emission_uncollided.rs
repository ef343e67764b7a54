//! The emission's uncollided light traced from the emitting voxels (`solver.emission_uncollided`,
//! `solver::uncollided`): one emitting voxel in a uniform absorber against the exact voxel means,
//! both backends (the GPU's traced by the device kernel, `uncollided::gpu`), the books, bitwise repeats at any thread count, a mirror's images, resume, and
//! the plan's choice.
use crate::common::*;
use lpm::scene::{EmissionGrid, EmissionUncollided, Scene, Shape, SpatialScheme};
use lpm::solver::BackendKind::{Cpu, Gpu};

/// One emitting voxel at `at` (emission factor 1) in a uniform box of σt `sigma` and `albedo`,
/// voxel edge `h`, emitting `le`.
fn one_emitter(name: &str, dims: [u32; 3], at: [u32; 3], sigma: f64, albedo: f64, h: f64, le: f64) -> Scene {
    let path = temp_dir(name).join("emission.raw");
    write_raw_field(&path, dims, |v| if v == at { 1.0 } else { 0.0 });
    let mut sc = scene(Shape::Box, dims, [sigma; 3], [albedo; 3], vec![]);
    sc.volume.voxel_size = h;
    sc.medium.emission = [le; 3];
    sc.volume.emission = Some(EmissionGrid::Raw { path });
    sc.solver.directions_per_face = 3;
    sc.solver.max_orders = 4;
    sc.solver.tolerance = 1e-30;
    sc
}

/// Gauss–Legendre on [−1, 1], 4 points.
const GL4: [(f64, f64); 4] = [
    (-0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
    (-0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
    (0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
    (0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
];

/// The mean over a source voxel and a target voxel `c` voxels apart of e^{−σr}/r² (voxel units,
/// σ per voxel edge): ∫ Λ(u)·f(c + u) du with the tent Λ of two unit cubes, by Gauss–Legendre on
/// each half of [−1, 1] per axis (the tent is linear there). Exact to ~1e-6 for |c| ≥ 2√2.
fn pair_mean(c: [f64; 3], sigma: f64) -> f64 {
    let mut nodes = Vec::new();
    for (lo, hi) in [(-1.0, 0.0), (0.0, 1.0)] {
        for (x, w) in GL4 {
            let u: f64 = lo + (hi - lo) * 0.5 * (x + 1.0);
            nodes.push((u, w * 0.5 * (1.0 - u.abs())));
        }
    }
    let mut sum = 0.0;
    for &(x, wx) in &nodes {
        for &(y, wy) in &nodes {
            for &(z, wz) in &nodes {
                let d = [c[0] + x, c[1] + y, c[2] + z];
                let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                sum += wx * wy * wz * (-sigma * r2.sqrt()).exp() / r2;
            }
        }
    }
    sum
}

#[test]
fn one_emitting_voxel_in_an_absorber_is_the_exact_voxel_mean_on_both_backends() {
    let dims = [21, 19, 23];
    let at = [10, 9, 11];
    let (sigma, h, le) = (0.6, 0.5, 3.0);
    let sc = one_emitter("uncollided-absorber", dims, at, sigma, 0.0, h, le);
    let gpu = solve("uncollided-absorber-gpu", &sc, Gpu);
    let cpu = solve("uncollided-absorber-cpu", &sc, Cpu);
    assert!(gpu.run.plan.emission_traced, "{:?}", gpu.run.plan.reasons);
    assert!(gpu.run.plan.reasons.iter().any(|r| r.contains("traced (auto)")), "{:?}", gpu.run.plan.reasons);
    assert!(gpu.run.plan.reasons.iter().any(|r| r.starts_with("emission trace:")), "{:?}", gpu.run.plan.reasons);
    // The GPU backend traces on the device (uncollided::gpu), the CPU backend on the host.
    let ran =
        |s: &Solved, on: &str| s.run.plan.reasons.iter().any(|r| r.starts_with("emission trace:") && r.contains(on));
    assert!(ran(&gpu, "on the GPU ("), "{:?}", gpu.run.plan.reasons);
    assert!(ran(&cpu, "on the host, "), "{:?}", cpu.run.plan.reasons);
    assert!(gpu.run.phases.iter().any(|(p, _)| p == "emission trace"), "{:?}", gpu.run.phases);
    // A pure absorber scatters nothing: no word about the scattered light's streaks.
    assert!(!gpu.run.plan.reasons.iter().any(|r| r.contains("still streaks")), "{:?}", gpu.run.plan.reasons);
    // J = ρσa·Le per unit volume and steradian; φ = J·h·G(voxel units), σ per voxel edge σt·h.
    let j = sigma * le;
    let (mut checked, mut worst) = (0, 0.0f64);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let c = [x as f64 - at[0] as f64, y as f64 - at[1] as f64, z as f64 - at[2] as f64];
                if (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() < 3.0 {
                    continue;
                }
                let exact = j * h * pair_mean(c, sigma * h);
                for (backend, s) in [("gpu", &gpu), ("cpu", &cpu)] {
                    let got = s.fluence([x, y, z], 0);
                    let rel = (got - exact).abs() / exact;
                    assert!(rel < 0.01, "{backend} voxel {:?}: {got} vs {exact}", [x, y, z]);
                    worst = worst.max(rel);
                }
                checked += 1;
            }
        }
    }
    eprintln!("one emitting voxel, traced: worst relative error {worst:.2e} over {checked} voxels ≥ 3 voxels away");
    assert!(checked > 8000, "{checked}");
    // The device's f32 trace against the host's f64 one (module docs of uncollided::gpu).
    let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
    eprintln!("GPU (traced on the device) vs twin: relative L2 {err:.2e}");
    assert!(err <= 1e-6, "GPU vs twin {err}");
    // The books: what the voxel puts out (4π·J·h³) is emitted; what the medium does not take
    // leaves uncollided.
    for s in [&gpu, &cpu] {
        let e = s.run.outcome.energy;
        let power = 4.0 * std::f64::consts::PI * j * h * h * h;
        assert!((e.emitted[0] / power - 1.0).abs() < 1e-6, "{e:?}");
        assert!(e.uncollided_escaped[0] > 0.0 && e.uncollided_escaped[0] < power, "{e:?}");
        assert!(e.relative_imbalance < 1e-5, "{e:?}");
    }
    // Swept, the same scene streaks: far worse away from the voxel.
    let mut swept = sc.clone();
    swept.solver.emission_uncollided = EmissionUncollided::Swept;
    let s = solve("uncollided-absorber-swept", &swept, Cpu);
    assert!(!s.run.plan.emission_traced && s.run.plan.emission_field);
    let exact = j * h * pair_mean([6.0, 2.0, 1.0], sigma * h);
    let got = s.fluence([at[0] + 6, at[1] + 2, at[2] + 1], 0);
    eprintln!("swept at (6, 2, 1): {got} vs exact {exact}");
    assert!((got - exact).abs() > 0.2 * exact, "swept {got} vs {exact}: no ray effect?");
}

/// Item 5: the Monte-Carlo reference's near field is the same voxel mean the trace integrates.
/// `lpm reference` samples an emission photon uniformly within its voxel and tallies voxel means by
/// track length; around one emitting voxel in an absorber (the emitter itself, its face, edge and
/// corner neighbours, out to two voxels) it agrees with the traced solve within its noise plus
/// 0.5 % (rms of the z-scores 1.05 at 8·10⁶ photons), so a comparison of emission scenes against
/// the reference compares like with like.
#[test]
fn the_reference_near_field_is_the_traced_voxel_mean() {
    let dims = [13, 13, 13];
    let at = [6, 6, 6];
    let sc = one_emitter("uncollided-reference-near", dims, at, 0.6, 0.0, 0.5, 3.0);
    let traced = solve("uncollided-reference-near-cpu", &sc, Cpu);
    assert!(traced.run.plan.emission_traced, "{:?}", traced.run.plan.reasons);
    let opts = lpm::reference::ReferenceOptions {
        photons: 8_000_000,
        seed: 7,
        batches: 32,
        threads: 0,
        image_samples_per_pixel: 0,
        ..lpm::reference::ReferenceOptions::default()
    };
    let emitter = |v: [u32; 3]| if v == at { 1.0 } else { 0.0 };
    let mc = lpm::reference::run_with_emission(&sc, &|_| 1.0, Some(&emitter), 1, &opts);
    let (mut z2, mut n, mut worst) = (0.0, 0usize, 0.0f64);
    for dz in -2i32..=2 {
        for dy in -2i32..=2 {
            for dx in -2i32..=2 {
                let v = [(at[0] as i32 + dx) as u32, (at[1] as i32 + dy) as u32, (at[2] as i32 + dz) as u32];
                let i = ((v[2] * dims[1] + v[1]) * dims[0] + v[0]) as usize;
                let (f, se) = (mc.fluence[i] as f64, mc.std_error[i] as f64);
                let lpm = traced.fluence(v, 0);
                assert!(se > 0.0 && se < 0.01 * f, "voxel {v:?}: reference {f} ± {se}");
                assert!((f - lpm).abs() <= 4.0 * se + 0.005 * lpm, "voxel {v:?}: reference {f} ± {se}, traced {lpm}");
                worst = worst.max((f - lpm).abs() / lpm);
                z2 += ((f - lpm) / se).powi(2);
                n += 1;
            }
        }
    }
    let rms_z = (z2 / n as f64).sqrt();
    eprintln!("reference vs traced near field: {n} voxels, worst {worst:.2e}, rms z {rms_z:.2}");
    assert!(rms_z < 1.6, "rms z {rms_z}: the near fields differ beyond the reference's noise");
}

/// A scattering, anisotropic, RGB glowing core: the GPU matches its twin, the books balance, and
/// the trace is bitwise the same at one thread and at several.
#[test]
fn a_scattering_core_matches_the_twin_balances_and_repeats_bitwise() {
    let dims = [20, 22, 18];
    let path = temp_dir("uncollided-core").join("emission.raw");
    write_raw_field(&path, dims, |v| {
        if (8..11).contains(&v[0]) && (9..12).contains(&v[1]) && (7..9).contains(&v[2]) {
            2.0 + v[0] as f32
        } else {
            0.0
        }
    });
    let mut sc = scene(Shape::Sphere, dims, [0.5, 0.4, 0.3], [0.7, 0.6, 0.5], vec![sky(0.05)]);
    sc.medium.g = 0.5;
    sc.medium.emission = [1.0, 0.5, 2.0];
    sc.volume.emission = Some(EmissionGrid::Raw { path });
    sc.solver.emission_uncollided = EmissionUncollided::Traced;
    sc.solver.directions_per_face = 3;
    sc.solver.max_orders = 5;
    sc.solver.tolerance = 1e-30;
    let gpu = solve("uncollided-core-gpu", &sc, Gpu);
    let cpu = solve("uncollided-core-cpu", &sc, Cpu);
    assert!(gpu.run.plan.emission_traced && !gpu.run.plan.emission_field && gpu.run.plan.storage.len() > 1);
    // It scatters, at k = 3: orders 1 and 2 sweep the scattered light along 12×12 directions of
    // their own (which the GPU and the twin agree on below).
    assert_eq!(gpu.run.plan.scattered_directions_per_face(), 12, "{:?}", gpu.run.plan.reasons);
    assert!(
        gpu.run.plan.reasons.iter().any(|r| r.contains("scattered light: orders 1 and 2 sweep along 12×12")),
        "{:?}",
        gpu.run.plan.reasons
    );
    let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
    assert!(err <= 1e-4, "GPU vs twin {err}");
    assert!(gpu.run.outcome.energy.relative_imbalance < 1e-5, "{:?}", gpu.run.outcome.energy);
    assert!(cpu.run.outcome.energy.relative_imbalance < 1e-9, "{:?}", cpu.run.outcome.energy);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
    let single = one.install(|| solve("uncollided-core-gpu-1", &sc, Gpu));
    assert!(single.field_bits() == gpu.field_bits(), "one thread differs");
    let again = solve("uncollided-core-gpu-again", &sc, Gpu);
    assert!(again.field_bits() == gpu.field_bits(), "a second run differs");
}

/// An emitter beside a mirror lights the half volume as the whole volume's pair of emitters does
/// (the method of images): its uncollided light traced with its image, and with its scattering
/// (orders 1 and 2 on directions of their own, for which both backends solve the doubled
/// volume) the whole volume's answer.
#[test]
fn an_emitter_beside_a_mirror_is_traced_with_its_image() {
    let (half, whole) = ([10, 12, 14], [20, 12, 14]);
    let (sigma, h) = (0.4, 1.0);
    let mut mirrored = one_emitter("uncollided-mirror-half", half, [0, 5, 6], sigma, 0.5, h, 1.0);
    mirrored.boundary.reflective = [[true, false], [false; 2], [false; 2]];
    mirrored.solver.spatial = Some(SpatialScheme::Constant);
    mirrored.solver.emission_uncollided = EmissionUncollided::Traced;
    mirrored.solver.max_orders = 1;
    let path = temp_dir("uncollided-mirror-whole").join("emission.raw");
    write_raw_field(&path, whole, |v| if (v[0] == 9 || v[0] == 10) && v[1] == 5 && v[2] == 6 { 1.0 } else { 0.0 });
    let mut full = mirrored.clone();
    full.volume.dims = whole;
    full.volume.emission = Some(EmissionGrid::Raw { path });
    full.boundary.reflective = [[false; 2]; 3];
    // The worst relative difference of the half volume's fluence from the whole's.
    let worst_against = |s: &Solved, whole: &Solved| {
        let mut worst = 0.0f64;
        for z in 0..half[2] {
            for y in 0..half[1] {
                for x in 0..half[0] {
                    let (a, b) = (s.fluence([x, y, z], 0), whole.fluence([x + 10, y, z], 0));
                    worst = worst.max((a - b).abs() / b);
                }
            }
        }
        worst
    };
    let reference = solve("uncollided-mirror-whole-cpu", &full, Cpu);
    for backend in [Cpu, Gpu] {
        let s = solve(&format!("uncollided-mirror-{backend:?}"), &mirrored, backend);
        assert!(s.run.plan.emission_traced);
        // Order 0's fluence: the uncollided light (max_orders = 1 sweeps nothing more than order
        // 0, whose rays carry no source here).
        let worst = worst_against(&s, &reference);
        assert!(worst < 1e-5, "{backend:?}: worst relative difference {worst}");
    }
    mirrored.solver.max_orders = 3;
    full.solver.max_orders = 3;
    let reference = solve("uncollided-mirror-whole-3", &full, Cpu);
    let s = solve("uncollided-mirror-half-3", &mirrored, Cpu);
    assert_eq!(s.run.plan.scattered_directions_per_face(), 12);
    assert!(
        s.run.plan.reasons.iter().any(|r| r.contains("scattered light's own directions")),
        "{:?}",
        s.run.plan.reasons
    );
    let worst = worst_against(&s, &reference);
    assert!(worst < 1e-5, "three orders: worst relative difference {worst}");
}

/// The plan: `auto` sweeps an emission that fills the medium, says why, and a bad value is refused
/// naming its field.
#[test]
fn the_plan_chooses_and_a_bad_value_is_refused() {
    let dims = [16, 16, 16];
    let path = temp_dir("uncollided-plan").join("emission.raw");
    write_raw_field(&path, dims, |_| 1.0);
    let mut sc = scene(Shape::Box, dims, [0.5; 3], [0.5; 3], vec![]);
    sc.medium.emission = [1.0; 3];
    sc.volume.emission = Some(EmissionGrid::Raw { path });
    sc.solver.max_orders = 1;
    let s = solve("uncollided-plan-fills", &sc, Cpu);
    assert!(!s.run.plan.emission_traced && s.run.plan.emission_field);
    assert!(
        s.run.plan.reasons.iter().any(|r| r.contains("swept (auto)") && r.contains("fills")),
        "{:?}",
        s.run.plan.reasons
    );
    let text = "[volume]\nprocedural = \"sphere\"\ndims = [16, 16, 16]\n[medium]\nsigma_t = 1.0\nalbedo = 0.5\n\
                [solver]\nemission_uncollided = \"sometimes\"\n";
    let err = Scene::from_toml_str(text, std::path::Path::new("t.toml")).expect_err("refused");
    assert!(err.to_string().contains("solver.emission_uncollided"), "{err}");
    // The first-scattered light's directions must be a multiple of k.
    let text = "[volume]\nprocedural = \"sphere\"\ndims = [16, 16, 16]\n[medium]\nsigma_t = 1.0\nalbedo = 0.5\n\
                [solver]\ndirections_per_face = 5\nscattered_directions_per_face = 12\n";
    let err = Scene::from_toml_str(text, std::path::Path::new("t.toml")).expect_err("refused");
    assert!(
        err.to_string().contains("solver.scattered_directions_per_face") && err.to_string().contains("got 12"),
        "{err}"
    );
}

/// A killed GPU solve with a traced emission resumes to the same bits: the trace is not repeated
/// (its power travels in the checkpoint), so nothing is counted twice.
#[test]
fn a_killed_traced_solve_resumes_to_the_same_bits() {
    if !cfg!(feature = "test-hooks") {
        panic!("this kill test needs lpm's test hook: run it with `cargo test --features test-hooks`");
    }
    let dir = temp_dir("uncollided-resume");
    let dims = [20, 18, 22];
    write_raw_field(&dir.join("e.raw"), dims, |v| if v == [9, 8, 10] || v == [7, 9, 12] { 5.0 } else { 0.0 });
    let text = format!(
        "[volume]\nprocedural = \"sphere\"\ndims = [{}, {}, {}]\nemission_raw = \"e.raw\"\n[medium]\n\
         sigma_t = 0.8\nalbedo = 0.9\nemission = 2.0\n[solver]\ndirections_per_face = 3\nmax_orders = 5\n\
         tolerance = 1e-12\ncheckpoint_every_orders = 1\nemission_uncollided = \"traced\"\n",
        dims[0], dims[1], dims[2]
    );
    let scene = write_scene(&dir, &text);
    let s = scene.to_str().unwrap();
    let (whole, cut) = (dir.join("whole"), dir.join("cut"));
    let run = |args: &[&str], abort: Option<u32>| {
        let mut cmd = lpm_command(args);
        if let Some(n) = abort {
            cmd.env("LPM_TEST_ABORT_AT_SLICE", n.to_string());
        }
        cmd.output().expect("run lpm")
    };
    let o = run(&["solve", s, "--out", whole.to_str().unwrap(), "--no-image"], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = run(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image"], Some(20));
    assert!(!o.status.success(), "the solve should have been killed");
    let o = run(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image", "--resume"], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in ["fluence.raw", "source.raw"] {
        assert!(std::fs::read(whole.join(f)).unwrap() == std::fs::read(cut.join(f)).unwrap(), "{f} differs");
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(cut.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["plan"]["emission_uncollided"], "traced");
    let whole_report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(whole.join("report.json")).unwrap()).unwrap();
    for key in ["emitted", "uncollided_escaped", "absorbed"] {
        assert_eq!(report["energy"][key], whole_report["energy"][key], "{key}");
    }
}
