//! Verification of results: a fraction of the tasks ([`crate::ServerConfig::verify_fraction`])
//! is rendered again by another worker, and the two results compared bit for bit. The tracer
//! makes this exact: a tile's samples are a pure function of the job's seed, the pixel and the
//! sample index, so every honest worker renders the same bits.
//!
//! - **Which tasks.** A task is checked when a hash of its job and id falls under the fraction
//!   ([`checked`]), and only if one lease rendered all of it (one worker to answer for it).
//!   While it merges, its own accumulation is kept beside the tile's (`tasks.accum`); when it
//!   completes, a verification task over the same tile and samples is queued (`tasks.verifies`),
//!   not for its worker (`tasks.not_for`). The job completes only once its verification tasks
//!   are judged (`jobs.verifying`).
//! - **Judging.** A verification task's slices merge into its own accumulation, never into the
//!   image. When it completes: the same bits, the task is `verified`. Different bits: the task is
//!   `disputed`, and a third worker (neither of the two) renders it again. The third result
//!   agreeing with the first upholds it and the second worker is wrong; agreeing with the second
//!   refutes the first worker; agreeing with neither is `inconclusive` (logged; nobody is
//!   blamed).
//! - **A wrong worker** is marked untrusted (no more leases, its current leases taken back), and
//!   every tile it merged into (`tile_workers`, recorded while verification is on) is rendered
//!   again from nothing: its tasks queued from their first sample, the tile's sums cleared, its
//!   job's counts reduced, a completed job reopened. The tiles' other workers' samples go too: the
//!   sums are exact integers, but a tile keeps only their total, so the wrong worker's part cannot
//!   be told apart. So everything the worker merged that was not verified is discarded and its
//!   samples queued again.

use super::error::{Error, StoreResult};
use super::jobs::complete_when_done;
use super::statements::Statements;
use super::Store;
use crate::states::{JobEvent, TaskState};
use pathfarm_tracer::Accumulation;
use pathfarm_wire::{decode_slice, encode_slice, Slice, SliceLimits};
use sha2::{Digest, Sha256};
use sqlx::Row;

type Tx = sqlx::Transaction<'static, sqlx::Any>;

/// Whether task `task_id` of `job_id` is checked at `fraction` (0 to 1): its hash's leading 64
/// bits as a fraction of 2⁶⁴ below it. A pure function, so every server of a farm agrees.
pub(super) fn checked(fraction: f64, job_id: &str, task_id: i64) -> bool {
    if fraction <= 0.0 {
        return false;
    }
    let digest = Sha256::new()
        .chain_update(job_id.as_bytes())
        .chain_update(task_id.to_le_bytes())
        .finalize();
    let mut lead = [0u8; 8];
    lead.copy_from_slice(&digest[..8]);
    (u64::from_be_bytes(lead) as f64) < fraction * 18_446_744_073_709_551_616.0
}

/// An accumulation as stored (slice encoding over every sample index, as tiles are stored).
fn encode(acc: Accumulation) -> Vec<u8> {
    encode_slice(&Slice {
        sample_begin: 0,
        sample_end: u32::MAX,
        acc,
    })
}

fn decode(bytes: &[u8]) -> StoreResult<Accumulation> {
    decode_slice(
        bytes,
        &SliceLimits {
            max_pixels: u64::MAX,
        },
    )
    .map(|s| s.acc)
    .map_err(|e| Error::internal(format!("stored task accumulation: {e}")))
}

/// The same result: shape, every pixel's sums and counts, and the count of invalid samples (the
/// few invalid samples a slice records are diagnostics, in the order a worker's threads met them).
fn same(a: &Accumulation, b: &Accumulation) -> bool {
    (a.x0, a.y0, a.width, a.height, a.invalid_count)
        == (b.x0, b.y0, b.width, b.height, b.invalid_count)
        && a.pixels == b.pixels
}

