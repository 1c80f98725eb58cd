//! The hot writes that may share a transaction (`group_commit.rs` runs them in batches on
//! SQLite; `tasks.rs` and `lease.rs` do them): what each asks and what each answers. Its own
//! module, so that the batching and the writes it batches depend on it and not on each other.

use pathfarm_wire::api::{Lease, SliceAck};
use pathfarm_wire::Slice;

/// A write that may share a transaction.
pub(super) enum Op {
    Merge {
        task_id: i64,
        token: String,
        slice: Slice,
    },
    Lease {
        worker_id: String,
        lease_ms: u64,
        max_leases: u32,
    },
}

/// What an [`Op`] returns.
pub(super) enum Done {
    Merged(MergeOutcome),
    Leased(Option<Box<Lease>>),
}

/// What a merge did (the ack, plus what the caller may want to log or count).
#[derive(Clone, Debug)]
pub struct MergeOutcome {
    pub ack: SliceAck,
    pub samples: u64,
    /// Pixel samples merged into a verification task (rendered again to check another worker's
    /// result; in no image).
    pub verification_samples: u64,
    pub job_completed: bool,
    /// Set when every sample of the slice was invalid: nothing was merged, and the route answers
    /// 422 (after the transaction that requeued the task, or failed its job, committed).
    pub all_invalid: Option<AllInvalid>,
}

/// What a slice whose every sample is invalid did (see `Store::merge_slice`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum AllInvalid {
    /// Its task was queued again, for any worker but this one.
    Requeued { task_id: i64 },
    /// A second worker's slice of the same task was all invalid too: the job failed with this
    /// message.
    JobFailed { job_id: String, message: String },
}
