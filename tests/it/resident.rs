//! The device-resident mode (`solver::gpu::budget::Residency`): when every occupied brick's medium
//! and fields fit the budget they stay on the device, and the result is bitwise what streaming
//! every pass gives, for every kind of sweep (sun beams, f16 sources, anisotropic storage, periodic
//! carries, the diffusion acceleration's corrected sources, a point light's order 0 written by the
//! host); the plan says which mode and why.
use crate::common::*;
use lpm::scene::{Acceleration, Boundary, DeviceResidency, Scene, Shape, SpatialScheme, StoragePrecision};
use lpm::solver::gpu::budget::EndOfOrder;
use lpm::solver::gpu::budget::Residency;
use lpm::solver::BackendKind::Gpu;

/// Solves `scene` resident and streamed; asserts the modes and equal bits, orders and books, and
/// returns where the resident solve's passes between orders ran.
fn resident_equals_streamed(name: &str, scene: &Scene) -> EndOfOrder {
    let resident = solve(&format!("{name}-resident"), scene, Gpu);
    let mut s = scene.clone();
    s.solver.device_residency = DeviceResidency::Streamed;
    let streamed = solve(&format!("{name}-streamed"), &s, Gpu);
    let (r, st) = (resident.run.memory.expect("plan"), streamed.run.memory.expect("plan"));
    assert_eq!(r.residency, Residency::Resident, "{name}: {r:?}");
    assert_eq!(st.residency, Residency::StreamedOnRequest, "{name}: {st:?}");
    assert!(resident.field_bits() == streamed.field_bits(), "{name}: resident and streamed differ");
    let (a, b) = (&resident.run.outcome, &streamed.run.outcome);
    assert_eq!(a.orders, b.orders, "{name}");
    for (fa, fb) in a.energy.faces.iter().zip(&b.energy.faces) {
        assert_eq!(fa.power_in, fb.power_in, "{name}: {}", fa.face);
        assert_eq!(fa.power_out, fb.power_out, "{name}: {}", fa.face);
    }
    // The stop rule saw the same: every order's power and remaining error, to the bit.
    for (ra, rb) in a.history.iter().zip(&b.history) {
        assert_eq!(ra.new_source_power.to_bits(), rb.new_source_power.to_bits(), "{name}: order {}", ra.order);
        assert_eq!(
            ra.remaining_max.map(f64::to_bits),
            rb.remaining_max.map(f64::to_bits),
            "{name}: order {}",
            ra.order
        );
    }
    assert_eq!(a.remaining.map(|r| r.l2.to_bits()), b.remaining.map(|r| r.l2.to_bits()), "{name}");
    assert_eq!(st.end_of_order, EndOfOrder::HostStreamed, "{name}");
    r.end_of_order
}

/// The passes between orders run on the device when the plan needs nothing the device lacks: the
/// fields cross the bus once at the start and once at the end, and the answer, every order's power
/// and remaining error, and the books are bitwise the streamed mode's (whose host passes commit).
#[test]
fn the_device_commits_the_orders_as_the_host_does() {
    use lpm::scene::ForwardPeak;
    // RGB, f32, a sky and a sun; dims not a multiple of 16 (the bricks' padding is walked too).
    let mut grey = scene(
        Shape::Cloud,
        [24, 22, 26],
        [1.2, 0.9, 0.6],
        [0.7, 0.6, 0.5],
        vec![sky(0.5), sun([0.4, -0.3, 1.0], [2.0; 3])],
    );
    grey.solver.acceleration = Acceleration::Off;
    grey.solver.max_orders = 4;
    grey.solver.tolerance = 1e-9;
    assert_eq!(resident_equals_streamed("device-f32", &grey), EndOfOrder::Device);
    // f16 storage, anisotropic (2×2 storage directions per face, the phase function kept).
    let mut aniso = grey.clone();
    aniso.medium.g = 0.5;
    aniso.solver.forward_peak = ForwardPeak::Keep;
    aniso.solver.storage_directions_per_face = Some(2);
    aniso.solver.storage_precision = StoragePrecision::F16;
    aniso.solver.max_orders = 4;
    assert_eq!(resident_equals_streamed("device-f16", &aniso), EndOfOrder::Device);
    // A huge dynamic range: a dense core (σt·h up to 40) whose far side holds f32 denormals.
    let mut dark = scene(Shape::Cloud, [20, 20, 20], [40.0; 3], [0.5; 3], vec![sun([0.0, 0.0, 1.0], [1.0; 3])]);
    dark.solver.acceleration = Acceleration::Off;
    dark.solver.max_orders = 3;
    assert_eq!(resident_equals_streamed("device-dark", &dark), EndOfOrder::Device);
    // Converged by the stop rule (not the cap): the same order stops both.
    let mut stop = grey.clone();
    stop.solver.tolerance = 1e-2;
    stop.solver.max_orders = 40;
    assert_eq!(resident_equals_streamed("device-stop", &stop), EndOfOrder::Device);
}