/// `acc` merged into the accumulation stored in `stored` (none yet: `acc` alone), encoded.
fn merged_into(stored: Option<Vec<u8>>, acc: &Accumulation) -> StoreResult<Vec<u8>> {
    let mut total = match stored {
        Some(bytes) => decode(&bytes)?,
        None => Accumulation::new(acc.x0, acc.y0, acc.width, acc.height),
    };
    total
        .merge(acc)
        .map_err(|e| Error::internal(format!("task accumulation: {e}")))?;
    Ok(encode(total))
}

/// A task's result against a verification's.
enum Verdict {
    /// The same bits.
    Verified,
    /// Different bits, a third opinion queued.
    Disputed,
    /// A third opinion decided: the worker named is wrong.
    Wrong(String),
    /// Three different results.
    Inconclusive,
    /// The checked task was rendered again meanwhile (its tile reset): nothing to judge.
    Moot,
}

impl Store {
    /// For a merge of a slice of an ordinary task while verification is on: records that `worker`
    /// merged into the tile (a statement added to the merge's `writes`, which go to the database
    /// in one round trip on SQLite: this runs on every merge) and keeps the task's own
    /// accumulation when the task is checked; when this slice completes a checked task that one
    /// lease rendered, queues its verification. Returns the verification tasks queued (0 or 1).
    /// In the merge's transaction, before the job's row is written.
    #[allow(clippy::too_many_arguments)]
    pub(super) async fn track_for_verification(
        &self,
        tx: &mut Tx,
        writes: &mut Statements,
        job_id: &str,
        task_id: i64,
        tile_index: i64,
        worker: Option<&str>,
        slice: &Accumulation,
        complete: bool,
    ) -> StoreResult<i64> {
        if self.verify_fraction <= 0.0 {
            return Ok(0);
        }
        if let Some(worker) = worker {
            writes.push(
                "INSERT INTO tile_workers (job_id, tile_index, worker_id) VALUES ($1, $2, $3) \
                 ON CONFLICT DO NOTHING",
                vec![job_id.into(), tile_index.into(), worker.into()],
            );
        }
        if !checked(self.verify_fraction, job_id, task_id) {
            return Ok(0);
        }
        let row = sqlx::query(
            "SELECT accum, leases, pass, sample_begin, sample_end FROM tasks WHERE id = $1",
        )
        .bind(task_id)
        .fetch_one(&mut **tx)
        .await?;
        let accum = merged_into(row.try_get("accum")?, slice)?;
        let one_lease = row.try_get::<i64, _>("leases")? == 1;
        let opens = complete && one_lease && worker.is_some();
        sqlx::query("UPDATE tasks SET accum = $1, verify_state = $2 WHERE id = $3")
            .bind(if complete && !opens {
                None
            } else {
                Some(accum)
            })
            .bind(opens.then_some("pending"))
            .bind(task_id)
            .execute(&mut **tx)
            .await?;
        if !opens {
            return Ok(0);
        }
        self.queue_verification(tx, job_id, task_id, &row, worker.unwrap_or_default())
            .await?;
        Ok(1)
    }

    /// Queues a verification of task `checked` (its row `task`: pass and samples), not for the
    /// workers in `not_for` (separated by spaces).
    async fn queue_verification(
        &self,
        tx: &mut Tx,
        job_id: &str,
        checked: i64,
        task: &sqlx::any::AnyRow,
        not_for: &str,
    ) -> StoreResult<()> {
        let begin: i64 = task.try_get("sample_begin")?;
        sqlx::query(
            "INSERT INTO tasks (job_id, tile_index, pass, sample_begin, sample_end, done_end, \
             state, leases, verifies, not_for) \
             SELECT job_id, tile_index, $1, $2, $3, $2, 'queued', 0, id, $4 FROM tasks WHERE id = $5",
        )
        .bind(task.try_get::<i64, _>("pass")?)
        .bind(begin)
        .bind(task.try_get::<i64, _>("sample_end")?)
        .bind(not_for)
        .bind(checked)
        .execute(&mut **tx)
        .await?;
        tracing::debug!(job = job_id, task = checked, not_for, "verification queued");
        Ok(())
    }

