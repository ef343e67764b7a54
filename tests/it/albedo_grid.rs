//! Per-voxel albedo (`volume.albedo_raw`, `volume.albedo_grid`): a factor a(v) in [0, 1] on
//! `medium.albedo`. The limits it generalises (a = 1, 0, ½), a two-region medium on both backends
//! (GPU = twin, energy, bitwise repeat, Monte Carlo), emission over it (σa per voxel), VDB and raw
//! input read voxel for voxel, bad input, and a cancelled solve resumed to the same bits.
use crate::common::*;
use lpm::reference::{run_with_fields, ReferenceOptions, VoxelFields};
use lpm::scene::{AlbedoGrid, DiffusionCorrection, Scene, Shape, StoragePrecision};
use lpm::solver::BackendKind::{self, Cpu, Gpu};
use std::path::PathBuf;

const DIMS: [u32; 3] = [18, 16, 14];

/// Two regions: albedo factor 0.99 for x below the middle, 0.2 above it.
fn two_regions(v: [u32; 3]) -> f32 {
    if v[0] < DIMS[0] / 2 {
        0.99
    } else {
        0.2
    }
}

/// An RGB sphere under a sky and a sun, g = 0.3 (several storage directions), with the albedo
/// factor `a` from a raw file.
fn sphere_with_albedo(name: &str, a: impl Fn([u32; 3]) -> f32) -> (Scene, PathBuf) {
    // Not `name` itself: `solve` clears a directory of its own name.
    let path = temp_dir(&format!("{name}-input")).join("albedo.raw");
    write_raw_field(&path, DIMS, a);
    let mut sc = scene(
        Shape::Sphere,
        DIMS,
        [0.6, 0.5, 0.4],
        [0.9, 0.8, 0.7],
        vec![sky(0.3), sun([0.3, -0.5, 1.0], [2.0, 1.5, 1.0])],
    );
    sc.medium.g = 0.3;
    sc.volume.albedo = Some(AlbedoGrid::Raw { path: path.clone() });
    sc.solver.directions_per_face = 3;
    sc.solver.max_orders = 6;
    sc.solver.tolerance = 1e-30;
    (sc, path)
}

fn bits(s: &Solved) -> Vec<u64> {
    s.fluence_all().iter().map(|v| v.to_bits()).collect()
}

fn source_bits(s: &Solved) -> Vec<u32> {
    s.fields.source_total.as_slice().iter().map(|v| v.to_bits()).collect()
}

#[test]
fn a_grid_of_ones_is_bitwise_no_grid_on_both_backends() {
    let (grid, _) = sphere_with_albedo("albedo-ones", |_| 1.0);
    let mut none = grid.clone();
    none.volume.albedo = None;
    for backend in [Cpu, Gpu] {
        let a = solve("albedo-ones-grid", &grid, backend);
        let b = solve("albedo-ones-none", &none, backend);
        assert!(a.run.plan.albedo_field && !b.run.plan.albedo_field);
        assert!(bits(&a) == bits(&b), "{backend:?}: a(v) = 1 must give the fluence of no grid, bit for bit");
        assert!(source_bits(&a) == source_bits(&b), "{backend:?}: and the same summed source");
    }
}

#[test]
fn a_grid_of_zeros_is_an_absorber_and_a_half_halves_the_albedo() {
    let (zeros, _) = sphere_with_albedo("albedo-zeros", |_| 0.0);
    let (halves, _) = sphere_with_albedo("albedo-halves", |_| 0.5);
    let mut absorber = zeros.clone();
    absorber.volume.albedo = None;
    absorber.medium.albedo = [0.0; 3];
    let mut half = halves.clone();
    half.volume.albedo = None;
    half.medium.albedo = zeros.medium.albedo.map(|a| 0.5 * a);
    for backend in [Cpu, Gpu] {
        let (a, b) = (solve("albedo-zeros-grid", &zeros, backend), solve("albedo-zeros-medium", &absorber, backend));
        let err = relative_l2(&a.fluence_all(), &b.fluence_all());
        assert!(err <= 1e-6, "{backend:?}: a(v) = 0 against albedo 0: relative L2 {err}");
        assert_eq!(a.run.outcome.orders, 1, "{backend:?}: nothing scatters after order 0");
        let (a, b) = (solve("albedo-halves-grid", &halves, backend), solve("albedo-halves-medium", &half, backend));
        let err = relative_l2(&a.fluence_all(), &b.fluence_all());
        assert!(err <= 1e-6, "{backend:?}: a(v) = ½ against half the albedo: relative L2 {err}");
        for ch in 0..3 {
            let (x, y) = (a.run.outcome.energy.absorbed[ch], b.run.outcome.energy.absorbed[ch]);
            assert!((x / y - 1.0).abs() < 1e-6, "{backend:?} channel {ch}: absorbed {x} vs {y}");
        }
    }
    // The same with the source the rays gain stored in f16 (GPU): to f16's rounding.
    let (mut halves, mut half) = (halves, half);
    halves.solver.storage_precision = StoragePrecision::F16;
    half.solver.storage_precision = StoragePrecision::F16;
    let (a, b) = (solve("albedo-halves-f16-grid", &halves, Gpu), solve("albedo-halves-f16-medium", &half, Gpu));
    let err = relative_l2(&a.fluence_all(), &b.fluence_all());
    assert!(err <= 1e-3, "f16: a(v) = ½ against half the albedo: relative L2 {err}");
}

