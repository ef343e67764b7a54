//! Kobayashi et al. 2001 (Progress in Nuclear Energy 39(2), 119–144), problems 1 (a source, a
//! square void, a shield) and 3 (a dog-leg void duct), cases i (no scattering) and ii (albedo 0.5),
//! as written by `tools/benchmarks/kobayashi.py` at the coarse grid where every detector point is a
//! voxel centre (10 cm voxels: 20³ and 12 × 20 × 12). The octant problems with their mirror planes
//! are stated as the full mirrored domain (exact by the method of images), so the solution must be
//! mirror-symmetric; the source's power must be the benchmark's S = 1 /cm³/s over the source cube;
//! the books must balance; the GPU must match its twin; and the points a coarse grid can resolve
//! must be near the published values. The fine-grid comparison is in `benches/RESULTS.md`. The
//! octant as published, with mirrors at x, y, z = 0 (`--octant`), must solve to the same flux.
use crate::common::*;
use lpm::scene::Scene;
use lpm::solver::BackendKind::{self, Cpu, Gpu};
use std::path::PathBuf;

/// Runs the generator for `problem` and `case` at 10 cm voxels into a fresh directory.
fn generate(problem: u32, case: &str) -> (Scene, PathBuf) {
    generate_with(problem, case, &[])
}

/// [`generate`] with more of the generator's options.
fn generate_with(problem: u32, case: &str, options: &[&str]) -> (Scene, PathBuf) {
    let dir = temp_dir(&format!("kobayashi-scene-{problem}-{case}{}", options.concat()));
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tools/benchmarks/kobayashi.py");
    let out = std::process::Command::new("/usr/bin/python3")
        .arg(&script)
        .args(["generate", "--problem", &problem.to_string(), "--case", case, "--voxel-size", "10"])
        .args(options)
        .arg("--out")
        .arg(&dir)
        .output()
        .expect("run /usr/bin/python3");
    assert!(out.status.success(), "kobayashi.py: {}", String::from_utf8_lossy(&out.stderr));
    let scene = Scene::load(&dir.join("scene.toml")).expect("the generated scene loads");
    (scene, dir)
}

/// `scene` with its emission swept (`solver.emission_uncollided = "swept"`).
fn swept(mut scene: Scene) -> Scene {
    scene.solver.emission_uncollided = lpm::scene::EmissionUncollided::Swept;
    scene
}

/// The voxel of octant point `p` (cm) in the mirrored domain of 10 cm voxels centred on the origin.
fn voxel(s: &Solved, p: [f64; 3]) -> [u32; 3] {
    let dims = s.run.plan.dims;
    std::array::from_fn(|a| ((p[a] + 5.0 * dims[a] as f64) / 10.0 - 0.5).round() as u32)
}

fn phi(s: &Solved, p: [f64; 3]) -> f64 {
    s.fluence(voxel(s, p), 0)
}

/// Largest relative difference between the fluence and its mirror image about each axis.
fn mirror_asymmetry(s: &Solved) -> f64 {
    let dims = s.run.plan.dims;
    let mut worst = 0.0f64;
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let v = [x, y, z];
                for a in 0..3 {
                    let mut w = v;
                    w[a] = dims[a] - 1 - v[a];
                    let (p, q) = (s.fluence(v, 0), s.fluence(w, 0));
                    worst = worst.max((p - q).abs() / q.abs().max(1e-30));
                }
            }
        }
    }
    worst
}

/// What every solve of the benchmark must satisfy: one grey channel, the source's power, the
/// books, the mirror symmetry. Returns the solve.
fn solve_checked(name: &str, scene: &Scene, backend: BackendKind) -> Solved {
    let s = solve(name, scene, backend);
    assert_eq!(s.run.plan.channels, 1, "a grey problem");
    let e = &s.run.outcome.energy;
    // S = 1 /cm³/s over the source cube [−10, 10]³ of the mirrored domain: 8000 /s, whatever the
    // albedo (the generator divides the emission by σa; the medium is stored in f32, hence 1e-6).
    assert!((e.emitted[0] / 8000.0 - 1.0).abs() < 1e-6, "{name}: emitted {}", e.emitted[0]);
    assert_eq!(e.boundary_in[0], 0.0, "{name}: no light enters from outside");
    let tol = if backend == Cpu { 1e-9 } else { 1e-5 };
    assert!(e.relative_imbalance < tol, "{name}: {e:?}");
    let asym = mirror_asymmetry(&s);
    assert!(asym <= 1e-6, "{name}: the mirrored domain's solution is asymmetric by {asym}");
    s
}

