//! `solver.plan = "full"`: the plan's reductions turned off (3 channels, per-face storage
//! directions, f32 under `auto` precision). For a grey isotropic scene it must give the fluence of
//! the reduced plan to rounding, on the CPU twin and on the GPU (validation on); the report must
//! say what it modelled and why; `lpm bench accuracy --plans auto,full` sets the two side by side;
//! a bad value is a clear error.
use crate::common::*;
use lpm::scene::{PlanMode, Scene, SceneError, Shape, StoragePrecision};
use lpm::solver::plan::{Plan, Precision};
use lpm::solver::BackendKind::{self, Cpu, Gpu};
use std::path::Path;

/// Largest relative L2 difference of the fluence between the full and the auto plan of a grey
/// isotropic scene. The two differ only by rounding: the full plan's collect weights Ω_i·(Ω_d/4π)/Ω_d
/// could round differently in each storage direction d from the auto plan's Ω_i/4π, and the
/// source is stored in f32 either way. (Measured on this scene: bitwise equal on both backends.)
const SAME_FLUENCE: f64 = 1e-5;

fn with_plan(mut scene: Scene, plan: PlanMode) -> Scene {
    scene.solver.plan = plan;
    scene
}

/// A small grey isotropic cloud under a sky and a sun, a fixed number of orders (so both plans
/// propagate the same orders), k = 3: the full plan stores 6·2² = 24 directions × 3 channels.
fn grey_cloud() -> Scene {
    let mut s = scene(Shape::Cloud, [20, 18, 22], [0.9; 3], [0.9; 3], vec![sky(0.5), sun([0.3, -0.5, 1.0], [2.0; 3])]);
    s.solver.directions_per_face = 3;
    s.solver.max_orders = 5;
    s.solver.tolerance = 1e-30;
    s
}

/// The full plan's channel 0, voxel by voxel, after checking that its three channels are equal.
fn grey_channel_of_full(full: &Solved) -> Vec<f64> {
    assert_eq!(full.run.plan.channels, 3);
    let all = full.fluence_all();
    for v in all.chunks_exact(3) {
        assert!(v[0] == v[1] && v[1] == v[2], "a grey scene's channels differ: {v:?}");
    }
    all.chunks_exact(3).map(|v| v[0]).collect()
}

/// Solves the grey cloud with both plans on `backend`; returns the relative L2 difference.
fn full_against_auto(backend: BackendKind, name: &str) -> f64 {
    let scene = grey_cloud();
    let auto = solve(&format!("plan-auto-{name}"), &scene, backend);
    let full = solve(&format!("plan-full-{name}"), &with_plan(scene, PlanMode::Full), backend);
    let (pa, pf) = (&auto.run.plan, &full.run.plan);
    assert_eq!((pa.channels, pa.storage.len(), pa.source_precision), (1, 1, Precision::F32));
    assert_eq!((pf.channels, pf.storage.len(), pf.source_precision), (3, 24, Precision::F32));
    assert_eq!(auto.run.outcome.orders, full.run.outcome.orders);

    // The source of an isotropic medium is the same in every storage direction.
    let comps = pf.source_components() as usize;
    for v in [[10, 9, 11], [6, 12, 9], [14, 5, 13]] {
        let j: Vec<f32> = (0..comps as u32).map(|c| full.fields.source_total.value(v, c)).collect();
        let spread = j.iter().fold(0.0f32, |m, x| m.max((x - j[0]).abs()));
        assert!(spread <= 1e-5 * j[0].abs(), "voxel {v:?}: source differs between storage directions: {j:?}");
    }

    let (a, f) = (auto.fluence_all(), grey_channel_of_full(&full));
    assert!(a.iter().all(|v| v.is_finite() && *v >= 0.0));
    let diff = relative_l2(&f, &a);
    let worst = f.iter().zip(&a).filter(|(_, y)| **y > 0.0).map(|(x, y)| (x - y).abs() / y).fold(0.0, f64::max);
    eprintln!("{name}: full vs auto fluence relative L2 {diff:.3e}, max relative {worst:.3e}");
    assert!(diff <= SAME_FLUENCE, "{name}: full plan moved the fluence by {diff}");
    assert!(worst <= 10.0 * SAME_FLUENCE, "{name}: worst voxel moved by {worst}");
    diff
}

#[test]
fn full_plan_gives_the_auto_fluence_on_the_cpu_twin() {
    full_against_auto(Cpu, "cpu");
}

#[test]
fn full_plan_gives_the_auto_fluence_on_the_gpu() {
    full_against_auto(Gpu, "gpu");
}

