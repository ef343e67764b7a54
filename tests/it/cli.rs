//! The `lpm` binary end to end: outputs and their layout, `info`, and clear one-line errors that
//! leave nothing behind.
use crate::common::{lpm_command, temp_dir, write_scene};
use std::path::Path;
use std::process::Output;

fn lpm(args: &[&str]) -> Output {
    lpm_command(args).output().expect("run lpm")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

const SMALL: &str = r#"
[volume]
procedural = "sphere"
dims = [20, 17, 23]
voxel_size = 0.5
[medium]
sigma_t = [1.0, 0.8, 0.6]
albedo = 0.8
[[lights]]
kind = "sky"
radiance = 1.0
[[lights]]
kind = "sun"
direction = [0.3, 1.0, 0.2]
irradiance = 2.0
[solver]
directions_per_face = 2
max_orders = 6
[camera]
projection = "orthographic"
position = [5, -20, 6]
look_at = [5, 4, 6]
width = 40
height = 30
"#;

#[test]
fn help_explains_every_subcommand_and_option() {
    let o = lpm(&["--help"]);
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    for word in ["solve", "info"] {
        assert!(text.contains(word), "{text}");
    }
    let o = lpm(&["solve", "--help"]);
    let text = String::from_utf8_lossy(&o.stdout);
    for word in ["--out", "--backend", "--device", "--validation", "--keep-store", "--no-image"] {
        assert!(text.contains(word), "{text}");
    }
}

#[test]
fn solve_writes_every_output_with_the_documented_layout() {
    let dir = temp_dir("cli-solve");
    let scene = write_scene(&dir, SMALL);
    let out = dir.join("out");
    let o = lpm(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in [
        "fluence.raw",
        "fluence.json",
        "fluence.nhdr",
        "source.raw",
        "source.json",
        "source.nhdr",
        "image.exr",
        "image.png",
        "report.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    // RGB (the medium is not grey), original dims, channel fastest.
    let raw = std::fs::metadata(out.join("fluence.raw")).unwrap().len();
    assert_eq!(raw, 20 * 17 * 23 * 3 * 4);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("fluence.json")).unwrap()).unwrap();
    assert_eq!(json["dims"], serde_json::json!([20, 17, 23]));
    assert_eq!(json["components"], 3);
    assert_eq!(json["voxel_size"], 0.5);
    let nhdr = std::fs::read_to_string(out.join("fluence.nhdr")).unwrap();
    assert!(nhdr.starts_with("NRRD") && nhdr.contains("sizes: 3 20 17 23"), "{nhdr}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["plan"]["channels"], 3);
    assert_eq!(report["plan"]["propagation_directions"], 24);
    assert!(report["plan"]["bricks_total"].as_u64().unwrap() > 0);
    assert!(report["orders"].as_u64().unwrap() >= 1);
    assert!(report["final_residual"].is_number());
    assert!(report["peak_device_bytes"].as_u64().unwrap() > 0);
    assert!(report["device"].as_str().unwrap().len() > 3);
    assert!(report["seconds"].as_array().unwrap().len() >= 4);
    let faces = report["energy"]["faces"].as_array().unwrap();
    assert_eq!(faces.len(), 6);
    assert_eq!(faces[5]["face"], "+z");
    assert!(faces.iter().all(|f| f["power_out"][0].as_f64().unwrap() > 0.0), "{faces:?}");
    // No temporary files or store left behind.
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("tmp") || n.starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");

    let o = lpm(&["info", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("3 channel(s)") && text.contains("fluence.raw") && text.contains("residual"), "{text}");
    assert!(text.contains("faces     -x in "), "{text}");
}

#[test]
fn cpu_backend_writes_the_same_layout() {
    let dir = temp_dir("cli-cpu");
    let scene = write_scene(&dir, SMALL);
    let out = dir.join("out");
    let o = lpm(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--backend", "cpu", "--no-image"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::metadata(out.join("fluence.raw")).unwrap().len(), 20 * 17 * 23 * 3 * 4);
    assert!(!out.join("image.png").exists());
}

/// Issue 36, item 2: not at a terminal, a solve logs a line per stage and per order, each with the
/// percentage done and the time left (known from order 1 on, where the decay is first seen); the
/// last order's residual and the summary's are report.json's `final_residual`.
#[test]
fn log_lines_carry_percent_and_time_left_and_the_last_residual_is_the_reports() {
    let dir = temp_dir("cli-progress");
    let scene = write_scene(&dir, SMALL);
    let out = dir.join("out");
    let o = lpm_command(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--backend", "cpu"])
        .env("LPM_LOG", "info")
        .output()
        .expect("run lpm");
    assert!(o.status.success(), "{}", stderr(&o));
    let log = stderr(&o);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let orders = report["orders"].as_u64().unwrap();
    let final_residual = format!("{:.3e}", report["final_residual"].as_f64().unwrap());
    let order_lines: Vec<&str> = log.lines().filter(|l| l.contains(" done: residual ")).collect();
    assert_eq!(order_lines.len() as u64, orders, "{log}");
    for (k, line) in order_lines.iter().enumerate() {
        assert!(line.contains(&format!("order {k} done")) && line.contains(" %, "), "{line}");
        if k >= 1 {
            assert!(line.contains(" left") && !line.contains("not known"), "{line}");
        }
    }
    for stage in ["building the brick store", "planning", "exporting the fields", "rendering"] {
        assert!(log.lines().any(|l| l.contains(stage) && l.contains(" %, ")), "no line for {stage}: {log}");
    }
    let last = order_lines.last().unwrap();
    assert!(last.contains(&format!("residual {final_residual}")), "{last} against {final_residual}");
    let summary = String::from_utf8_lossy(&o.stdout);
    assert!(summary.contains(&format!("residual {final_residual},")), "{summary} against {final_residual}");
}

/// A failing solve: exit status 1, one line on stderr with every `needle`, and nothing written.
fn assert_fails_cleanly(name: &str, scene_text: &str, extra: impl FnOnce(&Path), needles: &[&str]) {
    let dir = temp_dir(name);
    extra(&dir);
    let scene = write_scene(&dir, scene_text);
    let out = dir.join("out");
    let o = lpm(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    let last = err.lines().last().unwrap_or("");
    assert!(last.starts_with("lpm: "), "{err}");
    for n in needles {
        assert!(last.contains(n), "{n:?} not in {last:?}");
    }
    assert!(!out.exists(), "output directory left behind");
}

#[test]
fn bad_scene_is_rejected_with_file_key_and_problem() {
    let text = SMALL.replace("albedo = 0.8", "albedo = 1.5");
    assert_fails_cleanly("cli-bad-albedo", &text, |_| {}, &["scene.toml", "medium.albedo", "1.5"]);
    let text = SMALL.replace("sigma_t = [1.0, 0.8, 0.6]", "sigma_t = nan");
    assert_fails_cleanly("cli-nan", &text, |_| {}, &["scene.toml", "medium.sigma_t"]);
    let text = SMALL.replace("voxel_size = 0.5", "voxel_size = 0.5\ncolour = 1");
    assert_fails_cleanly("cli-unknown", &text, |_| {}, &["scene.toml", "colour"]);
}

const RAW: &str = r#"
[volume]
raw = "density.raw"
dims = [5, 4, 3]
[medium]
sigma_t = 1.0
albedo = 0.5
[[lights]]
kind = "sky"
radiance = 1.0
"#;

fn write_raw(dir: &Path, values: &[f32]) {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.join("density.raw"), bytes).unwrap();
}

#[test]
fn bad_raw_files_are_rejected_and_nothing_is_written() {
    // A NaN at voxel (2, 1, 0): index 2 + 5·1.
    let mut values = vec![0.5f32; 60];
    values[7] = f32::NAN;
    assert_fails_cleanly("cli-raw-nan", RAW, |d| write_raw(d, &values), &["density.raw", "(2, 1, 0)"]);
    let mut values = vec![0.5f32; 60];
    values[59] = -1.0;
    assert_fails_cleanly("cli-raw-negative", RAW, |d| write_raw(d, &values), &["density.raw", "-1"]);
    assert_fails_cleanly("cli-raw-truncated", RAW, |d| write_raw(d, &[0.5; 59]), &["density.raw", "240"]);
    assert_fails_cleanly("cli-raw-missing", RAW, |_| {}, &["density.raw"]);
}

#[test]
fn a_failed_solve_leaves_earlier_outputs_untouched() {
    let dir = temp_dir("cli-keep");
    let scene = write_scene(&dir, SMALL);
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("fluence.raw"), b"earlier").unwrap();
    let bad = write_scene(&dir, &SMALL.replace("dims = [20, 17, 23]", "dims = [20, 0, 23]"));
    let o = lpm(&["solve", bad.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(std::fs::read(out.join("fluence.raw")).unwrap(), b"earlier");
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 1);
    let _ = scene;
}

#[test]
fn reference_compare_and_bench_stream_from_the_command_line() {
    let dir = temp_dir("cli-ref");
    let text = SMALL
        .replace("dims = [20, 17, 23]", "dims = [10, 9, 8]")
        .replace("directions_per_face = 2", "directions_per_face = 3");
    let scene = write_scene(&dir, &text);
    let s = scene.to_str().unwrap();
    let (solved, reference) = (dir.join("solved"), dir.join("reference"));
    let o = lpm(&["solve", s, "--out", solved.to_str().unwrap(), "--no-image"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = lpm(&["reference", s, "--out", reference.to_str().unwrap(), "--samples", "200000", "--seed", "5"]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ["fluence.raw", "fluence.json", "fluence_stderr.raw", "report.json"] {
        assert!(reference.join(f).is_file(), "{f} missing");
    }
    let json = dir.join("cmp.json");
    let o = lpm(&["compare", solved.to_str().unwrap(), reference.to_str().unwrap(), "--json", json.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("rel. L2"), "{text}");
    let c: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert!(c["fluence"]["metrics"]["relative_l2"].as_f64().unwrap() < 0.2, "{c}");

    let o = lpm(&["bench", "stream", s, "--orders", "2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    // Resident, and the orders committed on the device as a solve commits them: after the first
    // load nothing crosses the bus (no acceleration at albedo 0.8, so no moments either).
    assert_eq!(report["memory"]["end_of_order"], "device", "{}", report["memory"]);
    assert_eq!(report["orders"][1]["upload_bytes"], 0, "{report}");
    assert_eq!(report["orders"][1]["download_bytes"], 0, "{report}");
    let order = &report["orders"][0];
    for key in [
        "upload_seconds",
        "compute_seconds",
        "download_seconds",
        "hidden_transfer_fraction",
        "upload_bytes_per_second",
        "download_bytes_per_second",
        "updates_per_second",
    ] {
        assert!(order[key].is_number(), "{key} missing in {report}");
    }
    assert!(order["compute_seconds"].as_f64().unwrap() > 0.0);
    assert!(report["note"].as_str().unwrap().len() > 10);
}

#[test]
fn device_memory_budget_flag_and_too_small_budget() {
    let dir = temp_dir("cli-budget");
    let scene = write_scene(&dir, SMALL);
    let out = dir.join("out");
    let o = lpm(&[
        "solve",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--no-image",
        "--device-memory-budget",
        "16K",
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(err.contains("too small") && err.contains("--device-memory-budget"), "{err}");
    let o = lpm(&[
        "solve",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--no-image",
        "--device-memory-budget",
        "64M",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["device_memory"]["budget_bytes"], 64 << 20);
    assert!(report["device_memory"]["planned_bytes"].as_u64().unwrap() <= 64 << 20);
    let o = lpm(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--device-memory-budget", "lots"]);
    assert_eq!(o.status.code(), Some(2), "clap rejects a malformed budget");
}

#[test]
fn bench_accuracy_writes_json_csv_and_plots() {
    let dir = temp_dir("cli-accuracy");
    let text =
        SMALL.replace("dims = [20, 17, 23]", "dims = [8, 8, 8]").replace("sigma_t = [1.0, 0.8, 0.6]", "sigma_t = 0.8");
    let scene = write_scene(&dir, &text);
    let out = dir.join("acc");
    let o = lpm(&[
        "bench",
        "accuracy",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--k",
        "1,2",
        "--tolerances",
        "1e-2",
        "--samples",
        "2e4,8e4",
        "--reference-samples",
        "4e5",
        "--max-rel-stderr",
        "0.2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("accuracy.json")).unwrap()).unwrap();
    let rows = report["rows"].as_array().unwrap();
    // Two k × the default precisions (f32, f16), then two photon counts.
    assert_eq!(rows.len(), 6);
    assert!(rows.iter().all(|r| r["seconds"].as_f64().unwrap() > 0.0 && r["relative_l2"].is_number()));
    for pair in rows[..4].chunks(2) {
        let (a, b) = (&pair[0], &pair[1]);
        assert_eq!(
            (a["storage_precision"].as_str(), b["storage_precision"].as_str()),
            (Some("f32"), Some("f16")),
            "{pair:?}"
        );
        assert!(b["planned_device_bytes"].as_u64().unwrap() < a["planned_device_bytes"].as_u64().unwrap(), "{pair:?}");
        let (ea, eb) = (a["relative_l2"].as_f64().unwrap(), b["relative_l2"].as_f64().unwrap());
        assert!((ea - eb).abs() < 1e-2 * ea.max(1e-3), "f16 error {eb} vs f32 error {ea}");
    }
    let csv = std::fs::read_to_string(out.join("accuracy.csv")).unwrap();
    assert_eq!(csv.lines().count(), 7);
    assert!(csv.lines().next().unwrap().contains("storage_precision,peak_device_bytes"));
    assert!(std::fs::read_to_string(out.join("accuracy.svg")).unwrap().contains("Monte Carlo"));
    assert!(std::fs::metadata(out.join("accuracy.svg")).unwrap().len() > 1000);
}

#[test]
fn bench_accuracy_order_caps_cut_the_series_short() {
    let dir = temp_dir("cli-accuracy-caps");
    let text = SMALL
        .replace("dims = [20, 17, 23]", "dims = [10, 10, 10]")
        .replace("sigma_t = [1.0, 0.8, 0.6]", "sigma_t = 1.5");
    let scene = write_scene(&dir, &text);
    let out = dir.join("acc");
    let o = lpm(&[
        "bench",
        "accuracy",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--k",
        "2",
        "--tolerances",
        "1e-4",
        "--max-orders",
        "1,4",
        "--precisions",
        "f32",
        "--samples",
        "2e4",
        "--reference-samples",
        "1e6",
        "--max-rel-stderr",
        "0.2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("accuracy.json")).unwrap()).unwrap();
    let rows = report["rows"].as_array().unwrap();
    // Two caps, then one photon count.
    assert_eq!(rows.len(), 3);
    let (one, four) = (&rows[0], &rows[1]);
    assert_eq!(one["setting"], "k=2 tol=1e-4 max_orders=1 f32");
    assert_eq!((one["orders"].as_u64(), four["orders"].as_u64()), (Some(1), Some(4)), "{rows:?}");
    // Single scattering alone misses the multiply scattered light (albedo 0.8): a larger error.
    let (e1, e4) = (one["relative_l2"].as_f64().unwrap(), four["relative_l2"].as_f64().unwrap());
    assert!(e1 > 2.0 * e4, "cap 1: {e1}, cap 4: {e4}");
    assert!(out.join("runs/lpm-k2-tol1e-4-orders1-f32/report.json").exists());
}

/// `--sky-directions` runs every setting with each `sky_directions_per_face` (0: the sky on the k×k
/// directions), and a scene's own value below a `--k` is dropped rather than making the run's scene
/// invalid.
#[test]
fn bench_accuracy_sky_directions_run_each_value_and_fit_every_k() {
    let dir = temp_dir("cli-accuracy-sky");
    let text = SMALL
        .replace("dims = [20, 17, 23]", "dims = [8, 8, 8]")
        .replace("sigma_t = [1.0, 0.8, 0.6]", "sigma_t = 0.8")
        .replace("directions_per_face = 2\n", "directions_per_face = 2\nsky_directions_per_face = 3\n");
    let scene = write_scene(&dir, &text);
    let run = |out: &std::path::Path, extra: &[&str]| {
        let mut args = vec!["bench", "accuracy", scene.to_str().unwrap(), "--out", out.to_str().unwrap()];
        args.extend_from_slice(&["--tolerances", "1e-2", "--precisions", "f32", "--samples", "2e4"]);
        args.extend_from_slice(&["--reference-samples", "2e5", "--max-rel-stderr", "0.3"]);
        args.extend_from_slice(extra);
        let o = lpm(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("accuracy.json")).unwrap()).unwrap();
        report["rows"].as_array().unwrap().clone()
    };
    let rows = run(&dir.join("acc"), &["--k", "2,4", "--sky-directions", "0,6"]);
    let settings: Vec<&str> = rows.iter().map(|r| r["setting"].as_str().unwrap()).collect();
    assert_eq!(
        settings[..4],
        ["k=2 tol=1e-2 f32 sky=2", "k=2 tol=1e-2 f32 sky=6", "k=4 tol=1e-2 f32 sky=4", "k=4 tol=1e-2 f32 sky=6"]
    );
    for (name, sky) in [("lpm-k2-tol1e-2-f32-sky2", 2), ("lpm-k2-tol1e-2-f32-sky6", 6), ("lpm-k4-tol1e-2-f32-sky6", 6)]
    {
        let report: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("acc/runs").join(name).join("report.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(report["plan"]["sky_directions_per_face"], sky, "{name}");
    }
    // The scene's own 3 sky directions per face, with k = 4: dropped, the run goes on.
    let rows = run(&dir.join("own"), &["--k", "4"]);
    assert_eq!(rows[0]["setting"], "k=4 tol=1e-2 f32");
}

/// Where the fields are in the world and how many channels the report speaks of: the NRRD headers
/// carry `space origin` (the first voxel's centre) and `space directions`, the JSON sidecars the
/// volume's corner as `origin`; a grey solve's energy arrays have one entry each, not three.
#[test]
fn outputs_are_placed_in_the_world_and_a_grey_report_has_one_channel() {
    let dir = temp_dir("cli-origin");
    let grey = SMALL
        .replace("sigma_t = [1.0, 0.8, 0.6]", "sigma_t = 1.0")
        .replace("voxel_size = 0.5", "voxel_size = 0.5\norigin = [-3.0, 2.0, 10.5]")
        .replace("max_orders = 6", "max_orders = 2");
    let scene = write_scene(&dir, &grey);
    let out = dir.join("out");
    let o = lpm(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--backend", "cpu", "--no-image"]);
    assert!(o.status.success(), "{}", stderr(&o));
    for base in ["fluence", "source"] {
        let nhdr = std::fs::read_to_string(out.join(format!("{base}.nhdr"))).unwrap();
        assert!(nhdr.contains("space origin: (-2.75,2.25,10.75)\n"), "{nhdr}");
        assert!(nhdr.contains("space directions: (0.5,0,0) (0,0.5,0) (0,0,0.5)\n"), "{nhdr}");
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join(format!("{base}.json"))).unwrap()).unwrap();
        assert_eq!(json["origin"], serde_json::json!([-3.0, 2.0, 10.5]));
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["plan"]["channels"], 1);
    let energy = &report["energy"];
    for key in ["boundary_in", "emitted", "point_lights", "boundary_out", "absorbed", "absorptance", "unpropagated"] {
        assert_eq!(energy[key].as_array().map(Vec::len), Some(1), "{key}: {energy}");
    }
    for face in energy["faces"].as_array().unwrap() {
        for key in ["power_in", "power_out", "reflectance", "transmittance"] {
            assert_eq!(face[key].as_array().map(Vec::len), Some(1), "{key}: {face}");
        }
    }
    assert!(energy["absorptance"][0].as_f64().unwrap() > 0.0);
    let o = lpm(&["info", out.to_str().unwrap()]);
    assert!(o.status.success() && String::from_utf8_lossy(&o.stdout).contains("faces     -x in "), "{}", stderr(&o));
}
