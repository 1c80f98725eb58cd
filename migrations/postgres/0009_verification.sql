-- Verification of results by other workers (keep in step with the other dialect; the server's
-- store/verification.rs says how they are used).
-- A verification task renders an already merged task again: it names the task it checks.
ALTER TABLE tasks ADD COLUMN verifies BIGINT;
-- The task's own accumulation (slice encoding), kept while it is being verified, and that of a
-- verification task until it is judged.
ALTER TABLE tasks ADD COLUMN accum BYTEA;
-- A checked task's verification: pending, disputed (a second opinion disagreed: a third decides),
-- verified, refuted, upheld or inconclusive.
ALTER TABLE tasks ADD COLUMN verify_state TEXT;
-- Workers (ids separated by spaces) that must not be given this task: a verification is never
-- rendered by a worker that already gave its result.
ALTER TABLE tasks ADD COLUMN not_for TEXT;
-- Verification tasks of the job not judged yet: the job completes only once they are.
ALTER TABLE jobs ADD COLUMN verifying BIGINT NOT NULL DEFAULT 0;
-- A worker caught merging a wrong result: it is given no more tasks.
ALTER TABLE workers ADD COLUMN untrusted BIGINT NOT NULL DEFAULT 0;
-- Which workers merged into which tiles (kept while verification is on): the tiles to render
-- again when one of them turns out untrustworthy.
CREATE TABLE tile_workers (
    job_id TEXT NOT NULL,
    tile_index BIGINT NOT NULL,
    worker_id TEXT NOT NULL,
    PRIMARY KEY (job_id, tile_index, worker_id)
);
CREATE INDEX tile_workers_by_worker ON tile_workers(worker_id);
-- The monitor looks for verification tasks no worker may take.
CREATE INDEX tasks_verifications ON tasks(verifies) WHERE verifies IS NOT NULL;
