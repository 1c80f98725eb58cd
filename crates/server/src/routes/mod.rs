//! The HTTP routes. [`api_routes`] is the single list the router is built from, so the test that
//! holds `openapi.yaml` and the router to each other reads the same list the server serves.

mod frames;
mod health;
mod images;
mod jobs;
mod json;
mod media;
pub(crate) mod metrics;
pub(crate) use json::{starts_an_object, JsonBody, OptionalJsonBody};
mod submit;
mod tasks;
mod workers;

use crate::config::{Limits, MAX_JSON_BODY_BYTES};
use crate::error::ApiError;
use crate::AppState;
use axum::extract::rejection::BytesRejection;
use axum::extract::Request;
use axum::http::{Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::{delete, get, patch, post, MethodRouter};

pub struct Route {
    pub method: Method,
    /// In OpenAPI form: `/api/v1/jobs/{id}`.
    pub path: &'static str,
    pub handler: MethodRouter<AppState>,
}

fn route(method: Method, path: &'static str, handler: MethodRouter<AppState>) -> Route {
    Route {
        method,
        path,
        handler,
    }
}

/// Every route of the API.
pub fn api_routes() -> Vec<Route> {
    use Method as M;
    vec![
        route(M::GET, "/healthz", get(health::healthz)),
        route(M::GET, "/readyz", get(health::healthz)),
        route(M::GET, "/metrics", get(metrics::metrics)),
        route(M::POST, "/api/v1/jobs", post(submit::submit)),
        route(M::GET, "/api/v1/jobs", get(jobs::list)),
        route(M::GET, "/api/v1/jobs/{id}", get(jobs::show)),
        route(M::PATCH, "/api/v1/jobs/{id}", patch(jobs::patch_job)),
        route(M::DELETE, "/api/v1/jobs/{id}", delete(jobs::delete_job)),
        route(M::POST, "/api/v1/jobs/{id}/cancel", post(jobs::cancel)),
        route(M::POST, "/api/v1/jobs/{id}/pause", post(jobs::pause)),
        route(M::POST, "/api/v1/jobs/{id}/resume", post(jobs::resume)),
        route(
            M::GET,
            "/api/v1/jobs/{id}/convergence",
            get(jobs::convergence),
        ),
        route(
            M::GET,
            "/api/v1/jobs/{id}/image.exr",
            get(images::image_exr),
        ),
        route(
            M::GET,
            "/api/v1/jobs/{id}/preview.png",
            get(images::preview_png),
        ),
        route(
            M::GET,
            "/api/v1/jobs/{id}/frames.tar",
            get(frames::frames_tar),
        ),
        route(
            M::GET,
            "/api/v1/jobs/{id}/preview.apng",
            get(frames::preview_apng),
        ),
        route(M::GET, "/api/v1/scenes/{hash}", get(tasks::scene)),
        route(M::POST, "/api/v1/workers", post(workers::register)),
        route(M::GET, "/api/v1/workers", get(workers::list)),
        route(
            M::DELETE,
            "/api/v1/workers/{id}",
            delete(workers::deregister),
        ),
        route(
            M::POST,
            "/api/v1/workers/{id}/heartbeat",
            post(workers::heartbeat),
        ),
        route(M::POST, "/api/v1/workers/{id}/lease", post(workers::lease)),
        route(
            M::POST,
            "/api/v1/tasks/{id}/slices",
            post(tasks::upload_slice),
        ),
        route(M::POST, "/api/v1/tasks/{id}/release", post(tasks::release)),
    ]
}

/// The store's answers in HTTP: its refusals with their status and code, its failures as 503
/// `database` (or 500 `internal`) with a message of ours; the database's own text is logged, and
/// never sent.
impl From<crate::store::Error> for ApiError {
    fn from(e: crate::store::Error) -> ApiError {
        use crate::store::Error as E;
        let message = e.to_string();
        match e {
            E::NotFound { .. } => ApiError::new(StatusCode::NOT_FOUND, "not_found", message),
            E::StaleLease { .. } => ApiError::conflict("stale_lease", message),
            E::NotLessee { .. } => ApiError::new(StatusCode::FORBIDDEN, "not_your_lease", message),
            E::Untrusted { .. } => {
                ApiError::new(StatusCode::FORBIDDEN, "untrusted_worker", message)
            }
            E::TooManyLeases { .. } => {
                ApiError::new(StatusCode::TOO_MANY_REQUESTS, "too_many_leases", message)
            }
            E::TooManyWorkers { .. } => ApiError {
                retry_after: Some(60),
                ..ApiError::new(StatusCode::SERVICE_UNAVAILABLE, "too_many_workers", message)
            },
            E::QuotaExceeded { .. } => {
                ApiError::new(StatusCode::TOO_MANY_REQUESTS, "quota_exceeded", message)
            }
            E::DeletedWhileStored(_) => ApiError::conflict("deleted_while_stored", message),
            E::TaskNotLeased { .. } => ApiError::conflict("task_not_leased", message),
            E::SliceOutOfOrder { .. } => ApiError::conflict("slice_out_of_order", message),
            E::InvalidState(_) => ApiError::conflict("invalid_state", message),
            E::SliceShape(_) => ApiError::unprocessable("slice_shape", message),
            E::SliceValues(_) => ApiError::unprocessable("slice_values", message),
            E::Interrupted => ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "write_interrupted",
                message,
            ),
            E::Internal(_) => {
                tracing::error!(error = %message, "store: broken invariant or unreadable data");
                ApiError::internal("the server could not read its stored data (see its log)")
            }
            E::Database(_) => {
                tracing::error!(error = %message, "database error");
                ApiError::new(
                    StatusCode::SERVICE_UNAVAILABLE,
                    "database",
                    "the store failed or cannot be reached; retry later",
                )
            }
        }
    }
}

