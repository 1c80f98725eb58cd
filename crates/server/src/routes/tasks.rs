//! What workers call while rendering: fetch a scene, upload slices, give a lease back.

use super::{no_nul, parse_id, JsonBody};
use crate::auth::WorkerIdentity;
use crate::connections::content_length;
use crate::error::{ApiError, ApiResult};
use crate::pacing::Write;
use crate::store::{AllInvalid, MergeOutcome};
use crate::AppState;
use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::IntoResponse;
use axum::Json;
use http_body_util::BodyExt;
use pathfarm_wire::api::{
    Release, SliceAck, LEASE_TOKEN_HEADER, SLICE_CONTENT_TYPE, SLICE_CONTENT_TYPE_LEGACY,
};
use pathfarm_wire::{
    decode_slice, decode_slice_header, max_slice_body_bytes, SliceError, SliceLimits,
};
use std::sync::atomic::Ordering;

/// The scene bytes by content hash (immutable, so cacheable forever), for a worker that holds a
/// lease on a job of this scene (or environment image): 403 `not_your_scene` otherwise, so that a
/// worker token does not read every scene of the farm. The lease must be held at the time of the
/// download; the worker daemon downloads right after its lease and caches the scene.
pub async fn scene(
    me: WorkerIdentity,
    State(state): State<AppState>,
    Path(hash): Path<String>,
) -> ApiResult<impl IntoResponse> {
    if !state.store.worker_needs_blob(&me.id, &hash).await? {
        return Err(ApiError::new(
            StatusCode::FORBIDDEN,
            "not_your_scene",
            format!(
                "worker {} holds no lease on a job of scene {hash}: a worker downloads only the \
                 scenes of its leases",
                me.id
            ),
        ));
    }
    let bytes = state.store.scene(&hash).await?;
    Ok((
        [
            (header::CONTENT_TYPE, "application/octet-stream"),
            (header::CACHE_CONTROL, "public, max-age=31536000, immutable"),
        ],
        bytes,
    ))
}

/// `POST /api/v1/tasks/{id}/slices`: one slice's accumulation, binary (`application/octet-stream`,
/// or the older `application/x-pathfarm-slice`), with the lease token in the
/// `Pathfarm-Lease-Token` header.
///
/// Everything that can refuse the upload without its body is checked before a byte of it is
/// read: the worker token, the content type, the lease token against the task, and the declared
/// length against the largest honest slice of the task's tile (`wire::max_slice_body_bytes`)
/// and the slice limit. The body is then read within that bound; its pixels are decoded only
/// once its header names the task's tile, so an upload makes the server allocate no more than
/// the tile it may write to.
pub async fn upload_slice(
    me: WorkerIdentity,
    State(state): State<AppState>,
    Path(id): Path<String>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Json<SliceAck>> {
    let task_id = parse_id(&id, "task")?;
    let ct = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    // The generic binary type (what the contract declares: client generators can send it), or
    // the slice's own type, which workers sent before.
    if ct != SLICE_CONTENT_TYPE && ct != SLICE_CONTENT_TYPE_LEGACY {
        return Err(ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "unsupported_media_type",
            format!("expected Content-Type {SLICE_CONTENT_TYPE}, got {ct:?}"),
        ));
    }
    let token = headers
        .get(LEASE_TOKEN_HEADER)
        .and_then(|v| v.to_str().ok())
        .ok_or_else(|| {
            ApiError::bad_request(
                "missing_lease_token",
                format!("the {LEASE_TOKEN_HEADER} header is required"),
            )
        })?
        .to_string();
    match merge_upload(&state, &me.id, task_id, &token, &headers, body).await {
        Ok(MergeOutcome {
            all_invalid: Some(refused),
            ..
        }) => {
            state
                .metrics
                .rejected_uploads
                .fetch_add(1, Ordering::Relaxed);
            let message = match refused {
                AllInvalid::Requeued { task_id } => format!(
                    "every sample of the slice is invalid: task {task_id} was not completed and \
                     is queued again for another worker"
                ),
                AllInvalid::JobFailed { job_id, message } => {
                    format!("job {job_id} failed: {message}")
                }
            };
            Err(ApiError::unprocessable("all_invalid", message))
        }
        Ok(mut out) => {
            state.pacing.seen(&me.id);
            out.ack.slice_seconds = Some(state.pacing.slice_seconds());
            if out.ack.duplicate {
                state
                    .metrics
                    .duplicate_uploads
                    .fetch_add(1, Ordering::Relaxed);
            } else {
                state.metrics.merged_uploads.fetch_add(1, Ordering::Relaxed);
                state
                    .metrics
                    .merged_samples
                    .fetch_add(out.samples, Ordering::Relaxed);
                state
                    .metrics
                    .verification_samples
                    .fetch_add(out.verification_samples, Ordering::Relaxed);
            }
            if out.job_completed {
                tracing::info!(task = task_id, "job completed");
            }
            Ok(Json(out.ack))
        }
        Err(e) => {
            if e.status.is_client_error() {
                state
                    .metrics
                    .rejected_uploads
                    .fetch_add(1, Ordering::Relaxed);
            }
            Err(e)
        }
    }
}

