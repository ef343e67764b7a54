-- lpm serve: the durable job queue (schema version 1). Applied once by db.rs when PRAGMA
-- user_version is 0; a later schema adds a new file and bumps user_version.
CREATE TABLE jobs (
    id                   INTEGER PRIMARY KEY AUTOINCREMENT,
    state                TEXT    NOT NULL CHECK (state IN ('queued', 'running', 'done', 'failed', 'cancelled')),
    priority             INTEGER NOT NULL DEFAULT 0,
    -- The validated scene as the solve reads it (volume paths made absolute and confined).
    scene                TEXT    NOT NULL,
    device_memory_budget INTEGER,
    no_image             INTEGER NOT NULL DEFAULT 0,
    no_fields            INTEGER NOT NULL DEFAULT 0,
    submitted_at         REAL    NOT NULL,
    started_at           REAL,
    finished_at          REAL,
    -- How many times a worker started the solve (a restart of the server resumes it: attempts > 1).
    attempts             INTEGER NOT NULL DEFAULT 0,
    orders               INTEGER,
    max_orders           INTEGER,
    residual             REAL,
    progress             REAL,
    seconds_left         REAL,
    error                TEXT
);
CREATE INDEX jobs_by_queue ON jobs (state, priority DESC, id);
