//! What the monitor collects so that the store does not grow forever: finished jobs past the
//! retention, blobs no job uses, and jobs whose submission stopped halfway.

use super::error::StoreResult;
use super::Store;
use crate::states::JobEvent;
use sqlx::Row;

/// Jobs collected per monitor step, each deleted in its own transaction: a backlog (a retention
/// shortened on a full store) is worked off over several steps without stalling the farm.
pub const JOBS_PER_STEP: u64 = 64;

impl Store {
    /// Deletes the jobs (up to [`JOBS_PER_STEP`], oldest first) that finished before `cutoff_ms`,
    /// with their tiles, tasks and progress, and their blobs once no job uses them; returns their
    /// ids.
    pub async fn collect_finished_jobs(&self, cutoff_ms: i64) -> StoreResult<Vec<String>> {
        let rows = sqlx::query(
            "SELECT id FROM jobs WHERE finished_ms < $1 \
             AND state IN ('completed', 'cancelled', 'failed') \
             ORDER BY finished_ms, id LIMIT $2",
        )
        .bind(cutoff_ms)
        .bind(JOBS_PER_STEP as i64)
        .fetch_all(self.pool())
        .await?;
        let mut deleted = Vec::with_capacity(rows.len());
        for row in rows {
            let id: String = row.try_get("id")?;
            match self.delete_job(&id).await {
                Ok(()) => deleted.push(id),
                // Deleted meanwhile, by a client or another server's monitor.
                Err(super::Error::NotFound { .. }) => {}
                Err(e) => return Err(e),
            }
        }
        Ok(deleted)
    }

    /// Deletes the scenes and environment images that no job uses and that were stored before
    /// `cutoff_ms`; returns how many. Deleting a job deletes its blobs when it was their last
    /// user, so this finds only what a race or an older server left behind.
    pub async fn collect_unused_blobs(&self, cutoff_ms: i64) -> StoreResult<u64> {
        let rows = sqlx::query(
            "SELECT hash FROM scenes WHERE created_ms < $1 AND NOT EXISTS \
             (SELECT 1 FROM jobs WHERE scene_hash = scenes.hash OR environment_hash = scenes.hash)",
        )
        .bind(cutoff_ms)
        .fetch_all(self.pool())
        .await?;
        let mut n = 0;
        for row in rows {
            let hash: String = row.try_get("hash")?;
            if self.delete_blob_if_unused(&hash).await? {
                n += 1;
            }
        }
        Ok(n)
    }

    /// Fails the unfinished jobs created before `cutoff_ms` whose tasks are not all stored: their
    /// submission was interrupted (see [`super::submission`]), so they could never complete.
    pub async fn fail_interrupted_submissions(&self, cutoff_ms: i64) -> StoreResult<Vec<String>> {
        let rows = sqlx::query(
            "SELECT id FROM jobs WHERE tasks_to_store > 0 AND created_ms < $1 \
             AND state IN ('queued', 'running', 'paused') ORDER BY created_ms, id",
        )
        .bind(cutoff_ms)
        .fetch_all(self.pool())
        .await?;
        let mut failed = Vec::with_capacity(rows.len());
        for row in rows {
            let id: String = row.try_get("id")?;
            let message = "its submission was interrupted (the server stopped) before all its \
                           tasks were stored; submit it again";
            match self.job_event(&id, JobEvent::Fail, Some(message)).await {
                Ok(_) => failed.push(id),
                // Ended or deleted meanwhile.
                Err(e) if e.is_refusal() => {}
                Err(e) => return Err(e),
            }
        }
        Ok(failed)
    }
}
