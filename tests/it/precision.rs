//! Storage precision of the source the rays gain (`solver.storage_precision`): the f16 GPU path
//! against the f16 CPU twin, f16 against f32, what `auto` picks and why, the bytes it saves, and
//! clear errors for bad values. Validation layers on (a validation error fails the solve).
use crate::common::*;
use lpm::scene::{Scene, SceneError, Shape, StoragePrecision};
use lpm::solver::plan::{half_scale_exponent, Plan, Precision};
use lpm::solver::BackendKind::{Cpu, Gpu};
use std::path::Path;

fn with_precision(mut scene: Scene, p: StoragePrecision) -> Scene {
    scene.solver.storage_precision = p;
    scene
}

fn anisotropic_cloud() -> Scene {
    let mut s = scene(Shape::Cloud, [24, 22, 26], [0.8; 3], [0.9; 3], vec![sky(0.3), sun([-0.5, 0.4, 1.0], [2.0; 3])]);
    s.medium.g = 0.7;
    s.solver.directions_per_face = 3;
    s.solver.storage_directions_per_face = Some(2);
    s.solver.max_orders = 4;
    s.solver.tolerance = 1e-30;
    with_precision(s, StoragePrecision::F16)
}

#[test]
fn f16_on_the_gpu_matches_the_f16_twin_at_any_budget() {
    let mut scene = anisotropic_cloud();
    let resident = solve("f16-aniso-gpu-resident", &scene, Gpu);
    // The cuts below are the streamed mode's; resident is the same bits.
    scene.solver.device_residency = lpm::scene::DeviceResidency::Streamed;
    let gpu = solve("f16-aniso-gpu", &scene, Gpu);
    assert!(resident.field_bits() == gpu.field_bits(), "resident and streamed f16 differ");
    assert_eq!(gpu.run.plan.source_precision, Precision::F16);
    let full = gpu.run.memory.expect("memory plan");
    assert_eq!(full.planes_per_slice, 16, "{full:?}");

    // The smallest budget forces sub-slices of one plane on any device (a budget between that
    // and the full plan lets the cost model choose between fewer slots and sub-slices, which it
    // does differently for a CPU and a GPU): the f16 slabs are cut out of the bricks by strided
    // runs.
    let budget = smallest_unit(&scene);
    let mut tight = scene.clone();
    tight.solver.device_memory_budget = Some(budget);
    let sub = solve("f16-aniso-gpu-sub", &tight, Gpu);
    let m = sub.run.memory.expect("memory plan");
    assert!(m.planes_per_slice < 16, "{m:?}");
    assert!(
        m.planned_bytes <= budget && sub.run.peak_device_bytes <= budget,
        "{m:?}, peak {}",
        sub.run.peak_device_bytes
    );
    assert!(sub.field_bits() == gpu.field_bits(), "sub-slices changed the f16 result");

    let twin16 = solve("f16-aniso-cpu", &scene, Cpu);
    let twin32 = solve("f32-aniso-cpu", &with_precision(scene.clone(), StoragePrecision::F32), Cpu);
    let (g, t16, t32) = (gpu.fluence_all(), twin16.fluence_all(), twin32.fluence_all());
    assert!(g.iter().all(|v| v.is_finite() && *v >= 0.0));
    let err = relative_l2(&g, &t16);
    let rounding = relative_l2(&t16, &t32);
    eprintln!("f16 GPU vs f16 twin: {err:.3e}; f16 twin vs f32 twin: {rounding:.3e}");
    assert!(err <= 1e-4, "relative L2 {err}");
    // The twin's rounding is real (and the GPU follows it, not the f32 path).
    assert!(rounding > 0.0);
    let gpu_vs_f32_twin = relative_l2(&g, &t32);
    assert!(
        err < gpu_vs_f32_twin,
        "the GPU should be closer to the f16 twin ({err}) than to the f32 one ({gpu_vs_f32_twin})"
    );
}

#[test]
fn f16_rgb_cloud_with_sun_and_sky_matches_the_f16_twin() {
    let mut scene = scene(
        Shape::Cloud,
        [28, 26, 30],
        [0.9, 0.7, 0.5],
        [0.95, 0.9, 0.8],
        vec![sky(0.4), sun([0.3, 1.0, 0.2], [3.0, 2.8, 2.5])],
    );
    scene.solver.directions_per_face = 4;
    scene.solver.max_orders = 8;
    scene.solver.tolerance = 1e-30;
    let scene = with_precision(scene, StoragePrecision::F16);
    let gpu = solve("f16-rgb-gpu", &scene, Gpu);
    let cpu = solve("f16-rgb-cpu", &scene, Cpu);
    let err = relative_l2(&gpu.fluence_all(), &cpu.fluence_all());
    eprintln!("rgb cloud, f16 GPU vs f16 twin: {err:.3e}");
    assert!(err <= 1e-4, "relative L2 {err}");
}

