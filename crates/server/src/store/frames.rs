//! The progress of a frame job's frames, read from its tiles (each names its frame).

use super::error::StoreResult;
use super::Store;
use pathfarm_wire::api::FrameProgress;
use sqlx::Row;

impl Store {
    /// Every frame of a frame job, in the job's frame order (the order of their tiles), with
    /// the samples merged into it and the fewest samples per pixel of its tiles; `spp` is the
    /// job's samples per pixel, which make a frame complete. Empty for a still job.
    pub async fn frame_progress(&self, job_id: &str, spp: u64) -> StoreResult<Vec<FrameProgress>> {
        let rows = sqlx::query(
            "SELECT frame, MIN(tile_index) AS first, MIN(samples) AS spp, \
             CAST(SUM(samples * width * height) AS BIGINT) AS done \
             FROM tiles WHERE job_id = $1 AND frame IS NOT NULL GROUP BY frame ORDER BY first",
        )
        .bind(job_id)
        .fetch_all(self.pool())
        .await?;
        Ok(rows
            .iter()
            .map(|r| {
                let per_pixel = r.try_get::<i64, _>("spp")?.max(0) as u64;
                Ok(FrameProgress {
                    frame: r.try_get("frame")?,
                    samples_done: r.try_get::<i64, _>("done")?.max(0) as u64,
                    samples_per_pixel: per_pixel,
                    complete: per_pixel >= spp,
                })
            })
            .collect::<Result<Vec<_>, sqlx::Error>>()?)
    }
}