/// GPU = twin, the energy books close with σa per voxel, and a repeat is bitwise the same.
fn two_regions_on_both_backends(name: &str, sc: &Scene) {
    let gpu = solve(&format!("{name}-gpu"), sc, Gpu);
    let cpu = solve(&format!("{name}-cpu"), sc, Cpu);
    let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
    assert!(err <= 1e-4, "{name}: GPU against the twin: relative L2 {err}");
    let e = &gpu.run.outcome.energy;
    assert!(e.relative_imbalance < 1e-5, "{name}: {e:?}");
    let e = &cpu.run.outcome.energy;
    assert!(e.relative_imbalance < 1e-9, "{name}: {e:?}");
    let again = solve(&format!("{name}-again"), sc, Gpu);
    assert!(bits(&gpu) == bits(&again), "{name}: a repeat must give the same bits");
    assert!(source_bits(&gpu) == source_bits(&again), "{name}: a repeat must give the same source");
    // The bright region scatters more: its fluence is above the dark one's, mirror voxel for mirror
    // voxel away from the sun's entry differences (compare the two halves' totals).
    let [nx, ny, nz] = DIMS;
    let (mut bright, mut dark) = (0.0, 0.0);
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx / 2 {
                bright += gpu.fluence([x, y, z], 0);
                dark += gpu.fluence([nx - 1 - x, y, z], 0);
            }
        }
    }
    assert!(bright > 1.1 * dark, "{name}: bright half {bright} against dark half {dark}");
}

#[test]
fn two_regions_gpu_matches_the_twin_balances_and_repeats() {
    let (sc, _) = sphere_with_albedo("albedo-two", two_regions);
    two_regions_on_both_backends("albedo-two", &sc);
    // The scaling comes before the diffusion correction, whose fluxes conserve what they are given:
    // the books still close with it on.
    let mut corrected = sc.clone();
    corrected.solver.diffusion_correction = DiffusionCorrection::On;
    two_regions_on_both_backends("albedo-two-corrected", &corrected);
}

#[test]
fn a_point_light_over_two_regions_matches_the_twin_and_balances() {
    // The point light's first scattering is written into order 0's new source, which the commit
    // scales by a(v) like any scattered source; its uncollided fluence is absorbed with σa(v).
    let (mut sc, _) = sphere_with_albedo("albedo-point", two_regions);
    sc.lights =
        vec![lpm::scene::Light::Point { position: glam::DVec3::new(6.0, 7.5, 6.5), intensity: [40.0, 30.0, 20.0] }];
    two_regions_on_both_backends("albedo-point", &sc);
}

#[test]
fn a_periodic_slab_over_two_regions_matches_the_twin_and_balances() {
    // Periodic in x and y (what leaves one side enters the other, the carried light a ray state,
    // not a source): the scaling and the books are unchanged by it.
    let (mut sc, _) = sphere_with_albedo("albedo-periodic", two_regions);
    sc.volume.source = lpm::scene::VolumeSource::Procedural { shape: Shape::Box, seed: 7 };
    sc.boundary = lpm::scene::Boundary { periodic: [true, true, false], ..Default::default() };
    // The scheme a scene file may pair with periodic boundaries (the validator refuses "linear").
    sc.solver.spatial = Some(lpm::scene::SpatialScheme::Constant);
    two_regions_on_both_backends("albedo-periodic", &sc);
}

