//! `lpm serve` with real processes and a real HTTP client: the API end to end, `kill -9` and restart
//! (a queued job and a running job both complete, the running one bitwise equal to an uninterrupted
//! solve), the queue bound and priorities, token and path-confinement refusals, size limits, and
//! the OpenAPI document against the routes, cancelling a running job, retention.
#![cfg(feature = "service")]
use crate::common::{killable_cloud_scene, lpm_command, temp_dir};

/// Slow enough (several orders of a few tenths of a second each) to be killed in the middle.
fn longer() -> String {
    killable_cloud_scene([32, 30, 34], 8)
}
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

const TINY: &str = r#"
[volume]
procedural = "sphere"
dims = [16, 16, 16]
[medium]
sigma_t = 0.8
albedo = 0.8
[[lights]]
kind = "sky"
radiance = 1.0
[solver]
directions_per_face = 2
max_orders = 3
tolerance = 1e-12
"#;

/// A running `lpm serve`, killed (SIGKILL) when dropped.
struct Server {
    child: Child,
    url: String,
}

impl Server {
    fn start(data: &Path, extra: &[&str]) -> Server {
        let mut args = vec!["serve", "--listen", "127.0.0.1:0", "--data", data.to_str().unwrap()];
        args.extend_from_slice(extra);
        let mut child = lpm_command(&args)
            .env("LPM_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start lpm serve");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).expect("read the server's first line");
        let url = line
            .split_whitespace()
            .find(|w| w.starts_with("http://"))
            .unwrap_or_else(|| panic!("the server did not say where it listens: {line:?}"))
            .to_string();
        Server { child, url }
    }

    fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.kill9();
    }
}

fn agent() -> ureq::Agent {
    ureq::AgentBuilder::new().timeout(Duration::from_secs(120)).build()
}

/// Status and body of any answer, error statuses included.
fn call(r: Result<ureq::Response, ureq::Error>) -> (u16, ureq::Response) {
    match r {
        Ok(r) => (r.status(), r),
        Err(ureq::Error::Status(s, r)) => (s, r),
        Err(e) => panic!("transport error: {e}"),
    }
}

fn json(r: ureq::Response) -> serde_json::Value {
    serde_json::from_str(&r.into_string().unwrap()).unwrap()
}

fn submit(url: &str, scene: &str, query: &str) -> (u16, serde_json::Value) {
    let (s, r) =
        call(agent().post(&format!("{url}/v1/jobs{query}")).set("Content-Type", "application/toml").send_string(scene));
    (s, json(r))
}

fn job(url: &str, id: i64, wait: f64) -> serde_json::Value {
    let (s, r) = call(agent().get(&format!("{url}/v1/jobs/{id}?wait={wait}")).call());
    assert_eq!(s, 200);
    json(r)
}

/// Long-polls job `id` until `done(job)` or `limit` passes.
fn wait_for(url: &str, id: i64, limit: Duration, done: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
    let t = Instant::now();
    loop {
        let j = job(url, id, 5.0);
        if done(&j) {
            return j;
        }
        assert!(t.elapsed() < limit, "job {id} still {j} after {limit:?}");
    }
}

fn ended(j: &serde_json::Value) -> bool {
    matches!(j["state"].as_str(), Some("done" | "failed" | "cancelled"))
}

/// Solves `scene` directly with the CLI into `dir/name`; returns the output directory.
fn direct_solve(dir: &Path, name: &str, scene: &str, extra: &[&str]) -> PathBuf {
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, scene).unwrap();
    let out = dir.join(name);
    let mut args = vec!["solve", path.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    let o = lpm_command(&args).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

fn fetch(url: &str, id: i64, name: &str) -> Vec<u8> {
    let (s, r) = call(agent().get(&format!("{url}/v1/jobs/{id}/outputs/{name}")).call());
    assert_eq!(s, 200, "{name}");
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut r.into_reader(), &mut bytes).unwrap();
    bytes
}

