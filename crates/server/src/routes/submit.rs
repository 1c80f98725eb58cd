//! Submitting a job: the multipart body, its settings checked against the limits, the scene and
//! environment image loaded as a worker will load them, the plan stored.

use crate::auth::ClientAuth;
use crate::error::{ApiError, ApiResult};
use crate::scheduler;
use crate::store::NewJob;
use crate::AppState;
use axum::body::Bytes;
use axum::extract::multipart::{Multipart, MultipartError, MultipartRejection};
use axum::extract::State;
use axum::http::StatusCode;
use axum::Json;
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_wire::api::{JobCreated, JobSettings};
use sha2::{Digest, Sha256};

/// Both limits in one unit people read: `67108864 bytes (64 MiB)`.
fn bytes_and_mib(bytes: usize) -> String {
    format!("{bytes} bytes ({} MiB)", bytes >> 20)
}

fn multipart_error(e: MultipartError, state: &AppState) -> ApiError {
    // The body limit shows as a multipart parse error whose status says what it is.
    if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "too_large",
            format!(
                "request body too large ({}): a scene may be at most {}",
                e.body_text(),
                bytes_and_mib(state.config.limits.max_scene_bytes)
            ),
        )
    } else {
        ApiError::bad_request(
            "bad_multipart",
            format!("invalid multipart body: {}", e.body_text()),
        )
    }
}

/// Most bytes of scene-loader warnings kept with a job (each warning is also cut to
/// [`MAX_WARNING_BYTES`]); the loader reports at most 100.
pub const MAX_WARNINGS_BYTES: usize = 16 << 10;
/// Most bytes of one warning kept.
pub const MAX_WARNING_BYTES: usize = 1024;

/// A job's default name from the scene part's file name: its control characters (NUL included,
/// possible with an RFC 5987 `filename*`) dropped and cut at 256 characters, the limits of a name
/// given in the settings; None when nothing is left.
fn name_from_file(file_name: &str) -> Option<String> {
    let name: String = file_name
        .chars()
        .filter(|c| !c.is_control())
        .take(256)
        .collect();
    (!name.trim().is_empty()).then_some(name)
}

/// The loader's warnings as a job keeps them: control characters (NUL included, which no store
/// takes) removed, each cut to [`MAX_WARNING_BYTES`] and all together to [`MAX_WARNINGS_BYTES`]
/// (a last line then says how many were left out).
pub(crate) fn clean_warnings(warnings: &[String]) -> Vec<String> {
    let mut out = Vec::new();
    let mut total = 0;
    for (i, w) in warnings.iter().enumerate() {
        let mut w: String = w.chars().filter(|c| !c.is_control()).collect();
        if w.len() > MAX_WARNING_BYTES {
            let mut end = MAX_WARNING_BYTES;
            while !w.is_char_boundary(end) {
                end -= 1;
            }
            w.truncate(end);
            w.push('…');
        }
        if total + w.len() > MAX_WARNINGS_BYTES {
            out.push(format!("… and {} more warnings", warnings.len() - i));
            break;
        }
        total += w.len();
        out.push(w);
    }
    out
}

/// Why a submission's scene or environment cannot be rendered (found on a blocking thread).
enum CheckError {
    Scene(String),
    Environment(String),
}

