//! PostgreSQL's merge in one statement. Every merge and every lease of a job writes the job's row
//! (its counters), and on a busy farm they queue on it: a transactional merge holds the row from
//! its job update until the server's COMMIT arrives, a round trip through a server that is busy
//! with thousands of requests. Here the task and its tile are read without locks, the slice is
//! checked and merged into the tile in the server, and `pathfarm_merge`
//! (`migrations/postgres/0012_lease_and_merge_functions.sql`) checks under the locks that the
//! task and tile are as read, writes, and commits within one round trip (docs/benchmarks.md,
//! "the lease and the merge in one statement"). When they changed meanwhile it writes nothing and
//! the merge reads again. Verification and all-invalid slices keep the transactional merge.

use super::error::{Error, StoreResult};
use super::merge_checks::{check_slice, Checked, TASK_AND_TILE};
use super::tasks::merged_tile;
use super::writes::MergeOutcome;
use super::{Dialect, Store};
use crate::states::{JobEvent, WorkerEvent};
use pathfarm_wire::api::{JobState, SliceAck};
use pathfarm_wire::Slice;
use sqlx::Row;
use std::sync::LazyLock;

/// How often the merge reads again after another merge changed its tile (or a retry its task)
/// before it takes the locks in a transaction instead.
const ATTEMPTS: usize = 4;

/// The state moves `pathfarm_merge` makes, as JSON (`states.rs`'s, spelled once per process):
/// the worker's after a slice that does not finish its task and one that does, the job's when
/// it completes.
static WORKER_MOVES: LazyLock<[String; 2]> = LazyLock::new(|| {
    [false, true].map(|complete| super::worker_moves_json(WorkerEvent::SliceMerged { complete }))
});
static COMPLETE_JOB_MOVES: LazyLock<String> =
    LazyLock::new(|| super::job_moves_json(JobEvent::Complete));

impl Store {
    /// Merges `slice` in one statement, or `None` when it must take the transactional merge:
    /// SQLite (whose merges share group-commit transactions), a verification task's slice, one
    /// with every sample invalid, verification on, or its tile changed by other merges on every
    /// attempt.
    pub(super) async fn merge_in_one_statement(
        &self,
        task_id: i64,
        token: &str,
        slice: &Slice,
    ) -> StoreResult<Option<MergeOutcome>> {
        if self.dialect() != Dialect::Postgres || self.verify_fraction > 0.0 {
            return Ok(None);
        }
        for _ in 0..ATTEMPTS {
            let Some(row) = sqlx::query(TASK_AND_TILE)
                .bind(task_id)
                .fetch_optional(self.pool())
                .await?
            else {
                return Err(Error::not_found("task", task_id));
            };
            let plan = match check_slice(task_id, token, &row, &row, slice)? {
                Checked::Duplicate(out) => return Ok(Some(out)),
                Checked::AllInvalid(_) => return Ok(None),
                Checked::Merge(plan) if plan.verifies.is_some() => return Ok(None),
                Checked::Merge(plan) => plan,
            };
            let (tile_samples, encoded, sums) = merged_tile(&row, &slice.acc, task_id, plan.n)?;
            let merges: i64 = row.try_get("merges")?;
            let done = sqlx::query(
                "SELECT outcome, job_state, completed FROM pathfarm_merge($1, $2, $3, $4, $5, \
                 $6, $7, $8, $9, $10, $11, $12, $13, $14, $15, $16)",
            )
            .bind(task_id)
            .bind(token)
            .bind(i64::from(plan.done_end))
            .bind(merges)
            .bind(i64::from(plan.end))
            .bind(plan.to.as_str())
            .bind(i64::from(plan.complete))
            .bind(tile_samples as i64)
            .bind(encoded)
            .bind(sums.variance())
            .bind(sums.luminance())
            .bind(sums.without_estimate() as i64)
            .bind(plan.samples as i64)
            .bind(self.now_ms())
            .bind(WORKER_MOVES[usize::from(plan.complete)].as_str())
            .bind(COMPLETE_JOB_MOVES.as_str())
            .fetch_one(self.pool())
            .await?;
            if done.try_get::<String, _>("outcome")? != "merged" {
                continue;
            }
            let state: String = done.try_get("job_state")?;
            let state = super::jobs::job_state(&state)?;
            return Ok(Some(MergeOutcome {
                ack: SliceAck {
                    duplicate: false,
                    task_samples_done: plan.end,
                    task_complete: plan.complete,
                    keep_going: !plan.complete && state == JobState::Running,
                    slice_seconds: None,
                },
                samples: plan.samples,
                verification_samples: 0,
                job_completed: done.try_get("completed")?,
                all_invalid: None,
            }));
        }
        Ok(None)
    }
}
