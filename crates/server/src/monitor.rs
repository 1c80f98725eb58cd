//! The background loop every server runs: expires leases, marks silent workers lost, collects
//! registrations idle past the worker expiry, wakes lease requests waiting for work, keeps each
//! job's error estimate current, and ends jobs at their noise target or time limit; and, less
//! often, keeps the store from growing forever ([`housekeeping`]). Every step is a transaction on
//! the shared store, so any number of servers can run it side by side.

use crate::states::JobEvent;
use crate::store::{Estimate, ImageEstimate, JobRow};
use crate::AppState;
use pathfarm_wire::api::JobState;
use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How often [`housekeeping`] runs: retention is counted in days, and its queries scan more than
/// a monitor step's.
pub const HOUSEKEEPING_INTERVAL: std::time::Duration = std::time::Duration::from_secs(60);

pub async fn run(state: AppState) {
    // Tiles merged before the error sums were kept (migration 0010), of jobs still running.
    match state.store.backfill_error_sums().await {
        Ok(0) => {}
        Ok(n) => tracing::info!(
            tiles = n,
            "error sums computed for tiles merged before they were kept"
        ),
        Err(e) => tracing::warn!(error = %e, "cannot compute the error sums of older tiles"),
    }
    let mut tick = tokio::time::interval(state.config.monitor_interval);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut last_housekeeping: Option<tokio::time::Instant> = None;
    loop {
        tick.tick().await;
        if let Err(e) = step(&state).await {
            tracing::warn!(error = %e, "monitor step failed");
        }
        if last_housekeeping.is_none_or(|t| t.elapsed() >= HOUSEKEEPING_INTERVAL) {
            last_housekeeping = Some(tokio::time::Instant::now());
            if let Err(e) = housekeeping(&state).await {
                tracing::warn!(error = %e, "housekeeping failed");
            }
        }
    }
}

/// Deletes finished jobs past [`crate::ServerConfig::job_retention`] (a bounded number per
/// call) and the blobs no job uses, and fails jobs whose submission was interrupted.
pub async fn housekeeping(state: &AppState) -> Result<(), crate::error::ApiError> {
    let store = &state.store;
    let now = store.now_ms();
    let grace = crate::store::SUBMISSION_TIMEOUT.as_millis() as i64;
    for id in store.fail_interrupted_submissions(now - grace).await? {
        tracing::warn!(job = %id, "job failed: its submission was interrupted");
    }
    if let Some(retention) = state.config.job_retention {
        let cutoff = now.saturating_sub(retention.as_millis().min(i64::MAX as u128) as i64);
        // A bounded number of rounds: a backlog (a retention just shortened) is worked off over
        // a few calls rather than in one long one.
        let mut deleted = Vec::new();
        for _ in 0..16 {
            let round = store.collect_finished_jobs(cutoff).await?;
            let more = round.len() as u64 == crate::store::JOBS_PER_STEP;
            deleted.extend(round);
            if !more {
                break;
            }
        }
        if !deleted.is_empty() {
            tracing::info!(
                jobs = deleted.len(),
                retention_s = retention.as_secs(),
                "finished jobs past their retention deleted"
            );
            for id in &deleted {
                state.images.forget(id);
            }
        }
    }
    let blobs = store.collect_unused_blobs(now - grace).await?;
    if blobs > 0 {
        tracing::info!(blobs, "scenes and environment images no job uses deleted");
    }
    Ok(())
}

/// A running job's error is estimated again no sooner than this many times what the last
/// aggregate over its tiles took (the part of an estimate that grows with the job's tiles and
/// frames; the writes after it, whose time is mostly waiting for the store's writer, are not
/// counted): about 2 % of a core per running job at most, however large it is. A job that has
/// ended is estimated at once, so its final answer carries its final error.
pub const ESTIMATE_COST_RATIO: u32 = 50;

/// When each running job's error was last estimated, and what that took.
#[derive(Default)]
pub struct EstimateClock(Mutex<HashMap<String, (Instant, Duration)>>);

