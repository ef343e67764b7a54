//! Per-voxel emission (`volume.emission_raw`, `volume.emission_grid`): the order-0 source both
//! backends gain, its energy, its agreement with the uniform emission it generalises and with the
//! Monte-Carlo reference, VDB grids read over the density's voxels, and bad input.
use crate::common::*;
use lpm::reference::{run_with_emission, ReferenceOptions};
use lpm::scene::{EmissionGrid, EmissionUncollided, Scene, Shape};
use lpm::solver::BackendKind::{Cpu, Gpu};
use std::path::PathBuf;

/// A glowing core: emission 4 in a small cube off centre, 0 elsewhere.
fn core(v: [u32; 3]) -> f32 {
    if (6..11).contains(&v[0]) && (8..14).contains(&v[1]) && (5..12).contains(&v[2]) {
        4.0
    } else {
        0.0
    }
}

/// An RGB sphere with sky light, emitting `core` tinted by `tint`.
fn glowing_sphere(name: &str, tint: [f64; 3], e: impl Fn([u32; 3]) -> f32) -> (Scene, PathBuf) {
    let dims = [20, 22, 18];
    let path = temp_dir(name).join("emission.raw");
    write_raw_field(&path, dims, e);
    let mut sc = scene(Shape::Sphere, dims, [0.8, 0.6, 0.4], [0.7, 0.6, 0.5], vec![sky(0.2)]);
    sc.medium.emission = tint;
    sc.volume.emission = Some(EmissionGrid::Raw { path: path.clone() });
    // The swept per-voxel source (solver::emission) is what these tests hold; the traced one has
    // its own (emission_uncollided.rs).
    sc.solver.emission_uncollided = EmissionUncollided::Swept;
    sc.solver.directions_per_face = 3;
    sc.solver.max_orders = 6;
    sc.solver.tolerance = 1e-30;
    (sc, path)
}

#[test]
fn gpu_matches_the_twin_and_energy_balances() {
    let (sc, _) = glowing_sphere("emission-gpu-twin", [1.0, 0.5, 2.0], core);
    let gpu = solve("emission-gpu", &sc, Gpu);
    let cpu = solve("emission-cpu", &sc, Cpu);
    assert!(gpu.run.plan.emission_field && !gpu.run.plan.emission);
    let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
    assert!(err <= 1e-4, "relative L2 {err}");
    let e = &gpu.run.outcome.energy;
    assert!(e.emitted.iter().all(|&p| p > 0.0), "{e:?}");
    assert!(e.relative_imbalance < 1e-5, "{e:?}");
    assert!(cpu.run.outcome.energy.relative_imbalance < 1e-9, "{:?}", cpu.run.outcome.energy);
    // The tint scales each channel: the blue core emits twice white, the green half.
    let [r, g, b] = gpu.run.outcome.energy.emitted;
    assert!((g / r - 0.5 * (0.6 * 0.4) / (0.8 * 0.3)).abs() < 1e-5, "{r} {g}");
    assert!((b / r - 2.0 * (0.4 * 0.5) / (0.8 * 0.3)).abs() < 1e-5, "{r} {b}");
}

#[test]
fn a_grid_of_ones_is_the_uniform_emission() {
    let (grid, _) = glowing_sphere("emission-ones", [0.7, 0.3, 1.1], |_| 1.0);
    let mut uniform = grid.clone();
    uniform.volume.emission = None;
    for backend in [Cpu, Gpu] {
        let a = solve("emission-ones-grid", &grid, backend);
        let b = solve("emission-ones-uniform", &uniform, backend);
        assert!(b.run.plan.emission && !b.run.plan.emission_field);
        let err = relative_l2(&a.fluence_all(), &b.fluence_all());
        assert!(err <= 1e-6, "{backend:?}: relative L2 {err}");
        for ch in 0..3 {
            let (ea, eb) = (a.run.outcome.energy.emitted[ch], b.run.outcome.energy.emitted[ch]);
            assert!((ea / eb - 1.0).abs() < 1e-6, "{backend:?} channel {ch}: {ea} vs {eb}");
        }
    }
}