/// The diffusion acceleration on the device: its kernels restrict each order's source to the
/// grid and prolong the correction bitwise as the host does, for cells of one voxel, cells inside
/// a brick, cells the size of a brick and cells holding several bricks (`solver.diffusion_cells`
/// makes them coarse), over dims no power of two, RGB, with voxels too thick for the grid. The
/// volume is 3×2×2 bricks (8 occupied): long enough in x for two cells of 32, each cell of 16 one
/// brick.
#[test]
fn the_device_accelerates_the_orders_as_the_host_does() {
    let mut thick = scene(
        Shape::Cloud,
        [34, 26, 24],
        [2.4, 1.6, 1.0],
        [0.99, 0.98, 0.995],
        vec![sky(1.0), sun([0.3, 0.2, 1.0], [1.0; 3])],
    );
    thick.solver.spatial = Some(SpatialScheme::Constant);
    thick.solver.acceleration = Acceleration::Diffusion;
    thick.solver.directions_per_face = 3;
    thick.solver.max_orders = 4;
    thick.solver.tolerance = 1e-9;
    // Cells of 1, 4, 16 and 32 voxels a side: (34/e)·(26/e)·(24/e) cells, rounded up.
    for (edge, cells) in [(1, None), (4, Some(9 * 7 * 6)), (16, Some(3 * 2 * 2)), (32, Some(2))] {
        let mut s = thick.clone();
        s.solver.diffusion_cells = cells;
        let max_cells = cells.map_or(lpm::solver::acceleration::MAX_CELLS, |c| c as usize);
        assert_eq!(lpm::solver::acceleration::grid_of(s.volume.dims, max_cells).0, edge);
        assert_eq!(resident_equals_streamed(&format!("device-accelerated-{edge}"), &s), EndOfOrder::Device);
    }
}

/// The diffusion correction on the device: what each order propagates, C(T + S) − C(T), is the
/// host's to the bit — thin and optically thick voxels (the stability limit's share, with its
/// exponential), partners across brick edges and empty bricks, periodic sides, f16 storage, with
/// and without the acceleration. (3×2×2 bricks, 8 occupied: the last x bricks are empty, the
/// cloud vanishing within 10 % of each face.)
#[test]
fn the_device_corrects_diffusion_as_the_host_does() {
    use lpm::scene::DiffusionCorrection;
    let mut cloud = scene(
        Shape::Cloud,
        [34, 26, 24],
        [3.5, 2.0, 1.0],
        [0.95, 0.9, 0.8],
        vec![sky(1.0), sun([0.3, -0.2, 1.0], [1.0; 3])],
    );
    cloud.solver.spatial = Some(SpatialScheme::Constant);
    cloud.solver.diffusion_correction = DiffusionCorrection::On;
    cloud.solver.acceleration = Acceleration::Off;
    cloud.solver.max_orders = 4;
    cloud.solver.tolerance = 1e-9;
    assert_eq!(resident_equals_streamed("device-corrected", &cloud), EndOfOrder::Device);
    let mut accelerated = cloud.clone();
    accelerated.medium.albedo = [0.99, 0.98, 0.995];
    accelerated.solver.acceleration = Acceleration::Diffusion;
    assert_eq!(resident_equals_streamed("device-corrected-accelerated", &accelerated), EndOfOrder::Device);
    let mut half = cloud.clone();
    half.solver.storage_precision = StoragePrecision::F16;
    half.solver.max_orders = 3;
    assert_eq!(resident_equals_streamed("device-corrected-f16", &half), EndOfOrder::Device);
    let mut slab = scene(Shape::Cloud, [24, 20, 28], [0.8; 3], [0.9; 3], vec![sun([0.5, 0.3, 1.0], [1.0; 3])]);
    slab.solver.spatial = Some(SpatialScheme::Constant);
    slab.solver.diffusion_correction = DiffusionCorrection::On;
    slab.boundary = Boundary { periodic: [true, true, false], ..Default::default() };
    slab.solver.max_orders = 4;
    assert_eq!(resident_equals_streamed("device-corrected-periodic", &slab), EndOfOrder::Device);
}

