//! The boundary power split by the six faces of the volume (`report.json`'s `energy.faces`): closed
//! forms for a beam through an absorbing slab (straight down: Beer–Lambert; slanted: the faces the
//! discrete rays' geometry gives), the faces adding up to the totals, the edge rule, and the GPU
//! against its CPU twin.
use crate::common::*;
use lpm::scene::{Scene, Shape, SpatialScheme};
use lpm::solver::energy::{EnergyBalance, VOLUME_FACES};
use lpm::solver::BackendKind::{self, Cpu, Gpu};

const MX: usize = 0;
const PX: usize = 1;
const MY: usize = 2;
const PY: usize = 3;
const MZ: usize = 4;
const PZ: usize = 5;

fn energy(name: &str, scene: &Scene, backend: BackendKind) -> EnergyBalance {
    solve(name, scene, backend).run.outcome.energy
}

/// |a − b| ≤ tol·scale.
fn close(a: f64, b: f64, tol: f64, scale: f64, what: &str) {
    assert!((a - b).abs() <= tol * scale, "{what}: {a} vs {b} (tolerance {tol} of {scale})");
}

/// The faces' sums are the totals (computed apart, per ray, on the CPU twin; by face on the GPU).
fn faces_add_up(e: &EnergyBalance, channels: usize, tol: f64) {
    for c in 0..channels {
        let (sum_in, sum_out): (f64, f64) =
            (e.faces.iter().map(|f| f.power_in[c]).sum(), e.faces.iter().map(|f| f.power_out[c]).sum());
        close(sum_in, e.boundary_in[c], tol, e.boundary_in[c], "Σ faces in vs boundary_in");
        close(sum_out, e.boundary_out[c], tol, e.boundary_in[c], "Σ faces out vs boundary_out");
    }
}

/// Every face's power in and out on the GPU against the twin, relative to the total power in.
fn gpu_matches_twin_by_face(gpu: &EnergyBalance, cpu: &EnergyBalance, channels: usize) {
    for c in 0..channels {
        let scale = cpu.boundary_in[c] + cpu.emitted[c];
        for (g, t) in gpu.faces.iter().zip(&cpu.faces) {
            close(g.power_in[c], t.power_in[c], 1e-4, scale, &format!("{} in, channel {c}", t.face));
            close(g.power_out[c], t.power_out[c], 1e-4, scale, &format!("{} out, channel {c}", t.face));
        }
        close(gpu.absorbed[c], cpu.absorbed[c], 1e-4, scale, "absorbed");
    }
}

fn absorbing_slab(dims: [u32; 3], sigma: f64, sun_dir: [f64; 3], e: f64) -> Scene {
    let mut s = scene(Shape::Box, dims, [sigma; 3], [0.0; 3], vec![sun(sun_dir, [e; 3])]);
    s.solver.tolerance = 1e-8;
    s
}

#[test]
fn an_overhead_sun_through_an_absorbing_slab_leaves_by_beer_lambert() {
    // The sun straight above (rays travel −z): every ray is born on the +z face. Per lateral axis
    // of n voxels the lattice holds n + 1 rays, one of them in the vacuum column beside the slab
    // (README, "Energy balance"): n_x·n_y rays cross σ·n_z of optical depth, the rest none.
    let (nx, ny, nz, sigma, e) = (12u32, 10u32, 4u32, 0.3, 2.0);
    let scene = absorbing_slab([nx, ny, nz], sigma, [0.0, 0.0, 1.0], e);
    let rays = ((nx + 1) * (ny + 1)) as f64;
    let inside = (nx * ny) as f64;
    let transmitted = e * (inside * (-sigma * nz as f64).exp() + rays - inside);
    for backend in [Cpu, Gpu] {
        let en = energy(&format!("slab-overhead-{backend:?}"), &scene, backend);
        let tol = if backend == Gpu { 1e-6 } else { 1e-12 };
        close(en.faces[PZ].power_in[0], e * rays, tol, e * rays, "in through +z");
        close(en.faces[MZ].power_out[0], transmitted, tol, e * rays, "out through −z");
        for f in [MX, PX, MY, PY, MZ] {
            assert_eq!(en.faces[f].power_in[0], 0.0, "{} in", VOLUME_FACES[f]);
        }
        for f in [MX, PX, MY, PY, PZ] {
            assert_eq!(en.faces[f].power_out[0], 0.0, "{} out", VOLUME_FACES[f]);
        }
        close(en.absorbed[0], e * rays - transmitted, 1e-5, e * rays, "absorbed");
        close(en.faces[PZ].transmittance[0].unwrap(), transmitted / (e * rays), tol, 1.0, "transmittance");
        assert_eq!(en.faces[PZ].reflectance[0], Some(0.0));
        assert_eq!(en.faces[MZ].transmittance[0], None, "nothing entered through −z");
        close(en.absorptance[0], 1.0 - transmitted / (e * rays), 1e-5, 1.0, "absorptance");
        faces_add_up(&en, 1, 1e-6);
    }
}

