//! Group commit of the hot writes (slice merges and leases) on SQLite.
//!
//! SQLite has one writer, so every merge and lease waits for the writer lock, and each paid for
//! its own transaction. Here a request joins a queue and then waits for the lock; whoever gets the
//! lock runs everything queued so far, in order, in one transaction and answers every request in
//! it. Under load the batches grow by themselves (what arrived during one commit forms the next
//! batch); with one request at a time a batch is that one request, at no extra latency.
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
        let (Some(queue), Some(writer)) = (&self.write_queue, &self.sqlite_writer) else {
            return Err(Error::internal("group commit without a SQLite writer"));
        };
        let (reply, answer) = oneshot::channel();
        let id = queue
            .next_id
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        queue.lock()?.push(Pending { id, op, reply });
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
                let tx = self.pool().begin_with(super::SQLITE_BEGIN_WRITE).await?;
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
                break;
            }
        }
        answer.await.unwrap_or_else(|_| Err(Error::Interrupted))
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
