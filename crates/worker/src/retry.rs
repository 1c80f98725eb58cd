//! The one retry policy of the worker and the command-line client: which failures are tried again,
//! how long to wait before each new try, and the helper every retry loop goes through.
//!
//! - **What is retried:** only [`ClientError::is_transient`] failures: no answer (connection
//!   refused or reset, a timeout) or a 5xx. A request that cannot be built, a failed TLS handshake,
//!   a malformed answer and every 4xx fail at once: trying again cannot change them. (A worker the
//!   server forgot, [`needs_registration`], registers again rather than retrying the call.)
//! - **How long to wait:** exponential growth from a policy's `base` up to its `cap` (backon's
//!   [`ExponentialBuilder`] computes the ceiling), with *full jitter*: each wait is drawn uniformly
//!   from `[0, ceiling]`. So a farm of workers that lost the server at the same moment does not
//!   come back on the same beat.
//! - **Retry-After:** when the server says how long to wait (a 503 `busy`, say), the wait is at least
//!   that (bounded by [`RETRY_AFTER_MAX`]).
//!
//! [`retry`] runs a call under a policy with backon's [`Retryable`]; [`Backoff`] gives the same waits
//! to loops that decide for themselves when to try again (the worker's abandoned tasks, its
//! lease requests refused with a 429 — the wait then at least the `Retry-After` — and its polls of
//! a server that answered at once that there is no work).

use crate::client::ClientError;
use backon::{BackoffBuilder, ExponentialBuilder, Retryable};
use std::future::Future;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// The longest `Retry-After` honoured: a server that asks for more is asked again after this.
pub const RETRY_AFTER_MAX: Duration = Duration::from_secs(300);

/// The waits of one retry loop: exponential from `base` to `cap`, each drawn with full jitter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Policy {
    /// The ceiling of the first wait.
    pub base: Duration,
    /// The largest ceiling: no wait is longer.
    pub cap: Duration,
}

/// Registration while the server cannot be reached.
pub const REGISTER: Policy = Policy::new(Duration::from_millis(100), Duration::from_secs(5));
/// A lease request that got no answer.
pub const LEASE: Policy = Policy::new(Duration::from_millis(250), Duration::from_secs(5));
/// A slice upload that got no answer (within the lease, see the worker).
pub const UPLOAD: Policy = Policy::new(Duration::from_millis(100), Duration::from_secs(2));
/// The worker's wait after a task it had to give back unfinished.
pub const ABANDONED: Policy = Policy::new(Duration::from_millis(200), Duration::from_secs(30));
/// The command-line client while the server does not answer (`submit --wait`).
pub const CLIENT: Policy = Policy::new(Duration::from_millis(200), Duration::from_secs(5));

impl Policy {
    pub const fn new(base: Duration, cap: Duration) -> Policy {
        Policy { base, cap }
    }

    /// The waits, one per failure, without end.
    pub fn delays(self) -> FullJitter {
        FullJitter {
            ceilings: ExponentialBuilder::new()
                .with_min_delay(self.base)
                .with_max_delay(self.cap)
                .without_max_times()
                .build(),
            cap: self.cap,
            rng: fastrand::Rng::new(),
        }
    }
}

impl BackoffBuilder for Policy {
    type Backoff = FullJitter;
    fn build(self) -> FullJitter {
        self.delays()
    }
}

/// Full jitter over backon's exponential ceilings: each wait uniform in `[0, ceiling]`.
#[derive(Debug)]
pub struct FullJitter {
    ceilings: backon::ExponentialBackoff,
    cap: Duration,
    rng: fastrand::Rng,
}

impl Iterator for FullJitter {
    type Item = Duration;
    fn next(&mut self) -> Option<Duration> {
        let ceiling = self.ceilings.next()?.min(self.cap);
        Some(ceiling.mul_f64(self.rng.f64()))
    }
}

/// The waits of a loop that also starts over: [`Backoff::reset`] after a success.
#[derive(Debug)]
pub struct Backoff {
    policy: Policy,
    delays: FullJitter,
}

impl Backoff {
    pub fn new(policy: Policy) -> Backoff {
        Backoff {
            policy,
            delays: policy.delays(),
        }
    }
    /// The wait before the next try.
    pub fn next_delay(&mut self) -> Duration {
        self.delays.next().unwrap_or(self.policy.cap)
    }
    pub fn reset(&mut self) {
        self.delays = self.policy.delays();
    }
}

