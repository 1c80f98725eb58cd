//! Task leases and the exact merge of uploaded slices.
//!
//! Lock order, in every transaction: tasks, then tiles, then jobs, then workers. PostgreSQL takes
//! row locks in that order, so concurrent servers never deadlock; SQLite has one writer anyway.

use super::error::{Error, StoreResult};
use super::jobs::complete_when_done;
use super::merge_checks::{check_slice, Checked, Plan, TASK_AND_TILE};
use super::statements::{Arg, Statements};
use super::writes::{Done, MergeOutcome, Op};
use super::{Dialect, Store};
use crate::job_image::Sums;
use crate::states::{task_transition, TaskEvent, TaskState, WorkerEvent};
use pathfarm_tracer::accumulation::MergeError;
use pathfarm_tracer::{Accumulation, Tile};
use pathfarm_wire::api::{JobState, SliceAck};
use pathfarm_wire::{decode_slice, encode_slice, Slice, SliceLimits};
use sqlx::Row;

pub(super) fn task_state(s: &str) -> Result<TaskState, sqlx::Error> {
    TaskState::parse(s).ok_or_else(|| sqlx::Error::Protocol(format!("unknown task state {s:?}")))
}

fn stale_lease(task_id: i64) -> Error {
    Error::StaleLease { task_id }
}

pub(super) fn new_token() -> String {
    uuid::Uuid::new_v4().simple().to_string()
}

impl Store {
    /// The tile of task `task_id` when `token` holds its lease: 404 `not_found` without such a
    /// task, 409 `stale_lease` when the token does not hold it (as [`Store::merge_slice`] answers).
    /// An upload is checked with this before its pixels are decoded, so that only a lease holder
    /// makes the server allocate for a slice, and no more than its tile takes. The merge checks
    /// the lease again in its own transaction.
    pub async fn leased_tile(&self, task_id: i64, token: &str) -> StoreResult<Tile> {
        self.leased_tile_checked(task_id, token, None).await
    }

    /// [`Store::leased_tile`] for an upload by `worker_id`: 403 `not_your_lease` when the token
    /// holds the task but the task is leased to another worker (a leaked token).
    pub async fn leased_tile_for(
        &self,
        task_id: i64,
        token: &str,
        worker_id: &str,
    ) -> StoreResult<Tile> {
        self.leased_tile_checked(task_id, token, Some(worker_id))
            .await
    }

    async fn leased_tile_checked(
        &self,
        task_id: i64,
        token: &str,
        worker: Option<&str>,
    ) -> StoreResult<Tile> {
        let row = sqlx::query(
            "SELECT t.lease_token, t.worker_id, ti.x0, ti.y0, ti.width, ti.height FROM tasks t JOIN tiles ti \
             ON ti.job_id = t.job_id AND ti.tile_index = t.tile_index WHERE t.id = $1",
        )
        .bind(task_id)
        .fetch_optional(self.pool())
        .await?;
        let Some(row) = row else {
            return Err(Error::not_found("task", task_id));
        };
        let lease_token: Option<String> = row.try_get("lease_token")?;
        if lease_token.as_deref() != Some(token) {
            return Err(stale_lease(task_id));
        }
        // The token is checked first: a stale lease is a 409 the worker expects (the farm took
        // the task back); a token that holds the task in another worker's hands is a 403. The
        // merge checks only the token again: a task's holder changes only with its token.
        if let Some(worker) = worker {
            if row.try_get::<Option<String>, _>("worker_id")?.as_deref() != Some(worker) {
                return Err(Error::NotLessee { task_id });
            }
        }
        let g = |c: &str| row.try_get::<i64, _>(c).map(|v| v as u32);
        Ok(Tile {
            x0: g("x0")?,
            y0: g("y0")?,
            width: g("width")?,
            height: g("height")?,
        })
    }

