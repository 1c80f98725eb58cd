//! JSON control messages of the REST API (`openapi.yaml`), shared by the server, the worker and the
//! command-line client so that all three agree on one contract.

use pathfarm_tracer::{DirectStrategy, RenderSettings, RussianRoulette, SamplerKind};
use serde::{Deserialize, Serialize};

/// Path prefix of every versioned endpoint.
pub const API_PREFIX: &str = "/api/v1";
/// Media type of a binary slice body (see [`crate::slice`]): the generic binary type, the one
/// client generators can send (the body's magic and version say what it is).
pub const SLICE_CONTENT_TYPE: &str = "application/octet-stream";
/// The slice body's own media type, which workers sent before [`SLICE_CONTENT_TYPE`]: still
/// accepted.
pub const SLICE_CONTENT_TYPE_LEGACY: &str = "application/x-pathfarm-slice";
/// Header that carries a task's lease token on slice uploads.
pub const LEASE_TOKEN_HEADER: &str = "pathfarm-lease-token";
/// Header that carries a worker's own credential (from its registration) on every call it makes
/// for itself: lease, heartbeat, sign-off, slice upload, release, scene download.
pub const WORKER_CREDENTIAL_HEADER: &str = "pathfarm-worker-credential";

/// Serializes a settings enum by its command-line name (`Display` / `FromStr`).
mod by_name {
    use serde::{de::Error, Deserialize, Deserializer, Serializer};
    use std::fmt::Display;
    use std::str::FromStr;

    pub fn serialize<T: Display, S: Serializer>(v: &T, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(v)
    }

    pub fn deserialize<'de, T, D>(d: D) -> Result<T, D::Error>
    where
        T: FromStr<Err = String>,
        D: Deserializer<'de>,
    {
        let s = String::deserialize(d)?;
        s.parse().map_err(D::Error::custom)
    }
}

/// Integers in request bodies, as JSON Schema counts them: `5` and `5.0` are the same integer
/// (`{"type": "integer"}` accepts any number with a zero fractional part), so an integral float is
/// accepted where it is exact and in range; `5.5`, `1e300` and out-of-range values are errors.
mod integer {
    use serde::de::{Error, Unexpected, Visitor};
    use serde::{Deserialize, Deserializer};
    use std::fmt;
    use std::marker::PhantomData;

    /// Largest integer every f64 below it represents exactly (2^53).
    const EXACT: f64 = 9_007_199_254_740_992.0;

    struct Exact<T>(PhantomData<T>);

    impl<T: TryFrom<i64> + TryFrom<u64>> Visitor<'_> for Exact<T> {
        type Value = T;

        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            write!(f, "an integer in range for {}", std::any::type_name::<T>())
        }

        fn visit_i64<E: Error>(self, v: i64) -> Result<T, E> {
            T::try_from(v).map_err(|_| E::invalid_value(Unexpected::Signed(v), &self))
        }

        fn visit_u64<E: Error>(self, v: u64) -> Result<T, E> {
            T::try_from(v).map_err(|_| E::invalid_value(Unexpected::Unsigned(v), &self))
        }

        fn visit_f64<E: Error>(self, v: f64) -> Result<T, E> {
            if v.fract() != 0.0 || v.abs() > EXACT {
                return Err(E::invalid_value(Unexpected::Float(v), &self));
            }
            // Integral and at most 2^53 in magnitude: the cast is exact.
            self.visit_i64(v as i64)
        }
    }

    pub fn deserialize<'de, T, D>(d: D) -> Result<T, D::Error>
    where
        T: TryFrom<i64> + TryFrom<u64>,
        D: Deserializer<'de>,
    {
        d.deserialize_any(Exact(PhantomData))
    }

    /// The same for an optional field (`null` or absent is `None`).
    pub mod option {
        use super::*;

        pub fn deserialize<'de, T, D>(d: D) -> Result<Option<T>, D::Error>
        where
            T: TryFrom<i64> + TryFrom<u64>,
            D: Deserializer<'de>,
        {
            #[derive(Deserialize)]
            struct Wrap<T: TryFrom<i64> + TryFrom<u64>>(
                #[serde(deserialize_with = "super::deserialize")] T,
            );
            Ok(Option::<Wrap<T>>::deserialize(d)?.map(|Wrap(v)| v))
        }
    }
}

