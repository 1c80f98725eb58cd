//! Task leases: which task a worker gets next, and the writes that hand it over.
//!
//! Jobs are taken by priority (highest first), then fair share (the job with the fewest leased
//! tasks), then age; within a job, by pass, so every tile gets its first samples before any gets
//! more. Lock order as everywhere (see [`super::tasks`]): tasks, tiles, jobs, workers.

use super::error::{Error, StoreResult};
use super::jobs::job_state;
use super::statements::Statements;
use super::tasks::{new_token, task_state};
use super::writes::{Done, Op};
use super::{Dialect, Store};
use crate::states::{job_transition, task_transition, JobEvent, TaskEvent, WorkerEvent};
use pathfarm_wire::api::{JobSettings, Lease, TileRect};
use sqlx::any::AnyRow;
use sqlx::Row;

/// The job order of the scheduler, shared by both dialects' queries.
macro_rules! candidate_jobs {
    () => {
        "SELECT id, state, settings, scene_hash, priority, leased_tasks, created_ms FROM jobs \
         WHERE state IN ('queued', 'running') AND queued_tasks > 0 \
         ORDER BY priority DESC, leased_tasks ASC, created_ms ASC, id ASC LIMIT 8"
    };
}

/// A task condition: not refused to the worker in parameter `$w`: its own slice of the task had
/// every sample invalid (`all_invalid.rs`), or it gave its result for the task a verification
/// task checks (`verification.rs`).
macro_rules! not_refused_by {
    ($w:literal) => {
        concat!(
            "(all_invalid_worker IS NULL OR all_invalid_worker <> ",
            $w,
            ") AND (not_for IS NULL OR (' ' || not_for || ' ') NOT LIKE ('% ' || ",
            $w,
            " || ' %'))"
        )
    };
}

/// The chosen task: its row (`id`, `tile_index`, `done_end`, `sample_end`, `state`) and its
/// tile's rectangle and frame with its job's row (`x0`…`height`, `frame`, `job_state`,
/// `settings`, `scene_hash`),
/// a second row where the dialect read them apart (`None`: the task's row holds them too).
struct Picked {
    job_id: String,
    task: AnyRow,
    job: Option<AnyRow>,
}

impl Store {
    /// Whether any job has a queued task (one some worker may lease: paused jobs and tasks
    /// refused to particular workers aside). What wakes long-polled leases from the monitor
    /// ([`crate::work_signal`]).
    pub async fn has_queued_work(&self) -> StoreResult<bool> {
        Ok(sqlx::query(
            "SELECT 1 AS one FROM jobs WHERE state IN ('queued', 'running') AND queued_tasks > 0 \
             LIMIT 1",
        )
        .fetch_optional(self.pool())
        .await?
        .is_some())
    }

    /// Leases the next task for `worker_id`, or `None` when there is no work; refused
    /// ([`Error::TooManyLeases`]) when the worker already holds `max_leases`.
    /// On SQLite leases share transactions with merges (group commit).
    pub async fn lease(
        &self,
        worker_id: &str,
        lease_ms: u64,
        max_leases: u32,
    ) -> StoreResult<Option<Lease>> {
        if self.write_queue.is_some() {
            let op = Op::Lease {
                worker_id: worker_id.to_string(),
                lease_ms,
                max_leases,
            };
            return match self.grouped(op).await? {
                Done::Leased(lease) => Ok(lease.map(|l| *l)),
                Done::Merged(_) => Err(Error::internal("a lease answered as a merge")),
            };
        }
        let mut w = self.write().await?;
        let lease = self
            .lease_in(&mut w.tx, worker_id, lease_ms, max_leases)
            .await?;
        w.commit().await?;
        Ok(lease)
    }

