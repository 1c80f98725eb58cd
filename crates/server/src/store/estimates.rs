//! Error estimates summed from the tiles, and a frame job's frames stopped at its noise target.
//!
//! Each merge stores its tile's share of the image-level relative error with the tile (Σ variance
//! of the pixel means, Σ mean luminance, pixels without a variance estimate: `tasks::merged_tile`,
//! migration 0010). A still job's error, and each frame's of a frame job, is then one aggregate
//! over its tiles: no image is assembled to estimate it, whatever its size or number of frames.

use super::error::{Error, StoreResult};
use super::jobs::complete_when_done;
use super::Store;
use crate::job_image::{relative_error, Sums};
use crate::states::{task_transition, TaskEvent, TaskState};
use pathfarm_wire::{decode_slice, SliceLimits};
use sqlx::Row;
use std::collections::{HashMap, HashSet};

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

    /// The frames of a frame job that still have queued tasks of their own (verifications
    /// aside): those a noise target can still stop.
    pub async fn frames_with_queued_tasks(&self, job_id: &str) -> StoreResult<HashSet<i64>> {
        let rows = sqlx::query(
            "SELECT DISTINCT ti.frame FROM tasks t JOIN tiles ti \
             ON ti.job_id = t.job_id AND ti.tile_index = t.tile_index \
             WHERE t.job_id = $1 AND t.state = 'queued' AND t.verifies IS NULL \
             AND ti.frame IS NOT NULL",
        )
        .bind(job_id)
        .fetch_all(self.pool())
        .await?;
        Ok(rows
            .iter()
            .map(|r| r.try_get("frame"))
            .collect::<Result<_, sqlx::Error>>()?)
    }

    /// Stops the frames of job `job_id` whose first tiles and tile counts are `frames` (their
    /// error reached the job's noise target), so that the farm's work goes to the frames still
    /// above it: each queued task ends as it stands (`TaskEvent::Stop`: done with the samples
    /// merged so far, which a tile rendered again renders again, or cancelled when none were),
    /// and its unmerged samples are no longer planned. A leased task runs on (its samples merge
    /// like any); verifications are left to be judged. A frame one of whose tiles was reset since
    /// it was estimated (rendered again from nothing: no sums) is left alone. When nothing planned
    /// is left the job completes by the one rule (`complete_when_done`).
    pub async fn stop_frames(&self, job_id: &str, frames: &[(i64, i64)]) -> StoreResult<Stopped> {
        let mut stopped = Stopped::default();
        // A few hundred ranges a statement: SQLite limits an expression's depth to 1000.
        for chunk in frames.chunks(200) {
            let out = self.stop_frame_chunk(job_id, chunk).await?;
            stopped.tasks += out.tasks;
            stopped.completed |= out.completed;
        }
        Ok(stopped)
    }

    async fn stop_frame_chunk(&self, job_id: &str, frames: &[(i64, i64)]) -> StoreResult<Stopped> {
        if frames.is_empty() {
            return Ok(Stopped::default());
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
            "SELECT id, tile_index, sample_begin, done_end, sample_end FROM tasks \
             WHERE job_id = $1 AND state = 'queued' AND verifies IS NULL AND ({ranges}) \
             ORDER BY id{}",
            self.dialect().for_update()
        )))
        .bind(job_id)
        .fetch_all(&mut *w.tx)
        .await?;
        if tasks.is_empty() {
            return Ok(Stopped::default());
        }
        let tiles = sqlx::query(sqlx::AssertSqlSafe(format!(
            "SELECT tile_index, width * height AS pixels, err_var FROM tiles \
             WHERE job_id = $1 AND ({ranges})"
        )))
        .bind(job_id)
        .fetch_all(&mut *w.tx)
        .await?;
        let mut pixels = HashMap::new();
        let mut reset = Vec::new();
        for t in &tiles {
            let index: i64 = t.try_get("tile_index")?;
            pixels.insert(index, t.try_get::<i64, _>("pixels")?);
            if t.try_get::<Option<f64>, _>("err_var")?.is_none() {
                reset.push(index);
            }
        }
        // The frames (ranges) holding a reset tile.
        let stale = |tile: i64| {
            frames.iter().any(|&(first, n)| {
                (first..first + n).contains(&tile)
                    && reset.iter().any(|r| (first..first + n).contains(r))
            })
        };
        let (mut unplanned, mut done, mut cancelled) = (0i64, Vec::new(), Vec::new());
        for t in &tasks {
            let tile: i64 = t.try_get("tile_index")?;
            if stale(tile) {
                continue;
            }
            let px = pixels.get(&tile).copied().ok_or_else(|| {
                Error::internal(format!(
                    "a task of job {job_id} names a missing tile {tile}"
                ))
            })?;
            let done_end: i64 = t.try_get("done_end")?;
            unplanned += (t.try_get::<i64, _>("sample_end")? - done_end).max(0) * px;
            let merged = done_end > t.try_get::<i64, _>("sample_begin")?;
            let to = task_transition(TaskState::Queued, TaskEvent::Stop { merged })
                .map_err(Error::internal)?;
            let id = t.try_get::<i64, _>("id")?.to_string();
            match to {
                TaskState::Done => done.push(id),
                _ => cancelled.push(id),
            }
        }
        let n = (done.len() + cancelled.len()) as i64;
        if n == 0 {
            return Ok(Stopped::default());
        }
        // A task stopped after some of its samples were merged keeps just those: its range ends
        // where they do, as a task that was planned that long.
        for (ids, set) in [
            (
                &done,
                format!(
                    "state = '{}', sample_end = done_end",
                    TaskState::Done.as_str()
                ),
            ),
            (
                &cancelled,
                format!("state = '{}'", TaskState::Cancelled.as_str()),
            ),
        ] {
            for chunk in ids.chunks(500) {
                sqlx::query(sqlx::AssertSqlSafe(format!(
                    "UPDATE tasks SET {set}, accum = NULL WHERE id IN ({})",
                    chunk.join(", ")
                )))
                .execute(&mut *w.tx)
                .await?;
            }
        }
        let job = sqlx::query(
            "UPDATE jobs SET queued_tasks = queued_tasks - $1, \
             samples_planned = samples_planned - $2 WHERE id = $3 \
             RETURNING state, samples_done, samples_planned, verifying",
        )
        .bind(n)
        .bind(unplanned)
        .bind(job_id)
        .fetch_optional(&mut *w.tx)
        .await?
        .ok_or_else(|| Error::not_found("job", job_id))?;
        let (_, completed) = complete_when_done(&mut w.tx, job_id, &job, self.now_ms()).await?;
        w.commit().await?;
        Ok(Stopped {
            tasks: n as u64,
            completed,
        })
    }

    /// Computes the error sums of the tiles merged before migration 0010 (which left them NULL)
    /// for the jobs that have not ended, so that their estimates and noise targets go on across
    /// the upgrade; a job that ended keeps the estimate it ended with. A tile merged meanwhile
    /// keeps the sums its merge wrote. Returns the tiles summed.
    pub async fn backfill_error_sums(&self) -> StoreResult<u64> {
        let keys = sqlx::query(
            "SELECT t.job_id, t.tile_index FROM tiles t JOIN jobs j ON j.id = t.job_id \
             WHERE t.accum IS NOT NULL AND t.err_var IS NULL \
             AND j.state IN ('queued', 'running', 'paused') ORDER BY t.job_id, t.tile_index",
        )
        .fetch_all(self.pool())
        .await?
        .iter()
        .map(|r| {
            Ok((
                r.try_get::<String, _>("job_id")?,
                r.try_get::<i64, _>("tile_index")?,
            ))
        })
        .collect::<Result<Vec<_>, sqlx::Error>>()?;
        let mut summed = 0;
        for batch in keys.chunks(64) {
            let mut w = self.write().await?;
            for (job_id, tile_index) in batch {
                let row = sqlx::query(
                    "SELECT accum, merges FROM tiles WHERE job_id = $1 AND tile_index = $2 \
                     AND accum IS NOT NULL AND err_var IS NULL",
                )
                .bind(job_id)
                .bind(tile_index)
                .fetch_optional(&mut *w.tx)
                .await?;
                let Some(row) = row else { continue };
                let accum: Vec<u8> = row.try_get("accum")?;
                let limits = SliceLimits {
                    max_pixels: u64::MAX,
                };
                let sums = match decode_slice(&accum, &limits) {
                    Ok(slice) => Sums::of(&slice.acc),
                    Err(e) => {
                        tracing::warn!(job = %job_id, tile = tile_index, error = %e, "a stored tile does not decode: no error estimate for its job");
                        continue;
                    }
                };
                // Unless a merge wrote the tile since it was read (PostgreSQL's writers run side
                // by side): its sums are then its own.
                summed += sqlx::query(
                    "UPDATE tiles SET err_var = $1, err_lum = $2, err_unestimated = $3 \
                     WHERE job_id = $4 AND tile_index = $5 AND merges = $6 AND err_var IS NULL",
                )
                .bind(sums.variance())
                .bind(sums.luminance())
                .bind(sums.without_estimate() as i64)
                .bind(job_id)
                .bind(tile_index)
                .bind(row.try_get::<i64, _>("merges")?)
                .execute(&mut *w.tx)
                .await?
                .rows_affected();
            }
            w.commit().await?;
        }
        Ok(summed)
    }
}

/// What [`Store::stop_frames`] did: the tasks it stopped, and whether that completed the job.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stopped {
    pub tasks: u64,
    pub completed: bool,
}