fn default_tile() -> u32 {
    64
}

fn one() -> f32 {
    1.0
}

/// A job's environment light: radiance from every direction a ray leaves the scene in, what
/// `pathfarm render --environment` gives a local render. Exactly one of `radiance` (one linear
/// colour) and `image` (the SHA-256 of an equirectangular OpenEXR or Radiance `.hdr` image the
/// server stores: uploaded as the submission's `environment` part, which sets it, or one it already
/// has). [`EnvironmentSettings::build`] makes the tracer's environment from it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentSettings {
    /// Linear RGB radiance, the same from every direction.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radiance: Option<[f32; 3]>,
    /// Lowercase hexadecimal SHA-256 of the image's bytes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<String>,
    /// Multiplies the radiance (`--environment-strength`).
    #[serde(default = "one")]
    pub strength: f32,
    /// Turns the image about the up axis (`--environment-rotation`).
    #[serde(default)]
    pub rotation_degrees: f32,
}

impl Default for EnvironmentSettings {
    fn default() -> Self {
        EnvironmentSettings {
            radiance: None,
            image: None,
            strength: 1.0,
            rotation_degrees: 0.0,
        }
    }
}

/// Everything a job is rendered with besides its scene: the JSON `settings` part of a submission.
/// The render-relevant fields mean exactly what the same `pathfarm render` flags mean, so a farm job
/// and a local render with equal settings give bit-identical images.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobSettings {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(deserialize_with = "integer::deserialize")]
    pub width: u32,
    #[serde(deserialize_with = "integer::deserialize")]
    pub height: u32,
    /// Samples (camera paths) per pixel.
    #[serde(deserialize_with = "integer::deserialize")]
    pub spp: u32,
    #[serde(default, deserialize_with = "integer::deserialize")]
    pub seed: u64,
    /// Tile edge in pixels (does not change the image).
    #[serde(default = "default_tile", deserialize_with = "integer::deserialize")]
    pub tile_size: u32,
    #[serde(default, with = "by_name")]
    pub direct: DirectStrategy,
    #[serde(default, with = "by_name")]
    pub rr: RussianRoulette,
    /// Maximum bounces; absent is unlimited (unbiased).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "integer::option::deserialize"
    )]
    pub max_depth: Option<u32>,
    #[serde(default, with = "by_name")]
    pub sampler: SamplerKind,
    /// Camera name; absent: the scene's first camera.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<String>,
    /// Higher runs first.
    #[serde(default, deserialize_with = "integer::deserialize")]
    pub priority: i32,
    /// Stop once the estimated relative error of the image falls below this (e.g. 0.02).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_target: Option<f64>,
    /// Stop after this many seconds of rendering.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_limit_s: Option<f64>,
    /// The environment light; absent: none (rays that escape see black).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub environment: Option<EnvironmentSettings>,
    /// Frames of the scene's animation to render, one image each (`1-240`, `1-240x2`,
    /// `1,5,10-12`: [`crate::frames::parse_frames`]); absent: one still image, as before.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<String>,
    /// Frames per second of `frames`: frame f is rendered at time f / fps (what
    /// `pathfarm render --frame f --fps fps` renders); absent: 24.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fps: Option<f64>,
    /// The order in which a frame job's frames are rendered; absent: interleaved.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_order: Option<FrameOrder>,
}

/// How a frame job's tasks are ordered.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FrameOrder {
    /// Every frame gets each pass before any frame gets the next: all frames sharpen together.
    #[default]
    Interleaved,
    /// Frame by frame, in the order written: each frame is finished before the next starts.
    Sequential,
}

