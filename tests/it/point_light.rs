//! Point lights (`[[lights]] kind = "point"`): the exact Beer–Lambert falloff of their uncollided
//! light on both backends, the energy books and GPU = twin with scattering, the Monte-Carlo
//! reference, a light in empty space beside a sparse volume, resume, the image, and bad input.
use crate::common::*;
use glam::DVec3;
use lpm::reference::{run, ReferenceOptions};
use lpm::scene::{ForwardPeak, Light, Scene, Shape};
use lpm::solver::BackendKind::{Cpu, Gpu};

fn point(position: [f64; 3], intensity: [f64; 3]) -> Light {
    Light::Point { position: DVec3::from_array(position), intensity }
}

/// Length of the segment from `a` to `b` inside the box [lo, hi] (slab clipping).
fn inside_length(a: DVec3, b: DVec3, lo: DVec3, hi: DVec3) -> f64 {
    let d = b - a;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for k in 0..3 {
        if d[k] == 0.0 {
            if a[k] < lo[k] || a[k] > hi[k] {
                return 0.0;
            }
            continue;
        }
        let (ta, tb) = ((lo[k] - a[k]) / d[k], (hi[k] - a[k]) / d[k]);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    (t1 - t0).max(0.0) * d.length()
}

#[test]
fn a_pure_absorber_shows_the_exact_beer_lambert_falloff() {
    let dims = [20, 18, 22];
    let (h, sigma, intensity) = (0.5, 0.3, 7.0);
    let origin = DVec3::new(1.0, -2.0, 0.5);
    let lo = origin;
    let hi = origin + DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) * h;
    // World positions: one outside the volume (beyond its -x face, off-axis), one inside.
    for (name, light) in [("outside", [-1.7, 3.1, 4.4]), ("inside", [5.3, 2.2, 6.9])] {
        let mut sc = scene(Shape::Box, dims, [sigma; 3], [0.0; 3], vec![]);
        sc.volume.voxel_size = h;
        sc.volume.origin = origin;
        // The validator moves the light into the volume's frame; here the scene is built by hand.
        sc.lights = vec![point((DVec3::from_array(light) - origin).to_array(), [intensity; 3])];
        let gpu = solve(&format!("point-absorber-{name}-gpu"), &sc, Gpu);
        let cpu = solve(&format!("point-absorber-{name}-cpu"), &sc, Cpu);
        assert_eq!(gpu.run.plan.point_lights.len(), 1);
        assert!(gpu.run.plan.reasons.iter().any(|r| r.contains("1 point light(s)")), "{:?}", gpu.run.plan.reasons);
        let p = DVec3::from_array(light);
        let (mut checked, mut worst) = (0, 0.0f64);
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let centre = origin + (DVec3::new(x as f64, y as f64, z as f64) + 0.5) * h;
                    let r = (centre - p).length();
                    // Nearer voxels take the voxel's mean (`solver::point::NEAR_VOXELS`).
                    if r < lpm::solver::point::NEAR_VOXELS * h {
                        continue;
                    }
                    let expected = intensity * (-sigma * inside_length(p, centre, lo, hi)).exp() / (r * r);
                    for (backend, s) in [("gpu", &gpu), ("cpu", &cpu)] {
                        let got = s.fluence([x, y, z], 0);
                        let rel = (got - expected).abs() / expected;
                        assert!(rel < 1e-5, "{name} {backend} voxel {:?}: {got} vs {expected}", [x, y, z]);
                        worst = worst.max(rel);
                    }
                    checked += 1;
                }
            }
        }
        assert!(checked > 7000, "{checked}");
        eprintln!("point light {name}: worst relative error {worst:.2e} over {checked} voxels");
        let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
        assert!(err <= 1e-6, "{name}: GPU vs twin {err}");
        // Nothing scatters: what the light gives the medium is all absorbed.
        let e = gpu.run.outcome.energy;
        assert!(e.point_lights[0] > 0.0 && e.boundary_in[0] == 0.0, "{e:?}");
        assert!(e.relative_imbalance < 1e-5, "{e:?}");
    }
}

/// A sphere of albedo 0.9 lit by a light inside it and one outside (grey, isotropic).
fn lit_sphere() -> Scene {
    let mut sc = scene(
        Shape::Sphere,
        [20, 20, 20],
        [0.4; 3],
        [0.9; 3],
        vec![point([7.3, 9.1, 12.6], [3.0; 3]), point([-6.0, 24.0, 10.0], [40.0; 3])],
    );
    sc.solver.directions_per_face = 3;
    sc.solver.tolerance = 1e-4;
    sc.solver.max_orders = 60;
    sc
}

