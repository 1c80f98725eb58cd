-- pathfarm schema, SQLite dialect (keep in step with migrations/postgres).
-- Integers are 64-bit everywhere so that one set of queries decodes the same on both stores.

CREATE TABLE scenes (
    hash        TEXT PRIMARY KEY,           -- SHA-256 of the bytes, hex
    bytes       BLOB NOT NULL,
    size        INTEGER NOT NULL,
    created_ms  INTEGER NOT NULL
);

CREATE TABLE jobs (
    id                TEXT PRIMARY KEY,
    name              TEXT NOT NULL,
    scene_hash        TEXT NOT NULL REFERENCES scenes(hash),
    settings          TEXT NOT NULL,        -- JobSettings as JSON
    priority          INTEGER NOT NULL,
    state             TEXT NOT NULL,
    samples_planned   INTEGER NOT NULL,
    samples_done      INTEGER NOT NULL DEFAULT 0,
    queued_tasks      INTEGER NOT NULL,
    leased_tasks      INTEGER NOT NULL DEFAULT 0,
    version           INTEGER NOT NULL DEFAULT 0,   -- +1 per merged slice
    rel_error         DOUBLE PRECISION,
    rel_error_version INTEGER NOT NULL DEFAULT -1,
    created_ms        INTEGER NOT NULL,
    started_ms        INTEGER,
    finished_ms       INTEGER,
    message           TEXT
);
CREATE INDEX jobs_by_state ON jobs(state, priority);
CREATE INDEX jobs_by_created ON jobs(created_ms);

CREATE TABLE tiles (
    job_id      TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    tile_index  INTEGER NOT NULL,
    x0          INTEGER NOT NULL,
    y0          INTEGER NOT NULL,
    width       INTEGER NOT NULL,
    height      INTEGER NOT NULL,
    samples     INTEGER NOT NULL DEFAULT 0, -- per pixel, merged
    accum       BLOB,                       -- merged accumulation (slice encoding); NULL until the first slice
    PRIMARY KEY (job_id, tile_index)
);

CREATE TABLE tasks (
    id                INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id            TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    tile_index        INTEGER NOT NULL,
    pass              INTEGER NOT NULL,
    sample_begin      INTEGER NOT NULL,
    sample_end        INTEGER NOT NULL,
    done_end          INTEGER NOT NULL,     -- samples [sample_begin, done_end) are merged
    state             TEXT NOT NULL,
    lease_token       TEXT,
    worker_id         TEXT,
    lease_expires_ms  INTEGER,
    leases            INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX tasks_pick ON tasks(job_id, state, pass, id);
CREATE INDEX tasks_expiry ON tasks(state, lease_expires_ms);

CREATE TABLE workers (
    id             TEXT PRIMARY KEY,
    name           TEXT NOT NULL,
    host           TEXT NOT NULL,
    threads        INTEGER NOT NULL,
    version        TEXT NOT NULL,
    state          TEXT NOT NULL,
    registered_ms  INTEGER NOT NULL,
    last_seen_ms   INTEGER NOT NULL,
    current_task   INTEGER,
    current_job    TEXT,
    samples_done   INTEGER NOT NULL DEFAULT 0
);
