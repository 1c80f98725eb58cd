//! The current image of a job: EXR (float32, optionally with variance and sample-count channels)
//! and a tone-mapped PNG preview, both rebuilt only when a slice was merged since the last request.

use crate::auth::ReadAuth;
use crate::error::{ApiError, ApiResult};
use crate::AppState;
use axum::extract::{Path, Query, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use pathfarm_tracer::output::{encode_exr, encode_png, ExrChannels};
use serde::Deserialize;

#[derive(Deserialize)]
pub struct ExrQuery {
    /// Add the `variance` (of the mean) and `samples` channels.
    #[serde(default)]
    extra: bool,
}

#[derive(Deserialize)]
pub struct PngQuery {
    #[serde(default)]
    exposure: f32,
}

fn image_response(bytes: axum::body::Bytes, content_type: &'static str, version: i64) -> Response {
    (
        [
            (header::CONTENT_TYPE, content_type.to_string()),
            (header::CACHE_CONTROL, "no-cache".to_string()),
            (header::ETAG, format!("\"v{version}\"")),
        ],
        bytes,
    )
        .into_response()
}

pub async fn image_exr(
    _: ReadAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    query: Result<Query<ExrQuery>, axum::extract::rejection::QueryRejection>,
) -> ApiResult<Response> {
    let Query(q) = query.map_err(|e| ApiError::bad_request("bad_query", e.body_text()))?;
    let job = state.store.job(&id).await?;
    let img = state
        .images
        .get(&state.store, &id, job.settings.width, job.settings.height)
        .await?;
    let key = if q.extra { "exr+extra" } else { "exr" };
    let bytes = img.encoded(key, |acc| {
        encode_exr(
            acc,
            ExrChannels {
                variance: q.extra,
                samples: q.extra,
            },
        )
        .map_err(|e| ApiError::internal(format!("EXR encoding: {e}")))
    })?;
    Ok(image_response(bytes, "image/x-exr", img.version))
}

pub async fn preview_png(
    _: ReadAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    query: Result<Query<PngQuery>, axum::extract::rejection::QueryRejection>,
) -> ApiResult<Response> {
    let Query(q) = query.map_err(|e| ApiError::bad_request("bad_query", e.body_text()))?;
    if !q.exposure.is_finite() || q.exposure.abs() > 64.0 {
        return Err(ApiError::bad_request(
            "bad_query",
            "exposure must be a number of stops in [-64, 64]",
        ));
    }
    let job = state.store.job(&id).await?;
    let img = state
        .images
        .get(&state.store, &id, job.settings.width, job.settings.height)
        .await?;
    let key = format!("png@{}", q.exposure);
    let bytes = img.encoded(&key, |acc| {
        encode_png(acc, q.exposure).map_err(|e| ApiError::internal(format!("PNG encoding: {e}")))
    })?;
    Ok(image_response(bytes, "image/png", img.version))
}
