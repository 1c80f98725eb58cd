//! Worker registration, heartbeats and leases.

use super::{no_control, no_nul, JsonBody, OptionalJsonBody, Page};
use crate::auth::{ReadAuth, WorkerAuth, WorkerIdentity};
use crate::error::{ApiError, ApiResult};
use crate::pacing::Write;
use crate::AppState;
use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use pathfarm_wire::api::{
    Heartbeat, HeartbeatReply, WorkerList, WorkerRegistered, WorkerRegistration,
};

pub async fn register(
    _: WorkerAuth,
    State(state): State<AppState>,
    JsonBody(reg): JsonBody<WorkerRegistration>,
) -> ApiResult<(StatusCode, Json<WorkerRegistered>)> {
    // Lengths in characters, as the contract's `maxLength` counts them.
    let chars = |s: &str| s.chars().count();
    if reg.name.is_empty()
        || chars(&reg.name) > 128
        || chars(&reg.host) > 256
        || chars(&reg.version) > 64
    {
        return Err(ApiError::unprocessable(
            "invalid_worker",
            "name must be 1..=128 characters, host at most 256, version at most 64",
        ));
    }
    no_control(
        "invalid_worker",
        &[
            ("name", &reg.name),
            ("host", &reg.host),
            ("version", &reg.version),
        ],
    )?;
    let (id, credential) = state.store.register_worker(&reg).await?;
    tracing::info!(worker = %id, name = %reg.name, host = %reg.host, threads = reg.threads, "worker registered");
    let lease_ms = state.config.lease_duration.as_millis() as u64;
    Ok((
        StatusCode::CREATED,
        Json(WorkerRegistered {
            worker_id: id,
            credential,
            lease_duration_ms: lease_ms,
            heartbeat_interval_ms: (lease_ms / 4).max(50),
        }),
    ))
}

#[derive(serde::Deserialize)]
pub struct ListQuery {
    page: Option<u32>,
    per_page: Option<u32>,
}

/// A page of workers (as the jobs are paged): every worker is on some page, however many there
/// are.
pub async fn list(
    _: ReadAuth,
    State(state): State<AppState>,
    query: Result<Query<ListQuery>, axum::extract::rejection::QueryRejection>,
) -> ApiResult<Json<WorkerList>> {
    let Query(q) = query.map_err(|e| ApiError::bad_request("bad_query", e.body_text()))?;
    let window = Page::new(q.page, q.per_page, 100, 1000);
    let (workers, total) = state.store.workers(window.offset(), window.limit()).await?;
    let Page { page, per_page } = window;
    Ok(Json(WorkerList {
        workers,
        total,
        page,
        per_page,
    }))
}

pub async fn deregister(
    me: WorkerIdentity,
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<StatusCode> {
    me.must_be(&id)?;
    state.store.deregister_worker(&id).await?;
    tracing::info!(worker = %id, "worker signed off");
    Ok(StatusCode::NO_CONTENT)
}

pub async fn heartbeat(
    me: WorkerIdentity,
    State(state): State<AppState>,
    Path(id): Path<String>,
    OptionalJsonBody(hb): OptionalJsonBody<Heartbeat>,
) -> ApiResult<Json<HeartbeatReply>> {
    me.must_be(&id)?;
    let hb = hb.unwrap_or_default();
    let lease_ms = state.config.lease_duration.as_millis() as u64;
    let lease = match (hb.task_id, hb.lease_token.as_deref()) {
        (Some(t), Some(tok)) => {
            no_nul("invalid_heartbeat", &[("lease_token", tok)])?;
            Some((t, tok))
        }
        (None, None) => None,
        _ => {
            return Err(ApiError::unprocessable(
                "invalid_heartbeat",
                "task_id and lease_token come together",
            ))
        }
    };
    let valid = state.store.heartbeat(&id, lease, lease_ms).await?;
    Ok(Json(HeartbeatReply {
        lease_valid: valid,
        lease_expires_in_ms: if valid { lease_ms } else { 0 },
    }))
}

/// `200` with a lease, or `204` when there is no work; `429 too_many_leases` when the worker
/// already holds [`crate::ServerConfig::max_leases_per_worker`].
pub async fn lease(
    me: WorkerIdentity,
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> ApiResult<Response> {
    me.must_be(&id)?;
    let lease_ms = state.config.lease_duration.as_millis() as u64;
    let started = std::time::Instant::now();
    let write = state
        .pacing
        .begin(Write::Lease, &id)
        .map_err(|slow| ApiError::slow_down(slow.retry_after_seconds))?;
    let lease = state
        .store
        .lease(&id, lease_ms, state.config.max_leases_per_worker)
        .await?;
    drop(write);
    state.metrics.observe_lease(started.elapsed());
    Ok(match lease {
        Some(mut l) => {
            state.pacing.seen(&id);
            l.slice_seconds = Some(state.pacing.slice_seconds());
            Json(l).into_response()
        }
        None => StatusCode::NO_CONTENT.into_response(),
    })
}
