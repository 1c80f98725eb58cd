-- Worker identities (keep in step with migrations/postgres). A registration gets a secret
-- credential of its own; only its SHA-256 digest (hex) is stored, so the database does not hold
-- anything a worker could present. Rows from before this migration have none: they cannot act
-- any more, and are collected once idle like any other registration.
ALTER TABLE workers ADD COLUMN credential_digest TEXT;
CREATE UNIQUE INDEX workers_by_credential ON workers(credential_digest);
-- Idle registrations are found by when they were last seen; leases by their holder (the per-worker
-- lease cap counts them on every lease).
CREATE INDEX workers_by_last_seen ON workers(last_seen_ms);
CREATE INDEX tasks_by_worker ON tasks(worker_id, state);