fn slice_error(e: SliceError) -> ApiError {
    match e {
        SliceError::PixelValues { .. } => {
            ApiError::unprocessable("slice_values", format!("slice body rejected: {e}"))
        }
        e => ApiError::unprocessable("invalid_slice", format!("slice body rejected: {e}")),
    }
}

/// Lease and declared length, then the body, its header against the tile, the pixels, then the
/// merge (which checks the lease again, in its transaction).
async fn merge_upload(
    state: &AppState,
    worker_id: &str,
    task_id: i64,
    token: &str,
    headers: &HeaderMap,
    body: Body,
) -> ApiResult<MergeOutcome> {
    let tile = state
        .store
        .leased_tile_for(task_id, token, worker_id)
        .await?;
    // A task never spans more than `u32::MAX` samples (a job's spp is a `u32`).
    let honest = max_slice_body_bytes(tile.pixel_count(), u64::from(u32::MAX));
    let limit = usize::try_from(honest)
        .unwrap_or(usize::MAX)
        .min(state.config.limits.max_slice_bytes);
    let too_large = |what: String| {
        ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "too_large",
            format!(
                "{what} exceeds the limit of {limit} bytes for task {task_id} (its {}x{} tile's \
                 largest slice, at most the slice limit of {} bytes)",
                tile.width, tile.height, state.config.limits.max_slice_bytes
            ),
        )
    };
    let declared = content_length(headers);
    if let Some(n) = declared.filter(|&n| n > limit as u64) {
        return Err(too_large(format!("the slice body's declared {n} bytes")));
    }
    // Room for it in the server's budget of bodies held in memory, before it is read.
    let need = declared.map_or(limit as u64, |n| n.min(limit as u64));
    let _room = state.bodies.reserve(need, "a slice upload").await?;
    let body = read_body(body, limit, declared)
        .await?
        .ok_or_else(|| too_large("the slice body".to_string()))?;
    let claimed = decode_slice_header(&body).map_err(slice_error)?;
    if (claimed.x0, claimed.y0, claimed.width, claimed.height)
        != (tile.x0, tile.y0, tile.width, tile.height)
    {
        return Err(ApiError::unprocessable(
            "slice_shape",
            format!(
                "slice covers {}x{} at ({}, {}), task {task_id}'s tile is {}x{} at ({}, {})",
                claimed.width,
                claimed.height,
                claimed.x0,
                claimed.y0,
                tile.width,
                tile.height,
                tile.x0,
                tile.y0
            ),
        ));
    }
    let limits = SliceLimits {
        max_pixels: tile.pixel_count().min(state.config.limits.max_pixels),
    };
    let slice = decode_slice(&body, &limits).map_err(slice_error)?;
    // Uploads are always admitted (they carry finished work), so this is never an error.
    let _write = state.pacing.begin(Write::Upload, worker_id).ok();
    Ok(state.store.merge_slice(task_id, token, slice).await?)
}

/// Reads a body of at most `limit` bytes (None: it is longer), into one buffer sized by its
/// declared length when it has one.
async fn read_body(
    mut body: Body,
    limit: usize,
    declared: Option<u64>,
) -> ApiResult<Option<Vec<u8>>> {
    let capacity = declared.map_or(0, |n| usize::try_from(n).unwrap_or(limit).min(limit));
    let mut buf = Vec::with_capacity(capacity);
    while let Some(frame) = body.frame().await {
        let frame = frame.map_err(|e| {
            ApiError::bad_request("bad_body", format!("the body could not be read: {e}"))
        })?;
        let Ok(chunk) = frame.into_data() else {
            continue; // trailers
        };
        if chunk.len() > limit - buf.len() {
            return Ok(None);
        }
        buf.extend_from_slice(&chunk);
    }
    Ok(Some(buf))
}

pub async fn release(
    me: WorkerIdentity,
    State(state): State<AppState>,
    Path(id): Path<String>,
    JsonBody(r): JsonBody<Release>,
) -> ApiResult<StatusCode> {
    let task_id = parse_id(&id, "task")?;
    no_nul("invalid_release", &[("lease_token", &r.lease_token)])?;
    state
        .store
        .release_by(task_id, &r.lease_token, &me.id)
        .await?;
    state.work.notify();
    Ok(StatusCode::NO_CONTENT)
}
