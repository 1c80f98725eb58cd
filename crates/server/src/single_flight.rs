//! Single flight: concurrent requests for the same piece of work (a job's image, one encoding of
//! it) wait for one run of it and share its result.
//!
//! The work runs in a task of its own, so it finishes (and its result can be kept) even when every
//! request that waited for it went away; a panic in it is a 500 for each waiter. A run carries a
//! *mark* the work may set as it goes (the job version an image build read): a newcomer joins a
//! run only if [`SingleFlight::run`]'s `joins` accepts its mark, else it starts a run of its own,
//! which later newcomers then join.

use crate::error::{ApiError, ApiResult};
use std::collections::HashMap;
use std::future::Future;
use std::hash::Hash;
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use tokio::sync::watch;

/// A run's mark before the work set one.
pub const UNMARKED: i64 = i64::MIN;

type Outcome<V> = Option<ApiResult<V>>;

struct Run<V> {
    id: u64,
    mark: Arc<AtomicI64>,
    done: watch::Receiver<Outcome<V>>,
}

type Runs<K, V> = Arc<Mutex<HashMap<K, Run<V>>>>;

pub struct SingleFlight<K, V> {
    runs: Runs<K, V>,
    next_id: AtomicU64,
    /// Callers that joined a run under way instead of starting one.
    joined: AtomicU64,
}

impl<K, V> Default for SingleFlight<K, V> {
    fn default() -> Self {
        SingleFlight {
            runs: Arc::default(),
            next_id: AtomicU64::new(0),
            joined: AtomicU64::new(0),
        }
    }
}

/// Nothing in this module panics while holding the lock, so the map is whole.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Takes a finished run out of the map (unless a newer run of the key replaced it), also when the
/// work panicked.
struct Finish<K: Eq + Hash, V> {
    runs: Runs<K, V>,
    key: K,
    id: u64,
}

impl<K: Eq + Hash, V> Drop for Finish<K, V> {
    fn drop(&mut self) {
        let mut runs = lock(&self.runs);
        if runs.get(&self.key).is_some_and(|r| r.id == self.id) {
            runs.remove(&self.key);
        }
    }
}

impl<K, V> SingleFlight<K, V>
where
    K: Eq + Hash + Clone + Send + Sync + 'static,
    V: Clone + Send + Sync + 'static,
{
    /// How many runs are under way.
    pub fn running(&self) -> usize {
        lock(&self.runs).len()
    }

    /// How many callers so far joined a run under way (rather than starting one).
    pub fn joined(&self) -> u64 {
        self.joined.load(Ordering::Relaxed)
    }

    /// The result of the run of `key` under way whose mark `joins` accepts, or of a new run of
    /// `work` (given the run's mark to set).
    pub async fn run<W, F>(&self, key: K, joins: impl Fn(i64) -> bool, work: W) -> ApiResult<V>
    where
        W: FnOnce(Arc<AtomicI64>) -> F,
        F: Future<Output = ApiResult<V>> + Send + 'static,
    {
        let mut done = {
            let mut runs = lock(&self.runs);
            match runs.get(&key) {
                Some(r) if joins(r.mark.load(Ordering::Acquire)) => {
                    self.joined.fetch_add(1, Ordering::Relaxed);
                    r.done.clone()
                }
                _ => {
                    let id = self.next_id.fetch_add(1, Ordering::Relaxed);
                    let mark = Arc::new(AtomicI64::new(UNMARKED));
                    let (tx, rx) = watch::channel(None);
                    let finish = Finish {
                        runs: self.runs.clone(),
                        key: key.clone(),
                        id,
                    };
                    let future = work(mark.clone());
                    tokio::spawn(async move {
                        let outcome = future.await;
                        // Out of the map before the result is out: whoever comes after it finds
                        // the result where the work left it (the cache), or starts afresh.
                        drop(finish);
                        let _ = tx.send(Some(outcome));
                    });
                    runs.insert(
                        key,
                        Run {
                            id,
                            mark,
                            done: rx.clone(),
                        },
                    );
                    rx
                }
            }
        };
        let result = match done.wait_for(Option::is_some).await {
            Ok(outcome) => match &*outcome {
                Some(result) => result.clone(),
                None => Err(ApiError::internal("image work ended without a result")),
            },
            // The work's task ended without sending: it panicked.
            Err(_) => Err(ApiError::internal("image work failed (a panic)")),
        };
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;
    use std::time::Duration;

    #[tokio::test]
    async fn concurrent_callers_share_one_run_and_later_ones_start_another() {
        let flights: Arc<SingleFlight<&str, usize>> = Arc::default();
        let runs = Arc::new(AtomicUsize::new(0));
        let (go, gate) = watch::channel(false);
        let mut waiters = Vec::new();
        for _ in 0..8 {
            let (flights, runs, gate) = (flights.clone(), runs.clone(), gate.clone());
            waiters.push(tokio::spawn(async move {
                flights
                    .run(
                        "k",
                        |_| true,
                        |_| async move {
                            let mut gate = gate;
                            let _ = gate.wait_for(|open| *open).await;
                            Ok(runs.fetch_add(1, Ordering::SeqCst) + 10)
                        },
                    )
                    .await
            }));
        }
        while flights.running() == 0 {
            tokio::task::yield_now().await;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
        go.send(true).unwrap();
        for w in waiters {
            assert_eq!(w.await.unwrap().unwrap(), 10);
        }
        assert_eq!(runs.load(Ordering::SeqCst), 1);
        assert_eq!(flights.running(), 0);
        let again = flights
            .run("k", |_| true, |_| async { Ok(99) })
            .await
            .unwrap();
        assert_eq!(again, 99, "a finished run is not joined");
    }

    /// A run whose mark the caller does not accept is not joined; a panic is a 500 for each
    /// waiter and leaves the key free.
    #[tokio::test]
    async fn marks_decide_who_joins_and_a_panic_is_an_internal_error() {
        let flights: Arc<SingleFlight<u8, i64>> = Arc::default();
        let (go, gate) = watch::channel(false);
        let slow = {
            let (flights, gate) = (flights.clone(), gate.clone());
            tokio::spawn(async move {
                flights
                    .run(
                        1,
                        |_| true,
                        |mark| async move {
                            mark.store(5, Ordering::Release);
                            let mut gate = gate;
                            let _ = gate.wait_for(|open| *open).await;
                            Ok(5)
                        },
                    )
                    .await
            })
        };
        while flights.running() == 0 {
            tokio::task::yield_now().await;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
        // Wants version 6 or later: the run at 5 will not do.
        let newer = flights
            .run(1, |mark| mark >= 6, |_| async { Ok(6) })
            .await
            .unwrap();
        assert_eq!(newer, 6);
        go.send(true).unwrap();
        assert_eq!(slow.await.unwrap().unwrap(), 5);
        let err = flights
            .run(
                2,
                |_| true,
                |_| async {
                    if 1 + 1 == 2 {
                        panic!("bug");
                    }
                    Ok(0)
                },
            )
            .await
            .unwrap_err();
        assert_eq!(err.code, "internal");
        assert_eq!(flights.running(), 0);
    }
}
