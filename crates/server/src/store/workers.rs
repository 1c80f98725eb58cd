//! Worker registration, identity, liveness, expiry and listing.
//!
//! Every registration gets a credential of its own: 256 random bits, handed to the worker once and
//! stored only as its SHA-256 digest. The routes find the worker a request acts for by that
//! digest ([`Store::worker_by_credential`]), so a worker token alone no longer names a worker.

use super::error::{Error, StoreResult};
use super::Store;
use crate::states::WorkerEvent;
use pathfarm_wire::api::{WorkerRegistration, WorkerState, WorkerView};
use sha2::{Digest, Sha256};
use sqlx::Row;

/// Most idle registrations one monitor step collects: a step stays one short transaction however
/// many fake registrations piled up; the next steps take the rest.
const COLLECT_BATCH: i64 = 500;

/// The stored form of a worker credential: its SHA-256 digest, hex.
pub fn credential_digest(credential: &str) -> String {
    hex::encode(Sha256::digest(credential.as_bytes()))
}

/// A new credential: 256 bits from the operating system's random source, hex.
fn new_credential() -> StoreResult<String> {
    let mut bytes = [0u8; 32];
    getrandom::fill(&mut bytes)
        .map_err(|e| Error::internal(format!("no random bytes for a worker credential: {e}")))?;
    Ok(hex::encode(bytes))
}

impl Store {
    /// Registers a worker: its id and its credential (which only this answer ever holds).
    pub async fn register_worker(&self, reg: &WorkerRegistration) -> StoreResult<(String, String)> {
        self.register_worker_within(reg, u64::MAX).await
    }

    /// [`Store::register_worker`] while fewer than `max_workers` registrations are kept
    /// ([`Error::TooManyWorkers`] otherwise): what a holder of the worker token can make the
    /// server store, and list, is bounded until idle registrations are collected. Counted in the
    /// registering transaction: on SQLite exact, on PostgreSQL servers registering at once may
    /// pass it by one each.
    pub async fn register_worker_within(
        &self,
        reg: &WorkerRegistration,
        max_workers: u64,
    ) -> StoreResult<(String, String)> {
        let id = uuid::Uuid::new_v4().simple().to_string();
        let credential = new_credential()?;
        let digest = credential_digest(&credential);
        let now = self.now_ms();
        let cached = self.credentials.lookup_began(std::time::Instant::now());
        let mut w = self.write().await?;
        if max_workers < u64::MAX {
            let registered: i64 = sqlx::query("SELECT COUNT(*) AS n FROM workers")
                .fetch_one(&mut *w.tx)
                .await?
                .try_get("n")?;
            let registered = registered.max(0) as u64;
            if registered >= max_workers {
                return Err(Error::TooManyWorkers {
                    registered,
                    limit: max_workers,
                });
            }
        }
        sqlx::query(
            "INSERT INTO workers (id, name, host, threads, version, state, registered_ms, \
             last_seen_ms, credential_digest) VALUES ($1, $2, $3, $4, $5, $6, $7, $7, $8)",
        )
        .bind(&id)
        .bind(&reg.name)
        .bind(&reg.host)
        .bind(reg.threads as i64)
        .bind(&reg.version)
        .bind(WorkerState::Idle.as_str())
        .bind(now)
        .bind(&digest)
        .execute(&mut *w.tx)
        .await?;
        w.commit().await?;
        // Its first calls need no lookup (a farm's workers all lease at once when it starts).
        self.credentials.insert(digest, id.clone(), cached);
        Ok((id, credential))
    }

