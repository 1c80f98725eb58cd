//! The progress of a frame job's frames, read from its tiles (each names its frame).

use super::error::StoreResult;
use super::Store;
use pathfarm_wire::api::FrameProgress;

impl Store {
    /// Every frame of a frame job, in the job's frame order (the order of their tiles), with
    /// the samples merged into it, the fewest samples per pixel of its tiles and its estimated
    /// error. `spp` is the job's samples per pixel and `noise_target` its noise target: a frame
    /// is complete when every planned sample is merged or its error reached the target. Empty
    /// for a still job.
    pub async fn frame_progress(
        &self,
        job_id: &str,
        spp: u64,
        noise_target: Option<f64>,
    ) -> StoreResult<Vec<FrameProgress>> {
        Ok(self
            .image_estimates(job_id)
            .await?
            .into_iter()
            .filter_map(|e| {
                let at_target = matches!(
                    (noise_target, e.relative_error),
                    (Some(t), Some(err)) if err <= t
                );
                Some(FrameProgress {
                    frame: e.frame?,
                    samples_done: e.samples_done,
                    samples_per_pixel: e.samples_per_pixel,
                    complete: e.samples_per_pixel >= spp || at_target,
                    relative_error: e.relative_error,
                })
            })
            .collect())
    }
}