    /// Merges a slice of verification task `task_id` (which checks task `checked`) into its own
    /// accumulation; `complete`: the slice ends the task, which is then judged. Returns how the
    /// job's counts change: (verification tasks judged, verification tasks queued).
    pub(super) async fn merge_verification(
        &self,
        tx: &mut Tx,
        job_id: &str,
        task_id: i64,
        checked_id: i64,
        slice: &Accumulation,
        complete: bool,
    ) -> StoreResult<(i64, i64)> {
        let own: Option<Vec<u8>> = sqlx::query("SELECT accum FROM tasks WHERE id = $1")
            .bind(task_id)
            .fetch_one(&mut **tx)
            .await?
            .try_get("accum")?;
        let accum = merged_into(own, slice)?;
        if !complete {
            sqlx::query("UPDATE tasks SET accum = $1 WHERE id = $2")
                .bind(accum)
                .bind(task_id)
                .execute(&mut **tx)
                .await?;
            return Ok((0, 0));
        }
        // Done before it is judged: a verdict that renders the checked task's tile again cancels
        // the tile's open verification tasks, and this one is counted by its own merge.
        sqlx::query(sql!(
            "UPDATE tasks SET state = '{}' WHERE id = $1",
            TaskState::Done.as_str()
        ))
        .bind(task_id)
        .execute(&mut **tx)
        .await?;
        let result = decode(&accum)?;
        let verdict = self.judge(tx, task_id, checked_id, &result).await?;
        // The second opinion is kept while a third is to come; every other is spent.
        let keep = matches!(verdict, Verdict::Disputed).then_some(accum);
        sqlx::query("UPDATE tasks SET accum = $1 WHERE id = $2")
            .bind(keep)
            .bind(task_id)
            .execute(&mut **tx)
            .await?;
        match verdict {
            Verdict::Verified | Verdict::Inconclusive | Verdict::Moot => Ok((1, 0)),
            Verdict::Disputed => Ok((1, 1)),
            Verdict::Wrong(worker) => {
                self.untrust(tx, &worker).await?;
                Ok((1, 0))
            }
        }
        .inspect(|_| tracing::debug!(job = job_id, task = checked_id, "verification judged"))
    }