    /// The id of the registered worker whose credential this is, if any. The lookup is by digest
    /// (an index, or the server's cache of lately found ones: `credentials.rs`), so the time it
    /// takes depends on the digest, never on the credential's bytes.
    pub async fn worker_by_credential(&self, credential: &str) -> StoreResult<Option<String>> {
        let digest = credential_digest(credential);
        let now = std::time::Instant::now();
        if let Some(id) = self.credentials.get(&digest, now) {
            return Ok(Some(id));
        }
        let start = self.credentials.lookup_began(now);
        let row = sqlx::query("SELECT id FROM workers WHERE credential_digest = $1")
            .bind(&digest)
            .fetch_optional(self.pool())
            .await?;
        let Some(row) = row else {
            return Ok(None);
        };
        let id: String = row.try_get("id")?;
        self.credentials.insert(digest, id.clone(), start);
        Ok(Some(id))
    }

    /// Whether `worker_id` holds a lease on a task of a job whose scene or environment image is
    /// the blob `hash`: a worker downloads only what the work it holds needs.
    pub async fn worker_needs_blob(&self, worker_id: &str, hash: &str) -> StoreResult<bool> {
        let row = sqlx::query(
            "SELECT 1 AS yes FROM tasks t JOIN jobs j ON j.id = t.job_id \
             WHERE t.worker_id = $1 AND t.state = 'leased' \
             AND (j.scene_hash = $2 OR j.environment_hash = $2) LIMIT 1",
        )
        .bind(worker_id)
        .bind(hash)
        .fetch_optional(self.pool())
        .await?;
        Ok(row.is_some())
    }

    /// Expires the registrations not seen for longer than `after_ms`: their leases go back to the
    /// queue (as an expired lease does) and their rows are deleted, so their credentials stop
    /// working. Returns how many were collected (at most a batch per call).
    pub async fn collect_idle_workers(&self, after_ms: u64) -> StoreResult<u64> {
        let cutoff = self.now_ms() - after_ms as i64;
        let mut w = self.write().await?;
        // Lock order: tasks before workers. An idle worker's leases have normally expired
        // already (a lease is much shorter than the expiry); these are the ones that have not.
        let leases = sqlx::query(sql!(
            "SELECT t.id, t.job_id, t.worker_id FROM tasks t WHERE t.state = 'leased' \
             AND t.worker_id IN (SELECT id FROM workers WHERE last_seen_ms < $1 \
             ORDER BY last_seen_ms LIMIT {COLLECT_BATCH}) ORDER BY t.id{}",
            self.dialect().skip_locked()
        ))
        .bind(cutoff)
        .fetch_all(&mut *w.tx)
        .await?;
        let mut requeued = Vec::with_capacity(leases.len());
        for r in leases {
            let task: i64 = r.try_get("id")?;
            let job_id: String = r.try_get("job_id")?;
            let worker: Option<String> = r.try_get("worker_id")?;
            tracing::info!(task, job = %job_id, worker = ?worker, "worker registration expired; its lease is queued again");
            requeued.push((task, job_id, worker));
        }
        self.requeue(&mut w.tx, &requeued).await?;
        // The cutoff is compared again by the delete itself: a worker seen meanwhile stays.
        let n = sqlx::query(sql!(
            "DELETE FROM workers WHERE id IN (SELECT id FROM workers WHERE last_seen_ms < $1 \
             ORDER BY last_seen_ms LIMIT {COLLECT_BATCH}) AND last_seen_ms < $1"
        ))
        .bind(cutoff)
        .execute(&mut *w.tx)
        .await?
        .rows_affected();
        w.commit().await?;
        if n > 0 {
            // Their credentials must stop working here at once (`credentials.rs`).
            self.credentials.clear();
        }
        Ok(n)
    }

