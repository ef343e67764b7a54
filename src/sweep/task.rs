//! Running one task of a sweep (`lpm solve MANIFEST --task N`), and what `--status` reports.
//!
//! Safe to re-run: a task that is done is not solved again; one that was killed (preempted,
//! requeued, timed out) continues from its checkpoint with `--resume`, to bitwise the result of an
//! uninterrupted solve. Safe to run concurrently: each task holds an exclusive `flock` on
//! `task-NNNN/lock` while it runs, so two runs of the same task never share a directory (the second
//! is refused with a clear message), while different tasks run side by side.

use super::{task_dir, Sweep, SweepError, Task};
use crate::job::{self, SolveJob};
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::Write;
use std::os::unix::io::AsRawFd;
use std::path::{Path, PathBuf};

/// `task-NNNN/status.json`.
#[derive(Debug, Serialize, Deserialize)]
pub struct TaskStatus {
    pub state: String,
    pub orders: Option<u32>,
    pub error: Option<String>,
    /// The previous frame's output directory this solve started from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warm_start: Option<String>,
}

/// `task-NNNN/task.json`: the frame and parameter values the task's scene was expanded with,
/// written with the scene. `--collect` labels a task's results with it (not with the manifest as
/// it reads now, which may have changed since the task ran).
#[derive(Debug, PartialEq, Serialize, Deserialize)]
pub struct Record {
    pub task: usize,
    pub frame: Option<i64>,
    /// Dotted scene key → the value the task's scene has.
    pub parameters: serde_json::Map<String, serde_json::Value>,
}

pub const RECORD: &str = "task.json";

impl Record {
    pub fn of(task: &Task) -> Record {
        Record {
            task: task.index,
            frame: task.frame,
            parameters: task.parameters.iter().map(|(k, v)| (k.clone(), super::toml_to_json(v))).collect(),
        }
    }

    /// The record in task directory `dir`, if it has one that reads.
    pub fn read(dir: &Path) -> Option<Record> {
        serde_json::from_slice(&std::fs::read(dir.join(RECORD)).ok()?).ok()
    }
}

/// Whether the task in `dir` was ever started (`lpm solve --task` writes `attempts.log` and
/// `status.json` before it solves into `out/`): its scene is then the one its results are of.
pub fn started(dir: &Path) -> bool {
    ["out", "status.json", "attempts.log"].iter().any(|f| dir.join(f).symlink_metadata().is_ok())
}

/// What [`Prepared::write`] will write for one task, decided (every check made) before anything
/// is written.
#[derive(Debug)]
pub struct Prepared<'a> {
    task: &'a Task,
    dir: PathBuf,
    write_scene: bool,
    /// The record's bytes, when it is missing or differs.
    record: Option<Vec<u8>>,
}

/// Checks the task's directory against `task` and says what is to be written, writing nothing:
/// the scene where it is missing or differs, refused ([`SweepError::Changed`]) when it differs
/// from that of a task already started.
pub fn check<'a>(sweep: &Sweep, task: &'a Task) -> Result<Prepared<'a>, SweepError> {
    let dir = task_dir(&sweep.dir, task.index);
    let scene = dir.join("scene.toml");
    let same = match std::fs::read(&scene) {
        Ok(old) => old == task.scene.as_bytes(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => false,
        Err(source) => return Err(SweepError::Io { path: scene, source }),
    };
    if !same && started(&dir) {
        return Err(SweepError::Changed { task: task.index, dir, more: 0 });
    }
    let mut record = serde_json::to_vec_pretty(&Record::of(task))
        .map_err(|e| SweepError::Io { path: dir.join(RECORD), source: e.into() })?;
    record.push(b'\n');
    let record_same = std::fs::read(dir.join(RECORD)).is_ok_and(|old| old == record);
    let record = (!record_same).then_some(record);
    Ok(Prepared { task, dir, write_scene: !same, record })
}

impl Prepared<'_> {
    /// Creates the task's directory and writes what [`check`] found missing or different, each
    /// file atomically; returns the directory.
    pub fn write(self) -> Result<PathBuf, SweepError> {
        let dir = self.dir;
        std::fs::create_dir_all(&dir).map_err(|source| SweepError::Io { path: dir.clone(), source })?;
        if let Some(record) = &self.record {
            crate::output::write_atomic(&dir.join(RECORD), |w| w.write_all(record))?;
        }
        if self.write_scene {
            crate::output::write_atomic(&dir.join("scene.toml"), |w| w.write_all(self.task.scene.as_bytes()))?;
        }
        Ok(dir)
    }
}

/// Creates the task's directory and writes its scene and record (unless they are already there,
/// the same); refused, writing nothing, when the scene of a started task changed.
pub fn prepare(sweep: &Sweep, task: &Task) -> Result<PathBuf, SweepError> {
    check(sweep, task)?.write()
}

/// An exclusive advisory lock, released when dropped (or when the process dies).
pub struct Lock(#[allow(dead_code)] File);

pub fn try_lock(path: &Path) -> Result<Option<Lock>, std::io::Error> {
    let file = std::fs::OpenOptions::new().create(true).truncate(false).write(true).open(path)?;
    // SAFETY: flock on a descriptor this function owns.
    let r = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    if r == 0 {
        Ok(Some(Lock(file)))
    } else {
        let e = std::io::Error::last_os_error();
        if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
            Ok(None)
        } else {
            Err(e)
        }
    }
}