impl JobSettings {
    /// Settings with the defaults of `pathfarm render`.
    pub fn new(width: u32, height: u32, spp: u32) -> Self {
        JobSettings {
            name: None,
            width,
            height,
            spp,
            seed: 0,
            tile_size: default_tile(),
            direct: DirectStrategy::default(),
            rr: RussianRoulette::default(),
            max_depth: None,
            sampler: SamplerKind::default(),
            camera: None,
            priority: 0,
            noise_target: None,
            time_limit_s: None,
            environment: None,
            frames: None,
            fps: None,
            frame_order: None,
        }
    }

    /// The frames of a frame job (`None` for a still job), as [`crate::frames::parse_frames`]
    /// reads `frames`.
    pub fn frame_list(&self) -> Result<Option<Vec<i64>>, crate::frames::FrameSpecError> {
        self.frames
            .as_deref()
            .map(crate::frames::parse_frames)
            .transpose()
    }

    /// Frames per second of a frame job: `fps`, or 24.
    pub fn frames_per_second(&self) -> f64 {
        self.fps.unwrap_or(pathfarm_tracer::gltf::DEFAULT_FPS)
    }

    /// The tracer's settings (what determines the bits of the image).
    pub fn render_settings(&self) -> RenderSettings {
        RenderSettings {
            width: self.width,
            height: self.height,
            seed: self.seed,
            direct: self.direct,
            rr: self.rr,
            max_depth: self.max_depth,
            sampler: self.sampler,
        }
    }
}

/// A job's life: see the state machine in `ARCHITECTURE.md`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    /// Waiting for its first task to be leased.
    Queued,
    Running,
    /// No new tasks are leased; leased ones may finish their current slice.
    Paused,
    /// Every planned sample merged, or stopped early by its noise target or time limit.
    Completed,
    Cancelled,
    Failed,
}

impl JobState {
    pub const ALL: [JobState; 6] = [
        JobState::Queued,
        JobState::Running,
        JobState::Paused,
        JobState::Completed,
        JobState::Cancelled,
        JobState::Failed,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Paused => "paused",
            JobState::Completed => "completed",
            JobState::Cancelled => "cancelled",
            JobState::Failed => "failed",
        }
    }

    pub fn parse(s: &str) -> Option<JobState> {
        JobState::ALL.into_iter().find(|j| j.as_str() == s)
    }

    /// Completed, cancelled and failed jobs never change again.
    pub fn is_final(self) -> bool {
        matches!(
            self,
            JobState::Completed | JobState::Cancelled | JobState::Failed
        )
    }
}

/// A worker's life: see the state machine in `ARCHITECTURE.md`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WorkerState {
    Idle,
    Busy,
    /// No heartbeat for longer than a lease; its leases have expired or will.
    Lost,
    /// Signed off cleanly.
    Offline,
}

impl WorkerState {
    pub fn as_str(self) -> &'static str {
        match self {
            WorkerState::Idle => "idle",
            WorkerState::Busy => "busy",
            WorkerState::Lost => "lost",
            WorkerState::Offline => "offline",
        }
    }

    pub fn parse(s: &str) -> Option<WorkerState> {
        [
            WorkerState::Idle,
            WorkerState::Busy,
            WorkerState::Lost,
            WorkerState::Offline,
        ]
        .into_iter()
        .find(|w| w.as_str() == s)
    }
}

/// A pixel rectangle of the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TileRect {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
}

/// Samples merged so far in one tile (every pixel of a tile has the same count).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TileProgress {
    #[serde(flatten)]
    pub rect: TileRect,
    pub samples_per_pixel: u64,
    /// The frame the tile belongs to (a frame job's tiles only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<i64>,
}

/// `201` answer to a submission.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobCreated {
    pub id: String,
    pub scene_hash: String,
    pub tasks: u64,
    pub samples_planned: u64,
}

