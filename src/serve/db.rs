//! The durable job queue: one SQLite table (`schema.sql`) in WAL mode with `synchronous = FULL`, so
//! a job is on disk before its `201 Created` is sent and survives `kill -9` of the server (and a
//! power cut). Every transition of the state machine in [`super`] is one SQL statement guarded by
//! the state it leaves (`UPDATE … WHERE state = 'running'`), so a worker finishing a job and a
//! client cancelling it cannot both win.

use rusqlite::{params, Connection, OptionalExtension, Row};
use serde::Serialize;
use std::path::Path;
use std::sync::Mutex;

const SCHEMA_V1: &str = include_str!("schema.sql");

/// A job as the API shows it (the scene text is left out).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Job {
    pub id: i64,
    pub state: String,
    pub priority: i64,
    pub device_memory_budget: Option<u64>,
    pub no_image: bool,
    pub no_fields: bool,
    pub submitted_at: f64,
    pub started_at: Option<f64>,
    pub finished_at: Option<f64>,
    pub attempts: i64,
    /// Orders completed so far (or in the result).
    pub order: Option<i64>,
    pub max_orders: Option<i64>,
    pub residual: Option<f64>,
    /// Estimated fraction done, 0 to 1.
    pub progress: Option<f64>,
    /// Estimated seconds left (from the residual's decay and the time per order).
    pub seconds_left: Option<f64>,
    pub error: Option<String>,
}

const JOB_COLUMNS: &str = "id, state, priority, device_memory_budget, no_image, no_fields, submitted_at, started_at, \
                           finished_at, attempts, orders, max_orders, residual, progress, seconds_left, error";

fn job_from_row(r: &Row) -> rusqlite::Result<Job> {
    Ok(Job {
        id: r.get(0)?,
        state: r.get(1)?,
        priority: r.get(2)?,
        device_memory_budget: r.get::<_, Option<i64>>(3)?.map(|b| b as u64),
        no_image: r.get(4)?,
        no_fields: r.get(5)?,
        submitted_at: r.get(6)?,
        started_at: r.get(7)?,
        finished_at: r.get(8)?,
        attempts: r.get(9)?,
        order: r.get(10)?,
        max_orders: r.get(11)?,
        residual: r.get(12)?,
        progress: r.get(13)?,
        seconds_left: r.get(14)?,
        error: r.get(15)?,
    })
}

/// What a client submits (already validated).
pub struct NewJob {
    pub scene: String,
    pub priority: i64,
    pub device_memory_budget: Option<u64>,
    pub no_image: bool,
    pub no_fields: bool,
    pub max_orders: u32,
}

/// A job a worker claimed, with what it needs to run it.
pub struct Claimed {
    pub id: i64,
    pub scene: String,
    pub device_memory_budget: Option<u64>,
    pub no_image: bool,
    pub no_fields: bool,
}

pub enum Insert {
    Accepted(Box<Job>),
    /// The queue already holds this many queued jobs.
    Full(u64),
}

pub enum Requeue {
    Queued(Job),
    /// The job is queued, running or done: nothing to resume.
    NotStopped(Job),
    /// The queue already holds this many queued jobs.
    Full(u64),
    Missing,
}

pub enum Cancel {
    Cancelled(Job),
    /// The job had already ended: nothing to cancel.
    Ended(Job),
    Missing,
}

pub struct Db {
    conn: Mutex<Connection>,
}

pub fn now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

impl Db {
    pub fn open(path: &Path) -> rusqlite::Result<Db> {
        let conn = Connection::open(path)?;
        conn.busy_timeout(std::time::Duration::from_secs(10))?;
        // Exclusive locking before WAL mode: SQLite then keeps the WAL index in the heap and never
        // maps a `lpm.sqlite-shm` file. A mapped shm that cannot grow (made immutable, or on a full
        // or odd file system) killed the server with SIGBUS and every job with it (issue 57); an
        // I/O error on the database or its WAL is a failed request instead. The server is the
        // queue's only user (one connection, behind the mutex below), so nothing is shut out;
        // a second server on the same data root finds the database locked.
        conn.pragma_update(None, "locking_mode", "EXCLUSIVE")?;
        conn.pragma_update(None, "journal_mode", "WAL")?;
        conn.pragma_update(None, "synchronous", "FULL")?;
        let version: i64 = conn.pragma_query_value(None, "user_version", |r| r.get(0))?;
        if version == 0 {
            conn.execute_batch(&format!("BEGIN; {SCHEMA_V1} PRAGMA user_version = 1; COMMIT;"))?;
        }
        Ok(Db { conn: Mutex::new(conn) })
    }

