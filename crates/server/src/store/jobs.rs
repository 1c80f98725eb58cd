//! Jobs, their tiles and scenes.

use super::error::{Error, StoreResult};
use super::Store;
use crate::states::{job_transition, JobEvent, TaskState, WorkerEvent};
use pathfarm_tracer::Tile;
use pathfarm_wire::api::{JobSettings, JobState};
use sqlx::any::AnyRow;
use sqlx::Row;

const JOB_COLUMNS: &str = "id, name, scene_hash, settings, priority, state, samples_planned, \
    samples_done, queued_tasks, leased_tasks, version, rel_error, rel_error_version, created_ms, \
    started_ms, finished_ms, message, warnings";

/// A job as stored.
#[derive(Clone, Debug)]
pub struct JobRow {
    pub id: String,
    pub name: String,
    pub scene_hash: String,
    pub settings: JobSettings,
    pub priority: i32,
    pub state: JobState,
    pub samples_planned: u64,
    pub samples_done: u64,
    pub queued_tasks: u64,
    pub leased_tasks: u64,
    /// Incremented by every merged slice: the image changes exactly when this does.
    pub version: i64,
    pub rel_error: Option<f64>,
    /// The version `rel_error` was estimated at (behind `version` until the monitor catches up).
    pub rel_error_version: i64,
    pub created_ms: i64,
    pub started_ms: Option<i64>,
    pub finished_ms: Option<i64>,
    pub message: Option<String>,
    /// What the scene loader ignored, as found at submission.
    pub warnings: Vec<String>,
}

impl JobRow {
    pub(crate) fn from_row(row: &AnyRow) -> Result<JobRow, sqlx::Error> {
        let settings: String = row.try_get("settings")?;
        let state: String = row.try_get("state")?;
        Ok(JobRow {
            id: row.try_get("id")?,
            name: row.try_get("name")?,
            scene_hash: row.try_get("scene_hash")?,
            settings: serde_json::from_str(&settings)
                .map_err(|e| sqlx::Error::Decode(Box::new(e)))?,
            priority: row.try_get::<i64, _>("priority")? as i32,
            state: job_state(&state)?,
            samples_planned: row.try_get::<i64, _>("samples_planned")? as u64,
            samples_done: row.try_get::<i64, _>("samples_done")? as u64,
            queued_tasks: row.try_get::<i64, _>("queued_tasks")? as u64,
            leased_tasks: row.try_get::<i64, _>("leased_tasks")? as u64,
            version: row.try_get("version")?,
            rel_error: row.try_get("rel_error")?,
            rel_error_version: row.try_get("rel_error_version")?,
            created_ms: row.try_get("created_ms")?,
            started_ms: row.try_get("started_ms")?,
            finished_ms: row.try_get("finished_ms")?,
            message: row.try_get("message")?,
            warnings: serde_json::from_str(&row.try_get::<String, _>("warnings")?)
                .map_err(|e| sqlx::Error::Decode(Box::new(e)))?,
        })
    }
}

/// A stored job state.
pub(crate) fn job_state(s: &str) -> Result<JobState, sqlx::Error> {
    JobState::parse(s).ok_or_else(|| sqlx::Error::Protocol(format!("unknown job state {s:?}")))
}

/// The one rule by which a job ends by itself: every planned sample merged and every
/// verification judged. `row` is the job's row as an `UPDATE jobs … RETURNING state,
/// samples_done, samples_planned, verifying` inside `tx` gave it (a merge, a verification
/// dropped, frames stopped at the noise target); when the rule holds and the job has not ended,
/// it is completed in `tx`. Returns the job's state after, and whether this completed it.
pub(super) async fn complete_when_done(
    tx: &mut sqlx::Transaction<'static, sqlx::Any>,
    job_id: &str,
    row: &AnyRow,
    now_ms: i64,
) -> StoreResult<(JobState, bool)> {
    let state = job_state(&row.try_get::<String, _>("state")?)?;
    let done =
        row.try_get::<i64, _>("samples_done")? >= row.try_get::<i64, _>("samples_planned")?;
    if !done || row.try_get::<i64, _>("verifying")? > 0 || state.is_final() {
        return Ok((state, false));
    }
    let to = job_transition(state, JobEvent::Complete).map_err(Error::internal)?;
    sqlx::query("UPDATE jobs SET state = $1, finished_ms = $2 WHERE id = $3")
        .bind(to.as_str())
        .bind(now_ms)
        .bind(job_id)
        .execute(&mut **tx)
        .await?;
    Ok((to, true))
}

/// Frees the workers busy with a job that ends or disappears. Called after the job row is
/// written, keeping the lock order (tasks, tiles, jobs, workers).
pub(super) async fn free_job_workers(
    tx: &mut sqlx::Transaction<'static, sqlx::Any>,
    job_id: &str,
) -> Result<(), sqlx::Error> {
    sqlx::query(sql!(
        "UPDATE workers SET current_task = NULL, current_job = NULL, state = {} \
         WHERE current_job = $1 AND state = 'busy'",
        super::worker_state_after(WorkerEvent::TaskTaken)
    ))
    .bind(job_id)
    .execute(&mut **tx)
    .await?;
    Ok(())
}

