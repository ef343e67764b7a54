//! Reflective faces (`[boundary] x = "reflective"`, `solver::mirror`): a volume with mirror faces
//! solves to the restriction of the volume doubled by its mirror images across those faces (the
//! method of images), which the solver never stores or sweeps; the energy books close.
use crate::common::*;
use lpm::reference::{self, ReferenceOptions};
use lpm::scene::{Boundary, Scene, SpatialScheme};
use lpm::solver::BackendKind::{Cpu, Gpu};

/// A lumpy medium over `dims`, the same function of the voxel everywhere, so that a volume and
/// its mirror images can be written from one function.
fn lumpy(v: [u32; 3]) -> f32 {
    let [x, y, z] = v.map(|c| c as f32);
    0.45 + 0.25 * (0.9 * x + 0.4).sin() * (0.7 * y + 1.1).cos() + 0.15 * (0.5 * z + 0.3).sin()
}

/// The voxel of the half volume `half` that voxel `v` of the doubled volume images, for mirrors
/// at the faces marked in `mirror` (per axis: low, high).
fn imaged(v: [u32; 3], half: [u32; 3], mirror: [[bool; 2]; 3]) -> [u32; 3] {
    let mut h = v;
    for a in 0..3 {
        let n = half[a];
        if mirror[a][0] {
            // The image lies below: doubled coordinate 0..n is the image, n..2n the volume.
            h[a] = if v[a] < n { n - 1 - v[a] } else { v[a] - n };
        } else if mirror[a][1] && v[a] >= n {
            h[a] = 2 * n - 1 - v[a];
        }
    }
    h
}

/// Where voxel `v` of the half volume lies in the doubled one.
fn in_doubled(v: [u32; 3], half: [u32; 3], mirror: [[bool; 2]; 3]) -> [u32; 3] {
    let mut d = v;
    for a in 0..3 {
        if mirror[a][0] {
            d[a] += half[a];
        }
    }
    d
}

fn mirrored_scene(
    name: &str,
    dims: [u32; 3],
    k: u32,
    mirror: [[bool; 2]; 3],
    density: impl Fn([u32; 3]) -> f32,
) -> Scene {
    thin_or_thick_scene(name, dims, k, mirror, 1.0, density)
}

/// [`mirrored_scene`] with extinction `sigma_t` at density 1.
fn thin_or_thick_scene(
    name: &str,
    dims: [u32; 3],
    k: u32,
    mirror: [[bool; 2]; 3],
    sigma_t: f64,
    density: impl Fn([u32; 3]) -> f32,
) -> Scene {
    let mut s = raw_scene(name, dims, sigma_t, 0.8, vec![sky(1.0)], density);
    s.solver.directions_per_face = k;
    s.solver.spatial = Some(SpatialScheme::Constant);
    s.solver.tolerance = 1e-9;
    s.boundary = Boundary { reflective: mirror, ..Default::default() };
    s
}

/// Solves `half` with mirrors at `mirror` and the doubled volume with open faces, and returns the
/// largest relative difference over the half volume's voxels, and the mirrored solve.
fn against_images(name: &str, half: [u32; 3], k: u32, mirror: [[bool; 2]; 3]) -> (f64, Solved) {
    against_images_at(name, half, k, mirror, 1.0)
}

/// [`against_images`] with extinction `sigma_t` at density 1.
fn against_images_at(name: &str, half: [u32; 3], k: u32, mirror: [[bool; 2]; 3], sigma_t: f64) -> (f64, Solved) {
    let doubled_dims = [0, 1, 2].map(|a| half[a] * if mirror[a].contains(&true) { 2 } else { 1 });
    let with_mirrors = thin_or_thick_scene(&format!("{name}-half"), half, k, mirror, sigma_t, lumpy);
    let doubled = thin_or_thick_scene(&format!("{name}-doubled"), doubled_dims, k, [[false; 2]; 3], sigma_t, |v| {
        lumpy(imaged(v, half, mirror))
    });
    let a = solve(&format!("{name}-half-solve"), &with_mirrors, Cpu);
    let b = solve(&format!("{name}-doubled-solve"), &doubled, Cpu);
    let mut worst = 0.0f64;
    for z in 0..half[2] {
        for y in 0..half[1] {
            for x in 0..half[0] {
                let v = [x, y, z];
                let (fa, fb) = (a.fluence(v, 0), b.fluence(in_doubled(v, half, mirror), 0));
                worst = worst.max((fa - fb).abs() / fb);
            }
        }
    }
    (worst, a)
}

