//! Tasks: the tiles they cover, their leases, slice acknowledgements and releases.

use super::JobSettings;
use serde::{Deserialize, Serialize};

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
