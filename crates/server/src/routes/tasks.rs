//! What workers call while rendering: fetch a scene, upload slices, give a lease back.

use super::{body_error, json_body, json_bytes, no_nul, parse_id};
use crate::auth::WorkerAuth;
use crate::error::{ApiError, ApiResult};
use crate::store::MergeOutcome;
use crate::AppState;
use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::IntoResponse;
use axum::Json;
use pathfarm_wire::api::{Release, SliceAck, LEASE_TOKEN_HEADER, SLICE_CONTENT_TYPE};
use pathfarm_wire::{decode_slice, decode_slice_header, SliceError, SliceLimits};
use std::sync::atomic::Ordering;

/// The scene bytes by content hash (immutable, so cacheable forever).
pub async fn scene(
    _: WorkerAuth,
    State(state): State<AppState>,
    Path(hash): Path<String>,
) -> ApiResult<impl IntoResponse> {
    let bytes = state.store.scene(&hash).await?;
    Ok((
        [
            (header::CONTENT_TYPE, "application/octet-stream"),
            (header::CACHE_CONTROL, "public, max-age=31536000, immutable"),
        ],
        bytes,
    ))
}

/// `POST /api/v1/tasks/{id}/slices`: one slice's accumulation, binary (`application/x-pathfarm-slice`),
/// with the lease token in the `Pathfarm-Lease-Token` header.
///
/// The body is read within the slice limit; its pixels are decoded only once the token is known
/// to hold the task and the header names the task's tile, so an upload makes the server allocate
/// no more than the tile it may write to.
pub async fn upload_slice(
    _: WorkerAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> ApiResult<Json<SliceAck>> {
    let body = body.map_err(|e| body_error(e, "slice", state.config.limits.max_slice_bytes))?;
    let task_id = parse_id(&id, "task")?;
    let ct = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    if ct != SLICE_CONTENT_TYPE {
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
    match merge_upload(&state, task_id, &token, &body).await {
        Ok(out) => {
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

/// Header, lease, tile, then the pixels, then the merge (which checks the lease again, in its
/// transaction).
async fn merge_upload(
    state: &AppState,
    task_id: i64,
    token: &str,
    body: &[u8],
) -> ApiResult<MergeOutcome> {
    let claimed = decode_slice_header(body).map_err(slice_error)?;
    let tile = state.store.leased_tile(task_id, token).await?;
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
    let slice = decode_slice(body, &limits).map_err(slice_error)?;
    state.store.merge_slice(task_id, token, slice).await
}

pub async fn release(
    _: WorkerAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> ApiResult<StatusCode> {
    let task_id = parse_id(&id, "task")?;
    let r: Release = json_body(&headers, &json_bytes(body)?)?;
    no_nul("invalid_release", &[("lease_token", &r.lease_token)])?;
    state.store.release(task_id, &r.lease_token).await?;
    Ok(StatusCode::NO_CONTENT)
}