/// `POST /api/v1/jobs`: multipart with a `scene` part (.glb or .gltf with embedded data), a
/// `settings` part (JSON [`JobSettings`]) and optionally an `environment` part (an equirectangular
/// .exr or .hdr image, which becomes `settings.environment.image`). The scene and the environment
/// are loaded here, as a worker will load them, so a broken one is refused with a 422 before any
/// job exists.
pub async fn submit(
    auth: ClientAuth,
    State(state): State<AppState>,
    headers: axum::http::HeaderMap,
    multipart: Result<Multipart, MultipartRejection>,
) -> ApiResult<(StatusCode, Json<JobCreated>)> {
    // Room for the body in the server's budget before a byte of it is read: its declared length,
    // else the most a submission may send.
    let most = super::body_limit(
        &axum::http::Method::POST,
        "/api/v1/jobs",
        &state.config.limits,
    ) as u64;
    let need = crate::connections::content_length(&headers).map_or(most, |n| n.min(most));
    let _room = state.bodies.reserve(need, "a submission").await?;
    let mut multipart = multipart.map_err(|e| {
        ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "unsupported_media_type",
            format!("expected a multipart/form-data body with `scene` and `settings` parts: {e}"),
        )
    })?;
    let mut scene: Option<Bytes> = None;
    let mut settings: Option<JobSettings> = None;
    let mut environment: Option<Bytes> = None;
    let mut file_name: Option<String> = None;
    while let Some(field) = multipart
        .next_field()
        .await
        .map_err(|e| multipart_error(e, &state))?
    {
        match field.name() {
            Some("scene") => {
                file_name = field.file_name().map(str::to_string);
                scene = Some(
                    field
                        .bytes()
                        .await
                        .map_err(|e| multipart_error(e, &state))?,
                );
            }
            Some("settings") => {
                let bytes = field
                    .bytes()
                    .await
                    .map_err(|e| multipart_error(e, &state))?;
                if !super::starts_an_object(&bytes) {
                    return Err(ApiError::unprocessable(
                        "invalid_settings",
                        "settings: expected a JSON object",
                    ));
                }
                settings = Some(serde_json::from_slice(&bytes).map_err(|e| {
                    ApiError::unprocessable("invalid_settings", format!("settings: {e}"))
                })?);
            }
            Some("environment") => {
                environment = Some(
                    field
                        .bytes()
                        .await
                        .map_err(|e| multipart_error(e, &state))?,
                );
            }
            Some(other) => {
                return Err(ApiError::bad_request(
                    "bad_multipart",
                    format!(
                        "unexpected part {other:?} (expected `scene`, `settings` and optionally \
                         `environment`)"
                    ),
                ))
            }
            None => return Err(ApiError::bad_request("bad_multipart", "a part has no name")),
        }
    }
    let scene =
        scene.ok_or_else(|| ApiError::bad_request("bad_multipart", "missing the `scene` part"))?;
    let mut settings = settings
        .ok_or_else(|| ApiError::bad_request("bad_multipart", "missing the `settings` part"))?;
    validate(&state, &settings, scene.len())?;
    let uploaded = environment_part(&state, &mut settings, environment)?;
    // The quotas, before the scene is loaded (the store checks them again as it stores the job).
    // A stored environment image named by hash is counted once it is read, by the store.
    let job_bytes = accumulation_bytes(&settings).saturating_add(scene.len() as u64);
    let stored_bytes =
        job_bytes.saturating_add(uploaded.as_ref().map_or(0, |(_, b)| b.len() as u64));
    state
        .store
        .usage(&auth.owner)
        .await?
        .admit(stored_bytes, &state.config.quotas)?;

    // Load the scene as a worker will, short of building it (no external resources: a URI in a
    // submitted scene never reads the server's files or the network), then the environment, as
    // the worker builds it; one after the other, so that each check holds only one of them in
    // memory.
    let camera = settings.camera.clone();
    let max_triangles = state.config.limits.max_scene_triangles;
    let scene_for_load = scene.clone();
    let environment_settings = settings.environment.clone();
    let _permit = state
        .scene_checks
        .acquire()
        .await
        .map_err(|e| ApiError::internal(format!("scene validation: {e}")))?;
    // A stored image the settings name is read under the permit too: like an upload, at most
    // `scene_checks` of them are in memory at once.
    let environment = environment_image(&state, &settings, uploaded).await?;
    let image_for_load = environment.as_ref().map(|(_, b)| b.clone());
    // A frame job's scene is loaded as its workers load it, and built at its first frame.
    let first_frame = settings
        .frame_list()
        .ok()
        .flatten()
        .and_then(|f| f.first().copied())
        .map(|f| gltf::frame_time(f, settings.frames_per_second()));
    let checked = tokio::task::spawn_blocking(move || {
        let options = LoadOptions {
            camera,
            max_triangles,
        };
        // A still is checked without its build (`gltf::check`: the BVH is the workers' to build);
        // a frame job's first frame is built, as the animation makes it.
        let checked = match first_frame {
            None => gltf::check(&scene_for_load, &NoExternalResources, &options),
            Some(time) => gltf::SceneSource::load(&scene_for_load, &NoExternalResources, &options)
                .and_then(|source| source.into_scene_at(time))
                .map(|s| s.info.warnings),
        };
        let warnings = checked.map_err(|e| CheckError::Scene(e.to_string()))?;
        if let Some(env) = environment_settings {
            env.build(image_for_load.as_deref())
                .map_err(|e| CheckError::Environment(e.to_string()))?;
        }
        Ok(warnings)
    })
    .await
    .map_err(|e| ApiError::internal(format!("scene validation: {e}")))?;
    let warnings = match checked {
        Ok(w) => clean_warnings(&w),
        Err(CheckError::Scene(e)) => {
            return Err(ApiError::unprocessable(
                "invalid_scene",
                format!("the scene cannot be loaded: {e}"),
            ))
        }
        Err(CheckError::Environment(e)) => {
            return Err(ApiError::unprocessable(
                "invalid_environment",
                format!("the environment cannot be loaded: {e}"),
            ))
        }
    };
    let hash = hex::encode(Sha256::digest(&scene));
    // `validate` checked the plan's size against the limits; a large plan still takes a while to
    // build, so it is built off the async workers.
    let size = (
        settings.width,
        settings.height,
        settings.tile_size,
        settings.spp,
    );
    let sizes = state.config.task_sizes();
    // `validate` parsed them.
    let frames = settings.frame_list().ok().flatten();
    let frame_count = frames.as_ref().map_or(1, |f| f.len() as u64);
    let order = settings.frame_order.unwrap_or_default();
    let (tiles, tasks) = tokio::task::spawn_blocking(move || {
        scheduler::plan_frames(size, sizes, frames.as_deref(), order)
    })
    .await
    .map_err(|e| ApiError::internal(format!("job planning: {e}")))?;
    let id = uuid::Uuid::new_v4().simple().to_string();
    let name = settings
        .name
        .clone()
        .or(file_name.and_then(|n| name_from_file(&n)))
        .unwrap_or_else(|| format!("job {}", &id[..8]));
    let samples_planned =
        settings.width as u64 * settings.height as u64 * settings.spp as u64 * frame_count;
    let task_count = tasks.len() as u64;
    let stored_bytes =
        job_bytes.saturating_add(environment.as_ref().map_or(0, |(_, b)| b.len() as u64));
    state
        .store
        .create_job(
            NewJob {
                id: id.clone(),
                name,
                settings,
                scene_hash: hash.clone(),
                scene_bytes: scene.to_vec(),
                environment: environment.map(|(h, b)| (h, b.to_vec())),
                warnings,
                tiles,
                tasks,
                samples_planned,
                owner: auth.owner,
                stored_bytes,
            },
            &state.config.quotas,
            state.config.submission_batch_rows,
        )
        .await?;
    tracing::info!(job = %id, scene = %hash, tasks = task_count, "job submitted");
    state.work.notify();
    Ok((
        StatusCode::CREATED,
        Json(JobCreated {
            id,
            scene_hash: hash,
            tasks: task_count,
            samples_planned,
        }),
    ))
}