    /// Merges one uploaded slice of a task, exactly once.
    ///
    /// A task's slices are merged in order: an upload must start where the merged part ends
    /// (`done_end`). One that ends at or before it is a retry or a replay and is acknowledged as a
    /// duplicate without being counted again; one with a token other than the task's current lease
    /// is rejected (fencing: a worker presumed dead cannot touch a task leased to another).
    ///
    /// On SQLite, whose one writer is the bottleneck, concurrent uploads are merged in one
    /// transaction (group commit, see [`super::group_commit`]); on PostgreSQL each is its own
    /// transaction, so that the documented lock order holds and servers never deadlock.
    pub async fn merge_slice(
        &self,
        task_id: i64,
        token: &str,
        slice: Slice,
    ) -> StoreResult<MergeOutcome> {
        if self.write_queue.is_some() {
            let op = Op::Merge {
                task_id,
                token: token.to_string(),
                slice,
            };
            return match self.grouped(op).await? {
                Done::Merged(out) => Ok(out),
                Done::Leased(_) => Err(Error::internal("a merge answered as a lease")),
            };
        }
        // PostgreSQL: one statement when it can (`merge_postgres.rs`), else a transaction.
        if let Some(out) = self.merge_in_one_statement(task_id, token, &slice).await? {
            return Ok(out);
        }
        let mut w = self.write().await?;
        let out = self.merge_in(&mut w.tx, task_id, token, &slice).await?;
        w.commit().await?;
        Ok(out)
    }

