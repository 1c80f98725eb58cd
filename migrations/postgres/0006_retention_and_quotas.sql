-- Retention, quotas and submissions stored in batches (keep in step with migrations/sqlite).
-- A job's owner is the client token that submitted it, as the first 16 hex digits of the token's
-- SHA-256 ('' when the server takes no tokens); quotas count jobs and bytes per owner. Its stored
-- bytes are what it may take in the store at most (its scene, its environment image, its tiles'
-- largest accumulations), fixed at submission. Tasks still to be stored: a big submission stores
-- its tasks in several short transactions, counting down; a job whose count stays above zero was
-- interrupted (its server stopped) and is failed by the monitor.
ALTER TABLE jobs ADD COLUMN owner TEXT NOT NULL DEFAULT '';
ALTER TABLE jobs ADD COLUMN stored_bytes BIGINT NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN tasks_to_store BIGINT NOT NULL DEFAULT 0;
-- Retention finds finished jobs by when they finished; quotas count an owner's jobs by state.
CREATE INDEX jobs_by_finished ON jobs(finished_ms);
CREATE INDEX jobs_by_owner ON jobs(owner, state);