#[test]
fn emission_over_an_albedo_grid_uses_the_voxels_absorption() {
    // A uniform emission: with an albedo grid σa varies per voxel, so its source is written per
    // voxel (σa(v)·Le) rather than added by the kernels.
    let (mut sc, _) = sphere_with_albedo("albedo-emission", two_regions);
    sc.medium.emission = [1.0, 0.5, 2.0];
    // The swept source is what this holds (a traced emission reads the same σa(v)·Le).
    sc.solver.emission_uncollided = lpm::scene::EmissionUncollided::Swept;
    let gpu = solve("albedo-emission-gpu", &sc, Gpu);
    let cpu = solve("albedo-emission-cpu", &sc, Cpu);
    assert!(gpu.run.plan.emission_field && !gpu.run.plan.emission && !gpu.run.plan.emission_grid);
    let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
    assert!(err <= 1e-4, "relative L2 {err}");
    let e = &gpu.run.outcome.energy;
    assert!(e.relative_imbalance < 1e-5, "{e:?}");
    // The power emitted: Σ 4π·ρ·σt·(1 − albedo·a(v))·Le·h³ over the sphere's voxels.
    let store = &gpu.store;
    for ch in 0..3 {
        let mut expect = 0.0;
        for z in 0..DIMS[2] {
            for y in 0..DIMS[1] {
                for x in 0..DIMS[0] {
                    let rho = store.density_at([x, y, z]) as f64;
                    let a = two_regions([x, y, z]) as f64;
                    expect += rho * sc.medium.sigma_t[ch] * (1.0 - sc.medium.albedo[ch] * a) * sc.medium.emission[ch];
                }
            }
        }
        expect *= 4.0 * std::f64::consts::PI;
        let got = e.emitted[ch];
        assert!((got / expect - 1.0).abs() < 1e-5, "channel {ch}: emitted {got} vs {expect}");
    }
    // A grid of ones with the same emission: the uniform emission (through the other path).
    let (mut ones, _) = sphere_with_albedo("albedo-emission-ones", |_| 1.0);
    ones.medium.emission = sc.medium.emission;
    ones.solver.emission_uncollided = sc.solver.emission_uncollided;
    let mut uniform = ones.clone();
    uniform.volume.albedo = None;
    for backend in [Cpu, Gpu] {
        let (a, b) =
            (solve("albedo-emission-ones", &ones, backend), solve("albedo-emission-uniform", &uniform, backend));
        assert!(b.run.plan.emission && !b.run.plan.emission_field);
        let err = relative_l2(&a.fluence_all(), &b.fluence_all());
        assert!(err <= 1e-6, "{backend:?}: relative L2 {err}");
    }
}

#[test]
fn two_regions_agree_with_monte_carlo() {
    // Grey, g = 0, sky only: a box of σt 0.3 per voxel, one half of albedo 0.99, the other 0.2.
    let path = temp_dir("albedo-mc-input").join("albedo.raw");
    write_raw_field(&path, DIMS, two_regions);
    let mut sc = scene(Shape::Box, DIMS, [0.3; 3], [1.0; 3], vec![sky(1.0)]);
    sc.volume.albedo = Some(AlbedoGrid::Raw { path });
    sc.solver.directions_per_face = 4;
    sc.solver.tolerance = 1e-4;
    let lpm = solve("albedo-mc-lpm", &sc, Cpu);
    let opts = ReferenceOptions { photons: 600_000, seed: 5, ..ReferenceOptions::default() };
    let albedo = |v: [u32; 3]| two_regions(v);
    let mc = run_with_fields(&sc, &|_| 1.0, VoxelFields { emission: None, albedo: Some(&albedo) }, 1, &opts);
    let lpm_phi: Vec<f64> = lpm.fluence_all();
    let mc_phi: Vec<f64> = mc.fluence.iter().map(|&v| v as f64).collect();
    // Per half: the mean fluence and its Monte-Carlo standard error (batch estimate, per voxel).
    let nx = DIMS[0] as usize;
    let half = |i: usize| ((i % nx) >= nx / 2) as usize;
    let (mut sums, mut counts, mut var) = ([[0.0f64; 2]; 2], [0usize; 2], [0.0f64; 2]);
    for (i, (&l, &m)) in lpm_phi.iter().zip(&mc_phi).enumerate() {
        let h = half(i);
        sums[h][0] += l;
        sums[h][1] += m;
        counts[h] += 1;
        var[h] += (mc.std_error[i] as f64).powi(2);
    }
    for h in 0..2 {
        let (l, m) = (sums[h][0] / counts[h] as f64, sums[h][1] / counts[h] as f64);
        let se = var[h].sqrt() / counts[h] as f64;
        eprintln!(
            "albedo two regions, half {h}: LPM {l:.5e}, Monte Carlo {m:.5e} ± {se:.1e} ({:+.3} %)",
            100.0 * (l / m - 1.0)
        );
        // The LPM's own discretisation error at k = 4 is of a few per cent here, grid or no grid:
        // measured +0.03 % (bright half) and +2.1 % (dark half), and +2.0 to +2.1 % in both halves
        // of the same box with a uniform albedo of 0.2. The Monte-Carlo error bar is far below it.
        assert!((l / m - 1.0).abs() < 0.03 + 3.0 * se / m, "half {h}: LPM {l} vs Monte Carlo {m} ± {se}");
    }
    assert!(sums[0][1] > 1.2 * sums[1][1], "the bright half must be brighter in Monte Carlo too");
    let err = relative_l2(&lpm_phi, &mc_phi);
    eprintln!("albedo two regions: relative L2 against Monte Carlo {err:.3e}");
    assert!(err < 0.06, "relative L2 {err}");
}