    fn conn(&self) -> std::sync::MutexGuard<'_, Connection> {
        // A panic while holding the lock leaves the connection usable (each statement is atomic).
        self.conn.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Enqueues `job` unless `max_queued` jobs are already waiting.
    pub fn insert(&self, job: &NewJob, max_queued: u64) -> rusqlite::Result<Insert> {
        let ok: rusqlite::Result<Result<Insert, std::convert::Infallible>> =
            self.insert_with(job, max_queued, &mut |_| Ok(job.scene.clone()));
        ok.map(|r| match r {
            Ok(i) => i,
        })
    }

    /// [`Db::insert`], where `finalize(id)` gives the scene text to store once the id is known
    /// (it runs inside the transaction: when it fails, nothing is inserted).
    pub fn insert_with<E>(
        &self,
        job: &NewJob,
        max_queued: u64,
        finalize: &mut dyn FnMut(i64) -> Result<String, E>,
    ) -> rusqlite::Result<Result<Insert, E>> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let queued: u64 = tx.query_row("SELECT COUNT(*) FROM jobs WHERE state = 'queued'", [], |r| r.get(0))?;
        if queued >= max_queued {
            return Ok(Ok(Insert::Full(queued)));
        }
        tx.execute(
            "INSERT INTO jobs (state, priority, scene, device_memory_budget, no_image, no_fields, submitted_at, max_orders)
             VALUES ('queued', ?1, ?2, ?3, ?4, ?5, ?6, ?7)",
            params![
                job.priority,
                job.scene,
                job.device_memory_budget.map(|b| b as i64),
                job.no_image,
                job.no_fields,
                now(),
                job.max_orders
            ],
        )?;
        let id = tx.last_insert_rowid();
        let scene = match finalize(id) {
            Ok(scene) => scene,
            Err(e) => return Ok(Err(e)),
        };
        if scene != job.scene {
            tx.execute("UPDATE jobs SET scene = ?2 WHERE id = ?1", params![id, scene])?;
        }
        let row = tx.query_row(&format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?1"), [id], job_from_row)?;
        tx.commit()?;
        Ok(Ok(Insert::Accepted(Box::new(row))))
    }

    pub fn get(&self, id: i64) -> rusqlite::Result<Option<Job>> {
        self.conn().query_row(&format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?1"), [id], job_from_row).optional()
    }

    pub fn list(&self) -> rusqlite::Result<Vec<Job>> {
        let conn = self.conn();
        let mut st = conn.prepare(&format!("SELECT {JOB_COLUMNS} FROM jobs ORDER BY id"))?;
        let rows = st.query_map([], job_from_row)?;
        rows.collect()
    }

    /// Jobs per state.
    pub fn counts(&self) -> rusqlite::Result<Vec<(String, u64)>> {
        let conn = self.conn();
        let mut st = conn.prepare("SELECT state, COUNT(*) FROM jobs GROUP BY state ORDER BY state")?;
        let rows = st.query_map([], |r| Ok((r.get(0)?, r.get(1)?)))?;
        rows.collect()
    }

    /// At start-up: jobs left `running` by a server that died go back to `queued` (they resume
    /// from their checkpoint). Returns how many.
    pub fn requeue_running(&self) -> rusqlite::Result<usize> {
        self.conn().execute("UPDATE jobs SET state = 'queued' WHERE state = 'running'", [])
    }

    /// Takes the next queued job (highest priority, then oldest) and marks it running.
    pub fn claim(&self) -> rusqlite::Result<Option<Claimed>> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let next = tx
            .query_row(
                "SELECT id, scene, device_memory_budget, no_image, no_fields FROM jobs WHERE state = 'queued'
                 ORDER BY priority DESC, id LIMIT 1",
                [],
                |r| {
                    Ok(Claimed {
                        id: r.get(0)?,
                        scene: r.get(1)?,
                        device_memory_budget: r.get::<_, Option<i64>>(2)?.map(|b| b as u64),
                        no_image: r.get(3)?,
                        no_fields: r.get(4)?,
                    })
                },
            )
            .optional()?;
        if let Some(job) = &next {
            tx.execute(
                "UPDATE jobs SET state = 'running', started_at = ?2, attempts = attempts + 1 WHERE id = ?1",
                params![job.id, now()],
            )?;
        }
        tx.commit()?;
        Ok(next)
    }