#[test]
fn with_scattering_the_books_close_and_the_backends_agree_bitwise_run_to_run() {
    let mut sc = lit_sphere();
    // The books close at any order count (the rest is counted as unpropagated).
    sc.solver.max_orders = 12;
    let gpu = solve("point-scatter-gpu", &sc, Gpu);
    let again = solve("point-scatter-gpu-again", &sc, Gpu);
    let cpu = solve("point-scatter-cpu", &sc, Cpu);
    let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
    assert!(err <= 1e-4, "GPU vs twin: relative L2 {err}");
    let bits = |s: &Solved| s.fluence_all().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert!(bits(&gpu) == bits(&again), "two GPU solves must give the same bits");
    for (backend, s) in [("gpu", &gpu), ("cpu", &cpu)] {
        let e = s.run.outcome.energy;
        assert!(e.point_lights[0] > 0.0 && e.boundary_in[0] == 0.0, "{backend}: {e:?}");
        assert!(e.relative_imbalance < 1e-5, "{backend}: {e:?}");
        // The per-face tallies see what leaves as rays only.
        assert!(e.boundary_out[0] > 0.0 && e.boundary_out[0] < e.point_lights[0], "{backend}: {e:?}");
    }
    // The first scattering is in the summed source the renderer integrates.
    let peak = gpu.fields.source_total.value([7, 9, 12], 0);
    assert!(peak > 0.0 && peak.is_finite(), "{peak}");
}

#[test]
fn an_anisotropic_coloured_medium_keeps_the_books_and_the_twin() {
    let mut sc = scene(
        Shape::Sphere,
        [16, 17, 15],
        [0.5, 0.4, 0.3],
        [0.8, 0.7, 0.9],
        vec![point([8.2, 3.0, 7.7], [2.0, 1.0, 0.5]), point([40.0, 8.0, 7.0], [30.0, 30.0, 30.0])],
    );
    sc.medium.g = 0.6;
    sc.solver.forward_peak = ForwardPeak::Keep;
    sc.solver.directions_per_face = 3;
    sc.solver.tolerance = 1e-4;
    sc.solver.max_orders = 8;
    let gpu = solve("point-aniso-gpu", &sc, Gpu);
    let cpu = solve("point-aniso-cpu", &sc, Cpu);
    assert!(gpu.run.plan.storage.len() > 1 && gpu.run.plan.channels == 3);
    let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
    assert!(err <= 1e-4, "GPU vs twin: relative L2 {err}");
    for (backend, s) in [("gpu", &gpu), ("cpu", &cpu)] {
        let e = s.run.outcome.energy;
        assert!(e.point_lights.iter().all(|&p| p > 0.0), "{backend}: {e:?}");
        assert!(e.relative_imbalance < 1e-5, "{backend}: {e:?}");
    }
    // Forward scattering: above the first light (it sits at low y, its light travels +y; the
    // second one's travels −x) the source is stronger in the storage directions along +y.
    let plan = &gpu.run.plan;
    let v = [8, 8, 7];
    let c = plan.channels as usize;
    let along = |d: usize| plan.storage.omega[d].y;
    let (mut fwd, mut back) = (0.0, 0.0);
    for d in 0..plan.storage.len() {
        let j = gpu.fields.source_total.value(v, (d * c) as u32) as f64;
        if along(d) > 0.5 {
            fwd += j;
        } else if along(d) < -0.5 {
            back += j;
        }
    }
    assert!(fwd > 1.2 * back, "forward {fwd} vs backward {back}");
}

