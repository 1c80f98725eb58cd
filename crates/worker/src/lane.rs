//! One lane of a worker: its loop of leasing, rendering and uploading tasks.

use crate::client::ApiClient;
use crate::config::WorkerConfig;
use crate::report::WorkerReport;
use crate::retry::{self, needs_registration, Backoff, Limits};
use crate::scene_cache::SceneCache;
use crate::session::{heartbeat_loop, register, CurrentLease, Session};
use crate::task::{give_back, work_on, InFlight, NextLease, Rate};
use crate::{lock, WorkerError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// One lane: register, then lease, render and upload until `stop` (see [`run`](crate::run)).
pub(crate) async fn lane(
    config: WorkerConfig,
    mut stop: watch::Receiver<bool>,
    pool: Arc<rayon::ThreadPool>,
    cache: Arc<tokio::sync::Mutex<SceneCache>>,
) -> Result<WorkerReport, WorkerError> {
    let client = ApiClient::with_ca_cert(
        &config.server,
        config.token.as_ref().map(|t| t.expose().to_string()),
        config.ca_cert.as_deref(),
    )?;
    let Some(mut session) = register(&client, &config, &mut stop).await? else {
        return Ok(WorkerReport::default());
    };
    let current: CurrentLease = Arc::new(Mutex::new(None));
    let lease_lost = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let beat = |session: &Session| {
        tokio::spawn(heartbeat_loop(
            session.client.clone(),
            session.worker_id.clone(),
            session.heartbeat_interval,
            current.clone(),
            lease_lost.clone(),
        ))
    };
    let mut heartbeat = beat(&session);
    let mut report = WorkerReport::default();
    let mut rate = Rate::default();
    // Waits between lease requests that found nothing (from a server that did not hold the
    // request) and after a lease refused (429), each with full jitter: workers that a server's
    // restart or a full queue stopped together do not come back together.
    let mut idle = retry::Backoff::new(retry::Policy::new(
        Duration::from_millis(20),
        config.idle_poll.max(Duration::from_millis(20)),
    ));
    let mut refused = retry::Backoff::new(retry::Policy::new(
        Duration::from_millis(250),
        (session.lease_duration / 4).max(Duration::from_millis(250)),
    ));
    let mut abandoned = Backoff::new(retry::ABANDONED);
    // The last slice of the task before, uploading while the next one is leased and rendered.
    let mut previous: Option<InFlight> = None;
    // The next task, asked for while the last slice of the current one renders.
    let mut next: Option<NextLease> = None;
    while !*stop.borrow() {
        let prefetched = match next.take() {
            // An empty queue or a failure: asked again below, with the usual retries and waits.
            Some(asked) => asked.await.ok().and_then(|r| r.ok()).flatten(),
            None => None,
        };
        // When the (last) lease request went out, if it asked the server to wait for work.
        let mut long_poll = None;
        let lease = match prefetched {
            Some(lease) => Ok(Some(lease)),
            None => {
                let wait = config.lease_wait;
                long_poll = (!wait.is_zero()).then(Instant::now);
                let asked = retry::retry(
                    retry::LEASE,
                    Limits {
                        deadline: None,
                        stop: Some(stop.clone()),
                    },
                    || {
                        long_poll = long_poll.map(|_| Instant::now());
                        session.client.lease_waiting(&session.worker_id, wait)
                    },
                    |e, d| tracing::warn!(error = %e, retry_in = ?d, "lease failed; retrying"),
                );
                // A long poll is not waited out when the worker is asked to stop.
                let mut stopping = stop.clone();
                tokio::select! {
                    answer = asked => answer,
                    _ = stopping.wait_for(|s| *s) => break,
                }
            }
        };
        if !matches!(lease, Ok(Some(_))) {
            // Nothing to render meanwhile: the answer for the last slice is awaited now.
            if let Some(p) = previous.take() {
                p.finish(&session.client, &mut report).await;
            }
        }
        let lease = match lease {
            Ok(l) => l,
            Err(_) if *stop.borrow() => break,
            Err(e) if needs_registration(&e) => {
                // The server forgot this worker (its registration expired while the worker was
                // cut off, say): register again, as a new worker, and go on.
                tracing::warn!(error = %e, "registration lost; registering again");
                heartbeat.abort();
                let Some(again) = register(&client, &config, &mut stop).await? else {
                    break;
                };
                session = again;
                heartbeat = beat(&session);
                continue;
            }
            Err(e) if e.status() == Some(reqwest::StatusCode::TOO_MANY_REQUESTS) => {
                // The farm is leasing as fast as the server's store can take (back-pressure:
                // its `Retry-After` says when), or leases this worker lost track of still count
                // against its cap until they expire: wait for that rather than give up.
                let after = retry::wait_after(&e, refused.next_delay());
                tracing::info!(error = %e, retry_in = ?after, "lease refused; waiting");
                wait(&mut stop, after).await;
                continue;
            }
            Err(e) => {
                heartbeat.abort();
                return Err(e.into());
            }
        };
        let Some(lease) = lease else {
            // A server that held the request has waited already; one that answered at once
            // (it does not wait, or it is shutting down) is asked again after a pause.
            let waited = long_poll.is_some_and(|t| t.elapsed() >= config.lease_wait / 2);
            if !waited {
                wait(&mut stop, idle.next_delay()).await;
            }
            continue;
        };
        idle.reset();
        refused.reset();
        *lock(&current) = Some((lease.task_id, lease.lease_token.clone()));
        lease_lost.store(false, std::sync::atomic::Ordering::SeqCst);
        let slices_before = report.slices;
        let outcome = work_on(
            &session,
            &config,
            &pool,
            &cache,
            &lease,
            &mut previous,
            &mut next,
            &mut stop,
            &lease_lost,
            &mut rate,
            &mut report,
        )
        .await;
        *lock(&current) = None;
        if let Some(p) = previous.take() {
            // The task ended before its first slice was rendered.
            p.finish(&session.client, &mut report).await;
        }
        if report.slices > slices_before {
            abandoned.reset();
        }
        match outcome {
            Ok(in_flight) => {
                match in_flight {
                    Some(last) => previous = Some(last),
                    None => report.tasks += 1,
                }
                abandoned.reset();
            }
            Err(e) if e.is_farm_decision() => {
                // The farm took the task back (a cancel, an early stop, an expired lease): nothing
                // is wrong here, so the next lease is asked for at once.
                tracing::info!(task = lease.task_id, reason = %e, "task taken back");
            }
            Err(e) => {
                // Whatever went wrong may well go wrong again with the next lease (often the same
                // task): wait before asking, longer each time nothing could be done.
                if let Some(asked) = next.take() {
                    give_back(asked, &session.client).await;
                }
                let delay = abandoned.next_delay();
                tracing::warn!(task = lease.task_id, error = %e, retry_in = ?delay, "task abandoned");
                wait(&mut stop, delay).await;
            }
        }
    }
    if let Some(p) = previous.take() {
        p.finish(&session.client, &mut report).await;
    }
    if let Some(asked) = next.take() {
        give_back(asked, &session.client).await;
    }
    heartbeat.abort();
    if let Err(e) = session.client.deregister(&session.worker_id).await {
        tracing::warn!(error = %e, "could not sign off");
    }
    tracing::info!(
        tasks = report.tasks,
        slices = report.slices,
        samples = report.samples,
        invalid_samples = report.invalid_samples,
        render_seconds = report.render_seconds,
        "worker stopped"
    );
    Ok(report)
}

/// Waits `d`, or less if asked to stop.
async fn wait(stop: &mut watch::Receiver<bool>, d: Duration) {
    let _ = tokio::time::timeout(d, stop.wait_for(|s| *s)).await;
}
