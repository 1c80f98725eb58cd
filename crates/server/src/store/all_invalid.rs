//! Slices whose every sample is invalid (NaN, infinite, negative or huge: see the slice format).
//!
//! Such a slice renders nothing a pixel can use, and merging it would complete its task with
//! nothing in the image: a worker that claims every sample invalid would finish jobs without
//! rendering them. So it completes nothing. The first such slice of a task queues the task again
//! and names its worker on the task (`all_invalid_worker`), which is then not given that task
//! again; when a second worker's slice of the same task is all invalid too, the scene itself
//! produces no valid value there, and the job fails with a message that says where. Nothing is
//! merged either way, so the tile keeps exactly what honest slices gave it.

use super::error::StoreResult;
use super::jobs::free_job_workers;
use super::writes::{AllInvalid, MergeOutcome};
use super::Store;
use crate::states::{JobEvent, TaskState};
use pathfarm_wire::api::SliceAck;

impl Store {
    /// Refuses the all-invalid `slice` (a description, for the job's message) of leased task
    /// `task_id`, inside the merge's transaction: the task is queued again for another worker,
    /// or, when another worker (`earlier`) already sent an all-invalid slice of it, the job fails.
    /// Locks in the documented order (tasks, jobs, workers) after the merge's task and tile.
    pub(super) async fn refuse_all_invalid(
        &self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
        task_id: i64,
        job_id: &str,
        worker: Option<String>,
        earlier: Option<String>,
        slice: String,
    ) -> StoreResult<MergeOutcome> {
        let worker = worker.unwrap_or_default();
        let refused = match earlier {
            Some(first) if first != worker => {
                let message = format!(
                    "{slice} had every sample invalid (NaN, infinite, negative or too large) on \
                     two workers ({first} and {worker}): the scene produces no valid value there"
                );
                self.fail_in(tx, job_id, &message).await?;
                tracing::warn!(job = job_id, task = task_id, %first, %worker, "job failed: every sample of a task invalid on two workers");
                AllInvalid::JobFailed {
                    job_id: job_id.to_string(),
                    message,
                }
            }
            _ => {
                self.requeue(tx, &[(task_id, job_id.to_string(), Some(worker.clone()))])
                    .await?;
                sqlx::query("UPDATE tasks SET all_invalid_worker = $1 WHERE id = $2")
                    .bind(&worker)
                    .bind(task_id)
                    .execute(&mut **tx)
                    .await?;
                tracing::warn!(job = job_id, task = task_id, %worker, "a slice with every sample invalid: the task is queued again for another worker");
                AllInvalid::Requeued { task_id }
            }
        };
        Ok(MergeOutcome {
            ack: SliceAck {
                duplicate: false,
                task_samples_done: 0,
                task_complete: false,
                keep_going: false,
                slice_seconds: None,
            },
            samples: 0,
            verification_samples: 0,
            job_completed: false,
            all_invalid: Some(refused),
        })
    }

    /// Fails job `job_id` with `message` inside `tx`: its unfinished tasks cancelled, its workers
    /// freed (as [`Store::job_event`] does in a transaction of its own).
    async fn fail_in(
        &self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
        job_id: &str,
        message: &str,
    ) -> StoreResult<()> {
        sqlx::query(sql!(
            "UPDATE tasks SET state = '{}', lease_token = NULL \
             WHERE job_id = $1 AND state IN ('queued', 'leased')",
            TaskState::Cancelled.as_str()
        ))
        .bind(job_id)
        .execute(&mut **tx)
        .await?;
        let (_, to) = self.locked_transition(tx, job_id, JobEvent::Fail).await?;
        sqlx::query(
            "UPDATE jobs SET state = $1, finished_ms = $2, queued_tasks = 0, leased_tasks = 0, \
             version = version + 1, message = $3 WHERE id = $4",
        )
        .bind(to.as_str())
        .bind(self.now_ms())
        .bind(message)
        .bind(job_id)
        .execute(&mut **tx)
        .await?;
        free_job_workers(tx, job_id).await?;
        Ok(())
    }
}
