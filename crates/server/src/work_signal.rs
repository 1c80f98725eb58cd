//! Long-polled leases: an idle worker asks for a lease with `wait_ms`, and the server holds the
//! request until a task may have become leasable, instead of the worker asking again every few
//! hundred milliseconds. A job submitted to an idle farm starts at once rather than at the
//! workers' next poll, and idle workers cost the server nothing between events.
//!
//! Work becomes leasable through this server ([`WorkSignal::notify`]: a submission, a resumed
//! job, a released task) or elsewhere: a lease that expired, a worker lost, or on a farm of
//! several servers sharing PostgreSQL, a job another server took in. The monitor looks for
//! those on every step and wakes the waiters when queued tasks exist ([`crate::monitor`]), so a
//! waiter waits at most a monitor interval past any event, and its own deadline at most.
//!
//! A waiter wakes, tries to lease once, and waits again if nothing was there for it. Shutdown
//! ([`WorkSignal::close`]) answers every waiter `204` at once, so that graceful shutdown does not
//! wait out long polls.

use std::time::Duration;
use tokio::sync::watch;

/// The default longest wait of a lease request ([`crate::ServerConfig::max_lease_wait`],
/// `--lease-wait-seconds`; `wait_ms` is cut to it): below common proxies' idle timeouts, and short
/// enough that a worker whose connection silently died notices.
pub const MAX_LEASE_WAIT: Duration = Duration::from_secs(20);

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Wake {
    /// Bumped whenever work may have become leasable.
    epoch: u64,
    /// The server is shutting down: waiters answer now.
    closing: bool,
}

/// What wakes waiting lease requests. One per server ([`crate::AppState`]).
pub struct WorkSignal {
    tx: watch::Sender<Wake>,
}

impl Default for WorkSignal {
    fn default() -> Self {
        WorkSignal {
            tx: watch::channel(Wake::default()).0,
        }
    }
}

/// A waiting lease request's view of the signal: subscribe before trying to lease, so that work
/// queued between the try and the wait is not missed.
pub struct Waiter {
    rx: watch::Receiver<Wake>,
}

/// Why a [`Waiter`] stopped waiting.
#[derive(Debug, PartialEq, Eq)]
pub enum Woken {
    /// Work may be leasable: try again.
    Work,
    /// The deadline passed or the server is shutting down: answer that there is no work.
    Done,
}

impl WorkSignal {
    /// Work may have become leasable: wakes every waiter.
    pub fn notify(&self) {
        self.tx.send_modify(|w| w.epoch = w.epoch.wrapping_add(1));
    }

    /// The server is shutting down: every waiter, now and later, stops waiting.
    pub fn close(&self) {
        self.tx.send_modify(|w| w.closing = true);
    }

    /// Whether any lease request is waiting (the monitor looks for queued work only then).
    pub fn has_waiters(&self) -> bool {
        // The sender holds no receiver of its own: every receiver is a waiter's.
        self.tx.receiver_count() > 0
    }

    pub fn waiter(&self) -> Waiter {
        let mut rx = self.tx.subscribe();
        rx.mark_unchanged();
        Waiter { rx }
    }
}

impl Waiter {
    /// Waits until work may be leasable or `deadline`, whichever is first.
    pub async fn wait(&mut self, deadline: tokio::time::Instant) -> Woken {
        // Looked at without marking it seen: a notify since the waiter subscribed (or since its
        // last wait) is still pending, and `changed` answers it at once.
        if self.rx.borrow().closing {
            return Woken::Done;
        }
        tokio::select! {
            changed = self.rx.changed() => match changed {
                Ok(()) if !self.rx.borrow_and_update().closing => Woken::Work,
                _ => Woken::Done,
            },
            _ = tokio::time::sleep_until(deadline) => Woken::Done,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::time::Instant;

    #[tokio::test]
    async fn a_notify_wakes_a_waiter_and_close_ends_every_wait() {
        let signal = std::sync::Arc::new(WorkSignal::default());
        assert!(!signal.has_waiters());
        let mut w = signal.waiter();
        assert!(signal.has_waiters());
        // Nothing happens: the deadline ends the wait.
        let t0 = Instant::now();
        let woken = w.wait(t0 + Duration::from_millis(50)).await;
        assert_eq!(woken, Woken::Done);
        assert!(t0.elapsed() >= Duration::from_millis(50));
        // A notify between subscribing and waiting is not lost.
        signal.notify();
        let woken = w.wait(Instant::now() + Duration::from_secs(30)).await;
        assert_eq!(woken, Woken::Work);
        // A notify while waiting wakes it.
        let s = signal.clone();
        let notifier = tokio::spawn(async move {
            tokio::time::sleep(Duration::from_millis(20)).await;
            s.notify();
        });
        let t0 = Instant::now();
        assert_eq!(w.wait(t0 + Duration::from_secs(30)).await, Woken::Work);
        assert!(t0.elapsed() < Duration::from_secs(30));
        notifier.await.unwrap();
        // Closing ends this wait and every later one at once.
        let s = signal.clone();
        tokio::spawn(async move {
            tokio::time::sleep(Duration::from_millis(20)).await;
            s.close();
        });
        assert_eq!(
            w.wait(Instant::now() + Duration::from_secs(30)).await,
            Woken::Done
        );
        let mut late = signal.waiter();
        assert_eq!(
            late.wait(Instant::now() + Duration::from_secs(30)).await,
            Woken::Done
        );
        drop((w, late));
        assert!(!signal.has_waiters());
    }
}