#[test]
fn the_plan_keeps_the_field_only_when_present_and_skips_delta_m_with_it() {
    let (mut sc, _) = sphere_with_albedo("albedo-plan", two_regions);
    sc.medium.g = 0.8;
    let plan = lpm::solver::plan::Plan::new(&sc, 8, 0);
    assert!(plan.albedo_field && plan.summary().albedo_per_voxel);
    assert!(plan.reasons.iter().any(|r| r.starts_with("albedo per voxel")), "{:?}", plan.reasons);
    // δ-M would make σt depend on each voxel's albedo: "auto" keeps the phase function.
    assert!(plan.delta_m().is_none() && plan.medium.g == 0.8, "{:?}", plan.reasons);
    assert!(plan.reasons.iter().any(|r| r.contains("δ-M scaling does not combine with a per-voxel albedo")));
    sc.volume.albedo = None;
    let plan = lpm::solver::plan::Plan::new(&sc, 8, 0);
    assert!(!plan.albedo_field && !plan.summary().albedo_per_voxel && plan.delta_m().is_some());
    assert!(!plan.reasons.iter().any(|r| r.contains("albedo per voxel")));
}

#[test]
fn the_image_emits_with_the_voxels_absorption_and_lpm_render_keeps_the_grid() {
    let dir = temp_dir("albedo-image");
    let dims = [20, 22, 18];
    write_raw_field(&dir.join("ones.raw"), dims, |_| 1.0);
    write_raw_field(&dir.join("zeros.raw"), dims, |_| 0.0);
    write_raw_field(&dir.join("split.raw"), dims, |v| if v[0] < 10 { 1.0 } else { 0.0 });
    let text = |albedo: &str| {
        format!(
            "[volume]\nprocedural = \"box\"\ndims = [20, 22, 18]\n{albedo}\n[medium]\nsigma_t = 0.1\nalbedo = 0.8\n\
             emission = [1.0, 0.5, 0.25]\n[solver]\ndirections_per_face = 2\nmax_orders = 2\n\
             [camera]\nwidth = 40\nheight = 36\n"
        )
    };
    let image = |name: &str, albedo: &str| {
        image_of(write_scene_as(&dir, &format!("{name}.toml"), &text(albedo)), &dir.join(name))
    };
    let ones = image("ones", "albedo_raw = \"ones.raw\"");
    let uniform = image("uniform", "");
    let zeros = image("zeros", "albedo_raw = \"zeros.raw\"");
    let split = image("split", "albedo_raw = \"split.raw\"");
    // A grid of ones renders as no grid (the trilinear weights sum to 1).
    for (a, b) in ones.iter().zip(&uniform) {
        for c in 0..4 {
            assert!((a[c] - b[c]).abs() <= 1e-5 * b[c].abs().max(1e-3), "{a:?} vs {b:?}");
        }
    }
    // Albedo 0 absorbs σt, five times albedo 0.8's σa: the emission it renders is far brighter.
    let sum = |img: &[[f32; 4]]| img.iter().map(|p| p[0] as f64).sum::<f64>();
    assert!(sum(&zeros) > 2.0 * sum(&uniform), "{} vs {}", sum(&zeros), sum(&uniform));
    assert!(sum(&split) > 1.2 * sum(&uniform) && sum(&split) < 0.9 * sum(&zeros));
    // `lpm render` re-renders from the kept data, the albedo field included: the same pixels.
    assert!(
        rerender_transparent(&dir.join("split"), &dir.join("again.exr")) == split,
        "lpm render must reproduce the solve's image"
    );
    assert!(dir.join("split/render-data/albedo.field").exists());
    assert!(!dir.join("uniform/render-data/albedo.field").exists());
}

