//! A worker's registration with the server (a [`Session`]) and the heartbeat that keeps it and
//! its lease alive.

use crate::client::ApiClient;
use crate::config::{host_name, WorkerConfig};
use crate::retry::{self, Limits};
use crate::{lock, WorkerError};
use pathfarm_wire::api::{Heartbeat, WorkerRegistration};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// The lease the heartbeat extends.
pub(crate) type CurrentLease = Arc<Mutex<Option<(i64, String)>>>;

pub(crate) struct Session {
    pub(crate) client: ApiClient,
    pub(crate) worker_id: String,
    pub(crate) heartbeat_interval: Duration,
    pub(crate) lease_duration: Duration,
}

/// How long a worker waits for an unreachable server before its retries are logged as warnings.
const QUIET_REGISTRATION: Duration = Duration::from_secs(30);

pub(crate) async fn register(
    client: &ApiClient,
    config: &WorkerConfig,
    stop: &mut watch::Receiver<bool>,
) -> Result<Option<Session>, WorkerError> {
    let reg = WorkerRegistration {
        name: config.name.clone(),
        threads: config.threads as u32,
        version: env!("CARGO_PKG_VERSION").into(),
        host: host_name(),
    };
    if *stop.borrow() {
        return Ok(None);
    }
    let started = Instant::now();
    let registered = retry::retry(
        retry::REGISTER,
        Limits {
            deadline: None,
            stop: Some(stop.clone()),
        },
        || client.register(&reg),
        // A worker started with its server (or before it) waits for it quietly a while; one that
        // still cannot reach it after that says so louder, with each try's error.
        |e, d| {
            if started.elapsed() < QUIET_REGISTRATION {
                tracing::info!(error = %e, retry_in = ?d, "server not reachable yet");
            } else {
                tracing::warn!(error = %e, retry_in = ?d, "server still not reachable; retrying");
            }
        },
    )
    .await;
    match registered {
        Ok(r) => {
            tracing::info!(worker = %r.worker_id, server = client.base(), "registered");
            Ok(Some(Session {
                client: client.clone(),
                worker_id: r.worker_id,
                heartbeat_interval: Duration::from_millis(r.heartbeat_interval_ms.max(50)),
                lease_duration: Duration::from_millis(r.lease_duration_ms),
            }))
        }
        Err(_) if *stop.borrow() => Ok(None),
        Err(e) => Err(e.into()),
    }
}

pub(crate) async fn heartbeat_loop(
    client: ApiClient,
    worker_id: String,
    interval: Duration,
    current: CurrentLease,
    lease_lost: Arc<std::sync::atomic::AtomicBool>,
) {
    // A heartbeat that gets no answer within an interval is given up, so the next one goes out
    // on time: one stalled request must not outlast the lease it should extend.
    let client = client.with_timeout(heartbeat_timeout(interval));
    loop {
        tokio::time::sleep(interval).await;
        let held = lock(&current).clone();
        let hb = Heartbeat {
            task_id: held.as_ref().map(|h| h.0),
            lease_token: held.as_ref().map(|h| h.1.clone()),
        };
        match client.heartbeat(&worker_id, &hb).await {
            Ok(reply) => {
                if held.is_some() && !reply.lease_valid && *lock(&current) == held {
                    tracing::warn!(task = ?hb.task_id, "lease lost");
                    lease_lost.store(true, std::sync::atomic::Ordering::SeqCst);
                }
            }
            Err(e) => tracing::warn!(error = %e, "heartbeat failed"),
        }
    }
}

/// The limit of one heartbeat request: about the heartbeat interval, but at least 250 ms (very
/// short leases, in tests, still get an answer on a loaded machine).
fn heartbeat_timeout(interval: Duration) -> Duration {
    interval.max(Duration::from_millis(250))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heartbeats_time_out_after_their_interval_with_a_floor() {
        assert_eq!(
            heartbeat_timeout(Duration::from_millis(7500)),
            Duration::from_millis(7500)
        );
        assert_eq!(
            heartbeat_timeout(Duration::from_millis(50)),
            Duration::from_millis(250)
        );
    }
}
