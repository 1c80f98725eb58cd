//! Storing a submitted job: its blobs and row at once, then its tiles and tasks in batches.
//!
//! A big plan (half a million tasks) written in one transaction held SQLite's write lock for over
//! a second, and every lease, upload and heartbeat of the farm waited behind it. So the job's row
//! comes first, with its quota check, not yet leasable (`queued_tasks` is 0, `tasks_to_store` the
//! plan's count); then its tiles, then its tasks, in batches ([`Store::default_batch_rows`]),
//! each its own transaction, which makes its tasks leasable at once (the plan is in lease order,
//! so the first batches are the first passes). Between batches the farm's other writes get their
//! turn.
//!
//! A submission ends early, without error, when its job was cancelled or failed meanwhile, and with
//! [`Error::DeletedWhileStored`] when it was deleted. One whose server stopped halfway leaves its
//! job with `tasks_to_store > 0`; the monitor fails such a job once [`SUBMISSION_TIMEOUT`] passed
//! since it was created ([`Store::fail_interrupted_submissions`]).

use super::error::{Error, StoreResult};
use super::{Dialect, Store};
use crate::config::Quotas;
use crate::scheduler::{PlannedTask, PlannedTile};
use crate::states::TaskState;
use pathfarm_wire::api::{JobSettings, JobState};
use sqlx::Row;
use std::time::Duration;

/// Rows per multi-row INSERT (7 parameters each stays far below both stores' limits).
const INSERT_BATCH: usize = 500;

/// Rows (tiles or tasks) per transaction on SQLite: a few milliseconds of the write lock.
pub const ROWS_PER_TRANSACTION: usize = 5_000;

/// How long after its creation a job whose tasks are not all stored counts as interrupted. A
/// submission stores a few hundred thousand rows a second; the largest plan the limits allow
/// takes seconds.
pub const SUBMISSION_TIMEOUT: Duration = Duration::from_secs(600);

pub struct NewJob {
    pub id: String,
    pub name: String,
    pub settings: JobSettings,
    pub scene_hash: String,
    pub scene_bytes: Vec<u8>,
    /// The environment image named by `settings.environment.image`: its hash and bytes, stored
    /// once per hash beside the scenes.
    pub environment: Option<(String, Vec<u8>)>,
    /// The scene loader's warnings, already cleaned and capped ([`crate::routes`]).
    pub warnings: Vec<String>,
    pub tiles: Vec<PlannedTile>,
    pub tasks: Vec<PlannedTask>,
    pub samples_planned: u64,
    /// Who submitted it ([`crate::auth::ClientAuth::owner`]): quotas count per owner.
    pub owner: String,
    /// The most bytes it may take in the store ([`Quotas::max_stored_bytes`]).
    pub stored_bytes: u64,
}

/// What an owner holds: its unfinished jobs and the stored bytes of all its jobs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Usage {
    pub unfinished_jobs: u64,
    pub stored_bytes: u64,
}

impl Usage {
    /// Refuses a job of `stored_bytes` that would take this usage past `quotas`.
    pub fn admit(&self, stored_bytes: u64, quotas: &Quotas) -> StoreResult<()> {
        let checks = [
            (
                "unfinished jobs",
                self.unfinished_jobs + 1,
                quotas.max_unfinished_jobs,
            ),
            (
                "stored bytes",
                self.stored_bytes.saturating_add(stored_bytes),
                quotas.max_stored_bytes,
            ),
        ];
        for (what, would_be, limit) in checks {
            if let Some(limit) = limit.filter(|&l| would_be > l) {
                return Err(Error::QuotaExceeded {
                    what,
                    would_be,
                    limit,
                });
            }
        }
        Ok(())
    }
}