#[test]
fn problem_1_both_cases() {
    // Published flux at the source point (5, 5, 5): case i 5.95659 (analytic), case ii 8.29260 (MC).
    // At 10 cm the source is two voxels wide and k = 5: measured C/E 1.047 and 1.095. The tolerance
    // (12 %) is the coarse grid's, not a claim about lpm's accuracy (RESULTS: 2 cm voxels).
    // The swept emission (the figures above are its); the traced one is held in RESULTS at 2 cm
    // and in tests/it/emission_uncollided.rs.
    let (i, ii) = (swept(generate(1, "i").0), swept(generate(1, "ii").0));
    let a = solve_checked("kobayashi-1-i", &i, Cpu);
    let b = solve_checked("kobayashi-1-ii", &ii, Cpu);
    for (s, published) in [(&a, 5.95659), (&b, 8.29260)] {
        let ce = phi(s, [5.0, 5.0, 5.0]) / published;
        assert!((ce - 1.0).abs() < 0.12, "source point C/E {ce}");
    }
    // Case i has no scattering: one order, and everything emitted is absorbed or leaves.
    assert_eq!(a.run.outcome.orders, 1);
    let e = &a.run.outcome.energy;
    assert!(((e.absorbed[0] + e.boundary_out[0]) / e.emitted[0] - 1.0).abs() < 1e-9, "{e:?}");
    assert_eq!(e.unpropagated[0], 0.0, "nothing scatters");
    // Scattering (albedo 0.5) raises the flux everywhere in the medium: half of what case i
    // absorbs is scattered on instead.
    let (fa, fb) = (a.fluence_all(), b.fluence_all());
    assert!(fa.iter().zip(&fb).all(|(x, y)| y >= x), "case ii below case i somewhere");
    // Problem 1 is a cube: its solution is symmetric under swapping axes too (the direction set is).
    let [n, _, _] = a.run.plan.dims;
    for (z, y, x) in (0..n).flat_map(|z| (0..n).flat_map(move |y| (0..n).map(move |x| (z, y, x)))) {
        let (p, q) = (b.fluence([x, y, z], 0), b.fluence([y, x, z], 0));
        assert!((p - q).abs() <= 1e-5 * q.max(1e-30), "({x}, {y}, {z}): {p} vs swapped {q}");
    }
}

#[test]
fn problem_3_both_cases_and_the_gpu() {
    let (i, ii) = (swept(generate(3, "i").0), swept(generate(3, "ii").0));
    assert_eq!(i.volume.dims, [12, 20, 12]);
    let a = solve_checked("kobayashi-3-i", &i, Cpu);
    let b = solve_checked("kobayashi-3-ii", &ii, Cpu);
    // Source point: published 5.95659 (case i) and 8.61578 (case ii); measured C/E 0.911 and 0.895
    // at 10 cm (see problem 1 for why the tolerance is wide).
    for (s, published) in [(&a, 5.95659), (&b, 8.61578)] {
        let ce = phi(s, [5.0, 5.0, 5.0]) / published;
        assert!((ce - 1.0).abs() < 0.12, "source point C/E {ce}");
    }
    // The duct's last leg (x 30–40, z 30–40, up to y = 100) carries flux past the shield: on line C
    // (x, 95, 35) the published case ii flux peaks at x = 35 (2.62e-4 against 2.06e-4 at x = 25 and
    // 1.05e-4 at x = 45); the coarse solve shows the same streaming peak.
    let duct = phi(&b, [35.0, 95.0, 35.0]);
    for x in [25.0, 45.0] {
        let beside = phi(&b, [x, 95.0, 35.0]);
        assert!(duct > 1.2 * beside, "duct {duct} vs shield at x = {x}: {beside}");
    }
    // The GPU solves the same discretisation (validation on).
    let g = solve_checked("kobayashi-3-ii-gpu", &ii, Gpu);
    let err = relative_l2(&g.fluence_all(), &b.fluence_all());
    assert!(err <= 1e-4, "GPU vs twin: relative L2 {err}");
}

