//! Jobs as the API shows them: their state, views, lists, convergence history, previews and
//! patches.

use super::{integer, JobSettings, TileProgress};
use serde::{Deserialize, Serialize};

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
