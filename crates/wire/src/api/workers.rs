//! Workers: their state, registration, views and lists, and their heartbeat.

use super::integer;
use serde::{Deserialize, Serialize};

/// A worker's life: see the state machine in `ARCHITECTURE.md`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WorkerState {
    Idle,
    Busy,
    /// No heartbeat for longer than a lease; its leases have expired or will.
    Lost,
    /// Signed off cleanly.
    Offline,
}

impl WorkerState {
    pub fn as_str(self) -> &'static str {
        match self {
            WorkerState::Idle => "idle",
            WorkerState::Busy => "busy",
            WorkerState::Lost => "lost",
            WorkerState::Offline => "offline",
        }
    }

    pub fn parse(s: &str) -> Option<WorkerState> {
        [
            WorkerState::Idle,
            WorkerState::Busy,
            WorkerState::Lost,
            WorkerState::Offline,
        ]
        .into_iter()
        .find(|w| w.as_str() == s)
    }
}

/// `POST /api/v1/workers`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorkerRegistration {
    pub name: String,
    #[serde(deserialize_with = "integer::deserialize")]
    pub threads: u32,
    pub version: String,
    pub host: String,
}

/// Answer to a registration: the worker's id, its credential and the timing it must keep.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorkerRegistered {
    pub worker_id: String,
    /// The worker's own secret, sent in [`WORKER_CREDENTIAL_HEADER`] on every call it makes for
    /// itself. Only this answer holds it (the server keeps its digest); a worker that loses it,
    /// or whose registration expired, registers again.
    ///
    /// [`WORKER_CREDENTIAL_HEADER`]: super::WORKER_CREDENTIAL_HEADER
    pub credential: String,
    pub lease_duration_ms: u64,
    pub heartbeat_interval_ms: u64,
}

/// One worker as `GET /api/v1/workers` shows it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorkerView {
    pub id: String,
    pub name: String,
    pub host: String,
    pub threads: u32,
    pub version: String,
    pub state: WorkerState,
    pub current_task: Option<i64>,
    pub current_job: Option<String>,
    pub samples_done: u64,
    pub samples_per_second: f64,
    pub registered_at_ms: i64,
    pub last_heartbeat_ms: i64,
    /// Caught merging a result other workers' renders of the same samples refuted (the server's
    /// `--verify-fraction` checks): it is given no more work.
    #[serde(default)]
    pub untrusted: bool,
}

/// A page of workers: newest registration first, then by id.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorkerList {
    pub workers: Vec<WorkerView>,
    /// Every registered worker, on all pages.
    pub total: u64,
    /// The page number asked for; 0 for a page asked for by cursor (`after`).
    pub page: u32,
    pub per_page: u32,
    /// The cursor of the next page (its `after`); absent on the last page.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next: Option<String>,
}

/// `POST /api/v1/workers/{id}/heartbeat`: the worker is alive, and extends its current lease.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Heartbeat {
    #[serde(default, deserialize_with = "integer::option::deserialize")]
    pub task_id: Option<i64>,
    #[serde(default)]
    pub lease_token: Option<String>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HeartbeatReply {
    /// False when the lease named in the heartbeat is gone (expired and re-leased, job cancelled):
    /// stop working on it.
    pub lease_valid: bool,
    pub lease_expires_in_ms: u64,
}
