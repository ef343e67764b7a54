//! Per-face exitance maps (issue 36, item 4; `solver::exitance`): each face's map adds up to the
//! power the books count out through that face (open, periodic and mirror faces; grey and RGB;
//! sun and sky), a symmetric scene gives symmetric maps, the maps are the same bits at any thread
//! count, and a solve writes them as `faces/<face>.exr`, `.raw` and `.nhdr`. The GPU backend's
//! maps (`solver::gpu::face_maps`) are the twin's to the f32 propagation's round-off, add up to
//! its own books, are the same bits run to run and resident or streamed in passes, and its job
//! writes them too.
use crate::common::*;
use lpm::scene::{Boundary, DeviceResidency, Scene, Shape};
use lpm::solver::exitance::ExitMaps;
use lpm::solver::gpu::budget::Residency;
use lpm::solver::BackendKind::{Cpu, Gpu};

/// Every map's sum against its face's `power_out` (relative to the power in), per channel.
fn maps_add_up_to_the_books(s: &Solved, what: &str) -> ExitMaps {
    maps_add_up_within(s, what, 1e-12)
}

/// [`maps_add_up_to_the_books`] to `tolerance` of the power in.
fn maps_add_up_within(s: &Solved, what: &str, tolerance: f64) -> ExitMaps {
    let maps = s.run.exit_maps.clone().expect("the solve gives its maps");
    let e = &s.run.outcome.energy;
    for ch in 0..s.run.plan.channels as usize {
        let scale = e.boundary_in[ch] + e.emitted[ch];
        assert!(scale > 0.0, "{what}: light comes in");
        for face in 0..6 {
            let (sum, books) = (maps.total(face)[ch], e.faces[face].power_out[ch]);
            assert!(
                (sum - books).abs() <= tolerance * scale,
                "{what}: face {} channel {ch}: map sums to {sum}, the books say {books}",
                ExitMaps::name(face)
            );
            assert!(maps.pixels(face).all(|p| p[ch] >= 0.0), "{what}: no negative power");
        }
    }
    maps
}

/// An RGB cloud lit by a sky and a slanted sun, its volume of unequal sides (light leaves by all
/// six faces, rays wrap across edges).
fn rgb_cloud() -> Scene {
    let mut sc = scene(
        Shape::Sphere,
        [13, 11, 9],
        [0.8, 0.5, 0.3],
        [0.9, 0.8, 0.7],
        vec![sky(0.5), sun([0.4, -0.3, 1.0], [2.0; 3])],
    );
    sc.solver.max_orders = 6;
    sc
}

#[test]
fn each_map_adds_up_to_its_faces_power_out_and_is_the_same_at_any_thread_count() {
    let sc = rgb_cloud();
    let pool = |threads: usize| rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
    let one = pool(1).install(|| solve("exitance-rgb-1", &sc, Cpu));
    let three = pool(3).install(|| solve("exitance-rgb-3", &sc, Cpu));
    let maps = maps_add_up_to_the_books(&one, "RGB cloud");
    // Light leaves through every face, and the map is not one value spread evenly.
    for face in 0..6 {
        let m: Vec<[f64; 3]> = maps.pixels(face).collect();
        assert_eq!(m.len() as u32, maps.size(face).iter().product::<u32>());
        let (lo, hi) = m.iter().fold((f64::MAX, 0f64), |(lo, hi), p| (lo.min(p[0]), hi.max(p[0])));
        assert!(hi > 0.0 && hi > 1.01 * lo, "face {}: {lo}..{hi}", ExitMaps::name(face));
    }
    let bits = |s: &Solved| {
        let maps = s.run.exit_maps.as_ref().expect("maps");
        (0..6).flat_map(|f| maps.map(f).iter().map(|v| v.to_bits()).collect::<Vec<_>>()).collect::<Vec<_>>()
    };
    assert_eq!(bits(&one), bits(&three), "the same bits on 1 and 3 threads");
}

