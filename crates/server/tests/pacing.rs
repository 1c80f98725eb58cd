//! Back-pressure (issue 32, item 10): every lease and upload acknowledgement carries the slice
//! length the server asks for, which follows the active workers and the store's measured write
//! capacity; `/metrics` shows the estimate. Real handlers through the router (`oneshot`) on the
//! real stores. (The arithmetic is tested in `pacing.rs`; the load it holds is measured by
//! `pathfarm bench farm --open-loop`.)

mod common;

use axum::http::StatusCode;
use common::*;
use pathfarm_server::AppState;
use std::time::Duration;

#[tokio::test]
async fn leases_and_acks_carry_a_slice_length_that_follows_the_workers() {
    for (store, url) in stores("pacing").await {
        let state = AppState::open(config(&url)).await.unwrap();
        let s = serde_json::to_string(&settings(64, 64, 8, 8)).unwrap();
        submit_ok(&state, None, &cornell(), &s).await;
        let mut workers = Vec::new();
        for _ in 0..30 {
            workers.push(register_in_process(&state).await);
        }
        // Each worker leases a task and uploads it one sample at a time.
        let mut leases = Vec::new();
        for w in &workers {
            let l = lease_in_process(&state, w).await.expect("a task");
            let hint = l.slice_seconds.expect("a lease names the slice length");
            assert!(hint.is_finite() && hint >= 0.0, "{store}: {hint}");
            leases.push(l);
        }
        for (w, l) in workers.iter().zip(&leases) {
            for b in l.sample_begin..l.sample_end {
                let ack = upload_grey(&state, w, l, (b, b + 1)).await;
                assert!(ack.slice_seconds.is_some(), "{store}: an ack names it too");
            }
        }
        // The next write after a window closes redoes the estimate.
        tokio::time::sleep(pathfarm_server::pacing::WINDOW + Duration::from_millis(50)).await;
        let l = lease_in_process(&state, &workers[0]).await.expect("a task");
        let view = state.pacing.view();
        assert_eq!(view.active_workers, 30, "{store}: {view:?}");
        let capacity = view.capacity.expect("a busy window was measured");
        assert!(capacity > 0.0, "{store}: {view:?}");
        // 30 workers' writes at half the measured capacity.
        let expected = 30.0 * (1.0 + view.leases_per_upload) / (0.5 * capacity);
        assert!(
            (view.slice_seconds - expected).abs() <= 1e-9 * expected,
            "{store}: {view:?}"
        );
        assert!(view.slice_seconds > 0.0, "{store}: {view:?}");
        assert_eq!(l.slice_seconds, Some(view.slice_seconds), "{store}");

        let (status, _, body) = call_raw(&state, request("GET", "/metrics", &[], "")).await;
        assert_eq!(status, StatusCode::OK);
        let text = String::from_utf8(body.to_vec()).unwrap();
        assert!(
            text.contains("\npathfarm_pacing_active_workers 30\n"),
            "{store}"
        );
        assert!(text.contains("\npathfarm_pacing_slice_seconds "), "{store}");
        state.store.close().await;
    }
}
