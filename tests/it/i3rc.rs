//! The I3RC step cloud (Cahalan et al. 2005, BAMS 86(9), 1275–1293; case 1, experiment 1: overhead
//! sun, albedo 1, g = 0.85, optical depth 2 | 18 in two halves, periodic across) as written by
//! `tools/benchmarks/i3rc.py` (32 × 4 × 16 voxels of 15.625 m, k = 3): a conservative periodic
//! cloud must give R + T = 1 with no net flow through its periodic faces, lose no sunlight at its
//! sides, be the same in every y row (it is uniform along y), and land near the consensus domain
//! means, per column too (from the faces' exitance maps). The GPU must match its twin. The comparison at more settings is in `benches/RESULTS.md`.
use crate::common::*;
use lpm::scene::Scene;
use lpm::solver::BackendKind::{Cpu, Gpu};
use std::path::PathBuf;

/// Domain means of the I3RC consensus reflectance and transmittance (direct + diffuse), case 1
/// experiment 1, averaged over its 32 columns (the generator holds the per-column values).
const CONSENSUS_R: f64 = 0.327595;
const CONSENSUS_T: f64 = 0.672398;
/// The consensus per column (1..32), as `tools/benchmarks/i3rc.py` holds them.
const COLUMN_R: [f64; 32] = [
    0.27859, 0.26712, 0.25531, 0.24542, 0.23761, 0.23207, 0.22805, 0.22592, 0.22597, 0.22796, 0.23176, 0.23787,
    0.24578, 0.25563, 0.26676, 0.27939, 0.32332, 0.36758, 0.39589, 0.41544, 0.43034, 0.44028, 0.44675, 0.45022,
    0.44978, 0.44676, 0.44118, 0.43032, 0.41623, 0.39624, 0.36826, 0.32325,
];
const COLUMN_T: [f64; 32] = [
    0.84654, 0.94825, 1.0049, 1.0359, 1.0539, 1.0638, 1.0697, 1.0706, 1.0703, 1.0697, 1.0640, 1.0543, 1.0363, 1.0045,
    0.94871, 0.84774, 0.44446, 0.35244, 0.32505, 0.31401, 0.30884, 0.30715, 0.30596, 0.30572, 0.30614, 0.30642,
    0.30683, 0.30907, 0.31385, 0.32537, 0.35255, 0.44375,
];

/// Runs the generator into a directory of its own (`name`: tests run in parallel).
fn generate(name: &str) -> Scene {
    let dir = temp_dir(name);
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tools/benchmarks/i3rc.py");
    let out = std::process::Command::new("/usr/bin/python3")
        .arg(&script)
        .args(["generate", "--ny", "4", "--k", "3", "--out"])
        .arg(&dir)
        .output()
        .expect("run /usr/bin/python3");
    assert!(out.status.success(), "i3rc.py: {}", String::from_utf8_lossy(&out.stderr));
    Scene::load(&dir.join("scene.toml")).expect("the generated scene loads")
}

/// (R, T): the top face's outgoing over incoming power, the bottom face's outgoing (the direct
/// beam included, as the consensus T) over the top's incoming.
fn reflectance_transmittance(s: &Solved) -> (f64, f64) {
    let faces = &s.run.outcome.energy.faces;
    let sun = faces[5].power_in[0];
    (faces[5].power_out[0] / sun, faces[4].power_out[0] / sun)
}

#[test]
fn the_step_cloud_conserves_and_is_near_the_consensus() {
    let sc = generate("i3rc-scene");
    assert_eq!(sc.volume.dims, [32, 4, 16]);
    let s = solve("i3rc-cpu", &sc, Cpu);
    assert!(s.run.outcome.converged);
    let e = &s.run.outcome.energy;
    assert!(e.relative_imbalance < 1e-9, "{e:?}");
    assert_eq!(e.absorbed[0], 0.0, "albedo 1 absorbs nothing");
    // The sun (irradiance 1, overhead) brings exactly E × the top face's area, 0.5 km × 4·h: with
    // periodic sides no ray is born beside the cloud.
    let area = 0.5 * 4.0 * 0.015625;
    assert!((e.faces[5].power_in[0] / area - 1.0).abs() < 1e-9, "sun power {}", e.faces[5].power_in[0]);
    assert!(e.faces[4].power_in[0] == 0.0, "nothing enters from below");
    // No net flow through a periodic face: what leaves one side enters the other (all but the
    // light still in flight when the orders stop).
    for f in 0..4 {
        let (came, left) = (e.faces[f].power_in[0], e.faces[f ^ 1].power_out[0]);
        assert!((came - left).abs() < 1e-4 * area, "face {f}: in {came} vs out of the opposite {left}");
    }
    // Conservative: R + T = 1 up to what the stop rule leaves (tolerance 1e-4; measured 0.999955).
    let (r, t) = reflectance_transmittance(&s);
    eprintln!("I3RC step cloud, k = 3: R {r:.5} (consensus {CONSENSUS_R}), T {t:.5} (consensus {CONSENSUS_T})");
    assert!((r + t - 1.0).abs() < 2e-4, "R {r} + T {t}");
    // Near the consensus. Measured at k = 3: R −2.3 %, T +1.1 % (k = 5: R −0.2 %, T +0.1 %). Before
    // δ-M kept HG(g)'s shape outside the forward peak (an HG(g') remainder) R was +7 % at every k:
    // see benches/RESULTS.md, "The forward peak's shape". These bounds are lpm's measured error
    // with margin, not a tuning target.
    assert!((r / CONSENSUS_R - 1.0).abs() < 0.04, "R {r} vs consensus {CONSENSUS_R}");
    assert!((t / CONSENSUS_T - 1.0).abs() < 0.02, "T {t} vs consensus {CONSENSUS_T}");
    // The thick half reflects more than the thin half lets through its top: the fluence near the
    // top of the thick half exceeds that of the thin half (consensus R 0.409 vs 0.246 per half).
    let top = |x0: u32| (x0..x0 + 16).map(|x| s.fluence([x, 0, 15], 0)).sum::<f64>();
    assert!(top(16) > top(0), "thick top {} vs thin top {}", top(16), top(0));
    per_column_r_and_t(&s, r, t);
    // Uniform along y: every y row alike, up to the lattice's own pattern (rays born where their
    // slots wrap), measured 0.7 %.
    let [nx, ny, nz] = s.run.plan.dims;
    for (x, y, z) in (0..nz).flat_map(|z| (0..ny).flat_map(move |y| (0..nx).map(move |x| (x, y, z)))) {
        let (a, b) = (s.fluence([x, y, z], 0), s.fluence([x, 0, z], 0));
        assert!((a - b).abs() < 0.02 * b, "({x}, {y}, {z}): {a} vs row 0 {b}");
    }
}

