//! Worker registration, heartbeats and leases.

use super::{no_control, no_nul, JsonBody, OptionalJsonBody, Page};
use crate::auth::{ReadAuth, WorkerAuth, WorkerIdentity};
use crate::error::{ApiError, ApiResult};
use crate::pacing::Write;
use crate::store::WorkerPage;
use crate::work_signal::Woken;
use crate::AppState;
use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use pathfarm_wire::api::{
    Heartbeat, HeartbeatReply, WorkerList, WorkerRegistered, WorkerRegistration,
};
use std::time::Duration;

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
    let (id, credential) = state
        .store
        .register_worker_within(&reg, state.config.max_workers)
        .await?;
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
    after: Option<String>,
}

/// A page of workers, by number or after a cursor (`next` of the page before): every worker is
/// on some page, however many there are, and the cursors reach each exactly once however the
/// farm changes while they are followed ([`crate::store::Store::workers`]).
pub async fn list(
    _: ReadAuth,
    State(state): State<AppState>,
    query: Result<Query<ListQuery>, axum::extract::rejection::QueryRejection>,
) -> ApiResult<Json<WorkerList>> {
    let Query(q) = query.map_err(|e| ApiError::bad_request("bad_query", e.body_text()))?;
    let window = Page::new(q.page, q.per_page, 100, 1000);
    // A cursor, when given, decides where the page starts; `page` is then not read.
    let from = match &q.after {
        None => WorkerPage::Offset(window.offset()),
        Some(after) => WorkerPage::After(after.parse().map_err(|()| {
            ApiError::bad_request(
                "bad_query",
                "`after` is not a cursor this server gave (the `next` of a page of workers)",
            )
        })?),
    };
    let (workers, total, next) = state.store.workers(from, window.limit()).await?;
    Ok(Json(WorkerList {
        workers,
        total,
        page: if q.after.is_some() { 0 } else { window.page },
        per_page: window.per_page,
        next: next.map(|c| c.to_string()),
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

/// The most `wait_ms` a lease request may give (the contract's `maximum`).
const MAX_WAIT_MS: u64 = 60_000;

#[derive(serde::Deserialize)]
pub struct LeaseQuery {
    /// How long to wait for work when there is none (long poll), in ms; cut to
    /// [`crate::ServerConfig::max_lease_wait`].
    wait_ms: Option<u64>,
}

/// `200` with a lease, or `204` when there is no work (after waiting up to `wait_ms` for some:
/// [`crate::work_signal`]); `429 too_many_leases` when the worker already holds
/// [`crate::ServerConfig::max_leases_per_worker`].
pub async fn lease(
    me: WorkerIdentity,
    State(state): State<AppState>,
    Path(id): Path<String>,
    query: Result<Query<LeaseQuery>, axum::extract::rejection::QueryRejection>,
) -> ApiResult<Response> {
    me.must_be(&id)?;
    let Query(q) = query.map_err(|e| ApiError::bad_request("bad_query", e.body_text()))?;
    let wait_ms = q.wait_ms.unwrap_or(0);
    if wait_ms > MAX_WAIT_MS {
        return Err(ApiError::bad_request(
            "bad_query",
            format!("wait_ms must be at most {MAX_WAIT_MS}, not {wait_ms}"),
        ));
    }
    let wait = Duration::from_millis(wait_ms).min(state.config.max_lease_wait);
    let deadline = tokio::time::Instant::now() + wait;
    // Subscribed before the first try: work queued between a try and the wait wakes it.
    let mut waiter = (!wait.is_zero()).then(|| state.work.waiter());
    loop {
        if let Some(lease) = try_lease(&state, &id).await? {
            return Ok(Json(lease).into_response());
        }
        let Some(w) = waiter.as_mut() else {
            return Ok(StatusCode::NO_CONTENT.into_response());
        };
        if w.wait(deadline).await == Woken::Done {
            return Ok(StatusCode::NO_CONTENT.into_response());
        }
    }
}

/// One try at leasing a task for worker `id`.
async fn try_lease(state: &AppState, id: &str) -> ApiResult<Option<pathfarm_wire::api::Lease>> {
    let lease_ms = state.config.lease_duration.as_millis() as u64;
    let started = std::time::Instant::now();
    let write = state
        .pacing
        .begin(Write::Lease, id)
        .map_err(|slow| ApiError::slow_down(slow.retry_after_seconds))?;
    let lease = state
        .store
        .lease(id, lease_ms, state.config.max_leases_per_worker)
        .await?;
    drop(write);
    state.metrics.observe_lease(started.elapsed());
    Ok(lease.map(|mut l| {
        state.pacing.seen(id);
        l.slice_seconds = Some(state.pacing.slice_seconds());
        l
    }))
}