    /// The lease itself, inside the caller's transaction; client errors come before any write.
    pub(super) async fn lease_in(
        &self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
        worker_id: &str,
        lease_ms: u64,
        max_leases: u32,
    ) -> StoreResult<Option<Lease>> {
        // The cap, before anything is picked or written (a refusal, so a batch goes on). On
        // PostgreSQL, where servers lease concurrently, one worker's leases are taken one at a time
        // (a transaction-scoped advisory lock on the worker): two racing on two servers would
        // otherwise both count the same held leases and both pass. Only leases take it, first,
        // so it adds no cycle to the row locks' order.
        if self.dialect() == Dialect::Postgres {
            sqlx::query("SELECT pg_advisory_xact_lock($1)")
                .bind(lease_lock_key(worker_id))
                .execute(&mut **tx)
                .await?;
        }
        let row = sqlx::query(
            "SELECT COUNT(*) AS n, (SELECT untrusted FROM workers WHERE id = $1) AS untrusted \
             FROM tasks WHERE worker_id = $1 AND state = 'leased'",
        )
        .bind(worker_id)
        .fetch_one(&mut **tx)
        .await?;
        let held: i64 = row.try_get("n")?;
        // Caught merging a wrong result (`verification.rs`): no more work.
        if row.try_get::<Option<i64>, _>("untrusted")? == Some(1) {
            return Err(Error::Untrusted {
                worker_id: worker_id.to_string(),
            });
        }
        if held >= i64::from(max_leases) {
            return Err(Error::TooManyLeases {
                worker_id: worker_id.to_string(),
                held: held as u64,
            });
        }
        let picked = match self.dialect() {
            Dialect::Sqlite => pick_sqlite(tx, worker_id).await?,
            Dialect::Postgres => pick_postgres(tx, worker_id).await?,
        };
        let Some(Picked { job_id, task, job }) = picked else {
            sqlx::query(sql!(
                "UPDATE workers SET state = {}, current_task = NULL, current_job = NULL, \
                 last_seen_ms = $1 WHERE id = $2",
                super::worker_state_after(WorkerEvent::NoWork)
            ))
            .bind(self.now_ms())
            .bind(worker_id)
            .execute(&mut **tx)
            .await?;
            return Ok(None);
        };
        let task_id: i64 = task.try_get("id")?;
        let begin: i64 = task.try_get("done_end")?;
        let end: i64 = task.try_get("sample_end")?;
        let to = task_transition(
            task_state(&task.try_get::<String, _>("state")?)?,
            TaskEvent::Lease,
        )
        .map_err(Error::internal)?;
        let job = job.as_ref().unwrap_or(&task);
        let state = job_state(&job.try_get::<String, _>("job_state")?)?;
        let job_to = job_transition(state, JobEvent::Leased).map_err(Error::internal)?;
        let settings: String = job.try_get("settings")?;
        let settings: JobSettings = serde_json::from_str(&settings)
            .map_err(|e| Error::internal(format!("stored settings: {e}")))?;
        let g = |c: &str| job.try_get::<i64, _>(c).map(|v| v as u32);
        let tile = TileRect {
            x0: g("x0")?,
            y0: g("y0")?,
            width: g("width")?,
            height: g("height")?,
        };
        let token = new_token();
        let now = self.now_ms();
        let expires = now + lease_ms as i64;
        // The writes in lock order, in one round trip on SQLite.
        let mut writes = Statements::new(self.dialect());
        writes
            .push(
                "UPDATE tasks SET state = $1, lease_token = $2, worker_id = $3, \
                 lease_expires_ms = $4, leases = leases + 1 WHERE id = $5",
                vec![
                    to.as_str().into(),
                    token.as_str().into(),
                    worker_id.into(),
                    expires.into(),
                    task_id.into(),
                ],
            )
            .push(
                "UPDATE jobs SET state = $1, started_ms = COALESCE(started_ms, $2), \
                 queued_tasks = queued_tasks - 1, leased_tasks = leased_tasks + 1 WHERE id = $3",
                vec![job_to.as_str().into(), now.into(), job_id.as_str().into()],
            )
            .push(
                format!(
                    "UPDATE workers SET state = {}, current_task = $1, current_job = $2, \
                     last_seen_ms = $3 WHERE id = $4",
                    super::worker_state_after(WorkerEvent::Leased)
                ),
                vec![
                    task_id.into(),
                    job_id.as_str().into(),
                    now.into(),
                    worker_id.into(),
                ],
            );
        writes.run(tx).await?;
        Ok(Some(Lease {
            task_id,
            job_id,
            lease_token: token,
            lease_expires_in_ms: lease_ms,
            scene_hash: job.try_get("scene_hash")?,
            settings,
            tile,
            sample_begin: begin as u32,
            sample_end: end as u32,
            frame: job.try_get("frame")?,
            slice_seconds: None,
        }))
    }
}

/// The advisory lock key of `worker_id`'s leases: the leading 64 bits of its SHA-256 (a key
/// shared by two workers only makes their leases wait for each other).
fn lease_lock_key(worker_id: &str) -> i64 {
    use sha2::{Digest, Sha256};
    let digest = Sha256::new()
        .chain_update(b"pathfarm lease ")
        .chain_update(worker_id.as_bytes())
        .finalize();
    let mut lead = [0u8; 8];
    lead.copy_from_slice(&digest[..8]);
    i64::from_be_bytes(lead)
}