fn plan_of(scene: &Scene) -> Plan {
    Plan::new(scene, 8, 3)
}

#[test]
fn the_full_plan_says_what_it_turned_off_and_what_it_kept() {
    let mut scene = grey_cloud();
    scene.solver.directions_per_face = 2;
    scene.solver.tolerance = 1e-2;
    let auto = plan_of(&scene);
    // At tolerance 1e-2 the auto plan stores f16; the full plan keeps f32.
    assert_eq!((auto.channels, auto.storage.len(), auto.source_precision), (1, 1, Precision::F16));
    let full = plan_of(&with_plan(scene.clone(), PlanMode::Full));
    assert_eq!((full.channels, full.storage.len(), full.storage.per_face), (3, 24, 2));
    assert_eq!(full.source_precision, Precision::F32);
    let summary = full.summary();
    assert_eq!((summary.mode.as_str(), summary.channels, summary.storage_directions), ("full", 3, 24));
    assert_eq!(auto.summary().mode, "auto");

    let reasons = full.reasons.join("\n");
    assert!(reasons.starts_with("plan = \"full\": the plan's reductions are off"), "{reasons}");
    assert!(
        reasons.contains("3 channels: plan = \"full\" (the medium and every light are grey, so 1 would do)"),
        "{reasons}"
    );
    assert!(
        reasons.contains("24 storage directions (2×2 per face): plan = \"full\" (the medium scatters isotropically"),
        "{reasons}"
    );
    assert!(reasons.contains("stored in f32 (auto under plan = \"full\""), "{reasons}");
    assert!(reasons.contains("3 of 8 bricks are empty") && reasons.contains("kept under plan = \"full\""), "{reasons}");
    assert!(!auto.reasons.join("\n").contains("full"), "{:?}", auto.reasons);

    // An explicit precision wins over the full plan's f32, and storage_directions_per_face sets k_s.
    let mut explicit = with_plan(scene.clone(), PlanMode::Full);
    explicit.solver.storage_precision = StoragePrecision::F16;
    explicit.solver.storage_directions_per_face = Some(1);
    let p = plan_of(&explicit);
    assert_eq!((p.source_precision, p.storage.len()), (Precision::F16, 6));
    // A medium that is already RGB and anisotropic keeps its own reasons.
    let mut rgb = with_plan(scene, PlanMode::Full);
    rgb.medium.albedo = [0.9, 0.8, 0.7];
    rgb.medium.g = 0.5;
    let p = plan_of(&rgb);
    assert_eq!((p.channels, p.storage.len()), (3, 24));
    let reasons = p.reasons.join("\n");
    assert!(reasons.contains("differs between r, g and b") && reasons.contains("anisotropic (g = 0.5)"), "{reasons}");
}