impl EstimateClock {
    fn due(&self, job: &str, now: Instant) -> bool {
        let last = self.lock().get(job).copied();
        last.is_none_or(|(at, took)| now.duration_since(at) >= took * ESTIMATE_COST_RATIO)
    }

    /// Records an estimate, and lets go of jobs not estimated for an hour (cancelled or deleted
    /// ones; one that runs on is merely estimated once more).
    fn record(&self, job: &str, at: Instant, took: Duration) {
        let mut map = self.lock();
        map.retain(|_, (last, _)| at.duration_since(*last) < Duration::from_secs(3600));
        map.insert(job.to_string(), (at, took));
    }

    fn forget(&self, job: &str) {
        self.lock().remove(job);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, (Instant, Duration)>> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }
}

pub async fn step(state: &AppState) -> Result<(), crate::error::ApiError> {
    let store = &state.store;
    let expired = store.expire_leases().await?;
    if expired > 0 {
        state
            .metrics
            .lease_expiries
            .fetch_add(expired, std::sync::atomic::Ordering::Relaxed);
    }
    let lost = store
        .mark_lost_workers(state.config.lease_duration.as_millis() as u64)
        .await?;
    if lost > 0 {
        tracing::warn!(workers = lost, "workers lost (no heartbeat)");
    }
    let stranded = store.drop_stranded_verifications().await?;
    if stranded > 0 {
        tracing::warn!(
            tasks = stranded,
            "verifications no worker may take were dropped"
        );
    }
    let collected = store
        .collect_idle_workers(state.config.worker_expiry.as_millis() as u64)
        .await?;
    if collected > 0 {
        tracing::info!(
            workers = collected,
            "idle worker registrations expired and collected"
        );
    }
    for (id, _) in store.jobs_needing_estimate().await? {
        let job = match store.job(&id).await {
            Ok(j) => j,
            Err(_) => {
                // Deleted meanwhile.
                state.estimates.forget(&id);
                continue;
            }
        };
        if job.state.is_final() {
            state.estimates.forget(&id);
        } else if !state.estimates.due(&id, Instant::now()) {
            continue;
        }
        // One job whose error cannot be estimated (a store error, say) must not keep the monitor
        // from every other job and from the time limits below.
        let estimated = refresh_estimate(state, &job).await;
        let err = match estimated {
            Ok(err) => err,
            Err(e) => {
                tracing::warn!(job = %id, error = %e, "cannot estimate the job's error");
                continue;
            }
        };
        if job.state == JobState::Running {
            if let (Some(target), Some(err)) = (job.settings.noise_target, err) {
                if err <= target {
                    let msg = format!(
                        "noise target {target} reached (estimated relative error {err:.4})"
                    );
                    tracing::info!(job = %id, "{msg}");
                    store
                        .job_event(&id, JobEvent::Complete, Some(&msg))
                        .await
                        .ok();
                }
            }
        }
    }
    // Leases that expired, workers lost, jobs another server took in: any of them may have
    // queued work that lease requests are waiting for.
    if state.work.has_waiters() && store.has_queued_work().await? {
        state.work.notify();
    }
    let now = store.now_ms();
    for job in store.jobs_in_states(&[JobState::Running]).await? {
        if let (Some(limit), Some(started)) = (job.settings.time_limit_s, job.started_ms) {
            if now - started >= (limit * 1000.0) as i64 {
                let msg = format!("time limit of {limit} s reached");
                tracing::info!(job = %job.id, "{msg}");
                store
                    .job_event(&job.id, JobEvent::Complete, Some(&msg))
                    .await
                    .ok();
            }
        }
    }
    Ok(())
}

