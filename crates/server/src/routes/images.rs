//! The current image of a job: EXR (float32, optionally with variance and sample-count channels)
//! and a tone-mapped PNG preview, both rebuilt only when a slice was merged since the last request
//! (and the image cache still holds them), once for all the requests that ask meanwhile, on
//! blocking threads and within the image budget (see [`crate::image_cache`]).

use crate::auth::ReadAuth;
use crate::error::{ApiError, ApiResult};
use crate::heatmap;
use crate::image_cache::image_key;
use crate::job_image::{cost, JobImage};
use crate::store::JobRow;
use crate::AppState;
use axum::extract::{Path, Query, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use pathfarm_tracer::output::ExrChannels;
use pathfarm_wire::api::{PreviewView, SCALE_MAX_HEADER, SCALE_MIN_HEADER};
use serde::Deserialize;
use std::sync::Arc;

#[derive(Deserialize)]
pub struct ExrQuery {
    /// Add the `variance` (of the mean) and `samples` channels.
    #[serde(default)]
    extra: bool,
    /// A frame job's frame (default: its first).
    #[serde(default)]
    frame: Option<i64>,
}

#[derive(Deserialize)]
pub struct PngQuery {
    #[serde(default)]
    exposure: f32,
    #[serde(default)]
    view: PreviewView,
    /// A frame job's frame (default: its first).
    #[serde(default)]
    frame: Option<i64>,
}

/// The image a request names: a still job's, or the frame `frame` of a frame job (its first when
/// `frame` is absent), with the key it is kept under and its frame's slot.
async fn job_image(
    state: &AppState,
    id: &str,
    frame: Option<i64>,
) -> ApiResult<(Arc<JobImage>, String, Option<u32>)> {
    let job = state.store.job(id).await?;
    let slot = frame_slot(&job, frame)?;
    let img = state.images.get_frame(&state.store, &job, slot).await?;
    Ok((img, image_key(id, slot), slot))
}

/// The slot in `job`'s frame list of the frame a request names (`frame`; a frame job's first
/// when absent; `None` for a still job's image): 404 for a frame the job does not render, and
/// for any frame of a still job.
pub(crate) fn frame_slot(job: &JobRow, frame: Option<i64>) -> ApiResult<Option<u32>> {
    let id = &job.id;
    let frames = job
        .settings
        .frame_list()
        .map_err(|e| ApiError::internal(format!("stored settings: {e}")))?;
    match (frames, frame) {
        (None, None) => Ok(None),
        // A still job has no frames: like a frame that a frame job does not render, the image
        // asked for does not exist.
        (None, Some(f)) => Err(ApiError::new(
            StatusCode::NOT_FOUND,
            "not_found",
            format!("job {id} is a still image: it has no frame {f}"),
        )),
        (Some(_), None) => Ok(Some(0)),
        (Some(frames), Some(f)) => match frames.iter().position(|&x| x == f) {
            Some(slot) => Ok(Some(slot as u32)),
            None => Err(ApiError::new(
                StatusCode::NOT_FOUND,
                "not_found",
                format!("frame {f} is not one of job {id}'s frames"),
            )),
        },
    }
}

/// A preview's exposure: a finite number of stops in [-64, 64] (400 otherwise).
pub(super) fn check_exposure(exposure: f32) -> ApiResult<()> {
    if exposure.is_finite() && exposure.abs() <= 64.0 {
        Ok(())
    } else {
        Err(ApiError::bad_request(
            "bad_query",
            "exposure must be a number of stops in [-64, 64]",
        ))
    }
}

/// One representation of a job's image: what the bytes are (the format and view, with the
/// exposure, `exr+extra`, `png@1.5`, `png:noise`, …), of which frame, in which media type.
struct Representation<'a> {
    what: &'a str,
    frame: Option<u32>,
    content_type: &'static str,
}

