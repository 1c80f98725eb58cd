//! Managing jobs: list, view, change, cancel, pause, resume, delete.

use super::{JsonBody, Page};
use crate::auth::{ClientAuth, ReadAuth};
use crate::error::{ApiError, ApiResult};
use crate::states::JobEvent;
use crate::store::JobRow;
use crate::AppState;
use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::Json;
use pathfarm_wire::api::{
    Convergence, JobList, JobPatch, JobState, JobView, TileProgress, TileRect,
};
use serde::Deserialize;

/// The API view of a stored job.
pub(crate) fn view(job: JobRow, tiles: Option<Vec<TileProgress>>, now: i64) -> JobView {
    let elapsed_s = job
        .started_ms
        .map(|s| ((job.finished_ms.unwrap_or(now) - s).max(1)) as f64 / 1000.0);
    let rate = elapsed_s.map_or(0.0, |t| job.samples_done as f64 / t);
    let eta = (!job.state.is_final() && rate > 0.0)
        .then(|| job.samples_planned.saturating_sub(job.samples_done) as f64 / rate);
    let mut settings = job.settings;
    settings.priority = job.priority;
    JobView {
        id: job.id,
        name: job.name,
        state: job.state,
        priority: job.priority,
        settings,
        scene_hash: job.scene_hash,
        samples_done: job.samples_done,
        samples_planned: job.samples_planned,
        relative_error: job.rel_error,
        samples_per_second: rate,
        eta_seconds: eta,
        created_at_ms: job.created_ms,
        started_at_ms: job.started_ms,
        finished_at_ms: job.finished_ms,
        message: job.message,
        leased_tasks: job.leased_tasks,
        warnings: job.warnings,
        tiles,
        frames_total: None,
        frames_done: None,
        frames: None,
    }
}

/// Adds a frame job's frame counts to its view (and, with `detail`, every frame's progress).
/// A still job's view is left as it is.
pub(crate) async fn with_frames(
    state: &AppState,
    mut view: JobView,
    detail: bool,
) -> ApiResult<JobView> {
    if view.settings.frames.is_none() {
        return Ok(view);
    }
    let frames = state
        .store
        .frame_progress(
            &view.id,
            u64::from(view.settings.spp),
            view.settings.noise_target,
        )
        .await?;
    view.frames_total = Some(frames.len() as u64);
    view.frames_done = Some(frames.iter().filter(|f| f.complete).count() as u64);
    view.frames = detail.then_some(frames);
    Ok(view)
}

#[derive(Deserialize)]
pub struct ListQuery {
    state: Option<String>,
    page: Option<u32>,
    per_page: Option<u32>,
}

pub async fn list(
    _: ReadAuth,
    State(state): State<AppState>,
    query: Result<Query<ListQuery>, axum::extract::rejection::QueryRejection>,
) -> ApiResult<Json<JobList>> {
    let Query(q) = query.map_err(|e| ApiError::bad_request("bad_query", e.body_text()))?;
    let filter = match q.state.as_deref() {
        None | Some("") => None,
        Some(s) => Some(JobState::parse(s).ok_or_else(|| {
            ApiError::bad_request(
                "bad_query",
                format!(
                    "unknown state {s:?} (queued, running, paused, completed, cancelled, failed)"
                ),
            )
        })?),
    };
    let window = Page::new(q.page, q.per_page, 50, 500);
    let (jobs, total) = state
        .store
        .jobs(filter, window.offset(), window.limit())
        .await?;
    let Page { page, per_page } = window;
    let now = state.store.now_ms();
    let mut views = Vec::with_capacity(jobs.len());
    for j in jobs {
        views.push(with_frames(&state, view(j, None, now), false).await?);
    }
    Ok(Json(JobList {
        jobs: views,
        total,
        page,
        per_page,
    }))
}

#[derive(Deserialize)]
pub struct ConvergenceQuery {
    /// A frame job's frame: its history instead of the job's.
    #[serde(default)]
    frame: Option<i64>,
}

/// The job's convergence history (or, with `frame`, that frame's): estimated error and
/// throughput against time.
pub async fn convergence(
    _: ReadAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(q): Query<ConvergenceQuery>,
) -> ApiResult<Json<Convergence>> {
    if q.frame.is_some() {
        // 404 for a frame the job does not render.
        super::images::frame_slot(&state.store.job(&id).await?, q.frame)?;
    }
    Ok(Json(state.store.convergence(&id, q.frame).await?))
}

pub async fn show(
    _: ReadAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<JobView>> {
    let mut job = state.store.job(&id).await?;
    if job.state.is_final() && job.rel_error_version < job.version {
        // The last merges finished the job before the monitor estimated their image: estimate it
        // now, so a client that waited for the end reads the final error, not a stale one.
        // Without room for the image now, the last estimate stands (the monitor catches up).
        job.rel_error = match crate::monitor::refresh_estimate(&state, &job).await {
            Err(e) if e.code == "busy" => job.rel_error,
            r => r?,
        };
    }
    let tiles = state
        .store
        .tiles(&id)
        .await?
        .into_iter()
        .map(|t| TileProgress {
            rect: TileRect {
                x0: t.tile.x0,
                y0: t.tile.y0,
                width: t.tile.width,
                height: t.tile.height,
            },
            samples_per_pixel: t.samples,
            frame: t.frame,
        })
        .collect();
    let v = view(job, Some(tiles), state.store.now_ms());
    Ok(Json(with_frames(&state, v, true).await?))
}

pub async fn patch_job(
    _: ClientAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    JsonBody(patch): JsonBody<JobPatch>,
) -> ApiResult<Json<JobView>> {
    let job = state.store.set_priority(&id, patch.priority).await?;
    let v = view(job, None, state.store.now_ms());
    Ok(Json(with_frames(&state, v, false).await?))
}

pub async fn delete_job(
    _: ClientAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<StatusCode> {
    state.store.delete_job(&id).await?;
    state.images.forget(&id);
    tracing::info!(job = %id, "job deleted");
    Ok(StatusCode::NO_CONTENT)
}

async fn event(state: &AppState, id: &str, e: JobEvent) -> ApiResult<Json<JobView>> {
    let job = state.store.job_event(id, e, None).await?;
    tracing::info!(job = %id, state = job.state.as_str(), "job state changed");
    let v = view(job, None, state.store.now_ms());
    Ok(Json(with_frames(state, v, false).await?))
}

pub async fn cancel(
    _: ClientAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<JobView>> {
    event(&state, &id, JobEvent::Cancel).await
}

pub async fn pause(
    _: ClientAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<JobView>> {
    event(&state, &id, JobEvent::Pause).await
}

pub async fn resume(
    _: ClientAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Json<JobView>> {
    let view = event(&state, &id, JobEvent::Resume { started: false }).await?;
    state.work.notify();
    Ok(view)
}
