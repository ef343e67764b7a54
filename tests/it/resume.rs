//! A solve killed mid-order resumes from its last checkpoint and ends bitwise identical to an
//! uninterrupted one; the kill leaves no half-written output behind.
use crate::common::{killable_cloud_scene, temp_dir};

fn lpm(args: &[&str], abort_at: Option<u32>) -> std::process::Output {
    let mut cmd = crate::common::lpm_command(args);
    if let Some(n) = abort_at {
        // The hook is compiled into lpm only with the `test-hooks` feature: without it the solve
        // would simply finish, and this test would test nothing.
        if !cfg!(feature = "test-hooks") {
            panic!(
                "this kill test needs lpm's test hook: run it with `cargo test --features test-hooks` (tools/test.sh does)"
            );
        }
        cmd.env("LPM_TEST_ABORT_AT_SLICE", n.to_string());
    }
    cmd.output().expect("run lpm")
}

/// Runs lpm to completion (no kill) and fails the test with its stderr if it did not succeed.
fn lpm_ok(args: &[&str]) {
    let o = lpm(args, None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// The exported fields and exitance maps of a resumed solve are byte for byte those of the
/// uninterrupted one (the checkpoint keeps the maps of the orders it holds).
fn assert_same_fields(whole: &std::path::Path, cut: &std::path::Path, context: &str) {
    for f in ["fluence.raw", "source.raw"] {
        assert!(std::fs::read(whole.join(f)).unwrap() == std::fs::read(cut.join(f)).unwrap(), "{f} differs {context}");
    }
    let maps: Vec<_> = std::fs::read_dir(whole.join("faces"))
        .expect("the uninterrupted solve's faces/")
        .map(|e| e.unwrap().file_name())
        .filter(|name| name.to_string_lossy().ends_with(".raw"))
        .collect();
    assert_eq!(maps.len(), 6, "one map per face");
    for name in maps {
        let (a, b) = (whole.join("faces").join(&name), cut.join("faces").join(&name));
        let resumed = std::fs::read(&b).unwrap_or_else(|e| panic!("{}: {e} {context}", b.display()));
        assert!(std::fs::read(&a).unwrap() == resumed, "faces/{} differs {context}", name.to_string_lossy());
    }
}

#[test]
fn killed_solve_resumes_to_the_same_bits() {
    let dir = temp_dir("resume");
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, killable_cloud_scene([34, 30, 38], 5)).unwrap();
    let (whole, cut) = (dir.join("whole"), dir.join("cut"));
    let s = scene.to_str().unwrap();

    lpm_ok(&["solve", s, "--out", whole.to_str().unwrap(), "--no-image"]);

    // Killed in the middle of a later order: order 0 computes slices 1–18 here, every later
    // order 12 (its faces), so slice 36 lies in order 2.
    let o = lpm(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image"], Some(36));
    assert!(!o.status.success(), "the solve should have been killed");
    let checkpoint: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(cut.join(".lpm-work/checkpoint.json")).expect("checkpoint"))
            .unwrap();
    let done = checkpoint["state"]["orders_done"].as_u64().unwrap();
    assert!((1..5).contains(&done), "killed after {done} orders");
    for f in ["fluence.raw", "source.raw", "report.json"] {
        assert!(!cut.join(f).exists(), "{f} written before the solve finished");
    }

    lpm_ok(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image", "--resume"]);
    assert_same_fields(&whole, &cut, "after resume");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(cut.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["orders"], 5);
    assert_eq!(report["history"].as_array().unwrap().len(), 5);
    assert!(!cut.join(".lpm-work").exists(), "the work store is removed after success");
}

#[test]
fn resume_with_nothing_to_resume_starts_fresh_and_cpu_refuses() {
    let dir = temp_dir("resume-fresh");
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, killable_cloud_scene([34, 30, 38], 1)).unwrap();
    let out = dir.join("out");
    let o = lpm(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-image", "--resume"], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o =
        lpm(&["solve", scene.to_str().unwrap(), "--out", out.to_str().unwrap(), "--resume", "--backend", "cpu"], None);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--resume needs the GPU backend"));
}

/// SIGTERM (what `lpm serve` sends to cancel a job, and Slurm before it preempts a task) stops the
/// solve at its next slice: exit status 3, the checkpoint kept, no output written; `--resume`
/// then ends bitwise identical to an uninterrupted solve.
#[test]
fn sigterm_stops_at_a_slice_keeps_the_checkpoint_and_resumes_to_the_same_bits() {
    let dir = temp_dir("resume-sigterm");
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, killable_cloud_scene([34, 30, 38], 6)).unwrap();
    let (whole, cut) = (dir.join("whole"), dir.join("cut"));
    let s = scene.to_str().unwrap();
    let o = lpm(&["solve", s, "--out", whole.to_str().unwrap(), "--no-image"], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let mut child = crate::common::lpm_command(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image"])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // After the first checkpointed order, in the middle of a later one.
    let t = std::time::Instant::now();
    loop {
        let order = std::fs::read(cut.join("progress.json"))
            .ok()
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .and_then(|p| p["order"].as_u64());
        if order.is_some_and(|o| o >= 1) {
            break;
        }
        assert!(child.try_wait().unwrap().is_none(), "the solve ended before it could be stopped");
        assert!(t.elapsed() < std::time::Duration::from_secs(300), "no second order after 300 s");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // SAFETY: kill(2) on our own child, not yet reaped.
    assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) }, 0);
    let o = child.wait_with_output().unwrap();
    let checkpoint = cancelled_with_a_checkpoint(&o, &cut);
    let done = checkpoint["state"]["orders_done"].as_u64().unwrap();
    assert!((2..6).contains(&done), "stopped after {done} orders");
    for f in ["fluence.raw", "source.raw", "report.json"] {
        assert!(!cut.join(f).exists(), "{f} written by a cancelled solve");
    }

    let o = lpm(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image", "--resume"], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_same_fields(&whole, &cut, "after resume");
}

/// Asserts that `o` is a cancelled solve's (exit status 3, saying its checkpoint is kept) and
/// returns the checkpoint it kept in `cut`'s work store.
fn cancelled_with_a_checkpoint(o: &std::process::Output, cut: &std::path::Path) -> serde_json::Value {
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("the solve was cancelled; its last checkpoint is kept"), "{stderr}");
    serde_json::from_str(&std::fs::read_to_string(cut.join(".lpm-work/checkpoint.json")).expect("checkpoint")).unwrap()
}

/// The six-order cloud checkpointed every other order (`solver.checkpoint_every_orders = 2`) and
/// streamed (`solver.device_residency`), as `dir/scene.toml`, and its uninterrupted solve in
/// `dir/whole`.
fn every_other_order_streamed(dir: &std::path::Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let scene = dir.join("scene.toml");
    let text = killable_cloud_scene([34, 30, 38], 6).replace(
        "checkpoint_every_orders = 1\n",
        "checkpoint_every_orders = 2\ncheckpoint_every_seconds = 1e9\ndevice_residency = \"streamed\"\n",
    );
    std::fs::write(&scene, text).unwrap();
    let whole = dir.join("whole");
    lpm_ok(&["solve", scene.to_str().unwrap(), "--out", whole.to_str().unwrap(), "--no-image"]);
    (scene, whole)
}

/// Checkpoints every other order (`solver.checkpoint_every_orders = 2`): a solve killed after an
/// order that was not checkpointed resumes from the checkpoint before it, whose fields the
/// uncheckpointed orders left alone (the diffusion correction writes a source field no checkpoint
/// names), to the same bits.
/// Streamed (`solver.device_residency`), so the kill tests cover both modes: the others run
/// device-resident.
#[test]
fn killed_between_checkpoints_resumes_to_the_same_bits() {
    let dir = temp_dir("resume-cadence");
    let (scene, whole) = every_other_order_streamed(&dir);
    let s = scene.to_str().unwrap();

    let mut skipped = false;
    // Slices of orders 3 and 5 (order 0 computes slices 1–15 here, every later order 12): both
    // after an order without a checkpoint.
    for abort_at in [46, 68] {
        let cut = dir.join(format!("cut-{abort_at}"));
        let o = lpm(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image"], Some(abort_at));
        assert!(!o.status.success(), "the solve should have been killed");
        let json = |p: std::path::PathBuf| -> serde_json::Value {
            serde_json::from_str(&std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display())))
                .unwrap()
        };
        let done = json(cut.join(".lpm-work/checkpoint.json"))["state"]["orders_done"].as_u64().unwrap();
        assert!(done % 2 == 0 && (2..6).contains(&done), "checkpoint after {done} orders");
        // progress.json counts every completed order, checkpointed or not.
        let completed = json(cut.join("progress.json"))["order"].as_u64().unwrap() + 1;
        skipped |= completed > done;
        lpm_ok(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image", "--resume"]);
        assert_same_fields(&whole, &cut, &format!("after resume (killed at slice {abort_at})"));
    }
    assert!(skipped, "no kill landed after an order without a checkpoint: move the abort points");
}

/// A solve cancelled (as SIGTERM does; the test hook raises the flag at a chosen slice) in an order
/// after one the cadence did not checkpoint checkpoints that order's state as it stops, with the
/// exitance maps as they were when it ended (the cancelled order had added some of its own): the
/// resumed solve's fields and maps are the uninterrupted one's, bit for bit.
#[test]
fn cancelled_after_an_order_without_a_checkpoint_keeps_that_order_maps_and_all() {
    if !cfg!(feature = "test-hooks") {
        panic!("this test needs lpm's test hooks: run it with `cargo test --features test-hooks`");
    }
    let dir = temp_dir("resume-cancel-pending");
    // Streamed: a device-resident solve committed the order on the device, whose state a cancel
    // cannot bring home, so it keeps the checkpoint before.
    let (scene, whole) = every_other_order_streamed(&dir);
    let s = scene.to_str().unwrap();
    let cut = dir.join("cut");

    // A slice of the fourth order (order 0 computes slices 1–15 here, every later order 12): the
    // third completed without a checkpoint (due after two and four).
    let o = crate::common::lpm_command(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image"])
        .env("LPM_TEST_CANCEL_AT_SLICE", "46")
        .output()
        .unwrap();
    let checkpoint = cancelled_with_a_checkpoint(&o, &cut);
    assert_eq!(checkpoint["state"]["orders_done"], 3, "the cancel checkpoints the order the cadence skipped");
    assert_eq!(checkpoint["exits"], "exits_3.f64");

    lpm_ok(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image", "--resume"]);
    assert_same_fields(&whole, &cut, "after resume");
}

/// Checkpoints are written in the background while the next order's sweeps run: a solve killed
/// while one is still being written (the test hook holds it back just before `checkpoint.json`)
/// resumes from the one before it, whose fields that order's sweeps left alone, to the same bits.
#[test]
fn killed_while_a_checkpoint_is_written_resumes_from_the_one_before() {
    if !cfg!(feature = "test-hooks") {
        panic!("this kill test needs lpm's test hooks: run it with `cargo test --features test-hooks`");
    }
    let dir = temp_dir("resume-writing");
    let scene = dir.join("scene.toml");
    // The diffusion correction checkpoints every order; the acceleration writes a correction file
    // before each checkpoint.json, which shows which checkpoint was in flight.
    std::fs::write(&scene, killable_cloud_scene([34, 30, 38], 6)).unwrap();
    let s = scene.to_str().unwrap();
    let (whole, cut) = (dir.join("whole"), dir.join("cut"));
    let o = lpm(&["solve", s, "--out", whole.to_str().unwrap(), "--no-image"], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let o = crate::common::lpm_command(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image"])
        // A slice of order 2 (order 0 computes slices 1–18, every later order 12): order 0's
        // checkpoint is on disk by then, order 1's in flight.
        .env("LPM_TEST_ABORT_AT_SLICE", "36")
        .env("LPM_TEST_CHECKPOINT_DELAY_MS", "3000")
        .output()
        .unwrap();
    assert!(!o.status.success(), "the solve should have been killed");
    let json = |p: std::path::PathBuf| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))).unwrap()
    };
    let checkpoint = json(cut.join(".lpm-work/checkpoint.json"));
    let done = checkpoint["state"]["orders_done"].as_u64().unwrap();
    let completed = json(cut.join("progress.json"))["order"].as_u64().unwrap() + 1;
    assert_eq!(completed, done + 1, "the checkpoint of the last completed order should have been in flight");
    assert_eq!(checkpoint["correction"], format!("correction_{done}.f64"));
    assert_eq!(checkpoint["exits"], format!("exits_{done}.f64"), "the exitance maps kept beside it");
    assert!(
        cut.join(format!(".lpm-work/correction_{completed}.f64")).exists(),
        "the in-flight checkpoint's correction file should be there"
    );
    let o = lpm(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image", "--resume"], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_same_fields(&whole, &cut, "after resuming from the checkpoint before the one in flight");
    assert!(!cut.join(".lpm-work").exists(), "the work store is removed after success");
}

/// A periodic solve carries ray state from one order into the next (what its sweeps along the
/// periodic axis carried out of the far face): the checkpoint saves it (`carry_<orders>.f64`), so a
/// killed periodic solve also resumes to the same bits.
#[test]
fn a_killed_periodic_solve_resumes_to_the_same_bits() {
    let dir = temp_dir("resume-periodic");
    let scene = dir.join("scene.toml");
    // The diffusion acceleration does not take periodic axes; the correction and its third
    // source file still rotate through the checkpoints.
    let text = killable_cloud_scene([34, 30, 38], 5).replace("acceleration = \"diffusion\"", "acceleration = \"off\"")
        + "[boundary]\nx = \"periodic\"\ny = \"periodic\"\n";
    std::fs::write(&scene, text).unwrap();
    let (whole, cut) = (dir.join("whole"), dir.join("cut"));
    let s = scene.to_str().unwrap();
    lpm_ok(&["solve", s, "--out", whole.to_str().unwrap(), "--no-image"]);

    // A slice of order 2 (as above).
    let o = lpm(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image"], Some(36));
    assert!(!o.status.success(), "the solve should have been killed");
    let work = cut.join(".lpm-work");
    let checkpoint: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(work.join("checkpoint.json")).expect("checkpoint")).unwrap();
    let done = checkpoint["state"]["orders_done"].as_u64().unwrap();
    assert!((1..5).contains(&done), "killed after {done} orders");
    let carry = checkpoint["carry"].as_str().expect("the checkpoint names the carried ray state");
    assert_eq!(carry, format!("carry_{done}.f64"));
    assert!(work.join(carry).exists());

    lpm_ok(&["solve", s, "--out", cut.to_str().unwrap(), "--no-image", "--resume"]);
    assert_same_fields(&whole, &cut, "after resume");
}

/// The report's fields that two runs of one solve share, as JSON text (equal text: equal bits,
/// as serde_json writes each f64 in the shortest form that reads back to it): all but the
/// timings, the peaks and the host memory budget (half of what the system has free then), which
/// any two runs may differ in.
fn same_in_any_run(report: &std::path::Path) -> Vec<(String, String)> {
    let mut r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(report).unwrap()).unwrap();
    r["host_memory"].as_object_mut().unwrap().retain(|k, _| k == "store_bytes");
    let mut kept: Vec<(String, String)> = r
        .as_object()
        .unwrap()
        .iter()
        .filter(|(k, _)| !["seconds", "peak_device_bytes", "peak_resident_bytes", "history"].contains(&k.as_str()))
        .map(|(k, v)| (k.clone(), v.to_string()))
        .collect();
    for (i, order) in r["history"].as_array().unwrap().iter().enumerate() {
        let mut order = order.clone();
        order.as_object_mut().unwrap().remove("seconds");
        kept.push((format!("history[{i}]"), order.to_string()));
    }
    kept
}

/// Issue 57, item 4: a solve killed after its last order, in the export or in the render (as
/// `kill -9` or SIGTERM would), resumes to the uninterrupted report, bit for bit: its
/// `remaining_error` is the one the order loop measured (the checkpoint keeps it; measured again
/// it differed), and its `store_bytes` the store's (not the killed render's fields left in it).
#[test]
fn killed_in_the_export_or_the_render_resumes_to_the_same_report() {
    if !cfg!(feature = "test-hooks") {
        panic!("this kill test needs lpm's test hooks: run it with `cargo test --features test-hooks`");
    }
    let dir = temp_dir("resume-after-last-order");
    let scene = dir.join("scene.toml");
    // Six orders, so that the stop rule's tail factors use the ratio's drift (from the fourth
    // order on), whose shrink ratio reads the history; a checkpoint after every order.
    let text = killable_cloud_scene([34, 30, 38], 6)
        .replace("checkpoint_every_orders = 1\n", "checkpoint_every_seconds = 0\n")
        + "[camera]\nwidth = 48\nheight = 32\n";
    std::fs::write(&scene, text).unwrap();
    let s = scene.to_str().unwrap();
    let whole = dir.join("whole");
    lpm_ok(&["solve", s, "--out", whole.to_str().unwrap()]);
    let expected = same_in_any_run(&whole.join("report.json"));
    for (stage, hook) in [
        ("export", "LPM_TEST_ABORT_AT_STAGE"),
        ("export", "LPM_TEST_CANCEL_AT_STAGE"),
        ("render", "LPM_TEST_ABORT_AT_STAGE"),
        ("render", "LPM_TEST_CANCEL_AT_STAGE"),
    ] {
        let cut = dir.join(format!("cut-{stage}-{hook}"));
        let o = crate::common::lpm_command(&["solve", s, "--out", cut.to_str().unwrap()])
            .env(hook, stage)
            .output()
            .unwrap();
        let context = format!("after {hook}={stage}");
        assert!(!o.status.success(), "the solve should have been stopped {context}");
        let work = cut.join(".lpm-work");
        let checkpoint: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(work.join("checkpoint.json")).expect("checkpoint")).unwrap();
        assert_eq!(checkpoint["state"]["orders_done"], 6, "{context}");
        if stage == "render" {
            assert!(work.join("render_source.field").exists(), "the render's fields should be in the store {context}");
        }
        assert!(!cut.join("report.json").exists(), "report.json written {context}");
        lpm_ok(&["solve", s, "--out", cut.to_str().unwrap(), "--resume"]);
        assert_same_fields(&whole, &cut, &context);
        let resumed = same_in_any_run(&cut.join("report.json"));
        for ((key, want), (_, got)) in expected.iter().zip(&resumed) {
            assert_eq!(want, got, "report.json's {key} differs {context}");
        }
        assert_eq!(expected.len(), resumed.len(), "{context}");
    }
}