#[test]
fn periodic_and_mirror_faces_hold_what_the_books_count_through_them() {
    // Periodic along x (a slanted sun crosses the periodic faces as the sweep axis's far face and
    // leaves by open sides in the step between periods), and with a mirror at −y and +z.
    let mut periodic = scene(Shape::Sphere, [12, 10, 8], [0.6; 3], [0.9; 3], vec![sun([0.5, 0.2, 1.0], [1.0; 3])]);
    periodic.boundary = Boundary { periodic: [true, false, false], ..Default::default() };
    periodic.solver.max_orders = 6;
    let s = solve("exitance-periodic", &periodic, Cpu);
    let maps = maps_add_up_to_the_books(&s, "periodic x");
    assert!(maps.total(0)[0] > 0.0 && maps.total(1)[0] > 0.0, "the periodic faces carry light out");

    let mut mirrored = scene(Shape::Cloud, [12, 10, 8], [0.6; 3], [0.9; 3], vec![sky(1.0)]);
    mirrored.boundary = Boundary { reflective: [[false; 2], [true, false], [false, true]], ..Default::default() };
    mirrored.solver.max_orders = 6;
    let s = solve("exitance-mirror", &mirrored, Cpu);
    let maps = maps_add_up_to_the_books(&s, "mirrors at -y and +z");
    assert!(maps.total(2)[0] > 0.0, "what reaches the mirror is counted there, as in the books");
}

#[test]
fn a_symmetric_scene_gives_symmetric_maps() {
    // A ball in a cube under a uniform sky: every face's map is the same, and each is symmetric
    // under u → n − 1 − u and v → n − 1 − v. With k = 2 no direction's rays ever sit on whole
    // columns; where one does (the slope-0 direction of an odd k), the maps are mirror-symmetric
    // only up to a plane's shift of some side exits (`solver::exitance`).
    let n = 10u32;
    let mut sc = scene(Shape::Sphere, [n; 3], [0.7; 3], [0.8; 3], vec![sky(1.0)]);
    sc.solver.directions_per_face = 2;
    sc.solver.max_orders = 5;
    let s = solve("exitance-symmetric", &sc, Cpu);
    let maps = maps_add_up_to_the_books(&s, "ball");
    let reference: Vec<[f64; 3]> = maps.pixels(0).collect();
    let largest = reference.iter().fold(0f64, |m, p| m.max(p[0]));
    let at = |m: &[[f64; 3]], u: u32, v: u32| m[(u + n * v) as usize][0];
    let mut worst = 0f64;
    for face in 0..6 {
        let m: Vec<[f64; 3]> = maps.pixels(face).collect();
        let m = &m[..];
        for v in 0..n {
            for u in 0..n {
                let value = at(m, u, v);
                for other in [at(&reference, u, v), at(m, n - 1 - u, v), at(m, u, n - 1 - v)] {
                    worst = worst.max((value - other).abs() / largest);
                }
            }
        }
    }
    assert!(worst <= 1e-9, "largest difference between pixels a symmetry maps onto each other: {worst} of the largest");
}

#[test]
fn a_solve_writes_the_maps_as_exr_and_nrrd() {
    for backend in [Cpu, Gpu] {
        a_solve_on_writes_the_maps(backend);
    }
}