const CLI_SCENE: &str = "[volume]\nprocedural = \"sphere\"\ndims = [12, 10, 9]\n[medium]\nsigma_t = 0.8\nalbedo = 0.8\n\
                         [[lights]]\nkind = \"sky\"\nradiance = 1.0\n[solver]\ndirections_per_face = 2\ntolerance = 1e-5\n";

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn report_info_and_compare_of_a_full_solve() {
    let dir = temp_dir("plan-cli");
    let auto_scene = write_scene_as(&dir, "auto.toml", CLI_SCENE);
    let full_scene = write_scene_as(&dir, "full.toml", &format!("{CLI_SCENE}plan = \"full\"\n"));
    let (auto_out, full_out) = (dir.join("out-auto"), dir.join("out-full"));
    for (scene, out) in [(&auto_scene, &auto_out), (&full_scene, &full_out)] {
        let o = lpm_command(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-image"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let report = read_json(&full_out.join("report.json"));
    let plan = &report["plan"];
    assert_eq!(
        (plan["mode"].as_str(), plan["channels"].as_u64(), plan["storage_directions"].as_u64()),
        (Some("full"), Some(3), Some(24))
    );
    assert_eq!(plan["storage_precision"], "f32");
    assert_eq!(read_json(&auto_out.join("report.json"))["plan"]["mode"], "auto");
    assert_eq!(read_json(&full_out.join("fluence.json"))["component_names"], serde_json::json!(["r", "g", "b"]));

    let info = lpm_command(&["info", full_out.to_str().unwrap()]).output().unwrap();
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(text.contains("3 channel(s)") && text.contains("24 storage direction(s)"), "{text}");
    assert!(text.contains("plan = \"full\": the plan's reductions are off"), "{text}");

    // `lpm compare` sets each of the full solve's channels against the grey one.
    let json = dir.join("compare.json");
    let o = lpm_command(&[
        "compare",
        full_out.to_str().unwrap(),
        auto_out.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ])
    .output()
    .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let c = read_json(&json);
    let l2 = c["fluence"]["metrics"]["relative_l2"].as_f64().unwrap();
    assert!(l2 <= SAME_FLUENCE, "full vs auto through lpm compare: {l2}");
    assert_eq!(c["fluence"]["components"], 3);
    assert!(c["notes"].as_array().unwrap().iter().any(|n| n.as_str().unwrap().contains("reference is grey")), "{c}");
    // The other way round (grey candidate, RGB reference) is still a mismatch.
    let o = lpm_command(&["compare", auto_out.to_str().unwrap(), full_out.to_str().unwrap()]).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("components"));
}

#[test]
fn bench_accuracy_runs_each_setting_with_each_plan() {
    let dir = temp_dir("plan-accuracy");
    let scene = write_scene(&dir, &CLI_SCENE.replace("dims = [12, 10, 9]", "dims = [8, 8, 8]"));
    let out = dir.join("acc");
    let o = lpm_command(&[
        "bench",
        "accuracy",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--k",
        "2",
        "--tolerances",
        "1e-2",
        "--precisions",
        "auto",
        "--plans",
        "auto,full",
        "--samples",
        "2e4",
        "--reference-samples",
        "4e5",
        "--max-rel-stderr",
        "0.2",
    ])
    .output()
    .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report = read_json(&out.join("accuracy.json"));
    let rows = report["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 3, "{rows:?}");
    let (auto, full) = (&rows[0], &rows[1]);
    assert_eq!(auto["setting"], "k=2 tol=1e-2 auto plan=auto");
    assert_eq!(full["setting"], "k=2 tol=1e-2 auto plan=full");
    let facts = |r: &serde_json::Value| {
        (r["plan"].clone(), r["channels"].as_u64(), r["storage_directions"].as_u64(), r["storage_precision"].clone())
    };
    assert_eq!(facts(auto), ("auto".into(), Some(1), Some(1), "f16".into()));
    assert_eq!(facts(full), ("full".into(), Some(3), Some(24), "f32".into()));
    assert!(full["peak_device_bytes"].as_u64().unwrap() > auto["peak_device_bytes"].as_u64().unwrap());
    // Same error against Monte Carlo: f16's rounding and the full plan's are far below it.
    let (ea, ef) = (auto["relative_l2"].as_f64().unwrap(), full["relative_l2"].as_f64().unwrap());
    assert!((ea - ef).abs() < 1e-2 * ea, "auto error {ea} vs full error {ef}");
    assert!(out.join("runs/lpm-k2-tol1e-2-auto-full/report.json").exists());

    let csv = std::fs::read_to_string(out.join("accuracy.csv")).unwrap();
    assert!(csv.lines().next().unwrap().contains(",plan,channels,storage_directions,"), "{csv}");
    assert!(csv.lines().nth(2).unwrap().contains(",full,3,24,"), "{csv}");
    let svg = std::fs::read_to_string(out.join("accuracy.svg")).unwrap();
    assert!(svg.contains("plan=auto") && svg.contains("plan=full"), "the plot names both plans");
}

fn load(text: &str) -> Result<Scene, SceneError> {
    Scene::from_toml_str(
        &format!("[volume]\nprocedural = \"box\"\ndims = [8, 8, 8]\n[medium]\nsigma_t = 0.5\nalbedo = 0.9\n{text}"),
        Path::new("p.toml"),
    )
}

#[test]
fn the_key_parses_and_bad_values_name_it() {
    let p = |text: &str| load(text).unwrap_or_else(|e| panic!("{e}")).solver.plan;
    assert_eq!(p(""), PlanMode::Auto);
    assert_eq!(p("[solver]\n"), PlanMode::Auto);
    assert_eq!(p("[solver]\nplan = \"auto\"\n"), PlanMode::Auto);
    assert_eq!(p("[solver]\nplan = \"full\"\n"), PlanMode::Full);

    let msg = load("[solver]\nplan = \"everything\"\n").expect_err("accepted").to_string();
    assert!(msg.contains("p.toml") && msg.contains("solver.plan") && msg.contains("\"everything\""), "{msg}");
    assert!(msg.contains("\"auto\", \"full\""), "{msg}");
    let msg = load("[solver]\nplan = true\n").expect_err("a boolean accepted").to_string();
    assert!(msg.contains("p.toml") && msg.contains("line 8") && msg.contains("solver.plan"), "{msg}");
}