/// The uploaded `environment` part, checked (size) and named in the settings: its hash becomes
/// `settings.environment.image` (the settings may give `strength` and `rotation_degrees`, not
/// `radiance`, nor another `image`). Then the settings' environment is checked: exactly one of
/// radiance and image, finite values.
fn environment_part(
    state: &AppState,
    settings: &mut JobSettings,
    part: Option<Bytes>,
) -> ApiResult<Option<(String, Bytes)>> {
    let bad = |m: String| ApiError::unprocessable("invalid_settings", m);
    let uploaded = match part {
        Some(bytes) => {
            let limit = state.config.limits.max_scene_bytes;
            if bytes.is_empty() {
                return Err(ApiError::unprocessable(
                    "invalid_environment",
                    "the environment part is empty",
                ));
            }
            if bytes.len() > limit {
                return Err(ApiError::new(
                    StatusCode::PAYLOAD_TOO_LARGE,
                    "too_large",
                    format!(
                        "environment image of {} bytes exceeds the limit of {}",
                        bytes.len(),
                        bytes_and_mib(limit)
                    ),
                ));
            }
            let hash = hex::encode(Sha256::digest(&bytes));
            let env = settings.environment.get_or_insert_with(Default::default);
            if env.radiance.is_some() {
                return Err(bad(
                    "environment: an `environment` part was uploaded and `radiance` given; \
                     give one"
                        .into(),
                ));
            }
            if env.image.as_ref().is_some_and(|named| *named != hash) {
                return Err(bad(format!(
                    "environment: `image` names another image than the uploaded part's \
                     (SHA-256 {hash})"
                )));
            }
            env.image = Some(hash.clone());
            Some((hash, bytes))
        }
        None => None,
    };
    if let Some(env) = &settings.environment {
        env.validate().map_err(|e| bad(e.to_string()))?;
    }
    Ok(uploaded)
}