// Directions swept across a mirror are nudged to move whole columns over the volume; the doubled
// volume's are not. The sizes across the mirrors below make the nudge zero (the lateral slopes of
// k = 3 are 0 and ±2/3, of k = 4 ±1/4 and ±3/4), so both solve the same directions.

#[test]
fn a_mirror_face_solves_to_the_doubled_volume() {
    for (k, nx, low) in [(3, 6, false), (4, 8, false), (4, 8, true)] {
        let mirror = [[low, !low], [false; 2], [false; 2]];
        let (worst, s) = against_images(&format!("mirror-x-{k}-{low}"), [nx, 5, 4], k, mirror);
        assert!(worst < 1e-5, "k = {k}, low = {low}: the half volume is {worst} from the doubled one");
        let balance = s.run.outcome.energy.relative_imbalance;
        assert!(balance < 1e-6, "k = {k}: energy balance {balance}");
    }
}

#[test]
fn three_mirrors_meeting_at_a_corner_solve_to_the_volume_doubled_three_times() {
    // As Kobayashi's problems are stated: mirrors at x = 0, y = 0, z = 0, open faces opposite.
    // Rays cross the mirrors' edges and their corner, where two or three hand-overs meet, and
    // (k = 4 has no zero slope) come in through a mirror while still outside along another axis.
    for (k, n) in [(3, 6), (4, 8)] {
        let mirror = [[true, false]; 3];
        let (worst, s) = against_images(&format!("mirror-corner-{k}"), [n, n, n], k, mirror);
        assert!(worst < 1e-5, "k = {k}: the mirrored volume is {worst} from the doubled one");
        let balance = s.run.outcome.energy.relative_imbalance;
        assert!(balance < 1e-6, "k = {k}: energy balance {balance}");
    }
}

#[test]
fn nudged_directions_find_their_mirror_images() {
    // k = 6 over 5 planes: the slopes ±1/2 move ±2.5 columns over the volume and are nudged to
    // ±3/5 (a tie, rounded away from zero for both signs: periodic::periodic_slope); a direction
    // whose image got the other rounding would hand its light to nobody (−10 % here). The doubled
    // volume is not nudged, so the two agree to the nudge's effect, which a nearly transparent
    // medium makes small (the sky reaches every voxel from every direction).
    let (worst, s) = against_images_at("mirror-nudged", [5, 6, 6], 6, [[true, false]; 3], 1e-3);
    assert!(worst < 1e-3, "the mirrored volume is {worst} from the doubled one");
    let balance = s.run.outcome.energy.relative_imbalance;
    assert!(balance < 1e-6, "energy balance {balance}");
}

#[test]
fn the_monte_carlo_reference_reflects_photons_at_mirrors() {
    // Mirrors at x = y = z = 0: the corner octant of a cloud. The reference reflects its photons
    // there, and must agree with its own answer for the volume doubled three times with open
    // faces (within its noise: means over the corner's 4³ voxels). The same half volume with open
    // faces (sky coming in where the mirrors are) reads far brighter near the corner, so the
    // comparison tells mirrors apart from open faces.
    let (half, k) = ([8, 8, 8], 4);
    let mirror = [[true, false]; 3];
    let scene = mirrored_scene("mirror-mc", half, k, mirror, lumpy);
    let photons = |n| ReferenceOptions { photons: n, seed: 5, ..ReferenceOptions::default() };
    let mc = reference::run(&scene, &lumpy, 1, &photons(400_000));
    let open = Scene { boundary: Boundary::default(), ..scene.clone() };
    let mc_open = reference::run(&open, &lumpy, 1, &photons(400_000));
    let density = move |v| lumpy(imaged(v, half, mirror));
    let doubled = mirrored_scene("mirror-mc-doubled", [16; 3], k, [[false; 2]; 3], density);
    let mc_doubled = reference::run(&doubled, &density, 1, &photons(3_200_000));
    let corner = |r: &reference::ReferenceResult, shift: u32| -> f64 {
        let n = r.dims[0];
        let mut sum = 0.0;
        for z in 0..4 {
            for y in 0..4 {
                for x in 0..4 {
                    let [x, y, z] = [x, y, z].map(|c| c + shift);
                    sum += r.fluence[(x + n * (y + n * z)) as usize] as f64;
                }
            }
        }
        sum / 64.0
    };
    let (a, b, c) = (corner(&mc, 0), corner(&mc_doubled, 8), corner(&mc_open, 0));
    let rel = (a - b).abs() / b;
    assert!(rel < 0.02, "corner mean fluence: mirrored {a} vs doubled {b} ({rel})");
    assert!((c - a) / a > 0.1, "open faces {c} vs mirrors {a}: the mirrors made no difference");
}

