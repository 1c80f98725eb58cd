//! What a merge checks before it writes: an uploaded slice against its task (the lease, the
//! sample range, the order) and its tile (the shape), and its values. Shared by the
//! transactional merge (`tasks.rs`, under the rows' locks) and PostgreSQL's one-statement merge
//! (`merge_postgres.rs`, on rows read without locks and checked again under them).

use super::error::{Error, StoreResult};
use super::tasks::task_state;
use super::writes::MergeOutcome;
use crate::states::{task_transition, TaskEvent, TaskState};
use pathfarm_wire::api::SliceAck;
use pathfarm_wire::Slice;
use sqlx::any::AnyRow;
use sqlx::Row;

/// A task and its tile in one row, as a merge checks them (no locks: SQLite's single writer, or
/// PostgreSQL's one-statement merge, which checks again under the locks).
pub(super) const TASK_AND_TILE: &str = "SELECT t.job_id, t.tile_index, t.sample_begin, \
     t.sample_end, t.done_end, t.state, t.lease_token, t.worker_id, t.all_invalid_worker, \
     t.verifies, ti.x0, ti.y0, ti.width, ti.height, ti.samples, ti.accum, ti.merges \
     FROM tasks t JOIN tiles ti ON ti.job_id = t.job_id AND ti.tile_index = t.tile_index \
     WHERE t.id = $1";

/// What the checks decided.
pub(super) enum Checked {
    /// The slice was merged before: the answer, with nothing to write.
    Duplicate(MergeOutcome),
    /// Every sample of the slice is invalid (`all_invalid.rs` decides what follows).
    AllInvalid(AllInvalidSlice),
    /// A slice to merge.
    Merge(Plan),
}

/// A slice whose every sample is invalid, and what refusing it needs.
pub(super) struct AllInvalidSlice {
    pub job_id: String,
    pub worker_id: Option<String>,
    pub all_invalid_worker: Option<String>,
    /// The slice, in words, for the job's failure message.
    pub slice: String,
}

/// A slice that passed every check: what its merge writes.
pub(super) struct Plan {
    pub job_id: String,
    pub tile_index: i64,
    /// The task's `done_end` as read (where the slice begins).
    pub done_end: u32,
    /// Where the slice ends: the task's `done_end` after the merge.
    pub end: u32,
    /// Samples a pixel.
    pub n: u32,
    /// Pixel samples: `n` times the tile's pixels.
    pub samples: u64,
    /// Whether the slice finishes its task.
    pub complete: bool,
    /// The task's state after the merge.
    pub to: TaskState,
    pub worker_id: Option<String>,
    /// A verification task: the task whose result it renders again (`verification.rs`).
    pub verifies: Option<i64>,
}

/// Checks `slice`, uploaded for task `task_id` with lease `token`, against the task's row
/// `task` and its tile's row `tile` (the same row when read joined: [`TASK_AND_TILE`]). Every
/// client error (4xx) comes from here, before any write.
pub(super) fn check_slice(
    task_id: i64,
    token: &str,
    task: &AnyRow,
    tile: &AnyRow,
    slice: &Slice,
) -> StoreResult<Checked> {
    let job_id: String = task.try_get("job_id")?;
    let tile_index: i64 = task.try_get("tile_index")?;
    let t_begin = task.try_get::<i64, _>("sample_begin")? as u32;
    let t_end = task.try_get::<i64, _>("sample_end")? as u32;
    let done_end = task.try_get::<i64, _>("done_end")? as u32;
    let state = task_state(&task.try_get::<String, _>("state")?)?;
    let lease_token: Option<String> = task.try_get("lease_token")?;
    let worker_id: Option<String> = task.try_get("worker_id")?;
    let all_invalid_worker: Option<String> = task.try_get("all_invalid_worker")?;
    let verifies: Option<i64> = task.try_get("verifies")?;
    if lease_token.as_deref() != Some(token) {
        return Err(Error::StaleLease { task_id });
    }
    let (s_begin, s_end) = (slice.sample_begin, slice.sample_end);
    if s_begin < t_begin || s_end > t_end {
        return Err(Error::SliceShape(format!(
            "slice samples [{s_begin}, {s_end}) lie outside task {task_id}'s [{t_begin}, {t_end})"
        )));
    }
    if s_end <= done_end {
        return Ok(Checked::Duplicate(MergeOutcome {
            ack: SliceAck {
                duplicate: true,
                task_samples_done: done_end,
                task_complete: done_end == t_end,
                keep_going: state == TaskState::Leased,
                slice_seconds: None,
            },
            samples: 0,
            verification_samples: 0,
            job_completed: false,
            all_invalid: None,
        }));
    }
    if state != TaskState::Leased {
        return Err(Error::TaskNotLeased {
            task_id,
            state: state.as_str(),
        });
    }
    if s_begin != done_end {
        return Err(Error::SliceOutOfOrder {
            task_id,
            done_end,
            begin: s_begin,
        });
    }
    let g = |c: &str| tile.try_get::<i64, _>(c).map(|v| v as u32);
    let (x0, y0, tw, th) = (g("x0")?, g("y0")?, g("width")?, g("height")?);
    let a = &slice.acc;
    if (a.x0, a.y0, a.width, a.height) != (x0, y0, tw, th) {
        return Err(Error::SliceShape(format!(
            "slice covers {}x{} at ({}, {}), task {task_id}'s tile is {tw}x{th} at ({x0}, {y0})",
            a.width, a.height, a.x0, a.y0
        )));
    }
    let n = s_end - s_begin;
    // Every pixel must account for every sample: valid ones are counted, invalid ones counted
    // apart, so the total matches the range.
    let counted: u64 = a.pixels.iter().map(|p| p.count).sum::<u64>() + a.invalid_count;
    let expected = n as u64 * a.pixels.len() as u64;
    if counted != expected {
        return Err(Error::SliceValues(format!(
            "slice holds {counted} samples, its shape needs {expected}"
        )));
    }
    if expected > 0 && a.invalid_count == expected {
        return Ok(Checked::AllInvalid(AllInvalidSlice {
            job_id,
            worker_id,
            all_invalid_worker,
            slice: format!(
                "task {task_id}'s slice of samples [{s_begin}, {s_end}) of tile {tile_index}"
            ),
        }));
    }
    let complete = s_end == t_end;
    let to = task_transition(state, TaskEvent::Merged { complete }).map_err(Error::internal)?;
    Ok(Checked::Merge(Plan {
        job_id,
        tile_index,
        done_end,
        end: s_end,
        n,
        samples: expected,
        complete,
        to,
        worker_id,
        verifies,
    }))
}