/// The discrete rays of a beam with lateral slope `slope` along x (and none along y), travelling
/// −z, under `solver.spatial = "constant"` (each ray meets the one voxel of its lattice column, the
/// column n being the vacuum outside), walked one by one: per face, the radiance·rays in and out.
/// The offsets are the nearest column's, written out here from their definition.
fn slanted_beam_by_hand(n: [u32; 3], slope: f64, optical_depth_per_plane: f64) -> ([f64; 6], [f64; 6]) {
    let (mut face_in, mut face_out) = ([0.0; 6], [0.0; 6]);
    let offset = |t: u32| (0.5 + slope * (t as f64 + 0.5)).floor() as i64 - 1;
    let period = n[0] as i64 + 1;
    let attenuation = (-optical_depth_per_plane).exp();
    for q in 0..=n[1] {
        for p in 0..=n[0] {
            let mut l = 1.0;
            face_in[PZ] += 1.0;
            let mut wraps = (p as i64 + offset(0) + 1).div_euclid(period);
            for t in 0..n[2] {
                let unwrapped = p as i64 + offset(t) + 1;
                if unwrapped.div_euclid(period) != wraps {
                    // Moving +x, the ray leaves through +x; the ray born in its slot enters
                    // through −x.
                    wraps = unwrapped.div_euclid(period);
                    face_out[PX] += l;
                    face_in[MX] += 1.0;
                    l = 1.0;
                }
                let column = unwrapped.rem_euclid(period);
                if column < n[0] as i64 && q < n[1] {
                    l *= attenuation;
                }
            }
            face_out[MZ] += l;
        }
    }
    (face_in, face_out)
}

#[test]
fn a_slanted_sun_leaves_through_the_side_the_geometry_gives() {
    // Rays travel along (0.5, 0, −1): half a voxel sideways per plane, out through +x, new rays in
    // through −x.
    let (dims, sigma, e) = ([16u32, 6, 8], 0.2, 1.5);
    let travel = glam::DVec3::new(0.5, 0.0, -1.0).normalize();
    let mut scene = absorbing_slab(dims, sigma, (-travel).to_array(), e);
    scene.solver.spatial = Some(SpatialScheme::Constant);
    let cos = travel.z.abs();
    let path = 1.0 / cos;
    let (by_hand_in, by_hand_out) = slanted_beam_by_hand(dims, 0.5, sigma * path);
    // A ray's power per unit radiance: h²·|ω_z|.
    let power = e * cos;
    let cpu = energy("slab-slanted-cpu", &scene, Cpu);
    let total_in = power * by_hand_in.iter().sum::<f64>();
    for f in 0..6 {
        close(cpu.faces[f].power_in[0], power * by_hand_in[f], 1e-12, total_in, &format!("{} in", VOLUME_FACES[f]));
        close(cpu.faces[f].power_out[0], power * by_hand_out[f], 1e-12, total_in, &format!("{} out", VOLUME_FACES[f]));
    }
    // The geometry: the side a beam of slope ½ crosses over 8 planes is 4 columns of rays wide,
    // against the n_x + 1 columns of the top.
    close(cpu.faces[MX].power_in[0] / cpu.faces[PZ].power_in[0], 4.0 / 17.0, 1e-12, 1.0, "side/top");
    assert!(cpu.faces[PX].power_out[0] > 0.0 && cpu.faces[MZ].power_out[0] > 0.0);
    faces_add_up(&cpu, 1, 1e-9);
    let gpu = energy("slab-slanted-gpu", &scene, Gpu);
    gpu_matches_twin_by_face(&gpu, &cpu, 1);
    faces_add_up(&gpu, 1, 1e-6);
}