#[test]
fn f16_and_f32_differ_by_less_than_the_tolerance_and_f16_saves_bytes() {
    let mut scene =
        scene(Shape::Cloud, [28, 26, 30], [1.2; 3], [0.9; 3], vec![sky(0.5), sun([0.2, -0.4, 1.0], [3.0; 3])]);
    // k = 2: the ~40 orders this cloud takes to reach the tolerance are what the test needs (f16
    // rounding summed over them), not many directions per order.
    scene.solver.directions_per_face = 2;
    scene.solver.tolerance = 1e-3;
    // `auto` at tolerance 1e-3 picks f16.
    let f16 = solve("prec-cloud-f16", &scene, Gpu);
    let f32 = solve("prec-cloud-f32", &with_precision(scene.clone(), StoragePrecision::F32), Gpu);
    assert_eq!(f16.run.plan.source_precision, Precision::F16);
    assert_eq!(f32.run.plan.source_precision, Precision::F32);
    let diff = relative_l2(&f16.fluence_all(), &f32.fluence_all());
    eprintln!(
        "cloud at tolerance 1e-3: f16 vs f32 fluence relative L2 {diff:.3e} ({} and {} orders), energy imbalance {:.2e} and {:.2e}",
        f16.run.outcome.orders,
        f32.run.outcome.orders,
        f16.run.outcome.energy.relative_imbalance,
        f32.run.outcome.energy.relative_imbalance
    );
    assert!(diff < scene.solver.tolerance, "f16 moved the fluence by {diff}");
    assert!(diff > 0.0, "f16 should round something");
    assert_eq!(f16.run.outcome.orders, f32.run.outcome.orders);

    // Bytes: the previous source is halved in each slot's upload staging, and in each slot's
    // device buffer when streamed or in the resident buffer when resident; nothing else changes,
    // and the plan stays exact.
    let (m16, m32) = (f16.run.memory.expect("plan"), f32.run.memory.expect("plan"));
    assert_eq!((m16.slices_in_flight, m16.planes_per_slice), (m32.slices_in_flight, m32.planes_per_slice));
    assert!(m16.is_resident() && m32.is_resident(), "{m16:?}");
    let comps = f16.run.plan.source_components() as u64;
    // f32 → f16 saves 2 bytes a value, over `bricks` bricks of `comps` components.
    let saved = |bricks: u64| bricks * 16 * 16 * 16 * 2 * comps;
    let slots = m16.slices_in_flight as u64;
    assert_eq!(
        m32.planned_bytes - m16.planned_bytes,
        saved(m16.slice.occupied_total) + slots * saved(m16.slice.occupied),
        "{m16:?} vs {m32:?}"
    );
    assert!(f16.run.peak_device_bytes < f32.run.peak_device_bytes);
    assert!(f16.run.peak_device_bytes <= m16.planned_bytes);
}

#[test]
fn f16_keeps_its_precision_at_any_light_scale() {
    // A sky of 1e7 makes the source far beyond f16's largest value (65504), and one of 1e-7 puts
    // it among f16's subnormals: the per-order power-of-two scale keeps both exact to f16's rounding.
    for (name, radiance) in [("bright", 1e7), ("faint", 1e-7)] {
        let mut scene = scene(Shape::Cloud, [24, 20, 22], [1.0; 3], [0.9; 3], vec![sky(radiance)]);
        scene.solver.max_orders = 4;
        scene.solver.tolerance = 1e-30;
        let f16 = solve(&format!("scale-{name}-f16"), &with_precision(scene.clone(), StoragePrecision::F16), Gpu);
        let f32 = solve(&format!("scale-{name}-f32"), &with_precision(scene, StoragePrecision::F32), Gpu);
        let (a, b) = (f16.fluence_all(), f32.fluence_all());
        assert!(a.iter().all(|v| v.is_finite()));
        let diff = relative_l2(&a, &b);
        eprintln!("sky {radiance:e}: f16 vs f32 relative L2 {diff:.3e}");
        assert!(diff < 1e-4, "sky {radiance:e}: {diff}");
    }
}

#[test]
fn the_scale_puts_the_largest_value_just_below_two_to_the_fourteen() {
    for max in [1.0f32, 0.75, 3.0e-9, 6.5e4, 1.0e7, 2.5e30, 1.0e-30, f32::MAX] {
        let e = half_scale_exponent(max);
        let scaled = max as f64 * 2f64.powi(e);
        assert!((8192.0..16384.0).contains(&scaled), "{max:e}: 2^{e} gives {scaled}");
    }
    // Below 2^-113 the scale stops at 2^127 (a normal f32): such a source is f16's subnormals at worst.
    assert_eq!(half_scale_exponent(f32::MIN_POSITIVE), 127);
    assert_eq!(half_scale_exponent(0.0), 0);
}

