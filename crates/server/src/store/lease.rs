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
use super::Store;
use crate::states::{job_transition, task_transition, JobEvent, TaskEvent, TaskState, WorkerEvent};
use pathfarm_wire::api::{JobSettings, Lease, TileRect};
use sqlx::any::AnyRow;
use sqlx::Row;
use std::sync::LazyLock;

/// The job order of the scheduler, shared by both dialects: SQLite's lease query embeds it,
/// PostgreSQL's lease function runs it as given.
macro_rules! candidate_jobs {
    () => {
        "SELECT id, state, settings, scene_hash, priority, leased_tasks, created_ms FROM jobs \
         WHERE state IN ('queued', 'running') AND queued_tasks > 0 \
         ORDER BY priority DESC, leased_tasks ASC, created_ms ASC, id ASC LIMIT 8"
    };
}

/// A task condition: not refused to the worker in parameter `$w`: its own slice of the task had
/// every sample invalid (`all_invalid.rs`), or it gave its result for the task a verification
/// task checks (`verification.rs`). SQLite's; PostgreSQL's lease function spells the same
/// condition (`migrations/postgres/0012_lease_and_merge_functions.sql`).
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

/// The state moves `pathfarm_lease` makes, as JSON (`states.rs`'s, spelled once per process).
static LEASED_JOB_MOVES: LazyLock<String> =
    LazyLock::new(|| super::job_moves_json(JobEvent::Leased));
static LEASED_WORKER_MOVES: LazyLock<String> =
    LazyLock::new(|| super::worker_moves_json(WorkerEvent::Leased));
static NO_WORK_WORKER_MOVES: LazyLock<String> =
    LazyLock::new(|| super::worker_moves_json(WorkerEvent::NoWork));