fn a_solve_on_writes_the_maps(backend: lpm::solver::BackendKind) {
    let dir = temp_dir(&format!("exitance-job-{backend:?}"));
    let text = "[volume]\nprocedural = \"sphere\"\ndims = [12, 10, 8]\nvoxel_size = 0.5\n[medium]\nsigma_t = 1.0\n\
                albedo = 0.9\n[[lights]]\nkind = \"sun\"\ndirection = [0.3, 0.2, 1.0]\nirradiance = 1.0\n\
                [solver]\ndirections_per_face = 3\nmax_orders = 4\n";
    let scene = write_scene(&dir, text);
    let out = dir.join("out");
    let job = lpm::job::SolveJob { backend, no_image: true, ..lpm::job::SolveJob::new(scene, out.clone()) };
    let report = lpm::job::run(&job, |_, _| {}).expect("solve");
    let faces = out.join("faces");
    for (f, face) in report.energy.faces.iter().enumerate() {
        for ext in ["exr", "raw", "nhdr"] {
            assert!(faces.join(format!("{}.{ext}", face.face)).is_file(), "faces/{}.{ext}", face.face);
        }
        let raw = std::fs::read(faces.join(format!("{}.raw", face.face))).expect("raw");
        let values: Vec<f32> = raw.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        let [u, v] = ExitMaps::axes(f).map(|a| [12u32, 10, 8][a] as usize);
        assert_eq!(values.len(), u * v, "one grey value per pixel");
        let sum: f64 = values.iter().map(|&x| x as f64).sum();
        let books = face.power_out[0];
        assert!((sum - books).abs() <= 1e-5 * report.energy.boundary_in[0], "{}: {sum} vs {books}", face.face);
        let header = std::fs::read_to_string(faces.join(format!("{}.nhdr", face.face))).expect("nhdr");
        assert!(header.contains(&format!("sizes: {u} {v}\n")), "{header}");
        let image = exr::prelude::read_first_flat_layer_from_file(faces.join(format!("{}.exr", face.face)))
            .expect("the EXR reads back");
        assert_eq!(image.layer_data.size.0 * image.layer_data.size.1, u * v);
    }
}

/// The GPU's books count what a slot carried out through the sides summed in f32 on the device
/// (per slot, over its wraps), the maps each exit in f64: they agree to f32 round-off.
const GPU_BOOKS: f64 = 1e-6;

/// Every pixel's bits of every map, for bitwise comparisons.
fn map_bits(s: &Solved) -> Vec<u64> {
    let maps = s.run.exit_maps.as_ref().expect("maps");
    (0..6).flat_map(|f| maps.map(f).iter().map(|v| v.to_bits()).collect::<Vec<_>>()).collect()
}

/// Solves `scene` for its fixed orders on both backends; the GPU's maps add up to its books and
/// are the twin's to f32 round-off: per face and channel, the relative L2 difference and the
/// largest pixel's difference (of the face's largest pixel) at most 1e-5. Not bitwise: the kernels
/// propagate in f32, the twin in f64 (both measure about 1e-7 here, f32's round-off).
fn gpu_maps_match_the_twin(name: &str, scene: &Scene) -> Solved {
    let mut sc = scene.clone();
    sc.solver.tolerance = 1e-30;
    let gpu = solve(&format!("{name}-gpu"), &sc, Gpu);
    let cpu = solve(&format!("{name}-cpu"), &sc, Cpu);
    assert_eq!(gpu.run.outcome.orders, cpu.run.outcome.orders, "{name}");
    let g = maps_add_up_within(&gpu, name, GPU_BOOKS);
    let c = maps_add_up_to_the_books(&cpu, name);
    for face in 0..6 {
        for ch in 0..gpu.run.plan.channels as usize {
            let (a, b): (Vec<f64>, Vec<f64>) = g.pixels(face).zip(c.pixels(face)).map(|(x, y)| (x[ch], y[ch])).unzip();
            let largest = b.iter().fold(0f64, |m, &v| m.max(v));
            let worst = a.iter().zip(&b).fold(0f64, |m, (x, y)| m.max((x - y).abs()));
            let l2 = if largest > 0.0 { relative_l2(&a, &b) } else { 0.0 };
            assert!(l2 <= 1e-5, "{name}: face {} channel {ch}: relative L2 {l2}", ExitMaps::name(face));
            assert!(
                worst <= 1e-5 * largest,
                "{name}: face {} channel {ch}: {worst} of {largest}",
                ExitMaps::name(face)
            );
        }
    }
    gpu
}

