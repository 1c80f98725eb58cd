//! Working on a leased task: rendering it in slices sized by the render speed ([`Rate`]),
//! each uploaded while the next renders ([`InFlight`]), and the next task leased ahead.

use crate::client::{ApiClient, ClientError};
use crate::config::WorkerConfig;
use crate::report::WorkerReport;
use crate::retry::{self, needs_registration, Limits};
use crate::scene_cache::{self, SceneCache};
use crate::session::Session;
use pathfarm_tracer::{render_tile, Tile};
use pathfarm_wire::api::Lease;
use pathfarm_wire::{encode_slice, Slice};
use std::sync::Arc;
use std::time::Instant;
use tokio::sync::watch;

/// Render speed, samples (camera paths) per second, for sizing slices.
#[derive(Default)]
pub(crate) struct Rate {
    samples_per_second: Option<f64>,
}

impl Rate {
    fn slice_spp(&self, target_s: f64, pixels: u64, remaining: u32) -> u32 {
        let spp = match self.samples_per_second {
            Some(r) => (target_s * r / pixels as f64).floor() as u64,
            None => 1,
        };
        spp.clamp(1, remaining as u64) as u32
    }
    fn observe(&mut self, samples: u64, secs: f64) {
        if secs > 0.0 {
            let r = samples as f64 / secs;
            self.samples_per_second = Some(match self.samples_per_second {
                Some(old) => 0.5 * old + 0.5 * r,
                None => r,
            });
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub(crate) enum TaskError {
    #[error(transparent)]
    Scene(#[from] scene_cache::SceneError),
    #[error(transparent)]
    Client(#[from] ClientError),
    #[error("the lease was lost")]
    LeaseLost,
    #[error("render thread: {0}")]
    Join(String),
}

impl TaskError {
    /// The server took the lease back (the job was cancelled, stopped early or its lease expired):
    /// a decision of the farm's, not a failure of this worker's that would repeat.
    pub(crate) fn is_farm_decision(&self) -> bool {
        match self {
            TaskError::LeaseLost => true,
            TaskError::Client(e @ ClientError::Api { status, .. }) => {
                *status == reqwest::StatusCode::CONFLICT
                    || *status == reqwest::StatusCode::NOT_FOUND
                    || needs_registration(e)
            }
            _ => false,
        }
    }
}

/// A lease asked for while the last slice of the current task renders, so that the next task
/// starts without a round trip.
pub(crate) type NextLease = tokio::task::JoinHandle<Result<Option<Lease>, ClientError>>;

/// Asks for the next task in the background.
fn ask_next(session: &Session) -> NextLease {
    let (client, worker_id) = (session.client.clone(), session.worker_id.clone());
    tokio::spawn(async move { client.lease(&worker_id).await })
}

/// Gives back a lease asked for ahead that will not be worked on.
pub(crate) async fn give_back(asked: NextLease, client: &ApiClient) {
    if let Ok(Ok(Some(lease))) = asked.await {
        let _ = client.release(lease.task_id, &lease.lease_token).await;
    }
}

/// A slice on its way to the server while the worker renders the next one: uploads never hold
/// the render threads up. A worker has at most two at once, one per task (the last slice of the
/// task it finished, while it leases and renders the next).
pub(crate) struct InFlight {
    task_id: i64,
    lease_token: String,
    /// Camera paths in the slice, valid and invalid.
    samples: u64,
    upload: tokio::task::JoinHandle<Result<pathfarm_wire::api::SliceAck, TaskError>>,
}

impl InFlight {
    /// Starts encoding and uploading `slice` (beside the next render), retrying while the server
    /// cannot be reached for as long as the lease can still be valid. A retry after a lost
    /// answer is harmless: the server counts a slice once.
    fn start(session: &Session, lease: &Lease, samples: u64, slice: Slice) -> InFlight {
        let client = session.client.clone();
        let (task_id, token) = (lease.task_id, lease.lease_token.clone());
        let limits = Limits {
            deadline: Some(Instant::now() + session.lease_duration),
            stop: None,
        };
        let upload = tokio::spawn(async move {
            let body = tokio::task::spawn_blocking(move || encode_slice(&slice))
                .await
                .map_err(|e| TaskError::Join(e.to_string()))?;
            let ack = retry::retry(
                retry::UPLOAD,
                limits,
                || client.upload_slice(task_id, &token, body.clone()),
                |e, d| {
                    tracing::warn!(task = task_id, error = %e, retry_in = ?d, "slice upload failed; retrying")
                },
            )
            .await?;
            Ok(ack)
        });
        InFlight {
            task_id: lease.task_id,
            lease_token: lease.lease_token.clone(),
            samples,
            upload,
        }
    }

    /// The server's answer. A failure that is not the farm's decision gives the lease back at
    /// once, so that the task is queued again now rather than when the lease expires.
    async fn settle(
        self,
        client: &ApiClient,
        report: &mut WorkerReport,
    ) -> Result<pathfarm_wire::api::SliceAck, TaskError> {
        let answer = match self.upload.await {
            Ok(answer) => answer,
            Err(e) => Err(TaskError::Join(e.to_string())),
        };
        match &answer {
            Ok(_) => {
                report.slices += 1;
                report.samples += self.samples;
            }
            Err(e) if !e.is_farm_decision() => {
                let _ = client.release(self.task_id, &self.lease_token).await;
            }
            Err(_) => {}
        }
        answer
    }

    /// Settles the last slice of a task the worker has moved on from: the task is done when it is
    /// accepted; a failure is logged (the lease was given back), and the worker goes on.
    pub(crate) async fn finish(self, client: &ApiClient, report: &mut WorkerReport) {
        let task = self.task_id;
        match self.settle(client, report).await {
            Ok(_) => report.tasks += 1,
            Err(e) if e.is_farm_decision() => {
                tracing::info!(task, reason = %e, "task taken back");
            }
            Err(e) => tracing::warn!(task, error = %e, "the last slice of a task was lost"),
        }
    }
}

/// Works on a leased task: renders it slice after slice, each uploaded while the next renders.
/// Returns the last slice still in flight (its answer is awaited while the next task renders),
/// or none when the task ended otherwise (completed early, given back, paused). `previous` is
/// the last slice of the task before, settled once the first slice of this one is rendered.
/// While the last slice renders, the next task is asked for (`next`), unless slices are long
/// against the lease (a lease asked for early is not extended by heartbeats until it is worked
/// on).
#[allow(clippy::too_many_arguments)]
pub(crate) async fn work_on(
    session: &Session,
    config: &WorkerConfig,
    pool: &Arc<rayon::ThreadPool>,
    cache: &tokio::sync::Mutex<SceneCache>,
    lease: &Lease,
    previous: &mut Option<InFlight>,
    next: &mut Option<NextLease>,
    stop: &mut watch::Receiver<bool>,
    lease_lost: &std::sync::atomic::AtomicBool,
    rate: &mut Rate,
    report: &mut WorkerReport,
) -> Result<Option<InFlight>, TaskError> {
    let client = &session.client;
    // One lane loads a scene while the others wait for it: one copy, loaded once.
    let scene = match cache
        .lock()
        .await
        .get(
            client,
            &lease.scene_hash,
            lease.settings.camera.clone(),
            lease.settings.environment.as_ref(),
            lease.frame.map(|f| (f, lease.settings.frames_per_second())),
        )
        .await
    {
        Ok(s) => s,
        Err(e) => {
            let _ = client.release(lease.task_id, &lease.lease_token).await;
            return Err(e.into());
        }
    };
    let settings = Arc::new(lease.settings.render_settings());
    let tile = Tile {
        x0: lease.tile.x0,
        y0: lease.tile.y0,
        width: lease.tile.width,
        height: lease.tile.height,
    };
    let mut begin = lease.sample_begin;
    // Back-pressure: the server's slice length when it asks for longer slices than ours.
    let mut slice_seconds = paced(config.slice_seconds, lease.slice_seconds);
    tracing::debug!(task = lease.task_id, job = %lease.job_id, samples = ?(begin..lease.sample_end), slice_seconds, "task leased");
    // This task's slice on its way while the next one renders.
    let mut pending: Option<InFlight> = None;
    while begin < lease.sample_end {
        if lease_lost.load(std::sync::atomic::Ordering::SeqCst) {
            if let Some(p) = pending.take() {
                let _ = p.settle(client, report).await;
            }
            return Err(TaskError::LeaseLost);
        }
        let n = config
            .slice_samples
            .unwrap_or_else(|| {
                rate.slice_spp(slice_seconds, tile.pixel_count(), lease.sample_end - begin)
            })
            .clamp(1, lease.sample_end - begin);
        let range = begin..begin + n;
        let short = slice_seconds * 4.0 < session.lease_duration.as_secs_f64();
        if range.end >= lease.sample_end && next.is_none() && short && !*stop.borrow() {
            *next = Some(ask_next(session));
        }
        let t0 = Instant::now();
        let (scene2, settings2, pool2, r2) =
            (scene.clone(), settings.clone(), pool.clone(), range.clone());
        let rendered = tokio::task::spawn_blocking(move || {
            pool2.install(|| render_tile(&scene2, &settings2, tile, r2))
        })
        .await;
        let render_seconds = t0.elapsed().as_secs_f64();
        if let Some(p) = previous.take() {
            p.finish(client, report).await;
        }
        let acc = match rendered {
            Ok(acc) => acc,
            Err(e) => {
                if let Some(p) = pending.take() {
                    let _ = p.settle(client, report).await;
                }
                let _ = client.release(lease.task_id, &lease.lease_token).await;
                return Err(TaskError::Join(e.to_string()));
            }
        };
        let samples = acc.total_samples() + acc.invalid_count;
        report.render_seconds += render_seconds;
        rate.observe(samples, render_seconds);
        report.note_invalid(&lease.job_id, &acc);
        let mut stopping = *stop.borrow();
        if let Some(p) = pending.take() {
            let ack = p.settle(client, report).await?;
            slice_seconds = paced(config.slice_seconds, ack.slice_seconds);
            if ack.task_complete {
                // Others' samples completed it meanwhile: the slice in hand is not needed.
                return Ok(None);
            }
            if ack.task_samples_done > range.start {
                // The server holds samples past the previous slice (from an earlier lease of the
                // task): the slice in hand repeats some of them, so it goes, and the rendering
                // goes on from the server's count.
                begin = ack.task_samples_done;
                continue;
            }
            // A paused job: the slice in hand is uploaded, then the rest given back.
            stopping |= !ack.keep_going;
        }
        let slice = Slice {
            sample_begin: range.start,
            sample_end: range.end,
            acc,
        };
        let in_flight = InFlight::start(session, lease, samples, slice);
        begin = range.end;
        if begin >= lease.sample_end {
            return Ok(Some(in_flight));
        }
        if stopping {
            // Asked to stop (or the job paused): the slice in hand is uploaded; give the rest back.
            let ack = in_flight.settle(client, report).await?;
            if !ack.task_complete {
                client.release(lease.task_id, &lease.lease_token).await?;
            }
            return Ok(None);
        }
        pending = Some(in_flight);
    }
    if let Some(p) = pending.take() {
        p.settle(client, report).await?;
    }
    Ok(None)
}

/// The slice length to render: `own`, or the server's when it asks for longer ones
/// (back-pressure), at most [`MAX_SERVER_SLICE_SECONDS`].
fn paced(own: f64, server: Option<f64>) -> f64 {
    match server {
        Some(s) if s.is_finite() && s > own => s.min(MAX_SERVER_SLICE_SECONDS),
        _ => own,
    }
}

/// The longest slice a server can ask for (the server's own cap, `pacing::MAX_SLICE_SECONDS`).
const MAX_SERVER_SLICE_SECONDS: f64 = 60.0;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_server_may_lengthen_slices_but_not_shorten_them() {
        assert_eq!(paced(1.5, None), 1.5, "an older server");
        assert_eq!(paced(1.5, Some(0.0)), 1.5);
        assert_eq!(paced(1.5, Some(0.4)), 1.5, "never shorter than ours");
        assert_eq!(paced(1.5, Some(12.0)), 12.0);
        assert_eq!(paced(1.5, Some(1e9)), MAX_SERVER_SLICE_SECONDS);
        assert_eq!(paced(1.5, Some(f64::NAN)), 1.5);
        assert_eq!(paced(1.5, Some(f64::INFINITY)), 1.5);
    }

    #[test]
    fn only_failures_of_the_workers_own_make_it_wait() {
        let api = |status: u16| {
            TaskError::Client(ClientError::Api {
                status: reqwest::StatusCode::from_u16(status).unwrap(),
                code: "x".into(),
                message: "x".into(),
                retry_after: None,
            })
        };
        // Taken back by the farm (a cancel, an early stop, an expired lease): lease again at once.
        assert!(TaskError::LeaseLost.is_farm_decision());
        assert!(api(409).is_farm_decision());
        assert!(api(404).is_farm_decision());
        // Failures that may well repeat with the next lease: back off.
        assert!(!api(503).is_farm_decision());
        assert!(!api(422).is_farm_decision());
        assert!(!TaskError::Join("panicked".into()).is_farm_decision());
    }
}
