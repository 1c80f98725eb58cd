//! Counts of jobs, tasks and workers by state, for `/metrics`.

use super::Store;
use crate::metrics::Gauges;
use crate::states::TaskState;
use pathfarm_wire::api::{JobState, WorkerState};
use sqlx::Row;
use std::collections::HashMap;

impl Store {
    /// Every known state with its count (zero included, so a series never disappears).
    pub async fn gauges(&self) -> super::StoreResult<Gauges> {
        let jobs = self.count_by_state("jobs").await?;
        let tasks = self.count_by_state("tasks").await?;
        let workers = self.count_by_state("workers").await?;
        let pick = |counts: &HashMap<String, u64>, names: &[&'static str]| {
            names
                .iter()
                .map(|s| (*s, counts.get(*s).copied().unwrap_or(0)))
                .collect()
        };
        let job_names: Vec<&'static str> = JobState::ALL.iter().map(|s| s.as_str()).collect();
        let task_names: Vec<&'static str> = [
            TaskState::Queued,
            TaskState::Leased,
            TaskState::Done,
            TaskState::Cancelled,
        ]
        .iter()
        .map(|s| s.as_str())
        .collect();
        let worker_names: Vec<&'static str> = [
            WorkerState::Idle,
            WorkerState::Busy,
            WorkerState::Lost,
            WorkerState::Offline,
        ]
        .iter()
        .map(|s| s.as_str())
        .collect();
        Ok(Gauges {
            jobs: pick(&jobs, &job_names),
            tasks: pick(&tasks, &task_names),
            workers: pick(&workers, &worker_names),
            pacing: Default::default(),
        })
    }

    async fn count_by_state(
        &self,
        table: &'static str,
    ) -> Result<HashMap<String, u64>, sqlx::Error> {
        let rows = sqlx::query(sql!(
            "SELECT state, COUNT(*) AS n FROM {table} GROUP BY state"
        ))
        .fetch_all(self.pool())
        .await?;
        rows.iter()
            .map(|r| Ok((r.try_get("state")?, r.try_get::<i64, _>("n")?.max(0) as u64)))
            .collect()
    }
}