/// How a task is run: the solve's own options (backend, device, …); `scene`, `out` and `resume`
/// are set per task. `slurm_job`: the Slurm job id, noted in the task's `attempts.log`.
pub fn run(
    sweep: &Sweep,
    index: usize,
    template: &SolveJob,
    slurm_job: Option<&str>,
) -> Result<RunOutcome, SweepError> {
    let task = sweep.task(index)?;
    let dir = prepare(sweep, task)?;
    let lock_path = dir.join("lock");
    let _lock = match try_lock(&lock_path).map_err(|source| SweepError::Io { path: lock_path.clone(), source })? {
        Some(lock) => lock,
        None => return Err(SweepError::Busy { task: index, lock: lock_path }),
    };
    let out = dir.join("out");
    if read_status(&dir).is_some_and(|s| s.state == "done") && out.join("report.json").exists() {
        return Ok(RunOutcome::AlreadyDone);
    }
    let checkpoint = job::work_dir(&out).join("checkpoint.json");
    let resume_from = std::fs::read(&checkpoint)
        .ok()
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
        .and_then(|v| v["state"]["orders_done"].as_u64());
    // A warm start from the previous frame, when it is done (else this frame starts cold).
    let warm_from = task.previous.filter(|_| resume_from.is_none()).map(|p| {
        let prev = task_dir(&sweep.dir, p);
        let done = read_status(&prev).is_some_and(|s| s.state == "done") && prev.join("out/source.raw").exists();
        (p, done.then(|| prev.join("out")))
    });
    let attempt = format!(
        "{:.0} {} (pid {}{})\n",
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64()),
        match (resume_from, &warm_from) {
            (Some(n), _) => format!("resumed after order {n}"),
            (None, Some((p, Some(_)))) => format!("started warm from task {p}"),
            (None, Some((p, None))) => format!("started cold (task {p}, the previous frame, is not done)"),
            (None, None) => "started".to_string(),
        },
        std::process::id(),
        slurm_job.map(|j| format!(", Slurm job {j}")).unwrap_or_default()
    );
    let log = dir.join("attempts.log");
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log)
        .and_then(|mut f| f.write_all(attempt.as_bytes()))
        .map_err(|source| SweepError::Io { path: log.clone(), source })?;
    write_status(&dir, &TaskStatus { state: "running".into(), orders: None, error: None, warm_start: None })?;

    let mut solve = template.clone();
    solve.scene = dir.join("scene.toml");
    solve.out = out;
    solve.resume = resume_from.is_some();
    solve.warm_start = warm_from.and_then(|(_, dir)| dir);
    solve.no_image |= sweep.solve.no_image;
    solve.no_fields |= sweep.solve.no_fields;
    if solve.device_memory_budget.is_none() {
        if let Some(b) = &sweep.solve.device_memory_budget {
            solve.device_memory_budget =
                Some(crate::scene::validate::parse_byte_size(b).map_err(|m| SweepError::Manifest {
                    path: sweep.manifest.clone(),
                    message: format!("solve.device_memory_budget: {m}"),
                })?);
        }
    }
    match job::run(&solve, |order, residual| {
        tracing::info!("task {index}: order {order} done, residual {residual:.3e}")
    }) {
        Ok(report) => {
            write_status(
                &dir,
                &TaskStatus {
                    state: "done".into(),
                    orders: Some(report.orders),
                    error: None,
                    warm_start: report.warm_start,
                },
            )?;
            Ok(RunOutcome::Solved { orders: report.orders, resumed: resume_from.is_some() })
        }
        // Stopped by SIGTERM (Slurm preempting it or ending its time): interrupted, not failed; the
        // rerun resumes from the checkpoint.
        Err(e @ job::JobError::Solve(crate::solver::SolveError::Cancelled { .. })) => {
            write_status(
                &dir,
                &TaskStatus { state: "cancelled".into(), orders: None, error: Some(e.to_string()), warm_start: None },
            )?;
            Err(e.into())
        }
        Err(e) => {
            write_status(
                &dir,
                &TaskStatus { state: "failed".into(), orders: None, error: Some(e.to_string()), warm_start: None },
            )?;
            Err(e.into())
        }
    }
}

pub enum RunOutcome {
    AlreadyDone,
    Solved { orders: u32, resumed: bool },
}

fn write_status(dir: &Path, status: &TaskStatus) -> Result<(), SweepError> {
    crate::output::write_json_atomic(&dir.join("status.json"), status)?;
    Ok(())
}

fn read_status(dir: &Path) -> Option<TaskStatus> {
    serde_json::from_slice(&std::fs::read(dir.join("status.json")).ok()?).ok()
}

/// What `--status` says of one task.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum State {
    Pending,
    Running,
    /// Started, not running now, not done: killed or preempted; resumes from its checkpoint.
    Interrupted,
    Failed,
    Done,
}

impl State {
    pub fn name(self) -> &'static str {
        match self {
            State::Pending => "pending",
            State::Running => "running",
            State::Interrupted => "interrupted",
            State::Failed => "failed",
            State::Done => "done",
        }
    }
}

/// The state of task `index`, from its directory alone.
pub fn state(sweep: &Sweep, index: usize) -> (State, Option<String>) {
    let dir = task_dir(&sweep.dir, index);
    let status = read_status(&dir);
    let locked = dir.join("lock").exists() && matches!(try_lock(&dir.join("lock")), Ok(None));
    if locked {
        return (State::Running, None);
    }
    match status {
        None => (State::Pending, None),
        Some(s) if s.state == "done" => (State::Done, None),
        Some(s) if s.state == "failed" => (State::Failed, s.error),
        Some(_) => (State::Interrupted, None),
    }
}