/// The GPU backend solves mirror faces on the volume doubled by its images (`solver::unfold`):
/// the twin's answer (to the f32 kernels' rounding; the sizes keep the twin's nudge at zero), its
/// energy books closed with no flow through the mirror faces, and the open faces' books the twin's.
#[test]
fn the_gpu_solves_mirror_faces_on_the_doubled_volume_as_the_twin_does() {
    for (name, half, mirror) in [
        ("x-high", [8, 5, 4], [[false, true], [false; 2], [false; 2]]),
        ("x-both", [8, 6, 5], [[true, true], [false; 2], [false; 2]]),
        ("corner", [8, 8, 8], [[true, false]; 3]),
    ] {
        let mut s = mirrored_scene(&format!("mirror-gpu-scene-{name}"), half, 4, mirror, lumpy);
        s.solver.tolerance = 1e-6;
        let (g, c) = (solve(&format!("mirror-gpu-{name}"), &s, Gpu), solve(&format!("mirror-twin-{name}"), &s, Cpu));
        let err = relative_l2(&g.fluence_all(), &c.fluence_all());
        assert!(err < 1e-4, "{name}: GPU vs twin {err}");
        let (eg, ec) = (&g.run.outcome.energy, &c.run.outcome.energy);
        assert!(eg.relative_imbalance < 1e-5, "{name}: {eg:?}");
        // Through a face no mirror borders, what came in is the twin's (the same births). Next to
        // a mirror the twin also counts the rays in its vacuum column beyond the mirror, born
        // beside the face and leaving again without meeting the medium (n + 1 lattice columns
        // across a mirrored axis against the doubled volume's 2n + 1 or 2n, over two): up to
        // 12 % of such a face's books in and out, the lattice's, not the light's, which the
        // absorbed power below shows (solver::unfold). Through a mirror nothing.
        let scale = ec.boundary_in[0];
        for (f, (fg, fc)) in eg.faces.iter().zip(&ec.faces).enumerate() {
            if mirror[f / 2][f % 2] {
                assert_eq!((fg.power_in[0], fg.power_out[0]), (0.0, 0.0), "{name}: mirror face {}", fg.face);
            } else if !(0..3).any(|a| a != f / 2 && mirror[a].contains(&true)) {
                assert!((fg.power_in[0] - fc.power_in[0]).abs() < 1e-5 * scale, "{name}: into {}", fg.face);
            }
        }
        let (ag, ac) = (eg.absorbed[0], ec.absorbed[0]);
        assert!((ag - ac).abs() < 1e-4 * scale, "{name}: absorbed GPU {ag} vs twin {ac}");
    }
}

/// A mirror on the low face of an axis whose length is not a multiple of 16 (issue 57: the GPU's
/// fluence was exactly 0 on planes z = 0–7 under a sphere in a 20 × 20 × 40 box): the volume lies
/// shifted by n in the doubled one, so its bricks straddle the doubled volume's. Here the doubled
/// brick z = 16..31 images only vacuum (z = 0..11) yet holds the volume's planes 0..11, which lie
/// in an occupied brick (medium from z = 12): the GPU must light them as the twin does. One brick
/// across, two deep (three in the doubled volume): the smallest volume with a straddling brick.
#[test]
fn the_gpu_lights_the_vacuum_beside_a_low_mirror_where_the_bricks_straddle() {
    let (half, mirror) = ([4, 4, 20], [[false; 2], [false; 2], [true, false]]);
    let density = |v: [u32; 3]| if v[2] >= 12 { lumpy(v) } else { 0.0 };
    let mut s = mirrored_scene("mirror-gpu-straddle-scene", half, 4, mirror, density);
    s.solver.tolerance = 1e-6;
    let (g, c) = (solve("mirror-gpu-straddle", &s, Gpu), solve("mirror-twin-straddle", &s, Cpu));
    let (fg, fc) = (g.fluence_all(), c.fluence_all());
    let dark = fg.iter().zip(&fc).filter(|(a, b)| **a == 0.0 && **b > 0.0).count();
    assert_eq!(dark, 0, "{dark} voxels dark on the GPU that the twin lights");
    let err = relative_l2(&fg, &fc);
    assert!(err < 1e-4, "GPU vs twin {err}");
}

