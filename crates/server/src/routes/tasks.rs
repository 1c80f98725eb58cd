//! What workers call while rendering: fetch a scene, upload slices, give a lease back.

use super::{json_body, parse_id};
use crate::auth::WorkerAuth;
use crate::error::{ApiError, ApiResult};
use crate::AppState;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::IntoResponse;
use axum::Json;
use pathfarm_wire::api::{Release, SliceAck, LEASE_TOKEN_HEADER, SLICE_CONTENT_TYPE};
use pathfarm_wire::{decode_slice, SliceLimits};
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
pub async fn upload_slice(
    _: WorkerAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    headers: HeaderMap,
    body: Bytes,
) -> ApiResult<Json<SliceAck>> {
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
    let limits = SliceLimits {
        max_pixels: state.config.limits.max_pixels,
    };
    let slice = match decode_slice(&body, &limits) {
        Ok(s) => s,
        Err(e) => {
            state
                .metrics
                .rejected_uploads
                .fetch_add(1, Ordering::Relaxed);
            return Err(ApiError::unprocessable(
                "invalid_slice",
                format!("slice body rejected: {e}"),
            ));
        }
    };
    match state.store.merge_slice(task_id, &token, slice).await {
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

pub async fn release(
    _: WorkerAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    headers: HeaderMap,
    body: Bytes,
) -> ApiResult<StatusCode> {
    let task_id = parse_id(&id, "task")?;
    let r: Release = json_body(&headers, &body)?;
    state.store.release(task_id, &r.lease_token).await?;
    Ok(StatusCode::NO_CONTENT)
}
