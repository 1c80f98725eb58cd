//! Group commit of the hot writes (slice merges and leases) on SQLite.
//!
//! SQLite has one writer, so every merge and lease waits for the writer lock, and each paid for
//! its own transaction. Here a request joins a queue and then waits for the lock; whoever gets the
//! lock runs everything queued so far, in order, in one transaction and answers every request in
//! it. Under load the batches grow by themselves (what arrived during one commit forms the next
//! batch); with one request at a time a batch is that one request, at no extra latency.
//!
//! A batch runs on a task of its own, not in the request that took the lock: a request whose
//! client went away is dropped by the HTTP server mid-way, and the batch it was running (everyone
//! else's merges and leases in it) must not be dropped with it.
//!
//! Every request is answered only after its batch committed, so an acknowledged slice or a granted
//! lease is durable exactly as before. A client error (stale token, gap, wrong shape, unknown
//! worker) concerns one request and leaves the others alone: those are all found before the
//! request's first write. Any other error rolls the whole batch back and every request in it is
//! answered with that error (workers retry; merges are idempotent, and a lease that was never
//! answered was never granted).

use super::error::{Error, StoreResult};
use super::writes::{Done, Op};
use super::{Store, WriteTx};
use tokio::sync::oneshot;

struct Pending {
    id: u64,
    op: Op,
    reply: oneshot::Sender<StoreResult<Done>>,
}

/// Requests waiting for the writer lock.
#[derive(Default)]
pub struct WriteQueue {
    pending: std::sync::Mutex<Vec<Pending>>,
    next_id: std::sync::atomic::AtomicU64,
}

impl WriteQueue {
    fn lock(&self) -> StoreResult<std::sync::MutexGuard<'_, Vec<Pending>>> {
        self.pending
            .lock()
            .map_err(|_| Error::internal("write queue lock poisoned"))
    }
}

/// At most this many requests per transaction, so one batch never holds the writer for long.
const MAX_BATCH: usize = 256;

impl Store {
    /// Runs `op` in the next group commit.
    pub(super) async fn grouped(&self, op: Op) -> StoreResult<Done> {
        let Some(queue) = &self.write_queue else {
            return Err(Error::internal("group commit without a SQLite writer"));
        };
        let (reply, answer) = oneshot::channel();
        let id = queue
            .next_id
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        queue.lock()?.push(Pending { id, op, reply });
        // Detached: dropping this request (its client left) leaves the commit running.
        let store = self.clone();
        tokio::spawn(async move { store.commit_through(id).await })
            .await
            .map_err(|e| Error::internal(format!("group commit task: {e}")))??;
        answer.await.unwrap_or_else(|_| Err(Error::Interrupted))
    }

    /// Takes the writer lock and runs the queued batches until request `id`'s has run.
    async fn commit_through(&self, id: u64) -> StoreResult<()> {
        let (Some(queue), Some(writer)) = (&self.write_queue, &self.sqlite_writer) else {
            return Err(Error::internal("group commit without a SQLite writer"));
        };
        // Whoever holds the lock next takes the queue, ours included if it is still there; we
        // drain again after any batch, so every queued upload is merged by a lock holder that
        // came after it.
        loop {
            let guard = writer.lock().await;
            let batch: Vec<Pending> = {
                let mut q = queue.lock()?;
                let n = q.len().min(MAX_BATCH);
                q.drain(..n).collect()
            };
            if !batch.is_empty() {
                // IMMEDIATE: take SQLite's write lock at BEGIN, where the busy timeout waits for
                // it. A deferred transaction that reads first and then writes cannot wait: when
                // another connection wrote since its read began, the upgrade fails at once with
                // "database is locked" (the soak's rare 503s on lease).
                let tx = match self.pool().begin_with(super::SQLITE_BEGIN_WRITE).await {
                    Ok(tx) => tx,
                    Err(e) => {
                        // Taken from the queue: answered here, or their requests would wait
                        // for an answer that never comes.
                        let e = Error::from(e);
                        for p in batch {
                            let _ = p.reply.send(Err(e.clone()));
                        }
                        return Err(e);
                    }
                };
                let w = WriteTx {
                    tx,
                    _writer: Some(guard),
                };
                self.run_batch(w, batch).await;
            } else {
                drop(guard);
            }
            // Ours was in this batch or an earlier one once its answer is there; otherwise it is
            // still queued (a batch was full) and we go again.
            if !queue.lock()?.iter().any(|p| p.id == id) {
                return Ok(());
            }
        }
    }

