//! The job, task and worker state machines, enforced here and nowhere else: every state change the
//! store makes asks these functions first. `ARCHITECTURE.md` draws the same machines.

use pathfarm_wire::api::{JobState, WorkerState};

/// What can happen to a job.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JobEvent {
    /// A worker leased one of its tasks.
    Leased,
    Pause,
    /// Resume a paused job; `started` says whether any task was ever leased.
    Resume {
        started: bool,
    },
    Cancel,
    /// Every planned sample merged, or the noise target or time limit reached.
    Complete,
    Fail,
    /// A completed job's tiles hold work of a worker since found wrong (`store/verification.rs`):
    /// they are rendered again.
    Reopen,
}

/// The state a job moves to, or `Err` with a message when the event is not allowed in `from`.
pub fn job_transition(from: JobState, event: JobEvent) -> Result<JobState, String> {
    use JobEvent as E;
    use JobState as S;
    let to = match (from, event) {
        (S::Queued | S::Running, E::Leased) => S::Running,
        (S::Queued | S::Running, E::Pause) => S::Paused,
        (S::Paused, E::Resume { started: true }) => S::Running,
        (S::Paused, E::Resume { started: false }) => S::Queued,
        (S::Queued | S::Running | S::Paused, E::Cancel) => S::Cancelled,
        // A paused job can complete: its leased tasks may finish their last slices.
        (S::Queued | S::Running | S::Paused, E::Complete) => S::Completed,
        (S::Queued | S::Running | S::Paused, E::Fail) => S::Failed,
        (S::Completed, E::Reopen) => S::Running,
        (S::Queued | S::Running | S::Paused, E::Reopen) => from,
        _ => {
            return Err(format!(
                "a {} job cannot {}",
                from.as_str(),
                match event {
                    E::Leased => "be leased",
                    E::Pause => "be paused",
                    E::Resume { .. } => "be resumed",
                    E::Cancel => "be cancelled",
                    E::Complete => "complete",
                    E::Fail => "fail",
                    E::Reopen => "be reopened",
                }
            ))
        }
    };
    Ok(to)
}

/// Task states. A task is `(job, tile, sample range)`; `done_end` records how far it is merged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TaskState {
    Queued,
    Leased,
    Done,
    Cancelled,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TaskEvent {
    Lease,
    /// A slice was merged; `complete` when it was the last one.
    Merged {
        complete: bool,
    },
    /// The worker gave the lease back, or the lease expired: the unmerged rest is queued again.
    Requeue,
    Cancel,
    /// Its frame reached the job's noise target while it was queued: it ends as it stands, done
    /// with the samples merged so far (`merged`: some were) or cancelled (none were).
    Stop {
        merged: bool,
    },
}

impl TaskState {
    pub fn as_str(self) -> &'static str {
        match self {
            TaskState::Queued => "queued",
            TaskState::Leased => "leased",
            TaskState::Done => "done",
            TaskState::Cancelled => "cancelled",
        }
    }
    pub fn parse(s: &str) -> Option<TaskState> {
        [
            TaskState::Queued,
            TaskState::Leased,
            TaskState::Done,
            TaskState::Cancelled,
        ]
        .into_iter()
        .find(|t| t.as_str() == s)
    }
}

pub fn task_transition(from: TaskState, event: TaskEvent) -> Result<TaskState, String> {
    use TaskEvent as E;
    use TaskState as S;
    match (from, event) {
        (S::Queued, E::Lease) => Ok(S::Leased),
        (S::Leased, E::Merged { complete: false }) => Ok(S::Leased),
        (S::Leased, E::Merged { complete: true }) => Ok(S::Done),
        (S::Leased, E::Requeue) => Ok(S::Queued),
        (S::Queued | S::Leased, E::Cancel) => Ok(S::Cancelled),
        (S::Queued, E::Stop { merged: true }) => Ok(S::Done),
        (S::Queued, E::Stop { merged: false }) => Ok(S::Cancelled),
        _ => Err(format!("a {} task cannot take {event:?}", from.as_str())),
    }
}

/// What can happen to a worker.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WorkerEvent {
    /// It was given a task.
    Leased,
    /// It asked for work and there was none.
    NoWork,
    /// One of its slices was merged; `complete` when it finished the task.
    SliceMerged { complete: bool },
    /// It said it is alive; `leased` when it still holds the lease it names.
    Heartbeat { leased: bool },
    /// Its task was given back or expired, or its job ended: it has nothing to do.
    TaskTaken,
    /// It was silent for longer than a lease.
    Silent,
    /// It signed off.
    SignOff,
}

