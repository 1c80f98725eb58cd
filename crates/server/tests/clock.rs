//! The store reads the time from the clock it is given: a lease expires, and a silent worker is
//! lost, when a manual clock passes the lease's duration, without the test waiting for it.

mod common;

use axum::http::StatusCode;
use common::*;
use pathfarm_server::store::{Error, ManualClock};
use pathfarm_server::{monitor, AppState};
use pathfarm_wire::api::{Lease, WorkerList, WorkerRegistered, WorkerState};
use serde_json::json;
use std::sync::Arc;
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn leases_expire_and_workers_are_lost_when_the_clock_says_so() {
    let clock = Arc::new(ManualClock::new());
    let url = format!("sqlite://{}", temp_dir("clock").join("farm.db").display());
    let mut c = config(&url);
    c.lease_duration = Duration::from_secs(30);
    c.clock = clock.clone();
    let state = AppState::open(c).await.unwrap();

    let (ct, body) = multipart(&cornell(), r#"{"width":16,"height":16,"spp":1}"#);
    let (status, _, _) = call_raw(
        &state,
        request("POST", "/api/v1/jobs", &[("content-type", &ct)], body),
    )
    .await;
    assert_eq!(status, StatusCode::CREATED);
    let registration = json!({"name": "w", "threads": 1, "version": "t", "host": "h"});
    let (status, reg): (_, WorkerRegistered) = call(
        &state,
        request(
            "POST",
            "/api/v1/workers",
            &[("content-type", "application/json")],
            registration.to_string(),
        ),
    )
    .await;
    assert_eq!(status, StatusCode::CREATED);
    let uri = format!("/api/v1/workers/{}/lease", reg.worker_id);
    let (status, lease): (_, Lease) = call(
        &state,
        request(
            "POST",
            &uri,
            &[("pathfarm-worker-credential", &reg.credential)],
            "",
        ),
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    let workers = |state: AppState| async move {
        let (_, list): (_, WorkerList) =
            call(&state, request("GET", "/api/v1/workers", &[], "")).await;
        list.workers[0].state
    };

    // Within the lease, by the clock: the monitor leaves it alone.
    clock.advance(Duration::from_secs(29));
    monitor::step(&state).await.unwrap();
    state
        .store
        .leased_tile(lease.task_id, &lease.lease_token)
        .await
        .expect("the lease holds");
    assert_eq!(workers(state.clone()).await, WorkerState::Busy);

    // Past it: the lease is gone and the worker lost, at once.
    clock.advance(Duration::from_secs(2));
    monitor::step(&state).await.unwrap();
    let stale = state
        .store
        .leased_tile(lease.task_id, &lease.lease_token)
        .await;
    assert!(matches!(stale, Err(Error::StaleLease { .. })), "{stale:?}");
    assert_eq!(workers(state.clone()).await, WorkerState::Lost);
}