/// Estimates the relative error of the job's current image and records it (with a convergence
/// point when one is due). The monitor calls it for every job whose image changed; `GET
/// /jobs/{id}` calls it for a finished job whose last image the monitor has not seen yet, so the
/// final answer carries the final image's error at once rather than one monitor tick later.
///
/// The error is summed from the tiles (`store::estimates`): no image is assembled. A frame job's
/// error is its worst frame's (`None` until every frame has one), and each frame's is recorded in
/// its own history; with a noise target, the frames that reached it stop taking samples
/// ([`Store::stop_frames`]) so that the farm's work goes to the others, and the job ends when
/// its worst frame reaches it.
///
/// [`Store::stop_frames`]: crate::store::Store::stop_frames
pub async fn refresh_estimate(
    state: &AppState,
    job: &JobRow,
) -> Result<Option<f64>, crate::error::ApiError> {
    let store = &state.store;
    // Read after `job`: what they sum is current as of the job's version at least.
    let images = if job.version == 0 {
        Vec::new()
    } else {
        let started = Instant::now();
        let images = store.image_estimates(&job.id).await?;
        if !job.state.is_final() {
            state.estimates.record(&job.id, started, started.elapsed());
        }
        images
    };
    let err = job_error(&images);
    let samples = images.iter().map(|i| i.samples_done).sum();
    let target = job.settings.noise_target;
    let at_target = |e: Option<f64>| matches!((target, e), (Some(t), Some(e)) if e <= t);
    let target_reached = at_target(err);
    let spp = u64::from(job.settings.spp);
    // The frames at the target stop first, so that an estimate whose stopped frames leave nothing
    // planned (the job completes) is recorded as the job's last.
    let mut ended = false;
    if job.settings.frames.is_some() && job.state == JobState::Running && !target_reached {
        ended = stop_frames_at_target(state, job, &images).await?;
    }
    let estimate = Estimate {
        version: job.version,
        relative_error: err,
        samples,
        last: target_reached || ended || samples >= job.samples_planned || job.state.is_final(),
    };
    let frames: &[ImageEstimate] = if job.settings.frames.is_some() {
        &images
    } else {
        &[]
    };
    let ended = |i: &ImageEstimate| i.samples_per_pixel >= spp || at_target(i.relative_error);
    store
        .record_estimates(&job.id, &estimate, frames, ended)
        .await?;
    Ok(err)
}

/// Stops the frames of a running frame job whose error reached its noise target and that still
/// have queued work ([`Store::stop_frames`]). Returns whether that completed the job.
///
/// [`Store::stop_frames`]: crate::store::Store::stop_frames
async fn stop_frames_at_target(
    state: &AppState,
    job: &JobRow,
    images: &[ImageEstimate],
) -> Result<bool, crate::error::ApiError> {
    let spp = u64::from(job.settings.spp);
    let target = job.settings.noise_target;
    let at_target = |e: Option<f64>| matches!((target, e), (Some(t), Some(e)) if e <= t);
    let mut at: Vec<&ImageEstimate> = images
        .iter()
        .filter(|i| i.samples_per_pixel < spp && at_target(i.relative_error))
        .collect();
    if at.is_empty() {
        return Ok(false);
    }
    // Frames stopped before stay at the target: only those with queued work are stopped now.
    let open = state.store.frames_with_queued_tasks(&job.id).await?;
    at.retain(|i| i.frame.is_some_and(|f| open.contains(&f)));
    let ranges: Vec<(i64, i64)> = at.iter().map(|i| (i.first_tile, i.tiles)).collect();
    let stopped = state.store.stop_frames(&job.id, &ranges).await?;
    if stopped.tasks > 0 {
        tracing::info!(
            job = %job.id,
            frames = ranges.len(),
            tasks = stopped.tasks,
            "frames at the noise target stopped"
        );
    }
    if stopped.completed {
        tracing::info!(job = %job.id, "job completed: every frame that still renders is at its noise target or its spp");
    }
    Ok(stopped.completed)
}

/// A job's error from its images' estimates: a still job's image's, a frame job's worst frame's
/// (`None` while any frame has none).
fn job_error(images: &[ImageEstimate]) -> Option<f64> {
    let mut worst: Option<f64> = None;
    for i in images {
        let e = i.relative_error?;
        worst = Some(worst.map_or(e, |w| w.max(e)));
    }
    worst
}