/// Writes `dir/smoke.vdb` with OpenVDB: density over [−3, 12]³ (index space) and an albedo grid
/// over a smaller box with varying values (background 0.5, so the voxels it leaves out read 0.5).
fn write_vdb(dir: &std::path::Path) -> PathBuf {
    let vdb = dir.join("smoke.vdb");
    let script = r#"
import sys
import pyopenvdb as openvdb
d = openvdb.FloatGrid(); d.name = "density"
a = openvdb.FloatGrid(0.5); a.name = "albedo"
for x in range(-3, 13):
    for y in range(-3, 13):
        for z in range(-3, 13):
            d.getAccessor().setValueOn((x, y, z), 1.0 + 0.01 * ((x + 2 * y + 3 * z) % 7))
for x in range(-1, 9):
    for y in range(0, 11):
        for z in range(2, 9):
            a.getAccessor().setValueOn((x, y, z), 0.1 * ((x + y + z) % 10) + 0.05)
openvdb.write(sys.argv[1], grids=[d, a])
"#;
    let out = std::process::Command::new("/usr/bin/python3")
        .args(["-c", script, vdb.to_str().expect("utf-8 path")])
        .output()
        .expect("run /usr/bin/python3 (install python3-openvdb: tools/setup.sh)");
    assert!(out.status.success(), "python3-openvdb: {}", String::from_utf8_lossy(&out.stderr));
    vdb
}

/// The albedo factor `write_vdb` wrote at voxel v of the imported volume (index −3 is voxel 0).
fn vdb_albedo(v: [u32; 3]) -> f32 {
    let c = v.map(|x| x as i32 - 3);
    if (-1..9).contains(&c[0]) && (0..11).contains(&c[1]) && (2..9).contains(&c[2]) {
        // In f64 and rounded once to f32, as Python computes and OpenVDB stores it.
        (0.1 * ((c[0] + c[1] + c[2]).rem_euclid(10)) as f64 + 0.05) as f32
    } else {
        0.5
    }
}