/// A warm start (here accelerated and diffusion-corrected, as a scattering cloud's plan is by
/// default): its first commit takes the guess back off on the host, the orders after it are
/// committed on the device, and the answer is the streamed solve's to the bit.
#[test]
fn a_warm_start_commits_on_the_device_after_its_first_order() {
    let dir = temp_dir("resident-warm");
    let run = |name: &str, sky: f64, residency: &str, warm: Option<&str>| -> (Vec<u8>, serde_json::Value) {
        let text = format!(
            "[volume]\nprocedural = \"cloud\"\ndims = [26, 22, 24]\n[medium]\nsigma_t = 1.5\nalbedo = 0.95\n\
             [[lights]]\nkind = \"sky\"\nradiance = {sky}\n[solver]\ndirections_per_face = 3\nmax_orders = 5\n\
             tolerance = 1e-9\ndevice_residency = \"{residency}\"\n"
        );
        let scene = write_scene_as(&dir, &format!("{name}.toml"), &text);
        let job = lpm::job::SolveJob {
            no_image: true,
            vk: validated(),
            warm_start: warm.map(|w| dir.join(w)),
            ..lpm::job::SolveJob::new(scene, dir.join(name))
        };
        lpm::job::run(&job, |_, _| {}).expect("solve");
        let report = serde_json::from_slice(&std::fs::read(dir.join(name).join("report.json")).expect("report"));
        (std::fs::read(dir.join(name).join("fluence.raw")).expect("fluence"), report.expect("json"))
    };
    run("cold", 1.0, "auto", None);
    let (resident, r) = run("warm-resident", 1.3, "auto", Some("cold"));
    let (streamed, s) = run("warm-streamed", 1.3, "streamed", Some("cold"));
    assert_eq!(r["device_memory"]["end_of_order"], "device", "{}", r["device_memory"]);
    assert_eq!(s["device_memory"]["end_of_order"], "host_streamed", "{}", s["device_memory"]);
    assert_eq!(r["plan"]["acceleration"], "diffusion");
    assert_eq!(r["plan"]["diffusion_grid"], serde_json::json!({"cells": [26, 22, 24], "cell_edge": 1}));
    assert!(r["warm_start"].is_string());
    assert_eq!(r["orders"], s["orders"]);
    assert!(resident == streamed, "a warm start resident and streamed differ");
}

/// A per-voxel albedo factor on the device: the new source scaled by it, the acceleration's
/// prolongation and the diffusion correction's weights with it, bitwise the host's.
#[test]
fn the_device_scales_by_an_albedo_grid_as_the_host_does() {
    use lpm::scene::DiffusionCorrection;
    let dims = [30, 26, 28];
    let path = temp_dir("resident-albedo-input").join("albedo.raw");
    write_raw_field(&path, dims, |v| if v[0] < 15 { 0.999 } else { 0.3 + 0.02 * (v[1] % 7) as f32 });
    let mut s = scene(Shape::Cloud, dims, [2.0, 1.5, 1.0], [0.99; 3], vec![sky(1.0), sun([0.3, 0.2, 1.0], [1.0; 3])]);
    s.volume.albedo = Some(lpm::scene::AlbedoGrid::Raw { path });
    s.solver.spatial = Some(SpatialScheme::Constant);
    s.solver.max_orders = 4;
    s.solver.tolerance = 1e-9;
    assert_eq!(resident_equals_streamed("device-albedo", &s), EndOfOrder::Device);
    let mut corrected = s.clone();
    corrected.solver.diffusion_correction = DiffusionCorrection::On;
    corrected.solver.acceleration = Acceleration::Diffusion;
    assert_eq!(resident_equals_streamed("device-albedo-corrected", &corrected), EndOfOrder::Device);
}