#[test]
fn the_gpu_maps_are_the_twins_and_add_up_to_its_books() {
    // RGB, sky and slanted sun, all six faces lit from inside, rays wrapping across edges.
    gpu_maps_match_the_twin("exitance-gpu-rgb", &rgb_cloud());
    // Periodic along x: the far face's exits of the x sweeps, the sides' in the step between
    // periods, and the carried rays.
    let mut periodic = scene(Shape::Sphere, [12, 10, 8], [0.6; 3], [0.9; 3], vec![sun([0.5, 0.2, 1.0], [1.0; 3])]);
    periodic.boundary = Boundary { periodic: [true, false, false], ..Default::default() };
    periodic.solver.max_orders = 6;
    let s = gpu_maps_match_the_twin("exitance-gpu-periodic", &periodic);
    let maps = s.run.exit_maps.as_ref().expect("maps");
    assert!(maps.total(0)[0] > 0.0 && maps.total(1)[0] > 0.0, "the periodic faces carry light out");
}

#[test]
fn the_gpu_maps_are_the_same_bits_run_to_run_and_resident_or_streamed_in_passes() {
    let sc = rgb_cloud();
    let resident = solve("exitance-gpu-resident", &sc, Gpu);
    let again = solve("exitance-gpu-again", &sc, Gpu);
    let r = resident.run.memory.expect("plan");
    assert_eq!(r.residency, Residency::Resident);
    assert!(r.exit_maps);
    assert!(map_bits(&resident) == map_bits(&again), "two runs give the same maps");
    // Streamed on budgets that cut the slices into sub-slices, and each face's directions into
    // passes (about 130 kB holds a face's 9 directions and their records here, 40 kB one): the
    // records of a pass are folded after it, the ray state starts afresh.
    let mut cuts = Vec::new();
    for budget in [300_000, 100_000] {
        let mut streamed = sc.clone();
        streamed.solver.device_residency = DeviceResidency::Streamed;
        streamed.solver.device_memory_budget = Some(budget);
        let st = solve(&format!("exitance-gpu-streamed-{budget}"), &streamed, Gpu);
        let m = st.run.memory.expect("plan");
        assert!(m.exit_maps, "the records fit: {m:?}");
        assert!(map_bits(&resident) == map_bits(&st), "resident and streamed ({m:?}) give the same maps");
        assert!(resident.field_bits() == st.field_bits(), "{m:?}");
        cuts.push((m.planes_per_slice, m.directions_per_pass));
    }
    let per_face = sc.solver.directions_per_face.pow(2);
    assert!(cuts.iter().any(|&(planes, _)| planes < 16), "sub-slices: {cuts:?}");
    assert!(cuts.iter().any(|&(_, pass)| pass < per_face), "passes: {cuts:?}");
}

#[test]
fn the_gpu_makes_no_maps_where_they_would_not_add_up_or_do_not_fit() {
    // Mirror faces: solved as the doubled volume, whose faces are not the scene's (a mirror is a
    // plane inside it), so there is nothing to place the light that reaches a mirror on.
    let mut mirrored = scene(Shape::Cloud, [12, 10, 8], [0.6; 3], [0.9; 3], vec![sky(1.0)]);
    mirrored.boundary = Boundary { reflective: [[false; 2], [true, false], [false; 2]], ..Default::default() };
    mirrored.solver.max_orders = 3;
    assert!(solve("exitance-gpu-mirror", &mirrored, Gpu).run.exit_maps.is_none(), "no maps with mirror faces");
    // The smallest budget a solve fits holds no side-exit records: the solve goes on without maps.
    let mut small = rgb_cloud();
    small.solver.max_orders = 2;
    small.solver.device_memory_budget = Some(smallest_unit(&small));
    let s = solve("exitance-gpu-small", &small, Gpu);
    assert!(!s.run.memory.expect("plan").exit_maps);
    assert!(s.run.exit_maps.is_none(), "no maps when their records do not fit");
}
