//! One full scattering order (all six faces, k = 5, 150 directions) over a 64³ procedural cloud,
//! on the Vulkan device and on the CPU twin. Throughput is in voxel·direction updates: criterion
//! prints it as "elements/s". On a machine without a GPU the Vulkan device is lavapipe, so the GPU
//! figure is a CPU figure: label it so in benches/RESULTS.md.
//!
//! Run: `cargo bench --bench order` (LPM_BENCH_DIMS=N and LPM_BENCH_K=k change the size).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glam::DVec3;
use lpm::scene::*;
use lpm::solver::cpu::CpuTwin;
use lpm::solver::fields::StoreFields;
use lpm::solver::gpu::GpuBackend;
use lpm::solver::orders::Backend;
use lpm::solver::plan::Plan;
use lpm::vk::{Context, ContextOptions};
use std::path::PathBuf;

fn env_u32(name: &str, default: u32) -> u32 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn bench_scene() -> Scene {
    let n = env_u32("LPM_BENCH_DIMS", 64);
    Scene {
        path: PathBuf::from("bench"),
        volume: Volume {
            source: VolumeSource::Procedural { shape: Shape::Cloud, seed: 1 },
            dims: [n; 3],
            voxel_size: 1.0,
            origin: DVec3::ZERO,
            emission: None,
            albedo: None,
        },
        medium: Medium { sigma_t: [0.5, 0.4, 0.3], albedo: [0.9; 3], g: 0.0, emission: [0.0; 3] },
        lights: vec![
            Light::Sky { radiance: [1.0; 3] },
            Light::Sun { direction: DVec3::new(0.3, 1.0, 0.2).normalize(), irradiance: [2.0; 3] },
        ],
        solver: SolverSettings {
            directions_per_face: env_u32("LPM_BENCH_K", 5),
            storage_directions_per_face: None,
            sky_directions_per_face: None,
            scattered_directions_per_face: None,
            max_orders: 1,
            tolerance: 1e-4,
            device_memory_budget: None,
            host_memory_budget: None,
            extrapolate_tail: false,
            storage_precision: StoragePrecision::Auto,
            plan: PlanMode::Auto,
            spatial: None,
            forward_peak: ForwardPeak::default(),
            emission_uncollided: Default::default(),
            diffusion_correction: DiffusionCorrection::default(),
            acceleration: Acceleration::default(),
            diffusion_cells: None,
            checkpoint: Default::default(),
            device_residency: Default::default(),
        },
        camera: None,
        boundary: Default::default(),
        display: Default::default(),
    }
}

fn order(c: &mut Criterion) {
    let scene = bench_scene();
    let dir = std::env::temp_dir().join(format!("lpm-bench-{}", std::process::id()));
    let store = lpm::solver::build_store(&scene, &dir).expect("store");
    let total = store.grid().brick_count();
    let plan = Plan::new(&scene, total, total - store.occupied_count());
    let [nx, ny, nz] = plan.dims;
    let updates = nx as u64 * ny as u64 * nz as u64 * plan.propagation.len() as u64;

    let mut group = c.benchmark_group(format!("order {nx}x{ny}x{nz} k={}", plan.propagation.k));
    group.sample_size(10);
    group.throughput(Throughput::Elements(updates));

    let ctx = Context::new(ContextOptions { validation: false, ..ContextOptions::default() }).expect("Vulkan");
    let label = format!("gpu [{}]", ctx.device_name());
    let mut fields = StoreFields::create(&store, &plan).expect("fields");
    {
        let mut gpu = GpuBackend::new(ctx.clone(), &plan, &store, &mut fields, lpm::solver::gpu::GpuOptions::default())
            .expect("GPU backend");
        gpu.propagate_order(0).expect("order 0");
        let (fields, medium) = gpu.fields();
        fields.commit_order(&plan, medium).expect("commit");
        group.bench_function(label, |b| b.iter(|| gpu.propagate_order(1).expect("order")));
    }
    let mut twin = CpuTwin::new(&plan, |v| store.density_at(v)).expect("twin");
    twin.propagate_order(0).expect("order 0");
    let (fields, medium) = twin.fields();
    fields.commit_order(&plan, medium).expect("commit");
    group.bench_function("cpu twin (f64, 1 thread)", |b| b.iter(|| twin.propagate_order(1).expect("order")));
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, order);
criterion_main!(benches);