/// An albedo grid is copied across the mirrors as the density is.
#[test]
fn the_gpu_doubles_an_albedo_grid_with_the_volume() {
    let (half, mirror) = ([6, 8, 5], [[false; 2], [true, false], [false; 2]]);
    let mut s = mirrored_scene("mirror-gpu-albedo-scene", half, 4, mirror, lumpy);
    let path = temp_dir("mirror-gpu-albedo-input").join("albedo.raw");
    write_raw_field(&path, half, |v| 0.5 + 0.5 * ((v[0] + 2 * v[1] + v[2]) % 3) as f32 / 2.0);
    s.volume.albedo = Some(lpm::scene::AlbedoGrid::Raw { path });
    s.solver.tolerance = 1e-6;
    let (g, c) = (solve("mirror-gpu-albedo", &s, Gpu), solve("mirror-twin-albedo", &s, Cpu));
    let err = relative_l2(&g.fluence_all(), &c.fluence_all());
    assert!(err < 1e-4, "GPU vs twin {err}");
    assert!(g.run.outcome.energy.relative_imbalance < 1e-5, "{:?}", g.run.outcome.energy);
}

/// The doubled volume is not checkpointed (its checkpoint would not be the scene's): a resumed
/// GPU solve with mirror faces finds no checkpoint and solves afresh, to the same bits.
#[test]
fn a_gpu_solve_with_mirror_faces_writes_no_checkpoint_and_resumes_afresh() {
    let s = mirrored_scene("mirror-gpu-resume-scene", [6, 5, 4], 3, [[false, true], [false; 2], [false; 2]], lumpy);
    let dir = temp_dir("mirror-gpu-resume");
    let store = lpm::solver::build_store(&s, &dir.join("store")).expect("store");
    let options = lpm::solver::gpu::GpuOptions::for_scene(&s);
    let run = |resume| {
        let (_, fields) =
            lpm::solver::solve_with(&s, &store, Gpu, validated(), options, resume, |_, _| {}).expect("solve");
        fields.fluence_total.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    };
    let first = run(false);
    assert!(!dir.join("store").join("checkpoint.json").exists(), "a checkpoint of the doubled volume");
    assert!(!dir.join("store").join("unfolded").exists(), "the doubled store was left behind");
    assert_eq!(run(true), first);
    // Cancelled, it says that there is nothing to resume (and leaves no doubled store behind).
    let cancel = lpm::solver::cancel::CancelFlag::new();
    let options = lpm::solver::gpu::GpuOptions { cancel: Some(cancel), ..options };
    let err = lpm::solver::solve_with(&s, &store, Gpu, validated(), options, false, |_, _| cancel.raise())
        .err()
        .expect("the solve is cancelled");
    assert!(matches!(err, lpm::solver::SolveError::Cancelled { resumable: false }), "{err}");
    assert!(err.to_string().contains("no checkpoint is kept"), "{err}");
    assert!(!dir.join("store").join("unfolded").exists(), "the doubled store was left behind");
}

/// `lpm bench stream` drives the GPU kernels directly, without doubling the volume: a scene with
/// mirror faces is refused there rather than solved as if the mirrors were open.
#[test]
fn bench_stream_refuses_mirror_faces() {
    let dir = temp_dir("mirror-bench-stream");
    let scene = write_scene(
        &dir,
        "[volume]\nprocedural = \"box\"\ndims = [8, 8, 8]\n[medium]\nsigma_t = 1.0\nalbedo = 0.5\n\
         [[lights]]\nkind = \"sky\"\nradiance = 1.0\n[boundary]\nx = [\"open\", \"reflective\"]\n",
    );
    let o = lpm_command(&["bench", "stream", scene.to_str().unwrap(), "--orders", "1"]).output().expect("run lpm");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("mirror faces"), "{err}");
}
