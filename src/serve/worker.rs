//! The workers: each takes the next queued job and runs it as a child `lpm solve` process (the same
//! executable) into the job's directory, `DATA/jobs/ID/out`, with `--resume` when a checkpoint is
//! there. The solve is confined to the data root (`--confine-to`): every file it opens is checked
//! to lie under the root as it is opened ([`crate::input`]), whatever it was when the job was
//! accepted.
//!
//! Why a child process rather than a thread: a solve owns a Vulkan device, memory maps and possibly
//! gigabytes of host memory; as a process it can be stopped at any moment (cancel) without leaving
//! the server in an unknown state, and a crash or out-of-memory kill of one solve takes down neither
//! the server nor the other jobs. The child is told to die with its parent (`PR_SET_PDEATHSIG`), so a
//! server killed with `kill -9` leaves no orphan solving into a directory the next server will use.
//! The solve checkpoints at its scene's cadence (and when cancelled, its last completed order); a
//! job stopped for any reason resumes from its last checkpoint, to
//! bitwise the result an uninterrupted solve gives. Cancelling sends the solve SIGTERM: it stops
//! at its next slice (see [`crate::solver::cancel`]) and exits with status 3, its checkpoint kept.

use super::{db, Shared};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::Duration;

/// How often a running job's progress file and state are looked at.
const POLL: Duration = Duration::from_millis(100);

/// How long a cancelled solve is given to reach its next slice before it is killed (a slice takes
/// well under a second on small volumes, seconds on huge ones; a kill keeps the checkpoint too).
const CANCEL_GRACE: Duration = Duration::from_secs(120);

/// How long a job waits for its output directory's lock before its solve starts. A server killed
/// with `kill -9` takes its solves with it (`PR_SET_PDEATHSIG`), but the kernel may take a moment
/// to tear a dying solve down and free its lock, while the next server takes the job again at
/// once: without the wait that job failed on "another lpm run is writing" (seen under load).
const LOCK_WAIT: Duration = Duration::from_secs(60);

/// Waits up to [`LOCK_WAIT`] until no process holds `out`'s lock (a dying solve of a killed
/// server); past it, the solve starts anyway and reports the holder itself.
fn wait_for_lock(id: i64, out: &Path) {
    let started = std::time::Instant::now();
    let mut said = false;
    while started.elapsed() < LOCK_WAIT {
        match crate::output::DirLock::acquire(out) {
            Err(crate::output::OutputError::Locked { .. }) => {
                if !said {
                    tracing::info!("job {id}: waiting for the previous solve into its directory to exit");
                    said = true;
                }
                std::thread::sleep(POLL);
            }
            // Free (the probe's lock is dropped here), or an error the solve will report.
            _ => return,
        }
    }
}

/// The exit status of a solve stopped at a slice by SIGTERM (see `EXIT_CANCELLED` in main.rs).
const EXIT_CANCELLED: i32 = 3;

/// Stops a cancelled job's solve: SIGTERM (it stops at its next slice and exits with
/// [`EXIT_CANCELLED`]), then SIGKILL if it has not exited within [`CANCEL_GRACE`].
fn stop(id: i64, child: &mut Child) {
    // SAFETY: kill(2) on the pid of a child this worker started and has not reaped yet (so the
    // pid cannot have been reused).
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    let t = std::time::Instant::now();
    let status = loop {
        match child.try_wait() {
            Ok(Some(status)) => break Some(status),
            Ok(None) if t.elapsed() < CANCEL_GRACE => std::thread::sleep(POLL / 2),
            _ => {
                let _ = child.kill();
                break child.wait().ok();
            }
        }
    };
    match status.and_then(|s| s.code()) {
        Some(EXIT_CANCELLED) => {
            tracing::info!("job {id}: cancelled; the solve stopped (its log says whether it kept a checkpoint)")
        }
        Some(0) => tracing::info!("job {id}: cancelled as its solve was finishing (it completed)"),
        _ => tracing::info!("job {id}: cancelled; the solve was stopped ({status:?})"),
    }
}