#[test]
fn a_vdb_albedo_grid_is_read_voxel_for_voxel_and_solves_like_raw() {
    let dir = temp_dir("albedo-vdb");
    write_vdb(&dir);
    let text = |albedo: &str| {
        format!(
            "[volume]\nvdb = \"smoke.vdb\"\n{albedo}\n[medium]\nsigma_t = 0.5\nalbedo = [0.9, 0.8, 0.6]\n\
             [[lights]]\nkind = \"sky\"\nradiance = 1.0\n\
             [solver]\ndirections_per_face = 2\nmax_orders = 4\ntolerance = 1e-30\n"
        )
    };
    let a = Scene::load(&write_scene_as(&dir, "vdb.toml", &text("albedo_grid = \"albedo\""))).expect("vdb scene");
    assert_eq!(a.volume.albedo, Some(AlbedoGrid::Vdb { grid: "albedo".into() }));
    write_raw_field(&dir.join("albedo.raw"), [16; 3], vdb_albedo);
    let b = Scene::load(&write_scene_as(&dir, "raw.toml", &text("albedo_raw = \"albedo.raw\""))).expect("raw scene");
    let (sa, sb) = (solve("albedo-vdb-a", &a, Gpu), solve("albedo-vdb-b", &b, Gpu));
    // The store's albedo field holds exactly what OpenVDB wrote (f32 values, compared as bits).
    for store in [&sa.store, &sb.store] {
        let field = lpm::store::albedo::open_albedo(store).expect("albedo field");
        for z in 0..16 {
            for y in 0..16 {
                for x in 0..16 {
                    let (got, want) = (field.value([x, y, z], 0), vdb_albedo([x, y, z]));
                    assert_eq!(got.to_bits(), want.to_bits(), "voxel ({x}, {y}, {z}): {got} vs {want}");
                }
            }
        }
    }
    assert!(bits(&sa) == bits(&sb), "the VDB albedo grid must solve like the same values given raw");
    // The same file converted to NanoVDB by NanoVDB's own converter (libnanovdb-tools, installed
    // by tools/setup.sh), named by `nvdb`: its albedo grid solves to the same bits.
    let out = std::process::Command::new("nanovdb_convert")
        .arg("-f")
        .arg(dir.join("smoke.vdb"))
        .arg(dir.join("smoke.nvdb"))
        .output()
        .expect("run nanovdb_convert (tools/setup.sh installs it)");
    assert!(out.status.success(), "nanovdb_convert: {}", String::from_utf8_lossy(&out.stderr));
    let nano = text("albedo_grid = \"albedo\"").replace("vdb = \"smoke.vdb\"", "nvdb = \"smoke.nvdb\"");
    let c = Scene::load(&write_scene_as(&dir, "nvdb.toml", &nano)).expect("nvdb scene");
    let sc = solve("albedo-vdb-c", &c, Gpu);
    assert!(bits(&sc) == bits(&sa), "the NanoVDB albedo grid must solve like the OpenVDB one");
    // The Monte-Carlo reference job reads the grid from the VDB file itself: the same photons
    // (same seed, one thread) give the same fluence as from the raw file.
    let reference = |scene: &str, out: &str| {
        let job = lpm::reference::job::ReferenceJob {
            scene: dir.join(scene),
            out: dir.join(out),
            photons: 4000,
            seed: 9,
            threads: 1,
            image_samples_per_pixel: 0,
            image_orders: lpm::reference::Orders::ALL,
        };
        lpm::reference::job::run(&job).expect("reference job with an albedo grid");
        std::fs::read(dir.join(out).join("fluence.raw")).expect("reference fluence")
    };
    assert!(reference("vdb.toml", "mc-vdb") == reference("raw.toml", "mc-raw"), "the reference reads both alike");
}

#[test]
fn bad_albedo_input_is_refused_with_its_name() {
    let dir = temp_dir("albedo-bad");
    let at = [1, 2, 3];
    for (name, value) in [("high.raw", 1.5f32), ("negative.raw", -0.25), ("nan.raw", f32::NAN)] {
        write_raw_field(&dir.join(name), [4, 4, 4], |v| if v == at { value } else { 0.5 });
    }
    std::fs::write(dir.join("short.raw"), [0u8; 12]).expect("write");
    write_vdb(&dir);
    let base = "[volume]\nprocedural = \"box\"\ndims = [4, 4, 4]\n";
    let tail = "[medium]\nsigma_t = 1.0\nalbedo = 0.5\n";
    // Scene errors naming the key: both keys, a grid for a non-VDB volume, a file of the wrong
    // size, a missing file, δ-M asked for with an albedo grid.
    for (keys, more, expect) in [
        ("albedo_raw = \"high.raw\"\nalbedo_grid = \"albedo\"\n", "", "volume.albedo_grid"),
        ("albedo_grid = \"albedo\"\n", "", "only applies to a `vdb` volume"),
        ("albedo_raw = \"short.raw\"\n", "", "volume.albedo_raw"),
        ("albedo_raw = \"missing.raw\"\n", "", "volume.albedo_raw"),
        ("albedo_raw = \"high.raw\"\n", "g = 0.8\n[solver]\nforward_peak = \"delta-m\"\n", "solver.forward_peak"),
    ] {
        let path = write_scene(&dir, &format!("{base}{keys}{tail}{more}"));
        let err = Scene::load(&path).expect_err("must be refused").to_string();
        assert!(err.contains(expect), "{keys}: {err}");
    }
    // A grid the VDB file does not have: named with the grids it does have.
    let path = write_scene(
        &dir,
        "[volume]\nvdb = \"smoke.vdb\"\nalbedo_grid = \"albedoo\"\n[medium]\nsigma_t = 1.0\nalbedo = 0.5\n",
    );
    let err = Scene::load(&path).expect_err("a missing grid").to_string();
    assert!(err.contains("volume.albedo_grid") && err.contains("albedoo") && err.contains("\"albedo\""), "{err}");
    // Values above 1, negative or NaN: the import names the file, the key, the voxel and "albedo".
    for name in ["high.raw", "negative.raw", "nan.raw"] {
        let path = write_scene(&dir, &format!("{base}albedo_raw = \"{name}\"\n{tail}"));
        let sc = Scene::load(&path).expect("valid scene");
        let err = lpm::solver::build_store(&sc, &dir.join(format!("store-{name}"))).err().expect("refused").to_string();
        assert!(
            err.contains(name)
                && err.contains("(1, 2, 3)")
                && err.contains("albedo")
                && err.contains("volume.albedo_raw"),
            "{err}"
        );
    }
    // The CLI reports it in plain words and exits non-zero.
    let path = write_scene(&dir, &format!("{base}albedo_raw = \"high.raw\"\n{tail}"));
    let o = lpm_command(&["solve", path.to_str().expect("utf-8"), "--out", dir.join("out").to_str().expect("utf-8")])
        .output()
        .expect("run lpm");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && stderr.contains("albedo factor 1.5"), "{stderr}");
}