/// The chosen task on SQLite: its job and one row with the task (`id`, `tile_index`, `done_end`,
/// `sample_end`, `state`), its tile's rectangle and frame (`x0`…`height`, `frame`) and its job's
/// `job_state`, `settings` and `scene_hash`.
struct Picked {
    job_id: String,
    task: AnyRow,
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
        self.lease_postgres(worker_id, lease_ms, max_leases).await
    }

    /// The cap and the worker's standing, before anything is picked or written (a refusal, so a
    /// batch goes on). SQLite only, where its one writer orders every lease; on PostgreSQL
    /// `pathfarm_lease` checks the same under the worker's lease lock.
    async fn check_lease_cap(
        &self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
        worker_id: &str,
        max_leases: u32,
    ) -> StoreResult<()> {
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
        Ok(())
    }

    /// Records that `worker_id` asked for work and there was none.
    async fn no_work(
        &self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
        worker_id: &str,
    ) -> StoreResult<()> {
        sqlx::query(sql!(
            "UPDATE workers SET state = {}, current_task = NULL, current_job = NULL, \
             last_seen_ms = $1 WHERE id = $2",
            super::worker_state_after(WorkerEvent::NoWork)
        ))
        .bind(self.now_ms())
        .bind(worker_id)
        .execute(&mut **tx)
        .await?;
        Ok(())
    }

    /// The lease itself on SQLite, inside the caller's transaction (a group commit's); client
    /// errors come before any write.
    pub(super) async fn lease_in(
        &self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
        worker_id: &str,
        lease_ms: u64,
        max_leases: u32,
    ) -> StoreResult<Option<Lease>> {
        self.check_lease_cap(tx, worker_id, max_leases).await?;
        let Some(Picked { job_id, task }) = pick_sqlite(tx, worker_id).await? else {
            self.no_work(tx, worker_id).await?;
            return Ok(None);
        };
        let task_id: i64 = task.try_get("id")?;
        let to = task_transition(
            task_state(&task.try_get::<String, _>("state")?)?,
            TaskEvent::Lease,
        )
        .map_err(Error::internal)?;
        let state = job_state(&task.try_get::<String, _>("job_state")?)?;
        let job_to = job_transition(state, JobEvent::Leased).map_err(Error::internal)?;
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
        lease_answer(task_id, job_id, token, lease_ms, &task, &task).map(Some)
    }

    /// The lease on PostgreSQL, in one statement outside any explicit transaction: on a busy farm
    /// every lease and every merge writes the same row, their job's (its counters), and each
    /// waits for the transaction that holds it. The function `pathfarm_lease`
    /// (`migrations/postgres/0013_lease_reads_its_candidates.sql`) takes the worker's lease lock,
    /// checks the cap, runs the candidate query it is given (`candidate_jobs!`, the scheduler's
    /// order, without locks), claims the first candidate's next task, writes task, job and
    /// worker, and commits inside this one round trip, so the job's row is never held while this
    /// server is busy elsewhere and a lease waits for one pooled connection once
    /// (docs/benchmarks.md, "the lease and the merge in one statement", "a lease in one round
    /// trip, and a shorter write queue"). The state machines' moves are passed in.
    async fn lease_postgres(
        &self,
        worker_id: &str,
        lease_ms: u64,
        max_leases: u32,
    ) -> StoreResult<Option<Lease>> {
        // The claim's filter takes only queued tasks.
        let to = task_transition(TaskState::Queued, TaskEvent::Lease).map_err(Error::internal)?;
        let token = new_token();
        let now = self.now_ms();
        let row = sqlx::query(
            "SELECT outcome, held, task_id, job_id, done_end, sample_end, x0, y0, width, \
             height, frame, settings, scene_hash \
             FROM pathfarm_lease($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11)",
        )
        .bind(worker_id)
        .bind(lease_lock_key(worker_id))
        .bind(i64::from(max_leases))
        .bind(candidate_jobs!())
        .bind(now)
        .bind(now + lease_ms as i64)
        .bind(&token)
        .bind(to.as_str())
        .bind(LEASED_JOB_MOVES.as_str())
        .bind(LEASED_WORKER_MOVES.as_str())
        .bind(NO_WORK_WORKER_MOVES.as_str())
        .fetch_one(self.pool())
        .await
        .map_err(|e| match &e {
            // The worker deregistered while its lease was written (rolled back).
            sqlx::Error::Database(d) if d.code().as_deref() == Some("P0002") => {
                Error::not_found("worker", worker_id)
            }
            _ => e.into(),
        })?;
        let held = || -> StoreResult<u64> { Ok(row.try_get::<i64, _>("held")? as u64) };
        match row.try_get::<String, _>("outcome")?.as_str() {
            "leased" => {
                let task_id: i64 = row.try_get("task_id")?;
                let job_id: String = row.try_get("job_id")?;
                lease_answer(task_id, job_id, token, lease_ms, &row, &row).map(Some)
            }
            "none" => Ok(None),
            "no_worker" => Err(Error::not_found("worker", worker_id)),
            "untrusted" => Err(Error::Untrusted {
                worker_id: worker_id.to_string(),
            }),
            "too_many" => Err(Error::TooManyLeases {
                worker_id: worker_id.to_string(),
                held: held()?,
            }),
            other => Err(Error::internal(format!(
                "pathfarm_lease answered {other:?}"
            ))),
        }
    }
}

/// The lease of `task_id` as answered to the worker: its range and tile from `task` (`done_end`,
/// `sample_end`, `x0`…`height`, `frame`), its job's `settings` and `scene_hash` from `job`.
fn lease_answer(
    task_id: i64,
    job_id: String,
    lease_token: String,
    lease_ms: u64,
    task: &AnyRow,
    job: &AnyRow,
) -> StoreResult<Lease> {
    let settings: String = job.try_get("settings")?;
    let settings: JobSettings = serde_json::from_str(&settings)
        .map_err(|e| Error::internal(format!("stored settings: {e}")))?;
    let g = |c: &str| task.try_get::<i64, _>(c).map(|v| v as u32);
    Ok(Lease {
        task_id,
        job_id,
        lease_token,
        lease_expires_in_ms: lease_ms,
        scene_hash: job.try_get("scene_hash")?,
        settings,
        tile: TileRect {
            x0: g("x0")?,
            y0: g("y0")?,
            width: g("width")?,
            height: g("height")?,
        },
        sample_begin: g("done_end")?,
        sample_end: g("sample_end")?,
        frame: task.try_get("frame")?,
        slice_seconds: None,
    })
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
    Ok(Some(Picked { job_id, task: row }))
}