/// Per column (one voxel wide at this size), R and T from the top and bottom faces' exitance
/// maps (`solver::exitance`): their means are the domain's R and T, each half lands near the
/// consensus's, and every column within the ray effects of k = 3 of it (measured C/E 0.75–1.16 for
/// R, 0.69–1.15 for T: the discrete directions light the columns unevenly, ±10 % from one column
/// to the next even at k = 5, benches/RESULTS.md "I3RC per-column R and T").
fn per_column_r_and_t(s: &Solved, r: f64, t: f64) {
    let maps = s.run.exit_maps.as_ref().expect("the CPU twin's maps");
    let [nx, ny, _] = s.run.plan.dims;
    let sun = s.run.outcome.energy.faces[5].power_in[0];
    // Each column receives sun / 32 (the top face is lit alike everywhere, periodic sides).
    let column =
        |face: usize, x: u32| (0..ny).map(|y| maps.pixel(face, (x + nx * y) as usize)[0]).sum::<f64>() * 32.0 / sun;
    let (rs, ts): (Vec<f64>, Vec<f64>) = (0..nx).map(|x| (column(5, x), column(4, x))).unzip();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!((mean(&rs) - r).abs() < 1e-9 && (mean(&ts) - t).abs() < 1e-9, "the columns add up to R and T");
    for (half, cols) in [("thin", 0..16), ("thick", 16..32)] {
        let (got_r, got_t) = (mean(&rs[cols.clone()]), mean(&ts[cols.clone()]));
        let (want_r, want_t) = (mean(&COLUMN_R[cols.clone()]), mean(&COLUMN_T[cols]));
        eprintln!("{half} half: R {got_r:.5} (consensus {want_r:.5}), T {got_t:.5} (consensus {want_t:.5})");
        // Measured: thin R −7.2 %, T +2.4 %; thick R +0.7 %, T −2.7 %.
        assert!((got_r / want_r - 1.0).abs() < 0.12, "{half} half R {got_r} vs {want_r}");
        assert!((got_t / want_t - 1.0).abs() < 0.05, "{half} half T {got_t} vs {want_t}");
    }
    for x in 0..32 {
        let (cr, ct) = (rs[x] / COLUMN_R[x], ts[x] / COLUMN_T[x]);
        assert!((0.6..1.4).contains(&cr) && (0.6..1.4).contains(&ct), "column {}: R C/E {cr}, T C/E {ct}", x + 1);
    }
}

#[test]
fn the_gpu_solves_the_step_cloud_as_its_twin() {
    // A few orders (validation on): the same discretisation, faces' books included.
    let mut sc = generate("i3rc-scene-gpu");
    sc.solver.max_orders = 6;
    sc.solver.tolerance = 1e-30;
    let (g, c) = (solve("i3rc-gpu", &sc, Gpu), solve("i3rc-gpu-twin", &sc, Cpu));
    let err = relative_l2(&g.fluence_all(), &c.fluence_all());
    assert!(err <= 1e-4, "GPU vs twin: relative L2 {err}");
    let (rg, tg) = reflectance_transmittance(&g);
    let (rc, tc) = reflectance_transmittance(&c);
    assert!((rg - rc).abs() < 1e-5 && (tg - tc).abs() < 1e-5, "GPU R {rg} T {tg} vs twin R {rc} T {tc}");
    assert!(g.run.outcome.energy.relative_imbalance < 1e-5, "{:?}", g.run.outcome.energy);
}