#[test]
fn resident_and_streamed_give_the_same_bits() {
    // RGB, sun and sky, anisotropic (2×2 storage directions), the source stored in f16.
    let mut cloud = scene(
        Shape::Cloud,
        [24, 22, 26],
        [0.9, 0.7, 0.5],
        [0.9, 0.8, 0.7],
        vec![sky(0.5), sun([0.4, -0.3, 1.0], [2.0; 3])],
    );
    cloud.medium.g = 0.5;
    cloud.solver.directions_per_face = 3;
    cloud.solver.storage_directions_per_face = Some(2);
    cloud.solver.max_orders = 4;
    cloud.solver.storage_precision = StoragePrecision::F16;
    resident_equals_streamed("cloud-f16", &cloud);

    // High albedo with the diffusion acceleration (every order's source corrected).
    let mut thick = scene(Shape::Cloud, [32, 32, 32], [2.0; 3], [0.99; 3], vec![sky(1.0)]);
    thick.solver.spatial = Some(SpatialScheme::Constant);
    thick.solver.acceleration = Acceleration::Diffusion;
    thick.solver.max_orders = 5;
    assert_eq!(resident_equals_streamed("thick-accelerated", &thick), EndOfOrder::Device);

    // Periodic sides: the rays carry what left one side into the next order.
    let mut slab = scene(Shape::Cloud, [24, 20, 28], [0.8; 3], [0.9; 3], vec![sun([0.5, 0.3, 1.0], [1.0; 3])]);
    slab.solver.spatial = Some(SpatialScheme::Constant);
    slab.boundary = Boundary { periodic: [true, true, false], ..Default::default() };
    slab.solver.max_orders = 4;
    resident_equals_streamed("periodic", &slab);

    // A point light: the host writes its order 0 into the accumulators before the sweeps, so
    // the resident load carries them instead of clearing.
    let point = lpm::scene::Light::Point { position: glam::DVec3::new(10.0, 12.0, 9.0), intensity: [40.0; 3] };
    let mut lit = scene(Shape::Cloud, [26, 22, 20], [0.6; 3], [0.8; 3], vec![point]);
    lit.solver.max_orders = 3;
    resident_equals_streamed("point-light", &lit);
}

#[test]
fn the_plan_says_resident_or_streamed_and_why() {
    let mut s = scene(Shape::Cloud, [34, 30, 38], [0.9; 3], [0.9; 3], vec![sky(1.0)]);
    s.solver.max_orders = 1;
    let resident = solve("plan-resident", &s, Gpu).run.memory.expect("plan");
    assert!(resident.is_resident() && resident.resident_field_bytes > 0, "{resident:?}");
    assert!(resident.residency_reason.starts_with("resident"), "{resident:?}");
    assert!(resident.planned_bytes <= resident.budget_bytes);
    // A budget under the resident working set streams, and says so.
    s.solver.device_memory_budget = Some(resident.resident_bytes - 1);
    let over = solve("plan-over", &s, Gpu).run.memory.expect("plan");
    assert_eq!(over.residency, Residency::StreamedOverBudget, "{over:?}");
    assert_eq!(over.resident_field_bytes, 0);
    assert!(over.residency_reason.contains("larger than the device memory budget"), "{over:?}");
}

/// `lpm solve` reports the mode in report.json and `lpm info` says it in words; the scene key
/// `solver.device_residency = "streamed"` turns the resident mode off.
#[test]
fn report_and_info_name_the_mode() {
    let dir = temp_dir("resident-cli");
    for (mode, key) in [("resident", ""), ("streamed_on_request", "device_residency = \"streamed\"\n")] {
        let text = killable_cloud_scene([20, 18, 22], 1).replacen("[solver]\n", &format!("[solver]\n{key}"), 1);
        let scene = dir.join(format!("{mode}.toml"));
        std::fs::write(&scene, text).unwrap();
        let out = dir.join(mode);
        let o = lpm_command(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-image"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
        assert_eq!(report["device_memory"]["residency"], mode, "{}", report["device_memory"]);
        let o = lpm_command(&["info", out.to_str().unwrap()]).output().unwrap();
        let text = String::from_utf8_lossy(&o.stdout);
        let words =
            if mode == "resident" { "resident: the medium and fields" } else { "streamed slice by slice, as asked" };
        assert!(text.contains(words), "{text}");
    }
}