/// The environment image a job uses, with its hash: the uploaded part, or the stored image that
/// `settings.environment.image` names (422 `invalid_environment` when the server has none).
async fn environment_image(
    state: &AppState,
    settings: &JobSettings,
    uploaded: Option<(String, Bytes)>,
) -> ApiResult<Option<(String, Bytes)>> {
    let named = settings.environment.as_ref().and_then(|e| e.image.as_ref());
    match (uploaded, named) {
        (Some(u), _) => Ok(Some(u)),
        (None, Some(hash)) => match state.store.scene(hash).await {
            Ok(bytes) => Ok(Some((hash.clone(), Bytes::from(bytes)))),
            Err(crate::store::Error::NotFound { .. }) => Err(ApiError::unprocessable(
                "invalid_environment",
                format!(
                    "environment: the server has no image {hash} (upload it as the \
                     `environment` part)"
                ),
            )),
            Err(e) => Err(e.into()),
        },
        (None, None) => Ok(None),
    }
}

/// The most bytes a job's tiles can take in the store: every tile's largest accumulation (a
/// slice's encoding, affine in its pixels), for every frame.
fn accumulation_bytes(s: &JobSettings) -> u64 {
    let (w, h, spp) = (u64::from(s.width), u64::from(s.height), u64::from(s.spp));
    let edge = u64::from(s.tile_size.max(1));
    let tiles = w.div_ceil(edge) * h.div_ceil(edge);
    let fixed = pathfarm_wire::max_slice_body_bytes(0, spp);
    let per_pixel = pathfarm_wire::max_slice_body_bytes(1, spp) - fixed;
    let frames = s.frame_list().ok().flatten().map_or(1, |f| f.len() as u64);
    tiles
        .saturating_mul(fixed)
        .saturating_add(per_pixel.saturating_mul(w * h))
        .saturating_mul(frames)
}