#[test]
fn the_octant_with_mirrors_solves_to_the_mirrored_domain() {
    // Problem 1 at 10 cm: the octant is 10³ voxels, and k = 5's slopes (0, ±0.4, ±0.8) move whole
    // voxels over its 10 planes, so the plan nudges nothing and the two statements are the same
    // discrete problem (the octant's reflections arrive an order late: solve both to the end).
    for case in ["i", "ii"] {
        let (mut octant, _) = generate_with(1, case, &["--octant"]);
        let (mut full, _) = generate(1, case);
        assert_eq!(octant.volume.dims, [10, 10, 10]);
        for s in [&mut octant, &mut full] {
            s.solver.tolerance = 1e-9;
        }
        let a = solve(&format!("kobayashi-octant-{case}"), &octant, Cpu);
        let b = solve_checked(&format!("kobayashi-full-{case}"), &full, Cpu);
        // A mirrored source cube of 20³ cm is 1000 /s in the octant.
        let e = &a.run.outcome.energy;
        assert!((e.emitted[0] / 1000.0 - 1.0).abs() < 1e-6, "octant {case}: emitted {}", e.emitted[0]);
        assert!(e.relative_imbalance < 1e-9, "octant {case}: {e:?}");
        let mut worst = 0.0f64;
        for (z, y, x) in (0..10).flat_map(|z| (0..10).flat_map(move |y| (0..10).map(move |x| (z, y, x)))) {
            let (p, q) = (a.fluence([x, y, z], 0), b.fluence([x + 10, y + 10, z + 10], 0));
            worst = worst.max((p - q).abs() / q);
        }
        assert!(worst < 1e-5, "case {case}: the octant is {worst} from the mirrored domain");
    }
}

/// On the GPU the octant is solved as the volume doubled by its three mirrors (`solver::unfold`),
/// the per-voxel emission copied across: the twin's octant to the kernels' rounding, with the
/// octant's own source power in the books.
#[test]
fn the_gpu_solves_the_octant_with_mirrors_as_the_twin() {
    let (mut octant, _) = generate_with(1, "ii", &["--octant"]);
    octant.solver.tolerance = 1e-6;
    let (g, c) = (solve("kobayashi-octant-gpu", &octant, Gpu), solve("kobayashi-octant-twin", &octant, Cpu));
    let err = relative_l2(&g.fluence_all(), &c.fluence_all());
    assert!(err < 1e-4, "GPU vs twin {err}");
    let e = &g.run.outcome.energy;
    assert!((e.emitted[0] / 1000.0 - 1.0).abs() < 1e-5, "emitted {}", e.emitted[0]);
    assert!(e.relative_imbalance < 1e-5, "{e:?}");
}

#[test]
fn bench_accuracy_runs_the_octant_with_both_methods_mirrored() {
    // `lpm bench accuracy` copies the scene for each run: the copies must find the files it names
    // beside it (the density and the per-voxel emission), and both the solver (CPU backend) and the
    // Monte-Carlo reference must treat the mirrors. Problem 1 case ii at 10 cm: one mean free path
    // per voxel and a 10 cm source, so lpm's error is large here; what is asserted is that every run
    // solved, and that the reference agrees with itself to its noise.
    let (_, dir) = generate_with(1, "ii", &["--octant"]);
    let out = dir.join("accuracy");
    let o = lpm_command(&[
        "bench",
        "accuracy",
        dir.join("scene.toml").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--backend",
        "cpu",
        "--k",
        "3",
        "--tolerances",
        "1e-3",
        "--precisions",
        "f32",
        "--samples",
        "1e5",
        "--reference-samples",
        "4e5",
    ])
    .output()
    .expect("run lpm");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("accuracy.json")).expect("accuracy.json"))
            .expect("accuracy.json is JSON");
    let rows = report["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 2, "{rows:?}");
    let error = |r: &serde_json::Value| r["relative_l2"].as_f64().expect("relative_l2");
    // lpm's error at this coarse grid (measured 0.36 at k = 3, mostly the 10 cm source's ray
    // effects); a copy that lost the emission file does not run at all.
    assert!(error(&rows[0]) < 0.5, "lpm: {}", rows[0]);
    assert!(error(&rows[1]) < 0.05, "Monte Carlo against its long run: {}", rows[1]);
}