#[test]
fn a_cancelled_solve_with_an_albedo_grid_resumes_to_the_same_bits() {
    let (mut sc, _) = sphere_with_albedo("albedo-resume", two_regions);
    sc.solver.diffusion_correction = DiffusionCorrection::On;
    sc.solver.max_orders = 5;
    let run = |store: &lpm::store::BrickStore, resume: bool, cancel_after: Option<u32>| {
        let cancel = lpm::solver::cancel::CancelFlag::new();
        let options = lpm::solver::gpu::GpuOptions {
            checkpoints: true,
            cancel: Some(cancel),
            ..lpm::solver::gpu::GpuOptions::default()
        };
        lpm::solver::solve_with(&sc, store, BackendKind::Gpu, validated(), options, resume, |order, _| {
            if cancel_after.is_some_and(|n| order >= n) {
                cancel.raise();
            }
        })
    };
    let whole_dir = temp_dir("albedo-resume-whole");
    let whole_store = lpm::solver::build_store(&sc, &whole_dir.join("store")).expect("store");
    let (_, whole) = run(&whole_store, false, None).expect("uninterrupted solve");
    let cut_dir = temp_dir("albedo-resume-cut");
    let cut_store = lpm::solver::build_store(&sc, &cut_dir.join("store")).expect("store");
    let err = run(&cut_store, false, Some(1)).err().expect("the solve is cancelled");
    assert!(matches!(err, lpm::solver::SolveError::Cancelled { resumable: true }), "{err}");
    let (resumed, cut) = run(&cut_store, true, None).expect("resumed solve");
    assert_eq!(resumed.outcome.orders, 5);
    assert!(resumed.outcome.history.len() == 5);
    let f = |fields: &lpm::solver::fields::StoreFields| {
        (
            fields.fluence_total.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            fields.source_total.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        )
    };
    assert!(f(&whole) == f(&cut), "a resumed solve must end with the uninterrupted one's bits");
}