#[test]
fn the_glowing_core_agrees_with_monte_carlo() {
    // Grey, so one channel; no sky: all light comes from the emission grid.
    let dims = [20, 22, 18];
    let path = temp_dir("emission-mc").join("emission.raw");
    write_raw_field(&path, dims, core);
    let mut sc = scene(Shape::Box, dims, [0.3; 3], [0.8; 3], vec![]);
    sc.medium.emission = [1.0; 3];
    sc.volume.emission = Some(EmissionGrid::Raw { path });
    sc.solver.directions_per_face = 4;
    sc.solver.tolerance = 1e-5;
    let lpm = solve("emission-mc-lpm", &sc, Cpu);
    let opts = ReferenceOptions { photons: 2_000_000, seed: 3, ..ReferenceOptions::default() };
    let e = |v: [u32; 3]| core(v);
    let mc = run_with_emission(&sc, &|_| 1.0, Some(&e), 1, &opts);
    let lpm_phi: Vec<f64> = lpm.fluence_all();
    let mc_phi: Vec<f64> = mc.fluence.iter().map(|&v| v as f64).collect();
    let (sa, sb): (f64, f64) = (lpm_phi.iter().sum(), mc_phi.iter().sum());
    eprintln!(
        "emission vs Monte Carlo: total fluence {sa:.5e} vs {sb:.5e}, relative L2 {:.3e}",
        relative_l2(&lpm_phi, &mc_phi)
    );
    assert!((sa / sb - 1.0).abs() < 0.02, "total fluence {sa} vs Monte Carlo {sb}");
    // Measured 5.8e-2: Monte-Carlo noise at 2·10⁶ photons over 7 920 voxels plus the LPM's own
    // spatial error at the core's sharp edges; the total is the tight check.
    assert!(relative_l2(&lpm_phi, &mc_phi) < 0.08);
}

#[test]
fn a_vdb_emission_grid_solves_like_the_same_raw_grid() {
    let dir = temp_dir("emission-vdb");
    let vdb = dir.join("fire.vdb");
    // Density over [−3, 12]³ (index space), flame over a smaller box inside it: OpenVDB writes it.
    let script = r#"
import sys
import pyopenvdb as openvdb
d = openvdb.FloatGrid(); d.name = "density"
f = openvdb.FloatGrid(); f.name = "flame"
for x in range(-3, 13):
    for y in range(-3, 13):
        for z in range(-3, 13):
            d.getAccessor().setValueOn((x, y, z), 1.0 + 0.01 * ((x + 2 * y + 3 * z) % 7))
for x in range(2, 7):
    for y in range(0, 5):
        for z in range(3, 9):
            f.getAccessor().setValueOn((x, y, z), 0.5 * (1 + (x + y + z) % 3))
openvdb.write(sys.argv[1], grids=[d, f])
"#;
    let out = std::process::Command::new("/usr/bin/python3")
        .args(["-c", script, vdb.to_str().expect("utf-8 path")])
        .output()
        .expect("run /usr/bin/python3 (install python3-openvdb: tools/setup.sh)");
    assert!(out.status.success(), "python3-openvdb: {}", String::from_utf8_lossy(&out.stderr));
    let text = |emission: &str| {
        format!(
            "[volume]\nvdb = \"fire.vdb\"\n{emission}\n[medium]\nsigma_t = 0.5\nalbedo = 0.6\nemission = [1.0, 0.6, 0.2]\n\
             [solver]\ndirections_per_face = 2\nmax_orders = 3\ntolerance = 1e-30\n"
        )
    };
    let a = Scene::load(&write_scene_as(&dir, "vdb.toml", &text("emission_grid = \"flame\""))).expect("vdb scene");
    // The same flame as a raw file over the density's voxels (index −3 is voxel 0).
    let raw = dir.join("flame.raw");
    write_raw_field(&raw, [16; 3], |v| {
        let c = v.map(|x| x as i32 - 3);
        if (2..7).contains(&c[0]) && (0..5).contains(&c[1]) && (3..9).contains(&c[2]) {
            0.5 * (1 + (c[0] + c[1] + c[2]) % 3) as f32
        } else {
            0.0
        }
    });
    let b = Scene::load(&write_scene_as(&dir, "raw.toml", &text("emission_raw = \"flame.raw\""))).expect("raw scene");
    let (sa, sb) = (solve("emission-vdb-a", &a, Gpu), solve("emission-vdb-b", &b, Gpu));
    let bits = |s: &Solved| s.fluence_all().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert!(sa.run.outcome.energy.emitted[0] > 0.0);
    assert!(bits(&sa) == bits(&sb), "the VDB flame grid must solve like the same values given raw");
}