    async fn run_batch(&self, mut w: WriteTx<'_>, batch: Vec<Pending>) {
        let mut answers = Vec::with_capacity(batch.len());
        let mut failure: Option<Error> = None;
        for p in batch {
            if failure.is_some() {
                answers.push((p.reply, Err(Error::internal("batch failed"))));
                continue;
            }
            let result = match p.op {
                Op::Merge {
                    task_id,
                    token,
                    slice,
                } => self
                    .merge_in(&mut w.tx, task_id, &token, &slice)
                    .await
                    .map(Done::Merged),
                Op::Lease {
                    worker_id,
                    lease_ms,
                    max_leases,
                } => self
                    .lease_in(&mut w.tx, &worker_id, lease_ms, max_leases)
                    .await
                    .map(|l| Done::Leased(l.map(Box::new))),
            };
            match result {
                Err(e) if !e.is_refusal() => {
                    failure = Some(e);
                    answers.push((p.reply, Err(Error::internal("batch failed"))));
                }
                result => answers.push((p.reply, result)),
            }
        }
        if let Some(e) = failure {
            drop(w); // rolls back
            for (reply, _) in answers {
                let _ = reply.send(Err(e.clone()));
            }
            return;
        }
        match w.commit().await {
            Ok(()) => {
                for (reply, result) in answers {
                    let _ = reply.send(result);
                }
            }
            Err(e) => {
                let e = Error::from(e);
                for (reply, _) in answers {
                    let _ = reply.send(Err(e.clone()));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Quotas;
    use crate::scheduler::{plan_frames, TaskSizes};
    use crate::store::NewJob;
    use pathfarm_wire::api::{FrameOrder, JobSettings, WorkerRegistration};
    use std::time::Duration;

    /// A request that took the writer lock and drained the queue is dropped (its client went
    /// away) while its batch runs: the other requests in the batch are answered all the same.
    #[tokio::test(flavor = "current_thread")]
    async fn a_dropped_request_does_not_take_its_batch_down() {
        let dir = std::env::temp_dir().join(format!(
            "pathfarm-group-commit-{}",
            uuid::Uuid::new_v4().simple()
        ));
        std::fs::create_dir_all(&dir).unwrap();
        let store = Store::connect(&format!("sqlite://{}", dir.join("farm.db").display()))
            .await
            .unwrap();
        let settings = JobSettings::new(16, 16, 4);
        let sizes = TaskSizes {
            max: 1 << 22,
            min: 1 << 16,
        };
        let (tiles, tasks) = plan_frames((16, 16, 8, 4), sizes, None, FrameOrder::default());
        store
            .create_job(
                NewJob {
                    id: "job".into(),
                    name: "job".into(),
                    settings,
                    scene_hash: "h".into(),
                    scene_bytes: b"scene".to_vec(),
                    environment: None,
                    warnings: Vec::new(),
                    tiles,
                    tasks,
                    samples_planned: 16 * 16 * 4,
                    owner: String::new(),
                    stored_bytes: 0,
                },
                &Quotas::default(),
                None,
            )
            .await
            .unwrap();
        let mut workers = Vec::new();
        for i in 0..2 {
            let reg = WorkerRegistration {
                name: format!("w{i}"),
                threads: 1,
                version: "t".into(),
                host: "h".into(),
            };
            workers.push(store.register_worker(&reg).await.unwrap().0);
        }
        let queued = || store.write_queue.as_ref().unwrap().lock().unwrap().len();

        // Both requests queue up while the writer lock is held elsewhere.
        let held = store.write().await.unwrap();
        let mut dropped = Box::pin(store.lease(&workers[0], 30_000, 4));
        let mut kept = Box::pin(store.lease(&workers[1], 30_000, 4));
        for f in [&mut dropped, &mut kept] {
            let _ = tokio::time::timeout(Duration::from_millis(1), f).await;
        }
        assert_eq!(queued(), 2);
        drop(held);
        // The first request's commit takes the lock and the whole queue; its request goes away
        // as soon as that happened.
        // One poll at a time, so that it is dropped right after it took the batch, before its
        // batch can finish.
        for _ in 0..1000 {
            if queued() == 0 {
                break;
            }
            if futures_util::FutureExt::now_or_never(&mut dropped).is_some() {
                panic!("the request finished before it was seen taking the batch");
            }
            tokio::task::yield_now().await;
        }
        assert_eq!(queued(), 0, "the batch was taken");
        drop(dropped);
        let lease = kept.await.expect("the other request is answered");
        assert!(lease.is_some(), "and leased a task");
    }
}
