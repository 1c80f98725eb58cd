//! Bearer tokens: client tokens manage jobs, worker tokens lease and upload. Reading (jobs, images,
//! workers) takes either. With no token configured at all the API is open (loopback only: `serve`
//! refuses to listen elsewhere without tokens).

use crate::error::ApiError;
use crate::AppState;
use axum::extract::FromRequestParts;
use axum::http::request::Parts;
use axum::http::StatusCode;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    Client,
    Worker,
}

fn bearer(parts: &Parts) -> Option<&str> {
    parts
        .headers
        .get(axum::http::header::AUTHORIZATION)?
        .to_str()
        .ok()?
        .strip_prefix("Bearer ")
        .map(str::trim)
}

/// Compares without an early exit, so the time taken says nothing about the token.
fn same(a: &str, b: &str) -> bool {
    a.len() == b.len()
        && a.bytes()
            .zip(b.bytes())
            .fold(0u8, |acc, (x, y)| acc | (x ^ y))
            == 0
}

fn role_of(state: &AppState, parts: &Parts) -> Result<Option<Role>, ApiError> {
    if !state.config.auth_required() {
        return Ok(None);
    }
    let Some(token) = bearer(parts) else {
        return Err(ApiError::new(
            StatusCode::UNAUTHORIZED,
            "unauthorized",
            "this server requires a bearer token (Authorization: Bearer …)",
        ));
    };
    if state.config.client_tokens.iter().any(|t| same(t, token)) {
        return Ok(Some(Role::Client));
    }
    if state.config.worker_tokens.iter().any(|t| same(t, token)) {
        return Ok(Some(Role::Worker));
    }
    Err(ApiError::new(
        StatusCode::UNAUTHORIZED,
        "unauthorized",
        "unknown token",
    ))
}

fn require(state: &AppState, parts: &Parts, want: Role) -> Result<(), ApiError> {
    match role_of(state, parts)? {
        None => Ok(()),
        Some(r) if r == want => Ok(()),
        Some(r) => Err(ApiError::new(
            StatusCode::FORBIDDEN,
            "forbidden",
            format!(
                "a {} token cannot do this; it needs a {} token",
                if r == Role::Client {
                    "client"
                } else {
                    "worker"
                },
                if want == Role::Client {
                    "client"
                } else {
                    "worker"
                }
            ),
        )),
    }
}

/// Extractor: the request carries a client token (or auth is off).
pub struct ClientAuth;
/// Extractor: the request carries a worker token (or auth is off).
pub struct WorkerAuth;
/// Extractor: the request carries any valid token (or auth is off).
pub struct ReadAuth;

impl FromRequestParts<AppState> for ClientAuth {
    type Rejection = ApiError;
    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, ApiError> {
        require(state, parts, Role::Client).map(|_| ClientAuth)
    }
}

impl FromRequestParts<AppState> for WorkerAuth {
    type Rejection = ApiError;
    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, ApiError> {
        require(state, parts, Role::Worker).map(|_| WorkerAuth)
    }
}

impl FromRequestParts<AppState> for ReadAuth {
    type Rejection = ApiError;
    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, ApiError> {
        role_of(state, parts).map(|_| ReadAuth)
    }
}