/// Runs jobs until the process ends. `device` is passed to the solve as `--device`.
pub fn run(shared: Arc<Shared>, device: Option<usize>) {
    loop {
        shared.expire_old_jobs();
        match shared.db.claim() {
            Ok(Some(job)) => run_job(&shared, job, device),
            Ok(None) => shared.wait_for_work(Duration::from_millis(500)),
            Err(e) => {
                tracing::error!("job queue: {e}");
                std::thread::sleep(Duration::from_secs(1));
            }
        }
    }
}

fn run_job(shared: &Shared, job: db::Claimed, device: Option<usize>) {
    let id = job.id;
    match start(shared, &job, device) {
        Ok(child) => watch(shared, id, child),
        Err(e) => {
            tracing::error!("job {id}: {e}");
            let _ = shared.db.finish(id, "failed", None, None, Some(&e));
        }
    }
}

fn start(shared: &Shared, job: &db::Claimed, device: Option<usize>) -> Result<Child, String> {
    let dir = shared.job_dir(job.id);
    let out = dir.join("out");
    std::fs::create_dir_all(&out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    wait_for_lock(job.id, &out);
    let scene = dir.join("scene.toml");
    crate::output::write_atomic(&scene, |w| std::io::Write::write_all(w, job.scene.as_bytes()))
        .map_err(|e| e.to_string())?;
    let log_path = dir.join("solve.log");
    let log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .map_err(|e| format!("cannot open {}: {e}", log_path.display()))?;
    let exe = std::env::current_exe().map_err(|e| format!("cannot find the lpm executable: {e}"))?;
    let mut cmd = Command::new(exe);
    cmd.arg("solve").arg(&scene).arg("--out").arg(&out);
    // The solve reads only under the data root, checked on every file it opens: the paths were
    // confined when the job was accepted, but a file (a NRRD header naming its data file) can be
    // replaced between then and now.
    cmd.arg("--confine-to").arg(&shared.data);
    let resume = crate::job::work_dir(&out).join("checkpoint.json").exists();
    if resume {
        cmd.arg("--resume");
    }
    if let Some(d) = device {
        cmd.arg("--device").arg(d.to_string());
    }
    if let Some(b) = job.device_memory_budget.or(shared.opts.device_memory_budget) {
        cmd.arg("--device-memory-budget").arg(b.to_string());
    }
    if job.no_image {
        cmd.arg("--no-image");
    }
    if job.no_fields {
        cmd.arg("--no-fields");
    }
    cmd.stdin(Stdio::null()).stdout(Stdio::null()).stderr(log);
    die_with_parent(&mut cmd);
    tracing::info!("job {}: solving{}", job.id, if resume { " (resuming from its checkpoint)" } else { "" });
    cmd.spawn().map_err(|e| format!("cannot start the solve: {e}"))
}

#[cfg(target_os = "linux")]
fn die_with_parent(cmd: &mut Command) {
    use std::os::unix::process::CommandExt;
    // SAFETY: prctl and getppid are async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The parent may have died before prctl: then the signal will never come.
            if libc::getppid() == 1 {
                return Err(std::io::Error::other("the server exited while starting the solve"));
            }
            Ok(())
        });
    }
}

#[cfg(not(target_os = "linux"))]
fn die_with_parent(_cmd: &mut Command) {}

