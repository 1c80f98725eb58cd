//! What the store answers besides its results: the farm's refusals (no such job, a lease that
//! does not hold the task, a slice that does not fit) and its own failures. It knows nothing of
//! HTTP: the routes map it to statuses and codes (`routes::store_error`), and the database's own
//! text is logged there, never sent to a client.

use std::sync::Arc;

#[derive(Debug, Clone, thiserror::Error)]
pub enum Error {
    /// No such job, task, worker or scene.
    #[error("{what} {id} not found")]
    NotFound { what: &'static str, id: String },
    /// The lease token does not hold the task (fencing).
    #[error("the lease token does not hold task {task_id} (the lease expired or was given back)")]
    StaleLease { task_id: i64 },
    /// The task is no longer leased (done or cancelled) and the slice is not a duplicate.
    #[error("task {task_id} is {state}")]
    TaskNotLeased { task_id: i64, state: &'static str },
    /// The lease token holds the task, but the task is leased to another worker than the one
    /// asking (its token leaked): a worker acts only for itself.
    #[error("task {task_id} is leased to another worker")]
    NotLessee { task_id: i64 },
    /// The worker already holds as many leases as a worker may
    /// (`ServerConfig::max_leases_per_worker`).
    #[error(
        "worker {worker_id} already holds {held} leases, the most a worker may hold; finish or \
         release one first"
    )]
    TooManyLeases { worker_id: String, held: u64 },
    /// The worker was caught merging a wrong result (verification): it is given no more work.
    #[error(
        "worker {worker_id} merged a result that other workers' renders of the same samples \
         refuted; it is given no more work"
    )]
    Untrusted { worker_id: String },
    /// The farm keeps as many worker registrations as it may (`ServerConfig::max_workers`).
    #[error(
        "the farm has {registered} worker registrations, its limit of {limit}; registrations \
         not seen for the worker expiry are collected, try again later"
    )]
    TooManyWorkers { registered: u64, limit: u64 },
    /// A submission would take its client token past one of its quotas ([`crate::Quotas`]).
    #[error(
        "quota exceeded: {what} would be {would_be}, over this client token's limit of {limit}; \
         finish or delete jobs first"
    )]
    QuotaExceeded {
        what: &'static str,
        would_be: u64,
        limit: u64,
    },
    /// The job was deleted while its submission was still being stored.
    #[error("job {0} was deleted while its submission was being stored")]
    DeletedWhileStored(String),
    /// A slice does not start where the task's merged samples end.
    #[error(
        "task {task_id} has samples up to {done_end} merged; a slice starting at {begin} does \
         not follow them"
    )]
    SliceOutOfOrder {
        task_id: i64,
        done_end: u32,
        begin: u32,
    },
    /// A slice's tile or sample range is not its task's.
    #[error("{0}")]
    SliceShape(String),
    /// A slice's counts or sums cannot be right, or would overflow its tile.
    #[error("{0}")]
    SliceValues(String),
    /// The job's state does not allow the change (`states::job_transition` refused it).
    #[error("{0}")]
    InvalidState(String),
    /// A grouped write was dropped before its batch committed.
    #[error("the write was interrupted before it committed; try again")]
    Interrupted,
    /// Stored data the server cannot read, or a broken invariant: a bug, not the client's doing.
    #[error("{0}")]
    Internal(String),
    /// The database failed or could not be reached.
    #[error("database: {0}")]
    Database(Arc<sqlx::Error>),
}

pub type StoreResult<T> = Result<T, Error>;

impl Error {
    pub fn not_found(what: &'static str, id: impl std::fmt::Display) -> Error {
        Error::NotFound {
            what,
            id: id.to_string(),
        }
    }

    pub fn internal(message: impl Into<String>) -> Error {
        Error::Internal(message.into())
    }

    /// A refusal of this request's input or of the farm's state, which concerns it alone (a
    /// group commit goes on with the others); the rest are failures of the store.
    pub fn is_refusal(&self) -> bool {
        !matches!(
            self,
            Error::Interrupted | Error::Internal(_) | Error::Database(_)
        )
    }
}

impl From<sqlx::Error> for Error {
    fn from(e: sqlx::Error) -> Error {
        Error::Database(Arc::new(e))
    }
}