/// A task id from the path.
/// A list's page as its query asked for it: pages counted from 1, `per_page` held to 1..=`max`.
pub(crate) struct Page {
    pub page: u32,
    pub per_page: u32,
}

impl Page {
    pub(crate) fn new(page: Option<u32>, per_page: Option<u32>, default: u32, max: u32) -> Page {
        Page {
            page: page.unwrap_or(1).max(1),
            per_page: per_page.unwrap_or(default).clamp(1, max),
        }
    }

    /// Rows before this page.
    pub(crate) fn offset(&self) -> u64 {
        (u64::from(self.page) - 1) * u64::from(self.per_page)
    }

    pub(crate) fn limit(&self) -> u64 {
        u64::from(self.per_page)
    }
}

pub(crate) fn parse_id(s: &str, what: &str) -> Result<i64, ApiError> {
    s.parse().map_err(|_| ApiError::not_found(what, s))
}

/// A body the framework could not read: over the route's limit (413 `too_large`, saying which
/// limit), or broken off.
pub(crate) fn body_error(e: BytesRejection, what: &str, limit: usize) -> ApiError {
    if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "too_large",
            format!("{what} body exceeds the limit of {limit} bytes"),
        )
    } else {
        ApiError::new(e.status(), "bad_request", e.body_text())
    }
}

/// Refuses a string of a request body that holds a NUL character, with 422 `code` naming the
/// field. SQLite stores such a string but PostgreSQL's `text` cannot (the query fails), so it is
/// refused here, before the store, and both stores answer alike.
pub(crate) fn no_nul(code: &'static str, fields: &[(&str, &str)]) -> Result<(), ApiError> {
    match fields.iter().find(|(_, v)| v.contains('\0')) {
        Some((field, _)) => Err(ApiError::unprocessable(
            code,
            format!("{field} contains a NUL character"),
        )),
        None => Ok(()),
    }
}

/// Refuses display names with control characters (NUL included): they would reach terminals and
/// log lines as they are (a newline in a name forged a log line).
pub(crate) fn no_control(code: &'static str, fields: &[(&str, &str)]) -> Result<(), ApiError> {
    match fields.iter().find(|(_, v)| v.chars().any(char::is_control)) {
        Some((field, _)) => Err(ApiError::unprocessable(
            code,
            format!("{field} contains a control character"),
        )),
        None => Ok(()),
    }
}

/// Middleware: a path with a NUL character (`%00`) names nothing (no id holds one, and
/// PostgreSQL could not even look it up), so it is answered 404 `not_found` before any handler.
pub(crate) async fn nul_paths(req: Request, next: Next) -> Response {
    if req.uri().path().contains("%00") {
        return ApiError::new(
            StatusCode::NOT_FOUND,
            "not_found",
            "nothing has a NUL character in its path",
        )
        .into_response();
    }
    next.run(req).await
}

/// The body limit of a route: the scene limit (plus room for the multipart framing and the
/// settings) for a job submission, the slice limit for a slice upload, and
/// [`MAX_JSON_BODY_BYTES`] for the rest (JSON, or no body at all).
/// What [`body_limit`] allows a route, in the words of a 413 answer (e.g. "a scene may be at most
/// 67108864 bytes (64 MiB)").
pub(crate) fn body_limit_reason(method: &Method, path: &str, limits: &Limits) -> String {
    let in_mib = |bytes: usize| format!("{bytes} bytes ({} MiB)", bytes >> 20);
    match (method.as_str(), path) {
        ("POST", "/api/v1/jobs") => {
            format!("a scene may be at most {}", in_mib(limits.max_scene_bytes))
        }
        ("POST", "/api/v1/tasks/{id}/slices") => {
            format!("a slice may be at most {}", in_mib(limits.max_slice_bytes))
        }
        _ => format!("a JSON body may be at most {MAX_JSON_BODY_BYTES} bytes"),
    }
}

pub fn body_limit(method: &Method, path: &str, limits: &Limits) -> usize {
    match (method.as_str(), path) {
        ("POST", "/api/v1/jobs") => limits.max_scene_bytes.saturating_add(1 << 20),
        ("POST", "/api/v1/tasks/{id}/slices") => limits.max_slice_bytes,
        _ => MAX_JSON_BODY_BYTES,
    }
}