/// Rows of the plan still to store.
enum Batch<'a> {
    Tiles(usize, &'a [PlannedTile]),
    Tasks(&'a [PlannedTask]),
}

impl Store {
    /// Rows a submission stores per transaction unless configured otherwise. SQLite has one
    /// writer: a plan stored at once held every lease, upload and heartbeat for over a second
    /// (458,752 tasks), so it is stored in batches of [`ROWS_PER_TRANSACTION`]. PostgreSQL's
    /// inserts block no other transaction, and there batches measured worse for the farm's
    /// leases (their p99 tripled: rows that become leasable while more arrive, and commits), so
    /// a plan is stored at once (tiles, then tasks). Figures: docs/benchmarks.md.
    pub fn default_batch_rows(&self) -> usize {
        match self.dialect() {
            Dialect::Sqlite => ROWS_PER_TRANSACTION,
            Dialect::Postgres => usize::MAX,
        }
    }

    /// What `owner` holds now.
    pub async fn usage(&self, owner: &str) -> StoreResult<Usage> {
        usage_in(self.pool(), owner).await
    }

    /// Stores the scene and the environment image (each once per content hash) and the job, if
    /// its owner's quotas allow; then its tiles and tasks in batches (see the module's doc).
    /// `batch_rows` rows per transaction (`None`: [`Store::default_batch_rows`]).
    pub async fn create_job(
        &self,
        job: NewJob,
        quotas: &Quotas,
        batch_rows: Option<usize>,
    ) -> StoreResult<()> {
        let batch_rows = batch_rows
            .unwrap_or_else(|| self.default_batch_rows())
            .max(1);
        let settings = serde_json::to_string(&job.settings)
            .map_err(|e| Error::internal(format!("cannot encode settings: {e}")))?;
        let warnings = serde_json::to_string(&job.warnings)
            .map_err(|e| Error::internal(format!("cannot encode warnings: {e}")))?;
        let now = self.now_ms();
        let mut w = self.write().await?;
        // On PostgreSQL two submissions of one owner on two servers may both pass; on SQLite the
        // writer lock makes the check and the insert one step.
        usage_in(&mut *w.tx, &job.owner)
            .await?
            .admit(job.stored_bytes, quotas)?;
        let blobs = std::iter::once((&job.scene_hash, &job.scene_bytes))
            .chain(job.environment.as_ref().map(|(h, b)| (h, b)));
        for (hash, bytes) in blobs {
            // An update of a stored blob (to itself) locks its row: a deletion of its last
            // job under way elsewhere (PostgreSQL) either finishes first, and the blob is stored
            // again, or waits for this job to be stored, and then keeps the blob.
            sqlx::query(
                "INSERT INTO scenes (hash, bytes, size, created_ms) VALUES ($1, $2, $3, $4) \
                 ON CONFLICT (hash) DO UPDATE SET size = scenes.size",
            )
            .bind(hash)
            .bind(bytes)
            .bind(bytes.len() as i64)
            .bind(now)
            .execute(&mut *w.tx)
            .await?;
        }
        sqlx::query(
            "INSERT INTO jobs (id, name, scene_hash, settings, priority, state, samples_planned, \
             queued_tasks, created_ms, environment_hash, warnings, owner, stored_bytes, \
             tasks_to_store) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, 0, $8, $9, $10, $11, $12, $13)",
        )
        .bind(&job.id)
        .bind(&job.name)
        .bind(&job.scene_hash)
        .bind(&settings)
        .bind(job.settings.priority as i64)
        .bind(JobState::Queued.as_str())
        .bind(job.samples_planned as i64)
        .bind(now)
        .bind(job.environment.as_ref().map(|(h, _)| h.as_str()))
        .bind(&warnings)
        .bind(&job.owner)
        .bind(job.stored_bytes as i64)
        .bind(job.tasks.len() as i64)
        .execute(&mut *w.tx)
        .await?;
        w.commit().await?;

        let tiles = job
            .tiles
            .chunks(batch_rows)
            .enumerate()
            .map(|(i, c)| Batch::Tiles(i * batch_rows, c));
        let tasks = job.tasks.chunks(batch_rows).map(Batch::Tasks);
        for batch in tiles.chain(tasks) {
            if !self.store_batch(&job.id, batch).await? {
                tracing::info!(job = %job.id, "job ended while its submission was stored");
                break;
            }
        }
        Ok(())
    }

    /// Stores one batch of a job's plan in its own transaction; false (nothing stored) when the
    /// job has ended meanwhile. Rows first, then the job's row: the lock order (tasks, tiles,
    /// jobs) every transaction follows.
    async fn store_batch(&self, job_id: &str, batch: Batch<'_>) -> StoreResult<bool> {
        let mut w = self.write().await?;
        let state: Option<String> = sqlx::query("SELECT state FROM jobs WHERE id = $1")
            .bind(job_id)
            .fetch_optional(&mut *w.tx)
            .await?
            .map(|r| r.try_get("state"))
            .transpose()?;
        let Some(state) = state else {
            return Err(Error::DeletedWhileStored(job_id.to_string()));
        };
        if super::jobs::job_state(&state)?.is_final() {
            return Ok(false);
        }
        match batch {
            Batch::Tiles(first_index, tiles) => {
                for (chunk_index, chunk) in tiles.chunks(INSERT_BATCH).enumerate() {
                    let mut sql = String::from(
                        "INSERT INTO tiles (job_id, tile_index, x0, y0, width, height, frame) \
                         VALUES ",
                    );
                    push_placeholders(&mut sql, chunk.len(), 7, self.dialect());
                    let mut q = sqlx::query(sqlx::AssertSqlSafe(sql));
                    for (i, PlannedTile { tile: t, frame }) in chunk.iter().enumerate() {
                        q = q
                            .bind(job_id)
                            .bind((first_index + chunk_index * INSERT_BATCH + i) as i64)
                            .bind(t.x0 as i64)
                            .bind(t.y0 as i64)
                            .bind(t.width as i64)
                            .bind(t.height as i64)
                            .bind(*frame);
                    }
                    q.execute(&mut *w.tx).await?;
                }
            }
            Batch::Tasks(tasks) => {
                for chunk in tasks.chunks(INSERT_BATCH) {
                    let mut sql = String::from(
                        "INSERT INTO tasks (job_id, tile_index, pass, sample_begin, sample_end, \
                         done_end, state) VALUES ",
                    );
                    push_placeholders(&mut sql, chunk.len(), 7, self.dialect());
                    let mut q = sqlx::query(sqlx::AssertSqlSafe(sql));
                    for t in chunk {
                        q = q
                            .bind(job_id)
                            .bind(t.tile_index as i64)
                            .bind(t.pass as i64)
                            .bind(t.sample_begin as i64)
                            .bind(t.sample_end as i64)
                            .bind(t.sample_begin as i64)
                            .bind(TaskState::Queued.as_str());
                    }
                    q.execute(&mut *w.tx).await?;
                }
                sqlx::query(
                    "UPDATE jobs SET queued_tasks = queued_tasks + $1, \
                     tasks_to_store = tasks_to_store - $1 WHERE id = $2",
                )
                .bind(tasks.len() as i64)
                .bind(job_id)
                .execute(&mut *w.tx)
                .await?;
            }
        }
        w.commit().await?;
        Ok(true)
    }
}

/// What `owner` holds, read on `executor` (the pool, or the submission's transaction).
async fn usage_in<'e, E>(executor: E, owner: &str) -> StoreResult<Usage>
where
    E: sqlx::Executor<'e, Database = sqlx::Any>,
{
    let row = sqlx::query(
        "SELECT CAST(COALESCE(SUM(CASE WHEN state IN ('queued', 'running', 'paused') THEN 1 \
         ELSE 0 END), 0) AS BIGINT) AS unfinished, \
         CAST(COALESCE(SUM(stored_bytes), 0) AS BIGINT) AS bytes FROM jobs WHERE owner = $1",
    )
    .bind(owner)
    .fetch_one(executor)
    .await?;
    Ok(Usage {
        unfinished_jobs: row.try_get::<i64, _>("unfinished")? as u64,
        stored_bytes: row.try_get::<i64, _>("bytes")? as u64,
    })
}

/// Appends `($1, $2, …), (…)` for `rows` rows of `cols` parameters.
fn push_placeholders(sql: &mut String, rows: usize, cols: usize, dialect: Dialect) {
    use std::fmt::Write;
    for r in 0..rows {
        sql.push_str(if r == 0 { "(" } else { ", (" });
        for c in 0..cols {
            sql.push_str(if c == 0 { "" } else { ", " });
            match dialect {
                // Anonymous parameters: sqlx binds a named one (`$n`) by asking SQLite for each
                // parameter's name, a scan of the statement's name list, so a 3,500-parameter
                // insert cost 6 million steps; `?` is bound by position.
                Dialect::Sqlite => sql.push('?'),
                Dialect::Postgres => {
                    let _ = write!(sql, "${}", r * cols + c + 1);
                }
            }
        }
        sql.push(')');
    }
}