    /// The merge itself, inside the caller's transaction. Every client error (4xx) is returned
    /// before the first write, so a batch can answer it and go on; any other error leaves the
    /// transaction half done and must roll it back.
    pub(super) async fn merge_in(
        &self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
        task_id: i64,
        token: &str,
        slice: &Slice,
    ) -> StoreResult<MergeOutcome> {
        // SQLite, with its single writer, reads the task and its tile in one statement; PostgreSQL
        // locks them one after the other, in the documented order.
        let (task, locked_tile) = match self.dialect() {
            Dialect::Sqlite => {
                let Some(row) = sqlx::query(TASK_AND_TILE)
                    .bind(task_id)
                    .fetch_optional(&mut **tx)
                    .await?
                else {
                    return Err(Error::not_found("task", task_id));
                };
                (row, None)
            }
            Dialect::Postgres => {
                let Some(task) = sqlx::query(
                    "SELECT job_id, tile_index, sample_begin, sample_end, done_end, state, \
                     lease_token, worker_id, all_invalid_worker, verifies FROM tasks \
                     WHERE id = $1 FOR UPDATE",
                )
                .bind(task_id)
                .fetch_optional(&mut **tx)
                .await?
                else {
                    return Err(Error::not_found("task", task_id));
                };
                let tile = sqlx::query(
                    "SELECT x0, y0, width, height, samples, accum FROM tiles \
                     WHERE job_id = $1 AND tile_index = $2 FOR UPDATE",
                )
                .bind(task.try_get::<String, _>("job_id")?)
                .bind(task.try_get::<i64, _>("tile_index")?)
                .fetch_one(&mut **tx)
                .await?;
                (task, Some(tile))
            }
        };
        let tile = locked_tile.as_ref().unwrap_or(&task);
        let Plan {
            job_id,
            tile_index,
            end: s_end,
            n,
            samples,
            complete,
            to,
            worker_id,
            verifies,
            ..
        } = match check_slice(task_id, token, &task, tile, slice)? {
            Checked::Duplicate(out) => return Ok(out),
            Checked::AllInvalid(r) => {
                return self
                    .refuse_all_invalid(
                        tx,
                        task_id,
                        &r.job_id,
                        r.worker_id,
                        r.all_invalid_worker,
                        r.slice,
                    )
                    .await
            }
            Checked::Merge(plan) => plan,
        };
        let a = &slice.acc;
        let now = self.now_ms();
        // The writes in lock order (tiles, tasks, jobs, workers), in one round trip on SQLite
        // (with, while verification is on, the record of who merged into the tile first). The
        // job's update returns what decides completion; its state changes (one more statement)
        // only on the job's last merge.
        let mut writes = Statements::new(self.dialect());
        // A verification task's slices go into its own accumulation, never into the image; an
        // ordinary task's into its tile (and, while verification is on, into its own when it is
        // checked). `judged` and `opened`: verification tasks judged and queued by this merge.
        let (tile_update, judged, opened) = match verifies {
            Some(checked) => {
                let (judged, opened) = self
                    .merge_verification(tx, &job_id, task_id, checked, a, complete)
                    .await?;
                (None, judged, opened)
            }
            None => {
                let update = merged_tile(tile, a, task_id, n)?;
                let opened = self
                    .track_for_verification(
                        tx,
                        &mut writes,
                        &job_id,
                        task_id,
                        tile_index,
                        worker_id.as_deref(),
                        a,
                        complete,
                    )
                    .await?;
                (Some(update), 0, opened)
            }
        };
        let image_samples = if tile_update.is_some() { samples } else { 0 };
        if let Some((new_samples, encoded, sums)) = tile_update {
            writes.push(
                "UPDATE tiles SET samples = $1, accum = $2, merges = merges + 1, err_var = $3, \
                 err_lum = $4, err_unestimated = $5 WHERE job_id = $6 AND tile_index = $7",
                vec![
                    (new_samples as i64).into(),
                    encoded.into(),
                    sums.variance().into(),
                    sums.luminance().into(),
                    (sums.without_estimate() as i64).into(),
                    job_id.as_str().into(),
                    tile_index.into(),
                ],
            );
        }
        writes.push(
            "UPDATE tasks SET done_end = $1, state = $2 WHERE id = $3",
            vec![(s_end as i64).into(), to.as_str().into(), task_id.into()],
        );
        let job_update =
            "UPDATE jobs SET samples_done = samples_done + $1, version = version + $2, \
             leased_tasks = leased_tasks - $3, queued_tasks = queued_tasks + $4, \
             verifying = verifying + $5 WHERE id = $6 \
             RETURNING state, samples_done, samples_planned, verifying";
        let job_args: Vec<Arg> = vec![
            (image_samples as i64).into(),
            i64::from(image_samples > 0).into(),
            (complete as i64).into(),
            opened.into(),
            (opened - judged).into(),
            job_id.as_str().into(),
        ];
        match &worker_id {
            None => {
                writes.push(job_update, job_args);
            }
            Some(worker) => {
                // A pipelined worker finishes a task's last upload after it leased its next
                // task: the merge that completes the task leaves that next task (and the worker
                // busy with it) as it is. SET reads the row as it was before the update, on both
                // stores.
                let worker_update = format!(
                    "UPDATE workers SET samples_done = samples_done + $7, last_seen_ms = $8, \
                     state = CASE WHEN $9 = 1 AND current_task <> $10 THEN state ELSE {} END, \
                     current_task = CASE WHEN $9 = 1 AND current_task = $10 THEN NULL \
                     ELSE current_task END, \
                     current_job = CASE WHEN $9 = 1 AND current_task = $10 THEN NULL \
                     ELSE current_job END WHERE id = $11",
                    super::worker_state_after(WorkerEvent::SliceMerged { complete })
                );
                let mut args = job_args;
                args.extend([
                    Arg::from(samples as i64),
                    now.into(),
                    (complete as i64).into(),
                    task_id.into(),
                    worker.as_str().into(),
                ]);
                // On PostgreSQL the job's row is the one every lease and merge of the job writes:
                // it is locked by the last statement, which writes the worker too (`w` reads
                // `j`, so the job's row is locked first), and held until the commit that follows
                // (see `Store::lease_postgres`). SQLite runs the two as one round trip anyway.
                match self.dialect() {
                    Dialect::Postgres => writes.push(
                        format!(
                            "WITH j AS ({job_update}), \
                             w AS ({worker_update} AND EXISTS (SELECT 1 FROM j)) \
                             SELECT * FROM j"
                        ),
                        args,
                    ),
                    Dialect::Sqlite => writes.push(format!("{job_update};\n{worker_update}"), args),
                };
            }
        }
        let rows = writes.run(tx).await?;
        let job = rows
            .first()
            .ok_or_else(|| Error::internal(format!("job {job_id} vanished during a merge")))?;
        let (new_state, job_completed) = complete_when_done(tx, &job_id, job, now).await?;
        Ok(MergeOutcome {
            ack: SliceAck {
                duplicate: false,
                task_samples_done: s_end,
                task_complete: complete,
                keep_going: !complete && new_state == JobState::Running,
                slice_seconds: None,
            },
            samples: image_samples,
            verification_samples: samples - image_samples,
            job_completed,
            all_invalid: None,
        })
    }

