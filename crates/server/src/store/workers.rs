//! Worker registration, liveness and listing.

use super::error::{Error, StoreResult};
use super::Store;
use crate::states::WorkerEvent;
use pathfarm_wire::api::{WorkerRegistration, WorkerState, WorkerView};
use sqlx::Row;

impl Store {
    pub async fn register_worker(&self, reg: &WorkerRegistration) -> StoreResult<String> {
        let id = uuid::Uuid::new_v4().simple().to_string();
        let now = self.now_ms();
        let mut w = self.write().await?;
        sqlx::query(
            "INSERT INTO workers (id, name, host, threads, version, state, registered_ms, \
             last_seen_ms) VALUES ($1, $2, $3, $4, $5, $6, $7, $7)",
        )
        .bind(&id)
        .bind(&reg.name)
        .bind(&reg.host)
        .bind(reg.threads as i64)
        .bind(&reg.version)
        .bind(WorkerState::Idle.as_str())
        .bind(now)
        .execute(&mut *w.tx)
        .await?;
        w.commit().await?;
        Ok(id)
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
                match self.release(task, &token).await {
                    Ok(()) | Err(Error::StaleLease { .. }) => {}
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
        let n = sqlx::query(sql!(
            "UPDATE workers SET state = {} WHERE state IN ('idle', 'busy') AND last_seen_ms < $1",
            super::worker_state_after(WorkerEvent::Silent)
        ))
        .bind(self.now_ms() - after_ms as i64)
        .execute(&mut *w.tx)
        .await?
        .rows_affected();
        w.commit().await?;
        Ok(n)
    }

    pub async fn workers(&self) -> StoreResult<Vec<WorkerView>> {
        let rows = sqlx::query(
            "SELECT id, name, host, threads, version, state, registered_ms, last_seen_ms, \
             current_task, current_job, samples_done FROM workers \
             ORDER BY CASE WHEN state = 'offline' THEN 1 ELSE 0 END, registered_ms DESC LIMIT 1000",
        )
        .fetch_all(self.pool())
        .await?;
        let now = self.now_ms();
        rows.iter()
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
                })
            })
            .collect::<Result<Vec<_>, sqlx::Error>>()
            .map_err(Error::from)
    }
}