/// A tile of a job and the samples per pixel merged into it.
#[derive(Clone, Debug)]
pub struct TileRow {
    pub tile_index: u32,
    pub tile: Tile,
    pub samples: u64,
    /// The frame it belongs to (a frame job's tiles only).
    pub frame: Option<i64>,
}

impl TileRow {
    fn from_row(row: &AnyRow) -> Result<TileRow, sqlx::Error> {
        let g = |c: &str| row.try_get::<i64, _>(c);
        Ok(TileRow {
            tile_index: g("tile_index")? as u32,
            tile: Tile {
                x0: g("x0")? as u32,
                y0: g("y0")? as u32,
                width: g("width")? as u32,
                height: g("height")? as u32,
            },
            samples: g("samples")? as u64,
            frame: row.try_get("frame")?,
        })
    }
}

impl Store {
    pub async fn job(&self, id: &str) -> StoreResult<JobRow> {
        let row = sqlx::query(sql!("SELECT {JOB_COLUMNS} FROM jobs WHERE id = $1"))
            .bind(id)
            .fetch_optional(self.pool())
            .await?;
        match row {
            Some(r) => Ok(JobRow::from_row(&r)?),
            None => Err(Error::not_found("job", id)),
        }
    }

    /// A page of jobs, newest first, optionally only those in one state; and the total count.
    pub async fn jobs(
        &self,
        state: Option<JobState>,
        offset: u64,
        limit: u64,
    ) -> StoreResult<(Vec<JobRow>, u64)> {
        let filter = "WHERE ($1 = '' OR state = $1)";
        let state_str = state.map_or("", JobState::as_str);
        let rows = sqlx::query(sql!(
            "SELECT {JOB_COLUMNS} FROM jobs {filter} ORDER BY created_ms DESC, id DESC \
             LIMIT $2 OFFSET $3"
        ))
        .bind(state_str)
        .bind(limit as i64)
        .bind(offset as i64)
        .fetch_all(self.pool())
        .await?;
        let total: i64 = sqlx::query(sql!("SELECT COUNT(*) AS n FROM jobs {filter}"))
            .bind(state_str)
            .fetch_one(self.pool())
            .await?
            .try_get("n")?;
        let jobs = rows
            .iter()
            .map(JobRow::from_row)
            .collect::<Result<Vec<_>, _>>()?;
        Ok((jobs, total as u64))
    }

    /// Jobs in the given states (for the monitor).
    pub async fn jobs_in_states(&self, states: &[JobState]) -> StoreResult<Vec<JobRow>> {
        let list = states
            .iter()
            .map(|s| format!("'{}'", s.as_str()))
            .collect::<Vec<_>>()
            .join(", ");
        let rows = sqlx::query(sql!(
            "SELECT {JOB_COLUMNS} FROM jobs WHERE state IN ({list}) ORDER BY created_ms"
        ))
        .fetch_all(self.pool())
        .await?;
        Ok(rows
            .iter()
            .map(JobRow::from_row)
            .collect::<Result<Vec<_>, _>>()?)
    }

    /// Jobs whose error estimate is older than their image.
    pub async fn jobs_needing_estimate(&self) -> StoreResult<Vec<(String, i64)>> {
        let rows = sqlx::query(
            "SELECT id, version FROM jobs WHERE rel_error_version < version ORDER BY created_ms",
        )
        .fetch_all(self.pool())
        .await?;
        rows.iter()
            .map(|r| Ok((r.try_get("id")?, r.try_get("version")?)))
            .collect()
    }

    pub async fn tiles(&self, job_id: &str) -> StoreResult<Vec<TileRow>> {
        let rows = sqlx::query(
            "SELECT tile_index, x0, y0, width, height, samples, frame FROM tiles \
             WHERE job_id = $1 ORDER BY tile_index",
        )
        .bind(job_id)
        .fetch_all(self.pool())
        .await?;
        Ok(rows
            .iter()
            .map(TileRow::from_row)
            .collect::<Result<Vec<_>, _>>()?)
    }

    /// The state job `job_id` is in, read under lock in `tx`, and the one `event` moves it to (a
    /// transition the state machine refuses is a bug of the caller's: internal).
    pub(super) async fn locked_transition(
        &self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
        job_id: &str,
        event: JobEvent,
    ) -> StoreResult<(JobState, JobState)> {
        let row = sqlx::query(sql!(
            "SELECT state FROM jobs WHERE id = $1{}",
            self.dialect().for_update()
        ))
        .bind(job_id)
        .fetch_one(&mut **tx)
        .await?;
        let from = job_state(&row.try_get::<String, _>("state")?)?;
        let to = job_transition(from, event).map_err(Error::internal)?;
        Ok((from, to))
    }