    /// Extends the lease of `task_id` when `token` still holds it; records the worker as alive.
    /// Returns whether the lease is still valid.
    pub async fn heartbeat(
        &self,
        worker_id: &str,
        lease: Option<(i64, &str)>,
        lease_ms: u64,
    ) -> StoreResult<bool> {
        let now = self.now_ms();
        let mut w = self.write().await?;
        let mut valid = false;
        if let Some((task_id, token)) = lease {
            valid = sqlx::query(
                "UPDATE tasks SET lease_expires_ms = $1 \
                 WHERE id = $2 AND lease_token = $3 AND state = 'leased' AND worker_id = $4",
            )
            .bind(now + lease_ms as i64)
            .bind(task_id)
            .bind(token)
            .bind(worker_id)
            .execute(&mut *w.tx)
            .await?
            .rows_affected()
                == 1;
        }
        let n = sqlx::query(sql!(
            "UPDATE workers SET last_seen_ms = $1, state = {} WHERE id = $2",
            super::worker_state_after(WorkerEvent::Heartbeat { leased: valid })
        ))
        .bind(now)
        .bind(worker_id)
        .execute(&mut *w.tx)
        .await?
        .rows_affected();
        w.commit().await?;
        if n == 0 {
            return Err(Error::not_found("worker", worker_id));
        }
        Ok(valid)
    }

    /// Gives a lease back: the task's unmerged samples are queued again. Idempotent: when
    /// `token` does not hold the task (any more: released before, expired, completed, or leased
    /// again since), there is nothing of that lease to give back, and nothing changes.
    pub async fn release(&self, task_id: i64, token: &str) -> StoreResult<()> {
        self.release_checked(task_id, token, None).await
    }

    /// [`Store::release`] by `worker_id`, which must be the task's holder (403 `not_your_lease`
    /// otherwise, after the token check as for uploads).
    pub async fn release_by(&self, task_id: i64, token: &str, worker_id: &str) -> StoreResult<()> {
        self.release_checked(task_id, token, Some(worker_id)).await
    }

    async fn release_checked(
        &self,
        task_id: i64,
        token: &str,
        worker: Option<&str>,
    ) -> StoreResult<()> {
        let mut w = self.write().await?;
        let task = sqlx::query(sql!(
            "SELECT state, lease_token, job_id, worker_id FROM tasks WHERE id = $1{}",
            self.dialect().for_update()
        ))
        .bind(task_id)
        .fetch_optional(&mut *w.tx)
        .await?;
        let Some(task) = task else {
            return Err(Error::not_found("task", task_id));
        };
        let lease_token: Option<String> = task.try_get("lease_token")?;
        let state = task_state(&task.try_get::<String, _>("state")?)?;
        if lease_token.as_deref() != Some(token) {
            // This lease is over already: a release repeated (a retry after a lost answer) or
            // late is a no-op, as the contract says.
            return Ok(());
        }
        let worker_id: Option<String> = task.try_get("worker_id")?;
        if worker.is_some_and(|w| worker_id.as_deref() != Some(w)) {
            return Err(Error::NotLessee { task_id });
        }
        if state == TaskState::Leased {
            let job_id: String = task.try_get("job_id")?;
            self.requeue(&mut w.tx, &[(task_id, job_id, worker_id)])
                .await?;
        }
        w.commit().await?;
        Ok(())
    }