#[test]
fn a_ray_crossing_an_edge_counts_half_to_each_side() {
    // A beam slanted equally along x and y over a square slab: x and y are exchangeable, and so
    // must their faces be (rays wrapping in both axes in one plane cross an edge).
    let mut scene = absorbing_slab([10, 10, 7], 0.25, [-0.45, -0.45, 1.0], 1.0);
    scene.solver.spatial = Some(SpatialScheme::Constant);
    for backend in [Cpu, Gpu] {
        let e = energy(&format!("edge-{backend:?}"), &scene, backend);
        let scale = e.boundary_in[0];
        assert!(e.faces[PX].power_out[0] > 0.0);
        close(e.faces[PX].power_out[0], e.faces[PY].power_out[0], 1e-6, scale, "+x vs +y out");
        close(e.faces[MX].power_in[0], e.faces[MY].power_in[0], 1e-6, scale, "−x vs −y in");
        faces_add_up(&e, 1, 1e-6);
    }
}

#[test]
fn faces_of_a_scattering_cloud_add_up_close_the_balance_and_match_the_twin() {
    let mut scene = scene(
        Shape::Cloud,
        [34, 30, 28],
        [1.0, 0.8, 0.6],
        [0.9, 0.8, 0.7],
        vec![sky(0.5), sun([0.35, -0.3, 1.0], [2.0, 1.5, 1.0])],
    );
    scene.solver.max_orders = 5;
    scene.solver.tolerance = 1e-30;
    let cpu = energy("faces-cloud-cpu", &scene, Cpu);
    let gpu = energy("faces-cloud-gpu", &scene, Gpu);
    for e in [&cpu, &gpu] {
        assert!(e.relative_imbalance < 1e-5, "{e:?}");
        faces_add_up(e, 3, 1e-6);
        // The sky lights every face; light leaves through every face.
        assert!(e.faces.iter().all(|f| f.power_in[0] > 0.0 && f.power_out[0] > 0.0), "{:?}", e.faces);
    }
    faces_add_up(&cpu, 3, 1e-12);
    gpu_matches_twin_by_face(&gpu, &cpu, 3);
}

#[test]
fn faces_of_a_sparse_volume_match_the_twin() {
    // Medium in the lower part only: the sweeps cross vacuum slices, the last ones included (the
    // GPU leaves out dispatches where rays do not move; what leaves through the far face is the
    // ray state itself).
    let scene =
        raw_scene("faces-sparse-raw", [40, 20, 44], 0.5, 0.8, vec![sky(1.0), sun([0.0, 0.0, 1.0], [2.0; 3])], |v| {
            if v[2] < 12 && v[0] < 24 {
                1.0
            } else {
                0.0
            }
        });
    let mut scene = scene;
    scene.solver.max_orders = 3;
    scene.solver.tolerance = 1e-30;
    let cpu = energy("faces-sparse-cpu", &scene, Cpu);
    let gpu = energy("faces-sparse-gpu", &scene, Gpu);
    faces_add_up(&cpu, 1, 1e-12);
    faces_add_up(&gpu, 1, 1e-6);
    gpu_matches_twin_by_face(&gpu, &cpu, 1);
}

#[test]
fn report_names_the_faces_with_their_fractions() {
    let scene = absorbing_slab([8, 8, 3], 0.4, [0.0, 0.0, 1.0], 1.0);
    let e = energy("faces-json", &scene, Cpu);
    let json = serde_json::to_value(e).expect("serialise");
    let faces = json["faces"].as_array().expect("faces");
    let names: Vec<&str> = faces.iter().map(|f| f["face"].as_str().unwrap()).collect();
    assert_eq!(names, VOLUME_FACES);
    assert!(faces[PZ]["transmittance"][0].as_f64().unwrap() > 0.0);
    assert!(faces[MZ]["reflectance"][0].is_null());
    assert!(json["absorptance"][0].as_f64().unwrap() > 0.0);
    assert!(json["absorbed"][0].as_f64().unwrap() > 0.0);
}