fn validate(state: &AppState, s: &JobSettings, scene_bytes: usize) -> ApiResult<()> {
    let l = &state.config.limits;
    let bad = |m: String| Err(ApiError::unprocessable("invalid_settings", m));
    if scene_bytes == 0 {
        return bad("the scene part is empty".into());
    }
    if scene_bytes > l.max_scene_bytes {
        return Err(ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "too_large",
            format!(
                "scene of {scene_bytes} bytes exceeds the limit of {}",
                bytes_and_mib(l.max_scene_bytes)
            ),
        ));
    }
    if s.width == 0 || s.height == 0 || s.width > l.max_dimension || s.height > l.max_dimension {
        return bad(format!(
            "width and height must be in 1..={} (got {}x{})",
            l.max_dimension, s.width, s.height
        ));
    }
    if s.width as u64 * s.height as u64 > l.max_pixels {
        return bad(format!(
            "{}x{} exceeds the limit of {} pixels",
            s.width, s.height, l.max_pixels
        ));
    }
    if s.spp == 0 || s.spp > l.max_spp {
        return bad(format!("spp must be in 1..={} (got {})", l.max_spp, s.spp));
    }
    if s.tile_size == 0 || s.tile_size > 4096 {
        return bad(format!(
            "tile_size must be in 1..=4096 (got {})",
            s.tile_size
        ));
    }
    // A slice always covers its whole tile: the largest tile's largest honest slice must fit the
    // slice route's body limit, or its uploads would be refused and the job never finish.
    let tile_pixels = u64::from(s.tile_size.min(s.width)) * u64::from(s.tile_size.min(s.height));
    let slice_bytes = pathfarm_wire::max_slice_body_bytes(tile_pixels, u64::from(s.spp));
    if slice_bytes > l.max_slice_bytes as u64 {
        let per_pixel = pathfarm_wire::max_slice_body_bytes(1, u64::from(s.spp))
            - pathfarm_wire::max_slice_body_bytes(0, u64::from(s.spp));
        let fixed = pathfarm_wire::max_slice_body_bytes(0, u64::from(s.spp));
        let largest = ((l.max_slice_bytes as u64).saturating_sub(fixed) / per_pixel).isqrt();
        return Err(ApiError::unprocessable(
            "limit",
            format!(
                "a slice of a {}x{} tile at {} spp may take {slice_bytes} bytes, over the slice \
                 limit of {} bytes (max_slice_bytes); use a tile_size of at most {largest}",
                s.tile_size.min(s.width),
                s.tile_size.min(s.height),
                s.spp,
                l.max_slice_bytes
            ),
        ));
    }
    if let Some(t) = s.noise_target {
        if !(t.is_finite() && t > 0.0) {
            return bad(format!("noise_target must be a positive number (got {t})"));
        }
    }
    if let Some(t) = s.time_limit_s {
        if !(t.is_finite() && t > 0.0) {
            return bad(format!("time_limit_s must be a positive number (got {t})"));
        }
    }
    // In characters, as the contract's `maxLength` counts them.
    if s.name.as_ref().is_some_and(|n| n.chars().count() > 256) {
        return bad("name is longer than 256 characters".into());
    }
    if s.name
        .as_ref()
        .is_some_and(|n| n.chars().any(char::is_control))
    {
        return bad("name contains a control character".into());
    }
    for (field, value) in [("name", &s.name), ("camera", &s.camera)] {
        if value.as_deref().is_some_and(|v| v.contains('\0')) {
            return bad(format!("{field} contains a NUL character"));
        }
    }
    let frames = match s.frame_list() {
        Ok(f) => f.map_or(1, |f| f.len() as u64),
        Err(e) => return bad(e.to_string()),
    };
    if s.frames.is_none() && (s.fps.is_some() || s.frame_order.is_some()) {
        return bad("fps and frame_order are settings of a frame job: give frames too".into());
    }
    if let Some(fps) = s.fps {
        if !(fps.is_finite() && fps > 0.0 && fps <= 1e6) {
            return bad(format!(
                "fps must be a positive number up to 1000000 (got {fps})"
            ));
        }
    }
    // The plan's size, computed before anything is planned: a submission cannot make the server
    // allocate more than the limits allow. A frame job plans every frame's tiles and tasks.
    let (tiles, tasks) = scheduler::plan_size(
        s.width,
        s.height,
        s.tile_size,
        s.spp,
        state.config.task_sizes(),
        s.frames.is_some(),
    );
    let (tiles, tasks) = (tiles.saturating_mul(frames), tasks.saturating_mul(frames));
    if tiles > l.max_tiles {
        return Err(ApiError::unprocessable(
            "limit",
            format!(
                "{tiles} tiles exceed the limit of {} tiles per job (max_tiles); use a larger \
                 tile_size or fewer frames",
                l.max_tiles
            ),
        ));
    }
    if tasks > l.max_tasks {
        return Err(ApiError::unprocessable(
            "limit",
            format!(
                "{tasks} tasks exceed the limit of {} tasks per job (max_tasks); use fewer spp, \
                 a smaller image or fewer frames",
                l.max_tasks
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn warnings_lose_control_characters_and_are_capped() {
        let w = clean_warnings(&["extension X\0 is\n not\u{1b}[31m supported".into()]);
        assert_eq!(w, ["extension X is not[31m supported"]);
        let long = "é".repeat(MAX_WARNING_BYTES);
        let w = clean_warnings(std::slice::from_ref(&long));
        assert!(w[0].len() <= MAX_WARNING_BYTES + '…'.len_utf8() && w[0].ends_with('…'));
        let many: Vec<String> = (0..100)
            .map(|i| format!("{i}{}", "x".repeat(900)))
            .collect();
        let w = clean_warnings(&many);
        let kept: usize = w[..w.len() - 1].iter().map(String::len).sum();
        assert!(kept <= MAX_WARNINGS_BYTES, "{kept}");
        assert_eq!(
            w.last().unwrap(),
            &format!("… and {} more warnings", 101 - w.len())
        );
    }
}