    pub fn state(&self, id: i64) -> rusqlite::Result<Option<String>> {
        self.conn().query_row("SELECT state FROM jobs WHERE id = ?1", [id], |r| r.get(0)).optional()
    }

    pub fn set_progress(
        &self,
        id: i64,
        order: u32,
        residual: f64,
        progress: Option<f64>,
        seconds_left: Option<f64>,
    ) -> rusqlite::Result<()> {
        self.conn().execute(
            "UPDATE jobs SET orders = ?2, residual = ?3, progress = ?4, seconds_left = ?5 WHERE id = ?1 AND state = 'running'",
            params![id, order, residual, progress, seconds_left],
        )?;
        Ok(())
    }

    /// running → done | failed. False when the job was no longer running (cancelled meanwhile).
    pub fn finish(
        &self,
        id: i64,
        state: &str,
        order: Option<u32>,
        residual: Option<f64>,
        error: Option<&str>,
    ) -> rusqlite::Result<bool> {
        let progress = (state == "done").then_some(1.0);
        let seconds_left = (state == "done").then_some(0.0);
        let n = self.conn().execute(
            "UPDATE jobs SET state = ?2, finished_at = ?3, orders = COALESCE(?4, orders), residual = COALESCE(?5, residual),
             error = ?6, progress = COALESCE(?7, progress), seconds_left = ?8 WHERE id = ?1 AND state = 'running'",
            params![id, state, now(), order, residual, error, progress, seconds_left],
        )?;
        Ok(n == 1)
    }

    /// queued | running → cancelled.
    pub fn cancel(&self, id: i64) -> rusqlite::Result<Cancel> {
        let n = self.conn().execute(
            "UPDATE jobs SET state = 'cancelled', finished_at = ?2, seconds_left = NULL
             WHERE id = ?1 AND state IN ('queued', 'running')",
            params![id, now()],
        )?;
        Ok(match (n, self.get(id)?) {
            (_, None) => Cancel::Missing,
            (1, Some(job)) => Cancel::Cancelled(job),
            (_, Some(job)) => Cancel::Ended(job),
        })
    }

    /// cancelled | failed → queued, unless `max_queued` jobs are already waiting: the next worker
    /// to take it continues its solve from the checkpoint it kept.
    pub fn requeue(&self, id: i64, max_queued: u64) -> rusqlite::Result<Requeue> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let Some(job) =
            tx.query_row(&format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?1"), [id], job_from_row).optional()?
        else {
            return Ok(Requeue::Missing);
        };
        if !matches!(job.state.as_str(), "cancelled" | "failed") {
            return Ok(Requeue::NotStopped(job));
        }
        let queued: u64 = tx.query_row("SELECT COUNT(*) FROM jobs WHERE state = 'queued'", [], |r| r.get(0))?;
        if queued >= max_queued {
            return Ok(Requeue::Full(queued));
        }
        tx.execute(
            "UPDATE jobs SET state = 'queued', finished_at = NULL, error = NULL, seconds_left = NULL WHERE id = ?1",
            [id],
        )?;
        let job = tx.query_row(&format!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = ?1"), [id], job_from_row)?;
        tx.commit()?;
        Ok(Requeue::Queued(job))
    }

    /// Removes an ended job's row (its files are removed by the caller).
    pub fn delete(&self, id: i64) -> rusqlite::Result<bool> {
        Ok(self.conn().execute("DELETE FROM jobs WHERE id = ?1 AND state IN ('done', 'failed', 'cancelled')", [id])?
            == 1)
    }

    /// Ended jobs that finished before `before` (seconds since the epoch).
    pub fn ended_before(&self, before: f64) -> rusqlite::Result<Vec<i64>> {
        let conn = self.conn();
        let mut st = conn.prepare(
            "SELECT id FROM jobs WHERE state IN ('done', 'failed', 'cancelled') AND finished_at < ?1 ORDER BY id",
        )?;
        let rows = st.query_map([before], |r| r.get(0))?;
        rows.collect()
    }
}
