//! Polling a farm's job until it ends, noting when its first complete pass showed.

use crate::error::farm_err;
use crate::BenchError;
use pathfarm_wire::api::JobView;
use pathfarm_worker::client::ApiClient;
use std::time::{Duration, Instant};

/// What polling a job until it ended saw.
pub struct Watched {
    pub view: JobView,
    /// From just before the submission until the job view first showed every tile with at least
    /// one sample per pixel (as observed by the poll).
    pub first_preview: Option<Duration>,
    /// From just before the submission until the job view first showed a final state.
    pub wall: Duration,
}

/// Polls job `id` every `poll` until it reaches a final state (an error after `timeout`).
pub async fn watch_job(
    client: &ApiClient,
    id: &str,
    t0: Instant,
    poll: Duration,
    timeout: Duration,
) -> Result<Watched, BenchError> {
    let mut first_preview = None;
    loop {
        let view = client
            .job(id)
            .await
            .map_err(|e| farm_err(format!("reading job {id}: {e}")))?;
        let now = t0.elapsed();
        if first_preview.is_none() {
            if let Some(tiles) = &view.tiles {
                if !tiles.is_empty() && tiles.iter().all(|t| t.samples_per_pixel >= 1) {
                    first_preview = Some(now);
                }
            }
        }
        if view.state.is_final() {
            return Ok(Watched {
                view,
                first_preview,
                wall: now,
            });
        }
        if now > timeout {
            return Err(farm_err(format!(
                "job {id} did not finish within {timeout:?} (state {}, {} of {} samples)",
                view.state.as_str(),
                view.samples_done,
                view.samples_planned
            )));
        }
        tokio::time::sleep(poll).await;
    }
}