    /// Signs a worker off; a lease it still holds is given back.
    pub async fn deregister_worker(&self, id: &str) -> StoreResult<()> {
        let leases = sqlx::query(
            "SELECT id, lease_token FROM tasks WHERE worker_id = $1 AND state = 'leased'",
        )
        .bind(id)
        .fetch_all(self.pool())
        .await?;
        for l in leases {
            let task: i64 = l.try_get("id")?;
            let token: Option<String> = l.try_get("lease_token")?;
            if let Some(token) = token {
                // A lease that changed hands meanwhile is not ours to give back.
                match self.release_by(task, &token, id).await {
                    Ok(()) | Err(Error::StaleLease { .. } | Error::NotLessee { .. }) => {}
                    Err(e) => return Err(e),
                }
            }
        }
        let mut w = self.write().await?;
        let n = sqlx::query(sql!(
            "UPDATE workers SET state = {}, current_task = NULL, current_job = NULL, \
             last_seen_ms = $1 WHERE id = $2",
            super::worker_state_after(WorkerEvent::SignOff)
        ))
        .bind(self.now_ms())
        .bind(id)
        .execute(&mut *w.tx)
        .await?
        .rows_affected();
        w.commit().await?;
        if n == 0 {
            return Err(Error::not_found("worker", id));
        }
        Ok(())
    }

    /// Workers silent for longer than `after_ms` become lost. Returns how many.
    pub async fn mark_lost_workers(&self, after_ms: u64) -> StoreResult<u64> {
        let mut w = self.write().await?;
        // The rows are locked in the order of their ids (on PostgreSQL; SQLite has one writer),
        // as every transaction that locks several workers does (`Store::requeue`).
        let n = sqlx::query(sql!(
            "UPDATE workers SET state = {} WHERE id IN (SELECT id FROM workers \
             WHERE state IN ('idle', 'busy') AND last_seen_ms < $1 ORDER BY id{})",
            super::worker_state_after(WorkerEvent::Silent),
            self.dialect().for_update()
        ))
        .bind(self.now_ms() - after_ms as i64)
        .execute(&mut *w.tx)
        .await?
        .rows_affected();
        w.commit().await?;
        Ok(n)
    }

    /// A page of `limit` workers from `from`, newest registration first, then by id; how many
    /// workers there are; and where the next page starts (`None` on the last). The order is
    /// by what never changes about a worker, so a client that follows the cursors from the
    /// first page sees every worker that was registered before it began and not collected before
    /// it ended exactly once, however the farm changes meanwhile: a worker that registers
    /// meanwhile comes before the first page, and one collected meanwhile moves no other worker
    /// (as it would between numbered pages).
    pub async fn workers(
        &self,
        from: WorkerPage,
        limit: u64,
    ) -> StoreResult<(Vec<WorkerView>, u64, Option<WorkerCursor>)> {
        let total: i64 = sqlx::query("SELECT COUNT(*) AS n FROM workers")
            .fetch_one(self.pool())
            .await?
            .try_get("n")?;
        // One more than the page, to know whether a next page exists.
        let fetch = i64::try_from(limit.saturating_add(1)).unwrap_or(i64::MAX);
        const COLUMNS: &str = "SELECT id, name, host, threads, version, state, registered_ms, \
             last_seen_ms, current_task, current_job, samples_done, untrusted FROM workers";
        const ORDER: &str = "ORDER BY registered_ms DESC, id ASC LIMIT $1";
        let mut rows = match from {
            WorkerPage::Offset(offset) => {
                sqlx::query(sql!("{COLUMNS} {ORDER} OFFSET $2"))
                    .bind(fetch)
                    .bind(i64::try_from(offset).unwrap_or(i64::MAX))
                    .fetch_all(self.pool())
                    .await?
            }
            WorkerPage::After(c) => {
                sqlx::query(sql!(
                    "{COLUMNS} WHERE registered_ms < $2 OR (registered_ms = $2 AND id > $3) {ORDER}"
                ))
                .bind(fetch)
                .bind(c.registered_ms)
                .bind(c.id)
                .fetch_all(self.pool())
                .await?
            }
        };
        let more = rows.len() as u64 > limit;
        rows.truncate(usize::try_from(limit).unwrap_or(usize::MAX));
        let next = match rows.last() {
            Some(last) if more => Some(WorkerCursor {
                registered_ms: last.try_get("registered_ms")?,
                id: last.try_get("id")?,
            }),
            _ => None,
        };
        let now = self.now_ms();
        let workers = rows
            .iter()
            .map(|r| {
                let state: String = r.try_get("state")?;
                let registered: i64 = r.try_get("registered_ms")?;
                let last: i64 = r.try_get("last_seen_ms")?;
                let samples = r.try_get::<i64, _>("samples_done")? as u64;
                let alive_s = ((if state == "offline" { last } else { now }) - registered).max(1)
                    as f64
                    / 1000.0;
                Ok(WorkerView {
                    id: r.try_get("id")?,
                    name: r.try_get("name")?,
                    host: r.try_get("host")?,
                    threads: r.try_get::<i64, _>("threads")? as u32,
                    version: r.try_get("version")?,
                    state: WorkerState::parse(&state).unwrap_or(WorkerState::Lost),
                    current_task: r.try_get("current_task")?,
                    current_job: r.try_get("current_job")?,
                    samples_done: samples,
                    samples_per_second: samples as f64 / alive_s,
                    registered_at_ms: registered,
                    last_heartbeat_ms: last,
                    untrusted: r.try_get::<i64, _>("untrusted")? != 0,
                })
            })
            .collect::<Result<Vec<_>, sqlx::Error>>()
            .map_err(Error::from)?;
        Ok((workers, total.max(0) as u64, next))
    }
}