    /// Puts leased tasks back in the queue: `(task, job, worker)` each. Rows are written in the
    /// documented lock order (tasks, jobs, workers), and within each table in the order of their
    /// ids, with one update per job: two servers requeueing overlapping jobs and workers (their
    /// monitors expiring leases at once) lock them in the same order, so they cannot deadlock.
    pub(super) async fn requeue(
        &self,
        tx: &mut sqlx::Transaction<'static, sqlx::Any>,
        leases: &[(i64, String, Option<String>)],
    ) -> StoreResult<()> {
        let to = task_transition(TaskState::Leased, TaskEvent::Requeue).map_err(Error::internal)?;
        let mut tasks: Vec<i64> = leases.iter().map(|(t, _, _)| *t).collect();
        tasks.sort_unstable();
        for task_id in tasks {
            sqlx::query(
                "UPDATE tasks SET state = $1, lease_token = NULL, worker_id = NULL, \
                 lease_expires_ms = NULL WHERE id = $2",
            )
            .bind(to.as_str())
            .bind(task_id)
            .execute(&mut **tx)
            .await?;
        }
        let mut jobs = std::collections::BTreeMap::<&str, i64>::new();
        for (_, job, _) in leases {
            *jobs.entry(job.as_str()).or_default() += 1;
        }
        for (job_id, n) in jobs {
            sqlx::query(
                "UPDATE jobs SET queued_tasks = queued_tasks + $1, \
                 leased_tasks = leased_tasks - $1 WHERE id = $2",
            )
            .bind(n)
            .bind(job_id)
            .execute(&mut **tx)
            .await?;
        }
        let mut workers: Vec<(&str, i64)> = leases
            .iter()
            .filter_map(|(t, _, worker)| worker.as_deref().map(|w| (w, *t)))
            .collect();
        workers.sort_unstable();
        for (worker, task_id) in workers {
            sqlx::query(sql!(
                "UPDATE workers SET current_task = NULL, current_job = NULL, state = {} \
                 WHERE id = $1 AND current_task = $2",
                super::worker_state_after(WorkerEvent::TaskTaken)
            ))
            .bind(worker)
            .bind(task_id)
            .execute(&mut **tx)
            .await?;
        }
        Ok(())
    }

    /// Puts the tasks whose lease expired back in the queue (only their unmerged samples: the
    /// merged part is kept in `done_end`). Returns how many.
    pub async fn expire_leases(&self) -> StoreResult<u64> {
        let mut w = self.write().await?;
        let rows = sqlx::query(sql!(
            "SELECT id, job_id, worker_id FROM tasks WHERE state = 'leased' \
             AND lease_expires_ms < $1 ORDER BY id LIMIT 256{}",
            self.dialect().skip_locked()
        ))
        .bind(self.now_ms())
        .fetch_all(&mut *w.tx)
        .await?;
        let n = rows.len() as u64;
        let mut leases = Vec::with_capacity(rows.len());
        for r in rows {
            let id: i64 = r.try_get("id")?;
            let job_id: String = r.try_get("job_id")?;
            let worker_id: Option<String> = r.try_get("worker_id")?;
            tracing::info!(task = id, job = %job_id, worker = ?worker_id, "lease expired; unmerged samples queued again");
            leases.push((id, job_id, worker_id));
        }
        self.requeue(&mut w.tx, &leases).await?;
        w.commit().await?;
        Ok(n)
    }
}

/// The tile (its row `tile`: samples, accumulation) with slice `a` of task `task_id` (`n` samples
/// a pixel) merged in: its new sample count, stored accumulation and error sums (what the job's
/// and its frame's error estimates add up: `estimates.rs`). Checked: an overflow refuses
/// the slice (before any write, so a batch goes on) and leaves the tile as it was, so honest
/// slices still merge into it.
pub(super) fn merged_tile(
    tile: &sqlx::any::AnyRow,
    a: &Accumulation,
    task_id: i64,
    n: u32,
) -> StoreResult<(u64, Vec<u8>, Sums)> {
    let tile_samples = tile.try_get::<i64, _>("samples")? as u64;
    let accum: Option<Vec<u8>> = tile.try_get("accum")?;
    let mut merged = match accum {
        Some(bytes) => {
            decode_slice(
                &bytes,
                &SliceLimits {
                    max_pixels: u64::MAX,
                },
            )
            .map_err(|e| Error::internal(format!("stored tile accumulation: {e}")))?
            .acc
        }
        None => Accumulation::new(a.x0, a.y0, a.width, a.height),
    };
    merged.merge(a).map_err(|e| match e {
        MergeError::Shape { .. } => Error::internal(format!("merge: {e}")),
        e => Error::SliceValues(format!(
            "slice refused: merging it into task {task_id}'s tile: {e}"
        )),
    })?;
    // The stored tile is the union of sample ranges that may not be contiguous yet (a later pass
    // can be merged before an earlier one), so its recorded invalid samples can lie beyond its
    // sample count: it is stored as covering every sample index. Its count is in `samples`.
    let sums = Sums::of(&merged);
    let encoded = encode_slice(&Slice {
        sample_begin: 0,
        sample_end: u32::MAX,
        acc: merged,
    });
    Ok((tile_samples + u64::from(n), encoded, sums))
}