fn plan_for(tolerance: f64, precision: StoragePrecision) -> Plan {
    let mut s = scene(Shape::Box, [8, 8, 8], [0.5; 3], [0.9; 3], vec![sky(1.0)]);
    s.solver.tolerance = tolerance;
    s.solver.storage_precision = precision;
    Plan::new(&s, 1, 0)
}

fn precision_reason(plan: &Plan) -> String {
    plan.reasons.iter().find(|r| r.contains("source the rays gain")).cloned().expect("a reason for the precision")
}

#[test]
fn auto_picks_f16_from_the_tolerance_and_says_why() {
    for tolerance in [1e-2, 1e-3] {
        let plan = plan_for(tolerance, StoragePrecision::Auto);
        assert_eq!(plan.source_precision, Precision::F16);
        let why = precision_reason(&plan);
        assert!(
            why.contains("f16") && why.contains("auto") && why.contains("tolerance") && why.contains("4.9e-4"),
            "{why}"
        );
    }
    for tolerance in [9.9e-4, 1e-4, 1e-6] {
        let plan = plan_for(tolerance, StoragePrecision::Auto);
        assert_eq!(plan.source_precision, Precision::F32);
        let why = precision_reason(&plan);
        assert!(why.contains("f32") && why.contains("auto") && why.contains("below"), "{why}");
    }
    let forced = plan_for(1e-2, StoragePrecision::F32);
    assert_eq!(forced.source_precision, Precision::F32);
    assert!(precision_reason(&forced).contains("storage_precision = \"f32\" in the scene"));
    let forced = plan_for(1e-6, StoragePrecision::F16);
    assert_eq!(forced.source_precision, Precision::F16);
    assert!(precision_reason(&forced).contains("storage_precision = \"f16\" in the scene"));
}

#[test]
fn the_report_and_info_state_the_precision_and_why() {
    let dir = temp_dir("prec-cli");
    for (tolerance, expected) in [("1e-2", "f16"), ("1e-5", "f32")] {
        let scene = write_scene_as(
            &dir,
            &format!("scene-{expected}.toml"),
            &format!(
                "[volume]\nprocedural = \"sphere\"\ndims = [12, 10, 9]\n[medium]\nsigma_t = 0.8\nalbedo = 0.8\n\
                 [[lights]]\nkind = \"sky\"\nradiance = 1.0\n[solver]\ndirections_per_face = 2\ntolerance = {tolerance}\n"
            ),
        );
        let out = dir.join(format!("out-{expected}"));
        let o = lpm_command(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-image"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
        assert_eq!(report["plan"]["storage_precision"], expected);
        let reasons = report["plan"]["reasons"].as_array().unwrap();
        assert!(reasons.iter().any(|r| r.as_str().unwrap().contains(&format!("stored in {expected}"))), "{reasons:?}");
        let info = lpm_command(&["info", out.to_str().unwrap()]).output().unwrap();
        let text = String::from_utf8_lossy(&info.stdout);
        assert!(text.contains(&format!("stored in {expected}")) && text.contains("tolerance"), "{text}");
    }
}

fn load(text: &str) -> Result<Scene, SceneError> {
    Scene::from_toml_str(
        &format!("[volume]\nprocedural = \"box\"\ndims = [8, 8, 8]\n[medium]\nsigma_t = 0.5\nalbedo = 0.9\n{text}"),
        Path::new("p.toml"),
    )
}

#[test]
fn the_key_parses_and_bad_values_name_it() {
    let p = |text: &str| load(text).unwrap_or_else(|e| panic!("{e}")).solver.storage_precision;
    assert_eq!(p(""), StoragePrecision::Auto);
    assert_eq!(p("[solver]\n"), StoragePrecision::Auto);
    assert_eq!(p("[solver]\nstorage_precision = \"auto\"\n"), StoragePrecision::Auto);
    assert_eq!(p("[solver]\nstorage_precision = \"f16\"\n"), StoragePrecision::F16);
    assert_eq!(p("[solver]\nstorage_precision = \"f32\"\n"), StoragePrecision::F32);

    let msg = load("[solver]\nstorage_precision = \"f8\"\n").expect_err("f8 accepted").to_string();
    assert!(msg.contains("p.toml") && msg.contains("solver.storage_precision") && msg.contains("\"f8\""), "{msg}");
    assert!(msg.contains("\"auto\", \"f16\", \"f32\""), "{msg}");
    let msg = load("[solver]\nstorage_precision = 16\n").expect_err("16 accepted").to_string();
    assert!(msg.contains("p.toml") && msg.contains("line 8") && msg.contains("solver.storage_precision"), "{msg}");
    let msg = load("[solver]\nstorage_precison = \"f16\"\n").expect_err("misspelt key accepted").to_string();
    assert!(msg.contains("storage_precison") && msg.contains("line 8"), "{msg}");
}
