//! Rendering a solved volume: what `lpm render OUT` costs per megapixel (the camera ray-march over
//! the kept source, on the CPU's threads), for an anisotropic cloud (24 storage directions, where
//! the source is blended between storage directions), the same cloud solved with δ-M (the render
//! adds the forward peak's chains, `lpm::render::peak`: two irradiance fields and a chain sum per
//! sample) and the same cloud isotropic (one storage direction); and the δ-M cloud seen towards the
//! sun (a 40° pinhole 62 voxels from its centre, `tools/forward_image_table.sh`'s backlit view),
//! where every ray also sharpens the sun's forward lobes (`lpm::render::peak`, "The forward
//! lobes": a sum over the lobes per sample). The solve is set
//! up once (CPU twin, two orders: the render's cost does not depend on how converged the source
//! is); each iteration renders one 256×256 image. Criterion's "elements/s" are pixels per second.
//!
//! Run: `cargo bench --bench render` (LPM_BENCH_DIMS=N changes the volume, LPM_BENCH_PIXELS=W the
//! image's width and height).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use lpm::job::{run, SolveJob};
use lpm::render::keep::open;
use lpm::render::Background;
use lpm::solver::BackendKind;
use std::path::Path;

fn env_u32(name: &str, default: u32) -> u32 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// A procedural cloud lit by a sun and a sky, Henyey–Greenstein `g`, solved into `out`.
fn solve(dir: &Path, name: &str, g: f64, forward_peak: &str) -> std::path::PathBuf {
    let n = env_u32("LPM_BENCH_DIMS", 48);
    let storage = if g == 0.0 { String::new() } else { "storage_directions_per_face = 2\n".to_string() };
    let scene = format!(
        "[volume]\nprocedural = \"cloud\"\ndims = [{n}, {n}, {n}]\nvoxel_size = 1.0\nseed = 2\n\n\
         [medium]\nsigma_t = 0.8\nalbedo = 0.99\ng = {g}\n\n\
         [[lights]]\nkind = \"sky\"\nradiance = 0.5\n\n\
         [[lights]]\nkind = \"sun\"\ndirection = [-0.55, -0.35, 0.75]\nirradiance = 3.0\n\n\
         [solver]\ndirections_per_face = 4\n{storage}max_orders = 2\nforward_peak = \"{forward_peak}\"\n"
    );
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, scene).expect("write the scene");
    let out = dir.join(name);
    let job =
        SolveJob { backend: BackendKind::Cpu, no_image: true, no_fields: true, ..SolveJob::new(path, out.clone()) };
    run(&job, |_, _| {}).expect("solve");
    out
}

fn render(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("lpm-bench-render-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("bench dir");
    let side = env_u32("LPM_BENCH_PIXELS", 256);
    let mut group = c.benchmark_group(format!("render {side}x{side}"));
    group.sample_size(10);
    group.throughput(Throughput::Elements(u64::from(side) * u64::from(side)));
    // The backlit view: the camera on the far side of the cloud from the sun, looking at it.
    let n = f64::from(env_u32("LPM_BENCH_DIMS", 48));
    let centre = glam::DVec3::splat(0.5 * n);
    let towards_sun = glam::DVec3::new(-0.55, -0.35, 0.75).normalize();
    let backlit = |camera: &lpm::scene::Camera| lpm::scene::Camera {
        projection: lpm::scene::Projection::Pinhole { fov_y_degrees: 40.0 },
        position: centre - towards_sun * (62.0 / 48.0 * n),
        look_at: centre,
        up: glam::DVec3::Z,
        ..camera.clone()
    };
    for (name, g, peak, towards) in [
        ("anisotropic g=0.8", 0.8, "keep", false),
        ("anisotropic g=0.8 delta-m", 0.8, "delta-m", false),
        ("anisotropic g=0.8 delta-m towards the sun", 0.8, "delta-m", true),
        ("isotropic", 0.0, "keep", false),
    ] {
        let out = solve(&dir, &name.replace([' ', '=', '-'], "_"), g, peak);
        let kept = open(&out).expect("render data");
        let camera = lpm::scene::Camera { width: side, height: side, ..kept.camera.clone() };
        let camera = if towards { backlit(&camera) } else { camera };
        group.bench_function(name, |b| b.iter(|| kept.render(&camera, Background::Sky)));
    }
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, render);
criterion_main!(benches);
