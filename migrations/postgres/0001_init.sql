-- pathfarm schema, PostgreSQL dialect (keep in step with migrations/sqlite).
-- Integers are 64-bit everywhere so that one set of queries decodes the same on both stores.

CREATE TABLE scenes (
    hash        TEXT PRIMARY KEY,           -- SHA-256 of the bytes, hex
    bytes       BYTEA NOT NULL,
    size        BIGINT NOT NULL,
    created_ms  BIGINT NOT NULL
);

CREATE TABLE jobs (
    id                TEXT PRIMARY KEY,
    name              TEXT NOT NULL,
    scene_hash        TEXT NOT NULL REFERENCES scenes(hash),
    settings          TEXT NOT NULL,        -- JobSettings as JSON
    priority          BIGINT NOT NULL,
    state             TEXT NOT NULL,
    samples_planned   BIGINT NOT NULL,
    samples_done      BIGINT NOT NULL DEFAULT 0,
    queued_tasks      BIGINT NOT NULL,
    leased_tasks      BIGINT NOT NULL DEFAULT 0,
    version           BIGINT NOT NULL DEFAULT 0,   -- +1 per merged slice
    rel_error         DOUBLE PRECISION,
    rel_error_version BIGINT NOT NULL DEFAULT -1,
    created_ms        BIGINT NOT NULL,
    started_ms        BIGINT,
    finished_ms       BIGINT,
    message           TEXT
);
CREATE INDEX jobs_by_state ON jobs(state, priority);
CREATE INDEX jobs_by_created ON jobs(created_ms);

CREATE TABLE tiles (
    job_id      TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    tile_index  BIGINT NOT NULL,
    x0          BIGINT NOT NULL,
    y0          BIGINT NOT NULL,
    width       BIGINT NOT NULL,
    height      BIGINT NOT NULL,
    samples     BIGINT NOT NULL DEFAULT 0, -- per pixel, merged
    accum       BYTEA,                       -- merged accumulation (slice encoding); NULL until the first slice
    PRIMARY KEY (job_id, tile_index)
);

CREATE TABLE tasks (
    id                BIGSERIAL PRIMARY KEY,
    job_id            TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    tile_index        BIGINT NOT NULL,
    pass              BIGINT NOT NULL,
    sample_begin      BIGINT NOT NULL,
    sample_end        BIGINT NOT NULL,
    done_end          BIGINT NOT NULL,     -- samples [sample_begin, done_end) are merged
    state             TEXT NOT NULL,
    lease_token       TEXT,
    worker_id         TEXT,
    lease_expires_ms  BIGINT,
    leases            BIGINT NOT NULL DEFAULT 0
);
CREATE INDEX tasks_pick ON tasks(job_id, state, pass, id);
CREATE INDEX tasks_expiry ON tasks(state, lease_expires_ms);

CREATE TABLE workers (
    id             TEXT PRIMARY KEY,
    name           TEXT NOT NULL,
    host           TEXT NOT NULL,
    threads        BIGINT NOT NULL,
    version        TEXT NOT NULL,
    state          TEXT NOT NULL,
    registered_ms  BIGINT NOT NULL,
    last_seen_ms   BIGINT NOT NULL,
    current_task   BIGINT,
    current_job    TEXT,
    samples_done   BIGINT NOT NULL DEFAULT 0
);
