-- A job's convergence history: one row per recorded point, roughly log-spaced in time (the
-- monitor decides), so that a long job keeps a bounded number of rows.
CREATE TABLE job_progress (
    job_id        TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    elapsed_ms    INTEGER NOT NULL,    -- since the job's first lease
    samples_done  INTEGER NOT NULL,    -- merged into the image the estimate was made on
    rel_error     DOUBLE PRECISION,
    PRIMARY KEY (job_id, elapsed_ms)
);