/// Where a page of workers starts ([`Store::workers`]).
pub enum WorkerPage {
    /// After this many workers (numbered pages).
    Offset(u64),
    /// After this worker (cursor pages).
    After(WorkerCursor),
}

/// A worker's place in the list: the page after it starts with the next worker. Sent to clients
/// as an opaque string, `REGISTERED_MS.ID`; read back exactly as [`WorkerCursor::PATTERN`] (the
/// contract's pattern for `after`) says, so that what the contract allows is accepted and nothing
/// else.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WorkerCursor {
    pub registered_ms: i64,
    pub id: String,
}

impl WorkerCursor {
    /// The cursor's form, as the contract states it: a millisecond count of at most 18 digits,
    /// a dot, and an id of 1 to 64 characters none of which is a control character.
    pub const PATTERN: &str = r"^-?[0-9]{1,18}\.[^\x00-\x1f\x7f-\x9f]{1,64}$";
}

impl std::fmt::Display for WorkerCursor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}.{}", self.registered_ms, self.id)
    }
}

impl std::str::FromStr for WorkerCursor {
    type Err = ();

    fn from_str(s: &str) -> Result<Self, ()> {
        let (ms, id) = s.split_once('.').ok_or(())?;
        let digits = ms.strip_prefix('-').unwrap_or(ms);
        let ms_ok = (1..=18).contains(&digits.len()) && digits.bytes().all(|b| b.is_ascii_digit());
        let id_chars = id.chars().count();
        if !ms_ok || !(1..=64).contains(&id_chars) || id.chars().any(char::is_control) {
            return Err(());
        }
        Ok(WorkerCursor {
            registered_ms: ms.parse().map_err(|_| ())?,
            id: id.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::WorkerCursor;

    #[test]
    fn a_cursor_reads_back_what_it_wrote_and_only_the_contracts_form() {
        let c = WorkerCursor {
            registered_ms: 1_764_000_000_123,
            id: "0123456789abcdef0123456789abcdef".into(),
        };
        assert_eq!(c.to_string().parse::<WorkerCursor>(), Ok(c));
        let long_id = "é".repeat(64);
        for good in [
            "0.a",
            "-5.x",
            "123456789012345678.id",
            &format!("1.{long_id}"),
            "7.a.b",
        ] {
            assert!(good.parse::<WorkerCursor>().is_ok(), "{good:?}");
        }
        let too_long = format!("1.{long_id}e");
        for bad in [
            "",
            ".",
            "1.",
            ".a",
            "a.b",
            "+1.a",
            "1234567890123456789.a",
            "--1.a",
            "1 .a",
            "1.a\u{0}",
            "1.a\nb",
            "1.\u{7f}",
            "1.\u{85}",
            &too_long,
        ] {
            assert!(bad.parse::<WorkerCursor>().is_err(), "{bad:?}");
        }
    }
}