/// The server does not know this worker any more (no registration has its credential, or none has
/// its id): register again instead of retrying.
pub fn needs_registration(e: &ClientError) -> bool {
    match e {
        ClientError::Api { status, code, .. } => {
            (*status == reqwest::StatusCode::UNAUTHORIZED && code == "unknown_worker_credential")
                || (*status == reqwest::StatusCode::NOT_FOUND && code == "not_found")
        }
        _ => false,
    }
}

/// The wait after `e` given the policy's `jittered` one: never shorter than the server's
/// `Retry-After` (at most [`RETRY_AFTER_MAX`]).
pub fn wait_after(e: &ClientError, jittered: Duration) -> Duration {
    match e.retry_after() {
        Some(asked) => jittered.max(asked.min(RETRY_AFTER_MAX)),
        None => jittered,
    }
}

/// When a retry loop gives up besides on a failure that is not transient.
#[derive(Clone, Debug, Default)]
pub struct Limits {
    /// No try starts after this (a wait that would end past it is not waited).
    pub deadline: Option<Instant>,
    /// Asked to stop: a wait ends at once and no further try is made.
    pub stop: Option<watch::Receiver<bool>>,
}

/// Runs `call` until it succeeds or fails for good (not [`ClientError::is_transient`]), or until
/// `limits` end it (then the last failure is returned); between tries it waits as `policy` and
/// [`wait_after`] say. `notify` hears of each failure retried and the wait before the next try.
pub async fn retry<T, F, Fut>(
    policy: Policy,
    limits: Limits,
    call: F,
    notify: impl FnMut(&ClientError, Duration),
) -> Result<T, ClientError>
where
    F: FnMut() -> Fut,
    Fut: Future<Output = Result<T, ClientError>>,
{
    let stopped = {
        let stop = limits.stop.clone();
        move || stop.as_ref().is_some_and(|s| *s.borrow())
    };
    let sleeper = {
        let stop = limits.stop.clone();
        move |d: Duration| {
            let stop = stop.clone();
            async move {
                match stop {
                    Some(mut s) => {
                        let _ = tokio::time::timeout(d, s.wait_for(|s| *s)).await;
                    }
                    None => tokio::time::sleep(d).await,
                }
            }
        }
    };
    let deadline = limits.deadline;
    let stop_check = stopped.clone();
    call.retry(policy)
        .sleep(sleeper)
        .when(move |e| e.is_transient() && !stopped())
        .adjust(move |e, jittered| {
            let wait = wait_after(e, jittered?);
            match deadline {
                Some(d) if Instant::now() + wait >= d => None,
                _ if stop_check() => None,
                _ => Some(wait),
            }
        })
        .notify(notify)
        .await
}

#[cfg(test)]
mod tests {
    use super::*;
    use reqwest::StatusCode;
    use std::sync::atomic::{AtomicU32, Ordering};

    fn api(status: u16, code: &str, retry_after: Option<u64>) -> ClientError {
        ClientError::Api {
            status: StatusCode::from_u16(status).unwrap(),
            code: code.into(),
            message: "x".into(),
            retry_after: retry_after.map(Duration::from_secs),
        }
    }

    #[test]
    fn waits_are_jittered_within_their_growing_ceilings() {
        let p = Policy::new(Duration::from_millis(100), Duration::from_secs(2));
        let a: Vec<Duration> = p.delays().take(40).collect();
        let b: Vec<Duration> = p.delays().take(40).collect();
        assert_ne!(a, b, "two sequences drew the same waits");
        for (i, d) in a.iter().enumerate() {
            let ceiling = (p.base * 2u32.pow(i.min(20) as u32)).min(p.cap);
            assert!(*d <= ceiling, "wait {i}: {d:?} above {ceiling:?}");
        }
        // The waits grow: averaged over many sequences, the 5th is about 16 times the 1st.
        let mean = |i: usize| {
            (0..400)
                .map(|_| p.delays().nth(i).unwrap().as_secs_f64())
                .sum::<f64>()
                / 400.0
        };
        let (first, fifth, late) = (mean(0), mean(4), mean(30));
        assert!((0.035..0.065).contains(&first), "{first}");
        assert!(fifth > 8.0 * first, "{first} {fifth}");
        // Capped: late waits average half the cap.
        assert!((0.8..1.2).contains(&late), "{late}");
    }