/// Every worker state, for the store's `CASE` over them ([`worker_transition`]).
pub const WORKER_STATES: [WorkerState; 4] = [
    WorkerState::Idle,
    WorkerState::Busy,
    WorkerState::Lost,
    WorkerState::Offline,
];

/// The state a worker moves to (itself when the event changes nothing). The store writes worker
/// states in set-based updates, so it asks this for every state at once
/// (`store::worker_state_after`) rather than reading each worker first.
pub fn worker_transition(from: WorkerState, event: WorkerEvent) -> WorkerState {
    use WorkerEvent as E;
    use WorkerState as S;
    match (from, event) {
        (_, E::Leased | E::SliceMerged { complete: false } | E::Heartbeat { leased: true }) => {
            S::Busy
        }
        (_, E::NoWork | E::SliceMerged { complete: true }) => S::Idle,
        // A busy worker's heartbeat without its lease keeps it busy until its upload or release
        // says otherwise; a lost or idle one is back and idle.
        (S::Busy, E::Heartbeat { leased: false }) => S::Busy,
        (_, E::Heartbeat { leased: false }) => S::Idle,
        (S::Busy, E::TaskTaken) => S::Idle,
        (S::Idle | S::Busy, E::Silent) => S::Lost,
        (_, E::SignOff) => S::Offline,
        (s, E::TaskTaken | E::Silent) => s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn workers_come_back_and_sign_off() {
        use WorkerEvent as E;
        use WorkerState as S;
        let lost = worker_transition(S::Busy, E::Silent);
        assert_eq!(lost, S::Lost);
        assert_eq!(worker_transition(lost, E::Silent), S::Lost);
        assert_eq!(
            worker_transition(lost, E::Heartbeat { leased: false }),
            S::Idle
        );
        assert_eq!(
            worker_transition(lost, E::Heartbeat { leased: true }),
            S::Busy
        );
        assert_eq!(worker_transition(S::Idle, E::TaskTaken), S::Idle);
        assert_eq!(worker_transition(S::Busy, E::TaskTaken), S::Idle);
        assert_eq!(worker_transition(S::Offline, E::Silent), S::Offline);
        for s in WORKER_STATES {
            assert_eq!(worker_transition(s, E::SignOff), S::Offline);
            assert_eq!(worker_transition(s, E::Leased), S::Busy);
        }
    }

    #[test]
    fn final_job_states_never_change() {
        for s in JobState::ALL.into_iter().filter(|s| s.is_final()) {
            for e in [
                JobEvent::Leased,
                JobEvent::Pause,
                JobEvent::Resume { started: true },
                JobEvent::Cancel,
                JobEvent::Complete,
                JobEvent::Fail,
            ] {
                assert!(job_transition(s, e).is_err(), "{s:?} {e:?}");
            }
        }
    }

    #[test]
    fn pause_resume_cycle() {
        let s = job_transition(JobState::Running, JobEvent::Pause).unwrap();
        assert_eq!(s, JobState::Paused);
        assert!(job_transition(s, JobEvent::Leased).is_err());
        assert_eq!(
            job_transition(s, JobEvent::Resume { started: true }).unwrap(),
            JobState::Running
        );
        assert_eq!(
            job_transition(s, JobEvent::Resume { started: false }).unwrap(),
            JobState::Queued
        );
        assert!(job_transition(JobState::Running, JobEvent::Resume { started: true }).is_err());
    }

    #[test]
    fn tasks_finish_once() {
        let t = task_transition(TaskState::Queued, TaskEvent::Lease).unwrap();
        let t = task_transition(t, TaskEvent::Merged { complete: true }).unwrap();
        assert_eq!(t, TaskState::Done);
        assert!(task_transition(t, TaskEvent::Requeue).is_err());
        assert!(task_transition(t, TaskEvent::Cancel).is_err());
        assert!(task_transition(TaskState::Queued, TaskEvent::Merged { complete: false }).is_err());
        // A queued task of a frame stopped at its noise target ends as it stands.
        let stop = |merged| task_transition(TaskState::Queued, TaskEvent::Stop { merged });
        assert_eq!(stop(true), Ok(TaskState::Done));
        assert_eq!(stop(false), Ok(TaskState::Cancelled));
        assert!(task_transition(TaskState::Leased, TaskEvent::Stop { merged: true }).is_err());
    }
}