    /// Compares verification `task_id`'s `result` with the checked task's (and, for a third
    /// opinion, with the second), recording the checked task's verification state.
    async fn judge(
        &self,
        tx: &mut Tx,
        task_id: i64,
        checked_id: i64,
        result: &Accumulation,
    ) -> StoreResult<Verdict> {
        let checked = sqlx::query(sql!(
            "SELECT accum, verify_state, worker_id, pass, sample_begin, sample_end, not_for \
             FROM tasks WHERE id = $1{}",
            self.dialect().for_update()
        ))
        .bind(checked_id)
        .fetch_optional(&mut **tx)
        .await?;
        let Some(checked) = checked else {
            return Ok(Verdict::Moot);
        };
        let state: Option<String> = checked.try_get("verify_state")?;
        let Some(first_bytes) = checked.try_get::<Option<Vec<u8>>, _>("accum")? else {
            return Ok(Verdict::Moot);
        };
        let first = decode(&first_bytes)?;
        let first_worker: String = checked
            .try_get::<Option<String>, _>("worker_id")?
            .unwrap_or_default();
        let this_worker: String = sqlx::query("SELECT worker_id FROM tasks WHERE id = $1")
            .bind(task_id)
            .fetch_one(&mut **tx)
            .await?
            .try_get::<Option<String>, _>("worker_id")?
            .unwrap_or_default();
        let set = |state: &'static str| {
            sqlx::query("UPDATE tasks SET verify_state = $1, accum = NULL WHERE id = $2")
                .bind(state)
                .bind(checked_id)
        };
        match state.as_deref() {
            Some("pending") if same(&first, result) => {
                set("verified").execute(&mut **tx).await?;
                Ok(Verdict::Verified)
            }
            Some("pending") => {
                sqlx::query("UPDATE tasks SET verify_state = 'disputed' WHERE id = $1")
                    .bind(checked_id)
                    .execute(&mut **tx)
                    .await?;
                let job_id: String = sqlx::query("SELECT job_id FROM tasks WHERE id = $1")
                    .bind(checked_id)
                    .fetch_one(&mut **tx)
                    .await?
                    .try_get("job_id")?;
                let not_for = format!("{first_worker} {this_worker}");
                self.queue_verification(tx, &job_id, checked_id, &checked, &not_for)
                    .await?;
                tracing::warn!(task = checked_id, %first_worker, second_worker = %this_worker, "two workers' results of the same samples differ; a third worker decides");
                Ok(Verdict::Disputed)
            }
            Some("disputed") => {
                let second = sqlx::query(
                    "SELECT accum, worker_id FROM tasks WHERE verifies = $1 AND id <> $2 \
                     AND accum IS NOT NULL ORDER BY id LIMIT 1",
                )
                .bind(checked_id)
                .bind(task_id)
                .fetch_optional(&mut **tx)
                .await?;
                let (second, second_worker) = match second {
                    Some(r) => (
                        decode(&r.try_get::<Vec<u8>, _>("accum")?)?,
                        r.try_get::<Option<String>, _>("worker_id")?
                            .unwrap_or_default(),
                    ),
                    None => return Ok(Verdict::Moot),
                };
                sqlx::query("UPDATE tasks SET accum = NULL WHERE verifies = $1")
                    .bind(checked_id)
                    .execute(&mut **tx)
                    .await?;
                if same(&first, result) {
                    set("upheld").execute(&mut **tx).await?;
                    tracing::warn!(task = checked_id, wrong = %second_worker, "a third worker agrees with the first: the second was wrong");
                    Ok(Verdict::Wrong(second_worker))
                } else if same(&second, result) {
                    set("refuted").execute(&mut **tx).await?;
                    tracing::warn!(task = checked_id, wrong = %first_worker, "a third worker agrees with the second: the first was wrong");
                    Ok(Verdict::Wrong(first_worker))
                } else {
                    set("inconclusive").execute(&mut **tx).await?;
                    tracing::error!(task = checked_id, %first_worker, %second_worker, third_worker = %this_worker, "three workers rendered the same samples three ways");
                    Ok(Verdict::Inconclusive)
                }
            }
            _ => Ok(Verdict::Moot),
        }
    }

    /// Cancels queued verification tasks that no worker may take: no trusted worker that is alive
    /// (idle or busy) outside their `not_for` — a farm of one worker, or of two that disagree.
    /// The checked task keeps its result, `unverified` (or `inconclusive` after a dispute); a job
    /// that waited only for them completes. Returns how many were cancelled (a bounded number a
    /// call: the monitor calls it every step).
    pub async fn drop_stranded_verifications(&self) -> StoreResult<u64> {
        // A task's `not_for` names at most two workers, so with three trusted workers alive
        // nothing is stranded: one cheap read per step, and a write only when there is work.
        let live: Vec<String> = sqlx::query(
            "SELECT id FROM workers WHERE untrusted = 0 AND state IN ('idle', 'busy') \
             ORDER BY id LIMIT 3",
        )
        .fetch_all(self.pool())
        .await?
        .iter()
        .map(|r| r.try_get("id"))
        .collect::<Result<_, _>>()?;
        if live.len() > 2 {
            return Ok(0);
        }
        let stranded = |not_for: &str| live.iter().all(|w| not_for.split(' ').any(|n| n == w));
        let queued = sqlx::query(
            "SELECT id, not_for FROM tasks WHERE verifies IS NOT NULL AND state = 'queued' \
             ORDER BY id LIMIT 64",
        )
        .fetch_all(self.pool())
        .await?;
        let mut ids = Vec::new();
        for r in &queued {
            let not_for: Option<String> = r.try_get("not_for")?;
            if stranded(not_for.as_deref().unwrap_or_default()) {
                ids.push(r.try_get::<i64, _>("id")?);
            }
        }
        if ids.is_empty() {
            return Ok(0);
        }
        let mut w = self.write().await?;
        let mut dropped = 0;
        for id in ids {
            // Still queued (a worker may have taken it meanwhile)?
            let r = sqlx::query(sql!(
                "SELECT id, job_id, verifies FROM tasks WHERE id = $1 AND state = 'queued'{}",
                self.dialect().skip_locked()
            ))
            .bind(id)
            .fetch_optional(&mut *w.tx)
            .await?;
            let Some(r) = r else { continue };
            let (id, job_id, checked): (i64, String, i64) = (
                r.try_get("id")?,
                r.try_get("job_id")?,
                r.try_get("verifies")?,
            );
            sqlx::query(sql!(
                "UPDATE tasks SET state = '{}', accum = NULL WHERE id = $1",
                TaskState::Cancelled.as_str()
            ))
            .bind(id)
            .execute(&mut *w.tx)
            .await?;
            sqlx::query(
                "UPDATE tasks SET verify_state = CASE WHEN verify_state = 'disputed' \
                 THEN 'inconclusive' ELSE 'unverified' END, accum = NULL WHERE id = $1",
            )
            .bind(checked)
            .execute(&mut *w.tx)
            .await?;
            sqlx::query("UPDATE tasks SET accum = NULL WHERE verifies = $1")
                .bind(checked)
                .execute(&mut *w.tx)
                .await?;
            let job = sqlx::query(
                "UPDATE jobs SET queued_tasks = queued_tasks - 1, verifying = verifying - 1 \
                 WHERE id = $1 RETURNING state, samples_done, samples_planned, verifying",
            )
            .bind(&job_id)
            .fetch_one(&mut *w.tx)
            .await?;
            complete_when_done(&mut w.tx, &job_id, &job, self.now_ms()).await?;
            tracing::warn!(job = %job_id, task = checked, "no other worker can verify the task: left unverified");
            dropped += 1;
        }
        w.commit().await?;
        Ok(dropped)
    }

    /// Marks `worker` untrusted, takes its leases back, and renders every tile it merged into
    /// again from nothing (see the module documentation).
    async fn untrust(&self, tx: &mut Tx, worker: &str) -> StoreResult<()> {
        if worker.is_empty() {
            return Ok(());
        }
        sqlx::query("UPDATE workers SET untrusted = 1 WHERE id = $1")
            .bind(worker)
            .execute(&mut **tx)
            .await?;
        let tiles = sqlx::query(
            "SELECT tw.job_id, tw.tile_index FROM tile_workers tw JOIN jobs j ON j.id = tw.job_id \
             WHERE tw.worker_id = $1 AND j.state IN ('queued', 'running', 'paused', 'completed') \
             ORDER BY tw.job_id, tw.tile_index",
        )
        .bind(worker)
        .fetch_all(&mut **tx)
        .await?;
        for t in &tiles {
            self.render_again(
                tx,
                &t.try_get::<String, _>("job_id")?,
                t.try_get("tile_index")?,
            )
            .await?;
        }
        // Its leases elsewhere: queued again (its uploads for them are then refused as stale).
        let held = sqlx::query(
            "SELECT id, job_id FROM tasks WHERE worker_id = $1 AND state = 'leased' ORDER BY id",
        )
        .bind(worker)
        .fetch_all(&mut **tx)
        .await?;
        let mut leases = Vec::with_capacity(held.len());
        for r in held {
            leases.push((
                r.try_get("id")?,
                r.try_get("job_id")?,
                Some(worker.to_string()),
            ));
        }
        self.requeue(tx, &leases).await?;
        tracing::warn!(%worker, tiles = tiles.len(), "worker untrusted: its tiles are rendered again");
        Ok(())
    }

    /// Clears tile `tile_index` of `job_id` and queues all its samples again: its ordinary tasks
    /// from their first sample (leases taken back), its open verification tasks cancelled, the
    /// job's counts reduced by what the tile held, a completed job reopened.
    async fn render_again(&self, tx: &mut Tx, job_id: &str, tile_index: i64) -> StoreResult<()> {
        let tasks = sqlx::query(
            "SELECT id, state, worker_id, verifies FROM tasks WHERE job_id = $1 AND tile_index = $2 \
             AND state IN ('queued', 'leased', 'done') ORDER BY id",
        )
        .bind(job_id)
        .bind(tile_index)
        .fetch_all(&mut **tx)
        .await?;
        let (mut queued, mut leased, mut verifying) = (0i64, 0i64, 0i64);
        let mut freed = Vec::new();
        for t in &tasks {
            let state: String = t.try_get("state")?;
            let verification = t.try_get::<Option<i64>, _>("verifies")?.is_some();
            match (verification, state.as_str()) {
                (false, "done") => queued += 1,
                (false, "leased") => (queued, leased) = (queued + 1, leased - 1),
                (true, "queued") => (queued, verifying) = (queued - 1, verifying - 1),
                (true, "leased") => (leased, verifying) = (leased - 1, verifying - 1),
                _ => {}
            }
            if state == "leased" {
                if let Some(w) = t.try_get::<Option<String>, _>("worker_id")? {
                    freed.push((w, t.try_get::<i64, _>("id")?));
                }
            }
        }
        sqlx::query(
            "UPDATE tasks SET state = 'queued', done_end = sample_begin, lease_token = NULL, \
             worker_id = NULL, lease_expires_ms = NULL, leases = 0, accum = NULL, \
             verify_state = NULL WHERE job_id = $1 AND tile_index = $2 AND verifies IS NULL \
             AND state IN ('queued', 'leased', 'done')",
        )
        .bind(job_id)
        .bind(tile_index)
        .execute(&mut **tx)
        .await?;
        sqlx::query(sql!(
            "UPDATE tasks SET state = '{}', lease_token = NULL, accum = NULL WHERE job_id = $1 \
             AND tile_index = $2 AND verifies IS NOT NULL AND state IN ('queued', 'leased')",
            TaskState::Cancelled.as_str()
        ))
        .bind(job_id)
        .bind(tile_index)
        .execute(&mut **tx)
        .await?;
        let tile = sqlx::query(sql!(
            "SELECT samples, width, height FROM tiles WHERE job_id = $1 AND tile_index = $2{}",
            self.dialect().for_update()
        ))
        .bind(job_id)
        .bind(tile_index)
        .fetch_one(&mut **tx)
        .await?;
        // What `samples_done` counted for the tile: its samples in every pixel.
        let held = tile.try_get::<i64, _>("samples")?
            * tile.try_get::<i64, _>("width")?
            * tile.try_get::<i64, _>("height")?;
        sqlx::query(
            "UPDATE tiles SET samples = 0, accum = NULL, merges = merges + 1, err_var = NULL, \
             err_lum = NULL, err_unestimated = NULL \
             WHERE job_id = $1 AND tile_index = $2",
        )
        .bind(job_id)
        .bind(tile_index)
        .execute(&mut **tx)
        .await?;
        sqlx::query("DELETE FROM tile_workers WHERE job_id = $1 AND tile_index = $2")
            .bind(job_id)
            .bind(tile_index)
            .execute(&mut **tx)
            .await?;
        let (_, to) = self.locked_transition(tx, job_id, JobEvent::Reopen).await?;
        sqlx::query(
            "UPDATE jobs SET state = $1, finished_ms = NULL, samples_done = samples_done - $2, \
             queued_tasks = queued_tasks + $3, leased_tasks = leased_tasks + $4, \
             verifying = verifying + $5, version = version + 1 WHERE id = $6",
        )
        .bind(to.as_str())
        .bind(held)
        .bind(queued)
        .bind(leased)
        .bind(verifying)
        .bind(job_id)
        .execute(&mut **tx)
        .await?;
        for (w, task) in freed {
            sqlx::query(sql!(
                "UPDATE workers SET current_task = NULL, current_job = NULL, state = {} \
                 WHERE id = $1 AND current_task = $2",
                super::worker_state_after(crate::states::WorkerEvent::TaskTaken)
            ))
            .bind(w)
            .bind(task)
            .execute(&mut **tx)
            .await?;
        }
        Ok(())
    }
}
