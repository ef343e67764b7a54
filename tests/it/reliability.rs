//! Issue 13, "nothing lost, nothing garbage, nothing let in": one test (at least) per defect found
//! by hostile use, each failing before its fix. Fault injection: a full disk (a small tmpfs, or
//! RLIMIT_FSIZE where mounting is not allowed), a solve killed with SIGKILL then resumed, two
//! solves into one --out.
use crate::common::{lpm_command, temp_dir, write_scene, write_scene_as};
use lpm::scene::Scene;
use std::path::{Path, PathBuf};
use std::process::Output;

const SMALL: &str = r#"
[volume]
procedural = "sphere"
dims = [16, 16, 16]
[medium]
sigma_t = 0.3
albedo = 0.6
[[lights]]
kind = "sky"
radiance = 1.0
[solver]
directions_per_face = 2
max_orders = 2
"#;

fn run(args: &[&str]) -> Output {
    lpm_command(args).output().expect("run lpm")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

fn scene_err(text: &str) -> String {
    Scene::from_toml_str(text, Path::new("t.toml")).expect_err("the scene should be refused").to_string()
}

// ---- 1: disk full ------------------------------------------------------------------------------

/// A tmpfs of `size` mounted on a fresh directory, unmounted on drop; `None` where mounting is not
/// allowed (not root, no CAP_SYS_ADMIN).
struct Tmpfs(PathBuf);
impl Tmpfs {
    fn mount(name: &str, size: &str) -> Option<Tmpfs> {
        let dir = temp_dir(name);
        let ok = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs", s(&dir)])
            .stderr(std::process::Stdio::null())
            .status()
            .is_ok_and(|st| st.success());
        ok.then_some(Tmpfs(dir))
    }
}
impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount").arg(&self.0).status();
    }
}

const RGB48: &str = r#"
[volume]
procedural = "box"
dims = [48, 48, 48]
[medium]
sigma_t = [0.3, 0.2, 0.1]
albedo = 0.8
[[lights]]
kind = "sky"
radiance = 1.0
[solver]
directions_per_face = 1
max_orders = 2
"#;

/// Runs `lpm solve` into `out`, on a small tmpfs when one can be mounted, else under a file size
/// limit (RLIMIT_FSIZE, with SIGXFSZ ignored so the write fails with EFBIG instead of killing).
fn solve_with_little_space(scene: &Path, out: &Path, bytes: u64, on_tmpfs: bool) -> Output {
    let mut cmd = lpm_command(&["solve", s(scene), "--out", s(out), "--backend", "cpu", "--no-image"]);
    if !on_tmpfs {
        use std::os::unix::process::CommandExt;
        // SAFETY: only async-signal-safe calls between fork and exec.
        unsafe {
            cmd.pre_exec(move || {
                libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
                let lim = libc::rlimit { rlim_cur: bytes, rlim_max: bytes };
                libc::setrlimit(libc::RLIMIT_FSIZE, &lim);
                Ok(())
            });
        }
    }
    cmd.output().expect("run lpm")
}

#[test]
fn a_full_disk_is_a_clear_error_at_every_point_not_a_sigbus() {
    let dir = temp_dir("rel-disk");
    let scene = write_scene(&dir, RGB48);
    // 8 MiB: the exports (2.6 MB) pass the up-front check, the store's fields do not fit.
    // 1 MiB: the up-front check refuses before anything is built.
    for (size, bytes, expect) in [("8m", 8u64 << 20, "not enough disk space"), ("1m", 1 << 20, "not enough disk space")]
    {
        let fs = Tmpfs::mount(&format!("rel-disk-{size}"), size);
        let out = match &fs {
            Some(t) => t.0.join("out"),
            None => dir.join(format!("out-{size}")),
        };
        let o = solve_with_little_space(&scene, &out, bytes, fs.is_some());
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "a signal or success at {size}: {:?}\n{err}", o.status);
        assert!(err.contains(expect) && (err.contains("needed") || err.contains("needs")), "{size}: {err}");
        assert!(err.contains("free"), "{size}: the free space is named: {err}");
        assert!(!out.join(".lpm-work").exists(), "{size}: the failed store is removed, freeing the disk");
    }
}