/// One job as `GET /api/v1/jobs/{id}` shows it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobView {
    pub id: String,
    pub name: String,
    pub state: JobState,
    pub priority: i32,
    pub settings: JobSettings,
    pub scene_hash: String,
    /// Samples (camera paths, over all pixels) merged.
    pub samples_done: u64,
    pub samples_planned: u64,
    /// Estimated relative standard error of the image mean; absent until every pixel has samples.
    pub relative_error: Option<f64>,
    pub samples_per_second: f64,
    pub eta_seconds: Option<f64>,
    /// Unix milliseconds.
    pub created_at_ms: i64,
    pub started_at_ms: Option<i64>,
    pub finished_at_ms: Option<i64>,
    /// Why a job ended early (noise target, time limit) or failed.
    pub message: Option<String>,
    pub leased_tasks: u64,
    /// What the scene loader ignored (unsupported extensions and features), one line each, as the
    /// server found them when the job was submitted.
    #[serde(default)]
    pub warnings: Vec<String>,
    /// Per-tile progress (only in the single-job view; of a frame job, every frame's tiles).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tiles: Option<Vec<TileProgress>>,
    /// A frame job's frames (absent for a still job).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames_total: Option<u64>,
    /// Of them, the frames whose every sample is merged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames_done: Option<u64>,
    /// Per-frame progress of a frame job, in the job's frame order (only in the single-job view).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<Vec<FrameProgress>>,
}

/// One frame of a frame job.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameProgress {
    pub frame: i64,
    /// Samples (camera paths, over all pixels) merged into this frame.
    pub samples_done: u64,
    /// The fewest samples per pixel of any of its tiles.
    pub samples_per_pixel: u64,
    /// Every planned sample of the frame is merged, or its error reached the job's noise target.
    pub complete: bool,
    /// The frame's estimated relative error (as the job's `relative_error` is the still image's):
    /// `None` until every pixel of the frame has two samples.
    #[serde(default)]
    pub relative_error: Option<f64>,
}

/// A page of jobs, newest first.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobList {
    pub jobs: Vec<JobView>,
    pub total: u64,
    pub page: u32,
    pub per_page: u32,
}

/// One point of a job's convergence history: recorded by the server as slices merge, roughly
/// log-spaced in time, so that a chart of error against time has as many points per decade late in
/// a long job as early on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ConvergencePoint {
    /// Seconds since the job's first lease.
    pub elapsed_s: f64,
    /// Samples merged into the image this point describes.
    pub samples_done: u64,
    /// Its estimated relative error (`None` until every pixel has two samples).
    pub relative_error: Option<f64>,
    /// Samples merged per second since the previous point (since the start for the first).
    pub samples_per_second: f64,
}

/// `GET /api/v1/jobs/{id}/convergence`: the job's history, oldest first.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Convergence {
    pub job_id: String,
    pub points: Vec<ConvergencePoint>,
}

/// What `preview.png` shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PreviewView {
    /// The tone-mapped mean.
    #[default]
    Image,
    /// Per-pixel sample count as a heat map (linear scale).
    Samples,
    /// Per-pixel relative standard error of the mean luminance as a heat map (log scale).
    Noise,
}

impl PreviewView {
    pub fn as_str(self) -> &'static str {
        match self {
            PreviewView::Image => "image",
            PreviewView::Samples => "samples",
            PreviewView::Noise => "noise",
        }
    }
}

/// Response headers of a heat-map `preview.png`: the values at the two ends of its colour scale.
pub const SCALE_MIN_HEADER: &str = "pathfarm-scale-min";
pub const SCALE_MAX_HEADER: &str = "pathfarm-scale-max";

/// `PATCH /api/v1/jobs/{id}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobPatch {
    #[serde(deserialize_with = "integer::deserialize")]
    pub priority: i32,
}

/// `POST /api/v1/workers`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorkerRegistration {
    pub name: String,
    #[serde(deserialize_with = "integer::deserialize")]
    pub threads: u32,
    pub version: String,
    pub host: String,
}

/// Answer to a registration: the worker's id, its credential and the timing it must keep.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorkerRegistered {
    pub worker_id: String,
    /// The worker's own secret, sent in [`WORKER_CREDENTIAL_HEADER`] on every call it makes for
    /// itself. Only this answer holds it (the server keeps its digest); a worker that loses it,
    /// or whose registration expired, registers again.
    pub credential: String,
    pub lease_duration_ms: u64,
    pub heartbeat_interval_ms: u64,
}