#[test]
fn the_monte_carlo_reference_agrees() {
    // Grey and isotropic; one light inside, one outside.
    let mut sc = scene(
        Shape::Box,
        [16, 16, 16],
        [0.25; 3],
        [0.9; 3],
        vec![point([5.2, 8.3, 9.1], [2.0; 3]), point([8.0, 8.0, -6.0], [30.0; 3])],
    );
    sc.solver.directions_per_face = 4;
    sc.solver.tolerance = 1e-5;
    sc.solver.max_orders = 200;
    let lpm = solve("point-mc-lpm", &sc, Cpu);
    let opts = ReferenceOptions { photons: 1_000_000, seed: 5, ..ReferenceOptions::default() };
    let mc = run(&sc, &|_| 1.0, 1, &opts);
    let a = lpm.fluence_all();
    let b: Vec<f64> = mc.fluence.iter().map(|&v| v as f64).collect();
    let se: Vec<f64> = mc.std_error.iter().map(|&v| v as f64).collect();
    let (sa, sb) = (a.iter().sum::<f64>(), b.iter().sum::<f64>());
    let l2 = relative_l2(&a, &b);
    // Voxels outside the error bars by more than 4σ plus a 5 % model error.
    let outliers = (0..a.len()).filter(|&i| (a[i] - b[i]).abs() > 4.0 * se[i] + 0.05 * b[i]).count();
    eprintln!(
        "point lights vs Monte Carlo: total {sa:.5e} vs {sb:.5e}, relative L2 {l2:.3e}, {outliers} of {} voxels \
         outside 4σ + 5 %",
        a.len()
    );
    // Measured −1.6 % and 5.0e-2 (1M photons, k = 4): the discrete ordinates' own error in the
    // scattered light, plus the centre values of voxels 4 or more voxels from a light, which lie
    // below the voxel's mean by about (h/r)²/4 (the mean is what Monte Carlo tallies).
    assert!((sa / sb - 1.0).abs() < 0.025, "total fluence {sa} vs Monte Carlo {sb}");
    assert!(l2 < 0.07, "relative L2 {l2}");
    assert!(outliers * 50 < a.len(), "{outliers} voxels outside the error bars");
}

#[test]
fn a_light_in_empty_space_beside_a_sparse_volume() {
    // One occupied brick of three along x; the light sits in an empty brick, another outside.
    let dims = [48, 16, 16];
    let density = |v: [u32; 3]| if (32..48).contains(&v[0]) { 1.0 } else { 0.0 };
    let sigma = 0.2;
    let lights = vec![point([8.0, 8.5, 7.5], [5.0; 3]), point([60.0, -4.0, 9.0], [9.0; 3])];
    let absorber = raw_scene("point-sparse-absorber", dims, sigma, 0.0, lights.clone(), density);
    let gpu = solve("point-sparse-gpu", &absorber, Gpu);
    let cpu = solve("point-sparse-cpu", &absorber, Cpu);
    assert_eq!(gpu.run.plan.bricks_empty, 2);
    let lo = DVec3::new(32.0, 0.0, 0.0);
    let hi = DVec3::new(48.0, 16.0, 16.0);
    for z in 0..16 {
        for y in 0..16 {
            for x in 32..48 {
                let c = DVec3::new(x as f64, y as f64, z as f64) + 0.5;
                let mut expected = 0.0;
                for l in &lights {
                    let Light::Point { position, intensity } = l else { unreachable!() };
                    let r = (c - *position).length();
                    expected += intensity[0] * (-sigma * inside_length(*position, c, lo, hi)).exp() / (r * r);
                }
                for s in [&gpu, &cpu] {
                    let got = s.fluence([x, y, z], 0);
                    assert!((got / expected - 1.0).abs() < 1e-5, "voxel {:?}: {got} vs {expected}", [x, y, z]);
                }
            }
        }
    }
    // With scattering: the books close and the backends agree.
    let scattering = raw_scene("point-sparse-scatter", dims, sigma, 0.7, lights, density);
    let gpu = solve("point-sparse-scatter-gpu", &scattering, Gpu);
    let cpu = solve("point-sparse-scatter-cpu", &scattering, Cpu);
    assert!(relative_l2(&gpu.fluence_all(), &cpu.fluence_all()) <= 1e-4);
    assert!(gpu.run.outcome.energy.relative_imbalance < 1e-5, "{:?}", gpu.run.outcome.energy);
}

#[test]
fn a_resumed_solve_does_not_add_the_light_twice() {
    let sc = lit_sphere();
    let dir = temp_dir("point-resume");
    let store = lpm::solver::build_store(&sc, &dir.join("store")).expect("store");
    let gpu_options = lpm::solver::gpu::GpuOptions { checkpoints: true, ..Default::default() };
    let solve = |resume: bool| {
        lpm::solver::solve_with(&sc, &store, Gpu, validated(), gpu_options, resume, |_, _| {}).expect("solve")
    };
    let (first, fields) = solve(false);
    let fluence: Vec<u32> = fields.fluence_total.as_slice().iter().map(|v| v.to_bits()).collect();
    drop(fields);
    // The checkpoint of the last order is still in the store: resuming finds the solve done.
    let (resumed, fields) = solve(true);
    let again: Vec<u32> = fields.fluence_total.as_slice().iter().map(|v| v.to_bits()).collect();
    assert!(fluence == again, "a resumed solve must leave the fluence as it was");
    let (a, b) = (first.outcome.energy, resumed.outcome.energy);
    assert_eq!(a.point_lights, b.point_lights);
    assert!(b.relative_imbalance < 1e-5, "{b:?}");
}