fn watch(shared: &Shared, id: i64, mut child: Child) {
    let out = shared.job_dir(id).join("out");
    let mut last_seen = None;
    let status = loop {
        match child.try_wait() {
            Ok(Some(status)) => break Ok(status),
            Ok(None) => {}
            Err(e) => break Err(e),
        }
        match shared.db.state(id) {
            Ok(Some(state)) if state == "running" => {}
            _ => {
                // Cancelled (or deleted): ask the solve to stop at its next slice; it keeps its
                // checkpoint, from which `POST /v1/jobs/{id}/resume` continues.
                stop(id, &mut child);
                shared.notify();
                return;
            }
        }
        // The job's state once it has done an order, updated as the solve moves to another stage
        // or order.
        if let Some(p) = read_progress(&out) {
            if let (Some(order), Some(residual)) = (p.order, p.residual) {
                if last_seen != Some((p.stage, order)) {
                    last_seen = Some((p.stage, order));
                    let _ = shared.db.set_progress(id, order, residual, Some(p.fraction), p.seconds_left);
                    shared.notify();
                }
            }
        }
        std::thread::sleep(POLL);
    };
    let result = match status {
        Ok(s) if s.success() => match report(&out) {
            Some((orders, residual)) => shared.db.finish(id, "done", Some(orders), Some(residual), None),
            None => shared.db.finish(id, "failed", None, None, Some("the solve wrote no readable report.json")),
        },
        Ok(s) => {
            let why = last_error(&shared.job_dir(id).join("solve.log")).unwrap_or_else(|| format!("the solve {s}"));
            shared.db.finish(id, "failed", None, None, Some(&why))
        }
        Err(e) => shared.db.finish(id, "failed", None, None, Some(&format!("cannot wait for the solve: {e}"))),
    };
    if let Err(e) = result {
        tracing::error!("job {id}: {e}");
    }
    tracing::info!("job {id}: {}", shared.db.state(id).ok().flatten().unwrap_or_default());
    shared.notify();
}

/// What the worker reads of the solve's `progress.json` ([`crate::job::Progress`]): the fraction
/// done and the seconds left are the solve's own estimate ([`crate::progress::Estimator`], the
/// one the CLI shows).
#[derive(serde::Deserialize)]
struct ProgressFile {
    stage: crate::progress::Stage,
    order: Option<u32>,
    residual: Option<f64>,
    fraction: f64,
    seconds_left: Option<f64>,
}

fn read_progress(out: &Path) -> Option<ProgressFile> {
    serde_json::from_slice(&std::fs::read(out.join("progress.json")).ok()?).ok()
}

fn report(out: &Path) -> Option<(u32, f64)> {
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("report.json")).ok()?).ok()?;
    Some((r["orders"].as_u64()? as u32, r["final_residual"].as_f64()?))
}

/// The solve's own one-line message (`lpm: …`), the last in its log.
fn last_error(log: &Path) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    text.lines().rev().find_map(|l| l.strip_prefix("lpm: ")).map(str::to_string)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The worker reads the estimate the solve wrote (`job::Progress`, from `progress::Estimator`)
    /// as it is, with no estimator of its own.
    #[test]
    fn the_progress_file_carries_the_solves_own_estimate() {
        let written = crate::job::Progress {
            stage: crate::progress::Stage::Order(3),
            order: Some(2),
            residual: Some(1.5e-3),
            residuals: &[1.0, 0.1, 1.5e-3],
            max_orders: 100,
            tolerance: 1e-3,
            seconds: 12.0,
            fraction: 0.4,
            seconds_left: Some(18.0),
            orders_left: Some(4),
        };
        let p: ProgressFile = serde_json::from_value(serde_json::to_value(&written).expect("json")).expect("read");
        assert_eq!((p.stage, p.order, p.residual), (crate::progress::Stage::Order(3), Some(2), Some(1.5e-3)));
        assert_eq!((p.fraction, p.seconds_left), (0.4, Some(18.0)));
        // Before order 1 the time left is not known: absent, not a guess from the cap.
        let early = crate::job::Progress { order: Some(0), seconds_left: None, orders_left: None, ..written };
        let p: ProgressFile = serde_json::from_value(serde_json::to_value(&early).expect("json")).expect("read");
        assert_eq!(p.seconds_left, None);
    }
}