/// One worker as `GET /api/v1/workers` shows it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorkerView {
    pub id: String,
    pub name: String,
    pub host: String,
    pub threads: u32,
    pub version: String,
    pub state: WorkerState,
    pub current_task: Option<i64>,
    pub current_job: Option<String>,
    pub samples_done: u64,
    pub samples_per_second: f64,
    pub registered_at_ms: i64,
    pub last_heartbeat_ms: i64,
    /// Caught merging a result other workers' renders of the same samples refuted (the server's
    /// `--verify-fraction` checks): it is given no more work.
    #[serde(default)]
    pub untrusted: bool,
}

/// A page of workers: newest registration first, then by id.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorkerList {
    pub workers: Vec<WorkerView>,
    /// Every registered worker, on all pages.
    pub total: u64,
    /// The page number asked for; 0 for a page asked for by cursor (`after`).
    pub page: u32,
    pub per_page: u32,
    /// The cursor of the next page (its `after`); absent on the last page.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next: Option<String>,
}

/// A leased task: render samples `[sample_begin, sample_end)` of every pixel of `tile`.
/// `sample_begin` is where uploads must resume: after a lease expired, the samples already merged
/// are not rendered again.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Lease {
    pub task_id: i64,
    pub job_id: String,
    pub lease_token: String,
    pub lease_expires_in_ms: u64,
    pub scene_hash: String,
    pub settings: JobSettings,
    pub tile: TileRect,
    pub sample_begin: u32,
    pub sample_end: u32,
    /// The frame to render the scene at (time = frame / `settings.fps`); absent for a still job.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<i64>,
    /// Back-pressure: the server asks for slices at least this long (seconds), so that its
    /// store keeps up with every worker's uploads; a worker renders slices of the longer of this
    /// and its own length. Absent from older servers: the worker's own length.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slice_seconds: Option<f64>,
}

/// `POST /api/v1/workers/{id}/heartbeat`: the worker is alive, and extends its current lease.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Heartbeat {
    #[serde(default, deserialize_with = "integer::option::deserialize")]
    pub task_id: Option<i64>,
    #[serde(default)]
    pub lease_token: Option<String>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HeartbeatReply {
    /// False when the lease named in the heartbeat is gone (expired and re-leased, job cancelled):
    /// stop working on it.
    pub lease_valid: bool,
    pub lease_expires_in_ms: u64,
}

/// Answer to a slice upload.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SliceAck {
    /// The slice had already been merged (a retry or replay); it was not counted again.
    pub duplicate: bool,
    /// Samples of the task merged so far: the next slice starts here.
    pub task_samples_done: u32,
    pub task_complete: bool,
    /// False when the job was paused: release the lease instead of rendering more.
    pub keep_going: bool,
    /// The server's slice length now ([`Lease::slice_seconds`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slice_seconds: Option<f64>,
}

/// `POST /api/v1/tasks/{id}/release`: give a lease back before its end.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Release {
    pub lease_token: String,
}

/// `GET /healthz`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Health {
    pub status: String,
    pub version: String,
    pub store: String,
}