#[test]
fn the_image_shows_the_scattered_light_and_no_light_itself() {
    let dir = temp_dir("point-image");
    let text = "[volume]\nprocedural = \"sphere\"\ndims = [20, 20, 20]\norigin = [-10.0, -10.0, -10.0]\n\
                [medium]\nsigma_t = 0.3\nalbedo = 0.9\n\
                [[lights]]\nkind = \"point\"\nposition = [0.0, 0.0, 0.0]\nintensity = [4.0, 2.0, 1.0]\n\
                [solver]\ndirections_per_face = 2\nmax_orders = 6\n\
                [camera]\nwidth = 32\nheight = 32\n";
    let pixels = image_of(write_scene(&dir, text), &dir.join("out"));
    assert!(pixels.iter().all(|p| p.iter().all(|c| c.is_finite() && *c >= 0.0)));
    let brightest = pixels.iter().fold([0f32; 4], |m, p| if p[0] > m[0] { *p } else { m });
    // The glow follows the light's colour, and is brightest in the middle of the image.
    assert!(brightest[0] > 0.0 && brightest[1] < brightest[0] && brightest[2] < brightest[1], "{brightest:?}");
    let centre = pixels[16 * 32 + 16][0];
    let corner = pixels[0][0];
    assert!(centre > 10.0 * corner, "centre {centre} vs corner {corner}");
}

#[test]
fn bad_point_light_input_is_refused_with_its_name() {
    let dir = temp_dir("point-bad");
    let base = "[volume]\nprocedural = \"box\"\ndims = [4, 4, 4]\n[medium]\nsigma_t = 1.0\nalbedo = 0.5\n[[lights]]\n";
    for (light, key, words) in [
        ("kind = \"point\"\nposition = [nan, 0, 0]\nintensity = 1.0\n", "lights[0].position[0]", "finite"),
        ("kind = \"point\"\nposition = [1, 2, 3]\nintensity = -1.0\n", "lights[0].intensity", "≥ 0"),
        ("kind = \"point\"\nposition = [1, 2, 3]\nintensity = [1.0, -2.0, 1.0]\n", "lights[0].intensity[1]", "≥ 0"),
        ("kind = \"point\"\nposition = [1, 2, 3]\nintensity = 1e300\n", "lights[0].intensity", "≤"),
        ("kind = \"point\"\nposition = [1, 2, 3]\nintensity = inf\n", "lights[0].intensity", "finite"),
        ("kind = \"point\"\nposition = [1e30, 2, 3]\nintensity = 1.0\n", "lights[0].position[0]", "within"),
        ("kind = \"point\"\nintensity = 1.0\n", "lights[0].position", "required"),
        ("kind = \"point\"\nposition = [1, 2, 3]\n", "lights[0].intensity", "required"),
        ("kind = \"point\"\nposition = [1, 2]\nintensity = 1.0\n", "position", "3"),
        (
            "kind = \"point\"\nposition = [1, 2, 3]\nintensity = 1.0\ndirection = [0, 0, 1]\n",
            "lights[0].direction",
            "point",
        ),
        (
            "kind = \"sun\"\nposition = [1, 2, 3]\ndirection = [0, 0, 1]\nirradiance = 1.0\n",
            "lights[0].position",
            "sun",
        ),
    ] {
        let path = write_scene(&dir, &format!("{base}{light}"));
        let err = Scene::load(&path).expect_err("must be refused").to_string();
        assert!(err.contains(key) && err.contains(words), "{light}: {err}");
        assert!(err.contains("scene.toml"), "{err}");
    }
    // A small voxel makes a modest intensity absurdly bright one voxel away.
    let tiny = "[volume]\nprocedural = \"box\"\ndims = [4, 4, 4]\nvoxel_size = 1e-9\n[medium]\nsigma_t = 1.0\n\
                albedo = 0.5\n[[lights]]\nkind = \"point\"\nposition = [0, 0, 0]\nintensity = 100.0\n";
    let err = Scene::load(&write_scene(&dir, tiny)).expect_err("must be refused").to_string();
    assert!(err.contains("lights[0].intensity") && err.contains("one voxel"), "{err}");
    // A good one loads, with its position moved into the volume's frame.
    let good = "[volume]\nprocedural = \"box\"\ndims = [4, 4, 4]\norigin = [10, 0, -1]\n[medium]\nsigma_t = 1.0\n\
                albedo = 0.5\n[[lights]]\nkind = \"point\"\nposition = [12, 1, 1]\nintensity = [1, 2, 3]\n";
    let sc = Scene::load(&write_scene(&dir, good)).expect("valid");
    assert_eq!(sc.lights, vec![point([2.0, 1.0, 2.0], [1.0, 2.0, 3.0])]);
    assert!(!sc.is_grey());
}