#[test]
fn absurd_dims_are_refused_up_front_naming_sizes() {
    let dir = temp_dir("rel-dims");
    let scene = write_scene(&dir, &SMALL.replace("[16, 16, 16]", "[65536, 65536, 256]"));
    let t = std::time::Instant::now();
    let o = run(&["solve", s(&scene), "--out", s(&dir.join("out")), "--backend", "cpu"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("not enough disk space") && err.contains("needed") && err.contains("free"), "{err}");
    assert!(err.contains("TiB"), "{err}");
    assert!(t.elapsed().as_secs() < 30, "refused before building anything");
}

// ---- 3: garbage in, garbage out ----------------------------------------------------------------

#[test]
fn huge_lights_are_refused_and_huge_directions_normalised() {
    for (key, text) in [
        ("lights[0].radiance", SMALL.replace("radiance = 1.0", "radiance = 1e308")),
        (
            "lights[1].irradiance",
            format!("{SMALL}\n[[lights]]\nkind = \"sun\"\ndirection = [0, 0, 1]\nirradiance = 1e308\n"),
        ),
        ("medium.emission", SMALL.replace("albedo = 0.6", "albedo = 0.6\nemission = 1e308")),
    ] {
        let e = scene_err(&text);
        assert!(e.contains(key) && e.contains("1e12") && e.contains("1e308"), "{e}");
    }
    let sun = format!("{SMALL}\n[[lights]]\nkind = \"sun\"\ndirection = [1e308, 1e308, 1e308]\nirradiance = 2\n");
    let scene = Scene::from_toml_str(&sun, Path::new("t.toml")).unwrap();
    let lpm::scene::Light::Sun { direction, .. } = scene.lights[1] else { panic!() };
    assert!((direction - glam::DVec3::splat(1.0 / 3f64.sqrt())).length() < 1e-15, "{direction}");
    let tiny = sun.replace("1e308", "1e-310");
    let scene = Scene::from_toml_str(&tiny, Path::new("t.toml")).unwrap();
    let lpm::scene::Light::Sun { direction, .. } = scene.lights[1] else { panic!() };
    assert!((direction.length() - 1.0).abs() < 1e-15, "{direction}");

    // And it solves to finite values end to end.
    let dir = temp_dir("rel-sun");
    let path = write_scene(&dir, &sun);
    let out = dir.join("out");
    let o = run(&["solve", s(&path), "--out", s(&out), "--backend", "cpu", "--no-image"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (_, fluence) = lpm::output::read_raw_field(&out, "fluence").unwrap();
    assert!(fluence.iter().any(|v| v.is_finite() && *v > 0.0));
    assert!(fluence.iter().all(|v| v.is_nan() || (v.is_finite() && *v >= 0.0)));
}

#[test]
fn an_all_zero_raw_volume_is_refused_not_converged_with_nan() {
    let dir = temp_dir("rel-zero");
    std::fs::write(dir.join("zero.raw"), vec![0u8; 16 * 16 * 16 * 4]).unwrap();
    let scene = write_scene(&dir, &SMALL.replace("procedural = \"sphere\"", "raw = \"zero.raw\""));
    let o = run(&["solve", s(&scene), "--out", s(&dir.join("out")), "--backend", "cpu"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("no medium"), "{}", stderr(&o));
    assert!(!dir.join("out").exists(), "nothing left behind");
}

/// `lpm compare` called NaN anywhere "not solved"; now only a brick that is NaN throughout in a
/// field marked `not_solved` is, and a NaN in a solved voxel fails the comparison. Also
/// `--fail-above`.
#[test]
fn compare_fails_on_nan_in_a_solved_voxel_and_on_fail_above() {
    let dir = temp_dir("rel-compare");
    let scene = write_scene(&dir, SMALL);
    let (a, b) = (dir.join("a"), dir.join("b"));
    for out in [&a, &b] {
        let o = run(&["solve", s(&scene), "--out", s(out), "--backend", "cpu", "--no-image"]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let o = run(&["compare", s(&a), s(&b), "--fail-above", "0"]);
    assert!(o.status.success(), "identical runs: error 0 ≤ 0: {}", stderr(&o));
    // One voxel of the candidate made NaN, in the middle of the (solved) sphere.
    let raw = a.join("fluence.raw");
    let mut bytes = std::fs::read(&raw).unwrap();
    let i = (8 + 16 * (8 + 16 * 8)) * 4;
    bytes[i..i + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&raw, &bytes).unwrap();
    let o = run(&["compare", s(&a), s(&b)]);
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stdout));
    assert!(stderr(&o).contains("non-finite") && stderr(&o).contains("(8, 8, 8)"), "{}", stderr(&o));
    // A small real difference: passes a loose limit, fails a tight one with status 2.
    bytes[i..i + 4].copy_from_slice(
        &(1.01f32 * f32::from_le_bytes(std::fs::read(b.join("fluence.raw")).unwrap()[i..i + 4].try_into().unwrap()))
            .to_le_bytes(),
    );
    std::fs::write(&raw, &bytes).unwrap();
    assert!(run(&["compare", s(&a), s(&b), "--fail-above", "0.1"]).status.success());
    let o = run(&["compare", s(&a), s(&b), "--fail-above", "1e-9"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("above the limit"), "{}", stderr(&o));
}

// ---- 4: arrays longer than 3 -------------------------------------------------------------------

#[test]
fn arrays_of_other_than_three_values_are_refused() {
    let cam = "\n[camera]\nposition = [40, 8, 8]\nlook_at = [8, 8, 8]\nup = [0, 0, 1]\n";
    let sun = "\n[[lights]]\nkind = \"sun\"\ndirection = [0, 0, 1]\nirradiance = 1\n";
    let base = format!("{SMALL}{sun}{cam}");
    Scene::from_toml_str(&base, Path::new("t.toml")).expect("the base scene is valid");
    for (from, to, key) in [
        ("dims = [16, 16, 16]", "dims = [16, 16, 16, 16]", "volume.dims"),
        ("direction = [0, 0, 1]", "direction = [0, 0, 1, 5]", "direction"),
        ("position = [40, 8, 8]", "position = [40, 8, 8, 1]", "camera.position"),
        ("look_at = [8, 8, 8]", "look_at = [8, 8, 8, 8]", "camera.look_at"),
        ("up = [0, 0, 1]", "up = [0, 0, 1, 0]", "camera.up"),
        ("dims = [16, 16, 16]", "dims = [16, 16]", "volume.dims"),
    ] {
        let e = scene_err(&base.replace(from, to));
        assert!(e.contains(key) && e.contains("exactly 3"), "{to}: {e}");
    }
}

// ---- 5: two solves into one --out --------------------------------------------------------------

#[test]
fn a_second_solve_into_a_locked_out_fails_clearly() {
    let dir = temp_dir("rel-lock");
    let scene = write_scene(&dir, SMALL);
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let held = lpm::output::DirLock::acquire(&out).unwrap();
    let o = run(&["solve", s(&scene), "--out", s(&out), "--backend", "cpu"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("another lpm run is writing to this directory"), "{}", stderr(&o));
    drop(held);
    assert!(run(&["solve", s(&scene), "--out", s(&out), "--backend", "cpu"]).status.success());
}

#[test]
fn two_concurrent_solves_into_one_out_never_mix() {
    let dir = temp_dir("rel-concurrent");
    let scene = write_scene(&dir, &SMALL.replace("[16, 16, 16]", "[40, 40, 40]"));
    let out = dir.join("out");
    let spawn = || {
        lpm_command(&["solve", s(&scene), "--out", s(&out), "--backend", "cpu", "--no-image"])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (a, b) = (spawn(), spawn());
    let results = [a.wait_with_output().unwrap(), b.wait_with_output().unwrap()];
    assert!(results.iter().any(|o| o.status.success()), "one solve at least succeeds");
    for o in results.iter().filter(|o| !o.status.success()) {
        assert!(stderr(o).contains("another lpm run"), "a failure is only ever the lock: {}", stderr(o));
    }
    assert_eq!(
        names(&out),
        [
            "faces",
            "fluence.json",
            "fluence.nhdr",
            "fluence.raw",
            "fluence.vdb",
            "render-data",
            "report.json",
            "source.json",
            "source.nhdr",
            "source.raw",
            "source.vdb"
        ]
    );
}

// ---- 6: stale temporaries, outputs as a set ----------------------------------------------------

#[test]
fn stale_temporaries_are_cleaned_and_a_rerun_replaces_the_whole_set() {
    let dir = temp_dir("rel-set");
    let scene = write_scene(&dir, SMALL);
    let out = dir.join("out");
    assert!(run(&["solve", s(&scene), "--out", s(&out), "--backend", "cpu"]).status.success());
    assert!(out.join("image.exr").exists() && out.join("image.png").exists());
    // What killed runs leave: the old scheme's and the new scheme's temporaries, a staging dir.
    std::fs::write(out.join("source.raw.tmp-4242"), b"junk").unwrap();
    std::fs::write(out.join(".fluence.raw.Zx81qP.lpm-tmp"), b"junk").unwrap();
    std::fs::create_dir(out.join(".lpm-staging-abc")).unwrap();
    std::fs::write(out.join("notes.txt"), b"mine").unwrap();
    let o = run(&["solve", s(&scene), "--out", s(&out), "--backend", "cpu", "--no-image"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        names(&out),
        [
            "faces",
            "fluence.json",
            "fluence.nhdr",
            "fluence.raw",
            "fluence.vdb",
            "notes.txt",
            "render-data",
            "report.json",
            "source.json",
            "source.nhdr",
            "source.raw",
            "source.vdb"
        ],
        "no temporaries, no old image.*, the user's file kept"
    );
}

// ---- 8: resume ---------------------------------------------------------------------------------

#[test]
fn a_checkpoint_is_never_silently_discarded() {
    let dir = temp_dir("rel-checkpoint");
    let scene = write_scene(&dir, SMALL);
    let out = dir.join("out");
    std::fs::create_dir_all(out.join(".lpm-work")).unwrap();
    std::fs::write(out.join(".lpm-work/checkpoint.json"), b"{}").unwrap();
    let o = run(&["solve", s(&scene), "--out", s(&out), "--backend", "cpu"]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(err.contains("unfinished solve") && err.contains("--resume") && err.contains("--fresh"), "{err}");
    assert!(out.join(".lpm-work/checkpoint.json").exists(), "the checkpoint is kept");
    let o = run(&["solve", s(&scene), "--out", s(&out), "--backend", "cpu", "--fresh"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!out.join(".lpm-work").exists());
}

#[test]
fn the_camera_does_not_change_the_checkpoint_digest() {
    let cam = |x: i32| format!("{SMALL}\n[camera]\nposition = [{x}, 8, 8]\nlook_at = [8, 8, 8]\nwidth = 64\n");
    let digest = |t: &str| lpm::solver::scene_digest(&Scene::from_toml_str(t, Path::new("t.toml")).unwrap());
    assert_eq!(digest(&cam(40)), digest(&cam(-40)));
    assert_eq!(digest(&cam(40)), digest(SMALL));
    assert_ne!(digest(SMALL), digest(&SMALL.replace("albedo = 0.6", "albedo = 0.7")));
}

#[test]
fn f64_tallies_round_trip_through_json_exactly() {
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    for _ in 0..100_000 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let v = f64::from_bits(x);
        if !v.is_finite() {
            continue;
        }
        let back: f64 = serde_json::from_str(&serde_json::to_string(&v).unwrap()).unwrap();
        assert_eq!(back.to_bits(), v.to_bits(), "{v:e}");
    }
}

/// `kill -9` in the middle of a GPU solve, then `--resume`: bitwise the fields of an uninterrupted
/// solve, and the same report (everything but wall-clock times and memory peaks).
#[test]
fn sigkill_during_solve_then_resume_gives_identical_fields_and_report() {
    let dir = temp_dir("rel-kill");
    let scene = write_scene(
        &dir,
        &SMALL
            .replace("[16, 16, 16]", "[40, 36, 44]")
            .replace("max_orders = 2", "max_orders = 6\ntolerance = 1e-12\ncheckpoint_every_seconds = 0"),
    );
    let (whole, cut) = (dir.join("whole"), dir.join("cut"));
    let o = run(&["solve", s(&scene), "--out", s(&whole), "--no-image"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut child = lpm_command(&["solve", s(&scene), "--out", s(&cut), "--no-image"]).spawn().unwrap();
    let checkpoint = cut.join(".lpm-work/checkpoint.json");
    let t = std::time::Instant::now();
    while !checkpoint.exists() && t.elapsed().as_secs() < 300 {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    child.kill().unwrap(); // SIGKILL
    let status = child.wait().unwrap();
    if status.success() {
        // Finished before the kill landed: nothing to resume, the test proves nothing this time;
        // the scene is sized so that this does not happen.
        panic!("the solve finished before it could be killed; make the scene larger");
    }
    assert!(checkpoint.exists());
    let o = run(&["solve", s(&scene), "--out", s(&cut), "--no-image", "--resume"]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ["fluence.raw", "source.raw", "fluence.json", "source.json"] {
        assert!(std::fs::read(whole.join(f)).unwrap() == std::fs::read(cut.join(f)).unwrap(), "{f} differs");
    }
    assert_eq!(report_without_timings(&whole), report_without_timings(&cut));
}

/// `DIR/report.json` without what depends on the run rather than the solve: timings, peaks and
/// the host's memory (whose residency line quotes the host's available memory). `store_bytes`
/// stays: it must not depend on the run (issue 35).
fn report_without_timings(dir: &Path) -> serde_json::Value {
    let mut r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    for k in ["seconds", "peak_resident_bytes", "peak_device_bytes", "host_memory"] {
        r.as_object_mut().unwrap().remove(k);
    }
    for h in r["history"].as_array_mut().unwrap() {
        h.as_object_mut().unwrap().remove("seconds");
    }
    r
}

// ---- 9: bounds ---------------------------------------------------------------------------------

#[test]
fn fifo_device_and_oversized_scene_paths_and_too_many_lights_are_refused() {
    let dir = temp_dir("rel-paths");
    let fifo = dir.join("scene.fifo");
    let c = std::ffi::CString::new(s(&fifo)).unwrap();
    // SAFETY: mkfifo with a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let big = write_scene_as(&dir, "big.toml", &format!("{SMALL}\n#{}\n", "x".repeat(2 << 20)));
    for p in [fifo.as_path(), Path::new("/dev/zero"), &big] {
        let e = Scene::load(p).expect_err("refused").to_string();
        assert!(e.contains("not a regular file") || e.contains("limit"), "{e}");
    }
    let raw_fifo = SMALL.replace("procedural = \"sphere\"", &format!("raw = \"{}\"", s(&fifo)));
    assert!(scene_err(&raw_fifo).contains("not a regular file"));
    let mut many = SMALL.to_string();
    for _ in 0..300 {
        many.push_str("\n[[lights]]\nkind = \"sun\"\ndirection = [0, 0, 1]\nirradiance = 1\n");
    }
    let e = scene_err(&many);
    assert!(e.contains("lights") && e.contains("256"), "{e}");
}

// ---- 10: reproducible image, no colours into pipes ---------------------------------------------

#[test]
fn exr_bytes_are_reproducible() {
    let dir = temp_dir("rel-exr");
    let (w, h) = (640u32, 480u32);
    let rgb: Vec<f32> = (0..w * h * 3).map(|i| (i.wrapping_mul(2654435761u32) % 1000) as f32 / 7.0).collect();
    let img = lpm::render::Image { width: w, height: h, rgb, alpha: None };
    let first = dir.join("a.exr");
    lpm::render::write_exr(&first, &img).unwrap();
    for k in 0..8 {
        let p = dir.join(format!("b{k}.exr"));
        lpm::render::write_exr(&p, &img).unwrap();
        assert!(std::fs::read(&first).unwrap() == std::fs::read(&p).unwrap(), "write {k} differs");
    }
}

#[test]
fn logs_into_a_pipe_carry_no_colour_codes_and_errors_say_the_reason_once() {
    let dir = temp_dir("rel-log");
    let scene = write_scene(&dir, SMALL);
    let mut cmd = lpm_command(&["solve", s(&scene), "--out", s(&dir.join("out")), "--backend", "cpu"]);
    let o = cmd.env("LPM_LOG", "info").output().unwrap();
    assert!(o.status.success());
    assert!(!o.stderr.is_empty() && !o.stderr.contains(&0x1b), "{}", stderr(&o));

    let missing = write_scene(&dir, &SMALL.replace("procedural = \"sphere\"", "raw = \"nope.raw\""));
    let o = run(&["solve", s(&missing), "--out", s(&dir.join("o2"))]);
    let err = stderr(&o);
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
    let evil = write_scene_as(&dir, "bad\u{1b}[31mname.toml", "x");
    let o = run(&["solve", s(&evil), "--out", s(&dir.join("o3"))]);
    assert!(!o.stderr.contains(&0x1b), "{}", stderr(&o));
    assert!(stderr(&o).contains("\\u{1b}"), "{}", stderr(&o));
}

/// Issue 13, items 9 and 11: a budget larger than the device is refused, and a budget error names
/// where the budget came from (the flag or the scene key).
#[test]
fn a_budget_larger_than_the_device_is_refused_naming_its_origin() {
    let dir = temp_dir("rel-budget");
    let scene = write_scene(&dir, SMALL);
    let o = run(&["solve", s(&scene), "--out", s(&dir.join("o1")), "--device-memory-budget", "65536T"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("--device-memory-budget") && err.contains("larger than the device"), "{err}");
    let keyed = write_scene_as(&dir, "keyed.toml", &format!("{SMALL}device_memory_budget = \"65536T\"\n"));
    let o = run(&["solve", s(&keyed), "--out", s(&dir.join("o2"))]);
    let err = stderr(&o);
    assert!(err.contains("solver.device_memory_budget") && err.contains("larger than the device"), "{err}");
    let tiny = write_scene_as(&dir, "tiny.toml", &format!("{SMALL}device_memory_budget = 1024\n"));
    let o = run(&["solve", s(&tiny), "--out", s(&dir.join("o3"))]);
    let err = stderr(&o);
    assert!(err.contains("solver.device_memory_budget") && err.contains("too small"), "{err}");
}

/// `kill -9` during export and render (while the staging directory exists), then `--resume`: the
/// outputs are those of an uninterrupted solve, and nothing of the killed run is left in `OUT`.
#[test]
fn sigkill_during_export_then_resume_publishes_the_same_set() {
    let plain =
        SMALL.replace("[16, 16, 16]", "[24, 20, 28]").replace("max_orders = 2", "max_orders = 3\ntolerance = 1e-12");
    // With the diffusion acceleration, whose pending correction enters the energy balance.
    let accelerated =
        plain.replace("albedo = 0.6", "albedo = 0.95").replace("[solver]", "[solver]\nacceleration = \"diffusion\"");
    for (name, text) in [("plain", plain), ("accelerated", accelerated)] {
        kill_during_export_then_resume(name, &text);
    }
}

fn kill_during_export_then_resume(name: &str, text: &str) {
    let dir = temp_dir(&format!("rel-kill-export-{name}"));
    let scene = write_scene(&dir, text);
    let (whole, cut) = (dir.join("whole"), dir.join("cut"));
    let o = run(&["solve", s(&scene), "--out", s(&whole)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut child = lpm_command(&["solve", s(&scene), "--out", s(&cut)]).spawn().unwrap();
    let staging = || {
        std::fs::read_dir(&cut)
            .map(|d| d.flatten().any(|e| e.file_name().to_string_lossy().starts_with(".lpm-staging-")))
            .unwrap_or(false)
    };
    let t = std::time::Instant::now();
    while !staging() && t.elapsed().as_secs() < 300 && child.try_wait().unwrap().is_none() {
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    child.kill().unwrap();
    assert!(!child.wait().unwrap().success(), "the solve finished before it could be killed in its export");
    assert!(!cut.join("report.json").exists(), "no report for an unpublished set");
    let o = run(&["solve", s(&scene), "--out", s(&cut), "--resume"]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ["fluence.raw", "source.raw", "image.exr", "image.png"] {
        assert!(std::fs::read(whole.join(f)).unwrap() == std::fs::read(cut.join(f)).unwrap(), "{f} differs");
    }
    // The report too (issue 35: after a kill in the export its remaining error was null and its
    // energy balance that of another state).
    assert_eq!(report_without_timings(&whole), report_without_timings(&cut));
    // The exitance maps too: the checkpoint kept those of the orders before it.
    assert!(names(&whole).iter().any(|n| n == "faces"), "the whole solve writes faces/");
    for face in ["-x", "+x", "-y", "+y", "-z", "+z"] {
        let f = format!("faces/{face}.raw");
        assert!(std::fs::read(whole.join(&f)).unwrap() == std::fs::read(cut.join(&f)).unwrap(), "{f} differs");
    }
    assert_eq!(names(&cut), names(&whole), "no temporaries or staging left");
}