/// Every error body: `{ "error": { "code": "...", "message": "..." } }`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorBody {
    pub error: ErrorDetail,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorDetail {
    pub code: String,
    pub message: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_round_trip_by_name() {
        let mut s = JobSettings::new(64, 32, 16);
        s.rr = RussianRoulette::Fixed(0.5);
        s.direct = DirectStrategy::Light;
        s.sampler = SamplerKind::Independent;
        let json = serde_json::to_string(&s).unwrap();
        assert!(json.contains("\"direct\":\"light\""), "{json}");
        assert!(json.contains("\"rr\":\"0.5\""), "{json}");
        let back: JobSettings = serde_json::from_str(&json).unwrap();
        assert_eq!(back, s);
    }

    /// The environment's floats reach the worker as JSON text; a render is the same bits as a local
    /// one only if every finite f32 comes back exactly (serde_json writes the shortest digits that
    /// round to the f32, and the f64 it reads them into rounds back to the same f32).
    #[test]
    fn environment_floats_survive_json_bit_for_bit() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            f32::from_bits((state >> 32) as u32)
        };
        let mut checked = 0;
        while checked < 200_000 {
            let v = [next(), next(), next(), next(), next()];
            if v.iter().any(|x| !x.is_finite()) {
                continue;
            }
            let mut s = JobSettings::new(8, 8, 1);
            s.environment = Some(EnvironmentSettings {
                radiance: Some([v[0], v[1], v[2]]),
                image: None,
                strength: v[3],
                rotation_degrees: v[4],
            });
            let back: JobSettings = serde_json::from_str(&serde_json::to_string(&s).unwrap())
                .unwrap_or_else(|e| panic!("{v:?}: {e}"));
            let env = back.environment.expect("environment kept");
            let got = [
                env.radiance.expect("radiance kept"),
                [env.strength, env.rotation_degrees, 0.0],
            ];
            let bits = |x: f32| x.to_bits();
            assert_eq!(got[0].map(bits), [v[0], v[1], v[2]].map(bits), "{v:?}");
            assert_eq!([got[1][0], got[1][1]].map(bits), [v[3], v[4]].map(bits));
            checked += 1;
        }
    }

    #[test]
    fn settings_defaults_and_errors() {
        let s: JobSettings = serde_json::from_str(r#"{"width":8,"height":4,"spp":2}"#).unwrap();
        assert_eq!(s, JobSettings::new(8, 4, 2));
        let e = serde_json::from_str::<JobSettings>(
            r#"{"width":8,"height":4,"spp":2,"direct":"magic"}"#,
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("unknown direct-lighting strategy"),
            "{e}"
        );
        let e = serde_json::from_str::<JobSettings>(r#"{"width":8,"height":4,"spp":2,"sppp":3}"#)
            .unwrap_err();
        assert!(e.to_string().contains("unknown field"), "{e}");
    }

    #[test]
    fn integers_may_be_written_as_integral_numbers() {
        // JSON Schema's `integer` is any number with no fractional part: 99999.0 is 99999.
        let s: JobSettings = serde_json::from_str(
            r#"{"width":8.0,"height":4,"spp":2e0,"seed":7.0,"tile_size":16.0,"max_depth":3.0,"priority":-99999.0}"#,
        )
        .unwrap();
        assert_eq!((s.width, s.height, s.spp, s.seed), (8, 4, 2, 7));
        assert_eq!(
            (s.tile_size, s.max_depth, s.priority),
            (16, Some(3), -99999)
        );
        let none: JobSettings =
            serde_json::from_str(r#"{"width":8,"height":4,"spp":2,"max_depth":null}"#).unwrap();
        assert_eq!(none.max_depth, None);
        let p: JobPatch = serde_json::from_str(r#"{"priority":99999.0}"#).unwrap();
        assert_eq!(p.priority, 99999);
        let r: WorkerRegistration =
            serde_json::from_str(r#"{"name":"w","threads":4.0,"version":"v","host":"h"}"#).unwrap();
        assert_eq!(r.threads, 4);
        let h: Heartbeat = serde_json::from_str(r#"{"task_id":12.0}"#).unwrap();
        assert_eq!(h.task_id, Some(12));

        // Fractions, out-of-range values and inexact huge floats are still errors.
        for bad in [
            r#"{"width":8.5,"height":4,"spp":2}"#,
            r#"{"width":-8,"height":4,"spp":2}"#,
            r#"{"width":4294967296,"height":4,"spp":2}"#,
            r#"{"width":8,"height":4,"spp":2,"seed":1e300}"#,
            r#"{"width":8,"height":4,"spp":2,"priority":3000000000.0}"#,
            r#"{"width":8,"height":4,"spp":"2"}"#,
        ] {
            let e = serde_json::from_str::<JobSettings>(bad).unwrap_err();
            assert!(e.to_string().contains("an integer in range"), "{bad}: {e}");
        }
    }
}