#[test]
fn a_warm_start_converges_to_the_cold_answer() {
    // A frame solved again from its own solution (the guess is the answer to the tolerance): the
    // point lights' order-0 contributions must enter once, as a sun's do.
    let dir = temp_dir("point-warm");
    let text = "[volume]\nprocedural = \"sphere\"\ndims = [18, 18, 18]\n[medium]\nsigma_t = 0.5\nalbedo = 0.9\n\
                [[lights]]\nkind = \"point\"\nposition = [6.5, 8.0, 9.5]\nintensity = 3.0\n\
                [[lights]]\nkind = \"point\"\nposition = [9.0, -8.0, 9.0]\nintensity = 40.0\n\
                [solver]\ndirections_per_face = 2\nmax_orders = 200\ntolerance = 1e-4\n";
    let scene = write_scene(&dir, text);
    let job = |out: &str, warm: Option<std::path::PathBuf>| {
        let job = lpm::job::SolveJob {
            vk: validated(),
            no_image: true,
            warm_start: warm,
            ..lpm::job::SolveJob::new(scene.clone(), dir.join(out))
        };
        lpm::job::run(&job, |_, _| {}).expect("solve");
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join(out).join("report.json")).expect("report")).expect("json");
        let fluence: Vec<f32> = std::fs::read(dir.join(out).join("fluence.raw"))
            .expect("fluence")
            .chunks(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        (report, fluence)
    };
    let (cold, a) = job("cold", None);
    let (warm, b) = job("warm", Some(dir.join("cold")));
    let orders = |r: &serde_json::Value| r["orders"].as_u64().expect("orders");
    assert!(orders(&warm) < orders(&cold), "warm {} vs cold {} orders", orders(&warm), orders(&cold));
    let worst = a
        .iter()
        .zip(&b)
        .filter(|(a, _)| a.is_finite() && **a > 0.0)
        .map(|(&a, &b)| ((b as f64 - a as f64) / a as f64).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-3, "warm vs cold: largest relative difference {worst:.3e}");
    let imbalance = warm["energy"]["relative_imbalance"].as_f64().expect("imbalance");
    assert!(imbalance < 1e-4, "warm start energy imbalance {imbalance:.3e} ({})", warm["energy"]);
}

/// In a vacuum (σt = 0) a point light gives the medium no power, yet its uncollided fluence I/r²
/// is order 0's (issue 57: the GPU's resident order 0 cleared it and returned zeros everywhere).
/// Every voxel is over 5 voxels from the light, where the solver takes the voxel's centre value.
#[test]
fn a_point_light_in_vacuum_gives_the_inverse_square_fluence_on_both_backends() {
    let (dims, intensity, p) = ([8, 8, 8], 5.0, DVec3::new(4.0, 4.0, -5.0));
    let sc = scene(Shape::Box, dims, [0.0; 3], [0.9; 3], vec![point(p.to_array(), [intensity; 3])]);
    let gpu = solve("point-vacuum-gpu", &sc, Gpu);
    let cpu = solve("point-vacuum-cpu", &sc, Cpu);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let r = (DVec3::new(x as f64, y as f64, z as f64) + 0.5 - p).length();
                let expected = intensity / (r * r);
                for (backend, s) in [("gpu", &gpu), ("cpu", &cpu)] {
                    let got = s.fluence([x, y, z], 0);
                    assert!((got - expected).abs() < 1e-5 * expected, "{backend} {:?}: {got} vs {expected}", [x, y, z]);
                }
            }
        }
    }
    assert!(relative_l2(&gpu.fluence_all(), &cpu.fluence_all()) <= 1e-6);
}