#[test]
fn bad_emission_input_is_refused_with_its_name() {
    let dir = temp_dir("emission-bad");
    write_raw_field(&dir.join("nan.raw"), [4, 4, 4], |v| if v == [1, 2, 3] { f32::NAN } else { 1.0 });
    std::fs::write(dir.join("short.raw"), [0u8; 12]).expect("write");
    let base = "[volume]\nprocedural = \"box\"\ndims = [4, 4, 4]\n";
    let tail = "[medium]\nsigma_t = 1.0\nalbedo = 0.5\n";
    // Both keys, a grid for a non-VDB volume, a file of the wrong size: scene errors naming the key.
    for (keys, expect) in [
        ("emission_raw = \"nan.raw\"\nemission_grid = \"flame\"\n", "volume.emission_grid"),
        ("emission_grid = \"flame\"\n", "only applies to a `vdb` volume"),
        ("emission_raw = \"short.raw\"\n", "volume.emission_raw"),
    ] {
        let path = write_scene(&dir, &format!("{base}{keys}{tail}"));
        let err = Scene::load(&path).expect_err("must be refused").to_string();
        assert!(err.contains(expect), "{err}");
    }
    // A NaN inside the file: the store import names the file, the voxel and "emission".
    let path = write_scene(&dir, &format!("{base}emission_raw = \"nan.raw\"\n{tail}"));
    let sc = Scene::load(&path).expect("valid scene");
    let err = lpm::solver::build_store(&sc, &dir.join("store")).err().expect("NaN refused").to_string();
    assert!(err.contains("nan.raw") && err.contains("(1, 2, 3)") && err.contains("emission"), "{err}");
}

#[test]
fn the_image_shows_the_glow_where_the_grid_emits() {
    let dir = temp_dir("emission-image");
    let dims = [20, 22, 18];
    write_raw_field(&dir.join("core.raw"), dims, core);
    write_raw_field(&dir.join("ones.raw"), dims, |_| 1.0);
    let text = |emission: &str| {
        format!(
            "[volume]\nprocedural = \"box\"\ndims = [20, 22, 18]\n{emission}\n[medium]\nsigma_t = 0.1\nalbedo = 0.5\n\
             emission = [1.0, 0.5, 0.25]\n[solver]\ndirections_per_face = 2\nmax_orders = 2\n\
             [camera]\nwidth = 40\nheight = 36\n"
        )
    };
    let glowing = image_of(write_scene_as(&dir, "core.toml", &text("emission_raw = \"core.raw\"")), &dir.join("core"));
    let ones = image_of(write_scene_as(&dir, "ones.toml", &text("emission_raw = \"ones.raw\"")), &dir.join("ones"));
    let uniform = image_of(write_scene_as(&dir, "uniform.toml", &text("")), &dir.join("uniform"));
    // A grid of ones renders as the uniform emission (the trilinear weights sum to 1).
    for (a, b) in ones.iter().zip(&uniform) {
        for c in 0..4 {
            assert!((a[c] - b[c]).abs() <= 1e-5 * b[c].abs().max(1e-3), "{a:?} vs {b:?}");
        }
    }
    // The core glows in some pixels and is dark in others; its colour follows the tint.
    let brightest = glowing.iter().fold([0f32; 4], |m, p| if p[0] > m[0] { *p } else { m });
    assert!(brightest[0] > 0.0 && brightest[1] / brightest[0] < 0.75, "{brightest:?}");
    assert!(glowing.iter().filter(|p| p[0] < 0.05 * brightest[0]).count() > glowing.len() / 4);
    // `lpm render` re-renders it from the kept data, the emission field included: the same pixels.
    let out = dir.join("core");
    assert!(
        rerender_transparent(&out, &dir.join("again.exr")) == glowing,
        "lpm render must reproduce the solve's image"
    );
}