#[test]
fn a_warm_start_with_an_albedo_grid_converges_to_the_cold_answer() {
    // The guess (the previous frame's source) is already scaled by a(v); order 0's commit scales
    // b + K·x0 before taking x0 back off, so the residual is the scaled one.
    let dir = temp_dir("albedo-warm");
    write_raw_field(&dir.join("albedo.raw"), DIMS, two_regions);
    let tolerance = 1e-3;
    let text = |sky: f64, tolerance: f64| {
        format!(
            "[volume]\nprocedural = \"sphere\"\ndims = [{}, {}, {}]\nalbedo_raw = \"albedo.raw\"\n\
             [medium]\nsigma_t = 0.8\nalbedo = 0.95\n[[lights]]\nkind = \"sky\"\nradiance = {sky}\n\
             [[lights]]\nkind = \"sun\"\ndirection = [0.3, -0.5, 1.0]\nirradiance = 2.0\n\
             [solver]\ndirections_per_face = 3\nmax_orders = 400\ntolerance = {tolerance}\n\
             acceleration = \"off\"\n",
            DIMS[0], DIMS[1], DIMS[2]
        )
    };
    let solve_job = |name: &str, sky: f64, tolerance: f64, warm: Option<&str>| {
        let scene = write_scene_as(&dir, &format!("{name}.toml"), &text(sky, tolerance));
        let job = lpm::job::SolveJob {
            no_image: true,
            warm_start: warm.map(|w| dir.join(w)),
            ..lpm::job::SolveJob::new(scene, dir.join(name))
        };
        lpm::job::run(&job, |_, _| {}).expect("solve");
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join(name).join("report.json")).expect("report")).expect("json");
        let fluence: Vec<f32> = std::fs::read(dir.join(name).join("fluence.raw"))
            .expect("fluence")
            .chunks(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        (report, fluence)
    };
    solve_job("previous", 0.4, tolerance, None);
    let (warm_report, warm) = solve_job("warm", 0.5, tolerance, Some("previous"));
    let (cold_report, _) = solve_job("cold", 0.5, tolerance, None);
    let (_, answer) = solve_job("answer", 0.5, 1e-7, None);
    let error = warm
        .iter()
        .zip(&answer)
        .filter(|(_, b)| b.is_finite() && **b > 0.0)
        .map(|(&a, &b)| ((a as f64 - b as f64) / b as f64).abs())
        .fold(0.0, f64::max);
    let (warm_orders, cold_orders) = (warm_report["orders"].as_u64().unwrap(), cold_report["orders"].as_u64().unwrap());
    eprintln!("albedo grid, warm start: {warm_orders} orders (cold {cold_orders}), per-voxel error {error:.3e}");
    assert!(warm_report["warm_start"].is_string(), "{warm_report}");
    assert!(error <= 1.5 * tolerance, "the warm start is off the answer by {error:.3e}");
    assert!(warm_orders < cold_orders, "the warm start saved no order: {warm_orders} vs {cold_orders}");
    let imbalance = warm_report["energy"]["relative_imbalance"].as_f64().unwrap();
    assert!(imbalance < 1e-4, "warm start energy imbalance {imbalance:.3e}");
}

#[test]
fn a_killed_solve_with_an_albedo_grid_resumes_to_the_same_bits() {
    // The kill test of resume.rs with an albedo grid: the checkpoints hold the scaled source.
    if !cfg!(feature = "test-hooks") {
        panic!(
            "this kill test needs lpm's test hook: run it with `cargo test --features test-hooks` (tools/test.sh does)"
        );
    }
    let dir = temp_dir("albedo-kill");
    let dims = [34, 30, 38];
    write_raw_field(&dir.join("albedo.raw"), dims, |v| if v[0] < 17 { 0.99 } else { 0.3 });
    let text = killable_cloud_scene(dims, 5).replacen("[volume]\n", "[volume]\nalbedo_raw = \"albedo.raw\"\n", 1);
    let scene = write_scene_as(&dir, "scene.toml", &text);
    let (s, whole, cut) = (scene.to_str().expect("utf-8"), dir.join("whole"), dir.join("cut"));
    let lpm = |out: &std::path::Path, extra: &[&str], abort_at: Option<u32>| {
        let mut args = vec!["solve", s, "--out", out.to_str().expect("utf-8"), "--no-image"];
        args.extend_from_slice(extra);
        let mut cmd = lpm_command(&args);
        if let Some(n) = abort_at {
            cmd.env("LPM_TEST_ABORT_AT_SLICE", n.to_string());
        }
        cmd.output().expect("run lpm")
    };
    let o = lpm(&whole, &[], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // A slice of order 2 (order 0 computes slices 1–18, every later order 12).
    let o = lpm(&cut, &[], Some(36));
    assert!(!o.status.success(), "the solve should have been killed");
    let checkpoint: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(cut.join(".lpm-work/checkpoint.json")).expect("checkpoint"))
            .expect("json");
    let done = checkpoint["state"]["orders_done"].as_u64().expect("orders_done");
    assert!((1..5).contains(&done), "killed after {done} orders");
    let o = lpm(&cut, &["--resume"], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in ["fluence.raw", "source.raw"] {
        let (a, b) = (std::fs::read(whole.join(f)).expect("whole"), std::fs::read(cut.join(f)).expect("cut"));
        assert!(a == b, "{f} differs after resume");
    }
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(cut.join("report.json")).expect("report")).expect("json");
    assert_eq!(report["plan"]["albedo_per_voxel"], true);
}