    #[test]
    fn a_backoff_starts_over_when_reset() {
        let mut b = Backoff::new(Policy::new(
            Duration::from_millis(10),
            Duration::from_secs(60),
        ));
        for _ in 0..12 {
            b.next_delay();
        }
        b.reset();
        assert!(b.next_delay() <= Duration::from_millis(10));
    }

    #[test]
    fn retry_after_is_a_floor_with_a_bound() {
        let j = Duration::from_millis(30);
        assert_eq!(
            wait_after(&api(503, "busy", Some(2)), j),
            Duration::from_secs(2)
        );
        assert_eq!(wait_after(&api(503, "busy", None), j), j);
        assert_eq!(
            wait_after(&api(503, "busy", Some(86_400)), j),
            RETRY_AFTER_MAX
        );
    }

    #[test]
    fn which_failures_are_retried() {
        assert!(api(503, "busy", None).is_transient());
        assert!(api(500, "internal", None).is_transient());
        for status in [400, 401, 403, 404, 409, 413, 422, 429] {
            assert!(!api(status, "x", None).is_transient(), "{status}");
        }
        assert!(!ClientError::Protocol("bad json".into()).is_transient());
        assert!(needs_registration(&api(
            401,
            "unknown_worker_credential",
            None
        )));
        assert!(!needs_registration(&api(401, "unauthorized", None)));
    }

    #[tokio::test]
    async fn a_fatal_failure_stops_at_once_and_a_transient_one_is_retried() {
        let calls = AtomicU32::new(0);
        let r: Result<(), _> = retry(
            REGISTER,
            Limits::default(),
            || async {
                calls.fetch_add(1, Ordering::SeqCst);
                Err(api(401, "unknown_worker_credential", None))
            },
            |_, _| {},
        )
        .await;
        assert!(r.is_err());
        assert_eq!(calls.load(Ordering::SeqCst), 1);

        let calls = AtomicU32::new(0);
        let mut waits = Vec::new();
        let quick = Policy::new(Duration::from_millis(1), Duration::from_millis(5));
        let r = retry(
            quick,
            Limits::default(),
            || async {
                match calls.fetch_add(1, Ordering::SeqCst) {
                    0..=3 => Err(api(502, "http", None)),
                    _ => Ok(7),
                }
            },
            |_, d| waits.push(d),
        )
        .await;
        assert_eq!(r.unwrap(), 7);
        assert_eq!(waits.len(), 4);
        assert!(waits.iter().all(|d| *d <= quick.cap), "{waits:?}");
    }

    #[tokio::test]
    async fn retry_after_is_honoured_and_a_deadline_ends_the_tries() {
        let t = Instant::now();
        let calls = AtomicU32::new(0);
        let r = retry(
            CLIENT,
            Limits::default(),
            || async {
                match calls.fetch_add(1, Ordering::SeqCst) {
                    0 => Err(api(503, "busy", Some(1))),
                    _ => Ok(()),
                }
            },
            |_, _| {},
        )
        .await;
        assert!(r.is_ok());
        // The policy's first wait is at most 0.2 s: the server's second was waited.
        assert!(t.elapsed() >= Duration::from_secs(1), "{:?}", t.elapsed());

        let limits = Limits {
            deadline: Some(Instant::now() + Duration::from_millis(1)),
            stop: None,
        };
        let calls = AtomicU32::new(0);
        let r: Result<(), _> = retry(
            CLIENT,
            limits,
            || async {
                calls.fetch_add(1, Ordering::SeqCst);
                Err(api(503, "busy", Some(1)))
            },
            |_, _| {},
        )
        .await;
        assert!(r.is_err());
        assert_eq!(calls.load(Ordering::SeqCst), 1);
    }

    #[tokio::test]
    async fn a_stop_ends_the_wait_and_the_tries() {
        let (tx, rx) = watch::channel(false);
        let limits = Limits {
            deadline: None,
            stop: Some(rx),
        };
        let t = Instant::now();
        let slow = Policy::new(Duration::from_secs(60), Duration::from_secs(60));
        let task = tokio::spawn(retry(
            slow,
            limits,
            || async { Err::<(), _>(api(503, "busy", Some(60))) },
            |_, _| {},
        ));
        tokio::time::sleep(Duration::from_millis(50)).await;
        tx.send(true).unwrap();
        assert!(task.await.unwrap().is_err());
        assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
    }
}