/// SQLite, with its one writer (nothing else can claim a task meanwhile): the worker's existence,
/// the candidate jobs, each one's next task, its tile and its job, in one query. No row: no such
/// worker; a row without a task: no work.
async fn pick_sqlite(
    tx: &mut sqlx::Transaction<'static, sqlx::Any>,
    worker_id: &str,
) -> StoreResult<Option<Picked>> {
    let row = sqlx::query(concat!(
        "SELECT w.id AS worker, c.* FROM workers w LEFT JOIN (\
         SELECT t.id, t.tile_index, t.done_end, t.sample_end, t.state, \
         ti.x0, ti.y0, ti.width, ti.height, ti.frame, j.id AS job_id, j.state AS job_state, j.settings, \
         j.scene_hash, j.priority, j.leased_tasks, j.created_ms FROM (",
        candidate_jobs!(),
        ") j JOIN tasks t ON t.id = (SELECT id FROM tasks \
         WHERE job_id = j.id AND state = 'queued' AND ",
        not_refused_by!("$1"),
        " ORDER BY pass, id LIMIT 1) \
         JOIN tiles ti ON ti.job_id = t.job_id AND ti.tile_index = t.tile_index) c ON 1 = 1 \
         WHERE w.id = $1 \
         ORDER BY c.priority DESC, c.leased_tasks ASC, c.created_ms ASC, c.job_id ASC LIMIT 1"
    ))
    .bind(worker_id)
    .fetch_optional(&mut **tx)
    .await?;
    let Some(row) = row else {
        return Err(Error::not_found("worker", worker_id));
    };
    let Some(job_id) = row.try_get::<Option<String>, _>("job_id")? else {
        return Ok(None);
    };
    Ok(Some(Picked {
        job_id,
        task: row,
        job: None,
    }))
}

/// PostgreSQL, where other servers claim tasks concurrently: the candidates, then per candidate
/// its next task not locked by another transaction (`SKIP LOCKED`), then that task's job row
/// locked, in the documented order; a candidate whose locked row is no longer leasable (paused
/// or ended meanwhile) is skipped.
async fn pick_postgres(
    tx: &mut sqlx::Transaction<'static, sqlx::Any>,
    worker_id: &str,
) -> StoreResult<Option<Picked>> {
    let candidates = sqlx::query(concat!(
        "SELECT w.id AS worker, j.id AS job_id FROM workers w LEFT JOIN (",
        candidate_jobs!(),
        ") j ON 1 = 1 WHERE w.id = $1 \
         ORDER BY j.priority DESC, j.leased_tasks ASC, j.created_ms ASC, j.id ASC"
    ))
    .bind(worker_id)
    .fetch_all(&mut **tx)
    .await?;
    if candidates.is_empty() {
        return Err(Error::not_found("worker", worker_id));
    }
    for cand in candidates {
        let Some(job_id) = cand.try_get::<Option<String>, _>("job_id")? else {
            continue;
        };
        let task = sqlx::query(concat!(
            "SELECT id, tile_index, done_end, sample_end, state FROM tasks \
             WHERE job_id = $1 AND state = 'queued' AND ",
            not_refused_by!("$2"),
            " ORDER BY pass, id LIMIT 1 FOR UPDATE SKIP LOCKED",
        ))
        .bind(&job_id)
        .bind(worker_id)
        .fetch_optional(&mut **tx)
        .await?;
        let Some(task) = task else { continue };
        let job = sqlx::query(
            "SELECT ti.x0, ti.y0, ti.width, ti.height, ti.frame, j.state AS job_state, j.settings, \
             j.scene_hash FROM tiles ti JOIN jobs j ON j.id = ti.job_id \
             WHERE ti.job_id = $1 AND ti.tile_index = $2 FOR UPDATE OF j",
        )
        .bind(&job_id)
        .bind(task.try_get::<i64, _>("tile_index")?)
        .fetch_one(&mut **tx)
        .await?;
        // The candidates were read without a lock: the job may have been paused (or ended) since,
        // by a transaction that committed before this one locked the job's row. The row read
        // under the lock is current; a job that can no longer be leased is passed over (its task
        // stays queued, unlocked when this transaction ends).
        let state = job_state(&job.try_get::<String, _>("job_state")?)?;
        if job_transition(state, JobEvent::Leased).is_err() {
            continue;
        }
        return Ok(Some(Picked {
            job_id,
            task,
            job: Some(job),
        }));
    }
    Ok(None)
}
