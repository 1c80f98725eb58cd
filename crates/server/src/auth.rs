//! Bearer tokens: client tokens manage jobs, worker tokens register workers. Reading (jobs,
//! images, workers) takes either. With no token configured at all the API is open (loopback only:
//! `serve` refuses to listen elsewhere without tokens).
//!
//! A worker token does not name a worker: every call a worker makes for itself (lease, heartbeat,
//! sign-off, upload, release, scene download) also carries the credential its registration
//! answered ([`WorkerIdentity`]), and acts only for the worker that credential belongs to.

use crate::error::ApiError;
use crate::AppState;
use axum::extract::FromRequestParts;
use axum::http::request::Parts;
use axum::http::StatusCode;
use pathfarm_wire::api::WORKER_CREDENTIAL_HEADER;
use sha2::{Digest, Sha256};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    Client,
    Worker,
}

/// The token of an `Authorization: Bearer …` header. The scheme is matched without regard to case
/// (RFC 9110, section 11.1: `bearer` and `BEARER` are the same scheme).
fn bearer(parts: &Parts) -> Option<&str> {
    let value = parts
        .headers
        .get(axum::http::header::AUTHORIZATION)?
        .to_str()
        .ok()?;
    let (scheme, token) = value.trim_start().split_once(' ')?;
    scheme
        .eq_ignore_ascii_case("bearer")
        .then_some(token.trim())
}

/// Compares the SHA-256 digests of the two tokens, byte by byte without an early exit: the time
/// taken says nothing about the token, not even its length (a comparison of the tokens
/// themselves must stop at the shorter one).
fn same(a: &str, b: &str) -> bool {
    let (a, b) = (Sha256::digest(a.as_bytes()), Sha256::digest(b.as_bytes()));
    a.iter()
        .zip(b.iter())
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
pub struct ClientAuth {
    /// Whose request it is, as the store keeps it with the jobs it submits: the first 16 hex
    /// digits of the token's SHA-256 (not the token, which the store must not hold), or `""` when
    /// the server takes no tokens. Quotas count per owner.
    pub owner: String,
}

/// The owner a client token's jobs are stored under ([`ClientAuth::owner`]).
pub fn owner_of(token: &str) -> String {
    let mut digest = hex::encode(Sha256::digest(token.as_bytes()));
    digest.truncate(16);
    digest
}
/// Extractor: the request carries a worker token (or auth is off).
pub struct WorkerAuth;
/// Extractor: the request carries any valid token (or auth is off).
pub struct ReadAuth;
/// Extractor: the request carries a worker token (or auth is off) and the credential of a
/// registered worker ([`WORKER_CREDENTIAL_HEADER`]); `id` is that worker. The credential is
/// required with auth off as well: it is what keeps one worker from acting for another, which a
/// bug can do as well as an attacker.
pub struct WorkerIdentity {
    pub id: String,
}

impl WorkerIdentity {
    /// Refuses (403 `not_your_worker`) a call for a worker other than the caller.
    pub fn must_be(&self, id: &str) -> Result<(), ApiError> {
        if self.id == id {
            return Ok(());
        }
        Err(ApiError::new(
            StatusCode::FORBIDDEN,
            "not_your_worker",
            format!(
                "this credential belongs to worker {}, not to worker {id}: a worker acts only for \
                 itself",
                self.id
            ),
        ))
    }
}

impl FromRequestParts<AppState> for ClientAuth {
    type Rejection = ApiError;
    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, ApiError> {
        require(state, parts, Role::Client)?;
        let owner = match bearer(parts) {
            Some(token) if state.config.auth_required() => owner_of(token),
            _ => String::new(),
        };
        Ok(ClientAuth { owner })
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

impl FromRequestParts<AppState> for WorkerIdentity {
    type Rejection = ApiError;
    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, ApiError> {
        require(state, parts, Role::Worker)?;
        let Some(credential) = parts
            .headers
            .get(WORKER_CREDENTIAL_HEADER)
            .and_then(|v| v.to_str().ok())
            .map(str::trim)
            .filter(|c| !c.is_empty())
        else {
            return Err(ApiError::new(
                StatusCode::UNAUTHORIZED,
                "missing_worker_credential",
                format!(
                    "this call needs the {WORKER_CREDENTIAL_HEADER} header: the credential \
                     POST /api/v1/workers answered"
                ),
            ));
        };
        match state.store.worker_by_credential(credential).await? {
            Some(id) => Ok(WorkerIdentity { id }),
            // A registration that expired (and was collected) lands here too: the worker must
            // register again, which the worker daemon does on this code.
            None => Err(ApiError::new(
                StatusCode::UNAUTHORIZED,
                "unknown_worker_credential",
                "no registered worker has this credential (its registration may have expired); \
                 register again",
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::Request;

    fn parts(authorization: &str) -> Parts {
        let request = Request::builder()
            .header("authorization", authorization)
            .body(())
            .expect("a request");
        request.into_parts().0
    }

    #[test]
    fn the_scheme_is_matched_without_regard_to_case() {
        for header in ["Bearer t0k", "bearer t0k", "BEARER t0k", "  Bearer   t0k  "] {
            assert_eq!(bearer(&parts(header)), Some("t0k"), "{header:?}");
        }
        for header in ["Basic t0k", "Bearer", "Bearert0k", "t0k"] {
            assert_eq!(bearer(&parts(header)), None, "{header:?}");
        }
    }

    #[test]
    fn tokens_compare_equal_only_when_equal() {
        assert!(same("secret", "secret"));
        assert!(!same("secret", "secreT"));
        assert!(!same("secret", "secret2"));
        assert!(!same("", "secret"));
        assert!(same("", ""));
    }
}
