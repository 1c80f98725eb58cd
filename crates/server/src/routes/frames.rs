//! A frame job's frames in one download: every frame with a merged sample as a tar of EXRs
//! (`frames.tar`, one `frame_NNNN.exr` each, as `image.exr?frame=N` serves it), and the frames
//! complete so far as one animated PNG (`preview.apng`, each frame as `preview.png?frame=N`
//! shows it).
//!
//! Both stream: a frame's image is built (or taken from the image cache), encoded, sent and let
//! go before the next one is built, through the image cache and within its budget like any image
//! request, so a download of 240 frames holds about one frame at a time however large the job.
//! The first frame is made before the response starts, so that what commonly fails (no room in
//! the budget: 503 with `Retry-After`) is an HTTP error; a failure after that ends the stream
//! early, which the client sees as a cut transfer (a tar without its end blocks, an APNG
//! without `IEND`), never as a complete file.

use crate::auth::ReadAuth;
use crate::error::{ApiError, ApiResult};
use crate::image_cache::{blocking, image_key};
use crate::job_image::{cost, JobImage};
use crate::store::JobRow;
use crate::AppState;
use axum::body::{Body, Bytes};
use axum::extract::{Path, Query, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use pathfarm_tracer::output::ExrChannels;
use serde::Deserialize;
use std::io::Write;
use std::sync::{Arc, Mutex, PoisonError};
use tokio::sync::mpsc;

/// Chunks in flight between the producing task and the response body: the producer waits for a
/// slow reader rather than buffering frames.
const CHUNKS_IN_FLIGHT: usize = 2;

/// The frames of `job` (a frame job: 404 for a still one) with their slots, in the job's order,
/// that `keep` selects from their progress.
async fn chosen_frames(
    state: &AppState,
    job: &JobRow,
    keep: impl Fn(&pathfarm_wire::api::FrameProgress) -> bool,
) -> ApiResult<Vec<(u32, i64)>> {
    let frames = job
        .settings
        .frame_list()
        .map_err(|e| ApiError::internal(format!("stored settings: {e}")))?;
    let Some(frames) = frames else {
        return Err(ApiError::new(
            StatusCode::NOT_FOUND,
            "not_found",
            format!(
                "job {} is a still image, not a frame job: it has no frames",
                job.id
            ),
        ));
    };
    let progress = state
        .store
        .frame_progress(
            &job.id,
            u64::from(job.settings.spp),
            job.settings.noise_target,
        )
        .await?;
    Ok(progress
        .iter()
        .filter(|p| keep(p))
        .filter_map(|p| {
            let slot = frames.iter().position(|&f| f == p.frame)?;
            Some((slot as u32, p.frame))
        })
        .collect())
}

/// The frame in `slot` of `job`, with the key it is kept under.
async fn frame_image(
    state: &AppState,
    job: &JobRow,
    slot: u32,
) -> ApiResult<(Arc<JobImage>, String)> {
    let img = state
        .images
        .get_frame(&state.store, job, Some(slot))
        .await?;
    Ok((img, image_key(&job.id, Some(slot))))
}

/// The body of a stream of chunks that `produce` sends (an `Err` cuts the transfer), run as a
/// task of its own that stops when the client goes away.
fn streamed<F>(produce: impl FnOnce(mpsc::Sender<std::io::Result<Bytes>>) -> F) -> Body
where
    F: std::future::Future<Output = ()> + Send + 'static,
{
    let (tx, rx) = mpsc::channel(CHUNKS_IN_FLIGHT);
    tokio::spawn(produce(tx));
    Body::from_stream(futures_util::stream::unfold(rx, |mut rx| async move {
        rx.recv().await.map(|chunk| (chunk, rx))
    }))
}

/// Sends `result`'s bytes, or the error that cuts the transfer; `false` when the stream is over
/// (the error sent, or the client gone).
async fn send(tx: &mpsc::Sender<std::io::Result<Bytes>>, result: ApiResult<Bytes>) -> bool {
    match result {
        Ok(bytes) => tx.send(Ok(bytes)).await.is_ok(),
        Err(e) => {
            tracing::warn!(error = %e.message, "a frame download was cut short");
            let _ = tx.send(Err(std::io::Error::other(e.message))).await;
            false
        }
    }
}

/// A streamed download's headers: its media type (`native`, or `application/octet-stream` for a
/// client that asks for that, see [`super::media`]) and its file name.
fn download_headers(
    request: &HeaderMap,
    native: &'static str,
    file_name: String,
) -> [(header::HeaderName, String); 4] {
    [
        (
            header::CONTENT_TYPE,
            super::media::binary_type(request, native).to_string(),
        ),
        (header::VARY, "accept".to_string()),
        (header::CACHE_CONTROL, "no-cache".to_string()),
        (
            header::CONTENT_DISPOSITION,
            format!("attachment; filename=\"{file_name}\""),
        ),
    ]
}

// ---------------------------------------------------------------------------------------------
// frames.tar

/// The EXR of frame `slot` (colour only: `image.exr?frame=N` without `extra`).
async fn frame_exr(state: &AppState, job: &JobRow, slot: u32) -> ApiResult<Bytes> {
    let (img, key) = frame_image(state, job, slot).await?;
    let need = cost::exr(img.width, img.height, 3);
    let channels = ExrChannels {
        variance: false,
        samples: false,
    };
    state
        .images
        .encoded(&key, &img, "exr", need, move |img| {
            img.exr(channels)
                .map_err(|e| ApiError::internal(format!("EXR encoding: {e}")))
        })
        .await
}

/// The name of `frame`'s file in the tar: its number padded with zeros to `digits`.
fn tar_name(frame: i64, digits: usize) -> String {
    format!("frame_{frame:0digits$}.exr")
}

/// The ustar header of a regular file `name` of `size` bytes, and the zeros that pad its data to
/// the tar's 512-byte blocks.
fn tar_entry_header(name: &str, size: u64, mtime: u64) -> std::io::Result<(Bytes, Bytes)> {
    let mut h = tar::Header::new_ustar();
    h.set_path(name)?;
    h.set_size(size);
    h.set_mode(0o644);
    h.set_mtime(mtime);
    h.set_entry_type(tar::EntryType::Regular);
    h.set_cksum();
    let pad = (512 - size % 512) % 512;
    Ok((
        Bytes::copy_from_slice(h.as_bytes()),
        Bytes::from(vec![0u8; pad as usize]),
    ))
}

/// `GET /api/v1/jobs/{id}/frames.tar`: every frame with at least one merged sample, in the job's
/// frame order, as `frame_NNNN.exr` (the frame number padded to four digits, or as many as the
/// job's largest frame needs). 404 for a still job, 409 before any frame has a sample.
pub async fn frames_tar(
    _: ReadAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    request: HeaderMap,
) -> ApiResult<Response> {
    let job = state.store.job(&id).await?;
    let frames = chosen_frames(&state, &job, |p| p.samples_done > 0).await?;
    let Some(&(first_slot, _)) = frames.first() else {
        return Err(ApiError::conflict(
            "no_frames",
            format!("no frame of job {id} has a merged sample yet"),
        ));
    };
    let largest = frames.iter().map(|&(_, f)| f).max().unwrap_or(0);
    let digits = largest.to_string().len().max(4);
    let mtime = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let first = frame_exr(&state, &job, first_slot).await?;
    let body = streamed(move |tx| async move {
        let mut pending = Some(first);
        for &(slot, frame) in &frames {
            let exr = match pending.take() {
                Some(b) => Ok(b),
                None => frame_exr(&state, &job, slot).await,
            };
            let entry = exr.and_then(|exr| {
                let (head, pad) =
                    tar_entry_header(&tar_name(frame, digits), exr.len() as u64, mtime)
                        .map_err(|e| ApiError::internal(format!("tar header: {e}")))?;
                Ok([head, exr, pad])
            });
            match entry {
                Ok(parts) => {
                    for part in parts {
                        if !send(&tx, Ok(part)).await {
                            return;
                        }
                    }
                }
                Err(e) => {
                    send(&tx, Err(e)).await;
                    return;
                }
            }
        }
        // The end of the archive: two blocks of zeros.
        send(&tx, Ok(Bytes::from_static(&[0; 1024]))).await;
    });
    Ok((
        download_headers(&request, "application/x-tar", format!("{id}-frames.tar")),
        body,
    )
        .into_response())
}

// ---------------------------------------------------------------------------------------------
// preview.apng

#[derive(Deserialize)]
pub struct ApngQuery {
    #[serde(default)]
    exposure: f32,
    /// Frames per second of the playback (default: the job's `fps`).
    #[serde(default)]
    fps: Option<f64>,
}

/// The tone-mapped 8-bit RGB of frame `slot`, as its `preview.png?frame=N` shows it.
async fn frame_rgb(state: &AppState, job: &JobRow, slot: u32, exposure: f32) -> ApiResult<Bytes> {
    let (img, key) = frame_image(state, job, slot).await?;
    let need = img.pixels().saturating_mul(3);
    state
        .images
        .encoded(&key, &img, &format!("rgb8@{exposure}"), need, move |img| {
            Ok(img.rgb8(exposure))
        })
        .await
}

/// Where the encoder writes: the bytes written since they were last taken.
#[derive(Clone, Default)]
struct Taken(Arc<Mutex<Vec<u8>>>);

impl Taken {
    fn take(&self) -> Bytes {
        Bytes::from(std::mem::take(
            &mut *self.0.lock().unwrap_or_else(PoisonError::into_inner),
        ))
    }
}

impl Write for Taken {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

type ApngWriter = png::Writer<Taken>;

fn png_error(e: png::EncodingError) -> ApiError {
    ApiError::internal(format!("APNG encoding: {e}"))
}

/// The frame delay of `fps` as the APNG's fraction of a second: milliseconds, at least one.
fn frame_delay(fps: f64) -> (u16, u16) {
    let ms = (1000.0 / fps).round().clamp(1.0, f64::from(u16::MAX));
    (ms as u16, 1000)
}

/// `GET /api/v1/jobs/{id}/preview.apng`: the frames complete so far, in the job's frame order, as
/// one animated PNG that loops, each frame tone-mapped as `preview.png?frame=N&exposure=E` is.
/// 404 for a still job, 409 before any frame is complete.
pub async fn preview_apng(
    _: ReadAuth,
    State(state): State<AppState>,
    Path(id): Path<String>,
    request: HeaderMap,
    query: Result<Query<ApngQuery>, axum::extract::rejection::QueryRejection>,
) -> ApiResult<Response> {
    let Query(q) = query.map_err(|e| ApiError::bad_request("bad_query", e.body_text()))?;
    super::images::check_exposure(q.exposure)?;
    if q.fps
        .is_some_and(|f| !(f.is_finite() && f > 0.0 && f <= 1000.0))
    {
        return Err(ApiError::bad_request(
            "bad_query",
            "fps must be a number of frames per second in (0, 1000]",
        ));
    }
    let job = state.store.job(&id).await?;
    let frames = chosen_frames(&state, &job, |p| p.complete).await?;
    let Some(&(first_slot, _)) = frames.first() else {
        return Err(ApiError::conflict(
            "no_frames",
            format!("no frame of job {id} is complete yet"),
        ));
    };
    let fps = q.fps.unwrap_or_else(|| job.settings.frames_per_second());
    let (width, height) = (job.settings.width, job.settings.height);
    let count = u32::try_from(frames.len()).unwrap_or(u32::MAX);
    let exposure = q.exposure;
    let out = Taken::default();
    let sink = out.clone();
    let writer: ApngWriter = blocking("APNG header", move || {
        let mut enc = png::Encoder::new(sink, width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::Fast);
        enc.set_animated(count, 0).map_err(png_error)?;
        let (num, den) = frame_delay(fps);
        enc.set_frame_delay(num, den).map_err(png_error)?;
        enc.write_header().map_err(png_error)
    })
    .await?;
    let first = frame_rgb(&state, &job, first_slot, exposure).await?;
    let body = streamed(move |tx| async move {
        let mut writer = Some(writer);
        let mut pending = Some(first);
        for &(slot, _) in &frames {
            let rgb = match pending.take() {
                Some(b) => Ok(b),
                None => frame_rgb(&state, &job, slot, exposure).await,
            };
            let Some(w) = writer.take() else { return };
            let written = match rgb {
                Ok(rgb) => {
                    blocking("APNG frame", move || {
                        let mut w = w;
                        w.write_image_data(&rgb).map_err(png_error)?;
                        Ok(w)
                    })
                    .await
                }
                Err(e) => Err(e),
            };
            match written {
                Ok(w) => writer = Some(w),
                Err(e) => {
                    send(&tx, Err(e)).await;
                    return;
                }
            }
            if !send(&tx, Ok(out.take())).await {
                return;
            }
        }
        if let Some(w) = writer {
            let finished = blocking("APNG end", move || w.finish().map_err(png_error)).await;
            if send(&tx, finished.map(|()| out.take())).await {
                tracing::debug!(frames = count, "animated preview sent");
            }
        }
    });
    Ok((
        download_headers(&request, "image/apng", format!("{id}-preview.apng")),
        body,
    )
        .into_response())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tar_entries_are_whole_blocks() {
        let (head, pad) = tar_entry_header("frame_0001.exr", 700, 0).unwrap();
        assert_eq!(head.len(), 512);
        assert_eq!((700 + pad.len()) % 512, 0);
        let (_, pad) = tar_entry_header("frame_0002.exr", 1024, 0).unwrap();
        assert!(pad.is_empty());
        assert_eq!(tar_name(7, 4), "frame_0007.exr");
        assert_eq!(tar_name(123_456, 6), "frame_123456.exr");
    }

    #[test]
    fn frame_delays_are_milliseconds() {
        assert_eq!(frame_delay(24.0), (42, 1000));
        assert_eq!(frame_delay(1000.0), (1, 1000));
        assert_eq!(frame_delay(0.01), (u16::MAX, 1000));
    }
}