impl Representation<'_> {
    /// The strong validator of this representation at image `version`:
    /// `"v<version>[.f<slot>].<what>[.bin]"`. Every format, view, exposure, frame and media type
    /// has its own, so a cache that keys by URL alone (or one that follows `Vary: Accept`) never
    /// takes one representation's bytes for another's.
    fn etag(&self, version: i64) -> String {
        let frame = self.frame.map(|f| format!(".f{f}")).unwrap_or_default();
        let bin = if self.content_type == super::media::OCTET_STREAM {
            ".bin"
        } else {
            ""
        };
        format!("\"v{version}{frame}.{}{bin}\"", self.what)
    }

    /// 304 Not Modified when the client already holds this version (`If-None-Match`): pollers
    /// of an image that did not change get no body at all.
    fn not_modified(&self, request: &HeaderMap, version: i64) -> Option<Response> {
        let tag = self.etag(version);
        let held = request.get(header::IF_NONE_MATCH)?.to_str().ok()?;
        held.split(',')
            .map(|t| t.trim().trim_start_matches("W/"))
            .any(|t| t == tag || t == "*")
            .then(|| {
                (
                    StatusCode::NOT_MODIFIED,
                    [
                        (header::CACHE_CONTROL, "no-cache".to_string()),
                        (header::VARY, "accept".to_string()),
                        (header::ETAG, tag),
                    ],
                )
                    .into_response()
            })
    }

    fn response(&self, bytes: axum::body::Bytes, version: i64) -> Response {
        (
            [
                (header::CONTENT_TYPE, self.content_type.to_string()),
                (header::CACHE_CONTROL, "no-cache".to_string()),
                (header::VARY, "accept".to_string()),
                (header::ETAG, self.etag(version)),
            ],
            bytes,
        )
            .into_response()
    }
}

pub async fn image_exr(
    _: ReadAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    request: HeaderMap,
    query: Result<Query<ExrQuery>, axum::extract::rejection::QueryRejection>,
) -> ApiResult<Response> {
    let Query(q) = query.map_err(|e| ApiError::bad_request("bad_query", e.body_text()))?;
    let (img, image, slot) = job_image(&state, &id, q.frame).await?;
    let key = if q.extra { "exr+extra" } else { "exr" };
    let repr = Representation {
        what: key,
        frame: slot,
        content_type: super::media::binary_type(&request, "image/x-exr"),
    };
    if let Some(r) = repr.not_modified(&request, img.version) {
        return Ok(r);
    }
    let channels = ExrChannels {
        variance: q.extra,
        samples: q.extra,
    };
    let need = cost::exr(img.width, img.height, if q.extra { 5 } else { 3 });
    let bytes = state
        .images
        .encoded(&image, &img, key, need, move |img| {
            img.exr(channels)
                .map_err(|e| ApiError::internal(format!("EXR encoding: {e}")))
        })
        .await?;
    Ok(repr.response(bytes, img.version))
}

pub async fn preview_png(
    _: ReadAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    request: HeaderMap,
    query: Result<Query<PngQuery>, axum::extract::rejection::QueryRejection>,
) -> ApiResult<Response> {
    let Query(q) = query.map_err(|e| ApiError::bad_request("bad_query", e.body_text()))?;
    check_exposure(q.exposure)?;
    let (img, image, slot) = job_image(&state, &id, q.frame).await?;
    let (key, scale) = match q.view {
        PreviewView::Image => (format!("png@{}", q.exposure), None),
        PreviewView::Samples => (
            "png:samples".to_string(),
            Some((0.0, img.max_samples as f64)),
        ),
        PreviewView::Noise => ("png:noise".to_string(), Some(heatmap::NOISE_SCALE)),
    };
    let repr = Representation {
        what: &key,
        frame: slot,
        content_type: super::media::binary_type(&request, "image/png"),
    };
    if let Some(r) = repr.not_modified(&request, img.version) {
        return Ok(r);
    }
    let (view, exposure) = (q.view, q.exposure);
    let need = cost::png(img.width, img.height);
    let bytes = state
        .images
        .encoded(&image, &img, &key, need, move |img| {
            match view {
                PreviewView::Image => img.png(exposure),
                PreviewView::Samples => img.samples_png(),
                PreviewView::Noise => img.noise_png(),
            }
            .map_err(|e| ApiError::internal(format!("PNG encoding: {e}")))
        })
        .await?;
    let mut resp = repr.response(bytes, img.version);
    if let Some((lo, hi)) = scale {
        let headers = resp.headers_mut();
        for (name, v) in [(SCALE_MIN_HEADER, lo), (SCALE_MAX_HEADER, hi)] {
            if let Ok(v) = HeaderValue::from_str(&v.to_string()) {
                headers.insert(name, v);
            }
        }
    }
    Ok(resp)
}