#[test]
fn api_end_to_end_with_real_clients() {
    let dir = temp_dir("serve-e2e");
    let server = Server::start(&dir.join("data"), &[]);
    let url = server.url.clone();

    let (s, r) = call(agent().get(&format!("{url}/v1/health")).call());
    assert_eq!(s, 200);
    assert_eq!(json(r)["status"], "ok");

    let (s, created) = submit(&url, TINY, "?priority=2&no_image=true&device_memory_budget=64M");
    assert_eq!(s, 201, "{created}");
    assert_eq!(created["state"], "queued");
    let id = created["id"].as_i64().unwrap();
    let done = wait_for(&url, id, Duration::from_secs(300), ended);
    assert_eq!(done["state"], "done", "{done}");
    assert_eq!(done["order"], 3);
    assert_eq!(done["priority"], 2);
    assert_eq!(done["progress"], 1.0);
    assert!(done["residual"].as_f64().unwrap() > 0.0);

    // The outputs, streamed, are the bits a direct CLI solve writes.
    let (s, r) = call(agent().get(&format!("{url}/v1/jobs/{id}/outputs")).call());
    assert_eq!(s, 200);
    let names: Vec<String> =
        json(r)["outputs"].as_array().unwrap().iter().map(|v| v.as_str().unwrap().to_string()).collect();
    assert!(names.contains(&"fluence.raw".to_string()) && names.contains(&"report.json".to_string()), "{names:?}");
    assert!(!names.iter().any(|n| n.starts_with("image")), "{names:?}");
    let direct = direct_solve(&dir, "direct", TINY, &["--no-image"]);
    for f in ["fluence.raw", "source.raw"] {
        assert!(fetch(&url, id, f) == std::fs::read(direct.join(f)).unwrap(), "{f} differs from a direct solve");
    }
    // The job's own device memory budget reached the solve.
    assert_eq!(done["device_memory_budget"], 64 << 20);
    let report: serde_json::Value = serde_json::from_slice(&fetch(&url, id, "report.json")).unwrap();
    assert_eq!(report["device_memory"]["budget_bytes"], 64 << 20, "{}", report["device_memory"]);
    let (s, r) = call(agent().get(&format!("{url}/v1/jobs/{id}/outputs/secret.txt")).call());
    assert_eq!(s, 404, "{}", r.into_string().unwrap());
    let (s, _) = call(agent().get(&format!("{url}/v1/jobs/{id}/outputs/..%2Flpm.sqlite")).call());
    assert_eq!(s, 404);
    // The queue keeps its WAL index in memory (exclusive locking): no shm file is mapped, whose
    // failure to grow (made immutable) killed the server with SIGBUS (issue 57).
    assert!(dir.join("data/lpm.sqlite-wal").exists(), "the queue is in WAL mode");
    assert!(!dir.join("data/lpm.sqlite-shm").exists(), "the queue maps a shared-memory file");

    // The CLI clients: submit --wait, status, fetch.
    let scene = dir.join("tiny.toml");
    std::fs::write(&scene, TINY).unwrap();
    let o = lpm_command(&["submit", scene.to_str().unwrap(), "--server", &url, "--wait"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let id2: i64 = String::from_utf8_lossy(&o.stdout).trim().parse().unwrap();
    let o = lpm_command(&["status", &id2.to_string(), "--server", &url]).output().unwrap();
    assert!(o.status.success());
    let status: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(status["state"], "done");
    let fetched = dir.join("fetched");
    let o = lpm_command(&["fetch", &id2.to_string(), "fluence.raw", "report.json", "--server", &url, "--out"])
        .arg(&fetched)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(std::fs::read(fetched.join("fluence.raw")).unwrap() == std::fs::read(direct.join("fluence.raw")).unwrap());
    let o = lpm_command(&["status", "--server", &url]).output().unwrap();
    let all: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(all["jobs"].as_array().unwrap().len(), 2);

    // A bad scene: 400 with the CLI's own one-line message.
    let bad = TINY.replace("albedo = 0.8", "albedo = 1.5");
    let (s, body) = submit(&url, &bad, "");
    assert_eq!(s, 400);
    std::fs::write(dir.join("scene.toml"), &bad).unwrap();
    let o = lpm_command(&["solve", "scene.toml", "--out", "bad-out"]).current_dir(&dir).output().unwrap();
    let cli = String::from_utf8_lossy(&o.stderr);
    let cli_line = cli.lines().find_map(|l| l.strip_prefix("lpm: ")).expect("the CLI's message");
    assert_eq!(body["error"], cli_line);
    let (s, body) = submit(&url, "[volume\n", "");
    assert_eq!(s, 400, "{body}");
    assert!(body["error"].as_str().unwrap().starts_with("scene.toml: line 1"), "{body}");
    let (s, _) =
        call(agent().post(&format!("{url}/v1/jobs")).set("Content-Type", "application/json").send_string("{}"));
    assert_eq!(s, 415);
    let (s, body) = submit(&url, TINY, "?priority=high");
    assert_eq!(s, 400, "{body}");

    // Unknown routes and methods; the OpenAPI document is served.
    assert_eq!(call(agent().get(&format!("{url}/v1/nothing")).call()).0, 404);
    assert_eq!(call(agent().put(&format!("{url}/v1/jobs")).call()).0, 405);
    assert_eq!(call(agent().get(&format!("{url}/v1/jobs/99999")).call()).0, 404);
    let (s, r) = call(agent().get(&format!("{url}/v1/openapi.json")).call());
    assert_eq!(s, 200);
    assert_eq!(r.into_string().unwrap(), lpm::serve::api::OPENAPI);

    // DELETE of an ended job removes it and its files.
    let (s, r) = call(agent().delete(&format!("{url}/v1/jobs/{id}")).call());
    assert_eq!(s, 200);
    assert_eq!(json(r)["state"], "deleted");
    assert_eq!(call(agent().get(&format!("{url}/v1/jobs/{id}")).call()).0, 404);
    assert!(!dir.join("data/jobs").join(id.to_string()).exists());
}

#[test]
fn kill_9_and_restart_lose_nothing_and_resume_bitwise() {
    let dir = temp_dir("serve-kill");
    let data = dir.join("data");
    let mut server = Server::start(&data, &[]);
    let url = server.url.clone();
    let (s, a) = submit(&url, &longer(), "?no_image=true");
    assert_eq!(s, 201);
    let (s, b) = submit(&url, TINY, "?no_image=true");
    assert_eq!(s, 201);
    let (a, b) = (a["id"].as_i64().unwrap(), b["id"].as_i64().unwrap());

    // Kill the server while job A is running, after its first checkpointed order.
    let j = wait_for(&url, a, Duration::from_secs(300), |j| j["order"].as_i64().is_some_and(|o| o >= 1) || ended(j));
    assert_eq!(j["state"], "running", "job A ended before the kill: make longer() slower ({j})");
    server.kill9();
    let checkpoint = data.join(format!("jobs/{a}/out/.lpm-work/checkpoint.json"));
    assert!(checkpoint.exists(), "job A has no checkpoint to resume from");
    // Its solve died with the server (PR_SET_PDEATHSIG): no writer is left in its directory.
    std::thread::sleep(Duration::from_millis(500));
    let orphans = processes_naming(&data.canonicalize().unwrap().join(format!("jobs/{a}/scene.toml")));
    assert_eq!(orphans, 0, "the solve of job A outlived its server");

    let server = Server::start(&data, &[]);
    let url = server.url.clone();
    let ja = wait_for(&url, a, Duration::from_secs(600), ended);
    let jb = wait_for(&url, b, Duration::from_secs(300), ended);
    assert_eq!(ja["state"], "done", "{ja}");
    assert_eq!(jb["state"], "done", "{jb}");
    assert_eq!(ja["attempts"], 2, "job A should have been resumed once: {ja}");
    assert_eq!(ja["order"], 8);
    let log = std::fs::read_to_string(data.join(format!("jobs/{a}/solve.log"))).unwrap();
    assert!(!log.contains("nothing to resume"), "job A started over instead of resuming:\n{log}");

    let direct = direct_solve(&dir, "direct", &longer(), &["--no-image"]);
    for f in ["fluence.raw", "source.raw"] {
        assert!(fetch(&url, a, f) == std::fs::read(direct.join(f)).unwrap(), "job A: {f} differs after the restart");
    }
    let tiny = direct_solve(&dir, "tiny", TINY, &["--no-image"]);
    assert!(fetch(&url, b, "fluence.raw") == std::fs::read(tiny.join("fluence.raw")).unwrap());
}

#[test]
fn queue_bound_priorities_and_cancel() {
    let dir = temp_dir("serve-queue");
    let data = dir.join("data");
    // No workers: jobs wait in the queue.
    let mut server = Server::start(&data, &["--workers", "0", "--max-queued", "3"]);
    let url = server.url.clone();
    let mut ids = Vec::new();
    for priority in [0, 5, 1] {
        let (s, j) = submit(&url, TINY, &format!("?priority={priority}&no_image=true&no_fields=true"));
        assert_eq!(s, 201, "{j}");
        ids.push(j["id"].as_i64().unwrap());
    }
    let (s, r) =
        call(agent().post(&format!("{url}/v1/jobs")).set("Content-Type", "application/toml").send_string(TINY));
    assert_eq!(s, 503);
    assert_eq!(r.header("Retry-After"), Some("30"));
    assert!(json(r)["error"].as_str().unwrap().contains("queue is full"));

    // Cancel the priority-1 job while queued: room for one more.
    let (s, r) = call(agent().delete(&format!("{url}/v1/jobs/{}", ids[2])).call());
    assert_eq!(s, 200);
    assert_eq!(json(r)["state"], "cancelled");
    let (s, j) = submit(&url, TINY, "?priority=3&no_image=true&no_fields=true");
    assert_eq!(s, 201);
    ids.push(j["id"].as_i64().unwrap());

    // Queued jobs survive kill -9; a server with a worker runs them by priority, then age.
    server.kill9();
    let server = Server::start(&data, &[]);
    let url = server.url.clone();
    let started: Vec<f64> = [ids[0], ids[1], ids[3]]
        .iter()
        .map(|&id| {
            let j = wait_for(&url, id, Duration::from_secs(300), ended);
            assert_eq!(j["state"], "done", "{j}");
            j["started_at"].as_f64().unwrap()
        })
        .collect();
    assert!(started[1] < started[2] && started[2] < started[0], "priority order 5, 3, 0: {started:?}");
    assert_eq!(job(&url, ids[2], 0.0)["state"], "cancelled");
}

#[test]
fn token_confinement_and_limits() {
    let dir = temp_dir("serve-safety");
    let data = dir.join("data");
    std::fs::create_dir_all(&data).unwrap();

    // Any non-loopback address needs a token.
    let o = lpm_command(&["serve", "--listen", "0.0.0.0:0", "--data", data.to_str().unwrap()])
        .env_remove("LPM_SERVE_TOKEN")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("needs a token"), "{}", String::from_utf8_lossy(&o.stderr));

    let token_file = dir.join("token");
    std::fs::write(&token_file, "s3cret-token\n").unwrap();
    let server = Server::start(&data, &["--token-file", token_file.to_str().unwrap(), "--max-body", "4K"]);
    let url = server.url.clone();
    let post = |auth: Option<&str>, body: &str| {
        let mut r = agent().post(&format!("{url}/v1/jobs?no_image=true&no_fields=true"));
        r = r.set("Content-Type", "application/toml");
        if let Some(a) = auth {
            r = r.set("Authorization", a);
        }
        let (s, r) = call(r.send_string(body));
        (s, json(r))
    };
    assert_eq!(post(None, TINY).0, 401);
    assert_eq!(post(Some("Bearer wrong"), TINY).0, 401);
    assert_eq!(call(agent().get(&format!("{url}/v1/jobs")).call()).0, 401);
    assert_eq!(call(agent().get(&format!("{url}/v1/health")).call()).0, 200);
    let good = Some("Bearer s3cret-token");
    assert_eq!(post(good, TINY).0, 201);

    // Volume paths: only under the data root.
    let raw_scene = |raw: &str| {
        TINY.replace("procedural = \"sphere\"\ndims = [16, 16, 16]", &format!("raw = \"{raw}\"\ndims = [16, 16, 16]"))
    };
    let density: Vec<u8> = (0..16 * 16 * 16).flat_map(|_| 0.5f32.to_le_bytes()).collect();
    std::fs::write(dir.join("outside.raw"), &density).unwrap();
    std::os::unix::fs::symlink(dir.join("outside.raw"), data.join("link.raw")).unwrap();
    for (raw, why) in [
        ("../outside.raw", "`..` is not allowed"),
        (dir.join("outside.raw").to_str().unwrap(), "outside the server's data root"),
        ("link.raw", "outside the server's data root"),
        ("/etc/passwd", "outside the server's data root"),
    ] {
        let (s, body) = post(good, &raw_scene(raw));
        assert_eq!(s, 400, "{raw}: {body}");
        assert!(body["error"].as_str().unwrap().contains(why), "{raw}: {body}");
    }
    // Every other key that names a file is confined the same way: a per-voxel emission file, a
    // NanoVDB file and an environment map outside the root are refused before anything reads them.
    let outside = dir.join("outside.raw");
    let outside = outside.to_str().unwrap();
    let emission = TINY.replace("dims = [16, 16, 16]", &format!("dims = [16, 16, 16]\nemission_raw = \"{outside}\""));
    let nvdb = TINY.replace("procedural = \"sphere\"\ndims = [16, 16, 16]", "nvdb = \"/etc/passwd\"");
    let map = TINY.replace("[solver]", &format!("[[lights]]\nkind = \"environment\"\nmap = \"{outside}\"\n[solver]"));
    let temperature =
        TINY.replace("dims = [16, 16, 16]", &format!("dims = [16, 16, 16]\ntemperature_raw = \"{outside}\""));
    for (scene, key) in [
        (emission, "volume.emission_raw"),
        (temperature, "volume.temperature_raw"),
        (nvdb, "volume.nvdb"),
        (map, "lights[1].map"),
    ] {
        let (s, body) = post(good, &scene);
        assert_eq!(s, 400, "{key}: {body}");
        let error = body["error"].as_str().unwrap();
        assert!(error.contains(key) && error.contains("outside the server's data root"), "{key}: {body}");
    }
    // Uploads land under the data root, under plain names only, within the size limit.
    let put = |name: &str, body: &[u8]| {
        call(
            agent()
                .put(&format!("{url}/v1/volumes/{name}"))
                .set("Authorization", "Bearer s3cret-token")
                .send_bytes(body),
        )
    };
    let (s, r) = put("cloud.raw", &density);
    assert_eq!(s, 201);
    assert_eq!(json(r)["path"], "volumes/cloud.raw");
    assert_eq!(std::fs::read(data.join("volumes/cloud.raw")).unwrap(), density);
    assert_eq!(put(".hidden", &density).0, 400);
    assert_eq!(put("a%2F..%2Fx", &density).0, 400);
    let (s, body) = post(good, &raw_scene("volumes/cloud.raw"));
    assert_eq!(s, 201, "{body}");
    let (s, body) = post(good, &raw_scene("volumes/missing.raw"));
    assert_eq!(s, 400, "{body}");
    // The size limit on scenes.
    let big = format!("{TINY}\n#{}\n", "x".repeat(5000));
    let (s, body) = post(good, &big);
    assert_eq!(s, 413, "{body}");
}

#[test]
fn openapi_document_matches_the_routes() {
    let doc: serde_json::Value = serde_json::from_str(lpm::serve::api::OPENAPI).expect("openapi.json is JSON");
    assert_eq!(doc["openapi"].as_str().map(|v| v.starts_with("3.")), Some(true));
    let mut documented: Vec<(String, String)> = Vec::new();
    for (path, item) in doc["paths"].as_object().unwrap() {
        for method in item.as_object().unwrap().keys() {
            documented.push((method.to_uppercase(), path.clone()));
        }
    }
    let mut served: Vec<(String, String)> =
        lpm::serve::api::ROUTES.iter().map(|r| (r.method.to_string(), r.path.to_string())).collect();
    documented.sort();
    served.sort();
    assert_eq!(served, documented, "the routes served and the OpenAPI paths differ");
    // Every documented path parameter is a {…} segment of its path, and the other way round.
    for (path, item) in doc["paths"].as_object().unwrap() {
        let segments: Vec<&str> =
            path.split('/').filter(|s| s.starts_with('{')).map(|s| s.trim_matches(|c| c == '{' || c == '}')).collect();
        for op in item.as_object().unwrap().values() {
            let params: Vec<&str> = op["parameters"]
                .as_array()
                .into_iter()
                .flatten()
                .filter(|p| p["in"] == "path")
                .map(|p| p["name"].as_str().unwrap())
                .collect();
            assert_eq!(params, segments, "{path}");
        }
    }
    // Each route is answered by the dispatcher (not 404) and only for its method.
    for r in lpm::serve::api::ROUTES {
        let concrete = r.path.replace("{id}", "1").replace("{name}", "x");
        assert!(lpm::serve::api::route(r.method, &concrete).is_ok(), "{} {}", r.method, r.path);
        assert!(lpm::serve::api::route("PATCH", &concrete).is_err());
    }
}

/// Processes whose command line names `path`.
fn processes_naming(path: &Path) -> usize {
    let needle = path.to_string_lossy().into_owned();
    std::fs::read_dir("/proc")
        .unwrap()
        .flatten()
        .filter_map(|e| std::fs::read(e.path().join("cmdline")).ok())
        .filter(|c| String::from_utf8_lossy(c).contains(&needle))
        .count()
}

#[test]
fn cancel_a_running_job_and_retention() {
    let dir = temp_dir("serve-cancel");
    let data = dir.join("data");
    // Ended jobs are deleted about 7 s after they end.
    let server = Server::start(&data, &["--retention-hours", "0.002"]);
    let url = server.url.clone();
    let (_, a) = submit(&url, &longer(), "?no_image=true");
    let a = a["id"].as_i64().unwrap();
    let j = wait_for(&url, a, Duration::from_secs(300), |j| j["order"].as_i64().is_some_and(|o| o >= 1) || ended(j));
    assert_eq!(j["state"], "running", "the job ended before it could be cancelled: {j}");
    let (s, r) = call(agent().delete(&format!("{url}/v1/jobs/{a}")).call());
    assert_eq!(s, 200);
    assert_eq!(json(r)["state"], "cancelled");
    // The solve stops (within the worker's poll) and keeps its checkpoint.
    let scene = data.canonicalize().unwrap().join(format!("jobs/{a}/scene.toml"));
    let t = Instant::now();
    while processes_naming(&scene) > 0 {
        assert!(t.elapsed() < Duration::from_secs(10), "the cancelled solve is still running");
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(data.join(format!("jobs/{a}/out/.lpm-work/checkpoint.json")).exists(), "the checkpoint was not kept");
    assert_eq!(job(&url, a, 0.0)["state"], "cancelled");
    let (s, _) = call(agent().get(&format!("{url}/v1/jobs/{a}/outputs")).call());
    assert_eq!(s, 409, "a cancelled job has no outputs");

    // Retention: ended jobs (the cancelled one, and a done one) disappear with their files.
    let (_, b) = submit(&url, TINY, "?no_image=true");
    let b = b["id"].as_i64().unwrap();
    assert_eq!(wait_for(&url, b, Duration::from_secs(300), ended)["state"], "done");
    let t = Instant::now();
    for id in [a, b] {
        // The row goes first, then the files.
        while call(agent().get(&format!("{url}/v1/jobs/{id}")).call()).0 != 404
            || data.join(format!("jobs/{id}")).exists()
        {
            assert!(t.elapsed() < Duration::from_secs(60), "job {id} outlived the retention limit");
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

/// `DELETE` of a running job stops its solve at the next slice (SIGTERM; the solve says so and
/// exits with its cancelled status), keeps its checkpoint, and `POST …/resume` continues it to
/// bitwise the result of an uninterrupted solve.
#[test]
fn cancel_stops_at_a_slice_and_resume_continues_bitwise() {
    let dir = temp_dir("serve-cancel-resume");
    let data = dir.join("data");
    let server = Server::start(&data, &[]);
    let url = server.url.clone();
    let (_, a) = submit(&url, &longer(), "?no_image=true");
    let a = a["id"].as_i64().unwrap();
    let j = wait_for(&url, a, Duration::from_secs(300), |j| j["order"].as_i64().is_some_and(|o| o >= 1) || ended(j));
    assert_eq!(j["state"], "running", "the job ended before it could be cancelled: {j}");
    let (s, r) = call(agent().post(&format!("{url}/v1/jobs/{a}/resume")).call());
    assert_eq!(s, 409, "a running job cannot be resumed: {}", r.into_string().unwrap());
    let (s, r) = call(agent().delete(&format!("{url}/v1/jobs/{a}")).call());
    assert_eq!(s, 200);
    assert_eq!(json(r)["state"], "cancelled");
    let scene = data.canonicalize().unwrap().join(format!("jobs/{a}/scene.toml"));
    let t = Instant::now();
    while processes_naming(&scene) > 0 {
        assert!(t.elapsed() < Duration::from_secs(60), "the cancelled solve is still running");
        std::thread::sleep(Duration::from_millis(50));
    }
    let log = std::fs::read_to_string(data.join(format!("jobs/{a}/solve.log"))).unwrap();
    assert!(
        log.contains("the solve was cancelled; its last checkpoint is kept"),
        "not cancelled keeping its checkpoint:\n{log}"
    );
    let checkpoint = data.join(format!("jobs/{a}/out/.lpm-work/checkpoint.json"));
    assert!(checkpoint.exists(), "the checkpoint was not kept");
    let kept: serde_json::Value = serde_json::from_slice(&std::fs::read(&checkpoint).unwrap()).unwrap();
    assert!(kept["state"]["orders_done"].as_u64().unwrap() >= 2, "{}", kept["state"]);
    assert_eq!(job(&url, a, 0.0)["state"], "cancelled");

    // Resumed: queued again, run from the checkpoint, the bits of an uninterrupted solve.
    let (s, r) = call(agent().post(&format!("{url}/v1/jobs/{a}/resume")).call());
    assert_eq!(s, 200);
    assert_eq!(json(r)["state"], "queued");
    let done = wait_for(&url, a, Duration::from_secs(600), ended);
    assert_eq!(done["state"], "done", "{done}");
    assert_eq!(done["attempts"], 2);
    assert_eq!(done["order"], 8);
    let log = std::fs::read_to_string(data.join(format!("jobs/{a}/solve.log"))).unwrap();
    assert!(log.contains("resuming after"), "the job did not resume from its checkpoint:\n{log}");
    let direct = direct_solve(&dir, "direct", &longer(), &["--no-image"]);
    for f in ["fluence.raw", "source.raw"] {
        assert!(fetch(&url, a, f) == std::fs::read(direct.join(f)).unwrap(), "{f} differs after cancel and resume");
    }
    let (s, _) = call(agent().post(&format!("{url}/v1/jobs/{a}/resume")).call());
    assert_eq!(s, 409, "a done job cannot be resumed");
    assert_eq!(call(agent().post(&format!("{url}/v1/jobs/99999/resume")).call()).0, 404);
}

/// A 16³ density (a ball of 0.9 in 0.05), as raw little-endian f32.
fn ball_density() -> Vec<u8> {
    let mut d = Vec::new();
    for z in 0..16 {
        for y in 0..16 {
            for x in 0..16 {
                let r2 = [x, y, z].iter().map(|&c| (c as f32 - 7.5).powi(2)).sum::<f32>();
                d.extend_from_slice(&(if r2 < 36.0 { 0.9f32 } else { 0.05 }).to_le_bytes());
            }
        }
    }
    d
}

/// TINY with its volume read from `raw`.
fn raw_tiny(raw: &str) -> String {
    TINY.replace("procedural = \"sphere\"\ndims = [16, 16, 16]", &format!("raw = \"{raw}\"\ndims = [16, 16, 16]"))
}

/// curl's `-F` (multipart/form-data): status and JSON body.
fn curl_form(url: &str, fields: &[String]) -> (u16, serde_json::Value) {
    let mut cmd = std::process::Command::new("curl");
    cmd.args(["-sS", "-o", "-", "-w", "\n%{http_code}"]);
    for f in fields {
        cmd.arg("-F").arg(f);
    }
    let o = cmd.arg(url).output().expect("run curl (tools/setup.sh installs it)");
    assert!(o.status.success(), "curl: {}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout).into_owned();
    let (body, code) = text.rsplit_once('\n').unwrap();
    (code.trim().parse().unwrap(), serde_json::from_str(body).unwrap_or(serde_json::Value::Null))
}

/// `POST /v1/jobs` as multipart/form-data, from curl and from `lpm submit --volume` (ureq): the
/// volume lands in the job's directory, the solve gives the bits of a direct CLI solve, and bad
/// forms are refused without leaving files behind.
#[test]
fn multipart_upload_of_a_scene_with_its_volume() {
    let dir = temp_dir("serve-multipart");
    let data = dir.join("data");
    let server = Server::start(&data, &["--max-upload", "40K"]);
    let url = server.url.clone();
    let local = dir.join("local");
    std::fs::create_dir_all(&local).unwrap();
    std::fs::write(local.join("ball.raw"), ball_density()).unwrap();
    std::fs::write(local.join("scene.toml"), raw_tiny("ball.raw")).unwrap();
    let scene = local.join("scene.toml");
    let ball = local.join("ball.raw");

    let (s, created) = curl_form(
        &format!("{url}/v1/jobs?no_image=true"),
        &[format!("scene=@{};type=application/toml", scene.display()), format!("volume=@{}", ball.display())],
    );
    assert_eq!(s, 201, "{created}");
    let id = created["id"].as_i64().unwrap();
    let stored = data.join(format!("jobs/{id}/inputs/ball.raw"));
    assert_eq!(std::fs::read(&stored).unwrap(), ball_density(), "the upload is not in the job's directory");
    let done = wait_for(&url, id, Duration::from_secs(300), ended);
    assert_eq!(done["state"], "done", "{done}");
    let direct_scene = raw_tiny(ball.to_str().unwrap());
    let direct = direct_solve(&dir, "direct", &direct_scene, &["--no-image"]);
    assert!(fetch(&url, id, "fluence.raw") == std::fs::read(direct.join("fluence.raw")).unwrap());

    // The same from the CLI client (ureq, streamed).
    let o = lpm_command(&["submit", scene.to_str().unwrap(), "--volume", ball.to_str().unwrap(), "--server", &url])
        .args(["--no-image", "--wait"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let id2: i64 = String::from_utf8_lossy(&o.stdout).trim().parse().unwrap();
    assert!(fetch(&url, id2, "fluence.raw") == std::fs::read(direct.join("fluence.raw")).unwrap());

    // Refusals: 400 or 413 with a message, and no file left under the data root.
    let scene_field = format!("scene=@{};type=application/toml", scene.display());
    let outside = dir.join("outside.toml");
    std::fs::write(&outside, raw_tiny("/etc/passwd")).unwrap();
    let big = local.join("big.raw");
    std::fs::write(&big, vec![0u8; 50_000]).unwrap();
    let cases: Vec<(Vec<String>, u16, &str)> = vec![
        (vec![format!("volume=@{}", ball.display())], 400, "no \"scene\" part"),
        (vec![scene_field.clone()], 400, "volume.raw"),
        (vec![scene_field.clone(), format!("volume=@{};filename=../ball.raw", ball.display())], 400, "file name"),
        (vec![scene_field.clone(), format!("other=@{}", ball.display())], 400, "unknown part"),
        (vec![format!("scene=@{}", outside.display()), format!("volume=@{}", ball.display())], 400, "outside"),
        (vec![scene_field.clone(), format!("volume=@{};filename=ball.raw", big.display())], 413, "limit"),
        (
            vec![scene_field.clone(), format!("volume=@{}", ball.display()), format!("volume=@{}", ball.display())],
            400,
            "twice",
        ),
    ];
    for (fields, status, why) in cases {
        let (s, body) = curl_form(&format!("{url}/v1/jobs"), &fields);
        assert_eq!(s, status, "{fields:?}: {body}");
        assert!(body["error"].as_str().is_some_and(|e| e.contains(why)), "{fields:?}: {body}");
    }
    let left: Vec<_> = std::fs::read_dir(data.join("uploads")).unwrap().flatten().map(|e| e.file_name()).collect();
    assert!(left.is_empty(), "staging left behind: {left:?}");
    let jobs: Vec<_> = std::fs::read_dir(data.join("jobs")).unwrap().flatten().collect();
    assert_eq!(jobs.len(), 2, "only the two accepted jobs have directories");
}

/// `GET /v1/jobs/{id}/events`: server-sent events read by a real client as they come, ending with
/// the job's final state.
#[test]
fn progress_is_pushed_as_server_sent_events() {
    let dir = temp_dir("serve-events");
    let server = Server::start(&dir.join("data"), &[]);
    let url = server.url.clone();
    let (s, created) = submit(&url, TINY, "?no_image=true&no_fields=true");
    assert_eq!(s, 201);
    let id = created["id"].as_i64().unwrap();
    let r = agent().get(&format!("{url}/v1/jobs/{id}/events")).call().expect("the event stream");
    assert_eq!(r.header("Content-Type"), Some("text/event-stream"));
    let mut events: Vec<serde_json::Value> = Vec::new();
    let mut kind = String::new();
    for line in BufReader::new(r.into_reader()).lines() {
        let line = line.expect("read the stream");
        if let Some(k) = line.strip_prefix("event: ") {
            kind = k.to_string();
        } else if let Some(d) = line.strip_prefix("data: ") {
            assert_eq!(kind, "job");
            events.push(serde_json::from_str(d).unwrap());
        }
    }
    // The stream ended by itself after the final state.
    assert!(events.len() >= 2, "{events:?}");
    let last = events.last().unwrap();
    assert_eq!(last["state"], "done", "{events:?}");
    assert_eq!(last["order"], 3);
    assert!(events[..events.len() - 1].iter().all(|e| !ended(e)), "{events:?}");
    let orders: Vec<i64> = events.iter().filter_map(|e| e["order"].as_i64()).collect();
    assert!(orders.windows(2).all(|w| w[0] <= w[1]), "orders go forward: {orders:?}");
    // Issue 36, item 2: the time left is the solve's own estimate (progress.json, written by
    // lpm::progress's estimator): known once order 1 is done, never negative, and the fraction
    // done within [0, 1].
    for e in events.iter().filter(|e| e["state"] == "running" && e["order"].as_i64() >= Some(1)) {
        assert!(e["seconds_left"].as_f64().is_some_and(|s| s >= 0.0), "{e}");
        assert!(e["progress"].as_f64().is_some_and(|p| (0.0..=1.0).contains(&p)), "{e}");
    }
    assert_eq!(last["seconds_left"], 0.0);
    // An ended job's stream is its one final event; an unknown job is a 404.
    let r = agent().get(&format!("{url}/v1/jobs/{id}/events")).call().unwrap();
    let text = r.into_string().unwrap();
    assert_eq!(text.matches("event: job").count(), 1, "{text}");
    assert_eq!(call(agent().get(&format!("{url}/v1/jobs/424242/events")).call()).0, 404);
}

/// Issue 35: a NRRD header checked when its job was accepted is replaced, before the job runs, by
/// one naming a data file outside the data root. The solve reads inputs only under the root,
/// checked on each file it opens, so the job fails saying so and the outside file is never solved.
#[test]
fn a_nrrd_header_replaced_after_submission_cannot_reach_outside_the_data_root() {
    let dir = temp_dir("serve-nrrd-swap");
    let data = dir.join("data");
    let server = Server::start(&data, &["--workers", "1"]);
    let url = server.url.clone();
    let put = |name: &str, body: &[u8]| {
        let (s, r) = call(agent().put(&format!("{url}/v1/volumes/{name}")).send_bytes(body));
        assert_eq!(s, 201, "{}", r.into_string().unwrap_or_default());
    };
    let density: Vec<u8> = (0..16 * 16 * 16).flat_map(|_| 0.5f32.to_le_bytes()).collect();
    let outside = dir.join("outside.raw");
    std::fs::write(&outside, &density).unwrap();
    let header = |data_file: &str| {
        format!(
            "NRRD0004\ntype: float\ndimension: 3\nsizes: 16 16 16\nendian: little\nencoding: raw\ndata file: {data_file}\n"
        )
    };
    put("v16.raw", &density);
    put("a.nhdr", header("v16.raw").as_bytes());
    // The one worker is kept busy while the NRRD job waits in the queue.
    let (_, busy) = submit(&url, &longer(), "?no_image=true&no_fields=true");
    let busy = busy["id"].as_i64().unwrap();
    wait_for(&url, busy, Duration::from_secs(300), |j| j["state"] == "running" || ended(j));
    let scene = TINY.replace("procedural = \"sphere\"\ndims = [16, 16, 16]", "nrrd = \"volumes/a.nhdr\"");
    let (s, job_b) = submit(&url, &scene, "?no_image=true");
    assert_eq!(s, 201, "the header is inside the root when the job is accepted: {job_b}");
    let b = job_b["id"].as_i64().unwrap();
    put("a.nhdr", header(outside.to_str().unwrap()).as_bytes());
    let (s, _) = call(agent().delete(&format!("{url}/v1/jobs/{busy}")).call());
    assert_eq!(s, 200);
    let j = wait_for(&url, b, Duration::from_secs(300), ended);
    assert_eq!(j["state"], "failed", "the outside file was solved: {j}");
    let error = j["error"].as_str().unwrap_or_default();
    assert!(error.contains("outside the data root this solve is confined to"), "{j}");
    let (s, _) = call(agent().get(&format!("{url}/v1/jobs/{b}/outputs/fluence.raw")).call());
    assert_ne!(s, 200, "the outside file's fluence can be fetched");
}

/// Issue 57, item 7: a `PUT` whose body ends before its `Content-Length` (the client sent part of
/// it and half-closed) is refused and leaves the stored volume byte for byte as it was, with no
/// temporary beside it; a chunked upload (whose end tiny_http cannot vouch for) is refused with 411;
/// a complete upload still replaces the file.
#[test]
fn a_truncated_upload_leaves_the_stored_volume_whole() {
    use std::io::{Read, Write};
    let dir = temp_dir("serve-truncated-put");
    let data = dir.join("data");
    let server = Server::start(&data, &[]);
    let url = server.url.clone();
    let put = |body: &[u8]| call(agent().put(&format!("{url}/v1/volumes/good.raw")).send_bytes(body)).0;
    let good: Vec<u8> = (0..16384u32).map(|i| (i % 251) as u8).collect();
    assert_eq!(put(&good), 201);
    let stored = data.join("volumes/good.raw");
    assert_eq!(std::fs::read(&stored).unwrap(), good);

    let addr = url.trim_start_matches("http://");
    let mut tcp = std::net::TcpStream::connect(addr).unwrap();
    tcp.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    write!(
        tcp,
        "PUT /v1/volumes/good.raw HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/octet-stream\r\n\
         Content-Length: 16384\r\n\r\n"
    )
    .unwrap();
    tcp.write_all(&[7u8; 5000]).unwrap();
    tcp.shutdown(std::net::Shutdown::Write).unwrap();
    let mut answer = Vec::new();
    // An error here (a reset) is the connection dropped: a refusal too.
    let _ = tcp.read_to_end(&mut answer);
    let answer = String::from_utf8_lossy(&answer);
    let status: Option<u16> = answer.strip_prefix("HTTP/1.1 ").and_then(|r| r.get(..3)).and_then(|c| c.parse().ok());
    assert!(!matches!(status, Some(200..=299)), "a truncated upload was accepted: {answer}");
    assert_eq!(std::fs::read(&stored).unwrap(), good, "the stored volume was replaced by a truncated one");
    let names: Vec<String> = std::fs::read_dir(data.join("volumes"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["good.raw"], "a temporary was left beside the volume");

    // ureq sends a body of unknown length chunked.
    let (s, r) = call(agent().put(&format!("{url}/v1/volumes/good.raw")).send(std::io::Cursor::new(vec![1u8; 20000])));
    assert_eq!(s, 411, "{}", r.into_string().unwrap_or_default());
    assert_eq!(std::fs::read(&stored).unwrap(), good);

    let newer = vec![9u8; 20000];
    assert_eq!(put(&newer), 201);
    assert_eq!(std::fs::read(&stored).unwrap(), newer);
}

/// The server's resident memory in KiB (`VmRSS` of /proc/PID/status).
fn resident_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status.lines().find(|l| l.starts_with("VmRSS:")).expect("VmRSS in /proc/PID/status");
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

/// Issue 57, item 6: a request header line without end, sent before any token is checked (to
/// `/v1/health`), is cut off with 431 (or the connection closed) while the server's memory stays
/// put; a head too large in all gets a 431 the client can read; the server answers afterwards, one
/// request per connection.
#[test]
fn an_endless_request_header_is_refused_without_growing_the_server() {
    use std::io::{Read, Write};
    let dir = temp_dir("serve-endless-header");
    let token_file = dir.join("token");
    std::fs::write(&token_file, "s3cret-token\n").unwrap();
    let server = Server::start(&dir.join("data"), &["--token-file", token_file.to_str().unwrap()]);
    let url = server.url.clone();
    let addr = url.trim_start_matches("http://").to_string();
    assert_eq!(call(agent().get(&format!("{url}/v1/health")).call()).0, 200);
    let before = resident_kib(server.child.id());

    let mut tcp = std::net::TcpStream::connect(&addr).unwrap();
    tcp.set_write_timeout(Some(Duration::from_secs(10))).unwrap();
    tcp.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    tcp.write_all(b"GET /v1/health HTTP/1.1\r\nHost: x\r\nX-Endless: ").unwrap();
    let chunk = vec![b'a'; 64 * 1024];
    let mut sent = 0usize;
    // 64 MiB, unless the server stops taking them (a reset, or the socket's buffers stay full).
    while sent < 64 << 20 {
        match tcp.write(&chunk) {
            Ok(0) | Err(_) => break,
            Ok(n) => sent += n,
        }
    }
    let mut answer = Vec::new();
    let _ = tcp.read_to_end(&mut answer);
    let answer = String::from_utf8_lossy(&answer);
    assert!(answer.is_empty() || answer.starts_with("HTTP/1.1 431"), "after {sent} bytes of one header line: {answer}");
    let after = resident_kib(server.child.id());
    assert!(
        after < before + 16 * 1024,
        "the server grew from {before} KiB to {after} KiB on {sent} bytes of one header"
    );
    drop(tcp);

    // A finite head over the limit: the client reads the 431 itself.
    let mut tcp = std::net::TcpStream::connect(&addr).unwrap();
    tcp.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let mut head = b"GET /v1/jobs HTTP/1.1\r\nHost: x\r\n".to_vec();
    for i in 0..100 {
        head.extend_from_slice(format!("X-Filler-{i}: {}\r\n", "b".repeat(1000)).as_bytes());
    }
    head.extend_from_slice(b"\r\n");
    tcp.write_all(&head).unwrap();
    let mut answer = String::new();
    tcp.read_to_string(&mut answer).unwrap();
    assert!(answer.starts_with("HTTP/1.1 431"), "{answer}");
    assert!(answer.contains("\"error\""), "{answer}");

    // The server still answers, and closes each connection after its one answer.
    assert_eq!(call(agent().get(&format!("{url}/v1/health")).call()).0, 200);
    let mut tcp = std::net::TcpStream::connect(&addr).unwrap();
    tcp.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    tcp.write_all(b"GET /v1/health HTTP/1.1\r\nHost: x\r\nConnection: keep-alive\r\n\r\n").unwrap();
    let mut answer = String::new();
    tcp.read_to_string(&mut answer).expect("the connection ends after the answer");
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    assert!(answer.to_ascii_lowercase().contains("\r\nconnection: close\r\n"), "{answer}");
    // The token is still asked for.
    assert_eq!(call(agent().get(&format!("{url}/v1/jobs")).call()).0, 401);
}