    /// Applies a state-machine event to a job, with its effect on the job's tasks.
    pub async fn job_event(
        &self,
        id: &str,
        event: JobEvent,
        message: Option<&str>,
    ) -> StoreResult<JobRow> {
        let mut w = self.write().await?;
        // Tasks first, then the job: the lock order every transaction follows (task, tile, job).
        if matches!(
            event,
            JobEvent::Cancel | JobEvent::Complete | JobEvent::Fail
        ) {
            sqlx::query(sql!(
                "UPDATE tasks SET state = '{}', lease_token = NULL \
                 WHERE job_id = $1 AND state IN ('queued', 'leased')",
                TaskState::Cancelled.as_str()
            ))
            .bind(id)
            .execute(&mut *w.tx)
            .await?;
        }
        let row = sqlx::query(sql!(
            "SELECT {JOB_COLUMNS} FROM jobs WHERE id = $1{}",
            self.dialect().for_update()
        ))
        .bind(id)
        .fetch_optional(&mut *w.tx)
        .await?;
        let job = match row {
            Some(r) => JobRow::from_row(&r)?,
            None => return Err(Error::not_found("job", id)),
        };
        let event = match event {
            JobEvent::Resume { .. } => JobEvent::Resume {
                started: job.started_ms.is_some(),
            },
            e => e,
        };
        let to = job_transition(job.state, event).map_err(Error::InvalidState)?;
        let now = self.now_ms();
        if to.is_final() {
            sqlx::query(
                "UPDATE jobs SET state = $1, finished_ms = $2, queued_tasks = 0, leased_tasks = 0, \
                 message = COALESCE($3, message) WHERE id = $4",
            )
            .bind(to.as_str())
            .bind(now)
            .bind(message)
            .bind(id)
            .execute(&mut *w.tx)
            .await?;
            free_job_workers(&mut w.tx, id).await?;
        } else {
            sqlx::query("UPDATE jobs SET state = $1 WHERE id = $2")
                .bind(to.as_str())
                .bind(id)
                .execute(&mut *w.tx)
                .await?;
        }
        w.commit().await?;
        self.job(id).await
    }

    pub async fn set_priority(&self, id: &str, priority: i32) -> StoreResult<JobRow> {
        let mut w = self.write().await?;
        let n = sqlx::query("UPDATE jobs SET priority = $1 WHERE id = $2")
            .bind(priority as i64)
            .bind(id)
            .execute(&mut *w.tx)
            .await?
            .rows_affected();
        w.commit().await?;
        if n == 0 {
            return Err(Error::not_found("job", id));
        }
        self.job(id).await
    }

    /// Deletes a job in any state, with its tiles and tasks; its scene and environment image too
    /// once no job uses them.
    pub async fn delete_job(&self, id: &str) -> StoreResult<()> {
        let mut w = self.write().await?;
        sqlx::query("DELETE FROM tasks WHERE job_id = $1")
            .bind(id)
            .execute(&mut *w.tx)
            .await?;
        sqlx::query("DELETE FROM tiles WHERE job_id = $1")
            .bind(id)
            .execute(&mut *w.tx)
            .await?;
        sqlx::query("DELETE FROM tile_workers WHERE job_id = $1")
            .bind(id)
            .execute(&mut *w.tx)
            .await?;
        let row =
            sqlx::query("DELETE FROM jobs WHERE id = $1 RETURNING scene_hash, environment_hash")
                .bind(id)
                .fetch_optional(&mut *w.tx)
                .await?;
        let Some(row) = row else {
            return Err(Error::not_found("job", id));
        };
        free_job_workers(&mut w.tx, id).await?;
        let scene: String = row.try_get("scene_hash")?;
        let environment: Option<String> = row.try_get("environment_hash")?;
        w.commit().await?;
        // Its blobs after the job is gone, each apart: a submission may be taking the same blob
        // meanwhile (on PostgreSQL), and then the blob stays and the deletion is still done.
        for hash in std::iter::once(scene).chain(environment) {
            self.delete_blob_if_unused(&hash).await?;
        }
        Ok(())
    }

    /// Deletes the scene or environment image `hash` when no job uses it; true when it did. A
    /// concurrent submission that took the blob meanwhile (PostgreSQL: the foreign key refuses
    /// the delete) keeps it.
    pub(super) async fn delete_blob_if_unused(&self, hash: &str) -> StoreResult<bool> {
        let mut w = self.write().await?;
        let deleted = sqlx::query(
            "DELETE FROM scenes WHERE hash = $1 AND NOT EXISTS \
             (SELECT 1 FROM jobs WHERE scene_hash = $1 OR environment_hash = $1)",
        )
        .bind(hash)
        .execute(&mut *w.tx)
        .await;
        match deleted {
            Ok(r) => {
                w.commit().await?;
                Ok(r.rows_affected() > 0)
            }
            Err(sqlx::Error::Database(e)) if e.is_foreign_key_violation() => Ok(false),
            Err(e) => Err(e.into()),
        }
    }

    pub async fn scene(&self, hash: &str) -> StoreResult<Vec<u8>> {
        let row = sqlx::query("SELECT bytes FROM scenes WHERE hash = $1")
            .bind(hash)
            .fetch_optional(self.pool())
            .await?;
        match row {
            Some(r) => Ok(r.try_get("bytes")?),
            None => Err(Error::not_found("scene", hash)),
        }
    }
}
