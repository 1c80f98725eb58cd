//! Error estimates summed from the tiles, and a frame job's frames stopped at its noise target.
//!
//! Each merge stores its tile's share of the image-level relative error with the tile (Σ variance
//! of the pixel means, Σ mean luminance, pixels without a variance estimate: `tasks::merged_tile`,
//! migration 0010). A still job's error, and each frame's of a frame job, is then one aggregate
//! over its tiles: no image is assembled to estimate it, whatever its size or number of frames.

use super::error::{Error, StoreResult};
use super::jobs::complete_when_done;
use super::Store;
use crate::job_image::relative_error;
use crate::states::TaskState;
use sqlx::Row;

/// What a job's tiles say of one image: a still job's, or one frame of a frame job.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageEstimate {
    /// The frame (`None` for a still job's image).
    pub frame: Option<i64>,
    /// Its first tile's index, and how many tiles it has (a frame's are one run).
    pub first_tile: i64,
    pub tiles: i64,
    /// Samples merged into it (camera paths over all its pixels).
    pub samples_done: u64,
    /// The fewest samples per pixel of its tiles.
    pub samples_per_pixel: u64,
    /// Its estimated relative error: `None` until every pixel has two samples (or while a tile
    /// merged before the sums were kept has not been merged again).
    pub relative_error: Option<f64>,
}

impl Store {
    /// The job's images as its tiles sum them: one for a still job, one per frame of a frame
    /// job in the job's frame order. Empty when the job has no tiles (or is gone).
    pub async fn image_estimates(&self, job_id: &str) -> StoreResult<Vec<ImageEstimate>> {
        let rows = sqlx::query(
            "SELECT frame, MIN(tile_index) AS first, CAST(COUNT(*) AS BIGINT) AS tiles, \
             MIN(samples) AS spp, CAST(SUM(samples * width * height) AS BIGINT) AS done, \
             CAST(SUM(width * height) AS BIGINT) AS pixels, \
             CAST(COUNT(*) - COUNT(err_var) AS BIGINT) AS unsummed, \
             SUM(err_var) AS var, SUM(err_lum) AS lum, \
             CAST(COALESCE(SUM(err_unestimated), 0) AS BIGINT) AS unestimated \
             FROM tiles WHERE job_id = $1 GROUP BY frame ORDER BY first",
        )
        .bind(job_id)
        .fetch_all(self.pool())
        .await?;
        rows.iter()
            .map(|r| {
                let unsummed: i64 = r.try_get("unsummed")?;
                let var: Option<f64> = r.try_get("var")?;
                let lum: Option<f64> = r.try_get("lum")?;
                let unestimated = r.try_get::<i64, _>("unestimated")?.max(0) as u64;
                let pixels = r.try_get::<i64, _>("pixels")?.max(0) as u64;
                let relative_error = match (unsummed, var, lum) {
                    (0, Some(var), Some(lum)) => relative_error(var, lum, unestimated, pixels),
                    _ => None,
                };
                Ok(ImageEstimate {
                    frame: r.try_get("frame")?,
                    first_tile: r.try_get("first")?,
                    tiles: r.try_get("tiles")?,
                    samples_done: r.try_get::<i64, _>("done")?.max(0) as u64,
                    samples_per_pixel: r.try_get::<i64, _>("spp")?.max(0) as u64,
                    relative_error,
                })
            })
            .collect::<Result<Vec<_>, sqlx::Error>>()
            .map_err(Error::from)
    }

    /// Stops the frames of job `job_id` whose first tiles and tile counts are `frames` (their
    /// error reached the job's noise target): their queued tasks are cancelled and their samples
    /// no longer planned, so that the farm's work goes to the frames still above the target. A
    /// leased task runs on (its samples are merged like any); verifications are left to be
    /// judged. When nothing planned is left the job completes (`complete_when_done`). Returns
    /// the tasks cancelled.
    pub async fn stop_frames(&self, job_id: &str, frames: &[(i64, i64)]) -> StoreResult<u64> {
        if frames.is_empty() {
            return Ok(0);
        }
        // The frames' tile ranges, as literals: integers the monitor read from the store.
        let ranges = frames
            .iter()
            .map(|(first, n)| format!("(tile_index BETWEEN {first} AND {})", first + n - 1))
            .collect::<Vec<_>>()
            .join(" OR ");
        let mut w = self.write().await?;
        // Tasks, then tiles, then the job: the documented lock order.
        let tasks = sqlx::query(sqlx::AssertSqlSafe(format!(
            "SELECT id, tile_index, sample_end - done_end AS unmerged FROM tasks \
             WHERE job_id = $1 AND state = 'queued' AND verifies IS NULL AND ({ranges}) \
             ORDER BY id{}",
            self.dialect().for_update()
        )))
        .bind(job_id)
        .fetch_all(&mut *w.tx)
        .await?;
        if tasks.is_empty() {
            return Ok(0);
        }
        let pixels: std::collections::HashMap<i64, i64> =
            sqlx::query(sqlx::AssertSqlSafe(format!(
                "SELECT tile_index, width * height AS pixels FROM tiles \
                 WHERE job_id = $1 AND ({ranges})"
            )))
            .bind(job_id)
            .fetch_all(&mut *w.tx)
            .await?
            .iter()
            .map(|r| Ok((r.try_get("tile_index")?, r.try_get("pixels")?)))
            .collect::<Result<_, sqlx::Error>>()?;
        let mut unplanned = 0i64;
        let mut ids = Vec::with_capacity(tasks.len());
        for t in &tasks {
            let tile: i64 = t.try_get("tile_index")?;
            let px = pixels.get(&tile).copied().ok_or_else(|| {
                Error::internal(format!("task of job {job_id} names a missing tile {tile}"))
            })?;
            unplanned += t.try_get::<i64, _>("unmerged")?.max(0) * px;
            ids.push(t.try_get::<i64, _>("id")?.to_string());
        }
        let cancelled = ids.len() as u64;
        for chunk in ids.chunks(500) {
            sqlx::query(sqlx::AssertSqlSafe(format!(
                "UPDATE tasks SET state = '{}' WHERE id IN ({})",
                TaskState::Cancelled.as_str(),
                chunk.join(", ")
            )))
            .execute(&mut *w.tx)
            .await?;
        }
        let job = sqlx::query(
            "UPDATE jobs SET queued_tasks = queued_tasks - $1, \
             samples_planned = samples_planned - $2 WHERE id = $3 \
             RETURNING state, samples_done, samples_planned, verifying",
        )
        .bind(cancelled as i64)
        .bind(unplanned)
        .bind(job_id)
        .fetch_optional(&mut *w.tx)
        .await?
        .ok_or_else(|| Error::not_found("job", job_id))?;
        complete_when_done(&mut w.tx, job_id, &job, self.now_ms()).await?;
        w.commit().await?;
        Ok(cancelled)
    }
}
